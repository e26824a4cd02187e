//! The STM32G431 boards as data.
//!
//! Every register value the firmware bindings write that a mistake could make wrong is computed here by a pure
//! (mostly `const`) function, from the rules of the reference manual (RM0440) and the limits of the parts, and
//! checked on the host: TIM1's commutation patterns and safe state ([`tim1`]), I2C timing ([`i2c`]), FDCAN bit
//! timing and its clock tolerance ([`fdcan`]), ADC sample times against source impedance ([`adc`]), the
//! independent watchdog against the slowest task and the bootloader's trial boot ([`iwdg`]), the flash's ECC flags
//! ([`flash`]), the backup registers and reset flags a start reads ([`backup`]), and the clock tree they all derive
//! from ([`clock`]). The boards and the pins each image uses are data too ([`pins`], [`images`]), checked for
//! collisions at build time.
//!
//! Sources are cited where a value is used. Where a primary document could not be read, the comment says which
//! secondary source the value comes from.
#![cfg_attr(not(any(test, feature = "build")), no_std)]
#![forbid(unsafe_code)]

pub mod adc;
pub mod backup;
pub mod clock;
pub mod fdcan;
pub mod flash;
pub mod i2c;
pub mod images;
pub mod iwdg;
#[cfg(feature = "build")]
pub mod link;
pub mod memory;
pub mod pins;
pub mod tim1;
