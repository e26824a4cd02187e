//! Link the firmware image against the workspace's `memory.x`; host builds need nothing.
fn main() {
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        let workspace = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        println!("cargo:rustc-link-search={}", workspace.display());
        println!("cargo:rustc-link-arg-bins=--nmagic");
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    }
    println!("cargo:rerun-if-changed=../memory.x");
    println!("cargo:rerun-if-changed=build.rs");
}
