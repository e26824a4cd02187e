//! `lbv hil`'s log reader on arbitrary logs: never panics, and passes a log only with the test's start, at least
//! one step, no failed step, no panic, and a PASS verdict whose counts match the steps.
#![no_main]

use std::time::Duration;

use lbv::hil::{EXIT_PASS, Ending, LogLine, MAX_LINE, Outcome, describe, judge};
use lbv::lines::Lines;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut lines = Lines::new(data, MAX_LINE);
    let mut outcome = Outcome::default();
    while let Ok(Some((_, line))) = lines.next_line() {
        if let Some(event) = outcome.feed(&LogLine::from(line)) {
            let _ = describe(&event);
        }
    }
    for ending in [Ending::Verdict, Ending::Timeout, Ending::LogEnded] {
        let (code, _) = judge(&outcome, ending, Duration::from_secs(1));
        if code == EXIT_PASS {
            assert!(outcome.started && outcome.passed > 0 && outcome.failed == 0 && !outcome.panicked);
            let verdict = outcome.verdict.expect("a verdict");
            assert!(verdict.pass && u64::from(verdict.passed) == outcome.passed && verdict.failed == 0);
        }
    }
});
