//! The master node on the emulated chip: `lbv_master_fw::run` with a production configuration, on ports that
//! lead to the thruster cores on the same chip (three in-memory buses), a battery CAN bus, and the console link to
//! the ground station (`station.rs`).

use core::convert::Infallible;
use core::marker::PhantomData;

use embassy_executor::{SendSpawner, Spawner};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_sync::pipe::Pipe;
use lbv_master_fw::MasterConfig;
use lbv_master_fw::console::ConsoleStats;
use lbv_master_fw::ports::{Board, BusWork, CanFrame, CanReceiver, Ports, Reboot};
use lbv_master_fw::settings::InRam;
use lbv_master_fw::shared::BUSES;
use lbv_master_fw::shared::Shared;
use lbv_master_fw::update::CheckOnly;
use static_cell::StaticCell;

use crate::i2c::{Bus, MAX_THRUSTERS, MasterPort};
use crate::meter::{self, Joined, Progress, metered_joined};
use crate::report;
use crate::stacks::Stack;
use crate::thruster::{HallInput, Thruster};

type Cs = CriticalSectionRawMutex;

/// The master's channels between its tasks.
pub static SHARED: Shared = Shared::new();
/// The console's counters.
pub static CONSOLE_STATS: ConsoleStats = ConsoleStats::new();
/// The console's serial link, each way (the ST-LINK virtual COM port on the board).
pub static UPLINK: Pipe<Cs, 512> = Pipe::new();
pub static DOWNLINK: Pipe<Cs, 1024> = Pipe::new();
/// The battery CAN bus.
pub static CAN: Channel<Cs, CanFrame, 8> = Channel::new();

/// The master's tasks (`lbv_master_fw::run`: the buses' work, battery, console receive and transmit, vehicle
/// joined), every poll and by which of them made progress.
pub static MASTER_METER: Joined = Joined::new("master tasks (run)", Progress::MASTER, None);

/// The master's ports, with `work` on the thruster buses.
pub type MasterPorts<J> = Ports<EmulatedChip<J>>;

/// The master's ports on the emulated chip, with `J` on the thruster buses. The chip has no flash set aside for the
/// settings: they stay in RAM; it has no bootloader, and its update sink sends nothing on.
#[derive(Debug)]
pub struct EmulatedChip<J>(PhantomData<J>);

impl<J: BusWork> Board for EmulatedChip<J> {
    type Bus = MasterPort;
    type Can = CanPort;
    type ConsoleRx = ConsoleRx;
    type ConsoleTx = ConsoleTx;
    type Settings = InRam;
    type Reboot = NoReboot;
    type Work = J;
    type Update = CheckOnly;
    type Own = ();
}

/// The thruster buses of `config`'s table, each thruster a motor-less thruster core started on the chip; the one
/// whose halls come through the hall-edge interrupt is the first when `halls` says so.
pub fn buses(config: &MasterConfig, thread: Spawner, high: SendSpawner, halls: HallInput) -> [&'static Bus; BUSES] {
    static BUSES_: [StaticCell<Bus>; BUSES] = [const { StaticCell::new() }; BUSES];
    let mut first = true;
    let mut index = 0u8;
    BUSES_.each_ref().map(|cell| {
        let mut thrusters = heapless::Vec::<&'static Thruster, MAX_THRUSTERS>::new();
        let on_bus = config.thrusters.as_slice().iter().filter(|slot| slot.bus == index);
        for slot in on_bus {
            if thrusters.push(Thruster::create(slot.family, slot.mux_channel)).is_err() {
                report::fail("more thrusters on one bus than the bus model takes");
            }
        }
        let mux_fitted = thrusters.iter().any(|thruster| thruster.mux_channel.is_some());
        index += 1;
        let bus: &'static Bus = cell.init(Bus::new(config.bus, &thrusters, mux_fitted));
        for thruster in bus.thrusters() {
            let input = if first { halls } else { HallInput::Model };
            first = false;
            thruster.start(thread, high, input, bus);
        }
        bus
    })
}

/// The master's ports on `buses`, the battery bus, the console link, with `work` on the buses.
pub fn ports<J: BusWork>(buses: [&'static Bus; BUSES], work: J) -> MasterPorts<J> {
    Ports {
        buses: buses.map(Bus::master),
        can: CanPort,
        console_rx: ConsoleRx,
        console_tx: ConsoleTx,
        settings: InRam,
        reboot: NoReboot,
        work,
        update: CheckOnly,
        own: (),
    }
}

/// The runs here never ask the master to restart: one that does fails.
#[derive(Debug)]
pub struct NoReboot;

impl Reboot for NoReboot {
    async fn reboot(&mut self) -> ! {
        report::fail("the master asked to reboot")
    }
}

/// The master as its STM32 binding runs it (`lbv-master-fw/src/stm32.rs`), polled on the master's own stack.
pub async fn run<J: BusWork>(ports: MasterPorts<J>, config: &MasterConfig) -> ! {
    let mut seen = None;
    // The vehicle task publishes its state on every pass.
    let vehicle = move || {
        let now = SHARED.vehicle.get_msg_id();
        if seen.replace(now) == Some(now) {
            0
        } else {
            Progress::MASTER_VEHICLE
        }
    };
    let master = lbv_master_fw::run(ports, config, &SHARED, &CONSOLE_STATS);
    metered_joined(&MASTER_METER, Stack::Master, vehicle, master).await
}

/// The battery CAN bus, seen from the master. Each wait for a frame, and each frame, is the battery task's
/// progress.
#[derive(Debug)]
pub struct CanPort;

impl CanReceiver for CanPort {
    type Error = Infallible;

    async fn receive(&mut self) -> Result<CanFrame, Infallible> {
        meter::progressed(Progress::MASTER_BATTERY);
        let frame = CAN.receive().await;
        meter::progressed(Progress::MASTER_BATTERY);
        Ok(frame)
    }
}

/// The console link's receive side. Each read is the console receive task's progress.
#[derive(Debug)]
pub struct ConsoleRx;

impl embedded_io_async::ErrorType for ConsoleRx {
    type Error = Infallible;
}

impl embedded_io_async::Read for ConsoleRx {
    async fn read(&mut self, buffer: &mut [u8]) -> Result<usize, Infallible> {
        meter::progressed(Progress::MASTER_CONSOLE_RX);
        let read = UPLINK.read(buffer).await;
        meter::progressed(Progress::MASTER_CONSOLE_RX);
        Ok(read)
    }
}

/// The console link's transmit side. Each write is the console transmit task's progress.
#[derive(Debug)]
pub struct ConsoleTx;

impl embedded_io_async::ErrorType for ConsoleTx {
    type Error = Infallible;
}

impl embedded_io_async::Write for ConsoleTx {
    async fn write(&mut self, bytes: &[u8]) -> Result<usize, Infallible> {
        meter::progressed(Progress::MASTER_CONSOLE_TX);
        let written = DOWNLINK.write(bytes).await;
        meter::progressed(Progress::MASTER_CONSOLE_TX);
        Ok(written)
    }

    /// The pipe holds nothing back: whatever was written is there to read.
    async fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}
