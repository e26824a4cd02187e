//! The thruster controller's slave port on lbv-sim's simulated bus, for the bench and thruster-fw's host tests
//! (which include this file).

use lbv_sim::i2c::{Target, TargetError};
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
