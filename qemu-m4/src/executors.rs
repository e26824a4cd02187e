//! The two executors, as in the STM32 thruster image: thread mode for everything but commutation, and an
//! `InterruptExecutor` on a real NVIC interrupt, above thread mode, for commutation.
//!
//! Thread mode is embassy's raw executor with its idle loop written here: embassy's `Executor` sleeps with WFE,
//! which QEMU 7.2 (Debian 12) treats as a yield, not a sleep, so the emulated core would spin and the virtual clock
//! would crawl through every idle instruction. This loop sleeps with WFI, which halts the emulated core until an
//! interrupt, and `-icount sleep=off` then jumps the clock to the next timer. Its pender pends an otherwise unused
//! interrupt whose handler only raises a flag, so a wake-up between the last poll and the WFI is never lost.

use core::sync::atomic::{AtomicBool, Ordering};

use embassy_executor::{InterruptExecutor, SendSpawner, Spawner, raw};
use static_cell::StaticCell;

use crate::board::{self, Irq, Priority};
use crate::meter::{self, Meter};

/// Commutation's executor.
static COMMUTATION: InterruptExecutor = InterruptExecutor::new();
/// Its interrupt's own work, beside the task it polls.
pub static COMMUTATION_ISR_METER: Meter = Meter::nested("commutation executor ISR");

/// Thread mode's executor: each round of polls, tasks included (their own meters tell them apart).
pub static THREAD_EXECUTOR_METER: Meter = Meter::task("thread executor");
/// The test bench's own thread-mode tasks (the ground station, the pilot, the battery board, the thrusters' power
/// supplies, the end of a run).
pub static BENCH_METER: Meter = Meter::task("test bench tasks");

/// Raised by the thread-mode pender's interrupt: there is work for thread mode.
static THREAD_WORK: AtomicBool = AtomicBool::new(false);
static THREAD: StaticCell<raw::Executor> = StaticCell::new();

/// Start the commutation executor at its priority; its spawner.
pub fn start_commutation() -> SendSpawner {
    board::set_priority(Irq::Commutation, Priority::Commutation);
    COMMUTATION.start(Irq::Commutation)
}

/// Run thread mode forever: `init` spawns the first tasks.
pub fn run_thread_mode(init: impl FnOnce(Spawner)) -> ! {
    board::enable(Irq::ThreadWake, Priority::Lowest);
    // The platform's pender pends the interrupt whose number is the executor's context.
    let executor: &'static raw::Executor = THREAD.init(raw::Executor::new(Irq::ThreadWake as usize as *mut ()));
    init(executor.spawner());
    loop {
        THREAD_WORK.store(false, Ordering::Relaxed);
        meter::measure(&THREAD_EXECUTOR_METER, || {
            // SAFETY: polled from this loop only, never re-entrantly (the pender only pends an interrupt).
            #[allow(unsafe_code)]
            unsafe {
                executor.poll()
            }
        });
        // With interrupts masked, WFI still wakes on a pending one; the handler then runs once they are unmasked.
        cortex_m::interrupt::free(|_| {
            if !THREAD_WORK.load(Ordering::Relaxed) {
                cortex_m::asm::wfi();
            }
        });
    }
}

/// The thread-mode pender's interrupt.
pub extern "C" fn on_thread_wake() {
    THREAD_WORK.store(true, Ordering::Relaxed);
}

/// The commutation executor's interrupt.
pub extern "C" fn on_commutation() {
    meter::measure(&COMMUTATION_ISR_METER, || {
        // SAFETY: this is the executor's own interrupt, bound in the vector table; it is started before any
        // task can pend it.
        #[allow(unsafe_code)]
        unsafe {
            COMMUTATION.on_interrupt()
        }
    });
}
