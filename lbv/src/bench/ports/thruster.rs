//! The thruster controller's slave port on lbv-sim's simulated bus and its bootloader state on lbv-sim's flash, for
//! the bench and thruster-fw's host tests (which include this file).

use embassy_boot::{FirmwareState, FirmwareUpdaterError, State};
use lbv_sim::flash::Flash;
use lbv_sim::i2c::{Target, TargetError};
use thruster_fw::trial::BootState;
use thruster_fw::{I2cTarget, Request};

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
