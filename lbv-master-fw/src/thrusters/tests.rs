//! The state machines alone, then the bus task on a simulated bus on virtual time.

use super::*;
use crate::recovery::BusConfig;
use crate::shared::Outgoing;
use crate::sim::thruster_bus;
use crate::tests::scripted::{Mode, SimThruster, speed};
use core::cell::{RefCell, RefMut};
use embedded_hal::i2c::NoAcknowledgeSource;
use lbv_sim::i2c::{Bus, Data, DeviceId, Route, Timing};
use lbv_sim::{Clock, Executor, clock};
use std::rc::Rc;
use tmc_proto::{MotorKind, SeaBotixStatus, Speed};

/// One bit at 100 kbit/s.
const BIT: Duration = Duration::from_micros(10);

const MS: Duration = Duration::from_millis(1);

fn at_ms(ms: u64) -> Instant {
    Instant::from_millis(ms)
}

fn seabotix_status(faults: Faults) -> Status {
    Status::SeaBotix(SeaBotixStatus {
        revision: 0,
        motor: MotorKind::Brushless,
        current_limited: true,
        faults,
        current_deciamps: 0,
        speed: Speed::ZERO,
        temperature_c: 20,
    })
}

// ---------------------------------------------------------------------------------------------------------------
// PollFailure classification

#[test]
fn bus_errors_are_classified_by_kind() {
    use ErrorKind::*;
    assert_eq!(
        PollFailure::of_bus_error(&NoAcknowledge(NoAcknowledgeSource::Address)),
        PollFailure::Nack
    );
    assert_eq!(
        PollFailure::of_bus_error(&NoAcknowledge(NoAcknowledgeSource::Data)),
        PollFailure::Nack
    );
    assert_eq!(
        PollFailure::of_bus_error(&NoAcknowledge(NoAcknowledgeSource::Unknown)),
        PollFailure::Nack
    );
    // embassy-stm32 reports its timeout as Other.
    assert_eq!(PollFailure::of_bus_error(&Other), PollFailure::Timeout);
    assert_eq!(PollFailure::of_bus_error(&Bus), PollFailure::Bus);
    assert_eq!(PollFailure::of_bus_error(&ArbitrationLoss), PollFailure::Bus);
    assert_eq!(PollFailure::of_bus_error(&Overrun), PollFailure::Bus);
}

#[test]
fn decode_errors_are_classified_by_variant() {
    let cases = [
        (DecodeError::Length { expected: 7, actual: 4 }, PollFailure::BadLength),
        (
            DecodeError::MessageType {
                expected: 0x53,
                actual: 0x55,
            },
            PollFailure::BadType,
        ),
        (
            DecodeError::Checksum { expected: 1, actual: 2 },
            PollFailure::BadChecksum,
        ),
        (DecodeError::SpeedOutOfRange(0), PollFailure::BadRange),
    ];
    for (error, failure) in cases {
        assert_eq!(PollFailure::of_decode_error(error), failure);
        assert_eq!(
            PollFailure::of_poll_error::<ErrorKind>(&PollError::Decode(error)),
            failure
        );
        assert!(!failure.needs_recovery());
    }
    assert_eq!(
        PollFailure::of_poll_error(&PollError::Order(ErrorKind::Other)),
        PollFailure::Timeout
    );
    assert_eq!(
        PollFailure::of_poll_error(&PollError::Status(ErrorKind::Bus)),
        PollFailure::Bus
    );
    assert!(
        PollFailure::Timeout.needs_recovery() && PollFailure::Bus.needs_recovery() && PollFailure::Mux.needs_recovery()
    );
    assert!(!PollFailure::Nack.needs_recovery());
}

// ---------------------------------------------------------------------------------------------------------------
// ThrusterLink

#[test]
fn a_nack_takes_a_thruster_offline_at_once_and_retries_back_off_to_the_cap() {
    let mut link = ThrusterLink::new(&PollConfig::DEFAULT);
    assert_eq!(link.state(), LinkState::Unknown);
    assert!(link.due(at_ms(0)));
    assert_eq!(
        link.on_outcome(at_ms(0), Outcome::NoOrder(PollFailure::Nack)),
        Some(LinkChange::Offline(PollFailure::Nack))
    );
    assert_eq!(link.state(), LinkState::Offline);
    let mut retries = Vec::new();
    let mut now = 0;
    while retries.len() < 8 {
        now += 20;
        if link.due(at_ms(now)) {
            retries.push(now);
            assert_eq!(
                link.on_outcome(at_ms(now), Outcome::NoOrder(PollFailure::Nack)),
                None,
                "already offline"
            );
        }
    }
    assert_eq!(retries, [100, 300, 700, 1500, 3100, 5100, 7100, 9100]);
    let health = link.health();
    assert_eq!((health.polls, health.nack, health.consecutive_failures), (9, 9, 9));
    assert!(!health.online);

    // The first good retry brings it back; the back-off starts again from the minimum.
    now += 2000;
    assert!(link.due(at_ms(now)));
    assert_eq!(
        link.on_outcome(at_ms(now), Outcome::Answered(seabotix_status(Faults::NONE))),
        Some(LinkChange::Online)
    );
    assert!(link.health().online && link.health().consecutive_failures == 0);
    assert!(link.due(at_ms(now + 1)), "online thrusters are always due");
    assert_eq!(
        link.on_outcome(at_ms(now), Outcome::NoOrder(PollFailure::Nack)),
        Some(LinkChange::Offline(PollFailure::Nack))
    );
    assert_eq!(link.retry_at(), Some(at_ms(now + 100)));
}

#[test]
fn orders_not_delivered_take_a_thruster_offline_after_three_in_a_row() {
    for failure in [PollFailure::Timeout, PollFailure::Bus, PollFailure::Mux] {
        let mut link = ThrusterLink::new(&PollConfig::DEFAULT);
        let good = Outcome::Answered(seabotix_status(Faults::NONE));
        let lost = Outcome::NoOrder(failure);
        assert_eq!(link.on_outcome(at_ms(0), good), Some(LinkChange::Online));
        assert_eq!(link.on_outcome(at_ms(20), lost), None);
        assert_eq!(link.on_outcome(at_ms(40), lost), None);
        // A delivered order in between resets the run, even without a status.
        assert_eq!(
            link.on_outcome(at_ms(60), Outcome::NoStatus(PollFailure::BadChecksum)),
            None
        );
        assert_eq!(link.on_outcome(at_ms(80), lost), None);
        assert_eq!(link.on_outcome(at_ms(100), lost), None);
        assert!(link.health().online);
        assert_eq!(link.health().consecutive_failures, 2);
        assert_eq!(link.on_outcome(at_ms(120), lost), Some(LinkChange::Offline(failure)));
        assert_eq!(link.retry_at(), Some(at_ms(220)));
        assert_eq!(
            link.status(),
            Some(seabotix_status(Faults::NONE)),
            "the last valid status is kept"
        );
        let h = link.health();
        let counted = match failure {
            PollFailure::Timeout => h.timeout,
            _ => h.bus_error,
        };
        assert_eq!(
            (h.polls, h.delivered, h.good, counted, h.bad_checksum),
            (7, 2, 1, 5, 1),
            "{failure:?}"
        );
    }
}

#[test]
fn a_status_that_cannot_be_read_costs_the_telemetry_not_the_orders() {
    for failure in [
        PollFailure::BadLength,
        PollFailure::BadType,
        PollFailure::BadChecksum,
        PollFailure::Timeout,
        PollFailure::Bus,
        PollFailure::Nack,
    ] {
        let mut link = ThrusterLink::new(&PollConfig::DEFAULT);
        let good = seabotix_status(Faults::NONE);
        assert_eq!(
            link.on_outcome(at_ms(0), Outcome::Answered(good)),
            Some(LinkChange::Online)
        );
        // Many seconds of unreadable statuses: told once, after three in a row; the thruster stays online and due
        // every period.
        let mut changes = Vec::new();
        for k in 1..=400 {
            assert!(link.due(at_ms(20 * k)), "{failure:?} poll {k}");
            changes.extend(link.on_outcome(at_ms(20 * k), Outcome::NoStatus(failure)));
        }
        assert_eq!(changes, [LinkChange::StatusLost(failure)], "{failure:?}");
        let h = link.health();
        assert!(h.online && h.status_lost && h.consecutive_failures == 0, "{h:?}");
        assert_eq!((h.polls, h.delivered, h.good, h.status_failures), (401, 401, 1, 400));
        assert_eq!(link.status(), Some(good), "the last valid status is kept");
        assert_eq!(link.retry_at(), None);
        assert_eq!(
            link.on_outcome(at_ms(9000), Outcome::Answered(good)),
            Some(LinkChange::StatusBack)
        );
        assert!(!link.health().status_lost && link.health().status_failures == 0);
    }
}

#[test]
fn failures_before_the_first_answer_go_offline_from_unknown() {
    let mut link = ThrusterLink::new(&PollConfig::DEFAULT);
    assert_eq!(link.on_outcome(at_ms(0), Outcome::NoOrder(PollFailure::Timeout)), None);
    assert_eq!(link.state(), LinkState::Unknown);
    assert_eq!(link.on_outcome(at_ms(20), Outcome::NoOrder(PollFailure::Timeout)), None);
    assert_eq!(
        link.on_outcome(at_ms(40), Outcome::NoOrder(PollFailure::Timeout)),
        Some(LinkChange::Offline(PollFailure::Timeout))
    );
    link.on_recovery();
    assert_eq!(link.health().recoveries, 1);
    assert_eq!(link.report().status, None);
    // Orders delivered from the start but never a readable status: online, the telemetry lost.
    let mut link = ThrusterLink::new(&PollConfig::DEFAULT);
    assert_eq!(
        link.on_outcome(at_ms(0), Outcome::NoStatus(PollFailure::BadChecksum)),
        Some(LinkChange::Online)
    );
    assert_eq!(
        link.on_outcome(at_ms(20), Outcome::NoStatus(PollFailure::BadChecksum)),
        None
    );
    assert_eq!(
        link.on_outcome(at_ms(40), Outcome::NoStatus(PollFailure::BadChecksum)),
        Some(LinkChange::StatusLost(PollFailure::BadChecksum))
    );
    assert_eq!(link.report().status, None);
}

#[test]
fn a_link_can_take_a_poll_result_directly() {
    let mut link = ThrusterLink::new(&PollConfig::DEFAULT);
    let result: Result<Polled, PollError<ErrorKind>> = Err(PollError::Order(ErrorKind::Other));
    assert_eq!(link.on_result(at_ms(0), &result), None);
    assert_eq!((link.health().timeout, link.health().delivered), (1, 0));
    let result: Result<Polled, PollError<ErrorKind>> = Err(PollError::Status(ErrorKind::Other));
    assert_eq!(
        link.on_result(at_ms(20), &result),
        Some(LinkChange::Online),
        "the order was delivered"
    );
    assert_eq!((link.health().timeout, link.health().delivered), (2, 1));
    let polled = Polled {
        decoded: Decoded::clean(seabotix_status(Faults::NONE)),
        form: StatusForm::ImpliedType,
        link_failsafe: false,
        overcurrent: false,
    };
    assert_eq!(link.on_result::<ErrorKind>(at_ms(40), &Ok(polled)), None);
    assert_eq!((link.health().good, link.health().implied_form), (1, 1));
}

// ---------------------------------------------------------------------------------------------------------------
// Faults and texts

#[test]
fn fault_changes_and_their_texts() {
    let mut watch = FaultWatch::new();
    assert_eq!(watch.update(Faults::NONE), None);
    let change = watch.update(Faults::WATER).unwrap();
    assert_eq!((change.raised, change.cleared), (Faults::WATER, Faults::NONE));
    let texts = |family, change| -> Vec<(Severity, String)> {
        fault_texts(2, family, change)
            .map(|(severity, text)| (severity, text.as_str().to_owned()))
            .collect()
    };
    // Water only warns on a SeaBotix controller; it stops a Legacy one.
    assert_eq!(
        texts(Family::SeaBotix, change),
        [(Severity::Warning, "T3 fault: water detect".to_owned())]
    );
    assert_eq!(
        texts(Family::Legacy, change),
        [(Severity::Critical, "T3 fault: water detect".to_owned())]
    );
    assert_eq!(watch.update(Faults::WATER), None, "no change, no text");
    let change = watch.update(Faults::GROUND | Faults::OVERTEMP).unwrap();
    assert_eq!(
        texts(Family::SeaBotix, change),
        [
            (Severity::Notice, "T3 fault cleared: water detect".to_owned()),
            (Severity::Critical, "T3 fault: overtemp".to_owned()),
            (Severity::Critical, "T3 fault: ground fault".to_owned()),
        ]
    );
    let change = watch.update(Faults::NONE).unwrap();
    assert_eq!(
        texts(Family::SeaBotix, change),
        [(Severity::Notice, "T3 faults cleared".to_owned())]
    );
    for fault in [Faults::OVERTEMP, Faults::STALL, Faults::HALL, Faults::GROUND] {
        for family in Family::ALL {
            assert_eq!(fault_severity(family, fault), Severity::Critical);
        }
    }
}

#[test]
fn link_texts() {
    assert_eq!(
        link_text(2, LinkChange::Online, false),
        (Severity::Info, Text::try_from("T3 online").unwrap())
    );
    assert_eq!(
        link_text(2, LinkChange::Offline(PollFailure::Nack), false),
        (Severity::Warning, Text::try_from("T3 offline: no answer").unwrap())
    );
    assert_eq!(
        link_text(7, LinkChange::Offline(PollFailure::BadChecksum), false)
            .1
            .as_str(),
        "T8 offline: bad checksum"
    );
    assert_eq!(
        link_text(2, LinkChange::Offline(PollFailure::Nack), true),
        (
            Severity::Info,
            Text::try_from("T3 offline: restarting into its update").unwrap()
        )
    );
    // Only going offline is the restart's: coming back is told as ever.
    assert_eq!(link_text(2, LinkChange::Online, true).1.as_str(), "T3 online");
}

#[test]
fn mux_masks() {
    assert_eq!(mux_mask(&ThrusterSlot::direct(0, Family::SeaBotix)), Ok(None));
    assert_eq!(
        mux_mask(&ThrusterSlot::behind_mux(0, 3, Family::SeaBotix)),
        Ok(Some(0x08))
    );
    assert_eq!(
        mux_mask(&ThrusterSlot::behind_mux(1, 7, Family::Legacy)),
        Ok(Some(0x80))
    );
    assert_eq!(
        mux_mask(&ThrusterSlot::behind_mux(0, 8, Family::Legacy)),
        Err(()),
        "channels 0..=7"
    );
    assert_eq!(poll_bits(Family::SeaBotix), 121);
    assert_eq!(poll_bits(Family::Legacy), 94);
}

#[test]
fn thruster_tables_are_checked() {
    const LBV300: [ThrusterSlot; 6] = [
        ThrusterSlot::behind_mux(1, 0, Family::SeaBotix),
        ThrusterSlot::behind_mux(1, 1, Family::SeaBotix),
        ThrusterSlot::behind_mux(1, 2, Family::SeaBotix),
        ThrusterSlot::behind_mux(1, 3, Family::SeaBotix),
        ThrusterSlot::behind_mux(1, 4, Family::Legacy),
        ThrusterSlot::behind_mux(1, 4, Family::SeaBotix),
    ];
    const _: () = assert!(check_table(&LBV300).is_ok());
    let ok = [
        ThrusterSlot::direct(0, Family::SeaBotix),
        ThrusterSlot::direct(0, Family::Legacy),
        ThrusterSlot::direct(1, Family::SeaBotix),
        ThrusterSlot::behind_mux(2, 0, Family::SeaBotix),
        ThrusterSlot::behind_mux(2, 1, Family::SeaBotix),
        ThrusterSlot::behind_mux(2, 0, Family::Legacy),
    ];
    assert_eq!(check_table(&ok), Ok(()));
    assert_eq!(check_table(&[]), Ok(()));
    let direct_twins = [
        ThrusterSlot::direct(0, Family::SeaBotix),
        ThrusterSlot::direct(0, Family::Legacy),
        ThrusterSlot::direct(0, Family::SeaBotix),
    ];
    assert_eq!(check_table(&direct_twins), Err(TableError::SharedAddress(0, 2)));
    let channel_twins = [
        ThrusterSlot::behind_mux(0, 5, Family::Legacy),
        ThrusterSlot::behind_mux(0, 5, Family::Legacy),
    ];
    assert_eq!(check_table(&channel_twins), Err(TableError::SharedAddress(0, 1)));
    let direct_and_muxed = [
        ThrusterSlot::behind_mux(0, 5, Family::Legacy),
        ThrusterSlot::direct(1, Family::Legacy),
        ThrusterSlot::direct(0, Family::Legacy),
    ];
    assert_eq!(check_table(&direct_and_muxed), Err(TableError::SharedAddress(0, 2)));
    assert_eq!(
        check_table(&[ThrusterSlot::direct(3, Family::Legacy)]),
        Err(TableError::Bus(0))
    );
    assert_eq!(
        check_table(&[
            ThrusterSlot::direct(0, Family::Legacy),
            ThrusterSlot::behind_mux(0, 8, Family::SeaBotix)
        ]),
        Err(TableError::Channel(1))
    );
    assert_eq!(
        check_table(&[ThrusterSlot::direct(0, Family::Legacy); 9]),
        Err(TableError::TooMany)
    );

    // A table kept by value holds the slots in order, and still knows when it was given too many.
    let table = ThrusterTable::new(&ok);
    assert_eq!(table.as_slice(), ok);
    assert_eq!((table.count(), table.check()), (6, Ok(())));
    assert!(table.uses_bus(2) && !ThrusterTable::new(&[]).uses_bus(0));
    let too_many = ThrusterTable::new(&[ThrusterSlot::direct(0, Family::Legacy); 9]);
    assert_eq!(too_many.as_slice().len(), MAX_THRUSTERS);
    assert_eq!(too_many.check(), Err(TableError::TooMany));
    assert_eq!(
        ThrusterTable::new(&channel_twins).check(),
        Err(TableError::SharedAddress(0, 1))
    );
}

// ---------------------------------------------------------------------------------------------------------------
// The bus task on a simulated bus

/// A slave stuck mid-byte needs this many clocks to let SDA go.
const STUCK_CLOCKS: u32 = 5;

/// One simulated bus with scripted thrusters on it, the shared channels and the texts the console would have
/// received.
struct Bench {
    bus: Bus,
    thrusters: Vec<Rc<RefCell<SimThruster>>>,
    /// The bus's handle of each thruster, in `thrusters`' order.
    ids: Vec<DeviceId>,
    shared: Shared,
    texts: RefCell<Vec<(Severity, String)>>,
}

/// The bus task running: the executor and the clock.
struct Runner<'a> {
    bench: &'a Bench,
    executor: Executor<'a>,
    clock: Clock,
}

impl Runner<'_> {
    /// Let virtual time pass one bit time at a time, collecting the texts.
    fn elapse(&mut self, duration: Duration) {
        let end = Instant::now() + duration;
        while Instant::now() < end {
            self.executor.run_for(&self.clock, BIT, BIT);
            self.bench.collect();
        }
    }
}

impl Bench {
    /// Scripted thrusters of these families, each on its TCA9548A channel or wired directly (None); the mux is
    /// fitted when any thruster needs it. The bus keeps a log.
    fn new(thrusters: &[(Family, Option<u8>)]) -> Self {
        Self::with_mux(thrusters, thrusters.iter().any(|(_, channel)| channel.is_some()))
    }

    /// Like [`Bench::new`], the mux fitted or not.
    fn with_mux(thrusters: &[(Family, Option<u8>)], mux: bool) -> Self {
        let bus = Bus::new(Timing::new(
            BusConfig::THRUSTERS.frequency_hz,
            BusConfig::THRUSTERS.timeout,
        ));
        if mux {
            bus.fit_mux(MUX_ADDRESS);
        }
        bus.record(true);
        let (thrusters, ids) = thrusters
            .iter()
            .map(|(family, channel)| {
                let thruster = Rc::new(RefCell::new(SimThruster::new(*family)));
                let id = bus.attach(thruster.clone(), channel.map_or(Route::Direct, Route::Mux));
                (thruster, id)
            })
            .unzip();
        Self {
            bus,
            thrusters,
            ids,
            shared: Shared::new(),
            texts: RefCell::new(Vec::new()),
        }
    }

    /// `count` thrusters of `family` on mux channels 0, 1, ...
    fn muxed(count: u8, family: Family) -> (Self, Vec<ThrusterSlot>) {
        let thrusters: Vec<(Family, Option<u8>)> = (0..count).map(|ch| (family, Some(ch))).collect();
        let table = (0..count).map(|ch| ThrusterSlot::behind_mux(0, ch, family)).collect();
        (Self::new(&thrusters), table)
    }

    /// Run bus 0's task alongside `script` until the script ends; virtual time starts at 0.
    fn run<'a>(&'a self, table: &'a [ThrusterSlot], config: &'a PollConfig, script: impl FnOnce(&mut Runner<'a>)) {
        self.run_carrying(table, config, None, script);
    }

    /// As [`Bench::run`], the bus task carrying `transfers` too.
    fn run_carrying<'a>(
        &'a self,
        table: &'a [ThrusterSlot],
        config: &'a PollConfig,
        transfers: Option<&'a Transfers>,
        script: impl FnOnce(&mut Runner<'a>),
    ) {
        let clock = clock::take();
        let mut executor = Executor::new();
        let mut port = thruster_bus(&self.bus, &BusConfig::THRUSTERS);
        executor.spawn(async move {
            // As `Polling::run` does at the start: every thruster of the table is to be asked what it runs.
            if let Some(transfers) = transfers {
                transfers.with(|courier| courier.expect(table.len()));
                transfers.publish(&self.shared);
            }
            bus_task(
                &mut port,
                0,
                table,
                config,
                &self.shared,
                &Links::new(config),
                transfers,
            )
            .await;
        });
        script(&mut Runner {
            bench: self,
            executor,
            clock,
        });
    }

    fn thruster(&self, index: usize) -> RefMut<'_, SimThruster> {
        self.thrusters[index].borrow_mut()
    }

    /// The control bytes written to the TCA9548A, with when.
    fn mux_writes(&self) -> Vec<(Instant, u8)> {
        self.bus
            .take_log()
            .into_iter()
            .filter(|transfer| transfer.address == MUX_ADDRESS)
            .filter_map(|transfer| match transfer.data {
                Data::Write(bytes) => bytes.last().map(|mask| (transfer.at, *mask)),
                Data::Read(_) => None,
            })
            .collect()
    }

    fn collect(&self) {
        while let Ok(message) = self.shared.outbox.try_receive() {
            if let Outgoing::Text(severity, text) = message {
                self.texts.borrow_mut().push((severity, text.as_str().to_owned()));
            }
        }
    }

    fn take_texts(&self) -> Vec<(Severity, String)> {
        self.collect();
        self.texts.take()
    }

    fn health(&self, index: usize) -> LinkHealth {
        self.report(index).health
    }

    fn report(&self, index: usize) -> ThrusterReport {
        self.shared.thrusters[index].try_get().expect("a report was published")
    }

    fn orders(&self, index: usize) -> Vec<Instant> {
        self.thruster(index).orders.clone()
    }
}

/// How many of `times` fall in [from, to) milliseconds.
fn count(times: &[Instant], from_ms: u64, to_ms: u64) -> usize {
    times
        .iter()
        .filter(|t| (at_ms(from_ms)..at_ms(to_ms)).contains(t))
        .count()
}

/// Each second of `seconds`, every thruster but `except` got 50 +- 1 orders.
fn assert_50_hz(bench: &Bench, thrusters: usize, seconds: u64, except: Option<usize>) {
    for index in (0..thrusters).filter(|i| Some(*i) != except) {
        let orders = bench.orders(index);
        for second in 0..seconds {
            let n = count(&orders, second * 1000, (second + 1) * 1000);
            assert!(
                (49..=51).contains(&n),
                "T{} got {n} orders in second {second}",
                index + 1
            );
        }
    }
}

fn utilisation(bits: u64, elapsed: Duration) -> f64 {
    (bits * BIT.as_micros()) as f64 / elapsed.as_micros() as f64
}

#[test]
fn six_thrusters_at_50_hz_are_polled_in_table_order_50_times_a_second() {
    let (bench, table) = Bench::muxed(6, Family::SeaBotix);
    bench.run(&table, &PollConfig::DEFAULT, |sim| {
        // Up to the last instant before the 501st cycle.
        sim.elapse(Duration::from_secs(10) - BIT);
    });
    assert_50_hz(&bench, 6, 10, None);
    // Within each cycle: T1..T6 in table order, each after selecting its channel.
    let masks: Vec<u8> = bench.mux_writes().iter().map(|(_, mask)| *mask).collect();
    assert_eq!(masks.len(), 6 * 500);
    for (i, mask) in masks.iter().enumerate() {
        assert_eq!(*mask, 1 << (i % 6));
    }
    for index in 0..6 {
        let first = bench.thruster(index).orders[0];
        let expected = index as u64 * (poll_bits(Family::SeaBotix) as u64 + 20) + 20;
        assert_eq!(
            first.as_micros(),
            expected * 10,
            "T{} polled {}th in the cycle",
            index + 1,
            index + 1
        );
    }
    for index in 0..6 {
        let h = bench.health(index);
        assert!(h.online);
        assert_eq!((h.polls, h.good), (500, 500));
    }
    // Each cycle: 6 x (mux select 20 bits + order 47 + status 74) = 846 bits.
    assert_eq!(bench.bus.stats().bits, 500 * 846);
    let load = utilisation(bench.bus.stats().bits, Duration::from_secs(10));
    println!(
        "50 Hz, 6 SeaBotix thrusters behind a TCA9548A on one bus: {} polls per thruster in 10 s, \
         bus utilisation {:.1} % ({} bit times per cycle)",
        bench.thruster(0).orders.len(),
        load * 100.0,
        bench.bus.stats().bits / 500
    );
    assert!((0.40..0.45).contains(&load));
}

#[test]
fn back_to_back_polling_is_limited_only_by_the_bus() {
    let (bench, table) = Bench::muxed(6, Family::SeaBotix);
    let config = PollConfig {
        period: Duration::from_ticks(0),
        ..PollConfig::DEFAULT
    };
    let seconds = 10;
    bench.run(&table, &config, |sim| {
        sim.elapse(Duration::from_secs(seconds));
    });
    let rates: Vec<f64> = (0..6)
        .map(|i| bench.thruster(i).orders.len() as f64 / seconds as f64)
        .collect();
    let load = utilisation(bench.bus.stats().bits, Duration::from_secs(seconds));
    // One cycle: 6 x 141 bit times = 8.46 ms, so 118.2 polls a second per thruster.
    let cycle = 6 * (poll_bits(Family::SeaBotix) + transfer_bits(1));
    let expected = 1e6 / (cycle as f64 * 10.0);
    println!(
        "back to back, 6 SeaBotix thrusters behind a TCA9548A on one bus: {:.1} polls/s per thruster \
         (cycle {} bit times = {:.2} ms; without the mux selects it would be {} bit times = {:.1} Hz), \
         bus utilisation {:.1} %",
        rates[0],
        cycle,
        cycle as f64 / 100.0,
        6 * poll_bits(Family::SeaBotix),
        1e6 / (6.0 * poll_bits(Family::SeaBotix) as f64 * 10.0),
        load * 100.0
    );
    for rate in &rates {
        assert!((rate - expected).abs() <= 0.2, "{rate} polls/s, expected {expected:.1}");
        assert!((100.0..150.0).contains(rate));
    }
    assert!(load > 0.99, "back to back keeps the bus busy: {load}");
    assert!(bench.bus.take_log().iter().all(|t| t.ok));
}

#[test]
fn back_to_back_with_one_thruster_per_family_on_a_direct_bus() {
    let bench = Bench::new(&[(Family::SeaBotix, None), (Family::Legacy, None)]);
    let table = [
        ThrusterSlot::direct(0, Family::SeaBotix),
        ThrusterSlot::direct(0, Family::Legacy),
    ];
    let config = PollConfig {
        period: Duration::from_ticks(0),
        ..PollConfig::DEFAULT
    };
    bench.run(&table, &config, |sim| {
        sim.elapse(Duration::from_secs(1));
    });
    let cycle = poll_bits(Family::SeaBotix) + poll_bits(Family::Legacy);
    let expected = 100_000 / cycle as usize;
    println!(
        "back to back, one SeaBotix and one Legacy thruster wired directly: {} and {} polls/s ({} bit times a cycle)",
        bench.thruster(0).orders.len(),
        bench.thruster(1).orders.len(),
        cycle
    );
    for thruster in &bench.thrusters {
        assert!(thruster.borrow().orders.len().abs_diff(expected) <= 1);
    }
    assert!(bench.mux_writes().is_empty());
}

#[test]
fn a_missing_thruster_is_found_by_its_first_nack_and_retried_with_back_off_without_slowing_the_others() {
    let (bench, table) = Bench::muxed(6, Family::SeaBotix);
    bench.thruster(2).mode = Mode::Silent;
    bench.run(&table, &PollConfig::DEFAULT, |sim| {
        sim.elapse(Duration::from_secs(10));
        assert_50_hz(&bench, 6, 10, Some(2));
        let h = bench.health(2);
        assert!(!h.online);
        assert_eq!((h.good, h.nack), (0, h.polls));
        assert_eq!(h.recoveries, 0, "a NACK needs no recovery");
        let texts = bench.take_texts();
        let offline: Vec<_> = texts.iter().filter(|(_, t)| t.starts_with("T3")).collect();
        assert_eq!(offline, [&(Severity::Warning, "T3 offline: no answer".to_owned())]);
        assert_eq!(texts.iter().filter(|(_, t)| t.ends_with("online")).count(), 5);

        // It turns up: the next retry finds it.
        bench.thruster(2).mode = Mode::Good;
        sim.elapse(Duration::from_millis(2100));
        assert!(bench.health(2).online);
        assert_eq!(bench.take_texts(), [(Severity::Info, "T3 online".to_owned())]);
        sim.elapse(Duration::from_secs(1));
    });
    // Its attempts: the first cycle, then 100, 200, 400 ... ms apart, capped at 2 s.
    let attempts = bench.thruster(2).addressed.clone();
    let start = attempts[0];
    // Two thrusters, each with its mux select, and T3's own select, come before it in the cycle.
    assert_eq!(start.as_micros(), (2 * 141 + 20) * 10);
    let gaps: Vec<u64> = attempts.windows(2).map(|w| (w[1] - w[0]).as_millis()).take(8).collect();
    assert_eq!(gaps, [100, 200, 400, 800, 1600, 2000, 2000, 2000]);
    let orders = bench.orders(2);
    let n = count(&orders, 12_100, 13_100);
    assert!((49..=51).contains(&n), "back at 50 Hz: {n}");
    assert_50_hz(&bench, 6, 13, Some(2));
}

#[test]
fn an_out_of_range_field_is_counted_but_the_status_and_its_faults_are_kept() {
    for family in Family::ALL {
        let bench = Bench::new(&[(family, Some(0))]);
        bench.thruster(0).mode = Mode::BadRange;
        let table = [ThrusterSlot::behind_mux(0, 0, family)];
        bench.run(&table, &PollConfig::DEFAULT, |sim| {
            sim.elapse(Duration::from_millis(100));
            let h = bench.health(0);
            assert!(h.online, "{family:?}");
            assert_eq!((h.good, h.bad_range, h.consecutive_failures), (h.polls, h.polls, 0));
            assert_eq!(bench.take_texts(), [(Severity::Info, "T1 online".to_owned())]);
        });
    }
}

#[test]
fn each_failure_kind_is_counted_and_only_orders_that_fail_take_the_thruster_offline() {
    // (mode, whether its orders are delivered, the text after three polls)
    let cases = [
        (Mode::BadChecksum, true, "T1 status unreadable: bad checksum"),
        (Mode::BadType, true, "T1 status unreadable: bad message type"),
        (Mode::Stretch, false, "T1 offline: timeout"),
    ];
    for family in Family::ALL {
        for (mode, delivered, text) in cases {
            let other = match family {
                Family::SeaBotix => Family::Legacy,
                Family::Legacy => Family::SeaBotix,
            };
            let bench = Bench::new(&[(family, Some(0)), (other, Some(1))]);
            bench.thruster(0).mode = mode;
            let table = [
                ThrusterSlot::behind_mux(0, 0, family),
                ThrusterSlot::behind_mux(0, 1, other),
            ];
            bench.run(&table, &PollConfig::DEFAULT, |sim| {
                sim.elapse(Duration::from_millis(100));
                let h = bench.health(0);
                let counted = match mode {
                    Mode::BadChecksum => h.bad_checksum,
                    Mode::BadType => h.bad_type,
                    Mode::Stretch => h.timeout,
                    _ => unreachable!(),
                };
                assert_eq!(h.nack + h.bus_error + h.bad_length, 0);
                let recoveries = if mode == Mode::Stretch { 3 } else { 0 };
                assert_eq!(h.recoveries, recoveries);
                assert_eq!(bench.bus.stats().pin_stops, u64::from(recoveries));
                let texts = bench.take_texts();
                if delivered {
                    // Polled every 20 ms in the 100 ms: every order taken, the status never read.
                    assert!(h.online && h.status_lost && h.consecutive_failures == 0, "{h:?}");
                    assert_eq!((h.polls, h.delivered, counted, h.good), (5, 5, 5, 0), "{mode:?}");
                    assert_eq!(bench.orders(0).len(), 5, "{mode:?}");
                    assert_eq!(
                        texts,
                        [
                            (Severity::Info, "T1 online".to_owned()),
                            (Severity::Info, "T2 online".to_owned()),
                            (Severity::Warning, text.to_owned())
                        ],
                        "{family:?} {mode:?}"
                    );
                } else {
                    assert!(!h.online);
                    assert_eq!((h.polls, counted, h.consecutive_failures), (3, 3, 3), "{mode:?}");
                    assert_eq!(
                        texts,
                        [
                            (Severity::Info, "T2 online".to_owned()),
                            (Severity::Warning, text.to_owned())
                        ],
                        "{family:?} {mode:?}"
                    );
                }
                // The other one works on.
                let h = bench.health(1);
                assert!(h.online && h.good == h.polls && h.polls >= 3);
            });
        }
    }
}

#[test]
fn a_missing_mux_counts_as_a_bus_error_of_the_thrusters_behind_it() {
    let bench = Bench::with_mux(&[(Family::Legacy, Some(0)), (Family::Legacy, Some(1))], false);
    let table = [
        ThrusterSlot::behind_mux(0, 0, Family::Legacy),
        ThrusterSlot::behind_mux(0, 1, Family::Legacy),
    ];
    bench.run(&table, &PollConfig::DEFAULT, |sim| {
        sim.elapse(Duration::from_millis(100));
    });
    for index in 0..2 {
        let h = bench.health(index);
        assert_eq!((h.polls, h.bus_error, h.recoveries, h.nack), (3, 3, 3, 0));
    }
    assert_eq!(
        bench.take_texts(),
        [
            (Severity::Warning, "T1 offline: mux error".to_owned()),
            (Severity::Warning, "T2 offline: mux error".to_owned()),
        ]
    );
    assert!(bench.thrusters.iter().all(|t| t.borrow().addressed.is_empty()));
}

#[test]
fn a_stuck_sda_is_recovered_and_polling_resumes() {
    let bench = Bench::new(&[(Family::SeaBotix, None), (Family::Legacy, None)]);
    let table = [
        ThrusterSlot::direct(0, Family::SeaBotix),
        ThrusterSlot::direct(0, Family::Legacy),
    ];
    bench.run(&table, &PollConfig::DEFAULT, |sim| {
        sim.elapse(Duration::from_millis(105));
        bench.bus.hold_sda(STUCK_CLOCKS);
        sim.elapse(Duration::from_millis(895));
        // T1's poll in the 120 ms cycle met the stuck bus; one recovery freed it; T2 went on in the same cycle.
        assert_eq!(bench.bus.stats().pin_stops, 1);
        assert!(!bench.bus.sda_held());
        let h = bench.health(0);
        assert_eq!((h.bus_error, h.recoveries, h.polls, h.good), (1, 1, 50, 49));
        assert!(h.online, "one failure is not enough to go offline");
        let h = bench.health(1);
        assert_eq!((h.bus_error, h.recoveries, h.good), (0, 0, 50));
        assert_eq!(
            count(&bench.orders(1), 120, 121),
            1,
            "T2 polled in the cycle of the recovery"
        );
        assert_eq!(count(&bench.orders(0), 120, 140), 0);
        assert_eq!(count(&bench.orders(0), 140, 141), 1, "T1 polled again the next cycle");
        let texts = bench.take_texts();
        assert!(texts.iter().all(|(_, t)| !t.contains("offline")), "{texts:?}");
    });
}

#[test]
fn a_bus_stuck_through_recoveries_takes_everyone_offline_until_it_frees() {
    let bench = Bench::new(&[(Family::SeaBotix, None), (Family::Legacy, None)]);
    let table = [
        ThrusterSlot::direct(0, Family::SeaBotix),
        ThrusterSlot::direct(0, Family::Legacy),
    ];
    bench.run(&table, &PollConfig::DEFAULT, |sim| {
        sim.elapse(Duration::from_millis(10));
        // A slave that needs more clocks than a recovery gives.
        bench.bus.hold_sda(u32::MAX);
        sim.elapse(Duration::from_millis(100));
        let texts = bench.take_texts();
        assert_eq!(
            texts,
            [
                (Severity::Info, "T1 online".to_owned()),
                (Severity::Info, "T2 online".to_owned()),
                (Severity::Warning, "T1 offline: bus error".to_owned()),
                (Severity::Warning, "T2 offline: bus error".to_owned()),
            ]
        );
        for index in 0..2 {
            let h = bench.health(index);
            assert_eq!((h.bus_error, h.recoveries), (3, 3));
        }
        // Freed (the next recovery works): both come back with their next retry.
        bench.bus.hold_sda(STUCK_CLOCKS);
        sim.elapse(Duration::from_millis(300));
        let texts = bench.take_texts();
        assert_eq!(
            texts,
            [
                (Severity::Info, "T2 online".to_owned()),
                (Severity::Info, "T1 online".to_owned()),
            ],
            "T1's retry met the stuck bus and recovered it; T2's then went through"
        );
        assert!(bench.health(0).online && bench.health(1).online);
        assert!(!bench.bus.sda_held());
    });
}

#[test]
fn the_mux_is_written_only_when_the_channel_changes() {
    let bench = Bench::new(&[
        (Family::SeaBotix, Some(0)),
        (Family::Legacy, Some(0)),
        (Family::SeaBotix, Some(1)),
    ]);
    let table = [
        ThrusterSlot::behind_mux(0, 0, Family::SeaBotix),
        ThrusterSlot::behind_mux(0, 0, Family::Legacy),
        ThrusterSlot::behind_mux(0, 1, Family::SeaBotix),
    ];
    bench.run(&table, &PollConfig::DEFAULT, |sim| {
        sim.elapse(Duration::from_millis(99));
        let masks: Vec<u8> = bench.mux_writes().iter().map(|(_, m)| *m).collect();
        assert_eq!(
            masks,
            [1, 2].repeat(5),
            "T1 and T2 share channel 0: one select for both"
        );
        for index in 0..3 {
            assert_eq!(bench.orders(index).len(), 5);
        }
        // After an error the selection is forgotten and written again, even for the same channel.
        bench.thruster(0).mode = Mode::BadChecksum;
        sim.elapse(Duration::from_millis(40));
        let masks: Vec<u8> = bench.mux_writes().iter().map(|(_, m)| *m).collect();
        assert_eq!(masks, [1, 1, 2].repeat(2));
        assert_eq!(bench.orders(1).len(), 7);
        assert_eq!(bench.orders(2).len(), 7);
    });
}

#[test]
fn thrusters_wired_directly_share_the_bus_with_the_mux_channels() {
    let bench = Bench::new(&[
        (Family::Legacy, None),
        (Family::SeaBotix, Some(4)),
        (Family::SeaBotix, Some(6)),
    ]);
    let table = [
        ThrusterSlot::direct(0, Family::Legacy),
        ThrusterSlot::behind_mux(0, 4, Family::SeaBotix),
        ThrusterSlot::behind_mux(0, 6, Family::SeaBotix),
    ];
    bench.run(&table, &PollConfig::DEFAULT, |sim| {
        sim.elapse(Duration::from_millis(99));
    });
    let masks: Vec<u8> = bench.mux_writes().iter().map(|(_, m)| *m).collect();
    // The one wired directly needs no selection.
    assert_eq!(masks, [0x10, 0x40].repeat(5));
    assert_eq!(bench.bus.stats().collisions, 0, "never two thrusters answering at once");
    for thruster in &bench.thrusters {
        let thruster = thruster.borrow();
        assert_eq!(thruster.orders.len(), 5);
        assert_eq!(
            thruster.addressed.len(),
            10,
            "each addressed only by its own order and status"
        );
    }
}

#[test]
fn legacy_and_seabotix_mixed_on_one_bus_follow_their_orders() {
    let bench = Bench::new(&[(Family::SeaBotix, None), (Family::Legacy, None)]);
    let table = [
        ThrusterSlot::direct(0, Family::SeaBotix),
        ThrusterSlot::direct(0, Family::Legacy),
    ];
    bench.run(&table, &PollConfig::DEFAULT, |sim| {
        sim.elapse(Duration::from_millis(50));
        // Until the vehicle publishes orders, every thruster is sent STOP.
        assert!(bench.thrusters.iter().all(|t| {
            let t = t.borrow();
            t.link.order() == Order::STOP && t.link.orders() == 3
        }));
        let mut orders = [Order::STOP; MAX_THRUSTERS];
        orders[0] = Order::new(speed(20));
        orders[1] = Order::new(speed(-30));
        bench.shared.orders.sender().send(orders);
        sim.elapse(Duration::from_millis(950) - BIT);
        assert_eq!(bench.thruster(0).link.order(), orders[0]);
        assert_eq!(bench.thruster(1).link.order(), orders[1]);
        assert_eq!(bench.bus.stats().bits, 50 * (121 + 94));
    });
    match bench.report(0).status {
        Some(Status::SeaBotix(status)) => assert_eq!(status.speed.step(), 20),
        other => panic!("{other:?}"),
    }
    match bench.report(1).status {
        Some(Status::Legacy(status)) => assert_eq!(status.max_power, tmc_proto::MaxPower::Power(speed(-30))),
        other => panic!("{other:?}"),
    }
    assert_50_hz(&bench, 2, 1, None);
    assert_eq!(bench.health(1).good, 50);
}

#[test]
fn a_legacy_thruster_whose_orders_stopped_for_over_a_second_is_told_stopped_when_it_answers_again() {
    let bench = Bench::new(&[(Family::SeaBotix, Some(0)), (Family::Legacy, Some(1))]);
    let table = [
        ThrusterSlot::behind_mux(0, 0, Family::SeaBotix),
        ThrusterSlot::behind_mux(0, 1, Family::Legacy),
    ];
    bench.run(&table, &PollConfig::DEFAULT, |sim| {
        sim.elapse(MS * 100);
        bench.take_texts();
        // Both unpowered 0.5 s: less than the thrusters' failsafe, nothing said of it.
        for id in &bench.ids {
            bench.bus.set_powered(*id, false);
        }
        sim.elapse(MS * 500);
        for id in &bench.ids {
            bench.bus.set_powered(*id, true);
        }
        sim.elapse(MS * 3000);
        let stopped = |texts: &[(Severity, String)]| texts.iter().filter(|(_, t)| t.contains("stopped")).count();
        assert_eq!(stopped(&bench.take_texts()), 0);
        // 1.5 s: the Legacy thruster, whose status has no bit for it, is told stopped by the master once it
        // answers again; the SeaBotix one's status would say it (the simulated thruster has no failsafe).
        for id in &bench.ids {
            bench.bus.set_powered(*id, false);
        }
        sim.elapse(MS * 1500);
        for id in &bench.ids {
            bench.bus.set_powered(*id, true);
        }
        sim.elapse(MS * 3000);
        let texts = bench.take_texts();
        assert!(
            texts.contains(&(Severity::Warning, "T2 stopped: 1 s without a valid order".to_owned())),
            "{texts:?}"
        );
        assert!(!texts.iter().any(|(_, t)| t.starts_with("T1 stopped")), "{texts:?}");
        assert_eq!((bench.health(0).link_failsafes, bench.health(1).link_failsafes), (0, 1));
    });
}

#[test]
fn a_thruster_stopped_by_its_link_failsafe_is_told_once_per_stop() {
    let bench = Bench::new(&[(Family::SeaBotix, Some(0)), (Family::Legacy, Some(1))]);
    let table = [
        ThrusterSlot::behind_mux(0, 0, Family::SeaBotix),
        ThrusterSlot::behind_mux(0, 1, Family::Legacy),
    ];
    bench.run(&table, &PollConfig::DEFAULT, |sim| {
        sim.elapse(MS * 10);
        bench.take_texts();
        // Its status says the failsafe stopped it (SeaBotix FAULT bit 5) for several polls: one text, one count.
        bench.thruster(0).link_failsafe = true;
        sim.elapse(MS * 100);
        assert_eq!(
            bench.take_texts(),
            [(Severity::Warning, "T1 stopped: 1 s without a valid order".to_owned())]
        );
        assert_eq!(bench.health(0).link_failsafes, 1);
        assert_eq!(
            bench.report(0).status.map(|s| s.faults()),
            Some(Faults::NONE),
            "not a fault"
        );
        // An order restarts it; a second stop is a second text.
        bench.thruster(0).link_failsafe = false;
        sim.elapse(MS * 40);
        bench.thruster(0).link_failsafe = true;
        sim.elapse(MS * 40);
        assert_eq!(bench.take_texts().len(), 1);
        assert_eq!(bench.health(0).link_failsafes, 2);
        assert_eq!(bench.health(1).link_failsafes, 0);
    });
}

#[test]
fn a_thruster_stopped_by_a_sustained_overcurrent_is_told_once_per_stop_and_counted() {
    let bench = Bench::new(&[(Family::SeaBotix, Some(0)), (Family::Legacy, Some(1))]);
    let table = [
        ThrusterSlot::behind_mux(0, 0, Family::SeaBotix),
        ThrusterSlot::behind_mux(0, 1, Family::Legacy),
    ];
    bench.run(&table, &PollConfig::DEFAULT, |sim| {
        sim.elapse(MS * 10);
        bench.take_texts();
        // Its status says so (SeaBotix FAULT bit 6) for as long as it is held off: one text, one count.
        bench.thruster(0).overcurrent = true;
        sim.elapse(MS * 100);
        assert_eq!(
            bench.take_texts(),
            [(
                Severity::Critical,
                "T1 stopped: overcurrent, off until a zero order".to_owned()
            )]
        );
        assert_eq!(bench.health(0).overcurrents, 1);
        assert_eq!(bench.health(0).link_failsafes, 0, "bit 6 is not bit 5");
        assert_eq!(
            bench.report(0).status.map(|s| s.faults()),
            Some(Faults::NONE),
            "none of the IDS's faults"
        );
        // A zero order clears it; a second short is a second text. With the link failsafe at the same time, both.
        bench.thruster(0).overcurrent = false;
        sim.elapse(MS * 40);
        bench.thruster(0).overcurrent = true;
        bench.thruster(0).link_failsafe = true;
        sim.elapse(MS * 40);
        let texts = bench.take_texts();
        assert_eq!(texts.len(), 2, "{texts:?}");
        assert_eq!(bench.health(0).overcurrents, 2);
        assert_eq!(bench.health(0).link_failsafes, 1);
        assert_eq!(bench.health(1).overcurrents, 0);
    });
}

#[test]
fn a_legacy_status_carries_no_overcurrent_bit() {
    // The Legacy STATUS byte's bits 5-7 are the revision: a Legacy thruster whose status had bit 6 set reads as
    // revision bits, never as an overcurrent.
    let bench = Bench::new(&[(Family::Legacy, Some(0))]);
    let table = [ThrusterSlot::behind_mux(0, 0, Family::Legacy)];
    bench.run(&table, &PollConfig::DEFAULT, |sim| {
        bench.thruster(0).overcurrent = true;
        sim.elapse(MS * 100);
        assert_eq!(bench.health(0).overcurrents, 0);
        assert!(bench.take_texts().iter().all(|(_, text)| !text.contains("overcurrent")));
    });
}

#[test]
fn texts_on_link_and_fault_changes_and_the_others_keep_working() {
    let bench = Bench::new(&[
        (Family::SeaBotix, Some(0)),
        (Family::Legacy, Some(1)),
        (Family::SeaBotix, Some(2)),
    ]);
    let table = [
        ThrusterSlot::behind_mux(0, 0, Family::SeaBotix),
        ThrusterSlot::behind_mux(0, 1, Family::Legacy),
        ThrusterSlot::behind_mux(0, 2, Family::SeaBotix),
    ];
    bench.run(&table, &PollConfig::DEFAULT, |sim| {
        sim.elapse(MS * 10);
        assert_eq!(
            bench.take_texts(),
            [
                (Severity::Info, "T1 online".to_owned()),
                (Severity::Info, "T2 online".to_owned()),
                (Severity::Info, "T3 online".to_owned()),
            ]
        );
        bench.thruster(0).faults = Faults::WATER;
        bench.thruster(1).faults = Faults::WATER;
        sim.elapse(MS * 20);
        assert_eq!(
            bench.take_texts(),
            [
                (Severity::Warning, "T1 fault: water detect".to_owned()),
                (Severity::Critical, "T2 fault: water detect".to_owned()),
            ]
        );
        bench.thruster(0).faults = Faults::WATER | Faults::GROUND;
        sim.elapse(MS * 100);
        assert_eq!(
            bench.take_texts(),
            [(Severity::Critical, "T1 fault: ground fault".to_owned())],
            "one text per change, not per poll"
        );
        bench.thruster(0).faults = Faults::NONE;
        bench.thruster(2).mode = Mode::Silent;
        sim.elapse(MS * 20);
        assert_eq!(
            bench.take_texts(),
            [
                (Severity::Notice, "T1 faults cleared".to_owned()),
                (Severity::Warning, "T3 offline: no answer".to_owned()),
            ]
        );
        let status = bench.report(0).status.expect("a status");
        assert_eq!(status.faults(), Faults::NONE);
        assert_eq!(bench.report(1).status.expect("a status").faults(), Faults::WATER);
        // The last valid status of the missing one is kept.
        assert!(bench.report(2).status.is_some());
    });
    assert_eq!(bench.health(0).polls, 8);
    assert_eq!(bench.health(1).polls, 8);
}

#[test]
fn each_bus_task_polls_only_its_own_bus() {
    let table = [
        ThrusterSlot::direct(0, Family::SeaBotix),
        ThrusterSlot::direct(1, Family::SeaBotix),
        ThrusterSlot::direct(0, Family::Legacy),
        ThrusterSlot::behind_mux(1, 3, Family::Legacy),
    ];
    let bus0 = Bench::new(&[(Family::SeaBotix, None), (Family::Legacy, None)]);
    let bus1 = Bench::new(&[(Family::SeaBotix, None), (Family::Legacy, Some(3))]);
    let shared = Shared::new();
    let mut orders = [Order::STOP; MAX_THRUSTERS];
    for (i, order) in orders.iter_mut().enumerate().take(4) {
        *order = Order::new(speed(10 * (i as i8 + 1)));
    }
    shared.orders.sender().send(orders);
    let config = PollConfig::DEFAULT;
    let clock = clock::take();
    let mut executor = Executor::new();
    for (index, bench) in [&bus0, &bus1].into_iter().enumerate() {
        let mut port = thruster_bus(&bench.bus, &BusConfig::THRUSTERS);
        let (table, config, shared) = (&table, &config, &shared);
        executor.spawn(async move {
            bus_task(&mut port, index as u8, table, config, shared, &Links::new(config), None).await;
        });
    }
    executor.run_for(&clock, Duration::from_secs(1), BIT);
    assert_eq!(bus0.thruster(0).link.order(), orders[0]);
    assert_eq!(bus0.thruster(1).link.order(), orders[2]);
    assert_eq!(bus1.thruster(0).link.order(), orders[1]);
    assert_eq!(bus1.thruster(1).link.order(), orders[3]);
    for thruster in bus0.thrusters.iter().chain(bus1.thrusters.iter()) {
        assert!(thruster.borrow().orders.len().abs_diff(50) <= 1);
    }
    for index in 0..4 {
        let h = shared.thrusters[index].try_get().unwrap().health;
        assert!(h.online && h.polls == h.good);
    }
    assert!(shared.thrusters[4].try_get().is_none());
}

#[test]
fn every_thruster_is_asked_what_it_runs_once_it_answers_and_again_when_it_answers_again_holding_arming_until_then() {
    use crate::shared::UpdateHold;
    // T2 is missing at first. The scripted thrusters speak only the IDS: their answer to `Version` is their status
    // frame, which says they take no update (and hold none).
    let (bench, table) = Bench::muxed(3, Family::SeaBotix);
    bench.thruster(1).mode = Mode::Silent;
    let transfers = Transfers::new();
    bench.run_carrying(&table, &PollConfig::DEFAULT, Some(&transfers), |sim| {
        // Before the first poll has an answer: every thruster of the bus may have come up on trial.
        sim.executor.run_for(&sim.clock, BIT, BIT);
        assert_eq!(bench.shared.holds.get(), Some(UpdateHold::Unasked(0)));
        // One cycle: the missing one is not waited for, the others have said.
        sim.elapse(Duration::from_millis(40));
        assert_eq!(bench.shared.holds.get(), None);
        // It turns up: held until it has said what it runs, which the next exchange asks.
        bench.thruster(1).mode = Mode::Good;
        let mut held = Vec::new();
        for _ in 0..2500 {
            sim.elapse(MS);
            held.push(bench.shared.holds.get());
            if held.len() > 1 && held.last() == Some(&None) && held.contains(&Some(UpdateHold::Unasked(1))) {
                break;
            }
        }
        let asked_for = held
            .iter()
            .filter(|hold| **hold == Some(UpdateHold::Unasked(1)))
            .count();
        assert!((1..=21).contains(&asked_for), "held {asked_for} ms, {held:?}");
        assert_eq!(held.last(), Some(&None));
        // Reset (gone and back): asked again.
        bench.thruster(2).mode = Mode::Silent;
        sim.elapse(Duration::from_millis(40));
        bench.thruster(2).mode = Mode::Good;
        let mut seen = Vec::new();
        for _ in 0..3000 {
            sim.elapse(MS);
            seen.push(bench.shared.holds.get());
        }
        assert!(seen.contains(&Some(UpdateHold::Unasked(2))), "asked again");
        assert_eq!(seen.last(), Some(&None));
    });
}
