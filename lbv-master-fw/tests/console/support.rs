//! Shared by the console tests: a scripted serial receive side, runners for the two console tasks, frame builders
//! and a reader that uses the mavlink crate's own parser. The clock and the capture port are lbv-sim's.
#![allow(dead_code)]

use std::cell::Cell;
use std::collections::VecDeque;
use std::convert::Infallible;
use std::rc::Rc;

use embassy_futures::block_on;
use embassy_futures::join::join4;
use embassy_futures::select::select;
use embassy_futures::yield_now;
use embassy_time::{Duration, Instant};
use lbv_master_fw::console::lbv::MavMessage;
use lbv_master_fw::console::signing::reservation_after;
use lbv_master_fw::console::{ConsoleConfig, ConsoleCounters, ConsoleStats, console_rx_task, console_tx_task};
use lbv_master_fw::params::Settings;
use lbv_master_fw::ports::Reboot;
use lbv_master_fw::settings::{InRam, settings_task};
use lbv_master_fw::shared::{Command, Request, Shared};
use lbv_master_fw::vehicle::{VehicleConfig, vehicle_task};
use mavlink_core::{MAVLinkV1MessageRaw, MAVLinkV2MessageRaw, MavHeader, MavlinkReader, MessageData};

/// The virtual clock is one per process: tests that move it take it (at 0).
pub fn clock() -> lbv_sim::Clock {
    lbv_sim::clock::take()
}

/// A serial port's transmit side that records every byte written (`take` returns them).
pub use lbv_sim::SerialTx as Capture;

/// A serial port's receive side that delivers `data` in chunks of `chunk` bytes, then waits forever; `idle`
/// turns true once everything was read.
pub struct ScriptedRx {
    data: Vec<u8>,
    pos: usize,
    chunk: usize,
    pub idle: Rc<Cell<bool>>,
}

impl ScriptedRx {
    pub fn new(data: Vec<u8>, chunk: usize) -> Self {
        Self {
            data,
            pos: 0,
            chunk: chunk.max(1),
            idle: Rc::default(),
        }
    }
}

impl embedded_io_async::ErrorType for ScriptedRx {
    type Error = Infallible;
}

impl embedded_io_async::Read for ScriptedRx {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        if self.pos >= self.data.len() {
            self.idle.set(true);
            core::future::pending::<()>().await;
        }
        // Let the other side run between chunks, as a UART would (before taking the bytes: a read may be dropped
        // while it waits, and a UART loses nothing then).
        yield_now().await;
        let n = self.chunk.min(buf.len()).min(self.data.len() - self.pos);
        buf[..n].copy_from_slice(&self.data[self.pos..self.pos + n]);
        self.pos += n;
        Ok(n)
    }
}

/// Feed `bytes` to a console receive task in chunks of `chunk`; returns the commands it produced, in order, and
/// its counters.
pub fn run_rx(bytes: &[u8], chunk: usize, config: &ConsoleConfig) -> (Vec<Command>, ConsoleCounters) {
    let (requests, counters) = run_rx_requests(bytes, chunk, config, &Shared::new());
    (requests.into_iter().map(|request| request.command).collect(), counters)
}

/// As [`run_rx`], with the requests (who sent what), and the settings in force in `shared`.
pub fn run_rx_requests(
    bytes: &[u8],
    chunk: usize,
    config: &ConsoleConfig,
    shared: &Shared,
) -> (Vec<Request>, ConsoleCounters) {
    let stats = ConsoleStats::new();
    let mut rx = ScriptedRx::new(bytes.to_vec(), chunk);
    let idle = rx.idle.clone();
    let mut commands = vec![];
    block_on(select(
        console_rx_task(
            &mut rx,
            config,
            shared,
            &stats,
            &lbv_master_fw::config::VEHICLE.thrusters,
            lbv_master_fw::mixer::FrameKind::Lbv300_6,
            lbv_master_fw::update::CheckOnly,
        ),
        async {
            loop {
                while let Ok(command) = shared.commands.try_receive() {
                    commands.push(command);
                }
                if idle.get() {
                    break;
                }
                yield_now().await;
            }
        },
    ));
    (commands, stats.snapshot())
}

/// The tx task's output after running it for `run_for` of virtual time, moved in steps of 10 ms, with `before`
/// called before each step (to queue messages, change the state).
pub fn run_tx(
    config: &ConsoleConfig,
    shared: &Shared,
    stats: &ConsoleStats,
    run_for: Duration,
    mut before: impl FnMut(Duration),
) -> Vec<u8> {
    let capture = Capture::default();
    let mut tx = capture.clone();
    let step = Duration::from_millis(10);
    block_on(select(console_tx_task(&mut tx, config, shared, stats), async {
        let mut elapsed = Duration::from_ticks(0);
        while elapsed <= run_for {
            before(elapsed);
            // Let the task send whatever is due now, then move the clock.
            for _ in 0..4 {
                yield_now().await;
            }
            lbv_sim::clock::advance(step);
            elapsed += step;
        }
    }));
    capture.take()
}

/// A MAVLink 2 frame of `message` from `system`/`component`, built by the mavlink crate.
pub fn v2<D: MessageData>(system: u8, component: u8, sequence: u8, message: &D) -> Vec<u8> {
    let mut raw = MAVLinkV2MessageRaw::new();
    let header = MavHeader {
        system_id: u32::from(system),
        component_id: component,
        sequence,
    };
    raw.serialize_message_data(header, message);
    raw.raw_bytes().to_vec()
}

/// A MAVLink 1 frame of `message`, built by the mavlink crate.
pub fn v1<D: MessageData>(system: u8, component: u8, sequence: u8, message: &D) -> Vec<u8> {
    let mut raw = MAVLinkV1MessageRaw::new();
    let header = MavHeader {
        system_id: u32::from(system),
        component_id: component,
        sequence,
    };
    raw.serialize_message_data(header, message);
    raw.raw_bytes().to_vec()
}

/// Every frame in `bytes`, parsed by the mavlink crate's own reader (MAVLink 2 only).
pub fn parse_all(bytes: &[u8]) -> Vec<(MavHeader, MavMessage)> {
    let mut reader = MavlinkReader::new(bytes);
    let mut out = vec![];
    while let Ok(frame) = reader.read_message::<MavMessage>(mavlink_core::MavlinkVersion::V2) {
        out.push(frame);
    }
    out
}

/// Message ids of `frames`, in order.
pub fn ids(frames: &[(MavHeader, MavMessage)]) -> Vec<u32> {
    use mavlink_core::Message;
    frames.iter().map(|(_, m)| m.message_id()).collect()
}

/// A serial line on the virtual clock: each burst of bytes arrives at its time (a ground station writes a frame
/// at once), and nothing between them.
pub struct Line(pub VecDeque<(Instant, Vec<u8>)>);

impl Line {
    /// Bursts at the given milliseconds, in time order.
    pub fn new(mut bursts: Vec<(u64, Vec<u8>)>) -> Self {
        bursts.sort_by_key(|(ms, _)| *ms);
        Self(
            bursts
                .into_iter()
                .map(|(ms, bytes)| (Instant::from_millis(ms), bytes))
                .collect(),
        )
    }
}

impl embedded_io_async::ErrorType for Line {
    type Error = Infallible;
}

impl embedded_io_async::Read for Line {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        loop {
            match self.0.front_mut() {
                Some((at, bytes)) if *at <= Instant::now() => {
                    let n = bytes.len().min(buf.len());
                    buf[..n].copy_from_slice(&bytes[..n]);
                    bytes.drain(..n);
                    if bytes.is_empty() {
                        self.0.pop_front();
                    }
                    return Ok(n);
                }
                _ => yield_now().await,
            }
        }
    }
}

/// Publish `settings` as [`lbv_master_fw::run`] does at a start: with a signing key, a reservation past its
/// timestamp is in flash.
pub fn publish(shared: &Shared, settings: Settings) {
    if let Some(key) = settings.signing {
        shared.signing_stored.sender().send(reservation_after(key.timestamp));
    }
    shared.settings.sender().send(settings);
}

/// A restart that never comes (the tests that run the settings task do not reboot).
pub struct NoReboot;

impl Reboot for NoReboot {
    async fn reboot(&mut self) -> ! {
        core::future::pending().await
    }
}

/// The console and the vehicle on the virtual clock, which this takes (at 0) for the run: the receive, transmit and
/// vehicle tasks (and the settings task, on settings kept in RAM), with `line` as the console's input, run for
/// `run_for` in 1 ms steps; `each_ms` sees the shared state after every step. Returns what the console sent.
pub fn run_console(
    settings: Settings,
    line: Line,
    run_for: Duration,
    mut each_ms: impl FnMut(Instant, &Shared, &ConsoleStats),
) -> Vec<u8> {
    let clock = clock();
    let shared = Shared::new();
    let stats = ConsoleStats::new();
    let capture = Capture::default();
    let mut tx = capture.clone();
    let mut rx = line;
    let config = ConsoleConfig::DEFAULT;
    publish(&shared, settings);
    let (mut store, mut reboot) = (InRam, NoReboot);
    let tasks = join4(
        console_rx_task(
            &mut rx,
            &config,
            &shared,
            &stats,
            &lbv_master_fw::config::VEHICLE.thrusters,
            lbv_master_fw::mixer::FrameKind::Lbv300_6,
            lbv_master_fw::update::CheckOnly,
        ),
        console_tx_task(&mut tx, &config, &shared, &stats),
        vehicle_task(VehicleConfig::DEFAULT, settings, &shared),
        settings_task(&mut store, &shared, &mut reboot),
    );
    block_on(select(tasks, async {
        let end = Instant::now() + run_for;
        while Instant::now() < end {
            for _ in 0..8 {
                yield_now().await;
            }
            each_ms(Instant::now(), &shared, &stats);
            clock.advance(Duration::from_millis(1));
        }
    }));
    capture.take()
}
