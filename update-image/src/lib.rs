//! The signed update image: its format, built by `lbv image`, checked by the thruster and the master.
//!
//! Field update carries one file per target (docs/field-update.md): an 80-byte [`Header`] and the payload, the
//! application binary exactly as it sits in flash from the start of the ACTIVE partition, padded with 0xFF to the
//! flash write unit ([`WRITE_UNIT`]). The thruster writes the payload into its DFU partition and hands embassy-boot
//! the header's signature with `FirmwareUpdater::verify_and_mark_updated(public_key, signature, payload_len)`,
//! which checks an ed25519 signature over the SHA-512 digest of DFU bytes `[0, payload_len)`. So the signature
//! covers the payload alone, not the header: the header only routes the file (which target, how long) before
//! the payload arrives.
//!
//! What makes the header trustworthy is the [`ImageInfo`] record every image embeds at [`INFO_OFFSET`]: it is part
//! of the payload, hence signed, and [`check()`] holds the header to it (same target, same version), then the
//! target to the device's own, and the length to the partition. A receiver can do this as soon as the first
//! `INFO_OFFSET + INFO_LEN` payload bytes are in, long before the signature can be checked.
//!
//! Every decoder answers every input with a value or a typed error; nothing here panics.
//!
//! Features: `key` (the [`UPDATE_KEY`] a firmware takes updates with, from `LBV_UPDATE_KEY`), `verify` (`Verifier`,
//! no_std, the salty ed25519 embassy-boot uses), `sign` (`sign` and `keygen`, std, ed25519-dalek), `defmt`.
//!
//! ```
//! use update_image::{INFO_LEN, INFO_OFFSET, ImageInfo, Target, Version};
//!
//! // What a firmware image embeds (the linker script puts `.image_info` at INFO_OFFSET):
//! // #[unsafe(link_section = ".image_info")]
//! // #[used]
//! // static IMAGE_INFO: [u8; INFO_LEN] = INFO.to_bytes();
//! const VERSION: Version = match Version::parse(env!("CARGO_PKG_VERSION")) {
//!     Some(version) => version,
//!     None => Version::new(0, 0, 0),
//! };
//! const INFO: ImageInfo = ImageInfo::new(Target::ThrusterSeabotix, VERSION);
//! const BYTES: [u8; INFO_LEN] = INFO.to_bytes();
//! assert_eq!(ImageInfo::parse(&BYTES), Ok(INFO));
//! assert_eq!(INFO_OFFSET, 0x200);
//! ```
#![cfg_attr(not(any(test, feature = "sign")), no_std)]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

mod bootloader;
mod check;
mod header;
mod hex;
mod info;
mod key;
#[cfg(feature = "sign")]
mod sign;
mod target;
#[cfg(feature = "verify")]
mod verify;
mod version;

pub use bootloader::{
    APPLIER_OFFSET, CrashCount, DIGEST_LEN, EARLY_CRASHES, EARLY_WINDOW_SECS, MIN_PAYLOAD, PREVIOUS_LEN,
    PREVIOUS_OFFSET, Previous, SLOTS, Slots, TICKET_LEN, TICKET_OFFSET, TOLD_OFFSET, Ticket, VERDICT_OFFSET, Verdict,
    checked_word, read_checked_word,
};
pub use check::{Refusal, check, check_file, check_upgrade};
pub use header::{Header, HeaderError};
pub use info::{ImageInfo, InfoError, image_record};
pub use key::{DEV_PUBLIC_KEY, key_from_hex};
#[cfg(feature = "key")]
pub use key::{UPDATE_KEY, UPDATE_KEY_IS_DEV};
#[cfg(feature = "sign")]
pub use sign::{SignError, keygen, public_key, sign};
pub use target::Target;
#[cfg(feature = "verify")]
pub use verify::{Verifier, VerifyError, verify};
pub use version::Version;

/// Where the [`ImageInfo`] sits, from the start of the image (the start of the ACTIVE partition).
///
/// The application's vector table is at offset 0; the STM32G431's is 472 bytes (16 system exception slots and 102
/// interrupts, FMAC the last at 101, 4 bytes each, as stm32-metapac's stm32g431rb lists them), so the record goes
/// at the next round offset after it, where a linker script can place it whatever the table's exact length.
pub const INFO_OFFSET: usize = 0x200;

/// Length of the [`ImageInfo`] record, in bytes.
pub const INFO_LEN: usize = 32;

/// Where an image keeps, right after its [`ImageInfo`], the ed25519 public key it takes updates with (its build's
/// [`UPDATE_KEY`], feature `key`): the bootloader checks a new image's signature with the key of the image that
/// runs, so the key an image embeds decides which files the vehicle takes after it. Format-2 images only.
pub const KEY_OFFSET: usize = INFO_OFFSET + INFO_LEN;

/// Length of the embedded key, in bytes.
pub const KEY_LEN: usize = 32;

/// What an image's `.image_info` section holds: its [`ImageInfo`] and its update key ([`image_record`]).
pub const IMAGE_RECORD_LEN: usize = INFO_LEN + KEY_LEN;

/// Length of the update file's [`Header`], in bytes.
pub const HEADER_LEN: usize = 80;

/// The flash write unit of the STM32G431, a double word (RM0440 3.3.7): the payload is a whole number of them, so
/// that the thruster can program every byte it receives and embassy-boot hashes exactly what was written.
pub const WRITE_UNIT: usize = 8;

/// What the payload is padded with: erased flash.
pub const PAD_BYTE: u8 = 0xFF;

/// The update file's format: the [`Header`] this crate writes and reads. A header of another format is refused,
/// not guessed at.
pub const FORMAT: u8 = 1;

/// The [`ImageInfo`]'s format this crate writes; it reads formats 1 and 2 (format 1 has no flags, no security
/// counter and no key record after it).
pub const INFO_FORMAT: u8 = 2;
