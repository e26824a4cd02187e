"""The independent watchdog (RM0440 42): counts down from RLR at LSI / (4 x 2^PR) once started, and resets the
chip when it reaches zero; KR = 0xAAAA reloads it. While the core is halted with DBGMCU_APB1FZR1.DBG_IWDG_STOP set
the counter stops (RM0440 42.3, "Debug mode"; 47.16), and goes on from there at the resume."""

from .peripheral import Peripheral

KR, PR, RLR, SR, WINR = 0x00, 0x04, 0x08, 0x0C, 0x10
START, RELOAD, UNLOCK = 0xCCCC, 0xAAAA, 0x5555
LSI_HZ = 32_000  # RM0440 7.2.5, DS12589 Table 48: 29.5-34 kHz


class Iwdg(Peripheral):
    resets = {RLR: 0xFFF, WINR: 0xFFF}
    # SR's update flags (42.4.4): a register update takes at once here, so they read 0.
    read_only = {SR: 0xFFFF_FFFF}

    def __init__(self, chip, name, base):
        super().__init__(chip, name, base)
        self.lsi_hz = LSI_HZ
        self.running = False
        self.unlocked = False
        self.reloads = 0
        self._generation = 0
        self._deadline = None
        self._divider = 4
        self._frozen_left = None  # cycles left to zero when DBG_IWDG_STOP stopped the counter (a debug halt)
        self.started_at = None  # the cycle of KR = 0xCCCC
        # Every reload (KR = 0xCCCC or 0xAAAA) while it runs: (cycle, the counter's value just before it), so a test
        # sees how close to zero it came.
        self.refreshes = []

    def reset(self):
        super().reset()
        self.running = False
        self.unlocked = False
        self.reloads = 0
        self._generation += 1
        self._deadline = None
        self._frozen_left = None
        self.started_at = None
        self.refreshes = []

    def timeout_cycles(self):
        divider = 4 << (self.regs.get(PR, 0) & 7)
        ticks = (self.regs.get(RLR, 0xFFF) & 0xFFF) + 1
        return ticks * divider * self.chip.core.hz // self.lsi_hz

    def counter(self):
        """The down-counter's value now (RM0440 42.3.2): the LSI ticks left before it reaches zero and resets the
        chip; None while it is stopped."""
        if not self.running or self._deadline is None:
            return None
        left = self._left()
        return left * self.lsi_hz // (self._divider * self.chip.core.hz)

    def write(self, offset, value):
        self.writes.add(offset)
        if offset == KR:
            key = value & 0xFFFF
            if key == UNLOCK:
                self.unlocked = True
            elif key in (START, RELOAD):
                if key == START and not self.running:
                    self.running = True
                    self.started_at = self.chip.core.cycles
                elif self.running:
                    self.refreshes.append((self.chip.core.cycles, self.counter()))
                self.unlocked = False
                self.reloads += 1
                self._arm()
            return
        if offset in (PR, RLR, WINR) and not self.unlocked:
            return  # write-protected until KR = 0x5555
        self.store(offset, value)

    def _left(self):
        if self._frozen_left is not None:
            return self._frozen_left
        return max(self._deadline - self.chip.core.cycles, 0)

    def _arm(self, cycles=None):
        self._generation += 1
        generation = self._generation
        self._divider = 4 << (self.regs.get(PR, 0) & 7)
        cycles = self.timeout_cycles() if cycles is None else cycles
        self._deadline = self.chip.core.cycles + cycles
        if self._frozen_left is not None:
            self._frozen_left = cycles  # reloaded while stopped: it counts from RLR at the resume
            return
        self.chip.core.at(self._deadline, lambda: self._expire(generation))

    def debug_freeze(self, frozen):
        """The core halted with DBG_IWDG_STOP set (`frozen`), or not: the counter stops, and counts on from where
        it stopped once the core runs again."""
        if frozen == (self._frozen_left is not None):
            return
        if frozen:
            self._frozen_left = self._left() if self._deadline is not None else 0
            self._generation += 1  # the scheduled expiry is void
            return
        left, self._frozen_left = self._frozen_left, None
        if self.running and self._deadline is not None:
            self._arm(left)

    def _expire(self, generation):
        if generation == self._generation and self.running:
            self.chip.request_reset("watchdog")
