//! NUCLEO-G431RB wiring of the master node, its build-time settings, and the adapters from embassy-stm32
//! peripherals to the core's ports.
//!
//! | function | pins | peripheral |
//! |---|---|---|
//! | thruster bus 1 SCL / SDA | PA15 / PB7 (CN7 17 / 21) | I2C1 |
//! | thruster bus 2 SCL / SDA | PA9 / PA8 (Arduino D8 / D7) | I2C2 |
//! | thruster bus 3 SCL / SDA | PC8 / PC9 (CN10 2 / 1) | I2C3 |
//! | battery CAN RX / TX (to a 3.3 V transceiver) | PA11 / PA12 (CN10 14 / 12) | FDCAN1 |
//! | operator console (ST-LINK virtual COM port) | PA2 TX / PA3 RX | LPUART1 |

use embassy_embedded_hal::SetConfig;
use embassy_stm32::can::{self, Can};
use embassy_stm32::i2c::{self, I2c, Master};
use embassy_stm32::mode::Async;
use embassy_stm32::pac;
use embassy_stm32::pac::gpio::vals::Moder;
use embassy_stm32::time::Hertz;
use embassy_time::{Duration, Timer};
use embedded_hal_async::i2c::{ErrorType, Operation};
#[cfg(feature = "acceptance")]
use lbv_master_fw::acceptance::{AcceptanceConfig, Prompt};
use lbv_master_fw::battery::{CanFrame, CanReceiver};
use lbv_master_fw::thrusters::{BusRecovery, PollConfig, ThrusterSlot};
use tmc_proto::Family;

/// IDS 6.4.1: the thruster buses run at 100 kbit/s.
pub const BUS_SPEED: Hertz = Hertz::khz(100);
/// A transfer stalled this long (SMBus's SCL-low timeout) is abandoned; embassy's default is 1 s.
pub const TRANSFER_TIMEOUT: Duration = Duration::from_millis(25);
/// The battery CAN bus bit rate.
pub const CAN_BITRATE: u32 = 1_000_000;
/// The console's serial link (the ST-LINK virtual COM port).
pub const CONSOLE_BAUD: u32 = 115_200;
/// Thruster polling: 50 Hz per thruster, retries of a missing one from 100 ms doubling to 2 s.
#[cfg_attr(
    feature = "acceptance",
    allow(dead_code, reason = "the acceptance image runs its script, not the poll")
)]
pub const POLL: PollConfig = PollConfig::DEFAULT;

/// The thruster table. The vehicle (default): an LBV300-6, six SeaBotix thrusters behind a TCA9548A on bus 2,
/// channels 0-5, numbered as in `lbv_master_fw::mixer`. With Cargo feature `devkit`: one thruster wired directly
/// to bus 2, of the family chosen by feature `legacy` (the two-board bench).
#[cfg(not(feature = "devkit"))]
pub const THRUSTERS: &[ThrusterSlot] = &[
    ThrusterSlot {
        bus: 1,
        mux_channel: Some(0),
        family: Family::SeaBotix,
    },
    ThrusterSlot {
        bus: 1,
        mux_channel: Some(1),
        family: Family::SeaBotix,
    },
    ThrusterSlot {
        bus: 1,
        mux_channel: Some(2),
        family: Family::SeaBotix,
    },
    ThrusterSlot {
        bus: 1,
        mux_channel: Some(3),
        family: Family::SeaBotix,
    },
    ThrusterSlot {
        bus: 1,
        mux_channel: Some(4),
        family: Family::SeaBotix,
    },
    ThrusterSlot {
        bus: 1,
        mux_channel: Some(5),
        family: Family::SeaBotix,
    },
];
#[cfg(feature = "devkit")]
pub const THRUSTERS: &[ThrusterSlot] = &[ThrusterSlot {
    bus: 1,
    mux_channel: None,
    family: if cfg!(feature = "legacy") {
        Family::Legacy
    } else {
        Family::SeaBotix
    },
}];

// Two thrusters that would answer the same transfer, or a bus or channel that does not exist, fail the build.
const _: () = assert!(lbv_master_fw::thrusters::check_table(THRUSTERS).is_ok());

/// How many thrusters the table holds.
pub const THRUSTER_COUNT: u8 = THRUSTERS.len() as u8;

/// The acceptance test (feature `acceptance`): the script's defaults, expecting the dev kit's family.
#[cfg(feature = "acceptance")]
pub const ACCEPTANCE: AcceptanceConfig = AcceptanceConfig {
    expect: Some(if cfg!(feature = "legacy") {
        Family::Legacy
    } else {
        Family::SeaBotix
    }),
    ..AcceptanceConfig::DEFAULT
};

/// The acceptance test waits this long after boot, so that a thruster board powered up at the same time is
/// running and the host has attached to the log.
#[cfg(feature = "acceptance")]
pub const ACCEPTANCE_START: Duration = Duration::from_secs(3);

/// How long the person at the bench gets for each prompt before the script goes on. The reset is pressed while
/// the script keeps the bus busy (for `reset_window`, 15 s), so its prompt only gives time to reach the button.
#[cfg(feature = "acceptance")]
pub const fn prompt_wait(prompt: Prompt) -> Duration {
    match prompt {
        Prompt::FitWaterResistor => Duration::from_secs(15),
        Prompt::RemoveWaterResistor => Duration::from_secs(10),
        Prompt::HoldRotor => Duration::from_secs(8),
        Prompt::ReleaseRotor => Duration::from_secs(5),
        Prompt::ResetThruster => Duration::from_secs(2),
    }
}

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

    fn drive(self, high: bool) {
        self.port.bsrr().write(|w| {
            if high {
                w.set_bs(self.number, true)
            } else {
                w.set_br(self.number, true)
            }
        });
    }

    fn is_high(self) -> bool {
        self.port.idr().read().idr(self.number) == pac::gpio::vals::Idr::HIGH
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
    /// UM10204 3.1.16: clock SCL (open drain, 5 us half periods) until the slave holding SDA lets go, at most
    /// 9 times, then a STOP; the pins go back to the peripheral, which is re-initialised.
    async fn recover(&mut self) -> bool {
        const HALF_BIT: Duration = Duration::from_micros(5);
        // The pins are already open drain (the I2C alternate function); as outputs they keep that.
        self.scl.drive(true);
        self.sda.drive(true);
        self.scl.set_mode(Moder::OUTPUT);
        for _ in 0..9 {
            if self.sda.is_high() {
                break;
            }
            self.scl.drive(false);
            Timer::after(HALF_BIT).await;
            self.scl.drive(true);
            Timer::after(HALF_BIT).await;
        }
        // STOP: SDA rises while SCL is high.
        self.sda.set_mode(Moder::OUTPUT);
        self.scl.drive(false);
        self.sda.drive(false);
        Timer::after(HALF_BIT).await;
        self.scl.drive(true);
        Timer::after(HALF_BIT).await;
        self.sda.drive(true);
        Timer::after(HALF_BIT).await;
        let released = self.sda.is_high();
        self.scl.set_mode(Moder::ALTERNATE);
        self.sda.set_mode(Moder::ALTERNATE);
        // Re-applying the bus speed turns the peripheral off and on, clearing its state machine.
        let _ = self.i2c.set_config(&BUS_SPEED);
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
