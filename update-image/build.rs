//! The public key the firmware accepts update files signed with (`update_image::UPDATE_KEY`, feature `key`): the
//! file named by `LBV_UPDATE_KEY`, the development key (keys/dev.pub) by default. Every build for the firmware
//! target, whatever its profile, refuses the development key unless `LBV_ALLOW_DEV_KEY=1` asks for it
//! (keys/README.md): its secret is published, and an image that embeds it passes the key on to every image after
//! it. A build without the feature (the bootloader's, which checks with the key of the image that runs) embeds no
//! key and refuses nothing.
use std::path::PathBuf;

// The key file reader the crate itself uses.
#[path = "src/hex.rs"]
mod hex;
use hex::key_from_hex;

fn main() -> Result<(), String> {
    if std::env::var_os("CARGO_FEATURE_KEY").is_none() {
        return Ok(());
    }
    println!("cargo:rerun-if-env-changed=LBV_UPDATE_KEY");
    println!("cargo:rerun-if-env-changed=LBV_ALLOW_DEV_KEY");
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").map_err(|e| e.to_string())?);
    let dev_path = manifest.join("../keys/dev.pub");
    println!("cargo:rerun-if-changed={}", dev_path.display());
    let path = std::env::var_os("LBV_UPDATE_KEY").map_or(dev_path.clone(), PathBuf::from);
    println!("cargo:rerun-if-changed={}", path.display());

    let read = |path: &PathBuf| -> Result<[u8; 32], String> {
        let text = std::fs::read_to_string(path).map_err(|error| format!("{}: {error}", path.display()))?;
        key_from_hex(&text).ok_or(format!("{}: not a public key (64 hex digits)", path.display()))
    };
    let key = read(&path)?;
    let development = key == read(&dev_path)?;
    let firmware = std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none");
    let allowed = std::env::var("LBV_ALLOW_DEV_KEY").as_deref() == Ok("1");
    if firmware && development && !allowed {
        return Err(
            "a firmware build would accept update files signed with the development key, whose secret is \
                    published (keys/README.md): set LBV_UPDATE_KEY=path/to/your.pub, or LBV_ALLOW_DEV_KEY=1 for \
                    an image that stays on the bench"
                .into(),
        );
    }
    let out = PathBuf::from(std::env::var("OUT_DIR").map_err(|e| e.to_string())?);
    std::fs::write(
        out.join("update_key.rs"),
        format!(
            "/// The public key update files must be signed with (from {}).\n\
             pub const UPDATE_KEY: [u8; 32] = {key:?};\n\
             /// Whether [`UPDATE_KEY`] is the development key.\n\
             pub const UPDATE_KEY_IS_DEV: bool = {development};\n",
            path.display()
        ),
    )
    .map_err(|error| error.to_string())
}
