//! The bench flown by MAVProxy, a real ground station, as a pilot flies (`tests/mavproxy_pilot.py`): MAVProxy
//! connects to `lbv bench --udp`, downloads the parameters itself, sets one, arms, holds the vehicle armed for
//! 8 s on its own 1 Hz heartbeats, disarms, reboots the master (the bench restarts its core with its flash kept),
//! finds the parameter still set, and runs a motor test; pymavlink watches what the vehicle sends. Runs in real
//! time (about 35 s).
//!
//! Needs python3 with MAVProxy and pymavlink (`pip install mavproxy pymavlink`; test.sh installs them); without
//! them this test fails, it does not skip.

mod support;

const PILOT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/mavproxy_pilot.py");
/// How long the bench runs, s; the pilot is done well before.
const BENCH_SECONDS: &str = "120";
/// The pilot's own time limit, s.
const PILOT_SECONDS: &str = "100";

#[test]
fn mavproxy_holds_the_vehicle_armed_on_its_heartbeats_and_flies_it() {
    let [gcs, bench_port, observer] = support::free_ports();
    let args = [gcs.to_string(), observer.to_string(), PILOT_SECONDS.to_string()];
    let (summary, bench_output) = support::fly(PILOT, &args, BENCH_SECONDS, gcs, bench_port, "mavproxy pymavlink");
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
