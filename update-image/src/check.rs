//! Whether an update file may go into a device's DFU partition, before its signature can be checked.

use core::cmp::Ordering;
use core::fmt;

use crate::bootloader::MIN_PAYLOAD;
use crate::{
    HEADER_LEN, Header, HeaderError, INFO_FORMAT, INFO_OFFSET, ImageInfo, InfoError, Target, Version, WRITE_UNIT,
};

/// Why an update is refused, each with a one-line reason for a person (its `Display`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Refusal {
    /// The header does not parse.
    Header(HeaderError),
    /// The payload's image info does not parse: an image built without one, or not an image.
    Info(InfoError),
    /// The file ends before the payload the header announces.
    Truncated {
        /// Payload bytes the header announces.
        announced: u32,
        /// Payload bytes there are.
        held: usize,
    },
    /// The file goes on after the payload the header announces.
    Trailing {
        /// Payload bytes the header announces.
        announced: u32,
        /// Payload bytes there are.
        held: usize,
    },
    /// The header announces no payload.
    Empty,
    /// The payload is not a whole number of flash write units, so it could not be programmed as it is.
    Unaligned {
        /// Payload length.
        len: u32,
    },
    /// The payload is larger than the partition it would go into (embassy-boot's `verify_and_mark_updated`
    /// asserts that it is not, so it must be refused before).
    TooLarge {
        /// Payload length.
        len: u32,
        /// The largest payload the device takes: its ACTIVE partition's size.
        max: u32,
    },
    /// The payload ends before the image info and the key it must hold.
    TooShort {
        /// Payload length.
        len: u32,
    },
    /// The header's target is not the payload's.
    TargetMismatch {
        /// The header's.
        header: Target,
        /// The payload's image info's.
        payload: Target,
    },
    /// The header's version is not the payload's.
    VersionMismatch {
        /// The header's.
        header: Version,
        /// The payload's image info's.
        payload: Version,
    },
    /// The image is built for another target than the device's.
    WrongTarget {
        /// The image's.
        image: Target,
        /// The device's own.
        device: Target,
    },
    /// The payload's image info is of format 1: it carries no update key, so the vehicle could check no update
    /// after it.
    NoKey,
    /// The image is older than the one that runs, and was not signed as a rollback (`--allow-rollback`).
    Older {
        /// The image's.
        image: Version,
        /// The one that runs.
        running: Version,
    },
    /// The image's security counter is below the one the device holds to.
    CounterBelow {
        /// The image's.
        image: u32,
        /// The device's.
        floor: u32,
    },
}

/// Checks the header of an update against the payload's image info (read from the payload at
/// [`INFO_OFFSET`]), the device's own target and the largest payload it takes (its ACTIVE partition's size), in
/// this order: the payload's length (not empty, whole write units, not over `max_payload`, long enough to hold
/// its info), then the header against the info (target, version), then the target against the device's.
///
/// A receiver can call it as soon as it holds the header and the first `INFO_OFFSET + INFO_LEN` payload bytes;
/// what it cannot tell is whether the payload is genuine, which only the signature says, once it is all in.
pub fn check(header: &Header, info: &ImageInfo, device: Target, max_payload: u32) -> Result<(), Refusal> {
    check_length(header, max_payload)?;
    check_info(header, info, device)
}

/// Whether `image` may replace the image that runs (`running`, when its info reads): no older version unless
/// signed as a rollback, and a security counter at least `floor` (the bootloader's stored counter; an
/// application that does not read it holds to the running image's own). Equal versions and counters are taken:
/// the same image may be installed again.
pub fn check_upgrade(image: &ImageInfo, running: Option<&ImageInfo>, floor: u32) -> Result<(), Refusal> {
    if let Some(running) = running
        && image.version < running.version
        && !image.rollback
    {
        return Err(Refusal::Older {
            image: image.version,
            running: running.version,
        });
    }
    if image.security_counter < floor {
        return Err(Refusal::CounterBelow {
            image: image.security_counter,
            floor,
        });
    }
    Ok(())
}

/// Checks a whole update file held in memory: its header parses, its length is the header's, its payload holds an
/// image info, and [`check`] passes. Gives the header and the info.
pub fn check_file(file: &[u8], device: Target, max_payload: u32) -> Result<(Header, ImageInfo), Refusal> {
    let header = Header::parse(file).map_err(Refusal::Header)?;
    let payload = file.get(HEADER_LEN..).unwrap_or_default();
    let announced = header.payload_len;
    let held = payload.len();
    match (held as u64).cmp(&u64::from(announced)) {
        Ordering::Less => return Err(Refusal::Truncated { announced, held }),
        Ordering::Greater => return Err(Refusal::Trailing { announced, held }),
        Ordering::Equal => {}
    }
    check_length(&header, max_payload)?;
    let info = ImageInfo::parse(payload.get(INFO_OFFSET..).unwrap_or_default()).map_err(Refusal::Info)?;
    check_info(&header, &info, device)?;
    Ok((header, info))
}

/// The header's payload length.
fn check_length(header: &Header, max_payload: u32) -> Result<(), Refusal> {
    let len = header.payload_len;
    if len == 0 {
        return Err(Refusal::Empty);
    }
    if !(len as usize).is_multiple_of(WRITE_UNIT) {
        return Err(Refusal::Unaligned { len });
    }
    if len > max_payload {
        return Err(Refusal::TooLarge { len, max: max_payload });
    }
    if len < MIN_PAYLOAD {
        return Err(Refusal::TooShort { len });
    }
    Ok(())
}

/// The header against the payload's info, the info against the device.
fn check_info(header: &Header, info: &ImageInfo, device: Target) -> Result<(), Refusal> {
    if header.target != info.target {
        return Err(Refusal::TargetMismatch {
            header: header.target,
            payload: info.target,
        });
    }
    if header.version != info.version {
        return Err(Refusal::VersionMismatch {
            header: header.version,
            payload: info.version,
        });
    }
    if info.target != device {
        return Err(Refusal::WrongTarget {
            image: info.target,
            device,
        });
    }
    if info.format < INFO_FORMAT {
        return Err(Refusal::NoKey);
    }
    Ok(())
}

/// "the SeaBotix family (0x52/0x53)", "the master": what an image is for.
fn for_whom(target: Target) -> &'static str {
    match target {
        Target::ThrusterSeabotix => "the SeaBotix family (0x52/0x53)",
        Target::ThrusterLegacy => "the Aveox/Legacy family (0x54/0x55)",
        Target::Master => "the master",
    }
}

/// "this thruster is SeaBotix (0x52/0x53)", "this is the master": what the device is.
fn this_is(target: Target) -> &'static str {
    match target {
        Target::ThrusterSeabotix => "this thruster is SeaBotix (0x52/0x53)",
        Target::ThrusterLegacy => "this thruster is Aveox/Legacy (0x54/0x55)",
        Target::Master => "this is the master",
    }
}

impl fmt::Display for Refusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Refusal::Header(error) => write!(f, "{error}"),
            Refusal::Info(error) => write!(f, "payload offset {INFO_OFFSET:#x}: {error}"),
            Refusal::Truncated { announced, held } => write!(
                f,
                "truncated: the header announces a payload of {announced} bytes, the file holds {held}"
            ),
            Refusal::Trailing { announced, held } => write!(
                f,
                "trailing bytes: the header announces a payload of {announced} bytes, the file holds {held}"
            ),
            Refusal::Empty => f.write_str("empty: the header announces no payload"),
            Refusal::Unaligned { len } => write!(
                f,
                "a payload of {len} bytes is not a whole number of {WRITE_UNIT}-byte flash double words"
            ),
            Refusal::TooLarge { len, max } => {
                write!(f, "too large: a payload of {len} bytes, the partition holds {max}")
            }
            Refusal::TooShort { len } => write!(
                f,
                "a payload of {len} bytes ends before its image info and key ({INFO_OFFSET:#x}..{MIN_PAYLOAD:#x})"
            ),
            Refusal::TargetMismatch { header, payload } => write!(
                f,
                "the header is for {}, the payload for {}",
                for_whom(header),
                for_whom(payload)
            ),
            Refusal::VersionMismatch { header, payload } => {
                write!(f, "the header says version {header}, the payload is version {payload}")
            }
            Refusal::WrongTarget { image, device } => {
                write!(f, "signed for {}, {}", for_whom(image), this_is(device))
            }
            Refusal::NoKey => {
                f.write_str("an image of info format 1 names no update key: nothing after it could be checked")
            }
            Refusal::Older { image, running } => {
                write!(f, "{image} is older than the {running} that runs (not a rollback)")
            }
            Refusal::CounterBelow { image, floor } => {
                write!(f, "security counter {image} is below the vehicle's {floor}")
            }
        }
    }
}

impl core::error::Error for Refusal {}

#[cfg(test)]
mod tests {
    use super::*;

    const VERSION: Version = Version::new(1, 2, 3);
    const MAX: u32 = 32 * 1024;

    fn header(target: Target, payload_len: u32) -> Header {
        Header {
            target,
            payload_len,
            version: VERSION,
            signature: [0x5A; 64],
        }
    }

    /// An update file with a payload of `len` bytes holding the image info of `info`.
    fn file(header: &Header, info: &ImageInfo, len: usize) -> Vec<u8> {
        let mut payload = vec![0xFF; len];
        if let Some(slot) = payload.get_mut(INFO_OFFSET..INFO_OFFSET + crate::INFO_LEN) {
            slot.copy_from_slice(&info.to_bytes());
        }
        let mut file = header.to_bytes().to_vec();
        file.extend_from_slice(&payload);
        file
    }

    #[test]
    fn a_good_update_passes() {
        for target in Target::ALL {
            let header = header(target, 1024);
            let info = ImageInfo::new(target, VERSION);
            assert_eq!(check(&header, &info, target, MAX), Ok(()));
            assert_eq!(check_file(&file(&header, &info, 1024), target, MAX), Ok((header, info)));
        }
        // At the limits: exactly the key's end, exactly the partition.
        let info = ImageInfo::new(Target::Master, VERSION);
        assert_eq!(
            check(&header(Target::Master, 0x240), &info, Target::Master, MAX),
            Ok(())
        );
        assert_eq!(check(&header(Target::Master, MAX), &info, Target::Master, MAX), Ok(()));
    }

    #[test]
    fn every_refusal() {
        let seabotix = ImageInfo::new(Target::ThrusterSeabotix, VERSION);
        let device = Target::ThrusterSeabotix;
        let refuse = |header: Header, info: ImageInfo| check(&header, &info, device, MAX).err();
        let at = |len| header(device, len);
        assert_eq!(refuse(at(0), seabotix), Some(Refusal::Empty));
        assert_eq!(refuse(at(1028), seabotix), Some(Refusal::Unaligned { len: 1028 }));
        assert_eq!(
            refuse(at(u32::MAX), seabotix),
            Some(Refusal::Unaligned { len: u32::MAX })
        );
        assert_eq!(
            refuse(at(MAX + 8), seabotix),
            Some(Refusal::TooLarge { len: MAX + 8, max: MAX })
        );
        assert_eq!(refuse(at(0x238), seabotix), Some(Refusal::TooShort { len: 0x238 }));
        let format_1 = ImageInfo { format: 1, ..seabotix };
        assert_eq!(refuse(at(1024), format_1), Some(Refusal::NoKey));
        assert_eq!(
            refuse(header(Target::ThrusterLegacy, 1024), seabotix),
            Some(Refusal::TargetMismatch {
                header: Target::ThrusterLegacy,
                payload: device
            })
        );
        let newer = ImageInfo::new(device, Version::new(1, 2, 4));
        assert_eq!(
            refuse(at(1024), newer),
            Some(Refusal::VersionMismatch {
                header: VERSION,
                payload: newer.version
            })
        );
        let legacy = ImageInfo::new(Target::ThrusterLegacy, VERSION);
        assert_eq!(
            refuse(header(Target::ThrusterLegacy, 1024), legacy),
            Some(Refusal::WrongTarget {
                image: Target::ThrusterLegacy,
                device
            })
        );
    }

    #[test]
    fn every_file_refusal() {
        let device = Target::Master;
        let info = ImageInfo::new(device, VERSION);
        let good = file(&header(device, 1024), &info, 1024);
        assert_eq!(
            check_file(&good[..79], device, MAX),
            Err(Refusal::Header(HeaderError::Short { len: 79 }))
        );
        assert_eq!(
            check_file(&good[..80 + 1000], device, MAX),
            Err(Refusal::Truncated {
                announced: 1024,
                held: 1000
            })
        );
        let mut longer = good.clone();
        longer.push(0xFF);
        assert_eq!(
            check_file(&longer, device, MAX),
            Err(Refusal::Trailing {
                announced: 1024,
                held: 1025
            })
        );
        let mut no_info = good.clone();
        no_info[80 + INFO_OFFSET] = 0;
        assert_eq!(
            check_file(&no_info, device, MAX),
            Err(Refusal::Info(InfoError::Magic([0, b'B', b'V', b'I'])))
        );
        // A payload too short for its info is said so, not as a short info.
        let short = file(&header(device, 0x100), &info, 0x100);
        assert_eq!(check_file(&short, device, MAX), Err(Refusal::TooShort { len: 0x100 }));
        assert_eq!(
            check_file(&good, Target::ThrusterLegacy, MAX),
            Err(Refusal::WrongTarget {
                image: device,
                device: Target::ThrusterLegacy
            })
        );
        assert_eq!(
            check_file(&good, device, 512),
            Err(Refusal::TooLarge { len: 1024, max: 512 })
        );
    }

    #[test]
    fn reasons_are_one_line_of_english() {
        let wrong = Refusal::WrongTarget {
            image: Target::ThrusterLegacy,
            device: Target::ThrusterSeabotix,
        };
        assert_eq!(
            wrong.to_string(),
            "signed for the Aveox/Legacy family (0x54/0x55), this thruster is SeaBotix (0x52/0x53)"
        );
        let to_master = Refusal::WrongTarget {
            image: Target::ThrusterSeabotix,
            device: Target::Master,
        };
        assert_eq!(
            to_master.to_string(),
            "signed for the SeaBotix family (0x52/0x53), this is the master"
        );
        assert_eq!(
            Refusal::Truncated {
                announced: 1024,
                held: 1000
            }
            .to_string(),
            "truncated: the header announces a payload of 1024 bytes, the file holds 1000"
        );
        assert_eq!(
            Refusal::Trailing {
                announced: 1024,
                held: 1025
            }
            .to_string(),
            "trailing bytes: the header announces a payload of 1024 bytes, the file holds 1025"
        );
        assert_eq!(
            Refusal::Info(InfoError::Magic([0xFF; 4])).to_string(),
            "payload offset 0x200: no image info: ff ff ff ff where \"LBVI\" goes"
        );
        assert_eq!(
            Refusal::TooShort { len: 16 }.to_string(),
            "a payload of 16 bytes ends before its image info and key (0x200..0x240)"
        );
        assert_eq!(
            Refusal::Older {
                image: Version::new(0, 1, 0),
                running: Version::new(0, 3, 0)
            }
            .to_string(),
            "0.1.0 is older than the 0.3.0 that runs (not a rollback)"
        );
        assert_eq!(
            Refusal::CounterBelow { image: 2, floor: 3 }.to_string(),
            "security counter 2 is below the vehicle's 3"
        );
        assert_eq!(
            Refusal::TargetMismatch {
                header: Target::Master,
                payload: Target::ThrusterLegacy
            }
            .to_string(),
            "the header is for the master, the payload for the Aveox/Legacy family (0x54/0x55)"
        );
        let all = [
            Refusal::Header(HeaderError::Format(2)),
            Refusal::Empty,
            Refusal::Unaligned { len: 9 },
            Refusal::TooLarge { len: 16, max: 8 },
            Refusal::VersionMismatch {
                header: VERSION,
                payload: VERSION,
            },
            wrong,
            Refusal::NoKey,
        ];
        for refusal in all {
            let text = refusal.to_string();
            assert!(!text.is_empty() && !text.contains('\n'), "{text:?}");
        }
    }

    #[test]
    fn no_older_image_unless_signed_to_go_back_and_no_counter_below_the_floor() {
        let running = ImageInfo::new(Target::Master, Version::new(0, 3, 0)).with_security_counter(2);
        let at = |major, minor, patch, counter| {
            ImageInfo::new(Target::Master, Version::new(major, minor, patch)).with_security_counter(counter)
        };
        // Newer, the same, and no running info to compare with: taken.
        assert_eq!(check_upgrade(&at(0, 3, 1, 2), Some(&running), 2), Ok(()));
        assert_eq!(check_upgrade(&at(0, 3, 0, 2), Some(&running), 2), Ok(()));
        assert_eq!(check_upgrade(&at(0, 1, 0, 2), None, 2), Ok(()));
        // Older: refused, unless signed as a rollback, which is still held to the counter.
        assert_eq!(
            check_upgrade(&at(0, 2, 9, 2), Some(&running), 2),
            Err(Refusal::Older {
                image: Version::new(0, 2, 9),
                running: running.version
            })
        );
        assert_eq!(
            check_upgrade(&at(0, 1, 0, 2).with_rollback(true), Some(&running), 2),
            Ok(())
        );
        assert_eq!(
            check_upgrade(&at(0, 1, 0, 1).with_rollback(true), Some(&running), 2),
            Err(Refusal::CounterBelow { image: 1, floor: 2 })
        );
        // The counter: equal taken, below refused, whatever the version.
        assert_eq!(check_upgrade(&at(1, 0, 0, 3), Some(&running), 3), Ok(()));
        assert_eq!(
            check_upgrade(&at(1, 0, 0, 2), Some(&running), 3),
            Err(Refusal::CounterBelow { image: 2, floor: 3 })
        );
    }
}
