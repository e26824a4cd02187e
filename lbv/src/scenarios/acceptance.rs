//! The master image's acceptance test, the same script as on the dev kits, with the bench doing what it asks of
//! the person at the bench through the same faults the other scenarios inject: the water-sensor resistor is
//! [`Fault::Water`], the held rotor [`Fault::BlockedPropeller`], the reset a [`Fault::PowerCut`] that lands during a
//! transfer to the thruster.

use embassy_time::{Duration, Instant};
use lbv_master_fw::acceptance::report::{MARKER, Prompt, Report, Step, family_token};
use serde_json::json;

use super::fault::{Fault, WATER_OHMS};
use super::harness::{Run, round};
use crate::bench::STEP;

pub fn acceptance(run: &mut Run) {
    let Some(desk) = run.bench.master.desk.clone() else {
        run.check("the master runs the acceptance test", false, "no acceptance desk");
        return;
    };
    let end = Instant::from_ticks(0) + run.duration;
    let mut reset: Option<usize> = None;
    while desk.verdict.get().is_none() && run.bench.now() < end {
        run.bench.run_for(STEP);
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
            if let Some(thruster) = index {
                let water = Fault::Water {
                    thruster,
                    ohms: WATER_OHMS,
                };
                let rope = Fault::BlockedPropeller { thruster };
                match prompt {
                    Prompt::FitWaterResistor => run.inject(water),
                    Prompt::RemoveWaterResistor => run.clear(water),
                    Prompt::HoldRotor => run.inject(rope),
                    Prompt::ReleaseRotor => run.clear(rope),
                    Prompt::ResetThruster => reset = Some(thruster),
                }
            }
            if !prompt.during_traffic() {
                desk.done.signal(());
            }
        }
        // The reset lands in a transfer to the thruster.
        if let Some(thruster) = reset
            && run
                .bench
                .thruster_bus()
                .in_transfer_with(run.bench.thrusters[thruster].device)
        {
            reset = None;
            let cut = Fault::PowerCut { thruster };
            run.inject(cut);
            run.bench.run_for(Duration::from_millis(30));
            run.clear(cut);
        }
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
        verdict.map_or("no verdict before the end of the run".to_string(), |v| {
            let line = Report::Verdict((&v).into()).to_string();
            line.strip_prefix(MARKER).unwrap_or(&line).to_string()
        }),
    );
    run.check(
        "the console hears the verdict",
        run.said("acceptance PASS"),
        "STATUSTEXT",
    );
    run.metric("acceptance_seconds", json!(round(run.bench.seconds(), 1)));
}
