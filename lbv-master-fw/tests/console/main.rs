//! The console (MAVLink to the operator's ground station) driven from outside as a ground station drives it, on the
//! virtual clock: receive and transmit sides, connect sequences, floods, signing, reboots, the joystick's buttons,
//! and pymavlink (`tests/mav_peer.py`) as an independent MAVLink implementation. One test binary, linked once.
#![allow(clippy::indexing_slicing, clippy::unwrap_used, clippy::panic)] // test helpers, not firmware

mod buttons;
mod connect;
mod flood;
mod pymavlink;
mod reboot;
mod regressions;
mod rx;
mod signing;
mod support;
mod tx;
