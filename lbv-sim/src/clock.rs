//! The virtual clock: embassy-time's time driver for every host build of the firmware cores.
//!
//! The cores take their time from embassy-time; on the host this driver provides it, and it moves only when told.
//! Each thread has its own clock, so tests on parallel threads (and a bench in each) never move each other's
//! time. Whoever runs cores on a thread first takes that thread's clock with [`take`], which starts it at 0 with
//! no timer pending.
//!
//! The timers are kept in arrival order with their wake-up times, so [`next_alarm`] can tell when anything is due
//! next.

use std::cell::{Cell, RefCell};
use std::task::Waker;

use embassy_time::{Duration, Instant};

/// A timer: when, and whom to wake.
struct Alarm {
    at: u64,
    waker: Waker,
}

/// One thread's clock: ticks since it was taken, and the timers pending.
#[derive(Default)]
struct State {
    now: u64,
    alarms: Vec<Alarm>,
}

thread_local! {
    static STATE: RefCell<State> = RefCell::default();
    static HELD: Cell<bool> = const { Cell::new(false) };
}

/// The host's time driver: this thread's clock.
struct Driver;

impl embassy_time_driver::Driver for Driver {
    fn now(&self) -> u64 {
        STATE.with(|state| state.borrow().now)
    }

    /// A waker already waiting keeps one timer, at the earlier time (as embassy-time's own queues do); a time
    /// already passed wakes at once.
    fn schedule_wake(&self, at: u64, waker: &Waker) {
        let due = STATE.with(|state| {
            let mut state = state.borrow_mut();
            if at <= state.now {
                return true;
            }
            match state.alarms.iter_mut().find(|alarm| alarm.waker.will_wake(waker)) {
                Some(alarm) => alarm.at = alarm.at.min(at),
                None => state.alarms.push(Alarm {
                    at,
                    waker: waker.clone(),
                }),
            }
            false
        });
        if due {
            waker.wake_by_ref();
        }
    }
}

embassy_time_driver::time_driver_impl!(static DRIVER: Driver = Driver);

/// This thread's virtual clock, held: time starts at 0 when it is taken and moves only through
/// [`Clock::advance`] (or an [`Executor`](crate::Executor) run). One run holds it at a time on a thread.
#[derive(Debug)]
pub struct Clock {
    _not_send: core::marker::PhantomData<*const ()>,
}

/// Take this thread's clock and set it to 0 with no timer pending. A thread takes it once at a time: taking it
/// again before the first is dropped would restart the first run's time.
pub fn take() -> Clock {
    let held = HELD.with(|held| held.replace(true));
    debug_assert!(!held, "this thread's clock is already taken");
    STATE.with(|state| *state.borrow_mut() = State::default());
    Clock {
        _not_send: core::marker::PhantomData,
    }
}

impl Drop for Clock {
    fn drop(&mut self) {
        HELD.with(|held| held.set(false));
    }
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

/// Move this thread's clock on by `duration`, waking every timer that falls due, earliest first. Only whoever
/// holds the [`Clock`] calls this (the executor does, in its runs).
pub fn advance(duration: Duration) {
    let mut due = STATE.with(|state| {
        let mut state = state.borrow_mut();
        state.now = state.now.saturating_add(duration.as_ticks());
        let now = state.now;
        let (due, pending): (Vec<Alarm>, Vec<Alarm>) = state.alarms.drain(..).partition(|alarm| alarm.at <= now);
        state.alarms = pending;
        due
    });
    // Woken outside the borrow: a waker may schedule again at once.
    due.sort_by_key(|alarm| alarm.at);
    for alarm in due {
        alarm.waker.wake();
    }
}

/// When the earliest pending timer is due, if any is.
pub fn next_alarm() -> Option<Instant> {
    STATE.with(|state| {
        state
            .borrow()
            .alarms
            .iter()
            .map(|alarm| alarm.at)
            .min()
            .map(Instant::from_ticks)
    })
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
    use embassy_time::Timer;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicU32, Ordering};
    use std::task::Wake;

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

    #[test]
    fn each_thread_has_its_own_clock() {
        let clock = take();
        clock.advance(Duration::from_secs(5));
        let other = std::thread::spawn(|| {
            let clock = take();
            clock.advance(Duration::from_millis(1));
            clock.now()
        });
        assert_eq!(other.join().ok(), Some(Instant::from_millis(1)));
        assert_eq!(clock.now(), Instant::from_secs(5));
    }

    struct Count(AtomicU32);

    impl Wake for Count {
        fn wake(self: Arc<Self>) {
            self.0.fetch_add(1, Ordering::Relaxed);
        }
    }

    #[test]
    fn timers_wake_once_when_due_and_the_next_one_is_known() {
        let clock = take();
        let count = Arc::new(Count(AtomicU32::new(0)));
        let waker = Waker::from(count.clone());
        let mut context = std::task::Context::from_waker(&waker);
        let mut late = core::pin::pin!(Timer::after(Duration::from_micros(30)));
        let mut early = core::pin::pin!(Timer::after(Duration::from_micros(10)));
        assert!(late.as_mut().poll(&mut context).is_pending());
        assert!(early.as_mut().poll(&mut context).is_pending());
        assert_eq!(
            next_alarm(),
            Some(Instant::from_micros(10)),
            "one waker, the earlier time"
        );
        clock.advance(Duration::from_micros(9));
        assert_eq!(count.0.load(Ordering::Relaxed), 0);
        clock.advance(Duration::from_micros(1));
        assert_eq!(count.0.load(Ordering::Relaxed), 1);
        assert_eq!(next_alarm(), None);
        assert!(late.as_mut().poll(&mut context).is_pending());
        assert_eq!(next_alarm(), Some(Instant::from_micros(30)));
        clock.advance(Duration::from_micros(100));
        assert_eq!(count.0.load(Ordering::Relaxed), 2);
        // A time already passed wakes at once (an embassy timer yields once whatever its time).
        let mut past = core::pin::pin!(Timer::at(Instant::from_micros(5)));
        assert!(past.as_mut().poll(&mut context).is_pending());
        assert_eq!(count.0.load(Ordering::Relaxed), 3);
        assert!(past.as_mut().poll(&mut context).is_ready());
    }
}
