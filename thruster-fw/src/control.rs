//! The speed side of the controller: takes orders, runs the link failsafe and the speed loop, and builds the
//! status the master reads.

use embassy_time::{Duration, Instant};
use tmc_proto::{
    Family, Faults, LegacyRevision, LegacyStatus, MaxPower, MotorKind, Order, SeaBotixStatus, Speed, Status,
};

use crate::drive::Duty;
use crate::failsafe::LinkFailsafe;
use crate::speed::{CurrentLimit, PowerLimit, SpeedConfig, SpeedController, step_of_brushed_duty};

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
    pub(crate) zero_orders: u32,
    /// When the master last addressed this controller (a valid order or a read).
    pub(crate) at: Instant,
    /// The first order refused (checksum, length, type, range) since the last valid one, if any was: the link
    /// failsafe stops the motor when no valid order follows it within its timeout, whatever reads come.
    pub(crate) refused_since: Option<Instant>,
}

/// What the fault side measured and decided, published after every sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Sensed {
    /// The faults to report.
    pub faults: Faults,
    /// Whether the motor may be driven.
    pub(crate) drive_allowed: bool,
    /// Motor current in 0.1 A.
    pub current_deciamps: u16,
    /// Motor (brushless) or controller (brushed) temperature in 0.1 deg C.
    pub(crate) temperature_decicelsius: i16,
    /// A sustained overcurrent holds the bridge off, its outputs disabled, until a zero order
    /// ([`crate::overcurrent::TripRule`]).
    pub overcurrent: bool,
    /// Samples that saw a break trip since start-up (cycle-by-cycle limiting included).
    pub break_trips: u32,
}

impl Sensed {
    /// Before the first sample nothing is known, so nothing may be driven.
    pub(crate) const UNKNOWN: Sensed = Sensed {
        faults: Faults::NONE,
        drive_allowed: false,
        current_deciamps: 0,
        temperature_decicelsius: 0,
        overcurrent: false,
        break_trips: 0,
    };
}

/// The order-to-duty path of one controller.
#[derive(Debug, Clone)]
pub(crate) struct Control {
    family: Family,
    motor: MotorKind,
    speed: SpeedController,
    power: PowerLimit,
    current_limit: CurrentLimit,
    /// `Sensed::break_trips` at the last step.
    break_trips_seen: u32,
    failsafe: LinkFailsafe,
    order: Order,
    orders_seen: u32,
    duty: Duty,
    /// The failsafe stopped the motor and no new order has come since.
    holding: bool,
}

impl Control {
    /// A stopped controller whose link failsafe counts from `now`.
    pub(crate) fn new(family: Family, speed: SpeedConfig, link_timeout: Duration, now: Instant) -> Self {
        Self {
            family,
            motor: speed.motor,
            speed: SpeedController::new(speed),
            power: PowerLimit::new(),
            current_limit: CurrentLimit::new(),
            break_trips_seen: 0,
            failsafe: LinkFailsafe::new(link_timeout, now),
            order: Order::STOP,
            orders_seen: 0,
            duty: Duty::ZERO,
            holding: false,
        }
    }

    /// The order being followed: the last valid one, or stop after the failsafe tripped.
    #[cfg(test)]
    pub(crate) fn order(&self) -> Order {
        self.order
    }

    /// How often the link failsafe has stopped the motor.
    pub(crate) fn failsafe_trips(&self) -> u32 {
        self.failsafe.trips()
    }

    /// Whether the link failsafe holds the motor stopped: from its trip until the next valid order (a read
    /// alone does not end it). SeaBotix builds report it in FAULT bit 5 (`SeaBotixStatus::FAULT_LINK_FAILSAFE`).
    pub(crate) fn failsafe_holding(&self) -> bool {
        self.holding
    }

    /// One control step: take the link's news, apply the failsafe and the fault verdict, run the speed loop.
    pub(crate) fn tick(&mut self, now: Instant, link: Option<LinkUpdate>, sensed: Sensed, rpm: i32) -> Duty {
        if let Some(update) = link {
            self.failsafe.on_life(update.at, update.refused_since);
            if update.orders != self.orders_seen {
                self.orders_seen = update.orders;
                self.order = update.order;
                self.holding = false;
            }
        }
        let trips = self.failsafe.trips();
        if self.failsafe.check(now) {
            if self.failsafe.trips() != trips {
                warn!(
                    "link failsafe: no transfer, or refused orders only, for its timeout: stopping ({} trips so far)",
                    self.failsafe.trips()
                );
            }
            self.holding = true;
            // Only a new order restarts the motor, not a read carrying the old one.
            self.order = Order::STOP;
        }
        // INFO limits the power drawn, and the current limit the current, both measured with the duty of the last
        // step (the one the current flowed at).
        let power_ceiling = self
            .power
            .update(now, self.order.power_cap_percent(), self.duty, sensed.current_deciamps);
        let tripped = sensed.break_trips != self.break_trips_seen;
        self.break_trips_seen = sensed.break_trips;
        let current_ceiling = self.current_limit.update(
            self.speed.config().current_limit_deciamps,
            self.duty,
            sensed.current_deciamps,
            tripped,
        );
        let ceiling = power_ceiling.min(current_ceiling);
        self.duty = if sensed.drive_allowed && !self.failsafe.expired(now) {
            self.speed.update_within(now, self.order.speed, ceiling, rpm)
        } else {
            self.speed.reset();
            Duty::ZERO
        };
        self.duty
    }

    /// The status to answer the next read with.
    pub(crate) fn status(&self, sensed: Sensed, rpm: i32) -> Status {
        // Brushed controllers report the PWM value in the SPEED encoding (IDS 8.4.2), brushless the measured speed.
        let speed = match self.motor {
            MotorKind::Brushless => Speed::from_rpm(rpm),
            // Rounded as the order was turned into the duty, so the order reads back at steady state.
            MotorKind::Brushed => step_of_brushed_duty(self.duty, self.speed.config().max_duty),
        };
        status_of(self.family, self.motor, sensed, speed)
    }
}

/// The status of a stopped controller that has measured nothing yet.
pub(crate) fn idle_status(family: Family, motor: MotorKind) -> Status {
    status_of(family, motor, Sensed::UNKNOWN, Speed::ZERO)
}

fn status_of(family: Family, motor: MotorKind, sensed: Sensed, speed: Speed) -> Status {
    let current = u8::try_from(sensed.current_deciamps).unwrap_or(u8::MAX);
    match family {
        Family::SeaBotix => Status::SeaBotix(SeaBotixStatus {
            // 0 is the original brushless software (IDS 8.4.2); a brushed build reports the IDS's brushed
            // revision number instead (`SeaBotixStatus::REVISION_BRUSHED`).
            revision: match motor {
                MotorKind::Brushless => 0,
                MotorKind::Brushed => SeaBotixStatus::REVISION_BRUSHED,
            },
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

/// 0.1 deg C to the status's unsigned whole degrees.
fn celsius_byte(decicelsius: i16) -> u8 {
    u8::try_from(decicelsius.max(0) / 10).unwrap_or(u8::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use tmc_proto::Decoded;

    const TIMEOUT: Duration = Duration::from_secs(1);
    const HEALTHY: Sensed = Sensed {
        faults: Faults::NONE,
        drive_allowed: true,
        current_deciamps: 0,
        temperature_decicelsius: 250,
        ..Sensed::UNKNOWN
    };

    fn ms(value: u64) -> Instant {
        Instant::from_millis(value)
    }

    fn update(step: i8, orders: u32, at: Instant) -> Option<LinkUpdate> {
        let order = Order::new(Speed::new(step).unwrap());
        Some(LinkUpdate {
            order,
            orders,
            zero_orders: 0,
            at,
            refused_since: None,
        })
    }

    fn brushless(family: Family) -> Control {
        Control::new(family, SpeedConfig::BRUSHLESS_DEFAULT, TIMEOUT, ms(0))
    }

    #[test]
    fn follows_a_new_order_and_only_a_new_one() {
        let mut control = brushless(Family::SeaBotix);
        // The ramp starts from zero at the first step.
        assert_eq!(control.tick(ms(1), update(40, 1, ms(1)), HEALTHY, 0), Duty::ZERO);
        assert!(control.tick(ms(2), update(40, 1, ms(1)), HEALTHY, 0).value() > 0);
        assert_eq!(control.order().speed.step(), 40);
        // The same count again (a read) leaves the order alone even if it carried another speed.
        control.tick(ms(3), update(-40, 1, ms(3)), HEALTHY, 0);
        assert_eq!(control.order().speed.step(), 40);
    }

    #[test]
    fn a_fault_verdict_stops_at_once_and_the_order_resumes_after_it() {
        let mut control = brushless(Family::SeaBotix);
        let link = update(60, 1, ms(1));
        for t in 1..100 {
            control.tick(ms(t), link, HEALTHY, 1000);
        }
        let stopped = Sensed {
            faults: Faults::OVERTEMP,
            drive_allowed: false,
            ..HEALTHY
        };
        assert_eq!(control.tick(ms(100), link, stopped, 1000), Duty::ZERO);
        // Overtemp clears: the order still stands and the ramp starts again from zero.
        assert_eq!(control.tick(ms(101), link, HEALTHY, 0), Duty::ZERO);
        let duty = control.tick(ms(102), link, HEALTHY, 0);
        assert!(
            duty.value() > 0 && duty.value() < 1500,
            "restarts from the ramp's start: {duty:?}"
        );
    }

    #[test]
    fn the_failsafe_trips_at_the_timeout_and_a_new_order_resumes() {
        let mut control = brushless(Family::Legacy);
        let link = update(50, 1, ms(10));
        control.tick(ms(10), link, HEALTHY, 0);
        assert!(control.tick(ms(11), link, HEALTHY, 0).value() > 0);
        assert!(
            control.tick(ms(1009), link, HEALTHY, 0).value() > 0,
            "999 ms after the last life"
        );
        assert_eq!(control.tick(ms(1010), link, HEALTHY, 0), Duty::ZERO, "1000 ms");
        assert_eq!(control.failsafe_trips(), 1);
        assert_eq!(control.order(), Order::STOP);
        // A read (same order count, new time) is life but not an order.
        assert_eq!(control.tick(ms(1500), update(50, 1, ms(1500)), HEALTHY, 0), Duty::ZERO);
        control.tick(ms(1501), update(50, 2, ms(1501)), HEALTHY, 0);
        assert!(control.tick(ms(1502), update(50, 2, ms(1501)), HEALTHY, 0).value() > 0);
        assert_eq!(control.failsafe_trips(), 1);
    }

    /// The supply power of a propeller-loaded motor at `duty` and `rpm` (the reference motor's figures: 24 V,
    /// 1.2 ohm, 19.2 V of back-EMF at 5000 rpm), and the motor current it draws in 0.1 A.
    fn motor_current(duty: Duty, rpm: f64) -> u16 {
        let back_emf = 19.2 * rpm / 5000.0;
        let amps = ((f64::from(duty.magnitude()) / 10_000.0 * 24.0 - back_emf) / 1.2).max(0.0);
        (amps * 10.0).round() as u16
    }

    #[test]
    fn the_info_byte_limits_the_power_drawn_not_the_duty() {
        for (info, cap_w) in [(50u8, 48.0), (25, 24.0)] {
            let mut control = brushless(Family::SeaBotix);
            let order = Order {
                speed: Speed::MAX_FORWARD,
                info,
            };
            let link = Some(LinkUpdate {
                order,
                orders: 1,
                zero_orders: 0,
                at: ms(0),
                refused_since: None,
            });
            // A first-order motor with a propeller: steady speed ~ 5000 rpm x duty, 50 ms time constant.
            let (mut rpm, mut duty) = (0.0f64, Duty::ZERO);
            let mut power = 0.0;
            for t in 0..3000 {
                let current = motor_current(duty, rpm);
                let sensed = Sensed {
                    current_deciamps: current,
                    ..HEALTHY
                };
                let link = link.map(|update| LinkUpdate { at: ms(t), ..update });
                duty = control.tick(ms(t), link, sensed, rpm.round() as i32);
                power = f64::from(duty.magnitude()) / 10_000.0 * f64::from(current) / 10.0 * 24.0;
                let steady = 5000.0 * f64::from(duty.value()) / 10_000.0;
                rpm += (steady - rpm) * 0.001 / 0.05;
            }
            assert!(
                (power - cap_w).abs() < cap_w * 0.05,
                "INFO {info}: {power:.1} W against {cap_w} W, duty {duty:?}"
            );
            // Far more than INFO % of the duty, which gave about 15 % of full power at INFO 50.
            assert!(
                duty.magnitude() > u16::from(info) * 100 + 1000,
                "INFO {info}: duty {duty:?}"
            );
        }
    }

    /// Drive the reference motor model from rest at full order with `info` for `steps` ms; the power drawn after
    /// each step (W).
    fn power_trace(info: u8, steps: u64) -> Vec<f64> {
        let mut control = brushless(Family::SeaBotix);
        let (mut rpm, mut duty) = (0.0f64, Duty::ZERO);
        (0..steps)
            .map(|t| {
                let order = Order {
                    speed: Speed::MAX_FORWARD,
                    info,
                };
                let link = Some(LinkUpdate {
                    order,
                    orders: 1,
                    zero_orders: 0,
                    at: ms(t),
                    refused_since: None,
                });
                let current = motor_current(duty, rpm);
                let sensed = Sensed {
                    current_deciamps: current,
                    ..HEALTHY
                };
                duty = control.tick(ms(t), link, sensed, rpm.round() as i32);
                rpm += (5000.0 * f64::from(duty.value()) / 10_000.0 - rpm) * 0.001 / 0.05;
                // The power drawn, from the model's current before the sensor rounds it to 0.1 A.
                let d = f64::from(duty.magnitude()) / 10_000.0;
                d * 24.0 * ((d * 24.0 - 19.2 * rpm / 5000.0) / 1.2).max(0.0)
            })
            .collect()
    }

    /// The peak of the power averaged over 10 ms (W, as a power meter shows it: the 0.1 A the current is measured
    /// in is 15 % of INFO 10's power at half duty), the time (ms) from the power first exceeding the cap until
    /// that average last stands more than 10 % above it, and whether it then swings more than 15 % below (an
    /// oscillation).
    fn hold(powers: &[f64], cap_w: f64) -> (f64, usize, bool) {
        let mean: Vec<f64> = powers.windows(10).map(|w| w.iter().sum::<f64>() / 10.0).collect();
        let peak = mean.iter().copied().fold(0.0, f64::max);
        let first = powers.iter().position(|p| *p > cap_w).unwrap_or(powers.len());
        let last_high = mean
            .iter()
            .rposition(|p| *p > cap_w * 1.1)
            .map_or(first, |last| last + 10);
        let settled = last_high.max(first);
        let swings = mean
            .get(settled..)
            .unwrap_or_default()
            .iter()
            .any(|p| *p < cap_w * 0.85);
        (peak, settled.saturating_sub(first), swings)
    }

    #[test]
    fn the_power_limit_holds_within_50_ms_from_a_standing_start() {
        for info in [10u8, 25, 50] {
            let cap_w = 96.0 * f64::from(info) / 100.0;
            let (peak, took, swings) = hold(&power_trace(info, 3000), cap_w);
            println!("INFO {info} from rest: peak {peak:.1} W against {cap_w:.1} W, over 10 % for {took} ms");
            assert!(
                took <= 50 && !swings,
                "INFO {info} from rest: more than 10 % over {cap_w} W for {took} ms, peak {peak:.1} W, swings {swings}"
            );
        }
        // A change of INFO at full speed is judged on the bench (`info-power-response`): this model has no
        // propeller and no braking current, which is what that case turns on.
    }

    #[test]
    fn info_100_and_no_info_do_not_limit() {
        for info in [0u8, 100, 101, 255] {
            let mut control = brushless(Family::SeaBotix);
            let link = Some(LinkUpdate {
                order: Order {
                    speed: Speed::MAX_FORWARD,
                    info,
                },
                orders: 1,
                zero_orders: 0,
                at: ms(0),
                refused_since: None,
            });
            // A locked rotor's current: the limit never bites.
            let sensed = Sensed {
                current_deciamps: 200,
                ..HEALTHY
            };
            let mut highest = 0;
            for t in 0..900 {
                highest = highest.max(control.tick(ms(t), link, sensed, 0).value());
            }
            assert_eq!(highest, i16::try_from(crate::speed::MAX_DUTY).unwrap(), "INFO {info}");
        }
    }

    #[test]
    fn the_power_limit_holds_a_brushed_motor_too() {
        let mut control = Control::new(Family::Legacy, SpeedConfig::BRUSHED_DEFAULT, TIMEOUT, ms(0));
        let link = Some(LinkUpdate {
            order: Order {
                speed: Speed::MAX_FORWARD,
                info: 50,
            },
            orders: 1,
            zero_orders: 0,
            at: ms(0),
            refused_since: None,
        });
        let (mut rpm, mut duty, mut power) = (0.0f64, Duty::ZERO, 0.0);
        for t in 0..3000 {
            let current = motor_current(duty, rpm);
            let sensed = Sensed {
                current_deciamps: current,
                ..HEALTHY
            };
            let link = link.map(|update| LinkUpdate { at: ms(t), ..update });
            duty = control.tick(ms(t), link, sensed, 0);
            power = f64::from(duty.magnitude()) / 10_000.0 * f64::from(current) / 10.0 * 24.0;
            rpm += (5000.0 * f64::from(duty.value()) / 10_000.0 - rpm) * 0.001 / 0.05;
        }
        assert!((power - 48.0).abs() < 2.4, "{power:.1} W, duty {duty:?}");
    }

    #[test]
    fn status_fields_for_each_family_and_motor() {
        let sensed = Sensed {
            faults: Faults::WATER,
            drive_allowed: true,
            current_deciamps: 42,
            temperature_decicelsius: 567,
            ..Sensed::UNKNOWN
        };
        let Status::SeaBotix(status) = brushless(Family::SeaBotix).status(sensed, 2250) else {
            panic!()
        };
        assert_eq!(
            status,
            SeaBotixStatus {
                revision: 0,
                motor: MotorKind::Brushless,
                current_limited: true,
                faults: Faults::WATER,
                current_deciamps: 42,
                speed: Speed::new(51).unwrap(),
                temperature_c: 56,
            }
        );
        let Status::Legacy(status) = brushless(Family::Legacy).status(sensed, 0) else {
            panic!()
        };
        assert_eq!(status.revision, LegacyRevision::AVEOX_BRUSHLESS);
        assert_eq!(status.max_power, MaxPower::Current { deciamps: 42 });

        // Brushed: the power set into the motor, in the SPEED encoding.
        let mut brushed = Control::new(Family::Legacy, SpeedConfig::BRUSHED_DEFAULT, TIMEOUT, ms(0));
        let link = update(51, 1, ms(0));
        for t in 0..1000 {
            brushed.tick(ms(t), link, HEALTHY, 0);
        }
        let Status::Legacy(status) = brushed.status(sensed, 0) else {
            panic!()
        };
        assert_eq!(status.revision, LegacyRevision::BRUSHED_REV4);
        assert_eq!(status.max_power, MaxPower::Power(Speed::new(51).unwrap()));
    }

    #[test]
    fn a_brushed_order_reads_back_at_steady_state_for_every_step() {
        for max_duty in [crate::speed::MAX_DUTY, 9_500, Duty::FULL as u16, 1_000, 103] {
            let config = SpeedConfig {
                max_duty,
                ..SpeedConfig::BRUSHED_DEFAULT
            };
            for family in Family::ALL {
                for step in -102..=102i8 {
                    let mut brushed = Control::new(family, config, TIMEOUT, ms(0));
                    let link = update(step, 1, ms(0));
                    // 0.5 s of ramp reaches any step.
                    for t in 0..600 {
                        brushed.tick(ms(t), link, HEALTHY, 0);
                    }
                    let read = match brushed.status(HEALTHY, 0) {
                        Status::SeaBotix(status) => status.speed,
                        Status::Legacy(LegacyStatus {
                            max_power: MaxPower::Power(speed),
                            ..
                        }) => speed,
                        other => panic!("{other:?}"),
                    };
                    assert_eq!(read.step(), step, "max duty {max_duty}, {family:?}");
                }
            }
        }
    }

    #[test]
    fn out_of_range_readings_saturate_in_the_status() {
        let sensed = Sensed {
            current_deciamps: 9999,
            temperature_decicelsius: -400,
            ..HEALTHY
        };
        let Status::SeaBotix(status) = brushless(Family::SeaBotix).status(sensed, i32::MAX) else {
            panic!()
        };
        assert_eq!(
            (status.current_deciamps, status.temperature_c, status.speed),
            (255, 0, Speed::MAX_FORWARD)
        );
        let hot = Sensed {
            temperature_decicelsius: i16::MAX,
            ..HEALTHY
        };
        let Status::SeaBotix(status) = brushless(Family::SeaBotix).status(hot, i32::MIN) else {
            panic!()
        };
        assert_eq!((status.temperature_c, status.speed), (255, Speed::MAX_REVERSE));
    }

    proptest! {
        #[test]
        fn every_status_decodes_with_tmc_proto(
            family in prop::sample::select(&Family::ALL[..]),
            faults in any::<u8>(),
            current in any::<u16>(),
            temperature in any::<i16>(),
            rpm in any::<i32>(),
        ) {
            let sensed = Sensed {
                faults: Faults::from_bits_truncate(faults),
                drive_allowed: false,
                current_deciamps: current,
                temperature_decicelsius: temperature,
                ..Sensed::UNKNOWN
            };
            for control in [brushless(family), Control::new(family, SpeedConfig::BRUSHED_DEFAULT, TIMEOUT, ms(0))] {
                let status = control.status(sensed, rpm);
                prop_assert_eq!(Status::decode(family, status.encode().as_bytes()), Ok(Decoded::clean(status)));
                prop_assert_eq!(status.faults(), sensed.faults);
            }
        }
    }
}
