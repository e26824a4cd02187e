//! Requests that make the vehicle send more than they cost, limited per requester, so that no one on the link can
//! fill the console's outbox and line with answers: a PARAM_REQUEST_LIST (2 payload bytes) is answered with every
//! PARAM_VALUE (25 bytes each), a MAV_CMD_REQUEST_MESSAGE with a COMMAND_ACK and the message (AUTOPILOT_VERSION
//! is 78 bytes), a MAVLink FTP ListDirectory with a directory entry. Unlimited, a flood of them from anyone on the
//! link, another system or another component of the operator's, keeps the outbox full: the operator's answers are
//! dropped, the vehicle task waits for room, the console stops reading behind it and the UART's 256-byte buffer
//! overruns, losing the operator's HEARTBEAT and MANUAL_CONTROL.
//!
//! Each requester (system and component) has an allowance of frames the vehicle sends it, [`BURST`] when full and
//! refilled at one frame every [`FRAME_COST`] (a token bucket, kept as the time at which it is full again: one
//! `Instant` a requester). A request whose answers do not fit what is left is dropped unanswered, as a frame lost
//! on the link is, and counted ([`crate::console::ConsoleCounters::rate_limited`]); a ground station asks again.
//! What a request costs is [`cost`].
//!
//! The numbers: [`BURST`] (80 frames) holds what a ground station asks at once when it connects (the parameter
//! list, now 64 frames, AUTOPILOT_VERSION and a few messages, or an SDK's ten REQUEST_MESSAGEs), and a listing of
//! the update directory (eight requests); one frame every 100 ms is a whole parameter list every 6.4 s, some
//! 370 bytes a second (500 signed), 3-4 % of the console's 115200 baud. [`REQUESTERS`] (4) requesters
//! are kept apart (the operator's ground station, a companion computer, a second station and one more); any
//! others share one more allowance, so that a flood from ever new system ids gets five allowances at most: some
//! 20 % of the line, which leaves the operator's own traffic and the telemetry (about 12 %) room.
//!
//! The operator's system (`SYSID_MYGCS`) reads files over MAVLink FTP from an allowance of its own, counted in
//! bytes: [`READ_RATE`] bytes a second, half the console's 115200-baud line, so that the black box (hundreds of
//! kilobytes) downloads in a minute or two rather than the quarter of an hour its share of frames would take
//! ([`Limiter::allow_read`]). Its clients ask for one reply at a time, so the allowance paces them without a loss
//! in the usual run; a flood that claims the operator's system id (a link without signing) gets that half of the
//! line, and the other half stays for the telemetry and the rest. A requester not
//! kept takes the place of one whose allowance is full (it has asked nothing for four seconds, so nothing of it is
//! lost), or, when it is of the operator's system (`SYSID_MYGCS`), that of another system, so that floods from
//! other systems never leave the operator's ground station to the shared allowance.

use embassy_time::{Duration, Instant};

use crate::params::LISTED_COUNT;
use crate::shared::{Command, Sender};

/// What one frame sent costs a requester's allowance: it refills at ten frames a second.
pub(crate) const FRAME_COST: Duration = Duration::from_millis(100);
/// The frames a full allowance holds.
pub const BURST: u32 = 80;
/// Requesters kept apart; the others share one allowance.
pub(crate) const REQUESTERS: usize = 4;
/// The bytes a second of the operator's file reads: half of what the console's 115200-baud line carries (11,520
/// bytes a second, ten bits a byte).
#[cfg(not(feature = "acceptance"))]
pub(crate) const READ_RATE: u32 = 5_760;
/// The bytes the operator's read allowance holds when full: sixteen 251-byte FTP replies.
#[cfg(not(feature = "acceptance"))]
pub(crate) const READ_BURST: u32 = 16 * 251;

/// The frames the vehicle sends for `command`: the parameter list's values, a parameter's value, a MISSION_COUNT or
/// MISSION_ACK,
/// a requested message and its COMMAND_ACK (a message it does not send: the COMMAND_ACK alone); 0 for commands answered with
/// at most one frame smaller than the request (a COMMAND_ACK for a COMMAND_LONG), or not at all.
pub(crate) const fn cost(command: &Command) -> u32 {
    match command {
        Command::ParamRequestList => LISTED_COUNT as u32,
        Command::ParamRequestRead { .. }
        | Command::MissionRequestList { .. }
        | Command::MissionClear { .. }
        | Command::MissionUpload { .. } => 1,
        Command::RequestMessage { message: Some(_), .. } => 2,
        Command::RequestMessage { message: None, .. } => 1,
        _ => 0,
    }
}

/// One requester's allowance.
#[derive(Debug, Clone, Copy)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
struct Allowance {
    /// Whose (none yet).
    who: Option<Sender>,
    /// When it is full again: at or before now, it is full.
    full_at: Instant,
}

/// The requesters' allowances (see the module documentation).
#[derive(Debug, Clone)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct Limiter {
    requesters: [Allowance; REQUESTERS],
    /// The allowance the requesters not kept share: when it is full again.
    others: Instant,
    /// The operator's file reads' allowance: when it is full again.
    #[cfg(not(feature = "acceptance"))]
    reads: Instant,
}

impl Default for Limiter {
    fn default() -> Self {
        Self::new()
    }
}

impl Limiter {
    /// Nobody has asked anything yet.
    pub(crate) const fn new() -> Self {
        Self {
            requesters: [Allowance {
                who: None,
                full_at: Instant::from_ticks(0),
            }; REQUESTERS],
            others: Instant::from_ticks(0),
            #[cfg(not(feature = "acceptance"))]
            reads: Instant::from_ticks(0),
        }
    }

    /// Whether the operator's system may have a file read's reply of `bytes` at `now` (taking them from its read
    /// allowance if so). The acceptance image serves no files.
    #[cfg(not(feature = "acceptance"))]
    pub(crate) fn allow_read(&mut self, bytes: u32, now: Instant) -> bool {
        let cost = |bytes: u32| Duration::from_micros(u64::from(bytes) * 1_000_000 / u64::from(READ_RATE));
        let after = self.reads.max(now) + cost(bytes);
        if after > now + cost(READ_BURST) {
            return false;
        }
        self.reads = after;
        true
    }

    /// Whether `from` may have the vehicle send `frames` frames at `now` (taking them from its allowance if so);
    /// `operator` is `SYSID_MYGCS`. Nothing that costs nothing is refused.
    pub(crate) fn allow(&mut self, from: Sender, frames: u32, operator: u8, now: Instant) -> bool {
        if frames == 0 {
            return true;
        }
        let full_at = match self.place(from, operator, now) {
            Some(allowance) => &mut allowance.full_at,
            None => &mut self.others,
        };
        let after = (*full_at).max(now) + FRAME_COST * frames;
        if after > now + FRAME_COST * BURST {
            return false;
        }
        *full_at = after;
        true
    }

    /// `from`'s allowance: its own, a free one or one that is full (whose requester has asked nothing for a
    /// while), or for the operator's system another system's; `None`: the shared one.
    fn place(&mut self, from: Sender, operator: u8, now: Instant) -> Option<&mut Allowance> {
        let requesters = &self.requesters;
        let at = requesters
            .iter()
            .position(|a| a.who == Some(from))
            .or_else(|| requesters.iter().position(|a| a.who.is_none() || a.full_at <= now))
            .or_else(|| {
                (from.system == operator)
                    .then(|| {
                        requesters
                            .iter()
                            .position(|a| a.who.is_some_and(|who| who.system != operator))
                    })
                    .flatten()
            })?;
        let allowance = self.requesters.get_mut(at)?;
        if allowance.who != Some(from) {
            *allowance = Allowance {
                who: Some(from),
                full_at: now,
            };
        }
        Some(allowance)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const fn sender(system: u8, component: u8) -> Sender {
        Sender { system, component }
    }

    const GCS: Sender = sender(255, 190);

    fn at(ms: u64) -> Instant {
        Instant::from_millis(ms)
    }

    /// How many requests of `frames` each `from` gets through at `now`, of `tries`.
    fn through(limiter: &mut Limiter, from: Sender, frames: u32, now: Instant, tries: u32) -> u32 {
        (0..tries).filter(|_| limiter.allow(from, frames, 255, now)).count() as u32
    }

    #[test]
    fn a_full_allowance_takes_a_burst_then_refills_at_ten_frames_a_second() {
        let mut limiter = Limiter::new();
        let list = cost(&Command::ParamRequestList);
        assert_eq!(list, 64);
        // A parameter list at once, with 16 frames to spare (AUTOPILOT_VERSION and a few messages), not a second.
        assert_eq!(through(&mut limiter, GCS, list, at(1000), 10), 1);
        assert_eq!(through(&mut limiter, GCS, 16, at(1000), 10), 1);
        // One more each 6.4 s.
        assert_eq!(through(&mut limiter, GCS, list, at(7399), 10), 0);
        assert_eq!(through(&mut limiter, GCS, list, at(7400), 10), 1);
        assert_eq!(through(&mut limiter, GCS, 1, at(7500), 10), 1);
        // Idle for eight seconds: full again.
        assert_eq!(through(&mut limiter, GCS, list, at(15_500), 10), 1);
        assert_eq!(through(&mut limiter, GCS, 16, at(15_500), 10), 1);
        // Sustained: 10 frames a second, whatever is asked.
        let mut sent = 0;
        for ms in (20_000..30_000).step_by(10) {
            sent += through(&mut limiter, GCS, 2, at(ms), 5) * 2;
        }
        assert!((100..=100 + BURST).contains(&sent), "{sent} frames in 10 s");
        // Commands answered with one small frame, or none, cost nothing.
        assert_eq!(cost(&Command::Heartbeat), 0);
        assert_eq!(cost(&Command::Arm(true)), 0);
        assert_eq!(through(&mut limiter, GCS, 0, at(30_000), 1000), 1000);
    }

    #[test]
    fn the_operators_reads_take_half_the_line() {
        let mut limiter = Limiter::new();
        // A burst of sixteen whole replies at once, not a seventeenth.
        assert_eq!((0..20).filter(|_| limiter.allow_read(251, at(1000))).count(), 16);
        // Sustained, one reply at a time as the clients ask: READ_RATE bytes a second.
        let mut bytes = 0;
        for ms in (2_000..12_000).step_by(5) {
            if limiter.allow_read(251, at(ms)) {
                bytes += 251;
            }
        }
        assert!((57_600..=57_600 + READ_BURST).contains(&bytes), "{bytes} bytes in 10 s");
        // The frames' allowances are apart: a parameter list still goes at once.
        assert!(limiter.allow(GCS, cost(&Command::ParamRequestList), 255, at(12_000)));
    }

    #[test]
    fn each_requester_has_its_own_and_others_share_one() {
        let mut limiter = Limiter::new();
        let now = at(500);
        // Four requesters, each its own allowance, the operator's station among them.
        for requester in [GCS, sender(255, 1), sender(77, 1), sender(77, 2)] {
            assert_eq!(through(&mut limiter, requester, 20, now, 10), 4, "{requester:?}");
        }
        // Any more share one: a flood from new ids gets one allowance more, no more.
        let shared: u32 = (0..50)
            .map(|n| through(&mut limiter, sender(100 + n, 1), 20, now, 10))
            .sum();
        assert_eq!(shared, 4);
        // The operator's station keeps its own, empty for now, and refills.
        assert_eq!(through(&mut limiter, GCS, 20, at(2500), 10), 1);
    }

    #[test]
    fn the_operators_station_is_never_left_to_the_shared_allowance() {
        let mut limiter = Limiter::new();
        let now = at(500);
        // Four other systems take every place, and keep asking.
        for system in 1..=4 {
            assert_eq!(through(&mut limiter, sender(system, 1), 20, now, 10), 4);
        }
        // The shared allowance drained by a fifth.
        assert_eq!(through(&mut limiter, sender(9, 1), 20, now, 10), 4);
        // The operator's station takes the place of another system's, with a full allowance.
        assert_eq!(through(&mut limiter, GCS, 20, now, 10), 4);
        // The system it displaced goes to the shared allowance, which is empty.
        assert_eq!(through(&mut limiter, sender(1, 1), 20, now, 10), 0);
        // A requester whose allowance is full gives its place up to a new one, losing nothing.
        let mut limiter = Limiter::new();
        for system in 1..=4 {
            assert_eq!(through(&mut limiter, sender(system, 1), 1, now, 1), 1);
        }
        assert_eq!(through(&mut limiter, sender(5, 1), 20, at(700), 10), 4);
        assert_eq!(
            through(&mut limiter, sender(6, 1), 20, at(700), 10),
            4,
            "another idle one's"
        );
    }
}
