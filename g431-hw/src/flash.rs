//! A flash ECC double error, and what an image's NMI handler does about it.
//!
//! The G4 keeps 8 ECC bits with every 64-bit double word of its flash (RM0440 3.3.2, "Error code correction
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
//!
//! And the G474's bank mode ([`master_layout_ok`]): the master's partitions and settings are placed for its two
//! banks of 2 KiB pages, which the user option bytes can turn into one bank of 4 KiB pages.

use crate::memory::{FLASH_ORIGIN, G474_BANK2, G474RE, Span};

/// FLASH_ECCR's fields (RM0440 3.7.7; positions as in ST's SVD for the category 2 devices, the G431; the category 3
/// devices, the G474, have the same, and set BK_ECC in dual-bank mode).
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

// The address field reaches every byte of a bank.
const _: () = assert!(eccr::ADDR_ECC >= G474_BANK2 - FLASH_ORIGIN - 1);

/// FLASH_OPTR's fields read here, the user option bytes as loaded at reset (RM0440 3.7.8, "Flash option register
/// (FLASH_OPTR)"; the position as in ST's SVD for the G474, the stm32g4 crate 0.16's `flash::optr`).
pub mod optr {
    /// DBANK, bit 22, category 3 devices (the G474) only: 1 is dual-bank mode, two banks of 256 KiB in 2 KiB pages;
    /// 0 is one bank of 4 KiB pages.
    pub const DBANK: u32 = 1 << 22;
    /// The option bytes as they leave the factory (RM0440 3.4.1; the SVD's reset value): DBANK set.
    pub const FACTORY: u32 = 0xFFEF_F8AA;
}

/// Whether the G474's flash, FLASH_OPTR reading `optr`, is in the layout the master's partitions and settings are
/// placed for ([`G474RE`], `memory::MASTER_PARTITIONS`, `memory::MASTER_STORAGE`): dual-bank mode. In single-bank
/// mode an erase's page number, which the driver counts in bank 2's 2 KiB pages, names a 4 KiB page of the one
/// bank: other pages than the ones meant, the images' code among them. embassy-stm32 checks DBANK only in its
/// blocking driver, which the bootloader uses; the application's async driver does not.
pub const fn master_layout_ok(optr: u32) -> bool {
    optr & optr::DBANK != 0
}

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

    /// The double word's address in the main flash: in bank 2 (only ever reported by the G474 in dual-bank mode)
    /// the offset counts from that bank's start.
    pub const fn address(&self) -> u32 {
        if self.bank2 {
            G474_BANK2 + self.offset
        } else {
            FLASH_ORIGIN + self.offset
        }
    }

    /// Whether the error is in the main flash inside `span`.
    pub const fn within(&self, span: Span) -> bool {
        let address = self.address();
        !self.system_memory && address < G474RE.flash.end() && span.origin <= address && address < span.end()
    }
}

/// FLASH_ECCR's address bits for an ECC error at `address` in the main flash: the offset from its bank's start,
/// and BK_ECC in the G474's bank 2 (what a model of the chip reports; [`EccError::address`] reads it back).
pub const fn eccr_address(address: u32) -> u32 {
    if address >= G474_BANK2 {
        eccr::BK_ECC | (address - G474_BANK2)
    } else {
        address - FLASH_ORIGIN
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
    use crate::memory::{MASTER_PARTITIONS, MASTER_STORAGE, THRUSTER_PARTITIONS};

    const PASS: NmiAction = NmiAction::PassDataRead { clear: ECCD };

    /// The settings, in bank 2 of the G474 (offset 0x3_C000 there).
    fn settings() -> Span {
        MASTER_STORAGE
    }

    #[test]
    fn a_double_error_in_a_data_page_is_passed() {
        // The first and the last double word of the master's 16 KiB at 0x0807_C000, and one inside: bank 2.
        for offset in [0x3_C000, 0x3_D238, 0x3_FFF8] {
            assert_eq!(nmi_action(ECCD | BK_ECC | offset, &[settings()]), PASS, "{offset:#x}");
            let error = EccError::decode(ECCD | BK_ECC | offset);
            assert!(error.double && error.within(settings()) && !error.corrected);
            assert_eq!(error.address(), 0x0804_0000 + offset);
            assert_eq!(eccr_address(error.address()), BK_ECC | offset);
        }
        // The master's state, record and DFU, all in bank 2.
        let master = [MASTER_PARTITIONS.state, MASTER_PARTITIONS.record, MASTER_PARTITIONS.dfu];
        for eccr in [
            BK_ECC,
            BK_ECC | 0xFF8,
            BK_ECC | 0x1000,
            BK_ECC | 0x27F8,
            BK_ECC | 0x2800,
            BK_ECC | 0x3_BFF8,
        ] {
            assert_eq!(nmi_action(ECCD | eccr, &master), PASS, "{eccr:#x}");
        }
        // The thruster's state page, the ends of its record and of its DFU partition.
        let thruster = [
            THRUSTER_PARTITIONS.state,
            THRUSTER_PARTITIONS.record,
            THRUSTER_PARTITIONS.dfu,
        ];
        for offset in [0x4000, 0x47F8, 0x4800, 0x5FF8, 0x1_2800, 0x1_F7F8] {
            assert_eq!(nmi_action(ECCD | offset, &thruster), PASS, "{offset:#x}");
        }
    }

    #[test]
    fn a_double_error_anywhere_else_stops() {
        // The settings' offsets in bank 1 (the master's code), DFU's last double word, and the master's ACTIVE.
        for eccr in [0x3_C000, 0x3_FFF8, BK_ECC | 0x3_BFF8, 0x0, 0x3000, 0x3_E7F8] {
            assert_eq!(nmi_action(ECCD | eccr, &[settings()]), NmiAction::Stop, "{eccr:#x}");
        }
        // The master's bootloader and ACTIVE (bank 1: its code), and its settings.
        let master = [MASTER_PARTITIONS.state, MASTER_PARTITIONS.record, MASTER_PARTITIONS.dfu];
        for eccr in [0x0, 0x3FF8, 0x4000, 0x3_CFF8, 0x3_FFF8, BK_ECC | 0x3_C000] {
            assert_eq!(nmi_action(ECCD | eccr, &master), NmiAction::Stop, "{eccr:#x}");
        }
        // The thruster's bootloader and ACTIVE (its code).
        let thruster = [
            THRUSTER_PARTITIONS.state,
            THRUSTER_PARTITIONS.record,
            THRUSTER_PARTITIONS.dfu,
        ];
        for offset in [0x0, 0x3FF8, 0x6000, 0x1_27F8, 0x1_F800] {
            assert_eq!(nmi_action(ECCD | offset, &thruster), NmiAction::Stop, "{offset:#x}");
        }
        // The system memory, at an offset that would be in the settings pages; the thruster's DFU offset in a
        // second bank, which the G431 does not have.
        assert_eq!(
            nmi_action(ECCD | SYSF_ECC | BK_ECC | 0x3_C000, &[settings()]),
            NmiAction::Stop
        );
        assert_eq!(nmi_action(ECCD | BK_ECC | 0x1_2800, &thruster), NmiAction::Stop);
        // No data pages at all.
        assert_eq!(nmi_action(ECCD | BK_ECC | 0x3_C000, &[]), NmiAction::Stop);
    }

    #[test]
    fn an_nmi_that_is_no_double_error_stops() {
        // Another cause (FLASH_ECCR clear), or only a corrected error on record.
        assert_eq!(nmi_action(0, &[settings()]), NmiAction::Stop);
        assert_eq!(nmi_action(ECCC | BK_ECC | 0x3_C000, &[settings()]), NmiAction::Stop);
    }

    #[test]
    fn clearing_keeps_the_correction_interrupt_enable_and_writes_only_ecc_d() {
        assert_eq!(
            nmi_action(ECCD | ECCC | ECCCIE | BK_ECC | 0x3_E000, &[settings()]),
            NmiAction::PassDataRead { clear: ECCD | ECCCIE }
        );
        // ECCC is cleared by writing 1 too: left as it is (0 written), as are the read-only fields.
        let NmiAction::PassDataRead { clear } = nmi_action(ECCD | ECCC | BK_ECC | 0x3_E000, &[settings()]) else {
            panic!("passed")
        };
        assert_eq!(clear & (ECCC | ADDR_ECC | SYSF_ECC | BK_ECC), 0);
    }

    #[test]
    fn the_master_s_layout_is_dual_bank_mode_whatever_the_other_option_bytes_say() {
        assert!(master_layout_ok(optr::FACTORY), "as the chips leave the factory");
        assert!(!master_layout_ok(optr::FACTORY & !optr::DBANK), "one bank");
        assert_eq!(optr::DBANK, 1 << 22);
        // Only DBANK counts: every other bit set or clear, as a vehicle's option bytes set them or not (nSWBOOT0,
        // nBOOT0, IWDG_SW, BFB2, RDP...).
        assert!(master_layout_ok(optr::DBANK) && master_layout_ok(u32::MAX));
        assert!(!master_layout_ok(0) && !master_layout_ok(!optr::DBANK));
        for bit in (0..32).filter(|bit| 1 << bit != optr::DBANK) {
            assert!(master_layout_ok(optr::FACTORY ^ (1 << bit)), "bit {bit}");
            assert!(
                !master_layout_ok((optr::FACTORY & !optr::DBANK) ^ (1 << bit)),
                "bit {bit}"
            );
        }
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
