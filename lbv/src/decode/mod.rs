//! `lbv decode`: read what people capture on the bench (logic-analyser I2C exports, candump logs) and print it
//! decoded with the project's protocol crates.

pub mod can;
pub mod i2c;

use std::process::ExitCode;

pub const USAGE: &str =
    "usage: lbv decode i2c [FILE|-] [--json] [--samplerate HZ] [--unshifted]   (lbv decode i2c --help for more)
       lbv decode can [FILE|-] [--json]

lbv decode can: candump logs (`candump -l`: `(TIME) IFACE ID#DATA`) from FILE or standard input: the BAT board's
             0x620 info, 0x629 status (every bit in words at the first, then the bits that switched) and 0x628
             BMS alarms, decoded with bat-proto, one line per frame; other frames are counted, not printed.
             --json: one object per frame (time, id, voltage_v, current_a, charge_pct, temperature_c, status,
             status_bits, changed, alarms, alarm_bits). Bad lines are reported on standard error with their
             number and skipped. Exit status 1 when lines were skipped or BAT frames did not decode, 2 when the
             input cannot be read.";

/// `lbv decode ...`
pub fn main(args: &[String]) -> ExitCode {
    let rest = args.get(1..).unwrap_or_default();
    match args.first().map(String::as_str) {
        Some("i2c") => i2c::main(rest),
        Some("can") => can::main(rest),
        _ => {
            eprintln!("{USAGE}");
            ExitCode::from(2)
        }
    }
}
