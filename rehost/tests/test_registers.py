"""After start-up the peripheral registers hold what g431-hw computes, and the pins are set up as
`g431_hw::images` describes them, no other pin touched (RM0440 7.4, 9.4, 28, 37, 42, 44)."""

import pytest

from conftest import ALL, THRUSTERS, boot
from g431.core import IRQ0
from g431.timers import CCER, CCMR1, CCMR2


@pytest.fixture(scope="module")
def booted():
    return {}


def chip_for(name, booted):
    if name not in booted:
        chip = boot(name)
        chip.run_for(0.005)  # past the first update events (TIM1's outputs come on at one)
        booted[name] = chip
    return booted[name]


@pytest.mark.parametrize("name", ALL)
def test_registers_equal_what_g431_hw_computes(name, expected, booted):
    chip = chip_for(name, booted)
    wrong = []
    for register in expected["images"][name]["registers"]:
        value = chip.peek(register["address"]) & register["mask"]
        if value != register["value"]:
            wrong.append(f"{register['name']}: {value:#x}, not {register['value']:#x} ({register['source']})")
    assert not wrong, "\n".join(wrong)


@pytest.mark.parametrize("name", ALL)
def test_pins_are_set_up_as_described_and_no_other_is_touched(name, expected, booted):
    chip = chip_for(name, booted)
    wrong = []
    listed = set()
    for pin in expected["images"][name]["pins"]:
        listed.add((pin["port"], pin["pin"]))
        state = chip.gpio[pin["port"]].pin_state(pin["pin"])
        want = {"mode": pin["mode"], "pull": pin["pull"], "open_drain": pin["open_drain"]}
        if pin["mode"] == "alternate":
            want["af"] = pin["af"]
        if pin["mode"] == "output":
            want["level"] = pin["level"]
        got = {**state, "level": chip.gpio[pin["port"]].level(pin["pin"])}
        got = {key: got[key] for key in want}
        if got != want:
            wrong.append(f"P{pin['port']}{pin['pin']} ({pin['function']}): {got}, not {want}")
    for letter, port in chip.gpio.items():
        for number in sorted(port.changed_pins()):
            if (letter, number) not in listed:
                wrong.append(f"P{letter}{number} is changed from its reset state, but no image table lists it")
    assert not wrong, "\n".join(wrong)


# RM0440 Table 97: the interrupts the images' descriptions name, by position.
IRQ_POSITION = {"UART4": 52}


@pytest.mark.parametrize("name", ALL)
def test_interrupts_run_at_the_priority_described(name, expected, booted):
    chip = chip_for(name, booted)
    for interrupt in expected["images"][name]["interrupts"]:
        position = IRQ_POSITION[interrupt["name"]]
        vector = IRQ0 + position
        # The position is the one the image's own vector table gives the handler of that name.
        assert chip.core.read32(chip.core.vtor + 4 * vector) | 1 == chip.image.symbols[interrupt["name"]] | 1
        # The NVIC keeps the upper four bits of IPRn's byte (RM0440 16.1: 16 levels).
        got = chip.nvic.priority(vector) >> 4
        assert got == interrupt["priority"], f"{interrupt['name']} at level {got}, not {interrupt['priority']}"


@pytest.mark.parametrize("name", [n for n in THRUSTERS if n != "thruster-fw-motorless"])
def test_the_bridge_coasts_with_the_outputs_armed(name, expected, booted):
    chip = chip_for(name, booted)
    coast = expected["images"][name]["coast"]
    active = chip.tim1.active
    assert (active[CCMR1], active[CCMR2], active[CCER]) == (coast["ccmr1"], coast["ccmr2"], coast["ccer"])
    assert chip.tim1.moe(), "the outputs never came on (BDTR.MOE after the first update event)"


def test_the_motorless_image_leaves_tim1_alone(booted):
    chip = chip_for("thruster-fw-motorless", booted)
    assert not chip.tim1.writes


@pytest.mark.parametrize("name", THRUSTERS)
def test_each_conversion_uses_the_sample_time_g431_hw_computes(name, expected, booted):
    chip = chip_for(name, booted)
    spec = expected["images"][name]
    wanted = {}
    for pin in spec["pins"]:
        if pin["mode"] == "analog":
            function = pin["function"]
            kind = {"water sensor": "water", "supply voltage": "vbus"}.get(
                function, "current" if function.endswith("current") else "ntc")
            wanted[pin["adc1_in"]] = spec["sample_times"][kind]
    seen = {}
    for conversion in chip.adc1.conversions:
        seen.setdefault(conversion.channel, set()).add(conversion.smp)
    assert set(seen) == set(wanted), f"channels converted {sorted(seen)}, listed {sorted(wanted)}"
    # The motor-less image's water pin may also see the current's short sample time: the ES0431 throw-away
    # conversion before each reading, whose result is dropped.
    throwaway = {spec["sample_times"]["current"]} if name.endswith("motorless") else set()
    wrong = [f"ADC1_IN{c}: SMPR {sorted(seen[c])}, not {wanted[c]}" for c in wanted
             if wanted[c] not in seen[c] or seen[c] - {wanted[c]} - throwaway]
    assert not wrong, "\n".join(wrong)
