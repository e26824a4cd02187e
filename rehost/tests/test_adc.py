"""ADC1 and TIM1's trigger outputs at register level (RM0440 21, 28): no image, a chip that sleeps in WFE while the
test writes its registers and lets time pass. The clocks are those both images set: SYSCLK 170 MHz from the PLL,
ADC12SEL = SYSCLK, ADC12_CCR CKMODE 0 and PRESC /4, an ADC clock of 42.5 MHz: four core cycles an ADC cycle."""

import math

import pytest

from conftest import Blank
from g431 import adc, system, timers
from g431.chip import Stm32g4
from g431.core import G431RB, G474RE

PER_ADC_CYCLE = 4  # 170 MHz / 42.5 MHz
SAMPLE = dict(enumerate(adc.SAMPLE_CYCLES))


@pytest.fixture(params=[G431RB, G474RE], ids=lambda part: part.name)
def chip(request):
    chip = Stm32g4(Blank(request.param))
    rcc = chip.rcc
    # HSI16 / 4 * 85 / 2 = 170 MHz, PLLR enabled (bit 24); PLLP enabled too, unused here.
    rcc.write(system.PLLCFGR, 2 | 3 << 4 | 85 << 8 | 1 << 16 | 1 << 24)
    rcc.write(system.CR, rcc.reg(system.CR) | 1 << 24)
    # Range 1 boost mode, then SYSCLK to the PLL at AHB /2 (RM0440 6.1.5); HCLK stays at 85 MHz, which the ADC's
    # kernel clock (SYSCLK) does not see.
    chip.pwr.write(system.PWR_CR5, 0)
    rcc.write(system.CFGR, 3 | 0b1000 << 4)
    rcc.write(system.CCIPR, 2 << 28)  # ADC12SEL = SYSCLK
    chip.adc_common.write(adc.CCR, 2 << 18)  # CKMODE 0, PRESC /4
    chip.adc1.write(adc.CR, adc.ADVREGEN)
    chip.adc1.write(adc.CR, adc.ADVREGEN | adc.ADEN)
    assert chip.adc1.clock_hz() == 42_500_000
    return chip


def run_to(chip, cycle):
    """Time passes through `cycle`: the events due then have happened."""
    chip.core.run(until_cycle=cycle + 1)
    assert chip.core.fault is None, chip.core.fault


def start(chip, bits):
    chip.adc1.write(adc.CR, chip.adc1.reg(adc.CR) | bits)


def ramp(seconds):
    """An input rising one code every 10 ns: its value tells the instant it was taken."""
    return int(seconds * 1e8) % 4096


@pytest.mark.parametrize("smp", [0b000, 0b010, 0b111])
def test_a_software_regular_conversion_ends_after_smp_plus_12_5_adc_cycles(chip, smp):
    a = chip.adc1
    a.write(adc.SMPR2, smp << 3 * 1)  # channel 11
    a.write(adc.SQR1, 11 << 6)
    a.inputs[11] = ramp
    begin = chip.core.cycles
    start(chip, adc.ADSTART)
    end = begin + math.ceil((SAMPLE[smp] + 12.5) * PER_ADC_CYCLE)
    run_to(chip, end - 1)
    assert not a.reg(adc.ISR) & (adc.EOC | adc.EOS), "converted before SMP + 12.5 ADC cycles"
    assert a.reg(adc.CR) & adc.ADSTART
    run_to(chip, end)
    assert a.reg(adc.ISR) & (adc.EOC | adc.EOS) == adc.EOC | adc.EOS
    assert not a.reg(adc.CR) & adc.ADSTART, "ADSTART cleared at EOS (single mode, software start)"
    (conversion,) = a.conversions
    sampled = begin + math.ceil(SAMPLE[smp] * PER_ADC_CYCLE)
    assert (conversion.start, conversion.cycle, conversion.end) == (begin, sampled, end)
    assert a.read(adc.DR) == ramp(sampled / chip.core.hz)
    assert not a.reg(adc.ISR) & adc.EOC, "reading DR clears EOC"


def test_a_regular_sequence_converts_rank_by_rank(chip):
    a = chip.adc1
    a.write(adc.SMPR1, 0b001 << 3 * 3 | 0b100 << 3 * 5)  # channel 3: 6.5 cycles, channel 5: 47.5
    a.write(adc.SQR1, 2 | 5 << 6 | 3 << 12 | 5 << 18)  # L = 2: channels 5, 3, 5
    a.inputs[3], a.inputs[5] = 100, ramp
    begin = chip.core.cycles
    start(chip, adc.ADSTART)
    first = begin + (47.5 + 12.5) * PER_ADC_CYCLE
    run_to(chip, first)
    assert a.reg(adc.ISR) & (adc.EOC | adc.EOS) == adc.EOC
    a.read(adc.DR)
    run_to(chip, first + (6.5 + 12.5) * PER_ADC_CYCLE)
    assert a.reg(adc.ISR) & (adc.EOC | adc.EOS) == adc.EOC and a.read(adc.DR) == 100
    run_to(chip, first + (6.5 + 12.5 + 47.5 + 12.5) * PER_ADC_CYCLE)
    assert a.reg(adc.ISR) & adc.EOS and not a.reg(adc.CR) & adc.ADSTART
    assert [(c.channel, c.rank) for c in a.conversions] == [(5, 0), (3, 1), (5, 2)]
    assert a.read(adc.DR) == ramp(a.conversions[2].cycle / chip.core.hz)


def test_a_software_injected_start_converts_once(chip):
    a = chip.adc1
    a.write(adc.SMPR1, 0b011 << 3 * 1 | 0b000 << 3 * 2)  # 24.5 and 2.5 cycles
    a.write(adc.JSQR, 1 | 1 << 9 | 2 << 15)  # JL = 1: channels 1, 2; JEXTEN = 00
    a.inputs[1], a.inputs[2] = 111, 222
    begin = chip.core.cycles
    start(chip, adc.JADSTART)
    middle = begin + (24.5 + 12.5) * PER_ADC_CYCLE
    run_to(chip, middle)
    assert a.reg(adc.ISR) & (adc.JEOC | adc.JEOS) == adc.JEOC and a.reg(adc.CR) & adc.JADSTART
    run_to(chip, middle + (2.5 + 12.5) * PER_ADC_CYCLE + 1)
    assert a.reg(adc.ISR) & adc.JEOS and not a.reg(adc.CR) & adc.JADSTART, "JADSTART cleared at JEOS"
    assert (a.reg(adc.JDR[0]), a.reg(adc.JDR[1])) == (111, 222)
    run_to(chip, chip.core.cycles + 10_000)
    assert len(a.conversions) == 2, "converted once"


def test_an_injected_start_pre_empts_a_regular_conversion_which_starts_again_after_it(chip):
    a = chip.adc1
    a.write(adc.SMPR1, 0b111 << 3 * 4 | 0b010 << 3 * 6)  # channel 4: 640.5 cycles, channel 6: 12.5
    a.write(adc.SQR1, 4 << 6)
    a.write(adc.JSQR, 6 << 9)
    begin = chip.core.cycles
    start(chip, adc.ADSTART)
    run_to(chip, begin + 1000)
    at = chip.core.cycles  # the regular conversion is in its sampling phase
    start(chip, adc.JADSTART)
    run_to(chip, at + 100 + 2612)
    regular = [c for c in a.conversions if c.group == "regular"]
    injected = [c for c in a.conversions if c.group == "injected"]
    assert [(c.start, c.end) for c in injected] == [(at, at + 100)]
    assert [(c.start, c.end) for c in regular] == [(at + 100, at + 100 + 2612)], "the regular one from its start"
    assert a.reg(adc.ISR) & (adc.JEOS | adc.EOS) == adc.JEOS | adc.EOS


def configure_tim1(chip, arr, psc, ccr4, mms2=0b0111, oc4m=0b0110, cms=0b01):
    """TIM1 centre-aligned (CMS), OC4M and OC4PE on channel 4 (its pin unused: CC4E clear), TRGO2 per MMS2."""
    t = chip.tim1
    t.write(timers.ARR, arr)
    t.write(timers.PSC, psc)
    t.write(timers.CCMR2, (oc4m & 7) << 12 | (oc4m >> 3) << 24 | 1 << 11)
    t.write(timers.CCR4, ccr4)
    t.write(timers.CR2, mms2 << 20)
    t.write(timers.EGR, timers.UG)
    return t


def test_injected_sequences_on_trgo2_oc4ref_start_where_the_down_count_passes_ccr4(chip):
    arr, psc, ccr4 = 2125, 1, 400  # 20 kHz: 2 * 2125 ticks of 2 cycles
    t = configure_tim1(chip, arr, psc, ccr4)
    a = chip.adc1
    a.write(adc.SMPR1, 0b001 << 3 * 1 | 0b011 << 3 * 2)  # channel 1: 6.5 cycles, channel 2: 24.5
    a.write(adc.JSQR, 1 | 8 << 2 | 0b01 << 7 | 1 << 9 | 2 << 15)  # JL = 1, JEXTSEL 8 TIM1_TRGO2, rising
    a.inputs[1] = a.inputs[2] = ramp
    start(chip, adc.JADSTART)
    run_to(chip, chip.core.cycles + 50_000)
    assert not a.conversions, "TIM1 stopped (CEN = 0): no trigger"
    origin = chip.core.cycles
    t.write(timers.CR1, 0b01 << 5 | 1)  # CMS = 01, CEN
    tick, period = psc + 1, 2 * arr * (psc + 1)
    run_to(chip, origin + 5 * period)
    starts = [c.start for c in a.conversions if c.rank == 0]
    # OC4REF (PWM mode 1) goes active counting down at CNT = CCR4: (2 * ARR - CCR4) ticks into each period.
    assert starts == [origin + (2 * arr - ccr4) * tick + n * period for n in range(5)]
    for conversion in a.conversions:
        offset = {1: 6.5, 2: 24.5}[conversion.channel] * PER_ADC_CYCLE
        assert conversion.cycle == conversion.start + math.ceil(offset)
        assert conversion.value == ramp(conversion.cycle / chip.core.hz), "taken at the end of its sampling"
    assert a.conversions[1].start == a.conversions[0].end, "rank 2 follows rank 1"
    assert a.reg(adc.CR) & adc.JADSTART, "a hardware trigger leaves JADSTART set"
    # The counter agrees: at the last trigger, down at CCR4; a tick before, at CCR4 + 1.
    last = starts[-1] + period
    run_to(chip, last - tick)
    assert t.counter() == ccr4 + 1
    run_to(chip, last)
    assert t.counter() == ccr4
    run_to(chip, last + 1000)
    assert [c.start for c in a.conversions if c.rank == 0][-1] == last


def test_ccr4_with_preload_moves_the_trigger_at_the_next_update_event(chip):
    arr, ccr4 = 1000, 300
    t = configure_tim1(chip, arr, 0, ccr4)
    a = chip.adc1
    a.write(adc.JSQR, 8 << 2 | 0b01 << 7 | 3 << 9)
    start(chip, adc.JADSTART)
    origin = chip.core.cycles
    t.write(timers.CR1, 0b01 << 5 | 1)
    run_to(chip, origin + 500)  # counting up
    t.write(timers.CCR4, 700)  # preloaded: takes effect at the overflow (CNT = ARR), an update event
    run_to(chip, origin + 2 * 2 * arr)
    assert [c.start for c in a.conversions] == [origin + 2 * arr - 700, origin + 4 * arr - 700]


def test_a_trigger_during_an_injected_sequence_is_ignored(chip):
    arr = 1000
    configure_tim1(chip, arr, 0, 500)
    a = chip.adc1
    a.write(adc.SMPR1, 0b111 << 3)  # channel 1: 640.5 cycles
    a.write(adc.JSQR, 0b01 | 8 << 2 | 0b01 << 7 | 1 << 9 | 1 << 15)  # two conversions: 1306 cycles, 5224 core
    start(chip, adc.JADSTART)
    origin = chip.core.cycles
    chip.tim1.write(timers.CR1, 0b01 << 5 | 1)
    run_to(chip, origin + 6 * 2 * arr)
    starts = [c.start for c in a.conversions if c.rank == 0]
    first = origin + 2 * arr - 500
    assert starts == [first, first + 3 * 2 * arr]
    assert [cycle for cycle, _ in a.ignored_triggers] == [first + 2 * arr, first + 2 * 2 * arr, first + 4 * 2 * arr,
                                                          first + 5 * 2 * arr]


def test_trgo_update_events_trigger_at_every_under_and_overflow(chip):
    arr = 800
    t = configure_tim1(chip, arr, 0, 0)
    t.write(timers.CR2, 0b010 << 4)  # MMS = update
    a = chip.adc1
    a.write(adc.JSQR, 0 << 2 | 0b01 << 7)  # JEXTSEL 0: TIM1_TRGO
    start(chip, adc.JADSTART)
    origin = chip.core.cycles
    t.write(timers.CR1, 0b11 << 5 | 1)
    run_to(chip, origin + 4 * arr + 100)
    assert [c.start for c in a.conversions] == [origin + n * arr for n in range(1, 5)]


def test_edge_aligned_pwm_mode_2_on_oc4ref(chip):
    arr, ccr4 = 999, 250
    t = configure_tim1(chip, arr, 0, ccr4, oc4m=0b0111)
    a = chip.adc1
    a.write(adc.JSQR, 8 << 2 | 0b01 << 7)
    start(chip, adc.JADSTART)
    origin = chip.core.cycles
    t.write(timers.CR1, 1)  # edge-aligned, up: PWM mode 2 goes active at CNT = CCR4
    run_to(chip, origin + 3 * (arr + 1))
    assert [c.start for c in a.conversions] == [origin + ccr4 + n * (arr + 1) for n in range(3)]


def expect_failure(chip, words):
    assert chip.core.fault is not None, "no failure"
    assert all(word in chip.core.fault for word in words), chip.core.fault


def test_smpr_written_while_converting_fails(chip):
    chip.adc1.write(adc.SMPR1, 0b111)
    start(chip, adc.ADSTART)
    chip.adc1.write(adc.SMPR1, 0)
    expect_failure(chip, ["SMPR1", "ADSTART"])


def test_sqr_written_while_adstart_is_set_fails(chip):
    chip.adc1.write(adc.SMPR1, 0b111)
    start(chip, adc.ADSTART)
    chip.adc1.write(adc.SQR3, 1)
    expect_failure(chip, ["SQR3", "ADSTART"])


def test_jsqr_written_while_jadstart_is_set_fails(chip):
    chip.adc1.write(adc.JSQR, 8 << 2 | 0b01 << 7)
    start(chip, adc.JADSTART)
    chip.adc1.write(adc.JSQR, 0)
    expect_failure(chip, ["JSQR", "JADSTART"])


@pytest.mark.parametrize("bits", [adc.ADSTART, adc.JADSTART])
def test_a_start_with_the_adc_disabled_fails(chip, bits):
    chip.adc1.write(adc.CR, chip.adc1.reg(adc.CR) | adc.ADDIS)
    assert not chip.adc1.reg(adc.CR) & adc.ADEN
    start(chip, bits)
    expect_failure(chip, ["not enabled"])


@pytest.mark.parametrize("group, register, value, words", [
    ("injected", adc.JSQR, 2 << 2 | 0b01 << 7, ["JEXTSEL 2", "TIM2_TRGO"]),
    ("injected", adc.JSQR, 1 << 2 | 0b11 << 7, None),  # TIM1_CC4: modelled
    ("regular", adc.CFGR, adc.JQDIS | 3 << 5 | 0b01 << 10, ["EXTSEL 3", "TIM2_CC2"]),
])
def test_a_trigger_no_model_produces_fails_when_armed(chip, group, register, value, words):
    chip.adc1.write(register, value)
    start(chip, adc.ADSTART if group == "regular" else adc.JADSTART)
    if words is None:
        assert chip.core.fault is None, chip.core.fault
    else:
        expect_failure(chip, words)


def test_a_trgo2_mode_the_timer_model_lacks_fails_when_armed(chip):
    configure_tim1(chip, 1000, 0, 300, mms2=0b1000)  # OC5REF
    chip.adc1.write(adc.JSQR, 8 << 2 | 0b01 << 7)
    start(chip, adc.JADSTART)
    expect_failure(chip, ["TRGO2", "not modelled"])
