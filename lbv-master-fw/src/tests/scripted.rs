//! A scripted thruster for the tests: its link core is the thruster firmware's own (it takes orders as the real
//! controller does); its status reports the ordered speed as reached, with the faults and the misbehaviour the
//! test sets.

use embassy_time::Instant;
use lbv_sim::i2c::{Device, Reply};
use thruster_fw::MasterLink;
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
    pub link: MasterLink,
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
            link: MasterLink::new(family),
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
