//! MAVLink FTP's wire format: the 251-byte payload of FILE_TRANSFER_PROTOCOL (mavlink.io/en/services/ftp.html),
//! as ArduPilot's server (`GCS_FTP.cpp`) and pymavlink's and MAVProxy's clients (`mavftp.py`,
//! `mavproxy_ftp.py`) lay it out, all little-endian:
//!
//! | offset | field          |                                                                |
//! |--------|----------------|----------------------------------------------------------------|
//! | 0      | seq u16        | a reply carries its request's + 1                              |
//! | 2      | session u8     | chosen by the client; a reply carries its request's            |
//! | 3      | opcode u8      | `Opcode`; a reply is [`ACK`] or [`NAK`]                        |
//! | 4      | size u8        | bytes of `data` used, at most `DATA_LEN`                       |
//! | 5      | req_opcode u8  | in a reply: the request's opcode                               |
//! | 6      | burst_complete | in a reply to a burst read: its last reply                     |
//! | 7      | padding        |                                                                |
//! | 8      | offset u32     | file offset, or the first entry of a directory listing         |
//! | 12     | data, 239      | a path, file bytes, a listing; a NAK's error code ([`Nak`])    |

use crate::shared::{FTP_PAYLOAD, FTP_REPLY_DATA, FtpReply};

/// Bytes before `data`.
pub(crate) const HEADER_LEN: usize = 12;
/// Room for data in one message.
pub(crate) const DATA_LEN: usize = FTP_PAYLOAD - HEADER_LEN;
/// A reply's opcode: done.
pub const ACK: u8 = 128;
/// A reply's opcode: refused, `data[0]` says why.
pub const NAK: u8 = 129;

/// The request opcodes this server answers; every other one is NAKed [`Nak::UnknownCommand`] (ArduPilot's answer
/// for the ones it does not implement), and an [`ACK`] or [`NAK`] sent to it is not answered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) enum Opcode {
    /// 0: nothing; ACKed.
    None,
    /// 1: close the session.
    TerminateSession,
    /// 2: close every session of the sender.
    ResetSessions,
    /// 3: list a directory from entry `offset` on.
    ListDirectory,
    /// 4: open a file for reading: `@SYS/versions.txt` ([`crate::update::sys`]) or `@PARAM/param.pck`
    /// ([`crate::update::param_pck`]), its ACK carrying its length (u32). An update slot is NAKed
    /// [`Nak::FileProtected`], anything else [`Nak::FileNotFound`], so a ground station that asks for a file the
    /// vehicle does not have falls back at once rather than after its retries.
    OpenFileRO,
    /// 5: read `size` bytes from `offset` of the file open for reading.
    ReadFile,
    /// 6: open a file for writing, truncated.
    CreateFile,
    /// 7: write `data` at `offset`.
    WriteFile,
    /// 8: remove a file.
    RemoveFile,
    /// 11: open a file for writing (here the same as [`Opcode::CreateFile`]).
    OpenFileWO,
    /// 14: the CRC32 of a file.
    CalcFileCrc32,
    /// 15: read from `offset` of the file open for reading, in replies of `size` bytes: here one reply, marked the
    /// burst's last, and the client asks for the next from where it ends.
    BurstReadFile,
    /// Any other byte.
    Other(u8),
}

impl Opcode {
    /// The opcode of a request byte.
    pub(crate) const fn from_byte(byte: u8) -> Self {
        match byte {
            0 => Self::None,
            1 => Self::TerminateSession,
            2 => Self::ResetSessions,
            3 => Self::ListDirectory,
            4 => Self::OpenFileRO,
            5 => Self::ReadFile,
            6 => Self::CreateFile,
            7 => Self::WriteFile,
            8 => Self::RemoveFile,
            11 => Self::OpenFileWO,
            14 => Self::CalcFileCrc32,
            15 => Self::BurstReadFile,
            other => Self::Other(other),
        }
    }
}

/// A NAK's error code (`data[0]`), as the clients name them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Nak {
    /// 1: failed (refused now: armed, a bad update file, a sink that could not take it).
    Fail = 1,
    /// 3: `size` beyond [`DATA_LEN`], a path that is empty or holds a NUL, or a read of no bytes.
    InvalidDataSize = 3,
    /// 4: no such session open for this sender.
    InvalidSession = 4,
    /// 5: the one session is in use.
    NoSessionsAvailable = 5,
    /// 6: a listing has no more entries; a read at or past the end of its file.
    EndOfFile = 6,
    /// 7: an opcode this server does not implement.
    UnknownCommand = 7,
    /// 9: only the operator's ground station may write; an update slot cannot be read, nor `@SYS` written.
    FileProtected = 9,
    /// 10: no such file or directory.
    FileNotFound = 10,
}

/// A request, borrowed from its payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Request<'a> {
    /// The client's sequence number.
    pub(crate) seq: u16,
    /// The client's session.
    pub(crate) session: u8,
    /// The opcode byte.
    pub(crate) opcode: u8,
    /// `offset`.
    pub(crate) offset: u32,
    /// `data[..size]`; `None` when `size` is beyond [`DATA_LEN`].
    pub(crate) data: Option<&'a [u8]>,
}

impl<'a> Request<'a> {
    /// Read a payload; every payload reads as a request.
    pub(crate) fn parse(payload: &'a [u8; FTP_PAYLOAD]) -> Self {
        let (header, data) = payload.split_at(HEADER_LEN);
        let byte = |n: usize| header.get(n).copied().unwrap_or(0);
        Self {
            seq: u16::from_le_bytes([byte(0), byte(1)]),
            session: byte(2),
            opcode: byte(3),
            offset: u32::from_le_bytes([byte(8), byte(9), byte(10), byte(11)]),
            data: data.get(..usize::from(byte(4))),
        }
    }

    /// The path in `data`: its `size` bytes, one trailing NUL allowed (ArduPilot's `check_name_len`), none inside.
    pub(crate) fn path(&self) -> Result<&'a [u8], Nak> {
        let data = self.data.ok_or(Nak::InvalidDataSize)?;
        let len = data.iter().position(|byte| *byte == 0).unwrap_or(data.len());
        match data.get(..len) {
            Some(path) if len > 0 && data.len() - len <= 1 => Ok(path),
            _ => Err(Nak::InvalidDataSize),
        }
    }
}

/// The reply to `request`: `opcode` ([`ACK`] or [`NAK`]), the request's offset, and `data` (at most
/// [`FTP_REPLY_DATA`] bytes; what is beyond is cut).
pub(crate) fn reply(request: &Request<'_>, opcode: u8, data: &[u8]) -> FtpReply {
    let data = data.get(..FTP_REPLY_DATA).unwrap_or(data);
    let [s0, s1] = request.seq.wrapping_add(1).to_le_bytes();
    let [o0, o1, o2, o3] = request.offset.to_le_bytes();
    let header = [
        s0,
        s1,
        request.session,
        opcode,
        data.len() as u8,
        request.opcode,
        0,
        0,
        o0,
        o1,
        o2,
        o3,
    ];
    let mut payload = [0; HEADER_LEN + FTP_REPLY_DATA];
    let (head, rest) = payload.split_at_mut(HEADER_LEN);
    head.copy_from_slice(&header);
    for (slot, byte) in rest.iter_mut().zip(data) {
        *slot = *byte;
    }
    payload
}

/// The NAK of `request` for `reason`.
pub(crate) fn nak(request: &Request<'_>, reason: Nak) -> FtpReply {
    reply(request, NAK, &[reason as u8])
}

/// `crc` continued over `bytes`: ArduPilot's `crc_crc32` (the reflected CRC-32 polynomial 0xEDB88320, no
/// inversions), from 0 for a whole file, which is what MAVFTP's CalcFileCRC32 answers and MAVProxy's `ftp
/// crclocal` computes. Bitwise: a table would cost 1 KiB of flash for a few milliseconds per image.
pub(crate) fn crc32(crc: u32, bytes: &[u8]) -> u32 {
    bytes.iter().fold(crc, |crc, byte| {
        (0..8).fold(crc ^ u32::from(*byte), |crc, _| {
            if crc & 1 == 1 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            }
        })
    })
}
