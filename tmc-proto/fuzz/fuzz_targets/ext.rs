//! The field-update extension's decoders on arbitrary bytes: never panic; a command that decodes re-encodes to
//! the same bytes, and no IDS order decoder takes it; a reply that decodes re-encodes to itself.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tmc_proto::ext::{CommandFrame, Reply, reply_len};
use tmc_proto::{Family, Order, checksum};

fuzz_target!(|data: &[u8]| {
    if let Ok(frame) = CommandFrame::decode(data) {
        let bytes = frame.encode();
        assert_eq!(bytes.as_bytes(), data);
        // The guard: read as an IDS order, its CSUM is off by 0x80.
        if let [b0, b1, b2, b3, ..] = *data {
            assert_eq!(checksum(&[b0, b1, b2]) ^ b3, 0x80);
        }
        for family in Family::ALL {
            assert!(Order::decode(family, data).is_err());
            assert!(Order::decode(family, data.get(..4).unwrap_or_default()).is_err());
        }
    }
    if let Ok(reply) = Reply::decode(data) {
        let bytes = reply.encode();
        assert_eq!(bytes.as_bytes().len(), reply_len(reply.command()));
        assert_eq!(Reply::decode(bytes.as_bytes()), Ok(reply));
        // Only the reply's own length was looked at.
        assert_eq!(Reply::decode(&data[..bytes.as_bytes().len()]), Ok(reply));
    }
});
