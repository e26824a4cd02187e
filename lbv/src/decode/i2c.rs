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

use std::io::{self, BufRead, Write};
use std::path::PathBuf;
use std::process::ExitCode;

use serde::Serialize;
use tmc_proto::{Family, Faults, MaxPower, MotorKind, ORDER_LEN, Order, Speed, Status, checksum};

use crate::exit;
use crate::lines::{Line, Lines};

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
    let result = result.and_then(|()| out.flush().map_err(Failure::Write));
    decoder.summary(&mut err);
    match result {
        Ok(()) if decoder.counts.skipped == 0 => ExitCode::SUCCESS,
        Ok(()) => ExitCode::from(exit::FAILED),
        // A reader that stopped early (`| head`) is not an error.
        Err(Failure::Write(error)) if error.kind() == io::ErrorKind::BrokenPipe => ExitCode::SUCCESS,
        Err(Failure::Write(error)) => {
            eprintln!("lbv decode i2c: cannot write the output: {error}");
            ExitCode::from(exit::TROUBLE)
        }
        Err(Failure::Read(error)) => {
            eprintln!("lbv decode i2c: cannot read {name}: {error}");
            ExitCode::from(exit::TROUBLE)
        }
    }
}

/// Why a run stopped before the end of its input.
#[derive(Debug)]
pub enum Failure {
    /// Reading the input failed.
    Read(io::Error),
    /// Writing the output failed.
    Write(io::Error),
}

/// Decode the annotations of `input` as `args` say: transfers to `out`, bad lines and the summary to `err`.
pub fn run(input: impl BufRead, out: &mut impl Write, err: &mut impl Write, args: &Args) -> Result<Counts, Failure> {
    let mut decoder = Decoder::new(args);
    decoder.run(input, out, err)?;
    decoder.summary(err);
    Ok(decoder.counts)
}

/// What one annotation says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Event {
    Start,
    RepeatStart,
    Stop,
    Ack,
    Nack,
    /// Slave address as exported (shifted, 7-bit, unless `--unshifted`).
    Address {
        read: bool,
        value: u8,
    },
    Data {
        read: bool,
        byte: u8,
    },
    /// Bits and the read/write marker: carried by the other annotations too, so not needed.
    Ignored,
}

/// Where an annotation sits in time, as the export gives it.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Stamp {
    None,
    /// Start and end sample numbers.
    Samples(u64, u64),
    /// Start time in seconds (trace events).
    Seconds(f64),
}

/// One annotation line.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Annotation {
    event: Event,
    stamp: Stamp,
}

/// Longest line read; annotation lines are far shorter. Longer lines are skipped (only this much of one is kept).
pub const MAX_LINE: usize = 4096;

/// Read one line: `Ok(None)` for lines with nothing to read (blank, `#` comments, trace header and footer, trace
/// end events), an error saying why for lines that are not I2C annotations. Linear in the line's length.
fn parse_line(line: &str) -> Result<Option<Annotation>, String> {
    let text = line.trim_matches(|c: char| c.is_whitespace() || c == '\u{feff}');
    if text.is_empty() || text.starts_with('#') {
        return Ok(None);
    }
    if text.starts_with('{') || text.starts_with(']') {
        return parse_trace_event(text);
    }
    let (stamp, rest) = split_samples(text)?;
    let event = if rest.contains('"') {
        // Quoted texts (sigrok-cli -l 4, PulseView %q): the first quoted text that is an annotation.
        rest.split('"').skip(1).step_by(2).find_map(parse_text)
    } else {
        candidates(rest).find_map(parse_text)
    };
    match event {
        Some(event) => Ok(Some(Annotation { event, stamp })),
        None => Err("not an I2C annotation".into()),
    }
}

/// The texts that an unquoted line's annotation may be, leftmost first. Fields are separated by `:`, `,`, `;` or
/// tabs, and stand between the decoder, row and class names and anything after; the annotation text is a field
/// (`Start`, `ACK`) or a field and the next after a colon (`Address write: 29`). Each byte is in at most three
/// candidates, so reading a line is linear in its length.
fn candidates(rest: &str) -> impl Iterator<Item = &str> {
    let mut fields = Vec::new();
    let mut start = 0;
    for (at, c) in rest.char_indices() {
        if matches!(c, ':' | ',' | ';' | '\t') {
            fields.push((start, at, c == ':'));
            start = at + c.len_utf8();
        }
    }
    fields.push((start, rest.len(), false));
    (0..fields.len()).flat_map(move |i| {
        let (start, end, colon) = fields.get(i).copied().unwrap_or_default();
        let next_end = fields.get(i + 1).filter(|_| colon).map(|next| next.1);
        [
            rest.get(start..end),
            next_end.and_then(|next_end| rest.get(start..next_end)),
        ]
        .into_iter()
        .flatten()
    })
}

/// A leading `START-END` sample range, if any, and the rest of the line.
fn split_samples(text: &str) -> Result<(Stamp, &str), String> {
    let digits = |s: &str| s.find(|c: char| !c.is_ascii_digit()).unwrap_or(s.len());
    let first = digits(text);
    let Some(after_dash) = text.get(first..).and_then(|rest| rest.strip_prefix('-')) else {
        return Ok((Stamp::None, text));
    };
    let second = digits(after_dash);
    let (Some(start), Some(end), Some(rest)) = (text.get(..first), after_dash.get(..second), after_dash.get(second..))
    else {
        return Ok((Stamp::None, text));
    };
    let separated = rest.is_empty() || rest.starts_with(|c: char| c.is_whitespace() || matches!(c, ',' | ';' | ':'));
    if start.is_empty() || end.is_empty() || !separated {
        return Ok((Stamp::None, text));
    }
    let number = |s: &str| s.parse::<u64>().map_err(|_| format!("sample number {s} too large"));
    let rest = rest.trim_start_matches(|c: char| c.is_whitespace() || matches!(c, ',' | ';' | ':'));
    Ok((Stamp::Samples(number(start)?, number(end)?), rest))
}

/// One line of sigrok-cli's `--protocol-decoder-jsontrace` output.
fn parse_trace_event(text: &str) -> Result<Option<Annotation>, String> {
    if text.starts_with("{\"traceEvents\"") || text.starts_with(']') {
        return Ok(None);
    }
    let body = text.strip_suffix(',').unwrap_or(text);
    let value: serde_json::Value = serde_json::from_str(body).map_err(|_| "not a trace event".to_string())?;
    if value.get("ph").and_then(serde_json::Value::as_str) != Some("B") {
        // End events repeat the begin event's text.
        return if value.get("ph").is_some() {
            Ok(None)
        } else {
            Err("trace event without a phase".into())
        };
    }
    let name = value
        .get("name")
        .and_then(serde_json::Value::as_str)
        .unwrap_or_default();
    let event = parse_text(name).ok_or("trace event that is not an I2C annotation")?;
    let micros = value
        .get("ts")
        .and_then(serde_json::Value::as_f64)
        .filter(|ts| ts.is_finite())
        .ok_or("trace event without a time")?;
    Ok(Some(Annotation {
        event,
        stamp: Stamp::Seconds(micros / 1e6),
    }))
}

/// The event an annotation text stands for, if it is one of the I2C decoder's (longest) texts.
fn parse_text(text: &str) -> Option<Event> {
    let lower = text.trim().to_ascii_lowercase();
    let event = match lower.as_str() {
        "start" => Event::Start,
        "start repeat" => Event::RepeatStart,
        "stop" => Event::Stop,
        "ack" => Event::Ack,
        "nack" => Event::Nack,
        "read" | "write" | "0" | "1" => Event::Ignored,
        _ => {
            let (head, value) = lower.split_once(':')?;
            let value = value.trim();
            let value = value.strip_prefix("0x").unwrap_or(value);
            if value.is_empty() || value.len() > 2 || !value.bytes().all(|b| b.is_ascii_hexdigit()) {
                return None;
            }
            let value = u8::from_str_radix(value, 16).ok()?;
            match head.trim() {
                "address read" => Event::Address { read: true, value },
                "address write" => Event::Address { read: false, value },
                "data read" => Event::Data {
                    read: true,
                    byte: value,
                },
                "data write" => Event::Data {
                    read: false,
                    byte: value,
                },
                _ => return None,
            }
        }
    };
    Some(event)
}

/// A moment: the sample number and / or the time in seconds, whichever the export gives.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct When {
    sample: Option<u64>,
    seconds: Option<f64>,
}

/// Data bytes kept of one transfer: a thruster message has at most 7; a longer transfer is shown cut, so that
/// memory stays bounded whatever the capture holds.
pub const MAX_TRANSFER_BYTES: usize = 64;

/// One transfer being put together: address, direction, data bytes and their acknowledges. Its size is bounded:
/// the first [`MAX_TRANSFER_BYTES`] data bytes, counts for the rest, at most one problem of each kind.
#[derive(Debug, Clone, Default)]
struct Transfer {
    start: When,
    end: When,
    address: u8,
    read: bool,
    /// The address byte's acknowledge; `None` when the capture stops before it.
    address_ack: Option<bool>,
    /// The first data bytes.
    bytes: Vec<u8>,
    /// Data bytes in all.
    count: u64,
    /// The last data byte has had no ACK or NACK yet.
    awaiting_ack: bool,
    /// The first data byte that the receiver NACKed.
    first_nack: Option<u64>,
    /// Data bytes that went the other way from the address's R/W bit: how many, and the first one.
    wrong_way: (u64, u8),
    /// How the transfer ended, when it did not end well.
    problems: Vec<String>,
}

/// Groups annotations into transfers.
#[derive(Debug, Default)]
struct Assembler {
    unshifted: bool,
    samplerate: Option<f64>,
    current: Option<Transfer>,
    /// A START whose address has not come yet.
    pending_start: Option<When>,
}

impl Assembler {
    fn when(&self, stamp: Stamp) -> (When, When) {
        match stamp {
            Stamp::None => (When::default(), When::default()),
            Stamp::Seconds(seconds) => {
                let when = When {
                    sample: None,
                    seconds: Some(seconds),
                };
                (when, when)
            }
            Stamp::Samples(start, end) => {
                let at = |sample: u64| When {
                    sample: Some(sample),
                    seconds: self.samplerate.map(|rate| sample as f64 / rate),
                };
                (at(start), at(end))
            }
        }
    }

    /// Take one annotation; returns the transfer it ends, if any, or why the annotation makes no sense here.
    fn feed(&mut self, annotation: Annotation) -> Result<Option<Transfer>, String> {
        let (start, end) = self.when(annotation.stamp);
        match annotation.event {
            Event::Ignored => Ok(None),
            Event::Start | Event::RepeatStart => {
                let finished = self.current.take().map(|mut transfer| {
                    if annotation.event == Event::Start {
                        transfer.problems.push("no STOP before the next START".into());
                    }
                    transfer.end = start;
                    transfer
                });
                self.pending_start = Some(start);
                Ok(finished)
            }
            Event::Stop => {
                self.pending_start = None;
                Ok(self.current.take().map(|mut transfer| {
                    transfer.end = end;
                    transfer
                }))
            }
            Event::Address { read, value } => {
                let address = if self.unshifted { value >> 1 } else { value };
                if address > 0x7F {
                    return Err(format!(
                        "address {value:#04x} is not a 7-bit address (10-bit addressing is not read; an unshifted \
                         export needs --unshifted)"
                    ));
                }
                let finished = self.current.take().map(|mut transfer| {
                    transfer
                        .problems
                        .push("no STOP or repeated START before the next address".into());
                    transfer
                });
                self.current = Some(Transfer {
                    start: self.pending_start.take().unwrap_or(start),
                    end,
                    address,
                    read,
                    ..Transfer::default()
                });
                Ok(finished)
            }
            Event::Ack | Event::Nack => {
                let ack = annotation.event == Event::Ack;
                let Some(transfer) = self.current.as_mut() else {
                    return Err(format!("{} outside a transfer", if ack { "ACK" } else { "NACK" }));
                };
                transfer.end = end;
                if transfer.count == 0 && transfer.address_ack.is_none() {
                    transfer.address_ack = Some(ack);
                    return Ok(None);
                }
                if !transfer.awaiting_ack {
                    return Err(format!("{} with no byte before it", if ack { "ACK" } else { "NACK" }));
                }
                transfer.awaiting_ack = false;
                if !ack && transfer.first_nack.is_none() {
                    transfer.first_nack = Some(transfer.count - 1);
                }
                Ok(None)
            }
            Event::Data { read, byte } => {
                let Some(transfer) = self.current.as_mut() else {
                    return Err(format!(
                        "data byte {byte:02X} outside a transfer (does the capture start in the middle of one?)"
                    ));
                };
                if read != transfer.read {
                    if transfer.wrong_way.0 == 0 {
                        transfer.wrong_way.1 = byte;
                    }
                    transfer.wrong_way.0 += 1;
                }
                transfer.end = end;
                if transfer.bytes.len() < MAX_TRANSFER_BYTES {
                    transfer.bytes.push(byte);
                }
                transfer.count += 1;
                transfer.awaiting_ack = true;
                Ok(None)
            }
        }
    }

    /// The transfer still open at the end of the input.
    fn finish(&mut self) -> Option<Transfer> {
        self.current.take().map(|mut transfer| {
            transfer.problems.push("the capture ends before the STOP".into());
            transfer
        })
    }
}

/// What kind of transfer a record is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Default)]
#[serde(rename_all = "lowercase")]
enum Kind {
    Order,
    Status,
    #[default]
    Other,
}

/// One transfer as printed: the JSON object, and the source of the human line.
#[derive(Debug, Default, Serialize)]
struct Record {
    /// Start (START condition) in seconds from the start of the capture; null when the export gives no time.
    time: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    sample: Option<u64>,
    /// Transfer number, from 0.
    index: u64,
    /// 7-bit address.
    address: u8,
    direction: &'static str,
    /// Whether a device acknowledged the address; null when the capture stops before.
    ack: Option<bool>,
    bytes: Vec<u8>,
    family: Option<&'static str>,
    kind: Kind,
    #[serde(skip_serializing_if = "Option::is_none")]
    device: Option<&'static str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    mux_channels: Option<Vec<u8>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    speed_step: Option<i8>,
    /// Brushless reading of the speed (full scale 4500 rpm; IDS 8.3.2).
    #[serde(skip_serializing_if = "Option::is_none")]
    speed_rpm: Option<i32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    info: Option<u8>,
    #[serde(skip_serializing_if = "Option::is_none")]
    revision: Option<u8>,
    #[serde(skip_serializing_if = "Option::is_none")]
    motor: Option<&'static str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    current_limited: Option<bool>,
    #[serde(skip_serializing_if = "Option::is_none")]
    faults: Option<Vec<&'static str>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    current_a: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    temperature_c: Option<u8>,
    /// Legacy brushed status: the power set into the motor, as a speed step.
    #[serde(skip_serializing_if = "Option::is_none")]
    power_step: Option<i8>,
    /// Legacy status: the MAX POWER byte as received.
    #[serde(skip_serializing_if = "Option::is_none")]
    max_power: Option<u8>,
    /// Whether CSUM matches the bytes before it; null when there is no thruster message of the right length.
    checksum_ok: Option<bool>,
    /// A status in the implied-type form (MT taken as the address byte: 6 SeaBotix bytes, 3 Legacy, read alone or
    /// followed by an idle byte): "implied-type"; absent for the full form.
    #[serde(skip_serializing_if = "Option::is_none")]
    form: Option<&'static str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<String>,
    /// Seconds since the previous transfer started (any address).
    since_prev_s: Option<f64>,
    /// Seconds since the previous transfer to the same address started.
    since_prev_same_address_s: Option<f64>,
    /// Seconds from START to STOP (or to the repeated START that ends it).
    duration_s: Option<f64>,
}

/// The TCA9548A I2C multiplexer's address range.
const MUX_ADDRESSES: std::ops::RangeInclusive<u8> = 0x70..=0x77;

/// Build the record of a finished transfer.
fn record(transfer: Transfer, index: u64) -> Record {
    let mut record = Record {
        time: transfer.start.seconds,
        sample: transfer.start.sample,
        index,
        address: transfer.address,
        direction: if transfer.read { "read" } else { "write" },
        ack: transfer.address_ack,
        family: Family::from_address(transfer.address).map(Family::name),
        duration_s: transfer
            .start
            .seconds
            .zip(transfer.end.seconds)
            .map(|(start, end)| round_ns(end - start)),
        ..Record::default()
    };
    let mut problems = Vec::new();
    match transfer.wrong_way {
        (0, _) => {}
        (1, byte) => problems.push(format!(
            "data byte {byte:02X} goes the other way from the address's R/W bit"
        )),
        (n, byte) => problems.push(format!(
            "{n} data bytes go the other way from the address's R/W bit, the first {byte:02X}"
        )),
    }
    problems.extend(transfer.problems);
    if !transfer.read
        && let Some(at) = transfer.first_nack
        && at + 1 < transfer.count
    {
        problems.push(format!("the slave NACKed data byte {at} and the master wrote on"));
    }
    if transfer.count > MAX_TRANSFER_BYTES as u64 {
        problems.push(format!(
            "{} data bytes, the first {MAX_TRANSFER_BYTES} shown",
            transfer.count
        ));
    }
    let bytes = transfer.bytes;
    match Family::from_address(transfer.address) {
        Some(family) if transfer.address_ack != Some(false) => {
            if transfer.read {
                decode_status(&mut record, family, &bytes);
            } else {
                decode_order(&mut record, family, &bytes);
            }
        }
        Some(_) => record.kind = if transfer.read { Kind::Status } else { Kind::Order },
        None => {
            if MUX_ADDRESSES.contains(&transfer.address) {
                record.device = Some("TCA9548A mux");
                if let [mask] = bytes[..] {
                    record.mux_channels = Some((0..8).filter(|bit| mask & (1 << bit) != 0).collect());
                }
            }
        }
    }
    if transfer.address_ack == Some(false) {
        problems.insert(0, nack_text(record.family.is_some()).into());
    }
    if let Some(error) = record.error.take() {
        problems.insert(0, error);
    }
    if !problems.is_empty() {
        record.error = Some(problems.join("; "));
    }
    record.bytes = bytes;
    record
}

/// The error of a transfer whose address no device acknowledged.
fn nack_text(thruster: bool) -> &'static str {
    if thruster {
        "address NACKed: no thruster answered"
    } else {
        "address NACKed: no device answered"
    }
}

/// Round a duration to the nanosecond, so differences of sample times print short.
fn round_ns(seconds: f64) -> f64 {
    (seconds * 1e9).round() / 1e9
}

/// Whether the last byte is the checksum of the others, for a message of the expected length.
fn checksum_verdict(bytes: &[u8], expected_len: usize) -> Option<bool> {
    match bytes.split_last() {
        Some((csum, body)) if bytes.len() == expected_len => Some(checksum(body) == *csum),
        _ => None,
    }
}

/// An order to a thruster: decoded with `tmc-proto`; when that fails, the fields are still read where the layout
/// allows (right length and message type), so a bad checksum shows what was sent.
fn decode_order(record: &mut Record, family: Family, bytes: &[u8]) {
    record.kind = Kind::Order;
    record.checksum_ok = checksum_verdict(bytes, ORDER_LEN);
    match Order::decode(family, bytes) {
        Ok(order) => set_order(record, Some(order.speed), order.info),
        Err(error) => {
            record.error = Some(error.to_string());
            if let [mt, speed, info, _] = bytes[..]
                && mt == family.order_type()
            {
                set_order(record, Speed::from_byte(speed).ok(), info);
            }
        }
    }
}

fn set_order(record: &mut Record, speed: Option<Speed>, info: u8) {
    record.speed_step = speed.map(Speed::step);
    record.speed_rpm = speed.map(Speed::rpm);
    record.info = Some(info);
}

/// A status from a thruster: decoded with `tmc-proto` in the full form, else in the implied-type form (read as
/// the frame alone, or as the full length with an idle byte after it, as this project's master reads it); when
/// neither decodes, read again with the checksum (and an out-of-range speed byte) mended, so every field that can
/// be read is shown.
fn decode_status(record: &mut Record, family: Family, bytes: &[u8]) {
    record.kind = Kind::Status;
    record.checksum_ok = checksum_verdict(bytes, family.status_len());
    let padded: Vec<u8> = if bytes.len() + 1 == family.status_len() {
        bytes.iter().copied().chain([0xFF]).collect()
    } else {
        bytes.to_vec()
    };
    let decoded = match (Status::decode(family, bytes), Status::decode_implied(family, &padded)) {
        (Ok(decoded), _) | (Err(_), Ok(decoded)) => {
            if Status::decode(family, bytes).is_err() {
                record.form = Some("implied-type");
                record.checksum_ok = Some(true);
            }
            record.error = decoded.warning.map(|warning| warning.to_string());
            Some((decoded.status, decoded.warning.is_none()))
        }
        (Err(error), Err(_)) => {
            record.error = Some(error.to_string());
            salvage_status(family, bytes)
        }
    };
    if let Some((status, speed_read)) = decoded {
        set_status(record, status, speed_read);
        if family == Family::Legacy {
            // As received, even when the speed it holds was out of range.
            let at = if record.form.is_some() { 1 } else { 2 };
            record.max_power = bytes.get(at).copied();
        }
    }
}

/// The status as far as it can be read: right length and message type needed; the checksum is mended (the second
/// value says whether the speed could be read).
fn salvage_status(family: Family, bytes: &[u8]) -> Option<(Status, bool)> {
    if bytes.len() != family.status_len() || bytes.first() != Some(&family.status_type()) {
        return None;
    }
    let mut mended = bytes.to_vec();
    let mend = |mended: &mut Vec<u8>| {
        if let Some((csum, body)) = mended.split_last_mut() {
            *csum = checksum(body);
        }
    };
    mend(&mut mended);
    // An out-of-range speed byte is read as zero by tmc-proto, with a warning: the speed could not be read.
    Status::decode(family, &mended)
        .ok()
        .map(|decoded| (decoded.status, decoded.warning.is_none()))
}

fn motor_name(motor: MotorKind) -> &'static str {
    match motor {
        MotorKind::Brushless => "brushless",
        MotorKind::Brushed => "brushed",
    }
}

fn fault_names(faults: Faults) -> Vec<&'static str> {
    faults.iter().map(Faults::name).collect()
}

fn set_status(record: &mut Record, status: Status, speed_read: bool) {
    record.faults = Some(fault_names(status.faults()));
    match status {
        Status::SeaBotix(status) => {
            record.revision = Some(status.revision);
            record.motor = Some(motor_name(status.motor));
            record.current_limited = Some(status.current_limited);
            record.current_a = Some(f64::from(status.current_deciamps) / 10.0);
            if speed_read {
                record.speed_step = Some(status.speed.step());
                // Brushed controllers report a PWM value, not a speed.
                record.speed_rpm = (status.motor == MotorKind::Brushless).then(|| status.speed.rpm());
            }
            record.temperature_c = Some(status.temperature_c);
        }
        Status::Legacy(status) => {
            record.revision = Some(status.revision.number());
            record.motor = status.revision.motor_kind().map(motor_name);
            match status.max_power {
                MaxPower::Current { deciamps } => record.current_a = Some(f64::from(deciamps) / 10.0),
                MaxPower::Power(speed) => record.power_step = speed_read.then(|| speed.step()),
                MaxPower::Raw(_) => {}
            }
        }
    }
}

/// A signed speed step: `+51`, `-20`, `0`.
fn step_text(step: i8) -> String {
    if step == 0 { "0".into() } else { format!("{step:+}") }
}

fn millis_text(seconds: f64) -> String {
    format!("+{:.3} ms", seconds * 1e3)
}

/// The human line of a record.
fn human(record: &Record) -> String {
    let mut words: Vec<String> = Vec::new();
    words.push(match (record.time, record.sample) {
        (Some(time), _) => format!("{time:.6}"),
        (None, Some(sample)) => format!("@{sample}"),
        (None, None) => format!("#{}", record.index),
    });
    if let Some(gap) = record.since_prev_s {
        words.push(millis_text(gap));
    }
    words.push(format!("0x{:02X}", record.address));
    words.push(if record.direction == "read" { "R" } else { "W" }.into());
    if record.ack == Some(false) {
        words.push(
            if record.family.is_some() {
                "NACK (no thruster)"
            } else {
                "NACK (no device)"
            }
            .into(),
        );
    } else {
        if let Some(family) = record.family {
            words.push(family.into());
        }
        words.push(
            match record.kind {
                Kind::Order => "order",
                Kind::Status => "status",
                Kind::Other => record.device.unwrap_or("other"),
            }
            .into(),
        );
        describe_fields(record, &mut words);
        if let Some(form) = record.form {
            words.push(format!("({form} form)"));
        }
        match record.checksum_ok {
            Some(true) => words.push("csum ok".into()),
            Some(false) => words.push("csum BAD".into()),
            None => {}
        }
        let hex: Vec<String> = record.bytes.iter().map(|byte| format!("{byte:02X}")).collect();
        words.push(format!("[{}]", hex.join(" ")));
    }
    let mut error = record.error.as_deref().unwrap_or_default();
    if record.ack == Some(false) {
        // The NACK is in the line already.
        error = error.trim_start_matches(nack_text(record.family.is_some()));
        error = error.trim_start_matches("; ");
    }
    if !error.is_empty() {
        words.push(format!("({error})"));
    }
    if let Some(gap) = record.since_prev_same_address_s {
        words.push(format!("| 0x{:02X} {}", record.address, millis_text(gap)));
    }
    words.join(" ")
}

/// The decoded fields, in words.
fn describe_fields(record: &Record, words: &mut Vec<String>) {
    if let Some(channels) = &record.mux_channels {
        let list: Vec<String> = channels.iter().map(u8::to_string).collect();
        let verb = if record.direction == "read" { "reads" } else { "selects" };
        words.push(match list.len() {
            0 => format!("{verb} no channel"),
            1 => format!("{verb} channel {}", list.join(",")),
            _ => format!("{verb} channels {}", list.join(",")),
        });
    }
    if let Some(faults) = &record.faults {
        let names = if faults.is_empty() {
            "none".to_string()
        } else {
            faults.join(", ")
        };
        words.push(format!("faults: {names}"));
    }
    if record.kind == Kind::Status
        && let (Some(revision), Some(motor)) = (record.revision, record.motor)
    {
        words.push(format!("rev {revision} {motor}"));
    } else if let Some(revision) = record.revision {
        words.push(format!("rev {revision}"));
    }
    if let Some(current) = record.current_a {
        words.push(format!("current {current:.1} A"));
    }
    if let Some(step) = record.speed_step {
        match record.speed_rpm {
            Some(rpm) => words.push(format!("speed {} ({rpm} rpm)", step_text(step))),
            None => words.push(format!("speed {}", step_text(step))),
        }
    }
    if let Some(step) = record.power_step {
        words.push(format!("power {}", step_text(step)));
    } else if let (Some(byte), None) = (record.max_power, record.current_a) {
        words.push(format!("max power {byte:#04x}"));
    }
    if let Some(info) = record.info {
        words.push(format!("info {info}"));
    }
    if let Some(temperature) = record.temperature_c {
        words.push(format!("temp {temperature} C"));
    }
}

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
    fn run(&mut self, input: impl BufRead, out: &mut impl Write, err: &mut impl Write) -> Result<(), Failure> {
        let mut lines = Lines::new(input, MAX_LINE);
        while let Some((number, line)) = lines.next_line().map_err(Failure::Read)? {
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
                Ok(Some(transfer)) => self.emit(transfer, out).map_err(Failure::Write)?,
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
            self.emit(transfer, out).map_err(Failure::Write)?;
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

#[cfg(test)]
mod tests {
    use super::*;

    fn event(line: &str) -> Event {
        parse_line(line).unwrap().unwrap().event
    }

    #[test]
    fn every_layout_reads_the_same_annotation() {
        let address = Event::Address {
            read: false,
            value: 0x29,
        };
        for line in [
            "i2c-1: Address write: 29",
            "35-105 i2c-1: Address write: 29",
            "35-105 i2c-1: address-write: \"Address write: 29\" \"AW: 29\" \"29\"",
            "35-105 I²C: Address/Data: Address write: 29",
            "35-105 \"I²C\": \"Address/Data\": \"Address write: 29\"",
            "35-105 \"I²C\": \"Address/data\": \"Address write: 29\",\"AW: 29\",\"29\"",
            "35-105,I²C,Address/Data,Address write: 29",
            "35-105\tI²C\taddress-write\tAddress write: 29",
            "35-105 I²C: Address/Data: Address write: 29,AW: 29,29",
            "I²C;Address/Data;Address write: 29;35",
            "35-105 I2C: ADDRESS WRITE: 0x29\r\n",
            "Address write: 29",
            "{\"ph\": \"B\", \"ts\": 35.000000, \"pid\": \"i2c-1\", \"tid\": \"Address/Data\", \"name\": \"Address write: 29\"},",
        ] {
            assert_eq!(event(line), address, "{line}");
        }
    }

    #[test]
    fn stamps() {
        assert_eq!(
            parse_line("35-105 i2c-1: Start").unwrap().unwrap().stamp,
            Stamp::Samples(35, 105)
        );
        assert_eq!(parse_line("i2c-1: Start").unwrap().unwrap().stamp, Stamp::None);
        assert_eq!(
            parse_line("{\"ph\": \"B\", \"ts\": 25.5, \"name\": \"Start\"}")
                .unwrap()
                .unwrap()
                .stamp,
            Stamp::Seconds(25.5e-6)
        );
        assert!(parse_line("99999999999999999999999-1 i2c-1: Start").is_err());
    }

    #[test]
    fn every_event() {
        assert_eq!(event("i2c-1: Start"), Event::Start);
        assert_eq!(event("i2c-1: Start repeat"), Event::RepeatStart);
        assert_eq!(event("i2c-1: Stop"), Event::Stop);
        assert_eq!(event("i2c-1: ACK"), Event::Ack);
        assert_eq!(event("i2c-1: NACK"), Event::Nack);
        assert_eq!(event("i2c-1: Read"), Event::Ignored);
        assert_eq!(event("i2c-1: Write"), Event::Ignored);
        assert_eq!(event("105-115 i2c-1: 0"), Event::Ignored);
        assert_eq!(event("105-115 i2c-1: bit: \"1\""), Event::Ignored);
        assert_eq!(event("i2c-1: Data read: 0C"), Event::Data { read: true, byte: 0x0C });
        assert_eq!(
            event("i2c-1: Data write: b3"),
            Event::Data {
                read: false,
                byte: 0xB3
            }
        );
        assert_eq!(
            event("i2c-1: Address read: 2A"),
            Event::Address {
                read: true,
                value: 0x2A
            }
        );
    }

    #[test]
    fn nothing_to_read() {
        for line in [
            "",
            "   \r\n",
            "# a comment",
            "{\"traceEvents\": [",
            "]}",
            "{\"ph\": \"E\", \"name\": \"Start\"}",
        ] {
            assert_eq!(parse_line(line), Ok(None), "{line:?}");
        }
    }

    #[test]
    fn not_annotations() {
        for line in [
            "hello",
            "i2c-1: Data write: 123",
            "i2c-1: Data write: ZZ",
            "i2c-1: Data write:",
            "i2c-1: Packet: 29",
            "uart-1: RX: 41",
            "{not json",
            "{\"ph\": \"B\", \"name\": \"Start\"}",
            "{\"ph\": \"B\", \"ts\": 1, \"name\": \"TX: 41\"}",
            "12-",
        ] {
            assert!(parse_line(line).is_err(), "{line:?}");
        }
    }

    /// Reading a line is linear in its length: on lines of separators (which once cost time cubic in their
    /// length) the annotation texts tried add up to at most three times the line.
    #[test]
    fn separator_storms_cost_linear_work() {
        for filler in [":", ",", ";", "\t", ": ", "a:", "Address write:", "x:y,"] {
            let line = filler.repeat(MAX_LINE / filler.len());
            let (count, bytes) = candidates(&line).fold((0, 0), |(n, bytes), text| (n + 1, bytes + text.len()));
            let fields = line.matches([':', ',', ';', '\t']).count() + 1;
            assert!(count <= 2 * fields, "{filler:?}: {count} candidates");
            assert!(bytes <= 3 * line.len(), "{filler:?}: {bytes} bytes tried");
            assert!(!matches!(parse_line(&line), Ok(Some(_))), "{filler:?}");
        }
        // The annotation is still found at the far end of such a line.
        let line = format!("{}Address write: 29", ":".repeat(MAX_LINE - 20));
        assert_eq!(
            event(&line),
            Event::Address {
                read: false,
                value: 0x29
            }
        );
    }

    #[test]
    fn sample_rates() {
        assert_eq!(parse_rate("1000000"), Ok(1e6));
        assert_eq!(parse_rate("1M"), Ok(1e6));
        assert_eq!(parse_rate("1MHz"), Ok(1e6));
        assert_eq!(parse_rate("24 MHz"), Ok(24e6));
        assert_eq!(parse_rate("500k"), Ok(5e5));
        assert_eq!(parse_rate("1e6"), Ok(1e6));
        assert_eq!(parse_rate("1G"), Ok(1e9));
        assert_eq!(parse_rate("1"), Ok(1.0));
        for bad in [
            "", "0", "-5", "fast", "inf", "NaN", "Hz", "M", "1e400", "0.5", "2e12", "1e-300",
        ] {
            assert!(parse_rate(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn command_line() {
        #[derive(Debug, clap::Parser)]
        struct Cli {
            #[command(flatten)]
            args: Args,
        }
        let parse = |line: &[&str]| {
            use clap::Parser as _;
            Cli::try_parse_from(std::iter::once("i2c").chain(line.iter().copied())).map(|cli| cli.args)
        };
        let args = parse(&["cap.txt", "--json", "--samplerate", "2M", "--unshifted"]).unwrap();
        assert_eq!(args.input.as_deref(), Some(std::path::Path::new("cap.txt")));
        assert!(args.json && args.unshifted);
        assert_eq!(args.samplerate, Some(2e6));
        assert_eq!(parse(&["--samplerate=4k"]).unwrap().samplerate, Some(4e3));
        assert_eq!(parse(&["-"]).unwrap().input.as_deref(), Some(std::path::Path::new("-")));
        for bad in [
            &["--samplerate"][..],
            &["--frobnicate"],
            &["a", "b"],
            &["--samplerate", "0"],
        ] {
            assert!(parse(bad).is_err(), "{bad:?}");
        }
    }

    fn records(text: &str, samplerate: Option<f64>) -> (Vec<serde_json::Value>, String) {
        let args = Args {
            json: true,
            samplerate,
            ..Args::default()
        };
        let (mut out, mut err) = (Vec::new(), Vec::new());
        run(text.as_bytes(), &mut out, &mut err, &args).unwrap();
        let records = String::from_utf8(out)
            .unwrap()
            .lines()
            .map(|line| serde_json::from_str(line).unwrap())
            .collect();
        (records, String::from_utf8(err).unwrap())
    }

    /// sigrok's annotations of one read from 7-bit `address` of `bytes`, starting at sample `at`.
    fn read_annotations(at: u64, address: u8, bytes: &[u8]) -> String {
        let mut lines = vec![
            format!("{at}-{at} i2c-1: Start"),
            format!("{}-{} i2c-1: Address read: {address:02X}", at + 10, at + 80),
        ];
        let mut t = at + 90;
        lines.push(format!("{t}-{} i2c-1: ACK", t + 10));
        for (n, byte) in bytes.iter().enumerate() {
            t += 10;
            lines.push(format!("{t}-{} i2c-1: Data read: {byte:02X}", t + 80));
            t += 90;
            let ack = if n + 1 == bytes.len() { "NACK" } else { "ACK" };
            lines.push(format!("{t}-{} i2c-1: {ack}", t + 10));
        }
        lines.push(format!("{}-{} i2c-1: Stop", t + 20, t + 20));
        lines.join("\n") + "\n"
    }

    #[test]
    fn a_status_in_the_implied_type_form_is_read_and_named() {
        let status = tmc_proto::Status::SeaBotix(tmc_proto::SeaBotixStatus {
            revision: 0,
            motor: MotorKind::Brushless,
            current_limited: true,
            faults: Faults::WATER,
            current_deciamps: 25,
            speed: Speed::new(20).unwrap(),
            temperature_c: 33,
        });
        let full = status.encode();
        let full = full.as_bytes();
        let frame = &full[1..];
        let with_idle: Vec<u8> = frame.iter().copied().chain([0xFF]).collect();
        let text = read_annotations(0, 0x29, full)
            + &read_annotations(2000, 0x29, frame)
            + &read_annotations(4000, 0x29, &with_idle);
        let (records, err) = records(&text, None);
        assert_eq!(records.len(), 3, "{err}");
        for (record, form) in
            records
                .iter()
                .zip([serde_json::Value::Null, "implied-type".into(), "implied-type".into()])
        {
            assert_eq!(record["kind"], "status");
            assert_eq!(record["faults"], serde_json::json!(["water detect"]), "{record}");
            assert_eq!(record["current_a"], 2.5);
            assert_eq!(record["temperature_c"], 33);
            assert_eq!(record["checksum_ok"], true);
            assert_eq!(record.get("form").cloned().unwrap_or_default(), form, "{record}");
        }
    }

    #[test]
    fn order_status_and_gaps() {
        let text = "\
10-10 i2c-1: Start
20-90 i2c-1: Address write: 29
90-100 i2c-1: ACK
100-180 i2c-1: Data write: 52
180-190 i2c-1: ACK
190-270 i2c-1: Data write: B3
270-280 i2c-1: ACK
280-360 i2c-1: Data write: 64
360-370 i2c-1: ACK
370-450 i2c-1: Data write: 69
450-460 i2c-1: ACK
470-470 i2c-1: Stop
1010-1010 i2c-1: Start
1020-1090 i2c-1: Address read: 2A
1090-1100 i2c-1: ACK
1100-1180 i2c-1: Data read: 55
1180-1190 i2c-1: ACK
1190-1270 i2c-1: Data read: 20
1270-1280 i2c-1: ACK
1280-1360 i2c-1: Data read: 22
1360-1370 i2c-1: ACK
1370-1450 i2c-1: Data read: 97
1450-1460 i2c-1: NACK
1470-1470 i2c-1: Stop
";
        let (records, err) = records(text, Some(1e6));
        assert_eq!(records.len(), 2, "{err}");
        let order = &records[0];
        assert_eq!(order["time"], 10e-6);
        assert_eq!(order["address"], 0x29);
        assert_eq!(order["direction"], "write");
        assert_eq!(order["kind"], "order");
        assert_eq!(order["family"], "SeaBotix");
        assert_eq!(order["speed_step"], 51);
        assert_eq!(order["speed_rpm"], 2250);
        assert_eq!(order["info"], 100);
        assert_eq!(order["checksum_ok"], true);
        assert_eq!(order["duration_s"], 460e-6);
        assert_eq!(order["since_prev_s"], serde_json::Value::Null);
        let status = &records[1];
        assert_eq!(status["family"], "Legacy");
        assert_eq!(status["kind"], "status");
        assert_eq!(status["revision"], 1);
        assert_eq!(status["motor"], "brushless");
        assert_eq!(status["current_a"], 3.4);
        assert_eq!(status["faults"], serde_json::json!([]));
        assert_eq!(status["checksum_ok"], true);
        assert_eq!(status["since_prev_s"], 1000e-6);
        assert_eq!(status["since_prev_same_address_s"], serde_json::Value::Null);
        assert!(err.contains("0 lines skipped"), "{err}");
    }

    #[test]
    fn repeated_start_splits_and_orphans_are_skipped() {
        let text = "\
i2c-1: Data write: 01
i2c-1: ACK
i2c-1: Start
i2c-1: Address write: 70
i2c-1: ACK
i2c-1: Data write: 04
i2c-1: ACK
i2c-1: Start repeat
i2c-1: Address read: 70
i2c-1: ACK
i2c-1: Data read: 04
i2c-1: NACK
i2c-1: Stop
garbage
i2c-1: Start
i2c-1: Address write: 2A
i2c-1: NACK
i2c-1: Stop
i2c-1: Start
i2c-1: Address read: 29
i2c-1: ACK
i2c-1: Data read: 53
";
        let (records, err) = records(text, None);
        assert_eq!(records.len(), 4, "{err}");
        assert_eq!(records[0]["device"], "TCA9548A mux");
        assert_eq!(records[0]["mux_channels"], serde_json::json!([2]));
        assert_eq!(records[0]["kind"], "other");
        assert_eq!(records[0]["time"], serde_json::Value::Null);
        assert_eq!(records[1]["direction"], "read");
        assert_eq!(records[1]["mux_channels"], serde_json::json!([2]));
        assert_eq!(records[2]["ack"], false);
        assert_eq!(records[2]["family"], "Legacy");
        assert!(records[2]["error"].as_str().unwrap().contains("no thruster"));
        assert_eq!(records[3]["bytes"], serde_json::json!([0x53]));
        assert!(records[3]["error"].as_str().unwrap().contains("before the STOP"));
        assert_eq!(records[3]["checksum_ok"], serde_json::Value::Null);
        for line in ["line 1:", "line 2:", "line 14:"] {
            assert!(err.contains(line), "{line} in {err}");
        }
        assert!(err.contains("3 lines skipped"), "{err}");
    }

    #[test]
    fn bad_checksum_still_shows_the_fields() {
        let (records, _) = records(
            "i2c-1: Start\ni2c-1: Address write: 29\ni2c-1: ACK\ni2c-1: Data write: 52\ni2c-1: ACK\n\
             i2c-1: Data write: 8A\ni2c-1: ACK\ni2c-1: Data write: 64\ni2c-1: ACK\ni2c-1: Data write: 41\n\
             i2c-1: ACK\ni2c-1: Stop\n",
            None,
        );
        let order = &records[0];
        assert_eq!(order["checksum_ok"], false);
        assert_eq!(order["speed_step"], 10);
        assert_eq!(order["info"], 100);
        assert_eq!(order["error"], "bad checksum: computed 0x40, received 0x41");
    }

    #[test]
    fn status_salvage() {
        // SeaBotix status, speed byte 0x05 out of range and a bad checksum: the rest is still read.
        let bytes = [0x53, 0x02, 0x10, 12, 0x05, 21, 0x00];
        let mut record = Record::default();
        decode_status(&mut record, Family::SeaBotix, &bytes);
        assert_eq!(record.checksum_ok, Some(false));
        assert_eq!(record.speed_step, None);
        assert_eq!(record.faults, Some(vec!["water detect"]));
        assert_eq!(record.temperature_c, Some(21));
        assert_eq!(record.current_a, Some(1.2));
        // Wrong message type: nothing to read.
        let mut record = Record::default();
        decode_status(&mut record, Family::SeaBotix, &[0xFF; 7]);
        assert_eq!(record.faults, None);
        assert!(record.error.unwrap().contains("message type"));
        let mut record = Record::default();
        decode_status(&mut record, Family::Legacy, &[0xFF; 4]);
        assert_eq!((record.faults, record.max_power), (None, None));
        // Legacy brushed, power byte out of range.
        let mut record = Record::default();
        decode_status(&mut record, Family::Legacy, &[0x55, 0x40, 0x05, 0x9A]);
        assert_eq!(record.motor, Some("brushed"));
        assert_eq!(record.power_step, None);
        assert_eq!(record.max_power, Some(0x05));
        assert_eq!(record.checksum_ok, Some(true));
    }

    #[test]
    fn human_lines() {
        let mut decoder = Decoder::new(&Args::default());
        let (mut out, mut err) = (Vec::new(), Vec::new());
        let text = "\
0-0 i2c-1: Start
1-2 i2c-1: Address write: 29
2-3 i2c-1: ACK
3-4 i2c-1: Data write: 52
4-5 i2c-1: ACK
5-6 i2c-1: Data write: B3
6-7 i2c-1: ACK
7-8 i2c-1: Data write: 64
8-9 i2c-1: ACK
9-10 i2c-1: Data write: 69
10-11 i2c-1: ACK
12-12 i2c-1: Stop
900-900 i2c-1: Start
901-902 i2c-1: Address write: 29
902-903 i2c-1: NACK
904-904 i2c-1: Stop
";
        decoder.run(text.as_bytes(), &mut out, &mut err).unwrap();
        let out = String::from_utf8(out).unwrap();
        let lines: Vec<&str> = out.lines().collect();
        assert_eq!(
            lines[0],
            "@0 0x29 W SeaBotix order speed +51 (2250 rpm) info 100 csum ok [52 B3 64 69]"
        );
        assert_eq!(lines[1], "@900 0x29 W NACK (no thruster)");
    }

    fn feed(assembler: &mut Assembler, event: Event) -> Option<Transfer> {
        assembler
            .feed(Annotation {
                event,
                stamp: Stamp::None,
            })
            .unwrap_or(None)
    }

    /// A transfer that never ends, with data going the wrong way and every byte NACKed, keeps a bounded size.
    #[test]
    fn an_endless_transfer_keeps_bounded_state() {
        let mut assembler = Assembler::default();
        feed(&mut assembler, Event::Start);
        feed(
            &mut assembler,
            Event::Address {
                read: false,
                value: 0x29,
            },
        );
        feed(&mut assembler, Event::Ack);
        for i in 0..200_000u32 {
            let byte = i as u8;
            feed(&mut assembler, Event::Data { read: i % 2 == 0, byte });
            feed(&mut assembler, Event::Nack);
        }
        let transfer = assembler.current.as_ref().unwrap();
        assert_eq!(transfer.bytes.len(), MAX_TRANSFER_BYTES);
        assert_eq!(transfer.count, 200_000);
        assert!(transfer.problems.is_empty());
        let transfer = assembler.finish().unwrap();
        let record = record(transfer, 0);
        assert_eq!(record.bytes.len(), MAX_TRANSFER_BYTES);
        let error = record.error.unwrap();
        for says in [
            "100000 data bytes go the other way from the address's R/W bit, the first 00",
            "the capture ends before the STOP",
            "the slave NACKed data byte 0 and the master wrote on",
            "200000 data bytes, the first 64 shown",
        ] {
            assert!(error.contains(says), "{says:?} in {error}");
        }
        assert!(error.len() < 400, "{error}");
    }

    /// Starts and addresses with no STOP: every transfer is printed as it ends, none is kept.
    #[test]
    fn transfers_without_a_stop_are_not_kept() {
        let mut assembler = Assembler::default();
        let mut printed = 0;
        for i in 0..10_000u32 {
            let event = match i % 3 {
                0 => Event::Start,
                1 => Event::Address {
                    read: true,
                    value: 0x2A,
                },
                _ => Event::Data { read: true, byte: 0x55 },
            };
            printed += usize::from(feed(&mut assembler, event).is_some());
        }
        assert_eq!(printed, 3333);
        assert!(assembler.current.as_ref().map_or(0, |t| t.bytes.len()) <= 1);
    }
}
