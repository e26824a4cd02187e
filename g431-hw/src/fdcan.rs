//! FDCAN nominal bit timing and the clock tolerance it leaves.
//!
//! embassy-stm32 0.6's `CanConfigurator::set_bitrate` picks the timing itself (`calc_can_timings` in its
//! `can/util.rs`): at most 10 time quanta at 1 Mbit/s and SJW 1. From the old 85 MHz kernel clock that gives 5 tq
//! (prescaler 17, TSEG1 3, TSEG2 1), which tolerates 0.78 % of clock error, and HSI16 is specified at +-1 %. The
//! master now clocks FDCAN from the NUCLEO's 24 MHz crystal and sets the timing from [`nominal`].
//!
//! Tolerance, per node, from ISO 11898-1's conditions as given by Bosch ("The Configuration of the CAN Bit
//! Timing", Hartwich and Bassemir, 6th iCC 1999), in time quanta with NBT = 1 + TSEG1 + TSEG2:
//! df <= min(PS1, PS2) / (2 (13 NBT - PS2)) and df <= SJW / (20 NBT). The FDCAN (M_CAN) has no separate
//! propagation segment, so PS1 is TSEG1 less the quanta the bus's round-trip delay needs.
//!
//! FDCAN_NBTP (RM0440): NSJW\[31:25\], NBRP\[24:16\], NTSEG1\[15:8\], NTSEG2\[6:0\], each holding its value minus one.

/// Nominal bit timing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BitTiming {
    /// Kernel clock divider, 1..=512.
    pub prescaler: u16,
    /// Time segment 1 (propagation + phase segment 1), in tq, 1..=255.
    pub tseg1: u8,
    /// Time segment 2 (phase segment 2), in tq, 1..=128.
    pub tseg2: u8,
    /// Resynchronisation jump width, in tq, 1..=128, at most TSEG2.
    pub sjw: u8,
}

/// Why no timing was found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimingError {
    /// The kernel clock is not a whole number of 8..=25 quanta per bit at any prescaler.
    NoQuanta,
    /// The bus delay leaves no phase segment 1.
    NoPhaseSegment,
}

/// The least and most time quanta per bit taken (CiA's advice: 8 to 25).
const MIN_QUANTA: u32 = 8;
const MAX_QUANTA: u32 = 25;

impl BitTiming {
    /// Time quanta per bit.
    pub const fn quanta(&self) -> u32 {
        1 + self.tseg1 as u32 + self.tseg2 as u32
    }

    /// The bit rate at `kernel_hz`, rounded down.
    pub const fn bitrate(&self, kernel_hz: u32) -> u32 {
        kernel_hz / (self.prescaler as u32 * self.quanta())
    }

    /// The sample point, in thousandths of the bit.
    pub const fn sample_point_permille(&self) -> u32 {
        1000 * (1 + self.tseg1 as u32) / self.quanta()
    }

    /// Quanta the round trip `bus_delay_ns` takes at `kernel_hz`, rounded up.
    pub const fn propagation_quanta(&self, kernel_hz: u32, bus_delay_ns: u32) -> u32 {
        (bus_delay_ns as u64 * kernel_hz as u64).div_ceil(self.prescaler as u64 * 1_000_000_000) as u32
    }

    /// The clock error each node may have, in parts per million, on a bus with a round-trip delay of
    /// `bus_delay_ns`: the smaller of ISO 11898-1's two conditions (module documentation). 0 when the delay
    /// leaves no phase segment 1.
    pub const fn tolerance_ppm(&self, kernel_hz: u32, bus_delay_ns: u32) -> u32 {
        let propagation = self.propagation_quanta(kernel_hz, bus_delay_ns);
        let ps1 = (self.tseg1 as u32).saturating_sub(propagation);
        let ps2 = self.tseg2 as u32;
        let nbt = self.quanta() as u64;
        let phase = if ps1 < ps2 { ps1 } else { ps2 } as u64;
        let resync = phase * 1_000_000 / (2 * (13 * nbt - ps2 as u64));
        let jump = self.sjw as u64 * 1_000_000 / (20 * nbt);
        (if resync < jump { resync } else { jump }) as u32
    }

    /// The FDCAN_NBTP value.
    pub const fn nbtp(&self) -> u32 {
        ((self.sjw as u32 - 1) << 25)
            | ((self.prescaler as u32 - 1) << 16)
            | ((self.tseg1 as u32 - 1) << 8)
            | (self.tseg2 as u32 - 1)
    }

    /// Whether every field is in its register range and SJW at most TSEG2.
    pub const fn is_valid(&self) -> bool {
        self.prescaler >= 1
            && self.prescaler <= 512
            && self.tseg1 >= 1
            && self.tseg2 >= 1
            && self.tseg2 <= 128
            && self.sjw >= 1
            && self.sjw <= 128
            && self.sjw <= self.tseg2
    }
}

/// The nominal timing for `bitrate` at `kernel_hz`: the smallest prescaler giving a whole number of 8..=25 quanta
/// (so each quantum is as fine as the clock allows), the sample point as near `sample_point_permille` as the
/// quanta allow, and SJW as large as phase segments 1 and 2 (left after `bus_delay_ns` of round trip) allow.
pub const fn nominal(
    kernel_hz: u32,
    bitrate: u32,
    sample_point_permille: u32,
    bus_delay_ns: u32,
) -> Result<BitTiming, TimingError> {
    if bitrate == 0 {
        return Err(TimingError::NoQuanta);
    }
    let mut prescaler: u32 = 1;
    while prescaler <= 512 {
        let per_bit = prescaler * bitrate;
        if kernel_hz.is_multiple_of(per_bit) {
            let quanta = kernel_hz / per_bit;
            if quanta >= MIN_QUANTA && quanta <= MAX_QUANTA {
                // 1 + TSEG1 = SP * NBT, rounded to the nearest quantum; TSEG2 at least 1.
                let before = (sample_point_permille * quanta + 500) / 1000;
                let tseg1 = if before >= quanta { quanta - 2 } else { before - 1 };
                let tseg2 = quanta - 1 - tseg1;
                let mut timing = BitTiming {
                    prescaler: prescaler as u16,
                    tseg1: tseg1 as u8,
                    tseg2: tseg2 as u8,
                    sjw: 1,
                };
                let ps1 = tseg1.saturating_sub(timing.propagation_quanta(kernel_hz, bus_delay_ns));
                if ps1 == 0 {
                    return Err(TimingError::NoPhaseSegment);
                }
                timing.sjw = (if ps1 < tseg2 { ps1 } else { tseg2 }) as u8;
                return Ok(timing);
            }
        }
        prescaler += 1;
    }
    Err(TimingError::NoQuanta)
}

/// The battery bus: 1 Mbit/s (the BAT board's, iCub CAN).
pub const BITRATE: u32 = 1_000_000;
/// Sample point aimed at: 80 %, within the 75..=90 % CiA 301 and most 1 Mbit/s networks use.
pub const SAMPLE_POINT_PERMILLE: u32 = 800;
/// Round-trip bus delay budget: twice (5 m of cable at 5 ns/m + 2 x 75 ns through a 3.3 V transceiver such as the
/// SN65HVD230, its typical driver and receiver delays), rounded up to 400 ns. An assumption about the vehicle's
/// harness: measure it if the bus grows.
pub const BUS_DELAY_NS: u32 = 400;
/// What a crystal-clocked node's frequency error stays within (crystal tolerance, temperature and ageing): an
/// allowance for the NUCLEO's 24 MHz crystal, whose part is not in the documents read here.
pub const CRYSTAL_PPM: u32 = 100;
/// HSI16's accuracy (DS12589 features: +-1 %).
pub const HSI16_PPM: u32 = 10_000;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::FDCAN_KERNEL_HZ;
    use stm32_metapac::can::regs::Nbtp;

    #[test]
    fn the_master_timing_from_the_crystal() {
        let timing = nominal(FDCAN_KERNEL_HZ, BITRATE, SAMPLE_POINT_PERMILLE, BUS_DELAY_NS).unwrap();
        assert_eq!(
            timing,
            BitTiming {
                prescaler: 1,
                tseg1: 18,
                tseg2: 5,
                sjw: 5
            }
        );
        assert!(timing.is_valid());
        assert_eq!(timing.bitrate(FDCAN_KERNEL_HZ), BITRATE);
        assert_eq!(timing.quanta(), 24);
        assert_eq!(timing.sample_point_permille(), 791);
        // 0.81 % per node: eighty times the crystal's error allowance; still short of HSI16's 1 %.
        let tolerance = timing.tolerance_ppm(FDCAN_KERNEL_HZ, BUS_DELAY_NS);
        assert_eq!(tolerance, 8_143);
        assert!(tolerance >= 10 * CRYSTAL_PPM);
        assert!(tolerance < HSI16_PPM, "the crystal is still needed");
    }

    #[test]
    fn embassys_timing_does_not_tolerate_hsi16() {
        // embassy-stm32 0.6 at the old 85 MHz PLL Q clock: 5 tq, prescaler 17, TSEG1 3, TSEG2 1, SJW 1.
        let embassy = BitTiming {
            prescaler: 17,
            tseg1: 3,
            tseg2: 1,
            sjw: 1,
        };
        assert_eq!(embassy.bitrate(85_000_000), BITRATE);
        assert_eq!(embassy.tolerance_ppm(85_000_000, BUS_DELAY_NS), 7_812);
        assert!(embassy.tolerance_ppm(85_000_000, BUS_DELAY_NS) < HSI16_PPM);
        // More quanta alone do not rescue HSI16: this module's rule at the same clock takes 17 tq and SJW 3, and
        // tolerates less (PS2 is a smaller share of the bit). The crystal is the fix.
        let ours = nominal(85_000_000, BITRATE, SAMPLE_POINT_PERMILLE, BUS_DELAY_NS).unwrap();
        assert_eq!((ours.prescaler, ours.quanta(), ours.tseg2, ours.sjw), (5, 17, 3, 3));
        assert_eq!(ours.sample_point_permille(), 823);
        assert_eq!(ours.tolerance_ppm(85_000_000, BUS_DELAY_NS), 6_880);
    }

    #[test]
    fn tolerance_follows_the_two_conditions() {
        // Bosch's worked figures for a 10-tq bit with PS1 = PS2 = 4, SJW 4 and no propagation: condition I gives
        // 4 / (2 * (130 - 4)) = 1.587 %, condition II 4 / 200 = 2 %.
        let timing = BitTiming {
            prescaler: 1,
            tseg1: 5,
            tseg2: 4,
            sjw: 4,
        };
        // 1 tq of propagation at 10 MHz is 100 ns.
        assert_eq!(timing.tolerance_ppm(10_000_000, 100), 15_873);
        // SJW 1 makes condition II the limit: 1 / 200.
        assert_eq!(BitTiming { sjw: 1, ..timing }.tolerance_ppm(10_000_000, 100), 5_000);
        // A delay that eats TSEG1 leaves nothing.
        assert_eq!(timing.tolerance_ppm(10_000_000, 1_000), 0);
    }

    #[test]
    fn impossible_requests_are_refused() {
        assert_eq!(nominal(FDCAN_KERNEL_HZ, 0, 800, 0), Err(TimingError::NoQuanta));
        // 24 MHz is not a whole number of quanta per bit at 7 Mbit/s.
        assert_eq!(nominal(FDCAN_KERNEL_HZ, 7_000_000, 800, 0), Err(TimingError::NoQuanta));
        // 4 us of round trip at 1 Mbit/s.
        assert_eq!(
            nominal(FDCAN_KERNEL_HZ, BITRATE, 800, 4_000),
            Err(TimingError::NoPhaseSegment)
        );
        // Other bit rates from the crystal.
        for bitrate in [125_000, 250_000, 500_000] {
            let timing = nominal(FDCAN_KERNEL_HZ, bitrate, 875, BUS_DELAY_NS).unwrap();
            assert!(timing.is_valid());
            assert_eq!(timing.bitrate(FDCAN_KERNEL_HZ), bitrate);
        }
    }

    #[test]
    fn field_positions_agree_with_the_pac() {
        let timing = nominal(FDCAN_KERNEL_HZ, BITRATE, SAMPLE_POINT_PERMILLE, BUS_DELAY_NS).unwrap();
        let mut reg = Nbtp(0);
        reg.set_nsjw(timing.sjw - 1);
        reg.set_nbrp(timing.prescaler - 1);
        reg.set_ntseg1(timing.tseg1 - 1);
        reg.set_ntseg2(timing.tseg2 - 1);
        assert_eq!(timing.nbtp(), reg.0);
    }
}
