//! The console under a flood of requests from others on its link, with the link as the master's binding has it:
//! 115200 baud, the LPUART's 256-byte receive and 512-byte transmit buffers ([`crate::bench::master::ConsoleLine`]),
//! so that a console that stops reading loses the bytes that come meanwhile, as the chip does, and one that has
//! more to send than the line carries waits.

use lbv_master_fw::mixer::ManualInput;
use lbv_master_fw::shared::LinkHealth;
use lbv_master_fw::update::ftp::ACK;
use lbv_station::GroundStation;
use serde_json::json;

use super::harness::{NEUTRAL, Run, round};

/// MAVLink FTP's ListDirectory.
const LIST: u8 = 3;
/// The two stick positions the operator alternates between, every [`FLIP`] s, so that each change shows when it
/// reached the thrusters.
const STICKS: [ManualInput; 2] = [ManualInput { x: 600, ..NEUTRAL }, ManualInput { x: 300, ..NEUTRAL }];
const FLIP: f64 = 0.5;
/// A flood frame every so often: a ListDirectory of `/update` (34 bytes, 2.95 ms at 115200 baud) fills 84 % of
/// the line, and leaves the operator's own frames room.
const EVERY: f64 = 0.0035;
/// The latest a stick change may reach the thrusters' orders: the ground station sends the sticks at 10 Hz, the
/// frame takes 3 ms on the line and may wait one flood frame's time behind another: 100 + 3 + 3 ms, and a
/// margin.
const STICK_LATENCY_MS: f64 = 120.0;

/// The order thruster 1 is given now (its speed step).
fn order(run: &Run) -> i8 {
    run.bench
        .master
        .shared
        .orders
        .try_get()
        .map_or(0, |orders| orders[0].speed.step())
}

/// Every thruster's link health now.
fn healths(run: &Run) -> Vec<LinkHealth> {
    (0..run.bench.thrusters.len()).map(|index| run.health(index)).collect()
}

/// What a flood phase found.
struct Flown {
    /// Each stick change's time to reach thruster 1's order, ms (`None`: it never did within the flip).
    latencies: Vec<Option<f64>>,
    /// Orders each thruster acknowledged per second meanwhile.
    order_rates: Vec<f64>,
    /// Whether the vehicle stayed armed.
    armed: bool,
}

/// Fly for `seconds` while `flood` gives a frame every [`EVERY`] s (its argument counts them) and `extra` may send
/// the operator's own requests (its argument the seconds since the start): the sticks flip every [`FLIP`] s.
fn fly_through(
    run: &mut Run,
    seconds: f64,
    steady: [i8; 2],
    mut flood: impl FnMut(u32) -> Vec<u8>,
    mut extra: impl FnMut(&mut Run, f64),
) -> Flown {
    let start = run.bench.now();
    let before = healths(run);
    let steps = (seconds / EVERY).round() as u32;
    let per_flip = (FLIP / EVERY).round() as u32;
    let mut latencies = Vec::new();
    let mut changed_at: Option<(f64, i8)> = None;
    let mut armed = true;
    for step in 0..steps {
        let t = f64::from(step) * EVERY;
        if step % per_flip == 0 {
            if let Some((_, _)) = changed_at.take() {
                latencies.push(None);
            }
            let position = ((step / per_flip) % 2) as usize;
            run.bench.ground.sticks = Some(STICKS[position]);
            changed_at = Some((t, steady[position]));
        }
        let frame = flood(step);
        run.bench.send(frame);
        extra(run, t);
        run.run_for(EVERY);
        armed &= run
            .bench
            .master
            .shared
            .vehicle
            .try_get()
            .is_some_and(|state| state.armed);
        if let Some((at, wanted)) = changed_at
            && order(run) == wanted
        {
            latencies.push(Some(round((t + EVERY - at) * 1e3, 1)));
            changed_at = None;
        }
    }
    let elapsed = (run.bench.now() - start).as_micros() as f64 / 1e6;
    let order_rates = healths(run)
        .iter()
        .zip(&before)
        .map(|(after, before)| round(f64::from(after.delivered - before.delivered) / elapsed, 1))
        .collect();
    Flown {
        latencies,
        order_rates,
        armed,
    }
}

/// Another system (77) floods the console with MAVLink FTP ListDirectory for 10 s, then the operator's companion
/// computer (system 255, component 1) for 5 s, then for 5 s system 77 asks for the parameter list and the companion
/// for AUTOPILOT_VERSION as fast, while the operator lists the update directory twelve times: the operator flies
/// throughout, its sticks flipping every half second. The master reads every byte (none lost to its UART's buffer),
/// no failsafe acts, the vehicle stays armed, every stick change reaches the thrusters' orders within one stick
/// period, the thrusters take their orders at the usual 50 Hz, and every one of the operator's listings is answered.
pub fn console_flood(run: &mut Run) {
    let line = run
        .bench
        .wiring
        .console_line
        .clone()
        .expect("the scenario's vehicle has its console link at its baud rate");
    // The order each stick position gives thruster 1, before any flood.
    run.arm_and_go(STICKS[1]);
    run.run_for(0.5);
    let slow = order(run);
    run.bench.ground.sticks = Some(STICKS[0]);
    run.run_for(0.5);
    let fast = order(run);
    run.check(
        "the two stick positions give thruster 1 two orders",
        fast != slow && slow != 0,
        format!("orders {fast} and {slow}"),
    );
    let steady = [fast, slow];
    let failsafes_before = failsafe_texts(run);
    let counters_before = run.bench.master.console_stats.snapshot();
    let lost_before = line.to_master.lost();

    let mut other = GroundStation::with_system(77);
    let mut companion = GroundStation::with_ids(255, 1);
    let mut phases = Vec::new();
    run.bench.note("flood: FTP ListDirectory from system 77");
    let flown = fly_through(
        run,
        10.0,
        steady,
        |n| other.ftp_request(n as u16, 0, LIST, 0, b"/update"),
        |_, _| {},
    );
    phases.push(("list from system 77", flown));
    run.bench
        .note("flood: FTP ListDirectory from component 1 of the operator's system");
    let flown = fly_through(
        run,
        5.0,
        steady,
        |n| companion.ftp_request(n as u16, 0, LIST, 0, b"/update"),
        |_, _| {},
    );
    phases.push(("list from the operator's companion", flown));
    run.bench
        .note("flood: PARAM_REQUEST_LIST from system 77, AUTOPILOT_VERSION from the companion; the operator lists");
    let operator_seq = |n: u32| 50_000 + n as u16;
    let mut listed = 0;
    let flown = fly_through(
        run,
        5.0,
        steady,
        |n| {
            if n % 2 == 0 {
                other.param_list()
            } else {
                companion.command(512, [148.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
            }
        },
        |run, t| {
            if listed < 12 && t >= 0.2 * f64::from(listed + 1) {
                let frame = run
                    .bench
                    .ground
                    .ftp_request(operator_seq(listed), 0, LIST, 0, b"/update");
                run.bench.send(frame);
                listed += 1;
            }
        },
    );
    phases.push(("parameter lists and messages asked for", flown));
    run.run_for(0.5);

    let lost = line.to_master.lost() - lost_before;
    run.check(
        "the master reads every byte: none is lost to its UART's 256-byte buffer",
        lost == 0,
        format!("{lost} bytes lost"),
    );
    for (name, flown) in &phases {
        let worst = flown
            .latencies
            .iter()
            .map(|l| l.unwrap_or(f64::INFINITY))
            .fold(0.0, f64::max);
        run.check(
            &format!("{name}: every stick change reaches the thrusters within one stick period"),
            !flown.latencies.is_empty() && worst <= STICK_LATENCY_MS,
            format!("latencies {:?} ms", flown.latencies),
        );
        run.check(
            &format!("{name}: the thrusters take their orders at the usual rate, armed throughout"),
            flown.armed && flown.order_rates.iter().all(|rate| *rate >= 48.0),
            format!("armed {}, orders/s {:?}", flown.armed, flown.order_rates),
        );
    }
    let failsafes: Vec<String> = failsafe_texts(run).into_iter().skip(failsafes_before.len()).collect();
    run.check("no failsafe", failsafes.is_empty(), format!("{failsafes:?}"));
    // The operator's listings: each answered (a reply carries the request's sequence number + 1).
    let answered = (0..12)
        .filter(|n| {
            run.bench.ground.seen.ftp.iter().any(|reply| {
                u16::from_le_bytes([reply[0], reply[1]]) == operator_seq(*n).wrapping_add(1)
                    && reply[3] == ACK
                    && reply[5] == LIST
            })
        })
        .count();
    run.check(
        "every one of the operator's twelve listings is answered during the floods",
        answered == 12,
        format!("{answered} of 12"),
    );
    let counters = run.bench.master.console_stats.snapshot();
    let limited = counters.rate_limited - counters_before.rate_limited;
    run.check(
        "what the floods asked beyond each requester's allowance was dropped, and counted",
        limited > 1000,
        format!("{limited} requests over their allowance"),
    );
    run.metric("flood_bytes_lost", json!(lost));
    run.metric("flood_rate_limited", json!(limited));
    run.metric(
        "flood_replies_dropped",
        json!(counters.replies_dropped - counters_before.replies_dropped),
    );
    run.metric(
        "flood_stick_latency_ms",
        json!(
            phases
                .iter()
                .map(|(_, flown)| flown.latencies.iter().flatten().copied().fold(0.0, f64::max))
                .collect::<Vec<f64>>()
        ),
    );
    run.metric("console_to_master_bytes", json!(run.bench.console_bytes.0));
    run.disarm();
}

/// The failsafe texts the operator has seen.
fn failsafe_texts(run: &Run) -> Vec<String> {
    run.bench
        .ground
        .seen
        .texts
        .iter()
        .filter(|(_, text)| text.starts_with("Failsafe"))
        .map(|(_, text)| text.clone())
        .collect()
}
