//! Thruster speed, as ordered (IDS 8.3) and as reported (IDS 8.4).

use crate::DecodeError;

/// Speed as a signed step, -102..=102: 102 discrete speeds each way (IDS 6.2).
///
/// Positive is forward (shaft counter-clockwise seen from the shaft end), negative reverse (IDS 6.2).
/// The constructors keep the step in range, so every `Speed` encodes to a valid SPEED byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Speed(i8);

impl Speed {
    /// Largest step magnitude: 102 speeds each way (IDS 6.2).
    pub const MAX_STEP: i8 = 102;
    /// Stopped.
    pub const ZERO: Speed = Speed(0);
    /// Maximum forward speed, byte 0xE6 (IDS 8.3).
    pub const MAX_FORWARD: Speed = Speed(Self::MAX_STEP);
    /// Maximum reverse speed, byte 0x19 (IDS 8.3).
    pub const MAX_REVERSE: Speed = Speed(-Self::MAX_STEP);
    /// Brushless full scale in rpm, either way (IDS 8.3.2). Brushed motors: the step is a PWM value.
    pub const FULL_SCALE_RPM: i32 = 4500;

    /// Speed of a step; `None` outside -102..=102.
    pub const fn new(step: i8) -> Option<Speed> {
        if step >= -Self::MAX_STEP && step <= Self::MAX_STEP {
            Some(Speed(step))
        } else {
            None
        }
    }

    /// Speed of a step, clamped to -102..=102.
    pub const fn new_saturating(step: i32) -> Speed {
        if step > Self::MAX_STEP as i32 {
            Self::MAX_FORWARD
        } else if step < -(Self::MAX_STEP as i32) {
            Self::MAX_REVERSE
        } else {
            Speed(step as i8)
        }
    }

    /// Signed step, -102..=102.
    pub const fn step(self) -> i8 {
        self.0
    }

    /// Whether this is zero speed.
    pub const fn is_zero(self) -> bool {
        self.0 == 0
    }

    /// Decode a SPEED byte (IDS 8.3): 0x7F and 0x80 are zero, 0x81..=0xE6 forward 1..=102,
    /// 0x7E..=0x19 reverse 1..=102; anything else is [`DecodeError::SpeedOutOfRange`].
    pub const fn from_byte(byte: u8) -> Result<Speed, DecodeError> {
        match byte {
            0x7F | 0x80 => Ok(Speed::ZERO),
            // In range, so 1..=102: no overflow.
            0x81..=0xE6 => Ok(Speed((byte - 0x80) as i8)),
            0x19..=0x7E => Ok(Speed(-((0x7F - byte) as i8))),
            _ => Err(DecodeError::SpeedOutOfRange(byte)),
        }
    }

    /// Encode as a SPEED byte (IDS 8.3). Zero is sent as 0x80, forward `s` as 0x80 + s, reverse `s` as 0x7F - s.
    pub const fn to_byte(self) -> u8 {
        // The invariant keeps the step in -102..=102, so the result is in 0x19..=0xE6.
        if self.0 > 0 {
            0x80 + self.0 as u8
        } else if self.0 < 0 {
            0x7F - self.0.unsigned_abs()
        } else {
            0x80
        }
    }

    /// Brushless speed in rpm: step * 4500 / 102, rounded to nearest, half away from zero (IDS 8.3.2).
    /// Exact at full scale: ±102 gives ±4500.
    pub const fn rpm(self) -> i32 {
        // |step * 4500| <= 459_000: fits an i32.
        let scaled = self.0 as i32 * Self::FULL_SCALE_RPM;
        let magnitude = (scaled.abs() + Self::MAX_STEP as i32 / 2) / Self::MAX_STEP as i32;
        if scaled < 0 { -magnitude } else { magnitude }
    }

    /// Nearest step to a measured brushless speed in rpm (half away from zero), saturating beyond ±4500 rpm.
    ///
    /// Inverse of [`Speed::rpm`]: `Speed::from_rpm(s.rpm()) == s` for every speed.
    pub const fn from_rpm(rpm: i32) -> Speed {
        // In i64: |rpm * 102| < 2^39, no overflow for any i32.
        let scaled = rpm as i64 * Self::MAX_STEP as i64;
        let full = Self::FULL_SCALE_RPM as i64;
        let magnitude = (scaled.abs() + full / 2) / full;
        if magnitude > Self::MAX_STEP as i64 {
            if scaled < 0 {
                Self::MAX_REVERSE
            } else {
                Self::MAX_FORWARD
            }
        } else if scaled < 0 {
            Speed(-(magnitude as i8))
        } else {
            Speed(magnitude as i8)
        }
    }
}

impl TryFrom<u8> for Speed {
    type Error = DecodeError;

    /// Same as [`Speed::from_byte`].
    fn try_from(byte: u8) -> Result<Speed, DecodeError> {
        Speed::from_byte(byte)
    }
}

impl From<Speed> for u8 {
    /// Same as [`Speed::to_byte`].
    fn from(speed: Speed) -> u8 {
        speed.to_byte()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constructors_enforce_range() {
        assert_eq!(Speed::new(102), Some(Speed::MAX_FORWARD));
        assert_eq!(Speed::new(-102), Some(Speed::MAX_REVERSE));
        assert_eq!(Speed::new(103), None);
        assert_eq!(Speed::new(-103), None);
        assert_eq!(Speed::new(i8::MIN), None);
        assert_eq!(Speed::new(i8::MAX), None);
        assert_eq!(Speed::new_saturating(i32::MAX), Speed::MAX_FORWARD);
        assert_eq!(Speed::new_saturating(i32::MIN), Speed::MAX_REVERSE);
        assert_eq!(Speed::new_saturating(103), Speed::MAX_FORWARD);
        assert_eq!(Speed::new_saturating(-7).step(), -7);
        assert!(Speed::ZERO.is_zero());
        assert!(!Speed::MAX_FORWARD.is_zero());
        assert_eq!(Speed::default(), Speed::ZERO);
    }

    #[test]
    fn rpm_values() {
        assert_eq!(Speed::ZERO.rpm(), 0);
        // 4500 / 102 = 44.12
        assert_eq!(Speed::new_saturating(1).rpm(), 44);
        assert_eq!(Speed::new_saturating(-1).rpm(), -44);
        // 51 * 4500 / 102 = 2250 exactly
        assert_eq!(Speed::new_saturating(51).rpm(), 2250);
        // 2 * 4500 / 102 = 88.24 -> 88
        assert_eq!(Speed::new_saturating(2).rpm(), 88);
        assert_eq!(Speed::MAX_FORWARD.rpm(), 4500);
        assert_eq!(Speed::MAX_REVERSE.rpm(), -4500);
    }

    #[test]
    fn from_rpm_saturates_and_never_overflows() {
        assert_eq!(Speed::from_rpm(i32::MAX), Speed::MAX_FORWARD);
        assert_eq!(Speed::from_rpm(i32::MIN), Speed::MAX_REVERSE);
        assert_eq!(Speed::from_rpm(4522), Speed::MAX_FORWARD);
        assert_eq!(Speed::from_rpm(-9000), Speed::MAX_REVERSE);
        assert_eq!(Speed::from_rpm(0), Speed::ZERO);
        // 22 rpm = 0.4987 step -> 0; 23 rpm = 0.5213 step -> 1
        assert_eq!(Speed::from_rpm(22), Speed::ZERO);
        assert_eq!(Speed::from_rpm(23).step(), 1);
        assert_eq!(Speed::from_rpm(-23).step(), -1);
    }
}
