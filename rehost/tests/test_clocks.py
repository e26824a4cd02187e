"""The switch to 170 MHz in RM0440's order (6.1.5, 7.2.7), and time that still runs right after it: the RCC model
records every RCC_CFGR write and stops a run that switches SYSCLK above 80 MHz at AHB /1 in boost mode, raises
HPRE back to /1 within 1 us of that switch, or runs HCLK above 150 MHz in range 1 normal mode (`g431/system.py`)."""

import pytest

from conftest import ALL, boot, image
from g431.chip import Stm32g4
from g431.system import CFGR, CR, PLLCFGR, PWR_CR5

# The clocks the images run at (g431_hw::clock): HCLK = SYSCLK, PCLK1 = PCLK2 = 85 MHz, the timers at 2 x PCLK.
HCLK_HZ, PCLK_HZ, TIMER_HZ = 170_000_000, 85_000_000, 170_000_000


@pytest.mark.parametrize("name", ALL)
def test_the_switch_to_170_mhz_follows_rm0440(name):
    chip = boot(name)
    assert chip.core.fault is None, chip.core.fault
    log = chip.rcc.cfgr_log  # (cycle, SWS, SYSCLK, HPRE, PPRE1, PPRE2, R1MODE)
    # The last switch to the PLL: in boost mode (R1MODE = 0), at AHB /2.
    switches = [n for n, (_, sws, *_) in enumerate(log) if sws == 3 and (n == 0 or log[n - 1][1] != 3)]
    assert switches, log
    at = switches[-1]
    cycle, _, sysclk, hpre, _, _, r1mode = log[at]
    assert (sysclk, hpre, r1mode) == (170_000_000, 2, False), log
    # Then AHB /1, at least 1 us later, with both APB prescalers /2 in the same write.
    raised = [entry for entry in log[at:] if entry[3] == 1]
    assert raised, log
    assert raised[0][0] - cycle >= chip.core.hz // 1_000_000, log
    assert raised[0][3:6] == (1, 2, 2), log
    rcc = chip.rcc
    assert (rcc.hclk_hz(), rcc.pclk_hz(1), rcc.pclk_hz(2)) == (HCLK_HZ, PCLK_HZ, PCLK_HZ)
    assert (rcc.timer_hz(1), rcc.timer_hz(2)) == (TIMER_HZ, TIMER_HZ)


def fresh_chip():
    """A chip at reset with the PLL locked at 170 MHz from HSE and boost mode entered, nothing run."""
    chip = Stm32g4(image("thruster-fw"))
    chip.rcc.write(CR, (1 << 8) | (1 << 16))  # HSION, HSEON
    chip.rcc.write(PLLCFGR, 0b11 | 5 << 4 | 85 << 8 | 1 << 24)  # HSE / 6 * 85 / 2, R on
    chip.rcc.write(CR, (1 << 8) | (1 << 16) | (1 << 24))  # PLLON
    chip.pwr.write(PWR_CR5, 0)  # R1MODE = 0
    return chip


def test_the_model_refuses_embassy_stm32_0_6s_switch():
    # embassy-stm32 0.6.0's `rcc/g4.rs`: HPRE /2 on HSI16, then SW = PLL and HPRE = /1 in one write.
    chip = fresh_chip()
    chip.rcc.write(CFGR, 0b01 | 0b1000 << 4)
    assert chip.core.fault is None
    chip.rcc.write(CFGR, 0b11)
    assert "RM0440 6.1.5" in (chip.core.fault or ""), chip.core.fault


def test_the_model_refuses_ahb_1_within_1_us():
    chip = fresh_chip()
    chip.rcc.write(CFGR, 0b01 | 0b1000 << 4)
    chip.rcc.write(CFGR, 0b11 | 0b1000 << 4)
    assert chip.core.fault is None
    chip.core.cycles += chip.core.hz // 1_000_000 - 1
    chip.rcc.write(CFGR, 0b11)
    assert "at least 1 us" in (chip.core.fault or ""), chip.core.fault
    # A microsecond is enough.
    chip = fresh_chip()
    chip.rcc.write(CFGR, 0b01 | 0b1000 << 4)
    chip.rcc.write(CFGR, 0b11 | 0b1000 << 4)
    chip.core.cycles += chip.core.hz // 1_000_000
    chip.rcc.write(CFGR, 0b11)
    assert chip.core.fault is None, chip.core.fault


def test_the_model_refuses_170_mhz_in_normal_mode():
    chip = fresh_chip()
    chip.pwr.write(PWR_CR5, 1 << 8)
    chip.rcc.write(CFGR, 0b11 | 0b1000 << 4)
    assert chip.core.fault is None  # HCLK 85 MHz
    chip.rcc.write(CFGR, 0b11)
    assert "normal mode" in (chip.core.fault or ""), chip.core.fault


@pytest.mark.parametrize("name", ["thruster-fw", "lbv-master-fw"])
def test_time_runs_at_the_modelled_rate(name, expected):
    # The watchdog is fed every `watchdog_feed_us` of embassy time (a Timer in a loop): the feeds' spacing in
    # modelled time shows embassy's time driver counting at its tick. A driver counting twice as fast (its
    # prescaler left for the 85 MHz embassy recorded) would feed twice as often.
    chip = boot(name)
    chip.run_for(1.2)
    feed = expected["images"][name]["watchdog_feed_us"] / 1e6
    cycles = [cycle for cycle, _ in chip.iwdg.refreshes]
    # The first spacing is the start's: the master's set-up reloads the watchdog just before its feeding task does.
    spacing = [(b - a) / chip.core.hz for a, b in zip(cycles, cycles[1:])][1:]
    assert len(spacing) >= 1.2 / feed - 2, spacing
    for each in spacing:
        assert feed * 0.99 <= each <= feed * 1.02, (feed, spacing)
