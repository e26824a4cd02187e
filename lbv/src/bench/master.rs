//! The master on the bench: the master as it ships (`lbv_master_fw::run` with the production configuration) on
//! the bench's simulated buses, CAN bus and console link. Its thruster buses run either the vehicle's polling or
//! the acceptance script, whose operator is the scenario (through a [`Desk`]).
//!
//! What the master is wired to ([`Wiring`]) lives as long as the bench, and so does its flash
//! ([`MasterBoard::flash`], the G474's 512 KiB: a factory image in ACTIVE, the settings in their pages); the node
//! itself (its tasks and their state) is dropped and booted afresh by [`MasterBoard::reboot`], which the bench also
//! calls when the master asks for it (MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, or the restart into an update). Every
//! boot first runs the bootloader on that flash (`lbv_boot::prepare`: the swap of an update, or the revert of one
//! that never confirmed); the master's tasks start once the time its flash work takes has passed. Both images keep
//! their settings in that flash.
//!
//! The master runs on a [`Cpu`] its flash stalls as the G474's does with the code in bank 1
//! ([`FlashTiming::G474_DUAL_BANK`]): work in bank 1 stalls it (a page erase 25 ms), and meanwhile none of its tasks
//! runs; work in bank 2 (the settings, DFU) runs beside it, the task that asked for it waiting. A reset ends a
//! stall.

use core::cell::{Cell, RefCell};
use core::marker::PhantomData;
use std::rc::Rc;

use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::signal::Signal;
use g431_hw::memory::MASTER_PARTITIONS;
use lbv_boot::{CrashCount, Outcome};
use lbv_master_fw::acceptance::report::{Prompt, StepResult, Verdict};
use lbv_master_fw::acceptance::{Operator, Script};
use lbv_master_fw::blackbox::BlackBox;
use lbv_master_fw::console::ConsoleStats;
use lbv_master_fw::ports::{Board, BusWork, CanFrame, CrashRegister, OwnUpdate, Ports, UpdateSink};
use lbv_master_fw::settings::Store;
use lbv_master_fw::shared::BUSES;
use lbv_master_fw::shared::Shared;
use lbv_master_fw::update::VehicleSink;
use lbv_master_fw::update::courier::Transfers;
use lbv_master_fw::update::own::{OwnFlash, OwnImage, Updating};
use lbv_master_fw::{MasterConfig, Polling};
use lbv_sim::flash::{FlashTiming, Stm32g4Flash};
use lbv_sim::i2c::Bus;
use lbv_sim::{Cpu, Executor, LineRx, LineTx, Queue, SerialLine, SerialRx, SerialTx, TaskId};
use tmc_proto::Family;
use update_image::{INFO_LEN, INFO_OFFSET, ImageInfo, Target, Version};

use super::thruster::{made_up_image, partition};
use lbv_master_fw::sim::{
    CanNode, RebootRequest, Recorded, ThrusterBus, UpdateRecorder, flash_store, master_flash, thruster_bus,
};

/// The version of the image a bench master leaves the factory with.
pub const MASTER_FACTORY_VERSION: Version = Version::new(0, 1, 0);

/// The length of the image a bench master leaves the factory with, about the application's.
pub const MASTER_FACTORY_IMAGE_LEN: usize = 136 * 1024;

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
    /// The console link at its baud rate instead of the two queues, when the bench has one
    /// ([`crate::bench::BenchConfig::console_baud`]).
    pub console_line: Option<ConsoleLine>,
}

/// The console link at its baud rate, between the master's UART (LPUART1: 512-byte transmit and 256-byte receive
/// ring buffers, as its binding has them) and the ground station's (a PC's, which keeps up).
#[derive(Debug, Clone)]
pub struct ConsoleLine {
    /// Ground station to master: what finds the master's 256-byte receive buffer full is lost.
    pub to_master: SerialLine,
    /// Master to ground station.
    pub from_master: SerialLine,
}

impl ConsoleLine {
    /// The master's transmit buffer, as its binding has it (`stm32.rs`).
    pub const MASTER_TX_BUFFER: usize = 512;
    /// The master's receive buffer, as its binding has it (`stm32.rs`).
    pub const MASTER_RX_BUFFER: usize = 256;

    /// A link at `baud` both ways.
    pub fn new(baud: u32) -> Self {
        Self {
            to_master: SerialLine::new(baud, usize::MAX, Self::MASTER_RX_BUFFER),
            from_master: SerialLine::new(baud, Self::MASTER_TX_BUFFER, usize::MAX),
        }
    }
}

/// The master's console receive port: the bench's instant queue, or the line at its baud rate.
#[derive(Debug)]
pub enum ConsoleRx {
    /// Every byte at once.
    Instant(SerialRx),
    /// At the line's rate, into the UART's buffer.
    Line(LineRx),
}

impl embedded_io_async::ErrorType for ConsoleRx {
    type Error = core::convert::Infallible;
}

impl embedded_io_async::Read for ConsoleRx {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        match self {
            Self::Instant(rx) => rx.read(buf).await,
            Self::Line(rx) => rx.read(buf).await,
        }
    }
}

/// The master's console transmit port: the bench's instant queue, or the line at its baud rate.
#[derive(Debug)]
pub enum ConsoleTx {
    /// Every byte at once.
    Instant(SerialTx),
    /// At the line's rate, through the UART's buffer.
    Line(LineTx),
}

impl embedded_io_async::ErrorType for ConsoleTx {
    type Error = core::convert::Infallible;
}

impl embedded_io_async::Write for ConsoleTx {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        match self {
            Self::Instant(tx) => tx.write(buf).await,
            Self::Line(tx) => tx.write(buf).await,
        }
    }

    async fn flush(&mut self) -> Result<(), Self::Error> {
        match self {
            Self::Instant(tx) => tx.flush().await,
            Self::Line(tx) => tx.flush().await,
        }
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
    /// Its CPU: the flash's erases and writes in bank 1 stall it.
    pub cpu: Cpu,
    /// What the bootloader did at the last boot.
    pub boot_outcome: Option<Outcome>,
    /// The next boot's bootloader loses the power after this many bytes of flash work (a cut mid-swap): the board
    /// then stays off until the next [`MasterBoard::reboot`].
    pub cut_in_bootloader: Option<usize>,
    /// Where its update images go: every one recorded, across reboots.
    pub updates: UpdateRecorder,
    /// The backup register the bootloader counts early crashes in (`g431_hw::backup::CRASH_REGISTER`): kept over
    /// resets, cleared by a power cycle.
    pub crash_register: Rc<Cell<u32>>,
    /// The next boot follows a watchdog reset (a crash: [`MasterBoard::crash`]).
    watchdog_reset: bool,
    reboot: RebootRequest,
    task: Option<TaskId>,
    /// The black box's RAM between two starts (`g431_hw::memory::BLACK_BOX`): a reset keeps it, a power cut
    /// clears it. While the master runs, its `Shared` holds it.
    black_box: Option<&'static mut BlackBox>,
}

/// A backup register on the bench: a word kept over resets.
struct BackupRegister(Rc<Cell<u32>>);

impl CrashRegister for BackupRegister {
    fn load(&mut self) -> u32 {
        self.0.get()
    }

    fn store(&mut self, word: u32) {
        self.0.set(word);
    }
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
        let factory = made_up_image(Target::Master, MASTER_FACTORY_VERSION, MASTER_FACTORY_IMAGE_LEN, 1);
        embedded_storage::nor_flash::NorFlash::write(&mut partition(&flash, MASTER_PARTITIONS.active), 0, &factory)
            .expect("the factory image fits ACTIVE");
        flash.stall_cpu(&cpu, FlashTiming::G474_DUAL_BANK);
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
            boot_outcome: None,
            cut_in_bootloader: None,
            updates: UpdateRecorder::default(),
            crash_register: Rc::default(),
            watchdog_reset: false,
            reboot: RebootRequest::default(),
            task: None,
            black_box: Some(Box::leak(Box::new(BlackBox::new()))),
        };
        board.start(wiring, executor);
        board
    }

    /// The image ACTIVE holds now, by its information record.
    pub fn running_image(&self) -> Option<ImageInfo> {
        let mut info = [0xFF; INFO_LEN];
        embedded_storage::nor_flash::ReadNorFlash::read(
            &mut partition(&self.flash, MASTER_PARTITIONS.active),
            INFO_OFFSET as u32,
            &mut info,
        )
        .ok()?;
        ImageInfo::parse(&info).ok()
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
        self.black_box = self.shared.black_box.release().or(self.black_box.take());
        self.shared = Rc::new(Shared::new());
        self.console_stats = Rc::new(ConsoleStats::new());
        wiring.can.clear();
        if let Some(line) = &wiring.console_line {
            line.to_master.reset_receiver();
        }
        self.cpu.reset();
        if !self.flash.powered() {
            self.crash_register.set(0);
            if let Some(black_box) = self.black_box.as_deref_mut() {
                *black_box = BlackBox::new();
            }
        }
        self.flash.power_on();
        self.start(wiring, executor);
    }

    /// The image crashes: it stops, and the watchdog resets the chip.
    pub fn crash(&mut self, wiring: &Wiring, executor: &mut Executor<'static>) {
        self.watchdog_reset = true;
        self.reboot(wiring, executor);
    }

    fn start(&mut self, wiring: &Wiring, executor: &mut Executor<'static>) {
        self.reboot = RebootRequest::default();
        self.boots += 1;
        // The bootloader, on the flash as the last power-down left it: its work is done at once, and the master's
        // tasks wait for the time it takes, one operation after another.
        let before = self.flash.stats();
        self.flash.stall_nothing();
        if let Some(bytes) = self.cut_in_bootloader.take() {
            self.flash.cut_power_after(bytes);
        }
        // The bootloader's count of early crashes, as its binding keeps it (`lbv-boot/src/stm32.rs`).
        let crashes =
            CrashCount::from_word(self.crash_register.get()).at_start(core::mem::take(&mut self.watchdog_reset));
        self.crash_register.set(crashes.to_word());
        let outcome = lbv_boot::prepare(self.flash.clone(), &MASTER_PARTITIONS, crashes, || {});
        if let Outcome::Restored { .. } = outcome {
            self.crash_register.set(
                CrashCount {
                    crashes: 0,
                    restored: true,
                }
                .to_word(),
            );
        }
        self.boot_outcome = Some(outcome);
        self.flash.stall_cpu(&self.cpu, FlashTiming::G474_DUAL_BANK);
        if !self.flash.powered() {
            return;
        }
        self.cpu
            .stall(FlashTiming::G474_DUAL_BANK.work_time(before, self.flash.stats()));
        let script = self.acceptance.then(|| {
            let desk = Rc::new(Desk::default());
            self.desk = Some(desk.clone());
            Script(DeskOperator(desk))
        });
        // The image's start hands the black box its RAM; the acceptance image has none.
        if !self.acceptance
            && let Some(black_box) = self.black_box.take()
        {
            let thrusters = usize::from(self.config.thrusters.count());
            self.shared
                .black_box
                .keep(black_box, embassy_time::Instant::now(), thrusters);
        }
        self.task = Some(self.spawn(wiring, executor, script));
    }

    /// The node on its ports: the acceptance `script` on its thruster buses, or without one the vehicle's polling,
    /// which carries the update images the console receives to the thrusters (each recorded too).
    fn spawn(&self, wiring: &Wiring, executor: &mut Executor<'static>, script: Option<Script<DeskOperator>>) -> TaskId {
        let parts = Parts {
            buses: wiring.buses.each_ref().map(|bus| thruster_bus(bus, &self.config.bus)),
            can: CanNode(wiring.can.clone()),
            console_rx: match &wiring.console_line {
                Some(line) => ConsoleRx::Line(line.to_master.rx()),
                None => ConsoleRx::Instant(SerialRx::new(wiring.console_in.clone())),
            },
            console_tx: match &wiring.console_line {
                Some(line) => ConsoleTx::Line(line.from_master.tx()),
                None => ConsoleTx::Instant(SerialTx(wiring.console_out.clone())),
            },
            settings: flash_store(&self.flash),
            reboot: self.reboot.clone(),
        };
        let recorder = self.updates.clone();
        let (config, shared, stats) = (self.config, self.shared.clone(), self.console_stats.clone());
        let flash = self.flash.clone();
        let crash_register = self.crash_register.clone();
        executor.spawn_on(&self.cpu, async move {
            // The node's statics: what its console hands on, its bus tasks carry and its own update writes.
            let transfers = Transfers::new();
            let image = OwnImage::new();
            let update = Recorded {
                recorder,
                sink: VehicleSink::new(&transfers, &image),
            };
            let own = Updating {
                flash: OwnFlash::new(flash),
                image: &image,
                crashes: BackupRegister(crash_register),
            };
            match script {
                Some(script) => lbv_master_fw::run(with(parts, script, update, own), &config, &shared, &stats).await,
                None => {
                    let polling = Polling {
                        transfers: Some(&transfers),
                    };
                    lbv_master_fw::run(with(parts, polling, update, own), &config, &shared, &stats).await
                }
            }
        })
    }
}

/// The bench master's board: lbv-sim's parts, with `J` on the thruster buses, `U` for the update images and `O` for
/// the master's own update.
#[derive(Debug)]
struct BenchMaster<J, U, O>(PhantomData<(J, U, O)>);

impl<J: BusWork, U: UpdateSink, O: OwnUpdate> Board for BenchMaster<J, U, O> {
    type Bus = ThrusterBus;
    type Can = CanNode;
    type ConsoleRx = ConsoleRx;
    type ConsoleTx = ConsoleTx;
    type Settings = Store<Stm32g4Flash>;
    type Reboot = RebootRequest;
    type Work = J;
    type Update = U;
    type Own = O;
}

/// The ports that are the bench's parts, made before the node's task: the rest borrow what the task owns ([`with`]).
struct Parts {
    buses: [ThrusterBus; BUSES],
    can: CanNode,
    console_rx: ConsoleRx,
    console_tx: ConsoleTx,
    settings: Store<Stm32g4Flash>,
    reboot: RebootRequest,
}

/// `parts` with `work` on the thruster buses, `update` for the images and `own` for the master's own.
fn with<J: BusWork, U: UpdateSink, O: OwnUpdate>(
    parts: Parts,
    work: J,
    update: U,
    own: O,
) -> Ports<BenchMaster<J, U, O>> {
    Ports {
        buses: parts.buses,
        can: parts.can,
        console_rx: parts.console_rx,
        console_tx: parts.console_tx,
        settings: parts.settings,
        reboot: parts.reboot,
        work,
        update,
        own,
    }
}
