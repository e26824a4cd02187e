//! The acceptance test of the thruster(s) wired to the master on the bench: one fixed script, run by the master
//! image built with feature `acceptance` and by the virtual bench's `acceptance` scenario.
//!
//! The script writes raw bytes on the bus itself (it must send orders that `poll_thruster` would never build) and
//! judges each step from the status frames the thruster answers with:
//!
//! | step | what it does | passes when |
//! |---|---|---|
//! | `discovery` | reads a status at 0x29 (SeaBotix) and 0x2A (Legacy) | at least one answers with a valid status (the expected family, when one is set); every one that answers is tested in turn |
//! | `speed-forward`, `speed-reverse` | orders every step 1..=102 (then -1..=-102), one after the other | each step's status *follows* it within `settle`, and no fault is reported |
//! | `bad-checksum` | holds a stop, then the drive step, sending for [`BAD_ORDERS_FOR`] each time a stop and the opposite drive step with their checksums off by one | every status still shows the order held |
//! | `out-of-range` | the same with SPEED bytes 0x00, 0x18, 0xE7, 0xFF and good checksums | every status still shows the order held |
//! | `failsafe` | holds a valid order, then leaves the bus silent for `silence` (1.5 s) and only reads after it | the first read shows the drive off, the speed reaches 0 within `coast`, stays there while only reads come, and the same order sent again drives |
//! | `held-rotor` | prompts the operator to hold the rotor, orders the drive step | STALL within `fault_within` and the drive off; after the release a zero order clears it and the drive step drives again |
//! | `water` | prompts the operator to fit the test resistor on the water sensor | WATER within `fault_within`; SeaBotix keeps driving and clears the bit once the resistor is removed, Legacy stops and keeps the bit latched |
//! | `reset` | prompts the operator to power-cycle the thruster board while polling back to back | a failure is seen (NACK, timeout, bus error or a torn frame), the recoveries free the bus, `recovered_polls` good polls follow, and the thruster drives again without fault (a latched Legacy water fault is gone) |
//!
//! What *follows* an order means per family (IDS 8.4.1, 8.4.2):
//! - SeaBotix: the status's SPEED (measured speed for brushless, PWM for brushed) is within `tolerance` steps of
//!   the order.
//! - Legacy brushed (revisions 2 and 4): MAX POWER, the power set into the motor in the SPEED encoding, likewise.
//! - Legacy brushless (Aveox, revision 1) reports no speed, only the motor current in MAX POWER: at a zero order the
//!   current must read 0; at `drive_step` and beyond it must read at least `min_current_deciamps`; in between any
//!   valid status will do.
//!
//! The drive is *off* when the reported current is 0 (for Legacy brushed, which reports none: when MAX POWER is 0);
//! the thruster is *at rest* when the drive is off and any reported speed is 0.
//!
//! What the script reports, and the formats it reports in, are [`report`]'s.

use embassy_time::{Duration, Instant, Timer};
use embedded_hal_async::i2c::I2c;
use tmc_proto::{Decoded, Family, Faults, MAX_STATUS_LEN, MaxPower, ORDER_LEN, Order, Speed, Status, checksum};

use crate::ports::BusRecovery;
use crate::shared::{BUSES, Shared};
use crate::thrusters::PollFailure;

pub mod report;

use report::{Prompt, Step, StepResult, Verdict, family_token, prompt_text, step_text, verdict_text};

/// The person at the bench (or the virtual bench acting for one), who is also told how the script goes. The
/// console hears every prompt, step and verdict anyway ([`Script`]); these are for the report's other readers.
#[allow(async_fn_in_trait)]
pub trait Operator {
    /// Ask for `what` on the thruster of `family`. Return once it is done; for a prompt that is
    /// [`Prompt::during_traffic`], once the operator has been told and is about to act.
    async fn prompt(&mut self, what: Prompt, family: Family);
    /// The script starts.
    fn started(&mut self) {}
    /// A step ended.
    fn reported(&mut self, result: &StepResult) {
        let _ = result;
    }
    /// The script ended.
    fn concluded(&mut self, verdict: &Verdict) {
        let _ = verdict;
    }
}

/// The acceptance image's work on the thruster buses (its [`BusWork`](crate::ports::BusWork) impl is in the crate
/// root, which hands it `config.acceptance`): `setup.start` after boot, the script on the dev kit's bus, with every
/// prompt, step and verdict said on the console as well as told to the operator; the other buses stay idle.
#[derive(Debug)]
pub struct Script<O>(pub O);

impl<O: Operator> Script<O> {
    /// Run the script on `buses[setup.bus]`.
    pub(crate) async fn run<B: I2c + BusRecovery>(
        self,
        buses: &mut [B; BUSES],
        setup: &AcceptanceSetup,
        shared: &Shared,
    ) {
        Timer::after(setup.start).await;
        let Some(bus) = buses.get_mut(usize::from(setup.bus)) else {
            return;
        };
        let mut operator = Announced {
            operator: self.0,
            shared,
        };
        operator.started();
        let verdict = acceptance_test(bus, &mut operator, &setup.script).await;
        operator.concluded(&verdict);
    }
}

/// An operator whose prompts, steps and verdict the console hears too.
struct Announced<'a, O> {
    operator: O,
    shared: &'a Shared,
}

impl<O: Operator> Operator for Announced<'_, O> {
    async fn prompt(&mut self, what: Prompt, family: Family) {
        let (severity, text) = prompt_text(what);
        self.shared.say(severity, text);
        self.operator.prompt(what, family).await;
    }

    fn started(&mut self) {
        self.operator.started();
    }

    fn reported(&mut self, result: &StepResult) {
        let (severity, text) = step_text(result);
        self.shared.say(severity, text);
        self.operator.reported(result);
    }

    fn concluded(&mut self, verdict: &Verdict) {
        let (severity, text) = verdict_text(verdict);
        self.shared.say(severity, text);
        self.operator.concluded(verdict);
    }
}

/// Timings and limits of the script.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct AcceptanceConfig {
    /// The family the build expects to find (the dev kit's `legacy` feature); None: whichever answers.
    pub expect: Option<Family>,
    /// Time between polls within a step.
    pub(crate) period: Duration,
    /// How long a status may take to follow a new order.
    pub(crate) settle: Duration,
    /// How far (in speed steps) a reported speed may be from the order.
    pub(crate) tolerance: u8,
    /// The step used wherever the thruster must visibly drive (failsafe, faults, bad orders).
    pub(crate) drive_step: i8,
    /// The least current (0.1 A) a Legacy brushless thruster must report at `drive_step` and beyond.
    pub(crate) min_current_deciamps: u8,
    /// How long the bus stays silent in the failsafe step (the thruster's failsafe trips at 1 s).
    pub(crate) silence: Duration,
    /// How long a stopped thruster may take to report speed 0 (a propeller in water coasts for seconds).
    pub(crate) coast: Duration,
    /// How long a stopped thruster must stay stopped while only reads reach it.
    pub(crate) stay_stopped: Duration,
    /// How long a provoked fault may take to be reported, and to clear.
    pub(crate) fault_within: Duration,
    /// How long the reset step keeps the bus busy waiting for the reset and the recovery.
    pub(crate) reset_window: Duration,
    /// Good polls in a row that count as recovered after a failure.
    pub(crate) recovered_polls: u16,
}

impl AcceptanceConfig {
    /// The script's defaults: polls every 10 ms, 1 s to follow an order within 1 step, drive step 60, 1.5 s of
    /// silence, 10 s to coast to rest, faults within 2 s, 15 s for the operator to reset the board.
    pub(crate) const DEFAULT: AcceptanceConfig = AcceptanceConfig {
        expect: None,
        period: Duration::from_millis(10),
        settle: Duration::from_secs(1),
        tolerance: 1,
        drive_step: 60,
        min_current_deciamps: 1,
        silence: Duration::from_millis(1500),
        coast: Duration::from_secs(10),
        stay_stopped: Duration::from_millis(500),
        fault_within: Duration::from_secs(2),
        reset_window: Duration::from_secs(15),
        recovered_polls: 20,
    };
}

impl Default for AcceptanceConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Where the acceptance image runs its script, and the person at the bench's timings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct AcceptanceSetup {
    /// The script's timings and limits.
    pub script: AcceptanceConfig,
    /// The bus the dev kits are wired on (its index, as in the thruster table).
    pub(crate) bus: u8,
    /// The script starts this long after boot, so that a thruster board powered up at the same time is running
    /// and the host has attached to the log.
    pub(crate) start: Duration,
}

impl AcceptanceSetup {
    /// How long the person at the bench gets for each prompt before the script goes on. The power cycle happens while
    /// the script keeps the bus busy (for `reset_window`, 15 s), so its prompt only gives time to reach the cable.
    pub const fn prompt_wait(&self, prompt: Prompt) -> Duration {
        match prompt {
            Prompt::FitWaterResistor => Duration::from_secs(15),
            Prompt::RemoveWaterResistor => Duration::from_secs(10),
            Prompt::HoldRotor => Duration::from_secs(8),
            Prompt::ReleaseRotor => Duration::from_secs(5),
            Prompt::ResetThruster => Duration::from_secs(5),
        }
    }
}

/// The speed a status reports, in steps: SeaBotix SPEED; Legacy brushed MAX POWER (the power set into the
/// motor). None for Legacy brushless, which reports only its current.
pub(crate) fn reported_speed(status: &Status) -> Option<i8> {
    match status {
        Status::SeaBotix(status) => Some(status.speed.step()),
        Status::Legacy(status) => match status.max_power {
            MaxPower::Power(speed) => Some(speed.step()),
            MaxPower::Current { .. } | MaxPower::Raw(_) => None,
        },
    }
}

/// The motor current a status reports, in 0.1 A: SeaBotix CURRENT; Legacy brushless MAX POWER. None for Legacy
/// brushed.
pub(crate) fn reported_current(status: &Status) -> Option<u8> {
    match status {
        Status::SeaBotix(status) => Some(status.current_deciamps),
        Status::Legacy(status) => match status.max_power {
            MaxPower::Current { deciamps } => Some(deciamps),
            MaxPower::Power(_) | MaxPower::Raw(_) => None,
        },
    }
}

/// Whether a status follows the order `step` (see the module's documentation); faults are judged separately.
pub(crate) fn follows(status: &Status, step: i8, config: &AcceptanceConfig) -> bool {
    if let Some(speed) = reported_speed(status) {
        return (i16::from(speed) - i16::from(step)).unsigned_abs() <= u16::from(config.tolerance);
    }
    match (status, reported_current(status)) {
        (Status::Legacy(_), Some(current)) => {
            if step == 0 {
                current == 0
            } else if step.unsigned_abs() >= config.drive_step.unsigned_abs() {
                current >= config.min_current_deciamps
            } else {
                true
            }
        }
        _ => false,
    }
}

/// Whether the status shows the drive off: no current (Legacy brushed: no power set into the motor).
pub(crate) fn drive_off(status: &Status) -> bool {
    match reported_current(status) {
        Some(current) => current == 0,
        None => reported_speed(status) == Some(0),
    }
}

/// Whether the status shows the thruster at rest: the drive off and any reported speed 0.
pub(crate) fn at_rest(status: &Status) -> bool {
    drive_off(status) && reported_speed(status).is_none_or(|speed| speed == 0)
}

/// The order for `step`, encoded for `family`.
fn order_bytes(family: Family, step: i8) -> [u8; ORDER_LEN] {
    Order::new(Speed::new_saturating(i32::from(step))).encode(family)
}

/// How long the bad-order steps send refused orders: less than the 1 s after which a thruster stops on refused
/// orders alone (docs/thruster.md, "The link failsafe"), so every status must still show the order held.
pub(crate) const BAD_ORDERS_FOR: Duration = Duration::from_millis(500);

/// The out-of-range SPEED bytes sent, each with a matching checksum: both ends of both gaps.
pub(crate) const OUT_OF_RANGE_SPEEDS: [u8; 4] = [0x00, 0x18, 0xE7, 0xFF];

/// Bus failures seen, by kind, and the recoveries run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct FailureCounts {
    nack: u32,
    timeout: u32,
    bus: u32,
    frame: u32,
    recoveries: u32,
    recoveries_failed: u32,
}

impl FailureCounts {
    fn total(&self) -> u32 {
        self.nack
            .saturating_add(self.timeout)
            .saturating_add(self.bus)
            .saturating_add(self.frame)
    }
}

/// What a run of polls saw.
#[derive(Debug, Clone, Copy, Default)]
struct PollRun {
    /// How long until the condition held; None if it never did.
    took: Option<Duration>,
    /// The last valid status.
    last: Option<Status>,
    /// Every fault bit any status reported.
    faults: Faults,
    polls: u32,
    /// Valid statuses for which `condition` did not hold.
    misses: u32,
    /// Polls that failed on the bus or with an invalid frame.
    failures: u32,
}

/// The script's state: the bus, the operator, the tally.
struct Tester<'a, B, O> {
    bus: &'a mut B,
    operator: &'a mut O,
    config: &'a AcceptanceConfig,
    verdict: Verdict,
    failures: FailureCounts,
}

impl<B, O> Tester<'_, B, O>
where
    B: I2c + BusRecovery,
    O: Operator,
{
    fn finish(&mut self, result: StepResult) {
        self.verdict.count(&result);
        self.operator.reported(&result);
    }

    /// Count a failure and recover the bus when it may be stuck.
    async fn failed(&mut self, failure: PollFailure) -> PollFailure {
        let counter = match failure {
            PollFailure::Nack => &mut self.failures.nack,
            PollFailure::Timeout => &mut self.failures.timeout,
            PollFailure::Bus | PollFailure::Mux => &mut self.failures.bus,
            PollFailure::BadLength | PollFailure::BadType | PollFailure::BadChecksum | PollFailure::BadRange => {
                &mut self.failures.frame
            }
        };
        *counter = counter.saturating_add(1);
        if failure.needs_recovery() {
            self.failures.recoveries = self.failures.recoveries.saturating_add(1);
            if !self.bus.recover().await {
                self.failures.recoveries_failed = self.failures.recoveries_failed.saturating_add(1);
            }
        }
        failure
    }

    /// Write `order` (any bytes, when given) to the thruster of `family`, then read its status.
    async fn exchange(&mut self, family: Family, order: Option<&[u8]>) -> Result<Status, PollFailure> {
        let address = family.address();
        if let Some(bytes) = order
            && let Err(error) = self.bus.write(address, bytes).await
        {
            return Err(self.failed(PollFailure::of_bus_error(&error)).await);
        }
        let mut buffer = [0; MAX_STATUS_LEN];
        // Never empty: status_len() is at most MAX_STATUS_LEN.
        let reply = buffer.get_mut(..family.status_len()).unwrap_or_default();
        if let Err(error) = self.bus.read(address, reply).await {
            return Err(self.failed(PollFailure::of_bus_error(&error)).await);
        }
        match Status::decode(family, reply) {
            Ok(Decoded { status, warning: None }) => Ok(status),
            // The thruster under test must send only values its encoding defines.
            Ok(Decoded { warning: Some(_), .. }) => Err(self.failed(PollFailure::BadRange).await),
            Err(error) => Err(self.failed(PollFailure::of_decode_error(error)).await),
        }
    }

    /// Poll every `period` with `order` (or reads only) until `condition` holds for a valid status, or `within`
    /// has passed. With `whole` the polls go on for all of `within` and every status is judged.
    async fn poll(
        &mut self,
        family: Family,
        order: Option<&[u8]>,
        within: Duration,
        whole: bool,
        mut condition: impl FnMut(&Status) -> bool,
    ) -> PollRun {
        let start = Instant::now();
        let mut polled = PollRun::default();
        loop {
            polled.polls = polled.polls.saturating_add(1);
            match self.exchange(family, order).await {
                Ok(status) => {
                    polled.faults = polled.faults.union(status.faults());
                    polled.last = Some(status);
                    if condition(&status) {
                        polled.took.get_or_insert(start.elapsed());
                        if !whole {
                            return polled;
                        }
                    } else {
                        polled.misses = polled.misses.saturating_add(1);
                    }
                }
                Err(_) => polled.failures = polled.failures.saturating_add(1),
            }
            if start.elapsed() >= within {
                return polled;
            }
            Timer::after(self.config.period).await;
        }
    }

    /// Order `step` and wait until the status follows it.
    async fn drive(&mut self, family: Family, step: i8) -> PollRun {
        let config = self.config;
        let order = order_bytes(family, step);
        self.poll(family, Some(&order), config.settle, false, |status| {
            follows(status, step, config)
        })
        .await
    }

    /// Order zero and give the thruster `settle` to stop driving (not judged).
    async fn stop(&mut self, family: Family) {
        let order = order_bytes(family, 0);
        self.poll(family, Some(&order), self.config.settle, false, drive_off)
            .await;
    }

    async fn discovery(&mut self) -> heapless::Vec<Family, 2> {
        let mut result = StepResult::new(Step::Discovery, None);
        let mut found = heapless::Vec::new();
        for family in Family::ALL {
            let answer = self.exchange(family, None).await;
            let figure = match answer {
                Ok(_) => {
                    let _ = found.push(family);
                    1
                }
                Err(PollFailure::Nack) => 0,
                // Something answered, but not with a valid status of the family.
                Err(_) => -1,
            };
            result.figure(family_token(family), figure);
            result.require(figure >= 0);
        }
        result.figure("found", found.len());
        result.require(!found.is_empty());
        if let Some(expected) = self.config.expect {
            result.require(found.contains(&expected));
        }
        self.finish(result);
        found
    }

    async fn sweep(&mut self, family: Family, step: Step, sign: i8) {
        let mut result = StepResult::new(step, Some(family));
        let (mut ok, mut worst, mut first_bad, mut faults) = (0u8, Duration::from_ticks(0), None, Faults::NONE);
        let mut at_full = None;
        for magnitude in 1..=Speed::MAX_STEP {
            let target = sign.saturating_mul(magnitude);
            let polled = self.drive(family, target).await;
            faults = faults.union(polled.faults);
            match polled.took {
                Some(took) => {
                    ok = ok.saturating_add(1);
                    worst = worst.max(took);
                }
                None => {
                    first_bad.get_or_insert(target);
                }
            }
            at_full = polled.last;
        }
        result.figure("steps", Speed::MAX_STEP);
        result.figure("ok", ok);
        result.millis("worst_ms", Some(worst));
        if let Some(status) = at_full {
            match reported_speed(&status) {
                Some(speed) => result.figure("speed_at_full", speed),
                None => result.figure("current_da", reported_current(&status).unwrap_or(0)),
            }
        }
        if let Some(bad) = first_bad {
            result.figure("first_bad", bad);
        }
        result.figure("faults", faults.bits());
        result.require(ok == Speed::MAX_STEP.unsigned_abs() && faults.is_empty());
        self.finish(result);
        self.stop(family).await;
    }

    /// Send each of `bad` in turn (with a read after each) for [`BAD_ORDERS_FOR`] while the thruster holds a stop, then
    /// again while it holds the drive step, each time once it has held the order for `settle`: every status must still show the order held (the drive off, then
    /// following the drive step). Taking a bad order shows in one phase or the other whatever the family reports.
    async fn bad_orders(&mut self, family: Family, step: Step, bad: &[[u8; ORDER_LEN]]) {
        let config = self.config;
        let drive = config.drive_step;
        let mut result = StepResult::new(step, Some(family));
        let (mut ready, mut sent, mut held, mut failures, mut faults) = (true, 0u32, 0u32, 0u32, Faults::NONE);
        let mut last = None;
        // The speeds reported while the drive step was held, for the families that report one.
        let (mut lowest, mut highest) = (i8::MAX, i8::MIN);
        for hold in [0, drive] {
            let holds = |status: &Status| {
                if hold == 0 {
                    drive_off(status)
                } else {
                    follows(status, hold, config)
                }
            };
            let order = order_bytes(family, hold);
            ready &= self
                .poll(family, Some(&order), config.settle, false, holds)
                .await
                .took
                .is_some();
            // Let the speed loop settle (a propeller's loop overshoots a little after a step).
            self.poll(family, Some(&order), config.settle, true, holds).await;
            let start = Instant::now();
            for order in bad.iter().cycle() {
                if start.elapsed() >= BAD_ORDERS_FOR {
                    break;
                }
                sent = sent.saturating_add(1);
                match self.exchange(family, Some(order)).await {
                    Ok(status) => {
                        faults = faults.union(status.faults());
                        if holds(&status) {
                            held = held.saturating_add(1);
                        }
                        if hold != 0
                            && let Some(speed) = reported_speed(&status)
                        {
                            (lowest, highest) = (lowest.min(speed), highest.max(speed));
                        }
                        last = Some(status);
                    }
                    Err(_) => failures = failures.saturating_add(1),
                }
                Timer::after(config.period).await;
            }
        }
        result.figure("ready", u8::from(ready));
        result.figure("sent", sent);
        result.figure("held", held);
        if let Some(status) = last {
            match reported_speed(&status) {
                Some(speed) => result.figure("speed", speed),
                None => result.figure("current_da", reported_current(&status).unwrap_or(0)),
            }
        }
        result.figure("failures", failures);
        if lowest <= highest {
            result.figure("min", lowest);
            result.figure("max", highest);
        }
        result.require(ready && sent > 0 && held == sent && faults.is_empty());
        self.finish(result);
        self.stop(family).await;
    }

    async fn bad_checksum(&mut self, family: Family) {
        // A stop and the opposite of the drive step, each with its checksum off by one: taking either would show.
        let corrupt = |step: i8| {
            let mut order = order_bytes(family, step);
            if let Some(sum) = order.last_mut() {
                *sum = sum.wrapping_add(1);
            }
            order
        };
        let drive = self.config.drive_step;
        self.bad_orders(
            family,
            Step::BadChecksum,
            &[corrupt(drive.saturating_neg()), corrupt(0)],
        )
        .await;
    }

    async fn out_of_range(&mut self, family: Family) {
        let mt = family.order_type();
        let info = Order::INFO_NO_CAP;
        let orders = OUT_OF_RANGE_SPEEDS.map(|speed| [mt, speed, info, checksum(&[mt, speed, info])]);
        self.bad_orders(family, Step::OutOfRange, &orders).await;
    }

    async fn failsafe(&mut self, family: Family) {
        let config = self.config;
        let drive = config.drive_step;
        let mut result = StepResult::new(Step::Failsafe, Some(family));
        let ready = self.drive(family, drive).await.took.is_some();
        result.figure("ready", u8::from(ready));
        Timer::after(config.silence).await;
        let first = self.exchange(family, None).await;
        let off = first.as_ref().is_ok_and(drive_off);
        result.figure("off_at_first_read", u8::from(off));
        if let Ok(status) = first {
            match reported_speed(&status) {
                Some(speed) => result.figure("speed_at_first_read", speed),
                None => result.figure("current_da", reported_current(&status).unwrap_or(0)),
            }
        }
        let rest = self.poll(family, None, config.coast, false, at_rest).await;
        result.millis("rest_ms", rest.took);
        // Reads are life for the link, but only a new order may restart the motor.
        let stayed = self.poll(family, None, config.stay_stopped, true, at_rest).await;
        let stayed = stayed.misses == 0 && stayed.failures == 0;
        result.figure("stayed", u8::from(stayed));
        let restarted = self.drive(family, drive).await;
        result.millis("restart_ms", restarted.took);
        result.require(ready && off && rest.took.is_some() && stayed && restarted.took.is_some());
        self.finish(result);
        self.stop(family).await;
    }

    async fn held_rotor(&mut self, family: Family) {
        let config = self.config;
        let drive = config.drive_step;
        let mut result = StepResult::new(Step::HeldRotor, Some(family));
        self.operator.prompt(Prompt::HoldRotor, family).await;
        let order = order_bytes(family, drive);
        let stall = self
            .poll(family, Some(&order), config.fault_within, false, |status| {
                status.faults().contains(Faults::STALL)
            })
            .await;
        result.millis("stall_ms", stall.took);
        // Stalled, the controller stops driving although the order stands.
        let stopped = self.poll(family, Some(&order), config.settle, false, drive_off).await;
        result.figure("stopped", u8::from(stopped.took.is_some()));
        self.operator.prompt(Prompt::ReleaseRotor, family).await;
        let zero = order_bytes(family, 0);
        let cleared = self
            .poll(family, Some(&zero), config.fault_within, false, |status| {
                !status.faults().contains(Faults::STALL)
            })
            .await;
        result.millis("cleared_ms", cleared.took);
        let resumed = self.drive(family, drive).await;
        result.millis("resumed_ms", resumed.took);
        let faults = resumed.last.map_or(Faults::NONE, |status| status.faults());
        result.figure("faults", faults.bits());
        result.require(
            stall.took.is_some()
                && stopped.took.is_some()
                && cleared.took.is_some()
                && resumed.took.is_some()
                && faults.is_empty(),
        );
        self.finish(result);
        self.stop(family).await;
    }

    async fn water(&mut self, family: Family) {
        let config = self.config;
        let drive = config.drive_step;
        let mut result = StepResult::new(Step::Water, Some(family));
        self.operator.prompt(Prompt::FitWaterResistor, family).await;
        let order = order_bytes(family, drive);
        let wet = |status: &Status| status.faults().contains(Faults::WATER);
        let seen = self.poll(family, Some(&order), config.fault_within, false, wet).await;
        result.millis("water_ms", seen.took);
        // IDS 8.4: water is a warning on a SeaBotix controller (it keeps driving) and stops a Legacy one.
        let keeps_driving = family == Family::SeaBotix;
        let behaves = self
            .poll(family, Some(&order), config.settle, false, |status| {
                if keeps_driving {
                    follows(status, drive, config)
                } else {
                    drive_off(status)
                }
            })
            .await;
        result.figure("driving", u8::from(behaves.took.is_some() == keeps_driving));
        self.operator.prompt(Prompt::RemoveWaterResistor, family).await;
        let after = if keeps_driving {
            // The warning clears once the resistance is back above 1 Mohm.
            let cleared = self
                .poll(family, Some(&order), config.fault_within, false, |status| !wet(status))
                .await;
            result.millis("cleared_ms", cleared.took);
            cleared.took.is_some()
        } else {
            // Latched until power cycle: still set, still stopped, after the resistor is gone.
            let latched = self
                .poll(family, Some(&order), config.fault_within, true, |status| {
                    wet(status) && drive_off(status)
                })
                .await;
            let latched = latched.took.is_some() && latched.misses == 0;
            result.figure("latched", u8::from(latched));
            latched
        };
        result.require(seen.took.is_some() && behaves.took.is_some() && after);
        self.finish(result);
        self.stop(family).await;
    }

    async fn reset(&mut self, family: Family) {
        let config = self.config;
        let drive = config.drive_step;
        let mut result = StepResult::new(Step::Reset, Some(family));
        let order = order_bytes(family, drive);
        self.operator.prompt(Prompt::ResetThruster, family).await;
        let before = self.failures;
        let start = Instant::now();
        let (mut first_failure, mut recovered, mut good_run) = (None, None, 0u16);
        // Back to back, so that the reset lands in a transfer.
        while start.elapsed() < config.reset_window {
            match self.exchange(family, Some(&order)).await {
                Ok(_) => {
                    good_run = good_run.saturating_add(1);
                    if first_failure.is_some() && good_run >= config.recovered_polls {
                        recovered = Some(start.elapsed());
                        break;
                    }
                }
                Err(_) => {
                    good_run = 0;
                    first_failure.get_or_insert(start.elapsed());
                }
            }
            // Let other work run between polls without leaving the bus idle.
            embassy_futures::yield_now().await;
        }
        let seen = FailureCounts {
            nack: self.failures.nack.wrapping_sub(before.nack),
            timeout: self.failures.timeout.wrapping_sub(before.timeout),
            bus: self.failures.bus.wrapping_sub(before.bus),
            frame: self.failures.frame.wrapping_sub(before.frame),
            recoveries: self.failures.recoveries.wrapping_sub(before.recoveries),
            recoveries_failed: self.failures.recoveries_failed.wrapping_sub(before.recoveries_failed),
        };
        result.figure("nack", seen.nack);
        result.figure("timeout", seen.timeout);
        result.figure("bus_error", seen.bus);
        result.figure("bad_frame", seen.frame);
        result.figure("recoveries", seen.recoveries);
        let outage = first_failure
            .zip(recovered)
            .map(|(failed, back)| Duration::from_ticks(back.as_ticks().saturating_sub(failed.as_ticks())));
        result.millis("recovered_ms", outage);
        // A fresh controller: no fault left (a latched water fault is gone) and it takes orders again.
        let again = self.drive(family, drive).await;
        let clean = again.took.is_some() && again.last.is_some_and(|status| status.faults().is_empty());
        result.figure("drives_again", u8::from(clean));
        result.require(seen.total() > 0 && recovered.is_some() && seen.recoveries_failed == 0 && clean);
        self.finish(result);
        self.stop(family).await;
    }

    async fn thruster(&mut self, family: Family) {
        self.sweep(family, Step::SpeedForward, 1).await;
        self.sweep(family, Step::SpeedReverse, -1).await;
        self.bad_checksum(family).await;
        self.out_of_range(family).await;
        self.failsafe(family).await;
        self.held_rotor(family).await;
        self.water(family).await;
        self.reset(family).await;
    }
}

/// Run the whole script against whatever answers on `bus`, telling the operator each step's result as it ends, and
/// return the verdict. Discovery finds the thrusters; every one found is tested in turn (SeaBotix first). Leaves
/// every thruster ordered to stop.
pub(crate) async fn acceptance_test<B, O>(bus: &mut B, operator: &mut O, config: &AcceptanceConfig) -> Verdict
where
    B: I2c + BusRecovery,
    O: Operator,
{
    let mut tester = Tester {
        bus,
        operator,
        config,
        verdict: Verdict::default(),
        failures: FailureCounts::default(),
    };
    let found = tester.discovery().await;
    for family in found {
        tester.thruster(family).await;
    }
    tester.verdict
}

#[cfg(test)]
mod tests;
