//! The master's own update on lbv-sim's G474 flash, on virtual time: an image written page by page into DFU and
//! marked for the swap when its signature is good; refused, with its reason, when its signature is bad, its info is
//! not a master's, it is too large or the running image is on trial; and the trial confirmed once the operator is
//! heard, or given up (back to the previous image) when not.

use std::vec::Vec;

use embassy_time::Duration;
use lbv_sim::Executor;
use lbv_sim::clock::{self, Clock};
use lbv_sim::flash::Stm32g4Flash;
use update_image::{INFO_OFFSET, ImageInfo, Version, key_from_hex};

use super::*;
use crate::shared::VehicleState;
use crate::sim::master_flash;
use crate::update::parse_header;

const OPERATOR: Sender = Sender {
    system: 255,
    component: 190,
};

/// A signed update file of `len` payload bytes for `target`, version 0.2.0, with the development key.
fn signed(target: Target, len: usize) -> Vec<u8> {
    let mut payload: Vec<u8> = (0..len as u32)
        .map(|n| (n.wrapping_mul(2_654_435_761) >> 9) as u8)
        .collect();
    let info = ImageInfo::new(target, Version::new(0, 2, 0)).to_bytes();
    payload[INFO_OFFSET..INFO_OFFSET + info.len()].copy_from_slice(&info);
    let seed = key_from_hex(include_str!("../../../keys/dev.key")).unwrap();
    update_image::sign(&payload, &seed).unwrap()
}

/// The flash as a probe leaves it: the running image (0.1.0) in ACTIVE, the bootloader's state erased.
fn flashed() -> Stm32g4Flash {
    let mut flash = master_flash();
    let info = ImageInfo::new(Target::Master, Version::new(0, 1, 0)).to_bytes();
    let active = MASTER_PARTITIONS.active.origin - FLASH_ORIGIN;
    embassy_futures::block_on(flash.write(active + IMAGE_INFO_OFFSET, &info)).unwrap();
    flash
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

/// The console's side and what the master said.
struct Bench<'a> {
    clock: Clock,
    executor: Executor<'a>,
    own: &'a OwnImage,
    shared: &'a Shared,
}

impl<'a> Bench<'a> {
    fn new(own: &'a OwnImage, shared: &'a Shared, updating: &'a OwnFlash<Stm32g4Flash>) -> Self {
        let clock = clock::take();
        let mut executor = Executor::new();
        executor.spawn(async move {
            own_image_task(updating, own, shared).await;
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
            armed: false,
            console_alive: alive,
            refused: 0,
            armable: true,
            failsafe: false,
            param_type_mismatches: 0,
            operator: OPERATOR.system,
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
    assert_eq!(texts(&said).len(), 1, "{said:?}");
    assert!(texts(&said)[0].starts_with("master.lbvu: refused: "), "{said:?}");
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
    assert_eq!(texts(&bench.said()), ["master.lbvu: larger than ACTIVE (238 KiB)"]);
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
    assert_eq!(texts[1..], ["master.lbvu: signature good, restarting"]);
    assert_eq!(state_of(&flash), State::Swap);
}
