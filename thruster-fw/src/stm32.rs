//! Interrupts, clocks, peripheral set-up, the panic and fault handlers, and tasks of the thruster image.

use crash_record::{Frame, Image, Kind, Region, ResetCause};
use defmt::{info, unwrap, warn};
use defmt_rtt as _;
use embassy_executor::{InterruptExecutor, Spawner};
use embassy_stm32::adc::{Adc, AdcChannel, AdcConfig};
use embassy_stm32::exti;
use embassy_stm32::i2c::{self, I2c, SlaveAddrConfig};
use embassy_stm32::rcc;
use embassy_stm32::time::Hertz;
use embassy_stm32::{bind_interrupts, dma, interrupt, pac, peripherals};
use g431_hw::clock;
use g431_hw::flash::{self, NmiAction};
use g431_hw::memory::{Span, THRUSTER_PARTITIONS};
use static_cell::StaticCell;
use thruster_fw::faults::ResetKind;
use thruster_fw::ports::{Board, Ports};
use thruster_fw::shared::Shared;
use thruster_fw::{CONFIG, FAMILY};

use crate::board::{self, BackupLatch, BootRecord, ImageSwap, Iwdg, SlavePort};

bind_interrupts!(struct Irqs {
    I2C3_EV => i2c::EventInterruptHandler<peripherals::I2C3>;
    I2C3_ER => i2c::ErrorInterruptHandler<peripherals::I2C3>;
    DMA1_CHANNEL1 => dma::InterruptHandler<peripherals::DMA1_CH1>;
    DMA1_CHANNEL2 => dma::InterruptHandler<peripherals::DMA1_CH2>;
    EXTI3 => exti::InterruptHandler<interrupt::typelevel::EXTI3>;
    EXTI15_10 => exti::InterruptHandler<interrupt::typelevel::EXTI15_10>;
});

/// Commutation runs on its own executor, in an otherwise unused interrupt, above everything in thread mode.
static COMMUTATION_EXECUTOR: InterruptExecutor = InterruptExecutor::new();

#[interrupt]
#[allow(unsafe_code)]
unsafe fn UART4() {
    // SAFETY: the executor's own interrupt, started once in `main`.
    unsafe { COMMUTATION_EXECUTOR.on_interrupt() }
}

/// The image as its post-mortem record keeps it: this family's thruster, the crate's version.
const CRASH_IMAGE: Image = Image {
    target: update_image::Target::thruster(FAMILY).to_byte(),
    version: match update_image::Version::parse(env!("CARGO_PKG_VERSION")) {
        Some(version) => version.to_bytes(),
        None => [0; 4],
    },
};

// The region fills the room kept for it, and its record is the one the master fetches.
const _: () = assert!(core::mem::size_of::<Region>() == g431_hw::memory::CRASH.length as usize);
const _: () = assert!(crash_record::LEN == tmc_proto::ext::RECORD_LEN);

/// The post-mortem region at the bottom of RAM (`g431_hw::memory::CRASH`).
#[allow(unsafe_code)]
fn crash_region() -> &'static mut Region {
    // SAFETY: that RAM is linked to nothing and no stack within its budget reaches it. The start takes it once and
    // hands it to the tasks' `Shared`; `record_stop` takes it again only once every other context has stopped for
    // good.
    unsafe { crash_record::cortex_m::region(g431_hw::memory::CRASH.origin) }
}

/// Record a stop in the post-mortem region (after the bridge is off); the watchdog resets the chip afterwards.
fn record_stop(kind: Kind, frame: Frame) {
    let uptime_ms = embassy_time::Instant::now().as_millis() as u32;
    crash_region().record(crash_record::cortex_m::stop(kind, frame, None, uptime_ms), CRASH_IMAGE);
}

/// A panic stops the bridge before anything else: the watchdog would take up to its timeout to do it. It reads
/// nothing of the panic: a handler that looks at its location or message keeps every panic site's arguments in the
/// image (each site's `Location` and source path, core::fmt for a bounds check's numbers: 7.6 KiB), where one that
/// ignores them lets fat LTO drop them. Where it panicked is in probe-rs's backtrace at the fault the undefined
/// instruction raises, read from the ELF's debug information (the frames under `core::panicking`); the record
/// keeps that it was a panic, and where the stack stood.
#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    board::stop_bridge();
    cortex_m::interrupt::disable();
    record_stop(Kind::Panic, crash_record::cortex_m::stack_pointer());
    defmt::error!("panicked");
    // An undefined instruction: probe-rs reports the panic; without a probe the watchdog resets the chip.
    cortex_m::asm::udf()
}

/// defmt's `panic!` / `unwrap!` take the same way out.
#[defmt::panic_handler]
fn defmt_panic() -> ! {
    board::stop_bridge();
    record_stop(Kind::Panic, crash_record::cortex_m::stack_pointer());
    cortex_m::asm::udf()
}

/// A hard fault (flip-link turns a stack overflow into one) stops the bridge too; the watchdog then resets.
#[cortex_m_rt::exception]
#[allow(unsafe_code)]
unsafe fn HardFault(frame: &cortex_m_rt::ExceptionFrame) -> ! {
    board::stop_bridge();
    record_stop(Kind::HardFault, crash_record::cortex_m::stacked(frame));
    loop {
        cortex_m::asm::nop();
    }
}

/// A stray interrupt (one the image never enables) stops the bridge too: cortex-m-rt's default handler would spin
/// with the bridge driving until the watchdog bit.
#[cortex_m_rt::exception]
#[allow(unsafe_code)]
unsafe fn DefaultHandler(_irqn: i16) -> ! {
    board::stop_bridge();
    record_stop(Kind::StrayInterrupt, Frame::default());
    loop {
        cortex_m::asm::nop();
    }
}

/// The pages the image reads data from: the bootloader's state (each start reads it), its record (the verdict
/// beside the last ticket) and the DFU partition.
const DATA_PAGES: [Span; 3] = [
    THRUSTER_PARTITIONS.state,
    THRUSTER_PARTITIONS.record,
    THRUSTER_PARTITIONS.dfu,
];

/// So does an NMI, but for a flash ECC double error in the state, the bootloader's record or DFU pages: a double word a power cut tore
/// there reads back as it is and embassy-boot copes with its content, whereas stopping would stop every start
/// that reads it (`g431_hw::flash`). Any other NMI source (the same error in the code also trips TIM1's break
/// through SYSCFG_CFGR2) is a fault; the watchdog then resets.
#[cortex_m_rt::exception]
#[allow(unsafe_code)]
unsafe fn NonMaskableInt() {
    match flash::nmi_action(pac::FLASH.eccr().read().0, &DATA_PAGES) {
        NmiAction::PassDataRead { clear } => pac::FLASH.eccr().write_value(pac::flash::regs::Eccr(clear)),
        NmiAction::Stop => {
            board::stop_bridge();
            record_stop(Kind::Nmi, Frame::default());
            loop {
                cortex_m::asm::nop();
            }
        }
    }
}

/// What this image is (target: this family's thruster; version: the crate's) and the key it takes updates with,
/// where `lbv image`, a receiving thruster and the bootloader look for them (the linker script places
/// `.image_info` at `g431_hw::memory::IMAGE_INFO_OFFSET`).
#[allow(unsafe_code)] // a link section: the record's place is the linker script's, checked there by size
#[unsafe(link_section = ".image_info")]
#[used]
static IMAGE_INFO: [u8; update_image::IMAGE_RECORD_LEN] =
    update_image::image_info!(update_image::Target::thruster(FAMILY));

/// The channels between the tasks, set up by `main` before it spawns them: in `.bss`, where a static with a `const`
/// value is in `.data`, whose whole initial value (0.5 KiB, nearly all zeros) would take flash.
static SHARED: StaticCell<Shared> = StaticCell::new();

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    // The chip as the image's description (`g431_hw::images`) gives it: nothing else of it is in reach.
    let chip = embassy_stm32::init(clocks());
    // The switch to 170 MHz in RM0440's order, after `init`'s (docs/hardware.md "The switch to 170 MHz").
    if !g431_hw::boost_to_170_mhz!() {
        warn!("TIM15's prescaler was not embassy's for 85 MHz: the time driver's tick is off");
    }
    #[cfg(not(any(feature = "brushed", feature = "motorless")))]
    let chip = g431_hw::chip!(thruster_image, chip);
    #[cfg(all(feature = "brushed", not(feature = "motorless")))]
    let chip = g431_hw::chip!(thruster_brushed_image, chip);
    #[cfg(feature = "motorless")]
    let chip = g431_hw::chip!(thruster_motorless_image, chip);
    let shared: &'static Shared = SHARED.init(Shared::new());
    // The stop before this start, read before anything else writes RAM there and before `reset_cause` clears why
    // the chip reset (RCC_CSR, RM0440 7.4.30). It stays there for a debugger, until the next stop or power cycle.
    let crash = crash_region();
    let post_mortem = crash.start(ResetCause(pac::RCC.csr().read().0), CRASH_IMAGE);
    // From here on the tasks note their events in its ring.
    shared.keep_crash(crash);
    if let Some(record) = &post_mortem {
        warn!(
            "stopped before this start: {=str} at {:#010x}",
            record.kind.name(),
            record.frame.pc
        );
    }
    let reset = reset_cause();
    let latch = BackupLatch::open(reset);
    info!(
        "thruster-fw: {} controller at I2C address {=u8:#x}",
        FAMILY.name(),
        FAMILY.address()
    );
    if cfg!(feature = "bringup") {
        warn!(
            "bring-up build: the duty never exceeds {=u16} / 10000",
            thruster_fw::speed::MAX_DUTY
        );
    }

    // The power stage (`board/power_stage.rs`).
    #[cfg(not(feature = "motorless"))]
    let (halls, bridge, analog) = {
        use crate::board::{AnalogInputs, BRIDGE, Halls, PowerStage};
        use embassy_stm32::exti::ExtiInput;
        use embassy_stm32::gpio::{OutputType, Pull};
        use embassy_stm32::timer::complementary_pwm::{ComplementaryPwm, ComplementaryPwmPin};
        use embassy_stm32::timer::low_level::CountingMode;
        use embassy_stm32::timer::simple_pwm::PwmPin;

        // The bridge first, every switch off, before anything can ask it to drive.
        let pwm = ComplementaryPwm::new(
            chip.bridge,
            Some(PwmPin::new(chip.uh, OutputType::PushPull)),
            Some(ComplementaryPwmPin::new(chip.ul, OutputType::PushPull)),
            Some(PwmPin::new(chip.vh, OutputType::PushPull)),
            Some(ComplementaryPwmPin::new(chip.vl, OutputType::PushPull)),
            Some(PwmPin::new(chip.wh, OutputType::PushPull)),
            Some(ComplementaryPwmPin::new(chip.wl, OutputType::PushPull)),
            None,
            None,
            Hertz(BRIDGE.pwm_hz),
            CountingMode::CenterAlignedBothInterrupts,
        );
        let bridge = PowerStage::new(pwm, chip.bkin, chip.current_ref);

        let halls = Halls::new(
            ExtiInput::new(chip.h1, chip.h1_exti, Pull::Up, Irqs),
            ExtiInput::new(chip.h2, chip.h2_exti, Pull::Up, Irqs),
            ExtiInput::new(chip.h3, chip.h3_exti, Pull::Up, Irqs),
        );

        let adc = Adc::new(chip.adc, AdcConfig::default());
        check_adc_clock();
        let analog = AnalogInputs::new(
            adc,
            chip.water.degrade_adc(),
            // The motor's NTC (PB11) or, brushed, the power stage's (PC2): the image's description picks the pin.
            chip.ntc.degrade_adc(),
            chip.vbus.degrade_adc(),
            [
                chip.current_a.degrade_adc(),
                chip.current_b.degrade_adc(),
                chip.current_c.degrade_adc(),
            ],
        );
        (halls, bridge, analog)
    };
    // No power stage fitted (`board/motorless.rs`): TIM1 and its pins are never touched, the halls and the current
    // come from the model, the water sensor is the real pin (a resistor across it provokes the fault), and B1 holds
    // the model's rotor.
    #[cfg(feature = "motorless")]
    let (halls, bridge, analog) = {
        info!("motor-less: no power stage, the motor is a model; B1 holds its rotor");
        let adc = Adc::new(chip.adc, AdcConfig::default());
        check_adc_clock();
        board::wire(adc, chip.water.degrade_adc(), chip.hold)
    };

    let mut i2c_config = i2c::Config::default();
    i2c_config.frequency = Hertz(CONFIG.bus.frequency_hz);
    i2c_config.timeout = CONFIG.bus.timeout;
    let slave = I2c::new(
        chip.slave,
        chip.scl,
        chip.sda,
        chip.slave_tx_dma,
        chip.slave_rx_dma,
        Irqs,
        i2c_config,
    )
    .into_slave_multimaster(SlaveAddrConfig::basic(FAMILY.address()));
    board::set_i2c_timing(pac::I2C3);

    let watchdog = Iwdg::start(chip.watchdog);

    let high = COMMUTATION_EXECUTOR.start(chip.commutation);
    high.spawn(unwrap!(commutation(halls, bridge, shared)));
    let flash = board::open_flash(chip.flash);
    spawner.spawn(unwrap!(controller(
        Ports::<G431> {
            i2c: SlavePort(slave),
            sensors: analog,
            watchdog,
            latch,
            boot: BootRecord::open(flash),
            dfu: board::dfu(flash),
            // The master fetches the record (`tmc_proto::ext::Command::PostMortem`).
            updater: ImageSwap::new(flash, post_mortem.map(|record| record.encode())),
        },
        shared
    )));
    spawner.spawn(unwrap!(early_window()));
}

/// The bootloader's count of early crashes (`update_image::CrashCount`, `g431_hw::backup::CRASH_REGISTER`; the
/// backup domain is open, `BackupLatch::open`): say at the start that the bootloader put this image back after the
/// one it replaced crashed early, and clear the count once the image has run the early window through. The master
/// sees the version the thruster runs in its `Version` reply.
#[embassy_executor::task]
async fn early_window() {
    use update_image::{CrashCount, EARLY_CRASHES, EARLY_WINDOW_SECS};
    let register = pac::TAMP.bkpr(g431_hw::backup::CRASH_REGISTER);
    if CrashCount::from_word(register.read().bkp()).restored {
        warn!(
            "the image after this one crashed {=u8} times early: the bootloader put this one back",
            EARLY_CRASHES
        );
    }
    embassy_time::Timer::after_secs(EARLY_WINDOW_SECS).await;
    register.write(|w| w.set_bkp(CrashCount::default().to_word()));
}

/// 170 MHz from the NUCLEO's 24 MHz crystal (`g431_hw::clock::PLL`); I2C from HSI16 (its timing is computed for
/// that clock); FDCAN, unused here, stays on HSE; the ADC on SYSCLK, divided to 42.5 MHz by `Adc::new`.
fn clocks() -> embassy_stm32::Config {
    let mut config = g431_hw::embassy_clocks!();
    config.rcc.mux.adc12sel = rcc::mux::Adcsel::SYS;
    config.rcc.mux.i2c3sel = rcc::mux::I2csel::HSI;
    config
}

/// The ADC clock must be the one the sample times were computed for.
fn check_adc_clock() {
    let expected = clock::adc_prescaler(clock::ADC_KERNEL_HZ).map_or(u8::MAX, |(bits, _)| bits);
    let presc = pac::ADC12_COMMON.ccr().read().presc().to_bits();
    if presc != expected {
        warn!(
            "ADC prescaler {=u8}, expected {=u8}: the sample times do not match the clock",
            presc, expected
        );
    }
}

/// Say why the chip last reset (a watchdog reset means a task stopped making progress), clear the flags, and
/// tell the latches whether this was a power cycle: RCC_CSR.BORRSTF is set by a power-on or brown-out reset.
fn reset_cause() -> ResetKind {
    let csr = pac::RCC.csr().read();
    let cause = if csr.iwdgrstf() {
        "independent watchdog"
    } else if csr.wwdgrstf() {
        "window watchdog"
    } else if csr.sftrstf() {
        "software"
    } else if csr.borrstf() {
        "brown-out / power-on"
    } else if csr.lpwrrstf() {
        "low-power"
    } else if csr.oblrstf() {
        "option byte load"
    } else if csr.pinrstf() {
        "reset pin"
    } else {
        "unknown"
    };
    info!("reset cause: {}", cause);
    pac::RCC.csr().modify(|w| w.set_rmvf(true));
    if csr.borrstf() {
        ResetKind::PowerCycle
    } else {
        ResetKind::Other
    }
}

/// Commutation, on the high-priority interrupt executor.
#[embassy_executor::task]
async fn commutation(halls: board::HallInputs, bridge: board::Stage, shared: &'static Shared) -> ! {
    thruster_fw::run_commutation(halls, bridge, &CONFIG, shared).await
}

/// The G431's ports for the controller's thread-mode tasks (`board.rs`).
struct G431;

impl Board for G431 {
    type I2c = SlavePort;
    type Sensors = board::Analog;
    type Watchdog = Iwdg;
    type Latch = BackupLatch;
    type Boot = BootRecord;
    type Dfu = board::Dfu;
    type Updater = ImageSwap;
}

/// The controller's other tasks, on the thread-mode executor.
#[embassy_executor::task]
async fn controller(ports: Ports<G431>, shared: &'static Shared) -> ! {
    thruster_fw::run(ports, &CONFIG, shared).await
}
