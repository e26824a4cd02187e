//! Thruster polling: one task per I2C bus sends every thruster on it its order, reads its status and keeps its
//! link health.
//!
//! The thruster table ([`ThrusterTable`] of [`ThrusterSlot`]s, the production ones in [`crate::config`]) is fixed
//! at build time: each entry names the bus (I2C1..3), the TCA9548A channel when the thruster sits behind the
//! multiplexer, and the controller family, so Legacy and SeaBotix controllers can share a bus. A thruster's index
//! in the table is its index in `Shared::orders` and `Shared::thrusters`, and its number in console texts is that
//! index plus one.
//!
//! The decisions live in small synchronous state machines that the virtual bench can reuse:
//! - [`PollFailure`] classifies a failed poll (NACK, timeout, bus error, mux, decode errors);
//! - [`ThrusterLink`] keeps one thruster's health, its last valid status and its retry back-off;
//! - [`FaultWatch`] turns the status's fault bits into changes worth a console text.
//!
//! [`bus_task`] wires them to a bus: every poll period it polls each due thruster once, in table order. A missing
//! thruster (its first NACK) is taken offline at once and retried with a doubling back-off, skipped between
//! retries so it never slows the others. Only orders that do not get through take a thruster offline: one whose
//! orders are acknowledged keeps its full order rate however its status reads go, and a status it cannot read
//! costs only the telemetry (counted, and told on the console once it has failed for `offline_after` polls in a
//! row). After a timeout or a bus error the bus is recovered (up to 9 SCL pulses, then STOP) and polling goes on
//! with the next thruster.

use core::cell::Cell;

use crash_record::What;
use embassy_futures::yield_now;
use embassy_time::{Duration, Instant, Timer};
use embedded_hal::i2c::ErrorKind;
use embedded_hal_async::i2c::I2c;
use tmc_proto::{DecodeError, Decoded, Family, Faults, Order, Status, StatusForm};

use crate::follow::{FollowChange, FollowCheck};
use crate::poll::{PollError, Polled, poll_thruster};
use crate::ports::BusRecovery;
use crate::shared::{BUSES, LinkHealth, MAX_THRUSTERS, Severity, Shared, Text, ThrusterReport, text};
use crate::update::courier::{self, ExchangeError, Sent, Transfers};

#[cfg(test)]
mod tests;

/// TCA9548A address (A0..A2 low).
pub const MUX_ADDRESS: u8 = 0x70;

/// TCA9548A channels.
pub(crate) const MUX_CHANNELS: u8 = 8;

/// The SDA and SCL pull-ups each TCA9548A channel carries, to the bus's 3.3 V (docs/hardware.md).
const MUX_PULLUP_OHM: u32 = 4_700;
const BUS_MV: u32 = 3_300;
/// How many thrusters one update write may reach at once, their channels enabled together: three, by the current
/// their pull-ups in parallel make a driver sink ([`g431_hw::i2c::channels_together`]).
pub(crate) const CAST_CHANNELS: u32 = g431_hw::i2c::channels_together(BUS_MV, MUX_PULLUP_OHM);

/// Bit times of one I2C transfer of `bytes` data bytes: START, the address byte and its ACK, 9 bits per data
/// byte (8 + ACK), STOP. An order (4 bytes) is 47; a SeaBotix status read (7 bytes) 74; a Legacy one 47.
#[cfg(test)]
pub(crate) const fn transfer_bits(bytes: u32) -> u32 {
    1 + 9 + 9 * bytes + 1
}

/// Bit times of one poll of a `family` thruster: the order write and the status read.
#[cfg(test)]
pub(crate) const fn poll_bits(family: Family) -> u32 {
    transfer_bits(tmc_proto::ORDER_LEN as u32) + transfer_bits(family.status_len() as u32)
}

/// One thruster in the table: which bus (0 = I2C1, 1 = I2C2, 2 = I2C3), which TCA9548A channel (None when wired
/// directly), which family.
///
/// The family fixes the address, so a bus holds at most one directly wired thruster per family, and a thruster
/// of a family wired directly excludes that family from the bus's mux channels; [`check_table`] checks this.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct ThrusterSlot {
    /// Bus index: 0 = I2C1, 1 = I2C2, 2 = I2C3.
    pub bus: u8,
    /// TCA9548A channel 0..=7 the thruster hangs on, or None when it is wired to the bus directly.
    pub mux_channel: Option<u8>,
    /// Controller family: sets the address and the status length.
    pub family: tmc_proto::Family,
}

impl ThrusterSlot {
    /// A thruster wired to `bus` directly.
    pub const fn direct(bus: u8, family: Family) -> Self {
        Self {
            bus,
            mux_channel: None,
            family,
        }
    }

    /// A thruster on TCA9548A channel `channel` of `bus`.
    pub(crate) const fn behind_mux(bus: u8, channel: u8, family: Family) -> Self {
        Self {
            bus,
            mux_channel: Some(channel),
            family,
        }
    }
}

/// What is wrong with a thruster table; thrusters are named by their index in the table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) enum TableError {
    /// More thrusters than `Shared` has room for ([`MAX_THRUSTERS`]).
    TooMany,
    /// A bus index beyond I2C3.
    Bus(usize),
    /// A TCA9548A channel beyond 7.
    Channel(usize),
    /// Two thrusters would answer the same transfer: same bus, same family (hence address), and either the same
    /// mux channel or one of them wired directly (a direct thruster hears every transfer of the bus).
    SharedAddress(usize, usize),
}

/// Check a thruster table; meant for build time: `const _: () = assert!(check_table(&TABLE).is_ok());`.
pub(crate) const fn check_table(table: &[ThrusterSlot]) -> Result<(), TableError> {
    if table.len() > MAX_THRUSTERS {
        return Err(TableError::TooMany);
    }
    let mut rest = table;
    let mut i = 0;
    while let [slot, tail @ ..] = rest {
        if slot.bus as usize >= BUSES {
            return Err(TableError::Bus(i));
        }
        if let Some(channel) = slot.mux_channel
            && channel >= MUX_CHANNELS
        {
            return Err(TableError::Channel(i));
        }
        let mut others = tail;
        let mut j = i + 1;
        while let [other, more @ ..] = others {
            let same_wire = match (slot.mux_channel, other.mux_channel) {
                (Some(a), Some(b)) => a == b,
                _ => true,
            };
            if other.bus == slot.bus && other.family.address() == slot.family.address() && same_wire {
                return Err(TableError::SharedAddress(i, j));
            }
            others = more;
            j += 1;
        }
        rest = tail;
        i += 1;
    }
    Ok(())
}

/// A thruster table: at most [`MAX_THRUSTERS`] slots, kept by value so a configuration owns its table. A thruster's
/// index in the table is its index in `Shared::orders` and `Shared::thrusters`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct ThrusterTable {
    slots: [ThrusterSlot; MAX_THRUSTERS],
    len: u8,
}

impl ThrusterTable {
    /// The table of `slots`; slots beyond [`MAX_THRUSTERS`] are dropped (and [`ThrusterTable::check`] says so).
    pub const fn new(slots: &[ThrusterSlot]) -> Self {
        let mut table = [ThrusterSlot::direct(0, Family::SeaBotix); MAX_THRUSTERS];
        let mut len = 0;
        let mut from = slots;
        let mut to: &mut [ThrusterSlot] = &mut table;
        loop {
            match (from, to) {
                ([slot, from_rest @ ..], [place, to_rest @ ..]) => {
                    *place = *slot;
                    len += 1;
                    from = from_rest;
                    to = to_rest;
                }
                ([], _) => break,
                // More than fit: marked so that `check` fails.
                (_, []) => {
                    len = u8::MAX;
                    break;
                }
            }
        }
        Self { slots: table, len }
    }

    /// The slots, in order.
    pub const fn as_slice(&self) -> &[ThrusterSlot] {
        let len = if (self.len as usize) < MAX_THRUSTERS {
            self.len as usize
        } else {
            MAX_THRUSTERS
        };
        match self.slots.split_at_checked(len) {
            Some((slots, _)) => slots,
            None => &[],
        }
    }

    /// How many thrusters the table holds.
    pub const fn count(&self) -> u8 {
        self.as_slice().len() as u8
    }

    /// Check the table ([`check_table`]); meant for build time: `const _: () = assert!(TABLE.check().is_ok());`.
    pub(crate) const fn check(&self) -> Result<(), TableError> {
        if self.len as usize > MAX_THRUSTERS {
            return Err(TableError::TooMany);
        }
        check_table(self.as_slice())
    }

    /// Whether any thruster hangs on bus `bus`.
    pub(crate) fn uses_bus(&self, bus: u8) -> bool {
        self.as_slice().iter().any(|slot| slot.bus == bus)
    }
}

/// How often thrusters are polled and how offline ones are retried.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct PollConfig {
    /// Per-thruster poll period; `Duration::from_ticks(0)` polls back to back, limited only by the bus.
    pub(crate) period: Duration,
    /// First retry of an offline thruster comes this long after it went offline.
    pub(crate) retry_min: Duration,
    /// The retry interval doubles after each failed retry, up to this.
    pub(crate) retry_max: Duration,
    /// Consecutive failures other than a NACK before a thruster is taken offline (a NACK does it at once).
    pub(crate) offline_after: u16,
}

impl PollConfig {
    /// 20 ms (50 Hz per thruster); retries 100 ms doubling up to 2 s; offline after 3 failures in a row.
    pub(crate) const DEFAULT: PollConfig = PollConfig {
        period: Duration::from_millis(20),
        retry_min: Duration::from_millis(100),
        retry_max: Duration::from_secs(2),
        offline_after: 3,
    };
}

impl Default for PollConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Why one poll failed, as the link health counts it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) enum PollFailure {
    /// The thruster did not acknowledge: it is missing or unpowered.
    Nack,
    /// The transfer timed out. embedded-hal has no timeout kind: embassy-stm32 reports its timeout as
    /// `ErrorKind::Other` (as it does its unused PEC and zero-length errors), so every `Other` counts here.
    Timeout,
    /// Bus error, arbitration loss or overrun: something disturbed SDA or SCL.
    Bus,
    /// Selecting the thruster's TCA9548A channel failed (or the table names a channel the mux does not have).
    /// Counted as a bus error.
    Mux,
    /// The status had the wrong length.
    BadLength,
    /// The status's MT byte was not the family's.
    BadType,
    /// The status's checksum did not match.
    BadChecksum,
    /// A status field was out of range.
    BadRange,
}

impl PollFailure {
    /// Class of a bus error, by its embedded-hal kind.
    pub(crate) fn of_bus_error<E: embedded_hal::i2c::Error>(error: &E) -> PollFailure {
        match error.kind() {
            ErrorKind::NoAcknowledge(_) => PollFailure::Nack,
            ErrorKind::Other => PollFailure::Timeout,
            _ => PollFailure::Bus,
        }
    }

    /// Class of a status that failed to decode.
    pub(crate) const fn of_decode_error(error: DecodeError) -> PollFailure {
        match error {
            DecodeError::Length { .. } => PollFailure::BadLength,
            DecodeError::MessageType { .. } => PollFailure::BadType,
            DecodeError::Checksum { .. } => PollFailure::BadChecksum,
            DecodeError::SpeedOutOfRange(_) => PollFailure::BadRange,
        }
    }

    /// Class of a failed [`poll_thruster`].
    pub(crate) fn of_poll_error<E: embedded_hal::i2c::Error>(error: &PollError<E>) -> PollFailure {
        match error {
            PollError::Order(error) | PollError::Status(error) => PollFailure::of_bus_error(error),
            PollError::Decode(error) => PollFailure::of_decode_error(*error),
        }
    }

    /// Whether the bus may be left stuck, so a recovery should follow.
    pub(crate) const fn needs_recovery(self) -> bool {
        matches!(self, PollFailure::Timeout | PollFailure::Bus | PollFailure::Mux)
    }

    /// Short words for console texts.
    pub(crate) const fn reason(self) -> &'static str {
        match self {
            PollFailure::Nack => "no answer",
            PollFailure::Timeout => "timeout",
            PollFailure::Bus => "bus error",
            PollFailure::Mux => "mux error",
            PollFailure::BadLength => "bad length",
            PollFailure::BadType => "bad message type",
            PollFailure::BadChecksum => "bad checksum",
            PollFailure::BadRange => "value out of range",
        }
    }
}

/// What one poll came to, as the link counts it.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) enum Outcome {
    /// The order was delivered and the status read.
    Answered(Status),
    /// The order was delivered (its write acknowledged), but the status could not be read.
    NoStatus(PollFailure),
    /// The order was not delivered.
    NoOrder(PollFailure),
}

impl Outcome {
    /// The outcome of a [`poll_thruster`].
    pub(crate) fn of_poll<E: embedded_hal::i2c::Error>(result: &Result<Polled, PollError<E>>) -> Outcome {
        match result {
            Ok(polled) => Outcome::Answered(polled.decoded.status),
            Err(error) if error.delivered() => Outcome::NoStatus(PollFailure::of_poll_error(error)),
            Err(error) => Outcome::NoOrder(PollFailure::of_poll_error(error)),
        }
    }

    /// Why the poll failed, if it did.
    pub(crate) const fn failure(&self) -> Option<PollFailure> {
        match self {
            Outcome::Answered(_) => None,
            Outcome::NoStatus(failure) | Outcome::NoOrder(failure) => Some(*failure),
        }
    }
}

/// A thruster's link failsafe: 1 s without a valid order stops its motor (docs/thruster.md, "The link failsafe").
pub(crate) const THRUSTER_FAILSAFE: Duration = Duration::from_secs(1);

/// Where a thruster's link stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) enum LinkState {
    /// Not polled yet, or only failures short of the offline threshold so far.
    Unknown,
    /// Answered; any failures since are short of the offline threshold.
    Online,
    /// Missing or failing: polled only when its retry is due.
    Offline,
}

/// A change of a thruster's link worth telling the console.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) enum LinkChange {
    /// The first delivered order after start-up or after being offline.
    Online,
    /// Taken offline, for this last failure.
    Offline(PollFailure),
    /// Orders delivered, but the status unreadable for `offline_after` polls in a row, for this last failure.
    StatusLost(PollFailure),
    /// A status read again after [`LinkChange::StatusLost`].
    StatusBack,
}

/// One thruster's link: health counters, the last valid status and the retry schedule while offline.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct ThrusterLink {
    health: LinkHealth,
    state: LinkState,
    status: Option<Status>,
    /// The form the last valid status came in.
    form: Option<StatusForm>,
    /// The last valid status said the link failsafe had stopped the thruster.
    link_failsafe: bool,
    /// The start of the last poll cycle whose order was delivered.
    last_delivered: Option<Instant>,
    /// The last valid status said a sustained overcurrent held the thruster's bridge off.
    overcurrent: bool,
    /// Whether its status shows it following its orders.
    follow: FollowCheck,
    /// While offline: when the next retry is due.
    retry_at: Instant,
    /// While offline: the interval after the next failed retry.
    next_backoff: Duration,
    retry_min: Duration,
    retry_max: Duration,
    offline_after: u16,
}

impl ThrusterLink {
    /// A thruster not polled yet.
    pub(crate) const fn new(config: &PollConfig) -> Self {
        Self {
            health: LinkHealth {
                online: false,
                consecutive_failures: 0,
                status_failures: 0,
                status_lost: false,
                polls: 0,
                delivered: 0,
                good: 0,
                implied_form: 0,
                link_failsafes: 0,
                overcurrents: 0,
                not_followed: 0,
                not_following: false,
                nack: 0,
                timeout: 0,
                bad_checksum: 0,
                bad_type: 0,
                bad_length: 0,
                bad_range: 0,
                bus_error: 0,
                recoveries: 0,
            },
            state: LinkState::Unknown,
            status: None,
            form: None,
            link_failsafe: false,
            last_delivered: None,
            overcurrent: false,
            follow: FollowCheck::new(),
            retry_at: Instant::from_ticks(0),
            next_backoff: config.retry_min,
            retry_min: config.retry_min,
            retry_max: config.retry_max,
            offline_after: config.offline_after,
        }
    }

    /// Health and counters.
    #[cfg(test)]
    pub(crate) const fn health(&self) -> LinkHealth {
        self.health
    }

    /// Where the link stands.
    #[cfg(test)]
    pub(crate) const fn state(&self) -> LinkState {
        self.state
    }

    /// The last valid status, kept across failures.
    #[cfg(test)]
    pub(crate) const fn status(&self) -> Option<Status> {
        self.status
    }

    /// The form the last valid status came in ([`poll_thruster`] takes only that form once it is known full).
    pub(crate) const fn form(&self) -> Option<StatusForm> {
        self.form
    }

    /// What the bus task publishes.
    pub(crate) const fn report(&self) -> ThrusterReport {
        ThrusterReport {
            health: self.health,
            status: self.status,
        }
    }

    /// When an offline thruster is next retried; None while it is polled every period.
    pub(crate) const fn retry_at(&self) -> Option<Instant> {
        match self.state {
            LinkState::Offline => Some(self.retry_at),
            LinkState::Unknown | LinkState::Online => None,
        }
    }

    /// Whether to poll the thruster in the cycle starting at `now`: always, unless it is offline and its retry
    /// is not due yet.
    pub(crate) fn due(&self, now: Instant) -> bool {
        self.retry_at().is_none_or(|at| now >= at)
    }

    /// Count a poll's result; `now` is the start of the poll cycle, which retries are scheduled from.
    pub(crate) fn on_result<E: embedded_hal::i2c::Error>(
        &mut self,
        now: Instant,
        result: &Result<Polled, PollError<E>>,
    ) -> Option<LinkChange> {
        if let Ok(polled) = result {
            self.form = Some(polled.form);
            if polled.form == StatusForm::ImpliedType {
                self.health.implied_form = self.health.implied_form.saturating_add(1);
            }
        }
        self.on_outcome(now, Outcome::of_poll(result))
    }

    /// Take the link failsafe bit of a valid status; true when it has just risen (the thruster went 1 s without a
    /// valid order and stopped), which is counted.
    pub(crate) fn on_link_failsafe(&mut self, set: bool) -> bool {
        rise(&mut self.link_failsafe, set, &mut self.health.link_failsafes)
    }

    /// Take the overcurrent bit of a valid status; true when it has just risen (a sustained overcurrent stopped the
    /// thruster's bridge until a zero order), which is counted.
    pub(crate) fn on_overcurrent(&mut self, set: bool) -> bool {
        rise(&mut self.overcurrent, set, &mut self.health.overcurrents)
    }

    /// Judge whether the valid status read at `now` follows `order`, the order sent in the same poll
    /// ([`FollowCheck::observe`]); a change is returned, and a loss counted.
    pub(crate) fn on_follow(
        &mut self,
        now: Instant,
        order: Order,
        status: &Status,
        stopped_for_a_reason: bool,
    ) -> Option<FollowChange> {
        let change = self.follow.observe(now, order, status, stopped_for_a_reason);
        if change == Some(FollowChange::Lost) {
            self.health.not_followed = self.health.not_followed.saturating_add(1);
        }
        self.health.not_following = self.follow.not_following();
        change
    }

    /// Note whether the order of the poll cycle starting at `now` was delivered to a thruster of `family`; true
    /// when a delivery to a Legacy thruster ends a gap of more than `failsafe` since the last one: it then went
    /// that long without a valid order and its own link failsafe stopped it, which its status has no bit to say
    /// (a SeaBotix thruster's says it: [`ThrusterLink::on_link_failsafe`]). Counted in `link_failsafes`.
    pub(crate) fn on_delivery(&mut self, now: Instant, delivered: bool, family: Family, failsafe: Duration) -> bool {
        if !delivered {
            return false;
        }
        let gap = self
            .last_delivered
            .replace(now)
            .and_then(|last| now.checked_duration_since(last));
        let stopped = family == Family::Legacy && gap.is_some_and(|gap| gap > failsafe);
        if stopped {
            self.health.link_failsafes = self.health.link_failsafes.saturating_add(1);
        }
        stopped
    }

    /// Count a poll's outcome, already classified; `now` is the start of the poll cycle.
    pub(crate) fn on_outcome(&mut self, now: Instant, outcome: Outcome) -> Option<LinkChange> {
        let health = &mut self.health;
        health.polls = health.polls.saturating_add(1);
        if let Some(failure) = outcome.failure() {
            let counter = match failure {
                PollFailure::Nack => &mut health.nack,
                PollFailure::Timeout => &mut health.timeout,
                PollFailure::Bus | PollFailure::Mux => &mut health.bus_error,
                PollFailure::BadLength => &mut health.bad_length,
                PollFailure::BadType => &mut health.bad_type,
                PollFailure::BadChecksum => &mut health.bad_checksum,
                PollFailure::BadRange => &mut health.bad_range,
            };
            *counter = counter.saturating_add(1);
        }
        let failure = match outcome {
            Outcome::NoOrder(failure) => failure,
            Outcome::Answered(_) | Outcome::NoStatus(_) => {
                health.delivered = health.delivered.saturating_add(1);
                health.consecutive_failures = 0;
                health.online = true;
                self.next_backoff = self.retry_min;
                let was = core::mem::replace(&mut self.state, LinkState::Online);
                let status = match outcome {
                    Outcome::Answered(status) => {
                        health.good = health.good.saturating_add(1);
                        health.status_failures = 0;
                        self.status = Some(status);
                        Ok(())
                    }
                    Outcome::NoStatus(failure) | Outcome::NoOrder(failure) => {
                        health.status_failures = health.status_failures.saturating_add(1);
                        Err(failure)
                    }
                };
                if was != LinkState::Online {
                    health.status_lost = false;
                    return Some(LinkChange::Online);
                }
                return match status {
                    Ok(()) if health.status_lost => {
                        health.status_lost = false;
                        Some(LinkChange::StatusBack)
                    }
                    Err(failure) if !health.status_lost && health.status_failures >= self.offline_after.max(1) => {
                        health.status_lost = true;
                        Some(LinkChange::StatusLost(failure))
                    }
                    _ => None,
                };
            }
        };
        health.consecutive_failures = health.consecutive_failures.saturating_add(1);
        match self.state {
            LinkState::Offline => {
                // A failed retry: wait longer before the next.
                self.retry_at = now + self.next_backoff;
                self.next_backoff = self.doubled(self.next_backoff);
                None
            }
            LinkState::Unknown | LinkState::Online => {
                let missing = failure == PollFailure::Nack;
                if missing || health.consecutive_failures >= self.offline_after.max(1) {
                    health.online = false;
                    self.state = LinkState::Offline;
                    let first = self.retry_min.min(self.retry_max);
                    self.retry_at = now + first;
                    self.next_backoff = self.doubled(first);
                    Some(LinkChange::Offline(failure))
                } else {
                    None
                }
            }
        }
    }

    /// Count a status that decoded with an out-of-range field: the poll still counts as good (its faults are
    /// read), the field's oddity goes to `bad_range`.
    pub(crate) fn on_odd_field(&mut self) {
        self.health.bad_range = self.health.bad_range.saturating_add(1);
    }

    /// Count a bus recovery run after this thruster's failure.
    pub(crate) fn on_recovery(&mut self) {
        self.health.recoveries = self.health.recoveries.saturating_add(1);
    }

    fn doubled(&self, interval: Duration) -> Duration {
        Duration::from_ticks(interval.as_ticks().saturating_mul(2)).min(self.retry_max)
    }
}

/// Takes a status bit into `flag`; true when it has just risen, which `count` counts.
fn rise(flag: &mut bool, set: bool, count: &mut u32) -> bool {
    let risen = set && !*flag;
    *flag = set;
    if risen {
        *count = count.saturating_add(1);
    }
    risen
}

/// A change of a thruster's fault bits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct FaultChange {
    /// Faults newly set.
    pub(crate) raised: Faults,
    /// Faults newly cleared.
    pub(crate) cleared: Faults,
    /// All faults now set.
    pub(crate) now: Faults,
}

/// The fault bits last reported by one thruster, to report only their changes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct FaultWatch {
    faults: Faults,
}

impl FaultWatch {
    /// No fault seen yet.
    pub(crate) const fn new() -> Self {
        Self { faults: Faults::NONE }
    }

    /// Take the faults of a valid status; returns what changed, if anything.
    pub(crate) fn update(&mut self, faults: Faults) -> Option<FaultChange> {
        let before = core::mem::replace(&mut self.faults, faults);
        (before != faults).then_some(FaultChange {
            raised: faults.difference(before),
            cleared: before.difference(faults),
            now: faults,
        })
    }
}

/// Severity of one fault flag: Critical when the controller stops for it, Warning for water on a SeaBotix
/// controller, which only warns and keeps driving (IDS 8.4 remarks).
pub(crate) fn fault_severity(family: Family, fault: Faults) -> Severity {
    if family == Family::SeaBotix && fault == Faults::WATER {
        Severity::Warning
    } else {
        Severity::Critical
    }
}

/// The console text for a link change of thruster `index` (0-based; texts count from 1). One that goes offline
/// while `restarting` into its update (its bootloader swapping the image in) is told as that, not as a fault.
pub(crate) fn link_text(index: usize, change: LinkChange, restarting: bool) -> (Severity, Text) {
    let number = index.saturating_add(1);
    match change {
        LinkChange::Online => (Severity::Info, text(format_args!("T{number} online"))),
        LinkChange::Offline(_) if restarting => (
            Severity::Info,
            text(format_args!("T{number} offline: restarting into its update")),
        ),
        LinkChange::Offline(failure) => (
            Severity::Warning,
            text(format_args!("T{number} offline: {}", failure.reason())),
        ),
        LinkChange::StatusLost(failure) => (
            Severity::Warning,
            text(format_args!("T{number} status unreadable: {}", failure.reason())),
        ),
        LinkChange::StatusBack => (Severity::Notice, text(format_args!("T{number} status readable again"))),
    }
}

/// The console texts for a fault change of thruster `index` (0-based): one per cleared fault, or "faults
/// cleared" when none is left, then one per raised fault.
pub(crate) fn fault_texts(index: usize, family: Family, change: FaultChange) -> impl Iterator<Item = (Severity, Text)> {
    let number = index.saturating_add(1);
    let all_clear = change.now.is_empty() && !change.cleared.is_empty();
    let cleared_all = all_clear.then(|| (Severity::Notice, text(format_args!("T{number} faults cleared"))));
    let cleared = change.cleared.iter().filter(move |_| !all_clear).map(move |fault| {
        (
            Severity::Notice,
            text(format_args!("T{number} fault cleared: {}", fault.name())),
        )
    });
    let raised = change.raised.iter().map(move |fault| {
        (
            fault_severity(family, fault),
            text(format_args!("T{number} fault: {}", fault.name())),
        )
    });
    cleared_all.into_iter().chain(cleared).chain(raised)
}

/// The TCA9548A control byte a slot needs before its poll: `Ok(Some(mask))` to select its channel, `Ok(None)`
/// for a thruster wired directly (any selection will do), `Err(())` for a channel the mux does not have.
fn mux_mask(slot: &ThrusterSlot) -> Result<Option<u8>, ()> {
    match slot.mux_channel {
        Some(channel) if channel < MUX_CHANNELS => Ok(Some(1 << channel)),
        Some(_) => Err(()),
        None => Ok(None),
    }
}

/// Why a slot's poll did not happen or failed: the mux could not be set (the order was not delivered), or the
/// poll itself failed.
enum SlotError<E> {
    Mux,
    Poll(PollError<E>),
}

/// Select the slot's mux channel if needed.
///
/// `selected` is the control byte last written to the mux, None when unknown; it is forgotten after any error so
/// the next transfer writes it again.
async fn select<B: I2c>(bus: &mut B, slot: &ThrusterSlot, selected: &mut Option<u8>) -> Result<(), ()> {
    match mux_mask(slot)? {
        Some(mask) => select_channels(bus, mask, selected).await,
        None => Ok(()),
    }
}

/// Enable the TCA9548A channels that are the bits of `channels`, unless they are what `selected` says is enabled
/// (forgotten on an error, as [`select`]).
async fn select_channels<B: I2c>(bus: &mut B, channels: u8, selected: &mut Option<u8>) -> Result<(), ()> {
    if *selected != Some(channels) {
        *selected = None;
        bus.write(MUX_ADDRESS, &[channels]).await.map_err(|_| ())?;
        *selected = Some(channels);
    }
    Ok(())
}

/// Select the slot's mux channel if needed, then poll the thruster.
async fn poll_slot<B: I2c>(
    bus: &mut B,
    slot: &ThrusterSlot,
    selected: &mut Option<u8>,
    order: Order,
    form: Option<StatusForm>,
) -> Result<Polled, SlotError<B::Error>> {
    select(bus, slot, selected).await.map_err(|()| SlotError::Mux)?;
    let result = poll_thruster(bus, slot.family, order, form).await;
    result.map_err(|error| {
        *selected = None;
        SlotError::Poll(error)
    })
}

/// Each thruster's link health and fault watch, kept between cycles by the task of its bus. One for the whole table,
/// which the bus tasks share: a slot is only ever touched by its own bus's task, and the master keeps one copy
/// instead of one for each of its three buses (912 B of RAM each, counted twice: the node's future is built on the
/// stack before it moves into its task).
#[derive(Debug)]
pub(crate) struct Links([Cell<(ThrusterLink, FaultWatch)>; MAX_THRUSTERS]);

impl Links {
    /// Every thruster's link as `config` starts it.
    pub(crate) fn new(config: &PollConfig) -> Self {
        Self(core::array::from_fn(|_| {
            Cell::new((ThrusterLink::new(config), FaultWatch::new()))
        }))
    }
}

/// What one bus task keeps between cycles.
struct BusState<'a> {
    links: &'a Links,
    /// The mux control byte last written, None when unknown.
    mux: Option<u8>,
    /// The poll period: how late a delivery may come after a gap of the thruster's failsafe.
    period: Duration,
}

impl BusState<'_> {
    /// Poll every due thruster of bus `bus_index` once, in table order; `cycle` is the cycle's start. Returns
    /// how many were polled. `transfers` tells a thruster restarting into its update from one that fails.
    async fn cycle<B: I2c + BusRecovery>(
        &mut self,
        bus: &mut B,
        bus_index: u8,
        table: &[ThrusterSlot],
        cycle: Instant,
        shared: &Shared,
        transfers: Option<&Transfers>,
    ) -> usize {
        // STOP until the vehicle has published orders.
        let orders = shared.orders.try_get().unwrap_or([Order::STOP; MAX_THRUSTERS]);
        let mut polled = 0;
        for (index, slot) in table.iter().enumerate() {
            if slot.bus != bus_index {
                continue;
            }
            let (Some(entry), Some(order), Some(report)) =
                (self.links.0.get(index), orders.get(index), shared.thrusters.get(index))
            else {
                // Beyond MAX_THRUSTERS: nowhere to publish it.
                continue;
            };
            // Taken out for the poll and put back after it: only this task touches its slots.
            let (mut link, mut faults) = entry.get();
            let (link, faults) = (&mut link, &mut faults);
            if !link.due(cycle) {
                continue;
            }
            polled += 1;
            let result = poll_slot(bus, slot, &mut self.mux, *order, link.form()).await;
            // A status with an odd field still reports its faults.
            if let Ok(Polled {
                decoded: Decoded { warning: Some(_), .. },
                ..
            }) = result
            {
                link.on_odd_field();
            }
            let (failsafe, overcurrent) = match &result {
                Ok(polled) => (polled.link_failsafe, polled.overcurrent),
                Err(_) => (false, false),
            };
            let (change, outcome) = match result {
                Ok(polled) => (
                    link.on_result::<B::Error>(cycle, &Ok(polled)),
                    Outcome::Answered(polled.decoded.status),
                ),
                Err(SlotError::Poll(error)) => {
                    let outcome = Outcome::of_poll::<B::Error>(&Err(error));
                    (link.on_outcome(cycle, outcome), outcome)
                }
                Err(SlotError::Mux) => {
                    let outcome = Outcome::NoOrder(PollFailure::Mux);
                    (link.on_outcome(cycle, outcome), outcome)
                }
            };
            // A bad channel number in the table never reached the bus: nothing to recover.
            let on_bus = mux_mask(slot).is_ok();
            if let Some(failure) = outcome.failure()
                && failure.needs_recovery()
                && on_bus
            {
                self.mux = None;
                // Whether SDA came free or not, go on: the next transfer tells, and recovers again if needed.
                let _ = bus.recover().await;
                link.on_recovery();
            }
            report.sender().send(link.report());
            if let Some(change) = change {
                let answering = match change {
                    LinkChange::Online => Some(true),
                    LinkChange::Offline(_) => Some(false),
                    LinkChange::StatusLost(_) | LinkChange::StatusBack => None,
                };
                let restarting = u8::try_from(index)
                    .ok()
                    .zip(transfers)
                    .is_some_and(|(slot, transfers)| {
                        let restarting = transfers.with(|courier| {
                            // One that answers again is asked what it runs before the vehicle arms.
                            if let Some(answering) = answering {
                                courier.seen(slot, answering);
                            }
                            courier.restarting(slot)
                        });
                        transfers.publish(shared);
                        restarting
                    });
                let (severity, text) = link_text(index, change, restarting);
                shared.say(severity, text);
                let slot = u8::try_from(index).unwrap_or(u8::MAX);
                match change {
                    LinkChange::Online => shared.note(What::ThrusterBack(slot)),
                    LinkChange::Offline(_) => shared.note(What::ThrusterLost(slot)),
                    _ => {}
                }
            }
            // The status tells a SeaBotix thruster's failsafe stop (FAULT bit 5); the Legacy status has no bit for
            // it, so the master tells it from how long it could not deliver an order.
            let delivered = !matches!(outcome, Outcome::NoOrder(_));
            let late = THRUSTER_FAILSAFE.checked_add(self.period).unwrap_or(Duration::MAX);
            let silenced = link.on_delivery(cycle, delivered, slot.family, late);
            if silenced || (matches!(outcome, Outcome::Answered(_)) && link.on_link_failsafe(failsafe)) {
                let number = index.saturating_add(1);
                shared.say(
                    Severity::Warning,
                    text(format_args!("T{number} stopped: 1 s without a valid order")),
                );
            }
            if matches!(outcome, Outcome::Answered(_)) && link.on_overcurrent(overcurrent) {
                let number = index.saturating_add(1);
                shared.say(
                    Severity::Critical,
                    text(format_args!("T{number} stopped: overcurrent, off until a zero order")),
                );
            }
            if let Outcome::Answered(status) = outcome
                && let Some(change) = link.on_follow(cycle, *order, &status, failsafe || overcurrent)
            {
                let number = index.saturating_add(1);
                let (severity, text) = match change {
                    FollowChange::Lost => (
                        Severity::Warning,
                        text(format_args!("T{number} does not follow its order")),
                    ),
                    FollowChange::Regained => (Severity::Info, text(format_args!("T{number} follows its order again"))),
                };
                shared.say(severity, text);
            }
            if let Outcome::Answered(status) = outcome
                && let Some(change) = faults.update(status.faults())
            {
                for (severity, text) in fault_texts(index, slot.family, change) {
                    shared.say(severity, text);
                }
            }
            entry.set((*link, *faults));
        }
        polled
    }

    /// One exchange of the update on its way to a thruster of bus `bus_index`, if there is one; returns whether
    /// there was, and whether it was answered. A failed exchange is the courier's to retry; the bus is recovered as
    /// after a failed poll.
    ///
    /// An exchange the courier gives to several thrusters behind the bus's TCA9548A ([`courier::Exchange::with`]) is
    /// one write with all their channels enabled (the TCA9548A's control register takes any set of channels; a write
    /// to their family's address reaches each), then each reply read with its thruster's channel alone. The write's
    /// ACK is wired-AND, so one thruster that missed it hides behind the others': its own reply, read alone, tells.
    async fn carry<B: I2c + BusRecovery>(
        &mut self,
        bus: &mut B,
        bus_index: u8,
        table: &[ThrusterSlot],
        transfers: &Transfers,
        shared: &Shared,
    ) -> Option<bool> {
        let on_bus = |slot: u8| table.get(usize::from(slot)).is_some_and(|s| s.bus == bus_index);
        let behind_mux = |slot: u8| {
            table
                .get(usize::from(slot))
                .is_some_and(|s| s.bus == bus_index && matches!(mux_mask(s), Ok(Some(_))))
        };
        // Only the encoded command (then its reply) and a few bytes of the exchange are kept across the transfers:
        // the rest goes out of scope here.
        let (slot, sent, members, mut buffer, len) =
            transfers.next(on_bus, behind_mux, CAST_CHANNELS).and_then(|exchange| {
                let slot = table.get(usize::from(exchange.slot))?;
                let frame = exchange.frame.encode();
                let mut buffer = [0; tmc_proto::ext::MAX_FRAME_LEN];
                let len = frame.as_bytes().len();
                buffer.get_mut(..len)?.copy_from_slice(frame.as_bytes());
                Some((slot, exchange.sent(), exchange.slots(), buffer, len))
            })?;
        let address = slot.family.address();
        let mut out = |message| {
            let _ = shared.outbox.try_send(message);
        };
        let channels = members
            .clone()
            .filter_map(|member| table.get(usize::from(member)).and_then(|s| mux_mask(s).ok().flatten()))
            .fold(0u8, |channels, channel| channels | channel);
        let shared_write = channels.count_ones() > 1;
        let selected = if shared_write {
            select_channels(bus, channels, &mut self.mux).await
        } else {
            select(bus, slot, &mut self.mux).await
        };
        let written = match selected {
            Ok(()) => courier::send(bus, address, &buffer, len, &sent).await,
            Err(()) => Err(ExchangeError::Bus),
        };
        if written.is_err() {
            self.mux = None;
            let _ = bus.recover().await;
        }
        let mut answered = true;
        for member in members {
            let sent = Sent { slot: member, ..sent };
            // A shared write's replies are read each with its thruster's channel alone.
            let alone = match table.get(usize::from(member)) {
                Some(member) if shared_write => select(bus, member, &mut self.mux).await,
                Some(_) => Ok(()),
                None => Err(()),
            };
            let result = match (written, alone) {
                (Err(error), _) => Err(error),
                (Ok(()), Ok(())) => courier::read_reply(bus, address, &mut buffer, &sent).await,
                (Ok(()), Err(())) => Err(ExchangeError::Bus),
            };
            if written.is_ok() && result == Err(ExchangeError::Bus) {
                self.mux = None;
                let _ = bus.recover().await;
            }
            answered &= result.is_ok();
            if let Some(fetched) = transfers.done(sent, result, &mut out) {
                keep_post_mortem(shared, fetched);
            }
        }
        transfers.publish(shared);
        Some(answered)
    }

    /// The earliest retry of an offline thruster of the bus.
    fn next_retry(&self, bus_index: u8, table: &[ThrusterSlot]) -> Option<Instant> {
        table
            .iter()
            .zip(self.links.0.iter())
            .filter(|(slot, _)| slot.bus == bus_index)
            .filter_map(|(_, entry)| entry.get().0.retry_at())
            .min()
    }
}

/// Keep the post-mortem record fetched from a thruster, and tell a new one: the stop it made and where to read it.
fn keep_post_mortem(shared: &Shared, fetched: courier::PostMortem) {
    match shared.keep_post_mortem(fetched.slot, &fetched.record) {
        Ok(Some(record)) => crate::tell_stop(shared, Some(fetched.slot), &record),
        Ok(None) => {}
        Err(_) => {
            let who = u16::from(fetched.slot) + 1;
            shared.say(
                Severity::Warning,
                text(format_args!("T{who}: its post-mortem record does not check")),
            );
        }
    }
}

/// The poll cycle of a bus that carries an update while the vehicle is disarmed: every thruster still gets an
/// order and a status read more than 10 times a second (its failsafe acts after 1 s without an order), even when a
/// cycle runs over by an exchange or a page erase, and the rest of the bus carries the update.
pub(crate) const UPDATE_PERIOD: Duration = Duration::from_millis(60);

/// Whether the vehicle is armed (or has not said yet): update traffic then keeps to one exchange a cycle.
fn armed(shared: &Shared) -> bool {
    shared.vehicle.try_get().is_none_or(|vehicle| vehicle.armed)
}

/// Poll every thruster of `table` whose `bus` is `bus_index`, forever. The thruster's index in `table` is its
/// index in `shared.thrusters` and in the orders array.
///
/// Every `config.period` each due thruster of the bus is polled once, in table order, on a fixed schedule (like
/// embassy's `Ticker`; after an overrun the next cycle starts at once and the schedule restarts from there). With
/// a zero period the cycles run back to back, yielding between cycles so other tasks run, and sleeping until the
/// next retry when every thruster of the bus is offline. Each poll's report goes to `shared.thrusters[i]`; link
/// and fault changes go to the console as texts.
///
/// Its thrusters' link health is kept in `links`, which the other bus tasks may share. With `transfers`, each cycle
/// also carries the exchanges of an update image on its way to a thruster of the bus ([`crate::update::courier`]):
/// one while armed, and while disarmed as many as the rest of the cycle holds.
#[allow(
    clippy::too_many_arguments,
    reason = "the bus, its place, and what it shares with the other tasks"
)]
pub(crate) async fn bus_task<B>(
    bus: &mut B,
    bus_index: u8,
    table: &[ThrusterSlot],
    config: &PollConfig,
    shared: &Shared,
    links: &Links,
    transfers: Option<&Transfers>,
) -> !
where
    B: I2c + BusRecovery,
{
    let mut state = BusState {
        links,
        mux: None,
        period: config.period,
    };
    let back_to_back = config.period == Duration::from_ticks(0);
    let mut next = Instant::now();
    let mut period = config.period;
    loop {
        let polled = {
            let cycle = if back_to_back { Instant::now() } else { next };
            let polled = state.cycle(bus, bus_index, table, cycle, shared, transfers).await;
            let (mut carried, mut updating) = (0, false);
            if let Some(transfers) = transfers {
                // Disarmed with an update image on its way, as many exchanges as the cycle holds (the last may run
                // over it, and the next cycle starts late); otherwise (armed, cycles back to back, or only the
                // master's questions of what a thruster runs), one a cycle. One that fails is tried again at the
                // next cycle, not at once.
                updating = !back_to_back && !armed(shared) && transfers.with(|courier| courier.carrying());
                let more = || updating && Instant::now() < cycle + period;
                while let Some(answered) = state.carry(bus, bus_index, table, transfers, shared).await {
                    carried += 1;
                    if !answered || !more() {
                        break;
                    }
                }
            }
            // Then the polls slow down and leave the bus to the update.
            period = if updating && carried > 0 {
                config.period.max(UPDATE_PERIOD)
            } else {
                config.period
            };
            state.period = period;
            polled + carried
        };
        if back_to_back {
            if polled > 0 {
                yield_now().await;
            } else if let Some(at) = state.next_retry(bus_index, table) {
                Timer::at(at).await;
            } else {
                // No thruster on this bus.
                core::future::pending::<()>().await;
            }
        } else {
            next += period;
            next = next.max(Instant::now());
            Timer::at(next).await;
        }
    }
}
