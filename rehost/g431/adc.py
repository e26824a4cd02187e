"""ADC1 and the ADC12 common registers (RM0440 21): the start-up handshakes, and regular and injected sequences that
take the time RM0440 gives them, started by software or by the trigger outputs the timer models produce, each
channel's input taken at the end of its sampling phase."""

import math
from typing import NamedTuple

from .peripheral import Peripheral, field

ISR, IER, CR, CFGR, CFGR2, SMPR1, SMPR2 = 0x00, 0x04, 0x08, 0x0C, 0x10, 0x14, 0x18
SQR1, SQR2, SQR3, SQR4, DR, JSQR = 0x30, 0x34, 0x38, 0x3C, 0x40, 0x4C
OFR = (0x60, 0x64, 0x68, 0x6C)
JDR = (0x80, 0x84, 0x88, 0x8C)
CCR = 0x08  # ADC12_CCR, in the common block
ADRDY, EOSMP, EOC, EOS, OVR, JEOC, JEOS = 1 << 0, 1 << 1, 1 << 2, 1 << 3, 1 << 4, 1 << 5, 1 << 6
ADEN, ADDIS, ADSTART, JADSTART, ADSTP, JADSTP = 1 << 0, 1 << 1, 1 << 2, 1 << 3, 1 << 4, 1 << 5
ADVREGEN, DEEPPWD, ADCAL = 1 << 28, 1 << 29, 1 << 31
# CFGR (21.7.4)
DMAEN, OVRMOD, CONT, ALIGN, DISCEN, JDISCEN, JAUTO, JQDIS = 1 << 0, 1 << 12, 1 << 13, 1 << 15, 1 << 16, 1 << 20, \
    1 << 25, 1 << 31
# CFGR's fields by the start bits that must be clear to write them (21.7.4's notes): ADSTART = 0 for EXTSEL, EXTEN,
# OVRMOD, CONT, DISCEN, DISCNUM; JADSTART = 0 for JDISCEN, JQM, JAWD1EN; both for the rest.
CFGR_REGULAR = 0x1F << 5 | 3 << 10 | OVRMOD | CONT | DISCEN | 7 << 17
CFGR_INJECTED = JDISCEN | 1 << 21 | 1 << 24
# CR's bits software sets and only the ADC clears: a 0 written leaves them (RM0440 21.7.3, "rs").
SET_ONLY = ADCAL | JADSTP | ADSTP | JADSTART | ADSTART | ADDIS | ADEN
ADC1_2_IRQ = 18  # RM0440 Table 97

# Sampling times in ADC clock cycles, SMPx (21.7.6); SMPPLUS (SMPR1 bit 31) makes 2.5 cycles 3.5.
SAMPLE_CYCLES = (2.5, 6.5, 12.5, 24.5, 47.5, 92.5, 247.5, 640.5)
# The successive approximation, by CFGR.RES: 12, 10, 8, 6 bits (21.4.16: tCONV = tSMPL + tSAR).
SAR_CYCLES = (12.5, 10.5, 8.5, 6.5)
# ADC12_CCR.PRESC's dividers of the kernel clock (21.8.2).
PRESCALERS = (1, 2, 4, 6, 8, 10, 12, 16, 32, 64, 128, 256)

# "ADC1/ADC2 - External triggers for regular channels" (EXTSEL) and "... for injected channels" (JEXTSEL), RM0440
# 21.4.18, as stm32-data lists them for ADC1 (stm32-metapac 21, ADC_EXT_TRGn / ADC_JEXT_TRGn).
REGULAR_TRIGGERS = (
    "TIM1_CC1", "TIM1_CC2", "TIM1_CC3", "TIM2_CC2", "TIM3_TRGO", "TIM4_CC4", "EXTI11", "TIM8_TRGO", "TIM8_TRGO2",
    "TIM1_TRGO", "TIM1_TRGO2", "TIM2_TRGO", "TIM4_TRGO", "TIM6_TRGO", "TIM15_TRGO", "TIM3_CC4", "TIM20_TRGO",
    "TIM20_TRGO2", "TIM20_CC1", "TIM20_CC2", "TIM20_CC3", "HRTIM_ADC_TRG1", "HRTIM_ADC_TRG3", "HRTIM_ADC_TRG5",
    "HRTIM_ADC_TRG6", "HRTIM_ADC_TRG7", "HRTIM_ADC_TRG8", "HRTIM_ADC_TRG9", "HRTIM_ADC_TRG10", "LPTIMOUT",
    "TIM7_TRGO", "reserved")
INJECTED_TRIGGERS = (
    "TIM1_TRGO", "TIM1_CC4", "TIM2_TRGO", "TIM2_CC1", "TIM3_CC4", "TIM4_TRGO", "EXTI15", "TIM8_CC4", "TIM1_TRGO2",
    "TIM8_TRGO", "TIM8_TRGO2", "TIM3_CC3", "TIM3_TRGO", "TIM3_CC1", "TIM6_TRGO", "TIM15_TRGO", "TIM20_TRGO",
    "TIM20_TRGO2", "TIM20_CC4", "HRTIM_ADC_TRG2", "HRTIM_ADC_TRG4", "HRTIM_ADC_TRG5", "HRTIM_ADC_TRG6",
    "HRTIM_ADC_TRG7", "HRTIM_ADC_TRG8", "HRTIM_ADC_TRG9", "HRTIM_ADC_TRG10", "TIM16_CC1", "reserved", "LPTIMOUT",
    "TIM7_TRGO", "reserved")
# The trigger sources a model produces: TIM1's outputs (timers.Tim1.watch).
TIM1_OUTPUTS = {"TIM1_TRGO": "TRGO", "TIM1_TRGO2": "TRGO2", "TIM1_CC1": "CC1", "TIM1_CC2": "CC2", "TIM1_CC3": "CC3",
                "TIM1_CC4": "CC4"}


class Conversion(NamedTuple):
    cycle: int  # the end of the sampling phase: the instant the input was taken
    channel: int
    smp: int  # SMPRx's field for the channel
    group: str  # "regular" or "injected"
    rank: int  # its place in the sequence, from 0
    start: int  # the cycle its sampling began
    end: int  # the cycle it ended (EOC or JEOC)
    value: int


class Sequence:
    def __init__(self, group, channels):
        self.group = group
        self.channels = channels
        self.rank = 0
        self.start = None  # the current conversion's first cycle; None while held (pre-empted)
        self.token = None


class Adc(Peripheral):
    """One ADC (RM0440 21.4): regular sequences (SQR1-SQR4, L) and injected ones (JSQR, JL), started by software
    (ADSTART, JADSTART with EXTEN, JEXTEN = 00) or by a trigger edge (21.4.18). A conversion takes SMPx + 12.5 ADC
    clock cycles (21.4.16) and holds the input as it was at the end of its SMPx sampling cycles; the next rank
    follows at once. An injected trigger during a regular conversion aborts it; the regular sequence resumes at
    that rank after the injected one (21.4.19). Write rules RM0440 gives are checked: a firmware breaking one stops
    the run. `inputs[channel]` is a 12-bit value, or a function of the time in seconds.
    """

    resets = {CR: DEEPPWD, CFGR: JQDIS}  # 21.7.3, 21.7.4
    read_only = {DR: 0xFFFF_FFFF, **{offset: 0xFFFF_FFFF for offset in JDR}}

    def __init__(self, chip, name, base):
        super().__init__(chip, name, base)
        self.inputs = {}  # channel -> 12-bit value, or a function of the time in seconds
        self.conversions = []  # a Conversion for each that ended
        self.ignored_triggers = []  # (cycle, group) of trigger edges that came while the group was converting
        self.stuck = False  # a test sets True: conversions never end (EOC never set)
        self._clear_state()

    def _clear_state(self):
        self._regular = None  # the Sequence converting (or held by an injected one)
        self._injected = None
        self._regular_waiting = False  # a regular start that came during an injected sequence
        self._ready = False  # ADEN set and the ADC ready (ADRDY's event; the flag itself software may clear)
        self._token = 0

    def reset(self):
        super().reset()
        self.conversions = []
        self.ignored_triggers = []
        self._clear_state()

    # Configuration -------------------------------------------------------------------------------------------
    def sample_time(self, channel):
        """SMPRx's field for a channel (SMPR1: channels 0-9, SMPR2: 10-18)."""
        register = SMPR1 if channel < 10 else SMPR2
        return field(self.regs.get(register, 0), 3 * (channel % 10), 3)

    def clock_hz(self):
        """The ADC clock (21.4.3, ADC12_CCR 21.8.2): CKMODE = 00, the kernel clock RCC_CCIPR.ADC12SEL picks
        through PRESC; 01, 10, 11: HCLK / 1, 2, 4. 0 when there is none."""
        ccr = self.chip.adc_common.regs.get(CCR, 0)
        ckmode, presc = field(ccr, 16, 2), field(ccr, 18, 4)
        if ckmode:
            return self.chip.rcc.hclk_hz() / (1, 2, 4)[ckmode - 1]
        if presc >= len(PRESCALERS):
            return 0
        return self.chip.rcc.adc12_kernel_hz() / PRESCALERS[presc]

    def _cycles(self, adc_cycles):
        """ADC clock cycles as core cycles, rounded up."""
        return math.ceil(adc_cycles * self.chip.core.hz / self.clock_hz() - 1e-9)

    def _regular_channels(self):
        sqr = [self.regs.get(offset, 0) for offset in (SQR1, SQR2, SQR3, SQR4)]
        # SQ1-SQ4 at SQR1 bits 6, 12, 18, 24; SQ5-SQ9, SQ10-SQ14, SQ15-SQ16 from bit 0 of SQR2-SQR4 (21.7.11-14).
        slots = [(0, 6 * n) for n in range(1, 5)] + [(r, 6 * n) for r in (1, 2) for n in range(5)] + [(3, 0), (3, 6)]
        return [field(sqr[r], shift, 5) for r, shift in slots[:field(sqr[0], 0, 4) + 1]]

    def _injected_channels(self):
        jsqr = self.regs.get(JSQR, 0)
        return [field(jsqr, shift, 5) for shift in (9, 15, 21, 27)[:field(jsqr, 0, 2) + 1]]  # 21.7.16

    def _unmodelled(self, group):
        """What a start would need that the model does not do, or None."""
        cfgr, cfgr2 = self.regs.get(CFGR, 0), self.regs.get(CFGR2, 0)
        found = [name for name, set_ in (
            ("continuous mode (CONT)", group == "regular" and cfgr & CONT),
            ("DMA (DMAEN)", group == "regular" and cfgr & DMAEN),
            ("discontinuous mode (DISCEN)", group == "regular" and cfgr & DISCEN),
            ("injected discontinuous mode (JDISCEN)", group == "injected" and cfgr & JDISCEN),
            ("auto-injection (JAUTO)", cfgr & JAUTO),
            ("left alignment (ALIGN)", cfgr & ALIGN),
            ("oversampling (CFGR2 ROVSE, JOVSE)", cfgr2 & 3),
            ("offsets (OFRy.OFFSET_EN)", any(self.regs.get(offset, 0) >> 31 for offset in OFR))) if set_]
        if not self.clock_hz():
            found.append("a clock (RCC_CCIPR.ADC12SEL and ADC12_CCR give none)")
        return ", ".join(found) or None

    # Registers ----------------------------------------------------------------------------------------------------
    def write(self, offset, value):
        self.writes.add(offset)
        cr = self.regs.get(CR, 0)
        fail = self.chip.core.fail
        if offset == ISR:
            self.regs[ISR] = self.regs.get(ISR, 0) & ~value  # rc_w1
            self._update_irq()
            return
        if offset == CR:
            self._write_cr(value)
            return
        if offset in (SMPR1, SMPR2) and cr & (ADSTART | JADSTART):
            fail(f"{self.name}: SMPR{1 if offset == SMPR1 else 2} written with ADSTART or JADSTART set "
                 f"(RM0440 21.7.6)")
        if offset in (SQR1, SQR2, SQR3, SQR4) and cr & ADSTART:
            fail(f"{self.name}: SQR{(offset - SQR1) // 4 + 1} written with ADSTART set (RM0440 21.7.11)")
        if offset == JSQR:
            if not self.regs.get(CFGR, 0) & JQDIS:
                fail(f"{self.name}: JSQR written with the injected queue enabled (CFGR.JQDIS = 0): not modelled")
            elif cr & JADSTART:
                fail(f"{self.name}: JSQR written with JADSTART set and the queue disabled (RM0440 21.7.16, 21.4.21)")
        if offset == CFGR:
            changed = self.regs.get(CFGR, 0) ^ value
            both = ~(CFGR_REGULAR | CFGR_INJECTED)
            if (changed & (CFGR_REGULAR | both) and cr & ADSTART) or (changed & (CFGR_INJECTED | both)
                                                                          and cr & JADSTART):
                fail(f"{self.name}: CFGR bits {changed:#x} changed with ADSTART or JADSTART set (RM0440 21.7.4)")
            if changed & JQDIS:
                self.regs[JSQR] = 0  # "A set or reset of JQDIS bit causes ... the JSQR register is cleared"
        self.store(offset, value)
        if offset == IER:
            self._update_irq()

    def _write_cr(self, value):
        fail = self.chip.core.fail
        old = self.regs.get(CR, 0)
        value |= old & SET_ONLY
        new = value & ~old
        if value & ADCAL:
            if old & ADEN:
                fail(f"{self.name}: ADCAL with ADEN set (RM0440 21.7.3)")
            value &= ~ADCAL  # calibration done at once
        if new & ADEN:
            self._ready = True
            self.regs[ISR] = self.regs.get(ISR, 0) | ADRDY
        if value & ADSTP:
            value &= ~(ADSTP | ADSTART)  # stopped at once
            self._stop_regular()
        if value & JADSTP:
            value &= ~(JADSTP | JADSTART)
            self._stop_injected()
        if new & ADDIS:
            if old & (ADSTART | JADSTART):
                fail(f"{self.name}: ADDIS with ADSTART or JADSTART set (RM0440 21.7.3)")
            value &= ~(ADDIS | ADEN)
            self._ready = False
        self.regs[CR] = value
        for bit_, group in ((ADSTART, "regular"), (JADSTART, "injected")):
            if not new & bit_:
                continue
            if not value & ADEN or value & ADDIS or not self._ready:
                fail(f"{self.name}: {'ADSTART' if group == 'regular' else 'JADSTART'} with the ADC not enabled "
                     f"and ready (ADEN = 1, ADRDY, ADDIS = 0; RM0440 21.7.3)")
                continue
            missing = self._unmodelled(group)
            if missing:
                fail(f"{self.name}: a {group} start with {missing}: not modelled")
                continue
            self._arm(group)
        self._update_irq()

    def read(self, offset):
        value = super().read(offset)
        if offset == DR:
            self.chip.core.changing_read = True  # the read clears EOC
            self.regs[ISR] = self.regs.get(ISR, 0) & ~EOC
            self._update_irq()
        return value

    def _update_irq(self):
        level = bool(self.regs.get(ISR, 0) & self.regs.get(IER, 0) & 0x7FF)
        self.chip.irq(self, ADC1_2_IRQ, level)

    # Triggers -----------------------------------------------------------------------------------------------------
    def _edges(self, group):
        """EXTEN or JEXTEN: 0 software, 1 rising, 2 falling, 3 both (21.4.18)."""
        return field(self.regs.get(CFGR, 0), 10, 2) if group == "regular" else field(self.regs.get(JSQR, 0), 7, 2)

    def _arm(self, group):
        """ADSTART / JADSTART: a software start converts now; with a hardware trigger it waits for its edges."""
        if not self._edges(group):
            self._trigger(group)
            return
        if group == "regular":
            selection, source = field(self.regs.get(CFGR, 0), 5, 5), REGULAR_TRIGGERS
        else:
            selection, source = field(self.regs.get(JSQR, 0), 2, 5), INJECTED_TRIGGERS
        trigger = source[selection]
        if trigger not in TIM1_OUTPUTS:
            kind = "EXTSEL" if group == "regular" else "JEXTSEL"
            self.chip.core.fail(f"{self.name}: {kind} {selection} ({trigger}) armed: no model produces that trigger")
            return
        self.chip.tim1.watch((self.name, group), TIM1_OUTPUTS[trigger], lambda rising: self._edge(group, rising))

    def _edge(self, group, rising):
        armed = self.regs.get(CR, 0) & (ADSTART if group == "regular" else JADSTART)
        if armed and self._edges(group) & (1 if rising else 2):
            self._trigger(group)

    def _trigger(self, group):
        now = self.chip.core.now()
        if group == "injected":
            if self._injected is not None:
                self.ignored_triggers.append((now, group))  # "a new trigger during a conversion is ignored"
                return
            if self._regular is not None and self._regular.start is not None:
                # The regular conversion is aborted; its rank converts again after the injected sequence (21.4.19).
                self._regular.start = None
                self._regular.token = None
            self._injected = Sequence(group, self._injected_channels())
            self._begin(self._injected, now)
            return
        if self._regular is not None:
            self.ignored_triggers.append((now, group))
        elif self._injected is not None:
            self._regular_waiting = True
        else:
            self._regular = Sequence(group, self._regular_channels())
            self._begin(self._regular, now)

    def _stop_regular(self):
        self.chip.tim1.unwatch((self.name, "regular"))
        self._regular = None
        self._regular_waiting = False

    def _stop_injected(self):
        self.chip.tim1.unwatch((self.name, "injected"))
        if self._injected is not None:
            self._injected = None
            self._resume_regular()

    # Conversions --------------------------------------------------------------------------------------------------
    def _begin(self, sequence, start):
        channel = sequence.channels[sequence.rank]
        smp = self.sample_time(channel)
        sampling = SAMPLE_CYCLES[smp]
        if smp == 0 and self.regs.get(SMPR1, 0) >> 31:
            sampling = 3.5  # SMPPLUS
        resolution = field(self.regs.get(CFGR, 0), 3, 2)
        sampled = start + self._cycles(sampling)
        end = start + self._cycles(sampling + SAR_CYCLES[resolution])
        self._token += 1
        token = self._token
        sequence.start, sequence.token = start, token
        if not self.stuck:
            self.chip.core.at(end, lambda: self._end(sequence, token, channel, smp, sampled, end))

    def _sample(self, channel, cycle):
        source = self.inputs.get(channel, 0)
        value = source(cycle / self.chip.core.hz) if callable(source) else source
        resolution = field(self.regs.get(CFGR, 0), 3, 2)
        return min(max(int(value), 0), 0xFFF) >> (2 * resolution)  # right-aligned (21.4.26)

    def _end(self, sequence, token, channel, smp, sampled, end):
        if sequence.token != token or sequence not in (self._regular, self._injected):
            return  # aborted or stopped
        value = self._sample(channel, sampled)
        self.conversions.append(Conversion(sampled, channel, smp, sequence.group, sequence.rank, sequence.start,
                                           end, value))
        isr = self.regs.get(ISR, 0)
        last = sequence.rank == len(sequence.channels) - 1
        if sequence.group == "regular":
            if isr & EOC:
                isr |= OVR  # overrun: EOC still set (21.4.27); DR keeps the old data unless OVRMOD
                if self.regs.get(CFGR, 0) & OVRMOD:
                    self.regs[DR] = value
            else:
                self.regs[DR] = value
            isr |= EOC | (EOS if last else 0)
        else:
            self.regs[JDR[sequence.rank]] = value
            isr |= JEOC | (JEOS if last else 0)
        self.regs[ISR] = isr
        if not last:
            sequence.rank += 1
            self._begin(sequence, end)
        elif sequence.group == "regular":
            self._regular = None
            if not self._edges("regular"):
                self.regs[CR] = self.regs.get(CR, 0) & ~ADSTART  # single mode, software start: cleared at EOS
        else:
            self._injected = None
            if not self._edges("injected"):
                self.regs[CR] = self.regs.get(CR, 0) & ~JADSTART  # software start: cleared at JEOS
            self._resume_regular()
        self._update_irq()

    def _resume_regular(self):
        now = self.chip.core.now()
        if self._regular is not None and self._regular.start is None:
            self._begin(self._regular, now)
        elif self._regular is None and self._regular_waiting:
            self._regular_waiting = False
            self._regular = Sequence("regular", self._regular_channels())
            self._begin(self._regular, now)


class AdcCommon(Peripheral):
    """ADC12_CSR, ADC12_CCR, ADC12_CDR (21.8): registers that hold what is written; CCR's CKMODE and PRESC set the
    ADC clock (`Adc.clock_hz`)."""
