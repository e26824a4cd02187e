//! Interrupts, peripheral set-up and tasks of the thruster image.

use defmt::{info, unwrap, warn};
use embassy_executor::Spawner;
use embassy_stm32::i2c::{self, I2c, SlaveAddrConfig};
use embassy_stm32::{bind_interrupts, dma, peripherals};
use embassy_time::Duration;
use thruster_fw::{Link, ServeEvent, serve_once};
use tmc_proto::MotorKind;
use {defmt_rtt as _, panic_probe as _};

use crate::board::{FAMILY, SlavePort};

bind_interrupts!(struct Irqs {
    I2C3_EV => i2c::EventInterruptHandler<peripherals::I2C3>;
    I2C3_ER => i2c::ErrorInterruptHandler<peripherals::I2C3>;
    DMA1_CHANNEL1 => dma::InterruptHandler<peripherals::DMA1_CH1>;
    DMA1_CHANNEL2 => dma::InterruptHandler<peripherals::DMA1_CH2>;
});

/// SMBus calls SCL held low for longer than this a timeout; a transfer that stalls this long is abandoned.
const TRANSFER_TIMEOUT: Duration = Duration::from_millis(25);

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let p = embassy_stm32::init(Default::default());
    info!(
        "thruster-fw: {} controller at I2C address {=u8:#x}",
        FAMILY.name(),
        FAMILY.address()
    );

    let mut config = i2c::Config::default();
    config.timeout = TRANSFER_TIMEOUT;
    let slave = I2c::new(p.I2C3, p.PC8, p.PC9, p.DMA1_CH1, p.DMA1_CH2, Irqs, config)
        .into_slave_multimaster(SlaveAddrConfig::basic(FAMILY.address()));

    spawner.spawn(unwrap!(i2c_task(
        SlavePort(slave),
        Link::new(FAMILY, MotorKind::Brushless)
    )));
}

#[embassy_executor::task]
async fn i2c_task(mut port: SlavePort, mut link: Link) -> ! {
    loop {
        match serve_once(&mut port, &mut link).await {
            Ok(ServeEvent::Order(order)) => info!("order: step {} info {}", order.speed.step(), order.info),
            Ok(ServeEvent::Rejected(error)) => warn!("order discarded: {} ({} so far)", error, link.errors().total()),
            Ok(ServeEvent::StatusSent) => {}
            Err(error) => warn!("I2C: {}", error),
        }
    }
}
