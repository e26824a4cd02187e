//! The console's outgoing MAVLink messages, built from the vehicle's state, and their MAVLink 2 framing.
//!
//! Every field of every message is set here on purpose: the generated `Default` of a bit-flag field is its first
//! flag, not empty (a default HEARTBEAT would claim to be armed).

use mavlink_core::MessageData;
use tmc_proto::{MaxPower, MotorKind, Speed, Status};

use super::lbv::{
    AUTOPILOT_VERSION_DATA, AVAILABLE_MODES_DATA, BATTERY_STATUS_DATA, COMMAND_ACK_DATA, ESC_INFO_DATA,
    ESC_STATUS_DATA, ESC_TELEMETRY_1_TO_4_DATA, ESC_TELEMETRY_5_TO_8_DATA, EscConnectionType, EscFailureFlags,
    FILE_TRANSFER_PROTOCOL_DATA, HEARTBEAT_DATA, MISSION_ACK_DATA, MISSION_COUNT_DATA, MavAutopilot,
    MavBatteryChargeState, MavBatteryFault, MavBatteryFunction, MavBatteryMode, MavBatteryType, MavModeFlag,
    MavParamType, MavProtocolCapability, MavResult, MavSeverity, MavState, MavSysStatusSensor,
    MavSysStatusSensorExtended, MavType, NAMED_VALUE_FLOAT_DATA, PARAM_VALUE_DATA, SERVO_OUTPUT_RAW_DATA,
    STATUSTEXT_DATA, SYS_STATUS_DATA,
};
use crate::params::{ParamId, ParamType};
use crate::shared::{
    ARDUSUB_MODE_MANUAL, AckResult, BatterySummary, FTP_PAYLOAD, MAX_THRUSTERS, Sender, Severity, Text, ThrusterReport,
    VehicleState,
};
use crate::update::{Contents, FtpAnswer};
use bat_proto::BmsAlarms;
use tmc_proto::Faults;

include!(concat!(env!("OUT_DIR"), "/build_info.rs"));

/// AUTOPILOT_VERSION.vendor_id: 0x0483, STMicroelectronics' USB vendor id (the G431's maker; the console's ST-LINK
/// virtual COM port enumerates under it). The board has no USB id of its own.
pub(crate) const VENDOR_ID: u16 = 0x0483;
/// AUTOPILOT_VERSION.product_id: 0x0469, the device id of the master's STM32G474 (DBGMCU_IDCODE.DEV_ID, RM0440
/// section 47.6.1: 0x469 for the G47x/G48x, 0x468 for the G431/G441).
pub(crate) const PRODUCT_ID: u16 = 0x0469;

/// What the master can do, as AUTOPILOT_VERSION announces it: MAVLink 2, COMMAND_INT (the same commands as
/// COMMAND_LONG), and integer parameters carried as the float of their value (PARAM_ENCODE_C_CAST, what ArduPilot
/// and ArduSub announce and do). No mission, fence or rally bits: there are none, so a ground station does not
/// ask for them. No FTP bit either: the FTP server holds only the update files and `@SYS/versions.txt`
/// ([`crate::update`]), and the bit tells a ground station it may fetch its own files over FTP (ArduPilot's
/// parameter and mission files); MAVProxy and pymavlink use FTP without looking at it.
pub(crate) const CAPABILITIES: MavProtocolCapability = MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_MAVLINK2
    .union(MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_COMMAND_INT)
    .union(MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST);

/// AUTOPILOT_VERSION.middleware_custom_version of an image that takes update files signed with the development key
/// (`dev_key`, update-image's `UPDATE_KEY_IS_DEV`), whose secret is published: "DEVKEY" in ASCII, NUL-padded. Zeros
/// otherwise. The field is free: the master has no middleware.
pub(crate) const DEV_KEY_MARK: [u8; 8] = *b"DEVKEY\0\0";

/// AUTOPILOT_VERSION: the crate version ([`FLIGHT_SW_VERSION`]) and git revision ([`GIT_REVISION`]) the image was
/// built from, [`CAPABILITIES`], [`VENDOR_ID`] / [`PRODUCT_ID`], and the chip's 96-bit unique id `uid`: whole in
/// uid2 (its first 12 bytes, the rest 0), folded into uid (the X/Y word, and the wafer/lot words XORed above it).
/// No middleware, OS or board version (0); middleware_custom_version is [`DEV_KEY_MARK`] when the image takes
/// development-key files (`dev_key`).
pub(crate) fn autopilot_version(uid: &[u8; 12], dev_key: bool) -> AUTOPILOT_VERSION_DATA {
    let word = |n: usize| {
        let mut bytes = [0u8; 4];
        if let Some(src) = uid.get(n * 4..n * 4 + 4) {
            bytes.copy_from_slice(src);
        }
        u32::from_le_bytes(bytes)
    };
    let mut uid2 = [0u8; 18];
    for (dst, src) in uid2.iter_mut().zip(uid) {
        *dst = *src;
    }
    AUTOPILOT_VERSION_DATA {
        capabilities: CAPABILITIES,
        uid: u64::from(word(0)) | u64::from(word(1) ^ word(2)) << 32,
        flight_sw_version: FLIGHT_SW_VERSION,
        middleware_sw_version: 0,
        os_sw_version: 0,
        board_version: 0,
        vendor_id: VENDOR_ID,
        product_id: PRODUCT_ID,
        flight_custom_version: GIT_REVISION,
        middleware_custom_version: if dev_key { DEV_KEY_MARK } else { [0; 8] },
        os_custom_version: [0; 8],
        uid2,
    }
}

/// HEARTBEAT.mavlink_version: MAVLink protocol version 3 of the XML definitions.
const MAVLINK_VERSION: u8 = 3;

/// The latest thruster reports, one per configured thruster (`None`: not configured or not yet heard).
pub(crate) type Reports = [Option<ThrusterReport>; MAX_THRUSTERS];

/// HEARTBEAT: a submarine with an ArduPilot autopilot (so QGroundControl shows its ArduSub views and pilots see
/// the familiar mode), in ArduSub's MANUAL mode, armed or not as the vehicle task says (not armed when it has not
/// said anything yet).
pub(crate) fn heartbeat(vehicle: Option<VehicleState>) -> HEARTBEAT_DATA {
    heartbeat_of(vehicle.is_some_and(|v| v.armed))
}

/// HEARTBEAT of a vehicle `armed` or not ([`heartbeat`]).
pub(crate) fn heartbeat_of(armed: bool) -> HEARTBEAT_DATA {
    let mut base_mode =
        MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | MavModeFlag::MAV_MODE_FLAG_MANUAL_INPUT_ENABLED;
    base_mode.set(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED, armed);
    HEARTBEAT_DATA {
        custom_mode: ARDUSUB_MODE_MANUAL,
        mavtype: MavType::MAV_TYPE_SUBMARINE,
        autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
        base_mode,
        system_status: if armed {
            MavState::MAV_STATE_ACTIVE
        } else {
            MavState::MAV_STATE_STANDBY
        },
        mavlink_version: MAVLINK_VERSION,
    }
}

/// Console link quality over the last telemetry period, for SYS_STATUS.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct ConsoleLinkQuality {
    /// Corrupt frames as a share of all frames received, in 0.01 % (0..=10000).
    pub(crate) drop_rate: u16,
    /// Corrupt frames since start (saturating: a flood must not wrap it back to a small number).
    pub(crate) errors: u16,
    /// Requests refused since start because they came from another system than the operator's (saturating).
    pub(crate) refused_other_system: u16,
    /// Frames refused since start by the signing checks (saturating).
    pub(crate) refused_by_signing: u16,
}

/// The battery's fresh reading: `None` when there is none or it is stale.
fn fresh(battery: Option<&BatterySummary>) -> Option<&BatterySummary> {
    battery.filter(|b| !b.info_stale && b.info.is_some())
}

/// Whether the battery reports an alarm or a DCDC fault, each from its own frame while that frame is fresh.
fn battery_faulty(battery: &BatterySummary) -> bool {
    battery.fresh_alarms().is_some_and(|a| !a.is_empty()) || battery.fresh_status().is_some_and(|s| s.has_fault())
}

/// Thruster link errors of every kind, summed.
fn link_errors(report: &ThrusterReport) -> u32 {
    let h = &report.health;
    [
        h.nack,
        h.timeout,
        h.bad_checksum,
        h.bad_type,
        h.bad_length,
        h.bad_range,
        h.bus_error,
    ]
    .into_iter()
    .fold(0u32, u32::wrapping_add)
}

/// SYS_STATUS.
///
/// - Sensors: MOTOR_OUTPUTS (present and enabled when thrusters are configured, healthy when every configured
///   thruster is online with its status readable and follows its orders, `driving`), PROPULSION (healthy when no configured thruster reports a fault), BATTERY (present and
///   enabled always, healthy with a fresh reading and no BMS alarm nor DCDC fault), RC_RECEIVER (the pilot's
///   control link, the ground station's heartbeats and MANUAL_CONTROL: present and enabled always, unhealthy
///   while a failsafe is in force, [`VehicleState::failsafe`]), PREARM_CHECK (present and enabled always, healthy
///   exactly when an arm command would be accepted, [`VehicleState::armable`]) and, in the extended bits, LEAK
///   (healthy when no thruster reports its water sensor). Before the vehicle task has said anything, RC_RECEIVER
///   and PREARM_CHECK are unhealthy.
/// - voltage_battery mV, current_battery cA, battery_remaining %: from a fresh battery reading, else the
///   "unknown" values UINT16_MAX, -1, -1.
/// - drop_rate_comm, errors_comm: the console link ([`ConsoleLinkQuality`]).
/// - errors_count1: thruster link errors (NACK, timeout, checksum, type, length, range, bus), summed over the
///   configured thrusters; errors_count2: battery CAN frames that did not decode; errors_count3: console
///   requests refused because they came from another system than the operator's; errors_count4: console frames
///   refused by the signing checks.
/// - load: 0 (not measured). Every counter saturates at UINT16_MAX rather than wrap.
pub(crate) fn sys_status(
    thrusters: usize,
    reports: &Reports,
    battery: Option<&BatterySummary>,
    vehicle: Option<VehicleState>,
    link: ConsoleLinkQuality,
) -> SYS_STATUS_DATA {
    let configured = reports.iter().take(thrusters);
    let all_driving = configured.clone().all(|r| r.as_ref().is_some_and(driving));
    let faults = configured
        .clone()
        .flatten()
        .filter_map(|r| r.status)
        .fold(Faults::NONE, |all, s| all.union(s.faults()));
    let errors = configured.flatten().map(link_errors).fold(0u32, u32::wrapping_add);

    let motors = if thrusters > 0 {
        MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_PROPULSION
    } else {
        MavSysStatusSensor::empty()
    };
    let present = motors
        | MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_BATTERY
        | MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_RC_RECEIVER
        | MavSysStatusSensor::MAV_SYS_STATUS_PREARM_CHECK;
    // No geofence exists, so none is breached: reported healthy as ArduPilot does. Ground stations that take the
    // bit's absence for a breach (MAVProxy says "fence breach" at connect) stay quiet.
    let mut health = present | MavSysStatusSensor::MAV_SYS_STATUS_GEOFENCE;
    health.set(MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS, all_driving);
    health.set(
        MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_PROPULSION,
        faults.difference(Faults::WATER).is_empty(),
    );
    health.set(
        MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_RC_RECEIVER,
        vehicle.is_some_and(|v| !v.failsafe),
    );
    health.set(
        MavSysStatusSensor::MAV_SYS_STATUS_PREARM_CHECK,
        vehicle.is_some_and(|v| v.armable),
    );
    let fresh = fresh(battery);
    health.set(
        MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_BATTERY,
        fresh.is_some_and(|b| !battery_faulty(b)),
    );
    let leak = if thrusters > 0 {
        MavSysStatusSensorExtended::MAV_SYS_STATUS_SENSOR_LEAK
    } else {
        MavSysStatusSensorExtended::empty()
    };
    let mut leak_health = leak;
    leak_health.set(
        MavSysStatusSensorExtended::MAV_SYS_STATUS_SENSOR_LEAK,
        !faults.contains(Faults::WATER),
    );
    let present = if leak.is_empty() {
        present
    } else {
        present | MavSysStatusSensor::MAV_SYS_STATUS_EXTENSION_USED
    };

    let info = fresh.and_then(|b| b.info);
    SYS_STATUS_DATA {
        onboard_control_sensors_present: present,
        onboard_control_sensors_enabled: present,
        onboard_control_sensors_health: health,
        load: 0,
        voltage_battery: info.map_or(u16::MAX, |i| millivolts(i.voltage_decivolts)),
        current_battery: info.and_then(|i| i.current_deciamps).map_or(-1, centiamps),
        battery_remaining: info
            .and_then(|i| i.charge_percent)
            .map_or(-1, |charge| charge.min(100) as i8),
        drop_rate_comm: link.drop_rate,
        errors_comm: link.errors,
        errors_count1: saturate(errors),
        errors_count2: battery.map_or(0, |b| saturate(b.errors)),
        errors_count3: link.refused_other_system,
        errors_count4: link.refused_by_signing,
        onboard_control_sensors_present_extended: leak,
        onboard_control_sensors_enabled_extended: leak,
        onboard_control_sensors_health_extended: leak_health,
    }
}

/// A 32-bit counter in a 16-bit field: UINT16_MAX once it no longer fits.
pub(crate) fn saturate(count: u32) -> u16 {
    u16::try_from(count).unwrap_or(u16::MAX)
}

/// 0.1 V to mV, below UINT16_MAX (which means "unknown").
fn millivolts(decivolts: u16) -> u16 {
    (u32::from(decivolts) * 100).min(u32::from(u16::MAX - 1)) as u16
}

/// 0.1 A to cA; -1 means "unknown" and cannot come out of a multiple of 10.
fn centiamps(deciamps: i16) -> i16 {
    (i32::from(deciamps) * 10).clamp(i32::from(i16::MIN), i32::from(i16::MAX)) as i16
}

/// MAVLink battery faults of the BMS alarms that have one.
fn battery_faults(alarms: BmsAlarms) -> MavBatteryFault {
    let mut faults = MavBatteryFault::empty();
    faults.set(
        MavBatteryFault::MAV_BATTERY_FAULT_DEEP_DISCHARGE,
        alarms.contains(BmsAlarms::LOW_VOLTAGE),
    );
    faults.set(
        MavBatteryFault::MAV_BATTERY_FAULT_OVER_CURRENT,
        alarms.contains(BmsAlarms::OVERCURRENT_DISCHARGE) || alarms.contains(BmsAlarms::OVERCURRENT_CHARGE),
    );
    faults.set(
        MavBatteryFault::MAV_BATTERY_FAULT_OVER_TEMPERATURE,
        alarms.contains(BmsAlarms::HIGH_TEMPERATURE),
    );
    faults.set(
        MavBatteryFault::MAV_BATTERY_FAULT_UNDER_TEMPERATURE,
        alarms.contains(BmsAlarms::LOW_TEMPERATURE),
    );
    faults
}

/// BATTERY_STATUS of the BAT board's pack: id 0, function ALL, chemistry LION.
///
/// From a fresh reading: temperature cdegC (INT16_MAX when the board does not report it), `voltages[0]` the pack
/// voltage in mV (no cell voltages: the others UINT16_MAX), current cA (-1 when not reported), remaining %.
/// Without a fresh reading every value is "unknown". current_consumed and energy_consumed are -1 (not
/// estimated), time_remaining 0 (not estimated), mode UNKNOWN.
///
/// charge_state: UNDEFINED without a fresh reading; UNHEALTHY with a BMS alarm or a DCDC fault, each from a frame
/// of its own that is fresh (a stale status or alarm frame counts as unknown, not as the old value; fault_bitmask
/// names the alarms MAVLink has a bit for: low voltage as DEEP_DISCHARGE, over-current, over- and
/// under-temperature); LOW with only the BMS low-charge alarm; CHARGING when the current is negative; else OK.
pub(crate) fn battery_status(battery: Option<&BatterySummary>) -> BATTERY_STATUS_DATA {
    BatteryFields::of(battery).message()
}

/// What BATTERY_STATUS says of the pack that changes ([`battery_status`]), each field in the message's unit with its
/// "unknown" value: what the black box keeps of the battery ([`crate::blackbox`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct BatteryFields {
    /// Pack voltage, mV (UINT16_MAX unknown).
    pub(crate) millivolts: u16,
    /// Current, cA (-1 unknown).
    pub(crate) centiamps: i16,
    /// Charge, % (-1 unknown).
    pub(crate) remaining: i8,
    /// Temperature, cdegC (INT16_MAX unknown).
    pub(crate) temperature: i16,
    pub(crate) charge_state: MavBatteryChargeState,
    pub(crate) faults: MavBatteryFault,
}

impl BatteryFields {
    /// The fields of the master's battery summary.
    pub(crate) fn of(battery: Option<&BatterySummary>) -> Self {
        let fresh = fresh(battery);
        let info = fresh.and_then(|b| b.info);
        let alarms = fresh.and_then(BatterySummary::fresh_alarms).unwrap_or(BmsAlarms::NONE);
        let dcdc_fault = fresh
            .and_then(BatterySummary::fresh_status)
            .is_some_and(|s| s.has_fault());
        let serious_alarm = alarms.bits() & !BmsAlarms::LOW_CHARGE.bits() != 0;
        let charge_state = match info {
            None => MavBatteryChargeState::MAV_BATTERY_CHARGE_STATE_UNDEFINED,
            Some(_) if dcdc_fault || serious_alarm => MavBatteryChargeState::MAV_BATTERY_CHARGE_STATE_UNHEALTHY,
            Some(_) if alarms.contains(BmsAlarms::LOW_CHARGE) => MavBatteryChargeState::MAV_BATTERY_CHARGE_STATE_LOW,
            Some(i) if i.current_deciamps.is_some_and(|c| c < 0) => {
                MavBatteryChargeState::MAV_BATTERY_CHARGE_STATE_CHARGING
            }
            Some(_) => MavBatteryChargeState::MAV_BATTERY_CHARGE_STATE_OK,
        };
        Self {
            millivolts: info.map_or(u16::MAX, |i| millivolts(i.voltage_decivolts)),
            centiamps: info.and_then(|i| i.current_deciamps).map_or(-1, centiamps),
            remaining: info
                .and_then(|i| i.charge_percent)
                .map_or(-1, |charge| charge.min(100) as i8),
            temperature: info.and_then(|i| i.temperature_decicelsius).map_or(i16::MAX, |t| {
                (i32::from(t) * 10).clamp(i32::from(i16::MIN), i32::from(i16::MAX - 1)) as i16
            }),
            charge_state,
            faults: battery_faults(alarms),
        }
    }

    /// Its BATTERY_STATUS.
    pub(crate) fn message(&self) -> BATTERY_STATUS_DATA {
        let mut voltages = [u16::MAX; 10];
        if let Some(first) = voltages.first_mut() {
            *first = self.millivolts;
        }
        BATTERY_STATUS_DATA {
            id: 0,
            battery_function: MavBatteryFunction::MAV_BATTERY_FUNCTION_ALL,
            mavtype: MavBatteryType::MAV_BATTERY_TYPE_LION,
            temperature: self.temperature,
            voltages,
            current_battery: self.centiamps,
            current_consumed: -1,
            energy_consumed: -1,
            battery_remaining: self.remaining,
            time_remaining: 0,
            charge_state: self.charge_state,
            voltages_ext: [0; 4],
            mode: MavBatteryMode::MAV_BATTERY_MODE_UNKNOWN,
            fault_bitmask: self.faults,
        }
    }
}

/// One thruster's ESC_TELEMETRY entry.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct EscEntry {
    /// Temperature, °C.
    pub(crate) temperature: u8,
    /// Motor current, cA.
    pub(crate) current: u16,
    /// Speed magnitude, rpm.
    pub(crate) rpm: u16,
    /// Good polls (wrapping).
    pub(crate) count: u16,
}

/// A thruster's ESC_TELEMETRY entry: rpm from a brushless SeaBotix status (a brushed one reports PWM, not rpm,
/// and a Legacy thruster no speed at all: 0); current from the SeaBotix CURRENT or the brushless Legacy MAX POWER
/// byte; temperature from SeaBotix (Legacy has none: 0); count the good polls. Voltage and total current are not
/// measured (0). Offline or absent thrusters read all zeros. ardupilotmega.xml defines no "unknown" value for any
/// of these fields; ArduPilot sends 0 for data an ESC does not report, and so does the master. ESC_INFO and
/// ESC_STATUS say what is not known where their fields can ([`esc_info`], [`esc_status`]).
pub(crate) fn esc_entry(report: Option<&ThrusterReport>) -> EscEntry {
    report.map_or_else(EscEntry::default, |r| {
        EscEntry::of(&Esc::of_report(r), r.health.good as u16)
    })
}

impl EscEntry {
    /// The entry of a thruster that reports `esc`, `count` its good polls ([`esc_entry`]).
    pub(crate) fn of(esc: &Esc, count: u16) -> Self {
        if !esc.reporting {
            return Self::default();
        }
        Self {
            temperature: esc.temperature_c.unwrap_or(0),
            current: esc.current_deciamps.map_or(0, |deciamps| u16::from(deciamps) * 10),
            rpm: esc
                .speed
                .map_or(0, |speed| u16::try_from(speed.rpm().unsigned_abs()).unwrap_or(u16::MAX)),
            count,
        }
    }
}

/// The four ESC entries of thrusters `first..first + 4`, zero beyond the configured ones.
fn esc_block(thrusters: usize, reports: &Reports, first: usize) -> [EscEntry; 4] {
    core::array::from_fn(|i| {
        let n = first + i;
        if n < thrusters {
            esc_entry(reports.get(n).and_then(Option::as_ref))
        } else {
            EscEntry::default()
        }
    })
}

/// ESC_TELEMETRY_1_TO_4 of thrusters 1..=4.
pub(crate) fn esc_telemetry_1_to_4(thrusters: usize, reports: &Reports) -> ESC_TELEMETRY_1_TO_4_DATA {
    esc_telemetry_of(&esc_block(thrusters, reports, 0))
}

/// ESC_TELEMETRY_1_TO_4 of four entries (ESC_TELEMETRY_5_TO_8 has the same fields: [`esc_telemetry_5_to_8`]).
pub(crate) fn esc_telemetry_of(e: &[EscEntry; 4]) -> ESC_TELEMETRY_1_TO_4_DATA {
    ESC_TELEMETRY_1_TO_4_DATA {
        temperature: e.map(|e| e.temperature),
        voltage: [0; 4],
        current: e.map(|e| e.current),
        totalcurrent: [0; 4],
        rpm: e.map(|e| e.rpm),
        count: e.map(|e| e.count),
    }
}

/// ESC_TELEMETRY_5_TO_8 of thrusters 5..=8.
pub(crate) fn esc_telemetry_5_to_8(thrusters: usize, reports: &Reports) -> ESC_TELEMETRY_5_TO_8_DATA {
    esc_telemetry_5_to_8_of(&esc_block(thrusters, reports, 4))
}

/// ESC_TELEMETRY_5_TO_8 of four entries.
pub(crate) fn esc_telemetry_5_to_8_of(e: &[EscEntry; 4]) -> ESC_TELEMETRY_5_TO_8_DATA {
    let m = esc_telemetry_of(e);
    ESC_TELEMETRY_5_TO_8_DATA {
        temperature: m.temperature,
        voltage: m.voltage,
        current: m.current,
        totalcurrent: m.totalcurrent,
        rpm: m.rpm,
        count: m.count,
    }
}

/// Whether a thruster's report is current: online, and its status readable (one whose orders get through but
/// whose status has not been read for a while reads as unknown, not as its last values).
fn reporting(report: &ThrusterReport) -> bool {
    report.health.online && !report.health.status_lost
}

/// Online, reporting, and following its orders ([`crate::follow`]): what MOTOR_OUTPUTS' health asks of every
/// configured thruster.
fn driving(report: &ThrusterReport) -> bool {
    reporting(report) && !report.health.not_following
}

/// What ESC_STATUS and ESC_INFO say of one thruster ([`esc_status`], [`esc_info`]): what the black box keeps of it
/// too ([`crate::blackbox`]). What a thruster does not report, or not now, is `None`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct Esc {
    /// Online, and its status readable ([`reporting`]).
    pub(crate) reporting: bool,
    /// The speed a brushless SeaBotix thruster reports, negative astern.
    pub(crate) speed: Option<Speed>,
    /// The motor current, 0.1 A: the SeaBotix CURRENT or the brushless Legacy MAX POWER byte.
    pub(crate) current_deciamps: Option<u8>,
    /// The SeaBotix temperature, °C.
    pub(crate) temperature_c: Option<u8>,
    /// The last status's faults, whether the thruster reports now or not.
    pub(crate) faults: Faults,
}

impl Esc {
    /// What thruster `n` of the `thrusters` configured reports (nothing for one past them).
    pub(crate) fn of(thrusters: usize, reports: &Reports, n: usize) -> Self {
        reports
            .get(n)
            .filter(|_| n < thrusters)
            .and_then(Option::as_ref)
            .map_or_else(Self::default, Self::of_report)
    }

    /// What a thruster's report says of it.
    pub(crate) fn of_report(report: &ThrusterReport) -> Self {
        let faults = report.status.map_or(Faults::NONE, |s| s.faults());
        let status = report.status.filter(|_| reporting(report));
        let (speed, current_deciamps, temperature_c) = match status {
            Some(Status::SeaBotix(s)) => (
                (s.motor == MotorKind::Brushless).then_some(s.speed),
                Some(s.current_deciamps),
                Some(s.temperature_c),
            ),
            Some(Status::Legacy(s)) => match s.max_power {
                MaxPower::Current { deciamps } => (None, Some(deciamps), None),
                MaxPower::Power(_) | MaxPower::Raw(_) => (None, None, None),
            },
            None => (None, None, None),
        };
        Self {
            reporting: reporting(report),
            speed,
            current_deciamps,
            temperature_c,
            faults,
        }
    }

    /// Thrusters `first..first + 4`.
    pub(crate) fn block(thrusters: usize, reports: &Reports, first: usize) -> [Self; 4] {
        core::array::from_fn(|i| Self::of(thrusters, reports, first + i))
    }
}

/// ESC_STATUS of thrusters `first..first + 4` (index `first`, time since boot).
///
/// rpm: the speed a brushless SeaBotix thruster reports, negative astern. common.xml defines no "unknown" rpm,
/// so a thruster that reports none (brushed SeaBotix, Legacy 0x54/0x55, offline, not configured) reads 0, as
/// ArduPilot fills rpm it does not have. voltage: not measured per thruster, NaN (MAVLink's "invalid" for a float
/// field). current: the reported motor current in A, NaN where none is reported.
pub(crate) fn esc_status(first: usize, escs: &[Esc; 4], time_usec: u64) -> ESC_STATUS_DATA {
    ESC_STATUS_DATA {
        index: first as u8,
        time_usec,
        rpm: escs.map(|e| e.speed.map_or(0, Speed::rpm)),
        voltage: [f32::NAN; 4],
        current: escs.map(|e| e.current_deciamps.map_or(f32::NAN, |d| f32::from(d) / 10.0)),
    }
}

/// The ESC failure flags of a thruster's faults: overtemperature, stall (motor stuck), hall or ground fault
/// (generic). Water is a leak, which SYS_STATUS reports, not a failure of the ESC.
fn esc_failures(faults: Faults) -> u16 {
    let mut flags = EscFailureFlags::empty();
    flags.set(
        EscFailureFlags::ESC_FAILURE_OVER_TEMPERATURE,
        faults.contains(Faults::OVERTEMP),
    );
    flags.set(EscFailureFlags::ESC_FAILURE_MOTOR_STUCK, faults.contains(Faults::STALL));
    flags.set(
        EscFailureFlags::ESC_FAILURE_GENERIC,
        faults.contains(Faults::HALL) || faults.contains(Faults::GROUND),
    );
    flags.bits()
}

/// The link counters ESC_INFO carries of a block of thrusters: the good polls of the block (wrapping), and each
/// one's link errors.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct EscCounters {
    pub(crate) counter: u16,
    pub(crate) errors: [u32; 4],
}

impl EscCounters {
    /// Thrusters `first..first + 4`'s counters.
    pub(crate) fn of(thrusters: usize, reports: &Reports, first: usize) -> Self {
        let report = |i: usize| {
            let n = first + i;
            reports.get(n).filter(|_| n < thrusters).and_then(Option::as_ref)
        };
        Self {
            counter: (0..4)
                .filter_map(report)
                .fold(0u16, |sum, r| sum.wrapping_add(r.health.good as u16)),
            errors: core::array::from_fn(|i| report(i).map_or(0, link_errors)),
        }
    }
}

/// ESC_INFO of thrusters `first..first + 4` of `thrusters` (index `first`, time since boot): count the configured
/// thrusters, connection I2C, info bit n set when thruster `first + n` is reporting, counter and error_count from
/// `counters`, failure_flags from the last status's faults, temperature the SeaBotix temperature in cdegC and
/// INT16_MAX (common.xml's "not supplied") for Legacy, offline or absent thrusters.
pub(crate) fn esc_info(
    thrusters: usize,
    first: usize,
    escs: &[Esc; 4],
    counters: &EscCounters,
    time_usec: u64,
) -> ESC_INFO_DATA {
    ESC_INFO_DATA {
        index: first as u8,
        time_usec,
        counter: counters.counter,
        count: thrusters.min(MAX_THRUSTERS) as u8,
        connection_type: EscConnectionType::ESC_CONNECTION_TYPE_I2C,
        info: (0..4).fold(0u8, |bits, i| {
            if escs.get(i).is_some_and(|e| e.reporting) {
                bits | 1 << i
            } else {
                bits
            }
        }),
        failure_flags: escs.map(|e| esc_failures(e.faults)),
        error_count: counters.errors,
        temperature: escs.map(|e| e.temperature_c.map_or(i16::MAX, |t| i16::from(t) * 100)),
    }
}

/// `n / d` rounded to the nearest whole number, halves away from zero (`d` > 0).
pub const fn rounded_div(n: i32, d: i32) -> i32 {
    if n >= 0 { (n + d / 2) / d } else { (n - d / 2) / d }
}

/// SERVO_OUTPUT_RAW of the orders to the `thrusters` configured: each as the pulse ArduSub would give a thruster
/// for it, 1500 us stopped and 400 us either way at full speed (its MOT_PWM_MIN/MAX defaults, 1100 and 1900), so
/// a ground station's log tools draw them as ArduSub's motor outputs. Outputs past the thrusters read 0, as
/// ArduPilot sends them for outputs it does not use.
pub(crate) fn servo_output_raw(
    thrusters: usize,
    orders: &[Speed; MAX_THRUSTERS],
    time_usec: u32,
) -> SERVO_OUTPUT_RAW_DATA {
    let pulse = |n: usize| match orders.get(n).filter(|_| n < thrusters) {
        // Rounded to the nearest microsecond: a step is 3.9 us, so each pulse reads back as its step.
        Some(speed) => (1500 + rounded_div(i32::from(speed.step()) * 400, i32::from(Speed::MAX_STEP))) as u16,
        None => 0,
    };
    SERVO_OUTPUT_RAW_DATA {
        time_usec,
        port: 0,
        servo1_raw: pulse(0),
        servo2_raw: pulse(1),
        servo3_raw: pulse(2),
        servo4_raw: pulse(3),
        servo5_raw: pulse(4),
        servo6_raw: pulse(5),
        servo7_raw: pulse(6),
        servo8_raw: pulse(7),
        servo9_raw: 0,
        servo10_raw: 0,
        servo11_raw: 0,
        servo12_raw: 0,
        servo13_raw: 0,
        servo14_raw: 0,
        servo15_raw: 0,
        servo16_raw: 0,
    }
}

/// MAV_SEVERITY of a [`Severity`].
pub(crate) fn severity(severity: Severity) -> MavSeverity {
    match severity {
        Severity::Critical => MavSeverity::MAV_SEVERITY_CRITICAL,
        Severity::Error => MavSeverity::MAV_SEVERITY_ERROR,
        Severity::Warning => MavSeverity::MAV_SEVERITY_WARNING,
        Severity::Notice => MavSeverity::MAV_SEVERITY_NOTICE,
        Severity::Info => MavSeverity::MAV_SEVERITY_INFO,
    }
}

/// MAV_RESULT of an [`AckResult`].
pub(crate) fn result(result: AckResult) -> MavResult {
    match result {
        AckResult::Accepted => MavResult::MAV_RESULT_ACCEPTED,
        AckResult::TemporarilyRejected => MavResult::MAV_RESULT_TEMPORARILY_REJECTED,
        AckResult::Denied => MavResult::MAV_RESULT_DENIED,
        AckResult::Unsupported => MavResult::MAV_RESULT_UNSUPPORTED,
        AckResult::Failed => MavResult::MAV_RESULT_FAILED,
        AckResult::InProgress => MavResult::MAV_RESULT_IN_PROGRESS,
    }
}

/// STATUSTEXT: one chunk (id 0), the text NUL-padded to 50 bytes.
pub(crate) fn statustext(level: Severity, text: &Text) -> STATUSTEXT_DATA {
    let mut bytes = [0u8; 50];
    for (dst, src) in bytes.iter_mut().zip(text.as_bytes()) {
        *dst = *src;
    }
    STATUSTEXT_DATA {
        severity: severity(level),
        text: bytes.into(),
        id: 0,
        chunk_seq: 0,
    }
}

/// COMMAND_ACK IN_PROGRESS with `progress` (0-100), addressed to the command's sender.
pub(crate) fn command_progress(command: u16, progress: u8, to: Sender) -> COMMAND_ACK_DATA {
    COMMAND_ACK_DATA {
        progress,
        ..command_ack(command, AckResult::InProgress, to)
    }
}

/// COMMAND_ACK, addressed to the command's sender. Progress and result_param2 are 0 (an IN_PROGRESS with its
/// progress is [`command_progress`]).
pub(crate) fn command_ack(command: u16, answer: AckResult, to: Sender) -> COMMAND_ACK_DATA {
    COMMAND_ACK_DATA {
        command,
        result: result(answer),
        progress: 0,
        result_param2: 0,
        target_system: to.system,
        target_component: to.component,
    }
}

/// AVAILABLE_MODES of the one mode the vehicle has: ArduSub's MANUAL (custom mode 19), MAV_STANDARD_MODE_NON_STANDARD
/// (0: none of MAVLink's standard modes fits it), no properties (it may be chosen, and is not advanced).
pub(crate) fn available_modes() -> AVAILABLE_MODES_DATA {
    let mut mode_name = [0; 35];
    if let Some(name) = mode_name.get_mut(..6) {
        name.copy_from_slice(b"MANUAL");
    }
    AVAILABLE_MODES_DATA {
        number_modes: 1,
        mode_index: 1,
        standard_mode: 0,
        custom_mode: ARDUSUB_MODE_MANUAL,
        properties: 0,
        mode_name: mode_name.into(),
    }
}

/// MISSION_COUNT 0 of `mission_type`, addressed to who asked: the master keeps no mission, fence or rally points
/// (opaque_id 0: no plan to identify).
pub(crate) fn mission_count(to: Sender, mission_type: u8) -> MISSION_COUNT_DATA {
    MISSION_COUNT_DATA {
        target_system: to.system,
        target_component: to.component,
        count: 0,
        mission_type,
        opaque_id: 0,
    }
}

/// MISSION_ACK of a clear or an upload of `mission_type`, addressed to who asked: MAV_MISSION_ACCEPTED (0), or
/// MAV_MISSION_UNSUPPORTED (3) for an upload the master does not take (opaque_id 0: it keeps no plan to identify).
pub(crate) fn mission_ack(to: Sender, mission_type: u8, accepted: bool) -> MISSION_ACK_DATA {
    MISSION_ACK_DATA {
        target_system: to.system,
        target_component: to.component,
        mavtype: if accepted { 0 } else { 3 },
        mission_type,
        opaque_id: 0,
    }
}

/// PARAM_VALUE, with the parameter's own type (an integer's value as the float, PARAM_ENCODE_C_CAST).
pub(crate) fn param_value(id: &ParamId, value: f32, param_type: ParamType, index: u16, count: u16) -> PARAM_VALUE_DATA {
    PARAM_VALUE_DATA {
        param_id: (*id).into(),
        param_value: value,
        param_type: match param_type {
            ParamType::Int8 => MavParamType::MAV_PARAM_TYPE_INT8,
            ParamType::Int16 => MavParamType::MAV_PARAM_TYPE_INT16,
            ParamType::Int32 => MavParamType::MAV_PARAM_TYPE_INT32,
            ParamType::Real32 => MavParamType::MAV_PARAM_TYPE_REAL32,
        },
        param_count: count,
        param_index: index,
    }
}

/// NAMED_VALUE_FLOAT "PilotGain": the pilot gain `percent` as the fraction ArduSub sends (its `gain`, 0.1..1.0;
/// QGroundControl shows it times 100), at `time_boot_ms`.
pub(crate) fn pilot_gain(percent: u8, time_boot_ms: u32) -> NAMED_VALUE_FLOAT_DATA {
    let mut name = [0; 10];
    if let Some(slot) = name.get_mut(..9) {
        slot.copy_from_slice(b"PilotGain");
    }
    NAMED_VALUE_FLOAT_DATA {
        time_boot_ms,
        name: name.into(),
        value: f32::from(percent) / 100.0,
    }
}

/// MAVLink 2 header length (start byte included).
const HEADER_LEN: usize = 10;
/// Largest MAVLink 2 payload.
const MAX_PAYLOAD: usize = 255;

/// MAVLink 2 framing of outgoing messages: this system's header and a sequence number that counts every frame.
/// Only the payload's encoding is generic; the header and CRC are written by one function for every message type
/// (the mavlink crate's framing would be copied into the image once per type).
#[derive(Debug)]
pub struct Framer {
    system_id: u8,
    component_id: u8,
    sequence: u8,
    frame: [u8; HEADER_LEN + MAX_PAYLOAD + 2],
}

impl Framer {
    /// Frames from `system_id` / `component_id`, starting at sequence 0.
    pub(crate) const fn new(system_id: u8, component_id: u8) -> Self {
        Self {
            system_id,
            component_id,
            sequence: 0,
            frame: [0; HEADER_LEN + MAX_PAYLOAD + 2],
        }
    }

    /// Frame one message (MAVLink 2, unsigned: [`crate::console::signing::SigningState::sign`] signs it) and return its
    /// bytes.
    pub(crate) fn frame<D: MessageData>(&mut self, message: &D) -> &[u8] {
        let len = match self.frame.get_mut(HEADER_LEN..HEADER_LEN + MAX_PAYLOAD) {
            Some(payload) => message.ser(mavlink_core::MavlinkVersion::V2, payload),
            None => 0,
        };
        self.finish(D::ID, D::EXTRA_CRC, len)
    }

    /// The system and component ids of its frames.
    #[cfg(not(feature = "acceptance"))]
    pub(crate) fn ids(&self) -> (u8, u8) {
        (self.system_id, self.component_id)
    }

    /// Frame one message with its payload whole, not cut at its trailing zeros, as sequence number `sequence`: a
    /// frame whose length does not depend on its values, for a file whose every part is found by counting
    /// ([`crate::blackbox`]). MAVLink 2 receivers take a whole payload as they take a cut one.
    pub(crate) fn frame_whole<D: MessageData>(&mut self, message: &D, sequence: u8) -> &[u8] {
        if let Some(payload) = self.frame.get_mut(HEADER_LEN..HEADER_LEN + D::ENCODED_LEN) {
            message.ser(mavlink_core::MavlinkVersion::V2, payload);
        }
        self.sequence = sequence;
        self.finish(D::ID, D::EXTRA_CRC, D::ENCODED_LEN)
    }

    /// Frame a FILE_TRANSFER_PROTOCOL carrying the update server's `reply` (its payload's start, or all of it; a
    /// read made from `contents`) to `to` (network 0). Encoded by hand: its fields are bytes in this order (target_network, target_system,
    /// target_component, payload), and the generated encoder costs a kilobyte of flash for its 251-byte array.
    pub fn frame_ftp(&mut self, to: Sender, reply: &FtpAnswer, contents: &Contents<'_>) -> &[u8] {
        let mut len = 0;
        if let Some(payload) = self.frame.get_mut(HEADER_LEN..HEADER_LEN + 3 + FTP_PAYLOAD) {
            payload.fill(0);
            if let Some((targets, ftp)) = payload.split_first_chunk_mut::<3>() {
                *targets = [0, to.system, to.component];
                reply.write_to(ftp, contents);
            }
            // MAVLink 2 sends the payload without its trailing zeros.
            len = payload.iter().rposition(|byte| *byte != 0).map_or(0, |last| last + 1);
        }
        self.finish(
            FILE_TRANSFER_PROTOCOL_DATA::ID,
            FILE_TRANSFER_PROTOCOL_DATA::EXTRA_CRC,
            len,
        )
    }

    /// The frame last built: its `len` bytes.
    pub(crate) fn last(&self, len: usize) -> &[u8] {
        self.frame.get(..len).unwrap_or_default()
    }

    /// The header and CRC around the `len`-byte payload just encoded.
    #[inline(never)]
    fn finish(&mut self, id: u32, extra_crc: u8, len: usize) -> &[u8] {
        let [id0, id1, id2, _] = id.to_le_bytes();
        let header = [
            0xFD,
            len as u8,
            0,
            0,
            self.sequence,
            self.system_id,
            self.component_id,
            id0,
            id1,
            id2,
        ];
        if let Some(slot) = self.frame.get_mut(..HEADER_LEN) {
            slot.copy_from_slice(&header);
        }
        self.sequence = self.sequence.wrapping_add(1);
        let end = HEADER_LEN + len;
        let crc = mavlink_core::calculate_crc(self.frame.get(1..end).unwrap_or_default(), extra_crc);
        if let Some(slot) = self.frame.get_mut(end..end + 2) {
            slot.copy_from_slice(&crc.to_le_bytes());
        }
        self.frame.get(..end + 2).unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::console::ConsoleCounters;
    use crate::shared::LinkHealth;
    use bat_proto::{BatteryInfo, DcdcStatus, StatusBit};
    use tmc_proto::{LegacyRevision, LegacyStatus, SeaBotixStatus, Speed};

    fn seabotix(speed: i8, current: u8, temperature: u8) -> Status {
        Status::SeaBotix(SeaBotixStatus {
            revision: 0,
            motor: MotorKind::Brushless,
            current_limited: false,
            faults: Faults::NONE,
            current_deciamps: current,
            speed: Speed::new(speed).unwrap(),
            temperature_c: temperature,
        })
    }

    fn online(status: Option<Status>, good: u32) -> Option<ThrusterReport> {
        Some(ThrusterReport {
            health: LinkHealth {
                online: true,
                good,
                ..LinkHealth::default()
            },
            status,
        })
    }

    fn battery() -> BatterySummary {
        BatterySummary {
            info: Some(BatteryInfo {
                voltage_decivolts: 252,
                charge_percent: Some(80),
                current_deciamps: Some(-35),
                temperature_decicelsius: Some(215),
            }),
            status: Some(DcdcStatus::from_word(0)),
            alarms: Some(BmsAlarms::NONE),
            stale: false,
            info_stale: false,
            status_stale: false,
            alarms_stale: false,
            frames: 10,
            errors: 2,
        }
    }

    /// Disarmed, armable, no failsafe.
    const READY: VehicleState = VehicleState::READY;

    #[test]
    fn sys_status_prearm_and_failsafe_follow_the_vehicle() {
        let mut reports: Reports = [None; MAX_THRUSTERS];
        for r in reports.iter_mut().take(6) {
            *r = online(Some(seabotix(0, 0, 20)), 1);
        }
        let prearm = MavSysStatusSensor::MAV_SYS_STATUS_PREARM_CHECK;
        let rc = MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_RC_RECEIVER;
        let link = ConsoleLinkQuality::default();
        for (vehicle, prearm_ok, rc_ok) in [
            (Some(READY), true, true),
            (
                Some(VehicleState {
                    armable: false,
                    ..READY
                }),
                false,
                true,
            ),
            (
                Some(VehicleState {
                    failsafe: true,
                    ..READY
                }),
                true,
                false,
            ),
            (None, false, false),
        ] {
            let s = sys_status(6, &reports, Some(&battery()), vehicle, link);
            assert_eq!(s.onboard_control_sensors_present.bits() & 0x1001_0000, 0x1001_0000);
            assert_eq!(s.onboard_control_sensors_enabled.bits() & 0x1001_0000, 0x1001_0000);
            assert_eq!(
                s.onboard_control_sensors_health.contains(prearm),
                prearm_ok,
                "{vehicle:?}"
            );
            assert_eq!(s.onboard_control_sensors_health.contains(rc), rc_ok, "{vehicle:?}");
        }
    }

    #[test]
    fn sys_status_counters_saturate() {
        let reports: Reports = [None; MAX_THRUSTERS];
        let flood = ConsoleCounters {
            bad_frames: 70_000,
            unknown_messages: 1,
            unsigned: 40_000,
            bad_signatures: 40_000,
            ..ConsoleCounters::default()
        };
        let link = crate::console::link_quality(&ConsoleCounters::default(), &flood, 65_537);
        assert_eq!(
            (link.errors, link.refused_other_system, link.refused_by_signing),
            (u16::MAX, u16::MAX, u16::MAX)
        );
        let battery = BatterySummary {
            errors: 1 << 20,
            ..battery()
        };
        let s = sys_status(6, &reports, Some(&battery), Some(READY), link);
        assert_eq!(
            (s.errors_comm, s.errors_count2, s.errors_count3, s.errors_count4),
            (u16::MAX, u16::MAX, u16::MAX, u16::MAX)
        );
        assert_eq!(saturate(65_535), 65_535);
        assert_eq!(saturate(65_536), u16::MAX);
        assert_eq!(saturate(7), 7);
    }

    #[test]
    fn heartbeat_is_disarmed_unless_the_vehicle_says_armed() {
        for vehicle in [None, Some(VehicleState::READY)] {
            let hb = heartbeat(vehicle);
            assert_eq!(hb.base_mode.bits(), 0x41);
            assert_eq!(hb.system_status, MavState::MAV_STATE_STANDBY);
        }
        let hb = heartbeat(Some(VehicleState {
            armed: true,
            ..VehicleState::READY
        }));
        assert_eq!(hb.base_mode.bits(), 0xC1);
        assert_eq!(hb.system_status, MavState::MAV_STATE_ACTIVE);
        assert_eq!((hb.mavtype as u8, hb.autopilot as u8, hb.custom_mode), (12, 3, 19));
    }

    #[test]
    fn esc_entries() {
        let r = online(Some(seabotix(-102, 23, 41)), 70_000).unwrap();
        assert_eq!(
            esc_entry(Some(&r)),
            EscEntry {
                temperature: 41,
                current: 230,
                rpm: 4500,
                count: (70_000u32 % 65_536) as u16
            }
        );
        let legacy = Status::Legacy(LegacyStatus {
            revision: LegacyRevision::AVEOX_BRUSHLESS,
            faults: Faults::NONE,
            max_power: MaxPower::Current { deciamps: 12 },
        });
        let r = online(Some(legacy), 5).unwrap();
        assert_eq!(
            esc_entry(Some(&r)),
            EscEntry {
                temperature: 0,
                current: 120,
                rpm: 0,
                count: 5
            }
        );
        let mut off = online(Some(seabotix(50, 10, 30)), 9).unwrap();
        off.health.online = false;
        assert_eq!(esc_entry(Some(&off)), EscEntry::default());
        assert_eq!(esc_entry(None), EscEntry::default());
        // Online, but its status unreadable for a while: its last values are not shown as current.
        let mut lost = online(Some(seabotix(50, 10, 30)), 9).unwrap();
        lost.health.status_lost = true;
        assert_eq!(esc_entry(Some(&lost)), EscEntry::default());
    }

    fn legacy(deciamps: u8, faults: Faults) -> Status {
        Status::Legacy(LegacyStatus {
            revision: LegacyRevision::AVEOX_BRUSHLESS,
            faults,
            max_power: MaxPower::Current { deciamps },
        })
    }

    #[test]
    fn esc_status_reports_rpm_and_current_where_known() {
        let mut reports: Reports = [None; MAX_THRUSTERS];
        reports[0] = online(Some(seabotix(-102, 23, 41)), 10);
        reports[1] = online(Some(legacy(12, Faults::NONE)), 10);
        reports[2] = online(None, 0);
        let mut off = online(Some(seabotix(50, 10, 30)), 9);
        off.as_mut().unwrap().health.online = false;
        reports[3] = off;
        reports[4] = online(Some(seabotix(51, 5, 20)), 1);
        let s = esc_status(0, &Esc::block(6, &reports, 0), 123_456);
        assert_eq!((s.index, s.time_usec), (0, 123_456));
        // Astern is negative; Legacy, no status yet and offline report no rpm: 0 (no "unknown" is defined).
        assert_eq!(s.rpm, [-4500, 0, 0, 0]);
        assert!(s.voltage.iter().all(|v| v.is_nan()), "not measured");
        assert_eq!(s.current[0], 2.3);
        assert_eq!(s.current[1], 1.2, "Legacy MAX POWER as current");
        assert!(s.current[2].is_nan() && s.current[3].is_nan());
        let b = esc_status(4, &Esc::block(6, &reports, 4), 0);
        assert_eq!((b.index, b.rpm), (4, [2250, 0, 0, 0]));
        assert!(
            b.current[1..].iter().all(|c| c.is_nan()),
            "thruster 6 unheard, 7 and 8 not configured"
        );
    }

    #[test]
    fn esc_info_says_what_is_not_known() {
        let mut reports: Reports = [None; MAX_THRUSTERS];
        reports[0] = online(
            Some(Status::SeaBotix(SeaBotixStatus {
                faults: Faults::OVERTEMP.union(Faults::WATER),
                ..match seabotix(10, 1, 41) {
                    Status::SeaBotix(s) => s,
                    Status::Legacy(_) => unreachable!(),
                }
            })),
            300,
        );
        reports[1] = online(Some(legacy(3, Faults::STALL.union(Faults::HALL))), 200);
        if let Some(r) = reports[1].as_mut() {
            r.health.timeout = 4;
            r.health.nack = 1;
        }
        let mut off = online(Some(seabotix(0, 0, 25)), 9);
        off.as_mut().unwrap().health.online = false;
        reports[2] = off;
        let i = esc_info(6, 0, &Esc::block(6, &reports, 0), &EscCounters::of(6, &reports, 0), 99);
        assert_eq!((i.index, i.time_usec, i.count), (0, 99, 6));
        assert_eq!(i.connection_type, EscConnectionType::ESC_CONNECTION_TYPE_I2C);
        assert_eq!(i.info, 0b0011, "thrusters 1 and 2 online");
        assert_eq!(i.counter, 509);
        assert_eq!(
            i.failure_flags,
            [4, 32 | 64, 0, 0],
            "over-temperature; stuck and generic"
        );
        assert_eq!(i.error_count, [0, 5, 0, 0]);
        // SeaBotix in cdegC; Legacy has no sensor, thruster 3 is offline, 4 unheard: INT16_MAX.
        assert_eq!(i.temperature, [4100, i16::MAX, i16::MAX, i16::MAX]);
        let b = esc_info(6, 4, &Esc::block(6, &reports, 4), &EscCounters::of(6, &reports, 4), 99);
        assert_eq!((b.index, b.info, b.temperature), (4, 0, [i16::MAX; 4]));
    }

    #[test]
    fn autopilot_version_carries_the_build_and_the_chip() {
        let uid: [u8; 12] = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12];
        let v = autopilot_version(&uid, false);
        assert_eq!(v.capabilities.bits(), 0x2_2008);
        let part = |s: &str| s.parse::<u32>().unwrap();
        assert_eq!(
            v.flight_sw_version >> 8,
            part(env!("CARGO_PKG_VERSION_MAJOR")) << 16
                | part(env!("CARGO_PKG_VERSION_MINOR")) << 8
                | part(env!("CARGO_PKG_VERSION_PATCH"))
        );
        assert_eq!(v.flight_custom_version, GIT_REVISION);
        assert!(GIT_REVISION == [0; 8] || GIT_REVISION.iter().all(u8::is_ascii_hexdigit));
        assert_eq!(&v.uid2[..12], &uid);
        assert_eq!(&v.uid2[12..], &[0; 6]);
        assert_eq!(v.uid, 0x0403_0201 | (0x0807_0605u64 ^ 0x0C0B_0A09) << 32);
        assert_eq!((v.vendor_id, v.product_id), (0x0483, 0x0469));
        assert_eq!(autopilot_version(&[0; 12], false).uid, 0, "unknown");
        assert_eq!(
            v.middleware_custom_version, [0; 8],
            "nothing to say without the development key"
        );
    }

    #[test]
    fn autopilot_version_says_when_the_image_takes_development_key_files() {
        let v = autopilot_version(&[0; 12], true);
        assert_eq!(&v.middleware_custom_version, b"DEVKEY\0\0");
        assert_eq!(v.flight_custom_version, GIT_REVISION, "the rest as without");
    }

    #[test]
    fn esc_blocks_stop_at_the_configured_thrusters() {
        let mut reports: Reports = [None; MAX_THRUSTERS];
        for r in &mut reports {
            *r = online(Some(seabotix(51, 5, 20)), 1);
        }
        let a = esc_telemetry_1_to_4(6, &reports);
        let b = esc_telemetry_5_to_8(6, &reports);
        assert_eq!(a.rpm, [2250; 4]);
        assert_eq!(b.rpm, [2250, 2250, 0, 0]);
        assert_eq!(b.count, [1, 1, 0, 0]);
        assert_eq!((a.voltage, a.totalcurrent), ([0; 4], [0; 4]));
    }

    #[test]
    fn sys_status_health_and_battery() {
        let mut reports: Reports = [None; MAX_THRUSTERS];
        for r in reports.iter_mut().take(6) {
            *r = online(Some(seabotix(0, 0, 20)), 1);
        }
        let link = ConsoleLinkQuality {
            drop_rate: 250,
            errors: 3,
            refused_other_system: 4,
            refused_by_signing: 5,
        };
        let s = sys_status(6, &reports, Some(&battery()), Some(READY), link);
        let motors = MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS;
        let bat = MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_BATTERY;
        assert!(s.onboard_control_sensors_present.contains(motors | bat));
        assert!(s.onboard_control_sensors_health.contains(motors | bat));
        let fence = MavSysStatusSensor::MAV_SYS_STATUS_GEOFENCE;
        assert!(!s.onboard_control_sensors_present.contains(fence) && s.onboard_control_sensors_health.contains(fence));
        assert_eq!(
            (s.voltage_battery, s.current_battery, s.battery_remaining),
            (25_200, -350, 80)
        );
        assert_eq!((s.drop_rate_comm, s.errors_comm, s.errors_count2), (250, 3, 2));
        assert_eq!((s.errors_count3, s.errors_count4), (4, 5));

        // One thruster whose orders get through but whose status cannot be read: the motors' health is unknown.
        let mut unread = reports;
        if let Some(r) = unread[1].as_mut() {
            r.health.status_lost = true;
        }
        let s = sys_status(6, &unread, Some(&battery()), Some(READY), link);
        assert!(!s.onboard_control_sensors_health.contains(motors));

        // One thruster that answers but does not follow its order: the motors are not healthy.
        let mut astray = reports;
        if let Some(r) = astray[4].as_mut() {
            r.health.not_following = true;
        }
        let s = sys_status(6, &astray, Some(&battery()), Some(READY), link);
        assert!(!s.onboard_control_sensors_health.contains(motors));

        // One thruster offline with errors, a stale battery.
        if let Some(r) = reports[2].as_mut() {
            r.health.online = false;
            r.health.timeout = 7;
            r.health.nack = 1;
        }
        let stale = BatterySummary {
            stale: true,
            info_stale: true,
            status_stale: true,
            alarms_stale: true,
            ..battery()
        };
        let s = sys_status(6, &reports, Some(&stale), Some(READY), link);
        assert!(!s.onboard_control_sensors_health.contains(motors));
        assert!(!s.onboard_control_sensors_health.contains(bat));
        assert_eq!(
            (s.voltage_battery, s.current_battery, s.battery_remaining),
            (u16::MAX, -1, -1)
        );
        assert_eq!(s.errors_count1, 8);

        // A thruster beyond the configured ones does not count; a DCDC fault makes the battery unhealthy.
        let faulty = BatterySummary {
            status: Some(DcdcStatus::from_word(0).with(StatusBit::HsmFault, true)),
            ..battery()
        };
        let s = sys_status(2, &reports, Some(&faulty), Some(READY), link);
        assert!(s.onboard_control_sensors_health.contains(motors));
        assert!(!s.onboard_control_sensors_health.contains(bat));
    }

    #[test]
    fn battery_status_known_and_unknown() {
        let b = battery_status(Some(&battery()));
        assert_eq!(b.voltages[0], 25_200);
        assert!(b.voltages[1..].iter().all(|&v| v == u16::MAX));
        assert_eq!(
            (b.temperature, b.current_battery, b.battery_remaining),
            (2150, -350, 80)
        );
        assert_eq!(b.charge_state, MavBatteryChargeState::MAV_BATTERY_CHARGE_STATE_CHARGING);
        assert_eq!(b.fault_bitmask, MavBatteryFault::empty());
        assert_eq!((b.current_consumed, b.energy_consumed), (-1, -1));

        let u = battery_status(None);
        assert_eq!(u.voltages, [u16::MAX; 10]);
        assert_eq!(
            (u.temperature, u.current_battery, u.battery_remaining),
            (i16::MAX, -1, -1)
        );
        assert_eq!(
            u.charge_state,
            MavBatteryChargeState::MAV_BATTERY_CHARGE_STATE_UNDEFINED
        );

        let hot = BatterySummary {
            alarms: Some(BmsAlarms::HIGH_TEMPERATURE.union(BmsAlarms::LOW_VOLTAGE)),
            ..battery()
        };
        let h = battery_status(Some(&hot));
        assert_eq!(
            h.charge_state,
            MavBatteryChargeState::MAV_BATTERY_CHARGE_STATE_UNHEALTHY
        );
        assert_eq!(
            h.fault_bitmask,
            MavBatteryFault::MAV_BATTERY_FAULT_OVER_TEMPERATURE | MavBatteryFault::MAV_BATTERY_FAULT_DEEP_DISCHARGE
        );
        // A status word that held HSM_F when its frame stopped coming 5 s ago says nothing of now.
        let faulted = BatterySummary {
            status: Some(DcdcStatus::from_word(0x0002)),
            ..battery()
        };
        assert_eq!(
            battery_status(Some(&faulted)).charge_state,
            MavBatteryChargeState::MAV_BATTERY_CHARGE_STATE_UNHEALTHY
        );
        let gone = BatterySummary {
            status_stale: true,
            ..faulted
        };
        // The reference pack is charging (-3.5 A): what it would read without the fault.
        assert_eq!(
            battery_status(Some(&gone)).charge_state,
            MavBatteryChargeState::MAV_BATTERY_CHARGE_STATE_CHARGING
        );
        let low = BatterySummary {
            alarms: Some(BmsAlarms::LOW_CHARGE),
            ..battery()
        };
        assert_eq!(
            battery_status(Some(&low)).charge_state,
            MavBatteryChargeState::MAV_BATTERY_CHARGE_STATE_LOW
        );
    }

    #[test]
    fn framer_builds_what_the_mavlink_crate_builds() {
        let mut framer = Framer::new(1, 1);
        let mut raw = mavlink_core::MAVLinkV2MessageRaw::new();
        for sequence in 0..3u8 {
            let version = autopilot_version(&[7; 12], true);
            let ours = framer.frame(&version).to_vec();
            let header = mavlink_core::MavHeader {
                system_id: 1,
                component_id: 1,
                sequence,
            };
            raw.serialize_message_data(header, &version);
            assert_eq!(ours, raw.raw_bytes());
            let empty = framer.frame(&PARAM_VALUE_DATA::DEFAULT).to_vec();
            raw.serialize_message_data(
                mavlink_core::MavHeader {
                    sequence: sequence.wrapping_add(1),
                    ..header
                },
                &PARAM_VALUE_DATA::DEFAULT,
            );
            assert_eq!(empty, raw.raw_bytes(), "a payload of zeros truncated to one byte");
            framer.sequence = sequence.wrapping_add(1);
        }
    }

    #[test]
    fn framer_counts_sequence_numbers() {
        let mut framer = Framer::new(1, 1);
        let a = framer.frame(&heartbeat(None)).to_vec();
        let b = framer.frame(&heartbeat(None)).to_vec();
        assert_eq!((a[0], a[4], a[5], a[6]), (0xFD, 0, 1, 1));
        assert_eq!(b[4], 1);
        // Header 10 + payload 9 + CRC 2.
        assert_eq!(a.len(), 21);
    }
}
