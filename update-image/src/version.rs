//! The firmware version an image carries.

use core::fmt;

/// A firmware version, as Cargo's package version gives it: major, minor, patch. Stored in 4 bytes, little-endian:
/// major, minor, then patch as a u16.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Version {
    /// Major version.
    pub major: u8,
    /// Minor version.
    pub minor: u8,
    /// Patch version.
    pub patch: u16,
}

impl Version {
    /// Length of a stored version, in bytes.
    pub const LEN: usize = 4;

    /// A version from its parts.
    pub const fn new(major: u8, minor: u8, patch: u16) -> Version {
        Version { major, minor, patch }
    }

    /// The version of a plain "x.y.z" (Cargo's `CARGO_PKG_VERSION`), at compile time. `None` for anything else: a
    /// pre-release or build suffix ("1.2.3-rc1"), a part that does not fit (major or minor over 255, patch over
    /// 65535), a missing or empty part. A pre-release is refused rather than stored as the release it precedes,
    /// which a device could then not tell from it.
    pub const fn parse(text: &str) -> Option<Version> {
        // The parts so far: [major, minor, patch], `part` the one being read.
        let (mut major, mut minor, mut patch) = (0u32, 0u32, 0u32);
        let mut part = 0;
        let mut digits = 0;
        let mut rest = text.as_bytes();
        while let [byte, tail @ ..] = rest {
            rest = tail;
            match *byte {
                b'0'..=b'9' => {
                    let slot = match part {
                        0 => &mut major,
                        1 => &mut minor,
                        _ => &mut patch,
                    };
                    // Below 65536 before, so no overflow here; stop as soon as no part can hold it.
                    *slot = *slot * 10 + (*byte - b'0') as u32;
                    if *slot > u16::MAX as u32 {
                        return None;
                    }
                    digits += 1;
                }
                b'.' if digits > 0 && part < 2 => {
                    part += 1;
                    digits = 0;
                }
                _ => return None,
            }
        }
        if part != 2 || digits == 0 || major > u8::MAX as u32 || minor > u8::MAX as u32 {
            return None;
        }
        Some(Version::new(major as u8, minor as u8, patch as u16))
    }

    /// The stored bytes.
    pub const fn to_bytes(self) -> [u8; Version::LEN] {
        let [patch_low, patch_high] = self.patch.to_le_bytes();
        [self.major, self.minor, patch_low, patch_high]
    }

    /// The version stored in these bytes (any 4 bytes are a version).
    pub const fn from_bytes(bytes: [u8; Version::LEN]) -> Version {
        let [major, minor, patch_low, patch_high] = bytes;
        Version::new(major, minor, u16::from_le_bytes([patch_low, patch_high]))
    }
}

/// "1.2.3".
impl fmt::Display for Version {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}.{}.{}", self.major, self.minor, self.patch)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_plain_versions() {
        assert_eq!(Version::parse("0.1.0"), Some(Version::new(0, 1, 0)));
        assert_eq!(Version::parse("255.255.65535"), Some(Version::new(255, 255, 65535)));
        assert_eq!(Version::parse("1.20.300"), Some(Version::new(1, 20, 300)));
        assert_eq!(
            Version::parse(env!("CARGO_PKG_VERSION"))
                .map(|v| v.to_string())
                .as_deref(),
            Some(env!("CARGO_PKG_VERSION"))
        );
        const AT_COMPILE_TIME: Option<Version> = Version::parse("2.0.7");
        assert_eq!(AT_COMPILE_TIME, Some(Version::new(2, 0, 7)));
    }

    #[test]
    fn refuses_anything_else() {
        for text in [
            "",
            "1",
            "1.2",
            "1.2.",
            ".1.2",
            "1..2",
            "1.2.3.4",
            "1.2.3-rc1",
            "1.2.3+build",
            " 1.2.3",
            "1.2.3 ",
            "256.0.0",
            "0.256.0",
            "0.0.65536",
            "0.0.99999999999",
            "a.b.c",
            "1.-2.3",
            "١.٢.٣",
        ] {
            assert_eq!(Version::parse(text), None, "{text:?}");
        }
    }

    #[test]
    fn bytes_are_little_endian() {
        let version = Version::new(1, 2, 0x0304);
        assert_eq!(version.to_bytes(), [1, 2, 0x04, 0x03]);
        assert_eq!(Version::from_bytes(version.to_bytes()), version);
        assert_eq!(version.to_string(), "1.2.772");
    }

    #[test]
    fn versions_order_as_releases() {
        assert!(Version::new(0, 9, 65535) < Version::new(1, 0, 0));
        assert!(Version::new(1, 1, 0) < Version::new(1, 1, 1));
    }
}
