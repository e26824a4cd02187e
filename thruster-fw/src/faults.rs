//! The thruster's fault table: detection, latching and whether the motor may run (IDS 8.4.1 and 8.4.2 remarks,
//! spec-notes section 1 "Faults: what the thruster does").
//!
//! | fault | set when | Legacy | SeaBotix |
//! |---|---|---|---|
//! | water detect | water sensor < 1 Mohm | stops; latched until power cycle | warning only; clears at >= 1.1 Mohm |
//! | ground fault | water sensor < 100 kohm | stops; latched until power cycle | same |
//! | overtemp | >= 110.0 C, cleared at <= 100.0 C | stops while set | same |
//! | stalled motor | [`StallDetector`] / [`CurrentStall`] verdict | stops; latched until a zero-speed order | same |
//! | hall sensor error | hall state invalid or illegal transition | stops; clears when the halls read normal | same |
//! | overcurrent (the project's) | break trips sustained ([`crate::overcurrent::TripRule`]) | stops, outputs off; latched until a zero-speed order; no status bit | same; FAULT bit 6 |
//!
//! The IDS leaves the filtering open; the project's reading (spec-notes, "How the project reads the rest of the
//! fault rules"): water and ground need their condition on [`Thresholds::latch_samples`] consecutive samples to
//! set (and water as many above its band to clear), a hall error needs [`Thresholds::hall_error_samples`]
//! consecutive abnormal readings. Overtemp has its own 10 C band and needs no count.
//!
//! The IDS does not say how a stall clears; the project follows the AM32 / BLHeli_32 rule (spec-notes): a
//! zero-speed order clears it. "Latched until power cycle" holds across every other reset (watchdog, reset pin,
//! software): the fault task keeps the latches in a [`LatchStore`] (on the STM32, a backup register), and
//! [`carried_latch`] drops them only after a power-on or brown-out. The controller keeps answering on I2C whatever
//! the faults (IDS 8.4 remark 1).

use embassy_time::{Duration, Instant};
use tmc_proto::{Family, Faults, Speed};

use crate::drive::{Direction, Duty};

/// Fault thresholds (spec-notes section 1, IDS 8.4 remarks).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Thresholds {
    /// Water detect when the water sensor resistance is below this, in ohms (IDS 8.4.2 remark 2: 1 Mohm).
    pub water_ohms: u32,
    /// A SeaBotix water warning clears only at or above this, in ohms: the threshold plus a band, so a sensor
    /// sitting at 1 Mohm with ADC noise does not toggle the warning (spec-notes: "a band on the clear").
    pub water_clear_ohms: u32,
    /// Water and ground fault need their condition on this many consecutive samples to set, and water as many
    /// at or above `water_clear_ohms` to clear; 0 acts as 1 (spec-notes: "consecutive samples, never one").
    pub latch_samples: u8,
    /// A hall error needs this many consecutive abnormal readings; 0 acts as 1 (spec-notes: "one bad hall
    /// reading is not yet a hall error").
    pub hall_error_samples: u8,
    /// Ground fault when the water sensor resistance is below this, in ohms (IDS 8.4 remarks: 100 kohm).
    pub ground_ohms: u32,
    /// Overtemp sets at or above this temperature, in 0.1 C (IDS 8.4 remarks: 110 C).
    pub overtemp_set_decicelsius: i16,
    /// A set overtemp clears at or below this temperature, in 0.1 C (IDS 8.4 remarks: 100 C).
    pub overtemp_clear_decicelsius: i16,
    /// Stall needs the duty magnitude strictly above this, in [`Duty`] units of 1/10 000 (IDS: above 8 %).
    pub stall_duty: u16,
    /// Stall window: the duty must stay above `stall_duty` this long, and the pulses are counted over it
    /// (IDS: 400 ms).
    pub stall_window: Duration,
    /// Stall when fewer than this many hall pulses arrive within the window (IDS: 3), a pulse being one hall
    /// state of net progress in the driven direction ([`Progress`]). At most [`StallDetector::MAX_PULSES`] take
    /// effect; 0 disables stall detection.
    pub stall_min_pulses: u8,
    /// Brushed stall ([`CurrentStall`]): the motor's locked-rotor current at full duty, in 0.1 A. A locked rotor
    /// draws this times the duty; the stall level is half of that at the applied duty.
    pub locked_rotor_deciamps: u16,
    /// Brushed stall: the level never exceeds this, in 0.1 A, so a power stage that limits the current below the
    /// locked-rotor current still sees a locked rotor as stalled.
    pub stall_current_ceiling_deciamps: u16,
    /// A sustained overcurrent: the leaky count of samples with a break trip at which the bridge stops
    /// ([`crate::overcurrent::TripRule`]); 0 acts as 1.
    pub overcurrent_ticks: u16,
}

impl Thresholds {
    /// The values of the IDS 8.4 remarks, and the project's filters where the IDS gives none.
    ///
    /// - `water_clear_ohms` 1.1 Mohm: a 10 % band. With the reference 1 Mohm pull-down (`sensors::WaterSensor`),
    ///   1 Mohm reads 2048 counts and 1.1 Mohm 1950: ~100 counts of band against an ADC noise of a few counts
    ///   (one count is ~1 kohm there).
    /// - `latch_samples` 3: at the 1 kHz sampling ([`crate::tasks::SAMPLE_PERIOD`]) water and ground faults are
    ///   reacted to in 3 ms instead of 1 ms; the IDS gives no reaction time, and the water sensor's own 100 nF
    ///   already filters over ~0.1 s (docs/hardware.md, the water sensor). Three covers a single spike and the
    ///   wrong first conversion after an idle ADC (STM32G4 errata ES0431) with a sample to spare.
    /// - `hall_error_samples` 3: a hall glitch shorter than a sample period gives at most two abnormal readings
    ///   (the illegal edge into the glitch, seen on one sample, and the one out of it, seen on the next when the
    ///   glitch spans a sample), so three in a row is a sensor that stays wrong: an unplugged or shorted sensor is
    ///   reacted to in 3 ms. The commutation still coasts at once on an invalid state.
    /// - `stall_min_pulses` 3 in `stall_window` 400 ms (the IDS), counted as net progress: at the reference
    ///   motor's 4 pole pairs (`Config::reference`) a hall state is 1/24 of a turn, and 3 states in every 400 ms
    ///   window need an edge at least every 133 ms: a rotor turning slower than 18.75 rpm, or rocking in place,
    ///   is stalled.
    /// - `locked_rotor_deciamps` 20 A: the reference BTD150-class motor (24 V across its 1.2 ohm winding, the
    ///   motor the bench models in `lbv/src/bench/plant.rs`). Half of it at the applied duty is far above what
    ///   the propeller draws turning (4 A at full speed, 0.4 A at 25 %).
    /// - `stall_current_ceiling_deciamps` 6 A: above the 4 A of full speed, below the power stage's 8 A
    ///   cycle-by-cycle limit (the IHM08M1's overcurrent comparator as the bench models it), which would
    ///   otherwise hold a locked rotor under a level it could never reach.
    /// - `overcurrent_ticks` 500: a break trip on every 1 ms sample stops the bridge after 0.5 s (20 000 PWM
    ///   periods, each cut by the hardware within a microsecond). Longer than the stall window, so a locked rotor
    ///   held at the current limit is reported as the stall it is: on the bench (its 8 A limit) a blocked
    ///   propeller brings the count to at most 375 before the stall stops it (the soak, 120 s), 275 in the stall
    ///   scenarios; on the IHM08M1, whose comparator sits near twice its rated current, the reference motor's
    ///   20 A locked-rotor current does not trip it at all. A short trips every period and gets there.
    pub const SPEC: Thresholds = Thresholds {
        water_ohms: 1_000_000,
        water_clear_ohms: 1_100_000,
        latch_samples: 3,
        hall_error_samples: 3,
        ground_ohms: 100_000,
        overtemp_set_decicelsius: 1100,
        overtemp_clear_decicelsius: 1000,
        stall_duty: 800,
        stall_window: Duration::from_millis(400),
        stall_min_pulses: 3,
        locked_rotor_deciamps: 200,
        stall_current_ceiling_deciamps: 60,
        overcurrent_ticks: 500,
    };
}

/// One fault-monitor input sample (taken at 1 kHz or faster by the caller).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Sample {
    /// Resistance between the water-sensor electrodes, in ohms (see `sensors::WaterSensor`).
    pub water_ohms: u32,
    /// The temperature the status reports, the motor's or the controller's, in 0.1 C (see `sensors::Ntc`).
    pub temperature_decicelsius: i16,
    /// The hall state is valid (not 000/111) and no illegal transition happened since the previous sample.
    pub halls_normal: bool,
}

/// Stall detection (IDS 8.4.1 remark 4, 8.4.2 remark 5): duty above 8 % and fewer than 3 hall pulses within
/// 400 ms.
///
/// Precisely, with W the window and N the minimum pulse count, [`StallDetector::update`] at `now` reports a stall
/// when all of these hold:
/// - the duty magnitude is strictly above the threshold now, and was at every `update` since an instant
///   `since <= now - W` (the duty is known only at `update` calls, so `since` is the first call that saw it
///   above; one call at or below the threshold restarts it);
/// - fewer than N pulses fall in the window (now - W, now]: a pulse exactly W before `now` no longer counts.
///
/// Since the window starts no earlier than `since`, pulses from before the duty rose (and one at the very instant
/// it was first seen above) never count. With the IDS values, a duty first seen above 8 % at t = 0 with at most
/// 2 pulses after it is reported stalled from t = 400 ms on, not at 399 ms.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct StallDetector {
    stall_duty: u16,
    window: Duration,
    /// The threshold's pulse count, clamped to `MAX_PULSES`.
    min_pulses: u8,
    /// First `update` of the current run of above-threshold duty.
    above_since: Option<Instant>,
    /// The latest pulses, newest first.
    pulses: [Option<Instant>; StallDetector::MAX_PULSES as usize],
}

impl StallDetector {
    /// The largest pulse count the detector remembers; a larger `stall_min_pulses` acts as this.
    pub const MAX_PULSES: u8 = 8;

    /// A detector that has seen no pulse and no duty.
    pub fn new(thresholds: &Thresholds) -> Self {
        StallDetector {
            stall_duty: thresholds.stall_duty,
            window: thresholds.stall_window,
            min_pulses: thresholds.stall_min_pulses.min(Self::MAX_PULSES),
            above_since: None,
            pulses: [None; Self::MAX_PULSES as usize],
        }
    }

    /// A legal hall edge (pulse) at `now`.
    pub fn on_pulse(&mut self, now: Instant) {
        self.pulses.rotate_right(1);
        if let Some(newest) = self.pulses.first_mut() {
            *newest = Some(now);
        }
    }

    /// Whether the motor is stalled at `now` with `duty` applied: the duty has stayed above the threshold for the
    /// whole window (continuously since at least now - 400 ms) and fewer than 3 pulses arrived in that window
    /// (now - 400 ms, now]. See the type's documentation for the exact rule. Reverse duty counts by magnitude.
    pub fn update(&mut self, now: Instant, duty: Duty) -> bool {
        if duty.magnitude() <= self.stall_duty {
            self.above_since = None;
            return false;
        }
        let since = *self.above_since.get_or_insert(now);
        if now.saturating_duration_since(since) < self.window {
            return false;
        }
        // Enough pulses when the N-th newest is inside the window; N = 0 never stalls.
        let Some(index) = usize::from(self.min_pulses).checked_sub(1) else {
            return false;
        };
        let enough = match self.pulses.get(index) {
            Some(Some(pulse)) => now.saturating_duration_since(*pulse) < self.window,
            _ => false,
        };
        !enough
    }

    /// Forget the pulses and the duty history, as after [`StallDetector::new`].
    pub fn reset(&mut self) {
        self.above_since = None;
        self.pulses = [None; Self::MAX_PULSES as usize];
    }
}

/// Net progress of the rotor in the driven direction, for the stall window's pulses (spec-notes: "a hall pulse is
/// net progress of one hall state in the driven direction").
///
/// A pulse is a hall state reached beyond the furthest one reached so far in the driven direction: an edge back,
/// and the edge forward again over the same boundary, count nothing, so a blocked rotor rocking across a hall
/// boundary gives at most one pulse. A change of the driven direction (or no drive) starts again from where the
/// rotor is.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Progress {
    /// The direction driven and the furthest hall position reached in it.
    mark: Option<(Direction, i32)>,
}

impl Progress {
    /// No mark: the next call starts from where the rotor is.
    pub const fn new() -> Self {
        Progress { mark: None }
    }

    /// The new pulses at hall `position` (the net count of [`crate::hall::HallTracker::position`]) with the
    /// motor driven in `driven` (`None`: not driven).
    pub fn advance(&mut self, position: i32, driven: Option<Direction>) -> u32 {
        let Some(direction) = driven else {
            self.mark = None;
            return 0;
        };
        let Some((marked, furthest)) = self.mark.filter(|(marked, _)| *marked == direction) else {
            self.mark = Some((direction, position));
            return 0;
        };
        // Wrapping: the position is a wrapping count, and the difference of two nearby ones is small.
        let gained = match marked {
            Direction::Forward => position.wrapping_sub(furthest),
            Direction::Reverse => furthest.wrapping_sub(position),
        };
        if gained > 0 {
            self.mark = Some((marked, position));
            gained.unsigned_abs()
        } else {
            0
        }
    }
}

/// Stall detection for a brushed motor, which has no halls (spec-notes: "stall on a brushed motor"): the duty
/// magnitude strictly above 8 % and the motor current at or above its stall level, continuously for 400 ms (the
/// window of the IDS's brushless rule). The level at duty d is min(d x locked-rotor / 2, ceiling)
/// ([`Thresholds::locked_rotor_deciamps`], [`Thresholds::stall_current_ceiling_deciamps`]). As for
/// [`StallDetector`], the condition first seen at t = 0 and held at every update reports a stall from t = 400 ms.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct CurrentStall {
    stall_duty: u16,
    window: Duration,
    locked_rotor_deciamps: u16,
    ceiling_deciamps: u16,
    /// First `update` of the current run of the condition.
    since: Option<Instant>,
}

impl CurrentStall {
    /// A detector that has seen nothing.
    pub const fn new(thresholds: &Thresholds) -> Self {
        CurrentStall {
            stall_duty: thresholds.stall_duty,
            window: thresholds.stall_window,
            locked_rotor_deciamps: thresholds.locked_rotor_deciamps,
            ceiling_deciamps: thresholds.stall_current_ceiling_deciamps,
            since: None,
        }
    }

    /// The stall level at `duty`, in 0.1 A.
    pub fn level_deciamps(&self, duty: Duty) -> u16 {
        // Both factors are below 2^16: the product fits in u32, and the quotient is at most 65 535 / 2.
        let half_locked = u32::from(self.locked_rotor_deciamps) * u32::from(duty.magnitude()) / (2 * FULL_DUTY);
        u16::try_from(half_locked)
            .unwrap_or(u16::MAX)
            .min(self.ceiling_deciamps)
    }

    /// Whether the motor is stalled at `now` with `duty` applied and `current_deciamps` measured.
    pub fn update(&mut self, now: Instant, duty: Duty, current_deciamps: u16) -> bool {
        if duty.magnitude() <= self.stall_duty || current_deciamps < self.level_deciamps(duty) {
            self.since = None;
            return false;
        }
        let since = *self.since.get_or_insert(now);
        now.saturating_duration_since(since) >= self.window
    }

    /// Forget the history, as after [`CurrentStall::new`].
    pub fn reset(&mut self) {
        self.since = None;
    }
}

/// Full scale of a [`Duty`], as the stall level's arithmetic takes it.
const FULL_DUTY: u32 = Duty::FULL as u32;

/// Consecutive samples of one condition, saturating.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
struct Run(u8);

impl Run {
    /// Count this sample (`on`) or start again; returns whether the run has reached `needed` (0 acts as 1).
    fn sample(&mut self, on: bool, needed: u8) -> bool {
        self.0 = if on { self.0.saturating_add(1) } else { 0 };
        self.0 >= needed.max(1)
    }
}

/// The fault state machine for one controller family: the table in this module's documentation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct FaultMonitor {
    family: Family,
    thresholds: Thresholds,
    faults: Faults,
    /// Consecutive samples below the water threshold, at or above its band, below the ground threshold, and with
    /// the halls abnormal.
    wet: Run,
    dry: Run,
    grounded: Run,
    bad_halls: Run,
}

impl FaultMonitor {
    /// A monitor with no fault, as at power-up.
    pub fn new(family: Family, thresholds: Thresholds) -> Self {
        FaultMonitor {
            family,
            thresholds,
            faults: Faults::NONE,
            wet: Run(0),
            dry: Run(0),
            grounded: Run(0),
            bad_halls: Run(0),
        }
    }

    /// Apply one sample (plus the stall detector's verdict) and return the faults to report.
    ///
    /// The returned faults already reflect this sample, so the motor stops on the sample that completes a
    /// fault's count (the first sample for overtemp and stall).
    pub fn update(&mut self, sample: Sample, stalled: bool) -> Faults {
        let t = &self.thresholds;
        let wet = self.wet.sample(sample.water_ohms < t.water_ohms, t.latch_samples);
        let dry = self
            .dry
            .sample(sample.water_ohms >= t.water_clear_ohms, t.latch_samples);
        if wet {
            self.faults.insert(Faults::WATER);
        }
        // IDS 8.4.1 remark 2: Legacy water is latched until power cycle; IDS 8.4.2 remark 2: the SeaBotix warning
        // clears when the resistance is back, here above the band.
        if dry && self.family == Family::SeaBotix {
            self.faults.remove(Faults::WATER);
        }
        // IDS 8.4.1 remark 6, 8.4.2 remark 3: latched until power cycle.
        if self.grounded.sample(sample.water_ohms < t.ground_ohms, t.latch_samples) {
            self.faults.insert(Faults::GROUND);
        }
        // Hysteresis: between the two thresholds the overtemp keeps its state.
        if sample.temperature_decicelsius >= t.overtemp_set_decicelsius {
            self.faults.insert(Faults::OVERTEMP);
        } else if sample.temperature_decicelsius <= t.overtemp_clear_decicelsius {
            self.faults.remove(Faults::OVERTEMP);
        }
        // Latched until a zero-speed order (`on_order`).
        if stalled {
            self.faults.insert(Faults::STALL);
        }
        // IDS 8.4 remarks: clears when the halls read normal, here on the first normal reading.
        let hall_error = self.bad_halls.sample(!sample.halls_normal, t.hall_error_samples);
        self.faults.set(Faults::HALL, hall_error);
        self.faults
    }

    /// A valid order arrived: a zero-speed order clears the stall latch (spec-notes: the AM32/BLHeli rule).
    /// Other orders, and other faults, are untouched.
    pub fn on_order(&mut self, speed: Speed) {
        if speed.is_zero() {
            self.faults.remove(Faults::STALL);
        }
    }

    /// The faults to report now.
    pub fn faults(&self) -> Faults {
        self.faults
    }

    /// The faults a family keeps until power cycle: ground fault, and for Legacy water too (IDS 8.4.1 remarks 2
    /// and 6, 8.4.2 remark 3).
    pub const fn power_cycle_latches(family: Family) -> Faults {
        match family {
            Family::Legacy => Faults::GROUND.union(Faults::WATER),
            Family::SeaBotix => Faults::GROUND,
        }
    }

    /// The power-cycle latches set now: what must survive a reset.
    pub fn latched(&self) -> Faults {
        self.faults & Self::power_cycle_latches(self.family)
    }

    /// Take back the latches carried over a reset; only those this family keeps until power cycle are taken.
    pub fn restore(&mut self, latched: Faults) {
        self.faults.insert(latched & Self::power_cycle_latches(self.family));
    }

    /// Whether the motor may be driven: false while any fault that stops the motor for this family is present.
    /// Every fault stops it except the SeaBotix water warning.
    pub fn drive_allowed(&self) -> bool {
        let stopping = match self.family {
            Family::Legacy => Faults::ALL,
            Family::SeaBotix => Faults::ALL.difference(Faults::WATER),
        };
        (self.faults & stopping).is_empty()
    }
}

/// Where the power-cycle latches live between resets.
pub trait LatchStore {
    /// The latches carried over the last reset (none after a power cycle).
    fn load(&mut self) -> Faults;
    /// Keep `latched` for the next reset.
    fn save(&mut self, latched: Faults);
}

/// A store that forgets at reset, as RAM does at power-off: for the host bench and tests, where every reset is a
/// power cycle.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct VolatileLatch(Faults);

impl LatchStore for VolatileLatch {
    fn load(&mut self) -> Faults {
        self.0
    }

    fn save(&mut self, latched: Faults) {
        self.0 = latched;
    }
}

/// How the chip came out of its last reset, as far as the latches are concerned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum ResetKind {
    /// Power-on or brown-out: a power cycle, which clears the latches.
    PowerCycle,
    /// Any other reset (watchdog, reset pin, software, option-byte load): the latches stay.
    Other,
}

/// Marks a latch word as written by this firmware.
const LATCH_TAG: u32 = 0x4C54;

/// The latches as one 32-bit word: a tag in the upper half, the fault bits and their complement below, so that a
/// word never written (zero after a power-on) or corrupted reads as no latch.
pub const fn latch_word(latched: Faults) -> u32 {
    let bits = latched.bits() as u32;
    (LATCH_TAG << 16) | ((!bits & 0xFF) << 8) | bits
}

/// The latches of a word written by [`latch_word`]; none for any other word.
pub const fn latch_from_word(word: u32) -> Faults {
    let bits = word & 0xFF;
    if word >> 16 == LATCH_TAG && (word >> 8) & 0xFF == !bits & 0xFF {
        Faults::from_bits_truncate(bits as u8)
    } else {
        Faults::NONE
    }
}

/// The latches to restore at boot from the stored word, after a reset of `kind`.
pub const fn carried_latch(kind: ResetKind, word: u32) -> Faults {
    match kind {
        ResetKind::PowerCycle => Faults::NONE,
        ResetKind::Other => latch_from_word(word),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
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
        assert_eq!(t.locked_rotor_deciamps, 200);
        assert_eq!(t.stall_current_ceiling_deciamps, 60);
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

    #[test]
    fn brushed_stall_level_and_window() {
        let mut s = CurrentStall::new(&Thresholds::SPEC);
        // Half the 20 A locked-rotor current at the duty, at most 6 A.
        assert_eq!(s.level_deciamps(duty(1000)), 10);
        assert_eq!(s.level_deciamps(duty(-5000)), 50);
        assert_eq!(s.level_deciamps(duty(9500)), 60);
        // 25 A at full order: stalled from 400 ms on.
        assert!(!s.update(ms(0), duty(9500), 250));
        assert!(!s.update(ms(399), duty(9500), 250));
        assert!(s.update(ms(400), duty(9500), 250));
        // A turning motor's current, at any duty, never stalls.
        let mut s = CurrentStall::new(&Thresholds::SPEC);
        for t in 0..2000 {
            assert!(!s.update(ms(t), duty(9500), 40));
        }
        // A locked rotor at 10 % duty draws 2 A: above its 1 A level.
        let mut s = CurrentStall::new(&Thresholds::SPEC);
        assert!(!s.update(ms(0), duty(1000), 20));
        assert!(s.update(ms(400), duty(1000), 20));
        // 8 % is not above 8 %; a dip of the current restarts the window.
        let mut s = CurrentStall::new(&Thresholds::SPEC);
        assert!(!s.update(ms(0), duty(800), 200));
        assert!(!s.update(ms(500), duty(800), 200));
        assert!(!s.update(ms(501), duty(9500), 200));
        assert!(!s.update(ms(700), duty(9500), 59));
        assert!(!s.update(ms(701), duty(9500), 60));
        assert!(!s.update(ms(1100), duty(9500), 60));
        assert!(s.update(ms(1101), duty(9500), 60));
        s.reset();
        assert!(!s.update(ms(1102), duty(9500), 60));
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
            let stops = self.overtemp
                || self.stall_latched
                || hall
                || self.ground_latched
                || (water && family == Family::Legacy);
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
}
