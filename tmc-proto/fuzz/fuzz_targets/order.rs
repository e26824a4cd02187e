//! Order decoders on arbitrary bytes: never panic, and whatever decodes re-encodes to the same order.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tmc_proto::{Family, Order, checksum};

fuzz_target!(|data: &[u8]| {
    for family in Family::ALL {
        if let Ok(order) = Order::decode(family, data) {
            let bytes = order.encode(family);
            assert_eq!(Order::decode(family, &bytes), Ok(order));
            // Same bytes, but zero speed is always sent as 0x80 and the checksum follows.
            let [mt, speed, info, _] = bytes;
            assert_eq!(Some(&mt), data.first());
            assert_eq!(Some(&info), data.get(2));
            let expected_speed = match data.get(1) {
                Some(0x7F) => 0x80,
                other => other.copied().unwrap_or_default(),
            };
            assert_eq!(speed, expected_speed);
            assert_eq!(bytes[3], checksum(&bytes[..3]));
        }
    }
    match Order::decode_any(data) {
        Ok((family, order)) => {
            assert_eq!(Order::decode(family, data), Ok(order));
            assert_eq!(Order::decode_any(&order.encode(family)), Ok((family, order)));
        }
        Err(e) => {
            for family in Family::ALL {
                assert!(Order::decode(family, data).is_err(), "{e:?} but {family:?} decodes");
            }
        }
    }
});
