//! The thruster motor controller's hardware-free core.
//!
//! Everything here runs unchanged on the STM32 (through the binding in `main.rs`) and on the host, where tests
//! drive it through simulated ports. It never touches a register and never panics on bus input.
#![cfg_attr(not(test), no_std)]

#[macro_use]
mod fmt;

pub mod commutation;
pub mod control;
pub mod drive;
pub mod failsafe;
pub mod faults;
pub mod hall;
pub mod health;
pub mod i2c_slave;
pub mod motorless;
pub mod sensors;
pub mod speed;
pub mod tasks;

pub use drive::{Direction, Duty};
pub use i2c_slave::{I2cTarget, Link, OrderErrors, Request, ServeEvent, serve};

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
