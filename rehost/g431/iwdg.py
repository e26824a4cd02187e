"""The independent watchdog (RM0440 42): counts down from RLR at LSI / (4 x 2^PR) once started, and resets the
chip when it reaches zero; KR = 0xAAAA reloads it."""

from .peripheral import Peripheral

KR, PR, RLR, SR, WINR = 0x00, 0x04, 0x08, 0x0C, 0x10
START, RELOAD, UNLOCK = 0xCCCC, 0xAAAA, 0x5555
LSI_HZ = 32_000  # RM0440 7.2.5, DS12589 Table 48: 29.5-34 kHz


class Iwdg(Peripheral):
    resets = {RLR: 0xFFF, WINR: 0xFFF}

    def __init__(self, chip, name, base):
        super().__init__(chip, name, base)
        self.lsi_hz = LSI_HZ
        self.running = False
        self.unlocked = False
        self.reloads = 0
        self._generation = 0

    def reset(self):
        super().reset()
        self.running = False
        self.unlocked = False
        self.reloads = 0
        self._generation += 1

    def timeout_cycles(self):
        divider = 4 << (self.regs.get(PR, 0) & 7)
        ticks = (self.regs.get(RLR, 0xFFF) & 0xFFF) + 1
        return ticks * divider * self.chip.core.hz // self.lsi_hz

    def write(self, offset, value):
        self.writes.add(offset)
        if offset == KR:
            key = value & 0xFFFF
            if key == UNLOCK:
                self.unlocked = True
            elif key in (START, RELOAD):
                if key == START:
                    self.running = True
                self.unlocked = False
                self.reloads += 1
                self._arm()
            return
        if offset in (PR, RLR, WINR) and not self.unlocked:
            return  # write-protected until KR = 0x5555
        self.regs[offset] = value

    def _arm(self):
        self._generation += 1
        generation = self._generation
        self.chip.core.at(self.chip.core.cycles + self.timeout_cycles(), lambda: self._expire(generation))

    def _expire(self, generation):
        if generation == self._generation and self.running:
            self.chip.request_reset("watchdog")
