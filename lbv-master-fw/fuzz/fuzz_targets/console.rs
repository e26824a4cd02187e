//! The console's receive path and the vehicle, end to end: bytes -> frame parser -> signing checks -> decoder ->
//! vehicle, on a clock the input moves. Two kinds of input:
//!
//! - A line: raw bytes, well-formed frames from any system (signed or not, when a key is set), pauses of the line
//!   and time passing, in any mix. Nothing panics; after every step every parameter is in its range; the
//!   vehicle arms only on an arm command from the operator's system (`SYSID_MYGCS` before the command); after a
//!   pause the parser holds nothing, so whatever noise came before cannot hide the next frame.
//! - A clean stream: well-formed frames only (those of messages outside the dialect too), cut into chunks of any
//!   size, with pauses only between frames. It comes out unchanged: exactly the requests each frame gives on its
//!   own, in order, with nothing counted as bad or skipped.
#![no_main]

use arbitrary::Arbitrary;
use embassy_time::Instant;
use lbv_master_fw::console::lbv::{
    COMMAND_LONG_DATA, HEARTBEAT_DATA, MANUAL_CONTROL_DATA, MavAutopilot, MavModeFlag, MavParamType, MavState, MavType,
    PARAM_REQUEST_LIST_DATA, PARAM_REQUEST_READ_DATA, PARAM_SET_DATA, SETUP_SIGNING_DATA,
};
use lbv_master_fw::console::{ConsoleConfig, ConsoleStats, Received, Receiver};
use lbv_master_fw::params::{Param, Settings};
use lbv_master_fw::shared::{Command, Outgoing, Request};
use lbv_master_fw::signing::{SIGNATURE_LEN, SigningState};
use lbv_master_fw::vehicle::{Vehicle, VehicleConfig};
// The host's time driver (virtual time; the harness passes its own instants).
use lbv_sim as _;
use libfuzzer_sys::fuzz_target;
use mavlink_core::{MAVLinkV1MessageRaw, MAVLinkV2MessageRaw, MavHeader, MessageData};

/// A message a ground station (or anyone) might send.
#[derive(Arbitrary, Debug, Clone)]
enum Message {
    Heartbeat {
        gcs: bool,
    },
    Manual {
        target: u8,
        x: i16,
        y: i16,
        z: i16,
        r: i16,
    },
    Command {
        target: (u8, u8),
        command: Cmd,
        params: [f32; 4],
    },
    ParamList {
        target: (u8, u8),
    },
    ParamRead {
        target: (u8, u8),
        name: Name,
        index: i16,
    },
    ParamSet {
        target: (u8, u8),
        name: Name,
        value: f32,
    },
    SetupSigning {
        target: (u8, u8),
        key: [u8; 32],
        timestamp: u64,
    },
    /// A message outside the dialect (framed by its length, payload as given).
    Unknown {
        id: u16,
        payload: Vec<u8>,
    },
}

/// The commands worth reaching, and any other.
#[derive(Arbitrary, Debug, Clone, Copy)]
enum Cmd {
    Arm,
    MotorTest,
    Reboot,
    Other(u16),
}

/// A parameter name: a real one mostly, any 16 bytes sometimes.
#[derive(Arbitrary, Debug, Clone, Copy)]
enum Name {
    Known(u8),
    Raw([u8; 16]),
}

#[derive(Arbitrary, Debug, Clone)]
struct Frame {
    system: u8,
    component: u8,
    /// The operator's system instead of `system`.
    from_operator: bool,
    sequence: u8,
    v1: bool,
    /// Signed with the vehicle's key (when it has one), this many units after the key's timestamp; otherwise
    /// unsigned.
    signed: Option<u16>,
    message: Message,
}

#[derive(Arbitrary, Debug, Clone)]
enum Op {
    /// Bytes on the line, whatever they are.
    Bytes(Vec<u8>),
    Frame(Frame),
    /// The line falls quiet.
    Pause,
    /// Time passes, in ms; the vehicle ticks.
    Wait(u16),
}

#[derive(Arbitrary, Debug)]
enum Input {
    Line(Vec<Op>),
    Clean {
        frames: Vec<Frame>,
        /// Chunk sizes (1..=64) the stream is cut into, in turn.
        chunks: Vec<u8>,
        /// After which frames the line pauses.
        pauses: Vec<bool>,
    },
}

const CONFIG: ConsoleConfig = ConsoleConfig::DEFAULT;

fn id(name: Name) -> [u8; 16] {
    match name {
        Name::Known(n) => Param::ALL[usize::from(n) % Param::ALL.len()].id(),
        Name::Raw(raw) => raw,
    }
}

/// Serialise `message` with `header` (MAVLink 1 or 2).
fn serialize<D: MessageData>(header: MavHeader, v1: bool, message: &D) -> (Vec<u8>, u8) {
    let bytes = if v1 {
        let mut raw = MAVLinkV1MessageRaw::new();
        raw.serialize_message_data(header, message);
        raw.raw_bytes().to_vec()
    } else {
        let mut raw = MAVLinkV2MessageRaw::new();
        raw.serialize_message_data(header, message);
        raw.raw_bytes().to_vec()
    };
    (bytes, D::EXTRA_CRC)
}

/// The frame's bytes, signed with `signer` when it has a key and the frame asks for it.
fn build(frame: &Frame, operator: u8, signer: &mut SigningState) -> Vec<u8> {
    let system = if frame.from_operator { operator } else { frame.system };
    let header = MavHeader {
        system_id: u32::from(system),
        component_id: frame.component,
        sequence: frame.sequence,
    };
    let v1 = frame.v1;
    let (mut bytes, extra) = match &frame.message {
        Message::Heartbeat { gcs } => serialize(
            header,
            v1,
            &HEARTBEAT_DATA {
                custom_mode: 0,
                mavtype: if *gcs {
                    MavType::MAV_TYPE_GCS
                } else {
                    MavType::MAV_TYPE_SUBMARINE
                },
                autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
                base_mode: MavModeFlag::empty(),
                system_status: MavState::MAV_STATE_ACTIVE,
                mavlink_version: 3,
            },
        ),
        Message::Manual { target, x, y, z, r } => serialize(
            header,
            v1,
            &MANUAL_CONTROL_DATA {
                target: *target,
                x: *x,
                y: *y,
                z: *z,
                r: *r,
                ..MANUAL_CONTROL_DATA::DEFAULT
            },
        ),
        Message::Command {
            target,
            command,
            params,
        } => serialize(
            header,
            v1,
            &COMMAND_LONG_DATA {
                target_system: target.0,
                target_component: target.1,
                command: match command {
                    Cmd::Arm => 400,
                    Cmd::MotorTest => 209,
                    Cmd::Reboot => 246,
                    Cmd::Other(n) => *n,
                },
                confirmation: 0,
                param1: params[0],
                param2: params[1],
                param3: params[2],
                param4: params[3],
                param5: 0.0,
                param6: 0.0,
                param7: 0.0,
            },
        ),
        Message::ParamList { target } => serialize(
            header,
            v1,
            &PARAM_REQUEST_LIST_DATA {
                target_system: target.0,
                target_component: target.1,
            },
        ),
        Message::ParamRead { target, name, index } => serialize(
            header,
            v1,
            &PARAM_REQUEST_READ_DATA {
                target_system: target.0,
                target_component: target.1,
                param_id: id(*name).into(),
                param_index: *index,
            },
        ),
        Message::ParamSet { target, name, value } => serialize(
            header,
            v1,
            &PARAM_SET_DATA {
                target_system: target.0,
                target_component: target.1,
                param_id: id(*name).into(),
                param_value: *value,
                param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
            },
        ),
        Message::SetupSigning { target, key, timestamp } => serialize(
            header,
            false,
            &SETUP_SIGNING_DATA {
                target_system: target.0,
                target_component: target.1,
                secret_key: *key,
                initial_timestamp: *timestamp,
            },
        ),
        Message::Unknown { id, payload } => {
            // Ids 42000..: none is in the dialect. MAVLink 2, the CRC made with a CRC_EXTRA of 0.
            let id = 42_000 + u32::from(*id);
            let payload = &payload[..payload.len().min(255)];
            let [i0, i1, i2, _] = id.to_le_bytes();
            let mut bytes = vec![
                0xFD,
                payload.len() as u8,
                0,
                0,
                frame.sequence,
                system,
                frame.component,
                i0,
                i1,
                i2,
            ];
            bytes.extend_from_slice(payload);
            let crc = mavlink_core::calculate_crc(&bytes[1..], 0);
            bytes.extend(crc.to_le_bytes());
            return bytes;
        }
    };
    if frame.signed.is_some() && signer.active() && bytes.first() == Some(&0xFD) {
        let len = bytes.len();
        bytes.resize(len + SIGNATURE_LEN, 0);
        match signer.sign(&mut bytes, len, extra) {
            Some(signed) => bytes.truncate(signed),
            None => bytes.truncate(len),
        }
    }
    bytes
}

/// The vehicle with its console, on a clock the input moves.
struct Rig {
    receiver: Receiver,
    stats: ConsoleStats,
    vehicle: Vehicle,
    now: u64,
}

impl Rig {
    fn new() -> Self {
        let config = VehicleConfig::DEFAULT;
        Self {
            receiver: Receiver::new(),
            stats: ConsoleStats::new(),
            vehicle: Vehicle::new(config, config.defaults()),
            now: 0,
        }
    }

    fn settings(&self) -> Settings {
        *self.vehicle.settings()
    }

    /// Take `bytes`; every request is applied to the vehicle (checking who may arm) and returned.
    fn feed(&mut self, bytes: &[u8], pause: bool) -> Vec<Request> {
        let mut requests = Vec::new();
        let mut rest = bytes;
        loop {
            let taken = self.receiver.push(rest);
            rest = &rest[taken..];
            if rest.is_empty() && pause {
                self.receiver.end_of_input();
            }
            loop {
                let key = self.settings().signing;
                let Some(received) = self.receiver.next(&CONFIG, key, &self.stats) else {
                    break;
                };
                if let Received::Request(request) = received {
                    self.apply(request);
                    requests.push(request);
                }
            }
            if rest.is_empty() {
                break;
            }
        }
        if pause {
            assert!(!self.receiver.pending(), "a pause leaves nothing in the parser");
        }
        requests
    }

    fn apply(&mut self, request: Request) {
        let operator = self.settings().params.operator();
        let was_armed = self.vehicle.state(Instant::from_millis(self.now)).armed;
        let mut said = Vec::new();
        self.vehicle
            .on_request(Instant::from_millis(self.now), request, &mut |o: Outgoing| said.push(o));
        let armed = self.vehicle.state(Instant::from_millis(self.now)).armed;
        if armed && !was_armed {
            assert_eq!(request.command, Command::Arm(true), "armed by {request:?}");
            assert_eq!(request.from.system, operator, "armed by another system: {request:?}");
        }
        self.check();
    }

    fn tick(&mut self, ms: u16) {
        self.now += u64::from(ms);
        let mut said = Vec::new();
        self.vehicle
            .orders(Instant::from_millis(self.now), &mut |o: Outgoing| said.push(o));
        self.check();
    }

    fn check(&self) {
        let params = self.settings().params;
        for param in Param::ALL {
            assert!(param.accepts(params.get(param)), "{param:?} = {}", params.get(param));
        }
    }
}

/// A ground station's signing state for the vehicle's key, `offset` units after the key's timestamp.
fn signer(settings: &Settings, offset: u16) -> SigningState {
    let mut signer = SigningState::new();
    if let Some(mut key) = settings.signing {
        key.timestamp = key.timestamp.saturating_add(u64::from(offset));
        signer.sync(Some(key));
    }
    signer
}

fuzz_target!(|input: Input| {
    match input {
        Input::Line(ops) => {
            let mut rig = Rig::new();
            for op in ops.iter().take(256) {
                match op {
                    Op::Bytes(bytes) => {
                        rig.feed(bytes, false);
                    }
                    Op::Frame(frame) => {
                        let settings = rig.settings();
                        let mut signer = signer(&settings, frame.signed.unwrap_or(0));
                        let bytes = build(frame, settings.params.operator(), &mut signer);
                        rig.feed(&bytes, false);
                    }
                    Op::Pause => {
                        rig.feed(&[], true);
                    }
                    Op::Wait(ms) => rig.tick(*ms),
                }
            }
        }
        Input::Clean { frames, chunks, pauses } => {
            // Signing stays off here (a SETUP_SIGNING in the stream would turn it on), so every frame is taken
            // for what it is.
            let frames: Vec<Frame> = frames
                .into_iter()
                .take(64)
                .filter(|f| !matches!(f.message, Message::SetupSigning { .. }))
                .collect();
            let operator = Rig::new().settings().params.operator();
            let mut unsigned = SigningState::new();
            let built: Vec<Vec<u8>> = frames.iter().map(|f| build(f, operator, &mut unsigned)).collect();
            // What each frame gives on its own.
            let expected: Vec<Request> = built.iter().flat_map(|bytes| Rig::new().feed(bytes, true)).collect();
            // The whole stream, cut anywhere, pausing only between frames.
            let mut rig = Rig::new();
            let mut got = Vec::new();
            let mut sizes = chunks.iter().map(|c| usize::from(*c % 64) + 1).cycle();
            for (n, bytes) in built.iter().enumerate() {
                let mut rest = bytes.as_slice();
                while !rest.is_empty() {
                    let size = sizes.next().unwrap_or(64).min(rest.len());
                    got.extend(rig.feed(&rest[..size], false));
                    rest = &rest[size..];
                }
                if pauses.get(n).copied().unwrap_or(false) {
                    got.extend(rig.feed(&[], true));
                }
            }
            got.extend(rig.feed(&[], true));
            // Compared as text: a NaN in a request is not equal to itself.
            assert_eq!(format!("{got:?}"), format!("{expected:?}"));
            let counters = rig.stats.snapshot();
            let unknown = frames
                .iter()
                .filter(|f| matches!(f.message, Message::Unknown { .. }))
                .count();
            assert_eq!(counters.skipped_bytes, 0, "{counters:?}");
            assert_eq!(counters.corrupt(), 0, "{counters:?}");
            assert_eq!(counters.unknown_messages as usize, unknown, "{counters:?}");
        }
    }
});
