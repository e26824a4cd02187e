//! An update image's way into a thruster: written into its DFU partition over the thruster's own bus with
//! tmc-proto's extension ([`tmc_proto::ext`]; docs/thruster.md, "Field-update extension"), then applied.
//!
//! The master has no room for a whole image, so the bytes go on as the ground station sends them. The update
//! server's sink (`update::VehicleSink`) gathers them a flash page (2 KiB) at a time in [`Transfers`], and the bus
//! task of the thruster's bus writes each page between its polls, in exchanges (a command and its reply) that fill
//! the rest of each poll cycle while the vehicle is disarmed (`thrusters::bus_task`), so every thruster of the bus,
//! the one being updated too, keeps being polled. The console reads on once there is room for the next write's
//! bytes: the upload goes at the pace of the bus.
//!
//! The [`Courier`] is the whole transfer as a state machine on explicit time, fed the exchanges' outcomes:
//!
//! 1. `Version`: the thruster speaks the extension (an IDS-only controller answers with its status frame) and can
//!    check signatures (otherwise it could never take the image: refused before anything is sent).
//! 2. `Begin` with the payload's length and the update file's target byte (the thruster refuses another family).
//! 3. For each page: `Check` what the thruster holds there; a page it already holds (from a transfer that was
//!    interrupted) is not written again, so sending the same file again resumes. Otherwise `Erase` it and `Write`
//!    it in 64-byte chunks, each chunk's read-back CRC compared with the bytes sent. Before the first page goes on,
//!    its image info (payload offset 0x200, signed) is held to the header and to the image the thruster runs
//!    (update-image's `check` and `check_upgrade`): the header's version must be the payload's, the info of format
//!    2, the image not older than the running one unless signed as a rollback, its security counter not below the
//!    running image's. A refusal ends the transfer with its sentence, nothing written.
//! 4. `Check` of the whole payload against the CRC of every byte received: written and verified.
//! 5. On the apply command: `Finish` (the thruster checks the image's information record, writes the ticket its
//!    bootloader checks the image with, and marks it), `Reboot`, then `Version` until it answers again, running the
//!    new version on trial, and then until it has confirmed itself: the apply command's final COMMAND_ACK says
//!    ACCEPTED only then (a reset before that and the bootloader reverts it: FAILED, "reverted to 0.1.0"). Its
//!    bootloader checks the signature before it swaps: one that refuses starts the old image again, whose `Version`
//!    carries the verdict ("T1: refused by its bootloader: signature", FAILED).
//!
//! An exchange that fails (no answer, a bus error, a reply that does not decode, or one still busy) is sent again
//! at the next cycle with the same sequence number (every command can be repeated); a thruster silent for
//! [`SILENCE_LIMIT`] ends the transfer. A thruster that reset meanwhile answers `NotBegun`: the courier begins
//! again and goes on with the page it holds. Any other refusal ends the transfer with the refusal's own sentence,
//! and so does a read-back that differs.
//!
//! The courier also keeps what each thruster's last `Version` said of its images ([`Courier::hold`]): whether one is
//! on trial or holds an update marked for its bootloader, either of which ends in a reset the vehicle must not take
//! in the water, so it keeps the vehicle from arming ([`UpdateHold`]). It learns it from every `Version` it reads
//! (a transfer's, a version query's), and it asks for it itself: a thruster that answers its polls again (at the
//! master's start, or after it was offline) may have reset into a swap or a revert, or have been marked while the
//! master was reset, and a power cycle of the vehicle brings every thruster back on whatever its bootloader started,
//! on trial perhaps; tracking only what the master saw would miss those. So each thruster is asked as soon as it
//! answers (and holds the vehicle until it has said), and one on trial is asked again every [`TRIAL_ASK`] until it
//! has confirmed itself. These looks, and the ground station's version queries, go on the bus when no transfer has an
//! exchange to make (none, one written whole and waiting for its apply, or one waiting for its next page), one at a
//! time, and a transfer's exchanges wait while one is under way.

use core::cell::RefCell;

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Timer};
use embedded_hal_async::i2c::I2c;
use tmc_proto::ext::{
    self, Chunk, Command, CommandFrame, CommandKind, Crc32, FrameError, MAX_CHUNK, Refusal, Reply, ReplyBody,
    SIGNATURE_LEN,
};
use update_image::{Header, HeaderError, INFO_OFFSET, ImageInfo, MIN_PAYLOAD, Target, Version, check_upgrade};

use crate::shared::{
    AckResult, MAX_THRUSTERS, Outgoing, Sender, Severity, Shared, UpdateAction, UpdateHold, texts, verdict_texts,
};

/// A flash page of the thruster's DFU partition: what the sink gathers before it goes on.
const PAGE: usize = ext::PAGE_LEN as usize;
/// The most bytes the sink is handed at once: one MAVLink FTP write's data.
pub const MAX_WRITE: usize = 239;
/// The sink's buffer: a page, and room for one write beyond it.
const BUFFER: usize = PAGE + MAX_WRITE;
/// The update file's header, before the payload: its signature is the last 64 bytes.
const FILE_HEADER_LEN: usize = 80;
/// A thruster that answers no exchange for this long is given up.
pub(crate) const SILENCE_LIMIT: Duration = Duration::from_secs(3);
/// After `Reboot`, the bootloader swaps the image in (two erases and a write per page of ACTIVE, some 2.5 s for
/// 29 pages on the G431) before the thruster answers again: it has this long.
pub(crate) const RESTART_LIMIT: Duration = Duration::from_secs(15);
/// The first `Version` after `Reboot` is sent this long after it.
const RESTART_FIRST_ASK: Duration = Duration::from_millis(200);
/// A new image on trial confirms itself after 3 s of every task healthy and 25 orders from the master
/// (docs/thruster.md, "A new image on trial"): an upload waits this long for a running image on trial to confirm
/// before it gives up, and an apply tells every so long that its new image is still on trial. The apply itself
/// waits for as long as the thruster runs the new image on trial: its final answer is what the thruster did,
/// confirmed or reverted, and a thruster kept from confirming (driven, or unwell) may still confirm later.
pub(crate) const CONFIRM_LIMIT: Duration = Duration::from_secs(30);
/// While an image is on trial, `Version` is asked this often.
pub(crate) const TRIAL_ASK: Duration = Duration::from_millis(500);
/// A reply read busy is read again this often, up to [`BUSY_READS`] times in one exchange; then the command is
/// sent again at the next cycle.
const BUSY_PAUSE: Duration = Duration::from_millis(2);
const BUSY_READS: u32 = 20;
/// Times a thruster may be found reset within one transfer before it is given up.
const RESTARTS_LIMIT: u8 = 3;

/// Where the bus task is in a transfer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
enum Step {
    /// Ask what runs, and whether the thruster speaks the extension.
    Hello,
    /// Begin the payload.
    Begin,
    /// Wait for the sink's next page.
    Idle,
    /// Compare the page at the buffer's start with what the thruster holds.
    CheckPage,
    /// Erase that page.
    Erase,
    /// Write the chunk at this offset within the page.
    Write(u16),
    /// Compare the whole payload.
    Verify,
    /// Written and verified: wait for the apply command.
    Written,
    /// Have the thruster check and mark the image.
    Finish,
    /// Have it reset into its bootloader.
    Reboot,
    /// Wait for it to answer again, since the reboot.
    Restart(Instant),
    /// The new image runs on trial, since then: wait for it to confirm itself, asking again at `next`.
    Trial { since: Instant, next: Instant },
    /// The thruster's running image is on trial, so it takes no update yet: begin again at this instant.
    Settle(Instant),
}

/// One image on its way to one thruster.
#[derive(Debug, Clone, Copy)]
struct Transfer {
    slot: u8,
    /// The update file's target byte.
    kind: u8,
    payload_len: u32,
    /// The image's version, as its header gives it.
    version: [u8; 4],
    signature: [u8; SIGNATURE_LEN],
    step: Step,
    /// Payload bytes the sink took.
    received: u32,
    /// Their CRC.
    crc: Crc32,
    /// The sink has every byte.
    complete: bool,
    /// Where the buffer's first byte goes in the payload: the page being written.
    page_offset: u32,
    /// Pages the thruster held already.
    skipped: u16,
    seq: u8,
    /// When the exchanges of this step began failing, none answered since.
    silent_since: Option<Instant>,
    /// Times the thruster was found reset.
    restarts: u8,
    /// Who applies it: the final COMMAND_ACK goes there.
    applier: Option<Sender>,
    /// Since when `Begin` has been refused because the running image is on trial.
    settling_since: Option<Instant>,
    /// The running image's information record, as the thruster's last `Version` gave it: what the image is held to.
    running: [u8; ext::INFO_LEN],
    /// The longest payload the thruster takes, as its last `Version` gave it.
    max_payload: u32,
}

impl Transfer {
    /// A transfer of a `payload_len` image to `slot` (`kind` its target byte), at its first step.
    fn new(slot: u8, kind: u8, payload_len: u32, version: [u8; 4], signature: [u8; SIGNATURE_LEN]) -> Self {
        Self {
            slot,
            kind,
            payload_len,
            version,
            signature,
            step: Step::Hello,
            received: 0,
            crc: Crc32::new(),
            complete: false,
            page_offset: 0,
            skipped: 0,
            seq: 0,
            silent_since: None,
            restarts: 0,
            applier: None,
            settling_since: None,
            running: [0; ext::INFO_LEN],
            max_payload: 0,
        }
    }

    /// Whether it is being applied: asked to, or marked and restarting into it (an update the thruster held).
    fn applying(&self) -> bool {
        self.applier.is_some()
            || matches!(
                self.step,
                Step::Finish | Step::Reboot | Step::Restart(_) | Step::Trial { .. }
            )
    }

    /// What the thruster's `Version` says of the image it runs.
    fn heard(&mut self, info: [u8; ext::INFO_LEN], max_payload: u32) {
        self.running = info;
        self.max_payload = max_payload;
    }

    /// Whether the image whose first page (or whole payload, if shorter) is `first` may go on: its signed image
    /// info against the header (update-image's `check`: length, target, version, an info of format 2) and against
    /// the image the thruster runs (`check_upgrade`, its counter the floor: the master does not read the
    /// bootloader's own).
    fn check_image(&self, first: &[u8]) -> Result<(), update_image::Refusal> {
        use update_image::Refusal as Why;
        let target = Target::from_byte(self.kind).ok_or(Why::Header(HeaderError::Target(self.kind)))?;
        let header = Header {
            target,
            payload_len: self.payload_len,
            version: Version::from_bytes(self.version),
            signature: self.signature,
        };
        let info = match ImageInfo::parse(first.get(INFO_OFFSET..).unwrap_or_default()) {
            Ok(info) => info,
            Err(_) if self.payload_len < MIN_PAYLOAD => return Err(Why::TooShort { len: self.payload_len }),
            Err(error) => return Err(Why::Info(error)),
        };
        update_image::check(&header, &info, target, self.max_payload)?;
        let running = ImageInfo::parse(&self.running).ok();
        check_upgrade(
            &info,
            running.as_ref(),
            running.map_or(0, |running| running.security_counter),
        )
    }
}

/// What a bus task sends next, to whom.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Exchange {
    /// The thruster's slot in the table.
    pub slot: u8,
    /// The command and its sequence number.
    pub frame: CommandFrame,
    /// How long to wait before the reply is read: a page erase stalls the thruster's CPU, the signature check
    /// takes time.
    pub(crate) wait: Duration,
}

impl Exchange {
    /// What its reply is read against: the few bytes of it a bus task keeps while the exchange is on the bus.
    pub(crate) fn sent(&self) -> Sent {
        Sent {
            slot: self.slot,
            seq: self.frame.seq,
            command: self.frame.command.kind(),
            wait: self.wait,
        }
    }
}

/// An exchange's command as sent: whom to, its sequence number and kind, and the wait before its reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Sent {
    /// The thruster's slot in the table.
    pub(crate) slot: u8,
    /// The command's sequence number.
    pub(crate) seq: u8,
    /// Which command.
    pub(crate) command: CommandKind,
    /// As [`Exchange::wait`].
    pub(crate) wait: Duration,
}

impl From<&Exchange> for Sent {
    fn from(exchange: &Exchange) -> Self {
        exchange.sent()
    }
}

/// Why an exchange got no reply to its command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum ExchangeError {
    /// The bus transfer failed (no acknowledge, a timeout, a bus error).
    Bus,
    /// What was read is not an extension reply: from an IDS-only controller, a status frame (its type is in the
    /// error).
    Frame(FrameError),
    /// Still busy after every read.
    Busy,
}

/// A transfer that ends early, and why: what the operator is told.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Ending {
    Refused(Refusal),
    /// The image's own info refused it, before anything was written.
    Image(update_image::Refusal),
    /// The thruster came back on its old image, its bootloader having refused the new one: its verdict's code.
    Verdict(u8),
    NoExtension,
    Silent,
    ReadBack,
    Mismatch,
    Restarts,
    NotBack,
    OldVersion([u8; 4]),
    Reverted([u8; 4]),
}

impl core::fmt::Display for Ending {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            Ending::Refused(refusal) => f.write_str(refusal.describe()),
            Ending::Image(refusal) => write!(f, "{refusal}"),
            Ending::Verdict(_) => f.write_str(BOOTLOADER_REFUSED),
            Ending::NoExtension => f.write_str("the thruster does not take updates"),
            Ending::Silent => f.write_str("the thruster stopped answering"),
            Ending::ReadBack => f.write_str("the flash read back differs"),
            Ending::Mismatch => f.write_str("the thruster's copy differs"),
            Ending::Restarts => f.write_str("the thruster keeps resetting"),
            Ending::NotBack => f.write_str("the thruster did not come back"),
            Ending::OldVersion(version) => write!(f, "still runs {}", Ver(version)),
            Ending::Reverted(version) => write!(f, "reverted to {}", Ver(version)),
        }
    }
}

/// What a thruster's bootloader did to the image it was to swap in, its verdict after it.
const BOOTLOADER_REFUSED: &str = "refused by its bootloader";

/// What the courier does not take: a call for a transfer it does not have (ended, or never begun), bytes out of
/// order or beyond its buffer, an image whose header lacks its fields.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NotTaken;

/// What the master knows of a thruster's images, by the last `Version` it answered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
enum Standing {
    /// Not answering its polls (or not in the table), and never asked since: asked once it answers.
    Away,
    /// Answering, not asked yet: it may have come up on trial.
    Unasked,
    /// Runs a confirmed image and holds no mark, or takes no update.
    Settled,
    /// Its image is on trial: asked again every [`TRIAL_ASK`].
    OnTrial,
    /// It holds an update marked for its bootloader.
    Marked,
}

impl Standing {
    /// What a `Version` reply says.
    fn of(on_trial: bool, marked: bool) -> Self {
        match (on_trial, marked) {
            (_, true) => Self::Marked,
            (true, _) => Self::OnTrial,
            _ => Self::Settled,
        }
    }
}

/// A `Version` asked alone: the ground station's version query, or the master's own look at a thruster.
#[derive(Debug, Clone, Copy)]
struct Query {
    slot: u8,
    seq: u8,
    /// Who asked (MAV_CMD_LBV_QUERY_VERSION), told what runs; `None`: the master's own look, asked once per turn.
    asker: Option<Sender>,
    /// When its exchanges began failing, none answered since.
    silent_since: Option<Instant>,
}

/// The transfer under way and the bytes waiting for the thruster, the version query, and what each thruster's
/// images are: the state [`crate::update::VehicleSink`] and the bus tasks share.
#[derive(Debug)]
pub struct Courier {
    transfer: Option<Transfer>,
    buffer: [u8; BUFFER],
    fill: usize,
    query: Option<Query>,
    /// The last query's sequence number.
    query_seq: u8,
    /// Each slot's thruster, by its last `Version`.
    standing: [Standing; MAX_THRUSTERS],
    /// When the thrusters on trial are next asked.
    trial_ask: Instant,
}

impl Default for Courier {
    fn default() -> Self {
        Self::new()
    }
}

impl Courier {
    /// Nothing under way.
    pub const fn new() -> Self {
        Self {
            transfer: None,
            buffer: [0; BUFFER],
            fill: 0,
            query: None,
            query_seq: 0,
            standing: [Standing::Away; MAX_THRUSTERS],
            trial_ask: Instant::from_ticks(0),
        }
    }

    /// Whether the sink may hand on one more write's bytes.
    pub fn has_room(&self) -> bool {
        self.transfer.is_none() || self.fill + MAX_WRITE <= BUFFER
    }

    /// An image for `slot` begins: `header` is its update file's header, which the update server has checked
    /// (`kind` its target byte, `payload_len` its payload's length). One under way for another thruster is dropped,
    /// unless it is being applied.
    pub fn begin(
        &mut self,
        slot: u8,
        kind: u8,
        payload_len: u32,
        header: &[u8; FILE_HEADER_LEN],
    ) -> Result<(), NotTaken> {
        if self.transfer.is_some_and(|t| t.applier.is_some()) {
            return Err(NotTaken);
        }
        let [.., v0, v1, v2, v3] = *header.first_chunk::<16>().ok_or(NotTaken)?;
        let signature = *header.last_chunk::<SIGNATURE_LEN>().ok_or(NotTaken)?;
        self.transfer = Some(Transfer::new(slot, kind, payload_len, [v0, v1, v2, v3], signature));
        self.fill = 0;
        Ok(())
    }

    /// Ask thruster `slot` which image it runs, for `from`: the answer goes out as a text (`runs 0.2.0`) and the
    /// final COMMAND_ACK of MAV_CMD_LBV_QUERY_VERSION. Whenever no transfer has an exchange to make (an image
    /// written whole and not applied waits meanwhile); refused, saying why, while one has, or while another query
    /// runs.
    pub fn query(&mut self, slot: u8, from: Sender) -> Result<(), &'static str> {
        if !self.quiet() {
            return Err("wait: an update is under way");
        }
        if self.query.is_some_and(|query| query.asker.is_some()) {
            return Err("wait: another query is under way");
        }
        // It takes the place of the master's own look, which asks again at its next turn.
        self.ask(slot, Some(from));
        Ok(())
    }

    /// A query of `slot` begins.
    fn ask(&mut self, slot: u8, asker: Option<Sender>) {
        self.query_seq = self.query_seq.wrapping_add(1);
        self.query = Some(Query {
            slot,
            seq: self.query_seq,
            asker,
            silent_since: None,
        });
    }

    /// Whether the transfer has no exchange to make: there is none, it waits for its apply, or for its next page.
    fn quiet(&self) -> bool {
        self.transfer.is_none_or(|transfer| match transfer.step {
            Step::Written => true,
            Step::Idle => !transfer.complete && self.page().is_none(),
            _ => false,
        })
    }

    /// The first `count` slots have thrusters, which have not said yet what they run: at the master's start, each
    /// is asked once it answers its polls (one that does not answer its first is not waited for, [`Courier::seen`]).
    pub(crate) fn expect(&mut self, count: usize) {
        for standing in self.standing.iter_mut().take(count) {
            *standing = Standing::Unasked;
        }
    }

    /// Thruster `slot` answers its polls again (`true`: it may have reset, into a swap or a revert; it is asked
    /// what it runs), or it stopped answering (one never asked is not waited for; what one said stays).
    pub(crate) fn seen(&mut self, slot: u8, answering: bool) {
        if let Some(standing) = self.standing.get_mut(usize::from(slot)) {
            *standing = match (*standing, answering) {
                (_, true) => Standing::Unasked,
                (Standing::Unasked, false) => Standing::Away,
                (standing, false) => standing,
            };
        }
    }

    /// What of the thrusters' updates keeps the vehicle from arming: an apply under way, then a thruster that
    /// holds a mark, runs an image on trial, or has not said yet what it runs.
    pub(crate) fn hold(&self) -> Option<UpdateHold> {
        if let Some(transfer) = self.transfer.filter(Transfer::applying) {
            return Some(UpdateHold::Applying(transfer.slot));
        }
        (0..).zip(self.standing).find_map(|(slot, standing)| match standing {
            Standing::Marked => Some(UpdateHold::Marked(slot)),
            Standing::OnTrial => Some(UpdateHold::OnTrial(slot)),
            Standing::Unasked => Some(UpdateHold::Unasked(slot)),
            Standing::Away | Standing::Settled => None,
        })
    }

    /// Who applies the image of `slot` under way, if it is being applied.
    pub(crate) fn applier(&self, slot: u8) -> Option<Sender> {
        self.transfer.filter(|t| t.slot == slot).and_then(|t| t.applier)
    }

    /// The payload's next bytes, at `offset` from the payload's start.
    pub fn write(&mut self, offset: u32, data: &[u8]) -> Result<(), NotTaken> {
        let fill = self.fill;
        let transfer = self
            .transfer
            .as_mut()
            .filter(|t| !t.complete && t.received == offset)
            .ok_or(NotTaken)?;
        let room = self.buffer.get_mut(fill..fill + data.len()).ok_or(NotTaken)?;
        room.copy_from_slice(data);
        self.fill += data.len();
        transfer.received += data.len() as u32;
        transfer.crc = transfer.crc.update(data);
        Ok(())
    }

    /// The upload is over: `complete` when every byte came (the last page goes on, then the whole payload is
    /// checked), otherwise the transfer is dropped (what the thruster holds stays, for a resumed transfer).
    pub fn finish(&mut self, complete: bool) -> Result<(), NotTaken> {
        match self.transfer.as_mut() {
            Some(transfer) if complete && transfer.received == transfer.payload_len => {
                transfer.complete = true;
                Ok(())
            }
            Some(transfer) if transfer.applier.is_none() => {
                self.transfer = None;
                self.fill = 0;
                if complete { Err(NotTaken) } else { Ok(()) }
            }
            _ => Err(NotTaken),
        }
    }

    /// The apply command for `slot`, from `from`: `Ok(true)` when the thruster is to take it now (the final
    /// COMMAND_ACK goes to `from`), `Ok(false)` when it is still on its way there, an error when it is not (it
    /// failed, or never came).
    pub fn apply(&mut self, slot: u8, from: Sender) -> Result<bool, NotTaken> {
        match self.transfer.as_mut().filter(|t| t.slot == slot) {
            Some(transfer) if transfer.step == Step::Written => {
                transfer.step = Step::Finish;
                transfer.applier = Some(from);
                transfer.silent_since = None;
                Ok(true)
            }
            Some(transfer) if transfer.applier.is_none() && transfer.complete => Ok(false),
            _ => Err(NotTaken),
        }
    }

    /// Whether thruster `slot` has been told to restart into its update and has not answered since: silent while
    /// its bootloader swaps the image in, as it should be.
    pub(crate) fn restarting(&self, slot: u8) -> bool {
        self.transfer
            .is_some_and(|t| t.slot == slot && matches!(t.step, Step::Reboot | Step::Restart(_)))
    }

    /// The page at the buffer's start, once it is whole (or the payload's last).
    fn page(&self) -> Option<&[u8]> {
        let transfer = self.transfer.as_ref()?;
        let len = self.fill.min(PAGE);
        let last = transfer.complete && transfer.page_offset + len as u32 == transfer.payload_len;
        (len == PAGE || last && len > 0)
            .then(|| self.buffer.get(..len))
            .flatten()
    }

    /// The next exchange, at `now`, if its thruster is one `ours` says yes to (one of the asking bus task's).
    // Out of line: every bus task calls it, and its code would be copied into each.
    #[inline(never)]
    pub fn next(&mut self, now: Instant, ours: impl Fn(u8) -> bool) -> Option<Exchange> {
        if self.query.is_none() && self.quiet() {
            let due =
                |standing| standing == Standing::Unasked || standing == Standing::OnTrial && now >= self.trial_ask;
            let slot = (0..)
                .zip(self.standing)
                .find(|(slot, standing)| ours(*slot) && due(*standing));
            if let Some((slot, _)) = slot {
                self.ask(slot, None);
            }
        }
        // One at a time: a transfer waits for the query's end.
        if let Some(query) = self.query {
            return self.exchange(query.slot, query.seq, Command::Version, None, ours);
        }
        let page = self.page().map(|page| (page.len() as u32, ext::crc32(page)));
        let chunk = |at: u16| {
            let start = usize::from(at);
            let end = page.map_or(start, |(len, _)| (len as usize).min(start + MAX_CHUNK));
            self.buffer.get(start..end).and_then(Chunk::new)
        };
        let transfer = self.transfer.as_ref()?;
        let step = match (transfer.step, page) {
            (Step::Idle, Some(_)) => Step::CheckPage,
            (Step::Idle, None) if transfer.complete && transfer.page_offset == transfer.payload_len => Step::Verify,
            (Step::Restart(since), _) if now < since + RESTART_FIRST_ASK => return None,
            (Step::Trial { next, .. } | Step::Settle(next), _) if now < next => return None,
            (Step::Settle(_), _) => Step::Begin,
            (step, _) => step,
        };
        let command = match step {
            Step::Hello | Step::Restart(_) | Step::Trial { .. } => Command::Version,
            Step::Begin => Command::Begin {
                payload_len: transfer.payload_len,
                target: transfer.kind,
            },
            // Turned into `Begin` above once it is time.
            Step::Idle | Step::Written | Step::Settle(_) => return None,
            Step::CheckPage => Command::Check {
                offset: transfer.page_offset,
                len: page?.0,
            },
            Step::Erase => Command::Erase {
                page: u16::try_from(transfer.page_offset / ext::PAGE_LEN).ok()?,
            },
            Step::Write(at) => Command::Write {
                offset: transfer.page_offset + u32::from(at),
                data: chunk(at)?,
            },
            Step::Verify => Command::Check {
                offset: 0,
                len: transfer.payload_len,
            },
            Step::Finish => Command::Finish {
                payload_len: transfer.payload_len,
                signature: transfer.signature,
            },
            Step::Reboot => Command::Reboot,
        };
        self.exchange(transfer.slot, transfer.seq, command, Some(step), ours)
    }

    /// The exchange of `command` to `slot`, if `ours` says it is the asking bus task's; the transfer moves to `step`
    /// as it goes on the bus.
    fn exchange(
        &mut self,
        slot: u8,
        seq: u8,
        command: Command,
        step: Option<Step>,
        ours: impl Fn(u8) -> bool,
    ) -> Option<Exchange> {
        if !ours(slot) {
            return None;
        }
        let wait = match command {
            Command::Erase { .. } => ext::ERASE_WAIT_MS,
            Command::Finish { .. } => ext::FINISH_WAIT_MS,
            _ => 0,
        };
        if let (Some(transfer), Some(step)) = (self.transfer.as_mut(), step) {
            transfer.step = step;
        }
        Some(Exchange {
            slot,
            frame: CommandFrame { seq, command },
            wait: Duration::from_millis(u64::from(wait)),
        })
    }

    /// What `exchange` got, at `now`: the transfer moves on, or ends; `out` takes the texts and the apply
    /// command's final acknowledgement.
    #[inline(never)]
    pub fn on_result(
        &mut self,
        now: Instant,
        exchange: impl Into<Sent>,
        result: Result<Reply, ExchangeError>,
        out: &mut impl FnMut(Outgoing),
    ) {
        let exchange: Sent = exchange.into();
        if let Some(query) = self
            .query
            .filter(|query| query.slot == exchange.slot && exchange.command == CommandKind::Version)
        {
            return self.answered(now, query, result, out);
        }
        let page = self.page().map(|page| (page.len(), ext::crc32(page)));
        let Some(transfer) = self.transfer.as_mut().filter(|t| t.slot == exchange.slot) else {
            return;
        };
        let slot = transfer.slot;
        let reply = match result {
            Ok(reply) if reply.seq() == exchange.seq && reply.command() == exchange.command => reply,
            Err(ExchangeError::Frame(FrameError::MessageType { .. })) if transfer.step == Step::Hello => {
                return self.end(Ending::NoExtension, out);
            }
            _ => {
                // Sent again at the next cycle, unless the thruster has been silent too long. While it restarts
                // it has its own limit.
                let since = *transfer.silent_since.get_or_insert(now);
                let limit = match transfer.step {
                    Step::Restart(rebooted) => now >= rebooted + RESTART_LIMIT,
                    // A reset on trial brings the bootloader's revert first; one told to restart may have before
                    // its reply was read whole (a reset tears the transfer it lands in), and is swapping.
                    Step::Trial { .. } | Step::Reboot => now >= since + RESTART_LIMIT,
                    _ => now >= since + SILENCE_LIMIT,
                };
                if limit {
                    let ending = match transfer.step {
                        Step::Restart(_) | Step::Trial { .. } | Step::Reboot => Ending::NotBack,
                        _ => Ending::Silent,
                    };
                    self.end(ending, out);
                }
                return;
            }
        };
        transfer.silent_since = None;
        transfer.seq = transfer.seq.wrapping_add(1);
        let body = match reply {
            Reply::Done { body, .. } => body,
            // A reset thruster forgets what it began: begin again, then go on with the page held.
            Reply::Refused {
                refusal: Refusal::NotBegun,
                ..
            } if !matches!(transfer.step, Step::Hello | Step::Begin | Step::Reboot) => {
                transfer.restarts += 1;
                if transfer.restarts > RESTARTS_LIMIT {
                    return self.end(Ending::Restarts, out);
                }
                transfer.step = Step::Begin;
                return;
            }
            // Reset between Finish and Reboot: the bootloader has swapped the image in already.
            Reply::Refused {
                refusal: Refusal::NotFinished | Refusal::NotBegun,
                ..
            } if transfer.step == Step::Reboot => {
                transfer.step = Step::Restart(now);
                return;
            }
            // Reset during Finish, after it marked the image: the bootloader has swapped it in.
            Reply::Refused {
                refusal: Refusal::OnTrial,
                ..
            } if transfer.applier.is_some() => {
                transfer.step = Step::Restart(now);
                return;
            }
            // An image on trial takes no update until it has confirmed itself: wait for that.
            Reply::Refused {
                refusal: Refusal::OnTrial,
                ..
            } if transfer.step == Step::Begin && now < *transfer.settling_since.get_or_insert(now) + CONFIRM_LIMIT => {
                transfer.step = Step::Settle(now + TRIAL_ASK);
                return;
            }
            // The thruster holds a finished update, signed and checked, that an apply whose master was reset left
            // unstarted: start it, then begin once it has confirmed itself.
            Reply::Refused {
                refusal: Refusal::Finished,
                ..
            } if transfer.step == Step::Begin && transfer.applier.is_none() => {
                say(out, Severity::Info, slot, format_args!("starting the update it holds"));
                transfer.step = Step::Reboot;
                return;
            }
            Reply::Refused { refusal, .. } => return self.end(Ending::Refused(refusal), out),
            // Not returned by the exchange: read again.
            Reply::Busy { .. } => return,
        };
        // What the thruster's images are now, for arming (its first `Version` said whether it runs one on trial or
        // holds one marked, which `Begin` is refused for; once it is applied, the apply holds the vehicle).
        if let ReplyBody::Version { on_trial, marked, .. } = body
            && let Some(standing) = self.standing.get_mut(usize::from(slot))
        {
            *standing = Standing::of(on_trial, marked);
        }
        let page_len = page.map_or(0, |(len, _)| len);
        transfer.step = match (transfer.step, body) {
            (
                Step::Hello,
                ReplyBody::Version {
                    checks_signatures,
                    info,
                    max_payload,
                    ..
                },
            ) => {
                if !checks_signatures {
                    return self.end(Ending::Refused(Refusal::NoSignatureCheck), out);
                }
                transfer.heard(info, max_payload);
                Step::Begin
            }
            // Begun again after a reset while being applied: the payload is whole in DFU already.
            (Step::Begin, ReplyBody::Begin { .. }) => {
                transfer.settling_since = None;
                if transfer.applier.is_some() {
                    Step::Finish
                } else {
                    Step::Idle
                }
            }
            // Nothing of the image has gone on yet: its info decides whether anything does.
            (Step::CheckPage, ReplyBody::Check { .. })
                if transfer.page_offset == 0
                    && let Err(refusal) = transfer.check_image(self.buffer.get(..page_len).unwrap_or_default()) =>
            {
                return self.end(Ending::Image(refusal), out);
            }
            (Step::CheckPage, ReplyBody::Check { crc, .. }) if page.is_some_and(|(_, page_crc)| page_crc == crc) => {
                transfer.skipped += 1;
                return self.page_done(page_len);
            }
            (Step::CheckPage, ReplyBody::Check { .. }) => Step::Erase,
            (Step::Erase, ReplyBody::Erase { .. }) => Step::Write(0),
            (Step::Write(at), ReplyBody::Write { len, crc, .. }) => {
                let start = usize::from(at);
                let sent = self.buffer.get(start..start + usize::from(len)).map(ext::crc32);
                if sent != Some(crc) {
                    return self.end(Ending::ReadBack, out);
                }
                let next = start + usize::from(len);
                if next >= page_len {
                    return self.page_done(page_len);
                }
                Step::Write(u16::try_from(next).unwrap_or(u16::MAX))
            }
            (Step::Verify, ReplyBody::Check { crc, .. }) if crc == transfer.crc.finish() => {
                let (n, skipped) = (transfer.payload_len, transfer.skipped);
                say(
                    out,
                    Severity::Info,
                    slot,
                    format_args!(
                        "{n} B verified, {skipped} page{} kept",
                        if skipped == 1 { "" } else { "s" }
                    ),
                );
                Step::Written
            }
            (Step::Verify, ReplyBody::Check { .. }) => return self.end(Ending::Mismatch, out),
            (Step::Finish, ReplyBody::Finish { .. }) => Step::Reboot,
            (Step::Reboot, ReplyBody::Reboot) => {
                // Its bootloader checks the signature before it swaps: nothing says yet that it is good.
                if transfer.applier.is_some() {
                    say(
                        out,
                        Severity::Info,
                        slot,
                        format_args!("marked, restarting into its update"),
                    );
                }
                Step::Restart(now)
            }
            // Back from starting the update it held: now this one.
            (Step::Restart(_), ReplyBody::Version { info, max_payload, .. }) if transfer.applier.is_none() => {
                transfer.heard(info, max_payload);
                Step::Begin
            }
            (
                Step::Restart(_) | Step::Trial { .. },
                ReplyBody::Version {
                    info,
                    on_trial,
                    verdict,
                    ..
                },
            ) => {
                let running = version_in(&info);
                match transfer.step {
                    _ if running != transfer.version => {
                        let ending = match transfer.step {
                            Step::Restart(_) if verdict != 0 => Ending::Verdict(verdict),
                            Step::Restart(_) => Ending::OldVersion(running),
                            _ => Ending::Reverted(running),
                        };
                        return self.end(ending, out);
                    }
                    _ if !on_trial => {
                        say(out, Severity::Info, slot, format_args!("{} confirmed", Ver(running)));
                        self.acknowledge(AckResult::Accepted, out);
                        self.transfer = None;
                        return;
                    }
                    // Still on trial: said every so long, and watched until it confirms or is reverted.
                    Step::Trial { since, .. } if now >= since + CONFIRM_LIMIT => {
                        say(
                            out,
                            Severity::Warning,
                            slot,
                            format_args!("{} still on trial", Ver(running)),
                        );
                        Step::Trial {
                            since: now,
                            next: now + TRIAL_ASK,
                        }
                    }
                    Step::Trial { since, .. } => Step::Trial {
                        since,
                        next: now + TRIAL_ASK,
                    },
                    _ => {
                        say(
                            out,
                            Severity::Info,
                            slot,
                            format_args!("runs {}, on trial", Ver(running)),
                        );
                        Step::Trial {
                            since: now,
                            next: now + TRIAL_ASK,
                        }
                    }
                }
            }
            // A reply that does not fit the step: ask again.
            (step, _) => step,
        };
    }

    /// The page at the buffer's start is on the thruster: the next one moves up.
    fn page_done(&mut self, len: usize) {
        if let Some(transfer) = self.transfer.as_mut() {
            transfer.page_offset += len as u32;
            transfer.step = Step::Idle;
        }
        self.buffer.copy_within(len.min(self.fill)..self.fill, 0);
        self.fill = self.fill.saturating_sub(len);
    }

    /// What a query's `Version` got, at `now`: what the thruster runs, told to who asked.
    fn answered(
        &mut self,
        now: Instant,
        query: Query,
        result: Result<Reply, ExchangeError>,
        out: &mut impl FnMut(Outgoing),
    ) {
        let slot = query.slot;
        let standing = self.standing.get_mut(usize::from(slot));
        let ending = match result {
            Ok(Reply::Done {
                seq,
                body:
                    ReplyBody::Version {
                        info,
                        on_trial,
                        checks_signatures,
                        marked,
                        dev_key,
                        ..
                    },
            }) if seq == query.seq => {
                if let Some(standing) = standing {
                    *standing = Standing::of(on_trial, marked);
                }
                if query.asker.is_some() {
                    let trial = if on_trial { ", on trial" } else { "" };
                    let updates = if checks_signatures { "" } else { ", no updates" };
                    let marked = if marked { ", update marked" } else { "" };
                    let dev_key = if dev_key { ", dev key" } else { "" };
                    let running = Ver(version_in(&info));
                    say(
                        out,
                        Severity::Info,
                        slot,
                        format_args!("runs {running}{trial}{updates}{marked}{dev_key}"),
                    );
                }
                None
            }
            // An IDS-only controller answers with its status frame: it takes no update, and holds none.
            Err(ExchangeError::Frame(FrameError::MessageType { .. })) => {
                if let Some(standing) = standing {
                    *standing = Standing::Settled;
                }
                Some(Ending::NoExtension)
            }
            // The ground station's query rides out a noisy bus short of the silence limit; the master's own look
            // asks again at its next turn.
            _ => {
                let since = self
                    .query
                    .as_mut()
                    .map_or(now, |query| *query.silent_since.get_or_insert(now));
                if query.asker.is_some() && now < since + SILENCE_LIMIT {
                    return;
                }
                Some(Ending::Silent)
            }
        };
        self.query = None;
        self.trial_ask = now + TRIAL_ASK;
        if let Some(to) = query.asker {
            if let Some(ending) = ending {
                say(out, Severity::Warning, slot, format_args!("{ending}"));
            }
            out(Outgoing::CommandAck {
                command: UpdateAction::QueryVersion.command(),
                result: if ending.is_some() {
                    AckResult::Failed
                } else {
                    AckResult::Accepted
                },
                to,
            });
        }
    }

    /// The transfer ends early: the operator is told why, the applier gets FAILED. A thruster that was being
    /// applied an image is asked again what it runs.
    fn end(&mut self, ending: Ending, out: &mut impl FnMut(Outgoing)) {
        let Some(transfer) = self.transfer else {
            return;
        };
        if transfer.applying()
            && let Some(standing) = self.standing.get_mut(usize::from(transfer.slot))
        {
            *standing = Standing::Unasked;
        }
        match ending {
            // "T1: ", not "thruster0.lbvu: ": it is the thruster's bootloader that refused, and it leaves room for
            // the verdict.
            Ending::Verdict(code) => {
                let who = u16::from(transfer.slot) + 1;
                let (first, second) = verdict_texts(format_args!("T{who}"), BOOTLOADER_REFUSED, code.into());
                for text in [Some(first), second].into_iter().flatten() {
                    out(Outgoing::Text(Severity::Warning, text));
                }
            }
            _ => say(out, Severity::Warning, transfer.slot, format_args!("{ending}")),
        }
        self.acknowledge(AckResult::Failed, out);
        self.transfer = None;
        self.fill = 0;
    }

    /// The apply command's final COMMAND_ACK, if there was one.
    fn acknowledge(&self, result: AckResult, out: &mut impl FnMut(Outgoing)) {
        if let Some(transfer) = self.transfer
            && let Some(to) = transfer.applier
        {
            out(Outgoing::CommandAck {
                command: UpdateAction::Apply.command(),
                result,
                to,
            });
        }
    }
}

/// The version an image info record holds (major, minor, patch u16 LE, at its bytes 8..12).
fn version_in(info: &[u8]) -> [u8; 4] {
    info.get(8..12)
        .and_then(|v| <[u8; 4]>::try_from(v).ok())
        .unwrap_or_default()
}

/// A version as the image info holds it (major, minor, patch u16 LE), for a person: "0.2.0".
struct Ver([u8; 4]);

impl core::fmt::Display for Ver {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let [major, minor, p0, p1] = self.0;
        write!(f, "{major}.{minor}.{}", u16::from_le_bytes([p0, p1]))
    }
}

/// "thruster2.lbvu: `args`", as the update server names the file the ground station wrote (in two texts when one
/// cannot hold it: a refusal's sentence goes on in the second).
fn say(out: &mut impl FnMut(Outgoing), severity: Severity, slot: u8, args: core::fmt::Arguments<'_>) {
    let (first, second) = texts(format_args!("thruster{slot}.lbvu"), args);
    for text in [Some(first), second].into_iter().flatten() {
        out(Outgoing::Text(severity, text));
    }
}

/// The courier, where the console's sink and the bus tasks meet.
pub struct Transfers {
    courier: Mutex<CriticalSectionRawMutex, RefCell<Courier>>,
    /// Bus task -> sink: the courier moved on.
    moved: Signal<CriticalSectionRawMutex, ()>,
}

impl core::fmt::Debug for Transfers {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Transfers").finish_non_exhaustive()
    }
}

impl Default for Transfers {
    fn default() -> Self {
        Self::new()
    }
}

impl Transfers {
    /// Nothing under way.
    pub const fn new() -> Self {
        Self {
            courier: Mutex::new(RefCell::new(Courier::new())),
            moved: Signal::new(),
        }
    }

    /// Work on the courier.
    pub(crate) fn with<T>(&self, f: impl FnOnce(&mut Courier) -> T) -> T {
        self.courier.lock(|courier| f(&mut courier.borrow_mut()))
    }

    /// The next exchange for a thruster `ours` says yes to, if there is one.
    pub(crate) fn next(&self, ours: impl Fn(u8) -> bool) -> Option<Exchange> {
        self.with(|courier| courier.next(Instant::now(), ours))
    }

    /// Tell the vehicle what of the thrusters' updates keeps it from arming now ([`Courier::hold`]).
    // Out of line: the bus tasks call it at every change.
    #[inline(never)]
    pub(crate) fn publish(&self, shared: &Shared) {
        shared.holds.set_thrusters(self.with(|courier| courier.hold()));
    }

    /// What `exchange` got: `out` takes the texts and acknowledgements; the sink hears that the courier moved on.
    pub(crate) fn done(&self, exchange: Sent, result: Result<Reply, ExchangeError>, out: &mut impl FnMut(Outgoing)) {
        self.with(|courier| courier.on_result(Instant::now(), exchange, result, out));
        self.moved.signal(());
    }

    /// Wait until the sink may hand on one more write's bytes.
    pub(crate) async fn room(&self) {
        while !self.with(|courier| courier.has_room()) {
            self.moved.wait().await;
        }
    }
}

/// Send the command in `buffer` (an exchange's, encoded: its first `len` bytes) to the thruster at `address` and read
/// its reply into the same buffer, reading again while it is busy. The caller's one buffer is all the bytes kept
/// across the transfers: the bus task's future holds them once for each of the master's three buses.
pub(crate) async fn exchange<B: I2c>(
    bus: &mut B,
    address: u8,
    buffer: &mut [u8; ext::MAX_FRAME_LEN],
    len: usize,
    sent: &Sent,
) -> Result<Reply, ExchangeError> {
    let command = buffer.get(..len).ok_or(ExchangeError::Bus)?;
    bus.write(address, command).await.map_err(|_| ExchangeError::Bus)?;
    if sent.wait > Duration::from_ticks(0) {
        Timer::after(sent.wait).await;
    }
    let reply = buffer.get_mut(..ext::reply_len(sent.command)).unwrap_or_default();
    for _ in 0..BUSY_READS {
        bus.read(address, reply).await.map_err(|_| ExchangeError::Bus)?;
        match Reply::decode(reply) {
            Ok(Reply::Busy { .. }) => Timer::after(BUSY_PAUSE).await,
            Ok(reply) => return Ok(reply),
            Err(error) => return Err(ExchangeError::Frame(error)),
        }
    }
    Err(ExchangeError::Busy)
}

#[cfg(test)]
mod tests;
