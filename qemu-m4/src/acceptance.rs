//! The dev-kit acceptance test looped back inside one chip: the master's acceptance image
//! (`lbv_master_fw::run` with `MasterConfig::devkit(family)` and the acceptance `Script`) drives one motor-less
//! thruster controller of the family under test over the in-memory bus, and a scripted operator does at once what
//! the prompts ask. The report lines are those of the master's acceptance image (`acceptance::report::Report`), so
//! `lbv hil --replay` judges them; the console's ground station must hear the verdict too.

use embassy_executor::Spawner;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Timer};
use lbv_master_fw::MasterConfig;
use lbv_master_fw::acceptance::report::{Prompt, Report, StepResult, Verdict};
use lbv_master_fw::acceptance::{Operator, Script};
use lbv_master_fw::config::THRUSTER_BUS;
use lbv_station::Seen;
use tmc_proto::Family;

use crate::i2c::{self, Bus};
use crate::master::{self, MASTER_METER, MasterPorts};
use crate::meter::metered;
use crate::stacks::Stack;
use crate::thruster::{self, HallInput, Thruster};
use crate::{executors, halls, report, say, station};

/// The dev kits' masters, one per family.
static SEABOTIX: MasterConfig = MasterConfig::devkit(Family::SeaBotix);
static LEGACY: MasterConfig = MasterConfig::devkit(Family::Legacy);

/// The script's verdict, when it has one.
static VERDICT: Signal<CriticalSectionRawMutex, Verdict> = Signal::new();
/// How long the console may take to pass the verdict on to the ground station.
const CONSOLE_GRACE: Duration = Duration::from_millis(500);
/// The beginning of the console text that carries the verdict (`acceptance::report::verdict_text`).
const VERDICT_PASS: &str = "acceptance PASS";
const VERDICT_FAIL: &str = "acceptance FAIL";

/// Start the loop for `family`.
pub fn start(thread: Spawner, family: Family) {
    let config: &'static MasterConfig = match family {
        Family::SeaBotix => &SEABOTIX,
        Family::Legacy => &LEGACY,
    };
    let high = executors::start_commutation();
    halls::init();
    let buses = master::buses(config, thread, high, HallInput::Interrupt);
    let Some((bus, thruster)) = buses
        .get(usize::from(THRUSTER_BUS))
        .and_then(|bus| Some((*bus, *bus.thrusters().first()?)))
    else {
        report::fail("the dev kit's table has no thruster on its bus");
    };
    let operator = ScriptedOperator { bus, thruster };
    report::spawn(thread, master(master::ports(buses, Script(operator)), config));
    report::spawn(thread, station::receive());
    report::spawn(thread, finish_after_verdict(bus));
}

/// The person at the bench, scripted: does what each prompt asks as soon as it is asked, and keeps the log the
/// acceptance image writes.
struct ScriptedOperator {
    bus: &'static Bus,
    thruster: &'static Thruster,
}

impl Operator for ScriptedOperator {
    async fn prompt(&mut self, what: Prompt, family: Family) {
        say!("{}", Report::prompt(what, family, Duration::from_ticks(0)));
        match what {
            Prompt::FitWaterResistor => self.thruster.fit_water_resistor(true),
            Prompt::RemoveWaterResistor => self.thruster.fit_water_resistor(false),
            Prompt::HoldRotor => self.thruster.hold_rotor(true),
            Prompt::ReleaseRotor => self.thruster.hold_rotor(false),
            Prompt::ResetThruster => self.bus.cut_power_during_next_transfer(self.thruster),
        }
    }

    fn started(&mut self) {
        say!("{}", Report::Start);
    }

    fn reported(&mut self, result: &StepResult) {
        say!("{}", Report::Step(result.clone()));
    }

    fn concluded(&mut self, verdict: &Verdict) {
        say!("{}", Report::Verdict(verdict.into()));
        VERDICT.signal(*verdict);
    }
}

/// The master image: the acceptance script on the dev kit's bus, and every other task of the master.
#[embassy_executor::task]
async fn master(ports: MasterPorts<Script<ScriptedOperator>>, config: &'static MasterConfig) -> ! {
    master::run(ports, config).await
}

/// Once the script has its verdict and the console has had time to say it, the figures and the exit status.
#[embassy_executor::task]
async fn finish_after_verdict(bus: &'static Bus) {
    let verdict = metered(&executors::BENCH_METER, None, async {
        let verdict = VERDICT.wait().await;
        Timer::after(CONSOLE_GRACE).await;
        verdict
    })
    .await;
    let (frames, texts, said) = station::seen(|seen| (seen.frames, seen.texts.len(), said(seen))).await;
    let heard = said == Some(verdict.pass());
    say!(
        "CONSOLE the ground station read {frames} frames, {texts} texts; it heard the verdict: {}",
        if heard { "yes" } else { "NO" }
    );
    let fed = report::bus(bus);
    let fit = report::stacks(&[("thruster", Stack::Thruster), ("master-acceptance", Stack::Master)]);
    let dispatch = report::cpu(
        &[&thruster::THREAD_METER, &MASTER_METER],
        &[&executors::BENCH_METER],
        &[
            &thruster::COMMUTATION_METER,
            &executors::COMMUTATION_ISR_METER,
            &halls::EDGE_ISR_METER,
            &crate::time::ALARM_METER,
            &thruster::MOTOR_MODEL_METER,
            &i2c::BUS_MODEL_METER,
        ],
    );
    report::thruster_load(dispatch);
    report::latency();
    report::exit(verdict.pass() && heard && fed && fit)
}

/// The verdict the console's last verdict text said: passed or not.
fn said(seen: &Seen) -> Option<bool> {
    seen.texts.iter().rev().find_map(|(_, text)| {
        if text.starts_with(VERDICT_PASS) {
            Some(true)
        } else if text.starts_with(VERDICT_FAIL) {
            Some(false)
        } else {
            None
        }
    })
}
