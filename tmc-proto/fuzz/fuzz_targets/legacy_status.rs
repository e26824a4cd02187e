//! Legacy status decoder on arbitrary bytes: never panics, and whatever decodes re-encodes to the same status.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tmc_proto::{Family, LegacyStatus, MaxPower, Status, checksum};

fuzz_target!(|data: &[u8]| {
    let decoded = LegacyStatus::decode(data);
    assert_eq!(Status::decode(Family::Legacy, data), decoded.map(|d| d.map(Status::Legacy)));
    if let Ok(decoded) = decoded {
        let status = decoded.status;
        let bytes = status.encode();
        // An odd brushed MAX POWER is kept raw, so it comes back with the same warning.
        assert_eq!(LegacyStatus::decode(&bytes), Ok(decoded));
        assert_eq!(Status::Legacy(status).encode().as_bytes(), bytes);
        // Same bytes up to the normalisations: a brushed MAX POWER of zero speed is sent as 0x80, checksum
        // recomputed. The Legacy STATUS byte has no reserved bits.
        let input: [u8; 4] = data.try_into().expect("decoded, so 4 bytes");
        let mut expected = input;
        if matches!(status.max_power, MaxPower::Power(_)) && expected[2] == 0x7F {
            expected[2] = 0x80;
        }
        expected[3] = checksum(&expected[..3]);
        assert_eq!(bytes, expected);
    }
});
