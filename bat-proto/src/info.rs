//! Battery pack info frame, ID 0x620.

use crate::{DecodeError, FRAME_LEN, INFO_ID, frame_bytes};

/// Battery pack info, sent on [`INFO_ID`] (0x620).
///
/// Layout (seed table; docs/decisions.md D23, D27):
///
/// | bytes | field |
/// |---|---|
/// | 0-1 | voltage, u16 little-endian, 0.1 V (`A4 01` = 0x01A4 = 42.0 V) |
/// | 2-3 | pack current, i16 little-endian, 0.1 A (newer firmware only) |
/// | 4 | charge, 0..=100 % |
/// | 5 | unused: sent as 0, ignored on receipt |
/// | 6-7 | temperature, i16 little-endian, 0.1 °C (filled from the BMS board) |
///
/// The BAT document gives bytes 2-3 and 6-7 as "not used", sent as 0; only newer firmware fills them (the pack
/// current, and a temperature from the BMS board). One frame cannot tell that firmware's 0.0 A from "not used",
/// so a 0 there decodes as `None`, and `None` encodes as 0; a receiver that has seen the pack report a non-zero
/// value knows it fills the field and reads a later 0 as zero (lbv-master-fw's battery monitor does).
///
/// Each field is read on its own: a charge byte above 100 gives `charge_percent: None` and leaves the voltage and
/// the rest of the frame as they are.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BatteryInfo {
    /// Pack voltage in 0.1 V.
    pub voltage_decivolts: u16,
    /// State of charge in percent, 0..=100; `None` when byte 4 held more than 100.
    pub charge_percent: Option<u8>,
    /// Pack current in 0.1 A, `None` when not reported (sent as 0). The sign convention is the firmware's;
    /// a negative value is read as charging.
    pub current_deciamps: Option<i16>,
    /// Pack temperature in 0.1 °C, `None` when not reported (sent as 0).
    pub temperature_decicelsius: Option<i16>,
}

impl BatteryInfo {
    /// Encodes the 8 data bytes of a 0x620 frame.
    ///
    /// The charge is written as given (`None` as 0xFF, which reads back as `None`; a value above 100, useful to a
    /// simulator that wants to send a faulty field, reads back as `None` too). `Some(0)` and `None` both write 0 for
    /// the current and the temperature.
    pub fn encode(&self) -> [u8; FRAME_LEN] {
        let [v0, v1] = self.voltage_decivolts.to_le_bytes();
        let [c0, c1] = self.current_deciamps.unwrap_or(0).to_le_bytes();
        let [t0, t1] = self.temperature_decicelsius.unwrap_or(0).to_le_bytes();
        [v0, v1, c0, c1, self.charge_percent.unwrap_or(u8::MAX), 0, t0, t1]
    }

    /// Decodes the data bytes of a 0x620 frame.
    ///
    /// Errors: [`DecodeError::Length`] unless exactly 8 bytes. A charge byte above 100 reads as `None` (see
    /// [`BatteryInfo::charge_out_of_range`]). Byte 5 is ignored.
    pub fn decode(data: &[u8]) -> Result<Self, DecodeError> {
        let [v0, v1, c0, c1, charge, _unused, t0, t1] = frame_bytes(INFO_ID, data)?;
        Ok(Self {
            voltage_decivolts: u16::from_le_bytes([v0, v1]),
            charge_percent: (charge <= 100).then_some(charge),
            current_deciamps: non_zero(i16::from_le_bytes([c0, c1])),
            temperature_decicelsius: non_zero(i16::from_le_bytes([t0, t1])),
        })
    }
}

impl BatteryInfo {
    /// The charge byte of a 0x620 frame's data if it is out of range (above 100 %): a field a receiver counts as
    /// bad while it takes the rest of the frame. None for a good byte or a frame of another length.
    pub fn charge_out_of_range(data: &[u8]) -> Option<u8> {
        data.get(4)
            .copied()
            .filter(|charge| *charge > 100 && data.len() == crate::FRAME_LEN)
    }
}

/// 0 on the wire means "not reported" (older firmware sends zeros).
const fn non_zero(value: i16) -> Option<i16> {
    if value == 0 { None } else { Some(value) }
}
