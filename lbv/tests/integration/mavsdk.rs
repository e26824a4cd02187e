//! The bench from MAVSDK, an SDK with its own MAVLink implementation (`tests/mavsdk_pilot.py`): MAVSDK finds the
//! master, downloads its mission with `MissionRaw` (empty, answered at once: no retry), reads every parameter
//! (the settings and the read-only stand-ins, each decoded as the integer or float its type says), sets one and
//! is refused one. Runs in real time (a few seconds).
//!
//! Needs python3 with MAVSDK (`mavsdk` in requirements.txt, which `./test.sh` sets up in target/python); without
//! it this test fails, it does not skip.

use crate::support;

const PILOT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/mavsdk_pilot.py");
/// How long the bench runs, s; the pilot is done well before.
const BENCH_SECONDS: &str = "60";
/// The pilot's own time limit, s.
const PILOT_SECONDS: &str = "45";

#[test]
fn mavsdk_downloads_an_empty_mission_at_once_and_reads_every_parameter() {
    let [gcs, bench_port] = support::free_ports();
    let args = [gcs.to_string(), PILOT_SECONDS.to_string()];
    let (summary, _) = support::fly(PILOT, &args, BENCH_SECONDS, gcs, bench_port, "mavsdk");
    assert_eq!(
        summary["steps"],
        serde_json::json!(["connect", "mission", "params", "param_set"]),
        "{summary}"
    );
    assert_eq!(summary["mission"]["items"], 0, "{summary}");
    assert_eq!(summary["mission"]["warnings"], serde_json::json!([]), "{summary}");
    // 64 parameters: 15 floats (the two timeouts, the offsets and the declination), 49 integers.
    assert_eq!(
        summary["params"],
        serde_json::json!({"int": 49, "float": 15}),
        "{summary}"
    );
    assert_eq!(summary["param_set"]["gain"], 60, "{summary}");
    assert_eq!(summary["param_set"]["read_only"]["value"], 19, "{summary}");
    println!("pilot: {summary}");
}
