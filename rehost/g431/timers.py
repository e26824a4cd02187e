"""TIM15 as embassy-stm32's time driver uses it, and TIM1 as the thruster's bridge does (RM0440 29, 30, 28)."""

from .peripheral import Peripheral, bit, field

CR1, CR2, SMCR, DIER, SR, EGR, CCMR1, CCMR2, CCER, CNT, PSC, ARR, RCR, CCR1, CCR2, CCR3, CCR4, BDTR = (
    0x00, 0x04, 0x08, 0x0C, 0x10, 0x14, 0x18, 0x1C, 0x20, 0x24, 0x28, 0x2C, 0x30, 0x34, 0x38, 0x3C, 0x40, 0x44)
AF1, AF2 = 0x60, 0x64

UIF, CC1IF, CC2IF, COMIF, BIF, B2IF, SBIF = 1 << 0, 1 << 1, 1 << 2, 1 << 5, 1 << 7, 1 << 8, 1 << 13
UG, COMG = 1 << 0, 1 << 5
MOE, AOE, BKE, BKP, OSSR, OSSI = 1 << 15, 1 << 14, 1 << 12, 1 << 13, 1 << 11, 1 << 10

# TIM1's channel outputs on the G431's pins in AF6 (DS12589 Table 13): (port, pin) -> (channel 0-2, complementary).
TIM1_PINS = {("A", 8): (0, False), ("A", 7): (0, True), ("A", 9): (1, False), ("B", 0): (1, True),
             ("A", 10): (2, False), ("B", 1): (2, True)}
TIM1_AF = 6

# RM0440 Table 97: TIM1's break and TIM15 share one vector.
TIM1_BRK_TIM15_IRQ = 24


class Tim15(Peripheral):
    """An up-counting timer whose counter follows the core clock: CNT = ticks since start mod (ARR + 1), with the
    update event at each wrap and the compare flags CCxIF when CNT passes CCRx (RM0440 30.4.3, 30.4.9)."""

    resets = {ARR: 0xFFFF}

    def __init__(self, chip, name, base):
        super().__init__(chip, name, base)
        self._origin = 0  # the cycle at which the counter held `_count0`
        self._count0 = 0
        self._psc = 0  # the prescaler in effect (PSC is preloaded: it takes effect at the update event)
        self._generation = 0

    def reset(self):
        super().reset()
        self._origin, self._count0, self._psc = 0, 0, 0
        self._generation += 1

    def _running(self):
        return bit(self.regs.get(CR1, 0), 0)

    def _ticks(self):
        return (self.chip.core.cycles - self._origin) // (self._psc + 1)

    def counter(self):
        if not self._running():
            return self._count0
        return (self._count0 + self._ticks()) % (self.regs.get(ARR, 0xFFFF) + 1)

    def _restart(self, count):
        self._count0 = count
        self._origin = self.chip.core.cycles
        self._schedule()

    def read(self, offset):
        if offset == CNT:
            self.chip.core.changing_read = True  # counts with time
            return self.counter()
        return super().read(offset)

    def write(self, offset, value):
        self.writes.add(offset)
        if offset == CNT:
            self._restart(value & 0xFFFF)
        elif offset == CR1:
            running = self._running()
            count = self.counter()
            self.regs[CR1] = value
            if running != bool(value & 1):
                self._restart(count)
        elif offset == SR:
            self.regs[SR] = self.regs.get(SR, 0) & value  # rc_w0
            self._update_irq()
        elif offset == EGR:
            if value & UG:
                self._psc = self.regs.get(PSC, 0)
                urs = bit(self.regs.get(CR1, 0), 2)
                if not urs:
                    self.regs[SR] = self.regs.get(SR, 0) | UIF
                self._restart(0)
                self._update_irq()
        else:
            self.regs[offset] = value
            if offset in (DIER, CCR1, CCR2, ARR):
                self._schedule()
                self._update_irq()

    def _schedule(self):
        """The next wrap or compare match, as a core-clock event."""
        self._generation += 1
        if not self._running():
            return
        generation = self._generation
        top = self.regs.get(ARR, 0xFFFF) + 1
        count = self.counter()
        targets = [0, self.regs.get(CCR1, 0) % top, self.regs.get(CCR2, 0) % top]
        ahead = min((t - count - 1) % top + 1 for t in targets)
        due_tick = self._ticks() + ahead
        due = self._origin + due_tick * (self._psc + 1)
        value = (self._count0 + due_tick) % top
        self.chip.core.at(due, lambda: self._event(generation, due, value))

    def _event(self, generation, due, count):
        if generation != self._generation:
            return
        flags = 0
        if count == self.regs.get(CCR1, 0):
            flags |= CC1IF
        if count == self.regs.get(CCR2, 0):
            flags |= CC2IF
        if count == 0:
            flags |= UIF
            self._psc = self.regs.get(PSC, 0)
            self._count0, self._origin = 0, due
        self.regs[SR] = self.regs.get(SR, 0) | flags
        self._schedule()
        self._update_irq()

    def _update_irq(self):
        level = bool(self.regs.get(SR, 0) & self.regs.get(DIER, 0) & (UIF | CC1IF | CC2IF))
        self.chip.irq(self, TIM1_BRK_TIM15_IRQ, level)


class Tim1(Peripheral):
    """The advanced timer driving the bridge: the registers software writes, the output state the bridge sees.

    With CR2.CCPC set, CCxE/CCxNE and OCxM are preloaded and reach the outputs at a COM event (EGR.COMG), RM0440
    28.3.20 "6-step PWM generation"; `active` holds what the outputs use. The break input (BKIN, active per
    BDTR.BKP) clears MOE and sets BIF (28.3.19); with AOE set, MOE is set again at the next update event once the
    break input is inactive. The counter itself is not modelled: update events come every half PWM period in
    centre-aligned mode (CMS != 0, RCR = 0), and are computed only while a break or AOE needs them.
    """

    resets = {ARR: 0xFFFF}

    def __init__(self, chip, name, base):
        super().__init__(chip, name, base)
        self.active = {CCMR1: 0, CCMR2: 0, CCER: 0}
        self.break_input_low = False
        self.breaks = 0
        self.system_breaks = 0
        self.com_events = 0
        self.com_log = []  # (cycle, CCMR1, CCMR2, CCER) after each COM event
        self.off_writes = []  # the instruction count at each BDTR write that turned the outputs off for good

    def reset(self):
        super().reset()
        self.active = {CCMR1: 0, CCMR2: 0, CCER: 0}
        self.com_events = 0
        self.com_log = []
        self.off_writes = []
        self.system_breaks = 0

    def moe(self):
        return bool(self.regs.get(BDTR, 0) & MOE)

    def _preloaded(self):
        return bit(self.regs.get(CR2, 0), 0)

    def write(self, offset, value):
        self.writes.add(offset)
        if offset == SR:
            self.regs[SR] = self.regs.get(SR, 0) & value  # rc_w0
            # A flag cannot be cleared while its break source is active (RM0440 28.6.5).
            if self._input_break_active():
                self.regs[SR] |= BIF
            if self.system_breaks:
                self.regs[SR] |= SBIF
            self._update_irq()
            return
        if offset == EGR:
            if value & COMG:
                self._commutate()
            if value & UG:
                self._update_event()
            return
        if offset == BDTR:
            if self.system_breaks or (self._input_break_active() and value & BKE):
                value &= ~MOE  # a break holds MOE clear while its source is active
            if not value & (MOE | AOE):
                self.off_writes.append(self.chip.core.instructions)  # outputs off, and they stay off
            self.regs[BDTR] = value
            self._await_update()
            return
        self.regs[offset] = value
        if offset == CR1:
            self._await_update()
        if offset in (CCMR1, CCMR2, CCER) and not self._preloaded():
            self.active[offset] = value

    def _commutate(self):
        self.com_events += 1
        for offset in (CCMR1, CCMR2, CCER):
            self.active[offset] = self.regs.get(offset, 0)
        self.com_log.append((self.chip.core.cycles, self.active[CCMR1], self.active[CCMR2], self.active[CCER]))
        self.regs[SR] = self.regs.get(SR, 0) | COMIF

    def _input_break_active(self):
        bdtr = self.regs.get(BDTR, 0)
        active_high = bool(bdtr & BKP)
        return bool(bdtr & BKE) and (self.break_input_low != active_high)

    def _break_active(self):
        return self.system_breaks > 0 or self._input_break_active()

    def system_break(self):
        """A system break source (the core's LOCKUP through SYSCFG_CFGR2.CLL): MOE clears and SBIF sets at once, and
        the source stays active, so AOE brings nothing back (RM0440 28.3.19)."""
        self.system_breaks += 1
        self.regs[BDTR] = self.regs.get(BDTR, 0) & ~MOE
        self.regs[SR] = self.regs.get(SR, 0) | SBIF
        self._update_irq()

    def set_break_input(self, low):
        """The overcurrent comparator pulls BKIN low (or lets it go)."""
        self.break_input_low = low
        if self._input_break_active():
            self.breaks += 1
            self.regs[BDTR] = self.regs.get(BDTR, 0) & ~MOE
            self.regs[SR] = self.regs.get(SR, 0) | BIF
            self._update_irq()
        else:
            # Automatic output enable: MOE comes back at the next update event.
            self._await_update()

    def _half_period(self):
        return (self.regs.get(ARR, 0) + 1) * (self.regs.get(PSC, 0) + 1)

    def _await_update(self):
        """With AOE set and MOE clear, the next update event sets MOE (RM0440 28.3.19); it comes within half a
        PWM period of a running centre-aligned counter."""
        bdtr = self.regs.get(BDTR, 0)
        if bdtr & AOE and not bdtr & MOE and bit(self.regs.get(CR1, 0), 0):
            self.chip.core.at(self.chip.core.cycles + self._half_period(), self._update_event)

    def _update_event(self):
        bdtr = self.regs.get(BDTR, 0)
        if bdtr & AOE and not self._break_active():
            self.regs[BDTR] = bdtr | MOE

    def _update_irq(self):
        # BIE (DIER bit 7) enables BIF, B2IF and SBIF alike (RM0440 28.6.4).
        dier, sr = self.regs.get(DIER, 0), self.regs.get(SR, 0)
        level = bool(dier & (1 << 7) and sr & (BIF | B2IF | SBIF))
        self.chip.irq(self, TIM1_BRK_TIM15_IRQ, level)

    def _reference(self, channel):
        """OCxREF of channel 0-2 from its output compare mode (RM0440 28.6.7, OCxM's four bits): 0 or 1 when it
        holds still, "pwm" when it switches within the period. The counter is not modelled, so a PWM mode is
        "pwm" unless its compare value keeps it at one level all period (CCR 0, or above ARR)."""
        ccmr = self.active[CCMR1 if channel < 2 else CCMR2]
        shift = 0 if channel != 1 else 8
        mode = field(ccmr, 4 + shift, 3) | bit(ccmr, 16 + shift) << 3
        ccr = self.regs.get((CCR1, CCR2, CCR3)[channel], 0)
        if mode == 0b0100:
            return 0
        if mode == 0b0101:
            return 1
        if mode in (0b0110, 0b0111):
            if ccr == 0 or ccr > self.regs.get(ARR, 0):
                level = 0 if ccr == 0 else 1
                return level if mode == 0b0110 else 1 - level
            return "pwm"
        return 0 if mode == 0 else "pwm"  # frozen holds the reset level; the other modes toggle

    def pin_output(self, channel, complementary):
        """What TIM1 puts on OCx (or OCxN) of channel 0-2: 0, 1, "pwm", or None when it does not drive the pin
        (Hi-Z), by RM0440 28.6.11's table of MOE, OSSI, OSSR, CCxE, CCxNE, the polarities CCxP / CCxNP and the idle
        levels OISx / OISxN (CR2). Read as: with MOE clear and OSSI set, a channel with either output enabled sits
        at its idle levels (the dead time before them is not modelled); with neither enabled it is Hi-Z."""
        ccer, bdtr, cr2 = self.active[CCER], self.regs.get(BDTR, 0), self.regs.get(CR2, 0)
        enabled = (bit(ccer, 4 * channel), bit(ccer, 4 * channel + 2))
        polarity = bit(ccer, 4 * channel + (3 if complementary else 1))
        mine = enabled[1] if complementary else enabled[0]
        if not bdtr & MOE:
            if not bdtr & OSSI or not any(enabled):
                return None
            return bit(cr2, 8 + 2 * channel + (1 if complementary else 0))
        if not mine:
            # Off-state with OSSR: enabled at its inactive level; else not driven.
            return polarity if bdtr & OSSR else None
        reference = self._reference(channel)
        if reference == "pwm":
            return "pwm"
        if complementary and enabled[0]:
            reference = 1 - reference  # the complementary output of a pair is OCxREF inverted (then dead time)
        return reference ^ polarity

    def outputs(self):
        """What each phase's two switches do: per channel 1-3, (high enabled, low enabled, mode)."""
        ccer = self.active[CCER]
        modes = (field(self.active[CCMR1], 4, 3) | bit(self.active[CCMR1], 16) << 3,
                 field(self.active[CCMR1], 12, 3) | bit(self.active[CCMR1], 24) << 3,
                 field(self.active[CCMR2], 4, 3) | bit(self.active[CCMR2], 16) << 3)
        return [(bit(ccer, 4 * n), bit(ccer, 4 * n + 2), modes[n]) for n in range(3)]
