//! A finished transfer as a record: its bytes decoded with `tmc-proto` as a thruster order or status, a mux
//! select, or left raw. The JSON output is the record serialised; the human line is made from it.

use serde::Serialize;
use tmc_proto::{Family, Faults, MaxPower, MotorKind, ORDER_LEN, Order, Speed, Status, checksum};

use super::MAX_TRANSFER_BYTES;
use super::assemble::Transfer;

/// What kind of transfer a record is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Default)]
#[serde(rename_all = "lowercase")]
pub(super) enum Kind {
    Order,
    Status,
    #[default]
    Other,
}

/// One transfer as printed: the JSON object, and the source of the human line.
#[derive(Debug, Default, Serialize)]
pub(super) struct Record {
    /// Start (START condition) in seconds from the start of the capture; null when the export gives no time.
    pub(super) time: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) sample: Option<u64>,
    /// Transfer number, from 0.
    pub(super) index: u64,
    /// 7-bit address.
    pub(super) address: u8,
    pub(super) direction: &'static str,
    /// Whether a device acknowledged the address; null when the capture stops before.
    pub(super) ack: Option<bool>,
    pub(super) bytes: Vec<u8>,
    pub(super) family: Option<&'static str>,
    pub(super) kind: Kind,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) device: Option<&'static str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) mux_channels: Option<Vec<u8>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) speed_step: Option<i8>,
    /// Brushless reading of the speed (full scale 4500 rpm; IDS 8.3.2).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) speed_rpm: Option<i32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) info: Option<u8>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) revision: Option<u8>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) motor: Option<&'static str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) current_limited: Option<bool>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) faults: Option<Vec<&'static str>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) current_a: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) temperature_c: Option<u8>,
    /// Legacy brushed status: the power set into the motor, as a speed step.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) power_step: Option<i8>,
    /// Legacy status: the MAX POWER byte as received.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) max_power: Option<u8>,
    /// Whether CSUM matches the bytes before it; null when there is no thruster message of the right length.
    pub(super) checksum_ok: Option<bool>,
    /// A status in the implied-type form (MT taken as the address byte: 6 SeaBotix bytes, 3 Legacy, read alone or
    /// followed by an idle byte): "implied-type"; absent for the full form.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) form: Option<&'static str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) error: Option<String>,
    /// Seconds since the previous transfer started (any address).
    pub(super) since_prev_s: Option<f64>,
    /// Seconds since the previous transfer to the same address started.
    pub(super) since_prev_same_address_s: Option<f64>,
    /// Seconds from START to STOP (or to the repeated START that ends it).
    pub(super) duration_s: Option<f64>,
}

/// The TCA9548A I2C multiplexer's address range.
const MUX_ADDRESSES: std::ops::RangeInclusive<u8> = 0x70..=0x77;

/// Build the record of a finished transfer.
pub(super) fn record(transfer: Transfer, index: u64) -> Record {
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
pub(super) fn nack_text(thruster: bool) -> &'static str {
    if thruster {
        "address NACKed: no thruster answered"
    } else {
        "address NACKed: no device answered"
    }
}

/// Round a duration to the nanosecond, so differences of sample times print short.
pub(super) fn round_ns(seconds: f64) -> f64 {
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
pub(super) fn decode_status(record: &mut Record, family: Family, bytes: &[u8]) {
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
