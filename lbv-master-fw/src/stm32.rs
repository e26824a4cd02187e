//! Interrupts, clocks, peripheral set-up and tasks of the master image.

use defmt::{info, unwrap};
#[cfg(not(feature = "acceptance"))]
use embassy_embedded_hal::adapter::BlockingAsync;
use embassy_executor::Spawner;
use embassy_stm32::can::{self, CanConfigurator};
#[cfg(not(feature = "acceptance"))]
use embassy_stm32::flash::{Blocking, Flash};
use embassy_stm32::i2c::{self, I2c};
use embassy_stm32::rcc::{self, Pll, PllMul, PllPreDiv, PllQDiv, PllRDiv, PllSource, Sysclk};
use embassy_stm32::usart::{self, BufferedUart, BufferedUartRx, BufferedUartTx};
use embassy_stm32::{bind_interrupts, dma, pac, peripherals};
use lbv_master_fw::battery;
use lbv_master_fw::console::{self, ConsoleConfig, ConsoleStats};
use lbv_master_fw::params::Settings;
use lbv_master_fw::settings::Reboot;
#[cfg(not(feature = "acceptance"))]
use lbv_master_fw::settings::{self, G431_STORAGE, Store};
use lbv_master_fw::shared::Shared;
use lbv_master_fw::vehicle::{self, VehicleConfig};
use static_cell::StaticCell;
use {defmt_rtt as _, panic_probe as _};

use crate::board::{self, BatteryCan, Pin, ThrusterBus};

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
});

static SHARED: Shared = Shared::new();
static CONSOLE: ConsoleConfig = ConsoleConfig {
    thrusters: board::THRUSTER_COUNT,
    ..ConsoleConfig::DEFAULT
};
static CONSOLE_STATS: ConsoleStats = ConsoleStats::new();
const VEHICLE: VehicleConfig = VehicleConfig {
    thrusters: board::THRUSTER_COUNT,
    ..VehicleConfig::DEFAULT
};

/// The settings store: embassy-stm32's flash driver (blocking: the G431 has one bank, so the CPU waits out every
/// write and erase anyway) behind the async NOR flash port.
#[cfg(not(feature = "acceptance"))]
type SettingsStore = Store<BlockingAsync<Flash<'static, Blocking>>>;

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let p = embassy_stm32::init(clocks());
    info!("lbv-master-fw: {} thrusters", board::THRUSTERS.len());

    let mut i2c_config = i2c::Config::default();
    i2c_config.frequency = board::BUS_SPEED;
    i2c_config.timeout = board::TRANSFER_TIMEOUT;
    let bus1 = ThrusterBus {
        i2c: I2c::new(p.I2C1, p.PA15, p.PB7, p.DMA1_CH1, p.DMA1_CH2, Irqs, i2c_config),
        scl: Pin {
            port: pac::GPIOA,
            number: 15,
        },
        sda: Pin {
            port: pac::GPIOB,
            number: 7,
        },
    };
    let bus2 = ThrusterBus {
        i2c: I2c::new(p.I2C2, p.PA9, p.PA8, p.DMA1_CH3, p.DMA1_CH4, Irqs, i2c_config),
        scl: Pin {
            port: pac::GPIOA,
            number: 9,
        },
        sda: Pin {
            port: pac::GPIOA,
            number: 8,
        },
    };
    let bus3 = ThrusterBus {
        i2c: I2c::new(p.I2C3, p.PC8, p.PC9, p.DMA1_CH5, p.DMA1_CH6, Irqs, i2c_config),
        scl: Pin {
            port: pac::GPIOC,
            number: 8,
        },
        sda: Pin {
            port: pac::GPIOC,
            number: 9,
        },
    };

    let mut can = CanConfigurator::new(p.FDCAN1, p.PA11, p.PA12, Irqs);
    can.set_bitrate(board::CAN_BITRATE);
    let can = BatteryCan(can.into_normal_mode());

    static TX_BUFFER: StaticCell<[u8; 512]> = StaticCell::new();
    static RX_BUFFER: StaticCell<[u8; 256]> = StaticCell::new();
    let mut uart_config = usart::Config::default();
    uart_config.baudrate = board::CONSOLE_BAUD;
    let uart = unwrap!(BufferedUart::new(
        p.LPUART1,
        p.PA3,
        p.PA2,
        TX_BUFFER.init([0; 512]),
        RX_BUFFER.init([0; 256]),
        Irqs,
        uart_config,
    ));
    let (console_tx, console_rx) = uart.split();

    // The settings in flash. The acceptance image (a bench test between two dev kits, whose script takes no
    // parameter) keeps them in RAM at their defaults: the store's code would take it over its flash budget.
    #[cfg(not(feature = "acceptance"))]
    let stored = {
        let mut store = unwrap!(Store::new(
            BlockingAsync::new(Flash::new_blocking(p.FLASH)),
            G431_STORAGE
        ));
        let stored = store.load(VEHICLE.defaults()).await;
        info!("settings: {} unreadable items", store.read_errors());
        spawner.spawn(unwrap!(settings_task(store)));
        stored
    };
    #[cfg(feature = "acceptance")]
    let stored = {
        spawner.spawn(unwrap!(reboot_task()));
        VEHICLE.defaults()
    };

    #[cfg(not(feature = "acceptance"))]
    for (index, bus) in [bus1, bus2, bus3].into_iter().enumerate() {
        let index = index as u8;
        if board::THRUSTERS.iter().any(|slot| slot.bus == index) {
            spawner.spawn(unwrap!(bus_task(bus, index)));
        }
    }
    // The bench test takes the dev kit's bus (I2C2) instead of the polling task; the other buses stay idle.
    #[cfg(feature = "acceptance")]
    {
        drop((bus1, bus3));
        spawner.spawn(unwrap!(acceptance::task(bus2)));
    }
    spawner.spawn(unwrap!(battery_task(can)));
    spawner.spawn(unwrap!(console_rx_task(console_rx)));
    spawner.spawn(unwrap!(console_tx_task(console_tx)));
    spawner.spawn(unwrap!(vehicle_task(stored)));
}

/// 170 MHz from the internal 16 MHz oscillator (HSI / 4 * 85 / 2), and 85 MHz from PLL Q for FDCAN, whose
/// default kernel clock (HSE) is not running on this board.
fn clocks() -> embassy_stm32::Config {
    let mut config = embassy_stm32::Config::default();
    config.rcc.pll = Some(Pll {
        source: PllSource::HSI,
        prediv: PllPreDiv::DIV4,
        mul: PllMul::MUL85,
        divp: None,
        divq: Some(PllQDiv::DIV4),
        divr: Some(PllRDiv::DIV2),
    });
    config.rcc.sys = Sysclk::PLL1_R;
    config.rcc.boost = true;
    config.rcc.mux.fdcansel = rcc::mux::Fdcansel::PLL1_Q;
    config
}

#[cfg(not(feature = "acceptance"))]
#[embassy_executor::task(pool_size = 3)]
async fn bus_task(mut bus: ThrusterBus, index: u8) -> ! {
    lbv_master_fw::thrusters::bus_task(&mut bus, index, board::THRUSTERS, &board::POLL, &SHARED).await
}

#[embassy_executor::task]
async fn battery_task(mut can: BatteryCan) -> ! {
    battery::can_task(&mut can, &SHARED).await
}

#[embassy_executor::task]
async fn console_rx_task(mut rx: BufferedUartRx<'static>) -> ! {
    console::console_rx_task(&mut rx, &CONSOLE, &SHARED, &CONSOLE_STATS).await
}

#[embassy_executor::task]
async fn console_tx_task(mut tx: BufferedUartTx<'static>) -> ! {
    console::console_tx_task(&mut tx, &CONSOLE, &SHARED, &CONSOLE_STATS).await
}

#[embassy_executor::task]
async fn vehicle_task(stored: Settings) -> ! {
    vehicle::vehicle_task(VEHICLE, stored, &SHARED).await
}

#[cfg(not(feature = "acceptance"))]
#[embassy_executor::task]
async fn settings_task(mut store: SettingsStore) -> ! {
    settings::settings_task(&mut store, &SHARED, &mut SystemReset).await
}

/// Without the settings store, the reboot alone.
#[cfg(feature = "acceptance")]
#[embassy_executor::task]
async fn reboot_task() {
    SHARED.reboot.wait().await;
    SystemReset.reboot();
}

/// A reboot is a system reset (AIRCR.SYSRESETREQ, ARMv7-M Architecture Reference Manual B3.2.6): the RAM state is
/// lost, the flash kept.
struct SystemReset;

impl Reboot for SystemReset {
    fn reboot(&mut self) {
        cortex_m::peripheral::SCB::sys_reset();
    }
}

/// The acceptance test's binding: its report lines over defmt and the console, its prompts as a log line and a
/// wait.
#[cfg(feature = "acceptance")]
mod acceptance {
    use core::fmt::Write;

    use defmt::{info, warn};
    use embassy_time::Timer;
    use lbv_master_fw::acceptance::{
        Operator, Prompt, StepResult, acceptance_test, family_token, prompt_text, step_text, verdict_text,
    };
    use tmc_proto::Family;

    use super::SHARED;
    use crate::board::{self, ThrusterBus};

    /// A report line's body; the longest step has 8 figures of ~20 characters.
    type Line = heapless::String<224>;

    fn line(args: core::fmt::Arguments<'_>) -> Line {
        let mut line = Line::new();
        // A line that does not fit is cut short; the parser still finds step, family and result first.
        let _ = line.write_fmt(args);
        line
    }

    /// The person at the bench: told what to do in the log and on the console, then given time to do it.
    struct Person;

    impl Operator for Person {
        async fn prompt(&mut self, what: Prompt, family: Family) {
            let wait = board::prompt_wait(what);
            info!(
                "ACCEPT prompt={=str} family={=str} wait_s={=u64}: {=str}",
                what.name(),
                family_token(family),
                wait.as_secs(),
                what.instruction()
            );
            let (severity, text) = prompt_text(what);
            SHARED.say(severity, text);
            Timer::after(wait).await;
        }
    }

    #[embassy_executor::task]
    pub async fn task(mut bus: ThrusterBus) {
        Timer::after(board::ACCEPTANCE_START).await;
        info!("ACCEPT start");
        let mut report = |result: StepResult| {
            let body = line(format_args!("{result}"));
            if result.passed {
                info!("ACCEPT {=str}", body.as_str());
            } else {
                warn!("ACCEPT {=str}", body.as_str());
            }
            let (severity, text) = step_text(&result);
            SHARED.say(severity, text);
        };
        let verdict = acceptance_test(&mut bus, &mut Person, &board::ACCEPTANCE, &mut report).await;
        info!("ACCEPT {=str}", line(format_args!("{verdict}")).as_str());
        let (severity, text) = verdict_text(&verdict);
        SHARED.say(severity, text);
    }
}
