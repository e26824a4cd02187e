//! Output to QEMU's standard output over semihosting, the exit status, and the figures every run prints at its end.
//!
//! A line is formatted in RAM first and handed to the host in one semihosting call, so that printing holds
//! interrupts off only for that call (which QEMU counts as one instruction).

use core::fmt::{self, Write};
use core::sync::atomic::Ordering;

use embassy_executor::{SendSpawner, SpawnError, SpawnToken, Spawner};
use embassy_time::Instant;

use crate::board::SYSCLK_HZ;
use crate::executors::THREAD_EXECUTOR_METER;
use crate::halls::{self, LATENCY};
use crate::heap::{self, HEAP_BYTES};
use crate::i2c::Bus;
use crate::meter::{self, Calibration, Joined, Meter, Usage};
use crate::stacks::{STACK_BYTES, Stack};

/// One line of output.
type Line = heapless::String<320>;

/// Print one line (cut short if it does not fit).
pub fn say(args: fmt::Arguments<'_>) {
    let mut line = Line::new();
    let _ = line.write_fmt(args);
    if line.push('\n').is_err() {
        line.pop();
        let _ = line.push('\n');
    }
    cortex_m_semihosting::hprint!("{}", line.as_str());
}

/// `say!("...", args)`: print one line.
#[macro_export]
macro_rules! say {
    ($($arg:tt)*) => { $crate::report::say(format_args!($($arg)*)) };
}

/// End the run: QEMU exits with status 0 when `pass`, 1 otherwise.
pub fn exit(pass: bool) -> ! {
    use cortex_m_semihosting::debug;
    debug::exit(if pass { debug::EXIT_SUCCESS } else { debug::EXIT_FAILURE });
    // Only reached without a debugger or emulator to exit to.
    loop {
        cortex_m::asm::wfi();
    }
}

/// Stop the run with a failure.
pub fn fail(why: &str) -> ! {
    say(format_args!("FAIL {why}"));
    exit(false)
}

/// Spawn a thread-mode task.
pub fn spawn<S>(spawner: Spawner, token: Result<SpawnToken<S>, SpawnError>) {
    match token {
        Ok(token) => spawner.spawn(token),
        Err(_) => fail("a task's pool is too small"),
    }
}

/// Spawn a task on the interrupt executor.
pub fn spawn_send<S: Send>(spawner: SendSpawner, token: Result<SpawnToken<S>, SpawnError>) {
    match token {
        Ok(token) => spawner.spawn(token),
        Err(_) => fail("a task's pool is too small"),
    }
}

/// The bus's counts and each thruster's watchdog; false if a watchdog would have bitten or a slave still holds
/// SDA.
pub fn bus(bus: &Bus) -> bool {
    let counts = bus.counts();
    let held = bus.sda_held();
    say!(
        "BUS transfers={} nacks={} timeouts={} bus_errors={}; recovery on the lines: clocks={} stops={}; SDA {}; \
         defmt frames the cores logged: {} (counted, not decoded)",
        counts.transfers,
        counts.nacks,
        counts.timeouts,
        counts.bus_errors,
        counts.pin_clocks,
        counts.pin_stops,
        if held { "STILL HELD LOW" } else { "free" },
        crate::DEFMT_FRAMES.load(Ordering::Relaxed)
    );
    say!(
        "HEAP of the bus model and the ground station: at most {} B in use of {HEAP_BYTES} B",
        heap::peak()
    );
    let mut fed = true;
    for (index, thruster) in bus.thrusters().iter().enumerate() {
        let (feeds, longest_gap_us) = thruster.watchdog();
        let bit = thruster.watchdog_bit();
        fed &= !bit;
        say!(
            "WATCHDOG thruster {} power-ups={} feeds={} longest gap={} us{}",
            index + 1,
            thruster.power_ups(),
            feeds,
            longest_gap_us,
            if bit {
                " (LONGER THAN ITS TIMEOUT: it would have reset the chip)"
            } else {
                ""
            }
        );
    }
    fed && !held
}

/// The STM32G431's clock, the figure the instruction counts are turned into time at.
const TARGET_HZ: f32 = 170e6;
/// Cycles per instruction assumed for the G431 (an assumption, not a measurement: most Cortex-M4 instructions
/// take one cycle, loads two, taken branches two to four; at 170 MHz the flash has 4 wait states behind the ART
/// accelerator's caches). Every time and load figure scales with it.
const CYCLES_PER_INSTRUCTION: f32 = 1.5;
/// Cortex-M4 exception entry and return, cycles (12 + 10; tail-chaining is quicker).
const EXCEPTION_CYCLES: f32 = 22.0;
/// A brushless thruster at full speed: 4500 rpm (IDS 8.3.2), 4 pole pairs (`Config::reference`), six hall edges
/// per electrical turn.
const FULL_SPEED_EDGES_PER_S: f32 = 4500.0 / 60.0 * 4.0 * 6.0;

/// The emulated time since boot, s.
fn seconds() -> f32 {
    Instant::now().as_micros() as f32 / 1e6
}

/// Mean instructions per poll.
fn mean(usage: &Usage) -> f32 {
    meter::instructions(u64::from(usage.cycles)) as f32 / usage.polls.max(1) as f32
}

/// One SYSCLK cycle, ns.
const CYCLE_NS: u32 = 1_000_000_000 / SYSCLK_HZ;

/// The calibration of the instruction clock.
pub fn calibration(calibration: Calibration) {
    say!(
        "CALIBRATION a loop of {} instructions took {} SYSCLK cycles of {} ns: {:.3} instructions per cycle, \
         {:.2} ns per instruction (QEMU -icount)",
        calibration.instructions,
        calibration.cycles,
        CYCLE_NS,
        calibration.instructions as f32 / calibration.cycles.max(1) as f32,
        CYCLE_NS as f32 * calibration.cycles as f32 / calibration.instructions.max(1) as f32
    );
}

/// Each stack's high-water mark, and each image's: `thread` is its thread-mode stack. False if one overflowed.
pub fn stacks(images: &[(&str, Stack)]) -> bool {
    let mut fit = true;
    for stack in Stack::ALL {
        let used = stack.high_water();
        fit &= used < STACK_BYTES;
        say!(
            "STACK {:<32} {:>6} B used of {} B{}",
            stack.name(),
            used,
            STACK_BYTES,
            if used >= STACK_BYTES { "  OVERFLOW" } else { "" }
        );
    }
    let handlers = Stack::Main.high_water();
    for (image, thread) in images {
        let thread_bytes = thread.high_water();
        let total = thread_bytes + handlers;
        say!(
            "STACK image={image} thread={thread_bytes} B + handlers={handlers} B = {total} B, {:.1} % of the G431's \
             32768 B RAM (upper bound: its deepest thread-mode poll with every handler nested on top)",
            total as f32 * 100.0 / 32768.0
        );
    }
    fit
}

/// The thread executor's own instructions per task poll: its rounds of polls, less the polls of `tasks` (every
/// thread-mode task's meter).
fn dispatch(tasks: &[&Meter]) -> f32 {
    let (cycles, polls) = tasks.iter().fold((0u64, 0u64), |(cycles, polls), meter| {
        let usage = meter.usage();
        (cycles + u64::from(usage.cycles), polls + u64::from(usage.polls))
    });
    let rounds = u64::from(THREAD_EXECUTOR_METER.usage().cycles);
    meter::instructions(rounds.saturating_sub(cycles)) as f32 / polls.max(1) as f32
}

/// One line of instructions per poll.
fn usage_line(name: fmt::Arguments<'_>, usage: &Usage, seconds: f32) {
    say!(
        "CPU {:<44} polls={:>8} per_s={:>8.1} mean={:>7.0} max={:>7}",
        name,
        usage.polls,
        usage.polls as f32 / seconds.max(1e-6),
        mean(usage),
        meter::instructions(u64::from(usage.max_cycles))
    );
}

/// The inner tasks of `set` (a bit mask over `tasks`), joined with `+`.
struct TaskSet<'a> {
    tasks: &'a [&'a str],
    set: u8,
}

impl fmt::Display for TaskSet<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.set == 0 {
            return f.write_str("none seen");
        }
        let mut first = true;
        for (bit, name) in self.tasks.iter().enumerate() {
            if self.set & (1 << bit) != 0 {
                if !first {
                    f.write_str("+")?;
                }
                f.write_str(name)?;
                first = false;
            }
        }
        Ok(())
    }
}

/// Instructions per poll of each image's joined thread-mode tasks (`joined`), in all and by the inner tasks that
/// progressed in the poll, of the test bench's own thread-mode tasks (`thread`: with `joined`, every thread-mode
/// task there is) and of the work nested in them (`nested`); the thread executor's own share.
pub fn cpu(joined: &[&Joined], thread: &[&Meter], nested: &[&Meter]) -> f32 {
    let seconds = seconds();
    say!("CPU instructions per poll, each net of the interrupts and model ports inside it; {seconds:.1} s emulated");
    for meter in joined {
        usage_line(format_args!("{}", meter.all.name), &meter.all.usage(), seconds);
        for (set, usage) in meter.classes() {
            let tasks = TaskSet {
                tasks: meter.tasks,
                set,
            };
            usage_line(format_args!("  polls in which progressed: {tasks}"), &usage, seconds);
        }
    }
    for meter in thread.iter().chain(nested) {
        usage_line(format_args!("{}", meter.name), &meter.usage(), seconds);
    }
    let every: heapless::Vec<&Meter, 8> = joined
        .iter()
        .map(|meter| &meter.all)
        .chain(thread.iter().copied())
        .collect();
    let dispatch = dispatch(&every);
    say!("CPU thread executor: {dispatch:.0} instructions per task poll of its own (its rounds less the tasks' polls)");
    dispatch
}

/// Share of a 170 MHz G431 that `instructions_per_s` take, %.
fn load_percent(instructions_per_s: f32, interrupts_per_s: f32) -> f32 {
    (instructions_per_s * CYCLES_PER_INSTRUCTION + interrupts_per_s * EXCEPTION_CYCLES) * 100.0 / TARGET_HZ
}

/// Instructions per second of `usage` as run.
fn per_second(usage: &Usage) -> f32 {
    meter::instructions(u64::from(usage.cycles)) as f32 / seconds().max(1e-6)
}

/// The CPU load of the run's one thruster at full speed.
///
/// `dispatch` is the thread executor's instructions per task poll. The thread-mode tasks (`run`) as they ran:
/// their polls per second are set by the 1 kHz fault and control ticks, the health task's 10 Hz and the I2C
/// traffic the acceptance script made, none of which depends on the motor's speed. Commutation at 4500 rpm: one
/// poll per hall edge (1800 a second from 4 pole pairs) and one per control tick (1000: the control task wakes it
/// every tick), each with its executor's interrupt, and a hall edge interrupt per edge. The time driver's alarm:
/// at most one per poll of `run` (every wake-up but an I2C transfer's is a timer's).
pub fn thruster_load(dispatch: f32) {
    use crate::thruster::{COMMUTATION_METER, THREAD_METER};
    let commutations = FULL_SPEED_EDGES_PER_S + 1000.0;
    let thread = THREAD_METER.all.usage();
    let thread_polls_per_s = thread.polls as f32 / seconds().max(1e-6);
    let terms = [
        ("thread-tasks", per_second(&thread), 0.0),
        (
            "commutation",
            (mean(&COMMUTATION_METER.usage()) + mean(&crate::executors::COMMUTATION_ISR_METER.usage())) * commutations,
            commutations,
        ),
        (
            "hall-edges",
            mean(&halls::EDGE_ISR_METER.usage()) * FULL_SPEED_EDGES_PER_S,
            FULL_SPEED_EDGES_PER_S,
        ),
        (
            "time-driver",
            mean(&crate::time::ALARM_METER.usage()) * thread_polls_per_s,
            thread_polls_per_s,
        ),
        ("thread-executor", dispatch * thread_polls_per_s, 0.0),
    ];
    let mut line = Line::new();
    let mut total = 0.0;
    for (name, instructions_per_s, interrupts_per_s) in terms {
        let percent = load_percent(instructions_per_s, interrupts_per_s);
        total += percent;
        let _ = write!(line, " {name}={percent:.2}%");
    }
    say!(
        "LOAD thruster at 4500 rpm on a 170 MHz G431 = {total:.2} % of the CPU:{}",
        line.as_str()
    );
    say!(
        "LOAD assumed: {CYCLES_PER_INSTRUCTION} cycles per instruction, {EXCEPTION_CYCLES} per interrupt, \
         {FULL_SPEED_EDGES_PER_S} hall edges/s and 1000 control wake-ups/s of commutation; thread tasks and alarms \
         as run; not included: the motor model, the real ports' ADC and timer accesses"
    );
}

/// The load of the master's tasks as they ran (`dispatch`: the thread executor's instructions per task poll).
pub fn master_load(dispatch: f32) {
    let usage = crate::master::MASTER_METER.all.usage();
    let per_s = per_second(&usage) + dispatch * usage.polls as f32 / seconds().max(1e-6);
    say!(
        "LOAD master tasks as run, with the executor's dispatch = {per_s:.0} instructions/s = {:.2} % of a 170 MHz \
         G431 (assumed {CYCLES_PER_INSTRUCTION} cycles per instruction; the time driver and the real peripherals' \
         interrupts not included)",
        load_percent(per_s, 0.0)
    );
}

/// Hall edge to commutation: the latency, and the edges that came while the thruster's thread tasks were polled.
pub fn latency() {
    let figures = LATENCY.figures();
    let instructions = |cycles: u32| meter::instructions(u64::from(cycles));
    let micros = |cycles: u32| {
        // Two exception entries: the hall edge's and the commutation executor's (tail-chained or preempting).
        (instructions(cycles) as f32 * CYCLES_PER_INSTRUCTION + 2.0 * EXCEPTION_CYCLES) / TARGET_HZ * 1e6
    };
    let longest_poll = crate::thruster::THREAD_METER.all.usage().max_cycles;
    say!(
        "LATENCY hall edge (APB timer 1 interrupt) to the commutation task polled: edges={} mean={} worst={} \
         instructions, worst {:.2} us at 170 MHz",
        figures.edges,
        instructions(figures.sum) / u64::from(figures.edges.max(1)),
        instructions(figures.worst),
        micros(figures.worst)
    );
    say!(
        "LATENCY while the thruster's thread tasks (run: the 1 kHz fault and control tasks, I2C, health) were being \
         polled: edges={} worst={} instructions ({:.2} us at 170 MHz); their longest poll is {} instructions, so \
         without preemption the worst would be at least that",
        figures.during_thread_tasks,
        instructions(figures.worst_during_thread_tasks),
        micros(figures.worst_during_thread_tasks),
        instructions(longest_poll)
    );
}
