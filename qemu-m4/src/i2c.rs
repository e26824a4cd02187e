//! The thruster bus inside the chip: the master's I2C controller port and each thruster's target port, with
//! 100 kbit/s bit times spent on the clock, a TCA9548A, NACKs from absent or unpowered thrusters, and a reset
//! pressed during a transfer.
//!
//! A transfer hands the master's bytes to the addressed thruster's I2C task and waits, as a clock-stretching
//! slave makes the master wait, until that task answers or the bus timeout passes.

use core::cell::RefCell;

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Timer, with_timeout};
use embedded_hal_async::i2c::{ErrorKind, ErrorType, I2c, NoAcknowledgeSource, Operation};
use lbv_master_fw::thrusters::{BUS_FREQUENCY_HZ, BUS_TIMEOUT, BusRecovery, MUX_ADDRESS, transfer_bits};
use thruster_fw::{I2cTarget, Request};
use tmc_proto::MAX_STATUS_LEN;

use crate::thruster::Thruster;

/// Bytes of a write a thruster keeps; the STM32 slave ACKs and drops the rest.
const WRITE_CAPACITY: usize = 8;
/// Most thrusters on the bus.
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

    /// Forget a transfer begun before the thruster was reset.
    pub fn clear(&self) {
        self.transfer.reset();
    }
}

/// The target port a thruster's I2C task serves.
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
        Ok(match self.line.transfer.wait().await {
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
    /// The thruster whose reset button the operator is about to press: it is reset as the transfer begins.
    Resetting(&'static Thruster),
    Nobody,
}

/// The bus's own state.
#[derive(Debug, Default)]
struct State {
    mux_mask: u8,
    reset_armed: Option<usize>,
    transfers: u32,
    nacks: u32,
    timeouts: u32,
}

/// The bus: its thrusters, whether a TCA9548A routes them, what it counted.
pub struct Bus {
    thrusters: heapless::Vec<&'static Thruster, MAX_THRUSTERS>,
    mux_fitted: bool,
    state: Mutex<CriticalSectionRawMutex, RefCell<State>>,
}

/// What the bus counted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BusCounts {
    /// Transfers the master started.
    pub transfers: u32,
    /// Of those, not acknowledged.
    pub nacks: u32,
    /// Of those, timed out.
    pub timeouts: u32,
}

impl Bus {
    /// A bus with `thrusters` on it, behind a TCA9548A when `mux_fitted` (each on its own channel).
    pub fn new(thrusters: &[&'static Thruster], mux_fitted: bool) -> Self {
        let mut list = heapless::Vec::new();
        for thruster in thrusters.iter().take(MAX_THRUSTERS) {
            let _ = list.push(*thruster);
        }
        Self {
            thrusters: list,
            mux_fitted,
            state: Mutex::new(RefCell::new(State::default())),
        }
    }

    /// The operator will press `thruster`'s reset button: it lands in the next transfer to it.
    pub fn reset_during_next_transfer(&self, thruster: &Thruster) {
        let index = self.thrusters.iter().position(|t| core::ptr::eq(*t, thruster));
        self.state.lock(|state| state.borrow_mut().reset_armed = index);
    }

    /// The thrusters on it.
    pub fn thrusters(&self) -> &[&'static Thruster] {
        &self.thrusters
    }

    /// What it counted.
    pub fn counts(&self) -> BusCounts {
        self.state.lock(|state| {
            let state = state.borrow();
            BusCounts {
                transfers: state.transfers,
                nacks: state.nacks,
                timeouts: state.timeouts,
            }
        })
    }

    fn reach(&self, address: u8) -> Reached {
        self.state.lock(|state| {
            let mut state = state.borrow_mut();
            state.transfers = state.transfers.wrapping_add(1);
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
                Some((index, thruster)) if state.reset_armed == Some(index) => {
                    state.reset_armed = None;
                    Reached::Resetting(thruster)
                }
                Some((_, thruster)) => Reached::Thruster(thruster),
                None => {
                    state.nacks = state.nacks.wrapping_add(1);
                    Reached::Nobody
                }
            }
        })
    }

    fn count_timeout(&self) {
        self.state.lock(|state| {
            let mut state = state.borrow_mut();
            state.timeouts = state.timeouts.wrapping_add(1);
        });
    }
}

/// The master's end of the bus.
pub struct ControllerPort(pub &'static Bus);

/// The time `bits` take on the bus.
fn bit_time(bits: u32) -> Duration {
    Duration::from_micros(u64::from(bits) * 1_000_000 / u64::from(BUS_FREQUENCY_HZ))
}

impl ControllerPort {
    async fn transfer(&mut self, address: u8, operation: &mut Operation<'_>) -> Result<(), ErrorKind> {
        let bytes = match operation {
            Operation::Write(bytes) => bytes.len(),
            Operation::Read(buffer) => buffer.len(),
        };
        let bits = transfer_bits(u32::try_from(bytes).unwrap_or(u32::MAX));
        let thruster = match self.0.reach(address) {
            Reached::Mux => {
                match operation {
                    Operation::Write(bytes) => {
                        if let Some(mask) = bytes.last() {
                            self.0.state.lock(|state| state.borrow_mut().mux_mask = *mask);
                        }
                    }
                    Operation::Read(buffer) => {
                        let mask = self.0.state.lock(|state| state.borrow().mux_mask);
                        buffer.iter_mut().for_each(|byte| *byte = mask);
                    }
                }
                Timer::after(bit_time(bits)).await;
                return Ok(());
            }
            Reached::Nobody => {
                // START, the address byte and its missing ACK, STOP.
                Timer::after(bit_time(transfer_bits(0))).await;
                return Err(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address));
            }
            Reached::Resetting(thruster) => {
                // The address was acknowledged, then the board went into reset: nobody finishes the transfer.
                thruster.press_reset();
                Timer::after(BUS_TIMEOUT).await;
                self.0.count_timeout();
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
        let answer = with_timeout(BUS_TIMEOUT, line.answer.wait()).await;
        Timer::after(bit_time(bits)).await;
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
                self.0.count_timeout();
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

impl BusRecovery for ControllerPort {
    async fn recover(&mut self) -> bool {
        // Nine clocks and a STOP (UM10204 3.1.16); no thruster here ever holds SDA, so it is always free after.
        Timer::after(bit_time(9 + 1)).await;
        true
    }
}
