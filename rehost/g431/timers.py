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
    """An up-counting timer: CNT = ticks since start mod (ARR + 1), a tick every PSC + 1 clocks of APB2's timer
    clock (`Rcc.timer_hz(2)`), with the update event at each wrap and the compare flags CCxIF when CNT passes CCRx
    (RM0440 30.4.3, 30.4.9). When RCC_CFGR changes that clock the count is kept and counting goes on at the new
    rate; the part of a tick the prescaler held then is dropped."""

    resets = {ARR: 0xFFFF}

    def __init__(self, chip, name, base):
        super().__init__(chip, name, base)
        self._origin = 0  # the cycle at which the counter held `_count0`
        self._count0 = 0
        self._psc = 0  # the prescaler in effect (PSC is preloaded: it takes effect at the update event)
        self._generation = 0
        self._held = 0  # the count when RCC_CFGR last changed the timer clock

    def reset(self):
        super().reset()
        self._origin, self._count0, self._psc = 0, 0, 0
        self._generation += 1

    def _running(self):
        return bit(self.regs.get(CR1, 0), 0)

    def _hz(self):
        return self.chip.rcc.timer_hz(2)  # TIM15 is on APB2 (RM0440 Table 4)

    def _ticks(self):
        clocks = (self.chip.core.cycles - self._origin) * self._hz() // self.chip.core.hz
        return clocks // (self._psc + 1)

    def clock_changing(self):
        """RCC_CFGR is about to change the timer clock: the count so far, at the old rate."""
        self._held = self.counter()

    def clock_changed(self):
        self._restart(self._held)

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
        due = self._origin - (-due_tick * (self._psc + 1) * self.chip.core.hz // self._hz())  # the first cycle there
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
    break input is inactive. For AOE, update events come every half PWM period in centre-aligned mode (CMS != 0,
    RCR = 0), and are computed only while a break or AOE needs them.

    The counter (RM0440 28.3.2 time-base unit, 28.3.3 counter modes, 28.3.4 repetition counter) is kept as
    arithmetic on the core's clock, one tick per PSC + 1 cycles: up 0..ARR, down ARR..0, or centre-aligned (CMS !=
    0) up 0..ARR-1 then down ARR..1, an under- or overflow every ARR ticks, an update event every RCR + 1 of them.
    PSC, RCR, ARR with ARPE and CCRx with OCxPE are preloaded: software writes the preload register, the counter
    uses the shadow taken at the next update event (or at UG). What it drives, TRGO (CR2.MMS) and TRGO2 (CR2.MMS2,
    RM0440 28.6.2) and the compare events, reaches those that `watch` it (ADC1's triggers), and is computed only
    while one does: edges as core events at the instants the signal changes. Nothing is produced while CEN = 0.

    Debug mode (RM0440 28.3, "Debug mode"; DBGMCU_APB2FZR.DBG_TIM1_STOP, 47.16): while the core is halted with
    DBG_TIM1_STOP set (`debug_freeze`), the counter stops and the outputs are disabled as if MOE were reset (to the
    idle levels with OSSI = 1, else not driven); MOE itself keeps its value, and at the resume the counter goes on
    from where it stopped and the outputs drive again.
    """

    resets = {ARR: 0xFFFF}

    def __init__(self, chip, name, base):
        super().__init__(chip, name, base)
        self.active = {CCMR1: 0, CCMR2: 0, CCER: 0}
        self.break_input_low = False
        self.breaks = 0
        self.system_breaks = 0  # how many system break events there have been
        self._system_sources = set()  # the system break sources active now ("lockup", "ecc")
        self.com_events = 0
        self.com_log = []  # (cycle, CCMR1, CCMR2, CCER) after each COM event
        self.off_writes = []  # the instruction count at each BDTR write that turned the outputs off for good
        self._counter_reset()

    def reset(self):
        super().reset()
        self.active = {CCMR1: 0, CCMR2: 0, CCER: 0}
        self.com_events = 0
        self.com_log = []
        self.off_writes = []
        self.system_breaks = 0
        self._system_sources = set()
        self._counter_reset()

    def _counter_reset(self):
        self._shadow = {PSC: 0, ARR: 0xFFFF, RCR: 0, CCR1: 0, CCR2: 0, CCR3: 0, CCR4: 0}
        self._pending = {}  # preloaded writes waiting for the next update event
        self._pending_since = 0
        # While CEN is set: (origin, cycles per tick, ARR, mode, k0): at `origin` the counter was at the start of
        # segment 0 (0 counting up; ARR counting down in down mode), each segment is one count between under- and
        # overflows, and segment k's start is an update event when (k - k0) is a multiple of RCR + 1.
        self._run = None
        self._count, self._down = 0, False  # the counter while stopped
        self._watchers = {}  # key -> (trigger, callback(rising))
        self._levels = {}  # key -> the level last given to that watcher
        self._plan_generation = 0
        self._frozen = None  # the cycle DBG_TIM1_STOP stopped the counter at, while the core is halted
        self._update_after_thaw = False

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
            if self._system_sources:
                self.regs[SR] |= SBIF
            self._update_irq()
            return
        if offset == EGR:
            if value & COMG:
                self._commutate()
            if value & UG:
                self._update_event()
                self._software_update()
            self._plan()
            return
        if offset in (CR1, CNT, PSC, ARR, RCR, CCR1, CCR2, CCR3, CCR4):
            self._time_base_write(offset, value)
            if offset == CR1:
                self._await_update()
            self._plan()
            return
        if offset == BDTR:
            if self._system_sources or (self._input_break_active() and value & BKE):
                value &= ~MOE  # a break holds MOE clear while its source is active
            if not value & (MOE | AOE):
                self.off_writes.append(self.chip.core.instructions)  # outputs off, and they stay off
            self.regs[BDTR] = value
            self._await_update()
            return
        self.regs[offset] = value
        if offset in (CCMR1, CCMR2, CCER) and not self._preloaded():
            self.active[offset] = value
        if offset in (CR2, CCMR1, CCMR2, CCER):
            self._plan()

    def read(self, offset):
        if offset == CNT:
            self.chip.core.changing_read = True  # counts with time
            return self.counter()
        return super().read(offset)

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
        return bool(self._system_sources) or self._input_break_active()

    def system_break(self, source="lockup"):
        """A system break source goes active (RM0440 28.3.19, the system break sources: the core's LOCKUP through
        SYSCFG_CFGR2.CLL, a flash ECC double error through ECCL, 9.2.5): MOE clears and SBIF sets at once. While any
        source is active SBIF cannot be cleared and AOE brings nothing back; LOCKUP stays active until a reset."""
        self.system_breaks += 1
        self._system_sources.add(source)
        self.regs[BDTR] = self.regs.get(BDTR, 0) & ~MOE
        self.regs[SR] = self.regs.get(SR, 0) | SBIF
        self._update_irq()

    def release_system_break(self, source):
        """A system break source goes inactive (an ECC double error's once FLASH_ECCR.ECCD is cleared)."""
        if source in self._system_sources:
            self._system_sources.discard(source)
            self._await_update()

    def debug_freeze(self, frozen):
        """The core halted with DBGMCU_APB2FZR.DBG_TIM1_STOP set (`frozen`), or not: "the TIMx counter either
        continues to work normally or stops ... when the counter is stopped (DBG_TIMx_STOP = 1), the outputs are
        disabled (as if the MOE bit was reset)" (RM0440 28.3, "Debug mode"). The count, the repetition counter's
        phase and any preload waiting for an update event are kept across the halt."""
        if frozen == (self._frozen is not None):
            return
        now = self.chip.core.cycles
        if frozen:
            self._sync()
            self._frozen = now
            self._plan()  # cancels what was scheduled: nothing moves while frozen
            return
        delta, self._frozen = now - self._frozen, None
        if self._run is not None:
            origin, *rest = self._run
            self._run = (origin + delta, *rest)
        if self._pending:
            self._pending_since += delta
        self._plan()
        if self._update_after_thaw:
            self._update_after_thaw = False
            self._await_update()

    def frozen(self):
        return self._frozen is not None

    def _clock(self):
        """The core cycle the counter is at: held while frozen."""
        return self.chip.core.cycles if self._frozen is None else self._frozen

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
        # In core cycles, TIM1 counting at APB2's timer clock (RM0440 7.2, "Timer clock").
        clocks = (self.regs.get(ARR, 0) + 1) * (self.regs.get(PSC, 0) + 1)
        return clocks * self.chip.core.hz // self.chip.rcc.timer_hz(2)

    def _await_update(self):
        """With AOE set and MOE clear, the next update event sets MOE (RM0440 28.3.19); it comes within half a
        PWM period of a running centre-aligned counter."""
        bdtr = self.regs.get(BDTR, 0)
        if bdtr & AOE and not bdtr & MOE and bit(self.regs.get(CR1, 0), 0):
            self.chip.core.at(self.chip.core.cycles + self._half_period(), self._update_event)

    def _update_event(self):
        if self._frozen is not None:
            self._update_after_thaw = True  # no update event while the counter is stopped
            return
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
        # A debug halt's freeze disables the outputs as if MOE were reset (28.3, "Debug mode").
        if not bdtr & MOE or self._frozen is not None:
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

    # The counter -------------------------------------------------------------------------------------------------
    def _mode(self):
        cr1 = self.regs.get(CR1, 0)
        if field(cr1, 5, 2):
            return "centre"  # CMS (RM0440 28.6.1)
        return "down" if bit(cr1, 4) else "up"  # DIR

    @staticmethod
    def _length(arr, mode):
        """Ticks from one under- or overflow to the next (28.3.3)."""
        return arr if mode == "centre" else arr + 1

    def _where(self, cycle):
        """(segment k, tick j in it, counting down, CNT) at `cycle` of a running counter."""
        origin, per_tick, arr, mode, _ = self._run
        k, j = divmod((cycle - origin) // per_tick, self._length(arr, mode))
        down = k % 2 == 1 if mode == "centre" else mode == "down"
        return k, j, down, arr - j if down else j

    def counter(self):
        if self._run is None:
            return self._count
        self._sync()
        return self._where(self._clock())[3]

    def _rebase(self, cycle, count, down, k0=0):
        """The counter at `count` (counting down or up) at `cycle`, with the shadows' PSC and ARR. A null ARR
        blocks the counter (28.3.2): it stops counting."""
        arr, per_tick, mode = self._shadow[ARR], self._shadow[PSC] + 1, self._mode()
        if arr == 0:
            self._run = None
            self._count, self._down = 0, down
            return
        count = min(count, arr)
        if mode == "centre":
            phase = 2 * arr - count if down and count else count
        else:
            phase = arr - count if mode == "down" else count
        self._run = (cycle - phase * per_tick, per_tick, arr, mode, k0)

    def _boundary(self, k):
        origin, per_tick, arr, mode, _ = self._run
        return origin + k * self._length(arr, mode) * per_tick

    def _is_update(self, k):
        return k >= 1 and (k - self._run[4]) % (self._shadow[RCR] + 1) == 0

    def _next_update(self, after):
        """The segment whose start is the first update event after cycle `after`."""
        origin, per_tick, arr, mode, k0 = self._run
        k = (after - origin) // (self._length(arr, mode) * per_tick) + 1
        return k + (k0 - k) % (self._shadow[RCR] + 1)

    def _sync(self):
        """Preloaded values reach the shadows at the first update event after they were written (28.3.2)."""
        now = self._clock()
        while self._pending and self._run is not None:
            k = self._next_update(self._pending_since)
            at = self._boundary(k)
            if at > now:
                return
            self._shadow.update(self._pending)
            self._pending = {}
            # The new PSC and ARR count from this update event: an underflow (0, up) or an overflow (ARR, down).
            overflow = self._run[3] == "centre" and k % 2 == 1
            self._rebase(at, self._shadow[ARR] if overflow else 0, overflow, k0=1 if overflow else 0)

    def _preloaded_register(self, offset):
        cr1, ccmr1, ccmr2 = self.regs.get(CR1, 0), self.regs.get(CCMR1, 0), self.regs.get(CCMR2, 0)
        return {PSC: True, RCR: True, ARR: bit(cr1, 7), CCR1: bit(ccmr1, 3), CCR2: bit(ccmr1, 11),
                CCR3: bit(ccmr2, 3), CCR4: bit(ccmr2, 11)}[offset]

    def _time_base_write(self, offset, value):
        self._sync()
        now = self._clock()
        if offset == CR1:
            old = self.regs.get(CR1, 0)
            running = self._run is not None
            if running and value & 1 and field(value ^ old, 5, 2):
                # "It is not allowed to switch from edge-aligned mode to center-aligned mode as long as the counter
                # is enabled (CEN=1)" (28.6.1, CMS).
                self.chip.core.fail(f"{self.name}: CR1.CMS changed with the counter running")
            if running and value & 1 and not field(value ^ old, 4, 1):
                self.regs[CR1] = value  # the counter goes on as it was
                return
            if running:
                _, _, self._down, self._count = self._where(now)
            self.regs[CR1] = value
            self._run = None
            if value & 1:
                self._rebase(now, self._count, self._down if self._mode() == "centre" else self._mode() == "down")
            return
        if offset == CNT:
            self.regs[CNT] = value & 0xFFFF
            if self._run is not None:
                self._rebase(now, value & 0xFFFF, self._where(now)[2])
            else:
                self._count = value & 0xFFFF
            return
        self.regs[offset] = value
        if self._preloaded_register(offset):
            if not self._pending:
                self._pending_since = now
            self._pending[offset] = value
            return
        self._shadow[offset] = value
        if offset == ARR and self._run is not None:
            _, _, down, count = self._where(now)
            self._rebase(now, count, down)

    def _software_update(self):
        """EGR.UG: the shadows take the preload registers, the counter restarts (0, or ARR counting down), the
        repetition counter reloads (28.3.2, 28.6.6); TRGO's "reset" and "update" see it."""
        for offset in self._shadow:
            self._shadow[offset] = self.regs.get(offset, self._shadow[offset] if offset == ARR else 0)
        self._pending = {}
        down = self._mode() == "down"
        if self._run is not None:
            self._rebase(self._clock(), self._shadow[ARR] if down else 0, down)
        else:
            self._count = self._shadow[ARR] if down else 0
        for key, (trigger, _) in list(self._watchers.items()):
            if self._signal(trigger) in (("reset",), ("update",)):
                self._pulse(key)

    # What the counter drives: TRGO, TRGO2 and the compare events -------------------------------------------------
    def watch(self, key, trigger, callback):
        """`callback(rising)` at each edge of `trigger`: "TRGO", "TRGO2" or "CC1".."CC4" (the compare events)."""
        self._watchers[key] = (trigger, callback)
        self._levels.pop(key, None)
        self._plan()

    def unwatch(self, key):
        if self._watchers.pop(key, None) is not None:
            self._levels.pop(key, None)
            self._plan()

    def _signal(self, trigger):
        """What a trigger output carries: ("reset",), ("enable",), ("update",) or ("match", n) pulses, or the level
        ("ref", n) of OCnREF (n = 0-3); None for what is not modelled. MMS (CR2 bits 25, 6:4) and MMS2 (bits
        23:20) share their first eight codes (28.6.2)."""
        cr2 = self.regs.get(CR2, 0)
        if trigger.startswith("CC"):
            return ("match", int(trigger[2]) - 1)
        code = field(cr2, 4, 3) | bit(cr2, 25) << 3 if trigger == "TRGO" else field(cr2, 20, 4)
        return {0: ("reset",), 1: ("enable",), 2: ("update",), 3: ("match", 0), 4: ("ref", 0), 5: ("ref", 1),
                6: ("ref", 2), 7: ("ref", 3)}.get(code)

    def _output_mode(self, channel):
        ccmr = self.active[CCMR1 if channel < 2 else CCMR2]
        shift = 8 * (channel % 2)
        return field(ccmr, 4 + shift, 3) | bit(ccmr, 16 + shift) << 3

    def reference_at(self, channel, cycle):
        """OCxREF of channel 0-3 at `cycle` of the running counter, with today's compare values; None while it is
        stopped (for a test's model of what the timer drives)."""
        if self._run is None:
            return None
        self._sync()
        _, _, down, count = self._where(cycle)
        return self._reference_at(channel, down, count)

    def counting_at(self, cycle):
        """(CNT, counting down) at `cycle` of the running counter; None while it is stopped."""
        if self._run is None:
            return None
        self._sync()
        _, _, down, count = self._where(cycle)
        return count, down

    def _reference_at(self, channel, down, count):
        """OCnREF with the counter at `count` (28.3.12 PWM mode: PWM mode 1 is active while CNT < CCRx counting
        up, while CNT <= CCRx counting down; PWM mode 2 the inverse; 28.3.10 forced levels). None: frozen, the
        level stays; "unmodelled" for the other modes."""
        mode = self._output_mode(channel)
        ccr = self._shadow[(CCR1, CCR2, CCR3, CCR4)[channel]]
        if mode in (0b0100, 0b0101):
            return mode & 1
        if mode in (0b0110, 0b0111):
            active = count <= ccr if down else count < ccr
            return int(active) ^ (mode & 1)
        if mode == 0:
            return None
        return "unmodelled"

    def _plan(self, inclusive=False):
        """Gives each watcher the edge its signal makes now, and schedules those to come within the counter's
        current segment and the segment's end. `inclusive`: at a segment's first cycle, its pulses are due."""
        self._plan_generation += 1
        if not self._watchers or self._frozen is not None:
            return
        self._sync()
        core = self.chip.core
        now, generation = core.now(), self._plan_generation
        where = self._where(now) if self._run is not None else None
        for key, (trigger, _) in list(self._watchers.items()):
            signal = self._signal(trigger)
            if signal is None:
                core.fail(f"{self.name}: {trigger} with CR2 {self.regs.get(CR2, 0):#010x} is not modelled")
                continue
            if signal[0] == "enable":
                self._levels.setdefault(key, int(self._run is not None))
                self._give(key, int(self._run is not None))
            if where is None or signal[0] not in ("ref", "match"):
                continue
            k, j, down, count = where
            origin, per_tick, arr, mode, _ = self._run
            start = self._boundary(k)
            length = self._length(arr, mode)
            if signal[0] == "ref":
                level = self._reference_at(signal[1], down, count)
                if level == "unmodelled":
                    core.fail(f"{self.name}: OC{signal[1] + 1}M {self._output_mode(signal[1]):04b} as a trigger "
                              f"output is not modelled")
                    continue
                if level is None:
                    continue
                if key not in self._levels:
                    self._levels[key] = level  # the level when watching began: no edge
                self._give(key, level)
                # The one change a PWM reference makes in a segment: where CNT passes CCRx.
                ccr = self._shadow[(CCR1, CCR2, CCR3, CCR4)[signal[1]]]
                change = arr - ccr if down else ccr
                if j < change < length:
                    new = self._reference_at(signal[1], down, arr - change if down else change)
                    if new != level:
                        at = start + change * per_tick
                        core.at(at, lambda key=key, new=new: generation == self._plan_generation
                                and self._give(key, new))
            else:
                ccr = self._shadow[(CCR1, CCR2, CCR3, CCR4)[signal[1]]]
                match = arr - ccr if down else ccr
                cms = field(self.regs.get(CR1, 0), 5, 2)
                # Centre-aligned, CMS says which count direction sets the compare flags (28.6.1).
                wanted = mode != "centre" or cms == 3 or (cms == 1) == down
                if wanted and 0 <= match < length and (j < match or (inclusive and j == match)):
                    at = start + match * per_tick
                    core.at(at, lambda key=key: generation == self._plan_generation and self._pulse(key))
        if self._run is not None:
            k = where[0] + 1
            update = self._is_update(k)
            core.at(self._boundary(k), lambda: generation == self._plan_generation and self._segment(update))

    def _segment(self, update):
        """An under- or overflow: an update event every RCR + 1 of them."""
        self._sync()
        if update:
            for key, (trigger, _) in list(self._watchers.items()):
                if self._signal(trigger) == ("update",):
                    self._pulse(key)
        self._plan(inclusive=True)

    def _give(self, key, level):
        if key in self._watchers and self._levels.get(key) != level:
            self._levels[key] = level
            self._watchers[key][1](bool(level))

    def _pulse(self, key):
        """A pulse of one timer clock: its rising edge now, its falling edge a cycle later."""
        if key in self._watchers:
            self._watchers[key][1](True)
            falling = lambda: key in self._watchers and self._watchers[key][1](False)  # noqa: E731
            self.chip.core.at(self.chip.core.now() + 1, falling)
