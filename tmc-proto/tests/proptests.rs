//! Property tests: roundtrips, robustness on arbitrary bytes, and corruption detection.

use proptest::prelude::*;
use tmc_proto::{
    DecodeError, Decoded, Family, Faults, LegacyRevision, LegacyStatus, MaxPower, MotorKind, Order, SeaBotixStatus,
    Speed, Status, StatusForm, checksum,
};

fn family() -> impl Strategy<Value = Family> {
    prop_oneof![Just(Family::SeaBotix), Just(Family::Legacy)]
}

fn speed() -> impl Strategy<Value = Speed> {
    (-Speed::MAX_STEP..=Speed::MAX_STEP).prop_filter_map("speed step", Speed::new)
}

fn faults() -> impl Strategy<Value = Faults> {
    (0u8..=0x1F).prop_map(Faults::from_bits_truncate)
}

fn motor() -> impl Strategy<Value = MotorKind> {
    prop_oneof![Just(MotorKind::Brushless), Just(MotorKind::Brushed)]
}

fn order() -> impl Strategy<Value = Order> {
    (speed(), any::<u8>()).prop_map(|(speed, info)| Order { speed, info })
}

fn seabotix_status() -> impl Strategy<Value = SeaBotixStatus> {
    (
        0u8..16,
        motor(),
        any::<bool>(),
        faults(),
        any::<u8>(),
        speed(),
        any::<u8>(),
    )
        .prop_map(
            |(revision, motor, current_limited, faults, current_deciamps, speed, temperature_c)| SeaBotixStatus {
                revision,
                motor,
                current_limited,
                faults,
                current_deciamps,
                speed,
                temperature_c,
            },
        )
}

/// A Legacy status whose MAX POWER variant matches its revision's motor kind.
fn legacy_status() -> impl Strategy<Value = LegacyStatus> {
    let revision = (0u8..8).prop_filter_map("3-bit revision", LegacyRevision::new);
    (revision, faults(), any::<u8>(), speed()).prop_map(|(revision, faults, byte, speed)| {
        let max_power = match revision.motor_kind() {
            Some(MotorKind::Brushless) => MaxPower::Current { deciamps: byte },
            Some(MotorKind::Brushed) => MaxPower::Power(speed),
            None => MaxPower::Raw(byte),
        };
        LegacyStatus {
            revision,
            faults,
            max_power,
        }
    })
}

fn status() -> impl Strategy<Value = Status> {
    prop_oneof![
        seabotix_status().prop_map(Status::SeaBotix),
        legacy_status().prop_map(Status::Legacy)
    ]
}

fn bytes() -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(any::<u8>(), 0..=16)
}

/// Flip one bit of a frame; every such flip changes the 8-bit sum, so the frame must be rejected.
fn flipped(frame: &[u8], bit: usize) -> Vec<u8> {
    let mut out = frame.to_vec();
    let index = (bit / 8) % out.len();
    if let Some(byte) = out.get_mut(index) {
        *byte ^= 1 << (bit % 8);
    }
    out
}

proptest! {
    #[test]
    fn order_roundtrip(family in family(), order in order()) {
        let bytes = order.encode(family);
        prop_assert_eq!(bytes[0], family.order_type());
        prop_assert_eq!(checksum(&bytes[..3]), bytes[3]);
        prop_assert_eq!(Order::decode(family, &bytes), Ok(order));
        prop_assert_eq!(Order::decode_any(&bytes), Ok((family, order)));
    }

    #[test]
    fn seabotix_status_roundtrip(status in seabotix_status()) {
        let bytes = status.encode();
        prop_assert_eq!(checksum(&bytes[..6]), bytes[6]);
        prop_assert_eq!(SeaBotixStatus::decode(&bytes), Ok(Decoded::clean(status)));
    }

    #[test]
    fn legacy_status_roundtrip(status in legacy_status()) {
        let bytes = status.encode();
        prop_assert_eq!(checksum(&bytes[..3]), bytes[3]);
        prop_assert_eq!(LegacyStatus::decode(&bytes), Ok(Decoded::clean(status)));
    }

    #[test]
    fn status_roundtrip(status in status()) {
        let frame = status.encode();
        prop_assert_eq!(frame.as_bytes().len(), status.family().status_len());
        prop_assert_eq!(Status::decode(status.family(), frame.as_bytes()), Ok(Decoded::clean(status)));
    }

    #[test]
    fn decoders_never_panic(bytes in bytes()) {
        for family in Family::ALL {
            if let Ok(order) = Order::decode(family, &bytes) {
                prop_assert_eq!(Order::decode(family, &order.encode(family)), Ok(order));
            }
            if let Ok(decoded) = Status::decode(family, &bytes) {
                let again = Status::decode(family, decoded.status.encode().as_bytes()).map(|d| d.status);
                prop_assert_eq!(again, Ok(decoded.status));
            }
            // Either form: the full layout whenever it decodes; else an implied-type frame (never one that starts
            // with the MT byte), which re-encodes in full to the same status; else the full layout's error.
            match Status::decode_either(family, &bytes) {
                Ok((decoded, StatusForm::Full)) => prop_assert_eq!(Status::decode(family, &bytes), Ok(decoded)),
                Ok((decoded, StatusForm::ImpliedType)) => {
                    prop_assert!(Status::decode(family, &bytes).is_err());
                    prop_assert_ne!(bytes.first().copied(), Some(family.status_type()));
                    let again = Status::decode(family, decoded.status.encode().as_bytes()).map(|d| d.status);
                    prop_assert_eq!(again, Ok(decoded.status));
                }
                Err(error) => prop_assert_eq!(Status::decode(family, &bytes).err(), Some(error)),
            }
        }
        if let Ok((family, order)) = Order::decode_any(&bytes) {
            prop_assert_eq!(Order::decode(family, &bytes), Ok(order));
        }
        if let Ok(decoded) = SeaBotixStatus::decode(&bytes) {
            // A zeroed odd speed re-encodes as a valid one.
            prop_assert_eq!(SeaBotixStatus::decode(&decoded.status.encode()), Ok(Decoded::clean(decoded.status)));
        }
        if let Ok(decoded) = LegacyStatus::decode(&bytes) {
            prop_assert_eq!(LegacyStatus::decode(&decoded.status.encode()), Ok(decoded));
        }
    }

    #[test]
    fn wrong_checksum_is_rejected(family in family(), speed in any::<u8>(), info in any::<u8>(), csum in any::<u8>()) {
        let mt = family.order_type();
        let sum = checksum(&[mt, speed, info]);
        prop_assume!(csum != sum);
        let bytes = [mt, speed, info, csum];
        prop_assert_eq!(Order::decode(family, &bytes), Err(DecodeError::Checksum { expected: sum, actual: csum }));
        prop_assert_eq!(Order::decode_any(&bytes), Err(DecodeError::Checksum { expected: sum, actual: csum }));
    }

    #[test]
    fn any_4_bytes_with_wrong_checksum_are_rejected(bytes in any::<[u8; 4]>()) {
        prop_assume!(checksum(&bytes[..3]) != bytes[3]);
        for family in Family::ALL {
            prop_assert!(Order::decode(family, &bytes).is_err());
        }
        prop_assert!(Order::decode_any(&bytes).is_err());
        prop_assert!(LegacyStatus::decode(&bytes).is_err());
    }

    #[test]
    fn single_bit_flip_in_order_is_rejected(family in family(), order in order(), bit in 0usize..32) {
        let bad = flipped(&order.encode(family), bit);
        prop_assert!(Order::decode(family, &bad).is_err());
        prop_assert!(Order::decode_any(&bad).is_err());
    }

    #[test]
    fn single_bit_flip_in_seabotix_status_is_rejected(status in seabotix_status(), bit in 0usize..56) {
        let bad = flipped(&status.encode(), bit);
        prop_assert!(SeaBotixStatus::decode(&bad).is_err());
    }

    #[test]
    fn single_bit_flip_in_legacy_status_is_rejected(status in legacy_status(), bit in 0usize..32) {
        let bad = flipped(&status.encode(), bit);
        prop_assert!(LegacyStatus::decode(&bad).is_err());
    }

    #[test]
    fn from_rpm_never_panics_and_stays_in_range(rpm in any::<i32>()) {
        let s = Speed::from_rpm(rpm);
        prop_assert!((-102..=102).contains(&s.step()));
        prop_assert_eq!(Speed::from_rpm(s.rpm()), s);
    }

    #[test]
    fn new_saturating_clamps(step in any::<i32>()) {
        let s = Speed::new_saturating(step);
        prop_assert_eq!(i32::from(s.step()), step.clamp(-102, 102));
    }
}
