//! The I2C slave side of the thruster interface (IDS 6.4.2, 6.6): take orders, answer status reads.

use tmc_proto::{
    DecodeError, Family, Faults, LegacyRevision, LegacyStatus, MaxPower, MotorKind, Order, SeaBotixStatus, Status,
    StatusFrame,
};

/// What the master asked for once it matched this controller's address.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Request {
    /// The master writes (an order).
    Write,
    /// The master reads (the status).
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
}

/// Writes are taken into a buffer longer than an order, so an over-long write is seen and rejected instead of
/// being cut down to a plausible four bytes.
const WRITE_BUFFER_LEN: usize = 8;

/// Orders discarded since power-up, by reason (IDS 6.6.1: a bad message is discarded whole).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct OrderErrors {
    /// Writes that were not 4 bytes long.
    pub length: u32,
    /// Writes whose first byte was not this family's order type.
    pub message_type: u32,
    /// Writes whose checksum did not match.
    pub checksum: u32,
    /// Orders whose SPEED byte was outside 0x19..=0xE6.
    pub speed_range: u32,
}

impl OrderErrors {
    fn count(&mut self, error: DecodeError) {
        let counter = match error {
            DecodeError::Length { .. } => &mut self.length,
            DecodeError::MessageType { .. } => &mut self.message_type,
            DecodeError::Checksum { .. } => &mut self.checksum,
            DecodeError::SpeedOutOfRange(_) => &mut self.speed_range,
        };
        *counter = counter.saturating_add(1);
    }

    /// All discarded orders.
    pub fn total(&self) -> u32 {
        self.length
            .saturating_add(self.message_type)
            .saturating_add(self.checksum)
            .saturating_add(self.speed_range)
    }
}

/// This controller's side of the link: its identity, the last valid order, the discard counters and the
/// status frame kept ready for the next read.
///
/// No power stage is driven yet, so the controller reports the ordered speed as reached, no current and no
/// faults; the temperature reads 0 until a sensor is wired in.
#[derive(Debug, Clone)]
pub struct Link {
    family: Family,
    motor: MotorKind,
    order: Order,
    errors: OrderErrors,
    frame: StatusFrame,
}

impl Link {
    /// A controller of `family` driving a `motor`, stopped until the first valid order.
    pub fn new(family: Family, motor: MotorKind) -> Self {
        let order = Order::STOP;
        let frame = status(family, motor, order).encode();
        Self {
            family,
            motor,
            order,
            errors: OrderErrors::default(),
            frame,
        }
    }

    /// The controller family this link answers as.
    pub fn family(&self) -> Family {
        self.family
    }

    /// The last valid order.
    pub fn order(&self) -> Order {
        self.order
    }

    /// Orders discarded so far.
    pub fn errors(&self) -> OrderErrors {
        self.errors
    }

    /// The status frame the next read gets.
    pub fn frame(&self) -> &StatusFrame {
        &self.frame
    }

    /// Take a write from the master: a valid order replaces the last one; anything else is counted and changes
    /// nothing else.
    pub fn accept(&mut self, bytes: &[u8]) -> Result<Order, DecodeError> {
        match Order::decode(self.family, bytes) {
            Ok(order) => {
                self.order = order;
                self.frame = status(self.family, self.motor, order).encode();
                Ok(order)
            }
            Err(error) => {
                self.errors.count(error);
                Err(error)
            }
        }
    }
}

/// The status this controller reports for an applied `order`.
fn status(family: Family, motor: MotorKind, order: Order) -> Status {
    let faults = Faults::NONE;
    match family {
        Family::SeaBotix => Status::SeaBotix(SeaBotixStatus {
            revision: 0,
            motor,
            current_limited: true,
            faults,
            current_deciamps: 0,
            speed: order.speed,
            temperature_c: 0,
        }),
        Family::Legacy => Status::Legacy(match motor {
            MotorKind::Brushless => LegacyStatus {
                revision: LegacyRevision::AVEOX_BRUSHLESS,
                faults,
                max_power: MaxPower::Current { deciamps: 0 },
            },
            MotorKind::Brushed => LegacyStatus {
                revision: LegacyRevision::BRUSHED_REV4,
                faults,
                max_power: MaxPower::Power(order.speed),
            },
        }),
    }
}

/// What one transfer did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum ServeEvent {
    /// A valid order was taken.
    Order(Order),
    /// A write was discarded.
    Rejected(DecodeError),
    /// The status frame was sent.
    StatusSent,
}

/// Serve one transfer: wait to be addressed, then take the order or send the ready status frame.
pub async fn serve_once<T: I2cTarget>(target: &mut T, link: &mut Link) -> Result<ServeEvent, T::Error> {
    match target.listen().await? {
        Request::Write => {
            let mut buffer = [0; WRITE_BUFFER_LEN];
            let received = target.respond_to_write(&mut buffer).await?;
            // A peripheral never reports more than the buffer holds; if one did, the whole buffer is judged.
            let bytes = buffer.get(..received).unwrap_or(&buffer);
            Ok(match link.accept(bytes) {
                Ok(order) => ServeEvent::Order(order),
                Err(error) => ServeEvent::Rejected(error),
            })
        }
        Request::Read => {
            target.respond_to_read(link.frame().as_bytes()).await?;
            Ok(ServeEvent::StatusSent)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embassy_futures::block_on;
    use std::collections::VecDeque;
    use tmc_proto::{Speed, checksum};

    /// A master's transfers, played one by one against the core.
    enum Transfer {
        Write(Vec<u8>),
        Read,
    }

    #[derive(Default)]
    struct ScriptedMaster {
        script: VecDeque<Transfer>,
        pending_write: Option<Vec<u8>>,
        replies: Vec<Vec<u8>>,
    }

    #[derive(Debug, PartialEq)]
    struct ScriptEnded;

    impl I2cTarget for ScriptedMaster {
        type Error = ScriptEnded;

        async fn listen(&mut self) -> Result<Request, ScriptEnded> {
            match self.script.pop_front().ok_or(ScriptEnded)? {
                Transfer::Write(bytes) => {
                    self.pending_write = Some(bytes);
                    Ok(Request::Write)
                }
                Transfer::Read => Ok(Request::Read),
            }
        }

        async fn respond_to_write(&mut self, buffer: &mut [u8]) -> Result<usize, ScriptEnded> {
            let bytes = self.pending_write.take().ok_or(ScriptEnded)?;
            // Like the STM32: bytes beyond the buffer are ACKed and dropped.
            let stored = bytes.len().min(buffer.len());
            buffer[..stored].copy_from_slice(&bytes[..stored]);
            Ok(stored)
        }

        async fn respond_to_read(&mut self, data: &[u8]) -> Result<(), ScriptEnded> {
            self.replies.push(data.to_vec());
            Ok(())
        }
    }

    fn run(link: &mut Link, script: Vec<Transfer>) -> (Vec<ServeEvent>, Vec<Vec<u8>>) {
        let mut master = ScriptedMaster {
            script: script.into(),
            ..Default::default()
        };
        let mut events = Vec::new();
        while let Ok(event) = block_on(serve_once(&mut master, link)) {
            events.push(event);
        }
        (events, master.replies)
    }

    fn order(family: Family, step: i8) -> Vec<u8> {
        Order::new(Speed::new(step).unwrap()).encode(family).to_vec()
    }

    #[test]
    fn starts_stopped_and_answers_with_a_valid_status_of_its_family() {
        for family in Family::ALL {
            let mut link = Link::new(family, MotorKind::Brushless);
            let (events, replies) = run(&mut link, vec![Transfer::Read]);
            assert_eq!(events, [ServeEvent::StatusSent]);
            assert_eq!(replies[0].len(), family.status_len());
            let status = Status::decode(family, &replies[0]).unwrap();
            assert_eq!(status.family(), family);
            assert!(status.faults().is_empty());
            assert_eq!(link.order(), Order::STOP);
        }
    }

    #[test]
    fn a_valid_order_is_applied_and_reported_in_the_next_status() {
        let mut link = Link::new(Family::SeaBotix, MotorKind::Brushless);
        let (events, replies) = run(
            &mut link,
            vec![Transfer::Write(order(Family::SeaBotix, 40)), Transfer::Read],
        );
        let expected = Order::new(Speed::new(40).unwrap());
        assert_eq!(events, [ServeEvent::Order(expected), ServeEvent::StatusSent]);
        match Status::decode(Family::SeaBotix, &replies[0]).unwrap() {
            Status::SeaBotix(status) => {
                assert_eq!(status.speed.step(), 40);
                assert_eq!(status.motor, MotorKind::Brushless);
            }
            other => panic!("wrong family: {other:?}"),
        }
    }

    #[test]
    fn legacy_brushed_reports_the_power_set_into_the_motor() {
        let mut link = Link::new(Family::Legacy, MotorKind::Brushed);
        let (_, replies) = run(
            &mut link,
            vec![Transfer::Write(order(Family::Legacy, -30)), Transfer::Read],
        );
        let Status::Legacy(status) = Status::decode(Family::Legacy, &replies[0]).unwrap() else {
            panic!("wrong family")
        };
        assert_eq!(status.revision, LegacyRevision::BRUSHED_REV4);
        assert_eq!(status.max_power, MaxPower::Power(Speed::new(-30).unwrap()));
    }

    #[test]
    fn bad_writes_are_counted_and_change_nothing() {
        let family = Family::SeaBotix;
        let mut bad_checksum = order(family, 10);
        bad_checksum[3] ^= 0x01;
        let mut out_of_range = vec![0x52, 0xE7, 100];
        out_of_range.push(checksum(&out_of_range));
        let too_long = [order(family, 10), vec![0]].concat();
        let script = vec![
            Transfer::Write(order(family, 20)),
            Transfer::Write(bad_checksum),
            Transfer::Write(out_of_range),
            Transfer::Write(order(Family::Legacy, 10)),
            Transfer::Write(order(family, 10)[..3].to_vec()),
            Transfer::Write(too_long),
            Transfer::Write(vec![0; 12]),
            Transfer::Read,
        ];
        let mut link = Link::new(family, MotorKind::Brushless);
        let (events, replies) = run(&mut link, script);

        assert_eq!(events.len(), 8);
        assert!(
            events[1..7]
                .iter()
                .all(|event| matches!(event, ServeEvent::Rejected(_)))
        );
        assert_eq!(link.order().speed.step(), 20, "the last valid order stands");
        let status = Status::decode(family, &replies[0]).unwrap();
        let Status::SeaBotix(status) = status else {
            panic!("wrong family")
        };
        assert_eq!(status.speed.step(), 20);
        assert_eq!(
            link.errors(),
            OrderErrors {
                length: 3,
                message_type: 1,
                checksum: 1,
                speed_range: 1
            },
            "12 bytes are cut to the 8-byte buffer and still rejected on length"
        );
        assert_eq!(link.errors().total(), 6);
    }

    #[test]
    fn the_latest_valid_order_wins() {
        let family = Family::Legacy;
        let mut link = Link::new(family, MotorKind::Brushless);
        let script = (1..=5).map(|step| Transfer::Write(order(family, -step * 20))).collect();
        run(&mut link, script);
        assert_eq!(link.order().speed.step(), -100);
    }
}
