"""What every modelled peripheral shares: a file of 32-bit registers with reset values, and its interrupt lines."""


class Peripheral:
    """Registers that read back what was written, unless a model says otherwise.

    `writes` keeps every register offset the image wrote, so a test can tell what it touched.
    """

    narrow_merge = True
    resets = {}
    # The bits of a register no write reaches: its read-only fields (RM0440's "r"), by offset.
    read_only = {}

    def __init__(self, chip, name, base):
        self.chip = chip
        self.name = name
        self.base = base
        self.regs = dict(self.resets)
        self.writes = set()

    def read(self, offset):
        return self.regs.get(offset, 0)

    def write(self, offset, value):
        self.writes.add(offset)
        self.store(offset, value)

    def store(self, offset, value):
        """A write of `value` as the register takes it: its read-only bits keep what they hold."""
        kept = self.read_only.get(offset, 0)
        self.regs[offset] = (self.regs.get(offset, 0) & kept) | (value & ~kept)

    def reg(self, offset):
        """A register's value, read without side effects (for tests)."""
        return self.regs.get(offset, 0)

    def reset(self):
        self.regs = dict(self.resets)
        self.writes = set()


def bit(value, n):
    return (value >> n) & 1


def field(value, shift, width):
    return (value >> shift) & ((1 << width) - 1)
