//! The event engine held against the fixed-step one: every registered scenario runs on both, and they must give
//! the same verdict on every check, the same faults and notes in the same order at nearly the same times, and every
//! metric within the tolerance below, which says why the two may differ at all.
//!
//! Where they differ, the fixed-step engine is the less exact one, in known ways: it fires every timer at its next
//! 50 us step (an I2C transfer of 11 bit times, 110 us, takes 150 us; a bus recovery's 5 us half-clocks take 50 us
//! each), it commutates at the first step after a hall edge (up to 50 us late), and a `run_until` there sees the
//! reaction one step late. The event engine fires timers and edges when they are due.

use serde_json::Value;

use super::harness::{Check, Options, Report, Scenario, run_guarded};
use super::{SCENARIOS, SEED};
use crate::bench::Engine;
use crate::bench::plant::DEFAULT_AMBIENT_C;
use lbv::trace::{Event, Sample, ThrusterSample, Trace};

/// How close a figure must be on the two engines.
#[derive(Debug, Clone, Copy)]
enum Within {
    /// Not compared: the engine's own work and speed.
    Skip,
    /// Equal.
    Same,
    /// `|events - exact| <= absolute`, in the figure's unit.
    Absolute(f64),
    /// `|events - exact| <= fraction * |exact|`, or `floor` whatever the value.
    Relative { fraction: f64, floor: f64 },
}

/// The tolerance of each metric of `scenario`, and the reason for it. A metric not named here (a new scenario's)
/// must agree to 1 %.
fn tolerance(scenario: &str, metric: &str) -> Within {
    // The acceptance test's transfers follow its length (`acceptance_seconds`), and its two resets add the NACKs of
    // an unpowered thruster, some 270 here and 200 there (see `bus_transfers` below).
    if (scenario, metric) == ("acceptance", "bus_transfers") {
        return Within::Relative {
            fraction: 0.1,
            floor: 2.0,
        };
    }
    if back_to_back_update(scenario) {
        match metric {
            m if m.starts_with("update_put") || m.starts_with("fleet_update") => return UPDATE_DRIFT,
            "bus_transfers" => return UPDATE_DRIFT,
            // A thruster restarting into its update answers nothing until its port is up again, and each failed
            // exchange with it recovers the bus: how many fall in that window moves with the exchanges' phase.
            "bus_recoveries" => return UPDATE_DRIFT,
            // A rate of about one poll a second (the count restarts with each thruster's update) is rounded to
            // 0.1: one step of it is a tenth.
            "poll_rate_hz" => {
                return Within::Relative {
                    fraction: 0.08,
                    floor: 0.2,
                };
            }
            "bus_utilisation" => return Within::Absolute(0.015),
            _ => {}
        }
    }
    match metric {
        // The engines' own figures: how fast they ran and how many steps or instants, polls they took.
        "real_time_factor" | "steps" | "task_polls" => Within::Skip,
        // The script's own random draws.
        "faults_drawn" => Within::Same,
        "bus_recoveries" => Within::Same,
        // Each thruster is polled at 50 Hz on both; a poll that meets a fault at its edge counts or not.
        "poll_rate_hz" => Within::Relative {
            fraction: 0.01,
            floor: 0.2,
        },
        // While a thruster is unpowered the master retries its address as fast as the bus allows: 110 us per NACK
        // here, 150 us on the fixed-step engine, so a power cut costs more transfers here.
        "bus_transfers" => Within::Relative {
            fraction: 0.04,
            floor: 2.0,
        },
        "bus_utilisation" => Within::Absolute(0.005),
        // Which thruster's transfer meets a held SDA or a power cut depends on where the poll cycle stands,
        // which the fixed-step engine's longer transfers shift by one; see `link_errors_agree` for the totals.
        "link_errors" => Within::Skip,
        "slave_reinits" | "console_frames_received" | "order_comparisons" => Within::Relative {
            fraction: 0.02,
            floor: 2.0,
        },
        // The limiter acts on the same 50 us grid on both; a commutation up to 50 us late on the fixed-step engine
        // moves when a reversal's current first passes the limit by a step or two of the limiter each time.
        "current_limited_seconds" => Within::Relative {
            fraction: 0.1,
            floor: 0.015,
        },
        // A timer fires at its time here, at the next 50 us step there, and `run_until` sees the reaction one
        // step late there.
        "reaction_ms" | "overcurrent_stop_after_ms" => Within::Absolute(0.1),
        "stall_detected_after_ms" | "console_to_wire_latency_ms" => Within::Absolute(0.25),
        "battery_v_at_end" => Within::Absolute(0.02),
        // The black box's rpm against the bench's own trace: a thruster's status says a whole speed step (44 rpm),
        // and which shaft speed it rounds sits a commutation (up to 50 us) apart on the two engines.
        "worst_rpm_error" => Within::Absolute(5.0),
        // The bytes back include the telemetry the master sends while the file goes in: a put that ends a little
        // later on one engine carries a frame or two more of it (a HEARTBEAT is 21 bytes, ESC telemetry 54).
        "master_update_put_bytes" => Within::Relative {
            fraction: 0.01,
            floor: 300.0,
        },
        // The acceptance test's sweeps wait for 204 speed steps, each to settle within a step of its order at a
        // poll; a settling that ends on the edge of a poll moves by a poll (the fixed-step engine alone moves
        // its slowest step from 319 ms to 46 ms when the pack is 1 mV lower). Its stops wait for the drive off,
        // which a SeaBotix thruster's status shows for a few milliseconds as its current passes zero on the way
        // down: a poll that meets that moment ends the stop (and the next step finds the motor still turning),
        // one that misses it waits some 0.2 s for the ramp's end, and the step after it as long again to spin up.
        "acceptance_seconds" => Within::Relative {
            fraction: 0.04,
            floor: 0.0,
        },
        _ => Within::Relative {
            fraction: 0.01,
            floor: 0.0,
        },
    }
}

/// Whether `scenario` carries thruster updates, whose exchanges follow one another back to back while the vehicle
/// is disarmed: what the fixed-step engine adds to each exchange (its transfers and the thruster's flash stalls end
/// on its 50 us grid, some 0.7 ms an exchange in all) then adds up instead of vanishing into a poll cycle's slack. A
/// put takes 4-6 % longer there, the polls between its exchanges come that much less often, and what follows it
/// comes later by as much.
fn back_to_back_update(scenario: &str) -> bool {
    matches!(scenario, "field-update" | "fleet-update")
}

/// How far the figures of a [`back_to_back_update`] scenario may drift apart.
const UPDATE_DRIFT: Within = Within::Relative {
    fraction: 0.08,
    floor: 0.0,
};

/// Who said an event: its order is compared with the same speaker's events only ([`differences`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Speaker {
    /// The battery monitor's texts.
    Battery,
    /// A thruster link's texts (`T3 online`, `T3 offline: ...`).
    Links,
    /// Everything else.
    Rest,
}

impl Speaker {
    fn of(text: &str) -> Speaker {
        let link = text
            .strip_prefix("STATUSTEXT T")
            .is_some_and(|rest| rest.starts_with(|c: char| c.is_ascii_digit()));
        if text.starts_with("STATUSTEXT BAT ") {
            Speaker::Battery
        } else if link {
            Speaker::Links
        } else {
            Speaker::Rest
        }
    }
}

/// How far apart the two engines may put the same fault, note or console text. The ground station and the battery board
/// send on the same 100 ms grid the master's own checks tick on; what the fixed-step engine delivers 50 us late then
/// lands after such a tick instead of on it, and is noticed one tick later: a 20 ms poll, or a 100 ms battery frame.
/// The acceptance test's prompts follow its sweeps' settling and its stops (see `acceptance_seconds`), a few hundred
/// milliseconds apart: one sweep's or stop's wait moves by 0.2-0.3 s with the poll phase (the Legacy forward sweep took
/// 0.34 s here and 0.15 s there before the thruster's fault filters, 0.13 s and 0.35 s after; since a thruster takes an
/// order only once its bytes have moved, several SeaBotix stops end at a passing zero of the current there and not
/// here), and they add up, so the prompts are held to 4 % of the test's ~39 s, as `acceptance_seconds` is. The field
/// update's uploads are stop-and-wait: each of a file's 224 blocks waits for its reply, and its page for some 34
/// exchanges on the bus, each of whose transfers the fixed-step engine ends up to 50 us later; a block's round trip
/// moves by up to a millisecond, and each put by its share of the time as [`back_to_back_update`] says. Its noisy bus
/// ends an upload whose ground station sends a lost request again after 1 s: whether the noise's end meets one request
/// or the next moves what follows by up to that second.
fn event_slack(scenario: &str, t: f64) -> f64 {
    match scenario {
        "acceptance" => 1.6,
        // And each put drifts as [`back_to_back_update`] says, which the events after it carry.
        "field-update" => 1.1 + 0.08 * t,
        "fleet-update" => 0.105 + 0.08 * t,
        _ => 0.105,
    }
}

/// Whether two numbers agree.
fn close(events: f64, exact: f64, within: Within) -> bool {
    let difference = (events - exact).abs();
    match within {
        Within::Skip => true,
        Within::Same => events == exact,
        Within::Absolute(absolute) => difference <= absolute,
        Within::Relative { fraction, floor } => difference <= (fraction * exact.abs()).max(floor),
    }
}

/// Whether two metric values agree: numbers within `within`, arrays element by element, objects key by key,
/// anything else equal.
fn agree(events: &Value, exact: &Value, within: Within) -> bool {
    match (events, exact, within) {
        (_, _, Within::Skip) => true,
        (Value::Number(a), Value::Number(b), _) => match (a.as_f64(), b.as_f64()) {
            (Some(a), Some(b)) => close(a, b, within),
            _ => a == b,
        },
        (Value::Array(a), Value::Array(b), _) => {
            a.len() == b.len() && a.iter().zip(b).all(|(a, b)| agree(a, b, within))
        }
        (Value::Object(a), Value::Object(b), _) => {
            a.len() == b.len() && a.iter().all(|(key, a)| b.get(key).is_some_and(|b| agree(a, b, within)))
        }
        _ => events == exact,
    }
}

/// The link errors of every thruster, by kind, summed over the thrusters: each within one or 10 %.
fn link_errors_agree(events: Option<&Value>, exact: Option<&Value>) -> bool {
    let totals = |value: Option<&Value>| {
        let mut totals = std::collections::BTreeMap::<String, f64>::new();
        for counts in value
            .and_then(Value::as_object)
            .into_iter()
            .flat_map(|map| map.values())
        {
            for (kind, count) in counts.as_object().into_iter().flatten() {
                *totals.entry(kind.clone()).or_default() += count.as_f64().unwrap_or(f64::NAN);
            }
        }
        totals
    };
    let (a, b) = (totals(events), totals(exact));
    a.keys().eq(b.keys())
        && a.iter().zip(b.values()).all(|((_, a), b)| {
            close(
                *a,
                *b,
                Within::Relative {
                    fraction: 0.1,
                    floor: 1.0,
                },
            )
        })
}

/// An event's text with its figures (every run of digits) left out: the acceptance test's step reports carry
/// figures that are compared through the checks' verdicts instead.
fn without_figures(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        if !c.is_ascii_digit() {
            out.push(c);
        } else if !out.ends_with('#') {
            out.push('#');
        }
    }
    out
}

/// Below this speed (about two of the protocol's speed steps) the speed loop hunts on either engine: it measures
/// the speed from hall edges 30 ms and more apart, and its limit cycle has no steady state to compare.
const CRAWL_RPM: f64 = 100.0;

/// Where one engine's samples leave the other's in steady running. Around each sample, the other engine's samples
/// within `slack` seconds (the same happening may come that much apart, see [`event_slack`]) make a window; where a
/// thruster runs steadily in it (its speed moves less than the rpm tolerance, above [`CRAWL_RPM`]), this sample's
/// speed must lie within
/// the window's range widened by 1 % (at least 10 rpm); where its current is steady too (the windows of both move
/// less than 25 %: the speed loop dithers the duty, and the current of a loaded motor is the small difference of
/// the drive and the back-EMF, so a sample moves by several percent from one tick to the next on either engine),
/// the mean current over this engine's window must be within 10 % (at least 0.1 A) of the other's. The winding
/// temperature must always lie within 0.2 C and 5 % of its rise above the water of the window's range (a transient
/// a poll earlier or later heats the winding a little more or less, which its 30 s time constant keeps for a
/// while), and the battery's voltage within 0.05 V of it wherever it is steady to 0.05 V.
fn samples_stray(name: &str, ours: &Trace, theirs: &Trace, slack: f64) -> Vec<String> {
    let window = |samples: &[Sample], t: f64| -> std::ops::Range<usize> {
        let start = samples.partition_point(|other| other.t < t - slack);
        let end = samples.partition_point(|other| other.t <= t + slack);
        start..end.max(start)
    };
    let range = |values: &mut dyn Iterator<Item = f64>| {
        values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), y| (lo.min(y), hi.max(y)))
    };
    let mean = |values: &[f64]| values.iter().sum::<f64>() / values.len().max(1) as f64;
    let mut stray = Vec::new();
    for sample in &ours.samples {
        let (mine, others) = (
            &ours.samples[window(&ours.samples, sample.t)],
            &theirs.samples[window(&theirs.samples, sample.t)],
        );
        if others.is_empty() {
            continue;
        }
        let mut say = |what: String| {
            if stray.len() < 10 {
                stray.push(format!("{name}: at {:.3} s {what} (within {slack} s)", sample.t));
            }
        };
        for (i, thruster) in sample.thrusters.iter().enumerate() {
            let figure = |samples: &[Sample], f: fn(&ThrusterSample) -> f64| -> Vec<f64> {
                samples.iter().filter_map(|s| s.thrusters.get(i).map(f)).collect()
            };
            let (lo, hi) = range(&mut figure(others, |t| t.rpm).into_iter());
            let rpm_tolerance = (0.01 * thruster.rpm.abs()).max(10.0);
            if hi - lo <= rpm_tolerance && lo.abs().max(hi.abs()) >= CRAWL_RPM {
                if !(lo - rpm_tolerance..=hi + rpm_tolerance).contains(&thruster.rpm) {
                    say(format!(
                        "T{} turns at {:.1} rpm, the other engine {lo:.1}..{hi:.1}",
                        i + 1,
                        thruster.rpm
                    ));
                }
                let (currents, theirs) = (figure(mine, |t| t.current_a), figure(others, |t| t.current_a));
                let (a, b) = (mean(&currents), mean(&theirs));
                let (lo, hi) = range(&mut theirs.iter().chain(&currents).copied());
                let steady = hi - lo <= 0.25 * b.abs() + 0.1;
                if steady && (a - b).abs() > (0.1 * b.abs()).max(0.1) {
                    say(format!(
                        "T{} draws {a:.3} A on average, the other engine {b:.3} A",
                        i + 1
                    ));
                }
            }
            let (lo, hi) = range(&mut figure(others, |t| t.temperature_c).into_iter());
            let heat_tolerance = 0.2 + 0.05 * (thruster.temperature_c - DEFAULT_AMBIENT_C).abs();
            if !(lo - heat_tolerance..=hi + heat_tolerance).contains(&thruster.temperature_c) {
                say(format!(
                    "T{} winding at {:.2} C, the other engine {lo:.2}..{hi:.2}",
                    i + 1,
                    thruster.temperature_c
                ));
            }
        }
        let (lo, hi) = range(&mut others.iter().map(|other| other.battery_v));
        if hi - lo <= 0.05 && !(lo - 0.05..=hi + 0.05).contains(&sample.battery_v) {
            say(format!(
                "the battery at {:.3} V, the other engine {lo:.3}..{hi:.3}",
                sample.battery_v
            ));
        }
    }
    stray
}

/// Every way the two runs of `scenario` disagree.
fn differences(scenario: &Scenario, events: &(Report, Trace), exact: &(Report, Trace)) -> Vec<String> {
    let name = scenario.name;
    let ((a, a_trace), (b, b_trace)) = (events, exact);
    let mut found = Vec::new();
    let verdicts = |checks: &[Check]| -> Vec<(String, bool)> {
        checks.iter().map(|check| (check.name.clone(), check.passed)).collect()
    };
    if verdicts(&a.checks) != verdicts(&b.checks) {
        found.push(format!(
            "{name}: check verdicts differ\n  events: {:?}\n  exact:  {:?}",
            a.checks, b.checks
        ));
    }
    for (metric, exact_value) in &b.metrics {
        let within = tolerance(name, metric);
        let events_value = a.metrics.get(metric);
        let agrees = match events_value {
            Some(value) => agree(value, exact_value, within),
            None => matches!(within, Within::Skip),
        };
        if !agrees {
            found.push(format!(
                "{name}: metric {metric}: events {events_value:?}, exact {exact_value} (within {within:?})"
            ));
        }
    }
    for metric in a.metrics.keys().filter(|metric| !b.metrics.contains_key(*metric)) {
        found.push(format!("{name}: metric {metric} only on the event engine"));
    }
    if !link_errors_agree(a.metrics.get("link_errors"), b.metrics.get("link_errors")) {
        found.push(format!(
            "{name}: link error totals differ: events {:?}, exact {:?}",
            a.metrics.get("link_errors"),
            b.metrics.get("link_errors")
        ));
    }
    // Each of the vehicle's speakers is compared on its own: the battery monitor, the thruster links, and the rest
    // (the update server and courier, the vehicle, the bench's notes) each speak in their own order on both
    // engines, but two of them may interleave either way when they speak within a tick of each other (after a
    // master reset: the battery's first report on its 100 ms grid and the first polls). An upload's progress, said
    // at most once a second, is a sample of it, not an event: how many texts an upload gets depends on where its
    // start falls in the second, which the engines may put either side of a tick. So is a family apply's.
    let events = |trace: &Trace, speaker: Speaker| -> Vec<Event> {
        trace
            .events
            .iter()
            .filter(|event| Speaker::of(&event.text) == speaker)
            .filter(|event| {
                let text = without_figures(&event.text);
                !text.ends_with(".lbvu: # of # bytes") && !text.contains(".lbvu: # of # done, T")
            })
            .cloned()
            .collect()
    };
    for speaker in [Speaker::Battery, Speaker::Links, Speaker::Rest] {
        let (a_events, b_events) = (&events(a_trace, speaker), &events(b_trace, speaker));
        let texts =
            |events: &[Event]| -> Vec<String> { events.iter().map(|event| without_figures(&event.text)).collect() };
        // A STATUSTEXT is cut at 50 characters: longer figures leave less of the rest.
        let same = |a: &String, b: &String| a.starts_with(b.as_str()) || b.starts_with(a.as_str());
        let (a_texts, b_texts) = (texts(a_events), texts(b_events));
        if a_texts.len() != b_texts.len() || !a_texts.iter().zip(&b_texts).all(|(a, b)| same(a, b)) {
            found.push(format!(
                "{name}: the events of {speaker:?} differ\n  events: {:?}\n  exact:  {:?}",
                a_texts, b_texts
            ));
        } else {
            for (x, y) in a_events.iter().zip(b_events) {
                let slack = event_slack(name, x.t.max(y.t));
                if (x.t - y.t).abs() > slack {
                    found.push(format!(
                        "{name}: \"{}\" at {:.5} s here, {:.5} s on the fixed-step engine (within {slack} s)",
                        x.text, x.t, y.t
                    ));
                }
            }
        }
    }
    let slack = event_slack(name, 0.0);
    found.extend(samples_stray(name, a_trace, b_trace, slack));
    found.extend(samples_stray(name, b_trace, a_trace, slack));
    found
}

/// Every registered scenario on both engines.
#[test]
fn every_scenario_agrees_on_both_engines() {
    let found: Vec<String> = SCENARIOS
        .iter()
        .flat_map(|scenario| {
            let [events, exact] =
                [Engine::Events, Engine::Exact].map(|engine| run_guarded(scenario, &Options::new(SEED, engine), None));
            differences(scenario, &events, &exact)
        })
        .collect();
    assert!(found.is_empty(), "{} differences:\n{}", found.len(), found.join("\n"));
}
