//! The courier that carries an update image to thrusters: any update file headers, for one slot or for any set of
//! slots (a family's file), any image bytes handed on in any sizes and at any offsets, finished or dropped, applied
//! (to one slot or to any set) or not, version queries, and for every exchange it
//! asks for any reply bytes a thruster (or the bus's noise) gives, decoded as the bus task decodes them, or a
//! failed transfer, as time passes. Nothing panics; the sink always gets room again once the bus task has had its exchanges; an
//! exchange is only ever asked for a slot begun with or queried.
#![no_main]

use arbitrary::Arbitrary;
use embassy_time::{Duration, Instant};
use lbv_master_fw::update::courier::{Courier, ExchangeError, File, MAX_WRITE};
use lbv_master_fw::shared::Sender;
// The host's time driver (the harness passes its own instants).
use lbv_sim as _;
use libfuzzer_sys::fuzz_target;
use tmc_proto::ext::{self, Reply};

#[derive(Arbitrary, Debug)]
enum Step {
    Begin { slot: u8, kind: u8, payload_len: u32, header: Vec<u8> },
    BeginFamily { slots: u8, kind: u8, payload_len: u32, header: Vec<u8> },
    Write { offset: u32, data: Vec<u8> },
    Finish(bool),
    Apply(u8),
    ApplyTo(u8),
    Query(u8),
    /// The bus task's turn: the thrusters `castable` says (as bits) may share a write; each reply's bytes, in the
    /// order of the exchange's slots (or none: the transfer failed).
    Exchange { castable: u8, most: u32, replies: Vec<Option<Vec<u8>>>, busy: bool },
    Wait(u16),
}

fuzz_target!(|steps: Vec<Step>| {
    let mut courier = Courier::new();
    let mut now = Instant::from_ticks(0);
    // The slots an exchange may be for: those begun with (as bits), and the one queried.
    let (mut begun, mut queried) = (0u8, None);
    for step in steps {
        match step {
            Step::Begin { slot, kind, payload_len, header } => {
                let mut bytes = [0u8; 80];
                for (to, from) in bytes.iter_mut().zip(header) {
                    *to = from;
                }
                if courier.begin(slot, kind, payload_len, &bytes).is_ok() {
                    begun = 1u8.checked_shl(u32::from(slot)).unwrap_or(0);
                }
            }
            Step::BeginFamily { slots, kind, payload_len, header } => {
                let mut bytes = [0u8; 80];
                for (to, from) in bytes.iter_mut().zip(header) {
                    *to = from;
                }
                let file = File::Family(tmc_proto::Family::SeaBotix);
                if courier.begin_to(slots, file, kind, payload_len, &bytes).is_ok() {
                    begun = slots;
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
            Step::Exchange { castable, most, replies, busy } => {
                let bit = |slot: u8| 1u8.checked_shl(u32::from(slot)).unwrap_or(0);
                let Some(exchange) = courier.next_cast(now, |_| true, |slot| castable & bit(slot) != 0, most) else {
                    continue;
                };
                assert!(
                    begun & bit(exchange.slot) != 0 || queried == Some(exchange.slot) && exchange.with == 0,
                    "an exchange for a slot never begun"
                );
                assert!(exchange.slots().count() <= most.max(1) as usize, "a write shared too widely");
                let mut replies = replies.into_iter();
                for slot in exchange.slots() {
                    assert!(slot == exchange.slot || begun & castable & bit(slot) != 0, "a write shared wrongly");
                    let result = match replies.next().flatten() {
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
