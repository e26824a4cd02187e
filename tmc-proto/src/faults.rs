//! Thruster fault flags, shared by both status layouts.

use core::ops::{BitAnd, BitOr, BitOrAssign};

/// Fault flags. The bit positions are the same in the Legacy STATUS byte, bits 0-4 (IDS 8.4.1), and the SeaBotix
/// FAULT byte, bits 0-4 (IDS 8.4.2). Only bits 0-4 can be set; bits 5-7 are reserved.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Faults(u8);

impl Faults {
    /// No fault.
    pub const NONE: Faults = Faults(0);
    /// Bit 0: overtemperature (set at 110 C, cleared at 100 C; IDS 8.4 remarks).
    pub const OVERTEMP: Faults = Faults(1 << 0);
    /// Bit 1: stalled motor.
    pub const STALL: Faults = Faults(1 << 1);
    /// Bit 2: hall sensor error.
    pub const HALL: Faults = Faults(1 << 2);
    /// Bit 3: ground fault (water sensor resistance below 100 kohm).
    pub const GROUND: Faults = Faults(1 << 3);
    /// Bit 4: water detected (water sensor resistance below 1 Mohm).
    pub const WATER: Faults = Faults(1 << 4);
    /// All five faults.
    pub const ALL: Faults = Faults(0x1F);

    /// Each flag alone, lowest bit first.
    const FLAGS: [Faults; 5] = [Self::OVERTEMP, Self::STALL, Self::HALL, Self::GROUND, Self::WATER];

    /// Faults from a raw byte, dropping the reserved bits 5-7 (IDS 8.1: receivers must not assume them zero).
    pub const fn from_bits_truncate(bits: u8) -> Faults {
        Faults(bits & Self::ALL.0)
    }

    /// Raw bits; bits 5-7 are always zero.
    pub const fn bits(self) -> u8 {
        self.0
    }

    /// Whether no fault is set.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// Whether every flag of `other` is set in `self`.
    pub const fn contains(self, other: Faults) -> bool {
        self.0 & other.0 == other.0
    }

    /// Flags set in either.
    pub const fn union(self, other: Faults) -> Faults {
        Faults(self.0 | other.0)
    }

    /// Flags set in `self` but not in `other`.
    pub const fn difference(self, other: Faults) -> Faults {
        Faults(self.0 & !other.0)
    }

    /// Set the flags of `other`.
    pub fn insert(&mut self, other: Faults) {
        self.0 |= other.0;
    }

    /// Clear the flags of `other`.
    pub fn remove(&mut self, other: Faults) {
        self.0 &= !other.0;
    }

    /// Set (`on`) or clear the flags of `other`.
    pub fn set(&mut self, other: Faults, on: bool) {
        if on {
            self.insert(other);
        } else {
            self.remove(other);
        }
    }

    /// Each set flag alone, lowest bit first.
    pub fn iter(self) -> impl Iterator<Item = Faults> {
        Self::FLAGS.into_iter().filter(move |flag| self.contains(*flag))
    }

    /// Name of a single flag as the IDS words it; "none" when empty, "multiple" when several are set.
    pub const fn name(self) -> &'static str {
        match self.0 {
            0 => "none",
            0x01 => "overtemp",
            0x02 => "stalled motor",
            0x04 => "hall sensor error",
            0x08 => "ground fault",
            0x10 => "water detect",
            _ => "multiple",
        }
    }
}

impl BitOr for Faults {
    type Output = Faults;

    fn bitor(self, rhs: Faults) -> Faults {
        self.union(rhs)
    }
}

impl BitOrAssign for Faults {
    fn bitor_assign(&mut self, rhs: Faults) {
        self.insert(rhs);
    }
}

impl BitAnd for Faults {
    type Output = Faults;

    fn bitand(self, rhs: Faults) -> Faults {
        Faults(self.0 & rhs.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bit_positions() {
        assert_eq!(Faults::OVERTEMP.bits(), 0x01);
        assert_eq!(Faults::STALL.bits(), 0x02);
        assert_eq!(Faults::HALL.bits(), 0x04);
        assert_eq!(Faults::GROUND.bits(), 0x08);
        assert_eq!(Faults::WATER.bits(), 0x10);
        assert_eq!(Faults::ALL.bits(), 0x1F);
        assert_eq!(Faults::NONE.bits(), 0);
        assert_eq!(Faults::default(), Faults::NONE);
    }

    #[test]
    fn truncate_masks_reserved_bits() {
        assert_eq!(Faults::from_bits_truncate(0xFF), Faults::ALL);
        assert_eq!(Faults::from_bits_truncate(0xE0), Faults::NONE);
        assert_eq!(Faults::from_bits_truncate(0xA5), Faults::OVERTEMP | Faults::HALL);
    }

    #[test]
    fn set_operations() {
        let mut f = Faults::NONE;
        assert!(f.is_empty());
        f.insert(Faults::WATER);
        f |= Faults::STALL;
        assert_eq!(f.bits(), 0x12);
        assert!(f.contains(Faults::WATER));
        assert!(f.contains(Faults::WATER | Faults::STALL));
        assert!(!f.contains(Faults::WATER | Faults::HALL));
        assert!(f.contains(Faults::NONE));
        f.remove(Faults::WATER);
        assert_eq!(f, Faults::STALL);
        f.set(Faults::GROUND, true);
        assert_eq!(f, Faults::STALL | Faults::GROUND);
        f.set(Faults::STALL, false);
        assert_eq!(f, Faults::GROUND);
        assert_eq!(Faults::ALL.difference(Faults::GROUND).bits(), 0x17);
        assert_eq!((Faults::ALL & Faults::HALL), Faults::HALL);
        assert_eq!((Faults::STALL & Faults::HALL), Faults::NONE);
        assert_eq!(Faults::OVERTEMP.union(Faults::WATER).bits(), 0x11);
    }

    #[test]
    fn iter_yields_single_flags_lowest_first() {
        assert_eq!(Faults::NONE.iter().count(), 0);
        let all: Vec<Faults> = Faults::ALL.iter().collect();
        assert_eq!(
            all,
            [
                Faults::OVERTEMP,
                Faults::STALL,
                Faults::HALL,
                Faults::GROUND,
                Faults::WATER
            ]
        );
        let two: Vec<Faults> = (Faults::WATER | Faults::STALL).iter().collect();
        assert_eq!(two, [Faults::STALL, Faults::WATER]);
        for bits in 0..=0x1F_u8 {
            let f = Faults::from_bits_truncate(bits);
            let rebuilt = f.iter().fold(Faults::NONE, |acc, x| acc | x);
            assert_eq!(rebuilt, f);
            assert_eq!(f.iter().count(), bits.count_ones() as usize);
        }
    }

    #[test]
    fn names() {
        assert_eq!(Faults::NONE.name(), "none");
        assert_eq!(Faults::OVERTEMP.name(), "overtemp");
        assert_eq!(Faults::STALL.name(), "stalled motor");
        assert_eq!(Faults::HALL.name(), "hall sensor error");
        assert_eq!(Faults::GROUND.name(), "ground fault");
        assert_eq!(Faults::WATER.name(), "water detect");
        assert_eq!((Faults::WATER | Faults::GROUND).name(), "multiple");
        assert_eq!(Faults::ALL.name(), "multiple");
    }
}
