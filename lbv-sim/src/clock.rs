//! The virtual clock.
//!
//! The firmware cores take their time from embassy-time; on the host that is embassy-time's mock driver, which
//! is one clock for the whole process and moves only when told. Whoever runs cores on it (a test, a bench run)
//! first takes the clock with [`take`]: that waits until no one else holds it, then starts it at 0. Holding the
//! [`Clock`] is what keeps two runs in one process (two tests on parallel threads) from moving each other's time.

use std::sync::{Mutex, MutexGuard};

use embassy_time::{Duration, Instant, MockDriver};

static CLOCK: Mutex<()> = Mutex::new(());

/// The virtual clock, held: time starts at 0 when it is taken and moves only through [`Clock::advance`] (or an
/// [`Executor`](crate::Executor) run). Dropping it lets the next run take the clock.
#[derive(Debug)]
pub struct Clock {
    _held: MutexGuard<'static, ()>,
}

/// Take the clock, waiting while another run holds it, and set it to 0 with no timer pending.
///
/// One thread must not take it twice: the second call would wait for itself.
pub fn take() -> Clock {
    // A test that failed while holding the clock poisons the lock; the clock itself is reset below.
    let held = CLOCK.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    MockDriver::get().reset();
    Clock { _held: held }
}

impl Clock {
    /// Virtual time now.
    pub fn now(&self) -> Instant {
        Instant::now()
    }

    /// Move time on by `duration`, waking every timer that falls due.
    pub fn advance(&self, duration: Duration) {
        advance(duration);
    }
}

/// Move the clock on by `duration`, waking every timer that falls due. Only whoever holds the [`Clock`] calls this
/// (the executor does, in its runs).
pub fn advance(duration: Duration) {
    MockDriver::get().advance(duration);
}

/// For a test that polls its tasks with embassy-futures' `block_on` over a `join` / `select` rather than on an
/// [`Executor`](crate::Executor): let `duration` pass in `step`s, yielding `turns` times after each step so that
/// what the step woke runs before the next. The caller holds the clock.
pub async fn elapse(duration: Duration, step: Duration, turns: u32) {
    let end = Instant::now() + duration;
    while Instant::now() < end {
        advance(step.min(end - Instant::now()));
        for _ in 0..turns {
            embassy_futures::yield_now().await;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_taken_clock_starts_at_zero_and_moves_only_when_told() {
        let clock = take();
        assert_eq!(clock.now(), Instant::from_ticks(0));
        clock.advance(Duration::from_millis(3));
        assert_eq!(Instant::now(), Instant::from_millis(3));
        drop(clock);
        let clock = take();
        assert_eq!(clock.now(), Instant::from_ticks(0), "taken again: back to 0");
    }
}
