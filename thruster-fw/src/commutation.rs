//! Six-step (trapezoidal) commutation: which half-bridge switches, which holds low and which floats, per hall state.
//!
//! The table assumes the sensor placement of [`hall_state_at`](crate::hall::hall_state_at): every hall edge falls
//! on a commutation point, 30 electrical degrees after a back-EMF zero crossing. In each sector the forward drive
//! switches the phase whose back-EMF is at its positive plateau, holds low the phase at its negative plateau and
//! floats the third, so the current always meets the largest back-EMF difference and the torque is steady.
//!
//! | sector | hall (H3 H2 H1) | electrical angle | Pwm | Low | Float |
//! |---|---|---|---|---|---|
//! | 0 | 001 | 30..90 | A | B | C |
//! | 1 | 011 | 90..150 | A | C | B |
//! | 2 | 010 | 150..210 | B | C | A |
//! | 3 | 110 | 210..270 | B | A | C |
//! | 4 | 100 | 270..330 | C | A | B |
//! | 5 | 101 | 330..30 | C | B | A |
//!
//! Reverse swaps Pwm and Low: the current, and so the torque, changes sign.

use crate::drive::{Direction, Duty};
use crate::hall::HallState;

/// What one half-bridge does during a commutation step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum PhaseDrive {
    /// Switched at the PWM duty (high side on for the duty, low side for the rest: complementary PWM).
    Pwm,
    /// Low side held on.
    Low,
    /// Both switches off: the phase floats.
    Float,
}

/// Drive of phases A, B, C.
pub type BridgeDrive = [PhaseDrive; 3];

/// All switches off: the motor coasts. Whenever driving must stop.
pub const COAST: BridgeDrive = [PhaseDrive::Float; 3];

/// Six-step commutation: the drive for a hall state and direction; `None` for an invalid hall state (the caller
/// coasts).
pub const fn commutate(hall: HallState, direction: Direction) -> Option<BridgeDrive> {
    use PhaseDrive::{Float, Low, Pwm};
    let forward = match hall.sector() {
        Some(0) => [Pwm, Low, Float],
        Some(1) => [Pwm, Float, Low],
        Some(2) => [Float, Pwm, Low],
        Some(3) => [Low, Pwm, Float],
        Some(4) => [Low, Float, Pwm],
        Some(5) => [Float, Low, Pwm],
        _ => return None,
    };
    match direction {
        Direction::Forward => Some(forward),
        Direction::Reverse => {
            let [a, b, c] = forward;
            Some([swap_pwm_low(a), swap_pwm_low(b), swap_pwm_low(c)])
        }
    }
}

/// Same with a duty: [`COAST`] for zero duty or invalid halls, else `commutate(hall, duty direction)`.
pub const fn drive_for(hall: HallState, duty: Duty) -> BridgeDrive {
    match duty.direction() {
        Some(direction) => match commutate(hall, direction) {
            Some(drive) => drive,
            None => COAST,
        },
        None => COAST,
    }
}

/// Pwm <-> Low; Float stays.
const fn swap_pwm_low(drive: PhaseDrive) -> PhaseDrive {
    match drive {
        PhaseDrive::Pwm => PhaseDrive::Low,
        PhaseDrive::Low => PhaseDrive::Pwm,
        PhaseDrive::Float => PhaseDrive::Float,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hall::{FORWARD_SEQUENCE, hall_state_at};

    const TURN: i64 = 360_000;
    const DIRECTIONS: [Direction; 2] = [Direction::Forward, Direction::Reverse];

    fn all_states() -> impl Iterator<Item = HallState> {
        (0..8u8).map(HallState::from_bits)
    }

    /// Phase A's back-EMF for forward rotation, in thousandths of its plateau, at `t` millidegrees: +1 on
    /// [30, 150), -1 on [210, 330), linear in between (zero crossings at 0 and 180).
    fn emf_a(t: i64) -> i64 {
        let t = t.rem_euclid(TURN);
        match t {
            0..30_000 => t / 30,
            30_000..150_000 => 1000,
            150_000..210_000 => (180_000 - t) / 30,
            210_000..330_000 => -1000,
            _ => (t - TURN) / 30,
        }
    }

    /// Back-EMF of phase `p` (0 = A, 1 = B, 2 = C): B lags A by 120 degrees, C by 240.
    fn emf(p: usize, t: i64) -> i64 {
        emf_a(t - 120_000 * p as i64)
    }

    /// Current into each phase: +1 into the Pwm phase, out of the Low phase, none in a floating one.
    fn current(d: PhaseDrive) -> i64 {
        match d {
            PhaseDrive::Pwm => 1,
            PhaseDrive::Low => -1,
            PhaseDrive::Float => 0,
        }
    }

    /// Electrical torque (power per speed) sum(e_x * i_x) for forward rotation at angle `t`.
    fn torque(drive: BridgeDrive, t: i64) -> i64 {
        (0..3).map(|p| emf(p, t) * current(drive[p])).sum()
    }

    fn phase_with(drive: BridgeDrive, role: PhaseDrive) -> usize {
        let found: Vec<usize> = (0..3).filter(|&p| drive[p] == role).collect();
        assert_eq!(found.len(), 1, "{drive:?} has not exactly one {role:?}");
        found[0]
    }

    fn drive_at(t: i64, direction: Direction) -> BridgeDrive {
        commutate(hall_state_at(t.rem_euclid(TURN) as u32), direction).unwrap()
    }

    /// Every whole degree, and 0.5 degree and 1 millidegree either side of every hall edge.
    fn sample_angles() -> Vec<i64> {
        let mut angles: Vec<i64> = (0..360).map(|d| d * 1000).collect();
        for k in 0..6 {
            let edge: i64 = 30_000 + 60_000 * k;
            for offset in [-500, -1, 0, 1, 500] {
                angles.push((edge + offset).rem_euclid(TURN));
            }
        }
        angles
    }

    #[test]
    fn each_step_drives_one_phase_high_one_low_and_floats_one() {
        for hall in all_states() {
            for direction in DIRECTIONS {
                match commutate(hall, direction) {
                    Some(drive) => {
                        assert!(hall.is_valid());
                        for role in [PhaseDrive::Pwm, PhaseDrive::Low, PhaseDrive::Float] {
                            phase_with(drive, role);
                        }
                    }
                    None => assert!(!hall.is_valid()),
                }
            }
        }
    }

    #[test]
    fn reverse_swaps_pwm_and_low() {
        for hall in FORWARD_SEQUENCE {
            let forward = commutate(hall, Direction::Forward).unwrap();
            let reverse = commutate(hall, Direction::Reverse).unwrap();
            for p in 0..3 {
                let expected = match forward[p] {
                    PhaseDrive::Pwm => PhaseDrive::Low,
                    PhaseDrive::Low => PhaseDrive::Pwm,
                    PhaseDrive::Float => PhaseDrive::Float,
                };
                assert_eq!(reverse[p], expected);
            }
        }
    }

    #[test]
    fn drive_for_follows_the_duty_and_coasts_when_it_must() {
        let duties = [-10_000, -810, -1, 1, 800, 10_000].map(Duty::new_saturating);
        for hall in all_states() {
            assert_eq!(drive_for(hall, Duty::ZERO), COAST);
            for duty in duties {
                let expected = match duty.direction() {
                    Some(direction) if hall.is_valid() => commutate(hall, direction).unwrap(),
                    _ => COAST,
                };
                assert_eq!(drive_for(hall, duty), expected, "{hall:?} {duty:?}");
            }
        }
        assert_eq!(
            drive_for(FORWARD_SEQUENCE[0], Duty::new_saturating(1)),
            [PhaseDrive::Pwm, PhaseDrive::Low, PhaseDrive::Float]
        );
        assert_eq!(
            drive_for(FORWARD_SEQUENCE[0], Duty::new_saturating(-1)),
            [PhaseDrive::Low, PhaseDrive::Pwm, PhaseDrive::Float]
        );
    }

    #[test]
    fn back_emf_model_and_halls_agree() {
        // The model's zero crossings and plateaus, then the hall placement: H1 = e_A > e_B, H2 = e_B > e_C,
        // H3 = e_C > e_A wherever the compared back-EMFs differ.
        assert_eq!(emf(0, 0), 0);
        assert_eq!(emf(0, 90_000), 1000);
        assert_eq!(emf(0, 180_000), 0);
        assert_eq!(emf(0, 270_000), -1000);
        assert_eq!(emf(1, 210_000), 1000);
        assert_eq!(emf(2, 330_000), 1000);
        for t in (0..TURN).step_by(100) {
            let bits = hall_state_at(t as u32).bits();
            for (bit, (x, y)) in [(0, 1), (1, 2), (2, 0)].into_iter().enumerate() {
                let (ex, ey) = (emf(x, t), emf(y, t));
                if ex != ey {
                    assert_eq!(bits & (1 << bit) != 0, ex > ey, "H{} at {t}", bit + 1);
                }
            }
        }
    }

    #[test]
    fn driven_phases_sit_on_their_plateaus_through_each_whole_sector() {
        // Every millidegree: the Pwm phase's back-EMF is at +1 and the Low phase's at -1, so each hall edge is an
        // ideal commutation point.
        for t in 0..TURN {
            let drive = drive_at(t, Direction::Forward);
            assert_eq!(emf(phase_with(drive, PhaseDrive::Pwm), t), 1000, "at {t}");
            assert_eq!(emf(phase_with(drive, PhaseDrive::Low), t), -1000, "at {t}");
        }
    }

    #[test]
    fn torque_has_the_sign_of_the_drive_direction() {
        for t in sample_angles() {
            let forward = torque(drive_at(t, Direction::Forward), t);
            let reverse = torque(drive_at(t, Direction::Reverse), t);
            assert!(forward > 0, "forward torque {forward} at {t}");
            assert!(reverse < 0, "reverse torque {reverse} at {t}");
            // Steady torque: the full line-to-line back-EMF, the most any pair offers at any angle.
            let best = (0..3)
                .flat_map(|x| (0..3).map(move |y| emf(x, t) - emf(y, t)))
                .max()
                .unwrap();
            assert_eq!(forward, best, "at {t}");
            assert_eq!(reverse, -best, "at {t}");
        }
    }

    #[test]
    fn driven_pair_has_the_largest_back_emf_difference_at_sector_middles() {
        for k in 0..6 {
            let middle = 60_000 + 60_000 * k;
            let drive = drive_at(middle, Direction::Forward);
            let (high, low) = (phase_with(drive, PhaseDrive::Pwm), phase_with(drive, PhaseDrive::Low));
            let driven = emf(high, middle) - emf(low, middle);
            for x in 0..3 {
                for y in 0..3 {
                    if (x, y) != (high, low) {
                        assert!(
                            emf(x, middle) - emf(y, middle) < driven,
                            "sector {k}: {x}-{y} beats {high}-{low}"
                        );
                    }
                }
            }
            assert_eq!(
                drive,
                commutate(FORWARD_SEQUENCE[k as usize], Direction::Forward).unwrap()
            );
        }
    }

    /// Between adjacent six-step states: one phase keeps its role (Pwm or Low), one goes from driven to floating,
    /// the floating one takes over the role of the phase that left; and the kept role alternates Pwm, Low, Pwm...
    fn assert_six_step(sequence: &[BridgeDrive; 6]) {
        let mut kept_roles = Vec::new();
        for k in 0..6 {
            let (a, b) = (sequence[k], sequence[(k + 1) % 6]);
            let kept: Vec<usize> = (0..3).filter(|&p| a[p] == b[p]).collect();
            assert_eq!(kept.len(), 1, "step {k}: {a:?} -> {b:?}");
            assert_ne!(a[kept[0]], PhaseDrive::Float, "step {k}");
            let left = (0..3).find(|&p| a[p] != PhaseDrive::Float && b[p] == PhaseDrive::Float);
            let joined = (0..3).find(|&p| a[p] == PhaseDrive::Float && b[p] != PhaseDrive::Float);
            let (left, joined) = (left.unwrap(), joined.unwrap());
            assert_eq!(b[joined], a[left], "step {k}");
            kept_roles.push(a[kept[0]]);
        }
        for k in 0..6 {
            assert_ne!(kept_roles[k], kept_roles[(k + 1) % 6]);
        }
    }

    #[test]
    fn consecutive_steps_hand_over_one_phase_at_a_time() {
        let forward = FORWARD_SEQUENCE.map(|h| commutate(h, Direction::Forward).unwrap());
        assert_six_step(&forward);
        // Reverse rotation walks the sequence backwards with the reverse drive.
        let mut reverse = FORWARD_SEQUENCE.map(|h| commutate(h, Direction::Reverse).unwrap());
        reverse.reverse();
        assert_six_step(&reverse);
    }

    #[test]
    fn reverse_drive_motors_a_reverse_turning_motor() {
        // Turning in reverse, the rotor passes the same angles backwards: back-EMF -e(t), halls hall_state_at(t).
        // The reverse drive then puts power into the motion.
        for t in sample_angles() {
            let drive = drive_at(t, Direction::Reverse);
            let power: i64 = (0..3).map(|p| -emf(p, t) * current(drive[p])).sum();
            assert_eq!(power, 2000, "at {t}");
        }
    }
}
