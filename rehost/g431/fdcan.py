"""FDCAN1 and its message RAM (RM0440 44.3.3, 44.4): the configuration handshake (CCCR.INIT / CCE), the reset
values embassy-stm32 checks, and received classic frames placed in Rx FIFO 0 as the hardware places them."""

import struct

from .peripheral import Peripheral, bit, field

CREL, ENDN, CCCR, NBTP, PSR, IR, IE, ILS, ILE, RXGFC = 0x00, 0x04, 0x18, 0x1C, 0x44, 0x50, 0x54, 0x58, 0x5C, 0x80
RXF0S, RXF0A, TXFQS, TXBAR, TXBTO = 0x90, 0x94, 0xC4, 0xCC, 0xD4
INIT, CCE, CSA, CSR = 1 << 0, 1 << 1, 1 << 3, 1 << 4
RF0N = 1 << 0
IT0_IRQ, IT1_IRQ = 21, 22  # RM0440 Table 97

# Message RAM layout per instance (RM0440 44.3.3, Figure 614): Rx FIFO 0 at word 44 (0x0B0), 3 elements of
# 18 words; Tx buffers at 0x278, 3 elements of 18 words.
RX_FIFO0, TX_BUFFERS, ELEMENT, ELEMENTS = 0x0B0, 0x278, 72, 3


class MessageRam(Peripheral):
    narrow_merge = True


class Fdcan(Peripheral):
    # CREL: release 3.2.1 (2014-12-18); ENDN: the endianness test value; CCCR: INIT after reset; NBTP's reset;
    # PSR: LEC and DLEC = 7 (no change); TXFQS: three free Tx buffers.
    resets = {CREL: 0x3214_1218, ENDN: 0x8765_4321, CCCR: INIT, NBTP: 0x0600_0A03, PSR: 0x0000_0707, TXFQS: 3}
    # The hardware's registers and fields (44.4): release, endianness, PSR's state, the FIFO and buffer status.
    read_only = {CREL: 0xFFFF_FFFF, ENDN: 0xFFFF_FFFF, PSR: 0x007F_00F8, RXF0S: 0xFFFF_FFFF, TXFQS: 0xFFFF_FFFF,
                 TXBTO: 0xFFFF_FFFF}

    def __init__(self, chip, name, base):
        super().__init__(chip, name, base)
        self.ram = None
        self.sent = []  # (id, data) of every frame the image transmitted

    def reset(self):
        super().reset()
        self.sent = []

    def write(self, offset, value):
        self.writes.add(offset)
        if offset == CCCR:
            if not value & INIT:
                value &= ~CCE  # CCE is cleared when INIT is (44.4.7)
            value = (value & ~CSA) | (CSA if value & CSR else 0)  # a clock stop is acknowledged at once (44.4)
            self.regs[CCCR] = value
        elif offset == IR:
            self.regs[IR] = self.regs.get(IR, 0) & ~value  # rc_w1
        elif offset == RXF0A:
            status = self.regs.get(RXF0S, 0)
            level = max(field(status, 0, 4) - 1, 0)
            get = (field(value, 0, 2) + 1) % ELEMENTS
            self.regs[RXF0S] = (status & ~0x30F) | level | (get << 8)
        elif offset == TXBAR:
            for index in range(ELEMENTS):
                if value >> index & 1:
                    self._transmit(index)
        elif offset in (NBTP,) and not (self.regs.get(CCCR, 0) & CCE):
            return  # protected unless CCE and INIT are set (44.4.9)
        else:
            self.store(offset, value)
        self._update_irq()

    def operational(self):
        return not self.regs.get(CCCR, INIT) & INIT

    def receive(self, can_id, data):
        """A classic standard-id frame from the bus, stored in Rx FIFO 0 (the default global filter accepts it)."""
        status = self.regs.get(RXF0S, 0)
        level, put = field(status, 0, 4), field(status, 16, 2)
        if not self.operational() or level >= ELEMENTS:
            return False
        words = [can_id << 18, len(data) << 16] + list(struct.unpack("<2I", bytes(data).ljust(8, b"\0")))
        self.ram.regs.update({RX_FIFO0 + ELEMENT * put + 4 * i: w for i, w in enumerate(words)})
        level += 1
        self.regs[RXF0S] = (status & ~0x3_000F & ~(1 << 24)) | level | (((put + 1) % ELEMENTS) << 16) | (
            (1 << 24) if level == ELEMENTS else 0)
        self.regs[IR] = self.regs.get(IR, 0) | RF0N
        self._update_irq()
        return True

    def _transmit(self, index):
        base = TX_BUFFERS + ELEMENT * index
        word0, word1 = self.ram.regs.get(base, 0), self.ram.regs.get(base + 4, 0)
        length = min(field(word1, 16, 4), 8)
        data = struct.pack("<2I", self.ram.regs.get(base + 8, 0), self.ram.regs.get(base + 12, 0))[:length]
        self.sent.append((field(word0, 18, 11), data))
        self.regs[TXBTO] = self.regs.get(TXBTO, 0) | (1 << index)

    def _update_irq(self):
        pending = self.regs.get(IR, 0) & self.regs.get(IE, 0)
        lines = self.regs.get(ILS, 0)
        enabled = self.regs.get(ILE, 0)
        # ILS groups the interrupts on G4 (RXFIFO0 is bit 0); ILE enables the two lines.
        line0 = bool(pending & ~lines) and bit(enabled, 0)
        line1 = bool(pending & lines) and bit(enabled, 1)
        self.chip.irq(self, IT0_IRQ, bool(line0))
        self.chip.irq(self, IT1_IRQ, bool(line1))
