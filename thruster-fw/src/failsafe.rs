//! Link failsafe: stop the motor when the master falls silent, or when no order it sends can be taken.

use embassy_time::{Duration, Instant};

/// Link failsafe: if nothing addressed to this controller arrives for `timeout` (default 1 s), the motor goes to
/// zero; the next valid order resumes. Reads count as life (masters that send orders only on change keep the link
/// alive by polling status). But an order refused (checksum, length, type, range) with no valid order after it for
/// `timeout` also stops the motor, however many reads come meanwhile: the link can no longer carry a change, and a
/// STOP may be among the orders lost (docs/thruster.md, "The link failsafe").
///
/// Only the latest life matters: if the clock ever reported an instant earlier than a previous one, the timeout
/// runs from that earlier instant, so the failsafe can never be pushed into the future by a bad time stamp.
#[derive(Debug, Clone, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct LinkFailsafe {
    timeout: Duration,
    last_life: Instant,
    /// The first order refused since the last valid one.
    refused_since: Option<Instant>,
    /// The instant the timeout of the last trip counted from: a trip is counted once, however often it is checked.
    tripped_from: Option<Instant>,
    trips: u32,
}

impl LinkFailsafe {
    /// One second without an order or a status read, or of refused orders only, stops the motor.
    pub(crate) const DEFAULT_TIMEOUT: Duration = Duration::from_secs(1);

    /// A failsafe that starts alive: the timeout runs from power-up (`now`).
    pub(crate) fn new(timeout: Duration, now: Instant) -> Self {
        LinkFailsafe {
            timeout,
            last_life: now,
            refused_since: None,
            tripped_from: None,
            trips: 0,
        }
    }

    /// The master last addressed this controller (a valid order or a status read) at `at`; `refused_since` is the
    /// first order refused since the last valid one, if any was.
    pub(crate) fn on_life(&mut self, at: Instant, refused_since: Option<Instant>) {
        self.last_life = at;
        self.refused_since = refused_since;
    }

    /// The instant the timeout runs from: the last life, or the first refused order if that came earlier.
    fn counting_from(&self) -> Instant {
        self.refused_since
            .map_or(self.last_life, |refused| refused.min(self.last_life))
    }

    /// True once `timeout` has passed since the last life, or since the first order refused after the last valid
    /// one (exactly: now - then >= timeout). Instants before those count as alive.
    pub(crate) fn expired(&self, now: Instant) -> bool {
        now.checked_duration_since(self.counting_from())
            .is_some_and(|passed| passed >= self.timeout)
    }

    /// Like [`LinkFailsafe::expired`], and counts a trip on each alive -> expired transition it observes.
    /// Returns whether the link is expired.
    pub(crate) fn check(&mut self, now: Instant) -> bool {
        let expired = self.expired(now);
        let from = self.counting_from();
        if expired && self.tripped_from != Some(from) {
            self.trips = self.trips.saturating_add(1);
            self.tripped_from = Some(from);
        }
        expired
    }

    /// Times the failsafe has tripped (alive -> expired transitions observed through `check`), for telemetry.
    /// Saturates at `u32::MAX`.
    pub(crate) fn trips(&self) -> u32 {
        self.trips
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(millis: u64) -> Instant {
        Instant::from_millis(millis)
    }

    #[test]
    fn expires_exactly_at_the_timeout() {
        let failsafe = LinkFailsafe::new(LinkFailsafe::DEFAULT_TIMEOUT, ms(0));
        assert!(!failsafe.expired(ms(0)));
        assert!(!failsafe.expired(ms(999)));
        assert!(failsafe.expired(ms(1_000)));
        assert!(failsafe.expired(ms(1_000_000)));

        let mut failsafe = LinkFailsafe::new(LinkFailsafe::DEFAULT_TIMEOUT, ms(500));
        failsafe.on_life(ms(2_000), None);
        assert!(!failsafe.expired(ms(2_999)));
        assert!(failsafe.expired(ms(3_000)));
    }

    #[test]
    fn timeout_is_configurable() {
        let failsafe = LinkFailsafe::new(Duration::from_millis(250), ms(100));
        assert!(!failsafe.expired(ms(349)));
        assert!(failsafe.expired(ms(350)));

        // A zero timeout is expired from the start.
        let failsafe = LinkFailsafe::new(Duration::from_ticks(0), ms(100));
        assert!(failsafe.expired(ms(100)));
    }

    #[test]
    fn life_resumes_and_trips_count_once_per_expiry() {
        let mut failsafe = LinkFailsafe::new(LinkFailsafe::DEFAULT_TIMEOUT, ms(0));
        assert!(!failsafe.check(ms(500)));
        assert_eq!(failsafe.trips(), 0);

        // Expired: counted once however often it is checked.
        for t in [1_000, 1_001, 1_500, 5_000] {
            assert!(failsafe.check(ms(t)));
        }
        assert_eq!(failsafe.trips(), 1);

        // Life resumes at once.
        failsafe.on_life(ms(5_100), None);
        assert!(!failsafe.check(ms(5_100)));
        assert!(!failsafe.check(ms(6_099)));
        assert_eq!(failsafe.trips(), 1);

        // A second silence is a second trip.
        assert!(failsafe.check(ms(6_100)));
        assert!(failsafe.check(ms(7_000)));
        assert_eq!(failsafe.trips(), 2);

        // Life followed by silence with no check in between is still a new trip.
        failsafe.on_life(ms(7_100), None);
        assert!(failsafe.check(ms(9_000)));
        assert_eq!(failsafe.trips(), 3);

        // expired() alone never counts.
        failsafe.on_life(ms(9_100), None);
        assert!(failsafe.expired(ms(20_000)));
        assert_eq!(failsafe.trips(), 3);
    }

    #[test]
    fn refused_orders_stop_the_motor_however_many_reads_come() {
        let mut failsafe = LinkFailsafe::new(LinkFailsafe::DEFAULT_TIMEOUT, ms(0));
        // An order refused at 100 ms, then a read every 20 ms: the reads are life, the refusal is not forgotten.
        failsafe.on_life(ms(0), Some(ms(100)));
        for t in (120..1_100).step_by(20) {
            failsafe.on_life(ms(t), Some(ms(100)));
            assert_eq!(failsafe.check(ms(t)), t >= 1_100, "at {t} ms");
        }
        assert!(!failsafe.check(ms(1_099)));
        assert!(failsafe.check(ms(1_100)), "1 s after the first refused order");
        for t in (1_120..3_000).step_by(20) {
            failsafe.on_life(ms(t), Some(ms(100)));
            assert!(failsafe.check(ms(t)));
        }
        assert_eq!(failsafe.trips(), 1, "one trip, however many reads follow it");
        // A valid order ends it.
        failsafe.on_life(ms(3_000), None);
        assert!(!failsafe.check(ms(3_000)));
        // A refusal after the last life, then silence: the silence's timeout comes first, from the last life.
        failsafe.on_life(ms(3_000), Some(ms(3_500)));
        assert!(!failsafe.check(ms(3_999)));
        assert!(failsafe.check(ms(4_000)));
        assert_eq!(failsafe.trips(), 2);
    }

    #[test]
    fn backwards_time_does_not_panic() {
        let mut failsafe = LinkFailsafe::new(LinkFailsafe::DEFAULT_TIMEOUT, ms(10_000));
        // Before the last life: alive.
        assert!(!failsafe.expired(ms(0)));
        assert!(!failsafe.check(Instant::from_ticks(0)));
        // A life stamped earlier restarts the timeout from that instant.
        failsafe.on_life(ms(2_000), None);
        assert!(failsafe.check(ms(3_000)));
        failsafe.on_life(Instant::MAX, None);
        assert!(!failsafe.check(Instant::MAX));
        assert!(!failsafe.check(ms(0)));

        let mut long = LinkFailsafe::new(Duration::MAX, Instant::from_ticks(0));
        assert!(!long.check(Instant::from_ticks(u64::MAX - 1)));
        assert!(long.check(Instant::MAX));
        assert_eq!(long.trips(), 1);
    }
}
