//! The bench's scenarios: each injects something into the running vehicle and checks the reaction the
//! interface specification (and the project's reading of it) calls for. `lbv bench` runs them, and so does
//! `cargo test` (one test each, in `tests.rs`), through the same harness.
//!
//! - [`harness`]: the run, its checks and report, and the checks every run gets;
//! - [`fault`]: the one [`Fault`] type the scenarios, the soak and the acceptance operator inject and clear;
//! - the scenario groups: [`vehicle`], [`console`], [`flood`], [`thruster_faults`], [`bus`], [`update`], [`soak`],
//!   [`acceptance`].

pub mod acceptance;
pub mod bus;
pub mod console;
pub mod fault;
pub mod flood;
pub mod harness;
pub mod soak;
pub mod thruster_faults;
pub mod update;
pub mod vehicle;

#[cfg(test)]
mod fidelity;
#[cfg(test)]
mod tests;

pub use harness::{Options, Report, Scenario, run_guarded};

use acceptance::acceptance;
use bus::{
    bad_frames, corrupted_stop, link_failsafe, missing_thruster, reset_mid_transfer, six_byte_status, status_noise,
    stuck_sda,
};
use console::{
    ground_station_1hz, second_sysid, settings_persist, settings_power_cut, settings_while_driving, signing,
    signing_reboot, stray_byte,
};
use flood::console_flood;
use harness::{brushed6, dev_kits, heavy_brushed6, lbv300, lbv300_uart, legacy6, mixed, mixed_uart};
use soak::soak;
use thruster_faults::{
    ground_fault, ground_glitch, hall, hall_glitches, heavy_start, info_power, info_power_response, overcurrent,
    overcurrent_intermittent, overtemp, rocking_rotor, stall, stall_brushed, water, water_threshold,
};
use update::{field_update, fleet_update, master_update};
use vehicle::{battery_bits, battery_lost, black_box, console_silence, dive, master_reboot, thruster_crash};

/// `lbv bench`'s default seed, which the tests run every scenario with.
#[cfg(test)]
const SEED: u64 = 1;

/// Every scenario, in the order `--list` and `--all` use.
pub const SCENARIOS: &[Scenario] = &[
    Scenario {
        name: "dive",
        about: "arm, drive ahead, yaw, disarm: thrusters follow the sticks, telemetry reaches the console",
        seconds: 12.0,
        vehicle: mixed,
        run: dive,
    },
    Scenario {
        name: "water-legacy",
        about: "water (500 kohm) in a Legacy thruster: it stops and latches; the others keep working",
        seconds: 6.0,
        vehicle: legacy6,
        run: water,
    },
    Scenario {
        name: "water-seabotix",
        about: "water (500 kohm) in a SeaBotix thruster: a warning only, it keeps driving; clears when dry",
        seconds: 6.0,
        vehicle: lbv300,
        run: water,
    },
    Scenario {
        name: "ground-fault-legacy",
        about: "50 kohm between the water electrodes, Legacy: stops, latched after drying",
        seconds: 6.0,
        vehicle: legacy6,
        run: ground_fault,
    },
    Scenario {
        name: "ground-fault-seabotix",
        about: "50 kohm between the water electrodes, SeaBotix: stops, latched after drying",
        seconds: 6.0,
        vehicle: lbv300,
        run: ground_fault,
    },
    Scenario {
        name: "overtemp-legacy",
        about: "a Legacy thruster's winding driven hot: stops at 110 C, resumes after cooling to 100 C",
        seconds: 60.0,
        vehicle: legacy6,
        run: overtemp,
    },
    Scenario {
        name: "overtemp-seabotix",
        about: "a SeaBotix thruster's winding driven hot: stops at 110 C, resumes after cooling to 100 C",
        seconds: 60.0,
        vehicle: lbv300,
        run: overtemp,
    },
    Scenario {
        name: "stall-legacy",
        about: "a rope in a Legacy thruster's propeller: stall in 400 ms, cleared by a zero order",
        seconds: 6.0,
        vehicle: legacy6,
        run: stall,
    },
    Scenario {
        name: "stall-brushed",
        about: "a rope in a Legacy brushed thruster's propeller: no back-EMF, stall in 400 ms, cleared by a zero order",
        seconds: 6.0,
        vehicle: brushed6,
        run: stall_brushed,
    },
    Scenario {
        name: "heavy-start-brushed",
        about: "brushed rotors four times as heavy: a full-order start and a full reversal draw the current limit \
                but are no stall",
        seconds: 6.5,
        vehicle: heavy_brushed6,
        run: heavy_start,
    },
    Scenario {
        name: "stall-seabotix",
        about: "a rope in a SeaBotix thruster's propeller: stall in 400 ms, cleared by a zero order",
        seconds: 6.0,
        vehicle: lbv300,
        run: stall,
    },
    Scenario {
        name: "hall-legacy",
        about: "a Legacy thruster's hall sensors unplugged (000): stops at once, resumes when they read normal",
        seconds: 6.0,
        vehicle: legacy6,
        run: hall,
    },
    Scenario {
        name: "hall-seabotix",
        about: "a SeaBotix thruster's hall sensors unplugged (000): stops at once, resumes when they read normal",
        seconds: 6.0,
        vehicle: lbv300,
        run: hall,
    },
    Scenario {
        name: "hall-glitches-seabotix",
        about: "hall noise on a SeaBotix thruster: 0.3 ms glitches keep it driving, 5 ms hall errors all reach the console",
        seconds: 6.0,
        vehicle: lbv300,
        run: hall_glitches,
    },
    Scenario {
        name: "hall-glitches-legacy",
        about: "hall noise on a Legacy thruster: 0.3 ms glitches keep it driving, 5 ms hall errors all reach the console",
        seconds: 6.0,
        vehicle: legacy6,
        run: hall_glitches,
    },
    Scenario {
        name: "rocking-rotor",
        about: "a rope holds a rotor across a hall boundary, rocking every 50 ms at full order: a stall in 400 ms",
        seconds: 6.0,
        vehicle: lbv300,
        run: rocking_rotor,
    },
    Scenario {
        name: "water-threshold",
        about: "a SeaBotix water sensor at 1 Mohm +- one ADC count for 2 s: one warning, no text storm",
        seconds: 6.0,
        vehicle: lbv300,
        run: water_threshold,
    },
    Scenario {
        name: "ground-glitch-seabotix",
        about: "single 90 kohm samples on a SeaBotix water sensor: no ground fault latches",
        seconds: 4.0,
        vehicle: lbv300,
        run: ground_glitch,
    },
    Scenario {
        name: "ground-glitch-legacy",
        about: "single 90 kohm samples on a Legacy water sensor: no ground fault latches",
        seconds: 4.0,
        vehicle: legacy6,
        run: ground_glitch,
    },
    Scenario {
        name: "overcurrent-seabotix",
        about: "a phase shorted: the break trips every period, 5 ms of it stops the bridge, FAULT bit 6 told, a zero \
                order clears it",
        seconds: 6.0,
        vehicle: lbv300,
        run: overcurrent,
    },
    Scenario {
        name: "overcurrent-legacy",
        about: "a phase shorted on a Legacy thruster: stopped as on SeaBotix, with no status bit for it",
        seconds: 6.0,
        vehicle: legacy6,
        run: overcurrent,
    },
    Scenario {
        name: "overcurrent-intermittent",
        about: "one comparator trip stops nothing; a shorted MOSFET tripping on a third of the samples stops the bridge \
                within the 200 ms window, FAULT bit 6 told",
        seconds: 6.0,
        vehicle: lbv300,
        run: overcurrent_intermittent,
    },
    Scenario {
        name: "info-power",
        about: "INFO 50 at full order: the power drawn held to 50 % of the rating, the speed well above half",
        seconds: 8.0,
        vehicle: lbv300,
        run: info_power,
    },
    Scenario {
        name: "info-power-response",
        about: "full ahead from rest at INFO 10, 25, 50, and INFO 100 to 10 at full ahead: the power held within 50 ms",
        seconds: 20.0,
        vehicle: lbv300,
        run: info_power_response,
    },
    Scenario {
        name: "bad-frames",
        about: "corrupted status frames, orders with bad checksums and out-of-range orders: counted, change nothing",
        seconds: 8.0,
        vehicle: mixed,
        run: bad_frames,
    },
    Scenario {
        name: "corrupted-stop",
        about: "STOP ordered while every order to T1 and T2 arrives corrupted, their reads clean: they stop on their \
                failsafe 1 s after the first, and the master says they do not follow",
        seconds: 8.0,
        vehicle: mixed,
        run: corrupted_stop,
    },
    Scenario {
        name: "status-noise",
        about: "8 s of unreadable status reads while the orders get through: full order rate, no stop, told once",
        seconds: 12.0,
        vehicle: lbv300,
        run: status_noise,
    },
    Scenario {
        name: "six-byte-status",
        about: "a thruster answering in the 6-byte SeaBotix form: read, counted, its faults reach the console",
        seconds: 40.0,
        vehicle: lbv300,
        run: six_byte_status,
    },
    Scenario {
        name: "link-failsafe",
        about: "the bus stuck 1.5 s: every thruster stops on its own failsafe; the console hears of each, SeaBotix from \
                FAULT bit 5, Legacy from the master's count of the undelivered orders",
        seconds: 5.0,
        vehicle: mixed,
        run: link_failsafe,
    },
    Scenario {
        name: "missing-thruster",
        about: "one thruster unpowered: found by its first NACK, retried with back-off, the others unslowed",
        seconds: 8.0,
        vehicle: lbv300,
        run: missing_thruster,
    },
    Scenario {
        name: "stuck-sda",
        about: "a slave holds SDA low for 5, then 12 clocks: the master's recovery clocks the bus free, polling resumes",
        seconds: 4.0,
        vehicle: lbv300,
        run: stuck_sda,
    },
    Scenario {
        name: "reset-mid-transfer",
        about: "a thruster loses power between two bytes of an order, then of a status read; its lines let go: the \
                order's next byte is not acknowledged, the read's rest is 0xFF (a bad checksum); no timeout; it \
                rejoins after each reboot",
        seconds: 6.0,
        vehicle: mixed,
        run: reset_mid_transfer,
    },
    Scenario {
        name: "console-silence",
        about: "the console link drops while armed: neutral after 3 s without sticks, disarmed 5 s after the last \
                heartbeat, no restart until re-armed",
        seconds: 11.0,
        vehicle: lbv300,
        run: console_silence,
    },
    Scenario {
        name: "master-reboot",
        about: "the master resets while driving: it orders every thruster to stop, finds them again, drives once re-armed",
        seconds: 6.0,
        vehicle: lbv300,
        run: master_reboot,
    },
    Scenario {
        name: "thruster-crash",
        about: "a thruster's core panics mid-dive: its bridge is off at once, its watchdog resets it, the master \
                drives it again, tells the stop and serves its post-mortem record over MAVLink FTP",
        seconds: 6.0,
        vehicle: lbv300,
        run: thruster_crash,
    },
    Scenario {
        name: "black-box",
        about: "a dive that ends in the master's watchdog reset: the black box keeps it across the reset and an FTP \
                client reads it as a telemetry log whose rpm, orders and arming are the bench's",
        seconds: 9.0,
        vehicle: lbv300,
        run: black_box,
    },
    Scenario {
        name: "battery-lost",
        about: "the BAT board's CAN frames stop for 3 s: flagged stale after 1 s, resumed after",
        seconds: 8.0,
        vehicle: lbv300,
        run: battery_lost,
    },
    Scenario {
        name: "battery-bits",
        about: "BAT status bits flip: start-up report of every bit, then only the switched bits",
        seconds: 5.0,
        vehicle: lbv300,
        run: battery_bits,
    },
    Scenario {
        name: "ground-station-1hz",
        about: "a ground station at 1 Hz holds the vehicle armed on its heartbeats alone, one lost, and with sticks",
        seconds: 20.0,
        vehicle: lbv300,
        run: ground_station_1hz,
    },
    Scenario {
        name: "stray-byte",
        about: "stray bytes on the console, alone and in front of a frame: the frame gets through, still armed",
        seconds: 6.0,
        vehicle: lbv300,
        run: stray_byte,
    },
    Scenario {
        name: "second-sysid",
        about: "system 42 tries to arm, command, set parameters and steer: DENIED or ignored, counted; no failsafe cover",
        seconds: 12.0,
        vehicle: lbv300,
        run: second_sysid,
    },
    Scenario {
        name: "signing",
        about: "a signing key set over the console: unsigned, badly signed and replayed frames refused, signed obeyed",
        seconds: 8.0,
        vehicle: lbv300,
        run: signing,
    },
    Scenario {
        name: "signing-reboot",
        about: "a signed session replayed after a reboot, a 2^48-1 timestamp, year-old frames: refused; all sent signed",
        seconds: 12.0,
        vehicle: lbv300,
        run: signing_reboot,
    },
    Scenario {
        name: "console-flood",
        about: "another system, then a companion, flood FTP listings, parameter lists and messages at 115200 baud for \
                20 s while the operator flies: every byte read, no failsafe, orders at the usual rate",
        seconds: 24.0,
        vehicle: lbv300_uart,
        run: console_flood,
    },
    Scenario {
        name: "settings-persist",
        about: "parameters set over the console survive a reboot (refused while armed) and a power cycle",
        seconds: 5.0,
        vehicle: lbv300,
        run: settings_persist,
    },
    Scenario {
        name: "settings-power-cut",
        about: "power cut during parameter writes, and during a page erase: only the interrupted write is lost",
        seconds: 20.0,
        vehicle: lbv300,
        run: settings_power_cut,
    },
    Scenario {
        name: "settings-while-driving",
        about: "parameter writes and page erases while driving (bank 2, beside the code): no thruster misses an order",
        seconds: 12.0,
        vehicle: lbv300,
        run: settings_while_driving,
    },
    Scenario {
        name: "field-update",
        about: "every thruster updated from the ground station over FTP and the bus; wrong key, family, armed, power cut",
        seconds: 120.0,
        vehicle: mixed,
        run: field_update,
    },
    Scenario {
        name: "fleet-update",
        about: "every thruster updated with one file per family over a 115200 baud console; one left behind caught up",
        seconds: 120.0,
        vehicle: mixed_uart,
        run: fleet_update,
    },
    Scenario {
        name: "master-update",
        about: "the master updated from the ground station over its console link; wrong key, power cuts, revert",
        seconds: 240.0,
        vehicle: lbv300,
        run: master_update,
    },
    Scenario {
        name: "acceptance",
        about: "the master's acceptance test against a SeaBotix and a Legacy thruster, the bench acting as operator",
        seconds: 60.0,
        vehicle: dev_kits,
        run: acceptance,
    },
    Scenario {
        name: "soak",
        about: "random faults and traffic over a long run: every order applied, no task stalled",
        seconds: 120.0,
        vehicle: mixed,
        run: soak,
    },
];

/// The scenario called `name`.
pub fn find(name: &str) -> Option<&'static Scenario> {
    SCENARIOS.iter().find(|scenario| scenario.name == name)
}
