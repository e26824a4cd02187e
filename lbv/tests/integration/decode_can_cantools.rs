//! `lbv decode can --json` and cantools with `lbv/dbc/bat.dbc` agree on a generated candump log
//! (`tests/decode_can_cantools.py` is the cantools side).
//!
//! Needs python3 with cantools (requirements.txt; `./test.sh --quick` sets it up in target/python); without it these tests fail, they do not skip.
//!
//! Documented differences, checked as such: bat-proto reads 0 in the current and temperature as "not reported"
//! (`null`) where cantools gives 0.0; bat-proto reads a charge above 100 % as unknown (`null`, the frame's other
//! fields kept) where cantools decodes the byte.

use std::path::PathBuf;
use std::process::{Command, Output};

use serde_json::Value;

const DBC: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/dbc/bat.dbc");
const CANTOOLS_SIDE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/decode_can_cantools.py");
const FRAMES: usize = 4000;

/// Runs python3 with `args`; fails the test with the install hint when python3 or cantools is missing.
fn python(args: &[&str]) -> Output {
    let output = match Command::new("python3").args(args).output() {
        Ok(output) => output,
        Err(error) => {
            panic!("cannot run python3 ({error}): install Python 3 and run `./test.sh --quick` (requirements.txt)")
        }
    };
    let stderr = String::from_utf8_lossy(&output.stderr);
    if output.status.code() == Some(3)
        || stderr.contains("No module named 'cantools'")
        || stderr.contains("No module named cantools")
    {
        panic!("this test needs cantools: `./test.sh --quick` sets up requirements.txt in target/python\n{stderr}");
    }
    assert!(
        output.status.success(),
        "python3 {args:?} failed ({}):\n{stderr}",
        output.status
    );
    output
}

/// xorshift64: the same log on every run.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }

    fn bytes<const N: usize>(&mut self) -> [u8; N] {
        std::array::from_fn(|_| self.next() as u8)
    }
}

fn hex(data: &[u8]) -> String {
    data.iter().map(|byte| format!("{byte:02X}")).collect()
}

/// A candump -l log of `FRAMES` frames: the three BAT IDs with random but deterministic values (negative and
/// zero currents and temperatures, charges 0..=100, every class of status pattern, BMS bytes with the undefined
/// bit 7), on two interfaces, among other IDs, remote requests, extended IDs, CAN FD and error frames, and a
/// few BAT frames with a wrong length or a charge above 100.
fn generate_log() -> String {
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let mut log = String::new();
    let mut status: u16 = 0x00AC;
    for i in 0..FRAMES {
        let micros = 1_700_000_000_000_000_u64 + i as u64 * 1_000 + rng.below(1_000);
        let iface = if rng.below(10) == 0 { "can1" } else { "can0" };
        let frame = match rng.below(20) {
            0..=5 => {
                let voltage = if rng.below(4) == 0 {
                    rng.next() as u16
                } else {
                    300 + rng.below(200) as u16
                };
                let current = match rng.below(5) {
                    0 => 0,
                    1 => rng.next() as i16,
                    _ => rng.below(1200) as i16 - 600,
                };
                let charge = match rng.below(10) {
                    0 => 0,
                    1 => 100,
                    _ => rng.below(101) as u8,
                };
                let temperature = match rng.below(5) {
                    0 => 0,
                    1 => rng.next() as i16,
                    _ => rng.below(800) as i16 - 200,
                };
                let [v0, v1] = voltage.to_le_bytes();
                let [c0, c1] = current.to_le_bytes();
                let [t0, t1] = temperature.to_le_bytes();
                let unused = rng.next() as u8;
                format!("620#{}", hex(&[v0, v1, c0, c1, charge, unused, t0, t1]))
            }
            6..=11 => {
                status = match rng.below(7) {
                    0 => 0,
                    1 => 0x0FFF,
                    2 => 1 << rng.below(12),
                    3 => rng.next() as u16 & 0x0FFF,
                    4 | 5 => status ^ (1 << rng.below(12)),
                    // The unused bits 12-15 set: both sides ignore them.
                    _ => rng.next() as u16 | 0xF000,
                };
                let [a, b] = status.to_le_bytes();
                let garbage: [u8; 6] = if rng.below(4) == 0 { rng.bytes() } else { [0; 6] };
                format!("629#{}{}", hex(&[a, b]), hex(&garbage))
            }
            12..=14 => {
                let alarms = if rng.below(3) == 0 { 0 } else { rng.next() as u8 };
                let rest: [u8; 7] = if rng.below(4) == 0 { rng.bytes() } else { [0; 7] };
                format!("628#{}{}", hex(&[alarms]), hex(&rest))
            }
            15 => {
                let id = loop {
                    let id = rng.below(0x800);
                    if ![0x620, 0x628, 0x629].contains(&id) {
                        break id;
                    }
                };
                let len = rng.below(9) as usize;
                format!("{id:03X}#{}", hex(&rng.bytes::<8>()[..len]))
            }
            16 => ["620#R", "629#R8", "628#R"][rng.below(3) as usize].to_string(),
            17 => match rng.below(3) {
                0 => format!("00000620#{}", hex(&rng.bytes::<8>())),
                1 => format!("123##1{}", hex(&rng.bytes::<12>())),
                _ => "20000004#0000000000000000".to_string(),
            },
            18 if rng.below(2) == 0 => {
                let len = [0, 1, 4, 7][rng.below(4) as usize];
                let id = [0x620, 0x628, 0x629][rng.below(3) as usize];
                format!("{id:03X}#{}", hex(&rng.bytes::<8>()[..len]))
            }
            18 => format!("620#A401000{}000000", ["065", "0FF", "0C8"][rng.below(3) as usize]),
            _ => format!("620#{}", hex(&[0x10, 0x01, 0, 0, 50, 0, 0, 0])),
        };
        log.push_str(&format!(
            "({}.{:06}) {iface} {frame}\n",
            micros / 1_000_000,
            micros % 1_000_000
        ));
    }
    log
}

fn json_lines(text: &[u8]) -> Vec<Value> {
    String::from_utf8_lossy(text)
        .lines()
        .map(|line| serde_json::from_str(line).unwrap_or_else(|error| panic!("not JSON ({error}): {line}")))
        .collect()
}

/// A value in tenths (0.1 V, 0.1 A, 0.1 °C), from lbv's one-decimal number or cantools' scaled float.
fn tenths(value: &Value) -> i64 {
    (value.as_f64().unwrap_or_else(|| panic!("not a number: {value}")) * 10.0).round() as i64
}

#[test]
fn cantools_and_lbv_agree_on_a_generated_log() {
    let log = generate_log();
    let path: PathBuf = std::env::temp_dir().join(format!("lbv-decode-can-agree-{}.log", std::process::id()));
    std::fs::write(&path, &log).unwrap();
    let path_text = path.to_str().unwrap();

    let lbv = Command::new(env!("CARGO_BIN_EXE_lbv"))
        .args(["decode", "can", "--json", path_text])
        .output()
        .unwrap();
    let cantools = python(&[CANTOOLS_SIDE, DBC, path_text]);
    let _ = std::fs::remove_file(&path);

    let lbv_stderr = String::from_utf8_lossy(&lbv.stderr);
    // The log has BAT frames that do not decode (wrong length): exit status 1, no bad line.
    assert_eq!(lbv.status.code(), Some(1), "{lbv_stderr}");
    assert!(lbv_stderr.contains("skipped 0 bad lines"), "{lbv_stderr}");
    assert!(lbv_stderr.contains(&format!("{FRAMES} lines")), "{lbv_stderr}");

    let ours = json_lines(&lbv.stdout);
    let theirs = json_lines(&cantools.stdout);
    assert_eq!(
        ours.len(),
        theirs.len(),
        "lbv and cantools decoded different numbers of BAT frames"
    );

    let mut seen = std::collections::BTreeMap::<&str, usize>::new();
    let mut count = |what| *seen.entry(what).or_default() += 1;
    for (ours, theirs) in ours.iter().zip(&theirs) {
        let line = &theirs["line"];
        let context = format!("line {line}: lbv {ours} / cantools {theirs}");
        assert_eq!(ours["id"], theirs["id"], "{context}");
        let (our_time, their_time) = (ours["time"].as_f64().unwrap(), theirs["time"].as_f64().unwrap());
        assert!((our_time - their_time).abs() < 1e-5, "{context}");

        if let Some(error) = ours.get("error") {
            assert_eq!(&ours["line"], line, "{context}");
            let error = error.as_str().unwrap();
            assert!(theirs.get("error").is_some(), "{context}");
            assert!(error.contains("data bytes, expected 8"), "{context}");
            count("wrong length, both reject");
            continue;
        }
        assert!(theirs.get("error").is_none(), "{context}");
        match ours["id"].as_u64().unwrap() {
            0x620 => {
                assert_eq!(tenths(&ours["voltage_v"]), tenths(&theirs["voltage_v"]), "{context}");
                if ours["charge_pct"].is_null() {
                    // Documented difference: bat-proto reads a charge above 100 % as unknown and keeps the frame's
                    // other fields; cantools decodes the byte.
                    assert!(theirs["charge_pct"].as_u64().unwrap() > 100, "{context}");
                    count("charge above 100: lbv unknown, cantools decodes");
                } else {
                    assert_eq!(ours["charge_pct"], theirs["charge_pct"], "{context}");
                }
                for field in ["current_a", "temperature_c"] {
                    if ours[field].is_null() {
                        // Documented difference: 0 on the wire is "not reported" for bat-proto.
                        assert_eq!(tenths(&theirs[field]), 0, "{field}: {context}");
                        count("0 read as not reported");
                    } else {
                        assert_eq!(tenths(&ours[field]), tenths(&theirs[field]), "{field}: {context}");
                        assert_ne!(tenths(&ours[field]), 0, "{field}: {context}");
                        if tenths(&ours[field]) < 0 {
                            count("negative current or temperature");
                        }
                    }
                }
                count(match ours["charge_pct"].as_u64() {
                    Some(0) => "charge 0",
                    Some(100) => "charge 100",
                    _ => "info",
                });
            }
            0x629 => {
                for field in ["status", "status_bits", "changed"] {
                    assert_eq!(ours[field], theirs[field], "{field}: {context}");
                }
                count(match ours["status"].as_u64() {
                    Some(0) => "status 0",
                    Some(0x0FFF) => "status all 12 bits",
                    Some(word) if word.count_ones() == 1 => "status one bit",
                    _ => "status other",
                });
                if ours["changed"].as_array().is_some_and(|changed| !changed.is_empty()) {
                    count("status changed");
                }
            }
            0x628 => {
                for field in ["alarms", "alarm_bits", "changed"] {
                    assert_eq!(ours[field], theirs[field], "{field}: {context}");
                }
                count("bms");
            }
            other => panic!("unexpected ID {other}: {context}"),
        }
    }
    // The log exercised every case it was made for.
    for case in [
        "wrong length, both reject",
        "charge above 100: lbv unknown, cantools decodes",
        "0 read as not reported",
        "negative current or temperature",
        "charge 0",
        "charge 100",
        "info",
        "status 0",
        "status all 12 bits",
        "status one bit",
        "status other",
        "status changed",
        "bms",
    ] {
        assert!(
            seen.get(case).is_some_and(|n| *n > 0),
            "no case {case:?} in the log: {seen:?}"
        );
    }
}

#[test]
fn cantools_loads_the_dbc() {
    let dump = python(&["-m", "cantools", "dump", DBC]);
    let dump = String::from_utf8_lossy(&dump.stdout);
    for expected in [
        "BAT_INFO",
        "0x620",
        "BAT_STATUS",
        "0x629",
        "BMS_ALARMS",
        "0x628",
        "HSM_SW_F",
        "Temperature",
    ] {
        assert!(dump.contains(expected), "cantools dump has no {expected}:\n{dump}");
    }
}
