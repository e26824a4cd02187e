//! The controller's ports on lbv-sim's simulated parts, for the bench (Cargo feature `sim`, host only) and the
//! host tests.

use crate::i2c_slave::{I2cTarget, Request};

/// The slave port of lbv-sim's simulated bus.
impl I2cTarget for lbv_sim::i2c::Target {
    type Error = lbv_sim::i2c::TargetError;

    async fn listen(&mut self) -> Result<Request, Self::Error> {
        Ok(match lbv_sim::i2c::Target::listen(self).await? {
            lbv_sim::i2c::Request::Write => Request::Write,
            lbv_sim::i2c::Request::Read => Request::Read,
        })
    }

    async fn respond_to_write(&mut self, buffer: &mut [u8]) -> Result<usize, Self::Error> {
        lbv_sim::i2c::Target::respond_to_write(self, buffer).await
    }

    async fn respond_to_read(&mut self, data: &[u8]) -> Result<(), Self::Error> {
        lbv_sim::i2c::Target::respond_to_read(self, data).await
    }

    fn reset(&mut self) {
        lbv_sim::i2c::Target::reset(self);
    }
}
