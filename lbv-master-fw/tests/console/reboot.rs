//! The attacks on the console's signing that a reboot once opened, each through the whole master ([`run`]) on
//! virtual time, its settings in a simulated G431 flash that outlives the reboots, and a ground station whose
//! signing is mavlink-core's (an independent implementation: real-time timestamps, following the vehicle's newer
//! ones as the MAVLink C library and pymavlink do):
//! - a signed session recorded by an attacker (heartbeat, arm, two seconds of sticks) and replayed 20 ms after
//!   the reboot's COMMAND_ACK armed the vehicle and drove it (the streams were in RAM, the stored timestamp up to
//!   a minute stale, and a new stream allowed a minute behind it);
//! - one signed frame with the timestamp 2^48 - 1 wrapped the vehicle's timestamps to 0, was stored, and after the
//!   next reboot frames signed a year earlier were accepted;
//! - the first telemetry after every reboot went out unsigned, and a frame waiting in the UART at reset was checked
//!   with no key (an unsigned SETUP_SIGNING with a zero key would have turned signing off).

use std::cell::Cell;
use std::convert::Infallible;
use std::rc::Rc;
use std::time::{SystemTime, UNIX_EPOCH};

use embassy_time::{Delay, Duration};
use embedded_hal_async::i2c::I2c;
use lbv_master_fw::config::{MasterConfig, VEHICLE};
use lbv_master_fw::console::framing::{Event, FrameParser};
use lbv_master_fw::console::lbv::{COMMAND_LONG_DATA, MANUAL_CONTROL_DATA, MavMessage, SETUP_SIGNING_DATA};
use lbv_master_fw::console::signing::{SIGNATURE_LEN, SigningKey, TIMESTAMP_MAX};
use lbv_master_fw::console::{ConsoleCounters, ConsoleStats, inbound};
use lbv_master_fw::ports::{BusRecovery, BusWork, CanFrame, CanReceiver, Ports, Reboot};
use lbv_master_fw::recovery::PinRecovery;
use lbv_master_fw::run;
use lbv_master_fw::settings::Store;
use lbv_master_fw::shared::BUSES;
use lbv_master_fw::shared::Shared;
use lbv_master_fw::update::CheckOnly;
use lbv_sim::flash::Stm32g4Flash;
use lbv_sim::i2c::{Bus, Master, Scl, Sda};
use lbv_sim::{Executor, Queue, SerialRx, SerialTx};
use lbv_station::GCS_HEARTBEAT;
use mavlink_core::{MAVLinkV2MessageRaw, MavHeader, SigningConfig, SigningData};

const KEY: [u8; 32] = *b"console-reboot-test-key-01234567";
const ARM: u16 = 400;
const REBOOT: u16 = 246;

/// Now in signing units: 10 us since 2015-01-01.
fn signing_now() -> u64 {
    let since_1970 = SystemTime::now().duration_since(UNIX_EPOCH).unwrap();
    (since_1970.as_micros() as u64 - 1_420_070_400_000_000) / 10
}

/// The thruster buses stay idle: these tests are about the console.
struct Idle;

impl BusWork for Idle {
    const POLLS: bool = false;

    async fn run<B: I2c + BusRecovery>(self, _: &mut [B; BUSES], _: &MasterConfig, _: &Shared) {}
}

/// No battery board.
struct NoCan;

impl CanReceiver for NoCan {
    type Error = Infallible;

    async fn receive(&mut self) -> Result<CanFrame, Infallible> {
        core::future::pending().await
    }
}

/// A reboot the board carries out: counted, then the test drops the master and boots it again.
#[derive(Clone, Default)]
struct Restart(Rc<Cell<u32>>);

impl Reboot for Restart {
    async fn reboot(&mut self) -> ! {
        self.0.set(self.0.get() + 1);
        core::future::pending().await
    }
}

/// The master's ports in these tests: lbv-sim's buses and flash, idle buses, no battery board, no update.
struct Wiring;

impl lbv_master_fw::ports::Board for Wiring {
    type Bus = PinRecovery<Master, Scl, Sda, Delay>;
    type Can = NoCan;
    type ConsoleRx = SerialRx;
    type ConsoleTx = SerialTx;
    type Settings = Store<Stm32g4Flash>;
    type Reboot = Restart;
    type Work = Idle;
    type Update = CheckOnly;
    type Own = ();
}

/// What one boot of the master saw and did.
#[derive(Default)]
struct Boot {
    /// The console's counters at the end.
    counters: ConsoleCounters,
    /// Whether the vehicle was armed at any time.
    armed: bool,
    /// When it was first armed, since the boot.
    armed_at: Option<Duration>,
    /// Whether any thruster was ordered to turn at any time.
    drove: bool,
    /// The signing key in force at the end.
    key: Option<SigningKey>,
    /// It asked to be rebooted.
    rebooted: bool,
}

/// The master's board: its flash and its console's UART, which keep their contents across a reboot (bytes a
/// ground station sent during the restart wait in the UART's buffer).
struct Board {
    clock: lbv_sim::Clock,
    flash: Stm32g4Flash,
    input: Queue<u8>,
    output: Queue<u8>,
}

impl Board {
    fn new() -> Self {
        Self {
            clock: lbv_sim::clock::take(),
            flash: Stm32g4Flash::new(256),
            input: Queue::new(),
            output: Queue::new(),
        }
    }

    /// Boot the master and run it for at most `limit` in 1 ms steps, or until it asks to reboot; `each_ms` is
    /// called before every step with the time since the boot and may send bytes on the console.
    fn boot(&self, limit: Duration, mut each_ms: impl FnMut(Duration, &Queue<u8>)) -> Boot {
        let config = VEHICLE;
        let buses: [Bus; BUSES] =
            core::array::from_fn(|_| Bus::new(lbv_sim::i2c::Timing::new(100_000, config.bus.timeout)));
        let shared = Shared::new();
        let stats = ConsoleStats::new();
        let restart = Restart::default();
        let ports = Ports::<Wiring> {
            buses: buses.each_ref().map(|bus| PinRecovery {
                i2c: bus.master(),
                scl: bus.scl(),
                sda: bus.sda(),
                delay: Delay,
                bus: config.bus,
            }),
            can: NoCan,
            console_rx: SerialRx::new(self.input.clone()),
            console_tx: SerialTx(self.output.clone()),
            settings: Store::master(self.flash.clone()),
            reboot: restart.clone(),
            work: Idle,
            update: CheckOnly,
            own: (),
        };
        let mut executor = Executor::new();
        executor.spawn(async {
            run(ports, &config, &shared, &stats).await;
        });
        let start = self.clock.now();
        let mut boot = Boot::default();
        while self.clock.now() - start < limit && restart.0.get() == 0 {
            each_ms(self.clock.now() - start, &self.input);
            executor.run_for(&self.clock, Duration::from_millis(1), Duration::from_millis(1));
            if shared.vehicle.try_get().is_some_and(|v| v.armed) {
                boot.armed = true;
                boot.armed_at.get_or_insert(self.clock.now() - start);
            }
            boot.drove |= shared
                .orders
                .try_get()
                .is_some_and(|orders| orders.iter().any(|order| !order.speed.is_zero()));
        }
        boot.counters = stats.snapshot();
        boot.key = shared.settings.try_get().and_then(|s| s.signing);
        boot.rebooted = restart.0.get() > 0;
        boot
    }
}

/// A frame the master sent, as the raw message mavlink-core checks.
fn raw(frame: &[u8]) -> MAVLinkV2MessageRaw {
    let mut raw = MAVLinkV2MessageRaw::new();
    raw.as_mut_slice()[..frame.len()].copy_from_slice(frame);
    raw
}

/// Every frame in `bytes` (MAVLink 2, the dialect's).
fn frames(bytes: &[u8]) -> Vec<Vec<u8>> {
    let mut parser = FrameParser::new();
    let mut out = Vec::new();
    for chunk in bytes.chunks(64) {
        assert_eq!(parser.push(chunk), chunk.len());
        while let Some(event) = parser.next(inbound::extra_crc) {
            if let Event::Frame(frame) = event {
                out.push(frame.bytes.to_vec());
            }
        }
    }
    out
}

/// The signature timestamp of a signed frame.
fn stamp(frame: &[u8]) -> u64 {
    let at = frame.len() - SIGNATURE_LEN + 1;
    let mut bytes = [0; 8];
    bytes[..6].copy_from_slice(&frame[at..at + 6]);
    u64::from_le_bytes(bytes)
}

/// The operator's ground station (system 255), signing with mavlink-core.
struct GroundStation {
    signing: SigningData,
    sequence: u8,
}

impl GroundStation {
    fn new() -> Self {
        Self {
            signing: SigningData::from_config(SigningConfig::new(KEY, 0, true, false)),
            sequence: 0,
        }
    }

    fn header(&mut self) -> MavHeader {
        self.sequence = self.sequence.wrapping_add(1);
        MavHeader {
            system_id: 255,
            component_id: 190,
            sequence: self.sequence,
        }
    }

    fn signed(&mut self, message: &MavMessage) -> Vec<u8> {
        let mut bytes = Vec::new();
        let header = self.header();
        mavlink_core::write_v2_msg_signed(&mut bytes, header, message, Some(&self.signing)).unwrap();
        bytes
    }

    fn unsigned(&mut self, message: &MavMessage) -> Vec<u8> {
        let mut bytes = Vec::new();
        mavlink_core::write_v2_msg(&mut bytes, self.header(), message).unwrap();
        bytes
    }

    /// Signed with exactly `timestamp` (what an attacker holding the key, or a broken clock, could send).
    fn signed_at(&mut self, message: &MavMessage, timestamp: u64) -> Vec<u8> {
        let mut raw = MAVLinkV2MessageRaw::new();
        raw.serialize_message_for_signing(self.header(), message);
        raw.signature_timestamp_bytes_mut()
            .copy_from_slice(&timestamp.to_le_bytes()[..6]);
        let mut signature = [0; 6];
        raw.calculate_signature(&KEY, &mut signature);
        raw.signature_value_mut().copy_from_slice(&signature);
        raw.raw_bytes().to_vec()
    }

    /// Read what the master sent: how many frames verified with the key (the station follows their
    /// timestamps), and how many did not.
    fn hear(&self, sent: &[u8]) -> (usize, usize) {
        let frames = frames(sent);
        let verified = frames.iter().filter(|f| self.signing.verify_signature(&raw(f))).count();
        (verified, frames.len() - verified)
    }
}

fn heartbeat() -> MavMessage {
    MavMessage::HEARTBEAT(GCS_HEARTBEAT)
}

fn command(command: u16, param1: f32) -> MavMessage {
    MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
        target_system: 1,
        target_component: 1,
        command,
        confirmation: 0,
        param1,
        param2: 0.0,
        param3: 0.0,
        param4: 0.0,
        param5: 0.0,
        param6: 0.0,
        param7: 0.0,
    })
}

fn sticks(x: i16) -> MavMessage {
    MavMessage::MANUAL_CONTROL(MANUAL_CONTROL_DATA {
        target: 1,
        x,
        y: 0,
        z: 500,
        r: 0,
        ..MANUAL_CONTROL_DATA::DEFAULT
    })
}

fn setup_signing(key: [u8; 32], timestamp: u64) -> MavMessage {
    MavMessage::SETUP_SIGNING(SETUP_SIGNING_DATA {
        target_system: 1,
        target_component: 1,
        secret_key: key,
        initial_timestamp: timestamp,
    })
}

/// Bytes due at given milliseconds since the boot, sent when their time comes.
fn at(schedule: &mut Vec<(u64, Vec<u8>)>, since_boot: Duration, input: &Queue<u8>) {
    let now = since_boot.as_millis();
    schedule.retain(|(ms, bytes)| {
        let due = *ms <= now;
        if due {
            input.send(bytes.iter().copied());
        }
        !due
    });
}

/// The first frame of a master's first boot: the key set over the console, unsigned, as it must be the first time
/// (the ST-LINK's USB link is the secure channel the spec asks for).
fn set_up(gcs: &mut GroundStation) -> (u64, Vec<u8>) {
    (100, gcs.unsigned(&setup_signing(KEY, signing_now())))
}

#[test]
fn a_session_recorded_before_a_reboot_is_refused_after_it() {
    let mut gcs = GroundStation::new();
    let board = Board::new();
    // The key set, then the operator's session, recorded by an attacker: heartbeat, arm, two seconds of sticks at
    // 10 Hz; then the operator disarms and reboots the master.
    let mut schedule = vec![set_up(&mut gcs)];
    let mut recorded = vec![(1000, gcs.signed(&heartbeat())), (1020, gcs.signed(&command(ARM, 1.0)))];
    for k in 0..20 {
        recorded.push((1100 + 100 * k, gcs.signed(&sticks(600))));
    }
    schedule.extend(recorded.iter().cloned());
    schedule.push((3200, gcs.signed(&command(ARM, 0.0))));
    schedule.push((3300, gcs.signed(&command(REBOOT, 1.0))));
    let first = board.boot(Duration::from_secs(4), |t, input| at(&mut schedule, t, input));
    assert_eq!(first.key.map(|k| k.secret), Some(KEY), "signing on");
    assert!(
        first.armed && first.drove,
        "the session drove the vehicle: {:?}",
        first.counters
    );
    assert!(first.rebooted, "the operator's reboot was taken");
    gcs.hear(&board.output.take());

    // The replay, 20 ms after the reboot's acknowledgement (the master restarts as soon as it is out); half a
    // second after it, the operator's station, which has heard the master's signed telemetry meanwhile, arms.
    let mut replay: Vec<(u64, Vec<u8>)> = recorded.iter().map(|(ms, bytes)| (ms - 980, bytes.clone())).collect();
    let last = replay.iter().map(|(ms, _)| *ms).max().unwrap();
    let operator_arms = last + 500;
    let mut heard = (0, 0);
    let second = board.boot(Duration::from_secs(3), |t, input| {
        at(&mut replay, t, input);
        if t.as_millis() == operator_arms {
            heard = gcs.hear(&board.output.take());
            input.send(gcs.signed(&heartbeat()));
            input.send(gcs.signed(&command(ARM, 1.0)));
        }
    });
    assert_eq!(second.counters.replayed, recorded.len() as u32, "{:?}", second.counters);
    assert!(!second.drove, "the replay did not drive");
    assert!(
        second.armed_at.is_some_and(|t| t.as_millis() >= operator_arms),
        "armed only by the operator: {:?}",
        second.armed_at
    );
    let (verified, unverified) = heard;
    assert!(verified > 5 && unverified == 0, "{verified} verified, {unverified} not");
}

/// The signature timestamps of the signed frames the master sent, in order.
fn stamps(sent: &[u8]) -> Vec<u64> {
    const SIGNED: u8 = 0x01;
    frames(sent)
        .iter()
        .filter(|frame| frame[2] & SIGNED != 0)
        .map(|frame| stamp(frame))
        .collect()
}

#[test]
fn the_largest_timestamp_is_refused_and_a_year_old_frame_stays_refused_after_reboots() {
    const YEAR: u64 = 365 * 24 * 3600 * 100_000;
    let mut gcs = GroundStation::new();
    let board = Board::new();
    let now = signing_now();
    // Frames the operator signed a year ago, recorded then.
    let old_heartbeat = gcs.signed_at(&heartbeat(), now - YEAR);
    let old_arm = gcs.signed_at(&command(ARM, 1.0), now - YEAR + 1);
    let mut schedule = vec![
        set_up(&mut gcs),
        // One frame signed with the largest timestamp, then the operator's own.
        (1000, gcs.signed_at(&heartbeat(), TIMESTAMP_MAX)),
        (1100, gcs.signed(&heartbeat())),
    ];
    let mut reboot = None;
    let first = board.boot(Duration::from_secs(3), |t, input| {
        at(&mut schedule, t, input);
        if t.as_millis() == 2000 {
            // The operator's station reads the telemetry, then reboots the master.
            reboot = Some(board.output.take());
            gcs.hear(reboot.as_deref().unwrap());
            input.send(gcs.signed(&command(REBOOT, 1.0)));
        }
    });
    assert!(first.rebooted);
    assert_eq!(first.counters.out_of_range, 1, "{:?}", first.counters);
    let mut before = stamps(&reboot.unwrap());
    before.extend(stamps(&board.output.take()));
    let signed = before;
    assert!(signed.len() > 5 && signed.windows(2).all(|w| w[0] < w[1]), "{signed:?}");
    assert!(
        signed.iter().all(|t| *t < now + 10 * 60 * 100_000),
        "no jump to the end: {signed:?}"
    );

    // Three reboots later the year-old frames, replayed 20 ms after each start, are still refused.
    let mut last = *signed.last().unwrap();
    for _ in 0..3 {
        let mut schedule = vec![(20, old_heartbeat.clone()), (25, old_arm.clone())];
        let mut sent = Vec::new();
        let boot = board.boot(Duration::from_secs(1), |t, input| {
            at(&mut schedule, t, input);
            if t.as_millis() == 500 {
                sent = board.output.take();
                gcs.hear(&sent);
                input.send(gcs.signed(&command(REBOOT, 1.0)));
            }
        });
        assert!(boot.rebooted && !boot.armed);
        assert_eq!(boot.counters.replayed, 2, "{:?}", boot.counters);
        sent.extend(board.output.take());
        let stamps = stamps(&sent);
        assert!(
            stamps.first().is_some_and(|first| *first > last),
            "resumes past {last}: {stamps:?}"
        );
        last = *stamps.last().unwrap();
    }
}

#[test]
fn from_the_first_frame_after_a_reboot_everything_is_signed_and_checked() {
    let mut gcs = GroundStation::new();
    let board = Board::new();
    let mut schedule = vec![set_up(&mut gcs)];
    let first = board.boot(Duration::from_secs(2), |t, input| {
        at(&mut schedule, t, input);
        if t.as_millis() == 1000 {
            gcs.hear(&board.output.take());
            input.send(gcs.signed(&command(REBOOT, 1.0)));
        }
    });
    assert!(first.rebooted && first.key.is_some());
    board.output.take();
    for reboot in 1..=6 {
        // Waiting in the UART at reset: an unsigned SETUP_SIGNING with a zero key (signing off) and an unsigned
        // arm.
        board.input.send(gcs.unsigned(&setup_signing([0; 32], 0)));
        board.input.send(gcs.unsigned(&command(ARM, 1.0)));
        let mut sent = Vec::new();
        let boot = board.boot(Duration::from_secs(1), |t, input| {
            if t.as_millis() == 500 {
                sent = board.output.take();
                gcs.hear(&sent);
                input.send(gcs.signed(&command(REBOOT, 1.0)));
            }
        });
        assert!(boot.rebooted, "reboot {reboot}");
        assert_eq!(
            boot.key.map(|k| k.secret),
            Some(KEY),
            "reboot {reboot}: signing still on"
        );
        assert!(!boot.armed);
        assert_eq!(boot.counters.unsigned, 2, "reboot {reboot}: {:?}", boot.counters);
        // What a station with the key reads of the boot: every frame signed with it, the very first included.
        let checker = SigningData::from_config(SigningConfig::new(KEY, 0, false, false));
        let frames = frames(&sent);
        assert!(frames.len() > 5);
        for (n, frame) in frames.iter().enumerate() {
            assert!(
                checker.verify_signature(&raw(frame)),
                "reboot {reboot}: frame {n} not signed with the key"
            );
        }
        board.output.take();
    }
}
