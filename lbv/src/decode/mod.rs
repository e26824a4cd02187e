//! `lbv decode`: read what people capture on the bench (logic-analyser I2C exports, candump logs) and print it
//! decoded with the project's protocol crates.

use std::process::ExitCode;

pub const USAGE: &str = "usage: lbv decode (i2c|can) [FILE|-] [--json]";

/// `lbv decode ...`
pub fn main(args: &[String]) -> ExitCode {
    let _ = args;
    eprintln!("{USAGE}");
    ExitCode::from(2)
}
