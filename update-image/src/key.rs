//! Keys as they are kept: 32 bytes in hex, one line.

/// The development public key, `keys/dev.pub`. Its secret, `keys/dev.key`, is published with the source, so
/// anyone can sign images a device that holds this key accepts: tools use it to say "signed with the development
/// key", and a release build refuses it (keys/README.md).
pub const DEV_PUBLIC_KEY: [u8; 32] = [
    0x1e, 0x69, 0x35, 0xc4, 0x7d, 0xfc, 0x05, 0x39, 0x9e, 0x73, 0x53, 0x77, 0x89, 0x2f, 0x67, 0xcf, 0x2d, 0x96, 0xf0,
    0x43, 0xf8, 0xd8, 0xf2, 0xde, 0xa9, 0xdd, 0xe1, 0x54, 0x67, 0x91, 0xc9, 0x54,
];

#[cfg(feature = "key")]
include!(concat!(env!("OUT_DIR"), "/update_key.rs"));

pub use crate::hex::key_from_hex;

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
