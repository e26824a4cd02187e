//! The bootloader of the thruster and of the master, hardware-free: embassy-boot's decision on a NOR flash laid out
//! as the board's partitions ([`THRUSTER_PARTITIONS`](g431_hw::memory::THRUSTER_PARTITIONS),
//! [`MASTER_PARTITIONS`](g431_hw::memory::MASTER_PARTITIONS)), and what the bootloader does when it fails.
//!
//! embassy-boot keeps the images in two partitions: ACTIVE, the image that runs, and DFU, where the running image
//! writes a new one and marks it updated. At the next reset [`prepare`] swaps the two a page at a time, noting its
//! progress in the state partition after every page, so that a power cut at any point resumes where it stopped. The
//! new image then runs on trial: it marks itself booted, or at the next reset the swap is undone (the old image
//! waits in DFU, one page up). The binding (`main.rs`, `stm32.rs`) runs [`prepare`] on the chip's flash and starts
//! ACTIVE; the host tests run the same function on lbv-sim's flash, with embassy-boot's own updater on the
//! application's side.
#![cfg_attr(not(test), no_std)]

use core::cell::RefCell;

use embassy_boot::{AlignedBuffer, BootLoader, BootLoaderConfig};
use embassy_embedded_hal::flash::partition::BlockingPartition;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embedded_storage::nor_flash::NorFlash;
use g431_hw::memory::{FLASH_ORIGIN, PAGE, Partitions, Span};

pub use embassy_boot::{BootError, State};

#[cfg(test)]
mod tests;

/// The flash, shared by its partitions as embassy-boot shares it: one lock, and nothing else runs meanwhile.
pub type SharedFlash<F> = Mutex<NoopRawMutex, RefCell<F>>;

/// One partition of the shared flash.
pub type Partition<'a, F> = BlockingPartition<'a, NoopRawMutex, F>;

/// How many times [`prepare`] runs embassy-boot before it gives up. Each attempt resumes from the progress the
/// last one recorded, so a transient error costs nothing; an error that stays is not worth waiting for.
pub const ATTEMPTS: u32 = 3;

/// Every copy goes through one page of RAM (on the stack): a page moves with one read and one write.
const BUFFER: usize = PAGE as usize;

/// The partition at `span` of the flash, addressed from the flash's start as embassy-stm32's flash driver (and the
/// `__bootloader_*` symbols of the image's memory.x, printed from the same partitions) address it.
fn partition<F: NorFlash>(flash: &SharedFlash<F>, span: Span) -> Partition<'_, F> {
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
    /// Every attempt failed with a flash error, the last one this: ACTIVE is started as it is.
    Failed(BootError),
}

/// Run embassy-boot's preparation (swap, resume or revert) on `flash`, laid out as `layout`, up to [`ATTEMPTS`]
/// times.
///
/// When every attempt fails, the bootloader starts ACTIVE all the same, and that is the safe choice for a thruster
/// or a master: stopping here leaves it silent with no way back but a debug probe, in the water. An error that stays
/// is not the flash's doing: embassy-boot programs only erased double words, or zeros over its own progress words,
/// which the G4 always takes (RM0440 3.3.7); what remains is a write protection (RM0440 3.5, WRPERR), which
/// neither image sets, and which stops the swap at the first page it protects. A power cut does not end here
/// either: the next start resumes the swap. Should ACTIVE not run, the watchdog the binding starts before the jump
/// resets the chip, and the next start tries again.
pub fn prepare<F: NorFlash>(flash: &SharedFlash<F>, layout: &Partitions) -> Outcome {
    let mut buffer = AlignedBuffer([0; BUFFER]);
    let mut attempt = 1;
    loop {
        match BootLoader::new(partitions(flash, layout)).prepare_boot(&mut buffer.0) {
            Ok(state) => return Outcome::Prepared { state, attempt },
            Err(error) if attempt >= ATTEMPTS => return Outcome::Failed(error),
            Err(_) => attempt += 1,
        }
    }
}
