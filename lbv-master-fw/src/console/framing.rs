//! MAVLink framing: finds MAVLink 2 (and 1) frames in a byte stream and resynchronises after noise.
//!
//! The parser keeps one maximum-size frame of look-ahead. A candidate that fails its CRC is dropped by one byte
//! only, so a good frame hiding behind a false start marker (a truncated frame, noise containing 0xFD or 0xFE) is
//! still found. So is a candidate whose claimed length has not arrived when the input ends
//! ([`FrameParser::end_of_input`]: the line fell quiet, the datagram ended): a stray start byte costs the time the
//! line needs to fall quiet, not the up to 280 bytes its claimed length would take to arrive.
//!
//! A frame whose message id the dialect does not know cannot be CRC-checked; its length is trusted only when the
//! byte after it starts another frame or the input ends there, otherwise it is treated as noise.
//!
//! Signatures are not checked here: a signed frame comes out whole, for [`crate::console::signing`] to check.

use mavlink_core::calculate_crc;

const STX_V1: u8 = 0xFE;
const STX_V2: u8 = 0xFD;
/// STX LEN SEQ SYS COMP MSGID.
const V1_HEADER: usize = 6;
/// STX LEN INCOMPAT COMPAT SEQ SYS COMP MSGID\[3\].
const V2_HEADER: usize = 10;
const CHECKSUM: usize = 2;
const SIGNATURE: usize = 13;
/// The only MAVLink 2 incompatibility flag understood: the frame carries a signature.
const IFLAG_SIGNED: u8 = 0x01;
/// The longest frame: signed MAVLink 2 with a 255-byte payload.
pub(crate) const MAX_FRAME: usize = V2_HEADER + 255 + CHECKSUM + SIGNATURE;
/// A whole frame, the byte after it (to accept an unknown message) and room for a read chunk.
const CAPACITY: usize = MAX_FRAME + 1 + 63;

/// MAVLink protocol version of a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) enum Version {
    /// MAVLink 1 (start byte 0xFE).
    V1,
    /// MAVLink 2 (start byte 0xFD).
    V2,
}

/// A frame, borrowed from the parser's buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Frame<'a> {
    /// By its start byte.
    pub(crate) version: Version,
    /// The sender's sequence number.
    pub(crate) sequence: u8,
    /// The sender's system id.
    pub(crate) system_id: u8,
    /// The sender's component id.
    pub(crate) component_id: u8,
    /// 24 bits in MAVLink 2, 8 in MAVLink 1.
    pub message_id: u32,
    /// The payload as sent (MAVLink 2 trims trailing zeros).
    pub payload: &'a [u8],
    /// It carries a signature (MAVLink 2 incompatibility flag 0x01): the last 13 of `bytes`.
    pub signed: bool,
    /// The whole frame as received, from its start byte to its checksum or signature.
    pub bytes: &'a [u8],
}

/// What [`FrameParser::next`] found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Event<'a> {
    /// A CRC-valid frame of a message the dialect holds.
    Frame(Frame<'a>),
    /// A well-framed message the dialect does not hold (its CRC cannot be checked), skipped whole.
    Unknown(Frame<'a>),
    /// A false start dropped by one byte: wrong CRC (a truncated frame shows as one), an unsupported MAVLink 2
    /// incompatibility flag, a claimed length that did not arrive before the end of the input, or an unknown
    /// message not followed by another frame.
    Corrupt,
}

/// The fixed part of a frame.
struct Header {
    version: Version,
    len: usize,
    payload_len: usize,
    incompat: u8,
    sequence: u8,
    system_id: u8,
    component_id: u8,
    message_id: u32,
}

impl Header {
    /// The header at the start of `window` (which starts with a start byte), `None` until all of it is there.
    fn read(window: &[u8]) -> Option<Header> {
        if window.first() == Some(&STX_V2) {
            let [
                _,
                len,
                incompat,
                _compat,
                sequence,
                system_id,
                component_id,
                id0,
                id1,
                id2,
            ] = *window.first_chunk::<V2_HEADER>()?;
            Some(Header {
                version: Version::V2,
                len: V2_HEADER,
                payload_len: usize::from(len),
                incompat,
                sequence,
                system_id,
                component_id,
                message_id: u32::from_le_bytes([id0, id1, id2, 0]),
            })
        } else {
            let [_, len, sequence, system_id, component_id, id] = *window.first_chunk::<V1_HEADER>()?;
            Some(Header {
                version: Version::V1,
                len: V1_HEADER,
                payload_len: usize::from(len),
                incompat: 0,
                sequence,
                system_id,
                component_id,
                message_id: u32::from(id),
            })
        }
    }

    fn signed(&self) -> bool {
        self.incompat & IFLAG_SIGNED != 0
    }

    /// Where the checksum starts.
    fn crc_at(&self) -> usize {
        self.len + self.payload_len
    }

    /// The whole frame's length.
    fn frame_len(&self) -> usize {
        self.crc_at() + CHECKSUM + if self.signed() { SIGNATURE } else { 0 }
    }
}

/// Incremental MAVLink frame parser with a fixed buffer; never panics, whatever the input.
#[derive(Debug, Clone)]
pub struct FrameParser {
    buf: [u8; CAPACITY],
    start: usize,
    end: usize,
    skipped: u32,
    /// No more bytes of the buffered frames will come (until the next push).
    ended: bool,
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
            ended: false,
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
            if taken > 0 {
                self.ended = false;
            }
            taken
        } else {
            0
        }
    }

    /// The input has ended for now (the line fell quiet, a datagram ended): no more bytes will complete the
    /// buffered candidates, so [`FrameParser::next`] resolves them all, and the buffer is empty once it returns
    /// `None`.
    pub fn end_of_input(&mut self) {
        self.ended = true;
    }

    /// Whether bytes are buffered (a frame begun but not complete).
    pub(crate) fn pending(&self) -> bool {
        self.end > self.start
    }

    /// Bytes dropped while looking for a start byte since the last call.
    pub(crate) fn take_skipped(&mut self) -> u32 {
        core::mem::take(&mut self.skipped)
    }

    /// The next frame or dropped candidate in the buffered bytes, or `None` when more bytes are needed.
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

        let Some(header) = Header::read(self.window()) else {
            return self.incomplete();
        };
        if header.incompat & !IFLAG_SIGNED != 0 {
            self.start += 1;
            return Some(Event::Corrupt);
        }
        let frame_len = header.frame_len();
        if self.window().len() < frame_len {
            return self.incomplete();
        }
        let Some(extra) = extra_crc(header.message_id) else {
            // Unknown message: trust its length only if another frame starts right after it, or nothing does.
            let trusted = match self.window().get(frame_len) {
                Some(&next) => next == STX_V1 || next == STX_V2,
                None if self.ended => true,
                None => return None,
            };
            if !trusted {
                self.start += 1;
                return Some(Event::Corrupt);
            }
            let begin = self.start;
            self.start += frame_len;
            return Some(Event::Unknown(self.frame_at(begin, &header)?));
        };
        let crc_at = header.crc_at();
        let window = self.window();
        let crc_ok = match (window.get(1..crc_at), window.get(crc_at..crc_at + CHECKSUM)) {
            (Some(body), Some(&[lo, hi])) => calculate_crc(body, extra) == u16::from_le_bytes([lo, hi]),
            _ => false,
        };
        if !crc_ok {
            self.start += 1;
            return Some(Event::Corrupt);
        }
        let begin = self.start;
        self.start += frame_len;
        Some(Event::Frame(self.frame_at(begin, &header)?))
    }

    /// A candidate that needs bytes not here yet: wait for them, or drop its start byte when the input has ended.
    fn incomplete(&mut self) -> Option<Event<'static>> {
        if self.ended {
            self.start += 1;
            Some(Event::Corrupt)
        } else {
            None
        }
    }

    /// The frame of `header` starting at `begin` in the buffer.
    fn frame_at(&self, begin: usize, header: &Header) -> Option<Frame<'_>> {
        let bytes = self.buf.get(begin..begin + header.frame_len())?;
        Some(Frame {
            version: header.version,
            sequence: header.sequence,
            system_id: header.system_id,
            component_id: header.component_id,
            message_id: header.message_id,
            payload: bytes.get(header.len..header.crc_at())?,
            signed: header.signed(),
            bytes,
        })
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

    /// What came out of the parser, in order.
    #[derive(Debug, Clone, PartialEq, Eq)]
    enum Seen {
        /// Sequence number and payload of a frame.
        Frame(u8, Vec<u8>),
        Unknown(u32),
        Corrupt,
    }

    /// Feed `pieces` one after the other in chunks of `chunk`, ending the input after each piece when `ends`;
    /// returns what came out and the skipped byte count.
    fn run_pieces(pieces: &[Vec<u8>], chunk: usize, ends: bool) -> (Vec<Seen>, u32) {
        let mut parser = FrameParser::new();
        let (mut seen, mut skipped) = (vec![], 0);
        let mut drain = |parser: &mut FrameParser| {
            while let Some(event) = parser.next(extra) {
                seen.push(match event {
                    Event::Frame(f) => {
                        assert_eq!(
                            f.bytes.len(),
                            f.payload.len() + if f.version == Version::V2 { 12 } else { 8 }
                        );
                        Seen::Frame(f.sequence, f.payload.to_vec())
                    }
                    Event::Unknown(f) => Seen::Unknown(f.message_id),
                    Event::Corrupt => Seen::Corrupt,
                });
            }
            skipped += parser.take_skipped();
        };
        for piece in pieces {
            for bytes in piece.chunks(chunk) {
                let mut rest = bytes;
                while !rest.is_empty() {
                    let taken = parser.push(rest);
                    rest = &rest[taken..];
                    drain(&mut parser);
                }
            }
            if ends {
                parser.end_of_input();
                drain(&mut parser);
                assert!(!parser.pending(), "the end of the input resolves everything");
            }
        }
        (seen, skipped)
    }

    fn run(bytes: &[u8], chunk: usize) -> (Vec<Seen>, u32) {
        run_pieces(&[bytes.to_vec()], chunk, false)
    }

    fn frames(seen: &[Seen]) -> Vec<Seen> {
        seen.iter().filter(|s| matches!(s, Seen::Frame(..))).cloned().collect()
    }

    #[test]
    fn frames_in_any_chunking() {
        let mut bytes = v2(1, 7, &[1, 2, 3]);
        bytes.extend(v1(2, 7, &[4, 5]));
        bytes.extend(v2(3, 7, &[0x55; 255]));
        for chunk in [1, 2, 3, 7, 64, 500] {
            let (seen, skipped) = run(&bytes, chunk);
            assert_eq!(seen.len(), 3, "chunk {chunk}");
            assert_eq!(seen[0], Seen::Frame(1, vec![1, 2, 3]));
            assert_eq!(seen[1], Seen::Frame(2, vec![4, 5]));
            assert_eq!(seen[2], Seen::Frame(3, vec![0x55; 255]));
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
        // The truncated frame's claimed length reaches past the good frame: in a stream that does not pause, the
        // good frame is found once the bytes that make up the claimed length have arrived (here, the next frame).
        bytes.extend(v2(6, 7, &[1; 20]));
        for chunk in [1, 5, 64] {
            let (seen, skipped) = run(&bytes, chunk);
            assert_eq!(
                seen,
                vec![
                    Seen::Corrupt,
                    Seen::Corrupt,
                    Seen::Frame(5, vec![10, 20, 30]),
                    Seen::Frame(6, vec![1; 20])
                ]
            );
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
        let (seen, _) = run(&bytes, 64);
        assert_eq!(seen, vec![Seen::Corrupt, Seen::Frame(1, vec![42])]);
    }

    /// The stray bytes that once blinded the parser for a whole claimed length (up to 280 bytes: 13 s of 1 Hz
    /// heartbeats on the serial link).
    const STRAYS: [&[u8]; 4] = [
        &[STX_V1],
        &[STX_V2, 0xFF, 0x00],
        &[STX_V2, 0xFF],
        &[0x00, STX_V2, 0xF0, 0x01],
    ];

    #[test]
    fn a_stray_byte_costs_nothing_once_the_input_ends() {
        let heartbeat = v2(9, 7, &[1, 2, 3, 4]);
        for stray in STRAYS {
            // The stray bytes and the frame in one piece (one datagram, or one burst on the line), the line quiet
            // after it: the frame is found at the end of the piece, not 280 bytes later.
            let piece = [stray, heartbeat.as_slice()].concat();
            for chunk in [1, 3, 64] {
                let (seen, _) = run_pieces(std::slice::from_ref(&piece), chunk, true);
                assert_eq!(
                    frames(&seen),
                    vec![Seen::Frame(9, vec![1, 2, 3, 4])],
                    "{stray:02x?} chunk {chunk}"
                );
            }
            // The stray bytes alone, then the frame later: each piece is resolved on its own.
            let (seen, _) = run_pieces(&[stray.to_vec(), heartbeat.clone()], 64, true);
            assert_eq!(frames(&seen), vec![Seen::Frame(9, vec![1, 2, 3, 4])], "{stray:02x?}");
            assert!(seen.contains(&Seen::Corrupt));
        }
        // Without the end of the input the parser waits for the claimed length: the end is what frees it.
        let piece = [&[STX_V1], heartbeat.as_slice()].concat();
        assert!(frames(&run(&piece, 64).0).is_empty());
    }

    #[test]
    fn a_clean_stream_is_unchanged_by_the_ends_of_input_between_frames() {
        let stream = [
            v2(1, 7, &[1]),
            v1(2, 7, &[2, 2]),
            v2(3, 99, &[3, 3, 3]),
            v2(4, 7, &[0xFD; 30]),
        ];
        for chunk in [1, 2, 64] {
            let (seen, skipped) = run_pieces(&stream, chunk, true);
            assert_eq!(
                seen,
                vec![
                    Seen::Frame(1, vec![1]),
                    Seen::Frame(2, vec![2, 2]),
                    Seen::Unknown(99),
                    Seen::Frame(4, vec![0xFD; 30])
                ]
            );
            assert_eq!(skipped, 0);
        }
    }

    #[test]
    fn unknown_messages_are_skipped_whole_when_followed_by_a_frame_or_the_end() {
        let mut bytes = v2(1, 99, &[STX_V2, STX_V1, 3]);
        bytes.extend(v2(2, 7, &[1]));
        let (seen, _) = run(&bytes, 64);
        assert_eq!(seen, vec![Seen::Unknown(99), Seen::Frame(2, vec![1])]);
        // Followed by nothing yet: waits; by the end of the input: skipped whole.
        assert_eq!(run(&v2(1, 99, &[5]), 64).0, vec![]);
        assert_eq!(run_pieces(&[v2(1, 99, &[5])], 64, true).0, vec![Seen::Unknown(99)]);
        // Followed by noise: not trusted, rescanned.
        let mut noisy = v2(1, 99, &[5]);
        noisy.push(0x00);
        assert_eq!(run(&noisy, 64).0.first(), Some(&Seen::Corrupt));
    }

    #[test]
    fn signed_frames_come_out_whole_and_unknown_flags_are_rejected() {
        let mut signed = v2(1, 7, &[1, 2]);
        signed[2] = IFLAG_SIGNED;
        let crc_at = signed.len() - 2;
        let crc = calculate_crc(&signed[1..crc_at], 42);
        signed[crc_at..].copy_from_slice(&crc.to_le_bytes());
        signed.extend([0xAA; SIGNATURE]);
        let mut flagged = v2(2, 7, &[3]);
        flagged[2] = 0x02;
        let mut parser = FrameParser::new();
        parser.push(&signed);
        match parser.next(extra) {
            Some(Event::Frame(f)) => {
                assert!(f.signed);
                assert_eq!(f.bytes, signed.as_slice());
                assert_eq!(f.payload, &[1, 2]);
            }
            other => panic!("{other:?}"),
        }
        let (seen, _) = run(&flagged, 64);
        assert_eq!(seen.first(), Some(&Seen::Corrupt));
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
        for chunk in [1, 13, 64] {
            // A full frame of zeros flushes any pending false candidate in a stream that never pauses...
            let flushed = [noise.clone(), vec![0u8; MAX_FRAME + 1], good.clone()].concat();
            let (seen, _) = run(&flushed, chunk);
            assert_eq!(seen.last(), Some(&Seen::Frame(77, vec![1, 2, 3])), "chunk {chunk}");
            // ...and so does the end of the input.
            let (seen, _) = run_pieces(&[noise.clone(), good.clone()], chunk, true);
            assert_eq!(seen.last(), Some(&Seen::Frame(77, vec![1, 2, 3])), "chunk {chunk}");
        }
    }
}
