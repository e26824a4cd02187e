//! The master on the bench: the master as it ships (`lbv_master_fw::run` with the production configuration) on
//! the bench's simulated buses, CAN bus and console link. Its thruster buses run either the vehicle's polling or
//! the acceptance script, whose operator is the scenario (through a [`Desk`]).
//!
//! What the master is wired to ([`Wiring`]) lives as long as the bench, and so does its flash
//! ([`MasterBoard::flash`], the G431's 128 KiB with the settings in their pages); the node itself (its tasks and
//! their state) is dropped and booted afresh by [`MasterBoard::reboot`], which the bench also calls when the
//! master asks for it (MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN). Both images keep their settings in that flash.
//!
//! The master runs on a [`Cpu`] its flash stalls as the G431's does ([`FlashTiming::G431`]: a page erase 25 ms):
//! meanwhile none of its tasks runs, and a transfer it has under way on a thruster bus waits for it. A reset ends
//! a stall.

use core::cell::{Cell, RefCell};
use std::rc::Rc;

use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::signal::Signal;
use lbv_master_fw::acceptance::report::{Prompt, StepResult, Verdict};
use lbv_master_fw::acceptance::{Operator, Script};
use lbv_master_fw::battery::CanFrame;
use lbv_master_fw::console::ConsoleStats;
use lbv_master_fw::courier::Transfers;
use lbv_master_fw::shared::BUSES;
use lbv_master_fw::shared::Shared;
use lbv_master_fw::update::ThrusterSink;
use lbv_master_fw::{MasterConfig, Polling, Ports};
use lbv_sim::flash::{FlashTiming, Stm32g4Flash};
use lbv_sim::i2c::Bus;
use lbv_sim::{Cpu, Executor, Queue, SerialRx, SerialTx, TaskId};
use tmc_proto::Family;

use super::ports::master::{CanNode, RebootRequest, Recorded, UpdateRecorder, flash_store, master_flash, thruster_bus};

/// What the master's ports are wired to: its three thruster buses, its CAN node's receive queue and its console
/// link, both ways.
#[derive(Debug, Clone)]
pub struct Wiring {
    /// I2C1..3.
    pub buses: [Bus; BUSES],
    /// Frames on the battery CAN bus for the master.
    pub can: Queue<CanFrame>,
    /// Bytes from the ground station to the master.
    pub console_in: Queue<u8>,
    /// Bytes the master sent to the ground station, not yet collected.
    pub console_out: Queue<u8>,
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
    pub done: Signal<NoopRawMutex, ()>,
}

/// The test's operator: hands the prompt to the scenario and waits until it is done (a prompt acted on during the
/// traffic returns at once).
struct DeskOperator(Rc<Desk>);

impl Operator for DeskOperator {
    async fn prompt(&mut self, what: Prompt, family: Family) {
        self.0.done.reset();
        self.0.request.set(Some((what, family)));
        if !what.during_traffic() {
            self.0.done.wait().await;
        }
    }

    fn reported(&mut self, result: &StepResult) {
        self.0.results.borrow_mut().push(result.clone());
    }

    fn concluded(&mut self, verdict: &Verdict) {
        self.0.verdict.set(Some(*verdict));
    }
}

/// The master node on the bench.
pub struct MasterBoard {
    /// Its configuration.
    pub config: MasterConfig,
    /// Whether it is the acceptance image (the script instead of the polling).
    acceptance: bool,
    /// Its tasks' channels: orders, thruster reports, battery summary, vehicle state.
    pub shared: Rc<Shared>,
    /// The console's counters.
    pub console_stats: Rc<ConsoleStats>,
    /// With the acceptance script: its results and prompts.
    pub desk: Option<Rc<Desk>>,
    /// Its flash: kept across reboots and power cycles (a handle; cut its power to cut the master's).
    pub flash: Stm32g4Flash,
    /// Times it has booted.
    pub boots: u32,
    /// Its CPU: the flash's erases and writes stall it.
    pub cpu: Cpu,
    /// Where its update images go: every one recorded, across reboots.
    pub updates: UpdateRecorder,
    reboot: RebootRequest,
    task: Option<TaskId>,
}

/// The unique device id the bench's master reports in AUTOPILOT_VERSION, where a G431 reports its own: a fixed
/// one ("LBV bench 01" in ASCII), so that every run reports the same.
pub const BENCH_UID: [u8; 12] = *b"LBV bench 01";

impl MasterBoard {
    /// The master with `config` (and [`BENCH_UID`]), booted on `wiring`; with `acceptance`, the acceptance image.
    pub fn boot(config: MasterConfig, acceptance: bool, wiring: &Wiring, executor: &mut Executor<'static>) -> Self {
        let mut config = config;
        config.console.uid = BENCH_UID;
        let cpu = Cpu::new();
        let flash = master_flash();
        flash.stall_cpu(&cpu, FlashTiming::G431);
        for bus in &wiring.buses {
            bus.set_master_cpu(&cpu);
        }
        let mut board = Self {
            config,
            acceptance,
            shared: Rc::new(Shared::new()),
            console_stats: Rc::new(ConsoleStats::new()),
            desk: None,
            flash,
            boots: 0,
            cpu,
            updates: UpdateRecorder::default(),
            reboot: RebootRequest::default(),
            task: None,
        };
        board.start(wiring, executor);
        board
    }

    /// Whether the master has asked to restart since it booted.
    pub fn reboot_requested(&self) -> bool {
        self.reboot.requested() > 0
    }

    /// Reset the master: its tasks stop where they are and it boots again with fresh state (a CAN controller that
    /// restarts has an empty receive FIFO). What it is wired to and its flash stay as they are; a flash whose power
    /// was cut has it back (a power cycle is a reset that may tear a flash write).
    pub fn reboot(&mut self, wiring: &Wiring, executor: &mut Executor<'static>) {
        if let Some(task) = self.task.take() {
            executor.remove(task);
        }
        self.shared = Rc::new(Shared::new());
        self.console_stats = Rc::new(ConsoleStats::new());
        wiring.can.clear();
        self.cpu.reset();
        self.flash.power_on();
        self.start(wiring, executor);
    }

    fn start(&mut self, wiring: &Wiring, executor: &mut Executor<'static>) {
        self.reboot = RebootRequest::default();
        self.boots += 1;
        let script = self.acceptance.then(|| {
            let desk = Rc::new(Desk::default());
            self.desk = Some(desk.clone());
            Script(DeskOperator(desk))
        });
        self.task = Some(self.spawn(wiring, executor, script));
    }

    /// The node on its ports: the acceptance `script` on its thruster buses, or without one the vehicle's polling,
    /// which carries the update images the console receives to the thrusters (each recorded too).
    fn spawn(&self, wiring: &Wiring, executor: &mut Executor<'static>, script: Option<Script<DeskOperator>>) -> TaskId {
        let ports = Ports {
            buses: wiring.buses.each_ref().map(|bus| thruster_bus(bus, &self.config.bus)),
            can: CanNode(wiring.can.clone()),
            console_rx: SerialRx::new(wiring.console_in.clone()),
            console_tx: SerialTx(wiring.console_out.clone()),
            settings: flash_store(&self.flash),
            reboot: self.reboot.clone(),
            work: (),
            update: (),
        };
        let recorder = self.updates.clone();
        let (config, shared, stats) = (self.config, self.shared.clone(), self.console_stats.clone());
        executor.spawn_on(&self.cpu, async move {
            // The node's static: what its console hands on and its bus tasks carry.
            let transfers = Transfers::new();
            let update = Recorded {
                recorder,
                sink: ThrusterSink::new(&transfers),
            };
            match script {
                Some(script) => lbv_master_fw::run(with(ports, script, update), &config, &shared, &stats).await,
                None => {
                    let polling = Polling {
                        transfers: Some(&transfers),
                    };
                    lbv_master_fw::run(with(ports, polling, update), &config, &shared, &stats).await
                }
            }
        })
    }
}

/// `ports` with `work` on the thruster buses and `update` for the images.
fn with<B, C, R, W, S, X, J, U>(
    ports: Ports<B, C, R, W, S, X, (), ()>,
    work: J,
    update: U,
) -> Ports<B, C, R, W, S, X, J, U> {
    Ports {
        buses: ports.buses,
        can: ports.can,
        console_rx: ports.console_rx,
        console_tx: ports.console_tx,
        settings: ports.settings,
        reboot: ports.reboot,
        work,
        update,
    }
}
