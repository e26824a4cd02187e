//! The candump line parser, the human and JSON lines, the change reports and the bounds, on small logs.

use super::render::{json_time, push_tenths, tenths};
use super::*;

fn decode(log: &str, json: bool) -> (String, String, Summary) {
    let (mut out, mut err) = (Vec::new(), Vec::new());
    let summary = run(log.as_bytes(), &mut out, &mut err, json).unwrap();
    (
        String::from_utf8(out).unwrap(),
        String::from_utf8(err).unwrap(),
        summary,
    )
}

fn classic(id: u16, data: &[u8]) -> CanFrame {
    let mut bytes = [0; 8];
    bytes[..data.len()].copy_from_slice(data);
    CanFrame::Classic {
        id,
        len: data.len(),
        data: bytes,
    }
}

#[test]
fn parses_candump_log_lines() {
    let frame = |line| match parse_line(line) {
        Ok(Line::Frame { frame, .. }) => Ok(frame),
        Ok(other) => panic!("{other:?}"),
        Err(error) => Err(error),
    };
    assert_eq!(
        parse_line(b"(1700000000.123456) can0 620#A401000058000000"),
        Ok(Line::Frame {
            time: b"1700000000.123456",
            iface: b"can0",
            frame: classic(0x620, &[0xA4, 0x01, 0, 0, 0x58, 0, 0, 0]),
        })
    );
    assert_eq!(
        frame(b"  (1.5)   vcan10  629#ac.00.00.00.0000.0000 R\r"),
        Ok(classic(0x629, &[0xAC, 0, 0, 0, 0, 0, 0, 0]))
    );
    assert_eq!(frame(b"(1.5) can0 123#"), Ok(classic(0x123, &[])));
    assert_eq!(
        frame(b"(1.5) can0 123#1122334455667788_E"),
        Ok(classic(0x123, &[0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77, 0x88]))
    );
    assert_eq!(frame(b"(1.5) can0 620#R"), Ok(CanFrame::Other(Other::Remote)));
    assert_eq!(frame(b"(1.5) can0 620#R8_9"), Ok(CanFrame::Other(Other::Remote)));
    assert_eq!(frame(b"(1.5) can0 620##1A4010000"), Ok(CanFrame::Other(Other::Fd)));
    assert_eq!(
        frame(b"(1.5) can0 00000620#A401000058000000"),
        Ok(CanFrame::Other(Other::Extended))
    );
    assert_eq!(
        frame(b"(1.5) can0 20000004#0000000000000000"),
        Ok(CanFrame::Other(Other::Error))
    );
    assert_eq!(
        frame(b"(1.5) can0 45123#81:00:12345678#11223344.556677"),
        Ok(CanFrame::Other(Other::Xl))
    );
    assert_eq!(parse_line(b" \t\r"), Ok(Line::Blank));
    assert_eq!(
        parse_line(b"DROPCOUNT: dropped 3 CAN frames on 'can0' socket (total drops 3)"),
        Ok(Line::DropCount)
    );

    for (line, reason) in [
        (&b"garbage"[..], "no (SECONDS.FRACTION) time at the start"),
        (b"(1.5)", "no interface name after the time"),
        (b"(1.5) can0", "no frame (ID#DATA) after the interface name"),
        (b"(1.x) can0 620#00", "the time is not SECONDS.FRACTION"),
        (b"(1.5) can0 620", "no '#' between the CAN ID and the data"),
        (
            b"(1.5) can0 62#00",
            "the CAN ID needs 3 (standard) or 8 (extended) hex digits",
        ),
        (b"(1.5) can0 G20#00", "the CAN ID is not hex"),
        (b"(1.5) can0 800#00", "a 3-digit (standard) CAN ID above 7FF"),
        (b"(1.5) can0 620#A40", "an odd number of hex digits in the data"),
        (b"(1.5) can0 620#A4.0", "an odd number of hex digits in the data"),
        (b"(1.5) can0 620#ZZ", "the data is not hex"),
        (
            b"(1.5) can0 620#A40100005800000000",
            "more than 8 data bytes (classic CAN)",
        ),
        (
            b"(1.5) can0 620#00_E",
            "a '_DLC' needs 8 data bytes and one hex digit 9 to F",
        ),
        (b"(1.5) can0 620#R9", "a remote request's length is not 0 to 8"),
        (b"(1.5) can0 620##", "no flags digit after '##' (CAN FD)"),
        (
            b"(1.5) can0 620#00 X",
            "text after the frame (only candump's direction R or T may follow)",
        ),
        (
            b"(1.5) can0 620#00 R R",
            "text after the frame (only candump's direction R or T may follow)",
        ),
    ] {
        assert_eq!(parse_line(line), Err(reason), "{}", String::from_utf8_lossy(line));
    }
}

#[test]
fn human_output_reports_start_up_then_changes() {
    let log = "(1700000000.123456) can0 620#A401E7FF3A00D700\n\
               (1700000000.223456) can0 629#AC00000000000000\n\
               (1700000000.323456) can0 629#AC00000000000000\n\
               (1700000000.423456) can0 629#AE04000000000000\n\
               (1700000000.523456) can0 628#0100000000000000\n\
               (1700000000.623456) can0 628#0200000000000000\n\
               (1700000000.723456) can0 620#A4010000\n\
               (1700000000.823456) can0 620#A401000058000000\n";
    let (out, err, summary) = decode(log, false);
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines[0], "1700000000.123456 0x620 info 42.0 V -2.5 A 58 % 21.5 C");
    assert!(
        lines[1].starts_with(
            "1700000000.223456 0x629 status 0x00ac HSM_PG HSM V12motor V12board; start-up: HSM_broken=0 (normal), "
        ),
        "{}",
        lines[1]
    );
    assert!(lines[1].ends_with("HSM_SW_F=0 (no fault)"), "{}", lines[1]);
    assert_eq!(
        lines[2],
        "1700000000.323456 0x629 status 0x00ac HSM_PG HSM V12motor V12board"
    );
    assert_eq!(
        lines[3],
        "1700000000.423456 0x629 status 0x04ae HSM_F HSM_PG HSM V12motor V12board HSM_HW_F; changed: \
         HSM_F=1 (hot swap manager overcurrent / overvoltage fault), HSM_HW_F=1 (HSM overcurrent fault from the \
         HSM's FLT pin)"
    );
    assert_eq!(
        lines[4],
        "1700000000.523456 0x628 bms alarms 0x01 low voltage; raised: low voltage"
    );
    assert_eq!(
        lines[5],
        "1700000000.623456 0x628 bms alarms 0x02 high voltage; raised: high voltage; cleared: low voltage"
    );
    assert_eq!(
        lines[6],
        "1700000000.723456 0x620 error (line 7): BAT frame 0x620 has 4 data bytes, expected 8"
    );
    assert_eq!(lines[7], "1700000000.823456 0x620 info 42.0 V 88 %");
    assert_eq!(err, "");
    assert_eq!((summary.decoded, summary.decode_errors, summary.bad), (7, 1, 0));
}

#[test]
fn json_output_has_the_documented_fields() {
    let log = "(0000000012.500000) can0 620#A401E7FF3A00D700\n\
               (0000000000.100000) can0 620#A401000058000000\n\
               (13) can0 629#AC00000000000000\n\
               (14.0) can0 629#AE00000000000000\n\
               (15.0) can0 628#8500000000000000\n\
               (16.0) can0 629#0000\n";
    let (out, _, _) = decode(log, true);
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(
        lines,
        [
            r#"{"time":12.500000,"id":1568,"voltage_v":42.0,"current_a":-2.5,"charge_pct":58,"temperature_c":21.5}"#,
            r#"{"time":0.100000,"id":1568,"voltage_v":42.0,"current_a":null,"charge_pct":88,"temperature_c":null}"#,
            r#"{"time":13,"id":1577,"status":172,"status_bits":["HSM_PG","HSM","V12motor","V12board"],"changed":[]}"#,
            r#"{"time":14.0,"id":1577,"status":174,"status_bits":["HSM_F","HSM_PG","HSM","V12motor","V12board"],"changed":["HSM_F"]}"#,
            r#"{"time":15.0,"id":1576,"alarms":5,"alarm_bits":["low voltage","overcurrent discharge"],"changed":["low voltage","overcurrent discharge"]}"#,
            r#"{"time":16.0,"id":1577,"line":6,"error":"BAT frame 0x629 has 2 data bytes, expected 8"}"#,
        ]
    );
    for line in lines {
        serde_json::from_str::<serde_json::Value>(line).unwrap();
    }
}

#[test]
fn status_changes_are_tracked_per_interface() {
    let log = "(1.0) can0 629#0400000000000000\n(2.0) can1 629#0800000000000000\n\
               (3.0) can0 629#0400000000000000\n(4.0) can1 629#0C00000000000000\n";
    let (out, _, _) = decode(log, true);
    let changed: Vec<serde_json::Value> = out
        .lines()
        .map(|line| serde_json::from_str::<serde_json::Value>(line).unwrap()["changed"].clone())
        .collect();
    assert_eq!(
        changed,
        [
            serde_json::json!([]),
            serde_json::json!([]),
            serde_json::json!([]),
            serde_json::json!(["HSM_PG"])
        ]
    );
}

#[test]
fn tenths_and_times_format_exactly() {
    let mut out = Vec::new();
    for value in [0, 5, -5, 420, -32768, 65535] {
        push_tenths(&mut out, value);
        out.push(b' ');
    }
    for time in [
        &b"0000000000.000001"[..],
        b"000",
        b"7",
        b"0012",
        b"0.0",
        b"1700000000.123456",
    ] {
        out.extend_from_slice(json_time(time).get().as_bytes());
        out.push(b' ');
    }
    assert_eq!(
        String::from_utf8(out).unwrap(),
        "0.0 0.5 -0.5 42.0 -3276.8 6553.5 0.000001 0 7 12 0.0 1700000000.123456 "
    );
}

/// serde_json writes every value a frame can carry in tenths (i16 or u16) as the human line does: one decimal.
#[test]
fn json_tenths_are_the_human_digits() {
    for value in i32::from(i16::MIN)..=i32::from(u16::MAX) {
        let mut human = Vec::new();
        push_tenths(&mut human, value);
        let json = serde_json::to_string(&tenths(value)).unwrap();
        assert_eq!(json.as_bytes(), human, "{value}");
    }
}

#[test]
fn random_lines_never_panic() {
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let alphabet = b"()0123456789abcdefABCDEF#.R_ :\t\r\ncanDROPCOUNT\xff\x00";
    for _ in 0..20_000 {
        let len = (next() % 60) as usize;
        let line: Vec<u8> = (0..len)
            .map(|_| alphabet[(next() % alphabet.len() as u64) as usize])
            .collect();
        let _ = parse_line(&line);
        let _ = run(&line[..], &mut Vec::new(), &mut Vec::new(), next() % 2 == 0);
    }
}

#[test]
fn long_lines_are_cut_and_skipped() {
    let mut log = vec![b'x'; MAX_LINE * 3];
    log.extend_from_slice(b"\n(1.0) can0 620#A401000058000000\n");
    let (mut out, mut err) = (Vec::new(), Vec::new());
    let summary = run(&log[..], &mut out, &mut err, false).unwrap();
    assert_eq!((summary.lines, summary.bad, summary.decoded), (2, 1, 1));
    assert!(
        String::from_utf8(err)
            .unwrap()
            .starts_with("lbv decode can: line 1: line too long")
    );
}

/// A log with more interfaces than [`MAX_INTERFACES`]: the boards remembered stay bounded, the least recently
/// heard is forgotten, and the summary says so.
#[test]
fn interfaces_beyond_the_limit_are_forgotten_least_recent_first() {
    let status = |iface: &str| format!("(1.0) {iface} 629#AC00000000000000\n");
    let mut log = String::new();
    for i in 0..10 * MAX_INTERFACES {
        log.push_str(&status(&format!("can{i}")));
    }
    // can0 .. can{MAX-1} were pushed out long ago; the last MAX_INTERFACES are remembered.
    let last = format!("can{}", 10 * MAX_INTERFACES - 1);
    log.push_str(&status(&last));
    log.push_str(&status("can0"));
    let mut decoder = Decoder::new(false);
    let mut lines = crate::lines::Lines::new(log.as_bytes(), MAX_LINE);
    let mut outputs = Vec::new();
    while let Some((number, line)) = lines.next_line().unwrap() {
        let Ok(Line::Frame { time, iface, frame }) = parse_line(line.bytes()) else {
            panic!("a frame")
        };
        decoder.frame(number, time, iface, frame);
        outputs.push(String::from_utf8(std::mem::take(&mut decoder.out)).unwrap());
    }
    assert_eq!(decoder.boards.len(), MAX_INTERFACES);
    let last_two: Vec<&String> = outputs.iter().rev().take(2).collect();
    assert!(!last_two[1].contains("start-up"), "still remembered: {}", last_two[1]);
    assert!(
        last_two[0].contains("start-up: "),
        "forgotten, so a start-up again: {}",
        last_two[0]
    );
    assert_eq!(decoder.summary.forgotten, 9 * MAX_INTERFACES as u64 + 1);
    assert!(decoder.summary.to_string().contains("forgotten"));
}
