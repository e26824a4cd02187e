//! The signature check on arbitrary keys, signatures and payloads: never panics, and answers as salty's own
//! `verify` does (salty takes an S at or above the group order, which the check refuses). With the first byte odd,
//! the key is made from the input's 32 bytes and the payload signed with it by salty, then the signature is XORed
//! with the input's 64 bytes, so signatures that verify, and those a few bits from one, are reached too.
#![no_main]

use libfuzzer_sys::fuzz_target;
use update_image::{Verifier, VerifyError};

fuzz_target!(|data: &[u8]| {
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    let Some((key, rest)) = rest.split_first_chunk::<32>() else {
        return;
    };
    let Some((signature, payload)) = rest.split_first_chunk::<64>() else {
        return;
    };
    let mut verifier = Verifier::new();
    verifier.update(payload);
    let digest = {
        let mut again = Verifier::new();
        again.update(payload);
        again.digest()
    };
    let (key, signature) = if mode % 2 == 1 {
        let pair = salty::Keypair::from(key);
        let mut signed = pair.sign(&digest).to_bytes();
        for (byte, mask) in signed.iter_mut().zip(signature) {
            *byte ^= mask;
        }
        (pair.public.to_bytes(), signed)
    } else {
        (*key, *signature)
    };
    let ours = verifier.finish(&signature, &key);
    let s = salty::Scalar::from_bytes(signature.last_chunk::<32>().unwrap());
    let theirs = salty::PublicKey::try_from(&key).map(|key| key.verify(&digest, &salty::Signature::from(&signature)));
    match theirs {
        _ if !s.is_canonical() => assert_eq!(ours, Err(VerifyError::Signature)),
        Err(_) => assert_eq!(ours, Err(VerifyError::PublicKey)),
        Ok(Ok(())) => assert_eq!(ours, Ok(())),
        Ok(Err(_)) => assert_eq!(ours, Err(VerifyError::Signature)),
    }
});
