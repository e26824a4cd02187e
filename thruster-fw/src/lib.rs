//! The thruster motor controller's hardware-free core.
//!
//! Everything here runs unchanged on the STM32, through the binding in the `thruster-fw` binary (`main.rs`,
//! `stm32.rs` and `board.rs`, compiled for the firmware target only), and on the host, where tests and the bench
//! drive it through simulated ports. It never touches a register and never panics on bus input.
//!
//! [`run`] and [`run_commutation`] are the whole controller: the STM32 binding builds their ports from peripherals
//! and calls them with [`CONFIG`]; the bench and the tests call them with simulated ports. Every port trait, and the
//! [`Board`](ports::Board) that names a binding's ports, is in [`ports`].
#![cfg_attr(not(test), no_std)]
// What only this crate uses is `pub(crate)`, and its docs still link to it: they are read with the private items
// documented (`cargo doc --document-private-items`, as test.sh builds them), where those links resolve.
#![allow(rustdoc::private_intra_doc_links)]

#[macro_use]
mod fmt;

pub mod commutation;
pub mod config;
pub mod control;
pub mod drive;
pub(crate) mod failsafe;
pub mod faults;
pub mod hall;
pub mod health;
pub mod i2c_slave;
pub mod motorless;
pub mod overcurrent;
pub mod ports;
pub mod sensors;
pub mod shared;
pub mod speed;
pub mod tasks;
pub mod trial;
pub mod update;

#[cfg(any(test, feature = "sim"))]
pub mod sim;

pub use config::Config;
pub use drive::{Direction, Duty};
pub use i2c_slave::MasterLink;
pub use tasks::{run, run_commutation};

use tmc_proto::{Family, MotorKind};

/// The controller family this image is built for: SeaBotix, or Aveox / Legacy with Cargo feature `legacy`.
pub const FAMILY: Family = if cfg!(feature = "legacy") {
    Family::Legacy
} else {
    Family::SeaBotix
};

/// The motor this image drives: brushless with hall commutation, or brushed with Cargo feature `brushed`.
pub(crate) const MOTOR: MotorKind = if cfg!(feature = "brushed") {
    MotorKind::Brushed
} else {
    MotorKind::Brushless
};

/// Everything this image is built with: the reference hardware (see [`Config::reference`]) for its family and motor.
pub const CONFIG: Config = Config::reference(FAMILY, MOTOR);
