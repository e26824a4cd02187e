//! Interrupts, clocks, peripheral set-up and tasks of the thruster image.

use defmt::{info, unwrap};
use embassy_executor::{InterruptExecutor, Spawner};
use embassy_stm32::adc::{Adc, AdcChannel, AdcConfig};
use embassy_stm32::exti;
use embassy_stm32::gpio::Pull;
use embassy_stm32::i2c::{self, I2c, SlaveAddrConfig};
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::rcc::{self, Pll, PllMul, PllPreDiv, PllRDiv, PllSource, Sysclk};
use embassy_stm32::time::Hertz;
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{bind_interrupts, dma, interrupt, pac, peripherals};
use thruster_fw::tasks::Shared;
use thruster_fw::{CONFIG, FAMILY, Ports};
use {defmt_rtt as _, panic_probe as _};

use crate::board::{self, Iwdg, SlavePort};

// The power stage, the halls and the analog inputs of a controller with a motor.
#[cfg(not(feature = "motorless"))]
use {
    crate::board::{AnalogInputs, Halls, PowerStage},
    embassy_stm32::exti::ExtiInput,
    embassy_stm32::gpio::OutputType,
    embassy_stm32::timer::complementary_pwm::{BreakInputPolarity, ComplementaryPwm, ComplementaryPwmPin, Ossr},
    embassy_stm32::timer::low_level::CountingMode,
    embassy_stm32::timer::simple_pwm::PwmPin,
};
// The motor-less controller: the model's ports, the real water-sensor pin and the user button.
#[cfg(feature = "motorless")]
use {
    crate::board::{UserButton, WaterPin},
    embassy_stm32::gpio::Input,
    thruster_fw::motorless::{ModelBridge, ModelHalls, ModelSensors},
};

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

/// PWM frequency: above hearing, and 4250 counts of resolution at 170 MHz center-aligned.
#[cfg(not(feature = "motorless"))]
const PWM_FREQUENCY: Hertz = Hertz::khz(20);
/// Dead time between a phase's high and low switch: 170 counts of 5.9 ns = 1 us (IHM08M1's MOSFETs need ~500 ns).
#[cfg(not(feature = "motorless"))]
const DEAD_TIME: u16 = 170;

static SHARED: Shared = Shared::new();

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let p = embassy_stm32::init(clocks());
    log_reset_cause();
    info!(
        "thruster-fw: {} controller at I2C address {=u8:#x}",
        FAMILY.name(),
        FAMILY.address()
    );

    #[cfg(not(feature = "motorless"))]
    let (halls, bridge, analog) = {
        // The bridge first, coasting, before anything can ask it to drive.
        let mut pwm = ComplementaryPwm::new(
            p.TIM1,
            Some(PwmPin::new(p.PA8, OutputType::PushPull)),
            Some(ComplementaryPwmPin::new(p.PA7, OutputType::PushPull)),
            Some(PwmPin::new(p.PA9, OutputType::PushPull)),
            Some(ComplementaryPwmPin::new(p.PB0, OutputType::PushPull)),
            Some(PwmPin::new(p.PA10, OutputType::PushPull)),
            Some(ComplementaryPwmPin::new(p.PB1, OutputType::PushPull)),
            None,
            None,
            PWM_FREQUENCY,
            CountingMode::CenterAlignedBothInterrupts,
        );
        pwm.set_dead_time(DEAD_TIME);
        pwm.set_off_state_selection_run(Ossr::IDLE_LEVEL);
        arm_overcurrent_break(&mut pwm);
        let bridge = PowerStage { pwm };

        let halls = Halls {
            h1: ExtiInput::new(p.PA15, p.EXTI15, Pull::Up, Irqs),
            h2: ExtiInput::new(p.PB3, p.EXTI3, Pull::Up, Irqs),
            h3: ExtiInput::new(p.PB10, p.EXTI10, Pull::Up, Irqs),
        };

        let analog = AnalogInputs {
            adc: Adc::new(p.ADC1, AdcConfig::default()),
            water: p.PC3.degrade_adc(),
            motor_ntc: p.PB12.degrade_adc(),
            current: p.PA0.degrade_adc(),
        };
        (halls, bridge, analog)
    };
    // No power stage fitted: TIM1 and its pins are never touched, the halls and the current come from the model,
    // the water sensor is the real pin (a resistor across it provokes the fault), and B1 holds the model's rotor.
    #[cfg(feature = "motorless")]
    let analog = {
        info!("motor-less: no power stage, the motor is a model; B1 holds its rotor");
        let water = WaterPin {
            adc: Adc::new(p.ADC1, AdcConfig::default()),
            pin: p.PC3.degrade_adc(),
        };
        // NUCLEO-64 (MB1367): B1 connects PC13 to 3V3 when pressed.
        let button = UserButton(Input::new(p.PC13, Pull::Down));
        ModelSensors::new(&board::MOTORLESS, &CONFIG, water, button)
    };

    let mut i2c_config = i2c::Config::default();
    i2c_config.frequency = Hertz(CONFIG.bus.frequency_hz);
    i2c_config.timeout = CONFIG.bus.timeout;
    let slave = I2c::new(p.I2C3, p.PC8, p.PC9, p.DMA1_CH1, p.DMA1_CH2, Irqs, i2c_config)
        .into_slave_multimaster(SlaveAddrConfig::basic(FAMILY.address()));

    let mut watchdog = IndependentWatchdog::new(p.IWDG, CONFIG.watchdog.timeout_us());
    watchdog.unleash();

    interrupt::UART4.set_priority(Priority::P1);
    let high = COMMUTATION_EXECUTOR.start(interrupt::UART4);
    #[cfg(feature = "motorless")]
    let (halls, bridge) = (ModelHalls::new(&board::MOTORLESS), ModelBridge(&board::MOTORLESS));
    high.spawn(unwrap!(commutation(halls, bridge)));
    spawner.spawn(unwrap!(controller(Ports {
        i2c: SlavePort(slave),
        sensors: analog,
        watchdog: Iwdg(watchdog),
    })));
}

/// 170 MHz from the internal 16 MHz oscillator: HSI / 4 * 85 / 2.
fn clocks() -> embassy_stm32::Config {
    let mut config = embassy_stm32::Config::default();
    config.rcc.pll = Some(Pll {
        source: PllSource::HSI,
        prediv: PllPreDiv::DIV4,
        mul: PllMul::MUL85,
        divp: None,
        divq: None,
        divr: Some(PllRDiv::DIV2),
    });
    config.rcc.sys = Sysclk::PLL1_R;
    config.rcc.boost = true;
    config.rcc.mux.adc12sel = rcc::mux::Adcsel::SYS;
    config
}

#[cfg(not(feature = "motorless"))]
/// The IHM08M1's overcurrent comparator pulls PA6 low: as TIM1's break input it turns the bridge off in hardware,
/// without waiting for software. Automatic output enable restarts the PWM at the next period once the current
/// has fallen: cycle-by-cycle current limiting.
fn arm_overcurrent_break(pwm: &mut ComplementaryPwm<'static, peripherals::TIM1>) {
    // PA6 in alternate function 6 (TIM1_BKIN); embassy-stm32 has no break-pin constructor.
    pac::GPIOA.afr(0).modify(|w| w.set_afr(6, 6));
    pac::GPIOA
        .moder()
        .modify(|w| w.set_moder(6, pac::gpio::vals::Moder::ALTERNATE));
    pwm.set_break_polarity(BreakInputPolarity::ACTIVE_LOW);
    pwm.set_break_input_pin_enable(true);
    pwm.set_break_enable(true);
    pwm.set_automatic_output_enable(true);
}

/// Say why the chip last reset (a watchdog reset means a task stopped making progress), then clear the flags.
fn log_reset_cause() {
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
}

/// Commutation, on the high-priority interrupt executor.
#[embassy_executor::task]
async fn commutation(halls: board::HallInputs, bridge: board::Stage) -> ! {
    thruster_fw::run_commutation(halls, bridge, &CONFIG, &SHARED).await
}

/// The controller's other tasks, on the thread-mode executor.
#[embassy_executor::task]
async fn controller(ports: Ports<SlavePort, board::Analog, Iwdg>) -> ! {
    thruster_fw::run(ports, &CONFIG, &SHARED).await
}
