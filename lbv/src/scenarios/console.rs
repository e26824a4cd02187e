//! The console as pilots use it: a ground station at 1 Hz that loses a heartbeat, a stray byte on the line, a
//! second system trying to take command, MAVLink 2 signing, and the settings in the master's flash across
//! reboots, power cycles and power cuts in the middle of a write.

use std::collections::BTreeMap;

use g431_hw::flash::{NmiAction, eccr, eccr_address, nmi_action};
use g431_hw::memory::FLASH_ORIGIN;
use lbv_master_fw::console::signing::TIMESTAMP_MAX;
use lbv_master_fw::console::{ConsoleCounters, LINE_IDLE};
use lbv_master_fw::params::{LISTED_COUNT, Settings};
use lbv_master_fw::settings::DATA_PAGES;
use lbv_master_fw::shared::{
    MAV_CMD_COMPONENT_ARM_DISARM as ARM_DISARM, MAV_CMD_DO_MOTOR_TEST as MOTOR_TEST,
    MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN as REBOOT,
};
use lbv_station::{GCS_HEARTBEAT, GroundStation, OPERATOR, SIGNING_EPOCH, Signing};
use serde_json::json;

use super::harness::{AHEAD, NEUTRAL, Run, round};

/// MAV_RESULT values.
const ACCEPTED: u8 = 0;
const TEMPORARILY_REJECTED: u8 = 1;
const DENIED: u8 = 2;

fn armed(run: &Run) -> bool {
    run.bench
        .master
        .shared
        .vehicle
        .try_get()
        .is_some_and(|state| state.armed)
}

fn counters(run: &Run) -> ConsoleCounters {
    run.bench.master.console_stats.snapshot()
}

/// The settings the master holds now (what it loaded at boot, and every change since).
fn settings(run: &Run) -> Option<Settings> {
    run.bench.master.shared.settings.try_get()
}

/// Seconds of virtual time now.
fn now(run: &Run) -> f64 {
    run.bench.seconds()
}

/// Whether every trace sample from `from` s on says armed.
fn armed_since(run: &Run, from: f64) -> bool {
    run.bench
        .trace
        .samples
        .iter()
        .filter(|sample| sample.t >= from)
        .all(|sample| sample.armed)
}

/// The horizontal thrusters' speeds, rpm.
fn horizontal_rpm(run: &Run) -> Vec<f64> {
    (0..4).map(|i| round(run.rpm(i), 0)).collect()
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

/// The COMMAND_ACK results addressed to system `to` for `command` so far.
fn results(run: &Run, to: u8, command: u16) -> Vec<u8> {
    run.bench
        .ground
        .seen
        .acks_to
        .iter()
        .filter(|(target, cmd, _)| *target == to && *cmd == command)
        .map(|(_, _, result)| *result)
        .collect()
}

/// The operator sets parameter `name` to `value`; true once the vehicle has answered with that value.
pub(super) fn set_param(run: &mut Run, name: &str, value: f32) -> bool {
    run.bench.ground.seen.params.remove(name);
    let frame = run.bench.ground.param_set(name, value);
    run.bench.send(frame);
    run.run_until(0.5, |bench| {
        bench
            .ground
            .seen
            .params
            .get(name)
            .is_some_and(|(seen, ..)| *seen == value)
    })
    .is_some()
}

/// Every parameter as the vehicle reports it to the operator now (PARAM_REQUEST_LIST).
pub(super) fn read_params(run: &mut Run) -> BTreeMap<String, f32> {
    run.bench.ground.seen.params.clear();
    let frame = run.bench.ground.param_list();
    run.bench.send(frame);
    run.run_for(0.3);
    // A list asked again within 4.8 s of the last is over the station's allowance (80 frames, a list is 64) and
    // dropped unanswered: ask again once it has refilled, as a ground station does.
    for _ in 0..5 {
        if run.bench.ground.seen.params.len() >= LISTED_COUNT {
            break;
        }
        run.run_for(1.0);
        let frame = run.bench.ground.param_list();
        run.bench.send(frame);
        run.run_for(0.3);
    }
    run.bench
        .ground
        .seen
        .params
        .iter()
        .map(|(name, (value, ..))| (name.clone(), *value))
        .collect()
}

/// Whether `read` holds every value of `expected`.
pub(super) fn holds(read: &BTreeMap<String, f32>, expected: &BTreeMap<&str, f32>) -> bool {
    expected.iter().all(|(name, value)| read.get(*name) == Some(value))
}

/// A ground station as MAVProxy is without a joystick (heartbeats at 1 Hz, nothing that steers) holds the vehicle
/// armed on its heartbeats alone, one of them lost; with a joystick's sticks at 10 Hz, as QGroundControl sends them,
/// it keeps driving through another lost heartbeat. Neither failsafe acts.
pub fn ground_station_1hz(run: &mut Run) {
    run.run_for(0.5);
    let arm = run.bench.ground.arm(true);
    run.bench.send(arm);
    run.run_for(0.2);
    run.check(
        "arming accepted",
        results(run, OPERATOR, ARM_DISARM) == [ACCEPTED],
        format!("{:?}", results(run, OPERATOR, ARM_DISARM)),
    );
    let armed_at = now(run);
    run.run_for(4.0);
    run.bench.note("one heartbeat lost");
    run.bench.ground.lose_heartbeats = 1;
    run.run_for(8.0);
    run.check(
        "armed on heartbeats alone, one lost",
        armed_since(run, armed_at),
        format!("heartbeats lost {}", run.bench.ground.heartbeats_lost),
    );
    run.bench.ground.sticks = Some(AHEAD);
    run.run_for(3.0);
    run.bench.note("another heartbeat lost");
    run.bench.ground.lose_heartbeats = 1;
    run.run_for(4.0);
    let lost = run.bench.ground.heartbeats_lost;
    run.check(
        "armed throughout, two 2 s gaps between heartbeats",
        armed_since(run, armed_at) && lost == 2,
        format!("heartbeats lost {lost}"),
    );
    let rpm = horizontal_rpm(run);
    run.check(
        "the sticks drive the thrusters",
        rpm.iter().all(|r| *r > 800.0),
        format!("rpm {rpm:?}"),
    );
    let failsafes = failsafe_texts(run);
    run.check("no failsafe", failsafes.is_empty(), format!("{failsafes:?}"));
    run.metric("armed_s", json!(round(now(run) - armed_at, 1)));
}

/// Stray bytes on the console (`fe`, a MAVLink 1 start; `fd ff 00`, a MAVLink 2 start claiming 255 bytes) cost at
/// most the line's idle time: alone between frames, and in front of a frame in the same burst, whose frame still
/// gets through. The vehicle stays armed and driving.
pub fn stray_byte(run: &mut Run) {
    run.arm_and_go(AHEAD);
    run.run_for(1.5);
    let armed_at = now(run);
    let before = counters(run);
    let mut delays = Vec::new();
    for stray in [&[0xFE][..], &[0xFD, 0xFF, 0x00]] {
        // The sticks pause (well inside the pilot-input failsafe's 3 s) so that the line falls quiet around the
        // burst.
        run.bench.ground.sticks = None;
        run.run_for(0.2);
        run.bench.note(format!("stray {stray:02x?}"));
        run.bench.send(stray.to_vec());
        run.run_for(0.2);
        // In front of a parameter read, whose answer shows when the read got through.
        run.bench.ground.seen.params.clear();
        let read = run.bench.ground.param_read("LBV_GAIN");
        run.bench.send([stray, read.as_slice()].concat());
        let answered = run.run_until(0.5, |bench| bench.ground.seen.params.contains_key("LBV_GAIN"));
        delays.push(answered.map(|s| round(s * 1e3, 1)));
        run.bench.ground.sticks = Some(AHEAD);
        run.run_for(1.0);
    }
    run.metric("read_behind_stray_ms", json!(delays));
    // The line's idle time, then the vehicle's 20 ms tick and the answer's transmission.
    let bound_ms = LINE_IDLE.as_millis() as f64 + 25.0;
    run.check(
        "the frame behind the stray bytes gets through within the line's idle time",
        delays.iter().all(|d| d.is_some_and(|ms| ms <= bound_ms)),
        format!("{delays:?} ms, bound {bound_ms} ms"),
    );
    // A start byte whose frame never completes is dropped as a corrupt frame, the bytes after it until the next
    // start byte are skipped: the eight stray bytes, and no byte of a good frame.
    let after = counters(run);
    let (false_starts, skipped) = (
        after.corrupt() - before.corrupt(),
        after.skipped_bytes - before.skipped_bytes,
    );
    run.check(
        "the stray bytes, and only they, are dropped and counted",
        false_starts + skipped == 2 * (1 + 3),
        format!("{false_starts} false starts, {skipped} bytes skipped"),
    );
    let failsafes = failsafe_texts(run);
    run.check(
        "armed throughout, no failsafe",
        armed_since(run, armed_at) && failsafes.is_empty(),
        format!("{failsafes:?}"),
    );
    let rpm = horizontal_rpm(run);
    run.check("still driving", rpm.iter().all(|r| *r > 800.0), format!("rpm {rpm:?}"));
}

/// A second ground station (system 42) tries to arm, run a motor test, set a parameter, reboot the master and
/// steer: COMMAND_LONGs are DENIED, the rest ignored, all counted (SYS_STATUS errors_count3). Its heartbeats do not
/// keep the failsafe from acting when the operator falls silent.
pub fn second_sysid(run: &mut Run) {
    const OTHER: u8 = 42;
    let mut other = GroundStation::with_system(OTHER);
    run.run_for(0.5);
    let mut frames = other.heartbeat();
    frames.extend(other.arm(true));
    frames.extend(other.motor_test(1, 20.0, 2.0));
    frames.extend(other.param_set("LBV_GAIN", 10.0));
    frames.extend(other.reboot());
    run.bench.send(frames);
    run.run_for(0.3);
    let answers = [ARM_DISARM, MOTOR_TEST, REBOOT].map(|command| results(run, OTHER, command));
    run.check(
        "arm, motor test and reboot from system 42 are DENIED",
        answers.iter().all(|results| *results == [DENIED]),
        format!("{answers:?}"),
    );
    let gain = settings(run).map(|s| s.params.gain_percent());
    run.check(
        "nothing changed: disarmed, no parameter set, no reboot",
        !armed(run) && gain == Some(50) && run.bench.master.boots == 1,
        format!(
            "armed {}, LBV_GAIN {gain:?}, boots {}",
            armed(run),
            run.bench.master.boots
        ),
    );

    // The operator drives ahead; system 42 steers astern.
    run.arm_and_go(AHEAD);
    for _ in 0..20 {
        let astern = other.manual(lbv_master_fw::mixer::ManualInput { x: -800, ..NEUTRAL });
        run.bench.send(astern);
        run.run_for(0.1);
    }
    let rpm = horizontal_rpm(run);
    run.check(
        "the operator's sticks alone drive",
        rpm.iter().all(|r| *r > 800.0),
        format!("rpm {rpm:?}"),
    );
    // SYS_STATUS goes out once a second.
    run.run_for(1.1);
    let refused = run
        .bench
        .master
        .shared
        .vehicle
        .try_get()
        .map_or(0, |state| state.refused);
    let reported = run.bench.ground.seen.refused_other_system;
    run.check(
        "every refused request is counted and reported in SYS_STATUS",
        refused == 4 + 20 && u32::from(reported) == refused,
        format!("refused {refused}, SYS_STATUS errors_count3 {reported}"),
    );

    // The operator's link fails; system 42 keeps sending heartbeats.
    run.bench.note("the operator's link fails");
    run.bench.ground.sticks = None;
    run.bench.ground.lose_heartbeats = u32::MAX;
    let mut disarmed = None;
    for tenth in 1..=70 {
        if tenth % 10 == 0 {
            let heartbeat = other.heartbeat();
            run.bench.send(heartbeat);
        }
        run.run_for(0.1);
        if disarmed.is_none() && !armed(run) {
            disarmed = Some(f64::from(tenth) / 10.0);
        }
    }
    // FS_GCS_TIMEOUT (5 s) after the operator's last heartbeat, up to 1 s before its link failed.
    run.check(
        "disarmed 5 s after the operator's last heartbeat, whatever system 42 sends",
        disarmed.is_some_and(|s| (4.0..=5.1).contains(&s)),
        format!("after {disarmed:?} s"),
    );
}

/// MAVLink 2 signing: the operator sets a key over the console; from then on unsigned frames, frames signed with
/// another key and replayed frames are refused and counted (SYS_STATUS errors_count4), frames signed with the key
/// are obeyed, and everything the master sends is signed with it (checked by the mavlink crate). The key is kept
/// in flash: after a reboot the master still refuses unsigned commands.
pub fn signing(run: &mut Run) {
    run.run_for(0.5);
    set_key(run, *b"lbv-bench-signing-key-0123456789");
    let verified_before = run.bench.ground.seen.verified;

    let mut unsigned = GroundStation::default();
    let mut forger = GroundStation::default();
    forger.signing = Some(Signing::new([0x11; 32]));
    let refused = counters(run);
    let mut frames = unsigned.arm(true);
    frames.extend(forger.arm(true));
    run.bench.send(frames);
    run.run_for(0.3);
    let after = counters(run);
    run.check(
        "an unsigned and a badly signed arm are refused and counted",
        !armed(run)
            && after.unsigned > refused.unsigned
            && after.bad_signatures > refused.bad_signatures
            && results(run, OPERATOR, ARM_DISARM).is_empty(),
        format!(
            "armed {}, unsigned {}, bad signatures {}",
            armed(run),
            after.unsigned,
            after.bad_signatures
        ),
    );

    let arm = run.bench.ground.arm(true);
    run.bench.send(arm);
    run.run_for(0.3);
    run.check(
        "a signed arm is obeyed",
        armed(run) && results(run, OPERATOR, ARM_DISARM) == [ACCEPTED],
        format!("{:?}", results(run, OPERATOR, ARM_DISARM)),
    );
    // A signed disarm, seen on the wire, replayed after a fresh arm.
    let disarm = run.bench.ground.arm(false);
    run.bench.send(disarm.clone());
    run.run_for(0.3);
    let arm = run.bench.ground.arm(true);
    run.bench.send(arm);
    run.run_for(0.3);
    let replayed = counters(run).replayed;
    run.bench.send(disarm);
    run.run_for(0.3);
    run.check(
        "a replayed signed disarm is refused and counted",
        armed(run) && counters(run).replayed == replayed + 1,
        format!("armed {}, replayed {}", armed(run), counters(run).replayed),
    );
    run.run_for(1.0);
    let (seen, refused_total) = (run.bench.ground.seen.clone(), counters(run).refused_by_signing());
    run.check(
        "refusals reported in SYS_STATUS",
        u32::from(seen.refused_by_signing) == refused_total && refused_total >= 3,
        format!("errors_count4 {}, counted {refused_total}", seen.refused_by_signing),
    );
    run.check(
        "everything the master sends is signed with the key",
        seen.verified > verified_before + 10 && seen.unverified == 0,
        format!("verified {}, not verified {}", seen.verified, seen.unverified),
    );

    // The key survives a reboot.
    let disarm = run.bench.ground.arm(false);
    run.bench.send(disarm);
    run.run_for(0.3);
    let reboot = run.bench.ground.reboot();
    run.bench.send(reboot);
    run.run_for(1.0);
    let boots = run.bench.master.boots;
    let arm = unsigned.arm(true);
    run.bench.send(arm);
    run.run_for(0.3);
    run.check(
        "after a reboot the key is still in force",
        boots == 2 && !armed(run) && counters(run).unsigned >= 1,
        format!(
            "boots {boots}, armed {}, unsigned {}",
            armed(run),
            counters(run).unsigned
        ),
    );
    let arm = run.bench.ground.arm(true);
    run.bench.send(arm);
    run.run_for(0.3);
    run.check("and a signed arm is obeyed", armed(run), "");
    run.disarm();
}

/// The attacks a reboot once opened on the signing, as an attacker on the console's line would try them: the
/// operator's session (heartbeat, arm, two seconds of sticks) recorded and replayed 20 ms after the reboot's
/// COMMAND_ACK; one frame signed with the largest timestamp, 2^48 - 1; frames signed a year ago, replayed after each
/// of two more reboots. All are refused and counted, the vehicle never arms or drives on them; the master's
/// timestamps never go back, everything it sends after each reboot is signed from the first frame, and the
/// operator, whose station follows the master's timestamps as the spec asks, is obeyed after every reboot.
pub fn signing_reboot(run: &mut Run) {
    const YEAR: u64 = 365 * 24 * 3600 * 100_000;
    run.run_for(0.5);
    set_key(run, *b"lbv-bench-signing-reboot-key-012");
    let unsigned_before = run.bench.ground.seen.unsigned;
    // Recorded then, signed with the key a year before the set-up.
    let year_old = [
        run.bench.ground.frame_signed_at(&GCS_HEARTBEAT, SIGNING_EPOCH - YEAR),
        run.bench.ground.arm_signed_at(SIGNING_EPOCH - YEAR + 1),
    ];

    // The operator's session, recorded as it goes out.
    let mut recorded = vec![run.bench.ground.heartbeat(), run.bench.ground.arm(true)];
    for frame in recorded.clone() {
        run.bench.send(frame);
    }
    for _ in 0..20 {
        let frame = run.bench.ground.manual(AHEAD);
        recorded.push(frame.clone());
        run.bench.send(frame);
        run.run_for(0.1);
    }
    let driven = horizontal_rpm(run);
    run.check(
        "the operator's session drives the vehicle",
        armed(run) && driven.iter().all(|rpm| *rpm > 100.0),
        format!("armed {}, rpm {driven:?}", armed(run)),
    );
    run.disarm();
    run.run_for(0.5);
    let reboot = run.bench.ground.reboot();
    run.bench.send(reboot);
    let boots = run.bench.master.boots;
    run.run_until(1.0, |bench| bench.master.boots > boots);
    let replayed = counters(run).replayed;
    run.run_for(0.02);
    let mut drove = false;
    for (n, frame) in recorded.iter().enumerate() {
        run.bench.send(frame.clone());
        drove |= driven_for(run, if n < 2 { 0.01 } else { 0.1 });
    }
    drove |= driven_for(run, 0.5);
    let refused = counters(run).replayed - replayed;
    run.check(
        "the session replayed 20 ms after the reboot is refused and counted, the thrusters ordered to stop",
        run.bench.master.boots == boots + 1 && refused >= recorded.len() as u32 && !drove,
        format!(
            "boots {}, replays refused {refused} of {}, armed or driven {drove}",
            run.bench.master.boots,
            recorded.len(),
        ),
    );

    let frame = run.bench.ground.frame_signed_at(&GCS_HEARTBEAT, TIMESTAMP_MAX);
    run.bench.send(frame);
    run.run_for(1.0);
    run.check(
        "a frame signed with the largest timestamp is refused and counted",
        counters(run).out_of_range == 1 && run.bench.ground.seen.timestamps_back == 0,
        format!(
            "out of range {}, timestamps back {}",
            counters(run).out_of_range,
            run.bench.ground.seen.timestamps_back
        ),
    );
    for _ in 0..2 {
        let reboot = run.bench.ground.reboot();
        run.bench.send(reboot);
        let boots = run.bench.master.boots;
        run.run_until(1.0, |bench| bench.master.boots > boots);
        let replayed = counters(run).replayed;
        run.run_for(0.02);
        for frame in &year_old {
            run.bench.send(frame.clone());
        }
        let drove = driven_for(run, 1.0);
        run.check(
            "year-old frames replayed after a reboot are refused",
            counters(run).replayed >= replayed + 2 && !drove,
            format!(
                "replays refused {}, armed or driven {drove}",
                counters(run).replayed - replayed
            ),
        );
    }
    let arm = run.bench.ground.arm(true);
    run.bench.send(arm);
    run.run_for(0.3);
    let seen = run.bench.ground.seen.clone();
    run.check(
        "the operator is obeyed after the reboots",
        armed(run) && results(run, OPERATOR, ARM_DISARM).last() == Some(&ACCEPTED),
        format!("{:?}", results(run, OPERATOR, ARM_DISARM)),
    );
    run.check(
        "everything sent after each reboot is signed with the key, its timestamps rising",
        seen.unsigned == unsigned_before && seen.unverified == 0 && seen.timestamps_back == 0,
        format!(
            "unsigned {}, not verified {}, timestamps back {}",
            seen.unsigned - unsigned_before,
            seen.unverified,
            seen.timestamps_back
        ),
    );
    run.disarm();
}

/// The operator sets `key` over the console (SETUP_SIGNING, unsigned as the first time must be) and signs with it
/// from then on; checked to be in force.
pub(super) fn set_key(run: &mut Run, key: [u8; 32]) {
    let setup = run.bench.ground.setup_signing(key, SIGNING_EPOCH);
    run.bench.send(setup);
    run.bench.ground.signing = Some(Signing::new(key));
    run.run_for(0.3);
    let set = settings(run).and_then(|s| s.signing);
    run.check(
        "the key is set",
        set.is_some_and(|set| set.secret == key),
        format!("{set:?}"),
    );
}

/// Run for `seconds` in 10 ms steps; whether the vehicle was armed or the master ordered a thruster to turn at any
/// of them.
fn driven_for(run: &mut Run, seconds: f64) -> bool {
    let mut drove = false;
    let steps = (seconds / 0.01).ceil() as u32;
    for _ in 0..steps {
        run.run_for(0.01);
        let orders = run.bench.master.shared.orders.try_get().unwrap_or_default();
        drove |= armed(run) || orders.iter().any(|order| !order.speed.is_zero());
    }
    drove
}

/// The operator's parameter changes survive a reboot asked over the console (refused while armed) and a power
/// cycle of the master: both lose its RAM and keep its flash.
pub fn settings_persist(run: &mut Run) {
    run.run_for(0.5);
    let expected = BTreeMap::from([("LBV_GAIN", 80.0), ("LBV_POWER_CAP", 75.0), ("FS_GCS_TIMEOUT", 10.0)]);
    let set = expected.iter().all(|(name, value)| set_param(run, name, *value));
    run.check("the parameters are set", set, format!("{expected:?}"));

    run.arm_and_go(NEUTRAL);
    let reboot = run.bench.ground.reboot();
    run.bench.send(reboot);
    run.run_for(0.3);
    run.check(
        "a reboot while armed is refused",
        results(run, OPERATOR, REBOOT) == [TEMPORARILY_REJECTED] && armed(run) && run.bench.master.boots == 1,
        format!("{:?}, boots {}", results(run, OPERATOR, REBOOT), run.bench.master.boots),
    );
    run.disarm();
    run.run_for(0.3);
    let reboot = run.bench.ground.reboot();
    run.bench.send(reboot);
    let rebooted = run.run_until(1.0, |bench| bench.master.boots == 2);
    run.check(
        "disarmed, the reboot is accepted and the master restarts once its answer is out",
        rebooted.is_some()
            && results(run, OPERATOR, REBOOT) == [TEMPORARILY_REJECTED, ACCEPTED]
            && run.said("Rebooting"),
        format!("after {rebooted:?} s: {:?}", results(run, OPERATOR, REBOOT)),
    );
    run.run_for(0.5);
    let read = read_params(run);
    run.check(
        "the parameters are still set after the reboot",
        holds(&read, &expected) && read.len() == LISTED_COUNT,
        format!("{read:?}"),
    );

    let writes = run.bench.master.flash.stats();
    run.bench.note("master power cycled");
    run.bench.reboot_master();
    run.run_for(0.5);
    let read = read_params(run);
    run.check("and after a power cycle", holds(&read, &expected), format!("{read:?}"));
    let rewritten = run.bench.master.flash.stats().programmed - writes.programmed;
    run.check(
        "starting up writes nothing",
        rewritten == 0,
        format!("{rewritten} bytes programmed"),
    );
}

/// The master's power is cut while it writes a parameter change into its flash: at points inside the write, and
/// during the erase of the oldest page when the log comes round. After each cut the master boots with every
/// earlier change kept and the interrupted one either whole or absent, the double words the cuts tore (ECC errors on
/// the chip) are all ones the NMI handler lets pass, and the store goes on working.
pub fn settings_power_cut(run: &mut Run) {
    run.run_for(0.5);
    let mut expected = BTreeMap::from([("LBV_GAIN", 70.0), ("LBV_POWER_CAP", 90.0)]);
    let set = expected.iter().all(|(name, value)| set_param(run, name, *value));
    run.check("the parameters are set", set, format!("{expected:?}"));

    // A write of one record is 168 bytes (with 16 more when it moves to a new page): cuts on a double word's
    // boundary and inside one.
    let mut outcomes = Vec::new();
    let mut kept_earlier = true;
    for (n, cut_after) in [0, 5, 8, 43, 88, 95].into_iter().enumerate() {
        let value = 10.0 + n as f32;
        let (lost, ok) = cut_during(run, cut_after, "LBV_MTEST_MAX", value, &mut expected);
        kept_earlier &= ok;
        outcomes.push(json!({"cut_after_bytes": cut_after, "interrupted_write_kept": !lost}));
    }

    // Fill the log until a write must first erase its oldest page (2 KiB), and cut the power in the middle of that
    // erase; a write that needs no erase (under 200 bytes) completes.
    let mut erase_cut = None;
    for n in 0..400 {
        let value = 1.0 + (n % 100) as f32;
        let flash = run.bench.master.flash.clone();
        flash.power_on();
        flash.cut_power_after(1021);
        run.bench.ground.seen.params.remove("LBV_GAIN");
        let frame = run.bench.ground.param_set("LBV_GAIN", value);
        run.bench.send(frame);
        let programmed = flash.stats().programmed;
        run.run_until(0.2, |bench| {
            !bench.master.flash.powered() || bench.ground.seen.params.contains_key("LBV_GAIN")
        });
        // Let the write finish (or the cut land).
        run.run_until(0.1, |bench| {
            !bench.master.flash.powered() || bench.master.flash.stats().programmed > programmed
        });
        run.run_for(0.01);
        if !flash.powered() {
            erase_cut = Some(n);
            break;
        }
        expected.insert("LBV_GAIN", value);
    }
    flash_power_back(run);
    let read = read_params(run);
    let erased = run.bench.master.flash.stats().erases;
    run.check(
        "a cut while the log erases its oldest page loses at most that write",
        erase_cut.is_some() && holds(&read, &expected) && erased > 0,
        format!("cut on write {erase_cut:?} ({erased} erases so far): {read:?}, expected {expected:?}"),
    );
    run.metric("power_cuts", json!(outcomes));

    run.check(
        "every earlier change survives every cut",
        kept_earlier,
        format!("{outcomes:?}"),
    );
    let lost = outcomes.iter().filter(|o| o["interrupted_write_kept"] == false).count();
    run.check(
        "cuts inside a record lose that record",
        lost >= 5,
        format!("{lost} of {} interrupted writes lost", outcomes.len()),
    );
    let torn = run.bench.master.flash.stats().torn;
    run.check(
        "every cut tore a flash operation",
        torn as usize == outcomes.len() + 1,
        format!("{torn} torn"),
    );

    // On the chip each torn double word the store read back was an ECC double error and an NMI: the binding's
    // handler must let every one of them pass.
    let torn = run.bench.master.flash.ecc_error_offsets();
    let passed = torn.iter().all(|offset| {
        matches!(
            nmi_action(eccr::ECCD | eccr_address(FLASH_ORIGIN + offset), &DATA_PAGES),
            NmiAction::PassDataRead { .. }
        )
    });
    run.metric(
        "ecc_double_errors_read",
        json!(run.bench.master.flash.stats().ecc_errors),
    );
    run.check(
        "the torn double words read back are in the settings pages, where the NMI handler lets them pass",
        !torn.is_empty() && passed,
        format!("torn double words read at {torn:x?}"),
    );

    // The store goes on working.
    let set = set_param(run, "LBV_MTEST_MAX", 42.0);
    expected.insert("LBV_MTEST_MAX", 42.0);
    run.run_for(0.1);
    run.bench.reboot_master();
    run.run_for(0.5);
    let read = read_params(run);
    run.check(
        "the store goes on working after the cuts",
        set && holds(&read, &expected),
        format!("{read:?}"),
    );
}

/// Cut the master's power `cut_after` bytes into the write of `name` = `value`, power it back up and read the
/// parameters. Returns whether the write was lost, and whether everything else was kept; `expected` then holds
/// what the master has.
fn cut_during(
    run: &mut Run,
    cut_after: usize,
    name: &'static str,
    value: f32,
    expected: &mut BTreeMap<&'static str, f32>,
) -> (bool, bool) {
    let before = read_params(run);
    run.bench.note(format!("power cut {cut_after} bytes into a write"));
    run.bench.master.flash.cut_power_after(cut_after);
    let frame = run.bench.ground.param_set(name, value);
    run.bench.send(frame);
    let cut = run.run_until(0.5, |bench| !bench.master.flash.powered()).is_some();
    flash_power_back(run);
    let after = read_params(run);
    // The new value, or the one from before the write; nothing else changed.
    let lost = after.get(name) != Some(&value);
    let as_before = |n: &str| after.contains_key(n) && after.get(n) == before.get(n);
    let ok = cut
        && after.len() == LISTED_COUNT
        && after.keys().filter(|n| *n != name).all(|n| as_before(n))
        && (!lost || as_before(name));
    if !lost {
        expected.insert(name, value);
    }
    (lost, ok && holds(&after, expected))
}

/// Power comes back: the master boots again from its flash.
fn flash_power_back(run: &mut Run) {
    run.bench.note("power back");
    run.bench.reboot_master();
    run.run_for(0.3);
}

/// The operator changes a parameter over and over while the vehicle drives ahead, until the settings log has gone
/// round its pages and erased the oldest several times. The settings are in the G474's bank 2, so a page erase
/// (25 ms on the bench) runs beside the code in bank 1 and stalls nothing (`FlashTiming::G474_DUAL_BANK`); the
/// master still writes only between poll cycles, with every bus idle. The thrusters miss no order (no timeout, no
/// failed poll, no link failsafe) and keep driving.
pub fn settings_while_driving(run: &mut Run) {
    run.arm_and_go(AHEAD);
    run.run_for(1.0);
    let thrusters = run.bench.thrusters.len();
    let before: Vec<_> = (0..thrusters).map(|index| run.health(index)).collect();
    let duties_before: Vec<i16> = (0..thrusters).map(|index| run.duty(index)).collect();
    let flash_before = run.bench.master.flash.stats();
    let stalls_before = run.bench.master.cpu.stalls();
    let mut answered = 0;
    // 96 records fill the eight pages; every 12 records after that erase one. The writes take their time beside
    // the code (bank 2), and changes that come meanwhile go into the next record together: fewer than 260.
    let n = 260u32;
    for write in 0..n {
        let value = 10.0 + (write % 50) as f32;
        answered += u32::from(set_param(run, "LBV_MTEST_MAX", value));
        // Spread the changes over every phase of the 20 ms poll cycle.
        run.run_for(f64::from(write % 7) * 0.0029);
    }
    run.run_for(0.5);
    let erases = run.bench.master.flash.stats().erases - flash_before.erases;
    let stalled_ms = run.bench.master.cpu.stalled_total().as_millis();
    let stalls = run.bench.master.cpu.stalls() - stalls_before;
    run.check(
        "every change is answered and the log erased pages meanwhile, in bank 2: the master never stalls",
        answered == n && erases >= 3 && stalls == 0,
        format!("{answered} of {n} answered, {erases} erases, {stalls} stalls, {stalled_ms} ms stalled since boot"),
    );
    let after: Vec<_> = (0..thrusters).map(|index| run.health(index)).collect();
    let missed: Vec<String> = before
        .iter()
        .zip(&after)
        .enumerate()
        .filter(|(_, (was, is))| {
            is.timeout != was.timeout
                || is.bus_error != was.bus_error
                || is.link_failsafes != was.link_failsafes
                || is.recoveries != was.recoveries
                || is.consecutive_failures != 0
                || !is.online
        })
        .map(|(index, (was, is))| {
            format!(
                "thruster {}: timeouts {} -> {}, bus errors {} -> {}, failsafes {} -> {}",
                index + 1,
                was.timeout,
                is.timeout,
                was.bus_error,
                is.bus_error,
                was.link_failsafes,
                is.link_failsafes
            )
        })
        .collect();
    let caught: u64 = run.bench.wiring.buses.iter().map(|bus| bus.stats().stalled).sum();
    run.check(
        "no transfer is caught by a flash stall: every thruster takes every order",
        missed.is_empty() && caught == 0,
        format!("{caught} transfers held past the timeout; {missed:?}"),
    );
    let delivered: Vec<u32> = before
        .iter()
        .zip(&after)
        .map(|(was, is)| is.delivered - was.delivered)
        .collect();
    let duties: Vec<i16> = (0..thrusters).map(|index| run.duty(index)).collect();
    run.check(
        "the thrusters kept driving as before",
        armed(run)
            && duties.iter().any(|duty| *duty != 0)
            && duties
                .iter()
                .zip(&duties_before)
                .all(|(now, was)| (i32::from(*now) - i32::from(*was)).abs() <= i32::from(*was).abs() / 10)
            && delivered.iter().all(|orders| *orders > 0),
        format!(
            "armed {}, duties {duties_before:?} -> {duties:?}, orders delivered: {delivered:?}",
            armed(run)
        ),
    );
}
