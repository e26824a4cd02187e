//! lbv-master-fw: the STM32G474 image of the LBV master node (NUCLEO-G474RE).
//!
//! The binding (`stm32.rs`, `board.rs`) exists only for the firmware target; on the host this binary is a stub and the
//! node's logic is tested through the library.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
mod board;
#[cfg(target_os = "none")]
mod stm32;

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("lbv-master-fw runs on the NUCLEO-G474RE's STM32G474: `cargo master` flashes it (docs/flashing.md)");
    std::process::exit(2);
}
