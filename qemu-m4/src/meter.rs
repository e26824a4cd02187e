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
//!
//! Each firmware image's thread-mode tasks are one joined future (`thruster_fw::run`, `lbv_master_fw::run`), so
//! a poll is measured as a whole; a [`Joined`] meter also files it under the set of the inner tasks that made
//! progress in it, as their ports and their outputs show ([`progressed`]).

use core::future::{Future, poll_fn};
use core::pin::pin;
use core::sync::atomic::{AtomicBool, AtomicU8, AtomicU32, Ordering::Relaxed};
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

/// True while the thruster's thread-mode tasks are being polled.
pub static THRUSTER_THREAD_BUSY: AtomicBool = AtomicBool::new(false);

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

/// Polls, their sum and the longest.
#[derive(Debug)]
struct Counters {
    polls: AtomicU32,
    cycles: AtomicU32,
    max_cycles: AtomicU32,
}

impl Counters {
    const fn new() -> Self {
        Self {
            polls: AtomicU32::new(0),
            cycles: AtomicU32::new(0),
            max_cycles: AtomicU32::new(0),
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

    fn usage(&self) -> Usage {
        Usage {
            polls: self.polls.load(Relaxed),
            cycles: self.cycles.load(Relaxed),
            max_cycles: self.max_cycles.load(Relaxed),
        }
    }
}

/// The instructions of one task or handler.
#[derive(Debug)]
pub struct Meter {
    /// What it measures, for the report.
    pub name: &'static str,
    nested: bool,
    busy: Option<&'static AtomicBool>,
    counters: Counters,
}

impl Meter {
    const fn new(name: &'static str, nested: bool, busy: Option<&'static AtomicBool>) -> Self {
        Self {
            name,
            nested,
            busy,
            counters: Counters::new(),
        }
    }

    /// A thread-mode task.
    pub const fn task(name: &'static str) -> Self {
        Self::new(name, false, None)
    }

    /// Work that may run inside another measurement: an interrupt handler, a task of an interrupt executor, a
    /// model port.
    pub const fn nested(name: &'static str) -> Self {
        Self::new(name, true, None)
    }

    /// What it has counted.
    pub fn usage(&self) -> Usage {
        self.counters.usage()
    }
}

/// Run `work` and count its instructions on `meter`, less the nested work it contained; the result and the count.
fn measure_net<R>(meter: &Meter, work: impl FnOnce() -> R) -> (R, u32) {
    if let Some(busy) = meter.busy {
        busy.store(true, Relaxed);
    }
    let nested_before = NESTED.load(Relaxed);
    let start = cycles();
    let result = work();
    let gross = cycles().wrapping_sub(start);
    let net = gross.saturating_sub(NESTED.load(Relaxed).wrapping_sub(nested_before));
    if let Some(busy) = meter.busy {
        busy.store(false, Relaxed);
    }
    if meter.nested {
        NESTED.fetch_add(net, Relaxed);
    }
    meter.counters.record(net);
    (result, net)
}

/// Run `work` and count its instructions on `meter`, less the nested work it contained.
pub fn measure<R>(meter: &Meter, work: impl FnOnce() -> R) -> R {
    measure_net(meter, work).0
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

/// The inner tasks of a joined future that made progress in the poll under way, one bit each (the [`Joined`]
/// meter's task names give their meaning); ports and outputs raise them.
static PROGRESS: AtomicU8 = AtomicU8::new(0);

/// Bits of [`PROGRESS`].
#[derive(Debug)]
pub struct Progress;

impl Progress {
    /// The thruster's I2C task began to wait for an address, or was addressed.
    pub const THRUSTER_I2C: u8 = 1 << 0;
    /// The thruster's fault task sampled its inputs.
    pub const THRUSTER_FAULTS: u8 = 1 << 1;
    /// The thruster's control task published a duty.
    pub const THRUSTER_CONTROL: u8 = 1 << 2;
    /// The thruster's health task fed the watchdog.
    pub const THRUSTER_HEALTH: u8 = 1 << 3;
    /// The names of the thruster's bits, lowest first.
    pub const THRUSTER: &[&str] = &["i2c", "faults", "control", "health"];

    /// The master's bus work made a transfer or worked the lines.
    pub const MASTER_BUS: u8 = 1 << 0;
    /// The master's battery task began to wait for a frame, or got one.
    pub const MASTER_BATTERY: u8 = 1 << 1;
    /// The master's console receive task read the link.
    pub const MASTER_CONSOLE_RX: u8 = 1 << 2;
    /// The master's console transmit task wrote the link.
    pub const MASTER_CONSOLE_TX: u8 = 1 << 3;
    /// The master's vehicle task published its state.
    pub const MASTER_VEHICLE: u8 = 1 << 4;
    /// The names of the master's bits, lowest first.
    pub const MASTER: &[&str] = &["bus", "battery", "console-rx", "console-tx", "vehicle"];
}

/// Note that an inner task made progress in the poll under way (`bits` of [`Progress`]).
pub fn progressed(bits: u8) {
    PROGRESS.fetch_or(bits, Relaxed);
}

/// Classes of polls a [`Joined`] meter keeps: one per set of up to five inner tasks.
const CLASSES: usize = 32;

/// The instructions of a joined future's polls, in all and filed by which of its inner tasks made progress.
#[derive(Debug)]
pub struct Joined {
    /// Every poll.
    pub all: Meter,
    /// The inner tasks' names, one per bit of [`Progress`].
    pub tasks: &'static [&'static str],
    classes: [Counters; CLASSES],
}

impl Joined {
    /// A joined future of `tasks`, raising `busy` while it is polled when one is given.
    pub const fn new(name: &'static str, tasks: &'static [&'static str], busy: Option<&'static AtomicBool>) -> Self {
        Self {
            all: Meter::new(name, false, busy),
            tasks,
            classes: [const { Counters::new() }; CLASSES],
        }
    }

    /// Each set of inner tasks seen progressing together (a bit mask), with its polls.
    pub fn classes(&self) -> impl Iterator<Item = (u8, Usage)> + '_ {
        (0u8..)
            .zip(&self.classes)
            .map(|(set, counters)| (set, counters.usage()))
            .filter(|(_, usage)| usage.polls > 0)
    }
}

/// `future`, each poll measured on `meter` and run on `stack`, and filed under the inner tasks the ports raised
/// in it plus those `outputs` sees (it is asked after each poll).
pub async fn metered_joined<F: Future>(
    meter: &Joined,
    stack: Stack,
    mut outputs: impl FnMut() -> u8,
    future: F,
) -> F::Output {
    let mut future = pin!(future);
    poll_fn(|cx| {
        let mut poll = Poll::Pending;
        let mut net = 0;
        stack.run(|| {
            PROGRESS.store(0, Relaxed);
            (poll, net) = measure_net(&meter.all, || future.as_mut().poll(cx));
        });
        let set = usize::from(PROGRESS.swap(0, Relaxed) | outputs()) % CLASSES;
        if let Some(class) = meter.classes.get(set) {
            class.record(net);
        }
        poll
    })
    .await
}
