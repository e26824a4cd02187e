"""The I2C v2 peripheral (RM0440 37) as a byte-level state machine on the core's clock, in both roles the images
use: a slave answering a modelled master (the thruster's I2C3), and a master talking to modelled devices (the
master's three buses). Clock stretching is what makes it work: whenever the peripheral needs software (ADDR set,
RXDR full, TXDR empty, TCR), the bus waits until the register access that releases it (37.4.5-37.4.9)."""

from .peripheral import Peripheral, field

CR1, CR2, OAR1, OAR2, TIMINGR, TIMEOUTR, ISR, ICR, PECR, RXDR, TXDR = (
    0x00, 0x04, 0x08, 0x0C, 0x10, 0x14, 0x18, 0x1C, 0x20, 0x24, 0x28)
# CR1
PE, TXIE, RXIE, ADDRIE, NACKIE, STOPIE, TCIE, ERRIE = (1 << n for n in range(8))
TXDMAEN, RXDMAEN, SBC, NOSTRETCH = 1 << 14, 1 << 15, 1 << 16, 1 << 17
# CR2
RD_WRN, START, STOP, NACK, RELOAD, AUTOEND, PECBYTE = 1 << 10, 1 << 13, 1 << 14, 1 << 15, 1 << 24, 1 << 25, 1 << 26
# ISR
TXE, TXIS, RXNE, ADDR, NACKF, STOPF, TC, TCR, BERR, ARLO, OVR = (1 << n for n in range(11))
TIMEOUT, BUSY, DIR = 1 << 12, 1 << 15, 1 << 16
ICR_FLAGS = ADDR | NACKF | STOPF | BERR | ARLO | OVR | (1 << 11) | TIMEOUT | (1 << 13)

# RM0440 Table 97: event and error vectors.
IRQS = {1: (31, 32), 2: (33, 34), 3: (92, 93)}


class Transaction:
    """A transfer the modelled master makes to the image's slave: write `data`, then (repeated START) read
    `read_length` bytes. `done` once the STOP is on the bus; `error` says why it stopped early."""

    def __init__(self, address, data, read_length, stretch_limit_us):
        self.address = address
        self.data = bytes(data)
        self.read_length = read_length
        self.stretch_limit_us = stretch_limit_us
        self.read = bytearray()
        self.done = False
        self.error = None
        self.started = None
        self.ended = None
        self.longest_stretch_us = 0.0


class I2c(Peripheral):
    resets = {ISR: TXE}
    read_only = {PECR: 0xFF, RXDR: 0xFF}

    def __init__(self, chip, name, base, number):
        super().__init__(chip, name, base)
        self.number = number
        self.devices = {}  # address -> device, for the image as master
        self.bus_hz = 100_000  # the modelled master's SCL rate
        self.transfers = []  # (address, written, read, acked) of the image's master transfers
        self._wait = None  # what the bus waits for: a function returning True once it may go on
        self._waiting_since = 0
        self._then = None
        self._job = None

    def reset(self):
        super().reset()
        self._wait = None
        self._then = None
        self._job = None
        self.transfers = []

    # Registers -------------------------------------------------------------------------------------------------
    def read(self, offset):
        value = super().read(offset)
        if offset == RXDR:
            self.chip.core.changing_read = True  # the read empties RXDR
            self.regs[ISR] = self.regs.get(ISR, 0) & ~RXNE
            self._poke()
        return value

    def write(self, offset, value):
        self.writes.add(offset)
        isr = self.regs.get(ISR, 0)
        if offset == ICR:
            self.regs[ISR] = isr & ~(value & ICR_FLAGS)
        elif offset == ISR:
            # Software may set TXE (flushing TXDR) and TXIS (only with NOSTRETCH), 37.7.7.
            self.regs[ISR] = isr | (value & TXE)
        elif offset == TXDR:
            self.regs[TXDR] = value & 0xFF
            self.regs[ISR] = isr & ~(TXE | TXIS)
        elif offset == CR1:
            self.regs[CR1] = value
            if not value & PE:
                # PE = 0 resets the state machine and clears the flags but the RXDR/TXDR content (37.4.6).
                self.regs[ISR] = TXE
                self.regs[CR2] = self.regs.get(CR2, 0) & ~(NACK | PECBYTE)
                self._wait = None
                self._job = None
        elif offset == CR2:
            old = self.regs.get(CR2, 0)
            # NACK and PECBYTE are set by software only: a 0 written leaves them (37.7.2).
            self.regs[CR2] = (value | (old & (NACK | PECBYTE))) & ~(START | STOP)
            if value & START and self.regs.get(CR1, 0) & PE:
                self._master_start(value)
            elif value & STOP and self._job is not None:
                self._master_stop()
            elif field(value, 16, 8) != field(old, 16, 8):
                self.regs[ISR] = self.regs.get(ISR, 0) & ~(TCR | TC)
        else:
            self.store(offset, value)
        self._poke()
        self._update_irq()

    # The bus's pacing ------------------------------------------------------------------------------------------
    def _bit_cycles(self):
        return self.chip.core.hz // self.bus_hz

    def _after_bits(self, bits, then):
        self.chip.core.at(self.chip.core.cycles + bits * self._bit_cycles(), then)

    def _until(self, condition, then):
        """Stretch the clock until `condition()` holds, then go on."""
        self._wait, self._then = condition, then
        self._waiting_since = self.chip.core.cycles
        self._poke()

    def _poke(self):
        if self._wait is not None and self._wait():
            then, self._wait = self._then, None
            self._note_stretch()
            then()

    def _note_stretch(self):
        job = self._job
        if isinstance(job, Transaction):
            stretch = (self.chip.core.cycles - self._waiting_since) * 1e6 / self.chip.core.hz
            job.longest_stretch_us = max(job.longest_stretch_us, stretch)

    def _set(self, flags):
        self.regs[ISR] = self.regs.get(ISR, 0) | flags
        if flags & (ADDR | STOPF):
            # An address matched or a STOP clears NACK and PECBYTE (37.7.2).
            self.regs[CR2] = self.regs.get(CR2, 0) & ~(NACK | PECBYTE)
        self._update_irq()

    def _clear(self, flags):
        self.regs[ISR] = self.regs.get(ISR, 0) & ~flags
        self._update_irq()

    def _update_irq(self):
        cr1, isr = self.regs.get(CR1, 0), self.regs.get(ISR, 0)
        event = ((cr1 & ADDRIE and isr & ADDR) or (cr1 & STOPIE and isr & STOPF) or (cr1 & TCIE and isr & (TC | TCR))
                 or (cr1 & NACKIE and isr & NACKF) or (cr1 & TXIE and isr & TXIS) or (cr1 & RXIE and isr & RXNE))
        error = cr1 & ERRIE and isr & (BERR | ARLO | OVR)
        ev, er = IRQS[self.number]
        self.chip.irq(self, ev, bool(event))
        self.chip.irq(self, er, bool(error))
        # DMA requests follow the flags (37.4.16): TXIS with TXDMAEN, RXNE with RXDMAEN.
        if cr1 & TXDMAEN and isr & TXIS:
            self.chip.dma1.request(f"I2C{self.number}_TX")
        if cr1 & RXDMAEN and self.regs.get(ISR, 0) & RXNE:
            self.chip.dma1.request(f"I2C{self.number}_RX")

    # Slave: the modelled master's side -------------------------------------------------------------------------
    def _matches(self, address):
        oar1 = self.regs.get(OAR1, 0)
        cr1 = self.regs.get(CR1, 0)
        return bool(cr1 & PE and oar1 & (1 << 15) and field(oar1, 1, 7) == address)

    def master_transfer(self, address, data=b"", read_length=0, stretch_limit_us=25_000):
        """The modelled master starts a transfer to the image's slave address; returns the `Transaction`."""
        job = Transaction(address, data, read_length, stretch_limit_us)
        job.started = self.chip.core.cycles
        self._job = job
        self._watchdog(job)
        if data:
            self._after_bits(10, lambda: self._slave_address(job, read=False))
        else:
            self._after_bits(10, lambda: self._slave_address(job, read=True))
        return job

    def _watchdog(self, job):
        """The modelled master gives up on a clock held low longer than its limit (a real master's timeout)."""
        limit = int(job.stretch_limit_us * self.chip.core.hz / 1e6)

        def check():
            if job.done or self._job is not job:
                return
            if self._wait is not None and self.chip.core.cycles - self._waiting_since >= limit:
                self._finish(job, f"SCL held low over {job.stretch_limit_us} us")
                return
            self.chip.core.at(self.chip.core.cycles + limit // 4 + 1, check)

        self.chip.core.at(self.chip.core.cycles + limit // 4 + 1, check)

    def _finish(self, job, error=None):
        job.error = job.error or error
        job.done = True
        job.ended = self.chip.core.cycles
        self._wait = None
        if self._job is job:
            self._job = None

    def _slave_address(self, job, read):
        if not self._matches(job.address):
            self._finish(job, "address not acknowledged")
            return
        self.regs[ISR] = (self.regs.get(ISR, 0) & ~(DIR | (0x7F << 17))) | BUSY | (job.address << 17) | (
            DIR if read else 0)
        self._set(ADDR)
        self._until(lambda: not self.regs.get(ISR, 0) & ADDR,
                    (lambda: self._slave_send(job, 0)) if read else (lambda: self._slave_receive(job, 0)))

    def _slave_receive(self, job, index):
        if index == len(job.data):
            if job.read_length:
                self._after_bits(10, lambda: self._slave_address(job, read=True))
            else:
                self._after_bits(1, lambda: self._slave_stop(job))
            return

        def arrive():
            self._until(lambda: not self.regs.get(ISR, 0) & RXNE, deliver)

        def deliver():
            self.regs[RXDR] = job.data[index]
            self._set(RXNE)
            self._slave_receive(job, index + 1)

        self._after_bits(9, arrive)

    def _slave_send(self, job, index):
        def need():
            if self.regs.get(ISR, 0) & TXE:
                self._set(TXIS)
            self._until(lambda: not self.regs.get(ISR, 0) & TXE, shift)

        def shift():
            byte = self.regs.get(TXDR, 0)
            self.regs[ISR] = self.regs.get(ISR, 0) | TXE
            self._after_bits(9, lambda: sent(byte))

        def sent(byte):
            job.read.append(byte)
            if index + 1 < job.read_length:
                self._slave_send(job, index + 1)
            else:
                # The master NACKs its last byte, then STOP (37.4.9: NACKF, then STOPF).
                self._set(NACKF)
                self._after_bits(1, lambda: self._slave_stop(job))

        need()

    def _slave_stop(self, job):
        self._clear(BUSY | TXIS)
        self._set(STOPF)
        self._finish(job)

    # Master: the image's side, with modelled devices -----------------------------------------------------------
    def _master_bit_cycles(self):
        # t_SCL = (SCLL + 1 + SCLH + 1) x (PRESC + 1) / f_I2CCLK (37.4.10); the kernel clock is HSI16.
        timing = self.regs.get(TIMINGR, 0)
        presc, scll, sclh = field(timing, 28, 4), field(timing, 0, 8), field(timing, 8, 8)
        return max(1, (scll + 1 + sclh + 1) * (presc + 1) * self.chip.core.hz // 16_000_000)

    def _master_after_bits(self, bits, then):
        self.chip.core.at(self.chip.core.cycles + bits * self._master_bit_cycles(), then)

    def _master_start(self, cr2):
        address = field(cr2, 1, 7)
        read = bool(cr2 & RD_WRN)
        self._job = ("master", address, read)
        self._clear(TC | TCR | NACKF)
        self._set(BUSY)
        self.regs[ISR] = (self.regs.get(ISR, 0) & ~DIR) | (DIR if read else 0)
        record = [address, bytearray(), bytearray(), None, read]
        self.transfers.append(record)
        self._master_after_bits(10, lambda: self._master_addressed(address, read, record))

    def _master_addressed(self, address, read, record):
        device = self.devices.get(address)
        acked = device is not None and device.start(address, read)
        record[3] = acked
        if not acked:
            self._master_nack()
            return
        self._master_byte(read, 0, record)

    def _master_nack(self):
        # A NACK: NACKF, and the peripheral sends STOP itself (37.4.9).
        self._set(NACKF)
        self._master_after_bits(1, self._master_stopped)

    def _master_byte(self, read, index, record):
        count = field(self.regs.get(CR2, 0), 16, 8)
        if index == count:
            cr2 = self.regs.get(CR2, 0)
            if cr2 & RELOAD:
                self._set(TCR)
                self._until(lambda: not self.regs.get(ISR, 0) & TCR, lambda: self._master_byte(read, 0, record))
            elif cr2 & AUTOEND:
                self._master_after_bits(1, self._master_stopped)
            else:
                self._set(TC)  # software writes START (repeated) or STOP
            return
        if read:
            def deliver():
                byte = device.read() if device is not None else 0xFF
                record[2].append(byte)
                self.regs[RXDR] = byte
                self._set(RXNE)
                self._master_byte(read, index + 1, record)

            device = self.devices.get(record[0])
            self._master_after_bits(9, lambda: self._until(lambda: not self.regs.get(ISR, 0) & RXNE, deliver))
        else:
            def shift():
                byte = self.regs.get(TXDR, 0)
                self.regs[ISR] = self.regs.get(ISR, 0) | TXE
                self._master_after_bits(9, lambda: sent(byte))

            def sent(byte):
                record[1].append(byte)
                device = self.devices.get(record[0])
                if device is not None and device.write(byte):
                    self._master_byte(read, index + 1, record)
                else:
                    self._master_nack()

            self._set(TXIS)
            self._until(lambda: not self.regs.get(ISR, 0) & TXE, shift)

    def _master_stop(self):
        self._clear(TC)
        self._master_after_bits(1, self._master_stopped)

    def _master_stopped(self):
        record = self.transfers[-1] if self.transfers else None
        if record is not None:
            device = self.devices.get(record[0])
            if device is not None and hasattr(device, "stop"):
                device.stop()
        self._job = None
        self._wait = None
        self._clear(BUSY | TXIS)
        self._set(STOPF)
