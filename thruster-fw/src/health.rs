//! Task heartbeat for the independent watchdog.

use core::sync::atomic::{AtomicU32, Ordering};

/// Task heartbeat for the independent watchdog: the watchdog is fed only while every task reports progress.
///
/// Shared by reference between tasks (`'static` on the target). Each task owns one bit of `reported`; a round is
/// complete when every bit of `expected` is set. The bits carry no other data, so relaxed atomics suffice: a
/// single atomic word has one modification order that every task sees.
#[derive(Debug)]
pub struct Health {
    reported: AtomicU32,
    /// Complete rounds since start (wrapping).
    rounds: AtomicU32,
    /// One bit per task: the first `tasks` bits set.
    expected: u32,
}

impl Health {
    /// Most tasks one `Health` can watch: one bit each in a `u32`.
    pub(crate) const MAX_TASKS: u8 = 32;

    /// `tasks` tasks (1..=32) must each report between two checks.
    ///
    /// `tasks` is clamped to 1..=32: 0 becomes 1 (a watchdog fed with nobody reporting would never bite) and
    /// more than 32 becomes 32.
    pub(crate) const fn new(tasks: u8) -> Self {
        let expected = if tasks >= Self::MAX_TASKS {
            u32::MAX
        } else if tasks == 0 {
            1
        } else {
            // tasks in 1..=31: the shift cannot overflow.
            (1u32 << tasks) - 1
        };
        Health {
            reported: AtomicU32::new(0),
            rounds: AtomicU32::new(0),
            expected,
        }
    }

    /// Task `task` (0-based id < tasks) made progress. Out-of-range ids are ignored.
    pub(crate) fn report(&self, task: u8) {
        let bit = match 1u32.checked_shl(u32::from(task)) {
            Some(bit) => bit & self.expected,
            None => 0,
        };
        if bit != 0 {
            self.reported.fetch_or(bit, Ordering::Relaxed);
        }
    }

    /// True when every task reported since the last successful check; then starts a new round. A false result
    /// leaves the reports in place (so a task that is merely late can still complete the round).
    pub(crate) fn check_and_clear(&self) -> bool {
        // Clear only if the round is complete, in one atomic step, so a report racing with the check is never
        // lost half-way.
        let complete = self
            .reported
            .fetch_update(Ordering::Relaxed, Ordering::Relaxed, |reported| {
                (reported & self.expected == self.expected).then_some(0)
            })
            .is_ok();
        if complete {
            self.rounds.fetch_add(1, Ordering::Relaxed);
        }
        complete
    }

    /// How many checks found every task reported, since start (a new image's trial counts them).
    pub fn rounds(&self) -> u32 {
        self.rounds.load(Ordering::Relaxed)
    }

    /// Which tasks have not reported in this round (bit mask, bit n = task n), for a log line when the watchdog
    /// is about to bite.
    pub(crate) fn missing(&self) -> u32 {
        self.expected & !self.reported.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn all_reported_passes_and_clears() {
        let health = Health::new(3);
        for task in 0..3 {
            health.report(task);
        }
        assert_eq!(health.missing(), 0);
        assert!(health.check_and_clear());
        // A new round: everyone must report again.
        assert_eq!(health.missing(), 0b111);
        assert!(!health.check_and_clear());
        // Reporting twice is the same as once.
        for task in [0, 0, 1, 2, 2] {
            health.report(task);
        }
        assert!(health.check_and_clear());
    }

    #[test]
    fn one_missing_fails_and_is_named() {
        let health = Health::new(4);
        for task in [0, 1, 3] {
            health.report(task);
        }
        assert!(!health.check_and_clear());
        assert_eq!(health.missing(), 0b0100);
        // The reports stay: the late task completes the round.
        assert!(!health.check_and_clear());
        health.report(2);
        assert!(health.check_and_clear());
        assert_eq!(health.missing(), 0b1111);
    }

    #[test]
    fn out_of_range_ids_are_ignored() {
        let health = Health::new(2);
        for task in [2, 5, 31, 32, 200, u8::MAX] {
            health.report(task);
        }
        assert_eq!(health.missing(), 0b11);
        assert!(!health.check_and_clear());
        health.report(0);
        health.report(1);
        assert!(health.check_and_clear());
    }

    #[test]
    fn thirty_two_tasks() {
        let health = Health::new(32);
        assert_eq!(health.missing(), u32::MAX);
        for task in 0..31 {
            health.report(task);
        }
        assert!(!health.check_and_clear());
        assert_eq!(health.missing(), 1 << 31);
        health.report(31);
        assert!(health.check_and_clear());
    }

    #[test]
    fn task_count_is_clamped() {
        // 0 tasks: one task, task 0, must report.
        let health = Health::new(0);
        assert_eq!(health.missing(), 1);
        assert!(!health.check_and_clear());
        health.report(0);
        assert!(health.check_and_clear());

        // More than 32: 32.
        for tasks in [33, u8::MAX] {
            let health = Health::new(tasks);
            assert_eq!(health.missing(), u32::MAX);
            for task in 0..=u8::MAX {
                health.report(task);
            }
            assert!(health.check_and_clear());
        }
    }

    #[test]
    fn usable_as_a_static_shared_between_threads() {
        static HEALTH: Health = Health::new(4);
        std::thread::scope(|scope| {
            for task in 0..4 {
                scope.spawn(move || HEALTH.report(task));
            }
        });
        assert!(HEALTH.check_and_clear());
    }
}
