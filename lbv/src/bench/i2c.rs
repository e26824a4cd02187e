//! The thruster bus: a 100 kbit/s I2C bus between the master's bus task and the thrusters' slave tasks. Every
//! transfer is charged its bit time on the virtual clock; absent addresses NACK; a TCA9548A routes channels;
//! hooks corrupt bytes, hold SDA low, and cut a slave off mid-transfer.

use core::cell::{Cell, RefCell};

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Timer, with_timeout};
use embedded_hal_async::i2c::{ErrorKind, ErrorType, I2c, NoAcknowledgeSource, Operation};
use lbv_master_fw::thrusters::{BusRecovery, MUX_ADDRESS};
use thruster_fw::{I2cTarget, Request};
use tmc_proto::Family;

/// One bit at 100 kbit/s.
pub const BIT: Duration = Duration::from_micros(10);
/// A slave that does not answer within this long leaves the master waiting for its timeout (SMBus, 25 ms).
const SLAVE_TIMEOUT: Duration = Duration::from_millis(25);

/// What the master asks of a slave in one transfer.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Transfer {
    Write(Vec<u8>),
    Read,
}

/// What the slave answered.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Answer {
    Written,
    Read(Vec<u8>),
}

/// One thruster's end of the bus, shared by the bus and the thruster's slave port.
#[derive(Default)]
pub struct SlaveLine {
    transfer: Signal<CriticalSectionRawMutex, Transfer>,
    answer: Signal<CriticalSectionRawMutex, Answer>,
    /// How often the thruster re-initialised its I2C peripheral.
    pub resets: Cell<u32>,
}

/// The slave port a thruster's I2C task serves.
pub struct SlavePort<'a> {
    line: &'a SlaveLine,
    write: Option<Vec<u8>>,
}

impl<'a> SlavePort<'a> {
    /// The port on `line`.
    pub fn new(line: &'a SlaveLine) -> Self {
        Self { line, write: None }
    }
}

impl I2cTarget for SlavePort<'_> {
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
        // Like the STM32: what does not fit is ACKed and dropped.
        let stored = bytes.len().min(buffer.len());
        for (slot, byte) in buffer.iter_mut().zip(&bytes) {
            *slot = *byte;
        }
        self.line.answer.signal(Answer::Written);
        Ok(stored)
    }

    async fn respond_to_read(&mut self, data: &[u8]) -> Result<(), ()> {
        self.line.answer.signal(Answer::Read(data.to_vec()));
        Ok(())
    }

    fn reset(&mut self) {
        self.line.resets.set(self.line.resets.get() + 1);
        self.write = None;
    }
}

/// A thruster as the bus sees it.
pub struct BusSlave {
    /// Its family, which sets its address.
    pub family: Family,
    /// Its TCA9548A channel, None when wired directly.
    pub channel: Option<u8>,
    /// Its end of the bus.
    pub line: &'static SlaveLine,
    /// False while the controller is resetting: it does not ACK.
    pub powered: bool,
    /// Flip these bits of every byte it sends (a noisy line).
    pub corrupt: u8,
    /// Flip these bits of the last byte the master writes to it (the order's checksum arrives wrong).
    pub corrupt_orders: u8,
    /// Replace the SPEED byte of every order it receives by 0x00, out of range, with a checksum that matches.
    pub out_of_range_orders: bool,
}

/// The bus, its multiplexer, and what the bench counts.
#[derive(Default)]
pub struct BusWorld {
    /// The thrusters on the bus.
    pub slaves: Vec<BusSlave>,
    /// Whether a TCA9548A is fitted.
    pub mux_fitted: bool,
    /// The TCA9548A's channel register.
    pub mux_mask: u8,
    /// A slave holds SDA low: every transfer fails until the master's recovery clocks it free.
    pub sda_stuck: bool,
    /// Bit times charged so far.
    pub bits: u64,
    /// Transfers attempted.
    pub transfers: u64,
    /// Recoveries the master ran.
    pub recoveries: u32,
}

impl BusWorld {
    fn reachable(&self, slave: &BusSlave) -> bool {
        slave
            .channel
            .is_none_or(|channel| self.mux_fitted && self.mux_mask & (1 << channel) != 0)
    }

    /// The powered slave that answers `address`, if any.
    fn addressed(&self, address: u8) -> Option<&BusSlave> {
        self.slaves
            .iter()
            .find(|slave| slave.powered && slave.family.address() == address && self.reachable(slave))
    }
}

/// The master's end of the bus.
pub struct MasterPort<'a>(pub &'a RefCell<BusWorld>);

impl ErrorType for MasterPort<'_> {
    type Error = ErrorKind;
}

/// START, the address byte with its ACK, and STOP.
const FRAME_BITS: u64 = 1 + 9 + 1;

impl MasterPort<'_> {
    /// Let the bus be busy for `bits` bit times.
    async fn charge(&self, bits: u64) {
        self.0.borrow_mut().bits += bits;
        Timer::after(BIT * u32::try_from(bits).unwrap_or(u32::MAX)).await;
    }

    async fn transfer(&mut self, address: u8, operation: &mut Operation<'_>) -> Result<(), ErrorKind> {
        let data_bits = 9 * match operation {
            Operation::Write(bytes) => bytes.len() as u64,
            Operation::Read(buffer) => buffer.len() as u64,
        };
        let (stuck, mux, slave) = {
            let mut world = self.0.borrow_mut();
            world.transfers += 1;
            let slave = world.addressed(address).map(|slave| {
                (
                    slave.line,
                    slave.corrupt,
                    slave.corrupt_orders,
                    slave.out_of_range_orders,
                )
            });
            (world.sda_stuck, world.mux_fitted && address == MUX_ADDRESS, slave)
        };
        if stuck {
            // The START cannot even be made: SDA is low.
            self.charge(1).await;
            return Err(ErrorKind::Bus);
        }
        if mux {
            if let Operation::Write(bytes) = operation
                && let Some(mask) = bytes.first()
            {
                self.0.borrow_mut().mux_mask = *mask;
            }
            self.charge(FRAME_BITS + data_bits).await;
            return Ok(());
        }
        let Some((line, corrupt, corrupt_orders, out_of_range)) = slave else {
            self.charge(FRAME_BITS).await;
            return Err(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address));
        };
        // An answer left over from a transfer the master gave up on is not this one's.
        line.answer.reset();
        line.transfer.signal(match operation {
            Operation::Write(bytes) => {
                let mut bytes = bytes.to_vec();
                if out_of_range && let [mt, speed, info, csum] = bytes.as_mut_slice() {
                    *speed = 0x00;
                    *csum = tmc_proto::checksum(&[*mt, *speed, *info]);
                }
                if let Some(last) = bytes.last_mut() {
                    *last ^= corrupt_orders;
                }
                Transfer::Write(bytes)
            }
            Operation::Read(_) => Transfer::Read,
        });
        // The slave stretches SCL until its firmware answers; one that never does times the master out.
        let answer = with_timeout(SLAVE_TIMEOUT, line.answer.wait()).await;
        self.charge(FRAME_BITS + data_bits).await;
        match (answer, operation) {
            (Ok(Answer::Written), Operation::Write(_)) => Ok(()),
            (Ok(Answer::Read(data)), Operation::Read(buffer)) => {
                for (i, byte) in buffer.iter_mut().enumerate() {
                    // A slave with nothing more to send leaves SDA high.
                    *byte = data.get(i).copied().unwrap_or(0xFF) ^ corrupt;
                }
                Ok(())
            }
            // embassy-stm32 reports its timeout as `Other`.
            (Err(_), _) => Err(ErrorKind::Other),
            _ => Err(ErrorKind::Bus),
        }
    }
}

impl I2c for MasterPort<'_> {
    async fn transaction(&mut self, address: u8, operations: &mut [Operation<'_>]) -> Result<(), ErrorKind> {
        for operation in operations {
            self.transfer(address, operation).await?;
        }
        Ok(())
    }
}

impl BusRecovery for MasterPort<'_> {
    async fn recover(&mut self) -> bool {
        // Nine clocks and a STOP free a slave that was mid-byte.
        self.charge(9 * 2 + 2).await;
        let mut world = self.0.borrow_mut();
        world.recoveries += 1;
        world.sda_stuck = false;
        true
    }
}
