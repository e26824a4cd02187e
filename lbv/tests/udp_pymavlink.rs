//! The bench's console over UDP, flown by a pymavlink script as a ground station would (`tests/udp_pilot.py`):
//! arm, sticks ahead, thruster telemetry moves, disarm. Runs in real time (about 6 s).
//!
//! Needs python3 with pymavlink (`pip install pymavlink`); without it this test fails, it does not skip.

use std::io::Read as _;
use std::net::UdpSocket;
use std::process::{Child, Command, Stdio};

const PILOT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/udp_pilot.py");
/// How long the bench runs, s; the pilot is done well before.
const BENCH_SECONDS: &str = "20";
/// The pilot's own time limit, s.
const PILOT_SECONDS: &str = "30";

/// The bench process, killed when the test ends however it ends.
struct Bench(Child);

impl Bench {
    /// Stop it and return what it printed.
    fn stop(mut self) -> String {
        let _ = self.0.kill();
        let _ = self.0.wait();
        let mut out = String::new();
        if let Some(mut stdout) = self.0.stdout.take() {
            let _ = stdout.read_to_string(&mut out);
        }
        if let Some(mut stderr) = self.0.stderr.take() {
            let _ = stderr.read_to_string(&mut out);
        }
        out
    }
}

impl Drop for Bench {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Two free loopback UDP ports (held together while they are chosen, so they differ).
fn free_ports() -> (u16, u16) {
    let a = UdpSocket::bind("127.0.0.1:0").unwrap();
    let b = UdpSocket::bind("127.0.0.1:0").unwrap();
    (a.local_addr().unwrap().port(), b.local_addr().unwrap().port())
}

#[test]
fn pymavlink_arms_flies_and_disarms_the_bench_over_udp() {
    let (gcs, bench_port) = free_ports();
    let bench = Command::new(env!("CARGO_BIN_EXE_lbv"))
        .args(["bench", "--udp", "--duration", BENCH_SECONDS])
        .args(["--udp-send", &format!("127.0.0.1:{gcs}")])
        .args(["--udp-listen", &format!("127.0.0.1:{bench_port}")])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start lbv bench --udp");
    let bench = Bench(bench);

    let pilot = Command::new("python3")
        .arg(PILOT)
        .args([&gcs.to_string(), &bench_port.to_string(), PILOT_SECONDS])
        .stdin(Stdio::null())
        .output();
    let pilot = match pilot {
        Ok(output) => output,
        Err(error) => panic!("cannot run python3 ({error}): install Python 3 and `pip install pymavlink`"),
    };
    let bench_output = bench.stop();
    let stdout = String::from_utf8_lossy(&pilot.stdout);
    let stderr = String::from_utf8_lossy(&pilot.stderr);
    if pilot.status.code() == Some(3) {
        panic!("udp_pilot.py needs pymavlink (`pip install pymavlink`): {stderr}");
    }
    assert!(
        pilot.status.success(),
        "udp_pilot.py failed ({}):\n{stderr}\nits summary: {stdout}\nthe bench printed:\n{bench_output}",
        pilot.status
    );
    let summary: serde_json::Value = serde_json::from_str(stdout.trim()).expect("the pilot's JSON summary");
    assert_eq!(summary["passed"], true, "{summary}");
    assert_eq!(summary["arm_ack"], 0, "{summary}");
    assert_eq!(summary["disarm_ack"], 0, "{summary}");
    println!("pilot: {summary}\nbench:\n{bench_output}");
}
