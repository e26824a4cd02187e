//! The master's whole core on the chip, as the vehicle image runs it: `lbv_master_fw::run` with the vehicle's
//! configuration (`VEHICLE`: an LBV300-6, six thrusters behind a TCA9548A) and `Polling` on the buses, six
//! motor-less thruster cores on the same chip, the battery monitor fed by a BAT board that sends the real
//! firmware's frames, and the MAVLink console. A scripted pilot at the ground station arms, flies forward, rides
//! out a thruster holding SDA low (which the master's recovery clears on the bus's lines), disarms, and lets the
//! console failsafe disarm the vehicle, checking each answer.

use bat_proto::{BatteryInfo, DcdcStatus, Frame};
use embassy_executor::Spawner;
use embassy_time::{Duration, Instant, Timer};
use lbv_master_fw::Polling;
use lbv_master_fw::config::{THRUSTER_BUS, VEHICLE};
use lbv_master_fw::console::lbv::MavResult;
use lbv_master_fw::mixer::ManualInput;
use lbv_master_fw::ports::CanFrame;
use lbv_master_fw::shared::MAV_CMD_COMPONENT_ARM_DISARM;
use lbv_master_fw::vehicle::NEUTRAL;
use lbv_station::Seen;

use crate::executors::{self, BENCH_METER};
use crate::i2c::{self, Bus, MAX_THRUSTERS};
use crate::master::{self, CAN, CONSOLE_STATS, MASTER_METER, MasterPorts};
use crate::meter::metered;
use crate::stacks::Stack;
use crate::station;
use crate::thruster::{self, HallInput};
use crate::{report, say};

/// Start the master, its six thrusters, the BAT board, the ground station and the pilot.
pub fn start(thread: Spawner) {
    let high = executors::start_commutation();
    let buses = master::buses(&VEHICLE, thread, high, HallInput::Model);
    let Some(bus) = buses.get(usize::from(THRUSTER_BUS)).copied() else {
        report::fail("the vehicle has no thruster bus");
    };
    report::spawn(thread, master(master::ports(buses, Polling::default())));
    report::spawn(thread, bat_board());
    report::spawn(thread, station::receive());
    report::spawn(thread, station::transmit());
    report::spawn(thread, pilot(bus));
}

/// The vehicle's master image.
#[embassy_executor::task]
async fn master(ports: MasterPorts<Polling<'static>>) -> ! {
    master::run(ports, &VEHICLE).await
}

/// The pack the BAT board reports: 25.2 V (7 cells), 80 %.
const PACK_DECIVOLTS: u16 = 252;
/// The DCDC status word of the seed's example (172): hot swap manager on and power good, both 12 V regulators on.
const DCDC_STATUS: u16 = 172;

/// The BAT board, with its firmware's timing: one frame every 100 ms, 0x620 and 0x629 in turn.
#[embassy_executor::task]
async fn bat_board() -> ! {
    metered(&BENCH_METER, None, send_bat_frames()).await
}

async fn send_bat_frames() -> ! {
    let frames = [
        Frame::Info(BatteryInfo {
            voltage_decivolts: PACK_DECIVOLTS,
            charge_percent: Some(80),
            current_deciamps: None,
            temperature_decicelsius: None,
        }),
        Frame::Status(DcdcStatus::from_word(DCDC_STATUS)),
    ];
    for frame in frames.iter().cycle() {
        let (id, data) = frame.encode();
        CAN.send(CanFrame { id, len: 8, data }).await;
        Timer::after(Duration::from_millis(100)).await;
    }
    report::fail("the BAT board's frame list ended")
}

/// How often the pilot looks at what came in.
const LOOK: Duration = Duration::from_millis(10);

/// Wait up to `within` for `condition` on what the station has seen, holding `sticks` meanwhile (the station
/// sends them at 10 Hz, as QGroundControl); how long it took.
async fn wait_for(
    within: Duration,
    sticks: Option<ManualInput>,
    condition: impl Fn(&Seen) -> bool,
) -> Option<Duration> {
    station::change(|station| station.sticks = sticks).await;
    let start = Instant::now();
    loop {
        if station::seen(&condition).await {
            return Some(start.elapsed());
        }
        if start.elapsed() >= within {
            return None;
        }
        Timer::after(LOOK).await;
    }
}

/// MAV_CMD_COMPONENT_ARM_DISARM, its answer awaited afresh.
async fn arm(arm: bool) {
    let frame = station::with(|station| {
        station.seen.acks.clear();
        station.arm(arm)
    })
    .await;
    station::send(&frame).await;
}

fn accepted(seen: &Seen) -> bool {
    seen.acks.last() == Some(&(MAV_CMD_COMPONENT_ARM_DISARM, MavResult::MAV_RESULT_ACCEPTED as u8))
}

/// Thrusters turning faster than `rpm`.
fn turning(seen: &Seen, rpm: u16) -> usize {
    seen.rpm
        .iter()
        .take(MAX_THRUSTERS)
        .filter(|speed| **speed > rpm)
        .count()
}

/// The tally of the pilot's steps.
#[derive(Debug, Default)]
struct Tally {
    passed: u8,
    failed: u8,
}

impl Tally {
    fn step(&mut self, name: &str, passed: bool, figures: core::fmt::Arguments<'_>) {
        if passed {
            self.passed += 1;
        } else {
            self.failed += 1;
        }
        say!(
            "PILOT step={name} result={} {figures}",
            if passed { "PASS" } else { "FAIL" }
        );
    }
}

/// Milliseconds for a report, -1 for never.
fn ms(took: Option<Duration>) -> i64 {
    took.map_or(-1, |took| i64::try_from(took.as_millis()).unwrap_or(i64::MAX))
}

/// Forward on the sticks: x 800 of 1000, heave neutral.
const FORWARD: ManualInput = ManualInput { x: 800, ..NEUTRAL };
/// The thruster a glitch leaves holding SDA, and for how many SCL clocks (fewer than the recovery's nine).
const GLITCHED_THRUSTER: usize = 2;
const GLITCH_CLOCKS: u32 = 5;
/// A thruster counts as driving above this speed, as stopped below the other.
const DRIVING_RPM: u16 = 500;
const STOPPED_RPM: u16 = 50;

/// The pilot's session, then the figures.
#[embassy_executor::task]
async fn pilot(bus: &'static Bus) {
    let (pass, frames) = metered(&BENCH_METER, None, async {
        (fly(bus).await, station::seen(|seen| seen.frames).await)
    })
    .await;
    finish(bus, pass, frames);
}

/// The pilot's steps; whether all passed.
async fn fly(bus: &Bus) -> bool {
    let mut tally = Tally::default();

    let link = wait_for(Duration::from_secs(3), None, |seen| seen.heartbeats > 0).await;
    tally.step("link", link.is_some(), format_args!("heartbeat_ms={}", ms(link)));

    let polled = wait_for(Duration::from_secs(3), None, |seen| {
        seen.polls.iter().take(MAX_THRUSTERS).all(|count| *count > 0)
    })
    .await;
    let polls = station::seen(|seen| seen.polls).await;
    tally.step(
        "thrusters-online",
        polled.is_some(),
        format_args!(
            "online_ms={} polls={:?}",
            ms(polled),
            polls.get(..MAX_THRUSTERS).unwrap_or_default()
        ),
    );

    let expected_mv = PACK_DECIVOLTS * 100;
    let battery = wait_for(Duration::from_secs(3), None, |seen| seen.battery_mv == expected_mv).await;
    let voltage_mv = station::seen(|seen| seen.battery_mv).await;
    tally.step(
        "battery",
        battery.is_some(),
        format_args!("voltage_mv={voltage_mv} expected_mv={expected_mv}"),
    );

    arm(true).await;
    let armed = wait_for(Duration::from_secs(1), None, |seen| accepted(seen) && seen.armed).await;
    tally.step("arm", armed.is_some(), format_args!("armed_ms={}", ms(armed)));

    let driving = wait_for(Duration::from_secs(3), Some(FORWARD), |seen| {
        turning(seen, DRIVING_RPM) >= 4
    })
    .await;
    // Keep flying a little, so the thrusters run at speed for a while.
    wait_for(Duration::from_secs(1), Some(FORWARD), |_| false).await;
    let rpm = station::seen(|seen| seen.rpm).await;
    tally.step(
        "fly-forward",
        driving.is_some(),
        format_args!(
            "driving_ms={} rpm={:?}",
            ms(driving),
            rpm.get(..MAX_THRUSTERS).unwrap_or_default()
        ),
    );

    // A glitch leaves a driving thruster holding SDA low in the middle of a byte: every transfer fails until the
    // master's recovery (the core's, on the bus's lines) clocks it free; then the thrusters drive on.
    let before = bus.counts();
    if let Some(thruster) = bus.thrusters().get(GLITCHED_THRUSTER) {
        bus.glitch_during_next_transfer(thruster, GLITCH_CLOCKS);
    }
    let freed = wait_for(Duration::from_secs(1), Some(FORWARD), |_| {
        bus.counts().bus_errors > before.bus_errors && !bus.sda_held()
    })
    .await;
    let after = bus.counts();
    let driving = wait_for(Duration::from_secs(1), Some(FORWARD), |seen| {
        turning(seen, DRIVING_RPM) >= 4
    })
    .await;
    tally.step(
        "stuck-sda",
        freed.is_some() && driving.is_some() && after.pin_stops > before.pin_stops,
        format_args!(
            "freed_ms={} bus_errors={} clocks={} stops={} driving_ms={}",
            ms(freed),
            after.bus_errors - before.bus_errors,
            after.pin_clocks - before.pin_clocks,
            after.pin_stops - before.pin_stops,
            ms(driving)
        ),
    );

    arm(false).await;
    let disarmed = wait_for(Duration::from_secs(1), None, |seen| accepted(seen) && !seen.armed).await;
    let stopped = wait_for(Duration::from_secs(2), None, |seen| turning(seen, STOPPED_RPM) == 0).await;
    tally.step(
        "disarm",
        disarmed.is_some() && stopped.is_some(),
        format_args!("disarmed_ms={} stopped_ms={}", ms(disarmed), ms(stopped)),
    );

    // The console failsafe: armed and flying, the station goes quiet; the vehicle disarms itself.
    arm(true).await;
    let rearmed = wait_for(Duration::from_secs(1), Some(FORWARD), |seen| {
        accepted(seen) && seen.armed
    })
    .await;
    wait_for(Duration::from_millis(500), Some(FORWARD), |_| false).await;
    let critical_before = station::seen(|seen| seen.critical_texts).await;
    station::change(|station| station.connected = false).await;
    // The ground-station failsafe acts FS_GCS_TIMEOUT after the last heartbeat (the pilot-input one, earlier, only
    // holds the sticks at neutral).
    let within = VEHICLE.vehicle.defaults().params.gcs_timeout() + Duration::from_secs(1);
    let failsafe = wait_for(within, None, |seen| {
        !seen.armed && seen.critical_texts > critical_before && turning(seen, STOPPED_RPM) == 0
    })
    .await;
    tally.step(
        "console-failsafe",
        rearmed.is_some() && failsafe.is_some(),
        format_args!("disarmed_and_stopped_ms={}", ms(failsafe)),
    );

    say!(
        "PILOT verdict={} passed={} failed={}",
        if tally.failed == 0 { "PASS" } else { "FAIL" },
        tally.passed,
        tally.failed
    );
    tally.failed == 0
}

/// The figures of the run, then the exit status.
fn finish(bus: &Bus, pass: bool, frames_read: u32) -> ! {
    let fed = report::bus(bus);
    let stats = CONSOLE_STATS.snapshot();
    say!(
        "CONSOLE frames in={} out={} bad={}; the pilot read {} frames",
        stats.frames_in,
        stats.frames_out,
        stats.bad_frames,
        frames_read
    );
    let fit = report::stacks(&[("master", Stack::Master), ("thruster", Stack::Thruster)]);
    let dispatch = report::cpu(
        &[&MASTER_METER, &thruster::THREAD_METER],
        &[&BENCH_METER],
        &[
            &thruster::COMMUTATION_METER,
            &executors::COMMUTATION_ISR_METER,
            &crate::time::ALARM_METER,
            &thruster::MOTOR_MODEL_METER,
            &i2c::BUS_MODEL_METER,
        ],
    );
    report::master_load(dispatch);
    report::exit(pass && fed && fit)
}
