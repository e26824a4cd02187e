//! Cross-check against an independent MAVLink implementation: pymavlink (`tests/mav_peer.py`) builds the frames
//! a ground station sends, and decodes the frames the console sends.
//!
//! Needs python3 with pymavlink (`pip install pymavlink`); without it these tests fail, they do not skip.

use std::collections::BTreeMap;
use std::io::Write as _;
use std::process::{Command as Process, Stdio};

use crate::support::{clock, run_rx, run_tx};
use embassy_time::Duration;
use lbv_master_fw::console::{ConsoleConfig, ConsoleStats, Received, Receiver};
use lbv_master_fw::mixer::FrameKind;
use lbv_master_fw::mixer::ManualInput;
use lbv_master_fw::params::{ParamType, Settings};
use lbv_master_fw::shared::{
    AckResult, BatterySummary, Command, Interval, LinkHealth, Message, Outgoing, Sender, Severity, Shared, Text,
    ThrusterReport, UpdateCommand, UpdateRequest, VehicleState,
};
use lbv_master_fw::update::FtpAnswer;
use serde_json::Value;
use tmc_proto::{Faults, MotorKind, SeaBotixStatus, Speed, Status};

const PEER: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/mav_peer.py");

/// Run the peer with `args` and `input` on stdin; its stdout. Panics (fails the test) when python3 or pymavlink
/// is missing.
fn peer(args: &[&str], input: &str) -> String {
    let child = Process::new("python3")
        .arg(PEER)
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn();
    let mut child = match child {
        Ok(child) => child,
        Err(error) => panic!("cannot run python3 ({error}): install Python 3 and `pip install pymavlink`"),
    };
    // A peer that exits early (pymavlink missing) closes its stdin: its exit status tells why.
    if let Some(mut stdin) = child.stdin.take() {
        let _ = stdin.write_all(input.as_bytes());
    }
    let output = child.wait_with_output().unwrap();
    assert!(
        output.status.success(),
        "mav_peer.py {args:?} failed (is pymavlink installed? `pip install pymavlink`): {}",
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8(output.stdout).unwrap()
}

fn hex_decode(hex: &str) -> Vec<u8> {
    (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
        .collect()
}

fn hex_encode(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// The frames pymavlink built, by name.
fn pymavlink_frames() -> BTreeMap<String, Vec<u8>> {
    let out = peer(&["emit"], "");
    let json: BTreeMap<String, String> = serde_json::from_str::<Value>(&out)
        .unwrap()
        .as_object()
        .unwrap()
        .iter()
        .map(|(k, v)| (k.clone(), v.as_str().unwrap().to_owned()))
        .collect();
    json.into_iter().map(|(k, v)| (k, hex_decode(&v))).collect()
}

fn param_id(name: &str) -> [u8; 16] {
    let mut id = [0u8; 16];
    id[..name.len()].copy_from_slice(name.as_bytes());
    id
}

#[test]
fn pymavlink_is_installed() {
    peer(&["check"], "");
}

/// The frames for the update server ([`ftp_frames_and_the_apply_command_go_to_the_update_server`]).
const UPDATE_FRAMES: [&str; 6] = [
    "ftp_list",
    "ftp_write",
    "ftp_other_system",
    "ftp_v1",
    "apply_update",
    "query_version",
];

/// A MAVLink FTP payload as pymavlink's MAVFTP packs it.
fn ftp_payload(seq: u16, session: u8, opcode: u8, offset: u32, data: &[u8]) -> [u8; 251] {
    let mut payload = [0u8; 251];
    payload[..2].copy_from_slice(&seq.to_le_bytes());
    payload[2] = session;
    payload[3] = opcode;
    payload[4] = data.len() as u8;
    payload[8..12].copy_from_slice(&offset.to_le_bytes());
    payload[12..12 + data.len()].copy_from_slice(data);
    payload
}

#[test]
fn ftp_frames_and_the_apply_command_go_to_the_update_server() {
    let frames = pymavlink_frames();
    let gcs = Sender {
        system: 255,
        component: 190,
    };
    let write_data: Vec<u8> = (1..240).collect();
    let expected = [
        (
            "ftp_list",
            Some(UpdateCommand::Ftp(ftp_payload(7, 3, 3, 0, b"/update"))),
        ),
        // To component 0: any component of ours. A full payload: nothing trimmed.
        (
            "ftp_write",
            Some(UpdateCommand::Ftp(ftp_payload(8, 3, 7, 239, &write_data))),
        ),
        ("ftp_other_system", None),
        ("ftp_v1", Some(UpdateCommand::Ftp(ftp_payload(10, 3, 3, 0, b"/")))),
        ("apply_update", Some(UpdateCommand::Apply(Some(2)))),
        ("query_version", Some(UpdateCommand::QueryVersion(Some(4)))),
    ];
    assert_eq!(expected.map(|(name, _)| name), UPDATE_FRAMES);
    for (name, what) in expected {
        let mut receiver = Receiver::new();
        let stats = ConsoleStats::new();
        assert_eq!(receiver.push(&frames[name]), frames[name].len());
        let got = receiver.next(&ConsoleConfig::DEFAULT, None, &stats);
        let want = what.map_or(Received::Nothing, |what| {
            Received::Update(UpdateRequest { from: gcs, what })
        });
        assert_eq!(got, Some(want), "{name}");
        assert_eq!(stats.snapshot().frames_in, 1, "{name}");
    }
}

#[test]
fn frames_built_by_pymavlink_give_the_right_commands() {
    let frames = pymavlink_frames();
    let expected: Vec<(&str, Option<Command>)> = vec![
        ("heartbeat_gcs", Some(Command::Heartbeat)),
        ("heartbeat_vehicle", None),
        (
            "manual",
            Some(Command::Manual(
                ManualInput {
                    x: 100,
                    y: -200,
                    z: 700,
                    r: -300,
                },
                5,
            )),
        ),
        ("manual_other", None),
        ("arm", Some(Command::Arm(true))),
        ("disarm", Some(Command::Arm(false))),
        (
            "motor_test",
            Some(Command::MotorTest {
                motor: 3,
                percent: -40,
                duration: Duration::from_millis(4500),
            }),
        ),
        ("motor_test_pwm", Some(Command::Unsupported { command: 209 })),
        ("unknown_command", Some(Command::Unsupported { command: 31012 })),
        ("arm_other_system", None),
        ("param_list", Some(Command::ParamRequestList)),
        ("set_mode_manual", Some(Command::SetMode { custom_mode: Some(19) })),
        ("set_mode_alt_hold", Some(Command::SetMode { custom_mode: Some(2) })),
        ("set_mode_base_only", Some(Command::SetMode { custom_mode: None })),
        (
            "mission_list_fence",
            Some(Command::MissionRequestList { mission_type: 1 }),
        ),
        ("mission_list_other", None),
        (
            "param_read_name",
            Some(Command::ParamRequestRead {
                id: param_id("THR_MAX"),
                index: -1,
            }),
        ),
        (
            "param_read_index",
            Some(Command::ParamRequestRead { id: [0; 16], index: 3 }),
        ),
        (
            "param_set",
            Some(Command::ParamSet {
                id: param_id("THR_MAX"),
                value: 0.75,
                param_type: 9,
            }),
        ),
        (
            "param_set_int8",
            Some(Command::ParamSet {
                id: param_id("FS_PILOT_INPUT"),
                value: 2.0,
                param_type: 2,
            }),
        ),
        ("arm_half", Some(Command::Unsupported { command: 400 })),
        ("arm_int", Some(Command::Arm(true))),
        (
            "request_version",
            Some(Command::RequestMessage {
                command: 512,
                message: Some(Message::AutopilotVersion),
                first: 0,
            }),
        ),
        (
            "request_version_int",
            Some(Command::RequestMessage {
                command: 512,
                message: Some(Message::AutopilotVersion),
                first: 0,
            }),
        ),
        (
            "request_capabilities",
            Some(Command::RequestMessage {
                command: 520,
                message: Some(Message::AutopilotVersion),
                first: 0,
            }),
        ),
        (
            "request_home",
            Some(Command::RequestMessage {
                command: 512,
                message: None,
                first: 0,
            }),
        ),
        (
            "esc_status_off",
            Some(Command::MessageInterval {
                message: Some(Message::EscStatus),
                interval: Some(Interval::Off),
            }),
        ),
        ("arm_v1", Some(Command::Arm(true))),
        (
            "manual_v1",
            Some(Command::Manual(
                ManualInput {
                    x: -1000,
                    y: 1000,
                    z: 0,
                    r: 1000,
                },
                0,
            )),
        ),
    ];
    assert_eq!(
        frames.len(),
        expected.len() + 1 + UPDATE_FRAMES.len(),
        "one unknown message and the update server's besides"
    );
    for (name, command) in &expected {
        let frame = &frames[*name];
        let (commands, counters) = run_rx(frame, 64, &ConsoleConfig::DEFAULT);
        assert_eq!(commands, command.iter().copied().collect::<Vec<_>>(), "{name}");
        assert_eq!((counters.frames_in, counters.bad_frames), (1, 0), "{name}");
    }

    // All of them in one stream, with noise and a message outside the dialect (skipped whole, since a frame
    // follows it) in between.
    let mut stream = vec![];
    for (name, _) in &expected {
        stream.extend(&frames[*name]);
        stream.extend([0x00, 0xFD, 0x13, 0x37]);
        stream.extend(&frames["system_time"]);
    }
    // A last frame after the last unknown message (a heartbeat: a second parameter list at once would be over the
    // requester's allowance).
    stream.extend(&frames["heartbeat_gcs"]);
    let (commands, counters) = run_rx(&stream, 7, &ConsoleConfig::DEFAULT);
    let mut want: Vec<Command> = expected.iter().filter_map(|(_, c)| *c).collect();
    want.push(Command::Heartbeat);
    assert_eq!(commands, want);
    assert_eq!(counters.frames_in as usize, expected.len() + 1);
    assert_eq!(counters.unknown_messages as usize, expected.len());
    assert!(counters.corrupt() as usize >= expected.len(), "{counters:?}");
}

fn thruster(step: i8, current: u8, temperature: u8, good: u32) -> ThrusterReport {
    ThrusterReport {
        health: LinkHealth {
            online: true,
            good,
            timeout: 2,
            ..LinkHealth::default()
        },
        status: Some(Status::SeaBotix(SeaBotixStatus {
            revision: 0,
            motor: MotorKind::Brushless,
            current_limited: false,
            faults: Faults::NONE,
            current_deciamps: current,
            speed: Speed::new(step).unwrap(),
            temperature_c: temperature,
        })),
    }
}

/// Messages of type `name` in pymavlink's decoding.
fn of_type<'a>(decoded: &'a [Value], name: &str) -> Vec<&'a Value> {
    decoded.iter().filter(|m| m["_type"] == name).collect()
}

#[test]
fn pymavlink_decodes_what_the_console_sends() {
    let _clock = clock();
    let shared = Shared::new();
    let stats = ConsoleStats::new();
    for (i, watch) in shared.thrusters.iter().enumerate().take(6) {
        watch.sender().send(thruster(
            -102 + 20 * i as i8,
            10 + i as u8,
            30 + i as u8,
            1000 * i as u32,
        ));
    }
    shared.battery.sender().send(BatterySummary {
        info: Some(bat_proto::BatteryInfo {
            voltage_decivolts: 252,
            charge_percent: Some(87),
            current_deciamps: Some(123),
            temperature_decicelsius: Some(-15),
        }),
        status: None,
        alarms: Some(bat_proto::BmsAlarms::NONE),
        frames: 40,
        errors: 1,
        ..BatterySummary::default()
    });
    shared.settings.sender().send(Settings::defaults(FrameKind::Lbv300_6));
    let mut text = Text::new();
    text.push_str("LBV master ready").unwrap();
    let config = ConsoleConfig {
        uid: *b"0123456789AB",
        ..ConsoleConfig::DEFAULT
    };
    let bytes = run_tx(&config, &shared, &stats, Duration::from_millis(1100), |elapsed| {
        if elapsed == Duration::from_millis(100) {
            shared
                .outbox
                .try_send(Outgoing::CommandAck {
                    command: 209,
                    result: AckResult::Denied,
                    to: Sender {
                        system: 255,
                        component: 190,
                    },
                })
                .unwrap();
            shared.say(Severity::Critical, text.clone());
            shared
                .outbox
                .try_send(Outgoing::ParamValue {
                    id: param_id("SIXTEEN_CHARS_ID"),
                    value: -2.5,
                    param_type: ParamType::Real32,
                    index: 4,
                    count: 9,
                })
                .unwrap();
            shared
                .outbox
                .try_send(Outgoing::ParamValue {
                    id: param_id("SYSID_MYGCS"),
                    value: 255.0,
                    param_type: ParamType::Int16,
                    index: 4,
                    count: 9,
                })
                .unwrap();
            shared
                .outbox
                .try_send(Outgoing::Message {
                    message: Message::AutopilotVersion,
                    first: 0,
                })
                .unwrap();
            shared
                .outbox
                .try_send(Outgoing::MissionCount {
                    to: Sender {
                        system: 255,
                        component: 190,
                    },
                    mission_type: 2,
                })
                .unwrap();
            // An FTP reply of the update server: a listing entry to a MAVFTP client.
            let mut reply = [0u8; 40];
            reply[..12].copy_from_slice(&[8, 0, 3, 128, 21, 3, 0, 0, 0, 0, 0, 0]);
            reply[12..33].copy_from_slice(b"Fthruster0.lbvu\t4176\0");
            shared
                .outbox
                .try_send(Outgoing::Ftp {
                    to: Sender {
                        system: 255,
                        component: 190,
                    },
                    reply: FtpAnswer::Reply(reply),
                })
                .unwrap();
            shared.outbox.try_send(versions_read()).unwrap();
        }
        if elapsed == Duration::from_millis(600) {
            shared.vehicle.sender().send(VehicleState {
                armed: true,
                console_alive: true,
                refused: 0,
                armable: true,
                failsafe: false,
                param_type_mismatches: 0,
                operator: 255,
            });
        }
    });
    let decoded: Vec<Value> = serde_json::from_str(&peer(&["decode"], &hex_encode(&bytes))).unwrap();
    assert!(
        of_type(&decoded, "BAD_DATA").is_empty(),
        "pymavlink rejected frames: {decoded:#?}"
    );
    assert_eq!(decoded.len() as u32, stats.snapshot().frames_out);
    // pymavlink's XML predates ESC_INFO and ESC_STATUS: it sees well-formed frames it cannot read.
    for m in of_type(&decoded, "UNKNOWN") {
        assert!([290, 291].contains(&m["_id"].as_u64().unwrap()), "{m}");
    }
    for (n, m) in decoded.iter().enumerate().filter(|(_, m)| m["_type"] != "UNKNOWN") {
        assert_eq!((m["_sys"].as_u64(), m["_comp"].as_u64()), (Some(1), Some(1)));
        assert_eq!(m["_seq"].as_u64(), Some(n as u64 % 256));
    }

    let counts = of_type(&decoded, "MISSION_COUNT");
    assert_eq!(counts.len(), 1, "{decoded:#?}");
    let count = counts[0];
    assert_eq!(
        (
            &count["target_system"],
            &count["target_component"],
            &count["count"],
            &count["mission_type"]
        ),
        (&Value::from(255), &Value::from(190), &Value::from(0), &Value::from(2)),
        "an empty rally point list, to who asked"
    );

    let heartbeats = of_type(&decoded, "HEARTBEAT");
    assert_eq!(heartbeats.len(), 2);
    for (hb, armed) in heartbeats.iter().zip([false, true]) {
        assert_eq!(hb["type"], 12, "MAV_TYPE_SUBMARINE");
        assert_eq!(hb["autopilot"], 3, "MAV_AUTOPILOT_ARDUPILOTMEGA");
        assert_eq!(hb["custom_mode"], 19, "ArduSub MANUAL");
        assert_eq!(hb["mavlink_version"], 3);
        let base_mode = hb["base_mode"].as_u64().unwrap();
        assert_eq!(base_mode & 0x80 != 0, armed, "MAV_MODE_FLAG_SAFETY_ARMED");
        assert_eq!(base_mode & 0x7F, 0x41, "CUSTOM_MODE_ENABLED | MANUAL_INPUT_ENABLED");
        assert_eq!(hb["system_status"], if armed { 4 } else { 3 });
    }

    let sys = of_type(&decoded, "SYS_STATUS");
    assert_eq!(sys.len(), 2);
    let sys = sys[0];
    assert_eq!(sys["voltage_battery"], 25_200);
    assert_eq!(sys["current_battery"], 1230);
    assert_eq!(sys["battery_remaining"], 87);
    assert_eq!(sys["errors_count1"], 12, "6 thrusters x 2 timeouts");
    let motor_outputs = 0x8000u64;
    let battery = 0x0200_0000u64;
    for field in [
        "onboard_control_sensors_present",
        "onboard_control_sensors_enabled",
        "onboard_control_sensors_health",
    ] {
        let bits = sys[field].as_u64().unwrap();
        assert_eq!(bits & (motor_outputs | battery), motor_outputs | battery, "{field}");
    }

    let bat = of_type(&decoded, "BATTERY_STATUS");
    assert_eq!(bat.len(), 2);
    let bat = bat[0];
    assert_eq!(bat["id"], 0);
    assert_eq!(bat["battery_function"], 1, "MAV_BATTERY_FUNCTION_ALL");
    assert_eq!(bat["type"], 3, "MAV_BATTERY_TYPE_LION");
    assert_eq!(bat["temperature"], -150);
    let mut voltages = vec![Value::from(25_200)];
    voltages.extend(std::iter::repeat_n(Value::from(u16::MAX), 9));
    assert_eq!(bat["voltages"], Value::Array(voltages));
    assert_eq!(bat["current_battery"], 1230);
    assert_eq!(
        (&bat["current_consumed"], &bat["energy_consumed"]),
        (&Value::from(-1), &Value::from(-1))
    );
    assert_eq!(bat["battery_remaining"], 87);
    assert_eq!(bat["charge_state"], 1, "MAV_BATTERY_CHARGE_STATE_OK");

    let esc = of_type(&decoded, "ESC_TELEMETRY_1_TO_4");
    assert_eq!(esc.len(), 5, "4 Hz over 1.1 s");
    let esc = esc[0];
    // Steps -102, -82, -62, -42: |rpm| 4500, 3618, 2735, 1853.
    assert_eq!(esc["rpm"], serde_json::json!([4500, 3618, 2735, 1853]));
    assert_eq!(esc["current"], serde_json::json!([100, 110, 120, 130]));
    assert_eq!(esc["temperature"], serde_json::json!([30, 31, 32, 33]));
    assert_eq!(esc["count"], serde_json::json!([0, 1000, 2000, 3000]));
    assert_eq!(esc["voltage"], serde_json::json!([0, 0, 0, 0]));
    let esc = of_type(&decoded, "ESC_TELEMETRY_5_TO_8");
    assert_eq!(esc.len(), 5);
    assert_eq!(esc[0]["rpm"], serde_json::json!([971, 88, 0, 0]));

    let acks = of_type(&decoded, "COMMAND_ACK");
    assert_eq!(acks.len(), 1);
    assert_eq!(
        (&acks[0]["command"], &acks[0]["result"]),
        (&Value::from(209), &Value::from(2))
    );

    let texts = of_type(&decoded, "STATUSTEXT");
    assert_eq!(texts.len(), 1);
    assert_eq!(texts[0]["severity"], 2, "MAV_SEVERITY_CRITICAL");
    assert_eq!(texts[0]["text"], "LBV master ready");

    // ArduSub's pilot gain, as QGroundControl's ArduSub plugin reads it: LBV_GAIN 50 % as 0.5.
    let gains = of_type(&decoded, "NAMED_VALUE_FLOAT");
    assert_eq!(gains.len(), 2, "1 Hz over 1.1 s");
    for (gain, ms) in gains.iter().zip([0, 1000]) {
        assert_eq!(
            (&gain["name"], &gain["value"]),
            (&Value::from("PilotGain"), &Value::from(0.5))
        );
        assert_eq!(gain["time_boot_ms"], ms);
    }

    let params = of_type(&decoded, "PARAM_VALUE");
    assert_eq!(params.len(), 2);
    assert_eq!(params[1]["param_id"], "SYSID_MYGCS");
    assert_eq!(params[1]["param_value"], 255.0, "C_CAST: the float holds the integer");
    assert_eq!(params[1]["param_type"], 4, "MAV_PARAM_TYPE_INT16");

    let ftp = of_type(&decoded, "FILE_TRANSFER_PROTOCOL");
    assert_eq!(ftp.len(), 2);
    assert_eq!(
        (
            &ftp[0]["target_network"],
            &ftp[0]["target_system"],
            &ftp[0]["target_component"]
        ),
        (&0.into(), &255.into(), &190.into())
    );
    let payload: Vec<u64> = ftp[0]["payload"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b.as_u64().unwrap())
        .collect();
    assert_eq!(payload.len(), 251, "zero-extended to its full length");
    assert_eq!(payload[..12], [8, 0, 3, 128, 21, 3, 0, 0, 0, 0, 0, 0]);
    let entry: Vec<u8> = payload[12..33].iter().map(|b| *b as u8).collect();
    assert_eq!(entry, b"Fthruster0.lbvu\t4176\0");
    assert!(payload[33..].iter().all(|b| *b == 0));
    // A read of `@SYS/versions.txt`: the whole payload, its data made as it was framed.
    let payload: Vec<u8> = ftp[1]["payload"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b.as_u64().unwrap() as u8)
        .collect();
    assert_eq!(payload[..12], [3, 0, 3, 128, 239, 15, 1, 0, 0, 0, 0, 0]);
    assert!(payload[12..].starts_with(b"board  family   version  state\nmaster -        -        unknown\n"));
    assert!(payload[12..].iter().all(|b| b.is_ascii_graphic() || b" \n".contains(b)));

    let versions = of_type(&decoded, "AUTOPILOT_VERSION");
    assert_eq!(versions.len(), 1);
    let v = versions[0];
    assert_eq!(
        v["capabilities"], 0x2_2008,
        "MAVLINK2 | COMMAND_INT | PARAM_ENCODE_C_CAST"
    );
    let version = v["flight_sw_version"].as_u64().unwrap();
    let part = |s: &str| s.parse::<u64>().unwrap();
    assert_eq!(
        version >> 8,
        part(env!("CARGO_PKG_VERSION_MAJOR")) << 16
            | part(env!("CARGO_PKG_VERSION_MINOR")) << 8
            | part(env!("CARGO_PKG_VERSION_PATCH"))
    );
    assert_eq!(
        (&v["vendor_id"], &v["product_id"]),
        (&Value::from(0x0483), &Value::from(0x0469))
    );
    let mut uid2: Vec<Value> = b"0123456789AB".iter().map(|&b| Value::from(b)).collect();
    uid2.extend(std::iter::repeat_n(Value::from(0), 6));
    assert_eq!(v["uid2"], Value::Array(uid2));
    let word = |n: usize| {
        u64::from(u32::from_le_bytes(
            b"0123456789AB"[n * 4..n * 4 + 4].try_into().unwrap(),
        ))
    };
    assert_eq!(v["uid"], word(0) | (word(1) ^ word(2)) << 32);
    // The git revision as 8 ASCII hex digits (pymavlink shows uint8_t[8] as numbers), or zeros outside git.
    let git: Vec<u8> = v["flight_custom_version"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b.as_u64().unwrap() as u8)
        .collect();
    assert!(git == [0; 8] || git.iter().all(u8::is_ascii_hexdigit), "{git:?}");
    // SYS_STATUS's pre-arm check: present and enabled, healthy once the vehicle says it is armable (at 600 ms).
    let prearm = 0x1000_0000u64;
    let sys_all = of_type(&decoded, "SYS_STATUS");
    for s in &sys_all {
        assert_eq!(s["onboard_control_sensors_present"].as_u64().unwrap() & prearm, prearm);
        assert_eq!(s["onboard_control_sensors_enabled"].as_u64().unwrap() & prearm, prearm);
    }
    let healthy: Vec<bool> = sys_all
        .iter()
        .map(|s| s["onboard_control_sensors_health"].as_u64().unwrap() & prearm != 0)
        .collect();
    assert_eq!(healthy, [false, true]);
    assert_eq!(params[0]["param_id"], "SIXTEEN_CHARS_ID");
    assert_eq!(params[0]["param_value"], -2.5);
    assert_eq!(params[0]["param_type"], 9, "MAV_PARAM_TYPE_REAL32");
    assert_eq!(
        (&params[0]["param_index"], &params[0]["param_count"]),
        (&Value::from(4), &Value::from(9))
    );
}

/// The update server's reply to a BurstReadFile of `@SYS/versions.txt`'s first 239 bytes (its sink knowing nothing
/// of the boards), to a MAVFTP client.
fn versions_read() -> Outgoing {
    use lbv_master_fw::config::VEHICLE;
    use lbv_master_fw::update::{CheckOnly, Context, UpdateServer};
    let mut server = UpdateServer::new(&VEHICLE.thrusters, FrameKind::Lbv300_6);
    let context = Context {
        armed: false,
        operator: 255,
        restarting: false,
        unsigned: false,
        params: None,
        crash: false,
        post_mortems: 0,
        black_box: None,
    };
    let gcs = Sender {
        system: 255,
        component: 190,
    };
    let request = |seq: u8, opcode: u8, size: u8, data: &[u8]| {
        let mut payload = [0u8; 251];
        payload[..5].copy_from_slice(&[seq, 0, 3, opcode, size]);
        payload[12..12 + data.len()].copy_from_slice(data);
        payload
    };
    let now = embassy_time::Instant::from_ticks(0);
    let open = request(1, 4, 17, b"@SYS/versions.txt");
    server.request(now, context, gcs, &open, &mut CheckOnly, &mut |_| {});
    let read = request(2, 15, 239, &[]);
    match server.request(now, context, gcs, &read, &mut CheckOnly, &mut |_| {}) {
        Some(reply @ FtpAnswer::Read(_)) => Outgoing::Ftp { to: gcs, reply },
        other => panic!("not a read: {other:?}"),
    }
}
