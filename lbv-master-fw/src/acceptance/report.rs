//! What the acceptance test reports, and how: its steps, prompts, measured figures and verdict, as the report lines
//! the acceptance image writes to its log and as console texts.

use core::fmt;

use embassy_time::Duration;
use tmc_proto::Family;

use crate::shared::{Severity, Text, text};

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
    /// The bus recovers after the thruster board is reset mid-transfer.
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
}

/// A family's name in the report lines.
pub const fn family_token(family: Family) -> &'static str {
    match family {
        Family::SeaBotix => "seabotix",
        Family::Legacy => "legacy",
    }
}

/// One measured figure of a step: a name and a whole number (milliseconds, counts, steps, 0.1 A).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Figure {
    /// Its name, one word.
    pub name: &'static str,
    /// Its value.
    pub value: i32,
}

/// Most figures a step reports.
pub const MAX_FIGURES: usize = 8;

/// The outcome of one step.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StepResult {
    /// Which step.
    pub step: Step,
    /// The thruster it tested; None for the discovery.
    pub family: Option<Family>,
    /// Whether it passed.
    pub passed: bool,
    /// What it measured.
    pub figures: heapless::Vec<Figure, MAX_FIGURES>,
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
    pub fn figure_value(&self, name: &str) -> Option<i32> {
        self.figures
            .iter()
            .find(|figure| figure.name == name)
            .map(|figure| figure.value)
    }
}

/// The report line's body: `step=<name> [family=<family>] result=PASS|FAIL <figure>=<value> ...`.
impl fmt::Display for StepResult {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "step={}", self.step.name())?;
        if let Some(family) = self.family {
            write!(f, " family={}", family_token(family))?;
        }
        write!(f, " result={}", if self.passed { "PASS" } else { "FAIL" })?;
        for figure in &self.figures {
            write!(f, " {}={}", figure.name, figure.value)?;
        }
        Ok(())
    }
}

/// The final verdict: how many steps passed and failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Verdict {
    /// Steps that passed.
    pub passed: u8,
    /// Steps that failed.
    pub failed: u8,
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

/// The report line's body: `verdict=PASS|FAIL passed=<n> failed=<m>`.
impl fmt::Display for Verdict {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "verdict={} passed={} failed={}",
            if self.pass() { "PASS" } else { "FAIL" },
            self.passed,
            self.failed
        )
    }
}

/// A step's result as a console text (STATUSTEXT holds 50 bytes: figures that do not fit are cut off):
/// `<step> [<family>] PASS|FAIL <figure>=<value> ...`, Info when it passed, Error when it failed.
pub fn step_text(result: &StepResult) -> (Severity, Text) {
    struct Compact<'a>(&'a StepResult);
    impl fmt::Display for Compact<'_> {
        fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            let result = self.0;
            write!(f, "{}", result.step.name())?;
            if let Some(family) = result.family {
                write!(f, " {}", family_token(family))?;
            }
            write!(f, " {}", if result.passed { "PASS" } else { "FAIL" })?;
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
pub fn verdict_text(verdict: &Verdict) -> (Severity, Text) {
    let (severity, word) = if verdict.pass() {
        (Severity::Notice, "PASS")
    } else {
        (Severity::Critical, "FAIL")
    };
    let line = text(format_args!(
        "acceptance {word} passed={} failed={}",
        verdict.passed, verdict.failed
    ));
    (severity, line)
}

/// A prompt as a console text: `DO: <instruction>`.
pub fn prompt_text(prompt: Prompt) -> (Severity, Text) {
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
    pub const fn instruction(self) -> &'static str {
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
            result.to_string(),
            "step=speed-forward family=legacy result=PASS steps=102 worst_ms=40 never_ms=-1"
        );
        result.require(false);
        assert!(result.to_string().contains(" result=FAIL "));
        for i in 0..20 {
            result.figure("extra", i);
        }
        assert_eq!(result.figures.len(), MAX_FIGURES, "extra figures are dropped");
        assert_eq!(
            Verdict { passed: 9, failed: 0 }.to_string(),
            "verdict=PASS passed=9 failed=0"
        );
        assert_eq!(
            Verdict { passed: 8, failed: 1 }.to_string(),
            "verdict=FAIL passed=8 failed=1"
        );
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
        for prompt in [
            Prompt::FitWaterResistor,
            Prompt::RemoveWaterResistor,
            Prompt::HoldRotor,
            Prompt::ReleaseRotor,
            Prompt::ResetThruster,
        ] {
            let (_, text) = prompt_text(prompt);
            assert!(
                text.ends_with(prompt.instruction()),
                "the whole instruction fits: {text}"
            );
        }
        let names: Vec<&str> = Step::ALL.iter().map(|step| step.name()).collect();
        assert!(names.iter().all(|name| !name.contains(' ') && !name.contains('=')));
    }
}
