//! NUCLEO-G431RB + X-NUCLEO-IHM08M1 wiring of the thruster controller and the adapters from embassy-stm32
//! peripherals to the core's ports; the settings they are configured with are the core's (`thruster_fw::CONFIG`).
//!
//! | function | pin | peripheral |
//! |---|---|---|
//! | I2C slave SCL / SDA | PC8 / PC9 (CN10 2 / 1) | I2C3 |
//! | phase A high / low | PA8 / PA7 | TIM1 CH1 / CH1N |
//! | phase B high / low | PA9 / PB0 | TIM1 CH2 / CH2N |
//! | phase C high / low | PA10 / PB1 | TIM1 CH3 / CH3N |
//! | overcurrent (break) | PA6 | TIM1 BKIN, active low |
//! | halls H1 / H2 / H3 | PA15 / PB3 / PB10 | EXTI 15 / 3 / 10 |
//! | motor current | PA0 | ADC1 IN1 |
//! | bus voltage | PA1 | ADC1 IN2 |
//! | power-stage NTC | PC2 | ADC1 IN8 |
//! | water-sensor electrodes | PC3 | ADC1 IN9 |
//! | motor NTC | PB12 | ADC1 IN11 |

use embassy_embedded_hal::SetConfig;
use embassy_futures::select::select3;
use embassy_stm32::adc::{Adc, AnyAdcChannel, SampleTime};
use embassy_stm32::exti::ExtiInput;
use embassy_stm32::i2c::{self, I2c, SlaveCommandKind};
use embassy_stm32::mode::Async;
use embassy_stm32::peripherals::{ADC1, IWDG, TIM1};
use embassy_stm32::time::Hertz;
use embassy_stm32::timer::Channel;
use embassy_stm32::timer::complementary_pwm::ComplementaryPwm;
use embassy_stm32::wdg::IndependentWatchdog;
use thruster_fw::commutation::{BridgeDrive, PhaseDrive};
use thruster_fw::hall::HallState;
use thruster_fw::tasks::{Bridge, HallSensors, RawSample, Sensors, Watchdog};
use thruster_fw::{CONFIG, Duty, FAMILY, I2cTarget, Request};
#[cfg(feature = "motorless")]
use {
    embassy_stm32::gpio::Input,
    thruster_fw::motorless::{HoldInput, ModelSensors, MotorModel, Motorless, WaterInput},
};

/// The motor-less controller's model motor (Cargo feature `motorless`), for the image's configuration.
#[cfg(feature = "motorless")]
pub static MOTORLESS: Motorless = Motorless::new(MotorModel::new(&CONFIG));

/// What the fault task samples: the ADC inputs, or in the motor-less controller the model and the water pin.
#[cfg(not(feature = "motorless"))]
pub type Analog = AnalogInputs;
#[cfg(feature = "motorless")]
pub type Analog = ModelSensors<'static, WaterPin, UserButton>;

/// What commutation reads and drives: the halls and the power stage, or in the motor-less controller the model's.
#[cfg(not(feature = "motorless"))]
pub type HallInputs = Halls;
#[cfg(not(feature = "motorless"))]
pub type Stage = PowerStage;
#[cfg(feature = "motorless")]
pub type HallInputs = thruster_fw::motorless::ModelHalls<'static>;
#[cfg(feature = "motorless")]
pub type Stage = thruster_fw::motorless::ModelBridge<'static>;

/// I2C3 as the thruster interface's slave port.
pub struct SlavePort(pub I2c<'static, Async, i2c::MultiMaster>);

impl I2cTarget for SlavePort {
    type Error = i2c::Error;

    async fn listen(&mut self) -> Result<Request, i2c::Error> {
        // Only the family's own address is configured, so every match is ours.
        let command = self.0.listen().await?;
        Ok(match command.kind {
            SlaveCommandKind::Write => Request::Write,
            SlaveCommandKind::Read => Request::Read,
        })
    }

    async fn respond_to_write(&mut self, buffer: &mut [u8]) -> Result<usize, i2c::Error> {
        self.0.respond_to_write(buffer).await
    }

    async fn respond_to_read(&mut self, data: &[u8]) -> Result<(), i2c::Error> {
        self.0.respond_to_read(data).await.map(|_| ())
    }

    fn reset(&mut self) {
        // Re-applying the configuration turns the peripheral off and on, which clears its state machine and
        // releases SCL and SDA.
        let _ = self.0.set_config(&(
            Hertz(CONFIG.bus.frequency_hz),
            i2c::SlaveAddrConfig::basic(FAMILY.address()),
        ));
    }
}

/// The three hall inputs.
#[cfg_attr(
    feature = "motorless",
    allow(dead_code, reason = "the motor-less controller's halls are modelled")
)]
pub struct Halls {
    pub h1: ExtiInput<'static, Async>,
    pub h2: ExtiInput<'static, Async>,
    pub h3: ExtiInput<'static, Async>,
}

impl HallSensors for Halls {
    async fn wait_for_edge(&mut self) {
        let Self { h1, h2, h3 } = self;
        select3(h1.wait_for_any_edge(), h2.wait_for_any_edge(), h3.wait_for_any_edge()).await;
    }

    fn read(&mut self) -> HallState {
        HallState::from_pins(self.h1.is_high(), self.h2.is_high(), self.h3.is_high())
    }
}

/// TIM1's three complementary pairs. Off-state selection (OSSR) holds both switches of a disabled phase off,
/// so a floating phase is really floating.
#[cfg_attr(feature = "motorless", allow(dead_code, reason = "no power stage is fitted"))]
pub struct PowerStage {
    pub pwm: ComplementaryPwm<'static, TIM1>,
}

impl Bridge for PowerStage {
    fn apply(&mut self, drive: BridgeDrive, duty: Duty) {
        let period = u16::try_from(self.pwm.get_max_duty()).unwrap_or(u16::MAX);
        let compare = u32::from(duty.compare(period));
        for (channel, phase) in [Channel::Ch1, Channel::Ch2, Channel::Ch3].into_iter().zip(drive) {
            match phase {
                PhaseDrive::Pwm => {
                    self.pwm.set_duty(channel, compare);
                    self.pwm.enable(channel);
                }
                PhaseDrive::Low => {
                    self.pwm.set_duty(channel, 0);
                    self.pwm.enable(channel);
                }
                PhaseDrive::Float => self.pwm.disable(channel),
            }
        }
    }
}

/// ADC1 and the fault / telemetry inputs.
#[cfg_attr(
    feature = "motorless",
    allow(dead_code, reason = "the motor-less controller reads only the water pin")
)]
pub struct AnalogInputs {
    pub adc: Adc<'static, ADC1>,
    pub water: AnyAdcChannel<'static, ADC1>,
    pub motor_ntc: AnyAdcChannel<'static, ADC1>,
    pub current: AnyAdcChannel<'static, ADC1>,
}

/// ADC sample time of every input: 47.5 cycles suit the water sensor's 1 Mohm divider.
const SAMPLE: SampleTime = SampleTime::CYCLES47_5;

impl Sensors for AnalogInputs {
    async fn sample(&mut self) -> RawSample {
        // Three blocking conversions take about 5 us in all: not worth a DMA round trip at 1 kHz.
        RawSample {
            water: self.adc.blocking_read(&mut self.water, SAMPLE),
            temperature: self.adc.blocking_read(&mut self.motor_ntc, SAMPLE),
            current: self.adc.blocking_read(&mut self.current, SAMPLE),
        }
    }
}

/// The water-sensor pin of the motor-less controller: the one input that stays real.
#[cfg(feature = "motorless")]
pub struct WaterPin {
    pub adc: Adc<'static, ADC1>,
    pub pin: AnyAdcChannel<'static, ADC1>,
}

#[cfg(feature = "motorless")]
impl WaterInput for WaterPin {
    async fn water(&mut self) -> u16 {
        self.adc.blocking_read(&mut self.pin, SAMPLE)
    }
}

/// The NUCLEO's blue user button B1 (PC13, high while pressed): holds the motor-less controller's model rotor.
#[cfg(feature = "motorless")]
pub struct UserButton(pub Input<'static>);

#[cfg(feature = "motorless")]
impl HoldInput for UserButton {
    fn held(&mut self) -> bool {
        self.0.is_high()
    }
}

/// The independent watchdog.
pub struct Iwdg(pub IndependentWatchdog<'static, IWDG>);

impl Watchdog for Iwdg {
    fn feed(&mut self) {
        self.0.pet();
    }
}
