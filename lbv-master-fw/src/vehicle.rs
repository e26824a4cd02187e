//! The vehicle: arming, the console failsafe, the motor test and the parameters, turned into one order per
//! thruster.
//!
//! Rules (ArduSub-like):
//! - Console life: every [`Command`] counts, whatever it is. The console is alive while the last one is less
//!   than `LBV_CONSOLE_TO` old. Time is evaluated before a command is applied, so a command that arrives after
//!   a silence first lets the failsafe act.
//! - Failsafe: armed and the console silent for `LBV_CONSOLE_TO` (at exactly that age) -> disarm, every order
//!   STOP, one Critical text. It acts once: arming again needs a command, which brings the console back. A
//!   running motor test is stopped as well.
//! - Arming (MAV_CMD_COMPONENT_ARM_DISARM): arm is accepted unless a motor test runs; then the test is stopped
//!   and the arm answered TEMPORARILY_REJECTED (arm again once the thruster has stopped). Disarm is always
//!   accepted and stops a motor test too. An arm command is itself console life, so the console is never
//!   silent when one is applied. Arming starts from neutral sticks.
//! - MANUAL_CONTROL is applied only while armed (ignored while disarmed) and forgotten on disarm: the orders
//!   are the mixer's output for the last input ([`crate::mixer`]), with `LBV_GAIN`.
//! - Motor test (MAV_CMD_DO_MOTOR_TEST, 209): thruster 1..=`thrusters` (else DENIED), only while disarmed
//!   (else TEMPORARILY_REJECTED). The percentage is clamped to +-`LBV_MTEST_MAX`; the test runs for its duration
//!   (at most 10 s) and stops at exactly its end. One thruster at a time: a new test replaces the running one;
//!   a test of 0 % or of zero duration stops it.
//! - Orders: disarmed, every order is [`Order::STOP`] except the motor test's thruster. Orders that drive
//!   (armed, or the motor test) carry INFO = `LBV_POWER_CAP`. Slots beyond `thrusters` are always STOP.
//! - Thruster reports do not change the orders: a thruster that is offline or has stopped on a fault still
//!   gets its order (the thruster decides), and the others keep working. Faults are reported elsewhere.
//! - Parameters: see [`Param`]. PARAM_REQUEST_LIST answers every PARAM_VALUE in index order;
//!   PARAM_REQUEST_READ the one asked (by index, or by name when the index is -1; unknown -> no answer);
//!   PARAM_SET of a known name applies a valid value and answers PARAM_VALUE; an invalid one (out of range, not
//!   a number, `LBV_FRAME` while armed) is rejected with a Warning text and a PARAM_VALUE of the unchanged
//!   value, as ArduPilot does. An unknown name gets no answer.
//! - Any other COMMAND_LONG: COMMAND_ACK UNSUPPORTED.
//! - Answer order: texts of what time did before the command (failsafe, end of a motor test), then the
//!   COMMAND_ACK, then the command's own texts.

use core::fmt;

use embassy_futures::select::{Either, select};
use embassy_time::{Duration, Instant, Ticker, with_deadline};
use tmc_proto::{Order, Speed};

use crate::mixer::{FrameKind, mix, round_div};
use crate::shared::{
    AckResult, Command, MAX_THRUSTERS, ManualInput, Outgoing, ParamId, Severity, Shared, VehicleState, text,
};

/// MAV_CMD_COMPONENT_ARM_DISARM.
pub const MAV_CMD_COMPONENT_ARM_DISARM: u16 = 400;
/// MAV_CMD_DO_MOTOR_TEST.
pub const MAV_CMD_DO_MOTOR_TEST: u16 = 209;
/// Longest motor test.
pub const MOTOR_TEST_MAX_DURATION: Duration = Duration::from_secs(10);

/// Sticks at rest: no motion (z = 500 is neutral heave).
pub const NEUTRAL: ManualInput = ManualInput {
    x: 0,
    y: 0,
    z: 500,
    r: 0,
};

/// The MAVLink parameters, in index order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Param {
    /// `LBV_CONSOLE_TO`: console timeout in ms, 100..=10000 (default 1000).
    ConsoleTimeout,
    /// `LBV_GAIN`: pilot gain in %, 1..=100 (default 50, ArduSub's JS_GAIN_DEFAULT).
    Gain,
    /// `LBV_POWER_CAP`: the orders' INFO byte, output power cap in %, 1..=100 (default 100: no cap).
    PowerCap,
    /// `LBV_FRAME`: 4 (LBV200-4) or 6 (LBV300-6); changed only while disarmed.
    Frame,
    /// `LBV_MTEST_MAX`: largest motor test throttle in %, 1..=100 (default 30: thrusters tested in air).
    MotorTestMax,
}

/// How many parameters there are.
pub const PARAM_COUNT: usize = 5;

impl Param {
    /// Every parameter, in index order.
    pub const ALL: [Param; PARAM_COUNT] = [
        Self::ConsoleTimeout,
        Self::Gain,
        Self::PowerCap,
        Self::Frame,
        Self::MotorTestMax,
    ];

    /// The MAVLink name (at most 16 characters).
    pub const fn name(self) -> &'static str {
        match self {
            Self::ConsoleTimeout => "LBV_CONSOLE_TO",
            Self::Gain => "LBV_GAIN",
            Self::PowerCap => "LBV_POWER_CAP",
            Self::Frame => "LBV_FRAME",
            Self::MotorTestMax => "LBV_MTEST_MAX",
        }
    }

    /// Smallest and largest value (`LBV_FRAME` takes only the two ends).
    pub const fn range(self) -> (i32, i32) {
        match self {
            Self::ConsoleTimeout => (100, 10_000),
            Self::Gain | Self::PowerCap | Self::MotorTestMax => (1, 100),
            Self::Frame => (4, 6),
        }
    }

    /// The index in PARAM_VALUE.
    pub const fn index(self) -> u16 {
        self as u16
    }

    /// The parameter at an index.
    pub fn from_index(index: u16) -> Option<Param> {
        Self::ALL.into_iter().find(|param| param.index() == index)
    }

    /// The parameter of a NUL-padded MAVLink name (exact, case-sensitive, as ArduPilot matches).
    pub fn from_id(id: &ParamId) -> Option<Param> {
        let len = id.iter().position(|byte| *byte == 0).unwrap_or(id.len());
        let name = id.get(..len)?;
        Self::ALL.into_iter().find(|param| param.name().as_bytes() == name)
    }

    /// The NUL-padded MAVLink name.
    pub fn id(self) -> ParamId {
        let mut id = [0; 16];
        for (slot, byte) in id.iter_mut().zip(self.name().bytes()) {
            *slot = byte;
        }
        id
    }

    /// Whether `value` is a valid setting.
    pub const fn accepts(self, value: i32) -> bool {
        let (min, max) = self.range();
        match self {
            Self::Frame => value == min || value == max,
            _ => min <= value && value <= max,
        }
    }
}

/// The tunable settings, exposed as MAVLink parameters ([`Param`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Params {
    /// `LBV_CONSOLE_TO`, ms.
    pub console_timeout_ms: u16,
    /// `LBV_GAIN`, %.
    pub gain_percent: u8,
    /// `LBV_POWER_CAP`, %.
    pub power_cap_percent: u8,
    /// `LBV_FRAME`.
    pub frame: FrameKind,
    /// `LBV_MTEST_MAX`, %.
    pub motor_test_max_percent: u8,
}

impl Params {
    /// The initial values from a configuration, each clamped into its parameter's range.
    pub fn from_config(config: &VehicleConfig) -> Self {
        let (min, max) = Param::ConsoleTimeout.range();
        let timeout = config.console_timeout.as_millis().clamp(min as u64, max as u64);
        Self {
            console_timeout_ms: u16::try_from(timeout).unwrap_or(u16::MAX),
            gain_percent: config.gain_percent.clamp(1, 100),
            power_cap_percent: config.power_cap_percent.clamp(1, 100),
            frame: config.frame,
            motor_test_max_percent: config.motor_test_max_percent.clamp(1, 100),
        }
    }

    /// A parameter's value.
    pub fn get(&self, param: Param) -> i32 {
        match param {
            Param::ConsoleTimeout => i32::from(self.console_timeout_ms),
            Param::Gain => i32::from(self.gain_percent),
            Param::PowerCap => i32::from(self.power_cap_percent),
            Param::Frame => self.frame.thrusters() as i32,
            Param::MotorTestMax => i32::from(self.motor_test_max_percent),
        }
    }

    /// Set a parameter; `false` (and nothing changed) if the value is not valid for it.
    pub fn set(&mut self, param: Param, value: i32) -> bool {
        if !param.accepts(value) {
            return false;
        }
        // In range, so every conversion below succeeds.
        match param {
            Param::ConsoleTimeout => self.console_timeout_ms = u16::try_from(value).unwrap_or(self.console_timeout_ms),
            Param::Gain => self.gain_percent = u8::try_from(value).unwrap_or(self.gain_percent),
            Param::PowerCap => self.power_cap_percent = u8::try_from(value).unwrap_or(self.power_cap_percent),
            Param::Frame => {
                self.frame = u8::try_from(value)
                    .ok()
                    .and_then(FrameKind::from_thrusters)
                    .unwrap_or(self.frame);
            }
            Param::MotorTestMax => {
                self.motor_test_max_percent = u8::try_from(value).unwrap_or(self.motor_test_max_percent);
            }
        }
        true
    }

    /// The console timeout as a duration.
    pub fn console_timeout(&self) -> Duration {
        Duration::from_millis(u64::from(self.console_timeout_ms))
    }
}

/// The vehicle's configuration at power-up: the frame, how many thrusters this master drives, and the initial
/// parameter values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct VehicleConfig {
    /// Thruster layout (initial `LBV_FRAME`).
    pub frame: FrameKind,
    /// Thrusters wired to this master, numbered 1..=thrusters (at most [`MAX_THRUSTERS`]); orders beyond are
    /// STOP and motor tests beyond are DENIED.
    pub thrusters: u8,
    /// Initial `LBV_CONSOLE_TO` (default 1 s).
    pub console_timeout: Duration,
    /// Initial `LBV_GAIN`, %.
    pub gain_percent: u8,
    /// Initial `LBV_POWER_CAP`, %.
    pub power_cap_percent: u8,
    /// Initial `LBV_MTEST_MAX`, %.
    pub motor_test_max_percent: u8,
}

impl VehicleConfig {
    /// The defaults for the LBV300-6, all six thrusters wired.
    pub const DEFAULT: VehicleConfig = VehicleConfig::new(FrameKind::Lbv300_6);

    /// The defaults for a frame, with all its thrusters wired.
    pub const fn new(frame: FrameKind) -> Self {
        Self {
            frame,
            thrusters: frame.thrusters() as u8,
            console_timeout: Duration::from_secs(1),
            gain_percent: 50,
            power_cap_percent: 100,
            motor_test_max_percent: 30,
        }
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

/// Arming, console failsafe, motor test, parameters -> orders. Pure state machine with explicit time.
#[derive(Debug, Clone)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Vehicle {
    thrusters: u8,
    params: Params,
    armed: bool,
    /// A command has come since power-up.
    heard: bool,
    /// When the last command came (power-up until one does).
    last_life: Instant,
    input: ManualInput,
    motor_test: Option<MotorTest>,
}

impl Vehicle {
    /// Disarmed, console not heard yet, parameters from `config`; `now` is power-up.
    pub fn new(config: VehicleConfig, now: Instant) -> Self {
        Self {
            thrusters: config.thrusters.min(MAX_THRUSTERS as u8),
            params: Params::from_config(&config),
            armed: false,
            heard: false,
            last_life: now,
            input: NEUTRAL,
            motor_test: None,
        }
    }

    /// The current parameters.
    pub fn params(&self) -> &Params {
        &self.params
    }

    /// Apply one console command at `now`; `out` receives the answers (COMMAND_ACK, PARAM_VALUEs, texts).
    pub fn on_command(&mut self, now: Instant, command: Command, out: &mut impl FnMut(Outgoing)) {
        self.update(now, out);
        self.heard = true;
        self.last_life = now;
        match command {
            Command::Heartbeat => {}
            Command::Manual(input) => {
                if self.armed {
                    self.input = input;
                }
            }
            Command::Arm(true) => self.arm(out),
            Command::Arm(false) => {
                ack(out, MAV_CMD_COMPONENT_ARM_DISARM, AckResult::Accepted);
                self.stop_motor_test(out);
                if self.armed {
                    self.disarm();
                    say(out, Severity::Info, format_args!("Disarmed"));
                }
            }
            Command::MotorTest {
                motor,
                percent,
                duration,
            } => self.motor_test(now, motor, percent, duration, out),
            Command::Unsupported { command } => ack(out, command, AckResult::Unsupported),
            Command::ParamRequestList => {
                for param in Param::ALL {
                    self.param_value(param, out);
                }
            }
            Command::ParamRequestRead { id, index } => {
                let param = match u16::try_from(index) {
                    Ok(index) => Param::from_index(index),
                    Err(_) => Param::from_id(&id),
                };
                if let Some(param) = param {
                    self.param_value(param, out);
                }
            }
            Command::ParamSet { id, value } => {
                if let Some(param) = Param::from_id(&id) {
                    self.param_set(param, value, out);
                }
            }
        }
    }

    /// The orders for every thruster at `now` (applying the failsafe and the end of a motor test first).
    pub fn orders(&mut self, now: Instant, out: &mut impl FnMut(Outgoing)) -> [Order; MAX_THRUSTERS] {
        self.update(now, out);
        let info = self.params.power_cap_percent;
        let mut orders = [Order::STOP; MAX_THRUSTERS];
        let wired = usize::from(self.thrusters);
        if self.armed {
            let speeds = mix(self.params.frame, self.input, self.params.gain_percent);
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
            console_alive: self.heard && !self.console_silent(now),
        }
    }

    fn console_silent(&self, now: Instant) -> bool {
        now.saturating_duration_since(self.last_life) >= self.params.console_timeout()
    }

    /// What the passing of time does: the failsafe, the end of a motor test.
    fn update(&mut self, now: Instant, out: &mut impl FnMut(Outgoing)) {
        if self.console_silent(now) {
            if self.armed {
                self.disarm();
                say(
                    out,
                    Severity::Critical,
                    format_args!("Failsafe: console lost, disarmed"),
                );
            }
            if let Some(test) = self.motor_test.take() {
                say(
                    out,
                    Severity::Warning,
                    format_args!("Motor test {} stopped: console lost", test.motor),
                );
            }
        }
        if let Some(test) = self.motor_test
            && now >= test.until
        {
            self.motor_test = None;
            say(out, Severity::Info, format_args!("Motor test {} done", test.motor));
        }
    }

    fn arm(&mut self, out: &mut impl FnMut(Outgoing)) {
        if self.motor_test.is_some() {
            ack(out, MAV_CMD_COMPONENT_ARM_DISARM, AckResult::TemporarilyRejected);
            self.stop_motor_test(out);
            say(
                out,
                Severity::Warning,
                format_args!("Arm rejected: motor test was running"),
            );
            return;
        }
        ack(out, MAV_CMD_COMPONENT_ARM_DISARM, AckResult::Accepted);
        if !self.armed {
            self.armed = true;
            self.input = NEUTRAL;
            say(out, Severity::Info, format_args!("Armed"));
        }
    }

    fn disarm(&mut self) {
        self.armed = false;
        self.input = NEUTRAL;
    }

    fn stop_motor_test(&mut self, out: &mut impl FnMut(Outgoing)) {
        if let Some(test) = self.motor_test.take() {
            say(out, Severity::Info, format_args!("Motor test {} stopped", test.motor));
        }
    }

    fn motor_test(&mut self, now: Instant, motor: u8, percent: i8, duration: Duration, out: &mut impl FnMut(Outgoing)) {
        if motor == 0 || motor > self.thrusters {
            ack(out, MAV_CMD_DO_MOTOR_TEST, AckResult::Denied);
            return;
        }
        if self.armed {
            ack(out, MAV_CMD_DO_MOTOR_TEST, AckResult::TemporarilyRejected);
            return;
        }
        ack(out, MAV_CMD_DO_MOTOR_TEST, AckResult::Accepted);
        if percent == 0 || duration == Duration::from_ticks(0) {
            self.stop_motor_test(out);
            return;
        }
        let max = i32::from(self.params.motor_test_max_percent);
        let percent = i32::from(percent).clamp(-max, max);
        let duration = duration.min(MOTOR_TEST_MAX_DURATION);
        self.motor_test = Some(MotorTest {
            motor,
            speed: Speed::new_saturating(round_div(percent * i32::from(Speed::MAX_STEP), 100)),
            until: now.saturating_add(duration),
        });
        say(
            out,
            Severity::Info,
            format_args!("Motor test {motor}: {percent} % for {} ms", duration.as_millis()),
        );
    }

    fn param_value(&self, param: Param, out: &mut impl FnMut(Outgoing)) {
        out(Outgoing::ParamValue {
            id: param.id(),
            value: self.params.get(param) as f32,
            index: param.index(),
            count: PARAM_COUNT as u16,
        });
    }

    fn param_set(&mut self, param: Param, value: f32, out: &mut impl FnMut(Outgoing)) {
        let (min, max) = param.range();
        match to_integer(value) {
            Some(_) if param == Param::Frame && self.armed => {
                say(out, Severity::Warning, format_args!("{}: disarm first", param.name()));
            }
            Some(value) if self.params.set(param, value) => {}
            _ if param == Param::Frame => {
                say(
                    out,
                    Severity::Warning,
                    format_args!("{}: must be {min} or {max}", param.name()),
                );
            }
            _ => say(
                out,
                Severity::Warning,
                format_args!("{}: range {min}..{max}", param.name()),
            ),
        }
        self.param_value(param, out);
    }
}

/// The nearest integer to a parameter value (half away from zero), or `None` if it is not a number.
fn to_integer(value: f32) -> Option<i32> {
    if !value.is_finite() {
        return None;
    }
    let rounded = if value >= 0.0 { value + 0.5 } else { value - 0.5 };
    // Saturating conversion; out-of-range values stay out of range.
    Some(rounded as i32)
}

fn ack(out: &mut impl FnMut(Outgoing), command: u16, result: AckResult) {
    out(Outgoing::CommandAck { command, result });
}

fn say(out: &mut impl FnMut(Outgoing), severity: Severity, args: fmt::Arguments<'_>) {
    out(Outgoing::Text(severity, text(args)));
}

/// The vehicle task's period: 50 Hz.
pub const TICK: Duration = Duration::from_millis(20);

/// Most answers one command and one evaluation can give (a parameter list plus a few texts).
const MAX_REPLIES: usize = PARAM_COUNT + 6;

/// Receive commands (`shared.commands`) and evaluate at 50 Hz; publish the orders (`shared.orders`) and the
/// state (`shared.vehicle`) after every command and every tick; queue the answers in `shared.outbox`, waiting
/// at most one tick for room (a console that does not drain it must not stall the failsafe).
pub async fn vehicle_task(config: VehicleConfig, shared: &Shared) -> ! {
    let mut vehicle = Vehicle::new(config, Instant::now());
    let orders = shared.orders.sender();
    let state = shared.vehicle.sender();
    let mut ticker = Ticker::every(TICK);
    loop {
        let command = match select(shared.commands.receive(), ticker.next()).await {
            Either::First(command) => Some(command),
            Either::Second(()) => None,
        };
        let now = Instant::now();
        let mut replies = heapless::Vec::<Outgoing, MAX_REPLIES>::new();
        let mut push = |reply| {
            // Bounded by construction (MAX_REPLIES); a reply beyond it would be dropped, not panic.
            let _ = replies.push(reply);
        };
        if let Some(command) = command {
            vehicle.on_command(now, command, &mut push);
        }
        orders.send(vehicle.orders(now, &mut push));
        state.send(vehicle.state(now));
        let deadline = now.saturating_add(TICK);
        for reply in replies {
            if with_deadline(deadline, shared.outbox.send(reply)).await.is_err() {
                break;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::battery::tests::elapse;
    use embassy_futures::block_on;

    fn t(ms: u64) -> Instant {
        Instant::from_millis(ms)
    }

    fn id(name: &str) -> ParamId {
        let mut id = [0; 16];
        id[..name.len()].copy_from_slice(name.as_bytes());
        id
    }

    /// A vehicle and what it said.
    struct Bench {
        vehicle: Vehicle,
        said: Vec<Outgoing>,
    }

    impl Bench {
        fn new(config: VehicleConfig) -> Self {
            Self {
                vehicle: Vehicle::new(config, t(0)),
                said: Vec::new(),
            }
        }

        /// Apply a command; returns what it answered.
        fn command(&mut self, ms: u64, command: Command) -> Vec<Outgoing> {
            let mut said = Vec::new();
            self.vehicle.on_command(t(ms), command, &mut |o| said.push(o));
            self.said.extend(said.iter().cloned());
            said
        }

        fn orders(&mut self, ms: u64) -> ([Order; MAX_THRUSTERS], Vec<Outgoing>) {
            let mut said = Vec::new();
            let orders = self.vehicle.orders(t(ms), &mut |o| said.push(o));
            (orders, said)
        }

        fn steps(&mut self, ms: u64) -> [i8; MAX_THRUSTERS] {
            self.orders(ms).0.map(|order| order.speed.step())
        }

        fn armed(&self, ms: u64) -> bool {
            self.vehicle.state(t(ms)).armed
        }
    }

    fn ack(command: u16, result: AckResult) -> Outgoing {
        Outgoing::CommandAck { command, result }
    }

    fn text(severity: Severity, text: &str) -> Outgoing {
        Outgoing::Text(severity, crate::shared::Text::try_from(text).unwrap())
    }

    fn value(param: Param, value: f32) -> Outgoing {
        Outgoing::ParamValue {
            id: param.id(),
            value,
            index: param.index(),
            count: 5,
        }
    }

    const ARM: u16 = MAV_CMD_COMPONENT_ARM_DISARM;
    const TEST: u16 = MAV_CMD_DO_MOTOR_TEST;
    const STOP: [Order; MAX_THRUSTERS] = [Order::STOP; MAX_THRUSTERS];

    fn manual(x: i16, y: i16, z: i16, r: i16) -> Command {
        Command::Manual(ManualInput { x, y, z, r })
    }

    fn motor_test(motor: u8, percent: i8, ms: u64) -> Command {
        Command::MotorTest {
            motor,
            percent,
            duration: Duration::from_millis(ms),
        }
    }

    #[test]
    fn starts_disarmed_with_the_console_unheard() {
        let mut bench = Bench::new(VehicleConfig::default());
        assert_eq!(
            bench.vehicle.state(t(0)),
            VehicleState {
                armed: false,
                console_alive: false
            }
        );
        assert_eq!(bench.orders(0), (STOP, vec![]));
        assert_eq!(bench.orders(60_000), (STOP, vec![]), "no failsafe text while disarmed");
    }

    #[test]
    fn arming_and_disarming() {
        let mut bench = Bench::new(VehicleConfig::default());
        assert_eq!(
            bench.command(10, Command::Arm(true)),
            [ack(ARM, AckResult::Accepted), text(Severity::Info, "Armed")]
        );
        assert_eq!(
            bench.vehicle.state(t(10)),
            VehicleState {
                armed: true,
                console_alive: true
            }
        );
        // Arming again is accepted and says nothing.
        assert_eq!(bench.command(20, Command::Arm(true)), [ack(ARM, AckResult::Accepted)]);
        assert_eq!(
            bench.command(30, Command::Arm(false)),
            [ack(ARM, AckResult::Accepted), text(Severity::Info, "Disarmed")]
        );
        assert!(!bench.armed(30));
        assert_eq!(bench.command(40, Command::Arm(false)), [ack(ARM, AckResult::Accepted)]);
    }

    #[test]
    fn console_failsafe_at_exactly_the_timeout() {
        let mut bench = Bench::new(VehicleConfig::default());
        bench.command(0, Command::Arm(true));
        bench.command(500, manual(1000, 0, 500, 0));
        // Any command is console life.
        bench.command(1000, Command::Heartbeat);
        let (orders, said) = bench.orders(1999);
        assert!(bench.armed(1999));
        assert!(bench.vehicle.state(t(1999)).console_alive);
        assert_eq!(orders[0].speed.step(), 51);
        assert!(said.is_empty());
        let (orders, said) = bench.orders(2000);
        assert_eq!(orders, STOP);
        assert_eq!(said, [text(Severity::Critical, "Failsafe: console lost, disarmed")]);
        assert_eq!(
            bench.vehicle.state(t(2000)),
            VehicleState {
                armed: false,
                console_alive: false
            }
        );
        // Once.
        assert_eq!(bench.orders(2020), (STOP, vec![]));
        // The console comes back: still disarmed, the last input forgotten.
        bench.command(3000, Command::Heartbeat);
        assert!(bench.vehicle.state(t(3000)).console_alive);
        bench.command(3000, Command::Arm(true));
        assert_eq!(bench.steps(3001), [0; MAX_THRUSTERS]);
    }

    #[test]
    fn a_late_command_lets_the_failsafe_act_first() {
        let mut bench = Bench::new(VehicleConfig::default());
        bench.command(0, Command::Arm(true));
        // Nobody asked for orders in between; the stick input after the silence is ignored.
        let said = bench.command(1000, manual(1000, 0, 500, 0));
        assert_eq!(said, [text(Severity::Critical, "Failsafe: console lost, disarmed")]);
        assert_eq!(bench.orders(1000), (STOP, vec![]));
    }

    #[test]
    fn manual_control_through_the_mixer_to_orders() {
        let mut bench = Bench::new(VehicleConfig::default());
        // Ignored while disarmed.
        bench.command(0, manual(1000, 0, 500, 0));
        assert_eq!(bench.orders(0).0, STOP);
        bench.command(10, Command::Arm(true));
        // Armed at neutral: zero speed, INFO = the power cap.
        let (orders, _) = bench.orders(10);
        assert!(orders[..6].iter().all(|o| *o
            == Order {
                speed: Speed::ZERO,
                info: 100
            }));
        bench.command(20, manual(1000, 0, 500, 0));
        // LBV_GAIN 50 %: half speed on the four horizontals.
        assert_eq!(bench.steps(20), [51, 51, 51, 51, 0, 0, 0, 0]);
        bench.command(30, manual(0, 0, 1000, 0));
        assert_eq!(bench.steps(30), [0, 0, 0, 0, 51, 0, 0, 0]);
        bench.command(
            40,
            Command::ParamSet {
                id: id("LBV_GAIN"),
                value: 100.0,
            },
        );
        bench.command(
            40,
            Command::ParamSet {
                id: id("LBV_POWER_CAP"),
                value: 60.0,
            },
        );
        let (orders, _) = bench.orders(40);
        assert_eq!(
            orders[4],
            Order {
                speed: Speed::MAX_FORWARD,
                info: 60
            }
        );
        assert_eq!(orders[6], Order::STOP, "slots beyond the frame");
        // Disarm: STOP, and the input is forgotten.
        bench.command(50, Command::Arm(false));
        assert_eq!(bench.orders(50).0, STOP);
        bench.command(60, Command::Arm(true));
        assert_eq!(bench.steps(60), [0; MAX_THRUSTERS]);
    }

    #[test]
    fn orders_beyond_the_wired_thrusters_stay_stop() {
        let config = VehicleConfig {
            thrusters: 4,
            gain_percent: 100,
            ..VehicleConfig::new(FrameKind::Lbv300_6)
        };
        let mut bench = Bench::new(config);
        bench.command(0, Command::Arm(true));
        bench.command(0, manual(0, 1000, 500, 0));
        let (orders, _) = bench.orders(0);
        assert_eq!(orders.map(|o| o.speed.step()), [-102, 102, 102, -102, 0, 0, 0, 0]);
        assert_eq!(orders[5], Order::STOP);
        assert_eq!(bench.command(0, Command::Arm(false)).len(), 2);
        assert_eq!(
            bench.command(0, motor_test(5, 10, 1000)),
            [ack(TEST, AckResult::Denied)]
        );
    }

    #[test]
    fn lbv200_frame() {
        let config = VehicleConfig {
            gain_percent: 100,
            ..VehicleConfig::new(FrameKind::Lbv200_4)
        };
        let mut bench = Bench::new(config);
        bench.command(0, Command::Arm(true));
        bench.command(0, manual(0, 0, 500, 1000));
        assert_eq!(bench.steps(0), [-102, 102, 0, 0, 0, 0, 0, 0]);
    }

    #[test]
    fn motor_test_runs_for_its_duration() {
        let mut bench = Bench::new(VehicleConfig::default());
        assert_eq!(
            bench.command(100, motor_test(3, 20, 2000)),
            [
                ack(TEST, AckResult::Accepted),
                text(Severity::Info, "Motor test 3: 20 % for 2000 ms")
            ]
        );
        let (orders, said) = bench.orders(100);
        // 20 % of 102 steps = 20.4 -> 20.
        assert_eq!(
            orders[2],
            Order {
                speed: Speed::new(20).unwrap(),
                info: 100
            }
        );
        assert!(orders.iter().enumerate().all(|(n, o)| n == 2 || *o == Order::STOP));
        assert!(said.is_empty());
        assert!(!bench.armed(100), "a motor test does not arm");
        // Console life keeps it going; it stops at exactly its end.
        bench.command(1000, Command::Heartbeat);
        bench.command(1900, Command::Heartbeat);
        assert_eq!(bench.steps(2099)[2], 20);
        let (orders, said) = bench.orders(2100);
        assert_eq!(orders, STOP);
        assert_eq!(said, [text(Severity::Info, "Motor test 3 done")]);
    }

    #[test]
    fn motor_test_clamps_and_limits() {
        let mut bench = Bench::new(VehicleConfig::default());
        // LBV_MTEST_MAX 30 %: 30.6 steps -> 31.
        bench.command(0, motor_test(1, 100, 1000));
        assert_eq!(bench.steps(0)[0], 31);
        bench.command(0, motor_test(1, -100, 1000));
        assert_eq!(bench.steps(0)[0], -31);
        bench.command(0, motor_test(1, i8::MIN, 1000));
        assert_eq!(bench.steps(0)[0], -31);
        bench.command(0, motor_test(1, -5, 1000));
        assert_eq!(bench.steps(0)[0], -5);
        // At most 10 s.
        let said = bench.command(0, motor_test(6, 10, 60_000));
        assert_eq!(said[1], text(Severity::Info, "Motor test 6: 10 % for 10000 ms"));
        for ms in (0..10_000).step_by(500) {
            bench.command(ms, Command::Heartbeat);
        }
        assert_eq!(bench.steps(9_999)[5], 10);
        assert_eq!(bench.steps(10_000)[5], 0);
    }

    #[test]
    fn motor_test_one_thruster_at_a_time() {
        let mut bench = Bench::new(VehicleConfig::default());
        bench.command(0, motor_test(1, 20, 5000));
        bench.command(10, motor_test(2, -20, 5000));
        assert_eq!(bench.steps(10), [0, -20, 0, 0, 0, 0, 0, 0]);
        // A zero-percent test stops it.
        assert_eq!(
            bench.command(20, motor_test(2, 0, 5000)),
            [
                ack(TEST, AckResult::Accepted),
                text(Severity::Info, "Motor test 2 stopped")
            ]
        );
        assert_eq!(bench.orders(20).0, STOP);
        // So does a zero duration.
        bench.command(30, motor_test(4, 20, 5000));
        bench.command(40, motor_test(4, 20, 0));
        assert_eq!(bench.orders(40).0, STOP);
        // And a disarm command.
        bench.command(50, motor_test(4, 20, 5000));
        assert_eq!(
            bench.command(60, Command::Arm(false)),
            [
                ack(ARM, AckResult::Accepted),
                text(Severity::Info, "Motor test 4 stopped")
            ]
        );
        assert_eq!(bench.orders(60).0, STOP);
    }

    #[test]
    fn arming_during_a_motor_test_stops_it_and_is_rejected() {
        let mut bench = Bench::new(VehicleConfig::default());
        bench.command(0, motor_test(5, 20, 5000));
        assert_eq!(
            bench.command(10, Command::Arm(true)),
            [
                ack(ARM, AckResult::TemporarilyRejected),
                text(Severity::Info, "Motor test 5 stopped"),
                text(Severity::Warning, "Arm rejected: motor test was running"),
            ]
        );
        assert!(!bench.armed(10));
        assert_eq!(bench.orders(10).0, STOP);
        // Arming again works.
        assert_eq!(bench.command(20, Command::Arm(true))[0], ack(ARM, AckResult::Accepted));
    }

    #[test]
    fn motor_test_denied_and_rejected() {
        let mut bench = Bench::new(VehicleConfig::default());
        for motor in [0, 7, 8, 255] {
            assert_eq!(
                bench.command(0, motor_test(motor, 20, 1000)),
                [ack(TEST, AckResult::Denied)]
            );
        }
        bench.command(0, Command::Arm(true));
        assert_eq!(
            bench.command(0, motor_test(1, 20, 1000)),
            [ack(TEST, AckResult::TemporarilyRejected)]
        );
        // A bad thruster number is denied whatever the state.
        assert_eq!(
            bench.command(0, motor_test(9, 20, 1000)),
            [ack(TEST, AckResult::Denied)]
        );
        assert_eq!(bench.steps(0), [0; MAX_THRUSTERS]);
    }

    #[test]
    fn console_loss_stops_a_motor_test() {
        let mut bench = Bench::new(VehicleConfig::default());
        bench.command(0, motor_test(1, 20, 5000));
        assert_eq!(bench.steps(999)[0], 20);
        let (orders, said) = bench.orders(1000);
        assert_eq!(orders, STOP);
        assert_eq!(said, [text(Severity::Warning, "Motor test 1 stopped: console lost")]);
    }

    #[test]
    fn parameter_list_and_read() {
        let mut bench = Bench::new(VehicleConfig::default());
        let all = [
            value(Param::ConsoleTimeout, 1000.0),
            value(Param::Gain, 50.0),
            value(Param::PowerCap, 100.0),
            value(Param::Frame, 6.0),
            value(Param::MotorTestMax, 30.0),
        ];
        assert_eq!(bench.command(0, Command::ParamRequestList), all);
        for (n, expected) in all.iter().enumerate() {
            let param = Param::ALL[n];
            assert_eq!(
                bench.command(
                    0,
                    Command::ParamRequestRead {
                        id: param.id(),
                        index: -1
                    }
                ),
                std::slice::from_ref(expected)
            );
            assert_eq!(
                bench.command(
                    0,
                    Command::ParamRequestRead {
                        id: id("WRONG"),
                        index: n as i16
                    }
                ),
                std::slice::from_ref(expected),
                "by index, the name ignored"
            );
            assert!(param.name().len() <= 16);
            assert_eq!(Param::from_id(&param.id()), Some(param));
        }
        // Unknown: no answer.
        for (name, index) in [
            ("LBV_GAINS", -1),
            ("lbv_gain", -1),
            ("", -1),
            ("LBV_GAIN", 5),
            ("LBV_GAIN", 300),
        ] {
            assert!(
                bench
                    .command(0, Command::ParamRequestRead { id: id(name), index })
                    .is_empty()
            );
        }
        // A 16-byte name without NUL.
        assert_eq!(Param::from_id(b"LBV_GAIN\0\0\0\0\0\0\0\0"), Some(Param::Gain));
        assert_eq!(Param::from_id(b"LBV_GAIN_LONGER_"), None);
    }

    #[test]
    fn parameter_set_in_and_out_of_range() {
        let mut bench = Bench::new(VehicleConfig::default());
        let set =
            |bench: &mut Bench, name: &str, value: f32| bench.command(0, Command::ParamSet { id: id(name), value });
        assert_eq!(set(&mut bench, "LBV_GAIN", 80.0), [value(Param::Gain, 80.0)]);
        assert_eq!(bench.vehicle.params().gain_percent, 80);
        // Rounded to the nearest integer.
        assert_eq!(set(&mut bench, "LBV_GAIN", 79.6), [value(Param::Gain, 80.0)]);
        assert_eq!(set(&mut bench, "LBV_GAIN", 70.4), [value(Param::Gain, 70.0)]);
        // Out of range: the unchanged value, and a warning.
        for bad in [0.0, 101.0, -5.0, 1e20, f32::NAN, f32::INFINITY] {
            assert_eq!(
                set(&mut bench, "LBV_GAIN", bad),
                [
                    text(Severity::Warning, "LBV_GAIN: range 1..100"),
                    value(Param::Gain, 70.0)
                ],
                "{bad}"
            );
        }
        assert_eq!(
            set(&mut bench, "LBV_CONSOLE_TO", 50.0),
            [
                text(Severity::Warning, "LBV_CONSOLE_TO: range 100..10000"),
                value(Param::ConsoleTimeout, 1000.0)
            ]
        );
        assert_eq!(
            set(&mut bench, "LBV_FRAME", 5.0),
            [
                text(Severity::Warning, "LBV_FRAME: must be 4 or 6"),
                value(Param::Frame, 6.0)
            ]
        );
        assert_eq!(set(&mut bench, "LBV_FRAME", 4.0), [value(Param::Frame, 4.0)]);
        assert_eq!(bench.vehicle.params().frame, FrameKind::Lbv200_4);
        assert_eq!(set(&mut bench, "LBV_POWER_CAP", 1.0), [value(Param::PowerCap, 1.0)]);
        assert_eq!(
            set(&mut bench, "LBV_MTEST_MAX", 100.0),
            [value(Param::MotorTestMax, 100.0)]
        );
        assert!(
            set(&mut bench, "LBV_NOTHING", 1.0).is_empty(),
            "unknown name: no answer"
        );
        // The frame only while disarmed.
        bench.command(0, Command::Arm(true));
        assert_eq!(
            set(&mut bench, "LBV_FRAME", 6.0),
            [
                text(Severity::Warning, "LBV_FRAME: disarm first"),
                value(Param::Frame, 4.0)
            ]
        );
        // A shorter console timeout applies at once.
        assert_eq!(
            set(&mut bench, "LBV_CONSOLE_TO", 200.0),
            [value(Param::ConsoleTimeout, 200.0)]
        );
        assert!(bench.orders(199).1.is_empty());
        assert_eq!(bench.orders(200).1.len(), 1);
        assert!(!bench.armed(200));
    }

    #[test]
    fn config_values_are_clamped_into_the_parameter_ranges() {
        let config = VehicleConfig {
            frame: FrameKind::Lbv200_4,
            thrusters: 200,
            console_timeout: Duration::from_secs(3600),
            gain_percent: 0,
            power_cap_percent: 0,
            motor_test_max_percent: 255,
        };
        let vehicle = Vehicle::new(config, t(0));
        assert_eq!(
            *vehicle.params(),
            Params {
                console_timeout_ms: 10_000,
                gain_percent: 1,
                power_cap_percent: 1,
                frame: FrameKind::Lbv200_4,
                motor_test_max_percent: 100
            }
        );
        assert_eq!(vehicle.thrusters, MAX_THRUSTERS as u8);
    }

    #[test]
    fn unknown_commands_are_unsupported() {
        let mut bench = Bench::new(VehicleConfig::default());
        assert_eq!(
            bench.command(0, Command::Unsupported { command: 511 }),
            [ack(511, AckResult::Unsupported)]
        );
        assert!(bench.vehicle.state(t(0)).console_alive, "still console life");
        assert_eq!(bench.said.len(), 1);
    }

    #[test]
    fn vehicle_task_publishes_orders_state_and_answers() {
        let _clock = crate::test_clock::lock();
        let shared = Shared::new();
        let config = VehicleConfig {
            gain_percent: 100,
            ..VehicleConfig::default()
        };
        let drain = || {
            let mut all = Vec::new();
            while let Ok(message) = shared.outbox.try_receive() {
                all.push(message);
            }
            all
        };
        let script = async {
            elapse(Duration::from_millis(25)).await;
            assert_eq!(shared.orders.try_get(), Some(STOP));
            assert_eq!(
                shared.vehicle.try_get(),
                Some(VehicleState {
                    armed: false,
                    console_alive: false
                })
            );
            shared.commands.send(Command::Arm(true)).await;
            shared.commands.send(manual(1000, 0, 500, 0)).await;
            elapse(Duration::from_millis(2)).await;
            assert_eq!(drain(), [ack(ARM, AckResult::Accepted), text(Severity::Info, "Armed")]);
            assert_eq!(
                shared.vehicle.try_get(),
                Some(VehicleState {
                    armed: true,
                    console_alive: true
                })
            );
            let orders = shared.orders.try_get().unwrap();
            assert_eq!(orders.map(|o| o.speed.step()), [102, 102, 102, 102, 0, 0, 0, 0]);

            shared.commands.send(Command::ParamRequestList).await;
            elapse(Duration::from_millis(2)).await;
            assert_eq!(drain().len(), PARAM_COUNT);

            // The console falls silent: disarmed by the 50 Hz tick within one period of the timeout.
            let last = Instant::now();
            let mut disarmed_at = None;
            while disarmed_at.is_none() {
                elapse(Duration::from_millis(1)).await;
                if !shared.vehicle.try_get().unwrap().armed {
                    disarmed_at = Some(Instant::now() - last);
                }
            }
            let after = disarmed_at.unwrap();
            assert!(
                after >= Duration::from_millis(1000) && after <= Duration::from_millis(1020),
                "{after:?}"
            );
            assert_eq!(shared.orders.try_get(), Some(STOP));
            assert_eq!(drain(), [text(Severity::Critical, "Failsafe: console lost, disarmed")]);

            // A motor test through the task, ending on time.
            shared.commands.send(motor_test(2, 10, 100)).await;
            elapse(Duration::from_millis(2)).await;
            assert_eq!(shared.orders.try_get().unwrap()[1].speed.step(), 10);
            elapse(Duration::from_millis(120)).await;
            assert_eq!(shared.orders.try_get(), Some(STOP));
            let said = drain();
            assert_eq!(said.len(), 3, "{said:?}");
            assert_eq!(said[2], text(Severity::Info, "Motor test 2 done"));
        };
        match block_on(select(vehicle_task(config, &shared), script)) {
            Either::First(never) => match never {},
            Either::Second(()) => {}
        }
    }
}
