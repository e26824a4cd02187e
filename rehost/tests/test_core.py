"""The core model's own rules, without an image."""

from unicorn import arm_const as arm

import conftest  # noqa: F401 (puts rehost/ on the path)
from g431.core import G474RE, Core


def test_the_run_stops_only_outside_an_it_block():
    """Unicorn starts again without the IT state it stopped in: the core must not stop (to take an exception) with
    ITSTATE set, or the block's remaining instructions run unconditionally. ITSTATE is xPSR bits 26:25 and 15:10
    (ARMv7-M B1.4.2), which Unicorn's xPSR reads back."""
    core = Core(G474RE)
    thumb = 1 << 24
    core.registers.write(arm.UC_ARM_REG_XPSR, thumb)
    assert not core.in_it_block()
    # ITT NE, its first instruction next: IT[7:0] = 0x1C (firstcond NE, two instructions).
    core.registers.write(arm.UC_ARM_REG_XPSR, thumb | (0x1C >> 2) << 10)
    assert core.in_it_block()
    # The last instruction of a block: only IT[1:0] left.
    core.registers.write(arm.UC_ARM_REG_XPSR, thumb | 0b01 << 25)
    assert core.in_it_block()
