//! Faults on the thruster bus: corrupted frames both ways, a missing thruster, a stuck SDA, a thruster reset in the
//! middle of a transfer.

use embassy_time::Duration;
use lbv_master_fw::shared::ManualInput;

use super::fault::Fault;
use super::harness::{AHEAD, Run, others_keep_working};

/// Thruster `index`'s link as its controller holds it: valid orders received and the last one.
fn held(run: &Run, index: usize) -> Option<(u32, tmc_proto::Order)> {
    run.bench.thrusters[index]
        .shared()
        .link
        .try_get()
        .map(|link| (link.orders, link.order))
}

pub fn bad_frames(run: &mut Run) {
    run.arm_and_go(AHEAD);
    run.run_for(1.0);
    let noise = Fault::NoisyStatus {
        thruster: 1,
        mask: 0x01,
    };
    run.inject(noise);
    run.run_for(1.0);
    let h = run.health(1);
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
    run.clear(noise);
    run.run_for(1.0);
    run.check(
        "it comes back once the line is clean",
        run.health(1).online,
        "online again",
    );

    // Orders with a bad checksum: the thruster discards them and keeps its last valid order.
    let before = held(run, 2);
    let corrupt = Fault::CorruptOrders {
        thruster: 2,
        mask: 0x55,
    };
    run.inject(corrupt);
    run.bench.ground.sticks = Some(ManualInput { x: -600, ..AHEAD });
    run.run_for(1.0);
    let after = held(run, 2);
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
    run.clear(corrupt);
    run.run_for(1.5);
    run.check(
        "valid orders apply again",
        run.rpm(2) < -800.0,
        format!("T3 rpm {:.0}", run.rpm(2)),
    );

    // Orders with a good checksum but an out-of-range SPEED byte: discarded the same way.
    let before = held(run, 2);
    let out_of_range = Fault::OutOfRangeOrders { thruster: 2 };
    run.inject(out_of_range);
    run.bench.ground.sticks = Some(AHEAD);
    run.run_for(1.0);
    let after = held(run, 2);
    run.check(
        "out-of-range orders change nothing",
        before == after,
        format!("before {before:?}, after {after:?}"),
    );
    run.clear(out_of_range);
}

pub fn missing_thruster(run: &mut Run) {
    let missing = Fault::PowerCut { thruster: 3 };
    run.inject(missing);
    run.arm_and_go(AHEAD);
    run.run_for(4.0);
    let h = run.health(3);
    run.check(
        "the missing thruster is offline",
        !h.online && h.nack > 0,
        format!("{h:?}"),
    );
    run.check(
        "retried with back-off",
        (3..=12).contains(&h.nack),
        format!("{} NACKs in ~4.7 s", h.nack),
    );
    let seconds = run.bench.seconds();
    let rates: Vec<f64> = [0usize, 1, 2, 4, 5]
        .iter()
        .map(|i| f64::from(run.health(*i).good) / seconds)
        .collect();
    run.check(
        "the others still poll at ~50 Hz",
        rates.iter().all(|r| *r > 45.0),
        format!("{rates:?} Hz"),
    );
    run.check("the console hears of it", run.said("T4 offline"), "STATUSTEXT");
    run.clear(missing);
    run.run_for(3.0);
    run.check(
        "it joins when it answers",
        run.health(3).online && run.rpm(3) > 800.0,
        format!("rpm {:.0}", run.rpm(3)),
    );
}

/// A slave holds SDA low: the master's recovery (the core's UM10204 3.1.16 bit-bang, on the simulated lines)
/// clocks it free. First one stuck mid-byte (5 clocks to go); then one that needs more clocks than one recovery
/// gives (9, and the STOP's tenth), which the next recovery finishes.
pub fn stuck_sda(run: &mut Run) {
    run.arm_and_go(AHEAD);
    run.run_for(1.0);
    let recoveries = |run: &Run| -> u32 { (0..6).map(|i| run.health(i).recoveries).sum() };
    for (clocks, needed) in [(5, 1), (12, 2)] {
        let (stats, ran) = (run.bench.thruster_bus().stats(), recoveries(run));
        run.inject(Fault::SdaHeld { clocks });
        let freed = run.run_until(1.0, |bench| !bench.thruster_bus().sda_held());
        run.run_for(1.0);
        let clocked = run.bench.thruster_bus().stats().pin_clocks - stats.pin_clocks;
        let ran = recoveries(run) - ran;
        run.check(
            &format!("a slave needing {clocks} clocks is clocked free"),
            freed.is_some() && clocked >= u64::from(clocks) && ran == needed,
            format!("after {freed:?} s: {ran} recoveries, {clocked} clocks"),
        );
        let online = (0..6).all(|i| run.health(i).online);
        run.check(
            &format!("a slave needing {clocks} clocks: polling resumes"),
            online,
            format!("all online {online}"),
        );
    }
}

pub fn reset_mid_transfer(run: &mut Run) {
    run.arm_and_go(AHEAD);
    run.run_for(1.0);
    // Cut T3 while a transfer to it is under way.
    let device = run.bench.thrusters[2].device;
    let caught = run.run_until(0.1, |bench| bench.thruster_bus().in_transfer_with(device));
    run.check(
        "the cut lands mid-transfer",
        caught.is_some(),
        format!("after {caught:?} s"),
    );
    let cut = Fault::PowerCut { thruster: 2 };
    run.inject(cut);
    run.bench.run_for(Duration::from_millis(30));
    run.clear(cut);
    run.run_for(2.0);
    let h = run.health(2);
    run.check("the master rides it out", h.online, format!("{h:?}"));
    run.check(
        "the thruster rejoins and follows its order",
        run.rpm(2) > 800.0,
        format!("rpm {:.0}", run.rpm(2)),
    );
    others_keep_working(run);
}
