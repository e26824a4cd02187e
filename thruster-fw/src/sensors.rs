//! Conversions of the analog sensor readings (12-bit ADC, raw 0..=4095, full scale = VDDA) to physical units.
//!
//! The fault monitor works in ohms and tenths of a degree (docs/interface.md, "Faults"); the status message
//! reports the motor current in 0.1 A (IDS 8.4.1 MAX POWER, 8.4.2 CURRENT). Every conversion accepts any `u16`,
//! including readings above the ADC's range, and never panics.

/// Largest reading of the 12-bit ADC: the input is at VDDA.
pub(crate) const ADC_MAX: u16 = 4095;

/// Water sensor: the two electrodes inside the thruster housing connect VDDA to the ADC node; a pull-down resistor
/// goes from the node to ground. Dry electrodes read ~0; water between them raises the node voltage.
///
/// raw = 4095 * R_pd / (R_pd + R), R being the resistance between the electrodes. The water fault is R < 1 Mohm,
/// the ground fault R < 100 kohm (IDS 8.4.1 remark 6, 8.4.2 remarks 2-3).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct WaterSensor {
    /// The pull-down from the ADC node to ground, in ohms.
    pub pull_down_ohms: u32,
}

impl WaterSensor {
    /// Resistance between the electrodes: R = R_pd * (4095 - raw) / raw, rounded to the nearest ohm.
    /// raw 0 (open, dry) -> `u32::MAX`; larger values saturate at `u32::MAX`; raw >= 4095 (short) -> 0.
    pub const fn resistance_ohms(&self, raw: u16) -> u32 {
        if raw == 0 {
            return u32::MAX;
        }
        if raw >= ADC_MAX {
            return 0;
        }
        let raw = raw as u64;
        // R_pd < 2^32 and 4095 - raw < 2^12: the product and the rounding term fit in u64.
        let ohms = (self.pull_down_ohms as u64 * (ADC_MAX as u64 - raw) + raw / 2) / raw;
        if ohms > u32::MAX as u64 { u32::MAX } else { ohms as u32 }
    }

    /// The raw reading at which the electrodes measure `ohms` (for thresholds and for simulation): inverse of
    /// [`WaterSensor::resistance_ohms`], raw = 4095 * R_pd / (R_pd + R) rounded to the nearest count (0..=4095).
    ///
    /// With a 1 Mohm pull-down, 1 Mohm reads 2048 and 100 kohm reads 3723: the first counts that
    /// `resistance_ohms` puts below those thresholds. A zero pull-down always reads 0.
    pub const fn raw_at(&self, ohms: u32) -> u16 {
        let pull_down = self.pull_down_ohms as u64;
        let den = pull_down + ohms as u64;
        if den == 0 {
            return 0;
        }
        // The quotient is at most 4095 because R_pd <= R_pd + R.
        ((2 * ADC_MAX as u64 * pull_down + den) / (2 * den)) as u16
    }
}

/// 0 degrees Celsius in kelvin.
const ZERO_CELSIUS_K: f32 = 273.15;
/// The NTC's reference temperature, 25 degrees Celsius, in kelvin.
const T25_K: f32 = 298.15;

/// Where an NTC sits in its divider.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) enum NtcPlacement {
    /// NTC from the ADC node to ground, the fixed resistor to VDDA: the reading falls as it warms.
    ToGround,
    /// NTC from VDDA to the ADC node, the fixed resistor to ground: the reading rises as it warms.
    ToSupply,
}

/// NTC thermistor in a divider with a fixed resistor, Beta model: 1/T = 1/T25 + ln(R / R25) / Beta, with
/// raw = 4095 * R / (R + R_fixed) for an NTC to ground, and 4095 minus that for an NTC to VDDA.
///
/// Feeds the overtemp fault (set at 110 C, cleared at 100 C, IDS 8.4 remarks) and the status TEMPERATURE byte,
/// which is the motor's for brushless controllers and the controller's for brushed ones (IDS 8.4.2).
/// Single-precision floats: the Cortex-M4F computes them in hardware.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Ntc {
    /// Resistance at 25 degrees Celsius, in ohms.
    pub(crate) r25_ohms: u32,
    /// The Beta constant, in kelvin.
    pub(crate) beta: u16,
    /// The divider's fixed resistor, in ohms.
    pub(crate) fixed_ohms: u32,
    /// Which side of the divider the NTC is on.
    pub(crate) placement: NtcPlacement,
}

impl Ntc {
    /// The reference motor's winding sensor: 10 kohm B3435 to ground, 10 kohm to VDDA.
    pub(crate) const MOTOR: Ntc = Ntc {
        r25_ohms: 10_000,
        beta: 3435,
        fixed_ohms: 10_000,
        placement: NtcPlacement::ToGround,
    };

    /// The X-NUCLEO-IHM08M1's power-stage sensor (PC2), the controller temperature of brushed builds: taken as a
    /// 10 kohm NTC to VDDA over 4.7 kohm to ground. Its schematic could not be read here; this divider reads
    /// 1.055 V at 25 C, the V0 that ST's motor-control SDK uses for its power boards' temperature sensors, and
    /// B3435 is assumed. Check both against the board before trusting its overtemp threshold.
    pub(crate) const IHM08M1: Ntc = Ntc {
        r25_ohms: 10_000,
        beta: 3435,
        fixed_ohms: 4_700,
        placement: NtcPlacement::ToSupply,
    };

    /// The reading as if the NTC were to ground, which the Beta model below is written for.
    const fn as_to_ground(&self, raw: u16) -> u16 {
        match self.placement {
            NtcPlacement::ToGround => raw,
            NtcPlacement::ToSupply => ADC_MAX - if raw > ADC_MAX { ADC_MAX } else { raw },
        }
    }

    /// Temperature in 0.1 deg C, rounded to the nearest tenth and saturated to the `i16` range.
    ///
    /// The ends fail towards the overtemp fault's safe side where they can: a shorted thermistor (raw 0 to ground,
    /// 4095 to VDDA) and readings beyond the model's range read very hot, `i16::MAX`; an open or disconnected one
    /// reads very cold, `i16::MIN`. Zero parameters give meaningless values but never panic.
    pub(crate) fn decicelsius(&self, raw: u16) -> i16 {
        let raw = self.as_to_ground(raw);
        if raw == 0 {
            return i16::MAX;
        }
        if raw >= ADC_MAX {
            return i16::MIN;
        }
        let ohms = self.fixed_ohms as f32 * f32::from(raw) / f32::from(ADC_MAX - raw);
        let inverse_kelvin = 1.0 / T25_K + libm::logf(ohms / self.r25_ohms as f32) / f32::from(self.beta);
        // A non-positive 1/T (or NaN from zero parameters) lies beyond the hot end of the model.
        if inverse_kelvin.is_nan() || inverse_kelvin <= 0.0 {
            return i16::MAX;
        }
        let tenths = libm::roundf((1.0 / inverse_kelvin - ZERO_CELSIUS_K) * 10.0);
        // `as` saturates at the i16 range ends.
        if tenths.is_nan() { i16::MAX } else { tenths as i16 }
    }

    /// Inverse of [`Ntc::decicelsius`], for simulation and tests: the reading at `decicelsius`, rounded to the
    /// nearest count (0..=4095). At or below absolute zero it reads like an open thermistor.
    pub fn raw_at(&self, decicelsius: i16) -> u16 {
        let kelvin = f32::from(decicelsius) / 10.0 + ZERO_CELSIUS_K;
        if kelvin.is_nan() || kelvin <= 0.0 {
            return self.as_to_ground(ADC_MAX);
        }
        let ohms = self.r25_ohms as f32 * libm::expf(f32::from(self.beta) * (1.0 / kelvin - 1.0 / T25_K));
        // R / (R + R_fixed) written so that an infinite R gives 1 and a zero R gives 0.
        let fraction = 1.0 / (1.0 + self.fixed_ohms as f32 / ohms);
        let raw = libm::roundf(f32::from(ADC_MAX) * fraction);
        // `as` saturates (NaN gives 0); the fraction is at most 1, so this only guards rounding.
        self.as_to_ground((raw as u16).min(ADC_MAX))
    }
}

/// Motor current from a shunt amplifier: I = (raw - offset) * milliamps_per_count.
///
/// Reported in 0.1 A, the unit of the status messages (IDS 8.4.1 MAX POWER, 8.4.2 CURRENT).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct CurrentSense {
    /// The reading at zero current.
    pub offset_raw: u16,
    /// Milliamps per ADC count above the offset.
    pub milliamps_per_count: u16,
}

impl CurrentSense {
    /// Current magnitude in 0.1 A, rounded to the nearest tenth and saturating at `u16::MAX`; readings at or
    /// below the offset give 0.
    pub const fn deciamps(&self, raw: u16) -> u16 {
        let counts = raw.saturating_sub(self.offset_raw) as u32;
        // Both factors are below 2^16, so the product fits in u32.
        let milliamps = counts * self.milliamps_per_count as u32;
        let deciamps = milliamps.saturating_add(50) / 100;
        if deciamps > u16::MAX as u32 {
            u16::MAX
        } else {
            deciamps as u16
        }
    }

    /// The motor current in 0.1 A from the three low-side shunts read at one instant. All of it returns to ground
    /// through the low switch of the phase held low, whose shunt reads it above the offset through the whole PWM
    /// period; the switching phase's shunt reads nothing while its high switch conducts and the recirculating
    /// current, below the offset, while its low switch does; the floating phase's reads nothing. So the largest
    /// reading is the motor's, whichever step the bridge is in and wherever in the period the sample fell.
    pub const fn motor_deciamps(&self, shunts: [u16; 3]) -> u16 {
        let [a, b, c] = shunts;
        let largest = if a > b { a } else { b };
        self.deciamps(if largest > c { largest } else { c })
    }
}

/// The supply (VBUS) through a resistor divider: V = raw / 4095 x VDDA x (upper + lower) / lower.
///
/// A brushed thruster needs it to know the voltage it applies (duty x VBUS) for its stall rule
/// (docs/decisions.md D13).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct VbusSense {
    /// From VBUS to the ADC node, in ohms.
    pub(crate) upper_ohms: u32,
    /// From the ADC node to ground, in ohms.
    pub(crate) lower_ohms: u32,
}

/// VDDA, which the ADC's full scale is, in mV (the NUCLEO's 3V3).
pub(crate) const VDDA_MV: u32 = 3_300;

impl VbusSense {
    /// The IHM08M1's divider on PA1: 169 kohm over 9.31 kohm, 63.2 V at full scale (docs/hardware.md).
    pub(crate) const IHM08M1: VbusSense = VbusSense {
        upper_ohms: 169_000,
        lower_ohms: 9_310,
    };

    /// VBUS in mV, rounded to the nearest; a zero lower resistor reads 0.
    pub(crate) const fn millivolts(&self, raw: u16) -> u32 {
        let den = ADC_MAX as u64 * self.lower_ohms as u64;
        if den == 0 {
            return 0;
        }
        // raw < 2^16, VDDA < 2^12, the sum < 2^33: the product fits in u64.
        let num = raw as u64 * VDDA_MV as u64 * (self.upper_ohms as u64 + self.lower_ohms as u64);
        let mv = (num + den / 2) / den;
        if mv > u32::MAX as u64 { u32::MAX } else { mv as u32 }
    }

    /// The reading at `millivolts` (for simulation and tests), rounded to the nearest count and saturating at
    /// full scale: the inverse of [`VbusSense::millivolts`].
    pub const fn raw_at(&self, millivolts: u32) -> u16 {
        let den = VDDA_MV as u64 * (self.upper_ohms as u64 + self.lower_ohms as u64);
        if den == 0 {
            return 0;
        }
        let (den, lower) = (den as u128, self.lower_ohms as u128);
        // < 2^32 x 2^12 x 2^32: fits in u128.
        let raw = (millivolts as u128 * ADC_MAX as u128 * lower + den / 2) / den;
        if raw > ADC_MAX as u128 { ADC_MAX } else { raw as u16 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const WATER: WaterSensor = WaterSensor {
        pull_down_ohms: 1_000_000,
    };

    /// A common 10 kohm, B 3435 winding thermistor with a 4.7 kohm pull-up.
    const NTC: Ntc = Ntc {
        r25_ohms: 10_000,
        beta: 3435,
        fixed_ohms: 4_700,
        placement: NtcPlacement::ToGround,
    };

    #[test]
    fn water_resistance_known_points() {
        // Node at half scale: the electrodes equal the pull-down.
        assert_eq!(WATER.resistance_ohms(2048), 999_512);
        assert_eq!(WATER.resistance_ohms(2047), 1_000_489);
        assert_eq!(WATER.resistance_ohms(819), 4_000_000);
        assert_eq!(WATER.resistance_ohms(4094), 244);
        assert_eq!(WATER.resistance_ohms(1), 4_094_000_000);
        assert_eq!(
            WaterSensor {
                pull_down_ohms: 2_000_000
            }
            .resistance_ohms(1),
            u32::MAX
        );
    }

    #[test]
    fn water_edges_do_not_panic() {
        for sensor in [
            WATER,
            WaterSensor { pull_down_ohms: 0 },
            WaterSensor {
                pull_down_ohms: u32::MAX,
            },
        ] {
            assert_eq!(sensor.resistance_ohms(0), u32::MAX);
            assert_eq!(sensor.resistance_ohms(4095), 0);
            assert_eq!(sensor.resistance_ohms(4096), 0);
            assert_eq!(sensor.resistance_ohms(u16::MAX), 0);
            for ohms in [0, 1, 1_000_000, u32::MAX] {
                assert!(sensor.raw_at(ohms) <= ADC_MAX);
            }
        }
        assert_eq!(WaterSensor { pull_down_ohms: 0 }.raw_at(0), 0);
        assert_eq!(WaterSensor { pull_down_ohms: 0 }.resistance_ohms(1), 0);
        assert_eq!(WATER.raw_at(0), 4095);
        assert_eq!(WATER.raw_at(u32::MAX), 1);
        assert_eq!(
            WaterSensor {
                pull_down_ohms: u32::MAX
            }
            .resistance_ohms(1),
            u32::MAX
        );
    }

    #[test]
    fn water_thresholds_land_on_the_first_fault_count() {
        // 1 Mohm water threshold, 100 kohm ground threshold, 1 Mohm pull-down.
        let water = WATER.raw_at(1_000_000);
        let ground = WATER.raw_at(100_000);
        assert_eq!(water, 2048);
        assert_eq!(ground, 3723);
        assert!(WATER.resistance_ohms(water) < 1_000_000);
        assert!(WATER.resistance_ohms(water - 1) >= 1_000_000);
        assert!(WATER.resistance_ohms(ground) < 100_000);
        assert!(WATER.resistance_ohms(ground - 1) >= 100_000);
        // Wetter reads higher.
        assert!(WATER.raw_at(0) > ground && ground > water && water > WATER.raw_at(u32::MAX));
    }

    #[test]
    fn water_round_trip_and_monotonic() {
        let mut previous = u32::MAX;
        for raw in 1..ADC_MAX {
            let ohms = WATER.resistance_ohms(raw);
            assert!(ohms < previous, "raw {raw}");
            previous = ohms;
            assert_eq!(WATER.raw_at(ohms), raw, "raw {raw}");
        }
    }

    #[test]
    fn ntc_reads_25_c_at_r25() {
        // Pull-ups that put R25 exactly on a count: 40 k -> 4095 / 5, 20 k -> 4095 / 3.
        let fifth = Ntc {
            fixed_ohms: 40_000,
            ..NTC
        };
        assert_eq!(fifth.decicelsius(819), 250);
        assert_eq!(fifth.raw_at(250), 819);
        let third = Ntc {
            fixed_ohms: 20_000,
            ..NTC
        };
        assert_eq!(third.decicelsius(1365), 250);
        assert_eq!(third.raw_at(250), 1365);
        assert_eq!(NTC.decicelsius(NTC.raw_at(250)), 250);
    }

    #[test]
    fn ntc_known_points() {
        // Beta model for 10 k / B 3435: R(100 C) = 10 k * exp(3435 * (1/373.15 - 1/298.15)) = 987.0 ohm,
        // R(0 C) = 28 704 ohm. raw = 4095 R / (R + 4700).
        assert_eq!(NTC.raw_at(1000), 711);
        assert_eq!(NTC.raw_at(0), 3519);
        assert!((NTC.decicelsius(711) - 1000).abs() <= 1);
        assert!(NTC.decicelsius(3519).abs() <= 1);
        // Hotter reads lower.
        assert!(NTC.raw_at(1100) < NTC.raw_at(1000));
    }

    /// Largest |decicelsius(raw_at(t)) - t| over -20.0..=150.0 C, in 0.1 C.
    fn worst_round_trip(ntc: &Ntc) -> i16 {
        (-200..=1500_i16)
            .map(|t| (ntc.decicelsius(ntc.raw_at(t)) - t).abs())
            .max()
            .unwrap()
    }

    #[test]
    fn ntc_round_trips_within_a_tenth() {
        assert!(worst_round_trip(&NTC) <= 1);
        assert!(worst_round_trip(&Ntc { beta: 3950, ..NTC }) <= 1);
        // A pull-up equal to R25 loses resolution at the hot end: 1 count is about 0.4 C at 150 C.
        assert!(
            worst_round_trip(&Ntc {
                fixed_ohms: 10_000,
                ..NTC
            }) <= 2
        );
    }

    #[test]
    fn ntc_is_monotonic() {
        let mut previous = i16::MAX;
        for raw in 0..=ADC_MAX {
            let t = NTC.decicelsius(raw);
            assert!(t <= previous, "raw {raw}");
            previous = t;
        }
    }

    #[test]
    fn ntc_edges_saturate() {
        assert_eq!(NTC.decicelsius(0), i16::MAX);
        assert_eq!(NTC.decicelsius(4095), i16::MIN);
        assert_eq!(NTC.decicelsius(4096), i16::MIN);
        assert_eq!(NTC.decicelsius(u16::MAX), i16::MIN);
        // One count off either end stays inside the model.
        assert!(NTC.decicelsius(1) > 1500);
        assert!(NTC.decicelsius(4094) < -200);
        assert_eq!(NTC.raw_at(i16::MIN), 4095);
        assert!(NTC.raw_at(i16::MAX) <= 1);
        assert!(NTC.raw_at(-2732) == 4095);
    }

    #[test]
    fn ntc_degenerate_parameters_do_not_panic() {
        let params = [0, 1, u32::MAX];
        for r25_ohms in params {
            for fixed_ohms in params {
                for beta in [0, 1, u16::MAX] {
                    let ntc = Ntc {
                        r25_ohms,
                        beta,
                        fixed_ohms,
                        placement: NtcPlacement::ToGround,
                    };
                    for raw in [0, 1, 2048, 4094, 4095, u16::MAX] {
                        let _ = ntc.decicelsius(raw);
                    }
                    for t in [i16::MIN, -2732, -2731, 0, 250, 1100, i16::MAX] {
                        assert!(ntc.raw_at(t) <= ADC_MAX);
                    }
                }
            }
        }
    }

    #[test]
    fn an_ntc_to_vdda_reads_the_other_way() {
        let stage = Ntc::IHM08M1;
        // 1.055 V at 25 C: 4095 * 4.7 / 14.7 = 1309 counts.
        assert_eq!(stage.raw_at(250), 1309);
        assert_eq!(stage.decicelsius(1309), 250);
        // Warmer reads higher.
        assert!(stage.raw_at(1100) > stage.raw_at(1000));
        assert!(stage.raw_at(1000) > stage.raw_at(250));
        let mut previous = i16::MIN;
        for raw in 0..=ADC_MAX {
            let t = stage.decicelsius(raw);
            assert!(t >= previous, "raw {raw}");
            previous = t;
        }
        // Round trip over the range that matters, within a few tenths (the 4.7 kohm divider is coarse when hot).
        for t in (-200..=1500_i16).step_by(10) {
            assert!((stage.decicelsius(stage.raw_at(t)) - t).abs() <= 3, "{t}");
        }
        // The same NTC placed the other way mirrors the reading.
        let to_ground = Ntc {
            placement: NtcPlacement::ToGround,
            ..stage
        };
        for t in [0, 250, 1000, 1100] {
            assert_eq!(stage.raw_at(t), ADC_MAX - to_ground.raw_at(t));
        }
        // Open (node at ground) reads very cold, shorted very hot, out-of-range readings as shorted.
        assert_eq!(stage.decicelsius(0), i16::MIN);
        assert_eq!(stage.decicelsius(ADC_MAX), i16::MAX);
        assert_eq!(stage.decicelsius(u16::MAX), i16::MAX);
        assert_eq!(stage.raw_at(i16::MIN), 0);
    }

    #[test]
    fn current_examples() {
        let sense = CurrentSense {
            offset_raw: 2048,
            milliamps_per_count: 40,
        };
        assert_eq!(sense.deciamps(2048), 0);
        assert_eq!(sense.deciamps(0), 0);
        assert_eq!(sense.deciamps(2047), 0);
        // 1 count = 40 mA rounds to 0.0 A; 2 counts = 80 mA to 0.1 A; 3 counts = 120 mA to 0.1 A.
        assert_eq!(sense.deciamps(2049), 0);
        assert_eq!(sense.deciamps(2050), 1);
        assert_eq!(sense.deciamps(2051), 1);
        // 30 counts = 1.2 A, the IDS example value 12.
        assert_eq!(sense.deciamps(2078), 12);
        assert_eq!(sense.deciamps(4095), 819);
        assert_eq!(sense.deciamps(u16::MAX), 25395);
        let big = CurrentSense {
            offset_raw: 0,
            milliamps_per_count: u16::MAX,
        };
        assert_eq!(big.deciamps(u16::MAX), u16::MAX);
        assert_eq!(big.deciamps(1), 655);
        assert_eq!(big.deciamps(0), 0);
        let none = CurrentSense {
            offset_raw: u16::MAX,
            milliamps_per_count: 0,
        };
        assert_eq!(none.deciamps(u16::MAX), 0);
    }

    #[test]
    fn the_motor_current_is_the_shunt_of_the_phase_held_low() {
        let sense = CurrentSense {
            offset_raw: 2048,
            milliamps_per_count: 40,
        };
        // 2 A out of the motor through phase B's low switch; phase A's low switch recirculating it (below the
        // offset) or its high switch conducting (nothing on its shunt); phase C floating.
        let low = 2048 + 50;
        for a in [2048 - 50, 2048] {
            for order in [[a, low, 2048], [low, a, 2048], [2048, a, low]] {
                assert_eq!(sense.motor_deciamps(order), 20, "{order:?}");
            }
        }
        // Coasting: every shunt at the offset, or a little noise below it.
        assert_eq!(sense.motor_deciamps([2048, 2047, 2040]), 0);
        assert_eq!(sense.motor_deciamps([0, 0, 0]), 0);
        assert_eq!(sense.motor_deciamps([u16::MAX, 0, 0]), sense.deciamps(u16::MAX));
    }

    #[test]
    fn vbus_of_the_ihm08m1() {
        let vbus = VbusSense::IHM08M1;
        // Full scale: 3.3 V x 178.31 / 9.31 = 63.20 V, 15.43 mV a count; 24 V reads 1555 counts.
        assert_eq!(vbus.millivolts(ADC_MAX), 63_203);
        assert_eq!(vbus.raw_at(24_000), 1555);
        assert_eq!(vbus.millivolts(1555), 24_000);
        assert_eq!(vbus.millivolts(0), 0);
        assert_eq!(vbus.raw_at(100_000), ADC_MAX);
        for raw in [0, 1, 777, 1555, 4094, ADC_MAX] {
            assert_eq!(vbus.raw_at(vbus.millivolts(raw)), raw);
        }
    }

    #[test]
    fn vbus_edges_do_not_panic() {
        for sense in [
            VbusSense::IHM08M1,
            VbusSense {
                upper_ohms: 0,
                lower_ohms: 0,
            },
            VbusSense {
                upper_ohms: u32::MAX,
                lower_ohms: 1,
            },
            VbusSense {
                upper_ohms: u32::MAX,
                lower_ohms: u32::MAX,
            },
        ] {
            for raw in [0, 1, ADC_MAX, u16::MAX] {
                let _ = sense.millivolts(raw);
            }
            for mv in [0, 1, u32::MAX] {
                assert!(sense.raw_at(mv) <= ADC_MAX);
            }
        }
    }
}
