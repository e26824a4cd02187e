//! What the controller asks of the power stage: a signed duty cycle.

/// Direction of rotation. Forward turns the shaft counter-clockwise seen from the shaft end (IDS 6.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Direction {
    /// Counter-clockwise seen from the shaft end.
    Forward,
    /// Clockwise seen from the shaft end.
    Reverse,
}

/// Signed PWM duty cycle in 1/10 000 of full scale (0.01 %): -10 000..=10 000. Positive drives forward.
///
/// Constructors keep the value in range, so every `Duty` is a valid PWM setting.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Duty(i16);

impl Duty {
    /// Full scale, 100 %.
    pub const FULL: i16 = 10_000;
    /// No drive.
    pub const ZERO: Duty = Duty(0);

    /// A duty of `value` / 10 000, clamped to -100 %..=100 %.
    pub const fn new_saturating(value: i32) -> Duty {
        if value > Self::FULL as i32 {
            Duty(Self::FULL)
        } else if value < -(Self::FULL as i32) {
            Duty(-Self::FULL)
        } else {
            Duty(value as i16)
        }
    }

    /// The signed value in 1/10 000.
    pub const fn value(self) -> i16 {
        self.0
    }

    /// The magnitude in 1/10 000, 0..=10 000.
    pub const fn magnitude(self) -> u16 {
        self.0.unsigned_abs()
    }

    /// The direction driven, `None` at zero.
    pub const fn direction(self) -> Option<Direction> {
        if self.0 > 0 {
            Some(Direction::Forward)
        } else if self.0 < 0 {
            Some(Direction::Reverse)
        } else {
            None
        }
    }

    /// The compare value for a PWM timer whose full period is `period` counts.
    #[cfg(test)]
    pub(crate) const fn compare(self, period: u16) -> u16 {
        // magnitude <= 10 000, so the product fits in u32 and the quotient in u16.
        (self.magnitude() as u32 * period as u32 / Self::FULL as u32) as u16
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn duty_saturates_and_reports_direction() {
        assert_eq!(Duty::new_saturating(20_000).value(), 10_000);
        assert_eq!(Duty::new_saturating(i32::MIN).value(), -10_000);
        assert_eq!(Duty::new_saturating(-810).magnitude(), 810);
        assert_eq!(Duty::new_saturating(1).direction(), Some(Direction::Forward));
        assert_eq!(Duty::new_saturating(-1).direction(), Some(Direction::Reverse));
        assert_eq!(Duty::ZERO.direction(), None);
    }

    #[test]
    fn compare_value_scales_to_the_timer_period() {
        assert_eq!(Duty::new_saturating(10_000).compare(4250), 4250);
        assert_eq!(Duty::new_saturating(-5_000).compare(4250), 2125);
        assert_eq!(Duty::new_saturating(800).compare(4250), 340);
        assert_eq!(Duty::ZERO.compare(u16::MAX), 0);
        assert_eq!(Duty::new_saturating(10_000).compare(u16::MAX), u16::MAX);
    }
}
