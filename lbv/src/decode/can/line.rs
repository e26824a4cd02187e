//! candump log lines read into frames: the time, the interface and the frame as can-utils writes it, with
//! what is wrong with a line that is not one, in words.

/// The error-frame flag in an 8-digit candump ID.
const CAN_ERR_FLAG: u32 = 0x2000_0000;

/// One line of a candump log.
#[derive(Debug, PartialEq, Eq)]
pub(super) enum Line<'a> {
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
pub(super) enum CanFrame {
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
pub(super) enum Other {
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
pub(super) fn parse_line(line: &[u8]) -> Result<Line<'_>, &'static str> {
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
