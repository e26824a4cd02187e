//! The pins each firmware image uses, on its boards. The bindings take exactly these pins (a test reads their
//! sources), assert [`check`](crate::pins::check) on them at build time, and the README's pin tables list them
//! (a test reads those too).

use crate::pins::Mode::{Alternate, Analog, Input};
use crate::pins::Port::{A, B, C};
use crate::pins::{Board, IHM08M1, Image, Mode, NUCLEO_G431RB, Pull, Use, af, i2c, pin};

/// The hall inputs with their internal pull-ups, which hold a line high whenever an open-collector sensor lets go.
const HALL: Mode = Input(Pull::Up);

/// The thruster's boards.
const POWER_STAGE: &[&Board] = &[&NUCLEO_G431RB, &IHM08M1];

/// Pins every thruster image with a power stage uses.
macro_rules! thruster_pins {
    ($($extra:expr),* $(,)?) => {
        &[
            Use::digital(pin(C, 8), "I2C slave SCL", i2c("I2C3_SCL", 8)),
            // I2C3's other SDA pin (AF8): PC9 carries the IHM08M1's GPIO_BEMF.
            Use::digital(pin(C, 11), "I2C slave SDA", i2c("I2C3_SDA", 8)),
            Use::of(pin(A, 8), "phase A high", "UH", af("TIM1_CH1", 6)),
            Use::of(pin(A, 7), "phase A low", "UL", af("TIM1_CH1N", 6)),
            Use::of(pin(A, 9), "phase B high", "VH", af("TIM1_CH2", 6)),
            Use::of(pin(B, 0), "phase B low", "VL", af("TIM1_CH2N", 6)),
            Use::of(pin(A, 10), "phase C high", "WH", af("TIM1_CH3", 6)),
            Use::of(pin(B, 1), "phase C low", "WL", af("TIM1_CH3N", 6)),
            // Pulled up: the comparators only pull the line low.
            Use::of(pin(A, 6), "overcurrent break", "BKIN", Alternate { signal: "TIM1_BKIN", af: 6, pull: Pull::Up }),
            Use::of(pin(A, 15), "hall H1", "H1", HALL),
            Use::of(pin(B, 3), "hall H2", "H2", HALL),
            Use::of(pin(B, 10), "hall H3", "H3", HALL),
            Use::of(pin(A, 0), "motor current", "CURR_FDBK_A", Analog { adc1_in: 1 }),
            // The one ADC pin neither board touches; PC3, used before, carries the IHM08M1's BEMF1.
            Use::analog(pin(B, 12), "water sensor", 11),
            $($extra,)*
        ]
    };
}

/// The brushless thruster: the motor's NTC on PB11 (ADC1 IN14), which the IHM08M1 also feeds BEMF2 through R60.
/// BEMF2 reaches PC4 through R61 as well, so R60 is removed and nothing is lost.
pub const THRUSTER: Image = Image {
    name: "thruster-fw",
    boards: POWER_STAGE,
    removed: &["R60"],
    uses: thruster_pins!(Use::analog(pin(B, 11), "motor NTC", 14)),
};

/// The brushed thruster: TEMPERATURE is the controller's (IDS 8.4.2), the IHM08M1's power-stage NTC on PC2.
pub const THRUSTER_BRUSHED: Image = Image {
    name: "thruster-fw (brushed)",
    boards: POWER_STAGE,
    removed: &[],
    uses: thruster_pins!(Use::of(
        pin(C, 2),
        "power-stage NTC",
        "TEMPERATURE",
        Analog { adc1_in: 8 }
    )),
};

/// The motor-less thruster on a bare NUCLEO: the I2C slave, the real water-sensor pin and B1 holding the model's
/// rotor.
pub const THRUSTER_MOTORLESS: Image = Image {
    name: "thruster-fw (motorless)",
    boards: &[&NUCLEO_G431RB],
    removed: &[],
    uses: &[
        Use::digital(pin(C, 8), "I2C slave SCL", i2c("I2C3_SCL", 8)),
        Use::digital(pin(C, 11), "I2C slave SDA", i2c("I2C3_SDA", 8)),
        Use::analog(pin(B, 12), "water sensor", 11),
        // B1 connects PC13 to 3V3 when pressed (MB1367): pulled down, it reads low when released.
        Use::of(pin(C, 13), "model rotor hold", "B1", Input(Pull::Down)),
    ],
};

/// The master node on a bare NUCLEO.
pub const MASTER: Image = Image {
    name: "lbv-master-fw",
    boards: &[&NUCLEO_G431RB],
    removed: &[],
    uses: &[
        Use::digital(pin(A, 15), "thruster bus 1 SCL", i2c("I2C1_SCL", 4)),
        Use::digital(pin(B, 7), "thruster bus 1 SDA", i2c("I2C1_SDA", 4)),
        Use::digital(pin(A, 9), "thruster bus 2 SCL", i2c("I2C2_SCL", 4)),
        Use::digital(pin(A, 8), "thruster bus 2 SDA", i2c("I2C2_SDA", 4)),
        Use::digital(pin(C, 8), "thruster bus 3 SCL", i2c("I2C3_SCL", 8)),
        Use::digital(pin(C, 9), "thruster bus 3 SDA", i2c("I2C3_SDA", 8)),
        Use::digital(pin(A, 11), "battery CAN RX", af("FDCAN1_RX", 9)),
        Use::digital(pin(A, 12), "battery CAN TX", af("FDCAN1_TX", 9)),
        Use::of(pin(A, 2), "console TX", "VCP (ST-LINK RX)", af("LPUART1_TX", 12)),
        Use::of(pin(A, 3), "console RX", "VCP (ST-LINK TX)", af("LPUART1_RX", 12)),
    ],
};

/// Every image.
pub const ALL: [&Image; 4] = [&THRUSTER, &THRUSTER_BRUSHED, &THRUSTER_MOTORLESS, &MASTER];

const _: () = {
    let mut rest: &[&Image] = &ALL;
    while let [image, tail @ ..] = rest {
        assert!(crate::pins::check(image).is_ok());
        rest = tail;
    }
};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pins::{Conflict, Pin, Port, check};
    use std::collections::BTreeSet;

    fn pins_of(images: &[&Image]) -> BTreeSet<Pin> {
        images
            .iter()
            .flat_map(|image| image.uses.iter().map(|used| used.pin))
            .collect()
    }

    /// Every `p.PXn` in a binding's source: the pins it takes from embassy-stm32.
    fn pins_in_source(source: &str) -> BTreeSet<Pin> {
        let mut found = BTreeSet::new();
        for (at, _) in source.match_indices("p.P") {
            let rest = &source[at + 3..];
            let mut chars = rest.chars();
            let port = match chars.next() {
                Some('A') => Port::A,
                Some('B') => Port::B,
                Some('C') => Port::C,
                Some('D') => Port::D,
                Some('F') => Port::F,
                Some('G') => Port::G,
                _ => continue,
            };
            let digits: String = chars.take_while(char::is_ascii_digit).collect();
            if let Ok(number) = digits.parse() {
                found.insert(pin(port, number));
            }
        }
        found
    }

    /// The (function, pin) rows of the first table after `heading` in the README.
    fn readme_rows(heading: &str) -> BTreeSet<(String, Pin)> {
        let readme = include_str!("../../docs/hardware.md");
        let section = readme.split(heading).nth(1).expect("README section");
        let mut rows = BTreeSet::new();
        let mut in_table = false;
        for line in section.lines() {
            if !line.starts_with('|') {
                if in_table {
                    break;
                }
                continue;
            }
            in_table = true;
            let cells: Vec<&str> = line.split('|').map(str::trim).collect();
            let (Some(function), Some(pin_cell)) = (cells.get(1), cells.get(2)) else {
                continue;
            };
            let pins = pins_in_source(&format!("p.{pin_cell}"));
            if let Some(pin) = pins.into_iter().next() {
                rows.insert((function.to_string(), pin));
            }
        }
        rows
    }

    fn rows_of(images: &[&Image]) -> BTreeSet<(String, Pin)> {
        images
            .iter()
            .flat_map(|image| image.uses.iter().map(|used| (used.function.to_string(), used.pin)))
            .collect()
    }

    #[test]
    fn every_image_fits_its_boards() {
        for image in ALL {
            assert_eq!(check(image), Ok(()), "{}", image.name);
        }
    }

    /// The thruster as it was: SDA on PC9 (the IHM08M1's GPIO_BEMF) and the water sensor on PC3 (BEMF1).
    const OLD: Image = Image {
        name: "old thruster",
        boards: POWER_STAGE,
        removed: &[],
        uses: &[
            Use::digital(pin(C, 8), "I2C slave SCL", i2c("I2C3_SCL", 8)),
            Use::digital(pin(C, 9), "I2C slave SDA", i2c("I2C3_SDA", 8)),
            Use::analog(pin(C, 3), "water sensor", 9),
        ],
    };

    #[test]
    fn a_collision_is_refused() {
        assert_eq!(
            check(&OLD),
            Err(Conflict::Occupied {
                pin: pin(C, 9),
                signal: "GPIO_BEMF"
            })
        );
        const WATER_ONLY: Image = Image {
            uses: &[Use::analog(pin(C, 3), "water sensor", 9)],
            ..OLD
        };
        assert_eq!(
            check(&WATER_ONLY),
            Err(Conflict::Occupied {
                pin: pin(C, 3),
                signal: "BEMF1"
            })
        );
        // The motor NTC on PB11 needs R60 out.
        const WITH_R60: Image = Image {
            removed: &[],
            ..THRUSTER
        };
        assert_eq!(
            check(&WITH_R60),
            Err(Conflict::Occupied {
                pin: pin(B, 11),
                signal: "BEMF2"
            })
        );
        // A pin taken twice, a signal that is not there, and an analog input on a listened-to pin.
        const TWICE: Image = Image {
            uses: &[
                Use::digital(pin(C, 8), "a", i2c("I2C3_SCL", 8)),
                Use::digital(pin(C, 8), "b", i2c("I2C3_SCL", 8)),
            ],
            ..OLD
        };
        assert_eq!(check(&TWICE), Err(Conflict::UsedTwice(pin(C, 8))));
        const MISSING: Image = Image {
            uses: &[Use::of(pin(C, 8), "hall", "H1", HALL)],
            ..OLD
        };
        assert_eq!(
            check(&MISSING),
            Err(Conflict::Missing {
                pin: pin(C, 8),
                signal: "H1"
            })
        );
        const LISTENED: Image = Image {
            uses: &[Use::analog(pin(A, 2), "sensor", 3)],
            ..MASTER
        };
        assert_eq!(
            check(&LISTENED),
            Err(Conflict::Occupied {
                pin: pin(A, 2),
                signal: "VCP (ST-LINK RX)"
            })
        );
        // Hall H2 shares PB3 with the ST-LINK's SWO input: fine for a digital input.
        assert_eq!(check(&THRUSTER), Ok(()));
    }

    #[test]
    fn the_bindings_take_exactly_these_pins() {
        let thruster = [
            include_str!("../../thruster-fw/src/stm32.rs"),
            include_str!("../../thruster-fw/src/board.rs"),
        ]
        .concat();
        assert_eq!(
            pins_in_source(&thruster),
            pins_of(&[&THRUSTER, &THRUSTER_BRUSHED, &THRUSTER_MOTORLESS])
        );
        let master = [
            include_str!("../../lbv-master-fw/src/stm32.rs"),
            include_str!("../../lbv-master-fw/src/board.rs"),
        ]
        .concat();
        assert_eq!(pins_in_source(&master), pins_of(&[&MASTER]));
    }

    #[test]
    fn the_readme_tables_agree() {
        assert_eq!(
            readme_rows("### Thruster board pins"),
            rows_of(&[&THRUSTER, &THRUSTER_BRUSHED, &THRUSTER_MOTORLESS])
        );
        assert_eq!(readme_rows("### Master board pins"), rows_of(&[&MASTER]));
    }

    /// Every alternate function and ADC channel an image names is the one ST's data gives that pin (stm32-metapac's
    /// pin table, generated from ST's device database; DS12589 Tables 12 and 13 are the same tables in print).
    #[test]
    fn alternate_functions_and_adc_channels_agree_with_st_data() {
        use crate::pins::Mode;
        use stm32_metapac::metadata::METADATA;
        for image in ALL {
            for used in image.uses {
                let (signal, af) = match used.mode {
                    Mode::Alternate { signal, af, .. } | Mode::AlternateOpenDrain { signal, af } => {
                        (signal.to_string(), Some(af))
                    }
                    // ST's data names ADC1's inputs INx, without an alternate function.
                    Mode::Analog { adc1_in } => (format!("ADC1_IN{adc1_in}"), None),
                    Mode::Input(_) => continue,
                };
                let name = format!("P{}{}", used.pin.port.letter(), used.pin.number);
                let known = METADATA
                    .peripherals
                    .iter()
                    .flat_map(|peripheral| peripheral.pins.iter().map(move |pin| (peripheral.name, pin)))
                    .any(|(peripheral, pin)| {
                        format!("{peripheral}_{}", pin.signal) == signal && pin.pin == name && pin.af == af
                    });
                assert!(known, "{}: {signal} is not {af:?} of {name} in ST's data", image.name);
            }
        }
    }
}
