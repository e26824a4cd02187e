//! The operator's side of the console link: a ground station that speaks MAVLink to the master's console as
//! QGroundControl or MAVProxy would (heartbeats at 1 Hz, the sticks at 10 Hz while they are held, commands,
//! parameters) and reads what the master sends into [`Seen`]. The bench drives the master with it on virtual
//! time, qemu-m4 on the emulated Cortex-M4, and the console tests take its [`GCS_HEARTBEAT`].
//!
//! `no_std` with `alloc`: frames are `Vec`s, and [`Seen`] keeps the texts and parameters. Whoever uses it moves the
//! bytes: [`GroundStation::periodic`] and the builders give frames to send, [`GroundStation::receive`] takes what
//! came. With the `signing` feature (std), frames are signed as MAVLink 2 signing asks, by the mavlink crate (its
//! signature computation, not the master's), and what the master signs is checked with it.
#![no_std]

extern crate alloc;

mod seen;
#[cfg(feature = "signing")]
mod signing;
mod upload;

use alloc::vec::Vec;

use embassy_time::{Duration, Instant};
use lbv_master_fw::console::framing::{Event, FrameParser};
use lbv_master_fw::console::lbv::{
    COMMAND_LONG_DATA, FILE_TRANSFER_PROTOCOL_DATA, HEARTBEAT_DATA, MANUAL_CONTROL_DATA, MavAutopilot, MavMessage,
    MavModeFlag, MavParamType, MavState, MavType, PARAM_REQUEST_LIST_DATA, PARAM_REQUEST_READ_DATA, PARAM_SET_DATA,
    SETUP_SIGNING_DATA,
};
use lbv_master_fw::mixer::ManualInput;
use lbv_master_fw::shared::{MAV_CMD_COMPONENT_ARM_DISARM, MAV_CMD_DO_MOTOR_TEST, MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN};
use mavlink_core::{MAVLinkV2MessageRaw, MavHeader, MavlinkVersion, Message, MessageData};

pub use seen::Seen;
#[cfg(feature = "signing")]
pub use signing::{SIGNING_EPOCH, Signing};
pub use upload::{Upload, UploadState};

/// QGroundControl's and MAVProxy's MAVLink system id, the master's default operator (`SYSID_MYGCS`).
pub const OPERATOR: u8 = 255;
/// MAV_COMP_ID_MISSIONPLANNER, the component QGroundControl and MAVProxy send as.
const COMPONENT: u8 = 190;
const HEARTBEAT_PERIOD: Duration = Duration::from_secs(1);
const STICK_PERIOD: Duration = Duration::from_millis(100);

/// A ground station's HEARTBEAT (type GCS), as QGroundControl and MAVProxy send it.
pub const GCS_HEARTBEAT: HEARTBEAT_DATA = HEARTBEAT_DATA {
    custom_mode: 0,
    mavtype: MavType::MAV_TYPE_GCS,
    autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
    base_mode: MavModeFlag::empty(),
    system_status: MavState::MAV_STATE_ACTIVE,
    mavlink_version: 3,
};

/// A ground station. The operator's is system [`OPERATOR`] (the default); a bench scenario may build others.
#[derive(Debug)]
pub struct GroundStation {
    /// Its MAVLink system id.
    pub system: u8,
    /// Its MAVLink component id (MAV_COMP_ID_MISSIONPLANNER, 190, for a ground station).
    pub component: u8,
    /// Whether it is connected: false models the console link dropping out (it sends nothing by itself).
    pub connected: bool,
    /// The pilot's sticks, sent while set.
    pub sticks: Option<ManualInput>,
    /// This many of its next heartbeats are lost on the way (the schedule goes on).
    pub lose_heartbeats: u32,
    /// Heartbeats lost so far.
    pub heartbeats_lost: u32,
    /// Its signing key: with one, every frame it sends is signed, and the master's signatures are checked.
    #[cfg(feature = "signing")]
    pub signing: Option<Signing>,
    sequence: u8,
    next_heartbeat: Instant,
    next_stick: Instant,
    parser: FrameParser,
    /// What it has seen of the vehicle.
    pub seen: Seen,
}

impl Default for GroundStation {
    fn default() -> Self {
        Self::with_system(OPERATOR)
    }
}

impl GroundStation {
    /// A station with MAVLink system id `system`.
    pub const fn with_system(system: u8) -> Self {
        Self::with_ids(system, COMPONENT)
    }

    /// A sender with MAVLink system id `system` and component id `component` (a companion computer of the
    /// operator's system, say).
    pub const fn with_ids(system: u8, component: u8) -> Self {
        Self {
            system,
            component,
            connected: true,
            sticks: None,
            lose_heartbeats: 0,
            heartbeats_lost: 0,
            #[cfg(feature = "signing")]
            signing: None,
            sequence: 0,
            next_heartbeat: Instant::from_ticks(0),
            next_stick: Instant::from_ticks(0),
            parser: FrameParser::new(),
            seen: Seen::new(),
        }
    }

    /// The header of its next frame.
    fn header(&mut self) -> MavHeader {
        let header = MavHeader {
            system_id: u32::from(self.system),
            component_id: self.component,
            sequence: self.sequence,
        };
        self.sequence = self.sequence.wrapping_add(1);
        header
    }

    /// `message` framed as MAVLink 2 from this station, signed when it has a key. By message type, not as a
    /// `MavMessage`, whose encoder takes in every message's: in qemu-m4's image that would change how the master's
    /// own encoders are inlined, and so the figures it gives of the master.
    pub fn frame<D: MessageData>(&mut self, message: &D) -> Vec<u8> {
        let header = self.header();
        #[cfg(feature = "signing")]
        if let Some(signing) = self.signing.as_mut() {
            let timestamp = signing.timestamp(Instant::now());
            return signing.frame(header, message, timestamp);
        }
        unsigned(header, message)
    }

    /// `message` signed with this station's key and exactly `timestamp`, whatever its clock says (a frame
    /// recorded long ago, or an attacker's); unsigned without a key.
    #[cfg(feature = "signing")]
    pub fn frame_signed_at<D: MessageData>(&mut self, message: &D, timestamp: u64) -> Vec<u8> {
        let header = self.header();
        match self.signing.as_ref() {
            Some(signing) => signing.frame(header, message, timestamp),
            None => unsigned(header, message),
        }
    }

    /// A COMMAND_LONG to the vehicle.
    pub fn command(&mut self, command: u16, params: [f32; 7]) -> Vec<u8> {
        let [param1, param2, param3, param4, param5, param6, param7] = params;
        self.frame(&COMMAND_LONG_DATA {
            param1,
            param2,
            param3,
            param4,
            param5,
            param6,
            param7,
            command,
            target_system: 1,
            target_component: 1,
            confirmation: 0,
        })
    }

    /// MAV_CMD_COMPONENT_ARM_DISARM.
    pub fn arm(&mut self, arm: bool) -> Vec<u8> {
        self.command(
            MAV_CMD_COMPONENT_ARM_DISARM,
            [if arm { 1.0 } else { 0.0 }, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        )
    }

    /// An arm, signed at exactly `timestamp` ([`GroundStation::frame_signed_at`]).
    #[cfg(feature = "signing")]
    pub fn arm_signed_at(&mut self, timestamp: u64) -> Vec<u8> {
        let message = COMMAND_LONG_DATA {
            param1: 1.0,
            command: MAV_CMD_COMPONENT_ARM_DISARM,
            target_system: 1,
            target_component: 1,
            ..Default::default()
        };
        self.frame_signed_at(&message, timestamp)
    }

    /// MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, param1 = 1: restart the autopilot (the master).
    pub fn reboot(&mut self) -> Vec<u8> {
        self.command(MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    }

    /// MAV_CMD_DO_MOTOR_TEST of thruster `motor` (1-based) at `percent` for `seconds`.
    pub fn motor_test(&mut self, motor: u8, percent: f32, seconds: f32) -> Vec<u8> {
        self.command(
            MAV_CMD_DO_MOTOR_TEST,
            [f32::from(motor), 0.0, percent, seconds, 0.0, 0.0, 0.0],
        )
    }

    /// Its HEARTBEAT.
    pub fn heartbeat(&mut self) -> Vec<u8> {
        self.frame(&GCS_HEARTBEAT)
    }

    /// MANUAL_CONTROL with `sticks`.
    pub fn manual(&mut self, sticks: ManualInput) -> Vec<u8> {
        self.frame(&MANUAL_CONTROL_DATA {
            x: sticks.x,
            y: sticks.y,
            z: sticks.z,
            r: sticks.r,
            buttons: 0,
            target: 1,
            ..Default::default()
        })
    }

    /// PARAM_SET of `name` to `value`.
    pub fn param_set(&mut self, name: &str, value: f32) -> Vec<u8> {
        self.frame(&PARAM_SET_DATA {
            param_value: value,
            target_system: 1,
            target_component: 1,
            param_id: param_id(name).into(),
            param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
        })
    }

    /// PARAM_REQUEST_READ of `name`.
    pub fn param_read(&mut self, name: &str) -> Vec<u8> {
        self.frame(&PARAM_REQUEST_READ_DATA {
            param_index: -1,
            target_system: 1,
            target_component: 1,
            param_id: param_id(name).into(),
        })
    }

    /// PARAM_REQUEST_LIST: every parameter.
    pub fn param_list(&mut self) -> Vec<u8> {
        self.frame(&PARAM_REQUEST_LIST_DATA {
            target_system: 1,
            target_component: 1,
        })
    }

    /// A MAVLink FTP request to the vehicle (FILE_TRANSFER_PROTOCOL), as the clients lay it out: `seq`, `session`,
    /// `opcode`, `offset` and `data` (at most 239 bytes).
    pub fn ftp_request(&mut self, seq: u16, session: u8, opcode: u8, offset: u32, data: &[u8]) -> Vec<u8> {
        let payload = upload::request(seq, session, opcode, offset, data);
        self.frame(&FILE_TRANSFER_PROTOCOL_DATA {
            target_network: 0,
            target_system: 1,
            target_component: 1,
            payload,
        })
    }

    /// SETUP_SIGNING with `key`, the link starting at `timestamp` (10 us units since 2015).
    pub fn setup_signing(&mut self, key: [u8; 32], timestamp: u64) -> Vec<u8> {
        self.frame(&SETUP_SIGNING_DATA {
            initial_timestamp: timestamp,
            target_system: 1,
            target_component: 1,
            secret_key: key,
        })
    }

    /// What it sends by itself at `now`: heartbeats, and the sticks while they are set.
    pub fn periodic(&mut self, now: Instant) -> Vec<u8> {
        let mut out = Vec::new();
        if !self.connected {
            return out;
        }
        if now >= self.next_heartbeat {
            self.next_heartbeat = now + HEARTBEAT_PERIOD;
            if self.lose_heartbeats > 0 {
                self.lose_heartbeats -= 1;
                self.heartbeats_lost += 1;
            } else {
                out.extend(self.heartbeat());
            }
        }
        if let Some(sticks) = self.sticks
            && now >= self.next_stick
        {
            self.next_stick = now + STICK_PERIOD;
            out.extend(self.manual(sticks));
        }
        out
    }

    /// When [`GroundStation::periodic`] next has something to send.
    pub fn next_due(&self) -> Option<Instant> {
        let sticks = self.sticks.is_some().then_some(self.next_stick);
        self.connected
            .then(|| sticks.map_or(self.next_heartbeat, |at| at.min(self.next_heartbeat)))
    }

    /// Read what the master sent, which came at `now`.
    pub fn receive(&mut self, now: Instant, mut bytes: &[u8]) {
        while !bytes.is_empty() {
            let taken = self.parser.push(bytes);
            bytes = bytes.get(taken..).unwrap_or_default();
            while let Some(event) = self.parser.next(|id| Some(MavMessage::extra_crc(id))) {
                let Event::Frame(frame) = event else { continue };
                #[cfg(feature = "signing")]
                signing::check(self.signing.as_mut(), &frame, &mut self.seen);
                #[cfg(not(feature = "signing"))]
                if frame.signed {
                    self.seen.unverified += 1;
                }
                let Ok(message) = MavMessage::parse(MavlinkVersion::V2, frame.message_id, frame.payload) else {
                    continue;
                };
                self.seen.note(now, message);
            }
        }
    }
}

/// `message` framed as unsigned MAVLink 2.
fn unsigned<D: MessageData>(header: MavHeader, message: &D) -> Vec<u8> {
    let mut raw = MAVLinkV2MessageRaw::new();
    raw.serialize_message_data(header, message);
    raw.raw_bytes().to_vec()
}

/// A parameter's name as MAVLink carries it.
fn param_id(name: &str) -> [u8; 16] {
    let mut id = [0; 16];
    for (slot, byte) in id.iter_mut().zip(name.bytes()) {
        *slot = byte;
    }
    id
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lost_heartbeat_leaves_a_two_second_gap() {
        let mut station = GroundStation {
            lose_heartbeats: 1,
            ..GroundStation::default()
        };
        let sent: Vec<u64> = (0..5_000u64)
            .step_by(100)
            .filter(|ms| !station.periodic(Instant::from_millis(*ms)).is_empty())
            .collect();
        assert_eq!(sent, [1_000, 2_000, 3_000, 4_000]);
        assert_eq!(station.heartbeats_lost, 1);
    }
}
