//! Link the bootloader against its memory layout, `memory.x` generated from `g431_hw::images` (its partitions'
//! offsets for embassy-boot included); host builds need nothing.
fn main() -> Result<(), Box<dyn std::error::Error>> {
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        let out = std::path::PathBuf::from(std::env::var_os("OUT_DIR").ok_or("OUT_DIR is not set")?);
        std::fs::write(
            out.join("memory.x"),
            g431_hw::images::layout_of(env!("CARGO_PKG_NAME"))?.to_string(),
        )?;
        println!("cargo:rustc-link-arg-bins=-L");
        println!("cargo:rustc-link-arg-bins={}", out.display());
        println!("cargo:rustc-link-arg-bins=--nmagic");
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
        // defmt's sections, for a build with embassy-stm32's defmt on (`stm32.rs`, `NoLog`); without, it adds
        // only the logger's two empty functions.
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    }
    println!("cargo:rerun-if-changed=build.rs");
    Ok(())
}
