//! The master on the bench: the real master core (lbv-master-fw's tasks) with its thruster bus, its CAN
//! receiver and its console link simulated. Its thruster bus runs either the vehicle's polling task or the
//! acceptance test, whose operator is the scenario (through a [`Desk`]).

use core::cell::{Cell, RefCell};
use core::convert::Infallible;
use std::collections::VecDeque;

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use lbv_master_fw::acceptance::{
    AcceptanceConfig, Operator, Prompt, StepResult, Verdict, acceptance_test, step_text, verdict_text,
};
use lbv_master_fw::battery::{CanFrame, CanReceiver, can_task};
use lbv_master_fw::console::{ConsoleConfig, ConsoleStats, console_rx_task, console_tx_task};
use lbv_master_fw::shared::Shared;
use lbv_master_fw::thrusters::{PollConfig, ThrusterSlot, bus_task};
use lbv_master_fw::vehicle::{VehicleConfig, vehicle_task};
use tmc_proto::Family;

use super::executor::Executor;
use super::i2c::{BusWorld, MasterPort};

/// A byte or frame queue with a wake-up for its reader.
#[derive(Default)]
pub struct Pipe<T> {
    queue: RefCell<VecDeque<T>>,
    ready: Signal<CriticalSectionRawMutex, ()>,
}

impl<T> Pipe<T> {
    /// Queue items and wake the reader.
    pub fn send(&self, items: impl IntoIterator<Item = T>) {
        self.queue.borrow_mut().extend(items);
        self.ready.signal(());
    }

    /// The next item, waiting for one.
    async fn receive(&self) -> T {
        loop {
            if let Some(item) = self.queue.borrow_mut().pop_front() {
                return item;
            }
            self.ready.wait().await;
        }
    }
}

/// The master's console serial port, seen from the master.
struct ConsoleRx(&'static Pipe<u8>);

impl embedded_io_async::ErrorType for ConsoleRx {
    type Error = Infallible;
}

impl embedded_io_async::Read for ConsoleRx {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        let Some(first) = buf.first_mut() else { return Ok(0) };
        *first = self.0.receive().await;
        let mut n = 1;
        let mut queue = self.0.queue.borrow_mut();
        for slot in buf.iter_mut().skip(1) {
            let Some(byte) = queue.pop_front() else { break };
            *slot = byte;
            n += 1;
        }
        Ok(n)
    }
}

struct ConsoleTx(&'static RefCell<Vec<u8>>);

impl embedded_io_async::ErrorType for ConsoleTx {
    type Error = Infallible;
}

impl embedded_io_async::Write for ConsoleTx {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        self.0.borrow_mut().extend_from_slice(buf);
        Ok(buf.len())
    }

    async fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}

struct Can(&'static Pipe<CanFrame>);

impl CanReceiver for Can {
    type Error = Infallible;

    async fn receive(&mut self) -> Result<CanFrame, Infallible> {
        Ok(self.0.receive().await)
    }
}

/// Between the master's acceptance test and the scenario acting as the person at the bench: the steps reported,
/// the verdict, and the prompt waiting to be acted on.
#[derive(Default)]
pub struct Desk {
    /// Each step's result, in order.
    pub results: RefCell<Vec<StepResult>>,
    /// The verdict, once the script has ended.
    pub verdict: Cell<Option<Verdict>>,
    /// A prompt the scenario has not acted on yet.
    pub request: Cell<Option<(Prompt, Family)>>,
    /// Raised by the scenario once it has done what was asked.
    pub done: Signal<CriticalSectionRawMutex, ()>,
}

/// The test's operator: hands the prompt to the scenario and waits until it is done (a prompt acted on during the
/// traffic returns at once).
struct DeskOperator(&'static Desk);

impl Operator for DeskOperator {
    async fn prompt(&mut self, what: Prompt, family: Family) {
        self.0.done.reset();
        self.0.request.set(Some((what, family)));
        if !what.during_traffic() {
            self.0.done.wait().await;
        }
    }
}

/// The master node and its links.
pub struct Master {
    /// The master's task channels: orders, thruster reports, battery summary, vehicle state.
    pub shared: &'static Shared,
    /// The thruster bus.
    pub bus: &'static RefCell<BusWorld>,
    /// Bytes from the ground station to the master.
    pub console_in: &'static Pipe<u8>,
    /// Bytes the master sent to the ground station, not yet collected.
    pub console_out: &'static RefCell<Vec<u8>>,
    /// CAN frames from the battery board.
    pub can: &'static Pipe<CanFrame>,
    /// The console's counters.
    pub console_stats: &'static ConsoleStats,
    /// With the acceptance test instead of the polling task: its results and prompts.
    pub desk: Option<&'static Desk>,
}

impl Master {
    /// The master with the thruster `table` on one bus, its tasks started.
    pub fn start(table: &'static [ThrusterSlot], bus: BusWorld, executor: &mut Executor<'static>) -> &'static Master {
        Self::start_with(table, bus, executor, None)
    }

    /// The master image built for the acceptance test: the test runs on the bus instead of the polling task.
    pub fn start_acceptance(
        table: &'static [ThrusterSlot],
        bus: BusWorld,
        executor: &mut Executor<'static>,
        config: AcceptanceConfig,
    ) -> &'static Master {
        Self::start_with(table, bus, executor, Some(config))
    }

    fn start_with(
        table: &'static [ThrusterSlot],
        bus: BusWorld,
        executor: &mut Executor<'static>,
        acceptance: Option<AcceptanceConfig>,
    ) -> &'static Master {
        let thrusters = u8::try_from(table.len()).unwrap_or(u8::MAX);
        let master: &'static Master = Box::leak(Box::new(Master {
            shared: Box::leak(Box::new(Shared::new())),
            bus: Box::leak(Box::new(RefCell::new(bus))),
            console_in: Box::leak(Box::default()),
            console_out: Box::leak(Box::default()),
            can: Box::leak(Box::default()),
            console_stats: Box::leak(Box::new(ConsoleStats::new())),
            desk: acceptance.map(|_| &*Box::leak(Box::default())),
        }));
        let console: &'static ConsoleConfig = Box::leak(Box::new(ConsoleConfig {
            thrusters,
            ..ConsoleConfig::DEFAULT
        }));
        let shared = master.shared;
        match (acceptance, master.desk) {
            (Some(config), Some(desk)) => executor.spawn(async move {
                let mut report = |result: StepResult| {
                    let (severity, text) = step_text(&result);
                    shared.say(severity, text);
                    desk.results.borrow_mut().push(result);
                };
                let mut operator = DeskOperator(desk);
                let verdict = acceptance_test(&mut MasterPort(master.bus), &mut operator, &config, &mut report).await;
                let (severity, text) = verdict_text(&verdict);
                shared.say(severity, text);
                desk.verdict.set(Some(verdict));
            }),
            _ => executor.spawn(async move {
                bus_task(&mut MasterPort(master.bus), 0, table, &PollConfig::DEFAULT, shared).await;
            }),
        };
        executor.spawn(async move {
            can_task(&mut Can(master.can), shared).await;
        });
        executor.spawn(async move {
            console_rx_task(&mut ConsoleRx(master.console_in), console, shared, master.console_stats).await;
        });
        executor.spawn(async move {
            console_tx_task(
                &mut ConsoleTx(master.console_out),
                console,
                shared,
                master.console_stats,
            )
            .await;
        });
        executor.spawn(async move {
            let config = VehicleConfig {
                thrusters,
                ..VehicleConfig::DEFAULT
            };
            vehicle_task(config, config.defaults(), shared).await;
        });
        master
    }
}
