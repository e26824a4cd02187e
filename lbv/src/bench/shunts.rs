//! The power stage's three low-side shunts as the thruster's ADC sees them: the IHM08M1 in its three-shunt
//! configuration (docs/hardware.md, "Current sensing"), sampled where the binding's TIM1 trigger puts the
//! conversions in each PWM period. Written from the stage's circuit and RM0440's PWM mode, not from what the
//! firmware makes of the readings: a controller that read one shunt, or read at an instant where no low switch of
//! the motor's current conducts, sees what the board would give it.

use g431_hw::clock::TIM1_HZ;
use g431_hw::tim1::IHM08M1;
use thruster_fw::Duty;
use thruster_fw::commutation::{BridgeDrive, PhaseDrive};
use thruster_fw::sensors::CurrentSense;

use super::thruster::round;

/// The three shunt amplifiers as the IHM08M1's stage gives them when TIM1 triggers their conversion, with the
/// phase currents `currents_a` (positive into the motor) flowing under `drive` at `duty`.
///
/// The trigger is the binding's (`g431_hw::tim1::Bridge::current_trigger`): OC4REF rises as the down-count
/// reaches CCR4, and counting down the switching phase's high switch is on while the count is at or below its CCR
/// (PWM mode 1, RM0440 28.3.12). A shunt carries its phase's current only while the phase's low switch conducts:
/// always for the phase held low, during the high switch's off-time for the switching phase (complementary PWM),
/// never for a floating phase. It reads the current flowing down through it to ground, the negative of the current
/// into the motor, as offset + I / (A per count), within the ADC's 12 bits. The plant's currents are averages
/// over the period: no ripple, no switching noise, no discontinuous conduction.
pub fn at_trigger(sense: &CurrentSense, drive: BridgeDrive, duty: Duty, currents_a: [f64; 3]) -> [u16; 3] {
    let arr = u16::try_from(IHM08M1.arr(TIM1_HZ)).unwrap_or(u16::MAX);
    let compare = IHM08M1.compare(duty.magnitude(), arr);
    let high_on = IHM08M1.current_trigger(compare, arr) <= compare;
    let per_amp = 1000.0 / f64::from(sense.milliamps_per_count.max(1));
    let mut readings = [sense.offset_raw; 3];
    for ((reading, phase), current) in readings.iter_mut().zip(drive).zip(currents_a) {
        let low_conducts = match phase {
            PhaseDrive::Low => true,
            PhaseDrive::Pwm => !high_on,
            PhaseDrive::Float => false,
        };
        if low_conducts {
            *reading = round(f64::from(sense.offset_raw) - current * per_amp).clamp(0, 4095) as u16;
        }
    }
    readings
}

#[cfg(test)]
mod tests {
    use super::*;

    const SENSE: CurrentSense = CurrentSense {
        offset_raw: 2122,
        milliamps_per_count: 16,
    };

    #[test]
    fn the_phase_held_low_carries_the_motor_current_at_every_duty() {
        // 4 A into phase A, out of phase B, C floating.
        let drive = [PhaseDrive::Pwm, PhaseDrive::Low, PhaseDrive::Float];
        let currents = [4.0, -4.0, 0.0];
        for duty in [1, 2_000, 4_999, 5_000, 9_500, 10_000] {
            let [a, b, c] = at_trigger(&SENSE, drive, Duty::new_saturating(duty), currents);
            assert_eq!(b, 2122 + 250, "duty {duty}");
            assert_eq!(c, 2122, "duty {duty}");
            // Phase A's shunt: nothing while its high switch conducts (the bottom of the period, from 50 % up),
            // the recirculating current below the offset while its low switch does.
            let high_on = duty >= 5_000;
            assert_eq!(a, if high_on { 2122 } else { 2122 - 250 }, "duty {duty}");
            assert_eq!(SENSE.motor_deciamps([a, b, c]), 40, "duty {duty}");
        }
    }

    #[test]
    fn one_shunt_alone_misses_the_current_in_most_steps() {
        // The old binding read phase A's shunt only: in the four steps where A is not held low it never sees the
        // motor's current flowing.
        let steps = [
            [PhaseDrive::Pwm, PhaseDrive::Low, PhaseDrive::Float],
            [PhaseDrive::Pwm, PhaseDrive::Float, PhaseDrive::Low],
            [PhaseDrive::Float, PhaseDrive::Pwm, PhaseDrive::Low],
            [PhaseDrive::Low, PhaseDrive::Pwm, PhaseDrive::Float],
            [PhaseDrive::Low, PhaseDrive::Float, PhaseDrive::Pwm],
            [PhaseDrive::Float, PhaseDrive::Low, PhaseDrive::Pwm],
        ];
        let mut phase_a_sees = 0;
        for drive in steps {
            let currents = drive.map(|phase| match phase {
                PhaseDrive::Pwm => 3.0,
                PhaseDrive::Low => -3.0,
                PhaseDrive::Float => 0.0,
            });
            let readings = at_trigger(&SENSE, drive, Duty::new_saturating(6_000), currents);
            assert_eq!(SENSE.motor_deciamps(readings), 30, "{drive:?}");
            if SENSE.deciamps(readings[0]) == 30 {
                phase_a_sees += 1;
            }
        }
        assert_eq!(phase_a_sees, 2);
    }

    #[test]
    fn coasting_reads_the_offset_and_extremes_saturate() {
        let coast = [PhaseDrive::Float; 3];
        assert_eq!(at_trigger(&SENSE, coast, Duty::ZERO, [0.0; 3]), [2122; 3]);
        let drive = [PhaseDrive::Low, PhaseDrive::Pwm, PhaseDrive::Float];
        let readings = at_trigger(&SENSE, drive, Duty::new_saturating(-3_000), [-1e6, 1e6, 0.0]);
        assert_eq!(readings, [4095, 0, 2122]);
        let nan = at_trigger(&SENSE, drive, Duty::new_saturating(3_000), [f64::NAN; 3]);
        assert!(nan.iter().all(|&raw| raw <= 4095));
    }
}
