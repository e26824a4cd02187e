//! Making update files, on the host: ed25519-dalek, an ed25519 other than the one the devices verify with, so the
//! tests that sign here and verify with salty and embassy-boot check two implementations against each other.

use std::fmt;
use std::vec::Vec;

use ed25519_dalek::{Signer, SigningKey};
use sha2::{Digest, Sha512};

use crate::{HEADER_LEN, Header, INFO_OFFSET, ImageInfo, InfoError, PAD_BYTE, WRITE_UNIT};

/// Why an update file could not be made.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SignError {
    /// The payload holds no image info at [`INFO_OFFSET`].
    Info(InfoError),
    /// The payload does not fit the header's u32 length.
    TooLarge(usize),
}

/// The update file of `payload` (the image as it sits in flash from the ACTIVE partition's start), signed with the
/// secret key `seed`: the header, then the payload padded with 0xFF to a whole number of [`WRITE_UNIT`]s. The
/// header's target and version are the payload's own image info's, read at [`INFO_OFFSET`], so the two cannot
/// disagree; the signature is over SHA-512 of the padded payload, what embassy-boot's `verify_and_mark_updated`
/// checks with `update_len` = its length.
pub fn sign(payload: &[u8], seed: &[u8; 32]) -> Result<Vec<u8>, SignError> {
    let info = ImageInfo::parse(payload.get(INFO_OFFSET..).unwrap_or_default()).map_err(SignError::Info)?;
    let padded_len = payload.len().div_ceil(WRITE_UNIT).saturating_mul(WRITE_UNIT);
    let payload_len = u32::try_from(padded_len).map_err(|_| SignError::TooLarge(payload.len()))?;
    let mut file = Vec::with_capacity(HEADER_LEN.saturating_add(padded_len));
    file.resize(HEADER_LEN, 0);
    file.extend_from_slice(payload);
    file.resize(HEADER_LEN.saturating_add(padded_len), PAD_BYTE);
    let digest = Sha512::digest(file.get(HEADER_LEN..).unwrap_or_default());
    let signature = SigningKey::from_bytes(seed).sign(&digest).to_bytes();
    let header = Header {
        target: info.target,
        payload_len,
        version: info.version,
        signature,
    };
    if let Some(start) = file.first_chunk_mut::<HEADER_LEN>() {
        *start = header.to_bytes();
    }
    Ok(file)
}

/// A new secret key (its 32-byte seed), from the operating system's random source.
pub fn keygen() -> Result<[u8; 32], getrandom::Error> {
    let mut seed = [0; 32];
    getrandom::fill(&mut seed)?;
    Ok(seed)
}

/// The public key of the secret key `seed`.
pub fn public_key(seed: &[u8; 32]) -> [u8; 32] {
    SigningKey::from_bytes(seed).verifying_key().to_bytes()
}

impl fmt::Display for SignError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SignError::Info(error) => write!(f, "offset {INFO_OFFSET:#x}: {error}"),
            SignError::TooLarge(len) => write!(f, "a payload of {len} bytes is too large for an update file"),
        }
    }
}

impl std::error::Error for SignError {}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{INFO_LEN, Target, Version, check_file};

    fn payload(len: usize, info: ImageInfo) -> Vec<u8> {
        let mut payload: Vec<u8> = (0..len).map(|i| i as u8).collect();
        payload[INFO_OFFSET..INFO_OFFSET + INFO_LEN].copy_from_slice(&info.to_bytes());
        payload
    }

    #[test]
    fn pads_to_the_write_unit_and_takes_the_header_from_the_info() {
        let info = ImageInfo::new(Target::ThrusterLegacy, Version::new(0, 3, 1));
        for len in [0x240, 0x241, 0x247, 0x248, 0x249, 4093] {
            let payload = payload(len, info);
            let file = sign(&payload, &[7; 32]).unwrap();
            let padded = len.div_ceil(8) * 8;
            assert_eq!(file.len(), HEADER_LEN + padded);
            assert_eq!(&file[HEADER_LEN..HEADER_LEN + len], &payload[..]);
            assert!(file[HEADER_LEN + len..].iter().all(|byte| *byte == 0xFF));
            let header = Header::parse(&file).unwrap();
            assert_eq!(header.payload_len as usize, padded);
            assert_eq!((header.target, header.version), (info.target, info.version));
            assert_eq!(check_file(&file, info.target, 1 << 20), Ok((header, info)));
        }
    }

    #[test]
    fn refuses_a_payload_without_image_info() {
        assert_eq!(
            sign(&[0xFF; 0x300], &[7; 32]),
            Err(SignError::Info(InfoError::Magic([0xFF; 4])))
        );
        assert_eq!(
            sign(&[0; 0x210], &[7; 32]),
            Err(SignError::Info(InfoError::Short { len: 0x10 }))
        );
        assert_eq!(sign(&[], &[7; 32]), Err(SignError::Info(InfoError::Short { len: 0 })));
    }

    #[test]
    fn keys_are_fresh_and_their_public_halves_stable() {
        let (a, b) = (keygen().unwrap(), keygen().unwrap());
        assert_ne!(a, b);
        assert_eq!(public_key(&a), public_key(&a));
        assert_ne!(public_key(&a), public_key(&b));
        // RFC 8032 7.1, test 1: the secret key and its public key.
        let seed = [
            0x9d, 0x61, 0xb1, 0x9d, 0xef, 0xfd, 0x5a, 0x60, 0xba, 0x84, 0x4a, 0xf4, 0x92, 0xec, 0x2c, 0xc4, 0x44, 0x49,
            0xc5, 0x69, 0x7b, 0x32, 0x69, 0x19, 0x70, 0x3b, 0xac, 0x03, 0x1c, 0xae, 0x7f, 0x60,
        ];
        let public = [
            0xd7, 0x5a, 0x98, 0x01, 0x82, 0xb1, 0x0a, 0xb7, 0xd5, 0x4b, 0xfe, 0xd3, 0xc9, 0x64, 0x07, 0x3a, 0x0e, 0xe1,
            0x72, 0xf3, 0xda, 0xa6, 0x23, 0x25, 0xaf, 0x02, 0x1a, 0x68, 0xf7, 0x07, 0x51, 0x1a,
        ];
        assert_eq!(public_key(&seed), public);
    }
}
