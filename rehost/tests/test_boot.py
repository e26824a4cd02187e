"""Every image starts, sets its clocks, and reaches its executors' idle without a fault, a panic or a busy loop;
and a board whose crystal does not start hangs as a real one would."""

import pytest

from conftest import ALL, BOOT_INSTRUCTIONS, Stm32g4, boot, image
from g431.core import Stop


@pytest.mark.parametrize("name", ALL)
def test_reaches_idle_without_a_fault_or_a_warning(name):
    chip = boot(name)
    assert chip.core.instructions < BOOT_INSTRUCTIONS
    assert chip.core.fault is None
    assert chip.rcc.sysclk_hz() == 170_000_000
    # The defmt log: the first lines a probe would show, and no warning or error (the bring-up build's one
    # warning is its purpose).
    levels = [level for level, _ in chip.log.lines]
    assert "info" in levels, chip.log_text()
    allowed = {"info", "debug", "trace"} | ({"warn"} if name.endswith("bringup") else set())
    assert set(levels) <= allowed, chip.log_text()
    # It stays idle: 50 ms more without a fault, and asleep most of the time.
    start_instructions, start_cycles = chip.core.instructions, chip.core.cycles
    chip.run_for(0.05)
    assert chip.core.fault is None
    busy = (chip.core.instructions - start_instructions) / (chip.core.cycles - start_cycles)
    assert busy < 0.5, f"{name} runs {busy:.0%} of the time at rest"


@pytest.mark.parametrize("name", ["thruster-fw", "lbv-master-fw"])
def test_a_crystal_that_does_not_start_hangs_the_start_up(name):
    chip = Stm32g4(image(name))
    chip.rcc.hse_starts = False
    with pytest.raises(Stop):
        chip.run_until(chip.idle, seconds=0.02, what="idle without HSE")
    # Stuck in embassy-stm32's wait for HSERDY, before the first log line: what a board without X3 does.
    assert not chip.log.lines
    assert chip.rcc.sysclk_hz() == 16_000_000
