//! The LBV master node's hardware-free core.
//!
//! Everything here runs unchanged on the STM32 (through the binding in `main.rs`) and on the host, where tests
//! drive it through simulated buses. It never touches a register and never panics on bus input.
#![cfg_attr(not(test), no_std)]

pub mod battery;
pub mod console;
pub mod mixer;
pub mod poll;
pub mod shared;
pub mod tasks;
pub mod thrusters;
pub mod vehicle;

pub use poll::{PollError, poll_thruster};
