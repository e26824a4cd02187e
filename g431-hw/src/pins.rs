//! Boards as data: what each board puts on each STM32 pin, which pins an image uses, and the check that refuses
//! an image using a pin twice or a pin a board drives or loads.
//!
//! The check is a `const fn`, so a binding asserts it at build time:
//!
//! ```
//! use g431_hw::{images, pins};
//! const _: () = assert!(pins::check(&images::THRUSTER).is_ok());
//! ```
//!
//! The thruster image as it was (I2C3's SDA on PC9, where the X-NUCLEO-IHM08M1 has GPIO_BEMF) does not build:
//!
//! ```compile_fail
//! use g431_hw::pins::{self, Image, Port::C, Use, pin};
//! use g431_hw::pins::{IHM08M1, NUCLEO_G431RB};
//! const OLD: Image = Image {
//!     name: "thruster with SDA on PC9",
//!     boards: &[&NUCLEO_G431RB, &IHM08M1],
//!     removed: &[],
//!     uses: &[
//!         Use::digital(pin(C, 8), "I2C3 SCL", pins::i2c("I2C3_SCL", 8)),
//!         Use::digital(pin(C, 9), "I2C3 SDA", pins::i2c("I2C3_SDA", 8)),
//!     ],
//!     peripherals: &[],
//!     interrupts: &[],
//! };
//! const _: () = assert!(pins::check(&OLD).is_ok());
//! ```

/// A GPIO port of the STM32G431 (LQFP64: A, B, C, D, F, G).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Port {
    /// GPIOA.
    A,
    /// GPIOB.
    B,
    /// GPIOC.
    C,
    /// GPIOD.
    D,
    /// GPIOF.
    F,
    /// GPIOG.
    G,
}

impl Port {
    /// The port's letter.
    pub const fn letter(self) -> char {
        match self {
            Port::A => 'A',
            Port::B => 'B',
            Port::C => 'C',
            Port::D => 'D',
            Port::F => 'F',
            Port::G => 'G',
        }
    }
}

/// One pin: port and number.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct Pin {
    /// Its port.
    pub port: Port,
    /// Its number in the port, 0..=15.
    pub number: u8,
}

/// Pin `number` of `port`.
pub const fn pin(port: Port, number: u8) -> Pin {
    Pin { port, number }
}

impl Pin {
    /// The pin of a name as the datasheet and embassy-stm32 write it, `"PA15"`; in a `const`, a name that is not a
    /// pin fails the build.
    pub const fn named(name: &str) -> Pin {
        let (port, number) = match name.as_bytes() {
            [b'P', port, digit @ b'0'..=b'9'] => (*port, Some(*digit - b'0')),
            [b'P', port, b'1', digit @ b'0'..=b'5'] => (*port, Some(10 + *digit - b'0')),
            _ => (0, None),
        };
        let port = match port {
            b'A' => Some(Port::A),
            b'B' => Some(Port::B),
            b'C' => Some(Port::C),
            b'D' => Some(Port::D),
            b'F' => Some(Port::F),
            b'G' => Some(Port::G),
            _ => None,
        };
        match (port, number) {
            (Some(port), Some(number)) => Pin { port, number },
            _ => {
                assert!(
                    port.is_some() && number.is_some(),
                    "a pin's name is P, a port letter and 0 to 15"
                );
                Pin {
                    port: Port::A,
                    number: 0,
                }
            }
        }
    }

    const fn is(self, other: Pin) -> bool {
        self.port as u8 == other.port as u8 && self.number == other.number
    }
}

impl core::fmt::Display for Pin {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "P{}{}", self.port.letter(), self.number)
    }
}

/// What a board does to a pin.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// Drives it: an output, a button, a crystal, a divider or amplifier output.
    Drives,
    /// Loads it: an LED, a pull resistor, a divider or gate-driver input.
    Loads,
    /// A high-impedance input listens to it (a debug probe's trace or serial input): harmless to a digital use,
    /// not to a high-impedance analog one.
    Listens,
}

/// A board's connection to a pin.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Signal {
    /// The pin.
    pub pin: Pin,
    /// The board's name for the signal.
    pub name: &'static str,
    /// What it does to the pin.
    pub kind: Kind,
    /// The solder bridge or 0-ohm resistor that makes the connection, when the board has one.
    pub via: Option<&'static str>,
}

/// A board: its connections to the STM32's pins.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Board {
    /// The board's name.
    pub name: &'static str,
    /// Every pin it connects to.
    pub signals: &'static [Signal],
}

/// A pin's internal pull resistor (GPIOx_PUPDR, RM0440 9.4.4).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pull {
    /// No pull.
    None,
    /// Pull-up.
    Up,
    /// Pull-down.
    Down,
}

/// How an image sets a pin up (GPIOx_MODER, OTYPER, PUPDR, AFRL/AFRH; RM0440 9.4). Alternate-function numbers are
/// DS12589's Table 13 ("Alternate function"), checked against stm32-metapac's pin table in this crate's tests.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// A peripheral's `signal` (ST's name: `TIM1_CH1N`) drives or reads the pin through alternate function `af`,
    /// push-pull.
    Alternate { signal: &'static str, af: u8, pull: Pull },
    /// The same, open-drain (the I2C lines, whose pull-ups are outside the chip).
    AlternateOpenDrain { signal: &'static str, af: u8 },
    /// A digital input read by software or EXTI.
    Input(Pull),
    /// An analog input, ADC1's channel `adc1_in` (DS12589 Table 12's ADC12_INx / ADC1_INx): the digital input is
    /// disconnected.
    Analog { adc1_in: u8 },
    /// A push-pull output the image sets to a level at start and holds there (GPIOx_ODR, RM0440 9.4.6).
    Output { high: bool },
}

/// An I2C line: open-drain in its alternate function.
pub const fn i2c(signal: &'static str, af: u8) -> Mode {
    Mode::AlternateOpenDrain { signal, af }
}

/// A push-pull alternate function without pull.
pub const fn af(signal: &'static str, af: u8) -> Mode {
    Mode::Alternate {
        signal,
        af,
        pull: Pull::None,
    }
}

/// One pin an image uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Use {
    /// The pin.
    pub pin: Pin,
    /// What the image uses it for.
    pub function: &'static str,
    /// The board signal it uses, when it is one (a gate-driver input, a hall line); `None` for a pin the boards
    /// must leave free.
    pub signal: Option<&'static str>,
    /// How the image sets it up.
    pub mode: Mode,
    /// Where a wire meets it on the NUCLEO's headers ("CN10 2"), when one does (a shield's pins have none).
    pub header: Option<&'static str>,
}

impl Use {
    /// A digital use of a pin the boards leave free.
    pub const fn digital(pin: Pin, function: &'static str, mode: Mode) -> Use {
        Use {
            pin,
            function,
            signal: None,
            mode,
            header: None,
        }
    }

    /// An analog use of a pin the boards leave free, on ADC1's channel `adc1_in`.
    pub const fn analog(pin: Pin, function: &'static str, adc1_in: u8) -> Use {
        Use {
            pin,
            function,
            signal: None,
            mode: Mode::Analog { adc1_in },
            header: None,
        }
    }

    /// A use of a board's signal.
    pub const fn of(pin: Pin, function: &'static str, signal: &'static str, mode: Mode) -> Use {
        Use {
            pin,
            function,
            signal: Some(signal),
            mode,
            header: None,
        }
    }

    /// The same use, wired at `header` ("CN10 2").
    pub const fn at(self, header: &'static str) -> Use {
        Use {
            header: Some(header),
            ..self
        }
    }

    /// A high-impedance analog input: even a listening input disturbs it.
    pub const fn is_analog(&self) -> bool {
        matches!(self.mode, Mode::Analog { .. })
    }
}

/// An image on its boards.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Image {
    /// The image's name.
    pub name: &'static str,
    /// The boards it runs on.
    pub boards: &'static [&'static Board],
    /// Solder bridges or resistors the image needs removed: the connections made through them are gone.
    pub removed: &'static [&'static str],
    /// The pins it uses.
    pub uses: &'static [Use],
    /// The peripherals it uses besides the pins.
    pub peripherals: &'static [Peripheral],
    /// The interrupts whose priority it sets.
    pub interrupts: &'static [Interrupt],
}

/// An interrupt whose priority an image sets (NVIC, RM0440 Table 97; embassy-stm32's `Priority`, P0 the highest).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Interrupt {
    /// Its name in ST's vector table and embassy-stm32 (`UART4`).
    pub name: &'static str,
    /// Its priority, `P0` (highest) to `P15`.
    pub priority: &'static str,
    /// What the image uses it for.
    pub function: &'static str,
}

/// A peripheral an image uses, with its name in embassy-stm32 and ST's documents (`I2C3`, `DMA1_CH1`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Peripheral {
    /// Its name.
    pub name: &'static str,
    /// What the image uses it for.
    pub function: &'static str,
}

/// Why an image does not fit its boards.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Conflict {
    /// The image uses the pin twice.
    UsedTwice(Pin),
    /// A board signal other than the one the use names is on the pin.
    Occupied {
        /// The pin.
        pin: Pin,
        /// The board signal in the way.
        signal: &'static str,
    },
    /// The use names a board signal that no board puts on the pin.
    Missing {
        /// The pin.
        pin: Pin,
        /// The signal expected.
        signal: &'static str,
    },
}

/// `a == b`, in a `const fn`.
pub(crate) const fn same(a: &str, b: &str) -> bool {
    let (mut a, mut b) = (a.as_bytes(), b.as_bytes());
    loop {
        match (a, b) {
            ([x, rest_a @ ..], [y, rest_b @ ..]) => {
                if *x != *y {
                    return false;
                }
                a = rest_a;
                b = rest_b;
            }
            ([], []) => return true,
            _ => return false,
        }
    }
}

/// Whether `name` is among `list`.
const fn listed(list: &[&str], name: &str) -> bool {
    let mut rest = list;
    while let [first, tail @ ..] = rest {
        if same(first, name) {
            return true;
        }
        rest = tail;
    }
    false
}

/// Check one use against every connection of every board.
const fn check_use(image: &Image, used: &Use) -> Result<(), Conflict> {
    let mut found = false;
    let mut boards = image.boards;
    while let [board, more_boards @ ..] = boards {
        let mut signals = board.signals;
        while let [signal, more_signals @ ..] = signals {
            let connected = match signal.via {
                Some(via) => !listed(image.removed, via),
                None => true,
            };
            if connected && signal.pin.is(used.pin) {
                let wanted = match used.signal {
                    Some(name) => same(name, signal.name),
                    None => false,
                };
                let harmless = matches!(signal.kind, Kind::Listens) && !used.is_analog();
                if wanted {
                    found = true;
                } else if !harmless {
                    return Err(Conflict::Occupied {
                        pin: used.pin,
                        signal: signal.name,
                    });
                }
            }
            signals = more_signals;
        }
        boards = more_boards;
    }
    match used.signal {
        Some(name) if !found => Err(Conflict::Missing {
            pin: used.pin,
            signal: name,
        }),
        _ => Ok(()),
    }
}

/// Check that the image uses no pin twice, and that each pin it uses carries nothing from its boards but the
/// signal the use names (high-impedance listeners aside, for digital uses).
pub const fn check(image: &Image) -> Result<(), Conflict> {
    let mut rest = image.uses;
    while let [first, tail @ ..] = rest {
        let mut others = tail;
        while let [other, more @ ..] = others {
            if first.pin.is(other.pin) {
                return Err(Conflict::UsedTwice(first.pin));
            }
            others = more;
        }
        if let Err(conflict) = check_use(image, first) {
            return Err(conflict);
        }
        rest = tail;
    }
    Ok(())
}

use Kind::{Drives, Listens, Loads};
use Port::{A, B, C, F, G};

const fn signal(pin: Pin, name: &'static str, kind: Kind, via: Option<&'static str>) -> Signal {
    Signal { pin, name, kind, via }
}

/// NUCLEO-G431RB (MB1367). UM2505 (STM32G4 Nucleo-64 boards) could not be read here; the connections below are
/// those of its tables as quoted by public projects built on this board family: the ST-LINK virtual COM port on
/// LPUART1 PA2 / PA3, LD2 on PA5, B1 on PC13 (to 3V3 when pressed), SWD on PA13 / PA14 and the ST-LINK's SWO
/// input on PB3 through SB15, PB8 shared with BOOT0, the 24 MHz crystal X3 on PF0 / PF1, the 32.768 kHz X2 on
/// PC14 / PC15, and NRST (B2 and the ST-LINK) on PG10.
pub const NUCLEO_G431RB: Board = Board {
    name: "NUCLEO-G431RB",
    signals: &[
        signal(pin(A, 2), "VCP (ST-LINK RX)", Listens, None),
        signal(pin(A, 3), "VCP (ST-LINK TX)", Drives, None),
        signal(pin(A, 5), "LD2", Loads, None),
        signal(pin(A, 13), "SWDIO", Drives, None),
        signal(pin(A, 14), "SWCLK", Drives, None),
        signal(pin(B, 3), "T_SWO", Listens, Some("SB15")),
        signal(pin(B, 8), "BOOT0", Loads, None),
        signal(pin(C, 13), "B1", Drives, None),
        signal(pin(C, 14), "LSE crystal X2", Drives, None),
        signal(pin(C, 15), "LSE crystal X2", Drives, None),
        signal(pin(F, 0), "HSE crystal X3", Drives, None),
        signal(pin(F, 1), "HSE crystal X3", Drives, None),
        signal(pin(G, 10), "NRST", Drives, None),
    ],
};

/// The master's board: the same MB1367 board as the NUCLEO-G431RB with an STM32G474RE fitted (UM2505 covers both),
/// so the same signals on the same pins, the 24 MHz HSE crystal among them.
pub const NUCLEO_G474RE: Board = Board {
    name: "NUCLEO-G474RE",
    signals: NUCLEO_G431RB.signals,
};

/// X-NUCLEO-IHM08M1 on the morpho connectors of a NUCLEO-G431RB. UM1996's tables and the board's schematic could
/// not be read here; the mapping is the one a public G474RE + IHM08M1 project derived pin by pin from UM1996
/// tables 3/4, the schematic and UM2505 (okhsunrog/oxifoc, `docs/hw/nucleo-g474re-ihm08m1.md`; the G474RE is the
/// same MB1367 board), cross-checked against NuttX's IHM08M1 table for the NUCLEO-F446RE (same morpho positions),
/// which adds GPIO3 on PB13. The resistors named are the shield's 0-ohm links. PB15 and PB14 carry the UL and
/// BKIN nets a second time (routes for other NUCLEO boards): on the G431 they are TIM1 CH3N / CH2N, so the image
/// must leave them alone, which this table makes it do.
pub const IHM08M1: Board = Board {
    name: "X-NUCLEO-IHM08M1",
    signals: &[
        signal(pin(A, 8), "UH", Loads, Some("R56")),
        signal(pin(A, 7), "UL", Loads, Some("R58")),
        signal(pin(B, 15), "UL", Loads, Some("R86")),
        signal(pin(A, 9), "VH", Loads, Some("R64")),
        signal(pin(B, 0), "VL", Loads, Some("R67")),
        signal(pin(A, 10), "WH", Loads, Some("R70")),
        signal(pin(B, 1), "WL", Loads, Some("R72")),
        signal(pin(A, 6), "BKIN", Drives, Some("R78")),
        signal(pin(A, 11), "BKIN", Drives, Some("R73")),
        signal(pin(B, 14), "BKIN", Drives, Some("R74")),
        signal(pin(A, 12), "CPOUT", Drives, Some("R52")),
        signal(pin(B, 4), "CURRENT_REF", Loads, Some("R77")),
        signal(pin(A, 0), "CURR_FDBK_A", Drives, Some("R47")),
        signal(pin(C, 1), "CURR_FDBK_B", Drives, Some("R48")),
        signal(pin(C, 0), "CURR_FDBK_C", Drives, Some("R50")),
        signal(pin(A, 1), "VBUS", Drives, Some("R51")),
        signal(pin(C, 2), "TEMPERATURE", Drives, Some("R54")),
        signal(pin(A, 15), "H1", Drives, Some("R79")),
        signal(pin(B, 3), "H2", Drives, Some("R81")),
        signal(pin(B, 10), "H3", Drives, Some("R84")),
        signal(pin(C, 3), "BEMF1", Drives, Some("R59")),
        signal(pin(B, 11), "BEMF2", Drives, Some("R60")),
        signal(pin(C, 4), "BEMF2", Drives, Some("R61")),
        signal(pin(C, 5), "BEMF3", Drives, Some("R65")),
        signal(pin(C, 9), "GPIO_BEMF", Loads, Some("R55")),
        signal(pin(A, 4), "POT", Drives, Some("R181")),
        signal(pin(B, 2), "LED", Loads, None),
        signal(pin(B, 5), "J7 debug", Loads, Some("R85")),
        signal(pin(B, 13), "GPIO3", Loads, None),
    ],
};

#[cfg(test)]
mod tests;
