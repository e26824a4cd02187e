//! Hall edges as a hardware interrupt, and their latency.
//!
//! On the STM32 a hall edge is an EXTI interrupt whose handler wakes the commutation task; here APB timer 1 fires
//! when the motor model's rotor is due to cross into the next hall sector, and its handler wakes the commutation
//! task the same way. The interrupt executor then polls that task: the time from the timer's expiry to that poll
//! is the latency [`LATENCY`] keeps, apart for the edges that came while the thruster's thread-mode tasks (the
//! 1 kHz fault and control tasks among them, joined in `thruster_fw::run`) were being polled. One thruster at a
//! time can have these halls (there is one such timer).

use core::future::poll_fn;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use core::task::Poll;

use embassy_sync::waitqueue::AtomicWaker;
use embassy_time::Duration;
use thruster_fw::hall::HallState;
use thruster_fw::motorless::Motorless;
use thruster_fw::ports::HallSensors;

use crate::board::{self, Irq, Priority, SYSCLK_HZ, TIMER1};
use crate::meter::{self, Meter, THRUSTER_THREAD_BUSY};
use crate::thruster::MOTOR_MODEL_METER;

/// The hall edge's handler.
pub static EDGE_ISR_METER: Meter = Meter::nested("hall edge ISR");
/// Longest wait for an edge before the model is looked at again (a rotor at rest has no edge to predict), as
/// the core's model halls do.
const EDGE_POLL: Duration = Duration::from_millis(5);

static WAKER: AtomicWaker = AtomicWaker::new();
static FIRED: AtomicBool = AtomicBool::new(false);
/// The SYSCLK cycle at which the armed edge is due.
static DEADLINE: AtomicU32 = AtomicU32::new(0);
/// The last edge came while the thruster's thread-mode tasks were being polled.
static DURING_THREAD_TASKS: AtomicBool = AtomicBool::new(false);

/// Latency from hall edges to the commutation task, in SYSCLK cycles.
#[derive(Debug)]
pub struct Latency {
    edges: AtomicU32,
    sum: AtomicU32,
    worst: AtomicU32,
    during_thread_tasks: AtomicU32,
    worst_during_thread_tasks: AtomicU32,
}

/// What [`Latency`] saw.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LatencyFigures {
    /// Edges that reached the commutation task through the interrupt.
    pub edges: u32,
    /// Their latencies summed.
    pub sum: u32,
    /// The longest.
    pub worst: u32,
    /// Edges that came while the thruster's thread-mode tasks were being polled.
    pub during_thread_tasks: u32,
    /// The longest of those.
    pub worst_during_thread_tasks: u32,
}

impl Latency {
    const fn new() -> Self {
        Self {
            edges: AtomicU32::new(0),
            sum: AtomicU32::new(0),
            worst: AtomicU32::new(0),
            during_thread_tasks: AtomicU32::new(0),
            worst_during_thread_tasks: AtomicU32::new(0),
        }
    }

    fn record(&self, cycles: u32, during_thread_tasks: bool) {
        self.edges.fetch_add(1, Ordering::Relaxed);
        self.sum.fetch_add(cycles, Ordering::Relaxed);
        self.worst.fetch_max(cycles, Ordering::Relaxed);
        if during_thread_tasks {
            self.during_thread_tasks.fetch_add(1, Ordering::Relaxed);
            self.worst_during_thread_tasks.fetch_max(cycles, Ordering::Relaxed);
        }
    }

    /// What it saw.
    pub fn figures(&self) -> LatencyFigures {
        LatencyFigures {
            edges: self.edges.load(Ordering::Relaxed),
            sum: self.sum.load(Ordering::Relaxed),
            worst: self.worst.load(Ordering::Relaxed),
            during_thread_tasks: self.during_thread_tasks.load(Ordering::Relaxed),
            worst_during_thread_tasks: self.worst_during_thread_tasks.load(Ordering::Relaxed),
        }
    }
}

/// Hall edge to commutation task.
pub static LATENCY: Latency = Latency::new();

/// Let the hall edge interrupt, at the priority the STM32 image's EXTI interrupts have.
pub fn init() {
    board::enable(Irq::Timer1, Priority::Highest);
}

/// Make the next edge come `wait` from now.
fn arm(wait: Duration) {
    TIMER1.stop();
    cortex_m::peripheral::NVIC::unpend(Irq::Timer1);
    FIRED.store(false, Ordering::Release);
    let cycles = wait.as_micros().saturating_mul(u64::from(SYSCLK_HZ) / 1_000_000);
    let cycles = u32::try_from(cycles).unwrap_or(u32::MAX).max(1);
    DEADLINE.store(meter::cycles().wrapping_add(cycles), Ordering::Relaxed);
    TIMER1.one_shot(cycles);
}

/// APB timer 1's interrupt: the edge.
pub extern "C" fn on_edge() {
    meter::measure(&EDGE_ISR_METER, || {
        TIMER1.stop();
        DURING_THREAD_TASKS.store(THRUSTER_THREAD_BUSY.load(Ordering::Relaxed), Ordering::Relaxed);
        FIRED.store(true, Ordering::Release);
        WAKER.wake();
    });
}

/// The halls of a motor model, their edges delivered by APB timer 1's interrupt.
#[derive(Debug)]
pub struct EdgeHalls {
    motorless: &'static Motorless,
    seen: HallState,
}

impl EdgeHalls {
    /// The halls of `motorless`.
    pub fn new(motorless: &'static Motorless) -> Self {
        Self {
            motorless,
            seen: hall_state(motorless),
        }
    }
}

/// The model's hall state now (the model's arithmetic is counted apart from the core's).
fn hall_state(motorless: &Motorless) -> HallState {
    meter::measure(&MOTOR_MODEL_METER, || motorless.now().hall_state())
}

impl HallSensors for EdgeHalls {
    async fn wait_for_edge(&mut self) {
        loop {
            let model = meter::measure(&MOTOR_MODEL_METER, || self.motorless.now());
            if model.hall_state() != self.seen {
                return;
            }
            arm(model.until_next_edge().map_or(EDGE_POLL, |wait| wait.min(EDGE_POLL)));
            let latency = poll_fn(|cx| {
                WAKER.register(cx.waker());
                if FIRED.swap(false, Ordering::Acquire) {
                    Poll::Ready(meter::cycles().wrapping_sub(DEADLINE.load(Ordering::Relaxed)))
                } else {
                    Poll::Pending
                }
            })
            .await;
            // An edge when the rotor did cross; otherwise the model's look at a rotor at rest, or a prediction that a
            // change of speed made early.
            if hall_state(self.motorless) != self.seen {
                LATENCY.record(latency, DURING_THREAD_TASKS.load(Ordering::Relaxed));
                return;
            }
        }
    }

    fn read(&mut self) -> HallState {
        self.seen = hall_state(self.motorless);
        self.seen
    }
}
