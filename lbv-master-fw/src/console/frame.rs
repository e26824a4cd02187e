//! MAVLink framing: finds CRC-valid MAVLink 2 (and 1) frames in a byte stream and resynchronises after noise.
//!
//! The parser keeps one maximum-size frame of look-ahead. A candidate that fails its CRC is dropped by one byte
//! only, so a good frame hiding behind a false start marker (a truncated frame, noise containing 0xFD) is still
//! found. A frame whose message id the dialect does not know cannot be CRC-checked; its length is trusted only
//! when the byte after it starts another frame, otherwise it is treated as noise.
//!
//! MAVLink 2 signed frames are accepted without checking the signature (the console link has no key).

use mavlink_core::calculate_crc;

const STX_V1: u8 = 0xFE;
const STX_V2: u8 = 0xFD;
/// STX LEN SEQ SYS COMP MSGID.
const V1_HEADER: usize = 6;
/// STX LEN INCOMPAT COMPAT SEQ SYS COMP MSGID[3].
const V2_HEADER: usize = 10;
const CHECKSUM: usize = 2;
const SIGNATURE: usize = 13;
/// The only MAVLink 2 incompatibility flag understood: the frame carries a signature.
const IFLAG_SIGNED: u8 = 0x01;
/// The longest frame: signed MAVLink 2 with a 255-byte payload.
pub const MAX_FRAME: usize = V2_HEADER + 255 + CHECKSUM + SIGNATURE;
/// A whole frame, the byte after it (to accept an unknown message) and room for a read chunk.
const CAPACITY: usize = MAX_FRAME + 1 + 63;

/// MAVLink protocol version of a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Version {
    /// MAVLink 1 (start byte 0xFE).
    V1,
    /// MAVLink 2 (start byte 0xFD).
    V2,
}

/// A CRC-valid frame, borrowed from the parser's buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Frame<'a> {
    /// Protocol version.
    pub version: Version,
    /// The sender's sequence number.
    pub sequence: u8,
    /// The sender's system id.
    pub system_id: u8,
    /// The sender's component id.
    pub component_id: u8,
    /// The message id.
    pub message_id: u32,
    /// The payload as sent (MAVLink 2 trims trailing zeros).
    pub payload: &'a [u8],
}

/// Why bytes that looked like a frame were dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Reject {
    /// Wrong CRC (also a truncated frame: its CRC is read from the next frame's bytes), or an unsupported
    /// MAVLink 2 incompatibility flag, or an unknown message that is not followed by another frame.
    Corrupt,
    /// A well-framed message the dialect does not hold (skipped whole).
    UnknownMessage(u32),
}

/// What [`FrameParser::next`] found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Event<'a> {
    /// A CRC-valid frame of a known message.
    Frame(Frame<'a>),
    /// A dropped candidate.
    Rejected(Reject),
}

/// Incremental MAVLink frame parser with a fixed buffer; never panics, whatever the input.
#[derive(Debug, Clone)]
pub struct FrameParser {
    buf: [u8; CAPACITY],
    start: usize,
    end: usize,
    skipped: u32,
}

impl Default for FrameParser {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameParser {
    /// An empty parser.
    pub const fn new() -> Self {
        Self {
            buf: [0; CAPACITY],
            start: 0,
            end: 0,
            skipped: 0,
        }
    }

    /// Append received bytes; returns how many were taken. All are taken when [`FrameParser::next`] was called
    /// until it returned `None` and `data` is at most 64 bytes; otherwise push the rest after draining again.
    pub fn push(&mut self, data: &[u8]) -> usize {
        self.compact();
        let free = self.buf.get_mut(self.end..).unwrap_or_default();
        let taken = free.len().min(data.len());
        if let (Some(dst), Some(src)) = (free.get_mut(..taken), data.get(..taken)) {
            dst.copy_from_slice(src);
            self.end += taken;
            taken
        } else {
            0
        }
    }

    /// Bytes dropped while looking for a start byte since the last call.
    pub fn take_skipped(&mut self) -> u32 {
        core::mem::take(&mut self.skipped)
    }

    /// The next frame or rejected candidate in the buffered bytes, or `None` when more bytes are needed.
    ///
    /// `extra_crc` gives the CRC_EXTRA byte of the message ids the dialect knows.
    pub fn next(&mut self, extra_crc: impl Fn(u32) -> Option<u8>) -> Option<Event<'_>> {
        // Find a start byte.
        let window = self.window();
        let Some(at) = window.iter().position(|&b| b == STX_V1 || b == STX_V2) else {
            self.skipped = self.skipped.wrapping_add(window.len() as u32);
            self.start = 0;
            self.end = 0;
            return None;
        };
        self.skipped = self.skipped.wrapping_add(at as u32);
        self.start += at;
        let window = self.window();

        let (header_len, payload_len, incompat, sequence, system_id, component_id, message_id, version) =
            if window.first() == Some(&STX_V2) {
                let [_, len, incompat, _compat, seq, sys, comp, id0, id1, id2] = *window.first_chunk::<V2_HEADER>()?;
                let id = u32::from_le_bytes([id0, id1, id2, 0]);
                (V2_HEADER, len, incompat, seq, sys, comp, id, Version::V2)
            } else {
                let [_, len, seq, sys, comp, id] = *window.first_chunk::<V1_HEADER>()?;
                (V1_HEADER, len, 0, seq, sys, comp, u32::from(id), Version::V1)
            };
        if incompat & !IFLAG_SIGNED != 0 {
            self.start += 1;
            return Some(Event::Rejected(Reject::Corrupt));
        }
        let crc_at = header_len + usize::from(payload_len);
        let signature = if incompat & IFLAG_SIGNED != 0 { SIGNATURE } else { 0 };
        let frame_len = crc_at + CHECKSUM + signature;

        let Some(extra) = extra_crc(message_id) else {
            // Unknown message: trust its length only if another frame starts right after it.
            let next = *window.get(frame_len)?;
            if next == STX_V1 || next == STX_V2 {
                self.start += frame_len;
                return Some(Event::Rejected(Reject::UnknownMessage(message_id)));
            }
            self.start += 1;
            return Some(Event::Rejected(Reject::Corrupt));
        };
        let frame = window.get(..frame_len)?;
        let crc_ok = match (frame.get(1..crc_at), frame.get(crc_at..crc_at + CHECKSUM)) {
            (Some(body), Some(&[lo, hi])) => calculate_crc(body, extra) == u16::from_le_bytes([lo, hi]),
            _ => false,
        };
        if !crc_ok {
            self.start += 1;
            return Some(Event::Rejected(Reject::Corrupt));
        }
        let payload_start = self.start + header_len;
        self.start += frame_len;
        let payload = self.buf.get(payload_start..payload_start + usize::from(payload_len))?;
        Some(Event::Frame(Frame {
            version,
            sequence,
            system_id,
            component_id,
            message_id,
            payload,
        }))
    }

    fn window(&self) -> &[u8] {
        self.buf.get(self.start..self.end).unwrap_or_default()
    }

    /// Move the pending bytes to the front of the buffer, in pieces that do not overlap (`memcpy` is in every
    /// image already, `memmove` would add 1.5 KiB).
    fn compact(&mut self) {
        let (shift, pending) = (self.start, self.end.saturating_sub(self.start));
        if shift == 0 {
            return;
        }
        let mut done = 0;
        while done < pending {
            let piece = shift.min(pending - done);
            let (head, tail) = self.buf.split_at_mut((done + shift).min(CAPACITY));
            if let (Some(dst), Some(src)) = (head.get_mut(done..done + piece), tail.get(..piece)) {
                dst.copy_from_slice(src);
            }
            done += piece;
        }
        self.start = 0;
        self.end = pending;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A made-up dialect for the parser alone: message 7 with CRC_EXTRA 42.
    fn extra(id: u32) -> Option<u8> {
        (id == 7).then_some(42)
    }

    fn v2(seq: u8, id: u32, payload: &[u8]) -> Vec<u8> {
        let [i0, i1, i2, _] = id.to_le_bytes();
        let mut f = vec![STX_V2, payload.len() as u8, 0, 0, seq, 9, 8, i0, i1, i2];
        f.extend_from_slice(payload);
        let crc = calculate_crc(&f[1..], extra(id).unwrap_or(0));
        f.extend_from_slice(&crc.to_le_bytes());
        f
    }

    fn v1(seq: u8, id: u8, payload: &[u8]) -> Vec<u8> {
        let mut f = vec![STX_V1, payload.len() as u8, seq, 9, 8, id];
        f.extend_from_slice(payload);
        let crc = calculate_crc(&f[1..], extra(u32::from(id)).unwrap_or(0));
        f.extend_from_slice(&crc.to_le_bytes());
        f
    }

    /// Sequence number and payload of a frame.
    type Seen = (u8, Vec<u8>);

    /// Feed `bytes` in chunks of `chunk`; returns every frame, every rejection and the skipped byte count.
    fn run(bytes: &[u8], chunk: usize) -> (Vec<Seen>, Vec<Reject>, u32) {
        let mut parser = FrameParser::new();
        let (mut frames, mut rejects, mut skipped) = (vec![], vec![], 0);
        for piece in bytes.chunks(chunk) {
            let mut rest = piece;
            while !rest.is_empty() {
                let taken = parser.push(rest);
                rest = &rest[taken..];
                while let Some(event) = parser.next(extra) {
                    match event {
                        Event::Frame(f) => frames.push((f.sequence, f.payload.to_vec())),
                        Event::Rejected(r) => rejects.push(r),
                    }
                }
                skipped += parser.take_skipped();
            }
        }
        (frames, rejects, skipped)
    }

    #[test]
    fn frames_in_any_chunking() {
        let mut bytes = v2(1, 7, &[1, 2, 3]);
        bytes.extend(v1(2, 7, &[4, 5]));
        bytes.extend(v2(3, 7, &[0x55; 255]));
        for chunk in [1, 2, 3, 7, 64, 500] {
            let (frames, rejects, skipped) = run(&bytes, chunk);
            assert_eq!(frames.len(), 3, "chunk {chunk}");
            assert_eq!(frames[0], (1, vec![1, 2, 3]));
            assert_eq!(frames[1], (2, vec![4, 5]));
            assert_eq!(frames[2].1.len(), 255);
            assert!(rejects.is_empty());
            assert_eq!(skipped, 0);
        }
    }

    #[test]
    fn bad_crc_truncation_and_noise_are_rejected_and_the_next_frame_found() {
        let good = v2(5, 7, &[10, 20, 30]);
        let mut bad_crc = v2(4, 7, &[1, 2, 3]);
        *bad_crc.last_mut().unwrap() ^= 0x01;
        let truncated = &v2(3, 7, &[9; 20])[..15];
        let mut bytes = vec![0x00, 0x11, 0x22];
        bytes.extend(&bad_crc);
        bytes.extend(truncated);
        bytes.extend(&good);
        // The truncated frame's claimed length reaches past the good frame: the good frame is found once the
        // bytes that make up the claimed length have arrived (here, the next frame).
        bytes.extend(v2(6, 7, &[1; 20]));
        for chunk in [1, 5, 64] {
            let (frames, rejects, skipped) = run(&bytes, chunk);
            assert_eq!(frames, vec![(5, vec![10, 20, 30]), (6, vec![1; 20])]);
            assert_eq!(rejects, vec![Reject::Corrupt, Reject::Corrupt]);
            assert!(skipped >= 3 + (bad_crc.len() as u32 - 1) + (truncated.len() as u32 - 1));
        }
    }

    #[test]
    fn a_frame_inside_a_false_candidate_is_found() {
        // A start byte whose claimed length swallows a real frame.
        let good = v2(1, 7, &[42]);
        let mut bytes = vec![STX_V2, 40, 0, 0, 0, 0, 0, 7, 0, 0];
        bytes.extend(&good);
        bytes.extend([0u8; 40]);
        let (frames, rejects, _) = run(&bytes, 64);
        assert_eq!(frames, vec![(1, vec![42])]);
        assert_eq!(rejects, vec![Reject::Corrupt]);
    }

    #[test]
    fn unknown_messages_are_skipped_whole_when_followed_by_a_frame() {
        let mut bytes = v2(1, 99, &[STX_V2, STX_V1, 3]);
        bytes.extend(v2(2, 7, &[1]));
        let (frames, rejects, _) = run(&bytes, 64);
        assert_eq!(frames, vec![(2, vec![1])]);
        assert_eq!(rejects, vec![Reject::UnknownMessage(99)]);
    }

    #[test]
    fn signed_frames_are_accepted_and_unknown_flags_rejected() {
        let mut signed = v2(1, 7, &[1, 2]);
        signed[2] = IFLAG_SIGNED;
        let crc_at = signed.len() - 2;
        let crc = calculate_crc(&signed[1..crc_at], 42);
        signed[crc_at..].copy_from_slice(&crc.to_le_bytes());
        signed.extend([0xAA; SIGNATURE]);
        let mut flagged = v2(2, 7, &[3]);
        flagged[2] = 0x02;
        let mut bytes = signed;
        bytes.extend(flagged);
        let (frames, rejects, _) = run(&bytes, 64);
        assert_eq!(frames, vec![(1, vec![1, 2])]);
        assert_eq!(rejects.first(), Some(&Reject::Corrupt));
    }

    #[test]
    fn random_bytes_never_panic_and_the_buffer_keeps_accepting() {
        let mut state = 0x1234_5678u32;
        let mut noise = vec![];
        for _ in 0..20_000 {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            // Plenty of start bytes and the known id.
            noise.push(match state % 8 {
                0 => STX_V2,
                1 => STX_V1,
                2 => 7,
                _ => (state >> 8) as u8,
            });
        }
        let good = v2(77, 7, &[1, 2, 3]);
        let mut bytes = noise;
        // A full frame of zeros flushes any pending false candidate, then a good frame.
        bytes.extend([0u8; MAX_FRAME + 1]);
        bytes.extend(&good);
        for chunk in [1, 13, 64] {
            let (frames, _, _) = run(&bytes, chunk);
            assert_eq!(frames.last(), Some(&(77, vec![1, 2, 3])), "chunk {chunk}");
        }
    }
}
