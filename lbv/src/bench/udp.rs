//! The console link over UDP, for an outside ground station (QGroundControl, a pymavlink script), with the bench
//! paced to the wall clock.
//!
//! Ground-station convention: the vehicle sends its MAVLink to the station's port (14550) and the station answers
//! to the address the datagrams came from, so one socket does both: bound to the listen address, it sends every
//! byte the master writes to the send address and feeds the frames of every datagram it receives into the
//! master's console.
//!
//! Each datagram is parsed on its own, as a MAVLink router does: its whole frames go to the console, and bytes
//! that make no frame are dropped at its end, so a broken datagram cannot hide the frames of the next one.
//!
//! The console is a serial line (115200 baud for `lbv bench --udp`) and a socket can bring far more than it
//! carries: the frames wait in a small inbox per sender address ([`INBOX`] bytes), which the line takes in turn,
//! a frame at a time, so that one sender's flood cannot starve another's orders; a frame that finds its inbox full
//! is dropped and counted, as a router in front of a radio does. The master's output goes out a frame per
//! datagram, as ArduPilot and MAVProxy send it.

use std::cell::{Cell, RefCell};
use std::collections::VecDeque;
use std::io::{self, ErrorKind, Write};
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4, UdpSocket};
use std::path::Path;
use std::rc::Rc;
use std::time::Instant as WallInstant;

use embassy_time::{Duration, Instant};
use lbv_master_fw::console::framing::{Event, FrameParser};
use lbv_master_fw::console::inbound;

use super::Bench;

/// Where QGroundControl and `pymavlink udpin:0.0.0.0:14550` listen.
pub const DEFAULT_SEND: SocketAddr = SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, 14550));
/// Where the bench listens for the station's answers.
pub const DEFAULT_LISTEN: SocketAddr = SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, 14551));
/// The console's baud rate on `lbv bench --udp`: the master's LPUART1 as its binding sets it.
pub const CONSOLE_BAUD: u32 = 115_200;
/// Virtual time run between looks at the socket and the wall clock.
const SLICE: Duration = Duration::from_millis(1);
/// How far virtual time may fall behind the wall clock before the difference is given up rather than caught up
/// in a burst (a burst would squeeze the station's 1 Hz heartbeats together and let the console failsafe act).
const MAX_LAG: std::time::Duration = std::time::Duration::from_millis(100);
/// Larger than any MAVLink frame, and than what a station packs into one datagram.
const DATAGRAM: usize = 2048;
/// Bytes of frames held for each sender while the line is busy: about 180 ms of the line at 115200 baud, several
/// of the largest frames.
pub const INBOX: usize = 2048;
/// Senders held apart; frames from more (each with frames waiting) are dropped.
const SENDERS: usize = 8;
/// Bytes kept handed to the line ahead of it, so that it does not fall idle between two looks at the socket (it
/// carries 11.5 bytes in a [`SLICE`] at 115200 baud); a whole frame goes at once, so the backlog stays below this
/// and one frame.
const AHEAD: usize = 64;

/// Datagram counters of the link.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LinkCounters {
    /// Datagrams received.
    pub datagrams_in: u64,
    /// Bytes of received datagrams that made no whole frame, dropped.
    pub dropped_bytes: u64,
    /// Bytes of whole frames dropped because their sender's inbox was full (it sent more than the line carries)
    /// or every inbox was taken.
    pub inbox_dropped: u64,
    /// Bytes the master's UART lost to its full receive buffer (an overrun).
    pub overruns: u64,
    /// Datagrams sent, one frame each.
    pub datagrams_out: u64,
    /// Bytes of the master's output not delivered: making no frame, or in a send that failed.
    pub out_dropped: u64,
    /// Sends that failed (nobody listening shows as one on some systems).
    pub send_errors: u64,
    /// Receives that failed (other than nothing to read).
    pub errors: u64,
}

/// The frames waiting for the line, per sender address.
#[derive(Debug, Default)]
struct Inboxes {
    senders: Vec<Inbox>,
    /// Where the next look for a frame starts: the senders take turns.
    turn: usize,
}

#[derive(Debug)]
struct Inbox {
    from: SocketAddr,
    frames: VecDeque<Vec<u8>>,
    bytes: usize,
}

impl Inboxes {
    /// Queue `frame` from `from`; `false` when it is dropped (its inbox full, or every inbox taken by others with
    /// frames waiting).
    fn push(&mut self, from: SocketAddr, frame: &[u8]) -> bool {
        let at = match self.senders.iter().position(|inbox| inbox.from == from) {
            Some(at) => at,
            None => match self.senders.iter().position(|inbox| inbox.frames.is_empty()) {
                Some(at) => at,
                None if self.senders.len() < SENDERS => {
                    self.senders.push(Inbox {
                        from,
                        frames: VecDeque::new(),
                        bytes: 0,
                    });
                    self.senders.len() - 1
                }
                None => return false,
            },
        };
        let Some(inbox) = self.senders.get_mut(at) else {
            return false;
        };
        inbox.from = from;
        if inbox.bytes + frame.len() > INBOX {
            return false;
        }
        inbox.bytes += frame.len();
        inbox.frames.push_back(frame.to_vec());
        true
    }

    /// The next sender's oldest frame, in turn.
    fn pop(&mut self) -> Option<Vec<u8>> {
        let count = self.senders.len();
        for k in 0..count {
            let at = (self.turn + k) % count;
            let Some(inbox) = self.senders.get_mut(at) else {
                continue;
            };
            if let Some(frame) = inbox.frames.pop_front() {
                inbox.bytes -= frame.len();
                self.turn = (at + 1) % count;
                return Some(frame);
            }
        }
        None
    }
}

/// Cuts the master's output into its frames, keeping a frame cut at the end of one call for the next: the output
/// is the master's own framing, so a frame's length is its header's.
#[derive(Debug, Default)]
pub struct FrameSplitter {
    pending: Vec<u8>,
}

impl FrameSplitter {
    /// Take `bytes`: `frame` gets each frame completed, in order. Returns the bytes dropped (found where a frame
    /// should start and not starting one).
    pub fn push(&mut self, bytes: &[u8], mut frame: impl FnMut(&[u8])) -> usize {
        let mut dropped = 0;
        for &byte in bytes {
            if self.pending.is_empty() && byte != 0xFD && byte != 0xFE {
                dropped += 1;
                continue;
            }
            self.pending.push(byte);
            if frame_len(&self.pending) == Some(self.pending.len()) {
                frame(&self.pending);
                self.pending.clear();
            }
        }
        dropped
    }
}

/// The length of the frame `head` starts, once its header is there.
fn frame_len(head: &[u8]) -> Option<usize> {
    match *head {
        [0xFD, len, incompat, ..] => Some(10 + usize::from(len) + 2 + if incompat & 1 != 0 { 13 } else { 0 }),
        [0xFE, len, ..] => Some(6 + usize::from(len) + 2),
        _ => None,
    }
}

/// The console's UDP socket.
#[derive(Debug)]
pub struct UdpLink {
    socket: UdpSocket,
    send_to: SocketAddr,
    counters: Rc<Cell<LinkCounters>>,
    inboxes: RefCell<Inboxes>,
}

impl UdpLink {
    /// Bind `listen` and send to `send_to`.
    pub fn open(listen: SocketAddr, send_to: SocketAddr) -> io::Result<Self> {
        let socket = UdpSocket::bind(listen)?;
        socket.set_nonblocking(true)?;
        Ok(Self {
            socket,
            send_to,
            counters: Rc::default(),
            inboxes: RefCell::default(),
        })
    }

    /// The address actually bound (the port the system chose when `listen` gave 0).
    pub fn local_addr(&self) -> io::Result<SocketAddr> {
        self.socket.local_addr()
    }

    /// The counters so far.
    pub fn counters(&self) -> LinkCounters {
        self.counters.get()
    }

    /// Give the bench's console link to this socket: the scripted ground station falls silent and the master's
    /// output is sent as it is written, a frame per datagram.
    pub fn attach(&self, bench: &mut Bench) -> io::Result<()> {
        let socket = self.socket.try_clone()?;
        let send_to = self.send_to;
        let counters = Rc::clone(&self.counters);
        let mut splitter = FrameSplitter::default();
        bench.console_sink = Some(Box::new(move |bytes: &[u8]| {
            let mut count = counters.get();
            let dropped = splitter.push(bytes, |frame| {
                // Nobody listening (the station not started yet) is not an error worth stopping for.
                match socket.send_to(frame, send_to) {
                    Ok(_) => count.datagrams_out += 1,
                    Err(_) => {
                        count.send_errors += 1;
                        count.out_dropped += frame.len() as u64;
                    }
                }
            });
            count.out_dropped += dropped as u64;
            counters.set(count);
        }));
        Ok(())
    }

    /// Take every datagram waiting into the inboxes, and hand the console the frames its line has room for.
    pub fn receive(&self, bench: &mut Bench) {
        let mut buf = [0u8; DATAGRAM];
        let mut count = self.counters.get();
        let mut inboxes = self.inboxes.borrow_mut();
        loop {
            match self.socket.recv_from(&mut buf) {
                Ok((n, from)) => {
                    count.datagrams_in += 1;
                    let datagram = buf.get(..n).unwrap_or_default();
                    count.dropped_bytes += each_frame(datagram, |frame| {
                        if !inboxes.push(from, frame) {
                            count.inbox_dropped += frame.len() as u64;
                        }
                    }) as u64;
                }
                Err(error) if error.kind() == ErrorKind::WouldBlock => break,
                // An ICMP "port unreachable" for an earlier send (no station listening yet) shows up here on some
                // systems; it is not about this read.
                Err(error)
                    if matches!(
                        error.kind(),
                        ErrorKind::Interrupted | ErrorKind::ConnectionRefused | ErrorKind::ConnectionReset
                    ) => {}
                Err(_) => {
                    count.errors += 1;
                    break;
                }
            }
        }
        // A console without a modelled line carries everything at once.
        while bench.console_backlog().is_none_or(|backlog| backlog < AHEAD) {
            let Some(frame) = inboxes.pop() else { break };
            bench.send(frame);
        }
        count.overruns = bench.console_overruns();
        self.counters.set(count);
    }
}

/// The whole frames of one datagram, in order (those of messages outside the master's dialect too, framed by
/// their length), and how many of its bytes made no frame.
#[cfg(test)]
fn frames_of(datagram: &[u8]) -> (Vec<u8>, usize) {
    let mut frames = Vec::with_capacity(datagram.len());
    let dropped = each_frame(datagram, |frame| frames.extend_from_slice(frame));
    (frames, dropped)
}

/// Give `frame` each whole frame of one datagram, in order; returns how many of its bytes made no frame.
fn each_frame(datagram: &[u8], mut frame: impl FnMut(&[u8])) -> usize {
    let mut parser = FrameParser::new();
    let mut framed = 0;
    let mut rest = datagram;
    loop {
        let taken = parser.push(rest);
        rest = rest.get(taken..).unwrap_or_default();
        if rest.is_empty() {
            parser.end_of_input();
        }
        while let Some(event) = parser.next(inbound::extra_crc) {
            if let Event::Frame(whole) | Event::Unknown(whole) = event {
                framed += whole.bytes.len();
                frame(whole.bytes);
            }
        }
        if rest.is_empty() {
            break;
        }
    }
    datagram.len() - framed
}

/// Keeps virtual time from running ahead of the wall clock; when the machine is too slow, virtual time falls
/// behind and the run goes as fast as it can.
#[derive(Debug)]
pub struct WallClock {
    wall_start: WallInstant,
    virtual_start: Instant,
    /// Wall time given up because the bench could not keep pace.
    lost: std::time::Duration,
}

impl WallClock {
    /// Start pacing now, from the bench's present virtual time.
    pub fn start(bench: &Bench) -> Self {
        Self {
            wall_start: WallInstant::now(),
            virtual_start: bench.now(),
            lost: std::time::Duration::ZERO,
        }
    }

    /// Sleep while the bench is ahead of the wall clock; note any lag beyond [`MAX_LAG`] as lost.
    pub fn hold(&mut self, bench: &Bench) {
        let simulated = std::time::Duration::from_micros((bench.now() - self.virtual_start).as_micros()) + self.lost;
        let wall = self.wall_start.elapsed();
        if let Some(ahead) = simulated.checked_sub(wall) {
            std::thread::sleep(ahead);
        } else if let Some(excess) = (wall - simulated).checked_sub(MAX_LAG) {
            self.lost += excess;
        }
    }

    /// Wall time given up so far because the bench could not keep pace.
    pub fn lost(&self) -> std::time::Duration {
        self.lost
    }

    /// Wall time since the start.
    pub fn elapsed(&self) -> std::time::Duration {
        self.wall_start.elapsed()
    }
}

/// Run the bench in real time with its console on `link`, for `duration` of virtual time or until the process
/// is stopped; with `status`, print a line every second (armed, each thruster's rpm, datagrams); with
/// `update_dir`, write there each update image the master's sink has finished ([`write_images`]); with `trace`,
/// write there each sample of the trace as a line of JSON as it comes (the bench must keep its samples:
/// [`Bench::keep_samples`]). Returns the pacing.
pub fn serve(
    bench: &mut Bench,
    link: &UdpLink,
    duration: Option<Duration>,
    status: bool,
    update_dir: Option<&Path>,
    mut trace: Option<&mut dyn Write>,
) -> io::Result<WallClock> {
    link.attach(bench)?;
    let end = duration.map(|duration| bench.now() + duration);
    let mut clock = WallClock::start(bench);
    let mut next_status = bench.now();
    let mut written = 0;
    while end.is_none_or(|end| bench.now() < end) {
        link.receive(bench);
        bench.run_for(SLICE);
        // Samples go to the trace file, if any, and are not kept: memory stays flat however long it runs.
        if let Some(out) = trace.as_deref_mut() {
            for sample in &bench.trace.samples {
                serde_json::to_writer(&mut *out, sample)?;
                out.write_all(b"\n")?;
            }
            out.flush()?;
        }
        bench.trace.samples.clear();
        if status && bench.now() >= next_status {
            next_status += Duration::from_secs(1);
            status_line(bench, link.counters());
        }
        if let Some(dir) = update_dir {
            written = write_images(bench, dir, written)?;
        }
        clock.hold(bench);
    }
    Ok(clock)
}

/// Write the update images the master's sink has finished since the first `written` ones to `dir`, each as
/// `<file>` (`thruster0.lbvu`, `master.lbvu`) when it came whole, `<file>.stopped` when it was stopped, with a
/// line on standard output; returns how many are written now. A later image for the same file replaces it.
pub fn write_images(bench: &Bench, dir: &Path, written: usize) -> io::Result<usize> {
    let images = bench.master.updates.images();
    let finished = images.iter().take_while(|image| image.complete.is_some()).count();
    for image in images.iter().take(finished).skip(written) {
        let name = image.target.to_string();
        let name = if image.complete == Some(true) {
            name
        } else {
            format!("{name}.stopped")
        };
        std::fs::write(dir.join(&name), &image.bytes)?;
        let mut out = io::stdout().lock();
        let _ = writeln!(
            out,
            "update image: {} bytes to {}",
            image.bytes.len(),
            dir.join(&name).display()
        );
        let _ = out.flush();
    }
    Ok(finished.max(written))
}

fn status_line(bench: &Bench, counters: LinkCounters) {
    let sample = bench.sample();
    let rpm: Vec<String> = sample
        .thrusters
        .iter()
        .map(|thruster| format!("{:5.0}", thruster.rpm))
        .collect();
    let mut out = io::stdout().lock();
    let _ = writeln!(
        out,
        "t {:7.1} s  {:<8}  rpm {}  udp in {} out {}{}",
        sample.t,
        if sample.armed { "ARMED" } else { "disarmed" },
        rpm.join(" "),
        counters.datagrams_in,
        counters.datagrams_out,
        drops(&counters)
    );
    let _ = out.flush();
}

/// The counters of what was dropped or failed, those not zero, for a status line: `""` when nothing was.
pub fn drops(counters: &LinkCounters) -> String {
    [
        ("dropped", counters.dropped_bytes, " B"),
        ("inbox full", counters.inbox_dropped, " B"),
        ("overrun", counters.overruns, " B"),
        ("out dropped", counters.out_dropped, " B"),
        ("send errors", counters.send_errors, ""),
        ("errors", counters.errors, ""),
    ]
    .into_iter()
    .filter(|(_, count, _)| *count > 0)
    .map(|(name, count, unit)| format!("  {name} {count}{unit}"))
    .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use lbv_master_fw::console::lbv::PARAM_REQUEST_LIST_DATA;
    use lbv_station::GroundStation;
    use mavlink_core::{MAVLinkV2MessageRaw, MavHeader, MessageData};

    fn frame<D: MessageData>(message: &D) -> Vec<u8> {
        let mut raw = MAVLinkV2MessageRaw::new();
        raw.serialize_message_data(
            MavHeader {
                system_id: 255,
                component_id: 190,
                sequence: 7,
            },
            message,
        );
        raw.raw_bytes().to_vec()
    }

    fn heartbeat() -> Vec<u8> {
        GroundStation::default().heartbeat()
    }

    #[test]
    fn whole_frames_pass_unchanged() {
        let list = frame(&PARAM_REQUEST_LIST_DATA {
            target_system: 1,
            target_component: 1,
        });
        // SYSTEM_TIME (id 2), outside the dialect: framed by its length.
        let mut system_time = vec![0xFD, 12, 0, 0, 0, 255, 190, 2, 0, 0];
        system_time.extend([1u8; 14]);
        let datagram = [heartbeat(), system_time, list].concat();
        assert_eq!(frames_of(&datagram), (datagram.clone(), 0));
        // Larger than the parser's buffer.
        let big: Vec<u8> = std::iter::repeat_n(heartbeat(), 200).flatten().collect();
        assert_eq!(frames_of(&big), (big.clone(), 0));
    }

    #[test]
    fn the_output_goes_a_frame_a_datagram_and_a_cut_frame_waits_for_its_rest() {
        let list = frame(&PARAM_REQUEST_LIST_DATA {
            target_system: 1,
            target_component: 1,
        });
        let mut signed = heartbeat();
        signed[2] |= 1;
        signed.extend([7u8; 13]);
        let output = [heartbeat(), list.clone(), signed.clone(), heartbeat()].concat();
        // Cut everywhere, including inside a header.
        for cut in 0..=output.len() {
            let mut splitter = FrameSplitter::default();
            let mut frames = Vec::new();
            let (first, second) = output.split_at(cut);
            let mut dropped = splitter.push(first, |frame| frames.push(frame.to_vec()));
            dropped += splitter.push(second, |frame| frames.push(frame.to_vec()));
            assert_eq!(
                frames,
                [heartbeat(), list.clone(), signed.clone(), heartbeat()],
                "cut at {cut}"
            );
            assert_eq!(dropped, 0);
        }
        // Bytes where a frame should start are dropped, and counted.
        let mut splitter = FrameSplitter::default();
        let mut frames = 0;
        assert_eq!(
            splitter.push(&[[0u8, 1].as_slice(), &heartbeat()].concat(), |_| frames += 1),
            2
        );
        assert_eq!(frames, 1);
    }

    #[test]
    fn senders_take_turns_and_a_full_inbox_drops() {
        let (a, b) = (DEFAULT_SEND, DEFAULT_LISTEN);
        let mut inboxes = Inboxes::default();
        let big = [0xFDu8; 300];
        let mut taken = 0;
        while inboxes.push(a, &big) {
            taken += 1;
        }
        assert_eq!(taken, INBOX / big.len());
        assert!(inboxes.push(b, &[1]));
        assert_eq!(inboxes.pop().map(|frame| frame.len()), Some(300));
        assert_eq!(inboxes.pop(), Some(vec![1]));
        assert_eq!(inboxes.pop().map(|frame| frame.len()), Some(300));
        // Every inbox taken, each with frames waiting: a new sender's frames are dropped.
        let mut inboxes = Inboxes::default();
        for port in 0..SENDERS as u16 {
            assert!(inboxes.push(SocketAddr::from((Ipv4Addr::LOCALHOST, 1000 + port)), &[2]));
        }
        assert!(!inboxes.push(a, &[3]));
        assert_eq!(inboxes.pop(), Some(vec![2]));
        assert!(inboxes.push(a, &[3]));
    }

    #[test]
    fn a_broken_datagram_does_not_hide_the_next_one() {
        // A stray start byte, alone or in front of a frame, and a frame cut short: what makes no frame is dropped
        // at the end of its datagram.
        for stray in [&[0xFE][..], &[0xFD, 0xFF, 0x00]] {
            assert_eq!(frames_of(stray), (vec![], stray.len()));
            let datagram = [stray, heartbeat().as_slice()].concat();
            assert_eq!(frames_of(&datagram), (heartbeat(), stray.len()), "{stray:02x?}");
        }
        let cut = &heartbeat()[..15];
        assert_eq!(frames_of(cut), (vec![], 15));
        assert_eq!(frames_of(&heartbeat()), (heartbeat(), 0));
    }
}
