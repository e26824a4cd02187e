//! The motor-less controller (Cargo feature `motorless`): a bare dev kit with no power stage fitted, for the
//! bench test between two dev kits.
//!
//! Nothing is driven: the binding never arms TIM1's outputs, and the bridge port hands the drive to a
//! [`MotorModel`] instead. The halls and the current come from the model; the water sensor stays the real ADC pin
//! (a resistor across it provokes the water fault); the winding reads 25 C. So the real speed loop, fault monitor,
//! stall detector and status run unchanged on a model motor:
//! - speed: first order, time constant [`MotorModel::TIME_CONSTANT`], towards the speed the duty would hold with no
//!   load (the speed loop's feed-forward duty gives exactly 4500 rpm);
//! - halls: [`hall_state_at`] of the modelled electrical angle, an edge at every sector boundary, as the motor's
//!   own halls would give;
//! - current: a propeller's load, rising with the square of the speed (3 A at 4500 rpm), plus the current of a
//!   held rotor (10 A at full duty);
//! - held rotor: while the hold input is on (the NUCLEO's blue user button B1), the rotor stands still: no hall
//!   edges, so the stall detector trips as it would on a rope in the propeller.

use core::cell::Cell;

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_time::{Duration, Instant, Timer};

use crate::commutation::{BridgeDrive, COAST};
use crate::config::Config;
use crate::drive::Duty;
use crate::hall::{HallState, hall_state_at};
use crate::ports::{Bridge, HallSensors, HoldInput, RawSample, Sensors, WaterInput};
use crate::sensors::CurrentSense;

/// Full-scale speed of the order encoding, rpm (IDS 8.3.2).
const FULL_SCALE_RPM: f32 = tmc_proto::Speed::FULL_SCALE_RPM as f32;
/// One electrical sector, degrees.
const SECTOR_DEG: f32 = 60.0;
/// Where sector 0 starts, electrical degrees (see [`hall_state_at`]).
const SECTOR_0_DEG: f32 = 30.0;
/// The modelled propeller's current at full-scale speed, mA.
const LOAD_MA_AT_FULL_SCALE: f32 = 3000.0;
/// The current of a held rotor at full duty, mA.
const HELD_MA_AT_FULL_DUTY: f32 = 10_000.0;

/// A motor that is not there: speed, angle and current from the duty the controller would apply.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotorModel {
    pole_pairs: u8,
    /// Speed at 100 % duty with no load, rpm.
    full_duty_rpm: f32,
    /// Signed mechanical speed, rpm.
    rpm: f32,
    /// Electrical angle, degrees, in [0, 360).
    angle_deg: f32,
    /// The duty applied (zero while coasting).
    duty: Duty,
    /// The rotor is held.
    held: bool,
    /// When the state was last brought up to date.
    at: Instant,
}

impl MotorModel {
    /// The speed's time constant: a small thruster motor spins up in about 0.2 s.
    pub(crate) const TIME_CONSTANT: Duration = Duration::from_millis(50);

    /// A stopped motor for the controller `config`, at angle 45 degrees (inside sector 0), at time 0. The speed at
    /// full duty is set so that the speed loop's feed-forward duty holds exactly 4500 rpm.
    pub const fn new(config: &Config) -> Self {
        let feed_forward = if config.speed.full_scale_duty == 0 {
            Duty::FULL as f32
        } else {
            config.speed.full_scale_duty as f32
        };
        Self {
            pole_pairs: if config.pole_pairs == 0 { 1 } else { config.pole_pairs },
            full_duty_rpm: FULL_SCALE_RPM * Duty::FULL as f32 / feed_forward,
            rpm: 0.0,
            angle_deg: 45.0,
            duty: Duty::ZERO,
            held: false,
            at: Instant::from_ticks(0),
        }
    }

    /// Bring the speed and angle up to `now` (the duty and hold held since the last update). Time going backwards
    /// changes nothing.
    pub(crate) fn advance(&mut self, now: Instant) {
        let Some(elapsed) = now.checked_duration_since(self.at) else {
            return;
        };
        self.at = now;
        if self.held {
            self.rpm = 0.0;
            return;
        }
        let dt = elapsed.as_micros() as f32 / 1e6;
        let tau = Self::TIME_CONSTANT.as_micros() as f32 / 1e6;
        let target = f32::from(self.duty.value()) / f32::from(Duty::FULL) * self.full_duty_rpm;
        let decay = libm::expf(-dt / tau);
        // Exact for a first-order response: the speed, and the revolutions turned on the way.
        let revolutions = (target * dt + (self.rpm - target) * tau * (1.0 - decay)) / 60.0;
        self.rpm = target + (self.rpm - target) * decay;
        let turned = revolutions * 360.0 * f32::from(self.pole_pairs);
        self.angle_deg = wrap_degrees(self.angle_deg + turned);
    }

    /// The bridge is driven with `drive` at `duty` from `now`; coasting applies nothing.
    pub(crate) fn drive(&mut self, now: Instant, drive: BridgeDrive, duty: Duty) {
        self.advance(now);
        self.duty = if drive == COAST { Duty::ZERO } else { duty };
    }

    /// The rotor is held (or let go) from `now`.
    pub(crate) fn hold(&mut self, now: Instant, held: bool) {
        self.advance(now);
        self.held = held;
        if held {
            self.rpm = 0.0;
        }
    }

    /// The hall inputs at the modelled angle.
    pub fn hall_state(&self) -> HallState {
        // `as` saturates; the angle is in [0, 360) anyway and hall_state_at wraps.
        hall_state_at((self.angle_deg * 1000.0) as u32)
    }

    /// Signed mechanical speed, rpm.
    #[cfg(test)]
    pub(crate) fn rpm(&self) -> f32 {
        self.rpm
    }

    /// The motor current, mA: the propeller's load, plus a held rotor's current.
    pub(crate) fn current_milliamps(&self) -> u32 {
        let speed = self.rpm / FULL_SCALE_RPM;
        let mut milliamps = LOAD_MA_AT_FULL_SCALE * speed * speed;
        if self.held {
            milliamps += HELD_MA_AT_FULL_DUTY * f32::from(self.duty.magnitude()) / f32::from(Duty::FULL);
        }
        // `as` saturates (NaN gives 0).
        milliamps as u32
    }

    /// How long until the next hall edge at the present speed; None when (nearly) still.
    pub fn until_next_edge(&self) -> Option<Duration> {
        let degrees_per_s = self.rpm / 60.0 * 360.0 * f32::from(self.pole_pairs);
        if self.held || libm::fabsf(degrees_per_s) < 1.0 {
            return None;
        }
        let into_sector = wrap_degrees(self.angle_deg - SECTOR_0_DEG) % SECTOR_DEG;
        let to_edge = if degrees_per_s > 0.0 {
            SECTOR_DEG - into_sector
        } else {
            into_sector
        };
        let micros = to_edge / libm::fabsf(degrees_per_s) * 1e6;
        // `as` saturates; a few microseconds more land just past the boundary rather than just before it.
        Some(Duration::from_micros(micros as u64 + 2))
    }
}

/// `degrees` in [0, 360).
fn wrap_degrees(degrees: f32) -> f32 {
    let wrapped = libm::fmodf(degrees, 360.0);
    let wrapped = if wrapped < 0.0 { wrapped + 360.0 } else { wrapped };
    // -0.0001 % 360 + 360 rounds to 360.0 in f32; NaN (never expected) restarts at 0.
    if wrapped.is_finite() && wrapped < 360.0 {
        wrapped
    } else {
        0.0
    }
}

/// The model, shared by the commutation task (halls, bridge) and the fault task (current, hold input), which may
/// run on different executors.
pub struct Motorless {
    model: Mutex<CriticalSectionRawMutex, Cell<MotorModel>>,
}

impl Motorless {
    /// Wrap a model.
    pub const fn new(model: MotorModel) -> Self {
        Self {
            model: Mutex::new(Cell::new(model)),
        }
    }

    /// Update the model at `now` with `change`, and return what `read` takes from it.
    fn with<T>(&self, change: impl FnOnce(&mut MotorModel), read: impl FnOnce(&MotorModel) -> T) -> T {
        self.model.lock(|cell| {
            let mut model = cell.get();
            change(&mut model);
            cell.set(model);
            read(&model)
        })
    }

    /// The model brought up to now.
    pub fn now(&self) -> MotorModel {
        let now = Instant::now();
        self.with(|model| model.advance(now), |model| *model)
    }
}

impl core::fmt::Debug for Motorless {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Motorless").finish_non_exhaustive()
    }
}

/// Longest wait for a hall edge before the halls are read again (a motor at rest has none to predict).
const EDGE_POLL: Duration = Duration::from_millis(5);

/// The halls of the model.
#[derive(Debug)]
pub struct ModelHalls<'a> {
    motorless: &'a Motorless,
    seen: HallState,
}

impl<'a> ModelHalls<'a> {
    /// The halls of `motorless`.
    pub fn new(motorless: &'a Motorless) -> Self {
        Self {
            motorless,
            seen: motorless.now().hall_state(),
        }
    }
}

impl HallSensors for ModelHalls<'_> {
    async fn wait_for_edge(&mut self) {
        loop {
            let model = self.motorless.now();
            if model.hall_state() != self.seen {
                return;
            }
            let wait = model.until_next_edge().map_or(EDGE_POLL, |wait| wait.min(EDGE_POLL));
            Timer::after(wait).await;
        }
    }

    fn read(&mut self) -> HallState {
        self.seen = self.motorless.now().hall_state();
        self.seen
    }
}

/// The bridge of a controller with no power stage: what would be driven goes to the model, nothing to a pin.
#[derive(Debug)]
pub struct ModelBridge<'a>(pub &'a Motorless);

impl Bridge for ModelBridge<'_> {
    fn apply(&mut self, drive: BridgeDrive, duty: Duty) {
        let now = Instant::now();
        self.0.with(|model| model.drive(now, drive, duty), |_| ());
    }

    /// No power stage, no break: the model's motor never trips it.
    fn hold_off(&mut self, _off: bool) {}
}

/// The analog inputs of the motor-less controller: the real water sensor, the model's current, 25 C.
#[derive(Debug)]
pub struct ModelSensors<'a, W, H> {
    motorless: &'a Motorless,
    water: W,
    hold: H,
    current: CurrentSense,
    temperature_raw: u16,
    vbus_raw: u16,
}

impl<'a, W: WaterInput, H: HoldInput> ModelSensors<'a, W, H> {
    /// The inputs of the controller `config`, the model in `motorless`.
    pub fn new(motorless: &'a Motorless, config: &Config, water: W, hold: H) -> Self {
        Self {
            motorless,
            water,
            hold,
            current: config.current,
            temperature_raw: config.ntc.raw_at(250),
            vbus_raw: config.vbus.raw_at(crate::speed::SUPPLY_MV),
        }
    }
}

impl<W: WaterInput, H: HoldInput> Sensors for ModelSensors<'_, W, H> {
    async fn sample(&mut self) -> RawSample {
        let held = self.hold.held();
        let now = Instant::now();
        let milliamps = self
            .motorless
            .with(|model| model.hold(now, held), MotorModel::current_milliamps);
        let per_count = u32::from(self.current.milliamps_per_count.max(1));
        let counts = u16::try_from(milliamps / per_count).unwrap_or(u16::MAX);
        RawSample {
            water: self.water.water().await,
            temperature: self.temperature_raw,
            currents: [
                self.current.offset_raw.saturating_add(counts),
                self.current.offset_raw,
                self.current.offset_raw,
            ],
            vbus: self.vbus_raw,
            break_tripped: false,
        }
    }
}

#[cfg(test)]
mod tests;
