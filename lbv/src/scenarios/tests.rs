//! Every scenario is a test: `cargo test` runs each through the same harness as `lbv bench --all`, with the same
//! default seed, and fails with the checks that did not hold.

use super::*;

/// `lbv bench`'s default seed.
const SEED: u64 = 1;

/// Run scenario `name` for its default duration and fail with every check that did not hold.
fn passes(name: &str) {
    let scenario = find(name).expect("a scenario of that name");
    let (report, _) = run_with(scenario, SEED, None, None);
    let failed: Vec<String> = report
        .checks
        .iter()
        .filter(|check| !check.passed)
        .map(|check| format!("{}: {}", check.name, check.detail))
        .collect();
    assert!(report.passed && failed.is_empty(), "{name} failed: {failed:#?}");
    assert!(!report.checks.is_empty(), "{name} checked nothing");
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
    stall_seabotix: "stall-seabotix",
    hall_legacy: "hall-legacy",
    hall_seabotix: "hall-seabotix",
    bad_frames: "bad-frames",
    missing_thruster: "missing-thruster",
    stuck_sda: "stuck-sda",
    reset_mid_transfer: "reset-mid-transfer",
    console_silence: "console-silence",
    master_reboot: "master-reboot",
    battery_lost: "battery-lost",
    battery_bits: "battery-bits",
    ground_station_1hz: "ground-station-1hz",
    stray_byte: "stray-byte",
    second_sysid: "second-sysid",
    signing: "signing",
    settings_persist: "settings-persist",
    settings_power_cut: "settings-power-cut",
    acceptance: "acceptance",
    soak: "soak",
}

fn trace_of(seed: u64) -> String {
    let (report, bench) = run_with(find("dive").unwrap(), seed, Some(4.0), None);
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
