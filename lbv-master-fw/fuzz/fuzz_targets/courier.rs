//! The courier that carries an update image to thrusters: any update file headers, for one slot or for any set of
//! slots (a family's file), any image bytes handed on in any sizes and at any offsets, finished or dropped, applied
//! (to one slot or to any set) or not, version queries, and for every exchange it
//! asks for any reply bytes a thruster (or the bus's noise) gives, decoded as the bus task decodes them, or a reply
//! made whole with any fields (a `Version` of any protocol, any part of a post-mortem record: what noise cannot
//! forge past the CRC), or a failed transfer, as time passes; thrusters answering their polls or not. Nothing
//! panics; the sink always gets room again once the bus task has had its exchanges; an exchange is only ever asked
//! for a slot begun with, queried or answering its polls.
#![no_main]

use arbitrary::Arbitrary;
use embassy_time::{Duration, Instant};
use lbv_master_fw::update::courier::{Courier, ExchangeError, File, MAX_WRITE};
use lbv_master_fw::shared::Sender;
// The host's time driver (the harness passes its own instants).
use lbv_sim as _;
use libfuzzer_sys::fuzz_target;
use tmc_proto::ext::{self, Reply, ReplyBody};

#[derive(Arbitrary, Debug)]
enum Step {
    Begin { slot: u8, kind: u8, payload_len: u32, header: Vec<u8> },
    BeginFamily { slots: u8, kind: u8, payload_len: u32, header: Vec<u8> },
    Write { offset: u32, data: Vec<u8> },
    Finish(bool),
    Apply(u8),
    ApplyTo(u8),
    Query(u8),
    /// The bus task's turn: the thrusters `castable` says (as bits) may share a write; each reply, in the order of
    /// the exchange's slots (or none: the transfer failed).
    Exchange { castable: u8, most: u32, replies: Vec<Option<Answer>>, busy: bool },
    Wait(u16),
    /// A bus task hears a thruster answer its polls, or stop answering.
    Seen { slot: u8, answering: bool },
}

#[derive(Arbitrary, Debug)]
enum Answer {
    /// Bytes off the bus.
    Raw(Vec<u8>),
    /// A `Version` done, with the exchange's sequence number.
    Version { protocol: u8, on_trial: bool, checks_signatures: bool, marked: bool, dev_key: bool, verdict: u8, info: [u8; 32] },
    /// A part of a post-mortem record, with the exchange's sequence number.
    PostMortem { len: u8, offset: u8, data: [u8; 32] },
}

fuzz_target!(|steps: Vec<Step>| {
    let mut courier = Courier::new();
    let mut now = Instant::from_ticks(0);
    // The slots an exchange may be for: those ever begun with (as bits: a thruster whose update ended is asked what
    // it runs), the one queried, and those seen answering.
    let (mut begun, mut queried, mut seen) = (0u8, None, 0u8);
    for step in steps {
        match step {
            Step::Begin { slot, kind, payload_len, header } => {
                let mut bytes = [0u8; 80];
                for (to, from) in bytes.iter_mut().zip(header) {
                    *to = from;
                }
                if courier.begin(slot, kind, payload_len, &bytes).is_ok() {
                    begun |= 1u8.checked_shl(u32::from(slot)).unwrap_or(0);
                }
            }
            Step::BeginFamily { slots, kind, payload_len, header } => {
                let mut bytes = [0u8; 80];
                for (to, from) in bytes.iter_mut().zip(header) {
                    *to = from;
                }
                let file = File::Family(tmc_proto::Family::SeaBotix);
                if courier.begin_to(slots, file, kind, payload_len, &bytes).is_ok() {
                    begun |= slots;
                }
            }
            Step::Write { offset, data } => {
                let data = data.get(..MAX_WRITE).unwrap_or(&data);
                let _ = courier.write(offset, data);
            }
            Step::Finish(complete) => {
                let _ = courier.finish(complete);
            }
            Step::Apply(slot) => {
                let _ = courier.apply(slot, Sender { system: 255, component: 190 });
            }
            Step::ApplyTo(slots) => {
                let _ = courier.apply_to(slots, Sender { system: 255, component: 190 });
            }
            Step::Query(slot) => {
                if courier.query(slot, Sender { system: 255, component: 190 }).is_ok() {
                    queried = Some(slot);
                }
            }
            Step::Seen { slot, answering } => {
                let slot = slot % 8;
                courier.seen(slot, answering);
                if answering {
                    seen |= 1 << slot;
                }
            }
            Step::Exchange { castable, most, replies, busy } => {
                let bit = |slot: u8| 1u8.checked_shl(u32::from(slot)).unwrap_or(0);
                let Some(exchange) = courier.next_cast(now, |_| true, |slot| castable & bit(slot) != 0, most) else {
                    continue;
                };
                let alone = exchange.with == 0;
                assert!(
                    begun & bit(exchange.slot) != 0
                        || (queried == Some(exchange.slot) || seen & bit(exchange.slot) != 0) && alone,
                    "an exchange for a slot never begun, queried or seen"
                );
                assert!(exchange.slots().count() <= most.max(1) as usize, "a write shared too widely");
                let mut replies = replies.into_iter();
                for slot in exchange.slots() {
                    assert!(slot == exchange.slot || begun & castable & bit(slot) != 0, "a write shared wrongly");
                    let seq = exchange.frame.seq;
                    let made = |body| Reply::Done { seq, body }.encode().as_bytes().to_vec();
                    let bytes = replies.next().flatten().map(|answer| match answer {
                        Answer::Raw(bytes) => bytes,
                        Answer::Version { protocol, on_trial, checks_signatures, marked, dev_key, verdict, info } => {
                            made(ReplyBody::Version {
                                protocol,
                                on_trial,
                                checks_signatures,
                                marked,
                                dev_key,
                                verdict,
                                max_payload: 58 * 1024,
                                info,
                            })
                        }
                        Answer::PostMortem { len, offset, data } => made(ReplyBody::PostMortem {
                            len,
                            offset,
                            data: core::array::from_fn(|i| data[i % 32]),
                        }),
                    });
                    let result = match bytes {
                        Some(bytes) => {
                            let len = ext::reply_len(exchange.frame.command.kind()).min(bytes.len());
                            match Reply::decode(&bytes[..len]) {
                                Ok(reply) => Ok(reply),
                                Err(error) => Err(ExchangeError::Frame(error)),
                            }
                        }
                        None if busy => Err(ExchangeError::Busy),
                        None => Err(ExchangeError::Bus),
                    };
                    courier.on_result(now, exchange.sent_to(slot), result, &mut |_| {});
                }
            }
            Step::Wait(ms) => now += Duration::from_millis(u64::from(ms)),
        }
    }
    // Left to a thruster that answers nothing, the courier gives up within its limits and makes room.
    for _ in 0..10_000 {
        if courier.has_room() && courier.next(now, |_| true).is_none() {
            break;
        }
        if let Some(exchange) = courier.next(now, |_| true) {
            courier.on_result(now, &exchange, Err(ExchangeError::Bus), &mut |_| {});
        }
        now += Duration::from_millis(20);
    }
    assert!(courier.has_room(), "the sink is left waiting");
});
