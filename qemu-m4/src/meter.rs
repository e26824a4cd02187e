//! Instructions counted on the emulated chip.
//!
//! The runner starts QEMU with `-icount shift=3`: virtual time then advances exactly 8 ns per guest instruction
//! executed (and jumps ahead while the core sleeps in WFI), and every timer of the board runs on that virtual time.
//! So the dual timer's second counter, at SYSCLK (25 MHz, 40 ns), counts instructions in steps of 5. [`calibrate`]
//! measures the ratio with a loop of known length instead of assuming it.
//!
//! A [`Meter`] sums the instructions of one piece of work: each poll of a task, each run of an interrupt handler.
//! Work that interrupts a measured poll, or that a poll hands to a model port, is nested: its meter adds its
//! instructions to [`NESTED`], and the enclosing measurement subtracts them, so every instruction is counted once,
//! by the innermost meter.

use core::future::{Future, poll_fn};
use core::pin::pin;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering::Relaxed};
use core::task::Poll;

use crate::board::DUAL_TIMER_2;
use crate::stacks::Stack;

/// SYSCLK cycles since boot (the dual timer's second counter), modulo 2^32 (171 s).
pub fn cycles() -> u32 {
    DUAL_TIMER_2.elapsed()
}

/// Start the instruction clock.
pub fn init() {
    DUAL_TIMER_2.start(false, false);
}

/// Instructions per SYSCLK cycle, as measured: `instructions` executed in `cycles`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Calibration {
    /// Instructions of the calibration loop.
    pub instructions: u32,
    /// SYSCLK cycles they took.
    pub cycles: u32,
}

static CALIBRATION: [AtomicU32; 2] = [AtomicU32::new(5), AtomicU32::new(1)];

/// Time a loop of exactly `2 * ITERATIONS` instructions (a subtract and a branch each) and keep the ratio.
pub fn calibrate() -> Calibration {
    const ITERATIONS: u32 = 50_000;
    let start = cycles();
    // SAFETY: a register-only countdown loop; it touches no memory and no stack.
    #[allow(unsafe_code)]
    unsafe {
        core::arch::asm!(
            "2:",
            "subs {n}, {n}, #1",
            "bne 2b",
            n = inout(reg) ITERATIONS => _,
            options(nomem, nostack),
        );
    }
    let taken = cycles().wrapping_sub(start).max(1);
    let calibration = Calibration {
        instructions: 2 * ITERATIONS,
        cycles: taken,
    };
    let [instructions, per] = &CALIBRATION;
    instructions.store(calibration.instructions, Relaxed);
    per.store(calibration.cycles, Relaxed);
    calibration
}

/// Instructions in `cycles` SYSCLK cycles, by the calibration.
pub fn instructions(cycles: u64) -> u64 {
    let [instructions, per] = &CALIBRATION;
    cycles * u64::from(instructions.load(Relaxed)) / u64::from(per.load(Relaxed).max(1))
}

/// Nested work measured so far, in cycles (wrapping).
static NESTED: AtomicU32 = AtomicU32::new(0);

/// True while a poll of one of the thruster's 1 kHz tasks (faults, control) is running.
pub static ONE_KHZ_BUSY: AtomicBool = AtomicBool::new(false);

/// What one meter counted.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Usage {
    /// Polls (or handler runs) measured.
    pub polls: u32,
    /// Their instructions in all, in SYSCLK cycles.
    pub cycles: u32,
    /// The longest one, in SYSCLK cycles.
    pub max_cycles: u32,
}

/// The instructions of one task or handler.
#[derive(Debug)]
pub struct Meter {
    /// What it measures, for the report.
    pub name: &'static str,
    nested: bool,
    one_khz: bool,
    polls: AtomicU32,
    cycles: AtomicU32,
    max_cycles: AtomicU32,
}

impl Meter {
    const fn new(name: &'static str, nested: bool, one_khz: bool) -> Self {
        Self {
            name,
            nested,
            one_khz,
            polls: AtomicU32::new(0),
            cycles: AtomicU32::new(0),
            max_cycles: AtomicU32::new(0),
        }
    }

    /// A thread-mode task.
    pub const fn task(name: &'static str) -> Self {
        Self::new(name, false, false)
    }

    /// One of the thruster's 1 kHz thread-mode tasks: a hall edge that comes during its poll is counted as such.
    pub const fn one_khz(name: &'static str) -> Self {
        Self::new(name, false, true)
    }

    /// Work that may run inside another measurement: an interrupt handler, a task of an interrupt executor, a
    /// model port.
    pub const fn nested(name: &'static str) -> Self {
        Self::new(name, true, false)
    }

    /// What it has counted.
    pub fn usage(&self) -> Usage {
        Usage {
            polls: self.polls.load(Relaxed),
            cycles: self.cycles.load(Relaxed),
            max_cycles: self.max_cycles.load(Relaxed),
        }
    }

    fn record(&self, cycles: u32) {
        self.polls.fetch_add(1, Relaxed);
        // A sum beyond 2^32 cycles (171 s of work) saturates rather than wraps.
        let _ = self
            .cycles
            .fetch_update(Relaxed, Relaxed, |sum| Some(sum.saturating_add(cycles)));
        self.max_cycles.fetch_max(cycles, Relaxed);
    }
}

/// Run `work` and count its instructions on `meter`, less the nested work it contained.
pub fn measure<R>(meter: &Meter, work: impl FnOnce() -> R) -> R {
    if meter.one_khz {
        ONE_KHZ_BUSY.store(true, Relaxed);
    }
    let nested_before = NESTED.load(Relaxed);
    let start = cycles();
    let result = work();
    let gross = cycles().wrapping_sub(start);
    let net = gross.saturating_sub(NESTED.load(Relaxed).wrapping_sub(nested_before));
    if meter.one_khz {
        ONE_KHZ_BUSY.store(false, Relaxed);
    }
    if meter.nested {
        NESTED.fetch_add(net, Relaxed);
    }
    meter.record(net);
    result
}

/// `future`, each poll measured on `meter` and run on `stack` when one is given.
pub async fn metered<F: Future>(meter: &Meter, stack: Option<Stack>, future: F) -> F::Output {
    let mut future = pin!(future);
    poll_fn(|cx| {
        let mut poll = Poll::Pending;
        let mut work = || poll = measure(meter, || future.as_mut().poll(cx));
        match stack {
            Some(stack) => stack.run(work),
            None => work(),
        }
        poll
    })
    .await
}
