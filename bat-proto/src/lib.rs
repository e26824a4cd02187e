//! CAN frames of the BAT battery board (iCub / R1 / ergoCub BAT protocol).
//!
//! The BAT board sends three classic CAN frames, all with standard 11-bit IDs and DLC 8. The IDs follow iCub's
//! scheme `class 6 << 8 | source 2 << 4 | type` (docs/decisions.md D21):
//!
//! | ID | type | content |
//! |---|---|---|
//! | [`INFO_ID`] `0x620` | [`BatteryInfo`] | pack voltage, charge, and (newer firmware) current and temperature |
//! | [`BMS_ID`] `0x628` | [`BmsAlarms`] | alarm bits of the battery management (BMS) board |
//! | [`STATUS_ID`] `0x629` | [`DcdcStatus`] | the 12 DCDC / hot swap manager status bits |
//!
//! The same types serve both sides: the vehicle's master node decodes ([`Frame::decode`]) and a simulated
//! battery board encodes ([`Frame::encode`]). Decoding never panics; malformed input gives a [`DecodeError`].
//!
//! ```
//! use bat_proto::{DcdcStatus, DecodeError, Frame, StatusBit, STATUS_ID};
//!
//! // The seed's example: status word 172 = 0b1010_1100.
//! let frame = Frame::decode(STATUS_ID, &[0xAC, 0x00, 0, 0, 0, 0, 0, 0])?;
//! let Frame::Status(status) = frame else { unreachable!() };
//! let set: Vec<&str> = status.set_bits().map(StatusBit::name).collect();
//! assert_eq!(set, ["HSM_PG", "HSM", "V12motor", "V12board"]);
//!
//! // On a change, report only the bits that switched.
//! let next = status.with(StatusBit::HsmFault, true);
//! let changes: Vec<String> = next.describe_changes(status).map(|r| r.to_string()).collect();
//! assert_eq!(changes, ["HSM_F=1 (hot swap manager overcurrent / overvoltage fault)"]);
//! assert_eq!(Frame::Status(next).encode(), (STATUS_ID, [0xAE, 0x00, 0, 0, 0, 0, 0, 0]));
//! # Ok::<(), DecodeError>(())
//! ```
//!
//! The seed document is the BAT board protocol page; where it is ambiguous or wrong this crate follows the
//! project's readings in docs/decisions.md (D21-D29), and the item docs say where.
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

mod bms;
mod error;
mod frame;
mod info;
mod status;

#[cfg(test)]
mod tests;

pub use bms::BmsAlarms;
pub use error::DecodeError;
pub use frame::Frame;
pub use info::BatteryInfo;
pub use status::{BitReport, DcdcStatus, StatusBit};

/// ID of the battery pack info frame (voltage, charge, current, temperature).
pub const INFO_ID: u16 = 0x620;
/// ID of the BMS status frame (alarm bits).
pub const BMS_ID: u16 = 0x628;
/// ID of the BAT DCDC status frame (status words A and B).
pub const STATUS_ID: u16 = 0x629;
/// Data length of every BAT frame: the board always sends DLC 8 (seed tables, docs/decisions.md D21).
pub const FRAME_LEN: usize = 8;

/// Checks that `data` is exactly [`FRAME_LEN`] bytes and returns them as an array, so that the decoders can
/// destructure the bytes instead of indexing.
pub(crate) fn frame_bytes(id: u16, data: &[u8]) -> Result<[u8; FRAME_LEN], DecodeError> {
    <[u8; FRAME_LEN]>::try_from(data).map_err(|_| DecodeError::Length { id, actual: data.len() })
}
