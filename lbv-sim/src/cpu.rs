//! A board's CPU as the simulation sees it: something that can stall.
//!
//! On the STM32G431 a flash erase or write stalls the CPU and every interrupt until it is done (one flash bank, and
//! the code runs from it: RM0440 3.3.6, 3.3.7). The simulated [`crate::flash`] tells the [`Cpu`] it is wired to; the
//! [`crate::Executor`] polls no task spawned on a stalled CPU until the stall ends (its wakes wait till then), while
//! the rest of the world (the other boards, the buses) goes on; an I2C master on a stalled CPU keeps its transfer
//! waiting on the CPU ([`crate::i2c::Bus::set_master_cpu`]).

use alloc::rc::Rc;
use core::cell::Cell;

use embassy_time::{Duration, Instant};

#[derive(Debug, Default)]
struct State {
    /// Stalled until then (if later than now).
    until: Cell<Option<Instant>>,
    /// Every stall so far, added up.
    total: Cell<Duration>,
    /// Stalls so far.
    stalls: Cell<u64>,
}

/// A CPU; clones are handles on the same one.
#[derive(Debug, Clone, Default)]
pub struct Cpu(Rc<State>);

impl Cpu {
    /// A CPU that runs.
    pub fn new() -> Self {
        Self::default()
    }

    /// Stall it for `duration` from now, or from the end of a stall under way (work done in one poll adds up).
    pub fn stall(&self, duration: Duration) {
        let now = Instant::now();
        let from = self.0.until.get().map_or(now, |until| until.max(now));
        self.0.until.set(Some(from + duration));
        self.0.total.set(self.0.total.get() + duration);
        self.0.stalls.set(self.0.stalls.get().saturating_add(1));
    }

    /// A reset or a power cycle: a stall under way ends now.
    pub fn reset(&self) {
        self.0.until.set(None);
    }

    /// When the stall under way ends; `None` when it runs.
    pub fn stalled_until(&self) -> Option<Instant> {
        self.0.until.get().filter(|until| *until > Instant::now())
    }

    /// Every stall so far, added up.
    pub fn stalled_total(&self) -> Duration {
        self.0.total.get()
    }

    /// Stalls so far.
    pub fn stalls(&self) -> u64 {
        self.0.stalls.get()
    }
}
