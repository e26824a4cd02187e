//! Link failsafe: stop the motor when the master falls silent.

use embassy_time::{Duration, Instant};

/// Link failsafe: if nothing addressed to this controller arrives for `timeout` (default 1 s), the motor goes to
/// zero; the next valid order resumes. Reads count as life (masters that send orders only on change keep the link
/// alive by polling status).
///
/// Only the latest life matters: if the clock ever reported an instant earlier than a previous one, the timeout
/// runs from that earlier instant, so the failsafe can never be pushed into the future by a bad time stamp.
#[derive(Debug, Clone, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct LinkFailsafe {
    timeout: Duration,
    last_life: Instant,
    /// The last `check` found the link expired, and no life has come since.
    tripped: bool,
    trips: u32,
}

impl LinkFailsafe {
    /// One second without an order or a status read stops the motor.
    pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(1);

    /// A failsafe that starts alive: the timeout runs from power-up (`now`).
    pub fn new(timeout: Duration, now: Instant) -> Self {
        LinkFailsafe {
            timeout,
            last_life: now,
            tripped: false,
            trips: 0,
        }
    }

    /// A valid order or a status read addressed to this controller at `now`.
    pub fn on_life(&mut self, now: Instant) {
        self.last_life = now;
        self.tripped = false;
    }

    /// True once `timeout` has passed since the last life (exactly: now - last >= timeout). Instants before the
    /// last life count as alive.
    pub fn expired(&self, now: Instant) -> bool {
        match now.checked_duration_since(self.last_life) {
            Some(silence) => silence >= self.timeout,
            None => false,
        }
    }

    /// Like [`LinkFailsafe::expired`], and counts a trip on each alive -> expired transition it observes.
    /// Returns whether the link is expired.
    pub fn check(&mut self, now: Instant) -> bool {
        let expired = self.expired(now);
        if expired && !self.tripped {
            self.trips = self.trips.saturating_add(1);
        }
        self.tripped = expired;
        expired
    }

    /// Times the failsafe has tripped (alive -> expired transitions observed through `check`), for telemetry.
    /// Saturates at `u32::MAX`.
    pub fn trips(&self) -> u32 {
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
        failsafe.on_life(ms(2_000));
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
        failsafe.on_life(ms(5_100));
        assert!(!failsafe.check(ms(5_100)));
        assert!(!failsafe.check(ms(6_099)));
        assert_eq!(failsafe.trips(), 1);

        // A second silence is a second trip.
        assert!(failsafe.check(ms(6_100)));
        assert!(failsafe.check(ms(7_000)));
        assert_eq!(failsafe.trips(), 2);

        // Life followed by silence with no check in between is still a new trip.
        failsafe.on_life(ms(7_100));
        assert!(failsafe.check(ms(9_000)));
        assert_eq!(failsafe.trips(), 3);

        // expired() alone never counts.
        failsafe.on_life(ms(9_100));
        assert!(failsafe.expired(ms(20_000)));
        assert_eq!(failsafe.trips(), 3);
    }

    #[test]
    fn backwards_time_does_not_panic() {
        let mut failsafe = LinkFailsafe::new(LinkFailsafe::DEFAULT_TIMEOUT, ms(10_000));
        // Before the last life: alive.
        assert!(!failsafe.expired(ms(0)));
        assert!(!failsafe.check(Instant::from_ticks(0)));
        // A life stamped earlier restarts the timeout from that instant.
        failsafe.on_life(ms(2_000));
        assert!(failsafe.check(ms(3_000)));
        failsafe.on_life(Instant::MAX);
        assert!(!failsafe.check(Instant::MAX));
        assert!(!failsafe.check(ms(0)));

        let mut long = LinkFailsafe::new(Duration::MAX, Instant::from_ticks(0));
        assert!(!long.check(Instant::from_ticks(u64::MAX - 1)));
        assert!(long.check(Instant::MAX));
        assert_eq!(long.trips(), 1);
    }
}
