//! The bench's scenarios: each injects something into the running vehicle and checks the reaction the
//! interface specification (and the project's reading of it) calls for.

use embassy_time::{Duration, Instant};
use serde::Serialize;
use serde_json::{Map, Value, json};
use tmc_proto::{Family, Faults};

use crate::bench::plant::DRY_WATER_OHMS;
use crate::bench::{Bench, BenchConfig};
use lbv_master_fw::acceptance::{Prompt, Step, family_token};
use lbv_master_fw::shared::ManualInput;

/// One check of a scenario.
#[derive(Debug, Clone, Serialize)]
pub struct Check {
    /// What was checked.
    pub name: String,
    /// Whether it held.
    pub passed: bool,
    /// The figures behind the verdict.
    pub detail: String,
}

/// A scenario's result, as `--json` writes it.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// The scenario's name.
    pub scenario: String,
    /// The seed.
    pub seed: u64,
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
    run: fn(&mut Run),
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
    fn check(&mut self, name: &str, passed: bool, detail: impl Into<String>) {
        self.checks.push(Check {
            name: name.to_string(),
            passed,
            detail: detail.into(),
        });
    }

    fn metric(&mut self, name: &str, value: Value) {
        self.metrics.insert(name.to_string(), value);
    }

    fn run_for(&mut self, seconds: f64) {
        self.bench.run_for(Duration::from_micros((seconds * 1e6) as u64));
    }

    /// Run until `done` or `limit` seconds; returns the seconds it took, None if it never happened.
    fn run_until(&mut self, limit: f64, mut done: impl FnMut(&Bench) -> bool) -> Option<f64> {
        let start = self.bench.now();
        let end = start + Duration::from_micros((limit * 1e6) as u64);
        while self.bench.now() < end {
            if done(&self.bench) {
                return Some((self.bench.now() - start).as_micros() as f64 / 1e6);
            }
            self.bench.run_for(super::bench::STEP);
        }
        None
    }

    /// Let the thrusters come online, arm, and push the sticks forward.
    fn arm_and_go(&mut self, sticks: ManualInput) {
        self.run_for(0.5);
        let arm = self.bench.ground.arm(true);
        self.bench.send(arm);
        self.run_for(0.2);
        self.bench.ground.sticks = Some(sticks);
    }

    fn disarm(&mut self) {
        self.bench.ground.sticks = Some(NEUTRAL);
        let disarm = self.bench.ground.arm(false);
        self.bench.send(disarm);
    }

    /// The fault bits thruster `index` reports now.
    fn faults(&self, index: usize) -> Faults {
        self.bench
            .thrusters
            .get(index)
            .and_then(|thruster| thruster.shared().sensed.try_get())
            .map_or(Faults::NONE, |sensed| sensed.faults)
    }

    /// The duty thruster `index`'s bridge applies now (0: coasting).
    fn duty(&self, index: usize) -> i16 {
        self.bench
            .thrusters
            .get(index)
            .map_or(0, |thruster| thruster.drive().1.value())
    }

    fn rpm(&self, index: usize) -> f64 {
        self.bench
            .thrusters
            .get(index)
            .map_or(0.0, |thruster| thruster.plant.borrow().rpm())
    }

    /// Whether the master has seen a STATUSTEXT containing `needle`.
    fn said(&self, needle: &str) -> bool {
        self.bench
            .ground
            .seen
            .texts
            .iter()
            .any(|(_, text)| text.contains(needle))
    }
}

const NEUTRAL: ManualInput = ManualInput {
    x: 0,
    y: 0,
    z: 500,
    r: 0,
};
const AHEAD: ManualInput = ManualInput {
    x: 600,
    y: 0,
    z: 500,
    r: 0,
};

fn lbv300(seed: u64) -> BenchConfig {
    BenchConfig::lbv300(seed)
}

fn legacy6(seed: u64) -> BenchConfig {
    BenchConfig {
        families: vec![Family::Legacy; 6],
        seed,
        acceptance: false,
    }
}

fn mixed(seed: u64) -> BenchConfig {
    BenchConfig {
        families: [Family::SeaBotix, Family::Legacy].repeat(3),
        seed,
        acceptance: false,
    }
}

/// The two-board bench, with a thruster of each family wired directly to the master's bus.
fn dev_kits(seed: u64) -> BenchConfig {
    BenchConfig {
        families: vec![Family::SeaBotix, Family::Legacy],
        seed,
        acceptance: true,
    }
}

/// Every scenario, in the order `--list` and `--all` use.
pub const SCENARIOS: &[Scenario] = &[
    Scenario {
        name: "dive",
        about: "arm, drive ahead, yaw, disarm: thrusters follow the sticks, telemetry reaches the console",
        seconds: 12.0,
        vehicle: mixed,
        run: dive,
    },
    Scenario {
        name: "water-legacy",
        about: "water (500 kohm) in a Legacy thruster: it stops and latches; the others keep working",
        seconds: 6.0,
        vehicle: legacy6,
        run: water,
    },
    Scenario {
        name: "water-seabotix",
        about: "water (500 kohm) in a SeaBotix thruster: a warning only, it keeps driving; clears when dry",
        seconds: 6.0,
        vehicle: lbv300,
        run: water,
    },
    Scenario {
        name: "ground-fault-legacy",
        about: "50 kohm between the water electrodes, Legacy: stops, latched after drying",
        seconds: 6.0,
        vehicle: legacy6,
        run: ground_fault,
    },
    Scenario {
        name: "ground-fault-seabotix",
        about: "50 kohm between the water electrodes, SeaBotix: stops, latched after drying",
        seconds: 6.0,
        vehicle: lbv300,
        run: ground_fault,
    },
    Scenario {
        name: "overtemp-legacy",
        about: "a Legacy thruster's winding driven hot: stops at 110 C, resumes after cooling to 100 C",
        seconds: 60.0,
        vehicle: legacy6,
        run: overtemp,
    },
    Scenario {
        name: "overtemp-seabotix",
        about: "a SeaBotix thruster's winding driven hot: stops at 110 C, resumes after cooling to 100 C",
        seconds: 60.0,
        vehicle: lbv300,
        run: overtemp,
    },
    Scenario {
        name: "stall-legacy",
        about: "a rope in a Legacy thruster's propeller: stall in 400 ms, cleared by a zero order",
        seconds: 6.0,
        vehicle: legacy6,
        run: stall,
    },
    Scenario {
        name: "stall-seabotix",
        about: "a rope in a SeaBotix thruster's propeller: stall in 400 ms, cleared by a zero order",
        seconds: 6.0,
        vehicle: lbv300,
        run: stall,
    },
    Scenario {
        name: "hall-legacy",
        about: "a Legacy thruster's hall sensors unplugged (000): stops at once, resumes when they read normal",
        seconds: 6.0,
        vehicle: legacy6,
        run: hall,
    },
    Scenario {
        name: "hall-seabotix",
        about: "a SeaBotix thruster's hall sensors unplugged (000): stops at once, resumes when they read normal",
        seconds: 6.0,
        vehicle: lbv300,
        run: hall,
    },
    Scenario {
        name: "bad-frames",
        about: "corrupted status frames, orders with bad checksums and out-of-range orders: counted, change nothing",
        seconds: 8.0,
        vehicle: mixed,
        run: bad_frames,
    },
    Scenario {
        name: "missing-thruster",
        about: "one thruster unpowered: found by its first NACK, retried with back-off, the others unslowed",
        seconds: 8.0,
        vehicle: lbv300,
        run: missing_thruster,
    },
    Scenario {
        name: "stuck-sda",
        about: "a slave holds SDA low: the master clocks the bus free and polling resumes",
        seconds: 4.0,
        vehicle: lbv300,
        run: stuck_sda,
    },
    Scenario {
        name: "reset-mid-transfer",
        about: "a thruster loses power mid-transfer: the master times out, recovers, and the thruster rejoins",
        seconds: 6.0,
        vehicle: mixed,
        run: reset_mid_transfer,
    },
    Scenario {
        name: "console-silence",
        about: "the console link drops while armed: neutral after 3 s without sticks, disarmed 5 s after the last \
                heartbeat, no restart until re-armed",
        seconds: 11.0,
        vehicle: lbv300,
        run: console_silence,
    },
    Scenario {
        name: "battery-lost",
        about: "the BAT board's CAN frames stop for 3 s: flagged stale after 1 s, resumed after",
        seconds: 8.0,
        vehicle: lbv300,
        run: battery_lost,
    },
    Scenario {
        name: "battery-bits",
        about: "BAT status bits flip: start-up report of every bit, then only the switched bits",
        seconds: 5.0,
        vehicle: lbv300,
        run: battery_bits,
    },
    Scenario {
        name: "acceptance",
        about: "the master's acceptance test against a SeaBotix and a Legacy thruster, the bench acting as operator",
        seconds: 60.0,
        vehicle: dev_kits,
        run: acceptance,
    },
    Scenario {
        name: "soak",
        about: "random faults and traffic over a long run: every order applied, no task stalled",
        seconds: 120.0,
        vehicle: mixed,
        run: soak,
    },
];

/// The scenario called `name`.
pub fn find(name: &str) -> Option<&'static Scenario> {
    SCENARIOS.iter().find(|scenario| scenario.name == name)
}

/// Run a scenario for `seconds` (its default when None), with `monitor` watching every sample, and report.
pub fn run_with(
    scenario: &Scenario,
    seed: u64,
    seconds: Option<f64>,
    monitor: Option<crate::bench::Monitor>,
) -> (Report, Bench) {
    let wall = std::time::Instant::now();
    let seconds = seconds.unwrap_or(scenario.seconds).max(0.1);
    let mut bench = Bench::new(&(scenario.vehicle)(seed));
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
        seed,
        passed,
        sim_seconds: round(sim_seconds, 3),
        wall_seconds: round(wall_seconds, 3),
        checks: run.checks,
        metrics: run.metrics,
    };
    (report, run.bench)
}

fn round(value: f64, places: i32) -> f64 {
    let scale = 10f64.powi(places);
    (value * scale).round() / scale
}

/// Checks and figures every run gets: no task stalled, link statistics.
fn common_checks(run: &mut Run) {
    let (steps, busy_rounds, polls) = run.bench.counters();
    let bites: u32 = run
        .bench
        .thrusters
        .iter()
        .map(|thruster| thruster.watchdog_bites.get())
        .sum();
    run.check(
        "no task stalled",
        busy_rounds == 0 && bites == 0,
        format!("watchdog bites {bites}, busy rounds {busy_rounds}"),
    );
    let seconds = run.bench.seconds().max(1e-9);
    let bus = run.bench.bus().borrow();
    let utilisation = bus.bits as f64 * 10e-6 / seconds;
    let (recoveries, transfers) = (bus.recoveries, bus.transfers);
    drop(bus);
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
    let rejected: u32 = run
        .bench
        .thrusters
        .iter()
        .map(|thruster| thruster.line.resets.get())
        .sum();
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
        .map(|thruster| {
            round(
                thruster.limited_steps.get() as f64 * crate::bench::STEP.as_micros() as f64 / 1e6,
                3,
            )
        })
        .collect();
    run.metric("current_limited_seconds", json!(limited));
    run.metric("steps", json!(steps));
    run.metric("task_polls", json!(polls));
    run.metric("console_frames_received", json!(run.bench.ground.seen.frames));
}

fn dive(run: &mut Run) {
    run.arm_and_go(AHEAD);
    let acked = run.bench.ground.seen.acks.first().copied();
    run.check(
        "arming accepted",
        acked == Some((400, 0)),
        format!("first COMMAND_ACK {acked:?}"),
    );

    // Console to wire: a new stick position reaches thruster 1's controller.
    let before = run.bench.thrusters[0].shared().link.try_get().map(|link| link.order);
    let latency = run.run_until(0.5, |bench| {
        bench.thrusters[0].shared().link.try_get().map(|link| link.order) != before
    });
    let latency_ms = latency.map(|s| round(s * 1e3, 2));
    run.metric("console_to_wire_latency_ms", json!(latency_ms));
    run.check(
        "stick reaches the thruster within 40 ms",
        latency.is_some_and(|s| s <= 0.04),
        format!("{latency_ms:?} ms"),
    );

    run.run_for(3.0);
    let rpm: Vec<f64> = (0..4).map(|i| round(run.rpm(i), 0)).collect();
    run.check(
        "the horizontal thrusters turn ahead",
        rpm.iter().all(|r| *r > 800.0),
        format!("rpm {rpm:?}"),
    );
    // SeaBotix thrusters report their speed; Legacy ones only their current (IDS 8.4.1).
    let seen = run.bench.ground.seen.clone();
    let moving = run
        .bench
        .thrusters
        .iter()
        .zip(seen.rpm.iter().zip(seen.current_ca))
        .take(4)
        .all(|(thruster, (rpm, ca))| match thruster.config.family {
            Family::SeaBotix => *rpm > 500,
            Family::Legacy => ca > 0,
        });
    run.check(
        "ESC telemetry reaches the console",
        moving,
        format!("telemetry rpm {:?}, cA {:?}", seen.rpm, seen.current_ca),
    );
    run.check(
        "the ground station sees it armed",
        run.bench.ground.seen.armed,
        "HEARTBEAT armed flag",
    );

    run.bench.ground.sticks = Some(ManualInput { r: 500, ..AHEAD });
    run.run_for(3.0);
    let yaw: Vec<f64> = (0..4).map(|i| round(run.rpm(i), 0)).collect();
    let differs = (yaw[0] - yaw[1]).abs() > 300.0;
    run.check("yaw splits the horizontal thrusters", differs, format!("rpm {yaw:?}"));

    run.disarm();
    run.run_for(2.0);
    let duties: Vec<i16> = run
        .bench
        .thrusters
        .iter()
        .map(|thruster| thruster.drive().1.value())
        .collect();
    let still: Vec<f64> = (0..run.bench.thrusters.len()).map(|i| round(run.rpm(i), 0)).collect();
    run.check(
        "disarmed, every thruster stops driving and slows",
        duties.iter().all(|d| *d == 0) && still.iter().all(|r| (0.0..300.0).contains(r)),
        format!("duty {duties:?}, rpm {still:?}"),
    );
    let faults: Vec<u8> = (0..run.bench.thrusters.len()).map(|i| run.faults(i).bits()).collect();
    run.check(
        "no faults in a clean dive",
        faults.iter().all(|f| *f == 0),
        format!("fault bits {faults:?}"),
    );
    run.metric("battery_v_at_end", json!(round(run.bench.battery.voltage, 2)));
}

/// Drive ahead, then let `inject` act on thruster 1; returns how long the bridge took to coast (None: it kept
/// driving for 1 s).
fn inject_and_time(run: &mut Run, inject: impl FnOnce(&mut Bench)) -> Option<f64> {
    run.arm_and_go(AHEAD);
    run.run_for(1.5);
    inject(&mut run.bench);
    run.run_until(1.0, |bench| bench.thrusters[0].drive().1.value() == 0)
}

fn coasted_within_a_sample(run: &mut Run, took: Option<f64>) {
    let ms = took.map(|s| round(s * 1e3, 2));
    run.metric("reaction_ms", json!(ms));
    run.check(
        "T1 stops within one 1 ms sample",
        took.is_some_and(|s| s <= 0.0011),
        format!("coasted after {ms:?} ms"),
    );
}

/// Thruster 1 reports `fault` in its status.
fn reported(run: &mut Run, fault: Faults) {
    let faults = run.faults(0);
    run.check(
        &format!("{} reported", fault.name()),
        faults.contains(fault),
        format!("faults {:#04x}", faults.bits()),
    );
}

/// Thruster 1 reports no fault and drives ahead again.
fn drives_again(run: &mut Run, name: &str) {
    let (faults, rpm) = (run.faults(0), run.rpm(0));
    run.check(
        name,
        faults.is_empty() && rpm > 800.0,
        format!("faults {:#04x}, rpm {rpm:.0}", faults.bits()),
    );
}

fn others_keep_working(run: &mut Run) {
    let rpm: Vec<f64> = (1..4).map(|i| round(run.rpm(i), 0)).collect();
    run.check(
        "the other thrusters keep working",
        rpm.iter().all(|r| *r > 800.0),
        format!("T2-T4 rpm {rpm:?}"),
    );
}

fn family(run: &Run) -> Family {
    run.bench.thrusters[0].config.family
}

fn water(run: &mut Run) {
    let legacy = family(run) == Family::Legacy;
    let took = inject_and_time(run, |bench| bench.thrusters[0].plant.borrow_mut().water_ohms = 500_000);
    if legacy {
        coasted_within_a_sample(run, took);
    } else {
        run.check(
            "SeaBotix keeps driving on water",
            took.is_none(),
            format!("coasted after {took:?} s"),
        );
    }
    run.run_for(0.5);
    reported(run, Faults::WATER);
    run.check("the console hears of it", run.said("T1 fault: water"), "STATUSTEXT");
    others_keep_working(run);
    run.bench.thrusters[0].plant.borrow_mut().water_ohms = 20_000_000;
    run.run_for(1.0);
    let still = run.faults(0).contains(Faults::WATER);
    if legacy {
        let duty = run.duty(0);
        run.check(
            "Legacy: water latched until power cycle",
            still && duty == 0,
            format!("duty {duty} after drying"),
        );
    } else {
        run.check(
            "SeaBotix: the warning clears when dry",
            !still && run.rpm(0) > 800.0,
            format!("rpm {:.0}", run.rpm(0)),
        );
    }
}

fn ground_fault(run: &mut Run) {
    let took = inject_and_time(run, |bench| bench.thrusters[0].plant.borrow_mut().water_ohms = 50_000);
    coasted_within_a_sample(run, took);
    run.run_for(0.5);
    reported(run, Faults::GROUND);
    others_keep_working(run);
    run.bench.thrusters[0].plant.borrow_mut().water_ohms = 20_000_000;
    run.run_for(1.5);
    run.check(
        "latched until power cycle",
        run.faults(0).contains(Faults::GROUND) && run.duty(0) == 0,
        format!(
            "faults {:#04x}, duty {} after drying",
            run.faults(0).bits(),
            run.duty(0)
        ),
    );
}

fn overtemp(run: &mut Run) {
    run.arm_and_go(AHEAD);
    run.run_for(1.0);
    // The winding's surroundings held at 150 C: it heats with a 30 s time constant.
    run.bench.thrusters[0].plant.borrow_mut().ambient_c = 150.0;
    run.bench.note("T1: surroundings at 150 C");
    let stopped = run.run_until(50.0, |bench| bench.thrusters[0].drive().1.value() == 0);
    let at = run.bench.thrusters[0].plant.borrow().winding_c();
    run.check(
        "stops at 110 C",
        // The ADC resolves 0.1 C: the winding reads 110.0 C from 109.95 C up.
        stopped.is_some() && (109.9..111.0).contains(&at),
        format!("coasted after {stopped:?} s at {at:.2} C"),
    );
    reported(run, Faults::OVERTEMP);
    run.bench.thrusters[0].plant.borrow_mut().ambient_c = 15.0;
    run.bench.note("T1: surroundings back to 15 C");
    let resumed = run.run_until(20.0, |bench| bench.thrusters[0].drive().1.value() != 0);
    let at = run.bench.thrusters[0].plant.borrow().winding_c();
    run.check(
        "resumes after cooling to 100 C",
        resumed.is_some() && (99.0..100.1).contains(&at),
        format!("drove again after {resumed:?} s at {at:.2} C"),
    );
}

fn stall(run: &mut Run) {
    let took = inject_and_time(run, |bench| {
        bench.thrusters[0].plant.borrow_mut().blocked = true;
        bench.note("T1: propeller blocked");
    });
    let ms = took.map(|s| round(s * 1e3, 1));
    run.metric("stall_detected_after_ms", json!(ms));
    // The window counts pulses over the last 400 ms: the last pulses before the block are in it at first.
    run.check(
        "stall stops it within the 400 ms window",
        took.is_some_and(|s| (0.39..=0.41).contains(&s)),
        format!("{ms:?} ms"),
    );
    run.run_for(0.2);
    reported(run, Faults::STALL);
    others_keep_working(run);
    run.bench.thrusters[0].plant.borrow_mut().blocked = false;
    run.bench.note("T1: propeller freed");
    run.run_for(1.0);
    run.check(
        "still stopped until a zero order",
        run.rpm(0).abs() < 100.0,
        format!("rpm {:.0}", run.rpm(0)),
    );
    run.bench.ground.sticks = Some(NEUTRAL);
    run.run_for(0.5);
    run.bench.ground.sticks = Some(AHEAD);
    run.run_for(1.5);
    drives_again(run, "a zero order clears it and the next order drives");
}

fn hall(run: &mut Run) {
    let took = inject_and_time(run, |bench| {
        bench.thrusters[0].plant.borrow_mut().hall_fault = Some(thruster_fw::hall::HallState::from_bits(0));
        bench.note("T1: halls unplugged");
    });
    let ms = took.map(|s| round(s * 1e3, 2));
    run.metric("reaction_ms", json!(ms));
    run.check(
        "coasts at once",
        took.is_some_and(|s| s <= 0.0011),
        format!("{ms:?} ms"),
    );
    run.run_for(0.2);
    reported(run, Faults::HALL);
    others_keep_working(run);
    run.bench.thrusters[0].plant.borrow_mut().hall_fault = None;
    run.bench.note("T1: halls plugged in");
    run.run_for(1.5);
    drives_again(run, "clears and drives when the halls read normal");
}

fn bad_frames(run: &mut Run) {
    run.arm_and_go(AHEAD);
    run.run_for(1.0);
    run.bench.bus().borrow_mut().slaves[1].corrupt = 0x01;
    run.bench.note("T2: status bytes corrupted");
    run.run_for(1.0);
    let health = |run: &Run, i: usize| {
        run.bench.master.shared.thrusters[i]
            .try_get()
            .map(|r| r.health)
            .unwrap_or_default()
    };
    let h = health(run, 1);
    run.check(
        "bad status frames are counted",
        h.bad_type + h.bad_checksum > 0,
        format!("{h:?}"),
    );
    run.check(
        "and mark the thruster offline",
        !h.online,
        format!("online {}", h.online),
    );
    run.bench.bus().borrow_mut().slaves[1].corrupt = 0;
    run.run_for(1.0);
    run.check(
        "it comes back once the line is clean",
        health(run, 1).online,
        "online again",
    );

    // Orders with a bad checksum: the thruster discards them and keeps its last valid order.
    let before = run.bench.thrusters[2]
        .shared()
        .link
        .try_get()
        .map(|link| (link.orders, link.order));
    run.bench.bus().borrow_mut().slaves[2].corrupt_orders = 0x55;
    run.bench.note("T3: orders corrupted");
    run.bench.ground.sticks = Some(ManualInput { x: -600, ..AHEAD });
    run.run_for(1.0);
    let after = run.bench.thrusters[2]
        .shared()
        .link
        .try_get()
        .map(|link| (link.orders, link.order));
    run.check(
        "corrupted orders change nothing",
        before == after,
        format!("before {before:?}, after {after:?}"),
    );
    run.check(
        "T3 keeps its last valid order",
        run.rpm(2) > 800.0,
        format!("T3 rpm {:.0}", run.rpm(2)),
    );
    run.bench.bus().borrow_mut().slaves[2].corrupt_orders = 0;
    run.run_for(1.5);
    run.check(
        "valid orders apply again",
        run.rpm(2) < -800.0,
        format!("T3 rpm {:.0}", run.rpm(2)),
    );

    // Orders with a good checksum but an out-of-range SPEED byte: discarded the same way.
    let before = run.bench.thrusters[2]
        .shared()
        .link
        .try_get()
        .map(|link| (link.orders, link.order));
    run.bench.bus().borrow_mut().slaves[2].out_of_range_orders = true;
    run.bench.note("T3: orders out of range");
    run.bench.ground.sticks = Some(AHEAD);
    run.run_for(1.0);
    let after = run.bench.thrusters[2]
        .shared()
        .link
        .try_get()
        .map(|link| (link.orders, link.order));
    run.check(
        "out-of-range orders change nothing",
        before == after,
        format!("before {before:?}, after {after:?}"),
    );
    run.bench.bus().borrow_mut().slaves[2].out_of_range_orders = false;
}

fn missing_thruster(run: &mut Run) {
    run.bench.bus().borrow_mut().slaves[3].powered = false;
    run.bench.note("T4 unpowered");
    run.arm_and_go(AHEAD);
    run.run_for(4.0);
    let health = |run: &Run, i: usize| {
        run.bench.master.shared.thrusters[i]
            .try_get()
            .map(|r| r.health)
            .unwrap_or_default()
    };
    let missing = health(run, 3);
    run.check(
        "the missing thruster is offline",
        !missing.online && missing.nack > 0,
        format!("{missing:?}"),
    );
    run.check(
        "retried with back-off",
        (3..=12).contains(&missing.nack),
        format!("{} NACKs in ~4.7 s", missing.nack),
    );
    let seconds = run.bench.seconds();
    let rates: Vec<f64> = [0usize, 1, 2, 4, 5]
        .iter()
        .map(|i| f64::from(health(run, *i).good) / seconds)
        .collect();
    run.check(
        "the others still poll at ~50 Hz",
        rates.iter().all(|r| *r > 45.0),
        format!("{rates:?} Hz"),
    );
    run.check("the console hears of it", run.said("T4 offline"), "STATUSTEXT");
    run.bench.bus().borrow_mut().slaves[3].powered = true;
    run.bench.note("T4 powered");
    run.run_for(3.0);
    run.check(
        "it joins when it answers",
        health(run, 3).online && run.rpm(3) > 800.0,
        format!("rpm {:.0}", run.rpm(3)),
    );
}

fn stuck_sda(run: &mut Run) {
    run.arm_and_go(AHEAD);
    run.run_for(1.0);
    let before = run.bench.bus().borrow().recoveries;
    run.bench.bus().borrow_mut().sda_stuck = true;
    run.bench.note("SDA held low");
    let freed = run.run_until(1.0, |bench| !bench.bus().borrow().sda_stuck);
    run.check(
        "the master clocks the bus free",
        freed.is_some(),
        format!("after {freed:?} s"),
    );
    run.run_for(1.0);
    let recoveries = run.bench.bus().borrow().recoveries - before;
    let online = (0..6).all(|i| {
        run.bench.master.shared.thrusters[i]
            .try_get()
            .is_some_and(|r| r.health.online)
    });
    run.check(
        "polling resumes",
        online && recoveries >= 1,
        format!("{recoveries} recoveries, all online {online}"),
    );
}

fn reset_mid_transfer(run: &mut Run) {
    run.arm_and_go(AHEAD);
    run.run_for(1.0);
    // Cut T3 while a transfer to it is under way.
    let _ = run.run_until(0.1, |bench| bench.bus().borrow().transfers % 13 == 7);
    run.bench.note("T3 power cut");
    run.bench.power_cycle(2, Duration::from_millis(30));
    run.bench.note("T3 power back");
    run.run_for(2.0);
    let h = run.bench.master.shared.thrusters[2]
        .try_get()
        .map(|r| r.health)
        .unwrap_or_default();
    run.check("the master rides it out", h.online, format!("{h:?}"));
    run.check(
        "the thruster rejoins and follows its order",
        run.rpm(2) > 800.0,
        format!("rpm {:.0}", run.rpm(2)),
    );
    others_keep_working(run);
}

fn console_silence(run: &mut Run) {
    run.arm_and_go(AHEAD);
    run.run_for(1.0);
    run.bench.ground.connected = false;
    run.bench.note("console link lost");
    // FS_PILOT_TIMEOUT (3 s) after the last stick frame, up to 0.1 s before the loss.
    let neutral = run.run_until(4.0, |bench| {
        bench
            .master
            .shared
            .orders
            .try_get()
            .is_some_and(|orders| orders.iter().all(|order| order.speed.is_zero()))
    });
    run.check(
        "neutral after 3 s without sticks",
        neutral.is_some_and(|s| (2.85..=3.05).contains(&s)),
        format!("after {neutral:?} s (the last stick frame was up to 0.1 s before the loss)"),
    );
    let armed = run.bench.master.shared.vehicle.try_get().is_some_and(|v| v.armed);
    run.check("still armed while neutral", armed, "");
    // FS_GCS_TIMEOUT (5 s) after the last heartbeat, up to 1 s before the loss.
    let disarmed = run
        .run_until(3.0, |bench| {
            !bench.master.shared.vehicle.try_get().is_some_and(|v| v.armed)
        })
        .zip(neutral)
        .map(|(disarmed, neutral)| disarmed + neutral);
    run.check(
        "disarms 5 s after the last heartbeat",
        disarmed.is_some_and(|s| (3.95..=5.05).contains(&s)),
        format!("after {disarmed:?} s (the last heartbeat was up to 1 s before the loss)"),
    );
    run.run_for(0.5);
    let duties: Vec<i16> = (0..6).map(|i| run.duty(i)).collect();
    run.check(
        "every thruster stops driving",
        duties.iter().all(|d| *d == 0),
        format!("duty {duties:?}"),
    );
    run.bench.ground.connected = true;
    run.bench.note("console link back");
    run.run_for(1.5);
    let duties: Vec<i16> = (0..6).map(|i| run.duty(i)).collect();
    run.check(
        "no restart until re-armed",
        duties.iter().all(|d| *d == 0),
        format!("duty {duties:?}"),
    );
    run.check("the console hears why", run.said("Failsafe"), "STATUSTEXT");
}

fn battery_lost(run: &mut Run) {
    run.run_for(1.5);
    let fresh = run.bench.master.shared.battery.try_get().is_some_and(|b| !b.stale);
    run.check("battery data fresh at first", fresh, "");
    run.bench.battery.sending = false;
    run.bench.note("BAT frames lost");
    let stale = run.run_until(2.0, |bench| {
        bench.master.shared.battery.try_get().is_some_and(|b| b.stale)
    });
    run.check(
        "flagged stale after 1 s",
        stale.is_some_and(|s| (0.9..=1.2).contains(&s)),
        format!("after {stale:?} s"),
    );
    run.run_for(2.0);
    run.bench.battery.sending = true;
    run.bench.note("BAT frames back");
    run.run_for(1.0);
    let fresh = run.bench.master.shared.battery.try_get().is_some_and(|b| !b.stale);
    run.check("resumed", fresh && run.said("BAT data resumed"), "");
    run.check("the console hears of it", run.said("BAT data stale"), "");
}

fn battery_bits(run: &mut Run) {
    run.run_for(1.0);
    let startup = run
        .bench
        .ground
        .seen
        .texts
        .iter()
        .filter(|(_, text)| text.starts_with("BAT ") && text.contains('='))
        .count();
    run.check(
        "start-up report names every bit",
        startup == 12,
        format!("{startup} bit texts"),
    );
    let before = run.bench.ground.seen.texts.len();
    run.bench.battery.status = run.bench.battery.status.with(bat_proto::StatusBit::HsmSwFault, true);
    run.bench.note("BAT: HSM_SW_F set");
    run.run_for(1.0);
    let new: Vec<String> = run
        .bench
        .ground
        .seen
        .texts
        .iter()
        .skip(before)
        .map(|(_, text)| text.clone())
        .collect();
    let bits: Vec<&String> = new.iter().filter(|text| text.contains('=')).collect();
    run.check(
        "only the switched bit is reported",
        bits.len() == 1 && bits[0].contains("HSM_SW_F=1"),
        format!("{new:?}"),
    );
}

fn soak(run: &mut Run) {
    run.arm_and_go(AHEAD);
    let seconds = run.duration.as_micros() as f64 / 1e6;
    let mut mismatches = 0u32;
    let mut comparisons = 0u32;
    while run.bench.seconds() < seconds - 2.0 {
        // A random event every second or so: sticks, a fault that clears, a bus glitch.
        let pick = run.bench.random.below(8);
        let thruster = run.bench.random.below(6) as usize;
        match pick {
            0 => {
                let x = run.bench.random.below(2001) as i16 - 1000;
                let r = run.bench.random.below(1001) as i16 - 500;
                run.bench.ground.sticks = Some(ManualInput { x, y: 0, z: 500, r });
            }
            1 => {
                run.bench.bus().borrow_mut().slaves[thruster].corrupt = 0x10;
                run.run_for(0.2);
                run.bench.bus().borrow_mut().slaves[thruster].corrupt = 0;
            }
            2 => run.bench.bus().borrow_mut().sda_stuck = true,
            3 => {
                run.bench.thrusters[thruster].plant.borrow_mut().blocked = true;
                run.run_for(0.6);
                run.bench.thrusters[thruster].plant.borrow_mut().blocked = false;
                run.bench.ground.sticks = Some(NEUTRAL);
            }
            4 => run.bench.power_cycle(thruster, Duration::from_millis(40)),
            _ => {}
        }
        let pause = 0.5 + run.bench.random.unit();
        run.run_for(pause);
        // Once the links settle, every online thruster holds the order the master sends it.
        let orders = run.bench.master.shared.orders.try_get();
        for (i, thruster) in run.bench.thrusters.iter().enumerate() {
            let online = run.bench.master.shared.thrusters[i]
                .try_get()
                .is_some_and(|r| r.health.online);
            let held = thruster.shared().link.try_get().map(|link| link.order);
            let sent = orders.and_then(|orders| orders.get(i).copied());
            if online && held.is_some() {
                comparisons += 1;
                if held != sent {
                    mismatches += 1;
                }
            }
        }
    }
    run.metric("order_comparisons", json!(comparisons));
    run.check(
        "every online thruster holds the master's order",
        comparisons > 0 && mismatches == 0,
        format!("{mismatches} of {comparisons} snapshots differed"),
    );
    run.disarm();
}

/// The master image's acceptance test, the same script as on the dev kits, with the bench doing what it asks of
/// the person at the bench: the water-sensor resistor is 500 kohm, the held rotor a blocked propeller, the reset a
/// power cycle of the thruster started during a transfer.
fn acceptance(run: &mut Run) {
    let Some(desk) = run.bench.master.desk else {
        run.check("the master runs the acceptance test", false, "no acceptance desk");
        return;
    };
    let end = Instant::from_ticks(0) + run.duration;
    let mut reset: Option<usize> = None;
    let mut transfers = run.bench.bus().borrow().transfers;
    while desk.verdict.get().is_none() && run.bench.now() < end {
        run.bench.run_for(crate::bench::STEP);
        if let Some((prompt, family)) = desk.request.take() {
            let index = run
                .bench
                .thrusters
                .iter()
                .position(|thruster| thruster.config.family == family);
            run.bench.note(format!(
                "operator: {} on the {} thruster",
                prompt.name(),
                family_token(family)
            ));
            if let Some(thruster) = index.and_then(|i| run.bench.thrusters.get(i)) {
                let mut plant = thruster.plant.borrow_mut();
                match prompt {
                    Prompt::FitWaterResistor => plant.water_ohms = 500_000,
                    Prompt::RemoveWaterResistor => plant.water_ohms = DRY_WATER_OHMS,
                    Prompt::HoldRotor => plant.blocked = true,
                    Prompt::ReleaseRotor => plant.blocked = false,
                    Prompt::ResetThruster => reset = index,
                }
            }
            if !prompt.during_traffic() {
                desk.done.signal(());
            }
        }
        // The reset lands in the transfer that has just begun.
        let now = run.bench.bus().borrow().transfers;
        if now != transfers
            && let Some(index) = reset.take()
        {
            run.bench.note("operator: reset pressed mid-transfer");
            run.bench.power_cycle(index, Duration::from_millis(30));
        }
        transfers = run.bench.bus().borrow().transfers;
    }
    let results = desk.results.borrow().clone();
    for result in &results {
        let name = match result.family {
            Some(family) => format!("{} {}", family_token(family), result.step.name()),
            None => result.step.name().to_string(),
        };
        let figures: Vec<String> = result
            .figures
            .iter()
            .map(|figure| format!("{}={}", figure.name, figure.value))
            .collect();
        run.check(&name, result.passed, figures.join(" "));
    }
    let families = run.bench.thrusters.len();
    run.check(
        "every step ran on every thruster",
        results.len() == 1 + (Step::ALL.len() - 1) * families,
        format!("{} step results for {families} thrusters", results.len()),
    );
    let verdict = desk.verdict.get();
    run.check(
        "verdict PASS",
        verdict.is_some_and(|verdict| verdict.pass()),
        verdict.map_or("no verdict before the end of the run".to_string(), |v| v.to_string()),
    );
    run.check(
        "the console hears the verdict",
        run.said("acceptance PASS"),
        "STATUSTEXT",
    );
    run.metric("acceptance_seconds", json!(round(run.bench.seconds(), 1)));
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

    /// The virtual clock is one per process: bench runs take turns.
    static CLOCK: Mutex<()> = Mutex::new(());

    fn trace_of(seed: u64) -> String {
        let _clock = CLOCK.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        let (report, bench) = run_with(find("dive").unwrap(), seed, Some(4.0), None);
        assert!(report.sim_seconds >= 4.0);
        serde_json::to_string(&bench.trace).unwrap()
    }

    #[test]
    fn the_same_seed_gives_the_same_trace_bit_for_bit() {
        let first = trace_of(7);
        assert_eq!(first, trace_of(7));
        assert_ne!(first, trace_of(8), "the seed sets the motors' starting positions");
    }

    #[test]
    fn scenario_names_are_unique_and_cover_every_fault_on_both_families() {
        let names: Vec<&str> = SCENARIOS.iter().map(|scenario| scenario.name).collect();
        let mut unique = names.clone();
        unique.sort_unstable();
        unique.dedup();
        assert_eq!(unique.len(), names.len());
        assert!(
            find("acceptance").is_some(),
            "the dev kits' acceptance test runs with --all"
        );
        for fault in ["water", "ground-fault", "overtemp", "stall", "hall"] {
            for family in ["legacy", "seabotix"] {
                assert!(find(&format!("{fault}-{family}")).is_some(), "{fault}-{family}");
            }
        }
    }
}
