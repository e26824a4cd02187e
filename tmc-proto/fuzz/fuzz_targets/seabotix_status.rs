//! SeaBotix status decoder on arbitrary bytes: never panics, and whatever decodes re-encodes to the same status.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tmc_proto::{Decoded, Family, SeaBotixStatus, Status, StatusForm, checksum};

fuzz_target!(|data: &[u8]| {
    let decoded = SeaBotixStatus::decode(data);
    assert_eq!(Status::decode(Family::SeaBotix, data), decoded.map(|d| d.map(Status::SeaBotix)));
    // Either form: the full layout whenever it decodes; an implied-type frame only when it does not.
    match Status::decode_either(Family::SeaBotix, data) {
        Ok((either, StatusForm::Full)) => assert_eq!(decoded.map(|d| d.map(Status::SeaBotix)), Ok(either)),
        Ok((_, StatusForm::ImpliedType)) => assert!(decoded.is_err() && data.first() != Some(&0x53)),
        Err(error) => assert_eq!(decoded.err(), Some(error)),
    }
    if let Ok(decoded) = decoded {
        let status = decoded.status;
        let bytes = status.encode();
        assert_eq!(SeaBotixStatus::decode(&bytes), Ok(Decoded::clean(status)));
        assert_eq!(Status::SeaBotix(status).encode().as_bytes(), bytes);
        // Same bytes up to the normalisations: reserved STATUS bits 2-3 and FAULT bits 5-7 zeroed, zero speed as
        // 0x80 (an out-of-range one too), checksum recomputed.
        let input: [u8; 7] = data.try_into().expect("decoded, so 7 bytes");
        let mut expected = input;
        expected[1] &= 0xF3;
        expected[2] &= 0x1F;
        // Zero speed as 0x80, and an out-of-range speed byte read as zero.
        if expected[4] == 0x7F || decoded.warning.is_some() {
            expected[4] = 0x80;
        }
        expected[6] = checksum(&expected[..6]);
        assert_eq!(bytes, expected);
    }
});
