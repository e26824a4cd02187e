//! Messages between the SeaBotix LBV motherboard (I2C master) and the thruster motor controllers (I2C slaves).
//!
//! Both controller families of the LBV Motherboard / Thruster Motor Controller IDS are covered:
//! - SeaBotix: order MT 0x52 (IDS 8.3.2), 7-byte status MT 0x53 (IDS 8.4.2);
//! - Aveox / Legacy SeaBotix: order MT 0x54 (IDS 8.3.1), 4-byte status MT 0x55 (IDS 8.4.1).
//!
//! Every message ends with an 8-bit checksum of the bytes before it ([`checksum`]). Decoders never panic: they
//! check, in this order, the length, the message type, the checksum and then the field ranges, and report the
//! first problem as a [`DecodeError`]. An order with an out-of-range SPEED is rejected; a status keeps its faults
//! and reports an out-of-range field as a [`FieldWarning`] beside it ([`Decoded`]). Reserved bits are sent as zero
//! and ignored on receipt (IDS 8.1).
//!
//! [`ext`] is this project's field-update extension, which an IDS-only controller discards (its first four bytes
//! never carry a valid CSUM).
//!
//! ```
//! use tmc_proto::{DecodeError, Family, Order, Speed};
//!
//! // SeaBotix order, speed +5, INFO 100: CSUM = 0x52 + 0x85 + 0x64 = 0x13B -> 0x3B.
//! let order = Order::new(Speed::new(5).ok_or("range")?);
//! assert_eq!(order.encode(Family::SeaBotix), [0x52, 0x85, 0x64, 0x3B]);
//! assert_eq!(Order::decode(Family::SeaBotix, &[0x52, 0x85, 0x64, 0x3B]), Ok(order));
//! assert_eq!(
//!     Order::decode(Family::SeaBotix, &[0x52, 0x85, 0x64, 0x3C]),
//!     Err(DecodeError::Checksum { expected: 0x3B, actual: 0x3C })
//! );
//! # Ok::<(), &'static str>(())
//! ```
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

mod error;
pub mod ext;
mod family;
mod faults;
mod order;
mod speed;
mod status;

pub use error::DecodeError;
pub use family::Family;
pub use faults::Faults;
pub use order::Order;
pub use speed::Speed;
pub use status::{
    Decoded, FieldWarning, LegacyRevision, LegacyStatus, MaxPower, MotorKind, SeaBotixStatus, Status, StatusForm,
    StatusFrame,
};

/// Length in bytes of an order, either family: MT, SPEED, INFO, CSUM (IDS 8.3).
pub const ORDER_LEN: usize = 4;

/// Length in bytes of the longest status message, the SeaBotix one (IDS 8.4.2).
pub const MAX_STATUS_LEN: usize = 7;

/// 8-bit sum without carry of all bytes (IDS 8.3: CSUM).
///
/// The CSUM byte of a message is the checksum of all bytes before it, the MT byte included.
pub const fn checksum(bytes: &[u8]) -> u8 {
    let mut sum = 0u8;
    let mut rest = bytes;
    while let [first, tail @ ..] = rest {
        sum = sum.wrapping_add(*first);
        rest = tail;
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checksum_discards_carry() {
        assert_eq!(checksum(&[]), 0);
        assert_eq!(checksum(&[0x52, 0x85, 0x64]), 0x3B);
        assert_eq!(checksum(&[0xFF, 0x01]), 0x00);
        assert_eq!(checksum(&[0xFF; 7]), 0xF9);
    }

    #[test]
    fn checksum_is_const() {
        const SUM: u8 = checksum(&[0x54, 0x80, 0x64]);
        assert_eq!(SUM, 0x38);
    }
}
