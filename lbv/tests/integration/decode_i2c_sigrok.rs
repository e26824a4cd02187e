//! `lbv decode i2c` against an independent I2C decoder: sigrok's.
//!
//! The test draws the SCL / SDA waveform of real thruster traffic (orders and status reads of both families, a
//! repeated START, a corrupted checksum, NACKed addresses, mux selects) bit by bit at 1 MHz sampling for a 100 kHz
//! bus, has sigrok-cli's I2C decoder read it (raw binary input, one byte per sample: bit 0 SCL, bit 1 SDA), feeds
//! its annotations to `lbv decode i2c --json` and checks every transfer: bytes, decoded fields, times and gaps.
//! The three sigrok-cli output layouts are checked: plain, `--protocol-decoder-samplenum`, and the JSON trace.
//!
//! Needs sigrok-cli (`apt-get install sigrok-cli`); without it this test fails, it does not skip.

use std::io::Write as _;
use std::process::{Command, Stdio};

use serde_json::{Value, json};
use tmc_proto::{Family, Faults, LegacyRevision, LegacyStatus, MaxPower, MotorKind, Order, SeaBotixStatus, Speed};

/// Samples per second: 10 samples per bit of the 100 kHz bus.
const SAMPLERATE: u32 = 1_000_000;

/// The two bus lines, sampled: bit 0 SCL, bit 1 SDA.
struct Bus {
    samples: Vec<u8>,
    scl: bool,
    sda: bool,
}

impl Bus {
    fn new() -> Bus {
        let mut bus = Bus {
            samples: Vec::new(),
            scl: true,
            sda: true,
        };
        bus.hold(50);
        bus
    }

    /// Keep both lines as they are for `n` samples.
    fn hold(&mut self, n: usize) {
        let sample = u8::from(self.scl) | (u8::from(self.sda) << 1);
        self.samples.extend(std::iter::repeat_n(sample, n));
    }

    fn now(&self) -> usize {
        self.samples.len()
    }

    /// Bus idle (both lines high) for `n` samples; only after a STOP.
    fn idle(&mut self, n: usize) {
        assert!(self.scl && self.sda);
        self.hold(n);
    }

    /// START from an idle bus: SDA falls while SCL is high. Returns the sample where SDA falls.
    fn start(&mut self) -> usize {
        self.hold(5);
        let at = self.now();
        self.sda = false;
        self.hold(5);
        self.scl = false;
        self.hold(2);
        at
    }

    /// Repeated START after an acknowledge bit (SCL low): SDA released, SCL high, then SDA falls.
    fn repeated_start(&mut self) -> usize {
        self.sda = true;
        self.hold(3);
        self.scl = true;
        self.hold(5);
        let at = self.now();
        self.sda = false;
        self.hold(5);
        self.scl = false;
        self.hold(2);
        at
    }

    /// One bit: SDA set up 3 µs before SCL rises, SCL high 5 µs, held 2 µs after SCL falls.
    fn bit(&mut self, high: bool) {
        self.sda = high;
        self.hold(3);
        self.scl = true;
        self.hold(5);
        self.scl = false;
        self.hold(2);
    }

    /// A byte, most significant bit first, then the acknowledge bit (low = ACK).
    fn byte(&mut self, value: u8, ack: bool) {
        for bit in (0..8).rev() {
            self.bit(value & (1 << bit) != 0);
        }
        self.bit(!ack);
    }

    /// STOP: SDA rises while SCL is high. Returns the sample where SDA rises.
    fn stop(&mut self) -> usize {
        self.sda = false;
        self.hold(3);
        self.scl = true;
        self.hold(5);
        let at = self.now();
        self.sda = true;
        self.hold(5);
        at
    }
}

/// A transfer as synthesised, and what the decoder must make of it.
struct Expected {
    start: usize,
    end: usize,
    address: u8,
    read: bool,
    ack: bool,
    bytes: Vec<u8>,
    family: Value,
    kind: &'static str,
    checksum_ok: Value,
    /// Decoded fields that must be there, with their values.
    fields: Value,
    /// Text the error must contain, if there must be one.
    error: Option<&'static str>,
}

/// Builds the capture and the list of expected transfers together.
struct Capture {
    bus: Bus,
    expected: Vec<Expected>,
}

impl Capture {
    /// One transfer on the bus: address (with its ACK or NACK), then the bytes; reads are ACKed by the master
    /// except the last byte. Returns its START sample.
    fn transfer(&mut self, address: u8, read: bool, ack: bool, bytes: &[u8], repeated: bool) -> usize {
        let start = if repeated {
            self.bus.repeated_start()
        } else {
            self.bus.start()
        };
        self.bus.byte((address << 1) | u8::from(read), ack);
        if ack {
            for (i, byte) in bytes.iter().enumerate() {
                self.bus.byte(*byte, !read || i + 1 < bytes.len());
            }
        }
        start
    }

    #[allow(clippy::too_many_arguments)]
    fn expect(
        &mut self,
        start: usize,
        address: u8,
        read: bool,
        ack: bool,
        bytes: &[u8],
        kind: &'static str,
        checksum_ok: Value,
        fields: Value,
        error: Option<&'static str>,
    ) {
        self.expected.push(Expected {
            start,
            end: 0,
            address,
            read,
            ack,
            bytes: bytes.to_vec(),
            family: Family::from_address(address).map_or(Value::Null, |family| json!(family.name())),
            kind,
            checksum_ok,
            fields,
            error,
        });
    }

    /// A whole transaction: START, one transfer, STOP, idle.
    #[allow(clippy::too_many_arguments)]
    fn single(
        &mut self,
        address: u8,
        read: bool,
        ack: bool,
        bytes: &[u8],
        kind: &'static str,
        checksum_ok: Value,
        fields: Value,
        error: Option<&'static str>,
    ) {
        let start = self.transfer(address, read, ack, bytes, false);
        self.expect(start, address, read, ack, bytes, kind, checksum_ok, fields, error);
        self.stop();
    }

    /// STOP, recorded as the end of the last transfer, then an idle gap that differs from one to the next.
    fn stop(&mut self) {
        let end = self.bus.stop();
        if let Some(last) = self.expected.last_mut() {
            last.end = end;
        }
        self.bus.idle(200 + 37 * self.expected.len());
    }
}

/// The synthesised traffic: what a master polling SeaBotix and Legacy thrusters behind a mux puts on the bus.
fn traffic() -> Capture {
    let mut capture = Capture {
        bus: Bus::new(),
        expected: Vec::new(),
    };
    let c = &mut capture;
    let yes = json!(true);
    let no = json!(false);

    // Mux: channel 2.
    c.single(
        0x70,
        false,
        true,
        &[0x04],
        "other",
        Value::Null,
        json!({"device": "TCA9548A mux", "mux_channels": [2]}),
        None,
    );

    // SeaBotix order +51 and status.
    let order = Order::new(Speed::new(51).unwrap()).encode(Family::SeaBotix);
    assert_eq!(order, [0x52, 0xB3, 0x64, 0x69]);
    c.single(
        0x29,
        false,
        true,
        &order,
        "order",
        yes.clone(),
        json!({"speed_step": 51, "speed_rpm": 2250, "info": 100}),
        None,
    );
    let status = SeaBotixStatus {
        revision: 0,
        motor: MotorKind::Brushless,
        current_limited: true,
        faults: Faults::WATER,
        current_deciamps: 12,
        speed: Speed::new(51).unwrap(),
        temperature_c: 21,
    }
    .encode();
    c.single(
        0x29,
        true,
        true,
        &status,
        "status",
        yes.clone(),
        json!({"revision": 0, "motor": "brushless", "current_limited": true, "faults": ["water detect"],
               "current_a": 1.2, "speed_step": 51, "speed_rpm": 2250, "temperature_c": 21}),
        None,
    );

    // Legacy order -20 with a 50 % power cap, and a brushless (Aveox) status.
    let order = Order {
        speed: Speed::new(-20).unwrap(),
        info: 50,
    }
    .encode(Family::Legacy);
    c.single(
        0x2A,
        false,
        true,
        &order,
        "order",
        yes.clone(),
        json!({"speed_step": -20, "speed_rpm": -882, "info": 50}),
        None,
    );
    let status = LegacyStatus {
        revision: LegacyRevision::AVEOX_BRUSHLESS,
        faults: Faults::NONE,
        max_power: MaxPower::Current { deciamps: 34 },
    }
    .encode();
    c.single(
        0x2A,
        true,
        true,
        &status,
        "status",
        yes.clone(),
        json!({"revision": 1, "motor": "brushless", "faults": [], "current_a": 3.4, "max_power": 34}),
        None,
    );

    // A SeaBotix order whose checksum was damaged on the way: the fields are still shown.
    let mut order = Order::new(Speed::new(10).unwrap()).encode(Family::SeaBotix);
    order[3] = order[3].wrapping_add(1);
    c.single(
        0x29,
        false,
        true,
        &order,
        "order",
        no.clone(),
        json!({"speed_step": 10, "info": 100}),
        Some("bad checksum"),
    );

    // A missing Legacy thruster: nobody acknowledges its address, the master stops.
    c.single(
        0x2A,
        false,
        false,
        &[],
        "order",
        Value::Null,
        json!({}),
        Some("no thruster"),
    );

    // Order, then the status read after a repeated START (no STOP between).
    let order = Order::STOP.encode(Family::SeaBotix);
    let start = c.transfer(0x29, false, true, &order, false);
    c.expect(
        start,
        0x29,
        false,
        true,
        &order,
        "order",
        yes.clone(),
        json!({"speed_step": 0, "speed_rpm": 0, "info": 100}),
        None,
    );
    let status = SeaBotixStatus {
        revision: 0,
        motor: MotorKind::Brushless,
        current_limited: false,
        faults: Faults::STALL | Faults::HALL,
        current_deciamps: 0,
        speed: Speed::ZERO,
        temperature_c: 30,
    }
    .encode();
    let repeated = c.transfer(0x29, true, true, &status, true);
    if let Some(order) = c.expected.last_mut() {
        order.end = repeated;
    }
    c.expect(
        repeated,
        0x29,
        true,
        true,
        &status,
        "status",
        yes.clone(),
        json!({"current_limited": false, "faults": ["stalled motor", "hall sensor error"], "current_a": 0.0,
               "speed_step": 0, "temperature_c": 30}),
        None,
    );
    c.stop();

    // Mux: channels 0 and 5, then a Legacy brushed status (power +20, ground fault).
    c.single(
        0x70,
        false,
        true,
        &[0x21],
        "other",
        Value::Null,
        json!({"mux_channels": [0, 5]}),
        None,
    );
    let status = LegacyStatus {
        revision: LegacyRevision::LEGACY_BRUSHED,
        faults: Faults::GROUND,
        max_power: MaxPower::Power(Speed::new(20).unwrap()),
    }
    .encode();
    c.single(
        0x2A,
        true,
        true,
        &status,
        "status",
        yes.clone(),
        json!({"revision": 2, "motor": "brushed", "faults": ["ground fault"], "power_step": 20, "max_power": 0x94}),
        None,
    );

    // A SeaBotix status with a bad checksum: overtemp at 112 C still shows.
    let mut status = SeaBotixStatus {
        revision: 1,
        motor: MotorKind::Brushless,
        current_limited: true,
        faults: Faults::OVERTEMP,
        current_deciamps: 5,
        speed: Speed::new(-3).unwrap(),
        temperature_c: 112,
    }
    .encode();
    status[6] ^= 0xFF;
    c.single(
        0x29,
        true,
        true,
        &status,
        "status",
        no.clone(),
        json!({"revision": 1, "faults": ["overtemp"], "temperature_c": 112, "speed_step": -3, "current_a": 0.5}),
        Some("bad checksum"),
    );

    // A status read from a missing SeaBotix thruster, and a Legacy order sent to the SeaBotix address.
    c.single(
        0x29,
        true,
        false,
        &[],
        "status",
        Value::Null,
        json!({}),
        Some("no thruster"),
    );
    let order = Order::STOP.encode(Family::Legacy);
    c.single(
        0x29,
        false,
        true,
        &order,
        "order",
        yes,
        json!({}),
        Some("wrong message type"),
    );

    // Mux: all channels off.
    c.single(
        0x70,
        false,
        true,
        &[0x00],
        "other",
        Value::Null,
        json!({"mux_channels": []}),
        None,
    );
    capture
}

/// Run sigrok-cli on the capture with extra arguments; its standard output.
fn sigrok(capture: &std::path::Path, extra: &[&str]) -> String {
    let output = Command::new("sigrok-cli")
        .arg("-i")
        .arg(capture)
        .args(["-I", &format!("binary:numchannels=2:samplerate={SAMPLERATE}")])
        .args(["-P", "i2c:scl=0:sda=1"])
        .args(extra)
        .output()
        .expect("run sigrok-cli");
    assert!(
        output.status.success(),
        "sigrok-cli failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8(output.stdout).expect("sigrok-cli writes UTF-8")
}

/// Feed annotations to `lbv decode i2c`; its standard output and standard error.
fn lbv(annotations: &str, args: &[&str]) -> (String, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_lbv"))
        .args(["decode", "i2c"])
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start lbv");
    child.stdin.take().unwrap().write_all(annotations.as_bytes()).unwrap();
    let output = child.wait_with_output().unwrap();
    assert!(output.status.success(), "lbv failed: {output:?}");
    (
        String::from_utf8(output.stdout).unwrap(),
        String::from_utf8(output.stderr).unwrap(),
    )
}

fn close(actual: &Value, expected: f64, what: &str) {
    let actual = actual
        .as_f64()
        .unwrap_or_else(|| panic!("{what}: {actual} is not a number"));
    assert!(
        (actual - expected).abs() < 1e-9,
        "{what}: {actual} s, expected {expected} s"
    );
}

/// Check the decoder's records against the synthesised transfers; `timed`: the export carries times.
fn check(records: &[Value], expected: &[Expected], timed: bool, layout: &str) {
    assert_eq!(records.len(), expected.len(), "{layout}: transfer count");
    let seconds = |sample: usize| sample as f64 / f64::from(SAMPLERATE);
    for (i, (record, want)) in records.iter().zip(expected).enumerate() {
        let at = format!("{layout}, transfer {i} ({record})");
        assert_eq!(record["index"], json!(i), "{at}");
        assert_eq!(record["address"], json!(want.address), "{at}");
        assert_eq!(
            record["direction"],
            json!(if want.read { "read" } else { "write" }),
            "{at}"
        );
        assert_eq!(record["ack"], json!(want.ack), "{at}");
        assert_eq!(record["bytes"], json!(want.bytes), "{at}");
        assert_eq!(record["family"], want.family, "{at}");
        assert_eq!(record["kind"], json!(want.kind), "{at}");
        assert_eq!(record["checksum_ok"], want.checksum_ok, "{at}");
        for (field, value) in want.fields.as_object().unwrap() {
            assert_eq!(&record[field], value, "{at}: {field}");
        }
        match want.error {
            Some(text) => assert!(
                record["error"].as_str().is_some_and(|error| error.contains(text)),
                "{at}: error should say {text:?}"
            ),
            None => assert_eq!(record.get("error"), None, "{at}: no error expected"),
        }
        if timed {
            close(&record["time"], seconds(want.start), &format!("{at}: time"));
            close(
                &record["duration_s"],
                seconds(want.end) - seconds(want.start),
                &format!("{at}: duration"),
            );
            match i.checked_sub(1).and_then(|prev| expected.get(prev)) {
                Some(prev) => close(
                    &record["since_prev_s"],
                    seconds(want.start) - seconds(prev.start),
                    &format!("{at}: since_prev_s"),
                ),
                None => assert_eq!(record["since_prev_s"], Value::Null, "{at}"),
            }
            let same = expected
                .get(..i)
                .unwrap()
                .iter()
                .rev()
                .find(|prev| prev.address == want.address);
            match same {
                Some(prev) => close(
                    &record["since_prev_same_address_s"],
                    seconds(want.start) - seconds(prev.start),
                    &format!("{at}: since_prev_same_address_s"),
                ),
                None => assert_eq!(record["since_prev_same_address_s"], Value::Null, "{at}"),
            }
        } else {
            assert_eq!(record["time"], Value::Null, "{at}");
            assert_eq!(record["since_prev_s"], Value::Null, "{at}");
        }
    }
}

fn records(out: &str) -> Vec<Value> {
    out.lines()
        .map(|line| serde_json::from_str(line).unwrap_or_else(|e| panic!("not JSON ({e}): {line}")))
        .collect()
}

#[test]
fn sigrok_decodes_the_synthesised_bus_and_lbv_agrees() {
    match Command::new("sigrok-cli").arg("--version").output() {
        Ok(output) if output.status.success() => {}
        _ => panic!(
            "sigrok-cli is needed for this cross-check and was not found: apt-get install sigrok-cli \
             (./test.sh installs it)"
        ),
    }
    let capture = traffic();
    let path = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("decode_i2c_sigrok.bin");
    std::fs::write(&path, &capture.bus.samples).unwrap();
    let expected = &capture.expected;
    let summary = format!(
        "{} transfers: 5 orders, 5 statuses, 3 other, 2 NACKed, 2 bad checksums; 0 lines skipped",
        expected.len()
    );

    // Plain annotations: no times.
    let plain = sigrok(&path, &["-A", "i2c"]);
    assert!(plain.contains("i2c-1: Address write: 29"), "{plain}");
    let (out, err) = lbv(&plain, &["--json"]);
    check(&records(&out), expected, false, "sigrok-cli -A i2c");
    assert!(err.contains(&summary), "{err}");

    // Sample numbers, turned into seconds.
    let numbered = sigrok(&path, &["-A", "i2c", "--protocol-decoder-samplenum"]);
    let (out, err) = lbv(&numbered, &["--json", "--samplerate", "1MHz"]);
    check(
        &records(&out),
        expected,
        true,
        "sigrok-cli --protocol-decoder-samplenum",
    );
    assert!(err.contains(&summary), "{err}");

    // The JSON trace: times in µs.
    let trace = sigrok(&path, &["--protocol-decoder-jsontrace"]);
    let (out, err) = lbv(&trace, &["--json"]);
    check(
        &records(&out),
        expected,
        true,
        "sigrok-cli --protocol-decoder-jsontrace",
    );
    assert!(err.contains(&summary), "{err}");

    // The human lines carry the same.
    let (out, _) = lbv(&numbered, &["--samplerate", "1000000"]);
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines.len(), expected.len(), "{out}");
    assert!(
        lines[1].contains("0x29 W SeaBotix order speed +51 (2250 rpm) info 100 csum ok [52 B3 64 69]"),
        "{out}"
    );
    assert!(
        lines[2].contains("0x29 R SeaBotix status faults: water detect"),
        "{out}"
    );
    assert!(
        lines[2].contains("current 1.2 A speed +51 (2250 rpm) temp 21 C csum ok"),
        "{out}"
    );
    assert!(lines[5].contains("csum BAD"), "{out}");
    assert!(lines[6].contains("0x2A W NACK (no thruster)"), "{out}");
    assert!(lines[0].contains("0x70 W TCA9548A mux selects channel 2 [04]"), "{out}");
    let _ = std::fs::remove_file(&path);
}
