//! The simulated world the LBV firmware cores run in on the host: the same `run` functions as the STM32 images,
//! against simulated ports, on virtual time. The bench (`lbv bench`) and every host test of the cores build on it;
//! nothing else models a bus, a link, a flash or the clock.
//!
//! - [`clock`]: the virtual clock (embassy-time's time driver on the host, one per thread);
//! - [`Executor`]: polls the woken tasks, removes tasks (a reset), moves the clock in steps;
//! - [`i2c`]: I2C buses with bit-time accounting, devices and firmware slave ports, a TCA9548A, NACKs, clock
//!   stretching, corruption, SDA held low, and the lines as GPIOs for the bus recovery;
//! - [`Queue`], [`SerialRx`], [`SerialTx`], [`CanBus`]: serial links and a CAN bus;
//! - [`SerialLine`]: a serial link at its baud rate, between UARTs with buffers of fixed size;
//! - [`flash`]: NOR flash with power-cut faults and the CPU stall of its erases and writes ([`Cpu`]);
//! - [`in_one_critical_section`]: a run at the cost of one critical section.
//!
//! All state is owned: a board is a set of handles on these parts and a few tasks; dropping them (a power cycle)
//! frees everything. This crate knows none of the firmware crates: their port traits are implemented by thin
//! adapters in each firmware crate's `sim` module (Cargo feature `sim`).
//!
//! The clock, the executor and the critical section are the host's (Cargo feature `std`, on by default). Without
//! it the parts need only `core` and `alloc`, and run on the time driver and executor of whoever uses them:
//! qemu-m4 puts its thruster buses on this I2C model on the emulated Cortex-M4.
#![cfg_attr(not(feature = "std"), no_std)]

extern crate alloc;

#[cfg(feature = "std")]
pub mod clock;
mod cpu;
#[cfg(feature = "std")]
mod executor;
pub mod flash;
pub mod i2c;
mod queue;
mod uart;

#[cfg(feature = "std")]
pub use clock::Clock;
pub use cpu::Cpu;

/// Run `f` inside one critical section. The cores' channels take a critical section for every access (tens of
/// thousands a simulated second); on the host each is a lock of the process's one critical-section mutex unless it
/// is nested in another. A run held in one section pays for one lock: every section inside is nested.
///
/// The section is the whole process's: while one thread runs in it, another thread's critical sections wait. Run
/// simulations side by side as processes, not threads.
#[cfg(feature = "std")]
pub fn in_one_critical_section<R>(f: impl FnOnce() -> R) -> R {
    critical_section::with(|_| f())
}
#[cfg(feature = "std")]
pub use executor::{Executor, TaskId};
pub use queue::{CanBus, Queue, SerialRx, SerialTx};
pub use uart::{LineRx, LineTx, SerialLine};
