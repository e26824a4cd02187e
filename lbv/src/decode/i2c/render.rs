//! The human line of a record.

use super::record::{Kind, Record, nack_text};

/// A signed speed step: `+51`, `-20`, `0`.
fn step_text(step: i8) -> String {
    if step == 0 { "0".into() } else { format!("{step:+}") }
}

fn millis_text(seconds: f64) -> String {
    format!("+{:.3} ms", seconds * 1e3)
}

/// The human line of a record.
pub(super) fn human(record: &Record) -> String {
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
