use proptest::prelude::*;
use std::vec::Vec;

use super::*;

fn event(at_ms: u32, what: What) -> Event {
    Event { at_ms, what }
}

const IMAGE: Image = Image {
    target: 3,
    version: [0, 0, 3, 0],
};

/// RCC_CSR after a power-on (BORRSTF, PINRSTF), a software reset (SFTRSTF, PINRSTF), the watchdog's (IWDGRSTF,
/// PINRSTF), as rehost and the silicon set them.
const POWER_ON: ResetCause = ResetCause(1 << 27 | 1 << 26);
const SOFTWARE: ResetCause = ResetCause(1 << 28 | 1 << 26);
const WATCHDOG: ResetCause = ResetCause(1 << 29 | 1 << 26);

fn a_panic() -> Stop {
    Stop {
        kind: Kind::Panic,
        frame: Frame {
            pc: 0x0800_4321,
            lr: 0x0800_1235,
            xpsr: 0x6100_0000,
            sp: 0x2001_7F00,
        },
        faults: FaultStatus::default(),
        exception: 0,
        panic: Some(PanicAt {
            file: 0x0801_2340,
            file_len: 27,
            line: 412,
        }),
        uptime_ms: 61_250,
    }
}

#[test]
fn a_record_reads_back_as_written_and_its_crc_is_zlibs() {
    let mut region = Region::new();
    region.start(POWER_ON, IMAGE);
    region.note(event(1_000, What::Armed));
    region.note(event(60_000, What::ThrusterLost(3)));
    region.record(a_panic(), IMAGE);
    let bytes = region.record;
    assert_eq!(&bytes[..4], b"LBVC");
    assert_eq!(
        u32::from_le_bytes(bytes[124..].try_into().unwrap()),
        crc32fast::hash(&bytes[..124])
    );
    let record = Record::decode(&bytes).unwrap();
    assert_eq!(record.kind, Kind::Panic);
    assert_eq!(record.frame.pc, 0x0800_4321);
    assert_eq!(record.panic.unwrap().line, 412);
    assert_eq!(
        record.events(),
        [
            event(0, What::Started(0x0C)),
            event(1_000, What::Armed),
            event(60_000, What::ThrusterLost(3))
        ]
    );
    assert_eq!(record.encode(), bytes);
}

#[test]
fn a_power_on_start_shows_no_record_whatever_ram_held() {
    let mut region = Region::new();
    region.start(POWER_ON, IMAGE);
    region.record(a_panic(), IMAGE);
    // The record a panic left, read after a power cycle: gone. So is noise.
    assert_eq!(region.start(POWER_ON, IMAGE), None);
    assert_eq!(region.read(), None);
    let mut noise = Region {
        record: [0xA5; LEN],
        ring: [0x5A; RING_LEN],
    };
    assert_eq!(noise.start(POWER_ON, IMAGE), None);
    assert_eq!(noise.read(), None);
}

#[test]
fn the_start_after_a_stop_keeps_the_record_with_why_the_chip_reset_until_it_is_cleared() {
    let mut region = Region::new();
    region.start(POWER_ON, IMAGE);
    region.record(a_panic(), IMAGE);
    let record = region.start(SOFTWARE, IMAGE).unwrap();
    assert_eq!(
        (record.kind, record.reset_cause, record.told),
        (Kind::Panic, SOFTWARE.0, false)
    );
    region.mark_told();
    // A later reset keeps it, told, and the cause of the reset that followed the stop.
    let again = region.start(WATCHDOG, IMAGE).unwrap();
    assert_eq!(
        (again.kind, again.reset_cause, again.told),
        (Kind::Panic, SOFTWARE.0, true)
    );
    region.clear();
    assert_eq!(region.start(SOFTWARE, IMAGE), None);
}

#[test]
fn the_first_stop_of_a_run_is_kept_and_the_next_run_records_its_own() {
    let mut region = Region::new();
    region.start(POWER_ON, IMAGE);
    region.record(a_panic(), IMAGE);
    // The panic handler's undefined instruction raises a HardFault: the panic stays.
    region.record(
        Stop {
            kind: Kind::HardFault,
            ..a_panic()
        },
        IMAGE,
    );
    assert_eq!(region.read().unwrap().kind, Kind::Panic);
    // After the reset, a stop of the new run replaces it.
    region.start(WATCHDOG, IMAGE);
    region.record(
        Stop {
            kind: Kind::Nmi,
            ..a_panic()
        },
        IMAGE,
    );
    assert_eq!(region.read().unwrap().kind, Kind::Nmi);
}

#[test]
fn a_watchdog_reset_leaves_a_record_of_the_events_before_it() {
    let mut region = Region::new();
    region.start(POWER_ON, IMAGE);
    for n in 0..10u8 {
        region.note(event(u32::from(n) * 100, What::ThrusterLost(n)));
    }
    let record = region.start(WATCHDOG, IMAGE).unwrap();
    assert_eq!(
        (record.kind, record.frame, record.reset_cause),
        (Kind::Watchdog, Frame::default(), WATCHDOG.0)
    );
    // The last seven, oldest first; its uptime the last event's.
    let slots: Vec<What> = record.events().iter().map(|e| e.what).collect();
    assert_eq!(slots, (3..10).map(What::ThrusterLost).collect::<Vec<_>>());
    assert_eq!(record.uptime_ms, 900);
    // A software reset without a record leaves none.
    let mut region = Region::new();
    region.start(POWER_ON, IMAGE);
    assert_eq!(region.start(SOFTWARE, IMAGE), None);
}

#[test]
fn a_torn_record_is_refused_by_its_crc() {
    let mut region = Region::new();
    region.start(POWER_ON, IMAGE);
    region.record(a_panic(), IMAGE);
    let good = region.record;
    for at in 5..LEN {
        for bit in 0..8 {
            let mut torn = good;
            torn[at] ^= 1 << bit;
            assert_eq!(Record::decode(&torn), Err(Error::Checksum), "byte {at} bit {bit}");
        }
    }
    // Half written: the first 64 bytes new, the rest an older record's.
    let mut older = Region::new();
    older.start(POWER_ON, IMAGE);
    older.record(
        Stop {
            kind: Kind::HardFault,
            ..a_panic()
        },
        IMAGE,
    );
    let mut half = older.record;
    half[..64].copy_from_slice(&good[..64]);
    assert_eq!(Record::decode(&half), Err(Error::Checksum));
    assert_eq!(Record::decode(&good[..100]), Err(Error::Length(100)));
    assert_eq!(Record::decode(&[0; LEN]), Err(Error::Magic));
}

#[test]
fn every_event_reads_back_as_itself() {
    for what in [
        What::Started(0x14),
        What::Armed,
        What::Disarmed(2),
        What::ThrusterLost(7),
        What::ThrusterBack(0),
        What::OperatorLost,
        What::OperatorBack,
        What::UpdateApplied(255),
        What::OrdersLost,
        What::FaultLatched(0x0840),
        What::Other { code: 999, arg: 1 },
    ] {
        let (code, arg) = what.to_parts();
        assert_eq!(What::from_parts(code, arg), what);
        assert_eq!(Event::from_bytes(event(7, what).to_bytes()), event(7, what));
    }
}

proptest! {
    #[test]
    fn any_bytes_decode_without_panicking_and_a_record_decoded_encodes_back(bytes in proptest::collection::vec(any::<u8>(), 0..140)) {
        if let Ok(record) = Record::decode(&bytes) {
            prop_assert_eq!(&record.encode()[..], &bytes[..]);
        }
    }

    #[test]
    fn any_ring_takes_events_and_gives_back_the_last_seven_in_order(
        start in proptest::collection::vec(any::<u8>(), RING_LEN),
        events in proptest::collection::vec((any::<u32>(), 1u16..11, any::<u8>()), 0..20),
    ) {
        let mut ring = Ring::from_bytes(start.try_into().unwrap());
        let _ = ring.events();
        let pushed: Vec<Event> = events
            .iter()
            .map(|&(at_ms, code, arg)| event(at_ms, What::from_parts(code, u16::from(arg))))
            .collect();
        for e in &pushed {
            ring.push(*e);
        }
        let (held, count) = ring.events();
        if !pushed.is_empty() {
            let last = &pushed[pushed.len().saturating_sub(EVENTS)..];
            prop_assert_eq!(&held[..usize::from(count)], last);
        }
    }

    #[test]
    fn any_region_starts_without_panicking(
        record in proptest::collection::vec(any::<u8>(), LEN),
        ring in proptest::collection::vec(any::<u8>(), RING_LEN),
        cause in any::<u32>(),
    ) {
        let mut region = Region { record: record.try_into().unwrap(), ring: ring.try_into().unwrap() };
        let found = region.start(ResetCause(cause), IMAGE);
        prop_assert_eq!(found, region.read());
    }
}
