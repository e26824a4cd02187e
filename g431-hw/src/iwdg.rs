//! The independent watchdog: prescaler and reload for a timeout, and the timing rules of a firmware that feeds it
//! only while every task reports progress.
//!
//! RM0440 (IWDG): the counter runs from the LSI through a prescaler of 4 << PR (PR 0..=6, 7 = /256), counting
//! down from RLR (12 bits); the timeout is (RLR + 1) * prescaler / f_LSI. The LSI is not precise, so the
//! schedule is checked at its fastest (shortest timeout).

use crate::clock::{LSI_HZ, LSI_MAX_HZ, LSI_MIN_HZ};

/// DBGMCU_APB1FZR1 (APB1LFZR in stm32-metapac): DBG_IWDG_STOP. The watchdog stops while a debugger halts the
/// core, so a breakpoint does not reset the chip under the probe; the bridge is safe meanwhile, TIM1 stopping with
/// it and turning every switch off ([`crate::tim1::DBGMCU_APB2FZR`]). Without a debugger the bit changes nothing
/// (RM0440 DBGMCU_APB1FZR1).
pub const DBGMCU_APB1FZR1: u32 = 1 << 12;

/// IWDG_PR and IWDG_RLR.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Iwdg {
    /// PR, 0..=6: prescaler 4 << PR.
    pub pr: u8,
    /// RLR, 0..=0xFFF.
    pub rlr: u16,
}

impl Iwdg {
    /// The prescaler's divisor.
    pub const fn prescaler(&self) -> u32 {
        4 << self.pr
    }

    /// The timeout at an LSI of `lsi_hz`, in microseconds.
    pub const fn timeout_us(&self, lsi_hz: u32) -> u32 {
        ((self.rlr as u64 + 1) * self.prescaler() as u64 * 1_000_000 / lsi_hz as u64) as u32
    }
}

/// The smallest prescaler whose reload reaches `timeout_us` at the nominal LSI, and that reload (rounded to the
/// nearest count); `None` beyond the longest timeout (32.8 s at 32 kHz) or for a zero timeout.
pub const fn for_timeout(timeout_us: u32) -> Option<Iwdg> {
    let mut pr: u8 = 0;
    while pr <= 6 {
        let prescaler = 4u64 << pr;
        let counts = (timeout_us as u64 * LSI_HZ as u64 + prescaler * 500_000) / (prescaler * 1_000_000);
        if counts >= 1 && counts <= 0x1000 {
            return Some(Iwdg {
                pr,
                rlr: (counts - 1) as u16,
            });
        }
        pr += 1;
    }
    None
}

/// The shortest timeout that still lasts `min_us` at the fastest LSI; `None` when none can.
pub const fn lasting_at_least(min_us: u32) -> Option<Iwdg> {
    // The nominal timeout that the fastest LSI shortens to `min_us`, rounded up; then one count more for
    // `for_timeout`'s rounding to the nearest count.
    let nominal = (min_us as u64 * LSI_MAX_HZ as u64).div_ceil(LSI_HZ as u64);
    if nominal > u32::MAX as u64 {
        return None;
    }
    let Some(iwdg) = for_timeout(nominal as u32) else {
        return None;
    };
    if iwdg.timeout_us(LSI_MAX_HZ) >= min_us {
        Some(iwdg)
    } else if iwdg.rlr < 0xFFF {
        Some(Iwdg {
            pr: iwdg.pr,
            rlr: iwdg.rlr + 1,
        })
    } else {
        None
    }
}

/// How long an image the bootloader starts may take to reach its own watchdog set-up, at the least: the thruster's
/// start-up (clocks, ADC calibration, the bridge and the I2C slave) takes milliseconds, so 2 s is generous, and
/// still short enough that an image that hangs before that is reset, and reverted by the bootloader, in seconds.
pub const BOOT_TRIAL_MIN_US: u32 = 2_000_000;

/// The watchdog the bootloader (lbv-boot) starts just before it jumps to the image: an image that hangs
/// before it sets up its own watchdog is reset, and embassy-boot then reverts it, since it never marked itself
/// booted. The image's own set-up reprograms it while it runs (RM0440 IWDG: after KR = 0x5555, PR and RLR take
/// new values once SR's PVU and RVU are clear; the refresh then reloads the counter from the new RLR).
pub const BOOT_TRIAL: Iwdg = match lasting_at_least(BOOT_TRIAL_MIN_US) {
    Some(iwdg) => iwdg,
    None => panic!("the boot trial's timeout cannot be set"),
};

/// The master's watchdog: fed every 250 ms by a task of the one executor every other task runs on, so that a task
/// that stops yielding (the executor stuck) resets the master within a second. Its longest stretch without a yield
/// is the signature check's last step (ed25519, some 6 M instructions: under 50 ms at 170 MHz). Set up by the image
/// over the bootloader's trial timeout.
pub const MASTER_SCHEDULE: Schedule = Schedule {
    feed_period_us: 250_000,
    slowest_report_us: 100_000,
    timeout_us: 1_000_000,
};

/// [`MASTER_SCHEDULE`]'s IWDG_PR and IWDG_RLR.
pub const MASTER: Iwdg = match MASTER_SCHEDULE.check() {
    Ok(iwdg) => iwdg,
    Err(_) => panic!("the master's watchdog schedule is unsound"),
};

/// How a firmware feeds the watchdog: a health task checks every `feed_period_us` that every task reported since
/// the last check and only then feeds it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Schedule {
    /// The health task's period.
    pub feed_period_us: u32,
    /// The longest a healthy task may go between two reports.
    pub slowest_report_us: u32,
    /// The watchdog's configured timeout.
    pub timeout_us: u32,
}

/// Why a schedule is unsound.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScheduleError {
    /// A healthy task may report less often than the health check runs: a check finds its bit missing (a false
    /// "tasks not reporting" warning) and skips a feed.
    ReportSlowerThanFeed,
    /// At the fastest LSI the watchdog bites before two feed periods: one late check resets the chip.
    TimeoutTooShort,
    /// The timeout cannot be set.
    NoTimeout,
}

impl Schedule {
    /// Check the schedule: every healthy task reports within a feed period, and at the fastest LSI the watchdog
    /// outlasts two feed periods.
    pub const fn check(&self) -> Result<Iwdg, ScheduleError> {
        let Some(iwdg) = for_timeout(self.timeout_us) else {
            return Err(ScheduleError::NoTimeout);
        };
        if self.slowest_report_us >= self.feed_period_us {
            return Err(ScheduleError::ReportSlowerThanFeed);
        }
        if (iwdg.timeout_us(LSI_MAX_HZ) as u64) < 2 * self.feed_period_us as u64 {
            return Err(ScheduleError::TimeoutTooShort);
        }
        Ok(iwdg)
    }

    /// The longest the watchdog can take to bite once feeding stops: its timeout at the slowest LSI.
    pub const fn worst_bite_us(&self) -> u32 {
        match for_timeout(self.timeout_us) {
            Some(iwdg) => iwdg.timeout_us(LSI_MIN_HZ),
            None => 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stm32_metapac::dbgmcu::regs::Apb1lfzr;
    use stm32_metapac::iwdg::vals::Pr;

    #[test]
    fn the_debug_freeze_is_dbg_iwdg_stop_alone() {
        let mut freeze = Apb1lfzr(0);
        freeze.set_iwdg(true);
        assert_eq!(DBGMCU_APB1FZR1, freeze.0);
    }

    #[test]
    fn prescaler_and_reload_follow_rm0440() {
        // RM0440's table at 32 kHz: /4 covers 0.125 ms..=512 ms, /8 up to 1024 ms, ..., /256 up to 32 768 ms.
        assert_eq!(for_timeout(125), Some(Iwdg { pr: 0, rlr: 0 }));
        assert_eq!(for_timeout(512_000), Some(Iwdg { pr: 0, rlr: 0xFFF }));
        assert_eq!(for_timeout(512_001).map(|i| i.pr), Some(0));
        assert_eq!(for_timeout(600_000).map(|i| i.pr), Some(1));
        assert_eq!(for_timeout(32_768_000), Some(Iwdg { pr: 6, rlr: 0xFFF }));
        assert_eq!(for_timeout(40_000_000), None);
        assert_eq!(for_timeout(0), None);
        // The thruster's 250 ms: /4, 2000 counts, as embassy-stm32 would set it.
        let iwdg = for_timeout(250_000).unwrap();
        assert_eq!(iwdg, Iwdg { pr: 0, rlr: 1999 });
        assert_eq!(iwdg.timeout_us(LSI_HZ), 250_000);
        // The divisors by PR, as the PAC names them.
        let pac = [
            (Pr::DIVIDE_BY4, 4),
            (Pr::DIVIDE_BY8, 8),
            (Pr::DIVIDE_BY16, 16),
            (Pr::DIVIDE_BY32, 32),
            (Pr::DIVIDE_BY64, 64),
            (Pr::DIVIDE_BY128, 128),
            (Pr::DIVIDE_BY256, 256),
        ];
        for (pr, (name, divisor)) in pac.into_iter().enumerate() {
            let iwdg = Iwdg { pr: pr as u8, rlr: 0 };
            assert_eq!((Pr::from_bits(iwdg.pr), iwdg.prescaler()), (name, divisor));
        }
    }

    #[test]
    fn the_previous_schedule_warned_falsely() {
        // Health checked every 50 ms while the I2C task, idle, reports every 50 ms plus up to one 25 ms transfer.
        let before = Schedule {
            feed_period_us: 50_000,
            slowest_report_us: 75_000,
            timeout_us: 250_000,
        };
        assert_eq!(before.check(), Err(ScheduleError::ReportSlowerThanFeed));
    }

    #[test]
    fn the_thruster_schedule_holds_at_either_lsi_extreme() {
        let schedule = Schedule {
            feed_period_us: 100_000,
            slowest_report_us: 75_000,
            timeout_us: 250_000,
        };
        let iwdg = schedule.check().unwrap();
        assert!(iwdg.timeout_us(LSI_MAX_HZ) >= 200_000);
        assert!(schedule.worst_bite_us() < 300_000);
        let short = Schedule {
            timeout_us: 150_000,
            ..schedule
        };
        assert_eq!(short.check(), Err(ScheduleError::TimeoutTooShort));
    }

    #[test]
    fn the_master_s_watchdog_outlasts_two_feeds_and_bites_within_a_second_and_a_half() {
        assert_eq!(MASTER, Iwdg { pr: 1, rlr: 3999 });
        assert!(MASTER.timeout_us(LSI_MAX_HZ) >= 2 * MASTER_SCHEDULE.feed_period_us);
        assert!(MASTER_SCHEDULE.worst_bite_us() < 1_500_000);
    }

    #[test]
    fn the_boot_trial_outlasts_its_minimum_at_the_fastest_lsi() {
        // 2 s at the fastest LSI (34 kHz) is 2125 ms at the nominal 32 kHz: beyond /16's 2048 ms, so /32 and 2125
        // counts.
        assert_eq!(BOOT_TRIAL, Iwdg { pr: 3, rlr: 2124 });
        assert!(BOOT_TRIAL.timeout_us(LSI_MAX_HZ) >= BOOT_TRIAL_MIN_US);
        assert!(
            BOOT_TRIAL.timeout_us(LSI_MIN_HZ) < 2_400_000,
            "and not much longer at the slowest"
        );
        // The shortest: one count less no longer lasts.
        let shorter = Iwdg {
            rlr: BOOT_TRIAL.rlr - 1,
            ..BOOT_TRIAL
        };
        assert!(shorter.timeout_us(LSI_MAX_HZ) < BOOT_TRIAL_MIN_US);
        for min_us in [125, 1_000, 250_000, 512_000, 1_000_000, 9_999_999, 30_000_000] {
            let iwdg = lasting_at_least(min_us).unwrap();
            assert!(iwdg.timeout_us(LSI_MAX_HZ) >= min_us, "{min_us}");
        }
        assert_eq!(lasting_at_least(32_000_000), None, "beyond /256 at the fastest LSI");
    }
}
