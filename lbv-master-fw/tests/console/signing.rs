//! MAVLink 2 signing on the console, checked against two independent implementations: pymavlink (a ground
//! station's side: SETUP_SIGNING, signed commands, and reading what the master signs) and mavlink-core's own
//! signing (its `mav2-message-signing` feature, which needs std and so runs on the host only).
//!
//! Needs python3 with pymavlink (`pip install pymavlink`); without it these tests fail, they do not skip.

use std::collections::BTreeMap;
use std::io::Write as _;
use std::process::{Command as Process, Stdio};
use std::time::{SystemTime, UNIX_EPOCH};

use crate::support::{Line, clock, run_console, run_rx_requests, run_tx};
use embassy_time::{Duration, Instant};
use lbv_master_fw::console::framing::{Event, FrameParser};
use lbv_master_fw::console::lbv::MavMessage;
use lbv_master_fw::console::signing::SigningKey;
use lbv_master_fw::console::{ConsoleConfig, ConsoleStats, inbound};
use lbv_master_fw::shared::{Command, Shared};
use lbv_master_fw::vehicle::VehicleConfig;
use lbv_station::GCS_HEARTBEAT;
use mavlink_core::{MAVLinkV2MessageRaw, MavHeader, SigningConfig, SigningData};
use serde_json::Value;

const PEER: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/mav_peer.py");
const KEY: [u8; 32] = [0x11; 32];

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn unhex(hex: &str) -> Vec<u8> {
    (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
        .collect()
}

/// Run the pymavlink peer; its stdout as JSON.
fn peer(args: &[&str], input: &str) -> Value {
    let mut child = Process::new("python3")
        .arg(PEER)
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|error| panic!("cannot run python3 ({error}): install Python 3 and pymavlink"));
    if let Some(mut stdin) = child.stdin.take() {
        let _ = stdin.write_all(input.as_bytes());
    }
    let output = child.wait_with_output().unwrap();
    assert!(
        output.status.success(),
        "mav_peer.py {args:?} failed (is pymavlink installed?): {}",
        String::from_utf8_lossy(&output.stderr)
    );
    serde_json::from_slice(&output.stdout).unwrap()
}

/// pymavlink's frames for a signed session, by name, signed from `timestamp` on.
fn ground_station(timestamp: u64) -> BTreeMap<String, Vec<u8>> {
    peer(&["signing", &hex(&KEY), &timestamp.to_string()], "")
        .as_object()
        .unwrap()
        .iter()
        .map(|(name, frame)| (name.clone(), unhex(frame.as_str().unwrap())))
        .collect()
}

/// Now in signing units: 10 us since 2015-01-01.
fn signing_now() -> u64 {
    let since_1970 = SystemTime::now().duration_since(UNIX_EPOCH).unwrap();
    (since_1970.as_micros() as u64 - 1_420_070_400_000_000) / 10
}

#[test]
fn after_setup_signing_only_signed_commands_pass_and_everything_sent_is_signed() {
    let frames = ground_station(1_000_000);
    let at = |ms: u64, name: &str| (ms, frames[name].clone());
    let line = Line::new(vec![
        at(0, "heartbeat_unsigned"),
        // Set up over the console itself (the ST-LINK's USB link is the secure channel the spec asks for).
        at(10, "setup"),
        // Unsigned, and signed with another key: refused.
        at(1000, "heartbeat_unsigned"),
        at(1010, "arm_unsigned"),
        at(1020, "arm_other_key"),
        // Signed with the key: accepted; the same frame again is a replay.
        at(2000, "heartbeat_signed"),
        at(2010, "arm_signed"),
        at(2020, "arm_signed"),
        at(3000, "heartbeat_signed_later"),
        at(3010, "disarm_signed"),
    ]);
    let mut armed_at = Vec::new();
    let mut counters = None;
    let mut key = None;
    let sent = run_console(
        VehicleConfig::DEFAULT.defaults(),
        line,
        Duration::from_millis(3500),
        |now, shared, stats| {
            if shared.vehicle.try_get().is_some_and(|v| v.armed) {
                armed_at.push(now);
            }
            counters = Some(stats.snapshot());
            key = shared.settings.try_get().and_then(|s| s.signing);
        },
    );
    assert_eq!(
        key,
        Some(SigningKey {
            secret: KEY,
            timestamp: 1_000_000
        })
    );
    let counters = counters.unwrap();
    assert_eq!(
        (counters.unsigned, counters.bad_signatures, counters.replayed),
        (2, 1, 1),
        "{counters:?}"
    );
    // Armed from the signed arm to the signed disarm, and only then.
    assert!(!armed_at.is_empty());
    assert!(armed_at.first().unwrap() >= &Instant::from_millis(2010));
    assert!(armed_at.last().unwrap() <= &Instant::from_millis(3012));

    // What the master sent, read by pymavlink with the key: the frames before the key are unsigned (pymavlink
    // refuses them), every frame after it signed, with timestamps pymavlink accepts.
    let decoded = peer(&["decode", &hex(&KEY)], &hex(&sent));
    // ESC_INFO and ESC_STATUS are newer than pymavlink's XML: it cannot check their signatures.
    let decoded: Vec<Value> = decoded
        .as_array()
        .unwrap()
        .iter()
        .filter(|m| m["_type"] != "UNKNOWN")
        .cloned()
        .collect();
    let first_signed = decoded.iter().position(|m| m["_type"] != "BAD_DATA").unwrap();
    assert!(
        first_signed <= 6,
        "only the first telemetry went out unsigned: {first_signed}"
    );
    let after: Vec<&Value> = decoded[first_signed..].iter().collect();
    assert!(after.len() > 20);
    assert!(after.iter().all(|m| m["_signed"] == true), "{after:#?}");
    let acks: Vec<(u64, u64)> = after
        .iter()
        .filter(|m| m["_type"] == "COMMAND_ACK")
        .map(|m| (m["command"].as_u64().unwrap(), m["result"].as_u64().unwrap()))
        .collect();
    assert_eq!(acks, [(400, 0), (400, 0)], "the signed arm and disarm, accepted");
    let texts: Vec<&str> = after
        .iter()
        .filter(|m| m["_type"] == "STATUSTEXT")
        .filter_map(|m| m["text"].as_str())
        .collect();
    assert!(texts.contains(&"Signing on"), "{texts:?}");
}

#[test]
fn mavlink_core_verifies_what_the_console_signs() {
    let _clock = clock();
    let shared = Shared::new();
    let stats = ConsoleStats::new();
    let mut settings = VehicleConfig::DEFAULT.defaults();
    settings.signing = Some(SigningKey {
        secret: KEY,
        timestamp: signing_now(),
    });
    crate::support::publish(&shared, settings);
    let bytes = run_tx(
        &ConsoleConfig::DEFAULT,
        &shared,
        &stats,
        Duration::from_millis(1100),
        |_| {},
    );
    let verifier = SigningData::from_config(SigningConfig::new(KEY, 0, false, false));
    let wrong = SigningData::from_config(SigningConfig::new([0x22; 32], 0, false, false));
    let mut parser = FrameParser::new();
    let mut checked = 0;
    for chunk in bytes.chunks(64) {
        assert_eq!(parser.push(chunk), chunk.len());
        while let Some(event) = parser.next(inbound::extra_crc) {
            let Event::Frame(frame) = event else {
                panic!("{event:?}")
            };
            assert!(frame.signed);
            let mut raw = MAVLinkV2MessageRaw::new();
            raw.as_mut_slice()[..frame.bytes.len()].copy_from_slice(frame.bytes);
            assert!(verifier.verify_signature(&raw), "frame {checked}");
            assert!(!wrong.verify_signature(&raw));
            checked += 1;
        }
    }
    assert!(checked >= 10, "{checked} frames");
}

#[test]
fn the_console_accepts_what_mavlink_core_signs() {
    let mut settings = VehicleConfig::DEFAULT.defaults();
    settings.signing = Some(SigningKey {
        secret: KEY,
        timestamp: signing_now(),
    });
    let shared = Shared::new();
    crate::support::publish(&shared, settings);
    let signer = SigningData::from_config(SigningConfig::new(KEY, 3, true, false));
    let header = MavHeader {
        system_id: 255,
        component_id: 190,
        sequence: 0,
    };
    let mut bytes = Vec::new();
    for _ in 0..3 {
        mavlink_core::write_v2_msg_signed(&mut bytes, header, &MavMessage::HEARTBEAT(GCS_HEARTBEAT), Some(&signer))
            .unwrap();
    }
    let unsigned_too = [bytes.clone(), crate::support::v2(255, 190, 0, &GCS_HEARTBEAT)].concat();
    let (requests, counters) = run_rx_requests(&unsigned_too, 64, &ConsoleConfig::DEFAULT, &shared);
    assert_eq!(requests.len(), 3);
    assert!(
        requests
            .iter()
            .all(|r| r.command == Command::Heartbeat && r.from.system == 255)
    );
    assert_eq!(
        (counters.unsigned, counters.bad_signatures, counters.replayed),
        (1, 0, 0)
    );
}

#[test]
fn with_a_key_an_unsigned_ftp_request_or_apply_is_refused_like_any_unsigned_frame() {
    use lbv_master_fw::console::lbv::{COMMAND_LONG_DATA, FILE_TRANSFER_PROTOCOL_DATA};
    use lbv_master_fw::shared::Outgoing;

    let mut settings = VehicleConfig::DEFAULT.defaults();
    settings.signing = Some(SigningKey {
        secret: KEY,
        timestamp: signing_now(),
    });
    let shared = Shared::new();
    crate::support::publish(&shared, settings);
    let signer = SigningData::from_config(SigningConfig::new(KEY, 3, true, false));
    let header = MavHeader {
        system_id: 255,
        component_id: 190,
        sequence: 0,
    };
    // ListDirectory "/update", as MAVFTP packs it.
    let mut payload = [0u8; 251];
    payload[..5].copy_from_slice(&[1, 0, 0, 3, 7]);
    payload[12..19].copy_from_slice(b"/update");
    let list = MavMessage::FILE_TRANSFER_PROTOCOL(FILE_TRANSFER_PROTOCOL_DATA {
        target_network: 0,
        target_system: 1,
        target_component: 1,
        payload,
    });
    let apply = COMMAND_LONG_DATA {
        target_system: 1,
        target_component: 1,
        command: 31010,
        param1: 0.0,
        ..COMMAND_LONG_DATA::DEFAULT
    };
    let mut bytes = Vec::new();
    mavlink_core::write_v2_msg_signed(&mut bytes, header, &list, Some(&signer)).unwrap();
    mavlink_core::write_v2_msg(&mut bytes, header, &list).unwrap();
    bytes.extend(crate::support::v2(255, 190, 2, &apply));
    let (requests, counters) = run_rx_requests(&bytes, 64, &ConsoleConfig::DEFAULT, &shared);
    assert!(requests.is_empty());
    assert_eq!((counters.unsigned, counters.frames_in), (2, 1));
    // Only the signed listing was served.
    let mut served = Vec::new();
    while let Ok(message) = shared.outbox.try_receive() {
        served.push(message);
    }
    let [Outgoing::Ftp { reply, .. }] = served.as_slice() else {
        panic!("{served:?}");
    };
    assert_eq!(
        [
            reply.payload(&lbv_master_fw::update::Contents::NOTHING)[3],
            reply.payload(&lbv_master_fw::update::Contents::NOTHING)[5]
        ],
        [128, 3],
        "{served:?}"
    );
}
