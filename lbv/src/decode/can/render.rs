//! A decoded BAT frame as output: the human line, or the JSON object serialised with serde_json. Both are
//! appended to the decoder's output buffer.

use std::io::Write;

use bat_proto::{BatteryInfo, BmsAlarms, DcdcStatus, DecodeError, StatusBit};
use serde::{Serialize, Serializer};
use serde_json::value::RawValue;

/// What one frame with a BAT ID gives to print.
#[derive(Debug, Clone, Copy)]
pub(super) enum Report {
    Info(BatteryInfo),
    /// A status, and the previous one on the same interface: none at the first, which is reported as at start-up.
    Status {
        status: DcdcStatus,
        previous: Option<DcdcStatus>,
    },
    /// BMS alarms, and the previous ones on the same interface (none before the first).
    Alarms {
        alarms: BmsAlarms,
        previous: BmsAlarms,
    },
    /// A frame that bat-proto rejected, with its line number.
    Error {
        line: u64,
        error: DecodeError,
    },
}

/// The alarms raised and the alarms cleared since `previous`.
fn raised_cleared(alarms: BmsAlarms, previous: BmsAlarms) -> (BmsAlarms, BmsAlarms) {
    (
        BmsAlarms::from_bits_truncate(alarms.bits() & !previous.bits()),
        BmsAlarms::from_bits_truncate(previous.bits() & !alarms.bits()),
    )
}

/// The human line: `T 0xNNN` and the frame in words.
pub(super) fn human(out: &mut Vec<u8>, time: &[u8], id: u16, report: Report) {
    out.extend_from_slice(time);
    out.extend_from_slice(b" 0x");
    for shift in [8, 4, 0] {
        out.push(b"0123456789abcdef"[usize::from(id >> shift & 0xF)]);
    }
    match report {
        Report::Info(info) => human_info(out, info),
        Report::Status { status, previous } => human_status(out, status, previous),
        Report::Alarms { alarms, previous } => human_alarms(out, alarms, previous),
        Report::Error { line, error } => {
            let _ = write!(out, " error (line {line}): {error}");
        }
    }
    out.push(b'\n');
}

fn human_info(out: &mut Vec<u8>, info: BatteryInfo) {
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

fn human_status(out: &mut Vec<u8>, status: DcdcStatus, previous: Option<DcdcStatus>) {
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

fn human_alarms(out: &mut Vec<u8>, alarms: BmsAlarms, previous: BmsAlarms) {
    let (raised, cleared) = raised_cleared(alarms, previous);
    let _ = write!(out, " bms alarms {:#04x} ", alarms.bits());
    push_list(out, alarms.iter().map(BmsAlarms::name), "none");
    for (label, which) in [("; raised: ", raised), ("; cleared: ", cleared)] {
        if !which.is_empty() {
            out.extend_from_slice(label.as_bytes());
            push_list(out, which.iter().map(BmsAlarms::name), "");
        }
    }
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
pub(super) fn push_tenths(out: &mut Vec<u8>, tenths: i32) {
    if tenths < 0 {
        out.push(b'-');
    }
    let magnitude = tenths.unsigned_abs();
    push_u64(out, u64::from(magnitude / 10));
    out.push(b'.');
    out.push(b'0' + (magnitude % 10) as u8);
}

/// One object of the JSON output: the frame's time and ID, then the fields of its kind.
#[derive(Debug, Serialize)]
struct JsonLine<'a> {
    /// The log's own digits ([`json_time`]): as an f64 they would lose their trailing zeros.
    time: &'a RawValue,
    id: u16,
    #[serde(flatten)]
    fields: JsonFields,
}

/// The fields of each kind of frame, in the order they are written.
#[derive(Debug, Serialize)]
#[serde(untagged)]
enum JsonFields {
    /// `null` for a value the frame does not report (sent as 0) or out of range.
    Info {
        voltage_v: f64,
        current_a: Option<f64>,
        charge_pct: Option<u8>,
        temperature_c: Option<f64>,
    },
    Status {
        status: u16,
        status_bits: StatusNames,
        /// The bits that switched; none at an interface's first status, which has nothing to compare with.
        changed: StatusNames,
    },
    Alarms {
        alarms: u8,
        alarm_bits: AlarmNames,
        /// The alarms raised or cleared.
        changed: AlarmNames,
    },
    Error {
        line: u64,
        error: String,
    },
}

/// The bits set in a status word, as an array of their names in bit order.
#[derive(Debug)]
struct StatusNames(DcdcStatus);

impl Serialize for StatusNames {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_seq(self.0.set_bits().map(StatusBit::name))
    }
}

/// The alarms set, as an array of their names in bit order.
#[derive(Debug)]
struct AlarmNames(BmsAlarms);

impl Serialize for AlarmNames {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_seq(self.0.iter().map(BmsAlarms::name))
    }
}

/// A value in tenths as a JSON number: serde_json writes the shortest digits that read back the same, which
/// for these values are one decimal, as in the human line (`42.0`, `-2.5`).
pub(super) fn tenths(tenths: i32) -> f64 {
    f64::from(tenths) / 10.0
}

/// The JSON object, on one line.
pub(super) fn json(out: &mut Vec<u8>, time: &[u8], id: u16, report: Report) {
    let fields = match report {
        Report::Info(info) => JsonFields::Info {
            voltage_v: tenths(i32::from(info.voltage_decivolts)),
            current_a: info.current_deciamps.map(|current| tenths(i32::from(current))),
            charge_pct: info.charge_percent,
            temperature_c: info
                .temperature_decicelsius
                .map(|temperature| tenths(i32::from(temperature))),
        },
        Report::Status { status, previous } => JsonFields::Status {
            status: status.word(),
            status_bits: StatusNames(status),
            changed: StatusNames(
                previous
                    .map(|previous| DcdcStatus::from_word(status.word() ^ previous.word()))
                    .unwrap_or_default(),
            ),
        },
        Report::Alarms { alarms, previous } => {
            let (raised, cleared) = raised_cleared(alarms, previous);
            JsonFields::Alarms {
                alarms: alarms.bits(),
                alarm_bits: AlarmNames(alarms),
                changed: AlarmNames(raised.union(cleared)),
            }
        }
        Report::Error { line, error } => JsonFields::Error {
            line,
            error: error.to_string(),
        },
    };
    let line = JsonLine {
        time: json_time(time),
        id,
        fields,
    };
    // Writing to a Vec does not fail, and every field serialises.
    let _ = serde_json::to_writer(&mut *out, &line);
    out.push(b'\n');
}

/// The log's time as a JSON number: the same digits without the leading zeros candump pads it with
/// (`0000000012.5` is `12.5`; JSON forbids leading zeros).
pub(super) fn json_time(time: &[u8]) -> &RawValue {
    let significant = time.iter().position(|&byte| byte != b'0').unwrap_or(time.len());
    // One zero stays before the dot, or as the whole number.
    let start = match time.get(significant) {
        None | Some(b'.') => significant.saturating_sub(1),
        Some(_) => significant,
    };
    // parse_time let through only digits with at most one dot between them: a JSON number once the padding is
    // off, so the null is never written.
    let digits = std::str::from_utf8(&time[start..]).unwrap_or_default();
    serde_json::from_str(digits).unwrap_or(RawValue::NULL)
}
