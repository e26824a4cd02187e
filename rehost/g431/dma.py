"""DMA1 and the DMAMUX in front of it (RM0440 12, 13): a peripheral asks for one transfer by its request number
(RM0440 Table 91), the DMAMUX channel routing that request picks the DMA channel, and the channel moves one item
between memory and the peripheral register, counting down CNDTR and raising its flags. DMA1 has the part's channels
(RM0440 12.3.2: six on the G431, category 2; eight on the G474, categories 3 and 4); the G474's DMA2 is not
modelled."""

from .peripheral import Peripheral, bit, field

ISR, IFCR = 0x00, 0x04
# Each channel's interrupt (RM0440 Table 97): DMA1_CH1-DMA1_CH7 at 11-17 (17 only in categories 3 and 4),
# DMA1_CH8 at 96.
IRQS = (11, 12, 13, 14, 15, 16, 17, 96)
CHANNEL_BYTES = 0x14

# Request numbers (RM0440 Table 91, as stm32-data gives them for the G431).
REQUESTS = {"I2C1_RX": 16, "I2C1_TX": 17, "I2C2_RX": 18, "I2C2_TX": 19, "I2C3_RX": 20, "I2C3_TX": 21,
            "LPUART1_RX": 34, "LPUART1_TX": 35}


def ccr(channel):
    return 0x08 + CHANNEL_BYTES * (channel - 1)


class Dmamux(Peripheral):
    def channel_for(self, request):
        """The DMA1 channel whose DMAMUX channel routes `request`: DMAMUX channel n - 1 serves DMA1 channel n
        (RM0440 13.3.2; those after DMA1's serve DMA2)."""
        for channel in range(1, self.chip.part.dma_channels + 1):
            if field(self.regs.get(4 * (channel - 1), 0), 0, 7) == request:
                return channel
        return None


class Dma(Peripheral):
    def __init__(self, chip, name, base):
        super().__init__(chip, name, base)
        self.channels = chip.part.dma_channels

    def reset(self):
        super().reset()
        self._done = {}  # items moved since the channel was enabled
        self._total = {}  # CNDTR when it was enabled

    def _absent(self, offset):
        """A channel's registers past the part's last channel (RM0440 12.6: CCR7-CMAR8 exist only in categories 3
        and 4; 12.3.2): the run stops there."""
        if offset >= ccr(self.channels + 1):
            self.chip.core.fail(f"{self.name} {offset:#04x}: the {self.chip.part.name}'s DMA1 has {self.channels} "
                                "channels (RM0440 12.3.2)")
            return True
        return False

    def read(self, offset):
        if self._absent(offset):
            return 0
        return super().read(offset)

    def write(self, offset, value):
        self.writes.add(offset)
        if self._absent(offset):
            return
        if offset == IFCR:
            self.regs[ISR] = self.regs.get(ISR, 0) & ~value
        elif offset == ISR:
            return
        else:
            channel = (offset - 0x08) // 0x14 + 1
            if (offset - 0x08) % 0x14 == 0 and value & 1 and not self.enabled(channel):
                self._done[channel] = 0
                self._total[channel] = self.regs.get(offset + 4, 0)
            self.regs[offset] = value
        self._update_irq()

    def enabled(self, channel):
        return bit(self.regs.get(ccr(channel), 0), 0)

    def remaining(self, channel):
        return self.regs.get(ccr(channel) + 4, 0)

    def request(self, name):
        """One transfer for a peripheral's request; False if no enabled channel serves it (the peripheral waits)."""
        channel = self.chip.dmamux.channel_for(REQUESTS[name])
        if channel is None or not self.enabled(channel):
            return False
        base = ccr(channel)
        config = self.regs.get(base, 0)
        count = self.regs.get(base + 4, 0)
        if count == 0:
            return False
        done = self._done.get(channel, 0)
        psize = 1 << field(config, 8, 2)
        msize = 1 << field(config, 10, 2)
        peripheral = self.regs.get(base + 8, 0) + (done * psize if bit(config, 6) else 0)
        memory = self.regs.get(base + 12, 0) + (done * msize if bit(config, 7) else 0)
        core = self.chip.core
        if bit(config, 4):  # DIR: memory to peripheral
            value = int.from_bytes(core.uc.mem_read(memory, msize), "little")
            core.bus_write(peripheral, psize, value)
        else:
            value = core.bus_read(peripheral, psize)
            core.uc.mem_write(memory, (value & ((1 << (8 * msize)) - 1)).to_bytes(msize, "little"))
        count -= 1
        done += 1
        total = self._total.get(channel, done + count)
        flags = 0
        if done == total // 2:
            flags |= 0b0101  # GIF, HTIF
        if count == 0:
            flags |= 0b0011  # GIF, TCIF
            if bit(config, 5):  # CIRC: start again
                count, done = total, 0
        self._done[channel] = done
        self.regs[base + 4] = count
        self.regs[ISR] = self.regs.get(ISR, 0) | (flags << (4 * (channel - 1)))
        self._update_irq()
        return True

    def _update_irq(self):
        isr = self.regs.get(ISR, 0)
        for channel in range(1, self.channels + 1):
            config = self.regs.get(ccr(channel), 0)
            flags = field(isr, 4 * (channel - 1), 4)
            # TCIE, HTIE and TEIE (CCR bits 1-3) enable TCIF, HTIF and TEIF (ISR bits 1-3).
            self.chip.irq(self, IRQS[channel - 1], bool(flags & config & 0b1110))
