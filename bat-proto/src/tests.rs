//! Vectors from the seed, docs/interface.md and docs/decisions.md, plus property tests.

use proptest::prelude::*;

use crate::*;

// ---- 0x620 battery info -------------------------------------------------------------------------------------

#[test]
fn voltage_0x01a4_is_42_0_volts_little_endian() {
    let info = BatteryInfo::decode(&[0xA4, 0x01, 0, 0, 0, 0, 0, 0]).unwrap();
    assert_eq!(info.voltage_decivolts, 0x01A4);
    assert_eq!(info.voltage_decivolts, 420); // 42.0 V
    assert_eq!(info.charge_percent, Some(0));
    assert_eq!(info.current_deciamps, None);
    assert_eq!(info.temperature_decicelsius, None);

    let encoded = BatteryInfo {
        voltage_decivolts: 420,
        charge_percent: Some(0),
        current_deciamps: None,
        temperature_decicelsius: None,
    }
    .encode();
    assert_eq!(encoded, [0xA4, 0x01, 0, 0, 0, 0, 0, 0]);
}

#[test]
fn charge_is_byte_4() {
    let info = BatteryInfo::decode(&[0xA4, 0x01, 0, 0, 87, 0, 0, 0]).unwrap();
    assert_eq!(info.charge_percent, Some(87));
    assert_eq!(info.voltage_decivolts, 420);

    let bytes = BatteryInfo {
        voltage_decivolts: 0,
        charge_percent: Some(100),
        current_deciamps: None,
        temperature_decicelsius: None,
    }
    .encode();
    assert_eq!(bytes, [0, 0, 0, 0, 100, 0, 0, 0]);
}

#[test]
fn charge_bounds_and_each_field_on_its_own() {
    assert_eq!(
        BatteryInfo::decode(&[0, 0, 0, 0, 100, 0, 0, 0]).unwrap().charge_percent,
        Some(100)
    );
    // A charge above 100 % is unknown; the voltage, current and temperature of the same frame stand.
    for charge in [101, 0xFF] {
        let info = BatteryInfo::decode(&[0xA4, 0x01, 0x7D, 0, charge, 0, 0xD7, 0]).unwrap();
        assert_eq!(info.charge_percent, None);
        assert_eq!(
            (
                info.voltage_decivolts,
                info.current_deciamps,
                info.temperature_decicelsius
            ),
            (420, Some(125), Some(215))
        );
        assert_eq!(
            BatteryInfo::charge_out_of_range(&[0, 0, 0, 0, charge, 0, 0, 0]),
            Some(charge)
        );
    }
    assert_eq!(BatteryInfo::charge_out_of_range(&[0, 0, 0, 0, 100, 0, 0, 0]), None);
    assert_eq!(
        BatteryInfo::charge_out_of_range(&[0, 0, 0, 0, 200, 0, 0]),
        None,
        "another length"
    );
    assert!(matches!(
        Frame::decode(INFO_ID, &[0, 0, 0, 0, 101, 0, 0, 0]),
        Ok(Frame::Info(BatteryInfo {
            charge_percent: None,
            ..
        }))
    ));
    // Unknown encodes as 0xFF, which reads back unknown.
    let unknown = BatteryInfo {
        charge_percent: None,
        ..BatteryInfo::default()
    };
    assert_eq!(BatteryInfo::decode(&unknown.encode()).unwrap(), unknown);
}

#[test]
fn current_and_temperature_present() {
    // 12.5 A = 125 = 0x007D; 25.3 degC = 253 = 0x00FD.
    let data = [0xA4, 0x01, 0x7D, 0x00, 55, 0, 0xFD, 0x00];
    let info = BatteryInfo::decode(&data).unwrap();
    assert_eq!(
        info,
        BatteryInfo {
            voltage_decivolts: 420,
            charge_percent: Some(55),
            current_deciamps: Some(125),
            temperature_decicelsius: Some(253),
        }
    );
    assert_eq!(info.encode(), data);
}

#[test]
fn negative_current_is_charging_and_negative_temperature() {
    // -3.2 A = -32 = 0xFFE0; -5.0 degC = -50 = 0xFFCE.
    let data = [0x10, 0x01, 0xE0, 0xFF, 30, 0, 0xCE, 0xFF];
    let info = BatteryInfo::decode(&data).unwrap();
    assert_eq!(info.voltage_decivolts, 0x0110);
    assert_eq!(info.current_deciamps, Some(-32));
    assert_eq!(info.temperature_decicelsius, Some(-50));
    assert_eq!(info.encode(), data);

    let extremes = [0, 0, 0x00, 0x80, 0, 0, 0xFF, 0x7F];
    let info = BatteryInfo::decode(&extremes).unwrap();
    assert_eq!(info.current_deciamps, Some(i16::MIN));
    assert_eq!(info.temperature_decicelsius, Some(i16::MAX));
}

#[test]
fn zero_current_and_temperature_read_as_not_reported() {
    let info = BatteryInfo::decode(&[0xA4, 0x01, 0, 0, 50, 0, 0, 0]).unwrap();
    assert_eq!(info.current_deciamps, None);
    assert_eq!(info.temperature_decicelsius, None);

    // Only one of the two present.
    let info = BatteryInfo::decode(&[0xA4, 0x01, 0, 0, 50, 0, 0x2C, 0x01]).unwrap();
    assert_eq!(info.current_deciamps, None);
    assert_eq!(info.temperature_decicelsius, Some(300));

    // Some(0) writes 0 and so reads back as None (documented).
    let zero = BatteryInfo {
        voltage_decivolts: 420,
        charge_percent: Some(50),
        current_deciamps: Some(0),
        temperature_decicelsius: Some(0),
    };
    assert_eq!(zero.encode(), [0xA4, 0x01, 0, 0, 50, 0, 0, 0]);
    let back = BatteryInfo::decode(&zero.encode()).unwrap();
    assert_eq!(back.current_deciamps, None);
    assert_eq!(back.temperature_decicelsius, None);
}

#[test]
fn info_byte_5_ignored_and_sent_as_zero() {
    let info = BatteryInfo::decode(&[0xA4, 0x01, 0, 0, 50, 0xEE, 0, 0]).unwrap();
    assert_eq!(info, BatteryInfo::decode(&[0xA4, 0x01, 0, 0, 50, 0, 0, 0]).unwrap());
    assert_eq!(info.encode()[5], 0);
}

// ---- 0x629 DCDC status --------------------------------------------------------------------------------------

#[test]
fn seed_example_172() {
    assert_eq!(172, 0b1010_1100);
    let status = DcdcStatus::from_word(172);
    let set: Vec<StatusBit> = status.set_bits().collect();
    assert_eq!(
        set,
        [
            StatusBit::HsmPowerGood,
            StatusBit::Hsm,
            StatusBit::V12Motor,
            StatusBit::V12Board
        ]
    );
    let names: Vec<&str> = status.set_bits().map(StatusBit::name).collect();
    assert_eq!(names, ["HSM_PG", "HSM", "V12motor", "V12board"]);
    assert_eq!(status.a(), 0xAC);
    assert_eq!(status.b(), 0x00);
    assert_eq!(status.word(), 172);
    assert!(!status.has_fault());
    assert_eq!(status.encode(), [0xAC, 0x00, 0, 0, 0, 0, 0, 0]);
    assert_eq!(DcdcStatus::decode(&[0xAC, 0x00, 0, 0, 0, 0, 0, 0]), Ok(status));
    assert_eq!(DcdcStatus::from_bytes(0xAC, 0x00), status);
}

#[test]
fn combined_word_is_b_shifted_8_or_a() {
    let status = DcdcStatus::from_bytes(0x00, 0x0C);
    assert_eq!(status.word(), 0x0C00);
    let set: Vec<StatusBit> = status.set_bits().collect();
    assert_eq!(set, [StatusBit::HsmHwFault, StatusBit::HsmSwFault]);
    assert_eq!(set.iter().map(|b| b.bit()).collect::<Vec<_>>(), [10, 11]);
    assert_eq!(
        set.iter().map(|b| b.name()).collect::<Vec<_>>(),
        ["HSM_HW_F", "HSM_SW_F"]
    );
    // Only B bits set: still a fault, named, not "no faults".
    assert!(status.has_fault());

    let both = DcdcStatus::decode(&[0xAC, 0x03, 0, 0, 0, 0, 0, 0]).unwrap();
    assert_eq!(both.word(), 0x03AC);
    assert_eq!(both.a(), 0xAC);
    assert_eq!(both.b(), 0x03);
    assert!(both.is_set(StatusBit::Pb2Restart));
    assert!(both.is_set(StatusBit::Pb1Restart));
    assert!(both.is_set(StatusBit::HsmPowerGood));
    assert!(!both.has_fault());
}

#[test]
fn status_byte_order_is_a_then_b() {
    // Byte 0 is A (bits 0-7), byte 1 is B (bits 8-11): the seed's "DCDC status A" label on byte 1 is an erratum.
    let status = DcdcStatus::decode(&[0x01, 0x02, 0, 0, 0, 0, 0, 0]).unwrap();
    assert!(status.is_set(StatusBit::HsmBroken));
    assert!(status.is_set(StatusBit::Pb1Restart));
    assert_eq!(status.word(), 0x0201);
}

/// (bit, name, set meaning, clear meaning, is_fault), condensed from the status word's table in docs/interface.md.
const TABLE: [(u8, &str, &str, &str, bool); 12] = [
    (
        0,
        "HSM_broken",
        "hot swap manager MOSFETs probably damaged",
        "normal",
        true,
    ),
    (
        1,
        "HSM_F",
        "hot swap manager overcurrent / overvoltage fault",
        "normal",
        true,
    ),
    (
        2,
        "HSM_PG",
        "hot swap manager power good (output stable)",
        "output voltage not guaranteed",
        false,
    ),
    (3, "HSM", "hot swap manager on", "off", false),
    (4, "V12motor_F", "12 V motor regulator overcurrent", "normal", true),
    (5, "V12motor", "12 V motor regulator on", "off", false),
    (6, "V12board_F", "12 V board regulator overcurrent", "normal", true),
    (7, "V12board", "12 V board regulator on", "off", false),
    (
        8,
        "PB2_restart",
        "push button 2 in start-up phase",
        "stable operation",
        false,
    ),
    (
        9,
        "PB1_restart",
        "push button 1 in start-up phase",
        "stable operation",
        false,
    ),
    (
        10,
        "HSM_HW_F",
        "HSM overcurrent fault from the HSM's FLT pin",
        "no fault",
        true,
    ),
    (
        11,
        "HSM_SW_F",
        "HSM overcurrent fault from the firmware threshold",
        "no fault",
        true,
    ),
];

#[test]
fn each_status_bit_alone() {
    for (bit, (pos, name, when_set, when_clear, fault)) in StatusBit::ALL.into_iter().zip(TABLE) {
        assert_eq!(bit.bit(), pos, "{name}");
        assert_eq!(bit.mask(), 1u16 << pos, "{name}");
        assert_eq!(bit.name(), name);
        assert_eq!(bit.meaning(true), when_set, "{name}");
        assert_eq!(bit.meaning(false), when_clear, "{name}");
        assert_eq!(bit.is_fault(), fault, "{name}");

        let alone = DcdcStatus::from_word(1 << pos);
        assert_eq!(alone.set_bits().collect::<Vec<_>>(), [bit]);
        assert_eq!(alone.has_fault(), fault, "{name}");
        assert_eq!(DcdcStatus::default().with(bit, true), alone);
        assert_eq!(alone.with(bit, false), DcdcStatus::default());

        // Bits 0-7 land in byte 0 (A), bits 8-11 in byte 1 (B).
        let bytes = alone.encode();
        if pos < 8 {
            assert_eq!(bytes, [1 << pos, 0, 0, 0, 0, 0, 0, 0], "{name}");
            assert_eq!((alone.a(), alone.b()), (1 << pos, 0));
        } else {
            assert_eq!(bytes, [0, 1 << (pos - 8), 0, 0, 0, 0, 0, 0], "{name}");
            assert_eq!((alone.a(), alone.b()), (0, 1 << (pos - 8)));
        }
        assert_eq!(DcdcStatus::decode(&bytes), Ok(alone));
    }
}

#[test]
fn unused_status_bits_12_to_15_masked() {
    assert_eq!(DcdcStatus::from_word(0xF000).word(), 0);
    assert_eq!(DcdcStatus::from_word(0xF0AC).word(), 0x00AC);
    assert_eq!(DcdcStatus::from_word(0xFFFF).word(), 0x0FFF);
    assert_eq!(DcdcStatus::from_bytes(0x00, 0xF0).word(), 0);
    let status = DcdcStatus::decode(&[0xAC, 0xFC, 0, 0, 0, 0, 0, 0]).unwrap();
    assert_eq!(status.word(), 0x0CAC);
    assert_eq!(status.b(), 0x0C);
    assert_eq!(status.encode(), [0xAC, 0x0C, 0, 0, 0, 0, 0, 0]);
    // Bytes 2-7 ignored.
    assert_eq!(DcdcStatus::decode(&[0xAC, 0, 1, 2, 3, 4, 5, 6]).unwrap().word(), 0xAC);
}

#[test]
fn describe_all_reports_every_bit_in_order() {
    let reports: Vec<BitReport> = DcdcStatus::from_word(172).describe_all().collect();
    assert_eq!(reports.len(), 12);
    let expected_set = [
        false, false, true, true, false, true, false, true, false, false, false, false,
    ];
    for ((report, bit), set) in reports.iter().zip(StatusBit::ALL).zip(expected_set) {
        assert_eq!(*report, BitReport { bit, set });
    }
    let text: Vec<String> = reports.iter().map(ToString::to_string).collect();
    assert_eq!(text[0], "HSM_broken=0 (normal)");
    assert_eq!(text[2], "HSM_PG=1 (hot swap manager power good (output stable))");
    assert_eq!(text[3], "HSM=1 (hot swap manager on)");
    assert_eq!(text[8], "PB2_restart=0 (stable operation)");
    assert_eq!(text[11], "HSM_SW_F=0 (no fault)");
}

#[test]
fn describe_changes_reports_only_switched_bits() {
    let before = DcdcStatus::from_word(172);
    let after = before.with(StatusBit::HsmFault, true);
    assert_eq!(after.word(), 172 | 0b10);
    let changes: Vec<BitReport> = after.describe_changes(before).collect();
    assert_eq!(
        changes,
        [BitReport {
            bit: StatusBit::HsmFault,
            set: true
        }]
    );
    assert_eq!(
        changes[0].to_string(),
        "HSM_F=1 (hot swap manager overcurrent / overvoltage fault)"
    );

    // Back again: the same bit, now clear.
    let back: Vec<BitReport> = before.describe_changes(after).collect();
    assert_eq!(
        back,
        [BitReport {
            bit: StatusBit::HsmFault,
            set: false
        }]
    );
    assert_eq!(back[0].to_string(), "HSM_F=0 (normal)");

    assert_eq!(before.describe_changes(before).count(), 0);

    let all: Vec<BitReport> = DcdcStatus::from_word(0x0FFF)
        .describe_changes(DcdcStatus::from_word(0))
        .collect();
    assert_eq!(all.len(), 12);
    assert!(all.iter().zip(StatusBit::ALL).all(|(r, bit)| r.bit == bit && r.set));
}

#[test]
fn describe_changes_names_b_bits() {
    // Only HSM_HW_F / HSM_SW_F switch: reported by name, never as "no faults".
    let before = DcdcStatus::from_word(172);
    let after = DcdcStatus::from_bytes(0xAC, 0x0C);
    let text: Vec<String> = after.describe_changes(before).map(|r| r.to_string()).collect();
    assert_eq!(
        text,
        [
            "HSM_HW_F=1 (HSM overcurrent fault from the HSM's FLT pin)",
            "HSM_SW_F=1 (HSM overcurrent fault from the firmware threshold)",
        ]
    );
}

// ---- 0x628 BMS alarms ---------------------------------------------------------------------------------------

#[test]
fn each_bms_alarm_bit_alone() {
    let expected = [
        (BmsAlarms::LOW_VOLTAGE, "low voltage"),
        (BmsAlarms::HIGH_VOLTAGE, "high voltage"),
        (BmsAlarms::OVERCURRENT_DISCHARGE, "overcurrent discharge"),
        (BmsAlarms::OVERCURRENT_CHARGE, "overcurrent charge"),
        (BmsAlarms::LOW_CHARGE, "low state of charge"),
        (BmsAlarms::LOW_TEMPERATURE, "low temperature"),
        (BmsAlarms::HIGH_TEMPERATURE, "high temperature"),
    ];
    assert_eq!(BmsAlarms::ALL.len(), expected.len());
    for (pos, ((alarm, name), listed)) in expected.into_iter().zip(BmsAlarms::ALL).enumerate() {
        assert_eq!(alarm, listed);
        assert_eq!(alarm.bits(), 1 << pos, "{name}");
        assert_eq!(alarm.name(), name);
        let data = [1u8 << pos, 0, 0, 0, 0, 0, 0, 0];
        let decoded = BmsAlarms::decode(&data).unwrap();
        assert_eq!(decoded, alarm);
        assert_eq!(decoded.iter().collect::<Vec<_>>(), [alarm]);
        assert_eq!(alarm.encode(), data);
        assert_eq!(Frame::decode(BMS_ID, &data), Ok(Frame::Bms(alarm)));
        assert!(!alarm.is_empty());
    }
}

#[test]
fn bms_flag_operations() {
    let both = BmsAlarms::LOW_VOLTAGE | BmsAlarms::HIGH_TEMPERATURE;
    assert_eq!(both, BmsAlarms::LOW_VOLTAGE.union(BmsAlarms::HIGH_TEMPERATURE));
    assert_eq!(both.bits(), 0b0100_0001);
    assert!(both.contains(BmsAlarms::LOW_VOLTAGE));
    assert!(both.contains(BmsAlarms::HIGH_TEMPERATURE));
    assert!(!both.contains(BmsAlarms::HIGH_VOLTAGE));
    assert!(both.contains(BmsAlarms::NONE));
    assert_eq!(both.name(), "several alarms");
    assert_eq!(
        both.iter().map(BmsAlarms::name).collect::<Vec<_>>(),
        ["low voltage", "high temperature"]
    );
    assert!(BmsAlarms::NONE.is_empty());
    assert_eq!(BmsAlarms::NONE.name(), "no alarm");
    assert_eq!(BmsAlarms::NONE.iter().count(), 0);
    assert_eq!(BmsAlarms::default(), BmsAlarms::NONE);
}

#[test]
fn bms_bit_7_and_other_bytes_masked() {
    assert_eq!(BmsAlarms::from_bits_truncate(0x80), BmsAlarms::NONE);
    assert_eq!(BmsAlarms::from_bits_truncate(0xFF).bits(), 0x7F);
    let decoded = BmsAlarms::decode(&[0x81, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF]).unwrap();
    assert_eq!(decoded, BmsAlarms::LOW_VOLTAGE);
    assert_eq!(decoded.encode(), [0x01, 0, 0, 0, 0, 0, 0, 0]);
}

// ---- Frame dispatch and errors ------------------------------------------------------------------------------

#[test]
fn frame_ids_and_encoding() {
    let info = BatteryInfo {
        voltage_decivolts: 420,
        charge_percent: Some(80),
        current_deciamps: Some(-15),
        temperature_decicelsius: Some(281),
    };
    let frames = [
        (Frame::Info(info), 0x620),
        (Frame::Status(DcdcStatus::from_word(172)), 0x629),
        (Frame::Bms(BmsAlarms::OVERCURRENT_CHARGE), 0x628),
    ];
    for (frame, id) in frames {
        assert_eq!(frame.id(), id);
        let (enc_id, data) = frame.encode();
        assert_eq!(enc_id, id);
        assert_eq!(Frame::decode(enc_id, &data), Ok(frame));
    }
    assert_eq!(Frame::Info(info).encode().1, info.encode());
    assert_eq!(Frame::from(info), Frame::Info(info));
    assert_eq!(Frame::from(BmsAlarms::NONE), Frame::Bms(BmsAlarms::NONE));
    assert_eq!(Frame::from(DcdcStatus::default()), Frame::Status(DcdcStatus::default()));
}

#[test]
fn unknown_ids_rejected() {
    for id in [0x000, 0x621, 0x61F, 0x627, 0x62A, 0x7FF, 0xFFFF] {
        assert_eq!(Frame::decode(id, &[0; 8]), Err(DecodeError::UnknownId(id)));
        // The ID is checked before the length.
        assert_eq!(Frame::decode(id, &[0; 3]), Err(DecodeError::UnknownId(id)));
    }
}

#[test]
fn wrong_lengths_rejected() {
    let buf = [0u8; 9];
    for id in [INFO_ID, STATUS_ID, BMS_ID] {
        for len in (0..=7).chain([9]) {
            let expected = Err(DecodeError::Length { id, actual: len });
            assert_eq!(Frame::decode(id, &buf[..len]), expected, "id {id:#x} len {len}");
        }
    }
    for len in (0..=7).chain([9]) {
        assert_eq!(
            BatteryInfo::decode(&buf[..len]),
            Err(DecodeError::Length {
                id: INFO_ID,
                actual: len
            })
        );
        assert_eq!(
            DcdcStatus::decode(&buf[..len]),
            Err(DecodeError::Length {
                id: STATUS_ID,
                actual: len
            })
        );
        assert_eq!(
            BmsAlarms::decode(&buf[..len]),
            Err(DecodeError::Length {
                id: BMS_ID,
                actual: len
            })
        );
    }
    assert_eq!(
        BatteryInfo::decode(&[0, 0, 0, 0, 200, 0, 0]),
        Err(DecodeError::Length { id: INFO_ID, actual: 7 })
    );
}

#[test]
fn error_display() {
    assert_eq!(DecodeError::UnknownId(0x621).to_string(), "unknown BAT CAN ID 0x621");
    assert_eq!(DecodeError::UnknownId(0).to_string(), "unknown BAT CAN ID 0x000");
    assert_eq!(
        DecodeError::Length { id: 0x629, actual: 3 }.to_string(),
        "BAT frame 0x629 has 3 data bytes, expected 8"
    );
    let err: &dyn core::error::Error = &DecodeError::UnknownId(1);
    assert!(err.source().is_none());
}

// ---- Properties ---------------------------------------------------------------------------------------------

fn reported() -> impl Strategy<Value = Option<i16>> {
    prop::option::of(any::<i16>().prop_filter("0 means not reported", |v| *v != 0))
}

fn battery_info() -> impl Strategy<Value = BatteryInfo> {
    (any::<u16>(), prop::option::of(0u8..=100), reported(), reported()).prop_map(
        |(voltage, charge, current, temperature)| BatteryInfo {
            voltage_decivolts: voltage,
            charge_percent: charge,
            current_deciamps: current,
            temperature_decicelsius: temperature,
        },
    )
}

fn status() -> impl Strategy<Value = DcdcStatus> {
    (0u16..=0x0FFF).prop_map(DcdcStatus::from_word)
}

fn alarms() -> impl Strategy<Value = BmsAlarms> {
    (0u8..=0x7F).prop_map(BmsAlarms::from_bits_truncate)
}

fn frame() -> impl Strategy<Value = Frame> {
    prop_oneof![
        battery_info().prop_map(Frame::Info),
        status().prop_map(Frame::Status),
        alarms().prop_map(Frame::Bms),
    ]
}

proptest! {
    #[test]
    fn battery_info_round_trip(info in battery_info()) {
        prop_assert_eq!(BatteryInfo::decode(&info.encode()), Ok(info));
    }

    #[test]
    fn status_round_trip(status in status()) {
        prop_assert_eq!(DcdcStatus::decode(&status.encode()), Ok(status));
        prop_assert_eq!(DcdcStatus::from_word(status.word()), status);
        prop_assert_eq!(DcdcStatus::from_bytes(status.a(), status.b()), status);
    }

    #[test]
    fn alarms_round_trip(alarms in alarms()) {
        prop_assert_eq!(BmsAlarms::decode(&alarms.encode()), Ok(alarms));
        let rebuilt = alarms.iter().fold(BmsAlarms::NONE, |acc, a| acc | a);
        prop_assert_eq!(rebuilt, alarms);
    }

    #[test]
    fn frame_round_trip(frame in frame()) {
        let (id, data) = frame.encode();
        prop_assert_eq!(id, frame.id());
        prop_assert_eq!(Frame::decode(id, &data), Ok(frame));
    }

    #[test]
    fn frame_decode_never_panics(id in any::<u16>(), data in prop::collection::vec(any::<u8>(), 0..=16)) {
        let result = Frame::decode(id, &data);
        let known = [INFO_ID, STATUS_ID, BMS_ID].contains(&id);
        match result {
            Ok(frame) => {
                prop_assert!(known);
                prop_assert_eq!(data.len(), FRAME_LEN);
                prop_assert_eq!(frame.id(), id);
            }
            Err(DecodeError::UnknownId(got)) => {
                prop_assert!(!known);
                prop_assert_eq!(got, id);
            }
            Err(DecodeError::Length { id: got, actual }) => {
                prop_assert!(known);
                prop_assert_eq!(got, id);
                prop_assert_eq!(actual, data.len());
                prop_assert_ne!(actual, FRAME_LEN);
            }
        }
        // Every 8-byte frame of a known ID decodes, each field on its own.
        if known && data.len() == FRAME_LEN {
            prop_assert!(result.is_ok());
        }
    }

    #[test]
    fn describe_changes_counts_switched_bits(a in 0u16..=0x0FFF, b in 0u16..=0x0FFF) {
        let (new, old) = (DcdcStatus::from_word(a), DcdcStatus::from_word(b));
        let changes: Vec<BitReport> = new.describe_changes(old).collect();
        prop_assert_eq!(changes.len(), (a ^ b).count_ones() as usize);
        for report in &changes {
            prop_assert_eq!(report.set, new.is_set(report.bit));
            prop_assert_ne!(new.is_set(report.bit), old.is_set(report.bit));
        }
        prop_assert!(changes.windows(2).all(|w| w[0].bit < w[1].bit));
    }

    #[test]
    fn describe_all_matches_word(word in any::<u16>()) {
        let status = DcdcStatus::from_word(word);
        let rebuilt = status
            .describe_all()
            .filter(|r| r.set)
            .fold(0u16, |acc, r| acc | r.bit.mask());
        prop_assert_eq!(rebuilt, word & 0x0FFF);
        prop_assert_eq!(status.describe_all().count(), 12);
        prop_assert_eq!(status.has_fault(), status.set_bits().any(StatusBit::is_fault));
    }
}
