//! `lbv decode can` as a command: files and standard input, bad lines reported with their numbers and skipped,
//! never a panic, and the exit status.

use std::io::{Read, Write};
use std::path::PathBuf;
use std::process::{Command, Output, Stdio};

/// Runs `lbv decode can ARGS` with `input` on standard input.
fn lbv(args: &[&str], input: &[u8]) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_lbv"))
        .args(["decode", "can"])
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    let input = input.to_vec();
    // Written from another thread, so that a large input cannot block against a full output pipe.
    let writer = std::thread::spawn(move || {
        let _ = stdin.write_all(&input);
    });
    let output = child.wait_with_output().unwrap();
    writer.join().unwrap();
    output
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// A file in the temporary directory, removed when dropped.
struct TempFile(PathBuf);

impl TempFile {
    fn new(name: &str, contents: &[u8]) -> Self {
        let path = std::env::temp_dir().join(format!("lbv-decode-can-{}-{name}", std::process::id()));
        std::fs::write(&path, contents).unwrap();
        Self(path)
    }

    fn path(&self) -> &str {
        self.0.to_str().unwrap()
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

const GOOD: &str = "(1700000000.100000) can0 620#A401E7FF3A00D700\n\
                    (1700000000.200000) can0 629#AC00000000000000\n\
                    (1700000000.300000) can0 628#0000000000000000\n";

#[test]
fn a_good_log_decodes_from_a_file_and_from_standard_input_alike() {
    let file = TempFile::new("good.log", GOOD.as_bytes());
    for json in [false, true] {
        let flag: &[&str] = if json { &["--json"] } else { &[] };
        let from_file = lbv(&[flag, &[file.path()]].concat(), b"");
        let from_stdin = lbv(flag, GOOD.as_bytes());
        let from_dash = lbv(&[flag, &["-"]].concat(), GOOD.as_bytes());
        assert_eq!(from_file.status.code(), Some(0), "{}", text(&from_file.stderr));
        assert_eq!(from_file.stdout, from_stdin.stdout);
        assert_eq!(from_file.stdout, from_dash.stdout);
        assert_eq!(text(&from_file.stdout).lines().count(), 3);
        assert_eq!(
            text(&from_file.stderr),
            "lbv decode can: 3 lines: 3 BAT frames decoded, 0 did not decode, 0 other frames ignored, skipped 0 bad \
             lines\n"
        );
    }
}

#[test]
fn bad_lines_are_reported_with_their_numbers_counted_and_skipped() {
    let log = b"(1700000000.100000) can0 620#A401E7FF3A00D700\n\
                this is not a candump line\n\
                (1700000000.2000\n\
                (1700000000.300000) can0 629#AC0\n\
                (1700000000.400000) can0 629#AC000000000000000000\n\
                \n\
                   \t \n\
                (1700000000.500000) can0 629#AC00000000000000\r\n\
                (1700000000.600000) can0 620#A40100\n\
                (1700000000.700000) can0 7FF#00 junk\n\
                (1700000000.800000) can0 620#R\n\
                \xff\xfe\x00binary\n\
                (1700000000.900000) can0 628#0100000000000000";
    for json in [false, true] {
        let output = lbv(if json { &["--json"] } else { &[] }, log);
        let stdout = text(&output.stdout);
        let stderr = text(&output.stderr);
        assert_eq!(output.status.code(), Some(1), "{stderr}");
        let messages: Vec<&str> = stderr.lines().collect();
        assert_eq!(messages.len(), 7, "{stderr}");
        for (message, (line, reason)) in messages.iter().zip([
            (2, "no (SECONDS.FRACTION) time at the start"),
            (3, "no (SECONDS.FRACTION) time at the start"),
            (4, "an odd number of hex digits in the data"),
            (5, "more than 8 data bytes (classic CAN)"),
            (10, "text after the frame"),
            (12, "no (SECONDS.FRACTION) time at the start"),
        ]) {
            assert!(
                message.starts_with(&format!("lbv decode can: line {line}: {reason}")),
                "line {line}: {message}"
            );
        }
        assert_eq!(
            messages[6],
            "lbv decode can: 13 lines: 3 BAT frames decoded, 1 did not decode, 1 other frame ignored (1 remote \
             request), skipped 6 bad lines"
        );
        // Blank lines and CRLF are fine; the BAT frame with 3 bytes is a decode error in the output, in place.
        let lines: Vec<&str> = stdout.lines().collect();
        assert_eq!(lines.len(), 4, "{stdout}");
        if json {
            assert!(
                lines[1].contains(r#""time":1700000000.500000,"id":1577,"status":172"#),
                "{stdout}"
            );
            assert_eq!(
                lines[2],
                r#"{"time":1700000000.600000,"id":1568,"line":9,"error":"BAT frame 0x620 has 3 data bytes, expected 8"}"#
            );
        } else {
            assert!(
                lines[1].starts_with("1700000000.500000 0x629 status 0x00ac"),
                "{stdout}"
            );
            assert_eq!(
                lines[2],
                "1700000000.600000 0x620 error (line 9): BAT frame 0x620 has 3 data bytes, expected 8"
            );
            assert_eq!(
                lines[3],
                "1700000000.900000 0x628 bms alarms 0x01 low voltage; raised: low voltage"
            );
        }
    }
}

#[test]
fn only_the_first_hundred_bad_lines_are_shown_but_all_are_counted() {
    let log = "nonsense\n".repeat(250);
    let output = lbv(&[], log.as_bytes());
    let stderr = text(&output.stderr);
    assert_eq!(stderr.lines().count(), 101, "{stderr}");
    assert!(
        stderr
            .lines()
            .nth(99)
            .unwrap()
            .starts_with("lbv decode can: line 100: ")
    );
    assert!(
        stderr.ends_with("skipped 250 bad lines (the first 100 shown)\n"),
        "{}",
        stderr.lines().last().unwrap()
    );
}

#[test]
fn random_bytes_never_crash_it() {
    let mut state = 0x0123_4567_89AB_CDEF_u64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    for round in 0..8 {
        let len = 1 << (8 + round);
        let mut input: Vec<u8> = (0..len).map(|_| next() as u8).collect();
        // Some of it near the format, so that the parser gets past its first checks.
        if round % 2 == 1 {
            let pieces: [&[u8]; 8] = [b"(", b"1700000000.1", b") ", b"can0 ", b"620#", b"A4", b"\n", b"##"];
            input = (0..len).flat_map(|_| pieces[(next() % 8) as usize].to_vec()).collect();
        }
        for json in [false, true] {
            let output = lbv(if json { &["--json"] } else { &[] }, &input);
            let stderr = text(&output.stderr);
            assert!(matches!(output.status.code(), Some(0 | 1)), "round {round}: {stderr}");
            assert!(!stderr.contains("panicked"), "round {round}: {stderr}");
            assert!(
                stderr.lines().last().unwrap().contains("bad line"),
                "round {round}: {stderr}"
            );
        }
    }
    // One line far longer than any candump line, without an end of line.
    let output = lbv(&[], &vec![b'7'; 1 << 20]);
    assert_eq!(output.status.code(), Some(1));
    assert!(text(&output.stderr).contains("line 1: line too long"));
}

#[test]
fn usage_and_input_errors_exit_with_2() {
    for args in [&["--bogus"][..], &["a.log", "b.log"]] {
        let output = lbv(args, b"");
        assert_eq!(output.status.code(), Some(2), "{args:?}");
        let err = text(&output.stderr);
        assert!(
            err.starts_with("error: ") && err.contains("Usage: lbv decode can"),
            "{args:?}: {err}"
        );
    }
    let help = lbv(&["--help"], b"");
    assert_eq!(help.status.code(), Some(0));
    assert!(text(&help.stdout).contains("Exit status: 0 every line read"));
    let output = lbv(&["/nonexistent/candump.log"], b"");
    assert_eq!(output.status.code(), Some(2));
    assert!(text(&output.stderr).contains("cannot open /nonexistent/candump.log"));
}

#[test]
fn a_reader_that_stops_early_is_not_an_error() {
    let log = GOOD.repeat(100_000);
    let file = TempFile::new("long.log", log.as_bytes());
    let mut child = Command::new(env!("CARGO_BIN_EXE_lbv"))
        .args(["decode", "can", "--json", file.path()])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = [0_u8; 100];
    child.stdout.take().unwrap().read_exact(&mut first).unwrap();
    // The pipe is closed here, as `| head` does.
    let output = child.wait_with_output().unwrap();
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    assert!(!text(&output.stderr).contains("panicked"));
}
