//! `lbv image`: signing keys, signed update files made from firmware ELFs, and what a file (or an ELF) is.
//!
//! The format is update-image's (docs/field-update.md): an 80-byte header and the payload, the image as it sits in
//! flash from the ACTIVE partition's start. Signing is ed25519-dalek; `inspect` and the check after signing use
//! salty, what the devices verify with, so a file this writes is one they take.

use std::ffi::OsString;
use std::fmt;
use std::fs::{File, OpenOptions};
use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use object::Endianness;
use object::elf::{ELFCLASS32, EM_ARM, FileHeader32, PT_LOAD};
use object::read::elf::{FileHeader, ProgramHeader};
use update_image::{
    DEV_PUBLIC_KEY, HEADER_LEN, Header, INFO_FORMAT, INFO_LEN, INFO_OFFSET, ImageInfo, InfoError, KEY_LEN, KEY_OFFSET,
    PAD_BYTE, Refusal, Verifier, VerifyError, WRITE_UNIT, check_file, key_from_hex, public_key,
};

use crate::exit;

/// The largest update file read: the master's G474 has 512 KiB of flash, more than any payload (its ACTIVE
/// partition is 238 KiB).
pub const MAX_UPDATE_FILE: u64 = 512 * 1024;
/// The largest ELF read. A release image carries its full debug info (the workspace's release profile has
/// `debug = 2`), several MiB of it beside the few tens of KiB that load.
pub const MAX_ELF: u64 = 64 * 1024 * 1024;
/// The largest payload: the whole flash of the larger chip, the master's G474. An ELF whose segments span more is
/// not an image for either board.
pub const MAX_PAYLOAD: u64 = g431_hw::memory::G474RE.flash.length as u64;
/// The largest key file read: one line of 64 hex digits.
const MAX_KEY_FILE: u64 = 4096;

const HELP: &str = "\
keygen makes a signing key pair; sign turns a firmware ELF into a signed update file (.lbvu);
inspect says what an update file or a firmware ELF is and checks the signature. The development
key (keys/dev.key) is published with the source: sign refuses it without --allow-dev-key.

An image embeds the public key the vehicle checks the next update with, once the image runs.
sign refuses an ELF whose embedded key is not the signing key's public half (--rotate-key signs it
all the same, to move the vehicle to the embedded key), and one of image info format 1, which
embeds none.

Exit status: 0 done (inspect: the file is consistent and its signature verifies); 1 inspect
found a failure (a file refused, a signature that does not verify, an ELF without image info
or update key); 2 bad command line, a file that cannot be read or written, a key or ELF sign
cannot use.";

/// `lbv image`'s commands.
#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Make a signing key pair: PREFIX.key (the secret) and PREFIX.pub
    #[command(after_help = HELP)]
    Keygen(KeygenArgs),
    /// Sign a firmware ELF into an update file
    #[command(after_help = HELP)]
    Sign(SignArgs),
    /// Say what an update file (or a firmware ELF) is, and whether its signature verifies
    #[command(after_help = HELP)]
    Inspect(InspectArgs),
}

/// `lbv image keygen`'s command line.
#[derive(Debug, clap::Args)]
pub struct KeygenArgs {
    /// Where the keys go: PREFIX.key and PREFIX.pub (neither may exist)
    #[arg(long, value_name = "PREFIX")]
    pub out: PathBuf,
}

/// `lbv image sign`'s command line.
#[derive(Debug, clap::Args)]
pub struct SignArgs {
    /// The firmware ELF (built for field update: with its image info at the start of the image + 0x200)
    #[arg(value_name = "ELF")]
    pub elf: PathBuf,
    /// The secret key (lbv image keygen makes one)
    #[arg(long, value_name = "FILE.key")]
    pub key: PathBuf,
    /// The update file to write
    #[arg(long, value_name = "FILE.lbvu")]
    pub out: PathBuf,
    /// Where the payload starts, the ACTIVE partition's start [default: the ELF's lowest load address]
    #[arg(long, value_name = "ADDRESS", value_parser = address)]
    pub base: Option<u32>,
    /// Sign with the development key all the same (its secret is public: for bench images only); also needed to
    /// rotate to it
    #[arg(long)]
    pub allow_dev_key: bool,
    /// The image's security counter, set in its image info before signing: once it confirms, the vehicle takes no
    /// image with a lower one [default: the ELF's own, 0 from a build]
    #[arg(long, value_name = "N", value_parser = counter)]
    pub security_counter: Option<u32>,
    /// Sign the image as a rollback: the vehicle takes it over a newer version (still held to the security counter)
    #[arg(long)]
    pub allow_rollback: bool,
    /// Sign an ELF that embeds another update key than the signing key's public half: once the image confirms,
    /// the vehicle takes only files signed with the embedded key
    #[arg(long)]
    pub rotate_key: bool,
}

/// `lbv image inspect`'s command line.
#[derive(Debug, clap::Args)]
pub struct InspectArgs {
    /// An update file, or a firmware ELF
    #[arg(value_name = "FILE")]
    pub file: PathBuf,
    /// The public key to check the signature with [default: the development key]
    #[arg(long, value_name = "FILE.pub")]
    pub key: Option<PathBuf>,
}

/// `--base`: an address, in hex (0x...) or decimal.
fn address(text: &str) -> Result<u32, String> {
    let parsed = match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => u32::from_str_radix(&hex.replace('_', ""), 16),
        None => text.parse(),
    };
    parsed.map_err(|_| format!("{text:?} is not a 32-bit address (0x08002800, say)"))
}

/// `--security-counter`: a whole number that fits the image info's u32.
fn counter(text: &str) -> Result<u32, String> {
    text.parse().map_err(|_| {
        format!(
            "{text:?} is not a security counter: a whole number from 0 to {}",
            u32::MAX
        )
    })
}

/// A line on standard output; a reader that went away (`| head`) is not a panic, and the work is done all the same.
macro_rules! say {
    ($($arg:tt)*) => {{
        let _ = writeln!(io::stdout().lock(), $($arg)*);
    }};
}

/// `lbv image ...`
pub fn main(command: Command) -> ExitCode {
    let (name, outcome) = match command {
        Command::Keygen(args) => ("lbv image keygen", keygen(&args)),
        Command::Sign(args) => ("lbv image sign", sign(&args)),
        Command::Inspect(args) => ("lbv image inspect", inspect(&args)),
    };
    match outcome {
        Ok(code) => ExitCode::from(code),
        Err(Trouble(message)) => {
            eprintln!("{name}: {message}");
            ExitCode::from(exit::TROUBLE)
        }
    }
}

/// Why a command could not do its job (exit status 2).
#[derive(Debug)]
struct Trouble(String);

impl<T: fmt::Display> From<T> for Trouble {
    fn from(message: T) -> Self {
        Trouble(message.to_string())
    }
}

/// `lbv image keygen --out PREFIX`
fn keygen(args: &KeygenArgs) -> Result<u8, Trouble> {
    let (secret_path, public_path) = (with_suffix(&args.out, ".key"), with_suffix(&args.out, ".pub"));
    for path in [&secret_path, &public_path] {
        if path.exists() {
            return Err(format!(
                "{} exists: a key is never overwritten (choose another --out)",
                path.display()
            )
            .into());
        }
    }
    let seed = update_image::keygen().map_err(|error| format!("no random numbers from the system: {error}"))?;
    let public = public_key(&seed);
    write_new(&secret_path, &hex(&seed), true)?;
    if let Err(trouble) = write_new(&public_path, &hex(&public), false) {
        // Not half a pair: the secret without its public key would only be in the way of the next try.
        let _ = std::fs::remove_file(&secret_path);
        return Err(trouble);
    }
    say!(
        "wrote {} (the secret: keep it off the vehicle and out of version control) and {} (the public key, {})",
        secret_path.display(),
        public_path.display(),
        hex(&public)
    );
    Ok(exit::OK)
}

/// `path` with `suffix` after its name ("keys/mine" and ".key": "keys/mine.key"), whatever dots the name has.
fn with_suffix(path: &Path, suffix: &str) -> PathBuf {
    let mut name = OsString::from(path.as_os_str());
    name.push(suffix);
    PathBuf::from(name)
}

/// Write a key file that does not exist yet, one line; a secret readable by its owner only.
fn write_new(path: &Path, line: &str, secret: bool) -> Result<(), Trouble> {
    let mut options = OpenOptions::new();
    options.write(true).create_new(true);
    #[cfg(unix)]
    if secret {
        std::os::unix::fs::OpenOptionsExt::mode(&mut options, 0o600);
    }
    #[cfg(not(unix))]
    let _ = secret;
    let mut file = options
        .open(path)
        .map_err(|error| format!("cannot create {}: {error}", path.display()))?;
    writeln!(file, "{line}").map_err(|error| format!("cannot write {}: {error}", path.display()))?;
    Ok(())
}

/// Lower-case hex.
fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|byte| format!("{byte:02x}")).collect()
}

/// A public key in hex, and "(the development key)" after it when it is that one.
fn key_words(key: &[u8; KEY_LEN]) -> String {
    if *key == DEV_PUBLIC_KEY {
        format!("{} (the development key)", hex(key))
    } else {
        hex(key)
    }
}

/// The update key a payload embeds after its image info, at [`KEY_OFFSET`]; `None` when it ends before. Only an
/// image info of format 2 is followed by one.
fn embedded_key(payload: &[u8]) -> Option<[u8; KEY_LEN]> {
    payload
        .get(KEY_OFFSET..)
        .and_then(|rest| rest.first_chunk::<KEY_LEN>())
        .copied()
}

/// `lbv image sign ELF --key FILE.key --out FILE.lbvu`
fn sign(args: &SignArgs) -> Result<u8, Trouble> {
    if has_extension(&args.key, "pub") {
        return Err(format!(
            "{} is a public key: sign takes the secret one (.key)",
            args.key.display()
        )
        .into());
    }
    let seed = read_key(&args.key)?;
    let public = public_key(&seed);
    if public == DEV_PUBLIC_KEY && !args.allow_dev_key {
        return Err(format!(
            "{} is the development key, whose secret is published with the source: anyone can sign images a \
             vehicle holding it runs. Sign with your own key (lbv image keygen), or pass --allow-dev-key for a \
             bench image",
            args.key.display()
        )
        .into());
    }
    let elf = read_input(&args.elf)?;
    let elf_name = args.elf.display();
    let mut payload = payload_from_elf(&elf, args.base).map_err(|error| format!("{elf_name}: {error}"))?;
    let built = payload.info().map_err(|error| format!("{elf_name}: {error}"))?;
    // The key it embeds is the one the vehicle checks every later file with: an image without one would strand it.
    if built.format < INFO_FORMAT {
        return Err(format!(
            "{elf_name}: {} (build it again from the current sources)",
            Refusal::NoKey
        )
        .into());
    }
    let embedded = payload.key().ok_or_else(|| {
        format!(
            "{elf_name}: the image ends at {:#x}, before the update key after its image info ({KEY_OFFSET:#x}..{:#x})",
            payload.bytes.len(),
            KEY_OFFSET + KEY_LEN
        )
    })?;
    let rotates = embedded != public;
    if rotates && !args.rotate_key {
        return Err(format!(
            "{elf_name} embeds the update key {}, not the public half of {} ({}): once installed, the vehicle \
             would take only files signed with the key it embeds. Build the image with LBV_UPDATE_KEY naming \
             the signing key's .pub, or pass --rotate-key to move the vehicle to the embedded key",
            key_words(&embedded),
            args.key.display(),
            hex(&public)
        )
        .into());
    }
    if rotates && embedded == DEV_PUBLIC_KEY && !args.allow_dev_key {
        return Err(format!(
            "{elf_name} embeds the development key: --rotate-key would move the vehicle to a key whose secret is \
             published with the source, so that anyone could sign the images it runs next. Build the image with \
             your own key (LBV_UPDATE_KEY), or pass --allow-dev-key as well for a bench vehicle"
        )
        .into());
    }
    // The info is in the signed payload: what is set here is signed with the rest.
    let info = built
        .with_security_counter(args.security_counter.unwrap_or(built.security_counter))
        .with_rollback(args.allow_rollback || built.rollback);
    payload.set_info(&info);
    let file = update_image::sign(&payload.bytes, &seed).map_err(|error| format!("{elf_name}: {error}"))?;
    // What the devices will do with it, before it leaves: the same checks, salty's verification.
    let (header, _) =
        check_file(&file, info.target, u32::MAX).map_err(|refusal| format!("made a bad file: {refusal}"))?;
    let signed_payload = file.get(HEADER_LEN..).unwrap_or_default();
    update_image::verify(&header, signed_payload, &public)
        .map_err(|error| format!("made a file that does not verify: {error}"))?;
    // A vehicle running this image checks the next file with the embedded key: one no signature verifies with
    // would leave it unable to take any.
    if update_image::verify(&header, signed_payload, &embedded) == Err(VerifyError::PublicKey) {
        return Err(format!(
            "{elf_name} embeds {} as its update key, which is not an ed25519 public key: no file would verify \
             with it, so a vehicle that installed this image could take no update after it",
            hex(&embedded)
        )
        .into());
    }
    std::fs::write(&args.out, &file).map_err(|error| format!("cannot write {}: {error}", args.out.display()))?;
    say!(
        "wrote {}: {}, version {}, a payload of {} bytes from {:#010x}, signed with {}{}",
        args.out.display(),
        info.target,
        info.version,
        header.payload_len,
        payload.base,
        args.key.display(),
        if public == DEV_PUBLIC_KEY {
            " (the development key)"
        } else {
            ""
        }
    );
    if info.security_counter > 0 {
        say!(
            "  security counter {}: once it confirms, the vehicle takes no image with a lower one",
            info.security_counter
        );
    }
    if info.rollback {
        say!("  signed as a rollback: the vehicle takes it over a newer version");
    }
    if rotates {
        say!(
            "  key rotation: once this image confirms, the vehicle takes only files signed with the key it embeds, \
             {}, and no longer files signed with {}",
            key_words(&embedded),
            args.key.display()
        );
    }
    Ok(exit::OK)
}

/// Whether `path`'s extension is `extension`.
fn has_extension(path: &Path, extension: &str) -> bool {
    path.extension().is_some_and(|found| found == extension)
}

/// A key file's 32 bytes.
fn read_key(path: &Path) -> Result<[u8; 32], Trouble> {
    let bytes = read_capped(path, MAX_KEY_FILE)?;
    std::str::from_utf8(&bytes).ok().and_then(key_from_hex).ok_or_else(|| {
        format!(
            "{} is not a key file: one line of 64 hex digits (lbv image keygen makes them)",
            path.display()
        )
        .into()
    })
}

/// The whole of a file of at most `cap` bytes; a larger one is refused after reading `cap + 1` bytes of it.
pub fn read_capped(path: &Path, cap: u64) -> Result<Vec<u8>, String> {
    let file = File::open(path).map_err(|error| format!("cannot open {}: {error}", path.display()))?;
    let mut bytes = Vec::new();
    file.take(cap.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(|error| format!("cannot read {}: {error}", path.display()))?;
    if bytes.len() as u64 > cap {
        return Err(format!("{} is larger than {}: not read", path.display(), size(cap)));
    }
    Ok(bytes)
}

/// "512 KiB", "64 MiB".
fn size(bytes: u64) -> String {
    if bytes >= 1024 * 1024 {
        format!("{} MiB", bytes / (1024 * 1024))
    } else {
        format!("{} KiB", bytes / 1024)
    }
}

/// An image as it sits in flash, from `base`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Payload {
    /// Its address in flash: the ACTIVE partition's start.
    pub base: u32,
    /// Its bytes, gaps filled and the end padded with 0xFF to a whole number of write units.
    pub bytes: Vec<u8>,
}

impl Payload {
    /// The image info at `base + INFO_OFFSET`.
    pub fn info(&self) -> Result<ImageInfo, ElfError> {
        let at = u64::from(self.base) + INFO_OFFSET as u64;
        ImageInfo::parse(self.bytes.get(INFO_OFFSET..).unwrap_or_default())
            .map_err(|error| ElfError::NoInfo { at, error })
    }

    /// The update key the image embeds after its info; `None` when the payload ends before it.
    pub fn key(&self) -> Option<[u8; KEY_LEN]> {
        embedded_key(&self.bytes)
    }

    /// Writes `info` (in format 2) over the image info at `base + INFO_OFFSET`; nothing when the payload ends before.
    pub fn set_info(&mut self, info: &ImageInfo) {
        if let Some(slot) = self
            .bytes
            .get_mut(INFO_OFFSET..)
            .and_then(|rest| rest.first_chunk_mut::<INFO_LEN>())
        {
            *slot = info.to_bytes();
        }
    }
}

/// Why an ELF gives no payload.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ElfError {
    /// Not an ELF the object crate reads.
    NotElf(String),
    /// An ELF, but not a 32-bit little-endian ARM one.
    NotArm,
    /// No loadable segment with bytes in the file.
    NoSegments,
    /// A segment starts below the base.
    BelowBase {
        /// The segment's load address.
        segment: u64,
        /// The base asked for.
        base: u32,
    },
    /// Two segments load at the same addresses.
    Overlap {
        /// Where the second starts.
        at: u64,
    },
    /// The segments span more than the chip's flash.
    TooLarge {
        /// From where.
        base: u64,
        /// To where (exclusive).
        end: u64,
    },
    /// No image info where it belongs.
    NoInfo {
        /// Where it should be.
        at: u64,
        /// What is there instead.
        error: InfoError,
    },
}

impl fmt::Display for ElfError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ElfError::NotElf(error) => write!(f, "not an ELF file ({error})"),
            ElfError::NotArm => f.write_str("not a 32-bit little-endian ARM ELF: not a firmware image for the STM32G4"),
            ElfError::NoSegments => f.write_str("no loadable segment: nothing would go into flash"),
            ElfError::BelowBase { segment, base } => {
                write!(f, "a segment loads at {segment:#010x}, below the base {base:#010x}")
            }
            ElfError::Overlap { at } => write!(f, "segments overlap at {at:#010x}"),
            ElfError::TooLarge { base, end } => write!(
                f,
                "its segments span {base:#010x}..{end:#010x}, more than the {} of the chip's flash (a segment \
                 loaded in RAM?)",
                size(MAX_PAYLOAD)
            ),
            ElfError::NoInfo { at, error } => {
                write!(
                    f,
                    "no image info at {at:#010X}: is this image built for field update? ({error})"
                )
            }
        }
    }
}

impl std::error::Error for ElfError {}

/// The payload an ELF puts in flash: its loadable segments' file bytes at their physical (load) addresses, from
/// `base` (by default the lowest of them, the ACTIVE partition's start in an image linked for it), gaps filled
/// with 0xFF, padded to a whole number of write units. Segments with no bytes in the file (.bss) are not in it;
/// `.data` is, at its load address in flash.
pub fn payload_from_elf(elf: &[u8], base: Option<u32>) -> Result<Payload, ElfError> {
    if !elf.starts_with(b"\x7fELF") {
        return Err(ElfError::NotElf("no ELF magic".into()));
    }
    if elf.get(4) != Some(&ELFCLASS32.0) {
        return Err(ElfError::NotArm);
    }
    let header = FileHeader32::<Endianness>::parse(elf).map_err(|error| ElfError::NotElf(error.to_string()))?;
    let endian = header.endian().map_err(|error| ElfError::NotElf(error.to_string()))?;
    if endian != Endianness::Little || header.e_machine(endian) != EM_ARM {
        return Err(ElfError::NotArm);
    }
    let program_headers = header
        .program_headers(endian, elf)
        .map_err(|error| ElfError::NotElf(error.to_string()))?;
    let mut segments = Vec::new();
    for segment in program_headers {
        if segment.p_type(endian) != PT_LOAD || segment.p_filesz(endian) == 0 {
            continue;
        }
        let bytes = segment
            .data(endian, elf)
            .map_err(|()| ElfError::NotElf("a segment's bytes lie outside the file".into()))?;
        segments.push((u64::from(segment.p_paddr(endian)), bytes));
    }
    segments.sort_by_key(|(address, _)| *address);
    let Some(lowest) = segments.first().map(|(address, _)| *address) else {
        return Err(ElfError::NoSegments);
    };
    let base = match base {
        Some(base) if lowest < u64::from(base) => {
            return Err(ElfError::BelowBase { segment: lowest, base });
        }
        Some(base) => u64::from(base),
        None => lowest,
    };
    let end = segments
        .iter()
        .map(|(address, bytes)| address + bytes.len() as u64)
        .max()
        .unwrap_or(base);
    if end - base > MAX_PAYLOAD {
        return Err(ElfError::TooLarge { base, end });
    }
    let padded = (end - base).div_ceil(WRITE_UNIT as u64) * WRITE_UNIT as u64;
    let mut payload = vec![PAD_BYTE; padded as usize];
    let mut filled_to = base;
    for (address, bytes) in segments {
        if address < filled_to {
            return Err(ElfError::Overlap { at: address });
        }
        let start = (address - base) as usize;
        if let Some(slot) = payload.get_mut(start..start + bytes.len()) {
            slot.copy_from_slice(bytes);
        }
        filled_to = address + bytes.len() as u64;
    }
    Ok(Payload {
        base: base as u32,
        bytes: payload,
    })
}

/// `lbv image inspect FILE [--key FILE.pub]`
fn inspect(args: &InspectArgs) -> Result<u8, Trouble> {
    if let Some(key) = &args.key
        && has_extension(key, "key")
    {
        return Err(format!("{} is a secret key: inspect takes the public one (.pub)", key.display()).into());
    }
    let key = match &args.key {
        Some(path) => Some((read_key(path)?, path)),
        None => None,
    };
    let bytes = read_input(&args.file)?;
    let name = args.file.display();
    if bytes.starts_with(b"\x7fELF") {
        return Ok(inspect_elf(&bytes, &args.file));
    }
    let header = match Header::parse(&bytes) {
        Ok(header) => header,
        Err(error) => {
            say!("{name}: {error}");
            return Ok(exit::FAILED);
        }
    };
    let payload = bytes.get(HEADER_LEN..).unwrap_or_default();
    say!("{name}: update file, format {}", update_image::FORMAT);
    say!("  target     {}", header.target);
    say!("  version    {}", header.version);
    // The payload's own info, signed where the header is not; one that does not read is refused below.
    if let Ok(info) = ImageInfo::parse(payload.get(INFO_OFFSET..).unwrap_or_default()) {
        say_info(&info);
    }
    let mut hash = Verifier::new();
    hash.update(payload);
    let digest = hash.digest();
    say!(
        "  payload    {} bytes, SHA-512 {}...",
        header.payload_len,
        hex(digest.get(..16).unwrap_or_default())
    );
    // The device's own checks, less the ones that need a device: it takes the header's target and any length.
    if let Err(refusal) = check_file(&bytes, header.target, u32::MAX) {
        say!("  refused    {refusal}");
        return Ok(exit::FAILED);
    }
    let dev = update_image::verify(&header, payload, &DEV_PUBLIC_KEY).is_ok();
    // The key it verifies with, if any.
    let signer = match key {
        Some((public, path)) => {
            let answer = update_image::verify(&header, payload, &public);
            match &answer {
                Ok(()) => say!("  signature  verifies with {}", path.display()),
                Err(error) => say!("  signature  DOES NOT VERIFY with {}: {error}", path.display()),
            }
            answer.is_ok().then_some(public)
        }
        None if dev => {
            say!("  signature  verifies with the development key");
            Some(DEV_PUBLIC_KEY)
        }
        None => {
            say!("  signature  not the development key's; give --key FILE.pub to check it with yours");
            None
        }
    };
    // check_file took it, so its info is format 2 and the payload holds the key after it.
    if let Some(embedded) = embedded_key(payload) {
        say!("  key        {}", key_words(&embedded));
        match signer {
            Some(signer) if signer == embedded => {
                say!("             the key that signed it: the vehicle goes on taking files signed with it");
            }
            Some(_) => say!(
                "             a rotation to another key than the one that signed it: once this image confirms, the \
                 vehicle takes only files signed with this one"
            ),
            None => {}
        }
    }
    if dev {
        say!("  dev key    signed with the development key: anyone can sign for a vehicle that takes it");
    } else if args.key.is_some() {
        say!("  dev key    not signed with the development key");
    }
    Ok(if signer.is_some() { exit::OK } else { exit::FAILED })
}

/// The image info's lines beyond target and version, for an update file and an ELF alike.
fn say_info(info: &ImageInfo) {
    say!("  info       format {}", info.format);
    say!("  counter    {}", info.security_counter);
    if info.rollback {
        say!("  rollback   yes: signed to replace a newer version");
    } else {
        say!("  rollback   no");
    }
}

/// An update file or an ELF, each read to its own cap (its first 4 bytes say which), so that no file makes it
/// read more than [`MAX_ELF`], nor more than [`MAX_UPDATE_FILE`] unless it opens as an ELF.
fn read_input(path: &Path) -> Result<Vec<u8>, Trouble> {
    let file = File::open(path).map_err(|error| format!("cannot open {}: {error}", path.display()))?;
    let mut bytes = Vec::new();
    let mut file = io::BufReader::new(file);
    (&mut file)
        .take(4)
        .read_to_end(&mut bytes)
        .map_err(|error| format!("cannot read {}: {error}", path.display()))?;
    let cap = if bytes.starts_with(b"\x7fELF") {
        MAX_ELF
    } else {
        MAX_UPDATE_FILE
    };
    file.take(cap.saturating_add(1).saturating_sub(bytes.len() as u64))
        .read_to_end(&mut bytes)
        .map_err(|error| format!("cannot read {}: {error}", path.display()))?;
    if bytes.len() as u64 > cap {
        return Err(format!(
            "{} is larger than {} ({} for an ELF): not read",
            path.display(),
            size(MAX_UPDATE_FILE),
            size(MAX_ELF)
        )
        .into());
    }
    Ok(bytes)
}

/// `lbv image inspect FILE.elf`: the image info and the payload it would sign.
fn inspect_elf(elf: &[u8], path: &Path) -> u8 {
    let name = path.display();
    let payload = match payload_from_elf(elf, None) {
        Ok(payload) => payload,
        Err(error) => {
            say!("{name}: {error}");
            return exit::FAILED;
        }
    };
    let info = match payload.info() {
        Ok(info) => info,
        Err(error) => {
            say!("{name}: {error}");
            return exit::FAILED;
        }
    };
    let mut hash = Verifier::new();
    hash.update(&payload.bytes);
    say!("{name}: firmware ELF (not signed; lbv image sign makes its update file)");
    say!("  target     {}", info.target);
    say!("  version    {}", info.version);
    say_info(&info);
    say!(
        "  payload    {} bytes from {:#010x}, SHA-512 {}...",
        payload.bytes.len(),
        payload.base,
        hex(hash.digest().get(..16).unwrap_or_default())
    );
    if info.format < INFO_FORMAT {
        say!("  key        none: {} (sign refuses it)", Refusal::NoKey);
        return exit::FAILED;
    }
    let Some(key) = payload.key() else {
        say!(
            "  key        none: the image ends at {:#x}, before the key after its image info ({KEY_OFFSET:#x}..{:#x})",
            payload.bytes.len(),
            KEY_OFFSET + KEY_LEN
        );
        return exit::FAILED;
    };
    say!("  key        {}", key_words(&key));
    say!("             once this image runs, the vehicle takes only files signed with this key");
    exit::OK
}
