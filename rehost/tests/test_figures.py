"""Each image's start-up time, stack high-water mark and load, measured under the models (instructions at
170 MHz, one per cycle): the figures the note reports beside the QEMU run's."""

import pytest

from conftest import ALL, boot, image
from thruster import exchange, set_halls, start


def stack_within_budget(chip, name, expected, figures, when):
    """The stack's high-water mark, held to the image's budget (g431_hw::images::BUILDS, its `stack_budget`)."""
    used = chip.stack_high_water()
    budget = expected["stack_budgets"][name]
    size = image(name).symbol("_stack_start") - 0x2000_0000
    figures[f"{name}: stack high-water {when}"] = f"{used:,} B of its {budget:,} B budget ({size:,} B there)"
    assert used <= budget <= size, f"{name}: {used} B of stack used {when}, budget {budget} B, {size} B there"


@pytest.mark.parametrize("name", ALL)
def test_start_up_and_stack(name, expected, figures):
    chip = boot(name)
    startup_us, startup = chip.core.cycles / 170, chip.core.instructions
    chip.run_for(0.2)
    figures[f"{name}: start-up to idle"] = f"{startup_us:,.0f} us, {startup:,} instructions"
    stack_within_budget(chip, name, expected, figures, "at idle")


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
    stack_within_budget(chip, "thruster-fw", expected, figures, "at 4500 rpm")


def test_master_load_polling_six_thrusters(expected, figures):
    from master import start as start_master
    chip, _, _ = start_master("lbv-master-fw", expected)
    busy = load(chip, 0.5)
    figures["lbv-master-fw: instructions per second polling 6 thrusters"] = (
        f"{busy / 1e6:.2f} M ({busy / 170e6:.1%} of the core)")
    assert busy < 0.5 * 170e6
    stack_within_budget(chip, "lbv-master-fw", expected, figures, "polling 6 thrusters")
