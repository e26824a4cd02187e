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
        # The log says it panicked; where is probe-rs's backtrace's (the handler reads nothing of the panic, so the
        # image keeps no location or message for it).
        assert ("error", "panicked") in chip.log.lines, chip.log_text()


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


# DBGMCU (RM0440 47.16): DBGMCU_APB2FZR's DBG_TIM1_STOP, DBGMCU_APB1FZR1's DBG_IWDG_STOP.
APB1FZR1, APB2FZR = 0xE004_2008, 0xE004_2010
DBG_TIM1_STOP, DBG_IWDG_STOP = 1 << 11, 1 << 12
TIM1_SR, SBIF = 0x4001_2C10, 1 << 13
FLASH_ECCR, ECCD, SYSCFG_CFGR2, ECCL = 0x4002_2018, 1 << 31, 0x4001_001C, 1 << 3


def test_a_debug_halt_stops_tim1_and_turns_every_switch_off_until_the_core_runs_again(expected):
    """RM0440 28.3 "Debug mode": with DBG_TIM1_STOP set, a halted core stops TIM1's counter and disables its
    outputs as if MOE were reset: OSSI = 1 takes them to their idle levels, every switch off."""
    chip, spec = driving(expected)
    assert chip.peek(APB2FZR) & DBG_TIM1_STOP, "the image leaves TIM1 running under a debugger"
    chip.halt()
    assert all_off(chip, spec), f"halted: {switches(chip, spec)}"
    count, instructions = chip.tim1.counter(), chip.core.instructions
    chip.run_for(0.02)
    assert chip.core.instructions == instructions, "the core ran while halted"
    assert chip.tim1.counter() == count, "TIM1 counted while halted"
    assert chip.tim1.moe(), "a halt disables the outputs as if MOE were reset: the bit itself stays"
    assert all_off(chip, spec), f"halted: {switches(chip, spec)}"
    chip.resume()
    chip.run_for(0.005)
    assert chip.core.instructions > instructions
    assert chip.tim1.counter() != count or chip.tim1.counting_at(chip.core.cycles + 1000) != (count, False)
    assert not all_off(chip, spec), f"resumed: {switches(chip, spec)}"
    assert "pwm" in {state for pair in switches(chip, spec).values() for state in pair}, switches(chip, spec)


def test_without_dbg_tim1_stop_a_halt_leaves_the_bridge_switching(expected):
    """The image's choice matters: the freeze bit cleared (as a debugger might write it), a halted core leaves TIM1
    counting and its outputs driving the last step (RM0440 28.3 "Debug mode": "continues to work normally")."""
    chip, spec = driving(expected)
    chip.core.bus_write(APB2FZR, 4, chip.peek(APB2FZR) & ~DBG_TIM1_STOP)
    chip.halt()
    before = switches(chip, spec)
    assert not all_off(chip, spec), before
    seen = set()
    for _ in range(10):
        chip.run_for(0.000_013)  # not a multiple of the PWM period
        seen.add(chip.tim1.counter())
        assert switches(chip, spec) == before
    assert len(seen) > 1, f"TIM1's counter stood still while halted without DBG_TIM1_STOP: {seen}"
    assert "pwm" in {state for pair in before.values() for state in pair}, before


@pytest.mark.parametrize("freeze", [True, False], ids=["image's DBG_IWDG_STOP", "DBG_IWDG_STOP cleared"])
def test_the_watchdog_stops_during_a_long_halt_with_the_images_setting(freeze, expected):
    """RM0440 42.3 "Debug mode": with DBG_IWDG_STOP set the watchdog's counter stops while the core is halted, so a
    halt far longer than its timeout resets nothing; cleared, the watchdog bites during the halt."""
    chip, spec = driving(expected)
    assert chip.peek(APB1FZR1) & DBG_IWDG_STOP, "the image lets the watchdog run under a debugger"
    if not freeze:
        chip.core.bus_write(APB1FZR1, 4, chip.peek(APB1FZR1) & ~DBG_IWDG_STOP)
    timeout = spec["watchdog_timeout_us"] / 1e6
    chip.halt()
    left = chip.iwdg.counter()
    chip.run_for(timeout * 3)
    if not freeze:
        assert chip.resets and chip.resets[-1][1] == "watchdog", chip.resets
        return
    assert not chip.resets, chip.resets
    assert chip.iwdg.counter() == left
    chip.resume()
    resumed = chip.core.cycles
    chip.run_for(timeout * 2)
    assert not chip.resets, chip.resets
    assert chip.iwdg.refreshes[-1][0] > resumed, "the image does not feed the watchdog after the halt"


def test_a_flash_ecc_double_error_turns_the_outputs_off_through_the_system_break(expected):
    """RM0440 3.3.4: a read with two bit errors sets FLASH_ECCR.ECCD and raises the NMI; with SYSCFG_CFGR2.ECCL set
    (9.2.5) it is also a system break source of TIM1 (28.3.19): MOE clears and SBIF sets in hardware, before any
    handler runs. An error in the image's code: the NMI handler stops the bridge and waits for the watchdog."""
    chip, spec = driving(expected)
    assert chip.peek(SYSCFG_CFGR2) & ECCL, "the image does not route ECC double errors to TIM1's break"
    chip.run_until(lambda: not chip.core.active and not chip.core.sleeping, 0.01, "thread mode")
    address = chip.core.pc & ~7
    chip.flash_interface.inject_ecc_double(address)
    chip.run_until(lambda: chip.flash_interface.ecc_errors, 0.001, "the double word fetched")
    assert chip.peek(TIM1_SR) & SBIF, "SBIF"
    assert not chip.tim1.moe()
    assert all_off(chip, spec), f"an ECC double error left a switch on: {switches(chip, spec)}"
    assert chip.peek(FLASH_ECCR) == ECCD | (address - 0x0800_0000), hex(chip.peek(FLASH_ECCR))
    chip.run_for(0.01)
    assert 2 in chip.core.active, "the NMI handler is not running"  # it stops the bridge and waits (NMI = 2)
    assert chip.peek(TIM1_SR) & SBIF and not chip.tim1.moe()
    assert all_off(chip, spec), switches(chip, spec)
    assert not chip.resets
