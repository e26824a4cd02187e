//! ADC sample times against the impedance of what is sampled.
//!
//! The ADC charges its sample-and-hold capacitor C_ADC from the source during the sampling time T_S. Two bounds on
//! the source's resistance are applied, and a sample time must meet both:
//!
//! - **DS12589's "Maximum ADC R_AIN" table** ([`Adc::table_max_source_ohms`]): the largest source resistance per
//!   sample time, for fast channels (ADCx_IN1..IN5) and slow channels (the rest), at 12 bits and f_ADC = 60 MHz.
//!   The datasheet itself could not be read here: the figures are the STM32G4 table as a public STM32G4 project
//!   reproduces it in a header comment (found by text search; 12-bit, 60 MHz, fast / slow ohms). Confirm them
//!   against DS12589 before relying on the margins. The table is applied by cycle count at this project's slower
//!   42.5 MHz clock, where the same count samples 41 % longer: conservative.
//! - **The R_AIN formula** ([`Adc::max_source_ohms`]) of STM32 datasheets ("Equation 1: R_AIN max formula", e.g.
//!   the STM32F103x4/x6 datasheet, Doc ID 15060, whose table 47 this module reproduces in its tests), for an error
//!   under 1/4 LSB: R_AIN < T_S / (f_ADC * C_ADC * ln(2^(N + 2))) - R_ADC, T_S in ADC clock cycles, with
//!   C_ADC = 5 pF and R_ADC = 0 (DS12589 as recalled, not read). It is the looser of the two for every row of the
//!   table (a test checks), so the table decides; the formula stays for the water sensor's hold capacitor, which the
//!   table does not cover.
//!
//! A source too slow for the longest sample time (the water sensor's 1 Mohm divider) gets a capacitor at the pin:
//! it supplies the sample's charge, and must be large enough that sharing it with C_ADC moves the pin by less than
//! 1/4 LSB after a full-scale step (C >= C_ADC * 2^(N + 2)). The source then only has to refill that charge between
//! conversions; the error that leaves is [`Adc::recharge_error_lsb`].
//!
//! A conversion takes the sample time plus 12.5 cycles of successive approximation at 12 bits (RM0440 21.4.16,
//! "t_CONV = t_SMPL + t_SAR"): [`conversion_ns`]. The thruster's inputs and the order it reads them in each 1 ms
//! tick are [`THRUSTER_SEQUENCE`]; its phase currents, converted at TIM1's trigger, [`CURRENT_SEQUENCE`].

use crate::clock::ADC_HZ;

/// ADC_SMPRx SMPy values (RM0440): the sampling time in ADC clock cycles.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum SampleTime {
    /// 2.5 cycles.
    Cycles2_5,
    /// 6.5 cycles.
    Cycles6_5,
    /// 12.5 cycles.
    Cycles12_5,
    /// 24.5 cycles.
    Cycles24_5,
    /// 47.5 cycles.
    Cycles47_5,
    /// 92.5 cycles.
    Cycles92_5,
    /// 247.5 cycles.
    Cycles247_5,
    /// 640.5 cycles.
    Cycles640_5,
}

impl SampleTime {
    /// Every sample time, shortest first.
    pub const ALL: [SampleTime; 8] = [
        SampleTime::Cycles2_5,
        SampleTime::Cycles6_5,
        SampleTime::Cycles12_5,
        SampleTime::Cycles24_5,
        SampleTime::Cycles47_5,
        SampleTime::Cycles92_5,
        SampleTime::Cycles247_5,
        SampleTime::Cycles640_5,
    ];

    /// The longest.
    pub const LONGEST: SampleTime = SampleTime::Cycles640_5;

    /// The SMPy field value.
    pub const fn bits(self) -> u8 {
        self as u8
    }

    /// The sampling time in ADC clock cycles.
    pub const fn cycles(self) -> f64 {
        match self {
            SampleTime::Cycles2_5 => 2.5,
            SampleTime::Cycles6_5 => 6.5,
            SampleTime::Cycles12_5 => 12.5,
            SampleTime::Cycles24_5 => 24.5,
            SampleTime::Cycles47_5 => 47.5,
            SampleTime::Cycles92_5 => 92.5,
            SampleTime::Cycles247_5 => 247.5,
            SampleTime::Cycles640_5 => 640.5,
        }
    }
}

/// The parts of an ADC that bound what it can sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Adc {
    /// The sample-and-hold capacitor, in pF.
    pub c_adc_pf: f64,
    /// The sampling switch's resistance, in ohms.
    pub r_adc_ohms: f64,
    /// Resolution in bits.
    pub bits: u32,
}

/// The STM32G431's ADC in 12-bit mode (see the module documentation for the figures' source).
pub const G431: Adc = Adc {
    c_adc_pf: 5.0,
    r_adc_ohms: 0.0,
    bits: 12,
};

/// An ADC input's kind: DS12589 allows a fast channel (ADC1/2_IN1..IN5 on the G431) a larger source at the same
/// sample time than a slow one (every other input).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Channel {
    /// ADCx_IN1..IN5.
    Fast,
    /// The other inputs.
    Slow,
}

/// An analog input as the ADC sees it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Source {
    /// The largest Thevenin resistance of the source, in ohms.
    pub ohms: u32,
    /// A capacitor from the pin to ground, in pF (0 for none).
    pub hold_capacitor_pf: u32,
    /// The kind of input it is wired to.
    pub channel: Channel,
}

/// The ADC clock DS12589's R_AIN table is given for: 60 MHz.
pub const TABLE_ADC_HZ: u32 = 60_000_000;

/// Successive-approximation cycles of a 12-bit conversion (RM0440 21.4.16).
pub const SAR_CYCLES_12_BIT: f64 = 12.5;

/// One conversion at `sample` and `adc_hz`, in ns: the sample time and the 12.5 SAR cycles (RM0440 21.4.16).
pub const fn conversion_ns(sample: SampleTime, adc_hz: u32) -> f64 {
    (sample.cycles() + SAR_CYCLES_12_BIT) * 1e9 / adc_hz as f64
}

/// Conversions one after another, in ns.
pub const fn sequence_ns(samples: &[SampleTime], adc_hz: u32) -> f64 {
    let mut total = 0.0;
    let mut rest = samples;
    while let [sample, tail @ ..] = rest {
        total += conversion_ns(*sample, adc_hz);
        rest = tail;
    }
    total
}

/// ln 2.
const LN_2: f64 = core::f64::consts::LN_2;

impl Adc {
    /// ln(2^(N + 2)): the settling needed for 1/4 LSB.
    const fn settling(&self) -> f64 {
        (self.bits + 2) as f64 * LN_2
    }

    /// DS12589's "Maximum ADC R_AIN" at 12 bits and 60 MHz (see the module documentation for the figures'
    /// source): the largest source resistance `sample` allows on a `channel` input, in ohms; `None` where the table
    /// allows none (2.5 cycles on a slow channel). Valid for any ADC clock up to 60 MHz: a slower clock samples
    /// longer for the same count.
    pub const fn table_max_source_ohms(sample: SampleTime, channel: Channel) -> Option<u32> {
        let (fast, slow) = match sample {
            SampleTime::Cycles2_5 => (100, 0),
            SampleTime::Cycles6_5 => (330, 100),
            SampleTime::Cycles12_5 => (680, 470),
            SampleTime::Cycles24_5 => (1_500, 1_200),
            SampleTime::Cycles47_5 => (2_200, 1_800),
            SampleTime::Cycles92_5 => (4_700, 3_900),
            SampleTime::Cycles247_5 => (12_000, 10_000),
            SampleTime::Cycles640_5 => (39_000, 33_000),
        };
        let ohms = match channel {
            Channel::Fast => fast,
            Channel::Slow => slow,
        };
        if ohms == 0 { None } else { Some(ohms) }
    }

    /// Whether `source` settles by itself with `sample` at `adc_hz`: within both DS12589's table (for clocks up to
    /// its 60 MHz) and the 1/4 LSB formula.
    pub const fn settles_unheld(&self, source: Source, sample: SampleTime, adc_hz: u32) -> bool {
        let table = match Self::table_max_source_ohms(sample, source.channel) {
            Some(ohms) => adc_hz <= TABLE_ADC_HZ && source.ohms <= ohms,
            None => false,
        };
        table && source.ohms as f64 <= self.max_source_ohms(sample, adc_hz)
    }

    /// The largest source resistance `sample` settles within 1/4 LSB at an ADC clock of `adc_hz`, in ohms.
    pub const fn max_source_ohms(&self, sample: SampleTime, adc_hz: u32) -> f64 {
        sample.cycles() / (adc_hz as f64 * self.c_adc_pf * 1e-12 * self.settling()) - self.r_adc_ohms
    }

    /// The least capacitor at a pin that keeps the charge shared with C_ADC under 1/4 LSB after a full-scale
    /// step: C_ADC * 2^(N + 2), in pF.
    pub const fn min_hold_capacitor_pf(&self) -> f64 {
        self.c_adc_pf * (1u64 << (self.bits + 2)) as f64
    }

    /// Whether `source` is read within 1/4 LSB with `sample` at `adc_hz`: either it settles by itself
    /// ([`Adc::settles_unheld`]), or a large enough capacitor holds the pin and the longest sample time is used.
    pub const fn settles(&self, source: Source, sample: SampleTime, adc_hz: u32) -> bool {
        self.settles_unheld(source, sample, adc_hz)
            || (source.hold_capacitor_pf as f64 >= self.min_hold_capacitor_pf()
                && sample as u8 == SampleTime::LONGEST as u8)
    }

    /// The shortest sample time that reads `source` by itself ([`Adc::settles_unheld`]) at `adc_hz`; the longest
    /// when none does (then [`Adc::settles`] says whether its capacitor makes up for it).
    pub const fn sample_time(&self, source: Source, adc_hz: u32) -> SampleTime {
        let mut rest: &[SampleTime] = &SampleTime::ALL;
        while let [sample, tail @ ..] = rest {
            if self.settles_unheld(source, *sample, adc_hz) {
                return *sample;
            }
            rest = tail;
        }
        SampleTime::LONGEST
    }

    /// The error, in LSB, left on a held pin by repeated conversions: each conversion of a pin at a full-scale
    /// distance from what C_ADC last held takes C_ADC * V_FS from the pin's capacitor, which the source refills
    /// through `source_ohms`. In the steady state the pin sits short of the source by R / (R + 1 / (f C_ADC)) of
    /// full scale, f being the conversion rate: the conversions act as a switched-capacitor resistor. Independent
    /// of the hold capacitor's size.
    pub const fn recharge_error_lsb(&self, source_ohms: u32, conversions_per_s: u32) -> f64 {
        let switched = 1.0 / (conversions_per_s as f64 * self.c_adc_pf * 1e-12);
        let r = source_ohms as f64;
        (1u64 << self.bits) as f64 * r / (r + switched)
    }
}

/// The thruster's water sensor on PB12 (ADC1_IN11, a slow channel): the electrodes (1 Mohm at the water threshold,
/// open when dry) over a 1 Mohm pull-down, so the source is at most 1 Mohm; 100 nF at the pin, the first E6 value
/// above the 82 nF [`Adc::min_hold_capacitor_pf`] asks for. The RC of 1 Mohm and 100 nF (100 ms) delays a water
/// reading by a fraction of a second, well within what a leak allows.
pub const WATER: Source = Source {
    ohms: 1_000_000,
    hold_capacitor_pf: 100_000,
    channel: Channel::Slow,
};

/// A 10 kohm NTC with a 10 kohm (motor) or 4.7 kohm (IHM08M1) fixed resistor: the parallel pair never exceeds the
/// fixed resistor. On PB11 (ADC12_IN14) or the IHM08M1's PC2 (ADC12_IN8): slow channels.
pub const NTC: Source = Source {
    ohms: 10_000,
    hold_capacitor_pf: 0,
    channel: Channel::Slow,
};

/// The IHM08M1's three current-sense amplifier outputs, CURR_FDBK_A/B/C on PA0, PC1 and PC0 (ADC12_IN1, a fast
/// channel; IN7 and IN6, slow ones: the slow limits apply). Each is a TSV994 stage driving the pin through the
/// board's 0 ohm links (R47, R48, R50); what else sits in series is not in the documents read here, so 1 kohm is
/// budgeted. The sample time this gives is short enough for the three conversions to fit well inside the quiet
/// middle of a PWM half-period (`tim1::Bridge::sample_window_ticks`); a board with more resistance there shows
/// it at the first power-up's step 6 (docs/hardware.md).
pub const CURRENT: Source = Source {
    ohms: 1_000,
    hold_capacitor_pf: 0,
    channel: Channel::Slow,
};

/// The IHM08M1's VBUS divider on PA1 (ADC12_IN2, a fast channel): 169 kohm over 9.31 kohm, 8.8 kohm seen from the
/// pin (thruster-fw's `VbusSense::IHM08M1`); whatever capacitor the board puts across it only helps.
pub const VBUS: Source = Source {
    ohms: 8_824,
    hold_capacitor_pf: 0,
    channel: Channel::Fast,
};

/// The thruster's sample times (the shortest each source allows, [`Adc::sample_time`]): the water sensor relies on
/// its 100 nF and the longest time; the NTC needs 247.5 cycles by DS12589's table (10 kohm: the slow channels'
/// limit at 247.5), where the formula alone gave 24.5; the currents 24.5 (1.2 kohm on a slow channel).
pub const WATER_SAMPLE: SampleTime = G431.sample_time(WATER, ADC_HZ);
/// See [`WATER_SAMPLE`].
pub const NTC_SAMPLE: SampleTime = G431.sample_time(NTC, ADC_HZ);
/// See [`WATER_SAMPLE`].
pub const CURRENT_SAMPLE: SampleTime = G431.sample_time(CURRENT, ADC_HZ);
/// See [`WATER_SAMPLE`].
pub const VBUS_SAMPLE: SampleTime = G431.sample_time(VBUS, ADC_HZ);

const _: () = assert!(
    G431.settles(WATER, WATER_SAMPLE, ADC_HZ)
        && G431.settles(NTC, NTC_SAMPLE, ADC_HZ)
        && G431.settles(CURRENT, CURRENT_SAMPLE, ADC_HZ)
        && G431.settles(VBUS, VBUS_SAMPLE, ADC_HZ)
);

/// The regular conversions of one thruster sample, started by software in this order: the water sensor, the NTC
/// and the supply. They block the thread executor: [`THRUSTER_SEQUENCE_NS`] is held against the 1 ms tick by
/// thruster-fw's tests. (STM32G4 errata ES0431: the first conversion after the ADC idled about 1 ms may be wrong;
/// the injected conversions of the currents keep it from idling, one sequence per PWM period.)
pub const THRUSTER_SEQUENCE: [SampleTime; 3] = [WATER_SAMPLE, NTC_SAMPLE, VBUS_SAMPLE];

/// How long [`THRUSTER_SEQUENCE`] takes at [`ADC_HZ`], in ns, an injected sequence aside: about 31.8 us.
pub const THRUSTER_SEQUENCE_NS: f64 = sequence_ns(&THRUSTER_SEQUENCE, ADC_HZ);

/// The injected sequence TIM1 triggers once per PWM period: the three phase currents.
pub const CURRENT_SEQUENCE: [SampleTime; 3] = [CURRENT_SAMPLE; 3];

/// How long [`CURRENT_SEQUENCE`] takes at [`ADC_HZ`], in ns: about 2.6 us.
pub const CURRENT_SEQUENCE_NS: f64 = sequence_ns(&CURRENT_SEQUENCE, ADC_HZ);

/// ADC_SMPR1 and ADC_SMPR2 with each of `inputs` (an ADCx_INn number and its sample time) in its field: SMPR1
/// holds channels 0..=9 and SMPR2 10..=18, three bits each (RM0440 ADC_SMPR1, ADC_SMPR2); others are left out.
/// Written once, whole: RM0440 allows SMPRx writes only while no conversion runs (ADSTART = JADSTART = 0), and
/// the injected conversions never stop.
pub const fn smpr(inputs: &[(u8, SampleTime)]) -> [u32; 2] {
    let mut registers = [0u32; 2];
    let mut rest = inputs;
    while let [(channel, sample), tail @ ..] = rest {
        let channel = *channel as u32;
        if channel < 10 {
            registers[0] |= (sample.bits() as u32) << (3 * channel);
        } else if channel < 19 {
            registers[1] |= (sample.bits() as u32) << (3 * (channel - 10));
        }
        rest = tail;
    }
    registers
}

/// ADC_JSQR.JEXTSEL for TIM1_TRGO2 on ADC1 and ADC2 (RM0440 21.4.18, the table of external triggers for injected
/// channels: JEXT8; stm32-data lists ADC1's ADC_JEXT_TRG8 as TIM1_TRGO2 too).
pub const JEXTSEL_TIM1_TRGO2: u32 = 8;

/// ADC_JSQR.JEXTEN: a hardware trigger, on its rising edge.
pub const JEXTEN_RISING: u32 = 0b01;

/// ADC_JSQR for an injected sequence of `channels` (ADCx_INn numbers, in order) started by TIM1_TRGO2's rising
/// edge: JL = length - 1, JEXTSEL, JEXTEN, JSQ1..JSQ3 (RM0440 ADC_JSQR). Channel numbers above 31 are masked to
/// their 5-bit field.
pub const fn jsqr(channels: [u8; 3]) -> u32 {
    let [first, second, third] = channels;
    (channels.len() as u32 - 1)
        | (JEXTSEL_TIM1_TRGO2 << 2)
        | (JEXTEN_RISING << 7)
        | ((first as u32 & 0x1F) << 9)
        | ((second as u32 & 0x1F) << 15)
        | ((third as u32 & 0x1F) << 21)
}

#[cfg(test)]
mod tests {
    use super::*;
    use stm32_metapac::adc::vals::SampleTime as PacSampleTime;

    /// The STM32F103's ADC: C_ADC 8 pF, R_ADC 1 kohm (its datasheets' ADC characteristics).
    const F103: Adc = Adc {
        c_adc_pf: 8.0,
        r_adc_ohms: 1_000.0,
        bits: 12,
    };

    #[test]
    fn formula_reproduces_the_datasheet_table() {
        // STM32F103x4/x6 (Doc ID 15060) table 47, R_AIN max for f_ADC = 14 MHz: cycles -> kohm.
        let table = [
            (1.5, 0.4),
            (7.5, 5.9),
            (13.5, 11.4),
            (28.5, 25.2),
            (41.5, 37.2),
            (55.5, 50.0),
        ];
        for (cycles, kohm) in table {
            let r = cycles / (14e6 * F103.c_adc_pf * 1e-12 * F103.settling()) - F103.r_adc_ohms;
            assert!((r / 1000.0 - kohm).abs() < 0.1, "{cycles}: {r}");
        }
    }

    #[test]
    fn the_water_sensor_cannot_be_read_without_its_capacitor() {
        // The binding before: 47.5 cycles at 42.5 MHz settles about 23 kohm, a fiftieth of the sensor.
        assert!((G431.max_source_ohms(SampleTime::Cycles47_5, ADC_HZ) - 23_030.0).abs() < 10.0);
        let bare = Source {
            hold_capacitor_pf: 0,
            ..WATER
        };
        assert!(!G431.settles(bare, SampleTime::Cycles47_5, ADC_HZ));
        // Not even the longest sample time does: about 310 kohm.
        assert!(G431.max_source_ohms(SampleTime::LONGEST, ADC_HZ) < 320_000.0);
        assert!(!G431.settles(bare, SampleTime::LONGEST, ADC_HZ));
        // With 100 nF at the pin and the longest time it does.
        assert_eq!(G431.sample_time(WATER, ADC_HZ), SampleTime::LONGEST);
        assert!(G431.settles(WATER, SampleTime::LONGEST, ADC_HZ));
        assert!(!G431.settles(WATER, SampleTime::Cycles47_5, ADC_HZ));
        assert!((G431.min_hold_capacitor_pf() - 81_920.0).abs() < 1.0);
        assert!(f64::from(WATER.hold_capacitor_pf) >= G431.min_hold_capacitor_pf());
    }

    #[test]
    fn repeated_conversions_leave_the_thresholds_where_they_are() {
        // Sampled at 1 kHz. The source is the electrodes in parallel with the 1 Mohm pull-down.
        let parallel = |ohms: f64| ohms * 1e6 / (ohms + 1e6);
        // At the 1 Mohm water threshold (node at mid-scale, 1.02 counts per kohm): 10 LSB, 1 % of the threshold.
        let water = G431.recharge_error_lsb(parallel(1e6) as u32, 1_000);
        assert!(water < 10.5, "{water}");
        let counts_per_ohm = 4095.0 * 1e6 / (2e6 * 2e6);
        assert!(water / counts_per_ohm < 0.011 * 1e6);
        // At the 100 kohm ground threshold (3.38 counts per kohm): under 2 LSB, 0.6 % of the threshold.
        let ground = G431.recharge_error_lsb(parallel(1e5) as u32, 1_000);
        assert!(ground < 2.0, "{ground}");
        let counts_per_ohm = 4095.0 * 1e6 / (1.1e6 * 1.1e6);
        assert!(ground / counts_per_ohm < 0.006 * 1e5);
    }

    #[test]
    fn the_datasheet_table_is_stricter_than_the_formula() {
        // At the table's own 60 MHz, every row allows less than the 5 pF / 0 ohm formula: the table decides.
        for sample in SampleTime::ALL {
            for channel in [Channel::Fast, Channel::Slow] {
                let formula = G431.max_source_ohms(sample, TABLE_ADC_HZ);
                if let Some(table) = Adc::table_max_source_ohms(sample, channel) {
                    assert!(
                        f64::from(table) < formula / 2.0,
                        "{sample:?} {channel:?}: {table} vs {formula}"
                    );
                }
            }
        }
        // 24.5 cycles, what the formula alone chose for 10 kohm: 1.5 / 1.2 kohm by the table.
        assert_eq!(
            Adc::table_max_source_ohms(SampleTime::Cycles24_5, Channel::Fast),
            Some(1_500)
        );
        assert_eq!(
            Adc::table_max_source_ohms(SampleTime::Cycles24_5, Channel::Slow),
            Some(1_200)
        );
        // A slow channel cannot sample in 2.5 cycles at all; the fast and slow columns grow with the time.
        assert_eq!(Adc::table_max_source_ohms(SampleTime::Cycles2_5, Channel::Slow), None);
        let column = |channel| SampleTime::ALL.map(|sample| Adc::table_max_source_ohms(sample, channel).unwrap_or(0));
        for (fast, slow) in column(Channel::Fast).into_iter().zip(column(Channel::Slow)) {
            assert!(fast > slow);
        }
        assert!(column(Channel::Slow).windows(2).all(|pair| pair[0] < pair[1]));
        // Above the table's 60 MHz nothing settles unheld.
        assert!(!G431.settles_unheld(NTC, SampleTime::LONGEST, 80_000_000));
    }

    #[test]
    fn other_inputs_settle_on_their_own() {
        // 10 kohm on a slow channel: 247.5 cycles (the table's 10 kohm), not 92.5 (3.9 kohm).
        let sample = G431.sample_time(NTC, ADC_HZ);
        assert_eq!(sample, SampleTime::Cycles247_5);
        assert!(G431.settles(NTC, sample, ADC_HZ));
        assert!(!G431.settles(NTC, SampleTime::Cycles92_5, ADC_HZ));
        assert!(!G431.settles(NTC, SampleTime::Cycles24_5, ADC_HZ), "the old choice");
        // The currents' 1 kohm on a slow channel: 24.5 cycles (1.2 kohm), not 12.5 (470 ohm).
        assert_eq!(G431.sample_time(CURRENT, ADC_HZ), SampleTime::Cycles24_5);
        assert!(!G431.settles(CURRENT, SampleTime::Cycles12_5, ADC_HZ));
        // VBUS's 8.8 kohm on a fast channel: 247.5 as well.
        assert!(!G431.settles(VBUS, SampleTime::Cycles92_5, ADC_HZ));
        assert_eq!(
            (WATER_SAMPLE, NTC_SAMPLE, CURRENT_SAMPLE, VBUS_SAMPLE),
            (
                SampleTime::LONGEST,
                SampleTime::Cycles247_5,
                SampleTime::Cycles24_5,
                SampleTime::Cycles247_5
            )
        );
    }

    #[test]
    fn a_thruster_sample_takes_28_us_and_the_currents_2_6_us() {
        // RM0440 21.4.16: t_CONV = t_SMPL + 12.5 cycles at 12 bits. 640.5 + 12.5 cycles at 42.5 MHz: 15.36 us.
        assert!((conversion_ns(SampleTime::LONGEST, ADC_HZ) - 15_364.7).abs() < 0.1);
        assert!((conversion_ns(SampleTime::Cycles247_5, ADC_HZ) - 6_117.6).abs() < 0.1);
        // Water, NTC, VBUS: 1173 cycles, 27.6 us.
        assert!((THRUSTER_SEQUENCE_NS - 1173.0 / 42.5e6 * 1e9).abs() < 0.1);
        // The three currents: 3 x 37 cycles, 2.6 us.
        assert!((CURRENT_SEQUENCE_NS - 111.0 / 42.5e6 * 1e9).abs() < 0.1);
        assert_eq!(sequence_ns(&[], ADC_HZ), 0.0);
    }

    #[test]
    fn smpr_agrees_with_the_pac() {
        use stm32_metapac::adc::regs::{Smpr, Smpr2};
        let inputs = [
            (1, SampleTime::Cycles24_5),
            (2, SampleTime::Cycles247_5),
            (9, SampleTime::LONGEST),
            (11, SampleTime::LONGEST),
            (18, SampleTime::Cycles6_5),
            (19, SampleTime::LONGEST),
        ];
        let (mut smpr1, mut smpr2) = (Smpr(0), Smpr2(0));
        for (channel, sample) in inputs.into_iter().take(5) {
            let field = PacSampleTime::from_bits(sample.bits());
            if channel < 10 {
                smpr1.set_smp(usize::from(channel), field);
            } else {
                smpr2.set_smp(usize::from(channel - 10), field);
            }
        }
        assert_eq!(smpr(&inputs), [smpr1.0, smpr2.0]);
        assert_eq!(smpr(&[]), [0, 0]);
    }

    #[test]
    fn jsqr_agrees_with_the_pac() {
        use stm32_metapac::adc::regs::Jsqr;
        use stm32_metapac::adc::vals::Exten;
        let mut want = Jsqr(0);
        want.set_jl(2);
        want.set_jextsel(8);
        want.set_jexten(Exten::RISING_EDGE);
        for (n, channel) in [1, 7, 6].into_iter().enumerate() {
            want.set_jsq(n, channel);
        }
        assert_eq!(jsqr([1, 7, 6]), want.0);
        // Out-of-range channel numbers stay in their fields.
        assert_eq!(jsqr([0xFF, 0, 0]) & !(0x1F << 9), jsqr([0, 0, 0]));
    }

    #[test]
    fn field_values_agree_with_the_pac() {
        let pac = [
            PacSampleTime::CYCLES2_5,
            PacSampleTime::CYCLES6_5,
            PacSampleTime::CYCLES12_5,
            PacSampleTime::CYCLES24_5,
            PacSampleTime::CYCLES47_5,
            PacSampleTime::CYCLES92_5,
            PacSampleTime::CYCLES247_5,
            PacSampleTime::CYCLES640_5,
        ];
        for (ours, theirs) in SampleTime::ALL.into_iter().zip(pac) {
            assert_eq!(ours.bits(), theirs.to_bits());
        }
    }
}
