//! What a bench run records: per-thruster samples over time, and the run's events.

use serde::Serialize;

/// One thruster at one instant.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct ThrusterSample {
    /// Shaft speed, rpm (signed, forward positive).
    pub rpm: f64,
    /// Motor current, A.
    pub current_a: f64,
    /// Winding temperature, deg C.
    pub temperature_c: f64,
    /// The fault bits the thruster reports (tmc-proto `Faults::bits`).
    pub faults: u8,
    /// Whether the master sees the thruster online.
    pub online: bool,
    /// The ordered speed step on the wire (-102..=102).
    pub ordered_step: i8,
}

/// Every thruster at one instant, plus the battery.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Sample {
    /// Virtual time, s.
    pub t: f64,
    /// One entry per thruster, in table order.
    pub thrusters: Vec<ThrusterSample>,
    /// Battery terminal voltage, V.
    pub battery_v: f64,
    /// Whether the vehicle is armed.
    pub armed: bool,
}

/// Something that happened, with its virtual time.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Event {
    /// Virtual time, s.
    pub t: f64,
    /// What happened, in words (e.g. a STATUSTEXT the master sent, or an injected fault).
    pub text: String,
}

/// A run's recording: samples at a fixed interval and events as they happen.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Trace {
    /// Samples, oldest first.
    pub samples: Vec<Sample>,
    /// Events, oldest first.
    pub events: Vec<Event>,
}
