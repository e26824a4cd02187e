//! The flash interface's ECC flags, for the bootloader's handling of a read of a double word a power cut tore.
//!
//! RM0440 3.3.4 (error code correction): every double word carries 8 ECC bits. A read whose ECC shows two errors
//! sets FLASH_ECCR.ECCD, keeps the double word's address in ADDR_ECC and raises a non-maskable interrupt; the read
//! itself completes. ECCD is cleared by writing 1 to it, and ECCR records no other error until it is. A double
//! word whose programming or erase a power cut interrupted is left with data and ECC bits that disagree: such a
//! word (lbv-sim's flash records every read of one) is where a bootloader meets this interrupt.

/// FLASH_ECCR with only ECCD set: written, it clears ECCD and leaves the rest as it is (ECCC, also cleared by
/// writing 1, is written 0; ECCCIE 0 keeps the single-error interrupt off, as at reset).
pub const ECCR_CLEAR_ECCD: u32 = 1 << 31;

#[cfg(test)]
mod tests {
    use super::*;
    use stm32_metapac::flash::regs::Eccr;

    #[test]
    fn clearing_eccd_writes_eccd_alone() {
        let mut eccr = Eccr(0);
        eccr.set_eccd(true);
        assert_eq!(ECCR_CLEAR_ECCD, eccr.0);
    }
}
