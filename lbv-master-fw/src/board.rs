//! NUCLEO-G474RE wiring of the master node and the adapters from embassy-stm32 peripherals to the core's ports;
//! the settings they are configured with are the core's (`lbv_master_fw::CONFIG`).
//!
//! The pins and peripherals are the image's description, `g431_hw::images::MASTER`, checked at build time against
//! what the NUCLEO puts on each pin; the I2C and CAN timings come from `g431_hw`.

use core::convert::Infallible;

use embassy_embedded_hal::SetConfig;
use embassy_stm32::can::{self, Can};
use embassy_stm32::gpio::{self, Pin as _};
use embassy_stm32::i2c::{self, I2c, Master};
use embassy_stm32::mode::Async;
use embassy_stm32::pac::gpio::vals::Moder;
use embassy_stm32::time::Hertz;
use embassy_stm32::{Peri, pac};
use embassy_time::{Delay, Duration, Instant, Timer};
use embedded_hal::digital::{ErrorType as PinErrorType, InputPin, OutputPin};
use embedded_hal_async::i2c::{ErrorType, Operation};
use g431_hw::fdcan;
use lbv_master_fw::CONFIG;
use lbv_master_fw::ports::{BusRecovery, CanFrame, CanReceiver};
use lbv_master_fw::recovery::clear_bus;

/// The bootloader's count of early crashes (`update_image::CrashCount`), in its backup register
/// (`g431_hw::backup::CRASH_REGISTER`). Taken once, at the start, where the reset flags are read and cleared.
pub struct CrashRegister(());

impl CrashRegister {
    /// Open the backup domain for writing (PWR_CR1.DBP, with the PWR and RTC/TAMP APB clocks on; the bootloader
    /// opened it too, but the image does not count on that), say why the chip last reset and clear the flags
    /// (RCC_CSR.RMVF), so that the bootloader's next start reads only the next reset's.
    pub fn open() -> Self {
        pac::RCC.apb1enr1().modify(|w| w.0 |= g431_hw::backup::APB1ENR1_BACKUP);
        pac::PWR.cr1().modify(|w| w.0 |= g431_hw::backup::PWR_CR1_DBP);
        let csr = pac::RCC.csr().read().0;
        if g431_hw::backup::watchdog_reset(csr) {
            defmt::warn!("reset by the watchdog (RCC_CSR {:#010x})", csr);
        } else {
            defmt::info!("reset (RCC_CSR {:#010x})", csr);
        }
        pac::RCC.csr().modify(|w| w.set_rmvf(true));
        CrashRegister(())
    }
}

impl lbv_master_fw::ports::CrashRegister for CrashRegister {
    fn load(&mut self) -> u32 {
        pac::TAMP.bkpr(g431_hw::backup::CRASH_REGISTER).read().bkp()
    }

    fn store(&mut self, word: u32) {
        pac::TAMP
            .bkpr(g431_hw::backup::CRASH_REGISTER)
            .write(|w| w.set_bkp(word));
    }
}

/// The independent watchdog, started with the master's timeout (`g431_hw::iwdg::MASTER`) over the one the
/// bootloader started it with: RM0440's IWDG procedure (start, unlock, prescaler, reload, wait for the update,
/// reload the counter). Fed by [`Watchdog::feed`]; taking the peripheral keeps anyone else from it.
pub struct Watchdog(());

impl Watchdog {
    /// Set the watchdog up; it has been running since the bootloader started it.
    pub fn start(_iwdg: Peri<'static, embassy_stm32::peripherals::IWDG>) -> Self {
        use pac::iwdg::vals::{Key, Pr};
        // Frozen while a debugger halts the core, so a breakpoint does not reset the master under the probe.
        pac::DBGMCU
            .apb1lfzr()
            .write_value(pac::dbgmcu::regs::Apb1lfzr(g431_hw::iwdg::DBGMCU_APB1FZR1));
        let regs = pac::IWDG;
        regs.kr().write(|w| w.set_key(Key::START));
        regs.kr().write(|w| w.set_key(Key::ENABLE));
        regs.pr().write(|w| w.set_pr(Pr::from_bits(g431_hw::iwdg::MASTER.pr)));
        regs.rlr().write(|w| w.set_rl(g431_hw::iwdg::MASTER.rlr));
        // A few LSI cycles; were the LSI dead, the watchdog (running since START) resets the chip.
        while regs.sr().read().0 != 0 {}
        regs.kr().write(|w| w.set_key(Key::RESET));
        Watchdog(())
    }

    /// Reload the counter.
    pub fn feed(&mut self) {
        pac::IWDG.kr().write(|w| w.set_key(pac::iwdg::vals::Key::RESET));
    }
}

/// The battery bus's nominal bit timing, from the 24 MHz crystal: 24 tq, sample point 79 %, SJW 5, which
/// tolerates 0.81 % of clock error per node (`g431_hw::fdcan`).
pub const CAN_TIMING: fdcan::BitTiming = match fdcan::nominal(
    g431_hw::clock::FDCAN_KERNEL_HZ,
    CONFIG.can_bitrate,
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
        && CAN_TIMING.bitrate(g431_hw::clock::FDCAN_KERNEL_HZ) == CONFIG.can_bitrate
        && CAN_TIMING.tolerance_ppm(g431_hw::clock::FDCAN_KERNEL_HZ, fdcan::BUS_DELAY_NS) >= 10 * fdcan::CRYSTAL_PPM
);

/// Write a standard-mode TIMINGR (`g431_hw::i2c`) into an I2C peripheral, over embassy-stm32's own value,
/// disabling it meanwhile as RM0440 requires.
pub fn set_i2c_timing(regs: pac::i2c::I2c) {
    regs.cr1().modify(|w| w.set_pe(false));
    regs.timingr()
        .write_value(pac::i2c::regs::Timingr(g431_hw::i2c::TIMINGR));
    regs.cr1().modify(|w| w.set_pe(true));
}

/// One GPIO pin, named for the bus recovery's bit-banging.
#[derive(Clone, Copy)]
pub struct Pin {
    pub port: pac::gpio::Gpio,
    pub number: usize,
}

impl Pin {
    /// `pin`'s port registers and number, taken from embassy-stm32's own, for a pin lent to a peripheral.
    pub fn of(pin: Peri<'_, impl gpio::Pin>) -> Pin {
        let pin: Peri<'_, gpio::AnyPin> = pin.into();
        Pin {
            port: pin.block(),
            number: usize::from(pin.pin()),
        }
    }

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
            if start.elapsed() >= CONFIG.bus.timeout {
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
    /// The core's UM10204 3.1.16 recovery with the pins taken from the peripheral as GPIOs; then the pins go back
    /// to the peripheral, which is re-initialised. The peripheral is disabled (PE = 0) meanwhile, so it neither
    /// drives the lines nor takes the bit-banged edges for traffic.
    async fn recover(&mut self) -> bool {
        self.regs.cr1().modify(|w| w.set_pe(false));
        // Released (high) before they become outputs, so that switching them does not pull a line low.
        let _ = self.scl.set_high();
        let _ = self.sda.set_high();
        self.scl.set_mode(Moder::OUTPUT);
        self.sda.set_mode(Moder::OUTPUT);
        let released = clear_bus(&mut self.scl, &mut self.sda, &mut Delay, &CONFIG.bus).await;
        self.scl.set_mode(Moder::ALTERNATE);
        self.sda.set_mode(Moder::ALTERNATE);
        // Re-applying the bus speed turns the peripheral on again with a clean state machine; then our timing.
        let _ = self.i2c.set_config(&Hertz(CONFIG.bus.frequency_hz));
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
