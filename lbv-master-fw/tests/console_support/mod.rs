//! Shared by the console tests: a scripted serial receive side, runners for the two console tasks, frame builders
//! and a reader that uses the mavlink crate's own parser. The clock and the capture port are lbv-sim's.
#![allow(dead_code)]

use std::cell::Cell;
use std::convert::Infallible;
use std::rc::Rc;

use embassy_futures::block_on;
use embassy_futures::select::select;
use embassy_futures::yield_now;
use embassy_time::Duration;
use lbv_master_fw::console::lbv::MavMessage;
use lbv_master_fw::console::{ConsoleConfig, ConsoleCounters, ConsoleStats, console_rx_task, console_tx_task};
use lbv_master_fw::shared::{Command, Shared};
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
        let n = self.chunk.min(buf.len()).min(self.data.len() - self.pos);
        buf[..n].copy_from_slice(&self.data[self.pos..self.pos + n]);
        self.pos += n;
        // Let the other side run between chunks, as a UART would.
        yield_now().await;
        Ok(n)
    }
}

/// Feed `bytes` to a console receive task in chunks of `chunk`; returns the commands it produced, in order, and
/// its counters.
pub fn run_rx(bytes: &[u8], chunk: usize, config: &ConsoleConfig) -> (Vec<Command>, ConsoleCounters) {
    let shared = Shared::new();
    let stats = ConsoleStats::new();
    let mut rx = ScriptedRx::new(bytes.to_vec(), chunk);
    let idle = rx.idle.clone();
    let mut commands = vec![];
    block_on(select(console_rx_task(&mut rx, config, &shared, &stats), async {
        loop {
            while let Ok(command) = shared.commands.try_receive() {
                commands.push(command);
            }
            if idle.get() {
                break;
            }
            yield_now().await;
        }
    }));
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
