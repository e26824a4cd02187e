//! Every scenario is a test: `cargo test` runs each through the same harness as `lbv bench --all`, with the same
//! default seed, and fails with the checks that did not hold.

use super::*;
use crate::bench::Engine;
use harness::run_with;

/// Run scenario `name` as `options` say and fail with every check that did not hold.
fn passes_with(name: &str, options: &Options) {
    let scenario = find(name).expect("a scenario of that name");
    let (report, _) = run_guarded(scenario, options, None);
    let failed: Vec<String> = report
        .checks
        .iter()
        .filter(|check| !check.passed)
        .map(|check| format!("{}: {}", check.name, check.detail))
        .collect();
    assert!(report.passed && failed.is_empty(), "{name} failed: {failed:#?}");
    assert!(!report.checks.is_empty(), "{name} checked nothing");
}

/// Run scenario `name` for its default duration on the default engine and fail with every check that did not hold.
fn passes(name: &str) {
    passes_with(name, &Options::new(SEED, Engine::default()));
}

macro_rules! scenario_tests {
    ($($test:ident: $name:literal,)*) => {
        $(
            #[test]
            fn $test() {
                passes($name);
            }
        )*

        #[test]
        fn every_scenario_is_a_test() {
            let tested = [$($name),*];
            let listed: Vec<&str> = SCENARIOS.iter().map(|scenario| scenario.name).collect();
            assert_eq!(tested.as_slice(), listed.as_slice());
        }
    };
}

scenario_tests! {
    dive: "dive",
    water_legacy: "water-legacy",
    water_seabotix: "water-seabotix",
    ground_fault_legacy: "ground-fault-legacy",
    ground_fault_seabotix: "ground-fault-seabotix",
    overtemp_legacy: "overtemp-legacy",
    overtemp_seabotix: "overtemp-seabotix",
    stall_legacy: "stall-legacy",
    stall_brushed: "stall-brushed",
    heavy_start_brushed: "heavy-start-brushed",
    stall_seabotix: "stall-seabotix",
    hall_legacy: "hall-legacy",
    hall_seabotix: "hall-seabotix",
    hall_glitches_seabotix: "hall-glitches-seabotix",
    hall_glitches_legacy: "hall-glitches-legacy",
    rocking_rotor: "rocking-rotor",
    water_threshold: "water-threshold",
    ground_glitch_seabotix: "ground-glitch-seabotix",
    ground_glitch_legacy: "ground-glitch-legacy",
    overcurrent_seabotix: "overcurrent-seabotix",
    overcurrent_legacy: "overcurrent-legacy",
    overcurrent_intermittent: "overcurrent-intermittent",
    info_power: "info-power",
    info_power_response: "info-power-response",
    bad_frames: "bad-frames",
    corrupted_stop: "corrupted-stop",
    status_noise: "status-noise",
    six_byte_status: "six-byte-status",
    link_failsafe: "link-failsafe",
    missing_thruster: "missing-thruster",
    stuck_sda: "stuck-sda",
    reset_mid_transfer: "reset-mid-transfer",
    console_silence: "console-silence",
    master_reboot: "master-reboot",
    thruster_crash: "thruster-crash",
    black_box: "black-box",
    battery_lost: "battery-lost",
    battery_bits: "battery-bits",
    ground_station_1hz: "ground-station-1hz",
    stray_byte: "stray-byte",
    second_sysid: "second-sysid",
    signing: "signing",
    signing_reboot: "signing-reboot",
    console_flood: "console-flood",
    settings_persist: "settings-persist",
    settings_power_cut: "settings-power-cut",
    settings_while_driving: "settings-while-driving",
    field_update: "field-update",
    fleet_update: "fleet-update",
    master_update: "master-update",
    acceptance: "acceptance",
    soak: "soak",
}

fn trace_of(seed: u64) -> String {
    let options = Options {
        seconds: Some(4.0),
        ..Options::new(seed, Engine::default())
    };
    let (report, bench) = run_with(find("dive").unwrap(), &options, None);
    assert!(report.sim_seconds >= 4.0);
    serde_json::to_string(&bench.trace).unwrap()
}

#[test]
fn the_same_seed_gives_the_same_trace_bit_for_bit() {
    let first = trace_of(7);
    assert_eq!(first, trace_of(7));
    assert_ne!(first, trace_of(8), "the seed sets the motors' starting positions");
}

#[test]
fn scenario_names_are_unique_and_cover_every_fault_on_both_families() {
    let names: Vec<&str> = SCENARIOS.iter().map(|scenario| scenario.name).collect();
    let mut unique = names.clone();
    unique.sort_unstable();
    unique.dedup();
    assert_eq!(unique.len(), names.len());
    assert!(
        find("acceptance").is_some(),
        "the dev kits' acceptance test runs with --all"
    );
    for fault in ["water", "ground-fault", "overtemp", "stall", "hall"] {
        for family in ["legacy", "seabotix"] {
            assert!(find(&format!("{fault}-{family}")).is_some(), "{fault}-{family}");
        }
    }
}

/// FNV-1a, 64 bits: a hash whose value does not depend on the Rust release.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |hash, byte| {
        (hash ^ u64::from(*byte)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// What a run produced, hashed in three parts: its checks, its metrics (but the wall-clock figure) and its trace.
fn outputs_hash(name: &str, seed: u64, seconds: Option<f64>) -> [u64; 3] {
    let options = Options {
        seconds,
        ..Options::new(seed, Engine::Exact)
    };
    let (mut report, bench) = run_with(find(name).unwrap(), &options, None);
    report.metrics.remove("real_time_factor");
    let hash = |value: String| fnv1a(value.as_bytes());
    [
        hash(serde_json::to_string(&report.checks).unwrap()),
        hash(serde_json::to_string(&report.metrics).unwrap()),
        hash(serde_json::to_string(&bench.trace).unwrap()),
    ]
}

/// The fixed-step engine's outputs, bit for bit, as they were before its speed-ups: a change that is only meant to
/// make the bench faster must leave these alone. (The soak's metrics and trace moved when a thruster whose orders
/// get through stopped going offline over unreadable statuses: its texts and link counts differ. The soak's and
/// the acceptance test's moved again when the thruster's fault filters and status path changed what it does, and
/// every run's metrics and trace when the master began to say at each start that it takes development-key files.
/// The dive's and the soak's metrics moved when the master began to ask each thruster what it runs as it answers,
/// before the vehicle may arm: one `Version` exchange each, on the bus. The acceptance test's moved when its
/// bad-order steps were cut to 0.5 s, below the thruster's 1 s stop on refused orders alone. All three moved when
/// a thruster's slave port began to take a write, and to end a read, once its bytes have moved on the bus rather
/// than at its START: an order reaches the thruster some 0.5 ms later (the dive's stick-to-wire latency went from
/// 20.3 to 20.8 ms), which shifts every poll's phase against the thrusters' control loops; and the acceptance
/// test's reset, which lands in the address byte of a transfer, now has that address not acknowledged. Every run's
/// metrics moved again when the master began to send "PilotGain" at 1 Hz: one console frame more a second. The
/// soak's metrics and trace, and all three of the acceptance test's, moved when the bench's comparator went from 8 A
/// to the IHM08M1's 30 A: a held rotor now draws its locked-rotor current until the stall stops it, where it was
/// cut. The dive's and the soak's metrics moved when the master began to ask each thruster of extension protocol 2
/// for its post-mortem record once it has said what it runs: one `PostMortem` exchange more each, on the bus.)
#[test]
fn the_fixed_step_engine_gives_the_same_outputs_bit_for_bit() {
    let hashes = [
        ("dive", outputs_hash("dive", 1, None)),
        ("soak", outputs_hash("soak", 3, Some(30.0))),
        ("acceptance", outputs_hash("acceptance", 1, None)),
    ];
    assert_eq!(
        hashes,
        [
            (
                "dive",
                [
                    9_438_953_949_539_847_389,
                    161_005_013_714_987_244,
                    9_168_998_874_324_394_523
                ]
            ),
            (
                "soak",
                [
                    11_520_363_284_237_921_549,
                    17_289_854_587_462_362_001,
                    6_464_279_142_245_404_592
                ]
            ),
            (
                "acceptance",
                [
                    3_919_343_844_451_674_287,
                    10_959_146_811_726_100_654,
                    10_816_395_420_685_957_923
                ]
            ),
        ]
    );
}
