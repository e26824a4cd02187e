//! A single-threaded executor for the bench: it polls only the tasks that were woken, and never moves time
//! itself. The bench runs it until nothing is ready, then advances the virtual clock.

use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::task::{Context, Poll, Wake, Waker};

/// The bench's tasks are firmware task bodies that never end, and bench processes that do.
type Task<'a> = Pin<Box<dyn Future<Output = ()> + 'a>>;

/// A task's wake-up flag.
struct Flag(AtomicBool);

impl Wake for Flag {
    fn wake(self: Arc<Self>) {
        self.0.store(true, Ordering::Relaxed);
    }

    fn wake_by_ref(self: &Arc<Self>) {
        self.0.store(true, Ordering::Relaxed);
    }
}

struct Slot<'a> {
    task: Option<Task<'a>>,
    flag: Arc<Flag>,
    waker: Waker,
}

/// Tasks by id; a removed task leaves an empty slot so ids stay valid.
#[derive(Default)]
pub struct Executor<'a> {
    slots: Vec<Slot<'a>>,
    polls: u64,
}

/// A task's handle, for removing it (a thruster that resets).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TaskId(usize);

/// A task that keeps waking itself without waiting for anything would hold the bench at one instant forever.
const MAX_ROUNDS: usize = 10_000;

impl<'a> Executor<'a> {
    /// Add a task; it is polled at the next run.
    pub fn spawn(&mut self, task: impl Future<Output = ()> + 'a) -> TaskId {
        let flag = Arc::new(Flag(AtomicBool::new(true)));
        let waker = Waker::from(flag.clone());
        self.slots.push(Slot {
            task: Some(Box::pin(task)),
            flag,
            waker,
        });
        TaskId(self.slots.len() - 1)
    }

    /// Drop a task, as a reset drops a controller's work in progress.
    pub fn remove(&mut self, id: TaskId) {
        if let Some(slot) = self.slots.get_mut(id.0) {
            slot.task = None;
        }
    }

    /// Poll woken tasks until none is left woken. Returns false if tasks were still waking one another after
    /// many rounds (a busy loop in a task).
    pub fn run_until_idle(&mut self) -> bool {
        for _ in 0..MAX_ROUNDS {
            let mut polled = false;
            for slot in &mut self.slots {
                if !slot.flag.0.swap(false, Ordering::Relaxed) {
                    continue;
                }
                let Some(task) = slot.task.as_mut() else { continue };
                polled = true;
                self.polls += 1;
                if task.as_mut().poll(&mut Context::from_waker(&slot.waker)) == Poll::Ready(()) {
                    slot.task = None;
                }
            }
            if !polled {
                return true;
            }
        }
        false
    }

    /// Task polls so far, for the bench's performance figures.
    pub fn polls(&self) -> u64 {
        self.polls
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
    use embassy_sync::signal::Signal;
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
        signal.signal(8);
        assert!(executor.run_until_idle());
        assert_eq!(got.get(), 7, "finished tasks are not polled again");
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
    }
}
