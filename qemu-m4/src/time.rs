//! embassy-time's driver on the board's timers: the clock is the dual timer's first counter, free-running at
//! SYSCLK / 16 (1.5625 MHz, 0.64 us), the alarm is APB timer 0 in one-shot mode at SYSCLK.
//!
//! The clock spans 2^32 counts, 45.8 minutes of emulated time, with no wrap handling: the runs last a few
//! minutes, and a wrap stops the run with an error rather than letting time jump back.

use core::cell::RefCell;
use core::task::Waker;

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_time_driver::Driver;
use embassy_time_queue_utils::Queue;

use crate::board::{self, DUAL_TIMER_1, Irq, Priority, SYSCLK_HZ, TIMER0};
use crate::meter::{self, Meter};

/// SYSCLK cycles per embassy-time tick.
const CYCLES_PER_TICK: u64 = SYSCLK_HZ as u64 / embassy_time_driver::TICK_HZ;
const _: () = assert!(
    embassy_time_driver::TICK_HZ == 1_000_000,
    "the conversions assume 1 us ticks"
);

/// The time driver's alarm interrupt, as the figures report it.
pub static ALARM_METER: Meter = Meter::nested("time driver alarm ISR");

struct Clock {
    queue: Mutex<CriticalSectionRawMutex, RefCell<Queue>>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: Clock = Clock {
    queue: Mutex::new(RefCell::new(Queue::new())),
});

/// Start the clock at 0 and enable the alarm.
pub fn init() {
    DUAL_TIMER_1.start(true, true);
    board::enable(Irq::DualTimer, Priority::Highest);
    board::enable(Irq::Timer0, Priority::Highest);
}

/// Ticks since `init`: the clock's counts of 0.64 us in whole microseconds, floor(counts * 16 / 25), in 32-bit
/// arithmetic (counts = 25 q + r, so the floor is 16 q + floor(16 r / 25)).
fn now_ticks() -> u64 {
    let counts = DUAL_TIMER_1.elapsed();
    u64::from(counts / 25) * 16 + u64::from(counts % 25 * 16 / 25)
}

/// Arm the alarm for `at`; false when `at` has already come (the caller handles the expired timers first).
fn set_alarm(at: u64) -> bool {
    if at == u64::MAX {
        TIMER0.stop();
        return true;
    }
    let now = now_ticks();
    if at <= now {
        TIMER0.stop();
        return false;
    }
    // One tick more: the clock reads in whole ticks, so it shows `at` by the time the alarm fires.
    let cycles = (at - now + 1).saturating_mul(CYCLES_PER_TICK);
    TIMER0.one_shot(u32::try_from(cycles).unwrap_or(u32::MAX));
    true
}

/// Hand the expired timers their wake-up and arm the alarm for the next.
fn rearm(queue: &mut Queue) {
    let mut next = queue.next_expiration(now_ticks());
    while !set_alarm(next) {
        next = queue.next_expiration(now_ticks());
    }
}

impl Driver for Clock {
    fn now(&self) -> u64 {
        now_ticks()
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        self.queue.lock(|queue| {
            let mut queue = queue.borrow_mut();
            if queue.schedule_wake(at, waker) {
                rearm(&mut queue);
            }
        });
    }
}

/// APB timer 0's interrupt: the alarm.
pub extern "C" fn on_alarm() {
    meter::measure(&ALARM_METER, || {
        TIMER0.stop();
        DRIVER.queue.lock(|queue| rearm(&mut queue.borrow_mut()));
    });
}

/// The dual timer's interrupt: the clock wrapped after 45.8 minutes, and time would run backwards.
pub extern "C" fn on_wrap() {
    crate::report::fail("the emulated clock wrapped: a run must stay under 45 minutes of emulated time");
}
