//! One motor-less thruster controller on the emulated chip: the thruster core as the STM32 binding runs it,
//! `thruster_fw::run` in thread mode and `thruster_fw::run_commutation` on the interrupt executor, on ports that
//! lead to the core's motor model (`thruster_fw::motorless`) and to the scripted operator.
//!
//! Its power can be cut: the I2C line stops answering, the bridge coasts, both futures are dropped, and 30 ms
//! later the controller starts again with fresh RAM (a new `Shared`, a new latch store), as after a power cycle;
//! the motor model, which is the physical rotor, carries on.

use core::future::Future;
use core::sync::atomic::{AtomicBool, AtomicU32, AtomicUsize, Ordering};

use embassy_executor::{SendSpawner, Spawner};
use embassy_futures::select::{Either, select};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_sync::watch::Watch;
use embassy_time::{Duration, Instant, Timer};
use static_cell::StaticCell;
use thruster_fw::commutation::{BridgeDrive, COAST};
use thruster_fw::faults::VolatileLatch;
use thruster_fw::hall::HallState;
use thruster_fw::motorless::{ModelBridge, ModelHalls, ModelSensors, MotorModel, Motorless};
use thruster_fw::ports::{self, Board, Bridge as _, HallSensors, HoldInput, Ports, RawSample, Sensors, WaterInput};
use thruster_fw::shared::Shared;
use thruster_fw::trial::Confirmed;
use thruster_fw::update::NoUpdate;
use thruster_fw::{Config, Duty};
use tmc_proto::{Family, MotorKind};

use crate::executors::BENCH_METER;
use crate::halls::EdgeHalls;
use crate::i2c::{Bus, MAX_THRUSTERS, TargetPort};
use crate::meter::{self, Joined, Meter, Progress, THRUSTER_THREAD_BUSY, metered, metered_joined};
use crate::report;
use crate::stacks::Stack;

/// The thread-mode tasks (`thruster_fw::run`: I2C, faults, control, health joined), every poll and by which of
/// them made progress.
pub static THREAD_METER: Joined = Joined::new(
    "thruster thread tasks (run)",
    Progress::THRUSTER,
    Some(&THRUSTER_THREAD_BUSY),
);
/// Commutation (`thruster_fw::run_commutation`), on the interrupt executor: one poll per commutation event.
pub static COMMUTATION_METER: Meter = Meter::nested("thruster commutation (run_commutation)");
/// The motor model behind the ports: firmware in the motor-less image, but pin and ADC reads in the image with a
/// motor, so the tasks' figures leave it out.
pub static MOTOR_MODEL_METER: Meter = Meter::nested("motor model (ports)");

/// How long a power cut holds the controller down.
const POWER_CUT: Duration = Duration::from_millis(30);
/// The operator's water-sensor test resistor: 470 kohm from the sensor pin to 3V3 (the acceptance prompt).
const WATER_TEST_OHMS: u32 = 470_000;
/// Power-ups one controller can have in a run: the first and two cuts (each gets fresh RAM).
const POWER_UPS: usize = 3;
/// Tasks per controller that follow its power: thread mode and commutation.
const POWERED_TASKS: usize = 2;

/// How the controller's halls reach the commutation task.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HallInput {
    /// A hardware interrupt per edge (APB timer 1), with the latency measured: one thruster per chip.
    Interrupt,
    /// The core's model halls, which wait on embassy-time timers.
    Model,
}

/// What the watchdog saw.
struct WatchdogLog {
    feeds: AtomicU32,
    last_feed_us: AtomicU32,
    longest_gap_us: AtomicU32,
}

/// One controller and what surrounds it.
pub struct Thruster {
    /// The controller's configuration: the image's for its family (`thruster_fw::CONFIG` is
    /// `Config::reference(FAMILY, MOTOR)`; one emulated image serves both families).
    pub config: Config,
    /// Its TCA9548A channel, None when wired to the bus directly.
    pub mux_channel: Option<u8>,
    motorless: Motorless,
    water_resistor: AtomicBool,
    rotor_held: AtomicBool,
    /// The RAM of the running power-up, and its number; None while the power is cut.
    power: Watch<CriticalSectionRawMutex, Option<(usize, &'static Shared)>, POWERED_TASKS>,
    rams: [StaticCell<Shared>; POWER_UPS],
    power_ups: AtomicUsize,
    power_cut: Signal<CriticalSectionRawMutex, ()>,
    watchdog: WatchdogLog,
}

static THRUSTERS: [StaticCell<Thruster>; MAX_THRUSTERS] = [const { StaticCell::new() }; MAX_THRUSTERS];
static CREATED: AtomicUsize = AtomicUsize::new(0);

impl Thruster {
    /// A brushless motor-less controller of `family`, at rest, not yet powered.
    pub fn create(family: Family, mux_channel: Option<u8>) -> &'static Thruster {
        let config = Config::reference(family, MotorKind::Brushless);
        let index = CREATED.fetch_add(1, Ordering::Relaxed);
        let thruster = THRUSTERS.get(index).and_then(|cell| {
            cell.try_init(Thruster {
                motorless: Motorless::new(MotorModel::new(&config)),
                config,
                mux_channel,
                water_resistor: AtomicBool::new(false),
                rotor_held: AtomicBool::new(false),
                power: Watch::new(),
                rams: [const { StaticCell::new() }; POWER_UPS],
                power_ups: AtomicUsize::new(0),
                power_cut: Signal::new(),
                watchdog: WatchdogLog {
                    feeds: AtomicU32::new(0),
                    last_feed_us: AtomicU32::new(0),
                    longest_gap_us: AtomicU32::new(0),
                },
            })
        });
        match thruster {
            Some(thruster) => thruster,
            None => report::fail("more thrusters than the chip has room for"),
        }
    }

    /// Spawn the controller's two tasks and its power supply, and power it up; its I2C port is on `bus`.
    pub fn start(&'static self, thread: Spawner, high: SendSpawner, halls: HallInput, bus: &'static Bus) {
        report::spawn(thread, controller(self, bus));
        report::spawn(thread, power_supply(self));
        report::spawn_send(high, commutation(self, halls));
        self.power_on();
    }

    /// The operator fits (or removes) the water-sensor test resistor.
    pub fn fit_water_resistor(&self, fitted: bool) {
        self.water_resistor.store(fitted, Ordering::Relaxed);
    }

    /// The operator holds (or lets go of) the rotor.
    pub fn hold_rotor(&self, held: bool) {
        self.rotor_held.store(held, Ordering::Relaxed);
    }

    /// Cut the power now (its bus port, which cuts it, stops answering); it comes back after [`POWER_CUT`].
    pub fn cut_power(&self) {
        self.power.sender().send(None);
        // The gate drivers let go: whatever was driven, the motor coasts.
        ModelBridge(&self.motorless).apply(COAST, Duty::ZERO);
        self.power_cut.signal(());
    }

    /// Power-ups so far (1 + power cuts).
    pub fn power_ups(&self) -> usize {
        self.power_ups.load(Ordering::Relaxed)
    }

    /// Feeds of the watchdog, and the longest time between two (or since power-up), us.
    pub fn watchdog(&self) -> (u32, u32) {
        (
            self.watchdog.feeds.load(Ordering::Relaxed),
            self.watchdog.longest_gap_us.load(Ordering::Relaxed),
        )
    }

    /// Whether the watchdog would ever have bitten.
    pub fn watchdog_bit(&self) -> bool {
        u64::from(self.watchdog().1) > self.config.watchdog.timeout.as_micros()
    }

    /// Start with fresh RAM.
    fn power_on(&'static self) {
        let power_up = self.power_ups.fetch_add(1, Ordering::Relaxed);
        let Some(shared) = self.rams.get(power_up).and_then(|ram| ram.try_init(Shared::new())) else {
            report::fail("a thruster lost its power more often than the test provides RAM for");
        };
        self.watchdog.last_feed_us.store(now_us(), Ordering::Relaxed);
        self.power.sender().send(Some((power_up, &*shared)));
    }

    /// Run `body` with the RAM of each power-up, until that power-up ends.
    async fn powered_run<F: Future>(&'static self, body: impl Fn(&'static Shared) -> F) -> ! {
        let Some(mut power) = self.power.receiver() else {
            report::fail("a thruster has more powered tasks than its power watch has receivers");
        };
        let mut now = power.changed_and(Option::is_some).await;
        loop {
            let Some((power_up, shared)) = now else {
                now = power.changed_and(Option::is_some).await;
                continue;
            };
            // Whatever comes next ends this power-up: a power cut, or (if this task was slow to see the cut) the
            // next power-up already, which it then runs.
            let ended = power.changed_and(move |next| next.is_none_or(|(next, _)| next != power_up));
            now = match select(body(shared), ended).await {
                Either::First(_) => None,
                Either::Second(next) => next,
            };
        }
    }
}

/// What the thruster's outputs show of its control task: it publishes a duty every tick.
struct ControlOutput {
    seen: Option<(usize, u64)>,
}

impl ControlOutput {
    /// [`Progress::THRUSTER_CONTROL`] when the running power-up's duty was published since the last look.
    fn progress(&mut self, thruster: &Thruster) -> u8 {
        let now = thruster
            .power
            .try_get()
            .flatten()
            .map(|(power_up, shared)| (power_up, shared.duty.get_msg_id()));
        if now.is_some() && now != core::mem::replace(&mut self.seen, now) {
            Progress::THRUSTER_CONTROL
        } else {
            0
        }
    }
}

fn now_us() -> u32 {
    u32::try_from(Instant::now().as_micros()).unwrap_or(u32::MAX)
}

/// The water-sensor pin: the test resistor, or nothing (the pull-down reads 0).
struct WaterPin(&'static Thruster);

impl WaterInput for WaterPin {
    async fn water(&mut self) -> u16 {
        if self.0.water_resistor.load(Ordering::Relaxed) {
            self.0.config.water.raw_at(WATER_TEST_OHMS)
        } else {
            0
        }
    }
}

/// The user button that holds the model's rotor.
struct HoldButton(&'static Thruster);

impl HoldInput for HoldButton {
    fn held(&mut self) -> bool {
        self.0.rotor_held.load(Ordering::Relaxed)
    }
}

/// The fault task's inputs: the core's model sensors, counted as model work. A sample is the fault task's
/// progress.
struct Inputs(ModelSensors<'static, WaterPin, HoldButton>);

impl Sensors for Inputs {
    async fn sample(&mut self) -> RawSample {
        meter::progressed(Progress::THRUSTER_FAULTS);
        metered(&MOTOR_MODEL_METER, None, self.0.sample()).await
    }
}

/// The halls, either kind, their model arithmetic counted as model work.
enum Halls {
    Interrupt(EdgeHalls),
    Model(ModelHalls<'static>),
}

impl HallSensors for Halls {
    async fn wait_for_edge(&mut self) {
        match self {
            Halls::Interrupt(halls) => halls.wait_for_edge().await,
            Halls::Model(halls) => metered(&MOTOR_MODEL_METER, None, halls.wait_for_edge()).await,
        }
    }

    fn read(&mut self) -> HallState {
        match self {
            Halls::Interrupt(halls) => halls.read(),
            Halls::Model(halls) => meter::measure(&MOTOR_MODEL_METER, || halls.read()),
        }
    }
}

/// The bridge: what would be driven goes to the model.
struct Bridge(&'static Motorless);

impl ports::Bridge for Bridge {
    fn apply(&mut self, drive: BridgeDrive, duty: Duty) {
        meter::measure(&MOTOR_MODEL_METER, || ModelBridge(self.0).apply(drive, duty));
    }

    fn hold_off(&mut self, off: bool) {
        ModelBridge(self.0).hold_off(off);
    }
}

/// The watchdog: counts feeds and the longest gap. A feed is the health task's progress.
struct Watchdog(&'static Thruster);

impl ports::Watchdog for Watchdog {
    fn feed(&mut self) {
        meter::progressed(Progress::THRUSTER_HEALTH);
        let log = &self.0.watchdog;
        let now = now_us();
        let gap = now.wrapping_sub(log.last_feed_us.swap(now, Ordering::Relaxed));
        log.longest_gap_us.fetch_max(gap, Ordering::Relaxed);
        log.feeds.fetch_add(1, Ordering::Relaxed);
    }
}

/// The emulated controller's ports: the bus's target port, the model's sensors, no bootloader and no DFU partition.
struct Emulated;

impl Board for Emulated {
    type I2c = TargetPort;
    type Sensors = Inputs;
    type Watchdog = Watchdog;
    type Latch = VolatileLatch;
    type Boot = Confirmed;
    type Dfu = NoUpdate;
    type Updater = NoUpdate;
}

// The controller as the STM32 binding runs it (`thruster-fw/src/stm32.rs`): `run` in thread mode, polled on the
// thruster's own stack, `run_commutation` on the interrupt executor; each power-up with fresh RAM.

#[embassy_executor::task(pool_size = MAX_THRUSTERS)]
async fn controller(t: &'static Thruster, bus: &'static Bus) -> ! {
    let body = t.powered_run(|shared| {
        // Each power-up boots with a fresh peripheral; from then on the thruster answers on the bus.
        let Some(i2c) = bus.target(t) else {
            report::fail("a thruster is not on the bus it was started on");
        };
        let ports = Ports::<Emulated> {
            i2c,
            sensors: Inputs(ModelSensors::new(&t.motorless, &t.config, WaterPin(t), HoldButton(t))),
            watchdog: Watchdog(t),
            // A power cut clears the latches, as the operator's power cycle does (a backup register would keep
            // them over any other reset).
            latch: VolatileLatch::default(),
            // Started as the probe starts it, with no bootloader: nothing on trial, and no DFU partition to update.
            boot: Confirmed,
            dfu: NoUpdate,
            updater: NoUpdate,
        };
        thruster_fw::run(ports, &t.config, shared)
    });
    let mut control = ControlOutput { seen: None };
    metered_joined(&THREAD_METER, Stack::Thruster, || control.progress(t), body).await
}

#[embassy_executor::task(pool_size = MAX_THRUSTERS)]
async fn commutation(t: &'static Thruster, input: HallInput) -> ! {
    let body = t.powered_run(|shared| {
        let halls = match input {
            HallInput::Interrupt => Halls::Interrupt(EdgeHalls::new(&t.motorless)),
            HallInput::Model => Halls::Model(ModelHalls::new(&t.motorless)),
        };
        thruster_fw::run_commutation(halls, Bridge(&t.motorless), &t.config, shared)
    });
    metered(&COMMUTATION_METER, None, body).await
}

/// The supply: the controller comes back [`POWER_CUT`] after its power was cut.
#[embassy_executor::task(pool_size = MAX_THRUSTERS)]
async fn power_supply(t: &'static Thruster) -> ! {
    let supply = async {
        loop {
            t.power_cut.wait().await;
            Timer::after(POWER_CUT).await;
            t.power_on();
        }
    };
    metered(&BENCH_METER, None, supply).await
}
