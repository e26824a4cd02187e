use super::*;
use crate::config::{VEHICLE, devkit, lbv300_6};
use crate::params::{LISTED_COUNT, Listed, Param, Params};
use crate::shared::{MAV_CMD_LBV_APPLY_UPDATE, MAV_CMD_LBV_QUERY_VERSION};
use crate::sim::{ReceivedImage, UpdateRecorder};
use crate::update::sys::{ImageState, Running};
use ftp::{DATA_LEN, NAK};
use proptest::prelude::*;

fn t(ms: u64) -> Instant {
    Instant::from_millis(ms)
}

/// The operator's ground station (MAVProxy's ids) and another system.
const GCS: Sender = Sender {
    system: 255,
    component: 190,
};
const OTHER: Sender = Sender {
    system: 42,
    component: 1,
};
const DISARMED: Context = Context {
    armed: false,
    operator: 255,
    restarting: false,
    unsigned: false,
    params: None,
    crash: false,
    post_mortems: 0,
    black_box: None,
};
const ARMED: Context = Context {
    armed: true,
    ..DISARMED
};
/// The master's own image is marked for the swap: it restarts into it.
const RESTARTING: Context = Context {
    restarting: true,
    ..DISARMED
};

// Opcodes, as the clients send them.
const TERMINATE: u8 = 1;
const RESET: u8 = 2;
const LIST: u8 = 3;
const OPEN_RO: u8 = 4;
const CREATE: u8 = 6;
const WRITE: u8 = 7;
const REMOVE: u8 = 8;
const OPEN_WO: u8 = 11;
const CRC: u8 = 14;

/// A request payload as pymavlink's `FTP_OP.pack` builds it (then padded with zeros to 251 bytes).
fn payload(seq: u16, session: u8, opcode: u8, offset: u32, data: &[u8]) -> FtpPayload {
    let mut p = [0u8; 251];
    p[..2].copy_from_slice(&seq.to_le_bytes());
    p[2] = session;
    p[3] = opcode;
    p[4] = data.len() as u8;
    p[8..12].copy_from_slice(&offset.to_le_bytes());
    p[12..12 + data.len()].copy_from_slice(data);
    p
}

/// An update file: `LBVU`, format 1, `kind`, reserved 0, `payload_len`, a version and a signature, then
/// `payload_len` bytes.
fn update_file(kind: u8, payload_len: u32) -> Vec<u8> {
    let mut file = b"LBVU".to_vec();
    file.extend([1, kind, 0, 0]);
    file.extend(payload_len.to_le_bytes());
    file.extend([0, 1, 0, 0]);
    file.extend([0x5A; 64]);
    file.extend((0..payload_len).map(|n| (n * 7 + 3) as u8));
    file
}

/// A reply, read back.
#[derive(Debug, PartialEq)]
struct Reply {
    seq: u16,
    session: u8,
    opcode: u8,
    req_opcode: u8,
    burst_complete: bool,
    offset: u32,
    data: Vec<u8>,
}

fn read(reply: &[u8]) -> Reply {
    let size = usize::from(reply[4]);
    Reply {
        seq: u16::from_le_bytes([reply[0], reply[1]]),
        session: reply[2],
        opcode: reply[3],
        req_opcode: reply[5],
        burst_complete: reply[6] == 1,
        offset: u32::from_le_bytes(reply[8..12].try_into().unwrap()),
        data: reply[12..12 + size].to_vec(),
    }
}

/// A server for the vehicle's table (six SeaBotix thrusters), its sink, and what it said.
struct Server<S = UpdateRecorder> {
    server: UpdateServer,
    sink: S,
    said: Vec<Outgoing>,
    seq: u16,
}

impl Server {
    fn new() -> Self {
        Self::with(&VEHICLE.thrusters)
    }

    fn with(table: &ThrusterTable) -> Self {
        Self::with_sink(table, UpdateRecorder::default())
    }

    fn images(&self) -> Vec<ReceivedImage> {
        self.sink.images()
    }
}

impl<S: UpdateSink> Server<S> {
    fn with_sink(table: &ThrusterTable, sink: S) -> Self {
        Self {
            server: UpdateServer::new(table, FrameKind::Lbv300_6),
            sink,
            said: Vec::new(),
            seq: 0,
        }
    }

    /// Send a request; the reply, if any.
    fn send(&mut self, ms: u64, context: Context, from: Sender, payload: &FtpPayload) -> Option<Reply> {
        let mut said = Vec::new();
        let reply = self
            .server
            .request(t(ms), context, from, payload, &mut self.sink, &mut |o| said.push(o));
        self.said.extend(said);
        // A read is framed with the parameters the request came with.
        reply.map(|r| {
            read(&r.payload(&Contents {
                params: context.params.as_ref(),
                crash: None,
                black_box: None,
            }))
        })
    }

    /// Send a request from the operator, disarmed, with the next sequence number.
    fn op(&mut self, ms: u64, session: u8, opcode: u8, offset: u32, data: &[u8]) -> Option<Reply> {
        self.seq = self.seq.wrapping_add(1);
        let p = payload(self.seq, session, opcode, offset, data);
        self.send(ms, DISARMED, GCS, &p)
    }

    fn apply(&mut self, context: Context, from: Sender, slot: Option<u8>) -> Vec<Outgoing> {
        let mut said = Vec::new();
        self.server
            .apply(context, from, slot, &mut self.sink, &mut |o| said.push(o));
        said
    }

    /// Upload `file` to `path` in session `session` in writes of `block` bytes, in order; the last reply.
    fn put(&mut self, ms: u64, session: u8, path: &str, file: &[u8], block: usize) -> Option<Reply> {
        let created = self.op(ms, session, CREATE, 0, path.as_bytes());
        if created.as_ref().is_none_or(|r| r.opcode != ACK) {
            return created;
        }
        let mut last = created;
        for (n, chunk) in file.chunks(block).enumerate() {
            last = self.op(ms, session, WRITE, (n * block) as u32, chunk);
            if last.as_ref().is_none_or(|r| r.opcode != ACK) {
                break;
            }
        }
        last
    }

    fn texts(&self) -> Vec<String> {
        self.said
            .iter()
            .filter_map(|o| match o {
                Outgoing::Text(_, text) => Some(text.to_string()),
                _ => None,
            })
            .collect()
    }
}

fn ack(reply: &Option<Reply>) -> bool {
    reply.as_ref().is_some_and(|r| r.opcode == ACK)
}

fn nak(reply: &Option<Reply>) -> Option<u8> {
    reply
        .as_ref()
        .filter(|r| r.opcode == NAK)
        .and_then(|r| r.data.first().copied())
}

const THRUSTER0: &str = "/update/thruster0.lbvu";

#[test]
fn crc32_is_ardupilots() {
    // zlib.crc32(b"123456789", 0xFFFFFFFF) ^ 0xFFFFFFFF, what MAVProxy's `ftp crclocal` computes.
    assert_eq!(ftp::crc32(0, b"123456789"), 0x2DFD_2D88);
    assert_eq!(ftp::crc32(ftp::crc32(0, b"1234"), b"56789"), 0x2DFD_2D88);
    assert_eq!(ftp::crc32(0, b""), 0);
}

#[test]
fn headers_are_read_as_update_image_lays_them_out() {
    let file = update_file(2, 4096);
    let header = parse_header(file[..80].try_into().unwrap()).unwrap();
    assert_eq!((header.target, header.payload_len, header.file_len()), (2, 4096, 4176));
    assert_eq!(header.bytes[..], file[..80]);
    let with = |n: usize, byte: u8| {
        let mut bytes: [u8; 80] = file[..80].try_into().unwrap();
        bytes[n] = byte;
        parse_header(&bytes)
    };
    assert_eq!(with(0, b'X'), Err(HeaderError::Magic(*b"XBVU")));
    assert_eq!(with(4, 2), Err(HeaderError::Format(2)));
    assert_eq!(with(5, 0), Err(HeaderError::Target(0)));
    assert_eq!(with(5, 4), Err(HeaderError::Target(4)));
    assert_eq!(with(7, 1), Err(HeaderError::Reserved(0x100)));
}

#[test]
fn the_listing_shows_the_directory_and_one_file_per_target() {
    let mut s = Server::new();
    // The directories in one reply, `@SYS` and `@PARAM` after `update` (ArduPilot lists its own after the real
    // ones).
    let root = s.op(0, 0, LIST, 0, b"/").unwrap();
    assert_eq!(
        (root.opcode, root.req_opcode, root.data.as_slice()),
        (ACK, LIST, &b"Dupdate\0D@SYS\0D@PARAM\0"[..])
    );
    assert_eq!(s.op(0, 0, LIST, 1, b"/").unwrap().data, b"D@SYS\0D@PARAM\0");
    assert_eq!(nak(&s.op(0, 0, LIST, 3, b"/")), Some(Nak::EndOfFile as u8));
    // One entry per reply, each at its offset, then the end.
    let mut names = Vec::new();
    for offset in 0.. {
        let reply = s.op(0, 0, LIST, offset, b"/update").unwrap();
        if reply.opcode == NAK {
            assert_eq!(reply.data, [Nak::EndOfFile as u8]);
            break;
        }
        assert_eq!(reply.offset, offset, "the offset is echoed");
        names.push(String::from_utf8(reply.data).unwrap());
    }
    // The table has SeaBotix thrusters only: one family file.
    let expected: Vec<String> = (0..6)
        .map(|n| format!("Fthruster{n}.lbvu\t0\0"))
        .chain([
            "Fthrusters-seabotix.lbvu\t0\0".to_owned(),
            "Fmaster.lbvu\t0\0".to_owned(),
        ])
        .collect();
    assert_eq!(names, expected);
    // The same directory, written as clients may write it.
    for path in [&b"update"[..], b"/update/", b"update/", b"/update\0"] {
        assert!(ack(&s.op(0, 0, LIST, 0, path)), "{path:?}");
    }
    for path in [&b"/updates"[..], b"/foo", b"/update/x"] {
        assert_eq!(
            nak(&s.op(0, 0, LIST, 0, path)),
            Some(Nak::FileNotFound as u8),
            "{path:?}"
        );
    }
    // A file is not a directory.
    assert_eq!(
        nak(&s.op(0, 0, LIST, 0, THRUSTER0.as_bytes())),
        Some(Nak::FileNotFound as u8)
    );
    // The dev kit's table has one thruster.
    let mut kit = Server::with(&devkit(Family::Legacy));
    assert_eq!(kit.op(0, 0, LIST, 0, b"/update").unwrap().data, b"Fthruster0.lbvu\t0\0");
    assert_eq!(
        kit.op(0, 0, LIST, 1, b"/update").unwrap().data,
        b"Fthrusters-legacy.lbvu\t0\0"
    );
    assert_eq!(kit.op(0, 0, LIST, 2, b"/update").unwrap().data, b"Fmaster.lbvu\t0\0");
    assert_eq!(nak(&kit.op(0, 0, LIST, 3, b"/update")), Some(Nak::EndOfFile as u8));
}

#[test]
fn a_put_goes_to_the_sink_byte_for_byte_in_order() {
    let mut s = Server::new();
    let file = update_file(1, 4096);
    // MAVProxy writes 239 bytes at a time, pymavlink 80.
    for (block, session) in [(239, 7), (80, 8)] {
        let created = s.op(0, session, CREATE, 0, THRUSTER0.as_bytes()).unwrap();
        assert_eq!(
            created,
            Reply {
                seq: s.seq.wrapping_add(1),
                session,
                opcode: ACK,
                req_opcode: CREATE,
                burst_complete: false,
                offset: 0,
                data: vec![]
            },
            "a reply carries the request's sequence + 1 and its session"
        );
        for (n, chunk) in file.chunks(block).enumerate() {
            let offset = (n * block) as u32;
            let reply = s.op(10, session, WRITE, offset, chunk).unwrap();
            assert_eq!((reply.opcode, reply.req_opcode, reply.offset), (ACK, WRITE, offset));
            assert!(reply.data.is_empty());
        }
        assert!(s.server.is_received(UpdateTarget::Thruster(0)));
        assert_eq!(
            s.server.received(UpdateTarget::Thruster(0)),
            (4176, ftp::crc32(0, &file))
        );
        assert!(ack(&s.op(20, session, TERMINATE, 0, &[])));
        let images = s.images();
        let last = images.last().unwrap();
        assert_eq!(
            (last.target, last.complete, &last.bytes),
            (UpdateTarget::Thruster(0), Some(true), &file)
        );
    }
    assert_eq!(s.images().len(), 2);
    assert!(
        s.texts()
            .iter()
            .all(|t| t == "thruster0.lbvu: received, ready to apply"),
        "{:?}",
        s.texts()
    );
    // The listing and the CRC show it.
    assert_eq!(
        s.op(30, 0, LIST, 0, b"/update").unwrap().data,
        b"Fthruster0.lbvu\t4176\0"
    );
    let crc = s.op(30, 0, CRC, 0, THRUSTER0.as_bytes()).unwrap();
    assert_eq!(
        (crc.opcode, crc.data),
        (ACK, ftp::crc32(0, &file).to_le_bytes().to_vec())
    );
    assert_eq!(s.op(30, 0, CRC, 0, b"/update/master.lbvu").unwrap().data, [0; 4]);
}

#[test]
fn progress_is_told_at_most_once_a_second() {
    let mut s = Server::new();
    let file = update_file(1, 8000);
    assert!(ack(&s.op(0, 1, CREATE, 0, THRUSTER0.as_bytes())));
    for (n, chunk) in file.chunks(239).enumerate() {
        // A write every 100 ms.
        assert!(ack(&s.op(100 * n as u64, 1, WRITE, (n * 239) as u32, chunk)));
    }
    let texts = s.texts();
    assert_eq!(
        texts.first().map(String::as_str),
        Some("thruster0.lbvu: 2629 of 8080 bytes")
    );
    assert_eq!(texts.len(), 4, "{texts:?}");
    assert_eq!(
        texts.last().map(String::as_str),
        Some("thruster0.lbvu: received, ready to apply")
    );
}

#[test]
fn a_write_sent_again_is_acked_again_and_a_gap_is_left_unanswered() {
    let mut s = Server::new();
    let file = update_file(1, 1000);
    assert!(ack(&s.op(0, 3, CREATE, 0, THRUSTER0.as_bytes())));
    assert!(ack(&s.op(0, 3, WRITE, 0, &file[..239])));
    // Its ACK was lost: the same block again, with the same or a new sequence number.
    let seq = s.seq;
    let again = s
        .send(0, DISARMED, GCS, &payload(seq, 3, WRITE, 0, &file[..239]))
        .unwrap();
    assert_eq!((again.opcode, again.seq, again.offset), (ACK, seq.wrapping_add(1), 0));
    assert!(ack(&s.op(0, 3, WRITE, 0, &file[..239])));
    // A write beyond the next byte (the one before it was lost): no answer, nothing taken.
    assert_eq!(s.op(0, 3, WRITE, 478, &file[478..717]), None);
    assert_eq!(s.server.received(UpdateTarget::Thruster(0)).0, 239);
    // The lost block comes round again, and then the one after it.
    assert!(ack(&s.op(0, 3, WRITE, 239, &file[239..478])));
    assert!(ack(&s.op(0, 3, WRITE, 478, &file[478..717])));
    // A block that overlaps what was taken (another block size): only its new bytes are taken.
    assert!(ack(&s.op(0, 3, WRITE, 700, &file[700..939])));
    assert!(ack(&s.op(0, 3, WRITE, 939, &file[939..])));
    assert_eq!(s.images()[0].bytes, file);
    // The last block again after the image is whole: ACKed, nothing changes.
    assert!(ack(&s.op(0, 3, WRITE, 939, &file[939..])));
    let counters = s.server.counters();
    assert_eq!((counters.duplicates, counters.gaps, counters.naks), (3, 1, 0));
    assert_eq!(s.images().len(), 1);
    assert_eq!(s.images()[0].complete, Some(true));
}

#[test]
fn bad_headers_and_targets_that_do_not_fit_are_refused_before_the_sink_sees_them() {
    let file = update_file(1, 1024);
    let mut magic = file.clone();
    magic[0] = b'X';
    let mut format = file.clone();
    format[4] = 9;
    let legacy = update_file(2, 1024);
    let master = update_file(3, 1024);
    let cases: [(&str, &[u8], &str); 8] = [
        (THRUSTER0, &magic, "thruster0.lbvu: not an update file"),
        (THRUSTER0, &format, "thruster0.lbvu: bad update file header"),
        (THRUSTER0, &legacy, "thruster0.lbvu: Legacy image, slot is SeaBotix"),
        (THRUSTER0, &master, "thruster0.lbvu: master image, slot is SeaBotix"),
        (
            "/update/master.lbvu",
            &file,
            "master.lbvu: SeaBotix image, slot is master",
        ),
        (
            THRUSTER0,
            &update_file(1, 0),
            "thruster0.lbvu: payload length not valid",
        ),
        (
            THRUSTER0,
            &update_file(1, 1001),
            "thruster0.lbvu: payload length not valid",
        ),
        (
            THRUSTER0,
            &update_file(1, THRUSTER_MAX_PAYLOAD + 8)[..239],
            "thruster0.lbvu: payload length not valid",
        ),
    ];
    for (path, bytes, text) in cases {
        let mut s = Server::new();
        let reply = s.put(0, 1, path, bytes, 239);
        assert_eq!(nak(&reply), Some(Nak::Fail as u8), "{text}");
        assert_eq!(s.texts(), [text]);
        assert!(s.images().is_empty(), "{text}: the sink never began");
        // The upload is over: the session is closed and nothing is held.
        assert_eq!(nak(&s.op(0, 1, WRITE, 239, &[1; 10])), Some(Nak::InvalidSession as u8));
        assert_eq!(s.server.received(UpdateTarget::Thruster(0)), (0, 0));
    }
    // The dev kit's Legacy slot takes a Legacy image; the master slot a master image.
    let mut kit = Server::with(&devkit(Family::Legacy));
    assert!(ack(&kit.put(0, 1, THRUSTER0, &legacy, 239)));
    assert!(ack(&kit.put(0, 2, "/update/master.lbvu", &master, 239)));
    // A table of mixed families: each slot its own.
    let mut mixed = Server::with(&lbv300_6(
        [Family::SeaBotix, Family::Legacy].repeat(3).try_into().unwrap(),
    ));
    assert!(ack(&mixed.put(0, 1, "/update/thruster1.lbvu", &legacy, 239)));
    assert_eq!(
        nak(&mixed.put(0, 2, "/update/thruster2.lbvu", &legacy, 239)),
        Some(Nak::Fail as u8)
    );
}

#[test]
fn the_header_must_come_in_the_first_write() {
    let mut s = Server::new();
    let file = update_file(1, 1024);
    assert_eq!(nak(&s.put(0, 1, THRUSTER0, &file, 64)), Some(Nak::Fail as u8));
    assert_eq!(s.texts(), ["thruster0.lbvu: header not in the first write"]);
    // A first write of the header alone is enough (pymavlink writes 80 bytes at a time).
    assert!(ack(&s.put(0, 2, THRUSTER0, &file, 80)));
}

#[test]
fn a_file_longer_than_its_header_says_is_refused() {
    // The last block goes past the end.
    let mut s = Server::new();
    let mut file = update_file(1, 1000);
    file.extend([0xEE; 100]);
    assert_eq!(nak(&s.put(0, 1, THRUSTER0, &file, 239)), Some(Nak::Fail as u8));
    assert_eq!(s.texts(), ["thruster0.lbvu: longer than its header says"]);
    assert_eq!(s.images()[0].complete, Some(false), "the sink dropped it");
    assert!(!s.server.is_received(UpdateTarget::Thruster(0)));
    // Or a block comes after the image is whole.
    let mut s = Server::new();
    // 1912 bytes: eight whole blocks of 239.
    let mut file = update_file(1, 1832);
    assert_eq!(file.len(), 239 * 8);
    file.extend([0xEE; 50]);
    assert_eq!(nak(&s.put(0, 1, THRUSTER0, &file, 239)), Some(Nak::Fail as u8));
    assert!(
        s.texts()
            .contains(&"thruster0.lbvu: longer than its header says".to_owned())
    );
    // The write is refused, the image received whole is kept as it was received.
    assert!(s.server.is_received(UpdateTarget::Thruster(0)));
    assert_eq!(
        s.server.received(UpdateTarget::Thruster(0)),
        (1912, ftp::crc32(0, &file[..1912]))
    );
    assert_eq!(s.images()[0].complete, Some(true));
}

#[test]
fn one_write_past_the_end_of_an_image_whole_is_refused_and_the_image_kept() {
    let file = update_file(1, 1000);
    // Right after the last byte (the client's file is longer), or further on (a block of another file).
    for (offset, data) in [(1080, &[0xEE; 20][..]), (1300, &[0xEE; 20]), (1000, &[0xEE; 239])] {
        let mut s = Server::new();
        assert!(ack(&s.put(0, 1, THRUSTER0, &file, 239)));
        let whole = s.server.received(UpdateTarget::Thruster(0));
        assert_eq!(whole, (1080, ftp::crc32(0, &file)));
        s.said.clear();
        assert_eq!(nak(&s.op(0, 1, WRITE, offset, data)), Some(Nak::Fail as u8), "{offset}");
        assert_eq!(s.texts(), ["thruster0.lbvu: longer than its header says"], "{offset}");
        assert!(s.server.is_received(UpdateTarget::Thruster(0)), "{offset}: kept");
        assert_eq!(s.server.received(UpdateTarget::Thruster(0)), whole, "{offset}");
        assert_eq!(
            (s.images().len(), s.images()[0].complete, &s.images()[0].bytes),
            (1, Some(true), &file),
            "{offset}: the sink kept what it got"
        );
        // The session is over; the image can be applied.
        assert_eq!(nak(&s.op(0, 1, WRITE, 1080, &[1])), Some(Nak::InvalidSession as u8));
        assert_eq!(acked(&s.apply(DISARMED, GCS, Some(0))), Some(AckResult::Accepted));
    }
}

#[test]
fn a_block_sent_again_with_other_bytes_is_refused() {
    let file = update_file(1, 2000);
    let mut changed = file.clone();
    changed[300] ^= 0x01;
    // Under way: the write is refused and the upload stops (the sink drops it).
    let mut s = Server::new();
    assert!(ack(&s.op(0, 1, CREATE, 0, THRUSTER0.as_bytes())));
    for n in 0..3 {
        assert!(ack(&s.op(
            0,
            1,
            WRITE,
            n * 239,
            &file[n as usize * 239..(n as usize + 1) * 239]
        )));
    }
    // The same block again: a duplicate, ACKed.
    assert!(ack(&s.op(0, 1, WRITE, 239, &file[239..478])));
    // Its ACK lost, sent again with a byte changed: refused; so is the last block changed.
    assert_eq!(nak(&s.op(0, 1, WRITE, 239, &changed[239..478])), Some(Nak::Fail as u8));
    assert_eq!(s.texts(), ["thruster0.lbvu: bytes sent again differ"]);
    assert_eq!(s.images()[0].complete, Some(false), "dropped");
    assert_eq!(s.server.received(UpdateTarget::Thruster(0)), (0, 0));
    assert_eq!(s.server.counters().duplicates, 1);
    // Sent again reaching past what was taken: its old bytes are checked, its new ones taken.
    let mut s = Server::new();
    assert!(ack(&s.op(0, 2, CREATE, 0, THRUSTER0.as_bytes())));
    assert!(ack(&s.op(0, 2, WRITE, 0, &file[..239])));
    assert!(ack(&s.op(0, 2, WRITE, 239, &file[239..400])));
    assert_eq!(nak(&s.op(0, 2, WRITE, 239, &changed[239..478])), Some(Nak::Fail as u8));
    let mut s = Server::new();
    assert!(ack(&s.op(0, 2, CREATE, 0, THRUSTER0.as_bytes())));
    assert!(ack(&s.op(0, 2, WRITE, 0, &file[..239])));
    assert!(ack(&s.op(0, 2, WRITE, 239, &file[239..400])));
    assert!(ack(&s.op(0, 2, WRITE, 239, &file[239..478])));
    assert_eq!(
        s.server.received(UpdateTarget::Thruster(0)),
        (478, ftp::crc32(0, &file[..478]))
    );
    // Whole: the write is refused and the image kept.
    let mut s = Server::new();
    let mut last = file.clone();
    *last.last_mut().unwrap() ^= 0x80;
    assert!(ack(&s.put(0, 3, THRUSTER0, &file, 239)));
    let end = (file.len() / 239 * 239) as u32;
    assert_eq!(
        nak(&s.op(0, 3, WRITE, end, &last[end as usize..])),
        Some(Nak::Fail as u8)
    );
    assert!(s.server.is_received(UpdateTarget::Thruster(0)));
    assert_eq!(s.server.received(UpdateTarget::Thruster(0)).1, ftp::crc32(0, &file));
    assert_eq!(s.texts().last().unwrap(), "thruster0.lbvu: bytes sent again differ");
}

#[test]
fn a_block_sent_again_from_where_no_mark_is_kept_cannot_be_checked_and_is_taken_as_before() {
    let file = update_file(1, 8000);
    let mut changed = file.clone();
    changed[100] ^= 0x01;
    let mut s = Server::new();
    assert!(ack(&s.op(0, 1, CREATE, 0, THRUSTER0.as_bytes())));
    // Another block size: from 100, no write ended there.
    assert!(ack(&s.op(0, 1, WRITE, 0, &file[..239])));
    assert!(ack(&s.op(0, 1, WRITE, 100, &changed[100..300])));
    // Older than the last MARKS writes: the first block, after 16 more.
    for n in 0..MARKS {
        let from = 300 + n * 200;
        assert!(ack(&s.op(0, 1, WRITE, from as u32, &file[from..from + 200])), "{n}");
    }
    assert!(ack(&s.op(0, 1, WRITE, 0, &changed[..239])));
    // The bytes taken are the first ones sent: what the sink has, and the CRC the listing gives.
    let received = s.server.received(UpdateTarget::Thruster(0));
    let n = received.0 as usize;
    assert_eq!(received.1, ftp::crc32(0, &file[..n]));
    assert_eq!(s.images()[0].bytes, file[..n]);
    // A block from a mark kept is still checked.
    let start = n - 200;
    let mut late = file[start..n].to_vec();
    late[3] ^= 0x10;
    assert_eq!(nak(&s.op(0, 1, WRITE, start as u32, &late)), Some(Nak::Fail as u8));
}

#[test]
fn one_session_at_a_time() {
    let mut s = Server::new();
    let file = update_file(1, 2000);
    assert!(ack(&s.op(0, 1, CREATE, 0, THRUSTER0.as_bytes())));
    assert!(ack(&s.op(0, 1, WRITE, 0, &file[..239])));
    // Another session, another client: busy while the first is active.
    assert_eq!(
        nak(&s.op(1000, 2, CREATE, 0, b"/update/thruster1.lbvu")),
        Some(Nak::NoSessionsAvailable as u8)
    );
    let other = payload(1, 9, CREATE, 0, b"/update/thruster1.lbvu");
    let mut operator_elsewhere = GCS;
    operator_elsewhere.component = 1;
    assert_eq!(
        nak(&s.send(1000, DISARMED, operator_elsewhere, &other)),
        Some(Nak::NoSessionsAvailable as u8)
    );
    // The same session opening again: one file per session.
    assert_eq!(
        nak(&s.op(1000, 1, CREATE, 0, THRUSTER0.as_bytes())),
        Some(Nak::Fail as u8)
    );
    // Writes in another session than the one open.
    assert_eq!(
        nak(&s.op(1000, 2, WRITE, 239, &file[239..478])),
        Some(Nak::InvalidSession as u8)
    );
    // Listing, CRC need no session.
    assert!(ack(&s.op(1000, 5, LIST, 0, b"/update")));
    assert!(ack(&s.op(1000, 5, CRC, 0, THRUSTER0.as_bytes())));
    // Idle for 3 s: a new open takes over, and the upload in the old one stops.
    assert!(ack(&s.op(3000, 2, CREATE, 0, b"/update/thruster1.lbvu")));
    assert_eq!(s.texts(), ["thruster0.lbvu: stopped at 239 of 2080 bytes"]);
    assert_eq!(s.images()[0].complete, Some(false));
    assert_eq!(s.server.received(UpdateTarget::Thruster(0)), (0, 0));
    assert_eq!(
        nak(&s.op(3000, 1, WRITE, 239, &file[239..478])),
        Some(Nak::InvalidSession as u8)
    );
}

#[test]
fn terminate_and_reset_close_the_session() {
    let mut s = Server::new();
    let file = update_file(1, 2000);
    // Terminating a session when none is open: nothing to do, ACKed (as ArduPilot does).
    assert!(ack(&s.op(0, 4, TERMINATE, 0, &[])));
    assert!(ack(&s.op(0, 1, CREATE, 0, THRUSTER0.as_bytes())));
    assert!(ack(&s.op(0, 1, WRITE, 0, &file[..239])));
    // A session that is not the sender's: another session of its own, or another client's (another system, another
    // component of the operator's system) is refused, and left open.
    let mut operator_elsewhere = GCS;
    operator_elsewhere.component = 1;
    for (from, opcode, session) in [
        (GCS, TERMINATE, 4),
        (OTHER, TERMINATE, 1),
        (OTHER, RESET, 0),
        (OTHER, RESET, 1),
        (operator_elsewhere, TERMINATE, 1),
        (operator_elsewhere, RESET, 1),
    ] {
        let reply = s.send(0, DISARMED, from, &payload(1, session, opcode, 0, &[]));
        assert_eq!(
            nak(&reply),
            Some(Nak::InvalidSession as u8),
            "{from:?} {opcode} {session}"
        );
    }
    assert!(s.texts().is_empty());
    assert!(ack(&s.op(0, 1, WRITE, 239, &file[239..478])));
    // Its own terminate stops the upload: the sink drops it.
    assert!(ack(&s.op(0, 1, TERMINATE, 0, &[])));
    assert_eq!(s.texts(), ["thruster0.lbvu: stopped at 478 of 2080 bytes"]);
    assert_eq!(s.images()[0].complete, Some(false));
    // Reset closes every session of its sender.
    assert!(ack(&s.op(0, 2, CREATE, 0, THRUSTER0.as_bytes())));
    assert!(ack(&s.op(0, 9, RESET, 0, &[])));
    assert_eq!(
        nak(&s.op(0, 2, WRITE, 0, &file[..239])),
        Some(Nak::InvalidSession as u8)
    );
    // Before the header came, the sink had not begun: nothing to drop.
    assert_eq!(s.images().len(), 1);
}

#[test]
fn only_the_operator_writes_and_nothing_changes_while_armed() {
    let mut s = Server::new();
    let file = update_file(1, 1000);
    let create = payload(1, 1, CREATE, 0, THRUSTER0.as_bytes());
    assert_eq!(
        nak(&s.send(0, DISARMED, OTHER, &create)),
        Some(Nak::FileProtected as u8)
    );
    assert_eq!(
        nak(&s.send(0, DISARMED, OTHER, &payload(2, 0, REMOVE, 0, THRUSTER0.as_bytes()))),
        Some(Nak::FileProtected as u8)
    );
    // Anyone may read.
    assert!(ack(&s.send(0, DISARMED, OTHER, &payload(3, 0, LIST, 0, b"/update"))));
    assert!(ack(&s.send(
        0,
        DISARMED,
        OTHER,
        &payload(4, 0, CRC, 0, THRUSTER0.as_bytes())
    )));
    assert_eq!(s.server.counters().refused, 2);
    // Armed: no upload starts, nothing is removed.
    assert_eq!(nak(&s.send(0, ARMED, GCS, &create)), Some(Nak::Fail as u8));
    assert_eq!(
        nak(&s.send(0, ARMED, GCS, &payload(5, 0, REMOVE, 0, THRUSTER0.as_bytes()))),
        Some(Nak::Fail as u8)
    );
    assert_eq!(
        s.texts(),
        ["thruster0.lbvu: disarm to update", "thruster0.lbvu: disarm to update"]
    );
    // Arming during an upload stops it at its next request.
    s.said.clear();
    assert!(ack(&s.op(0, 1, CREATE, 0, THRUSTER0.as_bytes())));
    assert!(ack(&s.op(0, 1, WRITE, 0, &file[..239])));
    let write = payload(9, 1, WRITE, 239, &file[239..478]);
    assert_eq!(nak(&s.send(0, ARMED, GCS, &write)), Some(Nak::InvalidSession as u8));
    assert_eq!(s.texts(), ["thruster0.lbvu: stopped, armed"]);
    assert_eq!(s.images()[0].complete, Some(false));
    // Nothing was ever held: nothing to apply.
    assert!(!s.server.is_received(UpdateTarget::Thruster(0)));
}

#[test]
fn nothing_changes_once_the_master_is_marked_to_restart_into_its_update() {
    const MASTER: &str = "/update/master.lbvu";
    let mut s = Server::new();
    let file = update_file(1, 1000);
    // An image held for thruster 0, and an upload under way to thruster 1 when the master's own image is marked.
    assert!(ack(&s.put(0, 1, THRUSTER0, &file, 239)));
    assert!(ack(&s.op(0, 1, TERMINATE, 0, &[])));
    assert!(ack(&s.op(0, 2, CREATE, 0, b"/update/thruster1.lbvu")));
    assert!(ack(&s.op(0, 2, WRITE, 0, &file[..239])));
    let before = s.images();
    s.said.clear();
    // Its next write is refused, and the upload stops.
    let write = payload(40, 2, WRITE, 239, &file[239..478]);
    assert_eq!(nak(&s.send(0, RESTARTING, GCS, &write)), Some(Nak::Fail as u8));
    assert_eq!(s.texts(), ["thruster1.lbvu: master restarting into its update"]);
    assert_eq!(s.images().last().unwrap().complete, Some(false), "dropped, not taken");
    // No upload begins, for any target, and nothing is removed.
    s.said.clear();
    for (n, path) in [THRUSTER0, "/update/thruster1.lbvu", MASTER].into_iter().enumerate() {
        for opcode in [CREATE, OPEN_WO, REMOVE] {
            let request = payload(50 + n as u16, 3, opcode, 0, path.as_bytes());
            assert_eq!(
                nak(&s.send(0, RESTARTING, GCS, &request)),
                Some(Nak::Fail as u8),
                "{path} {opcode}"
            );
        }
    }
    assert_eq!(s.texts().len(), 9);
    assert!(
        s.texts()
            .iter()
            .all(|text| text.ends_with(".lbvu: master restarting into its update")),
        "{:?}",
        s.texts()
    );
    assert!(s.server.is_received(UpdateTarget::Thruster(0)), "the image held stays");
    // The image held is not applied.
    let said = s.apply(RESTARTING, GCS, Some(0));
    assert_eq!(
        (acked(&said), text_of(&said)),
        (
            Some(AckResult::TemporarilyRejected),
            vec!["thruster0.lbvu: master restarting into its update".into()]
        )
    );
    let images = s.images();
    assert_eq!(images.len(), before.len(), "the sink began nothing");
    assert_eq!(images[0].applied, 0, "nor applied anything");
    assert_eq!(
        images.last().unwrap().bytes,
        before.last().unwrap().bytes,
        "nor took any byte"
    );
    // Anyone may still read.
    assert!(ack(&s.send(0, RESTARTING, OTHER, &payload(60, 0, LIST, 0, b"/update"))));
}

#[test]
fn the_context_says_when_the_master_restarts_into_its_update() {
    let shared = Shared::new();
    assert!(!Context::of(&shared).restarting);
    shared.restarting.store(true, Ordering::Relaxed);
    assert!(Context::of(&shared).restarting);
}

/// A ground station that asks for a file the vehicle does not have falls back at once on FileNotFound, and waits
/// out its retries on any other answer: a file that is not here is FileNotFound, an update slot cannot be read.
#[test]
fn a_file_opened_for_reading_is_not_found_or_protected() {
    let mut s = Server::new();
    for path in [
        &b"@PARAM/params.pck"[..],
        b"@PARAM/param.pckx",
        b"@PARAM/param.pck/",
        b"@PARAMS/param.pck",
        b"@PARAM",
        b"/APM/LOGS/00000001.BIN",
        b"/update/nothing",
        b"",
        b"/update",
    ] {
        let reply = s.op(0, 0, OPEN_RO, 0, path).unwrap();
        assert_eq!(
            (reply.opcode, reply.req_opcode, reply.data),
            (NAK, OPEN_RO, vec![Nak::FileNotFound as u8]),
            "{path:?}"
        );
    }
    for path in [&b"/update/master.lbvu"[..], b"/update/thruster1.lbvu"] {
        let reply = s.op(0, 0, OPEN_RO, 0, path).unwrap();
        assert_eq!(
            (reply.opcode, reply.data),
            (NAK, vec![Nak::FileProtected as u8]),
            "{path:?}"
        );
    }
}

/// A sink that knows the boards' images as it is told (the master's, then each slot's thruster's), and takes every
/// image.
#[derive(Default)]
struct Fleet([Running; 1 + MAX_THRUSTERS]);

impl UpdateSink for Fleet {
    fn begin(&mut self, _: UpdateTarget, _: &ImageHeader) -> Result<(), Refused> {
        Ok(())
    }

    fn write(&mut self, _: u32, _: &[u8]) -> Result<(), Refused> {
        Ok(())
    }

    fn finish(&mut self, _: bool) -> Result<(), Refused> {
        Ok(())
    }

    fn apply(&mut self, _: UpdateTarget, _: Sender) -> Result<Applied, Nak> {
        Ok(Applied::NotWired)
    }

    fn boards(&self, versions: &mut Versions) {
        for (board, running) in self.0.into_iter().enumerate() {
            versions.set(board, running);
        }
    }
}

/// `versions.txt` of a table whose slots have `families`, its boards running `boards` (the master's first).
fn versions_of(families: &[Option<Family>; MAX_THRUSTERS], boards: [Running; 1 + MAX_THRUSTERS]) -> Versions {
    let mut versions = Versions::new(families);
    Fleet(boards).boards(&mut versions);
    versions
}

const VERSIONS: &[u8] = b"@SYS/versions.txt";
const READ: u8 = 5;
const BURST: u8 = 15;

/// `version` as the image info holds it.
fn v(major: u8, minor: u8, patch: u16) -> Option<[u8; 4]> {
    Some(update_image::Version::new(major, minor, patch).to_bytes())
}

/// The mixed vehicle (SeaBotix and Legacy in turn) after its SeaBotix thrusters took 0.3.0: T3 still on trial, T4
/// offline, T6 not asked yet since it came back.
fn mixed_fleet() -> Server<Fleet> {
    let running = |version, state| Running { version, state };
    let mut boards = [Running::default(); 1 + MAX_THRUSTERS];
    boards[..7].copy_from_slice(&[
        running(v(0, 1, 0), ImageState::Confirmed),
        running(v(0, 3, 0), ImageState::Confirmed),
        running(v(0, 1, 0), ImageState::Confirmed),
        running(v(0, 3, 0), ImageState::OnTrial),
        running(v(0, 1, 0), ImageState::Offline),
        running(v(0, 3, 0), ImageState::Marked),
        running(None, ImageState::Unasked),
    ]);
    let table = lbv300_6([Family::SeaBotix, Family::Legacy].repeat(3).try_into().unwrap());
    Server::with_sink(&table, Fleet(boards))
}

const MIXED_FLEET: &str = "\
board  family   version  state
master -        0.1.0    confirmed
T1     SeaBotix 0.3.0    confirmed
T2     Legacy   0.1.0    confirmed
T3     SeaBotix 0.3.0    on-trial
T4     Legacy   0.1.0    offline
T5     SeaBotix 0.3.0    marked
T6     Legacy   -        unasked
";

impl<S: UpdateSink> Server<S> {
    /// OpenFileRO of `@SYS/versions.txt` in `session`, then reads of `size` bytes with `opcode` from where the
    /// last ended, until EndOfFile (or a reply shorter than asked, after a burst: MAVProxy's end), then
    /// TerminateSession: the length the open gave, and the bytes read.
    fn get(&mut self, ms: u64, session: u8, opcode: u8, size: u8) -> (u32, Vec<u8>) {
        self.get_file(ms, DISARMED, session, VERSIONS, opcode, size)
    }

    /// [`Server::get`] of the file at `path`, with `context`, from another system than the operator's.
    fn get_file(
        &mut self,
        ms: u64,
        context: Context,
        session: u8,
        path: &[u8],
        opcode: u8,
        size: u8,
    ) -> (u32, Vec<u8>) {
        let mut seq = 0;
        let mut send = |s: &mut Self, opcode, offset, data: &[u8]| {
            seq += 1;
            s.send(ms, context, OTHER, &payload(seq, session, opcode, offset, data))
        };
        let open = send(self, OPEN_RO, 0, path).unwrap();
        assert_eq!((open.opcode, open.data.len()), (ACK, 4), "{open:?}");
        let len = u32::from_le_bytes(open.data.try_into().unwrap());
        let mut text = Vec::new();
        loop {
            let reply = send(self, opcode, text.len() as u32, &vec![0; usize::from(size)]).unwrap();
            if reply.opcode == NAK {
                assert_eq!(reply.data, [Nak::EndOfFile as u8]);
                break;
            }
            assert_eq!((reply.req_opcode, reply.offset), (opcode, text.len() as u32));
            assert_eq!(reply.burst_complete, opcode == BURST, "a burst is one reply");
            assert!(!reply.data.is_empty() && reply.data.len() <= usize::from(size));
            let short = reply.data.len() < usize::from(size);
            text.extend(reply.data);
            if short && opcode == BURST {
                break;
            }
        }
        assert!(ack(&send(self, TERMINATE, 0, &[])));
        (len, text)
    }
}

#[test]
fn versions_txt_says_what_every_board_runs_in_columns() {
    let mut s = mixed_fleet();
    let (len, text) = s.get(0, 1, READ, 239);
    assert_eq!(String::from_utf8(text).unwrap(), MIXED_FLEET);
    assert_eq!(len as usize, MIXED_FLEET.len());
    // What a sink that reaches no board knows: nothing.
    let mut s = Server::new();
    let (_, text) = s.get(0, 1, READ, 239);
    let unknown: String = (1..=6)
        .map(|n| format!("T{n}     SeaBotix -        unknown\n"))
        .collect();
    assert_eq!(
        String::from_utf8(text).unwrap(),
        format!("board  family   version  state\nmaster -        -        unknown\n{unknown}")
    );
    // The longest text: eight slots, the longest versions, the longest state.
    let longest = Running {
        version: v(255, 255, 65535),
        state: ImageState::NoUpdates,
    };
    let text = versions_of(&[Some(Family::SeaBotix); MAX_THRUSTERS], [longest; 1 + MAX_THRUSTERS]);
    assert_eq!(text.len(), sys::MAX_LEN);
    // A version of 8 characters fills its column; a longer one is followed by one space. A slot without a thruster
    // has no line.
    let confirmed = |version| Running {
        version,
        state: ImageState::Confirmed,
    };
    let mut families = [None; MAX_THRUSTERS];
    families[1] = Some(Family::Legacy);
    let mut boards = [confirmed(v(10, 10, 100)); 1 + MAX_THRUSTERS];
    boards[0] = confirmed(v(0, 10, 100));
    let wide = versions_of(&families, boards);
    let mut bytes = [0; 120];
    let n = wide.read(0, &mut bytes);
    assert_eq!(
        String::from_utf8_lossy(&bytes[..n]),
        "board  family   version  state\nmaster -        0.10.100 confirmed\nT2     Legacy   10.10.100 confirmed\n"
    );
    assert_eq!(wide.len() as usize, n);
    // Read from an offset into a room smaller than the rest: the bytes there.
    let mut some = [0; 5];
    assert_eq!(wide.read(7, &mut some), 5);
    assert_eq!(&some, b"famil");
    let mut bytes = [0; 500];
    let n = text.read(0, &mut bytes);
    assert!(
        String::from_utf8_lossy(&bytes[..n]).contains("\nT8     SeaBotix 255.255.65535 no-updates\n"),
        "{:?}",
        String::from_utf8_lossy(&bytes[..n])
    );
}

#[test]
fn versions_txt_is_read_whole_by_readfile_and_by_burst_as_each_client_asks() {
    // ReadFile of 239 (QGroundControl fills gaps so), of 80 and of 1; BurstReadFile of 239 (MAVProxy, QGroundControl)
    // and of 80 (pymavlink).
    for (opcode, size) in [(READ, 239), (READ, 80), (READ, 1), (BURST, 239), (BURST, 80)] {
        let mut s = mixed_fleet();
        let (len, text) = s.get(0, 1, opcode, size);
        assert_eq!(text, MIXED_FLEET.as_bytes(), "{opcode} {size}");
        assert_eq!(len as usize, text.len());
    }
    // A burst that ends exactly at the end: the next is EndOfFile (QGroundControl's end).
    let mut s = mixed_fleet();
    assert!(ack(&s.op(0, 1, OPEN_RO, 0, VERSIONS)));
    let len = MIXED_FLEET.len() as u32;
    let last = s.op(0, 1, BURST, len - 10, &[0; 10]).unwrap();
    assert_eq!((last.data.len(), last.burst_complete), (10, true));
    assert_eq!(nak(&s.op(0, 1, BURST, len, &[0; 10])), Some(Nak::EndOfFile as u8));
    // The listing shows its length, then the crash records' directory. Made at each opening, it has no CRC to
    // compare a copy with.
    assert_eq!(
        s.op(0, 5, LIST, 0, b"@SYS").unwrap().data,
        format!("Fversions.txt\t{len}\0Dcrash\0").as_bytes()
    );
    assert_eq!(s.op(0, 5, LIST, 1, b"/@SYS/").unwrap().data, b"Dcrash\0");
    assert_eq!(nak(&s.op(0, 5, LIST, 2, b"/@SYS/")), Some(Nak::EndOfFile as u8));
    assert_eq!(nak(&s.op(0, 5, CRC, 0, VERSIONS)), Some(Nak::FileProtected as u8));
    // The same file, written as clients may write it; nothing else is in `@SYS`.
    assert!(ack(&s.op(0, 1, TERMINATE, 0, &[])));
    assert!(ack(&s.op(0, 6, OPEN_RO, 0, b"/@SYS/versions.txt\0")));
    assert!(ack(&s.op(0, 6, TERMINATE, 0, &[])));
    for path in [
        &b"@SYS/threads.txt"[..],
        b"@SYS/versions.txt/",
        b"@SYSversions.txt",
        b"@SYS2",
        b"/@SYS/x",
    ] {
        assert_eq!(
            nak(&s.op(0, 5, LIST, 0, path)),
            Some(Nak::FileNotFound as u8),
            "{path:?}"
        );
        assert_eq!(
            nak(&s.op(0, 7, OPEN_RO, 0, path)),
            Some(Nak::FileNotFound as u8),
            "{path:?}"
        );
    }
    assert_eq!(
        nak(&s.op(0, 5, LIST, 0, VERSIONS)),
        Some(Nak::FileNotFound as u8),
        "a file"
    );
    assert_eq!(
        nak(&s.op(0, 7, OPEN_RO, 0, b"@SYS")),
        Some(Nak::FileNotFound as u8),
        "a directory"
    );
}

#[test]
fn a_read_is_of_the_text_as_it_stood_when_it_was_opened() {
    let mut s = mixed_fleet();
    assert!(ack(&s.op(0, 1, OPEN_RO, 0, VERSIONS)));
    let first = s.op(0, 1, READ, 0, &[0; 100]).unwrap();
    // T3 confirms and T6 answers between two reads: the open file does not change.
    s.sink.0[3].state = ImageState::Confirmed;
    s.sink.0[6] = Running {
        version: v(0, 1, 0),
        state: ImageState::Confirmed,
    };
    let rest = s.op(0, 1, READ, 100, &[0; 239]).unwrap();
    assert_eq!([first.data, rest.data].concat(), MIXED_FLEET.as_bytes());
    // A read sent again (its reply lost) gets the same bytes.
    assert_eq!(
        s.op(0, 1, READ, 100, &[0; 239]).unwrap().data,
        MIXED_FLEET.as_bytes()[100..]
    );
    assert!(ack(&s.op(0, 1, TERMINATE, 0, &[])));
    // Opened again, it says what is now.
    let (_, text) = s.get(0, 2, BURST, 239);
    let now = String::from_utf8(text).unwrap();
    assert!(now.contains("T3     SeaBotix 0.3.0    confirmed\n"), "{now}");
    assert!(now.ends_with("T6     Legacy   0.1.0    confirmed\n"), "{now}");
}

#[test]
fn bad_reads_get_their_naks() {
    let mut s = mixed_fleet();
    let len = MIXED_FLEET.len() as u32;
    // No session open: nothing to read.
    assert_eq!(nak(&s.op(0, 1, READ, 0, &[0; 10])), Some(Nak::InvalidSession as u8));
    assert_eq!(nak(&s.op(0, 1, BURST, 0, &[0; 10])), Some(Nak::InvalidSession as u8));
    assert!(ack(&s.op(0, 1, OPEN_RO, 0, VERSIONS)));
    // The same session opening again: one file per session.
    assert_eq!(nak(&s.op(0, 1, OPEN_RO, 0, VERSIONS)), Some(Nak::Fail as u8));
    // At or past the end: EndOfFile, as ArduPilot answers.
    for offset in [len, len + 1, u32::MAX] {
        assert_eq!(
            nak(&s.op(0, 1, READ, offset, &[0; 10])),
            Some(Nak::EndOfFile as u8),
            "{offset}"
        );
        assert_eq!(
            nak(&s.op(0, 1, BURST, offset, &[0; 10])),
            Some(Nak::EndOfFile as u8),
            "{offset}"
        );
    }
    // Nothing asked for.
    assert_eq!(nak(&s.op(0, 1, READ, 0, &[])), Some(Nak::InvalidDataSize as u8));
    assert_eq!(nak(&s.op(0, 1, BURST, 0, &[])), Some(Nak::InvalidDataSize as u8));
    // More than a reply holds.
    let mut p = payload(1, 1, READ, 0, &[]);
    p[4] = DATA_LEN as u8 + 1;
    assert_eq!(nak(&s.send(0, DISARMED, GCS, &p)), Some(Nak::InvalidDataSize as u8));
    // Another session of the reader's, another component of its system, another system.
    let mut operator_elsewhere = GCS;
    operator_elsewhere.component = 1;
    for (from, session) in [(GCS, 2), (operator_elsewhere, 1), (OTHER, 1)] {
        let read = payload(1, session, READ, 0, &[0; 10]);
        assert_eq!(
            nak(&s.send(0, DISARMED, from, &read)),
            Some(Nak::InvalidSession as u8),
            "{from:?} {session}"
        );
    }
    // The reader's own session still reads; once it is closed (TerminateSession, or QGroundControl's
    // ResetSessions at the end of its download), it does not.
    assert!(ack(&s.op(0, 1, READ, 0, &[0; 10])));
    assert!(ack(&s.op(0, 1, TERMINATE, 0, &[])));
    assert_eq!(nak(&s.op(0, 1, READ, 0, &[0; 10])), Some(Nak::InvalidSession as u8));
    assert!(ack(&s.op(0, 0, OPEN_RO, 0, VERSIONS)));
    assert!(ack(&s.op(0, 0, RESET, 0, &[])));
    assert_eq!(nak(&s.op(0, 0, BURST, 0, &[0; 239])), Some(Nak::InvalidSession as u8));
    // An upload's session is not read.
    assert!(ack(&s.op(0, 3, CREATE, 0, THRUSTER0.as_bytes())));
    assert_eq!(nak(&s.op(0, 3, READ, 0, &[0; 10])), Some(Nak::Fail as u8));
    assert!(s.texts().is_empty(), "{:?}", s.texts());
}

#[test]
fn nothing_in_sys_is_written_created_or_removed() {
    let mut s = mixed_fleet();
    for path in [VERSIONS, b"/@SYS/versions.txt", b"@SYS/new.txt", b"@SYS", b"@SYS/"] {
        for opcode in [CREATE, OPEN_WO, REMOVE] {
            for from in [GCS, OTHER] {
                assert_eq!(
                    nak(&s.send(0, DISARMED, from, &payload(1, 1, opcode, 0, path))),
                    Some(Nak::FileProtected as u8),
                    "{path:?} {opcode} {from:?}"
                );
            }
        }
    }
    // A session that reads writes nothing.
    assert!(ack(&s.op(0, 1, OPEN_RO, 0, VERSIONS)));
    assert_eq!(nak(&s.op(0, 1, WRITE, 0, b"board")), Some(Nak::FileProtected as u8));
    assert_eq!(
        s.op(0, 1, READ, 0, &[0; 239]).unwrap().data,
        MIXED_FLEET.as_bytes()[..239]
    );
    // Refused before anything is said or counted as the operator's refusal.
    assert!(s.texts().is_empty(), "{:?}", s.texts());
    assert_eq!(s.server.counters().refused, 0);
    // The update files stay write-only.
    assert_eq!(
        nak(&s.op(0, 2, OPEN_RO, 0, THRUSTER0.as_bytes())),
        Some(Nak::FileProtected as u8)
    );
}

#[test]
fn a_read_session_and_an_upload_session_take_turns_as_any_two_sessions() {
    let mut s = mixed_fleet();
    let file = update_file(1, 2000);
    let mut operator_elsewhere = GCS;
    operator_elsewhere.component = 1;
    // An upload under way: no read opens beside it, until it has been idle for 3 s.
    assert!(ack(&s.op(0, 1, CREATE, 0, THRUSTER0.as_bytes())));
    assert!(ack(&s.op(0, 1, WRITE, 0, &file[..239])));
    for (from, session) in [(GCS, 2), (operator_elsewhere, 1), (OTHER, 1)] {
        let open = payload(1, session, OPEN_RO, 0, VERSIONS);
        assert_eq!(
            nak(&s.send(2999, DISARMED, from, &open)),
            Some(Nak::NoSessionsAvailable as u8),
            "{from:?}"
        );
    }
    assert!(ack(&s.op(3000, 2, OPEN_RO, 0, VERSIONS)));
    assert_eq!(s.texts(), ["thruster0.lbvu: stopped at 239 of 2080 bytes"]);
    assert_eq!(
        nak(&s.op(3000, 1, WRITE, 239, &file[239..478])),
        Some(Nak::InvalidSession as u8)
    );
    // A read under way holds the operator's own uploads back as any session does, each read keeping it live.
    assert!(ack(&s.op(5000, 2, READ, 0, &[0; 10])));
    for (from, session) in [(GCS, 3), (operator_elsewhere, 3)] {
        let create = payload(1, session, CREATE, 0, THRUSTER0.as_bytes());
        assert_eq!(
            nak(&s.send(7999, DISARMED, from, &create)),
            Some(Nak::NoSessionsAvailable as u8),
            "{from:?}"
        );
    }
    // Idle for 3 s: an upload takes over.
    assert!(ack(&s.op(8000, 3, CREATE, 0, THRUSTER0.as_bytes())));
    assert_eq!(nak(&s.op(8000, 2, READ, 10, &[0; 10])), Some(Nak::InvalidSession as u8));
    // An image whole has nothing left to lose: a read opens at once.
    for (n, chunk) in file.chunks(239).enumerate() {
        assert!(ack(&s.op(8000, 3, WRITE, (n * 239) as u32, chunk)));
    }
    assert!(ack(&s.op(8001, 4, OPEN_RO, 0, VERSIONS)));
    assert!(s.server.is_received(UpdateTarget::Thruster(0)), "the image is kept");
    assert!(ack(&s.op(8001, 4, TERMINATE, 0, &[])));
    // Another system's read holds no update back: the operator's upload takes over at once, and the reader opens
    // again later.
    let open = payload(1, 1, OPEN_RO, 0, VERSIONS);
    assert!(ack(&s.send(9000, DISARMED, OTHER, &open)));
    assert!(ack(&s.op(9001, 5, CREATE, 0, THRUSTER0.as_bytes())));
    let read = payload(2, 1, READ, 0, &[0; 10]);
    assert_eq!(
        nak(&s.send(9001, DISARMED, OTHER, &read)),
        Some(Nak::InvalidSession as u8)
    );
    // The upload, live, is not taken over by that system's read in turn: it waits, as for any live session.
    assert_eq!(
        nak(&s.send(9002, DISARMED, OTHER, &open)),
        Some(Nak::NoSessionsAvailable as u8)
    );
}

#[test]
fn a_read_goes_on_while_armed_restarting_or_unsigned() {
    let mut s = mixed_fleet();
    for context in [
        ARMED,
        RESTARTING,
        Context {
            unsigned: true,
            ..DISARMED
        },
    ] {
        let open = payload(1, 1, OPEN_RO, 0, VERSIONS);
        assert!(ack(&s.send(0, context, OTHER, &open)), "{context:?}");
        let mut text = Vec::new();
        for offset in [0, 239] {
            let read = payload(2, 1, BURST, offset, &[0; 239]);
            text.extend(s.send(0, context, OTHER, &read).unwrap().data);
        }
        assert_eq!(text, MIXED_FLEET.as_bytes(), "{context:?}");
        assert!(ack(&s.send(0, context, OTHER, &payload(3, 1, TERMINATE, 0, &[]))));
    }
    assert!(s.texts().is_empty(), "{:?}", s.texts());
}

/// `param.pck` as ArduPilot's AP_Filesystem README describes it, read back without the encoder: the header, then
/// each parameter's name, type code, value and default, zeros skipped before a parameter.
#[derive(Debug)]
struct Unpacked {
    magic: u16,
    count: u16,
    total: u16,
    params: Vec<Packed>,
    /// Where each parameter's value (and default) lie in the file.
    data: Vec<std::ops::Range<usize>>,
}

/// A parameter's name, type code, value bytes and default bytes.
type Packed = (String, u8, Vec<u8>, Option<Vec<u8>>);

fn unpack(file: &[u8]) -> Unpacked {
    let word = |at: usize| u16::from_le_bytes([file[at], file[at + 1]]);
    let mut unpacked = Unpacked {
        magic: word(0),
        count: word(2),
        total: word(4),
        params: Vec::new(),
        data: Vec::new(),
    };
    let mut at = 6;
    let mut last: Vec<u8> = Vec::new();
    while at < file.len() {
        if file[at] == 0 {
            at += 1;
            continue;
        }
        let (code, flags) = (file[at] & 0x0F, file[at] >> 4);
        let (common, own) = (usize::from(file[at + 1] & 0x0F), usize::from(file[at + 1] >> 4) + 1);
        let mut name = last[..common].to_vec();
        name.extend(&file[at + 2..at + 2 + own]);
        let size = match code {
            1 => 1,
            2 => 2,
            3 | 4 => 4,
            _ => panic!("type {code} at {at}"),
        };
        let start = at + 2 + own;
        let value = file[start..start + size].to_vec();
        let default =
            (unpacked.magic == 0x671C && flags & 1 == 1).then(|| file[start + size..start + 2 * size].to_vec());
        let end = start + size * (1 + usize::from(default.is_some()));
        unpacked.data.push(start..end);
        unpacked
            .params
            .push((String::from_utf8(name.clone()).unwrap(), code, value, default));
        last = name;
        at = end;
    }
    unpacked
}

/// The vehicle's defaults (the LBV300-6's) with a few changed: the operator's gain, a timeout, the operator's
/// system and the frame.
fn changed_params() -> Params {
    let mut params = Params::defaults(FrameKind::Lbv300_6);
    assert!(params.set(Param::Gain, 70));
    assert!(params.set(Param::GcsTimeout, 100));
    assert!(params.set(Param::OperatorId, 200));
    assert!(params.set(Param::Frame, 4));
    params
}

fn with_params(params: Params) -> Context {
    Context {
        params: Some(params),
        ..DISARMED
    }
}

const PARAM_PCK: &[u8] = b"@PARAM/param.pck";

#[test]
fn param_pck_lists_every_parameter_as_ardupilot_packs_them() {
    let mut s = Server::new();
    let (len, file) = s.get_file(0, with_params(changed_params()), 1, PARAM_PCK, BURST, 239);
    assert_eq!(len as usize, file.len());
    let unpacked = unpack(&file);
    let listed = LISTED_COUNT as u16;
    assert_eq!(
        (unpacked.magic, unpacked.count, unpacked.total),
        (0x671B, listed, listed)
    );
    let names: Vec<&str> = unpacked.params.iter().map(|(name, ..)| name.as_str()).collect();
    let expected: Vec<&str> = Listed::all().map(|listed| listed.name()).collect();
    assert_eq!(names, expected);
    let find = |name: &str| unpacked.params.iter().find(|(n, ..)| n == name).unwrap().clone();
    // Each type as AP_Param numbers it, with the value in the displayed unit.
    assert_eq!(find("LBV_GAIN"), ("LBV_GAIN".into(), 1, vec![70], None));
    assert_eq!(
        find("SYSID_MYGCS"),
        ("SYSID_MYGCS".into(), 2, 200u16.to_le_bytes().to_vec(), None)
    );
    assert_eq!(
        find("FS_GCS_TIMEOUT"),
        ("FS_GCS_TIMEOUT".into(), 4, 10.0f32.to_le_bytes().to_vec(), None)
    );
    assert_eq!(find("FS_PILOT_TIMEOUT").2, 3.0f32.to_le_bytes());
    assert_eq!(find("LBV_FRAME").2, [4]);
    // The read-only stand-ins after the settings, INT32 among them.
    assert_eq!(find("COMPASS_DEV_ID2"), ("COMPASS_DEV_ID2".into(), 3, vec![0; 4], None));
    assert_eq!(find("INS_ACCOFFS_Z").2, 0.0f32.to_le_bytes());
    assert_eq!(find("FLTMODE6").2, [19]);
    assert_eq!(find("SERVO14_FUNCTION").1, 2);
    assert_eq!(find("BATT_MONITOR").2, [0xFF], "-1");
    // A name shares its start with the one before: BTN1_FUNCTION sends "1_FUNCTION" after "BTN".
    assert!(
        file.windows(12).any(|w| w == b"\x01\x931_FUNCTION"),
        "type 1, 3 bytes shared, 10 of its own"
    );
    // It spans two blocks of 239 bytes, and no value crosses from one to the next.
    assert!(file.len() > 239, "{}", file.len());
    for data in &unpacked.data {
        assert_eq!(data.start / 239, (data.end - 1) / 239, "{data:?}");
    }
}

#[test]
fn param_pck_with_defaults_carries_the_default_of_each_parameter_changed() {
    let mut s = Server::new();
    let path = b"@PARAM/param.pck?withdefaults=1";
    let (len, file) = s.get_file(0, with_params(changed_params()), 1, path, BURST, 239);
    assert_eq!(len as usize, file.len());
    let unpacked = unpack(&file);
    assert_eq!((unpacked.magic, unpacked.count), (0x671C, LISTED_COUNT as u16));
    let with_defaults: Vec<(&str, &[u8])> = unpacked
        .params
        .iter()
        .filter_map(|(name, _, _, default)| Some((name.as_str(), default.as_deref()?)))
        .collect();
    assert_eq!(
        with_defaults,
        [
            ("FS_GCS_TIMEOUT", &5.0f32.to_le_bytes()[..]),
            ("SYSID_MYGCS", &255u16.to_le_bytes()[..]),
            ("LBV_GAIN", &[50][..]),
            // The build's frame.
            ("LBV_FRAME", &[6][..]),
        ]
    );
    for data in &unpacked.data {
        assert_eq!(data.start / 239, (data.end - 1) / 239, "{data:?}");
    }
    // The same file whatever the client reads it in: ReadFile of 239, 80 and 1 (a value split across two reads is
    // still the value it was opened with), BurstReadFile of 80.
    for (opcode, size) in [(READ, 239), (READ, 80), (READ, 1), (BURST, 80)] {
        let (_, again) = s.get_file(0, with_params(changed_params()), 2, path, opcode, size);
        assert_eq!(again, file, "{opcode} {size}");
    }
}

#[test]
fn param_pck_takes_ardupilots_query_and_refuses_what_it_cannot_serve() {
    let mut s = Server::new();
    let context = with_params(changed_params());
    let magic = |path: &[u8], s: &mut Server| {
        let (_, file) = s.get_file(0, context, 1, path, BURST, 239);
        let unpacked = unpack(&file);
        let listed = LISTED_COUNT as u16;
        assert_eq!(
            (unpacked.count, unpacked.total, unpacked.params.len()),
            (listed, listed, LISTED_COUNT)
        );
        unpacked.magic
    };
    assert_eq!(magic(b"@PARAM/param.pck?withdefaults=0", &mut s), 0x671B);
    assert_eq!(magic(b"/@PARAM/param.pck?withdefaults=1", &mut s), 0x671C);
    // Keys it does not know are ignored, as ArduPilot ignores them (its `start` and `count` among them: the whole
    // list comes, and says so); so is an empty query.
    assert_eq!(magic(b"@PARAM/param.pck?format=2&withdefaults=1&x", &mut s), 0x671C);
    assert_eq!(magic(b"@PARAM/param.pck?start=10&count=5", &mut s), 0x671B);
    assert_eq!(magic(b"@PARAM/param.pck?", &mut s), 0x671B);
    for path in [
        &b"@PARAM/param.pck?withdefaults=2"[..],
        b"@PARAM/param.pck?withdefaults",
        b"@PARAM/param.pck?withdefaults=",
        b"@PARAM/param.pck?withdefaults=01",
    ] {
        assert_eq!(
            nak(&s.send(0, context, OTHER, &payload(1, 3, OPEN_RO, 0, path))),
            Some(Nak::Fail as u8),
            "{}",
            String::from_utf8_lossy(path)
        );
    }
    // Before the settings are published there are no values to list.
    assert_eq!(nak(&s.op(0, 3, OPEN_RO, 0, PARAM_PCK)), Some(Nak::Fail as u8));
    // Read-only: the operator may not write, create, remove or checksum it.
    for opcode in [CREATE, OPEN_WO, REMOVE, CRC] {
        assert_eq!(
            nak(&s.send(0, context, GCS, &payload(1, 4, opcode, 0, PARAM_PCK))),
            Some(Nak::FileProtected as u8),
            "{opcode}"
        );
    }
    // `@PARAM` lists it with its length (without a query); nothing else is there.
    let (len, _) = s.get_file(0, context, 1, PARAM_PCK, BURST, 239);
    let listed = s.send(0, context, OTHER, &payload(1, 5, LIST, 0, b"@PARAM")).unwrap();
    assert_eq!(listed.data, format!("Fparam.pck\t{len}\0").as_bytes());
    assert_eq!(
        nak(&s.send(0, context, OTHER, &payload(2, 5, LIST, 1, b"/@PARAM/"))),
        Some(Nak::EndOfFile as u8)
    );
    assert_eq!(
        nak(&s.send(0, context, OTHER, &payload(3, 5, LIST, 0, PARAM_PCK))),
        Some(Nak::FileNotFound as u8)
    );
}

#[test]
fn a_parameter_set_while_param_pck_is_read_fails_the_reads_until_it_is_opened_again() {
    let mut s = Server::new();
    let before = with_params(changed_params());
    assert!(ack(&s.send(0, before, OTHER, &payload(1, 1, OPEN_RO, 0, PARAM_PCK))));
    let first = s.send(0, before, OTHER, &payload(2, 1, BURST, 0, &[0; 239])).unwrap();
    assert_eq!((first.opcode, first.data.len()), (ACK, 239));
    // LBV_GAIN set between the two reads: the rest of the file would not be the file begun.
    let mut params = changed_params();
    assert!(params.set(Param::Gain, 71));
    let after = with_params(params);
    let second = s.send(0, after, OTHER, &payload(3, 1, BURST, 239, &[0; 239]));
    assert_eq!(nak(&second), Some(Nak::Fail as u8));
    // The same read, made when the value has gone back, is the file again.
    let again = s.send(0, before, OTHER, &payload(4, 1, BURST, 239, &[0; 239])).unwrap();
    assert_eq!(again.opcode, ACK);
    // Opened again, the file has the new value.
    assert!(ack(&s.send(0, after, OTHER, &payload(5, 1, TERMINATE, 0, &[]))));
    let (_, file) = s.get_file(0, after, 2, PARAM_PCK, BURST, 239);
    let gain = unpack(&file)
        .params
        .into_iter()
        .find(|(name, ..)| name == "LBV_GAIN")
        .unwrap();
    assert_eq!(gain.2, [71]);
}

#[test]
fn param_pck_never_panics_on_a_query_or_a_read() {
    proptest!(|(query in proptest::collection::vec(any::<u8>(), 0..40), offset in any::<u32>(), size in 0usize..300)| {
        let params = changed_params();
        if let Some(file) = ParamFile::open(&query, &params, FrameKind::Lbv300_6) {
            let mut into = vec![0; size];
            let filled = file.read(offset, &mut into, &params).unwrap();
            let len = u32::from(u16::from_le_bytes(file.len));
            prop_assert_eq!(filled as u32, len.saturating_sub(offset).min(size as u32));
        }
    });
}

/// A record as a master's region holds one after a panic.
fn a_crash_record() -> [u8; crash_record::LEN] {
    let mut region = crash_record::Region::new();
    let image = crash_record::Image {
        target: 3,
        version: [0, 1, 0, 0],
    };
    region.start(crash_record::ResetCause(1 << 27), image);
    region.note(crash_record::Event {
        at_ms: 500,
        what: crash_record::What::Armed,
    });
    region.record(
        crash_record::Stop {
            kind: crash_record::Kind::Panic,
            frame: crash_record::Frame {
                pc: 0x0800_1001,
                ..Default::default()
            },
            faults: Default::default(),
            exception: 0,
            panic: None,
            uptime_ms: 900,
        },
        image,
    );
    region.record
}

const CRASH: &[u8] = b"@SYS/crash/master.bin";

#[test]
fn the_crash_record_is_served_read_only_while_the_region_holds_one() {
    let record = a_crash_record();
    let held = Context {
        crash: true,
        ..DISARMED
    };
    let mut s = Server::new();
    // None held: the directory is empty and the file is not there.
    assert_eq!(nak(&s.op(0, 1, LIST, 0, b"@SYS/crash")), Some(Nak::EndOfFile as u8));
    assert_eq!(nak(&s.op(0, 1, OPEN_RO, 0, CRASH)), Some(Nak::FileNotFound as u8));
    // Held: listed with its length, opened, read whole by anyone, as MAVProxy's `ftp get` reads it.
    let listed = s
        .send(0, held, OTHER, &payload(1, 1, LIST, 0, b"/@SYS/crash/"))
        .unwrap();
    assert_eq!(listed.data, b"Fmaster.bin\t128\0");
    let open = s.send(0, held, OTHER, &payload(2, 1, OPEN_RO, 0, CRASH)).unwrap();
    assert_eq!((open.opcode, open.data.clone()), (ACK, 128u32.to_le_bytes().to_vec()));
    let contents = Contents {
        params: None,
        crash: Some(&record),
        black_box: None,
    };
    let mut got = Vec::new();
    for (seq, offset) in [(3, 0), (4, 80)] {
        let mut said = Vec::new();
        let answer = s
            .server
            .request(
                t(0),
                held,
                OTHER,
                &payload(seq, 1, READ, offset, &[0; 80]),
                &mut s.sink,
                &mut |o| said.push(o),
            )
            .unwrap();
        got.extend(read(&answer.payload(&contents)).data);
        // A read framed once the record is gone (never, while the session is open) is refused, not made up.
        assert_eq!(read(&answer.payload(&Contents::NOTHING)).opcode, NAK);
    }
    assert_eq!(got, record);
    assert_eq!(
        crash_record::Record::decode(&got).unwrap().kind,
        crash_record::Kind::Panic
    );
    assert_eq!(
        nak(&s.send(0, held, OTHER, &payload(5, 1, READ, 128, &[0; 80]))),
        Some(Nak::EndOfFile as u8)
    );
    // Nobody writes, removes or checksums it, the operator included.
    for opcode in [CREATE, OPEN_WO, REMOVE, CRC] {
        assert_eq!(
            nak(&s.send(0, held, GCS, &payload(6, 2, opcode, 0, CRASH))),
            Some(Nak::FileProtected as u8),
            "{opcode}"
        );
    }
}

#[test]
fn the_thrusters_records_are_listed_after_the_masters_and_read_by_their_slot() {
    let held = Context {
        crash: true,
        post_mortems: 0b1000_0100,
        ..DISARMED
    };
    let mut s = Server::new();
    // As many entries as a reply holds (28 bytes: one here), the next from the offset after the last.
    let entries: Vec<Vec<u8>> = (0..3)
        .map(|first| {
            s.send(0, held, OTHER, &payload(1, 1, LIST, first, b"@SYS/crash"))
                .unwrap()
                .data
        })
        .collect();
    assert_eq!(
        entries,
        [
            &b"Fmaster.bin\t128\0"[..],
            b"Fthruster2.bin\t128\0",
            b"Fthruster7.bin\t128\0"
        ]
    );
    assert_eq!(
        nak(&s.send(0, held, OTHER, &payload(3, 1, LIST, 3, b"@SYS/crash"))),
        Some(Nak::EndOfFile as u8)
    );
    for (path, open) in [
        (&b"@SYS/crash/thruster2.bin"[..], true),
        (b"/@SYS/crash/thruster7.bin", true),
        (b"@SYS/crash/thruster1.bin", false),
        (b"@SYS/crash/thruster8.bin", false),
        (b"@SYS/crash/thruster22.bin", false),
        (b"@SYS/crash/thruster.bin", false),
    ] {
        let reply = s.send(0, held, OTHER, &payload(4, 1, OPEN_RO, 0, path)).unwrap();
        let expected = if open { ACK } else { NAK };
        assert_eq!(reply.opcode, expected, "{}", String::from_utf8_lossy(path));
        let _ = s.send(0, held, OTHER, &payload(5, 1, TERMINATE, 0, b""));
    }
}

#[test]
fn the_master_keeps_each_thrusters_record_once_and_refuses_one_that_does_not_check() {
    let shared = Shared::new();
    let record = a_crash_record();
    assert_eq!(shared.post_mortem(3), None);
    let decoded = shared.keep_post_mortem(3, &record).unwrap().unwrap();
    assert_eq!(decoded.kind, crash_record::Kind::Panic);
    assert_eq!(
        (Context::of(&shared).post_mortems, shared.post_mortem(3)),
        (0b1000, Some(record))
    );
    // The same record fetched again (the thruster reset once more) is not new.
    assert_eq!(shared.keep_post_mortem(3, &record), Ok(None));
    let mut torn = record;
    torn[40] ^= 1;
    assert!(shared.keep_post_mortem(3, &torn).is_err());
    assert_eq!(shared.post_mortem(3), Some(record));
    // A slot past the table's largest keeps nothing.
    assert_eq!(shared.keep_post_mortem(8, &record), Ok(None));
    assert_eq!(Context::of(&shared).post_mortems, 0b1000);
}

#[test]
fn the_context_tells_whether_the_region_holds_a_record() {
    let shared = Shared::new();
    assert!(!Context::of(&shared).crash);
    let region = Box::leak(Box::new(crash_record::Region {
        record: a_crash_record(),
        ring: [0; crash_record::RING_LEN],
    }));
    shared.keep_crash(region);
    assert!(Context::of(&shared).crash);
    assert_eq!(shared.crash_bytes(), Some(a_crash_record()));
}

#[test]
fn a_reads_reply_stays_the_size_of_an_outbox_slot() {
    // The console's outbox holds 16 messages, each as large as the largest: a read's reply, with the snapshot its
    // 239 bytes are made from, and a 4-byte offset (the black box is larger than 64 KiB): 64 bytes on the target
    // (`shared.rs` holds it there), beside a STATUSTEXT's 60.
    assert_eq!(core::mem::size_of::<FtpAnswer>(), 58);
    assert_eq!(core::mem::size_of::<Versions>(), 49);
}

#[test]
fn a_read_is_served_to_the_console_with_its_snapshot_and_framed_whole() {
    let shared = Shared::new();
    let mut updates = Updates::new(&VEHICLE.thrusters, FrameKind::Lbv300_6, CheckOnly);
    let ftp = |seq, opcode, offset: u32, data: &[u8]| UpdateRequest {
        from: OTHER,
        what: UpdateCommand::Ftp(payload(seq, 1, opcode, offset, data)),
    };
    let open = updates.serve(ftp(1, OPEN_RO, 0, VERSIONS), &shared);
    let Some(Outgoing::Ftp {
        to: OTHER,
        reply: FtpAnswer::Reply(open),
    }) = open
    else {
        panic!("the open's ACK: {open:?}");
    };
    assert_eq!((open[3], open[4]), (ACK, 4));
    let read = updates.serve(ftp(2, BURST, 0, &[0; 239]), &shared);
    let Some(Outgoing::Ftp {
        to: OTHER,
        reply: reply @ FtpAnswer::Read(_),
    }) = read
    else {
        panic!("a read of versions.txt: {read:?}");
    };
    let payload = reply.payload(&Contents::NOTHING);
    assert_eq!(payload[..8], [3, 0, 1, ACK, 239, BURST, 1, 0]);
    assert!(payload[12..].starts_with(b"board  family   version  state\nmaster -        -        unknown\n"));
    assert_ne!(payload[250], 0, "the whole payload");
    // param.pck: not before the settings are published; then made from the parameters in force as it is framed.
    let open = updates.serve(ftp(3, TERMINATE, 0, &[]), &shared);
    assert!(matches!(open, Some(Outgoing::Ftp { reply: FtpAnswer::Reply(r), .. }) if r[3] == ACK));
    let refused = updates.serve(ftp(4, OPEN_RO, 0, PARAM_PCK), &shared);
    assert!(matches!(refused, Some(Outgoing::Ftp { reply: FtpAnswer::Reply(r), .. }) if r[3] == NAK));
    let settings = crate::params::Settings::defaults(FrameKind::Lbv300_6);
    shared.settings.sender().send(settings);
    let open = updates.serve(ftp(5, OPEN_RO, 0, PARAM_PCK), &shared);
    assert!(matches!(open, Some(Outgoing::Ftp { reply: FtpAnswer::Reply(r), .. }) if r[3] == ACK));
    let Some(Outgoing::Ftp { reply, .. }) = updates.serve(ftp(6, BURST, 0, &[0; 239]), &shared) else {
        panic!("a read of param.pck");
    };
    assert_eq!(
        reply.payload(&Contents {
            params: Some(&settings.params),
            crash: None,
            black_box: None,
        })[..6],
        [7, 0, 1, ACK, 239, BURST]
    );
    assert_eq!(
        reply.payload(&Contents {
            params: Some(&settings.params),
            crash: None,
            black_box: None,
        })[12..18],
        [0x1B, 0x67, 64, 0, 64, 0]
    );
    // The console without the settings (never, once the file is open) sends a NAK rather than other values.
    assert_eq!(reply.payload(&Contents::NOTHING)[..6], [7, 0, 1, NAK, 1, BURST]);
}

#[test]
fn opcodes_it_does_not_serve_and_bad_payloads() {
    let mut s = Server::new();
    // CreateDirectory, RemoveDirectory, TruncateFile, Rename, ListDirectoryWithTime (MAVProxy's first try), and
    // bytes that are no opcode.
    for opcode in [9, 10, 12, 13, 16, 17, 99, 127, 130, 255] {
        let reply = s.op(0, 0, opcode, 0, b"@PARAM/param.pck").unwrap();
        assert_eq!(
            (reply.opcode, reply.req_opcode, reply.data),
            (NAK, opcode, vec![Nak::UnknownCommand as u8])
        );
    }
    // A reply sent to the server is not answered.
    assert_eq!(s.op(0, 0, ACK, 0, &[]), None);
    assert_eq!(s.op(0, 0, NAK, 0, &[1]), None);
    // None: ACKed.
    assert!(ack(&s.op(0, 0, 0, 0, &[])));
    // A size beyond the data room, for any opcode.
    for opcode in [0, LIST, CREATE, WRITE, CRC, 99] {
        let mut p = payload(1, 0, opcode, 0, b"/update");
        p[4] = DATA_LEN as u8 + 1;
        assert_eq!(
            nak(&s.send(0, DISARMED, GCS, &p)),
            Some(Nak::InvalidDataSize as u8),
            "{opcode}"
        );
    }
    // Paths: empty, a NUL inside; a trailing NUL is allowed.
    assert_eq!(nak(&s.op(0, 0, LIST, 0, b"")), Some(Nak::InvalidDataSize as u8));
    assert_eq!(
        nak(&s.op(0, 0, LIST, 0, b"/upd\0ate")),
        Some(Nak::InvalidDataSize as u8)
    );
    assert!(ack(&s.op(0, 0, CRC, 0, b"/update/thruster5.lbvu\0")));
    // No such files: slots beyond the table, other names.
    for path in [
        "/update/thruster6.lbvu",
        "/update/thruster9.lbvu",
        "/update/thrusterA.lbvu",
        "/update/thruster0.bin",
    ] {
        assert_eq!(
            nak(&s.op(0, 0, CRC, 0, path.as_bytes())),
            Some(Nak::FileNotFound as u8),
            "{path}"
        );
        assert_eq!(
            nak(&s.op(0, 0, CREATE, 0, path.as_bytes())),
            Some(Nak::FileNotFound as u8),
            "{path}"
        );
    }
    assert_eq!(nak(&s.op(0, 0, CREATE, 0, b"/update")), Some(Nak::FileNotFound as u8));
    assert!(s.texts().is_empty());
    assert_eq!(s.server.counters().naks, 10 + 6 + 2 + 8 + 1);
}

#[test]
fn open_file_wo_starts_an_upload_too() {
    let mut s = Server::new();
    let file = update_file(1, 1000);
    assert!(ack(&s.op(0, 1, OPEN_WO, 0, THRUSTER0.as_bytes())));
    for (n, chunk) in file.chunks(239).enumerate() {
        assert!(ack(&s.op(0, 1, WRITE, (n * 239) as u32, chunk)));
    }
    assert!(s.server.is_received(UpdateTarget::Thruster(0)));
}

#[test]
fn remove_forgets_and_a_refused_upload_keeps_the_image_held() {
    let mut s = Server::new();
    let file = update_file(1, 1000);
    assert!(ack(&s.put(0, 1, THRUSTER0, &file, 239)));
    assert!(ack(&s.op(0, 1, TERMINATE, 0, &[])));
    // A refused upload to another slot, or to this one, leaves it.
    assert_eq!(
        nak(&s.put(0, 2, "/update/master.lbvu", &file, 239)),
        Some(Nak::Fail as u8)
    );
    assert_eq!(
        nak(&s.put(0, 3, THRUSTER0, &update_file(2, 1000), 239)),
        Some(Nak::Fail as u8)
    );
    assert!(s.server.is_received(UpdateTarget::Thruster(0)));
    // An upload to this slot that begins replaces it.
    assert!(ack(&s.op(0, 4, CREATE, 0, THRUSTER0.as_bytes())));
    assert!(
        s.server.is_received(UpdateTarget::Thruster(0)),
        "not until its header passes"
    );
    assert!(ack(&s.op(0, 4, WRITE, 0, &file[..239])));
    assert!(!s.server.is_received(UpdateTarget::Thruster(0)));
    assert!(ack(&s.op(0, 4, TERMINATE, 0, &[])));
    assert!(ack(&s.put(0, 5, THRUSTER0, &file, 239)));
    assert!(ack(&s.op(0, 5, TERMINATE, 0, &[])));
    // Removed: the listing shows nothing, nothing to apply.
    s.said.clear();
    assert!(ack(&s.op(0, 0, REMOVE, 0, THRUSTER0.as_bytes())));
    assert_eq!(s.texts(), ["thruster0.lbvu: removed"]);
    assert_eq!(s.op(0, 0, LIST, 0, b"/update").unwrap().data, b"Fthruster0.lbvu\t0\0");
    assert!(!s.server.is_received(UpdateTarget::Thruster(0)));
    // Removing during an upload stops it.
    assert!(ack(&s.op(0, 6, CREATE, 0, THRUSTER0.as_bytes())));
    assert!(ack(&s.op(0, 6, WRITE, 0, &file[..239])));
    assert!(ack(&s.op(0, 0, REMOVE, 0, THRUSTER0.as_bytes())));
    assert_eq!(
        nak(&s.op(0, 6, WRITE, 239, &file[239..478])),
        Some(Nak::InvalidSession as u8)
    );
    assert_eq!(s.images().last().unwrap().complete, Some(false));
}

#[test]
fn a_remove_of_another_components_live_upload_is_refused() {
    let mut s = Server::new();
    let file = update_file(1, 2000);
    let mut companion = GCS;
    companion.component = 1;
    let remove = |seq| payload(seq, 0, REMOVE, 0, THRUSTER0.as_bytes());
    assert!(ack(&s.op(0, 1, CREATE, 0, THRUSTER0.as_bytes())));
    assert!(ack(&s.op(0, 1, WRITE, 0, &file[..239])));
    // Another component of the operator's system, while the upload is live: refused, the upload goes on.
    assert_eq!(
        nak(&s.send(2000, DISARMED, companion, &remove(40))),
        Some(Nak::Fail as u8)
    );
    assert_eq!(s.texts(), ["thruster0.lbvu: another component is uploading it"]);
    assert!(ack(&s.op(2500, 1, WRITE, 239, &file[239..478])));
    // Another file than the one uploaded is its to remove.
    assert!(ack(&s.send(
        2500,
        DISARMED,
        companion,
        &payload(41, 0, REMOVE, 0, b"/update/master.lbvu")
    )));
    // Idle for TAKEOVER_IDLE, the upload may be taken over, and removed.
    assert!(ack(&s.send(5500, DISARMED, companion, &remove(42))));
    assert_eq!(s.images()[0].complete, Some(false));
    assert_eq!(
        nak(&s.op(5500, 1, WRITE, 478, &file[478..717])),
        Some(Nak::InvalidSession as u8)
    );
    // Once whole, the image is anyone's of the operator's to remove, the session still open.
    assert!(ack(&s.put(6000, 2, THRUSTER0, &file, 239)));
    assert!(ack(&s.send(6000, DISARMED, companion, &remove(43))));
    assert!(!s.server.is_received(UpdateTarget::Thruster(0)));
}

#[test]
fn nothing_changes_over_a_link_without_signing_unless_allowed() {
    const UNSIGNED_LINK: Context = Context {
        unsigned: true,
        ..DISARMED
    };
    let mut s = Server::new();
    let file = update_file(1, 1000);
    // An upload under way when signing goes off stops at its next write.
    assert!(ack(&s.op(0, 1, CREATE, 0, THRUSTER0.as_bytes())));
    assert!(ack(&s.op(0, 1, WRITE, 0, &file[..239])));
    let write = payload(30, 1, WRITE, 239, &file[239..478]);
    assert_eq!(nak(&s.send(0, UNSIGNED_LINK, GCS, &write)), Some(Nak::Fail as u8));
    assert_eq!(s.images()[0].complete, Some(false));
    // No upload begins, nothing is removed.
    for (n, opcode) in [CREATE, OPEN_WO, REMOVE].into_iter().enumerate() {
        let request = payload(40 + n as u16, 2, opcode, 0, THRUSTER0.as_bytes());
        assert_eq!(
            nak(&s.send(0, UNSIGNED_LINK, GCS, &request)),
            Some(Nak::Fail as u8),
            "{opcode}"
        );
    }
    assert_eq!(s.texts(), ["thruster0.lbvu: refused, the link is not signed"; 4]);
    // Anyone may still read.
    assert!(ack(&s.send(
        0,
        UNSIGNED_LINK,
        OTHER,
        &payload(50, 0, LIST, 0, b"/update")
    )));
    assert!(ack(&s.send(
        0,
        UNSIGNED_LINK,
        GCS,
        &payload(51, 0, CRC, 0, THRUSTER0.as_bytes())
    )));
    assert_eq!(s.images().len(), 1, "the sink began nothing more");
}

/// A vehicle publishing its state and `settings` into `shared`, as the vehicle task does.
fn publish(shared: &Shared, settings: crate::params::Settings) {
    let vehicle = crate::vehicle::Vehicle::new(crate::vehicle::VehicleConfig::DEFAULT, settings);
    shared.vehicle.sender().send(vehicle.state(t(0)));
    shared.settings.sender().send(settings);
}

#[test]
fn the_link_is_unsigned_for_updates_unless_a_key_is_in_force_or_the_parameter_allows_it() {
    use crate::console::signing::SigningKey;
    use crate::params::{Param, Settings};
    let shared = Shared::new();
    assert!(Context::of(&shared).unsigned, "before the settings are known");
    let defaults = Settings::defaults(crate::mixer::FrameKind::Lbv300_6);
    publish(&shared, defaults);
    assert!(Context::of(&shared).unsigned, "no key, LBV_UPD_UNSIGNED 0");
    let mut allowed = defaults;
    assert!(allowed.params.set(Param::UnsignedUpdates, 1));
    publish(&shared, allowed);
    assert!(!Context::of(&shared).unsigned);
    let signed = Settings {
        signing: Some(SigningKey {
            secret: [3; 32],
            timestamp: 1,
        }),
        ..defaults
    };
    publish(&shared, signed);
    assert!(!Context::of(&shared).unsigned);
}

#[test]
fn the_apply_command_over_a_link_without_signing_is_denied_with_why() {
    use crate::params::{Param, Settings};
    let shared = Shared::new();
    let defaults = Settings::defaults(crate::mixer::FrameKind::Lbv300_6);
    let mut allowed = defaults;
    assert!(allowed.params.set(Param::UnsignedUpdates, 1));
    publish(&shared, allowed);
    let mut updates = Updates::new(&VEHICLE.thrusters, FrameKind::Lbv300_6, CheckOnly);
    let file = update_file(1, 1000);
    let ftp = |seq, opcode, offset: u32, data: &[u8]| UpdateRequest {
        from: GCS,
        what: UpdateCommand::Ftp(payload(seq, 1, opcode, offset, data)),
    };
    assert!(
        updates
            .serve(ftp(1, CREATE, 0, THRUSTER0.as_bytes()), &shared)
            .is_some()
    );
    for (n, chunk) in file.chunks(239).enumerate() {
        let reply = updates.serve(ftp(2 + n as u16, WRITE, (n * 239) as u32, chunk), &shared);
        assert!(matches!(reply, Some(Outgoing::Ftp { reply, .. }) if reply.payload(&Contents::NOTHING)[3] == ACK));
    }
    let drain = || core::iter::from_fn(|| shared.outbox.try_receive().ok()).collect::<Vec<_>>();
    drain();
    // LBV_UPD_UNSIGNED back to 0: the image held is not applied.
    publish(&shared, defaults);
    let apply = UpdateRequest {
        from: GCS,
        what: UpdateCommand::Apply(Some(0)),
    };
    assert_eq!(updates.serve(apply, &shared), None);
    let said = drain();
    assert_eq!(
        (acked(&said), text_of(&said)),
        (
            Some(AckResult::Denied),
            vec!["update: refused, the link is not signed".to_owned()]
        )
    );
    // Allowed again: applied.
    publish(&shared, allowed);
    assert_eq!(updates.serve(apply, &shared), None);
    assert_eq!(acked(&drain()), Some(AckResult::Accepted));
}

/// A sink that takes every image and keeps nothing: an apply starts for a thruster and fails for the master; a
/// version query is taken for slot 1 only, as the courier takes one when it carries nothing (each slot asked is
/// kept).
#[derive(Default)]
struct Nowhere {
    queried: Vec<u8>,
}

impl UpdateSink for Nowhere {
    fn begin(&mut self, _: UpdateTarget, _: &ImageHeader) -> Result<(), Refused> {
        Ok(())
    }
    fn write(&mut self, _: u32, _: &[u8]) -> Result<(), Refused> {
        Ok(())
    }
    fn finish(&mut self, _: bool) -> Result<(), Refused> {
        Ok(())
    }
    fn apply(&mut self, target: UpdateTarget, _: Sender) -> Result<Applied, Nak> {
        match target {
            UpdateTarget::Master => Err(Nak::Fail),
            UpdateTarget::Thruster(_) | UpdateTarget::Family { .. } => Ok(Applied::Started),
        }
    }
    fn query_version(&mut self, slot: u8, _: Sender) -> Result<(), Refused> {
        self.queried.push(slot);
        if slot == 1 {
            Ok(())
        } else {
            Err(Refused::Because("wait: an update is under way"))
        }
    }
}

fn acked(said: &[Outgoing]) -> Option<AckResult> {
    said.iter().find_map(|o| match o {
        Outgoing::CommandAck { command, result, to } => {
            assert_eq!((*command, *to), (MAV_CMD_LBV_APPLY_UPDATE, GCS));
            Some(*result)
        }
        _ => None,
    })
}

fn text_of(said: &[Outgoing]) -> Vec<String> {
    said.iter()
        .filter_map(|o| match o {
            Outgoing::Text(_, text) => Some(text.to_string()),
            _ => None,
        })
        .collect()
}

#[test]
fn apply_checks_its_preconditions_then_hands_the_image_to_the_sink() {
    let mut s = Server::new();
    let file = update_file(1, 1000);
    let said = s.apply(DISARMED, GCS, Some(0));
    assert_eq!(
        (acked(&said), text_of(&said)),
        (Some(AckResult::Denied), vec!["thruster0.lbvu: nothing to apply".into()])
    );
    // Another system: DENIED, counted, no text.
    let mut other = OTHER;
    other.component = 190;
    let said = s.apply(DISARMED, other, Some(0));
    assert!(matches!(said.as_slice(), [Outgoing::CommandAck { result: AckResult::Denied, to, .. }] if *to == other));
    assert_eq!(s.server.counters().refused, 1);
    // No such target.
    // 201: every Legacy thruster, and the table has none.
    for slot in [Some(6), Some(201), Some(202), None] {
        let said = s.apply(DISARMED, GCS, slot);
        assert_eq!(
            (acked(&said), text_of(&said)),
            (Some(AckResult::Denied), vec!["update: no such target".into()])
        );
    }
    // Still receiving.
    assert!(ack(&s.op(0, 1, CREATE, 0, THRUSTER0.as_bytes())));
    assert!(ack(&s.op(0, 1, WRITE, 0, &file[..239])));
    let said = s.apply(DISARMED, GCS, Some(0));
    assert_eq!(acked(&said), Some(AckResult::TemporarilyRejected));
    assert_eq!(text_of(&said), ["thruster0.lbvu: still receiving"]);
    for (n, chunk) in file.chunks(239).enumerate().skip(1) {
        assert!(ack(&s.op(0, 1, WRITE, (n * 239) as u32, chunk)));
    }
    // Whole, before and after the session closes; armed: not now.
    let said = s.apply(ARMED, GCS, Some(0));
    assert_eq!(acked(&said), Some(AckResult::TemporarilyRejected));
    assert_eq!(text_of(&said), ["thruster0.lbvu: disarm to update"]);
    assert!(s.images()[0].applied == 0);
    for n in 1..=2 {
        let said = s.apply(DISARMED, GCS, Some(0));
        assert_eq!(acked(&said), Some(AckResult::Accepted));
        assert_eq!(text_of(&said), ["thruster0.lbvu: valid; not sent, no I2C yet"]);
        assert_eq!(s.images()[0].applied, n);
        assert!(ack(&s.op(0, 1, TERMINATE, 0, &[])));
    }
    // Another slot, and the master: nothing there.
    assert_eq!(acked(&s.apply(DISARMED, GCS, Some(3))), Some(AckResult::Denied));
    assert_eq!(
        acked(&s.apply(DISARMED, GCS, Some(MASTER_SLOT))),
        Some(AckResult::Denied)
    );
    // The sink may fail it, or say it started.
    let mut server = UpdateServer::new(&VEHICLE.thrusters, FrameKind::Lbv300_6);
    for (target, path, kind, result, text) in [
        (
            UpdateTarget::Thruster(0),
            THRUSTER0,
            1,
            AckResult::InProgress,
            "thruster0.lbvu: applying",
        ),
        (
            UpdateTarget::Master,
            "/update/master.lbvu",
            3,
            AckResult::Failed,
            "master.lbvu: not on the target: send it again",
        ),
    ] {
        let file = update_file(kind, 152);
        let mut said = Vec::new();
        let mut out = |o| said.push(o);
        let create = payload(1, 1, CREATE, 0, path.as_bytes());
        assert!(
            server
                .request(t(0), DISARMED, GCS, &create, &mut Nowhere::default(), &mut out)
                .is_some()
        );
        let write = payload(2, 1, WRITE, 0, &file);
        assert_eq!(
            server
                .request(t(0), DISARMED, GCS, &write, &mut Nowhere::default(), &mut out)
                .map(|r| r.payload(&Contents::NOTHING)[3]),
            Some(ACK)
        );
        let terminate = payload(3, 1, TERMINATE, 0, &[]);
        assert!(
            server
                .request(t(0), DISARMED, GCS, &terminate, &mut Nowhere::default(), &mut out)
                .is_some()
        );
        assert!(server.is_received(target), "{target:?}");
        said.clear();
        server.apply(DISARMED, GCS, Some(target.slot()), &mut Nowhere::default(), &mut |o| {
            said.push(o)
        });
        assert_eq!((acked(&said), text_of(&said)), (Some(result), vec![text.to_owned()]));
    }
    // One image is held at a time: the master's replaced the thruster's.
    assert!(!server.is_received(UpdateTarget::Thruster(0)));
}

#[test]
fn a_sink_that_refuses_ends_the_upload() {
    #[derive(Default)]
    struct Picky {
        finished: Vec<bool>,
        refuse: u8,
    }
    impl UpdateSink for Picky {
        fn begin(&mut self, _: UpdateTarget, _: &ImageHeader) -> Result<(), Refused> {
            if self.refuse == 1 {
                Err(Refused::Because("picky"))
            } else {
                Ok(())
            }
        }
        fn write(&mut self, offset: u32, _: &[u8]) -> Result<(), Refused> {
            if self.refuse == 2 && offset > 500 {
                Err(Refused::Told)
            } else {
                Ok(())
            }
        }
        fn finish(&mut self, complete: bool) -> Result<(), Refused> {
            self.finished.push(complete);
            if self.refuse == 3 && complete {
                Err(Refused::Because("picky"))
            } else {
                Ok(())
            }
        }
        fn apply(&mut self, _: UpdateTarget, _: Sender) -> Result<Applied, Nak> {
            Ok(Applied::NotWired)
        }
    }
    let file = update_file(1, 1000);
    // A sink that tells its reason itself (2) gets no text from the server.
    for (refuse, finished, said) in [
        (1, vec![], vec!["thruster0.lbvu: picky"]),
        (2, vec![false], vec![]),
        (3, vec![true, false], vec!["thruster0.lbvu: picky"]),
    ] {
        let mut server = UpdateServer::new(&VEHICLE.thrusters, FrameKind::Lbv300_6);
        let mut sink = Picky {
            refuse,
            ..Picky::default()
        };
        let mut texts = Vec::new();
        let mut out = |o| {
            if let Outgoing::Text(_, text) = o {
                texts.push(text.to_string());
            }
        };
        let create = payload(1, 1, CREATE, 0, THRUSTER0.as_bytes());
        assert!(
            server
                .request(t(0), DISARMED, GCS, &create, &mut sink, &mut out)
                .is_some()
        );
        let mut last = None;
        for (n, chunk) in file.chunks(239).enumerate() {
            let write = payload(2 + n as u16, 1, WRITE, (n * 239) as u32, chunk);
            last = server.request(t(0), DISARMED, GCS, &write, &mut sink, &mut out);
            if last.is_some_and(|r| r.payload(&Contents::NOTHING)[3] == NAK) {
                break;
            }
        }
        assert_eq!(
            last.map(|r| (r.payload(&Contents::NOTHING)[3], r.payload(&Contents::NOTHING)[12])),
            Some((NAK, Nak::Fail as u8)),
            "{refuse}"
        );
        assert_eq!(texts, said, "{refuse}");
        assert_eq!(sink.finished, finished, "{refuse}");
        assert!(!server.is_received(UpdateTarget::Thruster(0)));
    }
}

#[test]
fn check_only_checks_and_applies_nothing() {
    let mut server = UpdateServer::new(&VEHICLE.thrusters, FrameKind::Lbv300_6);
    let file = update_file(1, 1000);
    let mut said = Vec::new();
    let mut out = |o| said.push(o);
    let create = payload(1, 1, CREATE, 0, THRUSTER0.as_bytes());
    server.request(t(0), DISARMED, GCS, &create, &mut CheckOnly, &mut out);
    for (n, chunk) in file.chunks(239).enumerate() {
        let write = payload(2 + n as u16, 1, WRITE, (n * 239) as u32, chunk);
        assert_eq!(
            server
                .request(t(0), DISARMED, GCS, &write, &mut CheckOnly, &mut out)
                .map(|r| r.payload(&Contents::NOTHING)[3]),
            Some(ACK)
        );
    }
    assert_eq!(server.received(UpdateTarget::Thruster(0)), (1080, ftp::crc32(0, &file)));
    said.clear();
    server.apply(DISARMED, GCS, Some(0), &mut CheckOnly, &mut |o| said.push(o));
    assert_eq!(acked(&said), Some(AckResult::Accepted));
}

/// What a client may send, in any mix.
#[derive(Debug, Clone)]
enum Step {
    Raw(Vec<u8>),
    Op {
        from_operator: bool,
        session: u8,
        opcode: u8,
        offset: u32,
        data: Vec<u8>,
    },
    Apply(Option<u8>),
    Time(u16),
    Arm(bool),
}

fn step() -> impl Strategy<Value = Step> {
    let opcode = prop_oneof![
        Just(TERMINATE),
        Just(RESET),
        Just(LIST),
        Just(CREATE),
        Just(WRITE),
        Just(REMOVE),
        Just(OPEN_WO),
        Just(CRC),
        Just(OPEN_RO),
        Just(READ),
        Just(BURST),
        any::<u8>()
    ];
    let path = prop_oneof![
        Just(THRUSTER0.as_bytes().to_vec()),
        Just(VERSIONS.to_vec()),
        Just(b"@SYS".to_vec()),
        Just(b"/update/thruster3.lbvu".to_vec()),
        Just(b"/update/master.lbvu".to_vec()),
        Just(b"/update".to_vec()),
        proptest::collection::vec(any::<u8>(), 0..40),
    ];
    let file = update_file(1, 1200);
    let data = prop_oneof![
        path,
        (0usize..1280, 1usize..240)
            .prop_map(move |(at, len)| file[at.min(file.len())..(at + len).min(file.len())].to_vec()),
    ];
    prop_oneof![
        proptest::collection::vec(any::<u8>(), 251).prop_map(Step::Raw),
        (
            any::<bool>(),
            0u8..3,
            opcode,
            prop_oneof![(0u32..1300), any::<u32>()],
            data
        )
            .prop_map(|(from_operator, session, opcode, offset, data)| Step::Op {
                from_operator,
                session,
                opcode,
                offset,
                data
            }),
        proptest::option::of(any::<u8>()).prop_map(Step::Apply),
        any::<u16>().prop_map(Step::Time),
        any::<bool>().prop_map(Step::Arm),
    ]
}

proptest! {
    /// Whatever comes, nothing panics, every request but a reply or a gap is answered with the request's
    /// sequence + 1 and session, the sink only ever gets bytes in order (the recorder refuses any other), and a
    /// text never says the sink refused.
    #[test]
    fn any_requests_in_any_order(steps in proptest::collection::vec(step(), 0..200)) {
        let mut s = Server::new();
        let mut ms = 0u64;
        let mut context = DISARMED;
        for (n, step) in steps.into_iter().enumerate() {
            let seq = n as u16;
            match step {
                Step::Raw(bytes) => {
                    let p: FtpPayload = bytes.try_into().unwrap();
                    if let Some(reply) = s.send(ms, context, GCS, &p) {
                        prop_assert_eq!(reply.seq, u16::from_le_bytes([p[0], p[1]]).wrapping_add(1));
                        prop_assert_eq!((reply.session, reply.req_opcode), (p[2], p[3]));
                    }
                }
                Step::Op { from_operator, session, opcode, offset, data } => {
                    let from = if from_operator { GCS } else { OTHER };
                    let p = payload(seq, session, opcode, offset, &data);
                    if let Some(reply) = s.send(ms, context, from, &p) {
                        prop_assert_eq!((reply.seq, reply.session, reply.req_opcode), (seq.wrapping_add(1), session, opcode));
                        prop_assert!(reply.opcode == ACK || reply.opcode == NAK);
                    } else {
                        prop_assert!(opcode == WRITE || opcode == ACK || opcode == NAK);
                    }
                }
                Step::Apply(slot) => {
                    let said = s.apply(context, GCS, slot);
                    prop_assert!(acked(&said).is_some());
                }
                Step::Time(dt) => ms += u64::from(dt),
                Step::Arm(armed) => context.armed = armed,
            }
        }
        // The recorder refuses writes out of order and a second finish: the server never makes them.
        prop_assert!(
            s.texts().iter().all(|t| !t.contains("out of order") && !t.contains("finished twice")),
            "{:?}",
            s.texts()
        );
        for image in s.images() {
            prop_assert!(image.bytes.len() <= HEADER_LEN + THRUSTER_MAX_PAYLOAD as usize);
        }
    }
}

#[test]
fn a_version_query_goes_to_the_sink_for_the_operator_and_a_thruster_slot_only() {
    let mut server = UpdateServer::new(&VEHICLE.thrusters, FrameKind::Lbv300_6);
    let mut sink = Nowhere::default();
    let mut ask = |context, from, slot| {
        let mut said = Vec::new();
        server.query_version(context, from, slot, &mut sink, &mut |o| said.push(o));
        let ack = said.iter().find_map(|o| match o {
            Outgoing::CommandAck { command, result, .. } => Some((*command, *result)),
            _ => None,
        });
        (
            ack.map(|(_, result)| result),
            ack.map(|(command, _)| command),
            text_of(&said),
        )
    };
    let query = Some(MAV_CMD_LBV_QUERY_VERSION);
    // Armed or not: the thruster answers `Version` whatever it does.
    assert_eq!(ask(ARMED, GCS, Some(1)), (Some(AckResult::InProgress), query, vec![]));
    assert_eq!(
        ask(DISARMED, GCS, Some(2)),
        (
            Some(AckResult::TemporarilyRejected),
            query,
            vec!["thruster2.lbvu: wait: an update is under way".to_owned()]
        )
    );
    assert_eq!(ask(DISARMED, OTHER, Some(1)), (Some(AckResult::Denied), query, vec![]));
    assert_eq!(
        ask(DISARMED, GCS, Some(MASTER_SLOT)),
        (
            Some(AckResult::Denied),
            query,
            vec!["update: the master's is in AUTOPILOT_VERSION".to_owned()]
        )
    );
    for nowhere in [Some(200), None] {
        assert_eq!(
            ask(DISARMED, GCS, nowhere),
            (
                Some(AckResult::Denied),
                query,
                vec!["update: no such target".to_owned()]
            )
        );
    }
    assert_eq!(
        sink.queried,
        [1, 2],
        "only the operator's queries of thruster slots reach the sink"
    );
}

/// A sink whose apply is under way already, for `by`; it counts the times it was asked to publish its holds, and
/// publishes an apply of thruster 0.
struct UnderWay {
    by: Sender,
    published: core::cell::Cell<u32>,
}

impl UpdateSink for UnderWay {
    fn begin(&mut self, _: UpdateTarget, _: &ImageHeader) -> Result<(), Refused> {
        Ok(())
    }
    fn write(&mut self, _: u32, _: &[u8]) -> Result<(), Refused> {
        Ok(())
    }
    fn finish(&mut self, _: bool) -> Result<(), Refused> {
        Ok(())
    }
    fn apply(&mut self, _: UpdateTarget, _: Sender) -> Result<Applied, Nak> {
        Ok(Applied::Applying(self.by))
    }
    fn publish(&self, holds: &UpdateHolds) {
        self.published.set(self.published.get() + 1);
        holds.set_thrusters(Some(crate::shared::UpdateHold::Applying(0)));
    }
}

#[test]
fn a_second_apply_while_one_runs_is_answered_as_the_one_under_way_never_failed() {
    let mut server = UpdateServer::new(&VEHICLE.thrusters, FrameKind::Lbv300_6);
    let mut sink = UnderWay {
        by: GCS,
        published: core::cell::Cell::new(0),
    };
    // An image held whole for each target, as the first apply found it.
    for (path, kind) in [(THRUSTER0, 1), ("/update/master.lbvu", 3)] {
        let file = update_file(kind, 152);
        for (seq, opcode, data) in [
            (1, CREATE, path.as_bytes()),
            (2, WRITE, &file[..]),
            (3, TERMINATE, &[][..]),
        ] {
            let request = payload(seq, 1, opcode, 0, data);
            assert!(
                server
                    .request(t(0), DISARMED, GCS, &request, &mut sink, &mut |_| {})
                    .is_some()
            );
        }
        let target = if kind == 3 { MASTER_SLOT } else { 0 };
        let name = path.trim_start_matches("/update/");
        // The same requester (its answer lost, say) twice: IN_PROGRESS, the final answer to follow.
        for _ in 0..2 {
            let mut said = Vec::new();
            server.apply(DISARMED, GCS, Some(target), &mut sink, &mut |o| said.push(o));
            assert_eq!(
                (acked(&said), text_of(&said)),
                (Some(AckResult::InProgress), vec![format!("{name}: applying")])
            );
        }
        // Another component of the operator's system: not its apply.
        let companion = Sender {
            system: GCS.system,
            component: 1,
        };
        let mut said = Vec::new();
        server.apply(DISARMED, companion, Some(target), &mut sink, &mut |o| said.push(o));
        assert!(matches!(
            said.as_slice(),
            [Outgoing::CommandAck { result: AckResult::TemporarilyRejected, to, .. }, Outgoing::Text(_, text)]
                if *to == companion && text.as_str() == format!("{name}: applying")
        ));
        // Armed, as ever: not now.
        let mut said = Vec::new();
        server.apply(ARMED, GCS, Some(target), &mut sink, &mut |o| said.push(o));
        assert_eq!(acked(&said), Some(AckResult::TemporarilyRejected));
        assert_eq!(text_of(&said), [format!("{name}: disarm to update")]);
    }
}

#[test]
fn the_update_server_has_the_sink_publish_its_holds_as_soon_as_an_apply_command_is_served() {
    let shared = Shared::new();
    let mut updates = Updates::new(
        &VEHICLE.thrusters,
        FrameKind::Lbv300_6,
        UnderWay {
            by: GCS,
            published: core::cell::Cell::new(0),
        },
    );
    let request = UpdateRequest {
        from: GCS,
        what: UpdateCommand::Apply(Some(0)),
    };
    assert_eq!(updates.serve(request, &shared), None);
    // Before any other task runs: an arm command read next finds the vehicle held.
    assert_eq!(updates.sink.published.get(), 1);
    assert_eq!(shared.holds.get(), Some(crate::shared::UpdateHold::Applying(0)));
    // Not for the other requests.
    let query = UpdateRequest {
        from: GCS,
        what: UpdateCommand::QueryVersion(Some(0)),
    };
    updates.serve(query, &shared);
    assert_eq!(updates.sink.published.get(), 1);
}

#[test]
fn the_black_box_is_listed_read_past_64_kib_and_held_while_the_operator_reads_it() {
    use crate::blackbox::{BlackBox, HOLD, PERIOD};
    use crate::console::tlog::{Event, layout, record, tests::sample};
    let shared = Shared::new();
    // The operator's ground station is GCS's system.
    shared.vehicle.sender().send(crate::shared::VehicleState {
        operator: GCS.system,
        ..crate::shared::VehicleState::READY
    });
    let mut updates = Updates::new(&VEHICLE.thrusters, FrameKind::Lbv300_6, CheckOnly);
    let from = |from: Sender| {
        move |seq, opcode, offset: u32, data: &[u8]| UpdateRequest {
            from,
            what: UpdateCommand::Ftp(payload(seq, 1, opcode, offset, data)),
        }
    };
    let ftp = from(GCS);
    let ack_data = |answer: Option<Outgoing>| match answer {
        Some(Outgoing::Ftp {
            reply: FtpAnswer::Reply(r),
            ..
        }) => (r[3], r[12..12 + usize::from(r[4])].to_vec()),
        other => panic!("a reply: {other:?}"),
    };
    // Without a region there is no file.
    assert_eq!(ack_data(updates.serve(ftp(1, LIST, 2, b"@SYS"), &shared)).0, NAK);
    assert_eq!(
        ack_data(updates.serve(ftp(2, OPEN_RO, 0, b"@SYS/blackbox.tlog"), &shared)).0,
        NAK
    );
    shared
        .black_box
        .keep(Box::leak(Box::new(BlackBox::new())), Instant::from_ticks(0), 6);
    shared.black_box.lay_out(layout(6));
    // A minute of samples, with the master's start marked: a file past 64 KiB.
    let t0 = Instant::from_secs(1);
    for n in 0..600 {
        let event = (n == 0).then_some(Event::Started);
        assert!(record(&shared.black_box, t0 + PERIOD * n, sample(n, event)));
    }
    let (answer, listed) = ack_data(updates.serve(ftp(3, LIST, 2, b"@SYS"), &shared));
    let len = shared.black_box.open().unwrap().len();
    assert!(len > 64 * 1024);
    assert_eq!((answer, listed), (ACK, format!("Fblackbox.tlog\t{len}\0").into_bytes()));
    let (answer, opened) = ack_data(updates.serve(ftp(4, OPEN_RO, 0, b"@SYS/blackbox.tlog"), &shared));
    assert_eq!((answer, opened), (ACK, len.to_le_bytes().to_vec()));
    // From the open on, the samples are held: none is recorded.
    let now = Instant::now();
    assert!(!record(&shared.black_box, now + PERIOD, sample(600, None)));
    // A read past 64 KiB: the offset whole in the reply's header, the bytes those of the file there.
    let offset = 70_000;
    let Some(Outgoing::Ftp { reply, .. }) = updates.serve(ftp(5, BURST, offset, &[0; 239]), &shared) else {
        panic!("a read of the black box");
    };
    let read =
        |file: &_, offset, into: &mut [u8]| crate::console::tlog::read(&shared.black_box, file, offset, into, (1, 1));
    let contents = Contents {
        black_box: Some(&read),
        ..Contents::NOTHING
    };
    let framed = reply.payload(&contents);
    assert_eq!(framed[..12], [6, 0, 1, ACK, 239, BURST, 1, 0, 0x70, 0x11, 0x01, 0]);
    let file = shared.black_box.open().unwrap();
    let mut expected = [0u8; 239];
    assert_eq!(read(&file, offset, &mut expected), Some(239));
    assert_eq!(framed[12..251], expected);
    // The session's end lets the recording go on.
    assert_eq!(ack_data(updates.serve(ftp(6, TERMINATE, 0, &[]), &shared)).0, ACK);
    assert!(record(&shared.black_box, now + PERIOD, sample(600, None)));
    // A session that reads on holds them until HOLD after its last read.
    assert_eq!(
        ack_data(updates.serve(ftp(7, OPEN_RO, 0, b"@SYS/blackbox.tlog"), &shared)).0,
        ACK
    );
    let read_at = Instant::now();
    assert!(!record(&shared.black_box, read_at + HOLD - PERIOD, sample(601, None)));
    assert!(record(&shared.black_box, read_at + HOLD, sample(601, None)));
    assert_eq!(ack_data(updates.serve(ftp(8, TERMINATE, 0, &[]), &shared)).0, ACK);
    // Another system reads it too, and holds nothing: it cannot keep the vehicle from recording.
    let other = from(OTHER);
    assert_eq!(
        ack_data(updates.serve(other(9, OPEN_RO, 0, b"@SYS/blackbox.tlog"), &shared)).0,
        ACK
    );
    assert!(matches!(
        updates.serve(other(10, BURST, 0, &[0; 239]), &shared),
        Some(Outgoing::Ftp {
            reply: FtpAnswer::Read(_),
            ..
        })
    ));
    assert!(record(&shared.black_box, read_at + HOLD + PERIOD, sample(602, None)));
}
