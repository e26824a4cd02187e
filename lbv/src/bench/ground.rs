//! A ground station on the bench: it speaks MAVLink to the master's console like QGroundControl or MAVProxy would
//! (heartbeats at 1 Hz, the sticks at 10 Hz while flying, commands, parameters, MAVLink 2 signing), and reads what
//! the master sends. The bench's own station is the operator (system 255); a scenario may build others and send
//! their frames with `Bench::send`.
//!
//! Frames are built, and signed, by the mavlink crate (its signature computation, not the master's), and what the
//! master signs is checked with it.

use std::collections::BTreeMap;

use embassy_time::{Duration, Instant};
use lbv_master_fw::console::lbv::{
    COMMAND_LONG_DATA, HEARTBEAT_DATA, MANUAL_CONTROL_DATA, MavAutopilot, MavMessage, MavModeFlag, MavParamType,
    MavState, MavType, PARAM_REQUEST_LIST_DATA, PARAM_REQUEST_READ_DATA, PARAM_SET_DATA, SETUP_SIGNING_DATA,
};
use lbv_master_fw::framing::{Event, FrameParser};
use lbv_master_fw::mixer::ManualInput;
use mavlink_core::{MAVLinkV2MessageRaw, MavHeader, MavlinkVersion, Message};

/// QGroundControl's and MAVProxy's MAVLink system id, the master's default operator (`SYSID_MYGCS`).
pub const OPERATOR: u8 = 255;
const COMPONENT: u8 = 190;
const HEARTBEAT_PERIOD: Duration = Duration::from_secs(1);
const STICK_PERIOD: Duration = Duration::from_millis(100);
/// MAVLink 2 signing's clock: 10 us units since 2015-01-01. The bench's starts at 2025-01-01 (plus virtual time).
pub const SIGNING_EPOCH: u64 = 10 * 31_557_600 * 100_000;

/// MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN.
pub const REBOOT: u16 = 246;
/// MAV_CMD_COMPONENT_ARM_DISARM.
pub const ARM_DISARM: u16 = 400;
/// MAV_CMD_DO_MOTOR_TEST.
pub const MOTOR_TEST: u16 = 209;

/// The ground station's view of the vehicle, from the master's telemetry.
#[derive(Debug, Clone, Default)]
pub struct Seen {
    /// The last HEARTBEAT said armed.
    pub armed: bool,
    /// COMMAND_ACKs: (command, result).
    pub acks: Vec<(u16, u8)>,
    /// COMMAND_ACKs with whom they are addressed to: (target system, command, result).
    pub acks_to: Vec<(u8, u16, u8)>,
    /// STATUSTEXTs with their arrival time.
    pub texts: Vec<(Instant, String)>,
    /// rpm of each thruster from ESC telemetry.
    pub rpm: [u16; 8],
    /// Current of each thruster from ESC telemetry, cA.
    pub current_ca: [u16; 8],
    /// Battery voltage from SYS_STATUS, mV (u16::MAX unknown).
    pub battery_mv: u16,
    /// SYS_STATUS errors_count3: requests refused because they came from another system than the operator's.
    pub refused_other_system: u16,
    /// SYS_STATUS errors_count4: frames refused by the signing checks.
    pub refused_by_signing: u16,
    /// The last PARAM_VALUE of each parameter: (value, index, count).
    pub params: BTreeMap<String, (f32, u16, u16)>,
    /// Frames received.
    pub frames: u32,
    /// Of those, signed frames whose signature the mavlink crate verified with this station's key.
    pub verified: u32,
    /// Signed frames whose signature did not verify (or that came while this station had no key).
    pub unverified: u32,
    /// Unsigned frames that came while this station had a key.
    pub unsigned: u32,
    /// Verified frames whose signature timestamp was not newer than the one before (a wrap, a restart behind).
    pub timestamps_back: u32,
    /// The newest signature timestamp verified.
    pub newest_timestamp: u64,
}

/// A MAVLink 2 signing key as a station holds it, and the timestamp of its last signature (or the newest one it
/// verified from the vehicle, which it follows).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Signing {
    /// The secret.
    pub key: [u8; 32],
    /// The link id its signatures carry.
    pub link_id: u8,
    last: u64,
}

impl Signing {
    /// Sign with `key` on link 0.
    pub fn new(key: [u8; 32]) -> Self {
        Self {
            key,
            link_id: 0,
            last: 0,
        }
    }

    /// The signing timestamp at virtual time `now`, later than the last one used.
    fn timestamp(&mut self, now: Instant) -> u64 {
        let at = SIGNING_EPOCH + now.as_micros() / 10;
        self.last = at.max(self.last + 1);
        self.last
    }
}

/// A ground station.
pub struct GroundStation {
    /// Its MAVLink system id.
    pub system: u8,
    /// Whether it is connected: false models the console link dropping out.
    pub connected: bool,
    /// The pilot's sticks, sent while set.
    pub sticks: Option<ManualInput>,
    /// This many of its next heartbeats are lost on the way (the schedule goes on).
    pub lose_heartbeats: u32,
    /// Heartbeats lost so far.
    pub heartbeats_lost: u32,
    /// Its signing key: with one, every frame it sends is signed, and the master's signatures are checked.
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
    pub fn with_system(system: u8) -> Self {
        Self {
            system,
            connected: true,
            sticks: None,
            lose_heartbeats: 0,
            heartbeats_lost: 0,
            signing: None,
            sequence: 0,
            next_heartbeat: Instant::from_ticks(0),
            next_stick: Instant::from_ticks(0),
            parser: FrameParser::new(),
            seen: Seen::default(),
        }
    }

    /// `message` framed as MAVLink 2 from this station, signed when it has a key.
    pub fn frame(&mut self, message: &MavMessage) -> Vec<u8> {
        let timestamp = self.signing.as_mut().map(|signing| signing.timestamp(Instant::now()));
        self.framed(message, timestamp)
    }

    /// `message` signed with this station's key and exactly `timestamp`, whatever its clock says (a frame
    /// recorded long ago, or an attacker's); unsigned without a key.
    pub fn frame_signed_at(&mut self, message: &MavMessage, timestamp: u64) -> Vec<u8> {
        self.framed(message, Some(timestamp))
    }

    fn framed(&mut self, message: &MavMessage, timestamp: Option<u64>) -> Vec<u8> {
        let header = MavHeader {
            system_id: u32::from(self.system),
            component_id: COMPONENT,
            sequence: self.sequence,
        };
        self.sequence = self.sequence.wrapping_add(1);
        let mut raw = MAVLinkV2MessageRaw::new();
        match (self.signing.as_ref(), timestamp) {
            (Some(signing), Some(timestamp)) => {
                raw.serialize_message_for_signing(header, message);
                *raw.signature_link_id_mut() = signing.link_id;
                raw.signature_timestamp_bytes_mut()
                    .copy_from_slice(&timestamp.to_le_bytes()[..6]);
                let mut signature = [0; 6];
                raw.calculate_signature(&signing.key, &mut signature);
                raw.signature_value_mut().copy_from_slice(&signature);
            }
            _ => raw.serialize_message(header, message),
        }
        raw.raw_bytes().to_vec()
    }

    /// A COMMAND_LONG to the vehicle.
    pub fn command(&mut self, command: u16, params: [f32; 7]) -> Vec<u8> {
        let [param1, param2, param3, param4, param5, param6, param7] = params;
        self.frame(&MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
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
        }))
    }

    /// MAV_CMD_COMPONENT_ARM_DISARM.
    pub fn arm(&mut self, arm: bool) -> Vec<u8> {
        self.command(ARM_DISARM, [if arm { 1.0 } else { 0.0 }, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    }

    /// An arm, signed at exactly `timestamp` ([`GroundStation::frame_signed_at`]).
    pub fn arm_signed_at(&mut self, timestamp: u64) -> Vec<u8> {
        let message = MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
            param1: 1.0,
            command: ARM_DISARM,
            target_system: 1,
            target_component: 1,
            ..Default::default()
        });
        self.frame_signed_at(&message, timestamp)
    }

    /// MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, param1 = 1: restart the autopilot (the master).
    pub fn reboot(&mut self) -> Vec<u8> {
        self.command(REBOOT, [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    }

    /// MAV_CMD_DO_MOTOR_TEST of thruster `motor` (1-based) at `percent` for `seconds`.
    pub fn motor_test(&mut self, motor: u8, percent: f32, seconds: f32) -> Vec<u8> {
        self.command(MOTOR_TEST, [f32::from(motor), 0.0, percent, seconds, 0.0, 0.0, 0.0])
    }

    /// A HEARTBEAT, as a ground station sends it.
    pub fn heartbeat(&mut self) -> Vec<u8> {
        self.frame(&heartbeat_message())
    }

    /// MANUAL_CONTROL with `sticks`.
    pub fn manual(&mut self, sticks: ManualInput) -> Vec<u8> {
        self.frame(&MavMessage::MANUAL_CONTROL(MANUAL_CONTROL_DATA {
            x: sticks.x,
            y: sticks.y,
            z: sticks.z,
            r: sticks.r,
            buttons: 0,
            target: 1,
            ..Default::default()
        }))
    }

    /// PARAM_SET of `name` to `value`.
    pub fn param_set(&mut self, name: &str, value: f32) -> Vec<u8> {
        self.frame(&MavMessage::PARAM_SET(PARAM_SET_DATA {
            param_value: value,
            target_system: 1,
            target_component: 1,
            param_id: param_id(name).into(),
            param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
        }))
    }

    /// PARAM_REQUEST_READ of `name`.
    pub fn param_read(&mut self, name: &str) -> Vec<u8> {
        self.frame(&MavMessage::PARAM_REQUEST_READ(PARAM_REQUEST_READ_DATA {
            param_index: -1,
            target_system: 1,
            target_component: 1,
            param_id: param_id(name).into(),
        }))
    }

    /// PARAM_REQUEST_LIST: every parameter.
    pub fn param_list(&mut self) -> Vec<u8> {
        self.frame(&MavMessage::PARAM_REQUEST_LIST(PARAM_REQUEST_LIST_DATA {
            target_system: 1,
            target_component: 1,
        }))
    }

    /// SETUP_SIGNING with `key`, the link starting at `timestamp` (10 us units since 2015).
    pub fn setup_signing(&mut self, key: [u8; 32], timestamp: u64) -> Vec<u8> {
        self.frame(&MavMessage::SETUP_SIGNING(SETUP_SIGNING_DATA {
            initial_timestamp: timestamp,
            target_system: 1,
            target_component: 1,
            secret_key: key,
        }))
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

    /// When [`GroundStation::periodic`] next has something to send (the event engine wakes for it).
    pub fn next_due(&self) -> Option<Instant> {
        let sticks = self.sticks.is_some().then_some(self.next_stick);
        self.connected
            .then(|| sticks.map_or(self.next_heartbeat, |at| at.min(self.next_heartbeat)))
    }

    /// Read what the master sent.
    pub fn receive(&mut self, now: Instant, mut bytes: &[u8]) {
        while !bytes.is_empty() {
            let taken = self.parser.push(bytes);
            bytes = bytes.get(taken..).unwrap_or_default();
            while let Some(event) = self.parser.next(|id| Some(MavMessage::extra_crc(id))) {
                let Event::Frame(frame) = event else { continue };
                if frame.signed {
                    match (verified(frame.bytes, self.signing.as_ref()), self.signing.as_mut()) {
                        (Some(timestamp), Some(signing)) => {
                            self.seen.verified += 1;
                            if timestamp <= self.seen.newest_timestamp {
                                self.seen.timestamps_back += 1;
                            }
                            self.seen.newest_timestamp = self.seen.newest_timestamp.max(timestamp);
                            // As the spec asks (and the C library and pymavlink do): follow a newer timestamp.
                            signing.last = signing.last.max(timestamp);
                        }
                        _ => self.seen.unverified += 1,
                    }
                } else if self.signing.is_some() {
                    self.seen.unsigned += 1;
                }
                let Ok(message) = MavMessage::parse(MavlinkVersion::V2, frame.message_id, frame.payload) else {
                    continue;
                };
                self.seen.frames += 1;
                self.read(now, message);
            }
        }
    }

    fn read(&mut self, now: Instant, message: MavMessage) {
        match message {
            MavMessage::HEARTBEAT(heartbeat) => {
                self.seen.armed = heartbeat.base_mode.contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED);
            }
            MavMessage::COMMAND_ACK(ack) => {
                self.seen.acks.push((ack.command, ack.result as u8));
                self.seen
                    .acks_to
                    .push((ack.target_system, ack.command, ack.result as u8));
            }
            MavMessage::STATUSTEXT(text) => {
                let text: String = text.text.to_str().unwrap_or("?").trim_end_matches('\0').to_string();
                self.seen.texts.push((now, text));
            }
            MavMessage::PARAM_VALUE(value) => {
                let name = value
                    .param_id
                    .to_str()
                    .unwrap_or("?")
                    .trim_end_matches('\0')
                    .to_string();
                self.seen
                    .params
                    .insert(name, (value.param_value, value.param_index, value.param_count));
            }
            MavMessage::ESC_TELEMETRY_1_TO_4(esc) => {
                self.seen
                    .rpm
                    .iter_mut()
                    .zip(esc.rpm)
                    .for_each(|(slot, rpm)| *slot = rpm);
                self.seen
                    .current_ca
                    .iter_mut()
                    .zip(esc.current)
                    .for_each(|(slot, ca)| *slot = ca);
            }
            MavMessage::ESC_TELEMETRY_5_TO_8(esc) => {
                self.seen
                    .rpm
                    .iter_mut()
                    .skip(4)
                    .zip(esc.rpm)
                    .for_each(|(slot, rpm)| *slot = rpm);
                self.seen
                    .current_ca
                    .iter_mut()
                    .skip(4)
                    .zip(esc.current)
                    .for_each(|(slot, ca)| *slot = ca);
            }
            MavMessage::SYS_STATUS(status) => {
                self.seen.battery_mv = status.voltage_battery;
                self.seen.refused_other_system = status.errors_count3;
                self.seen.refused_by_signing = status.errors_count4;
            }
            _ => {}
        }
    }
}

/// The signature timestamp of the signed frame `bytes` when the mavlink crate finds its signature made with
/// `signing`'s key.
fn verified(bytes: &[u8], signing: Option<&Signing>) -> Option<u64> {
    let signing = signing?;
    let mut raw = MAVLinkV2MessageRaw::new();
    raw.as_mut_slice().get_mut(..bytes.len())?.copy_from_slice(bytes);
    let mut signature = [0; 6];
    raw.calculate_signature(&signing.key, &mut signature);
    (signature == raw.signature_value()).then(|| raw.signature_timestamp())
}

/// A ground station's HEARTBEAT.
pub fn heartbeat_message() -> MavMessage {
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: 0,
        mavtype: MavType::MAV_TYPE_GCS,
        autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
        base_mode: MavModeFlag::empty(),
        system_status: MavState::MAV_STATE_ACTIVE,
        mavlink_version: 3,
    })
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
    use mavlink_core::{SigningConfig, SigningData};

    #[test]
    fn signed_frames_verify_with_the_mavlink_crate_and_unsigned_ones_parse() {
        let _clock = lbv_sim::clock::take();
        let key = [7; 32];
        let mut station = GroundStation::default();
        let unsigned = station.heartbeat();
        assert_eq!(unsigned[2] & 1, 0);
        // The mavlink crate refuses a new stream more than a minute older than its wall clock: sign at its time.
        let since_2015 = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_micros() as u64
            / 10
            - 142_007_040_000_000;
        station.signing = Some(Signing {
            last: since_2015,
            ..Signing::new(key)
        });
        let first = station.arm(true);
        let second = station.arm(true);
        let verifier = SigningData::from_config(SigningConfig::new(key, 0, false, false));
        for frame in [&first, &second] {
            let mut raw = MAVLinkV2MessageRaw::new();
            raw.as_mut_slice()[..frame.len()].copy_from_slice(frame);
            assert!(verifier.verify_signature(&raw), "{frame:02x?}");
            assert!(verified(frame, station.signing.as_ref()).is_some());
            assert!(verified(frame, Some(&Signing::new([8; 32]))).is_none());
        }
        // Each signature is newer than the last, at the same virtual time too.
        let stamp = |frame: &[u8]| {
            let mut raw = MAVLinkV2MessageRaw::new();
            raw.as_mut_slice()[..frame.len()].copy_from_slice(frame);
            raw.signature_timestamp()
        };
        assert_eq!(stamp(&second), stamp(&first) + 1);
        // On virtual time, from the bench's epoch.
        station.signing = Some(Signing::new(key));
        assert_eq!(stamp(&station.heartbeat()), SIGNING_EPOCH);
    }

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
