//! The console's receive path and the vehicle, end to end: bytes -> frame parser -> signing checks -> decoder ->
//! vehicle, on a clock the input moves. Two kinds of input:
//!
//! - A line: raw bytes, well-formed frames from any system (signed or not, when a key is set), pauses of the line,
//!   time passing, reboots of the master (its settings and signing reservation kept as its flash keeps them), and
//!   frames recorded before a reboot sent again after it, in any mix. Nothing panics; after every step every
//!   parameter is in its range; the vehicle arms only on an arm command from the operator's system (`SYSID_MYGCS`
//!   before the command); after a pause the parser holds nothing, so whatever noise came before cannot hide the
//!   next frame; while signing is on, no frame the master took in before a reboot is accepted after it.
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
use lbv_master_fw::console::{ConsoleConfig, ConsoleCounters, ConsoleStats, Received, Receiver};
use lbv_master_fw::params::{LISTED_COUNT, Listed, Param, Settings};
use lbv_master_fw::shared::{Command, Outgoing, Request, Shared};
use lbv_master_fw::console::signing::{SIGNATURE_LEN, SigningState, TIMESTAMP_MAX, reservation_after};
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
        buttons: u16,
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
    /// The master reboots.
    Reboot,
    /// A frame recorded before the last reboot (by its number, modulo how many there are) is sent again.
    Replay(u8),
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
        // A setting's name, or a read-only stand-in's.
        Name::Known(n) => Listed::from_index(u16::from(n) % LISTED_COUNT as u16).map_or([0; 16], Listed::id),
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
        Message::Manual {
            target,
            x,
            y,
            z,
            r,
            buttons,
        } => serialize(
            header,
            v1,
            &MANUAL_CONTROL_DATA {
                target: *target,
                x: *x,
                y: *y,
                z: *z,
                r: *r,
                buttons: *buttons,
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

/// What the master's flash keeps: the settings (every change is written) and the signing reservation.
#[derive(Clone, Copy)]
struct Flash {
    settings: Settings,
    reservation: u64,
}

/// The vehicle with its console, on a clock the input moves.
struct Rig {
    receiver: Receiver,
    stats: ConsoleStats,
    shared: Shared,
    vehicle: Vehicle,
    flash: Flash,
    now: u64,
}

impl Rig {
    fn new() -> Self {
        let defaults = VehicleConfig::DEFAULT.defaults();
        Self::boot(Flash {
            settings: defaults,
            reservation: 0,
        })
    }

    /// A start from what `flash` holds, as `lbv_master_fw::run` and the settings store do it: the key's timestamp
    /// is the later of its own and the reservation (the floor), a new reservation past it is stored, and the
    /// settings are published before anything is read.
    fn boot(mut flash: Flash) -> Self {
        let config = VehicleConfig::DEFAULT;
        let shared = Shared::new();
        if let Some(key) = flash.settings.signing.as_mut() {
            key.timestamp = key.timestamp.max(flash.reservation);
            flash.reservation = reservation_after(key.timestamp);
            shared.signing_stored.sender().send(flash.reservation);
        }
        shared.settings.sender().send(flash.settings);
        let stats = ConsoleStats::new();
        stats.follow(&shared);
        Self {
            receiver: Receiver::new(),
            stats,
            shared,
            vehicle: Vehicle::new(config, flash.settings),
            flash,
            now: 0,
        }
    }

    /// The reboot: the master's RAM is lost, its flash kept.
    fn reboot(&mut self) {
        *self = Self::boot(self.flash);
    }

    /// The settings task: the settings the vehicle publishes and the reservation the console asks for are written
    /// (at once: a write takes milliseconds) and the console is told.
    fn store(&mut self) {
        let settings = self.settings();
        if self.shared.settings.try_get() != Some(settings) {
            self.shared.settings.sender().send(settings);
            self.flash.settings = settings;
        }
        self.stats.follow(&self.shared);
        if let Some(reservation) = self.shared.signing_time.try_get()
            && reservation > self.flash.reservation
        {
            self.flash.reservation = reservation;
            self.shared.signing_stored.sender().send(reservation);
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
                let key = self.stats.follow(&self.shared);
                let Some(received) = self.receiver.next(&CONFIG, key, &self.stats) else {
                    break;
                };
                if let Received::Request(request) = received {
                    self.apply(request);
                    requests.push(request);
                }
                self.store();
            }
            self.store();
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
            // The arm command, or a button pressed (one whose BTNn_FUNCTION is arm).
            let pressed = matches!(request.command, Command::Manual(_, buttons) if buttons != 0);
            assert!(request.command == Command::Arm(true) || pressed, "armed by {request:?}");
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
        signer.stored(TIMESTAMP_MAX);
    }
    signer
}

/// Frames the console has looked at: taken, refused, or dropped as bad.
fn looked_at(counters: &ConsoleCounters) -> u32 {
    counters.frames_in + counters.bad_frames + counters.refused_by_signing()
}

fuzz_target!(|input: Input| {
    match input {
        Input::Line(ops) => {
            let mut rig = Rig::new();
            // Frames the console looked at whole, since the first start, and how many came before the last reboot.
            let mut recorded: Vec<Vec<u8>> = Vec::new();
            let mut before_reboot = 0;
            for op in ops.iter().take(256) {
                match op {
                    Op::Bytes(bytes) => {
                        rig.feed(bytes, false);
                    }
                    Op::Frame(frame) => {
                        let settings = rig.settings();
                        let mut signer = signer(&settings, frame.signed.unwrap_or(0));
                        let bytes = build(frame, settings.params.operator(), &mut signer);
                        let (clean, seen) = (!rig.receiver.pending(), looked_at(&rig.stats.snapshot()));
                        rig.feed(&bytes, false);
                        if clean && !rig.receiver.pending() && looked_at(&rig.stats.snapshot()) == seen + 1 {
                            recorded.push(bytes);
                        }
                    }
                    Op::Pause => {
                        rig.feed(&[], true);
                    }
                    Op::Wait(ms) => rig.tick(*ms),
                    Op::Reboot => {
                        rig.reboot();
                        before_reboot = recorded.len();
                    }
                    Op::Replay(n) => {
                        if before_reboot == 0 {
                            continue;
                        }
                        let bytes = recorded[usize::from(*n) % before_reboot].clone();
                        let signing = rig.settings().signing.is_some();
                        let taken = rig.stats.snapshot().frames_in;
                        // The replay comes on a quiet line, as an attacker would send it.
                        rig.feed(&[], true);
                        let requests = rig.feed(&bytes, true);
                        if signing {
                            assert!(
                                requests.is_empty() && rig.stats.snapshot().frames_in == taken,
                                "a frame from before the reboot was accepted after it: {bytes:02x?}"
                            );
                        }
                    }
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
