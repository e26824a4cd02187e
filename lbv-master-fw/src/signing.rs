//! MAVLink 2 message signing (mavlink.io/en/guide/message_signing.html): the signature of a frame, and the checks
//! an incoming signed frame must pass once the operator has set a key with SETUP_SIGNING.
//!
//! With a key set:
//! - every incoming frame must be MAVLink 2, signed, and its signature right;
//! - its timestamp must be newer than the last one accepted from the same stream (system, component, link), and a
//!   new stream's first timestamp no more than a minute behind the link's own timestamp (replayed frames fail);
//! - the link's timestamp follows the newest accepted one, and every outgoing frame is signed with it, one unit
//!   later each (so a ground station that checks signatures accepts them).
//!
//! The master has no clock of its own: its timestamp starts from the one stored with the key and is stored again
//! at least once a minute while it advances (the spec's rule for systems without a real-time clock).
//!
//! The `mavlink` crates' signing (mavlink-core's `mav2-message-signing`) needs `std` (a `HashMap` of streams, a
//! `Mutex`, the system clock), so it cannot run on the STM32; this module is the same algorithm over a fixed
//! stream table, and the host tests check it against mavlink-core's and pymavlink's signatures.

use mavlink_core::calculate_crc;
use sha2::{Digest, Sha256};

use crate::console::frame::{Frame, Version};

/// Bytes of a frame's signature block: link id, 48-bit timestamp, 48-bit signature.
pub const SIGNATURE_LEN: usize = 13;
/// One minute in timestamp units (10 us).
pub const ONE_MINUTE: u64 = 6_000_000;
/// The link id the master signs with: it has one link.
pub const LINK_ID: u8 = 0;
/// Streams remembered; the first frame of a stream beyond them is refused (the MAVLink C library keeps 16; the
/// console's one ground station needs a few at most).
const STREAMS: usize = 8;
/// Timestamps are 48 bits.
const TIMESTAMP_MASK: u64 = (1 << 48) - 1;
/// MAVLink 2 header: STX LEN INCOMPAT COMPAT SEQ SYS COMP MSGID[3].
const V2_HEADER: usize = 10;
const IFLAG_SIGNED: u8 = 0x01;

/// A signing secret and the timestamp the link starts from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct SigningKey {
    /// The 32-byte secret (SETUP_SIGNING.secret_key).
    pub secret: [u8; 32],
    /// 10 us units since 2015-01-01 (SETUP_SIGNING.initial_timestamp, or the last one stored).
    pub timestamp: u64,
}

/// The 48-bit signature of a frame: the first 6 bytes of SHA-256 over the secret, the frame from its start byte to
/// its checksum (`signed_part`), the link id and the 6 timestamp bytes.
pub fn signature(secret: &[u8; 32], signed_part: &[u8], link_id: u8, timestamp: u64) -> [u8; 6] {
    let mut sha = Sha256::new();
    sha.update(secret);
    sha.update(signed_part);
    sha.update([link_id]);
    sha.update(timestamp.to_le_bytes().get(..6).unwrap_or_default());
    let digest = sha.finalize();
    let mut out = [0; 6];
    for (slot, byte) in out.iter_mut().zip(digest.iter()) {
        *slot = *byte;
    }
    out
}

/// Why a frame was refused while a key is set.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Refusal {
    /// Not signed (or MAVLink 1, which cannot be).
    Unsigned,
    /// The signature does not match.
    BadSignature,
    /// Correctly signed, but not newer than the last frame of its stream, or a new stream more than a minute behind
    /// the link's timestamp, or a new stream when the table is full: a replay.
    Replayed,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
struct Stream {
    system: u8,
    component: u8,
    link: u8,
    timestamp: u64,
}

/// The link's signing state: the key in force, the link's timestamp and the streams heard.
#[derive(Debug, Clone)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct SigningState {
    key: Option<SigningKey>,
    timestamp: u64,
    /// The timestamp last handed out for storing.
    saved: u64,
    streams: [Option<Stream>; STREAMS],
}

impl Default for SigningState {
    fn default() -> Self {
        Self::new()
    }
}

impl SigningState {
    /// No key: every frame passes, nothing is signed.
    pub const fn new() -> Self {
        Self {
            key: None,
            timestamp: 0,
            saved: 0,
            streams: [None; STREAMS],
        }
    }

    /// Follow the key in force (from the settings): a different secret forgets the streams; the link's timestamp
    /// never goes back.
    pub fn sync(&mut self, key: Option<SigningKey>) {
        if self.key == key {
            return;
        }
        if self.key.map(|k| k.secret) != key.map(|k| k.secret) {
            self.streams = [None; STREAMS];
        }
        if let Some(key) = key {
            self.timestamp = self.timestamp.max(key.timestamp & TIMESTAMP_MASK);
            self.saved = self.saved.max(key.timestamp);
        }
        self.key = key;
    }

    /// Whether a key is set.
    pub fn active(&self) -> bool {
        self.key.is_some()
    }

    /// The link's timestamp now.
    pub fn timestamp(&self) -> u64 {
        self.timestamp
    }

    /// Check an incoming frame; always `Ok` without a key.
    pub fn check(&mut self, frame: &Frame<'_>) -> Result<(), Refusal> {
        let Some(key) = self.key else { return Ok(()) };
        let block = match frame.version {
            Version::V2 if frame.signed => frame.bytes.len().checked_sub(SIGNATURE_LEN),
            _ => None,
        };
        let (Some(signed_part), Some(&[link, t0, t1, t2, t3, t4, t5, s0, s1, s2, s3, s4, s5])) = (
            block.and_then(|at| frame.bytes.get(..at)),
            block.and_then(|at| frame.bytes.get(at..)),
        ) else {
            return Err(Refusal::Unsigned);
        };
        let timestamp = u64::from_le_bytes([t0, t1, t2, t3, t4, t5, 0, 0]);
        if signature(&key.secret, signed_part, link, timestamp) != [s0, s1, s2, s3, s4, s5] {
            return Err(Refusal::BadSignature);
        }
        let (system, component) = (frame.system_id, frame.component_id);
        let same = |s: &Option<Stream>| s.is_some_and(|s| (s.system, s.component, s.link) == (system, component, link));
        let slot = match self.streams.iter().position(same) {
            Some(at) => match self.streams.get(at).copied().flatten() {
                Some(stream) if timestamp <= stream.timestamp => return Err(Refusal::Replayed),
                _ => at,
            },
            None if timestamp.saturating_add(ONE_MINUTE) < self.timestamp => return Err(Refusal::Replayed),
            None => self.streams.iter().position(Option::is_none).ok_or(Refusal::Replayed)?,
        };
        if let Some(entry) = self.streams.get_mut(slot) {
            *entry = Some(Stream {
                system,
                component,
                link,
                timestamp,
            });
        }
        self.timestamp = self.timestamp.max(timestamp);
        Ok(())
    }

    /// Sign the unsigned MAVLink 2 frame at the start of `buf` (`len` bytes, the signature block to follow in
    /// `buf`): set the signed flag, recompute the checksum with `extra_crc`, append the block. Returns the new
    /// length; `None` (and `buf` unchanged) without a key, or when `buf` is not such a frame or has no room.
    pub fn sign(&mut self, buf: &mut [u8], len: usize, extra_crc: u8) -> Option<usize> {
        let key = self.key?;
        let crc_at = V2_HEADER + usize::from(*buf.get(1)?);
        if buf.first() != Some(&0xFD) || len != crc_at + 2 || buf.len() < len + SIGNATURE_LEN {
            return None;
        }
        let flags = buf.get_mut(2)?;
        *flags |= IFLAG_SIGNED;
        let crc = calculate_crc(buf.get(1..crc_at)?, extra_crc);
        buf.get_mut(crc_at..len)?.copy_from_slice(&crc.to_le_bytes());
        let timestamp = self.timestamp;
        self.timestamp = (self.timestamp + 1) & TIMESTAMP_MASK;
        let signature = signature(&key.secret, buf.get(..len)?, LINK_ID, timestamp);
        let block = buf.get_mut(len..len + SIGNATURE_LEN)?;
        let (link, rest) = block.split_at_mut(1);
        let (stamp, sig) = rest.split_at_mut(6);
        link.copy_from_slice(&[LINK_ID]);
        stamp.copy_from_slice(timestamp.to_le_bytes().get(..6)?);
        sig.copy_from_slice(&signature);
        Some(len + SIGNATURE_LEN)
    }

    /// The link's timestamp when it has advanced a minute since it was last handed out for storing.
    pub fn due_for_storing(&mut self) -> Option<u64> {
        if self.key.is_some() && self.timestamp >= self.saved.saturating_add(ONE_MINUTE) {
            self.saved = self.timestamp;
            Some(self.timestamp)
        } else {
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::console::lbv::{HEARTBEAT_DATA, MavAutopilot, MavModeFlag, MavState, MavType};
    use mavlink_core::{MAVLinkV2MessageRaw, MavHeader, MessageData};

    const SECRET: [u8; 32] = [7; 32];

    fn key(timestamp: u64) -> SigningKey {
        SigningKey {
            secret: SECRET,
            timestamp,
        }
    }

    fn heartbeat() -> HEARTBEAT_DATA {
        HEARTBEAT_DATA {
            custom_mode: 0,
            mavtype: MavType::MAV_TYPE_GCS,
            autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
            base_mode: MavModeFlag::empty(),
            system_status: MavState::MAV_STATE_ACTIVE,
            mavlink_version: 3,
        }
    }

    /// A frame from `system`, signed by a sender whose link timestamp is `timestamp` (through the sender's own
    /// state, as the tx task signs).
    fn signed(system: u8, secret: [u8; 32], link: u8, timestamp: u64) -> Vec<u8> {
        let mut raw = MAVLinkV2MessageRaw::new();
        let header = MavHeader {
            system_id: u32::from(system),
            component_id: 190,
            sequence: 0,
        };
        raw.serialize_message_data(header, &heartbeat());
        let mut buf = raw.raw_bytes().to_vec();
        let len = buf.len();
        buf.resize(len + SIGNATURE_LEN, 0);
        let mut sender = SigningState::new();
        sender.sync(Some(SigningKey { secret, timestamp }));
        let signed = sender.sign(&mut buf, len, HEARTBEAT_DATA::EXTRA_CRC).unwrap();
        assert_eq!(signed, buf.len());
        buf[len] = link;
        // Re-sign with the link id given.
        let sig = signature(&secret, &buf[..len], link, timestamp);
        buf[len + 7..].copy_from_slice(&sig);
        buf
    }

    fn check(state: &mut SigningState, bytes: &[u8]) -> Result<(), Refusal> {
        let frame = Frame {
            version: Version::V2,
            sequence: bytes[4],
            system_id: bytes[5],
            component_id: bytes[6],
            message_id: 0,
            payload: &bytes[10..bytes.len() - 15],
            signed: bytes[2] & IFLAG_SIGNED != 0,
            bytes,
        };
        state.check(&frame)
    }

    #[test]
    fn without_a_key_everything_passes_and_nothing_is_signed() {
        let mut state = SigningState::new();
        assert_eq!(check(&mut state, &signed(255, [1; 32], 0, 5)), Ok(()));
        let mut buf = [0u8; 64];
        assert_eq!(state.sign(&mut buf, 21, 50), None);
        assert_eq!(state.due_for_storing(), None);
    }

    #[test]
    fn the_signature_matches_the_spec_example_layout() {
        // The spec's layout, computed independently here: SHA-256(secret + frame up to the CRC + link + 6 bytes of
        // timestamp), first 6 bytes. The host integration tests also check against mavlink-core and pymavlink.
        let frame = signed(255, SECRET, 3, 0x0102_0304_0506);
        let at = frame.len() - SIGNATURE_LEN;
        assert_eq!(frame[2] & IFLAG_SIGNED, IFLAG_SIGNED);
        assert_eq!(frame[at], 3);
        assert_eq!(&frame[at + 1..at + 7], &[6, 5, 4, 3, 2, 1]);
        let mut sha = Sha256::new();
        sha.update(SECRET);
        sha.update(&frame[..at + 7]);
        assert_eq!(&frame[at + 7..], &sha.finalize()[..6]);
    }

    #[test]
    fn refusals() {
        let mut state = SigningState::new();
        state.sync(Some(key(1_000_000_000)));
        // Unsigned.
        let mut raw = MAVLinkV2MessageRaw::new();
        raw.serialize_message_data(MavHeader::default(), &heartbeat());
        let mut unsigned = raw.raw_bytes().to_vec();
        unsigned.extend([0; SIGNATURE_LEN]);
        assert_eq!(check(&mut state, &unsigned), Err(Refusal::Unsigned));
        // Wrong key, flipped bit.
        assert_eq!(
            check(&mut state, &signed(255, [8; 32], 0, 1_000_000_001)),
            Err(Refusal::BadSignature)
        );
        let mut flipped = signed(255, SECRET, 0, 1_000_000_001);
        flipped[12] ^= 1;
        assert_eq!(check(&mut state, &flipped), Err(Refusal::BadSignature));
        // Good, then its replay, then an older one, then a newer one.
        let good = signed(255, SECRET, 0, 1_000_000_001);
        assert_eq!(check(&mut state, &good), Ok(()));
        assert_eq!(check(&mut state, &good), Err(Refusal::Replayed));
        assert_eq!(
            check(&mut state, &signed(255, SECRET, 0, 1_000_000_000)),
            Err(Refusal::Replayed)
        );
        assert_eq!(check(&mut state, &signed(255, SECRET, 0, 1_000_000_002)), Ok(()));
        assert_eq!(state.timestamp(), 1_000_000_002);
        // Another link of the same system is another stream.
        assert_eq!(check(&mut state, &signed(255, SECRET, 1, 1_000_000_001)), Ok(()));
        // A new stream: at most a minute behind the link's timestamp.
        let now = state.timestamp();
        assert_eq!(
            check(&mut state, &signed(200, SECRET, 0, now - ONE_MINUTE - 1)),
            Err(Refusal::Replayed)
        );
        assert_eq!(check(&mut state, &signed(200, SECRET, 0, now - ONE_MINUTE)), Ok(()));
        // The table fills: a stream beyond it is refused, known ones go on.
        for system in 1..=5 {
            assert_eq!(check(&mut state, &signed(system, SECRET, 0, now)), Ok(()), "{system}");
        }
        assert_eq!(check(&mut state, &signed(6, SECRET, 0, now)), Err(Refusal::Replayed));
        assert_eq!(check(&mut state, &signed(255, SECRET, 0, now + 1)), Ok(()));
        // A new secret forgets the streams; the timestamp stays.
        state.sync(Some(SigningKey {
            secret: [9; 32],
            timestamp: 0,
        }));
        assert_eq!(state.timestamp(), now + 1);
        assert_eq!(check(&mut state, &signed(6, [9; 32], 0, now)), Ok(()));
    }

    #[test]
    fn outgoing_timestamps_rise_and_are_stored_once_a_minute() {
        let mut state = SigningState::new();
        state.sync(Some(key(500)));
        let mut last = 0;
        for _ in 0..3 {
            let frame = {
                let mut raw = MAVLinkV2MessageRaw::new();
                raw.serialize_message_data(MavHeader::default(), &heartbeat());
                let mut buf = raw.raw_bytes().to_vec();
                let len = buf.len();
                buf.resize(len + SIGNATURE_LEN, 0);
                assert_eq!(
                    state.sign(&mut buf, len, HEARTBEAT_DATA::EXTRA_CRC),
                    Some(len + SIGNATURE_LEN)
                );
                buf
            };
            let at = frame.len() - SIGNATURE_LEN;
            let stamp = u64::from_le_bytes([
                frame[at + 1],
                frame[at + 2],
                frame[at + 3],
                frame[at + 4],
                frame[at + 5],
                frame[at + 6],
                0,
                0,
            ]);
            assert!(stamp >= 500 && stamp > last || last == 0);
            last = stamp;
            // What the master sends, it would accept from a peer with the same key.
            let mut peer = SigningState::new();
            peer.sync(Some(key(0)));
            assert_eq!(check(&mut peer, &frame), Ok(()));
        }
        assert_eq!(last, 502);
        assert_eq!(state.due_for_storing(), None, "stored with the key");
        assert_eq!(
            check(&mut state, &signed(255, SECRET, 0, 500 + ONE_MINUTE + 10)),
            Ok(())
        );
        assert_eq!(state.due_for_storing(), Some(500 + ONE_MINUTE + 10));
        assert_eq!(state.due_for_storing(), None);
    }
}
