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
