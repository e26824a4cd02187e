//! A post-mortem record read from any bytes (what `lbv decode crash` and the master's FTP reader get), and any
//! region's start after any reset: nothing panics; a record decoded encodes back to its bytes; what a start finds
//! is what the region then holds.
#![no_main]

use crash_record::{Image, LEN, RING_LEN, Record, Region, ResetCause};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(record) = Record::decode(data) {
        assert_eq!(&record.encode()[..], data);
        let _ = record.events().len();
    }
    if data.len() >= LEN + RING_LEN + 4 {
        let mut region = Region::new();
        region.record.copy_from_slice(&data[..LEN]);
        region.ring.copy_from_slice(&data[LEN..LEN + RING_LEN]);
        let cause = u32::from_le_bytes(data[LEN + RING_LEN..LEN + RING_LEN + 4].try_into().unwrap());
        let found = region.start(ResetCause(cause), Image { target: 1, version: [0, 0, 1, 0] });
        assert_eq!(found, region.read());
    }
});
