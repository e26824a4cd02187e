//! Link the firmware image against its memory layout, `memory.x` generated from `g431_hw::images`; host builds
//! need nothing.
fn main() -> Result<(), Box<dyn std::error::Error>> {
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        let out = std::path::PathBuf::from(std::env::var_os("OUT_DIR").ok_or("OUT_DIR is not set")?);
        std::fs::write(
            out.join("memory.x"),
            g431_hw::images::layout_of(env!("CARGO_PKG_NAME"))?.to_string(),
        )?;
        // The search path only for this crate's own binary: a crate linking this one as a library (qemu-m4)
        // brings its own memory map.
        println!("cargo:rustc-link-arg-bins=-L");
        println!("cargo:rustc-link-arg-bins={}", out.display());
        println!("cargo:rustc-link-arg-bins=--nmagic");
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    }
    println!("cargo:rerun-if-changed=build.rs");
    Ok(())
}
