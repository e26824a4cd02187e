//! `lbv hil` end to end without boards: its exit status and output for recorded master logs, and the commands it
//! would run.

use std::path::PathBuf;
use std::process::{Command, Output};

fn lbv(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lbv"))
        .arg("hil")
        .args(args)
        .output()
        .expect("lbv runs")
}

fn fixture(name: &str) -> String {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
        .display()
        .to_string()
}

fn stdout(output: &Output) -> String {
    String::from_utf8_lossy(&output.stdout).into_owned()
}

#[test]
fn a_passing_log_exits_zero() {
    let output = lbv(&["--replay", &fixture("hil-pass.log")]);
    assert_eq!(output.status.code(), Some(0), "{}", stdout(&output));
    let out = stdout(&output);
    assert!(out.contains("verdict PASS: 9 passed, 0 failed"), "{out}");
    assert!(out.contains("lbv hil: PASS: 9 steps passed"), "{out}");
}

#[test]
fn a_failing_log_exits_one_and_names_the_step() {
    let output = lbv(&["--replay", &fixture("hil-fail.log")]);
    assert_eq!(output.status.code(), Some(1));
    let out = stdout(&output);
    assert!(out.contains("failed: legacy held-rotor"), "{out}");
    assert!(out.contains("  FAIL legacy    held-rotor"), "{out}");
}

#[test]
fn a_log_without_a_verdict_exits_four_and_the_log_is_kept() {
    let kept = std::env::temp_dir().join(format!("lbv-hil-replay-{}.log", std::process::id()));
    let kept_name = kept.display().to_string();
    let output = lbv(&["--replay", &fixture("hil-no-verdict.log"), "--log", &kept_name]);
    assert_eq!(output.status.code(), Some(4), "{}", stdout(&output));
    assert!(stdout(&output).contains("the log ended without a verdict"));
    let log = std::fs::read_to_string(&kept).expect("the log was kept");
    let _ = std::fs::remove_file(&kept);
    assert_eq!(log, std::fs::read_to_string(fixture("hil-no-verdict.log")).unwrap());
}

#[test]
fn a_dry_run_prints_the_commands_and_runs_nothing() {
    let output = lbv(&[
        "--master-probe",
        "0671FF3",
        "--thruster-probe",
        "066DFF4",
        "--family",
        "legacy",
        "--dry-run",
    ]);
    assert_eq!(output.status.code(), Some(0));
    let out = stdout(&output);
    assert!(out.contains("--features motorless,legacy"), "{out}");
    assert!(out.contains("--features acceptance,legacy"), "{out}");
    assert!(
        out.contains("probe-rs download --chip STM32G431RBTx --probe 0483:374e:066DFF4"),
        "{out}"
    );
    assert!(
        out.contains("probe-rs run --chip STM32G474RETx --probe 0483:374e:0671FF3"),
        "{out}"
    );
}

#[test]
fn bad_usage_exits_two() {
    assert_eq!(lbv(&["--master-probe", "A"]).status.code(), Some(2));
    assert_eq!(lbv(&["--replay", "/nonexistent/log"]).status.code(), Some(2));
}

/// Writes `log` to a file of its own and replays it.
fn replay(name: &str, log: &[u8]) -> Output {
    let path = std::env::temp_dir().join(format!("lbv-hil-{}-{name}.log", std::process::id()));
    std::fs::write(&path, log).unwrap();
    let output = lbv(&["--replay", &path.display().to_string()]);
    let _ = std::fs::remove_file(&path);
    output
}

#[test]
fn a_line_that_is_not_utf8_hides_nothing() {
    let mut log = b"\xff\xfe\n".to_vec();
    log.extend(std::fs::read(fixture("hil-pass.log")).unwrap());
    let output = replay("not-utf8", &log);
    assert_eq!(output.status.code(), Some(0), "{}", stdout(&output));
    assert!(stdout(&output).contains("lbv hil: PASS: 9 steps passed"));
}

#[test]
fn a_verdict_alone_does_not_pass() {
    let output = replay("verdict-alone", b"INFO  ACCEPT verdict=PASS passed=0 failed=0\n");
    assert_eq!(output.status.code(), Some(1), "{}", stdout(&output));
    assert!(
        stdout(&output).contains("a verdict alone proves nothing"),
        "{}",
        stdout(&output)
    );
}

#[test]
fn an_overlong_line_is_cut_and_not_read() {
    let mut log = vec![b'x'; 100_000];
    log.extend(b" ACCEPT verdict=PASS passed=0 failed=0\n");
    let output = replay("overlong", &log);
    assert_eq!(
        output.status.code(),
        Some(4),
        "no verdict was read: {}",
        stdout(&output)
    );
    assert!(String::from_utf8_lossy(&output.stderr).contains("1 log lines were longer than 8192 bytes"));
}
