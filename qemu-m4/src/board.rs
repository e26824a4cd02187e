//! The emulated board: QEMU's `mps2-an386`, ARM's MPS2 FPGA board with the AN386 image (Cortex-M4F, NVIC, the
//! Cortex-M System Design Kit's timers). Its interrupt numbers, the timers' registers and the vector table.
//!
//! Sources: ARM AN386 (its memory map and interrupts are AN385's, for a Cortex-M4), the CMSDK technical reference
//! manual (ARM DDI 0479C) for the APB timer (4.3) and the dual timer (4.4), and QEMU's `hw/arm/mps2.c`, which
//! clocks every timer from the 25 MHz SYSCLK.
// Registers are raw addresses and the vector table is a linker-placed static: this module is the binding.
#![allow(unsafe_code)]

use core::ptr::{read_volatile, write_volatile};

/// SYSCLK, which clocks the timers (QEMU `mps2.c`: `SYSCLK_FRQ`).
pub const SYSCLK_HZ: u32 = 25_000_000;

/// The interrupts this image uses (AN385 table "Interrupt map"; QEMU gives the board 32).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u16)]
pub enum Irq {
    /// APB timer 0: embassy-time's alarm.
    Timer0 = 8,
    /// APB timer 1: stands in for a hall sensor's edge (the EXTI interrupt on the STM32).
    Timer1 = 9,
    /// The dual timer: fires only if the clock ever wraps.
    DualTimer = 10,
    /// The audio I2S interrupt, whose device QEMU does not model: pended by software to run the commutation
    /// executor, as the STM32 image pends UART4's.
    Commutation = 14,
    /// The touch screen interrupt, not modelled either: pended by software to wake the thread-mode executor.
    ThreadWake = 15,
}

// SAFETY: every variant is an interrupt number the NVIC of this board has (fewer than 32).
unsafe impl cortex_m::interrupt::InterruptNumber for Irq {
    fn number(self) -> u16 {
        self as u16
    }
}

fn read(address: usize) -> u32 {
    // SAFETY: only called with the register addresses below, which the board maps.
    unsafe { read_volatile(address as *const u32) }
}

fn write(address: usize, value: u32) {
    // SAFETY: only called with the register addresses below, which the board maps.
    unsafe { write_volatile(address as *mut u32, value) }
}

/// A CMSDK APB timer (DDI 0479C 4.3): a 32-bit down counter clocked by SYSCLK that interrupts on reaching 0.
#[derive(Debug, Clone, Copy)]
pub struct ApbTimer(usize);

/// APB timer 0 (AN385: 0x4000_0000, IRQ 8).
pub const TIMER0: ApbTimer = ApbTimer(0x4000_0000);
/// APB timer 1 (AN385: 0x4000_1000, IRQ 9).
pub const TIMER1: ApbTimer = ApbTimer(0x4000_1000);

impl ApbTimer {
    const CTRL: usize = 0x00;
    const VALUE: usize = 0x04;
    const RELOAD: usize = 0x08;
    const INTSTATUS: usize = 0x0C;
    const ENABLE: u32 = 1 << 0;
    const INTERRUPT_ENABLE: u32 = 1 << 3;

    /// Interrupt once, `cycles` SYSCLK cycles from now (at least 1). RELOAD 0: the counter stays at 0 afterwards.
    pub fn one_shot(self, cycles: u32) {
        write(self.0 + Self::CTRL, 0);
        write(self.0 + Self::RELOAD, 0);
        write(self.0 + Self::VALUE, cycles.max(1));
        write(self.0 + Self::CTRL, Self::ENABLE | Self::INTERRUPT_ENABLE);
    }

    /// Stop the timer and clear its interrupt.
    pub fn stop(self) {
        write(self.0 + Self::CTRL, 0);
        write(self.0 + Self::INTSTATUS, 1);
    }
}

/// One half of the CMSDK dual timer (DDI 0479C 4.4), run free: a 32-bit down counter from 0xFFFF_FFFF.
#[derive(Debug, Clone, Copy)]
pub struct FreeCounter(usize);

/// Dual timer, first counter (AN385: 0x4000_2000, IRQ 10).
pub const DUAL_TIMER_1: FreeCounter = FreeCounter(0x4000_2000);
/// Dual timer, second counter.
pub const DUAL_TIMER_2: FreeCounter = FreeCounter(0x4000_2020);

impl FreeCounter {
    const LOAD: usize = 0x00;
    const VALUE: usize = 0x04;
    const CONTROL: usize = 0x08;
    const INTCLR: usize = 0x0C;
    const SIZE_32: u32 = 1 << 1;
    const PRESCALE_16: u32 = 1 << 2;
    const INTERRUPT_ENABLE: u32 = 1 << 5;
    const ENABLE: u32 = 1 << 7;

    /// Count down from 0xFFFF_FFFF at SYSCLK (or SYSCLK / 16), wrapping; interrupt on the wrap if asked.
    pub fn start(self, divide_by_16: bool, interrupt_on_wrap: bool) {
        let mut control = Self::SIZE_32 | Self::ENABLE;
        if divide_by_16 {
            control |= Self::PRESCALE_16;
        }
        if interrupt_on_wrap {
            control |= Self::INTERRUPT_ENABLE;
        }
        write(self.0 + Self::CONTROL, 0);
        write(self.0 + Self::INTCLR, 1);
        write(self.0 + Self::CONTROL, control);
        // Free-running mode: writing LOAD sets the count.
        write(self.0 + Self::LOAD, u32::MAX);
    }

    /// Counts since `start`, modulo 2^32.
    pub fn elapsed(self) -> u32 {
        !read(self.0 + Self::VALUE)
    }
}

/// A slot of the vector table.
#[derive(Clone, Copy)]
#[repr(C)]
pub union Vector {
    handler: unsafe extern "C" fn(),
    reserved: usize,
}

unsafe extern "C" {
    /// cortex-m-rt's handler for interrupts nobody bound.
    fn DefaultHandler();
}

/// The device interrupts (cortex-m-rt's `device` feature: the application supplies them).
#[allow(
    clippy::indexing_slicing,
    reason = "evaluated at compile time: an index out of range fails the build"
)]
#[unsafe(link_section = ".vector_table.interrupts")]
#[unsafe(no_mangle)]
pub static __INTERRUPTS: [Vector; 32] = {
    let mut vectors = [Vector {
        handler: DefaultHandler,
    }; 32];
    vectors[Irq::Timer0 as usize] = Vector {
        handler: crate::time::on_alarm,
    };
    vectors[Irq::Timer1 as usize] = Vector {
        handler: crate::halls::on_edge,
    };
    vectors[Irq::DualTimer as usize] = Vector {
        handler: crate::time::on_wrap,
    };
    vectors[Irq::Commutation as usize] = Vector {
        handler: crate::executors::on_commutation,
    };
    vectors[Irq::ThreadWake as usize] = Vector {
        handler: crate::executors::on_thread_wake,
    };
    vectors
};

/// Interrupt priorities, in steps of 0x20 so that they stay distinct with 3 implemented priority bits (the G431
/// has 4). They mirror the STM32 images: the time driver and the hall inputs highest (embassy-stm32's default P0),
/// commutation next (P1), thread mode below everything.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Priority {
    /// embassy-time's alarm and the hall edge.
    Highest = 0x00,
    /// The commutation executor.
    Commutation = 0x20,
    /// The thread-mode executor's wake-up, which only sets a flag.
    Lowest = 0xE0,
}

/// Let `irq` interrupt at `priority` (0 highest; see [`Priority`]).
pub fn enable(irq: Irq, priority: Priority) {
    // SAFETY: the NVIC is a core peripheral of every Cortex-M4; setting a priority and unmasking an interrupt
    // whose handler is bound in `__INTERRUPTS` is what they are for.
    unsafe {
        let mut core = cortex_m::Peripherals::steal();
        core.NVIC.set_priority(irq, priority as u8);
        cortex_m::peripheral::NVIC::unmask(irq);
    }
}

/// Set the priority of `irq` without unmasking it (the interrupt executor unmasks its own).
pub fn set_priority(irq: Irq, priority: Priority) {
    // SAFETY: as in `enable`.
    unsafe {
        let mut core = cortex_m::Peripherals::steal();
        core.NVIC.set_priority(irq, priority as u8);
    }
}
