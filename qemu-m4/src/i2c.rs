//! The thruster buses inside the chip: the master's I2C controller port and its two lines, each thruster's target
//! port, with bit times at the configured speed spent on the clock, a TCA9548A, NACKs from absent or unpowered
//! thrusters, a power cut during a transfer, and a slave that holds SDA low.
//!
//! A transfer hands the master's bytes to the addressed thruster's I2C task and waits, as a clock-stretching
//! slave makes the master wait, until that task answers or the bus timeout passes. The lines are open-drain pins
//! as embedded-hal sees them ([`Scl`], [`Sda`]), so the master's recovery is the core's own
//! (`lbv_master_fw::recovery::PinRecovery`): a slave holding SDA counts the SCL clocks it is given.

use core::cell::RefCell;
use core::convert::Infallible;

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Delay, Duration, Timer, with_timeout};
use embedded_hal::digital::{self, InputPin, OutputPin};
use embedded_hal_async::i2c::{ErrorKind, ErrorType, I2c, NoAcknowledgeSource, Operation};
use lbv_master_fw::recovery::BusConfig;
use lbv_master_fw::recovery::PinRecovery;
use lbv_master_fw::thrusters::{MUX_ADDRESS, transfer_bits};
use thruster_fw::{I2cTarget, Request};
use tmc_proto::MAX_STATUS_LEN;

use crate::meter::{self, Progress};
use crate::thruster::Thruster;

/// Bytes of a write a thruster keeps; the STM32 slave ACKs and drops the rest.
const WRITE_CAPACITY: usize = 8;
/// Most thrusters on one bus.
pub const MAX_THRUSTERS: usize = 6;

/// What the master asks of a thruster in one transfer.
#[derive(Debug, Clone)]
enum Transfer {
    Write(heapless::Vec<u8, WRITE_CAPACITY>),
    Read,
}

/// What the thruster answered.
#[derive(Debug, Clone)]
enum Answer {
    Written,
    Read(heapless::Vec<u8, MAX_STATUS_LEN>),
}

/// A thruster's end of the bus.
pub struct SlaveLine {
    transfer: Signal<CriticalSectionRawMutex, Transfer>,
    answer: Signal<CriticalSectionRawMutex, Answer>,
}

impl SlaveLine {
    /// An empty line.
    pub const fn new() -> Self {
        Self {
            transfer: Signal::new(),
            answer: Signal::new(),
        }
    }

    /// Forget a transfer begun before the thruster lost its power.
    pub fn clear(&self) {
        self.transfer.reset();
    }
}

/// The target port a thruster's I2C task serves. Every wait for an address it begins, and every answer, is
/// progress of that task ([`Progress::THRUSTER_I2C`]).
pub struct TargetPort {
    line: &'static SlaveLine,
    write: Option<heapless::Vec<u8, WRITE_CAPACITY>>,
}

impl TargetPort {
    /// The port on `line`.
    pub fn new(line: &'static SlaveLine) -> Self {
        Self { line, write: None }
    }
}

impl I2cTarget for TargetPort {
    type Error = ();

    async fn listen(&mut self) -> Result<Request, ()> {
        meter::progressed(Progress::THRUSTER_I2C);
        let transfer = self.line.transfer.wait().await;
        meter::progressed(Progress::THRUSTER_I2C);
        Ok(match transfer {
            Transfer::Write(bytes) => {
                self.write = Some(bytes);
                Request::Write
            }
            Transfer::Read => Request::Read,
        })
    }

    async fn respond_to_write(&mut self, buffer: &mut [u8]) -> Result<usize, ()> {
        let bytes = self.write.take().ok_or(())?;
        let mut stored = 0;
        for (slot, byte) in buffer.iter_mut().zip(&bytes) {
            *slot = *byte;
            stored += 1;
        }
        self.line.answer.signal(Answer::Written);
        Ok(stored)
    }

    async fn respond_to_read(&mut self, data: &[u8]) -> Result<(), ()> {
        let mut sent = heapless::Vec::new();
        for byte in data.iter().take(MAX_STATUS_LEN) {
            let _ = sent.push(*byte);
        }
        self.line.answer.signal(Answer::Read(sent));
        Ok(())
    }

    fn reset(&mut self) {
        self.write = None;
    }
}

/// Who a transfer reaches.
enum Reached {
    Mux,
    Thruster(&'static Thruster),
    /// The thruster whose power the operator is about to cut: it goes down as the transfer begins.
    PowerCut(&'static Thruster),
    Nobody,
    /// A slave holds SDA low: not even a START can be made.
    Stuck,
}

/// The bus's own state: the mux, the lines, what it counted.
#[derive(Debug, Default)]
struct State {
    mux_mask: u8,
    power_cut_armed: Option<usize>,
    /// A slave holds SDA low until it has seen this many more SCL clocks.
    sda_held: u32,
    /// A slave will take the next transfer to it for a glitch and hold SDA low for this many clocks.
    glitch_armed: Option<(usize, u32)>,
    scl_low: bool,
    sda_low: bool,
    counts: BusCounts,
}

/// What a bus counted.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BusCounts {
    /// Transfers the master started.
    pub transfers: u32,
    /// Of those, not acknowledged.
    pub nacks: u32,
    /// Of those, timed out.
    pub timeouts: u32,
    /// Of those, failed because SDA was held low.
    pub bus_errors: u32,
    /// SCL clocks the master gave on the lines (the recovery's, the STOP's included).
    pub pin_clocks: u32,
    /// STOPs the master made on the lines.
    pub pin_stops: u32,
}

/// A bus: its thrusters, whether a TCA9548A routes them, its speed, its lines.
pub struct Bus {
    thrusters: heapless::Vec<&'static Thruster, MAX_THRUSTERS>,
    mux_fitted: bool,
    config: BusConfig,
    state: Mutex<CriticalSectionRawMutex, RefCell<State>>,
}

impl Bus {
    /// A bus at `config`'s speed and timeout with `thrusters` on it, each on its TCA9548A channel when
    /// `mux_fitted`.
    pub fn new(config: BusConfig, thrusters: &[&'static Thruster], mux_fitted: bool) -> Self {
        let mut list = heapless::Vec::new();
        for thruster in thrusters.iter().take(MAX_THRUSTERS) {
            let _ = list.push(*thruster);
        }
        Self {
            thrusters: list,
            mux_fitted,
            config,
            state: Mutex::new(RefCell::new(State::default())),
        }
    }

    /// The master's port: transfers on this bus, the core's recovery on its lines.
    pub fn master(&'static self) -> MasterPort {
        PinRecovery {
            i2c: ControllerPort(self),
            scl: Scl(self),
            sda: Sda(self),
            delay: Delay,
            bus: self.config,
        }
    }

    /// The operator will cut `thruster`'s power: it lands in the next transfer to it.
    pub fn cut_power_during_next_transfer(&self, thruster: &Thruster) {
        let index = self.index_of(thruster);
        self.with(|state| state.power_cut_armed = index);
    }

    /// A glitch will leave `thruster` holding SDA low for `clocks` SCL clocks at the next transfer to it.
    pub fn glitch_during_next_transfer(&self, thruster: &Thruster, clocks: u32) {
        let index = self.index_of(thruster);
        self.with(|state| state.glitch_armed = index.map(|index| (index, clocks)));
    }

    /// Whether a slave still holds SDA low.
    pub fn sda_held(&self) -> bool {
        self.with(|state| state.sda_held > 0)
    }

    /// The thrusters on it.
    pub fn thrusters(&self) -> &[&'static Thruster] {
        &self.thrusters
    }

    /// What it counted.
    pub fn counts(&self) -> BusCounts {
        self.with(|state| state.counts)
    }

    fn index_of(&self, thruster: &Thruster) -> Option<usize> {
        self.thrusters.iter().position(|t| core::ptr::eq(*t, thruster))
    }

    fn with<R>(&self, f: impl FnOnce(&mut State) -> R) -> R {
        self.state.lock(|state| f(&mut state.borrow_mut()))
    }

    fn reach(&self, address: u8) -> Reached {
        self.with(|state| {
            state.counts.transfers = state.counts.transfers.wrapping_add(1);
            if state.sda_held > 0 {
                state.counts.bus_errors = state.counts.bus_errors.wrapping_add(1);
                return Reached::Stuck;
            }
            if self.mux_fitted && address == MUX_ADDRESS {
                return Reached::Mux;
            }
            let mask = state.mux_mask;
            let found = self.thrusters.iter().enumerate().find(|(_, thruster)| {
                let reachable = match thruster.mux_channel {
                    Some(channel) => self.mux_fitted && mask & (1 << channel) != 0,
                    None => true,
                };
                reachable && thruster.powered() && thruster.config.family.address() == address
            });
            match found {
                Some((index, thruster)) if state.power_cut_armed == Some(index) => {
                    state.power_cut_armed = None;
                    Reached::PowerCut(thruster)
                }
                Some((index, _)) if state.glitch_armed.is_some_and(|(glitched, _)| glitched == index) => {
                    state.sda_held = state.glitch_armed.take().map_or(0, |(_, clocks)| clocks);
                    state.counts.bus_errors = state.counts.bus_errors.wrapping_add(1);
                    Reached::Stuck
                }
                Some((_, thruster)) => Reached::Thruster(thruster),
                None => {
                    state.counts.nacks = state.counts.nacks.wrapping_add(1);
                    Reached::Nobody
                }
            }
        })
    }

    fn count_timeout(&self) {
        self.with(|state| state.counts.timeouts = state.counts.timeouts.wrapping_add(1));
    }

    /// The time `bits` take on the bus.
    fn bit_time(&self, bits: u32) -> Duration {
        let hz = u64::from(self.config.frequency_hz.max(1));
        Duration::from_micros(u64::from(bits) * 1_000_000 / hz)
    }
}

/// The master's port on a bus: the controller and the core's recovery on the lines.
pub type MasterPort = PinRecovery<ControllerPort, Scl, Sda, Delay>;

/// The master's I2C controller on a bus. Each transfer is progress of the master's bus work
/// ([`Progress::MASTER_BUS`]).
pub struct ControllerPort(&'static Bus);

impl ControllerPort {
    async fn transfer(&mut self, address: u8, operation: &mut Operation<'_>) -> Result<(), ErrorKind> {
        meter::progressed(Progress::MASTER_BUS);
        let bus = self.0;
        let bytes = match operation {
            Operation::Write(bytes) => bytes.len(),
            Operation::Read(buffer) => buffer.len(),
        };
        let bits = transfer_bits(u32::try_from(bytes).unwrap_or(u32::MAX));
        let thruster = match bus.reach(address) {
            Reached::Mux => {
                match operation {
                    Operation::Write(bytes) => {
                        if let Some(mask) = bytes.last() {
                            bus.with(|state| state.mux_mask = *mask);
                        }
                    }
                    Operation::Read(buffer) => {
                        let mask = bus.with(|state| state.mux_mask);
                        buffer.iter_mut().for_each(|byte| *byte = mask);
                    }
                }
                Timer::after(bus.bit_time(bits)).await;
                return Ok(());
            }
            Reached::Nobody => {
                // START, the address byte and its missing ACK, STOP.
                Timer::after(bus.bit_time(transfer_bits(0))).await;
                return Err(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address));
            }
            Reached::Stuck => {
                // The START fails at once: SDA is low.
                Timer::after(bus.bit_time(1)).await;
                return Err(ErrorKind::Bus);
            }
            Reached::PowerCut(thruster) => {
                // The address was acknowledged, then the board lost its power: nobody finishes the transfer.
                thruster.cut_power();
                Timer::after(bus.config.timeout).await;
                bus.count_timeout();
                return Err(ErrorKind::Other);
            }
            Reached::Thruster(thruster) => thruster,
        };
        let line = &thruster.line;
        // An answer left over from a transfer the master gave up on is not this one's.
        line.answer.reset();
        line.transfer.signal(match operation {
            Operation::Write(bytes) => {
                let mut kept = heapless::Vec::new();
                for byte in bytes.iter().take(WRITE_CAPACITY) {
                    let _ = kept.push(*byte);
                }
                Transfer::Write(kept)
            }
            Operation::Read(_) => Transfer::Read,
        });
        let answer = with_timeout(bus.config.timeout, line.answer.wait()).await;
        Timer::after(bus.bit_time(bits)).await;
        match (answer, operation) {
            (Ok(Answer::Written), Operation::Write(_)) => Ok(()),
            (Ok(Answer::Read(data)), Operation::Read(buffer)) => {
                for (index, byte) in buffer.iter_mut().enumerate() {
                    // A slave with nothing more to send leaves SDA high.
                    *byte = data.get(index).copied().unwrap_or(0xFF);
                }
                Ok(())
            }
            // embassy-stm32 reports its timeout as `Other`.
            (Err(_), _) => {
                bus.count_timeout();
                Err(ErrorKind::Other)
            }
            _ => Err(ErrorKind::Bus),
        }
    }
}

impl ErrorType for ControllerPort {
    type Error = ErrorKind;
}

impl I2c for ControllerPort {
    async fn transaction(&mut self, address: u8, operations: &mut [Operation<'_>]) -> Result<(), ErrorKind> {
        for operation in operations {
            self.transfer(address, operation).await?;
        }
        Ok(())
    }
}

/// The bus's SCL line as the master's open-drain GPIO.
pub struct Scl(&'static Bus);

/// The bus's SDA line as the master's open-drain GPIO: driven low or released, and read back.
pub struct Sda(&'static Bus);

impl digital::ErrorType for Scl {
    type Error = Infallible;
}

impl OutputPin for Scl {
    fn set_low(&mut self) -> Result<(), Infallible> {
        self.0.with(|state| state.scl_low = true);
        Ok(())
    }

    /// Releasing SCL after driving it low is one clock: a slave holding SDA counts it.
    fn set_high(&mut self) -> Result<(), Infallible> {
        self.0.with(|state| {
            if core::mem::replace(&mut state.scl_low, false) {
                state.counts.pin_clocks = state.counts.pin_clocks.wrapping_add(1);
                state.sda_held = state.sda_held.saturating_sub(1);
            }
        });
        Ok(())
    }
}

impl digital::ErrorType for Sda {
    type Error = Infallible;
}

impl OutputPin for Sda {
    fn set_low(&mut self) -> Result<(), Infallible> {
        self.0.with(|state| state.sda_low = true);
        Ok(())
    }

    /// SDA rising while SCL is high, nobody else holding it, is a STOP.
    fn set_high(&mut self) -> Result<(), Infallible> {
        self.0.with(|state| {
            if core::mem::replace(&mut state.sda_low, false) && !state.scl_low && state.sda_held == 0 {
                state.counts.pin_stops = state.counts.pin_stops.wrapping_add(1);
            }
        });
        Ok(())
    }
}

impl InputPin for Sda {
    fn is_high(&mut self) -> Result<bool, Infallible> {
        Ok(self.0.with(|state| !state.sda_low && state.sda_held == 0))
    }

    fn is_low(&mut self) -> Result<bool, Infallible> {
        self.is_high().map(|high| !high)
    }
}
