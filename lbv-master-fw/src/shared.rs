//! What the master's tasks tell one another: the console's commands, the vehicle's orders, the thrusters' and
//! the battery's reports, and the messages queued for the console. Every task owns its own state machines and
//! talks to the others only through [`Shared`]. The tasks' modules build on this one; it builds on none of them,
//! only on [`crate::params`] and [`crate::mixer`] for the settings and the pilot's sticks it carries.

use core::cell::{Cell, RefCell};
use core::sync::atomic::{AtomicBool, AtomicU8, Ordering};

use bat_proto::{BatteryInfo, BmsAlarms, DcdcStatus};
use crash_record::{Event, LEN as RECORD_LEN, Record, Region, What};
use embassy_sync::blocking_mutex::Mutex as BlockingMutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_sync::signal::Signal;
use embassy_sync::watch::Watch;
use embassy_time::Duration;
use tmc_proto::{Order, Status};

use crate::mixer::{FrameKind, ManualInput};
use crate::params::{ParamId, ParamType, Settings};

/// Most thrusters one master drives (the LBV300 has 6; two spare).
pub(crate) const MAX_THRUSTERS: usize = 8;

/// Thruster buses a master has: I2C1..3.
pub const BUSES: usize = 3;

/// The longest STATUSTEXT text, in bytes (MAVLink STATUSTEXT.text).
pub(crate) const TEXT_LEN: usize = 50;
/// A STATUSTEXT's text: at most [`TEXT_LEN`] bytes.
pub type Text = heapless::String<TEXT_LEN>;

/// Format a text; what does not fit in 50 bytes is cut off at a character boundary.
pub fn text(args: core::fmt::Arguments<'_>) -> Text {
    let mut writer = Truncating(Text::new());
    let _ = core::fmt::Write::write_fmt(&mut writer, args);
    writer.0
}

struct Truncating<const N: usize>(heapless::String<N>);

impl<const N: usize> core::fmt::Write for Truncating<N> {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        for c in s.chars() {
            if self.0.push(c).is_err() {
                break;
            }
        }
        Ok(())
    }
}

/// "`who`: `what`" for a person, in one text or, when one STATUSTEXT cannot hold it, in two, so that a reason is
/// not cut short. The first ends at a ": ", else at a ", ", else at a space: the last one that leaves the rest room
/// in the second ("`who`: " and the rest); failing that, at the last space that fits, the rest cut at its end.
pub(crate) fn texts(who: core::fmt::Arguments<'_>, what: core::fmt::Arguments<'_>) -> (Text, Option<Text>) {
    let mut whole = Truncating(heapless::String::<{ 3 * TEXT_LEN }>::new());
    let _ = core::fmt::Write::write_fmt(&mut whole, format_args!("{who}: "));
    let start = whole.0.len();
    let _ = core::fmt::Write::write_fmt(&mut whole, what);
    let whole = whole.0.as_str();
    if whole.len() <= TEXT_LEN {
        return (text(format_args!("{whole}")), None);
    }
    // The spaces the first text may end before, last first: past `who`, within its room. Bytes, not characters:
    // the marks are ASCII, so a cut before one is a character boundary.
    let bytes = whole.as_bytes();
    let spaces = || (start..=TEXT_LEN).rev().filter(|at| bytes.get(*at) == Some(&b' '));
    let after = |at: usize| at.checked_sub(1).and_then(|before| bytes.get(before)).copied();
    let rest_fits = |at: usize| start + whole.len() - at - 1 <= TEXT_LEN;
    let cut = [Some(b':'), Some(b','), None]
        .into_iter()
        .find_map(|mark| spaces().find(|at| mark.is_none_or(|mark| after(*at) == Some(mark)) && rest_fits(*at)))
        .or_else(|| spaces().next());
    match cut.and_then(|at| Some((whole.get(..at)?, whole.get(at + 1..)?))) {
        Some((first, rest)) => (text(format_args!("{first}")), Some(text(format_args!("{who}: {rest}")))),
        None => (text(format_args!("{whole}")), None),
    }
}

/// The texts that tell that a bootloader refused `who`'s image, `code` its verdict (update-image's `Verdict`):
/// "`who`: `what`: signature" ([`texts`]: "`who`: `what`:" and "`who`: security counter below the vehicle's"
/// when that is too long for one), or "`who`: `what` (code 12)" for a code this build does not know.
pub(crate) fn verdict_texts(who: core::fmt::Arguments<'_>, what: &str, code: u32) -> (Text, Option<Text>) {
    match u8::try_from(code).ok().and_then(update_image::Verdict::from_code) {
        Some(verdict) => texts(who, format_args!("{what}: {verdict}")),
        None => texts(who, format_args!("{what} (code {code})")),
    }
}

/// Who sent a console message: its MAVLink system and component ids.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Sender {
    /// MAVLink system id (a ground station is usually 255).
    pub system: u8,
    /// MAVLink component id.
    pub component: u8,
}

/// A console command and who sent it: the vehicle decides whether that sender may ask it.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Request {
    pub from: Sender,
    /// What it asks.
    pub command: Command,
}

// The MAV_CMD numbers the console decodes and the vehicle acknowledges (the dialect leaves COMMAND_LONG's command
// a plain number).
pub const MAV_CMD_COMPONENT_ARM_DISARM: u16 = 400;
pub const MAV_CMD_DO_MOTOR_TEST: u16 = 209;
/// MAV_CMD_DO_SET_MODE: param1 the base mode (MAV_MODE_FLAG_CUSTOM_MODE_ENABLED for a custom mode), param2 the
/// custom mode, ArduSub's mode number (QGroundControl's mode menu).
pub(crate) const MAV_CMD_DO_SET_MODE: u16 = 176;
/// ArduSub's MANUAL flight mode (its custom mode 19): the one mode the vehicle has, reported as HEARTBEAT's
/// custom_mode. ArduSub's other modes need what the master has not: a depth sensor, a compass, a position.
pub(crate) const ARDUSUB_MODE_MANUAL: u32 = 19;
pub const MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN: u16 = 246;
pub(crate) const MAV_CMD_SET_MESSAGE_INTERVAL: u16 = 511;
pub(crate) const MAV_CMD_REQUEST_MESSAGE: u16 = 512;
/// The older way to ask for AUTOPILOT_VERSION.
pub(crate) const MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: u16 = 520;
/// Apply the update image received for a target ([`crate::update`]): MAV_CMD_USER_1, the first of common.xml's
/// commands left to the vendor. MAVLink has no command that applies a file received over FTP; MAV_CMD_DO_UPGRADE
/// (247, work in progress) names the component to upgrade by MAVLink component id, not a thruster slot.
pub const MAV_CMD_LBV_APPLY_UPDATE: u16 = 31010;
/// Ask a thruster which image it runs, over the field update's extension ([`crate::update::courier`]): MAV_CMD_USER_2.
pub const MAV_CMD_LBV_QUERY_VERSION: u16 = 31011;

/// FILE_TRANSFER_PROTOCOL's payload: MAVLink FTP's header and data ([`crate::update::ftp`]).
pub(crate) const FTP_PAYLOAD: usize = 251;
/// A MAVLink FTP payload.
pub(crate) type FtpPayload = [u8; FTP_PAYLOAD];

/// A request for the update server: who sent it and what it asks. Apart from [`Request`]: an FTP payload is five
/// times the size of every other command, and only the update server takes it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UpdateRequest {
    pub from: Sender,
    /// What it asks.
    pub what: UpdateCommand,
}

/// What a ground station asks of the update server.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
// Boxing the payload needs an allocator; the apply command is rare and small.
#[allow(clippy::large_enum_variant)]
pub enum UpdateCommand {
    /// A FILE_TRANSFER_PROTOCOL addressed to us: its payload.
    Ftp(FtpPayload),
    /// MAV_CMD_LBV_APPLY_UPDATE with param1 the target: a thruster slot from 0, 255 the master; `None` when param1
    /// is not a whole number 0..=255.
    Apply(Option<u8>),
    /// MAV_CMD_LBV_QUERY_VERSION with param1 the target, as [`UpdateCommand::Apply`].
    QueryVersion(Option<u8>),
}

/// The start of an FTP reply's payload: its 12-byte header and up to [`FTP_REPLY_DATA`] bytes of data (the rest
/// of the 251 are zeros). The server's replies need no more (an ACK, a NAK's code, a CRC, one directory entry),
/// and so fit in [`Outgoing`] beside the other messages for the console; a read's data is made as it is framed
/// ([`FtpAnswer::Read`]).
pub(crate) type FtpReply = [u8; 12 + FTP_REPLY_DATA];
/// Data bytes an [`FtpReply`] carries.
pub(crate) const FTP_REPLY_DATA: usize = 28;

/// The update server's counters (wrapping).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct UpdateCounters {
    /// FTP requests answered with a NAK.
    pub(crate) naks: u32,
    /// Writes past the next byte expected (an earlier write was lost), dropped unanswered for the client to send
    /// again.
    pub(crate) gaps: u32,
    /// Writes of bytes already received (their ACK was lost), ACKed again.
    pub(crate) duplicates: u32,
    /// Writes, removals and apply commands refused because they came from another system than the operator's.
    pub(crate) refused: u32,
}

/// What an update command asks of its target.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum UpdateAction {
    /// MAV_CMD_LBV_APPLY_UPDATE: apply the image received for it.
    Apply,
    /// MAV_CMD_LBV_QUERY_VERSION: say which image it runs.
    QueryVersion,
}

impl UpdateAction {
    /// Its MAV_CMD, which its COMMAND_ACKs answer.
    pub(crate) const fn command(self) -> u16 {
        match self {
            UpdateAction::Apply => MAV_CMD_LBV_APPLY_UPDATE,
            UpdateAction::QueryVersion => MAV_CMD_LBV_QUERY_VERSION,
        }
    }
}

/// What the console asked for, decoded from MAVLink by the console task.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Command {
    /// A HEARTBEAT from the ground station: the console is alive.
    Heartbeat,
    /// MANUAL_CONTROL: the sticks, and the buttons held (`buttons`, bit n for button n).
    Manual(ManualInput, u16),
    /// MAV_CMD_COMPONENT_ARM_DISARM (400): arm (param1 = 1) or disarm (0).
    Arm(bool),
    /// COMMAND_LONG MAV_CMD_DO_MOTOR_TEST (209), as QGroundControl's motor test page sends it: thruster
    /// `motor` (1-based, param1), throttle in percent -100..=100 (param2 type MOTOR_TEST_THROTTLE_PERCENT,
    /// param3, signed for ArduSub's bidirectional thrusters), for `duration` (param4 seconds).
    MotorTest {
        /// Thruster number, 1-based.
        motor: u8,
        /// Throttle, percent of full speed, -100..=100.
        percent: i8,
        /// How long to run it.
        duration: Duration,
    },
    /// COMMAND_LONG MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN (246) with param1 = 1: restart the master.
    Reboot,
    /// MAV_CMD_DO_SET_MODE (176): the custom mode asked for (`None` when param1 does not set
    /// MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, or param2 is not a whole number).
    SetMode {
        /// ArduSub's mode number.
        custom_mode: Option<u32>,
    },
    /// SETUP_SIGNING: the MAVLink 2 signing key (all zeros: signing off) and the timestamp to start from.
    SetupSigning {
        /// The 32-byte secret (SETUP_SIGNING.secret_key).
        key: [u8; 32],
        /// 10 us units since 2015-01-01.
        timestamp: u64,
    },
    /// MAV_CMD_REQUEST_MESSAGE (512) or MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES (520): send one message now.
    RequestMessage {
        /// The MAV_CMD it came as (the COMMAND_ACK names it).
        command: u16,
        /// The message, `None` when the master does not send the one asked for (or not the block of it asked).
        message: Option<Message>,
        /// ESC_INFO's and ESC_STATUS's block: the index of its first thruster (param2: 0, 4), 0 for the others.
        first: u8,
    },
    /// MAV_CMD_SET_MESSAGE_INTERVAL (511): how often to send a periodic message.
    MessageInterval {
        /// The message, `None` when the master does not send the one asked for.
        message: Option<Message>,
        /// The interval, `None` when the value asked is not one (NaN, below -1).
        interval: Option<Interval>,
    },
    /// MAV_CMD_LBV_APPLY_UPDATE (31010) or MAV_CMD_LBV_QUERY_VERSION (31011): taken by the update server (an
    /// image without one, the acceptance image, answers MAV_RESULT_UNSUPPORTED). The target: a thruster slot from
    /// 0, 255 the master; `None` when param1 is not a whole number 0..=255.
    Update {
        /// Which of the two.
        action: UpdateAction,
        /// param1.
        target: Option<u8>,
    },
    /// Any other command (COMMAND_LONG or COMMAND_INT): answered MAV_RESULT_UNSUPPORTED.
    Unsupported {
        /// The MAV_CMD number.
        command: u16,
    },
    /// PARAM_REQUEST_LIST.
    ParamRequestList,
    /// MISSION_REQUEST_LIST: a ground station's download of the vehicle's plan of `mission_type` (MAV_MISSION_TYPE:
    /// 0 a mission, 1 a fence, 2 rally points), which QGroundControl starts at every connect whatever the
    /// capabilities say. The master keeps none: it answers MISSION_COUNT 0 of the same type.
    MissionRequestList {
        /// MISSION_REQUEST_LIST.mission_type, echoed.
        mission_type: u8,
    },
    /// MISSION_CLEAR_ALL of `mission_type`: there is nothing to clear, and it is done (MISSION_ACK accepted).
    MissionClear {
        /// MISSION_CLEAR_ALL.mission_type, echoed.
        mission_type: u8,
    },
    /// MISSION_COUNT from a ground station: the start of an upload of `count` items of `mission_type`. The master
    /// takes none (MISSION_ACK MAV_MISSION_UNSUPPORTED), as a vehicle without missions should; an empty one is
    /// the plan it has (accepted).
    MissionUpload {
        /// MISSION_COUNT.mission_type, echoed.
        mission_type: u8,
        /// MISSION_COUNT.count.
        count: u16,
    },
    /// PARAM_REQUEST_READ by name (index -1) or index.
    ParamRequestRead {
        /// The name, when asked by name.
        id: ParamId,
        /// The index, or -1 to look up `id`.
        index: i16,
    },
    /// PARAM_SET.
    ParamSet {
        /// The name.
        id: ParamId,
        /// The new value, as the message's float carries it.
        value: f32,
        /// The MAV_PARAM_TYPE the sender says the value has.
        param_type: u8,
    },
}

/// The messages the console sends that a ground station may ask for (MAV_CMD_REQUEST_MESSAGE) or pace
/// (MAV_CMD_SET_MESSAGE_INTERVAL).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Message {
    /// HEARTBEAT (0): always 1 Hz, as the heartbeat protocol asks.
    Heartbeat,
    /// SYS_STATUS (1).
    SysStatus,
    /// BATTERY_STATUS (147).
    BatteryStatus,
    /// AUTOPILOT_VERSION (148): only on request.
    AutopilotVersion,
    /// AVAILABLE_MODES (435), one per mode the vehicle has (MANUAL alone): only on request. QGroundControl asks for
    /// it and then lists those modes in its menu rather than ArduSub's.
    AvailableModes,
    /// ESC_INFO (290), every block of four thrusters.
    EscInfo,
    /// ESC_STATUS (291), every block of four thrusters.
    EscStatus,
    /// ESC_TELEMETRY_1_TO_4 (11030).
    EscTelemetry1To4,
    /// ESC_TELEMETRY_5_TO_8 (11031), only with more than four thrusters.
    EscTelemetry5To8,
    /// NAMED_VALUE_FLOAT (251) "PilotGain": `LBV_GAIN` as a fraction, as ArduSub sends its pilot gain (which
    /// QGroundControl's ArduSub instrument panel shows).
    NamedValueFloat,
}

impl Message {
    /// Whether it is sent periodically at an interval a ground station may change.
    pub(crate) const fn paced(self) -> bool {
        !matches!(self, Self::Heartbeat | Self::AutopilotVersion | Self::AvailableModes)
    }
}

/// A MAV_CMD_SET_MESSAGE_INTERVAL interval.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Interval {
    /// 0: the message's default rate.
    Default,
    /// -1: not sent.
    Off,
    /// Every so many milliseconds (clamped to what the link carries, see [`crate::console`]).
    Every(u32),
}

/// MAVLink MAV_RESULT values the master answers with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum AckResult {
    /// MAV_RESULT_ACCEPTED (0).
    Accepted,
    /// MAV_RESULT_TEMPORARILY_REJECTED (1): e.g. a motor test while armed.
    TemporarilyRejected,
    /// MAV_RESULT_DENIED (2): e.g. a motor test of a thruster that does not exist.
    Denied,
    /// MAV_RESULT_UNSUPPORTED (3).
    Unsupported,
    /// MAV_RESULT_FAILED (4).
    Failed,
    /// MAV_RESULT_IN_PROGRESS (5): a final COMMAND_ACK follows.
    InProgress,
}

/// STATUSTEXT severities used (MAV_SEVERITY).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Severity {
    /// MAV_SEVERITY_CRITICAL (2): a thruster fault that stops it, a failsafe.
    Critical,
    /// MAV_SEVERITY_ERROR (3): a failed acceptance step, a flash whose layout refuses settings and updates.
    Error,
    /// MAV_SEVERITY_WARNING (4): a thruster went offline, stale battery data, a warning fault.
    Warning,
    /// MAV_SEVERITY_NOTICE (5).
    Notice,
    /// MAV_SEVERITY_INFO (6): arming, a thruster online, battery bit reports.
    Info,
}

/// A message for the console that is not periodic telemetry.
#[derive(Debug, Clone, PartialEq)]
pub enum Outgoing {
    /// COMMAND_ACK for a COMMAND_LONG.
    CommandAck {
        /// The MAV_CMD answered.
        command: u16,
        result: AckResult,
        /// The command's sender, whom the answer is addressed to.
        to: Sender,
    },
    /// COMMAND_ACK IN_PROGRESS with MAVLink 2's `progress`: how far a command that runs on is.
    Progress {
        /// The MAV_CMD under way.
        command: u16,
        /// 0-100.
        progress: u8,
        /// The command's sender.
        to: Sender,
    },
    /// Every PARAM_VALUE in index order, with the values in force (`Shared::settings`) as they go: the answer to
    /// PARAM_REQUEST_LIST. The console sends them one at a time as the line takes them, so the list need not fit in
    /// the outbox.
    ParamList,
    /// PARAM_VALUE.
    ParamValue {
        /// The name.
        id: ParamId,
        /// The value (an integer parameter's as its float, MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST).
        value: f32,
        param_type: ParamType,
        /// Its index in the parameter table (PARAM_VALUE.param_index).
        index: u16,
        /// How many parameters there are.
        count: u16,
    },
    /// STATUSTEXT.
    Text(Severity, Text),
    /// MISSION_COUNT: the plan of `mission_type` holds nothing.
    MissionCount {
        /// Who asked.
        to: Sender,
        /// The type asked for.
        mission_type: u8,
    },
    /// MISSION_ACK of a clear or an upload of `mission_type`.
    MissionAck {
        /// Who asked.
        to: Sender,
        /// The type asked for.
        mission_type: u8,
        /// Taken (MAV_MISSION_ACCEPTED), or not (MAV_MISSION_UNSUPPORTED).
        accepted: bool,
    },
    /// One of the periodic messages (or AUTOPILOT_VERSION), now: the answer to a MAV_CMD_REQUEST_MESSAGE, or the pilot
    /// gain on a change. ESC_INFO and ESC_STATUS go for the block of four thrusters from `first` alone.
    Message {
        /// The message.
        message: Message,
        /// The first thruster of the block, for ESC_INFO and ESC_STATUS.
        first: u8,
    },
    /// Send a periodic message at this interval from now on.
    Interval(Message, Interval),
    /// Restart the master once everything queued before this has been sent (the reboot's COMMAND_ACK).
    Reboot,
    /// FILE_TRANSFER_PROTOCOL: the update server's reply, to the request's sender.
    Ftp {
        /// Who asked (the message's target system and component).
        to: Sender,
        /// The payload's start, or for a read what its data is made from.
        reply: FtpAnswer,
    },
}

/// Link health and error counters of one thruster. Counters saturate.
///
/// The order and the status are kept apart (IDS 8.3: the order "shall be sent whenever the LBV motherboard
/// requires an update"): a thruster whose orders are acknowledged stays online and keeps its full order rate
/// whatever becomes of its status reads; a status that cannot be read costs its telemetry, counted here and told
/// on the console ([`LinkHealth::status_lost`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct LinkHealth {
    /// Taking orders: true from the first delivered order until the thruster is taken offline.
    pub online: bool,
    /// Polls in a row whose order was not delivered.
    pub consecutive_failures: u16,
    /// Polls in a row whose order was delivered but whose status could not be read.
    pub status_failures: u16,
    /// The status has not been readable for the last [`crate::thrusters::PollConfig::offline_after`] polls
    /// though the orders were delivered: the telemetry is stale.
    pub status_lost: bool,
    /// Polls attempted, retries of an offline thruster included.
    pub polls: u32,
    /// Orders delivered: the thruster acknowledged the write.
    pub delivered: u32,
    /// Polls that returned a valid status.
    pub good: u32,
    /// Of those, statuses in the implied-type form (the 6-byte SeaBotix form, [`tmc_proto::StatusForm`]).
    pub implied_form: u32,
    /// Times the thruster said its link failsafe had stopped it (SeaBotix FAULT bit 5 rising: it went 1 s
    /// without a valid order).
    pub link_failsafes: u32,
    /// Times the thruster said a sustained overcurrent had stopped it (SeaBotix FAULT bit 6 rising: its power
    /// stage's hardware break kept tripping, and its outputs are off until a zero order).
    pub overcurrents: u32,
    /// Times its status showed it not following its order ([`crate::follow`]): the echo stayed off the order
    /// without closing in.
    pub not_followed: u32,
    /// It does not follow its order now, and has not matched it since it was found not to.
    pub not_following: bool,
    /// The thruster did not acknowledge (missing or unpowered).
    pub nack: u32,
    /// A transfer timed out (SCL held low past the bus's timeout, [`crate::recovery::BusConfig::timeout`]).
    pub timeout: u32,
    /// The status's checksum did not match.
    pub bad_checksum: u32,
    /// The status's message type was not the family's.
    pub bad_type: u32,
    /// The status had the wrong length.
    pub bad_length: u32,
    /// A status field was out of range (the speed byte); the status itself still counted, faults included.
    pub bad_range: u32,
    /// Bus error, arbitration loss, overrun, or a failed mux selection.
    pub bus_error: u32,
    /// Bus recoveries run after this thruster's timeouts and bus errors.
    pub recoveries: u32,
}

/// What the master knows of one thruster, published by its bus task after every poll.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ThrusterReport {
    /// Link health and error counters.
    pub health: LinkHealth,
    /// The last valid status, if any came.
    pub status: Option<Status>,
}

/// What the master knows of the battery (published to `shared.battery`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct BatterySummary {
    /// The last pack info (0x620).
    pub info: Option<BatteryInfo>,
    /// The last DCDC status (0x629).
    pub status: Option<DcdcStatus>,
    /// The last BMS alarms (0x628).
    pub alarms: Option<BmsAlarms>,
    /// No good BAT frame for [`crate::battery::BatteryMonitor::STALE_AFTER`], or none yet: the values above are old or absent.
    pub stale: bool,
    /// No pack info frame (0x620) for [`crate::battery::BatteryMonitor::STALE_AFTER`], or none yet: `info` is old or
    /// absent, whatever the other frames do.
    pub info_stale: bool,
    /// No DCDC status frame (0x629) for that long, or none yet: `status` is old or absent.
    pub status_stale: bool,
    /// No BMS alarm frame (0x628) for that long, or none yet: `alarms` are old or absent.
    pub alarms_stale: bool,
    /// Good BAT frames received.
    pub frames: u32,
    /// Bad BAT frames (unknown BAT ID, bad length, failed check) and receive errors.
    pub errors: u32,
}

impl BatterySummary {
    /// The DCDC status while its frame is fresh; unknown once it is stale, whatever the other frames do.
    pub(crate) fn fresh_status(&self) -> Option<DcdcStatus> {
        self.status.filter(|_| !self.status_stale)
    }

    /// The BMS alarms while their frame is fresh; unknown once it is stale.
    pub(crate) fn fresh_alarms(&self) -> Option<BmsAlarms> {
        self.alarms.filter(|_| !self.alarms_stale)
    }
}

/// The vehicle's state for telemetry: published by the vehicle task.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct VehicleState {
    /// Armed: thrusters follow the pilot.
    pub armed: bool,
    /// The operator's ground-station heartbeat has been heard within `FS_GCS_TIMEOUT`.
    pub console_alive: bool,
    /// Requests refused because they came from another system than the operator's (`SYSID_MYGCS`), wrapping.
    pub refused: u32,
    /// An arm command from the operator would be accepted now ([`crate::vehicle::Vehicle::arm_check`]).
    pub armable: bool,
    /// A failsafe is in force: the ground-station failsafe has acted and its heartbeats have not returned, or the
    /// pilot-input failsafe has acted and no MANUAL_CONTROL has come since.
    pub failsafe: bool,
    /// PARAM_SETs refused because their param_type was not the parameter's, wrapping.
    pub param_type_mismatches: u32,
    /// `SYSID_MYGCS`: the operator's ground station, the only system that may change the vehicle.
    pub operator: u8,
}

#[cfg(test)]
impl VehicleState {
    /// The tests' vehicle: disarmed, armable, no failsafe, the operator (system 255, QGroundControl's and MAVProxy's)
    /// heard.
    pub(crate) const READY: Self = Self {
        armed: false,
        console_alive: true,
        refused: 0,
        armable: true,
        failsafe: false,
        param_type_mismatches: 0,
        operator: 255,
    };
}

type Mutex = CriticalSectionRawMutex;

/// What of a field update keeps the vehicle from arming ([`crate::vehicle::Vehicle::arm_check`]): a reset that is
/// coming, or may come, which a vehicle in the water must not take. Thruster slots count from 0 here; the text
/// names them as the console does, from T1.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) enum UpdateHold {
    /// The master has not read yet whether its own image is on trial (its first moments).
    MasterStarting,
    /// The master's own image is being applied: its signature checked, then the mark and the restart.
    MasterApplying,
    /// The master's image is marked for the swap: it restarts into it.
    MasterRestarting,
    /// The master's running image is on trial: it restarts if it does not confirm.
    MasterOnTrial,
    /// An update is being applied to thruster `slot`: marked, its restart, its trial.
    Applying(u8),
    /// Thruster `slot`'s image is on trial, as its last `Version` said.
    OnTrial(u8),
    /// Thruster `slot` holds an update marked for its bootloader, which its next reset swaps in.
    Marked(u8),
    /// Thruster `slot` answers again (or at the master's start) and has not said yet what it runs: it may have
    /// come up on trial.
    Unasked(u8),
}

impl core::fmt::Display for UpdateHold {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let (slot, what) = match *self {
            Self::MasterStarting => (None, "master starting"),
            Self::MasterApplying => (None, "master update being applied"),
            Self::MasterRestarting => (None, "master restarting into its update"),
            Self::MasterOnTrial => (None, "master image on trial"),
            Self::Applying(slot) => (Some(slot), "update being applied"),
            Self::OnTrial(slot) => (Some(slot), "image on trial"),
            Self::Marked(slot) => (Some(slot), "holds an update marked"),
            Self::Unasked(slot) => (Some(slot), "image not asked yet"),
        };
        if let Some(slot) = slot {
            write!(f, "T{} ", u16::from(slot) + 1)?;
        }
        f.write_str(what)
    }
}

/// The holds the field update puts on arming: the master's own update's (its task and the update sink set it) and
/// the thrusters' (the courier's users set it: the bus tasks and the sink). Each is set, synchronously, as soon as
/// what it says changes, so that an arm command read after an apply command is refused.
pub struct UpdateHolds(BlockingMutex<Mutex, Cell<[Option<UpdateHold>; 2]>>);

impl UpdateHolds {
    /// Nothing held.
    pub(crate) const fn new() -> Self {
        Self(BlockingMutex::new(Cell::new([None, None])))
    }

    /// The master's own update's hold.
    pub(crate) fn set_master(&self, hold: Option<UpdateHold>) {
        self.0.lock(|holds| {
            let [_, thrusters] = holds.get();
            holds.set([hold, thrusters]);
        });
    }

    /// The thrusters' hold.
    pub(crate) fn set_thrusters(&self, hold: Option<UpdateHold>) {
        self.0.lock(|holds| {
            let [master, _] = holds.get();
            holds.set([master, hold]);
        });
    }

    /// What holds the vehicle from arming now: the master's first.
    pub(crate) fn get(&self) -> Option<UpdateHold> {
        let [master, thrusters] = self.0.lock(Cell::get);
        master.or(thrusters)
    }
}

impl Default for UpdateHolds {
    fn default() -> Self {
        Self::new()
    }
}

impl core::fmt::Debug for UpdateHolds {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_tuple("UpdateHolds").field(&self.get()).finish()
    }
}

/// The channels between the master's tasks.
pub struct Shared {
    /// Console -> vehicle: decoded commands and their senders, in order.
    pub commands: Channel<Mutex, Request, 8>,
    /// Vehicle -> bus tasks: the order for every thruster (STOP when disarmed).
    pub orders: Watch<Mutex, [Order; MAX_THRUSTERS], 1>,
    /// Vehicle -> console: armed and console state.
    pub vehicle: Watch<Mutex, VehicleState, 1>,
    /// Bus tasks -> console, vehicle: each thruster's latest report.
    pub thrusters: [Watch<Mutex, ThrusterReport, 1>; MAX_THRUSTERS],
    /// CAN task -> console: the battery summary.
    pub battery: Watch<Mutex, BatterySummary, 1>,
    /// Everyone -> console: acknowledgements, parameter values and texts, sent in order.
    pub outbox: Channel<Mutex, Outgoing, 16>,
    /// Vehicle -> settings store, console: the parameters and the signing key in force.
    pub settings: Watch<Mutex, Settings, 1>,
    /// Console -> settings store: the signing link's next reservation, to store ([`crate::console::signing`]).
    pub signing_time: Watch<Mutex, u64, 1>,
    /// Settings store -> console: the signing reservation in flash, once written.
    pub signing_stored: Watch<Mutex, u64, 1>,
    /// Console -> settings store: the reboot's acknowledgement has been sent; restart.
    pub reboot: Signal<Mutex, ()>,
    /// The master's own update -> update server: the master's image is marked for the swap and it restarts into
    /// it; no update file changes until then ([`crate::update::own`]). Only a restart clears it.
    pub(crate) restarting: AtomicBool,
    /// The master's own update, the courier's users -> vehicle: what keeps the vehicle from arming.
    pub(crate) holds: UpdateHolds,
    /// The post-mortem region ([`crash_record`]), once the binding has handed it over ([`Shared::keep_crash`]): the
    /// record of the stop before this start, served as `@SYS/crash/master.bin`, and the ring of the events noted
    /// since ([`Shared::note`]).
    crash: BlockingMutex<CriticalSectionRawMutex, RefCell<Option<&'static mut Region>>>,
    /// The region held a record when it was handed over; it gets no other until the next start.
    crash_held: AtomicBool,
    /// Bus tasks -> update server: each slot's thruster's post-mortem record, as last fetched
    /// ([`Shared::keep_post_mortem`]), served as `@SYS/crash/thruster<slot>.bin`; kept until the master's next start.
    post_mortems: BlockingMutex<CriticalSectionRawMutex, RefCell<[Option<[u8; RECORD_LEN]>; MAX_THRUSTERS]>>,
    /// The black box's task -> update server, console: the vehicle's last minutes ([`crate::blackbox`]), once the
    /// binding hands its region over ([`crate::blackbox::Recorder::keep`]).
    pub black_box: crate::blackbox::Recorder,
    /// The slots (bits) that have a record there.
    post_mortems_held: AtomicU8,
}

impl Shared {
    /// Empty channels.
    pub const fn new() -> Self {
        Self {
            commands: Channel::new(),
            orders: Watch::new(),
            vehicle: Watch::new(),
            thrusters: [const { Watch::new() }; MAX_THRUSTERS],
            battery: Watch::new(),
            outbox: Channel::new(),
            settings: Watch::new(),
            signing_time: Watch::new(),
            signing_stored: Watch::new(),
            reboot: Signal::new(),
            restarting: AtomicBool::new(false),
            holds: UpdateHolds::new(),
            crash: BlockingMutex::new(RefCell::new(None)),
            crash_held: AtomicBool::new(false),
            post_mortems: BlockingMutex::new(RefCell::new([None; MAX_THRUSTERS])),
            post_mortems_held: AtomicU8::new(0),
            black_box: crate::blackbox::Recorder::new(),
        }
    }

    /// Keep the post-mortem region, its start done ([`Region::start`]): from now on events are noted in it.
    pub fn keep_crash(&self, region: &'static mut Region) {
        self.crash_held.store(region.read().is_some(), Ordering::Relaxed);
        self.crash.lock(|crash| *crash.borrow_mut() = Some(region));
    }

    /// Whether the region holds a record of the stop before this start.
    pub(crate) fn crash_held(&self) -> bool {
        self.crash_held.load(Ordering::Relaxed)
    }

    /// Note `what` in the ring of the last events, with the time since the start (nothing without the region).
    #[inline(never)]
    pub fn note(&self, what: What) {
        let at_ms = embassy_time::Instant::now().as_millis() as u32;
        self.with_crash(|region| region.note(Event { at_ms, what }));
    }

    /// The record of the stop before this start, if the region holds one.
    pub fn crash_record(&self) -> Option<Record> {
        self.with_crash(|region| region.read()).flatten()
    }

    /// The record's bytes, if the region holds one (for the update server's reads, which the acceptance image has
    /// none of).
    #[cfg_attr(feature = "acceptance", allow(dead_code))]
    pub(crate) fn crash_bytes(&self) -> Option<[u8; crash_record::LEN]> {
        self.with_crash(|region| region.read().map(|_| region.record)).flatten()
    }

    /// The ring's bytes (for the tests).
    #[cfg(test)]
    pub(crate) fn crash_ring(&self) -> Option<[u8; crash_record::RING_LEN]> {
        self.with_crash(|region| region.ring)
    }

    /// The record has been told.
    pub(crate) fn crash_told(&self) {
        self.with_crash(|region| region.mark_told());
    }

    /// Keep `record`, the post-mortem record fetched from slot `slot`'s thruster: the record decoded when it is new
    /// (not the one kept for that slot), `None` when it is the one kept, an error when it does not check (it is not
    /// kept: a thruster that reset between the record's parts mixes two).
    pub(crate) fn keep_post_mortem(
        &self,
        slot: u8,
        record: &[u8; RECORD_LEN],
    ) -> Result<Option<Record>, crash_record::Error> {
        let decoded = Record::decode(record)?;
        let new = self.post_mortems.lock(|kept| {
            let mut kept = kept.borrow_mut();
            let held = kept.get_mut(usize::from(slot))?;
            (held.as_ref() != Some(record)).then(|| *held = Some(*record))
        });
        if new.is_some() {
            let bit = 1u8.checked_shl(slot.into()).unwrap_or(0);
            self.post_mortems_held.fetch_or(bit, Ordering::Relaxed);
        }
        Ok(new.map(|()| decoded))
    }

    /// The slots (bits) whose thrusters' post-mortem records are kept.
    pub(crate) fn post_mortems_held(&self) -> u8 {
        self.post_mortems_held.load(Ordering::Relaxed)
    }

    /// Slot `slot`'s thruster's post-mortem record, if one is kept (for the update server's reads).
    #[cfg_attr(feature = "acceptance", allow(dead_code))]
    pub(crate) fn post_mortem(&self, slot: u8) -> Option<[u8; RECORD_LEN]> {
        self.post_mortems
            .lock(|kept| kept.borrow().get(usize::from(slot)).copied().flatten())
    }

    fn with_crash<R>(&self, f: impl FnOnce(&mut Region) -> R) -> Option<R> {
        self.crash
            .lock(|crash| crash.try_borrow_mut().ok()?.as_deref_mut().map(f))
    }

    /// Queue a text for the console; when the outbox is full the text is dropped rather than stalling a task.
    pub fn say(&self, severity: Severity, text: Text) {
        let _ = self.outbox.try_send(Outgoing::Text(severity, text));
    }
}

impl Default for Shared {
    fn default() -> Self {
        Self::new()
    }
}

impl core::fmt::Debug for Shared {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Shared").finish_non_exhaustive()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn both(texts: (Text, Option<Text>)) -> Vec<String> {
        [Some(texts.0), texts.1]
            .into_iter()
            .flatten()
            .map(|text| text.to_string())
            .collect()
    }

    #[test]
    fn a_sentence_too_long_for_one_text_goes_on_in_a_second_cut_where_it_reads() {
        // One text when it fits, to the last byte.
        let fits = "x".repeat(TEXT_LEN - "T1: ".len());
        assert_eq!(
            both(texts(format_args!("T1"), format_args!("{fits}"))),
            [format!("T1: {fits}")]
        );
        // At a colon, then at a comma, when the rest fits in the second; else at the last space that fits.
        assert_eq!(
            both(texts(
                format_args!("T1"),
                format_args!("refused by its bootloader: security counter below the vehicle's")
            )),
            [
                "T1: refused by its bootloader:",
                "T1: security counter below the vehicle's"
            ]
        );
        assert_eq!(
            both(texts(
                format_args!("thruster0.lbvu"),
                format_args!("the header says version 0.5.0, the payload is version 0.4.0")
            )),
            [
                "thruster0.lbvu: the header says version 0.5.0,",
                "thruster0.lbvu: the payload is version 0.4.0"
            ]
        );
        assert_eq!(
            both(texts(
                format_args!("T1"),
                format_args!("{} {}", "a".repeat(40), "b".repeat(60))
            )),
            [format!("T1: {}", "a".repeat(40)), format!("T1: {}", "b".repeat(46))]
        );
        // No space to cut at: cut at 50 bytes, as one text is.
        let word = "y".repeat(60);
        assert_eq!(
            both(texts(format_args!("T1"), format_args!("{word}"))),
            [format!("T1: {}", &word[..46])]
        );
    }

    #[test]
    fn a_verdict_reads_as_its_sentence_or_its_code() {
        assert_eq!(
            both(verdict_texts(format_args!("T3"), "refused by its bootloader", 1)),
            ["T3: refused by its bootloader: signature"]
        );
        assert_eq!(
            both(verdict_texts(
                format_args!("master.lbvu"),
                "refused by the bootloader",
                9
            )),
            [
                "master.lbvu: refused by the bootloader:",
                "master.lbvu: the running image names no key"
            ]
        );
        for code in [0, 15, 300] {
            assert_eq!(
                both(verdict_texts(format_args!("T1"), "refused by its bootloader", code)),
                [format!("T1: refused by its bootloader (code {code})")]
            );
        }
    }
}

// What the files read over FTP are made of (`update::sys` and `update::param_pck` render them), here because a
// read's reply carries it in [`Outgoing`].

/// What the master knows of a board's running image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum ImageState {
    /// The master has not read it: its own bootloader's state, before its update task has looked (or on a board
    /// without a bootloader).
    #[default]
    Unknown,
    /// Runs a confirmed image and holds no update marked.
    Confirmed,
    /// Runs a new image on trial: it confirms itself, or its bootloader swaps the old one back.
    OnTrial,
    /// Holds an update marked for its bootloader, which swaps it in at the restart.
    Marked,
    /// A thruster that does not answer its polls.
    Offline,
    /// A thruster that answers and has not been asked yet what it runs since it came back (or the master started).
    Unasked,
    /// A thruster that answers without the field-update extension: it takes no update.
    NoUpdates,
}

/// A board's running image, as the master knows it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Running {
    /// Its version as the image info holds it (major, minor, patch u16 LE), once heard.
    pub version: Option<[u8; 4]>,
    /// Whether it is confirmed, on trial, marked, or the board is offline or not asked yet.
    pub state: ImageState,
}

/// `versions.txt` as it stood when it was opened, packed into 49 bytes: a read's reply carries it to the console,
/// whose outbox holds it beside the other messages (64 bytes each) without growing. Board 0 is the master, board
/// `n + 1` the thruster of slot `n`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Versions {
    /// The slots (bits) that have a thruster.
    pub(crate) slots: u8,
    /// The slots (bits) whose thruster is of the Legacy family.
    pub(crate) legacy: u8,
    /// The boards (bits of a u16, little-endian) whose version the master has heard.
    pub(crate) heard: [u8; 2],
    /// Each board's version, as the image info holds it; zeros where not heard.
    pub(crate) versions: [[u8; 4]; 1 + MAX_THRUSTERS],
    /// Each board's state.
    pub(crate) states: [ImageState; 1 + MAX_THRUSTERS],
}

/// `@PARAM/param.pck` as it was opened (`update::param_pck`, which renders it). Its values are read from the
/// settings in force as each read is framed; the CRC tells whether they are still those it was opened with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ParamFile {
    /// A parameter whose value is not its default carries its default too (`?withdefaults=1`).
    pub(crate) with_defaults: bool,
    /// The build's frame: `LBV_FRAME`'s default.
    pub(crate) frame: FrameKind,
    /// Its length in bytes, little-endian.
    pub(crate) len: [u8; 2],
    /// The CRC-32 of the values it was opened with, little-endian (bytes, so that a read's reply stays the size
    /// of `versions.txt`'s).
    pub(crate) crc: [u8; 4],
}

/// What a read session reads, as it was opened.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OpenFile {
    /// `@SYS/versions.txt`.
    Versions(Versions),
    /// `@PARAM/param.pck`.
    Params(ParamFile),
    /// A post-mortem record in `@SYS/crash`: the master's, the region holds, or a thruster's, as fetched.
    Crash(crate::update::sys::CrashFile),
    /// `@SYS/blackbox.tlog`: the samples it holds.
    BlackBox(crate::blackbox::TlogFile),
}

/// The reply to a ReadFile or BurstReadFile: what its header needs, and what its data is made from as it is framed
/// (its 239 bytes do not fit beside the console's other messages, [`FtpReply`]). 58 bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FileRead {
    /// The reply's sequence number (the request's + 1), little-endian.
    pub(crate) seq: [u8; 2],
    pub(crate) session: u8,
    /// The request's opcode: ReadFile or BurstReadFile.
    pub(crate) opcode: u8,
    pub(crate) size: u8,
    /// The offset read from, little-endian: within the file.
    pub(crate) offset: [u8; 4],
    pub(crate) file: OpenFile,
}

/// The server's answer to one FTP request.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FtpAnswer {
    /// A reply that carries its data.
    Reply(FtpReply),
    /// A read of a file, whose data is made as it is framed.
    Read(FileRead),
}
// The outbox holds 16 of them: 64 bytes each on the target, a read's reply (58 bytes, its offset 4 of them) and
// its addressee. Larger, and every message queued would cost the more.
#[cfg(target_os = "none")]
const _: () = assert!(core::mem::size_of::<Outgoing>() == 64);
