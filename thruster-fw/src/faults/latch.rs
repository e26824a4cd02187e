//! The power-cycle latches across resets: where they are kept ([`LatchStore`]), the word they are kept as
//! (tagged, so that a word never written reads as none), and which resets carry them ([`carried_latch`]). On the
//! STM32 the word is a backup register, kept over every reset but a power cycle.

use tmc_proto::Faults;

use crate::ports::LatchStore;

/// A store that forgets at reset, as RAM does at power-off: for the host bench and tests, where every reset is a
/// power cycle.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct VolatileLatch(Faults);

impl LatchStore for VolatileLatch {
    fn load(&mut self) -> Faults {
        self.0
    }

    fn save(&mut self, latched: Faults) {
        self.0 = latched;
    }
}

/// How the chip came out of its last reset, as far as the latches are concerned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum ResetKind {
    /// Power-on or brown-out: a power cycle, which clears the latches.
    PowerCycle,
    /// Any other reset (watchdog, reset pin, software, option-byte load): the latches stay.
    Other,
}

/// Marks a latch word as written by this firmware.
const LATCH_TAG: u32 = 0x4C54;

/// The latches as one 32-bit word: a tag in the upper half, the fault bits and their complement below, so that a
/// word never written (zero after a power-on) or corrupted reads as no latch.
pub const fn latch_word(latched: Faults) -> u32 {
    let bits = latched.bits() as u32;
    (LATCH_TAG << 16) | ((!bits & 0xFF) << 8) | bits
}

/// The latches of a word written by [`latch_word`]; none for any other word.
pub const fn latch_from_word(word: u32) -> Faults {
    let bits = word & 0xFF;
    if word >> 16 == LATCH_TAG && (word >> 8) & 0xFF == !bits & 0xFF {
        Faults::from_bits_truncate(bits as u8)
    } else {
        Faults::NONE
    }
}

/// The latches to restore at boot from the stored word, after a reset of `kind`.
pub const fn carried_latch(kind: ResetKind, word: u32) -> Faults {
    match kind {
        ResetKind::PowerCycle => Faults::NONE,
        ResetKind::Other => latch_from_word(word),
    }
}
