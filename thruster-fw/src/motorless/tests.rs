//! The model alone, then the controller's own tasks running on it on virtual time.

use super::*;
use crate::commutation::drive_for;
use crate::control::LinkUpdate;
use crate::faults::VolatileLatch;
use crate::hall::{FORWARD_SEQUENCE, Transition, transition};
use crate::ports::{Board, Ports, Watchdog};
use crate::shared::Shared;
use crate::sim::SlavePort;
use crate::trial::Confirmed;
use crate::update::NoUpdate;
use core::marker::PhantomData;
use core::ops::Deref;
use lbv_sim::i2c::{Bus, Route, Timing};
use lbv_sim::{Clock, Executor, clock};
use std::rc::Rc;
use tmc_proto::{Family, Faults, MotorKind, Order, Speed, Status};

const CONFIG: Config = Config::reference(Family::SeaBotix, MotorKind::Brushless);

fn ms(value: u64) -> Instant {
    Instant::from_millis(value)
}

fn driven(duty: i32) -> (BridgeDrive, Duty) {
    let duty = Duty::new_saturating(duty);
    (drive_for(FORWARD_SEQUENCE[0], duty), duty)
}

#[test]
fn the_feed_forward_duty_holds_full_scale_and_the_speed_settles_with_its_time_constant() {
    let mut model = MotorModel::new(&CONFIG);
    let (drive, duty) = driven(i32::from(CONFIG.speed.full_scale_duty));
    model.drive(ms(0), drive, duty);
    model.advance(ms(50));
    let one_tau = model.rpm();
    assert!(
        (2830.0..2860.0).contains(&one_tau),
        "63 % of 4500 after one time constant: {one_tau}"
    );
    model.advance(ms(1000));
    assert!((model.rpm() - 4500.0).abs() < 1.0, "{}", model.rpm());
    assert_eq!(model.current_milliamps(), 3000, "the propeller's 3 A at full scale");
    // Coasting: the speed decays with the same time constant.
    model.drive(ms(1000), COAST, duty);
    model.advance(ms(1300));
    assert!(model.rpm() < 15.0, "{}", model.rpm());
}

#[test]
fn the_halls_step_through_the_sequence_in_the_direction_of_the_duty() {
    for (duty, expected) in [(5000, Transition::Forward), (-5000, Transition::Reverse)] {
        let mut model = MotorModel::new(&CONFIG);
        let (drive, duty) = driven(duty);
        model.drive(ms(0), drive, duty);
        let mut last = model.hall_state();
        let mut edges = 0;
        // 50 us steps: never more than one sector per step at these speeds.
        for step in 1..=20_000u64 {
            model.advance(Instant::from_micros(step * 50));
            let state = model.hall_state();
            if state != last {
                assert_eq!(transition(last, state), expected, "at step {step}");
                edges += 1;
                last = state;
            }
        }
        // About 2800 rpm for most of the second, 4 pole pairs, 6 edges per electrical turn.
        assert!((900..1200).contains(&edges), "{edges} edges");
    }
}

#[test]
fn the_next_edge_is_predicted_to_within_a_few_microseconds() {
    let mut model = MotorModel::new(&CONFIG);
    let (drive, duty) = driven(8000);
    model.drive(ms(0), drive, duty);
    model.advance(ms(2000));
    for _ in 0..50 {
        let before = model.hall_state();
        let wait = model.until_next_edge().expect("turning");
        assert!(wait < Duration::from_micros(700), "{wait:?}");
        let mut early = model;
        early.advance(model.at + wait - Duration::from_micros(4));
        assert_eq!(early.hall_state(), before, "not before the edge");
        model.advance(model.at + wait);
        assert_ne!(model.hall_state(), before, "just after it");
    }
    assert_eq!(
        MotorModel::new(&CONFIG).until_next_edge(),
        None,
        "at rest there is none"
    );
}

#[test]
fn a_held_rotor_stands_still_and_draws_current() {
    let mut model = MotorModel::new(&CONFIG);
    let (drive, duty) = driven(5000);
    model.drive(ms(0), drive, duty);
    model.advance(ms(500));
    model.hold(ms(500), true);
    let (angle, hall) = (model.angle_deg, model.hall_state());
    model.advance(ms(900));
    assert_eq!((model.rpm(), model.angle_deg, model.hall_state()), (0.0, angle, hall));
    assert_eq!(model.until_next_edge(), None);
    assert_eq!(model.current_milliamps(), 5000, "10 A at full duty, held");
    model.hold(ms(900), false);
    model.advance(ms(1000));
    assert!(model.rpm() > 1000.0, "turns again once let go");
}

#[test]
fn time_going_backwards_changes_nothing() {
    let mut model = MotorModel::new(&CONFIG);
    let (drive, duty) = driven(5000);
    model.drive(ms(10), drive, duty);
    model.advance(ms(100));
    let before = model;
    model.advance(ms(50));
    assert_eq!(model, before);
    assert_eq!(wrap_degrees(-0.0001), 359.9999);
    assert_eq!(wrap_degrees(720.5), 0.5);
    assert_eq!(wrap_degrees(f32::NAN), 0.0);
}

// ---------------------------------------------------------------------------------------------------------------
// The controller's tasks on the model

/// The water sensor of a dry housing: the node reads 0.
struct Dry;

impl WaterInput for Dry {
    async fn water(&mut self) -> u16 {
        0
    }
}

/// The user button, as the test sets it.
struct Button(Rc<RigIo>);

impl HoldInput for Button {
    fn held(&mut self) -> bool {
        self.0.button.get()
    }
}

/// What the rig's ports share with the test.
struct RigIo {
    shared: Shared,
    motorless: Motorless,
    button: Cell<bool>,
    orders: Cell<u32>,
    zero_orders: Cell<u32>,
}

/// A watchdog nobody checks.
struct Unwatched;

impl Watchdog for Unwatched {
    fn feed(&mut self) {}
}

/// The rig's ports: the sensors of the model in `'a`, the rest as the emulated Cortex-M4 has them (no
/// bootloader, no update).
struct RigBoard<'a>(PhantomData<&'a Motorless>);

impl<'a> Board for RigBoard<'a> {
    type I2c = SlavePort;
    type Sensors = ModelSensors<'a, Dry, Button>;
    type Watchdog = Unwatched;
    type Latch = VolatileLatch;
    type Boot = Confirmed;
    type Dfu = NoUpdate;
    type Updater = NoUpdate;
}

/// The controller as it ships ([`crate::run`], [`crate::run_commutation`]) on the model, with a bus nobody talks
/// on: the test stands in for the I2C task and publishes the master's orders itself.
struct Rig {
    io: Rc<RigIo>,
    _bus: Bus,
    executor: Executor<'static>,
    clock: Clock,
}

impl Deref for Rig {
    type Target = RigIo;

    fn deref(&self) -> &RigIo {
        &self.io
    }
}

impl Rig {
    /// Start the controller at virtual time 0.
    fn new() -> Self {
        let clock = clock::take();
        let io = Rc::new(RigIo {
            shared: Shared::new(),
            motorless: Motorless::new(MotorModel::new(&CONFIG)),
            button: Cell::new(false),
            orders: Cell::new(0),
            zero_orders: Cell::new(0),
        });
        let bus = Bus::new(Timing::new(CONFIG.bus.frequency_hz, CONFIG.bus.timeout));
        let port = bus.target(bus.attach_target(CONFIG.family.address(), Route::Direct));
        let mut executor = Executor::new();
        let controller = io.clone();
        executor.spawn(async move {
            let Some(port) = port else { return };
            let ports = Ports::<RigBoard<'_>> {
                i2c: SlavePort(port),
                sensors: ModelSensors::new(&controller.motorless, &CONFIG, Dry, Button(controller.clone())),
                watchdog: Unwatched,
                latch: VolatileLatch::default(),
                boot: Confirmed,
                dfu: NoUpdate,
                updater: NoUpdate,
            };
            crate::run(ports, &CONFIG, &controller.shared).await;
        });
        let controller = io.clone();
        executor.spawn(async move {
            let halls = ModelHalls::new(&controller.motorless);
            let bridge = ModelBridge(&controller.motorless);
            crate::run_commutation(halls, bridge, &CONFIG, &controller.shared).await;
        });
        Self {
            io,
            _bus: bus,
            executor,
            clock,
        }
    }

    /// A valid order from the master, as the I2C task publishes it.
    fn order(&self, step: i8) {
        self.orders.set(self.orders.get() + 1);
        if step == 0 {
            self.zero_orders.set(self.zero_orders.get() + 1);
        }
        self.shared.link.sender().send(LinkUpdate {
            order: Order::new(Speed::new(step).unwrap()),
            orders: self.orders.get(),
            zero_orders: self.zero_orders.get(),
            at: Instant::now(),
            refused_since: None,
        });
    }

    /// The status the I2C task would answer with now.
    fn status(&self) -> Status {
        let frame = self.shared.status.try_get().expect("a status is ready");
        Status::decode(Family::SeaBotix, frame.as_bytes()).unwrap().status
    }

    fn speed(&self) -> i8 {
        let Status::SeaBotix(status) = self.status() else {
            unreachable!()
        };
        status.speed.step()
    }

    /// Let `duration` pass in 20 us steps, keeping the link alive with a read every 10 ms.
    fn elapse(&mut self, duration: Duration) {
        let end = Instant::now() + duration;
        while Instant::now() < end {
            self.executor
                .run_for(&self.clock, Duration::from_micros(20), Duration::from_micros(20));
            if Instant::now().as_micros().is_multiple_of(10_000)
                && let Some(mut link) = self.shared.link.try_get()
            {
                link.at = Instant::now();
                self.shared.link.sender().send(link);
            }
        }
    }
}

#[test]
fn the_speed_loop_drives_the_model_to_every_order_and_reports_it() {
    let mut rig = Rig::new();
    rig.elapse(Duration::from_millis(10));
    for step in [1, 2, 30, 60, 102, -1, -60, -102, 0] {
        rig.order(step);
        rig.elapse(Duration::from_millis(800));
        let reported = rig.speed();
        assert!(
            (i16::from(reported) - i16::from(step)).abs() <= 1,
            "ordered {step}, reported {reported}"
        );
        assert!(rig.status().faults().is_empty(), "{:?}", rig.status());
    }
    let hall = rig.shared.hall.try_get().unwrap();
    assert_eq!(hall.illegal_transitions(), 0, "every modelled edge is a legal one");
}

#[test]
fn the_current_shows_in_the_status() {
    let mut rig = Rig::new();
    rig.order(60);
    rig.elapse(Duration::from_millis(800));
    let Status::SeaBotix(status) = rig.status() else {
        unreachable!()
    };
    // 2647 rpm: 3 A x (2647 / 4500)^2 = 1.04 A.
    assert!((9..=11).contains(&status.current_deciamps), "{status:?}");
    assert_eq!(status.temperature_c, 25);
    rig.order(0);
    rig.elapse(Duration::from_millis(800));
    let Status::SeaBotix(status) = rig.status() else {
        unreachable!()
    };
    assert_eq!(status.current_deciamps, 0);
}

#[test]
fn holding_the_button_stalls_the_motor_and_a_zero_order_clears_it() {
    let mut rig = Rig::new();
    rig.order(60);
    rig.elapse(Duration::from_millis(800));
    rig.button.set(true);
    let held_at = Instant::now();
    while !rig.status().faults().contains(Faults::STALL) {
        rig.elapse(Duration::from_millis(1));
        assert!(held_at.elapsed() < Duration::from_secs(1), "no stall");
    }
    let after = held_at.elapsed().as_millis();
    // The window counts the last pulses before the hold: it trips 400 ms after the last edge.
    assert!((390..=430).contains(&after), "stall after {after} ms");
    rig.elapse(Duration::from_millis(5));
    assert_eq!(rig.motorless.now().duty, Duty::ZERO, "stalled: nothing driven");
    rig.button.set(false);
    rig.elapse(Duration::from_millis(100));
    assert!(
        rig.status().faults().contains(Faults::STALL),
        "latched until a zero order"
    );
    rig.order(0);
    rig.elapse(Duration::from_millis(5));
    assert!(rig.status().faults().is_empty());
    rig.order(60);
    rig.elapse(Duration::from_millis(800));
    assert!((59..=61).contains(&rig.speed()));
}
