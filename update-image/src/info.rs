//! The record every firmware image embeds, so that its payload says what it is, and the key it takes updates with.

use core::fmt;

use crate::{INFO_FORMAT, INFO_LEN, Target, Version};

/// What an image is, embedded in the image itself at [`INFO_OFFSET`](crate::INFO_OFFSET), 32 bytes (format 2):
///
/// | offset | length | field                                                              |
/// |--------|--------|--------------------------------------------------------------------|
/// | 0      | 4      | magic, `b"LBVI"`                                                   |
/// | 4      | 1      | format, 2                                                          |
/// | 5      | 1      | [`Target`]                                                         |
/// | 6      | 1      | flags: bit 0 [`rollback`](ImageInfo::rollback); bits 1-7 zero       |
/// | 7      | 1      | reserved, zero                                                     |
/// | 8      | 4      | [`Version`]: major, minor, patch (u16)                             |
/// | 12     | 4      | [`security_counter`](ImageInfo::security_counter), u32 little-endian |
/// | 16     | 16     | reserved, zero                                                     |
///
/// Format 1 had bytes 6, 7 and 12..32 reserved as zero: it reads as format 2 with no flags and counter 0, and
/// is read for what it says (an older image's record), though only a format-2 image carries the key record
/// after it ([`KEY_OFFSET`](crate::KEY_OFFSET)).
///
/// Being in the payload, it is covered by the signature; the update file's header repeats target and version
/// unsigned, for routing, and [`check`](crate::check()) holds the one to the other. The reserved bytes are zero so
/// that a later format can give them a meaning a format-2 reader refuses rather than misreads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ImageInfo {
    /// What the image runs on.
    pub target: Target,
    /// Its firmware version.
    pub version: Version,
    /// The lowest security counter a vehicle that ran this image takes: its bootloader keeps the highest counter
    /// of the images it confirmed and refuses to swap in one below it (MCUboot's security counter). Set when the
    /// image is signed (`lbv image sign --security-counter`); 0 in a build.
    pub security_counter: u32,
    /// The image was signed to go back on purpose (`lbv image sign --allow-rollback`): it may replace a newer
    /// version. It is still held to the security counter.
    pub rollback: bool,
    /// The record's format as read: 1 or 2 ([`INFO_FORMAT`]). Only a format-2 image embeds its update key.
    pub format: u8,
}

/// Why bytes are not an [`ImageInfo`]. Checked in this order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum InfoError {
    /// Fewer than 32 bytes.
    Short {
        /// How many there were.
        len: usize,
    },
    /// The first 4 bytes are not `b"LBVI"`: an image built without the record, or the wrong place.
    Magic([u8; 4]),
    /// A format this crate does not read.
    Format(u8),
    /// A target byte that names no target.
    Target(u8),
    /// A reserved byte or flag is not zero.
    Reserved,
}

/// The flag bit of [`ImageInfo::rollback`].
const ROLLBACK: u8 = 1;

impl ImageInfo {
    /// The magic bytes that open the record.
    pub const MAGIC: [u8; 4] = *b"LBVI";

    /// The record of an image for `target` at `version` (format 2, counter 0, no rollback); const, so a firmware
    /// declares it as a static.
    pub const fn new(target: Target, version: Version) -> ImageInfo {
        ImageInfo {
            target,
            version,
            security_counter: 0,
            rollback: false,
            format: INFO_FORMAT,
        }
    }

    /// The same record with `counter` as its security counter.
    pub const fn with_security_counter(self, counter: u32) -> ImageInfo {
        ImageInfo {
            security_counter: counter,
            ..self
        }
    }

    /// The same record, signed to go back on purpose or not.
    pub const fn with_rollback(self, rollback: bool) -> ImageInfo {
        ImageInfo { rollback, ..self }
    }

    /// The record's 32 bytes, in format 2 whatever format it was read from.
    pub const fn to_bytes(self) -> [u8; INFO_LEN] {
        let [m0, m1, m2, m3] = ImageInfo::MAGIC;
        let [v0, v1, v2, v3] = self.version.to_bytes();
        let [c0, c1, c2, c3] = self.security_counter.to_le_bytes();
        let flags = if self.rollback { ROLLBACK } else { 0 };
        #[rustfmt::skip]
        let bytes = [
            m0, m1, m2, m3, INFO_FORMAT, self.target.to_byte(), flags, 0,
            v0, v1, v2, v3, c0, c1, c2, c3,
            0, 0, 0, 0, 0, 0, 0, 0,
            0, 0, 0, 0, 0, 0, 0, 0,
        ];
        bytes
    }

    /// The record at the start of `bytes` (any bytes after its 32 are not looked at).
    pub fn parse(bytes: &[u8]) -> Result<ImageInfo, InfoError> {
        let Some(bytes) = bytes.first_chunk::<INFO_LEN>() else {
            return Err(InfoError::Short { len: bytes.len() });
        };
        let [
            m0,
            m1,
            m2,
            m3,
            format,
            target,
            flags,
            r0,
            v0,
            v1,
            v2,
            v3,
            c0,
            c1,
            c2,
            c3,
            reserved @ ..,
        ] = *bytes;
        if [m0, m1, m2, m3] != ImageInfo::MAGIC {
            return Err(InfoError::Magic([m0, m1, m2, m3]));
        }
        if !(1..=INFO_FORMAT).contains(&format) {
            return Err(InfoError::Format(format));
        }
        let target = Target::from_byte(target).ok_or(InfoError::Target(target))?;
        if flags & !ROLLBACK != 0 || r0 != 0 || reserved != [0; 16] {
            return Err(InfoError::Reserved);
        }
        // Format 1 reserved the flags and the counter as zero: a format-1 record with them set is not one.
        if format == 1 && (flags != 0 || [c0, c1, c2, c3] != [0; 4]) {
            return Err(InfoError::Reserved);
        }
        Ok(ImageInfo {
            target,
            version: Version::from_bytes([v0, v1, v2, v3]),
            security_counter: u32::from_le_bytes([c0, c1, c2, c3]),
            rollback: flags & ROLLBACK != 0,
            format,
        })
    }
}

impl fmt::Display for InfoError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            InfoError::Short { len } => write!(f, "the image info needs {INFO_LEN} bytes, there are {len}"),
            InfoError::Magic([a, b, c, d]) => write!(
                f,
                "no image info: {:02x} {:02x} {:02x} {:02x} where \"LBVI\" goes",
                a, b, c, d
            ),
            InfoError::Format(format) => {
                write!(f, "image info of format {format}, this build reads 1 to {INFO_FORMAT}")
            }
            InfoError::Target(byte) => write!(f, "image info for unknown target {byte:#04x}"),
            InfoError::Reserved => f.write_str("image info with reserved bytes or flags that are not zero"),
        }
    }
}

impl core::error::Error for InfoError {}

/// What an image's `.image_info` section holds for a firmware of `target` at the version of the crate that invokes
/// it (its `CARGO_PKG_VERSION`): its [`ImageInfo`] and, after it, the key it takes updates with
/// ([`UPDATE_KEY`](crate::UPDATE_KEY), feature `key`), [`IMAGE_RECORD_LEN`](crate::IMAGE_RECORD_LEN) bytes. A
/// version that is not plain `x.y.z` stops the build:
///
/// ```ignore
/// #[unsafe(link_section = ".image_info")]
/// #[used]
/// static IMAGE_INFO: [u8; update_image::IMAGE_RECORD_LEN] = update_image::image_info!(update_image::Target::Master);
/// ```
#[macro_export]
macro_rules! image_info {
    ($target:expr) => {
        match $crate::Version::parse(env!("CARGO_PKG_VERSION")) {
            Some(version) => $crate::image_record($crate::ImageInfo::new($target, version), &$crate::UPDATE_KEY),
            None => panic!("the crate's version is not major.minor.patch"),
        }
    };
}

/// An image's `.image_info` section: `info`'s bytes, then `key`.
pub const fn image_record(info: ImageInfo, key: &[u8; 32]) -> [u8; crate::IMAGE_RECORD_LEN] {
    let mut record = [0; crate::IMAGE_RECORD_LEN];
    let (head, tail) = record.split_at_mut(INFO_LEN);
    if let (Some(head), Some(tail)) = (head.first_chunk_mut::<INFO_LEN>(), tail.first_chunk_mut::<32>()) {
        *head = info.to_bytes();
        *tail = *key;
    }
    record
}

#[cfg(test)]
mod tests {
    use super::*;

    const INFO: ImageInfo = ImageInfo::new(Target::ThrusterLegacy, Version::new(1, 2, 0x0304));

    #[test]
    fn bytes_are_the_documented_layout() {
        let mut expected = [0u8; INFO_LEN];
        expected[..4].copy_from_slice(b"LBVI");
        expected[4] = 2;
        expected[5] = 2;
        expected[8..12].copy_from_slice(&[1, 2, 0x04, 0x03]);
        assert_eq!(INFO.to_bytes(), expected);
        assert_eq!(ImageInfo::parse(&expected), Ok(INFO));
        let signed = INFO.with_security_counter(0x0102_0304).with_rollback(true);
        expected[6] = 1;
        expected[12..16].copy_from_slice(&[4, 3, 2, 1]);
        assert_eq!(signed.to_bytes(), expected);
        assert_eq!(ImageInfo::parse(&expected), Ok(signed));
    }

    #[test]
    fn format_1_reads_as_no_flags_and_counter_0() {
        let mut bytes = INFO.to_bytes();
        bytes[4] = 1;
        let info = ImageInfo::parse(&bytes).unwrap();
        assert_eq!(info, ImageInfo { format: 1, ..INFO });
        // What format 1 reserved, it cannot carry.
        for at in [6, 12, 15] {
            let mut bytes = bytes;
            bytes[at] = 1;
            assert_eq!(ImageInfo::parse(&bytes), Err(InfoError::Reserved), "byte {at}");
        }
    }

    #[test]
    fn a_static_can_hold_it_and_the_key_after_it() {
        static IMAGE_INFO: [u8; crate::IMAGE_RECORD_LEN] = image_record(INFO, &[0x5A; 32]);
        assert_eq!(ImageInfo::parse(&IMAGE_INFO), Ok(INFO));
        assert_eq!(IMAGE_INFO[INFO_LEN..], [0x5A; 32]);
        assert_eq!(crate::KEY_OFFSET, crate::INFO_OFFSET + INFO_LEN);
    }

    #[test]
    fn refuses_in_order() {
        let good = INFO.to_bytes();
        assert_eq!(ImageInfo::parse(&good[..31]), Err(InfoError::Short { len: 31 }));
        assert_eq!(ImageInfo::parse(&[]), Err(InfoError::Short { len: 0 }));
        assert_eq!(ImageInfo::parse(&[0xFF; 32]), Err(InfoError::Magic([0xFF; 4])));
        for format in [0, 3, 0xFF] {
            let mut bytes = good;
            bytes[4] = format;
            bytes[5] = 0;
            assert_eq!(ImageInfo::parse(&bytes), Err(InfoError::Format(format)));
        }
        let mut bytes = good;
        bytes[5] = 0xFF;
        bytes[31] = 1;
        assert_eq!(ImageInfo::parse(&bytes), Err(InfoError::Target(0xFF)));
        for (at, value) in [(6, 0x02), (6, 0x80), (7, 1), (16, 1), (20, 0x80), (31, 0x80)] {
            let mut bytes = good;
            bytes[at] = value;
            assert_eq!(ImageInfo::parse(&bytes), Err(InfoError::Reserved), "byte {at}");
        }
        // What follows the record is not its business.
        let mut longer = [0xAA; 40];
        longer[..32].copy_from_slice(&good);
        assert_eq!(ImageInfo::parse(&longer), Ok(INFO));
    }

    #[test]
    fn errors_read_as_english() {
        assert_eq!(
            InfoError::Magic([0xFF; 4]).to_string(),
            "no image info: ff ff ff ff where \"LBVI\" goes"
        );
        assert_eq!(
            InfoError::Short { len: 3 }.to_string(),
            "the image info needs 32 bytes, there are 3"
        );
        assert_eq!(
            InfoError::Format(9).to_string(),
            "image info of format 9, this build reads 1 to 2"
        );
        assert_eq!(InfoError::Target(0).to_string(), "image info for unknown target 0x00");
    }
}
