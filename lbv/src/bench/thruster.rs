//! One thruster on the bench: the controller as it ships (`thruster_fw::run` and `run_commutation`, with the
//! image's own configuration for its family) on simulated ports, with the plant model behind them.
//!
//! The board is two parts: what is around the controller ([`ThrusterIo`]: the motor, the power stage, the watchdog
//! hardware), which lives as long as the bench, and the controller itself (its tasks and their channels), which a
//! power cycle drops and boots afresh.
//!
//! The chip's flash outlasts both: one lbv-sim flash laid out as the G431's (`THRUSTER_PARTITIONS`), holding at
//! first a factory image in ACTIVE. Every boot runs the thruster's bootloader on it (`lbv_boot::prepare`,
//! embassy-boot's swap and revert) before the controller starts, from whatever image ACTIVE then holds; the
//! controller's field update writes the DFU partition and marks the state partition, and its reset request
//! ([`BootUpdater::reboot`]) has the bench reset the board.
//!
//! So does the RAM at the bottom of the chip that a reset keeps and a power cut loses: the post-mortem region
//! (`g431_hw::memory::CRASH`, the crash-record crate's [`Region`]). A controller stopped as the image's fault
//! handlers stop it ([`ThrusterBoard::stop`]) leaves its record there, and its watchdog resets the chip; every boot
//! starts the region as the image's start does, with the reset's cause, and hands the record found to the
//! controller's updater, which serves it to the master (`PostMortem`). What the model leaves out: the stopped chip's
//! I2C peripheral, which on the G431 acknowledges its address and stretches the clock until the master's timeout,
//! here answers nothing (the master loses the thruster either way); the record's registers, which the bench has
//! none of (its frame is empty); and what the backup domain keeps across a reset on the chip (the bootloader's
//! count of early crashes, the Legacy family's latched faults), which a bench thruster starts without.

use core::cell::{Cell, RefCell};
use core::ops::Deref;
use std::rc::Rc;

use crash_record::{FaultStatus, Frame, Kind, Region, ResetCause, Stop};
use embassy_boot::{BlockingFirmwareState, State};
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Timer};
use embedded_storage::nor_flash::{NorFlash, ReadNorFlash};
use g431_hw::memory::{FLASH_ORIGIN, PAGE, Span, THRUSTER_PARTITIONS};
use lbv_boot::Outcome;
use lbv_sim::flash::{FlashTiming, Stm32g4Flash};
use lbv_sim::i2c::{Bus, DeviceId};
use lbv_sim::{Executor, TaskId};
use thruster_fw::commutation::{BridgeDrive, COAST};
use thruster_fw::faults::VolatileLatch;
use thruster_fw::hall::HallState;
use thruster_fw::ports::{Board, Bridge, HallSensors, Ports, RawSample, Sensors, Watchdog};
use thruster_fw::shared::Shared;
use thruster_fw::{Config, Duty};
use tmc_proto::{Family, MotorKind};
use update_image::{DEV_PUBLIC_KEY, INFO_LEN, INFO_OFFSET, ImageInfo, Target, Version, image_record};

use super::STEP;
use super::battery::Rail;
use super::plant::{MotorParams, Plant};
use super::shunts;
use thruster_fw::sim::{BootRecord, BootUpdater, SlavePort};

#[cfg(test)]
mod tests;

/// The power stage's overcurrent comparator trips TIM1's break input above this phase current, cutting the rest of
/// the PWM period: on average the current is held at the limit (cycle-by-cycle current limiting). The IHM08M1's
/// BKIN comparators trip at a fixed level, about twice the board's 15 A rating (docs/hardware.md, "The break"):
/// above any motor's locked-rotor current here, so only a short reaches it.
const CURRENT_LIMIT_A: f64 = 30.0;
/// The event engine advances a plant on the fixed-step engine's grid while a current limiter acts, and from this
/// phase current up: the comparator's discrete dynamics are those of the 50 us steps, a current rising towards it
/// between two looks (at most a millisecond apart) is caught before it passes it, and the brushed thruster's own
/// 7 A limit (`speed::CurrentLimit`, through the duty) holds its current just above this for long stretches.
const LIMITER_WATCH_A: f64 = 6.0;
/// How far ahead the event engine trusts a turning plant's predicted edge, as a fraction of the plant's mechanical
/// time constant: the prediction takes the acceleration as constant, which is off by about a third of this
/// fraction of the time to the edge (1 % of it); a look after this works it out again. A plant slowing to turn
/// back before its next edge is looked at again after this too.
const LOOK_AHEAD: f64 = 0.03;
/// The look-ahead's bounds: a driven motor's time constant is some 30 ms, a coasting one's seconds.
const LOOK_AHEAD_MIN: Duration = Duration::from_millis(1);
const LOOK_AHEAD_MAX: Duration = Duration::from_millis(100);

/// What is around one controller: the motor and its sensors, the bridge, the watchdog.
pub struct ThrusterIo {
    /// The motor, propeller and sensors.
    pub plant: RefCell<Plant>,
    /// What the commutation task drives.
    drive: Cell<(BridgeDrive, Duty)>,
    /// Raised by the plant on every hall change.
    hall_edge: Signal<NoopRawMutex, ()>,
    /// When the watchdog was last fed.
    last_feed: Cell<Instant>,
    /// Times the watchdog would have reset the controller.
    pub watchdog_bites: Cell<u32>,
    /// The fraction of the commanded duty the break input lets through (1.0 when not limiting).
    current_limit: Cell<f64>,
    /// The supply at the last fixed step, V (the event engine reads the rail instead).
    supply_v: Cell<f64>,
    /// Steps during which the break input limited the current.
    pub limited_steps: Cell<u64>,
    /// TIM1's break flag (SR.BIF): set by every trip, cleared by the fault task's sample that reads it.
    break_flag: Cell<bool>,
    /// The controller holds the bridge's outputs off (a sustained overcurrent): nothing is driven.
    held_off: Cell<bool>,
    /// A phase shorted (water in it, a failed MOSFET): the comparator trips as soon as the bridge switches, every
    /// period, so the motor gets no drive, and the break flag is set whenever the bridge drives.
    pub shorted: Cell<bool>,
    /// A shorted MOSFET: it shoots through only in the two sectors of six where its partner switches, so the
    /// comparator trips on one fault-task sample in three while the bridge drives (each cut pulse costs the motor
    /// little of its drive, which is left as it is).
    pub intermittent: Cell<bool>,
    /// Fault-task samples taken, for the intermittent short's one in three.
    samples: Cell<u32>,
    /// On the event engine: how the plant is advanced between events (None: the fixed-step engine steps it).
    lazy: Option<Lazy>,
}

/// The event engine's hold on one plant: the plant is advanced only when something reads it, changes its drive or
/// reaches a moment the bench was told of (a predicted hall edge, a step of the current limiter).
struct Lazy {
    /// The pack's terminals, shared by every thruster.
    rail: Rc<Rail>,
    /// This thruster's place on the rail.
    index: usize,
    /// Virtual time the plant has been advanced to.
    synced: Cell<Instant>,
    /// When the bench must next advance the plant.
    next: Cell<Option<Instant>>,
    /// The current limiter acts or may soon: the plant is advanced on the 50 us grid, the limiter at its points.
    limiting: Cell<bool>,
    /// How far ahead the last look trusted the plant's course (see [`LOOK_AHEAD`]): also its longest sub-step.
    look_ahead: Cell<Duration>,
    /// Its drive changed, its halls changed or it reached its moment since `next` was worked out: the bench works
    /// it out again once the instant's tasks are done.
    dirty: Cell<bool>,
}

/// The motor behind a bench thruster: its kind, and its rotor's inertia (propeller and entrained water included) as
/// a multiple of the reference thruster's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Motor {
    pub kind: MotorKind,
    pub inertia_x: u8,
}

impl Motor {
    /// The reference thruster: brushless, its own rotor.
    pub const REFERENCE: Motor = Motor {
        kind: MotorKind::Brushless,
        inertia_x: 1,
    };

    /// The plant's parameters.
    pub fn params(self) -> MotorParams {
        let base = match self.kind {
            MotorKind::Brushless => MotorParams::THRUSTER,
            MotorKind::Brushed => MotorParams::BRUSHED_THRUSTER,
        };
        MotorParams {
            inertia_kg_m2: base.inertia_kg_m2 * f64::from(self.inertia_x.max(1)),
            ..base
        }
    }
}

/// The length of the image a bench thruster leaves the factory with, about the application's.
pub const FACTORY_IMAGE_LEN: usize = 32 * 1024;

/// The version of the image a bench thruster leaves the factory with.
pub const FACTORY_VERSION: Version = Version::new(0, 1, 0);

/// A made-up image of `len` bytes (a multiple of the flash's 8-byte double word) for `target` at `version`: its
/// information record at [`INFO_OFFSET`], as a real image embeds it, and every other byte drawn from `seed`
/// (xorshift32), so that images of two seeds differ throughout.
pub fn made_up_image(target: Target, version: Version, len: usize, seed: u32) -> Vec<u8> {
    let mut x = seed.wrapping_mul(0x9E37_79B9) | 1;
    let mut image: Vec<u8> = (0..len)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x as u8
        })
        .collect();
    // Its image info and, after it, the key the bench's update files are signed with (the development key): the
    // bootloader checks the next image with it.
    let record = image_record(ImageInfo::new(target, version), &DEV_PUBLIC_KEY);
    if let Some(slot) = image.get_mut(INFO_OFFSET..INFO_OFFSET + record.len()) {
        slot.copy_from_slice(&record);
    }
    image
}

/// The image a bench thruster of `family` leaves the factory with: [`FACTORY_VERSION`], [`FACTORY_IMAGE_LEN`] bytes.
pub fn factory_image(family: Family) -> Vec<u8> {
    made_up_image(Target::thruster(family), FACTORY_VERSION, FACTORY_IMAGE_LEN, 1)
}

/// The partition at `span` (an address range, as `THRUSTER_PARTITIONS` gives it) of the thruster's `flash`, whose
/// offset 0 is the flash's first address, as embassy-stm32's flash driver addresses it.
pub fn partition(flash: &Stm32g4Flash, span: Span) -> Stm32g4Flash {
    flash
        .partition(span.origin - FLASH_ORIGIN, span.length)
        .expect("the thruster's partitions lie within its flash, on page boundaries")
}

/// The G431's flash, erased but for `image` at the start of ACTIVE, as a probe leaves it.
fn factory_flash(image: &[u8]) -> Stm32g4Flash {
    let flash = Stm32g4Flash::new((THRUSTER_PARTITIONS.chip.flash.length / PAGE) as usize);
    partition(&flash, THRUSTER_PARTITIONS.active)
        .write(0, image)
        .expect("the factory image fits ACTIVE");
    flash
}

/// The first point of the fixed-step engine's grid after `t`.
fn next_grid_point(t: Instant) -> Instant {
    Instant::from_ticks((t.as_ticks() / STEP.as_ticks() + 1) * STEP.as_ticks())
}

fn seconds(duration: Duration) -> f64 {
    duration.as_micros() as f64 / 1e6
}

/// A thruster: its controller's configuration, its place on the bus, what is around it and, while powered, the
/// controller's tasks.
pub struct ThrusterBoard {
    /// The controller's build-time configuration: the image's, for this family.
    pub config: Config,
    /// What is around the controller.
    pub io: Rc<ThrusterIo>,
    /// The bus it hangs on, and its place there.
    bus: Bus,
    /// Its slave port on the bus.
    pub device: DeviceId,
    /// The controller's task channels, fresh at every boot.
    shared: Rc<Shared>,
    /// The chip's flash (bootloader, state, ACTIVE, DFU), which outlasts a power cut.
    flash: Stm32g4Flash,
    /// The field update's side of the chip, as the controller was last booted with it (its running image's
    /// information record); its reboot counter lives as long as the board.
    updater: BootUpdater,
    /// Reboots asked for through the updater that a boot has since served.
    reboots_served: u32,
    /// What the bootloader did at the last boot.
    boot_outcome: Option<Outcome>,
    /// The next boot's bootloader loses the power after this many bytes of flash work (a cut mid-swap): the
    /// board then stays off until the next boot.
    pub cut_in_bootloader: Option<usize>,
    tasks: Vec<TaskId>,
    /// The post-mortem region: RAM that a reset keeps and a power cut loses. The board's while the controller is
    /// off; its controller's `Shared` has it while it runs, and notes its events in it.
    crash_ram: Option<&'static mut Region>,
    /// Why the next boot's reset comes (RCC_CSR's flags): a power-on, unless a stop's watchdog resets it.
    next_reset: ResetCause,
    /// When the controller last started, and when it stopped (its watchdog then resets it).
    started: Instant,
    stopped: Option<Instant>,
}

/// RCC_CSR after a power-on: BORRSTF and PINRSTF (RM0440 7.4.30; the reset pin follows every reset).
const POWER_ON: ResetCause = ResetCause(1 << 27 | 1 << 26);
/// RCC_CSR after the independent watchdog's reset: IWDGRSTF and PINRSTF.
const WATCHDOG_RESET: ResetCause = ResetCause(1 << 29 | 1 << 26);

impl Deref for ThrusterBoard {
    type Target = ThrusterIo;

    fn deref(&self) -> &ThrusterIo {
        &self.io
    }
}

impl ThrusterBoard {
    /// A thruster of `family` driving `motor` at `device` on `bus`, its rotor at `angle` (mechanical radians); not
    /// powered yet. Its
    /// flash holds a factory image of this family, version [`FACTORY_VERSION`], in ACTIVE, and nothing else. On
    /// the event engine `rail` is the pack's terminals and `index` its place there; without, the fixed-step engine
    /// steps the plant.
    pub fn new(
        family: Family,
        motor: Motor,
        bus: &Bus,
        device: DeviceId,
        angle: f64,
        rail: Option<(Rc<Rail>, usize)>,
    ) -> Self {
        let flash = factory_flash(&factory_image(family));
        let updater = BootUpdater::new(
            family,
            partition(&flash, THRUSTER_PARTITIONS.ticket()),
            partition(&flash, THRUSTER_PARTITIONS.state),
        );
        Self {
            config: Config::reference(family, motor.kind),
            io: Rc::new(ThrusterIo {
                plant: RefCell::new(Plant::new(motor.params()).with_angle(angle)),
                drive: Cell::new((COAST, Duty::ZERO)),
                hall_edge: Signal::new(),
                last_feed: Cell::new(Instant::from_ticks(0)),
                watchdog_bites: Cell::new(0),
                current_limit: Cell::new(1.0),
                supply_v: Cell::new(0.0),
                limited_steps: Cell::new(0),
                break_flag: Cell::new(false),
                held_off: Cell::new(false),
                shorted: Cell::new(false),
                intermittent: Cell::new(false),
                samples: Cell::new(0),
                lazy: rail.map(|(rail, index)| Lazy {
                    rail,
                    index,
                    synced: Cell::new(Instant::from_ticks(0)),
                    next: Cell::new(None),
                    limiting: Cell::new(false),
                    look_ahead: Cell::new(LOOK_AHEAD_MIN),
                    dirty: Cell::new(true),
                }),
            }),
            bus: bus.clone(),
            device,
            shared: Rc::new(Shared::new()),
            flash,
            updater,
            reboots_served: 0,
            boot_outcome: None,
            cut_in_bootloader: None,
            tasks: Vec::new(),
            // A board's own RAM, for as long as the bench runs.
            crash_ram: Some(Box::leak(Box::new(Region::new()))),
            next_reset: POWER_ON,
            started: Instant::from_ticks(0),
            stopped: None,
        }
    }

    /// Power up: the bootloader prepares ACTIVE (swapping a new image in, or an unconfirmed one out), then the
    /// controller boots with fresh state from the image ACTIVE holds and its slave port answers again. A powered
    /// controller is left as it is.
    ///
    /// The bootloader's flash work is done at once; the controller starts, and acknowledges on the bus, only once
    /// the time that work takes on the G431 has passed ([`FlashTiming::G431`]: about 3 s for a swap), and its
    /// watchdog runs from then, as the bootloader starts it just before the jump. A power cut in that time finds
    /// the swap done; one inside the swap itself is [`ThrusterBoard::cut_in_bootloader`].
    pub fn boot(&mut self, executor: &mut Executor<'static>) {
        if self.powered() {
            return;
        }
        let before = self.flash.stats();
        self.flash.power_on();
        if let Some(bytes) = self.cut_in_bootloader.take() {
            self.flash.cut_power_after(bytes);
        }
        // A bench thruster boots from power-off only (a power cycle clears the count of early crashes).
        let crashes = lbv_boot::CrashCount::default();
        self.boot_outcome = Some(lbv_boot::prepare(
            self.flash.clone(),
            &THRUSTER_PARTITIONS,
            crashes,
            || {},
        ));
        if !self.flash.powered() {
            // The power went in the bootloader's work: the board stays off until the next boot.
            return;
        }
        let starts = Instant::now() + FlashTiming::G431.work_time(before, self.flash.stats());
        let in_bootloader = starts > Instant::now();
        self.updater.info = self.read_running_info();
        // The image's start, first of all: the record of the stop before it, if the reset kept one.
        let image = self.crash_image();
        let cause = core::mem::replace(&mut self.next_reset, POWER_ON);
        if let Some(region) = self.crash_ram.take() {
            self.updater.post_mortem = region.start(cause, image).map(|record| record.encode());
            self.shared.keep_crash(region);
        }
        (self.started, self.stopped) = (starts, None);
        // A reset asked for before this boot is the one this boot is.
        self.reboots_served = self.updater.reboots.get();

        if !in_bootloader {
            self.bus.set_powered(self.device, true);
        }
        self.io.last_feed.set(starts);
        let Some(port) = self.bus.target(self.device) else {
            return;
        };
        // Wait for the bootloader only when it has work to wait for: a boot with nothing to swap runs its tasks at
        // once, as it always has.
        let bootloader = in_bootloader.then(|| (self.bus.clone(), self.device));
        let ports = Ports::<BenchBoard> {
            i2c: SlavePort(port),
            sensors: Adc {
                io: self.io.clone(),
                config: self.config.clone(),
            },
            watchdog: Dog(self.io.clone()),
            // Every bench boot follows a power cut: the latches start empty.
            latch: VolatileLatch::default(),
            boot: BootRecord(partition(&self.flash, THRUSTER_PARTITIONS.state)),
            dfu: partition(&self.flash, THRUSTER_PARTITIONS.dfu),
            updater: self.updater.clone(),
        };
        let (config, shared) = (self.config.clone(), self.shared.clone());
        let run = executor.spawn(async move {
            if let Some((bus, device)) = bootloader {
                Timer::at(starts).await;
                bus.set_powered(device, true);
            }
            thruster_fw::run(ports, &config, &shared).await;
        });
        let (halls, stage) = (Halls(self.io.clone()), Stage(self.io.clone()));
        let (config, shared) = (self.config.clone(), self.shared.clone());
        let commutation = executor.spawn(async move {
            if in_bootloader {
                Timer::at(starts).await;
            }
            thruster_fw::run_commutation(halls, stage, &config, &shared).await;
        });
        self.tasks = vec![run, commutation];
    }

    /// The information record of the image in ACTIVE, read where the image embeds it; erased bytes if unreadable
    /// (what a thruster without a record reports).
    fn read_running_info(&self) -> [u8; INFO_LEN] {
        let mut info = [0xFF; INFO_LEN];
        match partition(&self.flash, THRUSTER_PARTITIONS.active).read(INFO_OFFSET as u32, &mut info) {
            Ok(()) => info,
            Err(_) => [0xFF; INFO_LEN],
        }
    }

    /// Whether the controller asked for a reset that it has not had yet.
    pub fn reboot_requested(&self) -> bool {
        self.updater.reboots.get() != self.reboots_served
    }

    /// Cut the power: the controller stops where it is, the bridge coasts, the slave port stops answering, and
    /// everything the controller knew is gone.
    pub fn power_off(&mut self, executor: &mut Executor<'static>) {
        for task in self.tasks.drain(..) {
            executor.remove(task);
        }
        self.bus.set_powered(self.device, false);
        self.io.catch_up(Instant::now());
        self.io.drive.set((COAST, Duty::ZERO));
        // TIM1 comes out of reset with its outputs off and its flags clear.
        self.io.held_off.set(false);
        self.io.break_flag.set(false);
        self.io.disturbed();
        if let Some(region) = self.shared.take_crash() {
            self.crash_ram = Some(region);
        }
        self.shared = Rc::new(Shared::new());
        (self.next_reset, self.stopped) = (POWER_ON, None);
    }

    /// Stop the controller as the image's fault handlers do on a `kind` of stop (a panic, say): the bridge off first,
    /// every task stopped where it is, and the post-mortem record written; its slave port answers nothing from then
    /// on, and its watchdog resets it once its timeout has run out ([`ThrusterBoard::watchdog_reset_due`]).
    pub fn stop(&mut self, executor: &mut Executor<'static>, kind: Kind) {
        if !self.powered() {
            return;
        }
        let now = Instant::now();
        self.power_off(executor);
        let stop = Stop {
            kind,
            frame: Frame::default(),
            faults: FaultStatus::default(),
            exception: 0,
            panic: None,
            uptime_ms: now.saturating_duration_since(self.started).as_millis() as u32,
        };
        let image = self.crash_image();
        if let Some(region) = self.crash_ram.as_deref_mut() {
            region.record(stop, image);
        }
        (self.next_reset, self.stopped) = (WATCHDOG_RESET, Some(now));
    }

    /// The image as its post-mortem record keeps it: this family's thruster, the version ACTIVE holds.
    fn crash_image(&self) -> crash_record::Image {
        crash_record::Image {
            target: Target::thruster(self.config.family).to_byte(),
            version: self.running_image().map_or([0; 4], |info| info.version.to_bytes()),
        }
    }

    /// Whether the controller stopped and its watchdog's timeout has run out at `now`: the chip resets.
    pub fn watchdog_reset_due(&self, now: Instant) -> bool {
        self.stopped
            .is_some_and(|stopped| now >= stopped + self.config.watchdog.timeout)
    }

    /// Hang the controller: its thread-mode tasks stop where they are (a lock-up) while it stays powered and its
    /// commutation runs on, so its watchdog goes unfed.
    #[cfg(test)]
    pub fn hang(&mut self, executor: &mut Executor<'static>) {
        if let Some(run) = self.tasks.first() {
            executor.remove(*run);
        }
    }

    /// Whether the controller is powered.
    pub fn powered(&self) -> bool {
        !self.tasks.is_empty()
    }

    /// The controller's task channels (its fault verdict, duty and status frame).
    pub fn shared(&self) -> &Shared {
        &self.shared
    }

    /// How often the controller re-initialised its slave port.
    pub fn slave_resets(&self) -> u32 {
        self.bus.target_resets(self.device)
    }

    /// Fixed-step engine: advance the motor by `dt` on `supply_v` at `now`, raising a hall edge when the halls
    /// change; keep the watchdog's count.
    pub fn step(&self, now: Instant, dt: f64, supply_v: f64) {
        self.io.step(dt, supply_v);
        self.watch(now);
    }

    /// Count a watchdog reset if the controller has gone unfed past its timeout at `now`.
    pub fn watch(&self, now: Instant) {
        let io = &self.io;
        // The bootloader starts the watchdog at its end, which may not have come yet.
        if self.powered() && now.saturating_duration_since(io.last_feed.get()) > self.config.watchdog.timeout {
            io.watchdog_bites.set(io.watchdog_bites.get() + 1);
            io.last_feed.set(now);
        }
    }

    /// Event engine: when the bench must next look at this thruster (its plant's next moment, its watchdog's
    /// deadline).
    pub fn next_event(&self) -> Option<Instant> {
        let plant = self.io.lazy.as_ref().and_then(|lazy| lazy.next.get());
        let watchdog = match self.stopped {
            Some(stopped) => Some(stopped + self.config.watchdog.timeout),
            None => self
                .powered()
                .then(|| self.io.last_feed.get() + self.config.watchdog.timeout + Duration::from_ticks(1)),
        };
        match (plant, watchdog) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }
}

/// What a scenario looks at across a field update: the flash, the bootloader's work, the image that runs.
#[allow(
    dead_code,
    reason = "for scenarios that update a thruster over the bus; today the bench's own tests read them"
)]
impl ThrusterBoard {
    /// The chip's flash, the whole of it (`THRUSTER_PARTITIONS` says where each partition is).
    pub fn flash(&self) -> &Stm32g4Flash {
        &self.flash
    }

    /// The field update's side of the chip the controller runs with: a handle on the same flash and the same
    /// reboot counter, reporting the running image the last boot found.
    pub fn updater(&self) -> BootUpdater {
        self.updater.clone()
    }

    /// The information record of the image the controller runs (what its extension's `Version` reports).
    pub fn running_info(&self) -> [u8; INFO_LEN] {
        self.updater.info
    }

    /// The image the controller runs, from its information record; None if ACTIVE holds none.
    pub fn running_image(&self) -> Option<ImageInfo> {
        ImageInfo::parse(&self.updater.info).ok()
    }

    /// What the bootloader did at the last boot (None before the first).
    pub fn boot_outcome(&self) -> Option<&Outcome> {
        self.boot_outcome.as_ref()
    }

    /// The bootloader's state as embassy-boot reads it now (`Swap`: an image on trial); None if unreadable.
    pub fn boot_state(&self) -> Option<State> {
        let mut word = [0; 8];
        let state = partition(&self.flash, THRUSTER_PARTITIONS.state);
        BlockingFirmwareState::new(state, &mut word).get_state().ok()
    }

    /// Resets the controller asked for through its updater since the bench was built.
    pub fn reboots(&self) -> u32 {
        self.updater.reboots.get()
    }
}

impl ThrusterIo {
    /// The drive the bridge applies now.
    pub fn drive(&self) -> (BridgeDrive, Duty) {
        self.drive.get()
    }

    /// What reaches the motor: the drive applied, with the duty the bridge passes; nothing through a short.
    fn applied(&self) -> (BridgeDrive, Duty) {
        if self.shorted.get() {
            return (COAST, Duty::ZERO);
        }
        let (drive, duty) = self.drive.get();
        (drive, self.passed(duty))
    }

    /// Whether the break tripped since the last look, clearing the flag (as the fault task's sample clears BIF).
    fn take_break(&self) -> bool {
        let driving = !self.held_off.get() && self.drive.get().1 != Duty::ZERO;
        let samples = self.samples.get().wrapping_add(1);
        self.samples.set(samples);
        let intermittent = self.intermittent.get() && driving && samples.is_multiple_of(3);
        self.break_flag.replace(false) || (self.shorted.get() && driving) || intermittent
    }

    /// One comparator trip, as a switching spike gives: the next fault-task sample sees it.
    pub fn spike(&self) {
        self.break_flag.set(true);
    }

    /// The duty the bridge passes: the commanded one, scaled by the break input while it limits the current.
    fn passed(&self, duty: Duty) -> Duty {
        let scale = self.current_limit.get();
        if scale == 1.0 {
            return duty;
        }
        Duty::new_saturating(round(f64::from(duty.value()) * scale))
    }

    /// One step of the break input's limiting, after a step at `current`: on average it scales the duty to hold
    /// the limit.
    fn limit(&self, current: f64) {
        let scale = self.current_limit.get();

        if current > CURRENT_LIMIT_A {
            self.current_limit.set((scale * CURRENT_LIMIT_A / current).max(0.0));
            self.limited_steps.set(self.limited_steps.get() + 1);
            self.break_flag.set(true);
        } else {
            self.current_limit.set((scale * 1.05).min(1.0));
        }
    }

    fn step(&self, dt: f64, supply_v: f64) {
        self.supply_v.set(supply_v);
        let (drive, passed) = self.applied();
        let mut plant = self.plant.borrow_mut();
        if plant.step(dt, drive, passed, supply_v) {
            self.hall_edge.signal(());
        }
        // The hardware break acts within the PWM period.
        let current = plant.phase_current_a();
        drop(plant);
        self.limit(current);
    }

    /// Event engine: advance the plant from where it was left to `now` under the drive held since, in sub-steps of
    /// at most the look-ahead (on the 50 us grid while the limiter acts), each on the pack's voltage at its start;
    /// raise a hall edge where the halls changed. Between commutations the driven pair sees a constant back-EMF
    /// shape, so the speed follows a smooth first-order law that implicit steps of a small fraction of its time
    /// constant track closely (the fidelity test holds what the bench's figures make of it). Nothing on the
    /// fixed-step engine, which steps the plant itself.
    pub fn catch_up(&self, now: Instant) {
        let Some(lazy) = &self.lazy else { return };
        let mut t = lazy.synced.get();
        if t >= now {
            return;
        }
        let mut plant = self.plant.borrow_mut();
        let (grid, longest) = (lazy.limiting.get(), lazy.look_ahead.get());
        while t < now {
            let mut end = now.min(t + longest);
            if grid {
                end = end.min(next_grid_point(t));
            }
            let h = seconds(end - t);
            let (drive, passed) = self.applied();
            if plant.advance(h, drive, passed, lazy.rail.voltage()) {
                self.hall_edge.signal(());
                lazy.dirty.set(true);
            }
            lazy.rail.draw(lazy.index, plant.supply_current_a(), h);
            if grid && end.as_ticks().is_multiple_of(STEP.as_ticks()) {
                // A step of the limiter at the end of a step of the grid, on the current the step started with
                // (as the fixed-step engine's limiter takes it).
                self.limit(plant.phase_current_a());
                lazy.dirty.set(true);
            }
            t = end;
        }
        lazy.synced.set(now);
    }

    /// The winding temperature and phase currents the ADC sees at `now`. On the event engine the plant is not moved
    /// for it (the ADC samples every millisecond; the plant needs advancing only at its edges and drive changes):
    /// the temperature is the one advancing would give, the currents the present state's.
    fn sense(&self, now: Instant) -> (f64, [f64; 3]) {
        let mut plant = self.plant.borrow_mut();
        let (drive, passed) = self.applied();
        match &self.lazy {
            Some(lazy) => {
                let h = seconds(now - lazy.synced.get());
                plant.reading_after(h, drive, passed, lazy.rail.voltage())
            }
            // The currents of the drive applied now: the last step's may be of the step before a commutation, and
            // the shunts read by phase.
            None => (
                plant.winding_c(),
                plant.currents_with(drive, passed, self.supply_v.get()),
            ),
        }
    }

    /// The supply at the bridge, V: what VBUS's divider sees.
    fn supply(&self) -> f64 {
        match &self.lazy {
            Some(lazy) => lazy.rail.voltage(),
            None => self.supply_v.get(),
        }
    }

    /// Event engine: the plant's state was changed from outside (a fault, a power cut): have its next moment
    /// worked out again.
    pub fn disturbed(&self) {
        if let Some(lazy) = &self.lazy {
            lazy.dirty.set(true);
        }
    }

    /// Event engine: if the plant moved or its drive changed, evaluate its currents at `now` for the drive
    /// applied now (raising a hall edge if the halls changed without moving, as when a fault takes them) and work
    /// out when the bench must next advance it: at its next hall edge, and on every point of the 50 us grid while
    /// the current limiter acts or the current nears the limit.
    pub fn plan(&self, now: Instant) {
        let Some(lazy) = self.lazy.as_ref().filter(|lazy| lazy.dirty.replace(false)) else {
            return;
        };
        let mut plant = self.plant.borrow_mut();
        let (drive, passed) = self.applied();
        // The pack sees the new current from the sub-step that carries it (as on the fixed-step engine, where the
        // voltage of a step follows the currents of the one before).
        if plant.evaluate(drive, passed, lazy.rail.voltage()) {
            self.hall_edge.signal(());
        }
        let limiting = self.current_limit.get() < 1.0 || plant.phase_current_a() > LIMITER_WATCH_A;
        lazy.limiting.set(limiting);
        let look_ahead = plant.time_constant().map_or(LOOK_AHEAD_MIN, |tau| {
            Duration::from_micros((LOOK_AHEAD * tau * 1e6) as u64).clamp(LOOK_AHEAD_MIN, LOOK_AHEAD_MAX)
        });
        lazy.look_ahead.set(look_ahead);
        let edge = match plant.time_to_edge() {
            Some(s) => Some(now + Duration::from_micros((s * 1e6).ceil().clamp(1.0, 1e12) as u64).min(look_ahead)),
            None if plant.rpm() != 0.0 => Some(now + look_ahead),
            None => None,
        };
        let next = match (edge, limiting.then(|| next_grid_point(now))) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        lazy.next.set(next);
    }

    /// Event engine: the bench reached `now`; advance the plant if this is its moment.
    pub fn wake(&self, now: Instant) {
        if let Some(lazy) = &self.lazy
            && lazy.next.get().is_some_and(|next| next <= now)
        {
            self.catch_up(now);
            lazy.dirty.set(true);
        }
    }
}

/// `x` rounded half away from zero, as `f64::round`, without the library call (x86-64's baseline has no rounding
/// instruction): the fraction `x - trunc(x)` is exact. Saturates like `as i32`.
pub(super) fn round(x: f64) -> i32 {
    let whole = x as i32;
    let fraction = x - f64::from(whole);
    if fraction >= 0.5 {
        whole.saturating_add(1)
    } else if fraction <= -0.5 {
        whole.saturating_sub(1)
    } else {
        whole
    }
}

struct Halls(Rc<ThrusterIo>);

impl HallSensors for Halls {
    async fn wait_for_edge(&mut self) {
        self.0.hall_edge.wait().await;
    }

    fn read(&mut self) -> HallState {
        self.0.catch_up(Instant::now());
        self.0.plant.borrow().hall_state()
    }
}

struct Stage(Rc<ThrusterIo>);

impl Bridge for Stage {
    fn apply(&mut self, drive: BridgeDrive, duty: Duty) {
        self.0.catch_up(Instant::now());
        // Outputs held off drive nothing, whatever the pattern (TIM1 with MOE and AOE cleared).
        let (drive, duty) = if self.0.held_off.get() {
            (COAST, Duty::ZERO)
        } else {
            (drive, duty)
        };
        if self.0.drive.replace((drive, duty)) != (drive, duty) {
            self.0.disturbed();
        }
    }

    fn hold_off(&mut self, off: bool) {
        self.0.catch_up(Instant::now());
        self.0.held_off.set(off);
        if off && self.0.drive.replace((COAST, Duty::ZERO)) != (COAST, Duty::ZERO) {
            self.0.disturbed();
        }
    }
}

/// The ADC, reading the plant through the controller's sensors.
struct Adc {
    io: Rc<ThrusterIo>,
    config: Config,
}

impl Sensors for Adc {
    async fn sample(&mut self) -> RawSample {
        let (winding_c, currents_a) = self.io.sense(Instant::now());
        let (drive, duty) = self.io.applied();
        let config = &self.config;
        let decicelsius = round(winding_c * 10.0).clamp(i32::from(i16::MIN), i32::from(i16::MAX)) as i16;
        RawSample {
            water: config.water.raw_at(self.io.plant.borrow().water_ohms),
            temperature: config.ntc.raw_at(decicelsius),
            currents: shunts::at_trigger(&config.current, drive, duty, currents_a),
            vbus: config.vbus.raw_at(round(self.io.supply() * 1000.0).max(0) as u32),
            break_tripped: self.io.take_break(),
        }
    }
}

struct Dog(Rc<ThrusterIo>);

impl Watchdog for Dog {
    fn feed(&mut self) {
        self.0.last_feed.set(Instant::now());
    }
}

/// The bench controller's ports: lbv-sim's bus and flash, the rest the plant's.
struct BenchBoard;

impl Board for BenchBoard {
    type I2c = SlavePort;
    type Sensors = Adc;
    type Watchdog = Dog;
    type Latch = VolatileLatch;
    type Boot = BootRecord;
    type Dfu = Stm32g4Flash;
    type Updater = BootUpdater;
}
