//! The script against scripted thrusters on virtual time: good ones of each family pass; each defect a step is
//! meant to catch fails that step and the verdict.

use super::report::Report;
use super::*;
use crate::recovery::BusConfig;
use crate::sim::thruster_bus;
use core::cell::{Cell, RefCell};
use lbv_sim::i2c::{Bus, Device, Reply, Route, Timing};
use lbv_sim::{Executor, clock};
use std::rc::Rc;
use thruster_fw::MasterLink;
use tmc_proto::{LegacyRevision, LegacyStatus, MotorKind, SeaBotixStatus};

/// How long a scripted thruster takes to show a new target in its status.
const LAG: Duration = Duration::from_millis(20);
/// The thruster firmware's link failsafe.
const FAILSAFE: Duration = Duration::from_secs(1);
/// Stall: driven with the rotor held this long.
const STALL_WINDOW: Duration = Duration::from_millis(400);
/// A reset thruster NACKs this long while it boots.
const BOOT: Duration = Duration::from_millis(20);

/// What is wrong with a scripted thruster, if anything.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct Defects {
    /// Takes orders whatever their checksum.
    takes_bad_checksums: bool,
    /// Takes out-of-range SPEED bytes as full forward.
    takes_out_of_range: bool,
    /// Never stops for a silent link.
    no_failsafe: bool,
    /// Restarts on a read after the failsafe tripped.
    restarts_on_read: bool,
    /// Never reports a stall.
    no_stall: bool,
    /// Its water sensor is not connected.
    no_water: bool,
    /// Holds SDA low after its reset until the master clocks it free, and the recovery does not help.
    stuck_after_reset: bool,
}

/// A thruster controller reduced to what the script can observe.
struct Thruster {
    link: MasterLink,
    defects: Defects,
    /// Answers nothing before this (booting).
    boot_until: Instant,
    /// Reset at this instant (the operator's press lands during the traffic that follows the prompt).
    reset_at: Option<Instant>,
    /// The master last addressed it (an order or a read).
    last_life: Instant,
    /// Valid orders seen when the failsafe last tripped: only a newer one restarts.
    failsafe_orders: Option<u32>,
    zero_orders_seen: u32,
    /// Target step and since when.
    target: i8,
    target_since: Instant,
    /// Step shown in the status.
    shown: i8,
    water: bool,
    water_latched: bool,
    held: bool,
    stall: bool,
    driven_held_since: Option<Instant>,
    stuck: bool,
}

impl Thruster {
    fn new(family: Family, defects: Defects) -> Self {
        Self {
            link: MasterLink::new(family),
            defects,
            boot_until: Instant::from_ticks(0),
            reset_at: None,
            last_life: Instant::from_ticks(0),
            failsafe_orders: None,
            zero_orders_seen: 0,
            target: 0,
            target_since: Instant::from_ticks(0),
            shown: 0,
            water: false,
            water_latched: false,
            held: false,
            stall: false,
            driven_held_since: None,
            stuck: false,
        }
    }

    fn family(&self) -> Family {
        self.link.family()
    }

    /// Bring the state up to `now`.
    fn update(&mut self, now: Instant) {
        if let Some(at) = self.reset_at
            && now >= at
        {
            let fresh = Thruster::new(self.family(), self.defects);
            *self = Thruster {
                boot_until: now + BOOT,
                last_life: now,
                stuck: self.defects.stuck_after_reset,
                // The operator lets go of nothing else: the resistor and the rotor are as they were.
                water: self.water,
                held: self.held,
                ..fresh
            };
        }
        if !self.defects.no_failsafe
            && self.failsafe_orders.is_none()
            && now.saturating_duration_since(self.last_life) >= FAILSAFE
        {
            self.failsafe_orders = Some(self.link.orders());
        }
        if self.failsafe_orders.is_some_and(|seen| seen != self.link.orders()) {
            self.failsafe_orders = None;
        }
        if self.link.zero_orders() != self.zero_orders_seen {
            self.zero_orders_seen = self.link.zero_orders();
            self.stall = false;
        }
        if self.water && !self.defects.no_water {
            self.water_latched = true;
        }
        let stopped =
            self.failsafe_orders.is_some() || self.stall || (self.family() == Family::Legacy && self.water_latched);
        let step = if stopped { 0 } else { self.link.order().speed.step() };
        if self.held && step != 0 {
            let since = *self.driven_held_since.get_or_insert(now);
            if !self.defects.no_stall && now.saturating_duration_since(since) >= STALL_WINDOW {
                self.stall = true;
            }
        } else {
            self.driven_held_since = None;
        }
        let turning = if self.held || self.stall { 0 } else { step };
        if turning != self.target {
            self.target = turning;
            self.target_since = now;
        }
        if now.saturating_duration_since(self.target_since) >= LAG {
            self.shown = self.target;
        }
    }

    /// Whether the bridge is driven now.
    fn driving(&self) -> bool {
        let stopped =
            self.failsafe_orders.is_some() || self.stall || (self.family() == Family::Legacy && self.water_latched);
        !stopped && !self.link.order().speed.is_zero()
    }

    fn status(&self) -> Status {
        let mut faults = Faults::NONE;
        match self.family() {
            Family::SeaBotix => faults.set(Faults::WATER, self.water && !self.defects.no_water),
            Family::Legacy => faults.set(Faults::WATER, self.water_latched),
        }
        faults.set(Faults::STALL, self.stall);
        let current = if self.driving() {
            (self.shown.unsigned_abs() / 10).max(1)
        } else {
            0
        };
        match self.family() {
            Family::SeaBotix => Status::SeaBotix(SeaBotixStatus {
                revision: 0,
                motor: MotorKind::Brushless,
                current_limited: true,
                faults,
                current_deciamps: current,
                speed: Speed::new_saturating(i32::from(self.shown)),
                temperature_c: 25,
            }),
            Family::Legacy => Status::Legacy(LegacyStatus {
                revision: LegacyRevision::AVEOX_BRUSHLESS,
                faults,
                max_power: MaxPower::Current { deciamps: current },
            }),
        }
    }

    fn take(&mut self, bytes: &[u8]) {
        if self.defects.takes_bad_checksums
            && let [mt, speed, info, _] = *bytes
        {
            let _ = self.link.accept(&[mt, speed, info, checksum(&[mt, speed, info])]);
            return;
        }
        if self.defects.takes_out_of_range
            && let [mt, speed, info, sum] = *bytes
            && Speed::from_byte(speed).is_err()
            && sum == checksum(&[mt, speed, info])
        {
            let full = Speed::MAX_FORWARD.to_byte();
            let _ = self.link.accept(&[mt, full, info, checksum(&[mt, full, info])]);
            return;
        }
        let _ = self.link.accept(bytes);
    }
}

/// The scripted thrusters, shared by their ends of the bus and the test's operator.
#[derive(Default)]
struct World {
    thrusters: Vec<Thruster>,
    prompts: Vec<(Prompt, Family)>,
    results: Vec<StepResult>,
}

impl World {
    fn thruster(&mut self, family: Family) -> Option<&mut Thruster> {
        self.thrusters.iter_mut().find(|thruster| thruster.family() == family)
    }
}

/// One family's address on the bus: the scripted thruster of that family, brought up to date at every transfer.
struct Reach(Rc<RefCell<World>>, Family);

impl Reach {
    /// The thruster, up to date, if it answers now.
    fn answer(&mut self, then: impl FnOnce(&mut Thruster, Instant)) -> Reply {
        let now = Instant::now();
        let mut world = self.0.borrow_mut();
        for thruster in &mut world.thrusters {
            thruster.update(now);
        }
        let Some(thruster) = world.thruster(self.1) else {
            return Reply::Nack;
        };
        if thruster.stuck {
            // Gone wrong in its reset: SDA held low, and no number of clocks helps.
            return Reply::HoldSda(u32::MAX);
        }
        if now < thruster.boot_until {
            return Reply::Nack;
        }
        if !thruster.defects.restarts_on_read {
            thruster.last_life = now;
        }
        then(thruster, now);
        thruster.update(now);
        Reply::Ack
    }
}

impl Device for Reach {
    fn address(&self) -> u8 {
        self.1.address()
    }

    fn write(&mut self, bytes: &[u8]) -> Reply {
        self.answer(|thruster, now| {
            thruster.take(bytes);
            thruster.last_life = now;
        })
    }

    fn read(&mut self, buffer: &mut [u8]) -> Reply {
        self.answer(|thruster, now| {
            if thruster.defects.restarts_on_read {
                thruster.last_life = now;
                thruster.failsafe_orders = None;
            }
            let frame = thruster.status().encode();
            for (byte, status) in buffer.iter_mut().zip(frame.as_bytes()) {
                *byte = *status;
            }
        })
    }
}

/// The person at the bench: does what is asked, after a moment.
struct Hands(Rc<RefCell<World>>);

impl Operator for Hands {
    async fn prompt(&mut self, what: Prompt, family: Family) {
        {
            let mut world = self.0.borrow_mut();
            world.prompts.push((what, family));
            let now = Instant::now();
            if let Some(thruster) = world.thruster(family) {
                match what {
                    Prompt::FitWaterResistor => thruster.water = true,
                    Prompt::RemoveWaterResistor => thruster.water = false,
                    Prompt::HoldRotor => thruster.held = true,
                    Prompt::ReleaseRotor => thruster.held = false,
                    Prompt::ResetThruster => thruster.reset_at = Some(now + Duration::from_millis(30)),
                }
            }
        }
        if !what.during_traffic() {
            Timer::after(Duration::from_millis(100)).await;
        }
    }

    fn reported(&mut self, result: &StepResult) {
        self.0.borrow_mut().results.push(result.clone());
    }
}

/// Run the script against `thrusters` on a simulated bus with `config`; the results, the verdict, the thrusters
/// and the bus.
fn run_with(
    thrusters: Vec<Thruster>,
    config: &AcceptanceConfig,
) -> (Vec<StepResult>, Verdict, Rc<RefCell<World>>, Bus) {
    let world = Rc::new(RefCell::new(World {
        thrusters,
        ..World::default()
    }));
    let bus = Bus::new(Timing::new(
        BusConfig::THRUSTERS.frequency_hz,
        BusConfig::THRUSTERS.timeout,
    ));
    for family in Family::ALL {
        bus.attach(Rc::new(RefCell::new(Reach(world.clone(), family))), Route::Direct);
    }
    let clock = clock::take();
    let verdict = Cell::new(None);
    let mut port = thruster_bus(&bus, &BusConfig::THRUSTERS);
    let mut hands = Hands(world.clone());
    let mut executor = Executor::new();
    executor.spawn(async {
        verdict.set(Some(acceptance_test(&mut port, &mut hands, config).await));
    });
    executor.run_until(&clock, Duration::from_secs(3600), Duration::from_micros(250), || {
        verdict.get().is_some()
    });
    drop(executor);
    let results = core::mem::take(&mut world.borrow_mut().results);
    (results, verdict.get().unwrap_or_default(), world, bus)
}

fn run(thrusters: Vec<Thruster>) -> (Vec<StepResult>, Verdict, Rc<RefCell<World>>, Bus) {
    let config = AcceptanceConfig {
        reset_window: Duration::from_secs(2),
        ..AcceptanceConfig::DEFAULT
    };
    run_with(thrusters, &config)
}

fn good(family: Family) -> Thruster {
    Thruster::new(family, Defects::default())
}

fn with(family: Family, defects: Defects) -> Thruster {
    Thruster::new(family, defects)
}

fn failed(results: &[StepResult]) -> Vec<String> {
    results
        .iter()
        .filter(|result| !result.passed)
        .map(|result| Report::Step(result.clone()).to_string())
        .collect()
}

fn result(results: &[StepResult], step: Step) -> &StepResult {
    results
        .iter()
        .find(|result| result.step == step)
        .unwrap_or_else(|| panic!("no {} step in {results:?}", step.name()))
}

#[test]
fn a_good_thruster_of_each_family_passes_every_step() {
    for family in Family::ALL {
        let (results, verdict, world, _) = run(vec![good(family)]);
        assert!(failed(&results).is_empty(), "{family:?}: {:#?}", failed(&results));
        let steps: Vec<Step> = results.iter().map(|result| result.step).collect();
        assert_eq!(steps, Step::ALL, "every step once, in order");
        assert!(verdict.pass());
        assert_eq!(verdict, Verdict { passed: 9, failed: 0 });
        let discovery = result(&results, Step::Discovery);
        assert_eq!(discovery.family, None);
        assert_eq!(discovery.figure_value("found"), Some(1));
        assert_eq!(discovery.figure_value(family_token(family)), Some(1));
        for result in &results[1..] {
            assert_eq!(result.family, Some(family));
        }
        let prompts: Vec<Prompt> = world.borrow().prompts.iter().map(|(prompt, _)| *prompt).collect();
        assert_eq!(
            prompts,
            [
                Prompt::HoldRotor,
                Prompt::ReleaseRotor,
                Prompt::FitWaterResistor,
                Prompt::RemoveWaterResistor,
                Prompt::ResetThruster
            ]
        );
        // The script leaves the thruster stopped.
        let world = world.borrow();
        assert!(world.thrusters[0].link.order().speed.is_zero());
    }
}

#[test]
fn the_figures_tell_what_was_measured() {
    let (results, ..) = run(vec![good(Family::SeaBotix)]);
    let sweep = result(&results, Step::SpeedForward);
    assert_eq!(sweep.figure_value("steps"), Some(102));
    assert_eq!(sweep.figure_value("ok"), Some(102));
    // Taken as followed once within one step of the order.
    assert!(
        matches!(sweep.figure_value("speed_at_full"), Some(101..=102)),
        "{sweep:?}"
    );
    let worst = sweep.figure_value("worst_ms").unwrap();
    assert!(
        (20..=40).contains(&worst),
        "the status shows a new step after 20 ms: {worst}"
    );
    let reverse = result(&results, Step::SpeedReverse);
    assert!(
        matches!(reverse.figure_value("speed_at_full"), Some(-102..=-101)),
        "{reverse:?}"
    );
    let stall = result(&results, Step::HeldRotor).figure_value("stall_ms").unwrap();
    assert!((400..=420).contains(&stall), "stall after the 400 ms window: {stall}");
    let reset = result(&results, Step::Reset);
    assert!(reset.figure_value("nack").unwrap() > 0, "{reset:?}");
    assert_eq!(reset.figure_value("drives_again"), Some(1));
    let failsafe = result(&results, Step::Failsafe);
    assert_eq!(failsafe.figure_value("off_at_first_read"), Some(1));
    assert_eq!(failsafe.figure_value("stayed"), Some(1));

    let (results, ..) = run(vec![good(Family::Legacy)]);
    let sweep = result(&results, Step::SpeedForward);
    assert!(
        sweep.figure_value("current_da").unwrap() >= 1,
        "Legacy brushless reports current only: {sweep:?}"
    );
    assert_eq!(sweep.figure_value("speed_at_full"), None);
    assert_eq!(result(&results, Step::Water).figure_value("latched"), Some(1));
}

#[test]
fn both_families_on_one_bus_are_tested_in_turn() {
    let (results, verdict, ..) = run(vec![good(Family::Legacy), good(Family::SeaBotix)]);
    assert!(verdict.pass(), "{:#?}", failed(&results));
    assert_eq!(verdict.passed, 17);
    assert_eq!(result(&results, Step::Discovery).figure_value("found"), Some(2));
    let families: Vec<Option<Family>> = results.iter().map(|result| result.family).collect();
    assert_eq!(families[1], Some(Family::SeaBotix), "SeaBotix first");
    assert_eq!(families[9], Some(Family::Legacy));
}

#[test]
fn every_line_the_script_reports_reads_back_as_written() {
    let (results, verdict, world, _) = run(vec![good(Family::Legacy), good(Family::SeaBotix)]);
    assert_eq!(verdict.passed, 17);
    let prompts = world.borrow().prompts.clone();
    let reports = results
        .into_iter()
        .map(Report::Step)
        .chain(
            prompts
                .into_iter()
                .map(|(prompt, family)| Report::prompt(prompt, family, Duration::from_secs(15))),
        )
        .chain([Report::Verdict((&verdict).into())]);
    for report in reports {
        let line = report.to_string();
        assert_eq!(Report::parse(&line), Ok(report), "{line}");
    }
}

#[test]
fn an_empty_bus_fails_discovery_and_stops_there() {
    let (results, verdict, ..) = run(Vec::new());
    assert_eq!(results.len(), 1);
    assert!(!results[0].passed);
    assert_eq!(
        Report::Step(results[0].clone()).to_string(),
        "ACCEPT step=discovery result=FAIL seabotix=0 legacy=0 found=0"
    );
    assert_eq!(verdict, Verdict { passed: 0, failed: 1 });
    assert!(!verdict.pass());
}

#[test]
fn the_expected_family_must_answer() {
    let config = AcceptanceConfig {
        expect: Some(Family::Legacy),
        reset_window: Duration::from_secs(2),
        ..AcceptanceConfig::DEFAULT
    };
    let (results, verdict, ..) = run_with(vec![good(Family::SeaBotix)], &config);
    assert!(!result(&results, Step::Discovery).passed);
    assert!(!verdict.pass());
    assert_eq!(
        verdict.failed,
        1,
        "the thruster found is still tested: {:#?}",
        failed(&results)
    );
}

/// Run one thruster with `defects`: the steps that failed, by name.
fn failing_steps(family: Family, defects: Defects) -> Vec<Step> {
    let (results, verdict, ..) = run(vec![with(family, defects)]);
    assert!(!verdict.pass());
    results
        .iter()
        .filter(|result| !result.passed)
        .map(|result| result.step)
        .collect()
}

#[test]
fn each_defect_fails_its_step() {
    let cases = [
        (
            Defects {
                takes_bad_checksums: true,
                ..Defects::default()
            },
            vec![Step::BadChecksum],
        ),
        (
            Defects {
                takes_out_of_range: true,
                ..Defects::default()
            },
            vec![Step::OutOfRange],
        ),
        (
            Defects {
                no_failsafe: true,
                ..Defects::default()
            },
            vec![Step::Failsafe],
        ),
        (
            Defects {
                restarts_on_read: true,
                ..Defects::default()
            },
            vec![Step::Failsafe],
        ),
        (
            Defects {
                no_stall: true,
                ..Defects::default()
            },
            vec![Step::HeldRotor],
        ),
        (
            Defects {
                no_water: true,
                ..Defects::default()
            },
            vec![Step::Water],
        ),
    ];
    for family in Family::ALL {
        for (defects, expected) in &cases {
            assert_eq!(&failing_steps(family, *defects), expected, "{family:?} {defects:?}");
        }
    }
}

#[test]
fn a_bus_the_recovery_cannot_free_fails_the_reset_step() {
    let defects = Defects {
        stuck_after_reset: true,
        ..Defects::default()
    };
    let (results, verdict, world, bus) = run(vec![with(Family::SeaBotix, defects)]);
    assert!(!verdict.pass());
    let reset = result(&results, Step::Reset);
    assert!(!reset.passed);
    assert!(reset.figure_value("bus_error").unwrap() > 0, "{reset:?}");
    assert!(reset.figure_value("recoveries").unwrap() > 0, "{reset:?}");
    assert_eq!(reset.figure_value("recovered_ms"), Some(-1));
    assert!(bus.stats().pin_clocks > 0, "the recovery clocked the bus");
    drop(world);
}

#[test]
fn what_following_an_order_means_per_family() {
    let config = AcceptanceConfig::DEFAULT;
    let seabotix = |speed: i8, current: u8| {
        Status::SeaBotix(SeaBotixStatus {
            revision: 0,
            motor: MotorKind::Brushless,
            current_limited: true,
            faults: Faults::NONE,
            current_deciamps: current,
            speed: Speed::new(speed).unwrap(),
            temperature_c: 25,
        })
    };
    assert!(follows(&seabotix(50, 3), 51, &config));
    assert!(!follows(&seabotix(49, 3), 51, &config));
    assert!(follows(&seabotix(-102, 30), -102, &config));
    assert!(at_rest(&seabotix(0, 0)));
    assert!(!at_rest(&seabotix(3, 0)), "still coasting");
    assert!(drive_off(&seabotix(3, 0)));

    let brushless = |deciamps: u8| {
        Status::Legacy(LegacyStatus {
            revision: LegacyRevision::AVEOX_BRUSHLESS,
            faults: Faults::NONE,
            max_power: MaxPower::Current { deciamps },
        })
    };
    assert!(follows(&brushless(0), 0, &config));
    assert!(!follows(&brushless(2), 0, &config));
    assert!(
        follows(&brushless(0), 10, &config),
        "below the drive step any status will do"
    );
    assert!(follows(&brushless(4), -60, &config));
    assert!(!follows(&brushless(0), 60, &config));
    assert!(at_rest(&brushless(0)));

    let brushed = |step: i8| {
        Status::Legacy(LegacyStatus {
            revision: LegacyRevision::BRUSHED_REV4,
            faults: Faults::NONE,
            max_power: MaxPower::Power(Speed::new(step).unwrap()),
        })
    };
    assert!(follows(&brushed(30), 30, &config));
    assert!(!follows(&brushed(20), 30, &config));
    assert!(drive_off(&brushed(0)) && !drive_off(&brushed(1)));

    let unknown = Status::Legacy(LegacyStatus {
        revision: LegacyRevision::ORIGINAL,
        faults: Faults::NONE,
        max_power: MaxPower::Raw(7),
    });
    assert!(
        !follows(&unknown, 0, &config),
        "a revision with no defined MAX POWER never passes"
    );
}
