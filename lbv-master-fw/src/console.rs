//! The operator console: MAVLink 2 on LPUART1 (the ST-LINK virtual COM port), for QGroundControl, MAVProxy and
//! pymavlink scripts.
//!
//! - [`console_rx_task`] reads frames (MAVLink 2, and MAVLink 1 too) through a [`Receiver`], which checks their
//!   signatures when a key is set ([`crate::console::signing`]), decodes the few messages the master understands
//!   (`inbound::decode`) and hands them to the vehicle task as [`Request`]s: the command and who sent it; MAVLink
//!   FTP and the apply command go to the update server it runs instead ([`crate::update`]). It never stops reading
//!   for the update or for anyone on the link, and limits per requester what makes the vehicle send more than it
//!   costs ([`limit`]).
//! - [`console_tx_task`] sends the telemetry an ArduSub or QGroundControl ground station displays (HEARTBEAT,
//!   SYS_STATUS, BATTERY_STATUS, ESC_INFO and the "PilotGain" NAMED_VALUE_FLOAT at 1 Hz, ESC_TELEMETRY and
//!   ESC_STATUS at 4 Hz, at the intervals a ground station sets) and every message the other tasks queue in
//!   [`Shared::outbox`] (COMMAND_ACK, PARAM_VALUE, STATUSTEXT, a requested message such as AUTOPILOT_VERSION, an
//!   FTP reply) as soon as it is queued, signed when a key is set.
//!
//! The dialect ([`lbv`]) is generated at build time from `mavlink/lbv.xml`, which holds only the messages used,
//! copied from the official definitions; messages are encoded and decoded one type at a time, so the image
//! carries only their codecs. Both tasks share a [`ConsoleStats`]: the link's counters and its signing state.

use core::cell::RefCell;
use core::sync::atomic::{AtomicU32, Ordering};

#[cfg(not(feature = "acceptance"))]
use core::future::poll_fn;

use embassy_futures::select::{Either, Either3, select, select3};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
#[cfg(not(feature = "acceptance"))]
use embassy_sync::channel::TrySendError;
use embassy_time::{Duration, Instant, Ticker, Timer};
use embedded_io_async::{Read, Write};
use mavlink_core::MessageData;

use crate::console::framing::{Event, Frame, FrameParser};
use crate::console::signing::{Refusal, SigningKey, SigningState};
use crate::mixer::FrameKind;
use crate::params::{LISTED_COUNT, Listed};
use crate::ports::UpdateSink;
use crate::shared::{
    Command, Interval, MAX_THRUSTERS, Message, Outgoing, Request, Sender, Shared, UpdateAction, UpdateCommand,
    UpdateRequest,
};
use crate::thrusters::ThrusterTable;
use crate::update::FtpAnswer;
#[cfg(not(feature = "acceptance"))]
use crate::update::Updates;
#[cfg(not(feature = "acceptance"))]
use crate::update::ftp::Opcode;
use limit::Limiter;

pub mod framing;
pub mod inbound;
pub mod limit;
pub mod outbound;
pub mod signing;
pub(crate) mod tlog;

include!(concat!(env!("OUT_DIR"), "/lbv_dialect.rs"));

use outbound::{ConsoleLinkQuality, Framer, Reports};

/// The transmit task's clock: every message interval is a whole number of these (rounded, at least one).
pub(crate) const TX_TICK: Duration = Duration::from_millis(50);
/// Pause after a read error or end of input, so a failing port cannot monopolise the executor.
const READ_RETRY: Duration = Duration::from_millis(10);
/// The line is quiet for this long with a frame begun: the frame will not complete, so its start was false and
/// the bytes after it are read again. A ground station writes each frame at once, so a real frame has no gap
/// this long inside it (at 115200 baud a whole 280-byte frame takes 24 ms), and a stray start byte costs this
/// much instead of the up to 280 bytes its claimed length would take to arrive (13 s of 1 Hz heartbeats).
pub const LINE_IDLE: Duration = Duration::from_millis(50);

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
    /// The chip's 96-bit unique device id for AUTOPILOT_VERSION, as its three words read in little-endian order
    /// (RM0440 section 48.1: UID\[31:0\] at 0x1FFF_7590 first). The STM32 binding reads it; the core never touches
    /// hardware. All zeros: unknown.
    pub uid: [u8; 12],
}

impl ConsoleConfig {
    /// System 1, component 1 (MAV_COMP_ID_AUTOPILOT1), 6 thrusters (the LBV300), unique id unknown.
    pub const DEFAULT: ConsoleConfig = ConsoleConfig {
        system_id: 1,
        component_id: 1,
        thrusters: 6,
        uid: [0; 12],
    };

    /// The configured thrusters, capped at [`MAX_THRUSTERS`].
    pub(crate) fn thruster_count(&self) -> usize {
        usize::from(self.thrusters).min(MAX_THRUSTERS)
    }
}

impl Default for ConsoleConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// The console link's state shared by its two tasks: counters (atomics, read them with
/// [`ConsoleStats::snapshot`]; they wrap) and the signing state, which both the receiving side (checks, follows
/// the timestamps) and the sending side (signs) use.
#[derive(Debug)]
pub struct ConsoleStats {
    frames_in: AtomicU32,
    bad_frames: AtomicU32,
    unknown_messages: AtomicU32,
    skipped_bytes: AtomicU32,
    read_errors: AtomicU32,
    unsigned: AtomicU32,
    bad_signatures: AtomicU32,
    replayed: AtomicU32,
    ahead: AtomicU32,
    out_of_range: AtomicU32,
    frames_out: AtomicU32,
    write_errors: AtomicU32,
    rate_limited: AtomicU32,
    requests_dropped: AtomicU32,
    replies_dropped: AtomicU32,
    signing: Mutex<CriticalSectionRawMutex, RefCell<SigningState>>,
}

impl Default for ConsoleStats {
    fn default() -> Self {
        Self::new()
    }
}

/// A copy of the console counters.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct ConsoleCounters {
    /// CRC-valid frames of messages of the dialect whose payload decoded and that passed the signing checks
    /// (whether or not they were for us).
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
    pub(crate) read_errors: u32,
    /// With a signing key set: frames refused because they were not signed (or MAVLink 1).
    pub unsigned: u32,
    /// With a signing key set: frames refused because their signature was wrong.
    pub bad_signatures: u32,
    /// With a signing key set: correctly signed frames refused for their timestamp (a replay).
    pub replayed: u32,
    /// With a signing key set: correctly signed frames beyond the stored reservation, refused until the next one
    /// is stored (the first frame of a ground station whose clock ran on while the master was off).
    pub(crate) ahead: u32,
    /// With a signing key set: correctly signed frames with a timestamp so near 2^48 - 1 that the link's would
    /// run out.
    pub out_of_range: u32,
    /// Frames written.
    pub frames_out: u32,
    /// Frames the serial port failed to write.
    pub write_errors: u32,
    /// Requests dropped unanswered because their requester's allowance had no room for what they would make the
    /// vehicle send ([`limit`]).
    pub rate_limited: u32,
    /// Update requests dropped unanswered because the update sink had no room and the receive task held as many
    /// as it keeps already (a ground station sends them again).
    pub requests_dropped: u32,
    /// FTP replies dropped because the outbox was full: every reply to a listing or a CRC, and to anyone but the
    /// operator's system (a ground station asks again).
    pub replies_dropped: u32,
}

impl ConsoleCounters {
    /// Frames received damaged: bad frames other than unknown messages.
    pub fn corrupt(&self) -> u32 {
        self.bad_frames.wrapping_sub(self.unknown_messages)
    }

    /// Frames refused by the signing checks.
    pub fn refused_by_signing(&self) -> u32 {
        self.unsigned
            .wrapping_add(self.bad_signatures)
            .wrapping_add(self.replayed)
            .wrapping_add(self.ahead)
            .wrapping_add(self.out_of_range)
    }
}

impl ConsoleStats {
    /// All zero, no signing key.
    pub const fn new() -> Self {
        Self {
            frames_in: AtomicU32::new(0),
            bad_frames: AtomicU32::new(0),
            unknown_messages: AtomicU32::new(0),
            skipped_bytes: AtomicU32::new(0),
            read_errors: AtomicU32::new(0),
            unsigned: AtomicU32::new(0),
            bad_signatures: AtomicU32::new(0),
            replayed: AtomicU32::new(0),
            ahead: AtomicU32::new(0),
            out_of_range: AtomicU32::new(0),
            frames_out: AtomicU32::new(0),
            write_errors: AtomicU32::new(0),
            rate_limited: AtomicU32::new(0),
            requests_dropped: AtomicU32::new(0),
            replies_dropped: AtomicU32::new(0),
            signing: Mutex::new(RefCell::new(SigningState::new())),
        }
    }

    /// The counters now.
    pub fn snapshot(&self) -> ConsoleCounters {
        let load = |counter: &AtomicU32| counter.load(Ordering::Relaxed);
        ConsoleCounters {
            frames_in: load(&self.frames_in),
            bad_frames: load(&self.bad_frames),
            unknown_messages: load(&self.unknown_messages),
            skipped_bytes: load(&self.skipped_bytes),
            read_errors: load(&self.read_errors),
            unsigned: load(&self.unsigned),
            bad_signatures: load(&self.bad_signatures),
            replayed: load(&self.replayed),
            ahead: load(&self.ahead),
            out_of_range: load(&self.out_of_range),
            frames_out: load(&self.frames_out),
            write_errors: load(&self.write_errors),
            rate_limited: load(&self.rate_limited),
            requests_dropped: load(&self.requests_dropped),
            replies_dropped: load(&self.replies_dropped),
        }
    }

    /// Use the link's signing state, following `key` (the one in force) first.
    pub(crate) fn signing<T>(&self, key: Option<SigningKey>, f: impl FnOnce(&mut SigningState) -> T) -> T {
        self.signing.lock(|state| {
            let mut state = state.borrow_mut();
            state.sync(key);
            f(&mut state)
        })
    }

    /// Bring the signing state up to the settings and the flash: the key in force (`shared.settings`), the
    /// reservation stored (`shared.signing_stored`); hand a reservation that has fallen due to the settings store
    /// (`shared.signing_time`). Returns the key in force. [`crate::run`] calls it before any task starts, and both
    /// console tasks before every frame they take or send.
    pub fn follow(&self, shared: &Shared) -> Option<SigningKey> {
        let key = shared.settings.try_get().and_then(|settings| settings.signing);
        let stored = shared.signing_stored.try_get();
        let due = self.signing(key, |signing| {
            if let Some(reservation) = stored {
                signing.stored(reservation);
            }
            signing.due_for_storing()
        });
        if let Some(reservation) = due {
            shared.signing_time.sender().send(reservation);
        }
        key
    }

    fn count(counter: &AtomicU32, n: u32) {
        if n > 0 {
            counter.fetch_add(n, Ordering::Relaxed);
        }
    }
}

/// What one frame came to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Received {
    /// A request for the vehicle.
    Request(Request),
    /// A request for the update server: MAVLink FTP, or the apply command ([`crate::update::ENABLED`]).
    Update(UpdateRequest),
    /// Nothing for the vehicle: counted and dropped, or not addressed to us, or telemetry of another system.
    Nothing,
}

/// The receiving half of the console without its port: bytes in, requests for the vehicle out. Bad bytes and
/// frames are counted in the [`ConsoleStats`] and skipped; it never panics. [`console_rx_task`] runs it, and the
/// fuzz target drives it directly.
#[derive(Debug, Clone, Default)]
pub struct Receiver {
    parser: FrameParser,
}

impl Receiver {
    /// Nothing buffered.
    pub const fn new() -> Self {
        Self {
            parser: FrameParser::new(),
        }
    }

    /// Append received bytes; returns how many were taken (see [`FrameParser::push`]).
    pub fn push(&mut self, data: &[u8]) -> usize {
        self.parser.push(data)
    }

    /// The input has paused: a frame begun now will not complete (see [`FrameParser::end_of_input`]).
    pub fn end_of_input(&mut self) {
        self.parser.end_of_input();
    }

    /// Whether a frame has begun and is not complete.
    pub fn pending(&self) -> bool {
        self.parser.pending()
    }

    /// What the next buffered frame comes to, or `None` when more bytes are needed. `key` is the signing key in
    /// force: with one, frames that fail the signing checks are refused and counted.
    pub fn next(&mut self, config: &ConsoleConfig, key: Option<SigningKey>, stats: &ConsoleStats) -> Option<Received> {
        let event = self.parser.next(inbound::extra_crc);
        let received = match event {
            None => None,
            Some(Event::Corrupt) => {
                ConsoleStats::count(&stats.bad_frames, 1);
                Some(Received::Nothing)
            }
            Some(Event::Unknown(_)) => {
                ConsoleStats::count(&stats.bad_frames, 1);
                ConsoleStats::count(&stats.unknown_messages, 1);
                Some(Received::Nothing)
            }
            Some(Event::Frame(frame)) => Some(match stats.signing(key, |signing| signing.check(&frame)) {
                Err(refusal) => {
                    ConsoleStats::count(
                        match refusal {
                            Refusal::Unsigned => &stats.unsigned,
                            Refusal::BadSignature => &stats.bad_signatures,
                            Refusal::Replayed => &stats.replayed,
                            Refusal::Ahead => &stats.ahead,
                            Refusal::OutOfRange => &stats.out_of_range,
                        },
                        1,
                    );
                    Received::Nothing
                }
                Ok(()) => match decode(&frame, config) {
                    Ok(received) => {
                        ConsoleStats::count(&stats.frames_in, 1);
                        received
                    }
                    Err(_) => {
                        ConsoleStats::count(&stats.bad_frames, 1);
                        Received::Nothing
                    }
                },
            }),
        };
        ConsoleStats::count(&stats.skipped_bytes, self.parser.take_skipped());
        received
    }
}

/// What a frame that passed the signing checks asks, and of whom.
fn decode(frame: &Frame<'_>, config: &ConsoleConfig) -> Result<Received, mavlink_core::error::ParserError> {
    let from = Sender {
        system: frame.system_id,
        component: frame.component_id,
    };
    if crate::update::ENABLED
        && let Some(payload) = inbound::ftp(frame, config)
    {
        return Ok(Received::Update(UpdateRequest {
            from,
            what: UpdateCommand::Ftp(payload),
        }));
    }
    Ok(match inbound::decode(frame, config)? {
        Some(Command::Update { action, target }) if crate::update::ENABLED => Received::Update(UpdateRequest {
            from,
            what: match action {
                UpdateAction::Apply => UpdateCommand::Apply(target),
                UpdateAction::QueryVersion => UpdateCommand::QueryVersion(target),
            },
        }),
        Some(command) => Received::Request(Request { from, command }),
        None => Received::Nothing,
    })
}

/// Read MAVLink frames from `rx` and send the [`Request`]s they carry to `shared.commands`, awaiting room (the
/// vehicle task drains it at once); serve the [`UpdateRequest`]s with an update server for `thrusters` whose images
/// go to `sink` ([`Updates::serve`]). Reading never waits for the update sink or for room for an FTP reply: the
/// operator's HEARTBEAT and MANUAL_CONTROL are read as they come whatever the update does.
///
/// - A request that changes an upload or the images, or a session (every FTP opcode but ListDirectory,
///   CalcFileCrc32, ReadFile, BurstReadFile and those not served, and the update commands) is held, in order, and
///   served as soon as the sink is [`UpdateSink::ready`] (at once when it is: the task looks before it reads on),
///   one at a time; [`HELD`] of them at most, and the operator's (its system's) only once one is held. A request
///   beyond them is dropped unanswered, which a ground station takes for a lost frame and sends again
///   ([`ConsoleCounters::requests_dropped`]).
/// - Its reply, when it is for the operator's system and the outbox is full, waits for room while reading goes on
///   (no held request is served meanwhile, so the replies keep their order); any other FTP reply (to a listing, a
///   CRC, a read, or to another system) is dropped when the outbox is full ([`ConsoleCounters::replies_dropped`]).
/// - Requests that make the vehicle send more than they cost (the parameter list and reads, requested messages,
///   FTP listings, CRCs and reads) are limited per requester ([`limit`]), the operator's included (its system's
///   file reads from an allowance of their own, half the line); what is over its allowance is dropped unanswered
///   ([`ConsoleCounters::rate_limited`]).
///
/// A frame begun when the line falls quiet for [`LINE_IDLE`] is given up and the bytes after its start read
/// again, so noise never hides the frames behind it for longer. Frames from any system are read; only messages
/// addressed to our system (target 0 or ours, where the message has a target) become requests, and the vehicle
/// decides whether their sender may ask. With a signing key in force (`shared.settings`), frames that fail the
/// signing checks are refused, and the reservations the link needs are asked for ([`ConsoleStats::follow`]). A
/// read error is counted and reading resumes after a short pause.
pub async fn console_rx_task<R: Read, U: UpdateSink>(
    rx: &mut R,
    config: &ConsoleConfig,
    shared: &Shared,
    stats: &ConsoleStats,
    thrusters: &ThrusterTable,
    frame: FrameKind,
    sink: U,
) -> ! {
    #[cfg(not(feature = "acceptance"))]
    let mut updates = Updates::new(thrusters, frame, sink);
    #[cfg(not(feature = "acceptance"))]
    let mut held = Held::new();
    #[cfg(feature = "acceptance")]
    let _ = (thrusters, frame, sink);
    let mut limiter = Limiter::new();
    let mut receiver = Receiver::new();
    let mut chunk = [0u8; 64];
    loop {
        let pending = receiver.pending();
        let idle = async {
            if pending {
                Timer::after(LINE_IDLE).await;
            } else {
                core::future::pending::<()>().await;
            }
        };
        #[cfg(not(feature = "acceptance"))]
        let unblocked = held.unblocked(&mut updates.sink, shared);
        #[cfg(feature = "acceptance")]
        let unblocked = core::future::pending::<()>();
        // What was held goes on first, one request at a time, whenever it can; reading goes on meanwhile.
        let read = match select3(unblocked, rx.read(&mut chunk), idle).await {
            Either3::First(()) => {
                #[cfg(not(feature = "acceptance"))]
                held.go_on(&mut updates, shared, stats);
                continue;
            }
            Either3::Second(read) => Some(read),
            Either3::Third(()) => None,
        };
        let mut rest = match read {
            None => {
                receiver.end_of_input();
                &[][..]
            }
            Some(Ok(0)) => {
                Timer::after(READ_RETRY).await;
                continue;
            }
            Some(Ok(n)) => chunk.get(..n).unwrap_or_default(),
            Some(Err(_)) => {
                ConsoleStats::count(&stats.read_errors, 1);
                Timer::after(READ_RETRY).await;
                continue;
            }
        };
        loop {
            let taken = receiver.push(rest);
            rest = rest.get(taken..).unwrap_or_default();
            while let Some(received) = receiver.next(config, stats.follow(shared), stats) {
                match received {
                    Received::Request(request) => {
                        let cost = limit::cost(&request.command);
                        if limiter.allow(request.from, cost, operator(shared), Instant::now()) {
                            shared.commands.send(request).await;
                        } else {
                            ConsoleStats::count(&stats.rate_limited, 1);
                        }
                    }
                    // A cfg, not `if update::ENABLED`: an async branch never taken still costs its code.
                    #[cfg(not(feature = "acceptance"))]
                    Received::Update(request) => held.take(request, &mut updates, &mut limiter, shared, stats),
                    #[cfg(feature = "acceptance")]
                    Received::Update(_) => {}
                    Received::Nothing => {}
                }
            }
            stats.follow(shared);
            if rest.is_empty() {
                break;
            }
        }
    }
}

/// `SYSID_MYGCS` as the vehicle last said (0, nobody, before it has).
fn operator(shared: &Shared) -> u8 {
    shared.vehicle.try_get().map_or(0, |state| state.operator)
}

/// Update requests held until the update sink is ready for them, served in order; see [`console_rx_task`]. Eight:
/// MAVProxy and pymavlink keep five writes in flight (their `write_qsize`) and, after 0.2 s without an answer, take
/// one for lost and send the next; a page on its way to a thruster keeps the sink busy some 0.7 s, so a client's
/// upload sends eight writes meanwhile, all of which are kept for it (which the clients' round-robin resends would
/// otherwise find gaps behind, slowing the upload). 2 KiB of RAM.
#[cfg(not(feature = "acceptance"))]
pub const HELD: usize = 8;

/// What the receive task holds for the update server: the requests waiting for the sink, and a reply to the
/// operator waiting for room in the outbox.
#[cfg(not(feature = "acceptance"))]
struct Held {
    requests: heapless::Deque<UpdateRequest, HELD>,
    reply: Option<Outgoing>,
}

#[cfg(not(feature = "acceptance"))]
impl Held {
    const fn new() -> Self {
        Self {
            requests: heapless::Deque::new(),
            reply: None,
        }
    }

    /// Take `request` as it is read: a listing or a CRC (over its requester's allowance: dropped) is answered at
    /// once; a request that changes something is held, to be served in order once the sink is ready (at once when
    /// it is: the receive task looks before it reads on).
    fn take<S: UpdateSink>(
        &mut self,
        request: UpdateRequest,
        updates: &mut Updates<S>,
        limiter: &mut Limiter,
        shared: &Shared,
        stats: &ConsoleStats,
    ) {
        let operator = operator(shared);
        let Some((cost, read)) = reads(&request) else {
            let room = self.requests.is_empty() || request.from.system == operator;
            if !room || self.requests.push_back(request).is_err() {
                ConsoleStats::count(&stats.requests_dropped, 1);
            }
            return;
        };
        let allowed = match read {
            Some(bytes) if request.from.system == operator => limiter.allow_read(bytes, Instant::now()),
            _ => limiter.allow(request.from, cost, operator, Instant::now()),
        };
        if !allowed {
            return ConsoleStats::count(&stats.rate_limited, 1);
        }
        if let Some(reply) = updates.serve(request, shared)
            && shared.outbox.try_send(reply).is_err()
        {
            ConsoleStats::count(&stats.replies_dropped, 1);
        }
    }

    /// [`Held::unblocked`] has returned: send the reply held, or serve the next request, the sink being ready.
    fn go_on<S: UpdateSink>(&mut self, updates: &mut Updates<S>, shared: &Shared, stats: &ConsoleStats) {
        if let Some(reply) = self.reply.take() {
            if let Err(TrySendError::Full(reply)) = shared.outbox.try_send(reply) {
                self.reply = Some(reply);
            }
            return;
        }
        let Some(request) = self.requests.pop_front() else {
            return;
        };
        // The operator's system's reply waits for room; any other is dropped when there is none.
        match updates
            .serve(request, shared)
            .map(|reply| shared.outbox.try_send(reply))
        {
            None | Some(Ok(())) => {}
            Some(Err(TrySendError::Full(reply))) => match reply {
                Outgoing::Ftp { to, .. } if to.system == operator(shared) => self.reply = Some(reply),
                _ => ConsoleStats::count(&stats.replies_dropped, 1),
            },
        }
    }

    /// Until what is held can go on: the outbox has room for the reply held, or else the sink is ready for the next
    /// request (never, when nothing is held).
    async fn unblocked<S: UpdateSink>(&self, sink: &mut S, shared: &Shared) {
        if self.reply.is_some() {
            poll_fn(|cx| shared.outbox.poll_ready_to_send(cx)).await;
        } else if !self.requests.is_empty() {
            sink.ready().await;
        } else {
            core::future::pending::<()>().await;
        }
    }
}

/// The bytes of a reply to a listing, about: what a frame of a requester's allowance stands for ([`limit`]).
#[cfg(not(feature = "acceptance"))]
const LISTING_REPLY_BYTES: u32 = 48;

/// What a request that only reads (a listing, a CRC, a read of the file a session opened, an opcode not served)
/// costs its requester's allowance ([`limit`]), in frames, and for a read the bytes of its reply, which the
/// operator's system's reads take from their own ([`limit::Limiter::allow_read`]); `None` for one that changes an
/// upload or the images, which is served in order.
#[cfg(not(feature = "acceptance"))]
fn reads(request: &UpdateRequest) -> Option<(u32, Option<u32>)> {
    let UpdateCommand::Ftp(payload) = &request.what else {
        return None;
    };
    match Opcode::from_byte(payload.get(3).copied().unwrap_or(0)) {
        Opcode::ListDirectory | Opcode::CalcFileCrc32 => Some((1, None)),
        // Its reply carries up to the `size` bytes asked for: it costs what as many bytes of listing replies do,
        // and for the operator's system the bytes of its frame (header, FTP header, data, CRC).
        Opcode::ReadFile | Opcode::BurstReadFile => {
            let size = u32::from(payload.get(4).copied().unwrap_or(0));
            Some((1 + size / LISTING_REPLY_BYTES, Some(12 + 3 + 12 + size)))
        }
        Opcode::None | Opcode::Other(_) => Some((0, None)),
        _ => None,
    }
}

/// Whether the image sends ESC_INFO and ESC_STATUS. The acceptance image leaves them out: its script drives the
/// bus itself and publishes no thruster reports (they would only ever say "no thruster"), and their codecs do
/// not fit its flash budget beside the script.
pub(crate) const ESC_DETAIL: bool = !cfg!(feature = "acceptance");

/// The paced messages, in the order a batch carries them.
const PACED: [Message; 8] = [
    Message::Heartbeat,
    Message::SysStatus,
    Message::BatteryStatus,
    Message::EscTelemetry1To4,
    Message::EscTelemetry5To8,
    Message::EscInfo,
    Message::EscStatus,
    Message::NamedValueFloat,
];

/// A paced message's default period in [`TX_TICK`]s.
const fn default_ticks(message: Message) -> u16 {
    match message {
        Message::EscInfo | Message::EscStatus if !ESC_DETAIL => 0,
        Message::EscTelemetry1To4 | Message::EscTelemetry5To8 | Message::EscStatus => 5,
        _ => 20,
    }
}

/// Ticks per interval: rounded, at least one (the interval is already clamped, see [`inbound::interval`]).
fn interval_ticks(message: Message, interval: Interval) -> u16 {
    let tick = TX_TICK.as_millis() as u32;
    match interval {
        Interval::Default => default_ticks(message),
        Interval::Off => 0,
        Interval::Every(ms) => u16::try_from((ms + tick / 2) / tick).unwrap_or(u16::MAX).max(1),
    }
}

/// When each paced message goes: its period and the ticks left until it is due (0: off / due now).
#[derive(Debug, Clone)]
struct Schedule {
    period: [u16; PACED.len()],
    left: [u16; PACED.len()],
}

impl Schedule {
    /// The default rates, everything due at once.
    fn new() -> Self {
        Self {
            period: PACED.map(default_ticks),
            left: [0; PACED.len()],
        }
    }

    /// Pace `message` at `interval` from now: due at once, then every period.
    fn set(&mut self, message: Message, interval: Interval) {
        if let Some(n) = PACED.iter().position(|m| *m == message)
            && let (Some(period), Some(left)) = (self.period.get_mut(n), self.left.get_mut(n))
        {
            *period = interval_ticks(message, interval);
            *left = 0;
        }
    }

    /// One tick: the messages due now, in [`PACED`] order.
    fn tick(&mut self) -> [bool; PACED.len()] {
        core::array::from_fn(|n| match (self.period.get(n).copied(), self.left.get_mut(n)) {
            (Some(period), Some(left)) if period > 0 => {
                let due = *left == 0;
                *left = if due { period - 1 } else { *left - 1 };
                due
            }
            _ => false,
        })
    }
}

/// Send telemetry to `tx`: HEARTBEAT (always 1 Hz), SYS_STATUS, BATTERY_STATUS, ESC_INFO and "PilotGain" at 1 Hz,
/// ESC_TELEMETRY_1_TO_4 (and ESC_TELEMETRY_5_TO_8 when more than 4 thrusters are configured) and ESC_STATUS at
/// 4 Hz, the first set at once; [`Outgoing::Interval`] changes a paced message's interval (the next one goes at
/// once). ESC_INFO and ESC_STATUS go as one message per block of four configured thrusters. Every
/// [`Shared::outbox`] message goes as soon as it is queued, a requested one ([`Outgoing::Message`]) built then,
/// the parameter list ([`Outgoing::ParamList`]) one PARAM_VALUE at a time as the port takes them.
/// MAVLink 2 frames from `config`'s system and component, signed while a key is in force (`shared.settings`; a
/// batch waits for the signing reservation to have room, never going out unsigned); the sequence number counts
/// every frame. Write errors, and frames that could not be signed, are counted in `stats` as write errors and the
/// frame is dropped. [`Outgoing::Reboot`] flushes the port and raises `shared.reboot`.
///
/// SYS_STATUS's drop_rate_comm is the share of corrupt frames received since the last SYS_STATUS (see
/// [`ConsoleCounters::corrupt`]).
pub async fn console_tx_task<W: Write>(tx: &mut W, config: &ConsoleConfig, shared: &Shared, stats: &ConsoleStats) -> ! {
    let mut out = Output {
        tx,
        framer: Framer::new(config.system_id, config.component_id),
        stats,
        key: None,
        batch: [0; BATCH],
        len: 0,
        frames: 0,
    };
    let mut schedule = Schedule::new();
    let mut ticker = Ticker::every(TX_TICK);
    let mut last = stats.snapshot();
    loop {
        out.key = signing_room(shared, stats).await;
        for (message, due) in PACED.into_iter().zip(schedule.tick()) {
            if due {
                out.send(message, None, config, shared, &mut last);
            }
        }
        out.flush().await;

        while let Either::Second(message) = select(ticker.next(), shared.outbox.receive()).await {
            out.key = signing_room(shared, stats).await;
            match message {
                Outgoing::CommandAck { command, result, to } => out.push(&outbound::command_ack(command, result, to)),
                Outgoing::Progress { command, progress, to } => {
                    out.push(&outbound::command_progress(command, progress, to));
                }
                Outgoing::ParamValue {
                    id,
                    value,
                    param_type,
                    index,
                    count,
                } => out.push(&outbound::param_value(&id, value, param_type, index, count)),
                Outgoing::ParamList => {
                    // By index: an iterator held over the awaits would sit in the task's static storage.
                    for listed in (0..LISTED_COUNT as u16).filter_map(Listed::from_index) {
                        out.key = signing_room(shared, stats).await;
                        // The value alone, not the settings, is held over the write.
                        let value = match shared.settings.try_get() {
                            Some(settings) => listed.to_float(listed.value(&settings.params)),
                            None => break,
                        };
                        let count = LISTED_COUNT as u16;
                        out.push(&outbound::param_value(
                            &listed.id(),
                            value,
                            listed.param_type(),
                            listed.index(),
                            count,
                        ));
                        out.flush().await;
                    }
                }
                Outgoing::Text(severity, text) => out.push(&outbound::statustext(severity, &text)),
                Outgoing::MissionCount { to, mission_type } => out.push(&outbound::mission_count(to, mission_type)),
                Outgoing::MissionAck {
                    to,
                    mission_type,
                    accepted,
                } => out.push(&outbound::mission_ack(to, mission_type, accepted)),
                Outgoing::Message { message, first } => out.send(message, Some(first), config, shared, &mut last),
                Outgoing::Interval(message, interval) => schedule.set(message, interval),
                Outgoing::Ftp { to, reply } => out.ftp_reply(to, &reply, shared),
                Outgoing::Reboot => {
                    out.flush().await;
                    // The acknowledgement must leave the port before the restart cuts it off.
                    let _ = out.tx.flush().await;
                    shared.reboot.signal(());
                }
            }
            out.flush().await;
        }
    }
}

/// Most frames one batch signs: every paced message, ESC_INFO and ESC_STATUS twice (see [`BATCH`]).
const BATCH_FRAMES: u64 = 10;
/// Longest wait for a signing reservation to be stored before a batch goes (its frames beyond the reservation
/// are dropped then): a write takes milliseconds, a page erase about 20 ms.
const ROOM_WAIT: Duration = Duration::from_millis(50);

/// The key in force, once the signing reservation has room for a batch (at once without a key, or after
/// [`ROOM_WAIT`] at most): right after a start whose reservation could not be stored, or a SETUP_SIGNING with a
/// later timestamp, the frames wait for the settings store rather than go unsigned.
async fn signing_room(shared: &Shared, stats: &ConsoleStats) -> Option<SigningKey> {
    let deadline = Instant::now() + ROOM_WAIT;
    loop {
        let key = stats.follow(shared);
        if stats.signing(key, |signing| signing.room()) >= BATCH_FRAMES || Instant::now() >= deadline {
            return key;
        }
        Timer::after(Duration::from_millis(1)).await;
    }
}

/// Link quality between two snapshots of the counters; `refused` the vehicle's count of requests from other
/// systems. The totals saturate in SYS_STATUS's 16-bit fields.
pub(crate) fn link_quality(before: &ConsoleCounters, now: &ConsoleCounters, refused: u32) -> ConsoleLinkQuality {
    // A serial link carries far fewer than 400 000 frames a second: the product fits a u32 (no 64-bit division
    // code in the image).
    let corrupt = now.corrupt().wrapping_sub(before.corrupt()).min(400_000);
    let good = now.frames_in.wrapping_sub(before.frames_in).min(400_000);
    ConsoleLinkQuality {
        drop_rate: (corrupt * 10_000).checked_div(corrupt + good).unwrap_or(0) as u16,
        errors: outbound::saturate(now.corrupt()),
        refused_other_system: outbound::saturate(refused),
        refused_by_signing: outbound::saturate(now.refused_by_signing()),
    }
}

/// Room for the largest batch of frames written at once: every paced message with full payloads (HEARTBEAT 21,
/// SYS_STATUS 55, BATTERY_STATUS 66, two ESC_TELEMETRY 56 each, two ESC_INFO 58 each, two ESC_STATUS 69 each,
/// NAMED_VALUE_FLOAT 30: 538 bytes) and their 10 signatures (130): 668 bytes.
const BATCH: usize = 672;

/// The writing half: frames messages into a batch and writes the batch in one go (one await point for all
/// message types keeps the task small).
struct Output<'a, W> {
    tx: &'a mut W,
    framer: Framer,
    stats: &'a ConsoleStats,
    /// The signing key in force.
    key: Option<SigningKey>,
    batch: [u8; BATCH],
    len: usize,
    frames: u32,
}

impl<W: Write> Output<'_, W> {
    /// Frame one of the periodic (or requested) messages, built from the state now; `last` is the counters at the
    /// last SYS_STATUS (its drop rate covers the time since). ESC_INFO and ESC_STATUS go for every block of four
    /// thrusters, or the one from `first` alone (a request's).
    fn send(
        &mut self,
        message: Message,
        first: Option<u8>,
        config: &ConsoleConfig,
        shared: &Shared,
        last: &mut ConsoleCounters,
    ) {
        let thrusters = config.thruster_count();
        let reports: Reports = core::array::from_fn(|i| {
            shared
                .thrusters
                .get(i)
                .filter(|_| i < thrusters)
                .and_then(|w| w.try_get())
        });
        let time_usec = embassy_time::Instant::now().as_micros();
        // The blocks of four thrusters that have at least one configured.
        let blocks = (0..MAX_THRUSTERS)
            .step_by(4)
            .filter(|block| *block < thrusters.max(1) && first.is_none_or(|first| usize::from(first) == *block));
        match message {
            Message::Heartbeat => self.push(&outbound::heartbeat(shared.vehicle.try_get())),
            Message::SysStatus => {
                let vehicle = shared.vehicle.try_get();
                let now = self.stats.snapshot();
                let link = link_quality(last, &now, vehicle.map_or(0, |v| v.refused));
                *last = now;
                let battery = shared.battery.try_get();
                self.push(&outbound::sys_status(
                    thrusters,
                    &reports,
                    battery.as_ref(),
                    vehicle,
                    link,
                ));
            }
            Message::BatteryStatus => self.push(&outbound::battery_status(shared.battery.try_get().as_ref())),
            Message::AutopilotVersion => self.push(&outbound::autopilot_version(
                &config.uid,
                update_image::UPDATE_KEY_IS_DEV,
            )),
            Message::AvailableModes => self.push(&outbound::available_modes()),
            Message::EscTelemetry1To4 => self.push(&outbound::esc_telemetry_1_to_4(thrusters, &reports)),
            Message::EscTelemetry5To8 if thrusters > 4 => {
                self.push(&outbound::esc_telemetry_5_to_8(thrusters, &reports))
            }
            Message::EscTelemetry5To8 => {}
            Message::NamedValueFloat => {
                if let Some(settings) = shared.settings.try_get() {
                    let gain = settings.params.gain_percent();
                    // time_boot_ms wraps after 49 days, as the field does.
                    self.push(&outbound::pilot_gain(gain, time_usec.wrapping_div(1000) as u32));
                }
            }
            Message::EscInfo | Message::EscStatus if !ESC_DETAIL => {}
            Message::EscInfo => {
                for first in blocks {
                    let escs = outbound::Esc::block(thrusters, &reports, first);
                    let counters = outbound::EscCounters::of(thrusters, &reports, first);
                    self.push(&outbound::esc_info(thrusters, first, &escs, &counters, time_usec));
                }
            }
            Message::EscStatus => {
                for first in blocks {
                    let escs = outbound::Esc::block(thrusters, &reports, first);
                    self.push(&outbound::esc_status(first, &escs, time_usec));
                }
            }
        }
    }

    /// Frame an FTP reply, a read with the parameters and the crash record as they are now (nothing in an image
    /// without the update server, which has none to send).
    fn ftp_reply(&mut self, to: Sender, reply: &FtpAnswer, shared: &Shared) {
        #[cfg(not(feature = "acceptance"))]
        {
            let params = shared.settings.try_get().map(|settings| settings.params);
            let crash = match reply {
                FtpAnswer::Read(crate::update::FileRead {
                    file: crate::update::OpenFile::Crash(crate::update::sys::CrashFile(board)),
                    ..
                }) => board.map_or_else(|| shared.crash_bytes(), |slot| shared.post_mortem(slot)),
                _ => None,
            };
            let ids = self.framer.ids();
            let black_box = |file: &_, offset, into: &mut [u8]| tlog::read(&shared.black_box, file, offset, into, ids);
            let contents = crate::update::Contents {
                params: params.as_ref(),
                crash: crash.as_ref(),
                black_box: Some(&black_box),
            };
            let len = self.framer.frame_ftp(to, reply, &contents).len();
            self.append(len, lbv::FILE_TRANSFER_PROTOCOL_DATA::EXTRA_CRC);
        }
        let _ = (to, reply, shared);
    }

    /// Frame `message` into the batch, signed when a key is in force; a frame that does not fit is counted as a
    /// write error.
    fn push<D: MessageData>(&mut self, message: &D) {
        let len = self.framer.frame(message).len();
        self.append(len, D::EXTRA_CRC);
    }

    /// Take the `len`-byte frame the framer holds into the batch, signing it when a key is in force (not generic:
    /// one copy for every message type); a frame that does not fit is counted as a write error.
    #[inline(never)]
    fn append(&mut self, len: usize, extra_crc: u8) {
        match self.batch.get_mut(self.len..self.len + len) {
            Some(slot) => slot.copy_from_slice(self.framer.last(len)),
            None => return ConsoleStats::count(&self.stats.write_errors, 1),
        }
        let signed = match (self.key, self.batch.get_mut(self.len..)) {
            (Some(key), Some(rest)) => self
                .stats
                .signing(Some(key), |signing| signing.sign(rest, len, extra_crc)),
            _ => Some(len),
        };
        match signed {
            Some(len) => {
                self.len += len;
                self.frames += 1;
            }
            // No room left for the signature, or none in the signing reservation.
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
