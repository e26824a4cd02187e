//! The bench flown by MAVProxy, a real ground station, as a pilot flies (`tests/mavproxy_pilot.py`): MAVProxy
//! connects to `lbv bench --udp`, downloads the parameters itself, sets one, arms, holds the vehicle armed for
//! 8 s on its own 1 Hz heartbeats, disarms, reboots the master (the bench restarts its core with its flash kept),
//! finds the parameter still set, and runs a motor test; pymavlink watches what the vehicle sends. Runs in real
//! time (about 35 s).
//!
//! Needs python3 with MAVProxy and pymavlink (`pip install mavproxy pymavlink`; test.sh installs them); without
//! them this test fails, it does not skip.

use std::io::Read as _;
use std::net::UdpSocket;
use std::process::{Child, Command, Stdio};

const PILOT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/mavproxy_pilot.py");
/// How long the bench runs, s; the pilot is done well before.
const BENCH_SECONDS: &str = "120";
/// The pilot's own time limit, s.
const PILOT_SECONDS: &str = "100";

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

/// Three free loopback UDP ports (held together while they are chosen, so they differ).
fn free_ports() -> [u16; 3] {
    let sockets = [(); 3].map(|()| UdpSocket::bind("127.0.0.1:0").unwrap());
    sockets.map(|socket| socket.local_addr().unwrap().port())
}

#[test]
fn mavproxy_holds_the_vehicle_armed_on_its_heartbeats_and_flies_it() {
    let [gcs, bench_port, observer] = free_ports();
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
        .args([&gcs.to_string(), &observer.to_string(), PILOT_SECONDS])
        .stdin(Stdio::null())
        .output();
    let pilot = match pilot {
        Ok(output) => output,
        Err(error) => panic!("cannot run python3 ({error}): install Python 3, `pip install mavproxy pymavlink`"),
    };
    let bench_output = bench.stop();
    let stdout = String::from_utf8_lossy(&pilot.stdout);
    let stderr = String::from_utf8_lossy(&pilot.stderr);
    if pilot.status.code() == Some(3) {
        panic!("mavproxy_pilot.py needs MAVProxy and pymavlink (`pip install mavproxy pymavlink`): {stderr}");
    }
    assert!(
        pilot.status.success(),
        "mavproxy_pilot.py failed ({}):\n{stderr}\nits summary: {stdout}\nthe bench printed:\n{bench_output}",
        pilot.status
    );
    let summary: serde_json::Value = serde_json::from_str(stdout.trim()).expect("the pilot's JSON summary");
    assert_eq!(summary["passed"], true, "{summary}");
    assert_eq!(
        summary["steps"],
        serde_json::json!([
            "connect",
            "params",
            "param_set",
            "arm",
            "hold",
            "disarm",
            "reboot",
            "persisted",
            "motortest"
        ]),
        "{summary}"
    );
    assert_eq!(summary["hold"]["all_armed"], true, "{summary}");
    assert_eq!(summary["persisted"]["LBV_GAIN"], 80.0, "{summary}");
    assert!(summary["reboot"]["sequence_restarts"].as_u64() >= Some(1), "{summary}");
    println!("pilot: {summary}\nbench:\n{bench_output}");
}
