//! `lbv hil`: the bench test between two dev kits, run from the host.

use std::process::ExitCode;

pub const USAGE: &str = "usage: lbv hil ...";

/// `lbv hil ...`
pub fn main(args: &[String]) -> ExitCode {
    let _ = args;
    eprintln!("{USAGE}");
    ExitCode::from(2)
}
