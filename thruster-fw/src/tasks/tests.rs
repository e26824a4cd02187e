//! The controller as it ships ([`run`] and [`run_commutation`]) on virtual time: a master on a simulated bus,
//! halls, bridge and ADC inputs set by the test.

use super::*;
use crate::config::WatchdogTiming;
use crate::faults::{Thresholds, VolatileLatch};
use crate::hall::{FORWARD_SEQUENCE, HallState};
use crate::ports::RawSample;
use crate::sim::{BootRecord, BootUpdater, DFU_PAGES, SlavePort};
use core::cell::{Cell, RefCell};
use core::ops::Deref;
use embassy_boot::{FirmwareState, State};
use embassy_futures::block_on;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex as Mutex;
use embassy_sync::signal::Signal;
use embedded_hal_async::i2c::I2c;
use lbv_sim::Cpu;
use lbv_sim::flash::Flash;
use lbv_sim::i2c::{Bus, DeviceId, Route, Timing};
use lbv_sim::{Clock, Executor, Queue, clock};
use std::rc::Rc;
use tmc_proto::{Faults, Order, Speed, Status};

/// An empty transfer stands for a read.
const READ: Vec<u8> = Vec::new();

/// Hall inputs the test sets; every change is an edge.
struct HallInputs {
    state: Cell<HallState>,
    edge: Signal<Mutex, ()>,
}

impl HallInputs {
    fn new(state: HallState) -> Self {
        Self {
            state: Cell::new(state),
            edge: Signal::new(),
        }
    }

    fn get(&self) -> HallState {
        self.state.get()
    }

    fn set(&self, state: HallState) {
        if self.state.replace(state) != state {
            self.edge.signal(());
        }
    }
}

/// What the controller's ports read and drive, and what the test sees of it.
struct Io {
    config: Config,
    shared: Shared,
    halls: HallInputs,
    bridge: Cell<(BridgeDrive, Duty)>,
    /// The bridge's outputs are held off (a sustained overcurrent).
    held_off: Cell<bool>,
    /// A phase is shorted: the break trips whenever the bridge switches.
    shorted: Cell<bool>,
    /// Times the commutation task drove the bridge.
    applied: Cell<u32>,
    inputs: Cell<RawSample>,
    fed: Cell<u32>,
    /// The latch store, kept as a backup register keeps it over a reset.
    latch: Cell<VolatileLatch>,
    /// Every status the master read.
    replies: RefCell<Vec<Vec<u8>>>,
}

struct TestHalls(Rc<Io>);

impl HallSensors for TestHalls {
    async fn wait_for_edge(&mut self) {
        self.0.halls.edge.wait().await;
    }

    fn read(&mut self) -> HallState {
        self.0.halls.get()
    }
}

/// The bridge as last driven.
struct TestBridge(Rc<Io>);

impl Bridge for TestBridge {
    fn apply(&mut self, drive: BridgeDrive, duty: Duty) {
        self.0.bridge.set((drive, duty));
        self.0.applied.set(self.0.applied.get() + 1);
    }

    fn hold_off(&mut self, off: bool) {
        self.0.held_off.set(off);
    }
}

struct TestSensors(Rc<Io>);

impl Sensors for TestSensors {
    async fn sample(&mut self) -> RawSample {
        let io = &self.0;
        // A shorted phase trips the break in every PWM period the bridge switches, until its outputs are held
        // off; the flag is cleared by the sample that reads it.
        let (_, duty) = io.bridge.get();
        let shorted = io.shorted.get() && !io.held_off.get() && duty != Duty::ZERO;
        let sample = io.inputs.get();
        RawSample {
            break_tripped: sample.break_tripped || shorted,
            ..sample
        }
    }
}

struct TestLatch(Rc<Io>);

impl LatchStore for TestLatch {
    fn load(&mut self) -> Faults {
        self.0.latch.get().load()
    }

    fn save(&mut self, latched: Faults) {
        let mut store = self.0.latch.get();
        store.save(latched);
        self.0.latch.set(store);
    }
}

struct CountingWatchdog(Rc<Io>);

impl Watchdog for CountingWatchdog {
    fn feed(&mut self) {
        self.0.fed.set(self.0.fed.get() + 1);
    }
}

/// The test controller's ports: a slave port on lbv-sim's bus, the bootloader's state and a DFU partition on its
/// flash, the rest the test's own.
struct TestBoard;

impl Board for TestBoard {
    type I2c = SlavePort;
    type Sensors = TestSensors;
    type Watchdog = CountingWatchdog;
    type Latch = TestLatch;
    type Boot = BootRecord;
    type Dfu = Flash<8, 2048>;
    type Updater = BootUpdater;
}

/// A healthy controller's inputs: dry, 25 C, no current, 24 V.
fn dry(config: &Config) -> RawSample {
    RawSample {
        water: 0,
        temperature: config.ntc.raw_at(250),
        currents: [config.current.offset_raw; 3],
        vbus: config.vbus.raw_at(24_000),
        break_tripped: false,
    }
}

/// One controller on a bus, with a master that sends what the test queues, one transfer after the other.
struct Bench {
    io: Rc<Io>,
    /// The bootloader's state partition, which embassy-boot reads and writes.
    boot: Flash<8, 2048>,
    /// The DFU partition a field update writes.
    dfu: Flash<8, 2048>,
    /// The bootloader record's first page, where a field update writes its ticket.
    ticket: Flash<8, 2048>,
    /// The controller's CPU, which the flash's erases and writes stall once wired to it.
    cpu: Cpu,
    /// Reboots the field update asked for.
    reboots: Rc<Cell<u32>>,
    bus: Bus,
    device: DeviceId,
    transfers: Queue<Vec<u8>>,
    executor: Executor<'static>,
    clock: Clock,
}

impl Deref for Bench {
    type Target = Io;

    fn deref(&self) -> &Io {
        &self.io
    }
}

impl Bench {
    fn new(family: Family) -> Self {
        Self::with(
            Config::reference(family, MotorKind::Brushless),
            VolatileLatch::default(),
        )
    }

    fn brushed(family: Family) -> Self {
        Self::with(Config::reference(family, MotorKind::Brushed), VolatileLatch::default())
    }

    /// Start the controller at virtual time 0, with the latches a reset left in `latch`.
    fn with(config: Config, latch: VolatileLatch) -> Self {
        Self::booted(config, latch, Flash::new(1))
    }

    /// Start a SeaBotix controller the bootloader has just swapped in: on trial.
    fn on_trial() -> Self {
        let boot = Flash::new(1);
        let mut word = [0; 8];
        block_on(FirmwareState::new(&mut boot.clone(), &mut word).mark_updated()).expect("state written");
        let bench = Self::booted(
            Config::reference(Family::SeaBotix, MotorKind::Brushless),
            VolatileLatch::default(),
            boot,
        );
        assert_eq!(bench.boot_state(), State::Swap);
        bench
    }

    /// The bootloader's state as embassy-boot reads it.
    fn boot_state(&self) -> State {
        let mut word = [0; 8];
        block_on(FirmwareState::new(&mut self.boot.clone(), &mut word).get_state()).expect("state read")
    }

    /// Start the controller at virtual time 0, with the latches a reset left in `latch` and the bootloader's state
    /// in `boot`.
    fn booted(config: Config, latch: VolatileLatch, boot: Flash<8, 2048>) -> Self {
        Self::with_flash(config, latch, boot, Flash::new(DFU_PAGES))
    }

    /// Start the controller at virtual time 0 with the bootloader's state in `boot` and the DFU partition `dfu`
    /// (as a reset leaves them), and an empty bootloader record.
    fn with_flash(config: Config, latch: VolatileLatch, boot: Flash<8, 2048>, dfu: Flash<8, 2048>) -> Self {
        let ticket = Flash::new(1);
        let updater = BootUpdater::new(config.family, ticket.clone(), boot.clone());
        let reboots = updater.reboots.clone();
        let clock = clock::take();
        let io = Rc::new(Io {
            inputs: Cell::new(dry(&config)),
            config,
            shared: Shared::new(),
            halls: HallInputs::new(FORWARD_SEQUENCE[0]),
            bridge: Cell::new((COAST, Duty::ZERO)),
            held_off: Cell::new(false),
            shorted: Cell::new(false),
            applied: Cell::new(0),
            fed: Cell::new(0),
            latch: Cell::new(latch),
            replies: RefCell::new(Vec::new()),
        });
        let bus = Bus::new(Timing::new(io.config.bus.frequency_hz, io.config.bus.timeout));
        let family = io.config.family;
        let device = bus.attach_target(family.address(), Route::Direct);
        let transfers: Queue<Vec<u8>> = Queue::new();
        let mut executor = Executor::new();
        let port = bus.target(device).expect("a firmware port");
        let ports = Ports::<TestBoard> {
            i2c: SlavePort(port),
            sensors: TestSensors(io.clone()),
            watchdog: CountingWatchdog(io.clone()),
            latch: TestLatch(io.clone()),
            boot: BootRecord(boot.clone()),
            dfu: dfu.clone(),
            updater,
        };
        let (halls, bridge) = (TestHalls(io.clone()), TestBridge(io.clone()));
        let cpu = Cpu::new();
        let controller = io.clone();
        executor.spawn_on(&cpu, async move {
            run(ports, &controller.config, &controller.shared).await;
        });
        let controller = io.clone();
        executor.spawn_on(&cpu, async move {
            run_commutation(halls, bridge, &controller.config, &controller.shared).await;
        });
        let (mut master, queue, master_io) = (bus.master(), transfers.clone(), io.clone());
        executor.spawn(async move {
            loop {
                let bytes = queue.receive().await;
                if bytes.is_empty() {
                    let mut status = vec![0; family.status_len()];
                    if master.read(family.address(), &mut status).await.is_ok() {
                        master_io.replies.borrow_mut().push(status);
                    }
                } else {
                    let _ = master.write(family.address(), &bytes).await;
                }
            }
        });
        Self {
            io,
            boot,
            dfu,
            ticket,
            cpu,
            reboots,
            bus,
            device,
            transfers,
            executor,
            clock,
        }
    }

    fn send(&self, bytes: Vec<u8>) {
        self.transfers.push(bytes);
    }

    fn order(&self, step: i8) {
        self.send(
            Order::new(Speed::new(step).unwrap())
                .encode(self.config.family)
                .to_vec(),
        );
    }

    fn last_status(&self) -> Status {
        let replies = self.replies.borrow();
        let decoded = Status::decode(self.config.family, replies.last().expect("a status was read"));
        let decoded = decoded.expect("status decodes");
        assert_eq!(decoded.warning, None);
        decoded.status
    }

    fn duty(&self) -> Duty {
        self.bridge.get().1
    }

    /// Let virtual time pass in 100 us steps, every task running at each step.
    fn elapse(&mut self, duration: Duration) {
        self.executor.run_for(&self.clock, duration, Duration::from_micros(100));
    }

    /// Let virtual time pass with the motor turning forward at 1250 rpm (4 pole pairs: a hall edge every 2 ms),
    /// until `done` says stop; returns how long that took.
    fn turn_until(&mut self, mut done: impl FnMut(&Bench) -> bool) -> Duration {
        let start = Instant::now();
        while !done(self) {
            self.elapse(Duration::from_micros(100));
            let sector = (Instant::now().as_micros() / 2000 % 6) as usize;
            self.halls.set(FORWARD_SEQUENCE[sector]);
        }
        Instant::now() - start
    }

    /// Turn the motor for `duration`.
    fn turn(&mut self, duration: Duration) {
        let end = Instant::now() + duration;
        self.turn_until(|_| Instant::now() >= end);
    }
}

/// Milliseconds since the run started.
fn now_ms() -> u64 {
    Instant::now().as_millis()
}

#[test]
fn an_order_drives_the_bridge_forward_and_the_status_says_so() {
    let mut bench = Bench::new(Family::SeaBotix);
    bench.elapse(Duration::from_millis(5));
    assert_eq!(bench.bridge.get().0, COAST, "stopped until ordered");
    bench.order(51);
    bench.elapse(Duration::from_millis(20));
    let (drive, duty) = bench.bridge.get();
    assert!(duty.value() > 0, "forward duty, got {duty:?}");
    assert_eq!(drive, drive_for(bench.halls.get(), duty));
    bench.send(READ);
    bench.elapse(Duration::from_millis(1));
    assert!(bench.last_status().faults().is_empty());
}

#[test]
fn the_failsafe_stops_the_motor_after_exactly_one_second_of_silence() {
    let mut bench = Bench::new(Family::SeaBotix);
    bench.order(51);
    // The order is taken once its bytes have moved (START, the address and 4 bytes: 460 us).
    bench.elapse(Duration::from_micros(500));
    assert_eq!(bench.shared.link.try_get().map(|link| link.orders), Some(1));
    let ordered_at = now_ms();
    bench.turn(Duration::from_millis(990));
    assert!(
        bench.duty().value() > 0,
        "still driving at {} ms",
        now_ms() - ordered_at
    );
    bench.turn_until(|bench| bench.duty() == Duty::ZERO);
    let stopped_after = now_ms() - ordered_at;
    assert!(
        (1000..=1001).contains(&stopped_after),
        "stopped after {stopped_after} ms"
    );
    assert_eq!(bench.bridge.get().0, COAST);

    // The motor coasts to a stop. A read keeps the link alive but does not restart the motor; the next valid
    // order does.
    bench.elapse(Duration::from_millis(200));
    bench.send(READ);
    bench.elapse(Duration::from_millis(20));
    assert_eq!(bench.duty(), Duty::ZERO);
    bench.order(20);
    bench.elapse(Duration::from_millis(20));
    assert!(bench.duty().value() > 0);
}

/// Driving at 80, the master orders STOP, and every order arrives with its checksum off by one while its reads
/// are clean: the refused orders stop the motor 1 s after the first of them, in both families.
#[test]
fn orders_that_are_all_refused_for_one_second_stop_the_motor_whatever_reads_come() {
    for family in Family::ALL {
        let mut bench = Bench::new(family);
        bench.order(80);
        bench.turn(Duration::from_millis(500));
        assert!(bench.duty().value() > 0);
        let mut stop = Order::STOP.encode(family).to_vec();
        if let Some(csum) = stop.last_mut() {
            *csum = csum.wrapping_add(1);
        }
        let first_refused = now_ms();
        let mut stopped_after = None;
        // 50 Hz: a corrupted order, then a clean read, as the master's poll does.
        for _ in 0..100 {
            bench.send(stop.clone());
            bench.turn(Duration::from_millis(1));
            bench.send(READ);
            bench.turn(Duration::from_millis(19));
            if stopped_after.is_none() && bench.duty() == Duty::ZERO {
                stopped_after = Some(now_ms() - first_refused);
            }
        }
        let stopped_after = stopped_after.expect("the motor stopped");
        assert!(
            (1000..=1020).contains(&stopped_after),
            "{family:?}: stopped {stopped_after} ms after the first refused order"
        );
        assert_eq!(bench.duty(), Duty::ZERO, "{family:?}: still stopped with reads coming");
        if family == Family::SeaBotix {
            assert!(tmc_proto::SeaBotixStatus::link_failsafe_in(
                bench.replies.borrow().last().unwrap()
            ));
        }
        // One valid order ends it (once its ramp passes the 1250 rpm the bench turns the rotor at, it drives).
        bench.order(80);
        bench.turn(Duration::from_millis(300));
        assert!(bench.duty().value() > 0, "{family:?}: a valid order drives again");
    }
}

#[test]
fn one_refused_order_among_valid_ones_changes_nothing() {
    let mut bench = Bench::new(Family::SeaBotix);
    bench.order(60);
    let mut bad = Order::new(Speed::new(60).unwrap()).encode(Family::SeaBotix).to_vec();
    if let Some(csum) = bad.last_mut() {
        *csum ^= 0x10;
    }
    // Every fifth order corrupted, 3 s: the valid ones between restart the failsafe's count.
    for n in 0..150 {
        if n % 5 == 0 {
            bench.send(bad.clone());
        } else {
            bench.order(60);
        }
        bench.turn(Duration::from_millis(20));
    }
    assert!(bench.duty().value() > 0);
    bench.send(READ);
    bench.elapse(Duration::from_millis(1));
    assert!(!tmc_proto::SeaBotixStatus::link_failsafe_in(
        bench.replies.borrow().last().unwrap()
    ));
}

/// A master that sends an order only when it changes (IDS 8.3) and reads the status at 50 Hz in between: a
/// constant order holds for a minute, with no failsafe.
#[test]
fn a_change_only_master_holds_a_constant_order_for_a_minute() {
    for family in Family::ALL {
        let mut bench = Bench::new(family);
        bench.order(30);
        for n in 0..3_000 {
            bench.turn(Duration::from_millis(20));
            bench.send(READ);
            if n % 500 == 499 {
                assert!(
                    bench.duty().value() > 0,
                    "{family:?}: driving after {} ms",
                    (n + 1) * 20
                );
            }
        }
        assert!(
            bench.duty().value() > 0,
            "{family:?}: still driving after 60 s of reads"
        );
        if family == Family::SeaBotix {
            bench.elapse(Duration::from_millis(1));
            assert!(!tmc_proto::SeaBotixStatus::link_failsafe_in(
                bench.replies.borrow().last().unwrap()
            ));
        }
    }
}

#[test]
fn a_ground_fault_coasts_the_bridge_within_three_samples_and_latches() {
    for family in Family::ALL {
        let mut bench = Bench::new(family);
        bench.order(60);
        bench.turn(Duration::from_millis(100));
        assert!(bench.duty().value() > 0);
        let wet = RawSample {
            water: bench.config.water.raw_at(50_000),
            ..bench.inputs.get()
        };
        bench.inputs.set(wet);
        let reaction = bench.turn_until(|bench| bench.bridge.get().0 == COAST);
        assert!(reaction <= filtered(), "coasted after {reaction:?}");
        assert!(reaction > filtered() - SAMPLE_PERIOD, "coasted after {reaction:?}");

        // Dry again: the ground fault stays until power is cycled, and the master still gets answers.
        bench.inputs.set(dry(&bench.config));
        bench.order(60);
        bench.elapse(Duration::from_millis(50));
        bench.send(READ);
        bench.elapse(Duration::from_millis(1));
        assert!(bench.last_status().faults().contains(Faults::GROUND));
        assert_eq!(bench.bridge.get().0, COAST);
    }
}

/// The post-mortem ring, where the binding's handlers find what happened before a stop: the tasks note the link
/// failsafe's trip and a fault's stop of the motor, once each.
#[test]
fn orders_lost_and_a_faults_stop_are_noted_in_the_post_mortem_ring() {
    for family in Family::ALL {
        let mut bench = Bench::new(family);
        let region = Box::leak(Box::new(crash_record::Region::new()));
        let image = crash_record::Image {
            target: 0,
            version: [0; 4],
        };
        assert_eq!(region.start(crash_record::ResetCause(0), image), None);
        bench.shared.keep_crash(region);
        // Silence for its timeout: the failsafe trips once, however long the silence lasts.
        bench.order(60);
        bench.turn(Duration::from_millis(100));
        assert!(bench.duty().value() > 0, "{family:?}");
        bench.turn_until(|bench| bench.duty() == Duty::ZERO);
        let lost_at = now_ms();
        bench.turn(Duration::from_millis(500));
        // Driving again, then a ground fault stops the motor (and stays latched).
        bench.order(60);
        bench.turn(Duration::from_millis(100));
        assert!(bench.duty().value() > 0, "{family:?}");
        let grounded = RawSample {
            water: bench.config.water.raw_at(50_000),
            ..bench.inputs.get()
        };
        bench.inputs.set(grounded);
        bench.turn_until(|bench| bench.bridge.get().0 == COAST);
        let stopped_at = now_ms();
        bench.turn(Duration::from_millis(100));

        let region = bench.shared.take_crash().expect("the region");
        let (events, held) = crash_record::Ring::from_bytes(region.ring).events();
        let noted: Vec<(u64, What)> = events
            .iter()
            .take(usize::from(held))
            .map(|event| (u64::from(event.at_ms), event.what))
            .collect();
        assert_eq!(noted.len(), 3, "{family:?}: {noted:?}");
        assert_eq!(noted[0].1, What::Started(0));
        assert_eq!(noted[1], (lost_at, What::OrdersLost), "{family:?}");
        // 50 kohm is a ground fault, and below the water threshold too.
        let wet = What::FaultLatched(Faults::GROUND.union(Faults::WATER).bits().into());
        assert_eq!(noted[2].1, wet, "{family:?}: {noted:?}");
        assert!(
            noted[2].0 <= stopped_at && stopped_at - noted[2].0 <= 1,
            "{family:?}: {noted:?}"
        );
    }
}

#[test]
fn latches_outlast_a_reset_but_not_a_power_cycle() {
    for family in Family::ALL {
        let mut before = Bench::new(family);
        before.inputs.set(RawSample {
            water: before.config.water.raw_at(50_000),
            ..dry(&before.config)
        });
        before.elapse(Duration::from_millis(5));
        let stored = before.latch.get();
        drop(before);
        // The same controller after a watchdog or pin reset: fresh tasks, the store kept, dry electrodes.
        let mut after = Bench::with(Config::reference(family, MotorKind::Brushless), stored);
        after.order(60);
        after.elapse(Duration::from_millis(100));
        after.send(READ);
        after.elapse(Duration::from_millis(1));
        assert!(after.last_status().faults().contains(Faults::GROUND), "{family:?}");
        assert_eq!(
            after.last_status().faults().contains(Faults::WATER),
            family == Family::Legacy
        );
        assert_eq!(after.bridge.get().0, COAST);
        drop(after);
        // After a power cycle the store is empty and the controller drives.
        let mut cycled = Bench::new(family);
        cycled.order(60);
        cycled.elapse(Duration::from_millis(100));
        assert!(cycled.duty().value() > 0);
    }
}

#[test]
fn status_reads_always_decode_and_bad_orders_change_nothing() {
    let mut bench = Bench::new(Family::SeaBotix);
    bench.order(40);
    let mut bad = Order::new(Speed::new(-90).unwrap()).encode(Family::SeaBotix).to_vec();
    bad[3] ^= 0xFF;
    bench.send(bad);
    bench.send(vec![0x52, 0xF0, 100, 0x52u8.wrapping_add(0xF0).wrapping_add(100)]);
    bench.elapse(Duration::from_millis(10));
    assert_eq!(
        bench.shared.link.try_get().map(|link| link.order.speed.step()),
        Some(40)
    );
    for _ in 0..20 {
        bench.send(READ);
        bench.elapse(Duration::from_millis(1));
    }
    assert_eq!(bench.replies.borrow().len(), 20);
    for reply in bench.replies.borrow().iter() {
        Status::decode(Family::SeaBotix, reply).expect("every status decodes");
    }
}

#[test]
fn the_watchdog_is_fed_only_while_every_task_reports() {
    let mut bench = Bench::new(Family::SeaBotix);
    bench.elapse(Duration::from_millis(500));
    // Fed at every feed period: no task misses a check.
    let periods = (500 / bench.config.watchdog.feed.as_millis()) as u32;
    assert_eq!(bench.fed.get(), periods, "fed {} times in 500 ms", bench.fed.get());
}

#[test]
fn commutation_runs_on_edges_and_changes_and_still_reports_to_the_watchdog_at_rest() {
    let mut bench = Bench::new(Family::SeaBotix);
    bench.elapse(Duration::from_millis(100));
    // At rest with nothing changing, only its heartbeat wakes it: 10 s, 500 heartbeats, not 10 000 ticks.
    let before = bench.applied.get();
    bench.elapse(Duration::from_secs(10));
    let heartbeats = (10_000 / COMMUTATION_HEARTBEAT.as_millis()) as u32;
    assert!(
        (heartbeats - 1..=heartbeats + 1).contains(&(bench.applied.get() - before)),
        "{} runs in 10 s",
        bench.applied.get() - before
    );
    // And the watchdog is fed at every feed period all along.
    let periods = (10_100 / bench.config.watchdog.feed.as_millis()) as u32;
    assert_eq!(bench.fed.get(), periods);

    // Turning under orders that change, the bridge always carries the duty the control task last decided, in the
    // step it was decided: each change wakes the commutation task.
    bench.order(60);
    let mut checked = 0;
    for step in 0..3000 {
        if step == 1500 {
            bench.order(-30);
        }
        let end = Instant::now() + Duration::from_micros(100);
        bench.turn_until(|_| Instant::now() >= end);
        let decided = bench.shared.duty.try_get().unwrap_or(Duty::ZERO);
        if bench.shared.sensed.try_get().is_some_and(|sensed| sensed.drive_allowed) {
            assert_eq!(bench.duty(), decided, "at {} us", Instant::now().as_micros());
            checked += 1;
        }
    }
    assert!(
        checked > 2500 && bench.duty().value() < 0,
        "{checked} checks, duty {:?}",
        bench.duty()
    );
}

/// Drive forward, then `inject` a condition; returns how long the bridge took to coast (None: it kept driving
/// for 50 ms) and the faults then reported.
fn inject(family: Family, inject: impl Fn(&Bench)) -> (Option<Duration>, Faults, Bench) {
    let mut bench = Bench::new(family);
    let mut reaction = None;
    bench.order(60);
    bench.turn(Duration::from_millis(100));
    assert!(bench.duty().value() > 0, "driving before the fault");
    inject(&bench);
    // The halls now hold still (the condition is not overwritten), well short of the 400 ms stall window.
    let start = Instant::now();
    while bench.bridge.get().0 != COAST && Instant::now() - start < Duration::from_millis(50) {
        bench.elapse(Duration::from_micros(100));
    }
    let took = Instant::now() - start;
    if bench.bridge.get().0 == COAST {
        reaction = Some(took);
    }
    // The status frame follows within the filters' samples and a control step.
    bench.elapse(filtered() + CONTROL_PERIOD);
    bench.send(READ);
    bench.elapse(Duration::from_millis(1));
    let faults = bench.last_status().faults();
    (reaction, faults, bench)
}

/// How long a filtered fault (water, ground, hall) takes at most: its consecutive samples.
fn filtered() -> Duration {
    let samples = Thresholds::SPEC.latch_samples.max(Thresholds::SPEC.hall_error_samples);
    SAMPLE_PERIOD * u32::from(samples)
}

fn set_water(bench: &Bench, ohms: u32) {
    bench.inputs.set(RawSample {
        water: bench.config.water.raw_at(ohms),
        ..bench.inputs.get()
    });
}

fn set_temperature(bench: &Bench, decicelsius: i16) {
    bench.inputs.set(RawSample {
        temperature: bench.config.ntc.raw_at(decicelsius),
        ..bench.inputs.get()
    });
}

#[test]
fn water_stops_a_legacy_controller_but_only_warns_on_a_seabotix_one() {
    let (reaction, faults, _) = inject(Family::Legacy, |bench| set_water(bench, 500_000));
    assert!(
        reaction.is_some_and(|took| took <= filtered()),
        "legacy reaction {reaction:?}"
    );
    assert_eq!(faults, Faults::WATER);

    let (reaction, faults, _) = inject(Family::SeaBotix, |bench| set_water(bench, 500_000));
    assert_eq!(reaction, None, "SeaBotix keeps driving on water");
    assert_eq!(faults, Faults::WATER);
}

#[test]
fn overtemperature_stops_within_its_filter_and_resumes_after_cooling_to_100_c() {
    for family in Family::ALL {
        let (reaction, faults, mut bench) = inject(family, |bench| set_temperature(bench, 1105));
        assert!(
            reaction.is_some_and(|took| took <= filtered()),
            "{family:?}: {reaction:?}"
        );
        assert_eq!(faults, Faults::OVERTEMP);
        set_temperature(&bench, 1010);
        bench.order(60);
        bench.elapse(Duration::from_millis(20));
        assert_eq!(bench.duty(), Duty::ZERO, "101 C is still too hot");
        set_temperature(&bench, 995);
        // The halls have stood still since the stop: once the tracker reads standstill the speed loop ramps up
        // from rest (while it still reads the old speed, the loop would only brake).
        bench.elapse(crate::hall::HallTracker::STANDSTILL);
        assert!(bench.duty().value() > 0, "resumes below 100 C");
    }
}

#[test]
fn a_stalled_propeller_stops_the_motor_400_ms_after_the_duty_passes_8_percent_until_a_zero_order() {
    let mut bench = Bench::new(Family::SeaBotix);
    // The halls never move: the rotor is held.
    bench.order(60);
    let mut above_8_percent = None;
    while bench.bridge.get().0 != COAST || above_8_percent.is_none() {
        bench.elapse(Duration::from_micros(100));
        if above_8_percent.is_none() && bench.duty().magnitude() > 800 {
            above_8_percent = Some(Instant::now());
        }
    }
    let stalled_after = Instant::now() - above_8_percent.unwrap();
    assert!(
        (Duration::from_millis(400)..=Duration::from_millis(402)).contains(&stalled_after),
        "stalled after {stalled_after:?}"
    );
    bench.send(READ);
    bench.elapse(Duration::from_millis(1));
    assert_eq!(bench.last_status().faults(), Faults::STALL);

    // Another non-zero order does not clear the stall; a zero order does, and the next order drives again.
    bench.order(30);
    bench.elapse(Duration::from_millis(20));
    assert_eq!(bench.duty(), Duty::ZERO);
    bench.order(0);
    bench.elapse(Duration::from_millis(5));
    bench.order(30);
    bench.elapse(Duration::from_millis(20));
    assert!(bench.duty().value() > 0);
    // The stall was set after the last read: this read still carries it, the next one is clean.
    bench.send(READ);
    bench.elapse(Duration::from_millis(1));
    assert_eq!(bench.last_status().faults(), Faults::STALL);
    bench.send(READ);
    bench.elapse(Duration::from_millis(1));
    assert!(bench.last_status().faults().is_empty());
}

#[test]
fn an_invalid_hall_state_coasts_at_once_and_clears_when_the_halls_read_normal() {
    for family in Family::ALL {
        let (reaction, faults, mut bench) = inject(family, |bench| bench.halls.set(HallState::from_bits(0b000)));
        assert!(
            reaction.is_some_and(|took| took <= Duration::from_micros(100)),
            "{family:?}: {reaction:?}"
        );
        assert_eq!(faults, Faults::HALL);
        bench.halls.set(FORWARD_SEQUENCE[2]);
        bench.elapse(Duration::from_millis(5));
        bench.order(60);
        bench.elapse(Duration::from_millis(20));
        assert!(bench.duty().value() > 0, "drives again once the halls read normal");
        assert_eq!(bench.bridge.get().0, drive_for(FORWARD_SEQUENCE[2], bench.duty()));
    }
}

#[test]
fn a_brushed_build_drives_an_h_bridge_proportionally_and_reports_itself_brushed() {
    let mut bench = Bench::brushed(Family::SeaBotix);
    bench.order(51);
    // No halls on a brushed motor, so no stall or hall fault either: the order holds. Step 102 is the power
    // stage's largest duty, so step 51 is half of it.
    let max = i32::from(crate::speed::MAX_DUTY);
    bench.elapse(Duration::from_millis(600));
    assert_eq!(
        bench.bridge.get(),
        (
            [PhaseDrive::Pwm, PhaseDrive::Low, PhaseDrive::Float],
            Duty::new_saturating(max / 2)
        )
    );
    bench.send(READ);
    bench.elapse(Duration::from_millis(1));
    let Status::SeaBotix(status) = bench.last_status() else {
        panic!("wrong family")
    };
    assert_eq!((status.motor, status.speed.step()), (MotorKind::Brushed, 51));
    assert_eq!(status.revision, tmc_proto::SeaBotixStatus::REVISION_BRUSHED);

    bench.order(-102);
    // Half to all of it in reverse at 200 % per second: under 750 ms, well inside the link timeout.
    bench.elapse(Duration::from_millis(900));
    assert_eq!(
        bench.bridge.get(),
        (
            [PhaseDrive::Low, PhaseDrive::Pwm, PhaseDrive::Float],
            Duty::new_saturating(-max)
        )
    );
}

#[test]
fn a_failed_transfer_reinitialises_the_slave_and_changes_nothing() {
    let mut bench = Bench::new(Family::SeaBotix);
    bench.order(25);
    bench.elapse(Duration::from_millis(2));
    bench.bus.disturb(bench.device);
    bench.order(-80);
    bench.elapse(Duration::from_millis(2));
    assert_eq!(bench.bus.target_resets(bench.device), 1);
    assert_eq!(
        bench
            .shared
            .link
            .try_get()
            .map(|link| (link.orders, link.order.speed.step())),
        Some((1, 25))
    );

    bench.bus.disturb(bench.device);
    bench.send(READ);
    bench.send(READ);
    bench.elapse(Duration::from_millis(2));
    assert_eq!(bench.bus.target_resets(bench.device), 2);
    assert_eq!(
        bench.replies.borrow().len(),
        1,
        "the read after the failed one is answered"
    );
    bench.order(-80);
    bench.elapse(Duration::from_millis(2));
    assert_eq!(
        bench.shared.link.try_get().map(|link| link.order.speed.step()),
        Some(-80)
    );
}

#[test]
fn the_image_configuration_is_the_reference_hardware_with_the_spec_timings() {
    for family in Family::ALL {
        let config = Config::reference(family, MotorKind::Brushless);
        assert_eq!(
            (config.bus.frequency_hz, config.bus.timeout),
            (100_000, Duration::from_millis(25))
        );
        assert_eq!(config.link_timeout, Duration::from_secs(1));
        // Every task reports within a feed period and the IWDG outlasts two of them at the fastest LSI; the IWDG
        // driver takes the timeout in microseconds.
        assert_eq!(config.watchdog.schedule(&config.bus).check().map(|_| ()), Ok(()));
        // The commutation task, woken by edges and changes only, reports by its heartbeat: within the schedule.
        let schedule = config.watchdog.schedule(&config.bus);
        assert!(u64::from(schedule.slowest_report_us) >= COMMUTATION_HEARTBEAT.as_micros());
        assert_eq!(config.watchdog.timeout_us(), 250_000);
        // A 50 ms feed would miss the I2C task's reports (50 ms heartbeat + 25 ms transfer) and warn falsely.
        let eager = WatchdogTiming {
            feed: Duration::from_millis(50),
            ..config.watchdog
        };
        assert_eq!(
            eager.schedule(&config.bus).check().map(|_| ()),
            Err(g431_hw::iwdg::ScheduleError::ReportSlowerThanFeed)
        );
    }
    assert_eq!(crate::CONFIG.family, crate::FAMILY);
    let forever = WatchdogTiming {
        feed: Duration::from_secs(1),
        timeout: Duration::from_secs(10_000),
    };
    assert_eq!(forever.timeout_us(), u32::MAX, "saturates");
}

/// The three shunts' raw readings with a motor current of `deciamps` returning through phase B's low switch, and
/// phase A switching (its high switch on: nothing on its shunt).
fn shunts(config: &Config, deciamps: u32) -> [u16; 3] {
    let counts = deciamps * 100 / u32::from(config.current.milliamps_per_count);
    let offset = config.current.offset_raw;
    [offset, u16::try_from(u32::from(offset) + counts).unwrap(), offset]
}

#[test]
fn a_locked_brushed_rotor_stalls_400_ms_into_it_until_a_zero_order() {
    for family in Family::ALL {
        let mut bench = Bench::brushed(family);
        bench.order(102);
        // The ramp reaches the full duty within 0.5 s; a propeller turning draws 4 A.
        bench.inputs.set(RawSample {
            currents: shunts(&bench.config, 40),
            ..bench.inputs.get()
        });
        bench.elapse(Duration::from_millis(900));
        bench.order(102);
        assert!(bench.duty().magnitude() > 9000, "{family:?}: turning at full duty");
        // The rotor locks: 20 A at full duty through the 1.2 ohm winding, at 24 V, proportional to the duty. The
        // current limit brings the duty down to hold 7 A; nothing turns.
        let start = Instant::now();
        while bench.bridge.get().0 != COAST && Instant::now() - start < Duration::from_secs(1) {
            let locked = u32::from(bench.duty().magnitude()) * 200 / 10_000;
            bench.inputs.set(RawSample {
                currents: shunts(&bench.config, locked),
                ..bench.inputs.get()
            });
            bench.elapse(Duration::from_micros(100));
        }
        let took = Instant::now() - start;
        assert!(
            (Duration::from_millis(400)..=Duration::from_millis(403)).contains(&took),
            "{family:?}: stalled after {took:?}"
        );
        bench.send(READ);
        bench.elapse(Duration::from_millis(1));
        assert!(bench.last_status().faults().contains(Faults::STALL));
        // Latched until a zero order, as for brushless.
        bench.inputs.set(dry(&bench.config));
        bench.order(102);
        bench.elapse(Duration::from_millis(50));
        assert_eq!(bench.duty(), Duty::ZERO);
        bench.order(0);
        bench.elapse(Duration::from_millis(5));
        bench.order(102);
        bench.elapse(Duration::from_millis(50));
        assert!(bench.duty().value() > 0);
    }
}

#[test]
fn a_brushed_motor_over_its_current_limit_is_held_to_it() {
    let mut bench = Bench::brushed(Family::Legacy);
    bench.order(102);
    for _ in 0..2000 {
        // A locked rotor: 20 A at full duty.
        let locked = u32::from(bench.duty().magnitude()) * 200 / 10_000;
        bench.inputs.set(RawSample {
            currents: shunts(&bench.config, locked),
            ..bench.inputs.get()
        });
        bench.elapse(Duration::from_micros(100));
        assert!(locked <= 72, "{locked}");
    }
}

#[test]
fn a_blocked_rotor_rocking_across_a_hall_boundary_stalls() {
    // Rocking half-periods up to 130 ms were not flagged when every edge counted; 50 ms gives 8 edges a window.
    for half_period_ms in [10, 50, 130] {
        let mut bench = Bench::new(Family::SeaBotix);
        bench.order(102);
        let mut above_8_percent = None;
        let start = Instant::now();
        while bench.bridge.get().0 != COAST || above_8_percent.is_none() {
            bench.elapse(Duration::from_micros(100));
            let rocks = (Instant::now() - start).as_millis() / half_period_ms;
            bench.halls.set(FORWARD_SEQUENCE[(rocks % 2) as usize]);
            if above_8_percent.is_none() && bench.duty().magnitude() > 800 {
                above_8_percent = Some(Instant::now());
            }
            assert!(
                Instant::now() - start < Duration::from_secs(2),
                "{half_period_ms} ms: never stalled"
            );
        }
        let stalled_after = Instant::now() - above_8_percent.unwrap();
        assert!(
            (Duration::from_millis(400)..=Duration::from_millis(402)).contains(&stalled_after),
            "{half_period_ms} ms: stalled after {stalled_after:?}"
        );
        bench.send(READ);
        bench.elapse(Duration::from_millis(1));
        assert_eq!(bench.last_status().faults(), Faults::STALL);
    }
}

#[test]
fn the_stall_threshold_sits_at_one_hall_state_per_133_ms() {
    // 3 net states in 400 ms: an edge at least every 133 ms, 60 / (0.1333 s * 6 states * 4 pole pairs) =
    // 18.75 rpm. A motor turning one state per 130 ms (19.2 rpm) runs; one per 140 ms (17.9 rpm) stalls.
    for (period_ms, stalls) in [(130, false), (140, true)] {
        let mut bench = Bench::new(Family::SeaBotix);
        bench.order(102);
        let start = Instant::now();
        while Instant::now() - start < Duration::from_secs(2) {
            bench.elapse(Duration::from_micros(100));
            let elapsed = (Instant::now() - start).as_millis();
            bench.halls.set(FORWARD_SEQUENCE[(elapsed / period_ms % 6) as usize]);
            // Orders keep coming, as from a master, so the link failsafe stays out of it.
            if (Instant::now() - start).as_micros().is_multiple_of(100_000) {
                bench.order(102);
            }
        }
        bench.send(READ);
        bench.elapse(Duration::from_millis(5));
        assert_eq!(
            bench.last_status().faults().contains(Faults::STALL),
            stalls,
            "{period_ms} ms"
        );
        assert_eq!(bench.duty() == Duty::ZERO, stalls, "{period_ms} ms");
    }
}

#[test]
fn hall_glitches_do_not_cut_the_drive_and_a_short_hall_error_is_still_read() {
    for family in Family::ALL {
        let mut bench = Bench::new(family);
        bench.order(60);
        bench.turn(Duration::from_millis(200));
        let before = bench.duty().value();
        assert!(before > 0);
        // 20 glitches of 300 us to 111 while turning: the bridge coasts through each, the drive stays on.
        for _ in 0..20 {
            let sector = bench.halls.get();
            bench.halls.set(HallState::from_bits(0b111));
            bench.elapse(Duration::from_micros(300));
            bench.halls.set(sector);
            bench.turn(Duration::from_millis(20));
            assert!(bench.duty().value() > 0, "{family:?}: the drive was cut");
        }
        bench.send(READ);
        bench.elapse(Duration::from_millis(1));
        assert!(
            bench.last_status().faults().is_empty(),
            "{family:?}: glitches are no hall error"
        );
        // A hall error of 5 ms between two reads 20 ms apart: the next read carries it, the one after does not.
        let sector = bench.halls.get();
        bench.halls.set(HallState::from_bits(0b000));
        bench.elapse(Duration::from_millis(5));
        bench.halls.set(sector);
        bench.elapse(Duration::from_millis(15));
        bench.send(READ);
        bench.elapse(Duration::from_millis(1));
        assert_eq!(bench.last_status().faults(), Faults::HALL, "{family:?}");
        bench.send(READ);
        bench.elapse(Duration::from_millis(1));
        assert!(bench.last_status().faults().is_empty(), "{family:?}");
    }
}

#[test]
fn a_failed_read_keeps_the_unread_fault_for_the_next_one() {
    let mut bench = Bench::new(Family::SeaBotix);
    bench.elapse(Duration::from_millis(5));
    set_temperature(&bench, 1105);
    bench.elapse(Duration::from_millis(3));
    set_temperature(&bench, 250);
    bench.elapse(Duration::from_millis(3));
    // The read fails on the wire: the overtemp it would have carried waits for the next one.
    bench.bus.disturb(bench.device);
    bench.send(READ);
    bench.elapse(Duration::from_millis(2));
    bench.send(READ);
    bench.elapse(Duration::from_millis(1));
    assert_eq!(bench.last_status().faults(), Faults::OVERTEMP);
}

#[test]
fn the_failsafe_shows_in_seabotix_fault_bit_5_until_a_read_after_the_next_order() {
    let mut bench = Bench::new(Family::SeaBotix);
    bench.order(51);
    bench.turn(Duration::from_millis(100));
    bench.send(READ);
    bench.elapse(Duration::from_millis(1));
    let flagged = |bench: &Bench| tmc_proto::SeaBotixStatus::link_failsafe_in(bench.replies.borrow().last().unwrap());
    assert!(!flagged(&bench));
    // 1.1 s of silence: the failsafe stops the motor; the master's next read sees it.
    bench.turn(Duration::from_millis(1100));
    bench.send(READ);
    bench.elapse(Duration::from_millis(1));
    assert!(flagged(&bench), "the first read after the silence");
    // Reads alone do not restart the motor: the bit stays.
    bench.send(READ);
    bench.elapse(Duration::from_millis(1));
    assert!(flagged(&bench));
    // A new order restarts it; the read after it still carries the bit once, then it is gone.
    bench.order(51);
    bench.elapse(Duration::from_millis(5));
    bench.send(READ);
    bench.elapse(Duration::from_millis(1));
    assert!(flagged(&bench));
    bench.send(READ);
    bench.elapse(Duration::from_millis(1));
    assert!(!flagged(&bench));
    // The other faults are as they were: none.
    assert!(bench.last_status().faults().is_empty());
}

/// How long a trip on every sample takes to stop the bridge.
fn sustained() -> Duration {
    SAMPLE_PERIOD * u32::from(Thresholds::SPEC.overcurrent.run_ticks)
}

fn overcurrent_flagged(bench: &Bench) -> bool {
    tmc_proto::SeaBotixStatus::overcurrent_in(bench.replies.borrow().last().unwrap())
}

#[test]
fn isolated_break_trips_are_counted_and_the_motor_keeps_driving() {
    for family in Family::ALL {
        let mut bench = Bench::new(family);
        bench.order(60);
        bench.turn(Duration::from_millis(100));
        // Cycle-by-cycle limiting now and then: a trip on one sample in ten, for 3 s, orders coming.
        for n in 0..3000u32 {
            bench.inputs.set(RawSample {
                break_tripped: n % 10 == 0,
                ..bench.inputs.get()
            });
            bench.turn(Duration::from_millis(1));
            if n % 500 == 0 {
                bench.order(60);
            }
            assert!(bench.duty().value() > 0, "{family:?}: stopped at {n} ms");
        }
        assert!(!bench.held_off.get());
        let trips = bench.shared.sensed.try_get().map(|sensed| sensed.break_trips);
        assert!(
            trips.is_some_and(|trips| (299..=301).contains(&trips)),
            "{family:?}: {trips:?}"
        );
        bench.send(READ);
        bench.elapse(Duration::from_millis(1));
        assert!(bench.last_status().faults().is_empty());
        if family == Family::SeaBotix {
            assert!(!overcurrent_flagged(&bench));
        }
    }
}

#[test]
fn trips_on_a_third_of_the_samples_stop_the_bridge_within_the_window() {
    let limits = Thresholds::SPEC.overcurrent;
    for family in Family::ALL {
        let mut bench = Bench::new(family);
        bench.order(60);
        bench.turn(Duration::from_millis(100));
        // A shorted MOSFET: it shoots through in the two sectors of six where its partner switches (the test's
        // rotor turns a sector every 2 ms), a third of the samples.
        let took = bench.turn_until(|bench| {
            bench.inputs.set(RawSample {
                break_tripped: now_ms() / 2 % 6 < 2,
                ..bench.inputs.get()
            });
            bench.held_off.get()
        });
        let window = SAMPLE_PERIOD * u32::from(limits.window_ticks);
        assert!(took <= window, "{family:?}: held off after {took:?}");
        let trips = bench.shared.sensed.try_get().map(|sensed| sensed.break_trips);
        assert!(
            trips.is_some_and(|trips| trips > u32::from(limits.window_trips)),
            "{family:?}: {trips:?}"
        );
    }
}

#[test]
fn a_shorted_phase_stops_the_bridge_with_its_outputs_off_until_a_zero_order() {
    for family in Family::ALL {
        let mut bench = Bench::new(family);
        bench.order(60);
        bench.turn(Duration::from_millis(100));
        bench.shorted.set(true);
        let took = bench.turn_until(|bench| bench.held_off.get());
        assert!(
            (sustained() - SAMPLE_PERIOD..=sustained() + SAMPLE_PERIOD).contains(&took),
            "{family:?}: held off after {took:?}"
        );
        // The same step coasts the bridge.
        bench.elapse(Duration::from_micros(100));
        assert_eq!(bench.bridge.get(), (COAST, Duty::ZERO), "{family:?}");
        let sensed = bench.shared.sensed.try_get().unwrap();
        assert!(sensed.overcurrent && !sensed.drive_allowed);
        // The next status read says so on a SeaBotix controller (FAULT bit 6); a Legacy one has no bit for it and
        // reports no fault: its master sees a thruster that does not turn (MAX POWER: no current).
        bench.send(READ);
        bench.elapse(Duration::from_millis(1));
        assert!(
            bench.last_status().faults().is_empty(),
            "{family:?}: none of the IDS's faults"
        );
        match family {
            Family::SeaBotix => assert!(overcurrent_flagged(&bench)),
            Family::Legacy => {
                let Status::Legacy(status) = bench.last_status() else {
                    panic!()
                };
                assert_eq!(status.max_power, tmc_proto::MaxPower::Current { deciamps: 0 });
                assert_eq!(
                    bench.replies.borrow().last().unwrap()[1] & 0xE0,
                    0x20,
                    "the revision bits untouched"
                );
            }
        }

        // A non-zero order does not restart it, short or no short.
        bench.shorted.set(false);
        bench.order(60);
        bench.elapse(Duration::from_millis(100));
        assert!(bench.held_off.get(), "{family:?}");
        assert_eq!(bench.duty(), Duty::ZERO);
        bench.send(READ);
        bench.elapse(Duration::from_millis(1));
        if family == Family::SeaBotix {
            assert!(overcurrent_flagged(&bench), "set for as long as it holds");
        }

        // A zero order clears it: the outputs come back and the next order drives.
        bench.order(0);
        bench.elapse(Duration::from_millis(5));
        assert!(!bench.held_off.get(), "{family:?}");
        bench.order(60);
        // The speed loop starts again from rest, as after any stop (about 70 ms here).
        bench.turn(Duration::from_millis(100));
        assert!(bench.duty().value() > 0, "{family:?}: drives again");
        if family == Family::SeaBotix {
            // The read after the clear still carries the bit once, then it is gone.
            bench.send(READ);
            bench.elapse(Duration::from_millis(1));
            assert!(overcurrent_flagged(&bench));
            bench.send(READ);
            bench.elapse(Duration::from_millis(1));
            assert!(!overcurrent_flagged(&bench));
            assert!(bench.last_status().faults().is_empty());
        }
    }
}

#[test]
fn a_short_that_stays_trips_again_after_each_zero_order() {
    let mut bench = Bench::new(Family::SeaBotix);
    bench.order(60);
    bench.turn(Duration::from_millis(100));
    bench.shorted.set(true);
    bench.turn_until(|bench| bench.held_off.get());
    for _ in 0..2 {
        bench.order(0);
        bench.elapse(Duration::from_millis(5));
        assert!(!bench.held_off.get());
        bench.order(60);
        let took = bench.turn_until(|bench| bench.held_off.get());
        // The speed loop restarts from rest (about 70 ms) before the bridge switches for the short to trip on.
        assert!(
            took >= sustained() && took <= sustained() + Duration::from_millis(100),
            "held off again after {took:?}"
        );
    }
    let trips = bench.shared.sensed.try_get().map(|sensed| sensed.break_trips);
    let at_least = 3 * u32::from(Thresholds::SPEC.overcurrent.run_ticks);
    assert!(trips.is_some_and(|trips| trips >= at_least), "{trips:?}");
}

#[test]
fn the_adc_conversions_of_a_sample_fit_the_tick() {
    // The binding reads water, NTC and VBUS with blocking conversions (`g431_hw::adc::THRUSTER_SEQUENCE`) once per
    // sample tick, holding the thread executor meanwhile; TIM1's injected conversions of the currents may pre-empt
    // them once per 50 us PWM period. At DS12589's sample times that is under 32 us of the 1 ms tick, kept under
    // 5 % of both the sample and the control tick.
    let periods = g431_hw::adc::THRUSTER_SEQUENCE_NS / 50_000.0;
    let sequence_us =
        (g431_hw::adc::THRUSTER_SEQUENCE_NS + (periods.floor() + 1.0) * g431_hw::adc::CURRENT_SEQUENCE_NS) / 1000.0;
    assert!((30.0..32.0).contains(&sequence_us), "{sequence_us} us");
    for tick in [SAMPLE_PERIOD, CONTROL_PERIOD] {
        assert!(
            sequence_us < 0.05 * tick.as_micros() as f64,
            "{sequence_us} us of {tick:?}"
        );
    }
}

/// The master's poll, as lbv-master-fw runs it: an order at 50 Hz, each followed by a status read.
fn poll(bench: &mut Bench, step: i8, duration: Duration) {
    let end = Instant::now() + duration;
    while Instant::now() < end {
        bench.order(step);
        bench.send(READ);
        bench.elapse(Duration::from_millis(20));
    }
}

/// The master asks the thruster its `Version` over the field-update extension, as it asks an image on trial every
/// few seconds; the next reads of the poll get its reply.
fn ask_version(bench: &Bench) {
    use tmc_proto::ext::{Command, CommandFrame};
    let frame = CommandFrame {
        seq: 1,
        command: Command::Version,
    };
    bench.send(frame.encode().as_bytes().to_vec());
}

#[test]
fn a_new_image_confirms_itself_once_it_has_run_and_answered_the_master_at_rest() {
    let mut bench = Bench::on_trial();
    // Orders from the start: the trial's 25 orders come in half a second, its 30 watchdog rounds take 3 s.
    poll(&mut bench, 0, Duration::from_millis(2900));
    assert_eq!(bench.boot_state(), State::Swap, "confirmed before its watchdog rounds");
    poll(&mut bench, 0, Duration::from_millis(200));
    assert_eq!(
        bench.boot_state(),
        State::Swap,
        "confirmed before the master has read an extension reply: the path of the next update"
    );
    ask_version(&bench);
    poll(&mut bench, 0, Duration::from_millis(200));
    assert_eq!(
        bench.boot_state(),
        State::Boot,
        "confirmed after 3 s of health and orders"
    );
    // Confirmed once: the state page was erased once and is left alone from then on.
    let erases = bench.boot.stats().erases;
    poll(&mut bench, 0, Duration::from_secs(2));
    assert_eq!(bench.boot.stats().erases, erases);
}

#[test]
fn a_new_image_stays_on_trial_without_a_master_or_while_it_drives() {
    let mut bench = Bench::on_trial();
    bench.elapse(Duration::from_secs(5));
    assert_eq!(bench.boot_state(), State::Swap, "no master has spoken to it");

    // Ordered to turn, its version asked: the state page's erase would stall commutation, so it waits for a zero
    // order.
    ask_version(&bench);
    let end = Instant::now() + Duration::from_secs(5);
    while Instant::now() < end {
        bench.order(40);
        bench.send(READ);
        let next = Instant::now() + Duration::from_millis(20);
        bench.turn_until(|_| Instant::now() >= next);
    }
    assert_eq!(bench.boot_state(), State::Swap, "confirmed while driving");
    // At rest, with the master still polling, it confirms.
    poll(&mut bench, 0, Duration::from_secs(1));
    assert_eq!(bench.boot_state(), State::Boot);
}

#[test]
fn an_image_not_on_trial_leaves_the_bootloader_state_alone() {
    let mut bench = Bench::new(Family::SeaBotix);
    poll(&mut bench, 0, Duration::from_secs(5));
    assert_eq!(bench.boot_state(), State::Boot);
    assert_eq!(bench.boot.stats().erases, 0);
}

mod update;
