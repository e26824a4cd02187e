//! Field update from the ground station: update files put over MAVLink FTP to the master, which writes each into
//! its thruster's DFU partition over the thrusters' bus between its polls, and applied by the operator's command
//! (docs/field-update.md). The ground station is lbv-station's scripted one, its uploads stop-and-wait as
//! MAVProxy's `ftp put` goes when its window is one block.

use embassy_boot::State;
use embassy_time::Instant;
use lbv_master_fw::shared::{MAV_CMD_LBV_APPLY_UPDATE, MAV_CMD_LBV_QUERY_VERSION};
use lbv_master_fw::update::TAKEOVER_IDLE;
use lbv_station::{Upload, UploadState};
use serde_json::json;
use tmc_proto::Family;
use update_image::{DEV_PUBLIC_KEY, INFO_OFFSET, ImageInfo, Target, Version, image_record};

use super::fault::Fault;
use super::harness::{Run, round};

/// The development key's secret, which the bench's thrusters accept (keys/README.md).
const DEV_KEY: &str = include_str!("../../../keys/dev.key");
/// The images' payload: the thruster application's flash budget, the largest image an update carries to it.
const PAYLOAD_LEN: usize = g431_hw::images::THRUSTER_FLASH_BUDGET as usize;
/// MAV_RESULT_IN_PROGRESS and MAV_RESULT_ACCEPTED, MAV_RESULT_FAILED.
const IN_PROGRESS: u8 = 5;
const ACCEPTED: u8 = 0;
const DENIED: u8 = 2;
const FAILED: u8 = 4;
/// The version the bench's thrusters run.
const OLD: Version = Version::new(0, 1, 0);
/// The version the update brings.
const NEW: Version = Version::new(0, 2, 0);

/// A signed update file for `family`'s thrusters at `version`: a made-up payload of [`PAYLOAD_LEN`] bytes with its
/// image info at 0x200 and the development key after it (the key the next update is checked with), signed with
/// `seed`.
fn update_file(family: Family, version: Version, seed: &[u8; 32]) -> Vec<u8> {
    let mut payload: Vec<u8> = (0..PAYLOAD_LEN as u32)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 11) as u8)
        .collect();
    let record = image_record(ImageInfo::new(Target::thruster(family), version), &DEV_PUBLIC_KEY);
    payload[INFO_OFFSET..INFO_OFFSET + record.len()].copy_from_slice(&record);
    update_image::sign(&payload, seed).expect("the payload holds its image info")
}

fn dev_key() -> [u8; 32] {
    update_image::key_from_hex(DEV_KEY).expect("keys/dev.key is a key")
}

/// Put `file` to `path`, giving up after `limit` s; returns how it ended and the seconds it took.
fn put(run: &mut Run, path: &str, file: Vec<u8>, limit: f64) -> (UploadState, f64) {
    put_until(run, path, file, limit, |_, _| false)
}

/// As [`put`], but stopping (the ground station goes quiet) once `stop` says so, given the run (to inject faults
/// into) and the bytes acknowledged.
fn put_until(
    run: &mut Run,
    path: &str,
    file: Vec<u8>,
    limit: f64,
    mut stop: impl FnMut(&mut Run, usize) -> bool,
) -> (UploadState, f64) {
    let mut upload = Upload::new(path, file);
    let start = run.bench.seconds();
    while run.bench.seconds() - start < limit {
        if let Some(frame) = upload.poll(run.bench.now(), &mut run.bench.ground) {
            run.bench.send(frame);
        }
        match upload.state() {
            UploadState::Sending(acked) if !stop(run, *acked) => run.run_for(0.005),
            _ => break,
        }
    }
    (upload.state().clone(), round(run.bench.seconds() - start, 2))
}

/// Send the apply command for `slot` and wait up to `limit` s for its final COMMAND_ACK; returns the results of
/// the acknowledgements it got (the first IN_PROGRESS when it started) and the seconds to the last.
fn apply(run: &mut Run, slot: u8, limit: f64) -> (Vec<u8>, f64) {
    apply_with(run, slot, limit, |_| false, |_| {}, 0.0)
}

/// As [`apply`], cutting the thruster's power for 0.1 s `after` s after the master says `text` of it.
fn apply_cut(run: &mut Run, slot: u8, limit: f64, text: &str, after: f64) -> (Vec<u8>, f64) {
    let start = run.bench.now();
    let file = format!("thruster{slot}.lbvu: {text}");
    let said = |bench: &crate::bench::Bench| said_since(bench, start, |said| said.starts_with(&file));
    let cut = |run: &mut Run| {
        run.run_for(after);
        let thruster = usize::from(slot);
        run.bench
            .note(format!("power cut: T{} ({text} + {after} s)", thruster + 1));
        run.inject(Fault::PowerCut { thruster });
        run.run_for(0.1);
        run.clear(Fault::PowerCut { thruster });
    };
    apply_with(run, slot, limit, said, cut, limit)
}

/// Put `file` to thruster `slot` and wait for its copy to be verified; how the put ended.
fn put_verified(run: &mut Run, slot: usize, file: Vec<u8>) -> UploadState {
    let start = run.bench.now();
    let (state, _) = put(run, &format!("/update/thruster{slot}.lbvu"), file, 60.0);
    wait_verified(run, start, slot);
    state
}

/// The version thruster `index` runs now, as its ACTIVE partition holds it.
fn running(run: &Run, index: usize) -> Option<Version> {
    run.bench.thrusters.get(index)?.running_image().map(|info| info.version)
}

/// Texts for `file` since `since`.
fn texts_since(run: &Run, since: Instant, file: &str) -> Vec<String> {
    run.bench
        .ground
        .seen
        .texts
        .iter()
        .filter(|(at, text)| *at >= since && text.starts_with(file))
        .map(|(_, text)| text.clone())
        .collect()
}

/// Wait up to 5 s from now for the master to say that thruster `slot` holds its whole image, verified, since
/// `since`; whether it did.
fn wait_verified(run: &mut Run, since: Instant, slot: usize) -> bool {
    let file = format!("thruster{slot}.lbvu");
    let said = |bench: &crate::bench::Bench| {
        said_since(bench, since, |text| {
            text.starts_with(&file) && text.contains("B verified")
        })
    };
    run.run_until(5.0, said).is_some()
}

/// Whether the ground station has seen a text since `since` that `matches`.
fn said_since(bench: &crate::bench::Bench, since: Instant, matches: impl Fn(&str) -> bool) -> bool {
    bench
        .ground
        .seen
        .texts
        .iter()
        .any(|(at, text)| *at >= since && matches(text))
}

/// An upload of `file` to thruster `slot` cut half-way by `interrupt`, then sent again: it must resume from the
/// pages the thruster holds. `what` names the interruption in the check.
fn resumes(run: &mut Run, slot: usize, file: Vec<u8>, what: &str, interrupt: impl FnOnce(&mut Run)) {
    let start = run.bench.now();
    let path = format!("/update/thruster{slot}.lbvu");
    let mut acked_at_cut = 0;
    let (stopped, _) = put_until(run, &path, file.clone(), 60.0, |_, acked| {
        acked_at_cut = acked;
        acked > PAYLOAD_LEN / 2
    });
    interrupt(run);
    let (resumed, resume_s) = put(run, &path, file, 60.0);
    let verified = wait_verified(run, start, slot);
    let texts = texts_since(run, start, &format!("thruster{slot}.lbvu"));
    let kept = texts.iter().find(|t| t.ends_with(" kept")).cloned().unwrap_or_default();
    run.check(
        &format!("an upload stopped by {what}, sent again, resumes from the pages the thruster holds"),
        matches!(stopped, UploadState::Sending(_))
            && resumed == UploadState::Done
            && verified
            && !kept.contains(" 0 pages"),
        format!("stopped at {acked_at_cut} B, sent again: {resumed:?} in {resume_s} s, texts {texts:?}"),
    );
}

/// An upload of `file` to thruster `slot` during which the bus is noisy for `seconds` from a third of the way: every
/// byte the thruster sends has bits flipped, and every command's byte 3 (its guard) too, so that the thruster
/// discards it. Returns how the upload ended and the texts said for the file.
fn noisy_upload(run: &mut Run, slot: usize, file: Vec<u8>, seconds: f64) -> (UploadState, bool, Vec<String>) {
    let start = run.bench.now();
    let faults = [
        Fault::NoisyStatus {
            thruster: slot,
            mask: 0x10,
        },
        Fault::CorruptOrders {
            thruster: slot,
            mask: 0x55,
        },
    ];
    let mut noise_from = None;
    let (state, _) = put_until(
        run,
        &format!("/update/thruster{slot}.lbvu"),
        file,
        90.0,
        |run, acked| {
            let now = run.bench.seconds();
            match noise_from {
                None if acked > PAYLOAD_LEN / 3 => {
                    faults.iter().for_each(|fault| run.inject(*fault));
                    noise_from = Some(now);
                }
                Some(from) if now >= from + seconds && from.is_finite() => {
                    faults.iter().for_each(|fault| run.clear(*fault));
                    noise_from = Some(f64::INFINITY);
                }
                _ => {}
            }
            false
        },
    );
    if noise_from.is_some_and(f64::is_finite) {
        faults.iter().for_each(|fault| run.clear(*fault));
    }
    let verified = wait_verified(run, start, slot);
    (
        state,
        verified,
        texts_since(run, start, &format!("thruster{slot}.lbvu")),
    )
}

/// Over a link without signing (and `LBV_UPD_UNSIGNED` at its default, 0) an upload is refused at its start,
/// and the master says why.
fn unsigned_refused(run: &mut Run, file_name: &str, file: Vec<u8>) {
    let start = run.bench.now();
    let (state, _) = put(run, &format!("/update/{file_name}"), file, 5.0);
    let texts = texts_since(run, start, file_name);
    run.check(
        "over a link without signing, an upload is refused, and why is told",
        state == UploadState::Refused(1) && texts == [format!("{file_name}: refused, the link is not signed")],
        format!("{state:?}, texts {texts:?}"),
    );
}

/// Every thruster of the vehicle updated in turn from the ground station, the others polled meanwhile; then what is
/// refused, and a transfer cut by a thruster's power cut that resumes. The link is signed first, as
/// docs/field-update.md asks: without signing the uploads are refused.
pub fn field_update(run: &mut Run) {
    let key = dev_key();
    run.run_for(1.0);
    let families: Vec<Family> = run.bench.thrusters.iter().map(|t| t.config.family).collect();
    unsigned_refused(run, "thruster0.lbvu", update_file(families[0], NEW, &key));
    super::console::set_key(run, *b"lbv-bench-field-update-key-01234");
    let (mut put_times, mut apply_times, mut put_bus) = (Vec::new(), Vec::new(), Vec::new());
    for (slot, family) in families.iter().enumerate() {
        let file_name = format!("thruster{slot}.lbvu");
        let path = format!("/update/{file_name}");
        let polls_before = polls_of(run);
        let start = run.bench.now();
        let bits_before = run.bench.thruster_bus().stats().bits;
        let (put_state, put_s) = put(run, &path, update_file(*family, NEW, &key), 60.0);
        let bus = run.bench.thruster_bus();
        let bit_s = bus.timing().bit.as_micros() as f64 / 1e6;
        put_bus.push(round(
            (bus.stats().bits - bits_before) as f64 * bit_s / put_s.max(1e-9),
            3,
        ));
        let verified = wait_verified(run, start, slot);
        let (acks, apply_s) = apply(run, slot as u8, 30.0);
        let texts = texts_since(run, start, &file_name);
        let runs_new = texts.iter().any(|text| text.ends_with("runs 0.2.0, on trial"))
            && texts.last().is_some_and(|text| text.ends_with("0.2.0 confirmed"));
        // Its restart is told as the update's, not as a link fault.
        let link = texts_since(run, start, &format!("T{} offline", slot + 1));
        run.check(
            &format!("T{} ({family:?}) is updated from the ground station", slot + 1),
            put_state == UploadState::Done
                && verified
                && acks == [IN_PROGRESS, ACCEPTED]
                && runs_new
                && link.iter().all(|text| text.ends_with("restarting into its update")),
            format!(
                "put {put_state:?} in {put_s} s, apply acks {acks:?} in {apply_s} s, texts {texts:?}, link {link:?}"
            ),
        );
        let polls_after = polls_of(run);
        let seconds = (run.bench.now() - start).as_micros() as f64 / 1e6;
        let rates: Vec<f64> = (polls_before.iter().zip(&polls_after).enumerate())
            .filter(|(other, _)| *other != slot)
            .map(|(_, (before, after))| round((after - before) as f64 / seconds, 1))
            .collect();
        // Disarmed, the polls slow down to leave the bus to the update, each thruster still polled more than
        // 10 times a second (its failsafe acts after 1 s without an order).
        run.check(
            &format!("the other thrusters are polled while T{} is updated", slot + 1),
            rates.iter().all(|rate| *rate > 10.0),
            format!("polls/s of the others {rates:?}"),
        );
        put_times.push(put_s);
        apply_times.push(apply_s);
    }
    // Per thruster, in table order: the FTP put of a whole-budget image (its bytes on the thruster), and the apply
    // (checked, swapped in, confirmed).
    run.metric("update_put_s", json!(put_times));
    run.metric("update_apply_s", json!(apply_times));
    // The thruster bus's utilisation over each put: the polls and the update's exchanges.
    run.metric("update_put_bus_utilisation", json!(put_bus));

    // What a thruster runs, asked over its bus.
    let start = run.bench.now();
    let (acks, took) = query_version(run, 1, 5.0);
    let texts = texts_since(run, start, "thruster1.lbvu");
    run.check(
        "the ground station asks T2 which image it runs",
        acks == [IN_PROGRESS, ACCEPTED] && texts == ["thruster1.lbvu: runs 0.2.0, dev key"],
        format!("acks {acks:?} in {took} s, texts {texts:?}"),
    );

    // Signed with another key than the one the running image embeds: written and marked, then refused by the
    // thruster's bootloader, which starts the image that ran; the master reads why in its Version.
    let start = run.bench.now();
    let stranger = update_file(families[0], Version::new(0, 3, 0), &[0x42; 32]);
    let (state, _) = put(run, "/update/thruster0.lbvu", stranger, 60.0);
    wait_verified(run, start, 0);
    let (acks, _) = apply(run, 0, 30.0);
    let texts = texts_since(run, start, "T1: refused by its bootloader");
    let runs = run.bench.thrusters[0].running_image().map(|info| info.version);
    run.check(
        "an image signed with another key is refused by the thruster's bootloader",
        state == UploadState::Done
            && acks == [IN_PROGRESS, FAILED]
            && texts == ["T1: refused by its bootloader: signature"]
            && runs == Some(NEW),
        format!("put {state:?}, acks {acks:?}, texts {texts:?}, runs {runs:?}"),
    );

    // The other family's image, for slot 1 (Legacy in the mixed vehicle): the master refuses it at its header.
    let start = run.bench.now();
    let other = if families[1] == Family::SeaBotix {
        Family::Legacy
    } else {
        Family::SeaBotix
    };
    let (state, _) = put(run, "/update/thruster1.lbvu", update_file(other, NEW, &key), 10.0);
    let texts = texts_since(run, start, "thruster1.lbvu");
    run.check(
        "an image of the other family is refused at its header",
        state == UploadState::Refused(1) && texts.iter().any(|t| t.contains("image, slot is")),
        format!("put {state:?}, texts {texts:?}"),
    );

    // A truncated file: the ground station closes the session short of the length its header gives.
    let start = run.bench.now();
    let mut short = update_file(families[2], NEW, &key);
    let whole = short.len();
    short.truncate(whole / 2);
    let stopped = format!("stopped at {} of {whole} bytes", short.len());
    let (state, _) = put(run, "/update/thruster2.lbvu", short, 60.0);
    let (acks, _) = apply(run, 2, 5.0);
    let texts = texts_since(run, start, "thruster2.lbvu");
    run.check(
        "a truncated file stops short and cannot be applied",
        state == UploadState::Done
            && acks == [DENIED]
            && texts.iter().any(|t| t.contains(&stopped))
            && texts.iter().any(|t| t.contains("nothing to apply")),
        format!("put {state:?}, acks {acks:?}, texts {texts:?}"),
    );

    // Armed: nothing is written.
    let start = run.bench.now();
    let arm = run.bench.ground.arm(true);
    run.bench.send(arm);
    run.run_for(0.3);
    let (state, _) = put(run, "/update/thruster2.lbvu", update_file(families[2], NEW, &key), 10.0);
    let disarm = run.bench.ground.arm(false);
    run.bench.send(disarm);
    run.run_for(0.3);
    let texts = texts_since(run, start, "thruster2.lbvu");
    run.check(
        "an update while armed is refused",
        state == UploadState::Refused(1) && texts.iter().any(|t| t.contains("disarm to update")),
        format!("put {state:?}, texts {texts:?}"),
    );

    // A noisy bus in the middle of an upload: for 2 s, within the 3 s a silent thruster is given, the exchanges are
    // sent again until they get through; for 4 s, the transfer ends, and the file sent again resumes.
    let file = update_file(families[2], Version::new(0, 3, 0), &key);
    let (state, verified, texts) = noisy_upload(run, 2, file.clone(), 2.0);
    run.check(
        "2 s of a noisy bus in an upload: it goes on once the noise stops",
        state == UploadState::Done && verified,
        format!("put {state:?}, verified {verified}, texts {texts:?}"),
    );
    let (state, verified, texts) = noisy_upload(run, 1, update_file(families[1], Version::new(0, 3, 0), &key), 4.0);
    let ended = texts.iter().any(|t| t.ends_with("the thruster stopped answering"));
    run.check(
        "4 s of a noisy bus in an upload: the transfer ends saying why, and the upload is refused",
        state == UploadState::Refused(1) && !verified && ended,
        format!("put {state:?}, verified {verified}, texts {texts:?}"),
    );
    let start = run.bench.now();
    run.run_for(TAKEOVER_IDLE.as_micros() as f64 / 1e6 + 0.5);
    let (state, _) = put(
        run,
        "/update/thruster1.lbvu",
        update_file(families[1], Version::new(0, 3, 0), &key),
        60.0,
    );
    let verified = wait_verified(run, start, 1);
    let texts = texts_since(run, start, "thruster1.lbvu");
    run.check(
        "after 4 s of a noisy bus the file sent again resumes from the pages the thruster holds",
        state == UploadState::Done && verified && texts.iter().any(|t| t.ends_with(" kept") && !t.contains(" 0 pages")),
        format!("put {state:?}, verified {verified}, texts {texts:?}"),
    );

    // A thruster's power cut while its upload is under way stops the upload; sent again once the master lets a new
    // session take over the idle one, it resumes.
    let file = update_file(families[4], Version::new(0, 3, 0), &key);
    resumes(run, 4, file, "a thruster's power cut", |run| {
        run.inject(Fault::PowerCut { thruster: 4 });
        run.run_for(0.2);
        run.clear(Fault::PowerCut { thruster: 4 });
        run.run_for(TAKEOVER_IDLE.as_micros() as f64 / 1e6 + 0.5);
    });

    // Power cuts while an image is applied. In the thruster's Finish (its ticket and its mark written): it comes back
    // with the image marked or not, begins again where it must, and takes it.
    let start = run.bench.now();
    let (acks, took) = apply_cut(run, 4, 60.0, "applying", 0.02);
    let texts = texts_since(run, start, "thruster4.lbvu");
    run.check(
        "a power cut as the thruster marks the image: it is applied all the same",
        acks == [IN_PROGRESS, ACCEPTED] && running(run, 4) == Some(Version::new(0, 3, 0)),
        format!("acks {acks:?} in {took} s, runs {:?}, texts {texts:?}", running(run, 4)),
    );
    // The master reset in the middle of an upload.
    let file = update_file(families[5], Version::new(0, 3, 0), &key);
    resumes(run, 5, file, "the master's reset", |run| {
        run.bench.reboot_master();
        run.run_for(1.0);
    });

    // On trial, before the new image confirms itself: the bootloader reverts it, and the apply fails saying so.
    let start = run.bench.now();
    let state = put_verified(run, 3, update_file(families[3], Version::new(0, 3, 0), &key));
    let (acks, took) = apply_cut(run, 3, 60.0, "runs 0.3.0, on trial", 0.5);
    let texts = texts_since(run, start, "thruster3.lbvu");
    run.check(
        "a power cut before the new image confirms itself: it is reverted, and the apply fails",
        state == UploadState::Done
            && acks == [IN_PROGRESS, FAILED]
            && texts.last().is_some_and(|t| t.ends_with("reverted to 0.2.0"))
            && running(run, 3) == Some(NEW),
        format!("acks {acks:?} in {took} s, runs {:?}, texts {texts:?}", running(run, 3)),
    );

    // A power cut in the middle of the thruster's swap (100 kB into its bootloader's flash work, of some 240): off
    // until the power comes back a second later, when its bootloader finishes the swap; the image then confirms.
    let start = run.bench.now();
    let state = put_verified(run, 3, update_file(families[3], Version::new(0, 3, 0), &key));
    run.bench.thrusters[3].cut_in_bootloader = Some(100_000);
    let (acks, took) = apply_with(
        run,
        3,
        60.0,
        |bench| bench.thrusters[3].cut_in_bootloader.is_none() && !bench.thrusters[3].powered(),
        |run| {
            run.bench.note("power cut: T4 (mid-swap), power back after 1 s");
            run.run_for(1.0);
            run.bench.power(3, true);
        },
        60.0,
    );
    let texts = texts_since(run, start, "thruster3.lbvu");
    run.check(
        "a power cut in the thruster's swap: the next start finishes it, and the new image confirms",
        state == UploadState::Done && acks == [IN_PROGRESS, ACCEPTED] && running(run, 3) == Some(Version::new(0, 3, 0)),
        format!("acks {acks:?} in {took} s, runs {:?}, texts {texts:?}", running(run, 3)),
    );

    master_resets_while_applied(run, families[2], &key);
    holds_and_answers(run, families[0], &key);
}

/// The master reset while it applies an image to T3 (slot 2). In the thruster's Finish: the thruster finishes it and
/// keeps the image marked for its bootloader, still running the one before, and the master forgets
/// the transfer; the same file sent again has the master start the update the thruster holds first, then write
/// the file again, which its apply takes. On trial: the thruster confirms the new image once the master polls it
/// again, though the master that asked for it is gone.
fn master_resets_while_applied(run: &mut Run, family: Family, key: &[u8; 32]) {
    let reset_master = |run: &mut Run, when: &str| {
        run.bench.note(format!("master reset ({when})"));
        run.bench.reboot_master();
    };
    let before = running(run, 2);
    let (v4, v5) = (Version::new(0, 4, 0), Version::new(0, 5, 0));
    let file = update_file(family, v4, key);
    let start = run.bench.now();
    put_verified(run, 2, file.clone());
    let applying = move |bench: &crate::bench::Bench| said_since(bench, start, |t| t == "thruster2.lbvu: applying");
    // The reset lands once T3 has marked the image: its Finish command (with its signature, some 7 ms of bytes)
    // reaches it only once it has moved.
    let cut = |run: &mut Run| {
        run.run_until(0.1, |bench| bench.thrusters[2].boot_state() == Some(State::Swap));
        reset_master(run, "T3's Finish");
    };
    let (acks, _) = apply_with(run, 2, 60.0, applying, cut, 2.0);
    let held = (running(run, 2), run.bench.thrusters[2].boot_state());
    // The new master finds T3 holding the mark (its next reset swaps the image in): it refuses to arm, so no order
    // that drives reaches it.
    let asked_at = run.bench.now();
    run.run_for(0.5);
    let (marked_arm, marked_said) = arm(run, asked_at, 0.3);
    run.check(
        "a master reset in the thruster's Finish: the new master finds the thruster marked and refuses to arm",
        held.1 == Some(State::Swap)
            && marked_arm == [TEMPORARILY_REJECTED]
            && marked_said == ["Arm rejected: T3 holds an update marked"],
        format!("holds {held:?}, arm {marked_arm:?} {marked_said:?}"),
    );
    let again = run.bench.now();
    let (state, put_s) = put(run, "/update/thruster2.lbvu", file, 120.0);
    let verified = wait_verified(run, again, 2);
    let (reapplied, _) = apply(run, 2, 60.0);
    let texts = texts_since(run, again, "thruster2.lbvu");
    run.check(
        "a master reset in the thruster's Finish: the file sent again starts the update the thruster holds",
        acks == [IN_PROGRESS]
            && held == (before, Some(State::Swap))
            && state == UploadState::Done
            && verified
            && texts.iter().any(|t| t.ends_with("starting the update it holds"))
            && reapplied == [IN_PROGRESS, ACCEPTED]
            && running(run, 2) == Some(v4),
        format!(
            "acks {acks:?}, then runs and holds {held:?}; put again {state:?} in {put_s} s, apply {reapplied:?}, runs {:?}, \
             texts {texts:?}",
            running(run, 2)
        ),
    );

    let start = run.bench.now();
    put_verified(run, 2, update_file(family, v5, key));
    let on_trial =
        move |bench: &crate::bench::Bench| said_since(bench, start, |t| t == "thruster2.lbvu: runs 0.5.0, on trial");
    let (acks, _) = apply_with(run, 2, 60.0, on_trial, |run| reset_master(run, "T3 on trial"), 0.0);
    let confirmed = run.run_until(30.0, |bench| bench.thrusters[2].boot_state() == Some(State::Boot));
    run.check(
        "a master reset while the new image is on trial: the thruster confirms it once the master polls again",
        acks == [IN_PROGRESS] && confirmed.is_some() && running(run, 2) == Some(v5),
        format!(
            "acks {acks:?}, confirmed after {confirmed:?} s, runs {:?}",
            running(run, 2)
        ),
    );
}

/// The whole vehicle updated with one file per family: each put to its family's path and applied once, every
/// thruster of the family taking it together; timed from the first put's first byte to the last confirmation. The
/// bus is noisy for 2 s during the first put (every byte the thrusters send has bits flipped, every command's guard
/// too), and one of the family's thrusters is off for 1 s later in it (the writes shared meanwhile reach only the
/// others): both cost time, not the update. During the second put one thruster is off for 5 s, longer than the
/// master waits for a silent thruster: it is left behind, the master tells the operator when it is back, and the
/// family's file put again is written to it alone.
pub fn fleet_update(run: &mut Run) {
    let key = dev_key();
    run.run_for(1.0);
    super::console::set_key(run, *b"lbv-bench-fleet-update-key-01234");
    let families: Vec<Family> = run.bench.thrusters.iter().map(|t| t.config.family).collect();
    let start = run.bench.now();
    let polls_before = polls_of(run);
    let bits_before = run.bench.thruster_bus().stats().bits;
    let (mut steps, mut spoiled) = (Vec::new(), 0);
    for (family, name, slot) in [
        (Family::SeaBotix, "thrusters-seabotix.lbvu", 200),
        (Family::Legacy, "thrusters-legacy.lbvu", 201),
    ] {
        let first = steps.is_empty();
        let members: Vec<usize> = (0..families.len()).filter(|i| families[*i] == family).collect();
        let begun = run.bench.now();
        let noise: Vec<Fault> = (0..families.len())
            .flat_map(|thruster| {
                [
                    Fault::NoisyStatus { thruster, mask: 0x10 },
                    Fault::CorruptOrders { thruster, mask: 0x55 },
                ]
            })
            .filter(|_| first)
            .collect();
        let mut noise_from = None;
        // During each put, one thruster of the family loses power: the writes shared while it is off reach only
        // the others, whose acknowledgement hides its absence; its own replies tell. Off for a moment in the first
        // put, it catches up; off for longer than the master waits in the second, it is left behind.
        let (off, off_s) = (members[1], if first { BLINK_S } else { GONE_S });
        let mut off_from = None;
        let (put_state, put_s) = put_until(
            run,
            &format!("/update/{name}"),
            update_file(family, NEW, &key),
            120.0,
            |run, acked| {
                let now = run.bench.seconds();
                match noise_from {
                    None if acked > PAYLOAD_LEN / 3 => {
                        noise.iter().for_each(|fault| run.inject(*fault));
                        noise_from = Some(now);
                    }
                    Some(from) if now >= from + NOISE_S => {
                        noise.iter().for_each(|fault| run.clear(*fault));
                        noise_from = Some(f64::INFINITY);
                    }
                    _ => {}
                }
                match off_from {
                    None if acked > 2 * PAYLOAD_LEN / 3 => {
                        run.inject(Fault::PowerCut { thruster: off });
                        off_from = Some(now);
                    }
                    Some(from) if now >= from + off_s => {
                        run.clear(Fault::PowerCut { thruster: off });
                        off_from = Some(f64::INFINITY);
                    }
                    _ => {}
                }
                false
            },
        );
        // Power back at its time, if the put ended before it.
        let power_back = |run: &mut Run| {
            if let Some(from) = off_from.filter(|from| from.is_finite()) {
                run.run_for((from + off_s - run.bench.seconds()).max(0.0));
                run.clear(Fault::PowerCut { thruster: off });
            }
        };
        if first {
            power_back(run);
        }
        // Every thruster of the family that is there has the whole payload verified before the apply.
        let kept: Vec<usize> = members.iter().copied().filter(|i| first || *i != off).collect();
        let verified = |bench: &crate::bench::Bench| {
            kept.iter().all(|i| {
                let who = format!("T{}: ", i + 1);
                said_since(bench, begun, |text| {
                    text.starts_with(&who) && text.contains("B verified")
                })
            })
        };
        let verified = run.run_until(30.0, verified).is_some();
        if !noise.is_empty() {
            // The noise was on the bus: with their orders spoiled, the thrusters' failsafes acted.
            spoiled = (0..families.len())
                .filter(|i| {
                    let stopped = format!("T{} stopped: 1 s without a valid order", i + 1);
                    said_since(&run.bench, begun, |text| text == stopped)
                })
                .count();
        }
        let progress_before = run.bench.ground.seen.progress.len();
        let applied = run.bench.now();
        let (acks, apply_s) = apply(run, slot, 60.0);
        let runs_new = kept.iter().all(|i| running(run, *i) == Some(NEW));
        // IN_PROGRESS, then IN_PROGRESS with the progress as it goes, then the final answer: FAILED when a
        // thruster was left behind.
        let last = if first { ACCEPTED } else { FAILED };
        let answered = acks.first() == Some(&IN_PROGRESS)
            && acks.last() == Some(&last)
            && acks[1..acks.len() - 1].iter().all(|ack| *ack == IN_PROGRESS);
        run.check(
            &format!("every {family:?} thruster there is updated with one file and one apply"),
            put_state == UploadState::Done && verified && answered && runs_new,
            format!("put {put_state:?} in {put_s} s, verified {verified}, apply acks {acks:?} in {apply_s} s"),
        );
        let progress: Vec<u8> = run.bench.ground.seen.progress[progress_before..]
            .iter()
            .filter(|(command, _)| *command == MAV_CMD_LBV_APPLY_UPDATE)
            .map(|(_, progress)| *progress)
            .collect();
        let told = texts_since(run, applied, name)
            .into_iter()
            .filter(|text| text.contains(" done, T"))
            .count();
        run.check(
            &format!("the {family:?} apply tells its progress, at most once a second"),
            progress.windows(2).all(|pair| pair[0] <= pair[1])
                && progress.iter().any(|p| *p > 0)
                && told >= 2
                && told as f64 <= apply_s + 1.0,
            format!("progress {progress:?}, {told} texts in {apply_s} s"),
        );
        steps.push(json!({"family": format!("{family:?}"), "put_s": put_s, "apply_s": apply_s}));
        if first {
            run.check(
                &format!(
                    "T{} off for {BLINK_S} s during the put is caught up on its return",
                    off + 1
                ),
                running(run, off) == Some(NEW),
                format!("runs {:?}", running(run, off)),
            );
            continue;
        }
        // Back, on its old image: the master says so, and the file put again goes to it alone.
        power_back(run);
        let again = format!("T{}: runs {OLD}, put {name} again", off + 1);
        let told = run
            .run_until(10.0, |bench| said_since(bench, begun, |text| text == again))
            .is_some();
        let back = run.bench.now();
        let (put_state, put_s) = put(run, &format!("/update/{name}"), update_file(family, NEW, &key), 60.0);
        let skipped = kept.iter().all(|i| {
            let runs = format!("T{}: runs {NEW} already", i + 1);
            said_since(&run.bench, back, |text| text == runs)
        });
        let written = format!("T{}: ", off + 1);
        let written = |bench: &crate::bench::Bench| {
            said_since(bench, back, |text| {
                text.starts_with(&written) && text.contains("B verified")
            })
        };
        run.run_until(30.0, written);
        let (acks, apply_s) = apply(run, slot, 60.0);
        run.check(
            &format!(
                "T{} off for {GONE_S} s during the put is left behind, told on its return, and updated by the file \
                 put again",
                off + 1
            ),
            told && put_state == UploadState::Done
                && skipped
                && acks.first() == Some(&IN_PROGRESS)
                && acks.last() == Some(&ACCEPTED)
                && members.iter().all(|i| running(run, *i) == Some(NEW)),
            format!(
                "told {told}, put again {put_state:?} in {put_s} s, the others skipped {skipped}, apply \
                 acks {acks:?} in {apply_s} s, runs {:?}",
                running(run, off)
            ),
        );
        steps.push(json!({"family": format!("{family:?}"), "put_s": put_s, "apply_s": apply_s, "again": true}));
    }
    run.check(
        "2 s of a noisy bus during the first put cost time, not the update",
        spoiled > 0 && steps.len() == 3,
        format!("{spoiled} thrusters' failsafes acted on the spoiled orders"),
    );
    let seconds = (run.bench.now() - start).as_micros() as f64 / 1e6;
    let rates: Vec<f64> = polls_before
        .iter()
        .zip(polls_of(run))
        .map(|(before, after)| round((after - before) as f64 / seconds, 1))
        .collect();
    // The thruster off for 5 s answered none meanwhile: its rate counts the whole time all the same.
    run.check(
        "every thruster is polled more than 10 times a second throughout",
        rates.iter().all(|rate| *rate > 10.0),
        format!("polls/s {rates:?}"),
    );
    let bus = run.bench.thruster_bus();
    let bit_s = bus.timing().bit.as_micros() as f64 / 1e6;
    let busy = (bus.stats().bits - bits_before) as f64 * bit_s / seconds;
    // The payload each thruster took, over the time from the first byte put to the last confirmation.
    let payload_kb_s = (PAYLOAD_LEN * families.len()) as f64 / seconds / 1e3;
    run.metric("fleet_update_s", json!(round(seconds, 2)));
    run.metric("fleet_update_steps", json!(steps));
    run.metric("fleet_update_bus_utilisation", json!(round(busy, 3)));
    run.metric("fleet_update_payload_kb_s", json!(round(payload_kb_s, 2)));
}

/// How long the bus is noisy during the fleet update's first put: less than the 3 s a silent thruster is given.
const NOISE_S: f64 = 2.0;
/// How long a thruster is off during the fleet update's first put: it is back within the 3 s.
const BLINK_S: f64 = 1.0;
/// How long a thruster is off during the fleet update's second put: longer than the 3 s, it is left behind.
const GONE_S: f64 = 5.0;

/// Each thruster's answered polls so far.
fn polls_of(run: &Run) -> Vec<u64> {
    (0..run.bench.thrusters.len())
        .map(|i| {
            let report = run.bench.master.shared.thrusters.get(i).and_then(|w| w.try_get());
            report.map_or(0, |report| u64::from(report.health.good))
        })
        .collect()
}

/// The master's image in the scenario: its application's flash budget, the largest image its own update carries.
const MASTER_PAYLOAD_LEN: usize = g431_hw::images::MASTER_FLASH_BUDGET as usize;

/// A signed update file for the master at `version`: a made-up payload with its image info at 0x200 and the
/// development key after it, signed with `seed`.
fn master_file(version: Version, seed: &[u8; 32]) -> Vec<u8> {
    let mut payload: Vec<u8> = (0..MASTER_PAYLOAD_LEN as u32)
        .map(|i| (i.wrapping_mul(2_246_822_519) >> 13) as u8)
        .collect();
    let record = image_record(ImageInfo::new(Target::Master, version), &DEV_PUBLIC_KEY);
    payload[INFO_OFFSET..INFO_OFFSET + record.len()].copy_from_slice(&record);
    update_image::sign(&payload, seed).expect("the payload holds its image info")
}

/// The version the master's ACTIVE partition holds now.
fn master_runs(run: &Run) -> Option<Version> {
    run.bench.master.running_image().map(|info| info.version)
}

/// The master updated from the ground station over its own console link: the image put into its DFU partition
/// while it polls the thrusters, applied (its signature checked, the restart, the bootloader's swap, the new image
/// on trial until it hears the operator), the settings kept; what is refused; and power cuts mid-upload, mid-swap
/// and before the new image confirms. Over a link without signing, allowed by `LBV_UPD_UNSIGNED` (refused before).
pub fn master_update(run: &mut Run) {
    let key = dev_key();
    run.run_for(1.0);
    // Without signing, nobody may update; LBV_UPD_UNSIGNED allows it (set with the others, and kept as they are).
    unsigned_refused(run, "master.lbvu", master_file(NEW, &key));
    let expected =
        std::collections::BTreeMap::from([("LBV_GAIN", 80.0), ("FS_GCS_TIMEOUT", 10.0), ("LBV_UPD_UNSIGNED", 1.0)]);
    let set = expected
        .iter()
        .all(|(name, value)| super::console::set_param(run, name, *value));
    run.check("the parameters are set", set, format!("{expected:?}"));

    let start = run.bench.now();
    let polls_before = polls_of(run).iter().sum::<u64>();
    let bytes_before = run.bench.console_bytes;
    let (put_state, put_s) = put(run, "/update/master.lbvu", master_file(NEW, &key), 120.0);
    let polls = polls_of(run).iter().sum::<u64>() - polls_before;
    // The bench's console link carries bytes at once; at the console's 115200 baud (10 bits a byte), what the put
    // moved each way, requests and their replies one after another as a stop-and-wait put sends them.
    let (to_master, from_master) = (
        run.bench.console_bytes.0 - bytes_before.0,
        run.bench.console_bytes.1 - bytes_before.1,
    );
    let put_at_115200 = round((to_master + from_master) as f64 * 10.0 / 115_200.0, 1);
    let rate = polls as f64 / put_s / run.bench.thrusters.len() as f64;
    let (acks, apply_s) = apply(run, 255, 60.0);
    let texts = texts_since(run, start, "master.lbvu");
    let expected_texts = [
        "master.lbvu: applying",
        "master.lbvu: signature good, restarting",
        "master.lbvu: runs 0.2.0, on trial",
        "master.lbvu: 0.2.0 confirmed",
    ];
    run.check(
        "the master is updated from the ground station: put, applied, swapped in, confirmed",
        put_state == UploadState::Done
            && acks == [IN_PROGRESS, ACCEPTED]
            && expected_texts.iter().all(|t| texts.iter().any(|said| said == t))
            && master_runs(run) == Some(NEW),
        format!(
            "put {put_state:?} in {put_s} s, apply acks {acks:?} in {apply_s} s, runs {:?}, texts {texts:?}",
            master_runs(run)
        ),
    );
    run.check(
        "the thrusters are polled while the master's image is put",
        rate > 40.0,
        format!("{} polls/s each", round(rate, 1)),
    );
    run.metric("master_update_put_s", json!(put_s));
    run.metric("master_update_put_bytes", json!([to_master, from_master]));
    run.metric("master_update_put_at_115200_s", json!(put_at_115200));
    run.metric("master_update_apply_s", json!(apply_s));
    run.run_for(0.5);
    let read = super::console::read_params(run);
    run.check(
        "the settings survive the master's update",
        super::console::holds(&read, &expected),
        format!("{read:?}"),
    );

    // Signed with another key: written to DFU, refused at the apply; the master goes on running what it ran.
    let start = run.bench.now();
    let boots = run.bench.master.boots;
    let (state, _) = put(
        run,
        "/update/master.lbvu",
        master_file(Version::new(0, 3, 0), &[0x42; 32]),
        120.0,
    );
    let (acks, _) = apply(run, 255, 10.0);
    let texts = texts_since(run, start, "master.lbvu");
    run.check(
        "a master image signed with another key is refused, and the master goes on",
        state == UploadState::Done
            && acks == [IN_PROGRESS, FAILED]
            && texts.iter().any(|t| t == "master.lbvu: signature bad: image refused")
            && run.bench.master.boots == boots
            && master_runs(run) == Some(NEW),
        format!(
            "put {state:?}, acks {acks:?}, boots {}, texts {texts:?}",
            run.bench.master.boots - boots
        ),
    );

    // A thruster's image sent to the master's path: refused at its header.
    let start = run.bench.now();
    let (state, _) = put(
        run,
        "/update/master.lbvu",
        update_file(Family::SeaBotix, NEW, &key),
        10.0,
    );
    let texts = texts_since(run, start, "master.lbvu");
    run.check(
        "a thruster's image is refused by the master at its header",
        state == UploadState::Refused(1),
        format!("put {state:?}, texts {texts:?}"),
    );

    // A power cut half-way through the upload: the master comes back on its image, and the file sent again goes in.
    let next = Version::new(0, 3, 0);
    let (stopped, _) = put_until(
        run,
        "/update/master.lbvu",
        master_file(next, &key),
        120.0,
        |_, acked| acked > MASTER_PAYLOAD_LEN / 2,
    );
    run.bench.note("power cut: master (mid-upload)");
    run.bench.reboot_master();
    run.run_for(1.0);
    let came_back = master_runs(run) == Some(NEW);
    let (state, _) = put(run, "/update/master.lbvu", master_file(next, &key), 120.0);
    run.check(
        "a power cut mid-upload leaves the master on its image, and the file sent again goes in",
        matches!(stopped, UploadState::Sending(_)) && came_back && state == UploadState::Done,
        format!("stopped {stopped:?}, came back on {NEW}: {came_back}, sent again {state:?}"),
    );

    // A power cut in the bootloader's swap (400 kB into its flash work, about half-way): the next start resumes it.
    let start = run.bench.now();
    run.bench.master.cut_in_bootloader = Some(400_000);
    let (acks, took) = apply_with(
        run,
        255,
        90.0,
        |bench| !bench.master.flash.powered(),
        |run| {
            run.bench.note("power cut: master (mid-swap), power back after 0.5 s");
            run.run_for(0.5);
            run.bench.reboot_master();
        },
        60.0,
    );
    let texts = texts_since(run, start, "master.lbvu");
    run.check(
        "a power cut mid-swap: the next start finishes the swap, and the new image confirms",
        acks == [IN_PROGRESS, ACCEPTED] && master_runs(run) == Some(next),
        format!(
            "acks {acks:?} in {took} s, runs {:?}, texts {texts:?}",
            master_runs(run)
        ),
    );

    // A power cut while the new image is on trial: the bootloader swaps the previous one back.
    let newest = Version::new(0, 4, 0);
    let (state, _) = put(run, "/update/master.lbvu", master_file(newest, &key), 120.0);
    let start = run.bench.now();
    let on_trial =
        |bench: &crate::bench::Bench| said_since(bench, start, |said| said == "master.lbvu: runs 0.4.0, on trial");
    let cut = |run: &mut Run| {
        // Half a second into the trial, well before the 3 s of heartbeats it needs.
        run.run_for(0.5);
        run.bench.note("power cut: master (on trial)");
        run.bench.reboot_master();
    };
    let (acks, _) = apply_with(run, 255, 90.0, on_trial, cut, 20.0);
    let texts = texts_since(run, start, "master.lbvu");
    run.check(
        "a power cut before the new master image confirms: the previous one is swapped back",
        state == UploadState::Done
            && acks == [IN_PROGRESS]
            && !texts.iter().any(|t| t.ends_with("0.4.0 confirmed"))
            && master_runs(run) == Some(next),
        format!("acks {acks:?}, runs {:?}, texts {texts:?}", master_runs(run)),
    );
    let read = super::console::read_params(run);
    run.check(
        "the settings survive every cut",
        super::console::holds(&read, &expected),
        format!("{read:?}"),
    );
    master_apply_holds_arming(run, &key);
    master_crashes_early(run);
}

/// The confirmed master image crashes (its watchdog resets it) `times` times, each `after` s into its run.
fn crash_master(run: &mut Run, times: usize, after: f64) {
    for _ in 0..times {
        run.run_for(after);
        run.bench.note("the master's image crashes: watchdog reset");
        run.bench.crash_master();
    }
}

/// The image confirmed by the last step (0.5.0) crashes early: twice, then it runs past the early window, which
/// clears the count, so one more crash undoes nothing; then three in a row, and the bootloader puts the image it
/// replaced (0.3.0) back, which the master tells the operator.
fn master_crashes_early(run: &mut Run) {
    let (replaced, confirmed) = (Version::new(0, 3, 0), Version::new(0, 5, 0));
    let start = run.bench.now();
    crash_master(run, 2, 5.0);
    run.run_for(update_image::EARLY_WINDOW_SECS as f64 + 1.0);
    crash_master(run, 1, 5.0);
    run.run_for(5.0);
    let kept = master_runs(run);
    crash_master(run, 2, 5.0);
    // The undo takes the bootloader seconds of bank-1 flash work (two copies of every page), then the master
    // starts and hears the operator.
    run.run_for(15.0);
    let texts = texts_since(run, start, "master.lbvu");
    let restored = "master.lbvu: 3 early crashes: 0.3.0 restored";
    run.check(
        "a confirmed master image that crashes three times in a row early in its run is undone; crashes spread          past the early window are not",
        kept == Some(confirmed)
            && master_runs(run) == Some(replaced)
            && matches!(run.bench.master.boot_outcome, Some(lbv_boot::Outcome::Restored { .. }))
            && texts.iter().filter(|t| t.as_str() == restored).count() == 1,
        format!(
            "after the spread crashes {kept:?}, after three in a row {:?}, texts {texts:?}",
            master_runs(run)
        ),
    );
}

/// Ask thruster `slot` which image it runs and wait up to `limit` s for the final COMMAND_ACK; the results of the
/// acknowledgements, and the seconds to the last.
fn query_version(run: &mut Run, slot: u8, limit: f64) -> (Vec<u8>, f64) {
    let start = run.bench.now();
    let acks_before = run.bench.ground.seen.acks.len();
    let command = run.bench.ground.command(
        MAV_CMD_LBV_QUERY_VERSION,
        [f32::from(slot), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    );
    run.bench.send(command);
    let results = move |bench: &crate::bench::Bench| -> Vec<u8> {
        bench.ground.seen.acks[acks_before..]
            .iter()
            .filter(|(command, _)| *command == MAV_CMD_LBV_QUERY_VERSION)
            .map(|(_, result)| *result)
            .collect()
    };
    run.run_until(limit, |bench| results(bench).last().is_some_and(|r| *r != IN_PROGRESS));
    (
        results(&run.bench),
        round((run.bench.now() - start).as_micros() as f64 / 1e6, 2),
    )
}

/// Send the apply command for `slot` (255: the master) and run until its final COMMAND_ACK or `limit` s; should
/// `when` hold first, `act`, then run on for at most `settle` s. The acknowledgements' results (the first
/// IN_PROGRESS when it started) and the seconds to the last.
fn apply_with(
    run: &mut Run,
    slot: u8,
    limit: f64,
    when: impl Fn(&crate::bench::Bench) -> bool,
    act: impl FnOnce(&mut Run),
    settle: f64,
) -> (Vec<u8>, f64) {
    let start = run.bench.now();
    let acks_before = run.bench.ground.seen.acks.len();
    let command = run.bench.ground.command(
        MAV_CMD_LBV_APPLY_UPDATE,
        [f32::from(slot), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    );
    run.bench.send(command);
    let results = move |bench: &crate::bench::Bench| -> Vec<u8> {
        bench.ground.seen.acks[acks_before..]
            .iter()
            .filter(|(command, _)| *command == MAV_CMD_LBV_APPLY_UPDATE)
            .map(|(_, result)| *result)
            .collect()
    };
    let done = move |bench: &crate::bench::Bench| results(bench).last().is_some_and(|r| *r != IN_PROGRESS);
    let fired = run.run_until(limit, |bench| done(bench) || when(bench));
    if fired.is_some() && !done(&run.bench) {
        act(run);
        run.run_until(settle, done);
    }
    (
        results(&run.bench),
        round((run.bench.now() - start).as_micros() as f64 / 1e6, 2),
    )
}

/// MAV_RESULT_TEMPORARILY_REJECTED.
const TEMPORARILY_REJECTED: u8 = 1;
/// MAV_CMD_COMPONENT_ARM_DISARM.
const ARM_DISARM: u16 = 400;

/// Send the operator's arm command and run `seconds`: the results of the arm's COMMAND_ACKs, and its texts
/// ("Armed", "Arm rejected: ...") since `since`.
fn arm(run: &mut Run, since: Instant, seconds: f64) -> (Vec<u8>, Vec<String>) {
    let acks_before = run.bench.ground.seen.acks.len();
    let frame = run.bench.ground.arm(true);
    run.bench.send(frame);
    run.run_for(seconds);
    let acks = run.bench.ground.seen.acks[acks_before..]
        .iter()
        .filter(|(command, _)| *command == ARM_DISARM)
        .map(|(_, result)| *result)
        .collect();
    (acks, arm_texts(run, since))
}

/// The arm texts since `since`.
fn arm_texts(run: &Run, since: Instant) -> Vec<String> {
    run.bench
        .ground
        .seen
        .texts
        .iter()
        .filter(|(at, text)| *at >= since && (text == "Armed" || text.starts_with("Arm rejected")))
        .map(|(_, text)| text.clone())
        .collect()
}

/// Remove `path` (MAVLink FTP RemoveFile) and run a moment for the answer.
fn remove_file(run: &mut Run, path: &str) {
    const REMOVE_FILE: u8 = 8;
    let frame = run.bench.ground.ftp_request(0x4000, 0, REMOVE_FILE, 0, path.as_bytes());
    run.bench.send(frame);
    run.run_for(0.3);
    run.bench.ground.seen.ftp.clear();
}

/// No reset in the water, and answers that tell the truth (issue 30, items 3 and 7), on T1 (slot 0): the version query
/// is answered while an image written whole waits for its apply, and after its file is removed; an apply sent again
/// while it runs is answered as the one under way, and an arm meanwhile is refused; a master reset while the new
/// image is on trial leaves a thruster on trial that the new master finds, and refuses to arm for, until it
/// confirms.
fn holds_and_answers(run: &mut Run, family: Family, key: &[u8; 32]) {
    let (v6, v7) = (Version::new(0, 6, 0), Version::new(0, 7, 0));
    let file = update_file(family, v6, key);
    let start = run.bench.now();
    put_verified(run, 0, file.clone());
    let (written, _) = query_version(run, 0, 5.0);
    remove_file(run, "/update/thruster0.lbvu");
    let (removed, _) = query_version(run, 0, 5.0);
    let texts = texts_since(run, start, "thruster0.lbvu");
    run.check(
        "the version query is answered while an image written whole waits, and after its file is removed",
        written == [IN_PROGRESS, ACCEPTED]
            && removed == [IN_PROGRESS, ACCEPTED]
            && texts.iter().filter(|t| t.starts_with("thruster0.lbvu: runs ")).count() == 2
            && !texts.iter().any(|t| t.contains("wait:")),
        format!("written {written:?}, removed {removed:?}, texts {texts:?}"),
    );

    // Sent again (its pages kept), applied; while it runs the same apply is sent again and the operator arms.
    let start = run.bench.now();
    put_verified(run, 0, file);
    let armed = std::cell::Cell::new((Vec::new(), Vec::new()));
    let applying = move |bench: &crate::bench::Bench| said_since(bench, start, |t| t == "thruster0.lbvu: applying");
    let again = |run: &mut Run| {
        let frame = run.bench.ground.command(MAV_CMD_LBV_APPLY_UPDATE, [0.0; 7]);
        run.bench.send(frame);
        armed.set(arm(run, start, 0.3));
    };
    let (acks, took) = apply_with(run, 0, 60.0, applying, again, 60.0);
    let (arm_acks, arm_said) = armed.take();
    let texts = texts_since(run, start, "thruster0.lbvu");
    run.check(
        "an apply sent again while it runs is answered as the one under way, and arming meanwhile is refused",
        acks == [IN_PROGRESS, IN_PROGRESS, ACCEPTED]
            && texts.iter().filter(|t| *t == "thruster0.lbvu: applying").count() == 2
            && !texts.iter().any(|t| t.contains("send it again"))
            && arm_acks == [TEMPORARILY_REJECTED]
            && arm_said == ["Arm rejected: T1 update being applied"]
            && arm_texts(run, start) == arm_said
            && running(run, 0) == Some(v6),
        format!(
            "apply acks {acks:?} in {took} s, arm {arm_acks:?} {arm_said:?}, runs {:?}, texts {texts:?}",
            running(run, 0)
        ),
    );

    // The master reset while the new image is on trial: the new master asks what T1 runs, finds it on trial, and
    // refuses to arm until it has confirmed.
    let start = run.bench.now();
    put_verified(run, 0, update_file(family, v7, key));
    let on_trial =
        move |bench: &crate::bench::Bench| said_since(bench, start, |t| t == "thruster0.lbvu: runs 0.7.0, on trial");
    let reset = |run: &mut Run| {
        run.bench.note("master reset (T1 on trial)");
        run.bench.reboot_master();
    };
    let (acks, _) = apply_with(run, 0, 60.0, on_trial, reset, 0.0);
    let reset_at = run.bench.now();
    // Until the new master hears the operator (the ground station's next heartbeat), which arming needs first.
    let heard = |bench: &crate::bench::Bench| {
        bench
            .master
            .shared
            .vehicle
            .try_get()
            .is_some_and(|vehicle| vehicle.console_alive)
    };
    run.run_until(2.0, heard);
    let on_trial_after_reset = run.bench.thrusters[0].boot_state() == Some(State::Swap);
    let (refused, refused_said) = arm(run, reset_at, 0.3);
    let confirmed = run.run_until(30.0, |bench| bench.thrusters[0].boot_state() == Some(State::Boot));
    run.run_for(1.0);
    let since = run.bench.now();
    let (taken, taken_said) = arm(run, since, 0.3);
    let disarm = run.bench.ground.arm(false);
    run.bench.send(disarm);
    run.run_for(0.3);
    run.check(
        "a thruster found on trial by a master that restarted holds arming, with its reason, until it confirms",
        acks == [IN_PROGRESS]
            && on_trial_after_reset
            && refused == [TEMPORARILY_REJECTED]
            && refused_said == ["Arm rejected: T1 image on trial"]
            && confirmed.is_some()
            && taken == [ACCEPTED]
            && taken_said == ["Armed"]
            && running(run, 0) == Some(v7),
        format!(
            "acks {acks:?}, on trial at the restart {on_trial_after_reset}, arm {refused:?} {refused_said:?}, \
             confirmed after {confirmed:?} s, then arm {taken:?} {taken_said:?}"
        ),
    );
}

/// The master's own apply, sent twice, with the operator arming in the middle of it (in its signature check): one
/// apply, answered as the one under way the second time; the arm refused with its reason, so the master never
/// restarts armed; the final ACCEPTED, after the restart, to the component that applied it.
fn master_apply_holds_arming(run: &mut Run, key: &[u8; 32]) {
    let v5 = Version::new(0, 5, 0);
    let (state, _) = put(run, "/update/master.lbvu", master_file(v5, key), 120.0);
    let start = run.bench.now();
    let boots = run.bench.master.boots;
    let component_acks = run.bench.ground.seen.acks_to_component.len();
    let armed = std::cell::Cell::new((Vec::new(), Vec::new()));
    let applying = move |bench: &crate::bench::Bench| said_since(bench, start, |t| t == "master.lbvu: applying");
    let again_and_arm = |run: &mut Run| {
        let frame = run
            .bench
            .ground
            .command(MAV_CMD_LBV_APPLY_UPDATE, [255.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        run.bench.send(frame);
        armed.set(arm(run, start, 0.05));
    };
    let (acks, took) = apply_with(run, 255, 90.0, applying, again_and_arm, 60.0);
    let (arm_acks, arm_said) = armed.take();
    let texts = texts_since(run, start, "master.lbvu");
    let final_to: Vec<u8> = run.bench.ground.seen.acks_to_component[component_acks..]
        .iter()
        .filter(|(_, command, result)| *command == MAV_CMD_LBV_APPLY_UPDATE && *result == ACCEPTED)
        .map(|(component, ..)| *component)
        .collect();
    run.check(
        "an arm in the master's own apply is refused and the master never restarts armed; a second apply starts \
         nothing; the final answer goes to the component that applied it",
        state == UploadState::Done
            && acks == [IN_PROGRESS, IN_PROGRESS, ACCEPTED]
            && texts.iter().filter(|t| *t == "master.lbvu: applying").count() == 2
            && texts
                .iter()
                .filter(|t| *t == "master.lbvu: signature good, restarting")
                .count()
                == 1
            && arm_acks == [TEMPORARILY_REJECTED]
            && arm_said == ["Arm rejected: master update being applied"]
            && arm_texts(run, start) == arm_said
            && run.bench.master.boots == boots + 1
            && master_runs(run) == Some(v5)
            && final_to == [190],
        format!(
            "put {state:?}, apply acks {acks:?} in {took} s, arm {arm_acks:?} {arm_said:?}, boots {}, runs {:?}, \
             final ACCEPTED to component {final_to:?}, texts {texts:?}",
            run.bench.master.boots - boots,
            master_runs(run)
        ),
    );
}
