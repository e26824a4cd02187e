//! Fuzz target: decode arbitrary BAT frames, check the encode / decode round trip, and format every report.
//!
//! Input: the first two bytes (little-endian, masked to 11 bits) are the CAN ID, the rest is the data.
#![no_main]

use core::fmt::{self, Write};

use bat_proto::{BMS_ID, DcdcStatus, DecodeError, FRAME_LEN, Frame, INFO_ID, STATUS_ID};
use libfuzzer_sys::fuzz_target;

/// A fixed stack buffer for `core::fmt`, as firmware would use for log lines.
struct StackBuf {
    bytes: [u8; 128],
    len: usize,
}

impl StackBuf {
    fn new() -> Self {
        Self {
            bytes: [0; 128],
            len: 0,
        }
    }

    fn as_str(&self) -> &str {
        self.bytes
            .get(..self.len)
            .and_then(|b| core::str::from_utf8(b).ok())
            .unwrap_or("")
    }
}

impl Write for StackBuf {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        let end = self.len.checked_add(s.len()).ok_or(fmt::Error)?;
        let dst = self.bytes.get_mut(self.len..end).ok_or(fmt::Error)?;
        dst.copy_from_slice(s.as_bytes());
        self.len = end;
        Ok(())
    }
}

fn format_into(value: &impl fmt::Display) -> StackBuf {
    let mut buf = StackBuf::new();
    write!(buf, "{value}").expect("every report and error fits 128 bytes");
    assert!(!buf.as_str().is_empty());
    buf
}

fn check_status(status: DcdcStatus, previous: DcdcStatus) {
    let mut count = 0;
    for report in status.describe_all() {
        assert_eq!(report.set, status.is_set(report.bit));
        let text = format_into(&report);
        assert!(text.as_str().starts_with(report.bit.name()));
        count += 1;
    }
    assert_eq!(count, 12);

    let mut changed = 0;
    for report in status.describe_changes(previous) {
        assert_ne!(status.is_set(report.bit), previous.is_set(report.bit));
        let text = format_into(&report);
        assert!(text.as_str().starts_with(report.bit.name()));
        changed += 1;
    }
    assert_eq!(changed, (status.word() ^ previous.word()).count_ones());
}

fuzz_target!(|input: &[u8]| {
    let Some((&[lo, hi], data)) = input.split_first_chunk::<2>() else {
        return;
    };
    let id = u16::from_le_bytes([lo, hi]) & 0x07FF;
    let known = [INFO_ID, STATUS_ID, BMS_ID].contains(&id);

    match Frame::decode(id, data) {
        Ok(frame) => {
            assert!(known && data.len() == FRAME_LEN);
            assert_eq!(frame.id(), id);
            let (enc_id, bytes) = frame.encode();
            assert_eq!(enc_id, id);
            assert_eq!(Frame::decode(enc_id, &bytes), Ok(frame));
            // Re-encoding the decoded value gives the same bytes (ignored bits are dropped once).
            assert_eq!(Frame::decode(enc_id, &bytes).map(|f| f.encode()), Ok((enc_id, bytes)));

            // Each info field is read on its own: a charge above 100 % is unknown, the frame still decodes.
            if let Frame::Info(info) = frame {
                assert_eq!(info.charge_percent.is_none(), data.get(4).is_some_and(|charge| *charge > 100));
            }
            // Exercise the reports on the status in the frame (or one built from the data for other frames),
            // against a previous status taken from the raw ID bytes.
            let status = match frame {
                Frame::Status(status) => status,
                _ => DcdcStatus::from_bytes(bytes[0], bytes[1]),
            };
            check_status(status, DcdcStatus::from_bytes(lo, hi));
        }
        Err(err) => {
            match err {
                DecodeError::UnknownId(got) => assert!(!known && got == id),
                DecodeError::Length { id: got, actual } => {
                    assert!(known && got == id && actual == data.len() && actual != FRAME_LEN)
                }
            }
            let _ = format_into(&err);
            // Reports work on any raw bytes too.
            let a = data.first().copied().unwrap_or(0);
            let b = data.get(1).copied().unwrap_or(0);
            check_status(DcdcStatus::from_bytes(a, b), DcdcStatus::from_bytes(lo, hi));
        }
    }
});
