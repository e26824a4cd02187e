//! The speed loop: turns the ordered speed (IDS 8.3) into a duty for the power stage.
//!
//! Brushless motors run closed loop on the measured rpm: a slew-limited target, a feed-forward duty and a PI
//! correction. Brushed motors have no speed feedback and run open loop: the SPEED step is a PWM value (IDS 8.3.2).
//! Both honour the INFO power cap. All arithmetic is integer; nothing here can overflow or panic whatever the
//! inputs.

use embassy_time::{Duration, Instant};
use tmc_proto::{MotorKind, Speed};

use crate::drive::Duty;

/// Fractional bits of the PI gains.
const Q16: i64 = 1 << 16;
/// Microseconds per second. The ramp is kept in millionths of its unit (rpm or duty), so one step of
/// `ramp_per_s * dt_us` moves it exactly, with no rounding to accumulate.
const MICROS_PER_S: i64 = 1_000_000;
/// Longest time step taken in one update: a late call cannot make the ramp or the integrator jump.
const MAX_DT: Duration = Duration::from_millis(100);
/// Full scale duty, as the controller computes it.
const FULL: i64 = Duty::FULL as i64;
/// Bound on the integrator (duty, Q16): twice full scale, enough to offset any feed-forward.
const INTEGRAL_LIMIT: i64 = 2 * FULL * Q16;
/// Brushless full scale in rpm (IDS 8.3.2).
const FULL_SCALE_RPM: i64 = Speed::FULL_SCALE_RPM as i64;

/// Tuning of the speed loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct SpeedConfig {
    /// Which motor is driven: brushless runs closed loop in rpm, brushed open loop in duty.
    pub(crate) motor: MotorKind,
    /// Target slew limit, rpm per second (brushless) — the ramp. Brushed: duty per second in Duty units.
    /// 0 freezes the target where it is.
    pub(crate) ramp_per_s: u32,
    /// Feed-forward: the duty (1/10 000) that holds 4500 rpm at no load; the loop adds PI on top.
    /// Unused for brushed motors.
    pub(crate) full_scale_duty: u16,
    /// Proportional gain: duty units (1/10 000) per rpm of error, fixed point with 16 fractional bits
    /// (65 536 = 1 duty unit per rpm). Unused for brushed motors.
    pub(crate) kp_q16: u32,
    /// Integral gain: duty units per rpm of error per second, fixed point with 16 fractional bits.
    /// Unused for brushed motors.
    pub(crate) ki_q16_per_s: u32,
    /// The largest duty magnitude the loop puts out (1/10 000), whatever the order: the power stage's limit
    /// ([`MAX_DUTY`]). Brushed motors scale the SPEED step to it, so step 102 is this duty.
    pub(crate) max_duty: u16,
    /// The motor current the duty is held to, in 0.1 A ([`CurrentLimit`]); 0: none, the power stage's
    /// comparator alone limits it.
    pub current_limit_deciamps: u16,
}

/// The largest duty the reference power stage takes: 95 % on the X-NUCLEO-IHM08M1, whose high-side drivers
/// refresh their bootstrap capacitors while the low switch conducts (`g431_hw::tim1::IHM08M1`). With Cargo
/// feature `bringup` (the first power-up), 10 %.
pub const MAX_DUTY: u16 = if cfg!(feature = "bringup") {
    1_000
} else {
    g431_hw::tim1::IHM08M1.max_duty
};

impl SpeedConfig {
    /// Starting point for a brushless thruster: 0 to full scale in 0.5 s, 80 % duty for 4500 rpm unloaded,
    /// 2 duty units per rpm proportional and a 200 ms integral time. On a simulated 50 ms motor this settles
    /// within 2 % in about 0.5 s after the ramp, with a few percent overshoot at most while the feed-forward is
    /// at or below what the motor needs. To be tuned on the bench with the real motor and propeller.
    pub(crate) const BRUSHLESS_DEFAULT: SpeedConfig = SpeedConfig {
        motor: MotorKind::Brushless,
        ramp_per_s: 9_000,
        full_scale_duty: 8_000,
        kp_q16: 2 * 65_536,
        ki_q16_per_s: 10 * 65_536,
        max_duty: MAX_DUTY,
        current_limit_deciamps: 0,
    };

    /// Brushed thruster: open loop, 0 to 100 % duty in 0.5 s (the ramp's rate; the duty stops at `max_duty`).
    /// The feed-forward and gains are not used. The current is held to 7 A: above the reference motor's 4 A at
    /// full speed, below the power stage's comparator (the IHM08M1's near 30 A, as the bench has it), so the stage
    /// never cuts the pulses of a turning or locked motor and the voltage applied stays known (docs/decisions.md
    /// D13).
    pub const BRUSHED_DEFAULT: SpeedConfig = SpeedConfig {
        motor: MotorKind::Brushed,
        ramp_per_s: 20_000,
        full_scale_duty: Duty::FULL as u16,
        kp_q16: 0,
        ki_q16_per_s: 0,
        max_duty: MAX_DUTY,
        current_limit_deciamps: 70,
    };
}

/// Speed controller, stepped at 1 kHz by the control task.
///
/// Holds the ramped target and the integrator; [`SpeedController::reset`] forgets both.
#[derive(Debug, Clone, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct SpeedController {
    config: SpeedConfig,
    /// Ramped target in millionths of an rpm (brushless) or of a duty unit (brushed).
    ramp_micro: i64,
    /// PI integrator, duty units with 16 fractional bits, within ±[`INTEGRAL_LIMIT`].
    integral_q16: i64,
    /// Time of the previous update; `None` after `new()` or `reset()`.
    last: Option<Instant>,
}

impl SpeedController {
    /// A stopped controller.
    pub(crate) fn new(config: SpeedConfig) -> Self {
        SpeedController {
            config,
            ramp_micro: 0,
            integral_q16: 0,
            last: None,
        }
    }

    /// [`SpeedController::update_within`] with the duty held to a percentage (`Some(1..=100)`; `None`, `Some(0)`
    /// and `Some(101..)` mean no cap): the tests' shorthand.
    #[cfg(test)]
    pub(crate) fn update(
        &mut self,
        now: Instant,
        target: Speed,
        power_cap_percent: Option<u8>,
        measured_rpm: i32,
    ) -> Duty {
        let ceiling = u16::try_from(duty_limit(power_cap_percent)).unwrap_or(u16::MAX);
        self.update_within(now, target, ceiling, measured_rpm)
    }

    /// One control step at `now` (called at 1 kHz): the ordered speed, the duty magnitude's ceiling (1/10 000:
    /// what the INFO power limit, [`PowerLimit`], gives) and the measured signed rpm (ignored for brushed).
    /// Returns the duty to apply.
    ///
    /// Brushless: the target rpm slews towards `target.rpm()` at `ramp_per_s`; duty = feed-forward + PI on
    /// (ramped target - measured), clamped to ±100 % and to the ceiling. The integrator does not grow while the
    /// output is clamped (anti-windup), and while the ceiling holds the output the ramp holds too, so lifting it
    /// raises the speed at the ramp rate. The output never opposes the ramped target's direction: a slowing
    /// propeller is braked by the water, not by reverse torque. A zero ramped target gives exactly [`Duty::ZERO`]
    /// and resets the integrator, so a stopped motor is never driven.
    ///
    /// Brushed: open loop, duty proportional to the step (step 102 = 100 %), slewed at `ramp_per_s`, held to the
    /// ceiling. A lower ceiling takes effect at once; a higher one is reached through the ramp.
    ///
    /// The first call after `new()`/`reset()` uses dt = 0 (no jump from an unknown past); dt is clamped to
    /// 100 ms, and time going backwards counts as dt = 0.
    pub(crate) fn update_within(&mut self, now: Instant, target: Speed, ceiling: u16, measured_rpm: i32) -> Duty {
        let dt_us = self.step_time(now);
        let limit = i64::from(ceiling).min(FULL).min(i64::from(self.config.max_duty));
        match self.config.motor {
            MotorKind::Brushless => self.update_brushless(dt_us, target, limit, measured_rpm),
            MotorKind::Brushed => self.update_brushed(dt_us, target, limit),
        }
    }

    /// The configuration.
    pub(crate) fn config(&self) -> &SpeedConfig {
        &self.config
    }

    /// Forget the ramp and the integrator (on a stop, a fault or the failsafe): the next update starts from zero.
    pub(crate) fn reset(&mut self) {
        self.ramp_micro = 0;
        self.integral_q16 = 0;
        self.last = None;
    }

    /// The current ramped target in rpm (brushless) or duty units (brushed), for telemetry and tests.
    /// Truncated towards zero.
    pub(crate) fn ramped_target(&self) -> i32 {
        saturate_i32(self.ramp_micro / MICROS_PER_S)
    }

    /// The time since the previous update in microseconds, 0..=100 000, and remember `now`.
    fn step_time(&mut self, now: Instant) -> i64 {
        let dt = self
            .last
            .and_then(|last| now.checked_duration_since(last))
            .unwrap_or(Duration::from_ticks(0))
            .min(MAX_DT);
        self.last = Some(now);
        i64::try_from(dt.as_micros()).unwrap_or(0)
    }

    /// Largest ramp movement over `dt_us`, in millionths.
    fn max_step(&self, dt_us: i64) -> i64 {
        i64::from(self.config.ramp_per_s).saturating_mul(dt_us)
    }

    fn update_brushless(&mut self, dt_us: i64, target: Speed, limit: i64, measured_rpm: i32) -> Duty {
        let order = i64::from(target.rpm()).saturating_mul(MICROS_PER_S);
        let previous_ramp = self.ramp_micro;
        self.ramp_micro = slew(self.ramp_micro, order, self.max_step(dt_us));
        if self.ramp_micro == 0 {
            self.integral_q16 = 0;
            return Duty::ZERO;
        }

        // |ramp| <= 4500 rpm, so |error| < 2^32: no overflow in i64.
        let error = self.ramp_micro / MICROS_PER_S - i64::from(measured_rpm);
        // |full_scale_duty * ramp| <= 65 535 * 4.5e9 < 2^49.
        let feed_forward = i64::from(self.config.full_scale_duty) * self.ramp_micro / (FULL_SCALE_RPM * MICROS_PER_S);
        let proportional = i64::from(self.config.kp_q16).saturating_mul(error) / Q16;
        let fixed = feed_forward.saturating_add(proportional);

        // The output never drives against the ramped target's direction: slowing down is left to the water's drag
        // rather than to reverse torque, which would overshoot into reverse when the target reaches zero.
        let (low, high) = if self.ramp_micro > 0 { (0, limit) } else { (-limit, 0) };
        // Conditional integration: no growth while the output is already clamped in the error's direction.
        let before = fixed.saturating_add(self.integral_q16 / Q16);
        let winding_up = (before > high && error > 0) || (before < low && error < 0);
        if winding_up && limit < i64::from(self.config.max_duty) && (before > limit || before < -limit) {
            // The INFO cap holds the output: the ramp waits where it is, so lifting the cap later raises the
            // speed at the ramp rate instead of stepping the duty to the cap's far side.
            self.ramp_micro = previous_ramp;
        }
        if !winding_up {
            let delta = i64::from(self.config.ki_q16_per_s)
                .saturating_mul(error)
                .saturating_mul(dt_us)
                / MICROS_PER_S;
            self.integral_q16 = self
                .integral_q16
                .saturating_add(delta)
                .clamp(-INTEGRAL_LIMIT, INTEGRAL_LIMIT);
        }

        let output = fixed.saturating_add(self.integral_q16 / Q16).clamp(low, high);
        Duty::new_saturating(saturate_i32(output))
    }

    fn update_brushed(&mut self, dt_us: i64, target: Speed, limit: i64) -> Duty {
        self.integral_q16 = 0;
        let bound = limit.saturating_mul(MICROS_PER_S);
        let order = brushed_duty(target, self.config.max_duty)
            .clamp(-limit, limit)
            .saturating_mul(MICROS_PER_S);
        // A lowered cap applies at once; the ramp then never leaves the capped range.
        let capped = self.ramp_micro.clamp(-bound, bound);
        self.ramp_micro = slew(capped, order, self.max_step(dt_us));
        Duty::new_saturating(self.ramped_target())
    }
}

/// The INFO byte as a power limit, not a duty limit (docs/decisions.md D7): the power drawn from
/// the supply is held to INFO % of [`RATED_POWER_MW`], so the speed rises to the order as the current falls.
///
/// The power is estimated at the nominal [`SUPPLY_MV`] (VBUS is measured, for the brushed stall rule, but this
/// limit does not use it yet): |duty| x motor current x 24 V, the bridge's supply current times its nominal
/// voltage. A pack above or below 24 V makes the real power that much higher or lower.
///
/// The limit is a duty ceiling that integrates the power error relative to the cap: it moves by
/// [`POWER_LIMIT_GAIN_PER_S`] x full scale per second for an error of the whole cap. Relative to the cap, because the
/// power rises about with the square of the duty (P ~ 2P/d per unit of duty at fixed speed): the loop's time
/// constant is then about d / (2 x gain), 3.5 ms at the 14 % duty of INFO 10 from rest and 15 ms at 60 %, alike at
/// every INFO, where a gain on the rated power's error was 5 times slower at INFO 10 than at 50. A higher gain
/// brakes a fast rotor too hard when the cap falls: the current, measured without its sign, then reads the braking
/// current as power drawn, and the duty stays far below the cap until the rotor has slowed (on the bench, gain 50
/// held INFO 10 after INFO 100 at full ahead only after 154 ms; 20 holds it in 13 ms).
/// And while a cap is in force the ceiling never stands more than [`POWER_LIMIT_HEADROOM`] above the duty last
/// applied, limiting or not, so it has nothing to unwind when the power first exceeds the cap (from rest, or on a
/// lower INFO): it was that unwinding from full scale that let INFO 10 draw 52 W for 0.7 s. The headroom lets the
/// duty rise 10 x full scale per second, five times the speed ramp's pace, so it slows no start.
/// INFO 100, 0 and above 100 mean no limit (masters send 100 and behave as before: docs/decisions.md D6).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct PowerLimit {
    /// The duty ceiling in millionths of a duty unit.
    ceiling_micro: i64,
    last: Option<Instant>,
}

/// The reference thruster's rated power, mW: 96 W, what the BTD150-class thruster of `lbv/src/bench/plant.rs`
/// draws at full duty in water on 24 V (4 A). Full order (4500 rpm) draws less, so INFO 100 would never bite.
pub const RATED_POWER_MW: u32 = 96_000;
/// The nominal supply the power is estimated at, mV: the reference thruster's 24 V.
pub const SUPPLY_MV: u32 = 24_000;
/// The power limit's integrating gain, full scale per second per cap of error.
pub(crate) const POWER_LIMIT_GAIN_PER_S: i64 = 20;
/// How far the power limit's ceiling may stand above the duty last applied, in [`Duty`] units: 1 % of full scale,
/// 10 x full scale per second at the 1 kHz control step.
pub(crate) const POWER_LIMIT_HEADROOM: i64 = 100;

impl Default for PowerLimit {
    fn default() -> Self {
        Self::new()
    }
}

impl PowerLimit {
    /// No limit in effect yet: the ceiling at full scale.
    pub(crate) const fn new() -> Self {
        PowerLimit {
            ceiling_micro: FULL * MICROS_PER_S,
            last: None,
        }
    }

    /// The supply power estimated from the duty applied and the motor current, mW.
    pub(crate) fn power_mw(duty: Duty, current_deciamps: u16) -> i64 {
        // |duty| <= 10 000, current < 2^16, so the product stays far inside i64.
        // duty / 10 000 x deciamps / 10 x mV.
        i64::from(duty.magnitude()) * i64::from(current_deciamps) * i64::from(SUPPLY_MV) / (FULL * 10)
    }

    /// One step at `now`: INFO's `power_cap_percent`, the duty applied since the last step and the motor current
    /// it drew. Returns the duty ceiling (1/10 000).
    pub(crate) fn update(
        &mut self,
        now: Instant,
        power_cap_percent: Option<u8>,
        duty: Duty,
        current_deciamps: u16,
    ) -> u16 {
        let dt_us = self
            .last
            .and_then(|last| now.checked_duration_since(last))
            .map_or(0, |dt| i64::try_from(dt.min(MAX_DT).as_micros()).unwrap_or(0));
        self.last = Some(now);
        let full = FULL * MICROS_PER_S;
        let tracked = (i64::from(duty.magnitude()) + POWER_LIMIT_HEADROOM) * MICROS_PER_S;
        self.ceiling_micro = match power_cap_percent {
            Some(percent @ 1..=99) => {
                // At least 960 mW: the division below never sees zero.
                let cap = i64::from(RATED_POWER_MW) * i64::from(percent) / 100;
                let error = cap - Self::power_mw(duty, current_deciamps);
                // |error| <= ~1e7 mW, dt <= 1e5 us: the product stays inside i64. In millionths of a duty unit.
                let step = error * POWER_LIMIT_GAIN_PER_S * FULL * dt_us / cap.max(1);
                self.ceiling_micro.saturating_add(step).min(tracked).clamp(0, full)
            }
            _ => full,
        };
        u16::try_from(self.ceiling_micro / MICROS_PER_S).unwrap_or(u16::MAX)
    }
}

/// A motor current limit kept by the duty, for a brushed motor (docs/decisions.md D13): the power stage's
/// comparator would hold the current too, but by cutting pulses short, which leaves the voltage applied unknown
/// to the stall rule ([`crate::faults::CurrentStall`]).
///
/// A duty ceiling, stepped with each current sample: when the current exceeds the limit, the ceiling drops to the
/// duty applied scaled by limit / current (a locked rotor's current is proportional to the duty, so this lands on
/// the limit; a turning motor's falls faster than the duty, so it lands below), and to half of that when the break
/// tripped (the comparator held the current at its own threshold, so the reading understates what the duty
/// drives). Otherwise it rises by [`CURRENT_LIMIT_RISE`] a step, and never stands more than that above the duty
/// applied, so it has nothing to unwind when the current next exceeds the limit.
///
/// The current is measured without its sign, so a motor braking regeneratively (turning faster than the duty
/// drives it, as in the first part of a reversal) reads as drawing it: lowering the duty then raises the braking
/// current, and the ceiling falls until the bridge coasts, rising again as the rotor slows: the rotor slows on its
/// propeller's drag rather than braked at the limit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct CurrentLimit {
    /// The duty ceiling, in [`Duty`] units.
    ceiling: u16,
}

/// How far the current limit's ceiling rises a step (1 ms), in [`Duty`] units: 1 % of full scale, five times
/// the brushed ramp's pace.
pub(crate) const CURRENT_LIMIT_RISE: u16 = 100;

impl Default for CurrentLimit {
    fn default() -> Self {
        Self::new()
    }
}

impl CurrentLimit {
    /// Not limiting yet: the ceiling at full scale.
    pub(crate) const fn new() -> Self {
        CurrentLimit {
            ceiling: Duty::FULL as u16,
        }
    }

    /// One step: the limit in 0.1 A (0: none), the duty applied since the last step, the current it drew and
    /// whether the break tripped meanwhile. Returns the duty ceiling (1/10 000).
    pub(crate) fn update(
        &mut self,
        limit_deciamps: u16,
        duty: Duty,
        current_deciamps: u16,
        break_tripped: bool,
    ) -> u16 {
        let full = Duty::FULL as u16;
        let applied = duty.magnitude();
        self.ceiling = if limit_deciamps == 0 {
            full
        } else if break_tripped || current_deciamps > limit_deciamps {
            // applied <= 10 000 and limit < 2^16: the product fits in u32; the quotient is at most applied.
            let scaled =
                u32::from(applied) * u32::from(limit_deciamps) / u32::from(current_deciamps.max(limit_deciamps));
            let scaled = if break_tripped { scaled / 2 } else { scaled };
            u16::try_from(scaled).unwrap_or(full).min(self.ceiling)
        } else {
            self.ceiling
                .saturating_add(CURRENT_LIMIT_RISE)
                .min(applied.saturating_add(CURRENT_LIMIT_RISE))
                .min(full)
        };
        self.ceiling
    }
}

/// Duty magnitude allowed by the INFO power cap: `Some(1..=100)` percent of full scale, anything else full scale.
#[cfg(test)]
fn duty_limit(power_cap_percent: Option<u8>) -> i64 {
    match power_cap_percent {
        Some(percent @ 1..=100) => i64::from(percent) * (FULL / 100),
        _ => FULL,
    }
}

/// Open-loop brushed duty of a step: step * max_duty / 102, rounded half away from zero (step 102 = max_duty).
/// [`step_of_brushed_duty`] reads it back exactly for every step while max_duty > 102.
pub(crate) fn brushed_duty(target: Speed, max_duty: u16) -> i64 {
    divide_rounded(
        i64::from(target.step()) * i64::from(max_duty),
        i64::from(Speed::MAX_STEP),
    )
}

/// The SPEED step a brushed duty corresponds to: duty * 102 / max_duty, rounded half away from zero, saturated to
/// the step range (the status's readback of [`brushed_duty`]).
pub(crate) fn step_of_brushed_duty(duty: Duty, max_duty: u16) -> Speed {
    let step = divide_rounded(
        i64::from(duty.value()) * i64::from(Speed::MAX_STEP),
        i64::from(max_duty.max(1)),
    );
    Speed::new_saturating(saturate_i32(step))
}

/// `value / divisor` rounded half away from zero; `divisor` > 0.
fn divide_rounded(value: i64, divisor: i64) -> i64 {
    let half = divisor / 2;
    let rounded = if value < 0 { value - half } else { value + half };
    rounded / divisor
}

/// `current` moved towards `target` by at most `max_step` (max_step >= 0), never past it.
fn slew(current: i64, target: i64, max_step: i64) -> i64 {
    if target > current {
        current.saturating_add(max_step).min(target)
    } else {
        current.saturating_sub(max_step).max(target)
    }
}

fn saturate_i32(value: i64) -> i32 {
    i32::try_from(value).unwrap_or(if value < 0 { i32::MIN } else { i32::MAX })
}

#[cfg(test)]
mod tests {
    use super::*;
    use tmc_proto::Order;

    /// First-order motor: rpm' = (k * duty - rpm) / tau, with k so that `full_duty` gives 4500 rpm.
    struct Motor {
        rpm: f32,
        full_duty: f32,
        tau_s: f32,
    }

    impl Motor {
        fn new(full_duty: u16) -> Motor {
            Motor {
                rpm: 0.0,
                full_duty: f32::from(full_duty),
                tau_s: 0.05,
            }
        }

        fn step(&mut self, duty: Duty, dt_s: f32) {
            let steady = 4500.0 * f32::from(duty.value()) / self.full_duty;
            self.rpm += (steady - self.rpm) * dt_s / self.tau_s;
        }

        fn measured(&self) -> i32 {
            self.rpm.round() as i32
        }
    }

    /// Controller, motor and clock stepped together at 1 kHz.
    struct Rig {
        controller: SpeedController,
        motor: Motor,
        ms: u64,
    }

    impl Rig {
        fn new(config: SpeedConfig, motor_full_duty: u16) -> Rig {
            Rig {
                controller: SpeedController::new(config),
                motor: Motor::new(motor_full_duty),
                ms: 0,
            }
        }

        fn step(&mut self, step: i32, cap: Option<u8>) -> Duty {
            let duty = self.controller.update(
                Instant::from_millis(self.ms),
                Speed::new_saturating(step),
                cap,
                self.motor.measured(),
            );
            self.motor.step(duty, 0.001);
            self.ms += 1;
            duty
        }

        fn run(&mut self, step: i32, cap: Option<u8>, ms: u32) -> Duty {
            let mut duty = Duty::ZERO;
            for _ in 0..ms {
                duty = self.step(step, cap);
            }
            duty
        }
    }

    /// Within 2 % of the target (within 1 rpm of a zero target).
    fn within_2_percent(rpm: f32, target: i32) -> bool {
        if target == 0 {
            rpm.abs() <= 1.0
        } else {
            (rpm - target as f32).abs() <= 0.02 * (target as f32).abs()
        }
    }

    #[test]
    fn converges_to_the_ordered_rpm_both_ways() {
        // A motor matching the feed-forward, one needing more duty (load), one needing less.
        for motor_full_duty in [8_000, 9_500, 6_000] {
            let mut rig = Rig::new(SpeedConfig::BRUSHLESS_DEFAULT, motor_full_duty);
            for step in [10, 51, 102, -51, -102, 1, 0] {
                rig.run(step, None, 2_000);
                let target = Speed::new_saturating(step).rpm();
                assert_eq!(rig.controller.ramped_target(), target);
                assert!(
                    within_2_percent(rig.motor.rpm, target),
                    "motor {motor_full_duty}, step {step}: {} rpm for {target}",
                    rig.motor.rpm
                );
            }
        }
    }

    #[test]
    fn ramp_limit_is_respected_exactly() {
        let config = SpeedConfig::BRUSHLESS_DEFAULT;
        let mut controller = SpeedController::new(config);
        let mut previous = 0;
        // 9000 rpm/s at 1 ms steps: 9 rpm per step, full scale after exactly 500 ms.
        for ms in 0..=600u64 {
            controller.update(Instant::from_millis(ms), Speed::MAX_FORWARD, None, 0);
            let ramped = controller.ramped_target();
            assert!((ramped - previous).abs() <= 9, "at {ms} ms: {previous} -> {ramped}");
            assert_eq!(ramped, (9 * ms as i32).min(4500));
            previous = ramped;
        }

        // Irregular steps and a ramp that is not a whole number of rpm per millisecond: 4500 rpm/s.
        let config = SpeedConfig {
            ramp_per_s: 4_500,
            ..SpeedConfig::BRUSHLESS_DEFAULT
        };
        let mut controller = SpeedController::new(config);
        let mut ms = 0u64;
        let mut previous = 0;
        let mut reached_at = None;
        for dt in [1u64, 3, 7, 2].iter().cycle().take(800) {
            ms += dt;
            controller.update(Instant::from_millis(ms), Speed::MAX_FORWARD, None, 0);
            let ramped = controller.ramped_target();
            let allowed = (4_500 * *dt as u32).div_ceil(1_000) as i32;
            assert!(
                (ramped - previous).abs() <= allowed,
                "at {ms} ms: {previous} -> {ramped}"
            );
            if ramped == 4_500 && reached_at.is_none() {
                reached_at = Some(ms);
            }
            previous = ramped;
        }
        // The first update (at 1 ms) takes dt = 0, so full scale is reached 1000 ms after it.
        assert!(
            matches!(reached_at, Some(at) if (1_001..1_008).contains(&at)),
            "{reached_at:?}"
        );
    }

    #[test]
    fn reversal_passes_through_zero() {
        let mut rig = Rig::new(SpeedConfig::BRUSHLESS_DEFAULT, 8_000);
        rig.run(51, None, 2_000);
        let mut previous = rig.controller.ramped_target();
        let mut saw_zero = false;
        for _ in 0..2_000 {
            let duty = rig.step(-51, None);
            let ramped = rig.controller.ramped_target();
            assert!(ramped <= previous);
            if ramped == 0 {
                saw_zero = true;
                assert_eq!(duty, Duty::ZERO);
            }
            previous = ramped;
        }
        assert!(saw_zero);
        assert_eq!(rig.controller.ramped_target(), -2250);
        assert!(within_2_percent(rig.motor.rpm, -2250));
    }

    #[test]
    fn power_limit_estimate_and_ceiling_bounds() {
        // 50 % duty at 4 A on 24 V: 2 A from the supply, 48 W.
        assert_eq!(PowerLimit::power_mw(Duty::new_saturating(-5000), 40), 48_000);
        assert_eq!(PowerLimit::power_mw(Duty::ZERO, u16::MAX), 0);
        let mut limit = PowerLimit::new();
        let full = Duty::new_saturating(10_000);
        // Drawing far too much for 1 s: the ceiling falls to zero and stays there, never below.
        for t in 0..1000 {
            limit.update(Instant::from_millis(t), Some(10), full, u16::MAX);
        }
        assert_eq!(limit.update(Instant::from_millis(1000), Some(10), full, u16::MAX), 0);
        // Drawing nothing at zero duty: it stands the headroom above that duty, not at full scale, so it has
        // nothing to unwind when the motor starts. Drawing nothing at full duty: full scale, never above.
        for t in 1001..3000 {
            limit.update(Instant::from_millis(t), Some(10), Duty::ZERO, 0);
        }
        assert_eq!(
            limit.update(Instant::from_millis(3000), Some(10), Duty::ZERO, 0),
            u16::try_from(POWER_LIMIT_HEADROOM).unwrap()
        );
        for t in 3001..3200 {
            limit.update(Instant::from_millis(t), Some(10), full, 0);
        }
        assert_eq!(limit.update(Instant::from_millis(3200), Some(10), full, 0), 10_000);
        // INFO 100 is full scale at once.
        let mut limit = PowerLimit::new();
        limit.update(Instant::from_millis(0), Some(1), full, u16::MAX);
        assert!(limit.update(Instant::from_millis(100), Some(1), full, u16::MAX) < 10_000);
        assert_eq!(
            limit.update(Instant::from_millis(101), Some(100), full, u16::MAX),
            10_000
        );
        // A late or backwards clock takes a bounded step.
        let mut limit = PowerLimit::new();
        limit.update(Instant::from_ticks(u64::MAX), Some(50), full, 10);
        assert_eq!(limit.update(Instant::from_millis(0), Some(50), full, 10), 10_000);
    }

    #[test]
    fn power_cap_holds_the_duty() {
        for cap in [1u8, 10, 50, 100] {
            let mut rig = Rig::new(SpeedConfig::BRUSHLESS_DEFAULT, 9_500);
            let mut max = 0;
            for step in [102, -102, 51] {
                for _ in 0..1_500 {
                    max = max.max(rig.step(step, Some(cap)).magnitude());
                }
            }
            assert!(max <= u16::from(cap) * 100, "cap {cap}: {max}");
            if cap < 100 {
                assert_eq!(max, u16::from(cap) * 100, "cap {cap} is reached");
            }
        }

        // INFO 0 and above 100 mean no cap: same as None.
        for info in [0u8, 101, 255] {
            let order = Order {
                speed: Speed::MAX_FORWARD,
                info,
            };
            let mut capped = Rig::new(SpeedConfig::BRUSHLESS_DEFAULT, 9_500);
            let mut free = Rig::new(SpeedConfig::BRUSHLESS_DEFAULT, 9_500);
            let mut raw = Rig::new(SpeedConfig::BRUSHLESS_DEFAULT, 9_500);
            for _ in 0..1_500 {
                let a = capped.step(102, order.power_cap_percent());
                let b = free.step(102, None);
                let c = raw.step(102, Some(info));
                assert_eq!(a, b);
                assert_eq!(c, b);
            }
            assert!(within_2_percent(free.motor.rpm, 4500));
        }
    }

    #[test]
    fn the_power_stage_limit_holds_whatever_the_order() {
        for max_duty in [MAX_DUTY, 9_500, 1_000] {
            for base in [SpeedConfig::BRUSHLESS_DEFAULT, SpeedConfig::BRUSHED_DEFAULT] {
                let config = SpeedConfig { max_duty, ..base };
                // A loaded motor that would need more than full duty for full speed.
                let mut rig = Rig::new(config, 12_000);
                let mut largest = 0;
                for step in [102, -102, 51] {
                    for _ in 0..1_500 {
                        largest = largest.max(rig.step(step, None).magnitude());
                    }
                }
                assert_eq!(largest, max_duty, "{:?} {max_duty}", config.motor);
            }
        }
    }

    #[test]
    fn integrator_does_not_wind_up_while_capped() {
        let mut rig = Rig::new(SpeedConfig::BRUSHLESS_DEFAULT, 8_000);
        rig.run(102, Some(20), 1_000);
        let held = rig.controller.integral_q16;
        for _ in 0..1_000 {
            assert_eq!(rig.step(102, Some(20)).value(), 2_000);
            assert_eq!(rig.controller.integral_q16, held);
        }
        // Released, it converges without a long overshoot from a wound-up integrator.
        let mut peak = 0.0f32;
        for _ in 0..2_000 {
            rig.step(102, None);
            peak = peak.max(rig.motor.rpm);
        }
        assert!(peak < 4500.0 * 1.05, "overshoot to {peak}");
        assert!(within_2_percent(rig.motor.rpm, 4500));
    }

    #[test]
    fn lifting_the_cap_raises_the_duty_at_the_ramp_rate() {
        let mut rig = Rig::new(SpeedConfig::BRUSHLESS_DEFAULT, 8_000);
        rig.run(102, Some(20), 2_000);
        let mut previous = rig.step(102, Some(20)).value();
        assert_eq!(previous, 2_000);
        let mut largest_rise = 0;
        for _ in 0..2_000 {
            let duty = rig.step(102, None).value();
            largest_rise = largest_rise.max(duty - previous);
            previous = duty;
        }
        // Without the held ramp the duty steps from the cap to full scale (8000 units) at once; with it, only the
        // proportional term's margin over the cap is released (under 2.5 %), then the ramp takes over.
        assert!(largest_rise <= 250, "duty rose by {largest_rise} in one step");
        assert!(within_2_percent(rig.motor.rpm, 4500));
    }

    #[test]
    fn slowing_down_never_drives_in_reverse() {
        let mut rig = Rig::new(SpeedConfig::BRUSHLESS_DEFAULT, 8_000);
        rig.run(102, None, 2_000);
        for _ in 0..2_000 {
            let duty = rig.step(0, None);
            assert!(duty.value() >= 0, "reverse torque while stopping: {duty:?}");
        }
        assert!(rig.motor.rpm >= 0.0, "overshot into reverse: {}", rig.motor.rpm);
    }

    #[test]
    fn zero_order_gives_exactly_zero_duty() {
        let mut rig = Rig::new(SpeedConfig::BRUSHLESS_DEFAULT, 9_500);
        rig.run(51, None, 1_000);
        let mut reached = false;
        for _ in 0..1_000 {
            let duty = rig.step(0, None);
            if rig.controller.ramped_target() == 0 && rig.controller.ramp_micro == 0 {
                reached = true;
            }
            if reached {
                // The motor still turns (measured != 0) but is not driven.
                assert_eq!(duty, Duty::ZERO);
                assert_eq!(rig.controller.integral_q16, 0);
            }
        }
        assert!(reached);
        // A spinning shaft with a zero target is not driven either.
        let duty = rig
            .controller
            .update(Instant::from_millis(rig.ms), Speed::ZERO, None, 3_000);
        assert_eq!(duty, Duty::ZERO);
    }

    #[test]
    fn first_update_and_late_updates_take_bounded_steps() {
        let mut controller = SpeedController::new(SpeedConfig::BRUSHLESS_DEFAULT);
        // First call: dt = 0, however late it comes.
        let duty = controller.update(Instant::from_secs(1_000), Speed::MAX_FORWARD, None, 0);
        assert_eq!(controller.ramped_target(), 0);
        assert_eq!(duty, Duty::ZERO);
        // A call 5 s late moves the ramp by 100 ms worth only: 900 rpm.
        controller.update(Instant::from_secs(1_005), Speed::MAX_FORWARD, None, 0);
        assert_eq!(controller.ramped_target(), 900);
    }

    #[test]
    fn reset_forgets_ramp_and_integrator() {
        let mut rig = Rig::new(SpeedConfig::BRUSHLESS_DEFAULT, 9_500);
        rig.run(102, None, 1_500);
        rig.run(102, Some(30), 500);
        rig.controller.reset();
        assert_eq!(rig.controller.ramped_target(), 0);
        assert_eq!(rig.controller, SpeedController::new(SpeedConfig::BRUSHLESS_DEFAULT));

        // After a reset the controller behaves exactly like a new one.
        let mut fresh = SpeedController::new(SpeedConfig::BRUSHLESS_DEFAULT);
        for ms in 0..300u64 {
            let now = Instant::from_millis(10_000 + ms);
            let measured = 500 - ms as i32;
            assert_eq!(
                rig.controller.update(now, Speed::MAX_FORWARD, None, measured),
                fresh.update(now, Speed::MAX_FORWARD, None, measured)
            );
        }
    }

    #[test]
    fn brushed_is_open_loop_proportional_and_capped() {
        // At full scale (no stage limit), so steps map to round percentages.
        let mut controller = SpeedController::new(SpeedConfig {
            max_duty: Duty::FULL as u16,
            ..SpeedConfig::BRUSHED_DEFAULT
        });
        let mut ms = 0u64;
        let mut run = |controller: &mut SpeedController, step: i32, cap: Option<u8>, steps: u32| {
            let mut duty = Duty::ZERO;
            for _ in 0..steps {
                // The measured rpm is ignored: pass nonsense.
                duty = controller.update(Instant::from_millis(ms), Speed::new_saturating(step), cap, i32::MIN);
                ms += 1;
            }
            duty
        };

        // 20 000 duty/s: 20 per millisecond, 50 % after 250 ms (the first update takes dt = 0).
        assert_eq!(run(&mut controller, 51, None, 1).value(), 0);
        for n in 1..=300 {
            let duty = run(&mut controller, 51, None, 1).value();
            assert_eq!(duty, (20 * n).min(5_000));
        }
        assert_eq!(controller.ramped_target(), 5_000);
        assert_eq!(run(&mut controller, 102, None, 300).value(), 10_000);
        assert_eq!(run(&mut controller, 1, None, 600).value(), 98);
        assert_eq!(run(&mut controller, -51, None, 600).value(), -5_000);
        assert_eq!(run(&mut controller, -102, None, 600).value(), -10_000);

        // A lower cap applies at once, a higher one through the ramp.
        assert_eq!(run(&mut controller, -102, Some(30), 1).value(), -3_000);
        assert_eq!(run(&mut controller, -102, Some(40), 1).value(), -3_020);
        assert_eq!(run(&mut controller, -102, Some(40), 600).value(), -4_000);
        assert_eq!(run(&mut controller, 51, Some(1), 600).value(), 100);
        assert_eq!(run(&mut controller, 51, Some(0), 600).value(), 5_000);
        assert_eq!(run(&mut controller, 51, Some(101), 600).value(), 5_000);
        assert_eq!(run(&mut controller, 0, None, 300).value(), 0);

        for (step, duty) in [(0, 0), (1, 98), (51, 5_000), (102, 10_000), (-1, -98), (-102, -10_000)] {
            assert_eq!(brushed_duty(Speed::new_saturating(step), Duty::FULL as u16), duty);
        }
        // Scaled to the power stage's limit: step 102 is the largest duty it takes.
        for (step, duty) in [(1, 93), (51, 4_750), (102, 9_500), (-102, -9_500)] {
            assert_eq!(brushed_duty(Speed::new_saturating(step), 9_500), duty);
        }
    }

    #[test]
    fn extreme_inputs_do_not_panic() {
        let extreme = SpeedConfig {
            motor: MotorKind::Brushless,
            ramp_per_s: u32::MAX,
            full_scale_duty: u16::MAX,
            kp_q16: u32::MAX,
            ki_q16_per_s: u32::MAX,
            max_duty: u16::MAX,
            current_limit_deciamps: u16::MAX,
        };
        let brushed = SpeedConfig {
            motor: MotorKind::Brushed,
            ..extreme
        };
        let times = [
            Instant::from_ticks(0),
            Instant::MAX,
            Instant::from_ticks(0),
            Instant::from_millis(5),
            Instant::from_millis(4),
            Instant::from_ticks(u64::MAX - 1),
            Instant::MAX,
        ];
        for config in [
            SpeedConfig::BRUSHLESS_DEFAULT,
            SpeedConfig::BRUSHED_DEFAULT,
            extreme,
            brushed,
        ] {
            let mut controller = SpeedController::new(config);
            for now in times {
                for speed in [Speed::MAX_FORWARD, Speed::MAX_REVERSE, Speed::ZERO] {
                    for measured in [i32::MAX, i32::MIN, 0, -1] {
                        for cap in [None, Some(0), Some(1), Some(100), Some(255)] {
                            let duty = controller.update(now, speed, cap, measured);
                            assert!(duty.magnitude() <= 10_000);
                            if let Some(percent @ 1..=100) = cap {
                                assert!(duty.magnitude() <= u16::from(percent) * 100);
                            }
                            assert!(controller.ramped_target().abs() <= 10_000);
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn the_current_limit_holds_a_locked_rotor() {
        // A locked rotor on 24 V through 1.2 ohm: 20 A at full duty, the current proportional to the duty.
        let locked = |duty: u16| u16::try_from(u32::from(duty) * 200 / 10_000).unwrap_or(u16::MAX);
        let mut limit = CurrentLimit::new();
        let mut applied = 0u16;
        for _ in 0..1000 {
            // The speed loop asks for full duty; the bridge applies the ceiling.
            let ceiling = limit.update(70, Duty::new_saturating(i32::from(applied)), locked(applied), false);
            applied = ceiling.min(9_500);
            assert!(locked(applied) <= 72, "{applied}");
        }
        // Settled at the limit: 35 % draws 7 A.
        assert!((3_400..=3_600).contains(&applied), "{applied}");
    }

    #[test]
    fn the_current_limit_rises_only_from_the_duty_applied() {
        let mut limit = CurrentLimit::new();
        // Below the limit it tracks the duty: one rise above it.
        assert_eq!(limit.update(70, Duty::new_saturating(2_000), 10, false), 2_100);
        assert_eq!(limit.update(70, Duty::new_saturating(2_050), 10, false), 2_150);
        // Over it: scaled by limit / current.
        assert_eq!(limit.update(70, Duty::new_saturating(2_000), 140, false), 1_000);
        // A break trip halves that again, whatever the reading.
        assert_eq!(limit.update(70, Duty::new_saturating(1_000), 80, true), 437);
        assert_eq!(limit.update(70, Duty::new_saturating(400), 0, true), 200);
        // Then back up a step at a time.
        assert_eq!(limit.update(70, Duty::new_saturating(200), 30, false), 300);
        // No limit: full scale at once.
        assert_eq!(limit.update(0, Duty::new_saturating(200), 300, true), Duty::FULL as u16);
    }

    #[test]
    fn the_current_limit_takes_any_input() {
        let mut limit = CurrentLimit::new();
        for (cap, duty, current, tripped) in [
            (u16::MAX, i32::MIN, u16::MAX, true),
            (1, i32::MAX, u16::MAX, false),
            (u16::MAX, 0, 0, false),
            (1, -10_000, 1, true),
        ] {
            assert!(limit.update(cap, Duty::new_saturating(duty), current, tripped) <= Duty::FULL as u16);
        }
    }
}
