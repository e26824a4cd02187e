//! Property tests of the field-update extension: round trips, robustness on arbitrary bytes, corruption detection,
//! and the guard that makes every extension frame a bad order to an IDS-only controller.

use proptest::prelude::*;
use tmc_proto::ext::{
    Chunk, Command, CommandFrame, CommandKind, Crc32, EXT_MT, FrameError, MAX_CHUNK, MAX_FRAME_LEN, Refusal, Reply,
    ReplyBody, SIGNATURE_LEN, crc32, reply_len,
};
use tmc_proto::{Family, Order, Speed, Status, checksum};

fn chunk() -> impl Strategy<Value = Chunk> {
    prop::collection::vec(any::<u8>(), 1..=MAX_CHUNK).prop_filter_map("1 to 64 bytes", |data| Chunk::new(&data))
}

fn signature() -> impl Strategy<Value = [u8; SIGNATURE_LEN]> {
    prop::collection::vec(any::<u8>(), SIGNATURE_LEN).prop_filter_map("64 bytes", |bytes| bytes.try_into().ok())
}

fn command() -> impl Strategy<Value = Command> {
    prop_oneof![
        Just(Command::Version),
        (any::<u32>(), any::<u8>()).prop_map(|(payload_len, target)| Command::Begin { payload_len, target }),
        any::<u16>().prop_map(|page| Command::Erase { page }),
        (any::<u32>(), chunk()).prop_map(|(offset, data)| Command::Write { offset, data }),
        (any::<u32>(), any::<u32>()).prop_map(|(offset, len)| Command::Check { offset, len }),
        (any::<u32>(), signature()).prop_map(|(payload_len, signature)| Command::Finish { payload_len, signature }),
        Just(Command::Reboot),
        any::<u8>().prop_map(|offset| Command::PostMortem { offset }),
    ]
}

fn frame() -> impl Strategy<Value = CommandFrame> {
    (any::<u8>(), command()).prop_map(|(seq, command)| CommandFrame { seq, command })
}

fn kind() -> impl Strategy<Value = CommandKind> {
    prop::sample::select(CommandKind::ALL.to_vec())
}

fn body() -> impl Strategy<Value = ReplyBody> {
    let info = prop::array::uniform32(any::<u8>());
    prop_oneof![
        (any::<u8>(), any::<[bool; 4]>(), 0u8..16, any::<u32>(), info).prop_map(
            |(protocol, [on_trial, checks_signatures, marked, dev_key], verdict, max_payload, info)| {
                ReplyBody::Version {
                    protocol,
                    on_trial,
                    checks_signatures,
                    marked,
                    dev_key,
                    verdict,
                    max_payload,
                    info,
                }
            }
        ),
        any::<u32>().prop_map(|payload_len| ReplyBody::Begin { payload_len }),
        any::<u16>().prop_map(|page| ReplyBody::Erase { page }),
        (any::<u32>(), any::<u8>(), any::<u32>()).prop_map(|(offset, len, crc)| ReplyBody::Write { offset, len, crc }),
        (any::<u32>(), any::<u32>(), any::<u32>()).prop_map(|(offset, len, crc)| ReplyBody::Check { offset, len, crc }),
        any::<u32>().prop_map(|payload_len| ReplyBody::Finish { payload_len }),
        Just(ReplyBody::Reboot),
        (
            any::<u8>(),
            any::<u8>(),
            prop::array::uniform32(any::<u8>()),
            prop::array::uniform32(any::<u8>())
        )
            .prop_map(|(len, offset, low, high)| {
                let mut data = [0; MAX_CHUNK];
                data[..32].copy_from_slice(&low);
                data[32..].copy_from_slice(&high);
                ReplyBody::PostMortem { len, offset, data }
            }),
    ]
}

fn reply() -> impl Strategy<Value = Reply> {
    prop_oneof![
        (any::<u8>(), body()).prop_map(|(seq, body)| Reply::Done { seq, body }),
        (any::<u8>(), kind()).prop_map(|(seq, command)| Reply::Busy { seq, command }),
        (any::<u8>(), kind(), prop::sample::select(Refusal::ALL.to_vec()))
            .prop_map(|(seq, command, refusal)| { Reply::Refused { seq, command, refusal } }),
    ]
}

fn bytes() -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(any::<u8>(), 0..=MAX_FRAME_LEN + 4)
}

proptest! {
    #[test]
    fn commands_round_trip(frame in frame()) {
        let bytes = frame.encode();
        prop_assert!(bytes.as_bytes().len() <= MAX_FRAME_LEN);
        prop_assert_eq!(CommandFrame::decode(bytes.as_bytes()), Ok(frame));
    }

    #[test]
    fn replies_round_trip_at_their_commands_length(reply in reply(), filler in prop::collection::vec(any::<u8>(), 0..8)) {
        let bytes = reply.encode();
        prop_assert_eq!(bytes.as_bytes().len(), reply_len(reply.command()));
        prop_assert_eq!(Reply::decode(bytes.as_bytes()), Ok(reply));
        // Whatever follows the reply (the slave's filler) is not looked at.
        let mut read = bytes.as_bytes().to_vec();
        read.extend(filler);
        prop_assert_eq!(Reply::decode(&read), Ok(reply));
    }

    /// The guard: the first four bytes of every extension frame, read as an IDS order (MT, SPEED, INFO, CSUM),
    /// carry a CSUM off by 0x80 from the sum of the three before it, so an IDS-only controller discards the frame
    /// (IDS 6.6.1) whether it reads four bytes or all of them, and whatever it makes of MT: one that sums its own
    /// order type in place of byte 0 gets it wrong too.
    #[test]
    fn no_extension_frame_checks_as_an_ids_order(frame in frame()) {
        let encoded = frame.encode();
        let bytes = encoded.as_bytes();
        let prefix = &bytes[..4];
        prop_assert_eq!(checksum(&prefix[..3]) ^ prefix[3], 0x80);
        for family in Family::ALL {
            prop_assert!(Order::decode(family, bytes).is_err());
            prop_assert!(Order::decode(family, prefix).is_err());
            prop_assert_ne!(checksum(&[family.order_type(), prefix[1], prefix[2]]), prefix[3]);
            // A controller that took the address byte as MT and bytes 0..3 as SPEED, INFO, CSUM: if the sequence
            // number happens to check, the order it reads is a stop.
            let implied = [family.order_type(), prefix[0], prefix[1], prefix[2]];
            if let Ok(order) = Order::decode(family, &implied) {
                prop_assert!(order.speed.is_zero());
            }
        }
        prop_assert!(Order::decode_any(bytes).is_err());
        prop_assert!(Order::decode_any(prefix).is_err());
    }

    /// And back: no IDS order is an extension command, and no status a reply.
    #[test]
    fn no_ids_message_decodes_as_the_extension(step in -102i8..=102, info in any::<u8>(), raw in bytes()) {
        for family in Family::ALL {
            let order = Order { speed: Speed::new(step).unwrap(), info }.encode(family);
            prop_assert!(CommandFrame::decode(&order).is_err());
            let status = Status::decode(family, &raw);
            if let Ok(status) = status {
                let mut read = status.status.encode().as_bytes().to_vec();
                read.resize(MAX_FRAME_LEN, 0xFF);
                let is_type_error = matches!(Reply::decode(&read), Err(FrameError::MessageType { .. }));
                prop_assert!(is_type_error);
            }
        }
    }

    #[test]
    fn decoders_never_panic(raw in bytes()) {
        let _ = CommandFrame::decode(&raw);
        let _ = Reply::decode(&raw);
    }

    /// Whatever decodes re-encodes to the same bytes (commands have no field the encoder could normalise).
    #[test]
    fn a_decoded_command_is_the_bytes_it_came_from(raw in bytes(), mt_and_guard in any::<bool>()) {
        let mut raw = raw;
        // Half the inputs get a right MT, GUARD and CRC, so that the later checks are reached.
        if mt_and_guard && raw.len() >= 8 {
            raw[0] = EXT_MT;
            raw[3] = tmc_proto::ext::guard(raw[0], raw[1], raw[2]);
            let end = raw.len() - 4;
            let crc = crc32(&raw[..end]).to_le_bytes();
            raw[end..].copy_from_slice(&crc);
        }
        if let Ok(frame) = CommandFrame::decode(&raw) {
            let encoded = frame.encode();
            prop_assert_eq!(encoded.as_bytes(), &raw[..]);
        }
    }

    #[test]
    fn any_one_bit_flip_is_rejected(frame in frame(), reply in reply(), bit in any::<prop::sample::Index>()) {
        let encoded = frame.encode();
        let mut bytes = encoded.as_bytes().to_vec();
        let at = bit.index(bytes.len() * 8);
        bytes[at / 8] ^= 1 << (at % 8);
        prop_assert!(CommandFrame::decode(&bytes).is_err());

        let encoded = reply.encode();
        let mut bytes = encoded.as_bytes().to_vec();
        let at = bit.index(bytes.len() * 8);
        bytes[at / 8] ^= 1 << (at % 8);
        // A flip in byte 1 may name another command, whose reply is longer than what was read, or shorter (then
        // the CRC is looked for elsewhere): either way, no reply.
        prop_assert!(Reply::decode(&bytes).is_err());
    }

    #[test]
    fn the_crc_matches_an_independent_one_in_any_pieces(data in prop::collection::vec(any::<u8>(), 0..300), cut in any::<prop::sample::Index>()) {
        prop_assert_eq!(crc32(&data), crc32fast::hash(&data));
        let (head, tail) = data.split_at(cut.index(data.len() + 1));
        prop_assert_eq!(Crc32::new().update(head).update(tail).finish(), crc32(&data));
    }
}
