//! The thruster controller's slave port on lbv-sim's simulated bus, and its bootloader state and field update on
//! lbv-sim's flash: the ports the bench (`lbv`, with Cargo feature `sim`) and this crate's host tests run the core
//! on. Host only.

extern crate std;

use std::cell::Cell;
use std::rc::Rc;

use crate::ports::{BootState, I2cTarget, MarkError, Request, Updater};
use crate::update::{mark_for_swap, verdict_in};
use embassy_boot::{FirmwareState, FirmwareUpdaterError, State};
use g431_hw::memory::{PAGE, THRUSTER_PARTITIONS};
use lbv_sim::flash::Flash;
use lbv_sim::i2c::{Target, TargetError};
use tmc_proto::Family;
use tmc_proto::ext::{INFO_LEN, RECORD_LEN};
use update_image::{ImageInfo, Ticket, Verdict, Version};

/// A firmware slave port on a simulated bus ([`lbv_sim::i2c::Bus::target`]), as the controller's I2C task takes it.
#[derive(Debug)]
pub struct SlavePort(pub Target);

impl I2cTarget for SlavePort {
    type Error = TargetError;

    async fn listen(&mut self) -> Result<Request, TargetError> {
        Ok(match self.0.listen().await? {
            lbv_sim::i2c::Request::Write => Request::Write,
            lbv_sim::i2c::Request::Read => Request::Read,
        })
    }

    async fn respond_to_write(&mut self, buffer: &mut [u8]) -> Result<usize, TargetError> {
        self.0.respond_to_write(buffer).await
    }

    async fn respond_to_read(&mut self, data: &[u8]) -> Result<(), TargetError> {
        self.0.respond_to_read(data).await
    }

    fn reset(&mut self) {
        self.0.reset();
    }
}

/// The bootloader's state partition on lbv-sim's flash (one page, as on the chip), read and written by embassy-boot's
/// own code, as the binding's `BootRecord` does on the G431.
#[derive(Debug, Clone)]
pub struct BootRecord(pub Flash<8, 2048>);

impl BootState for BootRecord {
    type Error = FirmwareUpdaterError;

    async fn on_trial(&mut self) -> Result<bool, FirmwareUpdaterError> {
        let mut word = [0; 8];
        Ok(FirmwareState::new(&mut self.0, &mut word).get_state().await? == State::Swap)
    }

    async fn confirm(&mut self) -> Result<(), FirmwareUpdaterError> {
        let mut word = [0; 8];
        FirmwareState::new(&mut self.0, &mut word).mark_booted().await
    }
}

/// The DFU partition's pages (60 KiB, as on the G431), for a DFU flash of its own.
#[allow(
    dead_code,
    reason = "thruster-fw's tests give the controller a DFU flash of its own; the bench a partition of its chip's"
)]
pub(crate) const DFU_PAGES: usize = (THRUSTER_PARTITIONS.dfu.length / PAGE) as usize;

/// The bootloader's and the chip's side of a field update, as the binding's is on the G431: the ticket written and
/// the payload marked in the state partition ([`crate::update::mark_for_swap`]), the bootloader's verdict
/// read beside the ticket; a reboot is counted, and the bench, which watches the count, resets the thruster (its
/// bootloader then checks the image and swaps it in). The partitions may be whole flashes or views of one chip's
/// flash ([`Flash::partition`]).
#[derive(Debug, Clone)]
pub struct BootUpdater {
    /// The bootloader record's first page: the ticket, the verdict.
    pub(crate) ticket: Flash<8, 2048>,
    /// The bootloader's state partition (the trial's [`BootRecord`] shares it).
    pub(crate) state: Flash<8, 2048>,
    /// The running image's information record.
    pub info: [u8; INFO_LEN],
    /// Reboots asked for (clones share the count).
    pub reboots: Rc<Cell<u32>>,
    /// The post-mortem record the chip's start found, as the bench leaves it after a stop it models.
    pub post_mortem: Option<[u8; RECORD_LEN]>,
}

impl BootUpdater {
    /// An updater for a thruster of `family` running version 0.1.0.
    pub fn new(family: Family, ticket: Flash<8, 2048>, state: Flash<8, 2048>) -> Self {
        Self {
            ticket,
            state,
            info: info_record(family, Version::new(0, 1, 0)),
            reboots: Rc::new(Cell::new(0)),
            post_mortem: None,
        }
    }
}

/// The information record of a thruster image of `family` at `version`, as the image embeds it.
pub(crate) fn info_record(family: Family, version: Version) -> [u8; INFO_LEN] {
    ImageInfo::new(update_image::Target::thruster(family), version).to_bytes()
}

impl Updater for BootUpdater {
    fn running_info(&mut self) -> [u8; INFO_LEN] {
        self.info
    }

    fn checks_signatures(&self) -> bool {
        true
    }

    fn mark_updated(&mut self, ticket: &Ticket) -> Result<(), MarkError> {
        mark_for_swap(&mut self.ticket.clone(), &mut self.state.clone(), ticket)
    }

    fn verdict(&mut self) -> Option<Verdict> {
        verdict_in(&mut self.ticket.clone())
    }

    fn reboot(&mut self) {
        self.reboots.set(self.reboots.get() + 1);
    }

    fn post_mortem(&self) -> Option<[u8; RECORD_LEN]> {
        self.post_mortem
    }
}
