//! The controller's task bodies and [`run`], which joins them: each task owns its state machines and talks to the
//! others only through [`Shared`]. The tasks drive the ports of [`crate::ports`]. The STM32 binding, the bench and
//! the host tests all run the controller through [`run`] and [`run_commutation`].

use core::cell::Cell;

use crash_record::What;
use embassy_futures::join::{join, join5};
use embassy_futures::select::select3;

use embassy_time::{Duration, Instant, Ticker, Timer, with_timeout};
use tmc_proto::{Family, MotorKind, SeaBotixStatus};

use crate::commutation::{BridgeDrive, COAST, PhaseDrive, drive_for};
use crate::config::{COMMUTATION_HEARTBEAT, Config, LISTEN_HEARTBEAT};
use crate::control::{Control, LinkUpdate, Sensed, idle_status};
use crate::drive::{Direction, Duty};
use crate::faults::{BrushedSample, CurrentStall, FaultMonitor, Progress, Sample, StallDetector};
use crate::hall::HallTracker;
use crate::i2c_slave::{Answer, MasterLink, ServeEvent, serve};
use crate::overcurrent::TripRule;
use crate::ports::{Board, Bridge, HallSensors, I2cTarget, LatchStore, Ports, Sensors, Watchdog};
use crate::shared::{Shared, TaskId};
use crate::trial::trial_task;
use crate::update::update_task;

/// Fault inputs are sampled at 1 kHz (IDS faults must be seen within one sample).
pub(crate) const SAMPLE_PERIOD: Duration = Duration::from_millis(1);
/// The speed loop runs at 1 kHz.
pub(crate) const CONTROL_PERIOD: Duration = Duration::from_millis(1);
/// The I2C slave: takes orders, answers reads with the frame the control task keeps ready, re-initialises the
/// peripheral after any error (including a transfer stalled past the peripheral's timeout). Extension commands go
/// to the update task, and the read after one gets its reply ([`crate::update`]) instead of the status.
pub(crate) async fn i2c_task<T: I2cTarget>(target: &mut T, family: Family, motor: MotorKind, shared: &Shared) -> ! {
    let mut link = MasterLink::new(family);
    // What the link failsafe counts from: the master's last valid order or read, and the first order refused since
    // the last valid one.
    let mut last_life = Instant::now();
    let mut refused_since: Option<Instant> = None;
    let idle = idle_status(family, motor).encode();
    loop {
        shared.health.report(TaskId::I2c as u8);
        // Only the wait for an address is cut short, never a transfer under way.
        let request = match with_timeout(LISTEN_HEARTBEAT, target.listen()).await {
            Err(_) => continue,
            Ok(Ok(request)) => request,
            Ok(Err(_)) => {
                warn!("I2C error while listening: re-initialising the slave");
                target.reset();
                continue;
            }
        };
        let carried = Cell::new(0);
        let reply = Cell::new(None);
        let answer = || match shared.replies.for_read() {
            Some(pending) => {
                reply.set(Some(pending));
                Answer::Reply(*pending.frame())
            }
            None => {
                carried.set(shared.take_unread());
                Answer::Status(shared.status.try_get().unwrap_or(idle).with_fault_bits(carried.get()))
            }
        };
        let served = serve(target, &mut link, request, answer).await;
        if !matches!(served, Ok(ServeEvent::StatusSent)) {
            // Not carried to the master: they wait for the next read.
            shared.note_unread(carried.get());
        }
        let now = Instant::now();
        let alive = match served {
            Ok(ServeEvent::Order(_)) => {
                refused_since = None;
                true
            }
            Ok(ServeEvent::StatusSent) => true,
            Ok(ServeEvent::Command(frame)) => {
                shared.replies.command(frame);
                true
            }
            Ok(ServeEvent::ReplySent) => {
                if let Some(sent) = reply.get() {
                    shared.replies.sent(&sent);
                }
                true
            }
            Ok(ServeEvent::Rejected(error)) => {
                warn!("order discarded: {} ({} so far)", error, link.errors().total());
                // Not life, but told to the failsafe: refused orders alone for its timeout stop the motor.
                refused_since.get_or_insert(now);
                false
            }
            Ok(ServeEvent::CommandRejected(_)) => {
                warn!("extension command discarded ({} so far)", link.command_errors().total());
                continue;
            }
            Err(_) => {
                warn!("I2C transfer failed: re-initialising the slave");
                target.reset();
                continue;
            }
        };
        if alive {
            last_life = now;
        }
        shared.link.sender().send(LinkUpdate {
            order: link.order(),
            orders: link.orders(),
            zero_orders: link.zero_orders(),
            at: last_life,
            refused_since,
        });
    }
}

/// Commutation: on every hall edge, and whenever the duty or the fault verdict changes, drive the bridge from
/// the hall state. Runs at the highest priority so that no other work delays a commutation. Coasts whenever
/// driving must stop: zero duty, a fault, or an invalid hall state. Nothing else wakes it but its heartbeat to the
/// watchdog ([`COMMUTATION_HEARTBEAT`]): the bridge is a function of the halls, the duty and the verdict, and the
/// tasks that change those two wake it when they do.
pub(crate) async fn commutation_task<H: HallSensors, B: Bridge>(
    halls: &mut H,
    bridge: &mut B,
    motor: MotorKind,
    pole_pairs: u8,
    shared: &Shared,
) -> ! {
    let mut tracker = HallTracker::new(pole_pairs, halls.read(), Instant::now());
    bridge.apply(COAST, Duty::ZERO);
    let mut held_off = false;
    loop {
        let state = halls.read();
        tracker.on_edge(state, Instant::now());
        shared.hall.sender().send(tracker);
        let sensed = shared.sensed.try_get();
        // A sustained overcurrent takes the outputs off in hardware, not only to a coasting pattern; the fault
        // task wakes this task when it changes.
        let overcurrent = sensed.is_some_and(|sensed| sensed.overcurrent);
        if overcurrent != held_off {
            held_off = overcurrent;
            bridge.hold_off(held_off);
        }
        let allowed = sensed.is_some_and(|sensed| sensed.drive_allowed);
        let duty = if allowed {
            shared.duty.try_get().unwrap_or(Duty::ZERO)
        } else {
            Duty::ZERO
        };
        let drive = match motor {
            MotorKind::Brushless => drive_for(state, duty),
            MotorKind::Brushed => h_bridge(duty),
        };
        bridge.apply(drive, duty);
        shared.health.report(TaskId::Commutation as u8);
        select3(
            halls.wait_for_edge(),
            shared.wake.wait(),
            Timer::after(COMMUTATION_HEARTBEAT),
        )
        .await;
    }
}

/// A brushed motor between phases A and B, as an H-bridge: A switched and B low forward, the reverse backward.
pub const fn h_bridge(duty: Duty) -> BridgeDrive {
    match duty.direction() {
        Some(Direction::Forward) => [PhaseDrive::Pwm, PhaseDrive::Low, PhaseDrive::Float],
        Some(Direction::Reverse) => [PhaseDrive::Low, PhaseDrive::Pwm, PhaseDrive::Float],
        None => COAST,
    }
}

/// Faults: sample the ADC and the break flag at 1 kHz, follow the hall pulses and errors, apply the fault table
/// and the overcurrent trip rule, publish the verdict, and wake the commutation task at once when the verdict
/// changes. The power-cycle latches come from `latch` at start and go back to it whenever they change, so they
/// outlast any reset but a power cycle.
pub(crate) async fn fault_task<S: Sensors, L: LatchStore>(
    sensors: &mut S,
    latch: &mut L,
    config: &Config,
    shared: &Shared,
) -> ! {
    let mut monitor = FaultMonitor::new(config.family, config.thresholds);
    monitor.restore(latch.load());
    let mut saved = monitor.latched();
    let mut stall = StallDetector::new(&config.thresholds);
    let mut current_stall = CurrentStall::new(&config.thresholds);
    let mut progress = Progress::new();
    let mut breaks = TripRule::new(config.thresholds.overcurrent);
    let mut seen_illegal = None;
    let mut seen_zero_orders = 0;
    let mut allowed = false;
    let mut ticker = Ticker::every(SAMPLE_PERIOD);
    let mut first = true;
    loop {
        let raw = sensors.sample().await;
        let now = Instant::now();
        if core::mem::take(&mut first) {
            // The first power-up checks the divider against the bench supply, and the current stages' offsets with
            // the outputs off (docs/hardware.md, steps 3 and 6).
            info!("VBUS {} mV ({} counts)", config.vbus.millivolts(raw.vbus), raw.vbus);
            let [a, b, c] = raw.currents;
            info!("current stages at rest: {} {} {} counts", a, b, c);
        }
        let was_overcurrent = breaks.latched();

        if let Some(link) = shared.link.try_get()
            && link.zero_orders != seen_zero_orders
        {
            seen_zero_orders = link.zero_orders;
            monitor.on_order(tmc_proto::Speed::ZERO);
            stall.reset();
            current_stall.reset();
            progress = Progress::new();
            breaks.on_zero_order();
        }
        let overcurrent = breaks.tick(raw.break_tripped);
        if overcurrent && !was_overcurrent {
            warn!(
                "overcurrent: the break tripped on {} samples so far, outputs off until a zero order",
                breaks.trips()
            );
        }

        let duty = shared.duty.try_get().unwrap_or(Duty::ZERO);
        let current_deciamps = config.current.motor_deciamps(raw.currents);
        let mut halls_normal = true;
        let mut stalled = false;
        match config.motor {
            MotorKind::Brushless => {
                if let Some(hall) = shared.hall.try_get() {
                    // Each hall state gained in the driven direction is a pulse for the stall window (edges back
                    // and forth over one boundary are not); a few are enough to know the motor turns.
                    let new_pulses = progress.advance(hall.position(), duty.direction());
                    for _ in 0..new_pulses.min(u32::from(config.thresholds.stall_min_pulses)) {
                        stall.on_pulse(now);
                    }
                    let illegal = hall.illegal_transitions();
                    halls_normal = hall.state().is_valid() && seen_illegal.is_none_or(|seen| seen == illegal);
                    seen_illegal = Some(illegal);
                    stalled = stall.update(now, duty);
                }
            }
            MotorKind::Brushed => {
                let sample = BrushedSample {
                    duty,
                    current_deciamps,
                    vbus_mv: config.vbus.millivolts(raw.vbus),
                    break_tripped: raw.break_tripped,
                };
                stalled = current_stall.update(now, sample);
            }
        }

        let sample = Sample {
            water_ohms: config.water.resistance_ohms(raw.water),
            temperature_decicelsius: config.ntc.decicelsius(raw.temperature),
            halls_normal,
        };
        let faults = monitor.update(sample, stalled);
        let mut fault_bits = faults.bits();
        // SeaBotix FAULT bit 6 (this project's): the Legacy STATUS byte has no spare bit
        // (docs/thruster.md, "Sustained overcurrent").
        if config.family == Family::SeaBotix && overcurrent {
            fault_bits |= SeaBotixStatus::FAULT_OVERCURRENT;
        }
        shared.note_unread(fault_bits);
        if monitor.latched() != saved {
            saved = monitor.latched();
            latch.save(saved);
        }
        let sensed = Sensed {
            faults,
            drive_allowed: monitor.drive_allowed() && !overcurrent,
            current_deciamps,
            temperature_decicelsius: sample.temperature_decicelsius,
            overcurrent,
            break_trips: breaks.trips(),
        };
        shared.sensed.sender().send(sensed);
        if sensed.drive_allowed != allowed || overcurrent != was_overcurrent {
            if sensed.drive_allowed != allowed && !sensed.drive_allowed {
                warn!("fault: stopping the motor ({})", fault_bits);
                shared.note(What::FaultLatched(fault_bits.into()));
            }
            allowed = sensed.drive_allowed;
            shared.wake.signal(());
        }
        shared.health.report(TaskId::Faults as u8);
        ticker.next().await;
    }
}

/// Speed control at 1 kHz: orders and the link failsafe in, duty out to the commutation task (woken when the duty
/// changes), and the status frame kept ready for the I2C task.
pub(crate) async fn control_task(config: &Config, shared: &Shared) -> ! {
    let mut control = Control::new(config.family, config.speed, config.link_timeout, Instant::now());
    let mut ticker = Ticker::every(CONTROL_PERIOD);
    let mut sent = None;
    loop {
        let now = Instant::now();
        let rpm = shared.hall.try_get().map_or(0, |hall| hall.rpm(now));
        let sensed = shared.sensed.try_get().unwrap_or(Sensed::UNKNOWN);
        let trips = control.failsafe_trips();
        let duty = control.tick(now, shared.link.try_get(), sensed, rpm);
        if control.failsafe_trips() != trips {
            shared.note(What::OrdersLost);
        }
        // SeaBotix FAULT bit 5: the failsafe holds the motor stopped (the Legacy STATUS byte has no spare bit).
        if config.family == Family::SeaBotix && control.failsafe_holding() {
            shared.note_unread(SeaBotixStatus::FAULT_LINK_FAILSAFE);
        }
        if sent != Some(duty) {
            sent = Some(duty);
            shared.duty.sender().send(duty);
            shared.wake.signal(());
        }
        shared.status.sender().send(control.status(sensed, rpm).encode());
        shared.health.report(TaskId::Control as u8);
        ticker.next().await;
    }
}

/// Feed the watchdog every `period`, but only while every task keeps reporting progress.
pub(crate) async fn health_task<W: Watchdog>(watchdog: &mut W, period: Duration, shared: &Shared) -> ! {
    let mut ticker = Ticker::every(period);
    loop {
        ticker.next().await;
        if shared.health.check_and_clear() {
            watchdog.feed();
        } else {
            warn!(
                "tasks not reporting (mask {=u32:#x}): the watchdog will reset",
                shared.health.missing()
            );
        }
    }
}

/// The controller's thread-mode tasks, joined: the I2C slave, faults, speed control, health, a new image's trial
/// and the field update's receiver. Commutation runs apart ([`run_commutation`]), on an executor of its own above
/// these. They talk only through `shared`, which lives as long as the controller: a reset starts again from a
/// fresh one.
pub async fn run<B: Board>(ports: Ports<B>, config: &Config, shared: &Shared) -> ! {
    let Ports {
        mut i2c,
        mut sensors,
        mut watchdog,
        mut latch,
        mut boot,
        mut dfu,
        mut updater,
    } = ports;
    let ((never, ..), _) = join(
        join5(
            i2c_task(&mut i2c, config.family, config.motor, shared),
            fault_task(&mut sensors, &mut latch, config, shared),
            control_task(config, shared),
            health_task(&mut watchdog, config.watchdog.feed, shared),
            trial_task(&mut boot, shared),
        ),
        update_task(&mut dfu, &mut updater, config.family, shared),
    )
    .await;
    never
}

/// Commutation: the halls drive the bridge (see [`commutation_task`]). It runs on the highest-priority executor so
/// that no other work delays a commutation.
pub async fn run_commutation<H: HallSensors, B: Bridge>(
    mut halls: H,
    mut bridge: B,
    config: &Config,
    shared: &Shared,
) -> ! {
    commutation_task(&mut halls, &mut bridge, config.motor, config.pole_pairs, shared).await
}

#[cfg(test)]
mod tests;
