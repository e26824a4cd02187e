//! The speed side of the controller: takes orders, runs the link failsafe and the speed loop, and builds the
//! status the master reads.

use embassy_time::{Duration, Instant};
use tmc_proto::{
    Family, Faults, LegacyRevision, LegacyStatus, MaxPower, MotorKind, Order, SeaBotixStatus, Speed, Status,
};

use crate::drive::Duty;
use crate::failsafe::LinkFailsafe;
use crate::speed::{SpeedConfig, SpeedController};

/// What the I2C side last heard from the master, published after every valid order and every status read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct LinkUpdate {
    /// The last valid order.
    pub order: Order,
    /// Valid orders received since power-up (wrapping): a change means a new order arrived.
    pub orders: u32,
    /// Valid zero-speed orders received since power-up (wrapping): each one clears a stall, even when a newer
    /// non-zero order followed it before anyone looked.
    pub zero_orders: u32,
    /// When the master last addressed this controller (a valid order or a read).
    pub at: Instant,
}

/// What the fault side measured and decided, published after every sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Sensed {
    /// The faults to report.
    pub faults: Faults,
    /// Whether the motor may be driven.
    pub drive_allowed: bool,
    /// Motor current in 0.1 A.
    pub current_deciamps: u16,
    /// Motor (brushless) or controller (brushed) temperature in 0.1 deg C.
    pub temperature_decicelsius: i16,
}

impl Sensed {
    /// Before the first sample nothing is known, so nothing may be driven.
    pub const UNKNOWN: Sensed = Sensed {
        faults: Faults::NONE,
        drive_allowed: false,
        current_deciamps: 0,
        temperature_decicelsius: 0,
    };
}

/// The order-to-duty path of one controller.
#[derive(Debug, Clone)]
pub struct Control {
    family: Family,
    motor: MotorKind,
    speed: SpeedController,
    failsafe: LinkFailsafe,
    order: Order,
    orders_seen: u32,
    duty: Duty,
}

impl Control {
    /// A stopped controller whose link failsafe counts from `now`.
    pub fn new(family: Family, speed: SpeedConfig, link_timeout: Duration, now: Instant) -> Self {
        Self {
            family,
            motor: speed.motor,
            speed: SpeedController::new(speed),
            failsafe: LinkFailsafe::new(link_timeout, now),
            order: Order::STOP,
            orders_seen: 0,
            duty: Duty::ZERO,
        }
    }

    /// The order being followed: the last valid one, or stop after the failsafe tripped.
    pub fn order(&self) -> Order {
        self.order
    }

    /// How often the link failsafe has stopped the motor.
    pub fn failsafe_trips(&self) -> u32 {
        self.failsafe.trips()
    }

    /// One control step: take the link's news, apply the failsafe and the fault verdict, run the speed loop.
    pub fn tick(&mut self, now: Instant, link: Option<LinkUpdate>, sensed: Sensed, rpm: i32) -> Duty {
        if let Some(update) = link {
            self.failsafe.on_life(update.at);
            if update.orders != self.orders_seen {
                self.orders_seen = update.orders;
                self.order = update.order;
            }
        }
        let trips = self.failsafe.trips();
        if self.failsafe.check(now) {
            if self.failsafe.trips() != trips {
                warn!("link lost: no transfer for the failsafe timeout, stopping");
            }
            // Only a new order restarts the motor, not a read carrying the old one.
            self.order = Order::STOP;
        }
        self.duty = if sensed.drive_allowed && !self.failsafe.expired(now) {
            self.speed
                .update(now, self.order.speed, self.order.power_cap_percent(), rpm)
        } else {
            self.speed.reset();
            Duty::ZERO
        };
        self.duty
    }

    /// The status to answer the next read with.
    pub fn status(&self, sensed: Sensed, rpm: i32) -> Status {
        // Brushed controllers report the PWM value in the SPEED encoding (IDS 8.4.2), brushless the measured speed.
        let speed = match self.motor {
            MotorKind::Brushless => Speed::from_rpm(rpm),
            MotorKind::Brushed => duty_as_speed(self.duty),
        };
        status_of(self.family, self.motor, sensed, speed)
    }
}

/// The status of a stopped controller that has measured nothing yet.
pub fn idle_status(family: Family, motor: MotorKind) -> Status {
    status_of(family, motor, Sensed::UNKNOWN, Speed::ZERO)
}

fn status_of(family: Family, motor: MotorKind, sensed: Sensed, speed: Speed) -> Status {
    let current = u8::try_from(sensed.current_deciamps).unwrap_or(u8::MAX);
    match family {
        Family::SeaBotix => Status::SeaBotix(SeaBotixStatus {
            revision: 0,
            motor,
            current_limited: true,
            faults: sensed.faults,
            current_deciamps: current,
            speed,
            temperature_c: celsius_byte(sensed.temperature_decicelsius),
        }),
        Family::Legacy => Status::Legacy(match motor {
            MotorKind::Brushless => LegacyStatus {
                revision: LegacyRevision::AVEOX_BRUSHLESS,
                faults: sensed.faults,
                max_power: MaxPower::Current { deciamps: current },
            },
            // Brushed: MAX POWER is the power set into the motor, in the SPEED encoding (IDS 8.4.1).
            MotorKind::Brushed => LegacyStatus {
                revision: LegacyRevision::BRUSHED_REV4,
                faults: sensed.faults,
                max_power: MaxPower::Power(speed),
            },
        }),
    }
}

/// A duty as the SPEED step it corresponds to (100 % = step 102).
fn duty_as_speed(duty: Duty) -> Speed {
    Speed::new_saturating(i32::from(duty.value()) * i32::from(Speed::MAX_STEP) / i32::from(Duty::FULL))
}

/// 0.1 deg C to the status's unsigned whole degrees.
fn celsius_byte(decicelsius: i16) -> u8 {
    u8::try_from(decicelsius.max(0) / 10).unwrap_or(u8::MAX)
}
