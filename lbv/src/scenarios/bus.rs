//! Faults on the thruster bus: corrupted frames both ways, a missing thruster, a stuck SDA, a thruster reset in the
//! middle of a transfer.

use embassy_time::{Duration, Instant};
use lbv_master_fw::mixer::ManualInput;
use lbv_master_fw::shared::LinkHealth;
use lbv_sim::i2c::{Data, Request, Transfer};

use serde_json::json;

use super::fault::Fault;
use super::harness::{AHEAD, NEUTRAL, Run, others_keep_working, round};
use crate::bench::Bench;

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
        "and the telemetry marked lost, the thruster online: its orders get through",
        h.online && h.status_lost && run.said("T2 status unreadable"),
        format!("online {}, status lost {}", h.online, h.status_lost),
    );
    run.clear(noise);
    run.run_for(1.0);
    run.check(
        "its status is read again once the line is clean",
        !run.health(1).status_lost && run.said("T2 status readable again"),
        format!("{:?}", run.health(1)),
    );

    // Orders with a bad checksum: the thruster discards them and keeps its last valid order.
    let before = held(run, 2);
    let corrupt = Fault::CorruptOrders {
        thruster: 2,
        mask: 0x55,
    };
    run.inject(corrupt);
    run.bench.ground.sticks = Some(ManualInput { x: -600, ..AHEAD });
    // Half a second: less than the refused orders' failsafe (see `corrupted_stop`).
    run.run_for(0.5);
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
    run.run_for(0.5);
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

/// What one power cut in the middle of a transfer to T3 did: how far into the transfer's bytes it landed, the
/// master's count of T3's link before the cut and once the torn transfer's poll was counted, the transfer as the
/// master saw it, the bus's count of torn transfers, and the time of the cut.
struct Tear {
    into: Duration,
    before: LinkHealth,
    after: LinkHealth,
    transfer: Option<Transfer>,
    torn: u64,
    at: Instant,
}

impl Tear {
    /// Where the cut landed, for a check's detail: "100 us into its bytes, in byte 2 of 4".
    fn landed(&self, run: &Run) -> String {
        let byte_time = run
            .bench
            .thruster_bus()
            .timing()
            .bit
            .as_ticks()
            .saturating_mul(9)
            .max(1);
        let byte = self.into.as_ticks() / byte_time + 1;
        let of = match self.transfer.as_ref().map(|transfer| &transfer.data) {
            Some(Data::Write(bytes) | Data::Read(bytes)) => format!(" of {}", bytes.len()),
            None => String::new(),
        };
        format!("{} us into its bytes, in byte {byte}{of}", self.into.as_micros())
    }

    /// Whether the cut landed after the transfer's first byte had moved.
    fn after_the_first_byte(&self, run: &Run) -> bool {
        self.into.as_ticks() >= run.bench.thruster_bus().timing().bit.as_ticks().saturating_mul(9)
    }
}

/// Cut T3's power 0.1 ms after the bytes of a transfer to it are seen moving `way` (in its second byte: the
/// fixed-step engine sees them a step late), let the master count the transfer's poll, and power T3 again 30 ms
/// after the cut.
fn tear(run: &mut Run, way: Request) -> Option<Tear> {
    let device = run.bench.thrusters[2].device;
    let moving = |bench: &Bench| {
        bench
            .thruster_bus()
            .bytes_moving(device)
            .filter(|(request, _)| *request == way)
    };
    run.run_until(0.5, |bench| moving(bench).is_some())?;
    run.bench.run_for(Duration::from_micros(100));
    let (_, since) = moving(&run.bench)?;
    let (before, torn) = (run.health(2), run.bench.thruster_bus().stats().torn);
    let at = run.bench.now();
    let bus = run.bench.thruster_bus().clone();
    bus.record(true);
    let cut = Fault::PowerCut { thruster: 2 };
    run.inject(cut);
    run.run_until(0.01, |bench| !bench.thruster_bus().in_transfer_with(device));
    // The master's poll ends with the transfer; its count is published then.
    run.bench.run_for(Duration::from_millis(1));
    let transfer = bus.take_log().into_iter().next();
    bus.record(false);
    let after = run.health(2);
    let torn = bus.stats().torn - torn;
    run.bench.run_for(
        Duration::from_millis(30)
            .checked_sub(run.bench.now() - at)
            .unwrap_or_default(),
    );
    run.clear(cut);
    Some(Tear {
        into: at - since,
        before,
        after,
        transfer,
        torn,
        at,
    })
}

/// The bytes of a transfer, in hex.
fn hex(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|byte| format!("{byte:02x}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// Whether the master said something containing `needle` at `at` or later.
fn said_since(run: &Run, at: Instant, needle: &str) -> bool {
    run.bench
        .ground
        .seen
        .texts
        .iter()
        .any(|(when, text)| *when >= at && text.contains(needle))
}

/// T3 loses power twice, each time between two bytes of a transfer to it. An unpowered slave lets SCL and SDA go
/// (they are pulled up), so the master clocks on: no SCL held, no timeout, nothing for a bus recovery to free.
/// First in an order: its next byte is not acknowledged, the master's driver reports a NACK, and the master takes
/// T3 offline at once ("no answer"). Then in a status read: the rest of the read is 0xFF, which the driver returns
/// as read, and the frame fails its checksum; that poll's order went through, so T3 goes offline at its next poll,
/// which nobody acknowledges. Each time T3 boots, the master's retry finds it, and it rejoins.
pub fn reset_mid_transfer(run: &mut Run) {
    run.arm_and_go(AHEAD);
    run.run_for(1.0);
    let family = run.bench.thrusters[2].config.family;

    let write = tear(run, Request::Write);
    run.check(
        "T3's power is cut in the middle of an order to it, after its first byte",
        write.as_ref().is_some_and(|tear| tear.after_the_first_byte(run)),
        write
            .as_ref()
            .map_or("no order to T3 caught".to_string(), |tear| tear.landed(run)),
    );
    if let Some(tear) = &write {
        let (before, after) = (tear.before, tear.after);
        let order = match tear
            .transfer
            .as_ref()
            .map(|transfer| (transfer.ok, transfer.address, &transfer.data))
        {
            Some((false, address, Data::Write(bytes))) if address == family.address() => Some(hex(bytes)),
            _ => None,
        };
        run.check(
            "the bus tears the order: the byte the cut lands in is not acknowledged",
            tear.torn == 1 && order.is_some(),
            match &order {
                Some(order) => format!("order {order} failed, {} transfer torn", tear.torn),
                None => format!("{:?}, {} torn", tear.transfer, tear.torn),
            },
        );
        run.check(
            "the master's driver reports a NACK: counted, the order not delivered, no timeout, no bus error",
            after.nack == before.nack + 1
                && after.delivered == before.delivered
                && (after.timeout, after.bus_error) == (before.timeout, before.bus_error),
            format!(
                "nack {} -> {}, delivered {} -> {}, timeout {}, bus error {}",
                before.nack, after.nack, before.delivered, after.delivered, after.timeout, after.bus_error
            ),
        );
        run.check(
            "the master takes T3 offline at once: \"T3 offline: no answer\"",
            !after.online && said_since(run, tear.at, "T3 offline: no answer"),
            format!("online {}", after.online),
        );
        run.run_for(0.5);
        let h = run.health(2);
        run.check(
            "T3 rejoins after its reboot: \"T3 online\"",
            h.online && said_since(run, tear.at, "T3 online"),
            format!("online {}, delivered {}", h.online, h.delivered),
        );
    }

    run.run_for(0.5);
    let read = tear(run, Request::Read);
    run.check(
        "T3's power is cut in the middle of a status read from it, after its first byte",
        read.as_ref().is_some_and(|tear| tear.after_the_first_byte(run)),
        read.as_ref()
            .map_or("no status read from T3 caught".to_string(), |tear| tear.landed(run)),
    );
    if let Some(tear) = &read {
        let (before, after) = (tear.before, tear.after);
        let bytes = match tear.transfer.as_ref().map(|transfer| (transfer.ok, &transfer.data)) {
            Some((true, Data::Read(bytes))) => Some(bytes.clone()),
            _ => None,
        };
        // The cut lands in the second byte: the first came through, the third on are the pull-ups' 0xFF.
        let pulled_up = bytes.as_ref().is_some_and(|bytes| {
            bytes.first() == Some(&family.status_type()) && bytes.iter().skip(2).all(|byte| *byte == 0xFF)
        });
        run.check(
            "the bus tears the read: the rest of it is 0xFF (SDA pulled up), which the master's driver returns as read",
            tear.torn == 1 && pulled_up,
            match &bytes {
                Some(bytes) => format!("read {}, {} transfer torn", hex(bytes), tear.torn),
                None => format!("{:?}, {} torn", tear.transfer, tear.torn),
            },
        );
        run.check(
            "the master finds a bad checksum: counted, that poll's order delivered, T3 still online",
            after.bad_checksum == before.bad_checksum + 1
                && after.delivered == before.delivered + 1
                && after.nack == before.nack
                && after.online,
            format!(
                "bad checksum {} -> {}, delivered {} -> {}, nack {}, online {}",
                before.bad_checksum, after.bad_checksum, before.delivered, after.delivered, after.nack, after.online
            ),
        );
        run.run_for(0.5);
        let h = run.health(2);
        run.check(
            "its next poll is not acknowledged: \"T3 offline: no answer\"; after its reboot \"T3 online\"",
            h.nack > after.nack
                && said_since(run, tear.at, "T3 offline: no answer")
                && said_since(run, tear.at, "T3 online")
                && h.online,
            format!("nack {} -> {}, online {}", after.nack, h.nack, h.online),
        );
    }

    run.run_for(2.0);
    let h = run.health(2);
    run.check(
        "no timeout, no bus error, no bus recovery: released lines hold nothing",
        (h.timeout, h.bus_error, h.recoveries) == (0, 0, 0),
        format!(
            "timeout {}, bus error {}, recoveries {}",
            h.timeout, h.bus_error, h.recoveries
        ),
    );
    run.check(
        "the thruster follows its order again",
        run.rpm(2) > 800.0,
        format!("rpm {:.0}", run.rpm(2)),
    );
    others_keep_working(run);
}

/// Many seconds of status reads corrupted while the orders get through (a noisy read line): the thruster keeps its
/// full order rate, never stops on its own 1 s link failsafe, and follows a stick reversal at once; the master
/// counts the lost statuses and says so once, and again when they read well.
pub fn status_noise(run: &mut Run) {
    run.arm_and_go(AHEAD);
    run.run_for(1.0);
    let noise = Fault::NoisyStatus {
        thruster: 1,
        mask: 0x01,
    };
    let (before, _) = held(run, 1).unwrap_or_default();
    let from = run.bench.seconds();
    run.inject(noise);
    // T2's speed every 10 ms for 4 s.
    let mut speeds = Vec::new();
    for _ in 0..400 {
        run.run_for(0.01);
        speeds.push(run.rpm(1));
    }
    // A stick reversal in the middle of it.
    run.bench.ground.sticks = Some(ManualInput { x: -600, ..AHEAD });
    run.run_for(4.0);
    let (after, _) = held(run, 1).unwrap_or_default();
    let seconds = run.bench.seconds() - from;
    let rate = f64::from(after.saturating_sub(before)) / seconds;
    run.metric("T2 orders per second under status noise", json!(round(rate, 1)));
    run.check(
        "the thruster takes its orders at the full 50 Hz through 8 s of unreadable statuses",
        rate >= 49.0,
        format!("{rate:.1} orders/s"),
    );
    let slowest = speeds.iter().copied().fold(f64::INFINITY, f64::min);
    run.check(
        "it keeps driving: no link failsafe, no drop in speed",
        slowest > 800.0,
        format!("slowest {slowest:.0} rpm"),
    );
    run.check(
        "a stick reversal reaches it at once",
        run.rpm(1) < -800.0,
        format!("T2 rpm {:.0}", run.rpm(1)),
    );
    let h = run.health(1);
    run.check(
        "the lost statuses are counted and told once",
        h.status_lost && h.bad_checksum + h.bad_type > 300 && h.online && h.implied_form == 0,
        format!("{h:?}"),
    );
    run.clear(noise);
    run.run_for(0.5);
    run.check(
        "and the status is read again once the line is clean",
        !run.health(1).status_lost && run.said("T2 status readable again"),
        format!("{:?}", run.health(1)),
    );
}

/// A thruster that answers in the 6-byte SeaBotix form (MT as the address byte, as a public SeaBotix master
/// reads it): the master reads it as well as the others, counts the form, and its faults reach the console.
pub fn six_byte_status(run: &mut Run) {
    run.inject(Fault::ImpliedTypeStatus { thruster: 1 });
    run.arm_and_go(AHEAD);
    run.run_for(2.0);
    let h = run.health(1);
    run.check(
        "its status is read, in the implied-type form",
        h.online && !h.status_lost && h.good > 50 && h.implied_form == h.good && h.bad_type + h.bad_checksum == 0,
        format!("{h:?}"),
    );
    run.check(
        "the others read in the full form",
        run.health(0).implied_form == 0 && run.health(0).good > 50,
        format!("{:?}", run.health(0)),
    );
    run.check(
        "it follows its orders",
        run.rpm(1) > 800.0,
        format!("T2 rpm {:.0}", run.rpm(1)),
    );
    let heat = Fault::Heat {
        thruster: 1,
        celsius: 150.0,
    };
    run.inject(heat);
    let seen = run.run_until(60.0, |bench| {
        bench
            .ground
            .seen
            .texts
            .iter()
            .any(|(_, text)| text.starts_with("T2 fault: overtemp"))
    });
    run.check(
        "its faults reach the console",
        seen.is_some(),
        format!("overtemp text after {seen:?} s"),
    );
    run.clear(heat);
}

/// The bus stuck for 1.5 s (a slave holding SDA through every recovery): no order reaches the thrusters, and each
/// stops on its own link failsafe after 1 s. Once the bus is free, a SeaBotix thruster says so in its first status
/// (FAULT bit 5), and of a Legacy one, whose status has no bit for it, the master knows it from the 1.5 s it could
/// not deliver an order; it tells the console once per thruster and counts it, and the thrusters follow the orders
/// again.
pub fn link_failsafe(run: &mut Run) {
    run.arm_and_go(AHEAD);
    run.run_for(1.0);
    let stuck = Fault::SdaHeld { clocks: u32::MAX };
    run.inject(stuck);
    run.run_for(1.5);
    let duties: Vec<i16> = (0..6).map(|i| run.duty(i)).collect();
    run.check(
        "every thruster stops driving on its own failsafe while the bus is stuck",
        duties.iter().all(|duty| *duty == 0),
        format!("duty {duties:?}"),
    );
    run.clear(stuck);
    run.run_for(1.5);
    let counted: Vec<u32> = (0..6).map(|i| run.health(i).link_failsafes).collect();
    let told = (1..=6).all(|n| run.said(&format!("T{n} stopped: 1 s without a valid order")));
    run.check(
        "each thruster's stop reaches the console once it answers again, once each",
        told && counted.iter().all(|n| *n == 1),
        format!("told {told}, counted {counted:?}"),
    );
    run.check(
        "and the thrusters follow the orders again",
        (0..4).all(|i| run.rpm(i) > 800.0),
        format!("rpm {:?}", (0..4).map(|i| round(run.rpm(i), 0)).collect::<Vec<_>>()),
    );
}

/// Driving ahead, the pilot lets go of the sticks, and for 5 s every order to T1 (SeaBotix) and T2 (Legacy) arrives
/// with its checksum off by one while their status reads stay clean: a write path that corrupts. Each thruster
/// refuses every order and so never sees the STOP; its failsafe stops it 1 s after the first refused order, and the
/// master, whose echo check sees the two keep running against a STOP, says so before.
pub fn corrupted_stop(run: &mut Run) {
    // Full ahead: a Legacy brushless thruster echoes only its current, which must be clear of a stopped one's.
    run.arm_and_go(ManualInput { x: 1000, ..AHEAD });
    run.run_for(2.0);
    let driving = [0, 1].map(|i| run.duty(i));
    let drawn = [0, 1].map(|i| run.bench.ground.seen.current_ca[i]);
    run.check(
        "T1 and T2 drive full ahead",
        driving.iter().all(|duty| *duty > 0),
        format!("duty {driving:?}, current {drawn:?} cA"),
    );
    let faults = [0, 1].map(|thruster| Fault::CorruptOrders { thruster, mask: 0x01 });
    faults.iter().for_each(|fault| run.inject(*fault));
    run.bench.ground.sticks = Some(NEUTRAL);
    let released = run.bench.seconds();
    let mut stopped = [None; 3];
    let mut told = None;
    let mut motors_unhealthy = false;
    while run.bench.seconds() < released + 5.0 {
        run.run_for(0.002);
        let since = run.bench.seconds() - released;
        for (index, at) in stopped.iter_mut().enumerate() {
            if at.is_none() && run.duty(index) == 0 {
                *at = Some(round(since, 3));
            }
        }
        if told.is_none() && run.said("T1 does not follow its order") && run.said("T2 does not follow its order") {
            told = Some(round(since, 3));
        }
        motors_unhealthy |= told.is_some() && !run.bench.ground.seen.motors_healthy;
    }
    // The sticks reach the orders within a vehicle step and the next poll (20 ms); the failsafe counts from there.
    run.check(
        "T1 and T2 stop within 1 s + one poll of the first corrupted order; T3, whose orders are whole, through its ramp",
        matches!(stopped, [Some(t1), Some(t2), Some(t3)] if t1 <= 1.045 && t2 <= 1.045 && t1 >= 1.0 && t2 >= 1.0 && t3 < 0.6),
        format!("stopped after {stopped:?} s"),
    );
    run.check(
        "the master says they do not follow their orders before their failsafes act",
        told.is_some_and(|t| t < 1.0),
        format!("told after {told:?} s"),
    );
    run.check(
        "and T1 (SeaBotix) that its failsafe stopped it",
        run.said("T1 stopped: 1 s without a valid order"),
        "FAULT bit 5",
    );
    let counted: Vec<u32> = (0..6).map(|i| run.health(i).not_followed).collect();
    run.check(
        "counted once each, and no other thruster is said not to follow",
        counted == [1, 1, 0, 0, 0, 0] && !(3..=6).any(|n| run.said(&format!("T{n} does not follow"))),
        format!("not followed {counted:?}"),
    );
    run.check(
        "SYS_STATUS says MOTOR_OUTPUTS unhealthy once told",
        motors_unhealthy,
        "",
    );
    faults.iter().for_each(|fault| run.clear(*fault));
    run.bench.ground.sticks = Some(AHEAD);
    run.run_for(1.5);
    run.check(
        "once the orders arrive whole, T1 and T2 drive again and follow them",
        (0..2).all(|i| run.rpm(i) > 800.0 && !run.health(i).not_following)
            && run.said("T1 follows its order again")
            && run.bench.ground.seen.motors_healthy,
        format!(
            "rpm {:?}, motors healthy {}",
            (0..2).map(|i| round(run.rpm(i), 0)).collect::<Vec<_>>(),
            run.bench.ground.seen.motors_healthy
        ),
    );
}
