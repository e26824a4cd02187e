//! Byte vectors worked out by hand from the IDS (sections 6.4.2, 8.3, 8.4). Checksums are computed in the comments.

use tmc_proto::{
    DecodeError, Decoded, Family, Faults, FieldWarning, LegacyRevision, LegacyStatus, MaxPower, MotorKind, ORDER_LEN,
    Order, SeaBotixStatus, Speed, Status, checksum,
};

/// Speed of a step; the steps used here are all within -102..=102.
fn speed(step: i8) -> Speed {
    Speed::new_saturating(i32::from(step))
}

// ---- Addresses (IDS 6.4.2) ----

#[test]
fn addresses_are_7_bit_and_mt_bytes_are_the_8_bit_address_bytes() {
    assert_eq!(Family::SeaBotix.address(), 0x29);
    assert_eq!(Family::Legacy.address(), 0x2A);
    assert_eq!(Family::SeaBotix.order_type(), 0x52);
    assert_eq!(Family::SeaBotix.status_type(), 0x53);
    assert_eq!(Family::Legacy.order_type(), 0x54);
    assert_eq!(Family::Legacy.status_type(), 0x55);
    for family in Family::ALL {
        // address << 1 | R/W, with write = 0 and read = 1
        assert_eq!(family.address() << 1, family.order_type());
        assert_eq!((family.address() << 1) | 1, family.status_type());
        assert_eq!(Family::from_address(family.address()), Some(family));
    }
    assert_eq!(Family::from_address(0x52), None);
    assert_eq!(Family::from_address(0x00), None);
    assert_eq!(Family::SeaBotix.status_len(), 7);
    assert_eq!(Family::Legacy.status_len(), 4);
    assert_eq!(Family::SeaBotix.status_len(), SeaBotixStatus::LEN);
    assert_eq!(Family::Legacy.status_len(), LegacyStatus::LEN);
    assert_eq!(ORDER_LEN, 4);
}

// ---- SPEED byte (IDS 8.3) ----

#[test]
fn zero_speed_bytes_0x7f_and_0x80_decode_to_zero_and_zero_encodes_as_0x80() {
    assert_eq!(Speed::from_byte(0x7F), Ok(Speed::ZERO));
    assert_eq!(Speed::from_byte(0x80), Ok(Speed::ZERO));
    assert_eq!(Speed::ZERO.to_byte(), 0x80);
    assert_eq!(u8::from(Speed::ZERO), 0x80);
    assert_eq!(Speed::ZERO.rpm(), 0);
}

#[test]
fn byte_0xe6_is_max_forward_4500_rpm() {
    let s = Speed::from_byte(0xE6).unwrap();
    assert_eq!(s, Speed::MAX_FORWARD);
    assert_eq!(s.step(), 102);
    assert_eq!(s.rpm(), 4500);
    assert_eq!(Speed::MAX_FORWARD.to_byte(), 0xE6);
}

#[test]
fn byte_0x19_is_max_reverse_minus_4500_rpm() {
    let s = Speed::from_byte(0x19).unwrap();
    assert_eq!(s, Speed::MAX_REVERSE);
    assert_eq!(s.step(), -102);
    assert_eq!(s.rpm(), -4500);
    assert_eq!(Speed::MAX_REVERSE.to_byte(), 0x19);
}

#[test]
fn byte_0x81_is_plus_one_and_0x7e_minus_one() {
    assert_eq!(Speed::from_byte(0x81).map(Speed::step), Ok(1));
    assert_eq!(Speed::from_byte(0x7E).map(Speed::step), Ok(-1));
    assert_eq!(speed(1).to_byte(), 0x81);
    assert_eq!(speed(-1).to_byte(), 0x7E);
    assert_eq!(Speed::try_from(0x81_u8), Ok(speed(1)));
}

#[test]
fn bytes_outside_0x19_to_0xe6_are_out_of_range() {
    for byte in [0x18, 0xE7, 0x00, 0xFF] {
        assert_eq!(Speed::from_byte(byte), Err(DecodeError::SpeedOutOfRange(byte)));
        assert_eq!(Speed::try_from(byte), Err(DecodeError::SpeedOutOfRange(byte)));
    }
}

// ---- Orders (IDS 8.3) ----

#[test]
fn seabotix_order_plus_5_info_100() {
    // SPEED +5 = 0x80 + 5 = 0x85, INFO 100 = 0x64.
    // CSUM = 0x52 + 0x85 + 0x64 = 0x13B -> 0x3B.
    let order = Order {
        speed: speed(5),
        info: 100,
    };
    assert_eq!(Order::new(speed(5)), order);
    let bytes = [0x52, 0x85, 0x64, 0x3B];
    assert_eq!(order.encode(Family::SeaBotix), bytes);
    assert_eq!(Order::decode(Family::SeaBotix, &bytes), Ok(order));
    assert_eq!(Order::decode_any(&bytes), Ok((Family::SeaBotix, order)));
    assert_eq!(order.power_cap_percent(), Some(100));
}

#[test]
fn legacy_order_minus_10_info_50() {
    // SPEED -10 = 0x7F - 10 = 0x75, INFO 50 = 0x32.
    // CSUM = 0x54 + 0x75 + 0x32 = 0xFB.
    let order = Order {
        speed: speed(-10),
        info: 50,
    };
    let bytes = [0x54, 0x75, 0x32, 0xFB];
    assert_eq!(order.encode(Family::Legacy), bytes);
    assert_eq!(Order::decode(Family::Legacy, &bytes), Ok(order));
    assert_eq!(Order::decode_any(&bytes), Ok((Family::Legacy, order)));
    assert_eq!(order.power_cap_percent(), Some(50));
}

#[test]
fn stop_order_uses_0x80_and_0x7f_is_accepted_as_zero() {
    // 0x54 + 0x80 + 0x64 = 0x138 -> 0x38
    assert_eq!(Order::STOP.encode(Family::Legacy), [0x54, 0x80, 0x64, 0x38]);
    // 0x54 + 0x7F + 0x64 = 0x137 -> 0x37
    assert_eq!(
        Order::decode(Family::Legacy, &[0x54, 0x7F, 0x64, 0x37]),
        Ok(Order::STOP)
    );
}

#[test]
fn info_takes_any_value() {
    // INFO 0: 0x52 + 0xE6 + 0x00 = 0x138 -> 0x38; no cap.
    let order = Order::decode(Family::SeaBotix, &[0x52, 0xE6, 0x00, 0x38]).unwrap();
    assert_eq!(
        order,
        Order {
            speed: Speed::MAX_FORWARD,
            info: 0
        }
    );
    assert_eq!(order.power_cap_percent(), None);
    // INFO 0xFF: 0x52 + 0x19 + 0xFF = 0x16A -> 0x6A; no cap.
    let order = Order::decode(Family::SeaBotix, &[0x52, 0x19, 0xFF, 0x6A]).unwrap();
    assert_eq!(
        order,
        Order {
            speed: Speed::MAX_REVERSE,
            info: 0xFF
        }
    );
    assert_eq!(order.power_cap_percent(), None);
}

#[test]
fn bad_checksum_is_rejected_with_computed_and_received_values() {
    assert_eq!(
        Order::decode(Family::SeaBotix, &[0x52, 0x85, 0x64, 0x3C]),
        Err(DecodeError::Checksum {
            expected: 0x3B,
            actual: 0x3C
        })
    );
    assert_eq!(
        Order::decode_any(&[0x52, 0x85, 0x64, 0x00]),
        Err(DecodeError::Checksum {
            expected: 0x3B,
            actual: 0
        })
    );
}

#[test]
fn legacy_order_sent_to_seabotix_decoder_is_wrong_message_type() {
    let bytes = [0x54, 0x75, 0x32, 0xFB];
    assert_eq!(
        Order::decode(Family::SeaBotix, &bytes),
        Err(DecodeError::MessageType {
            expected: 0x52,
            actual: 0x54
        })
    );
    assert_eq!(
        Order::decode(Family::Legacy, &[0x52, 0x85, 0x64, 0x3B]),
        Err(DecodeError::MessageType {
            expected: 0x54,
            actual: 0x52
        })
    );
}

#[test]
fn unknown_message_type_in_decode_any_reports_0x52_expected() {
    // A SeaBotix status MT is not an order type.
    assert_eq!(
        Order::decode_any(&[0x53, 0x85, 0x64, 0x3C]),
        Err(DecodeError::MessageType {
            expected: 0x52,
            actual: 0x53
        })
    );
}

#[test]
fn wrong_order_lengths_are_rejected() {
    assert_eq!(
        Order::decode(Family::SeaBotix, &[0x52, 0x85, 0x64]),
        Err(DecodeError::Length { expected: 4, actual: 3 })
    );
    assert_eq!(
        Order::decode(Family::SeaBotix, &[0x52, 0x85, 0x64, 0x3B, 0x00]),
        Err(DecodeError::Length { expected: 4, actual: 5 })
    );
    assert_eq!(
        Order::decode_any(&[]),
        Err(DecodeError::Length { expected: 4, actual: 0 })
    );
    assert_eq!(
        Order::decode_any(&[0x54, 0x75, 0x32, 0xFB, 0xFB]),
        Err(DecodeError::Length { expected: 4, actual: 5 })
    );
}

#[test]
fn order_with_good_checksum_but_out_of_range_speed() {
    // 0x52 + 0x18 + 0x64 = 0xCE; the checksum passes, the speed does not.
    assert_eq!(
        Order::decode(Family::SeaBotix, &[0x52, 0x18, 0x64, 0xCE]),
        Err(DecodeError::SpeedOutOfRange(0x18))
    );
    // 0x54 + 0xE7 + 0x64 = 0x19F -> 0x9F
    assert_eq!(
        Order::decode_any(&[0x54, 0xE7, 0x64, 0x9F]),
        Err(DecodeError::SpeedOutOfRange(0xE7))
    );
}

#[test]
fn checks_come_in_order_length_type_checksum_range() {
    // Wrong type, wrong checksum and out-of-range speed at once: the type is reported.
    assert_eq!(
        Order::decode(Family::SeaBotix, &[0x00, 0x00, 0x00, 0x01]),
        Err(DecodeError::MessageType {
            expected: 0x52,
            actual: 0x00
        })
    );
    // Wrong checksum and out-of-range speed: the checksum is reported.
    assert_eq!(
        Order::decode(Family::SeaBotix, &[0x52, 0x00, 0x00, 0x00]),
        Err(DecodeError::Checksum {
            expected: 0x52,
            actual: 0x00
        })
    );
}

// ---- Legacy status (IDS 8.4.1) ----

/// Revision 1 (Aveox brushless), MAX POWER 12 (1.2 A): base sum 0x55 + 0x20 + 0x0C = 0x81.
const LEGACY_FAULT_VECTORS: [(Faults, [u8; 4]); 6] = [
    (Faults::OVERTEMP, [0x55, 0x21, 0x0C, 0x82]), // STATUS bit 0
    (Faults::STALL, [0x55, 0x22, 0x0C, 0x83]),    // STATUS bit 1
    (Faults::HALL, [0x55, 0x24, 0x0C, 0x85]),     // STATUS bit 2
    (Faults::GROUND, [0x55, 0x28, 0x0C, 0x89]),   // STATUS bit 3
    (Faults::WATER, [0x55, 0x30, 0x0C, 0x91]),    // STATUS bit 4
    (Faults::ALL, [0x55, 0x3F, 0x0C, 0xA0]),      // 0x81 + 0x1F = 0xA0
];

#[test]
fn legacy_status_each_fault_bit_alone_and_all() {
    for (faults, bytes) in LEGACY_FAULT_VECTORS {
        let status = LegacyStatus {
            revision: LegacyRevision::AVEOX_BRUSHLESS,
            faults,
            max_power: MaxPower::Current { deciamps: 12 },
        };
        assert_eq!(status.encode(), bytes, "{faults:?}");
        assert_eq!(LegacyStatus::decode(&bytes), Ok(Decoded::clean(status)), "{faults:?}");
        assert_eq!(
            Status::decode(Family::Legacy, &bytes),
            Ok(Decoded::clean(Status::Legacy(status)))
        );
        assert_eq!(Status::Legacy(status).faults(), faults);
    }
}

#[test]
fn legacy_revision_0_original_keeps_max_power_raw() {
    // 0x55 + 0x00 + 0x40 = 0x95
    let status = LegacyStatus::decode(&[0x55, 0x00, 0x40, 0x95]).unwrap().status;
    assert_eq!(status.revision, LegacyRevision::ORIGINAL);
    assert_eq!(status.revision.number(), 0);
    assert_eq!(status.revision.motor_kind(), None);
    assert_eq!(status.faults, Faults::NONE);
    assert_eq!(status.max_power, MaxPower::Raw(0x40));
}

#[test]
fn legacy_revision_1_brushless_max_power_is_current_12_is_1_2_amps() {
    // 0x55 + 0x20 + 0x0C = 0x81
    let status = LegacyStatus::decode(&[0x55, 0x20, 0x0C, 0x81]).unwrap().status;
    assert_eq!(status.revision, LegacyRevision::AVEOX_BRUSHLESS);
    assert_eq!(status.revision.number(), 1);
    assert_eq!(status.revision.motor_kind(), Some(MotorKind::Brushless));
    assert_eq!(status.max_power, MaxPower::Current { deciamps: 12 });
    // Brushless: any byte is a current, even one outside the speed range.
    // 0x55 + 0x20 + 0xFF = 0x174 -> 0x74
    assert_eq!(
        LegacyStatus::decode(&[0x55, 0x20, 0xFF, 0x74]).map(|d| d.status.max_power),
        Ok(MaxPower::Current { deciamps: 0xFF })
    );
}

#[test]
fn legacy_revision_2_brushed_max_power_is_speed() {
    // MAX POWER 0xA0 = +32; 0x55 + 0x40 + 0xA0 = 0x135 -> 0x35
    let status = LegacyStatus::decode(&[0x55, 0x40, 0xA0, 0x35]).unwrap().status;
    assert_eq!(status.revision, LegacyRevision::LEGACY_BRUSHED);
    assert_eq!(status.revision.number(), 2);
    assert_eq!(status.revision.motor_kind(), Some(MotorKind::Brushed));
    assert_eq!(status.max_power, MaxPower::Power(speed(32)));
}

#[test]
fn legacy_revision_4_brushed_max_power_is_speed() {
    // MAX POWER 0x60 = -(0x7F - 0x60) = -31; 0x55 + 0x80 + 0x60 = 0x135 -> 0x35
    let status = LegacyStatus::decode(&[0x55, 0x80, 0x60, 0x35]).unwrap().status;
    assert_eq!(status.revision, LegacyRevision::BRUSHED_REV4);
    assert_eq!(status.revision.number(), 4);
    assert_eq!(status.revision.motor_kind(), Some(MotorKind::Brushed));
    assert_eq!(status.max_power, MaxPower::Power(speed(-31)));
    assert_eq!(status.faults, Faults::NONE);
}

#[test]
fn legacy_brushed_max_power_out_of_speed_range_keeps_the_faults() {
    // 0x55 + 0x40 + 0x10 = 0xA5: revision 2, no fault, MAX POWER 0x10.
    assert_eq!(
        LegacyStatus::decode(&[0x55, 0x40, 0x10, 0xA5]),
        Ok(Decoded {
            status: LegacyStatus {
                revision: LegacyRevision::LEGACY_BRUSHED,
                faults: Faults::NONE,
                max_power: MaxPower::Raw(0x10),
            },
            warning: Some(FieldWarning::MaxPower(0x10)),
        })
    );
    // Revision 2 with WATER and MAX POWER 0x00: the water warning is not lost with the odd byte.
    // 0x55 + 0x50 + 0x00 = 0xA5
    let decoded = LegacyStatus::decode(&[0x55, 0x50, 0x00, 0xA5]).unwrap();
    assert_eq!(decoded.status.faults, Faults::WATER);
    assert_eq!(decoded.status.max_power, MaxPower::Raw(0x00));
    assert_eq!(decoded.warning, Some(FieldWarning::MaxPower(0x00)));
    assert_eq!(
        decoded.warning.map(|w| w.to_string()),
        Some("max power byte 0x00 out of range 0x19..=0xe6".to_string())
    );
    assert_eq!(
        Status::decode(Family::Legacy, &[0x55, 0x50, 0x00, 0xA5]).map(|d| d.status.faults()),
        Ok(Faults::WATER)
    );
    // Re-encoded, the raw byte goes out as it came.
    assert_eq!(decoded.status.encode(), [0x55, 0x50, 0x00, 0xA5]);
}

#[test]
fn legacy_undefined_revision_3_keeps_max_power_raw() {
    // STATUS 0x60 = revision 3; 0x55 + 0x60 + 0xFF = 0x1B4 -> 0xB4
    let status = LegacyStatus::decode(&[0x55, 0x60, 0xFF, 0xB4]).unwrap().status;
    assert_eq!(status.revision.number(), 3);
    assert_eq!(status.revision.motor_kind(), None);
    assert_eq!(status.max_power, MaxPower::Raw(0xFF));
}

#[test]
fn legacy_status_encode_writes_mismatched_max_power_as_is() {
    // Revision 2 (brushed) carrying a current: the byte is written, decode reads it as a speed.
    let status = LegacyStatus {
        revision: LegacyRevision::LEGACY_BRUSHED,
        faults: Faults::NONE,
        max_power: MaxPower::Current { deciamps: 0x85 },
    };
    // 0x55 + 0x40 + 0x85 = 0x11A -> 0x1A
    let bytes = status.encode();
    assert_eq!(bytes, [0x55, 0x40, 0x85, 0x1A]);
    assert_eq!(
        LegacyStatus::decode(&bytes).map(|d| d.status.max_power),
        Ok(MaxPower::Power(speed(5)))
    );
}

#[test]
fn legacy_status_errors() {
    assert_eq!(
        LegacyStatus::decode(&[0x55, 0x20, 0x0C]),
        Err(DecodeError::Length { expected: 4, actual: 3 })
    );
    assert_eq!(
        LegacyStatus::decode(&[0x53, 0x20, 0x0C, 0x7F]),
        Err(DecodeError::MessageType {
            expected: 0x55,
            actual: 0x53
        })
    );
    assert_eq!(
        LegacyStatus::decode(&[0x55, 0x20, 0x0C, 0x80]),
        Err(DecodeError::Checksum {
            expected: 0x81,
            actual: 0x80
        })
    );
}

// ---- SeaBotix status (IDS 8.4.2) ----

/// STATUS 0x02 (revision 0, brushless, current-limited), CURRENT 12, SPEED +5 (0x85), TEMPERATURE 25 (0x19):
/// base sum 0x53 + 0x02 + 0x0C + 0x85 + 0x19 = 0xFF; the FAULT byte adds to it, carry dropped.
const SEABOTIX_FAULT_VECTORS: [(Faults, [u8; 7]); 6] = [
    (Faults::OVERTEMP, [0x53, 0x02, 0x01, 0x0C, 0x85, 0x19, 0x00]), // FAULT bit 0
    (Faults::STALL, [0x53, 0x02, 0x02, 0x0C, 0x85, 0x19, 0x01]),    // FAULT bit 1
    (Faults::HALL, [0x53, 0x02, 0x04, 0x0C, 0x85, 0x19, 0x03]),     // FAULT bit 2
    (Faults::GROUND, [0x53, 0x02, 0x08, 0x0C, 0x85, 0x19, 0x07]),   // FAULT bit 3
    (Faults::WATER, [0x53, 0x02, 0x10, 0x0C, 0x85, 0x19, 0x0F]),    // FAULT bit 4
    (Faults::ALL, [0x53, 0x02, 0x1F, 0x0C, 0x85, 0x19, 0x1E]),      // 0xFF + 0x1F = 0x11E -> 0x1E
];

#[test]
fn seabotix_status_each_fault_bit_alone_and_all() {
    for (faults, bytes) in SEABOTIX_FAULT_VECTORS {
        let status = SeaBotixStatus {
            revision: 0,
            motor: MotorKind::Brushless,
            current_limited: true,
            faults,
            current_deciamps: 12,
            speed: speed(5),
            temperature_c: 25,
        };
        assert_eq!(status.encode(), bytes, "{faults:?}");
        assert_eq!(SeaBotixStatus::decode(&bytes), Ok(Decoded::clean(status)), "{faults:?}");
        assert_eq!(
            Status::decode(Family::SeaBotix, &bytes),
            Ok(Decoded::clean(Status::SeaBotix(status)))
        );
        assert_eq!(Status::SeaBotix(status).faults(), faults);
        assert_eq!(Status::SeaBotix(status).encode().as_bytes(), bytes);
    }
}

#[test]
fn seabotix_status_bit_1_motor_kind_and_bit_0_current_limiting() {
    // FAULT 0, CURRENT 0, SPEED 0x80, TEMPERATURE 20 (0x14): base sum 0x53 + 0x80 + 0x14 = 0xE7, plus STATUS.
    let cases = [
        (0x00, MotorKind::Brushed, true, 0xE7),
        (0x01, MotorKind::Brushed, false, 0xE8),
        (0x02, MotorKind::Brushless, true, 0xE9),
        (0x03, MotorKind::Brushless, false, 0xEA),
    ];
    for (status_byte, motor, current_limited, csum) in cases {
        let bytes = [0x53, status_byte, 0x00, 0x00, 0x80, 0x14, csum];
        let status = SeaBotixStatus::decode(&bytes).unwrap().status;
        assert_eq!(status.motor, motor, "STATUS {status_byte:#04x}");
        assert_eq!(status.current_limited, current_limited, "STATUS {status_byte:#04x}");
        assert_eq!(status.revision, 0);
        assert_eq!(status.speed, Speed::ZERO);
        assert_eq!(status.temperature_c, 20);
        assert_eq!(status.encode(), bytes);
    }
}

#[test]
fn seabotix_status_revision_is_bits_4_to_7() {
    // STATUS 0xF3: revision 15, brushless, not current-limited. 0xE7 + 0xF3 = 0x1DA -> 0xDA
    let bytes = [0x53, 0xF3, 0x00, 0x00, 0x80, 0x14, 0xDA];
    let status = SeaBotixStatus::decode(&bytes).unwrap().status;
    assert_eq!(status.revision, 15);
    assert_eq!(status.motor, MotorKind::Brushless);
    assert!(!status.current_limited);
    assert_eq!(status.encode(), bytes);
    // Encode keeps only 4 bits of the revision.
    let wide = SeaBotixStatus {
        revision: 0x1F,
        ..status
    };
    assert_eq!(wide.encode(), bytes);
}

#[test]
fn seabotix_reserved_bits_are_masked_not_rejected() {
    // STATUS 0x0E (bits 2-3 reserved set, bit 1 brushless), FAULT 0xE0 (bits 5-7 reserved set).
    // 0x53 + 0x0E + 0xE0 + 0x00 + 0x80 + 0x14 = 0x1D5 -> 0xD5
    let status = SeaBotixStatus::decode(&[0x53, 0x0E, 0xE0, 0x00, 0x80, 0x14, 0xD5])
        .unwrap()
        .status;
    assert_eq!(
        status,
        SeaBotixStatus {
            revision: 0,
            motor: MotorKind::Brushless,
            current_limited: true,
            faults: Faults::NONE,
            current_deciamps: 0,
            speed: Speed::ZERO,
            temperature_c: 20,
        }
    );
    // Re-encoded with the reserved bits zero: 0xE7 + 0x02 = 0xE9.
    assert_eq!(status.encode(), [0x53, 0x02, 0x00, 0x00, 0x80, 0x14, 0xE9]);

    // FAULT 0xE3: reserved bits plus overtemp and stall. 0xE9 + 0xE3 = 0x1CC -> 0xCC
    let status = SeaBotixStatus::decode(&[0x53, 0x02, 0xE3, 0x00, 0x80, 0x14, 0xCC])
        .unwrap()
        .status;
    assert_eq!(status.faults, Faults::OVERTEMP | Faults::STALL);
}

#[test]
fn seabotix_speed_out_of_range_keeps_the_faults() {
    // SPEED 0xFF: 0x53 + 0x02 + 0xFF + 0x14 = 0x168 -> 0x68
    let decoded = SeaBotixStatus::decode(&[0x53, 0x02, 0x00, 0x00, 0xFF, 0x14, 0x68]).unwrap();
    assert_eq!(decoded.warning, Some(FieldWarning::Speed(0xFF)));
    assert_eq!(decoded.status.speed, Speed::ZERO);
    assert_eq!(decoded.status.temperature_c, 20);
    // With GROUND and WATER set and SPEED 0x05 (a brushed PWM value): 0x53 + 0x02 + 0x18 + 0x05 + 0x14 = 0x86.
    let decoded = SeaBotixStatus::decode(&[0x53, 0x02, 0x18, 0x00, 0x05, 0x14, 0x86]).unwrap();
    assert_eq!(decoded.status.faults, Faults::GROUND | Faults::WATER);
    assert_eq!(decoded.warning, Some(FieldWarning::Speed(0x05)));
    assert_eq!(
        decoded.warning.map(|w| w.to_string()),
        Some("speed byte 0x05 out of range 0x19..=0xe6".to_string())
    );
}

#[test]
fn seabotix_status_errors() {
    // The 0x57 of IDS 8.4.2 is a typo for 0x53.
    assert_eq!(
        SeaBotixStatus::decode(&[0x57, 0x02, 0x00, 0x00, 0x80, 0x14, 0xED]),
        Err(DecodeError::MessageType {
            expected: 0x53,
            actual: 0x57
        })
    );
    assert_eq!(
        SeaBotixStatus::decode(&[0x53, 0x02, 0x00, 0x00, 0x80, 0x14, 0xEA]),
        Err(DecodeError::Checksum {
            expected: 0xE9,
            actual: 0xEA
        })
    );
    // A 6-byte read, as one public master implementation does, is too short.
    assert_eq!(
        SeaBotixStatus::decode(&[0x53, 0x02, 0x00, 0x00, 0x80, 0x14]),
        Err(DecodeError::Length { expected: 7, actual: 6 })
    );
    // A Legacy status to the SeaBotix decoder fails on length first.
    assert_eq!(
        Status::decode(Family::SeaBotix, &[0x55, 0x20, 0x0C, 0x81]),
        Err(DecodeError::Length { expected: 7, actual: 4 })
    );
}

#[test]
fn status_family_and_frames() {
    let legacy = Status::Legacy(LegacyStatus {
        revision: LegacyRevision::BRUSHED_REV4,
        faults: Faults::WATER,
        max_power: MaxPower::Power(Speed::MAX_FORWARD),
    });
    assert_eq!(legacy.family(), Family::Legacy);
    // 0x55 + 0x90 + 0xE6 = 0x1CB -> 0xCB
    assert_eq!(legacy.encode().as_bytes(), [0x55, 0x90, 0xE6, 0xCB]);
    assert_eq!(checksum(&[0x55, 0x90, 0xE6]), 0xCB);
    let seabotix = Status::decode(Family::SeaBotix, &SEABOTIX_FAULT_VECTORS[0].1)
        .unwrap()
        .status;
    assert_eq!(seabotix.family(), Family::SeaBotix);
    assert_eq!(seabotix.faults(), Faults::OVERTEMP);
}
