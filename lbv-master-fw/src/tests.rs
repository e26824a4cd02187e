//! The whole master on virtual time: a pilot's session built by pymavlink goes in on the console, six simulated
//! thrusters sit behind a TCA9548A on a 100 kbit/s bus, and pymavlink reads what the master sends back.

use core::cell::RefCell;
use core::convert::Infallible;
use std::collections::VecDeque;
use std::process::{Command as Process, Stdio};
use std::rc::Rc;

use embassy_futures::block_on;
use embassy_futures::join::join5;
use embassy_futures::select::{Either, select};
use embassy_futures::yield_now;
use embassy_time::{Duration, Instant, MockDriver};
use serde_json::Value;
use tmc_proto::Family;

use crate::battery::{CanFrame, CanReceiver, can_task};
use crate::console::{ConsoleConfig, ConsoleStats, console_rx_task, console_tx_task};
use crate::shared::{MAX_THRUSTERS, Shared};
use crate::thrusters::sim::{SimBus, SimThruster, World};
use crate::thrusters::{PollConfig, ThrusterSlot, bus_task};
use crate::vehicle::{VehicleConfig, vehicle_task};

/// Run the project's pymavlink peer (`tests/mav_peer.py`).
fn mav_peer(command: &str, input: &str) -> Value {
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/mav_peer.py");
    let mut child = Process::new("python3")
        .args([script, command])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("python3 runs");
    std::io::Write::write_all(child.stdin.as_mut().expect("stdin"), input.as_bytes()).expect("write to python");
    let output = child.wait_with_output().expect("python3 finishes");
    assert!(
        output.status.success(),
        "mav_peer.py {command} failed: pymavlink missing? (pip install pymavlink)"
    );
    serde_json::from_slice(&output.stdout).expect("mav_peer.py prints JSON")
}

fn unhex(hex: &str) -> Vec<u8> {
    (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).expect("hex"))
        .collect()
}

/// The console's receive side: each frame arrives at its time.
struct TimedRx(VecDeque<(Instant, Vec<u8>)>);

impl embedded_io_async::ErrorType for TimedRx {
    type Error = Infallible;
}

impl embedded_io_async::Read for TimedRx {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        loop {
            match self.0.front_mut() {
                Some((at, frame)) if *at <= Instant::now() => {
                    let n = frame.len().min(buf.len());
                    buf[..n].copy_from_slice(&frame[..n]);
                    frame.drain(..n);
                    if frame.is_empty() {
                        self.0.pop_front();
                    }
                    return Ok(n);
                }
                _ => yield_now().await,
            }
        }
    }
}

/// The console's transmit side.
#[derive(Clone, Default)]
struct Capture(Rc<RefCell<Vec<u8>>>);

impl embedded_io_async::ErrorType for Capture {
    type Error = Infallible;
}

impl embedded_io_async::Write for Capture {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        self.0.borrow_mut().extend_from_slice(buf);
        Ok(buf.len())
    }

    async fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}

/// A CAN bus with no battery board on it.
struct QuietCan;

impl CanReceiver for QuietCan {
    type Error = Infallible;

    async fn receive(&mut self) -> Result<CanFrame, Infallible> {
        core::future::pending().await
    }
}

#[test]
fn a_pymavlink_pilot_arms_drives_and_disarms_the_vehicle() {
    let _clock = crate::test_clock::lock();
    let session = mav_peer("session", "");
    let frames: VecDeque<(Instant, Vec<u8>)> = session
        .as_array()
        .expect("a list")
        .iter()
        .map(|event| {
            let at = Instant::from_millis(event[0].as_u64().expect("time"));
            (at, unhex(event[2].as_str().expect("hex")))
        })
        .collect();
    let sticks: Vec<Instant> = session
        .as_array()
        .expect("a list")
        .iter()
        .filter(|event| event[1] == "manual")
        .filter_map(|event| event[0].as_u64().map(Instant::from_millis))
        .collect();

    let table: Vec<ThrusterSlot> = (0..6)
        .map(|channel| ThrusterSlot::behind_mux(0, channel, Family::SeaBotix))
        .collect();
    let world = RefCell::new(World::with(
        (0..6)
            .map(|channel| SimThruster::new(Family::SeaBotix, Some(channel)))
            .collect(),
    ));
    let shared = Shared::new();
    let stats = ConsoleStats::new();
    let capture = Capture::default();
    let mut rx = TimedRx(frames);
    let mut tx = capture.clone();
    let mut bus = SimBus(&world);
    let mut can = QuietCan;
    // When thruster 1's order changed on the wire.
    let mut changes: Vec<Instant> = Vec::new();

    let tasks = join5(
        console_rx_task(&mut rx, &ConsoleConfig::DEFAULT, &shared, &stats),
        console_tx_task(&mut tx, &ConsoleConfig::DEFAULT, &shared, &stats),
        vehicle_task(VehicleConfig::DEFAULT, VehicleConfig::DEFAULT.defaults(), &shared),
        bus_task(&mut bus, 0, &table, &PollConfig::DEFAULT, &shared),
        can_task(&mut can, &shared),
    );
    let mut last_order = tmc_proto::Order::STOP;
    let script = async {
        let end = Instant::from_secs(3) + Duration::from_millis(200);
        while Instant::now() < end {
            MockDriver::get().advance(Duration::from_micros(100));
            for _ in 0..8 {
                yield_now().await;
            }
            let order = world.borrow().thrusters[0].link.order();
            if order != last_order {
                last_order = order;
                changes.push(Instant::now());
            }
        }
    };
    match block_on(select(tasks, script)) {
        Either::First(_) => unreachable!("the tasks never end"),
        Either::Second(()) => {}
    }

    // Console to wire: each stick frame's new order reaches thruster 1 on its next poll (50 Hz, so within 20 ms
    // plus the transfer).
    let latencies: Vec<Duration> = sticks
        .iter()
        .map(|stick| {
            *changes
                .iter()
                .find(|change| **change >= *stick)
                .expect("every stick frame moved thruster 1")
                - *stick
        })
        .collect();
    let (shortest, longest) = (latencies.iter().min().copied(), latencies.iter().max().copied());
    let mean = latencies.iter().map(|latency| latency.as_micros()).sum::<u64>() / latencies.len() as u64;
    println!(
        "console-to-wire latency over {} stick frames: min {} us, mean {mean} us, max {} us",
        latencies.len(),
        shortest.map_or(0, |d| d.as_micros()),
        longest.map_or(0, |d| d.as_micros())
    );
    assert!(
        longest.is_some_and(|longest| longest <= Duration::from_millis(21)),
        "latencies {latencies:?}"
    );
    assert!(
        world.borrow().thrusters.iter().all(|t| t.link.order().speed.is_zero()),
        "stopped after disarm"
    );

    let sent: String = capture.0.borrow().iter().map(|byte| format!("{byte:02x}")).collect();
    let messages = mav_peer("decode", &sent);
    let messages = messages.as_array().expect("a list");
    let of = |kind: &'static str| messages.iter().filter(move |m| m["_type"] == kind);

    let acks: Vec<_> = of("COMMAND_ACK")
        .map(|m| (m["command"].as_u64(), m["result"].as_u64()))
        .collect();
    assert_eq!(
        acks,
        [(Some(400), Some(0)), (Some(400), Some(0))],
        "arm and disarm accepted"
    );
    const ARMED: u64 = 128;
    let armed: Vec<bool> = of("HEARTBEAT")
        .map(|m| m["base_mode"].as_u64().unwrap_or(0) & ARMED != 0)
        .collect();
    assert!(armed.contains(&true), "a heartbeat says armed");
    assert_eq!(armed.last(), Some(&false), "the last heartbeat says disarmed");
    assert!(of("HEARTBEAT").all(|m| m["type"] == 12), "a submarine");
    // Forward stick: the four horizontal thrusters turn, and the ESC telemetry shows it.
    let peak_rpm = of("ESC_TELEMETRY_1_TO_4")
        .filter_map(|m| {
            m["rpm"]
                .as_array()
                .map(|rpm| rpm.iter().filter_map(Value::as_u64).min().unwrap_or(0))
        })
        .max()
        .unwrap_or(0);
    assert!(peak_rpm > 0, "thruster telemetry moved");
    let texts: Vec<&str> = of("STATUSTEXT").filter_map(|m| m["text"].as_str()).collect();
    assert!(
        texts.iter().any(|text| text.starts_with("T1 online")),
        "link texts: {texts:?}"
    );
    assert_eq!(MAX_THRUSTERS, 8);
}
