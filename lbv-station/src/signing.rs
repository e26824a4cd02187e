//! MAVLink 2 signing as a ground station does it, with the mavlink crate's signature computation.

use alloc::vec::Vec;

use embassy_time::Instant;
use lbv_master_fw::console::framing::Frame;
use mavlink_core::consts::v2::IFLAG_SIGNED;
use mavlink_core::{MAVLinkV2MessageRaw, MavHeader, MessageData};

use crate::Seen;

/// MAVLink 2 signing's clock: 10 us units since 2015-01-01. A station's starts at 2025-01-01 (plus embassy-time's
/// time: virtual on the bench).
pub const SIGNING_EPOCH: u64 = 10 * 31_557_600 * 100_000;

/// A MAVLink 2 signing key as a station holds it, and the timestamp of its last signature (or the newest one it
/// verified from the vehicle, which it follows).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Signing {
    /// The secret.
    pub key: [u8; 32],
    /// The link id its signatures carry.
    pub link_id: u8,
    last: u64,
}

impl Signing {
    /// Sign with `key` on link 0.
    pub fn new(key: [u8; 32]) -> Self {
        Self {
            key,
            link_id: 0,
            last: 0,
        }
    }

    /// The signing timestamp at `now`, later than the last one used.
    pub(crate) fn timestamp(&mut self, now: Instant) -> u64 {
        let at = SIGNING_EPOCH + now.as_micros() / 10;
        self.last = at.max(self.last + 1);
        self.last
    }

    /// `message` framed with `header` and signed at `timestamp`.
    pub(crate) fn frame<D: MessageData>(&self, header: MavHeader, message: &D, timestamp: u64) -> Vec<u8> {
        let mut raw = MAVLinkV2MessageRaw::new();
        // Flagged as signed first: the framing keeps the flags it finds, and the checksum covers them.
        *raw.incompatibility_flags_mut() = IFLAG_SIGNED;
        raw.serialize_message_data(header, message);
        *raw.signature_link_id_mut() = self.link_id;
        // The 48-bit timestamp: the low six bytes.
        raw.signature_timestamp_bytes_mut()
            .iter_mut()
            .zip(timestamp.to_le_bytes())
            .for_each(|(slot, byte)| *slot = byte);
        let mut signature = [0; 6];
        raw.calculate_signature(&self.key, &mut signature);
        raw.signature_value_mut().copy_from_slice(&signature);
        raw.raw_bytes().to_vec()
    }

    /// The signature timestamp of the signed frame `bytes` when its signature was made with this key.
    fn verify(&self, bytes: &[u8]) -> Option<u64> {
        let mut raw = MAVLinkV2MessageRaw::new();
        raw.as_mut_slice().get_mut(..bytes.len())?.copy_from_slice(bytes);
        let mut signature = [0; 6];
        raw.calculate_signature(&self.key, &mut signature);
        (signature == raw.signature_value()).then(|| raw.signature_timestamp())
    }
}

/// Count in `seen` what `frame`'s signature says, checked with `signing`'s key; a verified timestamp newer than
/// the station's own becomes its next.
pub(crate) fn check(signing: Option<&mut Signing>, frame: &Frame<'_>, seen: &mut Seen) {
    match signing {
        Some(signing) if frame.signed => match signing.verify(frame.bytes) {
            Some(timestamp) => {
                seen.verified += 1;
                if timestamp <= seen.newest_timestamp {
                    seen.timestamps_back += 1;
                }
                seen.newest_timestamp = seen.newest_timestamp.max(timestamp);
                // As the spec asks (and the C library and pymavlink do): follow a newer timestamp.
                signing.last = signing.last.max(timestamp);
            }
            None => seen.unverified += 1,
        },
        Some(_) => seen.unsigned += 1,
        None if frame.signed => seen.unverified += 1,
        None => {}
    }
}

#[cfg(test)]
mod tests {
    extern crate std;

    use super::*;
    use crate::GroundStation;
    use mavlink_core::{SigningConfig, SigningData};

    #[test]
    fn signed_frames_verify_with_the_mavlink_crate_and_unsigned_ones_parse() {
        let _clock = lbv_sim::clock::take();
        let key = [7; 32];
        let mut station = GroundStation::default();
        let unsigned = station.heartbeat();
        assert_eq!(unsigned[2] & 1, 0);
        // The mavlink crate refuses a new stream more than a minute older than its wall clock: sign at its time.
        let since_2015 = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_micros() as u64
            / 10
            - 142_007_040_000_000;
        station.signing = Some(Signing {
            last: since_2015,
            ..Signing::new(key)
        });
        let first = station.arm(true);
        let second = station.arm(true);
        assert_eq!(first[2] & 1, 1);
        let verifier = SigningData::from_config(SigningConfig::new(key, 0, false, false));
        let signing = station.signing.unwrap();
        for frame in [&first, &second] {
            let mut raw = MAVLinkV2MessageRaw::new();
            raw.as_mut_slice()[..frame.len()].copy_from_slice(frame);
            assert!(verifier.verify_signature(&raw), "{frame:02x?}");
            assert!(signing.verify(frame).is_some());
            assert!(Signing::new([8; 32]).verify(frame).is_none());
        }
        // Each signature is newer than the last, at the same virtual time too.
        let stamp = |frame: &[u8]| {
            let mut raw = MAVLinkV2MessageRaw::new();
            raw.as_mut_slice()[..frame.len()].copy_from_slice(frame);
            raw.signature_timestamp()
        };
        assert_eq!(stamp(&second), stamp(&first) + 1);
        // On virtual time, from the station's epoch.
        station.signing = Some(Signing::new(key));
        assert_eq!(stamp(&station.heartbeat()), SIGNING_EPOCH);
    }
}
