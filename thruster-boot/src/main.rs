//! thruster-boot: the thruster's bootloader for the STM32G431.
//!
//! The binding (`stm32.rs`) exists only for the firmware target; on the host this binary is a stub and the
//! bootloader's decision is tested through the library, on lbv-sim's flash.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
mod stm32;

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!(
        "thruster-boot runs on the STM32G431: cargo build --release -p thruster-boot --target thumbv7em-none-eabihf"
    );
    std::process::exit(2);
}
