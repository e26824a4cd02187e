//! The clock tree both images run, and the kernel clocks the other modules compute timings from.
//!
//! SYSCLK is 170 MHz from the NUCLEO-G431RB's 24 MHz crystal (X3 on MB1367, fitted; embassy-stm32's own G4
//! examples for this board family run HSE 24 MHz / 6 * 85 / 2 the same way). HSI16 is specified at only +-1 %
//! (DS12589 features list), too loose for 1 Mbit/s CAN (see [`crate::fdcan`]), so the PLL runs from the crystal.

/// The NUCLEO-G431RB's HSE crystal, X3, 24 MHz (from public board tables; see [`crate::pins::NUCLEO_G431RB`]).
pub const HSE_HZ: u32 = 24_000_000;
/// The internal 16 MHz RC oscillator.
pub const HSI16_HZ: u32 = 16_000_000;

/// PLL dividers: f_VCO = f_in / m * n, f_R = f_VCO / r.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pll {
    /// Input divider PLLM, 1..=16.
    pub m: u32,
    /// VCO multiplier PLLN, 8..=127.
    pub n: u32,
    /// R output divider PLLR: 2, 4, 6 or 8.
    pub r: u32,
}

impl Pll {
    /// VCO input frequency.
    pub const fn vco_input_hz(&self, input_hz: u32) -> u32 {
        input_hz / self.m
    }

    /// VCO output frequency.
    pub const fn vco_hz(&self, input_hz: u32) -> u32 {
        self.vco_input_hz(input_hz) * self.n
    }

    /// The R output, SYSCLK.
    pub const fn r_hz(&self, input_hz: u32) -> u32 {
        self.vco_hz(input_hz) / self.r
    }

    /// Whether the dividers are in their register ranges and every frequency in RM0440's limits (RCC_PLLCFGR):
    /// VCO input 2.66..=16 MHz, VCO output 96..=344 MHz, R output at most 170 MHz, and the input an exact multiple
    /// of M (so the frequencies above are exact).
    pub const fn is_valid(&self, input_hz: u32) -> bool {
        let dividers = self.m >= 1
            && self.m <= 16
            && self.n >= 8
            && self.n <= 127
            && matches!(self.r, 2 | 4 | 6 | 8)
            && input_hz.is_multiple_of(self.m);
        if !dividers {
            return false;
        }
        let vco_in = self.vco_input_hz(input_hz);
        let vco = self.vco_hz(input_hz);
        vco_in >= 2_660_000
            && vco_in <= 16_000_000
            && vco >= 96_000_000
            && vco <= 344_000_000
            && self.r_hz(input_hz) <= 170_000_000
    }
}

/// The PLL both images run: 24 MHz / 6 * 85 / 2 = 170 MHz.
pub const PLL: Pll = Pll { m: 6, n: 85, r: 2 };

/// SYSCLK = HCLK = PCLK1 = PCLK2 (AHB and APB prescalers 1, embassy-stm32's defaults).
pub const SYSCLK_HZ: u32 = PLL.r_hz(HSE_HZ);

/// TIM1's clock: PCLK2 with APB2 prescaler 1, so the timer runs at SYSCLK (RM0440 RCC: timer clocks are PCLK when
/// the APB prescaler is 1).
pub const TIM1_HZ: u32 = SYSCLK_HZ;

/// The I2C kernel clock: HSI16 (RCC_CCIPR I2CxSEL = 10), independent of SYSCLK, so the I2C timing of
/// [`crate::i2c`] holds whatever the system clock is.
pub const I2C_KERNEL_HZ: u32 = HSI16_HZ;

/// The FDCAN kernel clock: HSE, FDCANSEL's reset value (RCC_CCIPR FDCANSEL = 00).
pub const FDCAN_KERNEL_HZ: u32 = HSE_HZ;

/// The ADC12 kernel clock: SYSCLK (RCC_CCIPR ADC12SEL = 10).
pub const ADC_KERNEL_HZ: u32 = SYSCLK_HZ;

/// The fastest ADC clock of the STM32G431 (DS12589 ADC characteristics: f_ADC at most 60 MHz).
pub const ADC_MAX_HZ: u32 = 60_000_000;

/// The ADC_CCR PRESC divisors, in the order of their register values 0..=11 (RM0440 ADC_CCR).
const ADC_DIVISORS: [u32; 12] = [1, 2, 4, 6, 8, 10, 12, 16, 32, 64, 128, 256];

/// The smallest ADC_CCR PRESC divisor that brings `kernel_hz` to at most [`ADC_MAX_HZ`], with its register value;
/// `None` when even /256 is too fast. embassy-stm32 0.6's `Adc::new` picks its prescaler by this same rule
/// (`from_ker_ck` in its `adc/g4.rs`), so this is the ADC clock the firmware gets.
pub const fn adc_prescaler(kernel_hz: u32) -> Option<(u8, u32)> {
    let mut bits = 0;
    let mut rest: &[u32] = &ADC_DIVISORS;
    while let [divisor, tail @ ..] = rest {
        if kernel_hz as u64 <= ADC_MAX_HZ as u64 * *divisor as u64 {
            return Some((bits, *divisor));
        }
        bits += 1;
        rest = tail;
    }
    None
}

/// The ADC clock of both images: ADC_KERNEL_HZ / 4 = 42.5 MHz.
pub const ADC_HZ: u32 = match adc_prescaler(ADC_KERNEL_HZ) {
    Some((_, divisor)) => ADC_KERNEL_HZ / divisor,
    None => 0,
};

/// The LSI oscillator that clocks the independent watchdog: 32 kHz nominal. Its spread over voltage and
/// temperature is taken as 29.5..=34 kHz; DS12589's LSI table could not be read here, so these bounds are the
/// STM32G4 figures as commonly quoted (ST community, embassy-stm32 uses 32 kHz nominal): confirm against DS12589
/// before relying on the watchdog's margins.
pub const LSI_HZ: u32 = 32_000;
/// Slowest LSI, see [`LSI_HZ`].
pub const LSI_MIN_HZ: u32 = 29_500;
/// Fastest LSI, see [`LSI_HZ`].
pub const LSI_MAX_HZ: u32 = 34_000;

/// embassy-stm32's configuration of this clock tree ([`PLL`] from the crystal, SYSCLK from its R output, range 1
/// boost mode), which both bindings start from and add their kernel-clock muxes to. A macro, expanded in the
/// binding, which has embassy-stm32 for its chip; this crate does not depend on it.
#[macro_export]
macro_rules! embassy_clocks {
    () => {{
        use embassy_stm32::rcc::{Hse, HseMode, Pll, PllMul, PllPreDiv, PllRDiv, PllSource, Sysclk};
        const PLL: $crate::clock::Pll = $crate::clock::PLL;
        const _: () = assert!(PLL.is_valid($crate::clock::HSE_HZ));
        let mut config = embassy_stm32::Config::default();
        config.rcc.hse = Some(Hse {
            freq: embassy_stm32::time::Hertz($crate::clock::HSE_HZ),
            mode: HseMode::Oscillator,
        });
        config.rcc.pll = Some(Pll {
            source: PllSource::HSE,
            prediv: PllPreDiv::from_bits((PLL.m - 1) as u8),
            mul: PllMul::from_bits(PLL.n as u8),
            divp: None,
            divq: None,
            divr: Some(PllRDiv::from_bits((PLL.r / 2 - 1) as u8)),
        });
        config.rcc.sys = Sysclk::PLL1_R;
        config.rcc.boost = true;
        config
    }};
}

/// The register values of this clock tree after start-up (RM0440 7.4): what `embassy_stm32::init` must leave.
pub mod registers {
    use super::{PLL, Pll, SYSCLK_HZ};

    /// RCC_PLLCFGR with `pll` fed from HSE and only its R output on (RM0440 7.4.4): PLLSRC = 0b11 at bits 1:0,
    /// PLLM - 1 at bits 7:4, PLLN at 14:8, PLLREN at 24, PLLR = r / 2 - 1 at 26:25.
    pub const fn pllcfgr_hse(pll: Pll) -> u32 {
        0b11 | (pll.m - 1) << 4 | pll.n << 8 | 1 << 24 | (pll.r / 2 - 1) << 25
    }

    /// The PLL as both images set it.
    pub const PLLCFGR: u32 = pllcfgr_hse(PLL);

    /// RCC_CFGR.SW / SWS: the PLL's R output is the system clock (RM0440 7.4.3).
    pub const SW_PLL: u32 = 0b11;

    /// FLASH_ACR.LATENCY for an HCLK in range 1 boost mode, the mode both images run in (RM0440 3.3.3, "Number
    /// of wait states according to CPU clock frequency"): one wait state per started 34 MHz above 34 MHz.
    pub const fn boost_flash_latency(hclk_hz: u32) -> u32 {
        hclk_hz.saturating_sub(1) / 34_000_000
    }

    /// 170 MHz: 4 wait states.
    pub const LATENCY: u32 = boost_flash_latency(SYSCLK_HZ);

    /// RCC_CCIPR kernel-clock fields (RM0440 7.4.26): position of each mux and the value selecting a source.
    pub const I2C1SEL: u32 = 12;
    /// I2C2's mux.
    pub const I2C2SEL: u32 = 14;
    /// I2C3's mux.
    pub const I2C3SEL: u32 = 16;
    /// FDCAN's mux.
    pub const FDCANSEL: u32 = 24;
    /// ADC1/2's mux.
    pub const ADC12SEL: u32 = 28;
    /// I2CxSEL = 0b10: HSI16.
    pub const I2C_HSI16: u32 = 0b10;
    /// FDCANSEL = 0b00: HSE.
    pub const FDCAN_HSE: u32 = 0b00;
    /// ADC12SEL = 0b10: SYSCLK.
    pub const ADC_SYSCLK: u32 = 0b10;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pll_gives_170_mhz_within_rm0440_limits() {
        assert!(PLL.is_valid(HSE_HZ));
        assert_eq!(PLL.vco_input_hz(HSE_HZ), 4_000_000);
        assert_eq!(PLL.vco_hz(HSE_HZ), 340_000_000);
        assert_eq!(SYSCLK_HZ, 170_000_000);
        // The old HSI set-up (16 MHz / 4 * 85 / 2) was valid too; the reason to leave it is CAN, not the PLL.
        assert!(Pll { m: 4, n: 85, r: 2 }.is_valid(HSI16_HZ));
    }

    #[test]
    fn pll_limits_are_enforced() {
        // VCO above 344 MHz, SYSCLK above 170 MHz, VCO input below 2.66 MHz, bad R, inexact M.
        assert!(!Pll { m: 6, n: 87, r: 2 }.is_valid(HSE_HZ));
        assert!(!Pll { m: 6, n: 86, r: 2 }.is_valid(HSE_HZ));
        assert!(!Pll { m: 12, n: 100, r: 2 }.is_valid(HSE_HZ));
        assert!(!Pll { m: 6, n: 85, r: 3 }.is_valid(HSE_HZ));
        assert!(!Pll { m: 7, n: 85, r: 2 }.is_valid(HSE_HZ));
        assert!(!Pll { m: 0, n: 85, r: 2 }.is_valid(HSE_HZ));
    }

    #[test]
    fn adc_clock_is_what_embassy_picks() {
        // embassy-stm32 0.6: raw = (f - 1) / 60 MHz; 0 -> /1, 1 -> /2, 2..=3 -> /4, 4..=5 -> /6 ...
        let embassy = |f: u32| match (f - 1) / ADC_MAX_HZ {
            0 => 1,
            1 => 2,
            2..=3 => 4,
            4..=5 => 6,
            6..=7 => 8,
            8..=9 => 10,
            _ => 12,
        };
        for f in [
            16_000_000,
            60_000_000,
            60_000_001,
            120_000_000,
            150_000_000,
            170_000_000,
            240_000_000,
        ] {
            assert_eq!(adc_prescaler(f).map(|(_, d)| d), Some(embassy(f)), "{f}");
        }
        assert_eq!(adc_prescaler(170_000_000), Some((2, 4)));
        assert_eq!(ADC_HZ, 42_500_000);
        assert_eq!(adc_prescaler(u32::MAX).map(|(_, d)| d), Some(128));
    }

    #[test]
    fn start_up_registers_agree_with_the_pac() {
        use registers::*;
        use stm32_metapac::flash::vals::Latency;
        use stm32_metapac::rcc::regs::{Ccipr, Pllcfgr};
        use stm32_metapac::rcc::vals::{Adcsel, Fdcansel, I2csel, Pllm, Plln, Pllr, Pllsrc};
        let mut pllcfgr = Pllcfgr(0);
        pllcfgr.set_pllsrc(Pllsrc::HSE);
        pllcfgr.set_pllm(Pllm::DIV6);
        pllcfgr.set_plln(Plln::MUL85);
        pllcfgr.set_pllr(Pllr::DIV2);
        pllcfgr.set_pllren(true);
        assert_eq!(PLLCFGR, pllcfgr.0);
        let mut ccipr = Ccipr(0);
        ccipr.set_i2c1sel(I2csel::HSI);
        ccipr.set_i2c3sel(I2csel::HSI);
        ccipr.set_fdcansel(Fdcansel::HSE);
        ccipr.set_adc12sel(Adcsel::SYS);
        assert_eq!(
            ccipr.0,
            I2C_HSI16 << I2C1SEL | I2C_HSI16 << I2C3SEL | FDCAN_HSE << FDCANSEL | ADC_SYSCLK << ADC12SEL
        );
        assert_eq!(LATENCY, Latency::WS4.to_bits() as u32);
        // The table's edges (34 / 68 / 102 / 136 MHz), as embassy-stm32's G4 clock set-up has them too.
        let latency = [34, 35, 68, 69, 102, 136, 137, 170].map(|mhz| boost_flash_latency(mhz * 1_000_000));
        assert_eq!(latency, [0, 1, 1, 2, 2, 3, 4, 4]);
    }
}
