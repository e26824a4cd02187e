//! One thruster on the bench: the real controller core (thruster-fw's five tasks) on simulated ports, with the
//! plant model behind them.

use core::cell::{Cell, RefCell};

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant};
use thruster_fw::Duty;
use thruster_fw::commutation::{BridgeDrive, COAST};
use thruster_fw::faults::VolatileLatch;
use thruster_fw::hall::HallState;
use thruster_fw::tasks::{
    Bridge, Config, HallSensors, RawSample, Sensors, Shared, Watchdog, commutation_task, control_task, fault_task,
    health_task, i2c_task,
};
use tmc_proto::{Family, MotorKind};

use super::executor::{Executor, TaskId};
use super::i2c::{SlaveLine, SlavePort};
use super::plant::{MotorParams, Plant};

/// The power stage's overcurrent comparator trips TIM1's break input above this phase current, cutting the rest of
/// the PWM period: on average the current is held at the limit (cycle-by-cycle current limiting).
const CURRENT_LIMIT_A: f64 = 8.0;

/// How often the watchdog task checks; the independent watchdog bites after `WATCHDOG_TIMEOUT` unfed.
const WATCHDOG_FEED: Duration = Duration::from_millis(50);
const WATCHDOG_TIMEOUT: Duration = Duration::from_millis(250);

/// A thruster: its controller's configuration and channels, its bus line, its motor.
pub struct Thruster {
    /// The controller's build-time configuration.
    pub config: Config,
    /// The controller's task channels; a reset starts it afresh.
    shared: Cell<&'static Shared>,
    /// Its end of the I2C bus.
    pub line: &'static SlaveLine,
    /// The motor, propeller and sensors.
    pub plant: RefCell<Plant>,
    /// What the commutation task drives.
    drive: Cell<(BridgeDrive, Duty)>,
    /// Raised by the plant on every hall change.
    hall_edge: Signal<CriticalSectionRawMutex, ()>,
    /// When the watchdog was last fed, and whether it ever went hungry past its timeout.
    last_feed: Cell<Instant>,
    /// Times the watchdog would have reset the controller.
    pub watchdog_bites: Cell<u32>,
    /// The fraction of the commanded duty the break input lets through (1.0 when not limiting).
    current_limit: Cell<f64>,
    /// Steps during which the break input limited the current.
    pub limited_steps: Cell<u64>,
    tasks: RefCell<Vec<TaskId>>,
}

impl Thruster {
    /// A thruster of `family` with its motor at `angle` (mechanical radians), not yet running.
    pub fn new(family: Family, angle: f64) -> &'static Thruster {
        Box::leak(Box::new(Thruster {
            config: Config::reference(family, MotorKind::Brushless),
            shared: Cell::new(Box::leak(Box::new(Shared::new()))),
            line: Box::leak(Box::new(SlaveLine::default())),
            plant: RefCell::new(Plant::new(MotorParams::THRUSTER).with_angle(angle)),
            drive: Cell::new((COAST, Duty::ZERO)),
            hall_edge: Signal::new(),
            last_feed: Cell::new(Instant::from_ticks(0)),
            watchdog_bites: Cell::new(0),
            current_limit: Cell::new(1.0),
            limited_steps: Cell::new(0),
            tasks: RefCell::new(Vec::new()),
        }))
    }

    /// Start the controller's tasks (power-up).
    pub fn start(&'static self, executor: &mut Executor<'static>) {
        let shared = self.shared.get();
        self.last_feed.set(Instant::now());
        let ids = [
            executor.spawn(async move {
                i2c_task(
                    &mut SlavePort::new(self.line),
                    self.config.family,
                    self.config.motor,
                    shared,
                )
                .await;
            }),
            executor.spawn(async move {
                let (motor, pole_pairs) = (self.config.motor, self.config.pole_pairs);
                commutation_task(&mut Halls(self), &mut Stage(self), motor, pole_pairs, shared).await;
            }),
            executor.spawn(async move {
                // A bench reset is a power cycle: the latches start empty.
                fault_task(&mut Adc(self), &mut VolatileLatch::default(), &self.config, shared).await;
            }),
            executor.spawn(async move {
                control_task(&self.config, shared).await;
            }),
            executor.spawn(async move {
                health_task(&mut Dog(self), WATCHDOG_FEED, shared).await;
            }),
        ];
        self.tasks.borrow_mut().extend(ids);
    }

    /// Power the controller off: its tasks stop where they are and the bridge coasts.
    pub fn power_off(&self, executor: &mut Executor<'static>) {
        for id in self.tasks.borrow_mut().drain(..) {
            executor.remove(id);
        }
        self.drive.set((COAST, Duty::ZERO));
        // Everything the controller knew is lost; it boots with fresh state.
        self.shared.set(Box::leak(Box::new(Shared::new())));
    }

    /// The drive the bridge applies now.
    pub fn drive(&self) -> (BridgeDrive, Duty) {
        self.drive.get()
    }

    /// Advance the motor by `dt` on `supply_v` at `now`, raising a hall edge when the halls change.
    pub fn step(&self, now: Instant, dt: f64, supply_v: f64) {
        let (drive, duty) = self.drive.get();
        let passed = Duty::new_saturating((f64::from(duty.value()) * self.current_limit.get()).round() as i32);
        let mut plant = self.plant.borrow_mut();
        if plant.step(dt, drive, passed, supply_v) {
            self.hall_edge.signal(());
        }
        // The hardware break acts within the PWM period; on average it scales the duty to hold the limit.
        let current = plant.phase_current_a();
        drop(plant);
        let scale = self.current_limit.get();
        if current > CURRENT_LIMIT_A {
            self.current_limit.set((scale * CURRENT_LIMIT_A / current).max(0.0));
            self.limited_steps.set(self.limited_steps.get() + 1);
        } else {
            self.current_limit.set((scale * 1.05).min(1.0));
        }
        if now - self.last_feed.get() > WATCHDOG_TIMEOUT && !self.tasks.borrow().is_empty() {
            self.watchdog_bites.set(self.watchdog_bites.get() + 1);
            self.last_feed.set(now);
        }
    }

    /// The controller's task channels (its fault verdict, duty and status frame).
    pub fn shared(&self) -> &'static Shared {
        self.shared.get()
    }
}

struct Halls(&'static Thruster);

impl HallSensors for Halls {
    async fn wait_for_edge(&mut self) {
        self.0.hall_edge.wait().await;
    }

    fn read(&mut self) -> HallState {
        self.0.plant.borrow().hall_state()
    }
}

struct Stage(&'static Thruster);

impl Bridge for Stage {
    fn apply(&mut self, drive: BridgeDrive, duty: Duty) {
        self.0.drive.set((drive, duty));
    }
}

struct Adc(&'static Thruster);

impl Sensors for Adc {
    async fn sample(&mut self) -> RawSample {
        let plant = self.0.plant.borrow();
        let config = &self.0.config;
        let decicelsius = (plant.winding_c() * 10.0)
            .round()
            .clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16;
        let counts = plant.phase_current_a() * 1000.0 / f64::from(config.current.milliamps_per_count);
        RawSample {
            water: config.water.raw_at(plant.water_ohms),
            temperature: config.ntc.raw_at(decicelsius),
            current: (f64::from(config.current.offset_raw) + counts)
                .round()
                .clamp(0.0, 4095.0) as u16,
        }
    }
}

struct Dog(&'static Thruster);

impl Watchdog for Dog {
    fn feed(&mut self) {
        self.0.last_feed.set(Instant::now());
    }
}
