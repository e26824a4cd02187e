//! The update server's MAVLink FTP decoder and state machine: any FILE_TRANSFER_PROTOCOL payloads (raw bytes, or
//! well-formed requests of the opcodes it serves, with paths and image bytes that reach every branch, reads of
//! `@SYS/versions.txt` and `@PARAM/param.pck` with any query among them), from the operator or another system,
//! armed or not, as time passes, with apply commands and parameters set between, and at any moment the master
//! marked to restart into its own update, and the link's signing going off and on. Nothing panics; every reply
//! answers its request (sequence + 1, its session and opcode, ACK or NAK), a read of `versions.txt` is the text's
//! bytes at its offset, a read of `param.pck` is NAKed once a parameter has changed since it was opened; the sink gets each image's bytes in order, from its header
//! on, never beyond the length the header gives, nothing begun, written or applied once the master restarts, and
//! nothing begun or written over a link without signing.
#![no_main]

use arbitrary::Arbitrary;
use embassy_time::Instant;
use lbv_master_fw::config::VEHICLE;
use lbv_master_fw::mixer::FrameKind;
use lbv_master_fw::params::Param;
use lbv_master_fw::ports::{Applied, Refused, UpdateSink, UpdateTarget};
use lbv_master_fw::shared::{Outgoing, Sender};
use lbv_master_fw::update::ftp::{ACK, NAK, Nak};
use lbv_master_fw::update::{Context, Contents, FtpAnswer, HEADER_LEN, ImageHeader, UpdateServer};
// The host's time driver (the harness passes its own instants).
use lbv_sim as _;
use libfuzzer_sys::fuzz_target;

#[derive(Arbitrary, Debug)]
enum Step {
    Raw { operator: bool, payload: Vec<u8> },
    Request { operator: bool, session: u8, opcode: Opcode, offset: u32, data: Data },
    Apply { operator: bool, slot: Option<u8> },
    Wait(u16),
    Arm(bool),
    /// The master's own image is marked: it restarts into it (for good).
    Restart,
    /// The link's signing goes off (`true`: updates over it refused) or on.
    Unsigned(bool),
    /// A parameter is set (to a value it takes).
    SetParam { index: u8, value: i32 },
}

#[derive(Arbitrary, Debug, Clone, Copy)]
enum Opcode {
    Terminate,
    Reset,
    List,
    Create,
    Write,
    Remove,
    OpenWo,
    Crc,
    OpenRo,
    Read,
    Burst,
    Other(u8),
}

#[derive(Arbitrary, Debug)]
enum Data {
    Path(Path),
    /// Bytes of a valid-looking image, from `at`.
    Image { at: u16, len: u8 },
    Bytes(Vec<u8>),
}

#[derive(Arbitrary, Debug)]
enum Path {
    Thruster(u8),
    Master,
    Dir,
    Root,
    Sys,
    Versions,
    ParamDir,
    /// `@PARAM/param.pck` and these bytes after it.
    Params(Vec<u8>),
}

/// A SeaBotix image of 1200 payload bytes.
fn image() -> Vec<u8> {
    let mut file = b"LBVU".to_vec();
    file.extend([1, 1, 0, 0]);
    file.extend(1200u32.to_le_bytes());
    file.extend([0; 68]);
    file.extend((0..1200u32).map(|n| n as u8));
    file
}

/// Checks the server's promises to its sink.
#[derive(Default)]
struct Sink {
    /// The image under way: its next byte and length.
    open: Option<(u32, u32)>,
    /// The master restarts into its own update: nothing may change.
    restarting: bool,
    /// The link is not signed: nothing may begin or be written.
    unsigned: bool,
}

impl UpdateSink for Sink {
    fn begin(&mut self, _: UpdateTarget, header: &ImageHeader) -> Result<(), Refused> {
        assert!(!self.restarting, "begun while the master restarts");
        assert!(!self.unsigned, "begun over a link without signing");
        assert!(self.open.is_none(), "begun twice");
        self.open = Some((HEADER_LEN as u32, header.file_len()));
        Ok(())
    }

    fn write(&mut self, offset: u32, data: &[u8]) -> Result<(), Refused> {
        assert!(!self.restarting, "written while the master restarts");
        assert!(!self.unsigned, "written over a link without signing");
        let (next, total) = self.open.expect("a write outside an image");
        assert_eq!(offset, next, "out of order");
        assert!(u64::from(offset) + data.len() as u64 <= u64::from(total), "past the header's length");
        self.open = Some((next + data.len() as u32, total));
        Ok(())
    }

    fn finish(&mut self, complete: bool) -> Result<(), Refused> {
        let (next, total) = self.open.take().expect("finished, never begun");
        assert!(!complete || next == total, "whole at {next} of {total}");
        Ok(())
    }

    fn apply(&mut self, _: UpdateTarget, _: Sender) -> Result<Applied, Nak> {
        assert!(!self.restarting, "applied while the master restarts");
        Ok(Applied::NotWired)
    }
}

fn payload(seq: u16, session: u8, opcode: u8, offset: u32, data: &[u8]) -> [u8; 251] {
    let mut p = [0u8; 251];
    let data = &data[..data.len().min(239)];
    p[..2].copy_from_slice(&seq.to_le_bytes());
    p[2] = session;
    p[3] = opcode;
    p[4] = data.len() as u8;
    p[8..12].copy_from_slice(&offset.to_le_bytes());
    p[12..12 + data.len()].copy_from_slice(data);
    p
}

fuzz_target!(|steps: Vec<Step>| {
    let gcs = Sender { system: 255, component: 190 };
    let other = Sender { system: 7, component: 1 };
    let file = image();
    let mut server = UpdateServer::new(&VEHICLE.thrusters, FrameKind::Lbv300_6);
    let mut sink = Sink::default();
    let mut params = VEHICLE.vehicle.defaults().params;
    let mut context = Context { armed: false, operator: 255, restarting: false, unsigned: false, params: Some(params), crash: false, post_mortems: 0b101, black_box: None };
    // What the last file opened for reading is: param.pck (with the values it was opened with) or versions.txt.
    let mut opened = None;
    let mut now = Instant::from_ticks(0);
    let mut out = |_: Outgoing| {};
    // What the fuzzing sink knows of the boards: nothing.
    let unknown: String = (1..=6).map(|n| format!("T{n}     SeaBotix -        unknown\n")).collect();
    let versions = format!("board  family   version  state\nmaster -        -        unknown\n{unknown}").into_bytes();
    for (n, step) in steps.into_iter().enumerate() {
        let seq = n as u16;
        let (from, request) = match step {
            Step::Raw { operator, payload } => {
                let mut p = [0u8; 251];
                for (to, from) in p.iter_mut().zip(payload) {
                    *to = from;
                }
                (if operator { gcs } else { other }, p)
            }
            Step::Request { operator, session, opcode, offset, data } => {
                let opcode = match opcode {
                    Opcode::Terminate => 1,
                    Opcode::Reset => 2,
                    Opcode::List => 3,
                    Opcode::Create => 6,
                    Opcode::Write => 7,
                    Opcode::Remove => 8,
                    Opcode::OpenWo => 11,
                    Opcode::Crc => 14,
                    Opcode::OpenRo => 4,
                    Opcode::Read => 5,
                    Opcode::Burst => 15,
                    Opcode::Other(byte) => byte,
                };
                let bytes = match data {
                    Data::Path(Path::Thruster(slot)) => format!("/update/thruster{}.lbvu", slot % 10).into_bytes(),
                    Data::Path(Path::Master) => b"/update/master.lbvu".to_vec(),
                    Data::Path(Path::Dir) => b"/update".to_vec(),
                    Data::Path(Path::Root) => b"/".to_vec(),
                    Data::Path(Path::Sys) => b"@SYS".to_vec(),
                    Data::Path(Path::Versions) => b"@SYS/versions.txt".to_vec(),
                    Data::Path(Path::ParamDir) => b"@PARAM".to_vec(),
                    Data::Path(Path::Params(query)) => [&b"@PARAM/param.pck"[..], &query].concat(),
                    Data::Image { at, len } => {
                        let at = usize::from(at).min(file.len());
                        file[at..(at + usize::from(len)).min(file.len())].to_vec()
                    }
                    Data::Bytes(bytes) => bytes,
                };
                (if operator { gcs } else { other }, payload(seq, session % 4, opcode, offset % 1400, &bytes))
            }
            Step::Apply { operator, slot } => {
                server.apply(context, if operator { gcs } else { other }, slot, &mut sink, &mut out);
                continue;
            }
            Step::Wait(ms) => {
                now += embassy_time::Duration::from_millis(u64::from(ms));
                continue;
            }
            Step::Arm(armed) => {
                context.armed = armed;
                continue;
            }
            Step::Restart => {
                context.restarting = true;
                sink.restarting = true;
                continue;
            }
            Step::Unsigned(unsigned) => {
                context.unsigned = unsigned;
                sink.unsigned = unsigned;
                continue;
            }
            Step::SetParam { index, value } => {
                params.set(Param::ALL[usize::from(index) % Param::ALL.len()], value);
                context.params = Some(params);
                continue;
            }
        };
        if let Some(answer) = server.request(now, context, from, &request, &mut sink, &mut out) {
            let reply = answer.payload(&Contents { params: context.params.as_ref(), crash: None, black_box: None });
            let seq = u16::from_le_bytes([request[0], request[1]]);
            assert_eq!(u16::from_le_bytes([reply[0], reply[1]]), seq.wrapping_add(1));
            assert_eq!((reply[2], reply[5]), (request[2], request[3]));
            assert!(reply[3] == ACK || reply[3] == NAK);
            let size = usize::from(reply[4]);
            assert!(size <= reply.len() - 12);
            if request[3] == 4 && reply[3] == ACK {
                opened = Some(request[12..].starts_with(b"@PARAM").then_some(params));
            }
            match (answer, opened) {
                (FtpAnswer::Read(_), Some(Some(at_open))) if at_open != params => {
                    assert_eq!((reply[3], reply[12]), (NAK, Nak::Fail as u8), "a read of a file since changed");
                }
                (FtpAnswer::Read(_), Some(Some(_))) => {
                    assert_eq!(reply[3], ACK);
                    assert!(size > 0 && size <= usize::from(request[4]));
                }
                (FtpAnswer::Read(_), _) => {
                    // The text's bytes from the offset asked, no more than asked.
                    assert_eq!(reply[3], ACK);
                    assert!(size > 0 && size <= usize::from(request[4]));
                    let offset = u32::from_le_bytes([reply[8], reply[9], reply[10], reply[11]]) as usize;
                    let text = versions.get(offset..offset + size).expect("within the text");
                    assert_eq!(&reply[12..12 + size], text);
                }
                _ => {}
            }
        }
    }
});
