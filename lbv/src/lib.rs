//! The parts of the `lbv` host tools that read outside input: the capture decoders (`lbv decode`), the dev-kit
//! bench-test runner (`lbv hil`), the bounded line reader under them, and the update files and firmware ELFs of
//! `lbv image`, and the bench's trace and its plots, which `lbv decode tlog` draws a telemetry log with. A library,
//! so that the fuzz targets in `lbv/fuzz` reach the same parsers the command runs.

pub mod decode;
pub mod flash;
pub mod hil;
pub mod image;
pub mod lines;
pub mod plot;
pub mod trace;

/// Refuse a command line as clap does (the message, the command's usage, exit status 2): for the rules between
/// options that clap's attributes do not say.
pub fn refuse<C: clap::CommandFactory>(bin_name: &'static str, message: impl std::fmt::Display) -> ! {
    C::command()
        .bin_name(bin_name)
        .error(clap::error::ErrorKind::ArgumentConflict, message)
        .exit()
}

/// Exit statuses shared by every `lbv` command.
pub mod exit {
    /// The command did its job and all was well: every check passed, every line decoded, the verdict PASS.
    pub const OK: u8 = 0;
    /// The command did its job and found a failure: a check or step failed, lines were skipped, frames did not
    /// decode.
    pub const FAILED: u8 = 1;
    /// The command could not do its job: a bad command line, an input it cannot read, an output it cannot write,
    /// a build or flash that failed.
    pub const TROUBLE: u8 = 2;

    /// The convention in words, for every command's `--help`.
    pub const HELP: &str = "\
Exit status, every command: 0 all well (every check passed, every line decoded, verdict PASS);
1 a failure found (a check or step failed, lines skipped, frames that did not decode); 2 the
command could not do its job (bad command line, unreadable input, unwritable output, a build or
flash that failed). lbv hil adds 3 (no verdict in time) and 4 (the log ended without one).";
}
