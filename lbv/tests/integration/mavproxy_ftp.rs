//! Field update with MAVProxy, a real ground station, over a lossy link (`tests/mavproxy_ftp.py`): `ftp list`,
//! `ftp list /`, `ftp list @SYS` and `ftp get @SYS/versions.txt` (what every board runs),
//! `ftp put` over the link without signing (refused, saying why), `signing setup PASSPHRASE` (the key sent to the
//! vehicle, every frame signed from then on), `ftp put` of a validly signed image older than the one the thruster runs (refused with its reason at its first
//! page) and of one with a payload bit flipped (written, applied, refused by the thruster's bootloader, which
//! starts the image that ran), then `ftp put` of a SeaBotix update file signed with the development key to /update/thruster2.lbvu (which the master
//! writes on into the thruster) with MAVProxy's own link simulator losing a fifth of its requests and of the
//! vehicle's replies (so that blocks are sent again, both those the vehicle never got and those whose ACK was
//! lost), `ftp crc` against `ftp crclocal`, `long MAV_CMD_USER_1 2` to apply (the thruster checks the signature,
//! its bootloader swaps the image in, it runs it), `long MAV_CMD_USER_2 2` to ask what it runs, `ftp rm`. The
//! bench writes what its master's update sink received (`--update-dir`), which must be the file, byte for byte.
//! Last, one put to /update/thrusters-seabotix.lbvu and `long MAV_CMD_USER_1 200` update every SeaBotix thruster,
//! and one to /update/thrusters-legacy.lbvu and `long MAV_CMD_USER_1 201` every Legacy one, each apply's progress in
//! its COMMAND_ACKs and as MAVProxy prints the texts; `@SYS/versions.txt` got again then says every thruster runs
//! the new version; the same file put again is written to
//! none of them, and its apply answers ACCEPTED at once. Runs in real time (about 45 s).
//!
//! Needs python3 with MAVProxy and pymavlink (requirements.txt, which `./test.sh` sets up in target/python); without them this test fails,
//! it does not skip.

use crate::support;

const SCRIPT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/mavproxy_ftp.py");
/// How long the bench runs, s; the script is done well before.
const BENCH_SECONDS: &str = "100";
/// The script's own time limit, s.
const SCRIPT_SECONDS: &str = "90";

#[test]
fn mavproxy_puts_an_update_file_over_a_lossy_link_and_the_sink_gets_it_byte_for_byte() {
    let [gcs, bench_port, observer] = support::free_ports();
    let dir = support::TempDir::new("mavproxy-ftp");
    let (local, received) = (dir.join("local"), dir.join("received"));
    for path in [&local, &received] {
        std::fs::create_dir_all(path).unwrap();
    }
    std::fs::write(format!("{local}/thruster2.lbvu"), support::signed_update_file()).unwrap();
    let seabotix = update_image::Target::ThrusterSeabotix;
    let older = support::update_file(seabotix, update_image::Version::new(0, 0, 9), None);
    std::fs::write(format!("{local}/older.lbvu"), older).unwrap();
    let flipped = support::update_file(seabotix, update_image::Version::new(0, 3, 0), Some(3000));
    std::fs::write(format!("{local}/flipped.lbvu"), flipped).unwrap();
    let fleet = support::update_file(seabotix, update_image::Version::new(0, 3, 0), None);
    std::fs::write(format!("{local}/fleet.lbvu"), fleet).unwrap();
    let legacy = update_image::Target::ThrusterLegacy;
    let fleet_legacy = support::update_file(legacy, update_image::Version::new(0, 3, 0), None);
    std::fs::write(format!("{local}/fleet-legacy.lbvu"), fleet_legacy).unwrap();
    let args = [
        gcs.to_string(),
        observer.to_string(),
        local.clone(),
        SCRIPT_SECONDS.to_string(),
    ];
    let (summary, bench_output) = support::fly_with(
        SCRIPT,
        &args,
        BENCH_SECONDS,
        gcs,
        bench_port,
        "mavproxy pymavlink",
        &["--update-dir", &received],
    );
    assert_eq!(
        summary["steps"],
        serde_json::json!([
            "connect",
            "list",
            "versions",
            "unsigned",
            "signing",
            "older",
            "flipped",
            "lossy",
            "crc",
            "listed",
            "apply",
            "version",
            "remove",
            "fleet",
            "fleet_legacy",
            "versions_after",
            "again"
        ]),
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
                .map(|(name, size)| serde_json::json!([name, size]))
                .collect::<Vec<_>>(),
        )
    };
    assert_eq!(summary["list"], files([0; 9]), "{summary}");
    // `/` holds `update`, `@SYS` and `@PARAM` (MAVProxy prints a listing sorted), `@SYS` the versions file, whose length the
    // listing gives and `ftp get` reads: the bench vehicle's six thrusters, SeaBotix and Legacy in turn, and its
    // master, each on its first image.
    let before = versions(&summary["versions"], &summary);
    let first = ["0.1.0"; 6];
    assert_eq!(before, boards(first), "{summary}");
    // Over the link without signing: refused at its CreateFile, saying why; then MAVProxy sets signing up.
    let unsigned = &summary["unsigned"];
    assert_eq!(
        unsigned["texts"],
        serde_json::json!(["thruster2.lbvu: refused, the link is not signed"]),
        "{summary}"
    );
    assert!(
        unsigned["failed"].as_array().is_some_and(|failed| !failed.is_empty()),
        "{summary}"
    );
    assert_eq!(
        summary["signing"],
        serde_json::json!({"signed": true, "mavproxy": true}),
        "{summary}"
    );
    // The older image: refused at its first page, saying why; MAVProxy's put ends in a failed write.
    let older = &summary["older"];
    assert_eq!(
        older["texts"],
        serde_json::json!([
            "thruster2.lbvu: 0.0.9 is older than the 0.1.0 that",
            "thruster2.lbvu: runs (not a rollback)"
        ]),
        "{summary}"
    );
    assert!(
        older["failed"].as_array().is_some_and(|failed| !failed.is_empty()),
        "{summary}"
    );
    // The flipped one: written, marked, refused by the bootloader after the restart; the thruster runs 0.1.0.
    let flipped = &summary["flipped"];
    assert_eq!(
        flipped["results"],
        serde_json::json!([5, 4]),
        "IN_PROGRESS, FAILED: {summary}"
    );
    assert!(
        flipped["texts"]
            .as_array()
            .is_some_and(|texts| texts.contains(&"T3: refused by its bootloader: signature".into())),
        "{summary}"
    );
    assert_eq!(
        support::file_texts(&flipped["version"]),
        serde_json::json!(["thruster2.lbvu: runs 0.1.0, dev key"]),
        "{summary}"
    );
    let put = &summary["put"];
    assert_eq!((&put["sent"], &put["bytes"]), (&4176.into(), &4176.into()), "{summary}");
    assert_eq!(put["failed"], serde_json::json!([]), "{summary}");
    assert_eq!(
        put["texts"].as_array().and_then(|texts| texts.last()),
        Some(&"thruster2.lbvu: 4096 B verified, 0 pages kept".into()),
        "{summary}"
    );
    // The loss was there both ways, and MAVProxy sent blocks again.
    assert!(put["lost_requests"].as_u64() > Some(0), "{summary}");
    assert!(put["lost_replies"].as_u64() > Some(0), "{summary}");
    assert!(
        put["sent_again"].as_array().is_some_and(|again| !again.is_empty()),
        "{summary}"
    );
    // `ftp crc` and `ftp crclocal` print the same CRC32.
    let crc = &summary["crc"];
    assert!(
        crc["seen"]
            .as_array()
            .is_some_and(|seen| seen.len() == 2 && seen.iter().all(|c| *c == crc["vehicle"])),
        "{summary}"
    );
    assert_eq!(summary["listed"], files([0, 0, 4176, 0, 0, 0, 0, 0, 0]), "{summary}");
    assert_eq!(
        summary["apply"]["results"],
        serde_json::json!([5, 0]),
        "IN_PROGRESS, ACCEPTED: {summary}"
    );
    assert_eq!(
        support::file_texts(&summary["apply"]["texts"]),
        serde_json::json!([
            "thruster2.lbvu: applying",
            "thruster2.lbvu: marked, restarting into its update",
            "thruster2.lbvu: runs 0.2.0, on trial",
            "thruster2.lbvu: 0.2.0 confirmed"
        ]),
        "{summary}"
    );
    assert_eq!(summary["version"]["results"], serde_json::json!([5, 0]), "{summary}");
    assert_eq!(
        support::file_texts(&summary["version"]["texts"]),
        serde_json::json!(["thruster2.lbvu: runs 0.2.0, dev key"]),
        "{summary}"
    );
    assert_eq!(summary["remove"]["apply"], 2, "DENIED once removed: {summary}");
    // The denial's own text may come in before the script stops listening, or after.
    let removed = &summary["remove"]["texts"];
    assert!(
        *removed == serde_json::json!(["thruster2.lbvu: removed"])
            || *removed == serde_json::json!(["thruster2.lbvu: removed", "thruster2.lbvu: nothing to apply"]),
        "{summary}"
    );
    // One put and one apply per family, three thrusters each: IN_PROGRESS, its progress as they restart and
    // confirm, ACCEPTED.
    for (step, members) in [("fleet", [1, 3, 5]), ("fleet_legacy", [2, 4, 6])] {
        let fleet = &summary[step];
        let results = fleet["results"].as_array().unwrap();
        assert!(
            results.first() == Some(&5.into())
                && results.last() == Some(&0.into())
                && results[1..results.len() - 1].iter().all(|r| *r == 5),
            "{step}: {summary}"
        );
        let progress: Vec<u64> = fleet["progress"]
            .as_array()
            .unwrap()
            .iter()
            .filter_map(|p| p.as_u64())
            .collect();
        assert!(
            progress.windows(2).all(|pair| pair[0] <= pair[1]) && progress.iter().any(|p| *p > 0),
            "{step}: {summary}"
        );
        assert!(
            fleet["printed"].as_array().is_some_and(|printed| !printed.is_empty()),
            "{step}: {summary}"
        );
        for n in members {
            let confirmed = format!("T{n}: 0.3.0 confirmed");
            assert!(
                fleet["texts"].as_array().unwrap().contains(&confirmed.into()),
                "{step}: {summary}"
            );
        }
    }
    // Got again after the families' applies: every thruster runs 0.3.0.
    let after = versions(&summary["versions_after"], &summary);
    assert_eq!(after, boards(["0.3.0"; 6]), "{summary}");
    // The same file put again: every SeaBotix thruster runs it, so nothing is written and the apply has nothing to do.
    let again = &summary["again"];
    assert_eq!(
        again["put"],
        serde_json::json!(["Sent file of length 4176"]),
        "{summary}"
    );
    assert_eq!(again["results"], serde_json::json!([0]), "{summary}");
    let texts = again["texts"].as_array().unwrap();
    for told in [
        "T1: runs 0.3.0 already",
        "T3: runs 0.3.0 already",
        "T5: runs 0.3.0 already",
        "thrusters-seabotix.lbvu: all run it already",
    ] {
        assert!(texts.contains(&told.into()), "{summary}");
    }
    // Whatever was lost on the way, the sink got the file, byte for byte.
    let sent = std::fs::read(format!("{local}/thruster2.lbvu")).unwrap();
    let got = std::fs::read(format!("{received}/thruster2.lbvu")).unwrap();
    assert_eq!(sent.len(), 4176);
    assert!(got == sent, "the sink got {} bytes, not the file put", got.len());
    println!("mavproxy: {summary}\nbench:\n{bench_output}");
}

/// The lines of `@SYS/versions.txt` as a step of the script got it, each line's fields (board, family, version,
/// state), after checking the listings that came with it: `/` and `@SYS` (its length, which `ftp get` wrote).
fn versions(got: &serde_json::Value, summary: &serde_json::Value) -> Vec<[String; 4]> {
    assert_eq!(
        got["root"],
        serde_json::json!(["@PARAM", "@SYS", "update"]),
        "{summary}"
    );
    let text = got["text"].as_str().unwrap();
    assert_eq!(
        got["sys"],
        serde_json::json!([["versions.txt", text.len()]]),
        "{summary}"
    );
    assert_eq!(got["wrote"], text.len(), "{summary}");
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("board  family   version  state"), "{summary}");
    lines
        .map(|line| {
            let fields: Vec<String> = line.split_whitespace().map(str::to_owned).collect();
            fields
                .try_into()
                .unwrap_or_else(|fields| panic!("{fields:?}: {summary}"))
        })
        .collect()
}

/// The bench vehicle's boards, confirmed: its master on 0.1.0, T1 to T6 of SeaBotix and Legacy in turn on
/// `thrusters`.
fn boards(thrusters: [&str; 6]) -> Vec<[String; 4]> {
    let line = |board: &str, family: &str, version: &str| [board, family, version, "confirmed"].map(str::to_owned);
    let families = ["SeaBotix", "Legacy"].iter().cycle();
    std::iter::once(line("master", "-", "0.1.0"))
        .chain(
            (1..)
                .zip(families)
                .zip(thrusters)
                .map(|((n, family), version)| line(&format!("T{n}"), family, version)),
        )
        .collect()
}
