//! The master's own image on its way into DFU: any headers, any bytes handed on in any sizes and at any offsets,
//! finished or dropped, applied or not, with the task taking pages out at any moment, whatever it found in the flash,
//! and an image marked for the swap at any moment. Nothing panics; the pieces the task takes are contiguous from
//! DFU's offset 0, none longer than a page, each a whole number of double words; an upload begins only on a flash
//! with the bootloader's state, not on trial; once an image is marked, nothing is taken and no piece goes to DFU.
#![no_main]

use arbitrary::Arbitrary;
use lbv_master_fw::update::own::{NotTaken, OwnImage, PAGE_BYTES};
use lbv_master_fw::shared::Sender;
use lbv_master_fw::update::{HEADER_LEN, ImageHeader};
// The host's time driver, which every host build of the core links.
use lbv_sim as _;
use libfuzzer_sys::fuzz_target;

#[derive(Arbitrary, Debug)]
enum Step {
    Found(Option<bool>),
    Begin { payload_len: u32, header: Vec<u8> },
    Write { offset: u32, data: Vec<u8> },
    Finish(bool),
    Apply,
    /// The task's turn: it takes up to this many pieces.
    Drain(u8),
    /// The task marked an image for the swap.
    Mark,
}

fuzz_target!(|steps: Vec<Step>| {
    let own = OwnImage::new();
    let mut page = [0u8; PAGE_BYTES];
    let mut found = None;
    // The next DFU offset the task must be given, once an upload has begun.
    let mut next = None;
    let mut marked = false;
    for step in steps {
        match step {
            Step::Found(on_trial) => {
                own.found(on_trial);
                found = on_trial;
            }
            Step::Begin { payload_len, header } => {
                let mut bytes = [0u8; HEADER_LEN];
                for (to, from) in bytes.iter_mut().zip(header) {
                    *to = from;
                }
                let header = ImageHeader {
                    target: 3,
                    payload_len,
                    bytes,
                };
                let begun = own.begin(&header);
                match begun {
                    _ if marked => assert_eq!(begun, Err(NotTaken::Restarting), "begun once marked"),
                    Ok(()) => {
                        assert_eq!(found, Some(false), "begun on a flash that was not ready");
                        next = Some(0);
                    }
                    Err(NotTaken::OnTrial) => assert_eq!(found, Some(true)),
                    Err(NotTaken::NoBootloader) => assert_eq!(found, None),
                    Err(_) => next = None,
                }
            }
            Step::Write { offset, data } => {
                let data = &data[..data.len().min(239)];
                let written = own.write(offset, data);
                assert!(!marked || written == Err(NotTaken::Restarting), "taken once marked");
            }
            Step::Finish(complete) => {
                own.finish(complete);
                if !complete {
                    next = None;
                }
            }
            Step::Apply => {
                let applied = own.apply(Sender::default());
                assert!(!marked || applied == Err(NotTaken::Restarting), "applied once marked");
            }
            Step::Mark => {
                own.mark();
                marked = true;
            }
            Step::Drain(pieces) => {
                for _ in 0..pieces {
                    let Some(piece) = own.take_page(&mut page) else {
                        break;
                    };
                    assert!(!marked, "a piece for DFU once marked");
                    let (offset, len) = (piece.offset, piece.len);
                    assert!(len <= PAGE_BYTES && len % 8 == 0 && len > 0, "a piece of {len} bytes");
                    if let Some(expected) = next {
                        assert_eq!(offset, expected, "pieces out of order");
                    }
                    next = Some(offset + len as u32);
                }
            }
        }
    }
});
