//! NUCLEO-G431RB wiring of the thruster controller and the adapters from embassy-stm32 to the core's ports.

use embassy_stm32::i2c::{self, I2c, SlaveCommandKind};
use embassy_stm32::mode::Async;
use thruster_fw::{I2cTarget, Request};
use tmc_proto::Family;

/// The controller family this image answers as (Cargo feature `legacy`).
pub const FAMILY: Family = if cfg!(feature = "legacy") {
    Family::Legacy
} else {
    Family::SeaBotix
};

/// I2C3 as the thruster interface's slave port: SCL on PC8 (CN10 pin 2), SDA on PC9 (CN10 pin 1).
pub struct SlavePort(pub I2c<'static, Async, i2c::MultiMaster>);

impl I2cTarget for SlavePort {
    type Error = i2c::Error;

    async fn listen(&mut self) -> Result<Request, i2c::Error> {
        // Only the family's own address is configured, so every match is ours.
        let command = self.0.listen().await?;
        Ok(match command.kind {
            SlaveCommandKind::Write => Request::Write,
            SlaveCommandKind::Read => Request::Read,
        })
    }

    async fn respond_to_write(&mut self, buffer: &mut [u8]) -> Result<usize, i2c::Error> {
        self.0.respond_to_write(buffer).await
    }

    async fn respond_to_read(&mut self, data: &[u8]) -> Result<(), i2c::Error> {
        self.0.respond_to_read(data).await.map(|_| ())
    }
}
