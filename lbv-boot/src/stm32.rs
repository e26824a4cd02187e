//! The bootloader on the chip: the watchdog started first, the flash through embassy-stm32's blocking driver, the
//! check and embassy-boot's preparation ([`lbv_boot::prepare`]) on the board's partitions with the watchdog fed
//! between every flash operation, and the jump to ACTIVE.
//!
//! It never calls `embassy_stm32::init`: the image it starts finds the chip as the reset left it (the clocks on
//! HSI16, RCC_CSR's reset flags still set for it to read), but for the watchdog started here, the flash
//! interface, locked again after every operation, and the backup domain, opened to count early crashes.

use cortex_m::peripheral::SCB;
use embassy_boot_stm32::BootLoader;
use embassy_stm32::flash::Flash;
use embassy_stm32::pac;
use embassy_stm32::peripherals::IWDG;
use g431_hw::backup::{APB1ENR1_BACKUP, CRASH_REGISTER, PWR_CR1_DBP, watchdog_reset};
use g431_hw::flash::{self, NmiAction};
use g431_hw::iwdg::{BOOT_TRIAL, DBGMCU_APB1FZR1};
use g431_hw::memory::{Partitions, Span};
use lbv_boot::{CrashCount, Outcome, State};

/// The board's partitions.
#[cfg(feature = "thruster")]
const LAYOUT: Partitions = g431_hw::memory::THRUSTER_PARTITIONS;
#[cfg(feature = "master")]
const LAYOUT: Partitions = g431_hw::memory::MASTER_PARTITIONS;

#[cortex_m_rt::entry]
fn main() -> ! {
    // SAFETY: the bootloader is the only code running and takes each peripheral once, through its description
    // (`g431_hw::images`); `embassy_stm32::init`, which it skips, would only have checked that.
    #[allow(unsafe_code)]
    let chip = unsafe { embassy_stm32::Peripherals::steal() };
    let chip = g431_hw::chip!(boot_image, chip);
    #[cfg(feature = "thruster")]
    hold_gates_off();
    // The watchdog first: a swap or a check that hangs resets the chip, and the next start resumes it.
    start_trial_watchdog(chip.watchdog);
    let feed = || pac::IWDG.kr().write(|w| w.set_key(pac::iwdg::vals::Key::RESET));
    let crashes = count_crashes();
    let state = match lbv_boot::prepare(Flash::new_blocking(chip.flash), &LAYOUT, crashes, feed) {
        Outcome::Prepared { state, .. } => state,
        // The previous image back, for it to tell; the count starts again.
        Outcome::Restored { .. } => {
            keep_count(CrashCount {
                crashes: 0,
                restored: true,
            });
            State::Revert
        }
        // The image that ran, its update refused (the verdict is in the record for it to tell).
        Outcome::Refused { .. } => State::Boot,
        // ACTIVE as it is: `prepare` says why that is the safe choice.
        Outcome::Failed(_) => State::Boot,
    };
    // The image starts with the whole trial timeout before it.
    feed();
    // SAFETY: ACTIVE starts with the vector table of an image linked there (g431_hw::memory::THRUSTER, MASTER); `load` sets
    // VTOR to it, loads its initial stack pointer and jumps to its reset handler, and nothing of the bootloader is
    // used after that (the image's start-up initialises its own RAM).
    #[allow(unsafe_code)]
    unsafe {
        BootLoader { state }.load(LAYOUT.active.origin)
    }
}

/// This start's count of early crashes (`update_image::CrashCount`): the backup register's, one more when a
/// watchdog reset the chip (RCC_CSR, which the image reads and clears after this), none after any other reset;
/// written back at once, so that it holds whatever the swap does. The backup domain is opened for it as the
/// thruster opens it for its latches (`g431_hw::backup`).
fn count_crashes() -> CrashCount {
    pac::RCC.apb1enr1().modify(|w| w.0 |= APB1ENR1_BACKUP);
    pac::PWR.cr1().modify(|w| w.0 |= PWR_CR1_DBP);
    let stored = CrashCount::from_word(pac::TAMP.bkpr(CRASH_REGISTER).read().bkp());
    let count = stored.at_start(watchdog_reset(pac::RCC.csr().read().0));
    keep_count(count);
    count
}

/// Keep `count` in its backup register for the image and the next start.
fn keep_count(count: CrashCount) {
    pac::TAMP.bkpr(CRASH_REGISTER).write(|w| w.set_bkp(count.to_word()));
}

/// Drive the power stage's six gate inputs to their off level (`g431_hw::images::THRUSTER_GATES_OFF`) before the
/// bootloader does anything that takes time: the image it starts takes them over for TIM1. GPIOA and GPIOB's clocks
/// first (RCC_AHB2ENR bits 0 and 1, RM0440 7.4.16), then each port's levels, then its modes.
#[cfg(feature = "thruster")]
fn hold_gates_off() {
    pac::RCC.ahb2enr().modify(|w| {
        w.set_gpioaen(true);
        w.set_gpioben(true);
    });
    for gates in g431_hw::images::THRUSTER_GATES_OFF {
        let port = match gates.port {
            g431_hw::pins::Port::A => pac::GPIOA,
            _ => pac::GPIOB,
        };
        port.bsrr().write_value(pac::gpio::regs::Bsrr(gates.bsrr));
        port.moder()
            .modify(|w| w.0 = (w.0 & !gates.moder_mask) | gates.moder_output);
    }
}

/// How often the start-up polls the watchdog's status before it goes on regardless: an update takes up to five
/// LSI cycles (RM0440 IWDG_SR), 170 us at the slowest LSI, a few thousand polls at HSI16.
const WATCHDOG_POLLS: u32 = 100_000;

/// Start the independent watchdog with the trial timeout (`g431_hw::iwdg::BOOT_TRIAL`), RM0440's IWDG procedure
/// as the images run it: start, unlock, prescaler, reload, wait for the update, reload the counter. It runs
/// through the bootloader's check and swap, fed between their steps; an image that hangs before its own watchdog
/// set-up is reset, and embassy-boot reverts it if it was on trial. The wait for the update matters to the image:
/// while PVU or RVU is set its own writes to PR and RLR would be ignored.
fn start_trial_watchdog(_iwdg: embassy_stm32::Peri<'static, IWDG>) {
    use pac::iwdg::vals::{Key, Pr};
    // Frozen while a debugger halts the core, as the images' own watchdogs are.
    pac::DBGMCU
        .apb1lfzr()
        .write_value(pac::dbgmcu::regs::Apb1lfzr(DBGMCU_APB1FZR1));
    let regs = pac::IWDG;
    regs.kr().write(|w| w.set_key(Key::START));
    regs.kr().write(|w| w.set_key(Key::ENABLE));
    regs.pr().write(|w| w.set_pr(Pr::from_bits(BOOT_TRIAL.pr)));
    regs.rlr().write(|w| w.set_rl(BOOT_TRIAL.rlr));
    for _ in 0..WATCHDOG_POLLS {
        if regs.sr().read().0 == 0 {
            break;
        }
    }
    regs.kr().write(|w| w.set_key(Key::RESET));
}

/// A read of a double word whose ECC shows two errors (`g431_hw::flash`): one a power cut tore in the state, the
/// record, ACTIVE or DFU. The read has completed with the cells' bits, and embassy-boot's format is built to take a torn word for
/// what it is (an unfinished step, or no magic): clear the flag and let it go on. cortex-m-rt's default would spin
/// here, and since every start reads the same word, the board would never start again. Any other NMI source
/// (the clock security system, SRAM parity), or the same error in the bootloader's own code, resets the chip.
#[cortex_m_rt::exception]
#[allow(unsafe_code)]
unsafe fn NonMaskableInt() {
    const SWAPPED: [Span; 4] = [LAYOUT.state, LAYOUT.record, LAYOUT.active, LAYOUT.dfu];
    match flash::nmi_action(pac::FLASH.eccr().read().0, &SWAPPED) {
        NmiAction::PassDataRead { clear } => pac::FLASH.eccr().write_value(pac::flash::regs::Eccr(clear)),
        NmiAction::Stop => SCB::sys_reset(),
    }
}

/// A hard fault (flip-link turns a stack overflow into one) resets the chip: the next start tries again.
#[cortex_m_rt::exception]
#[allow(unsafe_code)]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    SCB::sys_reset()
}

/// No interrupt is enabled; should one arrive, reset rather than spin.
#[cortex_m_rt::exception]
#[allow(unsafe_code)]
unsafe fn DefaultHandler(_irqn: i16) -> ! {
    SCB::sys_reset()
}

/// The image has no panic path left once optimised (see the size report); were one reached, reset rather than
/// spin, without formatting a message nobody reads.
#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    SCB::sys_reset()
}

/// The bootloader logs nothing. A build that unifies its features with the other images' turns embassy-stm32's
/// defmt on: its log calls then land here, and go nowhere.
#[defmt::global_logger]
struct NoLog;

// SAFETY: a logger that does nothing cannot be entered twice in a way that matters.
#[allow(unsafe_code)]
unsafe impl defmt::Logger for NoLog {
    fn acquire() {}
    unsafe fn flush() {}
    unsafe fn release() {}
    unsafe fn write(_bytes: &[u8]) {}
}

/// defmt's `panic!` and `unwrap!` in such a build take the same way out as a panic.
#[defmt::panic_handler]
fn defmt_panic() -> ! {
    SCB::sys_reset()
}
