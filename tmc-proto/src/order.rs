//! The order, master -> thruster (IDS 8.3).

use crate::{DecodeError, Family, ORDER_LEN, Speed, checksum};

/// Order, master -> thruster, 4 bytes: MT SPEED INFO CSUM (IDS 8.3). MT is 0x52 (SeaBotix) or 0x54 (Legacy).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Order {
    /// Ordered speed (SPEED).
    pub speed: Speed,
    /// INFO byte, any value; see [`Order::power_cap_percent`].
    pub info: u8,
}

impl Order {
    /// INFO value masters send: the IDS says "currently set to 100" (IDS 8.3).
    pub const INFO_NO_CAP: u8 = 100;
    /// Stop: zero speed, INFO 100.
    pub const STOP: Order = Order::new(Speed::ZERO);

    /// Order for a speed, with INFO 100.
    pub const fn new(speed: Speed) -> Order {
        Order {
            speed,
            info: Self::INFO_NO_CAP,
        }
    }

    /// INFO read as an output power cap in percent (IDS 8.3: "intended to inform thruster to output no more than
    /// this value as a percentage of power"). 1..=100 caps (100 returns `Some(100)`, no reduction in effect);
    /// 0 and values above 100 mean no cap and return `None`.
    pub const fn power_cap_percent(self) -> Option<u8> {
        match self.info {
            1..=100 => Some(self.info),
            _ => None,
        }
    }

    /// Encode for a family: MT, SPEED (zero as 0x80), INFO, CSUM.
    pub fn encode(self, family: Family) -> [u8; ORDER_LEN] {
        let mt = family.order_type();
        let speed = self.speed.to_byte();
        [mt, speed, self.info, checksum(&[mt, speed, self.info])]
    }

    /// Decode an order addressed to a family. Checks, in this order: length 4 ([`DecodeError::Length`]),
    /// MT == `family.order_type()` ([`DecodeError::MessageType`]), CSUM ([`DecodeError::Checksum`]), SPEED range
    /// ([`DecodeError::SpeedOutOfRange`]). INFO may take any value.
    pub fn decode(family: Family, bytes: &[u8]) -> Result<Order, DecodeError> {
        let [mt, _, _, _] = order_array(bytes)?;
        let expected = family.order_type();
        if mt != expected {
            return Err(DecodeError::MessageType { expected, actual: mt });
        }
        decode_checked(bytes)
    }

    /// Decode an order of either family, the family being told by the MT byte (for bus capture decoders).
    ///
    /// Same checks as [`Order::decode`]. An MT byte that is neither 0x52 nor 0x54 gives
    /// [`DecodeError::MessageType`] with `expected` 0x52 (the SeaBotix order type).
    pub fn decode_any(bytes: &[u8]) -> Result<(Family, Order), DecodeError> {
        let [mt, _, _, _] = order_array(bytes)?;
        let family = Family::from_order_type(mt).ok_or(DecodeError::MessageType {
            expected: Family::SeaBotix.order_type(),
            actual: mt,
        })?;
        decode_checked(bytes).map(|order| (family, order))
    }
}

impl Default for Order {
    /// [`Order::STOP`].
    fn default() -> Order {
        Order::STOP
    }
}

/// The 4 order bytes, or a length error.
fn order_array(bytes: &[u8]) -> Result<[u8; ORDER_LEN], DecodeError> {
    <[u8; ORDER_LEN]>::try_from(bytes).map_err(|_| DecodeError::Length {
        expected: ORDER_LEN as u8,
        actual: bytes.len(),
    })
}

/// Checksum and field checks, once length and MT are known good.
fn decode_checked(bytes: &[u8]) -> Result<Order, DecodeError> {
    let [mt, speed, info, csum] = order_array(bytes)?;
    let sum = checksum(&[mt, speed, info]);
    if sum != csum {
        return Err(DecodeError::Checksum {
            expected: sum,
            actual: csum,
        });
    }
    Ok(Order {
        speed: Speed::from_byte(speed)?,
        info,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stop_and_new() {
        assert_eq!(
            Order::STOP,
            Order {
                speed: Speed::ZERO,
                info: 100
            }
        );
        assert_eq!(Order::default(), Order::STOP);
        assert_eq!(Order::new(Speed::MAX_FORWARD).info, 100);
        // 0x52 + 0x80 + 0x64 = 0x136 -> 0x36
        assert_eq!(Order::STOP.encode(Family::SeaBotix), [0x52, 0x80, 0x64, 0x36]);
    }

    #[test]
    fn power_cap() {
        let with = |info| Order {
            speed: Speed::ZERO,
            info,
        };
        assert_eq!(with(0).power_cap_percent(), None);
        assert_eq!(with(1).power_cap_percent(), Some(1));
        assert_eq!(with(50).power_cap_percent(), Some(50));
        assert_eq!(with(100).power_cap_percent(), Some(100));
        assert_eq!(with(101).power_cap_percent(), None);
        assert_eq!(with(255).power_cap_percent(), None);
    }

    #[test]
    fn decode_any_unknown_type() {
        // Length is checked before the type.
        assert_eq!(
            Order::decode_any(&[0x53, 0x80, 0x64]),
            Err(DecodeError::Length { expected: 4, actual: 3 })
        );
        assert_eq!(
            Order::decode_any(&[0x53, 0x80, 0x64, 0x37]),
            Err(DecodeError::MessageType {
                expected: 0x52,
                actual: 0x53
            })
        );
    }
}
