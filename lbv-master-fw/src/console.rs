//! The operator console: MAVLink 2 on LPUART1 (the ST-LINK virtual COM port), for QGroundControl and pymavlink
//! scripts.
//!
//! - [`console_rx_task`] reads frames (MAVLink 2, and MAVLink 1 too), decodes the few messages the master
//!   understands and hands them to the vehicle task as [`Command`](crate::shared::Command)s (mapping in
//!   [`inbound::decode`]).
//! - [`console_tx_task`] sends the telemetry an ArduSub ground station displays (HEARTBEAT, SYS_STATUS,
//!   BATTERY_STATUS at 1 Hz, ESC_TELEMETRY at 4 Hz) and every message the other tasks queue in
//!   [`Shared::outbox`] (COMMAND_ACK, PARAM_VALUE, STATUSTEXT) as soon as it is queued.
//!
//! The dialect ([`lbv`]) is generated at build time from `mavlink/lbv.xml`, which holds only the messages used,
//! copied from the official definitions; messages are encoded and decoded one type at a time, so the image
//! carries only their codecs. Both tasks keep their counters in a [`ConsoleStats`] they share.

use core::sync::atomic::{AtomicU16, AtomicU32, Ordering};

use embassy_futures::select::{Either, select};
use embassy_time::{Duration, Ticker, Timer};
use embedded_io_async::{Read, Write};
use mavlink_core::MessageData;

use crate::shared::{MAX_THRUSTERS, Outgoing, Shared};

pub mod frame;
pub mod inbound;
pub mod outbound;

include!(concat!(env!("OUT_DIR"), "/lbv_dialect.rs"));

use frame::{Event, FrameParser, Reject};
use outbound::{Framer, LinkQuality, Reports};

/// ESC telemetry period (4 Hz); HEARTBEAT, SYS_STATUS and BATTERY_STATUS go every fourth period (1 Hz).
pub const TELEMETRY_PERIOD: Duration = Duration::from_millis(250);
/// Telemetry periods per 1 Hz message set.
const SLOW_EVERY: u8 = 4;
/// Pause after a read error or end of input, so a failing port cannot monopolise the executor.
const READ_RETRY: Duration = Duration::from_millis(10);

/// Console settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct ConsoleConfig {
    /// Our MAVLink system id.
    pub system_id: u8,
    /// Our MAVLink component id.
    pub component_id: u8,
    /// How many thrusters are configured (at most [`MAX_THRUSTERS`]; more are ignored).
    pub thrusters: u8,
}

impl ConsoleConfig {
    /// System 1, component 1 (MAV_COMP_ID_AUTOPILOT1), 6 thrusters (the LBV300).
    pub const DEFAULT: ConsoleConfig = ConsoleConfig {
        system_id: 1,
        component_id: 1,
        thrusters: 6,
    };

    /// The configured thrusters, capped at [`MAX_THRUSTERS`].
    pub fn thruster_count(&self) -> usize {
        usize::from(self.thrusters).min(MAX_THRUSTERS)
    }
}

impl Default for ConsoleConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Counters of the console link, shared by the two tasks (atomics, so both take it by reference); read them
/// with [`ConsoleStats::snapshot`]. Counters wrap.
///
/// It also remembers who sent the last COMMAND_LONG, so its COMMAND_ACK is addressed back to that sender.
#[derive(Debug, Default)]
pub struct ConsoleStats {
    frames_in: AtomicU32,
    bad_frames: AtomicU32,
    unknown_messages: AtomicU32,
    skipped_bytes: AtomicU32,
    read_errors: AtomicU32,
    frames_out: AtomicU32,
    write_errors: AtomicU32,
    commander: AtomicU16,
}

/// A copy of the console counters.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct ConsoleCounters {
    /// CRC-valid frames of messages of the dialect whose payload decoded (whether or not they were for us).
    pub frames_in: u32,
    /// Frames dropped: CRC mismatch (a truncated frame shows as one), unknown message id, unsupported MAVLink 2
    /// incompatibility flag, or a payload that does not decode.
    pub bad_frames: u32,
    /// Of `bad_frames`, the well-framed messages with an id outside the dialect (a ground station sends many
    /// the master has no use for); they are not counted as link errors in SYS_STATUS.
    pub unknown_messages: u32,
    /// Bytes dropped while looking for a frame start.
    pub skipped_bytes: u32,
    /// Errors reported by the serial port (overrun, framing, noise).
    pub read_errors: u32,
    /// Frames written.
    pub frames_out: u32,
    /// Frames the serial port failed to write.
    pub write_errors: u32,
}

impl ConsoleCounters {
    /// Frames received damaged: bad frames other than unknown messages.
    pub fn corrupt(&self) -> u32 {
        self.bad_frames.wrapping_sub(self.unknown_messages)
    }
}

impl ConsoleStats {
    /// All zero.
    pub const fn new() -> Self {
        Self {
            frames_in: AtomicU32::new(0),
            bad_frames: AtomicU32::new(0),
            unknown_messages: AtomicU32::new(0),
            skipped_bytes: AtomicU32::new(0),
            read_errors: AtomicU32::new(0),
            frames_out: AtomicU32::new(0),
            write_errors: AtomicU32::new(0),
            commander: AtomicU16::new(0),
        }
    }

    /// The counters now.
    pub fn snapshot(&self) -> ConsoleCounters {
        ConsoleCounters {
            frames_in: self.frames_in.load(Ordering::Relaxed),
            bad_frames: self.bad_frames.load(Ordering::Relaxed),
            unknown_messages: self.unknown_messages.load(Ordering::Relaxed),
            skipped_bytes: self.skipped_bytes.load(Ordering::Relaxed),
            read_errors: self.read_errors.load(Ordering::Relaxed),
            frames_out: self.frames_out.load(Ordering::Relaxed),
            write_errors: self.write_errors.load(Ordering::Relaxed),
        }
    }

    /// System and component of the last COMMAND_LONG's sender (0, 0 before any).
    pub fn commander(&self) -> (u8, u8) {
        let [system, component] = self.commander.load(Ordering::Relaxed).to_be_bytes();
        (system, component)
    }

    fn count(counter: &AtomicU32, n: u32) {
        if n > 0 {
            counter.fetch_add(n, Ordering::Relaxed);
        }
    }
}

/// Read MAVLink frames from `rx`, decode them and send the [`Command`](crate::shared::Command)s to
/// `shared.commands`, awaiting room (the vehicle task drains it).
///
/// Bad bytes and frames are counted in `stats` and skipped; the parser resynchronises on the next start byte
/// (0xFD, or 0xFE for MAVLink 1) and never panics. Frames from any system are read; only messages addressed to
/// our system (target 0 or ours, where the message has a target) are acted on. A read error is counted and
/// reading resumes after a short pause.
pub async fn console_rx_task<R: Read>(rx: &mut R, config: &ConsoleConfig, shared: &Shared, stats: &ConsoleStats) -> ! {
    let mut parser = FrameParser::new();
    let mut chunk = [0u8; 64];
    loop {
        let received = match rx.read(&mut chunk).await {
            Ok(0) => {
                Timer::after(READ_RETRY).await;
                continue;
            }
            Ok(n) => chunk.get(..n).unwrap_or_default(),
            Err(_) => {
                ConsoleStats::count(&stats.read_errors, 1);
                Timer::after(READ_RETRY).await;
                continue;
            }
        };
        let mut rest = received;
        while !rest.is_empty() {
            let taken = parser.push(rest);
            rest = rest.get(taken..).unwrap_or_default();
            loop {
                let inbound = match parser.next(inbound::extra_crc) {
                    None => break,
                    Some(Event::Frame(frame)) => match inbound::decode(&frame, config) {
                        Ok(inbound) => {
                            ConsoleStats::count(&stats.frames_in, 1);
                            inbound
                        }
                        Err(_) => {
                            ConsoleStats::count(&stats.bad_frames, 1);
                            None
                        }
                    },
                    Some(Event::Rejected(reject)) => {
                        ConsoleStats::count(&stats.bad_frames, 1);
                        if let Reject::UnknownMessage(_) = reject {
                            ConsoleStats::count(&stats.unknown_messages, 1);
                        }
                        None
                    }
                };
                if let Some(inbound) = inbound {
                    if let Some((system, component)) = inbound.commander {
                        stats
                            .commander
                            .store(u16::from_be_bytes([system, component]), Ordering::Relaxed);
                    }
                    shared.commands.send(inbound.command).await;
                }
            }
            ConsoleStats::count(&stats.skipped_bytes, parser.take_skipped());
        }
    }
}

/// Send telemetry to `tx`: HEARTBEAT, SYS_STATUS and BATTERY_STATUS at 1 Hz (the first set at once),
/// ESC_TELEMETRY_1_TO_4 (and ESC_TELEMETRY_5_TO_8 when more than 4 thrusters are configured) at 4 Hz, and every
/// [`Shared::outbox`] message as soon as it is queued. MAVLink 2 frames from `config`'s system and component;
/// the sequence number counts every frame. Write errors are counted in `stats` and the frame is dropped.
///
/// SYS_STATUS's drop_rate_comm is the share of corrupt frames received during the last second (see
/// [`ConsoleCounters::corrupt`]).
pub async fn console_tx_task<W: Write>(tx: &mut W, config: &ConsoleConfig, shared: &Shared, stats: &ConsoleStats) -> ! {
    let mut out = Output {
        tx,
        framer: Framer::new(config.system_id, config.component_id),
        stats,
        batch: [0; BATCH],
        len: 0,
        frames: 0,
    };
    let thrusters = config.thruster_count();
    let mut ticker = Ticker::every(TELEMETRY_PERIOD);
    let mut tick: u8 = 0;
    let mut last = stats.snapshot();
    loop {
        let reports: Reports = core::array::from_fn(|i| {
            shared
                .thrusters
                .get(i)
                .filter(|_| i < thrusters)
                .and_then(|w| w.try_get())
        });
        if tick == 0 {
            let battery = shared.battery.try_get();
            let now = stats.snapshot();
            let link = link_quality(&last, &now);
            last = now;
            out.push(&outbound::heartbeat(shared.vehicle.try_get()));
            out.push(&outbound::sys_status(thrusters, &reports, battery.as_ref(), link));
            out.push(&outbound::battery_status(battery.as_ref()));
        }
        out.push(&outbound::esc_telemetry_1_to_4(thrusters, &reports));
        if thrusters > 4 {
            out.push(&outbound::esc_telemetry_5_to_8(thrusters, &reports));
        }
        out.flush().await;
        tick = (tick + 1) % SLOW_EVERY;

        while let Either::Second(message) = select(ticker.next(), shared.outbox.receive()).await {
            match message {
                Outgoing::CommandAck { command, result } => {
                    out.push(&outbound::command_ack(command, result, stats.commander()))
                }
                Outgoing::ParamValue {
                    id,
                    value,
                    index,
                    count,
                } => out.push(&outbound::param_value(&id, value, index, count)),
                Outgoing::Text(severity, text) => out.push(&outbound::statustext(severity, &text)),
            }
            out.flush().await;
        }
    }
}

/// Link quality between two snapshots of the counters.
fn link_quality(before: &ConsoleCounters, now: &ConsoleCounters) -> LinkQuality {
    // A serial link carries far fewer than 400 000 frames a second: the product fits a u32 (no 64-bit division
    // code in the image).
    let corrupt = now.corrupt().wrapping_sub(before.corrupt()).min(400_000);
    let good = now.frames_in.wrapping_sub(before.frames_in).min(400_000);
    LinkQuality {
        drop_rate: (corrupt * 10_000).checked_div(corrupt + good).unwrap_or(0) as u16,
        errors: now.corrupt() as u16,
    }
}

/// Room for the largest batch of frames written at once: the 1 Hz set and both ESC messages with full payloads
/// take 254 bytes.
const BATCH: usize = 256;

/// The writing half: frames messages into a batch and writes the batch in one go (one await point for all
/// message types keeps the task small).
struct Output<'a, W> {
    tx: &'a mut W,
    framer: Framer,
    stats: &'a ConsoleStats,
    batch: [u8; BATCH],
    len: usize,
    frames: u32,
}

impl<W: Write> Output<'_, W> {
    /// Frame `message` into the batch; a frame that does not fit is counted as a write error.
    fn push<D: MessageData>(&mut self, message: &D) {
        let bytes = self.framer.frame(message);
        match self.batch.get_mut(self.len..self.len + bytes.len()) {
            Some(room) => {
                room.copy_from_slice(bytes);
                self.len += bytes.len();
                self.frames += 1;
            }
            None => ConsoleStats::count(&self.stats.write_errors, 1),
        }
    }

    /// Write the batch; its frames count as written or as write errors.
    async fn flush(&mut self) {
        let batch = self.batch.get(..self.len).unwrap_or_default();
        let counter = match self.tx.write_all(batch).await {
            Ok(()) => &self.stats.frames_out,
            Err(_) => &self.stats.write_errors,
        };
        ConsoleStats::count(counter, self.frames);
        self.len = 0;
        self.frames = 0;
    }
}
