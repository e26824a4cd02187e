//! Link the firmware image against the workspace's `memory.x` (host builds need no link arguments), and, for
//! every target, generate the console's MAVLink dialect (`mavlink/lbv.xml`) into `OUT_DIR/lbv.rs`.
use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        let workspace = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        println!("cargo:rustc-link-search={}", workspace.display());
        println!("cargo:rustc-link-arg-bins=--nmagic");
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    }
    println!("cargo:rerun-if-changed=../memory.x");
    println!("cargo:rerun-if-changed=build.rs");

    // The console's MAVLink dialect: only the messages it uses, so the image carries only their codecs.
    let dialect = Path::new(env!("CARGO_MANIFEST_DIR")).join("mavlink/lbv.xml");
    let out_dir = std::env::var_os("OUT_DIR").ok_or("OUT_DIR is not set")?;
    let generated = mavlink_bindgen::generate(mavlink_bindgen::XmlDefinitions::Files(vec![dialect]), &out_dir)?;
    mavlink_bindgen::emit_cargo_build_messages(&generated);
    // The generated code has optional serde / arbitrary / ts-rs derives, never enabled here.
    println!("cargo::rustc-check-cfg=cfg(feature, values(\"serde\", \"arbitrary\", \"ts-rs\"))");
    // The generated module is not written to this crate's lint rules: `console.rs` includes this declaration.
    std::fs::write(
        Path::new(&out_dir).join("lbv_dialect.rs"),
        "/// The generated MAVLink dialect of `mavlink/lbv.xml`: message structs (`*_DATA`) and enums.\n\
         #[allow(missing_docs, missing_debug_implementations, non_camel_case_types, non_snake_case, \
         clippy::all, clippy::indexing_slicing, clippy::unwrap_used, clippy::expect_used, clippy::panic)]\n\
         pub mod lbv;\n",
    )?;
    Ok(())
}
