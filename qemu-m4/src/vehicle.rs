//! The master's whole core on the chip, as the vehicle image runs it: thruster polling of an LBV300-6 (six
//! motor-less thruster cores behind a TCA9548A, on the same chip), the battery monitor fed by a BAT board that
//! sends the real firmware's frames, the MAVLink console, and the vehicle task. A scripted pilot on the console's
//! other end arms, flies forward, disarms, and lets the console failsafe disarm the vehicle, checking each answer.

use core::cell::RefCell;
use core::convert::Infallible;
use core::sync::atomic::{AtomicBool, AtomicU8, Ordering};

use bat_proto::{BatteryInfo, DcdcStatus, Frame};
use embassy_executor::Spawner;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_sync::pipe::Pipe;
use embassy_time::{Duration, Instant, Timer};
use lbv_master_fw::battery::{CanFrame, CanReceiver, can_task};
use lbv_master_fw::console::frame::{Event, FrameParser};
use lbv_master_fw::console::lbv::{
    COMMAND_LONG_DATA, HEARTBEAT_DATA, MANUAL_CONTROL_DATA, MavAutopilot, MavMessage, MavModeFlag, MavResult,
    MavSeverity, MavState, MavType,
};
use lbv_master_fw::console::{ConsoleConfig, ConsoleStats, console_rx_task, console_tx_task};
use lbv_master_fw::shared::{ManualInput, Shared};
use lbv_master_fw::thrusters::{PollConfig, ThrusterSlot, bus_task, check_table};
use lbv_master_fw::vehicle::{MAV_CMD_COMPONENT_ARM_DISARM, NEUTRAL, VehicleConfig, vehicle_task};
use mavlink_core::{MAVLinkV2MessageRaw, MavHeader, MavlinkVersion, Message, MessageData};
use static_cell::StaticCell;
use tmc_proto::Family;

use crate::executors::{self, BENCH_METER};
use crate::i2c::{Bus, ControllerPort, MAX_THRUSTERS};
use crate::meter::{Meter, metered};
use crate::stacks::Stack;
use crate::thruster::{self, HallInput, Thruster};
use crate::{report, say};

type Cs = CriticalSectionRawMutex;

/// The LBV300-6 as the master image's table has it: six SeaBotix thrusters on TCA9548A channels 0-5 of I2C2.
const BUS_INDEX: u8 = 1;
const TABLE: [ThrusterSlot; MAX_THRUSTERS] = [
    ThrusterSlot::behind_mux(BUS_INDEX, 0, Family::SeaBotix),
    ThrusterSlot::behind_mux(BUS_INDEX, 1, Family::SeaBotix),
    ThrusterSlot::behind_mux(BUS_INDEX, 2, Family::SeaBotix),
    ThrusterSlot::behind_mux(BUS_INDEX, 3, Family::SeaBotix),
    ThrusterSlot::behind_mux(BUS_INDEX, 4, Family::SeaBotix),
    ThrusterSlot::behind_mux(BUS_INDEX, 5, Family::SeaBotix),
];
const _: () = assert!(check_table(&TABLE).is_ok());

static SHARED: Shared = Shared::new();
static CONSOLE: ConsoleConfig = ConsoleConfig {
    thrusters: MAX_THRUSTERS as u8,
    ..ConsoleConfig::DEFAULT
};
static CONSOLE_STATS: ConsoleStats = ConsoleStats::new();
/// The console's serial link, each way (the ST-LINK virtual COM port on the board).
static UPLINK: Pipe<Cs, 512> = Pipe::new();
static DOWNLINK: Pipe<Cs, 1024> = Pipe::new();
/// The battery CAN bus.
static CAN: Channel<Cs, CanFrame, 8> = Channel::new();

static BUS_METER: Meter = Meter::task("master thruster bus task");
static BATTERY_METER: Meter = Meter::task("master battery (CAN) task");
static CONSOLE_RX_METER: Meter = Meter::task("master console rx task");
static CONSOLE_TX_METER: Meter = Meter::task("master console tx task");
static VEHICLE_METER: Meter = Meter::task("master vehicle task");

/// Start the master, its six thrusters, the BAT board and the pilot.
pub fn start(thread: Spawner) {
    let high = executors::start_commutation();
    let mut thrusters = heapless::Vec::<&'static Thruster, MAX_THRUSTERS>::new();
    for slot in TABLE {
        let thruster = Thruster::create(slot.family, slot.mux_channel);
        thruster.start(thread, high, HallInput::Model);
        let _ = thrusters.push(thruster);
    }
    static BUS: StaticCell<Bus> = StaticCell::new();
    let bus: &'static Bus = BUS.init(Bus::new(&thrusters, true));
    report::spawn(thread, poll_thrusters(bus));
    report::spawn(thread, battery());
    report::spawn(thread, console_rx());
    report::spawn(thread, console_tx());
    report::spawn(thread, vehicle());
    report::spawn(thread, bat_board());
    report::spawn(thread, ground_station_rx());
    report::spawn(thread, heartbeats());
    report::spawn(thread, pilot(bus));
}

// The master's tasks, one line each around the core's task functions, as in the STM32 binding
// (`lbv-master-fw/src/stm32.rs`), polled on the master's own stack.

#[embassy_executor::task]
async fn poll_thrusters(bus: &'static Bus) -> ! {
    let mut port = ControllerPort(bus);
    let task = bus_task(&mut port, BUS_INDEX, &TABLE, &PollConfig::DEFAULT, &SHARED);
    metered(&BUS_METER, Some(Stack::Master), task).await
}

#[embassy_executor::task]
async fn battery() -> ! {
    metered(&BATTERY_METER, Some(Stack::Master), can_task(&mut CanPort, &SHARED)).await
}

#[embassy_executor::task]
async fn console_rx() -> ! {
    let mut uplink = &UPLINK;
    let task = console_rx_task(&mut uplink, &CONSOLE, &SHARED, &CONSOLE_STATS);
    metered(&CONSOLE_RX_METER, Some(Stack::Master), task).await
}

#[embassy_executor::task]
async fn console_tx() -> ! {
    let mut downlink = &DOWNLINK;
    let task = console_tx_task(&mut downlink, &CONSOLE, &SHARED, &CONSOLE_STATS);
    metered(&CONSOLE_TX_METER, Some(Stack::Master), task).await
}

#[embassy_executor::task]
async fn vehicle() -> ! {
    let config = VehicleConfig {
        thrusters: MAX_THRUSTERS as u8,
        ..VehicleConfig::DEFAULT
    };
    metered(&VEHICLE_METER, Some(Stack::Master), vehicle_task(config, &SHARED)).await
}

/// The battery CAN bus, seen from the master.
struct CanPort;

impl CanReceiver for CanPort {
    type Error = Infallible;

    async fn receive(&mut self) -> Result<CanFrame, Infallible> {
        Ok(CAN.receive().await)
    }
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
            charge_percent: 80,
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

/// The ground station's MAVLink identity (QGroundControl's).
const GCS_SYSTEM: u8 = 255;
const GCS_COMPONENT: u8 = 190;
static SEQUENCE: AtomicU8 = AtomicU8::new(0);
/// The pilot's station sends its 1 Hz heartbeat while this is set.
static CONNECTED: AtomicBool = AtomicBool::new(true);

/// What the station has seen of the vehicle.
#[derive(Debug, Clone, Copy)]
struct Seen {
    heartbeats: u32,
    armed: bool,
    /// The last COMMAND_ACK: command, accepted.
    ack: Option<(u16, bool)>,
    critical_texts: u32,
    rpm: [u16; 8],
    polls: [u16; 8],
    battery_mv: u16,
    frames: u32,
}

static SEEN: Mutex<Cs, RefCell<Seen>> = Mutex::new(RefCell::new(Seen {
    heartbeats: 0,
    armed: false,
    ack: None,
    critical_texts: 0,
    rpm: [0; 8],
    polls: [0; 8],
    battery_mv: 0,
    frames: 0,
}));

fn seen() -> Seen {
    SEEN.lock(|seen| *seen.borrow())
}

/// Send one message to the vehicle.
async fn send<D: MessageData>(message: &D) {
    let mut raw = MAVLinkV2MessageRaw::new();
    let header = MavHeader {
        system_id: u32::from(GCS_SYSTEM),
        component_id: GCS_COMPONENT,
        sequence: SEQUENCE.fetch_add(1, Ordering::Relaxed),
    };
    raw.serialize_message_data(header, message);
    UPLINK.write_all(raw.raw_bytes()).await;
}

/// The station's heartbeat, 1 Hz while connected.
#[embassy_executor::task]
async fn heartbeats() -> ! {
    metered(&BENCH_METER, None, send_heartbeats()).await
}

async fn send_heartbeats() -> ! {
    loop {
        if CONNECTED.load(Ordering::Relaxed) {
            send(&HEARTBEAT_DATA {
                custom_mode: 0,
                mavtype: MavType::MAV_TYPE_GCS,
                autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
                base_mode: MavModeFlag::empty(),
                system_status: MavState::MAV_STATE_ACTIVE,
                mavlink_version: 3,
            })
            .await;
        }
        Timer::after(Duration::from_secs(1)).await;
    }
}

/// Read everything the vehicle sends.
#[embassy_executor::task]
async fn ground_station_rx() -> ! {
    metered(&BENCH_METER, None, read_downlink()).await
}

async fn read_downlink() -> ! {
    let mut parser = FrameParser::new();
    let mut buffer = [0u8; 128];
    loop {
        let n = DOWNLINK.read(&mut buffer).await;
        let mut bytes = buffer.get(..n).unwrap_or_default();
        while !bytes.is_empty() {
            let taken = parser.push(bytes);
            bytes = bytes.get(taken..).unwrap_or_default();
            while let Some(event) = parser.next(|id| Some(MavMessage::extra_crc(id))) {
                let Event::Frame(frame) = event else { continue };
                let Ok(message) = MavMessage::parse(MavlinkVersion::V2, frame.message_id, frame.payload) else {
                    continue;
                };
                SEEN.lock(|seen| take(&mut seen.borrow_mut(), message));
            }
        }
    }
}

/// Note one message.
fn take(seen: &mut Seen, message: MavMessage) {
    seen.frames += 1;
    match message {
        MavMessage::HEARTBEAT(heartbeat) => {
            seen.heartbeats += 1;
            seen.armed = heartbeat.base_mode.contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED);
        }
        MavMessage::COMMAND_ACK(ack) => seen.ack = Some((ack.command, ack.result == MavResult::MAV_RESULT_ACCEPTED)),
        MavMessage::STATUSTEXT(text) if text.severity == MavSeverity::MAV_SEVERITY_CRITICAL => seen.critical_texts += 1,
        MavMessage::ESC_TELEMETRY_1_TO_4(esc) => {
            seen.rpm.iter_mut().zip(esc.rpm).for_each(|(slot, rpm)| *slot = rpm);
            seen.polls
                .iter_mut()
                .zip(esc.count)
                .for_each(|(slot, count)| *slot = count);
        }
        MavMessage::ESC_TELEMETRY_5_TO_8(esc) => {
            seen.rpm
                .iter_mut()
                .skip(4)
                .zip(esc.rpm)
                .for_each(|(slot, rpm)| *slot = rpm);
            seen.polls
                .iter_mut()
                .skip(4)
                .zip(esc.count)
                .for_each(|(slot, count)| *slot = count);
        }
        MavMessage::SYS_STATUS(status) => seen.battery_mv = status.voltage_battery,
        _ => {}
    }
}

/// How often the pilot looks at what came in, and sends the sticks while flying (10 Hz, as QGroundControl).
const LOOK: Duration = Duration::from_millis(10);
const STICK_PERIOD: Duration = Duration::from_millis(100);

/// Wait up to `within` for `condition` on what the station has seen, sending `sticks` every 100 ms meanwhile;
/// how long it took.
async fn wait_for(
    within: Duration,
    sticks: Option<ManualInput>,
    condition: impl Fn(&Seen) -> bool,
) -> Option<Duration> {
    let start = Instant::now();
    let mut next_stick = start;
    loop {
        if condition(&seen()) {
            return Some(start.elapsed());
        }
        if start.elapsed() >= within {
            return None;
        }
        if let Some(sticks) = sticks
            && Instant::now() >= next_stick
        {
            next_stick += STICK_PERIOD;
            send(&MANUAL_CONTROL_DATA {
                x: sticks.x,
                y: sticks.y,
                z: sticks.z,
                r: sticks.r,
                buttons: 0,
                target: 1,
                ..Default::default()
            })
            .await;
        }
        Timer::after(LOOK).await;
    }
}

/// MAV_CMD_COMPONENT_ARM_DISARM.
async fn arm(arm: bool) {
    SEEN.lock(|seen| seen.borrow_mut().ack = None);
    send(&COMMAND_LONG_DATA {
        param1: if arm { 1.0 } else { 0.0 },
        command: MAV_CMD_COMPONENT_ARM_DISARM,
        target_system: 1,
        target_component: 1,
        ..Default::default()
    })
    .await;
}

fn accepted(seen: &Seen) -> bool {
    seen.ack == Some((MAV_CMD_COMPONENT_ARM_DISARM, true))
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
/// A thruster counts as driving above this speed, as stopped below the other.
const DRIVING_RPM: u16 = 500;
const STOPPED_RPM: u16 = 50;

/// The pilot's session, then the figures.
#[embassy_executor::task]
async fn pilot(bus: &'static Bus) {
    let pass = metered(&BENCH_METER, None, fly()).await;
    finish(bus, pass);
}

/// The pilot's steps; whether all passed.
async fn fly() -> bool {
    let mut tally = Tally::default();

    let link = wait_for(Duration::from_secs(3), None, |seen| seen.heartbeats > 0).await;
    tally.step("link", link.is_some(), format_args!("heartbeat_ms={}", ms(link)));

    let polled = wait_for(Duration::from_secs(3), None, |seen| {
        seen.polls.iter().take(MAX_THRUSTERS).all(|count| *count > 0)
    })
    .await;
    let polls = seen().polls;
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
    tally.step(
        "battery",
        battery.is_some(),
        format_args!("voltage_mv={} expected_mv={expected_mv}", seen().battery_mv),
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
    let rpm = seen().rpm;
    tally.step(
        "fly-forward",
        driving.is_some(),
        format_args!(
            "driving_ms={} rpm={:?}",
            ms(driving),
            rpm.get(..MAX_THRUSTERS).unwrap_or_default()
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
    let critical_before = seen().critical_texts;
    CONNECTED.store(false, Ordering::Relaxed);
    let failsafe = wait_for(Duration::from_secs(3), None, |seen| {
        !seen.armed && seen.critical_texts > critical_before && turning(seen, STOPPED_RPM) == 0
    })
    .await;
    CONNECTED.store(true, Ordering::Relaxed);
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
fn finish(bus: &Bus, pass: bool) -> ! {
    let fed = report::bus(bus);
    let stats = CONSOLE_STATS.snapshot();
    say!(
        "CONSOLE frames in={} out={} bad={}; the pilot read {} frames",
        stats.frames_in,
        stats.frames_out,
        stats.bad_frames,
        seen().frames
    );
    let fit = report::stacks(&[("master", Stack::Master), ("thruster", Stack::Thruster)]);
    let master = [
        &BUS_METER,
        &BATTERY_METER,
        &CONSOLE_RX_METER,
        &CONSOLE_TX_METER,
        &VEHICLE_METER,
    ];
    let thrusters = [
        &thruster::FAULT_METER,
        &thruster::CONTROL_METER,
        &thruster::I2C_METER,
        &thruster::HEALTH_METER,
    ];
    let thread: heapless::Vec<&Meter, 10> = master
        .iter()
        .chain(&thrusters)
        .copied()
        .chain([&executors::BENCH_METER])
        .collect();
    let dispatch = report::cpu(
        &thread,
        &[
            &thruster::COMMUTATION_METER,
            &executors::COMMUTATION_ISR_METER,
            &crate::time::ALARM_METER,
            &thruster::MOTOR_MODEL_METER,
        ],
    );
    report::master_load(&master, dispatch);
    report::exit(pass && fed && fit)
}
