//! The bootloader of the thruster and of the master, hardware-free: what lbv-boot checks before embassy-boot's swap,
//! embassy-boot's decision on a NOR flash laid out as the board's partitions
//! ([`THRUSTER_PARTITIONS`](g431_hw::memory::THRUSTER_PARTITIONS),
//! [`MASTER_PARTITIONS`](g431_hw::memory::MASTER_PARTITIONS)), and what the bootloader does when it fails.
//!
//! embassy-boot keeps the images in two partitions: ACTIVE, the image that runs, and DFU, where the running image
//! writes a new one and marks it updated. At the next reset [`prepare`] swaps the two a page at a time, noting its
//! progress in the state partition after every page, so that a power cut at any point resumes where it stopped. The
//! new image then runs on trial: it marks itself booted, or at the next reset the swap is undone (the old image
//! waits in DFU, one page up). The binding (`main.rs`, `stm32.rs`) runs [`prepare`] on the chip's flash and starts
//! ACTIVE; the host tests run the same function on lbv-sim's flash, with embassy-boot's own updater on the
//! application's side.
//!
//! # What it checks before a swap begins
//!
//! Whatever the application did, an image is swapped in only once the bootloader has checked it, as MCUboot checks
//! its secondary slot ([`judge`]): the application's [`Ticket`] (the payload's length and signature, in the record's
//! first page) is there and its length fits ACTIVE; the payload's image info (format 2) is for the running image's
//! target; it is not older than the running image unless signed as a rollback, and its security counter is not below
//! the one the bootloader keeps ([`check_upgrade`]); DFU holds nothing but erased bytes past the payload in its last
//! page; and the ed25519 signature over SHA-512 of DFU `[0, payload_len)` checks with the key the *running* image
//! embeds (update-image's `KEY_OFFSET`), so the key an image carries decides which files the vehicle takes after it.
//! DFU's pages past the payload are then erased, so nothing unsigned reaches ACTIVE. An image that fails is not
//! swapped: the bootloader writes its [`Verdict`] beside the ticket, clears the mark, and the old image starts and
//! tells why. The check reads only, so a power cut in it costs nothing: the next start checks again.
//!
//! # The security counter
//!
//! The highest security counter of a confirmed image is kept in the record's counter journal, two pages of
//! [`checked_word`] entries written in turn: at every start where the running image is confirmed (embassy-boot's
//! state is not on trial) and its counter is above the stored one, the bootloader raises it. An entry a power cut
//! tears never reads as one, and the page with the highest entry is never the one erased, so a cut leaves the old
//! value or the new one, never less. It is kept in flash rather than in the G4's one-time-programmable area: OTP
//! double words cannot be erased, so a development board would be held forever to the highest counter it ever ran,
//! and the record's two pages last for hundreds of raises between erases.
//!
//! # An image that confirms and then crashes
//!
//! A confirmed image can still fail where its trial did not look: a master that faults ten seconds after its start
//! confirms at three, then resets by watchdog every ten seconds, and its own upload never finishes. The binding
//! counts the watchdog resets that come early in a run ([`CrashCount`], in a backup register; the image clears it
//! once it has run [`EARLY_WINDOW_SECS`](update_image::EARLY_WINDOW_SECS)), and passes the count to [`prepare`].
//! At the [`EARLY_CRASHES`](update_image::EARLY_CRASHES)th, with the image confirmed, the bootloader puts the
//! image the last swap moved out back into ACTIVE, if DFU still holds exactly the image whose digest
//! it noted before that swap ([`Previous`]) and its security counter is not below the stored one: an update that
//! raised the counter is never undone this way, which is what the counter is for. The restore is embassy-boot's
//! own revert, run on a state written as a finished swap, so a power cut in it resumes as a revert does. The
//! image that then runs finds embassy-boot's state at `Revert` and the count's `restored` flag set, and tells it.
//!
//! The watchdog runs through all of it: the binding starts it before [`prepare`], whose `feed` is called between
//! every flash operation and every chunk hashed.
#![cfg_attr(not(test), no_std)]

use core::cell::RefCell;

use embassy_boot::{AlignedBuffer, BlockingFirmwareState, BootLoader, BootLoaderConfig};
use embassy_embedded_hal::flash::partition::BlockingPartition;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
use g431_hw::memory::{FLASH_ORIGIN, PAGE, Partitions, Span, WRITE_UNIT};
use update_image::{
    DIGEST_LEN, INFO_LEN, INFO_OFFSET, ImageInfo, KEY_LEN, KEY_OFFSET, MIN_PAYLOAD, PREVIOUS_LEN, PREVIOUS_OFFSET,
    Previous, Refusal, Slots, TICKET_LEN, TICKET_OFFSET, Ticket, VERDICT_OFFSET, Verifier, check_upgrade, checked_word,
    read_checked_word,
};

pub use embassy_boot::{BootError, State};
pub use update_image::{CrashCount, Verdict};

#[cfg(test)]
mod tests;

/// The flash, shared by its partitions as embassy-boot shares it: one lock, and nothing else runs meanwhile.
pub type SharedFlash<F> = Mutex<NoopRawMutex, RefCell<F>>;

/// One partition of the shared flash.
pub type Partition<'a, F> = BlockingPartition<'a, NoopRawMutex, F>;

/// How many times [`prepare`] runs before it gives up. Each attempt resumes from the progress the last one
/// recorded, so a transient error costs nothing; an error that stays is not worth waiting for.
pub const ATTEMPTS: u32 = 3;

/// Every copy goes through one page of RAM (on the stack): a page moves with one read and one write, and the
/// check hashes a page at a time.
const BUFFER: usize = PAGE as usize;

/// The erased value of a flash byte.
const ERASED: u8 = 0xFF;

/// embassy-boot's magic for a state marked for the swap (embassy-boot 0.7 `SWAP_MAGIC`, crate-private there; a
/// test reads it back through embassy-boot's own `get_state`).
const SWAP_MAGIC: u8 = 0xF0;

/// What embassy-boot writes over a progress word once its step is done (the complement of the erased value).
const STEP_DONE: u8 = !ERASED;

/// The partition at `span` of the flash, addressed from the flash's start as embassy-stm32's flash driver (and the
/// `__bootloader_*` symbols of the image's memory.x, printed from the same partitions) address it.
pub fn partition<F: NorFlash>(flash: &SharedFlash<F>, span: Span) -> Partition<'_, F> {
    BlockingPartition::new(flash, span.origin - FLASH_ORIGIN, span.length)
}

/// embassy-boot's ACTIVE, DFU and state partitions on `flash`, at the offsets `layout` gives. The bootloader takes
/// them from the constants rather than from the linker's symbols (`BootLoaderConfig::from_linkerfile_blocking`):
/// the same values, but known to the compiler, so embassy-boot's checks of the partitions' sizes fold away instead
/// of staying in the image as panics (g431-hw checks the same rules at build time, `check_partitions`).
pub fn partitions<'a, F: NorFlash>(
    flash: &'a SharedFlash<F>,
    layout: &Partitions,
) -> BootLoaderConfig<Partition<'a, F>, Partition<'a, F>, Partition<'a, F>> {
    BootLoaderConfig {
        active: partition(flash, layout.active),
        dfu: partition(flash, layout.dfu),
        state: partition(flash, layout.state),
    }
}

/// What the bootloader did before it starts ACTIVE.
#[derive(Debug, PartialEq, Eq)]
pub enum Outcome {
    /// embassy-boot prepared ACTIVE at this attempt (1-based): `state` is what it found in the state partition
    /// (`Swap` when it swapped a new image in, and also when it reverted one that never marked itself booted).
    Prepared {
        /// The state embassy-boot read before it acted.
        state: State,
        /// The attempt that succeeded.
        attempt: u32,
    },
    /// An image was marked for the swap and the check refused it: its verdict is written, the mark cleared, and
    /// the image that ran starts again.
    Refused {
        /// Why.
        verdict: Verdict,
        /// The attempt that succeeded.
        attempt: u32,
    },
    /// The confirmed image crashed early [`EARLY_CRASHES`](update_image::EARLY_CRASHES) times in a row, and the
    /// image the last swap moved out is back in ACTIVE.
    Restored {
        /// The attempt that succeeded.
        attempt: u32,
    },
    /// Every attempt failed with a flash error, the last one this: ACTIVE is started as it is.
    Failed(BootError),
}

/// A flash that calls `feed` before every erase and write: the watchdog fed between the operations of a swap
/// (each a few tens of milliseconds at most), and so through the longest of them.
struct Fed<F, W> {
    flash: F,
    feed: W,
}

impl<F: ErrorType, W> ErrorType for Fed<F, W> {
    type Error = F::Error;
}

impl<F: ReadNorFlash, W> ReadNorFlash for Fed<F, W> {
    const READ_SIZE: usize = F::READ_SIZE;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.flash.read(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.flash.capacity()
    }
}

impl<F: NorFlash, W: FnMut()> NorFlash for Fed<F, W> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        (self.feed)();
        self.flash.erase(from, to)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        (self.feed)();
        self.flash.write(offset, bytes)
    }
}

/// Check an update marked for the swap, then run embassy-boot's preparation (swap, resume or revert) on `flash`,
/// laid out as `layout`, up to [`ATTEMPTS`] times; `feed` keeps the watchdog from biting meanwhile. `crashes` is the
/// count of early crashes at this start (the binding's [`CrashCount::at_start`]): when it is due, a confirmed image
/// is undone ([module docs](crate)).
///
/// When every attempt fails, the bootloader starts ACTIVE all the same, and that is the safe choice for a thruster
/// or a master: stopping here leaves it silent with no way back but a debug probe, in the water. An error that stays
/// is not the flash's doing: embassy-boot programs only erased double words, or zeros over its own progress words,
/// which the G4 always takes (RM0440 3.3.7); what remains is a write protection (RM0440 3.5, WRPERR), which
/// neither image sets, and which stops the swap at the first page it protects. A power cut does not end here
/// either: the next start resumes the swap. Should ACTIVE not run, the watchdog the binding starts resets the chip,
/// and the next start tries again.
pub fn prepare<F: NorFlash>(flash: F, layout: &Partitions, crashes: CrashCount, feed: impl FnMut()) -> Outcome {
    let flash = Mutex::new(RefCell::new(Fed { flash, feed }));
    let mut buffer = AlignedBuffer([0; BUFFER]);
    let mut attempt = 1;
    loop {
        match prepare_once(&flash, layout, crashes, &mut buffer.0) {
            Ok(Prepared::State(state)) => return Outcome::Prepared { state, attempt },
            Ok(Prepared::Refused(verdict)) => return Outcome::Refused { verdict, attempt },
            Ok(Prepared::Restored) => return Outcome::Restored { attempt },
            Err(error) if attempt >= ATTEMPTS => return Outcome::Failed(error),
            Err(_) => attempt += 1,
        }
    }
}

/// What one attempt of [`prepare`] did.
enum Prepared {
    /// embassy-boot prepared ACTIVE, having read this state.
    State(State),
    /// The update marked was refused.
    Refused(Verdict),
    /// The previous image is back.
    Restored,
}

/// One attempt of [`prepare`].
fn prepare_once<F: NorFlash, W: FnMut()>(
    flash: &SharedFlash<Fed<F, W>>,
    layout: &Partitions,
    crashes: CrashCount,
    buffer: &mut [u8; BUFFER],
) -> Result<Prepared, BootError> {
    let mut loader = BootLoader::new(partitions(flash, layout));
    let state = loader.read_state(buffer)?;
    let mut active = partition(flash, layout.active);
    if state == State::Boot && crashes.undo_due() && restorable(flash, layout, buffer)? {
        write_swapped(&mut partition(flash, layout.state), layout.active_pages())?;
        loader.prepare_boot(buffer)?;
        return Ok(Prepared::Restored);
    }
    if state != State::Swap {
        raise_counter(flash, layout, &mut active)?;
    } else if !swap_begun(&mut partition(flash, layout.state))? {
        let stored = stored_counter(&mut partition(flash, layout.counter()))?.unwrap_or(0);
        let mut dfu = partition(flash, layout.dfu);
        let verdict = judge(
            &mut dfu,
            &mut active,
            &mut partition(flash, layout.ticket()),
            stored,
            buffer,
            || flash.lock(|flash| (flash.borrow_mut().feed)()),
        );
        match verdict {
            Ok(payload_len) => {
                note_previous(flash, layout, buffer)?;
                erase_past(&mut dfu, payload_len, layout.active.length)?;
            }
            Err(verdict) => {
                refuse(flash, layout, verdict)?;
                return Ok(Prepared::Refused(verdict));
            }
        }
    }
    Ok(Prepared::State(loader.prepare_boot(buffer)?))
}

/// The digest kept of `len` bytes of `span` from `from` ([`Previous`]): the first half of their SHA-512.
fn digest<F: NorFlash, W: FnMut()>(
    flash: &SharedFlash<Fed<F, W>>,
    span: Span,
    from: u32,
    len: u32,
    buffer: &mut [u8; BUFFER],
) -> Result<[u8; DIGEST_LEN], BootError> {
    let mut feed = || flash.lock(|flash| (flash.borrow_mut().feed)());
    let whole = hash(&mut partition(flash, span), from, len, buffer, &mut feed)?;
    Ok(*whole.first_chunk::<DIGEST_LEN>().unwrap_or(&[0; DIGEST_LEN]))
}

/// Before a swap: note the digest of ACTIVE as it stands, the image the swap moves into DFU ([`Previous`]), unless
/// a start before this one noted it already (the entry is not erased). An entry a power cut tore stays torn, and
/// only costs the undo of this image.
fn note_previous<F: NorFlash, W: FnMut()>(
    flash: &SharedFlash<Fed<F, W>>,
    layout: &Partitions,
    buffer: &mut [u8; BUFFER],
) -> Result<(), BootError> {
    let mut ticket_page = partition(flash, layout.ticket());
    let entry = read_array::<PREVIOUS_LEN, _>(&mut ticket_page, PREVIOUS_OFFSET)?;
    if entry.iter().any(|byte| *byte != ERASED) {
        return Ok(());
    }
    let digest = digest(flash, layout.active, 0, layout.active.length, buffer)?;
    ticket_page.write(PREVIOUS_OFFSET, &Previous { digest }.to_bytes())?;
    Ok(())
}

/// Whether the image the last swap moved out can come back: DFU, one page up, still holds exactly the image noted
/// before that swap, and its security counter is not below the stored one.
fn restorable<F: NorFlash, W: FnMut()>(
    flash: &SharedFlash<Fed<F, W>>,
    layout: &Partitions,
    buffer: &mut [u8; BUFFER],
) -> Result<bool, BootError> {
    let entry = read_array::<PREVIOUS_LEN, _>(&mut partition(flash, layout.ticket()), PREVIOUS_OFFSET)?;
    let Some(previous) = Previous::parse(&entry) else {
        return Ok(false);
    };
    let info = read_array::<INFO_LEN, _>(&mut partition(flash, layout.dfu), PAGE + INFO_OFFSET as u32)?;
    let counter = ImageInfo::parse(&info).map_or(0, |info| info.security_counter);
    let stored = stored_counter(&mut partition(flash, layout.counter()))?.unwrap_or(0);
    if counter < stored {
        return Ok(false);
    }
    Ok(digest(flash, layout.dfu, PAGE, layout.active.length, buffer)? == previous.digest)
}

/// Write embassy-boot's state as it stands after a whole swap not yet confirmed: every progress word of the swap's
/// `2 * pages` steps done, then the swap's magic. embassy-boot's `prepare_boot` then reverts, as it reverts an image
/// that never confirmed. The magic goes last: a power cut before it leaves a state that reads as booted, which the
/// next start writes afresh (after the state's erase).
fn write_swapped<F: NorFlash>(state: &mut Partition<'_, F>, pages: u32) -> Result<(), BootError> {
    state.erase(0, state.capacity() as u32)?;
    for step in 0..2 * pages {
        state.write((2 + step) * WRITE_UNIT, &[STEP_DONE; WRITE_UNIT as usize])?;
    }
    state.write(0, &[SWAP_MAGIC; WRITE_UNIT as usize])?;
    Ok(())
}

/// Whether embassy-boot has begun the swap marked in its state: its progress-validity word or its first progress
/// word is written (embassy-boot's state layout: magic, progress validity, then one word per step of the swap).
/// Before it has, DFU holds what the application wrote and has to be checked; after, the check was done before the
/// swap began, and the swap resumes.
fn swap_begun<F: NorFlash>(state: &mut Partition<'_, F>) -> Result<bool, BootError> {
    let mut words = [0; 2 * WRITE_UNIT as usize];
    state.read(WRITE_UNIT, &mut words)?;
    Ok(words.iter().any(|byte| *byte != ERASED))
}

/// Read `N` bytes at `offset`.
fn read_array<const N: usize, F: NorFlash>(flash: &mut Partition<'_, F>, offset: u32) -> Result<[u8; N], BootError> {
    let mut bytes = [0; N];
    flash.read(offset, &mut bytes)?;
    Ok(bytes)
}

/// The bootloader's check of an image marked for the swap ([module docs](crate)): the payload's length when it may
/// be swapped in, or why not. Reads only; `feed` is called between the chunks it hashes.
pub fn judge<F: NorFlash>(
    dfu: &mut Partition<'_, F>,
    active: &mut Partition<'_, F>,
    ticket_page: &mut Partition<'_, F>,
    stored_counter: u32,
    buffer: &mut [u8; BUFFER],
    mut feed: impl FnMut(),
) -> Result<u32, Verdict> {
    fn flash<E>(_: E) -> Verdict {
        Verdict::Flash
    }
    let ticket = read_array::<TICKET_LEN, F>(ticket_page, TICKET_OFFSET).map_err(flash)?;
    let ticket = Ticket::parse(&ticket).ok_or(Verdict::NoTicket)?;
    let len = ticket.payload_len;
    if !len.is_multiple_of(WRITE_UNIT) || len < MIN_PAYLOAD || len > active.capacity() as u32 {
        return Err(Verdict::Length);
    }
    let image = read_array::<INFO_LEN, F>(dfu, INFO_OFFSET as u32).map_err(flash)?;
    let image = ImageInfo::parse(&image)
        .ok()
        .filter(|info| info.format >= update_image::INFO_FORMAT)
        .ok_or(Verdict::NoInfo)?;
    let running = read_array::<INFO_LEN, F>(active, INFO_OFFSET as u32).map_err(flash)?;
    let running = ImageInfo::parse(&running)
        .ok()
        .filter(|info| info.format >= update_image::INFO_FORMAT)
        .ok_or(Verdict::NoKey)?;
    let key = read_array::<KEY_LEN, F>(active, KEY_OFFSET as u32).map_err(flash)?;
    if image.target != running.target {
        return Err(Verdict::Target);
    }
    check_upgrade(&image, Some(&running), stored_counter).map_err(|refusal| match refusal {
        Refusal::Older { .. } => Verdict::Older,
        _ => Verdict::Counter,
    })?;
    // The last page's bytes past the payload, which the swap would copy with it.
    let tail = len.next_multiple_of(PAGE) - len;
    let tail_bytes = buffer.get_mut(..tail as usize).ok_or(Verdict::Length)?;
    dfu.read(len, tail_bytes).map_err(flash)?;
    if tail_bytes.iter().any(|byte| *byte != ERASED) {
        return Err(Verdict::PastPayload);
    }
    let digest = hash(dfu, 0, len, buffer, &mut feed).map_err(flash)?;
    Verifier::check_digest(&digest, &ticket.signature, &key)
        .map(|()| len)
        .map_err(|_| Verdict::Signature)
}

/// SHA-512 over `len` bytes of `part` from `from`, a page at a time, `feed` called after each.
fn hash<F: NorFlash>(
    part: &mut Partition<'_, F>,
    from: u32,
    len: u32,
    buffer: &mut [u8; BUFFER],
    feed: &mut impl FnMut(),
) -> Result<[u8; 64], BootError> {
    let mut verifier = Verifier::new();
    let mut offset = 0;
    while offset < len {
        let chunk = (len - offset).min(PAGE);
        let bytes = buffer.get_mut(..chunk as usize).unwrap_or_default();
        part.read(from + offset, bytes)?;
        verifier.update(bytes);
        offset += chunk;
        feed();
    }
    Ok(verifier.digest())
}

/// Erase DFU's pages past the payload's last, up to ACTIVE's length: what the swap copies into ACTIVE beside the
/// payload is erased flash. A page at a time, so that the watchdog is fed between two (a hundred pages of the
/// master's bank 2 take seconds).
fn erase_past<F: NorFlash>(dfu: &mut Partition<'_, F>, payload_len: u32, active_len: u32) -> Result<(), BootError> {
    let mut page = payload_len.next_multiple_of(PAGE);
    while page < active_len {
        dfu.erase(page, page + PAGE)?;
        page += PAGE;
    }
    Ok(())
}

/// Refuse the update marked: write its verdict beside its ticket (unless a start before this one wrote it already;
/// in the next slot if that start's was torn), then clear the mark with embassy-boot's own `mark_booted`, so that the image that ran starts again and a power
/// cut between the two only has the next start judge it again.
fn refuse<F: NorFlash, W: FnMut()>(
    flash: &SharedFlash<Fed<F, W>>,
    layout: &Partitions,
    verdict: Verdict,
) -> Result<(), BootError> {
    let mut ticket = partition(flash, layout.ticket());
    let slots = Slots(read_array(&mut ticket, VERDICT_OFFSET)?);
    if slots.value().is_none()
        && let Some(free) = slots.free()
    {
        ticket.write(VERDICT_OFFSET + free, &verdict.to_word())?;
    }
    let mut word = AlignedBuffer([0; WRITE_UNIT as usize]);
    BlockingFirmwareState::new(partition(flash, layout.state), &mut word.0)
        .mark_booted()
        .map_err(|_| BootError::Flash(embedded_storage::nor_flash::NorFlashErrorKind::Other))
}

/// The highest security counter the journal holds, `None` when it holds none: every [`checked_word`] entry of both
/// its pages (one torn by a power cut is none).
pub fn stored_counter<F: NorFlash>(journal: &mut Partition<'_, F>) -> Result<Option<u32>, BootError> {
    Ok(scan(journal)?.into_iter().filter_map(|page| page.highest).max())
}

/// One page of the counter journal.
#[derive(Debug, Clone, Copy)]
struct JournalPage {
    /// Its highest entry.
    highest: Option<u32>,
    /// Its first erased double word, where the next entry goes.
    free: Option<u32>,
    /// Every byte erased.
    erased: bool,
}

/// Both pages of the counter journal.
fn scan<F: NorFlash>(journal: &mut Partition<'_, F>) -> Result<[JournalPage; 2], BootError> {
    let mut pages = [JournalPage {
        highest: None,
        free: None,
        erased: true,
    }; 2];
    for (index, page) in pages.iter_mut().enumerate() {
        let start = index as u32 * PAGE;
        for offset in (start..start + PAGE).step_by(WRITE_UNIT as usize) {
            let word = read_array::<{ WRITE_UNIT as usize }, _>(journal, offset)?;
            if word.iter().all(|byte| *byte == ERASED) {
                page.free = page.free.or(Some(offset));
                continue;
            }
            page.erased = false;
            // An entry after an erased word would be one written out of turn; the journal appends only, so the
            // next free word is the one after the last written.
            page.free = None;
            if let Some(value) = read_checked_word(word) {
                page.highest = Some(page.highest.map_or(value, |highest| highest.max(value)));
            }
        }
    }
    Ok(pages)
}

/// At a start where the running image is confirmed: raise the stored counter to its own, if it is higher. The new
/// entry goes after the last one of the page holding the highest; when that page is full, into the other, erased
/// first if it must be: the highest entry stays whole through any power cut.
fn raise_counter<F: NorFlash, W: FnMut()>(
    flash: &SharedFlash<Fed<F, W>>,
    layout: &Partitions,
    active: &mut Partition<'_, Fed<F, W>>,
) -> Result<(), BootError> {
    let info = read_array::<INFO_LEN, _>(active, INFO_OFFSET as u32)?;
    let Some(counter) = ImageInfo::parse(&info).ok().map(|info| info.security_counter) else {
        return Ok(());
    };
    let mut journal = partition(flash, layout.counter());
    let pages = scan(&mut journal)?;
    let highest = pages.iter().filter_map(|page| page.highest).max();
    if highest.is_some_and(|highest| highest >= counter) || (highest.is_none() && counter == 0) {
        return Ok(());
    }
    // The page holding the highest entry (the first page when there is none), and the other.
    let [first, second] = pages;
    let (current, other, other_start) = if second.highest.is_some() && second.highest >= first.highest {
        (second, first, 0)
    } else {
        (first, second, PAGE)
    };
    let entry = checked_word(counter);
    if let Some(free) = current.free {
        journal.write(free, &entry)?;
        return Ok(());
    }
    if !other.erased {
        journal.erase(other_start, other_start + PAGE)?;
    }
    journal.write(other_start, &entry)?;
    Ok(())
}
