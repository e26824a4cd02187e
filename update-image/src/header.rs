//! The update file's header.

use core::fmt;

use crate::{FORMAT, HEADER_LEN, Target, Version};

/// The 80 bytes that open an update file, before the payload:
///
/// | offset | length | field                                            |
/// |--------|--------|--------------------------------------------------|
/// | 0      | 4      | magic, `b"LBVU"`                                 |
/// | 4      | 1      | format, 1                                        |
/// | 5      | 1      | [`Target`]                                       |
/// | 6      | 2      | reserved, zero                                   |
/// | 8      | 4      | payload length in bytes, u32 little-endian       |
/// | 12     | 4      | [`Version`]: major, minor, patch (u16)           |
/// | 16     | 64     | ed25519 signature over SHA-512(payload)          |
///
/// The signature is what embassy-boot's `verify_and_mark_updated` takes with `update_len` = the payload length.
/// The header itself is not signed: its target and version are there to route the file before its payload
/// arrives, and [`check`](crate::check()) holds them to the payload's own (signed) [`ImageInfo`](crate::ImageInfo).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Header {
    /// The target the payload is built for.
    pub target: Target,
    /// The payload's length in bytes.
    pub payload_len: u32,
    /// The payload's firmware version.
    pub version: Version,
    /// The ed25519 signature over the SHA-512 digest of the payload.
    pub signature: [u8; 64],
}

/// Why bytes are not a [`Header`]. Checked in this order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HeaderError {
    /// Fewer than 80 bytes.
    Short {
        /// How many there were.
        len: usize,
    },
    /// The first 4 bytes are not `b"LBVU"`: not an update file.
    Magic([u8; 4]),
    /// A format this crate does not read.
    Format(u8),
    /// A target byte that names no target.
    Target(u8),
    /// The reserved field is not zero.
    Reserved(u16),
}

impl Header {
    /// The magic bytes that open an update file.
    pub const MAGIC: [u8; 4] = *b"LBVU";

    /// The header's 80 bytes.
    pub fn to_bytes(&self) -> [u8; HEADER_LEN] {
        let [m0, m1, m2, m3] = Header::MAGIC;
        let [l0, l1, l2, l3] = self.payload_len.to_le_bytes();
        let [v0, v1, v2, v3] = self.version.to_bytes();
        let fixed = [
            m0,
            m1,
            m2,
            m3,
            FORMAT,
            self.target.to_byte(),
            0,
            0,
            l0,
            l1,
            l2,
            l3,
            v0,
            v1,
            v2,
            v3,
        ];
        let mut bytes = [0; HEADER_LEN];
        // Both chunks are within the 80 bytes (16 + 64), so both are always there.
        if let Some(start) = bytes.first_chunk_mut::<16>() {
            *start = fixed;
        }
        if let Some(end) = bytes.last_chunk_mut::<64>() {
            *end = self.signature;
        }
        bytes
    }

    /// The header at the start of `bytes` (the payload may follow; it is not looked at).
    pub fn parse(bytes: &[u8]) -> Result<Header, HeaderError> {
        let Some(bytes) = bytes.first_chunk::<HEADER_LEN>() else {
            return Err(HeaderError::Short { len: bytes.len() });
        };
        let [
            m0,
            m1,
            m2,
            m3,
            format,
            target,
            r0,
            r1,
            l0,
            l1,
            l2,
            l3,
            v0,
            v1,
            v2,
            v3,
            signature @ ..,
        ] = *bytes;
        if [m0, m1, m2, m3] != Header::MAGIC {
            return Err(HeaderError::Magic([m0, m1, m2, m3]));
        }
        if format != FORMAT {
            return Err(HeaderError::Format(format));
        }
        let target = Target::from_byte(target).ok_or(HeaderError::Target(target))?;
        let reserved = u16::from_le_bytes([r0, r1]);
        if reserved != 0 {
            return Err(HeaderError::Reserved(reserved));
        }
        Ok(Header {
            target,
            payload_len: u32::from_le_bytes([l0, l1, l2, l3]),
            version: Version::from_bytes([v0, v1, v2, v3]),
            signature,
        })
    }
}

impl fmt::Display for HeaderError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            HeaderError::Short { len } => write!(f, "the header needs {HEADER_LEN} bytes, there are {len}"),
            HeaderError::Magic([a, b, c, d]) => write!(
                f,
                "not an update file: it opens with {:02x} {:02x} {:02x} {:02x}, not \"LBVU\"",
                a, b, c, d
            ),
            HeaderError::Format(format) => write!(f, "update file of format {format}, this build reads {FORMAT}"),
            HeaderError::Target(byte) => write!(f, "update file for unknown target {byte:#04x}"),
            HeaderError::Reserved(value) => write!(f, "update file with reserved field {value:#06x}, not zero"),
        }
    }
}

impl core::error::Error for HeaderError {}

#[cfg(test)]
mod tests {
    use super::*;

    fn header() -> Header {
        let mut signature = [0; 64];
        for (i, byte) in signature.iter_mut().enumerate() {
            *byte = 0x80 + i as u8;
        }
        Header {
            target: Target::Master,
            payload_len: 0x0001_2340,
            version: Version::new(3, 4, 0x0506),
            signature,
        }
    }

    #[test]
    fn bytes_are_the_documented_layout() {
        let header = header();
        let bytes = header.to_bytes();
        assert_eq!(&bytes[..4], b"LBVU");
        assert_eq!(bytes[4], 1);
        assert_eq!(bytes[5], 3);
        assert_eq!(bytes[6..8], [0, 0]);
        assert_eq!(bytes[8..12], [0x40, 0x23, 0x01, 0x00]);
        assert_eq!(bytes[12..16], [3, 4, 0x06, 0x05]);
        assert_eq!(bytes[16..], header.signature);
        assert_eq!(Header::parse(&bytes), Ok(header));
    }

    #[test]
    fn refuses_in_order() {
        let good = header().to_bytes();
        assert_eq!(Header::parse(&good[..79]), Err(HeaderError::Short { len: 79 }));
        assert_eq!(Header::parse(b"LBVU"), Err(HeaderError::Short { len: 4 }));
        let mut bytes = good;
        bytes[3] = b'I';
        bytes[4] = 7;
        assert_eq!(Header::parse(&bytes), Err(HeaderError::Magic(*b"LBVI")));
        let mut bytes = good;
        bytes[4] = 0;
        bytes[5] = 0;
        assert_eq!(Header::parse(&bytes), Err(HeaderError::Format(0)));
        let mut bytes = good;
        bytes[5] = 4;
        bytes[7] = 1;
        assert_eq!(Header::parse(&bytes), Err(HeaderError::Target(4)));
        let mut bytes = good;
        bytes[7] = 1;
        assert_eq!(Header::parse(&bytes), Err(HeaderError::Reserved(0x0100)));
        // The payload after it is not looked at.
        let mut file = [0u8; 100];
        file[..80].copy_from_slice(&good);
        assert_eq!(Header::parse(&file), Ok(header()));
    }

    #[test]
    fn errors_read_as_english() {
        assert_eq!(
            HeaderError::Magic(*b"\x7fELF").to_string(),
            "not an update file: it opens with 7f 45 4c 46, not \"LBVU\""
        );
        assert_eq!(
            HeaderError::Short { len: 12 }.to_string(),
            "the header needs 80 bytes, there are 12"
        );
        assert_eq!(
            HeaderError::Reserved(1).to_string(),
            "update file with reserved field 0x0001, not zero"
        );
    }
}
