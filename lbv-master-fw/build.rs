//! Link the firmware image against its memory layout (`g431_hw::link`; host builds need nothing), and, for every
//! target, generate the console's MAVLink dialect (`mavlink/lbv.xml`) into `OUT_DIR/lbv.rs` and the image's
//! version for AUTOPILOT_VERSION into `OUT_DIR/build_info.rs`.
use std::path::{Path, PathBuf};
use std::process::Command;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out_dir = std::env::var_os("OUT_DIR").ok_or("OUT_DIR is not set")?;
    g431_hw::link::link_image(env!("CARGO_PKG_NAME"))?;

    // The console's MAVLink dialect: only the messages it uses, so the image carries only their codecs.
    let dialect = manifest_dir()?.join("mavlink/lbv.xml");
    let generated = mavlink_bindgen::generate(mavlink_bindgen::XmlDefinitions::Files(vec![dialect]), &out_dir)?;
    mavlink_bindgen::emit_cargo_build_messages(&generated);
    build_info(Path::new(&out_dir))?;
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

/// `OUT_DIR/build_info.rs`: the crate version as AUTOPILOT_VERSION.flight_sw_version encodes it, and the git
/// revision the image is built from (the first 8 hex digits in ASCII, as ArduPilot fills flight_custom_version).
/// Outside a git checkout, or without git, the revision is all zeros and a build warning says why: the build never
/// fails for it.
fn build_info(out_dir: &Path) -> Result<(), Box<dyn std::error::Error>> {
    let part =
        |name: &str| -> Result<u32, Box<dyn std::error::Error>> { Ok(std::env::var(name)?.parse::<u8>()?.into()) };
    // FIRMWARE_VERSION_TYPE: DEV (0) for a pre-release ("0.2.0-rc1"), BETA (128) for a release below 1.0 (semver's
    // "anything may change"), OFFICIAL (255) from 1.0 on. QGroundControl checks an OFFICIAL image of an ArduPilot
    // vehicle against ArduSub's latest stable release and tells the pilot it is out of date: this image is not
    // ArduSub, and not yet 1.0.
    let kind = if !std::env::var("CARGO_PKG_VERSION_PRE").unwrap_or_default().is_empty() {
        0
    } else if std::env::var("CARGO_PKG_VERSION_MAJOR")? == "0" {
        128
    } else {
        255
    };
    let version = part("CARGO_PKG_VERSION_MAJOR")? << 24
        | part("CARGO_PKG_VERSION_MINOR")? << 16
        | part("CARGO_PKG_VERSION_PATCH")? << 8
        | kind;
    let revision = match git_revision() {
        Ok(revision) => revision,
        Err(reason) => {
            println!("cargo:warning=AUTOPILOT_VERSION carries no git revision (zeros): {reason}");
            [0; 8]
        }
    };
    std::fs::write(
        out_dir.join("build_info.rs"),
        format!(
            "/// AUTOPILOT_VERSION.flight_sw_version: major, minor, patch, FIRMWARE_VERSION_TYPE, one byte each.\n\
             pub const FLIGHT_SW_VERSION: u32 = {version:#010x};\n\
             /// The git revision built from: 8 hex digits in ASCII (zeros when built outside git).\n\
             pub const GIT_REVISION: [u8; 8] = {revision:?};\n"
        ),
    )?;
    Ok(())
}

/// This crate's directory, as cargo gives it when it runs the script: not `env!`, which would keep the directory the
/// script was compiled in, and cargo runs the same compiled script for another checkout sharing the target directory.
fn manifest_dir() -> Result<PathBuf, std::env::VarError> {
    std::env::var("CARGO_MANIFEST_DIR").map(PathBuf::from)
}

/// The first 8 hex digits of HEAD, rebuilding when HEAD moves.
fn git_revision() -> Result<[u8; 8], String> {
    let git = |args: &[&str]| -> Result<String, String> {
        let output = Command::new("git")
            .args(args)
            .current_dir(manifest_dir().map_err(|error| error.to_string())?)
            .output()
            .map_err(|error| format!("git could not be run ({error})"))?;
        if !output.status.success() {
            return Err(format!(
                "`git {}` failed: {}",
                args.join(" "),
                String::from_utf8_lossy(&output.stderr).trim()
            ));
        }
        Ok(String::from_utf8_lossy(&output.stdout).trim().to_owned())
    };
    let hash = git(&["rev-parse", "HEAD"])?;
    // HEAD, the branch it names and the packed refs: a commit or a checkout changes one of them. A worktree keeps
    // its HEAD apart from the refs, which `--git-path` resolves.
    let mut watched = vec!["HEAD".to_owned(), "packed-refs".to_owned()];
    if let Ok(branch) = git(&["symbolic-ref", "-q", "HEAD"]) {
        watched.push(branch);
    }
    for name in watched {
        if let Ok(path) = git(&["rev-parse", "--git-path", &name]) {
            let path = manifest_dir()
                .map_err(|error| error.to_string())?
                .join(PathBuf::from(path));
            // A path that does not exist would make every build rerun this script.
            if path.exists() {
                println!("cargo:rerun-if-changed={}", path.display());
            }
        }
    }
    let bytes = hash.as_bytes();
    match bytes.get(..8) {
        Some(digits) if digits.iter().all(u8::is_ascii_hexdigit) => {
            let mut revision = [0; 8];
            revision.copy_from_slice(digits);
            Ok(revision)
        }
        _ => Err(format!("`git rev-parse HEAD` gave {hash:?}")),
    }
}
