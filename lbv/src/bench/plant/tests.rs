use super::*;
use thruster_fw::commutation::{COAST, commutate, drive_for};
use thruster_fw::drive::Direction;
use thruster_fw::hall::{FORWARD_SEQUENCE, Transition, transition};
use thruster_fw::sensors::WaterSensor;

const DT: f64 = 50e-6;
const V: f64 = 24.0;

fn duty(percent: f64) -> Duty {
    Duty::new_saturating((percent * 100.0).round() as i32)
}

/// Ideal commutation from the plant's own halls.
fn ideal(plant: &Plant, duty: Duty) -> BridgeDrive {
    drive_for(plant.hall_state(), duty)
}

/// Run for `seconds` at 50 us with the drive `drive_of` computes each step; returns the hall transitions seen.
fn run(plant: &mut Plant, seconds: f64, duty: Duty, drive_of: impl Fn(&Plant, Duty) -> BridgeDrive) -> Vec<Transition> {
    let steps = (seconds / DT).round() as usize;
    let mut transitions = Vec::new();
    for _ in 0..steps {
        let before = plant.hall_state();
        let drive = drive_of(plant, duty);
        if plant.step(DT, drive, duty, V) {
            transitions.push(transition(before, plant.hall_state()));
        }
    }
    transitions
}

/// Mean rpm, phase current and supply current over `seconds` more of the same drive.
fn average(plant: &mut Plant, seconds: f64, duty: Duty) -> (f64, f64, f64) {
    let steps = (seconds / DT).round() as usize;
    let (mut rpm, mut phase, mut supply) = (0.0, 0.0, 0.0);
    for _ in 0..steps {
        let drive = ideal(plant, duty);
        plant.step(DT, drive, duty, V);
        rpm += plant.rpm();
        phase += plant.phase_current_a();
        supply += plant.supply_current_a();
    }
    let n = steps as f64;
    (rpm / n, phase / n, supply / n)
}

fn settled(percent: f64) -> (Plant, f64, f64, f64) {
    let mut plant = Plant::new(MotorParams::THRUSTER).with_angle(0.3);
    run(&mut plant, 1.5, duty(percent), ideal);
    let (rpm, phase, supply) = average(&mut plant, 0.2, duty(percent));
    eprintln!("{percent} %: {rpm:.0} rpm, phase {phase:.2} A, supply {supply:.2} A");
    (plant, rpm, phase, supply)
}

#[test]
fn full_duty_settles_near_5000_rpm_at_4_amps() {
    let (plant, rpm, phase, supply) = settled(100.0);
    assert!((4700.0..=5200.0).contains(&rpm), "{rpm} rpm");
    assert!((3.5..=4.5).contains(&phase), "{phase} A");
    assert!((supply - phase).abs() < 1e-9, "full duty: supply = phase current");
    assert!(plant.torque_nm() > 0.0);
}

#[test]
fn lower_duties_give_lower_speeds() {
    let (_, rpm50, phase50, supply50) = settled(50.0);
    assert!((2600.0..=3000.0).contains(&rpm50), "{rpm50} rpm");
    assert!((1.2..=2.0).contains(&phase50), "{phase50} A");
    assert!((supply50 - 0.5 * phase50).abs() < 0.01, "{supply50} A");
    let (_, rpm25, phase25, _) = settled(25.0);
    assert!((1300.0..=1650.0).contains(&rpm25), "{rpm25} rpm");
    assert!((0.3..=0.7).contains(&phase25), "{phase25} A");
}

#[test]
fn spin_up_is_quick() {
    let mut plant = Plant::new(MotorParams::THRUSTER);
    run(&mut plant, 0.25, duty(100.0), ideal);
    assert!(plant.rpm() > 4600.0, "{} rpm after 0.25 s", plant.rpm());
}

#[test]
fn reverse_duty_spins_in_reverse_with_the_halls_walking_backwards() {
    let mut plant = Plant::new(MotorParams::THRUSTER).with_angle(1.0);
    run(&mut plant, 1.5, duty(-100.0), ideal);
    let transitions = run(&mut plant, 0.2, duty(-100.0), ideal);
    assert!((-5200.0..=-4700.0).contains(&plant.rpm()), "{} rpm", plant.rpm());
    assert!(plant.torque_nm() < 0.0);
    assert!((3.5..=4.5).contains(&plant.phase_current_a()));
    assert!(
        plant.supply_current_a() > 3.5,
        "reverse drive still draws from the supply"
    );
    // 0.2 s at ~5000 rpm: ~16 revolutions, 24 edges each.
    assert!(transitions.len() > 300, "{} edges", transitions.len());
    assert!(transitions.iter().all(|&t| t == Transition::Reverse), "{transitions:?}");
}

#[test]
fn wrong_commutation_does_not_spin_forward() {
    // The drive of the hall state two sectors ahead: 120 degrees early, its pair meets a reversed back-EMF.
    let two_ahead = |plant: &Plant, duty: Duty| {
        let drive = plant
            .hall_state()
            .sector()
            .and_then(|k| commutate(FORWARD_SEQUENCE[usize::from((k + 2) % 6)], Direction::Forward));
        match duty.direction() {
            Some(_) => drive.unwrap_or(COAST),
            None => COAST,
        }
    };
    let mut plant = Plant::new(MotorParams::THRUSTER).with_angle(0.3);
    run(&mut plant, 1.0, duty(100.0), two_ahead);
    assert!(plant.rpm() < 500.0, "two sectors ahead: {} rpm", plant.rpm());

    // The reverse table while asking forward (positive duty).
    let reverse_table = |plant: &Plant, _: Duty| commutate(plant.hall_state(), Direction::Reverse).unwrap_or(COAST);
    let mut plant = Plant::new(MotorParams::THRUSTER).with_angle(0.3);
    run(&mut plant, 1.0, duty(100.0), reverse_table);
    assert!(plant.rpm() < -4000.0, "reverse table: {} rpm", plant.rpm());
}

#[test]
fn torque_follows_commutation_at_every_angle() {
    // At standstill with 10 % duty, the ideal drive gives 2 ke i everywhere; every drive of another sector gives
    // less at some angle.
    let p = MotorParams::THRUSTER;
    let d = duty(10.0);
    let i = 0.1 * V / (2.0 * p.resistance_ohm);
    for step in 0..3600 {
        let angle = f64::from(step) / 3600.0 * TAU / f64::from(p.pole_pairs);
        let mut plant = Plant::new(p).with_angle(angle);
        let drive = ideal(&plant, d);
        plant.step(0.0, drive, d, V);
        assert!(
            (plant.torque_nm() - 2.0 * p.ke_v_s_per_rad * i).abs() < 1e-12,
            "at {angle}"
        );
        assert!((plant.phase_current_a() - i).abs() < 1e-12);
        for other in FORWARD_SEQUENCE {
            let drive = commutate(other, Direction::Forward).unwrap();
            plant.step(0.0, drive, d, V);
            assert!(plant.torque_nm() <= 2.0 * p.ke_v_s_per_rad * i + 1e-12);
        }
    }
}

#[test]
fn power_balances() {
    // Supply power = copper loss + mechanical power, at any instant, motoring or regenerating.
    let mut plant = Plant::new(MotorParams::THRUSTER).with_angle(0.1);
    run(&mut plant, 0.5, duty(100.0), ideal);
    let mut regenerated = false;
    for percent in [100.0, 60.0, 20.0, 5.0] {
        for _ in 0..200 {
            let d = duty(percent);
            let drive = ideal(&plant, d);
            plant.step(0.0, drive, d, V);
            let copper: f64 = plant.currents.iter().map(|i| i * i * plant.params.resistance_ohm).sum();
            let mechanical = plant.torque_nm() * plant.omega;
            let supply = V * plant.supply_current_a();
            assert!(
                (supply - copper - mechanical).abs() < 1e-9,
                "{supply} {copper} {mechanical}"
            );
            regenerated |= plant.supply_current_a() < 0.0;
            plant.step(DT, drive, d, V);
        }
    }
    // Dropping from full speed to 20 % duty, the back-EMF exceeds the applied voltage: regenerative braking.
    assert!(regenerated);
}

#[test]
fn sudden_low_duty_brakes_regeneratively() {
    let mut plant = Plant::new(MotorParams::THRUSTER);
    run(&mut plant, 1.0, duty(100.0), ideal);
    let d = duty(20.0);
    let drive = ideal(&plant, d);
    plant.step(DT, drive, d, V);
    assert!(plant.supply_current_a() < -1.0, "{} A", plant.supply_current_a());
    assert!(plant.torque_nm() < 0.0);
    assert!(plant.phase_current_a() > 1.0);
}

#[test]
fn coasting_rotor_slows_to_a_stop_without_current() {
    let mut plant = Plant::new(MotorParams::THRUSTER);
    run(&mut plant, 1.0, duty(100.0), ideal);
    let mut previous = plant.rpm();
    assert!(previous > 4700.0);
    for second in 1..=10 {
        for _ in 0..20_000 {
            plant.step(DT, COAST, Duty::ZERO, V);
            assert_eq!(plant.phase_current_a(), 0.0);
            assert_eq!(plant.supply_current_a(), 0.0);
            assert_eq!(plant.torque_nm(), 0.0);
            assert!(plant.rpm() <= previous && plant.rpm() >= 0.0);
            previous = plant.rpm();
        }
        if second == 3 {
            assert!(plant.rpm() < 300.0, "{} rpm after 3 s", plant.rpm());
        }
    }
    assert!(plant.rpm() < 20.0, "{} rpm after 10 s", plant.rpm());
    // Duty with a coasting bridge, or a drive with zero duty on one side only, still moves nothing.
    let mut still = Plant::new(MotorParams::THRUSTER);
    still.step(DT, COAST, duty(100.0), V);
    assert_eq!(still.phase_current_a(), 0.0);
}

#[test]
fn hall_edges_per_revolution_at_constant_speed() {
    for pole_pairs in [4u8, 1, 7] {
        for rpm in [600.0, 4500.0, -3000.0] {
            // No load and no drive: the speed stays exactly constant.
            let params = MotorParams {
                pole_pairs,
                prop_k: 0.0,
                friction: 0.0,
                ..MotorParams::THRUSTER
            };
            let mut plant = Plant::new(params).with_angle(0.123);
            plant.omega = rpm * TAU / 60.0;
            let revolution_s = 60.0 / f64::abs(rpm);
            let steps = (revolution_s / DT).round() as usize;
            let mut edges = Vec::new();
            for _ in 0..steps {
                let before = plant.hall_state();
                if plant.step(DT, COAST, Duty::ZERO, V) {
                    edges.push(transition(before, plant.hall_state()));
                }
            }
            assert!((plant.rpm() - rpm).abs() < 1e-9);
            assert_eq!(
                edges.len(),
                6 * usize::from(pole_pairs),
                "{pole_pairs} pole pairs, {rpm} rpm"
            );
            let expected = if rpm > 0.0 {
                Transition::Forward
            } else {
                Transition::Reverse
            };
            assert!(edges.iter().all(|&t| t == expected), "{edges:?}");
        }
    }
}

#[test]
fn driven_motor_walks_the_forward_sequence() {
    let mut plant = Plant::new(MotorParams::THRUSTER).with_angle(2.0);
    run(&mut plant, 1.0, duty(100.0), ideal);
    // Count over exactly one mechanical revolution, starting just after an edge.
    while !{
        let drive = ideal(&plant, duty(100.0));
        plant.step(DT, drive, duty(100.0), V)
    } {}
    let mut turned = 0.0;
    let mut states = vec![plant.hall_state()];
    while turned < TAU {
        let before = plant.angle_rad;
        let drive = ideal(&plant, duty(100.0));
        if plant.step(DT, drive, duty(100.0), V) {
            states.push(plant.hall_state());
        }
        turned += (plant.angle_rad - before).rem_euclid(TAU);
    }
    // 24 edges: back to the starting state, through FORWARD_SEQUENCE 4 times.
    assert_eq!(states.len(), 25);
    assert_eq!(states.first(), states.last());
    for pair in states.windows(2) {
        assert_eq!(transition(pair[0], pair[1]), Transition::Forward);
    }
}

/// Seconds until the winding passes `limit_c`, stalled at `percent` duty with the drive fixed at the start.
fn stall_time_to(percent: f64, limit_c: f64, max_s: f64) -> Option<f64> {
    let mut plant = Plant::new(MotorParams::THRUSTER).with_angle(0.5);
    plant.blocked = true;
    let d = duty(percent);
    let drive = ideal(&plant, d);
    let steps = (max_s / DT).round() as usize;
    for n in 1..=steps {
        assert!(!plant.step(DT, drive, d, V), "a held rotor makes no hall edge");
        if plant.winding_c() > limit_c {
            assert_eq!(plant.rpm(), 0.0);
            return Some(n as f64 * DT);
        }
    }
    None
}

#[test]
fn stalled_rotor_overheats_within_a_minute() {
    let at_30 = stall_time_to(30.0, 110.0, 80.0).expect("30 % stalled never passed 110 C");
    eprintln!("stalled at 30 %: 110 C after {at_30:.1} s");
    assert!((30.0..=50.0).contains(&at_30), "{at_30} s");
    let at_100 = stall_time_to(100.0, 110.0, 10.0).expect("100 % stalled never passed 110 C");
    eprintln!("stalled at 100 %: 110 C after {at_100:.2} s");
    assert!(at_100 < 3.0, "{at_100} s");

    // The held rotor draws |duty| V / 2R with no back-EMF, and the torque it would turn with.
    let mut plant = Plant::new(MotorParams::THRUSTER);
    plant.blocked = true;
    let drive = ideal(&plant, duty(30.0));
    plant.step(DT, drive, duty(30.0), V);
    assert!((plant.phase_current_a() - 6.0).abs() < 1e-9);
    assert!((plant.torque_nm() - 2.0 * 0.0183 * 6.0).abs() < 1e-9);
    assert!((plant.supply_current_a() - 1.8).abs() < 1e-9);
}

#[test]
fn full_speed_running_stays_cool_and_cools_after_stopping() {
    let mut plant = Plant::new(MotorParams::THRUSTER);
    let mut hottest: f64 = 0.0;
    for _ in 0..200 {
        run(&mut plant, 1.0, duty(100.0), ideal);
        hottest = hottest.max(plant.winding_c());
    }
    let after_200_s = plant.winding_c();
    run(&mut plant, 10.0, duty(100.0), ideal);
    eprintln!(
        "full speed: {after_200_s:.1} C after 200 s, {:.1} C after 210 s",
        plant.winding_c()
    );
    assert!((60.0..=85.0).contains(&after_200_s), "{after_200_s} C");
    assert!(hottest < 100.0);
    assert!((plant.winding_c() - after_200_s).abs() < 0.5, "settled");

    // Stop: exponential cooling towards the water with the 30 s time constant.
    let start = plant.winding_c();
    run(&mut plant, 30.0, Duty::ZERO, ideal);
    let expected = 15.0 + (start - 15.0) * (-1.0f64).exp();
    assert!(
        (plant.winding_c() - expected).abs() < 1.0,
        "{} C, expected {expected}",
        plant.winding_c()
    );
    run(&mut plant, 60.0, Duty::ZERO, ideal);
    eprintln!("90 s after stopping: {:.1} C", plant.winding_c());
    assert!(plant.winding_c() < 20.0);
}

#[test]
fn warm_water_raises_the_winding_temperature() {
    let mut plant = Plant::new(MotorParams::THRUSTER);
    plant.ambient_c = 40.0;
    for _ in 0..300 {
        plant.step(1.0, COAST, Duty::ZERO, V);
    }
    assert!((plant.winding_c() - 40.0).abs() < 0.01);
    // A stall in warm water trips sooner; 30 % stalled settles at 40 + 43.2 W x 3 K/W.
    plant.blocked = true;
    let d = duty(30.0);
    let drive = ideal(&plant, d);
    for _ in 0..300 {
        plant.step(1.0, drive, d, V);
    }
    assert!(
        (plant.winding_c() - (40.0 + 43.2 * 3.0)).abs() < 0.1,
        "{}",
        plant.winding_c()
    );
}

#[test]
fn blocked_rotor_holds_still_until_freed() {
    let mut plant = Plant::new(MotorParams::THRUSTER).with_angle(0.2);
    run(&mut plant, 0.5, duty(100.0), ideal);
    assert!(plant.rpm() > 4000.0);
    plant.blocked = true;
    let hall = plant.hall_state();
    let transitions = run(&mut plant, 0.5, duty(100.0), ideal);
    assert!(transitions.is_empty());
    assert_eq!(plant.rpm(), 0.0);
    assert_eq!(plant.hall_state(), hall);
    assert!(
        (plant.phase_current_a() - 20.0).abs() < 1e-9,
        "stall current {}",
        plant.phase_current_a()
    );
    plant.blocked = false;
    run(&mut plant, 0.5, duty(100.0), ideal);
    assert!(plant.rpm() > 4000.0);
}

#[test]
fn hall_fault_overrides_the_sensors() {
    let mut plant = Plant::new(MotorParams::THRUSTER).with_angle(0.2);
    let real = plant.hall_state();
    assert!(real.is_valid());
    assert!(!plant.step(DT, COAST, Duty::ZERO, V));
    plant.hall_fault = Some(HallState::from_bits(0b000));
    assert_eq!(plant.hall_state(), HallState::from_bits(0b000));
    // The change is reported once, at the next step.
    assert!(plant.step(DT, COAST, Duty::ZERO, V));
    assert!(!plant.step(DT, COAST, Duty::ZERO, V));
    // The controller's table coasts on an invalid state: the motor does not start.
    let transitions = run(&mut plant, 0.5, duty(100.0), ideal);
    assert!(transitions.is_empty());
    assert_eq!(plant.rpm(), 0.0);
    assert_eq!(plant.phase_current_a(), 0.0);
    // A stuck valid state: the drive never changes, so the rotor is pulled to one position, the halls still stuck.
    plant.hall_fault = Some(FORWARD_SEQUENCE[3]);
    assert!(plant.step(DT, COAST, Duty::ZERO, V));
    let transitions = run(&mut plant, 1.0, duty(30.0), ideal);
    assert!(transitions.is_empty());
    // It swings about that position, lightly damped, but never turns on.
    assert!(plant.rpm().abs() < 300.0, "{} rpm", plant.rpm());
    assert_eq!(plant.hall_state(), FORWARD_SEQUENCE[3]);
    // Cleared: the real sensors again, reported as a change if they differ.
    plant.hall_fault = None;
    let changed = plant.step(DT, COAST, Duty::ZERO, V);
    assert_eq!(changed, plant.hall_state() != FORWARD_SEQUENCE[3]);
    assert_eq!(plant.hall_state(), plant.rotor_hall_state());
}

#[test]
fn water_sensor_resistance_is_a_plain_setting() {
    let sensor = WaterSensor {
        pull_down_ohms: 1_000_000,
    };
    let mut plant = Plant::new(MotorParams::THRUSTER);
    assert_eq!(plant.water_ohms, 20_000_000);
    // Dry: well below the 1 Mohm water threshold's reading.
    assert!(sensor.raw_at(plant.water_ohms) < sensor.raw_at(1_000_000) / 4);
    plant.water_ohms = 500_000;
    run(&mut plant, 0.2, duty(100.0), ideal);
    assert_eq!(plant.water_ohms, 500_000);
    assert!(sensor.raw_at(plant.water_ohms) > sensor.raw_at(1_000_000));
}

#[test]
fn new_and_with_angle() {
    let plant = Plant::new(MotorParams::THRUSTER);
    assert_eq!((plant.rpm(), plant.winding_c(), plant.ambient_c), (0.0, 15.0, 15.0));
    assert!(!plant.blocked && plant.hall_fault.is_none());
    assert_eq!(plant.hall_state(), hall_state_at(0));
    // 10 mechanical degrees at 4 pole pairs: 40 electrical, sector 0.
    let plant = Plant::new(MotorParams::THRUSTER).with_angle(10f64.to_radians());
    assert_eq!(plant.hall_state(), FORWARD_SEQUENCE[0]);
    let plant = Plant::new(MotorParams::THRUSTER).with_angle(-10f64.to_radians());
    assert_eq!(plant.hall_state(), hall_state_at(320_000));
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        assert_eq!(Plant::new(MotorParams::THRUSTER).with_angle(bad).angle_rad, 0.0);
    }
    let plant = Plant::new(MotorParams::THRUSTER).with_angle(1e300);
    assert!((0.0..TAU).contains(&plant.angle_rad));
}

fn assert_finite(plant: &Plant, what: &str) {
    for (name, x) in [
        ("rpm", plant.rpm()),
        ("phase", plant.phase_current_a()),
        ("supply", plant.supply_current_a()),
        ("winding", plant.winding_c()),
        ("torque", plant.torque_nm()),
        ("angle", plant.angle_rad),
    ] {
        assert!(x.is_finite(), "{what}: {name} = {x}");
    }
}

#[test]
fn extreme_inputs_stay_finite() {
    let dts = [
        0.0,
        -1.0,
        f64::NAN,
        f64::INFINITY,
        f64::NEG_INFINITY,
        1e-300,
        1e9,
        f64::MAX,
        5e-5,
    ];
    let volts = [
        0.0,
        -24.0,
        f64::NAN,
        f64::INFINITY,
        f64::NEG_INFINITY,
        1e12,
        f64::MAX,
        24.0,
    ];
    let duties = [
        Duty::new_saturating(i32::MIN),
        Duty::ZERO,
        Duty::new_saturating(i32::MAX),
        duty(30.0),
    ];
    let mut plant = Plant::new(MotorParams::THRUSTER);
    plant.step(f64::NAN, ideal(&plant, duty(50.0)), duty(50.0), 24.0);
    assert_eq!(
        (plant.rpm(), plant.winding_c()),
        (0.0, 15.0),
        "a NaN step moves nothing"
    );
    plant.step(-1.0, ideal(&plant, duty(50.0)), duty(50.0), 24.0);
    assert_eq!(
        (plant.rpm(), plant.winding_c()),
        (0.0, 15.0),
        "a negative step moves nothing"
    );
    for dt in dts {
        for v in volts {
            for d in duties {
                for drive in [ideal(&plant, d), COAST, [PhaseDrive::Pwm; 3], [PhaseDrive::Low; 3]] {
                    plant.step(dt, drive, d, v);
                    assert_finite(&plant, &format!("dt {dt} V {v} {d:?} {drive:?}"));
                }
            }
        }
    }
    // Huge voltage with ideal commutation: absurd but finite.
    let mut plant = Plant::new(MotorParams::THRUSTER);
    for _ in 0..20_000 {
        let drive = ideal(&plant, duty(100.0));
        plant.step(DT, drive, duty(100.0), f64::MAX);
        assert_finite(&plant, "huge voltage");
    }
    // Garbage parameters and ambient.
    for value in [
        f64::NAN,
        f64::INFINITY,
        f64::NEG_INFINITY,
        0.0,
        -1.0,
        1e300,
        f64::MIN_POSITIVE,
    ] {
        let params = MotorParams {
            pole_pairs: 0,
            resistance_ohm: value,
            ke_v_s_per_rad: value,
            inertia_kg_m2: value,
            prop_k: value,
            friction: value,
            thermal_resistance_k_per_w: value,
            thermal_capacity_j_per_k: value,
            brushed: value.is_sign_negative(),
        };
        let mut plant = Plant::new(params).with_angle(value);
        plant.ambient_c = value;
        for dt in dts {
            for v in volts {
                let drive = ideal(&plant, duty(100.0));
                plant.step(dt, drive, duty(100.0), v);
                assert_finite(&plant, &format!("params {value} dt {dt} V {v}"));
                plant.hall_state();
            }
        }
    }
}

#[test]
fn rem_euclid_is_the_library_s_bit_for_bit() {
    let mut random = crate::bench::Random::new(5);
    let mut values: Vec<f64> = vec![
        0.0,
        -0.0,
        1e-300,
        -1e-300,
        f64::MIN_POSITIVE,
        TAU,
        -TAU,
        TAU - 1e-15,
        4.0 * TAU,
        360.0,
        -360.0,
        359.999_999_999_999_94,
        -1e-17,
        255.9 * 360.0,
        256.0 * 360.0,
        1e300,
        f64::MAX,
        f64::NAN,
        f64::INFINITY,
        f64::NEG_INFINITY,
    ];
    for _ in 0..200_000 {
        let scale = [1.0, 10.0, 400.0, 3000.0, 1e6][random.below(5) as usize];
        values.push((random.unit() - 0.3) * scale);
        values.push(f64::from_bits(random.next_u64()));
    }
    for m in [TAU, 360.0, 1.0, 0.3] {
        for &x in &values {
            let (ours, library) = (rem_euclid(x, m), x.rem_euclid(m));
            assert!(
                ours.to_bits() == library.to_bits() || (ours.is_nan() && library.is_nan()),
                "{x:e} rem {m}: {ours:e} != {library:e}"
            );
        }
    }
}

#[test]
fn emf_shape_matches_the_firmware_model() {
    for (deg, expected) in [
        (0.0, 0.0),
        (15.0, 0.5),
        (30.0, 1.0),
        (90.0, 1.0),
        (180.0, 0.0),
        (270.0, -1.0),
    ] {
        assert!((emf_shape(deg) - expected).abs() < 1e-12, "{deg}");
    }
    assert!((emf_shape(345.0) + 0.5).abs() < 1e-12);
    assert!((emf_shape(-15.0) + 0.5).abs() < 1e-12);
    assert_eq!(emf_shape(f64::NAN), 0.0);
    // H1 high while e_A > e_B, H2 while e_B > e_C, H3 while e_C > e_A.
    for tenth in 0..3600 {
        let deg = f64::from(tenth) / 10.0 + 0.05;
        let e = [emf_shape(deg), emf_shape(deg - 120.0), emf_shape(deg - 240.0)];
        let bits = hall_state_at((deg * 1000.0) as u32).bits();
        for (bit, (x, y)) in [(0, 1), (1, 2), (2, 0)].into_iter().enumerate() {
            if (e[x] - e[y]).abs() > 1e-9 {
                assert_eq!(bits & (1 << bit) != 0, e[x] > e[y], "H{} at {deg}", bit + 1);
            }
        }
    }
}

#[test]
fn a_brushed_motor_is_a_dc_motor_at_every_angle() {
    let forward = thruster_fw::tasks::h_bridge(Duty::new_saturating(10_000));
    let reverse = thruster_fw::tasks::h_bridge(Duty::new_saturating(-10_000));
    for angle in [0.0, 0.4, 1.3, 2.9] {
        // Locked: 24 V across 1.2 ohm, whatever the angle, either way.
        let mut plant = Plant::new(MotorParams::BRUSHED_THRUSTER).with_angle(angle);
        plant.blocked = true;
        plant.step(1e-3, forward, Duty::new_saturating(10_000), 24.0);
        assert!(
            (plant.phase_current_a() - 20.0).abs() < 1e-9,
            "{}",
            plant.phase_current_a()
        );
        assert!(plant.torque_nm() > 0.0);
        plant.step(1e-3, reverse, Duty::new_saturating(-10_000), 24.0);
        assert!((plant.phase_current_a() - 20.0).abs() < 1e-9);
        assert!(plant.torque_nm() < 0.0);
        assert_eq!(plant.hall_state(), HallState::from_bits(0b111));
        assert_eq!(plant.time_to_edge(), None);
    }
    // Free, at full duty: the BLDC motor's full speed and current on its plateaus (~5000 rpm, 4 A), and no hall
    // edge on the way.
    let mut plant = Plant::new(MotorParams::BRUSHED_THRUSTER).with_angle(1.0);
    let mut edges = 0;
    for _ in 0..40_000 {
        edges += usize::from(plant.step(50e-6, forward, Duty::new_saturating(10_000), 24.0));
    }
    assert_eq!(edges, 0);
    assert!((4_900.0..5_100.0).contains(&plant.rpm()), "{}", plant.rpm());
    assert!(
        (3.8..4.2).contains(&plant.phase_current_a()),
        "{}",
        plant.phase_current_a()
    );
    // The back-EMF across the terminals is 2 ke omega: 24 V less I x 1.2 ohm.
    let emf = 2.0 * MotorParams::THRUSTER.ke_v_s_per_rad * plant.rpm() * TAU / 60.0;
    assert!((emf - (24.0 - plant.phase_current_a() * 1.2)).abs() < 1e-6, "{emf}");
}
