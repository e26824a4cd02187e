//! Hardware overcurrent trips: counted, and a sustained trip stops the bridge until a zero order.
//!
//! The power stage's overcurrent comparator pulls TIM1's break input: the outputs go off at once, and with
//! automatic output enable (AOE) they come back at the next update event, so an isolated trip is cycle-by-cycle
//! current limiting and costs one PWM period at most. A short (water in a phase, a failed MOSFET) trips every
//! period instead, and AOE would retry it forever. What the binding can see of it is TIM1_SR.BIF, which the break
//! sets and only software clears (RM0440 TIMx_SR): the fault task reads and clears it once per 1 ms sample, so
//! [`TripRule::tick`] takes one bit per tick, "the break tripped at least once in the last millisecond" (40 update
//! events at 20 kHz centre-aligned). The break interrupt is no alternative on the STM32G431: TIM1_BRK shares its
//! vector with TIM15 (`TIM1_BRK_TIM15`), which embassy-stm32's time driver takes and handles for TIM15 alone, and
//! an interrupt per trip would be 40 000 a second under a short.
//!
//! The rule is a leaky count: +1 for a tick with a trip, -1 for a tick without (never below 0); the trip is
//! sustained once the count reaches `TripRule::ticks`. So a trip on every tick stops the bridge after `ticks` ms,
//! trips on 3 ticks of 4 after 2 x `ticks` ms, and trips on at most every other tick never do: a propeller
//! accelerating at the limit, or a noisy line, keeps driving. Once sustained, the trip is latched, and the
//! binding holds the outputs off for good (BDTR with AOE and MOE cleared), until a zero-speed order clears it, as
//! a stall is (docs/decisions.md D11; `faults::FaultMonitor::on_order`).

/// The trip rule and its state for one bridge.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct TripRule {
    /// The count at which a trip is sustained; 0 acts as 1.
    ticks: u16,
    /// The leaky count.
    level: u16,
    /// A sustained trip holds the bridge off until a zero order.
    latched: bool,
    /// Ticks with a trip since start-up (saturating).
    trips: u32,
    /// Sustained trips since start-up (saturating).
    stops: u32,
}

impl TripRule {
    /// A rule that has seen nothing: a trip is sustained at a count of `ticks`.
    pub const fn new(ticks: u16) -> Self {
        TripRule {
            ticks,
            level: 0,
            latched: false,
            trips: 0,
            stops: 0,
        }
    }

    /// One sample: whether the break tripped since the last. Returns whether the trip is sustained now (latched).
    pub fn tick(&mut self, tripped: bool) -> bool {
        if tripped {
            self.trips = self.trips.saturating_add(1);
            self.level = self.level.saturating_add(1);
        } else {
            self.level = self.level.saturating_sub(1);
        }
        if !self.latched && self.level >= self.ticks.max(1) {
            self.latched = true;
            self.stops = self.stops.saturating_add(1);
        }
        self.latched
    }

    /// A valid zero-speed order: clears a sustained trip and the count (the next order drives again).
    pub fn on_zero_order(&mut self) {
        self.latched = false;
        self.level = 0;
    }

    /// Whether a sustained trip holds the bridge off.
    pub const fn latched(&self) -> bool {
        self.latched
    }

    /// Ticks with a trip since start-up: every trip is counted, sustained or not.
    pub const fn trips(&self) -> u32 {
        self.trips
    }

    /// Sustained trips since start-up.
    pub const fn stops(&self) -> u32 {
        self.stops
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TICKS: u16 = 100;

    /// Feed `pattern` (true: a trip) `times` times; whether the rule latched on the way.
    fn feed(rule: &mut TripRule, pattern: &[bool], times: usize) -> bool {
        let mut latched = false;
        for _ in 0..times {
            for &tripped in pattern {
                latched |= rule.tick(tripped);
            }
        }
        latched
    }

    #[test]
    fn isolated_trips_are_counted_and_never_stop() {
        let mut rule = TripRule::new(TICKS);
        // One trip in ten ticks, for 100 s.
        let mut pattern = [false; 10];
        pattern[0] = true;
        assert!(!feed(&mut rule, &pattern, 10_000));
        assert_eq!((rule.trips(), rule.stops()), (10_000, 0));
        // Trips on every other tick never add up either.
        assert!(!feed(&mut rule, &[true, false], 50_000));
        assert!(!rule.latched());
    }

    #[test]
    fn bursts_shorter_than_the_rule_do_not_stop() {
        let mut rule = TripRule::new(TICKS);
        // 99 ms of trips (a hard acceleration at the limit), then as long without: never sustained.
        let mut burst = vec![true; usize::from(TICKS) - 1];
        burst.extend(vec![false; usize::from(TICKS) - 1]);
        assert!(!feed(&mut rule, &burst, 100));
        assert_eq!(rule.trips(), 9_900);
    }

    #[test]
    fn a_trip_on_every_tick_is_sustained_after_exactly_ticks_samples_and_latches() {
        let mut rule = TripRule::new(TICKS);
        for n in 1..TICKS {
            assert!(!rule.tick(true), "sustained after {n}");
        }
        assert!(rule.tick(true));
        assert_eq!(rule.stops(), 1);
        // Latched: the bridge is off, no more trips come, and it stays so.
        feed(&mut rule, &[false], 10_000);
        assert!(rule.latched());
        rule.on_zero_order();
        assert!(!rule.latched());
        // The count starts again from nothing: a second short takes as long again, and is a second stop.
        assert!(!feed(&mut rule, &[true], usize::from(TICKS) - 1));
        assert!(rule.tick(true));
        assert_eq!((rule.stops(), rule.trips()), (2, 2 * u32::from(TICKS)));
    }

    #[test]
    fn three_trips_in_four_ticks_take_twice_as_long() {
        let mut rule = TripRule::new(TICKS);
        let pattern = [true, true, true, false];
        // Net +2 every 4 ticks: 50 patterns (200 ticks) reach 100.
        assert!(!feed(&mut rule, &pattern, 49));
        assert!(feed(&mut rule, &pattern, 1));
    }

    #[test]
    fn zero_ticks_acts_as_one() {
        let mut rule = TripRule::new(0);
        assert!(!rule.tick(false));
        assert!(rule.tick(true));
    }

    #[test]
    fn counts_saturate() {
        let mut rule = TripRule {
            trips: u32::MAX,
            level: u16::MAX,
            ..TripRule::new(u16::MAX)
        };
        assert!(rule.tick(true));
        assert_eq!(rule.trips(), u32::MAX);
    }
}
