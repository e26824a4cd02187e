//! What `sign` makes is what the devices accept: salty's ed25519 (this crate's `Verifier`) agrees with
//! ed25519-dalek's (`sign`), and embassy-boot itself, given the payload in its DFU partition and the header's
//! signature, marks the update for swapping; a flipped bit, a short length or another key it refuses.
#![allow(clippy::indexing_slicing, clippy::unwrap_used, clippy::panic)] // test helpers, not firmware

use embassy_boot::{BlockingFirmwareUpdater, FirmwareUpdater, FirmwareUpdaterConfig, FirmwareUpdaterError, State};
use g431_hw::memory::{IMAGE_INFO_OFFSET, IMAGE_INFO_SIZE, THRUSTER_PARTITIONS};
use lbv_sim::flash::Stm32g4Flash;
use update_image::{
    DEV_PUBLIC_KEY, HEADER_LEN, Header, INFO_LEN, INFO_OFFSET, ImageInfo, Target, Verifier, VerifyError, Version,
    check_file, key_from_hex, keygen, public_key, sign, verify,
};

/// The thruster's ACTIVE partition, the largest payload it takes.
const ACTIVE: u32 = THRUSTER_PARTITIONS.active.length;
/// Its DFU partition, in 2 KiB pages (at least one more than ACTIVE, for embassy-boot's swap).
const DFU_PAGES: usize = (THRUSTER_PARTITIONS.dfu.length / 2048) as usize;

const INFO: ImageInfo = ImageInfo::new(Target::ThrusterSeabotix, Version::new(0, 4, 2));

/// An image of `len` bytes that looks like one: varied bytes, its image info at INFO_OFFSET.
fn image(len: usize) -> Vec<u8> {
    let mut image: Vec<u8> = (0..len as u32)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
        .collect();
    image[INFO_OFFSET..INFO_OFFSET + INFO_LEN].copy_from_slice(&INFO.to_bytes());
    image
}

fn signed(len: usize, seed: &[u8; 32]) -> (Header, Vec<u8>) {
    let file = sign(&image(len), seed).unwrap();
    let (header, info) = check_file(&file, INFO.target, ACTIVE).unwrap();
    assert_eq!(info, INFO);
    (header, file[HEADER_LEN..].to_vec())
}

/// What embassy-boot's blocking updater answers for `payload` in DFU, checked over `update_len` bytes, and the
/// state it leaves.
fn embassy_boot_answer(payload: &[u8], public: &[u8; 32], signature: &[u8; 64], update_len: u32) -> (bool, State) {
    let (dfu, state) = (Stm32g4Flash::new(DFU_PAGES), Stm32g4Flash::new(1));
    let mut aligned = [0; 8];
    let config = FirmwareUpdaterConfig {
        dfu: dfu.clone(),
        state: state.clone(),
    };
    let mut updater = BlockingFirmwareUpdater::new(config, &mut aligned);
    assert_eq!(updater.get_state().unwrap(), State::Boot);
    // In pieces, as it arrives over the bus.
    let mut offset = 0;
    for chunk in payload.chunks(1024) {
        updater.write_firmware(offset, chunk).unwrap();
        offset += chunk.len();
    }
    let answer = match updater.verify_and_mark_updated(public, signature, update_len) {
        Ok(()) => true,
        Err(FirmwareUpdaterError::Signature(_)) => false,
        Err(other) => panic!("embassy-boot failed otherwise: {other:?}"),
    };
    let after = updater.get_state().unwrap();
    assert_eq!(&dfu.contents()[..payload.len()], payload);
    (answer, after)
}

#[test]
fn salty_verifies_what_dalek_signs() {
    let seed = keygen().unwrap();
    let public = public_key(&seed);
    for len in [0x240, 0x1001, 20_000, ACTIVE as usize] {
        let (header, payload) = signed(len, &seed);
        assert_eq!(verify(&header, &payload, &public), Ok(()));
        // In chunks of every size, as the master sees it stream through.
        for chunk in [1, 7, 128, 1000] {
            let mut verifier = Verifier::new();
            for piece in payload.chunks(chunk) {
                verifier.update(piece);
            }
            assert_eq!(verifier.received(), u64::from(header.payload_len));
            assert_eq!(verifier.finish_header(&header, &public), Ok(()));
        }
    }
}

#[test]
fn salty_refuses_what_embassy_boot_refuses() {
    let seed = keygen().unwrap();
    let public = public_key(&seed);
    let (header, payload) = signed(4096, &seed);
    let mut flipped = payload.clone();
    flipped[3000] ^= 0x10;
    assert_eq!(verify(&header, &flipped, &public), Err(VerifyError::Signature));
    assert_eq!(
        verify(&header, &payload[..4088], &public),
        Err(VerifyError::Length {
            announced: 4096,
            received: 4088
        })
    );
    let mut short = Verifier::new();
    short.update(&payload[..4088]);
    assert_eq!(short.finish(&header.signature, &public), Err(VerifyError::Signature));
    let other = public_key(&keygen().unwrap());
    assert_eq!(verify(&header, &payload, &other), Err(VerifyError::Signature));
    // Not a point of the curve (y = 2 has no x): no key at all.
    let mut not_a_point = [0; 32];
    not_a_point[0] = 2;
    assert_eq!(verify(&header, &payload, &not_a_point), Err(VerifyError::PublicKey));
    let mut forged = header;
    forged.signature[40] ^= 1;
    assert_eq!(verify(&forged, &payload, &public), Err(VerifyError::Signature));
}

#[test]
fn embassy_boot_accepts_a_signed_update_and_marks_it_for_swap() {
    let seed = keygen().unwrap();
    let public = public_key(&seed);
    for len in [0x240, 5000, ACTIVE as usize - 3] {
        let (header, payload) = signed(len, &seed);
        assert_eq!(
            embassy_boot_answer(&payload, &public, &header.signature, header.payload_len),
            (true, State::Swap),
            "a {len}-byte image"
        );
    }
}

#[test]
fn embassy_boot_refuses_a_flipped_bit_a_short_length_and_another_key() {
    let seed = keygen().unwrap();
    let public = public_key(&seed);
    let (header, payload) = signed(10_000, &seed);
    let refused = (false, State::Boot);
    for bit in [0, 8 * 0x204 + 3, 8 * 9_999 + 7] {
        let mut flipped = payload.clone();
        flipped[bit / 8] ^= 1 << (bit % 8);
        assert_eq!(
            embassy_boot_answer(&flipped, &public, &header.signature, header.payload_len),
            refused,
            "bit {bit} flipped"
        );
    }
    for short in [header.payload_len - 8, header.payload_len - 1, 0] {
        assert_eq!(
            embassy_boot_answer(&payload, &public, &header.signature, short),
            refused,
            "update_len {short}"
        );
    }
    let other = public_key(&keygen().unwrap());
    assert_eq!(
        embassy_boot_answer(&payload, &other, &header.signature, header.payload_len),
        refused
    );
    let mut forged = header.signature;
    forged[0] ^= 0x80;
    assert_eq!(
        embassy_boot_answer(&payload, &public, &forged, header.payload_len),
        refused
    );
}

/// The async updater, which an Embassy application runs, answers the same.
#[test]
fn the_async_updater_answers_the_same() {
    let seed = keygen().unwrap();
    let public = public_key(&seed);
    let (header, payload) = signed(7000, &seed);
    embassy_futures::block_on(async {
        for (key, expected) in [(public_key(&keygen().unwrap()), State::Boot), (public, State::Swap)] {
            let (dfu, state) = (Stm32g4Flash::new(DFU_PAGES), Stm32g4Flash::new(1));
            let mut aligned = [0; 8];
            let mut updater = FirmwareUpdater::new(FirmwareUpdaterConfig { dfu, state }, &mut aligned);
            updater.write_firmware(0, &payload).await.unwrap();
            let answer = updater
                .verify_and_mark_updated(&key, &header.signature, header.payload_len)
                .await;
            assert_eq!(answer.is_ok(), expected == State::Swap);
            assert_eq!(updater.get_state().await.unwrap(), expected);
        }
    });
}

/// keys/dev.key is the secret half of keys/dev.pub, DEV_PUBLIC_KEY.
#[test]
fn the_development_key_pair_matches() {
    let seed = key_from_hex(include_str!("../../keys/dev.key")).unwrap();
    assert_eq!(public_key(&seed), DEV_PUBLIC_KEY);
    let (header, payload) = signed(3000, &seed);
    assert_eq!(verify(&header, &payload, &DEV_PUBLIC_KEY), Ok(()));
}

/// The format and the linker scripts g431-hw writes put the image info at the same place, of the same size.
#[test]
fn the_layout_places_the_image_info_where_the_format_reads_it() {
    assert_eq!(INFO_OFFSET, IMAGE_INFO_OFFSET as usize);
    assert_eq!(update_image::IMAGE_RECORD_LEN, IMAGE_INFO_SIZE as usize);
    assert_eq!(update_image::KEY_OFFSET, INFO_OFFSET + INFO_LEN);
    assert!(DFU_PAGES * 2048 > ACTIVE as usize);
}

/// The group order L, little-endian.
const ORDER: [u8; 32] = [
    0xED, 0xD3, 0xF5, 0x5C, 0x1A, 0x63, 0x12, 0x58, 0xD6, 0x9C, 0xF7, 0xA2, 0xDE, 0xF9, 0xDE, 0x14, 0, 0, 0, 0, 0, 0,
    0, 0, 0, 0, 0, 0, 0, 0, 0, 0x10,
];

#[test]
fn a_second_encoding_of_a_signature_s_plus_the_order_is_refused_where_embassy_boot_takes_it() {
    let (header, payload) = signed(4096, &[0x11; 32]);
    let public = public_key(&[0x11; 32]);
    // S + L: the same point equation holds, so salty (and embassy-boot through it) accepts it.
    let mut other = header.signature;
    let mut carry = 0u16;
    for (s, l) in other[32..].iter_mut().zip(ORDER) {
        let sum = u16::from(*s) + u16::from(l) + carry;
        *s = sum as u8;
        carry = sum >> 8;
    }
    assert_eq!(carry, 0);
    let len = payload.len() as u32;
    assert!(
        embassy_boot_answer(&payload, &public, &other, len).0,
        "salty takes S + L"
    );
    let mut verifier = Verifier::new();
    verifier.update(&payload);
    assert_eq!(verifier.finish(&other, &public), Err(VerifyError::Signature));
    // The signature as signed still verifies.
    assert_eq!(verify(&header, &payload, &public), Ok(()));
    // S = L - 1 is the largest S taken to the curve check; S = L is refused before it.
    let mut at_order = header.signature;
    at_order[32..].copy_from_slice(&ORDER);
    let mut verifier = Verifier::new();
    verifier.update(&payload);
    assert_eq!(verifier.finish(&at_order, &public), Err(VerifyError::Signature));
}
