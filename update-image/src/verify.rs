//! Checking a payload's signature as it streams through, with the answer embassy-boot gives.
//!
//! embassy-boot's `verify_and_mark_updated` (feature `ed25519-salty`) hashes DFU bytes `[0, update_len)` with
//! SHA-512 and verifies the header's signature over that 64-byte digest with salty's ed25519, plain (not the
//! prehashed ed25519ph). This does the same, a chunk at a time, so the master can refuse a forged image before it
//! sends any of it on, and a device checks its own without embassy-boot's verifier in its image. Its curve
//! arithmetic is salty's; two parts are chosen for size on the chip, each checked against salty's in the tests:
//! the SHA-512 is RustCrypto's (compact on the firmware target: 0.9 KiB smaller than salty's, from the crate whose
//! SHA-256 the master signs MAVLink with), and the reduction of the hash mod L is a loop of a few hundred bytes in place
//! of salty's 4.5 KiB unrolled one (see [`check`]).

use core::fmt;

use sha2::Digest;

use crate::Header;

/// The SHA-512 of the payload so far, and how many bytes it has had.
pub struct Verifier {
    hash: sha2::Sha512,
    received: u64,
}

/// Why a signature was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum VerifyError {
    /// The payload given is not as long as the header announces.
    Length {
        /// What the header announces.
        announced: u32,
        /// What was given.
        received: u64,
    },
    /// The public key is not a point of the curve: no signature verifies with it.
    PublicKey,
    /// The signature is not the key's over this payload.
    Signature,
}

impl Verifier {
    /// Nothing hashed yet.
    pub fn new() -> Verifier {
        Verifier {
            hash: sha2::Sha512::new(),
            received: 0,
        }
    }

    /// The next bytes of the payload.
    pub fn update(&mut self, chunk: &[u8]) {
        self.hash.update(chunk);
        self.received = self.received.saturating_add(chunk.len() as u64);
    }

    /// How many payload bytes it has had.
    pub fn received(&self) -> u64 {
        self.received
    }

    /// The SHA-512 digest of the payload: the message the signature is over.
    pub fn digest(self) -> [u8; 64] {
        self.hash.finalize().into()
    }

    /// Whether `signature` is `public_key`'s over the payload hashed, as embassy-boot would answer for the same
    /// bytes in DFU, but for one thing: a signature whose S is not below the group order L is refused, as RFC 8032
    /// (5.1.7) asks and salty does not check, so that a payload's signature has one encoding only. The caller sees
    /// to it that the bytes hashed are the header's `payload_len` (or uses [`finish_header`](Verifier::finish_header)).
    pub fn finish(self, signature: &[u8; 64], public_key: &[u8; 32]) -> Result<(), VerifyError> {
        Verifier::check_digest(&self.digest(), signature, public_key)
    }

    /// [`finish`](Verifier::finish) for a payload whose [`digest`](Verifier::digest) was taken already.
    pub fn check_digest(digest: &[u8; 64], signature: &[u8; 64], public_key: &[u8; 32]) -> Result<(), VerifyError> {
        if !s_below_order(signature) {
            return Err(VerifyError::Signature);
        }
        check(digest, signature, public_key)
    }

    /// [`finish`](Verifier::finish) with the header's signature, once exactly its payload length has been hashed.
    pub fn finish_header(self, header: &Header, public_key: &[u8; 32]) -> Result<(), VerifyError> {
        if self.received != u64::from(header.payload_len) {
            return Err(VerifyError::Length {
                announced: header.payload_len,
                received: self.received,
            });
        }
        self.finish(&header.signature, public_key)
    }
}

/// The order L of ed25519's base point, little-endian: 2^252 + 27742317777372353535851937790883648493.
const ORDER: [u8; 32] = [
    0xED, 0xD3, 0xF5, 0x5C, 0x1A, 0x63, 0x12, 0x58, 0xD6, 0x9C, 0xF7, 0xA2, 0xDE, 0xF9, 0xDE, 0x14, 0, 0, 0, 0, 0, 0,
    0, 0, 0, 0, 0, 0, 0, 0, 0, 0x10,
];

/// Whether the signature's S (its second half, little-endian) is below [`ORDER`].
fn s_below_order(signature: &[u8; 64]) -> bool {
    signature
        .last_chunk::<32>()
        .is_some_and(|s| below(&limbs(s), &limbs(&ORDER)))
}

/// Whether `signature` (its S below L) is `public_key`'s over `message`. RFC 8032 5.1.7: with
/// k = SHA-512(R || A || M) mod L, the signature holds when `[S]B = R + [k]A`, checked as salty's `verify` does,
/// by encoding `[S]B - [k]A` and comparing it with R.
fn check(message: &[u8; 64], signature: &[u8; 64], public_key: &[u8; 32]) -> Result<(), VerifyError> {
    let key = salty::CompressedY(*public_key)
        .decompressed()
        .map_err(|_| VerifyError::PublicKey)?;
    let signature = salty::Signature::from(signature);
    let hash: [u8; 64] = sha2::Sha512::new()
        .chain_update(signature.r.0)
        .chain_update(public_key)
        .chain_update(message)
        .finalize()
        .into();
    let k = salty::Scalar::from_bytes(&reduce_mod_order(&hash));
    let sum = &(&signature.s * &salty::EdwardsPoint::basepoint()) + &(&k * &-&key);
    if sum.compressed() == signature.r {
        Ok(())
    } else {
        Err(VerifyError::Signature)
    }
}

/// A 512-bit little-endian number mod [`ORDER`], little-endian: binary long division, one bit at a time from the
/// top (`r = 2r + bit`, less L when at or above it), so `r` stays below L and always fits its 256 bits.
/// Variable-time, which is fine here: everything a verification handles is public.
fn reduce_mod_order(wide: &[u8; 64]) -> [u8; 32] {
    let order = limbs(&ORDER);
    let mut r = [0u32; 8];
    for byte in wide.iter().rev() {
        for bit in (0..8).rev() {
            // r = 2r + bit: r < L < 2^253, so 2r + 1 < 2^254 and no bit leaves the top limb.
            let mut carry = u32::from(byte >> bit & 1);
            for limb in r.iter_mut() {
                let next = *limb >> 31;
                *limb = *limb << 1 | carry;
                carry = next;
            }
            if !below(&r, &order) {
                let mut borrow = false;
                for (limb, l) in r.iter_mut().zip(order) {
                    let (difference, under) = limb.overflowing_sub(l);
                    let (difference, under_again) = difference.overflowing_sub(u32::from(borrow));
                    *limb = difference;
                    borrow = under || under_again;
                }
            }
        }
    }
    let mut bytes = [0u8; 32];
    for (chunk, limb) in bytes.chunks_exact_mut(4).zip(r) {
        chunk.copy_from_slice(&limb.to_le_bytes());
    }
    bytes
}

/// The 32 little-endian bytes as eight little-endian 32-bit limbs.
fn limbs(bytes: &[u8; 32]) -> [u32; 8] {
    let mut limbs = [0u32; 8];
    for (limb, chunk) in limbs.iter_mut().zip(bytes.chunks_exact(4)) {
        *limb = chunk.iter().rev().fold(0, |value, byte| value << 8 | u32::from(*byte));
    }
    limbs
}

/// Whether `a < b`, both little-endian limbs.
fn below(a: &[u32; 8], b: &[u32; 8]) -> bool {
    for (a, b) in a.iter().rev().zip(b.iter().rev()) {
        if a != b {
            return a < b;
        }
    }
    false
}

impl Default for Verifier {
    fn default() -> Self {
        Verifier::new()
    }
}

impl fmt::Debug for Verifier {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Verifier")
            .field("received", &self.received)
            .finish_non_exhaustive()
    }
}

/// Whether the header's signature is `public_key`'s over `payload`, a whole payload in memory.
pub fn verify(header: &Header, payload: &[u8], public_key: &[u8; 32]) -> Result<(), VerifyError> {
    let mut verifier = Verifier::new();
    verifier.update(payload);
    verifier.finish_header(header, public_key)
}

impl fmt::Display for VerifyError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            VerifyError::Length { announced, received } => write!(
                f,
                "the header announces a payload of {announced} bytes, {received} were checked"
            ),
            VerifyError::PublicKey => f.write_str("the public key is not an ed25519 key"),
            VerifyError::Signature => f.write_str("the signature does not verify with this key"),
        }
    }
}

impl core::error::Error for VerifyError {}

#[cfg(test)]
mod tests {
    //! The digest, the reduction and the check against salty's own (`Sha512`, `Scalar::from_u512_le`,
    //! `PublicKey::verify`), on the edges and on random values; signatures made by ed25519-dalek, an implementation
    //! independent of both.
    #![allow(clippy::indexing_slicing, clippy::unwrap_used)]

    use ed25519_dalek::{Signer, SigningKey};
    use proptest::prelude::*;

    use super::*;

    fn salty_reduce(wide: &[u8; 64]) -> [u8; 32] {
        salty::Scalar::from_u512_le(wide).to_bytes()
    }

    /// L as 64 bytes, times a small factor, plus a small offset (wrapping at 2^512).
    fn multiple_of_order(factor: u8, plus: i8) -> [u8; 64] {
        let mut wide = [0u8; 64];
        let mut carry = i32::from(plus);
        for (i, byte) in wide.iter_mut().enumerate() {
            let l = i32::from(ORDER.get(i).copied().unwrap_or(0));
            let value = l * i32::from(factor) + carry;
            *byte = value.rem_euclid(256) as u8;
            carry = value.div_euclid(256);
        }
        wide
    }

    #[test]
    fn the_reduction_agrees_with_salty_on_the_edges() {
        let mut edges = vec![[0u8; 64], [0xFF; 64]];
        for factor in [1, 2, 15, 16, 255] {
            for plus in [-1, 0, 1] {
                edges.push(multiple_of_order(factor, plus));
            }
        }
        let mut top = [0u8; 64];
        top[63] = 0x80;
        edges.push(top);
        for wide in edges {
            assert_eq!(reduce_mod_order(&wide), salty_reduce(&wide), "{wide:02x?}");
        }
        assert_eq!(reduce_mod_order(&multiple_of_order(7, 0)), [0; 32]);
    }

    #[test]
    fn s_must_be_below_the_order() {
        let with_s = |s: [u8; 64]| {
            let mut signature = [0u8; 64];
            signature[32..].copy_from_slice(&s[..32]);
            s_below_order(&signature)
        };
        assert!(with_s([0; 64]));
        assert!(with_s(multiple_of_order(1, -1)));
        assert!(!with_s(multiple_of_order(1, 0)));
        assert!(!with_s(multiple_of_order(1, 1)));
        assert!(!with_s([0xFF; 64]));
    }

    proptest! {
        #[test]
        fn the_reduction_agrees_with_salty(wide in prop::array::uniform32(any::<u8>())
            .prop_flat_map(|low| prop::array::uniform32(any::<u8>()).prop_map(move |high| (low, high)))) {
            let mut bytes = [0u8; 64];
            bytes[..32].copy_from_slice(&wide.0);
            bytes[32..].copy_from_slice(&wide.1);
            prop_assert_eq!(reduce_mod_order(&bytes), salty_reduce(&bytes));
        }

        /// The payload's digest, however it arrives, is salty's SHA-512 of it (embassy-boot's).
        #[test]
        fn the_digest_is_salty_s(payload in prop::collection::vec(any::<u8>(), 0..600), chunk in 1usize..300) {
            let mut verifier = Verifier::new();
            for piece in payload.chunks(chunk) {
                verifier.update(piece);
            }
            prop_assert_eq!(verifier.digest(), salty::Sha512::new().updated(&payload).finalize());
        }

        /// What dalek signs verifies; with one bit of the message, the key or the signature flipped, the answer is
        /// salty's own `verify`'s (which takes an S at or above L that this refuses, so S stays below it here).
        #[test]
        fn the_check_answers_as_salty_does(seed in prop::array::uniform32(any::<u8>()),
                                           digest in prop::collection::vec(any::<u8>(), 64),
                                           flip in 0usize..(64 + 32 + 64) * 8) {
            let digest: [u8; 64] = digest.try_into().unwrap();
            let key = SigningKey::from_bytes(&seed);
            let mut public = key.verifying_key().to_bytes();
            let mut signature = key.sign(&digest).to_bytes();
            let check = |digest: &[u8; 64], public: &[u8; 32], signature: &[u8; 64]| {
                let mine = if s_below_order(signature) { check(digest, signature, public) } else { Err(VerifyError::Signature) };
                let theirs = salty::PublicKey::try_from(public)
                    .map(|key| key.verify(digest, &salty::Signature::from(signature)).is_ok());
                (mine, theirs)
            };
            prop_assert_eq!(check(&digest, &public, &signature), (Ok(()), Ok(true)));
            let mut digest = digest;
            match flip / 8 {
                byte @ 0..64 => digest[byte] ^= 1 << (flip % 8),
                byte @ 64..96 => public[byte - 64] ^= 1 << (flip % 8),
                byte => signature[byte - 96] ^= 1 << (flip % 8),
            }
            let (mine, theirs) = check(&digest, &public, &signature);
            match theirs {
                Err(_) => prop_assert_eq!(mine, Err(VerifyError::PublicKey)),
                Ok(_) if !s_below_order(&signature) => prop_assert_eq!(mine, Err(VerifyError::Signature)),
                Ok(true) => prop_assert_eq!(mine, Ok(())),
                Ok(false) => prop_assert_eq!(mine, Err(VerifyError::Signature)),
            }
        }
    }
}
