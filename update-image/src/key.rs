//! Keys as they are kept: 32 bytes in hex, one line.

/// The development public key, `keys/dev.pub`. Its secret, `keys/dev.key`, is published with the source, so
/// anyone can sign images a device that holds this key accepts: tools use it to say "signed with the development
/// key", and a release build refuses it (keys/README.md).
pub const DEV_PUBLIC_KEY: [u8; 32] = [
    0x1e, 0x69, 0x35, 0xc4, 0x7d, 0xfc, 0x05, 0x39, 0x9e, 0x73, 0x53, 0x77, 0x89, 0x2f, 0x67, 0xcf, 0x2d, 0x96, 0xf0,
    0x43, 0xf8, 0xd8, 0xf2, 0xde, 0xa9, 0xdd, 0xe1, 0x54, 0x67, 0x91, 0xc9, 0x54,
];

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_a_key_line() {
        let text = "000102030405060708090a0b0c0d0e0f101112131415161718191A1B1C1D1E1F\n";
        let key = key_from_hex(text).unwrap();
        for (i, byte) in key.iter().enumerate() {
            assert_eq!(*byte as usize, i);
        }
        assert_eq!(key_from_hex(&format!("  {}\r\n", text.trim())), Some(key));
        const AT_COMPILE_TIME: Option<[u8; 32]> =
            key_from_hex("ffffffffffffffffffffffffffffffffffffffffffffffffffffffffffffffff");
        assert_eq!(AT_COMPILE_TIME, Some([0xFF; 32]));
    }

    #[test]
    fn refuses_anything_else() {
        let good = "000102030405060708090a0b0c0d0e0f101112131415161718191a1b1c1d1e1f";
        for bad in [
            "".to_string(),
            good[..62].to_string(),
            format!("{good}00"),
            good.replace('a', "g"),
            format!("{} {}", &good[..32], &good[32..]),
            format!("0x{}", &good[2..]),
            good.replace("0a", "é"),
        ] {
            assert_eq!(key_from_hex(&bad), None, "{bad:?}");
        }
    }

    #[test]
    fn the_dev_key_is_keys_dev_pub() {
        let file = include_str!("../../keys/dev.pub");
        assert_eq!(key_from_hex(file), Some(DEV_PUBLIC_KEY));
    }
}
