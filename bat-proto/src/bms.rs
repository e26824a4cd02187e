//! BMS status frame, ID 0x628: the alarm bits of the battery management board.

use core::ops::BitOr;

use crate::{BMS_ID, DecodeError, FRAME_LEN, frame_bytes};

/// The 7 defined alarm bits of byte 0.
const VALID_MASK: u8 = 0x7F;

/// Alarms of the BMS board, byte 0 bits 0-6 of the frame on [`BMS_ID`] (0x628), as listed in docs/decisions.md
/// D22: low voltage, high voltage, overcurrent discharge, overcurrent charge, low state of charge,
/// low temperature, high temperature.
///
/// A set of flags: each constant other than [`BmsAlarms::NONE`] is one bit, and values combine with `|` or
/// [`BmsAlarms::union`]. Bit 7 and bytes 1-7 are not defined and are ignored on receipt, so a value holds only
/// bits 0-6.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BmsAlarms(u8);

impl BmsAlarms {
    /// No alarm.
    pub const NONE: BmsAlarms = BmsAlarms(0);
    /// Bit 0: low voltage.
    pub const LOW_VOLTAGE: BmsAlarms = BmsAlarms(1 << 0);
    /// Bit 1: high voltage.
    pub const HIGH_VOLTAGE: BmsAlarms = BmsAlarms(1 << 1);
    /// Bit 2: overcurrent while discharging.
    pub const OVERCURRENT_DISCHARGE: BmsAlarms = BmsAlarms(1 << 2);
    /// Bit 3: overcurrent while charging.
    pub const OVERCURRENT_CHARGE: BmsAlarms = BmsAlarms(1 << 3);
    /// Bit 4: low state of charge.
    pub const LOW_CHARGE: BmsAlarms = BmsAlarms(1 << 4);
    /// Bit 5: low temperature.
    pub const LOW_TEMPERATURE: BmsAlarms = BmsAlarms(1 << 5);
    /// Bit 6: high temperature.
    pub const HIGH_TEMPERATURE: BmsAlarms = BmsAlarms(1 << 6);

    /// The 7 single alarms, in bit order 0..=6.
    pub const ALL: [BmsAlarms; 7] = [
        Self::LOW_VOLTAGE,
        Self::HIGH_VOLTAGE,
        Self::OVERCURRENT_DISCHARGE,
        Self::OVERCURRENT_CHARGE,
        Self::LOW_CHARGE,
        Self::LOW_TEMPERATURE,
        Self::HIGH_TEMPERATURE,
    ];

    /// From the raw byte 0; bit 7 is dropped.
    pub const fn from_bits_truncate(bits: u8) -> Self {
        Self(bits & VALID_MASK)
    }

    /// The raw alarm bits (bit 7 always clear).
    pub const fn bits(self) -> u8 {
        self.0
    }

    /// Whether every alarm of `other` is set in `self`.
    pub const fn contains(self, other: BmsAlarms) -> bool {
        self.0 & other.0 == other.0
    }

    /// Whether no alarm is set.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// The alarms set in either value.
    #[must_use]
    pub const fn union(self, other: BmsAlarms) -> Self {
        Self(self.0 | other.0)
    }

    /// The single alarms that are set, in bit order.
    pub fn iter(self) -> impl Iterator<Item = BmsAlarms> {
        Self::ALL.into_iter().filter(move |alarm| self.contains(*alarm))
    }

    /// Words for a single alarm (e.g. `"low voltage"`), as in docs/decisions.md D22. For a value that is not a
    /// single alarm: `"no alarm"` when empty, `"several alarms"` when more than one is set (use
    /// [`BmsAlarms::iter`] to name each).
    pub const fn name(self) -> &'static str {
        match self {
            Self::NONE => "no alarm",
            Self::LOW_VOLTAGE => "low voltage",
            Self::HIGH_VOLTAGE => "high voltage",
            Self::OVERCURRENT_DISCHARGE => "overcurrent discharge",
            Self::OVERCURRENT_CHARGE => "overcurrent charge",
            Self::LOW_CHARGE => "low state of charge",
            Self::LOW_TEMPERATURE => "low temperature",
            Self::HIGH_TEMPERATURE => "high temperature",
            _ => "several alarms",
        }
    }

    /// Encodes the 8 data bytes of a 0x628 frame: the alarm bits, then seven zero bytes.
    pub const fn encode(self) -> [u8; FRAME_LEN] {
        [self.0, 0, 0, 0, 0, 0, 0, 0]
    }

    /// Decodes the data bytes of a 0x628 frame. Errors: [`DecodeError::Length`] unless exactly 8 bytes.
    /// Bit 7 of byte 0 and bytes 1-7 are ignored.
    pub fn decode(data: &[u8]) -> Result<Self, DecodeError> {
        let [alarms, ..] = frame_bytes(BMS_ID, data)?;
        Ok(Self::from_bits_truncate(alarms))
    }
}

impl BitOr for BmsAlarms {
    type Output = BmsAlarms;

    fn bitor(self, rhs: BmsAlarms) -> BmsAlarms {
        self.union(rhs)
    }
}
