"""Each image's start-up time, stack high-water mark and load, measured under the models (instructions at
170 MHz, one per cycle): the figures the note reports beside the QEMU run's."""

import pytest

from conftest import ALL, boot, image
from thruster import exchange, set_halls, start

# The stack every image must keep spare at its deepest (flip-link puts the stack below the statics: an overflow
# faults instead of corrupting them).
STACK_MARGIN = 1024


@pytest.mark.parametrize("name", ALL)
def test_start_up_and_stack(name, figures):
    chip = boot(name)
    startup_us, startup = chip.core.cycles / 170, chip.core.instructions
    chip.run_for(0.2)
    used = chip.stack_high_water()
    size = image(name).symbol("_stack_start") - 0x2000_0000
    figures[f"{name}: start-up to idle"] = f"{startup_us:,.0f} us, {startup:,} instructions"
    figures[f"{name}: stack high-water"] = f"{used:,} of {size:,} B"
    assert used + STACK_MARGIN <= size, f"{name}: {used} B of stack used, {size} B there"


def load(chip, seconds):
    instructions, cycles = chip.core.instructions, chip.core.cycles
    chip.run_for(seconds)
    return (chip.core.instructions - instructions) / ((chip.core.cycles - cycles) / 170e6)


def test_thruster_load_at_rest_and_at_full_speed(expected, figures):
    chip, spec = start("thruster-fw", expected)
    rest = load(chip, 0.2)
    figures["thruster-fw: instructions per second at rest"] = f"{rest / 1e6:.2f} M ({rest / 170e6:.1%} of the core)"
    # 4500 rpm: the halls step a sector every 60 / (4500 x 6 x pole pairs) s.
    sector = 60 / (4500 * 6 * spec["pole_pairs"])
    exchange(chip, spec, expected["orders"]["SeaBotix"]["63"])
    forward = [step["hall"] for step in spec["forward"]]
    instructions, cycles, steps = chip.core.instructions, chip.core.cycles, 0
    while chip.core.cycles - cycles < 0.2 * 170e6:
        set_halls(chip, forward[steps % 6])
        steps += 1
        chip.run_for(sector)
        if steps % 200 == 0:
            exchange(chip, spec, expected["orders"]["SeaBotix"]["63"])  # within the 1 s link timeout
    full = (chip.core.instructions - instructions) / ((chip.core.cycles - cycles) / 170e6)
    figures["thruster-fw: instructions per second at 4500 rpm"] = f"{full / 1e6:.2f} M ({full / 170e6:.1%} of the core)"
    assert chip.core.fault is None
    assert full < 0.5 * 170e6


def test_master_load_polling_six_thrusters(expected, figures):
    from master import start as start_master
    chip, _, _ = start_master("lbv-master-fw", expected)
    busy = load(chip, 0.5)
    figures["lbv-master-fw: instructions per second polling 6 thrusters"] = (
        f"{busy / 1e6:.2f} M ({busy / 170e6:.1%} of the core)")
    assert busy < 0.5 * 170e6
