//! A file put to the master over MAVLink FTP, one request at a time, as a ground station's `ftp put` does: close
//! whatever sessions it left open before (ResetSessions), open the file for writing (CreateFile), write it from the
//! start in 239-byte blocks, each waited for, then close the session. A request unanswered for [`RETRY_AFTER`] is
//! sent again (the master answers a repeated write as it answered the first); a NAK ends the upload.

use alloc::string::String;
use alloc::vec::Vec;

use embassy_time::{Duration, Instant};
use lbv_master_fw::console::lbv::FILE_TRANSFER_PROTOCOL_DATA;

use crate::GroundStation;

/// A request unanswered this long is sent again.
pub const RETRY_AFTER: Duration = Duration::from_secs(1);
/// Data bytes per write: a FILE_TRANSFER_PROTOCOL payload's 251 less the 12-byte header, as MAVProxy writes.
pub const BLOCK: usize = 239;

const ACK: u8 = 128;
const NAK: u8 = 129;
const TERMINATE: u8 = 1;
const RESET: u8 = 2;
const WRITE: u8 = 7;
const CREATE: u8 = 6;

/// Where an upload is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum UploadState {
    /// Under way: bytes acknowledged so far.
    Sending(usize),
    /// Every byte written and the session closed.
    Done,
    /// The master answered NAK with this error code (MAVLink FTP's: 1 Fail, 4 NoSessionsAvailable, ...).
    Refused(u8),
}

/// One file put.
#[derive(Debug, Clone)]
pub struct Upload {
    path: String,
    file: Vec<u8>,
    /// Its earlier sessions are closed.
    reset: bool,
    session: Option<u8>,
    /// Bytes acknowledged.
    acked: usize,
    seq: u16,
    /// The request in flight: its opcode and when it went.
    waiting: Option<(u8, Instant)>,
    state: UploadState,
}

impl Upload {
    /// Put `file` at `path` (e.g. `/update/thruster0.lbvu`).
    pub fn new(path: &str, file: Vec<u8>) -> Self {
        Self {
            path: path.into(),
            file,
            reset: false,
            session: None,
            acked: 0,
            seq: 0,
            waiting: None,
            state: UploadState::Sending(0),
        }
    }

    /// Where it is.
    pub fn state(&self) -> &UploadState {
        &self.state
    }

    /// Take the replies `station` has seen, then give the request to send at `now`, if one is due (framed).
    pub fn poll(&mut self, now: Instant, station: &mut GroundStation) -> Option<Vec<u8>> {
        for reply in core::mem::take(&mut station.seen.ftp) {
            self.on_reply(&reply);
        }
        if !matches!(self.state, UploadState::Sending(_)) {
            return None;
        }
        if let Some((_, at)) = self.waiting
            && now < at + RETRY_AFTER
        {
            return None;
        }
        let (opcode, offset, data) = match self.session {
            None if !self.reset => (RESET, 0, &[][..]),
            None => (CREATE, 0, self.path.as_bytes()),
            Some(_) if self.acked >= self.file.len() => (TERMINATE, 0, &[][..]),
            Some(_) => {
                let end = (self.acked + BLOCK).min(self.file.len());
                (WRITE, self.acked, self.file.get(self.acked..end).unwrap_or_default())
            }
        };
        self.waiting = Some((opcode, now));
        let payload = request(self.seq, self.session.unwrap_or(0), opcode, offset as u32, data);
        Some(station.frame(&FILE_TRANSFER_PROTOCOL_DATA {
            target_network: 0,
            target_system: 1,
            target_component: 1,
            payload,
        }))
    }

    fn on_reply(&mut self, reply: &[u8; 251]) {
        let [seq0, seq1, session, opcode, _, request, _, _, ..] = *reply;
        let Some((waiting, _)) = self.waiting else {
            return;
        };
        // A reply carries the next sequence number; one to an older request is stale.
        if u16::from_le_bytes([seq0, seq1]) != self.seq.wrapping_add(1) || request != waiting {
            return;
        }
        self.seq = self.seq.wrapping_add(2);
        self.waiting = None;
        match (opcode, waiting) {
            (ACK, RESET) => self.reset = true,
            (ACK, CREATE) => self.session = Some(session),
            (ACK, WRITE) => {
                self.acked = (self.acked + BLOCK).min(self.file.len());
                self.state = UploadState::Sending(self.acked);
            }
            (ACK, _) => self.state = UploadState::Done,
            (NAK, TERMINATE) => self.state = UploadState::Done,
            (_, _) => self.state = UploadState::Refused(reply.get(12).copied().unwrap_or(0)),
        }
    }
}

/// A request payload: seq, session, opcode, size, (padding), offset, data.
pub(crate) fn request(seq: u16, session: u8, opcode: u8, offset: u32, data: &[u8]) -> [u8; 251] {
    let data = data.get(..BLOCK).unwrap_or(data);
    let [s0, s1] = seq.to_le_bytes();
    let [o0, o1, o2, o3] = offset.to_le_bytes();
    let mut payload = [0; 251];
    let header = [s0, s1, session, opcode, data.len() as u8, 0, 0, 0, o0, o1, o2, o3];
    for (slot, byte) in payload.iter_mut().zip(header.iter().chain(data)) {
        *slot = *byte;
    }
    payload
}
