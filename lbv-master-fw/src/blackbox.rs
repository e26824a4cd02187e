//! The black box's RAM: a ring of samples that a warm reset keeps ([`BlackBox`]), and the recorder that writes it
//! and reads it back for the file made from it ([`Recorder`]). What a sample holds and the file's messages are the
//! console's ([`crate::console::tlog`]); this module keeps bytes, and knows of a sample only where its number of
//! events before it, its clock and its event mark are, and that its CRC is its last two bytes.
//!
//! **Across a reset.** The region is in RAM that start-up does not clear and a system reset keeps
//! (`g431_hw::memory::BLACK_BOX`). Its header says which samples it holds and is checked (CRC) at each start, and
//! so is every sample: a power-on leaves no header that checks, and begins an empty ring; a reset in the middle of
//! a sample's writing leaves that sample out. The samples' clock is the time since the start for a new ring; across
//! a reset it runs on by the time since the new start (how long the reset itself took is not known).
//!
//! **Reading.** The file is made again at every read from the ring: a sample's place in it follows from its number
//! and the events before it ([`FileLayout`]), found by a binary search. The ring records nothing while the
//! operator's ground station reads it (until [`HOLD`] after its last read, or its session's end), so the file does
//! not change under the reader; another system's read holds nothing (else anyone on the link could stop the
//! recording), and a file whose samples the ring has since dropped is refused rather than read with others.

// The acceptance image records nothing and serves no file: it keeps no region, and what only the recording uses is
// left out of it.
#![cfg_attr(feature = "acceptance", allow(dead_code))]

use core::cell::RefCell;

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_time::{Duration, Instant};

/// How often a sample is taken.
pub const PERIOD: Duration = Duration::from_millis(100);
/// How long after a read of the file the ring goes on holding its samples, when no other read or the session's
/// end comes: a ground station that stops reading without closing does not stop the recording for good.
pub const HOLD: Duration = Duration::from_secs(5);
/// The region's size (`g431_hw::memory::BLACK_BOX`).
pub const REGION_LEN: usize = 64 * 1024;
/// The most thrusters a sample holds (the master's table's).
pub const MAX_THRUSTERS: usize = 8;
const HEADER_LEN: usize = 32;
const RING_LEN: usize = REGION_LEN - HEADER_LEN;
/// The header's first word: "LBB" and the layout's version. A region of another layout begins empty.
const MAGIC: [u8; 4] = *b"LBB1";
/// A sample's bytes before its thrusters' (the CRC follows them).
pub(crate) const SAMPLE_HEAD: usize = 17;
/// A thruster's bytes in a sample.
pub(crate) const THRUSTER_LEN: usize = 5;
/// Where a sample keeps its flags; its event is in bits 4 and 5.
pub(crate) const FLAGS_AT: usize = 6;

/// The bytes of one sample of a vehicle with `thrusters`: its head, its thrusters' and its CRC.
pub const fn sample_len(thrusters: usize) -> usize {
    SAMPLE_HEAD + THRUSTER_LEN * thrusters + 2
}

/// How many samples the ring holds for `thrusters`.
pub const fn capacity(thrusters: usize) -> usize {
    RING_LEN / sample_len(thrusters)
}

/// Whether the sample in `bytes` checks: its CRC (MAVLink's CRC-16, X.25) is its last two bytes.
pub(crate) fn checks(bytes: &[u8]) -> bool {
    match bytes.split_last_chunk::<2>() {
        Some((body, crc)) => mavlink_core::calculate_crc(body, 0).to_le_bytes() == *crc,
        None => false,
    }
}

/// Write the CRC of the sample in `bytes` into its last two bytes.
pub(crate) fn seal(bytes: &mut [u8]) {
    if let Some((body, crc)) = bytes.split_last_chunk_mut::<2>() {
        *crc = mavlink_core::calculate_crc(body, 0).to_le_bytes();
    }
}

/// The black box's RAM: its header, then the ring of samples. Any bytes are a value of it: what a power-on leaves
/// there is refused by the header's check, not trusted.
#[repr(C)]
#[derive(Debug)]
pub struct BlackBox {
    header: [u8; HEADER_LEN],
    ring: [u8; RING_LEN],
}

/// What the header says: the samples held, numbered from the ring's beginning, `first..head`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Header {
    thrusters: u8,
    first: u32,
    head: u32,
    /// Events recorded before `head`, wrapping.
    events: u16,
    /// The clock of sample `head - 1`, ms.
    clock: u32,
}

impl Header {
    fn encode(&self) -> [u8; HEADER_LEN] {
        let mut bytes = [0u8; HEADER_LEN];
        let fields: [(usize, &[u8]); 6] = [
            (0, &MAGIC),
            (4, &[self.thrusters]),
            (8, &self.first.to_le_bytes()),
            (12, &self.head.to_le_bytes()),
            (16, &self.events.to_le_bytes()),
            (18, &self.clock.to_le_bytes()),
        ];
        for (at, field) in fields {
            if let Some(slot) = bytes.get_mut(at..at + field.len()) {
                slot.copy_from_slice(field);
            }
        }
        let crc = mavlink_core::calculate_crc(bytes.get(..HEADER_LEN - 2).unwrap_or_default(), 0);
        if let Some(slot) = bytes.get_mut(HEADER_LEN - 2..) {
            slot.copy_from_slice(&crc.to_le_bytes());
        }
        bytes
    }

    /// The header in `bytes`, if it checks and is possible: its thrusters at most [`MAX_THRUSTERS`], its samples
    /// at most what the ring holds.
    fn decode(bytes: &[u8; HEADER_LEN]) -> Option<Self> {
        let (body, crc) = bytes.split_at(HEADER_LEN - 2);
        if mavlink_core::calculate_crc(body, 0).to_le_bytes() != *crc || body.get(..4) != Some(&MAGIC) {
            return None;
        }
        let word = |at: usize| Some(u32::from_le_bytes(*bytes.get(at..)?.first_chunk::<4>()?));
        let header = Self {
            thrusters: *bytes.get(4)?,
            first: word(8)?,
            head: word(12)?,
            events: u16::from_le_bytes(*bytes.get(16..)?.first_chunk::<2>()?),
            clock: word(18)?,
        };
        let thrusters = usize::from(header.thrusters);
        let held = header.head.checked_sub(header.first)?;
        (thrusters <= MAX_THRUSTERS && held as usize <= capacity(thrusters)).then_some(header)
    }
}

impl Default for BlackBox {
    fn default() -> Self {
        Self::new()
    }
}

impl BlackBox {
    /// An empty region (the bench's and the tests'; the firmware's is the RAM a reset left).
    pub const fn new() -> Self {
        Self {
            header: [0; HEADER_LEN],
            ring: [0; RING_LEN],
        }
    }

    fn header(&self) -> Option<Header> {
        Header::decode(&self.header)
    }

    /// At a start: keep the samples a warm reset left, if the header checks and they were recorded for as many
    /// `thrusters`, from the oldest after the last that does not check (one a reset cut short); otherwise begin
    /// empty. Returns how many samples are kept.
    pub fn start(&mut self, thrusters: usize) -> u32 {
        let thrusters = thrusters.min(MAX_THRUSTERS);
        let mut header = match self.header() {
            Some(header) if usize::from(header.thrusters) == thrusters => header,
            _ => Header {
                thrusters: thrusters as u8,
                first: 0,
                head: 0,
                events: 0,
                clock: 0,
            },
        };
        for seq in header.first..header.head {
            if !self.slot(&header, seq).is_some_and(checks) {
                header.first = seq + 1;
            }
        }
        self.header = header.encode();
        header.head - header.first
    }

    /// Where sample `seq` is in the ring.
    fn slot(&self, header: &Header, seq: u32) -> Option<&[u8]> {
        let thrusters = usize::from(header.thrusters);
        let at = seq as usize % capacity(thrusters) * sample_len(thrusters);
        self.ring.get(at..at + sample_len(thrusters))
    }

    /// Record a sample `elapsed` after the last, in place of the oldest when the ring is full: `write` fills its
    /// slot given the events before it and its clock (and seals it), and says whether it marks an event. The
    /// header is written before and after the sample, so a reset in between leaves the sample out and nothing else.
    fn push(&mut self, elapsed: Duration, write: impl FnOnce(&mut [u8], u16, u32) -> bool) {
        let Some(mut header) = self.header() else {
            return;
        };
        let thrusters = usize::from(header.thrusters);
        if (header.head - header.first) as usize >= capacity(thrusters) {
            header.first += 1;
            self.header = header.encode();
        }
        let clock = header.clock.wrapping_add(elapsed.as_millis() as u32);
        let at = header.head as usize % capacity(thrusters) * sample_len(thrusters);
        let event = match self.ring.get_mut(at..at + sample_len(thrusters)) {
            Some(slot) => write(slot, header.events, clock),
            None => return,
        };
        header.head += 1;
        header.events = header.events.wrapping_add(u16::from(event));
        header.clock = clock;
        self.header = header.encode();
    }
}

/// `@SYS/blackbox.tlog` as it was opened: the samples it holds and its length. Bytes, so that a read's reply stays
/// the size of `versions.txt`'s.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TlogFile {
    /// Its first sample's number, little-endian.
    first: [u8; 4],
    /// Its samples, little-endian.
    count: [u8; 2],
    /// The thrusters of its samples.
    thrusters: u8,
    /// Its length in bytes, little-endian.
    len: [u8; 4],
}

impl TlogFile {
    /// Its length in bytes.
    pub(crate) fn len(&self) -> u32 {
        u32::from_le_bytes(self.len)
    }

    /// The thrusters of its samples.
    pub(crate) fn thrusters(&self) -> usize {
        usize::from(self.thrusters)
    }

    /// Its samples' numbers.
    pub(crate) fn samples(&self) -> core::ops::Range<u32> {
        let first = u32::from_le_bytes(self.first);
        first..first + u32::from(u16::from_le_bytes(self.count))
    }
}

/// How a file lays out its samples: the bytes and frames of one without an event, and what an event's message
/// adds (one frame).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct FileLayout {
    pub(crate) bytes: u32,
    pub(crate) frames: u32,
    pub(crate) event_bytes: u32,
}

/// Where a sample of the file starts: its byte and its first frame's number.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Place {
    pub(crate) offset: u32,
    pub(crate) frame: u32,
}

impl FileLayout {
    /// Where sample `seq` starts in a file from sample `first`, with `events` events between them.
    fn place(&self, first: u32, seq: u32, events: u16) -> Place {
        let k = seq - first;
        Place {
            offset: k * self.bytes + u32::from(events) * self.event_bytes,
            frame: k * self.frames + u32::from(events),
        }
    }
}

/// Whether the sample in `bytes` marks an event.
fn marks_event(bytes: &[u8]) -> bool {
    bytes.get(FLAGS_AT).is_some_and(|flags| flags >> 4 != 0)
}

/// The recording, and the file made from it: the region once the binding hands it over, and what the recorder
/// keeps beside it. Written by the black box's task, held by the update server, read by the console's transmit
/// task as it frames the file's reads.
#[derive(Debug)]
pub struct Recorder {
    state: Mutex<CriticalSectionRawMutex, RefCell<Recording>>,
}

#[derive(Debug)]
struct Recording {
    region: Option<&'static mut BlackBox>,
    /// When the master started: when the region was handed over.
    started: Instant,
    /// When the last sample was recorded since the start.
    last: Option<Instant>,
    /// Until when a read holds the samples.
    held_until: Option<Instant>,
    /// How the file lays out the samples, once the recording has said ([`Recorder::lay_out`]).
    layout: Option<FileLayout>,
}

impl Default for Recorder {
    fn default() -> Self {
        Self::new()
    }
}

impl Recorder {
    /// No region yet: nothing is recorded, and the file is not there.
    pub const fn new() -> Self {
        Self {
            state: Mutex::new(RefCell::new(Recording {
                region: None,
                started: Instant::from_ticks(0),
                last: None,
                held_until: None,
                layout: None,
            })),
        }
    }

    /// Record into `region` from now on, the master having started at `started`, for a vehicle of `thrusters`,
    /// keeping what a warm reset left in it ([`BlackBox::start`]).
    pub fn keep(&self, region: &'static mut BlackBox, started: Instant, thrusters: usize) {
        region.start(thrusters);
        self.state.lock(|state| {
            let state = &mut *state.borrow_mut();
            state.region = Some(region);
            state.started = started;
            state.last = None;
        });
    }

    /// Give the region back (the bench's master, restarting, hands it to its next start as a warm reset does).
    pub fn release(&self) -> Option<&'static mut BlackBox> {
        self.state.lock(|state| state.borrow_mut().region.take())
    }

    /// Record a sample at `now` ([`BlackBox::push`]'s `write`), unless a read holds the samples: whether it was
    /// recorded.
    #[inline(never)]
    pub(crate) fn record(&self, now: Instant, write: impl FnOnce(&mut [u8], u16, u32) -> bool) -> bool {
        self.state.lock(|state| {
            let state = &mut *state.borrow_mut();
            if state.held_until.is_some_and(|until| now < until) {
                return false;
            }
            let Some(region) = state.region.as_deref_mut() else {
                return false;
            };
            // The first after a start follows the last before it by the time since the start: how long the
            // reset took is not known (a fresh ring's clock is then the time since the start).
            let since = state.last.unwrap_or(state.started);
            region.push(now.saturating_duration_since(since), write);
            state.last = Some(now);
            true
        })
    }

    /// The file lays out its samples as `layout` says: the recording's task says so as it begins, and until then
    /// there is no file.
    pub(crate) fn lay_out(&self, layout: FileLayout) {
        self.state.lock(|state| state.borrow_mut().layout = Some(layout));
    }

    /// A read of the file at `now` holds the samples for [`HOLD`]; `None` lets them go (the session's end).
    pub(crate) fn hold(&self, now: Option<Instant>) {
        self.state
            .lock(|state| state.borrow_mut().held_until = now.map(|now| now + HOLD));
    }

    /// The file as it stands: `None` without a region, or before the recording has said how it lays it out.
    #[inline(never)]
    pub(crate) fn open(&self) -> Option<TlogFile> {
        self.state.lock(|state| {
            let state = state.borrow();
            let region = state.region.as_deref()?;
            let layout = state.layout?;
            let header = region.header()?;
            let count = header.head - header.first;
            let len = match header.head.checked_sub(1) {
                Some(last) if count > 0 => {
                    let bytes = region.slot(&header, last)?;
                    let events = count_events(region, &header, header.first, last)?;
                    let place = layout.place(header.first, last, events);
                    place.offset + layout.bytes + if marks_event(bytes) { layout.event_bytes } else { 0 }
                }
                _ => 0,
            };
            Some(TlogFile {
                first: header.first.to_le_bytes(),
                count: (count as u16).to_le_bytes(),
                thrusters: header.thrusters,
                len: len.to_le_bytes(),
            })
        })
    }

    /// Copy sample `seq` of `file` into `into` ([`sample_len`] of its thrusters), if the ring still holds it as it
    /// was.
    pub(crate) fn sample(&self, file: &TlogFile, seq: u32, into: &mut [u8]) -> Option<()> {
        self.state.lock(|state| {
            let state = state.borrow();
            let region = state.region.as_deref()?;
            let header = held(region, file)?;
            into.get_mut(..sample_len(file.thrusters()))?
                .copy_from_slice(region.slot(&header, seq)?);
            Some(())
        })
    }

    /// The sample of `file` that byte `offset` is in, and where it starts: a binary search on the events before
    /// each sample, which with the sample's number says where it starts.
    pub(crate) fn find(&self, file: &TlogFile, offset: u32) -> Option<(u32, Place)> {
        self.state.lock(|state| {
            let state = state.borrow();
            let region = state.region.as_deref()?;
            let header = held(region, file)?;
            let layout = state.layout?;
            let samples = file.samples();
            let at = |seq: u32| {
                let events = count_events(region, &header, samples.start, seq)?;
                Some(layout.place(samples.start, seq, events))
            };
            // The last sample that starts at or before `offset`.
            let (mut low, mut high) = (samples.start, samples.end);
            while high - low > 1 {
                let middle = low + (high - low) / 2;
                if at(middle)?.offset <= offset {
                    low = middle;
                } else {
                    high = middle;
                }
            }
            Some((low, at(low)?))
        })
    }
}

/// The ring's header, if the samples `file` was opened with are all still in it.
fn held(region: &BlackBox, file: &TlogFile) -> Option<Header> {
    let header = region.header()?;
    let samples = file.samples();
    (header.first <= samples.start && samples.end <= header.head && header.thrusters == file.thrusters)
        .then_some(header)
}

/// The events recorded from sample `from` to before sample `seq`.
fn count_events(region: &BlackBox, header: &Header, from: u32, seq: u32) -> Option<u16> {
    let events = |seq: u32| Some(u16::from_le_bytes(*region.slot(header, seq)?.first_chunk::<2>()?));
    Some(events(seq)?.wrapping_sub(events(from)?))
}

#[cfg(test)]
mod tests;
