//! The harness every scenario runs in, the same for `lbv bench` and for `cargo test`: the bench built from the
//! scenario's vehicle, the script, the checks every run gets, and the report.

use embassy_time::{Duration, Instant};
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value, json};
use tmc_proto::{Family, Faults, MotorKind};

use super::fault::Fault;
use crate::bench::{Bench, BenchConfig, Engine, Motor, STEP};
use lbv::trace::Trace;
use lbv_master_fw::mixer::ManualInput;
use lbv_master_fw::shared::LinkHealth;

/// One check of a scenario.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Check {
    /// What was checked.
    pub name: String,
    /// Whether it held.
    pub passed: bool,
    /// The figures behind the verdict.
    pub detail: String,
}

/// A scenario's result, as `--json` writes it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Report {
    /// The scenario's name.
    pub scenario: String,
    /// The seed.
    pub seed: u64,
    /// The engine that moved time: "events" or "exact".
    pub engine: String,
    /// Whether every check held.
    pub passed: bool,
    /// Virtual time run, s.
    pub sim_seconds: f64,
    /// Wall-clock time taken, s.
    pub wall_seconds: f64,
    /// The checks.
    pub checks: Vec<Check>,
    /// Figures: poll rate, bus utilisation, error counters, orders, latency, speed.
    pub metrics: Map<String, Value>,
}

/// A scenario: a name, what it does, how long it runs by default, and its script.
pub struct Scenario {
    /// Its name on the command line.
    pub name: &'static str,
    /// One line on what it injects and what it expects.
    pub about: &'static str,
    /// Default virtual duration, s.
    pub seconds: f64,
    /// Which thruster families the vehicle carries.
    pub vehicle: fn(u64) -> BenchConfig,
    /// The script.
    pub run: fn(&mut Run),
}

/// A scenario in progress: the bench, the checks so far, the figures.
pub struct Run {
    /// The vehicle.
    pub bench: Bench,
    /// The requested duration.
    pub duration: Duration,
    checks: Vec<Check>,
    metrics: Map<String, Value>,
}

impl Run {
    /// Record a check.
    pub fn check(&mut self, name: &str, passed: bool, detail: impl Into<String>) {
        self.checks.push(Check {
            name: name.to_string(),
            passed,
            detail: detail.into(),
        });
    }

    /// Record a figure.
    pub fn metric(&mut self, name: &str, value: Value) {
        self.metrics.insert(name.to_string(), value);
    }

    /// Let `seconds` of virtual time pass.
    pub fn run_for(&mut self, seconds: f64) {
        self.bench.run_for(Duration::from_micros((seconds * 1e6) as u64));
    }

    /// Run until `done` or `limit` seconds; returns the seconds it took, None if it never happened.
    pub fn run_until(&mut self, limit: f64, done: impl FnMut(&Bench) -> bool) -> Option<f64> {
        self.bench
            .run_until(Duration::from_micros((limit * 1e6) as u64), done)
            .map(|took| took.as_micros() as f64 / 1e6)
    }

    /// Let the thrusters come online, arm, and push the sticks forward.
    pub fn arm_and_go(&mut self, sticks: ManualInput) {
        self.run_for(0.5);
        let arm = self.bench.ground.arm(true);
        self.bench.send(arm);
        self.run_for(0.2);
        self.bench.ground.sticks = Some(sticks);
    }

    /// Sticks to neutral and disarm.
    pub fn disarm(&mut self) {
        self.bench.ground.sticks = Some(NEUTRAL);
        let disarm = self.bench.ground.arm(false);
        self.bench.send(disarm);
    }

    /// The fault bits thruster `index` reports now.
    pub fn faults(&self, index: usize) -> Faults {
        self.bench
            .thrusters
            .get(index)
            .and_then(|thruster| thruster.shared().sensed.try_get())
            .map_or(Faults::NONE, |sensed| sensed.faults)
    }

    /// The duty thruster `index`'s bridge applies now (0: coasting).
    pub fn duty(&self, index: usize) -> i16 {
        self.bench
            .thrusters
            .get(index)
            .map_or(0, |thruster| thruster.drive().1.value())
    }

    /// Thruster `index`'s shaft speed now, rpm.
    pub fn rpm(&self, index: usize) -> f64 {
        self.bench
            .thrusters
            .get(index)
            .map_or(0.0, |thruster| thruster.plant.borrow().rpm())
    }

    /// Whether the master has seen a STATUSTEXT containing `needle`.
    pub fn said(&self, needle: &str) -> bool {
        self.bench
            .ground
            .seen
            .texts
            .iter()
            .any(|(_, text)| text.contains(needle))
    }

    /// Thruster `index`'s link health as the master sees it.
    pub fn health(&self, index: usize) -> LinkHealth {
        self.bench
            .master
            .shared
            .thrusters
            .get(index)
            .and_then(|watch| watch.try_get())
            .map(|report| report.health)
            .unwrap_or_default()
    }

    /// Make `fault` happen now.
    pub fn inject(&mut self, fault: Fault) {
        fault.inject(&mut self.bench);
    }

    /// Make `fault` stop now.
    pub fn clear(&mut self, fault: Fault) {
        fault.clear(&mut self.bench);
    }
}

/// The sticks at rest.
pub const NEUTRAL: ManualInput = ManualInput {
    x: 0,
    y: 0,
    z: 500,
    r: 0,
};
/// The sticks pushed ahead.
pub const AHEAD: ManualInput = ManualInput {
    x: 600,
    y: 0,
    z: 500,
    r: 0,
};

/// The sticks pushed fully ahead, and fully astern.
pub const FULL_AHEAD: ManualInput = ManualInput { x: 1000, ..AHEAD };
pub const FULL_ASTERN: ManualInput = ManualInput { x: -1000, ..AHEAD };

/// The vehicle as built: an LBV300-6 with six SeaBotix thrusters.
pub fn lbv300(seed: u64) -> BenchConfig {
    BenchConfig::lbv300(seed)
}

/// The LBV300-6 with its console link at the binding's 115200 baud, into the LPUART's buffers
/// ([`crate::bench::master::ConsoleLine`]), rather than the bench's instant one.
pub fn lbv300_uart(seed: u64) -> BenchConfig {
    BenchConfig {
        console_baud: Some(115_200),
        ..BenchConfig::lbv300(seed)
    }
}

/// The LBV300-6 with six Legacy thrusters.
pub fn legacy6(seed: u64) -> BenchConfig {
    BenchConfig {
        families: vec![Family::Legacy; 6],
        seed,
        acceptance: false,
        console_baud: None,
        motor: Motor::REFERENCE,
    }
}

/// The LBV300-6 with six Legacy brushed thrusters (revision 4).
pub fn brushed6(seed: u64) -> BenchConfig {
    BenchConfig {
        motor: Motor {
            kind: MotorKind::Brushed,
            inertia_x: 1,
        },
        ..legacy6(seed)
    }
}

/// [`brushed6`] with rotors four times as heavy (a larger propeller, more entrained water).
pub fn heavy_brushed6(seed: u64) -> BenchConfig {
    BenchConfig {
        motor: Motor {
            kind: MotorKind::Brushed,
            inertia_x: 4,
        },
        ..legacy6(seed)
    }
}

/// The LBV300-6 with SeaBotix and Legacy thrusters alternating.
pub fn mixed(seed: u64) -> BenchConfig {
    BenchConfig {
        families: [Family::SeaBotix, Family::Legacy].repeat(3),
        seed,
        acceptance: false,
        console_baud: None,
        motor: Motor::REFERENCE,
    }
}

/// The mixed vehicle with its console link at the binding's 115200 baud, as [`lbv300_uart`].
pub fn mixed_uart(seed: u64) -> BenchConfig {
    BenchConfig {
        console_baud: Some(115_200),
        ..mixed(seed)
    }
}

/// The two-board bench, with a thruster of each family wired directly to the master's bus.
pub fn dev_kits(seed: u64) -> BenchConfig {
    BenchConfig {
        families: vec![Family::SeaBotix, Family::Legacy],
        seed,
        acceptance: true,
        console_baud: None,
        motor: Motor::REFERENCE,
    }
}

/// How to run a scenario.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Options {
    /// Seeds the motors' starting positions and the scenario's random choices.
    pub seed: u64,
    /// Virtual seconds to run; the scenario's default when None.
    pub seconds: Option<f64>,
    /// The engine that moves time.
    pub engine: Engine,
    /// Keep the trace's samples (only a plot reads them); the events are kept either way.
    pub samples: bool,
}

impl Options {
    /// The scenario's default length with `seed` on `engine`, samples kept.
    pub fn new(seed: u64, engine: Engine) -> Self {
        Self {
            seed,
            seconds: None,
            engine,
            samples: true,
        }
    }
}

/// Run a scenario as `options` say, with `monitor` watching every sample, and report.
pub fn run_with(scenario: &Scenario, options: &Options, monitor: Option<crate::bench::Monitor>) -> (Report, Bench) {
    let wall = std::time::Instant::now();
    let seconds = options.seconds.unwrap_or(scenario.seconds).max(0.1);
    let mut bench = Bench::new(&(scenario.vehicle)(options.seed), options.engine);
    bench.keep_samples(options.samples);
    bench.monitor = monitor;
    let mut run = Run {
        bench,
        duration: Duration::from_micros((seconds * 1e6) as u64),
        checks: Vec::new(),
        metrics: Map::new(),
    };
    (scenario.run)(&mut run);
    let end = Instant::from_ticks(0) + run.duration;
    if run.bench.now() < end {
        run.bench.run_for(end - run.bench.now());
    }
    common_checks(&mut run);
    let sim_seconds = run.bench.seconds();
    let wall_seconds = wall.elapsed().as_secs_f64();
    run.metric(
        "real_time_factor",
        json!(round(sim_seconds / wall_seconds.max(1e-9), 1)),
    );
    let passed = run.checks.iter().all(|check| check.passed);
    let report = Report {
        scenario: scenario.name.to_string(),
        seed: options.seed,
        engine: options.engine.name().to_string(),
        passed,
        sim_seconds: round(sim_seconds, 3),
        wall_seconds: round(wall_seconds, 3),
        checks: run.checks,
        metrics: run.metrics,
    };
    (report, run.bench)
}

/// What [`run_guarded`] checks of every run.
pub const NO_PANIC: &str = "the run ends without a panic";

/// Run a scenario as [`run_with`] does, and check that it ends without a panic: a run that panics (in the bench's
/// own code, the cores never panic) reports that check failed with the panic's message, instead of ending the
/// process. Returns the report and the trace.
pub fn run_guarded(scenario: &Scenario, options: &Options, monitor: Option<crate::bench::Monitor>) -> (Report, Trace) {
    let ran = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let (mut report, bench) = run_with(scenario, options, monitor);
        report.checks.push(Check {
            name: NO_PANIC.into(),
            passed: true,
            detail: String::new(),
        });
        (report, bench.trace)
    }));
    ran.unwrap_or_else(|panic| {
        let message = panic
            .downcast_ref::<&str>()
            .map(|text| text.to_string())
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "no message".into());
        (Report::broken(scenario.name, options, message), Trace::default())
    })
}

impl Report {
    /// The report of a run that broke off (a panic, a process that ended without a report): its one check failed.
    pub fn broken(scenario: &str, options: &Options, why: String) -> Self {
        Report {
            scenario: scenario.to_string(),
            seed: options.seed,
            engine: options.engine.name().to_string(),
            passed: false,
            sim_seconds: 0.0,
            wall_seconds: 0.0,
            checks: vec![Check {
                name: NO_PANIC.into(),
                passed: false,
                detail: why,
            }],
            metrics: Map::new(),
        }
    }
}

/// `value` to `places` decimals.
pub fn round(value: f64, places: i32) -> f64 {
    let scale = 10f64.powi(places);
    (value * scale).round() / scale
}

/// Checks and figures every run gets: no task stalled, link statistics.
fn common_checks(run: &mut Run) {
    let (steps, busy_runs, polls) = run.bench.counters();
    let bites: u32 = run
        .bench
        .thrusters
        .iter()
        .map(|thruster| thruster.watchdog_bites.get())
        .sum();
    run.check(
        "no watchdog bite",
        bites == 0,
        format!("{bites} times a controller went unfed past its watchdog's timeout"),
    );
    run.check(
        "no task kept busy",
        busy_runs == 0,
        format!("{busy_runs} runs where tasks kept waking one another"),
    );
    let seconds = run.bench.seconds().max(1e-9);
    let bus = run.bench.thruster_bus();
    let stats = bus.stats();
    let utilisation = stats.bits as f64 * bus.timing().bit.as_micros() as f64 / 1e6 / seconds;
    let (recoveries, transfers) = (stats.pin_stops, stats.transfers);
    let mut rates = Vec::new();
    let mut errors = json!({});
    for (i, watch) in run
        .bench
        .master
        .shared
        .thrusters
        .iter()
        .take(run.bench.thrusters.len())
        .enumerate()
    {
        let health = watch.try_get().map(|report| report.health).unwrap_or_default();
        rates.push(round(f64::from(health.good) / seconds, 1));
        errors[format!("T{}", i + 1)] = json!({
            "nack": health.nack, "timeout": health.timeout, "bad_checksum": health.bad_checksum,
            "bad_type": health.bad_type, "bad_length": health.bad_length, "bad_range": health.bad_range,
            "bus_error": health.bus_error, "recoveries": health.recoveries,
        });
    }
    let rejected: u32 = run.bench.thrusters.iter().map(|thruster| thruster.slave_resets()).sum();
    run.metric("poll_rate_hz", json!(rates));
    run.metric("bus_utilisation", json!(round(utilisation, 3)));
    run.metric("bus_transfers", json!(transfers));
    run.metric("bus_recoveries", json!(recoveries));
    run.metric("link_errors", errors);
    run.metric("slave_reinits", json!(rejected));
    let limited: Vec<f64> = run
        .bench
        .thrusters
        .iter()
        .map(|thruster| round(thruster.limited_steps.get() as f64 * STEP.as_micros() as f64 / 1e6, 3))
        .collect();
    run.metric("current_limited_seconds", json!(limited));
    run.metric("steps", json!(steps));
    run.metric("task_polls", json!(polls));
    run.metric("console_frames_received", json!(run.bench.ground.seen.frames));
    let dropped = run.bench.events_dropped();
    if dropped > 0 {
        run.metric("trace_events_not_kept", json!(dropped));
    }
}

/// Drive ahead, then let `inject` act on thruster 1; returns how long the bridge took to coast (None: it kept
/// driving for 1 s).
pub fn inject_and_time(run: &mut Run, fault: Fault) -> Option<f64> {
    run.arm_and_go(AHEAD);
    run.run_for(1.5);
    run.inject(fault);
    run.run_until(1.0, |bench| bench.thrusters[0].drive().1.value() == 0)
}

/// The bridge coasted within one 1 ms fault sample.
pub fn coasted_within_a_sample(run: &mut Run, took: Option<f64>) {
    let ms = took.map(|s| round(s * 1e3, 2));
    run.metric("reaction_ms", json!(ms));
    run.check(
        "T1 stops within one 1 ms sample",
        took.is_some_and(|s| s <= 0.0011),
        format!("coasted after {ms:?} ms"),
    );
}

/// The drive stopped on the sample that completed the fault's filter of `samples` consecutive 1 ms samples
/// (thruster-fw `Thresholds::SPEC`): not sooner than `samples - 1` samples, not later than `samples`.
pub fn stopped_after_consecutive_samples(run: &mut Run, took: Option<f64>, samples: u8) {
    let ms = took.map(|s| round(s * 1e3, 2));
    run.metric("reaction_ms", json!(ms));
    let n = f64::from(samples);
    run.check(
        &format!("T1 stops after {samples} consecutive 1 ms samples"),
        took.is_some_and(|s| s > (n - 1.0) * 1e-3 - 1e-4 && s <= n * 1e-3 + 1e-4),
        format!("stopped after {ms:?} ms"),
    );
}

/// Thruster 1 reports `fault` in its status.
pub fn reported(run: &mut Run, fault: Faults) {
    let faults = run.faults(0);
    run.check(
        &format!("{} reported", fault.name()),
        faults.contains(fault),
        format!("faults {:#04x}", faults.bits()),
    );
}

/// Thruster 1 reports no fault and drives ahead again.
pub fn drives_again(run: &mut Run, name: &str) {
    let (faults, rpm) = (run.faults(0), run.rpm(0));
    run.check(
        name,
        faults.is_empty() && rpm > 800.0,
        format!("faults {:#04x}, rpm {rpm:.0}", faults.bits()),
    );
}

/// Thrusters 2-4 keep turning ahead.
pub fn others_keep_working(run: &mut Run) {
    let rpm: Vec<f64> = (1..4).map(|i| round(run.rpm(i), 0)).collect();
    run.check(
        "the other thrusters keep working",
        rpm.iter().all(|r| *r > 800.0),
        format!("T2-T4 rpm {rpm:?}"),
    );
}

/// Thruster 1's family.
pub fn family(run: &Run) -> Family {
    run.bench.thrusters[0].config.family
}
