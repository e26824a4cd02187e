//! A flash ECC double error in the settings pages, and what the STM32 binding's NMI handler does about it.
//!
//! The G431 keeps 8 ECC bits with every 64-bit double word of its flash (RM0440 3.3.2, "Error code correction
//! (ECC)"). One wrong bit is corrected on the fly; two are only detected: FLASH_ECCR.ECCD is set, the double word's
//! address kept in ADDR_ECC, and an NMI raised (RM0440 3.3.2; the register in 3.7.7). A power cut while a double
//! word is being programmed, or while a page is being erased, can leave it so. In the settings pages that is a
//! record cut short, which the store skips (its CRC fails) — but only if the read returns: left to the default
//! handler, the NMI would stop the master at its next start, the first time the store reads the record.
//!
//! So the handler lets an ECC double error in the settings pages pass: it clears ECCD (written 1; ECCCIE kept)
//! and returns, and the read completes with what the cells hold. Anything else — an ECC error in the image or in
//! the system memory, or an NMI of another cause — is not one to run on: the master stops, its thruster buses go
//! quiet and every thruster stops by its own link failsafe.

use super::G431_STORAGE;

/// FLASH_ECCR's fields (RM0440 3.7.7; positions as in ST's SVD for category 2 devices, one bank).
pub mod eccr {
    /// ECC detection: two errors in a double word (cleared by writing 1).
    pub const ECCD: u32 = 1 << 31;
    /// ECC correction: one error, corrected (cleared by writing 1).
    pub const ECCC: u32 = 1 << 30;
    /// ECC correction interrupt enable.
    pub const ECCCIE: u32 = 1 << 24;
    /// The error is in the system memory (the boot loader), not in the main flash.
    pub const SYSF_ECC: u32 = 1 << 22;
    /// The error is in bank 2 (dual-bank category 3 devices only).
    pub const BK_ECC: u32 = 1 << 21;
    /// The failing double word's address, in bytes from the start of its bank.
    pub const ADDR_ECC: u32 = 0x7_FFFF;
}

// The address field reaches every byte of the settings pages.
const _: () = assert!(eccr::ADDR_ECC >= G431_STORAGE.end - 1);

/// An ECC error as FLASH_ECCR reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EccError {
    /// Two errors, detected and not corrected (the NMI's cause).
    pub double: bool,
    /// One error, corrected.
    pub corrected: bool,
    /// In the system memory rather than the main flash.
    pub system_memory: bool,
    /// In bank 2.
    pub bank2: bool,
    /// The double word's offset from the start of the flash bank.
    pub offset: u32,
}

impl EccError {
    /// The fields of a FLASH_ECCR value.
    pub const fn decode(eccr: u32) -> Self {
        Self {
            double: eccr & eccr::ECCD != 0,
            corrected: eccr & eccr::ECCC != 0,
            system_memory: eccr & eccr::SYSF_ECC != 0,
            bank2: eccr & eccr::BK_ECC != 0,
            offset: eccr & eccr::ADDR_ECC,
        }
    }

    /// Whether the error is in the pages kept for the settings ([`G431_STORAGE`]).
    pub const fn in_settings(&self) -> bool {
        !self.system_memory && !self.bank2 && G431_STORAGE.start <= self.offset && self.offset < G431_STORAGE.end
    }
}

/// What the NMI handler does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NmiAction {
    /// An ECC double error in the settings pages: write `clear` to FLASH_ECCR (ECCD cleared, ECCCIE as it was) and
    /// return, so the read completes and the store skips the record.
    PassSettingsRead {
        /// The value to write to FLASH_ECCR.
        clear: u32,
    },
    /// Anything else: stop the master.
    Stop,
}

/// What to do about an NMI, with FLASH_ECCR reading `eccr`.
pub const fn nmi_action(eccr: u32) -> NmiAction {
    let error = EccError::decode(eccr);
    if error.double && error.in_settings() {
        NmiAction::PassSettingsRead {
            clear: (eccr & eccr::ECCCIE) | eccr::ECCD,
        }
    } else {
        NmiAction::Stop
    }
}

#[cfg(test)]
mod tests {
    use super::eccr::*;
    use super::*;

    const PASS: NmiAction = NmiAction::PassSettingsRead { clear: ECCD };

    #[test]
    fn a_double_error_in_the_settings_pages_is_passed() {
        // The first and the last double word of the 16 KiB at 0x0801_C000, and one inside.
        for offset in [0x1_C000, 0x1_D238, 0x1_FFF8] {
            assert_eq!(nmi_action(ECCD | offset), PASS, "{offset:#x}");
            let error = EccError::decode(ECCD | offset);
            assert!(error.double && error.in_settings() && !error.corrected);
            assert_eq!(error.offset, offset);
        }
    }

    #[test]
    fn a_double_error_anywhere_else_stops() {
        // The image's last double word, its first (the vector table), beyond the 128 KiB.
        for offset in [0x1_BFF8, 0x0, 0x400, 0x2_0000, 0x7_FFF8] {
            assert_eq!(nmi_action(ECCD | offset), NmiAction::Stop, "{offset:#x}");
        }
        // The system memory and a second bank, at an offset that would be in the settings pages.
        assert_eq!(nmi_action(ECCD | SYSF_ECC | 0x1_C000), NmiAction::Stop);
        assert_eq!(nmi_action(ECCD | BK_ECC | 0x1_C000), NmiAction::Stop);
    }

    #[test]
    fn an_nmi_that_is_no_double_error_stops() {
        // Another cause (FLASH_ECCR clear), or only a corrected error on record.
        assert_eq!(nmi_action(0), NmiAction::Stop);
        assert_eq!(nmi_action(ECCC | 0x1_C000), NmiAction::Stop);
    }

    #[test]
    fn clearing_keeps_the_correction_interrupt_enable_and_writes_only_ecc_d() {
        assert_eq!(
            nmi_action(ECCD | ECCC | ECCCIE | 0x1_E000),
            NmiAction::PassSettingsRead { clear: ECCD | ECCCIE }
        );
        // ECCC is cleared by writing 1 too: left as it is (0 written), as are the read-only fields.
        let NmiAction::PassSettingsRead { clear } = nmi_action(ECCD | ECCC | 0x1_E000) else {
            panic!("passed")
        };
        assert_eq!(clear & (ECCC | ADDR_ECC | SYSF_ECC | BK_ECC), 0);
    }

    #[test]
    fn the_fields_do_not_overlap() {
        let fields = [ECCD, ECCC, ECCCIE, SYSF_ECC, BK_ECC, ADDR_ECC];
        for (i, a) in fields.iter().enumerate() {
            for b in &fields[i + 1..] {
                assert_eq!(a & b, 0, "{a:#x} {b:#x}");
            }
        }
    }
}
