//! NUCLEO-G431RB wiring of the master node, its build-time settings, and the adapters from embassy-stm32
//! peripherals to the core's ports.
//!
//! The pins are `g431_hw::images::MASTER`, checked at build time against what the NUCLEO puts on each pin; the
//! I2C and CAN timings come from `g431_hw`.

use embassy_embedded_hal::SetConfig;
use embassy_stm32::can::{self, Can};
use embassy_stm32::i2c::{self, I2c, Master};
use embassy_stm32::mode::Async;
use embassy_stm32::pac;
use embassy_stm32::pac::gpio::vals::Moder;
use embassy_stm32::time::Hertz;
use embassy_time::{Duration, Instant, Timer};
use embedded_hal_async::i2c::{ErrorType, Operation};
use g431_hw::{fdcan, images, pins};
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

/// The battery bus's nominal bit timing, from the 24 MHz crystal: 24 tq, sample point 79 %, SJW 5, which
/// tolerates 0.81 % of clock error per node (`g431_hw::fdcan`).
pub const CAN_TIMING: fdcan::BitTiming = match fdcan::nominal(
    g431_hw::clock::FDCAN_KERNEL_HZ,
    CAN_BITRATE,
    fdcan::SAMPLE_POINT_PERMILLE,
    fdcan::BUS_DELAY_NS,
) {
    Ok(timing) => timing,
    Err(_) => fdcan::BitTiming {
        prescaler: 1,
        tseg1: 1,
        tseg2: 1,
        sjw: 1,
    },
};
const _: () = assert!(
    CAN_TIMING.is_valid()
        && CAN_TIMING.bitrate(g431_hw::clock::FDCAN_KERNEL_HZ) == CAN_BITRATE
        && CAN_TIMING.tolerance_ppm(g431_hw::clock::FDCAN_KERNEL_HZ, fdcan::BUS_DELAY_NS) >= 10 * fdcan::CRYSTAL_PPM
);

// A pin used twice, or one the NUCLEO drives or loads, fails the build.
const _: () = assert!(pins::check(&images::MASTER).is_ok());
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

/// How long the person at the bench gets for each prompt before the script goes on. The power cycle happens while
/// the script keeps the bus busy (for `reset_window`, 15 s), so its prompt only gives time to reach the cable.
#[cfg(feature = "acceptance")]
pub const fn prompt_wait(prompt: Prompt) -> Duration {
    match prompt {
        Prompt::FitWaterResistor => Duration::from_secs(15),
        Prompt::RemoveWaterResistor => Duration::from_secs(10),
        Prompt::HoldRotor => Duration::from_secs(8),
        Prompt::ReleaseRotor => Duration::from_secs(5),
        Prompt::ResetThruster => Duration::from_secs(5),
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

/// Write a standard-mode TIMINGR (`g431_hw::i2c`) into an I2C peripheral, over embassy-stm32's own value,
/// disabling it meanwhile as RM0440 requires.
pub fn set_i2c_timing(regs: pac::i2c::I2c) {
    regs.cr1().modify(|w| w.set_pe(false));
    regs.timingr()
        .write_value(pac::i2c::regs::Timingr(g431_hw::i2c::TIMINGR));
    regs.cr1().modify(|w| w.set_pe(true));
}

/// How often a busy bus is looked at again.
const BUSY_POLL: Duration = Duration::from_micros(100);

/// A thruster bus: embassy-stm32's I2C master, its registers, and the pins for clearing a stuck bus.
pub struct ThrusterBus {
    pub i2c: I2c<'static, Async, Master>,
    pub regs: pac::i2c::I2c,
    pub scl: Pin,
    pub sda: Pin,
}

impl ThrusterBus {
    /// Wait, yielding, until the bus is free (ISR.BUSY clear), for at most a transfer's timeout. embassy-stm32
    /// waits for BUSY in a blocking loop before a write's START, which would stall every task of the executor for
    /// as long as another master or a stuck slave holds the bus.
    async fn bus_free(&self) -> Result<(), i2c::Error> {
        let start = Instant::now();
        while self.regs.isr().read().busy() {
            if start.elapsed() >= TRANSFER_TIMEOUT {
                return Err(i2c::Error::Timeout);
            }
            Timer::after(BUSY_POLL).await;
        }
        Ok(())
    }
}

impl ErrorType for ThrusterBus {
    type Error = i2c::Error;
}

impl embedded_hal_async::i2c::I2c for ThrusterBus {
    async fn transaction(&mut self, address: u8, operations: &mut [Operation<'_>]) -> Result<(), i2c::Error> {
        self.bus_free().await?;
        self.i2c.transaction(address, operations).await
    }
}

impl BusRecovery for ThrusterBus {
    /// UM10204 3.1.16: clock SCL (open drain, 5 us half periods) until the slave holding SDA lets go, at most
    /// 9 times, then a STOP; the pins go back to the peripheral, which is re-initialised. The peripheral is
    /// disabled (PE = 0) meanwhile, so it neither drives the lines nor takes the bit-banged edges for traffic.
    async fn recover(&mut self) -> bool {
        const HALF_BIT: Duration = Duration::from_micros(5);
        self.regs.cr1().modify(|w| w.set_pe(false));
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
        // Re-applying the bus speed turns the peripheral on again with a clean state machine; then our timing.
        let _ = self.i2c.set_config(&BUS_SPEED);
        set_i2c_timing(self.regs);
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
