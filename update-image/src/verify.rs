//! Checking a payload's signature as it streams through, with what embassy-boot checks it with.
//!
//! embassy-boot's `verify_and_mark_updated` (feature `ed25519-salty`) hashes DFU bytes `[0, update_len)` with
//! salty's SHA-512 and verifies the header's signature over that 64-byte digest with salty's ed25519, plain (not
//! the prehashed ed25519ph). This does the same, a chunk at a time, so the master can refuse a forged image
//! before it sends any of it on, and a device knows the answer embassy-boot will give. It uses salty's SHA-512
//! too, not a second implementation: a firmware that has embassy-boot then carries one of each.

use core::fmt;

use crate::Header;

/// The SHA-512 of the payload so far, and how many bytes it has had.
pub struct Verifier {
    hash: salty::Sha512,
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
            hash: salty::Sha512::new(),
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
        self.hash.finalize()
    }

    /// Whether `signature` is `public_key`'s over the payload hashed, as embassy-boot would answer for the same
    /// bytes in DFU, but for one thing: a signature whose S is not below the group order L is refused, as RFC 8032
    /// (5.1.7) asks and salty does not check, so that a payload's signature has one encoding only. The caller sees
    /// to it that the bytes hashed are the header's `payload_len` (or uses [`finish_header`](Verifier::finish_header)).
    pub fn finish(self, signature: &[u8; 64], public_key: &[u8; 32]) -> Result<(), VerifyError> {
        if !s_below_order(signature) {
            return Err(VerifyError::Signature);
        }
        let public_key = salty::PublicKey::try_from(public_key).map_err(|_| VerifyError::PublicKey)?;
        let signature = salty::Signature::from(signature);
        let digest = self.digest();
        public_key
            .verify(&digest, &signature)
            .map_err(|_| VerifyError::Signature)
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
    let s = signature.last_chunk::<32>().map_or(&ORDER, |s| s);
    // Compared from the most significant byte down.
    for (s, l) in s.iter().rev().zip(ORDER.iter().rev()) {
        if s != l {
            return s < l;
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
