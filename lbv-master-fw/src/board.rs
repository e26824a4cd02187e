//! NUCLEO-G431RB wiring of the master node and the adapters from embassy-stm32 peripherals to the core's ports;
//! the settings they are configured with are the core's (`lbv_master_fw::CONFIG`).
//!
//! | function | pins | peripheral |
//! |---|---|---|
//! | thruster bus 1 SCL / SDA | PA15 / PB7 (CN7 17 / 21) | I2C1 |
//! | thruster bus 2 SCL / SDA | PA9 / PA8 (Arduino D8 / D7) | I2C2 |
//! | thruster bus 3 SCL / SDA | PC8 / PC9 (CN10 2 / 1) | I2C3 |
//! | battery CAN RX / TX (to a 3.3 V transceiver) | PA11 / PA12 (CN10 14 / 12) | FDCAN1 |
//! | operator console (ST-LINK virtual COM port) | PA2 TX / PA3 RX | LPUART1 |

use core::convert::Infallible;

use embassy_embedded_hal::SetConfig;
use embassy_stm32::can::{self, Can};
use embassy_stm32::i2c::{self, I2c, Master};
use embassy_stm32::mode::Async;
use embassy_stm32::pac;
use embassy_stm32::pac::gpio::vals::Moder;
use embassy_stm32::time::Hertz;
use embassy_time::Delay;
use embedded_hal::digital::{ErrorType as PinErrorType, InputPin, OutputPin};
use embedded_hal_async::i2c::{ErrorType, Operation};
use lbv_master_fw::CONFIG;
use lbv_master_fw::battery::{CanFrame, CanReceiver};
use lbv_master_fw::recovery::{BusRecovery, clear_bus};

/// One GPIO pin, named for the bus recovery's bit-banging.
#[derive(Clone, Copy)]
pub struct Pin {
    pub port: pac::gpio::Gpio,
    pub number: usize,
}

impl Pin {
    fn set_mode(self, mode: Moder) {
        self.port.moder().modify(|w| w.set_moder(self.number, mode));
    }
}

impl PinErrorType for Pin {
    type Error = Infallible;
}

/// The pins are open drain (configured so for the I2C alternate function; as outputs they keep it): high releases
/// the line.
impl OutputPin for Pin {
    fn set_low(&mut self) -> Result<(), Infallible> {
        self.port.bsrr().write(|w| w.set_br(self.number, true));
        Ok(())
    }

    fn set_high(&mut self) -> Result<(), Infallible> {
        self.port.bsrr().write(|w| w.set_bs(self.number, true));
        Ok(())
    }
}

impl InputPin for Pin {
    fn is_high(&mut self) -> Result<bool, Infallible> {
        Ok(self.port.idr().read().idr(self.number) == pac::gpio::vals::Idr::HIGH)
    }

    fn is_low(&mut self) -> Result<bool, Infallible> {
        self.is_high().map(|high| !high)
    }
}

/// A thruster bus: embassy-stm32's I2C master, plus the pins for clearing a stuck bus.
pub struct ThrusterBus {
    pub i2c: I2c<'static, Async, Master>,
    pub scl: Pin,
    pub sda: Pin,
}

impl ErrorType for ThrusterBus {
    type Error = i2c::Error;
}

impl embedded_hal_async::i2c::I2c for ThrusterBus {
    async fn transaction(&mut self, address: u8, operations: &mut [Operation<'_>]) -> Result<(), i2c::Error> {
        self.i2c.transaction(address, operations).await
    }
}

impl BusRecovery for ThrusterBus {
    /// The core's UM10204 3.1.16 recovery with the pins taken from the peripheral as GPIOs; then the pins go back
    /// to the peripheral, which is re-initialised.
    async fn recover(&mut self) -> bool {
        // Released (high) before they become outputs, so that switching them does not pull a line low.
        let _ = self.scl.set_high();
        let _ = self.sda.set_high();
        self.scl.set_mode(Moder::OUTPUT);
        self.sda.set_mode(Moder::OUTPUT);
        let released = clear_bus(&mut self.scl, &mut self.sda, &mut Delay, &CONFIG.bus).await;
        self.scl.set_mode(Moder::ALTERNATE);
        self.sda.set_mode(Moder::ALTERNATE);
        // Re-applying the bus speed turns the peripheral off and on, clearing its state machine.
        let _ = self.i2c.set_config(&Hertz(CONFIG.bus.frequency_hz));
        released
    }
}

/// FDCAN1 receiving the battery board's frames.
pub struct BatteryCan(pub Can<'static>);

impl CanReceiver for BatteryCan {
    type Error = can::enums::BusError;

    async fn receive(&mut self) -> Result<CanFrame, Self::Error> {
        loop {
            let envelope = self.0.read().await?;
            // The BAT board sends standard IDs only; extended frames on a shared bus are not ours.
            let embedded_can::Id::Standard(id) = envelope.frame.id() else {
                continue;
            };
            let data = envelope.frame.data();
            let mut frame = CanFrame {
                id: id.as_raw(),
                len: 0,
                data: [0; 8],
            };
            for (slot, byte) in frame.data.iter_mut().zip(data) {
                *slot = *byte;
            }
            frame.len = u8::try_from(data.len().min(8)).unwrap_or(8);
            return Ok(frame);
        }
    }
}
