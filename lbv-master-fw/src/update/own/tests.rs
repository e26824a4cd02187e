//! The master's own update on lbv-sim's G474 flash, on virtual time: an image written page by page into DFU and
//! marked for the swap when its signature is good, its ticket handed to the bootloader, and nothing written after
//! the mark; refused, with its reason, when its signature is bad, its info is not a master's or is older than the
//! running image's, it is too large or the running image is on trial, and with nothing written at all on a flash
//! not in dual-bank mode; the bootloader's refusal told once; and the trial confirmed once the operator is heard,
//! or given up (back to the previous image) when not.

use std::cell::{Cell, RefCell};
use std::ops::Range;
use std::rc::Rc;
use std::vec::Vec;

use embassy_time::Duration;
use lbv_sim::Executor;
use lbv_sim::clock::{self, Clock};
use lbv_sim::flash::{FlashError, Stm32g4Flash};
use update_image::{
    DEV_PUBLIC_KEY, INFO_OFFSET, ImageInfo, Verdict, Version, image_record, key_from_hex, read_checked_word,
};

use super::*;
use crate::shared::{LinkHealth, ThrusterReport, VehicleState};
use crate::sim::master_flash;
use crate::update::parse_header;

const OPERATOR: Sender = Sender {
    system: 255,
    component: 190,
};

/// A signed update file of `len` payload bytes for `target`, version 0.2.0, with the development key.
fn signed(target: Target, len: usize) -> Vec<u8> {
    signed_as(ImageInfo::new(target, Version::new(0, 2, 0)), len)
}

/// A signed update file of `len` payload bytes whose image info is `info`, with the development key (which it
/// embeds after its info, as a build does).
fn signed_as(info: ImageInfo, len: usize) -> Vec<u8> {
    let mut payload: Vec<u8> = (0..len as u32)
        .map(|n| (n.wrapping_mul(2_654_435_761) >> 9) as u8)
        .collect();
    let record = image_record(info, &DEV_PUBLIC_KEY);
    payload[INFO_OFFSET..INFO_OFFSET + record.len()].copy_from_slice(&record);
    let seed = key_from_hex(include_str!("../../../../keys/dev.key")).unwrap();
    update_image::sign(&payload, &seed).unwrap()
}

/// The flash as a probe leaves it: the running image (0.1.0) in ACTIVE, the bootloader's state erased.
fn flashed() -> Stm32g4Flash {
    flashed_with(ImageInfo::new(Target::Master, Version::new(0, 1, 0)))
}

/// The flash as a probe leaves it, the running image's info `info`.
fn flashed_with(info: ImageInfo) -> Stm32g4Flash {
    let mut flash = master_flash();
    let record = image_record(info, &DEV_PUBLIC_KEY);
    let active = MASTER_PARTITIONS.active.origin - FLASH_ORIGIN;
    embassy_futures::block_on(flash.write(active + IMAGE_INFO_OFFSET, &record)).unwrap();
    flash
}

/// Where `span` starts, from the flash's start.
fn at(span: Span) -> u32 {
    span.origin - FLASH_ORIGIN
}

/// The master's flash with a hand in it: `on_read` runs at every read (given its offset from the flash's start),
/// and erases and writes within `lost` answer Ok and do nothing, as embassy-stm32's async driver can.
struct Meddled<'a> {
    flash: Stm32g4Flash,
    on_read: OnRead<'a>,
    lost: Range<u32>,
}

/// What runs at every read of a [`Meddled`] flash; shared, so that a test sets it once the flash is in use.
type OnRead<'a> = Rc<RefCell<Option<Box<dyn FnMut(u32) + 'a>>>>;

impl<'a> Meddled<'a> {
    fn new(flash: &Stm32g4Flash) -> Self {
        Self {
            flash: flash.clone(),
            on_read: Rc::default(),
            lost: 0..0,
        }
    }
}

impl embedded_storage_async::nor_flash::ErrorType for Meddled<'_> {
    type Error = FlashError;
}

impl ReadNorFlash for Meddled<'_> {
    const READ_SIZE: usize = 1;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        if let Some(hook) = self.on_read.borrow_mut().as_mut() {
            hook(offset);
        }
        self.flash.read(offset, bytes).await
    }

    fn capacity(&self) -> usize {
        ReadNorFlash::capacity(&self.flash)
    }
}

impl NorFlash for Meddled<'_> {
    const WRITE_SIZE: usize = 8;
    const ERASE_SIZE: usize = PAGE_BYTES;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        if self.lost.contains(&from) {
            return Ok(());
        }
        self.flash.erase(from, to).await
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        if self.lost.contains(&offset) {
            return Ok(());
        }
        self.flash.write(offset, bytes).await
    }
}

/// embassy-boot's state partition of `flash`, through its own code.
fn with_state<R>(flash: &Stm32g4Flash, f: impl AsyncFnOnce(&mut FirmwareState<'_, Stm32g4Flash>) -> R) -> R {
    let span = MASTER_PARTITIONS.state;
    let state = flash.partition(span.origin - FLASH_ORIGIN, span.length).unwrap();
    let mut word = AlignedBuffer([0; 8]);
    embassy_futures::block_on(f(&mut FirmwareState::new(state, &mut word.0)))
}

fn state_of(flash: &Stm32g4Flash) -> State {
    with_state(flash, async |state| state.get_state().await).unwrap()
}

/// Marked for the swap, as the image before it left it: the image running now is on trial.
fn on_trial(flash: &Stm32g4Flash) {
    with_state(flash, async |state| state.mark_updated().await).unwrap();
}

fn dfu(flash: &Stm32g4Flash, len: usize) -> Vec<u8> {
    let start = (MASTER_PARTITIONS.dfu.origin - FLASH_ORIGIN) as usize;
    flash.contents()[start..start + len].to_vec()
}

/// A backup register, kept by the test.
struct Kept<'a>(&'a Cell<u32>);

impl CrashRegister for Kept<'_> {
    fn load(&mut self) -> u32 {
        self.0.get()
    }

    fn store(&mut self, word: u32) {
        self.0.set(word);
    }
}

/// The console's side and what the master said.
struct Bench<'a> {
    clock: Clock,
    executor: Executor<'a>,
    own: &'a OwnImage,
    shared: &'a Shared,
}

impl<'a> Bench<'a> {
    fn new<F: NorFlash>(own: &'a OwnImage, shared: &'a Shared, updating: &'a OwnFlash<F>) -> Self {
        Self::with(own, shared, updating, 0, 0)
    }

    /// The task with `polled` thrusters to poll and a crash register holding `crashes`.
    fn with<F: NorFlash, C: CrashRegister + 'a>(
        own: &'a OwnImage,
        shared: &'a Shared,
        updating: &'a OwnFlash<F>,
        polled: u8,
        crashes: C,
    ) -> Self {
        let clock = clock::take();
        let mut executor = Executor::new();
        executor.spawn(async move {
            own_image_task(updating, own, crashes, polled, shared).await;
        });
        let mut bench = Self {
            clock,
            executor,
            own,
            shared,
        };
        bench.run(Duration::from_millis(10));
        bench
    }

    fn run(&mut self, duration: Duration) {
        self.executor.run_for(&self.clock, duration, Duration::from_millis(1));
    }

    /// Upload `file` as the update server hands it on: its header, then FTP writes of 239 bytes, each once the
    /// sink has room; the first refusal ends it.
    fn upload(&mut self, file: &[u8]) -> Result<(), NotTaken> {
        let header = parse_header(file[..HEADER_LEN].try_into().unwrap()).unwrap();
        self.own.begin(&header)?;
        let payload = &file[HEADER_LEN..];
        for (index, piece) in payload.chunks(DATA_LEN).enumerate() {
            let mut waited = 0;
            while self.own.with(|stage| stage.fill > PAGE_BYTES) {
                self.run(Duration::from_millis(1));
                waited += 1;
                assert!(waited < 1000, "the sink never had room");
            }
            self.own.write((index * DATA_LEN) as u32, piece)?;
            self.run(Duration::from_micros(100));
        }
        self.own.finish(true);
        self.run(Duration::from_millis(50));
        Ok(())
    }

    /// Everything the master queued for the console since the last look.
    fn said(&self) -> Vec<Outgoing> {
        core::iter::from_fn(|| self.shared.outbox.try_receive().ok()).collect()
    }

    fn hear_operator(&self, alive: bool) {
        self.shared.vehicle.sender().send(VehicleState {
            console_alive: alive,
            operator: OPERATOR.system,
            ..VehicleState::READY
        });
    }
}

fn texts(said: &[Outgoing]) -> Vec<String> {
    said.iter()
        .filter_map(|out| match out {
            Outgoing::Text(_, text) => Some(text.as_str().to_string()),
            _ => None,
        })
        .collect()
}

fn acks(said: &[Outgoing]) -> Vec<AckResult> {
    said.iter()
        .filter_map(|out| match out {
            Outgoing::CommandAck { result, .. } => Some(*result),
            _ => None,
        })
        .collect()
}

#[test]
fn a_signed_image_goes_into_dfu_and_is_marked_for_the_swap_then_the_master_restarts() {
    let flash = flashed();
    let (own, shared) = (OwnImage::new(), Shared::new());
    let updating = OwnFlash::new(flash.clone());
    let mut bench = Bench::new(&own, &shared, &updating);
    let file = signed(Target::Master, 5000);
    bench.upload(&file).unwrap();
    assert_eq!(
        dfu(&flash, file.len() - HEADER_LEN),
        file[HEADER_LEN..],
        "DFU holds the payload"
    );
    assert_eq!(state_of(&flash), State::Boot, "nothing marked before the apply");
    assert!(bench.said().is_empty());

    own.apply(OPERATOR).unwrap();
    bench.run(Duration::from_millis(100));
    let said = bench.said();
    assert_eq!(texts(&said), ["master.lbvu: signature good, restarting"]);
    assert!(matches!(said.last(), Some(Outgoing::Reboot)), "{said:?}");
    assert_eq!(state_of(&flash), State::Swap, "marked for the bootloader's swap");
}

#[test]
fn the_same_file_sent_again_keeps_the_pages_dfu_holds_and_writes_the_rest() {
    let flash = flashed();
    let (own, shared) = (OwnImage::new(), Shared::new());
    let updating = OwnFlash::new(flash.clone());
    let mut bench = Bench::new(&own, &shared, &updating);
    let file = signed(Target::Master, 5 * PAGE_BYTES + 100);
    bench.upload(&file).unwrap();
    let erases = flash.stats().erases;
    // Sent again, as after a lost link or a reset: every page is in DFU already, and none is erased.
    bench.upload(&file).unwrap();
    assert_eq!(flash.stats().erases, erases, "every page kept");
    // Another version of it, whose code is the same but for its image info: only the first page differs, and only
    // it is written.
    let other = signed_as(
        ImageInfo::new(Target::Master, Version::new(0, 3, 0)),
        5 * PAGE_BYTES + 100,
    );
    bench.upload(&other).unwrap();
    assert_eq!(flash.stats().erases, erases + 1, "the first page written");
    assert_eq!(dfu(&flash, other.len() - HEADER_LEN), other[HEADER_LEN..]);
    own.apply(OPERATOR).unwrap();
    bench.run(Duration::from_millis(100));
    assert_eq!(state_of(&flash), State::Swap, "marked");
}

#[test]
fn a_bad_signature_is_refused_and_nothing_is_marked() {
    let flash = flashed();
    let (own, shared) = (OwnImage::new(), Shared::new());
    let updating = OwnFlash::new(flash.clone());
    let mut bench = Bench::new(&own, &shared, &updating);
    let mut file = signed(Target::Master, 5000);
    // One bit of the payload, after the signature was made.
    file[HEADER_LEN + 3000] ^= 0x10;
    bench.upload(&file).unwrap();
    own.apply(OPERATOR).unwrap();
    bench.run(Duration::from_millis(100));
    let said = bench.said();
    assert_eq!(texts(&said), ["master.lbvu: signature bad: image refused"]);
    assert_eq!(acks(&said), [AckResult::Failed]);
    assert!(!said.iter().any(|out| matches!(out, Outgoing::Reboot)));
    assert_eq!(state_of(&flash), State::Boot);
    assert_eq!(
        own.apply(OPERATOR),
        Ok(()),
        "the same image may be applied again (and fail again)"
    );
}

#[test]
fn a_thruster_image_under_a_master_header_is_refused_at_its_first_page() {
    let flash = flashed();
    let (own, shared) = (OwnImage::new(), Shared::new());
    let updating = OwnFlash::new(flash.clone());
    let mut bench = Bench::new(&own, &shared, &updating);
    // A thruster payload, its header's target byte changed to the master's: the update server's path check passes,
    // the signed image info does not.
    let mut file = signed(Target::ThrusterSeabotix, 8000);
    file[5] = Target::Master.to_byte();
    assert_eq!(bench.upload(&file), Err(NotTaken::Refused));
    let said = bench.said();
    // Said whole as two texts would hold it.
    assert_eq!(
        texts(&said),
        [
            "master.lbvu: refused: the header is for the",
            "master.lbvu: master, the payload for the SeaBotix "
        ]
    );
    assert_eq!(own.apply(OPERATOR), Err(NotTaken::Nothing));
    assert_eq!(state_of(&flash), State::Boot);
}

#[test]
fn an_image_larger_than_active_is_refused_before_anything_is_written() {
    let flash = flashed();
    let (own, shared) = (OwnImage::new(), Shared::new());
    let updating = OwnFlash::new(flash.clone());
    let mut bench = Bench::new(&own, &shared, &updating);
    let mut header = parse_header(signed(Target::Master, 4096)[..HEADER_LEN].try_into().unwrap()).unwrap();
    header.payload_len = MASTER_PARTITIONS.active.length + 8;
    assert_eq!(own.begin(&header), Err(NotTaken::TooLarge));
    bench.run(Duration::from_millis(10));
    assert_eq!(texts(&bench.said()), ["master.lbvu: larger than ACTIVE (228 KiB)"]);
    assert_eq!(flash.stats().erases, 0);
}

#[test]
fn an_image_on_trial_confirms_once_the_operator_is_heard_for_three_seconds() {
    let flash = flashed();
    on_trial(&flash);
    let (own, shared) = (OwnImage::new(), Shared::new());
    let updating = OwnFlash::new(flash.clone());
    let mut bench = Bench::new(&own, &shared, &updating);
    assert_eq!(texts(&bench.said()), ["master.lbvu: runs 0.1.0, on trial"]);
    // While on trial, DFU keeps the image a revert needs: a new upload is refused.
    let file = signed(Target::Master, 4096);
    assert_eq!(bench.upload(&file), Err(NotTaken::OnTrial));
    bench.run(Duration::from_millis(200));
    assert_eq!(texts(&bench.said()), ["master.lbvu: on trial: wait for it to confirm"]);
    // Heard, then lost after 2 s: the count starts again.
    bench.hear_operator(true);
    bench.run(Duration::from_secs(2));
    bench.hear_operator(false);
    bench.run(Duration::from_millis(500));
    bench.hear_operator(true);
    bench.run(Duration::from_millis(2900));
    assert_eq!(state_of(&flash), State::Swap, "not yet: 2.9 s heard without a gap");
    bench.run(Duration::from_millis(300));
    assert_eq!(state_of(&flash), State::Boot, "confirmed");
    let said = bench.said();
    assert_eq!(texts(&said), ["master.lbvu: 0.1.0 confirmed"]);
    assert_eq!(acks(&said), [AckResult::Accepted]);
    assert!(matches!(
        said.last(),
        Some(Outgoing::CommandAck {
            to: Sender { system: 255, .. },
            ..
        })
    ));
    // Now it takes an update again.
    bench.upload(&file).unwrap();
}

#[test]
fn an_image_on_trial_confirms_only_once_every_thruster_has_been_polled() {
    let flash = flashed();
    on_trial(&flash);
    let (own, shared) = (OwnImage::new(), Shared::new());
    let updating = OwnFlash::new(flash.clone());
    let mut bench = Bench::with(&own, &shared, &updating, 2, 0);
    bench.hear_operator(true);
    bench.run(Duration::from_secs(4));
    assert_eq!(state_of(&flash), State::Swap, "heard, but no thruster polled");
    let polled = |index: usize| {
        let health = LinkHealth {
            polls: 1,
            ..LinkHealth::default()
        };
        shared.thrusters[index]
            .sender()
            .send(ThrusterReport { health, status: None });
    };
    polled(0);
    bench.run(Duration::from_millis(300));
    assert_eq!(state_of(&flash), State::Swap, "one of two polled");
    polled(1);
    bench.run(Duration::from_millis(300));
    assert_eq!(state_of(&flash), State::Boot, "confirmed");
}

#[test]
fn the_previous_image_put_back_after_early_crashes_says_so_once_and_the_count_clears_after_the_window() {
    let flash = flashed();
    let (own, shared) = (OwnImage::new(), Shared::new());
    let updating = OwnFlash::new(flash.clone());
    let register = Cell::new(
        CrashCount {
            crashes: 0,
            restored: true,
        }
        .to_word(),
    );
    let mut bench = Bench::with(&own, &shared, &updating, 0, Kept(&register));
    bench.run(Duration::from_secs(2));
    assert!(texts(&bench.said()).is_empty(), "nobody heard yet");
    bench.hear_operator(true);
    bench.run(Duration::from_millis(300));
    assert_eq!(texts(&bench.said()), ["master.lbvu: 3 early crashes: 0.1.0 restored"]);
    assert_eq!(CrashCount::from_word(register.get()), CrashCount::default(), "told");
    // A watchdog reset counted at this start: the count stands through the early window, and clears after it.
    register.set(
        CrashCount {
            crashes: 2,
            restored: false,
        }
        .to_word(),
    );
    bench.run(EARLY_WINDOW - Duration::from_millis(2500));
    assert_eq!(CrashCount::from_word(register.get()).crashes, 2);
    bench.run(Duration::from_millis(300));
    assert_eq!(CrashCount::from_word(register.get()), CrashCount::default());
    assert!(texts(&bench.said()).is_empty(), "told once");
}

#[test]
fn an_image_on_trial_that_never_hears_the_operator_restarts_to_be_reverted() {
    let flash = flashed();
    on_trial(&flash);
    let (own, shared) = (OwnImage::new(), Shared::new());
    let updating = OwnFlash::new(flash.clone());
    let mut bench = Bench::new(&own, &shared, &updating);
    bench.said();
    bench.run(TRIAL_LIMIT - Duration::from_millis(200));
    assert!(bench.said().is_empty());
    bench.run(Duration::from_millis(300));
    let said = bench.said();
    assert_eq!(texts(&said), ["master.lbvu: no GCS heard on trial: reverting"]);
    assert!(matches!(said.last(), Some(Outgoing::Reboot)));
    assert_eq!(
        state_of(&flash),
        State::Swap,
        "still on trial: the bootloader reverts it at the restart"
    );
}

#[test]
fn without_a_bootloader_state_readable_master_images_are_refused() {
    let (own, shared) = (OwnImage::new(), Shared::new());
    // Before the task has looked at the flash.
    let header = parse_header(signed(Target::Master, 4096)[..HEADER_LEN].try_into().unwrap()).unwrap();
    assert_eq!(own.begin(&header), Err(NotTaken::NoBootloader));
    let _ = shared;
}

#[test]
fn a_refusal_found_in_a_page_of_an_upload_stopped_meanwhile_does_not_touch_the_next_one() {
    let flash = flashed();
    // DFU's erases take their 25 ms beside the code, so the task is still at the first page when the next
    // upload begins.
    flash.stall_cpu(&lbv_sim::Cpu::new(), lbv_sim::flash::FlashTiming::G474_DUAL_BANK);
    let (own, shared) = (OwnImage::new(), Shared::new());
    let updating = OwnFlash::new(flash.clone());
    let mut bench = Bench::new(&own, &shared, &updating);
    // A thruster's payload under a master header: its first page will be refused.
    let mut stranger = signed(Target::ThrusterSeabotix, 8000);
    stranger[5] = Target::Master.to_byte();
    own.begin(&parse_header(stranger[..HEADER_LEN].try_into().unwrap()).unwrap())
        .unwrap();
    for (index, piece) in stranger[HEADER_LEN..].chunks(DATA_LEN).take(9).enumerate() {
        own.write((index * DATA_LEN) as u32, piece).unwrap();
    }
    bench.run(Duration::from_millis(1));
    own.finish(false);
    let file = signed(Target::Master, 5000);
    bench.upload(&file).unwrap();
    // Three pages' erases and writes, 25 ms and more each.
    bench.run(Duration::from_millis(200));
    assert!(
        dfu(&flash, file.len() - HEADER_LEN) == file[HEADER_LEN..],
        "DFU holds the second upload"
    );
    own.apply(OPERATOR).unwrap();
    bench.run(Duration::from_millis(100));
    let texts = texts(&bench.said());
    assert!(texts[0].starts_with("master.lbvu: refused: "), "{texts:?}");
    assert_eq!(texts.last().unwrap(), "master.lbvu: signature good, restarting");
    assert_eq!(state_of(&flash), State::Swap);
}

/// Who applied the image, as the ticket's page notes it.
fn applier_in(page: &[u8]) -> Option<Sender> {
    let word = page[APPLIER_OFFSET as usize..][..8].try_into().unwrap();
    let [component, system, ..] = read_checked_word(word)?.to_le_bytes();
    Some(Sender { system, component })
}

/// The bytes of `span` in `flash`.
fn bytes_of(flash: &Stm32g4Flash, span: Span) -> Vec<u8> {
    let start = at(span) as usize;
    flash.contents()[start..start + span.length as usize].to_vec()
}

#[test]
fn nothing_reaches_dfu_once_the_image_is_marked_not_even_an_upload_begun_during_its_check() {
    let flash = flashed();
    let (own, shared) = (OwnImage::new(), Shared::new());
    let meddled = Meddled::new(&flash);
    let hook = meddled.on_read.clone();
    let updating = OwnFlash::new(meddled);
    let mut bench = Bench::new(&own, &shared, &updating);
    let file = signed(Target::Master, 5000);
    bench.upload(&file).unwrap();
    // During the signature check (between two of its chunks), another master upload begins, all of it arrives
    // (one page: the sink holds it for the task) and is applied: a forgery, the good image's bytes changed.
    let mut forged = signed(Target::Master, PAGE_BYTES);
    forged[HEADER_LEN + 0x400..HEADER_LEN + 0x500].fill(0);
    let forgery = parse_header(forged[..HEADER_LEN].try_into().unwrap()).unwrap();
    let during_check = at(MASTER_PARTITIONS.dfu) + 4 * HASH_CHUNK as u32;
    let own_ref = &own;
    let forged_payload = forged[HEADER_LEN..].to_vec();
    *hook.borrow_mut() = Some(Box::new(move |offset| {
        if offset == during_check {
            own_ref.begin(&forgery).unwrap();
            for (index, piece) in forged_payload.chunks(DATA_LEN).enumerate() {
                own_ref.write((index * DATA_LEN) as u32, piece).unwrap();
            }
            own_ref.finish(true);
            // No second apply starts while one runs: it is answered as the one under way.
            assert_eq!(own_ref.apply(OPERATOR), Err(NotTaken::Applying(OPERATOR)));
        }
    }));
    own.apply(OPERATOR).unwrap();
    bench.run(Duration::from_millis(500));
    *hook.borrow_mut() = None;
    assert_eq!(state_of(&flash), State::Swap, "the good image is marked");
    assert_eq!(
        dfu(&flash, file.len() - HEADER_LEN),
        file[HEADER_LEN..],
        "DFU holds the image marked, not a byte of the forgery"
    );
    let said = bench.said();
    assert_eq!(texts(&said), ["master.lbvu: signature good, restarting"]);
    assert!(matches!(said.last(), Some(Outgoing::Reboot)), "{said:?}");
    // Latched until the restart: no upload begins, and the update server is told to change nothing.
    assert!(own.marked() && shared.restarting.load(Ordering::Relaxed));
    assert_eq!(own.begin(&forgery), Err(NotTaken::Restarting));
    assert_eq!(own.write(0, &[0; 8]), Err(NotTaken::Restarting));
    assert_eq!(own.apply(OPERATOR), Err(NotTaken::Restarting));
    let erases = flash.stats().erases;
    bench.run(Duration::from_millis(500));
    assert_eq!(texts(&bench.said()), ["master.lbvu: marked for the swap: restarting"]);
    assert_eq!(flash.stats().erases, erases, "no page erased after the mark");
    assert_eq!(dfu(&flash, file.len() - HEADER_LEN), file[HEADER_LEN..]);
}

#[test]
fn the_apply_hands_the_bootloader_its_ticket_before_it_marks_the_image() {
    let flash = flashed();
    // A verdict on an image marked before: the new ticket's page starts afresh.
    let ticket_page = at(MASTER_PARTITIONS.ticket());
    let mut writer = flash.clone();
    embassy_futures::block_on(writer.write(ticket_page + VERDICT_OFFSET, &Verdict::Signature.to_word())).unwrap();
    let (own, shared) = (OwnImage::new(), Shared::new());
    let updating = OwnFlash::new(flash.clone());
    let mut bench = Bench::new(&own, &shared, &updating);
    let file = signed(Target::Master, 5000);
    bench.upload(&file).unwrap();
    own.apply(OPERATOR).unwrap();
    bench.run(Duration::from_millis(100));
    assert_eq!(state_of(&flash), State::Swap);
    let page = bytes_of(&flash, MASTER_PARTITIONS.ticket());
    let ticket = Ticket::parse(&page).expect("a ticket");
    assert_eq!(ticket.payload_len, (file.len() - HEADER_LEN) as u32);
    assert_eq!(ticket.signature[..], file[16..HEADER_LEN]);
    assert_eq!(applier_in(&page), Some(OPERATOR), "who applied it, beside the ticket");
    assert!(
        page[TICKET_LEN..APPLIER_OFFSET as usize]
            .iter()
            .all(|byte| *byte == 0xFF),
        "no verdict left from before"
    );
}

#[test]
fn a_ticket_or_a_state_the_flash_did_not_take_fails_the_apply_and_nothing_is_latched() {
    for (lost, why) in [
        (
            MASTER_PARTITIONS.ticket(),
            "master.lbvu: ticket not written: send it again",
        ),
        (MASTER_PARTITIONS.state, "master.lbvu: state not written: send it again"),
    ] {
        let flash = flashed();
        let (own, shared) = (OwnImage::new(), Shared::new());
        let mut meddled = Meddled::new(&flash);
        // The driver answers Ok, and the flash keeps what it held.
        meddled.lost = at(lost)..at(lost) + lost.length;
        let updating = OwnFlash::new(meddled);
        let mut bench = Bench::new(&own, &shared, &updating);
        let file = signed(Target::Master, 5000);
        bench.upload(&file).unwrap();
        own.apply(OPERATOR).unwrap();
        bench.run(Duration::from_millis(100));
        let said = bench.said();
        assert_eq!(texts(&said), [why]);
        assert_eq!(acks(&said), [AckResult::Failed]);
        assert!(!said.iter().any(|out| matches!(out, Outgoing::Reboot)));
        assert_eq!(state_of(&flash), State::Boot);
        assert!(!own.marked() && !shared.restarting.load(Ordering::Relaxed));
        // It may be sent again.
        drop(bench);
        let mut bench = Bench::new(&own, &shared, &updating);
        bench.upload(&file).unwrap();
    }
}

/// The ticket page as a bootloader that refused the image marked leaves it: the ticket, then its verdict `code`.
fn refused_by_the_bootloader(flash: &Stm32g4Flash, code: u32) {
    let ticket_page = at(MASTER_PARTITIONS.ticket());
    let ticket = Ticket {
        payload_len: 5000,
        signature: [0x5A; 64],
    };
    let mut writer = flash.clone();
    embassy_futures::block_on(async {
        writer.write(ticket_page, &ticket.to_bytes()).await.unwrap();
        writer
            .write(ticket_page + VERDICT_OFFSET, &checked_word(code))
            .await
            .unwrap();
    });
}

#[test]
fn the_bootloaders_refusal_is_told_to_the_operator_once() {
    let flash = flashed();
    refused_by_the_bootloader(&flash, Verdict::Signature.code().into());
    let told = at(MASTER_PARTITIONS.ticket()) + TOLD_OFFSET;
    {
        let (own, shared) = (OwnImage::new(), Shared::new());
        let updating = OwnFlash::new(flash.clone());
        let mut bench = Bench::new(&own, &shared, &updating);
        // Nobody listens yet: kept for when the operator is heard.
        bench.run(Duration::from_secs(2));
        assert!(bench.said().is_empty());
        bench.hear_operator(true);
        bench.run(Duration::from_millis(200));
        let said = bench.said();
        assert_eq!(texts(&said), ["master.lbvu: refused by the bootloader: signature"]);
        assert!(matches!(
            said.as_slice(),
            [
                Outgoing::Text(Severity::Warning, _),
                Outgoing::CommandAck {
                    command: MAV_CMD_LBV_APPLY_UPDATE,
                    result: AckResult::Failed,
                    to: Sender { system: 255, .. }
                }
            ]
        ));
        let word: [u8; 8] = flash.contents()[told as usize..told as usize + 8].try_into().unwrap();
        assert!(read_checked_word(word).is_some(), "noted as told");
        bench.run(Duration::from_secs(1));
        assert!(bench.said().is_empty(), "told once");
    }
    // The next start has nothing to tell.
    let (own, shared) = (OwnImage::new(), Shared::new());
    let updating = OwnFlash::new(flash.clone());
    let mut bench = Bench::new(&own, &shared, &updating);
    bench.hear_operator(true);
    bench.run(Duration::from_secs(1));
    assert!(bench.said().is_empty());
}

#[test]
fn on_a_flash_not_in_dual_bank_mode_an_upload_is_refused_and_nothing_is_written() {
    // On trial, and a verdict of the bootloader's to tell: as far as reading goes, the flash is as it should be.
    let flash = flashed();
    on_trial(&flash);
    refused_by_the_bootloader(&flash, Verdict::Signature.code().into());
    let before = flash.stats();
    let (own, shared) = (OwnImage::new(), Shared::new());
    own.set_layout_ok(false);
    let updating = OwnFlash::new(flash.clone());
    let mut bench = Bench::new(&own, &shared, &updating);
    assert!(bench.said().is_empty(), "no trial: it could neither confirm nor revert");
    assert_eq!(own.hold(), None, "nothing to hold arming for");
    let file = signed(Target::Master, 4096);
    assert_eq!(bench.upload(&file), Err(NotTaken::Layout));
    bench.run(Duration::from_millis(10));
    assert_eq!(texts(&bench.said()), ["master.lbvu: refused: flash not dual-bank"]);
    assert_eq!(own.apply(OPERATOR), Err(NotTaken::Nothing));
    // Heard past the trial's limit: the verdict is told (and not noted as told), nothing confirmed, no restart.
    bench.hear_operator(true);
    bench.run(TRIAL_LIMIT + Duration::from_secs(1));
    let said = bench.said();
    assert_eq!(texts(&said), ["master.lbvu: refused by the bootloader: signature"]);
    assert!(!said.iter().any(|out| matches!(out, Outgoing::Reboot)));
    assert_eq!(state_of(&flash), State::Swap);
    assert_eq!(flash.stats(), before, "nothing erased or programmed");
    assert_eq!(bench.upload(&file), Err(NotTaken::Layout), "nor later");
}

#[test]
fn a_verdict_too_long_for_one_text_or_unknown_is_told_whole() {
    for (code, said) in [
        (
            Verdict::Counter.code().into(),
            &[
                "master.lbvu: refused by the bootloader:",
                "master.lbvu: security counter below the vehicle's",
            ][..],
        ),
        (14, &["master.lbvu: refused by the bootloader (code 14)"]),
    ] {
        let flash = flashed();
        refused_by_the_bootloader(&flash, code);
        // The first told slot torn by a power cut: the word goes in the next.
        let told = (at(MASTER_PARTITIONS.ticket()) + TOLD_OFFSET) as usize;
        let mut torn = checked_word(code);
        // A bit that was to be programmed to 0, still erased.
        torn[1] |= 0x80;
        embassy_futures::block_on(flash.clone().write(told as u32, &torn)).unwrap();
        let (own, shared) = (OwnImage::new(), Shared::new());
        let updating = OwnFlash::new(flash.clone());
        let mut bench = Bench::new(&own, &shared, &updating);
        bench.hear_operator(true);
        bench.run(Duration::from_millis(200));
        assert_eq!(texts(&bench.said()), said, "code {code}");
        let word: [u8; 8] = flash.contents()[told + 8..told + 16].try_into().unwrap();
        assert_eq!(read_checked_word(word), Some(code));
    }
}

#[test]
fn an_image_older_than_the_running_one_or_below_its_counter_is_refused_at_its_first_page() {
    let running = ImageInfo::new(Target::Master, Version::new(0, 3, 0)).with_security_counter(2);
    let at_version =
        |minor, counter| ImageInfo::new(Target::Master, Version::new(0, minor, 0)).with_security_counter(counter);
    for (image, refused) in [
        (at_version(2, 2), Some("master.lbvu: refused: 0.2.0 is older than the")),
        (
            at_version(4, 1),
            Some("master.lbvu: refused: security counter 1 is below"),
        ),
        (
            at_version(2, 1).with_rollback(true),
            Some("master.lbvu: refused: security counter 1 is below"),
        ),
        // Signed to go back, at the counter: taken; so are a newer image and the same one again.
        (at_version(2, 2).with_rollback(true), None),
        (at_version(4, 2), None),
        (running, None),
    ] {
        let flash = flashed_with(running);
        let (own, shared) = (OwnImage::new(), Shared::new());
        let updating = OwnFlash::new(flash.clone());
        let mut bench = Bench::new(&own, &shared, &updating);
        let file = signed_as(image, 5000);
        let uploaded = bench.upload(&file);
        let said = texts(&bench.said());
        match refused {
            Some(refused) => {
                assert_eq!(uploaded, Err(NotTaken::Refused), "{image:?}");
                assert!(said[0].starts_with(refused), "{image:?}: {said:?}");
                // Whole, in at most two texts: nothing cut at the end.
                assert!(
                    said.len() <= 2 && said.last().is_some_and(|text| text.len() < 50),
                    "{said:?}"
                );
                assert_eq!(own.apply(OPERATOR), Err(NotTaken::Nothing));
            }
            None => {
                assert_eq!((uploaded, said.len()), (Ok(()), 0), "{image:?}: {said:?}");
                own.apply(OPERATOR).unwrap();
                bench.run(Duration::from_millis(100));
                assert_eq!(state_of(&flash), State::Swap, "{image:?}");
            }
        }
    }
}

#[test]
fn a_verdict_not_told_before_the_next_image_is_marked_leaves_the_new_tickets_page_alone() {
    let flash = flashed();
    refused_by_the_bootloader(&flash, Verdict::Signature.code().into());
    let (own, shared) = (OwnImage::new(), Shared::new());
    let updating = OwnFlash::new(flash.clone());
    let mut bench = Bench::new(&own, &shared, &updating);
    // Applied before the operator's heartbeat was heard: the verdict is still to tell.
    let file = signed(Target::Master, 5000);
    bench.upload(&file).unwrap();
    own.apply(OPERATOR).unwrap();
    bench.run(Duration::from_millis(100));
    assert_eq!(state_of(&flash), State::Swap);
    bench.hear_operator(true);
    bench.run(Duration::from_millis(500));
    let said = texts(&bench.said());
    assert_eq!(said, ["master.lbvu: signature good, restarting"]);
    // The page holds the new ticket and nothing after it but who applied it: the bootloader's verdict on this image
    // will be told.
    let page = bytes_of(&flash, MASTER_PARTITIONS.ticket());
    assert!(Ticket::parse(&page).is_some());
    assert!(
        page[TICKET_LEN..APPLIER_OFFSET as usize]
            .iter()
            .all(|byte| *byte == 0xFF)
    );
    assert_eq!(applier_in(&page), Some(OPERATOR));
    assert!(page[APPLIER_OFFSET as usize + 8..].iter().all(|byte| *byte == 0xFF));
}

#[test]
fn the_vehicle_is_held_from_arming_from_the_apply_to_the_restart_and_a_second_apply_starts_nothing() {
    let flash = flashed();
    let (own, shared) = (OwnImage::new(), Shared::new());
    let meddled = Meddled::new(&flash);
    let hook = meddled.on_read.clone();
    let updating = OwnFlash::new(meddled);
    let mut bench = Bench::new(&own, &shared, &updating);
    assert_eq!((own.hold(), shared.holds.get()), (None, None));
    // A bad signature first: held during its check, free again after it.
    let mut bad = signed(Target::Master, 5000);
    bad[HEADER_LEN + 3000] ^= 0x10;
    bench.upload(&bad).unwrap();
    own.apply(OPERATOR).unwrap();
    assert_eq!(
        own.hold(),
        Some(UpdateHold::MasterApplying),
        "from the moment it is taken"
    );
    bench.run(Duration::from_millis(200));
    assert_eq!(acks(&bench.said()), [AckResult::Failed]);
    assert_eq!((own.hold(), shared.holds.get()), (None, None));

    // A good one: during its check (between two of its chunks) the vehicle is held, and the same apply sent again,
    // or another's, starts nothing: it is answered as the one under way.
    let file = signed(Target::Master, 5000);
    bench.upload(&file).unwrap();
    let during_check = at(MASTER_PARTITIONS.dfu) + 4 * HASH_CHUNK as u32;
    let seen = Rc::new(RefCell::new(Vec::new()));
    let (own_ref, shared_ref, seen_ref) = (&own, &shared, seen.clone());
    let stranger = Sender {
        system: OPERATOR.system,
        component: 1,
    };
    *hook.borrow_mut() = Some(Box::new(move |offset| {
        if offset == during_check {
            seen_ref
                .borrow_mut()
                .push((shared_ref.holds.get(), own_ref.apply(OPERATOR), own_ref.apply(stranger)));
        }
    }));
    own.apply(OPERATOR).unwrap();
    // Applied again before the task took it: the same.
    assert_eq!(own.apply(OPERATOR), Err(NotTaken::Applying(OPERATOR)));
    bench.run(Duration::from_millis(500));
    *hook.borrow_mut() = None;
    assert_eq!(
        *seen.borrow(),
        [(
            Some(UpdateHold::MasterApplying),
            Err(NotTaken::Applying(OPERATOR)),
            Err(NotTaken::Applying(OPERATOR))
        )],
        "read once: one check"
    );
    let said = bench.said();
    assert_eq!(texts(&said), ["master.lbvu: signature good, restarting"]);
    assert!(acks(&said).is_empty(), "the final answer comes after the restart");
    // Marked: held until the restart.
    assert_eq!(own.hold(), Some(UpdateHold::MasterRestarting));
    assert_eq!(shared.holds.get(), Some(UpdateHold::MasterRestarting));
}

#[test]
fn an_image_on_trial_holds_the_vehicle_until_it_confirms_and_answers_the_component_that_applied_it() {
    let flash = flashed();
    let applier = Sender {
        system: 255,
        component: 191,
    };
    {
        let (own, shared) = (OwnImage::new(), Shared::new());
        let updating = OwnFlash::new(flash.clone());
        let mut bench = Bench::new(&own, &shared, &updating);
        bench.upload(&signed(Target::Master, 5000)).unwrap();
        own.apply(applier).unwrap();
        bench.run(Duration::from_millis(100));
        assert_eq!(state_of(&flash), State::Swap);
    }
    // The restart: the bootloader swaps it in (here, only the state says so) and it runs on trial.
    let (own, shared) = (OwnImage::new(), Shared::new());
    let updating = OwnFlash::new(flash.clone());
    let mut bench = Bench::new(&own, &shared, &updating);
    assert_eq!(shared.holds.get(), Some(UpdateHold::MasterOnTrial));
    bench.said();
    bench.hear_operator(true);
    bench.run(Duration::from_millis(3200));
    assert_eq!(state_of(&flash), State::Boot);
    let said = bench.said();
    assert_eq!(texts(&said), ["master.lbvu: 0.1.0 confirmed"]);
    assert_eq!(
        said.last(),
        Some(&Outgoing::CommandAck {
            command: MAV_CMD_LBV_APPLY_UPDATE,
            result: AckResult::Accepted,
            to: applier
        }),
        "to the component that applied it, not to component 0"
    );
    assert_eq!(shared.holds.get(), None);
}

#[test]
fn the_trial_limit_never_restarts_an_armed_vehicle_it_waits_for_the_disarm() {
    let flash = flashed();
    on_trial(&flash);
    let (own, shared) = (OwnImage::new(), Shared::new());
    // Armed before the task has read the bootloader's state (an arm the vehicle task took at the very start, had
    // the start not held it: see the node's test of that), the operator not heard for 3 s without a gap.
    let updating = OwnFlash::new(flash.clone());
    shared.vehicle.sender().send(VehicleState {
        armed: true,
        console_alive: false,
        armable: false,
        operator: OPERATOR.system,
        ..VehicleState::READY
    });
    let mut bench = Bench::new(&own, &shared, &updating);
    assert_eq!(texts(&bench.said()), ["master.lbvu: runs 0.1.0, on trial"]);
    bench.run(TRIAL_LIMIT + Duration::from_secs(30));
    let said = bench.said();
    assert_eq!(texts(&said), ["master.lbvu: reverting once disarmed"], "said once");
    assert!(!said.iter().any(|out| matches!(out, Outgoing::Reboot)));
    // Disarmed (the operator's heartbeat lost, say): now it restarts, and the bootloader reverts the image.
    bench.hear_operator(false);
    bench.run(Duration::from_millis(200));
    let said = bench.said();
    assert_eq!(texts(&said), ["master.lbvu: no GCS heard on trial: reverting"]);
    assert!(matches!(said.last(), Some(Outgoing::Reboot)));
    assert_eq!(state_of(&flash), State::Swap);
}

#[test]
fn the_running_image_is_known_once_the_task_has_read_it() {
    let (own, shared) = (OwnImage::new(), Shared::new());
    assert_eq!(own.running(), Running::default(), "not read yet");
    let flash = flashed();
    on_trial(&flash);
    let updating = OwnFlash::new(flash.clone());
    let mut bench = Bench::new(&own, &shared, &updating);
    let version = Some(Version::new(0, 1, 0).to_bytes());
    let state = ImageState::OnTrial;
    assert_eq!(own.running(), Running { version, state });
    bench.hear_operator(true);
    bench.run(Duration::from_millis(3300));
    assert_eq!(own.running().state, ImageState::Confirmed);
    own.mark();
    assert_eq!(own.running().state, ImageState::Marked);
}
