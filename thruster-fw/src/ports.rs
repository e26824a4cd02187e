//! The core's ports: every trait through which the controller reaches its hardware, in one file, with the few types
//! their signatures need. A binding (the STM32's `board.rs`, `sim.rs` on lbv-sim's parts, the bench, qemu-m4, the
//! host tests) implements them; the core's tasks take them as generics and never see what is behind them.
//!
//! - the thread-mode tasks' ports, which [`run`](crate::run) takes as one [`Ports`] named by a [`Board`]: the I2C
//!   slave ([`I2cTarget`]), the ADC inputs ([`Sensors`]), the watchdog ([`Watchdog`]), the power-cycle latches'
//!   store ([`LatchStore`]), the bootloader's record ([`BootState`]), the DFU partition (embedded-storage's
//!   [`NorFlash`]) and the field update's side of the bootloader and chip ([`Updater`]);
//! - commutation's, which [`run_commutation`](crate::run_commutation) takes: the halls ([`HallSensors`]) and the
//!   power stage ([`Bridge`]);
//! - the motor-less controller's real inputs beside its model motor ([`crate::motorless`]): the water-sensor pin
//!   ([`WaterInput`]) and what holds the modelled rotor ([`HoldInput`]).

use embedded_storage::nor_flash::NorFlash;
use tmc_proto::Faults;
use tmc_proto::ext::{INFO_LEN, RECORD_LEN};
use update_image::{Ticket, Verdict};

use crate::commutation::BridgeDrive;
use crate::drive::Duty;
use crate::hall::HallState;

/// The hardware one controller runs on: the type of each port its thread-mode tasks take ([`run`](crate::run)).
/// Each binding declares one small type (no value is ever made of it) that names its ports here, and builds a
/// [`Ports`] of it: the STM32 binding's names the G431's peripherals, the bench's lbv-sim's parts, qemu-m4's the
/// emulated chip's, the host tests' their own fakes.
pub trait Board {
    /// The I2C slave port of the thruster interface.
    type I2c: I2cTarget;
    /// The ADC inputs.
    type Sensors: Sensors;
    /// The independent watchdog.
    type Watchdog: Watchdog;
    /// Where the power-cycle fault latches outlast a reset.
    type Latch: LatchStore;
    /// The bootloader's record of this image, which a new image confirms (see [`crate::trial`]).
    type Boot: BootState;
    /// The DFU partition a field update writes the new image into (see [`crate::update`]).
    type Dfu: NorFlash;
    /// The bootloader's and the chip's side of a field update: the signature check, the swap's mark, the reset.
    type Updater: Updater;
}

/// What the controller's thread-mode tasks are wired to: one port of each type `B` names.
#[derive(Debug)]
pub struct Ports<B: Board> {
    /// The I2C slave port of the thruster interface.
    pub i2c: B::I2c,
    /// The ADC inputs.
    pub sensors: B::Sensors,
    /// The independent watchdog.
    pub watchdog: B::Watchdog,
    /// Where the power-cycle fault latches outlast a reset.
    pub latch: B::Latch,
    /// The bootloader's record of this image, which a new image confirms (see [`crate::trial`]).
    pub boot: B::Boot,
    /// The DFU partition a field update writes the new image into (see [`crate::update`]).
    pub dfu: B::Dfu,
    /// The bootloader's and the chip's side of a field update: the signature check, the swap's mark, the reset.
    pub updater: B::Updater,
}

/// What the master asked for once it matched this controller's address.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Request {
    /// The master writes (an order, or an extension command).
    Write,
    /// The master reads (the status, or the reply to an extension command).
    Read,
}

/// The I2C slave peripheral as the core sees it, shaped like embassy-stm32's slave API.
///
/// The peripheral stretches SCL from the address match until `respond_*` is called, so the core keeps its
/// status reply ready before a read arrives.
#[allow(async_fn_in_trait)]
pub trait I2cTarget {
    /// A bus or peripheral error.
    type Error;
    /// Wait until the master addresses this controller.
    async fn listen(&mut self) -> Result<Request, Self::Error>;
    /// Receive the master's write into `buffer`; returns how many bytes were stored.
    async fn respond_to_write(&mut self, buffer: &mut [u8]) -> Result<usize, Self::Error>;
    /// Send `data` to the reading master.
    async fn respond_to_read(&mut self, data: &[u8]) -> Result<(), Self::Error>;
    /// Re-initialise the peripheral after an error, so that it releases SCL and SDA whatever state it was in.
    fn reset(&mut self);
}

/// The three hall sensor inputs.
#[allow(async_fn_in_trait)]
pub trait HallSensors {
    /// Wait until any hall input changes.
    async fn wait_for_edge(&mut self);
    /// The hall inputs now.
    fn read(&mut self) -> HallState;
}

/// The three half-bridges.
pub trait Bridge {
    /// Drive the phases; `duty` sets the PWM of the phase marked
    /// [`PhaseDrive::Pwm`](crate::commutation::PhaseDrive::Pwm).
    fn apply(&mut self, drive: BridgeDrive, duty: Duty);
    /// A sustained overcurrent (`true`): every output off and kept off, the hardware break's automatic restart
    /// disabled, whatever `apply` asks. `false`: the outputs may come back (at the next PWM period, once the
    /// break input is inactive).
    fn hold_off(&mut self, off: bool);
}

/// Raw ADC readings (12-bit) of the fault and telemetry inputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RawSample {
    /// Water-sensor node.
    pub water: u16,
    /// The NTC node of the temperature the status reports: the motor's (brushless), the controller's (brushed).
    pub temperature: u16,
    /// The three phase shunts' amplifiers (phases A, B, C), converted together at the last trigger of the power
    /// stage's PWM: the motor current is the largest ([`crate::sensors::CurrentSense::motor_deciamps`]).
    pub currents: [u16; 3],
    /// The supply's divider (VBUS).
    pub vbus: u16,
    /// The power stage's hardware break tripped (its overcurrent comparator) since the last sample; taking the
    /// sample clears it.
    pub break_tripped: bool,
}

/// The ADC inputs.
#[allow(async_fn_in_trait)]
pub trait Sensors {
    /// Convert every input once.
    async fn sample(&mut self) -> RawSample;
}

/// The independent watchdog.
pub trait Watchdog {
    /// Restart the watchdog's countdown.
    fn feed(&mut self);
}

/// Where the power-cycle latches live between resets (the word they are kept as, and which resets carry them:
/// [`crate::faults`]).
pub trait LatchStore {
    /// The latches carried over the last reset (none after a power cycle).
    fn load(&mut self) -> Faults;
    /// Keep `latched` for the next reset.
    fn save(&mut self, latched: Faults);
}

/// The bootloader's record of the image that runs (embassy-boot's state partition; the trial that confirms a new
/// image: [`crate::trial`]).
#[allow(async_fn_in_trait)]
pub trait BootState {
    /// Why the record could not be read or written.
    type Error;

    /// Whether the image is on trial: swapped in by the bootloader and not confirmed yet.
    async fn on_trial(&mut self) -> Result<bool, Self::Error>;

    /// Confirm the image: the bootloader keeps it at the next reset.
    async fn confirm(&mut self) -> Result<(), Self::Error>;
}

/// Why the [`Updater`] did not mark the payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum MarkError {
    /// The bootloader's state is not "booted" (the running image is on trial): embassy-boot refuses to mark.
    OnTrial,
    /// The flash failed, or did not keep what was written.
    Flash,
    /// This controller has no bootloader to hand an image to: it marks nothing.
    Unavailable,
}

/// What an update needs of the bootloader and the chip: the running image's record, the mark that hands the DFU
/// payload to the bootloader with its [`Ticket`], the bootloader's verdict on the last image marked, and the
/// reset that starts it. The host tests and the bench implement it with embassy-boot's state on lbv-sim's flash,
/// the binding on the G431's; both mark through [`mark_for_swap`](crate::update::mark_for_swap).
pub trait Updater {
    /// The running image's information record, as its flash holds it (ACTIVE +
    /// [`INFO_OFFSET`](crate::update::INFO_OFFSET)).
    fn running_info(&mut self) -> [u8; INFO_LEN];

    /// Whether an image marked here is checked before it runs (a bootloader that checks signatures is there): a
    /// master asks before it sends a payload for nothing.
    fn checks_signatures(&self) -> bool;

    /// Write `ticket` (the payload's length and signature) for the bootloader and mark DFU's payload for the swap
    /// at the next reset. Synchronous: the caller has just looked at the motor.
    fn mark_updated(&mut self, ticket: &Ticket) -> Result<(), MarkError>;

    /// Why the bootloader refused the last image marked, as it wrote it beside that image's ticket.
    fn verdict(&mut self) -> Option<Verdict>;

    /// Reset the chip, so that the bootloader swaps the marked payload in. On the chip it does not return.
    fn reboot(&mut self);

    /// The post-mortem record of the stop before this start (the crash-record crate's, encoded), if the start
    /// found one: the master fetches it ([`Command::PostMortem`](tmc_proto::ext::Command::PostMortem)).
    fn post_mortem(&self) -> Option<[u8; RECORD_LEN]>;
}

/// The water-sensor ADC pin, which stays real in the motor-less controller.
#[allow(async_fn_in_trait)]
pub trait WaterInput {
    /// Convert the water-sensor node once (12-bit).
    async fn water(&mut self) -> u16;
}

/// What holds the modelled rotor (the NUCLEO's user button).
pub trait HoldInput {
    /// Whether the rotor is held now.
    fn held(&mut self) -> bool;
}
