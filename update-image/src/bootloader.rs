//! What an application hands the bootloader with an update, and what the bootloader answers: the page of the
//! bootloader's record partition (g431-hw's `Partitions::record`) that they share.
//!
//! The application that marks an image for the swap first writes its [`Ticket`] there: the payload's length and
//! signature, which the bootloader needs to check DFU before it swaps anything in (the rest it reads from the
//! payload's signed [`ImageInfo`](crate::ImageInfo)). A bootloader that refuses the image writes its
//! [`Verdict`], clears the mark and starts the image that ran; that image reads the verdict at its next start and
//! tells it, then notes that it did (the told word). Every page of the record is written only after an erase, a
//! double word at a time:
//!
//! | offset | length | written by      | what                                                              |
//! |--------|--------|-----------------|-------------------------------------------------------------------|
//! | 0      | 72     | the application | the [`Ticket`]                                                    |
//! | 128    | 64     | the bootloader  | the [`Verdict`] on that ticket: [`SLOTS`] [`checked_word`]s       |
//! | 192    | 64     | the application | the verdict was told: [`SLOTS`] [`checked_word`]s                 |
//! | 256    | 8      | the application | who applied the image: a [`checked_word`] ([`APPLIER_OFFSET`])    |
//! | 320    | 40     | the bootloader  | the image the swap moved out: [`Previous`]                        |
//!
//! A checked word is a u32 and its complement: a double word torn by a power cut (some of its bits programmed,
//! the rest still erased) never reads as one, so a torn verdict is no verdict, and a torn counter entry (lbv-boot
//! keeps its security counter as a journal of them) leaves the value before it. A torn word cannot be written
//! again (flash programs only erased double words), so the verdict and the told mark each have a few slots: the
//! first whole word counts, and a writer that finds none writes the first erased slot ([`Slots`]).
//!
//! # Undoing an image that crashes after it confirmed
//!
//! A swap leaves the image it moved out in DFU, one page up, until the next upload overwrites it. Before it swaps,
//! the bootloader notes that image's digest ([`Previous`]); should the new image, once confirmed, crash
//! [`EARLY_CRASHES`] times in a row within [`EARLY_WINDOW_SECS`] of its start, the bootloader swaps the previous one
//! back if DFU still holds exactly it. The crashes are counted in a backup register ([`CrashCount`]), which the
//! bootloader raises at every start after a watchdog reset, and the application clears once it has run the
//! window through.

use core::fmt;

use crate::{INFO_LEN, INFO_OFFSET, KEY_LEN};

/// Where the [`Ticket`] starts in the record's first page.
pub const TICKET_OFFSET: u32 = 0;

/// The ticket's length: magic, payload length, signature.
pub const TICKET_LEN: usize = 4 + 4 + 64;

/// Where the bootloader writes its [`Verdict`] in the record's first page: [`SLOTS`] double words.
pub const VERDICT_OFFSET: u32 = 128;

/// Where the application notes that it told the verdict: [`SLOTS`] double words.
pub const TOLD_OFFSET: u32 = 192;

/// Where the application notes who applied the image (its MAVLink system and component, `component | system << 8`,
/// as a [`checked_word`]), written with the ticket: the image that runs after the restart answers the apply there.
/// The bootloader does not read it.
pub const APPLIER_OFFSET: u32 = 256;

/// Where the bootloader notes the image a swap moved out ([`Previous`]): [`PREVIOUS_LEN`] bytes.
pub const PREVIOUS_OFFSET: u32 = 320;

/// The length of the [`Previous`] entry: its digest, then the checked word that says it is whole.
pub const PREVIOUS_LEN: usize = DIGEST_LEN + 8;

/// The digest kept of an image: the first half of SHA-512 (SHA-512/256 would be as good; this is the hash the
/// bootloader already computes).
pub const DIGEST_LEN: usize = 32;

/// The image a swap moved out of ACTIVE into DFU, as the bootloader noted it before the swap began: the digest of
/// ACTIVE's whole partition, then a [`checked_word`] of [`Previous::MAGIC`] written last, so that an entry a power
/// cut tore never reads as one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Previous {
    /// The first [`DIGEST_LEN`] bytes of SHA-512 over ACTIVE's partition as it was before the swap.
    pub digest: [u8; DIGEST_LEN],
}

impl Previous {
    /// The value of the checked word that closes a whole entry.
    pub const MAGIC: u32 = 0x5052_4556;

    /// The entry's bytes.
    pub fn to_bytes(&self) -> [u8; PREVIOUS_LEN] {
        let mut bytes = [0xFF; PREVIOUS_LEN];
        let (digest, word) = bytes.split_at_mut(DIGEST_LEN);
        digest.copy_from_slice(&self.digest);
        word.copy_from_slice(&checked_word(Previous::MAGIC));
        bytes
    }

    /// The entry in `bytes`, if they hold a whole one.
    pub fn parse(bytes: &[u8; PREVIOUS_LEN]) -> Option<Previous> {
        let (digest, word) = bytes.split_first_chunk::<DIGEST_LEN>()?;
        let word = word.first_chunk::<8>()?;
        (read_checked_word(*word) == Some(Previous::MAGIC)).then_some(Previous { digest: *digest })
    }
}

/// How many watchdog resets in a row, each within [`EARLY_WINDOW_SECS`] of the start before it, make the bootloader
/// swap the previous image back in. One crash may be the water's doing (a brown-out that hangs a peripheral); three
/// in a row within a minute of each start is the image, and at a minute each the vehicle is back on its old image
/// within about three minutes, long before an operator could reach it with a probe.
pub const EARLY_CRASHES: u8 = 3;

/// How long an image must run after its start before a crash no longer counts as an early one: it clears the
/// count once it has run this long. A minute covers the start-up, the first thruster polls and the first
/// exchanges with a ground station, where an image's new paths are first exercised.
pub const EARLY_WINDOW_SECS: u64 = 60;

/// The bootloader's count of consecutive early crashes, kept in a backup register (`g431_hw::backup`) as a tagged
/// word, and whether it has just swapped the previous image back in (for the image that then runs to tell).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CrashCount {
    /// Watchdog resets in a row, each early in its run.
    pub crashes: u8,
    /// The bootloader swapped the previous image back in, and the image that runs has not told it yet.
    pub restored: bool,
}

impl CrashCount {
    /// The tag in the word's upper half.
    const TAG: u32 = 0x4352;

    /// Its register word: the tag, the count and flag byte's complement, the byte (bit 7 the flag).
    pub const fn to_word(self) -> u32 {
        let crashes = if self.crashes > 0x7F { 0x7F } else { self.crashes };
        let byte = crashes as u32 | if self.restored { 0x80 } else { 0 };
        (CrashCount::TAG << 16) | ((!byte & 0xFF) << 8) | byte
    }

    /// The count a register word holds; none (zero) for a word never written, such as a power-on's zero.
    pub const fn from_word(word: u32) -> CrashCount {
        let byte = word & 0xFF;
        if word >> 16 == CrashCount::TAG && (word >> 8) & 0xFF == !byte & 0xFF {
            CrashCount {
                crashes: (byte & 0x7F) as u8,
                restored: byte & 0x80 != 0,
            }
        } else {
            CrashCount {
                crashes: 0,
                restored: false,
            }
        }
    }

    /// The count at a start: one more after a watchdog reset, none after any other (a power cycle, the reset pin,
    /// a restart the image asked for). The restored flag stays until the image tells it.
    pub const fn at_start(self, watchdog_reset: bool) -> CrashCount {
        CrashCount {
            crashes: if watchdog_reset {
                self.crashes.saturating_add(1)
            } else {
                0
            },
            restored: self.restored,
        }
    }

    /// Whether the running image has crashed early often enough to be undone.
    pub const fn undo_due(self) -> bool {
        self.crashes >= EARLY_CRASHES
    }
}

/// The double words of the verdict's and of the told mark's slots.
pub const SLOTS: usize = 8;

/// The slots of a [`checked_word`] written once, as a page holds them: `SLOTS` double words.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Slots(pub [u8; 8 * SLOTS]);

impl Slots {
    /// The value of the first whole word, if there is one.
    pub fn value(&self) -> Option<u32> {
        self.0
            .chunks_exact(8)
            .filter_map(|word| word.first_chunk::<8>().copied())
            .find_map(read_checked_word)
    }

    /// Where, from the slots' start, the word goes when there is none yet: the first erased slot (`None` when
    /// every slot is torn, which a writer then leaves).
    pub fn free(&self) -> Option<u32> {
        self.0
            .chunks_exact(8)
            .position(|word| word.iter().all(|byte| *byte == 0xFF))
            .map(|slot| (slot * 8) as u32)
    }
}

/// What an application writes before it marks an image for the swap: the payload's length and its signature
/// (the update file header's), 72 bytes: `b"LBVT"`, the length (u32 little-endian), the ed25519 signature.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Ticket {
    /// The signed payload's length: DFU bytes `[0, payload_len)`.
    pub payload_len: u32,
    /// The ed25519 signature over SHA-512 of those bytes.
    pub signature: [u8; 64],
}

impl Ticket {
    /// The magic bytes that open a ticket.
    pub const MAGIC: [u8; 4] = *b"LBVT";

    /// The ticket's bytes.
    pub fn to_bytes(&self) -> [u8; TICKET_LEN] {
        let mut bytes = [0; TICKET_LEN];
        let (head, signature) = bytes.split_at_mut(8);
        if let (Some(head), Some(signature)) = (head.first_chunk_mut::<8>(), signature.first_chunk_mut::<64>()) {
            let [m0, m1, m2, m3] = Ticket::MAGIC;
            let [l0, l1, l2, l3] = self.payload_len.to_le_bytes();
            *head = [m0, m1, m2, m3, l0, l1, l2, l3];
            *signature = self.signature;
        }
        bytes
    }

    /// The ticket in `bytes`, if they hold one (anything after its 72 bytes is not looked at).
    pub fn parse(bytes: &[u8]) -> Option<Ticket> {
        let bytes = bytes.first_chunk::<TICKET_LEN>()?;
        let [m0, m1, m2, m3, l0, l1, l2, l3, signature @ ..] = *bytes;
        ([m0, m1, m2, m3] == Ticket::MAGIC).then_some(Ticket {
            payload_len: u32::from_le_bytes([l0, l1, l2, l3]),
            signature,
        })
    }
}

/// The shortest payload a bootloader takes: one that holds its image info and the key after it.
pub const MIN_PAYLOAD: u32 = (INFO_OFFSET + INFO_LEN + KEY_LEN) as u32;

/// Why a bootloader refused an image marked for the swap. Each has a code (1..=15: a thruster reports it in four
/// bits of its `Version` reply) and a sentence.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Verdict {
    /// The signature over DFU's payload does not check with the running image's key.
    Signature = 1,
    /// DFU holds bytes past the signed payload, in its last page.
    PastPayload = 2,
    /// The image is older than the one that runs, and was not signed as a rollback.
    Older = 3,
    /// Its security counter is below the one the bootloader keeps.
    Counter = 4,
    /// No ticket: the image was marked without one.
    NoTicket = 5,
    /// It is for another target than the image that runs.
    Target = 6,
    /// The ticket's length is not a payload this board takes.
    Length = 7,
    /// DFU's payload has no image info of format 2 (which carries the key the next update is checked with).
    NoInfo = 8,
    /// The running image carries no update key (no format-2 image info): nothing can be checked.
    NoKey = 9,
    /// The flash failed while the bootloader checked.
    Flash = 10,
}

impl Verdict {
    /// Every verdict, in code order.
    pub const ALL: [Verdict; 10] = [
        Verdict::Signature,
        Verdict::PastPayload,
        Verdict::Older,
        Verdict::Counter,
        Verdict::NoTicket,
        Verdict::Target,
        Verdict::Length,
        Verdict::NoInfo,
        Verdict::NoKey,
        Verdict::Flash,
    ];

    /// Its code, 1..=15.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The verdict of a code; `None` for 0 (no verdict) and a code this build does not know.
    pub fn from_code(code: u8) -> Option<Verdict> {
        Verdict::ALL.into_iter().find(|verdict| verdict.code() == code)
    }

    /// Its word in the record ([`VERDICT_OFFSET`]).
    pub const fn to_word(self) -> [u8; 8] {
        checked_word(self as u32)
    }

    /// The verdict a record's word holds: `None` for an erased or torn word or an unknown code.
    pub fn from_word(word: [u8; 8]) -> Option<Verdict> {
        Verdict::from_value(read_checked_word(word)?)
    }

    /// The verdict the record's slots hold ([`VERDICT_OFFSET`]): the first whole word's.
    pub fn from_slots(slots: &Slots) -> Option<Verdict> {
        Verdict::from_value(slots.value()?)
    }

    fn from_value(value: u32) -> Option<Verdict> {
        u8::try_from(value).ok().and_then(Verdict::from_code)
    }
}

/// "signature", "older than the image it runs": what follows "refused by its bootloader: ".
impl fmt::Display for Verdict {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Verdict::Signature => "signature",
            Verdict::PastPayload => "bytes past its payload",
            Verdict::Older => "older than the image it runs",
            Verdict::Counter => "security counter below the vehicle's",
            Verdict::NoTicket => "marked without a ticket",
            Verdict::Target => "for another target",
            Verdict::Length => "payload length",
            Verdict::NoInfo => "no image info with a key",
            Verdict::NoKey => "the running image names no key",
            Verdict::Flash => "flash error",
        })
    }
}

/// A u32 as a double word that a power cut cannot leave looking whole: the value and its complement, both
/// little-endian.
pub const fn checked_word(value: u32) -> [u8; 8] {
    let [a, b, c, d] = value.to_le_bytes();
    let [e, f, g, h] = (!value).to_le_bytes();
    [a, b, c, d, e, f, g, h]
}

/// The value of a [`checked_word`]; `None` for an erased word (all 0xFF) and for any word whose halves do not
/// complement each other, such as one torn while it was programmed.
pub const fn read_checked_word(word: [u8; 8]) -> Option<u32> {
    let [a, b, c, d, e, f, g, h] = word;
    let value = u32::from_le_bytes([a, b, c, d]);
    if u32::from_le_bytes([e, f, g, h]) == !value && value != u32::MAX {
        Some(value)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ticket_is_its_documented_bytes() {
        let mut signature = [0; 64];
        for (i, byte) in signature.iter_mut().enumerate() {
            *byte = i as u8;
        }
        let ticket = Ticket {
            payload_len: 0x0001_2340,
            signature,
        };
        let bytes = ticket.to_bytes();
        assert_eq!(&bytes[..4], b"LBVT");
        assert_eq!(bytes[4..8], [0x40, 0x23, 0x01, 0x00]);
        assert_eq!(bytes[8..], signature);
        assert_eq!(Ticket::parse(&bytes), Some(ticket));
        assert_eq!(Ticket::parse(&bytes[..71]), None);
        assert_eq!(Ticket::parse(&[0xFF; 80]), None, "an erased page holds none");
        assert!(TICKET_OFFSET as usize + TICKET_LEN <= VERDICT_OFFSET as usize);
        assert_eq!(VERDICT_OFFSET as usize + 8 * SLOTS, TOLD_OFFSET as usize);
        assert_eq!(TICKET_LEN % 8, 0, "written in whole double words");
    }

    #[test]
    fn a_checked_word_survives_no_torn_write() {
        for value in [0, 1, 7, 0x8000_0000, u32::MAX - 1] {
            let word = checked_word(value);
            assert_eq!(read_checked_word(word), Some(value));
            // A programming cut short leaves bits that were to become 0 at 1 (erased): any such word is refused.
            for bit in 0..64 {
                let (byte, mask) = (bit / 8, 1u8 << (bit % 8));
                if word[byte] & mask == 0 {
                    let mut torn = word;
                    torn[byte] |= mask;
                    assert_eq!(read_checked_word(torn), None, "{value:#x} with bit {bit} still erased");
                }
            }
        }
        assert_eq!(read_checked_word([0xFF; 8]), None, "erased");
        assert_eq!(read_checked_word([0; 8]), None, "zeroed");
    }

    #[test]
    fn verdicts_have_codes_of_four_bits_and_words() {
        for verdict in Verdict::ALL {
            assert!((1..=15).contains(&verdict.code()), "{verdict:?}");
            assert_eq!(Verdict::from_code(verdict.code()), Some(verdict));
            assert_eq!(Verdict::from_word(verdict.to_word()), Some(verdict));
        }
        assert_eq!(Verdict::from_code(0), None);
        assert_eq!(Verdict::from_code(15), None);
        assert_eq!(Verdict::from_word([0xFF; 8]), None);
        assert_eq!(Verdict::from_word(checked_word(300)), None);
        assert_eq!(Verdict::Signature.to_string(), "signature");
    }

    #[test]
    fn the_previous_entry_reads_only_whole() {
        let previous = Previous {
            digest: [0x5A; DIGEST_LEN],
        };
        let bytes = previous.to_bytes();
        assert_eq!(Previous::parse(&bytes), Some(previous));
        assert_eq!(Previous::parse(&[0xFF; PREVIOUS_LEN]), None, "erased");
        // Cut before or during its closing word: no entry.
        let mut torn = bytes;
        torn[DIGEST_LEN..].fill(0xFF);
        assert_eq!(Previous::parse(&torn), None);
        torn[DIGEST_LEN..DIGEST_LEN + 4].copy_from_slice(&bytes[DIGEST_LEN..DIGEST_LEN + 4]);
        assert_eq!(Previous::parse(&torn), None);
        assert!(APPLIER_OFFSET as usize + 8 <= PREVIOUS_OFFSET as usize);
        assert_eq!(PREVIOUS_OFFSET % 8, 0, "written in whole double words");
        assert_eq!(PREVIOUS_LEN % 8, 0);
    }

    #[test]
    fn early_crashes_count_up_and_anything_else_clears_them() {
        let none = CrashCount::default();
        // A power-on leaves the register zero: no count.
        assert_eq!(CrashCount::from_word(0), none);
        assert_eq!(CrashCount::from_word(u32::MAX), none);
        let mut count = none;
        for crash in 1..=EARLY_CRASHES {
            assert!(!count.undo_due());
            count = CrashCount::from_word(count.to_word()).at_start(true);
            assert_eq!(count.crashes, crash);
        }
        assert!(count.undo_due());
        // A restart the image asked for, the reset pin or a power cycle start the count again.
        assert_eq!(count.at_start(false).crashes, 0);
        let restored = CrashCount {
            crashes: 0,
            restored: true,
        };
        assert_eq!(CrashCount::from_word(restored.to_word()), restored);
        assert!(restored.at_start(false).restored, "kept until told");
        // A word with its check byte off reads as none.
        assert_eq!(CrashCount::from_word(count.to_word() ^ 0x100), none);
        let many = CrashCount {
            crashes: u8::MAX,
            restored: false,
        };
        assert_eq!(
            CrashCount::from_word(many.to_word()).crashes,
            0x7F,
            "held at its largest"
        );
    }

    #[test]
    fn a_torn_slot_is_passed_over() {
        let mut slots = Slots([0xFF; 8 * SLOTS]);
        assert_eq!((Verdict::from_slots(&slots), slots.free()), (None, Some(0)));
        // The first slot torn: no verdict, and the next slot is where it goes.
        let mut torn = Verdict::Older.to_word();
        torn[2] |= 0x80;
        slots.0[..8].copy_from_slice(&torn);
        assert_eq!((Verdict::from_slots(&slots), slots.free()), (None, Some(8)));
        slots.0[8..16].copy_from_slice(&Verdict::Older.to_word());
        assert_eq!(Verdict::from_slots(&slots), Some(Verdict::Older));
        // Every slot torn: nowhere left.
        let all_torn = Slots([0x00; 8 * SLOTS]);
        assert_eq!((all_torn.value(), all_torn.free()), (None, None));
    }
}
