//! The black box's samples and the telemetry log made from them, `@SYS/blackbox.tlog`: the vehicle's last minutes,
//! ten samples a second, which pymavlink's `mavlogdump.py`, MAVExplorer and the ground stations open as they open
//! their own logs. The ring they are kept in, and how it survives a reset, is [`crate::blackbox`]'s.
//!
//! **A sample** ([`Sample`]) holds what the master knows at that moment: the arm state, the ground station's link
//! and its failsafe, the battery as BATTERY_STATUS says it, and for each configured thruster its order, the speed,
//! current, temperature and faults it reports, and whether it reports. It is [`sample_len`] bytes: 19 and 5 per
//! thruster, so the 64 KiB region holds [`blackbox::capacity`] samples: 133 s for the LBV300-6's six thrusters, 167 s for
//! four, 111 s for eight. The first sample after a start is marked ([`Event::Started`]).
//!
//! **The file.** Each sample is a fixed set of MAVLink 2 messages, each after the 8-byte big-endian timestamp a
//! tlog puts before every message: HEARTBEAT (armed or not), SERVO_OUTPUT_RAW (the orders, as ArduSub's motor
//! outputs), BATTERY_STATUS, then for every block of four thrusters ESC_TELEMETRY_1_TO_4 or _5_TO_8 (rpm,
//! current, temperature: the message ArduPilot logs and pymavlink knows) and ESC_INFO (faults, which report; it is
//! common.xml's, which pymavlink 2.4.50 does not know yet and reads as UNKNOWN_290), and a STATUSTEXT when the
//! sample marks an event (the master started, the ground station's link lost or back). Their payloads are whole,
//! not cut at their trailing zeros: every sample's length is then known without making it ([`layout`]), and a read
//! anywhere in the file finds its sample at once. With six thrusters a sample is 420 bytes of the file: two minutes
//! are some 500 KB, which the operator's ground station reads at half the console's line
//! ([`crate::console::limit`]), in about 90 s.
//!
//! **What it simplifies.** The timestamps count from the ring's beginning, not from a calendar date: the master
//! has no clock (a tool reads them as times early on 1 January 1970). ESC_TELEMETRY's rpm is a magnitude (its field
//! is unsigned; the order says the direction). ESC_TELEMETRY's count and ESC_INFO's counter are the sample's
//! number, ESC_INFO's error counts 0: the link counters are not kept (SYS_STATUS says them live). A thruster's
//! temperature of 255 °C would read as unknown (the thruster stops at 110).

// The acceptance image records nothing (its task is not joined) and serves no file: what only the recording uses
// is left out of it.
#![cfg_attr(feature = "acceptance", allow(dead_code, unused_imports))]

use embassy_time::{Instant, Ticker};
use mavlink_core::MessageData;
use num_traits::FromPrimitive;
use tmc_proto::{Faults, Speed};

use super::lbv::{
    BATTERY_STATUS_DATA, ESC_INFO_DATA, ESC_TELEMETRY_1_TO_4_DATA, ESC_TELEMETRY_5_TO_8_DATA, HEARTBEAT_DATA,
    MavBatteryChargeState, MavBatteryFault, SERVO_OUTPUT_RAW_DATA, STATUSTEXT_DATA,
};
use super::outbound::{self, BatteryFields, Esc, EscCounters, EscEntry, Framer, Reports};
use crate::blackbox::sample_len;
use crate::blackbox::{self, FLAGS_AT, FileLayout, PERIOD, Recorder, SAMPLE_HEAD, THRUSTER_LEN, TlogFile};
use crate::shared::{MAX_THRUSTERS, Severity, Shared, Text, text};
use crate::update::window::Window;

// A sample holds as many thrusters as the master's table.
const _: () = assert!(blackbox::MAX_THRUSTERS == MAX_THRUSTERS);
/// The temperature byte of a thruster that reports none.
const NO_TEMPERATURE: u8 = u8::MAX;

/// What a sample marks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Event {
    /// The first sample after the master's start.
    Started,
    /// The ground station's heartbeats stopped.
    LinkLost,
    /// They came back.
    LinkBack,
}

impl Event {
    const fn code(self) -> u8 {
        match self {
            Self::Started => 1,
            Self::LinkLost => 2,
            Self::LinkBack => 3,
        }
    }

    const fn of_code(code: u8) -> Option<Self> {
        match code {
            1 => Some(Self::Started),
            2 => Some(Self::LinkLost),
            3 => Some(Self::LinkBack),
            _ => None,
        }
    }

    /// Its STATUSTEXT in the file.
    fn text(self) -> (Severity, Text) {
        match self {
            Self::Started => (Severity::Notice, text(format_args!("Black box: master started"))),
            Self::LinkLost => (Severity::Warning, text(format_args!("Black box: ground station lost"))),
            Self::LinkBack => (Severity::Info, text(format_args!("Black box: ground station back"))),
        }
    }
}

/// One sample: what the master knew at that moment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Sample {
    /// The black box's clock, ms: set when it is recorded.
    pub(crate) clock: u32,
    /// Events recorded before it, wrapping: set when it is recorded.
    events: u16,
    pub(crate) armed: bool,
    /// The ground station's heartbeats are heard.
    pub(crate) console_alive: bool,
    pub(crate) failsafe: bool,
    pub(crate) event: Option<Event>,
    pub(crate) battery: BatteryFields,
    /// The order to each thruster.
    pub(crate) orders: [Speed; MAX_THRUSTERS],
    /// What each thruster reports.
    pub(crate) escs: [Esc; MAX_THRUSTERS],
}

impl Sample {
    /// What `shared` says now of a vehicle of `thrusters`, marked with `event`. Not inlined into the task's
    /// future, which every task's code is joined in.
    #[cfg(not(feature = "acceptance"))]
    #[inline(never)]
    fn take(shared: &Shared, thrusters: usize, event: Option<Event>) -> Self {
        let vehicle = shared.vehicle.try_get();
        let reports: Reports = core::array::from_fn(|n| shared.thrusters.get(n).and_then(|w| w.try_get()));
        Self {
            clock: 0,
            events: 0,
            armed: vehicle.is_some_and(|v| v.armed),
            console_alive: vehicle.is_some_and(|v| v.console_alive),
            failsafe: vehicle.is_some_and(|v| v.failsafe),
            event,
            battery: BatteryFields::of(shared.battery.try_get().as_ref()),
            orders: shared
                .orders
                .try_get()
                .map_or([Speed::ZERO; MAX_THRUSTERS], |o| o.map(|o| o.speed)),
            escs: core::array::from_fn(|n| Esc::of(thrusters, &reports, n)),
        }
    }

    /// Its bytes for a vehicle of `thrusters` into `into` ([`sample_len`] long), its CRC last.
    fn encode(&self, thrusters: usize, into: &mut [u8]) {
        let flags = u8::from(self.armed)
            | u8::from(self.console_alive) << 1
            | u8::from(self.failsafe) << 2
            | self.event.map_or(0, Event::code) << 4;
        let b = &self.battery;
        let mut head = [0u8; SAMPLE_HEAD];
        let fields: [&[u8]; 9] = [
            &self.events.to_le_bytes(),
            &self.clock.to_le_bytes(),
            &[flags],
            &b.millivolts.to_le_bytes(),
            &b.centiamps.to_le_bytes(),
            &b.remaining.to_le_bytes(),
            &[b.charge_state as u8],
            &(b.faults.bits() as u16).to_le_bytes(),
            &b.temperature.to_le_bytes(),
        ];
        let mut at = 0;
        for field in fields {
            if let Some(slot) = head.get_mut(at..at + field.len()) {
                slot.copy_from_slice(field);
            }
            at += field.len();
        }
        let len = sample_len(thrusters);
        let Some(body) = into.get_mut(..len - 2) else {
            return;
        };
        let (front, rest) = body.split_at_mut(SAMPLE_HEAD.min(body.len()));
        front.copy_from_slice(head.get(..front.len()).unwrap_or_default());
        for ((entry, order), esc) in rest.chunks_exact_mut(THRUSTER_LEN).zip(&self.orders).zip(&self.escs) {
            let state = esc.faults.bits()
                | u8::from(esc.reporting) << 5
                | u8::from(esc.speed.is_some()) << 6
                | u8::from(esc.current_deciamps.is_some()) << 7;
            entry.copy_from_slice(&[
                order.step() as u8,
                esc.speed.map_or(0, Speed::step) as u8,
                esc.current_deciamps.unwrap_or(0),
                esc.temperature_c.unwrap_or(NO_TEMPERATURE),
                state,
            ]);
        }
        if let Some(sample) = into.get_mut(..len) {
            blackbox::seal(sample);
        }
    }

    /// The sample in `bytes`, recorded for `thrusters`, if its CRC checks.
    fn decode(bytes: &[u8], thrusters: usize) -> Option<Self> {
        let len = sample_len(thrusters);
        let sample = bytes.get(..len).filter(|sample| blackbox::checks(sample))?;
        let body = sample.get(..len - 2)?;
        let u16_at = |at: usize| Some(u16::from_le_bytes(*body.get(at..)?.first_chunk::<2>()?));
        let byte = |at: usize| body.get(at).copied();
        let flags = byte(FLAGS_AT)?;
        let mut orders = [Speed::ZERO; MAX_THRUSTERS];
        let mut escs = [Esc::default(); MAX_THRUSTERS];
        let entries = body.get(SAMPLE_HEAD..)?.chunks_exact(THRUSTER_LEN);
        for ((entry, order), esc) in entries.zip(&mut orders).zip(&mut escs) {
            let &[ordered, speed, current, temperature, state] = entry else {
                return None;
            };
            *order = Speed::new(ordered as i8).unwrap_or(Speed::ZERO);
            *esc = Esc {
                reporting: state & 1 << 5 != 0,
                speed: Speed::new(speed as i8).filter(|_| state & 1 << 6 != 0),
                current_deciamps: (state & 1 << 7 != 0).then_some(current),
                temperature_c: (temperature != NO_TEMPERATURE).then_some(temperature),
                faults: Faults::from_bits_truncate(state),
            };
        }
        Some(Self {
            events: u16_at(0)?,
            clock: u32::from_le_bytes(*body.get(2..)?.first_chunk::<4>()?),
            armed: flags & 1 != 0,
            console_alive: flags & 2 != 0,
            failsafe: flags & 4 != 0,
            event: Event::of_code(flags >> 4),
            battery: BatteryFields {
                millivolts: u16_at(7)?,
                centiamps: u16_at(9)? as i16,
                remaining: byte(11)? as i8,
                charge_state: MavBatteryChargeState::from_u8(byte(12)?)
                    .unwrap_or(MavBatteryChargeState::MAV_BATTERY_CHARGE_STATE_UNDEFINED),
                faults: MavBatteryFault::from_bits_truncate(u32::from(u16_at(13)?)),
                temperature: u16_at(15)? as i16,
            },
            orders,
            escs,
        })
    }
}

/// The file's part of one message: its timestamp and its frame with the payload whole.
const fn entry_len(payload: usize) -> u32 {
    (8 + 10 + payload + 2) as u32
}

// Both blocks' telemetry messages are the same length.
const _: () = assert!(ESC_TELEMETRY_1_TO_4_DATA::ENCODED_LEN == ESC_TELEMETRY_5_TO_8_DATA::ENCODED_LEN);

/// How the file lays out the samples of `thrusters`: HEARTBEAT, SERVO_OUTPUT_RAW and BATTERY_STATUS, two messages
/// a block of four thrusters, and an event's STATUSTEXT.
pub(crate) const fn layout(thrusters: usize) -> FileLayout {
    let blocks = thrusters.div_ceil(4) as u32;
    FileLayout {
        bytes: entry_len(HEARTBEAT_DATA::ENCODED_LEN)
            + entry_len(SERVO_OUTPUT_RAW_DATA::ENCODED_LEN)
            + entry_len(BATTERY_STATUS_DATA::ENCODED_LEN)
            + blocks * (entry_len(ESC_TELEMETRY_1_TO_4_DATA::ENCODED_LEN) + entry_len(ESC_INFO_DATA::ENCODED_LEN)),
        frames: 3 + 2 * blocks,
        event_bytes: entry_len(STATUSTEXT_DATA::ENCODED_LEN),
    }
}

/// Record `sample` at `now` unless a read holds the samples: whether it was recorded.
pub(crate) fn record(recorder: &Recorder, now: Instant, mut sample: Sample) -> bool {
    recorder.record(now, |slot, events, clock| {
        let thrusters = slot.len().saturating_sub(SAMPLE_HEAD + 2) / THRUSTER_LEN;
        sample.events = events;
        sample.clock = clock;
        sample.encode(thrusters, slot);
        sample.event.is_some()
    })
}

/// Write the bytes of `file` from `offset` into `into`, with frames from `system` / `component`: how many, or
/// `None` when the samples it was opened with are no longer all in the ring.
#[inline(never)]
pub(crate) fn read(recorder: &Recorder, file: &TlogFile, offset: u32, into: &mut [u8], ids: (u8, u8)) -> Option<usize> {
    let thrusters = file.thrusters();
    let samples = file.samples();
    let (mut seq, mut place) = recorder.find(file, offset)?;
    let mut window = Window::new(offset - place.offset, into);
    let mut framer = Framer::new(ids.0, ids.1);
    let mut bytes = [0u8; sample_len(MAX_THRUSTERS)];
    while seq < samples.end && window.filled < window.capacity() {
        recorder.sample(file, seq, &mut bytes)?;
        let sample = Sample::decode(&bytes, thrusters)?;
        render(
            &sample,
            seq - samples.start,
            place.frame,
            thrusters,
            &mut framer,
            &mut window,
        );
        place.frame += layout(thrusters).frames + u32::from(sample.event.is_some());
        seq += 1;
    }
    Some(window.filled)
}

/// Write sample number `k` of the file, whose first frame is number `frame`, into `window`.
fn render(sample: &Sample, k: u32, frame: u32, thrusters: usize, framer: &mut Framer, window: &mut Window<'_>) {
    let time_usec = u64::from(sample.clock) * 1000;
    let mut tlog = Tlog {
        framer,
        window,
        stamp: time_usec.to_be_bytes(),
        sequence: frame as u8,
    };
    tlog.put(&outbound::heartbeat_of(sample.armed));
    // SERVO_OUTPUT_RAW's time wraps after 71 minutes, as the field does.
    tlog.put(&outbound::servo_output_raw(thrusters, &sample.orders, time_usec as u32));
    tlog.put(&sample.battery.message());
    let counters = EscCounters {
        counter: k as u16,
        errors: [0; 4],
    };
    for first in (0..thrusters).step_by(4) {
        let escs: [Esc; 4] = core::array::from_fn(|i| {
            sample
                .escs
                .get(first + i)
                .copied()
                .filter(|_| first + i < thrusters)
                .unwrap_or_default()
        });
        let entries = escs.map(|esc| EscEntry::of(&esc, k as u16));
        if first == 0 {
            tlog.put(&outbound::esc_telemetry_of(&entries));
        } else {
            tlog.put(&outbound::esc_telemetry_5_to_8_of(&entries));
        }
        tlog.put(&outbound::esc_info(thrusters, first, &escs, &counters, time_usec));
    }
    if let Some(event) = sample.event {
        let (severity, text) = event.text();
        tlog.put(&outbound::statustext(severity, &text));
    }
}

/// The messages of one sample as the file has them: each after its timestamp, numbered on.
struct Tlog<'f, 'w> {
    framer: &'f mut Framer,
    window: &'f mut Window<'w>,
    stamp: [u8; 8],
    sequence: u8,
}

impl Tlog<'_, '_> {
    fn put<D: MessageData>(&mut self, message: &D) {
        self.window.put(&self.stamp);
        self.window.put(self.framer.frame_whole(message, self.sequence));
        self.sequence = self.sequence.wrapping_add(1);
    }
}

/// The black box's task: a sample every [`PERIOD`] of what `shared` says of a vehicle of `thrusters`.
#[cfg(not(feature = "acceptance"))]
pub(crate) async fn black_box_task(shared: &Shared, thrusters: usize) -> ! {
    shared.black_box.lay_out(layout(thrusters));
    let mut ticker = Ticker::every(PERIOD);
    let mut link: Option<bool> = None;
    let mut pending = None;
    loop {
        ticker.next().await;
        let alive = shared.vehicle.try_get().is_some_and(|v| v.console_alive);
        let event = match link {
            None => Some(Event::Started),
            Some(true) if !alive => Some(Event::LinkLost),
            Some(false) if alive => Some(Event::LinkBack),
            Some(_) => None,
        };
        link = Some(alive);
        // An event while a read holds the samples waits for the next sample recorded.
        let sample = Sample::take(shared, thrusters, pending.take().or(event));
        if !record(&shared.black_box, Instant::now(), sample) {
            pending = sample.event;
        }
    }
}

#[cfg(test)]
pub(crate) mod tests;
