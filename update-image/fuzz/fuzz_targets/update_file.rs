//! The update file's parsers and checks on arbitrary bytes: never panic, what parses writes back as read, and a
//! file `check_file` passes is one whose parts agree.
#![no_main]

use libfuzzer_sys::fuzz_target;
use update_image::{HEADER_LEN, Header, INFO_OFFSET, ImageInfo, Target, check, check_file};

fuzz_target!(|data: &[u8]| {
    if let Ok(header) = Header::parse(data) {
        assert_eq!(Header::parse(&header.to_bytes()), Ok(header));
        assert_eq!(Some(&header.to_bytes()[..]), data.get(..HEADER_LEN));
    }
    if let Ok(info) = ImageInfo::parse(data) {
        assert_eq!(ImageInfo::parse(&info.to_bytes()), Ok(info));
        assert_eq!(Some(&info.to_bytes()[..]), data.get(..info.to_bytes().len()));
    }
    // The partition size from the input too, so every length check is reached.
    let max = data.get(..4).map_or(0, |bytes| u32::from_le_bytes(bytes.try_into().unwrap_or_default()));
    for device in Target::ALL {
        for max in [max, 32 * 1024, u32::MAX] {
            match check_file(data, device, max) {
                Ok((header, info)) => {
                    assert_eq!(Header::parse(data), Ok(header));
                    let payload = &data[HEADER_LEN..];
                    assert_eq!(payload.len(), header.payload_len as usize);
                    assert_eq!(ImageInfo::parse(&payload[INFO_OFFSET..]), Ok(info));
                    assert_eq!(check(&header, &info, device, max), Ok(()));
                    assert_eq!(info.target, device);
                }
                Err(refusal) => assert!(!refusal.to_string().is_empty()),
            }
        }
    }
    // The header and the info at their places, checked as a device does before the payload is all in.
    if let (Ok(header), Ok(info)) = (
        Header::parse(data),
        ImageInfo::parse(data.get(HEADER_LEN + INFO_OFFSET..).unwrap_or_default()),
    ) {
        for device in Target::ALL {
            let _ = check(&header, &info, device, max);
        }
    }
});
