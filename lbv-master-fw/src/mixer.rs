//! The thruster mixer: the pilot's sticks (MANUAL_CONTROL) to one speed per thruster.
//!
//! Axes are the vehicle's: surge forward, sway right, heave up, yaw clockwise seen from above. Each thruster's
//! positive speed is the thrust direction given in the tables ("pushes"); the thrusters are mounted (or their
//! motor wires swapped) so that the controller's forward turns push that way.
//!
//! LBV300-6 (SeaBotix's vehicle: 4 horizontal, 1 vertical, 1 lateral; the LBV200-4 has 4). The four horizontal thrusters sit at the corners,
//! turned 45 degrees, in the usual vectored "X" (the numbering of ArduSub's vectored frame: front right, front
//! left, rear right, rear left). Together they surge, sway and yaw; the lateral thruster adds sway.
//!
//! | thruster | position | pushes (positive speed) | surge | sway | heave | yaw |
//! |---|---|---|---|---|---|---|
//! | 1 | front right, horizontal, 45 degrees | forward and left | +1 | -1 | 0 | -1 |
//! | 2 | front left, horizontal, 45 degrees | forward and right | +1 | +1 | 0 | +1 |
//! | 3 | rear right, horizontal, 45 degrees | forward and right | +1 | +1 | 0 | -1 |
//! | 4 | rear left, horizontal, 45 degrees | forward and left | +1 | -1 | 0 | +1 |
//! | 5 | centre, vertical | up | 0 | 0 | +1 | 0 |
//! | 6 | centre, lateral | right | 0 | +1 | 0 | 0 |
//!
//! LBV200-4: two aft thrusters side by side surge and yaw (differential thrust), one vertical, one lateral.
//!
//! | thruster | position | pushes (positive speed) | surge | sway | heave | yaw |
//! |---|---|---|---|---|---|---|
//! | 1 | aft starboard (right), horizontal | forward | +1 | 0 | 0 | -1 |
//! | 2 | aft port (left), horizontal | forward | +1 | 0 | 0 | +1 |
//! | 3 | centre, vertical | up | 0 | 0 | +1 | 0 |
//! | 4 | centre, lateral | right | 0 | +1 | 0 | 0 |
//!
//! (Yaw signs: a thruster on the right pushing forward turns the vehicle counter-clockwise, so a clockwise yaw
//! asks it to push astern.)
//!
//! Arithmetic: each stick becomes -1000..=1000 thousandths of full scale (z: `(z - 500) * 2`, so 500 is neutral
//! and 1000 full up), the frame's matrix mixes them, `gain_percent` scales the result, and when any thruster
//! would exceed full scale all are scaled down by the same factor, so the direction of motion is kept. The
//! result is rounded to the nearest of the 102 speed steps (half away from zero, so negated sticks give exactly
//! negated speeds). Integer arithmetic throughout; no input can overflow or panic.

use tmc_proto::Speed;

/// The pilot's sticks, as MAVLink MANUAL_CONTROL carries them: x forward, y right, r yaw clockwise, each
/// -1000..=1000; z vertical thrust 0..=1000 with 500 neutral (the ArduSub convention; 1000 = up).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct ManualInput {
    /// Surge, -1000 (astern) ..= 1000 (ahead).
    pub x: i16,
    /// Sway, -1000 (left) ..= 1000 (right).
    pub y: i16,
    /// Heave, 0 (down) ..= 1000 (up), 500 neutral.
    pub z: i16,
    /// Yaw, -1000 (counter-clockwise) ..= 1000 (clockwise), seen from above.
    pub r: i16,
}

/// The LBV thruster layouts (see the module tables).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum FrameKind {
    /// LBV200-4: 2 horizontal aft, 1 vertical, 1 lateral.
    Lbv200_4,
    /// LBV300-6: 4 horizontal vectored, 1 vertical, 1 lateral.
    Lbv300_6,
}

/// One thruster's share of (surge, sway, heave, yaw).
type Row = [i8; 4];

/// LBV200-4 (module table).
const LBV200_4: [Row; 4] = [[1, 0, 0, -1], [1, 0, 0, 1], [0, 0, 1, 0], [0, 1, 0, 0]];

/// LBV300-6 (module table).
const LBV300_6: [Row; 6] = [
    [1, -1, 0, -1],
    [1, 1, 0, 1],
    [1, 1, 0, -1],
    [1, -1, 0, 1],
    [0, 0, 1, 0],
    [0, 1, 0, 0],
];

/// Full scale, in thousandths.
const FULL: i32 = 1000;

impl FrameKind {
    /// How many thrusters the frame has.
    pub(crate) const fn thrusters(self) -> usize {
        match self {
            Self::Lbv200_4 => 4,
            Self::Lbv300_6 => 6,
        }
    }

    /// The frame with that many thrusters (the `LBV_FRAME` parameter: 4 or 6).
    pub(crate) const fn from_thrusters(count: u8) -> Option<Self> {
        match count {
            4 => Some(Self::Lbv200_4),
            6 => Some(Self::Lbv300_6),
            _ => None,
        }
    }

    /// The vehicle's name, e.g. `"LBV300-6"`.
    #[cfg(test)]
    pub(crate) const fn name(self) -> &'static str {
        match self {
            Self::Lbv200_4 => "LBV200-4",
            Self::Lbv300_6 => "LBV300-6",
        }
    }

    /// The mixing matrix: one row per thruster, in thruster order.
    const fn matrix(self) -> &'static [Row] {
        match self {
            Self::Lbv200_4 => &LBV200_4,
            Self::Lbv300_6 => &LBV300_6,
        }
    }
}

/// Mix the pilot's sticks into one speed per slot of the master's `N` thruster slots (slots beyond the frame's
/// thrusters are ZERO).
///
/// `gain_percent` is clamped to 1..=100; the sticks to their MANUAL_CONTROL ranges.
pub(crate) fn mix<const N: usize>(frame: FrameKind, input: ManualInput, gain_percent: u8) -> [Speed; N] {
    let axes = [
        stick(input.x),
        stick(input.y),
        (i32::from(input.z).clamp(0, FULL) - FULL / 2) * 2,
        stick(input.r),
    ];
    let gain = i32::from(gain_percent.clamp(1, 100));
    // Each thruster's demand in 1/100_000 of full scale: at most 4 axes * 1000 * 100, far from overflow.
    let mut demand = [0i32; N];
    for (value, row) in demand.iter_mut().zip(frame.matrix()) {
        let mixed: i32 = row.iter().zip(axes).map(|(c, axis)| i32::from(*c) * axis).sum();
        *value = mixed * gain;
    }
    // Full scale unless some thruster would exceed it: then everything shrinks by the same factor.
    let full = FULL * 100;
    let peak = demand.iter().map(|value| value.abs()).max().unwrap_or(0);
    let scale = peak.max(full);
    demand.map(|value| Speed::new_saturating(round_div(value * i32::from(Speed::MAX_STEP), scale)))
}

/// A stick, -1000..=1000.
fn stick(value: i16) -> i32 {
    i32::from(value).clamp(-FULL, FULL)
}

/// `numerator / denominator` rounded to nearest, half away from zero; `denominator` is positive.
pub(crate) fn round_div(numerator: i32, denominator: i32) -> i32 {
    let half = denominator / 2;
    if numerator >= 0 {
        (numerator + half) / denominator
    } else {
        -((-numerator + half) / denominator)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shared::MAX_THRUSTERS;

    const FRAMES: [FrameKind; 2] = [FrameKind::Lbv200_4, FrameKind::Lbv300_6];

    fn sticks(x: i16, y: i16, z: i16, r: i16) -> ManualInput {
        ManualInput { x, y, z, r }
    }

    fn steps(speeds: [Speed; MAX_THRUSTERS]) -> [i8; MAX_THRUSTERS] {
        speeds.map(Speed::step)
    }

    #[test]
    fn neutral_sticks_stop_every_thruster() {
        for frame in FRAMES {
            for gain in [1, 50, 100] {
                assert_eq!(mix(frame, sticks(0, 0, 500, 0), gain), [Speed::ZERO; MAX_THRUSTERS]);
            }
        }
    }

    #[test]
    fn frame_sizes() {
        assert_eq!(FrameKind::Lbv200_4.thrusters(), 4);
        assert_eq!(FrameKind::Lbv300_6.thrusters(), 6);
        for frame in FRAMES {
            assert_eq!(frame.matrix().len(), frame.thrusters());
            assert_eq!(FrameKind::from_thrusters(frame.thrusters() as u8), Some(frame));
        }
        assert_eq!(FrameKind::from_thrusters(5), None);
        assert_eq!(FrameKind::Lbv200_4.name(), "LBV200-4");
    }

    #[test]
    fn lbv300_pure_axes() {
        let f = FrameKind::Lbv300_6;
        // Surge ahead: the four horizontals forward, nothing else.
        assert_eq!(
            steps(mix(f, sticks(1000, 0, 500, 0), 100)),
            [102, 102, 102, 102, 0, 0, 0, 0]
        );
        // Sway right: the vectored pairs cancel their surge and yaw; the lateral pushes right.
        assert_eq!(
            steps(mix(f, sticks(0, 1000, 500, 0), 100)),
            [-102, 102, 102, -102, 0, 102, 0, 0]
        );
        // Heave up: only the vertical.
        assert_eq!(steps(mix(f, sticks(0, 0, 1000, 0), 100)), [0, 0, 0, 0, 102, 0, 0, 0]);
        assert_eq!(steps(mix(f, sticks(0, 0, 0, 0), 100)), [0, 0, 0, 0, -102, 0, 0, 0]);
        // Yaw clockwise: right-hand corners astern, left-hand corners ahead.
        assert_eq!(
            steps(mix(f, sticks(0, 0, 500, 1000), 100)),
            [-102, 102, -102, 102, 0, 0, 0, 0]
        );
        // Half surge.
        assert_eq!(steps(mix(f, sticks(500, 0, 500, 0), 100)), [51, 51, 51, 51, 0, 0, 0, 0]);
    }

    #[test]
    fn lbv300_rows_cancel_the_other_axes() {
        // The columns are orthogonal: a pure axis drives no net force or torque on any other axis (each row is
        // that thruster's share of every axis, up to its lever arm and the 45 degree factor).
        let rows = FrameKind::Lbv300_6.matrix();
        for axis in 0..4 {
            for other in 0..4 {
                if axis == other {
                    continue;
                }
                let sum: i32 = rows
                    .iter()
                    .map(|row| i32::from(row[axis]) * i32::from(row[other]))
                    .sum();
                assert_eq!(sum, 0, "axis {axis} leaks into {other}");
            }
        }
    }

    #[test]
    fn lbv200_pure_axes() {
        let f = FrameKind::Lbv200_4;
        assert_eq!(
            steps(mix(f, sticks(1000, 0, 500, 0), 100)),
            [102, 102, 0, 0, 0, 0, 0, 0]
        );
        assert_eq!(
            steps(mix(f, sticks(-1000, 0, 500, 0), 100)),
            [-102, -102, 0, 0, 0, 0, 0, 0]
        );
        assert_eq!(steps(mix(f, sticks(0, 1000, 500, 0), 100)), [0, 0, 0, 102, 0, 0, 0, 0]);
        assert_eq!(steps(mix(f, sticks(0, 0, 1000, 0), 100)), [0, 0, 102, 0, 0, 0, 0, 0]);
        // Clockwise: starboard astern, port ahead.
        assert_eq!(
            steps(mix(f, sticks(0, 0, 500, 1000), 100)),
            [-102, 102, 0, 0, 0, 0, 0, 0]
        );
    }

    #[test]
    fn gain_scales() {
        let f = FrameKind::Lbv300_6;
        assert_eq!(steps(mix(f, sticks(1000, 0, 500, 0), 50)), [51, 51, 51, 51, 0, 0, 0, 0]);
        assert_eq!(steps(mix(f, sticks(1000, 0, 500, 0), 1)), [1, 1, 1, 1, 0, 0, 0, 0]);
        // Out-of-range gains are clamped.
        assert_eq!(
            mix::<MAX_THRUSTERS>(f, sticks(1000, 0, 500, 0), 0),
            mix(f, sticks(1000, 0, 500, 0), 1)
        );
        assert_eq!(
            mix::<MAX_THRUSTERS>(f, sticks(1000, 0, 500, 0), 255),
            mix(f, sticks(1000, 0, 500, 0), 100)
        );
        // 1000 * 25 % = 250 thousandths = 25.5 steps -> 26 (half away from zero).
        assert_eq!(steps(mix(f, sticks(0, 0, 1000, 0), 25))[4], 26);
        assert_eq!(steps(mix(f, sticks(0, 0, 0, 0), 25))[4], -26);
    }

    #[test]
    fn saturation_keeps_the_ratios() {
        let f = FrameKind::Lbv300_6;
        // Surge + yaw at full stick: thrusters 2 and 4 would need 2x, 1 and 3 zero -> 2 and 4 at full.
        assert_eq!(
            steps(mix(f, sticks(1000, 0, 500, 1000), 100)),
            [0, 102, 0, 102, 0, 0, 0, 0]
        );
        // Surge + half yaw: 1.5 and 0.5 -> scaled by 1/1.5: 102 and 34.
        assert_eq!(
            steps(mix(f, sticks(1000, 0, 500, 500), 100)),
            [34, 102, 34, 102, 0, 0, 0, 0]
        );
        // Full surge + sway + yaw: thruster 2 needs 3x; everyone shrinks by 3, lateral included.
        assert_eq!(
            steps(mix(f, sticks(1000, 1000, 500, 1000), 100)),
            [-34, 102, 34, 34, 0, 34, 0, 0]
        );
        // With 50 % gain the same sticks saturate less: 1.5 peak.
        assert_eq!(
            steps(mix(f, sticks(1000, 1000, 500, 1000), 50)),
            [-34, 102, 34, 34, 0, 34, 0, 0]
        );
        assert_eq!(
            steps(mix(f, sticks(1000, 0, 500, 1000), 50)),
            [0, 102, 0, 102, 0, 0, 0, 0]
        );
        assert_eq!(steps(mix(f, sticks(500, 0, 500, 500), 50)), [0, 51, 0, 51, 0, 0, 0, 0]);
    }

    #[test]
    fn grid_in_range_symmetric_and_unused_slots_zero() {
        let values: Vec<i16> = (-1000..=1000).step_by(125).chain([i16::MIN, i16::MAX, -1, 1]).collect();
        let heaves: Vec<i16> = (0..=1000).step_by(125).chain([i16::MIN, i16::MAX, 499, 501]).collect();
        for frame in FRAMES {
            for gain in [1, 33, 50, 100] {
                for &x in &values {
                    for &y in &values {
                        for &r in &values {
                            for &z in &heaves {
                                let out: [Speed; MAX_THRUSTERS] = mix(frame, sticks(x, y, z, r), gain);
                                for speed in &out[frame.thrusters()..] {
                                    assert_eq!(*speed, Speed::ZERO);
                                }
                                let mirrored_z = 1000 - z.clamp(0, 1000);
                                let negated = mix(
                                    frame,
                                    sticks(x.saturating_neg(), y.saturating_neg(), mirrored_z, r.saturating_neg()),
                                    gain,
                                );
                                assert_eq!(
                                    steps(negated),
                                    steps(out).map(|s| -s),
                                    "{frame:?} {x} {y} {z} {r} gain {gain}"
                                );
                                assert!(out.iter().all(|s| s.step().unsigned_abs() <= 102));
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn saturated_outputs_are_proportional_to_the_demand() {
        // Every saturated mix is the unsaturated demand shrunk by one factor: each step is within rounding of
        // demand * 102 / peak.
        let f = FrameKind::Lbv300_6;
        for x in (-1000..=1000).step_by(250) {
            for y in (-1000..=1000).step_by(250) {
                for r in (-1000..=1000).step_by(250) {
                    let rows = f.matrix();
                    let demand: Vec<i32> = rows
                        .iter()
                        .map(|row| i32::from(row[0]) * x + i32::from(row[1]) * y + i32::from(row[3]) * r)
                        .collect();
                    let peak = demand.iter().map(|d| d.abs()).max().unwrap().max(1000);
                    let out: [Speed; MAX_THRUSTERS] = mix(f, sticks(x as i16, y as i16, 500, r as i16), 100);
                    for (speed, d) in out.iter().zip(&demand) {
                        let exact = f64::from(*d) * 102.0 / f64::from(peak);
                        assert!((f64::from(speed.step()) - exact).abs() <= 0.5, "{x} {y} {r}: {exact}");
                    }
                }
            }
        }
    }
}
