//! The field-update extension: this project's addition to the thruster interface, with which a master writes a
//! signed image into a thruster's DFU flash over the thrusters' own bus. An IDS-only master never sends it; an
//! IDS-only controller discards every frame of it.
//!
//! # Why it is safe next to the IDS
//!
//! Every frame the master writes opens with four bytes an IDS controller reads as an order (IDS 8.3: MT, SPEED,
//! INFO, CSUM):
//!
//! | byte | extension                | an IDS controller reads |
//! |------|--------------------------|-------------------------|
//! | 0    | [`EXT_MT`] (0x80)        | MT                      |
//! | 1    | the command              | SPEED                   |
//! | 2    | a sequence number        | INFO                    |
//! | 3    | GUARD = b0 + b1 + b2 + 0x80 (mod 256) | CSUM       |
//!
//! GUARD differs from the 8-bit sum of bytes 0..3 by 0x80, whatever they are, so the CSUM an IDS controller checks
//! is always wrong and the frame is discarded (IDS 6.6.1: "In the event of an invalid checksum being received, the
//! incoming message shall be discarded"): a controller that takes only the first four bytes (the STM32's slave
//! drops what overflows its buffer), one that ignores MT, or one that checks the length first all drop it.
//!
//! MT 0x80 is neither order type (0x52, 0x54) nor status type (0x53, 0x55), and at least three bits away from
//! each, so no single or double bit error turns an IDS message into an extension frame or back. It is also a
//! zero SPEED (IDS 8.3: "7F and 80 are zero speed"), for one more reading of the IDS: were a controller to take
//! the address byte as MT (8.3: "This value addresses the thruster") and the written bytes as SPEED, INFO, CSUM,
//! GUARD would not be looked at, and one frame in 256 (a sequence number that happens to match) would check as
//! an order; with this MT that order is a stop, which is what every thruster is ordered to during an update
//! anyway. (Such a controller would misread every order of this project's master too.) The replies open with
//! [`EXT_REPLY_MT`] (0x81), three bits or more from the status types.
//!
//! # Exchanges
//!
//! The master writes a command ([`CommandFrame`]) and then reads its reply ([`Reply`]) with a plain I2C read of
//! [`reply_len`] bytes. A thruster answers a read with its status frame (byte 0 = 0x53 or 0x55) unless an
//! extension command arrived since the last read; then with the reply to that command. It keeps one reply at a
//! time: a newer command replaces it. A reply not ready yet reads as [`Reply::Busy`], and the master reads again;
//! a reply read once is gone (the next read is the status), so a master that lost one sends the command again with
//! the same sequence number: every command can be repeated. So a master tells "no extension" from byte 0 of the
//! first reply: an IDS-only thruster answers the read with its status.
//!
//! A master reads [`Command::Version`] first: it says whether the thruster can take an update at all (it is not on
//! trial, it checks signatures).
//!
//! After an [`Command::Erase`] the master waits [`ERASE_WAIT_MS`] before it reads: a page erase stalls the G431's
//! CPU for about 25 ms, and a read that meets it is held (SCL stretched) until the master's 25 ms timeout.
//! After a [`Command::Finish`] it waits [`FINISH_WAIT_MS`]: the thruster hashes the payload, checks its signature and
//! writes the bootloader's state.
//!
//! Each frame ends with a CRC-32 ([`crc32`]) of every byte before it. The IDS's 8-bit sum misses many double
//! errors and every swap of two bytes; a frame carries up to 64 bytes of an image and offsets into the flash, and
//! CRC-32 finds every error of up to 4 bits in frames of this length (up to 80 bytes), every burst up to 32 bits,
//! and all but about one in 2^32 of the others. CRC-16/CCITT would do for the frames, but the same CRC also stands
//! for up to the whole payload in [`Command::Check`]'s reply, where a master resuming an interrupted transfer
//! compares it with its own, and 2^-16 is too weak there. It is computed bit by bit (no table, a few dozen bytes of
//! code): a 64-byte chunk costs a few microseconds on the thruster.
//!
//! Frames are at most [`MAX_FRAME_LEN`] (80) bytes, so a thruster's receive buffer stays small. Multi-byte fields
//! are little-endian.
//!
//! ```
//! use tmc_proto::ext::{Command, CommandFrame, Reply, ReplyBody};
//!
//! let frame = CommandFrame { seq: 7, command: Command::Erase { page: 3 } };
//! let bytes = frame.encode();
//! // The first four bytes never check as an IDS order: CSUM is off by 0x80.
//! let [b0, b1, b2, b3, ..] = *bytes.as_bytes() else { unreachable!() };
//! assert_eq!(b0.wrapping_add(b1).wrapping_add(b2) ^ b3, 0x80);
//! assert_eq!(CommandFrame::decode(bytes.as_bytes()), Ok(frame));
//!
//! let reply = Reply::Done { seq: 7, body: ReplyBody::Erase { page: 3 } };
//! assert_eq!(Reply::decode(reply.encode().as_bytes()), Ok(reply));
//! ```

use core::fmt;

/// Byte 0 of every frame a master writes (see the module's documentation for the choice).
pub const EXT_MT: u8 = 0x80;

/// Byte 0 of every reply a thruster sends.
pub const EXT_REPLY_MT: u8 = 0x81;

/// The extension's version, in [`ReplyBody::Version`]: what a thruster takes. 1: the update's commands;
/// 2 adds [`Command::PostMortem`], which a master sends only to a thruster of version 2 or more. Nothing else
/// changed, so masters of either version update thrusters of either.
pub const PROTOCOL_VERSION: u8 = 2;

/// The longest frame either way, in bytes (a [`Command::Write`] of [`MAX_CHUNK`] bytes is 77).
pub const MAX_FRAME_LEN: usize = 80;

/// The most image bytes one [`Command::Write`] carries.
pub const MAX_CHUNK: usize = 64;

/// The length of an ed25519 signature.
pub const SIGNATURE_LEN: usize = 64;

/// The length of an image's information record (update-image's `ImageInfo`).
pub const INFO_LEN: usize = 32;

/// The length of a post-mortem record ([`Command::PostMortem`]): the crash-record crate's `LEN`.
pub const RECORD_LEN: usize = 128;

/// The unit of [`Command::Erase`]: one page of the STM32G431's flash (RM0440 3.3.1: 2 KiB pages).
pub const PAGE_LEN: u32 = 2048;

/// The unit the payload is written in: the G431's flash programs double words (RM0440 3.3.7). A payload's length
/// and every write's offset are multiples of it.
pub const WRITE_UNIT: u32 = 8;

/// How long a master waits after an [`Command::Erase`] before it reads the reply, in milliseconds: the G431's page
/// erase (about 25 ms, as the bench charges it) and a margin. A reply still [`Reply::Busy`] is read again a
/// little later.
pub const ERASE_WAIT_MS: u32 = 30;

/// How long a master waits after a [`Command::Finish`] before it reads the reply, in milliseconds: the payload's
/// hash, the signature check and the bootloader state's page erase.
pub const FINISH_WAIT_MS: u32 = 200;

/// Bytes before a frame's fields: MT, command, sequence number, and GUARD (commands) or the result (replies).
const HEADER_LEN: usize = 4;

/// The CRC that ends every frame.
const CRC_LEN: usize = 4;

/// The shortest frame: a header and its CRC.
pub const MIN_FRAME_LEN: usize = HEADER_LEN + CRC_LEN;

/// GUARD, byte 3 of a command frame: the IDS checksum of bytes 0..3 plus 0x80, so that the four bytes never check
/// as an IDS order.
pub const fn guard(mt: u8, command: u8, seq: u8) -> u8 {
    crate::checksum(&[mt, command, seq]).wrapping_add(0x80)
}

/// CRC-32 (IEEE 802.3, as zlib and PNG: reflected polynomial 0xEDB88320, initial and final XOR 0xFFFFFFFF) of
/// `bytes`. `crc32(b"123456789")` is 0xCBF43926.
// Out of line: every encoder and decoder calls it.
#[inline(never)]
pub const fn crc32(bytes: &[u8]) -> u32 {
    Crc32::new().update(bytes).finish()
}

/// A CRC-32 ([`crc32`]) computed over bytes that come in pieces.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Crc32(u32);

impl Crc32 {
    /// Nothing seen yet.
    pub const fn new() -> Self {
        Crc32(0xFFFF_FFFF)
    }

    /// The CRC so far, followed by `bytes`.
    pub const fn update(self, bytes: &[u8]) -> Self {
        let mut crc = self.0;
        let mut rest = bytes;
        while let [byte, tail @ ..] = rest {
            crc ^= *byte as u32;
            let mut bit = 0;
            while bit < 8 {
                // Bit by bit, no table: the receiver's flash is scarce and its chunks are short.
                crc = (crc >> 1) ^ (0xEDB8_8320 & (crc & 1).wrapping_neg());
                bit += 1;
            }
            rest = tail;
        }
        Crc32(crc)
    }

    /// The CRC of everything seen.
    pub const fn finish(self) -> u32 {
        !self.0
    }
}

impl Default for Crc32 {
    fn default() -> Self {
        Self::new()
    }
}

/// The commands, as byte 1 of a frame carries them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum CommandKind {
    /// [`Command::Version`].
    Version = 1,
    /// [`Command::Begin`].
    Begin = 2,
    /// [`Command::Erase`].
    Erase = 3,
    /// [`Command::Write`].
    Write = 4,
    /// [`Command::Check`].
    Check = 5,
    /// [`Command::Finish`].
    Finish = 6,
    /// [`Command::Reboot`].
    Reboot = 7,
    /// [`Command::PostMortem`] (protocol 2).
    PostMortem = 8,
}

impl CommandKind {
    /// Every command.
    pub const ALL: [CommandKind; 8] = [
        CommandKind::Version,
        CommandKind::Begin,
        CommandKind::Erase,
        CommandKind::Write,
        CommandKind::Check,
        CommandKind::Finish,
        CommandKind::Reboot,
        CommandKind::PostMortem,
    ];

    /// Its byte.
    pub const fn to_byte(self) -> u8 {
        self as u8
    }

    /// The command a byte names, if any.
    pub const fn from_byte(byte: u8) -> Option<CommandKind> {
        match byte {
            1 => Some(CommandKind::Version),
            2 => Some(CommandKind::Begin),
            3 => Some(CommandKind::Erase),
            4 => Some(CommandKind::Write),
            5 => Some(CommandKind::Check),
            6 => Some(CommandKind::Finish),
            7 => Some(CommandKind::Reboot),
            8 => Some(CommandKind::PostMortem),
            _ => None,
        }
    }

    /// Its name, for logs and operators.
    pub const fn name(self) -> &'static str {
        match self {
            CommandKind::Version => "version",
            CommandKind::Begin => "begin",
            CommandKind::Erase => "erase",
            CommandKind::Write => "write",
            CommandKind::Check => "check",
            CommandKind::Finish => "finish",
            CommandKind::Reboot => "reboot",
            CommandKind::PostMortem => "post-mortem",
        }
    }

    /// The length of the fields of its reply when it is done ([`Reply::Done`]); a busy or refused reply has the same
    /// length, its fields zero.
    const fn reply_fields_len(self) -> usize {
        match self {
            CommandKind::Version => 2 + 4 + INFO_LEN,
            CommandKind::Begin | CommandKind::Finish => 4,
            CommandKind::Erase => 2,
            CommandKind::Write => 4 + 1 + 4,
            CommandKind::Check => 4 + 4 + 4,
            CommandKind::Reboot => 0,
            CommandKind::PostMortem => 2 + MAX_CHUNK,
        }
    }
}

/// The length of every reply to `command`, done, busy or refused: what a master reads after sending it.
pub const fn reply_len(command: CommandKind) -> usize {
    HEADER_LEN + command.reply_fields_len() + CRC_LEN
}

/// Up to [`MAX_CHUNK`] bytes of the image, for [`Command::Write`].
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct Chunk {
    len: u8,
    bytes: [u8; MAX_CHUNK],
}

impl Chunk {
    /// The chunk of `data`, or `None` when it is empty or longer than [`MAX_CHUNK`].
    pub fn new(data: &[u8]) -> Option<Chunk> {
        let len = u8::try_from(data.len())
            .ok()
            .filter(|len| (1..=MAX_CHUNK as u8).contains(len))?;
        let mut bytes = [0; MAX_CHUNK];
        bytes.get_mut(..data.len())?.copy_from_slice(data);
        Some(Chunk { len, bytes })
    }

    /// Its bytes.
    pub fn as_slice(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or(&self.bytes)
    }

    /// How many bytes it holds, 1..=64.
    pub fn len(&self) -> u8 {
        self.len
    }

    /// Never: a chunk holds at least one byte.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

impl fmt::Debug for Chunk {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_tuple("Chunk").field(&self.as_slice()).finish()
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for Chunk {
    fn format(&self, fmt: defmt::Formatter) {
        defmt::write!(fmt, "Chunk({=u8} bytes)", self.len)
    }
}

/// What a master asks a thruster to do. Offsets are from the DFU partition's start, where the payload goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Command {
    /// Say what runs: the running image's information record, whether it is on trial, this extension's version.
    /// Answered in any state.
    Version,
    /// Start an update of a payload of `payload_len` bytes (a multiple of [`WRITE_UNIT`], at most the ACTIVE
    /// partition) for `target` (the update file's target byte, as its header gives it: 1 SeaBotix thruster,
    /// 2 Legacy thruster, 3 master), so that a file for another target is refused before it is sent. Refused
    /// unless the thruster is ordered to zero speed and at zero duty. Erases nothing: a transfer interrupted by a
    /// reset starts again with `Begin` and resumes ([`Command::Check`]).
    Begin {
        /// The payload's length in bytes.
        payload_len: u32,
        /// The update file's target byte.
        target: u8,
    },
    /// Erase one [`PAGE_LEN`] page of the DFU partition, within the payload: the master asks for each page on
    /// its own, because an erase stalls the thruster's CPU (its commutation included) for about 25 ms.
    Erase {
        /// The page, counted from the DFU partition's start.
        page: u16,
    },
    /// Write `data` at `offset` (a multiple of [`WRITE_UNIT`]) into erased flash; a short last chunk is padded
    /// with 0xFF to the write unit. The reply carries the CRC of what the flash then holds there.
    Write {
        /// Where, from the DFU partition's start.
        offset: u32,
        /// What.
        data: Chunk,
    },
    /// The CRC of `len` bytes of the DFU partition from `offset`, as read back: a master resuming an interrupted
    /// transfer finds the first chunk that differs.
    Check {
        /// Where, from the DFU partition's start.
        offset: u32,
        /// How many bytes.
        len: u32,
    },
    /// The payload is written: check that its information record names this thruster's target, check its
    /// signature (ed25519 over the payload's SHA-512, as embassy-boot verifies) and mark it for the bootloader to
    /// swap in at the next reset.
    Finish {
        /// The payload's length, as in [`Command::Begin`].
        payload_len: u32,
        /// The update file's signature.
        signature: [u8; SIGNATURE_LEN],
    },
    /// Reset, so that the bootloader swaps the new image in; only after a successful [`Command::Finish`].
    Reboot,
    /// Up to [`MAX_CHUNK`] bytes of the post-mortem record the thruster kept from the stop before its start (the
    /// crash-record crate's [`RECORD_LEN`]-byte record), from `offset`. Protocol 2 on: a master asks only a thruster
    /// whose `Version` says [`PROTOCOL_VERSION`] 2 or more. Answered in any state: it reads RAM, nothing else.
    PostMortem {
        /// Where in the record.
        offset: u8,
    },
}

impl Command {
    /// Which command it is.
    pub const fn kind(&self) -> CommandKind {
        match self {
            Command::Version => CommandKind::Version,
            Command::Begin { .. } => CommandKind::Begin,
            Command::Erase { .. } => CommandKind::Erase,
            Command::Write { .. } => CommandKind::Write,
            Command::Check { .. } => CommandKind::Check,
            Command::Finish { .. } => CommandKind::Finish,
            Command::Reboot => CommandKind::Reboot,
            Command::PostMortem { .. } => CommandKind::PostMortem,
        }
    }
}

/// A command as the master writes it: the command and a sequence number, which its reply echoes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CommandFrame {
    /// Chosen by the master (counting up, say): it tells the reply to this command from an older one.
    pub seq: u8,
    /// What to do.
    pub command: Command,
}

/// Why a read-back or a command was refused: every reason its own code, for the master to show the operator.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Refusal {
    /// The thruster is ordered to a non-zero speed, or its duty is not zero yet: flash work would stall its
    /// commutation. An update under way is dropped as soon as a non-zero speed is ordered.
    Driving = 2,
    /// The running image is on trial (the bootloader swapped it in and it has not confirmed itself yet): the
    /// bootloader's state cannot take another update until it has.
    OnTrial = 3,
    /// No update under way: [`Command::Begin`] first (a reset or a non-zero order drops one).
    NotBegun = 4,
    /// A page, offset or length outside the payload (or the DFU partition).
    OutOfRange = 5,
    /// An offset, or a payload length, that is not a multiple of [`WRITE_UNIT`].
    Unaligned = 6,
    /// A payload longer than the ACTIVE partition it would be swapped into.
    TooLarge = 7,
    /// The payload is too short to hold its information record, or [`Command::Finish`]'s length is not
    /// [`Command::Begin`]'s.
    Truncated = 8,
    /// The update is for another target: the other controller family, or the master.
    WrongFamily = 9,
    /// The payload has no information record (update-image's `ImageInfo`, "LBVI" format 1) at 0x200.
    NoImageInfo = 10,
    /// The signature does not check against this thruster's key.
    BadSignature = 11,
    /// The flash reported an error.
    FlashError = 12,
    /// The flash where a write goes holds other data: erase its page first.
    NotErased = 13,
    /// [`Command::Reboot`] before a successful [`Command::Finish`].
    NotFinished = 14,
    /// An update is finished and marked for the bootloader: only [`Command::Reboot`] (or a reset) now.
    Finished = 15,
    /// The thruster's firmware cannot check signatures, so it marks no payload for the bootloader.
    NoSignatureCheck = 16,
    /// The image is older than the one that runs, and was not signed as a rollback.
    Older = 17,
    /// The image's security counter is below the running image's.
    CounterBelow = 18,
    /// The image's information record is of format 1: it names no update key, so nothing after it could be
    /// checked.
    NoKey = 19,
}

impl Refusal {
    /// Every refusal.
    pub const ALL: [Refusal; 18] = [
        Refusal::Driving,
        Refusal::OnTrial,
        Refusal::NotBegun,
        Refusal::OutOfRange,
        Refusal::Unaligned,
        Refusal::TooLarge,
        Refusal::Truncated,
        Refusal::WrongFamily,
        Refusal::NoImageInfo,
        Refusal::BadSignature,
        Refusal::FlashError,
        Refusal::NotErased,
        Refusal::NotFinished,
        Refusal::Finished,
        Refusal::NoSignatureCheck,
        Refusal::Older,
        Refusal::CounterBelow,
        Refusal::NoKey,
    ];

    /// Its result code.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The refusal of a result code, if it is one.
    pub const fn from_code(code: u8) -> Option<Refusal> {
        match code {
            2 => Some(Refusal::Driving),
            3 => Some(Refusal::OnTrial),
            4 => Some(Refusal::NotBegun),
            5 => Some(Refusal::OutOfRange),
            6 => Some(Refusal::Unaligned),
            7 => Some(Refusal::TooLarge),
            8 => Some(Refusal::Truncated),
            9 => Some(Refusal::WrongFamily),
            10 => Some(Refusal::NoImageInfo),
            11 => Some(Refusal::BadSignature),
            12 => Some(Refusal::FlashError),
            13 => Some(Refusal::NotErased),
            14 => Some(Refusal::NotFinished),
            15 => Some(Refusal::Finished),
            16 => Some(Refusal::NoSignatureCheck),
            17 => Some(Refusal::Older),
            18 => Some(Refusal::CounterBelow),
            19 => Some(Refusal::NoKey),
            _ => None,
        }
    }

    /// What it means, for the operator.
    pub const fn describe(self) -> &'static str {
        match self {
            Refusal::Driving => "the thruster is ordered to turn or still driving: order zero first",
            Refusal::OnTrial => "the running image is on trial and has not confirmed itself yet",
            Refusal::NotBegun => "no update under way (begin first)",
            Refusal::OutOfRange => "outside the payload or the update partition",
            Refusal::Unaligned => "not a multiple of the 8-byte write unit",
            Refusal::TooLarge => "the payload is larger than the partition it runs from",
            Refusal::Truncated => "the payload is too short, or its length is not the one begun with",
            Refusal::WrongFamily => "the image is for another target",
            Refusal::NoImageInfo => "the payload has no image information record",
            Refusal::BadSignature => "the signature does not check",
            Refusal::FlashError => "the flash reported an error",
            Refusal::NotErased => "the flash there is not erased: erase its page first",
            Refusal::NotFinished => "no finished update to reboot into",
            Refusal::Finished => "an update is finished: reboot to start it",
            Refusal::NoSignatureCheck => "this thruster's firmware cannot check signatures: it takes no update",
            Refusal::Older => "the image is older than the one that runs, and not signed as a rollback",
            Refusal::CounterBelow => "the image's security counter is below the running image's",
            Refusal::NoKey => "the image names no update key (image info format 1)",
        }
    }
}

/// Result code of a done command.
const RESULT_OK: u8 = 0;
/// Result code of a reply not ready yet.
const RESULT_BUSY: u8 = 1;

/// What a done command answers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ReplyBody {
    /// To [`Command::Version`].
    Version {
        /// The extension's version the thruster speaks ([`PROTOCOL_VERSION`]).
        protocol: u8,
        /// The running image is on trial (see [`Refusal::OnTrial`]); flags bit 0.
        on_trial: bool,
        /// The thruster checks signatures, so a finished update can be marked (see
        /// [`Refusal::NoSignatureCheck`]); flags bit 1. Its bootloader checks each image before it swaps it in.
        checks_signatures: bool,
        /// It holds an update marked for its bootloader, which the next reset swaps in ([`Command::Finish`] done,
        /// no [`Command::Reboot`] yet); flags bit 2.
        marked: bool,
        /// The running image takes update files signed with the development key, whose secret is published;
        /// flags bit 3.
        dev_key: bool,
        /// Why its bootloader refused the last image marked, as update-image's `Verdict` codes it (1..=15), or 0
        /// for no refusal since; flags bits 4-7.
        verdict: u8,
        /// The longest payload it takes: its ACTIVE partition.
        max_payload: u32,
        /// The running image's information record, as its flash holds it (update-image's `ImageInfo`).
        info: [u8; INFO_LEN],
    },
    /// To [`Command::Begin`]: the payload length begun with.
    Begin {
        /// As in the command.
        payload_len: u32,
    },
    /// To [`Command::Erase`]: the page erased.
    Erase {
        /// As in the command.
        page: u16,
    },
    /// To [`Command::Write`]: where, how many bytes, and the CRC of what the flash holds there now.
    Write {
        /// As in the command.
        offset: u32,
        /// The chunk's length, as in the command (the padding is not counted).
        len: u8,
        /// [`crc32`] of the `len` bytes read back from the flash.
        crc: u32,
    },
    /// To [`Command::Check`].
    Check {
        /// As in the command.
        offset: u32,
        /// As in the command.
        len: u32,
        /// [`crc32`] of the bytes read back.
        crc: u32,
    },
    /// To [`Command::Finish`]: the payload checked and marked for the bootloader.
    Finish {
        /// As in the command.
        payload_len: u32,
    },
    /// To [`Command::Reboot`]: the thruster resets once this reply has been read.
    Reboot,
    /// To [`Command::PostMortem`]: the record's length (0: the thruster holds none, [`RECORD_LEN`] otherwise), and
    /// its bytes from `offset`, zero past its end.
    PostMortem {
        /// The record's length: 0 or [`RECORD_LEN`].
        len: u8,
        /// As in the command.
        offset: u8,
        /// The bytes.
        data: [u8; MAX_CHUNK],
    },
}

impl ReplyBody {
    /// The command it answers.
    pub const fn kind(&self) -> CommandKind {
        match self {
            ReplyBody::Version { .. } => CommandKind::Version,
            ReplyBody::Begin { .. } => CommandKind::Begin,
            ReplyBody::Erase { .. } => CommandKind::Erase,
            ReplyBody::Write { .. } => CommandKind::Write,
            ReplyBody::Check { .. } => CommandKind::Check,
            ReplyBody::Finish { .. } => CommandKind::Finish,
            ReplyBody::Reboot => CommandKind::Reboot,
            ReplyBody::PostMortem { .. } => CommandKind::PostMortem,
        }
    }
}

/// A thruster's reply to a command: byte 0 [`EXT_REPLY_MT`], the command and its sequence number echoed, the
/// result code (0 done, 1 busy, a [`Refusal`]'s code), the fields, the CRC. Every reply to a command has its
/// [`reply_len`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Reply {
    /// The command was carried out.
    Done {
        /// The command's sequence number.
        seq: u8,
        /// What it answers.
        body: ReplyBody,
    },
    /// The command is still being carried out (an erase, the signature check): read again.
    Busy {
        /// The command's sequence number.
        seq: u8,
        /// The command.
        command: CommandKind,
    },
    /// The command was refused, and changed nothing.
    Refused {
        /// The command's sequence number.
        seq: u8,
        /// The command.
        command: CommandKind,
        /// Why.
        refusal: Refusal,
    },
}

impl Reply {
    /// The command it answers.
    pub const fn command(&self) -> CommandKind {
        match self {
            Reply::Done { body, .. } => body.kind(),
            Reply::Busy { command, .. } | Reply::Refused { command, .. } => *command,
        }
    }

    /// The sequence number of the command it answers.
    pub const fn seq(&self) -> u8 {
        match *self {
            Reply::Done { seq, .. } | Reply::Busy { seq, .. } | Reply::Refused { seq, .. } => seq,
        }
    }
}

/// Why bytes are not an extension frame. Decoders check in this order: length, MT, GUARD (commands), then for
/// commands the CRC and the command, for replies the command, its length and the CRC; then the fields.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// Fewer than [`MIN_FRAME_LEN`] bytes.
    Short {
        /// Bytes received.
        len: usize,
    },
    /// More than [`MAX_FRAME_LEN`] bytes.
    TooLong {
        /// Bytes received.
        len: usize,
    },
    /// Byte 0 is not the frame's MT. A reply read from a thruster without the extension fails here with its
    /// status type, 0x53 or 0x55.
    MessageType {
        /// MT expected.
        expected: u8,
        /// Byte 0 received.
        actual: u8,
    },
    /// A command's byte 3 is not its GUARD.
    Guard {
        /// GUARD of bytes 0..3.
        expected: u8,
        /// Byte 3 received.
        actual: u8,
    },
    /// The CRC does not match.
    Crc {
        /// CRC computed over the bytes received.
        expected: u32,
        /// CRC received.
        actual: u32,
    },
    /// Byte 1 names no command.
    UnknownCommand(u8),
    /// The frame's length is not its command's.
    Length {
        /// The command.
        command: CommandKind,
        /// Its length, in bytes.
        expected: usize,
        /// Bytes received.
        actual: usize,
    },
    /// A write whose chunk is empty or longer than [`MAX_CHUNK`].
    ChunkLength(u8),
    /// A reply's result code names no result.
    UnknownResult(u8),
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            FrameError::Short { len } => write!(f, "extension frame of {len} bytes, shorter than {MIN_FRAME_LEN}"),
            FrameError::TooLong { len } => write!(f, "extension frame of {len} bytes, longer than {MAX_FRAME_LEN}"),
            FrameError::MessageType { expected, actual } => {
                write!(f, "wrong message type: expected {expected:#04x}, got {actual:#04x}")
            }
            FrameError::Guard { expected, actual } => {
                write!(f, "bad guard byte: computed {expected:#04x}, received {actual:#04x}")
            }
            FrameError::Crc { expected, actual } => {
                write!(f, "bad CRC: computed {expected:#010x}, received {actual:#010x}")
            }
            FrameError::UnknownCommand(byte) => write!(f, "unknown extension command {byte:#04x}"),
            FrameError::Length {
                command,
                expected,
                actual,
            } => write!(f, "{} frame of {actual} bytes, expected {expected}", command.name()),
            FrameError::ChunkLength(len) => write!(f, "write of {len} bytes, expected 1..={MAX_CHUNK}"),
            FrameError::UnknownResult(code) => write!(f, "unknown result code {code}"),
        }
    }
}

impl core::error::Error for FrameError {}

/// An encoded frame, at most [`MAX_FRAME_LEN`] bytes.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct FrameBytes {
    bytes: [u8; MAX_FRAME_LEN],
    len: u8,
}

impl FrameBytes {
    const fn empty() -> Self {
        FrameBytes {
            bytes: [0; MAX_FRAME_LEN],
            len: 0,
        }
    }

    /// The frame's bytes.
    pub fn as_bytes(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or(&self.bytes)
    }

    /// Append `bytes`; what would not fit is dropped (no frame this module builds comes near the limit).
    fn put(&mut self, bytes: &[u8]) {
        let start = usize::from(self.len);
        let end = start.saturating_add(bytes.len());
        if let Some(slot) = self.bytes.get_mut(start..end) {
            slot.copy_from_slice(bytes);
            self.len = end as u8;
        }
    }

    /// Append the CRC of everything so far.
    fn seal(mut self) -> Self {
        let crc = crc32(self.as_bytes());
        self.put(&crc.to_le_bytes());
        self
    }
}

impl fmt::Debug for FrameBytes {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_tuple("FrameBytes").field(&self.as_bytes()).finish()
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for FrameBytes {
    fn format(&self, fmt: defmt::Formatter) {
        defmt::write!(fmt, "{=[u8]:x}", self.as_bytes())
    }
}

/// Reads a frame's fields front to back; running out gives zeros, which the decoders' length checks rule out.
struct Fields<'a>(&'a [u8]);

impl Fields<'_> {
    fn array<const N: usize>(&mut self) -> [u8; N] {
        match self.0.split_first_chunk::<N>() {
            Some((head, tail)) => {
                self.0 = tail;
                *head
            }
            None => [0; N],
        }
    }

    fn u8(&mut self) -> u8 {
        let [byte] = self.array();
        byte
    }

    fn u16(&mut self) -> u16 {
        u16::from_le_bytes(self.array())
    }

    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.array())
    }
}

/// The frame without its CRC, and whether the CRC matches.
fn split_crc(bytes: &[u8]) -> Result<&[u8], FrameError> {
    let Some((body, crc)) = bytes.split_last_chunk::<CRC_LEN>() else {
        return Err(FrameError::Short { len: bytes.len() });
    };
    let (expected, actual) = (crc32(body), u32::from_le_bytes(*crc));
    if expected != actual {
        return Err(FrameError::Crc { expected, actual });
    }
    Ok(body)
}

impl CommandFrame {
    /// The frame's bytes: MT, command, sequence number, GUARD, the fields, the CRC.
    pub fn encode(&self) -> FrameBytes {
        let kind = self.command.kind().to_byte();
        let mut out = FrameBytes::empty();
        out.put(&[EXT_MT, kind, self.seq, guard(EXT_MT, kind, self.seq)]);
        match &self.command {
            Command::Version | Command::Reboot => {}
            Command::Begin { payload_len, target } => {
                out.put(&payload_len.to_le_bytes());
                out.put(&[*target]);
            }
            Command::Erase { page } => out.put(&page.to_le_bytes()),
            Command::Write { offset, data } => {
                out.put(&offset.to_le_bytes());
                out.put(&[data.len()]);
                out.put(data.as_slice());
            }
            Command::Check { offset, len } => {
                out.put(&offset.to_le_bytes());
                out.put(&len.to_le_bytes());
            }
            Command::Finish { payload_len, signature } => {
                out.put(&payload_len.to_le_bytes());
                out.put(signature);
            }
            Command::PostMortem { offset } => out.put(&[*offset]),
        }
        out.seal()
    }

    /// Decode a frame a master wrote, all of it: checks its length, MT, GUARD, CRC, command, its length for that
    /// command, and a write's chunk length, in this order.
    pub fn decode(bytes: &[u8]) -> Result<CommandFrame, FrameError> {
        let len = bytes.len();
        if len > MAX_FRAME_LEN {
            return Err(FrameError::TooLong { len });
        }
        let Some(([mt, command, seq, guard_byte], _)) = bytes.split_first_chunk::<HEADER_LEN>() else {
            return Err(FrameError::Short { len });
        };
        if len < MIN_FRAME_LEN {
            return Err(FrameError::Short { len });
        }
        if *mt != EXT_MT {
            return Err(FrameError::MessageType {
                expected: EXT_MT,
                actual: *mt,
            });
        }
        let expected = guard(*mt, *command, *seq);
        if *guard_byte != expected {
            return Err(FrameError::Guard {
                expected,
                actual: *guard_byte,
            });
        }
        let body = split_crc(bytes)?;
        let kind = CommandKind::from_byte(*command).ok_or(FrameError::UnknownCommand(*command))?;
        let mut fields = Fields(body.get(HEADER_LEN..).unwrap_or_default());
        let expected_len = |fields_len: usize| {
            let expected = HEADER_LEN + fields_len + CRC_LEN;
            if len == expected {
                Ok(())
            } else {
                Err(FrameError::Length {
                    command: kind,
                    expected,
                    actual: len,
                })
            }
        };
        let command = match kind {
            CommandKind::Version => {
                expected_len(0)?;
                Command::Version
            }
            CommandKind::Reboot => {
                expected_len(0)?;
                Command::Reboot
            }
            CommandKind::Begin => {
                expected_len(5)?;
                Command::Begin {
                    payload_len: fields.u32(),
                    target: fields.u8(),
                }
            }
            CommandKind::Erase => {
                expected_len(2)?;
                Command::Erase { page: fields.u16() }
            }
            CommandKind::Write => {
                // The length byte sits behind the offset: a frame too short to hold them is judged on them.
                let offset = fields.u32();
                let chunk_len = fields.u8();
                expected_len(5 + usize::from(chunk_len))?;
                let data = Chunk::new(fields.0).ok_or(FrameError::ChunkLength(chunk_len))?;
                Command::Write { offset, data }
            }
            CommandKind::Check => {
                expected_len(8)?;
                Command::Check {
                    offset: fields.u32(),
                    len: fields.u32(),
                }
            }
            CommandKind::Finish => {
                expected_len(4 + SIGNATURE_LEN)?;
                Command::Finish {
                    payload_len: fields.u32(),
                    signature: fields.array(),
                }
            }
            CommandKind::PostMortem => {
                expected_len(1)?;
                Command::PostMortem { offset: fields.u8() }
            }
        };
        Ok(CommandFrame { seq: *seq, command })
    }
}

impl Reply {
    /// The reply's bytes: MT, command, sequence number, result code, the fields (zero unless done), the CRC; always
    /// [`reply_len`] of its command.
    // Out of line: a thruster encodes both its busy and its done replies with it.
    #[inline(never)]
    pub fn encode(&self) -> FrameBytes {
        let kind = self.command();
        let result = match self {
            Reply::Done { .. } => RESULT_OK,
            Reply::Busy { .. } => RESULT_BUSY,
            Reply::Refused { refusal, .. } => refusal.code(),
        };
        let mut out = FrameBytes::empty();
        out.put(&[EXT_REPLY_MT, kind.to_byte(), self.seq(), result]);
        match self {
            Reply::Done { body, .. } => match body {
                ReplyBody::Version {
                    protocol,
                    on_trial,
                    checks_signatures,
                    marked,
                    dev_key,
                    verdict,
                    max_payload,
                    info,
                } => {
                    let flags = u8::from(*on_trial)
                        | u8::from(*checks_signatures) << 1
                        | u8::from(*marked) << 2
                        | u8::from(*dev_key) << 3
                        | (*verdict & 0x0F) << 4;
                    out.put(&[*protocol, flags]);
                    out.put(&max_payload.to_le_bytes());
                    out.put(info);
                }
                ReplyBody::Begin { payload_len } | ReplyBody::Finish { payload_len } => {
                    out.put(&payload_len.to_le_bytes())
                }
                ReplyBody::Erase { page } => out.put(&page.to_le_bytes()),
                ReplyBody::Write { offset, len, crc } => {
                    out.put(&offset.to_le_bytes());
                    out.put(&[*len]);
                    out.put(&crc.to_le_bytes());
                }
                ReplyBody::Check { offset, len, crc } => {
                    out.put(&offset.to_le_bytes());
                    out.put(&len.to_le_bytes());
                    out.put(&crc.to_le_bytes());
                }
                ReplyBody::Reboot => {}
                ReplyBody::PostMortem { len, offset, data } => {
                    out.put(&[*len, *offset]);
                    out.put(data);
                }
            },
            Reply::Busy { .. } | Reply::Refused { .. } => {
                for _ in 0..kind.reply_fields_len() {
                    out.put(&[0]);
                }
            }
        }
        out.seal()
    }

    /// Decode a reply a master read. The reply's length is its command's ([`reply_len`]); bytes after it are not
    /// looked at, so a master may read the length of the reply it expects and still decode a shorter reply to
    /// another command (the thruster's I2C peripheral sends 0xFF after the reply's last byte). Checks the length,
    /// MT, command, the reply's length, CRC and result code, in this order. The fields of a busy or refused reply
    /// are not looked at.
    pub fn decode(bytes: &[u8]) -> Result<Reply, FrameError> {
        let len = bytes.len();
        let Some(([mt, command, seq, result], _)) = bytes.split_first_chunk::<HEADER_LEN>() else {
            return Err(FrameError::Short { len });
        };
        if len < MIN_FRAME_LEN {
            return Err(FrameError::Short { len });
        }
        if *mt != EXT_REPLY_MT {
            return Err(FrameError::MessageType {
                expected: EXT_REPLY_MT,
                actual: *mt,
            });
        }
        let kind = CommandKind::from_byte(*command).ok_or(FrameError::UnknownCommand(*command))?;
        let expected = reply_len(kind);
        let reply = bytes.get(..expected).ok_or(FrameError::Length {
            command: kind,
            expected,
            actual: len,
        })?;
        let body = split_crc(reply)?;
        let seq = *seq;
        let refusal = match *result {
            RESULT_OK => None,
            RESULT_BUSY => return Ok(Reply::Busy { seq, command: kind }),
            code => Some(Refusal::from_code(code).ok_or(FrameError::UnknownResult(code))?),
        };
        if let Some(refusal) = refusal {
            return Ok(Reply::Refused {
                seq,
                command: kind,
                refusal,
            });
        }
        let mut fields = Fields(body.get(HEADER_LEN..).unwrap_or_default());
        let body = match kind {
            CommandKind::Version => {
                let protocol = fields.u8();
                // A thruster from before bits 2-7 had meanings sends them as zero.
                let flags = fields.u8();
                ReplyBody::Version {
                    protocol,
                    on_trial: flags & 1 != 0,
                    checks_signatures: flags & 2 != 0,
                    marked: flags & 4 != 0,
                    dev_key: flags & 8 != 0,
                    verdict: flags >> 4,
                    max_payload: fields.u32(),
                    info: fields.array(),
                }
            }
            CommandKind::Begin => ReplyBody::Begin {
                payload_len: fields.u32(),
            },
            CommandKind::Erase => ReplyBody::Erase { page: fields.u16() },
            CommandKind::Write => ReplyBody::Write {
                offset: fields.u32(),
                len: fields.u8(),
                crc: fields.u32(),
            },
            CommandKind::Check => ReplyBody::Check {
                offset: fields.u32(),
                len: fields.u32(),
                crc: fields.u32(),
            },
            CommandKind::Finish => ReplyBody::Finish {
                payload_len: fields.u32(),
            },
            CommandKind::Reboot => ReplyBody::Reboot,
            CommandKind::PostMortem => ReplyBody::PostMortem {
                len: fields.u8(),
                offset: fields.u8(),
                data: fields.array(),
            },
        };
        Ok(Reply::Done { seq, body })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(command: Command) -> CommandFrame {
        CommandFrame { seq: 0x42, command }
    }

    fn every_command() -> [Command; 8] {
        [
            Command::Version,
            Command::Begin {
                payload_len: 32768,
                target: 1,
            },
            Command::Erase { page: 15 },
            Command::Write {
                offset: 0x1F40,
                data: Chunk::new(&[0xA5; MAX_CHUNK]).unwrap(),
            },
            Command::Check { offset: 0, len: 32768 },
            Command::Finish {
                payload_len: 32768,
                signature: [0x3C; SIGNATURE_LEN],
            },
            Command::Reboot,
            Command::PostMortem { offset: 64 },
        ]
    }

    #[test]
    fn crc32_is_the_ieee_one() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc32(&[]), 0);
        assert_eq!(Crc32::new().update(b"1234").update(b"56789").finish(), 0xCBF4_3926);
        const AT_COMPILE_TIME: u32 = crc32(b"a");
        assert_eq!(AT_COMPILE_TIME, 0xE8B7_BE43);
    }

    #[test]
    fn the_values_chosen_stay_clear_of_the_ids() {
        for ids in [0x52u8, 0x53, 0x54, 0x55] {
            assert!((EXT_MT ^ ids).count_ones() >= 3, "{ids:#04x}");
            assert!((EXT_REPLY_MT ^ ids).count_ones() >= 3, "{ids:#04x}");
        }
        assert_ne!(EXT_MT, EXT_REPLY_MT);
        // Read as a SPEED byte, MT is a stop.
        assert_eq!(crate::Speed::from_byte(EXT_MT), Ok(crate::Speed::ZERO));
    }

    #[test]
    fn lengths_are_as_documented() {
        let lengths = every_command().map(|command| frame(command).encode().as_bytes().len());
        assert_eq!(lengths, [8, 13, 10, 77, 16, 76, 8, 9]);
        let replies = CommandKind::ALL.map(reply_len);
        assert_eq!(replies, [46, 12, 10, 17, 20, 12, 8, 74]);
        assert!(lengths.iter().chain(&replies).all(|len| *len <= MAX_FRAME_LEN));
    }

    #[test]
    fn a_write_frame_byte_by_byte() {
        let write = frame(Command::Write {
            offset: 0x0102_0304,
            data: Chunk::new(&[9, 8, 7]).unwrap(),
        });
        let bytes = write.encode();
        let bytes = bytes.as_bytes();
        let guard = 0x80u8.wrapping_add(4).wrapping_add(0x42).wrapping_add(0x80);
        assert_eq!(&bytes[..12], &[0x80, 4, 0x42, guard, 4, 3, 2, 1, 3, 9, 8, 7]);
        assert_eq!(&bytes[12..], &crc32(&bytes[..12]).to_le_bytes());
        assert_eq!(CommandFrame::decode(bytes), Ok(write));
    }

    #[test]
    fn commands_round_trip() {
        for command in every_command() {
            let frame = frame(command);
            assert_eq!(CommandFrame::decode(frame.encode().as_bytes()), Ok(frame));
        }
    }

    #[test]
    fn command_errors_in_order() {
        let good = frame(Command::Erase { page: 1 }).encode();
        let good = good.as_bytes();
        assert_eq!(CommandFrame::decode(&good[..7]), Err(FrameError::Short { len: 7 }));
        assert_eq!(CommandFrame::decode(&[]), Err(FrameError::Short { len: 0 }));
        assert_eq!(CommandFrame::decode(&[0x80; 81]), Err(FrameError::TooLong { len: 81 }));
        let mut bytes = good.to_vec();
        bytes[0] = 0x52;
        assert_eq!(
            CommandFrame::decode(&bytes),
            Err(FrameError::MessageType {
                expected: 0x80,
                actual: 0x52
            })
        );
        let mut bytes = good.to_vec();
        bytes[3] ^= 0x80;
        assert!(matches!(CommandFrame::decode(&bytes), Err(FrameError::Guard { .. })));
        let mut bytes = good.to_vec();
        bytes[5] ^= 0x01;
        assert!(matches!(CommandFrame::decode(&bytes), Err(FrameError::Crc { .. })));
        // A well-formed frame of a command this side does not know.
        let unknown = seal_command(&[0x80, 0x09, 1, guard(0x80, 0x09, 1)]);
        assert_eq!(CommandFrame::decode(&unknown), Err(FrameError::UnknownCommand(9)));
        // An erase with a byte too many, sealed.
        let long = seal_command(&[0x80, 3, 1, guard(0x80, 3, 1), 1, 0, 0]);
        assert_eq!(
            CommandFrame::decode(&long),
            Err(FrameError::Length {
                command: CommandKind::Erase,
                expected: 10,
                actual: 11
            })
        );
        // A write whose length byte says 0, and one that says more than fits.
        let empty = seal_command(&[0x80, 4, 1, guard(0x80, 4, 1), 0, 0, 0, 0, 0]);
        assert_eq!(CommandFrame::decode(&empty), Err(FrameError::ChunkLength(0)));
        let mut big = vec![0x80, 4, 1, guard(0x80, 4, 1), 0, 0, 0, 0, 65];
        big.extend([0; 65]);
        let big = seal_command(&big);
        assert_eq!(big.len(), 78);
        assert_eq!(CommandFrame::decode(&big), Err(FrameError::ChunkLength(65)));
    }

    fn seal_command(bytes: &[u8]) -> Vec<u8> {
        let mut sealed = bytes.to_vec();
        sealed.extend(crc32(bytes).to_le_bytes());
        sealed
    }

    #[test]
    fn replies_round_trip_and_tolerate_filler_after_them() {
        let bodies = [
            ReplyBody::Version {
                protocol: PROTOCOL_VERSION,
                on_trial: true,
                checks_signatures: false,
                marked: true,
                dev_key: false,
                verdict: 3,
                max_payload: 58 * 1024,
                info: *b"LBVI\x01\x01\0\0\x01\0\x02\0\x03\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0",
            },
            ReplyBody::Begin { payload_len: 32768 },
            ReplyBody::Erase { page: 2 },
            ReplyBody::Write {
                offset: 64,
                len: 64,
                crc: 0xDEAD_BEEF,
            },
            ReplyBody::Check {
                offset: 0,
                len: 4096,
                crc: 7,
            },
            ReplyBody::Finish { payload_len: 32768 },
            ReplyBody::Reboot,
            ReplyBody::PostMortem {
                len: RECORD_LEN as u8,
                offset: 64,
                data: [0x5A; MAX_CHUNK],
            },
        ];
        for body in bodies {
            let command = body.kind();
            for reply in [
                Reply::Done { seq: 9, body },
                Reply::Busy { seq: 9, command },
                Reply::Refused {
                    seq: 9,
                    command,
                    refusal: Refusal::Driving,
                },
            ] {
                let bytes = reply.encode();
                assert_eq!(bytes.as_bytes().len(), reply_len(command));
                assert_eq!(Reply::decode(bytes.as_bytes()), Ok(reply));
                let mut read = bytes.as_bytes().to_vec();
                read.resize(MAX_FRAME_LEN, 0xFF);
                assert_eq!(Reply::decode(&read), Ok(reply), "read longer than the reply");
            }
        }
    }

    #[test]
    fn a_status_read_instead_of_a_reply_says_no_extension() {
        let status = [0x53, 0x02, 0, 0, 0x80, 25, 0];
        let mut read = status.to_vec();
        read.resize(reply_len(CommandKind::Version), 0xFF);
        assert_eq!(
            Reply::decode(&read),
            Err(FrameError::MessageType {
                expected: 0x81,
                actual: 0x53
            })
        );
    }

    #[test]
    fn reply_errors() {
        let reply = Reply::Done {
            seq: 1,
            body: ReplyBody::Erase { page: 1 },
        }
        .encode();
        let bytes = reply.as_bytes();
        assert_eq!(
            Reply::decode(&bytes[..9]),
            Err(FrameError::Length {
                command: CommandKind::Erase,
                expected: 10,
                actual: 9
            })
        );
        let mut bad = bytes.to_vec();
        bad[4] ^= 1;
        assert!(matches!(Reply::decode(&bad), Err(FrameError::Crc { .. })));
        let mut unknown = bytes[..6].to_vec();
        unknown[3] = 0x77;
        let unknown = seal_command(&unknown);
        assert_eq!(Reply::decode(&unknown), Err(FrameError::UnknownResult(0x77)));
        let mut command = bytes[..6].to_vec();
        command[1] = 0;
        let command = seal_command(&command);
        assert_eq!(Reply::decode(&command), Err(FrameError::UnknownCommand(0)));
    }

    #[test]
    fn every_refusal_has_its_own_code_and_words() {
        for (n, refusal) in Refusal::ALL.iter().enumerate() {
            assert_eq!(Refusal::from_code(refusal.code()), Some(*refusal));
            assert!(![RESULT_OK, RESULT_BUSY].contains(&refusal.code()));
            for other in &Refusal::ALL[n + 1..] {
                assert_ne!(refusal.code(), other.code());
                assert_ne!(refusal.describe(), other.describe());
            }
        }
        assert_eq!(Refusal::from_code(0), None);
        assert_eq!(Refusal::from_code(1), None);
        assert_eq!(Refusal::from_code(20), None);
        for kind in CommandKind::ALL {
            assert_eq!(CommandKind::from_byte(kind.to_byte()), Some(kind));
        }
    }

    #[test]
    fn errors_read_as_english() {
        assert_eq!(
            FrameError::Guard {
                expected: 0x12,
                actual: 0x92
            }
            .to_string(),
            "bad guard byte: computed 0x12, received 0x92"
        );
        assert_eq!(
            FrameError::Length {
                command: CommandKind::Write,
                expected: 77,
                actual: 76
            }
            .to_string(),
            "write frame of 76 bytes, expected 77"
        );
        assert_eq!(
            FrameError::Crc { expected: 1, actual: 2 }.to_string(),
            "bad CRC: computed 0x00000001, received 0x00000002"
        );
    }
}
