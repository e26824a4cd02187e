//! The console's transmit task on virtual time: telemetry periods, outbox messages at once, the armed flag, the
//! thrusters' and battery's values; frames read back with the mavlink crate's own parser.

use crate::support::{clock, ids, parse_all, run_tx};
use embassy_time::Duration;
use lbv_master_fw::console::lbv::{MavMessage, MavModeFlag, MavResult, MavSeverity, MavState, MavType};
use lbv_master_fw::console::{ConsoleConfig, ConsoleStats};
use lbv_master_fw::mixer::FrameKind;
use lbv_master_fw::params::{LISTED_COUNT, Listed, Param, ParamType, Settings};
use lbv_master_fw::shared::{
    AckResult, BatterySummary, LinkHealth, Message, Outgoing, Sender, Severity, Shared, Text, ThrusterReport,
    VehicleState,
};
use tmc_proto::{Faults, MotorKind, SeaBotixStatus, Speed, Status};

const HEARTBEAT: u32 = 0;
const SYS_STATUS: u32 = 1;
const BATTERY_STATUS: u32 = 147;
const ESC_1_TO_4: u32 = 11030;
const ESC_5_TO_8: u32 = 11031;
const ESC_INFO: u32 = 290;
const ESC_STATUS: u32 = 291;

fn count(frames: &[u32], id: u32) -> usize {
    frames.iter().filter(|&&i| i == id).count()
}

fn report(step: i8, good: u32) -> ThrusterReport {
    ThrusterReport {
        health: LinkHealth {
            online: true,
            good,
            ..LinkHealth::default()
        },
        status: Some(Status::SeaBotix(SeaBotixStatus {
            revision: 0,
            motor: MotorKind::Brushless,
            current_limited: false,
            faults: Faults::NONE,
            current_deciamps: 17,
            speed: Speed::new(step).unwrap(),
            temperature_c: 33,
        })),
    }
}

#[test]
fn telemetry_periods_on_virtual_time() {
    let _clock = clock();
    for (thrusters, five_to_eight) in [(6u8, true), (4, false)] {
        let config = ConsoleConfig {
            thrusters,
            ..ConsoleConfig::DEFAULT
        };
        let shared = Shared::new();
        let stats = ConsoleStats::new();
        // 0 .. 10.05 s: 1 Hz messages at 0, 1, ..., 10 s; 4 Hz ones at 0, 0.25, ..., 10 s.
        let bytes = run_tx(&config, &shared, &stats, Duration::from_millis(10_050), |_| {});
        let frames = parse_all(&bytes);
        let ids = ids(&frames);
        for id in [HEARTBEAT, SYS_STATUS, BATTERY_STATUS] {
            assert_eq!(count(&ids, id), 11, "message {id}");
        }
        assert_eq!(count(&ids, ESC_1_TO_4), 41);
        assert_eq!(count(&ids, ESC_5_TO_8), if five_to_eight { 41 } else { 0 });
        // One ESC_INFO (1 Hz) and ESC_STATUS (4 Hz) per block of four thrusters.
        let blocks = if five_to_eight { 2 } else { 1 };
        assert_eq!(count(&ids, ESC_INFO), 11 * blocks);
        assert_eq!(count(&ids, ESC_STATUS), 41 * blocks);
        assert_eq!(ids.len(), frames.len());
        assert_eq!(stats.snapshot().frames_out as usize, frames.len());
        // The sequence counts every frame; system 1, component 1.
        for (n, (header, _)) in frames.iter().enumerate() {
            assert_eq!(usize::from(header.sequence), n % 256);
            assert_eq!((header.system_id, header.component_id), (1, 1));
        }
        // The first second: the 1 Hz set first, at once.
        assert_eq!(&ids[..3], &[HEARTBEAT, SYS_STATUS, BATTERY_STATUS]);
    }
}

#[test]
fn outbox_messages_go_out_at_once() {
    let _clock = clock();
    let shared = Shared::new();
    let stats = ConsoleStats::new();
    let mut text = Text::new();
    text.push_str("thruster 3 offline").unwrap();
    let mut queued = false;
    // Queue between two telemetry ticks (at 100 ms), run until just before the next tick (250 ms).
    let bytes = run_tx(
        &ConsoleConfig::DEFAULT,
        &shared,
        &stats,
        Duration::from_millis(200),
        |elapsed| {
            if elapsed >= Duration::from_millis(100) && !queued {
                queued = true;
                shared
                    .outbox
                    .try_send(Outgoing::CommandAck {
                        command: 400,
                        result: AckResult::TemporarilyRejected,
                        to: Sender {
                            system: 255,
                            component: 190,
                        },
                    })
                    .unwrap();
                shared
                    .outbox
                    .try_send(Outgoing::ParamValue {
                        id: *b"THR_MAX\0\0\0\0\0\0\0\0\0",
                        value: 0.5,
                        param_type: ParamType::Real32,
                        index: 2,
                        count: 5,
                    })
                    .unwrap();
                shared.say(Severity::Warning, text.clone());
            }
        },
    );
    let frames = parse_all(&bytes);
    let messages: Vec<&MavMessage> = frames.iter().map(|(_, m)| m).collect();
    // Telemetry at t = 0 (HEARTBEAT, SYS_STATUS, BATTERY_STATUS, two ESC_TELEMETRY, two ESC_INFO, two
    // ESC_STATUS), then the three queued messages.
    assert_eq!(messages.len(), 12, "{messages:#?}");
    match messages[9] {
        MavMessage::COMMAND_ACK(ack) => {
            assert_eq!(
                (ack.command, ack.result),
                (400, MavResult::MAV_RESULT_TEMPORARILY_REJECTED)
            );
            assert_eq!(ack.progress, 0);
            assert_eq!((ack.target_system, ack.target_component), (255, 190), "to the sender");
        }
        other => panic!("expected COMMAND_ACK, got {other:?}"),
    }
    match messages[10] {
        MavMessage::PARAM_VALUE(p) => {
            assert_eq!(&p.param_id[..8], b"THR_MAX\0");
            assert_eq!((p.param_value, p.param_index, p.param_count), (0.5, 2, 5));
        }
        other => panic!("expected PARAM_VALUE, got {other:?}"),
    }
    match messages[11] {
        MavMessage::STATUSTEXT(t) => {
            assert_eq!(t.severity, MavSeverity::MAV_SEVERITY_WARNING);
            assert_eq!(&t.text[..18], b"thruster 3 offline");
            assert!(t.text[18..].iter().all(|&b| b == 0));
        }
        other => panic!("expected STATUSTEXT, got {other:?}"),
    }
}

#[test]
fn heartbeat_follows_the_armed_state_and_telemetry_the_reports() {
    let _clock = clock();
    let shared = Shared::new();
    let stats = ConsoleStats::new();
    for (i, watch) in shared.thrusters.iter().enumerate() {
        watch.sender().send(report(51 - 10 * i as i8, 100 + i as u32));
    }
    shared.battery.sender().send(BatterySummary {
        info: Some(bat_proto::BatteryInfo {
            voltage_decivolts: 168,
            charge_percent: Some(64),
            current_deciamps: Some(52),
            temperature_decicelsius: None,
        }),
        status: None,
        alarms: Some(bat_proto::BmsAlarms::NONE),
        frames: 3,
        ..BatterySummary::default()
    });
    let bytes = run_tx(
        &ConsoleConfig::DEFAULT,
        &shared,
        &stats,
        Duration::from_millis(1500),
        |elapsed| {
            if elapsed == Duration::from_millis(500) {
                shared.vehicle.sender().send(VehicleState {
                    armed: true,
                    console_alive: true,
                    refused: 0,
                    armable: true,
                    failsafe: false,
                    param_type_mismatches: 0,
                    operator: 255,
                });
            }
        },
    );
    let frames = parse_all(&bytes);
    let heartbeats: Vec<_> = frames
        .iter()
        .filter_map(|(_, m)| match m {
            MavMessage::HEARTBEAT(hb) => Some(hb.clone()),
            _ => None,
        })
        .collect();
    assert_eq!(heartbeats.len(), 2);
    assert_eq!(heartbeats[0].mavtype, MavType::MAV_TYPE_SUBMARINE);
    assert!(
        !heartbeats[0]
            .base_mode
            .contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED)
    );
    assert_eq!(heartbeats[0].system_status, MavState::MAV_STATE_STANDBY);
    assert!(
        heartbeats[1]
            .base_mode
            .contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED)
    );
    assert_eq!(heartbeats[1].system_status, MavState::MAV_STATE_ACTIVE);

    let esc = frames
        .iter()
        .find_map(|(_, m)| match m {
            MavMessage::ESC_TELEMETRY_1_TO_4(e) => Some(e.clone()),
            _ => None,
        })
        .unwrap();
    assert_eq!(esc.rpm, [2250, 1809, 1368, 926]);
    assert_eq!(esc.current, [170; 4]);
    assert_eq!(esc.temperature, [33; 4]);
    assert_eq!(esc.count, [100, 101, 102, 103]);
    let esc = frames
        .iter()
        .find_map(|(_, m)| match m {
            MavMessage::ESC_TELEMETRY_5_TO_8(e) => Some(e.clone()),
            _ => None,
        })
        .unwrap();
    // Thrusters 7 and 8 are not configured (6 thrusters).
    assert_eq!(esc.count, [104, 105, 0, 0]);

    let battery = frames
        .iter()
        .find_map(|(_, m)| match m {
            MavMessage::BATTERY_STATUS(b) => Some(b.clone()),
            _ => None,
        })
        .unwrap();
    assert_eq!(
        (battery.voltages[0], battery.current_battery, battery.battery_remaining),
        (16_800, 520, 64)
    );
    assert_eq!(battery.temperature, i16::MAX);
}

#[test]
fn drop_rate_comes_from_the_receive_counters() {
    use crate::support::run_rx;
    let _clock = clock();
    // Counters of a receive task that saw 3 good frames and 1 corrupt one.
    let config = ConsoleConfig::DEFAULT;
    let frame = crate::support::v2(
        255,
        190,
        0,
        &lbv_master_fw::console::lbv::PARAM_REQUEST_LIST_DATA {
            target_system: 9,
            target_component: 0,
        },
    );
    let mut corrupt = frame.clone();
    corrupt[10] ^= 1;
    let stream = [frame.clone(), corrupt, frame.clone(), frame].concat();
    let (_, counters) = run_rx(&stream, 64, &config);
    assert_eq!((counters.frames_in, counters.corrupt()), (3, 1));
    // The same counts, made by the tx task's own stats: feed them through a receive task sharing the stats.
    let shared = Shared::new();
    let stats = ConsoleStats::new();
    let mut rx = crate::support::ScriptedRx::new(stream, 64);
    let capture = crate::support::Capture::default();
    let mut tx = capture.clone();
    embassy_futures::block_on(embassy_futures::select::select3(
        lbv_master_fw::console::console_rx_task(
            &mut rx,
            &config,
            &shared,
            &stats,
            &lbv_master_fw::config::VEHICLE.thrusters,
            lbv_master_fw::mixer::FrameKind::Lbv300_6,
            lbv_master_fw::update::CheckOnly,
        ),
        lbv_master_fw::console::console_tx_task(&mut tx, &config, &shared, &stats),
        async {
            for _ in 0..120 {
                for _ in 0..4 {
                    embassy_futures::yield_now().await;
                }
                lbv_sim::clock::advance(Duration::from_millis(10));
            }
        },
    ));
    let frames = parse_all(&capture.take());
    let last_sys_status = frames
        .iter()
        .filter_map(|(_, m)| match m {
            MavMessage::SYS_STATUS(s) => Some(s.clone()),
            _ => None,
        })
        .next_back()
        .unwrap();
    // 1 corrupt in 4: 25.00 %.
    assert_eq!((last_sys_status.drop_rate_comm, last_sys_status.errors_comm), (2500, 1));
}

/// A serial port that fails every write.
struct Broken;

impl embedded_io_async::ErrorType for Broken {
    type Error = embedded_io_async::ErrorKind;
}

impl embedded_io_async::Write for Broken {
    async fn write(&mut self, _: &[u8]) -> Result<usize, Self::Error> {
        Err(embedded_io_async::ErrorKind::Other)
    }

    async fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

#[test]
fn write_errors_are_counted_and_the_task_carries_on() {
    let _clock = clock();
    let shared = Shared::new();
    let stats = ConsoleStats::new();
    let config = ConsoleConfig::DEFAULT;
    let mut tx = Broken;
    embassy_futures::block_on(embassy_futures::select::select(
        lbv_master_fw::console::console_tx_task(&mut tx, &config, &shared, &stats),
        async {
            for _ in 0..105 {
                for _ in 0..4 {
                    embassy_futures::yield_now().await;
                }
                lbv_sim::clock::advance(Duration::from_millis(10));
            }
        },
    ));
    let counters = stats.snapshot();
    // 0 and 1 s: 5 slow messages each (three, and ESC_INFO of two blocks); 0, 0.25, ..., 1 s: 4 fast ones each
    // (ESC_TELEMETRY 1-4 and 5-8, ESC_STATUS of two blocks).
    assert_eq!((counters.frames_out, counters.write_errors), (0, 2 * 5 + 5 * 4));
}

/// A serial port's transmit side that records what was written and, at each flush, how much had been written.
#[derive(Clone, Default)]
struct Flushing {
    written: std::rc::Rc<std::cell::RefCell<Vec<u8>>>,
    flushed_at: std::rc::Rc<std::cell::RefCell<Vec<usize>>>,
}

impl embedded_io_async::ErrorType for Flushing {
    type Error = core::convert::Infallible;
}

impl embedded_io_async::Write for Flushing {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.written.borrow_mut().extend_from_slice(buf);
        Ok(buf.len())
    }

    async fn flush(&mut self) -> Result<(), Self::Error> {
        let len = self.written.borrow().len();
        self.flushed_at.borrow_mut().push(len);
        Ok(())
    }
}

#[test]
fn a_reboot_waits_for_its_acknowledgement_to_leave_the_port() {
    use embassy_futures::select::{Either, select};
    use embassy_futures::{block_on, yield_now};
    use lbv_master_fw::console::console_tx_task;

    let _clock = clock();
    let shared = Shared::new();
    let stats = ConsoleStats::new();
    let port = Flushing::default();
    let mut tx = port.clone();
    let to = Sender {
        system: 255,
        component: 190,
    };
    let script = async {
        for _ in 0..4 {
            yield_now().await;
        }
        assert!(!shared.reboot.signaled());
        shared
            .outbox
            .send(Outgoing::CommandAck {
                command: 246,
                result: AckResult::Accepted,
                to,
            })
            .await;
        shared.outbox.send(Outgoing::Reboot).await;
        for _ in 0..4 {
            yield_now().await;
        }
    };
    match block_on(select(
        console_tx_task(&mut tx, &ConsoleConfig::DEFAULT, &shared, &stats),
        script,
    )) {
        Either::First(never) => match never {},
        Either::Second(()) => {}
    }
    assert!(shared.reboot.signaled(), "the reboot is let go");
    let written = port.written.borrow().clone();
    let frames = parse_all(&written);
    let (_, last) = frames.last().unwrap();
    match last {
        MavMessage::COMMAND_ACK(ack) => assert_eq!((ack.command, ack.result), (246, MavResult::MAV_RESULT_ACCEPTED)),
        other => panic!("the last frame before the reboot is its ACK, not {other:?}"),
    }
    // The port was flushed with the acknowledgement in it.
    assert_eq!(port.flushed_at.borrow().last(), Some(&written.len()));
}

#[test]
fn pilot_gain_goes_at_1_hz_as_the_fraction_ardusub_sends_and_at_once_when_asked() {
    let _clock = clock();
    let shared = Shared::new();
    let stats = ConsoleStats::new();
    let mut settings = Settings::defaults(FrameKind::Lbv300_6);
    shared.settings.sender().send(settings);
    let mut changed = false;
    // 0 .. 2.05 s; at 1.5 s the vehicle changes LBV_GAIN to 70 % and asks for PilotGain at once.
    let bytes = run_tx(
        &ConsoleConfig::DEFAULT,
        &shared,
        &stats,
        Duration::from_millis(2050),
        |elapsed| {
            if elapsed >= Duration::from_millis(1500) && !changed {
                changed = true;
                settings.params.set(Param::Gain, 70);
                shared.settings.sender().send(settings);
                shared
                    .outbox
                    .try_send(Outgoing::Message {
                        message: Message::NamedValueFloat,
                        first: 0,
                    })
                    .unwrap();
            }
        },
    );
    let gains: Vec<(u32, f32)> = parse_all(&bytes)
        .into_iter()
        .filter_map(|(_, m)| match m {
            MavMessage::NAMED_VALUE_FLOAT(v) => {
                assert_eq!(&v.name[..], b"PilotGain\0");
                Some((v.time_boot_ms, v.value))
            }
            _ => None,
        })
        .collect();
    assert_eq!(gains, [(0, 0.5), (1000, 0.5), (1500, 0.7), (2000, 0.7)]);
}

#[test]
fn the_parameter_list_goes_one_value_at_a_time_with_the_values_in_force() {
    let _clock = clock();
    let shared = Shared::new();
    let stats = ConsoleStats::new();
    let mut settings = Settings::defaults(FrameKind::Lbv300_6);
    settings.params.set(Param::Button0, 42);
    shared.settings.sender().send(settings);
    let mut asked = false;
    let bytes = run_tx(
        &ConsoleConfig::DEFAULT,
        &shared,
        &stats,
        Duration::from_millis(200),
        |elapsed| {
            if elapsed >= Duration::from_millis(100) && !asked {
                asked = true;
                shared.outbox.try_send(Outgoing::ParamList).unwrap();
            }
        },
    );
    let values: Vec<_> = parse_all(&bytes)
        .into_iter()
        .filter_map(|(_, m)| match m {
            MavMessage::PARAM_VALUE(p) => Some(p),
            _ => None,
        })
        .collect();
    assert_eq!(values.len(), LISTED_COUNT);
    for (p, listed) in values.iter().zip(Listed::all()) {
        assert_eq!(p.param_id.to_str().unwrap(), listed.name());
        assert_eq!(
            (usize::from(p.param_index), usize::from(p.param_count)),
            (listed.index().into(), LISTED_COUNT)
        );
        assert_eq!(
            p.param_value,
            listed.to_float(listed.value(&settings.params)),
            "{listed:?}"
        );
    }
    assert_eq!(values[Param::Button0.index() as usize].param_value, 42.0);
}
