//! Joystick buttons over the console, as QGroundControl's ArduSub joystick sends them: MANUAL_CONTROL at 10 Hz
//! with the buttons held in `buttons`, a button held over several frames. Each press does its `BTNn_FUNCTION`
//! once (the defaults: 6 arm, 4 disarm, 11 gain up, 12 gain down), a refused arm says why, and a gain step comes
//! back as PARAM_VALUE, "PilotGain" and a text; the console, the vehicle and the settings task on virtual time.

use crate::support::{Line, parse_all, run_console, v2};
use embassy_time::Duration;
use lbv_master_fw::console::lbv::{MANUAL_CONTROL_DATA, MavMessage, MavModeFlag};
use lbv_master_fw::vehicle::VehicleConfig;
use lbv_station::GCS_HEARTBEAT;

const GCS: (u8, u8) = (255, 190);
const ARM: u16 = 1 << 6;
const DISARM: u16 = 1 << 4;
const GAIN_UP: u16 = 1 << 11;
const GAIN_DOWN: u16 = 1 << 12;

fn manual(sequence: u8, z: i16, buttons: u16) -> Vec<u8> {
    let message = MANUAL_CONTROL_DATA {
        target: 1,
        z,
        buttons,
        ..MANUAL_CONTROL_DATA::DEFAULT
    };
    v2(GCS.0, GCS.1, sequence, &message)
}

#[test]
fn each_press_does_its_function_once_over_the_console() {
    // What the pilot holds, frame by frame (every 100 ms from 100 ms): the heave stick and the buttons.
    let held = |ms: u64| match ms {
        300..=500 => (500, ARM),
        800..=1000 => (500, GAIN_UP),
        1200 => (500, GAIN_DOWN),
        1500..=1700 => (500, DISARM),
        // A ground station sending its heave centre as 0.
        2000..=2100 => (0, ARM),
        _ => (500, 0),
    };
    let mut bursts: Vec<(u64, Vec<u8>)> = (0..3)
        .map(|s| (s * 1000, v2(GCS.0, GCS.1, 0, &GCS_HEARTBEAT)))
        .collect();
    for ms in (100..=2500).step_by(100) {
        let (z, buttons) = held(ms);
        bursts.push((ms, manual((ms / 100) as u8, z, buttons)));
    }
    let mut armed_at = Vec::new();
    let mut gain_at = Vec::new();
    let sent = run_console(
        VehicleConfig::DEFAULT.defaults(),
        Line::new(bursts),
        Duration::from_millis(2600),
        |now, shared, _| {
            let ms = now.as_millis();
            if ms % 100 == 50 {
                armed_at.push((ms, shared.vehicle.try_get().unwrap().armed));
                gain_at.push((ms, shared.settings.try_get().unwrap().params.gain_percent()));
            }
        },
    );
    let armed = |ms: u64| armed_at.iter().find(|(at, _)| *at == ms).unwrap().1;
    assert!(!armed(250) && armed(350) && armed(1450) && !armed(1550) && !armed(2550));
    let gain = |ms: u64| gain_at.iter().find(|(at, _)| *at == ms).unwrap().1;
    assert_eq!((gain(750), gain(850), gain(1150), gain(1250)), (50, 60, 60, 50));

    let frames = parse_all(&sent);
    let texts: Vec<String> = frames
        .iter()
        .filter_map(|(_, m)| match m {
            MavMessage::STATUSTEXT(t) => Some(String::from_utf8_lossy(&t.text[..]).trim_end_matches('\0').to_string()),
            _ => None,
        })
        .collect();
    assert_eq!(
        texts,
        [
            "Armed",
            "Pilot gain 60 %",
            "Pilot gain 50 %",
            "Disarmed",
            "Arm rejected: heave stick at 0, not 500"
        ],
        "once per press, however long it is held"
    );
    let gains: Vec<f32> = frames
        .iter()
        .filter_map(|(_, m)| match m {
            MavMessage::PARAM_VALUE(p) if p.param_id.to_str().unwrap() == "LBV_GAIN" => Some(p.param_value),
            _ => None,
        })
        .collect();
    assert_eq!(gains, [60.0, 50.0], "the ground station's copy follows");
    let pilot_gains: Vec<f32> = frames
        .iter()
        .filter_map(|(_, m)| match m {
            MavMessage::NAMED_VALUE_FLOAT(v) => Some(v.value),
            _ => None,
        })
        .collect();
    // At 0, 1 and 2 s, and at once after each step.
    assert_eq!(pilot_gains, [0.5, 0.6, 0.6, 0.5, 0.5]);
    assert!(
        !frames.iter().any(|(_, m)| matches!(m, MavMessage::COMMAND_ACK(_))),
        "a button is no command: no COMMAND_ACK"
    );
    let heartbeats_armed: Vec<bool> = frames
        .iter()
        .filter_map(|(_, m)| match m {
            MavMessage::HEARTBEAT(h) => Some(h.base_mode.contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED)),
            _ => None,
        })
        .collect();
    assert_eq!(heartbeats_armed, [false, true, false]);
}
