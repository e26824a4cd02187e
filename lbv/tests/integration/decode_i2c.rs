//! `lbv decode i2c` as a command: hand-written sigrok-cli and PulseView annotation text in each accepted layout,
//! file and standard input, bad lines, random bytes, and command-line errors.

use std::io::Write as _;
use std::process::{Command, Output, Stdio};

use serde_json::{Value, json};

/// A SeaBotix order (+51, INFO 100) and a Legacy status (brushless, 3.4 A), as sigrok-cli prints them with
/// `-A i2c`: the bit and read/write annotations included, as the decoder emits them.
const PLAIN: &str = "\
i2c-1: Start
i2c-1: 0
i2c-1: 1
i2c-1: 0
i2c-1: 0
i2c-1: 1
i2c-1: 0
i2c-1: 1
i2c-1: 0
i2c-1: Write
i2c-1: Address write: 29
i2c-1: ACK
i2c-1: Data write: 52
i2c-1: ACK
i2c-1: Data write: B3
i2c-1: ACK
i2c-1: Data write: 64
i2c-1: ACK
i2c-1: Data write: 69
i2c-1: ACK
i2c-1: Stop
i2c-1: Start
i2c-1: Read
i2c-1: Address read: 2A
i2c-1: ACK
i2c-1: Data read: 55
i2c-1: ACK
i2c-1: Data read: 20
i2c-1: ACK
i2c-1: Data read: 22
i2c-1: ACK
i2c-1: Data read: 97
i2c-1: NACK
i2c-1: Stop
";

/// The same with `--protocol-decoder-samplenum` (1 MHz sampling).
const NUMBERED: &str = "\
25-25 i2c-1: Start
105-115 i2c-1: Write
35-105 i2c-1: Address write: 29
115-125 i2c-1: ACK
125-205 i2c-1: Data write: 52
205-215 i2c-1: ACK
215-295 i2c-1: Data write: B3
295-305 i2c-1: ACK
305-385 i2c-1: Data write: 64
385-395 i2c-1: ACK
395-475 i2c-1: Data write: 69
475-485 i2c-1: ACK
490-490 i2c-1: Stop
20025-20025 i2c-1: Start
20105-20115 i2c-1: Read
20035-20105 i2c-1: Address read: 2A
20115-20125 i2c-1: ACK
20125-20205 i2c-1: Data read: 55
20205-20215 i2c-1: ACK
20215-20295 i2c-1: Data read: 20
20295-20305 i2c-1: ACK
20305-20385 i2c-1: Data read: 22
20385-20395 i2c-1: ACK
20395-20475 i2c-1: Data read: 97
20475-20485 i2c-1: NACK
20490-20490 i2c-1: Stop
";

/// PulseView "Export all annotations", default format `%s %d: %r: %1`: one row after the other, the bits first.
const PULSEVIEW: &str = "\
35-45 I²C: Bits: 0
45-55 I²C: Bits: 1
25-25 I²C: Address/Data: Start
35-105 I²C: Address/Data: Address write: 29
105-115 I²C: Address/Data: Write
115-125 I²C: Address/Data: ACK
125-205 I²C: Address/Data: Data write: 52
205-215 I²C: Address/Data: ACK
215-295 I²C: Address/Data: Data write: B3
295-305 I²C: Address/Data: ACK
305-385 I²C: Address/Data: Data write: 64
385-395 I²C: Address/Data: ACK
395-475 I²C: Address/Data: Data write: 69
475-485 I²C: Address/Data: ACK
490-490 I²C: Address/Data: Stop
20025-20025 I²C: Address/Data: Start
20035-20105 I²C: Address/Data: Address read: 2A
20115-20125 I²C: Address/Data: ACK
20125-20205 I²C: Address/Data: Data read: 55
20205-20215 I²C: Address/Data: ACK
20215-20295 I²C: Address/Data: Data read: 20
20295-20305 I²C: Address/Data: ACK
20305-20385 I²C: Address/Data: Data read: 22
20385-20395 I²C: Address/Data: ACK
20395-20475 I²C: Address/Data: Data read: 97
20475-20485 I²C: Address/Data: NACK
20490-20490 I²C: Address/Data: Stop
";

/// Run `lbv decode i2c ARGS` with `input` on standard input.
fn run(args: &[&str], input: &[u8]) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_lbv"))
        .args(["decode", "i2c"])
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start lbv");
    // Written from a thread so that a full stdout or stderr pipe cannot stall both sides.
    let mut stdin = child.stdin.take().unwrap();
    let input = input.to_vec();
    let writer = std::thread::spawn(move || {
        // lbv reads to the end unless it fails; a failure shows in the checks.
        let _ = stdin.write_all(&input);
    });
    let output = child.wait_with_output().unwrap();
    writer.join().unwrap();
    output
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8(bytes.to_vec()).unwrap()
}

fn json_lines(output: &Output) -> Vec<Value> {
    text(&output.stdout)
        .lines()
        .map(|line| serde_json::from_str(line).unwrap_or_else(|e| panic!("not JSON ({e}): {line}")))
        .collect()
}

/// The two transfers of the samples above, whatever the layout.
fn check_pair(records: &[Value], timed: bool) {
    assert_eq!(records.len(), 2, "{records:?}");
    let (order, status) = (&records[0], &records[1]);
    assert_eq!(order["address"], 0x29);
    assert_eq!(order["direction"], "write");
    assert_eq!(order["bytes"], json!([0x52, 0xB3, 0x64, 0x69]));
    assert_eq!(order["family"], "SeaBotix");
    assert_eq!(order["kind"], "order");
    assert_eq!(order["speed_step"], 51);
    assert_eq!(order["speed_rpm"], 2250);
    assert_eq!(order["info"], 100);
    assert_eq!(order["checksum_ok"], true);
    assert_eq!(order["ack"], true);
    assert_eq!(status["address"], 0x2A);
    assert_eq!(status["direction"], "read");
    assert_eq!(status["bytes"], json!([0x55, 0x20, 0x22, 0x97]));
    assert_eq!(status["family"], "Legacy");
    assert_eq!(status["kind"], "status");
    assert_eq!(status["revision"], 1);
    assert_eq!(status["motor"], "brushless");
    assert_eq!(status["current_a"], 3.4);
    assert_eq!(status["faults"], json!([]));
    assert_eq!(status["checksum_ok"], true);
    if timed {
        assert_eq!(order["time"], 25e-6);
        assert_eq!(order["duration_s"], 465e-6);
        assert_eq!(status["time"], 20025e-6);
        assert_eq!(status["since_prev_s"], 0.02);
    } else {
        assert_eq!(order["time"], Value::Null);
        assert_eq!(status["since_prev_s"], Value::Null);
    }
}

#[test]
fn sigrok_cli_plain_annotations() {
    let output = run(&["--json"], PLAIN.as_bytes());
    assert!(output.status.success());
    check_pair(&json_lines(&output), false);
    let err = text(&output.stderr);
    assert!(
        err.contains("2 transfers: 1 orders, 1 statuses, 0 other, 0 NACKed, 0 bad checksums; 0 lines skipped"),
        "{err}"
    );
}

#[test]
fn sample_numbers_with_and_without_a_rate() {
    let output = run(&["--json", "--samplerate", "1M"], NUMBERED.as_bytes());
    check_pair(&json_lines(&output), true);
    let output = run(&["--json"], NUMBERED.as_bytes());
    let records = json_lines(&output);
    check_pair(&records, false);
    assert_eq!(records[1]["sample"], 20025);
}

#[test]
fn pulseview_export_and_its_quoted_and_csv_variants() {
    check_pair(
        &json_lines(&run(&["--json", "--samplerate", "1000000"], PULSEVIEW.as_bytes())),
        true,
    );
    // %q: quotes around the names and the text.
    let quoted: String = PULSEVIEW
        .lines()
        .map(|line| {
            let (range, rest) = line.split_once(' ').unwrap();
            let fields: Vec<String> = rest.splitn(3, ": ").map(|field| format!("\"{field}\"")).collect();
            format!("{range} {}\n", fields.join(": "))
        })
        .collect();
    assert!(
        quoted.contains("35-105 \"I²C\": \"Address/Data\": \"Address write: 29\""),
        "{quoted}"
    );
    check_pair(
        &json_lines(&run(&["--json", "--samplerate", "1000000"], quoted.as_bytes())),
        true,
    );
    // A CSV-like format, %s,%d,%r,%1, with Windows line ends.
    let csv: String = PULSEVIEW
        .lines()
        .map(|line| {
            let (range, rest) = line.split_once(' ').unwrap();
            format!("{range},{}\r\n", rest.splitn(3, ": ").collect::<Vec<_>>().join(","))
        })
        .collect();
    check_pair(
        &json_lines(&run(&["--json", "--samplerate", "1000000"], csv.as_bytes())),
        true,
    );
}

#[test]
fn unshifted_addresses() {
    let unshifted = PLAIN
        .replace("Address write: 29", "Address write: 52")
        .replace("Address read: 2A", "Address read: 55");
    check_pair(
        &json_lines(&run(&["--json", "--unshifted"], unshifted.as_bytes())),
        false,
    );
}

#[test]
fn file_and_standard_input_agree() {
    let path = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("decode_i2c_numbered.txt");
    std::fs::write(&path, NUMBERED).unwrap();
    let path = path.to_str().unwrap();
    let from_file = run(&[path, "--samplerate", "1M"], b"");
    let from_dash = run(&["-", "--samplerate", "1M"], NUMBERED.as_bytes());
    let from_stdin = run(&["--samplerate", "1M"], NUMBERED.as_bytes());
    assert!(from_file.status.success());
    assert_eq!(from_file.stdout, from_dash.stdout);
    assert_eq!(from_file.stdout, from_stdin.stdout);
    let out = text(&from_file.stdout);
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(
        lines,
        [
            "0.000025 0x29 W SeaBotix order speed +51 (2250 rpm) info 100 csum ok [52 B3 64 69]",
            "0.020025 +20.000 ms 0x2A R Legacy status faults: none rev 1 brushless current 3.4 A csum ok [55 20 22 97]"
        ]
    );
}

#[test]
fn bad_lines_are_reported_with_their_numbers_and_skipped() {
    let mut input = String::new();
    for (i, line) in PLAIN.lines().enumerate() {
        input.push_str(line);
        input.push('\n');
        if i == 3 {
            input.push_str("this is not an annotation\n");
        }
        if i == 20 {
            input.push_str("i2c-1: Data write: 1234\n");
        }
    }
    input.insert_str(0, "i2c-1: Data read: 07\n");
    let output = run(&["--json"], input.as_bytes());
    assert_eq!(output.status.code(), Some(1), "skipped lines: exit status 1");
    check_pair(&json_lines(&output), false);
    let err = text(&output.stderr);
    // The orphan byte is line 1, then the two bad lines.
    for expected in [
        "line 1: data byte 07 outside a transfer",
        "line 6: not an I2C annotation, skipped: \"this is not an annotation\"",
        "line 24: not an I2C annotation, skipped: \"i2c-1: Data write: 1234\"",
        "3 lines skipped",
    ] {
        assert!(err.contains(expected), "{expected:?} in {err}");
    }
}

#[test]
fn empty_input_says_nothing_was_found() {
    let output = run(&[], b"");
    assert!(output.status.success());
    assert!(output.stdout.is_empty());
    let err = text(&output.stderr);
    assert!(
        err.contains("0 transfers") && err.contains("no I2C annotations found"),
        "{err}"
    );
}

/// xorshift64*: reproducible noise without a dependency.
struct Noise(u64);

impl Noise {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

/// No input makes it panic: random bytes, and annotation text cut, shuffled and spliced with noise.
#[test]
fn random_input_never_crashes() {
    let lines: Vec<&str> = NUMBERED.lines().chain(PLAIN.lines()).chain(PULSEVIEW.lines()).collect();
    for seed in 1..=40u64 {
        let mut noise = Noise(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1);
        let mut input = Vec::new();
        if seed % 4 == 0 {
            let len = 1 + noise.below(20_000);
            input.extend((0..len).map(|_| noise.next() as u8));
        } else {
            for _ in 0..200 {
                match noise.below(6) {
                    0 => input.extend((0..noise.below(80)).map(|_| noise.next() as u8)),
                    1 => {
                        let line = lines[noise.below(lines.len())].as_bytes();
                        input.extend_from_slice(&line[..noise.below(line.len() + 1)]);
                    }
                    2 => input.extend_from_slice(b"{\"ph\": \"B\", \"ts\": 1e400, \"name\": \"Start\"},"),
                    _ => input.extend_from_slice(lines[noise.below(lines.len())].as_bytes()),
                }
                input.push(b'\n');
            }
        }
        for args in [&["--json"][..], &["--samplerate", "1k"][..]] {
            let output = run(args, &input);
            let err = String::from_utf8_lossy(&output.stderr);
            assert!(
                matches!(output.status.code(), Some(0 | 1)),
                "seed {seed}: {:?}\n{err}",
                output.status
            );
            assert!(!err.contains("panicked"), "seed {seed}: {err}");
            assert!(err.contains("lines skipped"), "seed {seed}: {err}");
            if args[0] == "--json" {
                json_lines(&output);
            }
        }
    }
}

#[test]
fn command_line_errors() {
    let help = run(&["--help"], b"");
    assert!(help.status.success());
    let help = text(&help.stdout);
    assert!(
        help.contains("--samplerate") && help.contains("%s %d: %r: %1"),
        "{help}"
    );
    // The help says what the exit statuses are, and they are so.
    assert!(
        help.contains("Exit status: 0 every line read; 1 lines were skipped") && help.contains("2 bad command line"),
        "{help}"
    );

    for args in [
        &["--frobnicate"][..],
        &["--samplerate"][..],
        &["--samplerate", "fast"][..],
        &["--samplerate", "1e400"][..],
        &["a.txt", "b.txt"][..],
    ] {
        let output = run(args, b"");
        assert_eq!(output.status.code(), Some(2), "{args:?}");
        let err = text(&output.stderr);
        assert!(err.starts_with("error: ") && err.contains("--help"), "{args:?}: {err}");
    }
    let missing = run(&["/nonexistent/capture.txt"], b"");
    assert_eq!(missing.status.code(), Some(2));
    assert!(text(&missing.stderr).contains("cannot open /nonexistent/capture.txt"));

    let decode = Command::new(env!("CARGO_BIN_EXE_lbv")).arg("decode").output().unwrap();
    assert_eq!(decode.status.code(), Some(2));
    assert!(text(&decode.stderr).contains("i2c"));
}
