//! The battery monitor: the BAT board's CAN frames (docs/interface.md) to a summary for telemetry and texts
//! for the console.
//!
//! What the console hears:
//! - Start-up report: on the first status frame (0x629) after the master powers up, every one of the 12 status
//!   bits in words, one STATUSTEXT each (the seed: "at start-up the monitor reports every bit's state in words").
//! - Change report: on each later status frame that differs from the last one, only the bits that switched.
//!   After a stale period the first status frame is compared with the last one known before it: a loose
//!   connector does not repeat all 12 lines, and a BAT board that restarted shows up as the bits that differ.
//! - BMS alarms (0x628) that appear (Warning) and clear (Info); alarms already set in the first BMS frame
//!   count as appearing.
//! - "BAT data stale" when no good BAT frame came for [`BatteryMonitor::STALE_AFTER`] (also when none came at
//!   all within that time of the monitor starting), and "BAT data resumed" on the next good frame.
//! - One frame that stops while the others still come goes stale on its own ("BAT status (0x629) stale"), and
//!   "... resumed" when it comes again; its values are unknown at the console meanwhile
//!   ([`BatterySummary::fresh_status`]). A frame never seen (a vehicle without a BMS board sends no 0x628) is
//!   never said stale. A frame that comes at or past its deadline before a tick has told the stale period says
//!   both: never "resumed" without "stale" before it.
//!
//! Texts are at most 50 bytes (STATUSTEXT): `BAT <name>=<0|1> <meaning>`, e.g. `BAT HSM_PG=1 HSM power good
//! (output stable)`. The meanings are bat-proto's words, shortened ("hot swap manager" to "HSM", the FLT pin
//! and firmware threshold sources in brackets) where the full form would not fit. Severity is Warning for a
//! fault bit that is set, for power good lost, for a BMS alarm that appears and for stale data; Info otherwise.
//!
//! Frames: the three BAT IDs (0x620 info, 0x628 BMS, 0x629 status) are decoded with bat-proto. A BAT-source ID
//! (0x620..=0x62F, iCub's class 6, source 2) that bat-proto does not know and a BAT frame with a length other than
//! 8 are counted in `errors` and change nothing else: they do not even keep the data fresh. A field out of range
//! (a charge above 100 %) is counted too, and reads as unknown, while the frame's other fields are taken. Once the
//! pack has reported a non-zero current (or temperature), a 0 in that field is zero rather than "not used".
//! Frames of other sources are normal on a shared bus and only counted as ignored.

use bat_proto::{BatteryInfo, BitReport, BmsAlarms, DcdcStatus, Frame, StatusBit};
use embassy_time::{Duration, Instant, Timer, with_deadline};

use crate::ports::{CanFrame, CanReceiver};
use crate::shared::{BatterySummary, Outgoing, Severity, Shared, Text, text};

/// What one good BAT frame means for the console.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) enum News {
    /// The first status since power-up: report every bit.
    StartUp(DcdcStatus),
    /// The status changed: report the bits that switched.
    Changed {
        /// The status before.
        previous: DcdcStatus,
        /// The status now.
        current: DcdcStatus,
    },
    /// BMS alarms appeared or cleared.
    Alarms {
        /// Alarms newly set.
        raised: BmsAlarms,
        /// Alarms newly clear.
        cleared: BmsAlarms,
    },
}

/// The BAT frames whose freshness is told one by one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) enum FrameKind {
    /// 0x620: voltage, charge, current, temperature.
    Info,
    /// 0x629: the DCDC status word.
    Status,
    /// 0x628: the BMS alarms.
    Alarms,
}

impl FrameKind {
    const ALL: [FrameKind; 3] = [FrameKind::Info, FrameKind::Status, FrameKind::Alarms];

    const fn bit(self) -> u8 {
        match self {
            FrameKind::Info => 1,
            FrameKind::Status => 2,
            FrameKind::Alarms => 4,
        }
    }

    /// What is said when frames of this kind go stale, or come again.
    const fn words(self, stale: bool) -> &'static str {
        match (self, stale) {
            (FrameKind::Info, true) => "BAT info (0x620) stale",
            (FrameKind::Info, false) => "BAT info (0x620) resumed",
            (FrameKind::Status, true) => "BAT status (0x629) stale",
            (FrameKind::Status, false) => "BAT status (0x629) resumed",
            (FrameKind::Alarms, true) => "BMS alarms (0x628) stale",
            (FrameKind::Alarms, false) => "BMS alarms (0x628) resumed",
        }
    }
}

/// What is said when the whole data goes stale, or comes again: `frame` None; else that frame's words.
const fn freshness_words(frame: Option<FrameKind>, stale: bool) -> &'static str {
    match (frame, stale) {
        (None, true) => "BAT data stale",
        (None, false) => "BAT data resumed",
        (Some(kind), stale) => kind.words(stale),
    }
}

/// A set of [`FrameKind`]s.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct Frames(u8);

impl Frames {
    /// Whether `kind` is in the set.
    pub(crate) const fn contains(self, kind: FrameKind) -> bool {
        self.0 & kind.bit() != 0
    }

    fn insert(&mut self, kind: FrameKind) {
        self.0 |= kind.bit();
    }
}

/// What a frame or the passing of time means for the console.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) enum Report {
    /// Nothing to say.
    Nothing,
    /// A good frame with news.
    News(News),
    /// No good BAT frame for [`BatteryMonitor::STALE_AFTER`]: the data went stale (said once per stale period).
    Stale,
    /// These frames went stale while other BAT frames still come (each said once per its stale period).
    FramesStale(Frames),
    /// A good frame after a stale period: of the whole data (`frame` None) or of its own kind, with the frame's
    /// own news if any. `untold`: the stale period had not been said (the frame came at or past the deadline
    /// before a tick), so it is said first.
    Resumed {
        /// Whose stale period ends: the data's (None) or this frame kind's.
        frame: Option<FrameKind>,
        /// The stale period is said first.
        untold: bool,
        /// The frame's own news.
        news: Option<News>,
    },
}

/// Most texts one report gives: "stale" and "resumed" together, and the 12 bits of a start-up report.
#[cfg(test)]
pub(crate) const MAX_REPORT_TEXTS: usize = 14;

impl Report {
    /// The STATUSTEXTs for the console, in order, each formatted as it is taken: a task sends them one by one
    /// without a buffer, and formats each once.
    pub(crate) fn texts(self) -> impl Iterator<Item = (Severity, Text)> {
        let stale = |frame| Some((Severity::Warning, freshness_words(frame, true)));
        let (first, news) = match self {
            Self::Nothing => ([None; 3], None),
            Self::News(news) => ([None; 3], Some(news)),
            Self::Stale => ([stale(None), None, None], None),
            Self::FramesStale(frames) => (
                FrameKind::ALL.map(|kind| frames.contains(kind).then_some((Severity::Warning, kind.words(true)))),
                None,
            ),
            Self::Resumed { frame, untold, news } => (
                [
                    if untold { stale(frame) } else { None },
                    Some((Severity::Info, freshness_words(frame, false))),
                    None,
                ],
                news,
            ),
        };
        first
            .into_iter()
            .flatten()
            .map(|(severity, words)| (severity, format(format_args!("{words}"))))
            .chain(news.into_iter().flat_map(News::texts))
    }
}

impl News {
    fn texts(self) -> impl Iterator<Item = (Severity, Text)> {
        let (start_up, changed, alarms) = match self {
            Self::StartUp(status) => (Some(status), None, None),
            Self::Changed { previous, current } => (None, Some((previous, current)), None),
            Self::Alarms { raised, cleared } => (None, None, Some((raised, cleared))),
        };
        let bits = start_up
            .into_iter()
            .flat_map(DcdcStatus::describe_all)
            .chain(
                changed
                    .into_iter()
                    .flat_map(|(previous, current)| current.describe_changes(previous)),
            )
            .map(|report| (bit_severity(report), bit_text(report)));
        let (raised, cleared) = alarms.unwrap_or((BmsAlarms::NONE, BmsAlarms::NONE));
        let raised = raised.iter().map(|alarm| {
            let text = format(format_args!("BAT BMS alarm: {}", alarm.name()));
            (Severity::Warning, text)
        });
        let cleared = cleared.iter().map(|alarm| {
            let text = format(format_args!("BAT BMS alarm cleared: {}", alarm.name()));
            (Severity::Info, text)
        });
        bits.chain(raised).chain(cleared)
    }
}

fn bit_severity(report: BitReport) -> Severity {
    if bit_is_warning(report) {
        Severity::Warning
    } else {
        Severity::Info
    }
}

/// A set fault bit, or power good lost.
fn bit_is_warning(report: BitReport) -> bool {
    if report.bit == StatusBit::HsmPowerGood {
        !report.set
    } else {
        report.bit.is_fault() && report.set
    }
}

/// `BAT <name>=<0|1> <meaning>`, at most 50 bytes for every bit and state.
pub(crate) fn bit_text(report: BitReport) -> Text {
    format(format_args!(
        "BAT {}={} {}",
        report.bit.name(),
        u8::from(report.set),
        short_meaning(report.bit, report.set)
    ))
}

#[cfg(test)]
std::thread_local! {
    /// Texts formatted on this thread (host tests: a report's work is one formatting per text).
    static FORMATTED: core::cell::Cell<usize> = const { core::cell::Cell::new(0) };
}

/// Format one text of the monitor.
fn format(args: core::fmt::Arguments<'_>) -> Text {
    #[cfg(test)]
    FORMATTED.with(|count| count.set(count.get() + 1));
    text(args)
}

/// bat-proto's meaning, shortened where `BAT <name>=<state> <meaning>` would exceed 50 bytes.
fn short_meaning(bit: StatusBit, set: bool) -> &'static str {
    match (bit, set) {
        (StatusBit::HsmBroken, true) => "HSM MOSFETs probably damaged",
        (StatusBit::HsmFault, true) => "HSM overcurrent / overvoltage fault",
        (StatusBit::HsmPowerGood, true) => "HSM power good (output stable)",
        (StatusBit::HsmHwFault, true) => "HSM overcurrent fault (FLT pin)",
        (StatusBit::HsmSwFault, true) => "HSM overcurrent fault (firmware)",
        _ => bit.meaning(set),
    }
}

/// IDs of the BAT board's source (iCub class 6, source 2): 0x620..=0x62F.
const BAT_SOURCE: core::ops::RangeInclusive<u16> = 0x620..=0x62F;

/// One frame kind's freshness.
#[derive(Debug, Clone, Copy, Default)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
struct Freshness {
    /// When the last good frame of the kind came.
    last: Option<Instant>,
    /// When its stale period counts from: its last frame, or the data's resumption when that came later (a
    /// frame kind that does not come back with the others is told stale a period after the others resumed).
    counts_from: Option<Instant>,
    /// Its stale period has been said (or covered by "BAT data stale").
    told: bool,
}

impl Freshness {
    /// When it goes stale, if it is still to be told: never for a kind never seen.
    fn deadline(&self) -> Option<Instant> {
        if self.told || self.last.is_none() {
            return None;
        }
        self.counts_from
            .map(|from| from.saturating_add(BatteryMonitor::FRAME_STALE_AFTER))
    }
}

/// The monitor's state machine (pure, explicit time).
#[derive(Debug, Clone, Default)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct BatteryMonitor {
    info: Option<BatteryInfo>,
    status: Option<DcdcStatus>,
    alarms: Option<BmsAlarms>,
    /// When the last good BAT frame came.
    last_frame: Option<Instant>,
    /// Each frame kind's freshness, in [`FrameKind::ALL`]'s order: info (0x620), status (0x629), BMS alarms
    /// (0x628).
    kinds: [Freshness; 3],
    /// When the monitor was first used: staleness counts from here until a frame comes.
    started: Option<Instant>,
    /// "Stale" has been reported and no good frame came since.
    stale_reported: bool,
    /// The pack has reported a non-zero current, or temperature: its firmware fills those bytes of 0x620.
    reports_current: bool,
    reports_temperature: bool,
    frames: u32,
    errors: u32,
    ignored: u32,
}

impl BatteryMonitor {
    /// No good BAT frame for this long: the data is stale. The BAT sends each ID every 200 ms (docs/decisions.md D26).
    pub(crate) const STALE_AFTER: Duration = Duration::from_secs(1);

    /// No frame of one kind for this long while the others come: that kind is stale on its own. One BAT cycle
    /// (200 ms, each ID's period) longer than [`Self::STALE_AFTER`], so that a bus that stops whole, whose ID last
    /// sent goes quiet 100 ms after the other, is told once, as the data.
    pub(crate) const FRAME_STALE_AFTER: Duration = Duration::from_millis(1200);

    /// Nothing known yet.
    pub(crate) fn new() -> Self {
        Self::default()
    }

    /// One frame at `now`. Returns what to report.
    pub(crate) fn on_frame(&mut self, now: Instant, frame: &CanFrame) -> Report {
        self.start(now);
        if !BAT_SOURCE.contains(&frame.id) {
            self.ignored = self.ignored.wrapping_add(1);
            return Report::Nothing;
        }
        let decoded = frame.payload().map(|data| Frame::decode(frame.id, data));
        let Some(Ok(decoded)) = decoded else {
            self.errors = self.errors.wrapping_add(1);
            return Report::Nothing;
        };
        // A field out of range is counted; the frame's other fields are taken.
        if frame.id == bat_proto::INFO_ID && frame.payload().and_then(BatteryInfo::charge_out_of_range).is_some() {
            self.errors = self.errors.wrapping_add(1);
        }
        // A gap that went unnoticed (no tick at or after its deadline) is a stale period too, said now.
        let untold =
            !self.stale_reported && self.last_frame.is_some() && self.data_deadline().is_some_and(|at| now >= at);
        let resumed = self.stale_reported || untold;
        self.stale_reported = false;
        self.last_frame = Some(now);
        self.frames = self.frames.wrapping_add(1);
        let kind = match decoded {
            Frame::Info(_) => FrameKind::Info,
            Frame::Status(_) => FrameKind::Status,
            Frame::Bms(_) => FrameKind::Alarms,
        };
        let own = self.kinds.get(kind_index(kind)).copied().unwrap_or_default();
        let own_untold = own.deadline().is_some_and(|at| now >= at);
        let own_resumed = own.told || own_untold;
        if resumed {
            // Every kind seen before counts its stale period afresh from now; this one has just come.
            for freshness in &mut self.kinds {
                freshness.told = false;
                freshness.counts_from = Some(now);
            }
        }
        if let Some(freshness) = self.kinds.get_mut(kind_index(kind)) {
            *freshness = Freshness {
                last: Some(now),
                counts_from: Some(now),
                told: false,
            };
        }
        let news = match decoded {
            Frame::Info(mut info) => {
                // A pack that has reported a current or a temperature fills that field: a 0 from it is zero, not
                // "not used" (bat-proto's `BatteryInfo`).
                self.reports_current |= info.current_deciamps.is_some();
                self.reports_temperature |= info.temperature_decicelsius.is_some();
                if self.reports_current {
                    info.current_deciamps.get_or_insert(0);
                }
                if self.reports_temperature {
                    info.temperature_decicelsius.get_or_insert(0);
                }
                self.info = Some(info);
                None
            }
            Frame::Status(current) => match self.status.replace(current) {
                None => Some(News::StartUp(current)),
                Some(previous) if previous != current => Some(News::Changed { previous, current }),
                Some(_) => None,
            },
            Frame::Bms(current) => {
                let previous = self.alarms.replace(current).unwrap_or(BmsAlarms::NONE);
                let raised = BmsAlarms::from_bits_truncate(current.bits() & !previous.bits());
                let cleared = BmsAlarms::from_bits_truncate(previous.bits() & !current.bits());
                (!raised.is_empty() || !cleared.is_empty()).then_some(News::Alarms { raised, cleared })
            }
        };
        match (resumed, own_resumed, news) {
            (true, _, news) => Report::Resumed {
                frame: None,
                untold,
                news,
            },
            (false, true, news) => Report::Resumed {
                frame: Some(kind),
                untold: own_untold,
                news,
            },
            (false, false, Some(news)) => Report::News(news),
            (false, false, None) => Report::Nothing,
        }
    }

    /// The passing of time at `now`: reports [`Report::Stale`] once when no good frame came for
    /// [`Self::STALE_AFTER`] (counted from the first use of the monitor when none came at all), which covers every
    /// frame kind; else [`Report::FramesStale`] once for the kinds seen before that have not come for as long.
    pub(crate) fn on_tick(&mut self, now: Instant) -> Report {
        self.start(now);
        if self.data_deadline().is_some_and(|at| now >= at) {
            self.stale_reported = true;
            for freshness in &mut self.kinds {
                freshness.told = true;
            }
            return Report::Stale;
        }
        let mut gone = Frames::default();
        for (kind, freshness) in FrameKind::ALL.into_iter().zip(self.kinds.iter_mut()) {
            if freshness.deadline().is_some_and(|at| now >= at) {
                freshness.told = true;
                gone.insert(kind);
            }
        }
        if gone == Frames::default() {
            Report::Nothing
        } else {
            Report::FramesStale(gone)
        }
    }

    /// A failed receive: counted in `errors`.
    pub(crate) fn on_receive_error(&mut self) {
        self.errors = self.errors.wrapping_add(1);
    }

    /// When [`Self::on_tick`] will next report the data or a frame kind stale, if that is still to come.
    pub(crate) fn stale_at(&self) -> Option<Instant> {
        self.kinds
            .iter()
            .filter_map(Freshness::deadline)
            .chain(self.data_deadline())
            .min()
    }

    /// When the whole data goes stale, if that is still to be told.
    fn data_deadline(&self) -> Option<Instant> {
        if self.stale_reported {
            return None;
        }
        self.last_frame
            .or(self.started)
            .map(|from| from.saturating_add(Self::STALE_AFTER))
    }

    /// The summary at `now`: stale when no good BAT frame for [`Self::STALE_AFTER`], or none yet, and each value
    /// stale with the data or when its own frame has not come for [`Self::FRAME_STALE_AFTER`] (the BAT sends each
    /// ID on its own: one can stop while the others flow).
    pub(crate) fn summary(&self, now: Instant) -> BatterySummary {
        let silent =
            |last: Option<Instant>, limit| last.is_none_or(|last| now.saturating_duration_since(last) >= limit);
        let stale = silent(self.last_frame, Self::STALE_AFTER);
        let kind_stale = |kind| stale || silent(self.last(kind), Self::FRAME_STALE_AFTER);
        BatterySummary {
            info: self.info,
            status: self.status,
            alarms: self.alarms,
            stale,
            info_stale: kind_stale(FrameKind::Info),
            status_stale: kind_stale(FrameKind::Status),
            alarms_stale: kind_stale(FrameKind::Alarms),
            frames: self.frames,
            errors: self.errors,
        }
    }

    /// When the last good frame of `kind` came.
    fn last(&self, kind: FrameKind) -> Option<Instant> {
        self.kinds.get(kind_index(kind)).and_then(|freshness| freshness.last)
    }

    /// Frames of other sources seen on the bus.
    #[cfg(test)]
    pub(crate) fn ignored(&self) -> u32 {
        self.ignored
    }

    fn start(&mut self, now: Instant) {
        if self.started.is_none() {
            self.started = Some(now);
        }
    }
}

/// Where `kind` is in [`FrameKind::ALL`] and the monitor's freshness array.
const fn kind_index(kind: FrameKind) -> usize {
    match kind {
        FrameKind::Info => 0,
        FrameKind::Status => 1,
        FrameKind::Alarms => 2,
    }
}

/// How often the summary is published when nothing else happens.
pub(crate) const PUBLISH_PERIOD: Duration = Duration::from_secs(1);

/// How long one report's texts may wait for room in the outbox before the rest are dropped: the console
/// drains it, and a silent console must not stop the monitor.
pub(crate) const TEXT_DEADLINE: Duration = Duration::from_millis(100);

/// After a receive error, wait this long before the next receive, so a bus that keeps failing at once cannot
/// starve the other tasks.
pub(crate) const ERROR_BACKOFF: Duration = Duration::from_millis(10);

/// Receive frames forever; publish the summary at 1 Hz and on each report; queue the reports' texts.
pub(crate) async fn can_task<C: CanReceiver>(can: &mut C, shared: &Shared) -> ! {
    let publisher = shared.battery.sender();
    let mut monitor = BatteryMonitor::new();
    let mut next_publish = Instant::now();
    loop {
        let now = Instant::now();
        let report = monitor.on_tick(now);
        if report != Report::Nothing || now >= next_publish {
            publisher.send(monitor.summary(now));
        }
        if now >= next_publish {
            next_publish = next_publish.saturating_add(PUBLISH_PERIOD);
            if next_publish <= now {
                // Fell behind (a long stall): keep the rhythm from now rather than catching up in a burst.
                next_publish = now.saturating_add(PUBLISH_PERIOD);
            }
        }
        say(shared, &report, now).await;

        let wake = monitor.stale_at().map_or(next_publish, |at| at.min(next_publish));
        match with_deadline(wake, can.receive()).await {
            Ok(Ok(frame)) => {
                let now = Instant::now();
                let report = monitor.on_frame(now, &frame);
                if report != Report::Nothing {
                    publisher.send(monitor.summary(now));
                    say(shared, &report, now).await;
                }
            }
            Ok(Err(_)) => {
                monitor.on_receive_error();
                Timer::after(ERROR_BACKOFF).await;
            }
            Err(_timeout) => {}
        }
    }
}

/// Queue a report's texts, waiting at most [`TEXT_DEADLINE`] in all for room.
async fn say(shared: &Shared, report: &Report, now: Instant) {
    let deadline = now.saturating_add(TEXT_DEADLINE);
    for (severity, text) in report.texts() {
        if with_deadline(deadline, shared.outbox.send(Outgoing::Text(severity, text)))
            .await
            .is_err()
        {
            break;
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use bat_proto::{BMS_ID, INFO_ID, STATUS_ID};
    use embassy_futures::block_on;
    use embassy_futures::select::{Either, select};
    use lbv_sim::Queue;

    /// Let virtual time pass in 1 ms steps, giving every task its turn at each step.
    pub(crate) async fn elapse(duration: Duration) {
        lbv_sim::clock::elapse(duration, Duration::from_millis(1), 8).await;
    }

    fn t(ms: u64) -> Instant {
        Instant::from_millis(ms)
    }

    fn can(id: u16, data: [u8; 8]) -> CanFrame {
        CanFrame { id, len: 8, data }
    }

    fn bat(frame: Frame) -> CanFrame {
        let (id, data) = frame.encode();
        can(id, data)
    }

    fn status(word: u16) -> CanFrame {
        bat(Frame::Status(DcdcStatus::from_word(word)))
    }

    fn bms(alarms: BmsAlarms) -> CanFrame {
        bat(Frame::Bms(alarms))
    }

    fn info(decivolts: u16, charge: u8) -> CanFrame {
        bat(Frame::Info(BatteryInfo {
            voltage_decivolts: decivolts,
            charge_percent: Some(charge),
            ..BatteryInfo::default()
        }))
    }

    fn texts(report: &Report) -> Vec<(Severity, String)> {
        report
            .texts()
            .map(|(severity, text)| (severity, text.to_string()))
            .collect()
    }

    #[test]
    fn every_bit_text_fits_untruncated_and_names_the_bit() {
        for bit in StatusBit::ALL {
            for set in [false, true] {
                let report = BitReport { bit, set };
                let full = format!("BAT {}={} {}", bit.name(), u8::from(set), short_meaning(bit, set));
                assert!(full.len() <= 50, "{full} is {} bytes", full.len());
                assert_eq!(bit_text(report).as_str(), full);
            }
        }
    }

    #[test]
    fn start_up_report_gives_all_12_bits_in_words() {
        let mut monitor = BatteryMonitor::new();
        // The seed's example: 172 = HSM_PG, HSM, V12motor, V12board.
        let report = monitor.on_frame(t(0), &status(172));
        assert_eq!(report, Report::News(News::StartUp(DcdcStatus::from_word(172))));
        let lines = texts(&report);
        assert_eq!(
            lines,
            [
                (Severity::Info, "BAT HSM_broken=0 normal"),
                (Severity::Info, "BAT HSM_F=0 normal"),
                (Severity::Info, "BAT HSM_PG=1 HSM power good (output stable)"),
                (Severity::Info, "BAT HSM=1 hot swap manager on"),
                (Severity::Info, "BAT V12motor_F=0 normal"),
                (Severity::Info, "BAT V12motor=1 12 V motor regulator on"),
                (Severity::Info, "BAT V12board_F=0 normal"),
                (Severity::Info, "BAT V12board=1 12 V board regulator on"),
                (Severity::Info, "BAT PB2_restart=0 stable operation"),
                (Severity::Info, "BAT PB1_restart=0 stable operation"),
                (Severity::Info, "BAT HSM_HW_F=0 no fault"),
                (Severity::Info, "BAT HSM_SW_F=0 no fault"),
            ]
            .map(|(severity, text)| (severity, text.to_string()))
        );
        assert_eq!(
            report.texts().nth(2).map(|(_, text)| text.to_string()),
            Some(lines[2].1.clone())
        );
        assert_eq!(report.texts().nth(12), None);
        // Every bit set: the faults are warnings, the longest texts still fit.
        let mut monitor = BatteryMonitor::new();
        let report = monitor.on_frame(t(0), &status(0x0FFF));
        let lines = texts(&report);
        assert_eq!(lines.len(), 12);
        assert!(
            lines
                .iter()
                .all(|(_, text)| text.len() <= 50 && text.ends_with(|c: char| c != ' '))
        );
        let warnings: Vec<&str> = lines
            .iter()
            .filter(|(severity, _)| *severity == Severity::Warning)
            .map(|(_, text)| text.as_str())
            .collect();
        assert_eq!(
            warnings,
            [
                "BAT HSM_broken=1 HSM MOSFETs probably damaged",
                "BAT HSM_F=1 HSM overcurrent / overvoltage fault",
                "BAT V12motor_F=1 12 V motor regulator overcurrent",
                "BAT V12board_F=1 12 V board regulator overcurrent",
                "BAT HSM_HW_F=1 HSM overcurrent fault (FLT pin)",
                "BAT HSM_SW_F=1 HSM overcurrent fault (firmware)",
            ]
        );
    }

    #[test]
    fn change_report_names_only_the_switched_bits() {
        let mut monitor = BatteryMonitor::new();
        monitor.on_frame(t(0), &status(172));
        // The same status again: nothing.
        assert_eq!(monitor.on_frame(t(100), &status(172)), Report::Nothing);
        // Only bits 10 and 11 switch on: named, not "no faults".
        let report = monitor.on_frame(t(200), &status(172 | 0x0C00));
        assert_eq!(
            report,
            Report::News(News::Changed {
                previous: DcdcStatus::from_word(172),
                current: DcdcStatus::from_word(172 | 0x0C00)
            })
        );
        assert_eq!(
            texts(&report),
            [
                (
                    Severity::Warning,
                    "BAT HSM_HW_F=1 HSM overcurrent fault (FLT pin)".to_string()
                ),
                (
                    Severity::Warning,
                    "BAT HSM_SW_F=1 HSM overcurrent fault (firmware)".to_string()
                ),
            ]
        );
        // Bit 11 clears and power good is lost.
        let report = monitor.on_frame(t(300), &status((172 | 0x0400) & !0x0004));
        assert_eq!(
            texts(&report),
            [
                (
                    Severity::Warning,
                    "BAT HSM_PG=0 output voltage not guaranteed".to_string()
                ),
                (Severity::Info, "BAT HSM_SW_F=0 no fault".to_string()),
            ]
        );
        assert_eq!(monitor.summary(t(300)).status, Some(DcdcStatus::from_word(0x04A8)));
    }

    #[test]
    fn each_value_goes_stale_with_its_own_frame() {
        let mut monitor = BatteryMonitor::new();
        let fresh = |s: &BatterySummary| (s.stale, s.info_stale, s.status_stale, s.alarms_stale);
        assert_eq!(fresh(&monitor.summary(t(0))), (true, true, true, true), "none yet");
        monitor.on_frame(t(0), &status(172));
        monitor.on_frame(t(0), &bms(BmsAlarms::NONE));
        // 0x629 stops; 0x620 goes on every 200 ms.
        for ms in (0..=5000).step_by(200) {
            monitor.on_frame(t(ms), &info(420, 80));
        }
        let summary = monitor.summary(t(5000));
        assert_eq!(
            fresh(&summary),
            (false, false, true, true),
            "the status 172 of 5 s ago is stale"
        );
        assert_eq!(summary.status, Some(DcdcStatus::from_word(172)), "kept, marked stale");
        monitor.on_frame(t(5100), &status(172));
        assert_eq!(fresh(&monitor.summary(t(5100))), (false, false, false, true));
    }

    #[test]
    fn staleness_at_exactly_one_second_and_resumption() {
        let mut monitor = BatteryMonitor::new();
        assert!(monitor.summary(t(0)).stale, "stale until a frame comes");
        monitor.on_frame(t(0), &status(172));
        monitor.on_frame(t(10), &info(420, 80));
        assert!(!monitor.summary(t(10)).stale);
        assert_eq!(monitor.stale_at(), Some(t(1010)));
        assert_eq!(monitor.on_tick(t(1009)), Report::Nothing);
        assert!(!monitor.summary(t(1009)).stale);
        assert_eq!(monitor.on_tick(t(1010)), Report::Stale);
        assert!(monitor.summary(t(1010)).stale);
        assert_eq!(
            texts(&Report::Stale),
            [(Severity::Warning, "BAT data stale".to_string())]
        );
        // Said once.
        assert_eq!(monitor.on_tick(t(1500)), Report::Nothing);
        assert_eq!(monitor.on_tick(t(5000)), Report::Nothing);
        assert_eq!(monitor.stale_at(), None);
        // The values are kept while stale.
        let summary = monitor.summary(t(5000));
        assert_eq!(summary.info.map(|info| info.voltage_decivolts), Some(420));
        assert_eq!(summary.status, Some(DcdcStatus::from_word(172)));
        // Resumption with an info frame: no other news.
        let report = monitor.on_frame(t(5100), &info(419, 79));
        assert_eq!(
            report,
            Report::Resumed {
                frame: None,
                untold: false,
                news: None
            }
        );
        assert_eq!(texts(&report), [(Severity::Info, "BAT data resumed".to_string())]);
        assert!(!monitor.summary(t(5100)).stale);
        assert_eq!(monitor.stale_at(), Some(t(6100)));
        // Stale again; the status that resumes is compared with the last one known, not reported in full.
        assert_eq!(monitor.on_tick(t(6100)), Report::Stale);
        let report = monitor.on_frame(t(7000), &status(172 | 0x0001));
        assert_eq!(
            texts(&report),
            [
                (Severity::Info, "BAT data resumed".to_string()),
                (
                    Severity::Warning,
                    "BAT HSM_broken=1 HSM MOSFETs probably damaged".to_string()
                ),
            ]
        );
    }

    fn formatted() -> usize {
        FORMATTED.with(|count| count.replace(0))
    }

    #[test]
    fn each_text_of_a_report_is_formatted_once() {
        // The longest report: stale and resumed, then the start-up report of every bit, 14 texts. Taking them one by one
        // formats one each, so the task's work grows with the texts, not with their square.
        let report = Report::Resumed {
            frame: None,
            untold: true,
            news: Some(News::StartUp(DcdcStatus::from_word(0x0FFF))),
        };
        formatted();
        let mut taken = report.texts();
        for n in 1..=MAX_REPORT_TEXTS {
            assert!(taken.next().is_some(), "text {n}");
            assert_eq!(formatted(), 1, "text {n}");
        }
        assert!(taken.next().is_none());
        assert_eq!(formatted(), 0);

        // The task's path: every text queued for the console, each formatted once.
        let _clock = lbv_sim::clock::take();
        let shared = Shared::new();
        block_on(say(&shared, &report, Instant::now()));
        assert_eq!(shared.outbox.len(), MAX_REPORT_TEXTS);
        assert_eq!(formatted(), MAX_REPORT_TEXTS);

        // A change report and an alarm report likewise.
        let changed = Report::News(News::Changed {
            previous: DcdcStatus::from_word(0),
            current: DcdcStatus::from_word(0x0C01),
        });
        assert_eq!(changed.texts().count(), 3);
        assert_eq!(formatted(), 3);
        let alarms = Report::News(News::Alarms {
            raised: BmsAlarms::LOW_VOLTAGE | BmsAlarms::HIGH_TEMPERATURE,
            cleared: BmsAlarms::LOW_CHARGE,
        });
        assert_eq!(alarms.texts().count(), 3);
        assert_eq!(formatted(), 3);
    }

    #[test]
    fn a_frame_at_its_deadline_before_any_tick_says_stale_then_resumed() {
        let mut monitor = BatteryMonitor::new();
        monitor.on_frame(t(0), &info(420, 80));
        assert_eq!(monitor.on_frame(t(999), &info(420, 80)), Report::Nothing);
        let report = monitor.on_frame(t(1999), &info(420, 80));
        assert_eq!(
            report,
            Report::Resumed {
                frame: None,
                untold: true,
                news: None
            }
        );
        assert_eq!(
            texts(&report),
            [
                (Severity::Warning, "BAT data stale".to_string()),
                (Severity::Info, "BAT data resumed".to_string())
            ]
        );
        // One kind likewise, while the others come.
        monitor.on_frame(t(2000), &status(172));
        for ms in (2100..=3200).step_by(100) {
            assert_eq!(monitor.on_frame(t(ms), &info(420, 80)), Report::Nothing, "{ms}");
        }
        let report = monitor.on_frame(t(3200), &status(172));
        assert_eq!(
            texts(&report),
            [
                (Severity::Warning, "BAT status (0x629) stale".to_string()),
                (Severity::Info, "BAT status (0x629) resumed".to_string())
            ]
        );
    }

    #[test]
    fn one_frame_that_stops_goes_stale_on_its_own_and_its_values_go_unknown() {
        let mut monitor = BatteryMonitor::new();
        // A vehicle without a BMS board: 0x628 never comes and is never said stale.
        monitor.on_frame(t(0), &status(172 | 0x0002));
        monitor.on_frame(t(100), &info(420, 80));
        let mut said = Vec::new();
        // 0x629 stops after its first frame; 0x620 goes on every 200 ms for 5 s.
        let mut ms = 100;
        while ms < 5_000 {
            ms += 10;
            if ms % 200 == 100 {
                said.extend(texts(&monitor.on_frame(t(ms), &info(420, 80))));
            }
            if monitor.stale_at().is_some_and(|at| at <= t(ms)) {
                said.extend(texts(&monitor.on_tick(t(ms))));
            }
            if ms == 1_190 {
                let summary = monitor.summary(t(ms));
                assert!(
                    !summary.status_stale && summary.fresh_status().is_some(),
                    "fresh 1190 ms after"
                );
            }
        }
        assert_eq!(
            said,
            [(Severity::Warning, "BAT status (0x629) stale".to_string())],
            "once"
        );
        let summary = monitor.summary(t(ms));
        assert!(!summary.stale && !summary.info_stale && summary.status_stale);
        assert_eq!(
            summary.fresh_status(),
            None,
            "the HSM_F of 5 s ago is not reported as now"
        );
        assert_eq!(
            summary.status,
            Some(DcdcStatus::from_word(172 | 0x0002)),
            "kept for its next comparison"
        );
        // It comes again: said once, and no bit report (nothing changed).
        let report = monitor.on_frame(t(5_050), &status(172 | 0x0002));
        assert_eq!(
            texts(&report),
            [(Severity::Info, "BAT status (0x629) resumed".to_string())]
        );
        assert!(monitor.summary(t(5_050)).fresh_status().is_some());
    }

    #[test]
    fn a_bus_that_stops_whole_is_told_once_as_the_data() {
        let mut monitor = BatteryMonitor::new();
        // The BAT's rhythm: 0x620 and 0x629 alternating every 100 ms; then the connector comes loose at 1 s.
        for ms in (0..1_000).step_by(100) {
            let frame = if ms % 200 == 0 { info(420, 80) } else { status(172) };
            monitor.on_frame(t(ms), &frame);
        }
        let mut said = Vec::new();
        for ms in 1_000..4_000 {
            if monitor.stale_at().is_some_and(|at| at <= t(ms)) {
                said.extend(texts(&monitor.on_tick(t(ms))));
            }
        }
        assert_eq!(said, [(Severity::Warning, "BAT data stale".to_string())]);
        // Back, but 0x629 does not return: the data resumes, and 0x629 is told on its own 1.2 s later.
        let report = monitor.on_frame(t(4_000), &info(420, 80));
        assert_eq!(texts(&report), [(Severity::Info, "BAT data resumed".to_string())]);
        for ms in (4_200..=5_200).step_by(200) {
            monitor.on_frame(t(ms), &info(420, 80));
        }
        assert_eq!(
            monitor.stale_at(),
            Some(t(5_200)),
            "the data's next deadline 6.2 s, 0x629's 5.2 s"
        );
        assert_eq!(
            texts(&monitor.on_tick(t(5_200))),
            [(Severity::Warning, "BAT status (0x629) stale".to_string())]
        );
    }

    #[test]
    fn stale_when_nothing_ever_comes() {
        let mut monitor = BatteryMonitor::new();
        assert_eq!(monitor.stale_at(), None, "not started");
        assert_eq!(monitor.on_tick(t(50)), Report::Nothing);
        assert_eq!(monitor.stale_at(), Some(t(1050)));
        assert_eq!(monitor.on_tick(t(1049)), Report::Nothing);
        assert_eq!(monitor.on_tick(t(1050)), Report::Stale);
        // The first frame after that: resumed, and the start-up report.
        let report = monitor.on_frame(t(1200), &status(172));
        assert_eq!(
            report,
            Report::Resumed {
                frame: None,
                untold: false,
                news: Some(News::StartUp(DcdcStatus::from_word(172)))
            }
        );
        assert_eq!(texts(&report).len(), 13);
    }

    #[test]
    fn bms_alarms_appear_and_clear() {
        let mut monitor = BatteryMonitor::new();
        assert_eq!(monitor.on_frame(t(0), &bms(BmsAlarms::NONE)), Report::Nothing);
        assert_eq!(monitor.summary(t(0)).alarms, Some(BmsAlarms::NONE));
        let both = BmsAlarms::LOW_VOLTAGE | BmsAlarms::HIGH_TEMPERATURE;
        let report = monitor.on_frame(t(200), &bms(both));
        assert_eq!(
            report,
            Report::News(News::Alarms {
                raised: both,
                cleared: BmsAlarms::NONE
            })
        );
        assert_eq!(
            texts(&report),
            [
                (Severity::Warning, "BAT BMS alarm: low voltage".to_string()),
                (Severity::Warning, "BAT BMS alarm: high temperature".to_string()),
            ]
        );
        assert_eq!(monitor.on_frame(t(400), &bms(both)), Report::Nothing);
        let report = monitor.on_frame(t(600), &bms(BmsAlarms::HIGH_TEMPERATURE | BmsAlarms::LOW_CHARGE));
        assert_eq!(
            texts(&report),
            [
                (Severity::Warning, "BAT BMS alarm: low state of charge".to_string()),
                (Severity::Info, "BAT BMS alarm cleared: low voltage".to_string()),
            ]
        );
        // Alarms already set in the first BMS frame are reported.
        let mut monitor = BatteryMonitor::new();
        let report = monitor.on_frame(t(0), &bms(BmsAlarms::OVERCURRENT_DISCHARGE));
        assert_eq!(
            texts(&report),
            [(Severity::Warning, "BAT BMS alarm: overcurrent discharge".to_string())]
        );
        // Every alarm text fits.
        for alarm in BmsAlarms::ALL {
            let report = Report::News(News::Alarms {
                raised: alarm,
                cleared: alarm,
            });
            for (_, text) in texts(&report) {
                assert!(text.len() <= 50 && text.ends_with(alarm.name()), "{text}");
            }
        }
    }

    #[test]
    fn bad_frames_are_counted_and_change_nothing() {
        let mut monitor = BatteryMonitor::new();
        monitor.on_frame(t(0), &status(172));
        monitor.on_frame(t(0), &info(420, 80));
        monitor.on_frame(t(0), &bms(BmsAlarms::NONE));
        let before = monitor.summary(t(0));
        assert_eq!((before.frames, before.errors), (3, 0));
        let bad = [
            // A BAT ID with 7 bytes.
            CanFrame {
                len: 7,
                ..status(0x0FFF)
            },
            // A length code above 8.
            CanFrame {
                len: 9,
                ..bms(BmsAlarms::LOW_VOLTAGE)
            },
            CanFrame { len: 0, ..info(1, 1) },
            // A BAT-source ID that the protocol does not define.
            can(0x62A, [0xFF; 8]),
            can(0x621, [0; 8]),
        ];
        for (n, frame) in bad.iter().enumerate() {
            assert_eq!(monitor.on_frame(t(900), frame), Report::Nothing, "{frame:?}");
            let after = monitor.summary(t(900));
            assert_eq!(after.errors, n as u32 + 1);
            assert_eq!(
                BatterySummary {
                    errors: before.errors,
                    ..after
                },
                before
            );
        }
        // They do not keep the data fresh.
        assert_eq!(monitor.on_tick(t(1000)), Report::Stale);
        monitor.on_receive_error();
        assert_eq!(monitor.summary(t(1000)).errors, bad.len() as u32 + 1);
        assert_eq!(monitor.ignored(), 0);
    }

    #[test]
    fn each_info_field_is_read_on_its_own_and_a_reported_zero_is_zero() {
        let mut monitor = BatteryMonitor::new();
        // Older firmware: zeros in the current and temperature bytes are "not used".
        monitor.on_frame(t(0), &can(INFO_ID, [0xA4, 0x01, 0, 0, 80, 0, 0, 0]));
        let info = monitor.summary(t(0)).info.unwrap();
        assert_eq!((info.current_deciamps, info.temperature_decicelsius), (None, None));
        // A charge above 100 %: counted, unknown, and the voltage of the same frame taken.
        monitor.on_frame(t(100), &can(INFO_ID, [0x9A, 0x01, 0, 0, 101, 0, 0, 0]));
        let summary = monitor.summary(t(100));
        assert_eq!(summary.errors, 1);
        let info = summary.info.unwrap();
        assert_eq!((info.voltage_decivolts, info.charge_percent), (410, None));
        // Newer firmware reports -3.5 A and 21.5 C; then 0.0 A and 0.0 C are zeros, not "not used".
        monitor.on_frame(t(200), &can(INFO_ID, [0x9A, 0x01, 0xDD, 0xFF, 79, 0, 0xD7, 0]));
        monitor.on_frame(t(300), &can(INFO_ID, [0x9A, 0x01, 0, 0, 79, 0, 0, 0]));
        let info = monitor.summary(t(300)).info.unwrap();
        assert_eq!(
            (info.current_deciamps, info.temperature_decicelsius),
            (Some(0), Some(0))
        );
        assert_eq!(info.charge_percent, Some(79));
    }

    #[test]
    fn frames_of_other_ids_are_ignored() {
        let mut monitor = BatteryMonitor::new();
        monitor.on_frame(t(0), &status(172));
        for id in [0x000, 0x123, 0x61F, 0x630, 0x7FF, 0xFFFF] {
            assert_eq!(monitor.on_frame(t(500), &can(id, [0xFF; 8])), Report::Nothing);
            assert_eq!(
                monitor.on_frame(
                    t(500),
                    &CanFrame {
                        id,
                        len: 3,
                        data: [0; 8]
                    }
                ),
                Report::Nothing
            );
        }
        let summary = monitor.summary(t(500));
        assert_eq!((summary.frames, summary.errors), (1, 0));
        assert_eq!(monitor.ignored(), 12);
        assert_eq!(summary.status, Some(DcdcStatus::from_word(172)));
        assert_eq!(
            monitor.on_tick(t(1000)),
            Report::Stale,
            "other IDs do not keep the data fresh"
        );
    }

    #[test]
    fn summary_carries_the_decoded_frames() {
        let mut monitor = BatteryMonitor::new();
        monitor.on_frame(t(0), &can(INFO_ID, [0xA4, 0x01, 0xF6, 0xFF, 80, 0, 0xFA, 0x00]));
        monitor.on_frame(t(0), &can(STATUS_ID, [0xAC, 0x04, 0, 0, 0, 0, 0, 0]));
        monitor.on_frame(t(0), &can(BMS_ID, [0x81, 0, 0, 0, 0, 0, 0, 0]));
        assert_eq!(
            monitor.summary(t(0)),
            BatterySummary {
                info: Some(BatteryInfo {
                    voltage_decivolts: 420,
                    charge_percent: Some(80),
                    current_deciamps: Some(-10),
                    temperature_decicelsius: Some(250),
                }),
                status: Some(DcdcStatus::from_word(0x04AC)),
                alarms: Some(BmsAlarms::LOW_VOLTAGE),
                stale: false,
                info_stale: false,
                status_stale: false,
                alarms_stale: false,
                frames: 3,
                errors: 0,
            }
        );
    }

    /// A CAN port fed by the test: frames, or receive errors.
    struct TestPort(Queue<Result<CanFrame, ()>>);

    impl CanReceiver for TestPort {
        type Error = ();

        async fn receive(&mut self) -> Result<CanFrame, ()> {
            self.0.receive().await
        }
    }

    fn drain(shared: &Shared) -> Vec<(u64, Severity, String)> {
        let mut all = Vec::new();
        while let Ok(message) = shared.outbox.try_receive() {
            match message {
                Outgoing::Text(severity, text) => all.push((Instant::now().as_millis(), severity, text.to_string())),
                other => panic!("unexpected {other:?}"),
            }
        }
        all
    }

    /// Let time pass like [`elapse`], taking the texts as they are queued, with the time they were taken.
    async fn collect(shared: &Shared, duration: Duration) -> Vec<(u64, Severity, String)> {
        let mut all = Vec::new();
        let end = Instant::now() + duration;
        while Instant::now() < end {
            elapse(Duration::from_millis(1)).await;
            all.extend(drain(shared));
        }
        all
    }

    #[test]
    fn can_task_reports_start_up_changes_staleness_and_publishes_at_1_hz() {
        let _clock = lbv_sim::clock::take();
        let shared = Shared::new();
        let bus = Queue::new();
        let mut port = TestPort(bus.clone());
        let script = async {
            let push = |item| bus.push(item);
            elapse(Duration::from_millis(5)).await;
            let first = shared.battery.try_get().expect("published at once");
            assert!(first.stale);
            assert_eq!(first.frames, 0);

            push(Ok(status(172)));
            push(Ok(info(420, 80)));
            elapse(Duration::from_millis(5)).await;
            let texts = drain(&shared);
            assert_eq!(texts.len(), 12, "{texts:?}");
            assert_eq!(texts[2].2, "BAT HSM_PG=1 HSM power good (output stable)");
            let summary = shared.battery.try_get().unwrap();
            assert!(!summary.stale);
            assert_eq!(summary.status, Some(DcdcStatus::from_word(172)));

            // Both frames every 200 ms for 3 s: the summary is published once a second, plus for each report.
            let id = shared.battery.get_msg_id();
            for _ in 0..15 {
                push(Ok(info(420, 80)));
                push(Ok(status(172)));
                elapse(Duration::from_millis(200)).await;
            }
            let published = shared.battery.get_msg_id() - id;
            assert!((3..=4).contains(&published), "{published} publications in 3 s");
            assert!(drain(&shared).is_empty());
            assert_eq!(shared.battery.try_get().unwrap().frames, 32);

            // Bits 10-11 switch: two lines.
            push(Ok(status(172 | 0x0C00)));
            elapse(Duration::from_millis(5)).await;
            let texts: Vec<String> = drain(&shared).into_iter().map(|(_, _, text)| text).collect();
            assert_eq!(
                texts,
                [
                    "BAT HSM_HW_F=1 HSM overcurrent fault (FLT pin)",
                    "BAT HSM_SW_F=1 HSM overcurrent fault (firmware)"
                ]
            );

            // Silence: "stale" exactly 1 s after the last frame, without any frame arriving.
            let pushed = Instant::now().as_millis();
            push(Ok(info(420, 80)));
            let texts = collect(&shared, Duration::from_millis(1500)).await;
            // Received on the first 1 ms step after the push.
            assert_eq!(
                texts,
                [(pushed + 1 + 1000, Severity::Warning, "BAT data stale".to_string())]
            );
            assert!(shared.battery.try_get().unwrap().stale);

            // A receive error is counted and the task goes on.
            push(Err(()));
            push(Ok(bms(BmsAlarms::LOW_CHARGE)));
            elapse(Duration::from_millis(20)).await;
            let texts: Vec<(Severity, String)> = drain(&shared).into_iter().map(|(_, s, text)| (s, text)).collect();
            assert_eq!(
                texts,
                [
                    (Severity::Info, "BAT data resumed".to_string()),
                    (Severity::Warning, "BAT BMS alarm: low state of charge".to_string())
                ]
            );
            let summary = shared.battery.try_get().unwrap();
            assert!(!summary.stale);
            assert_eq!((summary.frames, summary.errors), (35, 1));
            assert_eq!(summary.alarms, Some(BmsAlarms::LOW_CHARGE));
        };
        match block_on(select(can_task(&mut port, &shared), script)) {
            Either::First(never) => match never {},
            Either::Second(()) => {}
        }
    }

    #[test]
    fn can_task_reports_stale_when_the_bus_is_silent_from_the_start() {
        let _clock = lbv_sim::clock::take();
        let shared = Shared::new();
        let bus = Queue::new();
        let mut port = TestPort(bus.clone());
        let script = async {
            let texts = collect(&shared, Duration::from_millis(4000)).await;
            assert_eq!(
                texts,
                [(1000, Severity::Warning, "BAT data stale".to_string())],
                "at 1 s, once"
            );
        };
        match block_on(select(can_task(&mut port, &shared), script)) {
            Either::First(never) => match never {},
            Either::Second(()) => {}
        }
    }

    #[test]
    fn can_task_does_not_stall_when_the_outbox_is_full() {
        let _clock = lbv_sim::clock::take();
        let shared = Shared::new();
        let bus = Queue::new();
        let mut port = TestPort(bus.clone());
        let script = async {
            // Nobody drains the outbox: the start-up report fills it, the rest is dropped after 100 ms.
            bus.push(Ok(status(0)));
            elapse(Duration::from_millis(1)).await;
            for _ in 0..4 {
                shared.say(Severity::Info, Text::try_from("filler").unwrap());
            }
            // A change report waits for room at most 100 ms, then the next frame is taken.
            bus.push(Ok(status(1)));
            bus.push(Ok(status(3)));
            elapse(Duration::from_millis(50)).await;
            assert_eq!(shared.battery.try_get().unwrap().frames, 2, "waiting for room");
            elapse(Duration::from_millis(100)).await;
            assert_eq!(shared.battery.try_get().unwrap().frames, 3, "frames still received");
            assert_eq!(shared.outbox.len(), 16);
        };
        match block_on(select(can_task(&mut port, &shared), script)) {
            Either::First(never) => match never {},
            Either::Second(()) => {}
        }
    }
}
