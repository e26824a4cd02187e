//! One thruster on the bench: the controller as it ships (`thruster_fw::run` and `run_commutation`, with the
//! image's own configuration for its family) on simulated ports, with the plant model behind them.
//!
//! The board is two parts: what is around the controller ([`ThrusterIo`]: the motor, the power stage, the watchdog
//! hardware), which lives as long as the bench, and the controller itself (its tasks and their channels), which a
//! power cycle drops and boots afresh.

use core::cell::{Cell, RefCell};
use core::ops::Deref;
use std::rc::Rc;

use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::Instant;
use lbv_sim::i2c::{Bus, DeviceId};
use lbv_sim::{Executor, TaskId};
use thruster_fw::commutation::{BridgeDrive, COAST};
use thruster_fw::faults::VolatileLatch;
use thruster_fw::hall::HallState;
use thruster_fw::tasks::{Bridge, HallSensors, RawSample, Sensors, Shared, Watchdog};
use thruster_fw::{Config, Duty, Ports};
use tmc_proto::{Family, MotorKind};

use super::plant::{MotorParams, Plant};

/// The power stage's overcurrent comparator trips TIM1's break input above this phase current, cutting the rest of
/// the PWM period: on average the current is held at the limit (cycle-by-cycle current limiting).
const CURRENT_LIMIT_A: f64 = 8.0;

/// What is around one controller: the motor and its sensors, the bridge, the watchdog.
pub struct ThrusterIo {
    /// The motor, propeller and sensors.
    pub plant: RefCell<Plant>,
    /// What the commutation task drives.
    drive: Cell<(BridgeDrive, Duty)>,
    /// Raised by the plant on every hall change.
    hall_edge: Signal<NoopRawMutex, ()>,
    /// When the watchdog was last fed.
    last_feed: Cell<Instant>,
    /// Times the watchdog would have reset the controller.
    pub watchdog_bites: Cell<u32>,
    /// The fraction of the commanded duty the break input lets through (1.0 when not limiting).
    current_limit: Cell<f64>,
    /// Steps during which the break input limited the current.
    pub limited_steps: Cell<u64>,
}

/// A thruster: its controller's configuration, its place on the bus, what is around it and, while powered, the
/// controller's tasks.
pub struct ThrusterBoard {
    /// The controller's build-time configuration: the image's, for this family.
    pub config: Config,
    /// What is around the controller.
    pub io: Rc<ThrusterIo>,
    /// The bus it hangs on, and its place there.
    bus: Bus,
    /// Its slave port on the bus.
    pub device: DeviceId,
    /// The controller's task channels, fresh at every boot.
    shared: Rc<Shared>,
    tasks: Vec<TaskId>,
}

impl Deref for ThrusterBoard {
    type Target = ThrusterIo;

    fn deref(&self) -> &ThrusterIo {
        &self.io
    }
}

impl ThrusterBoard {
    /// A thruster of `family` at `device` on `bus`, its motor at `angle` (mechanical radians); not powered yet.
    pub fn new(family: Family, bus: &Bus, device: DeviceId, angle: f64) -> Self {
        Self {
            config: Config::reference(family, MotorKind::Brushless),
            io: Rc::new(ThrusterIo {
                plant: RefCell::new(Plant::new(MotorParams::THRUSTER).with_angle(angle)),
                drive: Cell::new((COAST, Duty::ZERO)),
                hall_edge: Signal::new(),
                last_feed: Cell::new(Instant::from_ticks(0)),
                watchdog_bites: Cell::new(0),
                current_limit: Cell::new(1.0),
                limited_steps: Cell::new(0),
            }),
            bus: bus.clone(),
            device,
            shared: Rc::new(Shared::new()),
            tasks: Vec::new(),
        }
    }

    /// Power up: the controller boots with fresh state and its slave port answers again. A powered controller is
    /// left as it is.
    pub fn boot(&mut self, executor: &mut Executor<'static>) {
        if self.powered() {
            return;
        }
        self.bus.set_powered(self.device, true);
        self.io.last_feed.set(Instant::now());
        let Some(port) = self.bus.target(self.device) else {
            return;
        };
        let ports = Ports {
            i2c: port,
            sensors: Adc {
                io: self.io.clone(),
                config: self.config.clone(),
            },
            watchdog: Dog(self.io.clone()),
            // Every bench boot follows a power cut: the latches start empty.
            latch: VolatileLatch::default(),
        };
        let (config, shared) = (self.config.clone(), self.shared.clone());
        let run = executor.spawn(async move {
            thruster_fw::run(ports, &config, &shared).await;
        });
        let (halls, stage) = (Halls(self.io.clone()), Stage(self.io.clone()));
        let (config, shared) = (self.config.clone(), self.shared.clone());
        let commutation = executor.spawn(async move {
            thruster_fw::run_commutation(halls, stage, &config, &shared).await;
        });
        self.tasks = vec![run, commutation];
    }

    /// Cut the power: the controller stops where it is, the bridge coasts, the slave port stops answering, and
    /// everything the controller knew is gone.
    pub fn power_off(&mut self, executor: &mut Executor<'static>) {
        for task in self.tasks.drain(..) {
            executor.remove(task);
        }
        self.bus.set_powered(self.device, false);
        self.io.drive.set((COAST, Duty::ZERO));
        self.shared = Rc::new(Shared::new());
    }

    /// Whether the controller is powered.
    pub fn powered(&self) -> bool {
        !self.tasks.is_empty()
    }

    /// The controller's task channels (its fault verdict, duty and status frame).
    pub fn shared(&self) -> &Shared {
        &self.shared
    }

    /// How often the controller re-initialised its slave port.
    pub fn slave_resets(&self) -> u32 {
        self.bus.target_resets(self.device)
    }

    /// Advance the motor by `dt` on `supply_v` at `now`, raising a hall edge when the halls change; keep the
    /// watchdog's count.
    pub fn step(&self, now: Instant, dt: f64, supply_v: f64) {
        self.io.step(dt, supply_v);
        let io = &self.io;
        if self.powered() && now - io.last_feed.get() > self.config.watchdog.timeout {
            io.watchdog_bites.set(io.watchdog_bites.get() + 1);
            io.last_feed.set(now);
        }
    }
}

impl ThrusterIo {
    /// The drive the bridge applies now.
    pub fn drive(&self) -> (BridgeDrive, Duty) {
        self.drive.get()
    }

    fn step(&self, dt: f64, supply_v: f64) {
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
    }
}

struct Halls(Rc<ThrusterIo>);

impl HallSensors for Halls {
    async fn wait_for_edge(&mut self) {
        self.0.hall_edge.wait().await;
    }

    fn read(&mut self) -> HallState {
        self.0.plant.borrow().hall_state()
    }
}

struct Stage(Rc<ThrusterIo>);

impl Bridge for Stage {
    fn apply(&mut self, drive: BridgeDrive, duty: Duty) {
        self.0.drive.set((drive, duty));
    }
}

/// The ADC, reading the plant through the controller's sensors.
struct Adc {
    io: Rc<ThrusterIo>,
    config: Config,
}

impl Sensors for Adc {
    async fn sample(&mut self) -> RawSample {
        let plant = self.io.plant.borrow();
        let config = &self.config;
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

struct Dog(Rc<ThrusterIo>);

impl Watchdog for Dog {
    fn feed(&mut self) {
        self.0.last_feed.set(Instant::now());
    }
}
