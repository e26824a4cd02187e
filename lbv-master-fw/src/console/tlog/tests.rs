use mavlink_core::{MavlinkVersion, Message};

use super::*;
use crate::blackbox::{BlackBox, HOLD, capacity};

/// A recorder for six thrusters, the file laid out as the task lays it out.
fn recorder() -> Recorder {
    let recorder = Recorder::new();
    recorder.keep(region(), Instant::from_ticks(0), SIX);
    recorder.lay_out(layout(SIX));
    recorder
}
use crate::console::lbv::MavMessage;
use embassy_time::Duration;

const SIX: usize = 6;

/// A region in the heap, as a `'static` the recorder takes.
fn region() -> &'static mut BlackBox {
    Box::leak(Box::new(BlackBox::new()))
}

/// Sample `n`: armed on odd samples, T1 ordered and turning at `n` steps, T2 reporting a stall.
pub(crate) fn sample(n: u32, event: Option<Event>) -> Sample {
    let step = |n: u32| Speed::new((n % 100) as i8).unwrap_or(Speed::ZERO);
    let mut escs = [Esc::default(); MAX_THRUSTERS];
    escs[0] = Esc {
        reporting: true,
        speed: Some(step(n)),
        current_deciamps: Some(12),
        temperature_c: Some(31),
        faults: Faults::NONE,
    };
    escs[1] = Esc {
        reporting: true,
        speed: None,
        current_deciamps: Some(255),
        temperature_c: None,
        faults: Faults::STALL,
    };
    let mut orders = [Speed::ZERO; MAX_THRUSTERS];
    orders[0] = step(n);
    orders[5] = Speed::MAX_REVERSE;
    Sample {
        clock: 0,
        events: 0,
        armed: n % 2 == 1,
        console_alive: true,
        failsafe: false,
        event,
        battery: BatteryFields {
            millivolts: 24_000 + n as u16,
            centiamps: -1,
            remaining: 80,
            temperature: i16::MAX,
            charge_state: MavBatteryChargeState::MAV_BATTERY_CHARGE_STATE_OK,
            faults: MavBatteryFault::MAV_BATTERY_FAULT_OVER_CURRENT,
        },
        orders,
        escs,
    }
}

#[test]
fn a_sample_comes_back_as_it_was_recorded_and_a_changed_byte_is_refused() {
    let mut bytes = [0u8; sample_len(SIX)];
    let mut recorded = sample(41, Some(Event::LinkLost));
    recorded.clock = 123_456;
    recorded.events = 7;
    recorded.encode(SIX, &mut bytes);
    let mut expected = recorded;
    // The thrusters past the six are not kept.
    expected.orders[6..].fill(Speed::ZERO);
    expected.escs[6..].fill(Esc::default());
    assert_eq!(Sample::decode(&bytes, SIX), Some(expected));
    for at in 0..bytes.len() {
        let mut torn = bytes;
        torn[at] ^= 0x10;
        assert_eq!(Sample::decode(&torn, SIX), None, "byte {at} changed");
    }
    assert_eq!(Sample::decode(&bytes[..10], SIX), None);
}

/// The file's messages: (timestamp in us, sequence, message), each checked as a tlog reader does.
fn messages(file: &[u8]) -> Vec<(u64, u8, MavMessage)> {
    let mut rest = file;
    let mut out = Vec::new();
    while !rest.is_empty() {
        let (stamp, frame) = rest.split_at(8);
        assert_eq!(frame[0], 0xFD, "a MAVLink 2 frame after each timestamp");
        let len = usize::from(frame[1]);
        let id = u32::from_le_bytes([frame[7], frame[8], frame[9], 0]);
        let payload = &frame[10..10 + len];
        let extra = MavMessage::extra_crc(id);
        let crc = mavlink_core::calculate_crc(&frame[1..10 + len], extra);
        assert_eq!(frame[10 + len..12 + len], crc.to_le_bytes(), "message {id}'s CRC");
        let message = MavMessage::parse(MavlinkVersion::V2, id, payload).expect("a message of the dialect");
        out.push((u64::from_be_bytes(stamp.try_into().unwrap()), frame[4], message));
        rest = &frame[12 + len..];
    }
    out
}

/// The whole file, read as an FTP client does: in parts of `size` bytes from each offset.
fn read_all(recorder: &Recorder, file: &TlogFile, size: usize) -> Vec<u8> {
    let mut bytes = Vec::new();
    loop {
        let mut part = vec![0u8; size];
        let n = read(recorder, file, bytes.len() as u32, &mut part, (1, 1)).expect("the samples held");
        if n == 0 {
            return bytes;
        }
        bytes.extend_from_slice(&part[..n]);
    }
}

#[test]
fn the_file_is_a_telemetry_log_of_every_sample_read_from_any_offset() {
    let recorder = recorder();
    let t0 = Instant::from_millis(100);
    for n in 0..30u32 {
        let event = match n {
            0 => Some(Event::Started),
            12 => Some(Event::LinkLost),
            13 => Some(Event::LinkBack),
            _ => None,
        };
        assert!(record(&recorder, t0 + PERIOD * n, sample(n, event)));
    }
    let file = recorder.open().unwrap();
    let whole = read_all(&recorder, &file, 239);
    assert_eq!(whole.len() as u32, file.len());
    assert_eq!(file.len(), 30 * layout(SIX).bytes + 3 * layout(SIX).event_bytes);
    // Any offset, any size: the same bytes.
    for (offset, size) in [
        (0, 1),
        (1, 239),
        (586, 100),
        (layout(SIX).bytes - 3, 7),
        (file.len() - 5, 239),
    ] {
        let mut part = vec![0u8; size];
        let n = read(&recorder, &file, offset, &mut part, (1, 1)).unwrap();
        let end = (offset as usize + size).min(whole.len());
        assert_eq!(&part[..n], &whole[offset as usize..end], "{size} bytes from {offset}");
    }
    let messages = messages(&whole);
    assert_eq!(messages.len(), 30 * 7 + 3);
    // Frames numbered on through the file, timestamps in the samples' order, 100 ms apart.
    for (i, (_, sequence, _)) in messages.iter().enumerate() {
        assert_eq!(*sequence, i as u8);
    }
    assert!(messages.windows(2).all(|w| w[0].0 <= w[1].0));
    let statustexts: Vec<(u64, String)> = messages
        .iter()
        .filter_map(|(t, _, m)| match m {
            MavMessage::STATUSTEXT(s) => Some((*t, s.text.to_str().unwrap().to_string())),
            _ => None,
        })
        .collect();
    assert_eq!(
        statustexts,
        [
            (100_000, "Black box: master started".to_string()),
            (1_300_000, "Black box: ground station lost".to_string()),
            (1_400_000, "Black box: ground station back".to_string()),
        ]
    );
    // Sample 7: armed, T1 ordered and turning at 7 steps, T2 stalled, T6 ordered full astern.
    let of_sample = |n: u64| {
        messages
            .iter()
            .filter(move |(t, ..)| *t == (n + 1) * 100_000)
            .map(|(.., m)| m)
    };
    let mut kinds = Vec::new();
    for message in of_sample(7) {
        kinds.push(message.message_id());
        match message {
            MavMessage::HEARTBEAT(h) => assert_eq!(h.base_mode.bits() & 0x80, 0x80),
            MavMessage::SERVO_OUTPUT_RAW(s) => assert_eq!(
                [s.servo1_raw, s.servo2_raw, s.servo6_raw, s.servo7_raw],
                [1500 + 7 * 400 / 102, 1500, 1100, 0]
            ),
            MavMessage::BATTERY_STATUS(b) => assert_eq!((b.voltages[0], b.battery_remaining), (24_007, 80)),
            MavMessage::ESC_TELEMETRY_1_TO_4(t) => {
                assert_eq!(t.rpm, [Speed::new(7).unwrap().rpm() as u16, 0, 0, 0]);
                assert_eq!((t.current, t.temperature), ([120, 2550, 0, 0], [31, 0, 0, 0]));
                assert_eq!(
                    t.count,
                    [7, 7, 0, 0],
                    "the sample's number, for the thrusters that report"
                );
            }
            MavMessage::ESC_TELEMETRY_5_TO_8(t) => assert_eq!(t.rpm, [0; 4]),
            MavMessage::ESC_INFO(i) if i.index == 0 => {
                assert_eq!(
                    (i.count, i.info, i.temperature[0], i.temperature[1]),
                    (6, 0b11, 3100, i16::MAX)
                );
                assert_eq!(i.failure_flags[1], 32, "motor stuck");
            }
            MavMessage::ESC_INFO(_) => {}
            other => panic!("{other:?} in a sample without an event"),
        }
    }
    assert_eq!(kinds, [0, 36, 147, 11030, 290, 11031, 290]);
}

#[test]
fn a_read_holds_the_samples_and_a_file_whose_samples_are_gone_is_refused() {
    let recorder = recorder();
    let t0 = Instant::from_secs(1);
    assert!(record(&recorder, t0, sample(0, None)));
    let file = recorder.open().unwrap();
    // A read at t0 holds the samples for HOLD.
    recorder.hold(Some(t0));
    assert!(!record(&recorder, t0 + PERIOD, sample(1, None)));
    assert!(!record(
        &recorder,
        t0 + HOLD - Duration::from_millis(1),
        sample(1, None)
    ));
    assert!(record(&recorder, t0 + HOLD, sample(1, None)));
    // The session's end lets them go at once.
    recorder.hold(Some(t0 + HOLD));
    recorder.hold(None);
    assert!(record(&recorder, t0 + HOLD + PERIOD, sample(2, None)));
    // The file as it was opened still reads: its one sample is there.
    assert_eq!(read_all(&recorder, &file, 239).len() as u32, file.len());
    // Once the ring has gone round, its sample is not: the read is refused, not answered with others.
    for n in 0..capacity(SIX) as u32 {
        record(&recorder, t0 + HOLD + PERIOD * (n + 2), sample(n, None));
    }
    assert_eq!(read(&recorder, &file, 0, &mut [0; 239], (1, 1)), None);
    // Without a region there is no file.
    assert_eq!(Recorder::new().open(), None);
}

#[test]
fn an_empty_ring_is_an_empty_file() {
    let recorder = recorder();
    let file = recorder.open().unwrap();
    assert_eq!(file.len(), 0);
    assert_eq!(read(&recorder, &file, 0, &mut [0; 239], (1, 1)), Some(0));
}
