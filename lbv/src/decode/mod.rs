//! `lbv decode`: read what people capture on the bench (logic-analyser I2C exports, candump logs) and print it
//! decoded with the project's protocol crates.

pub mod i2c;

use std::process::ExitCode;

pub const USAGE: &str = "usage: lbv decode (i2c|can) [FILE|-] [--json]
       lbv decode i2c [FILE|-] [--json] [--samplerate HZ] [--unshifted]   (lbv decode i2c --help for more)";

/// `lbv decode ...`
pub fn main(args: &[String]) -> ExitCode {
    let rest = args.get(1..).unwrap_or_default();
    match args.first().map(String::as_str) {
        Some("i2c") => i2c::main(rest),
        _ => {
            eprintln!("{USAGE}");
            ExitCode::from(2)
        }
    }
}
