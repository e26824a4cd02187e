//! The ground station at the console link's other end: it reads everything the master sends and keeps what it
//! has seen, and sends the pilot's messages with QGroundControl's identity.

use core::cell::RefCell;
use core::sync::atomic::{AtomicU8, Ordering};

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use lbv_master_fw::console::lbv::{MavMessage, MavModeFlag, MavResult, MavSeverity};
use lbv_master_fw::framing::{Event, FrameParser};
use mavlink_core::{MAVLinkV2MessageRaw, MavHeader, MavlinkVersion, Message, MessageData};

use crate::executors::BENCH_METER;
use crate::master::{DOWNLINK, UPLINK};
use crate::meter::metered;

/// The ground station's MAVLink identity (QGroundControl's).
const GCS_SYSTEM: u8 = 255;
const GCS_COMPONENT: u8 = 190;
static SEQUENCE: AtomicU8 = AtomicU8::new(0);

/// The beginning of the console text that carries the acceptance test's verdict (`acceptance::report::verdict_text`).
const VERDICT_PASS: &str = "acceptance PASS";
const VERDICT_FAIL: &str = "acceptance FAIL";

/// What the station has seen of the master.
#[derive(Debug, Clone, Copy)]
pub struct Seen {
    /// Frames read.
    pub frames: u32,
    /// Heartbeats.
    pub heartbeats: u32,
    /// The last heartbeat said armed.
    pub armed: bool,
    /// The last COMMAND_ACK: command, accepted.
    pub ack: Option<(u16, bool)>,
    /// STATUSTEXTs, and of those the critical ones.
    pub texts: u32,
    pub critical_texts: u32,
    /// The acceptance test's verdict as the console said it: passed or not.
    pub acceptance: Option<bool>,
    /// Each thruster's speed and poll count (ESC telemetry).
    pub rpm: [u16; 8],
    pub polls: [u16; 8],
    /// The battery voltage (SYS_STATUS), mV.
    pub battery_mv: u16,
}

static SEEN: Mutex<CriticalSectionRawMutex, RefCell<Seen>> = Mutex::new(RefCell::new(Seen {
    frames: 0,
    heartbeats: 0,
    armed: false,
    ack: None,
    texts: 0,
    critical_texts: 0,
    acceptance: None,
    rpm: [0; 8],
    polls: [0; 8],
    battery_mv: 0,
}));

/// What the station has seen so far.
pub fn seen() -> Seen {
    SEEN.lock(|seen| *seen.borrow())
}

/// Change what the station keeps (forget the last acknowledgement before a command).
pub fn update(change: impl FnOnce(&mut Seen)) {
    SEEN.lock(|seen| change(&mut seen.borrow_mut()));
}

/// Send one message to the master.
pub async fn send<D: MessageData>(message: &D) {
    let mut raw = MAVLinkV2MessageRaw::new();
    let header = MavHeader {
        system_id: u32::from(GCS_SYSTEM),
        component_id: GCS_COMPONENT,
        sequence: SEQUENCE.fetch_add(1, Ordering::Relaxed),
    };
    raw.serialize_message_data(header, message);
    UPLINK.write_all(raw.raw_bytes()).await;
}

/// Read everything the master sends.
#[embassy_executor::task]
pub async fn receive() -> ! {
    metered(&BENCH_METER, None, read_downlink()).await
}

async fn read_downlink() -> ! {
    let mut parser = FrameParser::new();
    let mut buffer = [0u8; 128];
    loop {
        let n = DOWNLINK.read(&mut buffer).await;
        let mut bytes = buffer.get(..n).unwrap_or_default();
        while !bytes.is_empty() {
            let taken = parser.push(bytes);
            bytes = bytes.get(taken..).unwrap_or_default();
            while let Some(event) = parser.next(|id| Some(MavMessage::extra_crc(id))) {
                let Event::Frame(frame) = event else { continue };
                let Ok(message) = MavMessage::parse(MavlinkVersion::V2, frame.message_id, frame.payload) else {
                    continue;
                };
                update(|seen| take(seen, message));
            }
        }
    }
}

/// Note one message.
fn take(seen: &mut Seen, message: MavMessage) {
    seen.frames += 1;
    match message {
        MavMessage::HEARTBEAT(heartbeat) => {
            seen.heartbeats += 1;
            seen.armed = heartbeat.base_mode.contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED);
        }
        MavMessage::COMMAND_ACK(ack) => seen.ack = Some((ack.command, ack.result == MavResult::MAV_RESULT_ACCEPTED)),
        MavMessage::STATUSTEXT(text) => {
            seen.texts += 1;
            if text.severity == MavSeverity::MAV_SEVERITY_CRITICAL {
                seen.critical_texts += 1;
            }
            let words = text.text.to_str().unwrap_or_default();
            if words.starts_with(VERDICT_PASS) {
                seen.acceptance = Some(true);
            } else if words.starts_with(VERDICT_FAIL) {
                seen.acceptance = Some(false);
            }
        }
        MavMessage::ESC_TELEMETRY_1_TO_4(esc) => {
            seen.rpm.iter_mut().zip(esc.rpm).for_each(|(slot, rpm)| *slot = rpm);
            seen.polls
                .iter_mut()
                .zip(esc.count)
                .for_each(|(slot, count)| *slot = count);
        }
        MavMessage::ESC_TELEMETRY_5_TO_8(esc) => {
            seen.rpm
                .iter_mut()
                .skip(4)
                .zip(esc.rpm)
                .for_each(|(slot, rpm)| *slot = rpm);
            seen.polls
                .iter_mut()
                .skip(4)
                .zip(esc.count)
                .for_each(|(slot, count)| *slot = count);
        }
        MavMessage::SYS_STATUS(status) => seen.battery_mv = status.voltage_battery,
        _ => {}
    }
}
