//! The I2C slave side of the thruster interface (IDS 6.4.2, 6.6): take orders, answer status reads; and take the
//! field-update extension's commands ([`tmc_proto::ext`]: a write whose first byte is [`EXT_MT`]), answering the
//! read after one with its reply instead of the status.

use tmc_proto::ext::{self, CommandFrame, EXT_MT, FrameBytes, FrameError};
use tmc_proto::{DecodeError, Family, Order, StatusFrame};

use crate::ports::{I2cTarget, Request};

/// Writes are taken into a buffer one byte longer than the longest frame (an extension command), so an over-long
/// write is seen and rejected instead of being cut down to a plausible frame.
const WRITE_BUFFER_LEN: usize = ext::MAX_FRAME_LEN + 1;

/// Orders discarded since power-up, by reason (IDS 6.6.1: a bad message is discarded whole).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct OrderErrors {
    /// Writes that were not 4 bytes long.
    pub(crate) length: u32,
    /// Writes whose first byte was not this family's order type.
    pub(crate) message_type: u32,
    /// Writes whose checksum did not match.
    pub(crate) checksum: u32,
    /// Orders whose SPEED byte was outside 0x19..=0xE6.
    pub(crate) speed_range: u32,
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
    pub(crate) fn total(&self) -> u32 {
        self.length
            .saturating_add(self.message_type)
            .saturating_add(self.checksum)
            .saturating_add(self.speed_range)
    }
}

/// Extension commands discarded since power-up, by reason: a bad frame is discarded whole and changes nothing,
/// as a bad order.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct CommandErrors {
    /// Frames shorter or longer than any command, or not their command's length.
    pub(crate) length: u32,
    /// Frames whose GUARD byte was wrong.
    pub(crate) guard: u32,
    /// Frames whose CRC did not match.
    pub(crate) crc: u32,
    /// Frames of a command this controller does not know.
    pub(crate) command: u32,
    /// Writes whose chunk length was out of range.
    pub(crate) field: u32,
}

impl CommandErrors {
    fn count(&mut self, error: FrameError) {
        let counter = match error {
            FrameError::Short { .. } | FrameError::TooLong { .. } | FrameError::Length { .. } => &mut self.length,
            FrameError::Guard { .. } => &mut self.guard,
            FrameError::Crc { .. } => &mut self.crc,
            // Only a frame opening with EXT_MT is decoded as a command; a reply's type would be a stray one.
            FrameError::UnknownCommand(_) | FrameError::MessageType { .. } => &mut self.command,
            FrameError::ChunkLength(_) | FrameError::UnknownResult(_) => &mut self.field,
        };
        *counter = counter.saturating_add(1);
    }

    /// All discarded commands.
    pub(crate) fn total(&self) -> u32 {
        self.length
            .saturating_add(self.guard)
            .saturating_add(self.crc)
            .saturating_add(self.command)
            .saturating_add(self.field)
    }
}

/// The link to the master as this controller keeps it: its family, the last valid order and what was received.
#[derive(Debug, Clone)]
pub struct MasterLink {
    family: Family,
    order: Order,
    orders: u32,
    zero_orders: u32,
    errors: OrderErrors,
    commands: u32,
    command_errors: CommandErrors,
}

impl MasterLink {
    /// A controller of `family`, stopped until the first valid order.
    pub fn new(family: Family) -> Self {
        Self {
            family,
            order: Order::STOP,
            orders: 0,
            zero_orders: 0,
            errors: OrderErrors::default(),
            commands: 0,
            command_errors: CommandErrors::default(),
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

    /// Valid orders received (wrapping).
    pub fn orders(&self) -> u32 {
        self.orders
    }

    /// Valid zero-speed orders received (wrapping).
    pub fn zero_orders(&self) -> u32 {
        self.zero_orders
    }

    /// Orders discarded so far.
    pub(crate) fn errors(&self) -> OrderErrors {
        self.errors
    }

    /// Valid extension commands received (wrapping).
    #[cfg(test)]
    pub(crate) fn commands(&self) -> u32 {
        self.commands
    }

    /// Extension commands discarded so far.
    pub(crate) fn command_errors(&self) -> CommandErrors {
        self.command_errors
    }

    /// Take an extension command from the master (a write opening with [`EXT_MT`]); a bad one is counted and
    /// changes nothing else. The order stands either way.
    // Out of line: inlined into the I2C task's poll it costs more flash, as built.
    #[inline(never)]
    pub(crate) fn accept_command(&mut self, bytes: &[u8]) -> Result<CommandFrame, FrameError> {
        CommandFrame::decode(bytes)
            .inspect(|_| self.commands = self.commands.wrapping_add(1))
            .inspect_err(|error| self.command_errors.count(*error))
    }

    /// Take a write from the master: a valid order replaces the last one; anything else is counted and changes
    /// nothing else.
    pub fn accept(&mut self, bytes: &[u8]) -> Result<Order, DecodeError> {
        match Order::decode(self.family, bytes) {
            Ok(order) => {
                self.order = order;
                self.orders = self.orders.wrapping_add(1);
                if order.speed.is_zero() {
                    self.zero_orders = self.zero_orders.wrapping_add(1);
                }
                Ok(order)
            }
            Err(error) => {
                self.errors.count(error);
                Err(error)
            }
        }
    }
}

/// What one transfer did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) enum ServeEvent {
    /// A valid order was taken.
    Order(Order),
    /// A write was discarded.
    Rejected(DecodeError),
    /// The status frame was sent.
    StatusSent,
    /// A valid extension command was taken.
    Command(CommandFrame),
    /// An extension command was discarded.
    CommandRejected(FrameError),
    /// The reply to an extension command was sent.
    ReplySent,
}

/// What a read is answered with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Answer {
    /// The status (IDS 8.4).
    Status(StatusFrame),
    /// The reply to the last extension command.
    Reply(FrameBytes),
}

impl From<StatusFrame> for Answer {
    fn from(status: StatusFrame) -> Self {
        Answer::Status(status)
    }
}

impl Answer {
    fn as_bytes(&self) -> &[u8] {
        match self {
            Answer::Status(status) => status.as_bytes(),
            Answer::Reply(reply) => reply.as_bytes(),
        }
    }
}

/// Serve one transfer the master started with `request`: take the order or the extension command, or send what
/// `answer` gives (the status frame, or the reply to an extension command), which must be ready at once (SCL is
/// stretched until it is sent).
pub(crate) async fn serve<T: I2cTarget, A: Into<Answer>>(
    target: &mut T,
    link: &mut MasterLink,
    request: Request,
    answer: impl FnOnce() -> A,
) -> Result<ServeEvent, T::Error> {
    match request {
        Request::Write => {
            let mut buffer = [0; WRITE_BUFFER_LEN];
            let received = target.respond_to_write(&mut buffer).await?;
            // A peripheral never reports more than the buffer holds; if one did, the whole buffer is judged.
            let bytes = buffer.get(..received).unwrap_or(&buffer);
            // No IDS message opens with EXT_MT (it is neither order type), so IDS writes take the path they
            // always took.
            Ok(if bytes.first() == Some(&EXT_MT) {
                match link.accept_command(bytes) {
                    Ok(frame) => ServeEvent::Command(frame),
                    Err(error) => ServeEvent::CommandRejected(error),
                }
            } else {
                match link.accept(bytes) {
                    Ok(order) => ServeEvent::Order(order),
                    Err(error) => ServeEvent::Rejected(error),
                }
            })
        }
        Request::Read => {
            let answer = answer().into();
            target.respond_to_read(answer.as_bytes()).await?;
            Ok(match answer {
                Answer::Status(_) => ServeEvent::StatusSent,
                Answer::Reply(_) => ServeEvent::ReplySent,
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embassy_futures::block_on;
    use std::collections::VecDeque;
    use tmc_proto::{
        Faults, LegacyRevision, LegacyStatus, MaxPower, MotorKind, SeaBotixStatus, Speed, Status, checksum,
    };

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

        fn reset(&mut self) {}
    }

    /// A status frame with a recognisable speed, standing in for the one the control side keeps ready.
    fn frame(family: Family) -> StatusFrame {
        let status = match family {
            Family::SeaBotix => Status::SeaBotix(SeaBotixStatus {
                revision: 0,
                motor: MotorKind::Brushless,
                current_limited: true,
                faults: Faults::WATER,
                current_deciamps: 12,
                speed: Speed::new(33).unwrap(),
                temperature_c: 41,
            }),
            Family::Legacy => Status::Legacy(LegacyStatus {
                revision: LegacyRevision::AVEOX_BRUSHLESS,
                faults: Faults::WATER,
                max_power: MaxPower::Current { deciamps: 12 },
            }),
        };
        status.encode()
    }

    fn run(link: &mut MasterLink, script: Vec<Transfer>) -> (Vec<ServeEvent>, Vec<Vec<u8>>) {
        let mut master = ScriptedMaster {
            script: script.into(),
            ..Default::default()
        };
        let mut events = Vec::new();
        let family = link.family();
        while let Ok(request) = block_on(master.listen()) {
            events.push(block_on(serve(&mut master, link, request, || frame(family))).unwrap());
        }
        (events, master.replies)
    }

    fn order(family: Family, step: i8) -> Vec<u8> {
        Order::new(Speed::new(step).unwrap()).encode(family).to_vec()
    }

    #[test]
    fn starts_stopped_and_answers_reads_with_the_frame_kept_ready() {
        for family in Family::ALL {
            let mut link = MasterLink::new(family);
            let (events, replies) = run(&mut link, vec![Transfer::Read]);
            assert_eq!(events, [ServeEvent::StatusSent]);
            assert_eq!(replies, [frame(family).as_bytes().to_vec()]);
            assert_eq!(replies[0].len(), family.status_len());
            assert_eq!(link.order(), Order::STOP);
            assert_eq!(link.orders(), 0);
        }
    }

    #[test]
    fn a_valid_order_is_taken_and_counted() {
        let mut link = MasterLink::new(Family::SeaBotix);
        let script = vec![
            Transfer::Write(order(Family::SeaBotix, 40)),
            Transfer::Write(order(Family::SeaBotix, 0)),
            Transfer::Write(order(Family::SeaBotix, -7)),
        ];
        let (events, _) = run(&mut link, script);
        assert_eq!(events[0], ServeEvent::Order(Order::new(Speed::new(40).unwrap())));
        assert_eq!(link.order().speed.step(), -7);
        assert_eq!((link.orders(), link.zero_orders()), (3, 1));
    }

    #[test]
    fn a_zero_order_sent_as_0x7f_counts_as_zero() {
        let mut link = MasterLink::new(Family::Legacy);
        run(
            &mut link,
            vec![Transfer::Write(vec![
                0x54,
                0x7F,
                100,
                0x54u8.wrapping_add(0x7F).wrapping_add(100),
            ])],
        );
        assert_eq!((link.orders(), link.zero_orders()), (1, 1));
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
        let mut link = MasterLink::new(family);
        let (events, replies) = run(&mut link, script);

        assert_eq!(events.len(), 8);
        assert!(
            events[1..7]
                .iter()
                .all(|event| matches!(event, ServeEvent::Rejected(_)))
        );
        assert_eq!(link.order().speed.step(), 20, "the last valid order stands");
        assert_eq!(link.orders(), 1);
        assert_eq!(replies.len(), 1, "the read after the bad writes is still answered");
        assert_eq!(
            link.errors(),
            OrderErrors {
                length: 3,
                message_type: 1,
                checksum: 1,
                speed_range: 1
            },
            "12 zero bytes are rejected on length"
        );
        assert_eq!(link.errors().total(), 6);
    }

    #[test]
    fn extension_commands_are_taken_apart_from_orders_and_bad_ones_counted() {
        use tmc_proto::ext::{Command, CommandFrame, EXT_MT, Reply, crc32, guard};
        let family = Family::SeaBotix;
        let erase = CommandFrame {
            seq: 3,
            command: Command::Erase { page: 2 },
        };
        let good = erase.encode().as_bytes().to_vec();
        let mut bad_crc = good.clone();
        *bad_crc.last_mut().unwrap() ^= 0x10;
        let mut bad_guard = good.clone();
        bad_guard[3] = bad_guard[3].wrapping_add(1);
        let mut unknown = vec![EXT_MT, 0x33, 1, guard(EXT_MT, 0x33, 1)];
        unknown.extend(crc32(&unknown).to_le_bytes());
        // Longer than any frame: cut to the buffer, and still rejected.
        let mut too_long = good.clone();
        too_long.resize(100, 0);
        let script = vec![
            Transfer::Write(order(family, 20)),
            Transfer::Write(good.clone()),
            Transfer::Write(bad_crc),
            Transfer::Write(bad_guard),
            Transfer::Write(unknown),
            Transfer::Write(too_long),
            Transfer::Write(good[..7].to_vec()),
        ];
        let mut link = MasterLink::new(family);
        let (events, _) = run(&mut link, script);
        assert_eq!(events[1], ServeEvent::Command(erase));
        assert!(
            events[2..]
                .iter()
                .all(|event| matches!(event, ServeEvent::CommandRejected(_)))
        );
        assert_eq!(link.commands(), 1);
        assert_eq!(
            link.command_errors(),
            CommandErrors {
                length: 2,
                guard: 1,
                crc: 1,
                command: 1,
                field: 0
            }
        );
        assert_eq!(link.command_errors().total(), 5);
        // The order stands and no order error was counted.
        assert_eq!((link.order().speed.step(), link.orders()), (20, 1));
        assert_eq!(link.errors().total(), 0);

        // A read answered with a reply says so.
        let reply = Reply::Busy {
            seq: 3,
            command: erase.command.kind(),
        }
        .encode();
        let mut master = ScriptedMaster {
            script: vec![Transfer::Read].into(),
            ..Default::default()
        };
        let request = block_on(master.listen()).unwrap();
        let event = block_on(serve(&mut master, &mut link, request, || Answer::Reply(reply))).unwrap();
        assert_eq!(event, ServeEvent::ReplySent);
        assert_eq!(master.replies, [reply.as_bytes().to_vec()]);
    }

    #[test]
    fn the_latest_valid_order_wins() {
        let family = Family::Legacy;
        let mut link = MasterLink::new(family);
        let script = (1..=5).map(|step| Transfer::Write(order(family, -step * 20))).collect();
        run(&mut link, script);
        assert_eq!(link.order().speed.step(), -100);
    }
}
