//! What a ground station keeps of the master's telemetry.

use alloc::collections::BTreeMap;
use alloc::string::String;
use alloc::vec::Vec;

use embassy_time::Instant;
use lbv_master_fw::console::lbv::{MavMessage, MavModeFlag, MavResult, MavSeverity, MavSysStatusSensor};

/// The ground station's view of the vehicle, from the master's telemetry.
#[derive(Debug, Clone, Default)]
pub struct Seen {
    /// Frames received.
    pub frames: u32,
    /// HEARTBEATs received.
    pub heartbeats: u32,
    /// The last HEARTBEAT said armed.
    pub armed: bool,
    /// COMMAND_ACKs: (command, result).
    pub acks: Vec<(u16, u8)>,
    /// COMMAND_ACKs with whom they are addressed to: (target system, command, result).
    pub acks_to: Vec<(u8, u16, u8)>,
    /// COMMAND_ACKs with the component they are addressed to: (target component, command, result).
    pub acks_to_component: Vec<(u8, u16, u8)>,
    /// COMMAND_ACKs IN_PROGRESS: (command, progress).
    pub progress: Vec<(u16, u8)>,
    /// STATUSTEXTs with their arrival time.
    pub texts: Vec<(Instant, String)>,
    /// Of those, the ones of severity CRITICAL.
    pub critical_texts: u32,
    /// rpm of each thruster from ESC telemetry.
    pub rpm: [u16; 8],
    /// Current of each thruster from ESC telemetry, cA.
    pub current_ca: [u16; 8],
    /// Polls of each thruster from ESC telemetry (its `count`).
    pub polls: [u16; 8],
    /// Battery voltage from SYS_STATUS, mV (u16::MAX unknown).
    pub battery_mv: u16,
    /// SYS_STATUS errors_count3: requests refused because they came from another system than the operator's.
    pub refused_other_system: u16,
    /// SYS_STATUS errors_count4: frames refused by the signing checks.
    pub refused_by_signing: u16,
    /// SYS_STATUS says the motor outputs healthy (every thruster online, reporting, following its orders).
    pub motors_healthy: bool,
    /// The last PARAM_VALUE of each parameter: (value, index, count).
    pub params: BTreeMap<String, (f32, u16, u16)>,
    /// Signed frames whose signature the mavlink crate verified with this station's key.
    pub verified: u32,
    /// Signed frames whose signature did not verify (or that came while this station had no key).
    pub unverified: u32,
    /// Unsigned frames that came while this station had a key.
    pub unsigned: u32,
    /// Verified frames whose signature timestamp was not newer than the one before (a wrap, a restart behind).
    pub timestamps_back: u32,
    /// The newest signature timestamp verified.
    pub newest_timestamp: u64,
    /// FILE_TRANSFER_PROTOCOL payloads not yet taken by an [`crate::Upload`].
    pub ftp: Vec<[u8; 251]>,
}

impl Seen {
    /// Nothing seen yet (a `const` [`Seen::default`], for a station in a static).
    pub const fn new() -> Self {
        Self {
            frames: 0,
            heartbeats: 0,
            armed: false,
            acks: Vec::new(),
            acks_to: Vec::new(),
            acks_to_component: Vec::new(),
            progress: Vec::new(),
            texts: Vec::new(),
            critical_texts: 0,
            rpm: [0; 8],
            current_ca: [0; 8],
            polls: [0; 8],
            battery_mv: 0,
            refused_other_system: 0,
            refused_by_signing: 0,
            motors_healthy: false,
            params: BTreeMap::new(),
            verified: 0,
            unverified: 0,
            unsigned: 0,
            timestamps_back: 0,
            newest_timestamp: 0,
            ftp: Vec::new(),
        }
    }

    /// Note `message`, which came at `now`.
    pub(crate) fn note(&mut self, now: Instant, message: MavMessage) {
        self.frames += 1;
        match message {
            MavMessage::HEARTBEAT(heartbeat) => {
                self.heartbeats += 1;
                self.armed = heartbeat.base_mode.contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED);
            }
            MavMessage::COMMAND_ACK(ack) => {
                self.acks.push((ack.command, ack.result as u8));
                self.acks_to.push((ack.target_system, ack.command, ack.result as u8));
                self.acks_to_component
                    .push((ack.target_component, ack.command, ack.result as u8));
                if ack.result == MavResult::MAV_RESULT_IN_PROGRESS {
                    self.progress.push((ack.command, ack.progress));
                }
            }
            MavMessage::FILE_TRANSFER_PROTOCOL(ftp) => self.ftp.push(ftp.payload),
            MavMessage::STATUSTEXT(text) => {
                if text.severity == MavSeverity::MAV_SEVERITY_CRITICAL {
                    self.critical_texts += 1;
                }
                self.texts.push((now, text.text.to_str().unwrap_or("?").into()));
            }
            MavMessage::PARAM_VALUE(value) => {
                let name = value.param_id.to_str().unwrap_or("?").into();
                self.params
                    .insert(name, (value.param_value, value.param_index, value.param_count));
            }
            MavMessage::ESC_TELEMETRY_1_TO_4(esc) => {
                copy(&mut self.rpm, &esc.rpm);
                copy(&mut self.current_ca, &esc.current);
                copy(&mut self.polls, &esc.count);
            }
            MavMessage::ESC_TELEMETRY_5_TO_8(esc) => {
                copy(self.rpm.get_mut(4..).unwrap_or_default(), &esc.rpm);
                copy(self.current_ca.get_mut(4..).unwrap_or_default(), &esc.current);
                copy(self.polls.get_mut(4..).unwrap_or_default(), &esc.count);
            }
            MavMessage::SYS_STATUS(status) => {
                self.battery_mv = status.voltage_battery;
                self.refused_other_system = status.errors_count3;
                self.refused_by_signing = status.errors_count4;
                self.motors_healthy = status
                    .onboard_control_sensors_health
                    .contains(MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS);
            }
            _ => {}
        }
    }
}

/// `from` into the first slots of `to`.
fn copy(to: &mut [u16], from: &[u16]) {
    to.iter_mut().zip(from).for_each(|(slot, value)| *slot = *value);
}
