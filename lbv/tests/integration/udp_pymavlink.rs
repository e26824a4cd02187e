//! The bench's console over UDP, flown by a pymavlink script as a ground station would (`tests/udp_pilot.py`):
//! AUTOPILOT_VERSION (both ways of asking), a typed integer parameter, the pre-arm check, arm, sticks ahead, thruster
//! telemetry moves, disarm. Runs in real time (about 6 s).
//!
//! Needs python3 with pymavlink (requirements.txt, which `./test.sh` sets up in target/python); without it this test fails, it does not skip.

use crate::support;

const PILOT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/udp_pilot.py");
/// How long the bench runs, s; the pilot is done well before.
const BENCH_SECONDS: &str = "20";
/// The pilot's own time limit, s.
const PILOT_SECONDS: &str = "30";

#[test]
fn pymavlink_arms_flies_and_disarms_the_bench_over_udp() {
    let [gcs, bench_port] = support::free_ports();
    let args = [gcs.to_string(), bench_port.to_string(), PILOT_SECONDS.to_string()];
    let (summary, bench_output) = support::fly(PILOT, &args, BENCH_SECONDS, gcs, bench_port, "pymavlink");
    assert_eq!(summary["arm_ack"], 0, "{summary}");
    // AUTOPILOT_VERSION: MAVLINK2 | COMMAND_INT | PARAM_ENCODE_C_CAST, a version, the ids chosen.
    let version = &summary["autopilot_version"];
    assert_eq!(version["capabilities"], 0x2_2008, "{summary}");
    assert_ne!(version["flight_sw_version"], 0, "{summary}");
    assert_eq!(
        (&version["vendor_id"], &version["product_id"]),
        (&0x0483.into(), &0x0469.into()),
        "{summary}"
    );
    // FS_PILOT_INPUT is INT8: set as INT8, refused as INT32 (the value unchanged, a warning).
    let typed = &summary["param_types"];
    assert_eq!(typed["read"][1], 2, "{summary}");
    assert_eq!(typed["set_int8"], serde_json::json!([2.0, 2]), "{summary}");
    assert_eq!(typed["set_int32"], serde_json::json!([2.0, 2]), "{summary}");
    assert_eq!(
        typed["texts"],
        serde_json::json!(["FS_PILOT_INPUT: wrong param_type"]),
        "{summary}"
    );
    assert_eq!(summary["prearm_healthy"], true, "{summary}");
    assert_eq!(summary["disarm_ack"], 0, "{summary}");
    println!("pilot: {summary}\nbench:\n{bench_output}");
}
