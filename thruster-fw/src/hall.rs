//! Hall sensors: the rotor position in 60-degree sectors, the legality of each edge, and the speed.
//!
//! The three sensors sit 120 electrical degrees apart, so a turning motor steps through six states in a Gray code
//! (one bit changes per edge). 000 and 111 never occur on a healthy motor, and a jump of more than one sector
//! means an edge was missed or invented: both are the "hall sensor error" of the fault table.

use embassy_time::{Duration, Instant};

use crate::drive::Direction;

/// The three hall sensor inputs: H1 = bit 0, H2 = bit 1, H3 = bit 2.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct HallState(u8);

impl HallState {
    /// The state from the low 3 bits of `bits`; the rest are ignored.
    pub const fn from_bits(bits: u8) -> HallState {
        HallState(bits & 0b111)
    }

    /// The state from the three pin levels (true = high).
    pub const fn from_pins(h1: bool, h2: bool, h3: bool) -> HallState {
        HallState((h1 as u8) | ((h2 as u8) << 1) | ((h3 as u8) << 2))
    }

    /// H1 in bit 0, H2 in bit 1, H3 in bit 2.
    pub const fn bits(self) -> u8 {
        self.0
    }

    /// 000 and 111 cannot occur with 120-degree sensors: a sensor is open, shorted or unpowered.
    pub const fn is_valid(self) -> bool {
        self.0 != 0b000 && self.0 != 0b111
    }

    /// Position 0..=5 in [`FORWARD_SEQUENCE`]; `None` when invalid.
    pub const fn sector(self) -> Option<u8> {
        match self.0 {
            0b001 => Some(0),
            0b011 => Some(1),
            0b010 => Some(2),
            0b110 => Some(3),
            0b100 => Some(4),
            0b101 => Some(5),
            _ => None,
        }
    }

    /// The state of sector `k` of [`FORWARD_SEQUENCE`], `k` taken modulo 6.
    const fn of_sector(k: u8) -> HallState {
        match k % 6 {
            0 => HallState(0b001),
            1 => HallState(0b011),
            2 => HallState(0b010),
            3 => HallState(0b110),
            4 => HallState(0b100),
            _ => HallState(0b101),
        }
    }
}

/// The hall states in the order a forward-turning motor produces them (120-degree sensors):
/// 0b001, 0b011, 0b010, 0b110, 0b100, 0b101.
pub const FORWARD_SEQUENCE: [HallState; 6] = [
    HallState::of_sector(0),
    HallState::of_sector(1),
    HallState::of_sector(2),
    HallState::of_sector(3),
    HallState::of_sector(4),
    HallState::of_sector(5),
];

/// Electrical angle where sector 0 of [`FORWARD_SEQUENCE`] begins, in millidegrees.
const SECTOR_0_START_MILLIDEG: u32 = 30_000;
/// One sector: 60 electrical degrees.
const SECTOR_MILLIDEG: u32 = 60_000;
/// One electrical revolution.
const TURN_MILLIDEG: u32 = 360_000;

/// The hall state seen at an electrical angle (millidegrees, taken modulo 360_000) when the motor turns forward.
///
/// This defines the sensor placement the commutation table assumes; the simulated motor of the virtual bench
/// produces its hall signals with this function. The angle is that of the back-EMF: phase A's back-EMF crosses
/// zero rising at 0 degrees and is at its positive plateau on [30, 150) (trapezoidal motor; B lags A by 120
/// degrees, C by 240). Sector k of [`FORWARD_SEQUENCE`] covers [30 + k*60, 90 + k*60) degrees, so every hall edge
/// falls on a commutation point: in each sector one phase's back-EMF is at +1 and another's at -1 throughout.
/// Equivalently H1 is high while e_A > e_B, H2 while e_B > e_C, H3 while e_C > e_A.
pub const fn hall_state_at(angle_millideg: u32) -> HallState {
    let angle = angle_millideg % TURN_MILLIDEG;
    // angle < 360_000, so the sum stays far below u32::MAX.
    let from_sector_0 = (angle + TURN_MILLIDEG - SECTOR_0_START_MILLIDEG) % TURN_MILLIDEG;
    HallState::of_sector((from_sector_0 / SECTOR_MILLIDEG) as u8)
}

/// How the hall state moved between two readings.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Transition {
    /// Same valid state: no edge.
    Same,
    /// One sector forward.
    Forward,
    /// One sector back.
    Reverse,
    /// An invalid state on either side, or a jump of 2 or 3 sectors (a missed or spurious edge).
    Illegal,
}

/// Forward: `to` is the next state of [`FORWARD_SEQUENCE`] after `from`; Reverse: the previous one; Same: equal and
/// valid; Illegal: either state invalid, or a jump of 2 or 3 sectors (a missed or spurious edge).
pub const fn transition(from: HallState, to: HallState) -> Transition {
    match (from.sector(), to.sector()) {
        // Both sectors are < 6, so the sum cannot overflow.
        (Some(f), Some(t)) => match (t + 6 - f) % 6 {
            0 => Transition::Same,
            1 => Transition::Forward,
            5 => Transition::Reverse,
            _ => Transition::Illegal,
        },
        _ => Transition::Illegal,
    }
}

/// Edge intervals averaged for the speed: one electrical revolution.
const AVERAGED_INTERVALS: usize = 6;

/// Follows the hall edges of a turning motor: direction, electrical period, signed mechanical rpm, legal pulses and
/// the net position they add up to.
///
/// A plain value (Copy), so a task can publish snapshots of it for others to read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) struct HallTracker {
    /// Rotor pole pairs, at least 1.
    pole_pairs: u8,
    /// The last state recorded.
    state: HallState,
    /// Time of the last legal edge (or of `new`).
    last_edge: Instant,
    /// Direction of the current run of legal edges; `None` before the first legal edge and after an illegal one.
    run: Option<Direction>,
    /// The last edge intervals of the run, in microseconds (each 1..100 000).
    intervals_us: [u32; AVERAGED_INTERVALS],
    /// How many entries of `intervals_us` are filled, 0..=6.
    filled: u8,
    /// Where the next interval goes, 0..6.
    next: u8,
    /// Legal edges, wrapping.
    pulses: u32,
    /// Net legal edges, forward minus reverse, wrapping.
    position: i32,
    /// Illegal transitions, saturating.
    illegal: u32,
}

impl HallTracker {
    /// Mechanical speed reads 0 when no legal edge came for this long (at 4 pole pairs, 100 ms between edges is
    /// 25 rpm). An edge that comes this long or longer after the previous one starts a new average.
    pub(crate) const STANDSTILL: Duration = Duration::from_millis(100);

    /// A tracker for a motor with `pole_pairs` pole pairs (0 is taken as 1), its halls reading `initial` at `now`.
    pub(crate) fn new(pole_pairs: u8, initial: HallState, now: Instant) -> Self {
        HallTracker {
            pole_pairs: pole_pairs.max(1),
            state: initial,
            last_edge: now,
            run: None,
            intervals_us: [0; AVERAGED_INTERVALS],
            filled: 0,
            next: 0,
            pulses: 0,
            position: 0,
            illegal: 0,
        }
    }

    /// Record the hall state read at an edge (or any time: a Same state changes nothing). Returns the transition.
    ///
    /// Illegal transitions and invalid states are returned and counted, and reset the speed history. Every call
    /// that returns Illegal counts once: reading an invalid state again, or leaving it, is Illegal too.
    pub(crate) fn on_edge(&mut self, state: HallState, now: Instant) -> Transition {
        let t = transition(self.state, state);
        self.state = state;
        match t {
            Transition::Same => {}
            Transition::Forward => self.legal_edge(Direction::Forward, now),
            Transition::Reverse => self.legal_edge(Direction::Reverse, now),
            Transition::Illegal => {
                self.illegal = self.illegal.saturating_add(1);
                self.run = None;
                self.clear_intervals();
            }
        }
        t
    }

    /// The last state recorded.
    pub(crate) fn state(&self) -> HallState {
        self.state
    }

    /// Signed mechanical rpm (positive forward), rounded to the nearest rpm.
    ///
    /// Averaged over up to the last 6 edge intervals of the same direction (one electrical revolution: this
    /// cancels sensor placement error); needs at least 2 legal edges in the same direction; 0 once STANDSTILL has
    /// passed since the last legal edge, or after an illegal transition until 2 new legal edges.
    /// rpm = 60e6 us / (interval_us * 6 * pole_pairs).
    pub(crate) fn rpm(&self, now: Instant) -> i32 {
        let Some(direction) = self.run else {
            return 0;
        };
        if self.filled == 0 || now.saturating_duration_since(self.last_edge) >= Self::STANDSTILL {
            return 0;
        }
        let sum_us = self
            .intervals_us
            .iter()
            .take(usize::from(self.filled))
            .fold(0u64, |sum, &us| sum.saturating_add(u64::from(us)));
        // rpm = 60e6 * n / (sum_us * 6 * pole_pairs); every interval is >= 1 us, so the result is <= 10 000 000.
        let numerator = 60_000_000u64.saturating_mul(u64::from(self.filled));
        let denominator = sum_us.saturating_mul(6).saturating_mul(u64::from(self.pole_pairs));
        let rpm = numerator
            .saturating_add(denominator / 2)
            .checked_div(denominator)
            .unwrap_or(0);
        let rpm = i32::try_from(rpm).unwrap_or(i32::MAX);
        match direction {
            Direction::Forward => rpm,
            Direction::Reverse => -rpm,
        }
    }

    /// Legal edges (Forward or Reverse transitions) since `new`, wrapping.
    #[cfg(test)]
    pub(crate) fn pulses(&self) -> u32 {
        self.pulses
    }

    /// Net hall states moved since `new`: forward edges minus reverse edges, wrapping. Illegal transitions do not
    /// move it. The stall window counts progress in this ([`crate::faults::Progress`]).
    pub(crate) fn position(&self) -> i32 {
        self.position
    }

    /// Illegal transitions seen since `new`, saturating.
    pub(crate) fn illegal_transitions(&self) -> u32 {
        self.illegal
    }

    /// A Forward or Reverse edge at `now`: extends the current run, or starts a new one after a reversal, an
    /// illegal transition or a standstill.
    fn legal_edge(&mut self, direction: Direction, now: Instant) {
        self.pulses = self.pulses.wrapping_add(1);
        self.position = match direction {
            Direction::Forward => self.position.wrapping_add(1),
            Direction::Reverse => self.position.wrapping_sub(1),
        };
        let gap = now.saturating_duration_since(self.last_edge);
        if self.run == Some(direction) && gap < Self::STANDSTILL {
            // gap < 100 ms, so its microseconds fit a u32; 1 us at least keeps the speed finite.
            let us = u32::try_from(gap.as_micros()).unwrap_or(u32::MAX).max(1);
            if let Some(slot) = self.intervals_us.get_mut(usize::from(self.next)) {
                *slot = us;
            }
            self.next = (self.next + 1) % AVERAGED_INTERVALS as u8;
            self.filled = self.filled.saturating_add(1).min(AVERAGED_INTERVALS as u8);
        } else {
            self.run = Some(direction);
            self.clear_intervals();
        }
        self.last_edge = now;
    }

    fn clear_intervals(&mut self) {
        self.filled = 0;
        self.next = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ALL: [HallState; 8] = [
        HallState(0),
        HallState(1),
        HallState(2),
        HallState(3),
        HallState(4),
        HallState(5),
        HallState(6),
        HallState(7),
    ];

    /// The forward edges, written out by hand.
    const FORWARD_EDGES: [(u8, u8); 6] = [
        (0b001, 0b011),
        (0b011, 0b010),
        (0b010, 0b110),
        (0b110, 0b100),
        (0b100, 0b101),
        (0b101, 0b001),
    ];

    fn expected_transition(from: u8, to: u8) -> Transition {
        let valid = |s: u8| s != 0 && s != 7;
        if !valid(from) || !valid(to) {
            Transition::Illegal
        } else if from == to {
            Transition::Same
        } else if FORWARD_EDGES.contains(&(from, to)) {
            Transition::Forward
        } else if FORWARD_EDGES.contains(&(to, from)) {
            Transition::Reverse
        } else {
            Transition::Illegal
        }
    }

    #[test]
    fn bits_pins_and_validity() {
        for bits in 0..=255u8 {
            let s = HallState::from_bits(bits);
            assert_eq!(s.bits(), bits & 0b111);
            assert_eq!(HallState::from_pins(bits & 1 != 0, bits & 2 != 0, bits & 4 != 0), s);
            let valid = s.bits() != 0 && s.bits() != 7;
            assert_eq!(s.is_valid(), valid);
            assert_eq!(s.sector().is_some(), valid);
        }
        assert_eq!(HallState::from_pins(true, false, false).bits(), 0b001);
        assert_eq!(HallState::from_pins(false, true, false).bits(), 0b010);
        assert_eq!(HallState::from_pins(false, false, true).bits(), 0b100);
    }

    #[test]
    fn forward_sequence_is_a_gray_code_of_the_six_valid_states() {
        let mut seen = [0u8; 8];
        for (k, s) in FORWARD_SEQUENCE.iter().enumerate() {
            assert!(s.is_valid());
            assert_eq!(s.sector(), Some(k as u8));
            seen[usize::from(s.bits())] += 1;
            let next = FORWARD_SEQUENCE[(k + 1) % 6];
            assert_eq!((s.bits() ^ next.bits()).count_ones(), 1, "{s:?} -> {next:?}");
        }
        assert_eq!(seen, [0, 1, 1, 1, 1, 1, 1, 0]);
        let literal: [u8; 6] = [0b001, 0b011, 0b010, 0b110, 0b100, 0b101];
        assert_eq!(FORWARD_SEQUENCE.map(HallState::bits), literal);
    }

    #[test]
    fn every_transition_is_classified() {
        let mut counts = [0; 4];
        for from in ALL {
            for to in ALL {
                let t = transition(from, to);
                assert_eq!(t, expected_transition(from.bits(), to.bits()), "{from:?} -> {to:?}");
                // Between valid states an edge flips exactly one bit; two flipped bits are a missed edge.
                if from.is_valid() && to.is_valid() {
                    let flipped = (from.bits() ^ to.bits()).count_ones();
                    assert_eq!(flipped == 1, matches!(t, Transition::Forward | Transition::Reverse));
                    assert_eq!(flipped == 0, t == Transition::Same);
                }
                counts[t as usize] += 1;
            }
        }
        // Same, Forward, Reverse, Illegal.
        assert_eq!(counts, [6, 6, 6, 46]);
    }

    #[test]
    fn hall_state_at_walks_the_sequence_with_edges_on_commutation_points() {
        for deg in 0..360u32 {
            let k = ((deg + 330) % 360) / 60;
            assert_eq!(hall_state_at(deg * 1000), FORWARD_SEQUENCE[k as usize], "{deg} deg");
            assert_eq!(
                hall_state_at(deg * 1000 + 999),
                FORWARD_SEQUENCE[k as usize],
                "{deg}.999 deg"
            );
        }
        for k in 0..6u32 {
            let edge = 30_000 + 60_000 * k;
            let before = FORWARD_SEQUENCE[((k + 5) % 6) as usize];
            let after = FORWARD_SEQUENCE[k as usize];
            assert_eq!(hall_state_at(edge - 1), before, "edge {edge}");
            assert_eq!(hall_state_at(edge), after, "edge {edge}");
            assert_eq!(transition(before, after), Transition::Forward);
        }
    }

    #[test]
    fn hall_state_at_wraps() {
        assert_eq!(hall_state_at(360_000), hall_state_at(0));
        assert_eq!(hall_state_at(359_999), hall_state_at(0));
        assert_eq!(hall_state_at(0), HallState(0b101));
        assert_eq!(hall_state_at(720_000 + 45_000), hall_state_at(45_000));
        // u32::MAX = 11 930 turns + 167.295 degrees: sector 2.
        assert_eq!(hall_state_at(u32::MAX), HallState(0b010));
    }

    /// Feeds `n` edges in `direction`, starting from the tracker's state, at `start_us` + `interval_us` * i.
    fn edges(t: &mut HallTracker, direction: Direction, n: u32, start_us: u64, interval_us: u64) -> u64 {
        let mut now = start_us;
        for _ in 0..n {
            let k = t.state().sector().unwrap();
            let next = match direction {
                Direction::Forward => (k + 1) % 6,
                Direction::Reverse => (k + 5) % 6,
            };
            let expected = match direction {
                Direction::Forward => Transition::Forward,
                Direction::Reverse => Transition::Reverse,
            };
            assert_eq!(
                t.on_edge(FORWARD_SEQUENCE[usize::from(next)], Instant::from_micros(now)),
                expected
            );
            now += interval_us;
        }
        now - interval_us
    }

    fn us(v: u64) -> Instant {
        Instant::from_micros(v)
    }

    #[test]
    fn rpm_at_known_speeds() {
        // 4 pole pairs, 1000 rpm: 24 edges per revolution of 60 ms, an edge every 2500 us.
        let mut t = HallTracker::new(4, FORWARD_SEQUENCE[0], us(0));
        let last = edges(&mut t, Direction::Forward, 20, 1000, 2500);
        assert_eq!(t.rpm(us(last)), 1000);
        assert_eq!(t.rpm(us(last + 2000)), 1000);

        let mut t = HallTracker::new(4, FORWARD_SEQUENCE[3], us(0));
        let last = edges(&mut t, Direction::Reverse, 20, 1000, 2500);
        assert_eq!(t.rpm(us(last)), -1000);

        // 4500 rpm, 4 pole pairs: an edge every 555.55 us.
        let mut t = HallTracker::new(4, FORWARD_SEQUENCE[0], us(0));
        let mut k = 0;
        for i in 1..=30u64 {
            k = (k + 1) % 6;
            assert_eq!(t.on_edge(FORWARD_SEQUENCE[k], us(i * 10_000 / 18)), Transition::Forward);
        }
        assert!((t.rpm(us(30 * 10_000 / 18)) - 4500).abs() <= 1);

        // Very slow: 30 rpm at 4 pole pairs is 83 333 us between edges.
        let mut t = HallTracker::new(4, FORWARD_SEQUENCE[5], us(0));
        let last = edges(&mut t, Direction::Forward, 8, 0, 83_333);
        assert_eq!(t.rpm(us(last)), 30);

        // One pole pair, 60 000 rpm: an edge every 166.67 us.
        let mut t = HallTracker::new(1, FORWARD_SEQUENCE[0], us(0));
        let last = edges(&mut t, Direction::Forward, 7, 0, 167);
        assert_eq!(t.rpm(us(last)), 59_880);
    }

    #[test]
    fn zero_pole_pairs_count_as_one() {
        let mut t = HallTracker::new(0, FORWARD_SEQUENCE[0], us(0));
        let last = edges(&mut t, Direction::Forward, 7, 0, 10_000);
        assert_eq!(t.rpm(us(last)), 1000);
    }

    #[test]
    fn rpm_needs_two_edges_in_the_same_direction() {
        let mut t = HallTracker::new(4, FORWARD_SEQUENCE[0], us(0));
        assert_eq!(t.rpm(us(0)), 0);
        assert_eq!(t.rpm(us(1000)), 0);
        assert_eq!(t.on_edge(FORWARD_SEQUENCE[1], us(2500)), Transition::Forward);
        assert_eq!(t.rpm(us(2500)), 0);
        assert_eq!(t.on_edge(FORWARD_SEQUENCE[1], us(3000)), Transition::Same);
        assert_eq!(t.rpm(us(3000)), 0);
        assert_eq!(t.on_edge(FORWARD_SEQUENCE[2], us(5000)), Transition::Forward);
        assert_eq!(t.rpm(us(5000)), 1000);
    }

    #[test]
    fn average_spans_one_electrical_revolution() {
        // Sensor placement error: sectors alternate 2000 and 3000 us; the 6-interval mean is 2500 us.
        let mut t = HallTracker::new(4, FORWARD_SEQUENCE[0], us(0));
        let mut now = 0;
        for i in 0..13u64 {
            now += if i % 2 == 0 { 2000 } else { 3000 };
            let k = (t.state().sector().unwrap() + 1) % 6;
            t.on_edge(FORWARD_SEQUENCE[usize::from(k)], us(now));
        }
        assert_eq!(t.rpm(us(now)), 1000);

        // Only the last 6 intervals count: after a slow start at 5000 us, six at 2500 us read 1000 rpm.
        let mut t = HallTracker::new(4, FORWARD_SEQUENCE[0], us(0));
        let last = edges(&mut t, Direction::Forward, 10, 0, 5000);
        assert_eq!(t.rpm(us(last)), 500);
        let last = edges(&mut t, Direction::Forward, 5, last + 2500, 2500);
        assert_ne!(t.rpm(us(last)), 1000);
        let last = edges(&mut t, Direction::Forward, 1, last + 2500, 2500);
        assert_eq!(t.rpm(us(last)), 1000);
    }

    #[test]
    fn standstill() {
        let mut t = HallTracker::new(4, FORWARD_SEQUENCE[0], us(0));
        let last = edges(&mut t, Direction::Forward, 7, 0, 2500);
        assert_eq!(t.rpm(us(last + 99_000)), 1000);
        assert_eq!(t.rpm(us(last + 99_999)), 1000);
        assert_eq!(t.rpm(us(last + 100_000)), 0);
        assert_eq!(t.rpm(us(last + 101_000)), 0);

        // An edge 99 ms after the last is a (slow) interval; one 101 ms after restarts the average.
        let mut t = HallTracker::new(4, FORWARD_SEQUENCE[0], us(0));
        let last = edges(&mut t, Direction::Forward, 2, 0, 99_000);
        assert_eq!(t.rpm(us(last)), 25);
        let mut t = HallTracker::new(4, FORWARD_SEQUENCE[0], us(0));
        let last = edges(&mut t, Direction::Forward, 2, 0, 101_000);
        assert_eq!(t.rpm(us(last)), 0);
        let last = edges(&mut t, Direction::Forward, 1, last + 2500, 2500);
        assert_eq!(t.rpm(us(last)), 1000);
    }

    #[test]
    fn reversal_restarts_the_average() {
        let mut t = HallTracker::new(4, FORWARD_SEQUENCE[0], us(0));
        let last = edges(&mut t, Direction::Forward, 10, 0, 2500);
        assert_eq!(t.rpm(us(last)), 1000);
        let last = edges(&mut t, Direction::Reverse, 1, last + 5000, 5000);
        assert_eq!(t.rpm(us(last)), 0);
        let last = edges(&mut t, Direction::Reverse, 1, last + 5000, 5000);
        assert_eq!(t.rpm(us(last)), -500);
        let last = edges(&mut t, Direction::Reverse, 10, last + 2500, 2500);
        assert_eq!(t.rpm(us(last)), -1000);
        assert_eq!(t.pulses(), 22);
        // 10 forward, then 12 back: net 2 states back.
        assert_eq!(t.position(), -2);
        assert_eq!(t.illegal_transitions(), 0);
    }

    #[test]
    fn illegal_jump_is_counted_and_zeroes_rpm() {
        let mut t = HallTracker::new(4, FORWARD_SEQUENCE[0], us(0));
        let last = edges(&mut t, Direction::Forward, 10, 0, 2500);
        assert_eq!(t.pulses(), 10);
        let k = t.state().sector().unwrap();
        let jump = FORWARD_SEQUENCE[usize::from((k + 2) % 6)];
        assert_eq!(t.on_edge(jump, us(last + 2500)), Transition::Illegal);
        assert_eq!(t.state(), jump);
        assert_eq!(t.illegal_transitions(), 1);
        assert_eq!(t.pulses(), 10);
        assert_eq!(t.position(), 10, "an illegal jump does not move the position");
        assert_eq!(t.rpm(us(last + 2500)), 0);
        let last = edges(&mut t, Direction::Forward, 1, last + 5000, 2500);
        assert_eq!(t.rpm(us(last)), 0);
        let last = edges(&mut t, Direction::Forward, 1, last + 2500, 2500);
        assert_eq!(t.rpm(us(last)), 1000);
        assert_eq!(t.pulses(), 12);
    }

    #[test]
    fn invalid_states_are_illegal_and_counted() {
        let mut t = HallTracker::new(4, FORWARD_SEQUENCE[0], us(0));
        let last = edges(&mut t, Direction::Forward, 10, 0, 2500);
        assert_eq!(
            t.on_edge(HallState::from_bits(0b000), us(last + 100)),
            Transition::Illegal
        );
        assert!(!t.state().is_valid());
        assert_eq!(t.rpm(us(last + 100)), 0);
        // Still invalid, then leaving it: both illegal, the position having been lost.
        assert_eq!(
            t.on_edge(HallState::from_bits(0b000), us(last + 200)),
            Transition::Illegal
        );
        assert_eq!(t.on_edge(FORWARD_SEQUENCE[4], us(last + 300)), Transition::Illegal);
        assert_eq!(
            t.on_edge(HallState::from_bits(0b111), us(last + 400)),
            Transition::Illegal
        );
        assert_eq!(t.illegal_transitions(), 4);
        assert_eq!(t.pulses(), 10);

        // Starting from an invalid state, the first edge is illegal.
        let mut t = HallTracker::new(4, HallState::from_bits(0b111), us(0));
        assert_eq!(t.on_edge(FORWARD_SEQUENCE[0], us(10)), Transition::Illegal);
        assert_eq!(t.illegal_transitions(), 1);
    }

    #[test]
    fn counters_wrap_and_saturate() {
        let mut t = HallTracker::new(4, FORWARD_SEQUENCE[0], us(0));
        t.pulses = u32::MAX;
        t.illegal = u32::MAX;
        edges(&mut t, Direction::Forward, 1, 10, 10);
        assert_eq!(t.pulses(), 0);
        t.on_edge(HallState::from_bits(0), us(20));
        assert_eq!(t.illegal_transitions(), u32::MAX);
    }

    #[test]
    fn extreme_times_do_not_panic() {
        let mut t = HallTracker::new(255, FORWARD_SEQUENCE[0], Instant::MAX);
        assert_eq!(t.rpm(Instant::MIN), 0);
        edges(&mut t, Direction::Forward, 3, 0, 1_000_000_000_000);
        assert_eq!(t.rpm(Instant::MAX), 0);
        t.on_edge(FORWARD_SEQUENCE[4], Instant::MAX);
        t.on_edge(FORWARD_SEQUENCE[5], Instant::MAX);
        t.on_edge(FORWARD_SEQUENCE[0], Instant::MAX);
        // Edges at the same instant: a 1 us interval, the fastest speed that can be read.
        assert_eq!(t.rpm(Instant::MAX), 10_000_000 / 255 + 1);
        assert_eq!(t.rpm(Instant::MIN), 10_000_000 / 255 + 1);

        let mut t = HallTracker::new(1, FORWARD_SEQUENCE[0], Instant::MIN);
        t.on_edge(FORWARD_SEQUENCE[1], Instant::MIN);
        t.on_edge(FORWARD_SEQUENCE[2], Instant::MIN);
        assert_eq!(t.rpm(Instant::MIN), 10_000_000);
        t.on_edge(FORWARD_SEQUENCE[1], Instant::MAX);
        assert_eq!(t.rpm(Instant::MAX), 0);
        t.on_edge(FORWARD_SEQUENCE[0], Instant::MAX);
        assert_eq!(t.rpm(Instant::MAX), -10_000_000);
    }
}
