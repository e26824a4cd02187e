//! The master's ports on lbv-sim's simulated parts, for the bench (Cargo feature `sim`, host only) and the host
//! tests: a thruster bus recovered by the core's own [`clear_bus`](crate::recovery::clear_bus) on the simulated
//! lines, the battery CAN receiver on a simulated CAN bus, the settings store on a simulated G431 flash, and a
//! reboot that whoever runs the board carries out.

extern crate alloc;

use alloc::rc::Rc;
use core::cell::Cell;
use core::convert::Infallible;

use embassy_time::Delay;
use lbv_sim::Queue;
use lbv_sim::flash::Stm32g4Flash;
use lbv_sim::i2c::{Bus, Master, Scl, Sda};

use crate::battery::{CanFrame, CanReceiver};
use crate::recovery::BusConfig;
use crate::recovery::PinRecovery;
use crate::settings::{Reboot, Store};

/// A simulated thruster bus as the master sees it: transfers on lbv-sim's master port, the recovery on its lines.
pub type ThrusterBus = PinRecovery<Master, Scl, Sda, Delay>;

/// The master's port on `bus`, whose speed is `config`'s.
pub fn thruster_bus(bus: &Bus, config: &BusConfig) -> ThrusterBus {
    PinRecovery {
        i2c: bus.master(),
        scl: bus.scl(),
        sda: bus.sda(),
        delay: Delay,
        bus: *config,
    }
}

/// A node's receive queue on a simulated CAN bus.
impl CanReceiver for Queue<CanFrame> {
    type Error = Infallible;

    async fn receive(&mut self) -> Result<CanFrame, Infallible> {
        Ok(Queue::receive(self).await)
    }
}

/// The G431's 128 KiB of flash, erased: 64 pages of 2 KiB (RM0440 3.3.1).
pub fn g431_flash() -> Stm32g4Flash {
    Stm32g4Flash::new(64)
}

/// The settings store on a simulated G431 `flash`, in the pages the binding gives it (a handle: the memory stays
/// with whoever holds another).
pub fn flash_store(flash: &Stm32g4Flash) -> Store<Stm32g4Flash> {
    Store::g431(flash.clone())
}

/// A simulated master's reboot: it counts the request and waits; whoever runs the board sees
/// [`RebootRequest::requested`], drops the master's tasks and boots it again.
#[derive(Debug, Clone, Default)]
pub struct RebootRequest(Rc<Cell<u32>>);

impl RebootRequest {
    /// Reboots asked for so far.
    pub fn requested(&self) -> u32 {
        self.0.get()
    }
}

impl Reboot for RebootRequest {
    async fn reboot(&mut self) -> ! {
        self.0.set(self.0.get().saturating_add(1));
        core::future::pending().await
    }
}

/// A scripted thruster for the tests: its link core is the thruster firmware's own (it takes orders as the real
/// controller does); its status reports the ordered speed as reached, with the faults and the misbehaviour the
/// test sets.
#[cfg(test)]
pub(crate) mod scripted {
    use embassy_time::Instant;
    use lbv_sim::i2c::{Device, Reply};
    use thruster_fw::Link;
    use tmc_proto::{
        Family, Faults, LegacyRevision, LegacyStatus, MaxPower, MotorKind, SeaBotixStatus, Speed, Status, checksum,
    };

    use crate::recovery::BusConfig;

    /// How a scripted thruster behaves on the bus.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub(crate) enum Mode {
        /// Takes orders, answers a valid status of its family.
        Good,
        /// Never acknowledges its address (missing, unpowered).
        Silent,
        /// Answers with the checksum byte off by one.
        BadChecksum,
        /// Answers with the other family's message type.
        BadType,
        /// Answers with the speed byte 0x00 (out of range) and a matching checksum.
        BadRange,
        /// Acknowledges its address, then holds SCL low past the master's timeout.
        Stretch,
    }

    /// A scripted thruster.
    #[derive(Debug)]
    pub(crate) struct SimThruster {
        /// Its controller core's link.
        pub link: Link,
        pub mode: Mode,
        /// Faults its status reports.
        pub faults: Faults,
        /// Its status says its link failsafe stopped it (SeaBotix FAULT bit 5).
        pub link_failsafe: bool,
        /// Its status says a sustained overcurrent stopped it (SeaBotix FAULT bit 6).
        pub overcurrent: bool,
        /// When each transfer addressed to it began (while it was reachable), whatever its mode.
        pub addressed: Vec<Instant>,
        /// When each valid order arrived.
        pub orders: Vec<Instant>,
    }

    impl SimThruster {
        pub(crate) fn new(family: Family) -> Self {
            Self {
                link: Link::new(family),
                mode: Mode::Good,
                faults: Faults::NONE,
                link_failsafe: false,
                overcurrent: false,
                addressed: Vec::new(),
                orders: Vec::new(),
            }
        }

        fn family(&self) -> Family {
            self.link.family()
        }

        /// The status it answers: the ordered speed reached, its faults, its misbehaviour.
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
            let mut extensions = 0;
            if self.link_failsafe {
                extensions |= SeaBotixStatus::FAULT_LINK_FAILSAFE;
            }
            if self.overcurrent {
                extensions |= SeaBotixStatus::FAULT_OVERCURRENT;
            }
            let mut bytes = status.encode().with_fault_bits(extensions).as_bytes().to_vec();
            let last = bytes.len() - 1;
            match self.mode {
                Mode::BadChecksum => bytes[last] = bytes[last].wrapping_add(1),
                Mode::BadType => {
                    let other = match self.family() {
                        Family::SeaBotix => Family::Legacy,
                        Family::Legacy => Family::SeaBotix,
                    };
                    bytes[0] = other.status_type();
                    bytes[last] = checksum(&bytes[..last]);
                }
                Mode::BadRange => {
                    // SPEED is byte 4 of the SeaBotix status, MAX POWER byte 2 of a brushed Legacy one.
                    let at = match self.family() {
                        Family::SeaBotix => 4,
                        Family::Legacy => 2,
                    };
                    bytes[at] = 0x00;
                    bytes[last] = checksum(&bytes[..last]);
                }
                Mode::Good | Mode::Silent | Mode::Stretch => {}
            }
            bytes
        }

        /// How it answers being addressed now.
        fn addressed(&mut self) -> Option<Reply> {
            self.addressed.push(Instant::now());
            match self.mode {
                Mode::Silent => Some(Reply::Nack),
                Mode::Stretch => Some(Reply::Stretch(BusConfig::THRUSTERS.timeout)),
                _ => None,
            }
        }
    }

    impl Device for SimThruster {
        fn address(&self) -> u8 {
            self.family().address()
        }

        fn write(&mut self, bytes: &[u8]) -> Reply {
            if let Some(reply) = self.addressed() {
                return reply;
            }
            if self.link.accept(bytes).is_ok() {
                self.orders.push(Instant::now());
            }
            Reply::Ack
        }

        fn read(&mut self, buffer: &mut [u8]) -> Reply {
            if let Some(reply) = self.addressed() {
                return reply;
            }
            for (byte, status) in buffer.iter_mut().zip(self.status()) {
                *byte = status;
            }
            Reply::Ack
        }
    }

    /// Speed of a step, for orders in tests.
    pub(crate) fn speed(step: i8) -> Speed {
        Speed::new(step).expect("a valid step")
    }
}
