//! The master's configuration, in one place: the thruster tables, the thruster bus's speed and timeout, the
//! battery CAN and console links, the polling and the other tasks' settings, the acceptance test's timings.
//!
//! [`CONFIG`] is the one the image is built with (Cargo features `devkit`, `legacy`, `acceptance`); the STM32
//! binding configures its peripherals from it and hands it to [`crate::run`], and the bench and the tests run
//! [`crate::run`] with these same values.

use embassy_time::Duration;
use tmc_proto::Family;

use crate::acceptance::{AcceptanceConfig, AcceptanceSetup};
use crate::console::ConsoleConfig;
use crate::mixer::FrameKind;
use crate::recovery::BusConfig;
use crate::thrusters::{PollConfig, ThrusterSlot, ThrusterTable};
use crate::vehicle::VehicleConfig;

/// Everything fixed at build time for one master.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct MasterConfig {
    /// The thrusters: which bus, which TCA9548A channel, which family.
    pub thrusters: ThrusterTable,
    /// The thruster buses.
    pub bus: BusConfig,
    /// How often thrusters are polled and offline ones retried.
    pub(crate) poll: PollConfig,
    /// The battery CAN bus's bit rate.
    pub can_bitrate: u32,
    /// The console's serial link, baud.
    pub console_baud: u32,
    /// The console task's settings.
    pub console: ConsoleConfig,
    /// The vehicle task's settings.
    pub vehicle: VehicleConfig,
    /// The acceptance image's script (used only by `run` with the acceptance script as the buses' work).
    pub acceptance: AcceptanceSetup,
}

/// The bus the LBV300-6's TCA9548A and the dev kit's thruster are wired to: I2C2.
pub const THRUSTER_BUS: u8 = 1;

/// The LBV300-6's wiring: six thrusters behind a TCA9548A on I2C2, channels 0-5, numbered as in
/// [`crate::mixer`]; `families` says which controller sits on each.
pub const fn lbv300_6(families: [Family; 6]) -> ThrusterTable {
    let [f0, f1, f2, f3, f4, f5] = families;
    ThrusterTable::new(&[
        ThrusterSlot::behind_mux(THRUSTER_BUS, 0, f0),
        ThrusterSlot::behind_mux(THRUSTER_BUS, 1, f1),
        ThrusterSlot::behind_mux(THRUSTER_BUS, 2, f2),
        ThrusterSlot::behind_mux(THRUSTER_BUS, 3, f3),
        ThrusterSlot::behind_mux(THRUSTER_BUS, 4, f4),
        ThrusterSlot::behind_mux(THRUSTER_BUS, 5, f5),
    ])
}

/// The two-board bench: one thruster of `family` wired to I2C2 directly.
pub(crate) const fn devkit(family: Family) -> ThrusterTable {
    ThrusterTable::new(&[ThrusterSlot::direct(THRUSTER_BUS, family)])
}

/// The vehicle: an LBV300-6 with six SeaBotix thrusters.
pub(crate) const LBV300_6: ThrusterTable = lbv300_6([Family::SeaBotix; 6]);

impl MasterConfig {
    /// A master polling `thrusters`: the production bus, links, polling and task settings.
    pub const fn with_thrusters(thrusters: ThrusterTable) -> Self {
        let count = thrusters.count();
        Self {
            thrusters,
            bus: BusConfig::THRUSTERS,
            poll: PollConfig::DEFAULT,
            can_bitrate: 1_000_000,
            // The ST-LINK virtual COM port.
            console_baud: 115_200,
            console: ConsoleConfig {
                thrusters: count,
                ..ConsoleConfig::DEFAULT
            },
            vehicle: VehicleConfig {
                thrusters: count,
                ..VehicleConfig::new(FrameKind::Lbv300_6)
            },
            acceptance: AcceptanceSetup {
                script: AcceptanceConfig::DEFAULT,
                bus: THRUSTER_BUS,
                start: Duration::from_secs(3),
            },
        }
    }

    /// The dev kit's master, expecting a thruster of `family` (the acceptance script checks it answers).
    pub const fn devkit(family: Family) -> Self {
        let mut config = Self::with_thrusters(devkit(family));
        config.acceptance.script.expect = Some(family);
        config
    }
}

/// The vehicle's master.
pub const VEHICLE: MasterConfig = MasterConfig::with_thrusters(LBV300_6);

/// The family the dev-kit builds expect (Cargo feature `legacy`).
const DEVKIT_FAMILY: Family = if cfg!(feature = "legacy") {
    Family::Legacy
} else {
    Family::SeaBotix
};

/// The configuration this image is built with: the vehicle, or with Cargo feature `devkit` (and `acceptance`,
/// which implies it) the dev kit's one thruster of the `legacy` feature's family.
pub const CONFIG: MasterConfig = if cfg!(feature = "devkit") {
    MasterConfig::devkit(DEVKIT_FAMILY)
} else {
    VEHICLE
};

// Two thrusters that would answer the same transfer, or a bus or channel that does not exist, fail the build.
const _: () = assert!(CONFIG.thrusters.check().is_ok());
const _: () = assert!(VEHICLE.thrusters.check().is_ok());
const _: () = assert!(devkit(Family::Legacy).check().is_ok());

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_vehicle_is_six_seabotix_thrusters_behind_the_mux_on_i2c2() {
        let table = VEHICLE.thrusters;
        assert_eq!(table.as_slice().len(), 6);
        for (channel, slot) in (0..).zip(table.as_slice()) {
            assert_eq!(*slot, ThrusterSlot::behind_mux(1, channel, Family::SeaBotix));
        }
        assert_eq!(VEHICLE.console.thrusters, 6);
        assert_eq!(VEHICLE.vehicle.thrusters, 6);
        assert_eq!(VEHICLE.vehicle.frame, FrameKind::Lbv300_6);
    }

    #[test]
    fn the_devkit_is_one_thruster_on_i2c2_and_the_script_expects_its_family() {
        for family in Family::ALL {
            let config = MasterConfig::devkit(family);
            assert_eq!(config.thrusters.as_slice(), [ThrusterSlot::direct(1, family)]);
            assert_eq!(config.console.thrusters, 1);
            assert_eq!(config.acceptance.script.expect, Some(family));
            assert_eq!(config.acceptance.bus, 1);
        }
    }
}
