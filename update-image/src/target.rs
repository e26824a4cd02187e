//! What an image is built for.

use core::fmt;

use tmc_proto::Family;

/// The board and build an image runs on. A thruster image speaks one controller family's protocol on one bus
/// address, so the two families are two targets: an image of the other family would answer at the wrong address.
///
/// Stored as one byte; 0x00 and 0xFF (zeroed and erased flash) are no target, so neither reads as one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Target {
    /// A thruster of the SeaBotix controller family (address bytes 0x52/0x53).
    ThrusterSeabotix,
    /// A thruster of the Aveox/Legacy controller family (address bytes 0x54/0x55).
    ThrusterLegacy,
    /// The vehicle's master node.
    Master,
}

impl Target {
    /// Every target.
    pub const ALL: [Target; 3] = [Target::ThrusterSeabotix, Target::ThrusterLegacy, Target::Master];

    /// Its byte in the header and the image info.
    pub const fn to_byte(self) -> u8 {
        match self {
            Target::ThrusterSeabotix => 1,
            Target::ThrusterLegacy => 2,
            Target::Master => 3,
        }
    }

    /// The target of a header or image info byte, if it is one.
    pub const fn from_byte(byte: u8) -> Option<Target> {
        match byte {
            1 => Some(Target::ThrusterSeabotix),
            2 => Some(Target::ThrusterLegacy),
            3 => Some(Target::Master),
            _ => None,
        }
    }

    /// The thruster target of a controller family.
    pub const fn thruster(family: Family) -> Target {
        match family {
            Family::SeaBotix => Target::ThrusterSeabotix,
            Family::Legacy => Target::ThrusterLegacy,
        }
    }

    /// The controller family of a thruster target; `None` for the master.
    pub const fn family(self) -> Option<Family> {
        match self {
            Target::ThrusterSeabotix => Some(Family::SeaBotix),
            Target::ThrusterLegacy => Some(Family::Legacy),
            Target::Master => None,
        }
    }

    /// What the target is, for a person: "SeaBotix (0x52/0x53)", "Aveox/Legacy (0x54/0x55)", "master".
    pub const fn name(self) -> &'static str {
        match self {
            Target::ThrusterSeabotix => "SeaBotix (0x52/0x53)",
            Target::ThrusterLegacy => "Aveox/Legacy (0x54/0x55)",
            Target::Master => "master",
        }
    }
}

/// "thruster, SeaBotix family (0x52/0x53)" or "master".
impl fmt::Display for Target {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Target::ThrusterSeabotix => f.write_str("thruster, SeaBotix family (0x52/0x53)"),
            Target::ThrusterLegacy => f.write_str("thruster, Aveox/Legacy family (0x54/0x55)"),
            Target::Master => f.write_str("master"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_round_trip_and_flash_fill_is_no_target() {
        for target in Target::ALL {
            assert_eq!(Target::from_byte(target.to_byte()), Some(target));
        }
        for byte in [0x00, 0x04, 0x52, 0xFF] {
            assert_eq!(Target::from_byte(byte), None);
        }
        let known = (0..=u8::MAX).filter(|byte| Target::from_byte(*byte).is_some()).count();
        assert_eq!(known, Target::ALL.len());
    }

    #[test]
    fn families_map_to_thruster_targets() {
        for family in Family::ALL {
            assert_eq!(Target::thruster(family).family(), Some(family));
        }
        assert_eq!(Target::Master.family(), None);
        // The family bytes in the names are the family's order and status message types.
        for family in Family::ALL {
            let name = Target::thruster(family).name();
            let bytes = format!("(0x{:02X}/0x{:02X})", family.order_type(), family.status_type());
            assert!(name.ends_with(&bytes), "{name} names {bytes}");
        }
        assert_eq!(
            Target::ThrusterLegacy.to_string(),
            "thruster, Aveox/Legacy family (0x54/0x55)"
        );
    }
}
