//! The thruster's fault table: detection, latching and whether the motor may run (IDS 8.4.1 and 8.4.2 remarks,
//! docs/interface.md "Faults", docs/decisions.md D11-D17).
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
//! The IDS leaves the filtering open; the project's reading (docs/decisions.md D15, D17): water and ground need their
//! condition on [`Thresholds::latch_samples`] consecutive samples to set (and water as many above its band to clear),
//! and so does overtemp (at or above 110 C to set, at or below 100 C to clear, with its 10 C band between); a hall
//! error needs [`Thresholds::hall_error_samples`] consecutive abnormal readings. One noisy conversion never cuts
//! thrust.
//!
//! The IDS does not say how a stall clears; the project follows the AM32 / BLHeli_32 rule (docs/decisions.md D11): a
//! zero-speed order clears it. "Latched until power cycle" holds across every other reset (watchdog, reset pin,
//! software): the fault task keeps the latches in a [`LatchStore`](crate::ports::LatchStore) (on the STM32, a
//! backup register), and [`carried_latch`] drops them only after a power-on or brown-out. The controller keeps
//! answering on I2C whatever the faults (IDS 8.4 remark 1).

use embassy_time::{Duration, Instant};
use tmc_proto::{Family, Faults, Speed};

use crate::drive::{Direction, Duty};
use crate::overcurrent::TripLimits;

mod latch;

pub use latch::{ResetKind, VolatileLatch, carried_latch, latch_from_word, latch_word};

/// Fault thresholds (docs/interface.md "Faults", IDS 8.4 remarks; docs/decisions.md D15, D17).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Thresholds {
    /// Water detect when the water sensor resistance is below this, in ohms (IDS 8.4.2 remark 2: 1 Mohm).
    pub water_ohms: u32,
    /// A SeaBotix water warning clears only at or above this, in ohms: the threshold plus a band, so a sensor
    /// sitting at 1 Mohm with ADC noise does not toggle the warning (docs/decisions.md D15).
    pub(crate) water_clear_ohms: u32,
    /// Water, ground fault and overtemp need their condition on this many consecutive samples to set, and water
    /// and overtemp as many past their band to clear; 0 acts as 1 (one noisy conversion never cuts thrust).
    pub latch_samples: u8,
    /// A hall error needs this many consecutive abnormal readings; 0 acts as 1 (docs/decisions.md D17).
    pub hall_error_samples: u8,
    /// Ground fault when the water sensor resistance is below this, in ohms (IDS 8.4 remarks: 100 kohm).
    pub(crate) ground_ohms: u32,
    /// Overtemp sets at or above this temperature, in 0.1 C (IDS 8.4 remarks: 110 C).
    pub overtemp_set_decicelsius: i16,
    /// A set overtemp clears at or below this temperature, in 0.1 C (IDS 8.4 remarks: 100 C).
    pub overtemp_clear_decicelsius: i16,
    /// Stall needs the duty magnitude strictly above this, in [`Duty`] units of 1/10 000 (IDS: above 8 %).
    pub(crate) stall_duty: u16,
    /// Stall window: the duty must stay above `stall_duty` this long, and the pulses are counted over it
    /// (IDS: 400 ms).
    pub(crate) stall_window: Duration,
    /// Stall when fewer than this many hall pulses arrive within the window (IDS: 3), a pulse being one hall
    /// state of net progress in the driven direction ([`Progress`]). At most [`StallDetector::MAX_PULSES`] take
    /// effect; 0 disables stall detection.
    pub(crate) stall_min_pulses: u8,
    /// Brushed stall ([`CurrentStall`]): the motor's resistance between its terminals (armature and brushes), in
    /// mohm, for its back-EMF: the applied voltage less I x R.
    pub(crate) armature_milliohms: u16,
    /// A sustained overcurrent: the run of samples with a break trip, and the fraction of a window of them, at
    /// which the bridge stops ([`crate::overcurrent::TripRule`]).
    pub overcurrent: TripLimits,
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
    ///   wrong first conversion after an idle ADC (STM32G4 errata ES0431) with a sample to spare. Overtemp takes
    ///   the same count: 2 ms later than on one sample, against a motor's thermal time constant of minutes.
    /// - `hall_error_samples` 3: a hall glitch shorter than a sample period gives at most two abnormal readings
    ///   (the illegal edge into the glitch, seen on one sample, and the one out of it, seen on the next when the
    ///   glitch spans a sample), so three in a row is a sensor that stays wrong: an unplugged or shorted sensor is
    ///   reacted to in 3 ms. The commutation still coasts at once on an invalid state.
    /// - `stall_min_pulses` 3 in `stall_window` 400 ms (the IDS), counted as net progress: at the reference
    ///   motor's 4 pole pairs (`Config::reference`) a hall state is 1/24 of a turn, and 3 states in every 400 ms
    ///   window need an edge at least every 133 ms: a rotor turning slower than 18.75 rpm, or rocking in place,
    ///   is stalled.
    /// - `armature_milliohms` 1.2 ohm: the reference BTD150-class motor's winding (24 V across it is its 20 A
    ///   locked-rotor current; the motor the bench models in `lbv/src/bench/plant.rs`). Copper at 110 C has about
    ///   a third more; the rule's margin of half the applied voltage covers that both ways.
    /// - `overcurrent`: a break trip on 5 consecutive 1 ms samples (200 PWM periods, each cut by the hardware
    ///   within a microsecond), or on more than 40 of the last 200 (20 %): a shorted MOSFET trips on a third of
    ///   them and stops within the window, a continuous short within 5 ms, isolated trips never (docs/decisions.md
    ///   D30). The IHM08M1's comparator sits near twice its 15 A rating, above the reference motor's 20 A
    ///   locked-rotor current: a blocked rotor does not trip it and is reported as the stall it is.
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
        armature_milliohms: 1_200,
        overcurrent: TripLimits {
            run_ticks: 5,
            window_ticks: 200,
            window_trips: 40,
        },
    };
}

/// One fault-monitor input sample (taken at 1 kHz or faster by the caller).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct Sample {
    /// Resistance between the water-sensor electrodes, in ohms (see `sensors::WaterSensor`).
    pub(crate) water_ohms: u32,
    /// The temperature the status reports, the motor's or the controller's, in 0.1 C (see `sensors::Ntc`).
    pub(crate) temperature_decicelsius: i16,
    /// The hall state is valid (not 000/111) and no illegal transition happened since the previous sample.
    pub(crate) halls_normal: bool,
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
pub(crate) struct StallDetector {
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
    pub(crate) const MAX_PULSES: u8 = 8;

    /// A detector that has seen no pulse and no duty.
    pub(crate) fn new(thresholds: &Thresholds) -> Self {
        StallDetector {
            stall_duty: thresholds.stall_duty,
            window: thresholds.stall_window,
            min_pulses: thresholds.stall_min_pulses.min(Self::MAX_PULSES),
            above_since: None,
            pulses: [None; Self::MAX_PULSES as usize],
        }
    }

    /// A legal hall edge (pulse) at `now`.
    pub(crate) fn on_pulse(&mut self, now: Instant) {
        // Each slot takes the one before it, the first takes `now`, the oldest drops out. (`rotate_right` did the
        // same through core's general rotation, which linked a 1.5 KiB memmove into the image for these 8 slots.)
        let mut newer = Some(now);
        for slot in &mut self.pulses {
            newer = core::mem::replace(slot, newer);
        }
    }

    /// Whether the motor is stalled at `now` with `duty` applied: the duty has stayed above the threshold for the
    /// whole window (continuously since at least now - 400 ms) and fewer than 3 pulses arrived in that window
    /// (now - 400 ms, now]. See the type's documentation for the exact rule. Reverse duty counts by magnitude.
    pub(crate) fn update(&mut self, now: Instant, duty: Duty) -> bool {
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
    pub(crate) fn reset(&mut self) {
        self.above_since = None;
        self.pulses = [None; Self::MAX_PULSES as usize];
    }
}

/// Net progress of the rotor in the driven direction, for the stall window's pulses (docs/decisions.md D12).
///
/// A pulse is a hall state reached beyond the furthest one reached so far in the driven direction: an edge back,
/// and the edge forward again over the same boundary, count nothing, so a blocked rotor rocking across a hall
/// boundary gives at most one pulse. A change of the driven direction (or no drive) starts again from where the
/// rotor is.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct Progress {
    /// The direction driven and the furthest hall position reached in it.
    mark: Option<(Direction, i32)>,
}

impl Progress {
    /// No mark: the next call starts from where the rotor is.
    pub(crate) const fn new() -> Self {
        Progress { mark: None }
    }

    /// The new pulses at hall `position` (the net count of [`crate::hall::HallTracker::position`]) with the
    /// motor driven in `driven` (`None`: not driven).
    pub(crate) fn advance(&mut self, position: i32, driven: Option<Direction>) -> u32 {
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

/// Stall detection for a brushed motor, which has no halls (docs/decisions.md D13): the duty magnitude strictly
/// above 8 % and the motor not turning by its back-EMF, continuously for 400 ms (the window of the IDS's brushless
/// rule). The back-EMF is the applied voltage (|duty| x VBUS) less I x R ([`Thresholds::armature_milliohms`]); the
/// motor is not turning while it carries less than half the applied voltage, whichever way: the current is then
/// above half the locked-rotor current at that voltage. A heavy rotor's start or a reversal draws as much current
/// while it speeds up, but its back-EMF grows with the speed (and a reversal's opposes the drive) where a locked
/// rotor's stays at zero.
///
/// The applied voltage is known only while the power stage passes the whole duty: a sample in which the break
/// tripped (cycle-by-cycle limiting cut the pulses short) restarts the window. A brushed thruster therefore limits
/// its own current below the stage's comparator ([`crate::speed::CurrentLimit`]), and a locked rotor held at the
/// comparator all the same is stopped by the sustained overcurrent rule ([`crate::overcurrent::TripRule`]). As for
/// [`StallDetector`], the condition first seen at t = 0 and held at every update reports a stall from t = 400 ms.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct CurrentStall {
    stall_duty: u16,
    window: Duration,
    armature_milliohms: u16,
    /// First `update` of the current run of the condition.
    since: Option<Instant>,
}

/// What the fault task measured of a brushed motor in one sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct BrushedSample {
    /// The duty applied.
    pub(crate) duty: Duty,
    /// The motor current, in 0.1 A.
    pub(crate) current_deciamps: u16,
    /// The supply, in mV.
    pub(crate) vbus_mv: u32,
    /// The power stage's break tripped since the last sample.
    pub(crate) break_tripped: bool,
}

impl CurrentStall {
    /// A detector that has seen nothing.
    pub(crate) const fn new(thresholds: &Thresholds) -> Self {
        CurrentStall {
            stall_duty: thresholds.stall_duty,
            window: thresholds.stall_window,
            armature_milliohms: thresholds.armature_milliohms,
            since: None,
        }
    }

    /// The back-EMF of `sample` in mV, in the driven direction (negative when the motor turns against the
    /// drive), and the applied voltage it was taken from.
    pub(crate) fn back_emf_mv(&self, sample: &BrushedSample) -> (i64, i64) {
        // |duty| <= 10 000 and VBUS < 2^32 mV; current < 2^16 x 0.1 A and R < 2^16 mohm: all far inside i64.
        let applied = i64::from(sample.duty.magnitude()) * i64::from(sample.vbus_mv) / i64::from(FULL_DUTY);
        let drop = i64::from(sample.current_deciamps) * i64::from(self.armature_milliohms) / 10;
        (applied - drop, applied)
    }

    /// Whether the motor is stalled at `now`.
    pub(crate) fn update(&mut self, now: Instant, sample: BrushedSample) -> bool {
        let (emf, applied) = self.back_emf_mv(&sample);
        let still = 2 * emf.abs() < applied;
        if sample.duty.magnitude() <= self.stall_duty || sample.break_tripped || !still {
            self.since = None;
            return false;
        }
        let since = *self.since.get_or_insert(now);
        now.saturating_duration_since(since) >= self.window
    }

    /// Forget the history, as after [`CurrentStall::new`].
    pub(crate) fn reset(&mut self) {
        self.since = None;
    }
}

/// Full scale of a [`Duty`], as the back-EMF's arithmetic takes it.
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
pub(crate) struct FaultMonitor {
    family: Family,
    thresholds: Thresholds,
    faults: Faults,
    /// Consecutive samples below the water threshold, at or above its band, below the ground threshold, and with
    /// the halls abnormal.
    wet: Run,
    dry: Run,
    grounded: Run,
    bad_halls: Run,
    /// Consecutive samples at or above the overtemp threshold, and at or below its clear.
    hot: Run,
    cool: Run,
}

impl FaultMonitor {
    /// A monitor with no fault, as at power-up.
    pub(crate) fn new(family: Family, thresholds: Thresholds) -> Self {
        FaultMonitor {
            family,
            thresholds,
            faults: Faults::NONE,
            wet: Run(0),
            dry: Run(0),
            grounded: Run(0),
            bad_halls: Run(0),
            hot: Run(0),
            cool: Run(0),
        }
    }

    /// Apply one sample (plus the stall detector's verdict) and return the faults to report.
    ///
    /// The returned faults already reflect this sample, so the motor stops on the sample that completes a
    /// fault's count (the first sample for stall).
    pub(crate) fn update(&mut self, sample: Sample, stalled: bool) -> Faults {
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
        let temperature = sample.temperature_decicelsius;
        if self
            .hot
            .sample(temperature >= t.overtemp_set_decicelsius, t.latch_samples)
        {
            self.faults.insert(Faults::OVERTEMP);
        }
        if self
            .cool
            .sample(temperature <= t.overtemp_clear_decicelsius, t.latch_samples)
        {
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

    /// A valid order arrived: a zero-speed order clears the stall latch (the AM32/BLHeli rule, docs/decisions.md D11).
    /// Other orders, and other faults, are untouched.
    pub(crate) fn on_order(&mut self, speed: Speed) {
        if speed.is_zero() {
            self.faults.remove(Faults::STALL);
        }
    }

    /// The faults to report now.
    #[cfg(test)]
    pub(crate) fn faults(&self) -> Faults {
        self.faults
    }

    /// The faults a family keeps until power cycle: ground fault, and for Legacy water too (IDS 8.4.1 remarks 2
    /// and 6, 8.4.2 remark 3).
    pub(crate) const fn power_cycle_latches(family: Family) -> Faults {
        match family {
            Family::Legacy => Faults::GROUND.union(Faults::WATER),
            Family::SeaBotix => Faults::GROUND,
        }
    }

    /// The power-cycle latches set now: what must survive a reset.
    pub(crate) fn latched(&self) -> Faults {
        self.faults & Self::power_cycle_latches(self.family)
    }

    /// Take back the latches carried over a reset; only those this family keeps until power cycle are taken.
    pub(crate) fn restore(&mut self, latched: Faults) {
        self.faults.insert(latched & Self::power_cycle_latches(self.family));
    }

    /// Whether the motor may be driven: false while any fault that stops the motor for this family is present.
    /// Every fault stops it except the SeaBotix water warning.
    pub(crate) fn drive_allowed(&self) -> bool {
        let stopping = match self.family {
            Family::Legacy => Faults::ALL,
            Family::SeaBotix => Faults::ALL.difference(Faults::WATER),
        };
        (self.faults & stopping).is_empty()
    }
}

#[cfg(test)]
mod tests;
