//! Field update from a ground station, with pymavlink's own MAVLink FTP client (`tests/ftp_upload.py`, on
//! `pymavlink.mavftp`) against `lbv bench --udp`: it lists the update directory, gets `@SYS/versions.txt`, sees a
//! put refused over the link without signing and allows updates over it (`LBV_UPD_UNSIGNED` 1), puts a SeaBotix
//! update file signed
//! with the development key to /update/thruster0.lbvu, reads its CRC32, sees the same file refused for the Legacy
//! slot 1, and applies the image, which the thruster checks, swaps in and runs; then puts a master image to
//! /update/master.lbvu and applies it: the master checks it, restarts into its bootloader's swap, and the new image
//! confirms itself once it has heard the script's heartbeats. The bench writes what its master's update sink
//! received (`--update-dir`), which must be the file, byte for byte. Runs in real time (about 35 s: the master's
//! swap alone takes 11 s).
//!
//! Needs python3 with pymavlink (requirements.txt, which `./test.sh` sets up in target/python); without it this test fails, it does not skip.

use crate::support;

const SCRIPT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/ftp_upload.py");
/// How long the bench runs, s; the script is done well before.
const BENCH_SECONDS: &str = "90";
/// The script's own time limit, s.
const SCRIPT_SECONDS: &str = "80";

#[test]
fn pymavlink_puts_an_update_file_that_the_sink_gets_byte_for_byte_and_applies_it() {
    let [gcs, bench_port] = support::free_ports();
    let dir = support::TempDir::new("udp-ftp");
    let (local, received) = (dir.join("local"), dir.join("received"));
    for path in [&local, &received] {
        std::fs::create_dir_all(path).unwrap();
    }
    std::fs::write(format!("{local}/thruster0.lbvu"), support::signed_update_file()).unwrap();
    let master = support::signed_update_file_for(update_image::Target::Master);
    std::fs::write(format!("{local}/master.lbvu"), &master).unwrap();
    let args = [
        gcs.to_string(),
        bench_port.to_string(),
        local.clone(),
        SCRIPT_SECONDS.to_string(),
    ];
    let (summary, bench_output) = support::fly_with(
        SCRIPT,
        &args,
        BENCH_SECONDS,
        gcs,
        bench_port,
        "pymavlink",
        &["--update-dir", &received],
    );
    // The directories (in one reply, whose entries pymavlink sorts), then one file per slot of the dive vehicle's
    // table, one per family and the master's.
    assert_eq!(
        summary["root"],
        serde_json::json!([["@PARAM", 0, true], ["@SYS", 0, true], ["update", 0, true]]),
        "{summary}"
    );
    let files = |sizes: [u64; 9]| {
        let families = ["thrusters-seabotix.lbvu", "thrusters-legacy.lbvu", "master.lbvu"];
        let names = (0..6)
            .map(|n| format!("thruster{n}.lbvu"))
            .chain(families.map(str::to_owned));
        serde_json::Value::from(
            names
                .zip(sizes)
                .map(|(name, size)| serde_json::json!([name, size, false]))
                .collect::<Vec<_>>(),
        )
    };
    assert_eq!(summary["before"], files([0; 9]), "{summary}");
    // pymavlink's get of `@SYS/versions.txt` (80-byte bursts): a header, the master, then T1 to T6.
    assert_eq!(summary["versions"]["error"], 0, "{summary}");
    let text = summary["versions"]["text"].as_str().unwrap_or_default();
    let boards: Vec<&str> = text
        .lines()
        .map(|line| line.split(' ').next().unwrap_or_default())
        .collect();
    assert_eq!(
        boards,
        ["board", "master", "T1", "T2", "T3", "T4", "T5", "T6"],
        "{summary}"
    );
    assert!(
        text.starts_with("board  family   version  state\nmaster -        "),
        "{summary}"
    );
    // Without signing: refused, saying why, until LBV_UPD_UNSIGNED allows it. pymavlink sends its first writes
    // before the CreateFile's answer, so it reports the NAK of its first write (InvalidSession, 4: no session was
    // opened) rather than the CreateFile's (Fail).
    assert_ne!(summary["unsigned"]["error"], 0, "{summary}");
    assert_eq!(
        summary["unsigned"]["texts"],
        serde_json::json!(["thruster0.lbvu: refused, the link is not signed"]),
        "{summary}"
    );
    assert_eq!(summary["allowed"], 1.0, "{summary}");
    assert_eq!(summary["after"], files([4176, 0, 0, 0, 0, 0, 0, 0, 0]), "{summary}");
    // At the console's 115200 baud a put takes over a second, and the master tells its progress once a second.
    let without_progress = |texts: &serde_json::Value| {
        let texts = texts.as_array().into_iter().flatten();
        let progress = |text: &&serde_json::Value| text.as_str().is_some_and(|text| text.ends_with(" of 4176 bytes"));
        serde_json::Value::from(texts.filter(|text| !progress(text)).cloned().collect::<Vec<_>>())
    };
    assert_eq!(
        without_progress(&summary["put"]["texts"]),
        serde_json::json!([
            "thruster0.lbvu: received, ready to apply",
            "thruster0.lbvu: 4096 B verified, 0 pages kept"
        ]),
        "{summary}"
    );
    assert_eq!(summary["crc"]["vehicle"], summary["crc"]["local"], "{summary}");
    // MAVFTP's error for the NAK: Fail (1), and why.
    assert_eq!(summary["refused"]["error"], 1, "{summary}");
    assert_eq!(
        summary["refused"]["texts"],
        serde_json::json!(["thruster1.lbvu: SeaBotix image, slot is Legacy"]),
        "{summary}"
    );
    // IN_PROGRESS, then ACCEPTED once the thruster runs it, and what it did; DENIED where nothing was received.
    assert_eq!(summary["apply"]["thruster0"], serde_json::json!([5, 0]), "{summary}");
    assert_eq!(summary["apply"]["thruster2"], serde_json::json!([2]), "{summary}");
    assert_eq!(
        support::file_texts(&summary["apply"]["texts"]),
        serde_json::json!([
            "thruster0.lbvu: applying",
            "thruster0.lbvu: marked, restarting into its update",
            "thruster0.lbvu: runs 0.2.0, on trial",
            "thruster0.lbvu: 0.2.0 confirmed",
            "thruster2.lbvu: nothing to apply"
        ]),
        "{summary}"
    );
    // What the sink got is the file pymavlink read, byte for byte; the refused one never reached it.
    let sent = std::fs::read(format!("{local}/thruster0.lbvu")).unwrap();
    let got = std::fs::read(format!("{received}/thruster0.lbvu")).unwrap();
    assert_eq!(sent.len(), 4176);
    assert!(got == sent, "the sink got {} bytes, not the file put", got.len());
    assert!(!std::path::Path::new(&format!("{received}/thruster1.lbvu")).exists());
    // The master's own: IN_PROGRESS, then ACCEPTED from the new image once it has confirmed itself.
    assert_eq!(summary["master"]["results"], serde_json::json!([5, 0]), "{summary}");
    assert_eq!(
        without_progress(&summary["master"]["texts"]),
        serde_json::json!([
            "master.lbvu: received, ready to apply",
            "master.lbvu: applying",
            "master.lbvu: signature good, restarting",
            "master.lbvu: runs 0.2.0, on trial",
            "master.lbvu: 0.2.0 confirmed"
        ]),
        "{summary}"
    );
    let got = std::fs::read(format!("{received}/master.lbvu")).unwrap();
    assert!(got == master, "the sink got {} bytes, not the master's file", got.len());
    println!("script: {summary}\nbench:\n{bench_output}");
}
