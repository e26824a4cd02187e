//! `@PARAM/param.pck`: every parameter in one file, in ArduPilot's packed format (its `AP_Filesystem` README and
//! `AP_Filesystem_Param`), which QGroundControl and MAVProxy read over MAVLink FTP at connect, asking
//! `@PARAM/param.pck?withdefaults=1`, before they fall back to PARAM_REQUEST_LIST. Ten FTP replies' worth of
//! PARAM_VALUEs come as two.
//!
//! The file, all little-endian:
//! - a 6-byte header: magic 0x671B (0x671C with defaults), how many parameters follow, how many the vehicle has;
//! - per parameter, in index order: a byte of its type (low nibble: 1 INT8, 2 INT16, 3 INT32, 4 FLOAT, as
//!   AP_Param numbers them; MAVLink's own types are in [`crate::params::ParamType`]) and flags (high nibble: bit 0,
//!   a default follows the value); a byte of how many leading name bytes it shares with the previous parameter's (low
//!   nibble, at most 15) and how many follow, less one (high nibble); those name bytes; the value; with defaults,
//!   for a parameter whose value is not its default, the default;
//! - zero bytes before a parameter wherever its value and default would otherwise cross a 239-byte block (FTP's
//!   largest read, QGroundControl's and MAVProxy's): a block read again never splits a value. Readers skip zeros
//!   before a parameter (a type byte is never 0).
//!
//! The query, after `?`: `withdefaults=0|1`, as ArduPilot takes it, pairs joined by `&`; other keys are ignored,
//! as ArduPilot ignores those it does not know. ArduPilot's `start` and `count` (a part of the list) are among
//! them: no ground station we know asks for a part, and the whole file is 2 replies. A `withdefaults` that is not
//! 0 or 1 is refused ([`crate::update::ftp::Nak::Fail`]).
//!
//! Its length is fixed at OpenFileRO, as are the values it was opened with (their CRC,
//! [`ParamFile::crc`]): its bytes are made again from the settings in force at each read, so a parameter set
//! before the file is read whole would change them, and that read is refused instead
//! ([`crate::update::ftp::Nak::Fail`]; the ground station opens the file again or asks for the list). A
//! download is the parameters as they stood at one moment, never a value torn between two.

use crate::mixer::FrameKind;
use crate::params::{LISTED_COUNT, Listed, Param, ParamType, Params};
pub use crate::shared::ParamFile;
use crate::update::ftp::crc32;
use crate::update::window::Window;

/// The directory, as a request names it (after a leading `/`, which may be left out).
pub(crate) const DIR: &str = "@PARAM";
/// The file's name in its directory.
pub(crate) const NAME: &str = "param.pck";

const MAGIC: u16 = 0x671B;
const MAGIC_WITH_DEFAULTS: u16 = 0x671C;
/// The block no value crosses: FTP's largest read.
const BLOCK: u32 = 239;

/// Whether `path` (its leading `/` taken off) names `@PARAM`: `Some(None)` the directory, `Some(Some(query))` the
/// file, with what follows its name (empty, or a query from its `?`); `None` anything else.
pub(crate) fn in_dir(path: &[u8]) -> Option<Option<&[u8]>> {
    let rest = path.strip_prefix(DIR.as_bytes())?;
    match rest {
        b"" | b"/" => Some(None),
        _ => {
            let query = rest.strip_prefix(b"/")?.strip_prefix(NAME.as_bytes())?;
            (query.is_empty() || query.first() == Some(&b'?')).then_some(Some(query))
        }
    }
}

impl ParamFile {
    /// The file `query` asks for (empty, or `?` and its pairs), with `params` in force and `frame` the build's;
    /// `None` for a query it cannot serve.
    pub(crate) fn open(query: &[u8], params: &Params, frame: FrameKind) -> Option<Self> {
        let mut file = Self {
            with_defaults: false,
            frame,
            len: [0; 2],
            crc: crc(params).to_le_bytes(),
        };
        let pairs = match query {
            [] => &[][..],
            [b'?', pairs @ ..] => pairs,
            _ => return None,
        };
        for pair in pairs.split(|byte| *byte == b'&') {
            match pair.strip_prefix(b"withdefaults") {
                Some(b"=0") => file.with_defaults = false,
                Some(b"=1") => file.with_defaults = true,
                Some(_) => return None,
                None => {}
            }
        }
        let mut counted = Window::new(0, &mut []);
        file.render(params, &mut counted);
        file.len = u16::try_from(counted.total).ok()?.to_le_bytes();
        Some(file)
    }

    /// Its bytes from `offset` that fit `into`, made from `params`: how many, or `None` if `params` are no longer
    /// the values it was opened with.
    pub(crate) fn read(&self, offset: u32, into: &mut [u8], params: &Params) -> Option<usize> {
        if crc(params).to_le_bytes() != self.crc {
            return None;
        }
        let mut window = Window::new(offset, into);
        self.render(params, &mut window);
        Some(window.filled)
    }

    /// The whole file into `out`.
    fn render(&self, params: &Params, out: &mut Window<'_>) {
        let defaults = Params::defaults(self.frame);
        let magic = if self.with_defaults { MAGIC_WITH_DEFAULTS } else { MAGIC };
        let [m0, m1] = magic.to_le_bytes();
        let [c0, c1] = (LISTED_COUNT as u16).to_le_bytes();
        // How many it lists, then how many there are: all of them.
        out.put(&[m0, m1, c0, c1, c0, c1]);
        let mut previous: &[u8] = &[];
        for listed in Listed::all() {
            let name = listed.name().as_bytes();
            // At most 15 bytes shared (a nibble), and at least one of its own.
            let shared = previous.iter().zip(name).take_while(|(a, b)| a == b).count();
            let shared = shared.min(15).min(name.len().saturating_sub(1));
            let own = name.get(shared..).unwrap_or_default();
            let (kind, value) = packed(listed, listed.value(params));
            let (_, default) = packed(listed, listed.value(&defaults));
            let with_default = self.with_defaults && value != default;
            let size = kind.size();
            let data = size * (1 + u32::from(with_default));
            let start = out.total + 2 + own.len() as u32;
            let end = start + data - 1;
            if start / BLOCK != end / BLOCK {
                out.zeros(BLOCK - start % BLOCK);
            }
            out.put(&[
                kind.code() | u8::from(with_default) << 4,
                shared as u8 | (own.len().saturating_sub(1) as u8) << 4,
            ]);
            out.put(own);
            out.put(value.get(..size as usize).unwrap_or_default());
            if with_default {
                out.put(default.get(..size as usize).unwrap_or_default());
            }
            previous = name;
        }
    }
}

/// A parameter's type as the file numbers it (AP_Param's).
#[derive(Clone, Copy)]
enum Kind {
    Int8,
    Int16,
    Int32,
    Float,
}

impl Kind {
    const fn code(self) -> u8 {
        match self {
            Self::Int8 => 1,
            Self::Int16 => 2,
            Self::Int32 => 3,
            Self::Float => 4,
        }
    }

    const fn size(self) -> u32 {
        match self {
            Self::Int8 => 1,
            Self::Int16 => 2,
            Self::Int32 | Self::Float => 4,
        }
    }
}

/// `value` (the parameter's own unit) as the file carries it: its type, and its bytes (the first [`Kind::size`]).
/// An integer parameter's value is in its type's range ([`Params`] keeps every value in the parameter's).
fn packed(listed: Listed, value: i32) -> (Kind, [u8; 4]) {
    match listed.param_type() {
        ParamType::Int8 => (Kind::Int8, [value as i8 as u8, 0, 0, 0]),
        ParamType::Int16 => {
            let [b0, b1] = (value as i16).to_le_bytes();
            (Kind::Int16, [b0, b1, 0, 0])
        }
        ParamType::Int32 => (Kind::Int32, value.to_le_bytes()),
        ParamType::Real32 => (Kind::Float, listed.to_float(value).to_le_bytes()),
    }
}

/// The CRC-32 of every value, in index order.
fn crc(params: &Params) -> u32 {
    Param::ALL
        .into_iter()
        .fold(0, |crc, param| crc32(crc, &params.get(param).to_le_bytes()))
}
