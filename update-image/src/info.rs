//! The record every firmware image embeds, so that its payload says what it is.

use core::fmt;

use crate::{FORMAT, INFO_LEN, Target, Version};

/// What an image is, embedded in the image itself at [`INFO_OFFSET`](crate::INFO_OFFSET), 32 bytes:
///
/// | offset | length | field                                 |
/// |--------|--------|---------------------------------------|
/// | 0      | 4      | magic, `b"LBVI"`                      |
/// | 4      | 1      | format, 1                             |
/// | 5      | 1      | [`Target`]                            |
/// | 6      | 2      | reserved, zero                        |
/// | 8      | 4      | [`Version`]: major, minor, patch (u16) |
/// | 12     | 20     | reserved, zero                        |
///
/// Being in the payload, it is covered by the signature; the update file's header repeats it unsigned, for
/// routing, and [`check`](crate::check) holds the one to the other. The reserved bytes are zero so that a later
/// format can give them a meaning a format-1 reader refuses rather than misreads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ImageInfo {
    /// What the image runs on.
    pub target: Target,
    /// Its firmware version.
    pub version: Version,
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
    /// A reserved byte is not zero.
    Reserved,
}

impl ImageInfo {
    /// The magic bytes that open the record.
    pub const MAGIC: [u8; 4] = *b"LBVI";

    /// The record of an image for `target` at `version`; const, so a firmware declares it as a static.
    pub const fn new(target: Target, version: Version) -> ImageInfo {
        ImageInfo { target, version }
    }

    /// The record's 32 bytes.
    pub const fn to_bytes(self) -> [u8; INFO_LEN] {
        let [m0, m1, m2, m3] = ImageInfo::MAGIC;
        let [v0, v1, v2, v3] = self.version.to_bytes();
        #[rustfmt::skip]
        let bytes = [
            m0, m1, m2, m3, FORMAT, self.target.to_byte(), 0, 0,
            v0, v1, v2, v3, 0, 0, 0, 0,
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
        let [m0, m1, m2, m3, format, target, r0, r1, v0, v1, v2, v3, reserved @ ..] = *bytes;
        if [m0, m1, m2, m3] != ImageInfo::MAGIC {
            return Err(InfoError::Magic([m0, m1, m2, m3]));
        }
        if format != FORMAT {
            return Err(InfoError::Format(format));
        }
        let target = Target::from_byte(target).ok_or(InfoError::Target(target))?;
        if [r0, r1] != [0; 2] || reserved != [0; 20] {
            return Err(InfoError::Reserved);
        }
        Ok(ImageInfo::new(target, Version::from_bytes([v0, v1, v2, v3])))
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
            InfoError::Format(format) => write!(f, "image info of format {format}, this build reads {FORMAT}"),
            InfoError::Target(byte) => write!(f, "image info for unknown target {byte:#04x}"),
            InfoError::Reserved => f.write_str("image info with reserved bytes that are not zero"),
        }
    }
}

impl core::error::Error for InfoError {}

/// The record's bytes for a firmware of `target` at the version of the crate that invokes it (its
/// `CARGO_PKG_VERSION`), for the image's `.image_info` static; a version that is not plain `x.y.z` stops the build:
///
/// ```ignore
/// #[unsafe(link_section = ".image_info")]
/// #[used]
/// static IMAGE_INFO: [u8; update_image::INFO_LEN] = update_image::image_info!(update_image::Target::Master);
/// ```
#[macro_export]
macro_rules! image_info {
    ($target:expr) => {
        match $crate::Version::parse(env!("CARGO_PKG_VERSION")) {
            Some(version) => $crate::ImageInfo::new($target, version).to_bytes(),
            None => panic!("the crate's version is not major.minor.patch"),
        }
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    const INFO: ImageInfo = ImageInfo::new(Target::ThrusterLegacy, Version::new(1, 2, 0x0304));

    #[test]
    fn bytes_are_the_documented_layout() {
        let mut expected = [0u8; INFO_LEN];
        expected[..4].copy_from_slice(b"LBVI");
        expected[4] = 1;
        expected[5] = 2;
        expected[8..12].copy_from_slice(&[1, 2, 0x04, 0x03]);
        assert_eq!(INFO.to_bytes(), expected);
        assert_eq!(ImageInfo::parse(&expected), Ok(INFO));
    }

    #[test]
    fn a_static_can_hold_it() {
        static IMAGE_INFO: [u8; INFO_LEN] = INFO.to_bytes();
        assert_eq!(ImageInfo::parse(&IMAGE_INFO), Ok(INFO));
    }

    #[test]
    fn refuses_in_order() {
        let good = INFO.to_bytes();
        assert_eq!(ImageInfo::parse(&good[..31]), Err(InfoError::Short { len: 31 }));
        assert_eq!(ImageInfo::parse(&[]), Err(InfoError::Short { len: 0 }));
        assert_eq!(ImageInfo::parse(&[0xFF; 32]), Err(InfoError::Magic([0xFF; 4])));
        let mut bytes = good;
        bytes[4] = 2;
        bytes[5] = 0;
        assert_eq!(ImageInfo::parse(&bytes), Err(InfoError::Format(2)));
        let mut bytes = good;
        bytes[5] = 0xFF;
        bytes[31] = 1;
        assert_eq!(ImageInfo::parse(&bytes), Err(InfoError::Target(0xFF)));
        for reserved in [6, 7, 12, 20, 31] {
            let mut bytes = good;
            bytes[reserved] = 0x80;
            assert_eq!(ImageInfo::parse(&bytes), Err(InfoError::Reserved), "byte {reserved}");
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
            "image info of format 9, this build reads 1"
        );
        assert_eq!(InfoError::Target(0).to_string(), "image info for unknown target 0x00");
    }
}
