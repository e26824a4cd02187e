//! The command line of every `lbv` command, run as a user would: `--help` answers with exit status 0 and says
//! what the exit statuses mean; bad values are refused before anything runs, with exit status 2 and a message
//! naming the option, never a panic; `lbv bench --plot` writes a PNG or an SVG.

use std::path::PathBuf;
use std::process::{Command, Output};

fn lbv(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lbv"))
        .args(args)
        .output()
        .expect("lbv runs")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

fn fixture(name: &str) -> String {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name);
    path.display().to_string()
}

#[test]
fn every_command_answers_help_with_zero_and_its_exit_statuses() {
    for command in [
        &[][..],
        &["bench"],
        &["decode"],
        &["decode", "i2c"],
        &["decode", "can"],
        &["decode", "crash"],
        &["hil"],
        &["image"],
        &["image", "keygen"],
        &["image", "sign"],
        &["image", "inspect"],
    ] {
        for help in ["--help", "-h"] {
            let args: Vec<&str> = command.iter().copied().chain([help]).collect();
            let output = lbv(&args);
            assert_eq!(output.status.code(), Some(0), "lbv {args:?}: {}", text(&output.stderr));
            let out = text(&output.stdout);
            assert!(out.contains("Usage: lbv"), "lbv {args:?}: {out}");
            if help == "--help" && command != ["decode"] && command != ["image"] {
                assert!(
                    out.contains("Exit status"),
                    "lbv {args:?} says its exit statuses: {out}"
                );
            }
        }
    }
    let hil = text(&lbv(&["hil", "--help"]).stdout);
    for status in [
        "0 verdict PASS",
        "1 verdict FAIL",
        "2 bad command line",
        "3 no verdict",
        "4 the log ended",
    ] {
        assert!(hil.contains(status), "{status:?} in {hil}");
    }
}

#[test]
fn no_command_is_a_usage_error() {
    for args in [&[][..], &["decode"], &["image"], &["frobnicate"]] {
        let output = lbv(args);
        assert_eq!(output.status.code(), Some(2), "lbv {args:?}");
        assert!(text(&output.stderr).contains("Usage: lbv"), "lbv {args:?}");
    }
}

/// Every bad value: exit status 2, an error that names what was wrong, no panic, nothing run.
#[test]
fn bad_values_are_refused_with_two() {
    let probes = ["hil", "--master-probe", "A", "--thruster-probe", "B"];
    let with_probes = |more: &[&'static str]| -> Vec<&'static str> { probes.iter().chain(more).copied().collect() };
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["bench", "--duration", "1e14"], "outside 0 < SECONDS <= 86400"),
        (vec!["bench", "--duration", "86401"], "outside"),
        (vec!["bench", "--duration", "0"], "outside"),
        (vec!["bench", "--duration=-1"], "outside"),
        (vec!["bench", "--duration", "NaN"], "outside"),
        (vec!["bench", "--duration", "inf"], "outside"),
        (vec!["bench", "--duration", "soon"], "not a number of seconds"),
        (vec!["bench", "--duration"], "a value is required"),
        (vec!["bench", "--seed", "18446744073709551616"], "--seed"),
        (vec!["bench", "--seed=-1"], "--seed"),
        (vec!["bench", "--seed", "1.5"], "--seed"),
        (vec!["bench", "--plot", "run.pdf"], "does not end in .svg or .png"),
        (vec!["bench", "--plot", "run"], "does not end in .svg or .png"),
        (vec!["bench", "--scenario", "dive", "--all"], "cannot be used with"),
        (vec!["bench", "--udp", "--all"], "cannot be used with"),
        (vec!["bench", "--udp", "--json", "r.json"], "cannot be used with"),
        (vec!["bench", "--udp-send", "127.0.0.1:14550"], "--udp"),
        (vec!["bench", "--udp", "--udp-send", "nowhere"], "invalid value"),
        (
            vec!["bench", "--udp", "--udp-listen", "127.0.0.1:99999"],
            "invalid value",
        ),
        (
            vec!["bench", "--udp", "--udp-listen", "0.0.0.0:14551"],
            "not a loopback address",
        ),
        (
            vec!["bench", "--udp", "--scenario", "water-legacy"],
            "does not go with it",
        ),
        (vec!["bench", "--trace", "trace.jsonl"], "--udp"),
        (
            vec![
                "bench",
                "--udp",
                "--udp-listen",
                "127.0.0.1:0",
                "--trace",
                "/nonexistent/trace.jsonl",
            ],
            "cannot write /nonexistent/trace.jsonl",
        ),
        (
            vec!["bench", "--scenario", "no-such-scenario"],
            "no scenario called no-such-scenario",
        ),
        (vec!["bench", "--frobnicate"], "unexpected argument"),
        (with_probes(&["--timeout", "1e19"]), "outside 0 < S <= 86400"),
        (with_probes(&["--timeout", "0"]), "outside"),
        (with_probes(&["--timeout=-5"]), "outside"),
        (with_probes(&["--timeout", "NaN"]), "outside"),
        (with_probes(&["--timeout", "inf"]), "outside"),
        (with_probes(&["--family", "aveox"]), "invalid value 'aveox'"),
        (
            vec!["hil", "--master-probe", "A;rm", "--thruster-probe", "B"],
            "not a serial number",
        ),
        (
            vec!["hil", "--master-probe", "A", "--thruster-probe", "A"],
            "two probes",
        ),
        (vec!["hil", "--master-probe", "A"], "--thruster-probe"),
        (vec!["hil", "--replay", "x.log", "--dry-run"], "cannot be used with"),
        (
            vec!["hil", "--replay", "/nonexistent/run.log"],
            "cannot read /nonexistent/run.log",
        ),
        (
            vec!["decode", "i2c", "--samplerate", "0"],
            "not a rate from 1 Hz to 1 THz",
        ),
        (vec!["decode", "i2c", "--samplerate", "1e400"], "not a rate"),
        (vec!["decode", "i2c", "--samplerate=-1M"], "not a rate"),
        (
            vec!["decode", "i2c", "/nonexistent/capture.txt"],
            "cannot open /nonexistent/capture.txt",
        ),
        (
            vec!["decode", "can", "/nonexistent/candump.log"],
            "cannot open /nonexistent/candump.log",
        ),
        (vec!["decode", "can", "a.log", "b.log"], "unexpected argument"),
        (
            vec!["decode", "crash", "/nonexistent/record.bin"],
            "cannot open /nonexistent/record.bin",
        ),
        (vec!["decode", "crash", "a.bin", "b.bin"], "unexpected argument"),
        (vec!["decode", "crash", "/dev/null", "--elf"], "a value is required"),
        (
            vec!["decode", "crash", "/dev/null", "--elf", "/nonexistent/image.elf"],
            "cannot open /nonexistent/image.elf",
        ),
        (
            vec!["decode", "crash", "/dev/null", "--elf", "/dev/null"],
            "/dev/null: not an ELF file",
        ),
    ];
    for (args, says) in &cases {
        let output = lbv(args);
        let err = text(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "lbv {args:?}: {err}");
        assert!(err.contains(says), "lbv {args:?}: {says:?} in {err}");
        assert!(!err.contains("panicked"), "lbv {args:?}: {err}");
        assert!(output.stdout.is_empty(), "lbv {args:?} ran: {}", text(&output.stdout));
    }
}

/// Values at the edges of their ranges are taken.
#[test]
fn edge_values_are_taken() {
    let output = lbv(&[
        "bench",
        "--list",
        "--seed",
        "18446744073709551615",
        "--duration",
        "86400",
    ]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let replay = fixture("hil-pass.log");
    for timeout in ["86400", "0.5", "1e-3"] {
        let output = lbv(&["hil", "--replay", &replay, "--timeout", timeout]);
        let out = text(&output.stdout);
        // A tiny timeout may end the wait before the recorded verdict: 3; else the log's PASS: 0.
        assert!(
            matches!(output.status.code(), Some(0 | 3)),
            "--timeout {timeout}: {out}"
        );
        assert!(!text(&output.stderr).contains("panicked"));
    }
    let output = lbv(&["decode", "i2c", "--samplerate", "1e12", "/dev/null"]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
}

/// `lbv decode crash`: a record prints with exit status 0, with or without an ELF (here lbv's own); what is not one
/// (empty, cut short, one bit flipped, larger than a record file may be) is refused with 1 and the reason.
#[test]
fn decode_crash_prints_a_record_and_refuses_what_is_not_one() {
    use crash_record::{FaultStatus, Frame, Image, Kind, Region, ResetCause, Stop};
    let dir = std::env::temp_dir().join(format!("lbv-cli-crash-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut region = Region::new();
    let image = Image {
        target: 1,
        version: [0, 2, 7, 0],
    };
    region.start(ResetCause(1 << 27), image);
    let stop = Stop {
        kind: Kind::HardFault,
        frame: Frame {
            pc: 0x0800_4321,
            lr: 0xFFFF_FFF9,
            xpsr: 0x6100_0003,
            sp: 0x2000_7F00,
        },
        faults: FaultStatus {
            cfsr: 1 << 25,
            hfsr: 1 << 30,
            mmfar: 0,
            bfar: 0,
        },
        exception: 3,
        panic: None,
        uptime_ms: 5_001,
    };
    region.record(stop, image);
    let record = region.record;
    let file = |name: &str, bytes: &[u8]| {
        let path = dir.join(name);
        std::fs::write(&path, bytes).unwrap();
        path.display().to_string()
    };
    let good = file("good.bin", &record);
    let exe = env!("CARGO_BIN_EXE_lbv");
    for args in [
        vec!["decode", "crash", &good],
        vec!["decode", "crash", &good, "--elf", exe],
    ] {
        let output = lbv(&args);
        let out = text(&output.stdout);
        assert_eq!(output.status.code(), Some(0), "lbv {args:?}: {}", text(&output.stderr));
        for line in [
            "kind       HardFault\n",
            "target     SeaBotix thruster\n",
            "version    0.2.7\n",
            "uptime     5.001 s\n",
            "exception  3 HardFault\n",
            "LR         0xfffffff9  EXC_RETURN: no call site\n",
            "CFSR       0x02000000  DIVBYZERO\n",
            "  +000.000 s  started (reset flags 0x08, RCC_CSR's top byte)\n",
        ] {
            assert!(out.contains(line), "lbv {args:?}: {line:?} in {out}");
        }
    }
    let mut flipped = record;
    flipped[20] ^= 0x10;
    for (bytes, says) in [
        (&[][..], "0 bytes, not a record's 128"),
        (&record[..100], "100 bytes, not a record's 128"),
        (&flipped[..], "its CRC does not match"),
        (&[0x55; 4097][..], "larger than 4096 bytes"),
    ] {
        let path = file("bad.bin", bytes);
        let output = lbv(&["decode", "crash", &path]);
        let err = text(&output.stderr);
        assert_eq!(output.status.code(), Some(1), "{says}: {err}");
        assert!(
            err.contains(&format!("lbv decode crash: {path}: {says}")),
            "{says} in {err}"
        );
        assert!(output.stdout.is_empty() && !err.contains("panicked"), "{err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// `lbv bench --plot` writes a PNG or an SVG by the file's extension.
#[test]
fn bench_plots_png_and_svg() {
    let dir = std::env::temp_dir().join(format!("lbv-cli-plot-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for (name, magic) in [("run.png", &b"\x89PNG\r\n\x1a\n"[..]), ("run.SVG", b"<svg")] {
        let file = dir.join(name);
        let path = file.display().to_string();
        let output = lbv(&["bench", "--scenario", "stuck-sda", "--quiet", "--plot", &path]);
        assert_eq!(output.status.code(), Some(0), "{name}: {}", text(&output.stderr));
        let bytes = std::fs::read(&file).unwrap_or_default();
        assert!(bytes.starts_with(magic), "{name} is not what its name says");
        assert!(bytes.len() > 20_000, "{name}: {} bytes", bytes.len());
    }
    let unwritable = dir.join("no/such/dir/run.png").display().to_string();
    let output = lbv(&["bench", "--scenario", "stuck-sda", "--quiet", "--plot", &unwritable]);
    assert_eq!(output.status.code(), Some(2));
    assert!(
        text(&output.stderr).contains("cannot write"),
        "{}",
        text(&output.stderr)
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bench_all_runs_every_scenario_in_order_and_the_same_as_one_at_a_time() {
    let dir = std::env::temp_dir().join(format!("lbv-cli-all-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let all = dir.join("all.json");
    let output = lbv(&["bench", "--all", "--json", all.to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let listed: Vec<String> = text(&lbv(&["bench", "--list"]).stdout)
        .lines()
        .filter_map(|line| line.split_whitespace().next().map(str::to_string))
        .collect();
    let reports: serde_json::Value = serde_json::from_slice(&std::fs::read(&all).unwrap()).unwrap();
    let names: Vec<&str> = reports
        .as_array()
        .unwrap()
        .iter()
        .map(|report| report["scenario"].as_str().unwrap())
        .collect();
    assert_eq!(names, listed, "in the order --list gives");
    // A scenario of --all (run in a process of its own) gives what it gives alone, but for its wall clock.
    let one = dir.join("one.json");
    let output = lbv(&["bench", "--scenario", "stall-legacy", "--json", one.to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let mut alone: serde_json::Value = serde_json::from_slice(&std::fs::read(&one).unwrap()).unwrap();
    let mut within = reports
        .as_array()
        .unwrap()
        .iter()
        .find(|report| report["scenario"] == "stall-legacy")
        .unwrap()
        .clone();
    for report in [&mut alone, &mut within] {
        report["wall_seconds"] = serde_json::Value::Null;
        report["metrics"]["real_time_factor"] = serde_json::Value::Null;
    }
    assert_eq!(alone, within);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bench_output_to_a_reader_that_stops_early_ends_quietly() {
    use std::io::{BufRead, BufReader};
    let mut child = Command::new(env!("CARGO_BIN_EXE_lbv"))
        .args(["bench", "--all"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("lbv runs");
    let mut first = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    // The reader is gone (as `| head -1` leaves it).
    let output = child.wait_with_output().unwrap();
    assert!(first.starts_with("PASS dive"), "{first}");
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    assert!(text(&output.stderr).is_empty(), "{}", text(&output.stderr));
}
