//! `lbv decode can`: candump logs of the BAT board's CAN frames, decoded with bat-proto.
//!
//! Input: the log format that `candump -l` writes (and `candump -L` prints), one frame a line:
//! `(1700000000.123456) can0 620#A401E7FF3A00D700`, optionally followed by the ` R` / ` T` direction of
//! `candump -x`. Carriage returns (CRLF files) and blank lines are accepted; the `DROPCOUNT: ...` lines that
//! candump writes when the kernel dropped frames are passed on to standard error as a note.
//!
//! What each well-formed line becomes:
//! - a classic data frame with a standard ID that bat-proto knows (0x620 info, 0x629 status, 0x628 BMS alarms)
//!   is decoded and printed;
//! - such a frame that bat-proto rejects (a length other than 8) is printed in place as a decode error with its
//!   line number, and counted: it is a good log line carrying a bad frame (a charge above 100 % is one bad field:
//!   `charge_pct` is `null` and the frame's other fields are printed);
//! - every other frame (other IDs, remote requests such as `620#R`, CAN FD `620##0...`, extended IDs, error
//!   frames, CAN XL) is not a BAT data frame: it is left out of the output and only counted in the summary, so a
//!   busy shared bus does not drown the battery's frames.
//!
//! A line that is not a candump log line (garbage, truncated, odd or non-hex digits, more than 8 data bytes on
//! classic CAN, longer than [`MAX_LINE`]) is a bad line: it gets a message on standard error with its number
//! (the first [`MAX_MESSAGES`] of them; all are counted) and is skipped. At the end a summary on standard error
//! says how many lines were read, decoded, ignored and skipped. Exit status: 0 when every line was good, 1 when
//! lines were skipped or BAT frames did not decode (the output is complete all the same), 2 when the input
//! could not be read or the command line is wrong.
//!
//! Status reports mirror the master's battery monitor: the first 0x629 frame on an interface reports every one
//! of the 12 bits in words (start-up report), later ones the bits that switched since the previous frame on that
//! interface (change report); BMS alarms already set in the first 0x628 frame count as raised. The boards of at
//! most [`MAX_INTERFACES`] interfaces are remembered, so that memory stays bounded on any log.
//!
//! Human output, one line per BAT frame (`C` is degrees Celsius; a current or temperature that the frame does
//! not report, sent as 0, is left out):
//!
//! ```text
//! 1700000000.123456 0x620 info 42.0 V -2.5 A 58 % 21.5 C
//! 1700000000.223456 0x629 status 0x00ac HSM_PG HSM V12motor V12board; start-up: HSM_broken=0 (normal), ...
//! 1700000000.423456 0x629 status 0x00ae HSM_F HSM_PG HSM V12motor V12board; changed: HSM_F=1 (hot swap ...)
//! 1700000000.523456 0x628 bms alarms 0x01 low voltage; raised: low voltage
//! 1700000000.623456 0x620 error (line 7): BAT frame 0x620 has 4 data bytes, expected 8
//! ```
//!
//! `--json`: one object per line. `time` is the log's time in seconds, as a number with the log's digits (less
//! the leading zeros candump pads it with, which JSON forbids); `id` is the CAN ID as a number (1568 = 0x620).
//! Info: `voltage_v`, `current_a`, `charge_pct`, `temperature_c` (`null` when not reported, or out of range). Status: `status` (the combined 16-bit word), `status_bits`
//! (the bat-proto names of the bits set, in bit order), `changed` (names of the bits that switched; `[]` on the
//! first status frame, which has nothing to compare with). BMS: `alarms` (byte 0, bits 0-6), `alarm_bits` (the
//! alarms set, in bat-proto's words), `changed` (alarms raised or cleared). A frame that did not decode:
//! `line` and `error`.
//!
//! ```text
//! {"time":1700000000.123456,"id":1568,"voltage_v":42.0,"current_a":-2.5,"charge_pct":58,"temperature_c":21.5}
//! {"time":1700000000.223456,"id":1577,"status":172,"status_bits":["HSM_PG","HSM","V12motor","V12board"],"changed":[]}
//! {"time":1700000000.523456,"id":1576,"alarms":1,"alarm_bits":["low voltage"],"changed":["low voltage"]}
//! {"time":1700000000.623456,"id":1568,"line":7,"error":"BAT frame 0x620 has 4 data bytes, expected 8"}
//! ```
//!
//! The same frames are described for other CAN tools (cantools, SavvyCAN) by `lbv/dbc/bat.dbc`.

use std::io::{self, BufRead, BufWriter, Write};
use std::path::PathBuf;
use std::process::ExitCode;

use bat_proto::{BatteryInfo, BmsAlarms, DcdcStatus, DecodeError, Frame, StatusBit};

use super::StreamError;
use crate::exit;
use crate::lines::{Line as InputLine, Lines};

/// Longest line read whole. candump's longest line, a CAN XL frame of 2048 bytes, is about 4200 bytes.
pub const MAX_LINE: usize = 8192;
/// Bad lines reported one by one on standard error; the summary counts them all.
pub const MAX_MESSAGES: u64 = 100;
/// Interfaces whose BAT board is remembered for the change reports; past this many, the one heard from least
/// recently is forgotten (its next status is reported as a start-up again), so memory stays bounded.
pub const MAX_INTERFACES: usize = 64;
/// Output is built in memory and written in chunks of about this size.
const OUT_CHUNK: usize = 64 * 1024;
/// The error-frame flag in an 8-digit candump ID.
const CAN_ERR_FLAG: u32 = 0x2000_0000;

const HELP: &str = "\
Reads candump logs (`candump -l`: `(TIME) IFACE ID#DATA`) and decodes the BAT board's 0x620 info,
0x629 status (every bit in words at an interface's first frame, then the bits that switched) and
0x628 BMS alarms with bat-proto, one line per frame; other frames are counted, not printed. Bad
lines (and lines over 8192 bytes) are reported on standard error with their number and skipped. A
summary goes to standard error.

Exit status: 0 every line read and every BAT frame decoded; 1 lines were skipped or BAT frames did
not decode (the output is complete all the same); 2 bad command line, or the input cannot be read
or the output written.";

/// `lbv decode can`'s command line.
#[derive(Debug, Default, clap::Args)]
#[command(after_help = HELP)]
pub struct Args {
    /// The candump log; standard input when - or absent
    #[arg(value_name = "FILE")]
    pub input: Option<PathBuf>,
    /// One object per frame: time, id, voltage_v, current_a, charge_pct, temperature_c, status, status_bits,
    /// changed, alarms, alarm_bits; a frame that did not decode: line and error
    #[arg(long)]
    pub json: bool,
}

/// `lbv decode can [FILE|-] [--json]`
pub fn main(args: &Args) -> ExitCode {
    let (input, name) = match super::open(args.input.as_deref()) {
        Ok(input) => input,
        Err(message) => {
            eprintln!("lbv decode can: {message}");
            return ExitCode::from(exit::TROUBLE);
        }
    };
    let stdout = io::stdout();
    let mut out = BufWriter::with_capacity(OUT_CHUNK, stdout.lock());
    match run(input, &mut out, &mut io::stderr(), args.json) {
        Ok(summary) => {
            eprintln!("lbv decode can: {summary}");
            summary.exit_code()
        }
        Err(error) => error.exit("lbv decode can", &name),
    }
}

/// Decodes the candump log `input` to `out` (human or `json`), with bad-line messages and notes on `err`.
pub fn run(
    input: impl BufRead,
    out: &mut impl Write,
    err: &mut impl Write,
    json: bool,
) -> Result<Summary, StreamError> {
    let mut decoder = Decoder::new(json);
    let mut lines = Lines::new(input, MAX_LINE);
    while let Some((number, line)) = lines.next_line().map_err(StreamError::Read)? {
        let parsed = match line {
            InputLine::Whole(line) => parse_line(line),
            InputLine::TooLong { .. } => Err("line too long for a candump log line"),
        };
        match parsed {
            Ok(Line::Blank) => {}
            Ok(Line::DropCount) => {
                decoder.summary.drop_notes += 1;
                decoder.flush(out)?;
                let _ = writeln!(
                    err,
                    "lbv decode can: line {number}: the capture lost frames: {}",
                    shown(line.bytes())
                );
            }
            Ok(Line::Frame { time, iface, frame }) => decoder.frame(number, time, iface, frame),
            Err(reason) => {
                decoder.summary.bad += 1;
                if decoder.summary.bad <= MAX_MESSAGES {
                    decoder.flush(out)?;
                    let _ = writeln!(
                        err,
                        "lbv decode can: line {number}: {reason}, skipped: {}",
                        shown(line.bytes())
                    );
                }
            }
        }
        if decoder.out.len() >= OUT_CHUNK {
            decoder.flush(out)?;
        }
    }
    decoder.flush(out)?;
    decoder.summary.lines = lines.number();
    Ok(decoder.summary)
}

/// A line for a message: at most 80 bytes, not UTF-8 shown as U+FFFD, control characters escaped.
fn shown(line: &[u8]) -> String {
    let cut = &line[..line.len().min(80)];
    let text = format!("{:?}", String::from_utf8_lossy(cut));
    if cut.len() < line.len() {
        format!("{text}...")
    } else {
        text
    }
}

/// One line of a candump log.
#[derive(Debug, PartialEq, Eq)]
enum Line<'a> {
    /// Nothing but white space.
    Blank,
    /// candump's note that the kernel dropped frames.
    DropCount,
    /// A frame.
    Frame {
        /// The time as written, `SECONDS[.FRACTION]`, ASCII digits.
        time: &'a [u8],
        /// The interface name.
        iface: &'a [u8],
        /// The frame.
        frame: CanFrame,
    },
}

/// A frame of a log line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum CanFrame {
    /// A classic CAN data frame with a standard ID: the only kind a BAT frame can be.
    Classic {
        /// Standard 11-bit ID.
        id: u16,
        /// Data length, 0..=8.
        len: usize,
        /// Data; the first `len` bytes count.
        data: [u8; 8],
    },
    /// Any other frame: not a BAT data frame.
    Other(Other),
}

/// Frames that cannot be BAT data frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Other {
    /// A remote request (`620#R`).
    Remote,
    /// A CAN FD frame (`620##0...`): the BAT board speaks classic CAN.
    Fd,
    /// A frame with an extended 29-bit ID (8 digits).
    Extended,
    /// An error frame (8 digits with the error flag 0x20000000).
    Error,
    /// A CAN XL frame.
    Xl,
}

/// Parses one line (without its end of line). The error says what is wrong, in words.
fn parse_line(line: &[u8]) -> Result<Line<'_>, &'static str> {
    let line = line.trim_ascii();
    if line.is_empty() {
        return Ok(Line::Blank);
    }
    if line.starts_with(b"DROPCOUNT") {
        return Ok(Line::DropCount);
    }
    let mut tokens = line.split(u8::is_ascii_whitespace).filter(|token| !token.is_empty());
    let time = parse_time(tokens.next().unwrap_or_default())?;
    let iface = tokens.next().ok_or("no interface name after the time")?;
    let frame = tokens.next().ok_or("no frame (ID#DATA) after the interface name")?;
    match (tokens.next(), tokens.next()) {
        (None, _) | (Some(b"R" | b"T"), None) => {}
        _ => return Err("text after the frame (only candump's direction R or T may follow)"),
    }
    Ok(Line::Frame {
        time,
        iface,
        frame: parse_frame(frame)?,
    })
}

/// `(SECONDS.FRACTION)` to `SECONDS.FRACTION`.
fn parse_time(token: &[u8]) -> Result<&[u8], &'static str> {
    let time = token
        .strip_prefix(b"(")
        .and_then(|token| token.strip_suffix(b")"))
        .ok_or("no (SECONDS.FRACTION) time at the start")?;
    let digits = |part: &[u8]| !part.is_empty() && part.iter().all(u8::is_ascii_digit);
    let good = match time.iter().position(|&byte| byte == b'.') {
        Some(dot) => digits(&time[..dot]) && digits(&time[dot + 1..]),
        None => digits(time),
    };
    if good {
        Ok(time)
    } else {
        Err("the time is not SECONDS.FRACTION")
    }
}

/// `ID#DATA`, `ID#R`, `ID##FDATA` or a CAN XL frame, as candump writes them (can-utils' `parse_canframe`).
fn parse_frame(token: &[u8]) -> Result<CanFrame, &'static str> {
    let hash = token
        .iter()
        .position(|&byte| byte == b'#')
        .ok_or("no '#' between the CAN ID and the data")?;
    let (id, payload) = (&token[..hash], &token[hash + 1..]);
    match id.len() {
        3 => {
            let id = hex_u32(id).ok_or("the CAN ID is not hex")?;
            let id = u16::try_from(id)
                .ok()
                .filter(|id| *id <= 0x7FF)
                .ok_or("a 3-digit (standard) CAN ID above 7FF")?;
            parse_payload(id, payload)
        }
        8 => {
            let id = hex_u32(id).ok_or("the CAN ID is not hex")?;
            Ok(match parse_payload(0, payload)? {
                CanFrame::Classic { .. } if id & CAN_ERR_FLAG != 0 => CanFrame::Other(Other::Error),
                CanFrame::Classic { .. } => CanFrame::Other(Other::Extended),
                other => other,
            })
        }
        5 if payload.contains(&b'#') => parse_xl(id, payload),
        _ => Err("the CAN ID needs 3 (standard) or 8 (extended) hex digits"),
    }
}

/// What follows `ID#`: classic data (with an optional `_DLC` for DLC 9..F on 8 bytes), `R` for a remote
/// request, or `#` and a flags digit for CAN FD.
fn parse_payload(id: u16, payload: &[u8]) -> Result<CanFrame, &'static str> {
    if let Some(fd) = payload.strip_prefix(b"#") {
        let (flags, data) = fd.split_first().ok_or("no flags digit after '##' (CAN FD)")?;
        if !flags.is_ascii_hexdigit() {
            return Err("the CAN FD flags are not a hex digit");
        }
        hex_bytes(data, 64, |_, _| {})?;
        return Ok(CanFrame::Other(Other::Fd));
    }
    if let Some(remote) = payload.strip_prefix(b"R").or_else(|| payload.strip_prefix(b"r")) {
        return match remote {
            [] | [b'0'..=b'8'] => Ok(CanFrame::Other(Other::Remote)),
            [b'8', b'_', dlc] if len8_dlc(*dlc) => Ok(CanFrame::Other(Other::Remote)),
            _ => Err("a remote request's length is not 0 to 8"),
        };
    }
    let (hex, dlc) = match payload.iter().position(|&byte| byte == b'_') {
        Some(underscore) => (&payload[..underscore], Some(&payload[underscore + 1..])),
        None => (payload, None),
    };
    let mut data = [0_u8; 8];
    let len = hex_bytes(hex, 8, |index, byte| {
        if let Some(slot) = data.get_mut(index) {
            *slot = byte;
        }
    })?;
    if let Some(dlc) = dlc
        && !(len == 8 && matches!(dlc, [dlc] if len8_dlc(*dlc)))
    {
        return Err("a '_DLC' needs 8 data bytes and one hex digit 9 to F");
    }
    Ok(CanFrame::Classic { id, len, data })
}

/// A CAN XL frame: `VVPPP#FF:SS:AAAAAAAA#DATA` (VCID, priority, flags, SDU type, acceptance field, 1..=2048
/// bytes).
fn parse_xl(id: &[u8], payload: &[u8]) -> Result<CanFrame, &'static str> {
    const BAD: &str = "not a CAN XL frame (VVPPP#FF:SS:AAAAAAAA#DATA)";
    let hex = |text: &[u8]| text.iter().all(u8::is_ascii_hexdigit);
    match payload {
        [f0, f1, b':', s0, s1, b':', rest @ ..] if hex(id) && hex(&[*f0, *f1, *s0, *s1]) => {
            let (af, data) = rest.split_at_checked(8).ok_or(BAD)?;
            let data = data.strip_prefix(b"#").ok_or(BAD)?;
            if !hex(af) || hex_bytes(data, 2048, |_, _| {})? == 0 {
                return Err(BAD);
            }
            Ok(CanFrame::Other(Other::Xl))
        }
        _ => Err(BAD),
    }
}

/// Whether `digit` is a valid `_DLC` of a classic frame with 8 bytes: 9..F.
fn len8_dlc(digit: u8) -> bool {
    matches!(digit, b'9' | b'A'..=b'F' | b'a'..=b'f')
}

/// Hex digits (1 to 8) to a number.
fn hex_u32(text: &[u8]) -> Option<u32> {
    if text.is_empty() || text.len() > 8 {
        return None;
    }
    text.iter()
        .try_fold(0_u32, |value, &digit| Some(value << 4 | u32::from(nibble(digit)?)))
}

/// Hex data bytes, optionally separated by dots, at most `max`; each byte goes to `sink(index, byte)`. Returns
/// how many there are.
fn hex_bytes(mut text: &[u8], max: usize, mut sink: impl FnMut(usize, u8)) -> Result<usize, &'static str> {
    let mut len = 0;
    while let Some((&first, rest)) = text.split_first() {
        if first == b'.' {
            text = rest;
            continue;
        }
        let high = nibble(first).ok_or("the data is not hex")?;
        let (&second, rest) = rest.split_first().ok_or("an odd number of hex digits in the data")?;
        let low = nibble(second).ok_or(if second == b'.' {
            "an odd number of hex digits in the data"
        } else {
            "the data is not hex"
        })?;
        if len == max {
            return Err(if max == 8 {
                "more than 8 data bytes (classic CAN)"
            } else {
                "too many data bytes"
            });
        }
        sink(len, high << 4 | low);
        len += 1;
        text = rest;
    }
    Ok(len)
}

/// The value of one hex digit.
fn nibble(digit: u8) -> Option<u8> {
    match digit {
        b'0'..=b'9' => Some(digit - b'0'),
        b'a'..=b'f' => Some(digit - b'a' + 10),
        b'A'..=b'F' => Some(digit - b'A' + 10),
        _ => None,
    }
}

/// What a run did, for the summary and the exit status.
#[derive(Debug, Default, Clone, PartialEq, Eq)]
pub struct Summary {
    /// Lines read.
    pub lines: u64,
    /// BAT frames decoded.
    pub decoded: u64,
    /// Frames with a BAT ID that bat-proto rejected.
    pub decode_errors: u64,
    /// Bad lines skipped.
    pub bad: u64,
    /// candump's DROPCOUNT notes.
    pub drop_notes: u64,
    /// Frames of other IDs.
    pub other_ids: u64,
    /// Remote requests.
    pub remote: u64,
    /// CAN FD frames.
    pub fd: u64,
    /// Frames with extended IDs.
    pub extended: u64,
    /// Error frames.
    pub error_frames: u64,
    /// CAN XL frames.
    pub xl: u64,
    /// Interfaces' boards forgotten to keep at most [`MAX_INTERFACES`].
    pub forgotten: u64,
}

impl Summary {
    /// 0 when every line was good, 1 when lines were skipped or BAT frames did not decode.
    pub fn exit_code(&self) -> ExitCode {
        if self.bad == 0 && self.decode_errors == 0 {
            ExitCode::SUCCESS
        } else {
            ExitCode::FAILURE
        }
    }

    fn ignored(&self) -> u64 {
        self.other_ids + self.remote + self.fd + self.extended + self.error_frames + self.xl
    }
}

/// `n thing` or `n things`.
fn count(n: u64, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: {} decoded, {} did not decode, {} ignored",
            count(self.lines, "line", "lines"),
            count(self.decoded, "BAT frame", "BAT frames"),
            self.decode_errors,
            count(self.ignored(), "other frame", "other frames"),
        )?;
        let kinds: Vec<String> = [
            (self.other_ids, "other ID", "other IDs"),
            (self.remote, "remote request", "remote requests"),
            (self.fd, "CAN FD", "CAN FD"),
            (self.extended, "extended ID", "extended IDs"),
            (self.error_frames, "error frame", "error frames"),
            (self.xl, "CAN XL", "CAN XL"),
        ]
        .into_iter()
        .filter(|(n, _, _)| *n > 0)
        .map(|(n, one, many)| count(n, one, many))
        .collect();
        if !kinds.is_empty() {
            write!(f, " ({})", kinds.join(", "))?;
        }
        write!(f, ", skipped {}", count(self.bad, "bad line", "bad lines"))?;
        if self.bad > MAX_MESSAGES {
            write!(f, " (the first {MAX_MESSAGES} shown)")?;
        }
        if self.forgotten > 0 {
            write!(
                f,
                "; BAT boards on more than {MAX_INTERFACES} interfaces: {} forgotten (a board heard again after \
                 that reports its status as at start-up)",
                self.forgotten
            )?;
        }
        if self.drop_notes > 0 {
            write!(
                f,
                "; the capture reported lost frames on {}",
                count(self.drop_notes, "line", "lines")
            )?;
        }
        Ok(())
    }
}

/// What is remembered of one interface's BAT board, for the change reports.
#[derive(Debug, Default)]
struct Board {
    /// The interface's name.
    iface: Vec<u8>,
    /// When it was last heard from, in BAT frames decoded.
    heard: u64,
    status: Option<DcdcStatus>,
    alarms: Option<BmsAlarms>,
}

/// Decodes frames into an output buffer.
#[derive(Debug)]
struct Decoder {
    json: bool,
    /// At most [`MAX_INTERFACES`].
    boards: Vec<Board>,
    summary: Summary,
    out: Vec<u8>,
}

impl Decoder {
    fn new(json: bool) -> Self {
        Self {
            json,
            boards: Vec::new(),
            summary: Summary::default(),
            out: Vec::with_capacity(OUT_CHUNK + 1024),
        }
    }

    /// Writes what is buffered to `out`.
    fn flush(&mut self, out: &mut impl Write) -> Result<(), StreamError> {
        out.write_all(&self.out).map_err(StreamError::Write)?;
        self.out.clear();
        out.flush().map_err(StreamError::Write)
    }

    /// Applies `update` to the board on `iface`: a new one for an interface not seen yet, which takes the place
    /// of the one heard from least recently once [`MAX_INTERFACES`] are remembered.
    fn on_board<T>(&mut self, iface: &[u8], update: impl FnOnce(&mut Board) -> T) -> T {
        let heard = self.summary.decoded;
        let at = match self.boards.iter().position(|board| board.iface == iface) {
            Some(at) => at,
            None if self.boards.len() < MAX_INTERFACES => {
                self.boards.push(Board::default());
                self.boards.len() - 1
            }
            None => {
                self.summary.forgotten += 1;
                let oldest = self.boards.iter().enumerate().min_by_key(|(_, board)| board.heard);
                oldest.map_or(0, |(at, _)| at)
            }
        };
        let board = &mut self.boards[at];
        if board.iface != iface {
            *board = Board {
                iface: iface.to_vec(),
                ..Board::default()
            };
        }
        board.heard = heard;
        update(board)
    }

    fn frame(&mut self, line: u64, time: &[u8], iface: &[u8], frame: CanFrame) {
        let (id, data) = match frame {
            CanFrame::Classic { id, len, ref data } => (id, &data[..len]),
            CanFrame::Other(other) => {
                *match other {
                    Other::Remote => &mut self.summary.remote,
                    Other::Fd => &mut self.summary.fd,
                    Other::Extended => &mut self.summary.extended,
                    Other::Error => &mut self.summary.error_frames,
                    Other::Xl => &mut self.summary.xl,
                } += 1;
                return;
            }
        };
        match Frame::decode(id, data) {
            Ok(decoded) => {
                self.summary.decoded += 1;
                self.start(time, id);
                match decoded {
                    Frame::Info(info) => self.info(info),
                    Frame::Status(status) => self.status(iface, status),
                    Frame::Bms(alarms) => self.alarms(iface, alarms),
                }
                self.out.extend_from_slice(if self.json { b"}\n" } else { b"\n" });
            }
            Err(DecodeError::UnknownId(_)) => self.summary.other_ids += 1,
            Err(error) => {
                self.summary.decode_errors += 1;
                self.start(time, id);
                let out = &mut self.out;
                if self.json {
                    out.extend_from_slice(b",\"line\":");
                    push_u64(out, line);
                    out.extend_from_slice(b",\"error\":");
                    let _ = serde_json::to_writer(&mut *out, &error.to_string());
                    out.extend_from_slice(b"}\n");
                } else {
                    let _ = writeln!(out, " error (line {line}): {error}");
                }
            }
        }
    }

    /// `{"time":T,"id":N` or `T 0xNNN`.
    fn start(&mut self, time: &[u8], id: u16) {
        let out = &mut self.out;
        if self.json {
            out.extend_from_slice(b"{\"time\":");
            push_json_number(out, time);
            out.extend_from_slice(b",\"id\":");
            push_u64(out, u64::from(id));
        } else {
            out.extend_from_slice(time);
            out.extend_from_slice(b" 0x");
            for shift in [8, 4, 0] {
                out.push(b"0123456789abcdef"[usize::from(id >> shift & 0xF)]);
            }
        }
    }

    fn info(&mut self, info: BatteryInfo) {
        let out = &mut self.out;
        if self.json {
            out.extend_from_slice(b",\"voltage_v\":");
            push_tenths(out, i32::from(info.voltage_decivolts));
            out.extend_from_slice(b",\"current_a\":");
            push_optional_tenths(out, info.current_deciamps);
            out.extend_from_slice(b",\"charge_pct\":");
            match info.charge_percent {
                Some(charge) => push_u64(out, u64::from(charge)),
                None => out.extend_from_slice(b"null"),
            }
            out.extend_from_slice(b",\"temperature_c\":");
            push_optional_tenths(out, info.temperature_decicelsius);
        } else {
            out.extend_from_slice(b" info ");
            push_tenths(out, i32::from(info.voltage_decivolts));
            out.extend_from_slice(b" V");
            if let Some(current) = info.current_deciamps {
                out.push(b' ');
                push_tenths(out, i32::from(current));
                out.extend_from_slice(b" A");
            }
            if let Some(charge) = info.charge_percent {
                out.push(b' ');
                push_u64(out, u64::from(charge));
                out.extend_from_slice(b" %");
            }
            if let Some(temperature) = info.temperature_decicelsius {
                out.push(b' ');
                push_tenths(out, i32::from(temperature));
                out.extend_from_slice(b" C");
            }
        }
    }

    fn status(&mut self, iface: &[u8], status: DcdcStatus) {
        let previous = self.on_board(iface, |board| board.status.replace(status));
        let out = &mut self.out;
        if self.json {
            out.extend_from_slice(b",\"status\":");
            push_u64(out, u64::from(status.word()));
            out.extend_from_slice(b",\"status_bits\":");
            push_names(out, status.set_bits().map(StatusBit::name));
            out.extend_from_slice(b",\"changed\":");
            let changed = previous.map(|previous| DcdcStatus::from_word(status.word() ^ previous.word()));
            push_names(out, changed.unwrap_or_default().set_bits().map(StatusBit::name));
            return;
        }
        let _ = write!(out, " status {:#06x}", status.word());
        if status.word() == 0 {
            out.extend_from_slice(b" none");
        }
        for bit in status.set_bits() {
            out.push(b' ');
            out.extend_from_slice(bit.name().as_bytes());
        }
        let (label, reports): (&[u8], Vec<_>) = match previous {
            None => (b"; start-up: ", status.describe_all().collect()),
            Some(previous) => (b"; changed: ", status.describe_changes(previous).collect()),
        };
        for (i, report) in reports.iter().enumerate() {
            out.extend_from_slice(if i == 0 { label } else { b", " });
            let _ = write!(out, "{report}");
        }
    }

    fn alarms(&mut self, iface: &[u8], alarms: BmsAlarms) {
        let previous = self
            .on_board(iface, |board| board.alarms.replace(alarms))
            .unwrap_or(BmsAlarms::NONE);
        let raised = BmsAlarms::from_bits_truncate(alarms.bits() & !previous.bits());
        let cleared = BmsAlarms::from_bits_truncate(previous.bits() & !alarms.bits());
        let out = &mut self.out;
        if self.json {
            out.extend_from_slice(b",\"alarms\":");
            push_u64(out, u64::from(alarms.bits()));
            out.extend_from_slice(b",\"alarm_bits\":");
            push_names(out, alarms.iter().map(BmsAlarms::name));
            out.extend_from_slice(b",\"changed\":");
            push_names(out, raised.union(cleared).iter().map(BmsAlarms::name));
            return;
        }
        let _ = write!(out, " bms alarms {:#04x} ", alarms.bits());
        push_list(out, alarms.iter().map(BmsAlarms::name), "none");
        for (label, which) in [("; raised: ", raised), ("; cleared: ", cleared)] {
            if !which.is_empty() {
                out.extend_from_slice(label.as_bytes());
                push_list(out, which.iter().map(BmsAlarms::name), "");
            }
        }
    }
}

/// A JSON array of names (plain ASCII, nothing to escape).
fn push_names<'a>(out: &mut Vec<u8>, names: impl Iterator<Item = &'a str>) {
    out.push(b'[');
    for (i, name) in names.enumerate() {
        if i > 0 {
            out.push(b',');
        }
        out.push(b'"');
        out.extend_from_slice(name.as_bytes());
        out.push(b'"');
    }
    out.push(b']');
}

/// Names separated by ", ", or `empty` when there are none.
fn push_list<'a>(out: &mut Vec<u8>, names: impl Iterator<Item = &'a str>, empty: &str) {
    let start = out.len();
    for name in names {
        if out.len() > start {
            out.extend_from_slice(b", ");
        }
        out.extend_from_slice(name.as_bytes());
    }
    if out.len() == start {
        out.extend_from_slice(empty.as_bytes());
    }
}

/// The log's time as a JSON number: the same digits without the leading zeros candump pads it with
/// (`0000000012.5` is `12.5`; JSON forbids leading zeros).
fn push_json_number(out: &mut Vec<u8>, time: &[u8]) {
    let significant = time.iter().position(|&byte| byte != b'0').unwrap_or(time.len());
    let trimmed = &time[significant..];
    if trimmed.first().is_none_or(|&byte| byte == b'.') {
        out.push(b'0');
    }
    out.extend_from_slice(trimmed);
}

fn push_u64(out: &mut Vec<u8>, mut value: u64) {
    let mut digits = [0_u8; 20];
    let mut start = digits.len();
    loop {
        start -= 1;
        digits[start] = b'0' + (value % 10) as u8;
        value /= 10;
        if value == 0 {
            break;
        }
    }
    out.extend_from_slice(&digits[start..]);
}

/// A value in tenths with one decimal: -25 is `-2.5`, 420 is `42.0`.
fn push_tenths(out: &mut Vec<u8>, tenths: i32) {
    if tenths < 0 {
        out.push(b'-');
    }
    let magnitude = tenths.unsigned_abs();
    push_u64(out, u64::from(magnitude / 10));
    out.push(b'.');
    out.push(b'0' + (magnitude % 10) as u8);
}

fn push_optional_tenths(out: &mut Vec<u8>, tenths: Option<i16>) {
    match tenths {
        Some(tenths) => push_tenths(out, i32::from(tenths)),
        None => out.extend_from_slice(b"null"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode(log: &str, json: bool) -> (String, String, Summary) {
        let (mut out, mut err) = (Vec::new(), Vec::new());
        let summary = run(log.as_bytes(), &mut out, &mut err, json).unwrap();
        (
            String::from_utf8(out).unwrap(),
            String::from_utf8(err).unwrap(),
            summary,
        )
    }

    fn classic(id: u16, data: &[u8]) -> CanFrame {
        let mut bytes = [0; 8];
        bytes[..data.len()].copy_from_slice(data);
        CanFrame::Classic {
            id,
            len: data.len(),
            data: bytes,
        }
    }

    #[test]
    fn parses_candump_log_lines() {
        let frame = |line| match parse_line(line) {
            Ok(Line::Frame { frame, .. }) => Ok(frame),
            Ok(other) => panic!("{other:?}"),
            Err(error) => Err(error),
        };
        assert_eq!(
            parse_line(b"(1700000000.123456) can0 620#A401000058000000"),
            Ok(Line::Frame {
                time: b"1700000000.123456",
                iface: b"can0",
                frame: classic(0x620, &[0xA4, 0x01, 0, 0, 0x58, 0, 0, 0]),
            })
        );
        assert_eq!(
            frame(b"  (1.5)   vcan10  629#ac.00.00.00.0000.0000 R\r"),
            Ok(classic(0x629, &[0xAC, 0, 0, 0, 0, 0, 0, 0]))
        );
        assert_eq!(frame(b"(1.5) can0 123#"), Ok(classic(0x123, &[])));
        assert_eq!(
            frame(b"(1.5) can0 123#1122334455667788_E"),
            Ok(classic(0x123, &[0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77, 0x88]))
        );
        assert_eq!(frame(b"(1.5) can0 620#R"), Ok(CanFrame::Other(Other::Remote)));
        assert_eq!(frame(b"(1.5) can0 620#R8_9"), Ok(CanFrame::Other(Other::Remote)));
        assert_eq!(frame(b"(1.5) can0 620##1A4010000"), Ok(CanFrame::Other(Other::Fd)));
        assert_eq!(
            frame(b"(1.5) can0 00000620#A401000058000000"),
            Ok(CanFrame::Other(Other::Extended))
        );
        assert_eq!(
            frame(b"(1.5) can0 20000004#0000000000000000"),
            Ok(CanFrame::Other(Other::Error))
        );
        assert_eq!(
            frame(b"(1.5) can0 45123#81:00:12345678#11223344.556677"),
            Ok(CanFrame::Other(Other::Xl))
        );
        assert_eq!(parse_line(b" \t\r"), Ok(Line::Blank));
        assert_eq!(
            parse_line(b"DROPCOUNT: dropped 3 CAN frames on 'can0' socket (total drops 3)"),
            Ok(Line::DropCount)
        );

        for (line, reason) in [
            (&b"garbage"[..], "no (SECONDS.FRACTION) time at the start"),
            (b"(1.5)", "no interface name after the time"),
            (b"(1.5) can0", "no frame (ID#DATA) after the interface name"),
            (b"(1.x) can0 620#00", "the time is not SECONDS.FRACTION"),
            (b"(1.5) can0 620", "no '#' between the CAN ID and the data"),
            (
                b"(1.5) can0 62#00",
                "the CAN ID needs 3 (standard) or 8 (extended) hex digits",
            ),
            (b"(1.5) can0 G20#00", "the CAN ID is not hex"),
            (b"(1.5) can0 800#00", "a 3-digit (standard) CAN ID above 7FF"),
            (b"(1.5) can0 620#A40", "an odd number of hex digits in the data"),
            (b"(1.5) can0 620#A4.0", "an odd number of hex digits in the data"),
            (b"(1.5) can0 620#ZZ", "the data is not hex"),
            (
                b"(1.5) can0 620#A40100005800000000",
                "more than 8 data bytes (classic CAN)",
            ),
            (
                b"(1.5) can0 620#00_E",
                "a '_DLC' needs 8 data bytes and one hex digit 9 to F",
            ),
            (b"(1.5) can0 620#R9", "a remote request's length is not 0 to 8"),
            (b"(1.5) can0 620##", "no flags digit after '##' (CAN FD)"),
            (
                b"(1.5) can0 620#00 X",
                "text after the frame (only candump's direction R or T may follow)",
            ),
            (
                b"(1.5) can0 620#00 R R",
                "text after the frame (only candump's direction R or T may follow)",
            ),
        ] {
            assert_eq!(parse_line(line), Err(reason), "{}", String::from_utf8_lossy(line));
        }
    }

    #[test]
    fn human_output_reports_start_up_then_changes() {
        let log = "(1700000000.123456) can0 620#A401E7FF3A00D700\n\
                   (1700000000.223456) can0 629#AC00000000000000\n\
                   (1700000000.323456) can0 629#AC00000000000000\n\
                   (1700000000.423456) can0 629#AE04000000000000\n\
                   (1700000000.523456) can0 628#0100000000000000\n\
                   (1700000000.623456) can0 628#0200000000000000\n\
                   (1700000000.723456) can0 620#A4010000\n\
                   (1700000000.823456) can0 620#A401000058000000\n";
        let (out, err, summary) = decode(log, false);
        let lines: Vec<&str> = out.lines().collect();
        assert_eq!(lines[0], "1700000000.123456 0x620 info 42.0 V -2.5 A 58 % 21.5 C");
        assert!(
            lines[1].starts_with(
                "1700000000.223456 0x629 status 0x00ac HSM_PG HSM V12motor V12board; start-up: HSM_broken=0 (normal), "
            ),
            "{}",
            lines[1]
        );
        assert!(lines[1].ends_with("HSM_SW_F=0 (no fault)"), "{}", lines[1]);
        assert_eq!(
            lines[2],
            "1700000000.323456 0x629 status 0x00ac HSM_PG HSM V12motor V12board"
        );
        assert_eq!(
            lines[3],
            "1700000000.423456 0x629 status 0x04ae HSM_F HSM_PG HSM V12motor V12board HSM_HW_F; changed: \
             HSM_F=1 (hot swap manager overcurrent / overvoltage fault), HSM_HW_F=1 (HSM overcurrent fault from the \
             HSM's FLT pin)"
        );
        assert_eq!(
            lines[4],
            "1700000000.523456 0x628 bms alarms 0x01 low voltage; raised: low voltage"
        );
        assert_eq!(
            lines[5],
            "1700000000.623456 0x628 bms alarms 0x02 high voltage; raised: high voltage; cleared: low voltage"
        );
        assert_eq!(
            lines[6],
            "1700000000.723456 0x620 error (line 7): BAT frame 0x620 has 4 data bytes, expected 8"
        );
        assert_eq!(lines[7], "1700000000.823456 0x620 info 42.0 V 88 %");
        assert_eq!(err, "");
        assert_eq!((summary.decoded, summary.decode_errors, summary.bad), (7, 1, 0));
    }

    #[test]
    fn json_output_has_the_documented_fields() {
        let log = "(0000000012.500000) can0 620#A401E7FF3A00D700\n\
                   (0000000000.100000) can0 620#A401000058000000\n\
                   (13) can0 629#AC00000000000000\n\
                   (14.0) can0 629#AE00000000000000\n\
                   (15.0) can0 628#8500000000000000\n\
                   (16.0) can0 629#0000\n";
        let (out, _, _) = decode(log, true);
        let lines: Vec<&str> = out.lines().collect();
        assert_eq!(
            lines,
            [
                r#"{"time":12.500000,"id":1568,"voltage_v":42.0,"current_a":-2.5,"charge_pct":58,"temperature_c":21.5}"#,
                r#"{"time":0.100000,"id":1568,"voltage_v":42.0,"current_a":null,"charge_pct":88,"temperature_c":null}"#,
                r#"{"time":13,"id":1577,"status":172,"status_bits":["HSM_PG","HSM","V12motor","V12board"],"changed":[]}"#,
                r#"{"time":14.0,"id":1577,"status":174,"status_bits":["HSM_F","HSM_PG","HSM","V12motor","V12board"],"changed":["HSM_F"]}"#,
                r#"{"time":15.0,"id":1576,"alarms":5,"alarm_bits":["low voltage","overcurrent discharge"],"changed":["low voltage","overcurrent discharge"]}"#,
                r#"{"time":16.0,"id":1577,"line":6,"error":"BAT frame 0x629 has 2 data bytes, expected 8"}"#,
            ]
        );
        for line in lines {
            serde_json::from_str::<serde_json::Value>(line).unwrap();
        }
    }

    #[test]
    fn status_changes_are_tracked_per_interface() {
        let log = "(1.0) can0 629#0400000000000000\n(2.0) can1 629#0800000000000000\n\
                   (3.0) can0 629#0400000000000000\n(4.0) can1 629#0C00000000000000\n";
        let (out, _, _) = decode(log, true);
        let changed: Vec<serde_json::Value> = out
            .lines()
            .map(|line| serde_json::from_str::<serde_json::Value>(line).unwrap()["changed"].clone())
            .collect();
        assert_eq!(
            changed,
            [
                serde_json::json!([]),
                serde_json::json!([]),
                serde_json::json!([]),
                serde_json::json!(["HSM_PG"])
            ]
        );
    }

    #[test]
    fn tenths_and_times_format_exactly() {
        let mut out = Vec::new();
        for value in [0, 5, -5, 420, -32768, 65535] {
            push_tenths(&mut out, value);
            out.push(b' ');
        }
        for time in [&b"0000000000.000001"[..], b"000", b"7", b"0012"] {
            push_json_number(&mut out, time);
            out.push(b' ');
        }
        assert_eq!(
            String::from_utf8(out).unwrap(),
            "0.0 0.5 -0.5 42.0 -3276.8 6553.5 0.000001 0 7 12 "
        );
    }

    #[test]
    fn random_lines_never_panic() {
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let alphabet = b"()0123456789abcdefABCDEF#.R_ :\t\r\ncanDROPCOUNT\xff\x00";
        for _ in 0..20_000 {
            let len = (next() % 60) as usize;
            let line: Vec<u8> = (0..len)
                .map(|_| alphabet[(next() % alphabet.len() as u64) as usize])
                .collect();
            let _ = parse_line(&line);
            let _ = run(&line[..], &mut Vec::new(), &mut Vec::new(), next() % 2 == 0);
        }
    }

    #[test]
    fn long_lines_are_cut_and_skipped() {
        let mut log = vec![b'x'; MAX_LINE * 3];
        log.extend_from_slice(b"\n(1.0) can0 620#A401000058000000\n");
        let (mut out, mut err) = (Vec::new(), Vec::new());
        let summary = run(&log[..], &mut out, &mut err, false).unwrap();
        assert_eq!((summary.lines, summary.bad, summary.decoded), (2, 1, 1));
        assert!(
            String::from_utf8(err)
                .unwrap()
                .starts_with("lbv decode can: line 1: line too long")
        );
    }

    /// A log with more interfaces than [`MAX_INTERFACES`]: the boards remembered stay bounded, the least recently
    /// heard is forgotten, and the summary says so.
    #[test]
    fn interfaces_beyond_the_limit_are_forgotten_least_recent_first() {
        let status = |iface: &str| format!("(1.0) {iface} 629#AC00000000000000\n");
        let mut log = String::new();
        for i in 0..10 * MAX_INTERFACES {
            log.push_str(&status(&format!("can{i}")));
        }
        // can0 .. can{MAX-1} were pushed out long ago; the last MAX_INTERFACES are remembered.
        let last = format!("can{}", 10 * MAX_INTERFACES - 1);
        log.push_str(&status(&last));
        log.push_str(&status("can0"));
        let mut decoder = Decoder::new(false);
        let mut lines = crate::lines::Lines::new(log.as_bytes(), MAX_LINE);
        let mut outputs = Vec::new();
        while let Some((number, line)) = lines.next_line().unwrap() {
            let Ok(Line::Frame { time, iface, frame }) = parse_line(line.bytes()) else {
                panic!("a frame")
            };
            decoder.frame(number, time, iface, frame);
            outputs.push(String::from_utf8(std::mem::take(&mut decoder.out)).unwrap());
        }
        assert_eq!(decoder.boards.len(), MAX_INTERFACES);
        let last_two: Vec<&String> = outputs.iter().rev().take(2).collect();
        assert!(!last_two[1].contains("start-up"), "still remembered: {}", last_two[1]);
        assert!(
            last_two[0].contains("start-up: "),
            "forgotten, so a start-up again: {}",
            last_two[0]
        );
        assert_eq!(decoder.summary.forgotten, 9 * MAX_INTERFACES as u64 + 1);
        assert!(decoder.summary.to_string().contains("forgotten"));
    }
}
