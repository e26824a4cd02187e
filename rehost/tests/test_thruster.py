"""The thruster image answers on its modelled I2C3 in its family's protocol, and its bridge follows the halls."""

import pytest

from conftest import rehost
from g431.timers import CCER, CCMR1, CCMR2
from thruster import SWITCHES, all_off, exchange, set_halls, start, switches

FAMILIES = {"thruster-fw": "seabotix", "thruster-fw-legacy": "legacy"}


@pytest.mark.parametrize("name", list(FAMILIES))
def test_an_order_is_taken_and_the_status_is_tmc_protos_encoding(name, expected):
    chip, spec = start(name, expected)
    family = spec["family"]
    status, written, read = exchange(chip, spec, expected["orders"][family]["0"])
    decoded = rehost("status", FAMILIES[name], status.hex())
    # The full form with MT first, byte for byte what tmc-proto encodes for the fields it carries.
    assert decoded["form"] == "Full" and decoded["canonical"], decoded
    assert decoded["fields"]["faults"] == 0, decoded
    if family == "SeaBotix":
        assert decoded["fields"]["rpm"] == 0 and decoded["fields"]["temperature_c"] == 25, decoded
    # The reply was ready: the slave stretched SCL only while embassy set up its DMA.
    assert read.longest_stretch_us < 1000, read.longest_stretch_us


@pytest.mark.parametrize("name", list(FAMILIES))
def test_a_bad_checksum_is_refused_and_counted_without_a_change(name, expected):
    chip, spec = start(name, expected)
    order = list(expected["orders"][spec["family"]]["25"])
    order[-1] ^= 0xFF
    status, _, _ = exchange(chip, spec, order)
    decoded = rehost("status", FAMILIES[name], status.hex())
    assert decoded["canonical"] and decoded["fields"]["faults"] == 0
    chip.run_for(0.05)
    # Refused: every step the bridge took since is the coast it started in.
    coast = (spec["coast"]["ccmr1"], spec["coast"]["ccmr2"], spec["coast"]["ccer"])
    assert {entry[1:] for entry in chip.tim1.com_log} == {coast}


def test_water_is_reported(expected):
    chip, spec = start("thruster-fw", expected, water="wet")
    status, _, _ = exchange(chip, spec, expected["orders"]["SeaBotix"]["0"])
    decoded = rehost("status", "seabotix", status.hex())
    assert decoded["fields"]["faults"] & 0x10, decoded  # WATER is FAULT bit 4 (IDS 8.4.2)


def test_hall_edges_walk_the_six_step_sequence_and_a_zero_order_stops_it(expected):
    chip, spec = start("thruster-fw", expected)
    forward = spec["forward"]
    set_halls(chip, forward[0]["hall"])
    chip.run_for(0.005)
    exchange(chip, spec, expected["orders"]["SeaBotix"]["63"])
    # The speed loop's target ramps to full speed in 0.5 s (`SpeedConfig::ramp_per_s`): after 0.25 s it is ahead
    # of a rotor turning a sector every 4 ms, so the loop keeps driving (it lets a rotor faster than its target
    # coast), and the 400 ms stall window has not run out.
    chip.run_for(0.25)
    seen = []
    for step in forward + forward[:3]:
        set_halls(chip, step["hall"])
        chip.run_for(0.004)
        active = chip.tim1.active
        seen.append(((active[CCMR1], active[CCMR2], active[CCER]), switches(chip, spec), step))
    wrong = [f"hall {step['hall']:03b}: {got}, not {step['drive']}" for got, _, step in seen
             if got != (step["drive"]["ccmr1"], step["drive"]["ccmr2"], step["drive"]["ccer"])]
    assert not wrong, "\n".join(wrong)
    # And what the gate pins do, from the timer's output logic rather than the registers g431-hw computes.
    wrong = [f"hall {step['hall']:03b}: {gates}, not {step['phases']}" for _, gates, step in seen
             if gates != {phase: SWITCHES[drive] for phase, drive in zip("ABC", step["phases"])}]
    assert not wrong, "\n".join(wrong)
    assert chip.tim1.moe()
    exchange(chip, spec, expected["orders"]["SeaBotix"]["0"])
    # A zero order ramps the target down at the same slew (full scale in 0.5 s), then the bridge coasts.
    chip.run_for(0.55)
    coast = spec["coast"]
    active = chip.tim1.active
    assert (active[CCMR1], active[CCMR2], active[CCER]) == (coast["ccmr1"], coast["ccmr2"], coast["ccer"])
    assert all_off(chip, spec), switches(chip, spec)
