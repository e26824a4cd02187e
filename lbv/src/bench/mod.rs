//! The virtual bench: the master core, the thruster cores and a battery board, wired by simulated buses, with a
//! plant model behind every thruster, all on one virtual clock.
//!
//! Each step of [`STEP`] of virtual time: the firmware tasks that were woken run until none is ready, then the
//! motors, the battery and the ground station move by one step, then the clock advances. The same seed gives the
//! same run, bit for bit.

pub mod battery;
pub mod executor;
pub mod ground;
pub mod i2c;
pub mod master;
pub mod plant;
pub mod plot;
pub mod thruster;
pub mod trace;
pub mod udp;

use core::cell::RefCell;

use embassy_time::{Duration, Instant, MockDriver};
use lbv_master_fw::acceptance::AcceptanceConfig;
use lbv_master_fw::thrusters::ThrusterSlot;
use tmc_proto::Family;

use battery::BatteryBoard;
use executor::Executor;
use ground::GroundStation;
use i2c::{BusSlave, BusWorld};
use master::Master;
use thruster::Thruster;
use trace::{Event, Sample, ThrusterSample, Trace};

/// The plant and bus step.
pub const STEP: Duration = Duration::from_micros(50);
/// How often the trace records a sample.
pub const SAMPLE_PERIOD: Duration = Duration::from_millis(10);
/// What the vehicle's electronics draw besides the thrusters, A.
const HOTEL_LOAD_A: f64 = 0.6;

/// What to build.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BenchConfig {
    /// One family per thruster, in table order; each hangs on its own TCA9548A channel.
    pub families: Vec<Family>,
    /// Seeds the motors' starting positions and any random choices of a scenario.
    pub seed: u64,
    /// The two-board bench instead of the vehicle: every thruster wired to the bus directly (no TCA9548A) and the
    /// master running its acceptance test instead of polling.
    pub acceptance: bool,
}

impl BenchConfig {
    /// An LBV300-6: six SeaBotix thrusters.
    pub fn lbv300(seed: u64) -> Self {
        Self {
            families: vec![Family::SeaBotix; 6],
            seed,
            acceptance: false,
        }
    }
}

/// A small deterministic random source (xorshift64*), so that a seed fixes a run.
#[derive(Debug, Clone)]
pub struct Random(u64);

impl Random {
    /// From a seed (any value).
    pub fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// A number in 0..n (0 when n is 0).
    pub fn below(&mut self, n: u64) -> u64 {
        if n == 0 { 0 } else { self.next_u64() % n }
    }

    /// A number in 0.0..1.0.
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Something that watches the samples as they are recorded.
pub type Monitor = Box<dyn FnMut(&Sample)>;

/// Where the master's console output goes when an outside ground station has the link.
pub type ConsoleSink = Box<dyn FnMut(&[u8])>;

/// One vehicle on the bench.
pub struct Bench {
    executor: Executor<'static>,
    /// The thrusters, in table order.
    pub thrusters: Vec<&'static Thruster>,
    /// The master node.
    pub master: &'static Master,
    /// The battery board.
    pub battery: BatteryBoard,
    /// The operator's ground station.
    pub ground: GroundStation,
    /// What the run recorded.
    pub trace: Trace,
    /// Random choices of the scenario.
    pub random: Random,
    texts_seen: usize,
    next_sample: Instant,
    steps: u64,
    busy_rounds: u32,
    /// Extra ground-station bytes a UDP link or a scenario queued.
    outgoing: Vec<u8>,
    /// Called with every sample as it is recorded (the live view).
    pub monitor: Option<Monitor>,
    /// Set when an outside ground station has the console link (`lbv bench --udp`): the master's output goes
    /// here instead of to [`Bench::ground`], which then sends nothing; the outside station's bytes come in
    /// through [`Bench::send`].
    pub console_sink: Option<ConsoleSink>,
}

impl Bench {
    /// Build the vehicle and power it up at virtual time 0. One bench runs at a time: the virtual clock is one per
    /// process.
    pub fn new(config: &BenchConfig) -> Self {
        MockDriver::get().reset();
        let mut random = Random::new(config.seed);
        let mut executor = Executor::default();
        let thrusters: Vec<&'static Thruster> = config
            .families
            .iter()
            .map(|family| Thruster::new(*family, random.unit() * core::f64::consts::TAU))
            .collect();
        let channel = |channel: u8| (!config.acceptance).then_some(channel);
        let table: &'static [ThrusterSlot] = Box::leak(
            (0u8..)
                .zip(&config.families)
                .map(|(index, family)| match channel(index) {
                    Some(channel) => ThrusterSlot::behind_mux(0, channel, *family),
                    None => ThrusterSlot::direct(0, *family),
                })
                .collect::<Vec<_>>()
                .into_boxed_slice(),
        );
        let bus = BusWorld {
            slaves: (0u8..)
                .zip(&thrusters)
                .map(|(index, thruster)| BusSlave {
                    family: thruster.config.family,
                    channel: channel(index),
                    line: thruster.line,
                    powered: true,
                    corrupt: 0,
                    corrupt_orders: 0,
                    out_of_range_orders: false,
                })
                .collect(),
            mux_fitted: !config.acceptance,
            ..BusWorld::default()
        };
        let master = if config.acceptance {
            Master::start_acceptance(table, bus, &mut executor, AcceptanceConfig::DEFAULT)
        } else {
            Master::start(table, bus, &mut executor)
        };
        for thruster in &thrusters {
            thruster.start(&mut executor);
        }
        let mut battery = BatteryBoard::default();
        battery.step(0.0, HOTEL_LOAD_A);
        Self {
            executor,
            thrusters,
            master,
            battery,
            ground: GroundStation::default(),
            trace: Trace::default(),
            random,
            texts_seen: 0,
            next_sample: Instant::from_ticks(0),
            steps: 0,
            busy_rounds: 0,
            outgoing: Vec::new(),
            monitor: None,
            console_sink: None,
        }
    }

    /// Virtual time now.
    pub fn now(&self) -> Instant {
        Instant::now()
    }

    /// Seconds of virtual time now.
    pub fn seconds(&self) -> f64 {
        Instant::now().as_micros() as f64 / 1e6
    }

    /// Note something in the trace (an injected fault, a scenario step).
    pub fn note(&mut self, text: impl Into<String>) {
        let t = self.seconds();
        self.trace.events.push(Event { t, text: text.into() });
    }

    /// Send bytes to the master's console as the ground station.
    pub fn send(&mut self, bytes: Vec<u8>) {
        self.outgoing.extend(bytes);
    }

    /// The bus, its multiplexer and its hooks.
    pub fn bus(&self) -> &'static RefCell<BusWorld> {
        self.master.bus
    }

    /// Cut a thruster's power now (its controller stops mid-whatever it was doing) and restore it after `off`.
    pub fn power_cycle(&mut self, index: usize, off: Duration) {
        let Some(thruster) = self.thrusters.get(index).copied() else {
            return;
        };
        thruster.power_off(&mut self.executor);
        self.set_powered(index, false);
        self.run_for(off);
        self.set_powered(index, true);
        thruster.start(&mut self.executor);
    }

    fn set_powered(&self, index: usize, powered: bool) {
        if let Some(slave) = self.master.bus.borrow_mut().slaves.get_mut(index) {
            slave.powered = powered;
        }
    }

    /// Let `duration` of virtual time pass.
    pub fn run_for(&mut self, duration: Duration) {
        let steps = duration.as_ticks().div_ceil(STEP.as_ticks());
        for _ in 0..steps {
            self.step();
        }
    }

    /// Steps run so far and rounds where tasks kept waking one another (should stay 0).
    pub fn counters(&self) -> (u64, u32, u64) {
        (self.steps, self.busy_rounds, self.executor.polls())
    }

    fn step(&mut self) {
        if !self.executor.run_until_idle() {
            self.busy_rounds += 1;
        }
        let now = Instant::now();
        let dt = STEP.as_micros() as f64 / 1e6;

        let supply = self.battery.voltage;
        let mut drawn = HOTEL_LOAD_A;
        for thruster in &self.thrusters {
            thruster.step(now, dt, supply);
            drawn += thruster.plant.borrow().supply_current_a();
        }
        self.battery.step(dt, drawn);
        let frames = self.battery.frames(now);
        if !frames.is_empty() {
            self.master.can.send(frames);
        }

        let mut outgoing = core::mem::take(&mut self.outgoing);
        if self.console_sink.is_none() {
            outgoing.extend(self.ground.periodic(now));
        }
        if !outgoing.is_empty() && self.ground.connected {
            self.master.console_in.send(outgoing);
        }
        let received = core::mem::take(&mut *self.master.console_out.borrow_mut());
        if let Some(sink) = self.console_sink.as_mut() {
            if !received.is_empty() {
                sink(&received);
            }
        } else if !received.is_empty() {
            self.ground.receive(now, &received);
            for (at, text) in self.ground.seen.texts.iter().skip(self.texts_seen) {
                self.trace.events.push(Event {
                    t: at.as_micros() as f64 / 1e6,
                    text: format!("STATUSTEXT {text}"),
                });
            }
            self.texts_seen = self.ground.seen.texts.len();
        }

        if now >= self.next_sample {
            self.next_sample = now + SAMPLE_PERIOD;
            let sample = self.sample();
            if let Some(monitor) = self.monitor.as_mut() {
                monitor(&sample);
            }
            self.trace.samples.push(sample);
        }
        self.steps += 1;
        MockDriver::get().advance(STEP);
    }

    /// Every thruster and the battery now.
    pub fn sample(&self) -> Sample {
        let orders = self.master.shared.orders.try_get();
        let thrusters = self
            .thrusters
            .iter()
            .enumerate()
            .map(|(i, thruster)| {
                let plant = thruster.plant.borrow();
                ThrusterSample {
                    rpm: plant.rpm(),
                    current_a: plant.phase_current_a(),
                    temperature_c: plant.winding_c(),
                    faults: thruster
                        .shared()
                        .sensed
                        .try_get()
                        .map_or(0, |sensed| sensed.faults.bits()),
                    online: self
                        .master
                        .shared
                        .thrusters
                        .get(i)
                        .and_then(|watch| watch.try_get())
                        .is_some_and(|report| report.health.online),
                    ordered_step: orders
                        .and_then(|orders| orders.get(i).map(|order| order.speed.step()))
                        .unwrap_or(0),
                }
            })
            .collect();
        Sample {
            t: self.seconds(),
            thrusters,
            battery_v: self.battery.voltage,
            armed: self.master.shared.vehicle.try_get().is_some_and(|state| state.armed),
        }
    }
}
