//! Link the emulated image against its own memory map (`memory.x` here, the mps2-an386's); host builds need
//! nothing.
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        let out = PathBuf::from(std::env::var_os("OUT_DIR").ok_or("OUT_DIR is not set")?);
        std::fs::copy("memory.x", out.join("memory.x"))?;
        // cortex-m-rt's `device` feature includes a device.x; the vector table is written in Rust (`board.rs`).
        std::fs::write(
            out.join("device.x"),
            "/* mps2-an386: interrupt handlers are bound in board.rs */\n",
        )?;
        println!("cargo:rustc-link-arg-bins=-L");
        println!("cargo:rustc-link-arg-bins={}", out.display());
        println!("cargo:rustc-link-arg-bins=--nmagic");
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    }
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=build.rs");
    Ok(())
}
