//! The bench flown by MAVProxy, a real ground station, as a pilot flies (`tests/mavproxy_pilot.py`): MAVProxy
//! connects to `lbv bench --udp`, downloads the parameters itself over FTP (`@PARAM/param.pck`) and again as the
//! PARAM_VALUE list (each with its type, each value the file's), asks the vehicle's
//! AUTOPILOT_VERSION (`version`), lists the mission, the fence and the rally points (none) and clears the mission,
//! sets one parameter, arms, holds the vehicle armed for
//! 8 s on its own 1 Hz heartbeats, disarms, reboots the master (the bench restarts its core with its flash kept),
//! finds the parameter still set, and runs a motor test; pymavlink watches what the vehicle sends. Runs in real
//! time (about 35 s).
//!
//! Needs python3 with MAVProxy and pymavlink (requirements.txt, which `./test.sh` sets up in target/python); without
//! them this test fails, it does not skip.

use crate::support;

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
            "version",
            "plans",
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
    // MAV_MISSION_ACCEPTED, MAV_MISSION_TYPE_MISSION.
    assert_eq!(summary["plans"]["clear"], serde_json::json!([0, 0]), "{summary}");
    // MAVLINK2 | COMMAND_INT | PARAM_ENCODE_C_CAST; the crate version; the bench's unique id.
    assert_eq!(summary["version"]["capabilities"], 0x2_2008, "{summary}");
    let version = summary["version"]["flight_sw_version"].as_u64().unwrap_or(0);
    let crate_version: Vec<u64> = env!("CARGO_PKG_VERSION")
        .split('.')
        .map(|n| n.parse().unwrap_or(0))
        .collect();
    assert_eq!(
        version >> 8,
        crate_version[0] << 16 | crate_version[1] << 8 | crate_version[2],
        "{summary}"
    );
    assert_eq!(summary["version"]["uid2"], "LBV bench 01", "{summary}");
    assert_eq!(summary["param_types"]["SYSID_MYGCS"], 4, "INT16: {summary}");
    assert_eq!(summary["param_types"]["FS_PILOT_INPUT"], 2, "INT8: {summary}");
    assert_eq!(summary["param_types"]["FS_GCS_TIMEOUT"], 9, "REAL32: {summary}");
    // What MAVProxy decoded from param.pck: the defaults (its gain, its heartbeat timeout in seconds).
    assert_eq!(summary["ftp_params"]["LBV_GAIN"], 50.0, "{summary}");
    assert_eq!(summary["ftp_params"]["FS_GCS_TIMEOUT"], 5.0, "{summary}");
    assert_eq!(summary["persisted"]["LBV_GAIN"], 80.0, "{summary}");
    assert!(summary["reboot"]["sequence_restarts"].as_u64() >= Some(1), "{summary}");
    println!("pilot: {summary}\nbench:\n{bench_output}");
}

const BLACK_BOX: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/mavproxy_blackbox.py");

/// After a motor test, MAVProxy fetches the master's black box (`ftp get @SYS/blackbox.tlog`) and pymavlink's
/// `mavlogdump.py` reads every frame of it: a sample every 100 ms, thruster 1 turning in 2 s of them at the rpm
/// the live telemetry showed, and every thruster's rpm in every sample the bench's own, from the trace the bench
/// writes as it runs (`lbv bench --udp --trace`; `tests/mavproxy_blackbox.py`).
#[test]
fn mavproxy_fetches_the_black_box_and_mavlogdump_reads_it() {
    let [gcs, bench_port, observer] = support::free_ports();
    let work = support::TempDir::new("mavproxy-blackbox");
    let args = [
        gcs.to_string(),
        observer.to_string(),
        work.0.display().to_string(),
        PILOT_SECONDS.to_string(),
    ];
    let trace = work.join("trace.jsonl");
    let bench_args = ["--trace", trace.as_str()];
    let (summary, bench_output) = support::fly_with(
        BLACK_BOX,
        &args,
        BENCH_SECONDS,
        gcs,
        bench_port,
        "mavproxy pymavlink",
        &bench_args,
    );
    assert_eq!(
        summary["steps"],
        serde_json::json!(["connect", "ready", "motortest", "blackbox"]),
        "{summary}"
    );
    println!("black box: {summary}\nbench:\n{bench_output}");
}
