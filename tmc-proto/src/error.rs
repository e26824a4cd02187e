//! Decode errors.

use core::fmt;

/// Why a received message was rejected (IDS 6.6.1: such a message is discarded whole).
///
/// Decoders check, in this order: length, message type, checksum, then field ranges.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DecodeError {
    /// The message does not have the length of its layout.
    Length {
        /// Length of the layout, in bytes.
        expected: u8,
        /// Length received, in bytes.
        actual: usize,
    },
    /// The MT byte (first byte) is not the one of the expected message.
    MessageType {
        /// MT byte the decoder expects.
        expected: u8,
        /// MT byte received.
        actual: u8,
    },
    /// The CSUM byte does not match the 8-bit sum of the bytes before it (IDS 6.6.1).
    Checksum {
        /// Sum computed over the received bytes.
        expected: u8,
        /// CSUM byte received.
        actual: u8,
    },
    /// An order's SPEED byte outside 0x19..=0xE6 (IDS 8.3: SPEED range). A status with such a byte is not an
    /// error: its decoders report a [`FieldWarning`](crate::FieldWarning) and keep the frame.
    SpeedOutOfRange(u8),
}

impl fmt::Display for DecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            DecodeError::Length { expected, actual } => {
                write!(f, "wrong length: expected {expected} bytes, got {actual}")
            }
            DecodeError::MessageType { expected, actual } => {
                write!(f, "wrong message type: expected {expected:#04x}, got {actual:#04x}")
            }
            DecodeError::Checksum { expected, actual } => {
                write!(f, "bad checksum: computed {expected:#04x}, received {actual:#04x}")
            }
            DecodeError::SpeedOutOfRange(byte) => write!(f, "speed byte {byte:#04x} out of range 0x19..=0xe6"),
        }
    }
}

impl core::error::Error for DecodeError {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn display_is_short_english() {
        let e = DecodeError::Checksum {
            expected: 0x3B,
            actual: 0x3C,
        };
        assert_eq!(e.to_string(), "bad checksum: computed 0x3b, received 0x3c");
        assert_eq!(
            DecodeError::Length { expected: 4, actual: 5 }.to_string(),
            "wrong length: expected 4 bytes, got 5"
        );
        assert_eq!(
            DecodeError::MessageType {
                expected: 0x52,
                actual: 0x54
            }
            .to_string(),
            "wrong message type: expected 0x52, got 0x54"
        );
        assert_eq!(
            DecodeError::SpeedOutOfRange(0x18).to_string(),
            "speed byte 0x18 out of range 0x19..=0xe6"
        );
    }
}
