//! What survives a reset for the next start to read: the backup registers each image keeps a word in, and the
//! reset flags that say which reset it was.
//!
//! TAMP_BKPxR (RM0440 39.6.18; 32 registers on the G431 and the G474) sit in the backup domain: kept over every
//! reset but a power-on or a backup-domain reset, and on the NUCLEO boards VBAT is tied to VDD (UM2505 6.5), so a
//! power cut clears them. Writing one needs PWR_CR1.DBP (RM0440 6.1.5) with the PWR and RTC APB clocks on
//! (RCC_APB1ENR1 bits 28 PWREN and 10 RTCAPBEN, RM0440 7.4.19).

/// The thruster's power-cycle fault latches (`thruster_fw::faults::latch`).
pub const LATCH_REGISTER: usize = 0;

/// The bootloader's count of consecutive early crashes (`update_image::CrashCount`), on both boards.
pub const CRASH_REGISTER: usize = 1;

/// RCC_APB1ENR1: PWREN (bit 28) and RTCAPBEN (bit 10), the clocks the backup registers need.
pub const APB1ENR1_BACKUP: u32 = (1 << 28) | (1 << 10);

/// PWR_CR1.DBP (bit 8): writes to the backup domain allowed.
pub const PWR_CR1_DBP: u32 = 1 << 8;

/// RCC_CSR's independent-watchdog reset flag (IWDGRSTF, bit 29; RM0440 7.4.29).
pub const CSR_IWDGRSTF: u32 = 1 << 29;

/// RCC_CSR's window-watchdog reset flag (WWDGRSTF, bit 30).
pub const CSR_WWDGRSTF: u32 = 1 << 30;

/// Whether RCC_CSR says a watchdog reset the chip. The images stop on a panic, a fault or a stray interrupt and
/// let the independent watchdog reset them, so this is also how a crash shows. The flags accumulate until software
/// clears them (RMVF), which the images do after the bootloader has read them; a watchdog reset also sets PINRSTF
/// (the chip drives NRST low), so PINRSTF says nothing here.
pub const fn watchdog_reset(csr: u32) -> bool {
    csr & (CSR_IWDGRSTF | CSR_WWDGRSTF) != 0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_a_watchdog_flag_reads_as_a_watchdog_reset() {
        const PINRSTF: u32 = 1 << 26;
        const BORRSTF: u32 = 1 << 27;
        const SFTRSTF: u32 = 1 << 28;
        assert!(watchdog_reset(CSR_IWDGRSTF | PINRSTF));
        assert!(watchdog_reset(CSR_WWDGRSTF | PINRSTF));
        assert!(!watchdog_reset(SFTRSTF | PINRSTF), "a software reset");
        assert!(!watchdog_reset(BORRSTF | PINRSTF), "a power-on");
        assert!(!watchdog_reset(PINRSTF), "the reset button");
        assert_ne!(LATCH_REGISTER, CRASH_REGISTER);
    }

    #[test]
    fn the_bits_are_the_svds() {
        use stm32_metapac::pwr::regs::Cr1;
        use stm32_metapac::rcc::regs::{Apb1enr1, Csr};
        let mut csr = Csr(0);
        csr.set_iwdgrstf(true);
        csr.set_wwdgrstf(true);
        assert_eq!(csr.0, CSR_IWDGRSTF | CSR_WWDGRSTF);
        let mut enr = Apb1enr1(0);
        enr.set_pwren(true);
        enr.set_rtcapben(true);
        assert_eq!(enr.0, APB1ENR1_BACKUP);
        let mut cr1 = Cr1(0);
        cr1.set_dbp(true);
        assert_eq!(cr1.0, PWR_CR1_DBP);
    }
}
