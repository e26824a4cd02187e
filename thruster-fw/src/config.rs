//! Everything fixed at build time for one controller ([`Config`]): its family and motor, the loops' tuning, the
//! fault thresholds, the sensors' scaling, the I2C slave port and the watchdog's timing.

use embassy_time::Duration;
use tmc_proto::{Family, MotorKind};

use crate::failsafe::LinkFailsafe;
use crate::faults::Thresholds;
use crate::sensors::{CurrentSense, Ntc, VbusSense, WaterSensor};
use crate::speed::SpeedConfig;

/// How long the I2C task waits for its address before it reports itself alive anyway.
pub(crate) const LISTEN_HEARTBEAT: Duration = Duration::from_millis(50);
/// How long the commutation task waits for a hall edge or a change to drive before it reports itself alive anyway
/// (a motor at rest, or turning too slowly for an edge, with its duty unchanged).
pub(crate) const COMMUTATION_HEARTBEAT: Duration = Duration::from_millis(20);

/// Everything fixed at build time for one controller.
#[derive(Debug, Clone)]
pub struct Config {
    /// Controller family, which sets the address, the message types and the fault semantics.
    pub family: Family,
    /// Brushless (hall commutation, closed speed loop) or brushed (H-bridge, open loop).
    pub(crate) motor: MotorKind,
    /// Motor pole pairs, for rpm from hall edges.
    pub pole_pairs: u8,
    /// Link failsafe timeout.
    pub(crate) link_timeout: Duration,
    /// Speed loop tuning.
    pub(crate) speed: SpeedConfig,
    /// Fault thresholds.
    pub thresholds: Thresholds,
    /// Water-sensor divider.
    pub water: WaterSensor,
    /// The sensor of the temperature the status reports (IDS 8.4.2 TEMPERATURE).
    pub ntc: Ntc,
    /// Motor current sense.
    pub current: CurrentSense,
    /// The supply's divider.
    pub vbus: VbusSense,
    /// The I2C slave port.
    pub bus: SlaveBus,
    /// The independent watchdog.
    pub watchdog: WatchdogTiming,
}

/// The thruster interface's bus as the slave sees it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SlaveBus {
    /// SCL frequency, Hz (IDS 6.4.1: 100 kbit/s).
    pub frequency_hz: u32,
    /// A transfer stalled this long (SMBus's SCL-low timeout) is abandoned and the port re-initialised, so the
    /// controller never holds the bus (IDS 6.6.2). embassy-stm32's default is 1 s.
    pub timeout: Duration,
}

/// The independent watchdog's timing: fed every `feed` while every task reports progress; a chip left unfed for
/// `timeout` resets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WatchdogTiming {
    /// How often the health task checks the tasks and feeds the watchdog.
    pub(crate) feed: Duration,
    /// How long the watchdog waits unfed before it resets the chip.
    pub timeout: Duration,
}

impl WatchdogTiming {
    /// The timeout in microseconds, as the IWDG driver takes it (saturated).
    pub(crate) const fn timeout_us(&self) -> u32 {
        saturating_u32(self.timeout.as_micros())
    }

    /// The schedule the IWDG set-up is checked against: the slowest task to report goes at most this long between
    /// reports: the I2C task one listen heartbeat plus one transfer's timeout, the commutation task (woken only by
    /// hall edges and changes to drive) one commutation heartbeat; the others report every millisecond.
    pub const fn schedule(&self, bus: &SlaveBus) -> g431_hw::iwdg::Schedule {
        let i2c = LISTEN_HEARTBEAT.as_micros().saturating_add(bus.timeout.as_micros());
        let commutation = COMMUTATION_HEARTBEAT.as_micros();
        g431_hw::iwdg::Schedule {
            feed_period_us: saturating_u32(self.feed.as_micros()),
            slowest_report_us: saturating_u32(if i2c > commutation { i2c } else { commutation }),
            timeout_us: self.timeout_us(),
        }
    }
}

const fn saturating_u32(value: u64) -> u32 {
    if value > u32::MAX as u64 {
        u32::MAX
    } else {
        value as u32
    }
}

impl Config {
    /// The reference hardware: a 4-pole-pair hall-sensored motor on an X-NUCLEO-IHM08M1, the water-sensor
    /// electrodes over a 1 Mohm pull-down (the 1 Mohm water threshold sits at mid-scale, where the divider resolves
    /// best), the winding's NTC for a brushless motor and the power stage's for a brushed one, the spec's
    /// thresholds and a 1 s failsafe.
    pub const fn reference(family: Family, motor: MotorKind) -> Config {
        Config {
            family,
            motor,
            pole_pairs: 4,
            link_timeout: LinkFailsafe::DEFAULT_TIMEOUT,
            speed: match motor {
                MotorKind::Brushless => SpeedConfig::BRUSHLESS_DEFAULT,
                MotorKind::Brushed => SpeedConfig::BRUSHED_DEFAULT,
            },
            thresholds: Thresholds::SPEC,
            water: WaterSensor {
                pull_down_ohms: 1_000_000,
            },
            ntc: match motor {
                MotorKind::Brushless => Ntc::MOTOR,
                MotorKind::Brushed => Ntc::IHM08M1,
            },
            // IHM08M1, three shunts (docs/hardware.md, "Current sensing"): 10 mohm, gain 5.18, offset 1.71 V:
            // 3.3 V / 4096 / (0.01 ohm * 5.18) = 15.6 mA per count, 1.71 V / 3.3 V * 4096 = 2122.
            current: CurrentSense {
                offset_raw: 2122,
                milliamps_per_count: 16,
            },
            vbus: VbusSense::IHM08M1,
            bus: SlaveBus {
                frequency_hz: 100_000,
                timeout: Duration::from_millis(25),
            },
            // Fed every 100 ms: longer than the slowest task's gap between reports (the I2C task's listen
            // heartbeat plus one transfer's timeout, 75 ms), so a healthy controller never misses a feed; the
            // 250 ms timeout outlasts two feeds even at the fastest LSI (`g431_hw::iwdg::Schedule`).
            watchdog: WatchdogTiming {
                feed: Duration::from_millis(100),
                timeout: Duration::from_millis(250),
            },
        }
    }
}
