//! `@SYS/`: read-only files the master makes when they are opened, as ArduPilot serves its own `@SYS/` files
//! (`AP_Filesystem_Sys`): OpenFileRO fixes the content and answers its length, ReadFile and BurstReadFile read it by
//! offset until EndOfFile. `versions.txt`, what every board runs, as the master knows it; and in `crash/` the
//! post-mortem records held, each as the board kept it ([`crash_record`]): `master.bin`, the master's own stop
//! before this start, and `thruster<slot>.bin`, each thruster's, as the master fetched it (slots from 0, as the
//! update files count them: `thruster0.bin` is T1's). And `blackbox.tlog`, the vehicle's last minutes as a
//! telemetry log ([`crate::blackbox`]), when the master has a black box.
//!
//! Its text, one line per board after a header line, each line ending in `\n`, its fields apart by spaces and
//! padded into columns (board 6 wide, family 8, version 8, so a longer version pushes the state out):
//!
//! ```text
//! board  family   version  state
//! master -        0.1.0    confirmed
//! T1     SeaBotix 0.3.0    confirmed
//! T2     Legacy   0.1.0    offline
//! T3     SeaBotix 0.3.0    on-trial
//! ```
//!
//! - board: `master`, then `T1`.. for each slot of the thruster table, as the texts name them;
//! - family: `SeaBotix` or `Legacy` (`-` for the master);
//! - version: the running image's, as its image info gives it (`major.minor.patch`); `-` while the master has not
//!   heard it (a thruster not asked yet since the master started, one that takes no update);
//! - state ([`ImageState`]): `confirmed`, `on-trial`, `marked` (an update marked for its bootloader, waiting for its
//!   restart), `offline` (a thruster that does not answer its polls; its version is the last one heard),
//!   `unasked` (it answers, and has not been asked yet what it runs since it came back: the version is the last one
//!   heard), `no-updates` (a thruster that answers without the update extension), `unknown` (the master has not
//!   read its own bootloader's state).
//!
//! The file is not kept: [`Versions`] is what it is made of (49 bytes), taken at OpenFileRO, and each read makes the
//! text again from it and keeps the bytes asked for, so every read of one opening reads the same text. The text is
//! at most [`MAX_LEN`] bytes (two replies), for the eight slots of the largest table and the longest versions.

use core::fmt::{self, Write};

use tmc_proto::Family;
use update_image::Version;

use crate::shared::MAX_THRUSTERS;
pub use crate::shared::{ImageState, Running, Versions};
use crate::update::window::Window;

/// The directory, as a request names it (after a leading `/`, which may be left out).
pub(crate) const DIR: &str = "@SYS";
/// `versions.txt`'s name in its directory.
pub(crate) const VERSIONS: &str = "versions.txt";
/// The black box's file in the directory ([`crate::blackbox`]).
pub(crate) const BLACK_BOX: &str = "blackbox.tlog";
/// The longest text: the header line and nine lines of 41 bytes (the longest version, 13 bytes, and `no-updates`).
pub const MAX_LEN: u32 = 31 + 9 * 41;

const HEADER: &str = "board  family   version  state\n";

/// A post-mortem record's file in `@SYS/crash`: the master's (`None`) or slot `slot`'s thruster's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CrashFile(pub Option<u8>);

impl CrashFile {
    /// The file `name` names, if it is one: `master.bin`, `thruster0.bin` to `thruster7.bin`.
    pub(crate) fn named(name: &[u8]) -> Option<Self> {
        match name {
            b"master.bin" => Some(CrashFile(None)),
            [
                b't',
                b'h',
                b'r',
                b'u',
                b's',
                b't',
                b'e',
                b'r',
                digit,
                b'.',
                b'b',
                b'i',
                b'n',
            ] => {
                let slot = digit.wrapping_sub(b'0');
                (usize::from(slot) < MAX_THRUSTERS).then_some(CrashFile(Some(slot)))
            }
            _ => None,
        }
    }
}

impl fmt::Display for CrashFile {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.0 {
            None => f.write_str("master.bin"),
            Some(slot) => write!(f, "thruster{slot}.bin"),
        }
    }
}

/// What follows `@SYS` in `path` (its leading `/` taken off), if it begins so.
pub(crate) fn in_dir(path: &[u8]) -> Option<&[u8]> {
    match path.split_at_checked(DIR.len()) {
        Some((dir, rest)) if dir == DIR.as_bytes() => Some(rest),
        _ => None,
    }
}

/// Whether a request's path is `@SYS` or under it (the leading `/` may be left out).
pub(crate) fn is_sys(path: &[u8]) -> bool {
    in_dir(path.strip_prefix(b"/").unwrap_or(path)).is_some_and(|rest| rest.is_empty() || rest.first() == Some(&b'/'))
}

impl ImageState {
    /// Its word in the file.
    const fn word(self) -> &'static str {
        match self {
            Self::Unknown => "unknown",
            Self::Confirmed => "confirmed",
            Self::OnTrial => "on-trial",
            Self::Marked => "marked",
            Self::Offline => "offline",
            Self::Unasked => "unasked",
            Self::NoUpdates => "no-updates",
        }
    }
}

impl Versions {
    /// The file of a table whose slots have `families`, every board's image unknown until [`Versions::set`].
    pub(crate) fn new(families: &[Option<Family>; MAX_THRUSTERS]) -> Self {
        let mut versions = Self {
            slots: 0,
            legacy: 0,
            heard: [0; 2],
            versions: [[0; 4]; 1 + MAX_THRUSTERS],
            states: [ImageState::Unknown; 1 + MAX_THRUSTERS],
        };
        for (slot, family) in (0..).zip(families) {
            let bit = 1u8.checked_shl(slot).unwrap_or(0);
            match family {
                Some(Family::SeaBotix) => versions.slots |= bit,
                Some(Family::Legacy) => {
                    versions.slots |= bit;
                    versions.legacy |= bit;
                }
                None => {}
            }
        }
        versions
    }

    /// Board `board` (0 the master, `n + 1` slot `n`'s thruster) runs `running`.
    pub fn set(&mut self, board: usize, running: Running) {
        if let (Some(version), Some(bytes)) = (self.versions.get_mut(board), running.version) {
            *version = bytes;
            let heard = u16::from_le_bytes(self.heard) | 1u16.checked_shl(board as u32).unwrap_or(0);
            self.heard = heard.to_le_bytes();
        }
        if let Some(state) = self.states.get_mut(board) {
            *state = running.state;
        }
    }

    /// Board `board`'s version and state.
    fn running(&self, board: usize) -> Running {
        let heard = u16::from_le_bytes(self.heard).checked_shr(board as u32).unwrap_or(0) & 1 == 1;
        Running {
            version: self.versions.get(board).copied().filter(|_| heard),
            state: self.states.get(board).copied().unwrap_or_default(),
        }
    }

    /// Its text, into `out`. Its columns are padded by hand, not with format widths, for the flash that costs.
    fn write_to(&self, out: &mut Window<'_>) -> fmt::Result {
        out.write_str(HEADER)?;
        out.write_str("master -        ")?;
        line(out, self.running(0))?;
        for slot in 0..MAX_THRUSTERS {
            let bit = 1u8.checked_shl(slot as u32).unwrap_or(0);
            if self.slots & bit == 0 {
                continue;
            }
            // One digit: the table has at most eight slots.
            write!(out, "T{}     ", slot + 1)?;
            let family = if self.legacy & bit == 0 {
                "SeaBotix "
            } else {
                "Legacy   "
            };
            out.write_str(family)?;
            line(out, self.running(slot + 1))?;
        }
        Ok(())
    }

    /// Its length in bytes.
    pub(crate) fn len(&self) -> u32 {
        self.window(0, &mut []).1
    }

    /// The text's bytes from `offset` into `into`, as many as fit: how many (0 at or past the end).
    pub(crate) fn read(&self, offset: u32, into: &mut [u8]) -> usize {
        self.window(offset, into).0
    }

    /// The text's bytes from `offset` that fit `into`: how many, and the text's length.
    fn window(&self, offset: u32, into: &mut [u8]) -> (usize, u32) {
        let mut window = Window::new(offset, into);
        // A window takes every byte it is given: the text is never cut.
        let _ = self.write_to(&mut window);
        (window.filled, window.total)
    }
}

/// The end of a board's line, after its board and family columns: its version and state.
fn line(out: &mut Window<'_>, running: Running) -> fmt::Result {
    let start = out.total;
    match running.version {
        Some(version) => write!(out, "{}", Version::from_bytes(version))?,
        None => out.write_str("-")?,
    }
    let width = out.total.saturating_sub(start) as usize;
    out.write_str(SPACES.get(width.min(8)..).unwrap_or(" "))?;
    out.write_str(running.state.word())?;
    out.write_str("\n")
}

/// The version column (8 wide) and the space after it; a longer version is followed by one space.
const SPACES: &str = "         ";
