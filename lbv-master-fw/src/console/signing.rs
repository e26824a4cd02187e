//! MAVLink 2 message signing (mavlink.io/en/guide/message_signing.html): the signature of a frame, and the checks
//! an incoming signed frame must pass once the operator has set a key with SETUP_SIGNING.
//!
//! With a key set:
//! - every incoming frame must be MAVLink 2, signed, and its signature right;
//! - its timestamp must be newer than the last one accepted from the same stream (system, component, link); a new
//!   stream's first timestamp must be newer than anything the master may have used before it started (see below)
//!   and no more than a minute behind the link's own timestamp (the spec's rule); replayed frames fail;
//! - the link's timestamp follows the newest accepted one, and every outgoing frame is signed with it, one unit
//!   later each (so a ground station that checks signatures accepts them, and follows it as the spec asks);
//! - a timestamp so near 2^48 - 1 that the link's timestamp would run out is refused: the 48-bit timestamp never
//!   wraps.
//!
//! The master has no real-time clock, and the streams it has heard are in RAM: a reboot forgets them. The spec
//! keeps a restart safe by storing the timestamp at least once a minute; but a value stored up to a minute ago,
//! with a new stream allowed a minute behind it, would take back frames recorded up to two minutes before the
//! restart. So the master keeps a *reservation* in flash instead: a timestamp [`RESERVATION`] ahead of the link's,
//! stored before the link gets there. Nothing at or beyond the stored reservation is ever signed or accepted (a
//! frame that is, is refused as [`Refusal::Ahead`] and a new reservation is stored past it); a new one is asked for
//! when the link comes within [`RENEW_MARGIN`] of it (once a minute while the ground station's clock advances,
//! as the spec asks), and at every start. After a restart the stored reservation is the *floor*: every timestamp
//! used before is below it, the link resumes above it, and a stream's first frame must be at or above it. A
//! ground station follows the master's newer timestamp from its first signed frame (the C library and pymavlink
//! do), so it is not locked out; one that does not is refused until its own clock passes the floor, at most
//! [`RESERVATION`] later.
//!
//! The `mavlink` crates' signing (mavlink-core's `mav2-message-signing`) needs `std` (a `HashMap` of streams, a
//! `Mutex`, the system clock), so it cannot run on the STM32; this module is the same algorithm over a fixed
//! stream table, and the host tests check it against mavlink-core's and pymavlink's signatures.

use mavlink_core::calculate_crc;
use sha2::{Digest, Sha256};

use crate::console::framing::{Frame, Version};

/// Bytes of a frame's signature block: link id, 48-bit timestamp, 48-bit signature.
pub const SIGNATURE_LEN: usize = 13;
/// One minute in timestamp units (10 us).
pub(crate) const ONE_MINUTE: u64 = 6_000_000;
/// How far ahead of the link's timestamp a reservation is stored: a minute of progress between two writes, and
/// [`RENEW_MARGIN`] to write the next one in.
pub(crate) const RESERVATION: u64 = ONE_MINUTE + RENEW_MARGIN;
/// A new reservation is asked for when the link's timestamp comes this near the stored one (10 s; a write takes
/// milliseconds).
pub(crate) const RENEW_MARGIN: u64 = 1_000_000;
/// The largest 48-bit timestamp.
pub const TIMESTAMP_MAX: u64 = (1 << 48) - 1;
/// The newest incoming timestamp accepted: past it a reservation would not fit below [`TIMESTAMP_MAX`].
pub(crate) const LAST_ACCEPTED: u64 = TIMESTAMP_MAX - RESERVATION;
/// The link id the master signs with: it has one link.
pub(crate) const LINK_ID: u8 = 0;
/// Streams remembered; the first frame of a stream beyond them is refused (the MAVLink C library keeps 16; the
/// console's one ground station needs a few at most).
const STREAMS: usize = 8;
/// MAVLink 2 header: STX LEN INCOMPAT COMPAT SEQ SYS COMP MSGID\[3\].
const V2_HEADER: usize = 10;
const IFLAG_SIGNED: u8 = 0x01;

/// A signing secret and the timestamp the link starts from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct SigningKey {
    /// The 32-byte secret (SETUP_SIGNING.secret_key).
    pub secret: [u8; 32],
    /// 10 us units since 2015-01-01: SETUP_SIGNING.initial_timestamp, or after a start the later of it and the
    /// stored reservation. It is the link's floor: a new stream's first frame must be at least this.
    pub timestamp: u64,
}

/// The 48-bit signature of a frame: the first 6 bytes of SHA-256 over the secret, the frame from its start byte to
/// its checksum (`signed_part`), the link id and the 6 timestamp bytes.
pub(crate) fn signature(secret: &[u8; 32], signed_part: &[u8], link_id: u8, timestamp: u64) -> [u8; 6] {
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

/// The reservation to store for a link whose timestamp is `timestamp`.
pub const fn reservation_after(timestamp: u64) -> u64 {
    let next = timestamp.saturating_add(RESERVATION);
    if next > TIMESTAMP_MAX { TIMESTAMP_MAX } else { next }
}

/// Why a frame was refused while a key is set.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) enum Refusal {
    /// Not signed (or MAVLink 1, which cannot be).
    Unsigned,
    /// The signature does not match.
    BadSignature,
    /// Correctly signed, but not newer than the last frame of its stream; or a new stream below the floor, or
    /// more than a minute behind the link's timestamp, or beyond the table: a replay.
    Replayed,
    /// Correctly signed and new, but at or beyond the reservation stored: a new one is stored past it, and the
    /// stream's next frame passes.
    Ahead,
    /// Correctly signed, with a timestamp past [`LAST_ACCEPTED`]: the link's timestamp would run out.
    OutOfRange,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
struct Stream {
    system: u8,
    component: u8,
    link: u8,
    timestamp: u64,
}

/// The link's signing state: the key in force, the link's timestamp, the reservation and the streams heard.
#[derive(Debug, Clone)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct SigningState {
    key: Option<SigningKey>,
    /// The newest timestamp signed or accepted.
    timestamp: u64,
    /// Every timestamp used before this start (or before the key's set-up) is below it.
    floor: u64,
    /// The reservation stored: nothing at or beyond it is signed or accepted.
    stored: u64,
    /// The reservation last handed out for storing.
    requested: u64,
    /// The newest correctly signed timestamp seen at or beyond `stored`: the next reservation goes past it.
    wanted: u64,
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
            floor: 0,
            stored: 0,
            requested: 0,
            wanted: 0,
            streams: [None; STREAMS],
        }
    }

    /// Follow the key in force (from the settings): a different secret forgets the streams; the link's timestamp
    /// and the floor rise to the key's timestamp and never go back.
    pub fn sync(&mut self, key: Option<SigningKey>) {
        if self.key == key {
            return;
        }
        if self.key.map(|k| k.secret) != key.map(|k| k.secret) {
            self.streams = [None; STREAMS];
        }
        if let Some(key) = key {
            let start = key.timestamp.min(TIMESTAMP_MAX);
            self.timestamp = self.timestamp.max(start);
            self.floor = self.floor.max(start);
        }
        self.key = key;
    }

    /// The reservation `reservation` is in flash.
    pub fn stored(&mut self, reservation: u64) {
        self.stored = self.stored.max(reservation.min(TIMESTAMP_MAX));
        self.requested = self.requested.max(self.stored);
    }

    /// Whether a key is set.
    pub fn active(&self) -> bool {
        self.key.is_some()
    }

    /// The link's timestamp now: the newest signed or accepted.
    #[cfg(test)]
    pub(crate) fn timestamp(&self) -> u64 {
        self.timestamp
    }

    /// How many more frames can be signed before a new reservation is stored (unbounded without a key).
    pub(crate) fn room(&self) -> u64 {
        match self.key {
            Some(_) => self.stored.saturating_sub(self.timestamp).saturating_sub(1),
            None => u64::MAX,
        }
    }

    /// Check an incoming frame; always `Ok` without a key.
    pub(crate) fn check(&mut self, frame: &Frame<'_>) -> Result<(), Refusal> {
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
        if timestamp > LAST_ACCEPTED {
            return Err(Refusal::OutOfRange);
        }
        // Whatever becomes of it, a frame signed with the key is not to be accepted after a restart: the next
        // reservation goes past it.
        if timestamp >= self.stored {
            self.wanted = self.wanted.max(timestamp);
        }
        let (system, component) = (frame.system_id, frame.component_id);
        let same = |s: &Option<Stream>| s.is_some_and(|s| (s.system, s.component, s.link) == (system, component, link));
        let slot = match self.streams.iter().position(same) {
            Some(at) => match self.streams.get(at).copied().flatten() {
                Some(stream) if timestamp <= stream.timestamp => return Err(Refusal::Replayed),
                _ => at,
            },
            None if timestamp < self.floor || timestamp.saturating_add(ONE_MINUTE) < self.timestamp => {
                return Err(Refusal::Replayed);
            }
            None => self.streams.iter().position(Option::is_none).ok_or(Refusal::Replayed)?,
        };
        if timestamp >= self.stored {
            return Err(Refusal::Ahead);
        }
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
    /// `buf`): set the signed flag, recompute the checksum with `extra_crc`, append the block, with the link's
    /// timestamp one unit on. Returns the new length; `None` (and `buf` unchanged) without a key, when `buf` is
    /// not such a frame or has no room, or when the reservation stored has no room left (see [`Self::room`]).
    pub fn sign(&mut self, buf: &mut [u8], len: usize, extra_crc: u8) -> Option<usize> {
        let key = self.key?;
        let crc_at = V2_HEADER + usize::from(*buf.get(1)?);
        if buf.first() != Some(&0xFD) || len != crc_at + 2 || buf.len() < len + SIGNATURE_LEN {
            return None;
        }
        let timestamp = self.timestamp + 1;
        if timestamp >= self.stored {
            self.wanted = self.wanted.max(timestamp);
            return None;
        }
        let flags = buf.get_mut(2)?;
        *flags |= IFLAG_SIGNED;
        let crc = calculate_crc(buf.get(1..crc_at)?, extra_crc);
        buf.get_mut(crc_at..len)?.copy_from_slice(&crc.to_le_bytes());
        let signature = signature(&key.secret, buf.get(..len)?, LINK_ID, timestamp);
        let block = buf.get_mut(len..len + SIGNATURE_LEN)?;
        let (link, rest) = block.split_at_mut(1);
        let (stamp, sig) = rest.split_at_mut(6);
        link.copy_from_slice(&[LINK_ID]);
        stamp.copy_from_slice(timestamp.to_le_bytes().get(..6)?);
        sig.copy_from_slice(&signature);
        self.timestamp = timestamp;
        Some(len + SIGNATURE_LEN)
    }

    /// A new reservation to store, when the link's timestamp (or a frame seen beyond the stored one) has come
    /// within [`RENEW_MARGIN`] of the last one asked for; once handed out, it is not asked for again.
    pub(crate) fn due_for_storing(&mut self) -> Option<u64> {
        self.key?;
        let newest = self.timestamp.max(self.wanted);
        let next = reservation_after(newest);
        if newest.saturating_add(RENEW_MARGIN) <= self.requested || next <= self.requested {
            return None;
        }
        self.requested = next;
        Some(next)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::console::lbv::HEARTBEAT_DATA;
    // The ground station's HEARTBEAT is of the dialect in lbv-station's copy of this crate, a type apart from
    // `HEARTBEAT_DATA` here; these tests take only its bytes.
    use lbv_station::GCS_HEARTBEAT;
    use mavlink_core::{MAVLinkV2MessageRaw, MavHeader, MessageData};

    const SECRET: [u8; 32] = [7; 32];

    fn key(timestamp: u64) -> SigningKey {
        SigningKey {
            secret: SECRET,
            timestamp,
        }
    }

    /// A state with `key`, and a reservation stored past its timestamp.
    fn ready(key: SigningKey) -> SigningState {
        let mut state = SigningState::new();
        state.sync(Some(key));
        state.stored(reservation_after(key.timestamp));
        state
    }

    /// An unsigned heartbeat with room for its signature.
    fn unsigned() -> (Vec<u8>, usize) {
        let mut raw = MAVLinkV2MessageRaw::new();
        raw.serialize_message_data(MavHeader::default(), &GCS_HEARTBEAT);
        let mut buf = raw.raw_bytes().to_vec();
        let len = buf.len();
        buf.resize(len + SIGNATURE_LEN, 0);
        (buf, len)
    }

    /// A heartbeat from `system` on `link`, signed with `secret` and exactly `timestamp`.
    fn signed(system: u8, secret: [u8; 32], link: u8, timestamp: u64) -> Vec<u8> {
        let mut raw = MAVLinkV2MessageRaw::new();
        let header = MavHeader {
            system_id: u32::from(system),
            component_id: 190,
            sequence: 0,
        };
        raw.serialize_message_data(header, &GCS_HEARTBEAT);
        let mut buf = raw.raw_bytes().to_vec();
        let len = buf.len();
        buf.resize(len + SIGNATURE_LEN, 0);
        // The sender's own state signs it (as the tx task does); then the link id and timestamp given, signed again.
        let mut sender = ready(SigningKey { secret, timestamp: 0 });
        assert_eq!(sender.sign(&mut buf, len, HEARTBEAT_DATA::EXTRA_CRC), Some(buf.len()));
        buf[len] = link;
        buf[len + 1..len + 7].copy_from_slice(&timestamp.to_le_bytes()[..6]);
        let sig = signature(&secret, &buf[..len], link, timestamp);
        buf[len + 7..].copy_from_slice(&sig);
        buf
    }

    fn stamp_of(frame: &[u8]) -> u64 {
        let at = frame.len() - SIGNATURE_LEN + 1;
        let mut bytes = [0; 8];
        bytes[..6].copy_from_slice(&frame[at..at + 6]);
        u64::from_le_bytes(bytes)
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

    /// What the master does at a start with `floor` loaded from flash: the floor as the key's timestamp, a
    /// reservation stored past it.
    fn booted(floor: u64) -> SigningState {
        ready(key(floor))
    }

    #[test]
    fn without_a_key_everything_passes_and_nothing_is_signed() {
        let mut state = SigningState::new();
        assert_eq!(check(&mut state, &signed(255, [1; 32], 0, 5)), Ok(()));
        let (mut buf, len) = unsigned();
        assert_eq!(state.sign(&mut buf, len, HEARTBEAT_DATA::EXTRA_CRC), None);
        assert_eq!(state.due_for_storing(), None);
        assert_eq!(state.room(), u64::MAX);
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
        let mut state = booted(1_000_000_000);
        // Unsigned.
        let (unsigned, _) = unsigned();
        assert_eq!(check(&mut state, &unsigned), Err(Refusal::Unsigned));
        // Wrong key, flipped bit.
        assert_eq!(
            check(&mut state, &signed(255, [8; 32], 0, 1_000_000_001)),
            Err(Refusal::BadSignature)
        );
        let mut flipped = signed(255, SECRET, 0, 1_000_000_001);
        flipped[12] ^= 1;
        assert_eq!(check(&mut state, &flipped), Err(Refusal::BadSignature));
        // Below the floor: used before the start.
        assert_eq!(
            check(&mut state, &signed(255, SECRET, 0, 999_999_999)),
            Err(Refusal::Replayed)
        );
        // Good, then its replay, then an older one, then a newer one.
        let good = signed(255, SECRET, 0, 1_000_000_002);
        assert_eq!(check(&mut state, &good), Ok(()));
        assert_eq!(check(&mut state, &good), Err(Refusal::Replayed));
        assert_eq!(
            check(&mut state, &signed(255, SECRET, 0, 1_000_000_001)),
            Err(Refusal::Replayed)
        );
        assert_eq!(check(&mut state, &signed(255, SECRET, 0, 1_000_000_003)), Ok(()));
        assert_eq!(state.timestamp(), 1_000_000_003);
        // Another link of the same system is another stream.
        assert_eq!(check(&mut state, &signed(255, SECRET, 1, 1_000_000_001)), Ok(()));
        // A new stream: at most a minute behind the link's timestamp.
        let now = 1_000_000_000 + 2 * ONE_MINUTE;
        assert_eq!(check(&mut state, &signed(255, SECRET, 0, now)), Err(Refusal::Ahead));
        state.stored(reservation_after(now));
        assert_eq!(check(&mut state, &signed(255, SECRET, 0, now)), Ok(()));
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
    fn outgoing_timestamps_rise_from_the_floor_and_stay_within_the_reservation() {
        let mut state = booted(500);
        let mut stamps = Vec::new();
        for _ in 0..3 {
            let (mut frame, len) = unsigned();
            assert_eq!(
                state.sign(&mut frame, len, HEARTBEAT_DATA::EXTRA_CRC),
                Some(len + SIGNATURE_LEN)
            );
            stamps.push(stamp_of(&frame));
            // What the master sends, it would accept from a peer with the same key.
            assert_eq!(check(&mut booted(0), &frame), Ok(()));
        }
        assert_eq!(stamps, [501, 502, 503], "above the floor, one unit each");
        // The reservation stored at the start covers a minute of progress; then signing stops until the next one
        // is stored, and leaves the frame as it was.
        assert_eq!(state.room(), reservation_after(500) - 503 - 1);
        assert_eq!(state.due_for_storing(), None, "the start's reservation holds");
        assert_eq!(
            check(&mut state, &signed(255, SECRET, 0, reservation_after(500))),
            Err(Refusal::Ahead),
            "the reservation itself is not used"
        );
        assert_eq!(
            check(&mut state, &signed(255, SECRET, 0, reservation_after(500) - 1)),
            Ok(())
        );
        assert_eq!(state.room(), 0);
        let (mut frame, len) = unsigned();
        let before = frame.clone();
        assert_eq!(state.sign(&mut frame, len, HEARTBEAT_DATA::EXTRA_CRC), None);
        assert_eq!(frame, before);
        let next = state.due_for_storing().unwrap();
        assert_eq!(next, reservation_after(reservation_after(500)));
        assert_eq!(state.due_for_storing(), None, "asked for once");
        state.stored(next);
        assert_eq!(
            state.sign(&mut frame, len, HEARTBEAT_DATA::EXTRA_CRC),
            Some(len + SIGNATURE_LEN)
        );
    }

    #[test]
    fn a_reservation_is_asked_for_before_the_link_reaches_the_stored_one() {
        let mut state = booted(1_000);
        let stored = reservation_after(1_000);
        assert_eq!(
            check(&mut state, &signed(255, SECRET, 0, stored - RENEW_MARGIN)),
            Ok(())
        );
        assert_eq!(state.due_for_storing(), None);
        assert_eq!(
            check(&mut state, &signed(255, SECRET, 0, stored - RENEW_MARGIN + 1)),
            Ok(())
        );
        assert_eq!(
            state.due_for_storing(),
            Some(reservation_after(stored - RENEW_MARGIN + 1))
        );
        // Meanwhile the frames go on being accepted up to the stored reservation.
        assert_eq!(check(&mut state, &signed(255, SECRET, 0, stored - 1)), Ok(()));
    }

    #[test]
    fn a_frame_beyond_the_reservation_waits_for_the_next_one() {
        let mut state = booted(1_000);
        // A ground station whose clock is far ahead (the master was off for a day).
        let day = 24 * 60 * ONE_MINUTE;
        let first = signed(255, SECRET, 0, day);
        assert_eq!(check(&mut state, &first), Err(Refusal::Ahead));
        assert_eq!(state.timestamp(), 1_000, "a refused frame moves nothing");
        let next = state.due_for_storing().unwrap();
        assert_eq!(next, reservation_after(day));
        state.stored(next);
        assert_eq!(
            check(&mut state, &first),
            Ok(()),
            "taken once the reservation is stored"
        );
        assert_eq!(state.timestamp(), day);
    }

    /// The attack of a recorded session replayed after a reboot: every frame the master accepted, and every
    /// correctly signed one it refused, is refused after the restart, however soon after it the replay comes.
    #[test]
    fn nothing_recorded_before_a_restart_is_accepted_after_it() {
        let mut flash = reservation_after(10_000);
        let mut state = booted(10_000);
        state.stored(flash);
        let mut recorded = Vec::new();
        // Two minutes of a ground station at 50 frames a second, its clock running; the reservations it asks
        // for are stored as they come.
        let mut t = 10_001;
        while t < 10_000 + 2 * ONE_MINUTE {
            let frame = signed(255, SECRET, 0, t);
            let _ = check(&mut state, &frame);
            recorded.push(frame);
            if let Some(next) = state.due_for_storing() {
                flash = next;
                state.stored(flash);
            }
            t += 2_000;
        }
        // One the master refused as ahead of it.
        let ahead = signed(255, SECRET, 0, flash + 5);
        assert_eq!(check(&mut state, &ahead), Err(Refusal::Ahead));
        recorded.push(ahead);
        if let Some(next) = state.due_for_storing() {
            flash = next;
        }
        // The restart: the floor is what the flash holds.
        let mut restarted = booted(flash);
        for frame in &recorded {
            assert_eq!(
                check(&mut restarted, frame),
                Err(Refusal::Replayed),
                "{}",
                stamp_of(frame)
            );
        }
        // The ground station follows the master's first signed frame, and is heard.
        let (mut telemetry, len) = unsigned();
        restarted.sign(&mut telemetry, len, HEARTBEAT_DATA::EXTRA_CRC).unwrap();
        let follows = stamp_of(&telemetry) + 1;
        assert_eq!(check(&mut restarted, &signed(255, SECRET, 0, follows)), Ok(()));
    }

    #[test]
    fn the_timestamp_never_runs_past_48_bits() {
        let mut state = booted(1_000);
        // The largest timestamp, and anything that would leave no room for a reservation: refused.
        for t in [TIMESTAMP_MAX, LAST_ACCEPTED + 1] {
            assert_eq!(check(&mut state, &signed(255, SECRET, 0, t)), Err(Refusal::OutOfRange));
        }
        assert_eq!(state.due_for_storing(), None, "an out-of-range frame asks for nothing");
        // The last accepted one: its reservation ends at the maximum, and signing stops there.
        let last = signed(255, SECRET, 0, LAST_ACCEPTED);
        assert_eq!(check(&mut state, &last), Err(Refusal::Ahead));
        let next = state.due_for_storing().unwrap();
        assert_eq!(next, TIMESTAMP_MAX);
        state.stored(next);
        assert_eq!(check(&mut state, &last), Ok(()));
        let mut stamps = Vec::new();
        loop {
            let (mut frame, len) = unsigned();
            match state.sign(&mut frame, len, HEARTBEAT_DATA::EXTRA_CRC) {
                Some(_) => stamps.push(stamp_of(&frame)),
                None => break,
            }
            assert!(stamps.len() <= RESERVATION as usize);
            if stamps.len() == 3 {
                // Skip to the end rather than signing a minute of frames.
                state.timestamp = TIMESTAMP_MAX - 2;
            }
        }
        assert_eq!(stamps.last(), Some(&(TIMESTAMP_MAX - 1)), "{stamps:?}");
        assert!(stamps.windows(2).all(|w| w[0] < w[1]), "no wrap: {stamps:?}");
        assert_eq!(state.due_for_storing(), None, "nothing past the maximum");
        // A flash that holds more than 48 bits reads as the maximum.
        let mut state = SigningState::new();
        state.sync(Some(key(u64::MAX)));
        assert_eq!(state.timestamp(), TIMESTAMP_MAX);
    }
}
