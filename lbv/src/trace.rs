//! What a bench run records: per-thruster samples over time, and the run's events, within bounds so that memory
//! stays flat however long the run.

use serde::Serialize;

/// The most samples a trace keeps: a longer run keeps every second one of them, then every fourth, and so on
/// (a plot of a day still shows the whole day). About 300 bytes each for six thrusters.
pub const MAX_SAMPLES: usize = 1 << 16;
/// The most events a trace keeps; later ones are counted, not kept.
pub const MAX_EVENTS: usize = 1 << 16;

/// One thruster at one instant.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct ThrusterSample {
    /// Shaft speed, rpm (signed, forward positive).
    pub rpm: f64,
    /// Motor current, A.
    pub current_a: f64,
    /// Winding temperature, deg C.
    pub temperature_c: f64,
    /// The fault bits the thruster reports (tmc-proto `Faults::bits`).
    pub faults: u8,
    /// Whether the master sees the thruster online.
    pub online: bool,
    /// The ordered speed step on the wire (-102..=102).
    pub ordered_step: i8,
}

/// Every thruster at one instant, plus the battery.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Sample {
    /// Virtual time, s.
    pub t: f64,
    /// One entry per thruster, in table order.
    pub thrusters: Vec<ThrusterSample>,
    /// Battery terminal voltage, V.
    pub battery_v: f64,
    /// Whether the vehicle is armed.
    pub armed: bool,
}

/// Something that happened, with its virtual time.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Event {
    /// Virtual time, s.
    pub t: f64,
    /// What happened, in words (e.g. a STATUSTEXT the master sent, or an injected fault).
    pub text: String,
}

/// A run's recording: samples at a fixed interval and events as they happen.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Trace {
    /// Samples, oldest first.
    pub samples: Vec<Sample>,
    /// Events, oldest first.
    pub events: Vec<Event>,
}

/// What goes into a [`Trace`], within bounds: samples only when something reads them (a plot), thinned to at most
/// [`MAX_SAMPLES`]; events up to [`MAX_EVENTS`].
#[derive(Debug, Clone)]
pub struct Recorder {
    keep_samples: bool,
    /// Samples taken so far, kept or not.
    taken: u64,
    /// One sample in this many is kept.
    stride: u64,
    /// Events past [`MAX_EVENTS`], not kept.
    events_dropped: u64,
}

impl Recorder {
    /// A recorder that keeps samples or not.
    pub fn new(keep_samples: bool) -> Self {
        Self {
            keep_samples,
            taken: 0,
            stride: 1,
            events_dropped: 0,
        }
    }

    /// Record a sample into `trace`: kept if samples are, thinned to stay within [`MAX_SAMPLES`].
    pub fn sample(&mut self, trace: &mut Trace, sample: Sample) {
        let index = self.taken;
        self.taken += 1;
        if !self.keep_samples || !index.is_multiple_of(self.stride) {
            return;
        }
        if trace.samples.len() >= MAX_SAMPLES {
            let mut kept = 0;
            trace.samples.retain(|_| {
                kept += 1;
                kept % 2 == 1
            });
            self.stride *= 2;
            if !index.is_multiple_of(self.stride) {
                return;
            }
        }
        trace.samples.push(sample);
    }

    /// Record an event into `trace`: kept while it holds fewer than [`MAX_EVENTS`].
    pub fn event(&mut self, trace: &mut Trace, event: Event) {
        if trace.events.len() < MAX_EVENTS {
            trace.events.push(event);
        } else {
            self.events_dropped += 1;
        }
    }

    /// Events that came after [`MAX_EVENTS`] and were not kept.
    pub fn events_dropped(&self) -> u64 {
        self.events_dropped
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(t: f64) -> Sample {
        Sample { t, ..Sample::default() }
    }

    #[test]
    fn a_long_run_keeps_evenly_spread_samples_within_the_bound() {
        let (mut trace, mut recorder) = (Trace::default(), Recorder::new(true));
        let n = 5 * MAX_SAMPLES as u64 + 3;
        for i in 0..n {
            recorder.sample(&mut trace, at(i as f64));
        }
        assert!(trace.samples.len() <= MAX_SAMPLES);
        assert!(trace.samples.len() > MAX_SAMPLES / 2);
        assert_eq!(trace.samples.first().map(|s| s.t), Some(0.0));
        let stride = trace.samples[1].t - trace.samples[0].t;
        assert_eq!(stride, 8.0);
        assert!(trace.samples.windows(2).all(|pair| pair[1].t - pair[0].t == stride));
        assert!(n as f64 - trace.samples.last().map_or(0.0, |s| s.t) <= stride);
    }

    #[test]
    fn samples_are_dropped_when_nothing_reads_them_and_events_are_bounded() {
        let (mut trace, mut recorder) = (Trace::default(), Recorder::new(false));
        recorder.sample(&mut trace, at(1.0));
        assert!(trace.samples.is_empty());
        for i in 0..MAX_EVENTS + 10 {
            let event = Event {
                t: i as f64,
                text: String::new(),
            };
            recorder.event(&mut trace, event);
        }
        assert_eq!(trace.events.len(), MAX_EVENTS);
        assert_eq!(recorder.events_dropped(), 10);
    }
}
