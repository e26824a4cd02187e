//! The console's receive task under floods and a busy update sink, on virtual time: it never stops reading the
//! operator's HEARTBEAT and MANUAL_CONTROL, whatever another component asks, however full the outbox is, however
//! long the courier keeps the sink busy; and what makes the vehicle send more than it costs is limited per
//! requester.
//!
//! Before: every FTP reply waited for room in the outbox and every read for the sink's room, so 17 listings from
//! another system with the outbox full, or one write to a thruster whose page was on its way, stopped the reading
//! (on the chip, the UART's 256-byte buffer overran and the operator's frames were lost); a PARAM_REQUEST_LIST
//! from anyone was answered with every PARAM_VALUE, as often as it came.

use std::cell::{Cell, RefCell};
use std::rc::Rc;

use crate::support::{Line, clock, parse_all, publish, run_console, v2};
use embassy_futures::block_on;
use embassy_futures::select::select;
use embassy_futures::yield_now;
use embassy_time::{Duration, Instant};
use lbv_master_fw::console::lbv::{
    COMMAND_LONG_DATA, FILE_TRANSFER_PROTOCOL_DATA, MANUAL_CONTROL_DATA, MavMessage, PARAM_REQUEST_LIST_DATA,
};
use lbv_master_fw::console::limit::BURST;
use lbv_master_fw::console::{ConsoleConfig, ConsoleStats, HELD, console_rx_task};
use lbv_master_fw::mixer::FrameKind;
use lbv_master_fw::params::{LISTED_COUNT, Param, Settings};
use lbv_master_fw::ports::{Applied, Refused, UpdateSink, UpdateTarget};
use lbv_master_fw::shared::{Command, Outgoing, Request, Sender, Severity, Shared, text};
use lbv_master_fw::update::{Contents, ImageHeader, ftp};
use lbv_master_fw::vehicle::{Vehicle, VehicleConfig};
use lbv_station::GCS_HEARTBEAT;

const GCS: (u8, u8) = (255, 190);
const OTHER: (u8, u8) = (77, 1);
/// Another component of the operator's system (a companion computer).
const COMPANION: (u8, u8) = (255, 1);

const LIST: u8 = 3;
const CREATE: u8 = 6;
const WRITE: u8 = 7;
const TERMINATE: u8 = 1;

/// A FILE_TRANSFER_PROTOCOL frame from `from`: a MAVLink FTP request as pymavlink builds it.
fn ftp_frame(from: (u8, u8), seq: u16, session: u8, opcode: u8, offset: u32, data: &[u8]) -> Vec<u8> {
    let mut payload = [0u8; 251];
    payload[..2].copy_from_slice(&seq.to_le_bytes());
    payload[2] = session;
    payload[3] = opcode;
    payload[4] = data.len() as u8;
    payload[8..12].copy_from_slice(&offset.to_le_bytes());
    payload[12..12 + data.len()].copy_from_slice(data);
    let message = FILE_TRANSFER_PROTOCOL_DATA {
        target_network: 0,
        target_system: 1,
        target_component: 1,
        payload,
    };
    v2(from.0, from.1, seq as u8, &message)
}

fn heartbeat(from: (u8, u8), sequence: u8) -> Vec<u8> {
    v2(from.0, from.1, sequence, &GCS_HEARTBEAT)
}

fn sticks(sequence: u8, x: i16) -> Vec<u8> {
    let message = MANUAL_CONTROL_DATA {
        target: 1,
        x,
        z: 500,
        ..MANUAL_CONTROL_DATA::DEFAULT
    };
    v2(GCS.0, GCS.1, sequence, &message)
}

fn param_list(from: (u8, u8), sequence: u8) -> Vec<u8> {
    let message = PARAM_REQUEST_LIST_DATA {
        target_system: 1,
        target_component: 1,
    };
    v2(from.0, from.1, sequence, &message)
}

fn request_message(from: (u8, u8), sequence: u8, id: f32) -> Vec<u8> {
    let message = COMMAND_LONG_DATA {
        target_system: 1,
        target_component: 1,
        command: 512,
        param1: id,
        ..COMMAND_LONG_DATA::DEFAULT
    };
    v2(from.0, from.1, sequence, &message)
}

/// An update file for thruster slot 0 (SeaBotix): `LBVU`, format 1, the target, the payload's length, a version
/// and a signature, then the payload.
fn update_file(payload_len: u32) -> Vec<u8> {
    let mut file = b"LBVU".to_vec();
    file.extend([1, 1, 0, 0]);
    file.extend(payload_len.to_le_bytes());
    file.extend([0, 1, 0, 0]);
    file.extend([0x5A; 64]);
    file.extend((0..payload_len).map(|n| (n * 7 + 3) as u8));
    file
}

/// A sink whose room the test opens and closes, as the courier's does while a page goes to a thruster; it keeps
/// the offset and length of every write.
#[derive(Clone, Default)]
struct Gate {
    closed: Rc<Cell<bool>>,
    writes: Rc<RefCell<Vec<(u32, usize)>>>,
}

impl UpdateSink for Gate {
    async fn ready(&mut self) {
        while self.closed.get() {
            yield_now().await;
        }
    }

    fn begin(&mut self, _: UpdateTarget, _: &ImageHeader) -> Result<(), Refused> {
        Ok(())
    }

    fn write(&mut self, offset: u32, data: &[u8]) -> Result<(), Refused> {
        // A sink is only called when it has room.
        assert!(!self.closed.get(), "a write while the sink has no room");
        self.writes.borrow_mut().push((offset, data.len()));
        Ok(())
    }

    fn finish(&mut self, _: bool) -> Result<(), Refused> {
        Ok(())
    }

    fn apply(&mut self, _: UpdateTarget, _: Sender) -> Result<Applied, ftp::Nak> {
        Ok(Applied::NotWired)
    }
}

/// The defaults, with `LBV_UPD_UNSIGNED` 1 (these tests run without signing).
fn settings() -> Settings {
    let mut settings = VehicleConfig::DEFAULT.defaults();
    assert!(settings.params.set(Param::UnsignedUpdates, 1));
    settings
}

/// The receive task alone, on the virtual clock (taken at 0) with `line` as its input and `sink`, for `run_for` in
/// 1 ms steps; `each_ms` sees the shared state after each step and may change it. Nothing drains the outbox or
/// the commands but `each_ms`. The vehicle's state and `settings` are published first, as the vehicle task would.
fn run_rx(
    line: Line,
    sink: Gate,
    run_for: Duration,
    mut each_ms: impl FnMut(Instant, &Shared, &ConsoleStats),
) -> ConsoleStats {
    let clock = clock();
    let shared = Shared::new();
    let stats = ConsoleStats::new();
    let settings = settings();
    publish(&shared, settings);
    shared
        .vehicle
        .sender()
        .send(Vehicle::new(VehicleConfig::DEFAULT, settings).state(Instant::from_ticks(0)));
    let mut rx = line;
    let config = ConsoleConfig::DEFAULT;
    let table = lbv_master_fw::config::VEHICLE.thrusters;
    block_on(select(
        console_rx_task(&mut rx, &config, &shared, &stats, &table, FrameKind::Lbv300_6, sink),
        async {
            let end = Instant::now() + run_for;
            while Instant::now() < end {
                for _ in 0..8 {
                    yield_now().await;
                }
                each_ms(Instant::now(), &shared, &stats);
                clock.advance(Duration::from_millis(1));
            }
        },
    ));
    stats
}

/// The commands the vehicle would have been handed, taken from the channel.
fn take_commands(shared: &Shared, into: &mut Vec<(Instant, Request)>) {
    while let Ok(request) = shared.commands.try_receive() {
        into.push((Instant::now(), request));
    }
}

/// The FTP replies queued, taken from the outbox: (to, reply opcode, request opcode, seq).
fn take_replies(shared: &Shared, into: &mut Vec<(Sender, u8, u8, u16)>) {
    while let Ok(message) = shared.outbox.try_receive() {
        if let Outgoing::Ftp { to, reply } = message {
            let reply = reply.payload(&Contents::NOTHING);
            into.push((to, reply[3], reply[5], u16::from_le_bytes([reply[0], reply[1]])));
        }
    }
}

#[test]
fn a_listing_flood_from_another_system_with_the_outbox_full_never_stops_the_reading() {
    // System 77 lists the update directory 40 times at once (its whole allowance), with nothing draining the
    // outbox; then the operator's heartbeat and sticks.
    let flood: Vec<u8> = (0..40u16)
        .flat_map(|n| ftp_frame(OTHER, n, 0, LIST, 0, b"/update"))
        .collect();
    let line = Line::new(vec![(0, flood), (5, heartbeat(GCS, 0)), (6, sticks(1, 300))]);
    let mut commands = Vec::new();
    let stats = run_rx(line, Gate::default(), Duration::from_millis(20), |_, shared, _| {
        take_commands(shared, &mut commands)
    });
    let got: Vec<Command> = commands.iter().map(|(_, request)| request.command).collect();
    assert_eq!(got.len(), 2, "the operator's frames were read: {got:?}");
    assert_eq!(got[0], Command::Heartbeat);
    assert!(matches!(got[1], Command::Manual(input, _) if input.x == 300));
    // 16 replies fill the outbox, the other 24 are dropped.
    let counters = stats.snapshot();
    assert_eq!((counters.replies_dropped, counters.rate_limited), (24, 0));
}

#[test]
fn reading_goes_on_while_the_update_sink_has_no_room_and_held_writes_follow_in_order() {
    let file = update_file(3000);
    let gate = Gate::default();
    let block = |n: usize| &file[n * 239..((n + 1) * 239).min(file.len())];
    // The operator opens a file and writes its first block; the courier then has no room for 50 ms, during which
    // nine more writes arrive (one more than the receive task holds), and the operator's heartbeat and sticks.
    let mut bursts = vec![
        (0, ftp_frame(GCS, 1, 1, CREATE, 0, b"/update/thruster0.lbvu")),
        (1, ftp_frame(GCS, 2, 1, WRITE, 0, block(0))),
    ];
    for n in 1..=HELD + 1 {
        bursts.push((
            10 + n as u64,
            ftp_frame(GCS, 2 + n as u16, 1, WRITE, (n * 239) as u32, block(n)),
        ));
    }
    bursts.push((25, heartbeat(GCS, 0)));
    bursts.push((26, sticks(1, -400)));
    let (mut commands, mut replies) = (Vec::new(), Vec::new());
    let closed = gate.closed.clone();
    let stats = run_rx(
        Line::new(bursts),
        gate.clone(),
        Duration::from_millis(100),
        |now, shared, _| {
            closed.set((5..55).contains(&now.as_millis()));
            take_commands(shared, &mut commands);
            take_replies(shared, &mut replies);
        },
    );
    // The heartbeat and the sticks were read as they came, at 25 and 26 ms, while the sink had no room.
    let at: Vec<(u64, Command)> = commands
        .iter()
        .map(|(at, request)| (at.as_millis(), request.command))
        .collect();
    assert_eq!(at.len(), 2, "{at:?}");
    assert!(at[0].0 <= 26 && at[0].1 == Command::Heartbeat, "{at:?}");
    assert!(
        at[1].0 <= 27 && matches!(at[1].1, Command::Manual(input, _) if input.x == -400),
        "{at:?}"
    );
    // The writes held were taken in order once the sink had room; the one more was dropped unanswered (a client
    // sends it again).
    let taken: Vec<(u32, usize)> = [(80, 159)]
        .into_iter()
        .chain((1..=HELD).map(|n| ((n * 239) as u32, 239)))
        .collect();
    assert_eq!(
        *gate.writes.borrow(),
        taken,
        "the sink got the header's end and the blocks held, in order"
    );
    let acked: Vec<u16> = replies
        .iter()
        .filter(|(to, opcode, request, _)| {
            *to == Sender {
                system: 255,
                component: 190,
            } && *opcode == 128
                && *request == WRITE
        })
        .map(|(_, _, _, seq)| *seq - 1)
        .collect();
    assert_eq!(acked, (2..=2 + HELD as u16).collect::<Vec<u16>>());
    assert_eq!(stats.snapshot().requests_dropped, 1);
    assert_eq!(HELD, 8);
}

#[test]
fn the_operators_reply_waits_for_room_while_reading_goes_on_and_others_are_dropped() {
    let bursts = vec![
        // The outbox is full (the test fills it at 0 ms); the operator opens a file, system 77 lists twice, and
        // the operator's heartbeat comes.
        (1, ftp_frame(GCS, 1, 1, CREATE, 0, b"/update/thruster0.lbvu")),
        (2, ftp_frame(OTHER, 7, 0, LIST, 0, b"/update")),
        (3, ftp_frame(OTHER, 8, 0, LIST, 1, b"/update")),
        (4, heartbeat(GCS, 0)),
        (5, ftp_frame(GCS, 3, 1, TERMINATE, 0, b"")),
    ];
    let (mut commands, mut replies) = (Vec::new(), Vec::new());
    let stats = run_rx(
        Line::new(bursts),
        Gate::default(),
        Duration::from_millis(30),
        |now, shared, _| {
            if now.as_millis() == 0 {
                while shared
                    .outbox
                    .try_send(Outgoing::Text(Severity::Info, text(format_args!("filler"))))
                    .is_ok()
                {}
            }
            take_commands(shared, &mut commands);
            // Room again at 20 ms.
            if now.as_millis() >= 20 {
                take_replies(shared, &mut replies);
            }
        },
    );
    assert_eq!(commands.len(), 1);
    assert!(
        commands[0].0.as_millis() <= 5,
        "the heartbeat read at once: {:?}",
        commands[0].0
    );
    // The operator's replies, in order, once there was room; system 77's were dropped.
    let operator = Sender {
        system: 255,
        component: 190,
    };
    assert_eq!(replies, [(operator, 128, CREATE, 2), (operator, 128, TERMINATE, 4)]);
    assert_eq!(stats.snapshot().replies_dropped, 2);
}

#[test]
fn requests_that_make_the_vehicle_send_more_than_they_cost_are_limited_per_requester() {
    // For 2 s: system 77 asks for the parameter list every 5 ms, the operator's companion computer for a
    // HEARTBEAT every 5 ms; the operator lists the update directory twelve times, at 100 ms, and asks for the
    // parameter list once, at 1 s; its heartbeats go on at 1 Hz.
    let mut bursts = Vec::new();
    for n in 0..400u64 {
        bursts.push((n * 5, param_list(OTHER, n as u8)));
        bursts.push((n * 5 + 1, request_message(COMPANION, n as u8, 0.0)));
    }
    for n in 0..12u16 {
        bursts.push((100 + u64::from(n) * 10, ftp_frame(GCS, 10 + n, 0, LIST, 0, b"/update")));
    }
    bursts.push((1000, param_list(GCS, 99)));
    bursts.extend((0..3).map(|s| (s * 1000, heartbeat(GCS, s as u8))));
    let mut counted = None;
    let sent = run_console(
        settings(),
        Line::new(bursts),
        Duration::from_millis(2100),
        |now, _, stats| {
            if now.as_millis() == 2000 {
                counted = Some(stats.snapshot());
            }
        },
    );
    let frames = parse_all(&sent);
    let of = |id: &str| {
        frames
            .iter()
            .filter(|(_, m)| {
                use mavlink_core::Message;
                m.message_name() == id
            })
            .count() as u32
    };
    // The allowance of each (80 frames), then ten frames a second: for system 77 a list of 64 PARAM_VALUEs at once
    // (the next when 48 frames more have come back, at 4.8 s), and the operator's list; 40 + 9 HEARTBEATs for the
    // companion, each with its COMMAND_ACK.
    let list = LISTED_COUNT as u32;
    assert!(list < BURST && 2 * list > BURST);
    let values = of("PARAM_VALUE");
    assert_eq!(values, list + list, "PARAM_VALUEs");
    let acks = of("COMMAND_ACK");
    assert!((48..=50).contains(&acks), "{acks} COMMAND_ACKs");
    // Every one of the operator's listings answered.
    let listings = frames
        .iter()
        .filter(|(header, m)| {
            header.system_id == 1
                && matches!(m, MavMessage::FILE_TRANSFER_PROTOCOL(f) if f.target_system == 255 && f.payload[5] == LIST)
        })
        .count();
    assert_eq!(listings, 12);
    let counted = counted.unwrap();
    assert!(counted.rate_limited > 700, "{counted:?}");
}
