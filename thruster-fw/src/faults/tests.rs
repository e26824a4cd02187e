//! The latches across resets, then the fault table with and without its filters, and the stall detectors.

use super::*;
use crate::ports::LatchStore;
use tmc_proto::{LegacyRevision, LegacyStatus, MaxPower, MotorKind, SeaBotixStatus};

#[test]
fn latches_survive_every_reset_but_a_power_cycle() {
    for family in Family::ALL {
        let mut m = monitor(family);
        m.update(water(50_000), false);
        let latched = m.latched();
        let expected = match family {
            Family::Legacy => Faults::GROUND | Faults::WATER,
            Family::SeaBotix => Faults::GROUND,
        };
        assert_eq!(latched, expected);
        let word = latch_word(latched);
        // A watchdog or pin reset: the new monitor starts with the latches and does not drive.
        let mut after_reset = monitor(family);
        after_reset.restore(carried_latch(ResetKind::Other, word));
        assert_eq!(after_reset.update(HEALTHY, false), expected);
        assert!(!after_reset.drive_allowed());
        // A power cycle: clean.
        let mut after_power = monitor(family);
        after_power.restore(carried_latch(ResetKind::PowerCycle, word));
        assert_eq!(after_power.update(HEALTHY, false), Faults::NONE);
        assert!(after_power.drive_allowed());
    }
}

#[test]
fn only_power_cycle_latches_are_carried() {
    // Stall, hall and overtemp never come back from a store, nor a SeaBotix water warning.
    let mut m = monitor(Family::SeaBotix);
    m.restore(Faults::ALL);
    assert_eq!(m.faults(), Faults::GROUND);
    let mut m = monitor(Family::Legacy);
    m.restore(Faults::ALL);
    assert_eq!(m.faults(), Faults::GROUND | Faults::WATER);
    // Nor do overtemp and stall get saved.
    let mut m = monitor(Family::Legacy);
    m.update(temperature(1200), true);
    assert_eq!(m.latched(), Faults::NONE);
}

#[test]
fn a_latch_word_that_was_not_written_reads_as_none() {
    for faults in (0..=0x1F).map(Faults::from_bits_truncate) {
        assert_eq!(latch_from_word(latch_word(faults)), faults);
    }
    // Zero (a backup register after a power-on), all ones, and near misses.
    for word in [
        0,
        u32::MAX,
        latch_word(Faults::GROUND) ^ 1,
        latch_word(Faults::GROUND) ^ 0x1_0000,
    ] {
        assert_eq!(latch_from_word(word), Faults::NONE, "{word:#x}");
    }
    let mut store = VolatileLatch::default();
    assert_eq!(store.load(), Faults::NONE);
    store.save(Faults::GROUND);
    assert_eq!(store.load(), Faults::GROUND);
}

const HEALTHY: Sample = Sample {
    water_ohms: u32::MAX,
    temperature_decicelsius: 250,
    halls_normal: true,
};

fn water(ohms: u32) -> Sample {
    Sample {
        water_ohms: ohms,
        ..HEALTHY
    }
}

fn temperature(decicelsius: i16) -> Sample {
    Sample {
        temperature_decicelsius: decicelsius,
        ..HEALTHY
    }
}

const BAD_HALLS: Sample = Sample {
    halls_normal: false,
    ..HEALTHY
};

/// The table without its filters: one sample sets and clears, water clears at the threshold itself. The
/// table's tests use it; the filters have tests of their own with [`Thresholds::SPEC`].
const UNFILTERED: Thresholds = Thresholds {
    water_clear_ohms: 1_000_000,
    latch_samples: 1,
    hall_error_samples: 1,
    ..Thresholds::SPEC
};

fn monitor(family: Family) -> FaultMonitor {
    FaultMonitor::new(family, UNFILTERED)
}

fn filtered(family: Family) -> FaultMonitor {
    FaultMonitor::new(family, Thresholds::SPEC)
}

fn speed(step: i8) -> Speed {
    Speed::new(step).unwrap()
}

fn ms(millis: u64) -> Instant {
    Instant::from_millis(millis)
}

fn duty(value: i32) -> Duty {
    Duty::new_saturating(value)
}

/// Everything short of a new monitor: healthy and unhealthy samples, every kind of order. After it the
/// transient faults are clear again.
fn everything_but_power_cycle(m: &mut FaultMonitor) {
    for _ in 0..3 {
        m.update(HEALTHY, false);
    }
    m.on_order(Speed::ZERO);
    m.on_order(speed(102));
    m.on_order(speed(-102));
    m.update(temperature(i16::MAX), false);
    m.update(temperature(i16::MIN), false);
    m.update(BAD_HALLS, false);
    m.update(water(u32::MAX), true);
    m.on_order(Speed::ZERO);
    m.update(HEALTHY, false);
    m.on_order(Speed::ZERO);
}

#[test]
fn spec_thresholds() {
    let t = Thresholds::SPEC;
    assert_eq!(t.water_ohms, 1_000_000);
    assert_eq!(t.ground_ohms, 100_000);
    assert_eq!(t.overtemp_set_decicelsius, 1100);
    assert_eq!(t.overtemp_clear_decicelsius, 1000);
    assert_eq!(t.stall_duty, 800);
    assert_eq!(t.stall_window, Duration::from_millis(400));
    assert_eq!(t.stall_min_pulses, 3);
    assert_eq!(t.water_clear_ohms, 1_100_000);
    assert_eq!(t.latch_samples, 3);
    assert_eq!(t.hall_error_samples, 3);
    assert_eq!(t.armature_milliohms, 1_200);
}

#[test]
fn one_ground_sample_does_not_latch_but_three_in_a_row_do() {
    for family in Family::ALL {
        let mut m = filtered(family);
        // Single 90 kohm samples (a spike, or ES0431's wrong first conversion) between dry ones.
        for _ in 0..10 {
            assert_eq!(m.update(water(90_000), false), Faults::NONE, "{family:?}");
            assert_eq!(m.update(water(90_000), false), Faults::NONE, "{family:?}");
            assert_eq!(m.update(HEALTHY, false), Faults::NONE, "{family:?}");
        }
        assert!(m.drive_allowed());
        m.update(water(90_000), false);
        m.update(water(90_000), false);
        assert_eq!(m.update(water(90_000), false), Faults::GROUND | Faults::WATER);
        assert!(!m.drive_allowed());
        for _ in 0..10 {
            m.update(HEALTHY, false);
        }
        assert!(m.faults().contains(Faults::GROUND));
    }
}

#[test]
fn legacy_water_needs_three_samples_to_latch() {
    let mut m = filtered(Family::Legacy);
    assert_eq!(m.update(water(999_999), false), Faults::NONE);
    assert_eq!(m.update(water(999_999), false), Faults::NONE);
    assert_eq!(m.update(HEALTHY, false), Faults::NONE);
    for _ in 0..2 {
        assert_eq!(m.update(water(500_000), false), Faults::NONE);
    }
    assert_eq!(m.update(water(500_000), false), Faults::WATER);
    assert_eq!(m.update(HEALTHY, false), Faults::WATER);
}

#[test]
fn seabotix_water_at_its_threshold_does_not_chatter() {
    let sensor = crate::sensors::WaterSensor {
        pull_down_ohms: 1_000_000,
    };
    let at = sensor.raw_at(1_000_000);
    let mut m = filtered(Family::SeaBotix);
    let mut changes = 0;
    let mut last = Faults::NONE;
    // One ADC count either side of 1 Mohm, in every pattern of a slow pseudo-random walk, for 2 s.
    let mut state: u32 = 0x2545_F491;
    for _ in 0..2000 {
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        let raw = match state % 3 {
            0 => at - 1,
            1 => at,
            _ => at + 1,
        };
        let faults = m.update(water(sensor.resistance_ohms(raw)), false);
        if faults != last {
            changes += 1;
            last = faults;
        }
    }
    assert!(changes <= 1, "{changes} changes of the warning");
    // It clears above the band, after three samples there.
    assert!(m.faults().contains(Faults::WATER));
    assert_eq!(m.update(water(1_099_999), false), Faults::WATER);
    assert_eq!(m.update(water(1_100_000), false), Faults::WATER);
    assert_eq!(m.update(water(1_100_000), false), Faults::WATER);
    assert_eq!(m.update(water(1_100_000), false), Faults::NONE);
    assert!(m.drive_allowed());
}

#[test]
fn one_or_two_bad_hall_readings_are_not_a_hall_error() {
    for family in Family::ALL {
        let mut m = filtered(family);
        for _ in 0..20 {
            assert_eq!(m.update(BAD_HALLS, false), Faults::NONE);
            assert_eq!(m.update(BAD_HALLS, false), Faults::NONE);
            assert_eq!(m.update(HEALTHY, false), Faults::NONE);
            assert!(m.drive_allowed());
        }
        m.update(BAD_HALLS, false);
        m.update(BAD_HALLS, false);
        assert_eq!(m.update(BAD_HALLS, false), Faults::HALL);
        assert!(!m.drive_allowed());
        assert_eq!(m.update(HEALTHY, false), Faults::NONE);
    }
}

#[test]
fn progress_counts_only_new_ground_in_the_driven_direction() {
    let mut p = Progress::new();
    let forward = Some(Direction::Forward);
    assert_eq!(p.advance(10, forward), 0);
    // Rocking across one boundary: one pulse at most.
    let mut pulses = 0;
    for position in [11, 10, 11, 10, 11, 10, 11] {
        pulses += p.advance(position, forward);
    }
    assert_eq!(pulses, 1);
    assert_eq!(p.advance(13, forward), 2);
    // Turning backwards while driven forward counts nothing, nor does coming back.
    assert_eq!(p.advance(5, forward), 0);
    assert_eq!(p.advance(13, forward), 0);
    assert_eq!(p.advance(14, forward), 1);
    // Driven in reverse: progress is downwards, from where the rotor is when the direction changes.
    let reverse = Some(Direction::Reverse);
    assert_eq!(p.advance(14, reverse), 0);
    assert_eq!(p.advance(12, reverse), 2);
    assert_eq!(p.advance(13, reverse), 0);
    // Not driven: the mark goes.
    assert_eq!(p.advance(0, None), 0);
    assert_eq!(p.advance(-3, reverse), 0);
    assert_eq!(p.advance(-4, reverse), 1);
    // Across the wrap of the count.
    let mut p = Progress::new();
    assert_eq!(p.advance(i32::MAX, forward), 0);
    assert_eq!(p.advance(i32::MIN, forward), 1);
}

/// A brushed sample at 24 V, the break quiet.
fn brushed(duty_value: i32, current_deciamps: u16) -> BrushedSample {
    BrushedSample {
        duty: duty(duty_value),
        current_deciamps,
        vbus_mv: 24_000,
        break_tripped: false,
    }
}

#[test]
fn a_locked_brushed_rotor_stalls_after_the_window() {
    let mut s = CurrentStall::new(&Thresholds::SPEC);
    // 95 % of 24 V is 22.8 V: a locked rotor draws 19 A through 1.2 ohm, no back-EMF.
    assert_eq!(s.back_emf_mv(&brushed(9500, 190)), (0, 22_800));
    assert!(!s.update(ms(0), brushed(9500, 190)));
    assert!(!s.update(ms(399), brushed(9500, 190)));
    assert!(s.update(ms(400), brushed(9500, 190)));
    // Held by the thruster's own current limit at 7 A, the duty down to 35 %: still no back-EMF.
    let mut s = CurrentStall::new(&Thresholds::SPEC);
    assert!(!s.update(ms(0), brushed(3500, 70)));
    assert!(s.update(ms(400), brushed(-3500, 70)));
    // A locked rotor at 10 % duty draws 2 A.
    let mut s = CurrentStall::new(&Thresholds::SPEC);
    assert!(!s.update(ms(0), brushed(1000, 20)));
    assert!(s.update(ms(400), brushed(1000, 20)));
}

#[test]
fn a_turning_brushed_motor_never_stalls() {
    let mut s = CurrentStall::new(&Thresholds::SPEC);
    for t in 0..2000 {
        // Full speed: 4 A, 18 V of back-EMF.
        assert!(!s.update(ms(t), brushed(9500, 40)));
    }
    // Half the applied voltage is the edge: 8.4 V applied, 4.2 V of back-EMF (3.5 A) turns, 4.08 V (3.6 A) not.
    assert_eq!(s.back_emf_mv(&brushed(3500, 35)), (4_200, 8_400));
    assert!(!s.update(ms(3000), brushed(3500, 35)));
    assert!(!s.update(ms(3400), brushed(3500, 35)));
    assert!(!s.update(ms(3401), brushed(3500, 36)));
    assert!(s.update(ms(3801), brushed(3500, 36)));
    // A reversal: full reverse into a rotor still turning ahead draws 30 A, its back-EMF against the drive.
    let mut s = CurrentStall::new(&Thresholds::SPEC);
    assert_eq!(s.back_emf_mv(&brushed(-9500, 300)), (-13_200, 22_800));
    for t in 0..2000 {
        assert!(!s.update(ms(t), brushed(-9500, 300)));
    }
}

#[test]
fn a_brushed_stall_needs_the_duty_a_known_voltage_and_no_break() {
    // 8 % is not above 8 %.
    let mut s = CurrentStall::new(&Thresholds::SPEC);
    for t in 0..1000 {
        assert!(!s.update(ms(t), brushed(800, 16)));
    }
    // A break trip (the stage cut the pulses: the voltage applied is not known) restarts the window.
    let mut s = CurrentStall::new(&Thresholds::SPEC);
    assert!(!s.update(ms(0), brushed(9500, 190)));
    let tripped = BrushedSample {
        break_tripped: true,
        ..brushed(9500, 80)
    };
    assert!(!s.update(ms(300), tripped));
    assert!(!s.update(ms(301), brushed(9500, 190)));
    assert!(!s.update(ms(700), brushed(9500, 190)));
    assert!(s.update(ms(701), brushed(9500, 190)));
    s.reset();
    assert!(!s.update(ms(702), brushed(9500, 190)));
    // No supply read (VBUS 0): nothing is applied, nothing stalls.
    let mut s = CurrentStall::new(&Thresholds::SPEC);
    let unpowered = BrushedSample {
        vbus_mv: 0,
        ..brushed(9500, 0)
    };
    for t in 0..1000 {
        assert!(!s.update(ms(t), unpowered));
    }
    // Extremes neither panic nor stall on nonsense.
    let mut s = CurrentStall::new(&Thresholds::SPEC);
    let extreme = BrushedSample {
        duty: duty(i32::MIN),
        current_deciamps: u16::MAX,
        vbus_mv: u32::MAX,
        break_tripped: false,
    };
    let _ = s.back_emf_mv(&extreme);
    let _ = s.update(ms(0), extreme);
}

#[test]
fn healthy_samples_report_nothing() {
    for family in Family::ALL {
        let mut m = monitor(family);
        assert_eq!(m.faults(), Faults::NONE);
        assert!(m.drive_allowed());
        for _ in 0..10 {
            assert_eq!(m.update(HEALTHY, false), Faults::NONE);
            assert!(m.drive_allowed());
        }
        // The edges of every threshold on their healthy side.
        assert_eq!(m.update(water(1_000_000), false), Faults::NONE);
        assert_eq!(m.update(temperature(1099), false), Faults::NONE);
        assert_eq!(m.update(temperature(i16::MIN), false), Faults::NONE);
        assert!(m.drive_allowed());
    }
}

#[test]
fn legacy_water_stops_and_latches() {
    let mut m = monitor(Family::Legacy);
    assert_eq!(m.update(water(1_000_000), false), Faults::NONE);
    assert!(m.drive_allowed());
    assert_eq!(m.update(water(999_999), false), Faults::WATER);
    assert!(!m.drive_allowed());
    // Dry again: still latched.
    assert_eq!(m.update(water(1_000_000), false), Faults::WATER);
    everything_but_power_cycle(&mut m);
    assert_eq!(m.faults(), Faults::WATER);
    assert!(!m.drive_allowed());
    assert_eq!(m.update(HEALTHY, false), Faults::WATER);
    // Power cycle.
    let mut m = monitor(Family::Legacy);
    assert_eq!(m.update(HEALTHY, false), Faults::NONE);
    assert!(m.drive_allowed());
}

#[test]
fn seabotix_water_warns_and_clears() {
    let mut m = monitor(Family::SeaBotix);
    assert_eq!(m.update(water(1_000_000), false), Faults::NONE);
    assert_eq!(m.update(water(999_999), false), Faults::WATER);
    assert!(m.drive_allowed());
    assert_eq!(m.update(water(100_000), false), Faults::WATER);
    assert!(m.drive_allowed());
    assert_eq!(m.update(water(1_000_000), false), Faults::NONE);
    assert!(m.drive_allowed());
    assert_eq!(m.update(water(0xFFFF_FFFF), false), Faults::NONE);
    assert_eq!(m.update(water(999_999), false), Faults::WATER);
    assert_eq!(m.update(HEALTHY, false), Faults::NONE);
}

#[test]
fn ground_fault_stops_and_latches_in_both_families() {
    for family in Family::ALL {
        let mut m = monitor(family);
        // 100 kohm is water but not yet ground.
        assert_eq!(m.update(water(100_000), false), Faults::WATER, "{family:?}");
        assert_eq!(m.drive_allowed(), family == Family::SeaBotix);
        assert_eq!(m.update(water(99_999), false), Faults::GROUND | Faults::WATER);
        assert!(!m.drive_allowed());
        assert_eq!(m.update(water(0), false), Faults::GROUND | Faults::WATER);
        // Dry again: the ground fault stays; the water bit follows the family's rule.
        let after = match family {
            Family::Legacy => Faults::GROUND | Faults::WATER,
            Family::SeaBotix => Faults::GROUND,
        };
        assert_eq!(m.update(HEALTHY, false), after);
        assert!(!m.drive_allowed());
        everything_but_power_cycle(&mut m);
        assert_eq!(m.faults(), after);
        assert!(!m.drive_allowed());
        let mut m = monitor(family);
        assert_eq!(m.update(HEALTHY, false), Faults::NONE);
        assert!(m.drive_allowed());
    }
}

#[test]
fn overtemp_hysteresis_in_both_families() {
    for family in Family::ALL {
        let mut m = monitor(family);
        assert_eq!(m.update(temperature(1099), false), Faults::NONE);
        assert!(m.drive_allowed());
        assert_eq!(m.update(temperature(1100), false), Faults::OVERTEMP);
        assert!(!m.drive_allowed());
        for t in [1099, 1050, 1001, 1100, i16::MAX, 1001] {
            assert_eq!(m.update(temperature(t), false), Faults::OVERTEMP, "{family:?} {t}");
            assert!(!m.drive_allowed());
        }
        // Orders change nothing.
        m.on_order(Speed::ZERO);
        assert_eq!(m.faults(), Faults::OVERTEMP);
        assert_eq!(m.update(temperature(1000), false), Faults::NONE);
        assert!(m.drive_allowed());
        // Rising again through the band stays clear until 110.0 C.
        for t in [1001, 1050, 1099] {
            assert_eq!(m.update(temperature(t), false), Faults::NONE);
            assert!(m.drive_allowed());
        }
        assert_eq!(m.update(temperature(1100), false), Faults::OVERTEMP);
        assert_eq!(m.update(temperature(i16::MIN), false), Faults::NONE);
    }
}

#[test]
fn one_hot_sample_does_not_stop_the_motor_but_three_in_a_row_do() {
    for family in Family::ALL {
        let mut m = filtered(family);
        // A noisy conversion now and then (110.5 C, once or twice in a row) among 60 C readings.
        for _ in 0..10 {
            assert_eq!(m.update(temperature(1105), false), Faults::NONE, "{family:?}");
            assert_eq!(m.update(temperature(1105), false), Faults::NONE, "{family:?}");
            assert_eq!(m.update(temperature(600), false), Faults::NONE, "{family:?}");
        }
        assert!(m.drive_allowed());
        m.update(temperature(1105), false);
        m.update(temperature(1105), false);
        assert_eq!(
            m.update(temperature(1105), false),
            Faults::OVERTEMP,
            "{family:?}: the third in a row"
        );
        assert!(!m.drive_allowed());
        // Clearing takes as many at or below 100 C: one low reading does not restart a hot motor.
        for _ in 0..10 {
            assert_eq!(m.update(temperature(990), false), Faults::OVERTEMP);
            assert_eq!(m.update(temperature(990), false), Faults::OVERTEMP);
            assert_eq!(m.update(temperature(1050), false), Faults::OVERTEMP);
        }
        m.update(temperature(990), false);
        m.update(temperature(990), false);
        assert_eq!(m.update(temperature(990), false), Faults::NONE, "{family:?}");
        assert!(m.drive_allowed());
    }
}

#[test]
fn stall_latches_until_a_zero_order() {
    for family in Family::ALL {
        let mut m = monitor(family);
        assert_eq!(m.update(HEALTHY, true), Faults::STALL);
        assert!(!m.drive_allowed());
        for _ in 0..5 {
            assert_eq!(m.update(HEALTHY, false), Faults::STALL);
        }
        m.on_order(speed(1));
        m.on_order(speed(-1));
        m.on_order(Speed::MAX_FORWARD);
        m.on_order(Speed::MAX_REVERSE);
        assert_eq!(m.update(HEALTHY, false), Faults::STALL);
        assert!(!m.drive_allowed());
        m.on_order(Speed::ZERO);
        assert_eq!(m.faults(), Faults::NONE);
        assert!(m.drive_allowed());
        assert_eq!(m.update(HEALTHY, false), Faults::NONE);
        // A new verdict sets it again, also right after a zero order.
        assert_eq!(m.update(HEALTHY, true), Faults::STALL);
        m.on_order(Speed::ZERO);
        assert_eq!(m.update(HEALTHY, true), Faults::STALL);
        assert!(!m.drive_allowed());
    }
}

#[test]
fn hall_error_clears_when_halls_read_normal() {
    for family in Family::ALL {
        let mut m = monitor(family);
        assert_eq!(m.update(BAD_HALLS, false), Faults::HALL);
        assert!(!m.drive_allowed());
        assert_eq!(m.update(BAD_HALLS, false), Faults::HALL);
        m.on_order(Speed::ZERO);
        assert_eq!(m.faults(), Faults::HALL);
        assert_eq!(m.update(HEALTHY, false), Faults::NONE);
        assert!(m.drive_allowed());
    }
}

#[test]
fn several_faults_at_once() {
    let everything = Sample {
        water_ohms: 0,
        temperature_decicelsius: 1500,
        halls_normal: false,
    };
    for family in Family::ALL {
        let mut m = monitor(family);
        assert_eq!(m.update(everything, true), Faults::ALL);
        assert!(!m.drive_allowed());
        let latched = match family {
            Family::Legacy => Faults::GROUND | Faults::WATER,
            Family::SeaBotix => Faults::GROUND,
        };
        assert_eq!(m.update(HEALTHY, false), latched | Faults::STALL);
        m.on_order(Speed::ZERO);
        assert_eq!(m.faults(), latched);
        assert!(!m.drive_allowed());
    }
    // The SeaBotix water warning alongside a transient fault: the motor runs again when that one clears.
    let mut m = monitor(Family::SeaBotix);
    let wet_and_hot = Sample {
        water_ohms: 500_000,
        temperature_decicelsius: 1100,
        halls_normal: false,
    };
    assert_eq!(
        m.update(wet_and_hot, false),
        Faults::WATER | Faults::OVERTEMP | Faults::HALL
    );
    assert!(!m.drive_allowed());
    assert_eq!(m.update(water(500_000), false), Faults::WATER);
    assert!(m.drive_allowed());
}

/// The fault table written out row by row, to check the monitor against on every input sequence.
#[derive(Default)]
struct Model {
    water_latched: bool,
    ground_latched: bool,
    overtemp: bool,
    stall_latched: bool,
}

impl Model {
    fn update(&mut self, family: Family, sample: Sample, stalled: bool) -> (Faults, bool) {
        let wet = sample.water_ohms < 1_000_000;
        let grounded = sample.water_ohms < 100_000;
        self.water_latched |= wet;
        self.ground_latched |= grounded;
        if sample.temperature_decicelsius >= 1100 {
            self.overtemp = true;
        }
        if sample.temperature_decicelsius <= 1000 {
            self.overtemp = false;
        }
        self.stall_latched |= stalled;
        let hall = !sample.halls_normal;
        let water = match family {
            Family::Legacy => self.water_latched,
            Family::SeaBotix => wet,
        };
        let flags = [
            (self.overtemp, 0x01),
            (self.stall_latched, 0x02),
            (hall, 0x04),
            (self.ground_latched, 0x08),
            (water, 0x10),
        ];
        let bits = flags.iter().filter(|(on, _)| *on).fold(0, |acc, (_, bit)| acc | bit);
        let stops =
            self.overtemp || self.stall_latched || hall || self.ground_latched || (water && family == Family::Legacy);
        (Faults::from_bits_truncate(bits), !stops)
    }

    fn on_order(&mut self, speed: Speed) {
        if speed.step() == 0 {
            self.stall_latched = false;
        }
    }
}

/// Every combination of threshold-edge inputs.
fn inputs() -> Vec<(Sample, bool)> {
    let mut all = Vec::new();
    for water_ohms in [u32::MAX, 1_000_000, 999_999, 100_000, 99_999, 0] {
        for temperature_decicelsius in [i16::MIN, 1000, 1001, 1099, 1100, i16::MAX] {
            for halls_normal in [true, false] {
                for stalled in [false, true] {
                    let sample = Sample {
                        water_ohms,
                        temperature_decicelsius,
                        halls_normal,
                    };
                    all.push((sample, stalled));
                }
            }
        }
    }
    all
}

const ORDERS: [Option<Speed>; 3] = [None, Some(Speed::ZERO), Some(Speed::MAX_REVERSE)];

#[test]
fn every_pair_of_inputs_matches_the_table() {
    let inputs = inputs();
    for family in Family::ALL {
        for &(first, first_stalled) in &inputs {
            for order in ORDERS {
                for &(second, second_stalled) in &inputs {
                    let mut m = monitor(family);
                    let mut model = Model::default();
                    let (faults, drive) = model.update(family, first, first_stalled);
                    assert_eq!(m.update(first, first_stalled), faults);
                    assert_eq!(m.drive_allowed(), drive);
                    if let Some(order) = order {
                        m.on_order(order);
                        model.on_order(order);
                    }
                    let (faults, drive) = model.update(family, second, second_stalled);
                    assert_eq!(
                        m.update(second, second_stalled),
                        faults,
                        "{family:?} {first:?} {first_stalled} {order:?} {second:?} {second_stalled}"
                    );
                    assert_eq!(m.faults(), faults);
                    assert_eq!(m.drive_allowed(), drive);
                }
            }
        }
    }
}

#[test]
fn long_pseudo_random_sequences_match_the_table() {
    let inputs = inputs();
    let mut state: u32 = 0x1234_5678;
    let mut next = move || {
        // xorshift32
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        state as usize
    };
    for family in Family::ALL {
        for _ in 0..500 {
            let mut m = monitor(family);
            let mut model = Model::default();
            for _ in 0..40 {
                let (sample, stalled) = inputs[next() % inputs.len()];
                if let Some(order) = ORDERS[next() % ORDERS.len()] {
                    m.on_order(order);
                    model.on_order(order);
                }
                let (faults, drive) = model.update(family, sample, stalled);
                assert_eq!(m.update(sample, stalled), faults);
                assert_eq!(m.drive_allowed(), drive);
            }
        }
    }
}

#[test]
fn reported_bits_are_the_status_flags() {
    let rows = [
        (temperature(1100), false, Faults::OVERTEMP, 0x01),
        (HEALTHY, true, Faults::STALL, 0x02),
        (BAD_HALLS, false, Faults::HALL, 0x04),
        (water(99_999), false, Faults::GROUND | Faults::WATER, 0x18),
        (water(999_999), false, Faults::WATER, 0x10),
    ];
    for family in Family::ALL {
        for (sample, stalled, flags, bits) in rows {
            let mut m = monitor(family);
            let faults = m.update(sample, stalled);
            assert_eq!(faults, flags);
            assert_eq!(faults.bits(), bits);
            // The bits land in the status messages' fault fields unchanged (IDS 8.4.1 STATUS, 8.4.2 FAULT).
            let legacy = LegacyStatus {
                revision: LegacyRevision::AVEOX_BRUSHLESS,
                faults,
                max_power: MaxPower::Current { deciamps: 0 },
            }
            .encode();
            assert_eq!(legacy[1], 0x20 | bits);
            let seabotix = SeaBotixStatus {
                revision: 0,
                motor: MotorKind::Brushless,
                current_limited: true,
                faults,
                current_deciamps: 0,
                speed: Speed::ZERO,
                temperature_c: 25,
            }
            .encode();
            assert_eq!(seabotix[2], bits);
        }
    }
}

/// A detector whose duty rose above the threshold at `rise` ms (updated there with `value`).
fn rising_at(rise: u64, value: i32) -> StallDetector {
    let mut d = StallDetector::new(&Thresholds::SPEC);
    assert!(!d.update(ms(rise), duty(value)));
    d
}

#[test]
fn stall_window_edges() {
    // No pulse at all: stalled from exactly 400 ms after the rise.
    let mut d = rising_at(1000, 810);
    assert!(!d.update(ms(1399), duty(810)));
    assert!(d.update(ms(1400), duty(810)));
    assert!(d.update(ms(1401), duty(810)));
    assert!(d.update(ms(5000), duty(810)));
}

#[test]
fn stall_pulse_count_edges() {
    // 2 pulses: stalled at 400 ms.
    let mut d = rising_at(1000, 810);
    d.on_pulse(ms(1100));
    d.on_pulse(ms(1200));
    assert!(!d.update(ms(1399), duty(810)));
    assert!(d.update(ms(1400), duty(810)));
    // 3 pulses: not stalled while all 3 are inside (now - 400 ms, now].
    let mut d = rising_at(1000, 810);
    for t in [1100, 1200, 1300] {
        d.on_pulse(ms(t));
    }
    assert!(!d.update(ms(1400), duty(810)));
    assert!(!d.update(ms(1401), duty(810)));
    assert!(!d.update(ms(1499), duty(810)));
    // The pulse at 1100 is exactly 400 ms old at 1500: out of the window, 2 left.
    assert!(d.update(ms(1500), duty(810)));
    // A new pulse brings the count back to 3.
    d.on_pulse(ms(1500));
    assert!(!d.update(ms(1500), duty(810)));
    assert!(!d.update(ms(1599), duty(810)));
    assert!(d.update(ms(1600), duty(810)));
}

#[test]
fn a_spinning_motor_never_stalls() {
    let mut d = StallDetector::new(&Thresholds::SPEC);
    // A pulse every 100 ms, updates every millisecond for 10 s at full duty.
    for t in 0..10_000 {
        if t % 100 == 0 {
            d.on_pulse(ms(t));
        }
        assert!(!d.update(ms(t), duty(10_000)), "{t}");
    }
    // The motor blocks after the pulse at 9900: pulses at 9700, 9800, 9900 keep it running until 10 100.
    assert!(!d.update(ms(10_099), duty(10_000)));
    assert!(d.update(ms(10_100), duty(10_000)));
}

#[test]
fn pulses_from_before_the_rise_do_not_count() {
    let mut d = StallDetector::new(&Thresholds::SPEC);
    for t in [900, 950, 990] {
        d.on_pulse(ms(t));
        assert!(!d.update(ms(t), Duty::ZERO));
    }
    assert!(!d.update(ms(1000), duty(810)));
    assert!(!d.update(ms(1399), duty(810)));
    assert!(d.update(ms(1400), duty(810)));
    // A pulse at the very instant of the rise does not count either.
    let mut d = StallDetector::new(&Thresholds::SPEC);
    d.on_pulse(ms(1000));
    assert!(!d.update(ms(1000), duty(810)));
    d.on_pulse(ms(1200));
    d.on_pulse(ms(1300));
    assert!(d.update(ms(1400), duty(810)));
    // One after it does.
    let mut d = rising_at(1000, 810);
    for t in [1001, 1200, 1300] {
        d.on_pulse(ms(t));
    }
    assert!(!d.update(ms(1400), duty(810)));
    assert!(d.update(ms(1401), duty(810)));
}

#[test]
fn stall_duty_threshold_is_strict_and_by_magnitude() {
    for (value, stalls) in [
        (800, false),
        (801, true),
        (810, true),
        (-800, false),
        (-801, true),
        (-810, true),
        (0, false),
        (10_000, true),
        (-10_000, true),
    ] {
        let mut d = StallDetector::new(&Thresholds::SPEC);
        assert!(!d.update(ms(0), duty(value)));
        assert_eq!(d.update(ms(400), duty(value)), stalls, "{value}");
        assert_eq!(d.update(ms(10_000), duty(value)), stalls, "{value}");
    }
    // Forward and reverse above 8 % are one continuous run.
    let mut d = rising_at(0, 810);
    assert!(!d.update(ms(200), duty(-810)));
    assert!(d.update(ms(400), duty(-5000)));
}

#[test]
fn a_dip_to_the_threshold_restarts_the_window() {
    let mut d = rising_at(0, 810);
    assert!(!d.update(ms(300), duty(800)));
    assert!(!d.update(ms(301), duty(810)));
    assert!(!d.update(ms(700), duty(810)));
    assert!(d.update(ms(701), duty(810)));
    assert!(!d.update(ms(702), Duty::ZERO));
    assert!(!d.update(ms(703), duty(810)));
    assert!(!d.update(ms(1102), duty(810)));
    assert!(d.update(ms(1103), duty(810)));
}

#[test]
fn reset_forgets_everything() {
    let mut d = rising_at(0, 810);
    for t in [100, 200, 300] {
        d.on_pulse(ms(t));
    }
    assert!(!d.update(ms(400), duty(810)));
    d.reset();
    assert_eq!(d, StallDetector::new(&Thresholds::SPEC));
    // The window restarts at the next update and the old pulses are gone.
    assert!(!d.update(ms(401), duty(810)));
    assert!(!d.update(ms(800), duty(810)));
    assert!(d.update(ms(801), duty(810)));
}

#[test]
fn pulse_count_settings() {
    // 0 disables the detector.
    let none = Thresholds {
        stall_min_pulses: 0,
        ..Thresholds::SPEC
    };
    let mut d = StallDetector::new(&none);
    assert!(!d.update(ms(0), duty(10_000)));
    assert!(!d.update(ms(10_000), duty(10_000)));
    // 1: any pulse in the window keeps it running.
    let one = Thresholds {
        stall_min_pulses: 1,
        ..Thresholds::SPEC
    };
    let mut d = StallDetector::new(&one);
    assert!(!d.update(ms(0), duty(10_000)));
    d.on_pulse(ms(399));
    assert!(!d.update(ms(400), duty(10_000)));
    assert!(!d.update(ms(798), duty(10_000)));
    assert!(d.update(ms(799), duty(10_000)));
    // More than MAX_PULSES acts as MAX_PULSES.
    let many = Thresholds {
        stall_min_pulses: u8::MAX,
        ..Thresholds::SPEC
    };
    let mut d = StallDetector::new(&many);
    assert!(!d.update(ms(0), duty(10_000)));
    for t in 1..=u64::from(StallDetector::MAX_PULSES) {
        d.on_pulse(ms(t * 10));
    }
    assert!(!d.update(ms(400), duty(10_000)));
    assert!(d.update(ms(410), duty(10_000)));
}

#[test]
fn time_edges_do_not_panic() {
    let mut d = StallDetector::new(&Thresholds::SPEC);
    d.on_pulse(ms(0));
    assert!(!d.update(Instant::from_ticks(0), duty(10_000)));
    assert!(d.update(Instant::from_ticks(u64::MAX), duty(10_000)));
    // A clock that went backwards reads as no time passed.
    assert!(d.update(Instant::from_ticks(u64::MAX), duty(10_000)));
    assert!(!d.update(ms(0), Duty::ZERO));
    // Pulses stamped in the future count as inside the window.
    for _ in 0..3 {
        d.on_pulse(Instant::from_ticks(u64::MAX));
    }
    assert!(!d.update(ms(5), duty(10_000)));
    assert!(!d.update(ms(5000), duty(10_000)));
    let mut zero_window = StallDetector::new(&Thresholds {
        stall_window: Duration::from_ticks(0),
        ..Thresholds::SPEC
    });
    assert!(zero_window.update(ms(0), duty(10_000)));
}
