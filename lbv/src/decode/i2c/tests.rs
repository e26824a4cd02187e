//! The line formats, the assembly and the records, then whole runs on annotation texts.

use super::formats::{Annotation, Event, Stamp, candidates};
use super::record::{Record, decode_status};
use super::*;
use tmc_proto::{Family, Faults, MotorKind, Speed};

fn event(line: &str) -> Event {
    parse_line(line).unwrap().unwrap().event
}

#[test]
fn every_layout_reads_the_same_annotation() {
    let address = Event::Address {
        read: false,
        value: 0x29,
    };
    for line in [
        "i2c-1: Address write: 29",
        "35-105 i2c-1: Address write: 29",
        "35-105 i2c-1: address-write: \"Address write: 29\" \"AW: 29\" \"29\"",
        "35-105 I²C: Address/Data: Address write: 29",
        "35-105 \"I²C\": \"Address/Data\": \"Address write: 29\"",
        "35-105 \"I²C\": \"Address/data\": \"Address write: 29\",\"AW: 29\",\"29\"",
        "35-105,I²C,Address/Data,Address write: 29",
        "35-105\tI²C\taddress-write\tAddress write: 29",
        "35-105 I²C: Address/Data: Address write: 29,AW: 29,29",
        "I²C;Address/Data;Address write: 29;35",
        "35-105 I2C: ADDRESS WRITE: 0x29\r\n",
        "Address write: 29",
        "{\"ph\": \"B\", \"ts\": 35.000000, \"pid\": \"i2c-1\", \"tid\": \"Address/Data\", \"name\": \"Address write: 29\"},",
    ] {
        assert_eq!(event(line), address, "{line}");
    }
}

#[test]
fn stamps() {
    assert_eq!(
        parse_line("35-105 i2c-1: Start").unwrap().unwrap().stamp,
        Stamp::Samples(35, 105)
    );
    assert_eq!(parse_line("i2c-1: Start").unwrap().unwrap().stamp, Stamp::None);
    assert_eq!(
        parse_line("{\"ph\": \"B\", \"ts\": 25.5, \"name\": \"Start\"}")
            .unwrap()
            .unwrap()
            .stamp,
        Stamp::Seconds(25.5e-6)
    );
    assert!(parse_line("99999999999999999999999-1 i2c-1: Start").is_err());
}

#[test]
fn every_event() {
    assert_eq!(event("i2c-1: Start"), Event::Start);
    assert_eq!(event("i2c-1: Start repeat"), Event::RepeatStart);
    assert_eq!(event("i2c-1: Stop"), Event::Stop);
    assert_eq!(event("i2c-1: ACK"), Event::Ack);
    assert_eq!(event("i2c-1: NACK"), Event::Nack);
    assert_eq!(event("i2c-1: Read"), Event::Ignored);
    assert_eq!(event("i2c-1: Write"), Event::Ignored);
    assert_eq!(event("105-115 i2c-1: 0"), Event::Ignored);
    assert_eq!(event("105-115 i2c-1: bit: \"1\""), Event::Ignored);
    assert_eq!(event("i2c-1: Data read: 0C"), Event::Data { read: true, byte: 0x0C });
    assert_eq!(
        event("i2c-1: Data write: b3"),
        Event::Data {
            read: false,
            byte: 0xB3
        }
    );
    assert_eq!(
        event("i2c-1: Address read: 2A"),
        Event::Address {
            read: true,
            value: 0x2A
        }
    );
}

#[test]
fn nothing_to_read() {
    for line in [
        "",
        "   \r\n",
        "# a comment",
        "{\"traceEvents\": [",
        "]}",
        "{\"ph\": \"E\", \"name\": \"Start\"}",
    ] {
        assert_eq!(parse_line(line), Ok(None), "{line:?}");
    }
}

#[test]
fn not_annotations() {
    for line in [
        "hello",
        "i2c-1: Data write: 123",
        "i2c-1: Data write: ZZ",
        "i2c-1: Data write:",
        "i2c-1: Packet: 29",
        "uart-1: RX: 41",
        "{not json",
        "{\"ph\": \"B\", \"name\": \"Start\"}",
        "{\"ph\": \"B\", \"ts\": 1, \"name\": \"TX: 41\"}",
        "12-",
    ] {
        assert!(parse_line(line).is_err(), "{line:?}");
    }
}

/// Reading a line is linear in its length: on lines of separators (which once cost time cubic in their
/// length) the annotation texts tried add up to at most three times the line.
#[test]
fn separator_storms_cost_linear_work() {
    for filler in [":", ",", ";", "\t", ": ", "a:", "Address write:", "x:y,"] {
        let line = filler.repeat(MAX_LINE / filler.len());
        let (count, bytes) = candidates(&line).fold((0, 0), |(n, bytes), text| (n + 1, bytes + text.len()));
        let fields = line.matches([':', ',', ';', '\t']).count() + 1;
        assert!(count <= 2 * fields, "{filler:?}: {count} candidates");
        assert!(bytes <= 3 * line.len(), "{filler:?}: {bytes} bytes tried");
        assert!(!matches!(parse_line(&line), Ok(Some(_))), "{filler:?}");
    }
    // The annotation is still found at the far end of such a line.
    let line = format!("{}Address write: 29", ":".repeat(MAX_LINE - 20));
    assert_eq!(
        event(&line),
        Event::Address {
            read: false,
            value: 0x29
        }
    );
}

#[test]
fn sample_rates() {
    assert_eq!(parse_rate("1000000"), Ok(1e6));
    assert_eq!(parse_rate("1M"), Ok(1e6));
    assert_eq!(parse_rate("1MHz"), Ok(1e6));
    assert_eq!(parse_rate("24 MHz"), Ok(24e6));
    assert_eq!(parse_rate("500k"), Ok(5e5));
    assert_eq!(parse_rate("1e6"), Ok(1e6));
    assert_eq!(parse_rate("1G"), Ok(1e9));
    assert_eq!(parse_rate("1"), Ok(1.0));
    for bad in [
        "", "0", "-5", "fast", "inf", "NaN", "Hz", "M", "1e400", "0.5", "2e12", "1e-300",
    ] {
        assert!(parse_rate(bad).is_err(), "{bad}");
    }
}

#[test]
fn command_line() {
    #[derive(Debug, clap::Parser)]
    struct Cli {
        #[command(flatten)]
        args: Args,
    }
    let parse = |line: &[&str]| {
        use clap::Parser as _;
        Cli::try_parse_from(std::iter::once("i2c").chain(line.iter().copied())).map(|cli| cli.args)
    };
    let args = parse(&["cap.txt", "--json", "--samplerate", "2M", "--unshifted"]).unwrap();
    assert_eq!(args.input.as_deref(), Some(std::path::Path::new("cap.txt")));
    assert!(args.json && args.unshifted);
    assert_eq!(args.samplerate, Some(2e6));
    assert_eq!(parse(&["--samplerate=4k"]).unwrap().samplerate, Some(4e3));
    assert_eq!(parse(&["-"]).unwrap().input.as_deref(), Some(std::path::Path::new("-")));
    for bad in [
        &["--samplerate"][..],
        &["--frobnicate"],
        &["a", "b"],
        &["--samplerate", "0"],
    ] {
        assert!(parse(bad).is_err(), "{bad:?}");
    }
}

fn records(text: &str, samplerate: Option<f64>) -> (Vec<serde_json::Value>, String) {
    let args = Args {
        json: true,
        samplerate,
        ..Args::default()
    };
    let (mut out, mut err) = (Vec::new(), Vec::new());
    run(text.as_bytes(), &mut out, &mut err, &args).unwrap();
    let records = String::from_utf8(out)
        .unwrap()
        .lines()
        .map(|line| serde_json::from_str(line).unwrap())
        .collect();
    (records, String::from_utf8(err).unwrap())
}

/// sigrok's annotations of one read from 7-bit `address` of `bytes`, starting at sample `at`.
fn read_annotations(at: u64, address: u8, bytes: &[u8]) -> String {
    let mut lines = vec![
        format!("{at}-{at} i2c-1: Start"),
        format!("{}-{} i2c-1: Address read: {address:02X}", at + 10, at + 80),
    ];
    let mut t = at + 90;
    lines.push(format!("{t}-{} i2c-1: ACK", t + 10));
    for (n, byte) in bytes.iter().enumerate() {
        t += 10;
        lines.push(format!("{t}-{} i2c-1: Data read: {byte:02X}", t + 80));
        t += 90;
        let ack = if n + 1 == bytes.len() { "NACK" } else { "ACK" };
        lines.push(format!("{t}-{} i2c-1: {ack}", t + 10));
    }
    lines.push(format!("{}-{} i2c-1: Stop", t + 20, t + 20));
    lines.join("\n") + "\n"
}

#[test]
fn a_status_in_the_implied_type_form_is_read_and_named() {
    let status = tmc_proto::Status::SeaBotix(tmc_proto::SeaBotixStatus {
        revision: 0,
        motor: MotorKind::Brushless,
        current_limited: true,
        faults: Faults::WATER,
        current_deciamps: 25,
        speed: Speed::new(20).unwrap(),
        temperature_c: 33,
    });
    let full = status.encode();
    let full = full.as_bytes();
    let frame = &full[1..];
    let with_idle: Vec<u8> = frame.iter().copied().chain([0xFF]).collect();
    let text = read_annotations(0, 0x29, full)
        + &read_annotations(2000, 0x29, frame)
        + &read_annotations(4000, 0x29, &with_idle);
    let (records, err) = records(&text, None);
    assert_eq!(records.len(), 3, "{err}");
    for (record, form) in records
        .iter()
        .zip([serde_json::Value::Null, "implied-type".into(), "implied-type".into()])
    {
        assert_eq!(record["kind"], "status");
        assert_eq!(record["faults"], serde_json::json!(["water detect"]), "{record}");
        assert_eq!(record["current_a"], 2.5);
        assert_eq!(record["temperature_c"], 33);
        assert_eq!(record["checksum_ok"], true);
        assert_eq!(record.get("form").cloned().unwrap_or_default(), form, "{record}");
    }
}

#[test]
fn order_status_and_gaps() {
    let text = "\
10-10 i2c-1: Start
20-90 i2c-1: Address write: 29
90-100 i2c-1: ACK
100-180 i2c-1: Data write: 52
180-190 i2c-1: ACK
190-270 i2c-1: Data write: B3
270-280 i2c-1: ACK
280-360 i2c-1: Data write: 64
360-370 i2c-1: ACK
370-450 i2c-1: Data write: 69
450-460 i2c-1: ACK
470-470 i2c-1: Stop
1010-1010 i2c-1: Start
1020-1090 i2c-1: Address read: 2A
1090-1100 i2c-1: ACK
1100-1180 i2c-1: Data read: 55
1180-1190 i2c-1: ACK
1190-1270 i2c-1: Data read: 20
1270-1280 i2c-1: ACK
1280-1360 i2c-1: Data read: 22
1360-1370 i2c-1: ACK
1370-1450 i2c-1: Data read: 97
1450-1460 i2c-1: NACK
1470-1470 i2c-1: Stop
";
    let (records, err) = records(text, Some(1e6));
    assert_eq!(records.len(), 2, "{err}");
    let order = &records[0];
    assert_eq!(order["time"], 10e-6);
    assert_eq!(order["address"], 0x29);
    assert_eq!(order["direction"], "write");
    assert_eq!(order["kind"], "order");
    assert_eq!(order["family"], "SeaBotix");
    assert_eq!(order["speed_step"], 51);
    assert_eq!(order["speed_rpm"], 2250);
    assert_eq!(order["info"], 100);
    assert_eq!(order["checksum_ok"], true);
    assert_eq!(order["duration_s"], 460e-6);
    assert_eq!(order["since_prev_s"], serde_json::Value::Null);
    let status = &records[1];
    assert_eq!(status["family"], "Legacy");
    assert_eq!(status["kind"], "status");
    assert_eq!(status["revision"], 1);
    assert_eq!(status["motor"], "brushless");
    assert_eq!(status["current_a"], 3.4);
    assert_eq!(status["faults"], serde_json::json!([]));
    assert_eq!(status["checksum_ok"], true);
    assert_eq!(status["since_prev_s"], 1000e-6);
    assert_eq!(status["since_prev_same_address_s"], serde_json::Value::Null);
    assert!(err.contains("0 lines skipped"), "{err}");
}

#[test]
fn repeated_start_splits_and_orphans_are_skipped() {
    let text = "\
i2c-1: Data write: 01
i2c-1: ACK
i2c-1: Start
i2c-1: Address write: 70
i2c-1: ACK
i2c-1: Data write: 04
i2c-1: ACK
i2c-1: Start repeat
i2c-1: Address read: 70
i2c-1: ACK
i2c-1: Data read: 04
i2c-1: NACK
i2c-1: Stop
garbage
i2c-1: Start
i2c-1: Address write: 2A
i2c-1: NACK
i2c-1: Stop
i2c-1: Start
i2c-1: Address read: 29
i2c-1: ACK
i2c-1: Data read: 53
";
    let (records, err) = records(text, None);
    assert_eq!(records.len(), 4, "{err}");
    assert_eq!(records[0]["device"], "TCA9548A mux");
    assert_eq!(records[0]["mux_channels"], serde_json::json!([2]));
    assert_eq!(records[0]["kind"], "other");
    assert_eq!(records[0]["time"], serde_json::Value::Null);
    assert_eq!(records[1]["direction"], "read");
    assert_eq!(records[1]["mux_channels"], serde_json::json!([2]));
    assert_eq!(records[2]["ack"], false);
    assert_eq!(records[2]["family"], "Legacy");
    assert!(records[2]["error"].as_str().unwrap().contains("no thruster"));
    assert_eq!(records[3]["bytes"], serde_json::json!([0x53]));
    assert!(records[3]["error"].as_str().unwrap().contains("before the STOP"));
    assert_eq!(records[3]["checksum_ok"], serde_json::Value::Null);
    for line in ["line 1:", "line 2:", "line 14:"] {
        assert!(err.contains(line), "{line} in {err}");
    }
    assert!(err.contains("3 lines skipped"), "{err}");
}

#[test]
fn bad_checksum_still_shows_the_fields() {
    let (records, _) = records(
        "i2c-1: Start\ni2c-1: Address write: 29\ni2c-1: ACK\ni2c-1: Data write: 52\ni2c-1: ACK\n\
         i2c-1: Data write: 8A\ni2c-1: ACK\ni2c-1: Data write: 64\ni2c-1: ACK\ni2c-1: Data write: 41\n\
         i2c-1: ACK\ni2c-1: Stop\n",
        None,
    );
    let order = &records[0];
    assert_eq!(order["checksum_ok"], false);
    assert_eq!(order["speed_step"], 10);
    assert_eq!(order["info"], 100);
    assert_eq!(order["error"], "bad checksum: computed 0x40, received 0x41");
}

#[test]
fn status_salvage() {
    // SeaBotix status, speed byte 0x05 out of range and a bad checksum: the rest is still read.
    let bytes = [0x53, 0x02, 0x10, 12, 0x05, 21, 0x00];
    let mut record = Record::default();
    decode_status(&mut record, Family::SeaBotix, &bytes);
    assert_eq!(record.checksum_ok, Some(false));
    assert_eq!(record.speed_step, None);
    assert_eq!(record.faults, Some(vec!["water detect"]));
    assert_eq!(record.temperature_c, Some(21));
    assert_eq!(record.current_a, Some(1.2));
    // Wrong message type: nothing to read.
    let mut record = Record::default();
    decode_status(&mut record, Family::SeaBotix, &[0xFF; 7]);
    assert_eq!(record.faults, None);
    assert!(record.error.unwrap().contains("message type"));
    let mut record = Record::default();
    decode_status(&mut record, Family::Legacy, &[0xFF; 4]);
    assert_eq!((record.faults, record.max_power), (None, None));
    // Legacy brushed, power byte out of range.
    let mut record = Record::default();
    decode_status(&mut record, Family::Legacy, &[0x55, 0x40, 0x05, 0x9A]);
    assert_eq!(record.motor, Some("brushed"));
    assert_eq!(record.power_step, None);
    assert_eq!(record.max_power, Some(0x05));
    assert_eq!(record.checksum_ok, Some(true));
}

#[test]
fn human_lines() {
    let mut decoder = Decoder::new(&Args::default());
    let (mut out, mut err) = (Vec::new(), Vec::new());
    let text = "\
0-0 i2c-1: Start
1-2 i2c-1: Address write: 29
2-3 i2c-1: ACK
3-4 i2c-1: Data write: 52
4-5 i2c-1: ACK
5-6 i2c-1: Data write: B3
6-7 i2c-1: ACK
7-8 i2c-1: Data write: 64
8-9 i2c-1: ACK
9-10 i2c-1: Data write: 69
10-11 i2c-1: ACK
12-12 i2c-1: Stop
900-900 i2c-1: Start
901-902 i2c-1: Address write: 29
902-903 i2c-1: NACK
904-904 i2c-1: Stop
";
    decoder.run(text.as_bytes(), &mut out, &mut err).unwrap();
    let out = String::from_utf8(out).unwrap();
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(
        lines[0],
        "@0 0x29 W SeaBotix order speed +51 (2250 rpm) info 100 csum ok [52 B3 64 69]"
    );
    assert_eq!(lines[1], "@900 0x29 W NACK (no thruster)");
}

fn feed(assembler: &mut Assembler, event: Event) -> Option<Transfer> {
    assembler
        .feed(Annotation {
            event,
            stamp: Stamp::None,
        })
        .unwrap_or(None)
}

/// A transfer that never ends, with data going the wrong way and every byte NACKed, keeps a bounded size.
#[test]
fn an_endless_transfer_keeps_bounded_state() {
    let mut assembler = Assembler::default();
    feed(&mut assembler, Event::Start);
    feed(
        &mut assembler,
        Event::Address {
            read: false,
            value: 0x29,
        },
    );
    feed(&mut assembler, Event::Ack);
    for i in 0..200_000u32 {
        let byte = i as u8;
        feed(&mut assembler, Event::Data { read: i % 2 == 0, byte });
        feed(&mut assembler, Event::Nack);
    }
    let transfer = assembler.current.as_ref().unwrap();
    assert_eq!(transfer.bytes.len(), MAX_TRANSFER_BYTES);
    assert_eq!(transfer.count, 200_000);
    assert!(transfer.problems.is_empty());
    let transfer = assembler.finish().unwrap();
    let record = record(transfer, 0);
    assert_eq!(record.bytes.len(), MAX_TRANSFER_BYTES);
    let error = record.error.unwrap();
    for says in [
        "100000 data bytes go the other way from the address's R/W bit, the first 00",
        "the capture ends before the STOP",
        "the slave NACKed data byte 0 and the master wrote on",
        "200000 data bytes, the first 64 shown",
    ] {
        assert!(error.contains(says), "{says:?} in {error}");
    }
    assert!(error.len() < 400, "{error}");
}

/// Starts and addresses with no STOP: every transfer is printed as it ends, none is kept.
#[test]
fn transfers_without_a_stop_are_not_kept() {
    let mut assembler = Assembler::default();
    let mut printed = 0;
    for i in 0..10_000u32 {
        let event = match i % 3 {
            0 => Event::Start,
            1 => Event::Address {
                read: true,
                value: 0x2A,
            },
            _ => Event::Data { read: true, byte: 0x55 },
        };
        printed += usize::from(feed(&mut assembler, event).is_some());
    }
    assert_eq!(printed, 3333);
    assert!(assembler.current.as_ref().map_or(0, |t| t.bytes.len()) <= 1);
}
