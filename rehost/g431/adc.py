"""ADC1 and the ADC12 common registers (RM0440 21.7, 21.8): the start-up handshakes embassy-stm32 waits on, and
single regular conversions that return what a test puts on each channel."""

from .peripheral import Peripheral, field

ISR, IER, CR, CFGR, CFGR2, SMPR1, SMPR2, SQR1, DR = 0x00, 0x04, 0x08, 0x0C, 0x10, 0x14, 0x18, 0x30, 0x40
ADRDY, EOC, EOS = 1 << 0, 1 << 2, 1 << 3
ADEN, ADDIS, ADSTART, JADSTART, ADSTP, JADSTP = 1 << 0, 1 << 1, 1 << 2, 1 << 3, 1 << 4, 1 << 5
ADVREGEN, DEEPPWD, ADCAL = 1 << 28, 1 << 29, 1 << 31
JQDIS = 1 << 31  # CFGR
# CR's bits software sets and only the ADC clears: a 0 written leaves them (RM0440 21.7.3, "rs").
SET_ONLY = ADCAL | JADSTP | ADSTP | JADSTART | ADSTART | ADDIS | ADEN


class Adc(Peripheral):
    resets = {CR: DEEPPWD, CFGR: JQDIS}  # 21.7.3, 21.7.4
    read_only = {DR: 0xFFFF_FFFF}

    def __init__(self, chip, name, base):
        super().__init__(chip, name, base)
        self.inputs = {}  # channel -> 12-bit value, or a function of the time in seconds
        self.conversions = []  # (cycle, channel, sample time bits) of each conversion
        self.stuck = False  # a test sets True: conversions never end (EOC never set)

    def reset(self):
        super().reset()
        self.conversions = []

    def sample_time(self, channel):
        """SMPRx's field for a channel (SMPR1: channels 0-9, SMPR2: 10-18)."""
        register = SMPR1 if channel < 10 else SMPR2
        return field(self.regs.get(register, 0), 3 * (channel % 10), 3)

    def write(self, offset, value):
        self.writes.add(offset)
        if offset == ISR:
            self.regs[ISR] = self.regs.get(ISR, 0) & ~value  # rc_w1
            return
        if offset != CR:
            self.store(offset, value)
            return
        value |= self.regs.get(CR, 0) & SET_ONLY
        if value & ADSTP:
            value &= ~(ADSTP | ADSTART)  # stopped at once
        if value & JADSTP:
            value &= ~(JADSTP | JADSTART)
        if value & ADCAL:
            value &= ~ADCAL  # calibration done at once
        if value & ADEN:
            self.regs[ISR] = self.regs.get(ISR, 0) | ADRDY
        if value & ADDIS:
            value &= ~(ADDIS | ADEN)
        if value & ADSTART:
            if not value & ADEN:
                self.chip.core.fail(f"{self.name}: ADSTART with the ADC disabled")
            channel = field(self.regs.get(SQR1, 0), 6, 5)
            if self.stuck:
                self.regs[CR] = value
                return
            self.conversions.append((self.chip.core.cycles, channel, self.sample_time(channel)))
            source = self.inputs.get(channel, 0)
            sample = source(self.chip.core.seconds) if callable(source) else source
            self.regs[DR] = int(sample) & 0xFFF
            self.regs[ISR] = self.regs.get(ISR, 0) | EOC | EOS
            value &= ~ADSTART
        self.regs[CR] = value

    def read(self, offset):
        value = super().read(offset)
        if offset == DR:
            self.chip.core.changing_read = True  # the read clears EOC
            self.regs[ISR] = self.regs.get(ISR, 0) & ~EOC
        return value


class AdcCommon(Peripheral):
    pass
