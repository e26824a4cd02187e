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
pub mod sensors;
pub mod speed;
pub mod tasks;

pub use drive::{Direction, Duty};
pub use i2c_slave::{I2cTarget, Link, OrderErrors, Request, ServeEvent, serve};
