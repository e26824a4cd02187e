//! The whole master as it ships ([`run`] with the vehicle's configuration) on virtual time: a pilot's session built
//! by pymavlink goes in on the console, six scripted thrusters sit behind a TCA9548A on the 100 kbit/s I2C2 bus,
//! and pymavlink reads what the master sends back.

pub(crate) mod scripted;

use core::cell::RefCell;
use core::marker::PhantomData;
use std::collections::VecDeque;
use std::process::{Command as Process, Stdio};
use std::rc::Rc;

use embassy_time::{Duration, Instant};
use lbv_sim::flash::Stm32g4Flash;
use lbv_sim::i2c::{Bus, Route, Timing};
use lbv_sim::{Executor, Queue, SerialRx, SerialTx, clock};
use serde_json::Value;
use tmc_proto::Family;

use crate::config::VEHICLE;
use crate::console::ConsoleStats;
use crate::ports::Ports;
use crate::ports::{Board, OwnUpdate, UpdateSink};
use crate::settings::Store;
use crate::shared::{MAX_THRUSTERS, Shared};
use crate::sim::{CanNode, RebootRequest, ThrusterBus, flash_store, master_flash, thruster_bus};
use crate::tests::scripted::SimThruster;
use crate::thrusters::MUX_ADDRESS;
use crate::{Polling, run};

/// The master on lbv-sim's parts, polling its buses, with `U` for the update images and `O` for its own update.
#[derive(Debug)]
struct Simulated<U, O>(PhantomData<(U, O)>);

impl<U: UpdateSink, O: OwnUpdate> Board for Simulated<U, O> {
    type Bus = ThrusterBus;
    type Can = CanNode;
    type ConsoleRx = SerialRx;
    type ConsoleTx = SerialTx;
    type Settings = Store<Stm32g4Flash>;
    type Reboot = RebootRequest;
    type Work = Polling<'static>;
    type Update = U;
    type Own = O;
}

/// Run the project's pymavlink peer (`tests/mav_peer.py`).
fn mav_peer(command: &str, input: &str) -> Value {
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/mav_peer.py");
    let mut child = Process::new("python3")
        .args([script, command])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("python3 runs");
    std::io::Write::write_all(child.stdin.as_mut().expect("stdin"), input.as_bytes()).expect("write to python");
    let output = child.wait_with_output().expect("python3 finishes");
    assert!(
        output.status.success(),
        "mav_peer.py {command} failed: pymavlink missing? (pip install pymavlink)"
    );
    serde_json::from_slice(&output.stdout).expect("mav_peer.py prints JSON")
}

fn unhex(hex: &str) -> Vec<u8> {
    (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).expect("hex"))
        .collect()
}

#[test]
fn a_pymavlink_pilot_arms_drives_and_disarms_the_vehicle() {
    let session = mav_peer("session", "");
    let frames: VecDeque<(Instant, Vec<u8>)> = session
        .as_array()
        .expect("a list")
        .iter()
        .map(|event| {
            let at = Instant::from_millis(event[0].as_u64().expect("time"));
            (at, unhex(event[2].as_str().expect("hex")))
        })
        .collect();
    let sticks: Vec<Instant> = session
        .as_array()
        .expect("a list")
        .iter()
        .filter(|event| event[1] == "manual")
        .filter_map(|event| event[0].as_u64().map(Instant::from_millis))
        .collect();

    // The vehicle's own configuration: six SeaBotix thrusters behind a TCA9548A on I2C2.
    let config = VEHICLE;
    let timing = Timing::new(config.bus.frequency_hz, config.bus.timeout);
    let buses = [Bus::new(timing), Bus::new(timing), Bus::new(timing)];
    buses[1].fit_mux(MUX_ADDRESS);
    let thrusters: Vec<Rc<RefCell<SimThruster>>> = config
        .thrusters
        .as_slice()
        .iter()
        .map(|slot| {
            let thruster = Rc::new(RefCell::new(SimThruster::new(slot.family)));
            let route = slot.mux_channel.map_or(Route::Direct, Route::Mux);
            buses[usize::from(slot.bus)].attach(thruster.clone(), route);
            thruster
        })
        .collect();
    assert!(thrusters.iter().all(|t| t.borrow().link.family() == Family::SeaBotix));
    let (console_in, console_out) = (Queue::new(), Queue::new());
    let shared = Shared::new();
    let stats = ConsoleStats::new();
    let clock = clock::take();
    let mut executor = Executor::new();
    let ports = Ports::<Simulated<_, _>> {
        buses: buses.each_ref().map(|bus| thruster_bus(bus, &config.bus)),
        // No battery board on the CAN bus.
        can: CanNode::default(),
        console_rx: SerialRx::new(console_in.clone()),
        console_tx: SerialTx(console_out.clone()),
        settings: flash_store(&master_flash()),
        reboot: RebootRequest::default(),
        work: Polling::default(),
        update: crate::update::CheckOnly,
        own: (),
    };
    executor.spawn(async {
        run(ports, &config, &shared, &stats).await;
    });
    // When thruster 1's order changed on the wire.
    let mut changes: Vec<Instant> = Vec::new();
    let mut last_order = tmc_proto::Order::STOP;
    let mut frames = frames;
    let end = Instant::from_secs(3) + Duration::from_millis(200);
    while clock.now() < end {
        // Each frame arrives at its time.
        while frames.front().is_some_and(|(at, _)| *at <= clock.now()) {
            if let Some((_, frame)) = frames.pop_front() {
                console_in.send(frame);
            }
        }
        executor.run_for(&clock, Duration::from_micros(100), Duration::from_micros(100));
        let order = thrusters[0].borrow().link.order();
        if order != last_order {
            last_order = order;
            changes.push(clock.now());
        }
    }

    // Console to wire: each stick frame's new order reaches thruster 1 on its next poll (50 Hz, so within 20 ms
    // plus the transfer).
    let latencies: Vec<Duration> = sticks
        .iter()
        .map(|stick| {
            *changes
                .iter()
                .find(|change| **change >= *stick)
                .expect("every stick frame moved thruster 1")
                - *stick
        })
        .collect();
    let (shortest, longest) = (latencies.iter().min().copied(), latencies.iter().max().copied());
    let mean = latencies.iter().map(|latency| latency.as_micros()).sum::<u64>() / latencies.len() as u64;
    println!(
        "console-to-wire latency over {} stick frames: min {} us, mean {mean} us, max {} us",
        latencies.len(),
        shortest.map_or(0, |d| d.as_micros()),
        longest.map_or(0, |d| d.as_micros())
    );
    assert!(
        longest.is_some_and(|longest| longest <= Duration::from_millis(21)),
        "latencies {latencies:?}"
    );
    assert!(
        thrusters.iter().all(|t| t.borrow().link.order().speed.is_zero()),
        "stopped after disarm"
    );

    let sent: String = console_out.take().iter().map(|byte| format!("{byte:02x}")).collect();
    let messages = mav_peer("decode", &sent);
    let messages = messages.as_array().expect("a list");
    let of = |kind: &'static str| messages.iter().filter(move |m| m["_type"] == kind);

    let acks: Vec<_> = of("COMMAND_ACK")
        .map(|m| (m["command"].as_u64(), m["result"].as_u64()))
        .collect();
    assert_eq!(
        acks,
        [(Some(400), Some(0)), (Some(400), Some(0))],
        "arm and disarm accepted"
    );
    const ARMED: u64 = 128;
    let armed: Vec<bool> = of("HEARTBEAT")
        .map(|m| m["base_mode"].as_u64().unwrap_or(0) & ARMED != 0)
        .collect();
    assert!(armed.contains(&true), "a heartbeat says armed");
    assert_eq!(armed.last(), Some(&false), "the last heartbeat says disarmed");
    assert!(of("HEARTBEAT").all(|m| m["type"] == 12), "a submarine");
    // Forward stick: the four horizontal thrusters turn, and the ESC telemetry shows it.
    let peak_rpm = of("ESC_TELEMETRY_1_TO_4")
        .filter_map(|m| {
            m["rpm"]
                .as_array()
                .map(|rpm| rpm.iter().filter_map(Value::as_u64).min().unwrap_or(0))
        })
        .max()
        .unwrap_or(0);
    assert!(peak_rpm > 0, "thruster telemetry moved");
    let texts: Vec<&str> = of("STATUSTEXT").filter_map(|m| m["text"].as_str()).collect();
    assert!(
        texts.iter().any(|text| text.starts_with("T1 online")),
        "link texts: {texts:?}"
    );
    // The host build takes the development key unless LBV_UPDATE_KEY names another.
    assert_eq!(
        texts.contains(&crate::DEV_KEY_TEXT),
        update_image::UPDATE_KEY_IS_DEV,
        "start-up texts: {texts:?}"
    );
    assert_eq!(MAX_THRUSTERS, 8);
}

#[test]
fn an_arm_waiting_when_the_master_starts_on_trial_is_refused_until_its_image_has_confirmed() {
    use embassy_boot::{AlignedBuffer, FirmwareState};
    use g431_hw::memory::{FLASH_ORIGIN, MASTER_PARTITIONS};
    use lbv_station::GroundStation;

    use crate::update::own::{OwnFlash, OwnImage, Updating};

    // The master's flash as the bootloader leaves it after a swap: the running image on trial.
    let flash = master_flash();
    let span = MASTER_PARTITIONS.state;
    let state = flash.partition(span.origin - FLASH_ORIGIN, span.length).unwrap();
    let mut word = AlignedBuffer([0; 8]);
    embassy_futures::block_on(FirmwareState::new(state, &mut word.0).mark_updated()).unwrap();

    let config = VEHICLE;
    let timing = Timing::new(config.bus.frequency_hz, config.bus.timeout);
    let buses = [Bus::new(timing), Bus::new(timing), Bus::new(timing)];
    let (console_in, console_out) = (Queue::new(), Queue::new());
    let (shared, stats, image) = (Shared::new(), ConsoleStats::new(), OwnImage::new());
    let clock = clock::take();
    let mut executor = Executor::new();
    let ports = Ports::<Simulated<_, _>> {
        buses: buses.each_ref().map(|bus| thruster_bus(bus, &config.bus)),
        can: CanNode::default(),
        console_rx: SerialRx::new(console_in.clone()),
        console_tx: SerialTx(console_out.clone()),
        settings: flash_store(&master_flash()),
        reboot: RebootRequest::default(),
        work: Polling::default(),
        update: crate::update::CheckOnly,
        own: Updating {
            flash: OwnFlash::new(flash.clone()),
            image: &image,
            crashes: 0,
        },
    };
    // The operator's heartbeat and arm are in the UART before the master runs: the vehicle task takes them before
    // the own update has read the bootloader's state.
    let mut ground = GroundStation::default();
    console_in.send(ground.heartbeat());
    console_in.send(ground.arm(true));
    executor.spawn(async {
        run(ports, &config, &shared, &stats).await;
    });
    let mut until = |ground: &mut GroundStation, ms: u64| {
        while clock.now() < Instant::from_millis(ms) {
            if clock.now().as_millis().is_multiple_of(1000) {
                console_in.send(ground.heartbeat());
            }
            executor.run_for(&clock, Duration::from_millis(1), Duration::from_millis(1));
            ground.receive(clock.now(), &console_out.take());
        }
    };
    until(&mut ground, 200);
    // Once it has read it: on trial.
    console_in.send(ground.arm(true));
    until(&mut ground, 400);
    // Heard for 3 s, it confirms itself: then the arm is taken.
    until(&mut ground, 4_000);
    console_in.send(ground.arm(true));
    until(&mut ground, 5_200);
    let arms: Vec<u8> = ground
        .seen
        .acks
        .iter()
        .filter(|(command, _)| *command == 400)
        .map(|(_, r)| *r)
        .collect();
    let texts: Vec<&str> = ground.seen.texts.iter().map(|(_, text)| text.as_str()).collect();
    assert_eq!(arms, [1, 1, 0], "TEMPORARILY_REJECTED twice, then ACCEPTED: {texts:?}");
    let refusals: Vec<&str> = texts
        .iter()
        .copied()
        .filter(|t| t.starts_with("Arm rejected"))
        .collect();
    assert_eq!(
        refusals,
        ["Arm rejected: master starting", "Arm rejected: master image on trial"]
    );
    assert!(texts.contains(&"master.lbvu: ? confirmed"), "{texts:?}");
    assert!(ground.seen.armed);
}

#[test]
fn polling_holds_arming_until_every_thruster_of_the_table_has_said_what_it_runs_or_is_found_missing() {
    use crate::CONFIG;
    use crate::ports::BusWork;
    use crate::shared::UpdateHold;
    use crate::update::courier::Transfers;

    // No thruster on the buses: each is found missing by its first poll, and not waited for after it.
    let config = CONFIG;
    let timing = Timing::new(config.bus.frequency_hz, config.bus.timeout);
    let buses = [Bus::new(timing), Bus::new(timing), Bus::new(timing)];
    buses[1].fit_mux(MUX_ADDRESS);
    let mut ports = buses.each_ref().map(|bus| thruster_bus(bus, &config.bus));
    let (shared, transfers) = (Shared::new(), Transfers::new());
    let clock = clock::take();
    let mut executor = Executor::new();
    executor.spawn(async {
        Polling {
            transfers: Some(&transfers),
        }
        .run(&mut ports, &config, &shared)
        .await;
    });
    executor.run_for(&clock, Duration::from_micros(1), Duration::from_micros(1));
    assert_eq!(
        shared.holds.get(),
        Some(UpdateHold::Unasked(0)),
        "before any poll has an answer"
    );
    executor.run_for(&clock, Duration::from_millis(100), Duration::from_micros(100));
    assert_eq!(shared.holds.get(), None);
}

#[test]
fn a_master_whose_flash_is_not_dual_bank_says_so_once_and_writes_neither_settings_nor_updates() {
    use lbv_sim::flash::FlashStats;
    use lbv_station::{GroundStation, Upload, UploadState};
    use update_image::{ImageInfo, Target, Version};

    use crate::update::VehicleSink;
    use crate::update::courier::Transfers;
    use crate::update::own::{OwnFlash, OwnImage, Updating};

    // The binding read DBANK = 0: the settings store and the own update are told so before the tasks start.
    let flash = master_flash();
    let config = VEHICLE;
    let timing = Timing::new(config.bus.frequency_hz, config.bus.timeout);
    let buses = [Bus::new(timing), Bus::new(timing), Bus::new(timing)];
    let (console_in, console_out) = (Queue::new(), Queue::new());
    let (shared, stats, image, transfers) = (Shared::new(), ConsoleStats::new(), OwnImage::new(), Transfers::new());
    image.set_layout_ok(false);
    let mut settings = flash_store(&flash);
    settings.set_layout_ok(false);
    let clock = clock::take();
    let mut executor = Executor::new();
    let ports = Ports::<Simulated<_, _>> {
        buses: buses.each_ref().map(|bus| thruster_bus(bus, &config.bus)),
        can: CanNode::default(),
        console_rx: SerialRx::new(console_in.clone()),
        console_tx: SerialTx(console_out.clone()),
        settings,
        reboot: RebootRequest::default(),
        work: Polling::default(),
        update: VehicleSink::new(&transfers, &image),
        own: Updating {
            flash: OwnFlash::new(flash.clone()),
            image: &image,
            crashes: 0,
        },
    };
    executor.spawn(async {
        run(ports, &config, &shared, &stats).await;
    });
    let mut ground = GroundStation::default();
    let mut step = |ground: &mut GroundStation, upload: Option<&mut Upload>| {
        if clock.now().as_millis().is_multiple_of(1000) {
            console_in.send(ground.heartbeat());
        }
        if let Some(frame) = upload.and_then(|upload| upload.poll(clock.now(), ground)) {
            console_in.send(frame);
        }
        executor.run_for(&clock, Duration::from_millis(1), Duration::from_millis(1));
        ground.receive(clock.now(), &console_out.take());
    };
    for _ in 0..500 {
        step(&mut ground, None);
    }
    // A parameter takes effect until the next start, and is not saved: here the one that lets an update through
    // over this unsigned link.
    console_in.send(ground.param_set("LBV_UPD_UNSIGNED", 1.0));
    for _ in 0..500 {
        step(&mut ground, None);
    }
    let seed = update_image::key_from_hex(include_str!("../../keys/dev.key")).expect("a key");
    let mut payload = vec![0x5A; 4096];
    let record = update_image::image_record(
        ImageInfo::new(Target::Master, Version::new(0, 2, 0)),
        &update_image::DEV_PUBLIC_KEY,
    );
    payload[update_image::INFO_OFFSET..update_image::INFO_OFFSET + record.len()].copy_from_slice(&record);
    let mut upload = Upload::new(
        "/update/master.lbvu",
        update_image::sign(&payload, &seed).expect("signed"),
    );
    for _ in 0..2000 {
        step(&mut ground, Some(&mut upload));
    }
    assert!(
        matches!(upload.state(), UploadState::Refused(_)),
        "{:?}",
        upload.state()
    );

    let texts: Vec<&str> = ground.seen.texts.iter().map(|(_, text)| text.as_str()).collect();
    let count = |wanted: &str| texts.iter().filter(|text| **text == wanted).count();
    assert_eq!(
        count(crate::NOT_DUAL_BANK_TEXT),
        1,
        "said once, at the start: {texts:?}"
    );
    assert_eq!(count("Settings not saved: flash not dual-bank"), 1, "{texts:?}");
    assert_eq!(count("master.lbvu: refused: flash not dual-bank"), 1, "{texts:?}");
    assert_eq!(
        shared.settings.try_get().map(|s| s.params.unsigned_updates()),
        Some(true),
        "in force"
    );
    assert_eq!(flash.stats(), FlashStats::default(), "nothing erased or programmed");
}

/// The stop before this start is told once, as two texts, and the record marked told; events are noted in the ring
/// with the time since the start.
#[test]
fn the_crash_before_this_start_is_told_once_and_events_are_noted() {
    use crash_record::{Frame, Image, Kind, Region, ResetCause, Stop, What};
    let clock = clock::take();
    let shared = Shared::new();
    // Nothing held: nothing told, and notes go nowhere.
    super::tell_crash(&shared);
    shared.note(What::Armed);
    assert!(shared.outbox.try_receive().is_err());
    let image = Image {
        target: 3,
        version: [0, 1, 0, 0],
    };
    let region = Box::leak(Box::new(Region::new()));
    region.start(ResetCause(1 << 27), image);
    let stop = Stop {
        kind: Kind::HardFault,
        frame: Frame {
            pc: 0x0800_2468,
            ..Frame::default()
        },
        faults: Default::default(),
        exception: 3,
        panic: None,
        uptime_ms: 1234,
    };
    region.record(stop, image);
    assert!(region.start(ResetCause(1 << 28), image).is_some());
    shared.keep_crash(region);
    super::tell_crash(&shared);
    super::tell_crash(&shared);
    let mut texts = Vec::new();
    while let Ok(crate::shared::Outgoing::Text(severity, text)) = shared.outbox.try_receive() {
        texts.push((severity, text.to_string()));
    }
    assert_eq!(
        texts,
        [
            (
                crate::shared::Severity::Critical,
                "Crash before this start: HardFault at 0x08002468".to_owned()
            ),
            (
                crate::shared::Severity::Critical,
                "Its record: ftp get @SYS/crash/master.bin".to_owned()
            ),
        ]
    );
    assert!(shared.crash_record().unwrap().told);
    clock.advance(Duration::from_millis(2500));
    shared.note(What::ThrusterLost(2));
    let (events, held) = crash_record::Ring::from_bytes(shared.crash_ring().unwrap()).events();
    let last = events[usize::from(held) - 1];
    assert_eq!((last.what, last.at_ms), (What::ThrusterLost(2), 2500));
}
