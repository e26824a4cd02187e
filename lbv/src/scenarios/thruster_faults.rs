//! The IDS's thruster faults, on thruster 1 while the vehicle drives ahead: water, ground fault, overtemperature,
//! a stalled propeller, unplugged halls. Each checks the family's reaction (IDS 8.4) and that the others keep
//! working.

use serde_json::json;
use tmc_proto::{Family, Faults};

use super::fault::{Fault, GROUND_FAULT_OHMS, WATER_OHMS};
use super::harness::{
    AHEAD, NEUTRAL, Run, coasted_within_a_sample, drives_again, family, inject_and_time, others_keep_working, reported,
    round, stopped_after_consecutive_samples,
};
use thruster_fw::commutation::COAST;
use thruster_fw::faults::Thresholds;

pub fn water(run: &mut Run) {
    let legacy = family(run) == Family::Legacy;
    let water = Fault::Water {
        thruster: 0,
        ohms: WATER_OHMS,
    };
    let took = inject_and_time(run, water);
    if legacy {
        stopped_after_consecutive_samples(run, took, Thresholds::SPEC.latch_samples);
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
    run.clear(water);
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

pub fn ground_fault(run: &mut Run) {
    let ground_fault = Fault::Water {
        thruster: 0,
        ohms: GROUND_FAULT_OHMS,
    };
    let took = inject_and_time(run, ground_fault);
    stopped_after_consecutive_samples(run, took, Thresholds::SPEC.latch_samples);
    run.run_for(0.5);
    reported(run, Faults::GROUND);
    others_keep_working(run);
    run.clear(ground_fault);
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

pub fn overtemp(run: &mut Run) {
    run.arm_and_go(AHEAD);
    run.run_for(1.0);
    // The winding's surroundings held at 150 C: it heats with a 30 s time constant.
    let heat = Fault::Heat {
        thruster: 0,
        celsius: 150.0,
    };
    run.inject(heat);
    let stopped = run.run_until(50.0, |bench| bench.thrusters[0].drive().1.value() == 0);
    let at = run.bench.thrusters[0].plant.borrow().winding_c();
    run.check(
        "stops at 110 C",
        // The ADC resolves 0.1 C: the winding reads 110.0 C from 109.95 C up.
        stopped.is_some() && (109.9..111.0).contains(&at),
        format!("coasted after {stopped:?} s at {at:.2} C"),
    );
    reported(run, Faults::OVERTEMP);
    run.clear(heat);
    let resumed = run.run_until(20.0, |bench| bench.thrusters[0].drive().1.value() != 0);
    let at = run.bench.thrusters[0].plant.borrow().winding_c();
    run.check(
        "resumes after cooling to 100 C",
        resumed.is_some() && (99.0..100.1).contains(&at),
        format!("drove again after {resumed:?} s at {at:.2} C"),
    );
}

pub fn stall(run: &mut Run) {
    let rope = Fault::BlockedPropeller { thruster: 0 };
    let took = inject_and_time(run, rope);
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
    run.clear(rope);
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

pub fn hall(run: &mut Run) {
    let unplugged = Fault::HallsUnplugged { thruster: 0 };
    run.arm_and_go(AHEAD);
    run.run_for(1.5);
    run.inject(unplugged);
    // The commutation coasts the phases at once on the invalid state; the hall error (which stops the drive)
    // follows after its consecutive readings.
    let coasted = run.run_until(1.0, |bench| bench.thrusters[0].drive().0 == COAST);
    coasted_within_a_sample(run, coasted);
    let stopped = coasted.and_then(|s| {
        run.run_until(1.0, |bench| bench.thrusters[0].drive().1.value() == 0)
            .map(|more| s + more)
    });
    stopped_after_consecutive_samples(run, stopped, Thresholds::SPEC.hall_error_samples);
    run.run_for(0.2);
    reported(run, Faults::HALL);
    others_keep_working(run);
    run.clear(unplugged);
    run.run_for(1.5);
    drives_again(run, "clears and drives when the halls read normal");
}
