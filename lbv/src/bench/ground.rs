//! The operator's ground station on the bench: it speaks MAVLink to the master's console like QGroundControl
//! would (heartbeats at 1 Hz, the sticks at 10 Hz while flying, commands), and reads what the master sends.

use embassy_time::{Duration, Instant};
use lbv_master_fw::console::frame::{Event, FrameParser};
use lbv_master_fw::console::lbv::{
    COMMAND_LONG_DATA, HEARTBEAT_DATA, MANUAL_CONTROL_DATA, MavAutopilot, MavMessage, MavModeFlag, MavState, MavType,
};
use lbv_master_fw::shared::ManualInput;
use mavlink_core::{MAVLinkV2MessageRaw, MavHeader, MavlinkVersion, Message, MessageData};

/// QGroundControl's MAVLink identity.
const SYSTEM: u8 = 255;
const COMPONENT: u8 = 190;
const HEARTBEAT_PERIOD: Duration = Duration::from_secs(1);
const STICK_PERIOD: Duration = Duration::from_millis(100);

/// The ground station's view of the vehicle, from the master's telemetry.
#[derive(Debug, Clone, Default)]
pub struct Seen {
    /// The last HEARTBEAT said armed.
    pub armed: bool,
    /// COMMAND_ACKs: (command, result).
    pub acks: Vec<(u16, u8)>,
    /// STATUSTEXTs with their arrival time.
    pub texts: Vec<(Instant, String)>,
    /// rpm of each thruster from ESC telemetry.
    pub rpm: [u16; 8],
    /// Current of each thruster from ESC telemetry, cA.
    pub current_ca: [u16; 8],
    /// Battery voltage from SYS_STATUS, mV (u16::MAX unknown).
    pub battery_mv: u16,
    /// Frames received.
    pub frames: u32,
}

/// A ground station.
pub struct GroundStation {
    /// Whether it is connected: false models the console link dropping out.
    pub connected: bool,
    /// The pilot's sticks, sent while set.
    pub sticks: Option<ManualInput>,
    sequence: u8,
    next_heartbeat: Instant,
    next_stick: Instant,
    parser: FrameParser,
    /// What it has seen of the vehicle.
    pub seen: Seen,
}

impl Default for GroundStation {
    fn default() -> Self {
        Self {
            connected: true,
            sticks: None,
            sequence: 0,
            next_heartbeat: Instant::from_ticks(0),
            next_stick: Instant::from_ticks(0),
            parser: FrameParser::new(),
            seen: Seen::default(),
        }
    }
}

impl GroundStation {
    fn frame<D: MessageData>(&mut self, message: &D) -> Vec<u8> {
        let mut raw = MAVLinkV2MessageRaw::new();
        let header = MavHeader {
            system_id: u32::from(SYSTEM),
            component_id: COMPONENT,
            sequence: self.sequence,
        };
        self.sequence = self.sequence.wrapping_add(1);
        raw.serialize_message_data(header, message);
        raw.raw_bytes().to_vec()
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
        self.command(400, [if arm { 1.0 } else { 0.0 }, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    }

    /// What it sends by itself at `now`: heartbeats, and the sticks while they are set.
    pub fn periodic(&mut self, now: Instant) -> Vec<u8> {
        let mut out = Vec::new();
        if !self.connected {
            return out;
        }
        if now >= self.next_heartbeat {
            self.next_heartbeat = now + HEARTBEAT_PERIOD;
            let heartbeat = HEARTBEAT_DATA {
                custom_mode: 0,
                mavtype: MavType::MAV_TYPE_GCS,
                autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
                base_mode: MavModeFlag::empty(),
                system_status: MavState::MAV_STATE_ACTIVE,
                mavlink_version: 3,
            };
            out.extend(self.frame(&heartbeat));
        }
        if let Some(sticks) = self.sticks
            && now >= self.next_stick
        {
            self.next_stick = now + STICK_PERIOD;
            let manual = MANUAL_CONTROL_DATA {
                x: sticks.x,
                y: sticks.y,
                z: sticks.z,
                r: sticks.r,
                buttons: 0,
                target: 1,
                ..Default::default()
            };
            out.extend(self.frame(&manual));
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
                let Ok(message) = MavMessage::parse(MavlinkVersion::V2, frame.message_id, frame.payload) else {
                    continue;
                };
                self.seen.frames += 1;
                match message {
                    MavMessage::HEARTBEAT(heartbeat) => {
                        self.seen.armed = heartbeat.base_mode.contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED);
                    }
                    MavMessage::COMMAND_ACK(ack) => self.seen.acks.push((ack.command, ack.result as u8)),
                    MavMessage::STATUSTEXT(text) => {
                        let text: String = text.text.to_str().unwrap_or("?").trim_end_matches('\0').to_string();
                        self.seen.texts.push((now, text));
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
                    MavMessage::SYS_STATUS(status) => self.seen.battery_mv = status.voltage_battery,
                    _ => {}
                }
            }
        }
    }
}
