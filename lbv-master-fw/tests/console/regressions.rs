//! The bad inputs that once beat the console, each through the real receive, transmit and vehicle tasks on
//! virtual time, with a ground station's 1 Hz heartbeats:
//! - one stray byte (`fe`, or `fd ff 00`) made the frame parser wait for the false frame's whole claimed length,
//!   up to 280 bytes: some 13 s of heartbeats, so the failsafe disarmed a vehicle whose ground station was alive;
//! - traffic from any component (PARAM_REQUEST_READ from system 2) kept the failsafe from acting while the
//!   ground station was silent;
//! - any system id could arm: COMMAND_LONG 400 from system 42 was ACCEPTED.

use crate::support::{Line, parse_all, run_console, v2};
use embassy_time::{Duration, Instant};
use lbv_master_fw::console::LINE_IDLE;
use lbv_master_fw::console::lbv::{COMMAND_LONG_DATA, MavMessage, MavResult, PARAM_REQUEST_READ_DATA};
use lbv_master_fw::vehicle::VehicleConfig;
use lbv_station::GCS_HEARTBEAT;

const GCS: (u8, u8) = (255, 190);

fn heartbeat(from: (u8, u8), sequence: u8) -> Vec<u8> {
    v2(from.0, from.1, sequence, &GCS_HEARTBEAT)
}

fn arm(from: (u8, u8), sequence: u8) -> Vec<u8> {
    let message = COMMAND_LONG_DATA {
        target_system: 1,
        target_component: 1,
        command: 400,
        confirmation: 0,
        param1: 1.0,
        param2: 0.0,
        param3: 0.0,
        param4: 0.0,
        param5: 0.0,
        param6: 0.0,
        param7: 0.0,
    };
    v2(from.0, from.1, sequence, &message)
}

/// The ground station's heartbeats at 1 Hz for `seconds`, and an arm command right after the first.
fn pilot(seconds: u64) -> Vec<(u64, Vec<u8>)> {
    let mut bursts: Vec<(u64, Vec<u8>)> = (0..seconds).map(|s| (s * 1000, heartbeat(GCS, s as u8))).collect();
    bursts.push((10, arm(GCS, 200)));
    bursts
}

/// The failsafe texts in what the console sent.
fn failsafe_texts(sent: &[u8]) -> Vec<String> {
    parse_all(sent)
        .into_iter()
        .filter_map(|(_, m)| match m {
            MavMessage::STATUSTEXT(t) => Some(t.text.to_str().unwrap_or("?").trim_end_matches('\0').to_owned()),
            _ => None,
        })
        .filter(|text| text.starts_with("Failsafe"))
        .collect()
}

#[test]
fn a_stray_byte_does_not_blind_the_console() {
    const STRAYS: [&[u8]; 3] = [&[0xFE], &[0xFD, 0xFF, 0x00], &[0xFD, 0xFF]];
    for stray in STRAYS {
        let mut bursts = pilot(30);
        // Alone on the line between two heartbeats...
        bursts.push((2500, stray.to_vec()));
        // ...and right in front of one, in the same burst.
        let (at, hb) = bursts.iter().find(|(ms, _)| *ms == 12_000).cloned().unwrap();
        bursts.retain(|(ms, _)| *ms != 12_000);
        bursts.push((at, [stray, hb.as_slice()].concat()));
        let mut heard = None;
        let mut armed_ms = 0;
        let sent = run_console(
            VehicleConfig::DEFAULT.defaults(),
            Line::new(bursts),
            Duration::from_secs(30),
            |now, shared, stats| {
                armed_ms += u64::from(shared.vehicle.try_get().is_some_and(|v| v.armed));
                // When the heartbeat behind the stray bytes got through.
                if heard.is_none() && now >= Instant::from_millis(12_000) && stats.snapshot().frames_in >= 14 {
                    heard = Some(now);
                }
            },
        );
        assert!(armed_ms >= 29_900, "{stray:02x?}: armed for {armed_ms} ms of 30 s");
        assert!(
            failsafe_texts(&sent).is_empty(),
            "{stray:02x?}: {:?}",
            failsafe_texts(&sent)
        );
        // 12 heartbeats and the arm before 12 s, the 13th in the burst with the stray bytes.
        let heard = heard.unwrap_or_else(|| panic!("{stray:02x?}: the heartbeat behind the stray bytes was lost"));
        assert!(
            heard <= Instant::from_millis(12_000) + LINE_IDLE + Duration::from_millis(2),
            "{stray:02x?}: heard at {heard:?}, later than the line's idle time"
        );
    }
}

#[test]
fn another_systems_traffic_does_not_keep_the_failsafe_alive() {
    // The operator arms, then falls silent; system 2 keeps reading parameters and sending ground-station
    // heartbeats.
    let mut bursts = vec![(0, heartbeat(GCS, 0)), (10, arm(GCS, 1))];
    for n in 0..50u64 {
        let read = PARAM_REQUEST_READ_DATA {
            target_system: 1,
            target_component: 1,
            param_id: [0; 16].into(),
            param_index: 0,
        };
        bursts.push((100 + n * 200, v2(2, 1, n as u8, &read)));
        if n % 5 == 0 {
            bursts.push((150 + n * 200, heartbeat((2, 1), n as u8)));
        }
    }
    let mut disarmed_at = None;
    let sent = run_console(
        VehicleConfig::DEFAULT.defaults(),
        Line::new(bursts),
        Duration::from_secs(8),
        |now, shared, _| {
            let armed = shared.vehicle.try_get().is_some_and(|v| v.armed);
            if !armed && disarmed_at.is_none() && now > Instant::from_millis(100) {
                disarmed_at = Some(now);
            }
        },
    );
    let disarmed_at = disarmed_at.expect("the failsafe disarmed");
    // FS_GCS_TIMEOUT (5 s) after the operator's heartbeat, within a 50 Hz tick.
    assert!(
        disarmed_at >= Instant::from_millis(5000) && disarmed_at <= Instant::from_millis(5022),
        "{disarmed_at:?}"
    );
    assert_eq!(failsafe_texts(&sent), ["Failsafe: ground station lost, disarmed"]);
    // System 2's reads were answered all the same.
    let values = parse_all(&sent)
        .iter()
        .filter(|(_, m)| matches!(m, MavMessage::PARAM_VALUE(_)))
        .count();
    assert_eq!(values, 40, "one per read within 8 s");
}

#[test]
fn another_system_cannot_arm() {
    let other = (42, 1);
    let bursts = vec![
        (0, heartbeat(other, 0)),
        (10, arm(other, 1)),
        (1000, heartbeat(other, 2)),
    ];
    let mut ever_armed = false;
    let mut refused = 0;
    let sent = run_console(
        VehicleConfig::DEFAULT.defaults(),
        Line::new(bursts),
        Duration::from_millis(2100),
        |_, shared, _| {
            let state = shared.vehicle.try_get();
            ever_armed |= state.is_some_and(|s| s.armed);
            refused = state.map_or(0, |s| s.refused);
        },
    );
    assert!(!ever_armed);
    assert_eq!(refused, 1);
    let frames = parse_all(&sent);
    let acks: Vec<_> = frames
        .iter()
        .filter_map(|(_, m)| match m {
            MavMessage::COMMAND_ACK(ack) => Some(ack.clone()),
            _ => None,
        })
        .collect();
    assert_eq!(acks.len(), 1);
    assert_eq!(
        (
            acks[0].command,
            acks[0].result,
            acks[0].target_system,
            acks[0].target_component
        ),
        (400, MavResult::MAV_RESULT_DENIED, 42, 1)
    );
    // SYS_STATUS counts it for the pilot (errors_count3).
    let last_status = frames
        .iter()
        .filter_map(|(_, m)| match m {
            MavMessage::SYS_STATUS(s) => Some(s.errors_count3),
            _ => None,
        })
        .next_back();
    assert_eq!(last_status, Some(1));
}
