use super::*;

const SIX: usize = 6;

fn region() -> &'static mut BlackBox {
    Box::leak(Box::new(BlackBox::new()))
}

/// Sample `n`'s bytes as the console writes one: the events before it, its clock, its flags (an event or not),
/// then `n` in every byte up to its CRC.
fn write(n: u32, event: bool) -> impl FnOnce(&mut [u8], u16, u32) -> bool {
    move |slot, events, clock| {
        slot.fill(n as u8);
        slot[..2].copy_from_slice(&events.to_le_bytes());
        slot[2..6].copy_from_slice(&clock.to_le_bytes());
        slot[FLAGS_AT] = u8::from(event) << 4;
        seal(slot);
        event
    }
}

/// The samples the region holds, oldest first: (its clock, its `n`).
fn held(region: &BlackBox) -> Vec<(u32, u8)> {
    let header = region.header().expect("a header that checks");
    (header.first..header.head)
        .map(|seq| {
            let slot = region.slot(&header, seq).unwrap();
            assert!(checks(slot), "sample {seq}");
            (u32::from_le_bytes(slot[2..6].try_into().unwrap()), slot[10])
        })
        .collect()
}

#[test]
fn what_it_holds_for_each_vehicle() {
    assert_eq!((sample_len(6), capacity(6)), (49, 1336));
    assert_eq!((capacity(4), capacity(8)), (1679, 1110));
    // At 10 Hz: 133 s for the LBV300-6, 167 s for four thrusters, 111 s for eight.
    assert_eq!(capacity(6) as u64 * PERIOD.as_millis() / 1000, 133);
}

#[test]
fn a_power_on_begins_empty_and_a_warm_reset_keeps_the_samples() {
    let region = region();
    // What a power-on leaves in RAM.
    region.header.fill(0xA5);
    region.ring.fill(0x5A);
    assert_eq!(region.start(SIX), 0);
    for n in 0..10 {
        region.push(PERIOD, write(n, false));
    }
    let before = held(region);
    assert_eq!(before.len(), 10);
    assert_eq!(before[9], (1000, 9));
    // A warm reset: the same RAM, started again.
    assert_eq!(region.start(SIX), 10);
    assert_eq!(held(region), before);
    // The clock runs on from the last sample; the events are counted.
    region.push(PERIOD, write(10, true));
    region.push(PERIOD, write(11, false));
    assert_eq!(held(region)[10..], [(1100, 10), (1200, 11)]);
    assert_eq!(region.header().unwrap().events, 1);
    // Recorded for another vehicle: begun again.
    assert_eq!(region.start(4), 0);
    assert_eq!(region.start(SIX), 0);
}

#[test]
fn a_reset_in_the_middle_of_a_sample_loses_that_sample_only() {
    let region = region();
    region.start(SIX);
    let capacity = capacity(SIX) as u32;
    for n in 0..capacity + 5 {
        region.push(PERIOD, write(n, false));
    }
    let header = region.header().unwrap();
    assert_eq!((header.first, header.head), (5, capacity + 5));
    // The next sample goes where the oldest is: the header has dropped the oldest, and the reset comes halfway
    // through writing the new one.
    let mut next = header;
    next.first += 1;
    region.header = next.encode();
    let at = (header.head as usize % capacity as usize) * sample_len(SIX);
    region.ring[at..at + 20].fill(0);
    assert_eq!(region.start(SIX), capacity - 1);
    assert_eq!(held(region).first().map(|s| s.1), Some(6));
    // A sample torn some other way (a bit flipped in the oldest) is dropped at the start too.
    let header = region.header().unwrap();
    let oldest = (header.first as usize % capacity as usize) * sample_len(SIX);
    region.ring[oldest + 3] ^= 1;
    assert_eq!(region.start(SIX), capacity - 2);
    // A header that does not check: nothing is kept.
    region.header[9] ^= 1;
    assert_eq!(region.start(SIX), 0);
}
