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

mod line;
mod render;
mod summary;
#[cfg(test)]
mod tests;

use std::io::{self, BufRead, BufWriter, Write};
use std::path::PathBuf;
use std::process::ExitCode;

use bat_proto::{BmsAlarms, DcdcStatus, DecodeError, Frame};

use super::StreamError;
use crate::exit;
use crate::lines::{Line as InputLine, Lines};

use line::{CanFrame, Line, Other, parse_line};
use render::Report;
pub use summary::Summary;

/// Longest line read whole. candump's longest line, a CAN XL frame of 2048 bytes, is about 4200 bytes.
pub const MAX_LINE: usize = 8192;
/// Bad lines reported one by one on standard error; the summary counts them all.
pub const MAX_MESSAGES: u64 = 100;
/// Interfaces whose BAT board is remembered for the change reports; past this many, the one heard from least
/// recently is forgotten (its next status is reported as a start-up again), so memory stays bounded.
pub const MAX_INTERFACES: usize = 64;
/// Output is built in memory and written in chunks of about this size.
const OUT_CHUNK: usize = 64 * 1024;

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
        let report = match Frame::decode(id, data) {
            Ok(decoded) => {
                self.summary.decoded += 1;
                match decoded {
                    Frame::Info(info) => Report::Info(info),
                    Frame::Status(status) => Report::Status {
                        status,
                        previous: self.on_board(iface, |board| board.status.replace(status)),
                    },
                    Frame::Bms(alarms) => Report::Alarms {
                        alarms,
                        previous: self
                            .on_board(iface, |board| board.alarms.replace(alarms))
                            .unwrap_or(BmsAlarms::NONE),
                    },
                }
            }
            Err(DecodeError::UnknownId(_)) => {
                self.summary.other_ids += 1;
                return;
            }
            Err(error) => {
                self.summary.decode_errors += 1;
                Report::Error { line, error }
            }
        };
        if self.json {
            render::json(&mut self.out, time, id, report);
        } else {
            render::human(&mut self.out, time, id, report);
        }
    }
}
