//! For the firmware crates' build scripts (feature `build`): link an image against its memory layout.

use std::path::PathBuf;

use crate::images::layout_of;

/// Link `package`'s binary for the firmware target against its layout: write its `memory.x` (from
/// [`layout_of`]) into `OUT_DIR` and hand the linker that directory and cortex-m-rt's and defmt's scripts. The
/// arguments go to the crate's own binaries only, so a crate that links it as a library (qemu-m4) brings its own
/// memory map. A host build needs nothing.
pub fn link_image(package: &str) -> Result<(), Box<dyn std::error::Error>> {
    println!("cargo:rerun-if-changed=build.rs");
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() != Ok("none") {
        return Ok(());
    }
    let out = PathBuf::from(std::env::var_os("OUT_DIR").ok_or("OUT_DIR is not set")?);
    // Cargo tells a build script its crate's features as CARGO_FEATURE_<NAME> (upper case, `-` as `_`).
    let enabled = |feature: &str| {
        let name = feature.to_uppercase().replace('-', "_");
        std::env::var_os(format!("CARGO_FEATURE_{name}")).is_some()
    };
    std::fs::write(out.join("memory.x"), layout_of(package, enabled)?.to_string())?;
    // flip-link takes the search path as two arguments.
    println!("cargo:rustc-link-arg-bins=-L");
    println!("cargo:rustc-link-arg-bins={}", out.display());
    for arg in ["--nmagic", "-Tlink.x", "-Tdefmt.x"] {
        println!("cargo:rustc-link-arg-bins={arg}");
    }
    Ok(())
}
