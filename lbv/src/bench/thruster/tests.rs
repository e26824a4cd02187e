//! The bench thruster across a field update, as the board goes through one: a signed image written to DFU and
//! marked with its ticket, the reset the updater asks for, the thruster's bootloader's check and embassy-boot's
//! swap, the trial, a revert when the new image is cut off before it confirms, and a forged image the bootloader
//! refuses. On virtual time, against the bench's master.

use thruster_fw::ports::Updater;
use thruster_fw::trial::{TRIAL_CHECK, TRIAL_ROUNDS};
use update_image::{HEADER_LEN, Header, Ticket, Verdict, key_from_hex, sign};

use super::*;
use crate::bench::{Bench, BenchConfig, Engine};

/// The development key's secret half, which `lbv image sign --allow-dev-key` signs with.
const DEV_KEY: &str = include_str!("../../../../keys/dev.key");

fn new_version() -> Version {
    Version::new(0, 2, 0)
}

/// The payload and signature of `image`'s update file, as `lbv image sign` makes it with `seed` (keys/dev.key).
fn signed_with(image: &[u8], seed: &[u8; 32]) -> (Vec<u8>, [u8; 64]) {
    let file = sign(image, seed).unwrap();
    let header = Header::parse(&file).unwrap();
    (file[HEADER_LEN..].to_vec(), header.signature)
}

/// The thruster receives `image`, signed with `seed`, as its update task does: the payload's DFU pages erased and
/// written, then its ticket written and the payload marked for the bootloader.
fn receive_signed(thruster: &ThrusterBoard, image: &[u8], seed: &[u8; 32]) {
    let (payload, signature) = signed_with(image, seed);
    let mut dfu = partition(thruster.flash(), THRUSTER_PARTITIONS.dfu);
    let pages = payload.len().div_ceil(PAGE as usize) as u32;
    dfu.erase(0, pages * PAGE).unwrap();
    dfu.write(0, &payload).unwrap();
    let payload_len = payload.len() as u32;
    thruster
        .updater()
        .mark_updated(&Ticket { payload_len, signature })
        .unwrap();
}

/// The same, signed with the development key, which the bench's images take updates with.
fn receive(thruster: &ThrusterBoard, image: &[u8]) {
    receive_signed(thruster, image, &key_from_hex(DEV_KEY.trim()).unwrap());
}

fn running_version(thruster: &ThrusterBoard) -> Option<Version> {
    thruster.running_image().map(|image| image.version)
}

/// Whether ACTIVE starts with `image`.
fn active_holds(thruster: &ThrusterBoard, image: &[u8]) -> bool {
    partition(thruster.flash(), THRUSTER_PARTITIONS.active)
        .contents()
        .starts_with(image)
}

/// Whether the controller is up: it has taken an order since it booted.
fn answering(thruster: &ThrusterBoard) -> bool {
    thruster.shared().link.try_get().is_some()
}

fn swapped() -> Outcome {
    Outcome::Prepared {
        state: State::Swap,
        attempt: 1,
    }
}

/// A vehicle whose thruster T1 has received `new` and asked for the reset; run to just after the bench reset it.
/// Returns how long the reset's bootloader keeps the chip busy, and when the controller starts.
fn rebooted_into(bench: &mut Bench, new: &[u8]) -> (Duration, Instant) {
    bench.run_for(Duration::from_secs(1));
    let thruster = &bench.thrusters[0];
    assert_eq!(
        running_version(thruster),
        Some(FACTORY_VERSION),
        "the factory image runs"
    );
    receive(thruster, new);
    assert_eq!(thruster.boot_state(), Some(State::Swap), "marked for the swap");
    assert_eq!(running_version(thruster), Some(FACTORY_VERSION), "until the reset");

    let before = thruster.flash().stats();
    thruster.updater().reboot();
    // The bench resets it at the next instant it runs.
    let reset = bench.now();
    bench.run_for(Duration::from_millis(1));
    let thruster = &bench.thrusters[0];
    assert_eq!(thruster.reboots(), 1);
    assert!(!thruster.reboot_requested(), "served");
    assert_eq!(thruster.boot_outcome(), Some(&swapped()));
    let swap = FlashTiming::G431.work_time(before, thruster.flash().stats());
    (swap, reset + swap)
}

#[test]
fn a_signed_image_is_swapped_in_at_the_reset_confirms_itself_on_trial_and_stays() {
    let mut bench = Bench::new(&BenchConfig::lbv300(1), Engine::Events);
    let new = made_up_image(Target::ThrusterSeabotix, new_version(), FACTORY_IMAGE_LEN, 2);
    let (swap, starts) = rebooted_into(&mut bench, &new);
    assert!(
        (Duration::from_secs(2)..Duration::from_secs(3)).contains(&swap),
        "a swap of ACTIVE's 25 pages, and the erase of DFU past the payload, at the G431's timing: {swap:?}"
    );
    let thruster = &bench.thrusters[0];
    assert_eq!(running_version(thruster), Some(new_version()));
    assert_eq!(
        thruster.updater().running_info(),
        thruster.running_info(),
        "what Version reports"
    );
    assert!(active_holds(thruster, &new), "ACTIVE holds the new image");

    // Silent on the bus until the bootloader is done, then polled again within the master's retry.
    let started = bench
        .run_until(Duration::from_secs(10), |bench| answering(&bench.thrusters[0]))
        .unwrap();
    assert!(
        started >= swap - Duration::from_millis(1) && started < swap + Duration::from_secs(1),
        "answered {started:?} after the reset, the bootloader took {swap:?}"
    );
    assert!(
        bench.thrusters[0].shared().replies.on_trial(),
        "the new image runs on trial"
    );

    bench
        .run_until(Duration::from_secs(10), |bench| {
            bench.thrusters[0].boot_state() != Some(State::Swap)
        })
        .unwrap();
    let confirmed = bench.now() - starts;
    let trial = TRIAL_CHECK * TRIAL_ROUNDS;
    assert!(
        confirmed >= trial && confirmed < trial + Duration::from_secs(1),
        "confirmed {confirmed:?} after it started: the trial takes {trial:?} of watchdog rounds"
    );
    let thruster = &bench.thrusters[0];
    assert_eq!(thruster.boot_state(), Some(State::Boot));
    assert!(!thruster.shared().replies.on_trial());

    bench.power(0, false);
    bench.run_for(Duration::from_millis(100));
    bench.power(0, true);
    bench.run_for(Duration::from_millis(500));
    let thruster = &bench.thrusters[0];
    let kept = Outcome::Prepared {
        state: State::Boot,
        attempt: 1,
    };
    assert_eq!(thruster.boot_outcome(), Some(&kept), "nothing to swap");
    assert_eq!(running_version(thruster), Some(new_version()));
    assert!(active_holds(thruster, &new));
    assert!(answering(thruster), "no bootloader time without a swap");
    assert_eq!(
        running_version(&bench.thrusters[1]),
        Some(FACTORY_VERSION),
        "each thruster has its own flash"
    );
}

#[test]
fn a_new_image_cut_off_before_it_confirms_is_reverted_by_the_bootloader() {
    let mut bench = Bench::new(&BenchConfig::lbv300(2), Engine::Events);
    let new = made_up_image(Target::ThrusterSeabotix, new_version(), FACTORY_IMAGE_LEN, 2);
    let (swap, _) = rebooted_into(&mut bench, &new);
    bench.run_for(swap + Duration::from_secs(1));
    let thruster = &bench.thrusters[0];
    assert!(answering(thruster));
    assert_eq!(running_version(thruster), Some(new_version()));
    assert_eq!(thruster.boot_state(), Some(State::Swap), "still on trial");

    bench.power(0, false);
    bench.run_for(Duration::from_millis(100));
    bench.power(0, true);
    let thruster = &bench.thrusters[0];
    assert_eq!(
        thruster.boot_outcome(),
        Some(&swapped()),
        "a revert reads the state as a swap"
    );
    assert_eq!(running_version(thruster), Some(FACTORY_VERSION));
    assert!(
        active_holds(thruster, &factory_image(Family::SeaBotix)),
        "the factory image is back"
    );
    assert_ne!(thruster.boot_state(), Some(State::Swap), "not on trial");

    bench.run_for(Duration::from_secs(5));
    let thruster = &bench.thrusters[0];
    assert!(answering(thruster), "up again after the revert's time");
    assert!(!thruster.shared().replies.on_trial());
    assert_eq!(running_version(thruster), Some(FACTORY_VERSION));
}

#[test]
fn a_reboot_asked_through_the_updater_power_cycles_the_thruster_on_both_engines() {
    for engine in [Engine::Events, Engine::Exact] {
        let mut bench = Bench::new(&BenchConfig::lbv300(3), engine);
        bench.run_for(Duration::from_secs(2));
        let orders = |bench: &Bench, index: usize| bench.thrusters[index].shared().link.try_get().unwrap().orders;
        let rounds = |bench: &Bench, index: usize| bench.thrusters[index].shared().health.rounds();
        let (orders_before, rounds_before) = (orders(&bench, 2), rounds(&bench, 2));
        assert!(orders_before >= 50 && rounds_before >= 15, "{engine:?}: running");
        assert_eq!(bench.thrusters[2].reboots(), 0);

        bench.thrusters[2].updater().reboot();
        bench.run_for(Duration::from_millis(100));
        assert_eq!(bench.thrusters[2].reboots(), 1, "{engine:?}");
        assert!(!bench.thrusters[2].reboot_requested(), "{engine:?}");
        assert!(
            orders(&bench, 2) < 10 && rounds(&bench, 2) < 2,
            "{engine:?}: the controller started afresh ({} orders, {} rounds)",
            orders(&bench, 2),
            rounds(&bench, 2)
        );
        assert!(orders(&bench, 1) > orders_before, "{engine:?}: the others run on");
        let reset = &bench.trace.events.last().unwrap().text;
        assert_eq!(reset, "T3: reboots", "{engine:?}");
        assert_eq!(
            bench.thrusters[2].boot_outcome(),
            Some(&Outcome::Prepared {
                state: State::Boot,
                attempt: 1
            }),
            "{engine:?}: through the bootloader"
        );
        assert_eq!(
            running_version(&bench.thrusters[2]),
            Some(FACTORY_VERSION),
            "{engine:?}"
        );
    }
}

#[test]
fn an_image_its_bootloader_refuses_is_not_swapped_in_and_the_thruster_says_why() {
    let mut bench = Bench::new(&BenchConfig::lbv300(1), Engine::Events);
    bench.run_for(Duration::from_secs(1));
    let new = made_up_image(Target::ThrusterSeabotix, new_version(), FACTORY_IMAGE_LEN, 2);
    // Validly signed, but not with the key the running image embeds (the development key's).
    receive_signed(&bench.thrusters[0], &new, &[0x42; 32]);
    bench.thrusters[0].updater().reboot();
    bench.run_for(Duration::from_millis(1));
    let thruster = &bench.thrusters[0];
    assert_eq!(
        thruster.boot_outcome(),
        Some(&Outcome::Refused {
            verdict: Verdict::Signature,
            attempt: 1
        })
    );
    assert_eq!(running_version(thruster), Some(FACTORY_VERSION));
    assert!(active_holds(thruster, &factory_image(Family::SeaBotix)));
    assert_eq!(thruster.boot_state(), Some(State::Boot), "the mark cleared");
    assert_eq!(
        thruster.updater().verdict(),
        Some(Verdict::Signature),
        "what Version reports"
    );
    bench.run_for(Duration::from_secs(1));
    assert!(answering(&bench.thrusters[0]), "at once: nothing was swapped");
}
