//! The annotation line formats: sigrok-cli's text output (any log level, with or without sample numbers),
//! PulseView's annotation export and sigrok-cli's JSON trace, each line read into one annotation.

/// What one annotation says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Event {
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
pub(super) enum Stamp {
    None,
    /// Start and end sample numbers.
    Samples(u64, u64),
    /// Start time in seconds (trace events).
    Seconds(f64),
}

/// One annotation line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Annotation {
    pub(super) event: Event,
    pub(super) stamp: Stamp,
}

/// Read one line: `Ok(None)` for lines with nothing to read (blank, `#` comments, trace header and footer, trace
/// end events), an error saying why for lines that are not I2C annotations. Linear in the line's length.
pub(super) fn parse_line(line: &str) -> Result<Option<Annotation>, String> {
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
pub(super) fn candidates(rest: &str) -> impl Iterator<Item = &str> {
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
