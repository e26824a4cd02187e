"""GPIO ports (RM0440 9.4) and the EXTI lines they feed through SYSCFG_EXTICRx (RM0440 15.5, 9.2.3).

A port's registers take no access while its clock is off (RCC_AHB2ENR's GPIOxEN, clear after every reset; RM0440
7.4.16: "when the peripheral clock is not active, the peripheral registers read or write access is not supported"):
here a write is then lost and a read gives 0, so an image that forgets the clock leaves its pins as they were."""

from .peripheral import Peripheral, bit, field
from .timers import TIM1_AF, TIM1_PINS

MODER, OTYPER, OSPEEDR, PUPDR, IDR, ODR, BSRR, LCKR, AFRL, AFRH, BRR = (
    0x00, 0x04, 0x08, 0x0C, 0x10, 0x14, 0x18, 0x1C, 0x20, 0x24, 0x28)

# Reset values (RM0440 9.4.1, 9.4.3, 9.4.4): PA13/PA14 (SWD) and PB3/PB4 are in their debug alternate functions,
# PA13 (SWDIO) and PB3 (SWO) at very high speed.
RESETS = {
    "A": {MODER: 0xABFF_FFFF, OSPEEDR: 0x0C00_0000, PUPDR: 0x6400_0000},
    "B": {MODER: 0xFFFF_FEBF, OSPEEDR: 0x0000_00C0, PUPDR: 0x0000_0100},
}
# Fields per pin, for telling which pins the image changed.
PIN_FIELDS = ((MODER, 2), (OTYPER, 1), (OSPEEDR, 2), (PUPDR, 2))

INPUT, OUTPUT, ALTERNATE, ANALOG = 0, 1, 2, 3
AHB2ENR = 0x4C  # RCC_AHB2ENR (RM0440 7.4.16): GPIOAEN is bit 0, ... GPIOGEN bit 6
MODE_NAMES = {INPUT: "input", OUTPUT: "output", ALTERNATE: "alternate", ANALOG: "analog"}
PULL_NAMES = {0: "none", 1: "up", 2: "down"}


class Gpio(Peripheral):
    def __init__(self, chip, name, base, letter):
        self.letter = letter
        self.resets = {MODER: 0xFFFF_FFFF, **RESETS.get(letter, {})}
        super().__init__(chip, name, base)
        self.external = {}  # pin -> level something outside drives (a hall sensor, a button)

    def pin_state(self, pin):
        """Mode, output type, pull and alternate function of one pin."""
        afr = self.regs.get(AFRL if pin < 8 else AFRH, 0)
        return {
            "mode": MODE_NAMES[field(self.regs.get(MODER, 0), 2 * pin, 2)],
            "open_drain": bool(bit(self.regs.get(OTYPER, 0), pin)),
            "pull": PULL_NAMES.get(field(self.regs.get(PUPDR, 0), 2 * pin, 2), "reserved"),
            "af": field(afr, 4 * (pin % 8), 4),
        }

    def changed_pins(self):
        """Pins whose configuration differs from the reset state."""
        changed = set()
        for pin in range(16):
            for offset, width in PIN_FIELDS:
                if field(self.regs.get(offset, 0), width * pin, width) != field(self.resets.get(offset, 0), width * pin, width):
                    changed.add(pin)
            afr = AFRL if pin < 8 else AFRH
            if field(self.regs.get(afr, 0), 4 * (pin % 8), 4) != 0:
                changed.add(pin)
        return changed

    def output(self, pin):
        """What the chip drives on the pin: 0, 1, "pwm" (a timer switching it), or None (not driven)."""
        mode = field(self.regs.get(MODER, 0), 2 * pin, 2)
        if mode == OUTPUT:
            return bit(self.regs.get(ODR, 0), pin)
        if mode == ALTERNATE:
            af = field(self.regs.get(AFRL if pin < 8 else AFRH, 0), 4 * (pin % 8), 4)
            channel = TIM1_PINS.get((self.letter, pin))
            if channel is not None and af == TIM1_AF:
                return self.chip.tim1.pin_output(*channel)
        return None

    def level(self, pin):
        driven = self.output(pin)
        if driven is not None:
            return 0 if driven == "pwm" else driven
        if pin in self.external:
            return self.external[pin]
        return 1 if field(self.regs.get(PUPDR, 0), 2 * pin, 2) == 1 else 0

    def drive(self, pin, level):
        """Something outside the chip drives the pin; a rising or falling edge reaches EXTI."""
        before = self.level(pin)
        self.external[pin] = 1 if level else 0
        after = self.level(pin)
        if before != after:
            self.chip.exti.edge(self.letter, pin, after)

    def clocked(self):
        return bool(bit(self.chip.rcc.regs.get(AHB2ENR, 0), "ABCDEFG".index(self.letter)))

    def read(self, offset):
        if not self.clocked():
            return 0
        if offset == IDR:
            return sum(self.level(pin) << pin for pin in range(16))
        if offset == BSRR:
            return 0
        return super().read(offset)

    def write(self, offset, value):
        if not self.clocked():
            return
        self.writes.add(offset)
        if offset == BSRR:
            odr = self.regs.get(ODR, 0)
            odr = (odr | (value & 0xFFFF)) & ~(value >> 16)
            self.regs[ODR] = odr
        elif offset == BRR:
            self.regs[ODR] = self.regs.get(ODR, 0) & ~(value & 0xFFFF)
        elif offset == IDR:
            pass
        else:
            self.regs[offset] = value


# EXTI (15.5.1-15.5.7): IMR1, EMR1, RTSR1, FTSR1, SWIER1, PR1 and IMR2; lines 0-15 are the GPIO lines.
IMR1, EMR1, RTSR1, FTSR1, SWIER1, PR1 = 0x00, 0x04, 0x08, 0x0C, 0x10, 0x14
# RM0440 Table 97: EXTI0-4 have their own vectors, 5-9 and 10-15 share one each.
EXTI_IRQ = {0: 6, 1: 7, 2: 8, 3: 9, 4: 10, **{n: 23 for n in range(5, 10)}, **{n: 40 for n in range(10, 16)}}


class Exti(Peripheral):
    # IMR2's reserved bits read 1 (15.5.7).
    resets = {IMR1: 0xFF82_0000, 0x20: 0xFFFF_FF87}

    def edge(self, port, pin, level):
        exticr = self.chip.syscfg.regs.get(0x08 + 4 * (pin // 4), 0)
        selected = "ABCDEFG"[field(exticr, 4 * (pin % 4), 4)]
        if selected != port:
            return
        trigger = RTSR1 if level else FTSR1
        if bit(self.regs.get(trigger, 0), pin):
            self.regs[PR1] = self.regs.get(PR1, 0) | (1 << pin)
            self._update()

    def write(self, offset, value):
        self.writes.add(offset)
        if offset == PR1:
            self.regs[PR1] = self.regs.get(PR1, 0) & ~value
        elif offset == SWIER1:
            self.regs[PR1] = self.regs.get(PR1, 0) | (value & 0xFFFF)
        else:
            self.regs[offset] = value
        self._update()

    def _update(self):
        pending = self.regs.get(PR1, 0) & self.regs.get(IMR1, 0)
        for irq in sorted(set(EXTI_IRQ.values())):
            lines = [n for n, i in EXTI_IRQ.items() if i == irq]
            self.chip.nvic.line(irq, any(pending >> n & 1 for n in lines))
