"""LPUART1, the NUCLEO's virtual COM port (RM0440 38.7): bytes written to TDR leave one frame time later; bytes a
test sends arrive in RDR one frame time apart, with ORE when the image has not read the last one."""

from .peripheral import Peripheral

CR1, CR2, CR3, BRR, RQR, ISR, ICR, RDR, TDR, PRESC = 0x00, 0x04, 0x08, 0x0C, 0x18, 0x1C, 0x20, 0x24, 0x28, 0x2C
UE, RE, TE, RXNEIE, TCIE, TXEIE = 1 << 0, 1 << 2, 1 << 3, 1 << 5, 1 << 6, 1 << 7
ORE, IDLE, RXNE, TC, TXE, TEACK, REACK = 1 << 3, 1 << 4, 1 << 5, 1 << 6, 1 << 7, 1 << 21, 1 << 22
# ICR's clear bits, each clearing the ISR flag in its place: PE, FE, NE, ORE, IDLE, TC, CTSIF, CMF, WUF (38.7).
ICR_FLAGS = 0x0012_025F
IRQ = 91  # RM0440 Table 97


class Lpuart(Peripheral):
    narrow_merge = False
    resets = {ISR: TXE | TC}
    read_only = {ISR: 0xFFFF_FFFF, RDR: 0xFFFF_FFFF}

    def __init__(self, chip, name, base):
        super().__init__(chip, name, base)
        self.sent = bytearray()
        self.incoming = bytearray()
        self.overruns = 0
        self._sending = False
        self._receiving = False

    def reset(self):
        super().reset()
        self.sent = bytearray()
        self.incoming = bytearray()
        self._sending = False
        self._receiving = False

    def kernel_hz(self):
        return self.chip.rcc.pclk_hz(1)  # PCLK1, LPUART1's kernel clock after reset (CCIPR.LPUART1SEL = 00)

    def frame_cycles(self):
        # LPUART: baud = 256 x f_ck / BRR (38.5.7); a frame is 10 bits (8N1).
        brr = self.regs.get(BRR, 0) or 1
        return 10 * brr * self.chip.core.hz // (256 * self.kernel_hz())

    def baud(self):
        brr = self.regs.get(BRR, 0) or 1
        return 256 * self.kernel_hz() // brr

    def write(self, offset, value):
        self.writes.add(offset)
        isr = self.regs.get(ISR, 0)
        if offset == TDR:
            if not (self.regs.get(CR1, 0) & (UE | TE)) == (UE | TE):
                return
            self.regs[ISR] = isr & ~(TXE | TC)
            if not self._sending:
                self._start(value & 0xFF)
            else:
                self._next = value & 0xFF
        elif offset == ICR:
            self.regs[ISR] = isr & ~(value & ICR_FLAGS)
        elif offset == CR1:
            self.regs[CR1] = value
            ack = (TEACK if value & TE else 0) | (REACK if value & RE else 0)
            self.regs[ISR] = (isr & ~(TEACK | REACK)) | ack
        elif offset == RQR:
            if value & (1 << 3):  # RXFRQ
                self.regs[ISR] = isr & ~RXNE
        else:
            self.store(offset, value)
        self._update_irq()

    def read(self, offset):
        value = super().read(offset)
        if offset == RDR:
            self.chip.core.changing_read = True  # the read empties RDR
            self.regs[ISR] = self.regs.get(ISR, 0) & ~RXNE
            self._update_irq()
        return value

    def _start(self, byte):
        self._sending = True
        self._next = None
        # TDR moves to the shift register at once: TXE again, the byte on the wire for one frame.
        self.regs[ISR] = self.regs.get(ISR, 0) | TXE
        self.chip.core.at(self.chip.core.cycles + self.frame_cycles(), lambda: self._sent(byte))

    def _sent(self, byte):
        self.sent.append(byte)
        self._sending = False
        if self._next is not None:
            self._start(self._next)
        else:
            self.regs[ISR] = self.regs.get(ISR, 0) | TC | TXE
        self._update_irq()

    def send(self, data):
        """Bytes from the ground station, one frame time apart."""
        self.incoming += data
        if not self._receiving:
            self._receiving = True
            self.chip.core.at(self.chip.core.cycles + self.frame_cycles(), self._arrive)

    def _arrive(self):
        if not self.incoming:
            self._receiving = False
            return
        byte = self.incoming.pop(0)
        cr1 = self.regs.get(CR1, 0)
        if cr1 & UE and cr1 & RE:
            isr = self.regs.get(ISR, 0)
            if isr & RXNE:
                self.regs[ISR] = isr | ORE  # the byte in RDR was not read in time: this one is lost
                self.overruns += 1
            else:
                self.regs[RDR] = byte
                self.regs[ISR] = isr | RXNE
            self._update_irq()
        self.chip.core.at(self.chip.core.cycles + self.frame_cycles(), self._arrive)

    def _update_irq(self):
        cr1, isr = self.regs.get(CR1, 0), self.regs.get(ISR, 0)
        level = (cr1 & RXNEIE and isr & (RXNE | ORE)) or (cr1 & TXEIE and isr & TXE) or (cr1 & TCIE and isr & TC)
        self.chip.irq(self, IRQ, bool(level))
