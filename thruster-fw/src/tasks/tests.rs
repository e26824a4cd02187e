//! The tasks together, on virtual time: a scripted master, simulated halls, bridge and ADC inputs.

use super::*;
use crate::faults::VolatileLatch;
use crate::hall::FORWARD_SEQUENCE;
use crate::i2c_slave::Request;
use core::cell::{Cell, RefCell};
use embassy_futures::block_on;
use embassy_futures::join::join5;
use embassy_futures::select::{Either, select};
use embassy_futures::yield_now;
use embassy_time::MockDriver;
use std::collections::VecDeque;
use tmc_proto::{Faults, Order, Speed, Status};

/// The master's side of the bus: transfers queued by the test, status replies collected.
#[derive(Default)]
struct Master {
    queue: RefCell<VecDeque<Vec<u8>>>,
    replies: RefCell<Vec<Vec<u8>>>,
    resets: Cell<u32>,
    /// The next transfer fails on the bus (a glitch, a master reset mid-transfer, a stalled clock).
    fail_next: Cell<bool>,
}

/// An empty transfer stands for a read.
const READ: Vec<u8> = Vec::new();

struct MasterPort<'a> {
    master: &'a Master,
    pending: Option<Vec<u8>>,
}

impl I2cTarget for MasterPort<'_> {
    type Error = ();

    async fn listen(&mut self) -> Result<Request, ()> {
        loop {
            if let Some(transfer) = self.master.queue.borrow_mut().pop_front() {
                let request = if transfer.is_empty() {
                    Request::Read
                } else {
                    Request::Write
                };
                self.pending = Some(transfer);
                return Ok(request);
            }
            yield_now().await;
        }
    }

    async fn respond_to_write(&mut self, buffer: &mut [u8]) -> Result<usize, ()> {
        let bytes = self.pending.take().ok_or(())?;
        if self.master.fail_next.replace(false) {
            return Err(());
        }
        let stored = bytes.len().min(buffer.len());
        buffer[..stored].copy_from_slice(&bytes[..stored]);
        Ok(stored)
    }

    async fn respond_to_read(&mut self, data: &[u8]) -> Result<(), ()> {
        if self.master.fail_next.replace(false) {
            return Err(());
        }
        self.master.replies.borrow_mut().push(data.to_vec());
        Ok(())
    }

    fn reset(&mut self) {
        self.master.resets.set(self.master.resets.get() + 1);
    }
}

/// Hall inputs the test sets; every change is an edge.
struct TestHalls<'a>(&'a Cell<HallState>, HallState);

impl HallSensors for TestHalls<'_> {
    async fn wait_for_edge(&mut self) {
        while self.0.get() == self.1 {
            yield_now().await;
        }
        self.1 = self.0.get();
    }

    fn read(&mut self) -> HallState {
        self.1 = self.0.get();
        self.1
    }
}

/// The bridge as last driven.
struct TestBridge<'a>(&'a Cell<(BridgeDrive, Duty)>);

impl Bridge for TestBridge<'_> {
    fn apply(&mut self, drive: BridgeDrive, duty: Duty) {
        self.0.set((drive, duty));
    }
}

struct TestSensors<'a>(&'a Cell<RawSample>);

impl Sensors for TestSensors<'_> {
    async fn sample(&mut self) -> RawSample {
        self.0.get()
    }
}

/// A healthy controller's inputs: dry, 25 C, no current.
fn dry(config: &Config) -> RawSample {
    RawSample {
        water: 0,
        temperature: config.ntc.raw_at(250),
        current: config.current.offset_raw,
    }
}

/// One controller with its five tasks, and what a test can see and touch.
struct Bench {
    config: Config,
    shared: Shared,
    master: Master,
    halls: Cell<HallState>,
    bridge: Cell<(BridgeDrive, Duty)>,
    inputs: Cell<RawSample>,
    fed: Cell<u32>,
    /// The latch store, carried from one run to the next as a backup register is over a reset.
    latch: Cell<VolatileLatch>,
}

struct CountingWatchdog<'a>(&'a Cell<u32>);

impl Watchdog for CountingWatchdog<'_> {
    fn feed(&mut self) {
        self.0.set(self.0.get() + 1);
    }
}

impl Bench {
    fn new(family: Family) -> Self {
        Self::with(Config::reference(family, MotorKind::Brushless))
    }

    fn brushed(family: Family) -> Self {
        Self::with(Config::reference(family, MotorKind::Brushed))
    }

    fn with(config: Config) -> Self {
        let inputs = Cell::new(dry(&config));
        Self {
            config,
            shared: Shared::new(),
            master: Master::default(),
            halls: Cell::new(FORWARD_SEQUENCE[0]),
            bridge: Cell::new((COAST, Duty::ZERO)),
            inputs,
            fed: Cell::new(0),
            latch: Cell::new(VolatileLatch::default()),
        }
    }

    /// Run the controller's tasks alongside `script` until the script ends; virtual time starts at 0.
    fn run(&self, script: impl Future<Output = ()>) {
        let _clock = crate::test_clock::lock();
        let mut port = MasterPort {
            master: &self.master,
            pending: None,
        };
        let mut halls = TestHalls(&self.halls, self.halls.get());
        let mut bridge = TestBridge(&self.bridge);
        let mut sensors = TestSensors(&self.inputs);
        let mut watchdog = CountingWatchdog(&self.fed);
        let mut latch = self.latch.get();
        let tasks = join5(
            i2c_task(&mut port, self.config.family, self.config.motor, &self.shared),
            commutation_task(
                &mut halls,
                &mut bridge,
                self.config.motor,
                self.config.pole_pairs,
                &self.shared,
            ),
            fault_task(&mut sensors, &mut latch, &self.config, &self.shared),
            control_task(&self.config, &self.shared),
            health_task(&mut watchdog, Duration::from_millis(50), &self.shared),
        );
        match block_on(select(tasks, script)) {
            Either::First(_) => unreachable!("the tasks never end"),
            Either::Second(()) => {}
        }
        self.latch.set(latch);
    }

    fn send(&self, bytes: Vec<u8>) {
        self.master.queue.borrow_mut().push_back(bytes);
    }

    fn order(&self, step: i8) {
        self.send(
            Order::new(Speed::new(step).unwrap())
                .encode(self.config.family)
                .to_vec(),
        );
    }

    fn last_status(&self) -> Status {
        let replies = self.master.replies.borrow();
        let decoded = Status::decode(self.config.family, replies.last().expect("a status was read"));
        let decoded = decoded.expect("status decodes");
        assert_eq!(decoded.warning, None);
        decoded.status
    }

    fn duty(&self) -> Duty {
        self.bridge.get().1
    }
}

/// Let virtual time pass in 100 us steps, giving every task its turn at each step.
async fn elapse(duration: Duration) {
    let step = Duration::from_micros(100);
    let mut left = duration;
    while left > Duration::from_ticks(0) {
        let now = step.min(left);
        MockDriver::get().advance(now);
        left -= now;
        for _ in 0..4 {
            yield_now().await;
        }
    }
}

/// Let virtual time pass with the motor turning forward at 1250 rpm (4 pole pairs: a hall edge every 2 ms),
/// until `done` says stop; returns how long that took.
async fn turn_until(bench: &Bench, mut done: impl FnMut() -> bool) -> Duration {
    let start = Instant::now();
    while !done() {
        elapse(Duration::from_micros(100)).await;
        let sector = (Instant::now().as_micros() / 2000 % 6) as usize;
        bench.halls.set(FORWARD_SEQUENCE[sector]);
    }
    Instant::now() - start
}

/// Turn the motor for `duration`.
async fn turn(bench: &Bench, duration: Duration) {
    let end = Instant::now() + duration;
    turn_until(bench, || Instant::now() >= end).await;
}

/// Milliseconds since the run started.
fn now_ms() -> u64 {
    Instant::now().as_millis()
}

#[test]
fn an_order_drives_the_bridge_forward_and_the_status_says_so() {
    let bench = Bench::new(Family::SeaBotix);
    bench.run(async {
        elapse(Duration::from_millis(5)).await;
        assert_eq!(bench.bridge.get().0, COAST, "stopped until ordered");
        bench.order(51);
        elapse(Duration::from_millis(20)).await;
        let (drive, duty) = bench.bridge.get();
        assert!(duty.value() > 0, "forward duty, got {duty:?}");
        assert_eq!(drive, drive_for(bench.halls.get(), duty));
        bench.send(READ);
        elapse(Duration::from_millis(1)).await;
        assert!(bench.last_status().faults().is_empty());
    });
}

#[test]
fn the_failsafe_stops_the_motor_after_exactly_one_second_of_silence() {
    let bench = Bench::new(Family::SeaBotix);
    bench.run(async {
        bench.order(51);
        // The order is taken within the first 100 us step.
        elapse(Duration::from_micros(100)).await;
        assert_eq!(bench.shared.link.try_get().map(|link| link.orders), Some(1));
        let ordered_at = now_ms();
        turn(&bench, Duration::from_millis(990)).await;
        assert!(
            bench.duty().value() > 0,
            "still driving at {} ms",
            now_ms() - ordered_at
        );
        turn_until(&bench, || bench.duty() == Duty::ZERO).await;
        let stopped_after = now_ms() - ordered_at;
        assert!(
            (1000..=1001).contains(&stopped_after),
            "stopped after {stopped_after} ms"
        );
        assert_eq!(bench.bridge.get().0, COAST);

        // The motor coasts to a stop. A read keeps the link alive but does not restart the motor; the next valid
        // order does.
        elapse(Duration::from_millis(200)).await;
        bench.send(READ);
        elapse(Duration::from_millis(20)).await;
        assert_eq!(bench.duty(), Duty::ZERO);
        bench.order(20);
        elapse(Duration::from_millis(20)).await;
        assert!(bench.duty().value() > 0);
    });
}

#[test]
fn reads_alone_keep_the_link_alive() {
    let bench = Bench::new(Family::Legacy);
    bench.run(async {
        bench.order(30);
        for _ in 0..30 {
            turn(&bench, Duration::from_millis(100)).await;
            bench.send(READ);
        }
        assert!(bench.duty().value() > 0, "still driving after 3 s of reads");
    });
}

#[test]
fn a_ground_fault_coasts_the_bridge_within_one_sample_and_latches() {
    for family in Family::ALL {
        let bench = Bench::new(family);
        bench.run(async {
            bench.order(60);
            turn(&bench, Duration::from_millis(100)).await;
            assert!(bench.duty().value() > 0);
            let wet = RawSample {
                water: bench.config.water.raw_at(50_000),
                ..bench.inputs.get()
            };
            bench.inputs.set(wet);
            let reaction = turn_until(&bench, || bench.bridge.get().0 == COAST).await;
            assert!(reaction <= SAMPLE_PERIOD, "coasted after {reaction:?}");

            // Dry again: the ground fault stays until power is cycled, and the master still gets answers.
            bench.inputs.set(dry(&bench.config));
            bench.order(60);
            elapse(Duration::from_millis(50)).await;
            bench.send(READ);
            elapse(Duration::from_millis(1)).await;
            assert!(bench.last_status().faults().contains(Faults::GROUND));
            assert_eq!(bench.bridge.get().0, COAST);
        });
    }
}

#[test]
fn latches_outlast_a_reset_but_not_a_power_cycle() {
    for family in Family::ALL {
        let before = Bench::new(family);
        before.run(async {
            before.inputs.set(RawSample {
                water: before.config.water.raw_at(50_000),
                ..dry(&before.config)
            });
            elapse(Duration::from_millis(5)).await;
        });
        let stored = before.latch.get();
        // The same controller after a watchdog or pin reset: fresh tasks, the store kept, dry electrodes.
        let after = Bench::new(family);
        after.latch.set(stored);
        after.run(async {
            after.order(60);
            elapse(Duration::from_millis(100)).await;
            after.send(READ);
            elapse(Duration::from_millis(1)).await;
            assert!(after.last_status().faults().contains(Faults::GROUND), "{family:?}");
            assert_eq!(
                after.last_status().faults().contains(Faults::WATER),
                family == Family::Legacy
            );
            assert_eq!(after.bridge.get().0, COAST);
        });
        // After a power cycle the store is empty and the controller drives.
        let cycled = Bench::new(family);
        cycled.run(async {
            cycled.order(60);
            elapse(Duration::from_millis(100)).await;
            assert!(cycled.duty().value() > 0);
        });
    }
}

#[test]
fn status_reads_always_decode_and_bad_orders_change_nothing() {
    let bench = Bench::new(Family::SeaBotix);
    bench.run(async {
        bench.order(40);
        let mut bad = Order::new(Speed::new(-90).unwrap()).encode(Family::SeaBotix).to_vec();
        bad[3] ^= 0xFF;
        bench.send(bad);
        bench.send(vec![0x52, 0xF0, 100, 0x52u8.wrapping_add(0xF0).wrapping_add(100)]);
        elapse(Duration::from_millis(10)).await;
        assert_eq!(
            bench.shared.link.try_get().map(|link| link.order.speed.step()),
            Some(40)
        );
        for _ in 0..20 {
            bench.send(READ);
            elapse(Duration::from_millis(1)).await;
        }
        assert_eq!(bench.master.replies.borrow().len(), 20);
        for reply in bench.master.replies.borrow().iter() {
            Status::decode(Family::SeaBotix, reply).expect("every status decodes");
        }
    });
}

#[test]
fn the_watchdog_is_fed_only_while_every_task_reports() {
    let bench = Bench::new(Family::SeaBotix);
    bench.run(async {
        elapse(Duration::from_millis(500)).await;
        assert!(bench.fed.get() >= 9, "fed {} times in 500 ms", bench.fed.get());
    });
}

/// Drive forward, then `inject` a condition; returns how long the bridge took to coast (None: it kept driving
/// for 50 ms) and the faults then reported.
fn inject(family: Family, inject: impl Fn(&Bench)) -> (Option<Duration>, Faults, Bench) {
    let bench = Bench::new(family);
    let mut reaction = None;
    bench.run(async {
        bench.order(60);
        turn(&bench, Duration::from_millis(100)).await;
        assert!(bench.duty().value() > 0, "driving before the fault");
        inject(&bench);
        // The halls now hold still (the condition is not overwritten), well short of the 400 ms stall window.
        let start = Instant::now();
        while bench.bridge.get().0 != COAST && Instant::now() - start < Duration::from_millis(50) {
            elapse(Duration::from_micros(100)).await;
        }
        let took = Instant::now() - start;
        if bench.bridge.get().0 == COAST {
            reaction = Some(took);
        }
        // The status frame follows within a fault sample and a control step.
        elapse(SAMPLE_PERIOD + CONTROL_PERIOD).await;
        bench.send(READ);
        elapse(Duration::from_millis(1)).await;
    });
    let faults = bench.last_status().faults();
    (reaction, faults, bench)
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
        reaction.is_some_and(|took| took <= SAMPLE_PERIOD),
        "legacy reaction {reaction:?}"
    );
    assert_eq!(faults, Faults::WATER);

    let (reaction, faults, _) = inject(Family::SeaBotix, |bench| set_water(bench, 500_000));
    assert_eq!(reaction, None, "SeaBotix keeps driving on water");
    assert_eq!(faults, Faults::WATER);
}

#[test]
fn overtemperature_stops_within_one_sample_and_resumes_after_cooling_to_100_c() {
    for family in Family::ALL {
        let (reaction, faults, bench) = inject(family, |bench| set_temperature(bench, 1105));
        assert!(
            reaction.is_some_and(|took| took <= SAMPLE_PERIOD),
            "{family:?}: {reaction:?}"
        );
        assert_eq!(faults, Faults::OVERTEMP);
        bench.run(async {
            set_temperature(&bench, 1010);
            bench.order(60);
            elapse(Duration::from_millis(20)).await;
            assert_eq!(bench.duty(), Duty::ZERO, "101 C is still too hot");
            set_temperature(&bench, 995);
            elapse(Duration::from_millis(20)).await;
            assert!(bench.duty().value() > 0, "resumes below 100 C");
        });
    }
}

#[test]
fn a_stalled_propeller_stops_the_motor_400_ms_after_the_duty_passes_8_percent_until_a_zero_order() {
    let bench = Bench::new(Family::SeaBotix);
    bench.run(async {
        // The halls never move: the rotor is held.
        bench.order(60);
        let mut above_8_percent = None;
        while bench.bridge.get().0 != COAST || above_8_percent.is_none() {
            elapse(Duration::from_micros(100)).await;
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
        elapse(Duration::from_millis(1)).await;
        assert_eq!(bench.last_status().faults(), Faults::STALL);

        // Another non-zero order does not clear the stall; a zero order does, and the next order drives again.
        bench.order(30);
        elapse(Duration::from_millis(20)).await;
        assert_eq!(bench.duty(), Duty::ZERO);
        bench.order(0);
        elapse(Duration::from_millis(5)).await;
        bench.order(30);
        elapse(Duration::from_millis(20)).await;
        assert!(bench.duty().value() > 0);
        bench.send(READ);
        elapse(Duration::from_millis(1)).await;
        assert!(bench.last_status().faults().is_empty());
    });
}

#[test]
fn an_invalid_hall_state_coasts_at_once_and_clears_when_the_halls_read_normal() {
    for family in Family::ALL {
        let (reaction, faults, bench) = inject(family, |bench| bench.halls.set(HallState::from_bits(0b000)));
        assert!(
            reaction.is_some_and(|took| took <= Duration::from_micros(100)),
            "{family:?}: {reaction:?}"
        );
        assert_eq!(faults, Faults::HALL);
        bench.run(async {
            bench.halls.set(FORWARD_SEQUENCE[2]);
            elapse(Duration::from_millis(5)).await;
            bench.order(60);
            elapse(Duration::from_millis(20)).await;
            assert!(bench.duty().value() > 0, "drives again once the halls read normal");
            assert_eq!(bench.bridge.get().0, drive_for(FORWARD_SEQUENCE[2], bench.duty()));
        });
    }
}

#[test]
fn a_brushed_build_drives_an_h_bridge_proportionally_and_reports_itself_brushed() {
    let bench = Bench::brushed(Family::SeaBotix);
    bench.run(async {
        bench.order(51);
        // No halls on a brushed motor, so no stall or hall fault either: the order holds. Step 102 is the power
        // stage's largest duty, so step 51 is half of it.
        let max = i32::from(crate::speed::MAX_DUTY);
        elapse(Duration::from_millis(600)).await;
        assert_eq!(
            bench.bridge.get(),
            (
                [PhaseDrive::Pwm, PhaseDrive::Low, PhaseDrive::Float],
                Duty::new_saturating(max / 2)
            )
        );
        bench.send(READ);
        elapse(Duration::from_millis(1)).await;
        let Status::SeaBotix(status) = bench.last_status() else {
            panic!("wrong family")
        };
        assert_eq!((status.motor, status.speed.step()), (MotorKind::Brushed, 51));

        bench.order(-102);
        // Half to all of it in reverse at 200 % per second: under 750 ms, well inside the link timeout.
        elapse(Duration::from_millis(900)).await;
        assert_eq!(
            bench.bridge.get(),
            (
                [PhaseDrive::Low, PhaseDrive::Pwm, PhaseDrive::Float],
                Duty::new_saturating(-max)
            )
        );
    });
}

#[test]
fn a_failed_transfer_reinitialises_the_slave_and_changes_nothing() {
    let bench = Bench::new(Family::SeaBotix);
    bench.run(async {
        bench.order(25);
        elapse(Duration::from_millis(2)).await;
        bench.master.fail_next.set(true);
        bench.order(-80);
        elapse(Duration::from_millis(2)).await;
        assert_eq!(bench.master.resets.get(), 1);
        assert_eq!(
            bench
                .shared
                .link
                .try_get()
                .map(|link| (link.orders, link.order.speed.step())),
            Some((1, 25))
        );

        bench.master.fail_next.set(true);
        bench.send(READ);
        bench.send(READ);
        elapse(Duration::from_millis(2)).await;
        assert_eq!(bench.master.resets.get(), 2);
        assert_eq!(
            bench.master.replies.borrow().len(),
            1,
            "the read after the failed one is answered"
        );
        bench.order(-80);
        elapse(Duration::from_millis(2)).await;
        assert_eq!(
            bench.shared.link.try_get().map(|link| link.order.speed.step()),
            Some(-80)
        );
    });
}
