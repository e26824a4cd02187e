//! The virtual bench: the master and the thrusters as they ship (their cores' `run` functions with the images'
//! configurations: the LBV300-6 table, the bus speed and timeouts, the watchdog and task timings) and a battery
//! board, wired by lbv-sim's buses, with a plant model behind every thruster, all on one virtual clock.
//!
//! Two engines move time ([`Engine`]); the same seed gives the same run on each, bit for bit:
//! - the event engine (the default) goes from one event to the next: the next timer of any task, the next hall edge
//!   a plant predicts, the next step of a current limiter that acts, a watchdog's deadline, the battery's next
//!   frame, the ground station's next message, the next sample. A plant is advanced only when the firmware reads
//!   it, changes its drive or reaches a moment it asked for; each instant, the woken tasks run until none is ready.
//! - the fixed-step engine (`--exact`) takes steps of [`STEP`]: the firmware tasks that were woken run until none
//!   is ready, then the motors, the battery and the ground station move by one step, then the clock advances. It
//!   is the reference the event engine's fidelity is held against (`scenarios::fidelity`).

pub mod battery;
pub mod master;
pub mod plant;
pub mod shunts;
pub mod thruster;
pub mod udp;

use std::rc::Rc;

use embassy_time::{Duration, Instant};
use lbv_master_fw::MasterConfig;
use lbv_master_fw::config::{THRUSTER_BUS, lbv300_6};
use lbv_master_fw::ports::CanFrame;
use lbv_master_fw::thrusters::{MUX_ADDRESS, ThrusterSlot, ThrusterTable};
use lbv_sim::i2c::{Bus, Route, Timing};
use lbv_sim::{CanBus, Clock, Executor, Queue};
use lbv_station::GroundStation;
use tmc_proto::Family;

use battery::{BatteryBoard, Rail};
use lbv::trace::{Event, Recorder, Sample, ThrusterSample, Trace};
use master::{ConsoleLine, MasterBoard, Wiring};
pub use thruster::Motor;
use thruster::ThrusterBoard;

/// The plant and bus step.
pub const STEP: Duration = Duration::from_micros(50);
/// How often the trace records a sample.
pub const SAMPLE_PERIOD: Duration = Duration::from_millis(10);
/// What the vehicle's electronics draw besides the thrusters, A.
const HOTEL_LOAD_A: f64 = 0.6;

/// How the bench moves time (see the module documentation).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Engine {
    /// From one event to the next, each plant advanced when something needs it.
    #[default]
    Events,
    /// In fixed steps of [`STEP`], every plant stepped every time.
    Exact,
}

impl Engine {
    /// Its name in reports.
    pub fn name(self) -> &'static str {
        match self {
            Engine::Events => "events",
            Engine::Exact => "exact",
        }
    }
}

/// What to build.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BenchConfig {
    /// The vehicle (the LBV300-6's wiring, six thrusters): the family of each, in table order. The two-board bench
    /// (`acceptance`): one thruster of each family listed, wired directly.
    pub families: Vec<Family>,
    /// Seeds the motors' starting positions and any random choices of a scenario.
    pub seed: u64,
    /// The two-board bench instead of the vehicle: the thrusters wired to the dev kit's bus directly (no
    /// TCA9548A) and the master running its acceptance test instead of polling.
    pub acceptance: bool,
    /// The console link at this baud rate, into the master's UART buffers as its binding has them
    /// ([`master::ConsoleLine`]); `None`: every byte at once, in unbounded queues.
    pub console_baud: Option<u32>,
    /// The motor behind every thruster.
    pub motor: Motor,
}

impl BenchConfig {
    /// An LBV300-6: six SeaBotix thrusters, the vehicle's own table.
    pub fn lbv300(seed: u64) -> Self {
        Self {
            families: vec![Family::SeaBotix; 6],
            seed,
            acceptance: false,
            console_baud: None,
            motor: Motor::REFERENCE,
        }
    }

    /// The master's configuration and the thruster table the bench wires: the vehicle's (the LBV300-6 wiring with
    /// these families), or for the acceptance test the dev kit's master with these thrusters on its bus.
    fn master(&self) -> (MasterConfig, ThrusterTable) {
        if self.acceptance {
            let slots: Vec<ThrusterSlot> = self
                .families
                .iter()
                .map(|family| ThrusterSlot::direct(THRUSTER_BUS, *family))
                .collect();
            let mut config = MasterConfig::devkit(Family::SeaBotix);
            // Both families are wired: the script tests whichever answers.
            config.acceptance.script.expect = None;
            (config, ThrusterTable::new(&slots))
        } else {
            let families: [Family; 6] = self
                .families
                .as_slice()
                .try_into()
                .expect("the bench's vehicle is an LBV300-6: six thrusters");
            let config = MasterConfig::with_thrusters(lbv300_6(families));
            (config, config.thrusters)
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

/// One vehicle on the bench. Its runs hold the process's critical section (see
/// [`lbv_sim::in_one_critical_section`]): benches run side by side as processes, not threads.
pub struct Bench {
    engine: Engine,
    executor: Executor<'static>,
    /// The virtual clock, held while the bench exists: one bench at a time per process.
    clock: Clock,
    /// What the master is wired to: its thruster buses, CAN node and console link.
    pub wiring: Wiring,
    /// The battery CAN bus.
    pub can: CanBus<CanFrame>,
    /// The thrusters, in table order.
    pub thrusters: Vec<ThrusterBoard>,
    /// The master node.
    pub master: MasterBoard,
    /// The battery board.
    pub battery: BatteryBoard,
    /// The operator's ground station.
    pub ground: GroundStation,
    /// What the run recorded.
    pub trace: Trace,
    /// What goes into the trace: samples only when asked for ([`Bench::keep_samples`]), within bounds.
    recorder: Recorder,
    /// Random choices of the scenario.
    pub random: Random,
    texts_seen: usize,
    /// Bytes the console link has carried so far: to the master, and from it.
    pub console_bytes: (u64, u64),
    next_sample: Instant,
    /// Steps taken (fixed-step engine) or instants run (event engine).
    steps: u64,
    /// Event engine: the pack's terminals as the thrusters see them, and when the battery last took their draw.
    rail: Rc<Rail>,
    settled: Instant,
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
    /// Build the vehicle and power it up at virtual time 0, to run on `engine`. It holds its thread's virtual clock
    /// until it is dropped: one bench at a time per thread.
    pub fn new(config: &BenchConfig, engine: Engine) -> Self {
        let clock = lbv_sim::clock::take();
        let mut random = Random::new(config.seed);
        let mut executor = Executor::new();
        let (master_config, table) = config.master();
        let mut battery = BatteryBoard::default();
        let rail = Rc::new(Rail::new(&battery, table.as_slice().len(), HOTEL_LOAD_A));
        let timing = Timing::new(master_config.bus.frequency_hz, master_config.bus.timeout);
        let buses = [Bus::new(timing), Bus::new(timing), Bus::new(timing)];
        let mut thrusters = Vec::new();
        for slot in table.as_slice() {
            let Some(bus) = buses.get(usize::from(slot.bus)) else {
                continue;
            };
            let route = match slot.mux_channel {
                Some(channel) => {
                    if bus.mux_control().is_none() {
                        bus.fit_mux(MUX_ADDRESS);
                    }
                    Route::Mux(channel)
                }
                None => Route::Direct,
            };
            let device = bus.attach_target(slot.family.address(), route);
            let angle = random.unit() * core::f64::consts::TAU;
            let lazy = (engine == Engine::Events).then(|| (rail.clone(), thrusters.len()));
            thrusters.push(ThrusterBoard::new(slot.family, config.motor, bus, device, angle, lazy));
        }
        let mut can = CanBus::default();
        let wiring = Wiring {
            buses,
            can: can.attach(),
            console_in: Queue::new(),
            console_out: Queue::new(),
            console_line: config.console_baud.map(ConsoleLine::new),
        };
        let master = MasterBoard::boot(master_config, config.acceptance, &wiring, &mut executor);
        for thruster in &mut thrusters {
            thruster.boot(&mut executor);
        }
        battery.step(0.0, HOTEL_LOAD_A);
        Self {
            engine,
            executor,
            clock,
            wiring,
            can,
            thrusters,
            master,
            battery,
            ground: GroundStation::default(),
            trace: Trace::default(),
            recorder: Recorder::new(true),
            random,
            texts_seen: 0,
            console_bytes: (0, 0),
            next_sample: Instant::from_ticks(0),
            steps: 0,
            rail,
            settled: Instant::from_ticks(0),
            outgoing: Vec::new(),
            monitor: None,
            console_sink: None,
        }
    }

    /// Keep the samples in the trace (for a plot), or only the events. The run is the same either way.
    pub fn keep_samples(&mut self, keep: bool) {
        self.recorder = Recorder::new(keep);
    }

    /// Forget what the ground station has read of the console so far (its STATUSTEXTs and COMMAND_ACKs; the trace
    /// keeps the texts as events): a long run that does not look back at them stays within bounded memory.
    pub fn forget_console_texts(&mut self) {
        self.ground.seen.texts.clear();
        self.ground.seen.acks.clear();
        self.texts_seen = 0;
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
        let event = Event {
            t: self.seconds(),
            text: text.into(),
        };
        self.recorder.event(&mut self.trace, event);
    }

    /// Send bytes to the master's console as the ground station.
    pub fn send(&mut self, bytes: Vec<u8>) {
        self.outgoing.extend(bytes);
    }

    /// Bytes handed to the master's console and not yet out on the line towards it; `None` when the console
    /// carries every byte at once (no [`BenchConfig::console_baud`]).
    pub fn console_backlog(&self) -> Option<usize> {
        let line = self.wiring.console_line.as_ref()?;
        Some(self.outgoing.len() + line.to_master.unsent())
    }

    /// Bytes the master's console UART lost to its full receive buffer (0 without a modelled line).
    pub fn console_overruns(&self) -> u64 {
        self.wiring
            .console_line
            .as_ref()
            .map_or(0, |line| line.to_master.lost())
    }

    /// The bus the thrusters hang on (I2C2, in the vehicle's table and on the dev kit).
    pub fn thruster_bus(&self) -> &Bus {
        &self.wiring.buses[usize::from(THRUSTER_BUS)]
    }

    /// Cut thruster `index`'s power (its controller stops mid-whatever it was doing), or restore it (it boots).
    pub fn power(&mut self, index: usize, on: bool) {
        let Some(thruster) = self.thrusters.get_mut(index) else {
            return;
        };
        if on {
            thruster.boot(&mut self.executor);
        } else {
            thruster.power_off(&mut self.executor);
        }
    }

    /// Thruster `index`'s controller stops as its fault handlers stop it on a `kind` of stop (a panic, say); its
    /// watchdog then resets it, and it starts again with the record of the stop ([`ThrusterBoard::stop`]).
    pub fn stop_thruster(&mut self, index: usize, kind: crash_record::Kind) {
        if let Some(thruster) = self.thrusters.get_mut(index) {
            thruster.stop(&mut self.executor, kind);
        }
    }

    /// Reset the master: it boots again with fresh state; the thrusters, the buses and the links stay as they are.
    pub fn reboot_master(&mut self) {
        self.master.reboot(&self.wiring, &mut self.executor);
    }

    /// The master's image crashes: the watchdog resets it.
    pub fn crash_master(&mut self) {
        self.master.crash(&self.wiring, &mut self.executor);
    }

    /// Let `duration` of virtual time pass. The fixed-step engine takes whole steps (rounding `duration` up); on
    /// the event engine the clock ends exactly `duration` on, with what falls due then left for the next run.
    pub fn run_for(&mut self, duration: Duration) {
        lbv_sim::in_one_critical_section(|| match self.engine {
            Engine::Exact => {
                let steps = duration.as_ticks().div_ceil(STEP.as_ticks());
                for _ in 0..steps {
                    self.step();
                }
            }
            Engine::Events => {
                let end = self.now() + duration;
                self.run_events(end, &mut |_| false);
            }
        });
    }

    /// Run until `done` holds, at most `limit`; returns how long that took, None if it did not happen. `done` is
    /// asked after every step (fixed-step engine) or every instant at which anything happened (event engine); it
    /// sees the firmware as it is then, while the plants are brought up to date only on return.
    pub fn run_until(&mut self, limit: Duration, mut done: impl FnMut(&Bench) -> bool) -> Option<Duration> {
        let start = self.now();
        let end = start + limit;
        lbv_sim::in_one_critical_section(|| match self.engine {
            Engine::Exact => {
                while self.now() < end {
                    if done(self) {
                        return Some(self.now() - start);
                    }
                    self.run_for(STEP);
                }
                None
            }
            Engine::Events => self.run_events(end, &mut done).then(|| self.now() - start),
        })
    }

    /// Events the trace did not keep (past its bound).
    pub fn events_dropped(&self) -> u64 {
        self.recorder.events_dropped()
    }

    /// Steps (fixed-step engine) or instants (event engine) run so far, runs where tasks kept waking one another
    /// (should stay 0), and task polls.
    pub fn counters(&self) -> (u64, u32, u64) {
        (self.steps, self.executor.busy_runs(), self.executor.polls())
    }

    /// Run the tasks woken at this instant until none is ready: the one place both engines do so.
    fn run_tasks(&mut self) {
        self.executor.run_until_idle();
        // The master asked to restart (MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN): it boots again with its flash kept.
        if self.master.reboot_requested() {
            self.note("master reboots");
            self.reboot_master();
            self.executor.run_until_idle();
        }
        // A thruster asked to reset (the field update's Reboot): the bench has no reset but the power, so it
        // power-cycles it, and its bootloader runs before it starts again.
        while let Some(index) = self.thrusters.iter().position(ThrusterBoard::reboot_requested) {
            self.note(format!("T{}: reboots", index + 1));
            self.power(index, false);
            self.power(index, true);
            self.executor.run_until_idle();
        }
        // A thruster stopped by a fault handler: its watchdog resets it, and it starts with the record of the stop.
        let now = self.now();
        while let Some(index) = self.thrusters.iter().position(|t| t.watchdog_reset_due(now)) {
            self.note(format!("T{}: its watchdog resets it", index + 1));
            self.power(index, true);
            self.executor.run_until_idle();
        }
    }

    /// Fixed-step engine: one step.
    fn step(&mut self) {
        self.run_tasks();
        let now = self.clock.now();
        let dt = STEP.as_micros() as f64 / 1e6;

        let supply = self.battery.voltage;
        let mut drawn = HOTEL_LOAD_A;
        for thruster in &self.thrusters {
            thruster.step(now, dt, supply);
            drawn += thruster.plant.borrow().supply_current_a();
        }
        self.battery.step(dt, drawn);
        self.exchange(now);
        self.steps += 1;
        self.clock.advance(STEP);
    }

    /// Event engine: run every instant from now until `end` (the instant at `end` itself is left for the next
    /// run, as the fixed-step engine leaves it), asking `done` after each; returns whether it held, the clock then
    /// standing at that instant. The plants and the battery are up to date on return.
    fn run_events(&mut self, end: Instant, done: &mut dyn FnMut(&Bench) -> bool) -> bool {
        // What the caller changed (a fault in a plant, a power cut) is looked at before anything runs.
        for thruster in &self.thrusters {
            thruster.disturbed();
            thruster.plan(self.now());
        }
        let mut held = false;
        loop {
            let now = self.now();
            if now >= end {
                break;
            }
            self.steps += 1;
            loop {
                self.run_tasks();
                for thruster in &self.thrusters {
                    thruster.watch(now);
                }
                if !self.exchange(now) {
                    break;
                }
            }
            for thruster in &self.thrusters {
                thruster.plan(now);
            }
            if done(self) {
                held = true;
                break;
            }
            let next = self
                .next_event()
                .map_or(end, |next| next.min(end))
                .max(now + Duration::from_ticks(1));
            self.clock.advance(next - now);
            for thruster in &self.thrusters {
                thruster.wake(next);
            }
        }
        self.settle();
        held
    }

    /// Event engine: the earliest moment anything on the bench is due.
    fn next_event(&self) -> Option<Instant> {
        let mut next = [
            lbv_sim::clock::next_alarm(),
            Some(self.battery.next_frame()),
            Some(self.next_sample),
            if self.console_sink.is_none() {
                self.ground.next_due()
            } else {
                None
            },
            self.wiring
                .console_line
                .as_ref()
                .and_then(|line| line.from_master.next_arrival()),
        ]
        .into_iter()
        .flatten()
        .min();
        for thruster in &self.thrusters {
            if let Some(at) = thruster.next_event() {
                next = Some(next.map_or(at, |next| next.min(at)));
            }
        }
        next
    }

    /// Event engine: bring every plant up to now and let the battery take what they drew. Nothing on the
    /// fixed-step engine, where both are always up to date.
    fn settle(&mut self) {
        if self.engine != Engine::Events {
            return;
        }
        let now = self.now();
        for thruster in &self.thrusters {
            thruster.catch_up(now);
            thruster.plan(now);
        }
        self.battery
            .settle((now - self.settled).as_micros() as f64 / 1e6, &self.rail);
        self.settled = now;
    }

    /// What passes at `now` between the tasks and the bench: the battery's frames, the console both ways, the
    /// trace's sample. Returns whether it handed the tasks anything (which may wake them).
    fn exchange(&mut self, now: Instant) -> bool {
        let frame = now >= self.battery.next_frame();
        let ground = self.console_sink.is_none() && self.ground.next_due().is_some_and(|due| now >= due);
        let arrived = self
            .wiring
            .console_line
            .as_ref()
            .and_then(|line| line.from_master.next_arrival())
            .is_some_and(|at| at <= now);
        if !frame
            && !ground
            && !arrived
            && now < self.next_sample
            && self.outgoing.is_empty()
            && self.wiring.console_out.is_empty()
        {
            return false;
        }
        if self.engine == Engine::Events && (frame || now >= self.next_sample) {
            self.settle();
        }
        let mut handed = false;
        let frames = self.battery.frames(now);
        if !frames.is_empty() {
            self.can.send(&frames);
            handed = true;
        }

        let mut outgoing = core::mem::take(&mut self.outgoing);
        if self.console_sink.is_none() {
            outgoing.extend(self.ground.periodic(now));
        }
        if !outgoing.is_empty() && self.ground.connected {
            self.console_bytes.0 += outgoing.len() as u64;
            match &self.wiring.console_line {
                Some(line) => line.to_master.send(outgoing),
                None => self.wiring.console_in.send(outgoing),
            }
            handed = true;
        }
        let received = match &self.wiring.console_line {
            Some(line) => line.from_master.take_arrived(),
            None => self.wiring.console_out.take(),
        };
        self.console_bytes.1 += received.len() as u64;
        if let Some(sink) = self.console_sink.as_mut() {
            if !received.is_empty() {
                sink(&received);
            }
        } else if !received.is_empty() {
            self.ground.receive(now, &received);
            for (at, text) in self.ground.seen.texts.iter().skip(self.texts_seen) {
                let event = Event {
                    t: at.as_micros() as f64 / 1e6,
                    text: format!("STATUSTEXT {text}"),
                };
                self.recorder.event(&mut self.trace, event);
            }
            self.texts_seen = self.ground.seen.texts.len();
        }

        if now >= self.next_sample {
            self.next_sample = now + SAMPLE_PERIOD;
            let sample = self.sample();
            if let Some(monitor) = self.monitor.as_mut() {
                monitor(&sample);
            }
            self.recorder.sample(&mut self.trace, sample);
        }
        handed
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A controller that locks up stops feeding its watchdog: on both engines the bench counts a reset the
    /// watchdog's timeout after the last feed (the event engine at that instant, the fixed-step one at its next
    /// step), and every timeout after.
    #[test]
    fn a_hung_controller_bites_its_watchdog_when_due_on_both_engines() {
        let mut bites = Vec::new();
        for engine in [Engine::Events, Engine::Exact] {
            let mut bench = Bench::new(&BenchConfig::lbv300(1), engine);
            // Fed at 100 and 200 ms; the feed due at 300 ms has not run when this returns.
            bench.run_for(Duration::from_millis(300));
            if let Some(thruster) = bench.thrusters.get_mut(0) {
                thruster.hang(&mut bench.executor);
            }
            let first = bench.run_until(Duration::from_secs(1), |bench| {
                bench.thrusters[0].watchdog_bites.get() > 0
            });
            let first_ms = first.map(|took| took.as_micros() as f64 / 1e3);
            assert!(
                first_ms.is_some_and(|ms| (150.0..=150.1).contains(&ms)),
                "{engine:?}: first bite {first_ms:?} ms after the hang"
            );
            bench.run_for(Duration::from_secs(1));
            bites.push(bench.thrusters[0].watchdog_bites.get());
            let others: u32 = bench.thrusters.iter().skip(1).map(|t| t.watchdog_bites.get()).sum();
            assert_eq!(others, 0, "{engine:?}: the healthy controllers are fed");
        }
        // At 450, 700, 950 and 1200 ms; the next falls just after the run's end at 1450 ms.
        assert_eq!(bites, [4, 4], "a bite every 250 ms");
    }
}
