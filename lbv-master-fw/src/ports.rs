//! The master core's ports: every trait the core asks of what it runs on, in this one file, and [`Board`], which
//! names the type of each port.
//!
//! Who implements them: the STM32 binding (the binary's `stm32.rs` and `board.rs`) on embassy-stm32's drivers, the
//! crate's `sim` module on lbv-sim's simulated parts (for the bench and the tests), and qemu-m4 on its emulated chip.
//! Each declares a type that implements [`Board`] and hands [`crate::run`] the [`Ports`] of it. The
//! thruster buses are also `embedded_hal_async::i2c::I2c` and the console link `embedded_io_async`'s `Read` and
//! `Write`, traits of their own crates. The acceptance script's [`Operator`](crate::acceptance::Operator), the
//! person at the bench, is not a port: the script's own interface, it stays with the script.
//!
//! The types that exist for these traits' signatures live here with them ([`CanFrame`], [`StoreError`],
//! [`UpdateTarget`], [`Applied`], [`Refused`]). What else the signatures name comes from modules that do not import
//! this one (`shared`, `params`, `update::ftp`, `update::header`) or from the crate's root ([`MasterConfig`], which
//! [`BusWork::run`] takes whole), so that every module can import this one.

use embedded_hal_async::i2c::I2c;
use embedded_io_async::{Read, Write};

use crate::MasterConfig;
use crate::params::Settings;
use crate::shared::{BUSES, Sender, Shared, UpdateHolds};
use crate::update::ftp::Nak;
use crate::update::header::ImageHeader;
use crate::update::sys::Versions;
use tmc_proto::Family;

/// What a board gives the master's core: the type of each of its ports, one value of each in the
/// [`Ports`] that [`crate::run`] takes. The STM32 binding declares one for the NUCLEO, qemu-m4 one
/// for its emulated chip, the bench and the tests theirs on lbv-sim's parts (generic where the buses' work, the
/// update sink or the own update vary).
pub trait Board {
    /// A thruster bus (I2C1..3), with its recovery.
    type Bus: I2c + BusRecovery;
    /// The battery CAN bus, receiving.
    type Can: CanReceiver;
    /// The console link's receive side.
    type ConsoleRx: Read;
    /// The console link's transmit side.
    type ConsoleTx: Write;
    /// Where the settings are kept.
    type Settings: SettingsStore;
    /// How the master restarts.
    type Reboot: Reboot;
    /// What the thruster buses are for: polling the thrusters, or the acceptance script.
    type Work: BusWork;
    /// Where the update images received over MAVLink FTP go.
    type Update: UpdateSink;
    /// The master's own update.
    type Own: OwnUpdate;
}

/// What the master is wired to, on board `P` ([`Board`] names the types): the three thruster buses (I2C1..3,
/// indexed as in the thruster table), the battery CAN bus, the console's serial link, where the settings are kept,
/// how it restarts, what the buses are for, where update images go, and how it updates itself.
#[derive(Debug)]
pub struct Ports<P: Board> {
    /// The thruster buses, each with its recovery.
    pub buses: [P::Bus; BUSES],
    /// The battery board's frames.
    pub can: P::Can,
    /// The console link's receive side.
    pub console_rx: P::ConsoleRx,
    /// The console link's transmit side.
    pub console_tx: P::ConsoleTx,
    /// Where the settings are kept: [`Store`](crate::settings::Store) on the flash pages kept for them (or, on a board without
    /// them, [`InRam`](crate::settings::InRam)).
    pub settings: P::Settings,
    /// How the master restarts (MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN).
    pub reboot: P::Reboot,
    /// The buses' work: [`Polling`](crate::Polling) the thrusters (the vehicle), or the acceptance [`Script`](crate::acceptance::Script).
    pub work: P::Work,
    /// Where the update images received over MAVLink FTP go ([`crate::update`]): the vehicle's [`VehicleSink`](crate::update::VehicleSink),
    /// or [`CheckOnly`](crate::update::CheckOnly) in an image that sends none on (the acceptance image, the tests).
    pub update: P::Update,
    /// The master's own update ([`crate::update::own`]): [`Updating`](crate::update::own::Updating) on its flash, or `()` without a bootloader.
    pub own: P::Own,
}

/// A thruster bus the master can clear when a transfer times out or fails on the bus.
#[allow(async_fn_in_trait)]
pub trait BusRecovery {
    /// Clear the bus; true when SDA is free afterwards.
    async fn recover(&mut self) -> bool;
}

/// A received classic CAN frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct CanFrame {
    /// Standard 11-bit identifier.
    pub id: u16,
    /// Data length code, 0..=8 (a larger value is a bad frame).
    pub len: u8,
    /// Data bytes; only the first `len` count.
    pub data: [u8; 8],
}

impl CanFrame {
    /// The data bytes that count, or `None` if `len` is above 8.
    pub(crate) fn payload(&self) -> Option<&[u8]> {
        self.data.get(..usize::from(self.len))
    }
}

/// The CAN receive port.
///
/// `receive` must be cancel-safe: when its future is dropped before completing, no frame is lost (embassy-stm32's
/// FDCAN `read` is). The monitor drops it to wake up on time when the bus is silent.
#[allow(async_fn_in_trait)]
pub trait CanReceiver {
    /// Why a receive failed (bus off, error passive, overrun...): counted, never fatal.
    type Error;
    /// The next frame.
    async fn receive(&mut self) -> Result<CanFrame, Self::Error>;
}

/// Where the settings are kept.
#[allow(async_fn_in_trait)]
pub trait SettingsStore {
    /// The newest stored settings over `defaults` (what is missing or invalid stays default); called once, at
    /// start-up, before anything is saved.
    async fn load(&mut self, defaults: Settings) -> Settings;

    /// Store `settings`.
    async fn save(&mut self, settings: &Settings) -> Result<(), StoreError>;

    /// Store the signing link's reservation.
    async fn save_signing_time(&mut self, timestamp: u64) -> Result<(), StoreError>;

    /// Records that could not be read by [`SettingsStore::load`].
    fn read_errors(&self) -> u32 {
        0
    }

    /// Whether every write is refused ([`StoreError::Layout`]): the chip's flash is not in the layout the pages are
    /// placed for. [`crate::run`] says so at start, for the master's own update too, which the binding refuses on
    /// the same reading.
    fn writes_refused(&self) -> bool {
        false
    }
}

/// Why a write did not reach the flash.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum StoreError {
    /// The flash reported an error (or the power was cut, in the tests).
    Flash,
    /// The store found itself corrupt and could not repair it.
    Corrupt,
    /// The chip's flash is not in the layout the pages are placed for
    /// ([`Store::set_layout_ok`](crate::settings::Store::set_layout_ok)): nothing is written.
    Layout,
}

/// Restarts the master: a system reset on the STM32; the bench drops the master's tasks and boots it again with
/// its flash kept.
#[allow(async_fn_in_trait)]
pub trait Reboot {
    /// Restart now. It does not return: the STM32 resets; elsewhere the task waits here until it is dropped.
    async fn reboot(&mut self) -> !;
}

/// What the master does with its thruster buses.
#[allow(async_fn_in_trait)]
pub trait BusWork {
    /// Whether it polls the thrusters in the table, and so publishes their reports to `shared.thrusters`.
    const POLLS: bool;

    /// Use the buses; returning leaves them idle.
    async fn run<B: I2c + BusRecovery>(self, buses: &mut [B; BUSES], config: &MasterConfig, shared: &Shared);
}

/// Where an upload's bytes go, in order. [`VehicleSink`](crate::update::VehicleSink) sends thruster images on to
/// the thruster's DFU partition over its bus and the master's into its own; [`CheckOnly`](crate::update::CheckOnly)
/// keeps nothing, and the bench also records everything.
///
/// The calls do not wait: a sink that forwards over a bus keeps what it is given (at most one FTP write's worth,
/// [`DATA_LEN`](crate::update::ftp::DATA_LEN) bytes, per call), and the console reads on only once the sink is
/// [`UpdateSink::ready`]. An error NAKs the request and stops the upload. (Synchronous calls keep the server a
/// plain state machine: as async code it took three times the flash.)
#[allow(async_fn_in_trait)]
pub trait UpdateSink {
    /// Wait until the sink can take the calls of the next requests.
    async fn ready(&mut self) {}
    /// An image for `target` begins; its header has passed the server's checks.
    fn begin(&mut self, target: UpdateTarget, header: &ImageHeader) -> Result<(), Refused>;
    /// The file's bytes from `offset` on (past the header, always the next byte after the last write).
    fn write(&mut self, offset: u32, data: &[u8]) -> Result<(), Refused>;
    /// The image that began is done: `complete` when every byte its header announces arrived, otherwise it was
    /// stopped and what arrived is to be dropped.
    fn finish(&mut self, complete: bool) -> Result<(), Refused>;
    /// Apply the image received whole for `target`, as `from` asks.
    fn apply(&mut self, target: UpdateTarget, from: Sender) -> Result<Applied, Nak>;
    /// Ask thruster `slot` which image it runs, for `from`, who gets the answer (a text and the final
    /// COMMAND_ACK). A sink that reaches no thruster refuses.
    fn query_version(&mut self, slot: u8, from: Sender) -> Result<(), Refused> {
        let _ = (slot, from);
        Err(Refused::Because("no thruster bus here"))
    }
    /// Tell the vehicle, in `holds`, what of the updates keeps it from arming now: called as soon as an apply has
    /// been taken, so that an arm command read after it is refused. A sink that applies nothing holds nothing.
    fn publish(&self, holds: &UpdateHolds) {
        let _ = holds;
    }
    /// Tell `versions` what the master knows of each board's running image ([`Versions::set`], for
    /// `@SYS/versions.txt`). A sink that reaches no board knows nothing of them.
    fn boards(&self, versions: &mut Versions) {
        let _ = versions;
    }
}

/// The slot number of the master in the apply command's param1.
pub(crate) const MASTER_SLOT: u8 = 255;
/// The slot number of every SeaBotix thruster in the apply command's param1.
pub(crate) const SEABOTIX_SLOT: u8 = 200;
/// The slot number of every Legacy thruster in the apply command's param1.
pub(crate) const LEGACY_SLOT: u8 = 201;

/// What an update file is for: a slot of the thruster table, every thruster of a family, or the master.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum UpdateTarget {
    /// The thruster in this slot of the table, from 0.
    Thruster(u8),
    /// Every thruster of `family`: the slots that are bits of `slots`.
    Family { family: Family, slots: u8 },
    /// The master itself.
    Master,
}

impl UpdateTarget {
    /// Its slot number: the thruster's, the family's, or [`MASTER_SLOT`].
    pub(crate) const fn slot(self) -> u8 {
        match self {
            Self::Thruster(slot) => slot,
            Self::Family {
                family: Family::SeaBotix,
                ..
            } => SEABOTIX_SLOT,
            Self::Family {
                family: Family::Legacy, ..
            } => LEGACY_SLOT,
            Self::Master => MASTER_SLOT,
        }
    }
}

/// What [`UpdateSink::apply`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Applied {
    /// The target is taking the image: the final result follows as a second COMMAND_ACK.
    Started,
    /// Not yet: the image is still on its way to the target.
    Pending,
    /// Nothing: the path to the target is not there yet (the image was checked, and that is all).
    NotWired,
    /// Nothing new: an apply of the target is under way already, for this sender, whose final answer it gets.
    Applying(Sender),
    /// Nothing to do: every thruster the image went to runs it already.
    Runs,
}

/// Why a sink did not take an upload's call: the upload stops.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refused {
    /// The sink tells the operator why itself, with what it knows (the courier as its transfer ends, the master's
    /// own task once it has looked at its flash): the server adds nothing.
    Told,
    /// Why, for the server to tell.
    Because(&'static str),
}

impl Refused {
    /// What the server says of it: nothing when the sink tells it.
    pub(crate) fn why(self) -> &'static str {
        match self {
            Refused::Told => "",
            Refused::Because(why) => why,
        }
    }
}

/// What the master does for its own update: [`Updating`](crate::update::own::Updating) on its flash, or `()` on a
/// board with no bootloader (the cores on an emulated Cortex-M4, the tests), where master images are refused.
#[allow(async_fn_in_trait)]
pub trait OwnUpdate {
    /// Do it, for as long as the master runs, with the first `polled` thrusters of the table polled by the buses'
    /// work (none when it does not poll them).
    async fn run(self, polled: u8, shared: &Shared);
}

/// Where the bootloader counts early crashes ([`CrashCount`](update_image::CrashCount)): on the chip a backup
/// register (`g431_hw::backup`).
pub trait CrashRegister {
    /// The word it holds.
    fn load(&mut self) -> u32;
    /// Keep `word`.
    fn store(&mut self, word: u32);
}
