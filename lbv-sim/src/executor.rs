//! A single-threaded executor on virtual time: it polls only the tasks that were woken, in the order they were
//! woken, and never moves time itself unless asked to ([`Executor::run_for`]).
//!
//! Tasks are firmware task bodies (which never end) and the simulation's own processes (which may). A task can be
//! removed at any point, as a reset drops a controller's work in progress; its slot is then reused, and a waker
//! left behind by the removed task (in a timer queue, a signal) can never wake the task that took the slot over.

use std::cell::RefCell;
use std::collections::VecDeque;
use std::future::Future;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Wake, Waker};

use embassy_time::{Duration, Instant};

use crate::clock::{self, Clock};
use crate::cpu::Cpu;

type Task<'a> = Pin<Box<dyn Future<Output = ()> + 'a>>;

/// A task's handle, for removing it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TaskId {
    index: usize,
    generation: u32,
}

/// Executors made so far: each has its own number.
static EXECUTORS: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    /// The tasks woken on this thread for each executor living on it, by the executor's number, in wake order: a
    /// wake on the executor's own thread (the usual kind) takes no lock.
    static WOKEN: RefCell<Vec<(usize, VecDeque<TaskId>)>> = const { RefCell::new(Vec::new()) };
}

/// The tasks woken and not yet polled, in wake order: on the executor's thread in [`WOKEN`], from any other thread
/// behind a lock.
#[derive(Debug)]
struct ReadyQueue {
    executor: usize,
    elsewhere: Mutex<VecDeque<TaskId>>,
}

impl ReadyQueue {
    /// A queue for a new executor, on this thread.
    fn new() -> Self {
        let executor = EXECUTORS.fetch_add(1, Ordering::Relaxed);
        let _ = WOKEN.try_with(|woken| woken.borrow_mut().push((executor, VecDeque::new())));
        Self {
            executor,
            elsewhere: Mutex::default(),
        }
    }

    fn push(&self, id: TaskId) {
        let here = WOKEN.try_with(|woken| {
            let mut woken = woken.borrow_mut();
            let queue = woken.iter_mut().find(|(executor, _)| *executor == self.executor);
            queue.map(|(_, queue)| queue.push_back(id)).is_some()
        });
        if here != Ok(true) {
            self.lock().push_back(id);
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, VecDeque<TaskId>> {
        self.elsewhere.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// Move everything queued to the end of `batch`, keeping the order (those woken on this thread first).
    fn take_into(&self, batch: &mut VecDeque<TaskId>) {
        let _ = WOKEN.try_with(|woken| {
            let mut woken = woken.borrow_mut();
            if let Some((_, queue)) = woken.iter_mut().find(|(executor, _)| *executor == self.executor) {
                if batch.is_empty() {
                    core::mem::swap(queue, batch);
                } else {
                    batch.extend(queue.drain(..));
                }
            }
        });
        let mut elsewhere = self.lock();
        if !elsewhere.is_empty() {
            batch.extend(elsewhere.drain(..));
        }
    }

    /// Put `ids` back in front of what is queued, in their order.
    fn put_back(&self, ids: &mut VecDeque<TaskId>) {
        let _ = WOKEN.try_with(|woken| {
            let mut woken = woken.borrow_mut();
            if let Some((_, queue)) = woken.iter_mut().find(|(executor, _)| *executor == self.executor) {
                while let Some(id) = ids.pop_back() {
                    queue.push_front(id);
                }
            }
        });
        let mut elsewhere = self.lock();
        while let Some(id) = ids.pop_back() {
            elsewhere.push_front(id);
        }
    }
}

impl Drop for ReadyQueue {
    fn drop(&mut self) {
        let _ = WOKEN.try_with(|woken| woken.borrow_mut().retain(|(executor, _)| *executor != self.executor));
    }
}

/// One task's waker: queues the task once, however often it is woken before it is polled.
#[derive(Debug)]
struct TaskWaker {
    id: TaskId,
    queued: AtomicBool,
    ready: Arc<ReadyQueue>,
}

impl Wake for TaskWaker {
    fn wake(self: Arc<Self>) {
        self.wake_by_ref();
    }

    fn wake_by_ref(self: &Arc<Self>) {
        // A task woken again before its poll is queued once: the plain load spares the swap then.
        if !self.queued.load(Ordering::Relaxed) && !self.queued.swap(true, Ordering::Relaxed) {
            self.ready.push(self.id);
        }
    }
}

struct Slot<'a> {
    task: Option<Task<'a>>,
    generation: u32,
    waker: Arc<TaskWaker>,
    /// `waker` as a [`Waker`], made once: polls borrow it.
    handle: Waker,
    /// The CPU it runs on, if one that can stall.
    cpu: Option<Cpu>,
}

/// Polls woken tasks; see the module documentation.
pub struct Executor<'a> {
    slots: Vec<Slot<'a>>,
    free: Vec<usize>,
    ready: Arc<ReadyQueue>,
    /// The woken tasks being polled, taken from `ready` a batch at a time (kept for its allocation).
    batch: VecDeque<TaskId>,
    polls: u64,
    busy_runs: u32,
}

/// A task that keeps waking itself without waiting for anything would hold the run at one instant forever: one
/// run polls at most this many times.
const MAX_POLLS_PER_RUN: u32 = 100_000;

impl Default for Executor<'_> {
    fn default() -> Self {
        Self::new()
    }
}

impl core::fmt::Debug for Executor<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Executor")
            .field("tasks", &self.tasks())
            .field("polls", &self.polls)
            .finish_non_exhaustive()
    }
}

impl<'a> Executor<'a> {
    /// No tasks.
    pub fn new() -> Self {
        Self {
            slots: Vec::new(),
            free: Vec::new(),
            ready: Arc::new(ReadyQueue::new()),
            batch: VecDeque::new(),
            polls: 0,
            busy_runs: 0,
        }
    }

    /// Add a task; it is polled at the next run.
    pub fn spawn(&mut self, task: impl Future<Output = ()> + 'a) -> TaskId {
        self.spawn_task(task, None)
    }

    /// Add a task that runs on `cpu`: while the CPU is stalled the task is not polled; what wakes it meanwhile
    /// takes effect when the stall ends.
    pub fn spawn_on(&mut self, cpu: &Cpu, task: impl Future<Output = ()> + 'a) -> TaskId {
        self.spawn_task(task, Some(cpu.clone()))
    }

    fn spawn_task(&mut self, task: impl Future<Output = ()> + 'a, cpu: Option<Cpu>) -> TaskId {
        let index = self.free.pop().unwrap_or(self.slots.len());
        let generation = self.slots.get(index).map_or(0, |slot| slot.generation);
        let id = TaskId { index, generation };
        let waker = Arc::new(TaskWaker {
            id,
            queued: AtomicBool::new(true),
            ready: Arc::clone(&self.ready),
        });
        let slot = Slot {
            task: Some(Box::pin(task)),
            generation,
            handle: Waker::from(Arc::clone(&waker)),
            waker,
            cpu,
        };
        match self.slots.get_mut(index) {
            Some(free) => *free = slot,
            None => self.slots.push(slot),
        }
        self.ready.push(id);
        id
    }

    /// Drop a task where it stands, as a reset drops a controller's work in progress. A task already finished or
    /// removed is left alone.
    pub fn remove(&mut self, id: TaskId) {
        if let Some(slot) = self.slots.get_mut(id.index)
            && slot.generation == id.generation
            && slot.task.is_some()
        {
            Self::retire(slot, &mut self.free, id.index);
        }
    }

    fn retire(slot: &mut Slot<'a>, free: &mut Vec<usize>, index: usize) {
        slot.task = None;
        slot.generation = slot.generation.wrapping_add(1);
        free.push(index);
    }

    /// Poll woken tasks until none is left woken. Returns false if tasks were still waking one another after
    /// `MAX_POLLS_PER_RUN` polls (a busy loop in a task); the next run goes on from there.
    pub fn run_until_idle(&mut self) -> bool {
        let mut budget = MAX_POLLS_PER_RUN;
        loop {
            self.ready.take_into(&mut self.batch);
            if self.batch.is_empty() {
                return true;
            }
            while let Some(id) = self.batch.pop_front() {
                if budget == 0 {
                    self.batch.push_front(id);
                    self.ready.put_back(&mut self.batch);
                    self.busy_runs += 1;
                    return false;
                }
                budget -= 1;
                let Some(slot) = self.slots.get_mut(id.index) else {
                    continue;
                };
                if slot.generation != id.generation {
                    continue;
                }
                // Cleared before the poll: a wake during the poll queues the task again.
                slot.waker.queued.store(false, Ordering::Relaxed);
                let Some(task) = slot.task.as_mut() else {
                    continue;
                };
                // Its CPU is stalled: it is polled when the stall ends.
                if let Some(until) = slot.cpu.as_ref().and_then(Cpu::stalled_until) {
                    embassy_time_driver::schedule_wake(until.as_ticks(), &slot.handle);
                    continue;
                }
                self.polls += 1;
                if task.as_mut().poll(&mut Context::from_waker(&slot.handle)).is_ready() {
                    Self::retire(slot, &mut self.free, id.index);
                }
            }
        }
    }

    /// Run the woken tasks, then move the clock on in steps of `step` (the last one shorter if need be) until
    /// `duration` has passed, running the woken tasks after each step.
    pub fn run_for(&mut self, clock: &Clock, duration: Duration, step: Duration) {
        let end = clock.now() + duration;
        self.run_until_idle();
        while clock.now() < end {
            clock::advance(step.min(end - clock.now()));
            self.run_until_idle();
        }
    }

    /// Like [`Executor::run_for`], stopping as soon as `done` holds (checked before every step). Returns how long
    /// that took, None if it did not happen within `limit`.
    pub fn run_until(
        &mut self,
        clock: &Clock,
        limit: Duration,
        step: Duration,
        mut done: impl FnMut() -> bool,
    ) -> Option<Duration> {
        let start: Instant = clock.now();
        let end = start + limit;
        self.run_until_idle();
        loop {
            if done() {
                return Some(clock.now() - start);
            }
            if clock.now() >= end {
                return None;
            }
            clock::advance(step.min(end - clock.now()));
            self.run_until_idle();
        }
    }

    /// Tasks alive.
    pub fn tasks(&self) -> usize {
        self.slots.iter().filter(|slot| slot.task.is_some()).count()
    }

    /// Task polls so far, for performance figures.
    pub fn polls(&self) -> u64 {
        self.polls
    }

    /// Runs that ended with tasks still waking one another (should stay 0).
    pub fn busy_runs(&self) -> u32 {
        self.busy_runs
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
    use embassy_sync::signal::Signal;
    use embassy_time::Timer;
    use std::cell::Cell;

    #[test]
    fn only_woken_tasks_are_polled_and_finished_ones_are_dropped() {
        let signal: Signal<CriticalSectionRawMutex, u32> = Signal::new();
        let got = Cell::new(0);
        let mut executor = Executor::default();
        executor.spawn(async {
            got.set(signal.wait().await);
        });
        assert!(executor.run_until_idle());
        let polls = executor.polls();
        assert!(executor.run_until_idle());
        assert_eq!(executor.polls(), polls, "nothing woke it");
        signal.signal(7);
        assert!(executor.run_until_idle());
        assert_eq!(got.get(), 7);
        assert_eq!(executor.tasks(), 0);
        signal.signal(8);
        assert!(executor.run_until_idle());
        assert_eq!(got.get(), 7, "finished tasks are not polled again");
    }

    #[test]
    fn a_task_woken_on_another_thread_or_for_another_executor_is_polled() {
        let signal: Signal<CriticalSectionRawMutex, u32> = Signal::new();
        let nudge: Signal<CriticalSectionRawMutex, ()> = Signal::new();
        let (got, other_got) = (Cell::new(0), Cell::new(false));
        let mut executor = Executor::default();
        // A second executor on the same thread keeps its own wakes.
        let mut other = Executor::default();
        other.spawn(async {
            nudge.wait().await;
            other_got.set(true);
        });
        executor.spawn(async {
            got.set(signal.wait().await);
        });
        assert!(executor.run_until_idle() && other.run_until_idle());
        std::thread::scope(|scope| {
            scope.spawn(|| signal.signal(5));
        });
        nudge.signal(());
        assert!(executor.run_until_idle());
        assert_eq!((got.get(), other_got.get()), (5, false));
        assert!(other.run_until_idle());
        assert!(other_got.get());
        assert_eq!((executor.tasks(), other.tasks()), (0, 0));
    }

    #[test]
    fn a_busy_task_is_reported() {
        let mut executor = Executor::default();
        executor.spawn(async {
            loop {
                embassy_futures::yield_now().await;
            }
        });
        assert!(!executor.run_until_idle());
        assert_eq!(executor.busy_runs(), 1);
    }

    #[test]
    fn a_removed_task_stops_and_its_slot_is_reused_without_old_wakeups() {
        let signal: Signal<CriticalSectionRawMutex, ()> = Signal::new();
        let (first, second) = (Cell::new(0), Cell::new(0));
        let mut executor = Executor::default();
        let id = executor.spawn(async {
            loop {
                signal.wait().await;
                first.set(first.get() + 1);
            }
        });
        executor.run_until_idle();
        signal.signal(());
        executor.run_until_idle();
        assert_eq!(first.get(), 1);
        // The removed task's waker is still registered with the signal.
        executor.remove(id);
        let other = executor.spawn(async {
            loop {
                embassy_futures::yield_now().await;
                second.set(second.get() + 1);
                core::future::pending::<()>().await;
            }
        });
        assert_ne!(other, id, "a new generation");
        assert_eq!(executor.tasks(), 1);
        executor.run_until_idle();
        let polls = executor.polls();
        signal.signal(());
        executor.run_until_idle();
        assert_eq!(first.get(), 1, "the removed task never runs again");
        assert_eq!(executor.polls(), polls, "its old waker does not poll the new task");
        assert_eq!(second.get(), 1);
        executor.remove(id);
        assert_eq!(executor.tasks(), 1, "a stale id removes nothing");
    }

    #[test]
    fn a_task_on_a_stalled_cpu_waits_for_the_stall_while_the_others_run() {
        let clock = clock::take();
        let cpu = Cpu::new();
        let (stalled, free) = (Cell::new(None), Cell::new(None));
        let mut executor = Executor::default();
        executor.spawn_on(&cpu, async {
            Timer::after(Duration::from_millis(1)).await;
            stalled.set(Some(Instant::now()));
        });
        executor.spawn(async {
            Timer::after(Duration::from_millis(2)).await;
            free.set(Some(Instant::now()));
        });
        executor.run_until_idle();
        cpu.stall(Duration::from_millis(5));
        // Its timer falls due at 1 ms, the stall ends at 5 ms: the clock's next alarm is then.
        executor.run_for(&clock, Duration::from_millis(4), Duration::from_micros(500));
        assert_eq!((stalled.get(), free.get()), (None, Some(Instant::from_millis(2))));
        assert_eq!(clock::next_alarm(), Some(Instant::from_millis(5)));
        executor.run_for(&clock, Duration::from_millis(2), Duration::from_micros(500));
        assert_eq!(stalled.get(), Some(Instant::from_millis(5)));
        assert_eq!(executor.tasks(), 0);
    }

    #[test]
    fn runs_move_the_clock_in_steps() {
        let clock = clock::take();
        let fired = Cell::new(None);
        let mut executor = Executor::default();
        executor.spawn(async {
            Timer::after(Duration::from_micros(125)).await;
            fired.set(Some(Instant::now()));
        });
        executor.run_for(&clock, Duration::from_micros(95), Duration::from_micros(50));
        assert_eq!(clock.now(), Instant::from_micros(95), "the last step is cut short");
        assert_eq!(fired.get(), None);
        let took = executor.run_until(&clock, Duration::from_millis(1), Duration::from_micros(50), || {
            fired.get().is_some()
        });
        assert_eq!(
            fired.get(),
            Some(Instant::from_micros(145)),
            "a timer fires at the step it falls in"
        );
        assert_eq!(took, Some(Duration::from_micros(50)));
        assert_eq!(
            executor.run_until(&clock, Duration::from_micros(10), Duration::from_micros(50), || false),
            None
        );
        assert_eq!(clock.now(), Instant::from_micros(155));
    }
}
