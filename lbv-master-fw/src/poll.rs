//! One exchange with a thruster: send the order, read the status (IDS 6.6.1, 8.3, 8.4).

use embedded_hal_async::i2c::I2c;
use tmc_proto::{DecodeError, Decoded, Family, MAX_STATUS_LEN, Order, SeaBotixStatus, Status, StatusForm};

/// Why a poll failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) enum PollError<E> {
    /// Writing the order failed on the bus (a missing thruster NACKs its address): the order was not delivered.
    Order(E),
    /// The order was delivered, but reading the status failed on the bus.
    Status(E),
    /// The order was delivered, but the status is not a valid frame of the thruster's family in either form
    /// (wrong length, type or checksum).
    Decode(DecodeError),
}

impl<E> PollError<E> {
    /// Whether the order reached the thruster (its write was acknowledged) before the poll failed.
    pub(crate) const fn delivered(&self) -> bool {
        matches!(self, PollError::Status(_) | PollError::Decode(_))
    }
}

/// A status read back, and the form it came in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct Polled {
    /// The status, with a warning for an odd field.
    pub(crate) decoded: Decoded<Status>,
    /// Full (MT repeated) or implied-type (the 6-byte SeaBotix form some controllers send).
    pub(crate) form: StatusForm,
    /// The status says the thruster's link failsafe stopped it: this project's SeaBotix FAULT bit 5
    /// ([`SeaBotixStatus::FAULT_LINK_FAILSAFE`]), which only this project's thruster sends, in the full form.
    pub(crate) link_failsafe: bool,
    /// The status says a sustained overcurrent holds the thruster's bridge off until a zero order: this project's
    /// SeaBotix FAULT bit 6 ([`SeaBotixStatus::FAULT_OVERCURRENT`]), in the full form only, as bit 5.
    pub(crate) overcurrent: bool,
}

/// Send `order` to the thruster of `family` and read back its status.
///
/// The order and the read are separate transfers, each ended by STOP, as the IDS describes them (write at
/// 0x52/0x54, read at 0x53/0x55). The family's full status length is read, and the status taken in the full form
/// or, unless `last` (the form the thruster was last read in) is the full one, in the implied-type form: about one
/// damaged full frame in 256 checks as the other form, so line noise on a thruster known to send full frames must
/// not pass for one ([`Status::decode_either`]). A valid frame with an out-of-range field is a status (its faults
/// count) with a warning, not a failure.
pub(crate) async fn poll_thruster<I: I2c>(
    i2c: &mut I,
    family: Family,
    order: Order,
    last: Option<StatusForm>,
) -> Result<Polled, PollError<I::Error>> {
    let address = family.address();
    i2c.write(address, &order.encode(family))
        .await
        .map_err(PollError::Order)?;
    let mut buffer = [0; MAX_STATUS_LEN];
    // Never empty: status_len() is at most MAX_STATUS_LEN.
    let reply = buffer.get_mut(..family.status_len()).unwrap_or_default();
    i2c.read(address, reply).await.map_err(PollError::Status)?;
    let (decoded, form) = match last {
        Some(StatusForm::Full) => (Status::decode(family, reply), StatusForm::Full),
        None | Some(StatusForm::ImpliedType) => match Status::decode_either(family, reply) {
            Ok((decoded, form)) => (Ok(decoded), form),
            Err(error) => (Err(error), StatusForm::Full),
        },
    };
    let decoded = decoded.map_err(PollError::Decode)?;
    let extended = form == StatusForm::Full && family == Family::SeaBotix;
    Ok(Polled {
        decoded,
        form,
        link_failsafe: extended && SeaBotixStatus::link_failsafe_in(reply),
        overcurrent: extended && SeaBotixStatus::overcurrent_in(reply),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recovery::BusConfig;
    use crate::tests::scripted::SimThruster;
    use core::cell::{Cell, RefCell};
    use embassy_futures::block_on;
    use embassy_time::Duration;
    use embedded_hal_async::i2c::{ErrorKind, ErrorType, NoAcknowledgeSource, Operation};
    use lbv_sim::i2c::{Bus, DeviceId, Master, Route, Tamper, Timing};
    use lbv_sim::{Executor, clock};
    use std::rc::Rc;
    use tmc_proto::{Faults, SeaBotixStatus, Speed};

    /// A bus with one scripted thruster of `family` on it (its status reports the ordered speed as reached).
    fn bus_with(family: Family) -> (Bus, Rc<RefCell<SimThruster>>, DeviceId) {
        let bus = Bus::new(Timing::new(
            BusConfig::THRUSTERS.frequency_hz,
            BusConfig::THRUSTERS.timeout,
        ));
        let thruster = Rc::new(RefCell::new(SimThruster::new(family)));
        let id = bus.attach(thruster.clone(), Route::Direct);
        (bus, thruster, id)
    }

    /// One poll on `bus`, on virtual time.
    fn poll(bus: &Bus, family: Family, order: Order) -> Result<Polled, PollError<ErrorKind>> {
        poll_after(bus, family, order, None)
    }

    /// One poll on `bus` of a thruster last read in the form `last`, on virtual time.
    fn poll_after(
        bus: &Bus,
        family: Family,
        order: Order,
        last: Option<StatusForm>,
    ) -> Result<Polled, PollError<ErrorKind>> {
        let clock = clock::take();
        let result = Cell::new(None);
        let mut master: Master = bus.master();
        let mut executor = Executor::new();
        executor.spawn(async {
            result.set(Some(poll_thruster(&mut master, family, order, last).await));
        });
        executor.run_until(&clock, Duration::from_millis(100), Duration::from_micros(10), || {
            result.get().is_some()
        });
        drop(executor);
        result.get().expect("the poll ended")
    }

    fn forward(step: i8) -> Order {
        Order::new(Speed::new(step).unwrap())
    }

    #[test]
    fn polls_each_family_and_decodes_the_reply() {
        for family in Family::ALL {
            let (bus, thruster, _) = bus_with(family);
            let polled = poll(&bus, family, forward(25)).unwrap();
            assert_eq!(polled.form, StatusForm::Full);
            let decoded = polled.decoded;
            assert_eq!(decoded.warning, None);
            assert_eq!(decoded.status.family(), family);
            assert_eq!(
                thruster.borrow().link.order(),
                forward(25),
                "the order reached the thruster"
            );
            assert_eq!(bus.stats().transfers, 2, "one write and one read");
        }
    }

    #[test]
    fn the_status_reports_the_order_just_sent() {
        let (bus, ..) = bus_with(Family::SeaBotix);
        let status = poll(&bus, Family::SeaBotix, forward(-60)).unwrap().decoded.status;
        let Status::SeaBotix(SeaBotixStatus { speed, .. }) = status else {
            panic!("wrong family")
        };
        assert_eq!(speed.step(), -60);
    }

    #[test]
    fn a_missing_thruster_is_a_nack_on_the_order() {
        let (bus, ..) = bus_with(Family::Legacy);
        let error = poll(&bus, Family::SeaBotix, Order::STOP).unwrap_err();
        assert_eq!(
            error,
            PollError::Order(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address))
        );
        assert_eq!(bus.stats().transfers, 1, "no read after a failed order");
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
        let decoded = block_on(poll_thruster(&mut Odd, Family::Legacy, Order::STOP, None))
            .unwrap()
            .decoded;
        assert_eq!(decoded.status.faults(), Faults::WATER);
        assert_eq!(decoded.warning, Some(tmc_proto::FieldWarning::MaxPower(0x00)));
    }

    #[test]
    fn a_corrupted_status_is_a_decode_error() {
        let (bus, _, id) = bus_with(Family::SeaBotix);
        // A noisy line flips a bit of every byte the thruster sends.
        bus.tamper(
            id,
            Tamper {
                read_xor: 0x01,
                ..Tamper::NONE
            },
        );
        let error = poll(&bus, Family::SeaBotix, Order::STOP).unwrap_err();
        assert!(matches!(
            error,
            PollError::Decode(DecodeError::MessageType {
                expected: 0x53,
                actual: 0x52
            })
        ));
        assert!(error.delivered(), "the order went through; only the status is lost");
    }

    #[test]
    fn a_controller_that_sends_the_six_byte_form_is_read() {
        for family in Family::ALL {
            let (bus, _, id) = bus_with(family);
            // The MT taken as the address byte: the frame starts at STATUS, and the line reads 0xFF after it.
            fn implied(bytes: &mut [u8]) {
                bytes.rotate_left(1);
                if let Some(last) = bytes.last_mut() {
                    *last = 0xFF;
                }
            }
            bus.tamper(
                id,
                Tamper {
                    rewrite_read: Some(implied),
                    ..Tamper::NONE
                },
            );
            for last in [None, Some(StatusForm::ImpliedType)] {
                let polled = poll_after(&bus, family, forward(30), last).unwrap();
                assert_eq!(polled.form, StatusForm::ImpliedType, "{family:?}");
                assert_eq!(polled.decoded.warning, None);
                assert_eq!(polled.decoded.status.family(), family);
            }
            // Not from a thruster last read in full: there it is a damaged frame.
            let error = poll_after(&bus, family, forward(30), Some(StatusForm::Full)).unwrap_err();
            assert!(matches!(error, PollError::Decode(_)), "{error:?}");
        }
    }
}
