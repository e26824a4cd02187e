//! The console's receive task: frames built by the mavlink crate reach the vehicle as the right commands; noise,
//! truncated and corrupted frames are counted and skipped.

use crate::support::{run_rx, v1, v2};
use embassy_time::Duration;
use lbv_master_fw::console::ConsoleConfig;
use lbv_master_fw::console::lbv::{
    COMMAND_LONG_DATA, HEARTBEAT_DATA, MANUAL_CONTROL_DATA, MavAutopilot, MavModeFlag, MavParamType, MavState, MavType,
    PARAM_REQUEST_LIST_DATA, PARAM_REQUEST_READ_DATA, PARAM_SET_DATA, STATUSTEXT_DATA,
};
use lbv_master_fw::mixer::ManualInput;
use lbv_master_fw::shared::Command;

const GCS: (u8, u8) = (255, 190);
const CONFIG: ConsoleConfig = ConsoleConfig::DEFAULT;

fn heartbeat(mavtype: MavType) -> HEARTBEAT_DATA {
    HEARTBEAT_DATA {
        custom_mode: 0,
        mavtype,
        autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
        base_mode: MavModeFlag::empty(),
        system_status: MavState::MAV_STATE_ACTIVE,
        mavlink_version: 3,
    }
}

fn manual(target: u8, x: i16, y: i16, z: i16, r: i16) -> MANUAL_CONTROL_DATA {
    MANUAL_CONTROL_DATA {
        target,
        x,
        y,
        z,
        r,
        buttons: 0,
        buttons2: 0,
        enabled_extensions: 0,
        s: 0,
        t: 0,
        aux1: 0,
        aux2: 0,
        aux3: 0,
        aux4: 0,
        aux5: 0,
        aux6: 0,
    }
}

fn command(target: (u8, u8), command: u16, p: [f32; 4]) -> COMMAND_LONG_DATA {
    COMMAND_LONG_DATA {
        target_system: target.0,
        target_component: target.1,
        command,
        confirmation: 0,
        param1: p[0],
        param2: p[1],
        param3: p[2],
        param4: p[3],
        param5: 0.0,
        param6: 0.0,
        param7: 0.0,
    }
}

fn param_id(name: &str) -> [u8; 16] {
    let mut id = [0u8; 16];
    id[..name.len()].copy_from_slice(name.as_bytes());
    id
}

/// Every input message, as frames, with the command each must produce.
fn inputs() -> Vec<(Vec<u8>, Option<Command>)> {
    let (s, c) = GCS;
    vec![
        (v2(s, c, 0, &heartbeat(MavType::MAV_TYPE_GCS)), Some(Command::Heartbeat)),
        (
            v2(s, c, 1, &manual(1, 100, -200, 700, -300)),
            Some(Command::Manual(
                ManualInput {
                    x: 100,
                    y: -200,
                    z: 700,
                    r: -300,
                },
                0,
            )),
        ),
        (
            v2(s, c, 2, &command((1, 1), 400, [1.0, 0.0, 0.0, 0.0])),
            Some(Command::Arm(true)),
        ),
        (
            v2(s, c, 3, &command((1, 0), 400, [0.0, 0.0, 0.0, 0.0])),
            Some(Command::Arm(false)),
        ),
        (
            v2(s, c, 4, &command((1, 1), 209, [3.0, 0.0, -40.0, 4.5])),
            Some(Command::MotorTest {
                motor: 3,
                percent: -40,
                duration: Duration::from_millis(4500),
            }),
        ),
        (
            v2(s, c, 5, &command((1, 1), 209, [3.0, 1.0, 1600.0, 2.0])),
            Some(Command::Unsupported { command: 209 }),
        ),
        (
            v2(s, c, 6, &command((1, 1), 31012, [0.0; 4])),
            Some(Command::Unsupported { command: 31012 }),
        ),
        (
            v2(
                s,
                c,
                7,
                &PARAM_REQUEST_LIST_DATA {
                    target_system: 1,
                    target_component: 1,
                },
            ),
            Some(Command::ParamRequestList),
        ),
        (
            v2(
                s,
                c,
                8,
                &PARAM_REQUEST_READ_DATA {
                    target_system: 1,
                    target_component: 0,
                    param_id: param_id("THR_MAX").into(),
                    param_index: -1,
                },
            ),
            Some(Command::ParamRequestRead {
                id: param_id("THR_MAX"),
                index: -1,
            }),
        ),
        (
            v2(
                s,
                c,
                9,
                &PARAM_SET_DATA {
                    target_system: 1,
                    target_component: 1,
                    param_id: param_id("SIXTEEN_CHARS_ID").into(),
                    param_value: 0.75,
                    param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
                },
            ),
            Some(Command::ParamSet {
                id: param_id("SIXTEEN_CHARS_ID"),
                value: 0.75,
                param_type: 9,
            }),
        ),
        // MAVLink 1 is accepted too.
        (
            v1(s, c, 10, &command((1, 1), 400, [1.0, 0.0, 0.0, 0.0])),
            Some(Command::Arm(true)),
        ),
        (
            v1(s, c, 11, &heartbeat(MavType::MAV_TYPE_GCS)),
            Some(Command::Heartbeat),
        ),
        // Not for us, or not from a ground station: read, counted, not acted on.
        (v2(2, 1, 0, &heartbeat(MavType::MAV_TYPE_SUBMARINE)), None),
        (v2(s, c, 12, &manual(2, 500, 0, 500, 0)), None),
        (v2(s, c, 13, &command((2, 1), 400, [1.0, 0.0, 0.0, 0.0])), None),
        (v2(s, c, 14, &command((1, 100), 400, [1.0, 0.0, 0.0, 0.0])), None),
        (
            v2(
                s,
                c,
                15,
                &PARAM_REQUEST_LIST_DATA {
                    target_system: 3,
                    target_component: 0,
                },
            ),
            None,
        ),
        (v2(s, c, 16, &STATUSTEXT_DATA::DEFAULT), None),
    ]
}

#[test]
fn each_input_message_gives_its_command() {
    for (frame, expected) in inputs() {
        let (commands, counters) = run_rx(&frame, 64, &CONFIG);
        assert_eq!(commands, expected.into_iter().collect::<Vec<_>>(), "frame {frame:02x?}");
        assert_eq!((counters.frames_in, counters.bad_frames), (1, 0));
    }
}

#[test]
fn a_stream_of_messages_in_any_chunking_keeps_its_order() {
    let inputs = inputs();
    let stream: Vec<u8> = inputs.iter().flat_map(|(f, _)| f.clone()).collect();
    let expected: Vec<Command> = inputs.iter().filter_map(|(_, c)| *c).collect();
    // More commands than the channel holds: the task waits for room and loses none.
    assert!(expected.len() > 8);
    for chunk in [1, 2, 5, 17, 64, 1000] {
        let (commands, counters) = run_rx(&stream, chunk, &CONFIG);
        assert_eq!(commands, expected, "chunk {chunk}");
        assert_eq!(counters.frames_in as usize, inputs.len());
        assert_eq!((counters.bad_frames, counters.skipped_bytes), (0, 0));
    }
}

#[test]
fn another_system_id_is_honoured() {
    let config = ConsoleConfig {
        system_id: 7,
        component_id: 1,
        thrusters: 6,
        ..ConsoleConfig::DEFAULT
    };
    let ours = v2(255, 190, 0, &command((7, 1), 400, [1.0, 0.0, 0.0, 0.0]));
    let default_target = v2(255, 190, 1, &command((1, 1), 400, [1.0, 0.0, 0.0, 0.0]));
    let (commands, _) = run_rx(&[ours, default_target].concat(), 64, &config);
    assert_eq!(commands, vec![Command::Arm(true)]);
}

fn arm(sequence: u8) -> Vec<u8> {
    v2(255, 190, sequence, &command((1, 1), 400, [1.0, 0.0, 0.0, 0.0]))
}

#[test]
fn bad_crc_is_counted_and_skipped() {
    let mut bad = arm(0);
    let last = bad.len() - 1;
    bad[last] ^= 0xFF;
    let mut payload_hit = arm(1);
    payload_hit[12] ^= 0x01;
    let stream = [bad, payload_hit, arm(2)].concat();
    let (commands, counters) = run_rx(&stream, 64, &CONFIG);
    assert_eq!(commands, vec![Command::Arm(true)]);
    assert_eq!(counters.frames_in, 1);
    assert!(counters.bad_frames >= 2, "{counters:?}");
    assert_eq!(counters.unknown_messages, 0);
}

#[test]
fn truncated_frames_are_counted_and_the_next_frame_decoded() {
    let full = arm(0);
    let truncated = &full[..full.len() - 5];
    // Two truncated frames, then enough good frames to make up the claimed lengths.
    let stream = [truncated, truncated, &arm(1), &arm(2), &arm(3)].concat();
    let (commands, counters) = run_rx(&stream, 64, &CONFIG);
    assert_eq!(commands, vec![Command::Arm(true); 3]);
    assert!(counters.bad_frames >= 2, "{counters:?}");
}

#[test]
fn random_garbage_is_counted_and_a_frame_after_it_decoded() {
    let mut state = 0x9E37_79B9u32;
    let mut garbage = vec![];
    for _ in 0..5000 {
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        garbage.push(match state % 16 {
            0 => 0xFD,
            1 => 0xFE,
            _ => (state >> 8) as u8,
        });
    }
    // A frame's worth of zeros ends any false start, then a real frame.
    let stream = [garbage, vec![0; 300], arm(9)].concat();
    for chunk in [1, 7, 64] {
        let (commands, counters) = run_rx(&stream, chunk, &CONFIG);
        // Noise can hold a valid-looking frame only with a correct CRC: practically never.
        assert_eq!(commands, vec![Command::Arm(true)], "chunk {chunk}");
        assert!(counters.bad_frames > 100, "{counters:?}");
        // Noise that happens to look like a whole unknown message is skipped whole, the rest byte by byte.
        assert!(counters.skipped_bytes > 2000, "{counters:?}");
    }
}

#[test]
fn unknown_messages_are_counted_apart() {
    // SYSTEM_TIME (id 2) is not in the dialect: framed by hand with its official CRC_EXTRA (137).
    let mut system_time = vec![0xFD, 12, 0, 0, 0, 255, 190, 2, 0, 0];
    system_time.extend([1u8; 12]);
    let crc = mavlink_core::calculate_crc(&system_time[1..], 137);
    system_time.extend(crc.to_le_bytes());
    let stream = [system_time.clone(), arm(0), system_time, arm(1)].concat();
    let (commands, counters) = run_rx(&stream, 64, &CONFIG);
    assert_eq!(commands, vec![Command::Arm(true); 2]);
    assert_eq!(
        (counters.frames_in, counters.bad_frames, counters.unknown_messages),
        (2, 2, 2)
    );
    assert_eq!(counters.corrupt(), 0);
}

#[test]
fn undecodable_payloads_are_bad_frames() {
    // A HEARTBEAT with a MAV_TYPE that does not exist: CRC valid, payload invalid.
    let mut hb = vec![0xFD, 9, 0, 0, 0, 255, 190, 0, 0, 0, 0, 0, 0, 0, 250, 8, 0, 0, 3];
    let crc = mavlink_core::calculate_crc(&hb[1..], 50);
    hb.extend(crc.to_le_bytes());
    let stream = [hb, arm(0)].concat();
    let (commands, counters) = run_rx(&stream, 64, &CONFIG);
    assert_eq!(commands, vec![Command::Arm(true)]);
    assert_eq!((counters.frames_in, counters.bad_frames), (1, 1));
}
