//! A simulated I2C bus for the tests: 100 kbit/s bit-time accounting on the virtual clock, scripted thrusters
//! (good, silent, corrupting, clock-stretching), a stuck-SDA mode and a TCA9548A.

use core::cell::RefCell;

use embassy_time::{Duration, Instant, Timer};
use embedded_hal_async::i2c::{ErrorKind, ErrorType, I2c, NoAcknowledgeSource, Operation};
use thruster_fw::Link as ThrusterLink;
use tmc_proto::{
    Family, Faults, LegacyRevision, LegacyStatus, MaxPower, MotorKind, SeaBotixStatus, Speed, Status, checksum,
};

use super::{BUS_TIMEOUT, MUX_ADDRESS};

/// One bit at 100 kbit/s.
pub const BIT: Duration = Duration::from_micros(10);

/// How a simulated thruster behaves on the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Takes orders, answers a valid status of its family.
    Good,
    /// Never acknowledges its address (missing, unpowered).
    Silent,
    /// Answers with the checksum byte off by one.
    BadChecksum,
    /// Answers with the other family's message type.
    BadType,
    /// Answers a SeaBotix status with the speed byte 0x00 (out of range) and a matching checksum.
    BadRange,
    /// Acknowledges its address, then holds SCL low until the master's 25 ms timeout.
    Stretch,
}

/// A scripted thruster.
#[derive(Debug)]
pub struct SimThruster {
    /// Its controller core's link: takes the orders as the real firmware does.
    pub link: ThrusterLink,
    /// The TCA9548A channel it hangs on, None when wired directly.
    pub channel: Option<u8>,
    pub mode: Mode,
    /// Faults its status reports.
    pub faults: Faults,
    /// When each transfer addressed to it began (while it was reachable), whatever its mode.
    pub addressed: Vec<Instant>,
    /// When each valid order arrived.
    pub orders: Vec<Instant>,
}

impl SimThruster {
    pub fn new(family: Family, channel: Option<u8>) -> Self {
        Self {
            link: ThrusterLink::new(family),
            channel,
            mode: Mode::Good,
            faults: Faults::NONE,
            addressed: Vec::new(),
            orders: Vec::new(),
        }
    }

    fn family(&self) -> Family {
        self.link.family()
    }

    /// The status it answers: the ordered speed reached, its faults.
    fn status(&self) -> Vec<u8> {
        let speed = self.link.order().speed;
        let status = match self.family() {
            Family::SeaBotix => Status::SeaBotix(SeaBotixStatus {
                revision: 0,
                motor: MotorKind::Brushless,
                current_limited: true,
                faults: self.faults,
                current_deciamps: 12,
                speed,
                temperature_c: 21,
            }),
            Family::Legacy => Status::Legacy(LegacyStatus {
                revision: LegacyRevision::LEGACY_BRUSHED,
                faults: self.faults,
                max_power: MaxPower::Power(speed),
            }),
        };
        let mut bytes = status.encode().as_bytes().to_vec();
        match self.mode {
            Mode::BadChecksum => {
                if let Some(last) = bytes.last_mut() {
                    *last = last.wrapping_add(1);
                }
            }
            Mode::BadType => {
                let other = match self.family() {
                    Family::SeaBotix => Family::Legacy,
                    Family::Legacy => Family::SeaBotix,
                };
                bytes[0] = other.status_type();
                let last = bytes.len() - 1;
                bytes[last] = checksum(&bytes[..last]);
            }
            Mode::BadRange => {
                // SPEED is byte 4 of the SeaBotix status, MAX POWER byte 2 of a brushed Legacy one.
                let at = match self.family() {
                    Family::SeaBotix => 4,
                    Family::Legacy => 2,
                };
                bytes[at] = 0x00;
                let last = bytes.len() - 1;
                bytes[last] = checksum(&bytes[..last]);
            }
            Mode::Good | Mode::Silent | Mode::Stretch => {}
        }
        bytes
    }
}

/// One transfer as seen on the wire.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Transfer {
    pub at: Instant,
    pub address: u8,
    pub ok: bool,
}

/// Everything on one simulated bus.
#[derive(Debug, Default)]
pub struct World {
    pub thrusters: Vec<SimThruster>,
    /// A TCA9548A is fitted.
    pub mux_fitted: bool,
    /// Its control register.
    pub mux_mask: u8,
    /// When each mux control byte was written, and the byte.
    pub mux_writes: Vec<(Instant, u8)>,
    /// SDA held low: every transfer fails with a bus error until a recovery.
    pub stuck: bool,
    /// A recovery does not free SDA either.
    pub stuck_hard: bool,
    /// Bit times charged so far (recoveries included, clock stretching not).
    pub bits: u64,
    pub recoveries: u32,
    /// Transfers that two thrusters answered.
    pub collisions: u32,
    pub log: Vec<Transfer>,
}

impl World {
    pub fn with(thrusters: Vec<SimThruster>) -> Self {
        let mux_fitted = thrusters.iter().any(|t| t.channel.is_some());
        Self {
            thrusters,
            mux_fitted,
            ..Self::default()
        }
    }

    fn reachable(&self, thruster: &SimThruster) -> bool {
        thruster
            .channel
            .is_none_or(|channel| self.mux_fitted && self.mux_mask & (1 << channel) != 0)
    }

    /// Carry out a transaction at once; returns the bit times it takes, any stretching, and the result.
    fn transfer(&mut self, address: u8, operations: &mut [Operation<'_>]) -> (u64, Duration, Result<(), ErrorKind>) {
        let now = Instant::now();
        let data_bits = |operations: &[Operation<'_>]| -> u64 {
            operations
                .iter()
                .map(|op| match op {
                    Operation::Write(bytes) => 1 + 9 + 9 * bytes.len() as u64,
                    Operation::Read(buffer) => 1 + 9 + 9 * buffer.len() as u64,
                })
                .sum::<u64>()
                + 1
        };
        if self.stuck {
            // SDA low: the master cannot even make a START.
            self.log.push(Transfer {
                at: now,
                address,
                ok: false,
            });
            return (1, Duration::from_ticks(0), Err(ErrorKind::Bus));
        }
        const NACK: Result<(), ErrorKind> = Err(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address));
        if address == MUX_ADDRESS && self.mux_fitted {
            for op in operations.iter_mut() {
                match op {
                    Operation::Write(bytes) => {
                        if let Some(&mask) = bytes.last() {
                            self.mux_mask = mask;
                            self.mux_writes.push((now, mask));
                        }
                    }
                    Operation::Read(buffer) => buffer.fill(self.mux_mask),
                }
            }
            self.log.push(Transfer {
                at: now,
                address,
                ok: true,
            });
            return (data_bits(operations), Duration::from_ticks(0), Ok(()));
        }
        let answering: Vec<usize> = (0..self.thrusters.len())
            .filter(|&i| self.thrusters[i].family().address() == address && self.reachable(&self.thrusters[i]))
            .collect();
        if answering.len() > 1 {
            // Two slaves driving SDA at once: the master would read their wired-AND.
            self.collisions += 1;
            for &i in &answering[1..] {
                self.thrusters[i].addressed.push(now);
            }
        }
        let Some(thruster) = answering.first().and_then(|&i| self.thrusters.get_mut(i)) else {
            self.log.push(Transfer {
                at: now,
                address,
                ok: false,
            });
            return (11, Duration::from_ticks(0), NACK);
        };
        thruster.addressed.push(now);
        let (bits, stretch, result) = match thruster.mode {
            Mode::Silent => (11, Duration::from_ticks(0), NACK),
            Mode::Stretch => (10, BUS_TIMEOUT, Err(ErrorKind::Other)),
            _ => {
                for op in operations.iter_mut() {
                    match op {
                        Operation::Write(bytes) => {
                            if thruster.link.accept(bytes).is_ok() {
                                thruster.orders.push(now);
                            }
                        }
                        Operation::Read(buffer) => {
                            let status = thruster.status();
                            for (i, byte) in buffer.iter_mut().enumerate() {
                                // Nothing more to send: SDA stays high.
                                *byte = status.get(i).copied().unwrap_or(0xFF);
                            }
                        }
                    }
                }
                (data_bits(operations), Duration::from_ticks(0), Ok(()))
            }
        };
        self.log.push(Transfer {
            at: now,
            address,
            ok: result.is_ok(),
        });
        (bits, stretch, result)
    }
}

/// The master's handle on a simulated bus.
pub struct SimBus<'a>(pub &'a RefCell<World>);

impl ErrorType for SimBus<'_> {
    type Error = ErrorKind;
}

impl I2c for SimBus<'_> {
    async fn transaction(&mut self, address: u8, operations: &mut [Operation<'_>]) -> Result<(), ErrorKind> {
        let (bits, stretch, result) = {
            let mut world = self.0.borrow_mut();
            let (bits, stretch, result) = world.transfer(address, operations);
            world.bits += bits;
            (bits, stretch, result)
        };
        Timer::after(BIT * bits as u32 + stretch).await;
        result
    }
}

impl super::BusRecovery for SimBus<'_> {
    async fn recover(&mut self) -> bool {
        let freed = {
            let mut world = self.0.borrow_mut();
            world.recoveries += 1;
            // Nine SCL pulses, then STOP.
            world.bits += 10;
            if !world.stuck_hard {
                world.stuck = false;
            }
            !world.stuck
        };
        Timer::after(BIT * 10).await;
        freed
    }
}

/// Speed of a step, for orders in tests.
pub fn speed(step: i8) -> Speed {
    Speed::new(step).expect("a valid step")
}
