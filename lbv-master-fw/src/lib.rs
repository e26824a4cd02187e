//! The LBV master node's hardware-free core.
//!
//! Everything here runs unchanged on the STM32 (through the binding in `main.rs`) and on the host, where tests
//! drive it through simulated buses. It never touches a register and never panics on bus input.
#![cfg_attr(not(test), no_std)]

pub mod acceptance;
pub mod battery;
pub mod console;
pub mod mixer;
pub mod params;
pub mod poll;
pub mod settings;
pub mod shared;
pub mod signing;
pub mod thrusters;
pub mod vehicle;

pub use poll::{PollError, poll_thruster};

#[cfg(test)]
mod tests;

/// Virtual time for the host tests.
#[cfg(test)]
pub(crate) mod test_clock {
    use embassy_time::MockDriver;
    use std::sync::{Mutex, MutexGuard};

    /// embassy-time's mock driver is one clock for the whole test process: every test that moves it, in any
    /// module, holds this lock.
    static CLOCK: Mutex<()> = Mutex::new(());

    /// Take the virtual clock and set it to 0.
    pub(crate) fn lock() -> MutexGuard<'static, ()> {
        let guard = CLOCK.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        MockDriver::get().reset();
        guard
    }
}
