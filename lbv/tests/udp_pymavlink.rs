//! The bench's console over UDP, flown by a pymavlink script as a ground station would (`tests/udp_pilot.py`):
//! arm, sticks ahead, thruster telemetry moves, disarm. Runs in real time (about 6 s).
//!
//! Needs python3 with pymavlink (`pip install pymavlink`); without it this test fails, it does not skip.

mod support;

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
    assert_eq!(summary["disarm_ack"], 0, "{summary}");
    println!("pilot: {summary}\nbench:\n{bench_output}");
}
