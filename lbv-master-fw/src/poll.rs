//! One exchange with a thruster: send the order, read the status (IDS 6.6.1, 8.3, 8.4).

use embedded_hal_async::i2c::I2c;
use tmc_proto::{DecodeError, Decoded, Family, MAX_STATUS_LEN, Order, Status};

/// Why a poll failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum PollError<E> {
    /// Writing the order failed on the bus (a missing thruster NACKs its address).
    Order(E),
    /// Reading the status failed on the bus.
    Status(E),
    /// The status arrived but is not a valid frame of the thruster's family (wrong length, type or checksum).
    Decode(DecodeError),
}

/// Send `order` to the thruster of `family` and read back its status.
///
/// The order and the read are separate transfers, each ended by STOP, as the IDS describes them (write at
/// 0x52/0x54, read at 0x53/0x55). A valid frame with an out-of-range field is a status (its faults count) with a
/// warning, not a failure.
pub async fn poll_thruster<I: I2c>(
    i2c: &mut I,
    family: Family,
    order: Order,
) -> Result<Decoded<Status>, PollError<I::Error>> {
    let address = family.address();
    i2c.write(address, &order.encode(family))
        .await
        .map_err(PollError::Order)?;
    let mut buffer = [0; MAX_STATUS_LEN];
    // Never empty: status_len() is at most MAX_STATUS_LEN.
    let reply = buffer.get_mut(..family.status_len()).unwrap_or_default();
    i2c.read(address, reply).await.map_err(PollError::Status)?;
    Status::decode(family, reply).map_err(PollError::Decode)
}

#[cfg(test)]
mod tests {
    use super::*;
    use embassy_futures::block_on;
    use embedded_hal_async::i2c::{ErrorKind, ErrorType, NoAcknowledgeSource, Operation};
    use thruster_fw::Link;
    use tmc_proto::{Faults, LegacyRevision, LegacyStatus, MaxPower, MotorKind, SeaBotixStatus, Speed, StatusFrame};

    /// A bus with one thruster on it: the thruster firmware's own link core takes the orders, and the status
    /// reports the ordered speed as reached. `corrupt` flips bits of every status byte read, as a noisy line would.
    struct Bus {
        thruster: Link,
        corrupt: u8,
        transfers: usize,
    }

    impl Bus {
        fn with(family: Family) -> Self {
            Self {
                thruster: Link::new(family),
                corrupt: 0,
                transfers: 0,
            }
        }

        fn status(&self) -> StatusFrame {
            let faults = Faults::NONE;
            let speed = self.thruster.order().speed;
            let status = match self.thruster.family() {
                Family::SeaBotix => Status::SeaBotix(SeaBotixStatus {
                    revision: 0,
                    motor: MotorKind::Brushless,
                    current_limited: true,
                    faults,
                    current_deciamps: 0,
                    speed,
                    temperature_c: 20,
                }),
                Family::Legacy => Status::Legacy(LegacyStatus {
                    revision: LegacyRevision::LEGACY_BRUSHED,
                    faults,
                    max_power: MaxPower::Power(speed),
                }),
            };
            status.encode()
        }
    }

    impl ErrorType for Bus {
        type Error = ErrorKind;
    }

    impl I2c for Bus {
        async fn transaction(&mut self, address: u8, operations: &mut [Operation<'_>]) -> Result<(), ErrorKind> {
            self.transfers += 1;
            if address != self.thruster.family().address() {
                return Err(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address));
            }
            for operation in operations {
                match operation {
                    Operation::Write(bytes) => {
                        let _ = self.thruster.accept(bytes);
                    }
                    Operation::Read(buffer) => {
                        let frame = self.status();
                        let frame = frame.as_bytes();
                        for (i, byte) in buffer.iter_mut().enumerate() {
                            // A slave with nothing more to send leaves SDA high: 0xFF.
                            *byte = frame.get(i).copied().unwrap_or(0xFF) ^ self.corrupt;
                        }
                    }
                }
            }
            Ok(())
        }
    }

    fn forward(step: i8) -> Order {
        Order::new(Speed::new(step).unwrap())
    }

    #[test]
    fn polls_each_family_and_decodes_the_reply() {
        for family in Family::ALL {
            let mut bus = Bus::with(family);
            let decoded = block_on(poll_thruster(&mut bus, family, forward(25))).unwrap();
            assert_eq!(decoded.warning, None);
            assert_eq!(decoded.status.family(), family);
            assert_eq!(bus.thruster.order(), forward(25), "the order reached the thruster");
            assert_eq!(bus.transfers, 2, "one write and one read");
        }
    }

    #[test]
    fn the_status_reports_the_order_just_sent() {
        let mut bus = Bus::with(Family::SeaBotix);
        let status = block_on(poll_thruster(&mut bus, Family::SeaBotix, forward(-60)))
            .unwrap()
            .status;
        let Status::SeaBotix(SeaBotixStatus { speed, .. }) = status else {
            panic!("wrong family")
        };
        assert_eq!(speed.step(), -60);
    }

    #[test]
    fn a_missing_thruster_is_a_nack_on_the_order() {
        let mut bus = Bus::with(Family::Legacy);
        let error = block_on(poll_thruster(&mut bus, Family::SeaBotix, Order::STOP)).unwrap_err();
        assert_eq!(
            error,
            PollError::Order(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address))
        );
        assert_eq!(bus.transfers, 1, "no read after a failed order");
    }

    #[test]
    fn an_odd_field_keeps_the_faults() {
        // A brushed Legacy controller reporting WATER with MAX POWER 0x00, outside the SPEED range.
        struct Odd;
        impl ErrorType for Odd {
            type Error = ErrorKind;
        }
        impl I2c for Odd {
            async fn transaction(&mut self, _: u8, operations: &mut [Operation<'_>]) -> Result<(), ErrorKind> {
                for operation in operations {
                    if let Operation::Read(buffer) = operation {
                        for (slot, byte) in buffer.iter_mut().zip([0x55, 0x50, 0x00, 0xA5]) {
                            *slot = byte;
                        }
                    }
                }
                Ok(())
            }
        }
        let decoded = block_on(poll_thruster(&mut Odd, Family::Legacy, Order::STOP)).unwrap();
        assert_eq!(decoded.status.faults(), Faults::WATER);
        assert_eq!(decoded.warning, Some(tmc_proto::FieldWarning::MaxPower(0x00)));
    }

    #[test]
    fn a_corrupted_status_is_a_decode_error() {
        let mut bus = Bus::with(Family::SeaBotix);
        bus.corrupt = 0x01;
        let error = block_on(poll_thruster(&mut bus, Family::SeaBotix, Order::STOP)).unwrap_err();
        assert!(matches!(
            error,
            PollError::Decode(DecodeError::MessageType {
                expected: 0x53,
                actual: 0x52
            })
        ));
    }
}
