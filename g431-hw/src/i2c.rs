//! I2C_TIMINGR for standard mode, computed from RM0440's timing rules and checked against UM10204's limits.
//!
//! embassy-stm32 0.6 computes TIMINGR itself (`Timings::new` in its `i2c/v2.rs`) and gets standard mode wrong at
//! the kernel clocks it is given here: at 170 MHz it asks for SDADEL 21 and SCLDEL 84, at 16 MHz SCLDEL 31, and
//! the register keeps 4 bits of each (stm32-metapac's `set_sdadel` / `set_scldel` mask to 0x0F). The data setup
//! time then falls short of UM10204's 250 ns plus the 1 us rise time allowed at 100 kHz. The bindings therefore
//! write [`standard_mode`]'s value after every peripheral (re)initialisation, with the peripheral disabled as
//! RM0440 requires (TIMINGR is written while PE = 0).
//!
//! RM0440 (I2C "I2C timings"): t_PRESC = (PRESC + 1) t_I2CCLK; t_SCLDEL = (SCLDEL + 1) t_PRESC; t_SDADEL =
//! SDADEL t_PRESC; t_SCLL = (SCLL + 1) t_PRESC; t_SCLH = (SCLH + 1) t_PRESC;
//! SDADEL >= (t_f(max) + t_HD;DAT(min) - t_AF(min) - (DNF + 3) t_I2CCLK) / t_PRESC;
//! SDADEL <= (t_VD;DAT(max) - t_r(max) - 260 ns - (DNF + 4) t_I2CCLK) / t_PRESC;
//! SCLDEL >= (t_r(max) + t_SU;DAT(min)) / t_PRESC - 1;
//! the SCL period is t_SYNC1 + t_SYNC2 + t_SCLL + t_SCLH, each t_SYNC adding the edge, the analog filter's delay
//! t_AF (50 ns at least) and 2 to 3 t_I2CCLK of synchronisation. The digital filter is off (DNF = 0) and the
//! analog filter on (embassy-stm32 clears ANFOFF).
//!
//! UM10204 (Rev. 7, table 10, standard mode): f_SCL <= 100 kHz; t_LOW >= 4.7 us; t_HIGH >= 4.0 us;
//! t_SU;DAT >= 250 ns; t_HD;DAT >= 0; t_VD;DAT <= 3.45 us; t_r <= 1000 ns; t_f <= 300 ns.

/// UM10204 standard-mode limits, in ns.
const T_LOW_MIN: u32 = 4_700;
const T_HIGH_MIN: u32 = 4_000;
const T_SU_DAT_MIN: u32 = 250;
const T_HD_DAT_MIN: u32 = 0;
const T_VD_DAT_MAX: u32 = 3_450;
const T_R_MAX: u32 = 1_000;
const T_F_MAX: u32 = 300;
/// The analog filter's delay, at least (RM0440 formulas: t_AF(min) = 50 ns) and the fixed 260 ns it budgets.
const T_AF_MIN: u32 = 50;
const T_AF_BUDGET: u32 = 260;
/// The slowest SCL standard mode allows: 100 kHz.
const PERIOD_MIN_NS: u32 = 10_000;

/// The fields of I2C_TIMINGR.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Timing {
    /// PRESC, 0..=15.
    pub presc: u8,
    /// SCLDEL, 0..=15: data setup time.
    pub scldel: u8,
    /// SDADEL, 0..=15: data hold time.
    pub sdadel: u8,
    /// SCLH: SCL high period.
    pub sclh: u8,
    /// SCLL: SCL low period.
    pub scll: u8,
}

/// Why a timing does not meet standard mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Violation {
    /// A field does not fit its register bits.
    FieldRange,
    /// Data setup time shorter than t_r(max) + t_SU;DAT(min).
    Setup,
    /// Data hold outside RM0440's SDADEL window.
    Hold,
    /// SCL low shorter than 4.7 us.
    Low,
    /// SCL high shorter than 4.0 us.
    High,
    /// SCL faster than 100 kHz even with ideal edges.
    Frequency,
    /// No prescaler gives a valid timing at this kernel clock.
    NoTiming,
}

impl Timing {
    /// The I2C_TIMINGR value: PRESC\[31:28\], SCLDEL\[23:20\], SDADEL\[19:16\], SCLH\[15:8\], SCLL\[7:0\].
    pub const fn timingr(&self) -> u32 {
        ((self.presc as u32 & 0xF) << 28)
            | ((self.scldel as u32 & 0xF) << 20)
            | ((self.sdadel as u32 & 0xF) << 16)
            | ((self.sclh as u32) << 8)
            | self.scll as u32
    }

    /// The fields of a TIMINGR value.
    pub const fn from_timingr(value: u32) -> Timing {
        Timing {
            presc: ((value >> 28) & 0xF) as u8,
            scldel: ((value >> 20) & 0xF) as u8,
            sdadel: ((value >> 16) & 0xF) as u8,
            sclh: (value >> 8) as u8,
            scll: value as u8,
        }
    }

    /// t_PRESC in ps at a kernel clock of `kernel_hz`.
    const fn presc_ps(&self, kernel_hz: u32) -> u64 {
        (self.presc as u64 + 1) * 1_000_000_000_000 / kernel_hz as u64
    }

    /// The shortest SCL period in ns at `kernel_hz`: ideal edges, the analog filter's least delay and two kernel
    /// clocks of synchronisation on each edge.
    pub const fn min_period_ns(&self, kernel_hz: u32) -> u32 {
        let t = self.presc_ps(kernel_hz);
        let clock_ps = 1_000_000_000_000 / kernel_hz as u64;
        let counted = (self.scll as u64 + 1 + self.sclh as u64 + 1) * t;
        let sync = 2 * (T_AF_MIN as u64 * 1000 + 2 * clock_ps);
        ((counted + sync) / 1000) as u32
    }

    /// The SCL period in ns at `kernel_hz` on a bus with edges of `rise_ns` and `fall_ns`, taking the analog
    /// filter's delay at its budget and three clocks of synchronisation: the slow end, for reporting.
    pub const fn period_ns(&self, kernel_hz: u32, rise_ns: u32, fall_ns: u32) -> u32 {
        let t = self.presc_ps(kernel_hz);
        let clock_ps = 1_000_000_000_000 / kernel_hz as u64;
        let counted = (self.scll as u64 + 1 + self.sclh as u64 + 1) * t;
        let sync = (rise_ns as u64 + fall_ns as u64 + 2 * T_AF_BUDGET as u64) * 1000 + 6 * clock_ps;
        ((counted + sync) / 1000) as u32
    }

    /// Check the timing against RM0440's rules and UM10204's standard-mode limits at `kernel_hz`.
    pub const fn check_standard_mode(&self, kernel_hz: u32) -> Result<(), Violation> {
        if self.presc > 15 || self.scldel > 15 || self.sdadel > 15 {
            return Err(Violation::FieldRange);
        }
        let t = self.presc_ps(kernel_hz) as i64;
        let clock = (1_000_000_000_000 / kernel_hz as u64) as i64;
        // Setup: (SCLDEL + 1) t_PRESC >= t_r(max) + t_SU;DAT(min).
        if (self.scldel as i64 + 1) * t < (T_R_MAX + T_SU_DAT_MIN) as i64 * 1000 {
            return Err(Violation::Setup);
        }
        // Hold: SDADEL t_PRESC within RM0440's window (DNF = 0).
        let hold = self.sdadel as i64 * t;
        let hold_min = (T_F_MAX + T_HD_DAT_MIN) as i64 * 1000 - T_AF_MIN as i64 * 1000 - 3 * clock;
        let hold_max = (T_VD_DAT_MAX as i64 - T_R_MAX as i64 - T_AF_BUDGET as i64) * 1000 - 4 * clock;
        if hold < hold_min || hold > hold_max {
            return Err(Violation::Hold);
        }
        if (self.scll as i64 + 1) * t < T_LOW_MIN as i64 * 1000 {
            return Err(Violation::Low);
        }
        if (self.sclh as i64 + 1) * t < T_HIGH_MIN as i64 * 1000 {
            return Err(Violation::High);
        }
        if self.min_period_ns(kernel_hz) < PERIOD_MIN_NS {
            return Err(Violation::Frequency);
        }
        Ok(())
    }
}

/// TIMINGR for standard mode at the kernel clock both images give their I2C peripherals (HSI16).
pub const TIMINGR: u32 = match standard_mode(crate::clock::I2C_KERNEL_HZ) {
    Ok(timing) => timing.timingr(),
    Err(_) => 0,
};
const _: () = assert!(standard_mode(crate::clock::I2C_KERNEL_HZ).is_ok());

/// I2C_OAR1 for a 7-bit own address (RM0440 37.7.3): OA1EN at bit 15, OA1MODE = 0 (7-bit), the address in
/// OA1\[7:1\].
pub const fn oar1(address: u8) -> u32 {
    1 << 15 | ((address as u32) & 0x7F) << 1
}

/// `a / b` rounded up, for positive values.
const fn ceil_div(a: i64, b: i64) -> i64 {
    if a <= 0 { 0 } else { (a + b - 1) / b }
}

/// Standard mode (100 kHz at most) at a kernel clock of `kernel_hz`: the smallest prescaler whose fields fit, the
/// shortest setup and hold times RM0440 allows for the worst UM10204 edges, SCL low and high at their minimums
/// and then lengthened equally (low first) until even ideal edges cannot make SCL faster than 100 kHz.
pub const fn standard_mode(kernel_hz: u32) -> Result<Timing, Violation> {
    if kernel_hz == 0 {
        return Err(Violation::NoTiming);
    }
    let clock = (1_000_000_000_000 / kernel_hz as u64) as i64;
    let mut presc: i64 = 0;
    while presc <= 15 {
        let t = (presc + 1) * 1_000_000_000_000 / kernel_hz as i64;
        let scldel = ceil_div((T_R_MAX + T_SU_DAT_MIN) as i64 * 1000, t) - 1;
        let sdadel = ceil_div((T_F_MAX + T_HD_DAT_MIN - T_AF_MIN) as i64 * 1000 - 3 * clock, t);
        let mut scll = ceil_div(T_LOW_MIN as i64 * 1000, t) - 1;
        let mut sclh = ceil_div(T_HIGH_MIN as i64 * 1000, t) - 1;
        if scldel <= 15 && sdadel <= 15 && scll <= 255 && sclh <= 255 {
            let mut timing = Timing {
                presc: presc as u8,
                scldel: scldel as u8,
                sdadel: sdadel as u8,
                sclh: sclh as u8,
                scll: scll as u8,
            };
            let mut low_next = true;
            while timing.min_period_ns(kernel_hz) < PERIOD_MIN_NS && scll < 255 && sclh < 255 {
                if low_next {
                    scll += 1;
                } else {
                    sclh += 1;
                }
                low_next = !low_next;
                timing.scll = scll as u8;
                timing.sclh = sclh as u8;
            }
            if timing.check_standard_mode(kernel_hz).is_ok() {
                return Ok(timing);
            }
        }
        presc += 1;
    }
    Err(Violation::NoTiming)
}

/// UM10204 (Rev. 7, table 9, standard mode): a device's open-drain output holds V_OL <= 0.4 V while it sinks 3 mA.
const SINK_MAX_UA: u32 = 3_000;
const V_OL_MAX_MV: u32 = 400;

/// How many channels of a TCA9548A may be enabled together, each with its own SDA and SCL pull-ups of `pullup_ohm`
/// to `vdd_mv`, as the switch's downstream channels need (TI SCPS207, the TCA9548A datasheet: any combination of
/// channels may be enabled by its control register, and an enabled channel is joined to the upstream bus), the
/// upstream bus having a pair of its own. Enabled together, the pull-ups are in parallel, and whoever drives a line
/// low (the master writing, any thruster acknowledging) sinks the current of every one of them: no more than
/// UM10204's 3 mA at 0.4 V. The rise time does not limit it: each channel brings its capacitance and its pull-up,
/// so R·C, and the edge, stay those of one channel.
pub const fn channels_together(vdd_mv: u32, pullup_ohm: u32) -> u32 {
    /// The TCA9548A's channels.
    const CHANNELS: u64 = 8;
    if pullup_ohm == 0 || vdd_mv <= V_OL_MAX_MV {
        return 0;
    }
    let per_pair_ua = (vdd_mv - V_OL_MAX_MV) as u64 * 1_000 / pullup_ohm as u64;
    if per_pair_ua == 0 {
        return CHANNELS as u32;
    }
    // One pair is the upstream bus's.
    let pairs = SINK_MAX_UA as u64 / per_pair_ua;
    let channels = pairs.saturating_sub(1);
    (if channels < CHANNELS { channels } else { CHANNELS }) as u32
}

#[cfg(test)]
mod tests {
    use super::*;
    use stm32_metapac::i2c::regs::Timingr;

    /// embassy-stm32 0.6's standard-mode computation (`Timings::new`, frequency <= 100 kHz), then the 4-bit
    /// masking of the register.
    fn embassy(kernel_hz: u32) -> Timing {
        let ratio = kernel_hz / 100_000;
        let presc = ((ratio - 1) / 512).min(15);
        let p = presc + 1;
        let sclh = ((ratio / p) - 2) / 2;
        let sdadel = (kernel_hz / 2_000_000 / p).max(2);
        let scldel = (kernel_hz / 500_000 / p - 1).max(4);
        let mut reg = Timingr(0);
        reg.set_presc(presc as u8);
        reg.set_scll(sclh as u8);
        reg.set_sclh(sclh as u8);
        reg.set_sdadel(sdadel as u8);
        reg.set_scldel(scldel as u8);
        assert!(sdadel > 15 || scldel > 15, "{kernel_hz}: embassy's fields fit");
        Timing::from_timingr(reg.0)
    }

    #[test]
    fn three_mux_channels_at_once_keep_the_sink_current_within_standard_mode() {
        // 3.3 V and 4.7 kOhm: 617 uA a pair, four pairs within 3 mA, one of them upstream.
        assert_eq!(channels_together(3_300, 4_700), 3);
        // Stiffer pull-ups leave fewer: 2.2 kOhm is 1.3 mA a pair.
        assert_eq!(channels_together(3_300, 2_200), 1);
        assert_eq!(channels_together(3_300, 10_000), 8);
        // Nonsense in, no panic.
        assert_eq!(channels_together(0, 0), 0);
    }

    #[test]
    fn embassys_value_breaks_standard_mode_at_both_clocks() {
        // 170 MHz: SDADEL 21 -> 5, SCLDEL 84 -> 4: 117 ns of setup time.
        let at_170 = embassy(170_000_000);
        assert_eq!((at_170.presc, at_170.sdadel, at_170.scldel), (3, 5, 4));
        assert_eq!(at_170.check_standard_mode(170_000_000), Err(Violation::Setup));
        // 16 MHz (HSI16): SCLDEL 31 -> 15: 1000 ns, short of the 1250 ns a 1 us rise needs.
        let at_16 = embassy(16_000_000);
        assert_eq!(at_16.scldel, 15);
        assert_eq!(at_16.check_standard_mode(16_000_000), Err(Violation::Setup));
    }

    #[test]
    fn computed_value_meets_standard_mode() {
        for kernel_hz in [8_000_000, 16_000_000, 24_000_000, 48_000_000, 85_000_000, 170_000_000] {
            let timing = standard_mode(kernel_hz).unwrap();
            assert_eq!(timing.check_standard_mode(kernel_hz), Ok(()), "{kernel_hz}");
            // 100 kHz at most, and no slower than 80 kHz on a bus at UM10204's worst edges.
            let period = timing.period_ns(kernel_hz, T_R_MAX, T_F_MAX);
            assert!((10_000..=12_500).contains(&period), "{kernel_hz}: {period} ns");
        }
        // The firmware's: HSI16.
        let timing = standard_mode(16_000_000).unwrap();
        assert_eq!(
            timing,
            Timing {
                presc: 1,
                scldel: 9,
                sdadel: 1,
                sclh: 35,
                scll: 41
            }
        );
        assert_eq!(timing.timingr(), 0x1091_2329);
        assert_eq!(TIMINGR, 0x1091_2329);
        assert_eq!(Timing::from_timingr(timing.timingr()), timing);
    }

    #[test]
    fn rm0440_example_passes_the_rules_it_was_built_with() {
        // RM0440's example for f_I2CCLK = 16 MHz, standard mode 100 kHz: PRESC 3, SCLL 0x13, SCLH 0xF,
        // SDADEL 0x2, SCLDEL 0x4.
        let example = Timing::from_timingr(0x3042_0F13);
        assert_eq!(
            (
                example.presc,
                example.scll,
                example.sclh,
                example.sdadel,
                example.scldel
            ),
            (3, 0x13, 0xF, 2, 4)
        );
        // Its counted low and high times sum to 9 us: with ideal edges SCL would run above 100 kHz, so this
        // crate's stricter period rule rejects it while every other rule passes.
        assert_eq!(example.check_standard_mode(16_000_000), Err(Violation::Frequency));
        let stretched = Timing {
            scll: 0x13 + 3,
            ..example
        };
        assert_eq!(stretched.check_standard_mode(16_000_000), Ok(()));
    }

    #[test]
    fn field_positions_agree_with_the_pac() {
        let timing = standard_mode(16_000_000).unwrap();
        let mut reg = Timingr(0);
        reg.set_presc(timing.presc);
        reg.set_scldel(timing.scldel);
        reg.set_sdadel(timing.sdadel);
        reg.set_sclh(timing.sclh);
        reg.set_scll(timing.scll);
        assert_eq!(timing.timingr(), reg.0);
    }

    #[test]
    fn out_of_range_inputs_are_refused() {
        assert_eq!(standard_mode(0), Err(Violation::NoTiming));
        // Far too fast for PRESC to bring SCL within 8-bit counts.
        assert_eq!(standard_mode(u32::MAX), Err(Violation::NoTiming));
        // Too slow for the setup rule... there is no slowest: a slow clock still times 100 kHz.
        assert!(standard_mode(2_000_000).is_ok());
        let bad = Timing {
            presc: 16,
            ..standard_mode(16_000_000).unwrap()
        };
        assert_eq!(bad.check_standard_mode(16_000_000), Err(Violation::FieldRange));
    }

    #[test]
    fn own_address_register_agrees_with_the_pac() {
        use stm32_metapac::i2c::regs::Oar1;
        for address in [0x29, 0x2A, 0x7F] {
            let mut register = Oar1(0);
            register.set_oa1(u16::from(address) << 1);
            register.set_oa1en(true);
            assert_eq!(oar1(address), register.0);
        }
    }
}
