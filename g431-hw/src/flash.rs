//! A flash ECC double error, and what an image's NMI handler does about it.
//!
//! The G431 keeps 8 ECC bits with every 64-bit double word of its flash (RM0440 3.3.2, "Error code correction
//! (ECC)"). One wrong bit is corrected on the fly; two are only detected: FLASH_ECCR.ECCD is set, the double word's
//! address kept in ADDR_ECC, and an NMI raised; the read itself completes with what the cells hold. A power cut
//! while a double word is being programmed, or while its page is being erased, can leave it so. In the pages an
//! image keeps data in (the master's settings, the thruster's bootloader state and DFU partition) that is what a
//! power cut leaves, and the code reading them copes with any content (a record's CRC, embassy-boot's magic words,
//! a signature) — but only if the read returns: left to a handler that stops, the NMI would stop the image at its
//! next start, the first time it reads the same word, and at every start after.
//!
//! So [`nmi_action`] passes an ECC double error in the pages an image names: it clears ECCD (written 1; ECCCIE
//! kept) and the read completes. Anything else — an ECC error in the code, in the system memory, or an NMI of
//! another cause — is not one to run on.

use crate::memory::{FLASH, Span};

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

// The address field reaches every byte of the flash.
const _: () = assert!(eccr::ADDR_ECC >= FLASH.length - 1);

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

    /// Whether the error is in the main flash inside `span`.
    pub const fn within(&self, span: Span) -> bool {
        let address = FLASH.origin + self.offset;
        !self.system_memory && !self.bank2 && span.origin <= address && address < span.end()
    }
}

/// What an NMI handler does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NmiAction {
    /// An ECC double error in a page the image keeps data in: write `clear` to FLASH_ECCR (ECCD cleared, ECCCIE as
    /// it was) and return, so that the read completes.
    PassDataRead {
        /// The value to write to FLASH_ECCR.
        clear: u32,
    },
    /// Anything else: stop.
    Stop,
}

/// What to do about an NMI, with FLASH_ECCR reading `eccr`, in an image that keeps data in `data`.
pub const fn nmi_action(eccr: u32, data: &[Span]) -> NmiAction {
    let error = EccError::decode(eccr);
    if !error.double {
        return NmiAction::Stop;
    }
    let mut rest = data;
    while let [span, tail @ ..] = rest {
        if error.within(*span) {
            return NmiAction::PassDataRead {
                clear: (eccr & eccr::ECCCIE) | eccr::ECCD,
            };
        }
        rest = tail;
    }
    NmiAction::Stop
}

#[cfg(test)]
mod tests {
    use super::eccr::*;
    use super::*;
    use crate::memory::{MASTER, THRUSTER_PARTITIONS};

    const PASS: NmiAction = NmiAction::PassDataRead { clear: ECCD };

    fn settings() -> Span {
        MASTER.region("STORAGE").expect("the master keeps settings").span
    }

    #[test]
    fn a_double_error_in_a_data_page_is_passed() {
        // The first and the last double word of the master's 16 KiB at 0x0801_C000, and one inside.
        for offset in [0x1_C000, 0x1_D238, 0x1_FFF8] {
            assert_eq!(nmi_action(ECCD | offset, &[settings()]), PASS, "{offset:#x}");
            let error = EccError::decode(ECCD | offset);
            assert!(error.double && error.within(settings()) && !error.corrected);
            assert_eq!(error.offset, offset);
        }
        // The thruster's state page and the ends of its DFU partition.
        let thruster = [THRUSTER_PARTITIONS.state, THRUSTER_PARTITIONS.dfu];
        for offset in [0x2000, 0x27F8, 0x1_1000, 0x1_FFF8] {
            assert_eq!(nmi_action(ECCD | offset, &thruster), PASS, "{offset:#x}");
        }
    }

    #[test]
    fn a_double_error_anywhere_else_stops() {
        // The master's last code double word, its first (the vector table), beyond the 128 KiB.
        for offset in [0x1_BFF8, 0x0, 0x400, 0x2_0000, 0x7_FFF8] {
            assert_eq!(nmi_action(ECCD | offset, &[settings()]), NmiAction::Stop, "{offset:#x}");
        }
        // The thruster's bootloader and ACTIVE (its code).
        let thruster = [THRUSTER_PARTITIONS.state, THRUSTER_PARTITIONS.dfu];
        for offset in [0x0, 0x1FF8, 0x2800, 0x1_0FF8] {
            assert_eq!(nmi_action(ECCD | offset, &thruster), NmiAction::Stop, "{offset:#x}");
        }
        // The system memory and a second bank, at an offset that would be in the settings pages.
        assert_eq!(nmi_action(ECCD | SYSF_ECC | 0x1_C000, &[settings()]), NmiAction::Stop);
        assert_eq!(nmi_action(ECCD | BK_ECC | 0x1_C000, &[settings()]), NmiAction::Stop);
        // No data pages at all.
        assert_eq!(nmi_action(ECCD | 0x1_C000, &[]), NmiAction::Stop);
    }

    #[test]
    fn an_nmi_that_is_no_double_error_stops() {
        // Another cause (FLASH_ECCR clear), or only a corrected error on record.
        assert_eq!(nmi_action(0, &[settings()]), NmiAction::Stop);
        assert_eq!(nmi_action(ECCC | 0x1_C000, &[settings()]), NmiAction::Stop);
    }

    #[test]
    fn clearing_keeps_the_correction_interrupt_enable_and_writes_only_ecc_d() {
        assert_eq!(
            nmi_action(ECCD | ECCC | ECCCIE | 0x1_E000, &[settings()]),
            NmiAction::PassDataRead { clear: ECCD | ECCCIE }
        );
        // ECCC is cleared by writing 1 too: left as it is (0 written), as are the read-only fields.
        let NmiAction::PassDataRead { clear } = nmi_action(ECCD | ECCC | 0x1_E000, &[settings()]) else {
            panic!("passed")
        };
        assert_eq!(clear & (ECCC | ADDR_ECC | SYSF_ECC | BK_ECC), 0);
    }

    #[test]
    fn the_fields_do_not_overlap_and_match_the_register_map() {
        let fields = [ECCD, ECCC, ECCCIE, SYSF_ECC, BK_ECC, ADDR_ECC];
        for (i, a) in fields.iter().enumerate() {
            for b in &fields[i + 1..] {
                assert_eq!(a & b, 0, "{a:#x} {b:#x}");
            }
        }
        // As ST's SVD for the G431 has them, through stm32-metapac.
        use stm32_metapac::flash::regs::Eccr;
        assert!(Eccr(ECCD).eccd() && !Eccr(ECCD).eccc());
        assert!(Eccr(ECCC).eccc() && Eccr(ECCCIE).eccie());
        assert!(Eccr(SYSF_ECC).sysf_ecc() && Eccr(BK_ECC).bk_ecc());
        assert!(Eccr(ADDR_ECC).addr_ecc() == ADDR_ECC && Eccr(!ADDR_ECC).addr_ecc() == 0);
    }
}
