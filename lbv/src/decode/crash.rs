//! `lbv decode crash`: a board's post-mortem record (crash-record's format, the 128 bytes an image leaves at the
//! bottom of RAM after a panic, a fault or the watchdog's reset) printed for a person, one item a line.
//!
//! The record alone gives what stopped the board, its target and version, its uptime, why the chip reset, the
//! exception, the stacked registers, the fault status registers with their bits named and the last events. The ELF
//! the image was built from (`--elf`) adds the function and source line of PC and LR (its DWARF line tables, else
//! its symbol table) and a panic's source path, which the record keeps as an address in the image's flash.
//!
//! ```text
//! kind       HardFault
//! target     master
//! version    0.1.0
//! uptime     61.250 s
//! told       no
//! reset      RCC_CSR 0x14000000: SFTRSTF (software), PINRSTF (pin)
//! exception  3 HardFault
//! PC         0x0800d9f0  lbv_master_fw::update::UpdateServer::request at lbv-master-fw/src/update.rs:604
//!                        inlined into lbv_master_fw::update::Updates<S>::serve at lbv-master-fw/src/update.rs:1366
//! LR         0x08010e6d  lbv_master_fw::console::Output<W>::send at lbv-master-fw/src/console.rs:852
//! SP         0x2001ff00
//! xPSR       0x61000000
//! CFSR       0x00008200  PRECISERR, BFARVALID
//! HFSR       0x40000000  FORCED
//! BFAR       0x20030000
//! events     2, oldest first
//!   +000.000 s  started (reset flags 0x0c, RCC_CSR's top byte)
//!   +060.125 s  T4 lost
//! ```
//!
//! Memory stays flat: the record file is read up to [`MAX_RECORD_FILE`] bytes (a larger one is no record and is
//! not read further), the ELF up to [`image::MAX_ELF`]. Nothing in either file makes it panic: a file that is not
//! a record is refused with crash-record's reason, an ELF that does not read with object's, and DWARF that does
//! not read leaves the addresses without source lines.

use std::fmt::{self, Write as _};
use std::fs::File;
use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use addr2line::gimli;
use crash_record::{FaultStatus, Frame, Kind, Record};
use object::{Object, ObjectSection, ObjectSegment, ObjectSymbol, SectionFlags, SymbolKind};
use update_image::{ImageInfo, Target, Version};

use crate::{exit, image};

/// The largest record file read. A record is [`crash_record::LEN`] bytes: a file up to the cap is read whole and
/// refused with crash-record's reason when it is not one, a larger one once the cap is passed.
pub const MAX_RECORD_FILE: u64 = 4096;
/// Frames of one address printed at most: the function and the calls it was inlined into.
const MAX_FRAMES: usize = 16;

const HELP: &str = "\
Reads a board's post-mortem record: the 128 bytes an image keeps at the bottom of RAM (the
crash-record format) after a panic, a HardFault, an NMI, a stray interrupt or the watchdog's reset.
Prints one item a line: kind, target, version, uptime, whether the board has told it, why the chip
reset (RCC_CSR and its flags), the exception, PC, LR, SP, xPSR, CFSR and HFSR with their bits named
(MMFAR and BFAR when valid), a panic's line, and the last events, oldest first.

With --elf, the ELF the image was built from names the function and source line of PC and of LR's
call site (DWARF line tables, else the symbol table) and gives a panic's source path.

Exit status: 0 the record was read; 1 the file is not a record (a message says why; only its first
4 KiB are read); 2 bad command line, a file that cannot be read, an ELF that does not read.";

/// `lbv decode crash`'s command line.
#[derive(Debug, Default, clap::Args)]
#[command(after_help = HELP)]
pub struct Args {
    /// The record's bytes, as read from the board; standard input when - or absent
    #[arg(value_name = "FILE")]
    pub input: Option<PathBuf>,
    /// The ELF the board's image was built from: names PC's and LR's functions and lines, reads a panic's path
    #[arg(long, value_name = "IMAGE")]
    pub elf: Option<PathBuf>,
}

/// `lbv decode crash [FILE|-] [--elf IMAGE]`
pub fn main(args: &Args) -> ExitCode {
    const NAME: &str = "lbv decode crash";
    let (bytes, name) = match read_record_file(args.input.as_deref()) {
        Ok(read) => read,
        Err(message) => {
            eprintln!("{NAME}: {message}");
            return ExitCode::from(exit::TROUBLE);
        }
    };
    let elf_bytes = match &args.elf {
        Some(path) => match image::read_capped(path, image::MAX_ELF) {
            Ok(bytes) => Some((bytes, path)),
            Err(message) => {
                eprintln!("{NAME}: {message}");
                return ExitCode::from(exit::TROUBLE);
            }
        },
        None => None,
    };
    let elf = match &elf_bytes {
        Some((bytes, path)) => match Elf::parse(bytes) {
            Ok(elf) => Some(elf),
            Err(error) => {
                eprintln!("{NAME}: {}: {error}", path.display());
                return ExitCode::from(exit::TROUBLE);
            }
        },
        None => None,
    };
    if bytes.len() as u64 > MAX_RECORD_FILE {
        eprintln!(
            "{NAME}: {name}: larger than {MAX_RECORD_FILE} bytes, not a record's {}: not read further",
            crash_record::LEN
        );
        return ExitCode::from(exit::FAILED);
    }
    let record = match Record::decode(&bytes) {
        Ok(record) => record,
        Err(error) => {
            eprintln!("{NAME}: {name}: {error}");
            return ExitCode::from(exit::FAILED);
        }
    };
    let text = describe(&record, elf.as_ref());
    let mut out = io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Ok(()) => ExitCode::from(exit::OK),
        // A reader that went away (`| head`) is not an error.
        Err(error) if error.kind() == io::ErrorKind::BrokenPipe => ExitCode::from(exit::OK),
        Err(error) => {
            eprintln!("{NAME}: cannot write the output: {error}");
            ExitCode::from(exit::TROUBLE)
        }
    }
}

/// The record file's bytes (standard input for none or `-`), at most one more than [`MAX_RECORD_FILE`], and its
/// name for messages. Read without a buffer in front, so that no more than that is taken from the file or pipe.
fn read_record_file(input: Option<&Path>) -> Result<(Vec<u8>, String), String> {
    let (reader, name): (Box<dyn Read>, String) = match input {
        Some(path) if path != Path::new("-") => match File::open(path) {
            Ok(file) => (Box::new(file), path.display().to_string()),
            Err(error) => return Err(format!("cannot open {}: {error}", path.display())),
        },
        _ => (Box::new(io::stdin()), "standard input".into()),
    };
    let mut bytes = Vec::new();
    reader
        .take(MAX_RECORD_FILE + 1)
        .read_to_end(&mut bytes)
        .map_err(|error| format!("cannot read {name}: {error}"))?;
    Ok((bytes, name))
}

/// Why an ELF cannot be used.
#[derive(Debug)]
pub struct ElfError(String);

impl fmt::Display for ElfError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "not an ELF file that reads ({})", self.0)
    }
}

impl std::error::Error for ElfError {}

/// The DWARF reader: the ELF's sections where they lie in its bytes.
type Reader<'data> = gimli::EndianSlice<'data, gimli::RunTimeEndian>;

/// The ELF an image was built from, parsed once: its sections and symbols, and its DWARF when it has some that
/// reads.
pub struct Elf<'data> {
    file: object::File<'data>,
    /// `None` when it has no line tables, or they do not read.
    lines: Option<addr2line::Context<Reader<'data>>>,
    /// A 32-bit ARM ELF: its function symbols carry the Thumb bit.
    thumb: bool,
    /// Its image info, for a firmware image that has one.
    info: Option<ImageInfo>,
}

impl fmt::Debug for Elf<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Elf")
            .field("architecture", &self.file.architecture())
            .field("lines", &self.lines.is_some())
            .field("info", &self.info)
            .finish_non_exhaustive()
    }
}

/// Where an address is: one function of its inlining chain, innermost first.
#[derive(Debug, Clone, PartialEq, Eq)]
struct Place {
    function: Option<String>,
    file: Option<String>,
    line: Option<u32>,
}

impl fmt::Display for Place {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.function.as_deref().unwrap_or("??"))?;
        match (&self.file, self.line) {
            (Some(file), Some(line)) => write!(f, " at {file}:{line}"),
            (Some(file), None) => write!(f, " at {file}"),
            _ => Ok(()),
        }
    }
}

impl<'data> Elf<'data> {
    /// The ELF in `bytes`: refused when it is not one object reads. DWARF that does not read is not refused: the
    /// addresses are then named from the symbol table alone.
    pub fn parse(bytes: &'data [u8]) -> Result<Self, ElfError> {
        if !bytes.starts_with(b"\x7fELF") {
            return Err(ElfError("no ELF magic".into()));
        }
        let file = object::File::parse(bytes).map_err(|error| ElfError(error.to_string()))?;
        let endian = if file.is_little_endian() {
            gimli::RunTimeEndian::Little
        } else {
            gimli::RunTimeEndian::Big
        };
        // A section that is missing, does not read, or is compressed (not read here) is empty: its lookups find
        // nothing.
        let section = |id: gimli::SectionId| -> Result<Reader<'data>, gimli::Error> {
            let data = file
                .section_by_name(id.name())
                .filter(|section| {
                    section
                        .compressed_data()
                        .is_ok_and(|data| data.format == object::CompressionFormat::None)
                })
                .and_then(|section| section.data().ok())
                .unwrap_or_default();
            Ok(gimli::EndianSlice::new(data, endian))
        };
        let lines = gimli::Dwarf::load(section)
            .and_then(addr2line::Context::from_dwarf)
            .ok();
        let thumb = file.architecture() == object::Architecture::Arm;
        // Only a firmware image has one; for any other ELF it is simply absent.
        let info = image::payload_from_elf(bytes, None)
            .ok()
            .and_then(|payload| payload.info().ok());
        Ok(Self {
            file,
            lines,
            thumb,
            info,
        })
    }

    /// Where `address` is: the DWARF frames (the function, then each function it was inlined into, with the line
    /// of each), else the symbol that holds it. Empty when neither knows it.
    fn places(&self, address: u64) -> Vec<Place> {
        let mut places = Vec::new();
        if let Some(lines) = &self.lines
            && let Ok(mut frames) = lines.find_frames(address).skip_all_loads()
        {
            while places.len() < MAX_FRAMES {
                let Ok(Some(frame)) = frames.next() else { break };
                let function = frame
                    .function
                    .and_then(|name| name.demangle().ok().map(std::borrow::Cow::into_owned));
                let (file, line) = frame.location.map_or((None, None), |location| {
                    (location.file.map(str::to_owned), location.line)
                });
                places.push(Place { function, file, line });
            }
        }
        match places.first_mut() {
            Some(first) if first.function.is_none() => first.function = self.symbol(address),
            Some(_) => {}
            None => {
                if let Some(function) = self.symbol(address) {
                    places.push(Place {
                        function: Some(function),
                        file: None,
                        line: None,
                    });
                }
            }
        }
        places
    }

    /// The demangled name of the function symbol whose bytes hold `address`.
    fn symbol(&self, address: u64) -> Option<String> {
        let holds = |symbol: &object::Symbol<'data, '_>| {
            let start = if self.thumb {
                symbol.address() & !1
            } else {
                symbol.address()
            };
            symbol.kind() == SymbolKind::Text
                && symbol.size() > 0
                && start <= address
                && address - start < symbol.size()
        };
        let symbol = self
            .file
            .symbols()
            .find(|symbol| holds(symbol))
            .or_else(|| self.file.dynamic_symbols().find(|symbol| holds(symbol)))?;
        let name = symbol.name().ok()?;
        Some(addr2line::demangle_auto(name.into(), None).into_owned())
    }

    /// The `len` bytes at `address` in the image: in a section that is loaded, else in a loadable segment.
    fn bytes_at(&self, address: u64, len: u64) -> Option<&'data [u8]> {
        let loaded = |section: &object::Section<'data, '_>| match section.flags() {
            SectionFlags::Elf { sh_flags, .. } => sh_flags.contains(object::elf::SHF_ALLOC),
            _ => false,
        };
        self.file
            .sections()
            .filter(|section| loaded(section))
            .find_map(|section| section.data_range(address, len).ok().flatten())
            .or_else(|| {
                self.file
                    .segments()
                    .find_map(|segment| segment.data_range(address, len).ok().flatten())
            })
    }
}

/// The record's target byte (the update file's) in words.
fn target_name(target: u8) -> String {
    match Target::from_byte(target) {
        Some(Target::Master) => "master".into(),
        Some(Target::ThrusterSeabotix) => "SeaBotix thruster".into(),
        Some(Target::ThrusterLegacy) => "Legacy thruster".into(),
        None => format!("{target} (not a known target)"),
    }
}

/// The update-image target of the record's target byte, to compare with an ELF's image info.
fn update_target(target: u8) -> Option<Target> {
    Target::from_byte(target)
}

/// RCC_CSR's reset flags: bit, name, what reset the chip (RM0440 7.4.30 RCC_CSR).
const RESET_FLAGS: [(u32, &str, &str); 7] = [
    (31, "LPWRRSTF", "low-power"),
    (30, "WWDGRSTF", "window watchdog"),
    (29, "IWDGRSTF", "independent watchdog"),
    (28, "SFTRSTF", "software"),
    (27, "BORRSTF", "brown-out/power-on"),
    (26, "PINRSTF", "pin"),
    (25, "OBLRSTF", "option-byte load"),
];

/// CFSR's bits: MMFSR, BFSR, UFSR (ARMv7-M Architecture Reference Manual B3.2.15).
const CFSR_BITS: [(u32, &str); 19] = [
    (0, "IACCVIOL"),
    (1, "DACCVIOL"),
    (3, "MUNSTKERR"),
    (4, "MSTKERR"),
    (5, "MLSPERR"),
    (7, "MMARVALID"),
    (8, "IBUSERR"),
    (9, "PRECISERR"),
    (10, "IMPRECISERR"),
    (11, "UNSTKERR"),
    (12, "STKERR"),
    (13, "LSPERR"),
    (15, "BFARVALID"),
    (16, "UNDEFINSTR"),
    (17, "INVSTATE"),
    (18, "INVPC"),
    (19, "NOCP"),
    (24, "UNALIGNED"),
    (25, "DIVBYZERO"),
];
const MMARVALID: u32 = 1 << 7;
const BFARVALID: u32 = 1 << 15;

/// HFSR's bits (ARMv7-M Architecture Reference Manual B3.2.16).
const HFSR_BITS: [(u32, &str); 3] = [(1, "VECTTBL"), (30, "FORCED"), (31, "DEBUGEVT")];

/// The names of `value`'s set bits, in bit order; a set bit the table does not name is "bit N".
fn bit_names(value: u32, names: &[(u32, &str)]) -> String {
    let mut text = String::new();
    for bit in (0..32).filter(|bit| value & (1 << bit) != 0) {
        if !text.is_empty() {
            text.push_str(", ");
        }
        match names.iter().find(|(named, _)| *named == bit) {
            Some((_, name)) => text.push_str(name),
            None => {
                let _ = write!(text, "bit {bit}");
            }
        }
    }
    text
}

/// A register's value, and the names of its set bits after two spaces when there are any.
fn register(value: u32, names: &[(u32, &str)]) -> String {
    let bits = bit_names(value, names);
    if bits.is_empty() {
        format!("{value:#010x}")
    } else {
        format!("{value:#010x}  {bits}")
    }
}

/// Why the chip reset, from the RCC_CSR the start after the stop read.
fn reset_cause(csr: u32) -> String {
    if csr == 0 {
        return format!("RCC_CSR {csr:#010x}: not read yet (the start after the stop fills it in)");
    }
    let flags: Vec<String> = RESET_FLAGS
        .iter()
        .filter(|(bit, _, _)| csr & (1 << bit) != 0)
        .map(|(_, name, what)| format!("{name} ({what})"))
        .collect();
    if flags.is_empty() {
        format!("RCC_CSR {csr:#010x}: no reset flag set")
    } else {
        format!("RCC_CSR {csr:#010x}: {}", flags.join(", "))
    }
}

/// The exception number (IPSR) in words.
fn exception_name(number: u16) -> String {
    match number {
        0 => "thread mode".into(),
        1 => "Reset".into(),
        2 => "NMI".into(),
        3 => "HardFault".into(),
        4 => "MemManage".into(),
        5 => "BusFault".into(),
        6 => "UsageFault".into(),
        11 => "SVCall".into(),
        12 => "DebugMonitor".into(),
        14 => "PendSV".into(),
        15 => "SysTick".into(),
        16.. => format!("interrupt {}", number - 16),
        _ => "reserved".into(),
    }
}

/// Milliseconds as seconds with three decimals: "61.250".
fn seconds(ms: u32) -> String {
    format!("{}.{:03}", ms / 1000, ms % 1000)
}

/// A path from the ELF, as it is when it is printable text, else quoted with its escapes.
fn shown_path(bytes: &[u8]) -> String {
    match std::str::from_utf8(bytes) {
        Ok(text) if !text.is_empty() && !text.chars().any(char::is_control) => text.to_owned(),
        _ => format!("{:?}", String::from_utf8_lossy(bytes)),
    }
}

/// An address's line: the value, then what it is (`note`), or where the ELF says it is.
fn code_address(text: &mut String, label: &str, value: u32, note: Option<&str>, lookup: Option<(u64, &Elf<'_>)>) {
    let _ = write!(text, "{label:<10} {value:#010x}");
    if let Some(note) = note {
        let _ = write!(text, "  {note}");
    } else if let Some((address, elf)) = lookup {
        let places = elf.places(address);
        match places.split_first() {
            Some((first, inlined)) => {
                let _ = write!(text, "  {first}");
                for place in inlined {
                    let _ = write!(text, "\n{:23}inlined into {place}", "");
                }
            }
            None => text.push_str("  (not in the ELF)"),
        }
    }
    text.push('\n');
}

/// The record in words, one item a line; with the ELF, PC's and LR's places and a panic's path.
pub fn describe(record: &Record, elf: Option<&Elf<'_>>) -> String {
    let mut text = String::new();
    let mut line = |label: &str, value: &dyn fmt::Display| {
        let _ = writeln!(text, "{label:<10} {value}");
    };
    let version = Version::from_bytes(record.version);
    line("kind", &record.kind.name());
    line("target", &target_name(record.target));
    line("version", &version);
    line("uptime", &format_args!("{} s", seconds(record.uptime_ms)));
    line("told", &if record.told { "yes" } else { "no" });
    line("reset", &reset_cause(record.reset_cause));
    if let Some(info) = elf.and_then(|elf| elf.info.as_ref())
        && (info.version != version || update_target(record.target) != Some(info.target))
    {
        line(
            "warning",
            &format_args!(
                "the ELF is {} {}, the record's {} {version}: its symbols may be another image's",
                info.target.name(),
                info.version,
                target_name(record.target)
            ),
        );
    }
    let registers =
        record.frame != Frame::default() || record.faults != FaultStatus::default() || record.exception != 0;
    if registers {
        describe_registers(&mut text, record, elf);
    } else if record.kind == Kind::Watchdog {
        let _ = writeln!(text, "{:<10} none: the watchdog's reset ran no handler", "registers");
    } else {
        let _ = writeln!(text, "{:<10} none", "registers");
    }
    if let Some(panic) = record.panic {
        let path = match elf {
            Some(elf) => match elf.bytes_at(u64::from(panic.file), u64::from(panic.file_len)) {
                Some(bytes) => shown_path(bytes),
                None => format!(
                    "<path at {:#010x}, {} bytes: not in the ELF>",
                    panic.file, panic.file_len
                ),
            },
            None => format!(
                "<path at {:#010x}, {} bytes: --elf reads it>",
                panic.file, panic.file_len
            ),
        };
        let _ = writeln!(text, "panicked at {path}:{}", panic.line);
    }
    let events = record.events();
    if events.is_empty() {
        let _ = writeln!(text, "{:<10} none", "events");
    } else {
        let _ = writeln!(text, "{:<10} {}, oldest first", "events", events.len());
    }
    for event in events {
        let (whole, ms) = (event.at_ms / 1000, event.at_ms % 1000);
        let _ = writeln!(text, "  +{whole:03}.{ms:03} s  {}", event.what);
    }
    text
}

/// The exception, the stacked registers (PC and LR placed in the ELF) and the fault status registers.
fn describe_registers(text: &mut String, record: &Record, elf: Option<&Elf<'_>>) {
    let Frame { pc, lr, xpsr, sp } = record.frame;
    let _ = writeln!(
        text,
        "{:<10} {} {}",
        "exception",
        record.exception,
        exception_name(record.exception)
    );
    // Thumb code addresses carry bit 0; the instruction is at the address without it. The stacked PC is the
    // instruction that faulted (or the next one to run), so it is looked up as it is.
    let pc_at = u64::from(pc & !1);
    code_address(text, "PC", pc, None, elf.filter(|_| pc_at != 0).map(|elf| (pc_at, elf)));
    // LR is a return address, the instruction after the call: 2 bytes back is inside the call (a 2-byte BLX or a
    // 4-byte BL), so its line is the call site's. EXC_RETURN values (0xFFFFFFxx) are no code address.
    let exc_return = (lr >= 0xFFFF_FF00).then_some("EXC_RETURN: no call site");
    let lr_at = u64::from(lr & !1).checked_sub(2);
    code_address(text, "LR", lr, exc_return, elf.zip(lr_at).map(|(elf, at)| (at, elf)));
    let _ = writeln!(text, "{:<10} {sp:#010x}", "SP");
    let _ = writeln!(text, "{:<10} {xpsr:#010x}", "xPSR");
    let FaultStatus {
        cfsr,
        hfsr,
        mmfar,
        bfar,
    } = record.faults;
    let _ = writeln!(text, "{:<10} {}", "CFSR", register(cfsr, &CFSR_BITS));
    let _ = writeln!(text, "{:<10} {}", "HFSR", register(hfsr, &HFSR_BITS));
    // The fault address registers hold the fault's address only when their valid bit says so.
    if cfsr & MMARVALID != 0 {
        let _ = writeln!(text, "{:<10} {mmfar:#010x}", "MMFAR");
    }
    if cfsr & BFARVALID != 0 {
        let _ = writeln!(text, "{:<10} {bfar:#010x}", "BFAR");
    }
}

#[cfg(test)]
mod tests {
    use std::sync::OnceLock;

    use crash_record::{Event, Image, PanicAt, Region, ResetCause, Stop, What};
    use proptest::prelude::*;

    use super::*;

    /// RCC_CSR after a power-on (BORRSTF, PINRSTF) and after a software reset (SFTRSTF, PINRSTF).
    const POWER_ON: ResetCause = ResetCause(1 << 27 | 1 << 26);
    const SOFTWARE: ResetCause = ResetCause(1 << 28 | 1 << 26);
    const MASTER: Image = Image {
        target: 3,
        version: [0, 3, 0x2C, 0x01],
    };

    fn stop(kind: Kind, frame: Frame, faults: FaultStatus, panic: Option<PanicAt>) -> Stop {
        Stop {
            kind,
            frame,
            faults,
            exception: if kind == Kind::HardFault { 3 } else { 0 },
            panic,
            uptime_ms: 61_250,
        }
    }

    /// The bytes a board leaves after `stop`: started after a power-on, armed, lost T4, stopped, then started
    /// again after the software reset that followed (which fills in the reset cause).
    fn record_bytes(stop: Stop) -> [u8; crash_record::LEN] {
        let mut region = Region::new();
        region.start(POWER_ON, MASTER);
        region.note(Event {
            at_ms: 1_000,
            what: What::Armed,
        });
        region.note(Event {
            at_ms: 60_125,
            what: What::ThrusterLost(3),
        });
        region.record(stop, MASTER);
        assert!(region.start(SOFTWARE, MASTER).is_some());
        region.record
    }

    fn record(stop: Stop) -> Record {
        Record::decode(&record_bytes(stop)).unwrap()
    }

    fn bus_fault() -> Stop {
        stop(
            Kind::HardFault,
            Frame {
                pc: 0x0800_4321,
                lr: 0x0800_1235,
                xpsr: 0x6100_0000,
                sp: 0x2001_FF00,
            },
            FaultStatus {
                cfsr: 1 << 9 | 1 << 15,
                hfsr: 1 << 30,
                mmfar: 0xDEAD_BEEF,
                bfar: 0x2003_0000,
            },
            None,
        )
    }

    #[test]
    fn a_record_prints_every_item_in_order() {
        assert_eq!(
            describe(&record(bus_fault()), None),
            "\
kind       HardFault
target     master
version    0.3.300
uptime     61.250 s
told       no
reset      RCC_CSR 0x14000000: SFTRSTF (software), PINRSTF (pin)
exception  3 HardFault
PC         0x08004321
LR         0x08001235
SP         0x2001ff00
xPSR       0x61000000
CFSR       0x00008200  PRECISERR, BFARVALID
HFSR       0x40000000  FORCED
BFAR       0x20030000
events     3, oldest first
  +000.000 s  started (reset flags 0x0c, RCC_CSR's top byte)
  +001.000 s  armed
  +060.125 s  T4 lost
"
        );
    }

    #[test]
    fn register_bits_and_exceptions_are_named() {
        let all_cfsr = CFSR_BITS.iter().fold(0, |cfsr, (bit, _)| cfsr | 1 << bit);
        assert_eq!(
            bit_names(all_cfsr, &CFSR_BITS),
            "IACCVIOL, DACCVIOL, MUNSTKERR, MSTKERR, MLSPERR, MMARVALID, IBUSERR, PRECISERR, IMPRECISERR, \
             UNSTKERR, STKERR, LSPERR, BFARVALID, UNDEFINSTR, INVSTATE, INVPC, NOCP, UNALIGNED, DIVBYZERO"
        );
        // Reserved bits are not taken for others.
        assert_eq!(bit_names(1 << 2 | 1 << 26, &CFSR_BITS), "bit 2, bit 26");
        assert_eq!(
            register(0xC000_0002, &HFSR_BITS),
            "0xc0000002  VECTTBL, FORCED, DEBUGEVT"
        );
        assert_eq!(register(0, &HFSR_BITS), "0x00000000");
        assert_eq!(
            reset_cause(0xFE00_0000),
            "RCC_CSR 0xfe000000: LPWRRSTF (low-power), WWDGRSTF (window watchdog), IWDGRSTF (independent \
             watchdog), SFTRSTF (software), BORRSTF (brown-out/power-on), PINRSTF (pin), OBLRSTF (option-byte load)"
        );
        assert_eq!(reset_cause(0x0000_0C03), "RCC_CSR 0x00000c03: no reset flag set");
        assert!(reset_cause(0).contains("not read yet"));
        let names: Vec<String> = [0, 2, 3, 4, 5, 6, 11, 14, 15, 16, 58, 7].map(exception_name).into();
        assert_eq!(
            names,
            [
                "thread mode",
                "NMI",
                "HardFault",
                "MemManage",
                "BusFault",
                "UsageFault",
                "SVCall",
                "PendSV",
                "SysTick",
                "interrupt 0",
                "interrupt 42",
                "reserved"
            ]
        );
        assert_eq!(
            [3, 1, 2, 0].map(target_name),
            [
                "master",
                "SeaBotix thruster",
                "Legacy thruster",
                "0 (not a known target)"
            ]
        );
    }

    #[test]
    fn the_fault_address_registers_show_only_when_valid() {
        let mut fault = bus_fault();
        fault.faults.cfsr = 1 << 1 | 1 << 7;
        let text = describe(&record(fault), None);
        assert!(
            text.contains("CFSR       0x00000082  DACCVIOL, MMARVALID\nHFSR"),
            "{text}"
        );
        assert!(text.contains("MMFAR      0xdeadbeef\n"), "{text}");
        assert!(!text.contains("BFAR"), "{text}");
        fault.faults.cfsr = 1 << 16;
        let text = describe(&record(fault), None);
        assert!(!text.contains("MMFAR") && !text.contains("BFAR"), "{text}");
    }

    #[test]
    fn a_watchdog_record_has_no_registers_and_an_exc_return_no_call_site() {
        let mut watchdog = stop(Kind::Watchdog, Frame::default(), FaultStatus::default(), None);
        watchdog.uptime_ms = 900;
        let text = describe(&record(watchdog), None);
        assert!(text.starts_with("kind       watchdog reset\n"), "{text}");
        assert!(
            text.contains("\nregisters  none: the watchdog's reset ran no handler\n"),
            "{text}"
        );
        assert!(!text.contains("PC") && !text.contains("CFSR"), "{text}");
        let mut told = record(bus_fault());
        told.told = true;
        told.frame.lr = 0xFFFF_FFF9;
        told.target = 2;
        let text = describe(&told, None);
        assert!(text.contains("\ntold       yes\n"), "{text}");
        assert!(text.contains("\ntarget     Legacy thruster\n"), "{text}");
        assert!(
            text.contains("\nLR         0xfffffff9  EXC_RETURN: no call site\n"),
            "{text}"
        );
        told.held = 0;
        assert!(describe(&told, None).ends_with("\nevents     none\n"));
    }

    #[test]
    fn a_panic_without_the_elf_gives_its_path_s_address() {
        let panic = PanicAt {
            file: 0x0801_2340,
            file_len: 27,
            line: 412,
        };
        let text = describe(
            &record(stop(Kind::Panic, Frame::default(), FaultStatus::default(), Some(panic))),
            None,
        );
        assert!(text.starts_with("kind       panic\n"), "{text}");
        assert!(text.contains("\nregisters  none\n"), "{text}");
        assert!(
            text.contains("\npanicked at <path at 0x08012340, 27 bytes: --elf reads it>:412\n"),
            "{text}"
        );
    }

    /// The test executable, read once.
    fn exe() -> &'static [u8] {
        static EXE: OnceLock<Vec<u8>> = OnceLock::new();
        EXE.get_or_init(|| std::fs::read(std::env::current_exe().unwrap()).unwrap())
    }

    /// The line `marker` starts after.
    const MARKER_LINE: u32 = line!();
    #[inline(never)]
    fn marker(x: u32) -> u32 {
        std::hint::black_box(x).rotate_left(7) ^ 0x5EED_CAFE
    }

    /// A panic's source path, as the panic machinery keeps one: its bytes in the image's read-only data.
    static PANIC_PATH: &str = "lbv/decode-crash-test/panic_site.rs";

    /// The address of `marker` in the test executable, from its symbol table.
    fn marker_address() -> u32 {
        assert_eq!(std::hint::black_box(marker as fn(u32) -> u32)(0), 0x5EED_CAFE);
        let file = object::File::parse(exe()).unwrap();
        let symbol = file
            .symbols()
            .find(|symbol| {
                symbol.kind() == SymbolKind::Text
                    && addr2line::demangle_auto(symbol.name().unwrap_or_default().into(), None)
                        .ends_with("crash::tests::marker")
            })
            .expect("the test executable's symbol table names marker");
        u32::try_from(symbol.address()).unwrap()
    }

    /// The address of `PANIC_PATH`'s bytes in the test executable's read-only data.
    fn panic_path_address() -> u32 {
        let path = std::hint::black_box(PANIC_PATH).as_bytes();
        let file = object::File::parse(exe()).unwrap();
        let address = file
            .sections()
            .filter(|section| {
                matches!(
                    section.kind(),
                    object::SectionKind::ReadOnlyData | object::SectionKind::ReadOnlyString
                )
            })
            .find_map(|section| {
                let data = section.data().unwrap();
                let at = data.windows(path.len()).position(|window| window == path)?;
                Some(section.address() + at as u64)
            })
            .expect("the path's bytes in the read-only data");
        u32::try_from(address).unwrap()
    }

    /// The line number after `file:` in `text`.
    fn line_after(text: &str, file: &str) -> u32 {
        let at = text.find(file).unwrap_or_else(|| panic!("{file} in {text}")) + file.len();
        let digits: String = text[at..].chars().take_while(char::is_ascii_digit).collect();
        digits.parse().unwrap()
    }

    #[test]
    fn the_elf_names_pc_and_lr_and_reads_the_panic_s_path() {
        let elf = Elf::parse(exe()).unwrap();
        let address = marker_address();
        let mut crash = record(bus_fault());
        // The Thumb bit set on PC; LR as a return address inside marker, 2 bytes after its start.
        crash.frame.pc = address | 1;
        crash.frame.lr = (address + 2) | 1;
        crash.panic = Some(PanicAt {
            file: panic_path_address(),
            file_len: PANIC_PATH.len() as u16,
            line: 412,
        });
        let text = describe(&crash, Some(&elf));
        for register in ["PC", "LR"] {
            // The register's line and the lines of the functions its place was inlined into: marker is one.
            let start = text
                .find(&format!("\n{register} "))
                .unwrap_or_else(|| panic!("{register} in {text}"));
            let block: Vec<&str> = text[start + 1..]
                .lines()
                .enumerate()
                .take_while(|(n, line)| *n == 0 || line.trim_start().starts_with("inlined into "))
                .map(|(_, line)| line)
                .collect();
            let line = block
                .iter()
                .find(|line| line.contains("marker at "))
                .unwrap_or_else(|| panic!("marker in {block:?}"));
            let number = line_after(line, "crash.rs:");
            assert!(
                (MARKER_LINE + 1..=MARKER_LINE + 4).contains(&number),
                "{line}: marker is at lines {} to {}",
                MARKER_LINE + 2,
                MARKER_LINE + 4
            );
        }
        assert!(
            text.contains("\npanicked at lbv/decode-crash-test/panic_site.rs:412\n"),
            "{text}"
        );
        // A test executable has no image info to tell its version by.
        assert!(!text.contains("warning"), "{text}");
    }

    #[test]
    fn addresses_outside_the_elf_are_said_to_be() {
        let elf = Elf::parse(exe()).unwrap();
        let mut crash = record(bus_fault());
        crash.frame.pc = 0xFFFF_F000;
        crash.panic = Some(PanicAt {
            file: 0xFFFF_FF00,
            file_len: 200,
            line: 7,
        });
        let text = describe(&crash, Some(&elf));
        assert!(text.contains("\nPC         0xfffff000  (not in the ELF)\n"), "{text}");
        assert!(
            text.contains("\npanicked at <path at 0xffffff00, 200 bytes: not in the ELF>:7\n"),
            "{text}"
        );
    }

    #[test]
    fn what_is_not_a_record_is_refused_with_its_reason() {
        let bytes = record_bytes(bus_fault());
        assert_eq!(
            Record::decode(&bytes[..127]).unwrap_err().to_string(),
            "127 bytes, not a record's 128"
        );
        assert_eq!(Record::decode(&[0; 128]), Err(crash_record::Error::Magic));
        for bit in 0..bytes.len() * 8 {
            let mut flipped = bytes;
            flipped[bit / 8] ^= 1 << (bit % 8);
            assert!(Record::decode(&flipped).is_err(), "bit {bit} flipped");
        }
    }

    #[test]
    fn what_is_not_an_elf_is_refused() {
        for bytes in [
            &b""[..],
            b"not an ELF file",
            b"\x7fELF",
            b"\x7fELF\x01\x01\x01\x00garbage",
        ] {
            let error = Elf::parse(bytes).unwrap_err().to_string();
            assert!(error.starts_with("not an ELF file that reads ("), "{error}");
        }
        // An ELF cut short anywhere is refused or reads as far as it goes.
        let exe = exe();
        let crash = record(bus_fault());
        for len in [16, 52, 64, 1000, 4096, exe.len() / 3, exe.len() - 1] {
            if let Ok(elf) = Elf::parse(&exe[..len]) {
                describe(&crash, Some(&elf));
            }
        }
    }

    /// A small 32-bit ARM ELF, as an object file: a function, a path in read-only data, and DWARF sections of
    /// `debug` bytes each.
    fn small_elf(debug: &[u8]) -> Vec<u8> {
        use object::write::{Object as Writer, Symbol, SymbolSection};
        let mut writer = Writer::new(
            object::BinaryFormat::Elf,
            object::Architecture::Arm,
            object::Endianness::Little,
        );
        let text = writer.add_section(vec![], b".text".to_vec(), object::SectionKind::Text);
        writer.append_section_data(text, &[0x70, 0x47, 0x00, 0xBF, 0x70, 0x47, 0x00, 0xBF], 4);
        writer.add_symbol(Symbol {
            name: b"_ZN3lbv6marker17h0123456789abcdefE".to_vec(),
            value: 1,
            size: 8,
            kind: SymbolKind::Text,
            scope: object::SymbolScope::Linkage,
            weak: false,
            section: SymbolSection::Section(text),
            flags: object::SymbolFlags::None,
        });
        let rodata = writer.add_section(vec![], b".rodata".to_vec(), object::SectionKind::ReadOnlyData);
        writer.append_section_data(rodata, b"src/main.rs", 1);
        for name in [
            ".debug_info",
            ".debug_abbrev",
            ".debug_line",
            ".debug_aranges",
            ".debug_str",
        ] {
            let section = writer.add_section(vec![], name.as_bytes().to_vec(), object::SectionKind::Debug);
            writer.append_section_data(section, debug, 1);
        }
        writer.write().unwrap()
    }

    #[test]
    fn a_small_elf_names_its_function_from_the_symbol_table() {
        let bytes = small_elf(&[]);
        let elf = Elf::parse(&bytes).unwrap();
        // Its one symbol, at 0 with the Thumb bit, in a relocatable file whose sections all start at 0.
        assert_eq!(
            elf.places(4),
            [Place {
                function: Some("lbv::marker".into()),
                file: None,
                line: None
            }]
        );
        assert_eq!(elf.places(8), []);
    }

    proptest! {
        /// Any bytes: refused with a reason, or a record that prints; never a panic.
        #[test]
        fn any_bytes_are_a_record_or_refused(bytes in prop::collection::vec(any::<u8>(), 0..300)) {
            match Record::decode(&bytes) {
                Ok(record) => prop_assert!(!describe(&record, None).is_empty()),
                Err(error) => prop_assert!(!error.to_string().is_empty()),
            }
        }

        /// A record with any registers, events and panic site prints, with and without an ELF of garbage DWARF.
        #[test]
        fn any_record_prints_with_any_elf(
            record in prop::collection::vec(any::<u8>(), 128),
            debug in prop::collection::vec(any::<u8>(), 0..200),
            flips in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 0..8),
        ) {
            // A record that passes its checks: its kind and events held made valid, its CRC computed.
            let mut bytes: [u8; 128] = record.try_into().unwrap();
            bytes[..5].copy_from_slice(b"LBVC\x01");
            bytes[5] = bytes[5] % 5 + 1;
            bytes[64] %= 8;
            let crc = crash_record::crc32(&bytes[..124]);
            bytes[124..].copy_from_slice(&crc.to_le_bytes());
            let mut record = Record::decode(&bytes).unwrap();
            record.frame.pc &= 0xFF;
            let mut elf = small_elf(&debug);
            for (at, value) in flips {
                let at = at.index(elf.len());
                elf[at] ^= value;
            }
            if let Ok(elf) = Elf::parse(&elf) {
                let text = describe(&record, Some(&elf));
                prop_assert!(text.starts_with("kind "));
            }
        }
    }
}
