//! Exhaustive checks over every speed byte, every speed step and every small message.

use tmc_proto::{DecodeError, Family, FieldWarning, LegacyStatus, MaxPower, Order, SeaBotixStatus, Speed, checksum};

#[test]
fn all_256_speed_bytes() {
    let (mut forward, mut reverse, mut zero) = (0, 0, 0);
    for byte in 0..=u8::MAX {
        match Speed::from_byte(byte) {
            Ok(speed) => {
                assert!((0x19..=0xE6).contains(&byte), "{byte:#04x} decoded");
                let expected = if byte == 0x7F { 0x80 } else { byte };
                assert_eq!(speed.to_byte(), expected, "{byte:#04x}");
                match speed.step() {
                    0 => zero += 1,
                    s if s > 0 => forward += 1,
                    _ => reverse += 1,
                }
            }
            Err(e) => {
                assert!(!(0x19..=0xE6).contains(&byte), "{byte:#04x} rejected");
                assert_eq!(e, DecodeError::SpeedOutOfRange(byte));
            }
        }
    }
    assert_eq!((forward, reverse, zero), (102, 102, 2));
}

#[test]
fn all_205_steps() {
    let steps: Vec<Speed> = (-102..=102).map(|s| Speed::new(s).unwrap()).collect();
    assert_eq!(steps.len(), 205);
    for pair in steps.windows(2) {
        assert!(pair[0].rpm() < pair[1].rpm(), "{:?} {:?}", pair[0], pair[1]);
        assert!(pair[0].to_byte() < pair[1].to_byte() || pair[1].is_zero());
    }
    for s in &steps {
        assert_eq!(Speed::from_rpm(s.rpm()), *s, "{s:?}");
        assert_eq!(Speed::from_byte(s.to_byte()), Ok(*s));
        assert_eq!(Speed::new_saturating(i32::from(s.step())), *s);
        assert_eq!(s.rpm(), -Speed::new(-s.step()).unwrap().rpm());
    }
    assert_eq!(Speed::new(102).unwrap().rpm(), 4500);
    assert_eq!(Speed::new(-102).unwrap().rpm(), -4500);
    // Bytes follow steps: forward 0x80 + s, reverse 0x7F - s.
    for s in 1..=102_i8 {
        assert_eq!(Speed::new(s).unwrap().to_byte(), 0x80 + s as u8);
        assert_eq!(Speed::new(-s).unwrap().to_byte(), 0x7F - s as u8);
    }
}

#[test]
fn from_rpm_picks_the_nearest_step() {
    for rpm in -5000..=5000_i32 {
        let s = Speed::from_rpm(rpm);
        let clamped = rpm.clamp(-4500, 4500);
        // |s * 4500 / 102 - rpm| <= half a step, i.e. |s * 4500 - rpm * 102| <= 2250.
        let error = (i32::from(s.step()) * 4500 - clamped * 102).abs();
        assert!(error <= 2250, "rpm {rpm} -> {s:?}");
    }
}

#[test]
fn every_order_of_both_families() {
    for family in Family::ALL {
        for speed_byte in 0..=u8::MAX {
            for info in 0..=u8::MAX {
                let mt = family.order_type();
                let bytes = [mt, speed_byte, info, checksum(&[mt, speed_byte, info])];
                match Order::decode(family, &bytes) {
                    Ok(order) => {
                        assert_eq!(order.info, info);
                        assert_eq!(Speed::from_byte(speed_byte), Ok(order.speed));
                        assert_eq!(Order::decode_any(&bytes), Ok((family, order)));
                        let again = order.encode(family);
                        assert_eq!(Order::decode(family, &again), Ok(order));
                        if speed_byte != 0x7F {
                            assert_eq!(again, bytes);
                        }
                    }
                    Err(e) => assert_eq!(e, DecodeError::SpeedOutOfRange(speed_byte)),
                }
            }
        }
    }
}

#[test]
fn every_legacy_status_with_a_good_checksum() {
    let mut warned = 0;
    for status in 0..=u8::MAX {
        for max_power in 0..=u8::MAX {
            let bytes = [0x55, status, max_power, checksum(&[0x55, status, max_power])];
            let decoded = LegacyStatus::decode(&bytes).expect("every framed Legacy status decodes");
            // The faults are always read, whatever MAX POWER holds.
            assert_eq!(decoded.status.revision.number(), status >> 5);
            assert_eq!(decoded.status.faults.bits(), status & 0x1F);
            assert_eq!(
                LegacyStatus::decode(&decoded.status.encode()).map(|d| d.status),
                Ok(decoded.status)
            );
            if let Some(warning) = decoded.warning {
                // Only brushed revisions (2, 4) read MAX POWER as a speed.
                assert!(matches!(status >> 5, 2 | 4));
                assert_eq!(warning, FieldWarning::MaxPower(max_power));
                assert_eq!(decoded.status.max_power, MaxPower::Raw(max_power));
                assert!(Speed::from_byte(max_power).is_err());
                warned += 1;
            }
        }
    }
    // 2 revisions x 32 STATUS bytes each x 50 out-of-range bytes.
    assert_eq!(warned, 3200);
}

#[test]
fn every_seabotix_speed_byte_keeps_the_faults() {
    for speed in 0..=u8::MAX {
        for fault in 0..=u8::MAX {
            let body = [0x53, 0x02, fault, 12, speed, 25];
            let mut bytes = [0; 7];
            bytes[..6].copy_from_slice(&body);
            bytes[6] = checksum(&body);
            let decoded = SeaBotixStatus::decode(&bytes).expect("every framed SeaBotix status decodes");
            assert_eq!(decoded.status.faults.bits(), fault & 0x1F);
            assert_eq!(
                (decoded.status.current_deciamps, decoded.status.temperature_c),
                (12, 25)
            );
            match Speed::from_byte(speed) {
                Ok(reading) => assert_eq!((decoded.status.speed, decoded.warning), (reading, None)),
                Err(_) => assert_eq!(
                    (decoded.status.speed, decoded.warning),
                    (Speed::ZERO, Some(FieldWarning::Speed(speed)))
                ),
            }
        }
    }
}
