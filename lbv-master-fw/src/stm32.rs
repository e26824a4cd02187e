//! Interrupts, peripheral set-up and tasks of the master image.

use defmt::{info, unwrap, warn};
use embassy_executor::Spawner;
use embassy_stm32::i2c::{self, I2c, Master};
use embassy_stm32::mode::Async;
use embassy_stm32::time::Hertz;
use embassy_stm32::{bind_interrupts, dma, peripherals};
use embassy_time::{Duration, Ticker};
use lbv_master_fw::poll_thruster;
use tmc_proto::{Family, Order};
use {defmt_rtt as _, panic_probe as _};

bind_interrupts!(struct Irqs {
    I2C2_EV => i2c::EventInterruptHandler<peripherals::I2C2>;
    I2C2_ER => i2c::ErrorInterruptHandler<peripherals::I2C2>;
    DMA1_CHANNEL3 => dma::InterruptHandler<peripherals::DMA1_CH3>;
    DMA1_CHANNEL4 => dma::InterruptHandler<peripherals::DMA1_CH4>;
});

/// IDS 6.4.1: the motherboard is an I2C master at 100 kbit/s.
const BUS_SPEED: Hertz = Hertz::khz(100);
/// A transfer stalled for this long (SMBus's SCL-low timeout) is abandoned; embassy's default is 1 s.
const TRANSFER_TIMEOUT: Duration = Duration::from_millis(25);
/// Each thruster is polled at 50 Hz.
const POLL_PERIOD: Duration = Duration::from_millis(20);
/// The family of the one thruster this image polls (Cargo feature `legacy`).
const THRUSTER: Family = if cfg!(feature = "legacy") {
    Family::Legacy
} else {
    Family::SeaBotix
};

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let p = embassy_stm32::init(Default::default());
    info!(
        "lbv-master-fw: polling the {} thruster at {=u8:#x}",
        THRUSTER.name(),
        THRUSTER.address()
    );

    let mut config = i2c::Config::default();
    config.frequency = BUS_SPEED;
    config.timeout = TRANSFER_TIMEOUT;
    // I2C2: SCL on PA9 (Arduino D8), SDA on PA8 (Arduino D7).
    let bus = I2c::new(p.I2C2, p.PA9, p.PA8, p.DMA1_CH3, p.DMA1_CH4, Irqs, config);

    spawner.spawn(unwrap!(poll_task(bus)));
}

#[embassy_executor::task]
async fn poll_task(mut bus: I2c<'static, Async, Master>) -> ! {
    // No console link yet: the thruster is ordered to stay stopped.
    let order = Order::STOP;
    let mut ticker = Ticker::every(POLL_PERIOD);
    let mut last = None;
    loop {
        let result = poll_thruster(&mut bus, THRUSTER, order).await;
        // Log changes only: at 50 Hz a line per poll would drown the log.
        if last.as_ref() != Some(&result) {
            match &result {
                Ok(status) => info!("status: {}", status),
                Err(error) => warn!("poll failed: {}", error),
            }
        }
        last = Some(result);
        ticker.next().await;
    }
}
