//! Keys as they are kept, 32 bytes in hex on one line: read here by the crate and by its build script.

/// The 32-byte key written in `text` as 64 hex digits (either case), with any whitespace around them (a key file's
/// line end); `None` for anything else. Const, so a build can embed a key file's bytes with `include_str!`.
pub const fn key_from_hex(text: &str) -> Option<[u8; 32]> {
    let mut digits = text.trim_ascii().as_bytes();
    if digits.len() != 64 {
        return None;
    }
    let mut key = [0u8; 32];
    let mut bytes: &mut [u8] = &mut key;
    // Two digits a byte: the digits and the bytes walked in step, so there is no index to go out of bounds.
    while let ([high, low, rest @ ..], [byte, more @ ..]) = (digits, bytes) {
        let (Some(high), Some(low)) = (hex_digit(*high), hex_digit(*low)) else {
            return None;
        };
        *byte = (high << 4) | low;
        digits = rest;
        bytes = more;
    }
    Some(key)
}

/// The value of one hex digit.
const fn hex_digit(byte: u8) -> Option<u8> {
    match byte {
        b'0'..=b'9' => Some(byte - b'0'),
        b'a'..=b'f' => Some(byte - b'a' + 10),
        b'A'..=b'F' => Some(byte - b'A' + 10),
        _ => None,
    }
}
