//! The clock tree both images run, and the kernel clocks the other modules compute timings from.
//!
//! SYSCLK is 170 MHz from the NUCLEO-G431RB's 24 MHz crystal (X3 on MB1367, fitted; embassy-stm32's own G4
//! examples for this board family run HSE 24 MHz / 6 * 85 / 2 the same way). HSI16 is specified at only +-1 %
//! (DS12589 features list), too loose for 1 Mbit/s CAN (see [`crate::fdcan`]), so the PLL runs from the crystal.
//! HCLK is SYSCLK; PCLK1 = PCLK2 = 85 MHz (APB /2), so the timers run at 170 MHz. embassy-stm32 switches to the PLL
//! with AHB /2 and APB /1 ([`embassy_clocks!`](crate::embassy_clocks)), and
//! [`boost_to_170_mhz!`](crate::boost_to_170_mhz) finishes RM0440's sequence after it (docs/hardware.md, "The switch
//! to 170 MHz").

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

/// SYSCLK, the PLL's R output: 170 MHz.
pub const SYSCLK_HZ: u32 = PLL.r_hz(HSE_HZ);

/// An APB prescaler's divisor: PPRE1 / PPRE2 (RM0440 7.4.3) as 1, 2, 4, 8 or 16.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ApbDivisor(pub u32);

/// A bus's peripheral clock, PCLK = HCLK / the APB prescaler (RM0440 7.2, figure "Clock tree").
pub const fn pclk_hz(hclk_hz: u32, ppre: ApbDivisor) -> u32 {
    hclk_hz / ppre.0
}

/// The clock of the timers on a bus: PCLK when its APB prescaler is 1, else twice PCLK (RM0440 7.2, "Timer
/// clock"). The G4 has no TIMPRE bit to change that.
pub const fn timer_hz(hclk_hz: u32, ppre: ApbDivisor) -> u32 {
    let pclk = pclk_hz(hclk_hz, ppre);
    if ppre.0 == 1 { pclk } else { 2 * pclk }
}

/// HCLK while embassy-stm32 switches to the PLL and for at least 1 us after (AHB /2, RM0440 6.1.5): what embassy's
/// record of the clocks holds as HCLK, PCLK1, PCLK2 and both buses' timer clocks (APB /1 then).
pub const SWITCH_HCLK_HZ: u32 = SYSCLK_HZ / 2;

/// The APB prescalers during the switch: /1, so PCLK = timer clock = [`SWITCH_HCLK_HZ`].
pub const SWITCH_APB: ApbDivisor = ApbDivisor(1);

/// HCLK once the switch is done ([`boost_to_170_mhz!`](crate::boost_to_170_mhz)): AHB /1, SYSCLK.
pub const HCLK_HZ: u32 = SYSCLK_HZ;

/// The APB prescalers once the switch is done: /2, so PCLK1 = PCLK2 stay at what embassy recorded.
pub const APB: ApbDivisor = ApbDivisor(2);

/// PCLK1 = PCLK2: 85 MHz, the same before and after the AHB prescaler goes to /1, so every kernel clock embassy
/// computed from its record (LPUART1's, on PCLK1) holds.
pub const PCLK_HZ: u32 = pclk_hz(HCLK_HZ, APB);

/// Both buses' timer clocks once the switch is done: 2 x PCLK = 170 MHz, twice what embassy recorded.
pub const TIMER_HZ: u32 = timer_hz(HCLK_HZ, APB);

/// TIM1's clock, on APB2.
pub const TIM1_HZ: u32 = TIMER_HZ;

/// The clock of embassy-stm32's time driver, TIM15 on APB2 (the workspace's `time-driver-tim15`).
pub const TIME_DRIVER_HZ: u32 = TIMER_HZ;

/// What embassy-stm32 recorded as the time driver's clock, and set its prescaler for.
pub const TIME_DRIVER_RECORDED_HZ: u32 = timer_hz(SWITCH_HCLK_HZ, SWITCH_APB);

/// The I2C kernel clock: HSI16 (RCC_CCIPR I2CxSEL = 10), independent of SYSCLK, so the I2C timing of
/// [`crate::i2c`] holds whatever the system clock is.
pub const I2C_KERNEL_HZ: u32 = HSI16_HZ;

/// The FDCAN kernel clock: HSE, FDCANSEL's reset value (RCC_CCIPR FDCANSEL = 00).
pub const FDCAN_KERNEL_HZ: u32 = HSE_HZ;

/// The ADC12 kernel clock: SYSCLK (RCC_CCIPR ADC12SEL = 10), 170 MHz whatever the AHB prescaler; embassy records
/// it as SYSCLK too.
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

/// TIMx_PSC for a counter ticking at `tick_hz` from a `timer_hz` clock, f_CK_CNT = f_CK_PSC / (PSC + 1) (RM0440
/// 30.4, TIM15's prescaler): `timer_hz / tick_hz - 1`, as embassy-stm32's time driver computes it. `None` unless the
/// tick divides the clock exactly and the prescaler fits its 16 bits.
pub const fn tick_psc(timer_hz: u32, tick_hz: u64) -> Option<u16> {
    let timer_hz = timer_hz as u64;
    if tick_hz == 0 || !timer_hz.is_multiple_of(tick_hz) || timer_hz < tick_hz {
        return None;
    }
    let psc = timer_hz / tick_hz - 1;
    if psc > u16::MAX as u64 { None } else { Some(psc as u16) }
}

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
        // AHB /2 through the switch (RM0440 6.1.5), APB /1: embassy switches SYSCLK to the PLL with HCLK at
        // 85 MHz and records 85 MHz for HCLK, both PCLKs and the timers; `boost_to_170_mhz!` goes on from there.
        config.rcc.ahb_pre = embassy_stm32::rcc::AHBPrescaler::from_bits($crate::clock::registers::HPRE_DIV2 as u8);
        config.rcc.apb1_pre = embassy_stm32::rcc::APBPrescaler::from_bits($crate::clock::registers::PPRE_SWITCH as u8);
        config.rcc.apb2_pre = embassy_stm32::rcc::APBPrescaler::from_bits($crate::clock::registers::PPRE_SWITCH as u8);
        config.rcc.boost = true;
        config
    }};
}

/// RM0440's switch to range 1 boost mode (6.1.5), made again after `embassy_stm32::init` from
/// [`embassy_clocks!`](crate::embassy_clocks) left SYSCLK on the PLL at AHB /2 in range 1 *normal* mode:
/// embassy-stm32 0.6 resets PWR in `init` (so R1MODE cannot be cleared before it) and then clears the wrong bit
/// ([`registers::PWR_CR5_R1MODE`]). Expanded in a binding right after `init`, with embassy's time driver (TIM15)
/// held still throughout: SYSCLK back to HSI16 (AHB /2 kept), R1MODE cleared, SYSCLK to the PLL again at AHB /2,
/// at least 1 us, the flash wait states for 170 MHz, then in one RCC_CFGR write AHB /1 and both APB prescalers /2
/// (HCLK 170 MHz, PCLK1 = PCLK2 = 85 MHz as embassy recorded them, the timers at 170 MHz), and TIM15's prescaler
/// reloaded for its doubled clock, its count kept. Evaluates to whether TIM15's prescaler was the one embassy
/// computes for [`TIME_DRIVER_RECORDED_HZ`] (false: its tick is not what this assumes, and the binding says so).
///
/// [`registers::PWR_CR5_R1MODE`]: crate::clock::registers::PWR_CR5_R1MODE
/// [`TIME_DRIVER_RECORDED_HZ`]: crate::clock::TIME_DRIVER_RECORDED_HZ
#[macro_export]
macro_rules! boost_to_170_mhz {
    () => {{
        use embassy_stm32::pac;
        use pac::rcc::regs::Cfgr;
        use $crate::clock::registers as regs;
        const PSC: u16 = match $crate::clock::tick_psc($crate::clock::TIME_DRIVER_HZ, embassy_time::TICK_HZ) {
            Some(psc) => psc,
            None => panic!("the time driver's tick does not divide its clock"),
        };
        const RECORDED_PSC: Option<u16> =
            $crate::clock::tick_psc($crate::clock::TIME_DRIVER_RECORDED_HZ, embassy_time::TICK_HZ);
        let tim = pac::TIM15;
        let recorded = tim.psc().read();
        cortex_m::interrupt::free(|_| {
            // The time driver's counter stops while the clocks change and its new prescaler is loaded: its count
            // is kept, the few microseconds of the switch are lost once.
            tim.cr1().modify(|w| w.set_cen(false));
            let count = tim.cnt().read().cnt();
            // RM0440 7.2.7: back to HSI16 (AHB /2 kept from `init`), to leave range 1 normal mode below 150 MHz.
            pac::RCC
                .cfgr()
                .modify(|w| *w = Cfgr(regs::cfgr_with_sw(w.0, regs::SW_HSI16)));
            while regs::sws(pac::RCC.cfgr().read().0) != regs::SW_HSI16 {}
            // RM0440 6.1.5 steps 1 and 2 (6.4.19): at AHB /2, R1MODE = 0, range 1 boost mode.
            pac::PWR
                .cr5()
                .modify(|w| *w = pac::pwr::regs::Cr5(regs::pwr_cr5_boost(w.0)));
            // Steps 3 and 4: the wait states embassy set hold for HCLK = 85 MHz; SYSCLK to the PLL at AHB /2.
            pac::RCC
                .cfgr()
                .modify(|w| *w = Cfgr(regs::cfgr_with_sw(w.0, regs::SW_PLL)));
            while regs::sws(pac::RCC.cfgr().read().0) != regs::SW_PLL {}
            // Step 5: at least 1 us at AHB /2.
            cortex_m::asm::delay(regs::SETTLE_CYCLES);
            // RM0440 3.3.3: the wait states for the faster HCLK first, read back before it rises.
            pac::FLASH
                .acr()
                .modify(|w| w.set_latency(pac::flash::vals::Latency::from_bits(regs::LATENCY as u8)));
            while u32::from(pac::FLASH.acr().read().latency().to_bits()) != regs::LATENCY {}
            // RM0440 7.4.3: AHB /1 and APB1 = APB2 = /2 in one write, so no PCLK ever leaves 85 MHz.
            pac::RCC.cfgr().modify(|w| *w = Cfgr(regs::cfgr_boosted(w.0)));
            // RM0440 30 (TIM15): PSC is preloaded and taken at an update event; UG makes one, and with URS set it
            // raises no UIF, which the driver would count as an overflow. UG clears the counter: it is put back.
            tim.psc().write_value(PSC);
            tim.cr1().modify(|w| w.set_urs(pac::timer::vals::Urs::COUNTER_ONLY));
            tim.egr().write(|w| w.set_ug(true));
            tim.cr1().modify(|w| w.set_urs(pac::timer::vals::Urs::ANY_EVENT));
            tim.cnt().write(|w| w.set_cnt(count));
            tim.cr1().modify(|w| w.set_cen(true));
        });
        RECORDED_PSC == Some(recorded)
    }};
}

/// The register values of this clock tree after start-up (RM0440 7.4): what `embassy_stm32::init` must leave.
pub mod registers {
    use super::{APB, ApbDivisor, HCLK_HZ, PLL, Pll, SWITCH_APB, SYSCLK_HZ};

    /// RCC_PLLCFGR with `pll` fed from HSE and only its R output on (RM0440 7.4.4): PLLSRC = 0b11 at bits 1:0,
    /// PLLM - 1 at bits 7:4, PLLN at 14:8, PLLREN at 24, PLLR = r / 2 - 1 at 26:25.
    pub const fn pllcfgr_hse(pll: Pll) -> u32 {
        0b11 | (pll.m - 1) << 4 | pll.n << 8 | 1 << 24 | (pll.r / 2 - 1) << 25
    }

    /// The PLL as both images set it.
    pub const PLLCFGR: u32 = pllcfgr_hse(PLL);

    /// RCC_CFGR.SW / SWS: the PLL's R output is the system clock (RM0440 7.4.3).
    pub const SW_PLL: u32 = 0b11;
    /// SW / SWS = 0b01: HSI16.
    pub const SW_HSI16: u32 = 0b01;

    /// `cfgr` with SW (bits 1:0) = `sw` and every other field as it was.
    pub const fn cfgr_with_sw(cfgr: u32, sw: u32) -> u32 {
        (cfgr & !0b11) | (sw & 0b11)
    }

    /// RCC_CFGR.SWS (bits 3:2): the clock the system runs from.
    pub const fn sws(cfgr: u32) -> u32 {
        (cfgr >> 2) & 0b11
    }

    /// FLASH_ACR.LATENCY for an HCLK in range 1 boost mode, the mode both images run in (RM0440 3.3.3, "Number
    /// of wait states according to CPU clock frequency"): one wait state per started 34 MHz above 34 MHz.
    pub const fn boost_flash_latency(hclk_hz: u32) -> u32 {
        hclk_hz.saturating_sub(1) / 34_000_000
    }

    /// 170 MHz: 4 wait states, set by [`boost_to_170_mhz!`](crate::boost_to_170_mhz) before HCLK rises to it.
    pub const LATENCY: u32 = boost_flash_latency(HCLK_HZ);

    /// PWR_CR5.R1MODE (bit 8, RM0440 6.4.19, reset value 0x0000_0100): 1 is range 1 normal mode (up to 150 MHz),
    /// 0 boost mode (up to 170 MHz). stm32-metapac 21 puts it at bit 0, so embassy-stm32 0.6's `set_r1mode(false)`
    /// clears a reserved bit and leaves the chip in normal mode.
    pub const PWR_CR5_R1MODE: u32 = 1 << 8;

    /// `cr5` with R1MODE clear: range 1 boost mode.
    pub const fn pwr_cr5_boost(cr5: u32) -> u32 {
        cr5 & !PWR_CR5_R1MODE
    }

    /// RCC_CFGR.HPRE (bits 7:4, RM0440 7.4.3): 0b0000 is SYSCLK not divided.
    pub const HPRE_DIV1: u32 = 0b0000;
    /// HPRE = 0b1000: SYSCLK / 2.
    pub const HPRE_DIV2: u32 = 0b1000;

    /// RCC_CFGR.PPRE1 / PPRE2 (bits 10:8 / 13:11, RM0440 7.4.3) for an APB divisor: 0b0xx is /1, 0b100 /2,
    /// 0b101 /4, 0b110 /8, 0b111 /16; `None` for any other divisor.
    pub const fn ppre(divisor: ApbDivisor) -> Option<u32> {
        match divisor.0 {
            1 => Some(0b000),
            2 => Some(0b100),
            4 => Some(0b101),
            8 => Some(0b110),
            16 => Some(0b111),
            _ => None,
        }
    }

    /// PPRE1 = PPRE2 while embassy-stm32 switches: /1.
    pub const PPRE_SWITCH: u32 = match ppre(SWITCH_APB) {
        Some(bits) => bits,
        None => panic!("not an APB divisor"),
    };
    /// PPRE1 = PPRE2 once the switch is done: /2.
    pub const PPRE: u32 = match ppre(APB) {
        Some(bits) => bits,
        None => panic!("not an APB divisor"),
    };

    /// RCC_CFGR's three prescalers (RM0440 7.4.3): HPRE at bits 7:4, PPRE1 at 10:8, PPRE2 at 13:11.
    pub const fn cfgr_prescalers(hpre: u32, ppre1: u32, ppre2: u32) -> u32 {
        (hpre & 0xF) << 4 | (ppre1 & 0b111) << 8 | (ppre2 & 0b111) << 11
    }

    /// The bits of RCC_CFGR the prescalers take.
    pub const CFGR_PRESCALERS: u32 = cfgr_prescalers(0xF, 0b111, 0b111);

    /// The prescalers embassy-stm32 switches SYSCLK to the PLL with: AHB /2, APB1 = APB2 = /1.
    pub const CFGR_SWITCH: u32 = cfgr_prescalers(HPRE_DIV2, PPRE_SWITCH, PPRE_SWITCH);

    /// The prescalers the images run with: AHB /1, APB1 = APB2 = /2.
    pub const CFGR_BOOSTED: u32 = cfgr_prescalers(HPRE_DIV1, PPRE, PPRE);

    /// `cfgr` with [`CFGR_BOOSTED`]'s prescalers and every other field (SW, MCO) as it was.
    pub const fn cfgr_boosted(cfgr: u32) -> u32 {
        (cfgr & !CFGR_PRESCALERS) | CFGR_BOOSTED
    }

    /// Core cycles that last at least `ns` at any core clock up to `fastest_hz`.
    pub const fn cycles_at_least(ns: u32, fastest_hz: u32) -> u32 {
        (ns as u64 * fastest_hz as u64).div_ceil(1_000_000_000) as u32
    }

    /// The wait at AHB /2 after the switch (RM0440 6.1.5: at least 1 us), counted at SYSCLK although the core
    /// runs at half of it then: 170 cycles, 2 us at 85 MHz.
    pub const SETTLE_CYCLES: u32 = cycles_at_least(1_000, SYSCLK_HZ);

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
    fn the_clocks_after_the_switch() {
        assert_eq!((SWITCH_HCLK_HZ, HCLK_HZ), (85_000_000, 170_000_000));
        // What embassy records at the switch (HCLK 85 MHz, APB /1) and what the chip runs after it.
        assert_eq!(pclk_hz(SWITCH_HCLK_HZ, SWITCH_APB), 85_000_000);
        assert_eq!(TIME_DRIVER_RECORDED_HZ, 85_000_000);
        assert_eq!(PCLK_HZ, pclk_hz(SWITCH_HCLK_HZ, SWITCH_APB));
        assert_eq!(
            (TIMER_HZ, TIM1_HZ, TIME_DRIVER_HZ),
            (170_000_000, 170_000_000, 170_000_000)
        );
        // embassy-stm32's rule (`calc_pclk`): the timers run at PCLK when HCLK = PCLK, else at twice PCLK.
        for divisor in [1, 2, 4, 8, 16] {
            let ppre = ApbDivisor(divisor);
            let pclk = pclk_hz(HCLK_HZ, ppre);
            let embassy = if pclk == HCLK_HZ { pclk } else { 2 * pclk };
            assert_eq!(timer_hz(HCLK_HZ, ppre), embassy, "/{divisor}");
        }
        // The ADC's kernel clock is SYSCLK, so its prescaler does not move with the AHB prescaler.
        assert_eq!(ADC_KERNEL_HZ, SYSCLK_HZ);
    }

    #[test]
    fn the_time_driver_prescaler() {
        // embassy's time driver: timer_hz / TICK_HZ - 1, at its default 1 MHz tick.
        assert_eq!(tick_psc(TIME_DRIVER_HZ, 1_000_000), Some(169));
        assert_eq!(tick_psc(TIME_DRIVER_RECORDED_HZ, 1_000_000), Some(84));
        assert_eq!(tick_psc(TIME_DRIVER_HZ, 32_768), None);
        assert_eq!(tick_psc(TIME_DRIVER_HZ, 1_000), None);
        assert_eq!(tick_psc(TIME_DRIVER_HZ, 0), None);
        assert_eq!(tick_psc(1_000_000, 2_000_000), None);
        assert_eq!(tick_psc(65_536_000, 1_000), Some(u16::MAX));
    }

    #[test]
    fn the_wait_after_the_switch_lasts_1_us_at_85_mhz() {
        use registers::{SETTLE_CYCLES, cycles_at_least};
        assert_eq!(SETTLE_CYCLES, 170);
        // 170 cycles at the 85 MHz HCLK of the switch: 2 us, twice RM0440's minimum.
        assert!(SETTLE_CYCLES as u64 * 1_000_000_000 >= 2 * 1_000 * SWITCH_HCLK_HZ as u64);
        assert_eq!(cycles_at_least(1, 170_000_000), 1);
        assert_eq!(cycles_at_least(1_000, 85_000_001), 86);
    }

    #[test]
    fn switch_registers_agree_with_the_pac() {
        use registers::*;
        use stm32_metapac::flash::vals::Latency;
        use stm32_metapac::rcc::regs::Cfgr;
        use stm32_metapac::rcc::vals::{Hpre, Ppre, Sw};
        let cfgr = |hpre, ppre| {
            let mut cfgr = Cfgr(0);
            cfgr.set_hpre(hpre);
            cfgr.set_ppre1(ppre);
            cfgr.set_ppre2(ppre);
            cfgr.0
        };
        assert_eq!(CFGR_SWITCH, cfgr(Hpre::DIV2, Ppre::DIV1));
        assert_eq!(CFGR_BOOSTED, cfgr(Hpre::DIV1, Ppre::DIV2));
        assert_eq!(CFGR_PRESCALERS, 0x3FF0);
        let ppre = [1, 2, 4, 8, 16].map(|d| ppre(ApbDivisor(d)));
        let pac = [Ppre::DIV1, Ppre::DIV2, Ppre::DIV4, Ppre::DIV8, Ppre::DIV16].map(|p| Some(p.to_bits() as u32));
        assert_eq!(ppre, pac);
        assert_eq!(registers::ppre(ApbDivisor(3)), None);
        assert_eq!(
            (HPRE_DIV1, HPRE_DIV2),
            (Hpre::DIV1.to_bits() as u32, Hpre::DIV2.to_bits() as u32)
        );
        // The switch keeps SW, SWS and MCO as they are.
        let mut running = Cfgr(CFGR_SWITCH);
        running.set_sw(Sw::PLL1_R);
        running.set_sws(Sw::PLL1_R);
        running.set_mcopre(stm32_metapac::rcc::vals::Mcopre::DIV4);
        let boosted = Cfgr(cfgr_boosted(running.0));
        assert_eq!(
            (boosted.sw(), boosted.sws(), boosted.mcopre()),
            (running.sw(), running.sws(), running.mcopre())
        );
        assert_eq!(
            (boosted.hpre(), boosted.ppre1(), boosted.ppre2()),
            (Hpre::DIV1, Ppre::DIV2, Ppre::DIV2)
        );
        assert_eq!(LATENCY, Latency::WS4.to_bits() as u32);
    }

    #[test]
    fn boost_mode_is_r1mode_at_bit_8() {
        use registers::*;
        use stm32_metapac::rcc::regs::Cfgr;
        use stm32_metapac::rcc::vals::{Hpre, Sw};
        // RM0440 6.4.19: PWR_CR5 resets to 0x0000_0100, R1MODE = 1 (range 1 normal mode).
        assert_eq!(pwr_cr5_boost(0x0000_0100), 0);
        assert_eq!(pwr_cr5_boost(0x0000_0101), 1);
        // stm32-metapac 21 has R1MODE at bit 0, the reason the images clear it themselves. Should this fail, the
        // PAC has been mended and embassy-stm32's own write may be enough.
        let mut cr5 = stm32_metapac::pwr::regs::Cr5(0x0000_0100);
        cr5.set_r1mode(false);
        assert_eq!(cr5.0, 0x0000_0100);
        // HPRE /2 as `init` leaves it, SW = SWS = HSI16.
        let mut divided = Cfgr(0);
        divided.set_hpre(Hpre::DIV2);
        divided.set_sw(Sw::HSI);
        divided.set_sws(Sw::HSI);
        // SW to the PLL and back, HPRE kept; SWS read.
        let pll = Cfgr(cfgr_with_sw(divided.0, SW_PLL));
        assert_eq!((pll.sw(), pll.hpre()), (Sw::PLL1_R, Hpre::DIV2));
        assert_eq!(Cfgr(cfgr_with_sw(pll.0, SW_HSI16)).0, divided.0);
        assert_eq!(
            (SW_HSI16, SW_PLL),
            (Sw::HSI.to_bits() as u32, Sw::PLL1_R.to_bits() as u32)
        );
        let mut running = Cfgr(0);
        running.set_sws(Sw::PLL1_R);
        assert_eq!(sws(running.0), SW_PLL);
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
