//! Property tests: the parsers and `check` answer arbitrary bytes without panicking, what is written reads back,
//! and a file passes `check_file` exactly when its parts are consistent.

use proptest::prelude::*;
use update_image::{
    HEADER_LEN, Header, INFO_LEN, INFO_OFFSET, ImageInfo, Refusal, Target, Version, WRITE_UNIT, check, check_file,
    key_from_hex,
};

fn target() -> impl Strategy<Value = Target> {
    prop_oneof![
        Just(Target::ThrusterSeabotix),
        Just(Target::ThrusterLegacy),
        Just(Target::Master)
    ]
}

fn version() -> impl Strategy<Value = Version> {
    (any::<u8>(), any::<u8>(), any::<u16>()).prop_map(|(major, minor, patch)| Version::new(major, minor, patch))
}

fn info() -> impl Strategy<Value = ImageInfo> {
    (target(), version(), any::<u32>(), any::<bool>()).prop_map(|(target, version, counter, rollback)| {
        ImageInfo::new(target, version)
            .with_security_counter(counter)
            .with_rollback(rollback)
    })
}

fn header() -> impl Strategy<Value = Header> {
    (target(), any::<u32>(), version(), prop::array::uniform32(any::<u8>())).prop_map(
        |(target, payload_len, version, half)| {
            let mut signature = [0; 64];
            signature[..32].copy_from_slice(&half);
            signature[32..].copy_from_slice(&half);
            Header {
                target,
                payload_len,
                version,
                signature,
            }
        },
    )
}

proptest! {
    #[test]
    fn parsers_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..200)) {
        let _ = Header::parse(&bytes);
        let _ = ImageInfo::parse(&bytes);
        let _ = key_from_hex(&String::from_utf8_lossy(&bytes));
        for target in Target::ALL {
            for max in [0, 1024, u32::MAX] {
                let _ = check_file(&bytes, target, max);
            }
        }
    }

    #[test]
    fn check_never_panics(header in header(), info in info(), device in target(), max in any::<u32>()) {
        let _ = check(&header, &info, device, max);
    }

    #[test]
    fn headers_round_trip(header in header()) {
        prop_assert_eq!(Header::parse(&header.to_bytes()), Ok(header));
    }

    #[test]
    fn infos_round_trip(info in info()) {
        prop_assert_eq!(ImageInfo::parse(&info.to_bytes()), Ok(info));
    }

    #[test]
    fn versions_round_trip(version in version()) {
        prop_assert_eq!(Version::from_bytes(version.to_bytes()), version);
        prop_assert_eq!(Version::parse(&version.to_string()), Some(version));
    }

    /// Any single byte changed in a header's fixed fields is refused or read as the change.
    #[test]
    fn a_changed_header_byte_is_seen(header in header(), at in 0usize..16, value in any::<u8>()) {
        let mut bytes = header.to_bytes();
        bytes[at] = value;
        if let Ok(read) = Header::parse(&bytes) {
            prop_assert_eq!(read.to_bytes(), bytes);
        }
    }

    /// A consistent file passes; the same file with its header's target, version or length changed does not.
    #[test]
    fn consistent_files_pass_and_altered_ones_do_not(
        info in info(),
        units in (update_image::MIN_PAYLOAD as usize / WRITE_UNIT)..600,
        fill in any::<u8>(),
        other in info(),
    ) {
        let len = units * WRITE_UNIT;
        let mut payload = vec![fill; len];
        payload[INFO_OFFSET..INFO_OFFSET + INFO_LEN].copy_from_slice(&info.to_bytes());
        let header = Header {
            target: info.target,
            payload_len: len as u32,
            version: info.version,
            signature: [0; 64],
        };
        let file = [&header.to_bytes()[..], &payload].concat();
        prop_assert_eq!(check_file(&file, info.target, len as u32), Ok((header, info)));
        prop_assert_eq!(
            check_file(&file, info.target, len as u32 - 8),
            Err(Refusal::TooLarge { len: len as u32, max: len as u32 - 8 })
        );
        let altered = Header { target: other.target, version: other.version, ..header };
        let file_altered = [&altered.to_bytes()[..], &payload].concat();
        let answer = check_file(&file_altered, info.target, u32::MAX);
        prop_assert_eq!(answer.is_ok(), other == info);
        prop_assert_eq!(
            check_file(&file[..HEADER_LEN + len - 1], info.target, u32::MAX),
            Err(Refusal::Truncated { announced: len as u32, held: len - 1 })
        );
    }
}
