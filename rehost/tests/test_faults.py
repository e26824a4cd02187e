"""The fault paths of the thruster image as they run: an overcurrent break, a panic, a HardFault, an NMI and a
stray interrupt each turn the bridge's outputs off; a hung task lets the watchdog reset the chip; the fault latch
in the backup domain survives that reset and is cleared by a power cycle."""

import pytest
from unicorn import arm_const as arm

from g431.core import IRQ0, NMI
from thruster import all_off, exchange, set_analog, start, switches

# The most instructions from a fault to the outputs being off: the handlers' first act is one BDTR store, so a
# few dozen at most (exception entry, the vector, the store).
STOP_WITHIN = 64


def driving(expected, name="thruster-fw"):
    """A thruster driving its bridge at a quarter of full speed, its rotor held (the stall window is 400 ms)."""
    chip, spec = start(name, expected)
    exchange(chip, spec, expected["orders"][spec["family"]]["25"])
    chip.run_for(0.05)
    assert chip.tim1.moe() and chip.tim1.active != {0x18: spec["coast"]["ccmr1"], 0x1C: spec["coast"]["ccmr2"],
                                                    0x20: spec["coast"]["ccer"]}
    assert not all_off(chip, spec), switches(chip, spec)
    return chip, spec


def stops_within(chip, seconds=0.001):
    start = chip.core.instructions
    chip.run_until(lambda: chip.tim1.off_writes and chip.tim1.off_writes[-1] >= start, seconds, "the outputs off")
    took = chip.tim1.off_writes[-1] - start
    assert not chip.tim1.moe()
    return took


def test_a_sustained_overcurrent_break_stops_the_bridge_until_a_zero_order(expected):
    chip, spec = driving(expected)
    # Cycle-by-cycle limiting: 20 short trips 4 ms apart (fewer than the 40 of a window that make an overcurrent),
    # the outputs back at the next update event each time.
    for _ in range(20):
        chip.tim1.set_break_input(True)
        chip.run_for(0.0001)
        chip.tim1.set_break_input(False)
        chip.run_for(0.004)
    assert chip.tim1.moe(), "isolated trips must not stop the bridge"
    assert not all_off(chip, spec), switches(chip, spec)
    status, _, _ = exchange(chip, spec, expected["orders"]["SeaBotix"]["25"])
    assert status[2] & 0x40 == 0
    # A short that stays: MOE drops at once in hardware; after 5 samples (`Thresholds::SPEC.overcurrent`) the
    # firmware clears AOE too, and FAULT bit 6 says why.
    chip.tim1.set_break_input(True)
    assert not chip.tim1.moe()
    assert all_off(chip, spec), f"the break left a switch on: {switches(chip, spec)}"
    chip.run_for(0.6)
    bdtr = chip.tim1.regs[0x44]
    assert not bdtr & (1 << 14), f"AOE still set after a sustained trip: {bdtr:#x}"
    status, _, _ = exchange(chip, spec, expected["orders"]["SeaBotix"]["25"])
    assert status[2] & 0x40, status.hex()
    chip.tim1.set_break_input(False)
    chip.run_for(0.05)
    assert not chip.tim1.moe(), "a non-zero order must not restart a stopped bridge"
    assert all_off(chip, spec), switches(chip, spec)
    exchange(chip, spec, expected["orders"]["SeaBotix"]["0"])
    exchange(chip, spec, expected["orders"]["SeaBotix"]["25"])
    chip.run_for(0.05)
    assert chip.tim1.moe(), "a zero order clears the stop"
    assert not all_off(chip, spec), switches(chip, spec)


def symbol_ending(chip, suffix):
    for name, address in chip.image.symbols.items():
        if name.endswith(suffix):
            return address & ~1
    raise KeyError(suffix)


def call(chip, function, *args):
    """Makes the interrupted code call `function`: as a panic in a task would."""
    uc = chip.core.uc
    for register, value in zip((arm.UC_ARM_REG_R0, arm.UC_ARM_REG_R1, arm.UC_ARM_REG_R2), args):
        uc.reg_write(register, value)
    uc.reg_write(arm.UC_ARM_REG_LR, chip.core.pc | 1)
    chip.core.pc = function


@pytest.mark.parametrize("fault", ["panic", "hard fault", "nmi", "stray interrupt"])
def test_each_fault_turns_the_outputs_off_at_once(fault, expected, figures):
    chip, spec = driving(expected)
    chip.run_until(lambda: not chip.core.active and not chip.core.sleeping, 0.01, "thread mode")
    if fault == "panic":
        # An index out of range in a task: core::panicking::panic_bounds_check(index, len, location).
        call(chip, symbol_ending(chip, "9panicking18panic_bounds_check"), 5, 3, chip.image.symbols["__sdata"])
    elif fault == "hard fault":
        chip.core.enter_fault("a bus fault injected by the test", chip.core.pc)
    elif fault == "nmi":
        chip.core.pend(NMI)
    else:
        # WWDG's interrupt, which the image never enables: enabled and pended as a wild write would.
        chip.nvic.enabled.add(IRQ0 + 0)
        chip.nvic.set_pending(IRQ0 + 0)
    took = stops_within(chip)
    assert took <= STOP_WITHIN, f"{fault}: {took} instructions to turn the outputs off"
    figures[f"thruster: {fault} to outputs off"] = f"{took} instructions"
    assert all_off(chip, spec), f"{fault}: {switches(chip, spec)}"
    chip.run_for(0.01)
    assert not chip.tim1.moe()
    assert all_off(chip, spec), f"{fault}: {switches(chip, spec)}"
    if fault == "panic":
        # The log says where (here the test's made-up location): the bounds check's message has arguments, which
        # the image does not format.
        assert any("panicked at " in text for _, text in chip.log.lines), chip.log_text()


def test_a_lockup_turns_the_outputs_off_through_the_system_break(expected):
    """A fault while a fault handler is active locks the core up (ARMv7-M B1.5.15): no handler runs again. The
    image routes the core's LOCKUP output to TIM1's system break (SYSCFG_CFGR2.CLL), which alone can stop the
    bridge then."""
    chip, spec = driving(expected)
    chip.run_until(lambda: not chip.core.active and not chip.core.sleeping, 0.01, "thread mode")
    chip.core.enter_fault("a bus fault injected by the test", chip.core.pc)
    # A second one before the HardFault handler has run an instruction: its outputs-off store never happens.
    chip.core.enter_fault("a fault in the fault handler", chip.core.pc)
    assert chip.core.fault and chip.core.fault.startswith("lockup"), chip.core.fault
    assert not chip.tim1.off_writes, "the handler ran"
    assert chip.tim1.regs[0x10] & (1 << 13), "SBIF"
    assert all_off(chip, spec), f"a lockup left a switch on: {switches(chip, spec)}"


def test_a_hung_task_lets_the_watchdog_reset_and_the_latch_survives_it_but_not_a_power_cycle(expected):
    chip, spec = start("thruster-fw", expected, water="wet")
    status, _, _ = exchange(chip, spec, expected["orders"]["SeaBotix"]["0"])
    assert status[2] & 0x18 == 0x18, status.hex()  # GROUND and WATER, latched until a power cycle
    # The sampling task hangs: ADC1 never ends a conversion, the health task stops feeding the watchdog.
    chip.adc1.inputs.clear()
    chip.adc1.stuck = True
    timeout = spec["watchdog_timeout_us"] / 1e6
    chip.run_until(lambda: chip.resets, timeout * 1.2, "a watchdog reset")
    assert chip.resets[-1][1] == "watchdog"
    # After the reset the sensor is dry and the ADC works again: the latch still says ground fault.
    chip.adc1.stuck = False
    set_analog(chip, spec)
    chip.run_until(chip.idle, 0.05, "idle after the watchdog reset")
    assert any("independent watchdog" in text for _, text in chip.log.lines), chip.log_text()
    chip.run_for(0.01)
    status, _, _ = exchange(chip, spec, expected["orders"]["SeaBotix"]["0"])
    assert status[2] & 0x08, f"the ground fault was lost in a watchdog reset: {status.hex()}"
    # A power cycle clears it.
    chip.power_on()
    set_analog(chip, spec)
    chip.run_until(chip.idle, 0.05, "idle after the power cycle")
    chip.run_for(0.01)
    status, _, _ = exchange(chip, spec, expected["orders"]["SeaBotix"]["0"])
    assert status[2] & 0x18 == 0, status.hex()
