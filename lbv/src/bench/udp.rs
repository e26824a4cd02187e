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

use std::cell::Cell;
use std::io::{self, ErrorKind, Write as _};
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4, UdpSocket};
use std::path::Path;
use std::rc::Rc;
use std::time::Instant as WallInstant;

use embassy_time::{Duration, Instant};
use lbv_master_fw::console::framing::{Event, FrameParser};
use lbv_master_fw::console::inbound;
use lbv_master_fw::ports::UpdateTarget;

use super::Bench;

/// Where QGroundControl and `pymavlink udpin:0.0.0.0:14550` listen.
pub const DEFAULT_SEND: SocketAddr = SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, 14550));
/// Where the bench listens for the station's answers.
pub const DEFAULT_LISTEN: SocketAddr = SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, 14551));
/// Virtual time run between looks at the socket and the wall clock.
const SLICE: Duration = Duration::from_millis(1);
/// How far virtual time may fall behind the wall clock before the difference is given up rather than caught up
/// in a burst (a burst would squeeze the station's 1 Hz heartbeats together and let the console failsafe act).
const MAX_LAG: std::time::Duration = std::time::Duration::from_millis(100);
/// Larger than any MAVLink frame, and than what a station packs into one datagram.
const DATAGRAM: usize = 2048;

/// Datagram counters of the link.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LinkCounters {
    /// Datagrams received and fed to the master.
    pub datagrams_in: u64,
    /// Bytes of received datagrams that made no whole frame, dropped.
    pub dropped_bytes: u64,
    /// Datagrams sent (one per step in which the master wrote something).
    pub datagrams_out: u64,
    /// Sends or receives that failed (other than nothing to read).
    pub errors: u64,
}

/// The console's UDP socket.
#[derive(Debug)]
pub struct UdpLink {
    socket: UdpSocket,
    send_to: SocketAddr,
    counters: Rc<Cell<LinkCounters>>,
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
    /// output is sent as it is written.
    pub fn attach(&self, bench: &mut Bench) -> io::Result<()> {
        let socket = self.socket.try_clone()?;
        let send_to = self.send_to;
        let counters = Rc::clone(&self.counters);
        bench.console_sink = Some(Box::new(move |bytes: &[u8]| {
            let mut count = counters.get();
            // Nobody listening (the station not started yet) is not an error worth stopping for.
            match socket.send_to(bytes, send_to) {
                Ok(_) => count.datagrams_out += 1,
                Err(_) => count.errors += 1,
            }
            counters.set(count);
        }));
        Ok(())
    }

    /// Feed every datagram waiting into the master's console.
    pub fn receive(&self, bench: &mut Bench) {
        let mut buf = [0u8; DATAGRAM];
        let mut count = self.counters.get();
        loop {
            match self.socket.recv_from(&mut buf) {
                Ok((n, _)) => {
                    count.datagrams_in += 1;
                    let (frames, dropped) = frames_of(buf.get(..n).unwrap_or_default());
                    count.dropped_bytes += dropped as u64;
                    bench.send(frames);
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
        self.counters.set(count);
    }
}

/// The whole frames of one datagram, in order (those of messages outside the master's dialect too, framed by
/// their length), and how many of its bytes made no frame.
pub fn frames_of(datagram: &[u8]) -> (Vec<u8>, usize) {
    let mut parser = FrameParser::new();
    let mut frames = Vec::with_capacity(datagram.len());
    let mut rest = datagram;
    loop {
        let taken = parser.push(rest);
        rest = rest.get(taken..).unwrap_or_default();
        if rest.is_empty() {
            parser.end_of_input();
        }
        while let Some(event) = parser.next(inbound::extra_crc) {
            if let Event::Frame(frame) | Event::Unknown(frame) = event {
                frames.extend_from_slice(frame.bytes);
            }
        }
        if rest.is_empty() {
            break;
        }
    }
    let dropped = datagram.len() - frames.len();
    (frames, dropped)
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
/// `update_dir`, write there each update image the master's sink has finished ([`write_images`]). Returns the
/// pacing.
pub fn serve(
    bench: &mut Bench,
    link: &UdpLink,
    duration: Option<Duration>,
    status: bool,
    update_dir: Option<&Path>,
) -> io::Result<WallClock> {
    link.attach(bench)?;
    let end = duration.map(|duration| bench.now() + duration);
    let mut clock = WallClock::start(bench);
    let mut next_status = bench.now();
    let mut written = 0;
    while end.is_none_or(|end| bench.now() < end) {
        link.receive(bench);
        bench.run_for(SLICE);
        // Nothing reads the trace of a live run: keep memory flat however long it runs.
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
        let name = match image.target {
            UpdateTarget::Thruster(slot) => format!("thruster{slot}.lbvu"),
            UpdateTarget::Master => "master.lbvu".to_owned(),
        };
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
        "t {:7.1} s  {:<8}  rpm {}  udp in {} out {}{}{}",
        sample.t,
        if sample.armed { "ARMED" } else { "disarmed" },
        rpm.join(" "),
        counters.datagrams_in,
        counters.datagrams_out,
        if counters.dropped_bytes > 0 {
            format!(" dropped {} B", counters.dropped_bytes)
        } else {
            String::new()
        },
        if counters.errors > 0 {
            format!(" errors {}", counters.errors)
        } else {
            String::new()
        }
    );
    let _ = out.flush();
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
