//! The master's own update: an image sent to `/update/master.lbvu` is written to the master's DFU partition (bank 2
//! of its G474, beside the code) as it arrives; the apply command checks it and marks it for the bootloader's swap,
//! and the master restarts into it. The new image runs on trial and confirms itself once it has shown that the paths
//! of the next update work: it has heard the operator's ground station for [`TRIAL_HEARD`] (the console's receive
//! task, which serves FTP too) and polled every thruster (the buses, which carry the thrusters' updates); otherwise
//! it restarts after [`TRIAL_LIMIT`] and the bootloader swaps the previous image back (so does any reset before it
//! confirms: a power cut, the watchdog).
//!
//! What is checked, and when:
//! - as the upload begins: the running image is not on trial (DFU holds the image a revert needs), the payload fits
//!   ACTIVE, and the flash has the bootloader's partitions, in the layout they are placed for (the G474's dual-bank
//!   mode: on one bank this task writes nothing, [`OwnImage::set_layout_ok`]);
//! - once its first page is in: its image info (update-image's `check`: a master image, the header's version, an
//!   info of format 2; and `check_upgrade`: not older than the running image unless signed as a rollback, its
//!   security counter not below the running image's);
//! - when applied: the ed25519 signature over DFU, with the image's update key, as the thruster checks its own.
//!
//! The bootloader checks again before it swaps (lbv-boot): the apply writes the payload's length and signature in
//! the record's ticket page (update-image's `Ticket`) before it marks the state. A bootloader that refuses the image
//! writes its `Verdict` there and starts this image again, which tells the operator once it hears them, then notes
//! in the same page that it did (the told word), so that the next start does not tell it again.
//!
//! Once the image is marked, nothing writes DFU or the state until the restart: the [`OwnImage`] is latched (a new
//! upload and its writes are refused, no page goes to DFU), and [`Shared::restarting`] tells the update server to
//! change no update file.
//!
//! No reset while diving: from the apply command to the restart, and while the new image is on trial, the vehicle
//! is kept from arming ([`OwnImage::hold`], published to [`Shared::holds`]); an apply is refused while armed (the
//! update server). An apply sent again while one runs starts no second one: it is answered as the one under way
//! ([`NotTaken::Applying`]). The trial's limit never restarts an armed vehicle: the vehicle task can take an arm
//! command before this task has read the bootloader's state at the start (the node's tasks start in that order), so
//! the start holds arming until it has ([`UpdateHold::MasterStarting`]), and a limit reached while armed waits for
//! the disarm all the same. Who applied the image is kept in the ticket's page beside it
//! ([`update_image::APPLIER_OFFSET`]), so that the final answer after the restart goes to the component that asked.
//!
//! A power cut at any moment leaves a master that boots and can be updated again: while DFU is being written or
//! checked the running image is untouched (the state says nothing yet); the state's mark is one word, which a cut
//! leaves whole or not there (embassy-boot); the swap resumes where it stopped; a new image that has not confirmed
//! is swapped back at the next start. The settings' pages are none of these, and keep what they hold.
//!
//! An image that confirms and then crashes early, three times in a row, is undone by the bootloader (lbv-boot), which
//! counts the crashes in a backup register ([`CrashRegister`]): this task clears the count once the image has run
//! [`EARLY_WINDOW`], and tells the operator once, when it hears them, that the previous image is back.
//!
//! The console's update sink ([`crate::update::VehicleSink`]) hands the bytes to an [`OwnImage`], and
//! [`own_image_task`] writes them, a page at a time, between its trial checks.

use core::cell::RefCell;
use core::sync::atomic::Ordering;

use embassy_boot::{AlignedBuffer, FirmwareState, State};
use embassy_embedded_hal::flash::partition::Partition;
use embassy_futures::select::select;
use embassy_sync::blocking_mutex::Mutex as BlockingMutex;
use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, NoopRawMutex};
use embassy_sync::mutex::Mutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Timer};
use embedded_storage_async::nor_flash::{NorFlash, ReadNorFlash};
use g431_hw::memory::{FLASH_ORIGIN, IMAGE_INFO_OFFSET, MASTER_PARTITIONS, PAGE, Span};
use update_image::{
    APPLIER_OFFSET, CrashCount, EARLY_CRASHES, EARLY_WINDOW_SECS, Header, INFO_LEN, ImageInfo, Refusal, SLOTS, Slots,
    TICKET_LEN, TICKET_OFFSET, TOLD_OFFSET, Target, Ticket, VERDICT_OFFSET, Version, check_upgrade, checked_word,
    read_checked_word,
};

use crate::ports::{CrashRegister, OwnUpdate};
use crate::shared::{
    AckResult, MAV_CMD_LBV_APPLY_UPDATE, Outgoing, Sender, Severity, Shared, Text, UpdateHold, text, texts,
    verdict_texts,
};
use crate::update::ftp::DATA_LEN;
use crate::update::header::{HEADER_LEN, ImageHeader};
use crate::update::sys::{ImageState, Running};

/// How long the image runs before a crash is no longer an early one: the count of early crashes is cleared then.
pub(crate) const EARLY_WINDOW: Duration = Duration::from_secs(EARLY_WINDOW_SECS);

/// A register that forgets at every start, as a board without a bootloader has: the tests, the cores on QEMU.
impl CrashRegister for u32 {
    fn load(&mut self) -> u32 {
        *self
    }

    fn store(&mut self, word: u32) {
        *self = word;
    }
}

/// The operator's heartbeat must be live this long, without a gap, before an image on trial confirms itself.
pub(crate) const TRIAL_HEARD: Duration = Duration::from_secs(3);
/// An image on trial that has not confirmed this long after its start restarts, and the bootloader swaps the
/// previous image back.
pub(crate) const TRIAL_LIMIT: Duration = Duration::from_secs(60);
/// How often the trial looks at the heartbeat.
pub(crate) const TRIAL_CHECK: Duration = Duration::from_millis(100);

/// A flash page, the unit DFU is written in.
pub const PAGE_BYTES: usize = PAGE as usize;

/// The erased value of a flash byte.
const ERASED: u8 = 0xFF;
/// A page and one FTP write: the sink takes a write while the page before it is still to be programmed.
const BUFFER: usize = PAGE_BYTES + DATA_LEN;
/// DFU is hashed this many bytes at a time, the other tasks let run between two.
const HASH_CHUNK: usize = 256;
/// The largest payload: ACTIVE, which it is an image of.
const MAX_PAYLOAD: u32 = MASTER_PARTITIONS.active.length;

/// Why the master does not take an image of its own.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum NotTaken {
    /// The flash has no bootloader's partitions here (or has not been looked at yet).
    NoBootloader,
    /// The running image is on trial: DFU holds the image a revert would need.
    OnTrial,
    /// The payload is larger than ACTIVE.
    TooLarge,
    /// The image's info, or a flash write, refused it: the reason has been told.
    Refused,
    /// No image is received whole.
    Nothing,
    /// An image is marked for the swap: the master restarts into it, and nothing changes DFU until then.
    Restarting,
    /// An apply is under way already, for this sender: no second one starts.
    Applying(Sender),
    /// The chip's flash is not in the layout the partitions are placed for ([`OwnImage::set_layout_ok`]).
    Layout,
}

/// What the task found in the flash at start.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Flash {
    /// Not looked at yet, or no bootloader's state there.
    Unknown,
    /// The bootloader's partitions, the running image on trial or not.
    Ready { on_trial: bool },
    /// An image is marked for the swap: latched until the restart.
    Marked,
    /// Not in the layout the partitions are placed for: nothing is written until a restart.
    WrongLayout,
}

/// An image on its way into DFU.
#[derive(Debug, Clone, Copy)]
struct Incoming {
    /// Which upload it is: one more than the one begun before.
    generation: u32,
    header: [u8; HEADER_LEN],
    payload_len: u32,
    /// DFU offset of the buffer's first byte.
    page_offset: u32,
    /// Every byte is in the buffer or in DFU.
    complete: bool,
    /// Refused (its info, or a flash write): what is left of it is dropped.
    refused: bool,
}

/// Between the console's sink and the task.
struct Stage {
    flash: Flash,
    /// The running image's version, as its image info gives it (once the task has read it).
    version: Option<[u8; 4]>,
    image: Option<Incoming>,
    /// Uploads begun so far.
    begun: u32,
    buffer: [u8; BUFFER],
    fill: usize,
    /// The apply command's sender, once applied, until the task takes it.
    apply: Option<Sender>,
    /// The apply command's sender, while the task checks and marks its image.
    checking: Option<Sender>,
    /// A refusal to tell, found by the sink.
    untold: Option<NotTaken>,
}

/// The master's image on its way into its DFU partition: the sink's side and the task's.
pub struct OwnImage {
    stage: BlockingMutex<CriticalSectionRawMutex, RefCell<Stage>>,
    /// Sink -> task: bytes, an end or an apply to see to.
    work: Signal<CriticalSectionRawMutex, ()>,
    /// Task -> sink: a page went to flash.
    moved: Signal<CriticalSectionRawMutex, ()>,
}

impl core::fmt::Debug for OwnImage {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("OwnImage").finish_non_exhaustive()
    }
}

impl Default for OwnImage {
    fn default() -> Self {
        Self::new()
    }
}

impl OwnImage {
    /// Nothing under way; master images are refused until the task has looked at the flash.
    pub const fn new() -> Self {
        Self {
            stage: BlockingMutex::new(RefCell::new(Stage {
                flash: Flash::Unknown,
                version: None,
                image: None,
                begun: 0,
                buffer: [0; BUFFER],
                fill: 0,
                apply: None,
                checking: None,
                untold: None,
            })),
            work: Signal::new(),
            moved: Signal::new(),
        }
    }

    fn with<R>(&self, f: impl FnOnce(&mut Stage) -> R) -> R {
        self.stage.lock(|stage| f(&mut stage.borrow_mut()))
    }

    /// An image begins (its header passed the update server's checks): the one before it is dropped.
    pub fn begin(&self, header: &ImageHeader) -> Result<(), NotTaken> {
        let result = self.with(|stage| {
            stage.image = None;
            stage.fill = 0;
            stage.apply = None;
            let refusal = match stage.flash {
                Flash::Marked => NotTaken::Restarting,
                Flash::WrongLayout => NotTaken::Layout,
                Flash::Unknown => NotTaken::NoBootloader,
                Flash::Ready { on_trial: true } => NotTaken::OnTrial,
                Flash::Ready { .. } if header.payload_len > MAX_PAYLOAD => NotTaken::TooLarge,
                Flash::Ready { .. } => {
                    stage.begun = stage.begun.wrapping_add(1);
                    stage.image = Some(Incoming {
                        generation: stage.begun,
                        header: header.bytes,
                        payload_len: header.payload_len,
                        page_offset: 0,
                        complete: false,
                        refused: false,
                    });
                    return Ok(());
                }
            };
            stage.untold = Some(refusal);
            Err(refusal)
        });
        self.work.signal(());
        result
    }

    /// Payload bytes from `offset`, the next ones: kept until the task writes them.
    pub fn write(&self, offset: u32, data: &[u8]) -> Result<(), NotTaken> {
        let result = self.with(|stage| {
            if stage.flash == Flash::Marked {
                stage.untold = Some(NotTaken::Restarting);
                return Err(NotTaken::Restarting);
            }
            let Stage {
                image, buffer, fill, ..
            } = stage;
            let image = image
                .as_mut()
                .filter(|i| !i.refused && !i.complete)
                .ok_or(NotTaken::Refused)?;
            let end = *fill + data.len();
            let at = image.page_offset.checked_add(*fill as u32);
            match buffer.get_mut(*fill..end) {
                Some(room) if at == Some(offset) => {
                    room.copy_from_slice(data);
                    *fill = end;
                    Ok(())
                }
                _ => Err(NotTaken::Refused),
            }
        });
        self.work.signal(());
        result
    }

    /// The image ends: whole, or stopped (what arrived is dropped).
    pub fn finish(&self, complete: bool) {
        self.with(|stage| match stage.image.as_mut() {
            _ if stage.flash == Flash::Marked => {}
            Some(image) if complete => image.complete = true,
            _ => {
                stage.image = None;
                stage.fill = 0;
            }
        });
        self.work.signal(());
    }

    /// Apply the image received whole, for `from`: the task checks its signature once every byte is in DFU. Not
    /// while an apply runs: [`NotTaken::Applying`] names whom that one answers.
    pub fn apply(&self, from: Sender) -> Result<(), NotTaken> {
        let result = self.with(|stage| match stage.image {
            _ if stage.flash == Flash::Marked => Err(NotTaken::Restarting),
            _ if let Some(by) = stage.apply.or(stage.checking) => Err(NotTaken::Applying(by)),
            Some(image) if image.complete && !image.refused => {
                stage.apply = Some(from);
                Ok(())
            }
            _ => Err(NotTaken::Nothing),
        });
        self.work.signal(());
        result
    }

    /// Wait until the next FTP write fits.
    pub(crate) async fn room(&self) {
        while self.with(|stage| stage.fill > PAGE_BYTES) {
            self.moved.wait().await;
        }
    }

    /// The task's side: what it found in the flash (`None`: no bootloader's state there), which decides whether
    /// an upload may begin.
    pub fn found(&self, on_trial: Option<bool>) {
        self.with(|stage| {
            stage.flash = match (stage.flash, on_trial) {
                // Only the restart undoes the mark, or changes the layout.
                (Flash::Marked | Flash::WrongLayout, _) => stage.flash,
                (_, Some(on_trial)) => Flash::Ready { on_trial },
                (_, None) => Flash::Unknown,
            }
        });
    }

    /// The task's side: the running image's version, as its image info gives it (`None`: no info there).
    pub fn runs(&self, version: Option<Version>) {
        self.with(|stage| stage.version = version.map(Version::to_bytes));
    }

    /// The running image, as the master knows it (`@SYS/versions.txt`).
    pub(crate) fn running(&self) -> Running {
        self.with(|stage| Running {
            version: stage.version,
            state: match stage.flash {
                Flash::Ready { on_trial: true } => ImageState::OnTrial,
                Flash::Ready { on_trial: false } => ImageState::Confirmed,
                Flash::Marked => ImageState::Marked,
                Flash::Unknown | Flash::WrongLayout => ImageState::Unknown,
            },
        })
    }

    /// The binding's side, before the tasks start: whether the chip's flash is in the layout the partitions are
    /// placed for, as it reads it (`g431_hw::flash::master_layout_ok`: the G474's dual-bank mode). When it is not,
    /// every upload is refused ([`NotTaken::Layout`]) and the task writes nothing: an erase would land on other
    /// pages.
    pub fn set_layout_ok(&self, ok: bool) {
        if !ok {
            self.with(|stage| stage.flash = Flash::WrongLayout);
        }
    }

    fn layout_ok(&self) -> bool {
        self.with(|stage| stage.flash != Flash::WrongLayout)
    }

    /// The task's side: an image is marked for the swap, and the master restarts into it. From now on nothing is
    /// taken and nothing goes to DFU: an upload begun while the image was being checked is dropped, and a new one
    /// is refused.
    pub fn mark(&self) {
        self.with(|stage| {
            stage.flash = Flash::Marked;
            stage.image = None;
            stage.fill = 0;
            stage.apply = None;
            stage.checking = None;
        });
        self.moved.signal(());
    }

    /// Whether an image is marked for the swap ([`OwnImage::mark`]).
    #[cfg(test)]
    pub(crate) fn marked(&self) -> bool {
        self.with(|stage| stage.flash == Flash::Marked)
    }

    /// What of the master's own update keeps the vehicle from arming: marked and restarting, an apply under way, or
    /// the running image on trial.
    pub(crate) fn hold(&self) -> Option<UpdateHold> {
        self.with(|stage| match stage.flash {
            Flash::Marked => Some(UpdateHold::MasterRestarting),
            _ if stage.apply.or(stage.checking).is_some() => Some(UpdateHold::MasterApplying),
            Flash::Ready { on_trial: true } => Some(UpdateHold::MasterOnTrial),
            _ => None,
        })
    }

    /// The task's side: the next piece for DFU, a whole page or the last bytes once the image is complete (padded
    /// with erased bytes to the write unit), copied into `page` and taken out of the buffer.
    pub fn take_page(&self, page: &mut [u8; PAGE_BYTES]) -> Option<Piece> {
        self.with(|stage| {
            if stage.flash == Flash::Marked {
                return None;
            }
            let Stage {
                image, buffer, fill, ..
            } = stage;
            let image = image.as_mut().filter(|i| !i.refused)?;
            let len = if *fill >= PAGE_BYTES {
                PAGE_BYTES
            } else if image.complete && *fill > 0 {
                *fill
            } else {
                return None;
            };
            page.fill(0xFF);
            page.get_mut(..len)?.copy_from_slice(buffer.get(..len)?);
            buffer.copy_within(len..*fill, 0);
            *fill -= len;
            let offset = image.page_offset;
            image.page_offset += len as u32;
            Some(Piece {
                offset,
                len: len.next_multiple_of(8),
                generation: image.generation,
                header: image.header,
            })
        })
    }

    /// The piece's image is refused (its info, or its write): what is left of it is dropped, and the sink's next
    /// write refused. An upload begun since is not touched.
    fn refuse(&self, piece: &Piece) {
        self.with(|stage| {
            if let Some(image) = stage.image.as_mut().filter(|i| i.generation == piece.generation) {
                image.refused = true;
                stage.fill = 0;
            }
        });
    }
}

/// A piece of an image for DFU, as [`OwnImage::take_page`] hands it to the task.
#[derive(Debug, Clone, Copy)]
pub struct Piece {
    /// Its offset in DFU.
    pub offset: u32,
    /// Its length, a whole number of double words.
    pub len: usize,
    /// Which upload it is of.
    generation: u32,
    /// That upload's header.
    header: [u8; HEADER_LEN],
}

/// The master's flash as the task needs it (any async NOR flash addressed from the flash's start): the ACTIVE
/// image's info, DFU and the bootloader's state, at [`MASTER_PARTITIONS`]' offsets.
pub struct OwnFlash<F: NorFlash> {
    flash: Mutex<NoopRawMutex, F>,
}

impl<F: NorFlash> core::fmt::Debug for OwnFlash<F> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("OwnFlash").finish_non_exhaustive()
    }
}

impl<F: NorFlash> OwnFlash<F> {
    /// `flash`, the whole chip's.
    pub fn new(flash: F) -> Self {
        Self {
            flash: Mutex::new(flash),
        }
    }

    fn partition(&self, span: Span) -> Partition<'_, NoopRawMutex, F> {
        Partition::new(&self.flash, span.origin - FLASH_ORIGIN, span.length)
    }
}

impl OwnUpdate for () {
    /// Nothing to hold arming for ([`crate::run`] holds it until the own update has started).
    async fn run(self, _polled: u8, shared: &Shared) {
        shared.holds.set_master(None);
        core::future::pending().await
    }
}

/// The master's own update on `flash`, with the images the console's sink hands to `image`, and the bootloader's
/// count of early crashes in `crashes`.
#[derive(Debug)]
pub struct Updating<'a, F: NorFlash, C: CrashRegister> {
    /// The chip's flash.
    pub flash: OwnFlash<F>,
    /// The sink's side.
    pub image: &'a OwnImage,
    /// The bootloader's count of early crashes.
    pub crashes: C,
}

impl<F: NorFlash, C: CrashRegister> OwnUpdate for Updating<'_, F, C> {
    async fn run(self, polled: u8, shared: &Shared) {
        own_image_task(&self.flash, self.image, self.crashes, polled, shared).await
    }
}

/// Whether each of the first `polled` thrusters of the table has been polled since the start: the buses' work, the
/// path that carries the thrusters' updates, runs.
fn thrusters_polled(shared: &Shared, polled: u8) -> bool {
    shared
        .thrusters
        .iter()
        .take(usize::from(polled))
        .all(|thruster| thruster.try_get().is_some_and(|report| report.health.polls > 0))
}

/// "master.lbvu: `args`", as the update server names the file the ground station wrote (in two texts when one
/// cannot hold it: a refusal's sentence goes on in the second).
async fn say(shared: &Shared, severity: Severity, args: core::fmt::Arguments<'_>) {
    tell(shared, severity, texts(format_args!("master.lbvu"), args)).await;
}

/// Queue one or two texts.
async fn tell(shared: &Shared, severity: Severity, (first, second): (Text, Option<Text>)) {
    for text in [Some(first), second].into_iter().flatten() {
        shared.outbox.send(Outgoing::Text(severity, text)).await;
    }
}

async fn acknowledge(shared: &Shared, result: AckResult, to: Sender) {
    shared
        .outbox
        .send(Outgoing::CommandAck {
            command: MAV_CMD_LBV_APPLY_UPDATE,
            result,
            to,
        })
        .await;
}

/// The operator's ground station, once its heartbeat is heard: who gets the final COMMAND_ACK of an apply that
/// the restart cut short.
fn operator_heard(shared: &Shared) -> Option<Sender> {
    shared
        .vehicle
        .try_get()
        .filter(|vehicle| vehicle.console_alive)
        .map(|vehicle| Sender {
            system: vehicle.operator,
            component: 0,
        })
}

/// Why an apply did not mark the image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum NotMarked {
    /// The signature does not check with the update key.
    Signature,
    /// The ticket did not read back as written.
    Ticket,
    /// The state did not read back marked for the swap.
    State,
}

/// The master's own update and its trial, on `flash` (the whole chip's, [`OwnFlash`]): writes what `own` receives
/// into DFU, checks and marks it when applied, confirms an image on trial once the operator is heard, and tells the
/// operator once when the bootloader refused the image marked before the last restart, or undid one that crashed;
/// clears the count of early crashes once the image has run [`EARLY_WINDOW`].
pub(crate) async fn own_image_task<F: NorFlash, C: CrashRegister>(
    flash: &OwnFlash<F>,
    own: &OwnImage,
    mut crashes: C,
    polled: u8,
    shared: &Shared,
) -> ! {
    let mut restored = CrashCount::from_word(crashes.load()).restored;
    let mut early = true;
    let mut info = [0xFF; INFO_LEN];
    let _ = flash
        .partition(MASTER_PARTITIONS.active)
        .read(IMAGE_INFO_OFFSET, &mut info)
        .await;
    let running = ImageInfo::parse(&info).ok();
    own.runs(running.map(|info| info.version));
    let mut ticket_page = flash.partition(MASTER_PARTITIONS.ticket());
    let mut untold = untold_verdict(&mut ticket_page).await;
    let applier = applier_of(&mut ticket_page).await;
    let mut word = AlignedBuffer([0; 8]);
    let mut state = FirmwareState::new(flash.partition(MASTER_PARTITIONS.state), &mut word.0);
    let layout_ok = own.layout_ok();
    let mut on_trial = match state.get_state().await {
        // On the wrong layout a trial neither confirms (a write) nor reverts (a restart into the bootloader).
        Ok(found) if layout_ok => {
            let on_trial = found == State::Swap;
            own.found(Some(on_trial));
            on_trial
        }
        _ => false,
    };
    shared.holds.set_master(own.hold());
    if on_trial {
        say(
            shared,
            Severity::Info,
            format_args!("runs {}, on trial", Shown(running.map(|info| info.version))),
        )
        .await;
    }
    let started = Instant::now();
    let mut heard_since = None;
    let mut dfu = flash.partition(MASTER_PARTITIONS.dfu);
    let mut page = [0xFF; PAGE_BYTES];
    let mut waits_for_disarm = false;
    loop {
        select(own.work.wait(), Timer::after(TRIAL_CHECK)).await;
        shared.holds.set_master(own.hold());
        if on_trial {
            let now = Instant::now();
            let heard = shared.vehicle.try_get().is_some_and(|v| v.console_alive);
            heard_since = if heard { heard_since.or(Some(now)) } else { None };
            if heard_since.is_some_and(|since| now >= since + TRIAL_HEARD) && thrusters_polled(shared, polled) {
                if state.mark_booted().await.is_ok() {
                    on_trial = false;
                    own.found(Some(false));
                    let version = Shown(running.map(|info| info.version));
                    say(shared, Severity::Info, format_args!("{version} confirmed")).await;
                    let operator = shared.vehicle.try_get().map(|v| Sender {
                        system: v.operator,
                        component: 0,
                    });
                    if let Some(to) = applier.or(operator) {
                        acknowledge(shared, AckResult::Accepted, to).await;
                    }
                }
            } else if now >= started + TRIAL_LIMIT && shared.vehicle.try_get().is_some_and(|v| v.armed) {
                // Never a restart in the water.
                if !waits_for_disarm {
                    waits_for_disarm = true;
                    shared.say(
                        Severity::Warning,
                        text(format_args!("master.lbvu: reverting once disarmed")),
                    );
                }
            } else if now >= started + TRIAL_LIMIT {
                say(
                    shared,
                    Severity::Warning,
                    format_args!("no GCS heard on trial: reverting"),
                )
                .await;
                shared.outbox.send(Outgoing::Reboot).await;
                on_trial = false;
            }
        }
        if early && Instant::now() >= started + EARLY_WINDOW {
            early = false;
            crashes.store(CrashCount { crashes: 0, restored }.to_word());
        }
        // Told once the operator is heard: a text at the start, before any ground station listens, would be lost
        // and yet noted as told.
        if restored && operator_heard(shared).is_some() {
            say(
                shared,
                Severity::Warning,
                format_args!(
                    "{EARLY_CRASHES} early crashes: {} restored",
                    Shown(running.map(|info| info.version))
                ),
            )
            .await;
            restored = false;
            let count = CrashCount::from_word(crashes.load());
            crashes.store(CrashCount { restored, ..count }.to_word());
        }
        if let Some((verdict, free)) = untold
            && let Some(operator) = operator_heard(shared)
        {
            let told = verdict_texts(format_args!("master.lbvu"), "refused by the bootloader", verdict);
            tell(shared, Severity::Warning, told).await;
            acknowledge(shared, AckResult::Failed, applier.unwrap_or(operator)).await;
            // A write that fails, or is not made, leaves it to be told again at the next start.
            if let Some(free) = free.filter(|_| layout_ok) {
                let _ = ticket_page.write(TOLD_OFFSET + free, &checked_word(verdict)).await;
            }
            untold = None;
        }
        if let Some(refusal) = own.with(|stage| stage.untold.take()) {
            let kib = MAX_PAYLOAD / 1024;
            let why = match refusal {
                NotTaken::NoBootloader => format_args!("no bootloader here to swap it in"),
                NotTaken::OnTrial => format_args!("on trial: wait for it to confirm"),
                NotTaken::TooLarge => format_args!("larger than ACTIVE ({kib} KiB)"),
                NotTaken::Restarting => format_args!("marked for the swap: restarting"),
                NotTaken::Layout => format_args!("refused: {}", crate::NOT_DUAL_BANK),
                NotTaken::Refused | NotTaken::Nothing | NotTaken::Applying(_) => format_args!("refused"),
            };
            say(shared, Severity::Warning, why).await;
        }
        while let Some(piece) = own.take_page(&mut page) {
            // The page is out of the buffer: the console reads on while it is programmed (bank 2, beside the code),
            // rather than leave the next request to overrun the UART's receive buffer for the page's tens of ms.
            own.moved.signal(());
            let written = program(&mut dfu, piece.offset, page.get(..piece.len).unwrap_or_default()).await;
            let refusal = match written {
                Ok(()) if piece.offset == 0 => check_info(&piece.header, &page, running.as_ref()),
                Ok(()) => Ok(()),
                Err(()) => Err(None),
            };
            if refusal.is_err() {
                own.refuse(&piece);
                own.moved.signal(());
            }
            if let Err(refusal) = refusal {
                match refusal {
                    Some(refusal) => say(shared, Severity::Warning, format_args!("refused: {refusal}")).await,
                    None => {
                        say(
                            shared,
                            Severity::Warning,
                            format_args!("DFU write failed: send it again"),
                        )
                        .await
                    }
                }
                break;
            }
        }
        let ready = own.with(|stage| match (stage.image, stage.apply) {
            (Some(image), Some(from)) if stage.fill == 0 && image.page_offset >= image.payload_len => {
                stage.checking = stage.apply.take();
                Some((image.header, image.payload_len, from))
            }
            _ => None,
        });
        if let Some((header, payload_len, from)) = ready {
            let marked = mark(&mut dfu, &mut ticket_page, &mut state, &header, payload_len, from).await;
            // Past the signature, the ticket's page was erased: a verdict not told yet went with it, and a told
            // word written now would silence the bootloader's verdict on this image.
            if marked != Err(NotMarked::Signature) {
                untold = None;
            }
            match marked {
                Ok(()) => {
                    // Latched before anything else runs: an upload begun during the check goes no further.
                    own.mark();
                    shared.restarting.store(true, Ordering::Relaxed);
                    say(shared, Severity::Info, format_args!("signature good, restarting")).await;
                    shared.outbox.send(Outgoing::Reboot).await;
                }
                Err(why) => {
                    own.with(|stage| stage.checking = None);
                    let why = match why {
                        NotMarked::Signature => format_args!("signature bad: image refused"),
                        NotMarked::Ticket => format_args!("ticket not written: send it again"),
                        NotMarked::State => format_args!("state not written: send it again"),
                    };
                    say(shared, Severity::Warning, why).await;
                    acknowledge(shared, AckResult::Failed, from).await;
                }
            }
        }
    }
}

/// The bootloader's verdict on the image marked before the last restart, if it refused one and that was not told
/// yet (the verdict's slots hold a word, the told slots none), with where the told word goes (`None`: every told
/// slot is torn, and it is told at every start).
async fn untold_verdict<P: NorFlash>(page: &mut P) -> Option<(u32, Option<u32>)> {
    let mut verdict = Slots([0xFF; 8 * SLOTS]);
    let mut told = Slots([0xFF; 8 * SLOTS]);
    page.read(VERDICT_OFFSET, &mut verdict.0).await.ok()?;
    page.read(TOLD_OFFSET, &mut told.0).await.ok()?;
    let verdict = verdict.value().filter(|_| told.value().is_none())?;
    Some((verdict, told.free()))
}

/// Who applied the image whose ticket the page holds (written by [`mark`]), if a whole word says so.
async fn applier_of<P: NorFlash>(page: &mut P) -> Option<Sender> {
    let mut word = [0xFF; 8];
    page.read(APPLIER_OFFSET, &mut word).await.ok()?;
    let [component, system, ..] = read_checked_word(word)?.to_le_bytes();
    Some(Sender { system, component })
}

/// Check the signature over DFU's payload, hand the bootloader its ticket and note who applied it (`from`, whom the
/// final answer goes to after the restart), and mark the image for the swap. The flash is read back after each
/// write: embassy-stm32's async driver can answer Ok to an erase or a program that did not happen. A note that did
/// not take costs only where the final answer goes (the operator's system, component 0).
async fn mark<D: NorFlash, P: NorFlash, S: NorFlash>(
    dfu: &mut D,
    ticket_page: &mut P,
    state: &mut FirmwareState<'_, S>,
    header: &[u8; HEADER_LEN],
    payload_len: u32,
    from: Sender,
) -> Result<(), NotMarked> {
    let header = Header::parse(header).map_err(|_| NotMarked::Signature)?;
    verify(dfu, &header, payload_len)
        .await
        .map_err(|()| NotMarked::Signature)?;
    let ticket = Ticket {
        payload_len,
        signature: header.signature,
    }
    .to_bytes();
    let mut back = [0; TICKET_LEN];
    let written = async {
        ticket_page.erase(0, PAGE).await?;
        ticket_page.write(TICKET_OFFSET, &ticket).await?;
        ticket_page.read(TICKET_OFFSET, &mut back).await
    };
    if written.await.is_err() || back != ticket {
        return Err(NotMarked::Ticket);
    }
    let applier = u32::from_le_bytes([from.component, from.system, 0, 0]);
    let _ = ticket_page.write(APPLIER_OFFSET, &checked_word(applier)).await;
    if state.mark_updated().await.is_err() || !matches!(state.get_state().await, Ok(State::Swap)) {
        return Err(NotMarked::State);
    }
    Ok(())
}

/// The first page is in DFU: hold its upload's header to its image info (update-image's `check`), and the image to
/// the one that runs (`check_upgrade`: not older unless signed as a rollback, a security counter not below the
/// running image's). `None` when the header itself does not parse (the update server has read it already).
fn check_info(
    header: &[u8; HEADER_LEN],
    first: &[u8; PAGE_BYTES],
    running: Option<&ImageInfo>,
) -> Result<(), Option<Refusal>> {
    let header = Header::parse(header).map_err(|_| None)?;
    let info = first
        .get(IMAGE_INFO_OFFSET as usize..)
        .and_then(|bytes| ImageInfo::parse(bytes).ok());
    let Some(info) = info else {
        return Err(Some(Refusal::TooShort {
            len: header.payload_len,
        }));
    };
    update_image::check(&header, &info, Target::Master, MAX_PAYLOAD).map_err(Some)?;
    check_upgrade(&info, running, running.map_or(0, |running| running.security_counter)).map_err(Some)
}

/// Erase DFU's page at `offset` and program `data` there.
async fn program<D: NorFlash>(dfu: &mut D, offset: u32, data: &[u8]) -> Result<(), ()> {
    if holds(dfu, offset, data).await {
        return Ok(());
    }
    dfu.erase(offset, offset + PAGE).await.map_err(drop)?;
    dfu.write(offset, data).await.map_err(drop)
}

/// Whether DFU's page at `offset` holds `data` and erased flash after it: written by an upload of the same file
/// that stopped (a lost link, a reset), and kept rather than erased and written again, as a thruster keeps the
/// pages of an interrupted transfer.
async fn holds<D: NorFlash>(dfu: &mut D, offset: u32, data: &[u8]) -> bool {
    const CHUNK: usize = 64;
    let mut chunk = [0; CHUNK];
    let mut at = 0;
    while at < PAGE_BYTES {
        if dfu.read(offset + at as u32, &mut chunk).await.is_err() {
            return false;
        }
        let expected = data.get(at..).unwrap_or_default();
        let differs = chunk
            .iter()
            .enumerate()
            .any(|(i, byte)| *byte != expected.get(i).copied().unwrap_or(ERASED));
        if differs {
            return false;
        }
        at += CHUNK;
    }
    true
}

/// DFU's first `payload_len` bytes hashed with SHA-512 and the header's signature checked over the digest with the
/// image's update key (update-image's `Verifier`, salty, as the thruster checks its own).
async fn verify<D: NorFlash>(dfu: &mut D, header: &Header, payload_len: u32) -> Result<(), ()> {
    let mut verifier = update_image::Verifier::new();
    let mut chunk = [0; HASH_CHUNK];
    let mut offset = 0;
    while offset < payload_len {
        let len = usize::try_from(payload_len - offset).map_or(HASH_CHUNK, |left| left.min(HASH_CHUNK));
        let bytes = chunk.get_mut(..len).unwrap_or_default();
        dfu.read(offset, bytes).await.map_err(drop)?;
        verifier.update(bytes);
        offset += len as u32;
        embassy_futures::yield_now().await;
    }
    verifier
        .finish(&header.signature, &update_image::UPDATE_KEY)
        .map_err(drop)
}

/// A version for a person, "?" when the image has no info.
struct Shown(Option<Version>);

impl core::fmt::Display for Shown {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self.0 {
            Some(version) => write!(f, "{version}"),
            None => f.write_str("?"),
        }
    }
}

#[cfg(test)]
mod tests;
