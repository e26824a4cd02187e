//! The host tools keep memory flat on any input size. Each tool reads a generated input from a pipe, shaped like
//! the inputs that once made it grow (data bytes with no end to their transfer, a new CAN interface name on
//! every line, a log of nothing but step lines, one line of tens of megabytes), and its peak resident memory
//! (VmHWM, read from /proc while it still runs) stays far below what keeping the input would cost: tens to
//! hundreds of megabytes here, gigabytes at ten million lines.

use std::io::{BufWriter, Write};
use std::process::{Command, Stdio};

/// Peak resident memory allowed, KiB. The tools run in a few MiB; keeping these inputs would take 50 MiB or
/// more.
const LIMIT_KIB: u64 = 25 * 1024;

/// Runs `lbv args`, writes `input` to its standard input, and reads its peak resident memory before closing the
/// input (so that the tool is still running). Returns the peak in KiB and the exit status.
fn peak_rss(args: &[&str], input: impl FnOnce(&mut dyn Write), last: &[u8]) -> (u64, Option<i32>) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_lbv"))
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("lbv runs");
    let mut pipe = BufWriter::with_capacity(1 << 16, child.stdin.take().expect("a pipe"));
    input(&mut pipe);
    pipe.flush().expect("lbv reads its input");
    // All but the pipe's buffer is read by now.
    let status = std::fs::read_to_string(format!("/proc/{}/status", child.id())).expect("/proc is there");
    let peak = status
        .lines()
        .find_map(|line| line.strip_prefix("VmHWM:"))
        .and_then(|value| value.trim().trim_end_matches("kB").trim().parse().ok())
        .expect("VmHWM in /proc/PID/status");
    let _ = pipe.write_all(last);
    drop(pipe);
    let status = child.wait().expect("lbv ends");
    (peak, status.code())
}

fn lines(out: &mut dyn Write, count: usize, line: impl Fn(usize) -> String) {
    for i in 0..count {
        out.write_all(line(i).as_bytes()).expect("lbv reads its input");
    }
}

/// One line of `megabytes` MB, no end of line until the last byte.
fn huge_line(out: &mut dyn Write, megabytes: usize) {
    let block = vec![b'x'; 1 << 20];
    for _ in 0..megabytes {
        out.write_all(&block).expect("lbv reads its input");
    }
    out.write_all(b"\n").expect("lbv reads its input");
}

#[test]
fn decode_i2c_keeps_no_transfer_whole() {
    // Read data after a write address, never ACKed, never stopped: 300 000 lines.
    let (peak, code) = peak_rss(
        &["decode", "i2c"],
        |out| {
            lines(out, 2, |i| {
                ["i2c-1: Start\n", "i2c-1: Address write: 29\n"][i].to_string()
            });
            lines(out, 300_000, |_| "i2c-1: Data read: 55\n".to_string());
        },
        b"",
    );
    assert!(peak < LIMIT_KIB, "decode i2c peaked at {peak} KiB");
    assert_eq!(code, Some(0));

    let (peak, code) = peak_rss(&["decode", "i2c", "-"], |out| huge_line(out, 40), b"i2c-1: Start\n");
    assert!(peak < LIMIT_KIB, "decode i2c peaked at {peak} KiB on a 40 MB line");
    assert_eq!(code, Some(1), "the long line is skipped");
}

#[test]
fn decode_can_keeps_a_bounded_number_of_interfaces() {
    // A BMS frame on a new 500-byte interface name every line: 100 000 names.
    let name = "x".repeat(490);
    let (peak, code) = peak_rss(
        &["decode", "can"],
        |out| lines(out, 100_000, |i| format!("(1.0) {name}{i:010} 628#0100000000000000\n")),
        b"",
    );
    assert!(peak < LIMIT_KIB, "decode can peaked at {peak} KiB");
    assert_eq!(code, Some(0));

    let (peak, code) = peak_rss(&["decode", "can"], |out| huge_line(out, 40), b"");
    assert!(peak < LIMIT_KIB, "decode can peaked at {peak} KiB on a 40 MB line");
    assert_eq!(code, Some(1), "the long line is skipped");
}

#[test]
fn decode_crash_reads_no_more_than_a_record_file_may_hold() {
    // An endless stream where a 128-byte record belongs: refused once it passes 4 KiB. The tool ends before the
    // writer does, so its memory is not read from /proc: what it reads bounds what it holds, and the writer sees
    // the pipe close after its buffer's worth.
    let mut child = Command::new(env!("CARGO_BIN_EXE_lbv"))
        .args(["decode", "crash"])
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("lbv runs");
    let mut pipe = child.stdin.take().expect("a pipe");
    let block = vec![0x55u8; 1 << 16];
    let mut written = 0usize;
    while written < 256 << 20 {
        match pipe.write(&block) {
            Ok(count) => written += count,
            Err(_) => break,
        }
    }
    drop(pipe);
    let output = child.wait_with_output().expect("lbv ends");
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(written < 4 << 20, "lbv read {written} bytes of a stream");
    assert_eq!(output.status.code(), Some(1), "{err}");
    assert!(err.contains("larger than 4096 bytes"), "{err}");
}

#[test]
fn hil_replay_keeps_counts_not_lines() {
    // A start, 60 000 failed steps, then the verdict once the peak is read.
    let step = "INFO  ACCEPT step=speed-forward family=seabotix result=FAIL steps=102 ok=101 worst_ms=1001 \
                speed_at_full=101 faults=0 (lbv-master-fw/src/acceptance.rs:400)\n";
    let (peak, code) = peak_rss(
        &["hil", "--replay", "/dev/stdin"],
        |out| {
            lines(out, 1, |_| "INFO  ACCEPT start\n".to_string());
            lines(out, 60_000, |_| step.to_string());
            huge_line(out, 40);
        },
        b"INFO  ACCEPT verdict=FAIL passed=0 failed=60000\n",
    );
    assert!(peak < LIMIT_KIB, "hil --replay peaked at {peak} KiB");
    assert_eq!(code, Some(1), "verdict FAIL");
}
