//! An update image's way into a thruster: written into its DFU partition over the thruster's own bus with
//! tmc-proto's extension ([`tmc_proto::ext`]; docs/thruster.md, "Field-update extension"), then applied.
//!
//! The master has no room for a whole image, so the bytes go on as the ground station sends them. The update
//! server's sink (`update::VehicleSink`) gathers them a flash page (2 KiB) at a time in [`Transfers`], and the bus
//! task of the thruster's bus writes each page between its polls, in exchanges (a command and its reply) that fill
//! the rest of each poll cycle while the vehicle is disarmed (`thrusters::bus_task`), so every thruster of the bus,
//! the one being updated too, keeps being polled. The buffer holds a second page, which the console fills while the
//! first is written; it reads on once there is room for the next write's bytes: the upload goes at the pace of the
//! bus.
//!
//! An image for every thruster of a family (`thrusters-seabotix.lbvu`) has a transfer for each, which take turns on
//! the bus, or share a write when they are at the same step ([`Courier::next_cast`]); the page stays in the buffer
//! until each has it (or has ended), and one apply applies it to all, its final COMMAND_ACK once the last is done.
//! A thruster that runs the image already, confirmed (its `Version`'s image info is the one the first page holds), is
//! left be ([`Step::Runs`]): the family's file put again after one thruster was left behind, silent, goes to that
//! one alone, and the master tells it when it answers again ([`Courier::answered`]).
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
//!
//! The first `Version` a thruster answers after it came back, if it says extension protocol 2, is followed the same
//! way by the fetch of its post-mortem record: two `PostMortem` looks of 64 bytes each. [`Courier::on_result`]
//! returns the record whole ([`PostMortem`]); the bus task keeps it and tells it (`Shared::keep_post_mortem`).

use core::cell::RefCell;

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Timer};
use embedded_hal_async::i2c::I2c;
use tmc_proto::Family;
use tmc_proto::ext::{
    self, Chunk, Command, CommandFrame, CommandKind, Crc32, FrameError, MAX_CHUNK, RECORD_LEN, Refusal, Reply,
    ReplyBody, SIGNATURE_LEN,
};
use update_image::{Header, HeaderError, INFO_OFFSET, ImageInfo, MIN_PAYLOAD, Target, Version, check_upgrade};

use crate::ports::Applied;
use crate::shared::{
    AckResult, MAX_THRUSTERS, Outgoing, Sender, Severity, Shared, UpdateAction, UpdateHold, text, texts, verdict_texts,
};
use crate::update::sys::{ImageState, Running};

/// Progress reports (the upload's, a family apply's) come at most this often.
pub(crate) const PROGRESS_PERIOD: Duration = Duration::from_secs(1);
/// The file that carries an image to every thruster of `family`.
pub(crate) const fn family_file(family: Family) -> &'static str {
    match family {
        Family::SeaBotix => "thrusters-seabotix.lbvu",
        Family::Legacy => "thrusters-legacy.lbvu",
    }
}

/// A flash page of the thruster's DFU partition: what the sink gathers before it goes on.
const PAGE: usize = ext::PAGE_LEN as usize;
/// The most bytes the sink is handed at once: one MAVLink FTP write's data.
pub const MAX_WRITE: usize = 239;
/// The sink's buffer: the page being written, the next as the ground station sends it, and room for one write
/// beyond them.
const BUFFER: usize = 2 * PAGE + MAX_WRITE;
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
    /// It runs this image already, confirmed (a family's file: its image info is the one the thruster's last
    /// `Version` gave): nothing is written, and the apply leaves it be.
    Runs,
}

/// The image on its way: what its update file's header gives, and the bytes the sink has handed on, which every
/// transfer of it writes page by page in step ([`Courier::begin`]).
#[derive(Debug, Clone, Copy)]
struct Image {
    /// The update file's target byte.
    kind: u8,
    payload_len: u32,
    /// The image's version, as its header gives it.
    version: [u8; 4],
    signature: [u8; SIGNATURE_LEN],
    /// Payload bytes the sink took.
    received: u32,
    /// Their CRC.
    crc: Crc32,
    /// The sink has every byte.
    complete: bool,
    /// Where the buffer's first byte goes in the payload: the page being written.
    offset: u32,
    /// How the texts name its thrusters: it came in a slot's file, or in a family's.
    file: File,
    /// Who applies it: the final COMMAND_ACK goes there once every thruster it was applied to is done.
    applier: Option<Sender>,
    /// The slots it was applied to, as bits.
    applied: u8,
    /// The slots whose transfer of it failed, as bits.
    failed: u8,
    /// When the apply's progress was last told.
    reported: Instant,
}

impl Step {
    /// Whether the step's command may reach several thrusters in one write: it is the same for each at the same
    /// page, and what it does once is what it does again (a chunk the flash holds is not written twice).
    fn castable(self) -> bool {
        matches!(
            self,
            Step::Begin | Step::CheckPage | Step::Erase | Step::Write(_) | Step::Verify
        )
    }
}

impl Image {
    /// Whether the image whose first page (or whole payload, if shorter) is `first` may go on to a thruster whose
    /// last `Version` gave `running` and `max_payload`: its signed image info against the header (update-image's
    /// `check`: length, target, version, an info of format 2) and against the image the thruster runs
    /// (`check_upgrade`, its counter the floor: the master does not read the bootloader's own).
    fn check(
        &self,
        first: &[u8],
        running: &[u8; ext::INFO_LEN],
        max_payload: u32,
    ) -> Result<(), update_image::Refusal> {
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
        update_image::check(&header, &info, target, max_payload)?;
        let running = ImageInfo::parse(running).ok();
        check_upgrade(
            &info,
            running.as_ref(),
            running.map_or(0, |running| running.security_counter),
        )
    }
}

/// The file an image came in, which the texts name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum File {
    /// One slot's (`thruster2.lbvu`): the texts name the file.
    Slot,
    /// Every thruster of a family's (`thrusters-seabotix.lbvu`): the texts name each thruster (`T3`), and the
    /// apply's progress the file.
    Family(Family),
}

/// The image on its way to one thruster.
#[derive(Debug, Clone, Copy)]
struct Transfer {
    slot: u8,
    step: Step,
    /// Where the page it writes (or will) goes in the payload.
    page_offset: u32,
    /// Pages the thruster held already.
    skipped: u16,
    seq: u8,
    /// When the exchanges of this step began failing, none answered since.
    silent_since: Option<Instant>,
    /// Times the thruster was found reset.
    restarts: u8,
    /// The apply command has been given for it.
    applied: bool,
    /// Since when `Begin` has been refused because the running image is on trial.
    settling_since: Option<Instant>,
    /// The running image's information record, as the thruster's last `Version` gave it: what the image is held to.
    running: [u8; ext::INFO_LEN],
    /// The longest payload the thruster takes, as its last `Version` gave it.
    max_payload: u32,
}

impl Transfer {
    /// A transfer to `slot`, at its first step.
    fn new(slot: u8) -> Self {
        Self {
            slot,
            step: Step::Hello,
            page_offset: 0,
            skipped: 0,
            seq: 0,
            silent_since: None,
            restarts: 0,
            applied: false,
            settling_since: None,
            running: [0; ext::INFO_LEN],
            max_payload: 0,
        }
    }

    /// Whether it is being applied: asked to, or marked and restarting into it (an update the thruster held).
    fn applying(&self) -> bool {
        self.applied
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
}

/// What a bus task sends next, to whom.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Exchange {
    /// The thruster's slot in the table.
    pub slot: u8,
    /// The other thrusters the same write reaches (their slots as bits), each of whose replies is read alone:
    /// see [`Courier::next_cast`].
    pub with: u8,
    /// The command and its sequence number.
    pub frame: CommandFrame,
    /// How long to wait before the reply is read: a page erase stalls the thruster's CPU, the signature check
    /// takes time.
    pub(crate) wait: Duration,
}

impl Exchange {
    /// What its reply is read against: the few bytes of it a bus task keeps while the exchange is on the bus.
    pub(crate) fn sent(&self) -> Sent {
        self.sent_to(self.slot)
    }

    /// What the reply of `slot`, one of the thrusters the exchange's write reaches, is read against.
    pub fn sent_to(&self, slot: u8) -> Sent {
        Sent {
            slot,
            seq: self.frame.seq,
            command: self.frame.command.kind(),
            wait: self.wait,
        }
    }

    /// Every thruster the write reaches, its own slot first.
    pub fn slots(&self) -> impl Iterator<Item = u8> + Clone + use<> {
        let with = self.with & !bit(self.slot);
        core::iter::once(self.slot).chain((0..MAX_THRUSTERS as u8).filter(move |slot| with & bit(*slot) != 0))
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

/// What a [`Query`] reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Look {
    /// What runs: `Version`.
    Version,
    /// The post-mortem record's part from this offset: `PostMortem`.
    PostMortem(u8),
}

impl Look {
    fn command(self) -> Command {
        match self {
            Look::Version => Command::Version,
            Look::PostMortem(offset) => Command::PostMortem { offset },
        }
    }
}

/// A post-mortem record a thruster kept from the stop before its start, fetched whole ([`Courier::on_result`]):
/// its CRC is not checked yet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PostMortem {
    /// The thruster's slot.
    pub slot: u8,
    /// The record's bytes.
    pub record: [u8; RECORD_LEN],
}

/// An exchange of the master's own, one at a time: the ground station's version query, the master's look at what a
/// thruster runs, or its fetch of a thruster's post-mortem record.
#[derive(Debug, Clone, Copy)]
struct Query {
    slot: u8,
    look: Look,
    seq: u8,
    /// Who asked (MAV_CMD_LBV_QUERY_VERSION), told what runs; `None`: the master's own look, asked once per turn.
    asker: Option<Sender>,
    /// When its exchanges began failing, none answered since.
    silent_since: Option<Instant>,
}

/// The image under way and its bytes waiting for the thrusters, each thruster's transfer of it, the version query,
/// and what each thruster's images are: the state [`crate::update::VehicleSink`] and the bus tasks share.
#[derive(Debug)]
pub struct Courier {
    image: Option<Image>,
    /// Each slot's transfer of the image.
    transfers: [Option<Transfer>; MAX_THRUSTERS],
    buffer: [u8; BUFFER],
    fill: usize,
    /// The slot whose transfer made the last exchange: the next goes to the one after it.
    turn: usize,
    query: Option<Query>,
    /// The last query's sequence number.
    query_seq: u8,
    /// Each slot's thruster, by its last `Version`.
    standing: [Standing; MAX_THRUSTERS],
    /// The version each slot's thruster runs, by its last `Version` (`@SYS/versions.txt`).
    running: [Option<[u8; 4]>; MAX_THRUSTERS],
    /// The slots (bits) whose thrusters answer their polls, as the bus tasks last said ([`Courier::seen`]).
    answering: u8,
    /// Each slot's thruster that a family's update left behind, silent, and the version the family was given: told
    /// when it answers again on another ([`Courier::answered`]).
    behind: [Option<(Family, [u8; 4])>; MAX_THRUSTERS],
    /// When the thrusters on trial are next asked.
    trial_ask: Instant,
    /// The slots (bits) whose post-mortem records are to be fetched: each thruster that speaks `PostMortem`, once
    /// after it answers again (it may have stopped and reset).
    post_mortem_due: u8,
    /// The record being fetched, its parts read so far.
    fetching: [u8; RECORD_LEN],
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
            image: None,
            transfers: [None; MAX_THRUSTERS],
            buffer: [0; BUFFER],
            fill: 0,
            turn: MAX_THRUSTERS - 1,
            query: None,
            query_seq: 0,
            standing: [Standing::Away; MAX_THRUSTERS],
            running: [None; MAX_THRUSTERS],
            answering: 0,
            behind: [None; MAX_THRUSTERS],
            trial_ask: Instant::from_ticks(0),
            post_mortem_due: 0,
            fetching: [0; RECORD_LEN],
        }
    }

    /// Whether an image is on its way to thrusters (and not only the master's questions of what they run).
    pub(crate) fn carrying(&self) -> bool {
        self.image.is_some()
    }

    /// Whether the sink may hand on one more write's bytes.
    pub fn has_room(&self) -> bool {
        self.image.is_none() || self.fill + MAX_WRITE <= BUFFER
    }

    /// The transfers under way.
    fn live(&self) -> impl Iterator<Item = &Transfer> {
        self.transfers.iter().flatten()
    }

    /// An image for `slot` begins, in its own file: see [`Courier::begin_to`].
    pub fn begin(
        &mut self,
        slot: u8,
        kind: u8,
        payload_len: u32,
        header: &[u8; FILE_HEADER_LEN],
    ) -> Result<(), NotTaken> {
        self.begin_to(bit(slot), File::Slot, kind, payload_len, header)
    }

    /// An image for the thrusters whose slots are the bits of `slots` begins: `header` is its update file's header,
    /// which the update server has checked (`kind` its target byte, `payload_len` its payload's length), `file` the
    /// file it comes in. The image under way is dropped, unless it is being applied. Every thruster gets each page
    /// in turn, and the buffer moves on once each has it (or has ended).
    pub fn begin_to(
        &mut self,
        slots: u8,
        file: File,
        kind: u8,
        payload_len: u32,
        header: &[u8; FILE_HEADER_LEN],
    ) -> Result<(), NotTaken> {
        if self.image.is_some_and(|image| image.applier.is_some()) || self.live().any(Transfer::applying) {
            return Err(NotTaken);
        }
        let [.., v0, v1, v2, v3] = *header.first_chunk::<16>().ok_or(NotTaken)?;
        let signature = *header.last_chunk::<SIGNATURE_LEN>().ok_or(NotTaken)?;
        self.image = Some(Image {
            kind,
            payload_len,
            version: [v0, v1, v2, v3],
            signature,
            received: 0,
            crc: Crc32::new(),
            complete: false,
            offset: 0,
            file,
            applier: None,
            applied: 0,
            failed: 0,
            reported: Instant::from_ticks(0),
        });
        for (slot, transfer) in (0..).zip(self.transfers.iter_mut()) {
            *transfer = (slots & bit(slot) != 0).then(|| Transfer::new(slot));
        }
        for (slot, behind) in (0..).zip(self.behind.iter_mut()) {
            if slots & bit(slot) != 0 {
                *behind = None;
            }
        }
        self.fill = 0;
        // The lowest slot first.
        self.turn = MAX_THRUSTERS - 1;
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
        self.ask(slot, Look::Version, Some(from));
        Ok(())
    }

    /// A query of `slot` begins.
    fn ask(&mut self, slot: u8, look: Look, asker: Option<Sender>) {
        self.query_seq = self.query_seq.wrapping_add(1);
        self.query = Some(Query {
            slot,
            look,
            seq: self.query_seq,
            asker,
            silent_since: None,
        });
    }

    /// Whether no transfer has an exchange to make: none has, or each waits for its apply, or for its next page.
    fn quiet(&self) -> bool {
        self.live().all(|transfer| match transfer.step {
            Step::Written | Step::Runs => true,
            Step::Idle => self.page_for(transfer).is_none() && !self.image.is_some_and(|image| image.complete),
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
    pub fn seen(&mut self, slot: u8, answering: bool) {
        self.answering = if answering {
            self.answering | bit(slot)
        } else {
            self.answering & !bit(slot)
        };
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
        if let Some(transfer) = self.live().find(|transfer| transfer.applying()) {
            return Some(UpdateHold::Applying(transfer.slot));
        }
        (0..).zip(self.standing).find_map(|(slot, standing)| match standing {
            Standing::Marked => Some(UpdateHold::Marked(slot)),
            Standing::OnTrial => Some(UpdateHold::OnTrial(slot)),
            Standing::Unasked => Some(UpdateHold::Unasked(slot)),
            Standing::Away | Standing::Settled => None,
        })
    }

    /// What slot `slot`'s thruster runs, as its last `Version` said, and what it is now (`@SYS/versions.txt`).
    pub(crate) fn running(&self, slot: u8) -> Running {
        let index = usize::from(slot);
        let version = self.running.get(index).copied().flatten();
        let state = match self.standing.get(index) {
            Some(Standing::Unasked) => ImageState::Unasked,
            // What it said holds for arming while it is away, but it does not answer now.
            _ if self.answering & bit(slot) == 0 => ImageState::Offline,
            // Settled without a version: it answered without the extension.
            Some(Standing::Settled) if version.is_none() => ImageState::NoUpdates,
            Some(Standing::Settled) => ImageState::Confirmed,
            Some(Standing::OnTrial) => ImageState::OnTrial,
            Some(Standing::Marked) => ImageState::Marked,
            Some(Standing::Away) | None => ImageState::Offline,
        };
        Running { version, state }
    }

    /// Who applies the image on its way to `slot`, if it is being applied there.
    pub(crate) fn applier(&self, slot: u8) -> Option<Sender> {
        let applied = self.transfer(slot).is_some_and(|t| t.applied);
        self.image.and_then(|image| image.applier).filter(|_| applied)
    }

    /// Slot `slot`'s transfer.
    fn transfer(&self, slot: u8) -> Option<&Transfer> {
        self.transfers.get(usize::from(slot)).and_then(Option::as_ref)
    }

    /// The payload's next bytes, at `offset` from the payload's start.
    pub fn write(&mut self, offset: u32, data: &[u8]) -> Result<(), NotTaken> {
        let fill = self.fill;
        let going = self.live().next().is_some();
        let image = self
            .image
            .as_mut()
            .filter(|image| going && !image.complete && image.received == offset)
            .ok_or(NotTaken)?;
        let room = self.buffer.get_mut(fill..fill + data.len()).ok_or(NotTaken)?;
        room.copy_from_slice(data);
        self.fill += data.len();
        image.received += data.len() as u32;
        image.crc = image.crc.update(data);
        Ok(())
    }

    /// The upload is over: `complete` when every byte came (the last page goes on, then the whole payload is
    /// checked), otherwise the image is dropped (what the thrusters hold stays, for a resumed transfer).
    pub fn finish(&mut self, complete: bool) -> Result<(), NotTaken> {
        match self.image.as_mut() {
            Some(image)
                if complete && image.received == image.payload_len && self.transfers.iter().any(Option::is_some) =>
            {
                image.complete = true;
                Ok(())
            }
            Some(image) if image.applier.is_none() => {
                self.drop_image();
                if complete { Err(NotTaken) } else { Ok(()) }
            }
            _ => Err(NotTaken),
        }
    }

    /// Forget the image and its transfers.
    fn drop_image(&mut self) {
        self.image = None;
        self.transfers = [None; MAX_THRUSTERS];
        self.fill = 0;
    }

    /// The apply command for `slot`'s image, from `from`: see [`Courier::apply_to`].
    pub fn apply(&mut self, slot: u8, from: Sender) -> Result<Applied, NotTaken> {
        self.apply_to(bit(slot), from)
    }

    /// The apply command for the thrusters whose slots are the bits of `slots`, from `from`: [`Applied::Started`]
    /// when every one of them that still has the image on its way has it written, and takes it now (the final
    /// COMMAND_ACK goes to `from` once each is done), [`Applied::Pending`] when the image is whole but still on its
    /// way to some, [`Applied::Runs`] when each runs it already, an error when none has it (it failed, or never came).
    pub fn apply_to(&mut self, slots: u8, from: Sender) -> Result<Applied, NotTaken> {
        let image = self.image.filter(|image| image.applier.is_none()).ok_or(NotTaken)?;
        let ours = |transfer: &Transfer| slots & bit(transfer.slot) != 0;
        let mask = |step: fn(&Transfer) -> bool| {
            self.live()
                .filter(|t| ours(t) && step(t))
                .fold(0, |mask, t| mask | bit(t.slot))
        };
        let (targets, runs) = (mask(|_| true), mask(|t| t.step == Step::Runs));
        if targets == 0 {
            return Err(NotTaken);
        }
        if self
            .live()
            .filter(|t| ours(t))
            .any(|t| !matches!(t.step, Step::Written | Step::Runs))
        {
            return if image.complete {
                Ok(Applied::Pending)
            } else {
                Err(NotTaken)
            };
        }
        // Those that run it already are done: each was told so when its first page came.
        for transfer in self
            .transfers
            .iter_mut()
            .filter(|t| t.is_some_and(|t| runs & bit(t.slot) != 0))
        {
            *transfer = None;
        }
        if runs == targets {
            if self.transfers.iter().all(Option::is_none) {
                self.drop_image();
            }
            return Ok(Applied::Runs);
        }
        for transfer in self.transfers.iter_mut().flatten().filter(|t| ours(t)) {
            transfer.step = Step::Finish;
            transfer.applied = true;
            transfer.silent_since = None;
        }
        if let Some(image) = self.image.as_mut() {
            image.applier = Some(from);
            image.applied = targets & !runs;
        }
        Ok(Applied::Started)
    }

    /// Whether thruster `slot` has been told to restart into its update and has not answered since: silent while
    /// its bootloader swaps the image in, as it should be.
    pub(crate) fn restarting(&self, slot: u8) -> bool {
        self.transfer(slot)
            .is_some_and(|t| matches!(t.step, Step::Reboot | Step::Restart(_)))
    }

    /// The page at the buffer's start, once it is whole (or the payload's last).
    fn page(&self) -> Option<&[u8]> {
        let image = self.image.as_ref()?;
        let len = self.fill.min(PAGE);
        let last = image.complete && image.offset + len as u32 == image.payload_len;
        (len == PAGE || last && len > 0)
            .then(|| self.buffer.get(..len))
            .flatten()
    }

    /// The page `transfer` writes next, if it is in the buffer: the others wait for it.
    fn page_for(&self, transfer: &Transfer) -> Option<&[u8]> {
        self.page()
            .filter(|_| self.image.is_some_and(|image| image.offset == transfer.page_offset))
    }

    /// The next exchange, at `now`, if its thruster is one `ours` says yes to (one of the asking bus task's), each
    /// thruster by its own write: see [`Courier::next_cast`].
    pub fn next(&mut self, now: Instant, ours: impl Fn(u8) -> bool) -> Option<Exchange> {
        self.next_cast(now, ours, |_| false, 1)
    }

    /// The next exchange, at `now`, if its thruster is one `ours` says yes to (one of the asking bus task's): a
    /// query's, else the next transfer's after the last that made one, in turn. When the thrusters `castable` says
    /// yes to can share a write (behind the bus's multiplexer, whose channels can be enabled together), the other
    /// transfers at the same step of the same page, whose command is the same, take this exchange too, up to `most`
    /// thrusters in all ([`Exchange::with`]): a page's erase, check and chunks go once to the family, and each
    /// thruster's own reply, read alone, tells whether its copy arrived. Each takes the exchange's sequence number.
    // Out of line: every bus task calls it, and its code would be copied into each.
    #[inline(never)]
    pub fn next_cast(
        &mut self,
        now: Instant,
        ours: impl Fn(u8) -> bool,
        castable: impl Fn(u8) -> bool,
        most: u32,
    ) -> Option<Exchange> {
        if self.query.is_none() && self.quiet() {
            let due =
                |standing| standing == Standing::Unasked || standing == Standing::OnTrial && now >= self.trial_ask;
            let slot = (0..)
                .zip(self.standing)
                .find(|(slot, standing)| ours(*slot) && due(*standing));
            if let Some((slot, _)) = slot {
                self.ask(slot, Look::Version, None);
            } else if let Some(slot) =
                (0..MAX_THRUSTERS as u8).find(|slot| ours(*slot) && self.post_mortem_due & bit(*slot) != 0)
            {
                self.ask(slot, Look::PostMortem(0), None);
            }
        }
        // One at a time: the transfers wait for the query's end.
        if let Some(query) = self.query {
            return ours(query.slot).then(|| exchange_of(query.slot, query.seq, query.look.command()));
        }
        let image = self.image?;
        let count = self.transfers.len();
        for index in (1..=count).map(|n| (self.turn + n) % count) {
            let Some(transfer) = self.transfers.get(index).copied().flatten() else {
                continue;
            };
            if !ours(transfer.slot) {
                continue;
            }
            if let Some((step, command)) = self.step_of(now, &image, &transfer) {
                let shared = |other: &Transfer| {
                    other.slot != transfer.slot
                        && ours(other.slot)
                        && castable(other.slot)
                        && other.page_offset == transfer.page_offset
                        && self.step_of(now, &image, other) == Some((step, command))
                };
                let with = if step.castable() && castable(transfer.slot) {
                    self.live()
                        .filter(|other| shared(other))
                        .take(most.saturating_sub(1) as usize)
                        .fold(0, |with, other| with | bit(other.slot))
                } else {
                    0
                };
                for member in self.transfers.iter_mut().flatten() {
                    if member.slot == transfer.slot || with & bit(member.slot) != 0 {
                        member.step = step;
                        member.seq = transfer.seq;
                    }
                }
                self.turn = index;
                return Some(Exchange {
                    with,
                    ..exchange_of(transfer.slot, transfer.seq, command)
                });
            }
        }
        None
    }

    /// Where `transfer` of `image` is at `now`, and the command it sends there, if it has one to send.
    fn step_of(&self, now: Instant, image: &Image, transfer: &Transfer) -> Option<(Step, Command)> {
        let page = self.page_for(transfer).map(|page| page.len() as u32);
        let step = match (transfer.step, page) {
            (Step::Idle, Some(_)) => Step::CheckPage,
            (Step::Idle, None) if image.complete && transfer.page_offset == image.payload_len => Step::Verify,
            (Step::Restart(since), _) if now < since + RESTART_FIRST_ASK => return None,
            (Step::Trial { next, .. } | Step::Settle(next), _) if now < next => return None,
            (Step::Settle(_), _) => Step::Begin,
            (step, _) => step,
        };
        let command = match step {
            Step::Hello | Step::Restart(_) | Step::Trial { .. } => Command::Version,
            Step::Begin => Command::Begin {
                payload_len: image.payload_len,
                target: image.kind,
            },
            // Turned into `Begin` above once it is time.
            Step::Idle | Step::Written | Step::Settle(_) | Step::Runs => return None,
            Step::CheckPage => Command::Check {
                offset: transfer.page_offset,
                len: page?,
            },
            Step::Erase => Command::Erase {
                page: u16::try_from(transfer.page_offset / ext::PAGE_LEN).ok()?,
            },
            Step::Write(at) => {
                let start = usize::from(at);
                let end = (page? as usize).min(start + MAX_CHUNK);
                Command::Write {
                    offset: transfer.page_offset + u32::from(at),
                    data: self.buffer.get(start..end).and_then(Chunk::new)?,
                }
            }
            Step::Verify => Command::Check {
                offset: 0,
                len: image.payload_len,
            },
            Step::Finish => Command::Finish {
                payload_len: image.payload_len,
                signature: image.signature,
            },
            Step::Reboot => Command::Reboot,
        };
        Some((step, command))
    }

    /// What `exchange` got, at `now`: the transfer moves on, or ends; `out` takes the texts, the apply's progress
    /// and its final acknowledgement.
    #[inline(never)]
    pub fn on_result(
        &mut self,
        now: Instant,
        exchange: impl Into<Sent>,
        result: Result<Reply, ExchangeError>,
        out: &mut impl FnMut(Outgoing),
    ) -> Option<PostMortem> {
        let exchange = exchange.into();
        let fetch = self
            .query
            .filter(|query| query.slot == exchange.slot)
            .and_then(|query| match query.look {
                Look::PostMortem(offset) if exchange.command == CommandKind::PostMortem => Some((query, offset)),
                _ => None,
            });
        let fetched = match fetch {
            Some((query, offset)) => self.fetched(now, query, offset, result),
            None => {
                self.take(now, exchange, result, out);
                None
            }
        };
        self.report(now, out);
        fetched
    }

    /// At most once a [`PROGRESS_PERIOD`] while a family's image is applied: how far, as the
    /// apply's COMMAND_ACK IN_PROGRESS with its progress (each thruster's share: marked 10 %, restarting 20 %, on
    /// trial 60 %, done 100 %) and a text (`thrusters-seabotix.lbvu: 1 of 3 done, T3 60 %`).
    fn report(&mut self, now: Instant, out: &mut impl FnMut(Outgoing)) {
        let Some((File::Family(family), image)) = self.image.as_mut().map(|image| (image.file, image)) else {
            return;
        };
        let Some(to) = image.applier.filter(|_| now >= image.reported + PROGRESS_PERIOD) else {
            return;
        };
        image.reported = now;
        let count = image.applied.count_ones();
        let going = self.live().filter(|t| t.applied).count() as u32;
        let done = count.saturating_sub(going);
        let share = |transfer: &Transfer| -> u32 {
            match transfer.step {
                Step::Reboot => 10,
                Step::Restart(_) => 20,
                Step::Trial { .. } => 60,
                _ => 0,
            }
        };
        let shares: u32 = self.live().filter(|t| t.applied).map(share).sum();
        let progress = ((100 * done + shares) / count.max(1)).min(99) as u8;
        out(Outgoing::Progress {
            command: UpdateAction::Apply.command(),
            progress,
            to,
        });
        if let Some(first) = self.live().find(|t| t.applied) {
            let file = family_file(family);
            let what = format_args!("{file}: {done} of {count} done, T{} {} %", first.slot + 1, share(first));
            out(Outgoing::Text(Severity::Info, text(what)));
        }
    }

    /// What `exchange` got, at `now`: the transfer moves on, or ends.
    fn take(
        &mut self,
        now: Instant,
        exchange: Sent,
        result: Result<Reply, ExchangeError>,
        out: &mut impl FnMut(Outgoing),
    ) {
        if let Some(query) = self.query.filter(|query| {
            query.slot == exchange.slot && query.look == Look::Version && exchange.command == CommandKind::Version
        }) {
            return self.answered(now, query, result, out);
        }
        let Some(image) = self.image else {
            return;
        };
        let slot = exchange.slot;
        let page = self
            .transfer(slot)
            .and_then(|transfer| self.page_for(transfer))
            .map(|page| (page.len(), ext::crc32(page)));
        let first_page = self.buffer.get(..page.map_or(0, |(len, _)| len)).unwrap_or_default();
        let first_refused = self
            .transfer(slot)
            .filter(|transfer| transfer.page_offset == 0)
            .and_then(|transfer| image.check(first_page, &transfer.running, transfer.max_payload).err());
        // A family's file goes to the thrusters that do not run it yet: one that runs this image info (version,
        // security counter, flags), confirmed, is left be. A slot's own file is written whatever runs.
        let runs_it = matches!(image.file, File::Family(_))
            && self.standing.get(usize::from(slot)) == Some(&Standing::Settled)
            && self.transfer(slot).is_some_and(|transfer| {
                transfer.page_offset == 0
                    && first_page.get(INFO_OFFSET..INFO_OFFSET + ext::INFO_LEN) == Some(&transfer.running[..])
            });
        let name = image.file;
        let Some(transfer) = self.transfers.get_mut(usize::from(slot)).and_then(Option::as_mut) else {
            return;
        };
        let reply = match result {
            Ok(reply) if reply.seq() == exchange.seq && reply.command() == exchange.command => reply,
            Err(ExchangeError::Frame(FrameError::MessageType { .. })) if transfer.step == Step::Hello => {
                return self.end(slot, Ending::NoExtension, out);
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
                    self.end(slot, ending, out);
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
                    return self.end(slot, Ending::Restarts, out);
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
            } if transfer.applied => {
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
            } if transfer.step == Step::Begin && !transfer.applied => {
                say(
                    out,
                    Severity::Info,
                    name,
                    slot,
                    format_args!("starting the update it holds"),
                );
                transfer.step = Step::Reboot;
                return;
            }
            Reply::Refused { refusal, .. } => return self.end(slot, Ending::Refused(refusal), out),
            // Not returned by the exchange: read again.
            Reply::Busy { .. } => return,
        };
        // What the thruster's images are now, for arming (its first `Version` said whether it runs one on trial or
        // holds one marked, which `Begin` is refused for; once it is applied, the apply holds the vehicle).
        if let ReplyBody::Version {
            on_trial, marked, info, ..
        } = body
            && let Some(standing) = self.standing.get_mut(usize::from(slot))
        {
            *standing = Standing::of(on_trial, marked);
            if let Some(running) = self.running.get_mut(usize::from(slot)) {
                *running = Some(version_in(&info));
            }
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
                    return self.end(slot, Ending::Refused(Refusal::NoSignatureCheck), out);
                }
                transfer.heard(info, max_payload);
                Step::Begin
            }
            // Begun again after a reset while being applied: the payload is whole in DFU already.
            (Step::Begin, ReplyBody::Begin { .. }) => {
                transfer.settling_since = None;
                if transfer.applied { Step::Finish } else { Step::Idle }
            }
            (Step::CheckPage, ReplyBody::Check { .. }) if runs_it => {
                say(
                    out,
                    Severity::Info,
                    name,
                    slot,
                    format_args!("runs {} already", Ver(image.version)),
                );
                transfer.step = Step::Runs;
                // The buffer does not wait for it.
                transfer.page_offset = image.payload_len;
                return self.move_on();
            }
            // Nothing of the image has gone on yet: its info decides whether anything does.
            (Step::CheckPage, ReplyBody::Check { .. }) if let Some(refusal) = first_refused => {
                return self.end(slot, Ending::Image(refusal), out);
            }
            (Step::CheckPage, ReplyBody::Check { crc, .. }) if page.is_some_and(|(_, page_crc)| page_crc == crc) => {
                transfer.skipped += 1;
                return self.page_done(slot, page_len);
            }
            (Step::CheckPage, ReplyBody::Check { .. }) => Step::Erase,
            (Step::Erase, ReplyBody::Erase { .. }) => Step::Write(0),
            (Step::Write(at), ReplyBody::Write { len, crc, .. }) => {
                let start = usize::from(at);
                let sent = self.buffer.get(start..start + usize::from(len)).map(ext::crc32);
                if sent != Some(crc) {
                    return self.end(slot, Ending::ReadBack, out);
                }
                let next = start + usize::from(len);
                if next >= page_len {
                    return self.page_done(slot, page_len);
                }
                Step::Write(u16::try_from(next).unwrap_or(u16::MAX))
            }
            (Step::Verify, ReplyBody::Check { crc, .. }) if crc == image.crc.finish() => {
                let (n, skipped) = (image.payload_len, transfer.skipped);
                say(
                    out,
                    Severity::Info,
                    name,
                    slot,
                    format_args!(
                        "{n} B verified, {skipped} page{} kept",
                        if skipped == 1 { "" } else { "s" }
                    ),
                );
                Step::Written
            }
            (Step::Verify, ReplyBody::Check { .. }) => return self.end(slot, Ending::Mismatch, out),
            (Step::Finish, ReplyBody::Finish { .. }) => Step::Reboot,
            (Step::Reboot, ReplyBody::Reboot) => {
                // Its bootloader checks the signature before it swaps: nothing says yet that it is good.
                if transfer.applied {
                    say(
                        out,
                        Severity::Info,
                        name,
                        slot,
                        format_args!("marked, restarting into its update"),
                    );
                }
                Step::Restart(now)
            }
            // Back from starting the update it held: now this one.
            (Step::Restart(_), ReplyBody::Version { info, max_payload, .. }) if !transfer.applied => {
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
                    _ if running != image.version => {
                        let ending = match transfer.step {
                            Step::Restart(_) if verdict != 0 => Ending::Verdict(verdict),
                            Step::Restart(_) => Ending::OldVersion(running),
                            _ => Ending::Reverted(running),
                        };
                        return self.end(slot, ending, out);
                    }
                    _ if !on_trial => {
                        say(
                            out,
                            Severity::Info,
                            name,
                            slot,
                            format_args!("{} confirmed", Ver(running)),
                        );
                        return self.close(slot, None, out);
                    }
                    // Still on trial: said every so long, and watched until it confirms or is reverted.
                    Step::Trial { since, .. } if now >= since + CONFIRM_LIMIT => {
                        say(
                            out,
                            Severity::Warning,
                            name,
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
                            name,
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

    /// Thruster `slot` has the page at the buffer's start: it goes on to the next, and the buffer moves on once
    /// every transfer has the page.
    fn page_done(&mut self, slot: u8, len: usize) {
        if let Some(transfer) = self.transfers.get_mut(usize::from(slot)).and_then(Option::as_mut) {
            transfer.page_offset += len as u32;
            transfer.step = Step::Idle;
        }
        self.move_on();
    }

    /// Drop the page at the buffer's start once no transfer still has to write it.
    fn move_on(&mut self) {
        let Some(image) = self.image.as_mut() else {
            return;
        };
        let len = self.fill.min(PAGE);
        let waited_for = self.transfers.iter().flatten().any(|t| t.page_offset <= image.offset);
        if waited_for || len == 0 || self.page().is_none() {
            return;
        }
        if let Some(image) = self.image.as_mut() {
            image.offset += len as u32;
        }
        self.buffer.copy_within(len..self.fill, 0);
        self.fill -= len;
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
                        protocol,
                        info,
                        on_trial,
                        checks_signatures,
                        marked,
                        dev_key,
                        ..
                    },
            }) if seq == query.seq => {
                if let Some(standing) = standing {
                    // Its first answer since it came back: fetch the record of a stop before its start.
                    if *standing == Standing::Unasked && protocol >= 2 {
                        self.post_mortem_due |= bit(slot);
                    }
                    *standing = Standing::of(on_trial, marked);
                }
                if let Some(running) = self.running.get_mut(usize::from(slot)) {
                    *running = Some(version_in(&info));
                }
                if let Some((family, version)) = self.behind.get_mut(usize::from(slot)).and_then(Option::take)
                    && version_in(&info) != version
                {
                    // One STATUSTEXT: the version the family was given is in the operator's file.
                    let (file, runs) = (family_file(family), Ver(version_in(&info)));
                    let what = format_args!("runs {runs}, put {file} again");
                    say(out, Severity::Warning, File::Family(family), slot, what);
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
                        File::Slot,
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
                say(out, Severity::Warning, File::Slot, slot, format_args!("{ending}"));
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

    /// What a fetch's `PostMortem` for the part at `offset` got, at `now`: the next part is asked, or the record is
    /// whole (returned), or the thruster holds none. A reply that does not come is asked again until the thruster
    /// has been silent for [`SILENCE_LIMIT`]; one that says something else (a status frame: no extension after all;
    /// a refusal; a length this master does not know) ends the fetch with nothing.
    fn fetched(
        &mut self,
        now: Instant,
        query: Query,
        offset: u8,
        result: Result<Reply, ExchangeError>,
    ) -> Option<PostMortem> {
        let slot = query.slot;
        let start = usize::from(offset);
        let whole = match result {
            Ok(Reply::Done {
                seq,
                body: ReplyBody::PostMortem { len, offset: at, data },
            }) if seq == query.seq && at == offset => {
                let part = self.fetching.get_mut(start..).map(|rest| rest.iter_mut().zip(data));
                match usize::from(len) {
                    RECORD_LEN if start + MAX_CHUNK < RECORD_LEN => {
                        part.into_iter().flatten().for_each(|(to, from)| *to = from);
                        self.ask(slot, Look::PostMortem((start + MAX_CHUNK) as u8), None);
                        return None;
                    }
                    RECORD_LEN => {
                        part.into_iter().flatten().for_each(|(to, from)| *to = from);
                        true
                    }
                    _ => false,
                }
            }
            Ok(Reply::Refused { seq, .. }) if seq == query.seq => false,
            Err(ExchangeError::Frame(FrameError::MessageType { .. })) => false,
            _ => {
                let since = self
                    .query
                    .as_mut()
                    .map_or(now, |query| *query.silent_since.get_or_insert(now));
                if now < since + SILENCE_LIMIT {
                    return None;
                }
                false
            }
        };
        self.post_mortem_due &= !bit(slot);
        self.query = None;
        whole.then_some(PostMortem {
            slot,
            record: self.fetching,
        })
    }

    /// Slot `slot`'s transfer ends early: the operator is told why. A thruster that was being applied the image is
    /// asked again what it runs.
    fn end(&mut self, slot: u8, ending: Ending, out: &mut impl FnMut(Outgoing)) {
        let (Some(transfer), Some(image)) = (self.transfer(slot).copied(), self.image) else {
            return;
        };
        if transfer.applying()
            && let Some(standing) = self.standing.get_mut(usize::from(slot))
        {
            *standing = Standing::Unasked;
        }
        match ending {
            // "T1: ", not "thruster0.lbvu: ": it is the thruster's bootloader that refused, and it leaves room for
            // the verdict.
            Ending::Verdict(code) => {
                let who = u16::from(slot) + 1;
                let (first, second) = verdict_texts(format_args!("T{who}"), BOOTLOADER_REFUSED, code.into());
                for text in [Some(first), second].into_iter().flatten() {
                    out(Outgoing::Text(Severity::Warning, text));
                }
            }
            _ => say(out, Severity::Warning, image.file, slot, format_args!("{ending}")),
        }
        // Gone before its family's image reached it: told when it is back.
        if let (File::Family(family), Ending::Silent | Ending::NotBack) = (image.file, ending)
            && let Some(behind) = self.behind.get_mut(usize::from(slot))
        {
            *behind = Some((family, image.version));
        }
        self.close(slot, Some(ending), out);
    }

    /// Slot `slot`'s transfer is over, confirmed or ended (`ending`): the buffer moves on without it, and once no
    /// thruster the image was applied to is left, the applier gets its final answer, FAILED if any of them failed.
    fn close(&mut self, slot: u8, ending: Option<Ending>, out: &mut impl FnMut(Outgoing)) {
        if let Some(transfer) = self.transfers.get_mut(usize::from(slot)) {
            *transfer = None;
        }
        let Some(image) = self.image.as_mut() else {
            return;
        };
        if ending.is_some() {
            image.failed |= bit(slot);
        }
        if let Some(to) = image.applier
            && !self.transfers.iter().flatten().any(|t| t.applied)
        {
            let result = if image.failed == 0 {
                AckResult::Accepted
            } else {
                AckResult::Failed
            };
            // Each failure was told as it came; the end names them together.
            if let (File::Family(family), true) = (image.file, image.failed != 0) {
                let what = format_args!("{}: failed:{}", family_file(family), Thrusters(image.failed));
                out(Outgoing::Text(Severity::Warning, text(what)));
            }
            out(Outgoing::CommandAck {
                command: UpdateAction::Apply.command(),
                result,
                to,
            });
            image.applier = None;
        }
        if self.transfers.iter().all(Option::is_none) {
            self.drop_image();
        } else {
            self.move_on();
        }
    }
}

/// Slot `slot`'s bit in a mask of slots (none for a slot beyond the mask).
pub(crate) const fn bit(slot: u8) -> u8 {
    match 1u8.checked_shl(slot as u32) {
        Some(bit) => bit,
        None => 0,
    }
}

/// The thrusters whose slots are the bits of a mask, for a person: " T3 T5".
struct Thrusters(u8);

impl core::fmt::Display for Thrusters {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        (0..MAX_THRUSTERS as u8)
            .filter(|slot| self.0 & bit(*slot) != 0)
            .try_for_each(|slot| write!(f, " T{}", u16::from(slot) + 1))
    }
}

/// The exchange of `command` to `slot`, with sequence number `seq`.
fn exchange_of(slot: u8, seq: u8, command: Command) -> Exchange {
    let wait = match command {
        Command::Erase { .. } => ext::ERASE_WAIT_MS,
        Command::Finish { .. } => ext::FINISH_WAIT_MS,
        _ => 0,
    };
    Exchange {
        slot,
        with: 0,
        frame: CommandFrame { seq, command },
        wait: Duration::from_millis(u64::from(wait)),
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

/// "thruster2.lbvu: `args`" for an image in a slot's file, as the update server names the file the ground station
/// wrote, "T3: `args`" for one in a family's (in two texts when one cannot hold it: a refusal's sentence goes on in
/// the second).
fn say(out: &mut impl FnMut(Outgoing), severity: Severity, file: File, slot: u8, args: core::fmt::Arguments<'_>) {
    let (first, second) = match file {
        File::Slot => texts(format_args!("thruster{slot}.lbvu"), args),
        File::Family(_) => texts(format_args!("T{}", u16::from(slot) + 1), args),
    };
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

    /// The next exchange for a thruster `ours` says yes to, if there is one, shared by those `castable` says yes
    /// to ([`Courier::next_cast`]).
    pub(crate) fn next(&self, ours: impl Fn(u8) -> bool, castable: impl Fn(u8) -> bool, most: u32) -> Option<Exchange> {
        self.with(|courier| courier.next_cast(Instant::now(), ours, castable, most))
    }

    /// Tell the vehicle what of the thrusters' updates keeps it from arming now ([`Courier::hold`]).
    // Out of line: the bus tasks call it at every change.
    #[inline(never)]
    pub(crate) fn publish(&self, shared: &Shared) {
        shared.holds.set_thrusters(self.with(|courier| courier.hold()));
    }

    /// What `exchange` got: `out` takes the texts and acknowledgements; the sink hears that the courier moved on.
    /// A thruster's post-mortem record fetched whole comes back.
    pub(crate) fn done(
        &self,
        exchange: Sent,
        result: Result<Reply, ExchangeError>,
        out: &mut impl FnMut(Outgoing),
    ) -> Option<PostMortem> {
        let fetched = self.with(|courier| courier.on_result(Instant::now(), exchange, result, out));
        self.moved.signal(());
        fetched
    }

    /// Wait until the sink may hand on one more write's bytes.
    pub(crate) async fn room(&self) {
        while !self.with(|courier| courier.has_room()) {
            self.moved.wait().await;
        }
    }
}

/// Send the command in `buffer` (an exchange's, encoded: its first `len` bytes) to whoever answers `address` (one
/// thruster, or several on the mux channels enabled together), then wait as long as the command needs before its
/// reply is read ([`read_reply`]). The caller's one buffer, which then takes the reply, is all the bytes kept across
/// the transfers: the bus task's future holds them once for each of the master's three buses.
pub(crate) async fn send<B: I2c>(
    bus: &mut B,
    address: u8,
    buffer: &[u8; ext::MAX_FRAME_LEN],
    len: usize,
    sent: &Sent,
) -> Result<(), ExchangeError> {
    let command = buffer.get(..len).ok_or(ExchangeError::Bus)?;
    bus.write(address, command).await.map_err(|_| ExchangeError::Bus)?;
    if sent.wait > Duration::from_ticks(0) {
        Timer::after(sent.wait).await;
    }
    Ok(())
}

/// Read the reply to `sent` from the thruster at `address` into `buffer`, again while it is busy.
pub(crate) async fn read_reply<B: I2c>(
    bus: &mut B,
    address: u8,
    buffer: &mut [u8; ext::MAX_FRAME_LEN],
    sent: &Sent,
) -> Result<Reply, ExchangeError> {
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
