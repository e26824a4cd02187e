use super::*;
use crate::battery::tests::elapse;
use crate::params::{PARAM_COUNT, ParamId, Params};
use crate::shared::{Interval, Message};
use embassy_futures::block_on;

fn t(ms: u64) -> Instant {
    Instant::from_millis(ms)
}

fn id(name: &str) -> ParamId {
    let mut id = [0; 16];
    id[..name.len()].copy_from_slice(name.as_bytes());
    id
}

/// The operator's ground station (QGroundControl's ids) and two others.
const GCS: Sender = Sender {
    system: 255,
    component: 190,
};
const OTHER: Sender = Sender {
    system: 42,
    component: 1,
};
const COMPANION: Sender = Sender {
    system: 2,
    component: 191,
};

/// A vehicle and what it said.
struct Bench {
    vehicle: Vehicle,
    said: Vec<Outgoing>,
}

impl Bench {
    fn new(config: VehicleConfig) -> Self {
        Self::with(config, |_| {})
    }

    /// With parameters changed from the defaults.
    fn with(config: VehicleConfig, change: impl FnOnce(&mut Params)) -> Self {
        let mut settings = config.defaults();
        change(&mut settings.params);
        Self {
            vehicle: Vehicle::new(config, settings),
            said: Vec::new(),
        }
    }

    /// Apply a request from the operator; returns what it answered.
    fn command(&mut self, ms: u64, command: Command) -> Vec<Outgoing> {
        self.command_from(ms, GCS, command)
    }

    fn command_from(&mut self, ms: u64, from: Sender, command: Command) -> Vec<Outgoing> {
        let mut said = Vec::new();
        self.vehicle
            .on_request(t(ms), Request { from, command }, &mut |o| said.push(o));
        self.said.extend(said.iter().cloned());
        said
    }

    /// The operator's heartbeat, then arm.
    fn arm(&mut self, ms: u64) -> Vec<Outgoing> {
        self.command(ms, Command::Heartbeat);
        self.command(ms, Command::Arm(true))
    }

    fn orders(&mut self, ms: u64) -> ([Order; MAX_THRUSTERS], Vec<Outgoing>) {
        let mut said = Vec::new();
        let orders = self.vehicle.orders(t(ms), &mut |o| said.push(o));
        self.said.extend(said.iter().cloned());
        (orders, said)
    }

    fn steps(&mut self, ms: u64) -> [i8; MAX_THRUSTERS] {
        self.orders(ms).0.map(|order| order.speed.step())
    }

    fn armed(&self, ms: u64) -> bool {
        self.vehicle.state(t(ms)).armed
    }

    fn params(&self) -> &Params {
        &self.vehicle.settings().params
    }
}

fn ack(command: u16, result: AckResult) -> Outgoing {
    ack_to(command, result, GCS)
}

fn ack_to(command: u16, result: AckResult, to: Sender) -> Outgoing {
    Outgoing::CommandAck { command, result, to }
}

fn text(severity: Severity, text: &str) -> Outgoing {
    Outgoing::Text(severity, crate::shared::Text::try_from(text).unwrap())
}

fn value(param: Param, value: f32) -> Outgoing {
    Outgoing::ParamValue {
        id: param.id(),
        value,
        param_type: param.param_type(),
        index: param.index(),
        count: LISTED_COUNT as u16,
    }
}

/// PARAM_SET with the parameter's own type (REAL32 for an unknown name), as a ground station sends it after
/// reading the parameters.
fn set(name: &str, value: f32) -> Command {
    let param_type = Listed::from_id(&id(name)).map_or(9, |listed| listed.param_type().mav());
    Command::ParamSet {
        id: id(name),
        value,
        param_type,
    }
}

const ARM: u16 = MAV_CMD_COMPONENT_ARM_DISARM;
const TEST: u16 = MAV_CMD_DO_MOTOR_TEST;
const REBOOT: u16 = MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN;
const STOP: [Order; MAX_THRUSTERS] = [Order::STOP; MAX_THRUSTERS];
const GCS_LOST_DISARMED: &str = "Failsafe: ground station lost, disarmed";

fn manual(x: i16, y: i16, z: i16, r: i16) -> Command {
    Command::Manual(ManualInput { x, y, z, r }, 0)
}

/// MANUAL_CONTROL with the sticks at rest and `buttons` held.
fn buttons(buttons: u16) -> Command {
    Command::Manual(NEUTRAL, buttons)
}

fn motor_test(motor: u8, percent: i8, ms: u64) -> Command {
    Command::MotorTest {
        motor,
        percent,
        duration: Duration::from_millis(ms),
    }
}

/// Failsafe texts said so far.
fn failsafes(said: &[Outgoing]) -> Vec<&Outgoing> {
    said.iter()
        .filter(|o| matches!(o, Outgoing::Text(_, text) if text.starts_with("Failsafe")))
        .collect()
}

/// Whether the operator's arm would be accepted now, tried on a copy.
fn arm_accepted(vehicle: &Vehicle, ms: u64) -> bool {
    let mut copy = vehicle.clone();
    let mut said = vec![];
    copy.on_request(
        t(ms),
        Request {
            from: GCS,
            command: Command::Arm(true),
        },
        &mut |o| said.push(o),
    );
    said.contains(&ack(ARM, AckResult::Accepted))
}

#[test]
fn the_prearm_check_is_exactly_the_arm_rule() {
    let mut bench = Bench::new(VehicleConfig::default());
    let mut seen = (false, false);
    let mut check = |bench: &mut Bench, ms: u64| {
        bench.orders(ms);
        let armable = bench.vehicle.state(t(ms)).armable;
        assert_eq!(armable, arm_accepted(&bench.vehicle, ms), "at {ms} ms");
        assert_eq!(armable, bench.vehicle.arm_check(t(ms)).is_ok());
        if armable {
            seen.0 = true;
        } else {
            seen.1 = true;
        }
    };
    // No ground station; its heartbeat; a motor test; the test over; armed; silence (failsafe); back.
    check(&mut bench, 0);
    bench.command(10, Command::Heartbeat);
    check(&mut bench, 10);
    bench.command(20, motor_test(1, 20, 500));
    check(&mut bench, 30);
    check(&mut bench, 600);
    bench.command(700, Command::Arm(true));
    check(&mut bench, 710);
    for ms in [5_000, 5_709, 5_710, 5_711, 9_000] {
        check(&mut bench, ms);
    }
    bench.command(9_500, Command::Heartbeat);
    check(&mut bench, 9_500);
    assert_eq!(seen, (true, true));
}

#[test]
fn a_failsafe_in_force_shows_until_the_pilot_is_back() {
    let mut bench = Bench::new(VehicleConfig::default());
    bench.arm(0);
    assert!(!bench.vehicle.state(t(0)).failsafe);
    // Heartbeats on, sticks stop: the pilot-input failsafe (neutral) acts at 3 s, until the next sticks.
    bench.command(100, manual(500, 0, 500, 0));
    for ms in [1_000, 2_000, 3_000] {
        bench.command(ms, Command::Heartbeat);
    }
    bench.orders(3_100);
    assert!(bench.vehicle.state(t(3_100)).failsafe);
    bench.command(3_200, manual(0, 0, 500, 0));
    assert!(!bench.vehicle.state(t(3_200)).failsafe);
    // The heartbeats stop: disarmed at 5 s after the last, and the failsafe shows until they return.
    bench.orders(8_100);
    let state = bench.vehicle.state(t(8_100));
    assert!(state.failsafe && !state.armed && !state.armable);
    bench.command(9_000, Command::Heartbeat);
    let state = bench.vehicle.state(t(9_000));
    assert!(!state.failsafe && state.armable);
}

#[test]
fn message_requests_and_intervals() {
    let mut bench = Bench::new(VehicleConfig::default());
    let request = |message| Command::RequestMessage {
        command: 512,
        message,
        first: 0,
    };
    // Anyone may ask for a message.
    assert_eq!(
        bench.command_from(0, OTHER, request(Some(Message::AutopilotVersion))),
        [
            ack_to(512, AckResult::Accepted, OTHER),
            Outgoing::Message {
                message: Message::AutopilotVersion,
                first: 0
            }
        ]
    );
    assert_eq!(bench.command(0, request(None)), [ack(512, AckResult::Denied)]);
    let interval = |message, interval| Command::MessageInterval { message, interval };
    assert_eq!(
        bench.command(0, interval(Some(Message::EscStatus), Some(Interval::Off))),
        [
            ack(511, AckResult::Accepted),
            Outgoing::Interval(Message::EscStatus, Interval::Off)
        ]
    );
    for (message, every) in [
        (Some(Message::Heartbeat), Some(Interval::Every(200))),
        (Some(Message::AutopilotVersion), Some(Interval::Every(1000))),
        (None, Some(Interval::Default)),
        (Some(Message::SysStatus), None),
    ] {
        assert_eq!(
            bench.command(0, interval(message, every)),
            [ack(511, AckResult::Denied)]
        );
    }
    // Pacing the operator's link is the operator's.
    assert_eq!(
        bench.command_from(0, OTHER, interval(Some(Message::SysStatus), Some(Interval::Default))),
        [ack_to(511, AckResult::Denied, OTHER)]
    );
}

#[test]
fn starts_disarmed_with_no_ground_station() {
    let mut bench = Bench::new(VehicleConfig::default());
    assert_eq!(
        bench.vehicle.state(t(0)),
        VehicleState {
            armed: false,
            console_alive: false,
            refused: 0,
            armable: false,
            failsafe: false,
            param_type_mismatches: 0,
            operator: 255
        }
    );
    assert_eq!(bench.orders(0), (STOP, vec![]));
    assert_eq!(bench.orders(60_000), (STOP, vec![]), "no failsafe text while disarmed");
}

#[test]
fn the_one_mode_is_taken_and_every_other_denied_with_why() {
    let mut bench = Bench::new(VehicleConfig::default());
    let set = MAV_CMD_DO_SET_MODE;
    assert_eq!(
        bench.command(
            10,
            Command::SetMode {
                custom_mode: Some(ARDUSUB_MODE_MANUAL)
            }
        ),
        [ack(set, AckResult::Accepted)]
    );
    // ArduSub's STABILIZE (0), ALT_HOLD (2), POSHOLD (16), and a request that names no custom mode.
    for custom_mode in [Some(0), Some(2), Some(16), None] {
        assert_eq!(
            bench.command(20, Command::SetMode { custom_mode }),
            [ack(set, AckResult::Denied), text(Severity::Warning, MANUAL_ONLY)],
            "{custom_mode:?}"
        );
    }
    assert!(MANUAL_ONLY.len() <= 50, "one STATUSTEXT");
}

#[test]
fn arming_waits_for_the_heave_stick_at_its_centre() {
    let mut bench = Bench::new(VehicleConfig::default());
    bench.command(0, Command::Heartbeat);
    // A ground station set to send its centre as 0 (QGroundControl's centre-zero throttle): full descent here.
    bench.command(10, manual(0, 0, 0, 0));
    assert_eq!(
        bench.command(20, Command::Arm(true)),
        [
            ack(ARM, AckResult::TemporarilyRejected),
            text(Severity::Warning, "Arm rejected: heave stick at 0, not 500")
        ]
    );
    assert_eq!(bench.vehicle.arm_check(t(20)), Err(ArmRefusal::Heave(0)));
    assert!(!bench.vehicle.state(t(20)).armable, "the pre-arm check says so too");
    // Within the band around the centre, a joystick at rest.
    for z in [500 - HEAVE_ARM_BAND - 1, 500 + HEAVE_ARM_BAND + 1] {
        bench.command(30, manual(0, 0, z, 0));
        assert_eq!(bench.vehicle.arm_check(t(30)), Err(ArmRefusal::Heave(z)));
    }
    for z in [500 - HEAVE_ARM_BAND, 500 + HEAVE_ARM_BAND] {
        bench.command(40, manual(0, 0, z, 0));
        assert_eq!(bench.vehicle.arm_check(t(40)), Ok(()), "{z}");
    }
    // A stick input no longer live (the joystick switched off) does not hold arming.
    bench.command(50, manual(0, 0, 0, 0));
    let timeout = bench.params().pilot_timeout().as_millis();
    bench.command(50 + timeout, Command::Heartbeat);
    assert_eq!(bench.vehicle.arm_check(t(50 + timeout)), Ok(()));
    assert_eq!(
        bench.command(50 + timeout, Command::Arm(true)),
        [ack(ARM, AckResult::Accepted), text(Severity::Info, "Armed")]
    );
}

#[test]
fn arming_needs_the_operators_heartbeat() {
    let mut bench = Bench::new(VehicleConfig::default());
    assert_eq!(
        bench.command(10, Command::Arm(true)),
        [
            ack(ARM, AckResult::TemporarilyRejected),
            text(Severity::Warning, "Arm rejected: no ground station heartbeat")
        ]
    );
    assert_eq!(
        bench.arm(20),
        [ack(ARM, AckResult::Accepted), text(Severity::Info, "Armed")]
    );
    assert_eq!(
        bench.vehicle.state(t(20)),
        VehicleState {
            armed: true,
            console_alive: true,
            refused: 0,
            armable: true,
            failsafe: false,
            param_type_mismatches: 0,
            operator: 255
        }
    );
    // Arming again is accepted and says nothing.
    assert_eq!(bench.command(30, Command::Arm(true)), [ack(ARM, AckResult::Accepted)]);
    assert_eq!(
        bench.command(40, Command::Arm(false)),
        [ack(ARM, AckResult::Accepted), text(Severity::Info, "Disarmed")]
    );
    assert!(!bench.armed(40));
    assert_eq!(bench.command(50, Command::Arm(false)), [ack(ARM, AckResult::Accepted)]);
    // A heartbeat older than FS_GCS_TIMEOUT does not do.
    assert_eq!(
        bench.command(5_020, Command::Arm(true))[0],
        ack(ARM, AckResult::TemporarilyRejected)
    );
}

#[test]
fn arming_is_refused_while_the_field_update_holds_the_vehicle_saying_why() {
    use crate::shared::UpdateHold::*;
    for (hold, why) in [
        (MasterStarting, "Arm rejected: master starting"),
        (MasterApplying, "Arm rejected: master update being applied"),
        (MasterRestarting, "Arm rejected: master restarting into its update"),
        (MasterOnTrial, "Arm rejected: master image on trial"),
        (Applying(0), "Arm rejected: T1 update being applied"),
        (OnTrial(2), "Arm rejected: T3 image on trial"),
        (Marked(5), "Arm rejected: T6 holds an update marked"),
        (Unasked(7), "Arm rejected: T8 image not asked yet"),
    ] {
        let mut bench = Bench::new(VehicleConfig::default());
        bench.command(0, Command::Heartbeat);
        bench.vehicle.hold_for_update(Some(hold));
        assert_eq!(bench.vehicle.arm_check(t(10)), Err(ArmRefusal::Update(hold)));
        assert!(
            !bench.vehicle.state(t(10)).armable,
            "{hold:?}: the pre-arm check says so too"
        );
        // The same arm twice: refused twice, the same way, and nothing drives.
        for ms in [10, 20] {
            assert_eq!(
                bench.command(ms, Command::Arm(true)),
                [ack(ARM, AckResult::TemporarilyRejected), text(Severity::Warning, why)],
                "{hold:?}"
            );
        }
        bench.command(30, manual(1000, 0, 500, 0));
        assert!(!bench.armed(30) && bench.steps(30) == [0; MAX_THRUSTERS]);
        // Once nothing holds it, the same arm is taken.
        bench.vehicle.hold_for_update(None);
        assert_eq!(
            bench.command(40, Command::Arm(true)),
            [ack(ARM, AckResult::Accepted), text(Severity::Info, "Armed")]
        );
    }
    // Without the operator's heartbeat that is said first: the ground station hears what to fix first.
    let mut bench = Bench::new(VehicleConfig::default());
    bench.vehicle.hold_for_update(Some(OnTrial(0)));
    assert_eq!(bench.vehicle.arm_check(t(0)), Err(ArmRefusal::NoHeartbeat));
}

#[test]
fn ground_station_failsafe_disarms_at_exactly_the_timeout() {
    let mut bench = Bench::new(VehicleConfig::default());
    bench.arm(0);
    bench.command(500, manual(1000, 0, 500, 0));
    bench.command(1000, Command::Heartbeat);
    // Sticks keep coming; only the heartbeat counts for this failsafe.
    for ms in (600..6000).step_by(100) {
        bench.command(ms, manual(1000, 0, 500, 0));
    }
    let (orders, said) = bench.orders(5999);
    assert!(bench.armed(5999));
    assert!(bench.vehicle.state(t(5999)).console_alive);
    assert_eq!(orders[0].speed.step(), 51);
    assert!(said.is_empty());
    let (orders, said) = bench.orders(6000);
    assert_eq!(orders, STOP);
    assert_eq!(said, [text(Severity::Critical, GCS_LOST_DISARMED)]);
    assert_eq!(
        bench.vehicle.state(t(6000)),
        VehicleState {
            armed: false,
            console_alive: false,
            refused: 0,
            armable: false,
            failsafe: true,
            param_type_mismatches: 0,
            operator: 255
        }
    );
    // Once.
    assert_eq!(bench.orders(6020), (STOP, vec![]));
    // The ground station comes back: still disarmed, the last input forgotten.
    assert_eq!(
        bench.command(7000, Command::Heartbeat),
        [text(Severity::Info, "Ground station back")]
    );
    assert!(bench.vehicle.state(t(7000)).console_alive);
    bench.command(7000, Command::Arm(true));
    assert_eq!(bench.steps(7001), [0; MAX_THRUSTERS]);
}

#[test]
fn a_late_request_lets_the_failsafe_act_first() {
    let mut bench = Bench::new(VehicleConfig::default());
    bench.arm(0);
    // Nobody asked for orders in between; the stick input after the silence is ignored.
    let said = bench.command(5000, manual(1000, 0, 500, 0));
    assert_eq!(said, [text(Severity::Critical, GCS_LOST_DISARMED)]);
    assert_eq!(bench.orders(5000), (STOP, vec![]));
}

#[test]
fn ground_station_failsafe_warn_only() {
    let mut bench = Bench::with(VehicleConfig::default(), |p| {
        p.set(Param::GcsFailsafe, 1);
    });
    bench.arm(0);
    bench.command(100, manual(1000, 0, 500, 0));
    for ms in (200..9000).step_by(100) {
        bench.command(ms, manual(1000, 0, 500, 0));
    }
    assert_eq!(
        failsafes(&bench.said),
        [&text(Severity::Warning, "Failsafe: ground station lost")],
        "once"
    );
    assert!(bench.armed(9000));
    assert_eq!(bench.steps(9000)[0], 51, "still driving");
    assert_eq!(
        bench.command(9500, Command::Heartbeat),
        [text(Severity::Info, "Ground station back")]
    );
}

#[test]
fn ground_station_failsafe_neutral_holds_the_sticks_until_it_is_back() {
    // FS_GCS_ENABLE 1 (ArduSub's warn only) with LBV_GCS_NEUTRAL: earlier images' FS_GCS_ENABLE 3.
    let mut bench = Bench::with(VehicleConfig::default(), |p| {
        assert!(p.set(Param::GcsFailsafe, 1) && p.set(Param::GcsNeutral, 1));
    });
    bench.arm(0);
    bench.command(100, manual(1000, 0, 500, 0));
    assert_eq!(bench.steps(100)[0], 51);
    let (_, said) = bench.orders(5000);
    assert_eq!(
        said,
        [text(Severity::Critical, "Failsafe: ground station lost, neutral")]
    );
    assert!(bench.armed(5000));
    assert_eq!(bench.steps(5000), [0; MAX_THRUSTERS]);
    // Sticks from the operator without heartbeats: still held.
    bench.command(5100, manual(1000, 0, 500, 0));
    assert_eq!(bench.steps(5100), [0; MAX_THRUSTERS]);
    // The heartbeats return: the sticks count again.
    assert_eq!(
        bench.command(6000, Command::Heartbeat),
        [text(Severity::Info, "Ground station back")]
    );
    bench.command(6100, manual(1000, 0, 500, 0));
    assert_eq!(bench.steps(6100)[0], 51);
}

/// A 1 Hz stream with jitter and lost frames: the times it arrives at, over `seconds`.
fn one_hertz(seconds: u64, jitter_ms: u64, lose_every: u64, seed: u64) -> Vec<u64> {
    let mut state = seed | 1;
    (0..seconds)
        .filter(|n| (n + 1) % lose_every != 0)
        .map(|n| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            n * 1000 + state % (jitter_ms + 1)
        })
        .collect()
}

#[test]
fn one_hertz_heartbeats_and_sticks_with_one_lost_never_trip_either_failsafe() {
    for (jitter, lose_every) in [(0, 2), (500, 2), (300, 3), (0, 1000)] {
        let mut bench = Bench::new(VehicleConfig::default());
        bench.arm(0);
        bench.command(0, manual(500, 0, 500, 0));
        // Ten minutes of heartbeats and sticks, each at 1 Hz: every `lose_every`-th one lost (2: every other
        // one, so 2 s apart), late by up to `jitter`.
        let mut events: Vec<(u64, Command)> = one_hertz(600, jitter, lose_every, 7)
            .into_iter()
            .map(|ms| (ms, Command::Heartbeat))
            .chain(
                one_hertz(600, jitter, lose_every, 11)
                    .into_iter()
                    .map(|ms| (ms, manual(500, 0, 500, 0))),
            )
            .collect();
        events.sort_by_key(|(ms, _)| *ms);
        let mut events = events.into_iter().peekable();
        // Orders at 50 Hz, as the task asks.
        for ms in (0..600_000).step_by(20) {
            while let Some((at, command)) = events.next_if(|(at, _)| *at <= ms) {
                bench.command(at, command);
            }
            assert!(
                bench.armed(ms),
                "disarmed at {ms} ms (jitter {jitter}, 1 in {lose_every} lost)"
            );
            assert_eq!(bench.orders(ms).0[0].speed.step(), 26, "{ms} ms");
        }
        assert!(failsafes(&bench.said).is_empty(), "{:?}", failsafes(&bench.said));
    }
}

#[test]
fn heartbeats_alone_hold_the_vehicle_armed() {
    // MAVProxy without a joystick: heartbeats at 1 Hz, no MANUAL_CONTROL. The pilot-input failsafe watches a
    // stream that never started, so it stays quiet, and the thrusters stay neutral.
    let mut bench = Bench::new(VehicleConfig::default());
    bench.arm(0);
    for ms in (0..60_000).step_by(20) {
        if ms % 1000 == 0 {
            bench.command(ms, Command::Heartbeat);
        }
        let (orders, _) = bench.orders(ms);
        let neutral = Order {
            speed: Speed::ZERO,
            info: 100,
        };
        assert!(orders[..6].iter().all(|o| *o == neutral), "{ms} ms: {orders:?}");
    }
    assert!(bench.armed(60_000));
    assert!(failsafes(&bench.said).is_empty());
}

#[test]
fn pilot_input_failsafe_neutral_then_the_sticks_take_over_again() {
    let mut bench = Bench::new(VehicleConfig::default());
    bench.arm(0);
    for ms in (100..=4000).step_by(100) {
        if ms % 1000 == 0 {
            bench.command(ms, Command::Heartbeat);
        }
        if ms <= 2000 {
            bench.command(ms, manual(1000, 0, 500, 0));
        }
    }
    // The last stick frame at 2000: at 4999 still driving, at 5000 neutral, still armed.
    assert_eq!(bench.steps(4999)[0], 51);
    let (orders, said) = bench.orders(5000);
    assert!(orders.iter().all(|o| o.speed.is_zero()));
    assert_eq!(said, [text(Severity::Warning, "Failsafe: pilot input lost, neutral")]);
    assert!(bench.armed(5000));
    for ms in (5000..=8000).step_by(1000) {
        bench.command(ms, Command::Heartbeat);
    }
    assert_eq!(bench.orders(8000).1, [], "once");
    // The sticks come back.
    bench.command(8000, manual(-1000, 0, 500, 0));
    assert_eq!(bench.steps(8000)[0], -51);
}

#[test]
fn pilot_input_failsafe_disarm_or_off() {
    let mut bench = Bench::with(VehicleConfig::default(), |p| {
        p.set(Param::PilotFailsafe, 2);
        p.set(Param::PilotTimeout, 10);
    });
    bench.arm(0);
    bench.command(100, manual(1000, 0, 500, 0));
    bench.command(1000, Command::Heartbeat);
    assert!(bench.orders(1099).1.is_empty());
    assert_eq!(
        bench.orders(1100),
        (
            STOP,
            vec![text(Severity::Critical, "Failsafe: pilot input lost, disarmed")]
        )
    );
    assert!(!bench.armed(1100));

    let mut bench = Bench::with(VehicleConfig::default(), |p| {
        p.set(Param::PilotFailsafe, 0);
    });
    bench.arm(0);
    bench.command(100, manual(1000, 0, 500, 0));
    for ms in (1000..20_000).step_by(1000) {
        bench.command(ms, Command::Heartbeat);
    }
    assert_eq!(bench.steps(20_000)[0], 51, "off: the last input holds");
    assert!(failsafes(&bench.said).is_empty());
}

#[test]
fn only_the_operator_may_arm_steer_set_and_keep_the_failsafe_alive() {
    let mut bench = Bench::new(VehicleConfig::default());
    // Another system arms, with its own heartbeats: denied, to it, and counted.
    bench.command_from(0, OTHER, Command::Heartbeat);
    assert_eq!(
        bench.command_from(0, OTHER, Command::Arm(true)),
        [ack_to(ARM, AckResult::Denied, OTHER)]
    );
    assert!(!bench.armed(0));
    assert!(
        !bench.vehicle.state(t(0)).console_alive,
        "its heartbeat is not the operator's"
    );
    // Every command of another system is denied, whatever it asks.
    for command in [
        Command::Arm(false),
        motor_test(1, 10, 1000),
        Command::Reboot,
        Command::Unsupported { command: 31010 },
    ] {
        let said = bench.command_from(0, OTHER, command);
        assert!(matches!(
            said.as_slice(),
            [Outgoing::CommandAck {
                result: AckResult::Denied,
                to: OTHER,
                ..
            }]
        ));
    }
    // Parameter sets and the signing key: ignored (no answer in MAVLink), counted.
    assert_eq!(bench.command_from(0, OTHER, set("LBV_GAIN", 90.0)), []);
    assert_eq!(bench.params().gain_percent(), 50);
    assert_eq!(
        bench.command_from(
            0,
            OTHER,
            Command::SetupSigning {
                key: [1; 32],
                timestamp: 0
            }
        ),
        []
    );
    assert_eq!(bench.vehicle.settings().signing, None);
    assert_eq!(bench.vehicle.state(t(0)).refused, 7);
    // Reading the parameters is anyone's.
    assert_eq!(
        bench.command_from(
            0,
            OTHER,
            Command::ParamRequestRead {
                id: id("LBV_GAIN"),
                index: -1
            }
        ),
        [value(Param::Gain, 50.0)]
    );

    // The operator arms; another system's sticks are ignored and counted.
    bench.arm(100);
    bench.command_from(200, OTHER, manual(1000, 0, 500, 0));
    assert_eq!(bench.steps(200), [0; MAX_THRUSTERS]);
    assert_eq!(bench.vehicle.state(t(200)).refused, 8);
    // A companion computer keeps reading parameters and beating while the operator is silent: the failsafe
    // still acts.
    for ms in (200..5100).step_by(100) {
        bench.command_from(ms, COMPANION, Command::ParamRequestRead { id: id(""), index: 1 });
        bench.command_from(ms, COMPANION, Command::Heartbeat);
    }
    bench.orders(5100);
    assert!(!bench.armed(5100));
    assert_eq!(failsafes(&bench.said), [&text(Severity::Critical, GCS_LOST_DISARMED)]);
}

#[test]
fn the_operator_is_a_parameter_changed_only_while_disarmed() {
    let mut bench = Bench::new(VehicleConfig::default());
    bench.arm(0);
    assert_eq!(
        bench.command(0, set("SYSID_MYGCS", 42.0)),
        [
            text(Severity::Warning, "SYSID_MYGCS: disarm first"),
            value(Param::OperatorId, 255.0)
        ]
    );
    bench.command(0, Command::Arm(false));
    assert_eq!(
        bench.command(0, set("SYSID_MYGCS", 42.0)),
        [value(Param::OperatorId, 42.0)]
    );
    // The old operator is now a stranger; the new one is obeyed.
    assert_eq!(bench.command(10, Command::Arm(true)), [ack(ARM, AckResult::Denied)]);
    bench.command_from(20, OTHER, Command::Heartbeat);
    assert_eq!(
        bench.command_from(20, OTHER, Command::Arm(true)),
        [ack_to(ARM, AckResult::Accepted, OTHER), text(Severity::Info, "Armed")]
    );
}

#[test]
fn reboot_only_while_disarmed_after_its_acknowledgement() {
    let mut bench = Bench::new(VehicleConfig::default());
    bench.arm(0);
    assert_eq!(
        bench.command(0, Command::Reboot),
        [
            ack(REBOOT, AckResult::TemporarilyRejected),
            text(Severity::Warning, "Reboot rejected: disarm first")
        ]
    );
    bench.command(0, Command::Arm(false));
    assert_eq!(
        bench.command(0, Command::Reboot),
        [
            ack(REBOOT, AckResult::Accepted),
            text(Severity::Info, "Rebooting"),
            Outgoing::Reboot
        ]
    );
}

#[test]
fn setup_signing_sets_and_clears_the_key_while_disarmed() {
    let mut bench = Bench::new(VehicleConfig::default());
    let setup = |key: [u8; 32]| Command::SetupSigning { key, timestamp: 1_000 };
    assert_eq!(bench.command(0, setup([3; 32])), [text(Severity::Info, "Signing on")]);
    assert_eq!(
        bench.vehicle.settings().signing,
        Some(SigningKey {
            secret: [3; 32],
            timestamp: 1_000
        })
    );
    bench.arm(0);
    assert_eq!(
        bench.command(0, setup([0; 32])),
        [text(Severity::Warning, "Signing: disarm first")]
    );
    assert!(bench.vehicle.settings().signing.is_some());
    bench.command(0, Command::Arm(false));
    assert_eq!(bench.command(0, setup([0; 32])), [text(Severity::Info, "Signing off")]);
    assert_eq!(bench.vehicle.settings().signing, None);
}

#[test]
fn manual_control_through_the_mixer_to_orders() {
    let mut bench = Bench::new(VehicleConfig::default());
    bench.command(0, Command::Heartbeat);
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
    bench.command(40, set("LBV_GAIN", 100.0));
    bench.command(40, set("LBV_POWER_CAP", 60.0));
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
        ..VehicleConfig::new(FrameKind::Lbv300_6)
    };
    let mut bench = Bench::with(config, |p| {
        p.set(Param::Gain, 100);
    });
    bench.arm(0);
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
    let mut bench = Bench::with(VehicleConfig::new(FrameKind::Lbv200_4), |p| {
        p.set(Param::Gain, 100);
    });
    bench.arm(0);
    bench.command(0, manual(0, 0, 500, 1000));
    assert_eq!(bench.steps(0), [-102, 102, 0, 0, 0, 0, 0, 0]);
}

#[test]
fn motor_test_runs_for_its_duration() {
    let mut bench = Bench::new(VehicleConfig::default());
    bench.command(100, Command::Heartbeat);
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
    // It stops at exactly its end.
    bench.command(1000, Command::Heartbeat);
    assert_eq!(bench.steps(2099)[2], 20);
    let (orders, said) = bench.orders(2100);
    assert_eq!(orders, STOP);
    assert_eq!(said, [text(Severity::Info, "Motor test 3 done")]);
}

#[test]
fn motor_test_clamps_and_limits() {
    let mut bench = Bench::new(VehicleConfig::default());
    bench.command(0, Command::Heartbeat);
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
    for ms in (0..10_000).step_by(1000) {
        bench.command(ms, Command::Heartbeat);
    }
    assert_eq!(bench.steps(9_999)[5], 10);
    assert_eq!(bench.steps(10_000)[5], 0);
}

#[test]
fn motor_test_one_thruster_at_a_time() {
    let mut bench = Bench::new(VehicleConfig::default());
    bench.command(0, Command::Heartbeat);
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
    bench.command(0, Command::Heartbeat);
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
    // No heartbeat yet.
    assert_eq!(
        bench.command(0, motor_test(1, 20, 1000)),
        [ack(TEST, AckResult::TemporarilyRejected)]
    );
    bench.command(0, Command::Heartbeat);
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
fn ground_station_loss_stops_a_motor_test() {
    let mut bench = Bench::new(VehicleConfig::default());
    bench.command(0, Command::Heartbeat);
    bench.command(0, motor_test(1, 20, 9000));
    assert_eq!(bench.steps(4999)[0], 20);
    let (orders, said) = bench.orders(5000);
    assert_eq!(orders, STOP);
    assert_eq!(
        said,
        [text(Severity::Warning, "Motor test 1 stopped: ground station lost")]
    );
}

#[test]
fn parameter_list_and_read() {
    let mut bench = Bench::new(VehicleConfig::default());
    let mut all = vec![
        value(Param::GcsFailsafe, 2.0),
        value(Param::GcsTimeout, 5.0),
        value(Param::PilotFailsafe, 1.0),
        value(Param::PilotTimeout, 3.0),
        value(Param::OperatorId, 255.0),
        value(Param::Gain, 50.0),
        value(Param::PowerCap, 100.0),
        value(Param::Frame, 6.0),
        value(Param::MotorTestMax, 30.0),
        value(Param::UnsignedUpdates, 0.0),
    ];
    // The buttons: ArduSub's gamepad defaults for disarm (4), arm (3), gain up (42) and down (43).
    for n in 0..crate::params::BUTTONS {
        let function = [(4, 4.0), (6, 3.0), (11, 42.0), (12, 43.0)]
            .into_iter()
            .find_map(|(button, function)| (button == n).then_some(function));
        all.push(value(Param::button(n).unwrap(), function.unwrap_or(0.0)));
    }
    all.push(value(Param::GcsNeutral, 0.0));
    assert_eq!(all.len(), PARAM_COUNT);
    // The console sends the list, one value at a time.
    assert_eq!(bench.command(0, Command::ParamRequestList), [Outgoing::ParamList]);
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
    }
    // Unknown: no answer.
    for (name, index) in [
        ("LBV_GAINS", -1),
        ("lbv_gain", -1),
        ("", -1),
        ("LBV_GAIN", LISTED_COUNT as i16),
        ("LBV_GAIN", 300),
    ] {
        assert!(
            bench
                .command(0, Command::ParamRequestRead { id: id(name), index })
                .is_empty()
        );
    }
}

#[test]
fn a_stand_in_is_read_like_a_setting_and_never_set() {
    let mut bench = Bench::new(VehicleConfig::default());
    let before = *bench.params();
    let answer = |name: &str, value: f32| {
        let listed = Listed::from_id(&id(name)).unwrap();
        Outgoing::ParamValue {
            id: id(name),
            value,
            param_type: listed.param_type(),
            index: listed.index(),
            count: LISTED_COUNT as u16,
        }
    };
    let fltmode1 = answer("FLTMODE1", 19.0);
    let Outgoing::ParamValue { index, .. } = fltmode1 else {
        unreachable!()
    };
    assert!(usize::from(index) >= PARAM_COUNT, "after the settings");
    for request in [
        Command::ParamRequestRead {
            id: id("FLTMODE1"),
            index: -1,
        },
        Command::ParamRequestRead {
            id: id("WRONG"),
            index: index as i16,
        },
    ] {
        assert_eq!(bench.command(0, request), std::slice::from_ref(&fltmode1));
    }
    // A set of any value, of any type, is refused with the value it holds; nothing is stored, nothing counted.
    for (name, value, held, param_type) in [
        ("FLTMODE1", 0.0, 19.0, 2),
        ("INS_ACCOFFS_X", 0.25, 0.0, 9),
        ("COMPASS_DEV_ID", 97539.0, 0.0, 6),
        ("BATT_MONITOR", 4.0, -1.0, 9),
    ] {
        let set = Command::ParamSet {
            id: id(name),
            value,
            param_type,
        };
        assert_eq!(
            bench.command(0, set),
            [
                text(Severity::Warning, &format!("{name}: read-only")),
                answer(name, held)
            ]
        );
    }
    assert_eq!(*bench.params(), before);
    assert_eq!(bench.vehicle.state(t(0)).param_type_mismatches, 0);
}

#[test]
fn parameter_set_of_another_type_is_answered_unchanged_and_counted() {
    let mut bench = Bench::new(VehicleConfig::default());
    let typed = |name: &str, value: f32, param_type: u8| Command::ParamSet {
        id: id(name),
        value,
        param_type,
    };
    // FS_PILOT_INPUT is INT8: an INT32, UINT8, INT16 or unknown-type set changes nothing.
    for param_type in [6, 1, 4, 0] {
        assert_eq!(
            bench.command(0, typed("FS_PILOT_INPUT", 2.0, param_type)),
            [
                text(Severity::Warning, "FS_PILOT_INPUT: wrong param_type"),
                value(Param::PilotFailsafe, 1.0)
            ]
        );
    }
    assert_eq!(bench.vehicle.state(t(0)).param_type_mismatches, 4);
    assert_eq!(bench.params().pilot_failsafe(), PilotFailsafe::Neutral);
    // The right type is taken; SYSID_MYGCS is INT16, the timeouts REAL32.
    assert_eq!(
        bench.command(0, typed("FS_PILOT_INPUT", 2.0, 2)),
        [value(Param::PilotFailsafe, 2.0)]
    );
    assert_eq!(bench.params().pilot_failsafe(), PilotFailsafe::Disarm);
    // REAL32 too (MAVProxy's), the float holding the value.
    assert_eq!(
        bench.command(0, typed("FS_PILOT_INPUT", 0.0, 9)),
        [value(Param::PilotFailsafe, 0.0)]
    );
    assert_eq!(
        bench.command(0, typed("FS_GCS_TIMEOUT", 6.0, 2)).len(),
        2,
        "an integer type for a REAL32"
    );
    assert_eq!(bench.vehicle.state(t(0)).param_type_mismatches, 5);
    assert_eq!(
        bench.command(0, typed("FS_GCS_TIMEOUT", 6.5, 9)),
        [value(Param::GcsTimeout, 6.5)]
    );
    // (Last: the operator is someone else after it.)
    assert_eq!(
        bench.command(0, typed("SYSID_MYGCS", 254.0, 4)),
        [value(Param::OperatorId, 254.0)]
    );
    assert_eq!(bench.vehicle.state(t(0)).param_type_mismatches, 5);
}

#[test]
fn parameter_set_in_and_out_of_range() {
    let mut bench = Bench::new(VehicleConfig::default());
    let pilot_gain = Outgoing::Message {
        message: Message::NamedValueFloat,
        first: 0,
    };
    assert_eq!(
        bench.command(0, set("LBV_GAIN", 80.0)),
        [value(Param::Gain, 80.0), pilot_gain],
        "a change of the gain sends PilotGain at once"
    );
    assert_eq!(bench.params().gain_percent(), 80);
    // A timeout (seconds with a tenth) is rounded to the tenth.
    assert_eq!(
        bench.command(0, set("FS_GCS_TIMEOUT", 4.96)),
        [value(Param::GcsTimeout, 5.0)]
    );
    // Out of range, or not a whole number for an integer (2 as raw bits is a denormal): the unchanged value,
    // and a warning.
    for bad in [
        0.0,
        101.0,
        -5.0,
        1e20,
        f32::NAN,
        f32::INFINITY,
        79.6,
        f32::from_bits(80),
    ] {
        assert_eq!(
            bench.command(0, set("LBV_GAIN", bad)),
            [
                text(Severity::Warning, "LBV_GAIN: range 1..100"),
                value(Param::Gain, 80.0)
            ],
            "{bad}"
        );
    }
    // Seconds with a tenth.
    assert_eq!(
        bench.command(0, set("FS_GCS_TIMEOUT", 1.0)),
        [
            text(Severity::Warning, "FS_GCS_TIMEOUT: range 2..120"),
            value(Param::GcsTimeout, 5.0)
        ]
    );
    assert_eq!(
        bench.command(0, set("FS_GCS_TIMEOUT", 3.3)),
        [value(Param::GcsTimeout, 3.3)]
    );
    assert_eq!(bench.params().gcs_timeout(), Duration::from_millis(3300));
    assert_eq!(
        bench.command(0, set("FS_PILOT_TIMEOUT", 3.5)),
        [
            text(Severity::Warning, "FS_PILOT_TIMEOUT: range 0.1..3"),
            value(Param::PilotTimeout, 3.0)
        ]
    );
    assert_eq!(
        bench.command(0, set("FS_PILOT_TIMEOUT", 0.1)),
        [value(Param::PilotTimeout, 0.1)]
    );
    // ArduSub's 0 (off), 3 (depth hold) and 4 (surface) are not this vehicle's.
    for refused in [0.0, 3.0, 4.0] {
        assert_eq!(
            bench.command(0, set("FS_GCS_ENABLE", refused)),
            [
                text(Severity::Warning, "FS_GCS_ENABLE: range 1..2"),
                value(Param::GcsFailsafe, 2.0)
            ]
        );
    }
    assert_eq!(
        bench.command(0, set("LBV_GCS_NEUTRAL", 1.0)),
        [value(Param::GcsNeutral, 1.0)]
    );
    assert_eq!(
        bench.command(0, set("LBV_FRAME", 5.0)),
        [
            text(Severity::Warning, "LBV_FRAME: must be 4 or 6"),
            value(Param::Frame, 6.0)
        ]
    );
    assert_eq!(bench.command(0, set("LBV_FRAME", 4.0)), [value(Param::Frame, 4.0)]);
    assert_eq!(bench.params().frame(), FrameKind::Lbv200_4);
    assert_eq!(
        bench.command(0, set("LBV_POWER_CAP", 1.0)),
        [value(Param::PowerCap, 1.0)]
    );
    assert_eq!(
        bench.command(0, set("LBV_MTEST_MAX", 100.0)),
        [value(Param::MotorTestMax, 100.0)]
    );
    // A button function the vehicle has not (ArduSub's 5, manual mode) is refused as out of range is.
    assert_eq!(
        bench.command(0, set("BTN1_FUNCTION", 5.0)),
        [
            text(Severity::Warning, "BTN1_FUNCTION: must be 0, 3, 4, 42 or 43"),
            value(Param::Button1, 0.0)
        ]
    );
    assert_eq!(
        bench.command(0, set("BTN1_FUNCTION", 42.0)),
        [value(Param::Button1, 42.0)]
    );
    assert!(
        bench.command(0, set("LBV_NOTHING", 1.0)).is_empty(),
        "unknown name: no answer"
    );
    // The frame only while disarmed.
    bench.arm(0);
    assert_eq!(
        bench.command(0, set("LBV_FRAME", 6.0)),
        [
            text(Severity::Warning, "LBV_FRAME: disarm first"),
            value(Param::Frame, 4.0)
        ]
    );
    // A shorter heartbeat timeout applies at once.
    assert_eq!(
        bench.command(0, set("FS_GCS_TIMEOUT", 2.0)),
        [value(Param::GcsTimeout, 2.0)]
    );
    assert!(bench.orders(1999).1.is_empty());
    assert_eq!(bench.orders(2000).1.len(), 1);
    assert!(!bench.armed(2000));
}

const ARM_BUTTON: u16 = 1 << 6;
const DISARM_BUTTON: u16 = 1 << 4;
const GAIN_UP: u16 = 1 << 11;
const GAIN_DOWN: u16 = 1 << 12;

/// What a gain button's press says when it moves the gain to `percent`.
fn gain_moved(percent: u8) -> Vec<Outgoing> {
    vec![
        value(Param::Gain, f32::from(percent)),
        Outgoing::Message {
            message: Message::NamedValueFloat,
            first: 0,
        },
        gain_said(percent),
    ]
}

fn gain_said(percent: u8) -> Outgoing {
    text(Severity::Info, &format!("Pilot gain {percent} %"))
}

#[test]
fn arm_and_disarm_buttons_act_once_per_press() {
    let mut bench = Bench::new(VehicleConfig::default());
    bench.command(0, Command::Heartbeat);
    // The arm button (a gamepad's start): armed, with the command's text and no COMMAND_ACK.
    assert_eq!(bench.command(10, buttons(ARM_BUTTON)), [text(Severity::Info, "Armed")]);
    assert!(bench.armed(10));
    // Held: nothing more, however long, and through a disarm by command.
    assert!(bench.command(30, buttons(ARM_BUTTON)).is_empty());
    bench.command(40, Command::Arm(false));
    assert!(bench.command(50, buttons(ARM_BUTTON)).is_empty());
    assert!(!bench.armed(50), "a held arm button does not arm again");
    // Released and pressed again: armed again.
    assert!(bench.command(60, buttons(0)).is_empty());
    assert_eq!(bench.command(70, buttons(ARM_BUTTON)), [text(Severity::Info, "Armed")]);
    // The sticks of the same frames steer.
    bench.command(80, Command::Manual(ManualInput { x: 1000, ..NEUTRAL }, ARM_BUTTON));
    assert_eq!(bench.steps(80)[..4], [51; 4]);
    // The disarm button (back): every thruster stops; held, it says nothing more.
    assert_eq!(
        bench.command(90, buttons(DISARM_BUTTON)),
        [text(Severity::Info, "Disarmed")]
    );
    assert!(!bench.armed(90) && bench.steps(90) == [0; MAX_THRUSTERS]);
    assert!(bench.command(100, buttons(DISARM_BUTTON)).is_empty());
    // Pressed with an arm, the disarm wins.
    bench.command(110, buttons(0));
    assert!(bench.command(120, buttons(ARM_BUTTON | DISARM_BUTTON)).is_empty());
    assert!(!bench.armed(120));
    bench.command(130, buttons(0));
    bench.command(140, buttons(ARM_BUTTON));
    assert_eq!(
        bench.command(150, buttons(ARM_BUTTON | DISARM_BUTTON)),
        [text(Severity::Info, "Disarmed")]
    );
    // The disarm button stops a motor test, as the disarm command does.
    bench.command(160, buttons(0));
    bench.command(170, motor_test(1, 20, 1000));
    assert_eq!(
        bench.command(180, buttons(DISARM_BUTTON)),
        [text(Severity::Info, "Motor test 1 stopped")]
    );
    assert_eq!(bench.steps(180), [0; MAX_THRUSTERS]);
    // Another system's buttons are refused as its sticks are.
    bench.command(190, buttons(0));
    assert!(bench.command_from(200, OTHER, buttons(ARM_BUTTON)).is_empty());
    assert!(!bench.armed(200));
    assert_eq!(bench.vehicle.state(t(200)).refused, 1);
}

#[test]
fn an_arm_button_is_refused_as_the_arm_command_is_saying_why() {
    let mut bench = Bench::new(VehicleConfig::default());
    let press = |bench: &mut Bench, ms: u64, sticks: ManualInput| {
        bench.command(ms, Command::Manual(sticks, 0));
        bench.command(ms, Command::Manual(sticks, ARM_BUTTON))
    };
    let rejected = |why: &str| vec![text(Severity::Warning, &format!("Arm rejected: {why}"))];
    assert_eq!(press(&mut bench, 0, NEUTRAL), rejected("no ground station heartbeat"));
    bench.command(10, Command::Heartbeat);
    // The heave stick of the same frame, at a centre-zero ground station's 0.
    assert_eq!(
        press(&mut bench, 20, ManualInput { z: 0, ..NEUTRAL }),
        rejected("heave stick at 0, not 500")
    );
    bench.vehicle.hold_for_update(Some(UpdateHold::OnTrial(0)));
    assert_eq!(press(&mut bench, 30, NEUTRAL), rejected("T1 image on trial"));
    bench.vehicle.hold_for_update(None);
    bench.command(40, motor_test(2, 20, 1000));
    let mut said = vec![text(Severity::Info, "Motor test 2 stopped")];
    said.extend(rejected("motor test was running"));
    assert_eq!(press(&mut bench, 50, NEUTRAL), said);
    assert!(!bench.armed(50));
    assert_eq!(press(&mut bench, 60, NEUTRAL), [text(Severity::Info, "Armed")]);
    // Armed already: nothing to say, as for the command.
    assert!(press(&mut bench, 70, NEUTRAL).is_empty());
}

#[test]
fn gain_buttons_step_lbv_gain_within_its_limits_once_per_press() {
    let mut bench = Bench::new(VehicleConfig::default());
    bench.arm(0);
    bench.command(0, manual(1000, 0, 500, 0));
    assert_eq!(bench.steps(0)[..4], [51; 4], "50 %");
    // Up from 50 % in steps of 10 to 100 %, a press at a time; a held button does not repeat.
    let mut ms = 10;
    for percent in [60, 70, 80, 90, 100] {
        assert_eq!(bench.command(ms, buttons(GAIN_UP)), gain_moved(percent));
        assert!(bench.command(ms + 1, buttons(GAIN_UP)).is_empty());
        bench.command(ms + 2, buttons(0));
        ms += 10;
    }
    assert_eq!(bench.params().gain_percent(), 100);
    // Full surge is now full speed.
    bench.command(ms, manual(1000, 0, 500, 0));
    assert_eq!(bench.steps(ms)[..4], [102; 4]);
    // At the top: the press says where the gain stands, and changes nothing.
    assert_eq!(bench.command(ms, Command::Manual(NEUTRAL, GAIN_UP)), [gain_said(100)]);
    bench.command(ms + 1, buttons(0));
    // Down to 10 %, and no further.
    for percent in (1..=9).rev().map(|n| n * 10) {
        ms += 10;
        assert_eq!(bench.command(ms, buttons(GAIN_DOWN)), gain_moved(percent));
        bench.command(ms + 1, buttons(0));
    }
    assert_eq!(bench.command(ms + 10, buttons(GAIN_DOWN)), [gain_said(10)]);
    bench.command(ms + 11, buttons(0));
    // A gain set below the step by parameter is not raised by a down, and goes up from where it is.
    bench.command(ms + 20, set("LBV_GAIN", 5.0));
    assert_eq!(bench.command(ms + 30, buttons(GAIN_DOWN)), [gain_said(5)]);
    assert_eq!(bench.command(ms + 40, buttons(GAIN_UP)), gain_moved(15));
    // Up and down at once: both act, in button order.
    bench.command(ms + 50, buttons(0));
    let mut both = gain_moved(25);
    both.extend(gain_moved(15));
    assert_eq!(bench.command(ms + 60, buttons(GAIN_UP | GAIN_DOWN)), both);
    // Disarmed too: the gain is set on the surface.
    bench.command(ms + 70, Command::Arm(false));
    bench.command(ms + 80, buttons(0));
    assert_eq!(bench.command(ms + 90, buttons(GAIN_UP)), gain_moved(25));
}

#[test]
fn buttons_do_what_their_parameters_say() {
    // Arm on button 0 (a gamepad's A), nothing on 6, disarm on 15 as well as 4.
    let mut bench = Bench::with(VehicleConfig::default(), |p| {
        p.set(Param::Button0, 3);
        p.set(Param::Button6, 0);
        p.set(Param::Button15, 4);
    });
    bench.command(0, Command::Heartbeat);
    assert!(bench.command(10, buttons(ARM_BUTTON)).is_empty());
    assert_eq!(bench.command(20, buttons(1)), [text(Severity::Info, "Armed")]);
    assert_eq!(bench.command(30, buttons(1 << 15)), [text(Severity::Info, "Disarmed")]);
    // Changed over MAVLink, as QGroundControl's joystick setup does (INT8, the parameter's type).
    assert_eq!(
        bench.command(40, set("BTN15_FUNCTION", 42.0)),
        [value(Param::Button15, 42.0)]
    );
    bench.command(50, buttons(0));
    assert_eq!(bench.command(60, buttons(1 << 15)), gain_moved(60));
}

#[test]
fn unknown_commands_are_unsupported() {
    let mut bench = Bench::new(VehicleConfig::default());
    assert_eq!(
        bench.command(0, Command::Unsupported { command: 511 }),
        [ack(511, AckResult::Unsupported)]
    );
    assert!(!bench.vehicle.state(t(0)).console_alive, "only heartbeats are life");
    assert_eq!(bench.said.len(), 1);
}

#[test]
fn the_vehicle_task_refuses_an_arm_while_shared_holds_say_an_update_holds_it() {
    let _clock = lbv_sim::clock::take();
    let shared = Shared::new();
    let config = VehicleConfig::default();
    let drain = || core::iter::from_fn(|| shared.outbox.try_receive().ok()).collect::<Vec<_>>();
    let request = |command| Request { from: GCS, command };
    let script = async {
        elapse(Duration::from_millis(25)).await;
        // A thruster holds an update marked for its bootloader (its next reset swaps it in): no arm, so no order
        // that drives reaches it.
        shared.holds.set_thrusters(Some(crate::shared::UpdateHold::Marked(2)));
        shared.commands.send(request(Command::Heartbeat)).await;
        shared.commands.send(request(Command::Arm(true))).await;
        shared.commands.send(request(manual(1000, 0, 500, 0))).await;
        elapse(Duration::from_millis(30)).await;
        assert_eq!(
            drain(),
            [
                ack(ARM, AckResult::TemporarilyRejected),
                text(Severity::Warning, "Arm rejected: T3 holds an update marked")
            ]
        );
        let state = shared.vehicle.try_get().unwrap();
        assert!(!state.armed && !state.armable);
        assert_eq!(shared.orders.try_get(), Some(STOP));
        // The master's own hold comes first; once both are gone, the arm is taken.
        shared.holds.set_master(Some(crate::shared::UpdateHold::MasterOnTrial));
        shared.commands.send(request(Command::Arm(true))).await;
        elapse(Duration::from_millis(2)).await;
        assert_eq!(
            drain()[1],
            text(Severity::Warning, "Arm rejected: master image on trial")
        );
        shared.holds.set_master(None);
        shared.holds.set_thrusters(None);
        shared.commands.send(request(Command::Arm(true))).await;
        elapse(Duration::from_millis(2)).await;
        assert_eq!(drain(), [ack(ARM, AckResult::Accepted), text(Severity::Info, "Armed")]);
        assert!(shared.vehicle.try_get().unwrap().armed);
    };
    match block_on(select(vehicle_task(config, config.defaults(), &shared), script)) {
        Either::First(never) => match never {},
        Either::Second(()) => {}
    }
}

#[test]
fn vehicle_task_publishes_orders_state_settings_and_answers() {
    let _clock = lbv_sim::clock::take();
    let shared = Shared::new();
    let config = VehicleConfig::default();
    let mut settings = config.defaults();
    settings.params.set(Param::Gain, 100);
    let drain = || {
        let mut all = Vec::new();
        while let Ok(message) = shared.outbox.try_receive() {
            all.push(message);
        }
        all
    };
    let request = |command| Request { from: GCS, command };
    let script = async {
        elapse(Duration::from_millis(25)).await;
        assert_eq!(shared.orders.try_get(), Some(STOP));
        assert_eq!(
            shared.vehicle.try_get(),
            Some(VehicleState {
                armed: false,
                console_alive: false,
                refused: 0,
                armable: false,
                failsafe: false,
                param_type_mismatches: 0,
                operator: 255
            })
        );
        assert_eq!(
            shared.settings.try_get(),
            Some(settings),
            "the settings in force, at once"
        );
        let sent = Instant::now();
        shared.commands.send(request(Command::Heartbeat)).await;
        shared.commands.send(request(Command::Arm(true))).await;
        shared.commands.send(request(manual(1000, 0, 500, 0))).await;
        elapse(Duration::from_millis(2)).await;
        assert_eq!(drain(), [ack(ARM, AckResult::Accepted), text(Severity::Info, "Armed")]);
        assert_eq!(
            shared.vehicle.try_get(),
            Some(VehicleState {
                armed: true,
                console_alive: true,
                refused: 0,
                armable: true,
                failsafe: false,
                param_type_mismatches: 0,
                operator: 255
            })
        );
        let orders = shared.orders.try_get().unwrap();
        assert_eq!(orders.map(|o| o.speed.step()), [102, 102, 102, 102, 0, 0, 0, 0]);

        shared.commands.send(request(Command::ParamRequestList)).await;
        elapse(Duration::from_millis(2)).await;
        assert_eq!(drain(), [Outgoing::ParamList]);
        shared.commands.send(request(set("LBV_GAIN", 60.0))).await;
        elapse(Duration::from_millis(2)).await;
        assert_eq!(shared.settings.try_get().map(|s| s.params.gain_percent()), Some(60));

        // Everything falls silent: the sticks go neutral after FS_PILOT_TIMEOUT and the vehicle disarms
        // after FS_GCS_TIMEOUT, each within one 50 Hz tick of the request's arrival (the clock moves in 1 ms
        // steps).
        let mut neutral_at = None;
        let mut disarmed_at = None;
        while disarmed_at.is_none() {
            elapse(Duration::from_millis(1)).await;
            let moving = shared.orders.try_get().unwrap().iter().any(|o| !o.speed.is_zero());
            if neutral_at.is_none() && !moving {
                neutral_at = Some(Instant::now() - sent);
            }
            if !shared.vehicle.try_get().unwrap().armed {
                disarmed_at = Some(Instant::now() - sent);
            }
        }
        let (neutral, disarmed) = (neutral_at.unwrap(), disarmed_at.unwrap());
        assert!(
            neutral >= Duration::from_millis(3000) && neutral <= Duration::from_millis(3022),
            "{neutral:?}"
        );
        assert!(
            disarmed >= Duration::from_millis(5000) && disarmed <= Duration::from_millis(5022),
            "{disarmed:?}"
        );
        assert_eq!(shared.orders.try_get(), Some(STOP));
        let said = drain();
        assert_eq!(failsafes(&said).len(), 2, "{said:?}");

        // A motor test through the task, ending on time.
        shared.commands.send(request(Command::Heartbeat)).await;
        shared.commands.send(request(motor_test(2, 10, 100))).await;
        elapse(Duration::from_millis(2)).await;
        assert_eq!(shared.orders.try_get().unwrap()[1].speed.step(), 10);
        elapse(Duration::from_millis(120)).await;
        assert_eq!(shared.orders.try_get(), Some(STOP));
        let said = drain();
        assert_eq!(said.len(), 4, "{said:?}");
        assert_eq!(said[3], text(Severity::Info, "Motor test 2 done"));
    };
    match block_on(select(vehicle_task(config, settings, &shared), script)) {
        Either::First(never) => match never {},
        Either::Second(()) => {}
    }
}
