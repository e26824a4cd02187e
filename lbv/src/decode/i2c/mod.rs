//! `lbv decode i2c`: read what sigrok's I2C protocol decoder made of a logic capture (sigrok-cli's annotation
//! output or a PulseView annotation export) and print each transfer on the thruster bus decoded with `tmc-proto`.
//!
//! The input is one annotation per line. Three layouts are read, each with or without the sample range in front:
//! - sigrok-cli `-A i2c`: `i2c-1: Address write: 29`; with `--protocol-decoder-samplenum`:
//!   `35-105 i2c-1: Address write: 29`; at log level 4 or more (`-l 4`) the annotation class and every text,
//!   quoted: `35-105 i2c-1: address-write: "Address write: 29" "AW: 29" "29"`.
//! - PulseView "Export all annotations" / "Export annotations for this row": its default format `%s %d: %r: %1`
//!   gives `35-105 I²C: Address/Data: Address write: 29`; any format built from `%s` (if there, first), `%d`,
//!   `%r`, `%c`, `%1` or `%a`, with fields separated by `: `, `,`, `;` or tabs, and with or without `%q` quotes,
//!   is read.
//! - sigrok-cli `--protocol-decoder-jsontrace` (Google trace events): times come from its `ts` field (µs).
//!
//! Of each line only the annotation text counts: `Start`, `Start repeat`, `Stop`, `ACK`, `NACK`,
//! `Address read: HH`, `Address write: HH`, `Data read: HH`, `Data write: HH` (hex; any letter case), and the
//! bit and read/write marker annotations (`0`, `1`, `Read`, `Write`), which are ignored. Other lines are reported
//! on standard error with their line number and skipped.
//!
//! Transfers: a START (or repeated START) followed by an address and data bytes, ended by STOP or the next
//! repeated START. Writes to 0x29 / 0x2A are orders of the SeaBotix / Legacy family, reads from them statuses;
//! anything else is printed raw (a TCA9548A mux at 0x70..=0x77 is named, with its channel mask).

mod assemble;
mod formats;
mod record;
mod render;
#[cfg(test)]
mod tests;

use std::io::{self, BufRead, Write};
use std::path::PathBuf;
use std::process::ExitCode;

use super::StreamError;
use crate::exit;
use crate::lines::{Line, Lines};

use assemble::{Assembler, Transfer};
use formats::parse_line;
use record::{Kind, record, round_ns};
use render::human;

const HELP: &str = "\
Reads the output of sigrok's I2C protocol decoder, one annotation per line, in these layouts:
  sigrok-cli -A i2c                         i2c-1: Address write: 29
  ... --protocol-decoder-samplenum          35-105 i2c-1: Address write: 29
  ... -l 4 (class and all texts, quoted)    35-105 i2c-1: address-write: \"Address write: 29\" ...
  ... --protocol-decoder-jsontrace          {\"ph\": \"B\", \"ts\": 35.0, \"name\": \"Address write: 29\"}
  PulseView's annotation export, default format %s %d: %r: %1
                                            35-105 I²C: Address/Data: Address write: 29
  ... any format of %s (first, if there), %d, %r, %c, %1 or %a, separated by ': ' , ; or tabs,
      with or without %q
  e.g. sigrok-cli -i capture.sr -P i2c:scl=D0:sda=D1 -A i2c | lbv decode i2c
Bit and read/write annotations are ignored; other lines, and lines over 4096 bytes, are reported
(with their line number) and skipped.

Prints one line per transfer (START or repeated START to STOP or the next repeated START): start
time, time since the previous transfer, address, W/R, then the thruster order or status decoded
with tmc-proto (0x29 SeaBotix, 0x2A Legacy: speed, INFO, faults, current, temperature, checksum
verdict), a mux select at 0x70-0x77, or the raw bytes (the first 64 of a longer transfer); NACKed
addresses as NACK (no thruster). At the end, time since the last transfer to the same address. A
summary goes to standard error.

Exit status: 0 every line read; 1 lines were skipped (the output is complete all the same);
2 bad command line, or the input cannot be read or the output written.";

/// `lbv decode i2c`'s command line.
#[derive(Debug, Default, clap::Args)]
#[command(after_help = HELP)]
pub struct Args {
    /// The annotations; standard input when - or absent
    #[arg(value_name = "FILE")]
    pub input: Option<PathBuf>,
    /// One JSON object per transfer and line: time, address, direction, ack, bytes, family, kind (order, status,
    /// other), the decoded fields, checksum_ok, error, since_prev_s, since_prev_same_address_s, duration_s
    #[arg(long)]
    pub json: bool,
    /// Turn sample numbers into seconds (1000000, 1e6, 1M and 1MHz are the same; 1 Hz to 1 THz). Without it, and
    /// without trace times, time is null; the human line then shows the start sample @N or the transfer number #N
    #[arg(long, value_name = "HZ", value_parser = parse_rate)]
    pub samplerate: Option<f64>,
    /// The addresses were exported unshifted (sigrok's address_format=unshifted: R/W bit included)
    #[arg(long)]
    pub unshifted: bool,
}

/// A sample rate in Hz: a number with an optional k / M / G multiplier and an optional `Hz`, from 1 Hz to 1 THz.
fn parse_rate(text: &str) -> Result<f64, String> {
    let bad = || format!("{text:?} is not a rate from 1 Hz to 1 THz, such as 1000000 or 1M");
    let mut number = text.trim();
    if number.len() >= 2
        && number
            .get(number.len() - 2..)
            .is_some_and(|tail| tail.eq_ignore_ascii_case("hz"))
    {
        number = number.get(..number.len() - 2).unwrap_or_default().trim_end();
    }
    let (digits, scale) = match number.chars().last() {
        Some('k' | 'K') => (number.get(..number.len() - 1), 1e3),
        Some('M') => (number.get(..number.len() - 1), 1e6),
        Some('G' | 'g') => (number.get(..number.len() - 1), 1e9),
        _ => (Some(number), 1.0),
    };
    let value: f64 = digits.unwrap_or_default().trim().parse().map_err(|_| bad())?;
    let rate = value * scale;
    if (1.0..=1e12).contains(&rate) {
        Ok(rate)
    } else {
        Err(bad())
    }
}

/// `lbv decode i2c ...`
pub fn main(args: &Args) -> ExitCode {
    let (input, name) = match super::open(args.input.as_deref()) {
        Ok(input) => input,
        Err(message) => {
            eprintln!("lbv decode i2c: {message}");
            return ExitCode::from(exit::TROUBLE);
        }
    };
    let mut out = io::BufWriter::new(io::stdout().lock());
    let mut err = io::stderr();
    let mut decoder = Decoder::new(args);
    let result = decoder.run(input, &mut out, &mut err);
    let result = result.and_then(|()| out.flush().map_err(StreamError::Write));
    decoder.summary(&mut err);
    match result {
        Ok(()) if decoder.counts.skipped == 0 => ExitCode::SUCCESS,
        Ok(()) => ExitCode::from(exit::FAILED),
        Err(error) => error.exit("lbv decode i2c", &name),
    }
}

/// Decode the annotations of `input` as `args` say: transfers to `out`, bad lines and the summary to `err`.
pub fn run(
    input: impl BufRead,
    out: &mut impl Write,
    err: &mut impl Write,
    args: &Args,
) -> Result<Counts, StreamError> {
    let mut decoder = Decoder::new(args);
    decoder.run(input, out, err)?;
    decoder.summary(err);
    Ok(decoder.counts)
}

/// Longest line read; annotation lines are far shorter. Longer lines are skipped (only this much of one is kept).
pub const MAX_LINE: usize = 4096;

/// Data bytes kept of one transfer: a thruster message has at most 7; a longer transfer is shown cut, so that
/// memory stays bounded whatever the capture holds.
pub const MAX_TRANSFER_BYTES: usize = 64;

/// What a run read, for the summary and the exit status.
#[derive(Debug, Default, Clone, PartialEq, Eq)]
pub struct Counts {
    /// Transfers printed.
    pub transfers: u64,
    /// Thruster orders among them.
    pub orders: u64,
    /// Thruster statuses among them.
    pub statuses: u64,
    /// Transfers to other addresses.
    pub others: u64,
    /// Transfers whose address no device acknowledged.
    pub nacked: u64,
    /// Thruster messages whose checksum did not match.
    pub bad_checksums: u64,
    /// Annotations read.
    pub annotations: u64,
    /// Lines skipped.
    pub skipped: u64,
}

/// Bad lines reported one by one on standard error; the summary counts them all.
pub const MAX_MESSAGES: u64 = 100;

/// Reads the lines, assembles the transfers, prints them. Its state is bounded: the transfer being assembled
/// and one time per 7-bit address.
#[derive(Debug)]
struct Decoder {
    json: bool,
    assembler: Assembler,
    counts: Counts,
    last_start: Option<f64>,
    last_start_by_address: [Option<f64>; 128],
}

impl Decoder {
    fn new(args: &Args) -> Decoder {
        Decoder {
            json: args.json,
            assembler: Assembler {
                unshifted: args.unshifted,
                samplerate: args.samplerate,
                ..Assembler::default()
            },
            counts: Counts::default(),
            last_start: None,
            last_start_by_address: [None; 128],
        }
    }

    /// Decode every line of `input`; transfers go to `out`, bad lines to `err`.
    fn run(&mut self, input: impl BufRead, out: &mut impl Write, err: &mut impl Write) -> Result<(), StreamError> {
        let mut lines = Lines::new(input, MAX_LINE);
        while let Some((number, line)) = lines.next_line().map_err(StreamError::Read)? {
            let text = String::from_utf8_lossy(line.bytes());
            let outcome = match line {
                Line::TooLong { length, .. } => Err(format!("line of {length} bytes, longer than {MAX_LINE}")),
                Line::Whole(_) => parse_line(&text).and_then(|annotation| match annotation {
                    Some(annotation) => {
                        self.counts.annotations += 1;
                        self.assembler.feed(annotation)
                    }
                    None => Ok(None),
                }),
            };
            match outcome {
                Ok(Some(transfer)) => self.emit(transfer, out).map_err(StreamError::Write)?,
                Ok(None) => {}
                Err(reason) => {
                    self.counts.skipped += 1;
                    if self.counts.skipped <= MAX_MESSAGES {
                        let excerpt: String = text.trim_end().chars().take(60).collect();
                        let _ = writeln!(err, "lbv decode i2c: line {number}: {reason}, skipped: {excerpt:?}");
                    }
                }
            }
        }
        if let Some(transfer) = self.assembler.finish() {
            self.emit(transfer, out).map_err(StreamError::Write)?;
        }
        Ok(())
    }

    fn emit(&mut self, transfer: Transfer, out: &mut impl Write) -> io::Result<()> {
        let mut record = record(transfer, self.counts.transfers);
        if let Some(time) = record.time {
            record.since_prev_s = self.last_start.map(|last| round_ns(time - last));
            let last_here = self.last_start_by_address.get_mut(usize::from(record.address));
            if let Some(last_here) = last_here {
                record.since_prev_same_address_s = last_here.map(|last| round_ns(time - last));
                *last_here = Some(time);
            }
            self.last_start = Some(time);
        }
        self.counts.transfers += 1;
        if record.ack == Some(false) {
            self.counts.nacked += 1;
        } else {
            match record.kind {
                Kind::Order => self.counts.orders += 1,
                Kind::Status => self.counts.statuses += 1,
                Kind::Other => self.counts.others += 1,
            }
        }
        if record.checksum_ok == Some(false) {
            self.counts.bad_checksums += 1;
        }
        if self.json {
            let line = serde_json::to_string(&record).map_err(io::Error::other)?;
            writeln!(out, "{line}")
        } else {
            writeln!(out, "{}", human(&record))
        }
    }

    fn summary(&self, err: &mut impl Write) {
        let c = &self.counts;
        let _ = writeln!(
            err,
            "lbv decode i2c: {} transfers: {} orders, {} statuses, {} other, {} NACKed, {} bad checksums; {} lines \
             skipped{}",
            c.transfers,
            c.orders,
            c.statuses,
            c.others,
            c.nacked,
            c.bad_checksums,
            c.skipped,
            if c.skipped > MAX_MESSAGES {
                format!(" (the first {MAX_MESSAGES} shown)")
            } else {
                String::new()
            }
        );
        if c.annotations == 0 {
            let _ = writeln!(
                err,
                "lbv decode i2c: no I2C annotations found (expected sigrok-cli -A i2c output or a PulseView export)"
            );
        }
    }
}
