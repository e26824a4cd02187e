//! Decoding errors.

use core::fmt;

/// Why a received CAN frame could not be decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DecodeError {
    /// The ID is none of the BAT frames ([`INFO_ID`](crate::INFO_ID), [`BMS_ID`](crate::BMS_ID),
    /// [`STATUS_ID`](crate::STATUS_ID)).
    UnknownId(u16),
    /// The data length is not [`FRAME_LEN`](crate::FRAME_LEN): the BAT always sends DLC 8, so anything else is
    /// not a BAT frame (or a corrupted one).
    Length {
        /// ID of the frame.
        id: u16,
        /// Number of data bytes received.
        actual: usize,
    },
}

impl fmt::Display for DecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::UnknownId(id) => write!(f, "unknown BAT CAN ID {id:#05x}"),
            Self::Length { id, actual } => write!(
                f,
                "BAT frame {id:#05x} has {actual} data bytes, expected {}",
                crate::FRAME_LEN
            ),
        }
    }
}

impl core::error::Error for DecodeError {}
