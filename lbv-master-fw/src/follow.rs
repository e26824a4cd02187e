//! Whether a thruster follows its orders, judged from what its status echoes of them (docs/master.md, "Does each thruster follow its order").
//!
//! A write path that corrupts every order (a bad pin, a master bug) leaves a thruster running on its last good order
//! while its status reads stay clean, so the link's counters see nothing wrong. The status says what the thruster
//! does: the SeaBotix SPEED byte is the actual speed in the order's encoding, the Legacy brushed MAX POWER the power
//! set into the motor in the same encoding (IDS 8.4). A Legacy brushless thruster echoes only its current: what can
//! be checked there is that it draws none once ordered to stop; whether it turns the way it is ordered cannot.
//!
//! The rule, per answered poll: the echo is acceptable when it is within [`TOLERANCE`] steps of the order, or runs
//! in the order's direction no faster than ordered (on its way, or held back by the load or the INFO cap; with a cap
//! it may stand still). Otherwise it is off, and it must close in on the order: when it has come no step nearer for
//! [`NOT_FOLLOWING_AFTER`] under one order, the thruster does not follow. A fault that stops the motor explains
//! anything and is told on its own, so a thruster that reports one is not judged.

use embassy_time::{Duration, Instant};
use tmc_proto::{Faults, MaxPower, Order, Status};

/// How long an echo may stay off its order without closing in: longer than the thruster's ramp takes to move
/// ten steps (0.5 s for all 102) and than one poll's lag, shorter than its own 1 s failsafe, so a master whose
/// orders stopped arriving says so before the thruster's failsafe acts.
pub(crate) const NOT_FOLLOWING_AFTER: Duration = Duration::from_millis(500);

/// Steps an echo may differ from its order and still match it: a brushless speed measured from hall edges and
/// rounded to 44 rpm steps, a speed loop settling, an order too small to turn the motor.
pub(crate) const TOLERANCE: i16 = 4;

/// Current (0.1 A) a Legacy brushless thruster ordered to stop may still read: its sensor's offset and noise.
pub(crate) const STOPPED_CURRENT_DECIAMPS: i16 = 5;

/// A thruster started or stopped following its orders.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) enum FollowChange {
    /// Its echo stayed off the order without closing in for [`NOT_FOLLOWING_AFTER`].
    Lost,
    /// Its echo matches its order again.
    Regained,
}

/// What a status echoes of the order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Echo {
    /// The speed, in the order's steps (SeaBotix SPEED, Legacy brushed MAX POWER).
    Step(i16),
    /// Only the motor current in 0.1 A (Legacy brushless).
    Current(i16),
}

fn echo(status: &Status) -> Option<Echo> {
    match status {
        Status::SeaBotix(status) => Some(Echo::Step(status.speed.step().into())),
        Status::Legacy(status) => match status.max_power {
            MaxPower::Power(speed) => Some(Echo::Step(speed.step().into())),
            MaxPower::Current { deciamps } => Some(Echo::Current(deciamps.into())),
            MaxPower::Raw(_) => None,
        },
    }
}

/// Whether a reported fault stops the motor: any of them, except water on a SeaBotix controller (a warning there,
/// IDS 8.4 remarks).
fn stopping_fault(status: &Status) -> bool {
    let faults = status.faults();
    match status {
        Status::SeaBotix(_) => !faults.difference(Faults::WATER).is_empty(),
        Status::Legacy(_) => !faults.is_empty(),
    }
}

/// How far the echo is off the order: None when it is acceptable (see the module's rule).
fn off(order: Order, echo: Echo) -> Option<i16> {
    let ordered = i16::from(order.speed.step());
    match echo {
        Echo::Step(actual) => {
            let gap = ordered.abs_diff(actual);
            let same_way = ordered.signum() == actual.signum() || actual.abs() <= TOLERANCE;
            let no_faster = actual.abs() <= ordered.abs().saturating_add(TOLERANCE);
            let capped = order.power_cap_percent().is_some_and(|percent| percent < 100);
            let moving = actual.abs() > TOLERANCE || capped;
            let acceptable = gap <= TOLERANCE.unsigned_abs() || (ordered != 0 && same_way && no_faster && moving);
            (!acceptable).then(|| i16::try_from(gap).unwrap_or(i16::MAX))
        }
        Echo::Current(deciamps) => (ordered == 0 && deciamps > STOPPED_CURRENT_DECIAMPS).then_some(deciamps),
    }
}

/// One thruster's follow check, fed with every valid status and the order sent with it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct FollowCheck {
    /// While the echo is off: the order it is off, the nearest it has come, and since when it has come no nearer.
    off: Option<(Order, i16, Instant)>,
    not_following: bool,
}

impl Default for FollowCheck {
    fn default() -> Self {
        Self::new()
    }
}

impl FollowCheck {
    /// A thruster not yet judged: following.
    pub(crate) const fn new() -> Self {
        Self {
            off: None,
            not_following: false,
        }
    }

    /// Whether the thruster has been found not to follow its order and has not matched it since.
    pub(crate) const fn not_following(&self) -> bool {
        self.not_following
    }

    /// Judge the valid status read at `now` in the poll that sent `order`; `stopped_for_a_reason` is set when the
    /// status says the thruster's own failsafe or overcurrent rule holds it stopped (told on their own).
    pub(crate) fn observe(
        &mut self,
        now: Instant,
        order: Order,
        status: &Status,
        stopped_for_a_reason: bool,
    ) -> Option<FollowChange> {
        if stopped_for_a_reason || stopping_fault(status) {
            self.off = None;
            return None;
        }
        let Some(gap) = echo(status).and_then(|echo| off(order, echo)) else {
            self.off = None;
            return core::mem::take(&mut self.not_following).then_some(FollowChange::Regained);
        };
        match self.off {
            Some((judged, nearest, since)) if judged == order => {
                if gap < nearest {
                    self.off = Some((order, gap, now));
                } else if now.saturating_duration_since(since) >= NOT_FOLLOWING_AFTER && !self.not_following {
                    self.not_following = true;
                    return Some(FollowChange::Lost);
                }
            }
            _ => self.off = Some((order, gap, now)),
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use tmc_proto::{LegacyRevision, LegacyStatus, MotorKind, SeaBotixStatus, Speed};

    use super::*;

    fn seabotix(step: i8, faults: Faults) -> Status {
        Status::SeaBotix(SeaBotixStatus {
            revision: 0,
            motor: MotorKind::Brushless,
            current_limited: false,
            faults,
            current_deciamps: 10,
            speed: Speed::new(step).unwrap(),
            temperature_c: 20,
        })
    }

    fn legacy(revision: LegacyRevision, max_power: MaxPower) -> Status {
        Status::Legacy(LegacyStatus {
            revision,
            faults: Faults::NONE,
            max_power,
        })
    }

    fn order(step: i8) -> Order {
        Order::new(Speed::new(step).unwrap())
    }

    fn ms(t: u64) -> Instant {
        Instant::from_millis(t)
    }

    /// Feed the same order and status every 20 ms from `from` to `to`; the changes seen, with their times.
    fn run(check: &mut FollowCheck, from: u64, to: u64, order: Order, status: Status) -> Vec<(u64, FollowChange)> {
        (from..to)
            .step_by(20)
            .filter_map(|t| check.observe(ms(t), order, &status, false).map(|change| (t, change)))
            .collect()
    }

    #[test]
    fn a_thruster_that_keeps_driving_through_a_stop_is_found_after_half_a_second() {
        let mut check = FollowCheck::new();
        assert_eq!(run(&mut check, 0, 1_000, order(80), seabotix(80, Faults::NONE)), []);
        assert_eq!(
            run(&mut check, 1_000, 3_000, Order::STOP, seabotix(80, Faults::NONE)),
            [(1_500, FollowChange::Lost)],
            "once"
        );
        assert!(check.not_following());
        assert_eq!(
            run(&mut check, 3_000, 3_100, Order::STOP, seabotix(1, Faults::NONE)),
            [(3_000, FollowChange::Regained)]
        );
        assert!(!check.not_following());
    }

    #[test]
    fn one_that_does_not_start_is_found_too() {
        let mut check = FollowCheck::new();
        assert_eq!(
            run(&mut check, 0, 1_000, order(-60), seabotix(0, Faults::NONE)),
            [(500, FollowChange::Lost)]
        );
        // Running the wrong way is as bad.
        let mut check = FollowCheck::new();
        assert_eq!(
            run(&mut check, 0, 1_000, order(-60), seabotix(40, Faults::NONE)),
            [(500, FollowChange::Lost)]
        );
    }

    #[test]
    fn closing_in_is_following_however_slow_the_rotor() {
        let mut check = FollowCheck::new();
        // Coasting from 80 to 0 after a STOP, one step every 100 ms: 8 s, never a verdict.
        for t in (0..8_000).step_by(20) {
            let step = 80 - i8::try_from(t / 100).unwrap();
            assert_eq!(
                check.observe(ms(t), Order::STOP, &seabotix(step, Faults::NONE), false),
                None
            );
        }
        // A full reversal through zero likewise.
        for t in (0..2_000).step_by(20) {
            let step = i8::try_from(100 - i32::try_from(t / 10).unwrap()).unwrap();
            assert_eq!(
                check.observe(ms(t), order(-100), &seabotix(step, Faults::NONE), false),
                None
            );
        }
    }

    #[test]
    fn below_the_order_in_its_direction_is_following() {
        let mut check = FollowCheck::new();
        // The load or the INFO cap holds it at 70 of 102, for a minute.
        assert_eq!(run(&mut check, 0, 60_000, order(102), seabotix(70, Faults::NONE)), []);
        // Near zero, it must move unless a cap holds it there.
        let capped = Order {
            speed: Speed::new(50).unwrap(),
            info: 5,
        };
        assert_eq!(run(&mut check, 60_000, 70_000, capped, seabotix(0, Faults::NONE)), []);
        // Over the order is not.
        assert_eq!(
            run(&mut check, 70_000, 71_000, order(50), seabotix(60, Faults::NONE)),
            [(70_500, FollowChange::Lost)]
        );
    }

    #[test]
    fn a_stopping_fault_explains_a_stop_and_water_on_seabotix_does_not() {
        let mut check = FollowCheck::new();
        assert_eq!(run(&mut check, 0, 5_000, order(60), seabotix(0, Faults::STALL)), []);
        assert_eq!(
            run(&mut check, 5_000, 6_000, order(60), seabotix(0, Faults::WATER)),
            [(5_500, FollowChange::Lost)]
        );
        // The thruster's own failsafe or overcurrent stop is told on its own.
        let mut check = FollowCheck::new();
        for t in (0..5_000).step_by(20) {
            assert_eq!(check.observe(ms(t), order(60), &seabotix(0, Faults::NONE), true), None);
        }
    }

    #[test]
    fn a_new_order_restarts_the_count() {
        let mut check = FollowCheck::new();
        // The order changes every 400 ms and the echo lags: never judged.
        for t in (0..10_000).step_by(20) {
            let ordered = if t / 400 % 2 == 0 { 60 } else { -60 };
            let echoed = if (t + 200) / 400 % 2 == 0 { 60 } else { -60 };
            assert_eq!(
                check.observe(ms(t), order(ordered), &seabotix(echoed, Faults::NONE), false),
                None
            );
        }
    }

    #[test]
    fn legacy_brushed_echoes_its_power_and_legacy_brushless_only_its_current() {
        let brushed = |step| {
            legacy(
                LegacyRevision::LEGACY_BRUSHED,
                MaxPower::Power(Speed::new(step).unwrap()),
            )
        };
        let mut check = FollowCheck::new();
        assert_eq!(run(&mut check, 0, 1_000, order(80), brushed(80)), []);
        assert_eq!(
            run(&mut check, 1_000, 2_000, Order::STOP, brushed(80)),
            [(1_500, FollowChange::Lost)]
        );

        let brushless = |deciamps| legacy(LegacyRevision::AVEOX_BRUSHLESS, MaxPower::Current { deciamps });
        let mut check = FollowCheck::new();
        // Ordered to run: nothing can be said, whatever it draws.
        assert_eq!(run(&mut check, 0, 2_000, order(80), brushless(0)), []);
        assert_eq!(run(&mut check, 2_000, 4_000, order(-80), brushless(90)), []);
        // Ordered to stop, it must stop drawing current.
        assert_eq!(run(&mut check, 4_000, 5_000, Order::STOP, brushless(5)), []);
        assert_eq!(
            run(&mut check, 5_000, 6_000, Order::STOP, brushless(40)),
            [(5_500, FollowChange::Lost)]
        );
        // An unknown revision's MAX POWER says nothing.
        let mut check = FollowCheck::new();
        let raw = legacy(LegacyRevision::ORIGINAL, MaxPower::Raw(200));
        assert_eq!(run(&mut check, 0, 2_000, Order::STOP, raw), []);
    }

    #[test]
    fn a_brushed_seabotix_echo_is_judged_like_a_brushless_one() {
        let mut check = FollowCheck::new();
        let mut status = seabotix(80, Faults::NONE);
        if let Status::SeaBotix(s) = &mut status {
            s.motor = MotorKind::Brushed;
        }
        assert_eq!(
            run(&mut check, 0, 1_000, Order::STOP, status),
            [(500, FollowChange::Lost)]
        );
    }
}
