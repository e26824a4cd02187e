//! The dev-kit acceptance test looped back inside one chip: the master's acceptance script
//! (`lbv_master_fw::acceptance`) drives one motor-less thruster controller of the family under test over the
//! in-memory bus, and a scripted operator does at once what the prompts ask. The report lines are those of the
//! master's acceptance image (`ACCEPT ...`), so `lbv hil --replay` judges them.

use embassy_executor::Spawner;
use embassy_time::{Duration, Timer};
use lbv_master_fw::acceptance::{AcceptanceConfig, Operator, Prompt, StepResult, acceptance_test, family_token};
use static_cell::StaticCell;
use tmc_proto::Family;

use crate::i2c::{Bus, ControllerPort};
use crate::meter::{Meter, metered};
use crate::stacks::Stack;
use crate::thruster::{self, HallInput, Thruster};
use crate::{executors, halls, report, say};

/// The acceptance script, the master image's task.
static SCRIPT_METER: Meter = Meter::task("master acceptance script");
/// Time for the thruster's tasks to publish their first status (the dev kit waits for the other board to boot).
const START_DELAY: Duration = Duration::from_millis(50);

/// Start the loop for `family`.
pub fn start(thread: Spawner, family: Family) {
    let high = executors::start_commutation();
    halls::init();
    let thruster = Thruster::create(family, None);
    thruster.start(thread, high, HallInput::Interrupt);
    static BUS: StaticCell<Bus> = StaticCell::new();
    let bus: &'static Bus = BUS.init(Bus::new(&[thruster], false));
    report::spawn(thread, script(bus, thruster, family));
}

/// The person at the bench, scripted: does what each prompt asks as soon as it is asked.
struct ScriptedOperator {
    bus: &'static Bus,
    thruster: &'static Thruster,
}

impl Operator for ScriptedOperator {
    async fn prompt(&mut self, what: Prompt, family: Family) {
        say!(
            "ACCEPT prompt={} family={} wait_s=0: {}",
            what.name(),
            family_token(family),
            what.instruction()
        );
        match what {
            Prompt::FitWaterResistor => self.thruster.fit_water_resistor(true),
            Prompt::RemoveWaterResistor => self.thruster.fit_water_resistor(false),
            Prompt::HoldRotor => self.thruster.hold_rotor(true),
            Prompt::ReleaseRotor => self.thruster.hold_rotor(false),
            Prompt::ResetThruster => self.bus.reset_during_next_transfer(self.thruster),
        }
    }
}

#[embassy_executor::task]
async fn script(bus: &'static Bus, thruster: &'static Thruster, family: Family) {
    let run = async {
        Timer::after(START_DELAY).await;
        say!("ACCEPT start");
        let config = AcceptanceConfig {
            expect: Some(family),
            ..AcceptanceConfig::DEFAULT
        };
        let mut operator = ScriptedOperator { bus, thruster };
        let mut report = |result: StepResult| say!("ACCEPT {result}");
        let verdict = acceptance_test(&mut ControllerPort(bus), &mut operator, &config, &mut report).await;
        say!("ACCEPT {verdict}");
        verdict.pass()
    };
    let pass = metered(&SCRIPT_METER, Some(Stack::Master), run).await;
    finish(bus, pass);
}

/// The figures of the run, then the exit status.
fn finish(bus: &Bus, pass: bool) -> ! {
    let fed = report::bus(bus);
    let fit = report::stacks(&[("thruster", Stack::Thruster), ("master-acceptance", Stack::Master)]);
    let dispatch = report::cpu(
        &[
            &thruster::FAULT_METER,
            &thruster::CONTROL_METER,
            &thruster::I2C_METER,
            &thruster::HEALTH_METER,
            &SCRIPT_METER,
            &executors::BENCH_METER,
        ],
        &[
            &thruster::COMMUTATION_METER,
            &executors::COMMUTATION_ISR_METER,
            &halls::EDGE_ISR_METER,
            &crate::time::ALARM_METER,
            &thruster::MOTOR_MODEL_METER,
        ],
    );
    report::thruster_load(dispatch);
    report::latency();
    report::exit(pass && fed && fit)
}
