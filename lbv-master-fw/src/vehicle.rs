//! The vehicle: arming, the two failsafes, the one operator, the motor test, the parameters and the signing key,
//! turned into one order per thruster.
//!
//! Rules (ArduSub's, where it has one):
//! - One operator: only the ground station whose system id is `SYSID_MYGCS` (255, a ground station's usual id)
//!   may arm, command, set parameters or the signing key, steer, and keep the failsafes from acting. Its
//!   COMMAND_LONGs from another system are answered COMMAND_ACK DENIED; its MANUAL_CONTROL, PARAM_SET and
//!   SETUP_SIGNING are ignored (MAVLink has no answer for them); all are counted in [`VehicleState::refused`].
//!   Anyone may read the parameters.
//! - Ground-station failsafe (`FS_GCS_ENABLE`, `FS_GCS_TIMEOUT`): only the operator's HEARTBEATs (type GCS) count.
//!   Armed and none for `FS_GCS_TIMEOUT` (at exactly that age) -> warn, disarm, or hold neutral sticks (warn with
//!   `LBV_GCS_NEUTRAL`), once per silence with one text; a running motor test is stopped. When the heartbeats
//!   return, a text says so and the sticks count again. Arming and motor tests need a live heartbeat.
//! - Pilot-input failsafe (`FS_PILOT_INPUT`, `FS_PILOT_TIMEOUT`): once the operator's MANUAL_CONTROL has started
//!   after arming, armed and none for `FS_PILOT_TIMEOUT` -> neutral sticks (or disarm), once, with one text; the
//!   next MANUAL_CONTROL takes over again. A ground station that never sends MANUAL_CONTROL (MAVProxy, a script
//!   that only arms) leaves the sticks neutral and does not trip it.
//! - Time is evaluated before a request is applied, so a request that arrives after a silence first lets the
//!   failsafes act.
//! - Arming (MAV_CMD_COMPONENT_ARM_DISARM): arm is accepted with a live heartbeat unless a motor test runs; then
//!   the test is stopped and the arm answered TEMPORARILY_REJECTED (arm again once the thruster has stopped).
//!   The rule is [`Vehicle::arm_check`], which also gives SYS_STATUS's pre-arm check bit
//!   ([`VehicleState::armable`]), so a ground station that waits for it can always arm.
//!   Disarm is always accepted and stops a motor test too. Arming starts from neutral sticks, and is refused while
//!   the operator's live heave stick sits more than [`HEAVE_ARM_BAND`] from its centre: the vehicle would drive at
//!   once, and a ground station that sends its centre as 0 would send it diving.
//! - No reset while diving: arm is also answered TEMPORARILY_REJECTED, with "Arm rejected: " and why, while the
//!   field update holds the vehicle ([`UpdateHold`], from `Shared::holds`): an apply runs (the master's own or a
//!   thruster's), an image is on trial (the master's, or a thruster's by its last `Version`), a thruster holds an
//!   update marked for its bootloader, the master is marked and restarting, or a thruster that came back has not
//!   said yet what it runs. Each of these ends in a reset (a swap, a revert, a restart) that a vehicle in the
//!   water must not take; the update server refuses an apply while armed ([`crate::update`]).
//! - MANUAL_CONTROL is applied only while armed (ignored while disarmed) and forgotten on disarm: the orders
//!   are the mixer's output for the last input ([`crate::mixer`]), with `LBV_GAIN`.
//! - Joystick buttons (MANUAL_CONTROL's `buttons`, armed or not): a button acts when it is pressed, once: held, it
//!   does nothing more until released and pressed again (a MANUAL_CONTROL lost meanwhile changes nothing). What
//!   it does is its `BTNn_FUNCTION` ([`ButtonFunction`]): arm (the arm command's rule and texts, without a
//!   COMMAND_ACK), disarm (as the command: a motor test stops too), `LBV_GAIN` up or down by [`GAIN_STEP`] within
//!   [`GAIN_STEP`]..=100 (a text says where it stands, and a change is kept and sent as PARAM_VALUE and
//!   "PilotGain", so that the ground station's copy follows). A disarm pressed with an arm wins.
//! - Motor test (MAV_CMD_DO_MOTOR_TEST, 209): thruster 1..=`thrusters` (else DENIED), only while disarmed with a
//!   live heartbeat (else TEMPORARILY_REJECTED). The percentage is clamped to +-`LBV_MTEST_MAX`; the test runs for
//!   its duration (at most 10 s) and stops at exactly its end. One thruster at a time: a new test replaces the
//!   running one; a test of 0 % or of zero duration stops it.
//! - Reboot (MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, param1 = 1): only while disarmed (else TEMPORARILY_REJECTED);
//!   ACCEPTED, then [`Outgoing::Reboot`]: the master restarts once the acknowledgement is out.
//! - Orders: disarmed, every order is [`Order::STOP`] except the motor test's thruster. Orders that drive
//!   (armed, or the motor test) carry INFO = `LBV_POWER_CAP`. Slots beyond `thrusters` are always STOP.
//! - Thruster reports do not change the orders: a thruster that is offline or has stopped on a fault still
//!   gets its order (the thruster decides), and the others keep working. Faults are reported elsewhere.
//! - Parameters ([`crate::params`]): PARAM_REQUEST_LIST answers every PARAM_VALUE in index order
//!   ([`Outgoing::ParamList`]);
//!   PARAM_REQUEST_READ the one asked (by index, or by name when the index is -1; unknown -> no answer);
//!   PARAM_SET of a known name applies a valid value and answers PARAM_VALUE; an invalid one (out of range, not
//!   a number, a fraction for an integer parameter, `LBV_FRAME` or `SYSID_MYGCS` while armed) is rejected with a
//!   Warning text and a PARAM_VALUE of the unchanged value, as ArduPilot does. A PARAM_SET whose param_type is
//!   neither the parameter's ([`Param::param_type`]) nor REAL32 ([`Param::takes_type`]: what MAVProxy sends) is
//!   answered the same way and counted ([`VehicleState::param_type_mismatches`]): its value may be encoded
//!   otherwise. An unknown name gets no answer. A change of `LBV_GAIN` also sends "PilotGain" at once.
//! - MAV_CMD_REQUEST_MESSAGE / MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES (anyone may ask: it reads): ACCEPTED, then
//!   [`Outgoing::Message`]; a message the master does not send (HOME_POSITION: there is no home) DENIED, which
//!   MAV_RESULT defines as "supported but has invalid parameters" (the command is supported, its message id is
//!   not one the master has; UNSUPPORTED would tell a ground station the command itself is unknown).
//! - MAV_CMD_SET_MESSAGE_INTERVAL (the operator only): a paced message ([`crate::shared::Message::paced`]) with a
//!   valid interval is ACCEPTED, then [`Outgoing::Interval`]; HEARTBEAT (kept at 1 Hz), AUTOPILOT_VERSION, a
//!   message the master does not send or an invalid interval: DENIED. What is set is kept across power cycles
//!   ([`crate::settings`]).
//! - SETUP_SIGNING (only while disarmed): sets the signing key, or turns signing off with an all-zero key.
//! - Any other COMMAND_LONG: COMMAND_ACK UNSUPPORTED.
//! - Answer order: texts of what time did before the request (failsafe, end of a motor test), then the
//!   COMMAND_ACK, then the request's own texts.

use core::fmt;

use crash_record::What;
use embassy_futures::select::{Either, select};
use embassy_time::{Duration, Instant, Ticker, with_deadline};
use tmc_proto::{Order, Speed};

use crate::console::signing::SigningKey;
use crate::mixer::{FrameKind, ManualInput, mix, round_div};
use crate::params::{
    BUTTONS, ButtonFunction, GAIN_STEP, GcsFailsafe, LISTED_COUNT, Listed, Param, PilotFailsafe, Settings,
};
use crate::shared::{
    ARDUSUB_MODE_MANUAL, AckResult, Command, MAV_CMD_COMPONENT_ARM_DISARM, MAV_CMD_DO_MOTOR_TEST, MAV_CMD_DO_SET_MODE,
    MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, MAV_CMD_SET_MESSAGE_INTERVAL, MAX_THRUSTERS, Message, Outgoing, Request, Sender,
    Severity, Shared, UpdateHold, VehicleState, text,
};

/// Why a mode other than MANUAL is denied: ArduSub's other modes hold a depth, a heading or a position, and the
/// master has no sensor for any of them.
pub(crate) const MANUAL_ONLY: &str = "Mode: MANUAL only, no depth or heading sensor";

/// Longest motor test.
pub(crate) const MOTOR_TEST_MAX_DURATION: Duration = Duration::from_secs(10);

/// Sticks at rest: no motion (z = 500 is neutral heave).
pub const NEUTRAL: ManualInput = ManualInput {
    x: 0,
    y: 0,
    z: 500,
    r: 0,
};

/// The vehicle's build-time configuration: the frame and how many thrusters this master drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct VehicleConfig {
    /// Thruster layout (the default `LBV_FRAME`).
    pub(crate) frame: FrameKind,
    /// Thrusters wired to this master, numbered 1..=thrusters (at most [`MAX_THRUSTERS`]); orders beyond are
    /// STOP and motor tests beyond are DENIED.
    pub(crate) thrusters: u8,
}

impl VehicleConfig {
    /// The LBV300-6, all six thrusters wired.
    pub const DEFAULT: VehicleConfig = VehicleConfig::new(FrameKind::Lbv300_6);

    /// A frame with all its thrusters wired.
    pub(crate) const fn new(frame: FrameKind) -> Self {
        Self {
            frame,
            thrusters: frame.thrusters() as u8,
        }
    }

    /// The settings of a master that has none stored: default parameters for this frame, signing off.
    pub fn defaults(&self) -> Settings {
        Settings::defaults(self.frame)
    }
}

impl Default for VehicleConfig {
    /// [`VehicleConfig::DEFAULT`].
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// A running motor test.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
struct MotorTest {
    /// Thruster number, 1-based.
    motor: u8,
    speed: Speed,
    until: Instant,
}

/// Why an arm command would be refused now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) enum ArmRefusal {
    /// A motor test runs (arming stops it).
    MotorTest,
    /// The operator's heartbeat has not been heard within `FS_GCS_TIMEOUT`.
    NoHeartbeat,
    /// The field update holds the vehicle: a reset is coming, or may come.
    Update(UpdateHold),
    /// The operator's heave stick is away from its centre (500): arming would drive at once. This is also how a
    /// ground station that sends the centre as 0 shows (QGroundControl's "centre-zero throttle" or "negative
    /// thrust" for ArduSub), which this vehicle reads as full descent.
    Heave(i16),
}

impl fmt::Display for ArmRefusal {
    /// Why, as "Arm rejected: " goes on.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::MotorTest => f.write_str("motor test was running"),
            Self::NoHeartbeat => f.write_str("no ground station heartbeat"),
            Self::Update(hold) => write!(f, "{hold}"),
            Self::Heave(z) => write!(f, "heave stick at {z}, not 500"),
        }
    }
}

/// How far the heave stick may sit from its centre (500 of 0..=1000) for an arm: a joystick at rest reads within a
/// few counts of it; a ground station that sends its centre as 0 is 500 away.
pub(crate) const HEAVE_ARM_BAND: i16 = 100;

/// Arming, failsafes, operator, motor test, settings -> orders. Pure state machine with explicit time.
#[derive(Debug, Clone)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Vehicle {
    thrusters: u8,
    settings: Settings,
    armed: bool,
    /// When the operator's last heartbeat came.
    heartbeat: Option<Instant>,
    /// The ground-station failsafe has acted for the present silence.
    gcs_lost: bool,
    /// When the operator's last MANUAL_CONTROL came, since arming and since the pilot-input failsafe last acted.
    pilot_input: Option<Instant>,
    input: ManualInput,
    motor_test: Option<MotorTest>,
    refused: u32,
    /// The pilot-input failsafe has acted and no MANUAL_CONTROL has come since.
    pilot_lost: bool,
    param_type_mismatches: u32,
    /// What of the field update keeps the vehicle from arming, as last told ([`Vehicle::hold_for_update`]).
    update_hold: Option<UpdateHold>,
    /// The operator's last MANUAL_CONTROL, armed or not, and when it came: where the sticks stand for an arm.
    sticks: Option<(Instant, ManualInput)>,
    /// The joystick buttons held in the operator's last MANUAL_CONTROL: a button acts when it is pressed.
    buttons: u16,
}

impl Vehicle {
    /// Disarmed, no ground station heard yet, with `settings` (clamped to what `config` wires).
    pub fn new(config: VehicleConfig, settings: Settings) -> Self {
        Self {
            thrusters: config.thrusters.min(MAX_THRUSTERS as u8),
            settings,
            armed: false,
            heartbeat: None,
            gcs_lost: false,
            pilot_input: None,
            input: NEUTRAL,
            motor_test: None,
            refused: 0,
            pilot_lost: false,
            param_type_mismatches: 0,
            update_hold: None,
            sticks: None,
            buttons: 0,
        }
    }

    /// What of the field update keeps the vehicle from arming now (`Shared::holds`); an armed vehicle stays armed.
    pub(crate) fn hold_for_update(&mut self, hold: Option<UpdateHold>) {
        self.update_hold = hold;
    }

    /// The settings in force.
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// Apply one console request at `now`; `out` receives the answers (COMMAND_ACK, PARAM_VALUEs, texts).
    pub fn on_request(&mut self, now: Instant, request: Request, out: &mut impl FnMut(Outgoing)) {
        self.update(now, out);
        let Request { from, command } = request;
        let operator = from.system == self.settings.params.operator();
        match command {
            Command::ParamRequestList => out(Outgoing::ParamList),
            Command::MissionRequestList { mission_type } => out(Outgoing::MissionCount { to: from, mission_type }),
            Command::MissionClear { mission_type } => out(Outgoing::MissionAck {
                to: from,
                mission_type,
                accepted: true,
            }),
            Command::MissionUpload { mission_type, count } => out(Outgoing::MissionAck {
                to: from,
                mission_type,
                accepted: count == 0,
            }),
            Command::ParamRequestRead { id, index } => {
                let listed = match u16::try_from(index) {
                    Ok(index) => Listed::from_index(index),
                    Err(_) => Listed::from_id(&id),
                };
                if let Some(listed) = listed {
                    self.param_value(listed, out);
                }
            }
            Command::RequestMessage {
                command,
                message,
                first,
            } => match message {
                Some(message) => {
                    ack(out, command, AckResult::Accepted, from);
                    out(Outgoing::Message { message, first });
                }
                None => ack(out, command, AckResult::Denied, from),
            },
            // Another ground station's heartbeat is no sign of the pilot.
            Command::Heartbeat if !operator => {}
            Command::Heartbeat => {
                self.heartbeat = Some(now);
                if core::mem::take(&mut self.gcs_lost) {
                    say(out, Severity::Info, format_args!("Ground station back"));
                }
            }
            _ if !operator => {
                self.refused = self.refused.wrapping_add(1);
                if let Some(command) = command_long(&command) {
                    ack(out, command, AckResult::Denied, from);
                }
            }
            Command::Manual(input, buttons) => {
                self.sticks = Some((now, input));
                let held = self.gcs_lost && self.settings.params.gcs_failsafe() == GcsFailsafe::Neutral;
                if self.armed && !held {
                    self.input = input;
                    self.pilot_input = Some(now);
                    self.pilot_lost = false;
                }
                self.buttons(now, buttons, out);
            }
            Command::MessageInterval { message, interval } => match (message, interval) {
                (Some(message), Some(interval)) if message.paced() => {
                    ack(out, MAV_CMD_SET_MESSAGE_INTERVAL, AckResult::Accepted, from);
                    out(Outgoing::Interval(message, interval));
                }
                _ => ack(out, MAV_CMD_SET_MESSAGE_INTERVAL, AckResult::Denied, from),
            },
            Command::Arm(true) => self.arm(now, Some(from), out),
            Command::Arm(false) => {
                ack(out, MAV_CMD_COMPONENT_ARM_DISARM, AckResult::Accepted, from);
                self.stop(out);
            }
            Command::MotorTest {
                motor,
                percent,
                duration,
            } => self.motor_test(now, from, motor, percent, duration, out),
            Command::Reboot => {
                if self.armed {
                    ack(
                        out,
                        MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN,
                        AckResult::TemporarilyRejected,
                        from,
                    );
                    say(out, Severity::Warning, format_args!("Reboot rejected: disarm first"));
                } else {
                    self.stop_motor_test(out);
                    ack(out, MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, AckResult::Accepted, from);
                    say(out, Severity::Info, format_args!("Rebooting"));
                    out(Outgoing::Reboot);
                }
            }
            Command::Unsupported { command } => ack(out, command, AckResult::Unsupported, from),
            // The one mode there is, taken as it stands; any other denied with why (QGroundControl's mode menu
            // shows the text).
            Command::SetMode { custom_mode } => {
                if custom_mode == Some(ARDUSUB_MODE_MANUAL) {
                    ack(out, MAV_CMD_DO_SET_MODE, AckResult::Accepted, from);
                } else {
                    ack(out, MAV_CMD_DO_SET_MODE, AckResult::Denied, from);
                    say(out, Severity::Warning, format_args!("{MANUAL_ONLY}"));
                }
            }
            // Only an image without the update server sends it here (the console hands it to the update task).
            Command::Update { action, .. } => ack(out, action.command(), AckResult::Unsupported, from),
            Command::ParamSet { id, value, param_type } => match Listed::from_id(&id) {
                Some(stand_in @ Listed::StandIn { .. }) => {
                    say(out, Severity::Warning, format_args!("{}: read-only", stand_in.name()));
                    self.param_value(stand_in, out);
                }
                Some(Listed::Setting(param)) if !param.takes_type(param_type) => {
                    self.param_type_mismatches = self.param_type_mismatches.wrapping_add(1);
                    say(
                        out,
                        Severity::Warning,
                        format_args!("{}: wrong param_type", param.name()),
                    );
                    self.param_value(Listed::Setting(param), out);
                }
                Some(Listed::Setting(param)) => self.param_set(param, value, out),
                None => {}
            },
            Command::SetupSigning { key, timestamp } => self.setup_signing(key, timestamp, out),
        }
    }

    /// The orders for every thruster at `now` (applying the failsafes and the end of a motor test first).
    pub fn orders(&mut self, now: Instant, out: &mut impl FnMut(Outgoing)) -> [Order; MAX_THRUSTERS] {
        self.update(now, out);
        let params = &self.settings.params;
        let info = params.power_cap_percent();
        let mut orders = [Order::STOP; MAX_THRUSTERS];
        let wired = usize::from(self.thrusters);
        if self.armed {
            let speeds: [Speed; MAX_THRUSTERS] = mix(params.frame(), self.input, params.gain_percent());
            for (order, speed) in orders.iter_mut().zip(speeds).take(wired) {
                *order = Order { speed, info };
            }
        } else if let Some(test) = self.motor_test
            && let Some(order) = orders.get_mut(usize::from(test.motor.saturating_sub(1)))
        {
            *order = Order {
                speed: test.speed,
                info,
            };
        }
        orders
    }

    /// The state for telemetry at `now`.
    pub fn state(&self, now: Instant) -> VehicleState {
        VehicleState {
            armed: self.armed,
            console_alive: self.heartbeat_live(now),
            refused: self.refused,
            armable: self.arm_check(now).is_ok(),
            failsafe: self.gcs_lost || self.pilot_lost,
            param_type_mismatches: self.param_type_mismatches,
            operator: self.settings.params.operator(),
        }
    }

    /// Whether the operator's arm command would be accepted at `now`: the one rule for arming and for the
    /// pre-arm check that SYS_STATUS reports. (Evaluated after [`Vehicle::orders`] at the same `now`, so the
    /// failsafes and the end of a motor test have already acted.)
    pub(crate) fn arm_check(&self, now: Instant) -> Result<(), ArmRefusal> {
        if self.motor_test.is_some() {
            Err(ArmRefusal::MotorTest)
        } else if !self.heartbeat_live(now) {
            Err(ArmRefusal::NoHeartbeat)
        } else if let Some(hold) = self.update_hold {
            Err(ArmRefusal::Update(hold))
        } else if let Some(z) = self.heave_off_centre(now) {
            Err(ArmRefusal::Heave(z))
        } else {
            Ok(())
        }
    }

    /// The heave stick's position when the operator's last MANUAL_CONTROL, within `FS_PILOT_TIMEOUT`, puts it more
    /// than [`HEAVE_ARM_BAND`] from its centre; `None` when it is centred, or when no stick input is live (a ground
    /// station without a joystick arms with the sticks neutral).
    fn heave_off_centre(&self, now: Instant) -> Option<i16> {
        let (at, input) = self.sticks?;
        let live = now.saturating_duration_since(at) < self.settings.params.pilot_timeout();
        (live && (input.z - NEUTRAL.z).abs() > HEAVE_ARM_BAND).then_some(input.z)
    }

    fn heartbeat_live(&self, now: Instant) -> bool {
        self.heartbeat
            .is_some_and(|at| now.saturating_duration_since(at) < self.settings.params.gcs_timeout())
    }

    /// What the passing of time does: the failsafes, the end of a motor test.
    fn update(&mut self, now: Instant, out: &mut impl FnMut(Outgoing)) {
        let params = self.settings.params;
        if !self.heartbeat_live(now) {
            if let Some(test) = self.motor_test.take() {
                say(
                    out,
                    Severity::Warning,
                    format_args!("Motor test {} stopped: ground station lost", test.motor),
                );
            }
            if self.armed && !self.gcs_lost {
                self.gcs_lost = true;
                match params.gcs_failsafe() {
                    GcsFailsafe::Warn => say(out, Severity::Warning, format_args!("Failsafe: ground station lost")),
                    GcsFailsafe::Neutral => {
                        self.input = NEUTRAL;
                        self.pilot_input = None;
                        say(
                            out,
                            Severity::Critical,
                            format_args!("Failsafe: ground station lost, neutral"),
                        );
                    }
                    GcsFailsafe::Disarm => {
                        self.disarm();
                        say(
                            out,
                            Severity::Critical,
                            format_args!("Failsafe: ground station lost, disarmed"),
                        );
                    }
                }
            }
        }
        let pilot_silent = self
            .pilot_input
            .is_some_and(|at| now.saturating_duration_since(at) >= params.pilot_timeout());
        if self.armed && pilot_silent {
            self.pilot_input = None;
            self.pilot_lost = params.pilot_failsafe() != PilotFailsafe::Off;
            match params.pilot_failsafe() {
                PilotFailsafe::Off => {}
                PilotFailsafe::Neutral => {
                    self.input = NEUTRAL;
                    say(
                        out,
                        Severity::Warning,
                        format_args!("Failsafe: pilot input lost, neutral"),
                    );
                }
                PilotFailsafe::Disarm => {
                    self.disarm();
                    say(
                        out,
                        Severity::Critical,
                        format_args!("Failsafe: pilot input lost, disarmed"),
                    );
                }
            }
        }
        if let Some(test) = self.motor_test
            && now >= test.until
        {
            self.motor_test = None;
            say(out, Severity::Info, format_args!("Motor test {} done", test.motor));
        }
    }

    /// Arm for the operator's arm command (`from`, answered with a COMMAND_ACK) or an arm button (`None`): one
    /// rule ([`Vehicle::arm_check`]) and the same texts for both.
    fn arm(&mut self, now: Instant, from: Option<Sender>, out: &mut impl FnMut(Outgoing)) {
        let check = self.arm_check(now);
        if let Some(from) = from {
            let result = match check {
                Ok(()) => AckResult::Accepted,
                Err(_) => AckResult::TemporarilyRejected,
            };
            ack(out, MAV_CMD_COMPONENT_ARM_DISARM, result, from);
        }
        if let Err(refusal) = check {
            if refusal == ArmRefusal::MotorTest {
                self.stop_motor_test(out);
            }
            say(out, Severity::Warning, format_args!("Arm rejected: {refusal}"));
            return;
        }
        if !self.armed {
            self.armed = true;
            self.input = NEUTRAL;
            self.pilot_input = None;
            self.pilot_lost = false;
            self.gcs_lost = false;
            say(out, Severity::Info, format_args!("Armed"));
        }
    }

    fn disarm(&mut self) {
        self.armed = false;
        self.input = NEUTRAL;
        self.pilot_input = None;
        self.pilot_lost = false;
    }

    /// The operator's disarm, by command or button: a motor test stops too.
    fn stop(&mut self, out: &mut impl FnMut(Outgoing)) {
        self.stop_motor_test(out);
        if self.armed {
            self.disarm();
            say(out, Severity::Info, format_args!("Disarmed"));
        }
    }

    /// The operator's joystick buttons held now: each one pressed since the last MANUAL_CONTROL does its function
    /// once, the gain steps in button order, then a disarm, or else an arm (a disarm pressed with an arm wins).
    fn buttons(&mut self, now: Instant, held: u16, out: &mut impl FnMut(Outgoing)) {
        let pressed = held & !self.buttons;
        self.buttons = held;
        let (mut arm, mut disarm) = (false, false);
        for n in (0..BUTTONS).filter(|n| pressed & 1 << n != 0) {
            match self.settings.params.button(n) {
                Some(ButtonFunction::Arm) => arm = true,
                Some(ButtonFunction::Disarm) => disarm = true,
                Some(ButtonFunction::GainUp) => self.step_gain(true, out),
                Some(ButtonFunction::GainDown) => self.step_gain(false, out),
                None => {}
            }
        }
        if disarm {
            self.stop(out);
        } else if arm {
            self.arm(now, None, out);
        }
    }

    /// `LBV_GAIN` one [`GAIN_STEP`] up or down, within `GAIN_STEP..=100` (never against the press: a gain set
    /// below the step stays where it is on a down), kept like a PARAM_SET and told.
    fn step_gain(&mut self, up: bool, out: &mut impl FnMut(Outgoing)) {
        let gain = self.settings.params.gain_percent();
        let stepped = if up {
            gain.saturating_add(GAIN_STEP).min(100).max(gain)
        } else {
            gain.saturating_sub(GAIN_STEP).max(GAIN_STEP).min(gain)
        };
        if stepped != gain && self.settings.params.set(Param::Gain, i32::from(stepped)) {
            self.param_value(Listed::Setting(Param::Gain), out);
            out(PILOT_GAIN);
        }
        say(out, Severity::Info, format_args!("Pilot gain {stepped} %"));
    }

    fn stop_motor_test(&mut self, out: &mut impl FnMut(Outgoing)) {
        if let Some(test) = self.motor_test.take() {
            say(out, Severity::Info, format_args!("Motor test {} stopped", test.motor));
        }
    }

    fn motor_test(
        &mut self,
        now: Instant,
        from: Sender,
        motor: u8,
        percent: i8,
        duration: Duration,
        out: &mut impl FnMut(Outgoing),
    ) {
        if motor == 0 || motor > self.thrusters {
            ack(out, MAV_CMD_DO_MOTOR_TEST, AckResult::Denied, from);
            return;
        }
        if self.armed || !self.heartbeat_live(now) {
            ack(out, MAV_CMD_DO_MOTOR_TEST, AckResult::TemporarilyRejected, from);
            return;
        }
        ack(out, MAV_CMD_DO_MOTOR_TEST, AckResult::Accepted, from);
        if percent == 0 || duration == Duration::from_ticks(0) {
            self.stop_motor_test(out);
            return;
        }
        let max = i32::from(self.settings.params.motor_test_max_percent());
        let percent = i32::from(percent).clamp(-max, max);
        let duration = duration.min(MOTOR_TEST_MAX_DURATION);
        self.motor_test = Some(MotorTest {
            motor,
            speed: Speed::new_saturating(round_div(percent * i32::from(Speed::MAX_STEP), 100)),
            until: now.saturating_add(duration),
        });
        // At most MOTOR_TEST_MAX_DURATION: the milliseconds fit a u32 (whose formatting the image has already).
        let ms = u32::try_from(duration.as_millis()).unwrap_or(u32::MAX);
        say(
            out,
            Severity::Info,
            format_args!("Motor test {motor}: {percent} % for {ms} ms"),
        );
    }

    fn param_value(&self, listed: Listed, out: &mut impl FnMut(Outgoing)) {
        out(Outgoing::ParamValue {
            id: listed.id(),
            value: listed.to_float(listed.value(&self.settings.params)),
            param_type: listed.param_type(),
            index: listed.index(),
            count: LISTED_COUNT as u16,
        });
    }

    fn param_set(&mut self, param: Param, value: f32, out: &mut impl FnMut(Outgoing)) {
        let (min, max) = param.range();
        let (min, max) = (param.shown(min), param.shown(max));
        let name = param.name();
        let mut set = false;
        match param.from_float(value) {
            Some(_) if param.only_disarmed() && self.armed => {
                say(out, Severity::Warning, format_args!("{name}: disarm first"));
            }
            Some(value) if self.settings.params.set(param, value) => set = true,
            _ if param == Param::Frame => say(out, Severity::Warning, format_args!("{name}: must be {min} or {max}")),
            _ if param.is_button() => say(
                out,
                Severity::Warning,
                format_args!("{name}: must be 0, 3, 4, 42 or 43"),
            ),
            _ => say(out, Severity::Warning, format_args!("{name}: range {min}..{max}")),
        }
        self.param_value(Listed::Setting(param), out);
        if set && param == Param::Gain {
            out(PILOT_GAIN);
        }
    }

    fn setup_signing(&mut self, secret: [u8; 32], timestamp: u64, out: &mut impl FnMut(Outgoing)) {
        if self.armed {
            say(out, Severity::Warning, format_args!("Signing: disarm first"));
            return;
        }
        if secret == [0; 32] {
            self.settings.signing = None;
            say(out, Severity::Info, format_args!("Signing off"));
        } else {
            self.settings.signing = Some(SigningKey { secret, timestamp });
            say(out, Severity::Info, format_args!("Signing on"));
        }
    }
}

/// The MAV_CMD of a request that came as a COMMAND_LONG (and so is answered with a COMMAND_ACK).
fn command_long(command: &Command) -> Option<u16> {
    match command {
        Command::Arm(_) => Some(MAV_CMD_COMPONENT_ARM_DISARM),
        Command::MotorTest { .. } => Some(MAV_CMD_DO_MOTOR_TEST),
        Command::Reboot => Some(MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN),
        Command::SetMode { .. } => Some(MAV_CMD_DO_SET_MODE),
        Command::Unsupported { command } | Command::RequestMessage { command, .. } => Some(*command),
        Command::MessageInterval { .. } => Some(MAV_CMD_SET_MESSAGE_INTERVAL),
        Command::Update { action, .. } => Some(action.command()),
        Command::Heartbeat
        | Command::Manual(..)
        | Command::ParamRequestList
        | Command::MissionRequestList { .. }
        | Command::MissionClear { .. }
        | Command::MissionUpload { .. }
        | Command::ParamRequestRead { .. }
        | Command::ParamSet { .. }
        | Command::SetupSigning { .. } => None,
    }
}

/// The pilot gain's NAMED_VALUE_FLOAT, sent at once on a change.
const PILOT_GAIN: Outgoing = Outgoing::Message {
    message: Message::NamedValueFloat,
    first: 0,
};

fn ack(out: &mut impl FnMut(Outgoing), command: u16, result: AckResult, to: Sender) {
    out(Outgoing::CommandAck { command, result, to });
}

fn say(out: &mut impl FnMut(Outgoing), severity: Severity, args: fmt::Arguments<'_>) {
    out(Outgoing::Text(severity, text(args)));
}

/// The vehicle task's period: 50 Hz.
pub(crate) const TICK: Duration = Duration::from_millis(20);

/// Most answers one request and one evaluation can give: a failsafe's texts, then a request's (an arm refused
/// while a motor test runs: its COMMAND_ACK and two texts; a gain button: a PARAM_VALUE, "PilotGain" and a text),
/// with room for a few buttons pressed at once. A reply beyond them is dropped.
const MAX_REPLIES: usize = 16;

/// Receive requests (`shared.commands`) and evaluate at 50 Hz; publish the orders (`shared.orders`), the state
/// (`shared.vehicle`) and, when they change, the settings (`shared.settings`) after every request and every
/// tick; queue the answers in `shared.outbox`, waiting at most one tick for room (a console that does not drain
/// it must not stall the failsafes). `settings` are those stored (or the defaults).
pub async fn vehicle_task(config: VehicleConfig, settings: Settings, shared: &Shared) -> ! {
    let mut vehicle = Vehicle::new(config, settings);
    let orders = shared.orders.sender();
    let state = shared.vehicle.sender();
    let published = shared.settings.sender();
    let mut settings = *vehicle.settings();
    published.send(settings);
    let mut ticker = Ticker::every(TICK);
    // What the post-mortem ring was last told: armed, and the operator's heartbeats lost.
    let mut noted = (false, false);
    loop {
        let request = match select(shared.commands.receive(), ticker.next()).await {
            Either::First(request) => Some(request),
            Either::Second(()) => None,
        };
        let now = Instant::now();
        vehicle.hold_for_update(shared.holds.get());
        let mut replies = heapless::Vec::<Outgoing, MAX_REPLIES>::new();
        let mut push = |reply| {
            // Bounded by construction (MAX_REPLIES); a reply beyond it would be dropped, not panic.
            let _ = replies.push(reply);
        };
        if let Some(request) = request {
            vehicle.on_request(now, request, &mut push);
        }
        orders.send(vehicle.orders(now, &mut push));
        let published_state = vehicle.state(now);
        let now_noted = (published_state.armed, vehicle.gcs_lost);
        if now_noted.0 != noted.0 {
            shared.note(if now_noted.0 { What::Armed } else { What::Disarmed(0) });
        }
        if now_noted.1 != noted.1 {
            shared.note(if now_noted.1 {
                What::OperatorLost
            } else {
                What::OperatorBack
            });
        }
        noted = now_noted;
        state.send(published_state);
        if *vehicle.settings() != settings {
            settings = *vehicle.settings();
            published.send(settings);
        }
        let deadline = now.saturating_add(TICK);
        for reply in replies {
            if with_deadline(deadline, shared.outbox.send(reply)).await.is_err() {
                break;
            }
        }
    }
}

#[cfg(test)]
mod tests;
