//! The two thruster controller families and their bus addresses.

/// Thruster motor controller family; each has its own address and message layouts (IDS 6.4.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Family {
    /// SeaBotix motor controller: 8-bit address bytes 0x52 / 0x53, 7-byte status (IDS 8.3.2, 8.4.2).
    SeaBotix,
    /// Aveox / Legacy SeaBotix motor controller: address bytes 0x54 / 0x55, 4-byte status (IDS 8.3.1, 8.4.1).
    Legacy,
}

impl Family {
    /// Both families.
    pub const ALL: [Family; 2] = [Family::SeaBotix, Family::Legacy];

    /// 7-bit I2C slave address, as HALs take it: the IDS's 8-bit write byte shifted right by one (IDS 6.4.2).
    pub const fn address(self) -> u8 {
        match self {
            Family::SeaBotix => 0x29,
            Family::Legacy => 0x2A,
        }
    }

    /// MT byte of the order; equals the 8-bit write address byte (IDS 8.3).
    pub const fn order_type(self) -> u8 {
        self.address() << 1
    }

    /// MT byte of the status; equals the 8-bit read address byte (IDS 8.4).
    pub const fn status_type(self) -> u8 {
        (self.address() << 1) | 1
    }

    /// Length in bytes of this family's status message (IDS 8.4.1: 4, IDS 8.4.2: 7).
    pub const fn status_len(self) -> usize {
        match self {
            Family::SeaBotix => 7,
            Family::Legacy => 4,
        }
    }

    /// Family answering at a 7-bit address, if any.
    pub const fn from_address(address: u8) -> Option<Family> {
        match address {
            0x29 => Some(Family::SeaBotix),
            0x2A => Some(Family::Legacy),
            _ => None,
        }
    }

    /// Short name for logs.
    pub const fn name(self) -> &'static str {
        match self {
            Family::SeaBotix => "SeaBotix",
            Family::Legacy => "Legacy",
        }
    }

    /// Family whose order carries this MT byte.
    pub(crate) const fn from_order_type(mt: u8) -> Option<Family> {
        match mt {
            0x52 => Some(Family::SeaBotix),
            0x54 => Some(Family::Legacy),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_and_message_types() {
        assert_eq!(Family::SeaBotix.address(), 0x29);
        assert_eq!(Family::Legacy.address(), 0x2A);
        assert_eq!(Family::SeaBotix.order_type(), 0x52);
        assert_eq!(Family::SeaBotix.status_type(), 0x53);
        assert_eq!(Family::Legacy.order_type(), 0x54);
        assert_eq!(Family::Legacy.status_type(), 0x55);
        for family in Family::ALL {
            assert_eq!(Family::from_address(family.address()), Some(family));
            assert_eq!(Family::from_order_type(family.order_type()), Some(family));
        }
        assert_eq!(Family::from_address(0x52), None);
        assert_eq!(Family::from_order_type(0x53), None);
        assert_eq!(Family::SeaBotix.name(), "SeaBotix");
        assert_eq!(Family::Legacy.name(), "Legacy");
    }
}
