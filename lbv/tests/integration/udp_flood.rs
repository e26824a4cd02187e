//! `lbv bench --udp` under a flood: another system packs datagrams with MAVLink FTP requests (48 ListDirectory
//! frames each) and sends them far faster than the console's 115200 baud carries, while the operator's station,
//! on its own socket, arms the vehicle, sends its HEARTBEAT at 1 Hz, MANUAL_CONTROL at 10 Hz and a command every
//! second. The flood is dropped at the bridge's inboxes and the modelled UART; the operator keeps hearing the
//! vehicle's HEARTBEAT, the vehicle keeps taking the operator's orders (it stays armed, which it would not
//! without the sticks, and acknowledges the commands), and the bench's memory stays flat. Runs in real time
//! (about 13 s).

use std::net::UdpSocket;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use embassy_time::Instant as VirtualInstant;
use lbv_master_fw::mixer::ManualInput;
use lbv_station::GroundStation;

use crate::support;

/// How long the flood lasts, s.
const FLOOD_SECONDS: u64 = 10;
/// Frames in a flood datagram.
const PER_DATAGRAM: usize = 48;
/// MAVLink FTP's ListDirectory.
const LIST: u8 = 3;
/// MAV_CMD_REQUEST_MESSAGE, and what it asks for (AUTOPILOT_VERSION).
const REQUEST_MESSAGE: u16 = 512;
const AUTOPILOT_VERSION: f32 = 148.0;
/// The longest the operator may go without the vehicle's HEARTBEAT (it sends one a second).
const MAX_HEARTBEAT_GAP: Duration = Duration::from_millis(2_000);
/// The bench's resident memory may not exceed this, KiB (it runs in about 7 MiB; unbounded queues took it to
/// 0.9-1.5 GB).
const MAX_RSS_KIB: u64 = 64 * 1024;
const NEUTRAL: ManualInput = ManualInput {
    x: 0,
    y: 0,
    z: 500,
    r: 0,
};
const AHEAD: ManualInput = ManualInput {
    x: 600,
    y: 0,
    z: 500,
    r: 0,
};

#[test]
fn a_flood_from_another_system_is_dropped_and_the_operator_keeps_the_vehicle() {
    let [gcs, bench_port] = support::free_ports();
    let bench = support::start_bench("20", gcs, bench_port, &[]);
    let operator = UdpSocket::bind(("127.0.0.1", gcs)).unwrap();
    operator.set_read_timeout(Some(Duration::from_millis(5))).unwrap();
    let vehicle = ("127.0.0.1", bench_port);
    let mut station = GroundStation::default();
    let start = Instant::now();
    let virtual_now = |at: Instant| VirtualInstant::from_micros(at.duration_since(start).as_micros() as u64);
    let mut buf = [0u8; 2048];

    // Arm, with the sticks flowing (the master arms only with them): before the flood, so that what follows
    // shows the flood's effect alone.
    let mut next_beat = start;
    let mut next_sticks = start;
    let mut next_arm = start + Duration::from_millis(500);
    let mut pump = |station: &mut GroundStation, sticks: ManualInput| {
        let now = Instant::now();
        if now >= next_beat {
            operator.send_to(&station.heartbeat(), vehicle).unwrap();
            next_beat += Duration::from_secs(1);
        }
        if now >= next_sticks {
            operator.send_to(&station.manual(sticks), vehicle).unwrap();
            next_sticks += Duration::from_millis(100);
        }
        let mut beats = Vec::new();
        while let Ok(n) = operator.recv(&mut buf) {
            let before = station.seen.heartbeats;
            station.receive(virtual_now(Instant::now()), &buf[..n]);
            if station.seen.heartbeats > before {
                beats.push(Instant::now());
            }
        }
        beats
    };
    while !station.seen.armed {
        assert!(start.elapsed() < Duration::from_secs(8), "the vehicle did not arm");
        pump(&mut station, NEUTRAL);
        if Instant::now() >= next_arm {
            operator.send_to(&station.arm(true), vehicle).unwrap();
            next_arm += Duration::from_millis(500);
        }
    }

    // The flood, from system 7 on its own socket.
    let stop = Arc::new(AtomicBool::new(false));
    let flooded = Arc::new(AtomicU64::new(0));
    let flooder = {
        let (stop, flooded) = (Arc::clone(&stop), Arc::clone(&flooded));
        std::thread::spawn(move || {
            let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
            let mut other = GroundStation::with_system(7);
            while !stop.load(Ordering::Relaxed) {
                let datagram: Vec<u8> = (0..PER_DATAGRAM)
                    .flat_map(|seq| other.ftp_request(seq as u16, 0, LIST, 0, b"/update"))
                    .collect();
                if socket.send_to(&datagram, vehicle).is_ok() {
                    flooded.fetch_add(1, Ordering::Relaxed);
                }
                std::thread::sleep(Duration::from_micros(500));
            }
        })
    };

    let flood_start = Instant::now();
    let mut last_beat = flood_start;
    let mut worst_gap = Duration::ZERO;
    let mut max_rss = 0;
    let mut next_rss = flood_start;
    let mut next_command = flood_start;
    let mut commands = 0;
    let mut disarmed = false;
    let acked = |station: &GroundStation| {
        let acks = station.seen.acks.iter();
        acks.filter(|(command, result)| *command == REQUEST_MESSAGE && *result == 0)
            .count()
    };
    let acked_before = acked(&station);
    while flood_start.elapsed() < Duration::from_secs(FLOOD_SECONDS) {
        for beat in pump(&mut station, AHEAD) {
            worst_gap = worst_gap.max(beat - last_beat);
            last_beat = beat;
        }
        disarmed |= !station.seen.armed;
        let now = Instant::now();
        if now >= next_command {
            operator
                .send_to(
                    &station.command(REQUEST_MESSAGE, [AUTOPILOT_VERSION, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
                    vehicle,
                )
                .unwrap();
            commands += 1;
            next_command += Duration::from_secs(1);
        }
        if now >= next_rss {
            max_rss = max_rss.max(bench.rss_kib().unwrap_or(0));
            next_rss += Duration::from_millis(250);
        }
    }
    worst_gap = worst_gap.max(last_beat.elapsed());
    stop.store(true, Ordering::Relaxed);
    flooder.join().unwrap();
    // The acknowledgement of the last command may still be on its way.
    let settle = Instant::now();
    while settle.elapsed() < Duration::from_millis(500) {
        pump(&mut station, AHEAD);
    }
    let acks = acked(&station) - acked_before;
    let rpm = station.seen.rpm;
    let output = bench.stop();

    let report = format!(
        "flood datagrams {}, worst heartbeat gap {worst_gap:?}, commands acked {acks} of {commands}, max RSS {max_rss} \
         KiB, rpm {rpm:?}\nthe bench printed:\n{output}",
        flooded.load(Ordering::Relaxed)
    );
    assert!(worst_gap <= MAX_HEARTBEAT_GAP, "{report}");
    assert!(!disarmed, "the vehicle disarmed under the flood: {report}");
    assert!(acks + 1 >= commands, "{report}");
    assert!(
        rpm.iter().any(|&rpm| rpm > 500),
        "the thrusters did not follow the sticks: {report}"
    );
    assert!(max_rss > 0 && max_rss < MAX_RSS_KIB, "{report}");
    // The bench's status lines show what it dropped.
    assert!(output.contains("inbox full"), "{report}");
    println!("{report}");
}
