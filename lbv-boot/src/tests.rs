//! The bootloader's [`prepare`] and embassy-boot's own updater (the application's side) on lbv-sim's G4 flash, with
//! the thruster's partitions at their real offsets: a swap, a confirmation, a revert, and a power cut at every point
//! of each, checked byte for byte.
//!
//! What the flash model does with a power cut: the erase or program under way stops at that byte, and a double word
//! it leaves half done reads back as its cells hold it, every read recorded as an ECC double error (on the chip:
//! FLASH_ECCR.ECCD and an NMI, which the bootloader clears and returns from, `stm32.rs`). embassy-boot writes a
//! word of its state at a time: a torn magic word is no magic (the state reads `Boot`), a torn progress word has
//! erased bytes left (its step is done again), and a torn progress-validity word is not erased (the progress is
//! taken as complete). The tests below show where each of these leaves the images.

use embassy_boot::{BlockingFirmwareState, BlockingFirmwareUpdater, FirmwareUpdaterConfig};
use embedded_storage::nor_flash::NorFlash;
use g431_hw::memory::THRUSTER_PARTITIONS as LAYOUT;
use lbv_sim::flash::{FlashTiming, Stm32g4Flash};
use update_image::{Header, INFO_FORMAT, Target, Version, image_record};

use super::*;
use update_image::{PREVIOUS_LEN, PREVIOUS_OFFSET};

const PAGE_BYTES: usize = PAGE as usize;
const ACTIVE_BYTES: usize = LAYOUT.active.length as usize;
const ACTIVE_PAGES: usize = ACTIVE_BYTES / PAGE_BYTES;
/// What one page's copy costs in the flash's bytes: its erase, its programming and its progress word.
const COPY_BYTES: usize = 2 * PAGE_BYTES + 8;
/// What embassy-boot's `set_magic` (mark updated or booted, and the end of a revert) costs: the progress-validity
/// word, the state page's erase and the magic word.
const MAGIC_BYTES: usize = 8 + PAGE_BYTES + 8;

/// The secret key the tests sign with, and its public half, which every image here embeds.
const SEED: [u8; 32] = [7; 32];
/// Another key.
const OTHER_SEED: [u8; 32] = [9; 32];

/// What an image says of itself: its version, its security counter, whether it was signed to go back.
#[derive(Debug, Clone, Copy)]
struct Made {
    version: Version,
    counter: u32,
    rollback: bool,
    target: Target,
    /// Its payload's length: the image's bytes past it are erased, as a signed payload leaves them.
    len: usize,
}

const MADE: Made = Made {
    version: Version::new(0, 1, 0),
    counter: 0,
    rollback: false,
    target: Target::ThrusterSeabotix,
    len: ACTIVE_BYTES,
};

fn version(minor: u8) -> Made {
    Made {
        version: Version::new(0, minor, 0),
        ..MADE
    }
}

/// A made-up image of ACTIVE's size whose bytes `seed` picks (xorshift32), with its image info and the tests' key
/// where an image keeps them: two seeds differ in every page.
fn image(seed: u32) -> Vec<u8> {
    made(seed, MADE)
}

fn made(seed: u32, made: Made) -> Vec<u8> {
    let mut x = seed.wrapping_mul(0x9E37_79B9) | 1;
    let mut bytes: Vec<u8> = (0..ACTIVE_BYTES)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x as u8
        })
        .collect();
    let info = ImageInfo::new(made.target, made.version)
        .with_security_counter(made.counter)
        .with_rollback(made.rollback);
    let record = image_record(info, &update_image::public_key(&SEED));
    bytes[INFO_OFFSET..][..record.len()].copy_from_slice(&record);
    bytes[made.len..].fill(0xFF);
    bytes
}

/// The signature `seed` makes over an image's payload, its first `len` bytes (update-image's signing, ed25519-dalek:
/// not the ed25519 the bootloader checks with).
fn signature(payload: &[u8], seed: &[u8; 32]) -> [u8; 64] {
    let file = update_image::sign(payload, seed).unwrap();
    Header::parse(&file).unwrap().signature
}

/// The pages in which two images differ (an assertion on the images themselves would print 50 KiB).
fn pages_differing(actual: &[u8], expected: &[u8]) -> Vec<usize> {
    let pages = actual.chunks(PAGE_BYTES).zip(expected.chunks(PAGE_BYTES));
    let mut differing: Vec<usize> = pages
        .enumerate()
        .filter(|(_, (a, b))| a != b)
        .map(|(page, _)| page)
        .collect();
    if actual.len() != expected.len() {
        differing.push(usize::MAX);
    }
    differing
}

macro_rules! assert_image {
    ($actual:expr, $expected:expr, $($what:tt)+) => {
        let differing = pages_differing(&$actual, &$expected);
        assert!(differing.is_empty(), "{}: pages {differing:?} differ", format_args!($($what)+));
    };
}

fn offset(span: Span) -> usize {
    (span.origin - FLASH_ORIGIN) as usize
}

/// A chip's flash, erased but for `old` in ACTIVE, as a probe flashes it.
fn flashed(old: &[u8]) -> Stm32g4Flash {
    let mut flash = Stm32g4Flash::new((LAYOUT.chip.flash.length / PAGE) as usize);
    flash.write(offset(LAYOUT.active) as u32, old).unwrap();
    flash
}

/// Another chip's flash with the same contents, none of its history.
fn copy(flash: &Stm32g4Flash) -> Stm32g4Flash {
    let mut copy = Stm32g4Flash::new((LAYOUT.chip.flash.length / PAGE) as usize);
    copy.write(0, &flash.contents()).unwrap();
    copy
}

fn bytes(flash: &Stm32g4Flash, span: Span) -> Vec<u8> {
    flash.contents()[offset(span)..][..span.length as usize].to_vec()
}

fn active(flash: &Stm32g4Flash) -> Vec<u8> {
    bytes(flash, LAYOUT.active)
}

/// DFU's pages 1..=25: where a swap leaves the image it took out of ACTIVE.
fn dfu_shifted(flash: &Stm32g4Flash) -> Vec<u8> {
    bytes(flash, LAYOUT.dfu)[PAGE_BYTES..][..ACTIVE_BYTES].to_vec()
}

/// The bytes the flash has erased or programmed so far: what `cut_power_after` counts.
fn spent(flash: &Stm32g4Flash) -> usize {
    let stats = flash.stats();
    (stats.erases * PAGE as u64 + stats.programmed) as usize
}

/// A reset: the bootloader on the flash as the last power-down left it.
fn reset(flash: &Stm32g4Flash) -> Outcome {
    reset_after_crashes(flash, 0)
}

/// A reset after `crashes` early crashes in a row (the binding's count at this start).
fn reset_after_crashes(flash: &Stm32g4Flash, crashes: u8) -> Outcome {
    let count = CrashCount {
        crashes,
        restored: false,
    };
    prepare(flash.clone(), &LAYOUT, count, || {})
}

/// Resets, power restored before each, until the bootloader prepares (at most a few: a cut stops at most one).
fn reset_until_prepared(flash: &Stm32g4Flash) -> State {
    for _ in 0..3 {
        flash.power_on();
        if let Outcome::Prepared { state, .. } = reset(flash) {
            return state;
        }
    }
    panic!("the bootloader never prepared: {:?}", reset(flash));
}

/// Power back on and reset, with the power going again after `cut` bytes: the state prepared if the reset
/// finished before the cut came (which is then disarmed).
fn cut_again(flash: &Stm32g4Flash, cut: usize) -> Option<State> {
    flash.power_on();
    flash.cut_power_after(cut);
    let outcome = reset(flash);
    flash.power_on();
    match outcome {
        Outcome::Prepared { state, .. } => Some(state),
        Outcome::Refused { .. } | Outcome::Restored { .. } | Outcome::Failed(_) => None,
    }
}

/// The application's side of embassy-boot on the same flash: the state partition through
/// `BlockingFirmwareState` (whose `mark_updated` is there whatever signature features the build has).
fn with_state<R>(
    flash: &Stm32g4Flash,
    f: impl FnOnce(&mut BlockingFirmwareState<'_, Partition<'_, Stm32g4Flash>>) -> R,
) -> R {
    let shared = Mutex::new(RefCell::new(flash.clone()));
    let mut aligned = [0; 8];
    let mut state = BlockingFirmwareState::new(partitions(&shared, &LAYOUT).state, &mut aligned);
    f(&mut state)
}

fn state(flash: &Stm32g4Flash) -> State {
    with_state(flash, |state| state.get_state()).unwrap()
}

/// The running image writes `new` into DFU with embassy-boot's updater (in 1 KiB pieces, as it would arrive).
fn write_dfu(flash: &Stm32g4Flash, new: &[u8]) {
    let shared = Mutex::new(RefCell::new(flash.clone()));
    let config = partitions(&shared, &LAYOUT);
    let mut aligned = [0; 8];
    let mut updater = BlockingFirmwareUpdater::new(
        FirmwareUpdaterConfig {
            dfu: config.dfu,
            state: config.state,
        },
        &mut aligned,
    );
    for (index, piece) in new.chunks(1024).enumerate() {
        updater.write_firmware(index * 1024, piece).unwrap();
    }
}

/// The running image writes the ticket of a payload of `len` bytes signed `signature` into the record's first page.
fn write_ticket(flash: &Stm32g4Flash, payload_len: u32, signature: [u8; 64]) {
    let shared = Mutex::new(RefCell::new(flash.clone()));
    let mut page = partition(&shared, LAYOUT.ticket());
    page.erase(0, PAGE).unwrap();
    page.write(TICKET_OFFSET, &Ticket { payload_len, signature }.to_bytes())
        .unwrap();
}

fn mark_updated(flash: &Stm32g4Flash) {
    with_state(flash, |state| state.mark_updated()).unwrap();
}

/// The running image receives `new`, signed with the tests' key over its first `len` bytes: it writes it to DFU,
/// writes its ticket, and marks it for the swap.
fn receive_signed(flash: &Stm32g4Flash, new: &[u8], len: usize, seed: &[u8; 32]) {
    write_dfu(flash, new);
    write_ticket(flash, len as u32, signature(&new[..len], seed));
    mark_updated(flash);
}

/// The running image receives `new`, a payload of ACTIVE's whole length signed with the tests' key.
fn receive(flash: &Stm32g4Flash, new: &[u8]) {
    receive_signed(flash, new, new.len(), &SEED);
}

fn mark_booted(flash: &Stm32g4Flash) {
    with_state(flash, |state| state.mark_booted()).unwrap();
}

/// The verdict the bootloader left in the record, if any.
fn verdict(flash: &Stm32g4Flash) -> Option<Verdict> {
    let page = bytes(flash, LAYOUT.ticket());
    Verdict::from_slots(&update_image::Slots(
        page[VERDICT_OFFSET as usize..][..64].try_into().unwrap(),
    ))
}

/// The counter the bootloader keeps.
fn counter(flash: &Stm32g4Flash) -> Option<u32> {
    let shared = Mutex::new(RefCell::new(flash.clone()));
    stored_counter(&mut partition(&shared, LAYOUT.counter())).unwrap()
}

/// The flash as it stands when the bootloader is about to swap: `old` in ACTIVE, `new` in DFU, marked updated.
fn ready(old: &[u8], new: &[u8]) -> Stm32g4Flash {
    let flash = flashed(old);
    receive(&flash, new);
    flash
}

fn prepared(state: State) -> Outcome {
    Outcome::Prepared { state, attempt: 1 }
}

fn refused(verdict: Verdict) -> Outcome {
    Outcome::Refused { verdict, attempt: 1 }
}

#[test]
fn a_new_image_is_swapped_in_and_stays_once_it_marks_itself_booted() {
    let (old, new) = (image(1), image(2));
    let flash = flashed(&old);
    assert_eq!(reset(&flash), prepared(State::Boot), "nothing to do");
    assert_image!(active(&flash), old, "active");

    receive(&flash, &new);
    assert_eq!(state(&flash), State::Swap);
    assert_eq!(reset(&flash), prepared(State::Swap));
    assert_image!(active(&flash), new, "active");
    assert_image!(dfu_shifted(&flash), old, "the old image waits in DFU, one page up");
    assert_eq!(state(&flash), State::Swap, "on trial");
    assert_eq!(verdict(&flash), None);

    mark_booted(&flash);
    assert_eq!(state(&flash), State::Boot);
    for _ in 0..2 {
        assert_eq!(reset(&flash), prepared(State::Boot));
        assert_image!(active(&flash), new, "active");
    }
    assert_eq!(
        flash.ecc_error_offsets(),
        Vec::<u32>::new(),
        "no power cut, no torn word"
    );
}

#[test]
fn a_new_image_that_never_marks_itself_booted_is_reverted_at_the_next_reset() {
    let (old, new) = (image(3), image(4));
    let flash = ready(&old, &new);
    assert_eq!(reset(&flash), prepared(State::Swap));
    assert_image!(active(&flash), new, "active");
    // It hangs, or the watchdog bites, before it marks itself booted: the next reset reverts.
    assert_eq!(
        reset(&flash),
        prepared(State::Swap),
        "the state embassy-boot read before it reverted"
    );
    assert_image!(active(&flash), old, "active");
    assert_eq!(state(&flash), State::Revert);
    assert_eq!(
        bytes(&flash, LAYOUT.dfu)[..ACTIVE_BYTES],
        new[..],
        "the rejected image is back in DFU, in place"
    );
    assert_eq!(reset(&flash), prepared(State::Revert), "and it stays reverted");
    assert_image!(active(&flash), old, "active");
    // The old image can take an update again.
    receive(&flash, &new);
    assert_eq!(reset(&flash), prepared(State::Swap));
    assert_image!(active(&flash), new, "active");
}

/// A refused update leaves the image that ran, its verdict in the record, and the mark cleared: the next start has
/// nothing to do.
fn assert_refused(flash: &Stm32g4Flash, old: &[u8], why: Verdict) {
    assert_eq!(reset(flash), refused(why));
    assert_image!(active(flash), old, "{why:?}: the image that ran");
    assert_eq!(verdict(flash), Some(why));
    assert_eq!(state(flash), State::Boot, "{why:?}: the mark cleared");
    assert_eq!(reset(flash), prepared(State::Boot), "{why:?}: and nothing left to do");
    assert_image!(active(flash), old, "{why:?}");
    assert_eq!(verdict(flash), Some(why), "{why:?}: kept for the image to tell");
}

#[test]
fn an_image_whose_signature_does_not_check_is_not_swapped_in() {
    let (old, new) = (image(20), image(21));
    // One bit of DFU flipped after signing: a forged page written after the application checked it.
    let flash = flashed(&old);
    let mut forged = new.clone();
    forged[PAGE_BYTES * 3 + 17] ^= 0x10;
    write_dfu(&flash, &forged);
    write_ticket(&flash, new.len() as u32, signature(&new, &SEED));
    mark_updated(&flash);
    assert_refused(&flash, &old, Verdict::Signature);

    // Signed with another key than the running image embeds.
    let flash = flashed(&old);
    receive_signed(&flash, &new, new.len(), &OTHER_SEED);
    assert_refused(&flash, &old, Verdict::Signature);

    // The right one after a refusal: taken.
    receive(&flash, &new);
    assert_eq!(reset(&flash), prepared(State::Swap));
    assert_image!(active(&flash), new, "active");
}

#[test]
fn nothing_past_the_payload_reaches_active() {
    let old = image(22);
    let len = 20 * 1024 + 8;
    let new = made(23, Made { len, ..MADE });
    // DFU's last payload page holds a byte past the payload: refused.
    let flash = flashed(&old);
    let mut dirty = new.clone();
    dirty[len + 100] = 0x00;
    write_dfu(&flash, &dirty);
    write_ticket(&flash, len as u32, signature(&new[..len], &SEED));
    mark_updated(&flash);
    assert_refused(&flash, &old, Verdict::PastPayload);

    // Whole pages past it hold the last image's bytes (the image a swap took out): erased before the swap.
    let flash = flashed(&old);
    write_dfu(&flash, &image(24));
    receive_signed(&flash, &new[..len.next_multiple_of(PAGE_BYTES)], len, &SEED);
    assert_eq!(reset(&flash), prepared(State::Swap));
    assert_image!(active(&flash), new, "the payload, and erased flash after it");
}

#[test]
fn an_update_marked_without_a_good_ticket_is_refused() {
    let (old, new) = (image(25), image(26));
    let flash = flashed(&old);
    write_dfu(&flash, &new);
    mark_updated(&flash);
    assert_refused(&flash, &old, Verdict::NoTicket);

    for (len, why) in [
        (ACTIVE_BYTES + 8, "longer than ACTIVE"),
        (0x100, "shorter than the info and key"),
        (1001, "not whole double words"),
    ] {
        let flash = flashed(&old);
        write_dfu(&flash, &new);
        write_ticket(&flash, len as u32, signature(&new, &SEED));
        mark_updated(&flash);
        assert_eq!(reset(&flash), refused(Verdict::Length), "{why}");
    }
}

#[test]
fn an_image_for_another_target_or_without_its_key_is_refused() {
    let old = image(27);
    let legacy = made(
        28,
        Made {
            target: Target::ThrusterLegacy,
            ..MADE
        },
    );
    let flash = ready(&old, &legacy);
    assert_refused(&flash, &old, Verdict::Target);

    // A format-1 image info carries no key: nothing after it could be checked.
    let mut format_1 = image(29);
    format_1[INFO_OFFSET + 4] = 1;
    let flash = ready(&old, &format_1);
    assert_refused(&flash, &old, Verdict::NoInfo);

    // The running image has no key (a format-1 image, flashed by probe): the bootloader can check nothing.
    let mut old_format = old.clone();
    old_format[INFO_OFFSET + 4] = 1;
    let flash = ready(&old_format, &image(30));
    assert_refused(&flash, &old_format, Verdict::NoKey);
    assert_eq!(INFO_FORMAT, 2);
}

/// Confirm whatever ACTIVE holds and start again: the counter raise a confirmed image gets.
fn confirm_and_restart(flash: &Stm32g4Flash) {
    mark_booted(flash);
    assert_eq!(reset(flash), prepared(State::Boot));
}

#[test]
fn no_way_back_to_an_older_image_unless_signed_for_it_and_never_below_the_counter() {
    let running = made(
        31,
        Made {
            counter: 2,
            ..version(3)
        },
    );
    let flash = flashed(&running);
    assert_eq!(counter(&flash), None);
    assert_eq!(reset(&flash), prepared(State::Boot));
    assert_eq!(
        counter(&flash),
        Some(2),
        "raised at the first start of a confirmed image"
    );

    // An older version, validly signed: refused. The same version: taken (the same image again).
    let older = made(
        32,
        Made {
            counter: 2,
            ..version(1)
        },
    );
    receive(&flash, &older);
    assert_refused(&flash, &running, Verdict::Older);
    let again = made(
        33,
        Made {
            counter: 2,
            ..version(3)
        },
    );
    receive(&flash, &again);
    assert_eq!(reset(&flash), prepared(State::Swap));
    assert_image!(active(&flash), again, "the same version");
    confirm_and_restart(&flash);

    // Signed as a rollback on purpose: taken, its counter equal to the stored one.
    let rollback = made(
        34,
        Made {
            counter: 2,
            rollback: true,
            ..version(1)
        },
    );
    receive(&flash, &rollback);
    assert_eq!(reset(&flash), prepared(State::Swap));
    assert_image!(active(&flash), rollback, "the rollback");
    confirm_and_restart(&flash);
    assert_eq!(counter(&flash), Some(2));

    // A counter below the stored one: refused, rollback or not, newer version or not.
    for (seed, made_as) in [
        (
            35,
            Made {
                counter: 1,
                ..version(9)
            },
        ),
        (
            36,
            Made {
                counter: 1,
                rollback: true,
                ..version(9)
            },
        ),
    ] {
        let low = made(seed, made_as);
        receive(&flash, &low);
        assert_refused(&flash, &rollback, Verdict::Counter);
    }

    // A newer image with a higher counter: taken; the counter rises only once it is confirmed.
    let newer = made(
        37,
        Made {
            counter: 5,
            ..version(4)
        },
    );
    receive(&flash, &newer);
    assert_eq!(reset(&flash), prepared(State::Swap));
    assert_eq!(counter(&flash), Some(2), "not while it is on trial");
    assert_eq!(reset(&flash), prepared(State::Swap), "never confirmed: reverted");
    assert_eq!(counter(&flash), Some(2), "a reverted image raises nothing");
    assert_eq!(reset(&flash), prepared(State::Revert));
    assert_eq!(counter(&flash), Some(2));
    receive(&flash, &newer);
    assert_eq!(reset(&flash), prepared(State::Swap));
    confirm_and_restart(&flash);
    assert_eq!(counter(&flash), Some(5));
}

#[test]
fn the_counter_journal_fills_a_page_moves_to_the_other_and_never_goes_down() {
    let flash = flashed(&image(40));
    let shared = Mutex::new(RefCell::new(flash.clone()));
    // Past two pages' worth of raises: the journal moves between its pages, erasing the other each time.
    let entries_per_page = PAGE / WRITE_UNIT;
    for counter_value in 1..=(2 * entries_per_page + 10) {
        let mut active_part = partition(&shared, LAYOUT.active);
        let info = ImageInfo::new(Target::ThrusterSeabotix, Version::new(0, 1, 0)).with_security_counter(counter_value);
        active_part.erase(0, PAGE).unwrap();
        let mut first_page = image(40)[..PAGE_BYTES].to_vec();
        first_page[INFO_OFFSET..][..INFO_LEN].copy_from_slice(&info.to_bytes());
        active_part.write(0, &first_page).unwrap();
        assert_eq!(reset(&flash), prepared(State::Boot));
        assert_eq!(counter(&flash), Some(counter_value));
    }
}

#[test]
fn a_power_cut_while_the_counter_rises_leaves_the_old_value_or_the_new_never_less() {
    // A journal with one page full and the other holding older entries: the raise erases the other page first.
    let base = flashed(&image(41));
    let shared = Mutex::new(RefCell::new(base.clone()));
    let mut journal = partition(&shared, LAYOUT.counter());
    for slot in 0..PAGE / WRITE_UNIT {
        journal.write(slot * WRITE_UNIT, &checked_word(100 + slot)).unwrap();
    }
    journal.write(PAGE, &checked_word(7)).unwrap();
    let before = 100 + PAGE / WRITE_UNIT - 1;
    let raised = made(
        42,
        Made {
            counter: before + 1,
            ..MADE
        },
    );
    let mut active_part = partition(&shared, LAYOUT.active);
    active_part.erase(0, LAYOUT.active.length).unwrap();
    active_part.write(0, &raised).unwrap();
    let total = {
        let flash = copy(&base);
        let spent_before = spent(&flash);
        assert_eq!(reset(&flash), prepared(State::Boot));
        assert_eq!(counter(&flash), Some(before + 1));
        spent(&flash) - spent_before
    };
    assert_eq!(total, PAGE_BYTES + 8, "the other page's erase and one entry");
    for cut in (0..=total).step_by(7).chain([total - 8, total - 4, total - 1]) {
        let flash = copy(&base);
        flash.cut_power_after(cut);
        let _ = reset(&flash);
        flash.power_on();
        let stored = counter(&flash);
        assert!(
            stored == Some(before) || stored == Some(before + 1),
            "cut at {cut}: {stored:?}"
        );
        // The next start finishes the raise.
        assert_eq!(reset(&flash), prepared(State::Boot), "cut at {cut}");
        assert_eq!(counter(&flash), Some(before + 1), "cut at {cut}");
    }
}

#[test]
fn a_power_cut_while_the_bootloader_checks_or_refuses_changes_nothing_it_would_not_do_again() {
    let old = image(43);
    let len = 12 * 1024;
    let new = made(44, Made { len, ..MADE });
    // Stale pages past the payload, which the bootloader erases before the swap; and a forged image it refuses.
    let good = flashed(&old);
    write_dfu(&good, &image(45));
    receive_signed(&good, &new[..len], len, &SEED);
    let bad = flashed(&old);
    receive_signed(&bad, &new[..len], len, &OTHER_SEED);
    for (base, expected) in [(&good, &new), (&bad, &old)] {
        let total = {
            let flash = copy(base);
            let before = spent(&flash);
            let _ = reset(&flash);
            spent(&flash) - before
        };
        for cut in (0..total).step_by(311).chain([1, 8, 9, 16, 17]) {
            let flash = copy(base);
            flash.cut_power_after(cut);
            let _ = reset(&flash);
            let settled = reset_until_prepared(&flash);
            assert!(
                matches!(settled, State::Swap | State::Boot),
                "cut at {cut}: {settled:?}"
            );
            if expected == &old {
                assert_eq!(verdict(&flash), Some(Verdict::Signature), "cut at {cut}");
            }
            assert_image!(active(&flash), expected, "cut at {cut}");
        }
    }
}

#[test]
fn the_watchdog_is_fed_through_the_check_and_the_swap() {
    let (old, new) = (image(46), image(47));
    let flash = ready(&old, &new);
    // The flash time between two feeds: never more than a page's erase and its programming.
    let timing = FlashTiming::G431;
    let feeds = RefCell::new(Vec::new());
    let outcome = prepare(flash.clone(), &LAYOUT, CrashCount::default(), || {
        feeds.borrow_mut().push(flash.stats())
    });
    assert_eq!(outcome, prepared(State::Swap));
    let feeds = feeds.into_inner();
    assert!(feeds.len() > 3 * ACTIVE_PAGES, "{} feeds", feeds.len());
    let longest = feeds
        .windows(2)
        .map(|pair| timing.work_time(pair[0], pair[1]))
        .max()
        .unwrap();
    // A page's erase and its programming, and no more: far inside the trial watchdog's 2 s at the fastest LSI.
    assert!(
        longest.as_micros() <= 60_000,
        "{longest:?} of flash work between two feeds"
    );
    assert!(u64::from(g431_hw::iwdg::BOOT_TRIAL_MIN_US) > 30 * longest.as_micros());
}

/// The trials in which the bootloader read a torn double word (on the chip: an NMI, `stm32.rs`), by where it was:
/// the state, the record's [`Previous`] entry, or elsewhere.
#[derive(Debug, Default)]
struct TornReads {
    state: usize,
    previous: usize,
    elsewhere: usize,
}

impl TornReads {
    fn add(&mut self, flash: &Stm32g4Flash) {
        let state = offset(LAYOUT.state)..offset(LAYOUT.state) + LAYOUT.state.length as usize;
        let previous = offset(LAYOUT.ticket()) + PREVIOUS_OFFSET as usize;
        let previous = previous..previous + PREVIOUS_LEN;
        let offsets = flash.ecc_error_offsets();
        let any = |range: &core::ops::Range<usize>| offsets.iter().any(|at| range.contains(&(*at as usize)));
        self.state += usize::from(any(&state));
        self.previous += usize::from(any(&previous));
        self.elsewhere += usize::from(
            offsets
                .iter()
                .any(|at| !state.contains(&(*at as usize)) && !previous.contains(&(*at as usize))),
        );
    }
}

/// The points of an operation of `total` bytes a test cuts the power at: every `stride`-th byte (a stride prime to
/// the double word and the page, so the cuts fall at every offset within them), and in each page's copy a cut into
/// its erase, into a double word it programs and into its progress word.
fn cut_points(total: usize, stride: usize, copies_from: usize) -> Vec<usize> {
    let mut points: Vec<usize> = (0..total).step_by(stride).collect();
    for copy in 0..2 * ACTIVE_PAGES {
        let start = copies_from + copy * COPY_BYTES;
        points.extend([
            start + 1,
            start + PAGE_BYTES / 2,
            start + PAGE_BYTES + 3,
            start + 2 * PAGE_BYTES + 5,
        ]);
    }
    points.retain(|&n| n < total);
    points
}

#[test]
fn a_power_cut_anywhere_in_the_swap_ends_in_the_whole_new_image_then_the_whole_old_one() {
    let (old, new) = (image(5), image(6));
    let base = ready(&old, &new);
    let total = {
        let flash = copy(&base);
        let before = spent(&flash);
        assert_eq!(reset(&flash), prepared(State::Swap));
        spent(&flash) - before
    };
    assert_eq!(
        total,
        PREVIOUS_LEN + 2 * ACTIVE_PAGES * COPY_BYTES,
        "the previous image noted, then 50 page copies"
    );
    let mut points = cut_points(total, 997, PREVIOUS_LEN);
    points.extend([1, 8, 9, 33, PREVIOUS_LEN - 1]);
    let mut torn = TornReads::default();
    for (trial, &cut) in points.iter().enumerate() {
        let flash = copy(&base);
        flash.cut_power_after(cut);
        assert!(
            matches!(reset(&flash), Outcome::Failed(_)),
            "cut at {cut}: the power went"
        );
        // Every third trial the power goes a second time while the swap resumes.
        let again = if trial % 3 == 0 {
            cut_again(&flash, cut * 7 % total)
        } else {
            None
        };
        assert_eq!(
            again.unwrap_or_else(|| reset_until_prepared(&flash)),
            State::Swap,
            "cut at {cut}"
        );
        torn.add(&flash);
        assert_image!(
            active(&flash),
            new,
            "cut at {cut} (trial {trial}): the new image, whole"
        );
        assert_image!(dfu_shifted(&flash), old, "cut at {cut}: the old one, whole, in DFU");
        // Half the trials confirm it, half reset before it does and get the old image back.
        if trial % 2 == 0 {
            mark_booted(&flash);
            assert_eq!(reset(&flash), prepared(State::Boot));
            assert_image!(active(&flash), new, "cut at {cut}, confirmed");
        } else {
            assert_eq!(reset(&flash), prepared(State::Swap));
            assert_image!(active(&flash), old, "cut at {cut}, never confirmed");
        }
    }
    // A cut in a page's copy is redone from the page's erase, so only a progress word, or the note of the previous
    // image, is ever read torn.
    assert_eq!(torn.elsewhere, 0);
    assert!(torn.state > 0 && torn.previous > 0, "{torn:?}");
}

#[test]
fn a_power_cut_anywhere_in_a_revert_ends_in_the_whole_old_image() {
    let (old, new) = (image(7), image(8));
    let base = ready(&old, &new);
    assert_eq!(reset(&base), prepared(State::Swap));
    let base = copy(&base);
    let total = {
        let flash = copy(&base);
        let before = spent(&flash);
        assert_eq!(reset(&flash), prepared(State::Swap));
        spent(&flash) - before
    };
    assert_eq!(
        total,
        2 * ACTIVE_PAGES * COPY_BYTES + MAGIC_BYTES,
        "50 page copies, then the state rewritten"
    );
    let mut points = cut_points(total, 997, 0);
    // Into the progress-validity word, the state's erase and the REVERT magic.
    let end = 2 * ACTIVE_PAGES * COPY_BYTES;
    points.extend([
        end,
        end + 3,
        end + 8,
        end + 13,
        end + 8 + PAGE_BYTES / 2,
        end + 8 + PAGE_BYTES + 5,
    ]);
    let mut torn = TornReads::default();
    for (trial, &cut) in points.iter().enumerate() {
        let flash = copy(&base);
        flash.cut_power_after(cut);
        let _ = reset(&flash);
        let again = if trial % 3 == 0 {
            cut_again(&flash, cut * 7 % total)
        } else {
            None
        };
        let resumed = again.unwrap_or_else(|| reset_until_prepared(&flash));
        torn.add(&flash);
        assert!(
            matches!(resumed, State::Swap | State::Revert | State::Boot),
            "cut at {cut}: {resumed:?}"
        );
        assert_image!(active(&flash), old, "cut at {cut}: the old image, whole");
        assert!(matches!(state(&flash), State::Revert | State::Boot), "cut at {cut}");
        assert_eq!(
            reset(&flash),
            prepared(state(&flash)),
            "cut at {cut}: nothing left to do"
        );
        assert_image!(active(&flash), old, "active");
    }
    assert_eq!(torn.elsewhere + torn.previous, 0);
    assert!(torn.state > 0, "{torn:?}");
}

/// The points of embassy-boot's `set_magic` a test cuts the power at: every byte of its two words, and into the
/// state's erase at a stride.
fn magic_cut_points() -> Vec<usize> {
    let words = (0..=16).chain(MAGIC_BYTES - 8..=MAGIC_BYTES);
    words.chain((16..MAGIC_BYTES - 8).step_by(97)).collect()
}

#[test]
fn a_power_cut_while_marking_updated_leaves_the_old_image_and_the_update_can_be_marked_again() {
    let (old, new) = (image(9), image(10));
    let base = flashed(&old);
    // A previous update, confirmed: the state holds BOOT, DFU the image before.
    receive(&base, &new);
    assert_eq!(reset(&base), prepared(State::Swap));
    mark_booted(&base);
    let base = copy(&base);
    let (current, next) = (new, image(11));
    for cut in magic_cut_points() {
        let flash = copy(&base);
        write_dfu(&flash, &next);
        write_ticket(&flash, next.len() as u32, signature(&next, &SEED));
        flash.cut_power_after(cut);
        let marked = with_state(&flash, |state| state.mark_updated());
        let swapped = reset_until_prepared(&flash) == State::Swap;
        assert_eq!(marked.is_ok(), cut == MAGIC_BYTES, "cut at {cut}");
        assert_eq!(
            swapped,
            cut == MAGIC_BYTES,
            "cut at {cut}: only a whole magic word swaps"
        );
        let expected = if swapped { &next } else { &current };
        assert_image!(active(&flash), expected, "cut at {cut}");
        if !swapped {
            // The running image marks it again, and this time the swap happens.
            assert_eq!(state(&flash), State::Boot, "cut at {cut}");
            with_state(&flash, |state| state.mark_updated()).unwrap();
            assert_eq!(reset(&flash), prepared(State::Swap), "cut at {cut}");
            assert_image!(active(&flash), next, "cut at {cut}");
        }
    }
}

#[test]
fn a_power_cut_while_marking_booted_keeps_the_new_image_once_a_byte_of_it_is_written() {
    let (old, new) = (image(12), image(13));
    let base = ready(&old, &new);
    assert_eq!(reset(&base), prepared(State::Swap));
    let base = copy(&base);
    for cut in magic_cut_points() {
        let flash = copy(&base);
        flash.cut_power_after(cut);
        let _ = with_state(&flash, |state| state.mark_booted());
        let outcome = {
            flash.power_on();
            reset(&flash)
        };
        // Nothing written: the next reset reverts. Any byte of the progress-validity word written: the progress is
        // no longer valid, embassy-boot takes the swap as done and the revert as done too, and the new image stays.
        let expected = if cut == 0 { &old } else { &new };
        assert_image!(active(&flash), expected, "cut at {cut}: {outcome:?}");
        assert_eq!(reset(&flash), prepared(state(&flash)), "cut at {cut}: settled");
        assert_image!(active(&flash), expected, "cut at {cut}");
    }
}

#[test]
fn the_swap_takes_under_three_seconds_on_the_g431() {
    let (old, new) = (image(14), image(15));
    let flash = ready(&old, &new);
    let before = flash.stats();
    assert_eq!(reset(&flash), prepared(State::Swap));
    let after = flash.stats();
    let (erases, double_words) = (after.erases - before.erases, (after.programmed - before.programmed) / 8);
    let timing = FlashTiming::G431;
    let swap_us = erases * timing.erase_page.as_micros() + double_words * timing.program_unit.as_micros();
    // 50 page copies: 50 erases (1.25 s) and 50 x 257 double words, each page's and its progress word (1.29 s);
    // before them the note of the image moved out, five double words.
    assert_eq!((erases, double_words), (50, 50 * 257 + 5));
    assert_eq!(swap_us, 2_535_000 + 5 * timing.program_unit.as_micros());
    // The revert costs the same copies and the state's rewrite.
    let before = flash.stats();
    assert_eq!(reset(&flash), prepared(State::Swap));
    let after = flash.stats();
    let (erases, double_words) = (after.erases - before.erases, (after.programmed - before.programmed) / 8);
    assert_eq!((erases, double_words), (51, 50 * 257 + 2));
}

/// A power cut in the last word embassy-boot writes to mark an update leaves a torn magic word. embassy-boot reads
/// it as no magic (`Boot`: the update is not applied, ACTIVE stays whole), but nothing rewrites it: every start
/// reads it again, the bootloader's and then the application's (`get_state`, `mark_booted`), each time an ECC
/// double error, on the chip an NMI. The bootloader clears it and goes on (`stm32.rs`); an application whose NMI
/// handler stops and waits for its watchdog instead would reset at every start until it marks the state again.
#[test]
fn a_torn_magic_word_reads_as_no_update_and_stays_torn_until_the_state_is_marked_again() {
    let (old, new) = (image(16), image(17));
    let flash = flashed(&old);
    write_dfu(&flash, &new);
    write_ticket(&flash, new.len() as u32, signature(&new, &SEED));
    // The magic word's fourth byte.
    flash.cut_power_after(MAGIC_BYTES - 5);
    assert!(with_state(&flash, |state| state.mark_updated()).is_err());
    flash.power_on();
    let magic = offset(LAYOUT.state) as u32;
    for start in 1..=3 {
        assert_eq!(reset(&flash), prepared(State::Boot), "start {start}");
        assert_image!(active(&flash), old, "start {start}");
        assert_eq!(
            flash.ecc_error_offsets(),
            [magic],
            "the bootloader read the torn magic word"
        );
        let before = flash.stats().ecc_errors;
        assert_eq!(state(&flash), State::Boot);
        assert_eq!(
            flash.stats().ecc_errors,
            before + 1,
            "start {start}: and so does the application"
        );
    }
    // Marked again, the state is whole: no more ECC errors, and the swap happens.
    with_state(&flash, |state| state.mark_updated()).unwrap();
    let before = flash.stats().ecc_errors;
    assert_eq!(reset(&flash), prepared(State::Swap));
    assert_image!(active(&flash), new, "after the update was marked again");
    assert_eq!(flash.stats().ecc_errors, before);
}

/// `old` confirmed, then `new` swapped in and confirmed: the flash as a crash loop of `new` finds it.
fn confirmed_over(old: &[u8], new: &[u8]) -> Stm32g4Flash {
    let flash = ready(old, new);
    assert_eq!(reset(&flash), prepared(State::Swap));
    mark_booted(&flash);
    assert_eq!(reset(&flash), prepared(State::Boot));
    flash
}

#[test]
fn a_confirmed_image_that_crashes_early_three_times_in_a_row_is_undone() {
    let (old, new) = (image(50), image(51));
    let flash = confirmed_over(&old, &new);
    for crashes in 1..update_image::EARLY_CRASHES {
        assert_eq!(reset_after_crashes(&flash, crashes), prepared(State::Boot));
        assert_image!(active(&flash), new, "after {crashes} crashes");
    }
    assert_eq!(
        reset_after_crashes(&flash, update_image::EARLY_CRASHES),
        Outcome::Restored { attempt: 1 }
    );
    assert_image!(active(&flash), old, "the previous image back");
    assert_eq!(state(&flash), State::Revert, "which the image that runs finds");
    // The image put back is not on trial, and nothing swings back: DFU no longer holds the image noted.
    for crashes in [0, update_image::EARLY_CRASHES, 10] {
        assert_eq!(reset_after_crashes(&flash, crashes), prepared(State::Revert));
        assert_image!(active(&flash), old, "after {crashes} more crashes");
    }
}

#[test]
fn only_the_exact_previous_image_comes_back_and_never_below_the_counter() {
    let old = image(52);
    // A new upload begun over the previous image: DFU no longer holds it.
    let flash = confirmed_over(&old, &image(53));
    write_dfu(&flash, &image(54)[..4 * PAGE_BYTES]);
    assert_eq!(reset_after_crashes(&flash, 3), prepared(State::Boot));
    assert_image!(active(&flash), image(53), "kept: nothing whole to go back to");

    // One byte of the previous image changed in DFU.
    let flash = confirmed_over(&old, &image(55));
    let at = offset(LAYOUT.dfu) + PAGE_BYTES + 7 * PAGE_BYTES + 100;
    let mut contents = flash.contents();
    contents[at] ^= 0x01;
    let mut dfu = Stm32g4Flash::new((LAYOUT.chip.flash.length / PAGE) as usize);
    dfu.write(0, &contents).unwrap();
    assert_eq!(reset_after_crashes(&dfu, 3), prepared(State::Boot));
    assert_image!(active(&dfu), image(55), "kept");

    // An update that raised the security counter is not undone by crashes.
    let raised = made(56, Made { counter: 2, ..MADE });
    let flash = confirmed_over(&old, &raised);
    assert_eq!(counter(&flash), Some(2));
    assert_eq!(reset_after_crashes(&flash, 3), prepared(State::Boot));
    assert_image!(active(&flash), raised, "kept");

    // On trial, embassy-boot's own revert undoes it at any reset.
    let flash = ready(&old, &image(57));
    assert_eq!(reset(&flash), prepared(State::Swap));
    assert_eq!(reset_after_crashes(&flash, 3), prepared(State::Swap));
    assert_image!(active(&flash), old, "reverted");

    // A board flashed by a probe has no previous image.
    let flash = flashed(&old);
    assert_eq!(reset_after_crashes(&flash, 3), prepared(State::Boot));
    assert_image!(active(&flash), old, "as flashed");
}

#[test]
fn the_undo_is_written_as_a_swap_embassy_boot_reverts() {
    let flash = confirmed_over(&image(58), &image(59));
    let shared = Mutex::new(RefCell::new(flash.clone()));
    write_swapped(&mut partition(&shared, LAYOUT.state), LAYOUT.active_pages()).unwrap();
    assert_eq!(state(&flash), State::Swap, "embassy-boot reads the magic as its own");
    // ...and finds every step of the swap done: it reverts.
    assert_eq!(reset(&flash), prepared(State::Swap));
    assert_image!(active(&flash), image(58), "reverted");
}

#[test]
fn a_power_cut_anywhere_in_the_undo_ends_in_one_whole_image() {
    let (old, new) = (image(60), image(61));
    let base = confirmed_over(&old, &new);
    let total = {
        let flash = copy(&base);
        let before = spent(&flash);
        assert_eq!(reset_after_crashes(&flash, 3), Outcome::Restored { attempt: 1 });
        spent(&flash) - before
    };
    let write_swapped = PAGE_BYTES + (2 * ACTIVE_PAGES + 1) * 8;
    assert_eq!(total, write_swapped + 2 * ACTIVE_PAGES * COPY_BYTES + MAGIC_BYTES);
    let mut points = cut_points(total, 1201, write_swapped);
    points.extend([1, PAGE_BYTES + 3, write_swapped - 5, write_swapped - 1]);
    let mut torn = TornReads::default();
    for (trial, &cut) in points.iter().enumerate() {
        let flash = copy(&base);
        flash.cut_power_after(cut);
        let _ = reset_after_crashes(&flash, 3);
        flash.power_on();
        // A power cut clears the count (the backup domain goes with VDD on these boards): the next starts count
        // from none, and half the trials crash three times again.
        let crashes = if trial % 2 == 0 { 0 } else { 3 };
        let _ = reset_after_crashes(&flash, crashes);
        let _ = reset_until_prepared(&flash);
        torn.add(&flash);
        let running = active(&flash);
        if cut < write_swapped && crashes == 0 {
            assert_image!(running, new, "cut at {cut} before the undo began: the image that ran");
        } else {
            assert_image!(running, old, "cut at {cut}: the previous image, whole");
        }
    }
    assert_eq!(torn.elsewhere + torn.previous, 0, "{torn:?}");
}
