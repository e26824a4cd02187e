"""The system control space the Cortex-M4 brings and Unicorn lacks: NVIC, SCB and SysTick (ARMv7-M B3.2-B3.4),
with the G431's 4 priority bits (RM0440 16.1: 16 priority levels)."""

from .core import HARD_FAULT, IRQ0, NMI, PENDSV, SYSTICK
from .peripheral import Peripheral

PRIORITY_BITS = 4
PRIORITY_MASK = ((1 << PRIORITY_BITS) - 1) << (8 - PRIORITY_BITS)

# Offsets within the system control space at 0xE000_E000.
SYST_CSR, SYST_RVR, SYST_CVR = 0x010, 0x014, 0x018
ISER, ICER, ISPR, ICPR, IABR, IPR = 0x100, 0x180, 0x200, 0x280, 0x300, 0x400
CPUID, ICSR, VTOR, AIRCR, SCR, CCR, SHPR1, SHCSR, CFSR, HFSR, CPACR = (
    0xD00, 0xD04, 0xD08, 0xD0C, 0xD10, 0xD14, 0xD18, 0xD24, 0xD28, 0xD2C, 0xD88)
STIR = 0xF00
FPCCR = 0xF34

IRQS = 102  # RM0440 Table 97: the G431's last vector is FMAC, IRQ 101


class Nvic(Peripheral):
    resets = {CPUID: 0x410F_C241, CCR: 0x200, FPCCR: 0xC000_0000}

    def __init__(self, chip, name, base):
        super().__init__(chip, name, base)
        self.enabled = set()
        self.pending = set()
        self.lines = set()  # interrupt lines a peripheral holds asserted
        self.priorities = {}
        self.ready = False  # something is pending and enabled: the core looks whether it can be taken
        self.reset_requested = False

    def reset(self):
        super().reset()
        self.enabled.clear()
        self.pending.clear()
        self.lines.clear()
        self.priorities.clear()
        self.ready = False
        self.reset_requested = False

    # What the core asks --------------------------------------------------------------------------------------
    def wants_attention(self):
        return self.ready and self.chip.core.execution_priority() > self._best_priority()

    def _best_priority(self):
        number = self.highest_pending()
        return 256 if number is None else self.priority(number)

    def priority(self, number):
        if number == NMI:
            return -2
        if number == HARD_FAULT:
            return -1
        return self.priorities.get(number, 0)

    def highest_pending(self):
        if not self.pending:
            return None  # (most calls: the run loop asks after every stop)
        candidates = [n for n in self.pending if n < IRQ0 or n in self.enabled]
        if not candidates:
            return None
        # The lowest priority value wins; between equals, the lowest exception number (B1.5.4).
        return min(candidates, key=lambda n: (self.priority(n), n))

    def activate(self, number):
        self.pending.discard(number)
        self._update()

    def deactivate(self, number):
        # A level line still asserted pends its interrupt again once the handler returns.
        if number in self.lines:
            self.pending.add(number)
        self._update()

    def set_pending(self, number):
        self.pending.add(number)
        self._update()

    def line(self, irq, level):
        """A peripheral's interrupt line: asserting it pends the interrupt (B3.4.1)."""
        number = IRQ0 + irq
        if level:
            if number not in self.lines:
                self.lines.add(number)
                if number not in self.chip.core.active:
                    self.pending.add(number)
        else:
            self.lines.discard(number)
        self._update()

    def _update(self):
        self.ready = any(n < IRQ0 or n in self.enabled for n in self.pending)

    # Registers ------------------------------------------------------------------------------------------------
    def read(self, offset):
        if ISER <= offset < ISER + 0x40:
            return self._bits(self.enabled, (offset - ISER) // 4)
        if ICER <= offset < ICER + 0x40:
            return self._bits(self.enabled, (offset - ICER) // 4)
        if ISPR <= offset < ISPR + 0x40:
            return self._bits(self.pending, (offset - ISPR) // 4)
        if ICPR <= offset < ICPR + 0x40:
            return self._bits(self.pending, (offset - ICPR) // 4)
        if IABR <= offset < IABR + 0x40:
            return self._bits(set(self.chip.core.active), (offset - IABR) // 4)
        if IPR <= offset < IPR + IRQS:
            return sum(self.priorities.get(IRQ0 + offset - IPR + i, 0) << (8 * i) for i in range(4))
        if SHPR1 <= offset < SHPR1 + 12:
            return sum(self.priorities.get(4 + offset - SHPR1 + i, 0) << (8 * i) for i in range(4))
        if offset == ICSR:
            active = self.chip.core.active
            pending = self.highest_pending()
            value = (active[-1] if active else 0) | ((pending or 0) << 12)
            if PENDSV in self.pending:
                value |= 1 << 28
            if SYSTICK in self.pending:
                value |= 1 << 26
            return value
        if offset == VTOR:
            return self.chip.core.vtor
        if offset == SYST_CVR:
            self.chip.core.changing_read = True
            return self._systick_value()
        return super().read(offset)

    def write(self, offset, value):
        self.writes.add(offset)
        if ISER <= offset < ISER + 0x40:
            self.enabled |= self._numbers(value, (offset - ISER) // 4)
        elif ICER <= offset < ICER + 0x40:
            self.enabled -= self._numbers(value, (offset - ICER) // 4)
        elif ISPR <= offset < ISPR + 0x40:
            self.pending |= self._numbers(value, (offset - ISPR) // 4)
        elif ICPR <= offset < ICPR + 0x40:
            self.pending -= self._numbers(value, (offset - ICPR) // 4)
        elif IPR <= offset < IPR + IRQS:
            for i in range(4):
                self.priorities[IRQ0 + offset - IPR + i] = (value >> (8 * i)) & PRIORITY_MASK
        elif SHPR1 <= offset < SHPR1 + 12:
            for i in range(4):
                self.priorities[4 + offset - SHPR1 + i] = (value >> (8 * i)) & PRIORITY_MASK
        elif offset == STIR:
            self.pending.add(IRQ0 + (value & 0x1FF))
        elif offset == ICSR:
            if value & (1 << 28):
                self.pending.add(PENDSV)
            if value & (1 << 27):
                self.pending.discard(PENDSV)
            if value & (1 << 26):
                self.pending.add(SYSTICK)
            if value & (1 << 31):
                self.pending.add(NMI)
        elif offset == VTOR:
            self.chip.core.vtor = value & 0xFFFF_FF80
        elif offset == AIRCR:
            # VECTKEY 0x05FA and SYSRESETREQ (B3.2.6): a system reset.
            if value >> 16 == 0x05FA and value & (1 << 2):
                self.reset_requested = True
                self.chip.request_reset("software")
        elif offset == SYST_CSR:
            self.regs[offset] = value & 0x7
            self._systick_start()
        else:
            self.regs[offset] = value
        self._update()
        if self.ready:
            self.chip.core.request_stop()

    @staticmethod
    def _bits(numbers, word):
        return sum(1 << (n - IRQ0 - 32 * word) for n in numbers if 0 <= n - IRQ0 - 32 * word < 32)

    @staticmethod
    def _numbers(value, word):
        return {IRQ0 + 32 * word + i for i in range(32) if value >> i & 1}

    # SysTick: counted in core clocks (CLKSOURCE = 1) ----------------------------------------------------------
    def _systick_start(self):
        csr = self.regs.get(SYST_CSR, 0)
        if csr & 1:
            self._systick_origin = self.chip.core.cycles
            self._systick_generation = getattr(self, "_systick_generation", 0) + 1
            self._systick_schedule(self._systick_generation)

    def _systick_period(self):
        return (self.regs.get(SYST_RVR, 0) & 0xFF_FFFF) + 1

    def _systick_value(self):
        if not self.regs.get(SYST_CSR, 0) & 1:
            return 0
        elapsed = self.chip.core.cycles - self._systick_origin
        return (self._systick_period() - 1) - elapsed % self._systick_period()

    def _systick_schedule(self, generation):
        core = self.chip.core
        elapsed = core.cycles - self._systick_origin
        period = self._systick_period()
        due = self._systick_origin + (elapsed // period + 1) * period

        def tick():
            if generation != self._systick_generation or not self.regs.get(SYST_CSR, 0) & 1:
                return
            self.regs[SYST_CSR] |= 1 << 16
            if self.regs[SYST_CSR] & 2:
                self.set_pending(SYSTICK)
            self._systick_schedule(generation)

        core.at(due, tick)
