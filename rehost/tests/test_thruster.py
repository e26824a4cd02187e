"""The thruster image answers on its modelled I2C3 in its family's protocol, and its bridge follows the halls."""

import pytest

from conftest import rehost
from g431.timers import CCER, CCMR1, CCMR2
from thruster import CURRENTS, SWITCHES, all_off, channels, exchange, set_halls, set_shunts, start, switches

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


def sequence_starts(chip, since):
    """The cycles at which ADC1's injected sequences began since `since`."""
    return [c.start for c in chip.adc1.conversions if c.group == "injected" and c.rank == 0 and c.start >= since]


def assert_no_edge_near(chip, starts):
    """The switching phase (PWM mode 1 in the active CCMR) keeps one level a quarter period either side of each of
    `starts`: no switching edge near the conversions. Looked at in steps of 8 timer ticks, with the compare values
    of now (so only for recent starts)."""
    switching = [n for n in range(3) if chip.tim1._output_mode(n) == 0b0110]
    assert len(switching) == 1, chip.tim1.outputs()
    window = chip.tim1.regs[0x2C] // 2 - 8
    for start in starts:
        level = chip.tim1.reference_at(switching[0], start)
        near = [tick for tick in range(-window, window + 1, 8)
                if chip.tim1.reference_at(switching[0], start + tick) != level]
        assert not near, f"an edge {near[0]} ticks from the conversions at cycle {start}"


def test_the_phase_currents_are_converted_at_tim1s_trigger_away_from_the_edges(expected):
    """ADC1 converts the three shunts when TIM1's trigger fires, once per PWM period, at an instant where the
    switching phase's nearest edge is a quarter period away or more; the status reports the current the shunt of
    the phase held low carries. A rotor held in one sector, so the speed loop's duty climbs through 50 % (where the
    instant moves from just after the top of the period to just before the bottom) within the run."""
    chip, spec = start("thruster-fw", expected)
    set_halls(chip, spec["forward"][0]["hall"])
    set_shunts(chip, spec, amps=3.0)
    exchange(chip, spec, expected["orders"]["SeaBotix"]["63"])
    begin = chip.core.cycles
    arr = chip.tim1.regs[0x2C]
    instants = set()
    for _ in range(30):
        since = chip.core.cycles
        chip.run_for(0.01)
        recent = sequence_starts(chip, since)[-5:]
        assert_no_edge_near(chip, recent)
        instants |= {chip.tim1.counting_at(start) for start in recent}
    assert instants == {(arr - 1, True), (1, True)}, instants
    status, _, _ = exchange(chip, spec, expected["orders"]["SeaBotix"]["63"])
    decoded = rehost("status", "seabotix", status.hex())
    assert decoded["fields"]["current_deciamps"] == 30, decoded

    injected = [c for c in chip.adc1.conversions if c.group == "injected" and c.start >= begin]
    channel_of = channels(spec)
    assert {(c.rank, c.channel) for c in injected} == {(n, channel_of[f]) for n, f in enumerate(CURRENTS)}
    period = round(chip.core.hz / 20_000)
    starts = sequence_starts(chip, begin)
    gaps = [b - a for a, b in zip(starts, starts[1:])]
    # One PWM period apart (within a cycle of the model's rounding), but once, as the duty passes 50 %: the
    # instant moves from just after the top (ARR - 1, counting down) to just before the bottom (1).
    moves = [gap for gap in gaps if abs(gap - period) > 1]
    assert moves == [period + arr - 2], f"sequences {sorted(set(gaps))} cycles apart, period {period}"
