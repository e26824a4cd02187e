//! The stacks, and their high-water marks.
//!
//! Handlers run on the main stack (MSP); thread mode runs on the process stack (PSP), and each firmware image's
//! thread-mode tasks are polled on a stack of their own, so that each image's high-water mark is its own even
//! though both images share the chip. [`enter_thread_mode`] paints all four before anything runs on them;
//! [`Stack::high_water`] scans for the deepest word that is no longer paint. The main stack's top is the linker's
//! `_stack_start` (cortex-m-rt's or flip-link's), the others come from `memory.x`; each spans 32 KiB below its top.
// Switching stacks takes a few instructions of assembly and symbols from the linker script.
#![allow(unsafe_code)]

use core::arch::asm;
use core::ptr::addr_of;

/// Each stack's size: the STM32G431's whole RAM.
pub const STACK_BYTES: usize = 32 * 1024;
/// The paint (cortex-m-rt's, for its own `paint-stack`).
const PAINT: u32 = 0xCCCC_CCCC;

unsafe extern "C" {
    static _stack_start: u8;
    static _process_stack_start: u8;
    static _thruster_stack_start: u8;
    static _master_stack_start: u8;
}

/// One of the stacks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stack {
    /// Handlers: the time driver, the hall edge, the commutation executor.
    Main,
    /// Thread mode: the executor itself and the test's own tasks (scripted operator, pilot, battery board).
    Process,
    /// The thruster image's thread-mode tasks.
    Thruster,
    /// The master image's tasks.
    Master,
}

impl Stack {
    /// Every stack, for the report.
    pub const ALL: [Stack; 4] = [Stack::Main, Stack::Process, Stack::Thruster, Stack::Master];

    /// Its name in the report.
    pub const fn name(self) -> &'static str {
        match self {
            Stack::Main => "main (handlers)",
            Stack::Process => "process (executor, test tasks)",
            Stack::Thruster => "thruster thread tasks",
            Stack::Master => "master tasks",
        }
    }

    /// The address just above it (stacks grow down).
    fn top(self) -> usize {
        match self {
            Stack::Main => addr_of!(_stack_start) as usize,
            Stack::Process => addr_of!(_process_stack_start) as usize,
            Stack::Thruster => addr_of!(_thruster_stack_start) as usize,
            Stack::Master => addr_of!(_master_stack_start) as usize,
        }
    }

    /// Run `work` on this stack (in thread mode; directly when already on it).
    pub fn run(self, work: impl FnOnce()) {
        let top = self.top();
        let sp = stack_pointer();
        if sp <= top && sp > top - STACK_BYTES {
            work();
            return;
        }
        let mut work = Some(work);
        call_on(top, &mut || {
            if let Some(work) = work.take() {
                work();
            }
        });
    }

    /// The lowest address in it.
    fn bottom(self) -> usize {
        self.top() - STACK_BYTES
    }

    /// Bytes of it ever used: from its top down to the deepest word that is no longer paint.
    pub fn high_water(self) -> usize {
        let untouched = (self.bottom()..self.top())
            .step_by(4)
            // SAFETY: the stack regions are reserved by the linker script and always mapped; a word read here
            // is at worst a live stack word, read as a plain u32.
            .take_while(|&address| unsafe { core::ptr::read_volatile(address as *const u32) } == PAINT)
            .count();
        STACK_BYTES - untouched * 4
    }
}

/// The stack pointer now.
fn stack_pointer() -> usize {
    let sp: usize;
    // SAFETY: reads SP.
    unsafe { asm!("mov {}, sp", out(reg) sp, options(nomem, nostack, preserves_flags)) };
    sp
}

/// Call `work` with the stack pointer at `top`, then go back to the caller's stack.
fn call_on<F: FnMut()>(top: usize, work: &mut F) {
    extern "C" fn trampoline<F: FnMut()>(work: *mut F) {
        // SAFETY: `call_on` passes its exclusive borrow of the closure, alive for the whole call.
        unsafe { (*work)() }
    }
    // SAFETY: `top` is the 8-byte-aligned top of a stack region nobody else is using (thread mode runs one poll
    // at a time, and `run` does not switch when already on the region). r5 is callee-saved, so the trampoline
    // keeps the caller's stack pointer in it; every caller-saved register is declared clobbered.
    unsafe {
        asm!(
            "mov r5, sp",
            "mov sp, {top}",
            "blx {entry}",
            "mov sp, r5",
            top = in(reg) top,
            entry = in(reg) trampoline::<F> as extern "C" fn(*mut F),
            inout("r0") work as *mut F => _,
            out("r5") _,
            // The rest of the AAPCS caller-saved registers (this FPU has d0-d15 only, so not `clobber_abi`).
            out("r1") _, out("r2") _, out("r3") _, out("r12") _, out("lr") _,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _, out("d4") _, out("d5") _, out("d6") _, out("d7") _,
        );
    }
}

/// Leave the reset handler's main stack: paint the stacks, then thread mode continues on the process stack at
/// `entry`, and the handlers get the whole main stack.
pub fn enter_thread_mode(entry: extern "C" fn() -> !) -> ! {
    for stack in [Stack::Process, Stack::Thruster, Stack::Master] {
        for address in (stack.bottom()..stack.top()).step_by(4) {
            // SAFETY: these regions are reserved for the stacks by the linker script and nothing runs on them yet.
            unsafe { core::ptr::write_volatile(address as *mut u32, PAINT) };
        }
    }
    // CONTROL.SPSEL: thread mode uses the process stack.
    let control = cortex_m::register::control::read().bits() | 0b10;
    // SAFETY: after CONTROL.SPSEL = 1 thread mode uses PSP, so nothing on the main stack is live any more: it is
    // painted with registers only, MSP goes back to its top, and `entry` never returns.
    unsafe {
        asm!(
            "msr psp, {process}",
            "msr control, {control}",
            "isb",
            "2:",
            "str {paint}, [{bottom}], #4",
            "cmp {bottom}, {main}",
            "blo 2b",
            "msr msp, {main}",
            "bx {entry}",
            process = in(reg) Stack::Process.top(),
            control = in(reg) control,
            paint = in(reg) PAINT,
            bottom = in(reg) Stack::Main.bottom(),
            main = in(reg) Stack::Main.top(),
            entry = in(reg) entry,
            options(noreturn),
        )
    }
}
