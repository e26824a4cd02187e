//! The connect sequence of a standard ground station, played against the console and the vehicle tasks on the
//! virtual clock: QGroundControl's InitialConnectStateMachine (src/Vehicle/InitialConnectStateMachine.cc) step by
//! step, answering what the vehicle sends as QGroundControl would, then the message requests and intervals an SDK
//! uses. Frames are built and read with the mavlink crate (our dialect's definitions, copied from the official
//! XML).

use crate::support::{clock, parse_all, v2};
use embassy_futures::block_on;
use embassy_futures::join::join3;
use embassy_futures::select::select;
use embassy_futures::yield_now;
use embassy_time::{Duration, Instant};
use lbv_master_fw::console::lbv::{
    AUTOPILOT_VERSION_DATA, AVAILABLE_MODES_DATA, COMMAND_INT_DATA, COMMAND_LONG_DATA, FILE_TRANSFER_PROTOCOL_DATA,
    MISSION_ACK_DATA, MISSION_CLEAR_ALL_DATA, MISSION_COUNT_DATA, MISSION_REQUEST_LIST_DATA, MavMessage, MavModeFlag,
    MavParamType, MavProtocolCapability, MavResult, MavSysStatusSensor, PARAM_REQUEST_LIST_DATA, PARAM_SET_DATA,
};
use lbv_master_fw::console::{ConsoleConfig, ConsoleStats, console_rx_task, console_tx_task};
use lbv_master_fw::shared::Shared;
use lbv_master_fw::vehicle::{VehicleConfig, vehicle_task};
use lbv_sim::{Queue, SerialRx, SerialTx};
use lbv_station::GCS_HEARTBEAT;
use mavlink_core::MavHeader;

/// QGroundControl's own ids: system 255, MAV_COMP_ID_MISSIONPLANNER (190).
const GCS: (u8, u8) = (255, 190);
const UID: [u8; 12] = [0x31, 0x00, 0x52, 0x00, 0x0B, 0x51, 0x33, 0x32, 0x34, 0x38, 0x37, 0x39];

/// The ground station's end of the link: what it has received so far, and a way to send.
struct Station {
    to_vehicle: Queue<u8>,
    from_vehicle: SerialTx,
    received: Vec<(Instant, MavHeader, MavMessage)>,
    sequence: u8,
}

impl Station {
    fn send<D: mavlink_core::MessageData>(&mut self, message: &D) {
        self.to_vehicle.send(v2(GCS.0, GCS.1, self.sequence, message));
        self.sequence = self.sequence.wrapping_add(1);
    }

    fn heartbeat(&mut self) {
        self.send(&GCS_HEARTBEAT);
    }

    /// A MAVLink FTP request: sequence `seq`, session 0, `opcode`, `offset`, `data` (its length the size).
    fn ftp(&mut self, seq: u16, opcode: u8, offset: u32, data: &[u8]) {
        let mut payload = [0; 251];
        payload[..2].copy_from_slice(&seq.to_le_bytes());
        payload[3] = opcode;
        payload[4] = data.len() as u8;
        payload[8..12].copy_from_slice(&offset.to_le_bytes());
        payload[12..12 + data.len()].copy_from_slice(data);
        self.send(&FILE_TRANSFER_PROTOCOL_DATA {
            target_network: 0,
            target_system: 1,
            target_component: 1,
            payload,
        });
    }

    fn command(&mut self, command: u16, params: [f32; 7]) {
        self.send(&COMMAND_LONG_DATA {
            target_system: 1,
            target_component: 1,
            command,
            confirmation: 0,
            param1: params[0],
            param2: params[1],
            param3: params[2],
            param4: params[3],
            param5: params[4],
            param6: params[5],
            param7: params[6],
        });
    }

    /// Read what the vehicle has sent.
    fn poll(&mut self) {
        let now = Instant::now();
        for (header, message) in parse_all(&self.from_vehicle.take()) {
            self.received.push((now, header, message));
        }
    }

    /// Messages received from index `from` on.
    fn since(&self, from: usize) -> impl Iterator<Item = &MavMessage> {
        self.received.iter().skip(from).map(|(_, _, m)| m)
    }
}

/// Run the console and the vehicle (6 thrusters, defaults, [`UID`]) with `script` playing the ground station:
/// called every millisecond of virtual time with the station, until it returns `true` (done) or `limit` passes.
fn connect(limit: Duration, mut script: impl FnMut(&mut Station) -> bool) -> Station {
    let _clock = clock();
    let shared = Shared::new();
    let stats = ConsoleStats::new();
    let to_vehicle = Queue::new();
    let mut rx = SerialRx::new(to_vehicle.clone());
    let from_vehicle = SerialTx::default();
    let mut tx = from_vehicle.clone();
    let config = ConsoleConfig {
        uid: UID,
        ..ConsoleConfig::DEFAULT
    };
    let vehicle = VehicleConfig::DEFAULT;
    let mut station = Station {
        to_vehicle,
        from_vehicle,
        received: vec![],
        sequence: 0,
    };
    let tasks = join3(
        console_rx_task(
            &mut rx,
            &config,
            &shared,
            &stats,
            &lbv_master_fw::config::VEHICLE.thrusters,
            lbv_master_fw::mixer::FrameKind::Lbv300_6,
            lbv_master_fw::update::CheckOnly,
        ),
        console_tx_task(&mut tx, &config, &shared, &stats),
        vehicle_task(vehicle, vehicle.defaults(), &shared),
    );
    let mut done = false;
    block_on(select(tasks, async {
        let end = Instant::now() + limit;
        while Instant::now() < end && !done {
            for _ in 0..8 {
                yield_now().await;
            }
            station.poll();
            done = script(&mut station);
            lbv_sim::clock::advance(Duration::from_millis(1));
        }
    }));
    assert!(done, "the ground station's script did not finish");
    station
}

const REQUEST_MESSAGE: u16 = 512;
const REQUEST_AUTOPILOT_CAPABILITIES: u16 = 520;
const SET_MESSAGE_INTERVAL: u16 = 511;
const ARM_DISARM: u16 = 400;

/// The index of the first message from `from` on that `matches`.
fn find(station: &Station, from: usize, matches: impl Fn(&MavMessage) -> bool) -> Option<usize> {
    station.since(from).position(matches).map(|n| n + from)
}

fn ack(command: u16) -> impl Fn(&MavMessage) -> bool {
    move |m| matches!(m, MavMessage::COMMAND_ACK(a) if a.command == command)
}

/// The station after it has sent a heartbeat and what `send` sends, once, and listened for `listen`.
fn heard_after(listen: Duration, send: impl FnOnce(&mut Station)) -> Station {
    let mut send = Some(send);
    connect(listen + Duration::from_millis(500), |gcs| {
        if let Some(send) = send.take() {
            gcs.heartbeat();
            send(gcs);
        }
        Instant::now() >= Instant::from_ticks(0) + listen
    })
}

/// The results of every COMMAND_ACK of `command`, in order.
fn ack_results(station: &Station, command: u16) -> Vec<MavResult> {
    station
        .since(0)
        .filter_map(|m| match m {
            MavMessage::COMMAND_ACK(a) if a.command == command => Some(a.result),
            _ => None,
        })
        .collect()
}

fn ack_result(station: &Station, at: usize) -> MavResult {
    match &station.received[at].2 {
        MavMessage::COMMAND_ACK(a) => {
            assert_eq!((a.target_system, a.target_component), GCS, "addressed to the asker");
            a.result
        }
        other => panic!("not an ack: {other:?}"),
    }
}

fn prearm_healthy(m: &MavMessage) -> Option<bool> {
    match m {
        MavMessage::SYS_STATUS(s) => {
            let bit = MavSysStatusSensor::MAV_SYS_STATUS_PREARM_CHECK;
            assert!(s.onboard_control_sensors_present.contains(bit));
            assert!(s.onboard_control_sensors_enabled.contains(bit));
            Some(s.onboard_control_sensors_health.contains(bit))
        }
        _ => None,
    }
}

/// The AUTOPILOT_VERSION QGroundControl reads: version, git hash (ASCII, as for ArduPilot), capabilities, ids.
fn check_autopilot_version(v: &AUTOPILOT_VERSION_DATA) {
    let part = |name: &str| name.parse::<u32>().unwrap();
    let major = part(env!("CARGO_PKG_VERSION_MAJOR"));
    let minor = part(env!("CARGO_PKG_VERSION_MINOR"));
    let patch = part(env!("CARGO_PKG_VERSION_PATCH"));
    assert_eq!(v.flight_sw_version >> 8, major << 16 | minor << 8 | patch);
    // FIRMWARE_VERSION_TYPE: DEV for a pre-release, BETA below 1.0 (QGroundControl compares an OFFICIAL one with
    // ArduSub's releases), OFFICIAL from 1.0 on.
    let kind = if !env!("CARGO_PKG_VERSION_PRE").is_empty() {
        0
    } else if major == 0 {
        128
    } else {
        255
    };
    assert_eq!(v.flight_sw_version & 0xFF, kind, "FIRMWARE_VERSION_TYPE");
    let hash = v.flight_custom_version;
    assert!(
        hash == [0; 8] || hash.iter().all(u8::is_ascii_hexdigit),
        "8 hex digits of the git revision, or zeros outside git: {hash:?}"
    );
    let caps = v.capabilities;
    for needed in [
        MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_MAVLINK2,
        MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_COMMAND_INT,
        MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST,
    ] {
        assert!(caps.contains(needed), "{needed:?}");
    }
    // No mission, fence, rally, FTP: QGroundControl skips the fence and rally downloads.
    for absent in [
        MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT,
        MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_MISSION_INT,
        MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_MISSION_FENCE,
        MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_MISSION_RALLY,
        MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_FTP,
        MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE,
    ] {
        assert!(!caps.contains(absent), "{absent:?}");
    }
    assert_eq!(caps.bits() & 2, 0, "not the deprecated PARAM_FLOAT");
    assert_eq!((v.vendor_id, v.product_id), (0x0483, 0x0469));
    // An image that takes development-key files says so (the host build does unless LBV_UPDATE_KEY names another).
    let dev_key = if update_image::UPDATE_KEY_IS_DEV {
        *b"DEVKEY\0\0"
    } else {
        [0; 8]
    };
    assert_eq!(v.middleware_custom_version, dev_key);
    assert_eq!(&v.uid2[..12], &UID);
    assert_eq!(&v.uid2[12..], &[0; 6]);
    let word = |n: usize| u32::from_le_bytes(UID[n * 4..n * 4 + 4].try_into().unwrap());
    assert_eq!(v.uid, u64::from(word(0)) | u64::from(word(1) ^ word(2)) << 32);
}

/// QGroundControl's connect on an ArduPilot vehicle: the parameters from `@PARAM/param.pck` over MAVLink FTP.
#[test]
fn qgroundcontrol_initial_connect_then_arm() {
    qgroundcontrol_connect_then_arm(true);
}

/// QGroundControl's connect without the parameter file (a vehicle without MAVLink FTP, or a download that failed):
/// the parameter list.
#[test]
fn qgroundcontrol_initial_connect_by_the_parameter_list_then_arm() {
    qgroundcontrol_connect_then_arm(false);
}

fn qgroundcontrol_connect_then_arm(with_file: bool) {
    #[derive(Debug, Clone, Copy, PartialEq)]
    enum Step {
        /// Listen before saying anything: the vehicle's heartbeat, and its pre-arm check unhealthy without a
        /// ground station.
        Listen,
        /// An arm now must be refused: the pre-arm bit said so.
        ArmTooEarly {
            sent: usize,
        },
        /// Heartbeats from now on; REQUEST_MESSAGE AUTOPILOT_VERSION (QGroundControl asks component 1).
        RequestVersion {
            sent: usize,
        },
        /// The older MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES (what QGroundControl's older releases and some SDKs send).
        RequestCapabilities {
            sent: usize,
        },
        /// What QGroundControl asks for after AUTOPILOT_VERSION ([`ASKED`]), each answered at once.
        Ask {
            sent: usize,
            n: usize,
        },
        /// ParameterManager on an ArduPilot vehicle: `@PARAM/param.pck?withdefaults=1` over MAVLink FTP
        /// (OpenFileRO, BurstReadFile from where each reply ends until EndOfFile, TerminateSession).
        ParamFile {
            sent: usize,
        },
        /// ParameterManager::refreshAllParameters, QGroundControl's way without the file: PARAM_REQUEST_LIST, then
        /// every PARAM_VALUE.
        Parameters {
            sent: usize,
        },
        /// The mission download QGroundControl starts whatever the capabilities say (MissionManager's
        /// loadFromVehicle): MISSION_REQUEST_LIST, answered at once with MISSION_COUNT 0 of the type asked, so no
        /// retry and no "Mission transfer failed".
        Mission {
            sent: usize,
        },
        /// Wait for SYS_STATUS's pre-arm check to turn healthy (the capabilities announced no fence or rally, so
        /// those downloads are skipped).
        WaitArmable {
            from: usize,
        },
        /// Arm.
        Arm {
            sent: usize,
        },
        Done,
    }
    let mut step = Step::Listen;
    let mut last_heartbeat: Option<Instant> = None;
    let mut versions = 0;
    // param.pck: its length by the open's ACK, its bytes, and the FTP requests' sequence.
    let mut pck_len = None;
    let mut pck = Vec::new();
    let mut ftp_seq = 0u16;
    let mut connected = None;
    let station = connect(Duration::from_secs(20), |gcs| {
        let now = Instant::now();
        let talking = !matches!(step, Step::Listen | Step::ArmTooEarly { .. });
        if talking && last_heartbeat.is_none_or(|at| now - at >= Duration::from_secs(1)) {
            gcs.heartbeat();
            last_heartbeat = Some(now);
        }
        let len = gcs.received.len();
        step = match step {
            Step::Listen => {
                let heard = gcs.since(0).any(|m| matches!(m, MavMessage::HEARTBEAT(_)));
                let prearm = gcs.since(0).find_map(prearm_healthy);
                match prearm {
                    Some(healthy) if heard => {
                        assert!(!healthy, "no ground station yet: arming would be refused");
                        gcs.command(ARM_DISARM, [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
                        Step::ArmTooEarly { sent: len }
                    }
                    _ => Step::Listen,
                }
            }
            Step::ArmTooEarly { sent } => match find(gcs, sent, ack(ARM_DISARM)) {
                Some(at) => {
                    assert_eq!(ack_result(gcs, at), MavResult::MAV_RESULT_TEMPORARILY_REJECTED);
                    gcs.heartbeat();
                    last_heartbeat = Some(now);
                    gcs.command(REQUEST_MESSAGE, [148.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
                    Step::RequestVersion {
                        sent: gcs.received.len(),
                    }
                }
                None => step,
            },
            Step::RequestVersion { sent } | Step::RequestCapabilities { sent } => {
                let command = if matches!(step, Step::RequestVersion { .. }) {
                    REQUEST_MESSAGE
                } else {
                    REQUEST_AUTOPILOT_CAPABILITIES
                };
                let acked = find(gcs, sent, ack(command));
                let version = find(gcs, sent, |m| matches!(m, MavMessage::AUTOPILOT_VERSION(_)));
                match (acked, version) {
                    (Some(a), Some(v)) => {
                        assert!(a < v, "the COMMAND_ACK comes before the message");
                        assert_eq!(ack_result(gcs, a), MavResult::MAV_RESULT_ACCEPTED);
                        let MavMessage::AUTOPILOT_VERSION(version) = &gcs.received[v].2 else {
                            unreachable!()
                        };
                        check_autopilot_version(version);
                        versions += 1;
                        if command == REQUEST_MESSAGE {
                            gcs.command(REQUEST_AUTOPILOT_CAPABILITIES, [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
                            Step::RequestCapabilities {
                                sent: gcs.received.len(),
                            }
                        } else {
                            gcs.command(REQUEST_MESSAGE, [ASKED[0].0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
                            Step::Ask {
                                sent: gcs.received.len(),
                                n: 0,
                            }
                        }
                    }
                    _ => step,
                }
            }
            Step::Ask { sent, n } => match find(gcs, sent, ack(REQUEST_MESSAGE)) {
                Some(at) => {
                    let (message, accepted) = ASKED[n];
                    let result = ack_result(gcs, at);
                    assert_eq!(
                        result == MavResult::MAV_RESULT_ACCEPTED,
                        accepted,
                        "{message}: {result:?}"
                    );
                    assert!(
                        gcs.received[at].0 - gcs.received[sent.saturating_sub(1)].0 < Duration::from_millis(100),
                        "{message} answered at once"
                    );
                    if let Some(&(next, _)) = ASKED.get(n + 1) {
                        gcs.command(REQUEST_MESSAGE, [next, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
                        Step::Ask {
                            sent: gcs.received.len(),
                            n: n + 1,
                        }
                    } else if with_file {
                        gcs.ftp(ftp_seq, OPEN_RO, 0, b"@PARAM/param.pck?withdefaults=1");
                        Step::ParamFile {
                            sent: gcs.received.len(),
                        }
                    } else {
                        gcs.send(&PARAM_REQUEST_LIST_DATA {
                            target_system: 1,
                            target_component: 1,
                        });
                        Step::Parameters {
                            sent: gcs.received.len(),
                        }
                    }
                }
                None => step,
            },
            Step::ParamFile { sent } => match find(gcs, sent, |m| matches!(m, MavMessage::FILE_TRANSFER_PROTOCOL(_))) {
                Some(at) => {
                    let MavMessage::FILE_TRANSFER_PROTOCOL(reply) = &gcs.received[at].2 else {
                        unreachable!()
                    };
                    let reply = reply.payload;
                    let (opcode, size, asked) = (reply[3], usize::from(reply[4]), reply[5]);
                    assert_eq!(
                        u16::from_le_bytes([reply[0], reply[1]]),
                        ftp_seq + 1,
                        "answers the request"
                    );
                    let data = &reply[12..12 + size];
                    ftp_seq += 1;
                    match (opcode, asked) {
                        (ACK, OPEN_RO) => {
                            pck_len = Some(u32::from_le_bytes(data.try_into().unwrap()) as usize);
                            gcs.ftp(ftp_seq, BURST, 0, &[0; 239]);
                        }
                        (ACK, BURST) => {
                            pck.extend_from_slice(data);
                            gcs.ftp(ftp_seq, BURST, pck.len() as u32, &[0; 239]);
                        }
                        (NAK, BURST) => {
                            assert_eq!(data, [EOF], "the end of the file");
                            assert_eq!(Some(pck.len()), pck_len, "the length the open gave");
                            // With defaults; 64 parameters of 64; the first, FS_GCS_ENABLE 2, at its default.
                            assert_eq!(pck[..6], [0x1C, 0x67, 64, 0, 64, 0]);
                            assert_eq!(pck[6..22], *b"\x01\xC0FS_GCS_ENABLE\x02");
                            let names = pck_names(&pck);
                            assert_eq!(names.len(), 64);
                            setup_reads_nothing_missing(&names);
                            gcs.ftp(ftp_seq, TERMINATE, 0, &[]);
                        }
                        (ACK, TERMINATE) => {
                            gcs.send(&MISSION_REQUEST_LIST_DATA {
                                target_system: 1,
                                target_component: 1,
                                mission_type: 0,
                            });
                        }
                        other => panic!("param.pck: {other:?} {data:?}"),
                    }
                    let sent = gcs.received.len();
                    if (opcode, asked) == (ACK, TERMINATE) {
                        Step::Mission { sent }
                    } else {
                        Step::ParamFile { sent }
                    }
                }
                None => step,
            },
            Step::Parameters { sent } => {
                let values: Vec<_> = gcs
                    .since(sent)
                    .filter_map(|m| match m {
                        MavMessage::PARAM_VALUE(p) => Some(p.clone()),
                        _ => None,
                    })
                    .collect();
                match values.first() {
                    Some(first) if values.len() == usize::from(first.param_count) => {
                        // Ten of the vehicle's, the sixteen joystick buttons' functions (BTNn_FUNCTION), which
                        // QGroundControl's ArduSub joystick setup shows, LBV_GCS_NEUTRAL, and 37 read-only
                        // stand-ins for what its setup pages read.
                        assert_eq!(first.param_count, 64);
                        for (n, p) in values.iter().enumerate() {
                            assert_eq!(usize::from(p.param_index), n);
                            let name = p.param_id.to_str().unwrap();
                            let expected = ardusub_type(name);
                            assert_eq!(p.param_type, expected, "{name}");
                            if expected != MavParamType::MAV_PARAM_TYPE_REAL32 {
                                assert_eq!(p.param_value.fract(), 0.0, "C_CAST: the float is the integer");
                            }
                        }
                        let names: Vec<String> = values
                            .iter()
                            .map(|p| p.param_id.to_str().unwrap().to_string())
                            .collect();
                        setup_reads_nothing_missing(&names);
                        let value = |name: &str| {
                            values
                                .iter()
                                .find(|p| p.param_id.to_str().unwrap() == name)
                                .map(|p| p.param_value)
                        };
                        assert_eq!(value("SYSID_MYGCS"), Some(255.0));
                        assert_eq!(value("BTN6_FUNCTION"), Some(3.0), "ArduSub's arm");
                        assert_eq!(value("BTN15_FUNCTION"), Some(0.0));
                        gcs.send(&MISSION_REQUEST_LIST_DATA {
                            target_system: 1,
                            target_component: 1,
                            mission_type: 0,
                        });
                        Step::Mission {
                            sent: gcs.received.len(),
                        }
                    }
                    _ => step,
                }
            }
            Step::Mission { sent } => match find(gcs, sent, |m| matches!(m, MavMessage::MISSION_COUNT(_))) {
                Some(at) => {
                    let MavMessage::MISSION_COUNT(count) = &gcs.received[at].2 else {
                        unreachable!()
                    };
                    let answered = (
                        count.target_system,
                        count.target_component,
                        count.count,
                        count.mission_type,
                    );
                    assert_eq!(answered, (GCS.0, GCS.1, 0, 0), "an empty mission, to QGroundControl");
                    assert!(
                        gcs.received[at].0 - gcs.received[sent.saturating_sub(1)].0 < Duration::from_millis(100),
                        "answered at once: QGroundControl waits for nothing"
                    );
                    connected = Some(gcs.received[at].0);
                    Step::WaitArmable {
                        from: gcs.received.len(),
                    }
                }
                None => step,
            },
            Step::WaitArmable { from } => {
                if gcs.since(from).filter_map(prearm_healthy).any(|healthy| healthy) {
                    gcs.command(ARM_DISARM, [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
                    Step::Arm {
                        sent: gcs.received.len(),
                    }
                } else {
                    step
                }
            }
            Step::Arm { sent } => {
                let acked = find(gcs, sent, ack(ARM_DISARM));
                let armed = acked.and_then(|a| {
                    find(gcs, a, |m| {
                        matches!(m, MavMessage::HEARTBEAT(h)
                            if h.base_mode.contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED))
                    })
                });
                match (acked, armed) {
                    (Some(a), Some(_)) => {
                        assert_eq!(ack_result(gcs, a), MavResult::MAV_RESULT_ACCEPTED);
                        Step::Done
                    }
                    _ => step,
                }
            }
            Step::Done => Step::Done,
        };
        step == Step::Done
    });
    assert_eq!(versions, 2);
    // The connect (up to the mission list) within 5 s of the vehicle's first heartbeat: nothing waited for a
    // timeout. (This link carries frames at once; the time a 115200 baud line takes is the bench's to tell.)
    let first_heartbeat = station
        .received
        .iter()
        .find(|(_, _, m)| matches!(m, MavMessage::HEARTBEAT(_)))
        .map(|(at, ..)| *at)
        .unwrap();
    let connect_time = connected.unwrap() - first_heartbeat;
    assert!(connect_time < Duration::from_secs(5), "{connect_time:?}");
    // Every frame came from the vehicle's own system and component.
    assert!(
        station
            .received
            .iter()
            .all(|(_, h, _)| (h.system_id, h.component_id) == (1, 1))
    );
}

/// MAV_CMD_DO_SET_MODE.
const SET_MODE: u16 = 176;

/// What QGroundControl's ArduPilot plugin reads, on an ArduSub below 3.5, once the parameters are in: the sensors
/// check that decides whether it opens Vehicle Setup (APMSensorsComponent: the accelerometer's offsets, the compass
/// ids) and the setup pages' summaries (APMSensorParams, the flight modes, safety, lights and power summaries).
/// Any of them missing raises "Parameters are missing from firmware".
fn setup_reads() -> Vec<String> {
    let mut names: Vec<String> = ["COMPASS_DEV_ID", "COMPASS_DEV_ID2", "COMPASS_DEV_ID3", "COMPASS_DEC"]
        .into_iter()
        .chain([
            "FS_EKF_ACTION",
            "FS_LEAK_ENABLE",
            "FS_TEMP_ENABLE",
            "FS_PRESS_ENABLE",
            "BATT_MONITOR",
        ])
        .chain(["FS_GCS_ENABLE", "FS_PILOT_INPUT", "FS_PILOT_TIMEOUT"])
        .map(String::from)
        .collect();
    for axis in ["X", "Y", "Z"] {
        names.push(format!("INS_ACCOFFS_{axis}"));
        names.extend(["", "2", "3"].map(|n| format!("COMPASS_OFS{n}_{axis}")));
    }
    names.extend((1..=6).map(|n| format!("FLTMODE{n}")));
    names.extend((5..=14).map(|n| format!("SERVO{n}_FUNCTION")));
    names
}

/// Every name QGroundControl's setup reads is among `names` (their values: the vehicle's tests of the stand-ins).
fn setup_reads_nothing_missing(names: &[String]) {
    let missing: Vec<String> = setup_reads().into_iter().filter(|n| !names.contains(n)).collect();
    assert!(missing.is_empty(), "missing from the vehicle's parameters: {missing:?}");
}

/// A parameter's MAVLink type as ArduSub declares the parameter of that name (AP_Float and AP_Vector3f REAL32,
/// AP_Int16, AP_Int32), INT8 for the others.
fn ardusub_type(name: &str) -> MavParamType {
    let float = ["FS_GCS_TIMEOUT", "FS_PILOT_TIMEOUT", "COMPASS_DEC"].contains(&name)
        || name.starts_with("INS_ACCOFFS_")
        || name.starts_with("COMPASS_OFS");
    if float {
        MavParamType::MAV_PARAM_TYPE_REAL32
    } else if name == "SYSID_MYGCS" || (name.starts_with("SERVO") && name.ends_with("_FUNCTION")) {
        MavParamType::MAV_PARAM_TYPE_INT16
    } else if name.starts_with("COMPASS_DEV_ID") {
        MavParamType::MAV_PARAM_TYPE_INT32
    } else {
        MavParamType::MAV_PARAM_TYPE_INT8
    }
}

/// The names in a `param.pck` file, read as ArduPilot's `param_unpack.py` reads it: zeros between parameters are
/// padding; a type byte (low nibble: 1 INT8, 2 INT16, 3 INT32, 4 FLOAT; bit 4, a default follows), a byte of the
/// name bytes shared with the previous name and those of its own, less one, the name's own bytes, the value.
fn pck_names(file: &[u8]) -> Vec<String> {
    let with_defaults = file[..2] == [0x1C, 0x67];
    let (mut at, mut names, mut last) = (6, Vec::new(), Vec::new());
    while at < file.len() {
        if file[at] == 0 {
            at += 1;
            continue;
        }
        let size = match file[at] & 0x0F {
            1 => 1,
            2 => 2,
            3 | 4 => 4,
            other => panic!("type {other} at {at}"),
        };
        let defaulted = with_defaults && file[at] & 0x10 != 0;
        let (shared, own) = (usize::from(file[at + 1] & 0x0F), usize::from(file[at + 1] >> 4) + 1);
        let mut name: Vec<u8> = last[..shared].to_vec();
        name.extend_from_slice(&file[at + 2..at + 2 + own]);
        at += 2 + own + size * (1 + usize::from(defaulted));
        names.push(String::from_utf8(name.clone()).unwrap());
        last = name;
    }
    names
}

/// What QGroundControl asks for after AUTOPILOT_VERSION, in its InitialConnectStateMachine's order, and whether the
/// vehicle has it: AVAILABLE_MODES (435, StandardModes: the mode menu), then its component metadata
/// (COMPONENT_METADATA, 397) and the older COMPONENT_INFORMATION (395) it falls back to. The vehicle has no
/// metadata to give: a refusal at once lets QGroundControl go on without waiting out its retries.
const ASKED: [(f32, bool); 3] = [(435.0, true), (397.0, false), (395.0, false)];

// MAVLink FTP's opcodes, replies and EndOfFile.
const TERMINATE: u8 = 1;
const OPEN_RO: u8 = 4;
const BURST: u8 = 15;
const ACK: u8 = 128;
const NAK: u8 = 129;
const EOF: u8 = 6;

#[test]
fn a_plan_is_cleared_at_once_and_an_upload_refused_as_a_vehicle_without_missions_does() {
    let station = heard_after(Duration::from_millis(500), |gcs| {
        // QGroundControl's "clear" of the mission, the fence and the rally points; an upload of two items; an
        // empty upload, which is the plan the vehicle has.
        for mission_type in [0, 1, 2] {
            gcs.send(&MISSION_CLEAR_ALL_DATA {
                target_system: 1,
                target_component: 1,
                mission_type,
            });
        }
        for count in [2, 0] {
            gcs.send(&MISSION_COUNT_DATA {
                target_system: 1,
                target_component: 1,
                count,
                mission_type: 0,
                opaque_id: 0,
            });
        }
    });
    let acks: Vec<(u8, u8, u8, u8)> = station
        .since(0)
        .filter_map(|m| match m {
            MavMessage::MISSION_ACK(a) => Some((a.target_system, a.target_component, a.mavtype, a.mission_type)),
            _ => None,
        })
        .collect();
    // MAV_MISSION_ACCEPTED for each clear and the empty upload, MAV_MISSION_UNSUPPORTED for the other, each to
    // who asked, of the type asked; at once, so nothing waits for a retry.
    assert_eq!(
        acks,
        [
            (255, 190, 0, 0),
            (255, 190, 0, 1),
            (255, 190, 0, 2),
            (255, 190, 3, 0),
            (255, 190, 0, 0)
        ]
    );
    // The CRC_EXTRA the MAVLink generator gives the official definitions (pymavlink's common dialect).
    assert_eq!(<MISSION_ACK_DATA as mavlink_core::MessageData>::EXTRA_CRC, 153);
    assert_eq!(<MISSION_CLEAR_ALL_DATA as mavlink_core::MessageData>::EXTRA_CRC, 232);
}

#[test]
fn the_mode_menu_shows_the_one_mode_there_is_and_takes_only_it() {
    let mut phase = 0;
    let station = connect(Duration::from_secs(3), |gcs| {
        if phase == 0 {
            gcs.heartbeat();
            // QGroundControl's StandardModes: every mode (param2 0), then its menu's choices, MANUAL and ALT_HOLD.
            gcs.command(REQUEST_MESSAGE, [435.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
            gcs.command(SET_MODE, [1.0, 19.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
            gcs.command(SET_MODE, [1.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
            phase = 1;
        }
        Instant::now() >= Instant::from_secs(2)
    });
    let modes: Vec<_> = station
        .since(0)
        .filter_map(|m| match m {
            MavMessage::AVAILABLE_MODES(m) => Some(m.clone()),
            _ => None,
        })
        .collect();
    assert_eq!(modes.len(), 1, "{modes:?}");
    let manual = &modes[0];
    assert_eq!(
        (
            manual.number_modes,
            manual.mode_index,
            manual.standard_mode,
            manual.custom_mode
        ),
        (1, 1, 0, 19),
        "ArduSub's MANUAL, the mode HEARTBEAT reports"
    );
    assert_eq!(manual.mode_name.to_str().unwrap(), "MANUAL");
    assert_eq!(
        <AVAILABLE_MODES_DATA as mavlink_core::MessageData>::EXTRA_CRC,
        134,
        "the CRC_EXTRA the MAVLink generator gives the official definition"
    );
    assert_eq!(
        ack_results(&station, SET_MODE),
        [MavResult::MAV_RESULT_ACCEPTED, MavResult::MAV_RESULT_DENIED]
    );
    let said: Vec<String> = station
        .since(0)
        .filter_map(|m| match m {
            MavMessage::STATUSTEXT(t) => Some(t.text.to_str().unwrap().to_string()),
            _ => None,
        })
        .collect();
    assert!(
        said.iter()
            .any(|t| t == "Mode: MANUAL only, no depth or heading sensor"),
        "{said:?}"
    );
}

#[test]
fn request_message_and_message_intervals_as_an_sdk_uses_them() {
    let mut sent_at = None;
    let mut phase = 0;
    let station = connect(Duration::from_secs(6), |gcs| {
        let now = Instant::now();
        if phase == 0 {
            gcs.heartbeat();
            // Each message the vehicle sends, one at a time; HOME_POSITION (242) it has not; ESC_STATUS off;
            // SYS_STATUS at 5 Hz; HEARTBEAT may not be changed; COMMAND_INT carries the same request.
            for id in [0.0, 1.0, 147.0, 148.0, 290.0, 291.0, 11030.0, 11031.0, 242.0] {
                gcs.command(REQUEST_MESSAGE, [id, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
            }
            gcs.command(SET_MESSAGE_INTERVAL, [291.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
            gcs.command(SET_MESSAGE_INTERVAL, [1.0, 200_000.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
            gcs.command(SET_MESSAGE_INTERVAL, [0.0, 2_000_000.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
            gcs.command(SET_MESSAGE_INTERVAL, [242.0, 1_000_000.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
            gcs.send(&COMMAND_INT_DATA {
                target_system: 1,
                target_component: 1,
                frame: 0,
                command: REQUEST_MESSAGE,
                current: 0,
                autocontinue: 0,
                param1: 148.0,
                param2: 0.0,
                param3: 0.0,
                param4: 0.0,
                x: 0,
                y: 0,
                z: 0.0,
            });
            sent_at = Some(now);
            phase = 1;
        }
        now >= Instant::from_secs(5)
    });
    let start = sent_at.unwrap();
    let answers: Vec<&MavMessage> = station
        .received
        .iter()
        .filter(|(at, _, _)| *at >= start && *at < start + Duration::from_millis(100))
        .map(|(_, _, m)| m)
        .filter(|m| !matches!(m, MavMessage::STATUSTEXT(_)))
        .collect();
    // Every request answered in order: ACCEPTED and the message, or DENIED.
    let results: Vec<(u16, MavResult)> = answers
        .iter()
        .filter_map(|m| match m {
            MavMessage::COMMAND_ACK(a) => Some((a.command, a.result)),
            _ => None,
        })
        .collect();
    use MavResult::{MAV_RESULT_ACCEPTED as OK, MAV_RESULT_DENIED as NO};
    assert_eq!(
        results,
        [
            (512, OK),
            (512, OK),
            (512, OK),
            (512, OK),
            (512, OK),
            (512, OK),
            (512, OK),
            (512, OK),
            (512, NO),
            (511, OK),
            (511, OK),
            (511, NO),
            (511, NO),
            (512, OK),
        ]
    );
    let mut after_ack = vec![];
    for pair in answers.windows(2) {
        if let MavMessage::COMMAND_ACK(a) = pair[0]
            && a.command == 512
            && a.result == OK
        {
            use mavlink_core::Message;
            after_ack.push(pair[1].message_id());
        }
    }
    assert_eq!(after_ack, [0, 1, 147, 148, 290, 291, 11030, 11031, 148]);

    // From then on: no ESC_STATUS; SYS_STATUS at 5 Hz; HEARTBEAT still at 1 Hz.
    let later = |id: u32| {
        use mavlink_core::Message;
        station
            .received
            .iter()
            .filter(|(at, _, m)| *at >= start + Duration::from_millis(100) && m.message_id() == id)
            .count()
    };
    assert_eq!(later(291), 0);
    let sys = later(1);
    assert!((22..=25).contains(&sys), "about 5 Hz over 4.9 s: {sys}");
    let hb = later(0);
    assert!((4..=5).contains(&hb), "1 Hz: {hb}");
}

#[test]
fn an_esc_block_is_asked_for_by_its_index() {
    let station = heard_after(Duration::from_millis(500), |gcs| {
        // Stop the periodic ESC messages, then ask for each block of the six thrusters, ESC_INFO by REQUEST_MESSAGE's
        // param2, and for one that is no block (2) and one beyond them (8).
        gcs.command(SET_MESSAGE_INTERVAL, [290.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        gcs.command(SET_MESSAGE_INTERVAL, [291.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        for (id, index) in [(290.0, 4.0), (290.0, 0.0), (291.0, 4.0), (290.0, 2.0), (291.0, 8.0)] {
            gcs.command(REQUEST_MESSAGE, [id, index, 0.0, 0.0, 0.0, 0.0, 0.0]);
        }
    });
    // From the periodic ones' end on.
    let stopped =
        find(&station, 0, ack(SET_MESSAGE_INTERVAL)).and_then(|at| find(&station, at + 1, ack(SET_MESSAGE_INTERVAL)));
    let got: Vec<(u32, u8)> = station
        .since(stopped.unwrap())
        .filter_map(|m| match m {
            MavMessage::ESC_INFO(m) => Some((290, m.index)),
            MavMessage::ESC_STATUS(m) => Some((291, m.index)),
            _ => None,
        })
        .collect();
    assert_eq!(got, [(290, 4), (290, 0), (291, 4)]);
    use MavResult::{MAV_RESULT_ACCEPTED as OK, MAV_RESULT_DENIED as NO};
    assert_eq!(ack_results(&station, REQUEST_MESSAGE), [OK, OK, OK, NO, NO]);
}

#[test]
fn an_sdk_sets_an_integer_parameter_as_its_type() {
    let mut phase = 0;
    let station = connect(Duration::from_secs(2), |gcs| {
        let set = |gcs: &mut Station, name: &str, value: f32, param_type| {
            let mut id = [0u8; 16];
            id[..name.len()].copy_from_slice(name.as_bytes());
            gcs.send(&PARAM_SET_DATA {
                target_system: 1,
                target_component: 1,
                param_id: id.into(),
                param_value: value,
                param_type,
            });
        };
        if phase == 0 {
            gcs.heartbeat();
            // The SDK's integer set (C_CAST, the capability announced), then an INT32 one of the same INT8
            // parameter, and PX4's bytewise encoding of 1 for it (raw bits: a denormal, not a whole number).
            set(gcs, "FS_PILOT_INPUT", 2.0, MavParamType::MAV_PARAM_TYPE_INT8);
            set(gcs, "FS_PILOT_INPUT", 0.0, MavParamType::MAV_PARAM_TYPE_INT32);
            set(
                gcs,
                "FS_PILOT_INPUT",
                f32::from_bits(1),
                MavParamType::MAV_PARAM_TYPE_INT8,
            );
            phase = 1;
        }
        Instant::now() >= Instant::from_millis(1500)
    });
    let values: Vec<(f32, MavParamType)> = station
        .since(0)
        .filter_map(|m| match m {
            MavMessage::PARAM_VALUE(p) => Some((p.param_value, p.param_type)),
            _ => None,
        })
        .collect();
    let int8 = MavParamType::MAV_PARAM_TYPE_INT8;
    // Set; unchanged (wrong type); unchanged (not a whole number): the failsafe stays "disarm".
    assert_eq!(values, [(2.0, int8), (2.0, int8), (2.0, int8)]);
}
