//! Transfers put together from the annotations: START (or repeated START), address, data bytes and acknowledges,
//! to STOP or the next repeated START, in bounded memory.

use super::MAX_TRANSFER_BYTES;
use super::formats::{Annotation, Event, Stamp};

/// A moment: the sample number and / or the time in seconds, whichever the export gives.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(super) struct When {
    pub(super) sample: Option<u64>,
    pub(super) seconds: Option<f64>,
}

/// One transfer being put together: address, direction, data bytes and their acknowledges. Its size is bounded:
/// the first [`MAX_TRANSFER_BYTES`] data bytes, counts for the rest, at most one problem of each kind.
#[derive(Debug, Clone, Default)]
pub(super) struct Transfer {
    pub(super) start: When,
    pub(super) end: When,
    pub(super) address: u8,
    pub(super) read: bool,
    /// The address byte's acknowledge; `None` when the capture stops before it.
    pub(super) address_ack: Option<bool>,
    /// The first data bytes.
    pub(super) bytes: Vec<u8>,
    /// Data bytes in all.
    pub(super) count: u64,
    /// The last data byte has had no ACK or NACK yet.
    awaiting_ack: bool,
    /// The first data byte that the receiver NACKed.
    pub(super) first_nack: Option<u64>,
    /// Data bytes that went the other way from the address's R/W bit: how many, and the first one.
    pub(super) wrong_way: (u64, u8),
    /// How the transfer ended, when it did not end well.
    pub(super) problems: Vec<String>,
}

/// Groups annotations into transfers.
#[derive(Debug, Default)]
pub(super) struct Assembler {
    pub(super) unshifted: bool,
    pub(super) samplerate: Option<f64>,
    pub(super) current: Option<Transfer>,
    /// A START whose address has not come yet.
    pub(super) pending_start: Option<When>,
}

impl Assembler {
    fn when(&self, stamp: Stamp) -> (When, When) {
        match stamp {
            Stamp::None => (When::default(), When::default()),
            Stamp::Seconds(seconds) => {
                let when = When {
                    sample: None,
                    seconds: Some(seconds),
                };
                (when, when)
            }
            Stamp::Samples(start, end) => {
                let at = |sample: u64| When {
                    sample: Some(sample),
                    seconds: self.samplerate.map(|rate| sample as f64 / rate),
                };
                (at(start), at(end))
            }
        }
    }

    /// Take one annotation; returns the transfer it ends, if any, or why the annotation makes no sense here.
    pub(super) fn feed(&mut self, annotation: Annotation) -> Result<Option<Transfer>, String> {
        let (start, end) = self.when(annotation.stamp);
        match annotation.event {
            Event::Ignored => Ok(None),
            Event::Start | Event::RepeatStart => {
                let finished = self.current.take().map(|mut transfer| {
                    if annotation.event == Event::Start {
                        transfer.problems.push("no STOP before the next START".into());
                    }
                    transfer.end = start;
                    transfer
                });
                self.pending_start = Some(start);
                Ok(finished)
            }
            Event::Stop => {
                self.pending_start = None;
                Ok(self.current.take().map(|mut transfer| {
                    transfer.end = end;
                    transfer
                }))
            }
            Event::Address { read, value } => {
                let address = if self.unshifted { value >> 1 } else { value };
                if address > 0x7F {
                    return Err(format!(
                        "address {value:#04x} is not a 7-bit address (10-bit addressing is not read; an unshifted \
                         export needs --unshifted)"
                    ));
                }
                let finished = self.current.take().map(|mut transfer| {
                    transfer
                        .problems
                        .push("no STOP or repeated START before the next address".into());
                    transfer
                });
                self.current = Some(Transfer {
                    start: self.pending_start.take().unwrap_or(start),
                    end,
                    address,
                    read,
                    ..Transfer::default()
                });
                Ok(finished)
            }
            Event::Ack | Event::Nack => {
                let ack = annotation.event == Event::Ack;
                let Some(transfer) = self.current.as_mut() else {
                    return Err(format!("{} outside a transfer", if ack { "ACK" } else { "NACK" }));
                };
                transfer.end = end;
                if transfer.count == 0 && transfer.address_ack.is_none() {
                    transfer.address_ack = Some(ack);
                    return Ok(None);
                }
                if !transfer.awaiting_ack {
                    return Err(format!("{} with no byte before it", if ack { "ACK" } else { "NACK" }));
                }
                transfer.awaiting_ack = false;
                if !ack && transfer.first_nack.is_none() {
                    transfer.first_nack = Some(transfer.count - 1);
                }
                Ok(None)
            }
            Event::Data { read, byte } => {
                let Some(transfer) = self.current.as_mut() else {
                    return Err(format!(
                        "data byte {byte:02X} outside a transfer (does the capture start in the middle of one?)"
                    ));
                };
                if read != transfer.read {
                    if transfer.wrong_way.0 == 0 {
                        transfer.wrong_way.1 = byte;
                    }
                    transfer.wrong_way.0 += 1;
                }
                transfer.end = end;
                if transfer.bytes.len() < MAX_TRANSFER_BYTES {
                    transfer.bytes.push(byte);
                }
                transfer.count += 1;
                transfer.awaiting_ack = true;
                Ok(None)
            }
        }
    }

    /// The transfer still open at the end of the input.
    pub(super) fn finish(&mut self) -> Option<Transfer> {
        self.current.take().map(|mut transfer| {
            transfer.problems.push("the capture ends before the STOP".into());
            transfer
        })
    }
}
