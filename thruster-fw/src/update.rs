//! The field update's receiver: the thruster's side of tmc-proto's extension ([`tmc_proto::ext`]), with which the
//! master writes a signed image into the DFU partition over the thrusters' bus.
//!
//! The I2C task hands each valid extension command to `update_task` (through [`Shared`]) and answers the next
//! read with the reply kept in [`Replies`](crate::shared::Replies): "busy" until this task has carried the command out. The task owns the
//! DFU flash (blocking NOR flash: on the G431 an erase or a write holds the CPU whatever the API, and blocking
//! calls keep the receiver small) and the [`Updater`] port, and carries out one command at a time: erase a DFU
//! page, write a chunk (inside the payload, aligned to the flash's 8-byte write unit, a short last chunk padded
//! with 0xFF), read back CRCs, check the payload's information record (its family, a format that names the key
//! for the next update, no older version unless signed as a rollback, no lower security counter) and hand the
//! payload's ticket (length and signature) to the port, which marks it for the bootloader, and reset on the
//! master's word. The signature is the bootloader's to check (lbv-boot checks every image before it swaps it in,
//! with the running image's key): one that does not check comes back as the bootloader's verdict in the next
//! `Version`, the old image still running.
//!
//! Everything but `Version` is refused unless the master has ordered zero speed and the duty is zero: a page
//! erase stalls the G431's CPU, commutation included, for tens of milliseconds (one flash bank, the code runs
//! from it). `Finish` looks at the motor and writes the bootloader's state in one synchronous step, with no await
//! between, so no order can slip in between the look and the erase. An update under way is dropped as soon as the master orders a non-zero speed, even if it orders zero
//! again before its next command. Nothing here erases or writes outside the DFU partition's payload, and nothing
//! panics on a command: every refusal is a reply with its own code ([`Refusal`]) and changes nothing.

use embassy_boot::{AlignedBuffer, BlockingFirmwareState, State};
use embassy_futures::yield_now;
use embassy_time::{Duration, with_timeout};
use embedded_storage::nor_flash::{ErrorType, NorFlash, NorFlashErrorKind, ReadNorFlash};
use g431_hw::memory::{IMAGE_INFO_OFFSET, THRUSTER_PARTITIONS};
use tmc_proto::Family;
use tmc_proto::ext::{
    Command, CommandFrame, Crc32, INFO_LEN, MAX_CHUNK, PAGE_LEN, PROTOCOL_VERSION, RECORD_LEN, Refusal, Reply,
    ReplyBody, WRITE_UNIT,
};
use update_image::{
    INFO_FORMAT, ImageInfo, Refusal as ImageRefusal, SLOTS, Slots, TICKET_OFFSET, Target, Ticket, VERDICT_OFFSET,
    Verdict, check_upgrade,
};

use crate::drive::Duty;
use crate::ports::{MarkError, Updater};
use crate::shared::Shared;

/// The longest payload: the ACTIVE partition the bootloader swaps it into.
pub(crate) const MAX_PAYLOAD: u32 = THRUSTER_PARTITIONS.active.length;

/// Where a payload's information record starts (update-image's `ImageInfo`, just past the vector table).
pub(crate) const INFO_OFFSET: u32 = IMAGE_INFO_OFFSET;

/// A payload must be long enough to hold its information record and the key after it.
const INFO_END: u32 = update_image::MIN_PAYLOAD;

/// How long a reboot waits for the master to read its reply before the reset.
pub(crate) const REBOOT_GRACE: Duration = Duration::from_millis(100);

/// Hand a payload to the bootloader: erase the record's ticket page and write `ticket` there (read back), then mark
/// the state for the swap with embassy-boot's own `mark_updated`, and read the mark back (the G4's flash drivers
/// can answer Ok for an erase or program that failed). Refused while the running image is on trial, as embassy-boot
/// refuses. `ticket_page` is the record's first page (g431-hw's `Partitions::ticket`), `state` embassy-boot's state
/// partition.
pub fn mark_for_swap<T: NorFlash, S: NorFlash>(
    ticket_page: &mut T,
    state: &mut S,
    ticket: &Ticket,
) -> Result<(), MarkError> {
    let mut word = AlignedBuffer([0; WRITE_UNIT as usize]);
    let mut boot = BlockingFirmwareState::new(state, &mut word.0);
    if boot.get_state().map_err(|_| MarkError::Flash)? == State::Swap {
        return Err(MarkError::OnTrial);
    }
    let bytes = ticket.to_bytes();
    let flash = |_| MarkError::Flash;
    ticket_page.erase(0, PAGE_LEN).map_err(flash)?;
    ticket_page.write(TICKET_OFFSET, &bytes).map_err(flash)?;
    let mut back = [0; update_image::TICKET_LEN];
    ticket_page.read(TICKET_OFFSET, &mut back).map_err(flash)?;
    if back != bytes {
        return Err(MarkError::Flash);
    }
    boot.mark_updated().map_err(|_| MarkError::Flash)?;
    match boot.get_state() {
        Ok(State::Swap) => Ok(()),
        _ => Err(MarkError::Flash),
    }
}

/// The bootloader's verdict in the record's ticket page, if it left one.
pub fn verdict_in<T: NorFlash>(ticket_page: &mut T) -> Option<Verdict> {
    let mut slots = [0; 8 * SLOTS];
    ticket_page.read(VERDICT_OFFSET, &mut slots).ok()?;
    Verdict::from_slots(&Slots(slots))
}

/// No update: a controller built without a DFU partition (the emulated Cortex-M4 and the motor-less tests): a
/// flash of no capacity and an updater that marks nothing, so every command but `Version` is refused.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoUpdate;

impl Updater for NoUpdate {
    fn running_info(&mut self) -> [u8; INFO_LEN] {
        [0xFF; INFO_LEN]
    }

    fn checks_signatures(&self) -> bool {
        false
    }

    fn mark_updated(&mut self, _: &Ticket) -> Result<(), MarkError> {
        Err(MarkError::Unavailable)
    }

    fn verdict(&mut self) -> Option<Verdict> {
        None
    }

    fn reboot(&mut self) {}

    fn post_mortem(&self) -> Option<[u8; RECORD_LEN]> {
        None
    }
}

impl ErrorType for NoUpdate {
    type Error = NorFlashErrorKind;
}

impl ReadNorFlash for NoUpdate {
    const READ_SIZE: usize = 1;

    fn read(&mut self, _: u32, _: &mut [u8]) -> Result<(), Self::Error> {
        Err(NorFlashErrorKind::OutOfBounds)
    }

    fn capacity(&self) -> usize {
        0
    }
}

impl NorFlash for NoUpdate {
    const WRITE_SIZE: usize = WRITE_UNIT as usize;
    const ERASE_SIZE: usize = PAGE_LEN as usize;

    fn erase(&mut self, _: u32, _: u32) -> Result<(), Self::Error> {
        Err(NorFlashErrorKind::OutOfBounds)
    }

    fn write(&mut self, _: u32, _: &[u8]) -> Result<(), Self::Error> {
        Err(NorFlashErrorKind::OutOfBounds)
    }
}

/// The thruster family an information record names (`Ok(None)`: the master's), or a refusal for bytes that are no
/// record (update-image's `ImageInfo`).
pub(crate) fn info_family(info: &[u8; INFO_LEN]) -> Result<Option<Family>, Refusal> {
    ImageInfo::parse(info)
        .map(|info| info.target.family())
        .map_err(|_| Refusal::NoImageInfo)
}

/// How the motor stands when a command is carried out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Motion {
    /// The last order is zero speed (or none came) and the duty is zero.
    pub(crate) at_rest: bool,
    /// Non-zero orders received so far (wrapping): a change since `Begin` drops the update.
    pub(crate) turning_orders: u32,
}

impl Motion {
    /// The link's last order and the duty as `shared` holds them now.
    pub(crate) fn of(shared: &Shared) -> Motion {
        let link = shared.link.try_get();
        let duty = shared.duty.try_get().unwrap_or(Duty::ZERO);
        Motion {
            at_rest: link.is_none_or(|link| link.order.speed.is_zero()) && duty == Duty::ZERO,
            turning_orders: link.map_or(0, |link| link.orders.wrapping_sub(link.zero_orders)),
        }
    }
}

/// An update under way.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Session {
    payload_len: u32,
    /// [`Motion::turning_orders`] at `Begin`.
    turning_orders: u32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stage {
    Idle,
    Begun(Session),
    /// Marked for the bootloader: only a reboot now.
    Finished,
}

/// What a command's reply is, and whether to reset once it has been read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Outcome {
    /// The reply.
    pub(crate) reply: Reply,
    /// Reset after it.
    pub(crate) reboot: bool,
}

/// The receiver's state: whether an update is under way, and for which payload.
#[derive(Debug, Clone)]
pub(crate) struct Receiver {
    family: Family,
    stage: Stage,
}

impl Receiver {
    /// A thruster of `family`, no update under way (as after any reset).
    pub(crate) fn new(family: Family) -> Self {
        Self {
            family,
            stage: Stage::Idle,
        }
    }

    /// The payload length of the update under way, if any.
    #[cfg(test)]
    pub(crate) fn begun(&self) -> Option<u32> {
        match self.stage {
            Stage::Begun(session) => Some(session.payload_len),
            _ => None,
        }
    }

    /// Whether an update is finished and marked for the bootloader.
    pub(crate) fn finished(&self) -> bool {
        self.stage == Stage::Finished
    }

    /// Carry out one command with the motor as `motion` says.
    pub(crate) async fn handle<D: NorFlash, U: Updater>(
        &mut self,
        frame: CommandFrame,
        motion: Motion,
        on_trial: bool,
        dfu: &mut D,
        updater: &mut U,
    ) -> Outcome {
        let (seq, command) = (frame.seq, frame.command.kind());
        let result = match self.prepare(&frame.command, motion, on_trial, dfu, updater) {
            Next::Reply(result) => result,
            Next::Crc { offset, len } => {
                crc_of(dfu, offset, len)
                    .await
                    .map(|crc| ReplyBody::Check { offset, len, crc })
            }
        };
        let reboot = matches!(result, Ok(ReplyBody::Reboot));
        let reply = match result {
            Ok(body) => Reply::Done { seq, body },
            Err(refusal) => Reply::Refused { seq, command, refusal },
        };
        Outcome { reply, reboot }
    }

    /// The session a command needs.
    fn session(&self) -> Result<Session, Refusal> {
        match self.stage {
            Stage::Begun(session) => Ok(session),
            Stage::Idle => Err(Refusal::NotBegun),
            Stage::Finished => Err(Refusal::Finished),
        }
    }

    /// Everything of a command that needs no waiting: its checks, and the flash work (which blocks anyway). What is
    /// left for [`Receiver::handle`] to wait for is a CRC over a long range, which lets the other tasks run
    /// between chunks.
    // Out of line: a plain function beside the update task's poll, smaller as built.
    #[inline(never)]
    fn prepare<D: NorFlash, U: Updater>(
        &mut self,
        command: &Command,
        motion: Motion,
        on_trial: bool,
        dfu: &mut D,
        updater: &mut U,
    ) -> Next {
        if let Stage::Begun(session) = self.stage
            && session.turning_orders != motion.turning_orders
        {
            warn!("update dropped: the master ordered a non-zero speed");
            self.stage = Stage::Idle;
        }
        // Only `Version` and `PostMortem` are answered whatever the motor does: the rest may touch the flash.
        if !motion.at_rest && !matches!(command, Command::Version | Command::PostMortem { .. }) {
            return Next::Reply(Err(Refusal::Driving));
        }
        Next::Reply(match *command {
            Command::Version => Ok(ReplyBody::Version {
                protocol: PROTOCOL_VERSION,
                on_trial,
                checks_signatures: updater.checks_signatures(),
                marked: self.finished(),
                dev_key: update_image::UPDATE_KEY_IS_DEV,
                verdict: updater.verdict().map_or(0, Verdict::code),
                max_payload: MAX_PAYLOAD,
                info: updater.running_info(),
            }),
            Command::Begin { payload_len, target } => self.begin(payload_len, target, motion, on_trial, dfu),
            Command::Erase { page } => self.session().and_then(|session| {
                let from = u32::from(page).saturating_mul(PAGE_LEN);
                let to = from.saturating_add(PAGE_LEN);
                if from >= session.payload_len || to as usize > dfu.capacity() {
                    return Err(Refusal::OutOfRange);
                }
                dfu.erase(from, to).map_err(|_| Refusal::FlashError)?;
                Ok(ReplyBody::Erase { page })
            }),
            Command::Write { offset, data } => self
                .session()
                .and_then(|session| write_chunk(dfu, session, offset, data.as_slice())),
            Command::Check { offset, len } => match self.session() {
                Ok(session) if u64::from(offset) + u64::from(len) > u64::from(session.payload_len) => {
                    Err(Refusal::OutOfRange)
                }
                Ok(_) => return Next::Crc { offset, len },
                Err(refusal) => Err(refusal),
            },
            // The motor was seen at rest just above, and nothing here awaits: the look and the state's erase are
            // one step.
            Command::Finish { payload_len, signature } => self.finishable(payload_len, dfu, updater).and_then(|()| {
                updater
                    .mark_updated(&Ticket { payload_len, signature })
                    .map_err(|error| match error {
                        MarkError::OnTrial => Refusal::OnTrial,
                        MarkError::Flash => Refusal::FlashError,
                        MarkError::Unavailable => Refusal::NoSignatureCheck,
                    })?;
                info!("update finished: marked for the bootloader");
                self.stage = Stage::Finished;
                Ok(ReplyBody::Finish { payload_len })
            }),
            Command::Reboot => match self.stage {
                Stage::Finished => Ok(ReplyBody::Reboot),
                _ => Err(Refusal::NotFinished),
            },
            Command::PostMortem { offset } => post_mortem_part(updater.post_mortem().as_ref(), offset),
        })
    }

    fn begin<D: NorFlash>(
        &mut self,
        payload_len: u32,
        target: u8,
        motion: Motion,
        on_trial: bool,
        dfu: &D,
    ) -> Result<ReplyBody, Refusal> {
        if self.stage == Stage::Finished {
            return Err(Refusal::Finished);
        }
        if on_trial {
            return Err(Refusal::OnTrial);
        }
        if target != Target::thruster(self.family).to_byte() {
            return Err(Refusal::WrongFamily);
        }
        if !payload_len.is_multiple_of(WRITE_UNIT) {
            return Err(Refusal::Unaligned);
        }
        // embassy-boot's verify asserts that the payload fits the DFU partition: refused here instead.
        if payload_len > MAX_PAYLOAD || payload_len as usize > dfu.capacity() {
            return Err(Refusal::TooLarge);
        }
        if payload_len < INFO_END {
            return Err(Refusal::Truncated);
        }
        info!("update begun: {=u32} bytes", payload_len);
        self.stage = Stage::Begun(Session {
            payload_len,
            turning_orders: motion.turning_orders,
        });
        Ok(ReplyBody::Begin { payload_len })
    }

    /// Whether the payload is one to hand the bootloader: the length begun with, this family's record, of a format
    /// that names the key for the next update, and no step back from the running image (its version unless signed
    /// as a rollback, its security counter). The bootloader checks all of it again, and the signature.
    fn finishable<D: NorFlash, U: Updater>(
        &self,
        payload_len: u32,
        dfu: &mut D,
        updater: &mut U,
    ) -> Result<(), Refusal> {
        let session = self.session()?;
        if payload_len != session.payload_len {
            return Err(Refusal::Truncated);
        }
        let mut info = [0; INFO_LEN];
        dfu.read(INFO_OFFSET, &mut info).map_err(|_| Refusal::FlashError)?;
        if info_family(&info)? != Some(self.family) {
            return Err(Refusal::WrongFamily);
        }
        let image = ImageInfo::parse(&info).map_err(|_| Refusal::NoImageInfo)?;
        if image.format < INFO_FORMAT {
            return Err(Refusal::NoKey);
        }
        let running = ImageInfo::parse(&updater.running_info()).ok();
        let floor = running.map_or(0, |running| running.security_counter);
        check_upgrade(&image, running.as_ref(), floor).map_err(|refusal| match refusal {
            ImageRefusal::Older { .. } => Refusal::Older,
            _ => Refusal::CounterBelow,
        })
    }
}

/// What is left of a command once [`Receiver::prepare`] is done with it.
enum Next {
    /// Its reply.
    Reply(Result<ReplyBody, Refusal>),
    /// A CRC of the DFU partition to compute.
    Crc { offset: u32, len: u32 },
}

/// Write a chunk at `offset` in erased flash, padded with 0xFF to the write unit, and read it back. A chunk the
/// flash already holds is not written again, so that a master that lost a reply can send the command again.
// Out of line, as `Receiver::prepare`.
#[inline(never)]
/// The part of `record` (none: a record of length 0) from `offset`, zero past its end; an offset past the end is
/// refused.
fn post_mortem_part(record: Option<&[u8; RECORD_LEN]>, offset: u8) -> Result<ReplyBody, Refusal> {
    let held: &[u8] = record.map_or(&[], |record| record);
    let rest = held.get(usize::from(offset)..).ok_or(Refusal::OutOfRange)?;
    let mut data = [0; MAX_CHUNK];
    for (to, from) in data.iter_mut().zip(rest) {
        *to = *from;
    }
    Ok(ReplyBody::PostMortem {
        len: held.len() as u8,
        offset,
        data,
    })
}

fn write_chunk<D: NorFlash>(dfu: &mut D, session: Session, offset: u32, data: &[u8]) -> Result<ReplyBody, Refusal> {
    if !offset.is_multiple_of(WRITE_UNIT) {
        return Err(Refusal::Unaligned);
    }
    if u64::from(offset) + data.len() as u64 > u64::from(session.payload_len) {
        return Err(Refusal::OutOfRange);
    }
    // The payload's length is a multiple of the write unit, so the padding stays inside it.
    let padded = data.len().next_multiple_of(WRITE_UNIT as usize);
    let mut chunk = [0xFF; MAX_CHUNK];
    let mut held = [0; MAX_CHUNK];
    let (Some(to_write), Some(held)) = (chunk.get_mut(..padded), held.get_mut(..padded)) else {
        return Err(Refusal::OutOfRange);
    };
    if let Some(start) = to_write.get_mut(..data.len()) {
        start.copy_from_slice(data);
    }
    let flash = |_| Refusal::FlashError;
    dfu.read(offset, held).map_err(flash)?;
    if held != to_write {
        if held.iter().any(|byte| *byte != 0xFF) {
            return Err(Refusal::NotErased);
        }
        dfu.write(offset, to_write).map_err(flash)?;
        dfu.read(offset, held).map_err(flash)?;
    }
    let crc = tmc_proto::ext::crc32(held.get(..data.len()).unwrap_or(held));
    Ok(ReplyBody::Write {
        offset,
        len: data.len() as u8,
        crc,
    })
}

/// The CRC of `len` bytes of the DFU partition from `offset`, read a chunk at a time, letting the other tasks run
/// between chunks (the whole payload takes some milliseconds of CPU).
async fn crc_of<D: NorFlash>(dfu: &mut D, offset: u32, len: u32) -> Result<u32, Refusal> {
    let mut crc = Crc32::new();
    let mut buffer = [0; MAX_CHUNK];
    let end = offset.saturating_add(len);
    let mut at = offset;
    while at < end {
        let n = (end - at).min(MAX_CHUNK as u32);
        let Some(piece) = buffer.get_mut(..n as usize) else {
            break;
        };
        dfu.read(at, piece).map_err(|_| Refusal::FlashError)?;
        crc = crc.update(piece);
        at += n;
        yield_now().await;
    }
    Ok(crc.finish())
}

/// The update task: carries out each extension command the I2C task hands over and leaves its reply for the next
/// read; resets (through `updater`) once the master has read the reply to a `Reboot`, or after [`REBOOT_GRACE`].
pub(crate) async fn update_task<D: NorFlash, U: Updater>(
    dfu: &mut D,
    updater: &mut U,
    family: Family,
    shared: &Shared,
) -> ! {
    let mut receiver = Receiver::new(family);
    let replies = &shared.replies;
    loop {
        let frame = replies.commands.wait().await;
        let motion = Motion::of(shared);
        let outcome = receiver.handle(frame, motion, replies.on_trial(), dfu, updater).await;
        replies.read.reset();
        replies.complete(outcome.reply);
        if outcome.reboot {
            // The master reads the reply first; one that never does holds the reset back only this long.
            let _ = with_timeout(REBOOT_GRACE, replies.read.wait()).await;
            info!("rebooting into the new image");
            updater.reboot();
        }
    }
}

#[cfg(test)]
mod tests;
