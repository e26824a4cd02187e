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

use super::*;

const PAGE_BYTES: usize = PAGE as usize;
const ACTIVE_BYTES: usize = LAYOUT.active.length as usize;
const ACTIVE_PAGES: usize = ACTIVE_BYTES / PAGE_BYTES;
/// What one page's copy costs in the flash's bytes: its erase, its programming and its progress word.
const COPY_BYTES: usize = 2 * PAGE_BYTES + 8;
/// What embassy-boot's `set_magic` (mark updated or booted, and the end of a revert) costs: the progress-validity
/// word, the state page's erase and the magic word.
const MAGIC_BYTES: usize = 8 + PAGE_BYTES + 8;

/// A made-up image of ACTIVE's size whose bytes `seed` picks (xorshift32): two seeds differ in every page.
fn image(seed: u32) -> Vec<u8> {
    let mut x = seed.wrapping_mul(0x9E37_79B9) | 1;
    (0..ACTIVE_BYTES)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x as u8
        })
        .collect()
}

/// The pages in which two images differ (an assertion on the images themselves would print 58 KiB).
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

/// DFU's pages 1..=29: where a swap leaves the image it took out of ACTIVE.
fn dfu_shifted(flash: &Stm32g4Flash) -> Vec<u8> {
    bytes(flash, LAYOUT.dfu)[PAGE_BYTES..][..ACTIVE_BYTES].to_vec()
}

/// The bytes the flash has erased or programmed so far: what `cut_power_after` counts.
fn spent(flash: &Stm32g4Flash) -> usize {
    let stats = flash.stats();
    (stats.erases * PAGE as u64 + stats.programmed) as usize
}

/// A reset: the bootloader's preparation on the flash as the last power-down left it.
fn reset(flash: &Stm32g4Flash) -> Outcome {
    prepare(&Mutex::new(RefCell::new(flash.clone())), &LAYOUT)
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
        Outcome::Failed(_) => None,
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

/// The running image receives `new`: embassy-boot's updater writes it to DFU (in 1 KiB pieces, as it would
/// arrive), and the state is marked for the swap.
fn receive(flash: &Stm32g4Flash, new: &[u8]) {
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
    with_state(flash, |state| state.mark_updated()).unwrap();
}

fn mark_booted(flash: &Stm32g4Flash) {
    with_state(flash, |state| state.mark_booted()).unwrap();
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

/// The trials in which the bootloader read a torn double word (on the chip: an NMI, `stm32.rs`), by where it was.
#[derive(Debug, Default)]
struct TornReads {
    state: usize,
    outside_state: usize,
}

impl TornReads {
    fn add(&mut self, flash: &Stm32g4Flash) {
        let state = offset(LAYOUT.state)..offset(LAYOUT.state) + LAYOUT.state.length as usize;
        let offsets = flash.ecc_error_offsets();
        self.state += usize::from(offsets.iter().any(|at| state.contains(&(*at as usize))));
        self.outside_state += usize::from(offsets.iter().any(|at| !state.contains(&(*at as usize))));
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
    assert_eq!(total, 2 * ACTIVE_PAGES * COPY_BYTES, "a swap is 58 page copies");
    let points = cut_points(total, 997, 0);
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
    // A cut in a page's copy is redone from the page's erase, so only a progress word is ever read torn.
    assert_eq!(torn.outside_state, 0);
    assert!(torn.state > 0, "{torn:?}");
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
        "58 page copies, then the state rewritten"
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
    assert_eq!(torn.outside_state, 0);
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
        updater.write_firmware(0, &next).unwrap();
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
fn the_swap_takes_about_three_seconds_on_the_g431() {
    let (old, new) = (image(14), image(15));
    let flash = ready(&old, &new);
    let before = flash.stats();
    assert_eq!(reset(&flash), prepared(State::Swap));
    let after = flash.stats();
    let (erases, double_words) = (after.erases - before.erases, (after.programmed - before.programmed) / 8);
    let timing = FlashTiming::G431;
    let swap_us = erases * timing.erase_page.as_micros() + double_words * timing.program_unit.as_micros();
    // 58 page copies: 58 erases (1.45 s) and 58 x 257 double words, each page's and its progress word (1.49 s).
    assert_eq!((erases, double_words), (58, 58 * 257));
    assert_eq!(swap_us, 2_940_600);
    // The revert costs the same copies and the state's rewrite.
    let before = flash.stats();
    assert_eq!(reset(&flash), prepared(State::Swap));
    let after = flash.stats();
    let (erases, double_words) = (after.erases - before.erases, (after.programmed - before.programmed) / 8);
    assert_eq!((erases, double_words), (59, 58 * 257 + 2));
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
    updater.write_firmware(0, &new).unwrap();
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
