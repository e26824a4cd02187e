//! Hardware overcurrent trips: counted, and a sustained trip stops the bridge until a zero order.
//!
//! The power stage's overcurrent comparator pulls TIM1's break input: the outputs go off at once, and with
//! automatic output enable (AOE) they come back at the next update event, so an isolated trip is cycle-by-cycle
//! current limiting and costs one PWM period at most. A short (water in a phase, a failed MOSFET) trips every
//! period it is switched into instead, and AOE would retry it forever. What the binding can see of it is
//! TIM1_SR.BIF, which the break sets and only software clears (RM0440 TIMx_SR): the fault task reads and clears it
//! once per 1 ms sample, so [`TripRule::tick`] takes one bit per tick, "the break tripped at least once in the
//! last millisecond" (40 update events at 20 kHz centre-aligned). The break interrupt is no alternative on the
//! STM32G431: TIM1_BRK shares its vector with TIM15 (`TIM1_BRK_TIM15`), which embassy-stm32's time driver takes
//! and handles for TIM15 alone, and an interrupt per trip would be 40 000 a second under a short.
//!
//! The rule has two triggers ([`TripLimits`]; the numbers in `faults::Thresholds::SPEC`):
//!
//! - **a run**: trips on `run_ticks` consecutive ticks, a short that trips whenever the bridge switches;
//! - **a fraction**: more than `window_trips` of the last `window_ticks` ticks with a trip, a short that trips
//!   only part of the time: a shorted MOSFET shoots through in the two sectors of six where its partner
//!   switches, a third of the ticks or more.
//!
//! Isolated trips (a switching spike, a noisy line) meet neither and keep driving. The window is a bit-packed
//! ring of the last ticks, at most [`TripRule::WINDOW_MAX`] of them, and its count of set bits is kept as the
//! ring turns: constant memory, constant time a tick. Once sustained, the trip is latched, and the binding holds
//! the outputs off for good (BDTR with AOE and MOE cleared), until a zero-speed order clears it, as a stall is
//! (docs/decisions.md D11; `faults::FaultMonitor::on_order`); the window and the run then start empty.

/// When trips are sustained: on a run of them, or on a fraction of a sliding window.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct TripLimits {
    /// Sustained after a trip on this many consecutive ticks; 0 acts as 1.
    pub run_ticks: u16,
    /// The sliding window's length in ticks: 0 acts as 1, above [`TripRule::WINDOW_MAX`] as that.
    pub window_ticks: u16,
    /// Sustained once more than this many ticks of the window saw a trip (the window's first ticks after a start
    /// count as ticks without); at or above the window's length this trigger never fires.
    pub window_trips: u16,
}

/// The words of the window's ring.
const WORDS: usize = TripRule::WINDOW_MAX as usize / 32;

/// The trip rule and its state for one bridge.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct TripRule {
    /// The rule's numbers, the window's length clamped to 1..=[`TripRule::WINDOW_MAX`].
    limits: TripLimits,
    /// The last `window_ticks` ticks, one bit each (1: a trip), the oldest at `head`.
    window: [u32; WORDS],
    /// Where the next tick goes, replacing the oldest: 0..window_ticks.
    head: u16,
    /// Set bits in `window`.
    in_window: u16,
    /// Consecutive ticks with a trip, up to the last (saturating).
    run: u16,
    /// A sustained trip holds the bridge off until a zero order.
    latched: bool,
    /// Ticks with a trip since start-up (saturating).
    trips: u32,
    /// Sustained trips since start-up (saturating).
    stops: u32,
}

impl TripRule {
    /// The longest window the rule keeps: 256 ticks (0.256 s at 1 kHz) in 32 bytes.
    pub(crate) const WINDOW_MAX: u16 = 256;

    /// A rule that has seen nothing.
    pub(crate) const fn new(limits: TripLimits) -> Self {
        let window_ticks = if limits.window_ticks == 0 {
            1
        } else if limits.window_ticks > Self::WINDOW_MAX {
            Self::WINDOW_MAX
        } else {
            limits.window_ticks
        };
        TripRule {
            limits: TripLimits { window_ticks, ..limits },
            window: [0; WORDS],
            head: 0,
            in_window: 0,
            run: 0,
            latched: false,
            trips: 0,
            stops: 0,
        }
    }

    /// One sample: whether the break tripped since the last. Returns whether the trip is sustained now (latched).
    pub(crate) fn tick(&mut self, tripped: bool) -> bool {
        let bit = 1u32 << (self.head % 32);
        if let Some(word) = self.window.get_mut(usize::from(self.head / 32)) {
            // The bit at `head` is the tick `window_ticks` ago, leaving the window as this one enters it.
            if *word & bit != 0 {
                self.in_window = self.in_window.saturating_sub(1);
            }
            if tripped {
                *word |= bit;
                self.in_window = self.in_window.saturating_add(1);
            } else {
                *word &= !bit;
            }
        }
        self.head = self.head.saturating_add(1);
        if self.head >= self.limits.window_ticks {
            self.head = 0;
        }
        if tripped {
            self.trips = self.trips.saturating_add(1);
            self.run = self.run.saturating_add(1);
        } else {
            self.run = 0;
        }
        let sustained = self.run >= self.limits.run_ticks.max(1) || self.in_window > self.limits.window_trips;
        if !self.latched && sustained {
            self.latched = true;
            self.stops = self.stops.saturating_add(1);
        }
        self.latched
    }

    /// A valid zero-speed order: clears a sustained trip, the run and the window (the next order drives again).
    pub(crate) fn on_zero_order(&mut self) {
        self.latched = false;
        self.window = [0; WORDS];
        self.head = 0;
        self.in_window = 0;
        self.run = 0;
    }

    /// Whether a sustained trip holds the bridge off.
    pub(crate) const fn latched(&self) -> bool {
        self.latched
    }

    /// Ticks with a trip since start-up: every trip is counted, sustained or not.
    pub(crate) const fn trips(&self) -> u32 {
        self.trips
    }

    /// Sustained trips since start-up.
    #[cfg(test)]
    pub(crate) const fn stops(&self) -> u32 {
        self.stops
    }

    /// Ticks with a trip among the window's.
    #[cfg(test)]
    pub(crate) const fn trips_in_window(&self) -> u16 {
        self.in_window
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::faults::Thresholds;
    use proptest::prelude::*;

    /// The project's numbers.
    const LIMITS: TripLimits = Thresholds::SPEC.overcurrent;

    /// Feed `pattern` (true: a trip) `times` times; the tick (from 1) at which the rule latched, if it did.
    fn feed(rule: &mut TripRule, pattern: &[bool], times: usize) -> Option<usize> {
        let mut latched_at = None;
        for (n, &tripped) in pattern.iter().cycle().take(pattern.len() * times).enumerate() {
            if rule.tick(tripped) && latched_at.is_none() {
                latched_at = Some(n + 1);
            }
        }
        latched_at
    }

    /// One trip every `period` ticks.
    fn one_in(period: usize) -> Vec<bool> {
        let mut pattern = vec![false; period];
        pattern[0] = true;
        pattern
    }

    #[test]
    fn the_numbers_are_those_of_the_spec() {
        assert_eq!(
            (LIMITS.run_ticks, LIMITS.window_ticks, LIMITS.window_trips),
            (5, 200, 40)
        );
    }

    #[test]
    fn an_intermittent_short_on_a_third_of_the_ticks_latches_within_its_window() {
        // A trip on every third tick: the 41st is tick 121.
        let mut rule = TripRule::new(LIMITS);
        assert_eq!(feed(&mut rule, &one_in(3), 100), Some(121));
        assert_eq!(rule.stops(), 1);
        // A shorted MOSFET at speed: the two sectors of six where its partner switches, two ticks of six.
        let mut rule = TripRule::new(LIMITS);
        let sectors = [true, true, false, false, false, false];
        let at = feed(&mut rule, &sectors, 100);
        assert!(at.is_some_and(|at| at <= usize::from(LIMITS.window_ticks)), "{at:?}");
    }

    #[test]
    fn a_continuous_short_latches_after_the_run() {
        let mut rule = TripRule::new(LIMITS);
        assert_eq!(feed(&mut rule, &[true], 1_000), Some(usize::from(LIMITS.run_ticks)));
        // Latched: the bridge is off, no more trips come, and it stays so.
        assert_eq!(feed(&mut rule, &[false], 10_000), Some(1));
        assert!(rule.latched());
    }

    #[test]
    fn transients_never_latch() {
        let mut rule = TripRule::new(LIMITS);
        // One trip, then 100 s without.
        assert!(!rule.tick(true));
        assert_eq!(feed(&mut rule, &[false], 100_000), None);
        // A few trips spread out: one in ten ticks (20 in any window) for 100 s.
        assert_eq!(feed(&mut rule, &one_in(10), 10_000), None);
        // Runs one short of the run, far enough apart.
        let mut burst = vec![true; usize::from(LIMITS.run_ticks) - 1];
        burst.extend([false; 100]);
        assert_eq!(feed(&mut rule, &burst, 1_000), None);
        assert_eq!((rule.trips(), rule.stops()), (1 + 10_000 + 4_000, 0));
    }

    #[test]
    fn the_fraction_of_the_window_is_the_boundary() {
        // One trip in five ticks, the fifth: 40 in every window of 200, not more than 40, for 20 s.
        let mut rule = TripRule::new(LIMITS);
        assert_eq!(feed(&mut rule, &[false, false, false, false, true], 4_000), None);
        assert_eq!(rule.trips_in_window(), LIMITS.window_trips);
        // One trip more in the window, one tick early: 41.
        assert!(rule.tick(true));
        assert_eq!(rule.trips_in_window(), LIMITS.window_trips + 1);
    }

    #[test]
    fn a_zero_order_starts_afresh() {
        let mut rule = TripRule::new(LIMITS);
        assert!(feed(&mut rule, &[true], 10).is_some());
        rule.on_zero_order();
        assert!(!rule.latched());
        // The run starts from nothing: a second short takes as long again, and is a second stop.
        assert_eq!(feed(&mut rule, &[true], 10), Some(usize::from(LIMITS.run_ticks)));
        assert_eq!(rule.stops(), 2);
        // And so does the window: 40 trips before the order and one after are not 41.
        let mut rule = TripRule::new(LIMITS);
        assert_eq!(feed(&mut rule, &one_in(5), 40), None);
        assert_eq!(rule.trips_in_window(), 40);
        rule.on_zero_order();
        assert_eq!(rule.trips_in_window(), 0);
        assert!(!rule.tick(true));
        assert_eq!(feed(&mut rule, &one_in(5), 39), None);
    }

    #[test]
    fn limits_out_of_range_act_as_the_nearest() {
        let mut rule = TripRule::new(TripLimits {
            run_ticks: 0,
            window_ticks: 0,
            window_trips: 0,
        });
        assert!(!rule.tick(false));
        assert!(rule.tick(true));
        // A window longer than the ring keeps 256 ticks.
        let mut rule = TripRule::new(TripLimits {
            run_ticks: u16::MAX,
            window_ticks: u16::MAX,
            window_trips: 128,
        });
        assert_eq!(feed(&mut rule, &one_in(2), 10_000), None);
        assert_eq!(rule.trips_in_window(), 128);
    }

    #[test]
    fn counts_saturate() {
        let mut rule = TripRule {
            trips: u32::MAX,
            run: u16::MAX,
            ..TripRule::new(TripLimits {
                run_ticks: u16::MAX,
                ..LIMITS
            })
        };
        assert!(rule.tick(true));
        assert_eq!(rule.trips(), u32::MAX);
    }

    /// The rule as stated, on the whole history: sustained at the first tick that ends a run of `run_ticks` trips
    /// or a window of `window_ticks` with more than `window_trips`; a zero order forgets the history.
    fn model(limits: TripLimits, events: &[Option<bool>]) -> Vec<bool> {
        let window = usize::from(limits.window_ticks.clamp(1, TripRule::WINDOW_MAX));
        let run = usize::from(limits.run_ticks.max(1));
        let (mut history, mut latched, mut out) = (Vec::new(), false, Vec::new());
        for event in events {
            match *event {
                None => {
                    history.clear();
                    latched = false;
                }
                Some(tripped) => {
                    history.push(tripped);
                    let recent = &history[history.len().saturating_sub(window)..];
                    let in_window = recent.iter().filter(|&&tripped| tripped).count();
                    let ran = history.len() >= run && history[history.len() - run..].iter().all(|&t| t);
                    latched |= ran || in_window > usize::from(limits.window_trips);
                    out.push(latched);
                }
            }
        }
        out
    }

    proptest! {
        #[test]
        fn any_pattern_follows_the_rule_as_stated(
            run_ticks in prop_oneof![0..12u16, any::<u16>()],
            window_ticks in prop_oneof![0..300u16, any::<u16>()],
            window_trips in prop_oneof![0..300u16, any::<u16>()],
            density in 0.0..1.0f64,
            seeds in prop::collection::vec((any::<u16>(), any::<u8>()), 0..2_000),
        ) {
            let limits = TripLimits { run_ticks, window_ticks, window_trips };
            // Ticks with a trip at `density`, and now and then a zero order.
            let events: Vec<Option<bool>> = seeds
                .iter()
                .map(|&(draw, order)| (order != 0).then_some(f64::from(draw) < density * 65_536.0))
                .collect();
            let mut rule = TripRule::new(limits);
            let mut got = Vec::new();
            for event in &events {
                match *event {
                    None => rule.on_zero_order(),
                    Some(tripped) => got.push(rule.tick(tripped)),
                }
            }
            prop_assert_eq!(got, model(limits, &events));
        }
    }
}
