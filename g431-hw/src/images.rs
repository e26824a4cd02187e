//! Each firmware image described once, as data: the pins it uses and what for, the peripherals it takes, its memory
//! layout and its size budgets.
//!
//! A description is a macro that hands its rows to another macro, so the same rows become the `const` data here
//! ([`THRUSTER`], [`MASTER`], ...: checked against the boards at build time, printed as the docs' pin tables) and,
//! in a binding, the one struct it takes its peripherals from ([`chip!`](crate::chip)): a pin or peripheral that is
//! not in the description is not in that struct, and one that does not fit its peripheral (SDA on a pin without
//! that I2C's SDA function) fails embassy-stm32's trait bounds. Rows read `field: PIN @ "header" =
//! constructor(args)`: the constructor one of [`Use`](crate::pins::Use)'s, the header where a wire meets the pin on
//! the NUCLEO.

use core::fmt;

use crate::memory::{self, KIB, Layout};
use crate::pins::Mode::{Alternate, Analog, Input};
use crate::pins::{Board, IHM08M1, Image, Mode, NUCLEO_G431RB, NUCLEO_G474RE, Pull, af, i2c};

/// The hall inputs with their internal pull-ups, which hold a line high whenever an open-collector sensor lets go.
const HALL: Mode = Input(Pull::Up);

/// The thruster's boards.
const POWER_STAGE: &[&Board] = &[&NUCLEO_G431RB, &IHM08M1];

/// The rows every thruster image has (its I2C slave, the water sensor, the watchdog, the commutation executor),
/// then the `pins` and `peripherals` given, handed to `$then`.
#[doc(hidden)]
#[macro_export]
macro_rules! thruster_rows {
    ([$($then:ident)::+] [$($arg:tt)*] pins { $($pins:tt)* } peripherals { $($peripherals:tt)* }) => {
        $($then)::+! { [$($arg)*]
            pins {
                scl: PC8 @ "CN10 2" = digital("I2C slave SCL", i2c("I2C3_SCL", 8)),
                // I2C3's other SDA pin (AF8): PC9 carries the IHM08M1's GPIO_BEMF.
                sda: PC11 @ "CN7 2" = digital("I2C slave SDA", i2c("I2C3_SDA", 8)),
                // The one ADC pin neither board touches; PC3, used before, carries the IHM08M1's BEMF1.
                water: PB12 @ "CN10 16" = analog("water sensor", 11),
                $($pins)*
            }
            peripherals {
                slave: I2C3 = "I2C slave",
                slave_tx_dma: DMA1_CH1 = "I2C slave transmit DMA",
                slave_rx_dma: DMA1_CH2 = "I2C slave receive DMA",
                adc: ADC1 = "the analog inputs",
                watchdog: IWDG = "independent watchdog",
                flash: FLASH = "the bootloader's state (a new image's trial) and the DFU partition (field update)",
                $($peripherals)*
            }
            interrupts {
                // Above every other interrupt, so a hall edge's commutation step never waits for a task.
                commutation: UART4 = P1 "the commutation executor (UART4 itself is unused)",
            }
        }
    };
}

/// The rows of every thruster image with a power stage, then `$extra` pins, handed to `$then`.
#[doc(hidden)]
#[macro_export]
macro_rules! power_stage_rows {
    ([$($then:ident)::+] [$($arg:tt)*] $($extra:tt)*) => {
        $crate::thruster_rows! { [$($then)::+] [$($arg)*]
            pins {
                uh: PA8 = of("phase A high", "UH", af("TIM1_CH1", 6)),
                ul: PA7 = of("phase A low", "UL", af("TIM1_CH1N", 6)),
                vh: PA9 = of("phase B high", "VH", af("TIM1_CH2", 6)),
                vl: PB0 = of("phase B low", "VL", af("TIM1_CH2N", 6)),
                wh: PA10 = of("phase C high", "WH", af("TIM1_CH3", 6)),
                wl: PB1 = of("phase C low", "WL", af("TIM1_CH3N", 6)),
                // Pulled up: the comparators only pull the line low.
                bkin: PA6 = of("overcurrent break", "BKIN", Alternate { signal: "TIM1_BKIN", af: 6, pull: Pull::Up }),
                h1: PA15 = of("hall H1", "H1", HALL),
                h2: PB3 = of("hall H2", "H2", HALL),
                h3: PB10 = of("hall H3", "H3", HALL),
                // The three low-side shunts' amplifiers, converted together at TIM1's trigger (docs/hardware.md,
                // "Current sensing").
                current_a: PA0 = of("phase A current", "CURR_FDBK_A", Analog { adc1_in: 1 }),
                current_b: PC1 = of("phase B current", "CURR_FDBK_B", Analog { adc1_in: 7 }),
                current_c: PC0 = of("phase C current", "CURR_FDBK_C", Analog { adc1_in: 6 }),
                vbus: PA1 = of("supply voltage", "VBUS", Analog { adc1_in: 2 }),
                // A comparator's reference through R77 and the board's RC (PB4's reset state is JTAG's NJTRST with a
                // pull-up): driven high, a known level (docs/hardware.md, "The break").
                current_ref: PB4 = of("overcurrent threshold", "CURRENT_REF", Mode::Output { high: true }),
                $($extra)*
            }
            peripherals {
                bridge: TIM1 = "the bridge's PWM and break",
                h1_exti: EXTI15 = "hall H1 edges",
                h2_exti: EXTI3 = "hall H2 edges",
                h3_exti: EXTI10 = "hall H3 edges",
            }
        }
    };
}

/// The brushless thruster's description (see the module's documentation): the motor's NTC on PB11 (ADC1 IN14),
/// which the IHM08M1 also feeds BEMF2 through R60. BEMF2 reaches PC4 through R61 as well, so R60 is removed and
/// nothing is lost.
#[macro_export]
macro_rules! thruster_image {
    ($($then:ident)::+ $(, $arg:tt)*) => {
        $crate::power_stage_rows! { [$($then)::+] [$($arg),*]
            ntc: PB11 @ "CN10 18" = analog("motor NTC", 14),
        }
    };
}

/// The brushed thruster's description: TEMPERATURE is the controller's (IDS 8.4.2), the IHM08M1's power-stage
/// NTC on PC2.
#[macro_export]
macro_rules! thruster_brushed_image {
    ($($then:ident)::+ $(, $arg:tt)*) => {
        $crate::power_stage_rows! { [$($then)::+] [$($arg),*]
            ntc: PC2 = of("power-stage NTC", "TEMPERATURE", Analog { adc1_in: 8 }),
        }
    };
}

/// The motor-less thruster's description, on a bare NUCLEO: the I2C slave, the real water-sensor pin and B1
/// holding the model's rotor.
#[macro_export]
macro_rules! thruster_motorless_image {
    ($($then:ident)::+ $(, $arg:tt)*) => {
        $crate::thruster_rows! { [$($then)::+] [$($arg),*]
            pins {
                // B1 connects PC13 to 3V3 when pressed (MB1367): pulled down, it reads low when released.
                hold: PC13 = of("model rotor hold", "B1", Input(Pull::Down)),
            }
            peripherals {}
        }
    };
}

/// The master's description, on a bare NUCLEO-G474RE: the pins and alternate functions are the G431's (the two
/// chips share the LQFP64 pinout and these functions, DS12288 Table 13 and DS12589 Table 13), which embassy-stm32's
/// trait bounds check again in the image's build for the G474.
#[macro_export]
macro_rules! master_image {
    ($($then:ident)::+ $(, $arg:tt)*) => {
        $($then)::+! { [$($arg),*]
            pins {
                bus1_scl: PA15 @ "CN7 17" = digital("thruster bus 1 SCL", i2c("I2C1_SCL", 4)),
                bus1_sda: PB7 @ "CN7 21" = digital("thruster bus 1 SDA", i2c("I2C1_SDA", 4)),
                bus2_scl: PA9 @ "Arduino D8" = digital("thruster bus 2 SCL", i2c("I2C2_SCL", 4)),
                bus2_sda: PA8 @ "Arduino D7" = digital("thruster bus 2 SDA", i2c("I2C2_SDA", 4)),
                bus3_scl: PC8 @ "CN10 2" = digital("thruster bus 3 SCL", i2c("I2C3_SCL", 8)),
                bus3_sda: PC9 @ "CN10 1" = digital("thruster bus 3 SDA", i2c("I2C3_SDA", 8)),
                can_rx: PA11 @ "CN10 14" = digital("battery CAN RX", af("FDCAN1_RX", 9)),
                can_tx: PA12 @ "CN10 12" = digital("battery CAN TX", af("FDCAN1_TX", 9)),
                console_tx: PA2 = of("console TX", "VCP (ST-LINK RX)", af("LPUART1_TX", 12)),
                console_rx: PA3 = of("console RX", "VCP (ST-LINK TX)", af("LPUART1_RX", 12)),
            }
            peripherals {
                bus1: I2C1 = "thruster bus 1",
                bus1_tx_dma: DMA1_CH1 = "thruster bus 1 transmit DMA",
                bus1_rx_dma: DMA1_CH2 = "thruster bus 1 receive DMA",
                bus2: I2C2 = "thruster bus 2",
                bus2_tx_dma: DMA1_CH3 = "thruster bus 2 transmit DMA",
                bus2_rx_dma: DMA1_CH4 = "thruster bus 2 receive DMA",
                bus3: I2C3 = "thruster bus 3",
                bus3_tx_dma: DMA1_CH5 = "thruster bus 3 transmit DMA",
                bus3_rx_dma: DMA1_CH6 = "thruster bus 3 receive DMA",
                can: FDCAN1 = "battery CAN, 1 Mbit/s",
                console: LPUART1 = "console, MAVLink v2 at 115200 baud",
                flash: FLASH = "the settings pages, the bootloader's state (a new image's trial) and DFU (field update)",
                watchdog: IWDG = "independent watchdog, fed by a task of the one executor",
            }
            interrupts {}
        }
    };
}

/// The bootloader (lbv-boot), the thruster's and the master's: no pin it takes a peripheral through (the thruster's
/// holds the gate inputs off by GPIO registers before anything else, [`THRUSTER_GATES_OFF`], and the image it starts
/// takes them over); the flash it checks and swaps images in, and the watchdog it starts first and feeds through
/// the swap.
#[macro_export]
macro_rules! boot_image {
    ($($then:ident)::+ $(, $arg:tt)*) => {
        $($then)::+! { [$($arg),*]
            pins {}
            peripherals {
                flash: FLASH = "the swap: its state, ACTIVE and DFU",
                watchdog: IWDG = "started first and fed through the check and the swap; an image that hangs before its own set-up is reset and reverted",
            }
            interrupts {}
        }
    };
}

/// A description's pins as [`Use`]s.
#[doc(hidden)]
#[macro_export]
macro_rules! description_uses {
    ([] pins { $($field:ident : $pin:ident $(@ $header:literal)? = $use:ident ($($args:tt)*)),* $(,)? }
        peripherals { $($peripheral:ident : $name:ident = $what:literal),* $(,)? }
        interrupts { $($irq:ident : $irq_name:ident = $priority:ident $irq_what:literal),* $(,)? }) => {
        &[$($crate::pins::Use::$use($crate::pins::Pin::named(stringify!($pin)), $($args)*) $(.at($header))?),*]
    };
}

/// A description's peripherals as [`Peripheral`](crate::pins::Peripheral)s.
#[doc(hidden)]
#[macro_export]
macro_rules! description_peripherals {
    ([] pins { $($field:ident : $pin:ident $(@ $header:literal)? = $use:ident ($($args:tt)*)),* $(,)? }
        peripherals { $($peripheral:ident : $name:ident = $what:literal),* $(,)? }
        interrupts { $($irq:ident : $irq_name:ident = $priority:ident $irq_what:literal),* $(,)? }) => {
        &[$($crate::pins::Peripheral { name: stringify!($name), function: $what }),*]
    };
}

/// A description's interrupts as [`Interrupt`](crate::pins::Interrupt)s.
#[doc(hidden)]
#[macro_export]
macro_rules! description_interrupts {
    ([] pins { $($field:ident : $pin:ident $(@ $header:literal)? = $use:ident ($($args:tt)*)),* $(,)? }
        peripherals { $($peripheral:ident : $name:ident = $what:literal),* $(,)? }
        interrupts { $($irq:ident : $irq_name:ident = $priority:ident $irq_what:literal),* $(,)? }) => {
        &[$($crate::pins::Interrupt {
            name: stringify!($irq_name),
            priority: stringify!($priority),
            function: $irq_what,
        }),*]
    };
}

/// In a binding: `let chip = g431_hw::chip!(master_image, chip);`, with `chip` the `embassy_stm32::Peripherals`,
/// moves the description's pins and peripherals out of `chip` into a struct with one field per row and gives it
/// back, each interrupt of the description at its priority. Bound to the name `chip` again, it leaves nothing else
/// of the chip in reach.
#[macro_export]
macro_rules! chip {
    ($description:ident, $peripherals:ident) => {
        $crate::$description!($crate::chip_take, $peripherals)
    };
}

#[doc(hidden)]
#[macro_export]
macro_rules! chip_take {
    ([$chip:ident] pins { $($field:ident : $pin:ident $(@ $header:literal)? = $use:ident ($($args:tt)*)),* $(,)? }
        peripherals { $($peripheral:ident : $name:ident = $what:literal),* $(,)? }
        interrupts { $($irq:ident : $irq_name:ident = $priority:ident $irq_what:literal),* $(,)? }) => {{
        /// The pins and peripherals of the image's description (`g431_hw::images`).
        #[allow(dead_code)]
        struct Chip {
            $($field: ::embassy_stm32::Peri<'static, ::embassy_stm32::peripherals::$pin>,)*
            $($peripheral: ::embassy_stm32::Peri<'static, ::embassy_stm32::peripherals::$name>,)*
            $($irq: ::embassy_stm32::interrupt::Interrupt,)*
        }
        Chip {
            $($field: $chip.$pin,)*
            $($peripheral: $chip.$name,)*
            $($irq: {
                use ::embassy_stm32::interrupt::{Interrupt, InterruptExt as _, Priority};
                Interrupt::$irq_name.set_priority(Priority::$priority);
                Interrupt::$irq_name
            },)*
        }
    }};
}

/// The brushless thruster on its boards.
pub const THRUSTER: Image = Image {
    name: "thruster-fw",
    boards: POWER_STAGE,
    removed: &["R60"],
    uses: crate::thruster_image!(crate::description_uses),
    peripherals: crate::thruster_image!(crate::description_peripherals),
    interrupts: crate::thruster_image!(crate::description_interrupts),
};

/// The brushed thruster on its boards.
pub const THRUSTER_BRUSHED: Image = Image {
    name: "thruster-fw (brushed)",
    boards: POWER_STAGE,
    removed: &[],
    uses: crate::thruster_brushed_image!(crate::description_uses),
    peripherals: crate::thruster_brushed_image!(crate::description_peripherals),
    interrupts: crate::thruster_brushed_image!(crate::description_interrupts),
};

/// The motor-less thruster on a bare NUCLEO.
pub const THRUSTER_MOTORLESS: Image = Image {
    name: "thruster-fw (motorless)",
    boards: &[&NUCLEO_G431RB],
    removed: &[],
    uses: crate::thruster_motorless_image!(crate::description_uses),
    peripherals: crate::thruster_motorless_image!(crate::description_peripherals),
    interrupts: crate::thruster_motorless_image!(crate::description_interrupts),
};

/// The master on a bare NUCLEO-G474RE.
pub const MASTER: Image = Image {
    name: "lbv-master-fw",
    boards: &[&NUCLEO_G474RE],
    removed: &[],
    uses: crate::master_image!(crate::description_uses),
    peripherals: crate::master_image!(crate::description_peripherals),
    interrupts: crate::master_image!(crate::description_interrupts),
};

/// What the thruster's bootloader writes before anything else: the IHM08M1's six gate inputs (the brushless image's
/// TIM1 outputs, which the brushed one uses a part of) driven to their off level, PA7..PA10 on port A and PB0, PB1
/// on port B. Until then the L6398's low-side inputs are held off only by their weak internal pull-ups (3-20 uA,
/// datasheet table 8), and a drifting LIN would brake a windmilling motor through a swap that takes seconds.
pub const THRUSTER_GATES_OFF: [crate::tim1::GatesOff; 2] = [
    crate::tim1::gates_off(&THRUSTER, crate::tim1::IHM08M1.driver, crate::pins::Port::A),
    crate::tim1::gates_off(&THRUSTER, crate::tim1::IHM08M1.driver, crate::pins::Port::B),
];

/// The thruster's bootloader, on the thruster's boards.
pub const THRUSTER_BOOT: Image = Image {
    name: "thruster-boot",
    boards: POWER_STAGE,
    removed: &[],
    uses: crate::boot_image!(crate::description_uses),
    peripherals: crate::boot_image!(crate::description_peripherals),
    interrupts: crate::boot_image!(crate::description_interrupts),
};

/// The master's bootloader, on the master's board.
pub const MASTER_BOOT: Image = Image {
    name: "master-boot",
    boards: &[&NUCLEO_G474RE],
    ..THRUSTER_BOOT
};

/// Every image's pins.
pub const ALL: [&Image; 6] = [
    &THRUSTER,
    &THRUSTER_BRUSHED,
    &THRUSTER_MOTORLESS,
    &THRUSTER_BOOT,
    &MASTER,
    &MASTER_BOOT,
];

const _: () = {
    let mut rest: &[&Image] = &ALL;
    while let [image, tail @ ..] = rest {
        assert!(crate::pins::check(image).is_ok());
        rest = tail;
    }
};

/// One firmware image as `./test.sh` builds it, and what it may take of the chip.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Build {
    /// Its file under `target/images/`.
    pub name: &'static str,
    /// The crate it is built from.
    pub package: &'static str,
    /// The Cargo features it is built with, comma separated.
    pub features: &'static str,
    /// Its pins and peripherals.
    pub image: &'static Image,
    /// Its memory layout, printed as its `memory.x`.
    pub layout: &'static Layout,
    /// Its budget for flash (code, constants, `.data`'s initial values), in bytes: each application holds to what
    /// it needs and a margin, inside its ACTIVE partition (the thruster's 50 KiB, the master's 228 KiB), so that
    /// growth is a decision and not an accident; a bootloader has its whole partition.
    pub flash_budget: u32,
    /// Its budget for static RAM (`.data`, `.bss`, `.uninit`), in bytes; the rest of the RAM is stack.
    pub ram_budget: u32,
    /// Its budget for stack, in bytes: the deepest the stack may reach, held against the high-water mark rehost
    /// measures (`rehost/tests/test_figures.py`, `test_bootloader.py`), as Hubris holds each task to its
    /// `stacksize`. With the static RAM budget it fits the RAM: flip-link puts the stack below the statics, so an
    /// overflow faults instead of corrupting them.
    pub stack_budget: u32,
}

/// The flash budget of every thruster application ([`Build::flash_budget`]): the largest image field update has to
/// carry to a thruster. 40 KiB of ACTIVE's 50: the images are 34.4 to 35.3 KiB.
pub const THRUSTER_FLASH_BUDGET: u32 = 40 * KIB;

const fn thruster(name: &'static str, features: &'static str, image: &'static Image) -> Build {
    Build {
        name,
        package: "thruster-fw",
        features,
        image,
        layout: &memory::THRUSTER,
        flash_budget: THRUSTER_FLASH_BUDGET,
        ram_budget: 16 * KIB,
        // About 1.1 KiB measured at rest and driving: the tasks' futures live in statics, not on the stack.
        stack_budget: 4 * KIB,
    }
}

/// The flash budget of the vehicle's master application ([`Build::flash_budget`]): the largest image the master's
/// own update carries. ACTIVE holds 228 KiB; the budget keeps each step of growth deliberate (148 KiB until the
/// courier carried one image to every thruster of a family and told the apply's progress, 3.2 KiB of code; 156 KiB
/// until the parameters were served as `@PARAM/param.pck`, 1.5 KiB, and the post-mortem record was kept, told and
/// served, 4 KiB; 164 KiB until the black box, 8.4 KiB: its recording, the telemetry log made from it, and the
/// operator's own allowance for file reads; 172 KiB until the read-only parameters QGroundControl's setup pages
/// read, 1.3 KiB).
pub const MASTER_FLASH_BUDGET: u32 = 176 * KIB;

/// The acceptance images' flash budget: the master's core without the update server, with the acceptance script
/// (136 KiB until the post-mortem record, 3.4 KiB).
const ACCEPTANCE_FLASH_BUDGET: u32 = 140 * KIB;

const fn master(name: &'static str, features: &'static str, flash_budget: u32) -> Build {
    Build {
        name,
        package: "lbv-master-fw",
        features,
        image: &MASTER,
        layout: &memory::MASTER,
        flash_budget,
        // Of the G474's 128 KiB: the rest is stack, and below it the black box (64 KiB, `kept_ram`). 32 KiB until
        // the thrusters' post-mortem records, which the master keeps one per slot (8 x 128 B, and the one being
        // fetched).
        ram_budget: 34 * KIB,
        // 22.4 KiB measured (rehost, at idle and polling; 22.1 before the black box): embassy-executor materialises
        // the node's task, ports and all, on the stack when it spawns it (`stm32.rs`, "write_in_place").
        stack_budget: 24 * KIB,
    }
}

/// A bootloader: its partition is all its flash; its static RAM is next to nothing (the page buffer it swaps
/// through and the signature check's state are on its stack).
const fn bootloader(
    name: &'static str,
    features: &'static str,
    image: &'static Image,
    layout: &'static Layout,
) -> Build {
    Build {
        name,
        package: "lbv-boot",
        features,
        image,
        layout,
        flash_budget: match layout.boot {
            memory::Boot::Bootloader(partitions) => partitions.bootloader.length,
            _ => 0,
        },
        ram_budget: KIB,
        // The page it copies through (2 KiB) and the hash's and the curve's state.
        stack_budget: 8 * KIB,
    }
}

/// Every image `./test.sh` builds, lints and holds to its budgets.
pub const BUILDS: [Build; 12] = [
    thruster("thruster-fw", "", &THRUSTER),
    thruster("thruster-fw-legacy", "legacy", &THRUSTER),
    thruster("thruster-fw-brushed", "brushed", &THRUSTER_BRUSHED),
    thruster("thruster-fw-motorless", "motorless", &THRUSTER_MOTORLESS),
    thruster("thruster-fw-motorless-legacy", "motorless,legacy", &THRUSTER_MOTORLESS),
    thruster("thruster-fw-bringup", "bringup", &THRUSTER),
    bootloader("thruster-boot", "thruster", &THRUSTER_BOOT, &memory::THRUSTER_BOOT),
    bootloader("master-boot", "master", &MASTER_BOOT, &memory::MASTER_BOOT),
    master("lbv-master-fw", "", MASTER_FLASH_BUDGET),
    master("lbv-master-fw-devkit", "devkit,legacy", MASTER_FLASH_BUDGET),
    master("lbv-master-fw-acceptance", "acceptance", ACCEPTANCE_FLASH_BUDGET),
    master(
        "lbv-master-fw-acceptance-legacy",
        "acceptance,legacy",
        ACCEPTANCE_FLASH_BUDGET,
    ),
];

/// The one memory layout of every image built from `package` whose features are all `enabled`: a crate whose
/// images differ in layout tells them apart by a feature (lbv-boot's `thruster` and `master`).
pub fn layout_of(package: &str, enabled: impl Fn(&str) -> bool) -> Result<&'static Layout, LayoutOfError> {
    let mut layouts = BUILDS
        .iter()
        .filter(|build| build.package == package)
        .filter(|build| build.features.split(',').filter(|f| !f.is_empty()).all(&enabled))
        .map(|build| build.layout);
    let layout = layouts.next().ok_or(LayoutOfError::Unknown)?;
    if layouts.any(|other| other != layout) {
        return Err(LayoutOfError::Several);
    }
    Ok(layout)
}

/// Why a crate has no one memory layout.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LayoutOfError {
    /// No image is built from it with these features.
    Unknown,
    /// Its images with these features differ in layout: its build script cannot tell which it is building.
    Several,
}

impl fmt::Display for LayoutOfError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            LayoutOfError::Unknown => {
                "no image in g431_hw::images::BUILDS is built from this crate with these features \
                 (lbv-boot: --features thruster or --features master)"
            }
            LayoutOfError::Several => {
                "this crate's images in g431_hw::images::BUILDS with these features differ in memory layout"
            }
        })
    }
}

impl core::error::Error for LayoutOfError {}

/// The bytes at the bottom of a chip's RAM that the images keep over a reset: the post-mortem region, and on the
/// master's G474 its black box above it ([`memory::CRASH`], [`memory::BLACK_BOX`]).
pub const fn kept_ram(layout: &Layout) -> u32 {
    if layout.chip.ram.length == memory::G474RE.ram.length {
        memory::CRASH.length + memory::BLACK_BOX.length
    } else {
        memory::CRASH.length
    }
}

// Every budget fits its layout's FLASH and RAM regions, the stack's beside the statics' and above what the images
// keep at the bottom of RAM.
const _: () = {
    let mut rest: &[Build] = &BUILDS;
    while let [build, tail @ ..] = rest {
        assert!(memory::check(build.layout).is_ok());
        let (Some(flash), Some(ram)) = (build.layout.region("FLASH"), build.layout.region("RAM")) else {
            panic!("a layout without FLASH or RAM");
        };
        assert!(build.flash_budget <= flash.span.length);
        assert!(kept_ram(build.layout) + build.ram_budget + build.stack_budget <= ram.span.length);
        rest = tail;
    }
};

/// Write the pin table of `images` (each with the name its column gives it) as a Markdown table, one row per
/// distinct use: the docs' tables are this output (`cargo run -p g431-hw --bin images -- docs --write`).
pub fn write_pin_table(images: &[(&str, &Image)], out: &mut impl fmt::Write) -> fmt::Result {
    let several = images.len() > 1;
    write!(out, "| function | pin | set up as | on the boards |")?;
    if several {
        write!(out, " builds |")?;
    }
    write!(out, "\n|---|---|---|---|")?;
    if several {
        write!(out, "---|")?;
    }
    writeln!(out)?;
    for (index, (_, image)) in images.iter().enumerate() {
        for used in image.uses {
            let earlier = images.iter().take(index).any(|(_, other)| other.uses.contains(used));
            if earlier {
                continue;
            }
            write!(out, "| {} | {}", used.function, used.pin)?;
            if let Some(header) = used.header {
                write!(out, " ({header})")?;
            }
            write!(out, " | ")?;
            write_mode(used.mode, out)?;
            write!(out, " | ")?;
            match used.signal {
                Some(signal) => {
                    write!(out, "{signal}")?;
                    if let Some((board, via)) = board_of(image, used.pin, signal) {
                        write!(out, ": {board}")?;
                        if let Some(via) = via {
                            write!(out, ", {via}")?;
                        }
                    }
                }
                None => write!(out, "free")?,
            }
            write!(out, " |")?;
            if several {
                let mut users = images.iter().filter(|(_, other)| other.uses.contains(used));
                if users.clone().count() == images.len() {
                    write!(out, " all")?;
                } else {
                    let mut first = true;
                    for (name, _) in users.by_ref() {
                        write!(out, "{} {name}", if first { "" } else { "," })?;
                        first = false;
                    }
                }
                write!(out, " |")?;
            }
            writeln!(out)?;
        }
    }
    Ok(())
}

/// Write the peripherals `image` takes besides its pins, and the interrupts whose priority it sets, as a Markdown
/// table.
pub fn write_peripheral_table(image: &Image, out: &mut impl fmt::Write) -> fmt::Result {
    writeln!(out, "| peripheral | for |\n|---|---|")?;
    for peripheral in image.peripherals {
        writeln!(out, "| {} | {} |", peripheral.name, peripheral.function)?;
    }
    for interrupt in image.interrupts {
        writeln!(
            out,
            "| {} interrupt, priority {} | {} |",
            interrupt.name, interrupt.priority, interrupt.function
        )?;
    }
    Ok(())
}

fn write_mode(mode: Mode, out: &mut impl fmt::Write) -> fmt::Result {
    let pull = |pull| match pull {
        Pull::None => "",
        Pull::Up => ", pull-up",
        Pull::Down => ", pull-down",
    };
    match mode {
        Alternate { signal, af, pull: p } => write!(out, "{signal} (AF{af}){}", pull(p)),
        Mode::AlternateOpenDrain { signal, af } => write!(out, "{signal} (AF{af}), open drain"),
        Input(p) => write!(out, "input{}", pull(p)),
        Analog { adc1_in } => write!(out, "ADC1 IN{adc1_in}"),
        Mode::Output { high } => write!(out, "output, held {}", if high { "high" } else { "low" }),
    }
}

/// The board of `image` that puts `signal` on `pin`, and the link it goes through.
fn board_of(image: &Image, pin: crate::pins::Pin, signal: &str) -> Option<(&'static str, Option<&'static str>)> {
    image.boards.iter().find_map(|board| {
        board
            .signals
            .iter()
            .find(|s| s.pin == pin && s.name == signal)
            .map(|s| (board.name, s.via))
    })
}

/// The docs' generated tables, by the marker that opens each: `<!-- generated: NAME -->` ... `<!-- end -->`.
pub fn write_docs_table(name: &str, out: &mut impl fmt::Write) -> Option<fmt::Result> {
    Some(match name {
        "thruster pins" => write_pin_table(
            &[
                ("brushless", &THRUSTER),
                ("brushed", &THRUSTER_BRUSHED),
                ("motorless", &THRUSTER_MOTORLESS),
            ],
            out,
        ),
        "thruster peripherals" => write_peripheral_table(&THRUSTER, out),
        "bootloader peripherals" => write_peripheral_table(&THRUSTER_BOOT, out),
        "master pins" => write_pin_table(&[("", &MASTER)], out),
        "master peripherals" => write_peripheral_table(&MASTER, out),
        "thruster flash" => write_flash_table(&memory::THRUSTER, out),
        "master flash" => write_flash_table(&memory::MASTER, out),
        _ => return None,
    })
}

/// The names of the docs' generated tables.
pub const DOCS_TABLES: [&str; 7] = [
    "thruster pins",
    "thruster peripherals",
    "bootloader peripherals",
    "master pins",
    "master peripherals",
    "thruster flash",
    "master flash",
];

/// A layout's flash regions as a Markdown table: start, size and what each holds.
fn write_flash_table(layout: &Layout, out: &mut impl fmt::Write) -> fmt::Result {
    writeln!(out, "| Region | Start | Size | Holds |\n|---|---|---|---|")?;
    for region in layout
        .regions
        .iter()
        .filter(|region| layout.chip.flash.contains(region.span))
    {
        let span = region.span;
        writeln!(
            out,
            "| {} | 0x{:08X} | {} KiB | {} |",
            region.name,
            span.origin,
            span.length / KIB,
            region.holds
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pins::Port::{A, B, C};
    use crate::pins::{Conflict, Use, check, pin};

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
        peripherals: &[],
        interrupts: &[],
    };

    #[test]
    fn no_stack_within_its_budget_reaches_the_crash_record() {
        for build in BUILDS {
            let ram = build.layout.chip.ram;
            assert!(ram.contains(crate::memory::CRASH), "{}", build.name);
            // The stack's deepest, below the statics at the top, is still above the region at the bottom.
            let deepest = ram.end() - build.ram_budget - build.stack_budget;
            assert!(deepest >= crate::memory::CRASH.end(), "{}: {deepest:#x}", build.name);
        }
    }

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

    /// The docs' tables are the data's: `cargo run -p g431-hw --bin images -- docs --write` rewrites them.
    #[test]
    fn the_docs_tables_are_generated_from_the_descriptions() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/hardware.md");
        let docs = std::fs::read_to_string(path).expect("docs/hardware.md");
        for name in DOCS_TABLES {
            let open = format!("<!-- generated: {name} -->\n");
            let start = docs
                .find(&open)
                .unwrap_or_else(|| panic!("docs/hardware.md has no {open:?}"))
                + open.len();
            let end = start + docs[start..].find("<!-- end -->").expect("the table's end marker");
            let mut table = String::new();
            write_docs_table(name, &mut table)
                .expect("a known table")
                .expect("written");
            assert_eq!(
                docs[start..end],
                table,
                "docs/hardware.md's {name} table is not the data's: regenerate it"
            );
        }
    }

    #[test]
    fn each_crate_has_one_layout_and_the_bootloader_one_per_board() {
        let with = |features: &'static [&'static str]| move |feature: &str| features.contains(&feature);
        assert_eq!(layout_of("lbv-boot", with(&["thruster"])), Ok(&memory::THRUSTER_BOOT));
        assert_eq!(layout_of("lbv-boot", with(&["master"])), Ok(&memory::MASTER_BOOT));
        assert_eq!(layout_of("lbv-boot", with(&[])), Err(LayoutOfError::Unknown));
        assert_eq!(
            layout_of("lbv-boot", with(&["thruster", "master"])),
            Err(LayoutOfError::Several)
        );
        assert_eq!(layout_of("thruster-fw", with(&["stm32"])), Ok(&memory::THRUSTER));
        assert_eq!(
            layout_of("thruster-fw", with(&["stm32", "legacy", "brushed"])),
            Ok(&memory::THRUSTER)
        );
        assert_eq!(
            layout_of("lbv-master-fw", with(&["stm32", "acceptance"])),
            Ok(&memory::MASTER)
        );
        assert_eq!(layout_of("lbv", with(&[])), Err(LayoutOfError::Unknown));
        // A bootloader fills its partition at most, and takes no pin through embassy (the gates are GPIO writes).
        for (name, partitions) in [
            ("thruster-boot", memory::THRUSTER_PARTITIONS),
            ("master-boot", memory::MASTER_PARTITIONS),
        ] {
            let boot = BUILDS.iter().find(|build| build.name == name).unwrap();
            assert_eq!(boot.flash_budget, partitions.bootloader.length);
            assert_eq!(boot.layout.chip, partitions.chip);
            assert!(boot.image.uses.is_empty());
            let peripherals: Vec<&str> = boot.image.peripherals.iter().map(|p| p.name).collect();
            assert_eq!(peripherals, ["FLASH", "IWDG"]);
        }
    }

    #[test]
    fn the_thruster_bootloader_holds_every_gate_input_off() {
        use crate::pins::Port;
        let [a, b] = THRUSTER_GATES_OFF;
        assert_eq!((a.port, b.port), (Port::A, Port::B));
        // L6398: HIN (TIM1_CHx: PA8, PA9, PA10) active high, so low is off; LIN (TIM1_CHxN: PA7, PB0, PB1) active
        // low, so high is off.
        let reset = |pins: &[u32]| pins.iter().map(|n| 1u32 << (n + 16)).sum::<u32>();
        let set = |pins: &[u32]| pins.iter().map(|n| 1u32 << n).sum::<u32>();
        assert_eq!(a.bsrr, reset(&[8, 9, 10]) | set(&[7]));
        assert_eq!(b.bsrr, set(&[0, 1]));
        let output = |pins: &[u32]| pins.iter().map(|n| 1u32 << (2 * n)).sum::<u32>();
        assert_eq!(a.moder_output, output(&[7, 8, 9, 10]));
        assert_eq!(a.moder_mask, 3 * a.moder_output);
        assert_eq!(b.moder_output, output(&[0, 1]));
        // Every TIM1 channel output the brushless and brushed images use is among them, and the break input is not.
        for image in [&THRUSTER, &THRUSTER_BRUSHED] {
            for used in image.uses {
                if let Mode::Alternate { signal, .. } = used.mode
                    && signal.starts_with("TIM1_CH")
                {
                    let write = if used.pin.port == Port::A { a } else { b };
                    assert_ne!(
                        write.moder_output & (1 << (2 * used.pin.number)),
                        0,
                        "{signal} on {}",
                        used.pin
                    );
                }
            }
        }
        assert_eq!(
            crate::tim1::gate_off_level("TIM1_BKIN", crate::tim1::IHM08M1.driver),
            None
        );
    }

    #[test]
    fn a_pin_table_row_says_where_and_how() {
        let mut table = String::new();
        write_pin_table(&[("brushless", &THRUSTER), ("brushed", &THRUSTER_BRUSHED)], &mut table).unwrap();
        assert!(
            table.contains("| I2C slave SDA | PC11 (CN7 2) | I2C3_SDA (AF8), open drain | free | all |\n"),
            "{table}"
        );
        assert!(table.contains("| phase A low | PA7 | TIM1_CH1N (AF6) | UL: X-NUCLEO-IHM08M1, R58 | all |\n"));
        assert!(table.contains("| motor NTC | PB11 (CN10 18) | ADC1 IN14 | free | brushless |\n"));
        assert!(table.contains("| hall H1 | PA15 | input, pull-up | H1: X-NUCLEO-IHM08M1, R79 | all |\n"));
    }

    /// A description's rows are the binding's fields: the `chip!` expansion names each pin's embassy-stm32 type.
    #[test]
    fn descriptions_expand_to_pin_names() {
        macro_rules! pin_names {
            ([] pins { $($field:ident : $pin:ident $(@ $header:literal)? = $use:ident ($($args:tt)*)),* $(,)? }
                peripherals { $($peripheral:ident : $name:ident = $what:literal),* $(,)? }
                interrupts { $($irq:ident : $irq_name:ident = $priority:ident $irq_what:literal),* $(,)? }) => {
                [$(stringify!($pin)),*]
            };
        }
        let names = crate::master_image!(pin_names);
        let pins: Vec<String> = MASTER.uses.iter().map(|used| used.pin.to_string()).collect();
        assert_eq!(names.to_vec(), pins);
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
                    Mode::Input(_) | Mode::Output { .. } => continue,
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
