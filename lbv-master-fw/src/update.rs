//! Field update from the ground station: update images taken over MAVLink FTP and applied by a command.
//!
//! The master serves a small MAVLink FTP file system ([`ftp`] has the wire format) with one file per target:
//! `/update/thruster0.lbvu` ... one per slot of the thruster table, `/update/thrusters-seabotix.lbvu` and
//! `/update/thrusters-legacy.lbvu` for every thruster of a family the table has, and `/update/master.lbvu`.
//! MAVProxy's `ftp put FILE /update/thruster0.lbvu` and pymavlink's `MAVFTP` upload to it; `ftp list /update`
//! lists the targets with the bytes received for each; `ftp crc` gives the CRC32 of those bytes; `ftp rm` forgets
//! them. MAV_CMD_LBV_APPLY_UPDATE (31010, param1 the slot, 200 every SeaBotix thruster, 201 every Legacy one, 255
//! the master: [`UpdateTarget::slot`]) then applies an image received whole. The update files are write-only; the
//! files read are `@SYS/versions.txt`, what every board runs ([`sys`]), `@PARAM/param.pck`, the parameters as
//! ArduPilot packs them ([`param_pck`]), which QGroundControl and MAVProxy read when they connect, and, while the
//! post-mortem region holds one, `@SYS/crash/master.bin`, the record of the stop before this start
//! ([`crash_record`]).
//!
//! The master keeps no image itself: each write goes on to an [`UpdateSink`] as it comes ([`VehicleSink`]): for a
//! thruster, the thruster's DFU partition over its bus ([`crate::update::courier`]); for the master, its own DFU
//! partition ([`crate::update::own`]). A sink takes bytes in order, so the server does too (FTP clients write in
//! order):
//!
//! - a write at the next byte expected is taken;
//! - a write of bytes already taken is ACKed again and only what lies beyond it is taken: its ACK was lost, and
//!   both MAVProxy and pymavlink send such a block again when they come round to it. The server keeps the CRC of
//!   what it took, not the bytes, and where the upload's CRC stood after each of its last [`MARKS`] writes: a
//!   write sent again from one of those points is checked against them (up to the next point, or the end of what
//!   was taken), and refused when its bytes differ ("bytes sent again differ"). A write sent again from another
//!   point (another block size, or one older than the last [`MARKS`] writes) cannot be checked and is taken as
//!   before; so is one whose bytes differ but happen to have the same CRC-32 (the signature, checked before the
//!   image is applied, is what stands against a forged image, not this check);
//! - a write beyond the next byte (an earlier one was lost) is dropped unanswered, as ArduPilot drops a request
//!   its queue has no room for: both clients end an upload at its first NAK, while they send an unanswered
//!   block again once they have sent every other one (their writes go round the file), and the server takes
//!   the lost block then and those after it in order.
//!
//! Requests are idempotent, so one sent again (its reply lost) gets the answer the first one got; ArduPilot
//! keeps its last reply for that instead, which would cost RAM and flash here.
//!
//! The first write carries the file's 80-byte header ([`parse_header`]; MAVProxy writes 239 bytes at a time,
//! pymavlink 80): a bad header, or one whose target does not fit the path (a thruster image for the master, a
//! family the slot does not have), ends the upload with a NAK and a STATUSTEXT saying why, before anything goes
//! to the sink. So does a file longer than its header says; once an image is whole, a write past its end is refused
//! and the image kept.
//!
//! Rules:
//! - One session at a time, an upload's or a read's: a second open gets [`Nak::NoSessionsAvailable`] (MAVProxy
//!   waits and tries again) unless the session in use has been idle for [`TAKEOVER_IDLE`] or its image is whole;
//!   the operator's upload also takes over at once another system's read, so that no one else's read holds an
//!   update back. Listing, CRC and removal need no session; a reply carries the request's session, as the clients
//!   route them by it.
//!   TerminateSession closes the session it names if it is the sender's, ResetSessions the sender's session; either
//!   of a session that is not the sender's (another client's, or another session of its) is NAKed
//!   [`Nak::InvalidSession`] and leaves it open (ArduPilot's answer for a request on a session other than the one
//!   open); with no session open there is nothing to close, and they are ACKed. A RemoveFile of a file another
//!   client is uploading (its session live, its image not whole) is refused ([`Nak::Fail`], "another component is
//!   uploading it").
//! - Only the operator's ground station (`SYSID_MYGCS`) may write, remove or apply ([`Nak::FileProtected`],
//!   COMMAND_ACK DENIED); anyone may list, read CRCs and read the files, armed or not. Nothing in `@SYS` or
//!   `@PARAM` is written, created or removed, nor has a CRC ([`Nak::FileProtected`]). With a signing key set, unsigned FTP
//!   frames are refused before they get here, as every unsigned frame is ([`crate::console::signing`]).
//! - Without a signing key anyone on the link can claim `SYSID_MYGCS`: nothing is written, removed or applied
//!   ([`Nak::Fail`], COMMAND_ACK DENIED, and "refused, the link is not signed") unless `LBV_UPD_UNSIGNED` is 1
//!   ([`crate::params::Param::UnsignedUpdates`], [`Context::unsigned`]).
//! - Nothing is written, removed or applied while armed ([`Nak::Fail`], COMMAND_ACK TEMPORARILY_REJECTED, and
//!   "disarm to update"); arming during an upload stops it at its next request.
//! - Nor once the master's own image is marked for the swap, until it has restarted into it ([`Nak::Fail`],
//!   COMMAND_ACK TEMPORARILY_REJECTED, and "master restarting into its update"): an upload under way stops at its
//!   next write.
//! - Progress: a STATUSTEXT of the bytes received at most once per [`PROGRESS_PERIOD`], and one at the end.
//!   What a script reads: `ftp list /update` (each file's size is the bytes received), `ftp crc`, and the apply
//!   command's COMMAND_ACK.
//!
//! Slots count from 0 here, as the paths do: `thruster0.lbvu` is T1 of the console's texts.

pub mod courier;
pub mod ftp;
pub mod header;
pub mod own;
pub mod param_pck;
pub mod sys;
pub(crate) mod window;

pub(crate) use header::parse_header;
pub use header::{HEADER_LEN, ImageHeader};

use core::fmt::{self, Write as _};
use core::sync::atomic::Ordering;

use embassy_time::{Duration, Instant};
use tmc_proto::Family;

use crate::blackbox::TlogFile;
use crate::mixer::FrameKind;
use crate::params::Params;
use crate::ports::{Applied, MASTER_SLOT, Refused, UpdateSink, UpdateTarget};
use crate::shared::{
    AckResult, FTP_PAYLOAD, FTP_REPLY_DATA, FtpPayload, MAX_THRUSTERS, Outgoing, Sender, Severity, Shared,
    UpdateAction, UpdateCommand, UpdateCounters, UpdateHolds, UpdateRequest, text,
};
pub use crate::shared::{FileRead, FtpAnswer, OpenFile};
use crate::thrusters::ThrusterTable;
use crate::update::courier::{File, PROGRESS_PERIOD, Transfers, bit, family_file};
use crate::update::own::{NotTaken, OwnImage};
use crate::update::param_pck::ParamFile;
use crate::update::sys::CrashFile;
use crate::update::sys::Versions;
use crate::update::window::Window;
use ftp::{ACK, Nak, Opcode, Request};
use update_image::HeaderError;

/// Whether the image has the update server. The acceptance image leaves it out: it runs only on the two-dev-kit
/// bench with its test script, and its flash budget has no room left beside the script (its console answers FTP
/// frames with nothing and the apply command with UNSUPPORTED).
pub(crate) const ENABLED: bool = !cfg!(feature = "acceptance");

/// A session idle this long may be taken over by a new open, its upload stopped (ArduPilot's
/// FTP_SESSION_TIMEOUT).
pub const TAKEOVER_IDLE: Duration = Duration::from_secs(3);
/// The longest thruster payload: its ACTIVE partition, which the payload is an image of.
pub(crate) const THRUSTER_MAX_PAYLOAD: u32 = g431_hw::memory::THRUSTER_PARTITIONS.active.length;
/// The longest master payload: its ACTIVE partition, which the payload is an image of.
pub(crate) const MASTER_MAX_PAYLOAD: u32 = g431_hw::memory::MASTER_PARTITIONS.active.length;
/// Why no update file changes while the master's own image is marked for the swap ([`Context::restarting`]).
const RESTARTING: &str = "master restarting into its update";
/// Why an upload, or a write to an image whole, is refused: bytes past the end its header gives.
const LONGER: &str = "longer than its header says";
/// Why a write of bytes already taken is refused: they are not the bytes taken ([`Marks::check`]).
const DIFFER: &str = "bytes sent again differ";
/// Why no update file changes over a link without signing ([`Context::unsigned`]).
pub(crate) const UNSIGNED: &str = "refused, the link is not signed";
/// Writes whose end the upload's CRC is kept for (by [`UpdateServer`]'s WriteFile): a write sent again from one of
/// them is checked. MAVProxy and pymavlink keep five writes in flight and send again those whose ACK was lost: 16
/// covers them with room, for 128 bytes of RAM.
pub(crate) const MARKS: usize = 16;

/// The target byte of images for `family`'s thrusters.
const fn thruster_kind(family: Family) -> u8 {
    match family {
        Family::SeaBotix => 1,
        Family::Legacy => 2,
    }
}

/// A target byte's name, for a person.
fn kind_name(kind: u8) -> &'static str {
    match kind {
        1 => "SeaBotix",
        2 => "Legacy",
        _ => "master",
    }
}

impl FtpAnswer {
    /// The whole payload, as it goes out with `contents` ([`FileRead::write_to`]).
    pub fn payload(&self, contents: &Contents<'_>) -> FtpPayload {
        let mut payload = [0; FTP_PAYLOAD];
        self.write_to(&mut payload, contents);
        payload
    }

    /// Write the payload into `into`, which is zeros.
    pub(crate) fn write_to(&self, into: &mut [u8], contents: &Contents<'_>) {
        match self {
            Self::Reply(reply) => {
                if let Some(start) = into.get_mut(..reply.len()) {
                    start.copy_from_slice(reply);
                }
            }
            Self::Read(read) => read.write_to(into, contents),
        }
    }
}

/// A sink that keeps nothing and applies nothing ([`Applied::NotWired`]): the server still checks each image's
/// header, length and CRC. The acceptance image's (it has no update server) and the tests'.
#[derive(Debug, Clone, Copy, Default)]
pub struct CheckOnly;

impl UpdateSink for CheckOnly {
    fn begin(&mut self, _: UpdateTarget, _: &ImageHeader) -> Result<(), Refused> {
        Ok(())
    }

    fn write(&mut self, _: u32, _: &[u8]) -> Result<(), Refused> {
        Ok(())
    }

    fn finish(&mut self, _: bool) -> Result<(), Refused> {
        Ok(())
    }

    fn apply(&mut self, _: UpdateTarget, _: Sender) -> Result<Applied, Nak> {
        Ok(Applied::NotWired)
    }
}

/// The vehicle's sink: thruster images go on to their thrusters over the bus as they come ([`crate::update::courier`],
/// through the [`Transfers`] the bus tasks serve), the master's own into its DFU partition ([`crate::update::own`], through
/// the [`OwnImage`] its own task serves).
#[derive(Debug, Clone, Copy)]
pub struct VehicleSink<'a> {
    transfers: &'a Transfers,
    own: &'a OwnImage,
    /// The target of the image begun.
    target: Option<UpdateTarget>,
}

impl<'a> VehicleSink<'a> {
    /// A sink handing thruster images to `transfers`, which the bus tasks serve too ([`crate::Polling`]), and the
    /// master's to `own`.
    pub const fn new(transfers: &'a Transfers, own: &'a OwnImage) -> Self {
        Self {
            transfers,
            own,
            target: None,
        }
    }
}

impl UpdateSink for VehicleSink<'_> {
    async fn ready(&mut self) {
        self.transfers.room().await;
        self.own.room().await;
    }

    fn begin(&mut self, target: UpdateTarget, header: &ImageHeader) -> Result<(), Refused> {
        self.target = Some(target);
        match target {
            // The courier takes a new image unless one is being applied.
            UpdateTarget::Thruster(slot) => self
                .transfers
                .with(|courier| courier.begin(slot, header.target, header.payload_len, &header.bytes))
                .map_err(|_| Refused::Because("wait: another update is being applied")),
            UpdateTarget::Family { family, slots } => self
                .transfers
                .with(|courier| {
                    let file = File::Family(family);
                    courier.begin_to(slots, file, header.target, header.payload_len, &header.bytes)
                })
                .map_err(|_| Refused::Because("wait: another update is being applied")),
            UpdateTarget::Master => self.own.begin(header).map_err(|_| Refused::Told),
        }
    }

    // A transfer the courier or the own task has ended was ended saying why.
    fn write(&mut self, offset: u32, data: &[u8]) -> Result<(), Refused> {
        let offset = offset
            .checked_sub(HEADER_LEN as u32)
            .ok_or(Refused::Because("no header"))?;
        match self.target {
            Some(UpdateTarget::Thruster(_) | UpdateTarget::Family { .. }) => self
                .transfers
                .with(|courier| courier.write(offset, data))
                .map_err(|_| Refused::Told),
            Some(UpdateTarget::Master) => self.own.write(offset, data).map_err(|_| Refused::Told),
            None => Err(Refused::Because("nothing begun")),
        }
    }

    fn finish(&mut self, complete: bool) -> Result<(), Refused> {
        match self.target {
            Some(UpdateTarget::Thruster(_) | UpdateTarget::Family { .. }) => self
                .transfers
                .with(|courier| courier.finish(complete))
                .map_err(|_| Refused::Told),
            Some(UpdateTarget::Master) => {
                self.own.finish(complete);
                Ok(())
            }
            None => Ok(()),
        }
    }

    fn apply(&mut self, target: UpdateTarget, from: Sender) -> Result<Applied, Nak> {
        let slots = match target {
            UpdateTarget::Thruster(slot) => bit(slot),
            UpdateTarget::Family { slots, .. } => slots,
            UpdateTarget::Master => 0,
        };
        match target {
            UpdateTarget::Thruster(_) | UpdateTarget::Family { .. } => self.transfers.with(|courier| {
                if let Some(by) = (0..MAX_THRUSTERS as u8)
                    .filter(|slot| slots & bit(*slot) != 0)
                    .find_map(|slot| courier.applier(slot))
                {
                    return Ok(Applied::Applying(by));
                }
                courier.apply_to(slots, from).map_err(|_| Nak::Fail)
            }),
            UpdateTarget::Master => match self.own.apply(from) {
                Ok(()) => Ok(Applied::Started),
                Err(NotTaken::Applying(by)) => Ok(Applied::Applying(by)),
                Err(_) => Err(Nak::Fail),
            },
        }
    }

    fn query_version(&mut self, slot: u8, from: Sender) -> Result<(), Refused> {
        // One exchange at a time: not while a transfer has one to make.
        self.transfers
            .with(|courier| courier.query(slot, from))
            .map_err(Refused::Because)
    }

    fn publish(&self, holds: &UpdateHolds) {
        holds.set_thrusters(self.transfers.with(|courier| courier.hold()));
        holds.set_master(self.own.hold());
    }

    fn boards(&self, versions: &mut Versions) {
        versions.set(0, self.own.running());
        self.transfers.with(|courier| {
            for slot in 0..MAX_THRUSTERS as u8 {
                versions.set(1 + usize::from(slot), courier.running(slot));
            }
        });
    }
}

/// What the server must know of the vehicle for each request.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Context {
    /// The vehicle is armed.
    pub armed: bool,
    /// `SYSID_MYGCS`.
    pub operator: u8,
    /// The master's own image is marked for the swap and the master restarts into it ([`Shared::restarting`]):
    /// nothing is written, removed or applied until then.
    pub restarting: bool,
    /// No signing key is in force, so anyone on the link can claim `SYSID_MYGCS`, and `LBV_UPD_UNSIGNED` does not
    /// allow updates without one: nothing is written, removed or applied.
    pub unsigned: bool,
    /// The parameters in force, once the settings are published: what `@PARAM/param.pck` is opened with.
    pub params: Option<Params>,
    /// The post-mortem region holds a record: `@SYS/crash/master.bin` is there.
    pub crash: bool,
    /// The slots (bits) whose thrusters' post-mortem records the master has fetched: `@SYS/crash/thruster<slot>.bin`.
    pub post_mortems: u8,
    /// `@SYS/blackbox.tlog` as it stands, when the master has a black box ([`crate::blackbox`]).
    pub black_box: Option<TlogFile>,
}

impl Context {
    /// Whether `file` is there.
    fn holds(&self, file: CrashFile) -> bool {
        match file.0 {
            None => self.crash,
            Some(slot) => self.post_mortems & bit(slot) != 0,
        }
    }
}

impl Context {
    /// The vehicle's state now (before the vehicle task has published it: disarmed, no operator; before the
    /// settings are: unsigned).
    pub fn of(shared: &Shared) -> Self {
        let vehicle = shared.vehicle.try_get();
        let settings = shared.settings.try_get();
        Self {
            armed: vehicle.is_some_and(|v| v.armed),
            // 0 is no system: nobody may write before the vehicle has said whom it takes orders from.
            operator: vehicle.map_or(0, |v| v.operator),
            restarting: shared.restarting.load(Ordering::Relaxed),
            unsigned: settings.is_none_or(|s| s.signing.is_none() && !s.params.unsigned_updates()),
            params: settings.map(|s| s.params),
            crash: shared.crash_held(),
            post_mortems: shared.post_mortems_held(),
            black_box: shared.black_box.open(),
        }
    }
}

/// An image: the upload under way, or the last one received whole.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
struct Image {
    target: UpdateTarget,
    /// Received whole, header and length checked.
    whole: bool,
    /// Bytes received, header included.
    received: u32,
    /// The file's length by its header, once the sink has begun it; 0 before.
    total: u32,
    /// [`ftp::crc32`] of the bytes received.
    crc: u32,
}

/// The one session: an upload.
#[derive(Debug, Clone, Copy)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
struct Session {
    owner: Sender,
    id: u8,
    /// Its last request.
    last: Instant,
    /// Its last progress report.
    reported: Instant,
}

/// What a request's path names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Node {
    /// `/`.
    Root,
    /// `/update`.
    Updates,
    /// An update file.
    Update(UpdateTarget),
    /// `@SYS`.
    Sys,
    /// `@SYS/versions.txt`.
    Versions,
    /// `@PARAM`.
    ParamDir,
    /// `@PARAM/param.pck`, with a query or none.
    Params,
    /// `@SYS/crash`.
    CrashDir,
    /// A post-mortem record in `@SYS/crash`.
    Crash(CrashFile),
    /// `@SYS/blackbox.tlog`.
    BlackBox,
}

/// Why an upload stops before its end.
#[derive(Clone, Copy)]
enum Stop {
    /// Its session was closed (by its client, or taken over).
    Closed,
    Armed,
    /// Refused or removed: the reason is told where it is found.
    Quiet,
}

/// The MAVLink FTP server and its upload: a pure state machine on explicit time. Never panics on any request;
/// every refusal, gap and write sent again is counted, and a request refused changes nothing but the upload it
/// stops.
///
/// It holds the state of one image received whole at a time, the last one (the sink has the bytes, not the
/// master), and of the upload under way: listing and CRC show them for their targets and nothing for the others,
/// and only the image received whole can be applied. An upload that begins (its header passed) replaces the
/// image of its own target; one refused or stopped leaves the image received before as it was.
///
/// Requests are idempotent rather than remembered: one sent again (its reply lost) gets the reply the first one
/// got (a write of bytes already taken is ACKed again, a listing or CRC is the same) or, for a CreateFile whose
/// session is now open, [`Nak::Fail`], which is ArduPilot's answer and what MAVProxy takes for "already open"
/// after a retry.
#[derive(Debug)]
pub struct UpdateServer {
    /// The family of each slot of the thruster table.
    slots: [Option<Family>; MAX_THRUSTERS],
    /// The build's frame, for the parameters' defaults.
    frame: FrameKind,
    /// The session's upload (once opened; whole once received whole, until the session closes).
    upload: Option<Image>,
    /// The last image received whole.
    held: Option<Image>,
    session: Option<Session>,
    /// The session's file open for reading, as it was opened (a session either reads or uploads).
    reading: Option<OpenFile>,
    /// Where the upload's CRC stood after each of its last writes ([`Marks`]).
    marks: Marks,
    counters: UpdateCounters,
}

/// Where an upload's CRC stood after each of its last [`MARKS`] writes (and at its start): the file offset and
/// [`ftp::crc32`] of every byte before it, oldest overwritten first. A write of bytes already taken that starts at
/// one of them is checked against the next ([`Marks::check`]).
#[derive(Debug, Clone, Copy)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
struct Marks {
    at: [(u32, u32); MARKS],
    next: usize,
}

impl Marks {
    /// Only the start: offset 0, CRC 0.
    const fn new() -> Self {
        Self {
            // Every slot the start: a slot not yet written says nothing wrong.
            at: [(0, 0); MARKS],
            next: 0,
        }
    }

    /// The upload's CRC stood at `crc` after its first `offset` bytes.
    fn push(&mut self, offset: u32, crc: u32) {
        if let Some(slot) = self.at.get_mut(self.next % MARKS) {
            *slot = (offset, crc);
        }
        self.next = (self.next + 1) % MARKS;
    }

    /// The CRC after the first `offset` bytes, if it is kept.
    fn crc_at(&self, offset: u32) -> Option<u32> {
        self.at.iter().find(|(at, _)| *at == offset).map(|&(_, crc)| crc)
    }

    /// Whether `data`, written at `offset` below `received` (whose CRC is `crc`), holds the bytes taken there:
    /// `Some(false)` when it does not, `None` when that cannot be told (no mark where it starts, or none where its
    /// overlap with what was taken ends).
    fn check(&self, offset: u32, data: &[u8], received: u32, crc: u32) -> Option<bool> {
        let start = self.crc_at(offset)?;
        let taken = received.saturating_sub(offset);
        let len = u32::try_from(data.len()).unwrap_or(u32::MAX).min(taken);
        let end = offset + len;
        let expected = if end == received { crc } else { self.crc_at(end)? };
        let overlap = data.get(..len as usize)?;
        Some(ftp::crc32(start, overlap) == expected)
    }
}

impl UpdateServer {
    /// No image, no session, for a master with `thrusters`.
    pub fn new(thrusters: &ThrusterTable, frame: FrameKind) -> Self {
        let mut slots = [None; MAX_THRUSTERS];
        for (slot, thruster) in slots.iter_mut().zip(thrusters.as_slice()) {
            *slot = Some(thruster.family);
        }
        Self {
            slots,
            frame,
            upload: None,
            held: None,
            session: None,
            reading: None,
            marks: Marks::new(),
            counters: UpdateCounters::default(),
        }
    }

    /// The counters so far.
    #[cfg(test)]
    pub(crate) fn counters(&self) -> UpdateCounters {
        self.counters
    }

    /// Bytes received for `target` and their CRC: the upload's or the image's, when it is `target`'s (0, 0
    /// otherwise).
    pub(crate) fn received(&self, target: UpdateTarget) -> (u32, u32) {
        [self.upload, self.held]
            .into_iter()
            .flatten()
            .find(|i| i.target == target)
            .map_or((0, 0), |i| (i.received, i.crc))
    }

    /// Whether an image for `target` is held, received whole.
    pub(crate) fn is_received(&self, target: UpdateTarget) -> bool {
        self.held.is_some_and(|i| i.target == target)
    }

    /// The targets: the thruster table's slots, each family the table has, then the master.
    fn targets(&self) -> impl Iterator<Item = UpdateTarget> + '_ {
        (0..MAX_THRUSTERS as u8)
            .filter(|slot| self.slots.get(usize::from(*slot)).is_some_and(Option::is_some))
            .map(UpdateTarget::Thruster)
            .chain(Family::ALL.into_iter().filter_map(|family| self.family(family)))
            .chain([UpdateTarget::Master])
    }

    /// Every thruster of `family` in the table, if it has any.
    fn family(&self, family: Family) -> Option<UpdateTarget> {
        let slots = (0..)
            .zip(self.slots)
            .filter(|(_, slot)| *slot == Some(family))
            .fold(0, |slots, (slot, _)| slots | bit(slot));
        (slots != 0).then_some(UpdateTarget::Family { family, slots })
    }

    /// What a request's path names: `/`, `/update`, an update file (`/update/thruster<slot>.lbvu`,
    /// `/update/master.lbvu`, a family's), `@SYS`, `@SYS/versions.txt`, `@PARAM` or `@PARAM/param.pck` with a
    /// query (the leading `/` may be left out).
    fn lookup(&self, path: &[u8]) -> Result<Node, Nak> {
        let path = path.strip_prefix(b"/").unwrap_or(path);
        if path.is_empty() {
            return Ok(Node::Root);
        }
        if let Some(file) = param_pck::in_dir(path) {
            return Ok(if file.is_some() { Node::Params } else { Node::ParamDir });
        }
        if let Some(name) = sys::in_dir(path) {
            return match name {
                b"" | b"/" => Ok(Node::Sys),
                _ if name.strip_prefix(b"/") == Some(sys::VERSIONS.as_bytes()) => Ok(Node::Versions),
                _ if name.strip_prefix(b"/") == Some(sys::BLACK_BOX.as_bytes()) => Ok(Node::BlackBox),
                b"/crash" | b"/crash/" => Ok(Node::CrashDir),
                _ => name
                    .strip_prefix(b"/crash/")
                    .and_then(CrashFile::named)
                    .map(Node::Crash)
                    .ok_or(Nak::FileNotFound),
            };
        }
        let target = match path.strip_prefix(b"update") {
            Some(b"" | b"/") => return Ok(Node::Updates),
            Some(b"/master.lbvu") => Some(UpdateTarget::Master),
            Some(name) if let Some(family) = family_named(name) => self.family(family),
            Some(name) => match name.strip_prefix(b"/thruster") {
                Some([digit, b'.', b'l', b'b', b'v', b'u']) => self
                    .targets()
                    .find(|t| *t == UpdateTarget::Thruster(digit.wrapping_sub(b'0'))),
                _ => None,
            },
            None => None,
        };
        target.map(Node::Update).ok_or(Nak::FileNotFound)
    }

    /// The update file a request's path names, to write, create, remove or checksum: nothing in `@SYS` is written.
    fn target(&self, request: &Request<'_>) -> Result<UpdateTarget, Nak> {
        let path = request.path()?;
        if sys::is_sys(path) {
            return Err(Nak::FileProtected);
        }
        match self.lookup(path)? {
            Node::Update(target) => Ok(target),
            Node::Params => Err(Nak::FileProtected),
            _ => Err(Nak::FileNotFound),
        }
    }

    /// `@SYS/versions.txt` as it stands now.
    fn versions(&self, sink: &impl UpdateSink) -> Versions {
        let mut versions = Versions::new(&self.slots);
        sink.boards(&mut versions);
        versions
    }

    /// Answer one FILE_TRANSFER_PROTOCOL payload from `from` at `now`; `out` takes the texts and progress. The
    /// reply, or `None` when the request is left unanswered.
    pub fn request(
        &mut self,
        now: Instant,
        context: Context,
        from: Sender,
        payload: &FtpPayload,
        sink: &mut impl UpdateSink,
        out: &mut impl FnMut(Outgoing),
    ) -> Option<FtpAnswer> {
        // Arming stops an upload; a read changes nothing, and goes on.
        if context.armed && self.session.is_some() && self.reading.is_none() {
            self.stop(Stop::Armed, sink, out);
        }
        let request = Request::parse(payload);
        let ours = self.session.is_some_and(|s| s.owner == from && s.id == request.session);
        let mut data = Buf::default();
        let mut read = None;
        let opcode = Opcode::from_byte(request.opcode);
        let answer = match opcode {
            // A reply sent to a server: answering it could set two servers talking.
            Opcode::Other(ACK | ftp::NAK) => return None,
            _ if request.data.is_none() => Err(Nak::InvalidDataSize),
            Opcode::None => Ok(()),
            // Reset closes every session of the sender, Terminate the one it names; another's stays open.
            Opcode::TerminateSession | Opcode::ResetSessions => match self.session {
                None => Ok(()),
                Some(s) if ours || opcode == Opcode::ResetSessions && s.owner == from => {
                    self.stop(Stop::Closed, sink, out);
                    Ok(())
                }
                Some(_) => Err(Nak::InvalidSession),
            },
            Opcode::ListDirectory => request
                .path()
                .and_then(|path| self.list(path, request.offset, context, sink, &mut data)),
            Opcode::OpenFileRO => self
                .readable(&request, context, sink)
                .and_then(|file| self.open_read(now, from, &request, file, sink, out))
                .map(|len| {
                    data.put(&len.to_le_bytes());
                }),
            Opcode::ReadFile | Opcode::BurstReadFile if !ours => Err(Nak::InvalidSession),
            Opcode::ReadFile | Opcode::BurstReadFile => self.read(now, &request).map(|file| read = Some(file)),
            // `@SYS` has no CRC (FileProtected): its text is made at each opening, with nothing kept to compare.
            Opcode::CalcFileCrc32 => self.target(&request).map(|target| {
                data.put(&self.received(target).1.to_le_bytes());
            }),
            Opcode::CreateFile | Opcode::OpenFileWO => self.open(now, context, from, &request, sink, out),
            Opcode::WriteFile if !ours => Err(Nak::InvalidSession),
            // A session that reads writes nothing.
            Opcode::WriteFile if self.reading.is_some() => Err(Nak::FileProtected),
            // The upload stops here, told why, rather than halfway through at the restart.
            Opcode::WriteFile if context.restarting || context.unsigned => match self.upload {
                Some(image) => {
                    let why = if context.restarting { RESTARTING } else { UNSIGNED };
                    self.refuse(image.target, why, sink, out)
                }
                None => Err(Nak::Fail),
            },
            // A gap is left unanswered.
            Opcode::WriteFile => self.write(now, &request, sink, out)?,
            Opcode::RemoveFile => self.remove(now, context, from, &request, sink, out),
            Opcode::Other(_) => Err(Nak::UnknownCommand),
        };
        Some(match (answer, read) {
            (Ok(()), Some(read)) => FtpAnswer::Read(read),
            (Ok(()), None) => FtpAnswer::Reply(ftp::reply(&request, ACK, data.as_bytes())),
            (Err(reason), _) => {
                self.counters.naks = self.counters.naks.wrapping_add(1);
                FtpAnswer::Reply(ftp::nak(&request, reason))
            }
        })
    }

    /// The entries of `path` from entry `first` on, as ArduPilot lists them: `F<name>\t<size>\0` for a file (an
    /// update file's size the bytes held, `versions.txt`'s its length now), `D<name>\0` for a directory (`@SYS`
    /// after the others, as ArduPilot lists its own), as many as fit in a reply (the clients ask for the next from
    /// the offset after the last they got, until [`Nak::EndOfFile`]).
    fn list(
        &self,
        path: &[u8],
        first: u32,
        context: Context,
        sink: &impl UpdateSink,
        data: &mut Buf,
    ) -> Result<(), Nak> {
        let first = usize::try_from(first).unwrap_or(usize::MAX);
        match self.lookup(path)? {
            Node::Update(_) | Node::Versions | Node::Params | Node::Crash(_) | Node::BlackBox => {
                return Err(Nak::FileNotFound);
            }
            Node::Root => {
                for name in ["update", sys::DIR, param_pck::DIR].get(first..).unwrap_or_default() {
                    if !data.entry(format_args!("D{name}\0")) {
                        break;
                    }
                }
            }
            Node::Updates => {
                for target in self.targets().skip(first) {
                    if !data.entry(format_args!("F{}\t{}\0", target, self.received(target).0)) {
                        break;
                    }
                }
            }
            Node::Sys => {
                if first == 0 {
                    data.entry(format_args!("F{}\t{}\0", sys::VERSIONS, self.versions(sink).len()));
                }
                if first <= 1 {
                    data.entry(format_args!("Dcrash\0"));
                }
                if let Some(file) = context.black_box.filter(|_| first <= 2) {
                    data.entry(format_args!("F{}\t{}\0", sys::BLACK_BOX, file.len()));
                }
            }
            Node::CrashDir => {
                let held = [None]
                    .into_iter()
                    .chain((0..MAX_THRUSTERS as u8).map(Some))
                    .map(CrashFile);
                for file in held.filter(|file| context.holds(*file)).skip(first) {
                    if !data.entry(format_args!("F{file}\t{}\0", crash_record::LEN)) {
                        break;
                    }
                }
            }
            Node::ParamDir if first == 0 => {
                let len = context.params.map_or(0, |params| {
                    ParamFile::open(&[], &params, self.frame).map_or(0, |file| u16::from_le_bytes(file.len))
                });
                data.entry(format_args!("F{}\t{len}\0", param_pck::NAME));
            }
            Node::ParamDir => {}
        }
        if data.len == 0 { Err(Nak::EndOfFile) } else { Ok(()) }
    }

    /// Whether `from` may change `target`'s file now.
    fn may_write(
        &mut self,
        context: Context,
        from: Sender,
        target: UpdateTarget,
        out: &mut impl FnMut(Outgoing),
    ) -> Result<(), Nak> {
        if from.system != context.operator {
            self.counters.refused = self.counters.refused.wrapping_add(1);
            return Err(Nak::FileProtected);
        }
        if context.restarting {
            note(out, Severity::Warning, target, RESTARTING);
            return Err(Nak::Fail);
        }
        if context.unsigned {
            note(out, Severity::Warning, target, UNSIGNED);
            return Err(Nak::Fail);
        }
        if context.armed {
            note(out, Severity::Warning, target, "disarm to update");
            return Err(Nak::Fail);
        }
        Ok(())
    }

    /// CreateFile / OpenFileWO: start an upload to the file `request` names, in a new session.
    fn open(
        &mut self,
        now: Instant,
        context: Context,
        from: Sender,
        request: &Request<'_>,
        sink: &mut impl UpdateSink,
        out: &mut impl FnMut(Outgoing),
    ) -> Result<(), Nak> {
        let target = self.target(request)?;
        self.may_write(context, from, target, out)?;
        self.new_session(now, from, request.session, true, sink, out)?;
        self.upload = Some(Image {
            target,
            whole: false,
            received: 0,
            total: 0,
            crc: 0,
        });
        self.marks = Marks::new();
        Ok(())
    }

    /// The file an OpenFileRO of `request` reads, as it stands now: `@SYS/versions.txt`, or `@PARAM/param.pck`
    /// with the parameters in force ([`Nak::Fail`] for a query it cannot serve, or before the settings are
    /// published). An update file is write-only ([`Nak::FileProtected`]).
    fn readable(&self, request: &Request<'_>, context: Context, sink: &impl UpdateSink) -> Result<OpenFile, Nak> {
        let path = request.path().map_err(|_| Nak::FileNotFound)?;
        match self.lookup(path)? {
            Node::Versions => Ok(OpenFile::Versions(self.versions(sink))),
            Node::Params => {
                let query = path.iter().position(|byte| *byte == b'?').and_then(|at| path.get(at..));
                context
                    .params
                    .and_then(|params| ParamFile::open(query.unwrap_or_default(), &params, self.frame))
                    .map(OpenFile::Params)
                    .ok_or(Nak::Fail)
            }
            Node::Crash(file) if context.holds(file) => Ok(OpenFile::Crash(file)),
            Node::BlackBox => context.black_box.map(OpenFile::BlackBox).ok_or(Nak::FileNotFound),
            Node::Update(_) => Err(Nak::FileProtected),
            _ => Err(Nak::FileNotFound),
        }
    }

    /// OpenFileRO: a new session reads `file`; its length, which the ACK carries.
    fn open_read(
        &mut self,
        now: Instant,
        from: Sender,
        request: &Request<'_>,
        file: OpenFile,
        sink: &mut impl UpdateSink,
        out: &mut impl FnMut(Outgoing),
    ) -> Result<u32, Nak> {
        self.new_session(now, from, request.session, false, sink, out)?;
        self.reading = Some(file);
        Ok(file.len())
    }

    /// Open session `id` for `from` at `now` (`upload`: to upload, otherwise to read), in place of the session
    /// open if that one has nothing left to lose: idle for [`TAKEOVER_IDLE`], or its image whole; for the
    /// operator's upload, a read of another system's too, which that system opens again (no one else's read holds
    /// an update back). Otherwise [`Nak::NoSessionsAvailable`], and the same session opening again [`Nak::Fail`].
    fn new_session(
        &mut self,
        now: Instant,
        from: Sender,
        id: u8,
        upload: bool,
        sink: &mut impl UpdateSink,
        out: &mut impl FnMut(Outgoing),
    ) -> Result<(), Nak> {
        if let Some(session) = self.session {
            if session.owner == from && session.id == id {
                // One file per session, as ArduPilot has it.
                return Err(Nak::Fail);
            }
            let whole = self.upload.is_some_and(|i| i.whole);
            let others_read = upload && self.reading.is_some() && session.owner.system != from.system;
            if !whole && !others_read && now.saturating_duration_since(session.last) < TAKEOVER_IDLE {
                return Err(Nak::NoSessionsAvailable);
            }
            self.stop(Stop::Closed, sink, out);
        }
        self.session = Some(Session {
            owner: from,
            id,
            last: now,
            reported: now,
        });
        Ok(())
    }

    /// When the session reading `@SYS/blackbox.tlog` last asked something, while one of the operator's system
    /// (`operator`) does: the black box holds its samples for it ([`crate::blackbox::Recorder::hold`]). Another
    /// system's read holds nothing, or anyone on the link could keep the vehicle from recording by reading on; its
    /// file is refused once the ring has dropped its first samples.
    pub(crate) fn black_box_read(&self, operator: u8) -> Option<Instant> {
        match (self.session, self.reading) {
            (Some(session), Some(OpenFile::BlackBox(_))) if session.owner.system == operator => Some(session.last),
            _ => None,
        }
    }

    /// ReadFile / BurstReadFile in the sender's session: as many bytes of the file it opened as the request's size
    /// asks from its offset (fewer at the end), [`Nak::EndOfFile`] at or past the end, as ArduPilot answers. A
    /// burst is this one reply, marked its last: MAVProxy and pymavlink take a reply shorter than they asked for as
    /// the end and otherwise ask for the next burst where it ends, as QGroundControl does until EndOfFile.
    fn read(&mut self, now: Instant, request: &Request<'_>) -> Result<FileRead, Nak> {
        let (Some(session), Some(file)) = (self.session.as_mut(), self.reading) else {
            // An upload's session: its file is written, not read.
            return Err(Nak::Fail);
        };
        session.last = now;
        let asked = request.data.map_or(0, <[u8]>::len);
        if asked == 0 {
            return Err(Nak::InvalidDataSize);
        }
        let left = file.len().saturating_sub(request.offset);
        let size = u8::try_from(left.min(asked as u32)).unwrap_or(u8::MAX);
        if size == 0 {
            return Err(Nak::EndOfFile);
        }
        Ok(FileRead::new(request, size, file))
    }

    /// WriteFile in the session: take its bytes in order. `None`: left unanswered (a gap).
    fn write(
        &mut self,
        now: Instant,
        request: &Request<'_>,
        sink: &mut impl UpdateSink,
        out: &mut impl FnMut(Outgoing),
    ) -> Option<Result<(), Nak>> {
        let Some((session, mut image)) = self.session.as_mut().zip(self.upload) else {
            return Some(Err(Nak::InvalidSession));
        };
        session.last = now;
        let target = image.target;
        let data = request.data.unwrap_or_default();
        // A refused write ends the session; an image whole stays as it was received (only an upload not whole is
        // dropped, [`UpdateServer::stop`]).
        if request.offset > image.received {
            if image.whole {
                // Bytes past the end of an image whole.
                return Some(self.refuse(target, LONGER, sink, out));
            }
            self.counters.gaps = self.counters.gaps.wrapping_add(1);
            return None;
        }
        // Bytes already taken, sent again: they must be the bytes taken.
        if request.offset < image.received
            && self.marks.check(request.offset, data, image.received, image.crc) == Some(false)
        {
            return Some(self.refuse(target, DIFFER, sink, out));
        }
        let skip = usize::try_from(image.received - request.offset).unwrap_or(usize::MAX);
        let Some(new) = data.get(skip..).filter(|new| !new.is_empty()) else {
            self.counters.duplicates = self.counters.duplicates.wrapping_add(1);
            return Some(Ok(()));
        };
        if image.whole {
            return Some(self.refuse(target, LONGER, sink, out));
        }
        let mut rest = new;
        if image.received == 0 {
            let Some((header, tail)) = new.split_first_chunk::<HEADER_LEN>() else {
                return Some(self.refuse(target, "header not in the first write", sink, out));
            };
            let header = match self.check_header(target, header, out) {
                Ok(header) => header,
                Err(why) => return Some(self.refuse(target, why, sink, out)),
            };
            if let Err(refused) = sink.begin(target, &header) {
                return Some(self.refuse(target, refused.why(), sink, out));
            }
            image.total = header.file_len();
            self.upload = Some(image);
            // The sink has begun it: an image of the same target held before is gone.
            self.held = self.held.filter(|held| held.target != target);
            rest = tail;
            image.received = HEADER_LEN as u32;
        }
        if rest.len() as u64 > u64::from(image.total.saturating_sub(image.received)) {
            return Some(self.refuse(target, LONGER, sink, out));
        }
        if !rest.is_empty()
            && let Err(refused) = sink.write(image.received, rest)
        {
            return Some(self.refuse(target, refused.why(), sink, out));
        }
        image.crc = ftp::crc32(image.crc, new);
        image.received += rest.len() as u32;
        image.whole = image.received == image.total;
        self.marks.push(image.received, image.crc);
        if image.whole {
            if let Err(refused) = sink.finish(true) {
                return Some(self.refuse(target, refused.why(), sink, out));
            }
            self.held = Some(image);
        }
        self.upload = Some(image);
        if let Some(session) = self.session.as_mut()
            && (image.whole || now.saturating_duration_since(session.reported) >= PROGRESS_PERIOD)
        {
            session.reported = now;
            if image.whole {
                note(out, Severity::Info, target, "received, ready to apply");
            } else {
                note_of(out, target, "", image.received, image.total);
            }
        }
        Some(Ok(()))
    }

    /// The header of an image for `target`, checked: why it is refused (a target that does not fit is told
    /// here, in full).
    fn check_header(
        &self,
        target: UpdateTarget,
        bytes: &[u8; HEADER_LEN],
        out: &mut impl FnMut(Outgoing),
    ) -> Result<ImageHeader, &'static str> {
        let (kind, max) = match target {
            UpdateTarget::Thruster(slot) => (
                self.slots
                    .get(usize::from(slot))
                    .copied()
                    .flatten()
                    .map_or(0, thruster_kind),
                THRUSTER_MAX_PAYLOAD,
            ),
            UpdateTarget::Family { family, .. } => (thruster_kind(family), THRUSTER_MAX_PAYLOAD),
            UpdateTarget::Master => (3, MASTER_MAX_PAYLOAD),
        };
        match parse_header(bytes) {
            Err(HeaderError::Magic(_)) => Err("not an update file"),
            Err(_) => Err("bad update file header"),
            Ok(header) if header.target != kind => {
                say(
                    out,
                    Severity::Warning,
                    format_args!(
                        "{}: {} image, slot is {}",
                        target,
                        kind_name(header.target),
                        kind_name(kind)
                    ),
                );
                Err("")
            }
            Ok(header) if header.payload_len == 0 || header.payload_len % 8 != 0 || header.payload_len > max => {
                Err("payload length not valid")
            }
            Ok(header) => Ok(header),
        }
    }

    /// Stop the upload with `why` (told unless empty): NAK [`Nak::Fail`].
    fn refuse(
        &mut self,
        target: UpdateTarget,
        why: &str,
        sink: &mut impl UpdateSink,
        out: &mut impl FnMut(Outgoing),
    ) -> Result<(), Nak> {
        if !why.is_empty() {
            note(out, Severity::Warning, target, why);
        }
        self.stop(Stop::Quiet, sink, out);
        Err(Nak::Fail)
    }

    /// RemoveFile: forget the image held, if it is for the file `request` names.
    fn remove(
        &mut self,
        now: Instant,
        context: Context,
        from: Sender,
        request: &Request<'_>,
        sink: &mut impl UpdateSink,
        out: &mut impl FnMut(Outgoing),
    ) -> Result<(), Nak> {
        let target = self.target(request)?;
        self.may_write(context, from, target, out)?;
        // Another client's upload of it, live (not whole, not idle long enough to be taken over): left alone.
        let uploading = self.upload.is_some_and(|i| i.target == target && !i.whole);
        if uploading
            && self
                .session
                .is_some_and(|s| s.owner != from && now.saturating_duration_since(s.last) < TAKEOVER_IDLE)
        {
            note(out, Severity::Warning, target, "another component is uploading it");
            return Err(Nak::Fail);
        }
        if self.upload.is_some_and(|i| i.target == target) {
            self.stop(Stop::Quiet, sink, out);
        }
        self.held = self.held.filter(|held| held.target != target);
        note(out, Severity::Info, target, "removed");
        Ok(())
    }

    /// Close the session; an upload in it that is not whole stops (the sink drops what it began, the image is
    /// forgotten), and `why` says so.
    fn stop(&mut self, why: Stop, sink: &mut impl UpdateSink, out: &mut impl FnMut(Outgoing)) {
        self.session = None;
        self.reading = None;
        let Some(image) = self.upload.take().filter(|i| !i.whole) else {
            return;
        };
        if image.total == 0 {
            // Nothing began: nothing to drop, or to tell.
            return;
        }
        let _ = sink.finish(false);
        match why {
            Stop::Closed => note_of(out, image.target, "stopped at", image.received, image.total),
            Stop::Armed => note(out, Severity::Warning, image.target, "stopped, armed"),
            Stop::Quiet => {}
        }
    }

    /// MAV_CMD_LBV_APPLY_UPDATE from `from` for `slot` (a thruster slot from 0, [`MASTER_SLOT`]; `None` for a
    /// param1 that is neither): `out` takes the COMMAND_ACK, then a text. One sent again while the target's apply
    /// runs starts nothing: it is answered as the one under way (IN_PROGRESS `applying` for its sender, whose final
    /// answer follows once; TEMPORARILY_REJECTED `applying` for another), never FAILED.
    pub fn apply(
        &mut self,
        context: Context,
        from: Sender,
        slot: Option<u8>,
        sink: &mut impl UpdateSink,
        out: &mut impl FnMut(Outgoing),
    ) {
        let target = slot.and_then(|slot| self.targets().find(|t| t.slot() == slot));
        let receiving = self.upload.is_some_and(|i| Some(i.target) == target && !i.whole);
        let (result, text) = match target {
            _ if from.system != context.operator => {
                self.counters.refused = self.counters.refused.wrapping_add(1);
                (AckResult::Denied, None)
            }
            None => (AckResult::Denied, Some("no such target")),
            Some(_) if context.restarting => (AckResult::TemporarilyRejected, Some(RESTARTING)),
            Some(_) if context.armed => (AckResult::TemporarilyRejected, Some("disarm to update")),
            Some(_) if receiving => (AckResult::TemporarilyRejected, Some("still receiving")),
            Some(target) if !self.is_received(target) => (AckResult::Denied, Some("nothing to apply")),
            Some(target) => match sink.apply(target, from) {
                Ok(Applied::Started) => (AckResult::InProgress, Some("applying")),
                // The same apply sent again (its answer lost): the one under way, whose final answer follows.
                Ok(Applied::Applying(by)) if by == from => (AckResult::InProgress, Some("applying")),
                Ok(Applied::Applying(_)) => (AckResult::TemporarilyRejected, Some("applying")),
                Ok(Applied::Pending) => (AckResult::TemporarilyRejected, Some("still on its way")),
                Ok(Applied::NotWired) => (AckResult::Accepted, Some("valid; not sent, no I2C yet")),
                Ok(Applied::Runs) => (AckResult::Accepted, Some("all run it already")),
                Err(_) => (AckResult::Failed, Some("not on the target: send it again")),
            },
        };
        answer(out, UpdateAction::Apply, from, target, result, text);
    }

    /// MAV_CMD_LBV_QUERY_VERSION for `slot`, from `from`: which image thruster `slot` runs, asked over its bus
    /// whatever the vehicle does (the thruster answers `Version` even while it drives). The operator's only, as it
    /// holds the courier for the exchange. IN_PROGRESS, then the courier's text (`runs 0.2.0`) and ACCEPTED, or
    /// FAILED with why; the master's own version is AUTOPILOT_VERSION's.
    pub fn query_version(
        &mut self,
        context: Context,
        from: Sender,
        slot: Option<u8>,
        sink: &mut impl UpdateSink,
        out: &mut impl FnMut(Outgoing),
    ) {
        let target = slot.and_then(|slot| self.targets().find(|t| *t == UpdateTarget::Thruster(slot)));
        let (result, text) = match (target, slot) {
            _ if from.system != context.operator => {
                self.counters.refused = self.counters.refused.wrapping_add(1);
                (AckResult::Denied, None)
            }
            (_, Some(MASTER_SLOT)) => (AckResult::Denied, Some("the master's is in AUTOPILOT_VERSION")),
            (Some(UpdateTarget::Thruster(slot)), _) => match sink.query_version(slot, from) {
                Ok(()) => (AckResult::InProgress, None),
                Err(refused) => (AckResult::TemporarilyRejected, Some(refused.why())),
            },
            _ => (AckResult::Denied, Some("no such target")),
        };
        answer(out, UpdateAction::QueryVersion, from, target, result, text);
    }
}

/// An update command's COMMAND_ACK, and its text if it has one (about `target`, or the command when it names
/// none).
fn answer(
    out: &mut impl FnMut(Outgoing),
    action: UpdateAction,
    to: Sender,
    target: Option<UpdateTarget>,
    result: AckResult,
    text: Option<&str>,
) {
    out(Outgoing::CommandAck {
        command: action.command(),
        result,
        to,
    });
    let severity = if matches!(result, AckResult::Accepted | AckResult::InProgress) {
        Severity::Info
    } else {
        Severity::Warning
    };
    match (target, text) {
        (Some(target), Some(text)) => note(out, severity, target, text),
        (None, Some(text)) => say(out, severity, format_args!("update: {text}")),
        (_, None) => {}
    }
}

/// The family whose file `name` (`/thrusters-seabotix.lbvu`) is.
fn family_named(name: &[u8]) -> Option<Family> {
    let name = name.strip_prefix(b"/")?;
    Family::ALL
        .into_iter()
        .find(|family| name == family_file(*family).as_bytes())
}

/// A target's file name: "thruster2.lbvu", "thrusters-seabotix.lbvu", "master.lbvu".
impl fmt::Display for UpdateTarget {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            UpdateTarget::Thruster(slot) => write!(f, "thruster{slot}.lbvu"),
            UpdateTarget::Family { family, .. } => f.write_str(family_file(family)),
            UpdateTarget::Master => f.write_str("master.lbvu"),
        }
    }
}

/// "thruster2.lbvu: `what`": the texts name the file, as the ground station's user wrote it.
fn note(out: &mut impl FnMut(Outgoing), severity: Severity, target: UpdateTarget, what: &str) {
    say(out, severity, format_args!("{}: {what}", target));
}

/// "thruster2.lbvu: `before` `n` of `total` bytes" (a warning when `before` says why it stopped).
fn note_of(out: &mut impl FnMut(Outgoing), target: UpdateTarget, before: &str, n: u32, total: u32) {
    let severity = if before.is_empty() {
        Severity::Info
    } else {
        Severity::Warning
    };
    let space = if before.is_empty() { "" } else { " " };
    say(
        out,
        severity,
        format_args!("{}: {before}{space}{n} of {total} bytes", target),
    );
}

fn say(out: &mut impl FnMut(Outgoing), severity: Severity, args: fmt::Arguments<'_>) {
    out(Outgoing::Text(severity, text(args)));
}

/// A reply's data being written: a listing entry, a CRC.
#[derive(Default)]
struct Buf {
    bytes: [u8; FTP_REPLY_DATA],
    len: usize,
}

impl Buf {
    fn as_bytes(&self) -> &[u8] {
        self.bytes.get(..self.len).unwrap_or_default()
    }

    /// Append `bytes`; `false`, and nothing appended, when they do not fit.
    fn put(&mut self, bytes: &[u8]) -> bool {
        let end = self.len + bytes.len();
        match self.bytes.get_mut(self.len..end) {
            Some(slot) => {
                slot.copy_from_slice(bytes);
                self.len = end;
                true
            }
            None => false,
        }
    }

    /// Append one entry; `false`, and nothing appended, when it does not fit.
    fn entry(&mut self, args: fmt::Arguments<'_>) -> bool {
        let start = self.len;
        if self.write_fmt(args).is_err() {
            self.len = start;
            return false;
        }
        true
    }
}

impl fmt::Write for Buf {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        if self.put(s.as_bytes()) {
            Ok(())
        } else {
            Err(fmt::Error)
        }
    }
}

/// What the files read are made of as a read's reply is framed: the parameters in force and the crash record
/// held (the console's transmit task takes them from [`Shared`]).
#[derive(Clone, Copy, Default)]
pub struct Contents<'a> {
    pub params: Option<&'a Params>,
    pub crash: Option<&'a [u8; crash_record::LEN]>,
    /// The black box's file: what writes its bytes from an offset ([`ReadTlog`]).
    pub black_box: Option<&'a ReadTlog<'a>>,
}

/// What writes the bytes of `@SYS/blackbox.tlog` as it was opened from an offset, as many as fit: how many, or
/// `None` when its samples are gone ([`crate::console::tlog::read`]).
pub type ReadTlog<'a> = dyn Fn(&TlogFile, u32, &mut [u8]) -> Option<usize> + 'a;

impl core::fmt::Debug for Contents<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Contents")
            .field("params", &self.params)
            .field("crash", &self.crash)
            .field("black_box", &self.black_box.is_some())
            .finish()
    }
}

impl Contents<'_> {
    /// Nothing: a read of `param.pck` or of the crash record is NAKed.
    pub const NOTHING: Contents<'static> = Contents {
        params: None,
        crash: None,
        black_box: None,
    };
}

impl OpenFile {
    /// Its length in bytes.
    fn len(&self) -> u32 {
        match self {
            Self::Versions(versions) => versions.len(),
            Self::Params(file) => u16::from_le_bytes(file.len).into(),
            Self::Crash(_) => crash_record::LEN as u32,
            Self::BlackBox(file) => file.len(),
        }
    }
}

impl FileRead {
    /// The ACK of `request`: `size` bytes of `file` from the request's offset, which is within it.
    fn new(request: &Request<'_>, size: u8, file: OpenFile) -> Self {
        Self {
            seq: request.seq.wrapping_add(1).to_le_bytes(),
            session: request.session,
            opcode: request.opcode,
            size,
            offset: request.offset.to_le_bytes(),
            file,
        }
    }

    /// Write its payload into `into`, which is zeros: its header, then the bytes it names, made from `contents`
    /// for `param.pck` and the crash record. A BurstReadFile's reply is its burst's last. A read of `param.pck` whose
    /// values have changed since it was opened, or of a record no longer held, is NAKed [`Nak::Fail`] instead.
    pub(crate) fn write_to(&self, into: &mut [u8], contents: &Contents<'_>) {
        let [s0, s1] = self.seq;
        let [o0, o1, o2, o3] = self.offset;
        let burst = u8::from(Opcode::from_byte(self.opcode) == Opcode::BurstReadFile);
        let Some((head, data)) = into.split_first_chunk_mut::<{ ftp::HEADER_LEN }>() else {
            return;
        };
        let offset = u32::from_le_bytes(self.offset);
        let read = data.get_mut(..usize::from(self.size)).and_then(|data| match self.file {
            OpenFile::Versions(versions) => Some(versions.read(offset, data)),
            OpenFile::Params(file) => contents.params.and_then(|params| file.read(offset, data, params)),
            OpenFile::Crash(_) => contents.crash.map(|record| {
                let mut window = Window::new(offset, data);
                window.put(record);
                window.filled
            }),
            OpenFile::BlackBox(file) => contents.black_box.and_then(|read| read(&file, offset, data)),
        });
        let (opcode, size) = match read {
            Some(_) => (ACK, self.size),
            None => {
                if let Some(first) = data.first_mut() {
                    *first = Nak::Fail as u8;
                }
                (ftp::NAK, 1)
            }
        };
        *head = [
            s0,
            s1,
            self.session,
            opcode,
            size,
            self.opcode,
            burst,
            0,
            o0,
            o1,
            o2,
            o3,
        ];
    }
}

/// The update server and where its images go: what the console's receive task serves MAVLink FTP and the apply
/// command with.
#[derive(Debug)]
pub struct Updates<S> {
    /// The server.
    pub(crate) server: UpdateServer,
    /// Its sink.
    pub(crate) sink: S,
}

impl<S: UpdateSink> Updates<S> {
    /// The server for `thrusters`, with `sink`.
    pub fn new(thrusters: &ThrusterTable, frame: FrameKind, sink: S) -> Self {
        Self {
            server: UpdateServer::new(thrusters, frame),
            sink,
        }
    }

    /// Serve `request` with the vehicle's state in `shared`: acknowledgements, texts and progress go to
    /// `shared.outbox` (dropped when it is full, as texts are); the FTP reply is returned, for the caller to
    /// queue there after them (the console's receive task decides whether it waits for room). The apply command
    /// over a link without signing is DENIED here, before the server sees it ([`Context::unsigned`]).
    pub fn serve(&mut self, request: UpdateRequest, shared: &Shared) -> Option<Outgoing> {
        let now = Instant::now();
        let context = Context::of(shared);
        let mut out = |message| {
            let _ = shared.outbox.try_send(message);
        };
        let UpdateRequest { from, what } = request;
        match what {
            UpdateCommand::Ftp(payload) => {
                let answer = self
                    .server
                    .request(now, context, from, &payload, &mut self.sink, &mut out);
                shared.black_box.hold(self.server.black_box_read(context.operator));
                answer.map(|reply| Outgoing::Ftp { to: from, reply })
            }
            UpdateCommand::Apply(_) if context.unsigned && from.system == context.operator => {
                answer(
                    &mut out,
                    UpdateAction::Apply,
                    from,
                    None,
                    AckResult::Denied,
                    Some(UNSIGNED),
                );
                None
            }
            UpdateCommand::Apply(slot) => {
                self.server.apply(context, from, slot, &mut self.sink, &mut out);
                // Held from the moment it is taken: an arm command read next is refused.
                self.sink.publish(&shared.holds);
                None
            }
            UpdateCommand::QueryVersion(slot) => {
                self.server.query_version(context, from, slot, &mut self.sink, &mut out);
                None
            }
        }
    }
}

#[cfg(test)]
mod tests;
