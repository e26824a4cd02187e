//! `lbv decode tlog`: a telemetry log (the master's black box, `@SYS/blackbox.tlog`, or a ground station's own
//! `.tlog`) read back into the bench's trace: printed one line per moment, or drawn with the bench's plotters.
//!
//! A tlog is MAVLink frames, each after the 8-byte big-endian time it was logged at (microseconds). What the
//! vehicle says of its thrusters and battery is taken from the messages the master sends: ESC_TELEMETRY_1_TO_4 and
//! _5_TO_8 (rpm as a magnitude, current), ESC_STATUS (rpm with its sign, current), ESC_INFO (how many, which
//! report, temperature, faults), SERVO_OUTPUT_RAW (the orders, as ArduSub's motor outputs), BATTERY_STATUS
//! (voltage), HEARTBEAT (armed) and STATUSTEXT (events). The messages of one time make one sample.
//!
//! ```text
//! t 12.300 s  armed  24.0 V  T1 1235 rpm 1.2 A 31 C  T2 1235 rpm 1.1 A 30 C  ...
//! t 12.300 s  Black box: ground station lost
//! ```
//!
//! Memory stays flat: the file is read frame by frame, and the trace keeps at most
//! [`crate::trace::MAX_SAMPLES`] samples
//! (thinned evenly, as the bench's are). Bytes that are no frame are skipped to the next timestamp that is
//! followed by one (counted, not fatal), and no input makes it panic.

use std::io::{self, BufRead, Write};
use std::path::PathBuf;
use std::process::ExitCode;

use lbv_master_fw::console::lbv::{MavMessage, MavModeFlag};
use lbv_master_fw::console::outbound::rounded_div;
use mavlink_core::{MavlinkVersion, Message};

use crate::exit;
use crate::plot::{self, Format};
use crate::trace::{Event, Recorder, Sample, ThrusterSample, Trace};

const HELP: &str = "\
Reads a telemetry log: MAVLink frames, each after its 8-byte big-endian time in microseconds, as
the master serves its black box (ftp get @SYS/blackbox.tlog) and ground stations write their
.tlog files. The messages of one time make one moment: armed or not, the battery's voltage, and
each thruster's rpm, current and temperature (ESC_STATUS, ESC_INFO, BATTERY_STATUS, HEARTBEAT),
printed one line a moment, with the log's STATUSTEXTs between them.

With --plot, draws rpm, current, temperature, faults and events over time instead, as the bench
does (SVG or PNG by the file's extension).

Exit status: 0 the log was read; 1 nothing in it is a MAVLink frame; 2 bad command line, a file
that cannot be read or written.";

/// `lbv decode tlog`'s command line.
#[derive(Debug, Default, clap::Args)]
#[command(after_help = HELP)]
pub struct Args {
    /// The log; standard input when - or absent
    #[arg(value_name = "FILE")]
    pub input: Option<PathBuf>,
    /// Draw it into FILE.svg or FILE.png instead of printing it
    #[arg(long, value_name = "FILE.svg|FILE.png", value_parser = plot::file)]
    pub plot: Option<(PathBuf, Format)>,
}

/// `lbv decode tlog [FILE|-] [--plot FILE]`
pub fn main(args: &Args) -> ExitCode {
    let (input, name) = match super::open(args.input.as_deref()) {
        Ok(opened) => opened,
        Err(error) => {
            eprintln!("lbv decode tlog: {error}");
            return ExitCode::from(exit::TROUBLE);
        }
    };
    let stdout = io::stdout();
    let mut out = io::BufWriter::new(stdout.lock());
    let printing = args.plot.is_none();
    let read = read_trace(input, |item| match item {
        Item::Sample(sample) if printing => print_sample(&mut out, sample),
        Item::Event(event) if printing => writeln!(out, "t {:.3} s  {}", event.t, event.text),
        _ => Ok(()),
    });
    let (trace, stats) = match read {
        Ok(read) => read,
        Err(error) => return error.exit("lbv decode tlog", &name),
    };
    if let Err(error) = out.flush() {
        return super::StreamError::Write(error).exit("lbv decode tlog", &name);
    }
    if stats.frames == 0 {
        eprintln!("lbv decode tlog: {name} holds no MAVLink frame");
        return ExitCode::from(exit::FAILED);
    }
    if stats.skipped > 0 {
        eprintln!(
            "lbv decode tlog: {} bytes of {name} were no frame and were skipped",
            stats.skipped
        );
    }
    if let Some((path, format)) = &args.plot {
        let title = format!("{name}: {} frames", stats.frames);
        if let Err(error) = plot::write(&trace, &title, path, *format) {
            eprintln!("lbv decode tlog: {error}");
            return ExitCode::from(exit::TROUBLE);
        }
    }
    ExitCode::SUCCESS
}

/// What the reader hands on as it goes.
#[derive(Debug)]
pub enum Item<'a> {
    /// A moment's sample, complete.
    Sample(&'a Sample),
    /// A STATUSTEXT.
    Event(&'a Event),
}

/// How much of the log was read.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Stats {
    /// MAVLink frames read, whose CRC checked (those of messages this dialect does not know included).
    pub frames: u64,
    /// Bytes that were no frame after a timestamp.
    pub skipped: u64,
}

/// One frame of the log: its time and its message, when the dialect knows it.
struct Frame {
    t_us: u64,
    message: Option<MavMessage>,
}

/// Read a log into a trace, handing each sample and event to `each` as it is complete.
pub fn read_trace(
    mut input: impl BufRead,
    mut each: impl FnMut(Item<'_>) -> io::Result<()>,
) -> Result<(Trace, Stats), super::StreamError> {
    let mut trace = Trace::default();
    let mut recorder = Recorder::new(true);
    let mut stats = Stats::default();
    // The sample of the time being read, once a message has said something of it; and what the log has said so
    // far, which each sample starts from.
    let mut current: Option<Sample> = None;
    let mut state = Sample::default();
    let mut count = None;
    loop {
        let frame = next_frame(&mut input, &mut stats).map_err(super::StreamError::Read)?;
        let t = frame.as_ref().map(|frame| frame.t_us as f64 / 1e6);
        if current.as_ref().is_some_and(|sample| Some(sample.t) != t)
            && let Some(done) = current.take()
        {
            each(Item::Sample(&done)).map_err(super::StreamError::Write)?;
            recorder.sample(&mut trace, done);
        }
        let (Some(frame), Some(t)) = (frame, t) else {
            return Ok((trace, stats));
        };
        let Some(message) = frame.message else { continue };
        if let MavMessage::STATUSTEXT(text) = &message {
            let event = Event {
                t,
                text: String::from_utf8_lossy(text.text.as_slice())
                    .trim_end_matches('\0')
                    .to_string(),
            };
            each(Item::Event(&event)).map_err(super::StreamError::Write)?;
            recorder.event(&mut trace, event);
        } else if apply(&mut state, &mut count, &message) {
            state.t = t;
            current = Some(state.clone());
        }
    }
}

/// ESC_TELEMETRY's rpm (a magnitude) and current (cA) of thrusters `first..first + 4`.
fn telemetry(state: &mut Sample, count: Option<usize>, first: usize, rpm: &[u16; 4], current: &[u16; 4]) {
    for (i, (rpm, current)) in rpm.iter().zip(current).enumerate() {
        if let Some(t) = thruster(state, first + i, count) {
            t.rpm = f64::from(*rpm);
            t.current_a = f64::from(*current) / 100.0;
        }
    }
}

/// The most thrusters the ESC messages number: ESC_TELEMETRY's and the master's eight.
const MAX_THRUSTERS: usize = 8;

/// Take what `message` says into `state`, and into `count` how many thrusters there are once ESC_INFO says it:
/// whether it said anything the trace holds.
fn apply(state: &mut Sample, count: &mut Option<usize>, message: &MavMessage) -> bool {
    match message {
        MavMessage::HEARTBEAT(heartbeat) => {
            state.armed = heartbeat.base_mode.contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED);
        }
        MavMessage::BATTERY_STATUS(battery) => {
            state.battery_v = match battery.voltages.first() {
                Some(&mv) if mv != u16::MAX => f64::from(mv) / 1000.0,
                _ => f64::NAN,
            };
        }
        MavMessage::ESC_STATUS(status) => {
            for (i, (rpm, current)) in status.rpm.iter().zip(&status.current).enumerate() {
                if let Some(t) = thruster(state, usize::from(status.index) + i, *count) {
                    t.rpm = f64::from(*rpm);
                    t.current_a = f64::from(*current);
                }
            }
        }
        MavMessage::ESC_TELEMETRY_1_TO_4(t) => telemetry(state, *count, 0, &t.rpm, &t.current),
        MavMessage::ESC_TELEMETRY_5_TO_8(t) => telemetry(state, *count, 4, &t.rpm, &t.current),
        MavMessage::ESC_INFO(info) => {
            *count = Some(usize::from(info.count).min(MAX_THRUSTERS));
            state
                .thrusters
                .resize(usize::from(info.count).min(MAX_THRUSTERS), ThrusterSample::default());
            for (i, (temperature, flags)) in info.temperature.iter().zip(&info.failure_flags).enumerate() {
                if let Some(t) = state.thrusters.get_mut(usize::from(info.index) + i) {
                    t.online = info.info & 1 << i != 0;
                    t.temperature_c = if *temperature == i16::MAX {
                        f64::NAN
                    } else {
                        f64::from(*temperature) / 100.0
                    };
                    t.faults = fault_bits(*flags);
                }
            }
        }
        MavMessage::SERVO_OUTPUT_RAW(servo) => {
            let pulses = [
                servo.servo1_raw,
                servo.servo2_raw,
                servo.servo3_raw,
                servo.servo4_raw,
                servo.servo5_raw,
                servo.servo6_raw,
                servo.servo7_raw,
                servo.servo8_raw,
            ];
            for (t, pulse) in state.thrusters.iter_mut().zip(pulses) {
                t.ordered_step = step_of_pulse(pulse);
            }
        }
        _ => return false,
    }
    true
}

/// Thruster `n` of `state` (from 0): while no ESC_INFO has said how many there are (`count`), the thrusters up to
/// it are added as they first appear, up to the eight the ESC messages number.
fn thruster(state: &mut Sample, n: usize, count: Option<usize>) -> Option<&mut ThrusterSample> {
    if count.is_none() && n < MAX_THRUSTERS && state.thrusters.len() <= n {
        state.thrusters.resize(n + 1, ThrusterSample::default());
    }
    state.thrusters.get_mut(n)
}

/// The order's speed step of an ArduSub motor output (1500 us stopped, 400 us either way at full speed); 0 for an
/// output not driven.
fn step_of_pulse(pulse: u16) -> i8 {
    if pulse == 0 {
        return 0;
    }
    let max = i32::from(tmc_proto::Speed::MAX_STEP);
    rounded_div((i32::from(pulse) - 1500) * max, 400).clamp(-max, max) as i8
}

/// The thruster fault bits (tmc-proto `Faults`) ESC_INFO's failure flags stand for: overtemperature, stall; a
/// generic failure is drawn as a hall fault (hall and ground faults both read as generic).
fn fault_bits(flags: u16) -> u8 {
    u8::from(flags & 4 != 0) | u8::from(flags & 32 != 0) << 1 | u8::from(flags & 64 != 0) << 2
}

/// Print one sample on a line.
fn print_sample(out: &mut impl Write, sample: &Sample) -> io::Result<()> {
    write!(
        out,
        "t {:.3} s  {}  {:.1} V",
        sample.t,
        if sample.armed { "armed" } else { "disarmed" },
        sample.battery_v
    )?;
    for (n, t) in sample.thrusters.iter().enumerate() {
        write!(out, "  T{} {:.0} rpm {:.1} A", n + 1, t.rpm, t.current_a)?;
        if t.temperature_c.is_finite() {
            write!(out, " {:.0} C", t.temperature_c)?;
        }
        if !t.online {
            write!(out, " offline")?;
        }
    }
    writeln!(out)
}

/// The next frame: its timestamp, then a MAVLink 1 or 2 frame whose CRC checks. What does not make one is skipped
/// a byte at a time, counted in `stats.skipped`. `None` at the end of the input.
fn next_frame(input: &mut impl BufRead, stats: &mut Stats) -> io::Result<Option<Frame>> {
    let mut window: Vec<u8> = Vec::with_capacity(8 + 280);
    loop {
        // At least a timestamp and the frame's header in the window.
        if !fill(input, &mut window, 8 + 10)? {
            stats.skipped += window.len() as u64;
            return Ok(None);
        }
        if let Some(len) = frame_len(&window[8..]) {
            if !fill(input, &mut window, 8 + len)? {
                stats.skipped += window.len() as u64;
                return Ok(None);
            }
            if let Some(message) = check(&window[8..8 + len]) {
                stats.frames += 1;
                let t_us = u64::from_be_bytes(window[..8].try_into().unwrap_or_default());
                return Ok(Some(Frame { t_us, message }));
            }
        }
        window.remove(0);
        stats.skipped += 1;
    }
}

/// Read into `window` until it holds `n` bytes: false at the end of the input before that.
fn fill(input: &mut impl BufRead, window: &mut Vec<u8>, n: usize) -> io::Result<bool> {
    while window.len() < n {
        let available = input.fill_buf()?;
        if available.is_empty() {
            return Ok(false);
        }
        let take = available.len().min(n - window.len());
        window.extend_from_slice(&available[..take]);
        input.consume(take);
    }
    Ok(true)
}

/// The length of the frame `bytes` begin with, by its header: MAVLink 2 (0xFD, a signature when its first
/// incompatibility flag says so) or 1 (0xFE).
fn frame_len(bytes: &[u8]) -> Option<usize> {
    match bytes {
        [0xFD, len, flags, ..] => Some(10 + usize::from(*len) + 2 + if flags & 1 != 0 { 13 } else { 0 }),
        [0xFE, len, ..] => Some(6 + usize::from(*len) + 2),
        _ => None,
    }
}

/// The frame's message if its CRC checks; `Some(None)` for a message the dialect does not know, taken by its
/// header alone (its CRC cannot be checked without its CRC_EXTRA).
fn check(frame: &[u8]) -> Option<Option<MavMessage>> {
    let (version, id, header_len) = match frame {
        [0xFD, _, _, _, _, _, _, a, b, c, ..] => (MavlinkVersion::V2, u32::from_le_bytes([*a, *b, *c, 0]), 10),
        [0xFE, _, _, _, _, id, ..] => (MavlinkVersion::V1, u32::from(*id), 6),
        _ => return None,
    };
    let len = usize::from(*frame.get(1)?);
    let payload = frame.get(header_len..header_len + len)?;
    let crc = frame.get(header_len + len..header_len + len + 2)?;
    let Some(extra) = known_extra_crc(id) else {
        return Some(None);
    };
    let computed = mavlink_core::calculate_crc(frame.get(1..header_len + len)?, extra);
    if computed.to_le_bytes() != crc {
        return None;
    }
    Some(MavMessage::parse(version, id, payload).ok())
}

/// CRC_EXTRA of a message this dialect knows.
fn known_extra_crc(id: u32) -> Option<u8> {
    MavMessage::default_message_from_id(id).map(|_| MavMessage::extra_crc(id))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pulses_read_back_as_steps() {
        assert_eq!(step_of_pulse(1500), 0);
        assert_eq!(step_of_pulse(1900), 102);
        assert_eq!(step_of_pulse(1100), -102);
        assert_eq!(step_of_pulse(0), 0);
        assert_eq!(step_of_pulse(u16::MAX), 102);
    }

    #[test]
    fn bytes_that_are_no_frame_are_skipped_and_nothing_panics() {
        for input in [
            &b""[..],
            &[0xFD; 7],
            &[0u8; 100],
            &[0xFD, 255, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0],
        ] {
            let (trace, stats) = read_trace(input, |_| Ok(())).unwrap();
            assert_eq!(stats.frames, 0);
            assert!(trace.samples.is_empty());
        }
    }
}
