//! What the acceptance test reports, and how: its steps, prompts, measured figures and verdict, as the report lines
//! the acceptance image writes to its log and as console texts.
//!
//! The report lines ([`Report`]) are what `lbv hil` judges a run by. One line per event:
//!
//! - `ACCEPT start`
//! - `ACCEPT prompt=<name> family=<family> wait_s=<s>: <instruction>`
//! - `ACCEPT step=<name> [family=<family>] result=PASS|FAIL <figure>=<value> ...`
//! - `ACCEPT verdict=PASS|FAIL passed=<n> failed=<m>`
//!
//! [`Report`]'s `Display` writes a line and [`Report::parse`] reads one back: the acceptance image (STM32 and QEMU)
//! writes with the one, `lbv hil` reads with the other.

use core::fmt;
use core::iter::Peekable;
use core::str::SplitAsciiWhitespace;

use embassy_time::Duration;
use tmc_proto::Family;

use crate::shared::{Severity, Text, text};

/// What every report line begins with.
pub const MARKER: &str = "ACCEPT ";

/// One report line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Report<'a> {
    /// The script starts.
    Start,
    /// The person at the bench is asked to do something.
    Prompt {
        /// What is asked.
        prompt: Prompt,
        /// The thruster it concerns.
        family: Family,
        /// Seconds the script waits for it (0: it does not wait).
        wait_s: u32,
        /// What to do, in words: [`Prompt::instruction`] when written, as the line has it when read.
        instruction: &'a str,
    },
    /// A step ended.
    Step(StepResult<&'a str>),
    /// The script ended.
    Verdict(VerdictLine),
}

/// The verdict line: the verdict it states, and the counts. The script states [`Verdict::pass`]; a line whose
/// verdict disagrees with its counts still reads, for its reader to judge.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct VerdictLine {
    /// verdict=PASS.
    pub pass: bool,
    pub passed: u32,
    pub failed: u32,
}

impl From<&Verdict> for VerdictLine {
    fn from(verdict: &Verdict) -> Self {
        Self {
            pass: verdict.pass(),
            passed: verdict.passed.into(),
            failed: verdict.failed.into(),
        }
    }
}

/// Why a text is not a report line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParseError {
    /// It does not begin with [`MARKER`].
    NotAReport,
    /// After the marker comes none of `start`, `prompt=`, `step=` and `verdict=`.
    UnknownReport,
    /// The field with this key is missing, or not where the line has it.
    Missing(&'static str),
    /// The field with this key has a value the format does not have.
    BadValue(&'static str),
    /// A figure is not `<name>=<whole number>`.
    BadFigure,
    /// A step with more than [`MAX_FIGURES`] figures.
    TooManyFigures,
    /// Something follows the line's last field.
    Trailing,
}

impl Report<'static> {
    /// The line for `prompt` on the thruster of `family`, whose operator gets `wait` to do it.
    pub fn prompt(prompt: Prompt, family: Family, wait: Duration) -> Self {
        Report::Prompt {
            prompt,
            family,
            // 32 bits: no 64-bit formatting in the image for it.
            wait_s: u32::try_from(wait.as_secs()).unwrap_or(u32::MAX),
            instruction: prompt.instruction(),
        }
    }
}

impl<'a> Report<'a> {
    /// Read a report line, as [`Display`](fmt::Display) writes it: [`MARKER`] first, nothing after.
    pub fn parse(line: &'a str) -> Result<Self, ParseError> {
        let body = line.strip_prefix(MARKER).ok_or(ParseError::NotAReport)?;
        if body == "start" {
            Ok(Report::Start)
        } else if body.starts_with("prompt=") {
            let (fields, instruction) = body.split_once(": ").ok_or(ParseError::Missing("instruction"))?;
            let mut fields = Fields::of(fields);
            let report = Report::Prompt {
                prompt: fields.value("prompt", Prompt::from_name)?,
                family: fields.value("family", family_from_token)?,
                wait_s: fields.value("wait_s", |value| value.parse().ok())?,
                instruction,
            };
            fields.end(report)
        } else if body.starts_with("step=") {
            let mut fields = Fields::of(body);
            let step = fields.value("step", Step::from_name)?;
            let family = match fields.next_key() {
                Some("family") => Some(fields.value("family", family_from_token)?),
                _ => None,
            };
            let passed = fields.value("result", passed_from_word)?;
            let mut figures = heapless::Vec::new();
            for field in fields.0 {
                let (name, value) = field.split_once('=').ok_or(ParseError::BadFigure)?;
                let value = value.parse().map_err(|_| ParseError::BadFigure)?;
                if name.is_empty() {
                    return Err(ParseError::BadFigure);
                }
                figures
                    .push(Figure { name, value })
                    .map_err(|_| ParseError::TooManyFigures)?;
            }
            Ok(Report::Step(StepResult {
                step,
                family,
                passed,
                figures,
            }))
        } else if body.starts_with("verdict=") {
            let mut fields = Fields::of(body);
            let report = Report::Verdict(VerdictLine {
                pass: fields.value("verdict", passed_from_word)?,
                passed: fields.value("passed", |value| value.parse().ok())?,
                failed: fields.value("failed", |value| value.parse().ok())?,
            });
            fields.end(report)
        } else {
            Err(ParseError::UnknownReport)
        }
    }
}

/// The line: [`MARKER`], then the fields the module's documentation lists.
impl fmt::Display for Report<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(MARKER)?;
        match self {
            Report::Start => f.write_str("start"),
            Report::Prompt {
                prompt,
                family,
                wait_s,
                instruction,
            } => write!(
                f,
                "prompt={} family={} wait_s={wait_s}: {instruction}",
                prompt.name(),
                family_token(*family)
            ),
            Report::Step(result) => {
                write!(f, "step={}", result.step.name())?;
                if let Some(family) = result.family {
                    write!(f, " family={}", family_token(family))?;
                }
                write!(f, " result={}", result_word(result.passed))?;
                for figure in &result.figures {
                    write!(f, " {}={}", figure.name, figure.value)?;
                }
                Ok(())
            }
            Report::Verdict(verdict) => write!(
                f,
                "verdict={} passed={} failed={}",
                result_word(verdict.pass),
                verdict.passed,
                verdict.failed
            ),
        }
    }
}

/// A line's `key=value` fields, read in order.
struct Fields<'a>(Peekable<SplitAsciiWhitespace<'a>>);

impl<'a> Fields<'a> {
    fn of(text: &'a str) -> Self {
        Self(text.split_ascii_whitespace().peekable())
    }

    /// The key of the field next in turn.
    fn next_key(&mut self) -> Option<&'a str> {
        self.0
            .peek()
            .map(|field| field.split_once('=').map_or(*field, |(key, _)| key))
    }

    /// The next field, which must be `key`'s, its value read by `read`.
    fn value<T>(&mut self, key: &'static str, read: impl FnOnce(&'a str) -> Option<T>) -> Result<T, ParseError> {
        let value = self
            .0
            .next()
            .and_then(|field| field.strip_prefix(key)?.strip_prefix('='))
            .ok_or(ParseError::Missing(key))?;
        read(value).ok_or(ParseError::BadValue(key))
    }

    /// `report`, if no field is left.
    fn end<T>(mut self, report: T) -> Result<T, ParseError> {
        match self.0.next() {
            None => Ok(report),
            Some(_) => Err(ParseError::Trailing),
        }
    }
}

/// The steps of the script, in the order they run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Step {
    /// Which of the two family addresses answers.
    Discovery,
    /// Every forward speed step, with the status echo checked.
    SpeedForward,
    /// Every reverse speed step, with the status echo checked.
    SpeedReverse,
    /// Orders with a corrupted checksum change nothing.
    BadChecksum,
    /// Orders with an out-of-range SPEED byte change nothing.
    OutOfRange,
    /// The link failsafe stops the thruster after 1 s of silence, and only a new order restarts it.
    Failsafe,
    /// A held rotor is reported as STALL and stops the drive.
    HeldRotor,
    /// The water-sensor test resistor is reported as WATER.
    Water,
    /// The thruster answers again after its board is reset mid-transfer, and nothing holds the bus.
    Reset,
}

impl Step {
    /// Every step, in the order they run.
    pub const ALL: [Step; 9] = [
        Step::Discovery,
        Step::SpeedForward,
        Step::SpeedReverse,
        Step::BadChecksum,
        Step::OutOfRange,
        Step::Failsafe,
        Step::HeldRotor,
        Step::Water,
        Step::Reset,
    ];

    /// The step's name in the report lines.
    pub const fn name(self) -> &'static str {
        match self {
            Step::Discovery => "discovery",
            Step::SpeedForward => "speed-forward",
            Step::SpeedReverse => "speed-reverse",
            Step::BadChecksum => "bad-checksum",
            Step::OutOfRange => "out-of-range",
            Step::Failsafe => "failsafe",
            Step::HeldRotor => "held-rotor",
            Step::Water => "water",
            Step::Reset => "reset",
        }
    }

    /// The step of that name in the report lines.
    pub(crate) fn from_name(name: &str) -> Option<Step> {
        Step::ALL.into_iter().find(|step| step.name() == name)
    }
}

/// A family's name in the report lines.
pub const fn family_token(family: Family) -> &'static str {
    match family {
        Family::SeaBotix => "seabotix",
        Family::Legacy => "legacy",
    }
}

/// The family of that name in the report lines.
pub(crate) fn family_from_token(token: &str) -> Option<Family> {
    Family::ALL.into_iter().find(|family| family_token(*family) == token)
}

/// A step's result or the verdict in the report lines and console texts.
const fn result_word(passed: bool) -> &'static str {
    if passed { "PASS" } else { "FAIL" }
}

/// PASS or FAIL, read.
fn passed_from_word(word: &str) -> Option<bool> {
    match word {
        "PASS" => Some(true),
        "FAIL" => Some(false),
        _ => None,
    }
}

/// One measured figure of a step. Its name is the script's own `&'static str`, or a line's `&str` when read back
/// ([`Report::parse`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Figure<S = &'static str> {
    /// Its name, one word.
    pub name: S,
    /// In the unit its name ends in (`_ms`: milliseconds, -1 when it never happened; `_da`: 0.1 A), otherwise a
    /// count, a speed step or a 0/1 flag.
    pub value: i32,
}

/// Most figures a step reports.
pub(crate) const MAX_FIGURES: usize = 8;

/// The outcome of one step; `S` is its figures' names' type ([`Figure`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StepResult<S = &'static str> {
    pub step: Step,
    /// The thruster it tested; None for the discovery.
    pub family: Option<Family>,
    pub passed: bool,
    /// What it measured, in the order measured.
    pub figures: heapless::Vec<Figure<S>, MAX_FIGURES>,
}

impl StepResult {
    pub(super) fn new(step: Step, family: Option<Family>) -> Self {
        Self {
            step,
            family,
            passed: true,
            figures: heapless::Vec::new(),
        }
    }

    /// Add a figure; beyond [`MAX_FIGURES`] it is dropped.
    pub(super) fn figure(&mut self, name: &'static str, value: impl TryInto<i32>) {
        let value = value.try_into().unwrap_or(i32::MAX);
        let _ = self.figures.push(Figure { name, value });
    }

    /// Add a duration in whole milliseconds, or -1 when the thing never happened.
    pub(super) fn millis(&mut self, name: &'static str, took: Option<Duration>) {
        self.figure(
            name,
            took.map_or(-1, |took| i64::try_from(took.as_millis()).unwrap_or(i64::MAX)),
        );
    }

    /// Fail the step unless `ok`.
    pub(super) fn require(&mut self, ok: bool) {
        self.passed &= ok;
    }

    /// The value of the figure called `name`.
    #[cfg(test)]
    pub(crate) fn figure_value(&self, name: &str) -> Option<i32> {
        self.figures
            .iter()
            .find(|figure| figure.name == name)
            .map(|figure| figure.value)
    }
}

/// The final verdict: how many steps passed and failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Verdict {
    /// Steps that passed (at most 255: the count saturates).
    pub(crate) passed: u8,
    /// Steps that failed (saturating likewise).
    pub(crate) failed: u8,
}

impl Verdict {
    /// PASS: at least one step ran and none failed.
    pub const fn pass(&self) -> bool {
        self.failed == 0 && self.passed > 0
    }

    pub(super) fn count(&mut self, result: &StepResult) {
        if result.passed {
            self.passed = self.passed.saturating_add(1);
        } else {
            self.failed = self.failed.saturating_add(1);
        }
    }
}

/// A step's result as a console text (STATUSTEXT holds 50 bytes: figures that do not fit are cut off):
/// `<step> [<family>] PASS|FAIL <figure>=<value> ...`, Info when it passed, Error when it failed.
pub(crate) fn step_text(result: &StepResult) -> (Severity, Text) {
    struct Compact<'a>(&'a StepResult);
    impl fmt::Display for Compact<'_> {
        fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            let result = self.0;
            write!(f, "{}", result.step.name())?;
            if let Some(family) = result.family {
                write!(f, " {}", family_token(family))?;
            }
            write!(f, " {}", result_word(result.passed))?;
            for figure in &result.figures {
                write!(f, " {}={}", figure.name, figure.value)?;
            }
            Ok(())
        }
    }
    let severity = if result.passed { Severity::Info } else { Severity::Error };
    (severity, text(format_args!("{}", Compact(result))))
}

/// The verdict as a console text: `acceptance PASS|FAIL passed=<n> failed=<m>`.
pub(crate) fn verdict_text(verdict: &Verdict) -> (Severity, Text) {
    let severity = if verdict.pass() {
        Severity::Notice
    } else {
        Severity::Critical
    };
    let line = text(format_args!(
        "acceptance {} passed={} failed={}",
        result_word(verdict.pass()),
        verdict.passed,
        verdict.failed
    ));
    (severity, line)
}

/// A prompt as a console text: `DO: <instruction>`.
pub(crate) fn prompt_text(prompt: Prompt) -> (Severity, Text) {
    (Severity::Warning, text(format_args!("DO: {}", prompt.instruction())))
}

/// What the script needs a person (or the bench) to do to the thruster board.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Prompt {
    /// Fit the water-sensor test resistor (470 kohm from PB12 to 3V3): the sensor reads water (< 1 Mohm) but no
    /// ground fault (> 100 kohm).
    FitWaterResistor,
    /// Remove the test resistor.
    RemoveWaterResistor,
    /// Hold the rotor: with the motor-less image, press and hold the blue user button B1.
    HoldRotor,
    /// Let the rotor go (release B1).
    ReleaseRotor,
    /// Power-cycle the thruster board while the test keeps the bus busy. A power cycle, not the reset button:
    /// the IDS latches (a Legacy water fault) outlast every other reset.
    ResetThruster,
}

impl Prompt {
    /// Every prompt.
    pub(crate) const ALL: [Prompt; 5] = [
        Prompt::FitWaterResistor,
        Prompt::RemoveWaterResistor,
        Prompt::HoldRotor,
        Prompt::ReleaseRotor,
        Prompt::ResetThruster,
    ];

    /// The prompt of that name in the report lines.
    pub(crate) fn from_name(name: &str) -> Option<Prompt> {
        Prompt::ALL.into_iter().find(|prompt| prompt.name() == name)
    }

    /// The prompt's name in the report lines.
    pub const fn name(self) -> &'static str {
        match self {
            Prompt::FitWaterResistor => "fit-water-resistor",
            Prompt::RemoveWaterResistor => "remove-water-resistor",
            Prompt::HoldRotor => "hold-rotor",
            Prompt::ReleaseRotor => "release-rotor",
            Prompt::ResetThruster => "reset-thruster",
        }
    }

    /// What to do, in words for the person at the bench (short enough for a console text).
    pub(crate) const fn instruction(self) -> &'static str {
        match self {
            Prompt::FitWaterResistor => "fit 470k from PB12 to 3V3 on the thruster",
            Prompt::RemoveWaterResistor => "remove the resistor from PB12",
            Prompt::HoldRotor => "press and hold B1 on the thruster board",
            Prompt::ReleaseRotor => "release B1 on the thruster board",
            Prompt::ResetThruster => "power-cycle the thruster board (USB) now",
        }
    }

    /// The operator acts while the test keeps the bus busy: the prompt returns as soon as the operator is told,
    /// not once it is done.
    pub const fn during_traffic(self) -> bool {
        matches!(self, Prompt::ResetThruster)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn report_lines_have_a_fixed_shape() {
        let mut result = StepResult::new(Step::SpeedForward, Some(Family::Legacy));
        result.figure("steps", 102);
        result.millis("worst_ms", Some(Duration::from_micros(40_900)));
        result.millis("never_ms", None);
        assert_eq!(
            Report::Step(result.clone()).to_string(),
            "ACCEPT step=speed-forward family=legacy result=PASS steps=102 worst_ms=40 never_ms=-1"
        );
        result.require(false);
        assert!(Report::Step(result.clone()).to_string().contains(" result=FAIL "));
        for i in 0..20 {
            result.figure("extra", i);
        }
        assert_eq!(result.figures.len(), MAX_FIGURES, "extra figures are dropped");
        let verdict = |passed, failed| Report::Verdict((&Verdict { passed, failed }).into()).to_string();
        assert_eq!(verdict(9, 0), "ACCEPT verdict=PASS passed=9 failed=0");
        assert_eq!(verdict(8, 1), "ACCEPT verdict=FAIL passed=8 failed=1");
        assert_eq!(
            Report::prompt(Prompt::HoldRotor, Family::SeaBotix, Duration::from_secs(8)).to_string(),
            "ACCEPT prompt=hold-rotor family=seabotix wait_s=8: press and hold B1 on the thruster board"
        );
        assert_eq!(Report::Start.to_string(), "ACCEPT start");
        assert!(!Verdict::default().pass(), "nothing run is no pass");
        let (severity, text) = step_text(&result);
        assert_eq!(severity, Severity::Error);
        assert_eq!(
            text.as_str(),
            "speed-forward legacy FAIL steps=102 worst_ms=40 ne",
            "cut at 50 bytes"
        );
        assert_eq!(
            verdict_text(&Verdict { passed: 9, failed: 0 }),
            (
                Severity::Notice,
                crate::shared::text(format_args!("acceptance PASS passed=9 failed=0"))
            )
        );
        for prompt in Prompt::ALL {
            let (_, text) = prompt_text(prompt);
            assert!(
                text.ends_with(prompt.instruction()),
                "the whole instruction fits: {text}"
            );
        }
        let names: Vec<&str> = Step::ALL.iter().map(|step| step.name()).collect();
        assert!(names.iter().all(|name| !name.contains(' ') && !name.contains('=')));
    }

    #[test]
    fn every_report_reads_back_as_written() {
        let mut step = StepResult::new(Step::Discovery, None);
        step.figure("seabotix", -1);
        step.figure("found", 0);
        step.require(false);
        let mut full = StepResult::new(Step::Reset, Some(Family::Legacy));
        for (name, value) in
            ["a", "b", "c", "d", "e", "f", "g", "h"]
                .into_iter()
                .zip([i32::MIN, -1, 0, 1, 2, 3, 4, i32::MAX])
        {
            full.figure(name, value);
        }
        let mut reports = vec![
            Report::Start,
            Report::Step(step),
            Report::Step(full),
            Report::Step(StepResult::new(Step::Water, Some(Family::SeaBotix))),
            Report::Verdict((&Verdict { passed: 17, failed: 0 }).into()),
            Report::Verdict((&Verdict::default()).into()),
            Report::Verdict(VerdictLine {
                pass: true,
                passed: 0,
                failed: u32::MAX,
            }),
        ];
        for step in Step::ALL {
            reports.push(Report::Step(StepResult::new(step, Some(Family::SeaBotix))));
        }
        for (prompt, family) in Prompt::ALL.into_iter().zip(Family::ALL.into_iter().cycle()) {
            reports.push(Report::prompt(prompt, family, Duration::from_secs(15)));
        }
        for report in reports {
            let line = report.to_string();
            assert_eq!(Report::parse(&line), Ok(report), "{line}");
        }
    }

    #[test]
    fn a_malformed_line_is_a_typed_error() {
        for (line, error) in [
            ("", ParseError::NotAReport),
            ("INFO  ACCEPT start", ParseError::NotAReport),
            ("ACCEPT", ParseError::NotAReport),
            ("ACCEPT begin", ParseError::UnknownReport),
            ("ACCEPT start now", ParseError::UnknownReport),
            ("ACCEPT step=warp result=PASS", ParseError::BadValue("step")),
            (
                "ACCEPT step=water family=aveox result=PASS",
                ParseError::BadValue("family"),
            ),
            (
                "ACCEPT step=water family=legacy result=PA",
                ParseError::BadValue("result"),
            ),
            ("ACCEPT step=water family=legacy", ParseError::Missing("result")),
            ("ACCEPT step=water passed=1 result=PASS", ParseError::Missing("result")),
            ("ACCEPT step=water result=PASS water_ms", ParseError::BadFigure),
            ("ACCEPT step=water result=PASS water_ms=1.5", ParseError::BadFigure),
            ("ACCEPT step=water result=PASS =1", ParseError::BadFigure),
            (
                "ACCEPT step=water result=PASS water_ms=2147483648",
                ParseError::BadFigure,
            ),
            (
                "ACCEPT step=water result=PASS a=1 b=2 c=3 d=4 e=5 f=6 g=7 h=8 i=9",
                ParseError::TooManyFigures,
            ),
            ("ACCEPT verdict=PASS passed=9", ParseError::Missing("failed")),
            (
                "ACCEPT verdict=MAYBE passed=9 failed=0",
                ParseError::BadValue("verdict"),
            ),
            ("ACCEPT verdict=PASS passed=-9 failed=0", ParseError::BadValue("passed")),
            (
                "ACCEPT verdict=PASS passed=9 failed=0 (src/stm32.rs:1)",
                ParseError::Trailing,
            ),
            (
                "ACCEPT prompt=hold-rotor family=legacy wait_s=8",
                ParseError::Missing("instruction"),
            ),
            (
                "ACCEPT prompt=juggle family=legacy wait_s=8: juggle",
                ParseError::BadValue("prompt"),
            ),
            (
                "ACCEPT prompt=hold-rotor wait_s=8: press B1",
                ParseError::Missing("family"),
            ),
            (
                "ACCEPT prompt=hold-rotor family=legacy wait_s=soon: press B1",
                ParseError::BadValue("wait_s"),
            ),
        ] {
            assert_eq!(Report::parse(line), Err(error), "{line}");
        }
    }
}
