//! lbv-boot: the bootloader of the thruster (STM32G431, feature `thruster`) and of the master (STM32G474, feature
//! `master`).
//!
//! The binding (`stm32.rs`) exists only for the firmware target; on the host this binary is a stub and the
//! bootloader's decision is tested through the library, on lbv-sim's flash.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
mod stm32;

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!(
        "lbv-boot runs on the boards: cargo build --release -p lbv-boot --features thruster (or master) \
         --target thumbv7em-none-eabihf"
    );
    std::process::exit(2);
}
