//! What the console's MAVLink messages ask for: one [`Command`] per message addressed to this vehicle. Whether its
//! sender may ask it is the vehicle's decision.

use embassy_time::Duration;
use mavlink_core::MessageData;
use mavlink_core::error::ParserError;

use super::ConsoleConfig;
use super::lbv::{
    AUTOPILOT_VERSION_DATA, AVAILABLE_MODES_DATA, BATTERY_STATUS_DATA, COMMAND_ACK_DATA, COMMAND_INT_DATA,
    COMMAND_LONG_DATA, ESC_INFO_DATA, ESC_STATUS_DATA, ESC_TELEMETRY_1_TO_4_DATA, ESC_TELEMETRY_5_TO_8_DATA,
    FILE_TRANSFER_PROTOCOL_DATA, HEARTBEAT_DATA, MANUAL_CONTROL_DATA, MISSION_ACK_DATA, MISSION_CLEAR_ALL_DATA,
    MISSION_COUNT_DATA, MISSION_REQUEST_LIST_DATA, MavType, NAMED_VALUE_FLOAT_DATA, PARAM_REQUEST_LIST_DATA,
    PARAM_REQUEST_READ_DATA, PARAM_SET_DATA, PARAM_VALUE_DATA, SETUP_SIGNING_DATA, STATUSTEXT_DATA, SYS_STATUS_DATA,
};
use crate::console::framing::{Frame, Version};
use crate::mixer::ManualInput;
use crate::shared::{
    Command, FtpPayload, Interval, MAV_CMD_COMPONENT_ARM_DISARM, MAV_CMD_DO_MOTOR_TEST, MAV_CMD_DO_SET_MODE,
    MAV_CMD_LBV_APPLY_UPDATE, MAV_CMD_LBV_QUERY_VERSION, MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN,
    MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, MAV_CMD_REQUEST_MESSAGE, MAV_CMD_SET_MESSAGE_INTERVAL, Message,
    UpdateAction,
};

/// Shortest message interval taken, ms: every paced message at 10 Hz together takes some 5 kB/s, under half of
/// what 115200 baud carries, leaving room for the ground station's own frames and the parameter list.
pub(crate) const MIN_INTERVAL_MS: u32 = 100;
/// Longest message interval taken, ms.
pub(crate) const MAX_INTERVAL_MS: u32 = 60_000;
/// Its param1 asking the autopilot to reboot (REBOOT_SHUTDOWN_ACTION_REBOOT).
const REBOOT_AUTOPILOT: f32 = 1.0;
/// MOTOR_TEST_THROTTLE_PERCENT, the only motor test throttle type supported.
const MOTOR_TEST_THROTTLE_PERCENT: f32 = 0.0;
/// Longest motor test run.
const MOTOR_TEST_MAX_SECONDS: f32 = 10.0;

/// Message id and CRC_EXTRA of every message of the dialect.
const MESSAGES: [(u32, u8); 25] = [
    (HEARTBEAT_DATA::ID, HEARTBEAT_DATA::EXTRA_CRC),
    (SYS_STATUS_DATA::ID, SYS_STATUS_DATA::EXTRA_CRC),
    (PARAM_REQUEST_READ_DATA::ID, PARAM_REQUEST_READ_DATA::EXTRA_CRC),
    (PARAM_REQUEST_LIST_DATA::ID, PARAM_REQUEST_LIST_DATA::EXTRA_CRC),
    (PARAM_VALUE_DATA::ID, PARAM_VALUE_DATA::EXTRA_CRC),
    (PARAM_SET_DATA::ID, PARAM_SET_DATA::EXTRA_CRC),
    (MISSION_REQUEST_LIST_DATA::ID, MISSION_REQUEST_LIST_DATA::EXTRA_CRC),
    (MISSION_COUNT_DATA::ID, MISSION_COUNT_DATA::EXTRA_CRC),
    (MISSION_CLEAR_ALL_DATA::ID, MISSION_CLEAR_ALL_DATA::EXTRA_CRC),
    (MISSION_ACK_DATA::ID, MISSION_ACK_DATA::EXTRA_CRC),
    (MANUAL_CONTROL_DATA::ID, MANUAL_CONTROL_DATA::EXTRA_CRC),
    (COMMAND_INT_DATA::ID, COMMAND_INT_DATA::EXTRA_CRC),
    (COMMAND_LONG_DATA::ID, COMMAND_LONG_DATA::EXTRA_CRC),
    (COMMAND_ACK_DATA::ID, COMMAND_ACK_DATA::EXTRA_CRC),
    (FILE_TRANSFER_PROTOCOL_DATA::ID, FILE_TRANSFER_PROTOCOL_DATA::EXTRA_CRC),
    (BATTERY_STATUS_DATA::ID, BATTERY_STATUS_DATA::EXTRA_CRC),
    (AUTOPILOT_VERSION_DATA::ID, AUTOPILOT_VERSION_DATA::EXTRA_CRC),
    (NAMED_VALUE_FLOAT_DATA::ID, NAMED_VALUE_FLOAT_DATA::EXTRA_CRC),
    (STATUSTEXT_DATA::ID, STATUSTEXT_DATA::EXTRA_CRC),
    (AVAILABLE_MODES_DATA::ID, AVAILABLE_MODES_DATA::EXTRA_CRC),
    (SETUP_SIGNING_DATA::ID, SETUP_SIGNING_DATA::EXTRA_CRC),
    (ESC_INFO_DATA::ID, ESC_INFO_DATA::EXTRA_CRC),
    (ESC_STATUS_DATA::ID, ESC_STATUS_DATA::EXTRA_CRC),
    (ESC_TELEMETRY_1_TO_4_DATA::ID, ESC_TELEMETRY_1_TO_4_DATA::EXTRA_CRC),
    (ESC_TELEMETRY_5_TO_8_DATA::ID, ESC_TELEMETRY_5_TO_8_DATA::EXTRA_CRC),
];

/// CRC_EXTRA of a message id of the dialect; `None` for any other id.
pub fn extra_crc(message_id: u32) -> Option<u8> {
    MESSAGES.iter().find(|(id, _)| *id == message_id).map(|&(_, crc)| crc)
}

/// Decode a CRC-valid frame. `Ok(None)` for messages that ask nothing of this vehicle: telemetry from other
/// systems, messages addressed to another system or component, HEARTBEATs that are not from a ground station.
/// `Err` when the payload does not decode (an enum value that does not exist). Who sent it is in the frame's
/// header, and the vehicle decides whether that sender may ask it.
///
/// Mapping:
/// - HEARTBEAT with type MAV_TYPE_GCS: [`Command::Heartbeat`]. Other components' heartbeats (a companion
///   computer, another vehicle, our own echo) do not prove that the pilot is there.
/// - MANUAL_CONTROL to our system (or 0): [`Command::Manual`]; x, y, r clamped to -1000..=1000, z to 0..=1000
///   (ArduSub's 500-neutral heave); an axis sent as INT16_MAX ("invalid") reads as neutral; `buttons` as sent
///   (buttons 0-15; `buttons2`, 16-31, have no functions, as in ArduSub).
/// - COMMAND_LONG or COMMAND_INT (the same commands: none of them takes a position) to our system and component
///   (or 0): 400 gives [`Command::Arm`] (arm when param1 is exactly 1, disarm when exactly 0, any other value
///   [`Command::Unsupported`] as ArduPilot answers it: a half-received 0.5 or a NaN must not disarm a diving
///   vehicle); 512 gives [`Command::RequestMessage`] of the message param1 names (ESC_INFO and ESC_STATUS of the
///   block of four thrusters whose first param2 names, 0 or 4: another, none), 520 of AUTOPILOT_VERSION; 511
///   gives [`Command::MessageInterval`] (param1 the message, param2 the interval: 0 default, -1 off, else µs
///   clamped to [`MIN_INTERVAL_MS`]..=[`MAX_INTERVAL_MS`]); 209 gives [`Command::MotorTest`] for throttle type MOTOR_TEST_THROTTLE_PERCENT (param1
///   motor number, param3 percent clamped to -100..=100, param4 seconds clamped to 0..=10, NaN reads as 0), and
///   [`Command::Unsupported`] for the other throttle types; 246 with param1 exactly 1 (reboot the autopilot)
///   gives [`Command::Reboot`], other actions (shutdown, bootloader, none) [`Command::Unsupported`]; 176 gives
///   [`Command::SetMode`] of the custom mode param2 names when param1 enables custom modes; any other
///   command gives [`Command::Unsupported`]. The vehicle task answers every one with a COMMAND_ACK.
///   31010 (MAV_CMD_LBV_APPLY_UPDATE) and 31011 (MAV_CMD_LBV_QUERY_VERSION) give [`Command::Update`] of the
///   target param1 names (a whole number 0..=255, else `None`).
/// - SETUP_SIGNING to our system and component (or 0): [`Command::SetupSigning`].
/// - PARAM_REQUEST_LIST / PARAM_REQUEST_READ / PARAM_SET to our system and component (or 0): the matching
///   command; PARAM_SET carries its param_type, which the vehicle checks against the parameter's.
/// - MISSION_REQUEST_LIST to our system and component (or 0): [`Command::MissionRequestList`] of its mission type
///   (a mission, a fence, rally points: the master keeps none of them); MISSION_CLEAR_ALL
///   [`Command::MissionClear`], and MISSION_COUNT (an upload's start) [`Command::MissionUpload`], of theirs.
pub(crate) fn decode(frame: &Frame<'_>, config: &ConsoleConfig) -> Result<Option<Command>, ParserError> {
    let version = match frame.version {
        Version::V1 => mavlink_core::MavlinkVersion::V1,
        Version::V2 => mavlink_core::MavlinkVersion::V2,
    };
    let payload = frame.payload;
    let for_us = |system: u8, component: u8| {
        (system == 0 || system == config.system_id) && (component == 0 || component == config.component_id)
    };
    let command = match frame.message_id {
        HEARTBEAT_DATA::ID => {
            let m = HEARTBEAT_DATA::deser(version, payload)?;
            (m.mavtype == MavType::MAV_TYPE_GCS).then_some(Command::Heartbeat)
        }
        MANUAL_CONTROL_DATA::ID => {
            let m = MANUAL_CONTROL_DATA::deser(version, payload)?;
            (m.target == 0 || m.target == config.system_id).then(|| Command::Manual(manual_input(&m), m.buttons))
        }
        COMMAND_LONG_DATA::ID => {
            let m = COMMAND_LONG_DATA::deser(version, payload)?;
            for_us(m.target_system, m.target_component)
                .then(|| command(m.command, [m.param1, m.param2, m.param3, m.param4], config))
        }
        COMMAND_INT_DATA::ID => {
            let m = COMMAND_INT_DATA::deser(version, payload)?;
            for_us(m.target_system, m.target_component)
                .then(|| command(m.command, [m.param1, m.param2, m.param3, m.param4], config))
        }
        PARAM_REQUEST_LIST_DATA::ID => {
            let m = PARAM_REQUEST_LIST_DATA::deser(version, payload)?;
            for_us(m.target_system, m.target_component).then_some(Command::ParamRequestList)
        }
        PARAM_REQUEST_READ_DATA::ID => {
            let m = PARAM_REQUEST_READ_DATA::deser(version, payload)?;
            for_us(m.target_system, m.target_component).then_some(Command::ParamRequestRead {
                id: *m.param_id,
                index: m.param_index,
            })
        }
        PARAM_SET_DATA::ID => {
            let m = PARAM_SET_DATA::deser(version, payload)?;
            for_us(m.target_system, m.target_component).then_some(Command::ParamSet {
                id: *m.param_id,
                value: m.param_value,
                param_type: m.param_type as u8,
            })
        }
        MISSION_REQUEST_LIST_DATA::ID => {
            let m = MISSION_REQUEST_LIST_DATA::deser(version, payload)?;
            for_us(m.target_system, m.target_component).then_some(Command::MissionRequestList {
                mission_type: m.mission_type,
            })
        }
        MISSION_CLEAR_ALL_DATA::ID => {
            let m = MISSION_CLEAR_ALL_DATA::deser(version, payload)?;
            for_us(m.target_system, m.target_component).then_some(Command::MissionClear {
                mission_type: m.mission_type,
            })
        }
        MISSION_COUNT_DATA::ID => {
            let m = MISSION_COUNT_DATA::deser(version, payload)?;
            for_us(m.target_system, m.target_component).then_some(Command::MissionUpload {
                mission_type: m.mission_type,
                count: m.count,
            })
        }
        SETUP_SIGNING_DATA::ID => {
            let m = SETUP_SIGNING_DATA::deser(version, payload)?;
            for_us(m.target_system, m.target_component).then_some(Command::SetupSigning {
                key: m.secret_key,
                timestamp: m.initial_timestamp,
            })
        }
        _ => None,
    };
    Ok(command)
}

/// The MAVLink FTP payload of a FILE_TRANSFER_PROTOCOL frame addressed to our system and component (or 0, on
/// any network); `None` for any other frame. Read by hand: its fields are target_network, target_system,
/// target_component and the payload, all bytes, and the generated decoder would cost a kilobyte of flash for it.
pub(crate) fn ftp(frame: &Frame<'_>, config: &ConsoleConfig) -> Option<FtpPayload> {
    if frame.message_id != FILE_TRANSFER_PROTOCOL_DATA::ID {
        return None;
    }
    // MAVLink 2 trims trailing zeros: what is not there is 0.
    let byte = |n: usize| frame.payload.get(n).copied().unwrap_or(0);
    let (system, component) = (byte(1), byte(2));
    if !((system == 0 || system == config.system_id) && (component == 0 || component == config.component_id)) {
        return None;
    }
    let mut payload = [0; crate::shared::FTP_PAYLOAD];
    for (to, from) in payload.iter_mut().zip(frame.payload.get(3..).unwrap_or_default()) {
        *to = *from;
    }
    Some(payload)
}

/// The sticks of a MANUAL_CONTROL, with invalid axes neutral.
fn manual_input(m: &MANUAL_CONTROL_DATA) -> ManualInput {
    let axis = |v: i16| if v == i16::MAX { 0 } else { v.clamp(-1000, 1000) };
    ManualInput {
        x: axis(m.x),
        y: axis(m.y),
        z: if m.z == i16::MAX { 500 } else { m.z.clamp(0, 1000) },
        r: axis(m.r),
    }
}

/// The message a MAV_CMD_REQUEST_MESSAGE or MAV_CMD_SET_MESSAGE_INTERVAL names in a float, if the master sends
/// it: ESC_TELEMETRY_5_TO_8 only with more than four thrusters.
pub(crate) fn message(id: f32, config: &ConsoleConfig) -> Option<Message> {
    // Only a whole number names a message (the cast saturates: NaN reads 0, so check it comes back the same).
    let whole = id as u32;
    if whole as f32 != id {
        return None;
    }
    Some(match whole {
        HEARTBEAT_DATA::ID => Message::Heartbeat,
        SYS_STATUS_DATA::ID => Message::SysStatus,
        BATTERY_STATUS_DATA::ID => Message::BatteryStatus,
        AUTOPILOT_VERSION_DATA::ID => Message::AutopilotVersion,
        AVAILABLE_MODES_DATA::ID => Message::AvailableModes,
        ESC_INFO_DATA::ID if super::ESC_DETAIL => Message::EscInfo,
        ESC_STATUS_DATA::ID if super::ESC_DETAIL => Message::EscStatus,
        ESC_TELEMETRY_1_TO_4_DATA::ID => Message::EscTelemetry1To4,
        ESC_TELEMETRY_5_TO_8_DATA::ID if config.thruster_count() > 4 => Message::EscTelemetry5To8,
        NAMED_VALUE_FLOAT_DATA::ID => Message::NamedValueFloat,
        _ => return None,
    })
}

/// A MAV_CMD_SET_MESSAGE_INTERVAL interval in µs: 0 the default, -1 off, a positive value clamped to
/// [`MIN_INTERVAL_MS`]..=[`MAX_INTERVAL_MS`] (rounded to the ms); `None` for anything else (NaN, below -1).
pub(crate) fn interval(us: f32) -> Option<Interval> {
    if us == 0.0 {
        Some(Interval::Default)
    } else if us == -1.0 {
        Some(Interval::Off)
    } else if us > 0.0 {
        let ms = (us / 1000.0 + 0.5) as u32;
        Some(Interval::Every(ms.clamp(MIN_INTERVAL_MS, MAX_INTERVAL_MS)))
    } else {
        None
    }
}

/// The command a COMMAND_LONG or COMMAND_INT asks for, from its number and first four parameters.
fn command(command: u16, [param1, param2, param3, param4]: [f32; 4], config: &ConsoleConfig) -> Command {
    match command {
        // ArduPilot (GCS_MAVLINK::handle_command_component_arm_disarm) arms on exactly 1, disarms on exactly 0
        // and answers MAV_RESULT_UNSUPPORTED for anything else.
        MAV_CMD_COMPONENT_ARM_DISARM if param1 == 1.0 => Command::Arm(true),
        MAV_CMD_COMPONENT_ARM_DISARM if param1 == 0.0 => Command::Arm(false),
        MAV_CMD_REQUEST_MESSAGE => {
            // ESC_INFO's and ESC_STATUS's param2 is the index of the block's first thruster (MAVLink's "index ID"):
            // a block the vehicle has, or no message.
            let first = param2 as u8;
            let block =
                f32::from(first) == param2 && first.is_multiple_of(4) && usize::from(first) < config.thruster_count();
            match message(param1, config) {
                Some(Message::EscInfo | Message::EscStatus) if !block => Command::RequestMessage {
                    command,
                    message: None,
                    first: 0,
                },
                message => Command::RequestMessage {
                    command,
                    message,
                    first: if block { first } else { 0 },
                },
            }
        }
        MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES => Command::RequestMessage {
            command,
            message: Some(Message::AutopilotVersion),
            first: 0,
        },
        MAV_CMD_SET_MESSAGE_INTERVAL => Command::MessageInterval {
            message: message(param1, config),
            interval: interval(param2),
        },
        MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN if param1 == REBOOT_AUTOPILOT => Command::Reboot,
        // MAV_MODE_FLAG_CUSTOM_MODE_ENABLED (1) in the base mode says param2 is the custom mode; only a whole number
        // names one (the casts saturate and read NaN as 0).
        MAV_CMD_DO_SET_MODE => Command::SetMode {
            custom_mode: Some(param2 as u32).filter(|mode| (param1 as u32) & 1 == 1 && *mode as f32 == param2),
        },
        MAV_CMD_LBV_APPLY_UPDATE | MAV_CMD_LBV_QUERY_VERSION => Command::Update {
            action: if command == MAV_CMD_LBV_APPLY_UPDATE {
                UpdateAction::Apply
            } else {
                UpdateAction::QueryVersion
            },
            // Only a whole number names a target (the cast saturates and reads NaN as 0).
            target: Some(param1 as u8).filter(|target| f32::from(*target) == param1),
        },
        MAV_CMD_DO_MOTOR_TEST if param2 == MOTOR_TEST_THROTTLE_PERCENT => {
            // Float to integer casts saturate and read NaN as 0; `max`/`min` would turn NaN into the bound.
            let percent = if param3.is_nan() {
                0
            } else {
                param3.clamp(-100.0, 100.0) as i8
            };
            let seconds = if param4.is_nan() {
                0.0
            } else {
                param4.clamp(0.0, MOTOR_TEST_MAX_SECONDS)
            };
            Command::MotorTest {
                motor: param1 as u8,
                percent,
                duration: Duration::from_millis(u64::from((seconds * 1000.0) as u32)),
            }
        }
        command => Command::Unsupported { command },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(message_id: u32, payload: &[u8]) -> Frame<'_> {
        Frame {
            version: Version::V2,
            sequence: 0,
            system_id: 255,
            component_id: 190,
            message_id,
            payload,
            signed: false,
            bytes: &[],
        }
    }

    fn encode<D: MessageData>(m: &D) -> Vec<u8> {
        let mut buf = [0u8; 255];
        let len = m.ser(mavlink_core::MavlinkVersion::V2, &mut buf);
        buf[..len].to_vec()
    }

    fn long(command: u16, params: [f32; 4]) -> COMMAND_LONG_DATA {
        COMMAND_LONG_DATA {
            target_system: 1,
            target_component: 1,
            command,
            confirmation: 0,
            param1: params[0],
            param2: params[1],
            param3: params[2],
            param4: params[3],
            param5: 0.0,
            param6: 0.0,
            param7: 0.0,
        }
    }

    fn decode_long(m: &COMMAND_LONG_DATA) -> Option<Command> {
        let payload = encode(m);
        decode(&frame(COMMAND_LONG_DATA::ID, &payload), &ConsoleConfig::DEFAULT).unwrap()
    }

    #[test]
    fn every_message_has_its_official_crc_extra() {
        // From the official common.xml / ardupilotmega.xml (pymavlink's tables).
        for (id, crc) in [
            (0, 50),
            (1, 124),
            (20, 214),
            (21, 159),
            (22, 220),
            (23, 168),
            (69, 243),
            (76, 152),
            (77, 143),
            (147, 154),
            (253, 83),
            (256, 71),
            (75, 158),
            (148, 178),
            (290, 251),
            (291, 10),
            (11030, 144),
            (11031, 133),
            (110, 84),
            (43, 132),
            (44, 221),
            (45, 232),
            (47, 153),
        ] {
            assert_eq!(extra_crc(id), Some(crc), "message {id}");
        }
        assert_eq!(extra_crc(30), None);
    }

    #[test]
    fn motor_test_parameters_are_clamped() {
        let test = |p: [f32; 4]| decode_long(&long(MAV_CMD_DO_MOTOR_TEST, p));
        assert_eq!(
            test([3.0, 0.0, 25.0, 2.5]),
            Some(Command::MotorTest {
                motor: 3,
                percent: 25,
                duration: Duration::from_millis(2500)
            })
        );
        assert_eq!(
            test([1.0, 0.0, -250.0, 99.0]),
            Some(Command::MotorTest {
                motor: 1,
                percent: -100,
                duration: Duration::from_secs(10)
            })
        );
        assert_eq!(
            test([f32::NAN, 0.0, f32::NAN, f32::NAN]),
            Some(Command::MotorTest {
                motor: 0,
                percent: 0,
                duration: Duration::from_secs(0)
            })
        );
        assert_eq!(
            test([1.0, 0.0, 10.0, -3.0]),
            Some(Command::MotorTest {
                motor: 1,
                percent: 10,
                duration: Duration::from_secs(0)
            })
        );
        // PWM throttle type: not supported.
        assert_eq!(
            test([1.0, 1.0, 1500.0, 1.0]),
            Some(Command::Unsupported { command: 209 })
        );
    }

    #[test]
    fn arm_disarm_and_unknown_commands() {
        assert_eq!(decode_long(&long(400, [1.0, 0.0, 0.0, 0.0])), Some(Command::Arm(true)));
        assert_eq!(decode_long(&long(400, [0.0, 0.0, 0.0, 0.0])), Some(Command::Arm(false)));
        assert_eq!(
            decode_long(&long(400, [-0.0, 0.0, 0.0, 0.0])),
            Some(Command::Arm(false))
        );
        // Neither arm nor disarm: UNSUPPORTED, as ArduPilot answers; never a disarm.
        for param1 in [0.5, 2.0, -1.0, f32::NAN, f32::INFINITY, 1.0 + f32::EPSILON] {
            assert_eq!(
                decode_long(&long(400, [param1, 0.0, 0.0, 0.0])),
                Some(Command::Unsupported { command: 400 }),
                "{param1}"
            );
        }
        assert_eq!(
            decode_long(&long(31012, [0.0; 4])),
            Some(Command::Unsupported { command: 31012 })
        );
    }

    #[test]
    fn command_int_carries_the_same_commands() {
        let int = |command: u16, params: [f32; 4]| {
            let m = COMMAND_INT_DATA {
                target_system: 1,
                target_component: 0,
                frame: 2,
                command,
                current: 0,
                autocontinue: 0,
                param1: params[0],
                param2: params[1],
                param3: params[2],
                param4: params[3],
                x: 7,
                y: 8,
                z: 9.0,
            };
            let payload = encode(&m);
            decode(&frame(COMMAND_INT_DATA::ID, &payload), &ConsoleConfig::DEFAULT).unwrap()
        };
        for (command, params) in [
            (400, [1.0, 0.0, 0.0, 0.0]),
            (400, [0.5, 0.0, 0.0, 0.0]),
            (246, [1.0, 0.0, 0.0, 0.0]),
            (209, [2.0, 0.0, 20.0, 1.0]),
            (512, [148.0, 0.0, 0.0, 0.0]),
            (511, [1.0, 200_000.0, 0.0, 0.0]),
            (520, [1.0, 0.0, 0.0, 0.0]),
            (16, [0.0; 4]),
        ] {
            assert_eq!(int(command, params), decode_long(&long(command, params)), "{command}");
            assert!(int(command, params).is_some());
        }
        assert_eq!(int(16, [0.0; 4]), Some(Command::Unsupported { command: 16 }));
    }

    #[test]
    fn requested_messages_and_intervals() {
        let request = |id: f32| decode_long(&long(512, [id, 0.0, 0.0, 0.0]));
        let asked = |message| {
            Some(Command::RequestMessage {
                command: 512,
                message,
                first: 0,
            })
        };
        assert_eq!(request(148.0), asked(Some(Message::AutopilotVersion)));
        assert_eq!(request(435.0), asked(Some(Message::AvailableModes)));
        assert_eq!(request(0.0), asked(Some(Message::Heartbeat)));
        assert_eq!(request(1.0), asked(Some(Message::SysStatus)));
        assert_eq!(request(147.0), asked(Some(Message::BatteryStatus)));
        assert_eq!(request(290.0), asked(Some(Message::EscInfo)));
        assert_eq!(request(291.0), asked(Some(Message::EscStatus)));
        assert_eq!(request(11030.0), asked(Some(Message::EscTelemetry1To4)));
        assert_eq!(request(11031.0), asked(Some(Message::EscTelemetry5To8)));
        // HOME_POSITION: there is no home; not whole numbers, NaN, negative: no message.
        for id in [242.0, 148.5, f32::NAN, -1.0, 1e12] {
            assert_eq!(request(id), asked(None), "{id}");
        }
        assert_eq!(
            decode_long(&long(520, [1.0, 0.0, 0.0, 0.0])),
            Some(Command::RequestMessage {
                command: 520,
                message: Some(Message::AutopilotVersion),
                first: 0,
            })
        );
        // ESC_INFO and ESC_STATUS: param2 names the block of four by its first thruster, one the vehicle has.
        let block = |id: f32, param2: f32| decode_long(&long(512, [id, param2, 0.0, 0.0]));
        for (id, message) in [(290.0, Message::EscInfo), (291.0, Message::EscStatus)] {
            let asked = |first| {
                Some(Command::RequestMessage {
                    command: 512,
                    message: Some(message),
                    first,
                })
            };
            assert_eq!(block(id, 4.0), asked(4));
            assert_eq!(block(id, 0.0), asked(0));
            for beyond in [2.0, 4.5, 8.0, 255.0, -4.0, f32::NAN] {
                assert_eq!(
                    block(id, beyond),
                    asked(0).map(|_| Command::RequestMessage {
                        command: 512,
                        message: None,
                        first: 0
                    }),
                    "{beyond}"
                );
            }
        }
        // Another message's param2 is not read.
        assert_eq!(block(148.0, 3.0), asked(Some(Message::AutopilotVersion)));
        // Four thrusters: no ESC_TELEMETRY_5_TO_8.
        let four = ConsoleConfig {
            thrusters: 4,
            ..ConsoleConfig::DEFAULT
        };
        assert_eq!(message(11031.0, &four), None);
        assert_eq!(message(11030.0, &four), Some(Message::EscTelemetry1To4));

        assert_eq!(interval(0.0), Some(Interval::Default));
        assert_eq!(interval(-1.0), Some(Interval::Off));
        assert_eq!(interval(250_000.0), Some(Interval::Every(250)));
        assert_eq!(interval(1.0), Some(Interval::Every(MIN_INTERVAL_MS)));
        assert_eq!(interval(1e12), Some(Interval::Every(MAX_INTERVAL_MS)));
        assert_eq!(interval(f32::INFINITY), Some(Interval::Every(MAX_INTERVAL_MS)));
        for bad in [f32::NAN, -2.0, -0.5, f32::NEG_INFINITY] {
            assert_eq!(interval(bad), None, "{bad}");
        }
        assert_eq!(
            decode_long(&long(511, [291.0, -1.0, 0.0, 0.0])),
            Some(Command::MessageInterval {
                message: Some(Message::EscStatus),
                interval: Some(Interval::Off)
            })
        );
    }

    #[test]
    fn reboot_only_of_the_autopilot() {
        assert_eq!(decode_long(&long(246, [1.0, 0.0, 0.0, 0.0])), Some(Command::Reboot));
        for action in [0.0, 2.0, 3.0, f32::NAN] {
            assert_eq!(
                decode_long(&long(246, [action, 0.0, 0.0, 0.0])),
                Some(Command::Unsupported { command: 246 }),
                "{action}"
            );
        }
    }

    #[test]
    fn setup_signing() {
        let m = SETUP_SIGNING_DATA {
            target_system: 1,
            target_component: 0,
            secret_key: [0xA5; 32],
            initial_timestamp: 0x0000_1234_5678_9ABC,
        };
        let payload = encode(&m);
        assert_eq!(
            decode(&frame(SETUP_SIGNING_DATA::ID, &payload), &ConsoleConfig::DEFAULT).unwrap(),
            Some(Command::SetupSigning {
                key: [0xA5; 32],
                timestamp: 0x0000_1234_5678_9ABC
            })
        );
        let other = encode(&SETUP_SIGNING_DATA { target_system: 2, ..m });
        assert_eq!(
            decode(&frame(SETUP_SIGNING_DATA::ID, &other), &ConsoleConfig::DEFAULT).unwrap(),
            None
        );
    }

    #[test]
    fn commands_for_other_systems_or_components_are_ignored() {
        let mut m = long(400, [1.0, 0.0, 0.0, 0.0]);
        m.target_system = 2;
        assert_eq!(decode_long(&m), None);
        m.target_system = 0;
        assert_eq!(decode_long(&m), Some(Command::Arm(true)));
        m.target_component = 154;
        assert_eq!(decode_long(&m), None);
        m.target_component = 0;
        assert_eq!(decode_long(&m), Some(Command::Arm(true)));
    }

    #[test]
    fn manual_control_axes() {
        let m = MANUAL_CONTROL_DATA {
            target: 1,
            x: 2000,
            y: -2000,
            z: i16::MAX,
            r: i16::MAX,
            buttons: 0b1000_0000_0101_0000,
            buttons2: 0xffff,
            ..MANUAL_CONTROL_DATA::DEFAULT
        };
        let payload = encode(&m);
        let got = decode(&frame(MANUAL_CONTROL_DATA::ID, &payload), &ConsoleConfig::DEFAULT).unwrap();
        assert_eq!(
            got,
            Some(Command::Manual(
                ManualInput {
                    x: 1000,
                    y: -1000,
                    z: 500,
                    r: 0
                },
                0b1000_0000_0101_0000
            ))
        );
        let other = encode(&MANUAL_CONTROL_DATA { target: 7, ..m });
        assert_eq!(
            decode(&frame(MANUAL_CONTROL_DATA::ID, &other), &ConsoleConfig::DEFAULT).unwrap(),
            None
        );
    }

    #[test]
    fn a_bad_enum_value_is_an_error_not_a_panic() {
        // HEARTBEAT with type 250 (no such MAV_TYPE).
        let payload = [0, 0, 0, 0, 250, 8, 0, 0, 3];
        assert!(decode(&frame(HEARTBEAT_DATA::ID, &payload), &ConsoleConfig::DEFAULT).is_err());
        // Any length, any bytes: no panic.
        for len in 0..60 {
            let payload: Vec<u8> = (0..len).map(|i| (i * 37 + 11) as u8).collect();
            for (id, _) in MESSAGES {
                let _ = decode(&frame(id, &payload), &ConsoleConfig::DEFAULT);
            }
        }
    }
}
