//! The motor-less controller (Cargo feature `motorless`): the model motor (`thruster_fw::motorless`) in place of the
//! power stage, the real water-sensor pin, and the user button B1 that holds the model's rotor.

use embassy_stm32::Peri;
use embassy_stm32::adc::{Adc, AnyAdcChannel, SampleTime};
use embassy_stm32::gpio::{Input, Pin, Pull};
use embassy_stm32::peripherals::ADC1;
use g431_hw::adc;
use thruster_fw::CONFIG;
use thruster_fw::motorless::{ModelBridge, ModelHalls, ModelSensors, MotorModel, Motorless};
use thruster_fw::ports::{HoldInput, WaterInput};

/// The motor-less controller's model motor (Cargo feature `motorless`), for the image's configuration.
static MOTORLESS: Motorless = Motorless::new(MotorModel::new(&CONFIG));

/// What the fault task samples: the model and the water pin.
pub type Analog = ModelSensors<'static, WaterPin, UserButton>;

/// What commutation reads: the model's halls.
pub type HallInputs = ModelHalls<'static>;
/// What commutation drives: the model's bridge.
pub type Stage = ModelBridge<'static>;

/// The model's ports: its halls and bridge, and the fault task's inputs (the model, the water pin `water` on
/// `adc`, and B1 on `hold`).
pub fn wire(
    adc: Adc<'static, ADC1>,
    water: AnyAdcChannel<'static, ADC1>,
    hold: Peri<'static, impl Pin>,
) -> (HallInputs, Stage, Analog) {
    let water = WaterPin { adc, pin: water };
    // NUCLEO-64 (MB1367): B1 connects PC13 to 3V3 when pressed.
    let button = UserButton(Input::new(hold, Pull::Down));
    let analog = ModelSensors::new(&MOTORLESS, &CONFIG, water, button);
    (ModelHalls::new(&MOTORLESS), ModelBridge(&MOTORLESS), analog)
}

/// embassy-stm32's sample time of ours: `g431_hw::adc`'s, from the sources' impedance and DS12589's R_AIN table
/// (it checks that each input settles; the water sensor relies on its 100 nF).
const fn sample_time(sample: adc::SampleTime) -> SampleTime {
    SampleTime::from_bits(sample.bits())
}

/// The water-sensor pin of the motor-less controller: the one input that stays real.
pub struct WaterPin {
    adc: Adc<'static, ADC1>,
    pin: AnyAdcChannel<'static, ADC1>,
}

impl WaterInput for WaterPin {
    async fn water(&mut self) -> u16 {
        // ES0431: the first conversion after an idle ADC may be wrong (see `AnalogInputs::sample`); thrown away.
        let _ = self.adc.blocking_read(&mut self.pin, sample_time(adc::CURRENT_SAMPLE));
        self.adc.blocking_read(&mut self.pin, sample_time(adc::WATER_SAMPLE))
    }
}

/// The NUCLEO's blue user button B1 (PC13, high while pressed): holds the motor-less controller's model rotor.
pub struct UserButton(Input<'static>);

impl HoldInput for UserButton {
    fn held(&mut self) -> bool {
        self.0.is_high()
    }
}
