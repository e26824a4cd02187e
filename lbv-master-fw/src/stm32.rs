//! Interrupts, clocks, peripheral set-up and tasks of the master image.

use core::num::{NonZeroU8, NonZeroU16};
use core::sync::atomic::{AtomicU32, Ordering};

use crash_record::{Frame, Image, Kind, PanicAt, Region, ResetCause};
use defmt::{info, unwrap, warn};
use defmt_rtt as _;
use embassy_embedded_hal::flash::partition::Partition;
use embassy_executor::Spawner;
use embassy_stm32::can::config::NominalBitTiming;
use embassy_stm32::can::{self, CanConfigurator};
use embassy_stm32::flash::{Async, Flash};
use embassy_stm32::i2c::{self, I2c};
use embassy_stm32::rcc;
use embassy_stm32::time::Hertz;
use embassy_stm32::usart::{self, BufferedUart, BufferedUartRx, BufferedUartTx};
use embassy_stm32::{bind_interrupts, dma, pac, peripherals};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use g431_hw::flash::{self, NmiAction};
use lbv_master_fw::console::ConsoleStats;
use lbv_master_fw::ports::{Board, Ports, Reboot};
use lbv_master_fw::settings::{DATA_PAGES, Store};
use lbv_master_fw::shared::Shared;
use lbv_master_fw::update::own::{OwnFlash, OwnImage, Updating};
use lbv_master_fw::{CONFIG, MasterConfig};
use static_cell::StaticCell;

use crate::board::{self, BatteryCan, Pin, ThrusterBus, set_i2c_timing};

bind_interrupts!(struct Irqs {
    I2C1_EV => i2c::EventInterruptHandler<peripherals::I2C1>;
    I2C1_ER => i2c::ErrorInterruptHandler<peripherals::I2C1>;
    I2C2_EV => i2c::EventInterruptHandler<peripherals::I2C2>;
    I2C2_ER => i2c::ErrorInterruptHandler<peripherals::I2C2>;
    I2C3_EV => i2c::EventInterruptHandler<peripherals::I2C3>;
    I2C3_ER => i2c::ErrorInterruptHandler<peripherals::I2C3>;
    DMA1_CHANNEL1 => dma::InterruptHandler<peripherals::DMA1_CH1>;
    DMA1_CHANNEL2 => dma::InterruptHandler<peripherals::DMA1_CH2>;
    DMA1_CHANNEL3 => dma::InterruptHandler<peripherals::DMA1_CH3>;
    DMA1_CHANNEL4 => dma::InterruptHandler<peripherals::DMA1_CH4>;
    DMA1_CHANNEL5 => dma::InterruptHandler<peripherals::DMA1_CH5>;
    DMA1_CHANNEL6 => dma::InterruptHandler<peripherals::DMA1_CH6>;
    FDCAN1_IT0 => can::IT0InterruptHandler<peripherals::FDCAN1>;
    FDCAN1_IT1 => can::IT1InterruptHandler<peripherals::FDCAN1>;
    LPUART1 => usart::BufferedInterruptHandler<peripherals::LPUART1>;
    FLASH => embassy_stm32::flash::InterruptHandler;
});

static CONSOLE_STATS: ConsoleStats = ConsoleStats::new();

/// What this image is (target: the master; version: the crate's) and, after it, the key it takes updates with, where
/// `lbv image`, the master's own update and the bootloader look for them (the linker script places `.image_info` at
/// `g431_hw::memory::IMAGE_INFO_OFFSET`): the bootloader checks the next image's signature with this key.
#[allow(unsafe_code)] // a link section: the record's place is the linker script's, checked there by size
#[unsafe(link_section = ".image_info")]
#[used]
static IMAGE_INFO: [u8; update_image::IMAGE_RECORD_LEN] = update_image::image_info!(update_image::Target::Master);

// The record fills the room the linker script keeps for it.
const _: () = assert!(update_image::IMAGE_RECORD_LEN == g431_hw::memory::IMAGE_INFO_SIZE as usize);

/// The chip's flash through embassy-stm32's async driver, which waits for an erase or a program by its interrupt:
/// the settings, the bootloader's state and record, and DFU are in bank 2, where the work runs beside the code in
/// bank 1 (RM0440 3.3.8).
type ChipFlash = Mutex<CriticalSectionRawMutex, Flash<'static, Async>>;
/// The whole flash, addressed from its start, shared by the settings and the master's own update.
type WholeFlash = Partition<'static, CriticalSectionRawMutex, Flash<'static, Async>>;

/// What the thruster buses are for: polling the thrusters, or in the acceptance image the dev kits' test.
#[cfg(not(feature = "acceptance"))]
type Work = lbv_master_fw::Polling<'static>;
#[cfg(feature = "acceptance")]
type Work = lbv_master_fw::acceptance::Script<acceptance::Person>;
/// Where the console's update server hands the images it receives: on to the thrusters, or in the acceptance
/// image (which has no server) nowhere.
#[cfg(not(feature = "acceptance"))]
type Sink = lbv_master_fw::update::VehicleSink<'static>;
#[cfg(feature = "acceptance")]
type Sink = lbv_master_fw::update::CheckOnly;

/// The buses' work and the update sink. The vehicle's share the images on their way from the console's update
/// server to the thrusters' bus tasks, set up at start in a `StaticCell` (zeroed RAM): as a plain static their 2.4 KiB
/// would be `.data`, its initial values kept in flash.
#[cfg(not(feature = "acceptance"))]
fn work_and_sink(own: &'static OwnImage) -> (Work, Sink) {
    static TRANSFERS: StaticCell<lbv_master_fw::update::courier::Transfers> = StaticCell::new();
    let transfers: &'static _ = TRANSFERS.init_with(lbv_master_fw::update::courier::Transfers::new);
    (
        lbv_master_fw::Polling {
            transfers: Some(transfers),
        },
        lbv_master_fw::update::VehicleSink::new(transfers, own),
    )
}
#[cfg(feature = "acceptance")]
fn work_and_sink(_own: &'static OwnImage) -> (Work, Sink) {
    (
        lbv_master_fw::acceptance::Script(acceptance::Person),
        lbv_master_fw::update::CheckOnly,
    )
}

/// The image as its post-mortem record keeps it: the master, the crate's version.
const CRASH_IMAGE: Image = Image {
    target: update_image::Target::Master.to_byte(),
    version: match update_image::Version::parse(env!("CARGO_PKG_VERSION")) {
        Some(version) => version.to_bytes(),
        None => [0; 4],
    },
};

// The region fills the room kept for it.
const _: () = assert!(core::mem::size_of::<Region>() == g431_hw::memory::CRASH.length as usize);

/// The post-mortem region at the bottom of RAM (`g431_hw::memory::CRASH`).
#[allow(unsafe_code)]
fn crash_region() -> &'static mut Region {
    // SAFETY: that RAM is linked to nothing and no stack within its budget reaches it. The start takes it once and
    // hands it to the core; `record_stop` takes it again only once every other context has stopped for good.
    unsafe { crash_record::cortex_m::region(g431_hw::memory::CRASH.origin) }
}

// The black box fills the room kept for it.
const _: () =
    assert!(core::mem::size_of::<lbv_master_fw::blackbox::BlackBox>() == g431_hw::memory::BLACK_BOX.length as usize);

/// The black box's region above the post-mortem region (`g431_hw::memory::BLACK_BOX`), as a reset left it.
#[cfg(not(feature = "acceptance"))]
#[allow(unsafe_code)]
fn black_box_region() -> &'static mut lbv_master_fw::blackbox::BlackBox {
    // SAFETY: that RAM is linked to nothing, no stack within its budget reaches it (`g431_hw::images::kept_ram`),
    // and the start takes it once. Every byte pattern is a `BlackBox` (arrays of bytes): its header's check, not
    // the type, refuses what a power-on leaves.
    unsafe { &mut *(g431_hw::memory::BLACK_BOX.origin as *mut lbv_master_fw::blackbox::BlackBox) }
}

/// Record a stop in the post-mortem region; the watchdog resets the chip afterwards.
fn record_stop(kind: Kind, frame: Frame, panic: Option<PanicAt>) {
    let uptime_ms = embassy_time::Instant::now().as_millis() as u32;
    crash_region().record(crash_record::cortex_m::stop(kind, frame, panic, uptime_ms), CRASH_IMAGE);
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    // The chip as the image's description (`g431_hw::images`) gives it: nothing else of it is in reach.
    let chip = embassy_stm32::init(clocks());
    // The stop before this start, read before anything else writes RAM there and before `CrashRegister::open`
    // clears why the chip reset (RCC_CSR, RM0440 7.4.30).
    let crash = crash_region();
    if let Some(record) = crash.start(ResetCause(pac::RCC.csr().read().0), CRASH_IMAGE) {
        warn!(
            "stopped before this start: {=str} at {:#010x}",
            record.kind.name(),
            record.frame.pc
        );
    }
    // The switch to 170 MHz in RM0440's order, after `init`'s (docs/hardware.md "The switch to 170 MHz").
    if !g431_hw::boost_to_170_mhz!() {
        warn!("TIM15's prescaler was not embassy's for 85 MHz: the time driver's tick is off");
    }
    let mut chip = g431_hw::chip!(master_image, chip);
    info!("lbv-master-fw: {} thrusters", CONFIG.thrusters.count());

    let mut i2c_config = i2c::Config::default();
    i2c_config.frequency = Hertz(CONFIG.bus.frequency_hz);
    i2c_config.timeout = CONFIG.bus.timeout;
    let bus1 = ThrusterBus {
        scl: Pin::of(chip.bus1_scl.reborrow()),
        sda: Pin::of(chip.bus1_sda.reborrow()),
        i2c: I2c::new(
            chip.bus1,
            chip.bus1_scl,
            chip.bus1_sda,
            chip.bus1_tx_dma,
            chip.bus1_rx_dma,
            Irqs,
            i2c_config,
        ),
        regs: pac::I2C1,
    };
    let bus2 = ThrusterBus {
        scl: Pin::of(chip.bus2_scl.reborrow()),
        sda: Pin::of(chip.bus2_sda.reborrow()),
        i2c: I2c::new(
            chip.bus2,
            chip.bus2_scl,
            chip.bus2_sda,
            chip.bus2_tx_dma,
            chip.bus2_rx_dma,
            Irqs,
            i2c_config,
        ),
        regs: pac::I2C2,
    };
    let bus3 = ThrusterBus {
        scl: Pin::of(chip.bus3_scl.reborrow()),
        sda: Pin::of(chip.bus3_sda.reborrow()),
        i2c: I2c::new(
            chip.bus3,
            chip.bus3_scl,
            chip.bus3_sda,
            chip.bus3_tx_dma,
            chip.bus3_rx_dma,
            Irqs,
            i2c_config,
        ),
        regs: pac::I2C3,
    };

    for bus in [&bus1, &bus2, &bus3] {
        set_i2c_timing(bus.regs);
    }

    let mut can = CanConfigurator::new(chip.can, chip.can_rx, chip.can_tx, Irqs);
    can.set_config(can.config().set_nominal_bit_timing(nominal_bit_timing()));
    let can = BatteryCan(can.into_normal_mode());

    static TX_BUFFER: StaticCell<[u8; 512]> = StaticCell::new();
    static RX_BUFFER: StaticCell<[u8; 256]> = StaticCell::new();
    let mut uart_config = usart::Config::default();
    uart_config.baudrate = CONFIG.console_baud;
    let uart = unwrap!(BufferedUart::new(
        chip.console,
        chip.console_rx,
        chip.console_tx,
        TX_BUFFER.init([0; 512]),
        RX_BUFFER.init([0; 256]),
        Irqs,
        uart_config,
    ));
    let (console_tx, console_rx) = uart.split();

    // The settings, in the flash pages the images leave free (`memory.x`), and the master's own update, on one
    // flash. Its image in a `StaticCell` (zeroed RAM): as a plain static its 2.3 KiB buffer would be `.data`.
    static FLASH: StaticCell<ChipFlash> = StaticCell::new();
    static OWN_IMAGE: StaticCell<OwnImage> = StaticCell::new();
    let flash: &'static ChipFlash = FLASH.init(Mutex::new(Flash::new(chip.flash, Irqs)));
    let whole = || Partition::new(flash, 0, g431_hw::memory::G474RE.flash.length);
    // The partitions and the settings' pages are placed for dual-bank mode (FLASH_OPTR.DBANK, RM0440 3.7.8), which
    // the async driver does not check: on one bank the store and the own update refuse every write.
    let optr = pac::FLASH.optr().read().0;
    let layout_ok = g431_hw::flash::master_layout_ok(optr);
    if !layout_ok {
        defmt::error!(
            "flash not dual-bank (FLASH_OPTR {:#010x}): settings and updates refused",
            optr
        );
    }
    let mut settings = Store::master(whole());
    settings.set_layout_ok(layout_ok);
    let own_image: &'static OwnImage = OWN_IMAGE.init_with(OwnImage::new);
    own_image.set_layout_ok(layout_ok);
    let own = Updating {
        flash: OwnFlash::new(whole()),
        image: own_image,
        crashes: board::CrashRegister::open(),
    };

    // The build's configuration with the chip's 96-bit unique device id for AUTOPILOT_VERSION (RM0440 section
    // 48.1: UID_BASE 0x1FFF_7590, the address stm32-metapac gives the G4's UID block), read here so that the core
    // stays free of hardware. In a static (zeroed RAM): a copy inside the task would be moved with the task.
    static MASTER_CONFIG: StaticCell<MasterConfig> = StaticCell::new();
    let config = MASTER_CONFIG.init_with(|| {
        let mut config = CONFIG;
        config.console.uid = embassy_stm32::uid::uid();
        config
    });

    let watchdog = board::Watchdog::start(chip.watchdog);
    spawner.spawn(unwrap!(feed(watchdog)));

    let (work, update) = work_and_sink(own_image);
    spawner.spawn(unwrap!(master(
        Ports {
            buses: [bus1, bus2, bus3],
            can,
            console_rx,
            console_tx,
            settings,
            reboot: SystemReset,
            work,
            update,
            own,
        },
        config,
        crash
    )));
}

/// 170 MHz from the NUCLEO's 24 MHz crystal (`g431_hw::clock::PLL`); FDCAN on the crystal itself, which its bit
/// timing needs (`g431_hw::fdcan`: HSI16's 1 % is more than 1 Mbit/s tolerates); the I2C buses on HSI16, the clock
/// their timing is computed for.
fn clocks() -> embassy_stm32::Config {
    let mut config = g431_hw::embassy_clocks!();
    config.rcc.mux.fdcansel = rcc::mux::Fdcansel::HSE;
    config.rcc.mux.i2c1sel = rcc::mux::I2csel::HSI;
    config.rcc.mux.i2c2sel = rcc::mux::I2csel::HSI;
    config.rcc.mux.i2c3sel = rcc::mux::I2csel::HSI;
    config
}

/// `board::CAN_TIMING` in embassy-stm32's terms (it writes each field less one into FDCAN_NBTP).
fn nominal_bit_timing() -> NominalBitTiming {
    let timing = board::CAN_TIMING;
    // `CAN_TIMING.is_valid()` is asserted at build time, so no field is zero.
    let one = NonZeroU8::MIN;
    NominalBitTiming {
        prescaler: NonZeroU16::new(timing.prescaler).unwrap_or(NonZeroU16::MIN),
        seg1: NonZeroU8::new(timing.tseg1).unwrap_or(one),
        seg2: NonZeroU8::new(timing.tseg2).unwrap_or(one),
        sync_jump_width: NonZeroU8::new(timing.sjw).unwrap_or(one),
    }
}

/// Feed the watchdog every `g431_hw::iwdg::MASTER_SCHEDULE` period. A task of the executor every other task runs
/// on: one that stops yielding stops this one too, and the watchdog resets the master.
#[embassy_executor::task]
async fn feed(mut watchdog: board::Watchdog) -> ! {
    let period = embassy_time::Duration::from_micros(g431_hw::iwdg::MASTER_SCHEDULE.feed_period_us.into());
    loop {
        watchdog.feed();
        embassy_time::Timer::after(period).await;
    }
}

/// The master's ports on the NUCLEO.
struct Nucleo;

impl Board for Nucleo {
    type Bus = ThrusterBus;
    type Can = BatteryCan;
    type ConsoleRx = BufferedUartRx<'static>;
    type ConsoleTx = BufferedUartTx<'static>;
    /// The settings, in their pages of the whole flash.
    type Settings = Store<WholeFlash>;
    type Reboot = SystemReset;
    type Work = Work;
    type Update = Sink;
    /// The master's own update, on the same flash, at `g431_hw::memory::MASTER_PARTITIONS`' offsets.
    type Own = Updating<'static, WholeFlash, board::CrashRegister>;
}

/// The whole node, on the thread-mode executor. Its channels are set up at start in a `StaticCell` (zeroed RAM): a
/// static with an initial value would take 2.5 KiB of flash, and inside the task's future they would be built on
/// the stack with the rest of it when the task is spawned (embassy-executor's `write_in_place` materialises the
/// whole future there), which overflowed the 15 KiB stack at boot.
#[embassy_executor::task]
async fn master(ports: Ports<Nucleo>, config: &'static MasterConfig, crash: &'static mut Region) -> ! {
    static SHARED: StaticCell<Shared> = StaticCell::new();
    let shared = SHARED.init_with(Shared::new);
    shared.keep_crash(crash);
    #[cfg(not(feature = "acceptance"))]
    {
        let thrusters = usize::from(config.thrusters.count());
        shared
            .black_box
            .keep(black_box_region(), embassy_time::Instant::now(), thrusters);
    }
    lbv_master_fw::run(ports, config, shared, &CONSOLE_STATS).await
}

/// A panic logs its message when it is a plain string, and where, then stops on an undefined instruction: probe-rs
/// reports it; without a probe the thrusters stop by their link failsafe. Formatting a message with arguments would
/// link core::fmt (about 700 B here) for a path the lints keep out of the firmware's code. `lbv hil` looks for
/// "panicked at".
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    cortex_m::interrupt::disable();
    let (file, line) = info.location().map_or(("?", 0), |at| (at.file(), at.line()));
    // Where: the path's address in flash, which `lbv decode crash --elf` reads back.
    let at = PanicAt {
        file: file.as_ptr() as u32,
        file_len: file.len() as u16,
        line,
    };
    record_stop(Kind::Panic, crash_record::cortex_m::stack_pointer(), Some(at));
    match info.message().as_str() {
        Some(message) => defmt::error!("panicked at {=str}:{=u32}: {=str}", file, line, message),
        None => defmt::error!("panicked at {=str}:{=u32}", file, line),
    }
    cortex_m::asm::udf()
}

/// defmt's `panic!` / `unwrap!` take the same way out.
#[defmt::panic_handler]
fn defmt_panic() -> ! {
    record_stop(Kind::Panic, crash_record::cortex_m::stack_pointer(), None);
    cortex_m::asm::udf()
}

/// A HardFault (a panic's undefined instruction, a bus or usage fault, a stack overflow with flip-link) is recorded,
/// then the master waits for the watchdog: the thrusters stop by their link failsafe meanwhile. A panic recorded
/// first stays the record ([`Region::record`]).
#[cortex_m_rt::exception]
#[allow(unsafe_code)]
unsafe fn HardFault(frame: &cortex_m_rt::ExceptionFrame) -> ! {
    record_stop(Kind::HardFault, crash_record::cortex_m::stacked(frame), None);
    loop {
        cortex_m::asm::nop();
    }
}

/// An interrupt the image never enables: recorded, then the watchdog resets (cortex-m-rt's default handler would
/// spin unrecorded).
#[cortex_m_rt::exception]
#[allow(unsafe_code)]
unsafe fn DefaultHandler(_irqn: i16) -> ! {
    record_stop(Kind::StrayInterrupt, Frame::default(), None);
    loop {
        cortex_m::asm::nop();
    }
}

/// ECC double errors in the settings pages the NMI handler let pass since the start (for a debugger).
static SETTINGS_ECC_ERRORS: AtomicU32 = AtomicU32::new(0);

/// The NMI: an ECC double error in the settings pages (a write cut short by a power cut) is let pass, so the store
/// reads the record, finds its CRC wrong and skips it; any other NMI stops the master here, and the thrusters stop
/// by their link failsafe (`g431_hw::flash`, RM0440 3.3.2). It touches nothing a critical section guards, so it
/// logs nothing: a debugger reads `SETTINGS_ECC_ERRORS`, and after a stop FLASH_ECCR, which keeps the cause.
#[cortex_m_rt::exception]
#[allow(unsafe_code)]
unsafe fn NonMaskableInt() {
    let value = pac::FLASH.eccr().read().0;
    match flash::nmi_action(value, &DATA_PAGES) {
        NmiAction::PassDataRead { clear } => {
            pac::FLASH.eccr().write_value(pac::flash::regs::Eccr(clear));
            SETTINGS_ECC_ERRORS.fetch_add(1, Ordering::Relaxed);
        }
        NmiAction::Stop => {
            record_stop(Kind::Nmi, Frame::default(), None);
            loop {
                cortex_m::asm::nop();
            }
        }
    }
}

/// A reboot is a system reset (AIRCR.SYSRESETREQ, ARMv7-M Architecture Reference Manual B3.2.6): the RAM state is
/// lost, the flash kept.
struct SystemReset;

impl Reboot for SystemReset {
    async fn reboot(&mut self) -> ! {
        cortex_m::peripheral::SCB::sys_reset()
    }
}

/// The acceptance test's operator: its report lines over defmt (which `lbv hil` reads), its prompts as a log line
/// and a wait.
#[cfg(feature = "acceptance")]
mod acceptance {
    use core::fmt::Write;

    use defmt::{info, warn};
    use embassy_time::Timer;
    use lbv_master_fw::CONFIG;
    use lbv_master_fw::acceptance::Operator;
    use lbv_master_fw::acceptance::report::{Prompt, Report, StepResult, Verdict};
    use tmc_proto::Family;

    /// A report line; the longest, a step's with 8 figures of ~20 characters, is some 220 bytes.
    type Line = heapless::String<256>;

    /// Log a report line, at WARN for a failed step.
    fn log(report: &Report<'_>, warn: bool) {
        let mut line = Line::new();
        // A line cut short does not read back in `lbv hil`, whose count of steps then disagrees with the verdict's.
        let _ = write!(line, "{report}");
        if warn {
            warn!("{=str}", line.as_str());
        } else {
            info!("{=str}", line.as_str());
        }
    }

    /// The person at the bench: told what to do in the log (and on the console), then given time to do it.
    pub struct Person;

    impl Operator for Person {
        async fn prompt(&mut self, what: Prompt, family: Family) {
            let wait = CONFIG.acceptance.prompt_wait(what);
            log(&Report::prompt(what, family, wait), false);
            Timer::after(wait).await;
        }

        fn started(&mut self) {
            log(&Report::Start, false);
        }

        fn reported(&mut self, result: &StepResult) {
            log(&Report::Step(result.clone()), !result.passed);
        }

        fn concluded(&mut self, verdict: &Verdict) {
            log(&Report::Verdict(verdict.into()), false);
        }
    }
}
