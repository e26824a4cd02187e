//! `lbv hil`: the bench test between two dev kits, run from the host.
//!
//! It builds the motor-less thruster image and the master's acceptance image, flashes the thruster board and
//! starts it, then flashes and runs the master board with `probe-rs run`, following its defmt log: the master's
//! acceptance test reports its start, every prompt to the person at the bench, every step and the verdict as report
//! lines, which [`Report::parse`] reads (their format is `lbv_master_fw::acceptance::report`'s).
//!
//! The pieces are separate so that they can be tested without boards: [`plan`] builds the commands, [`parse_line`]
//! and [`Outcome`] read the log, [`follow`] runs the log through them against the clock, [`judge`] turns the
//! outcome into the exit status; [`main`] only starts processes and wires them together. `--replay LOG` follows a
//! recorded log instead of a board's, `--dry-run` prints the commands without running them.

use std::fs::File;
use std::io::{BufReader, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ExitCode, Stdio};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, SyncSender};
use std::time::{Duration, Instant};

use lbv_master_fw::acceptance::report::{MARKER, Report, Step, VerdictLine, family_token};
use tmc_proto::Family;

use crate::lines::{Line, Lines};

const HELP: &str = "\
The bench test between the master's NUCLEO-G474RE and a thruster's NUCLEO-G431RB (docs/devkit-bench.md):
builds the motor-less thruster image and the master's acceptance image, flashes the thruster board
and starts it, flashes and runs the master board with probe-rs, and follows the master's log until
the test's verdict.

Exit status: 0 verdict PASS; 1 verdict FAIL or a failed step; 2 bad command line, or a build or
flash failed; 3 no verdict before the timeout; 4 the log ended without a verdict.";

/// Exit status: the verdict was PASS.
pub const EXIT_PASS: u8 = crate::exit::OK;
/// Exit status: the verdict was FAIL, or a step failed.
pub const EXIT_FAIL: u8 = crate::exit::FAILED;
/// Exit status: bad usage, or a build or flash command failed.
pub const EXIT_SETUP: u8 = crate::exit::TROUBLE;
/// Exit status: no verdict before the timeout.
pub const EXIT_TIMEOUT: u8 = 3;
/// Exit status: the log ended without a verdict.
pub const EXIT_NO_VERDICT: u8 = 4;

/// The firmware target.
pub const TARGET: &str = "thumbv7em-none-eabihf";
/// The thruster's chip (NUCLEO-G431RB), as probe-rs names it.
pub const THRUSTER_CHIP: &str = "STM32G431RBTx";
/// The master's chip (NUCLEO-G474RE), as probe-rs names it.
pub const MASTER_CHIP: &str = "STM32G474RETx";
/// The NUCLEO-G431RB's on-board ST-LINK/V3E, as probe-rs selects probes: VID:PID.
pub const ST_LINK_V3E: &str = "0483:374e";
/// The defmt line format asked of probe-rs: level and message, one line per log frame.
const LOG_FORMAT: &str = "{L} {s}";
/// The longest wait for a verdict that --timeout takes: a day.
const MAX_TIMEOUT_S: f64 = 86_400.0;
/// Longest log line read whole; a longer one is cut, written to the log as cut, and never read as a report line.
pub const MAX_LINE: usize = 8192;
/// Batches of log lines in flight between the thread that reads them and the one that follows them.
const IN_FLIGHT: usize = 16;
/// A batch holds the lines read without waiting, up to about this many bytes of text.
const BATCH_BYTES: usize = 64 * 1024;

/// `lbv hil`'s command line.
#[derive(Debug, Clone, PartialEq, clap::Parser)]
#[command(after_help = HELP)]
pub struct Args {
    /// The master board's ST-LINK, by serial number (`probe-rs list` shows them), or as VID:PID:SERIAL
    #[arg(long, value_name = "SERIAL", value_parser = probe_arg, required_unless_present = "replay")]
    pub master_probe: Option<String>,
    /// The thruster board's ST-LINK, likewise
    #[arg(long, value_name = "SERIAL", value_parser = probe_arg, required_unless_present = "replay")]
    pub thruster_probe: Option<String>,
    /// The thruster image's controller family
    #[arg(long, value_enum, default_value_t = FamilyArg::Seabotix)]
    pub family: FamilyArg,
    /// Give up after S seconds without a verdict (0 < S <= 86400)
    #[arg(long, value_name = "S", default_value = "300", value_parser = timeout_seconds)]
    pub timeout: Duration,
    /// Keep the master's whole log in FILE
    #[arg(long, value_name = "FILE")]
    pub log: Option<PathBuf>,
    /// Print the commands and run nothing
    #[arg(long)]
    pub dry_run: bool,
    /// Follow a recorded log instead of a board's
    #[arg(long, value_name = "LOG", conflicts_with_all = ["master_probe", "thruster_probe", "dry_run"])]
    pub replay: Option<PathBuf>,
}

/// The thruster image's family, as the command line names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum FamilyArg {
    /// SeaBotix (0x52/0x53, 7-byte status)
    Seabotix,
    /// Aveox / Legacy (0x54/0x55, 4-byte status)
    Legacy,
}

impl From<FamilyArg> for Family {
    fn from(family: FamilyArg) -> Family {
        match family {
            FamilyArg::Seabotix => Family::SeaBotix,
            FamilyArg::Legacy => Family::Legacy,
        }
    }
}

/// `--timeout`: seconds, positive, finite, at most [`MAX_TIMEOUT_S`].
fn timeout_seconds(text: &str) -> Result<Duration, String> {
    let seconds: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("{text:?} is not a number of seconds"))?;
    if seconds.is_finite() && seconds > 0.0 && seconds <= MAX_TIMEOUT_S {
        Ok(Duration::from_secs_f64(seconds))
    } else {
        Err(format!("{text} is outside 0 < S <= {MAX_TIMEOUT_S}"))
    }
}

/// What the command line asked for, checked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Options {
    /// The master board's probe, as given.
    pub master_probe: String,
    /// The thruster board's probe, as given.
    pub thruster_probe: String,
    /// The thruster image's family.
    pub family: Family,
    /// How long to wait for the verdict.
    pub timeout: Duration,
    /// Where to keep the master's log.
    pub log: Option<PathBuf>,
    /// Print the commands only.
    pub dry_run: bool,
    /// Follow this recorded log instead of running anything.
    pub replay: Option<PathBuf>,
}

impl TryFrom<Args> for Options {
    type Error = String;

    /// The rule clap's attributes do not say: two boards need two probes.
    fn try_from(args: Args) -> Result<Options, String> {
        let (master_probe, thruster_probe) = (
            args.master_probe.unwrap_or_default(),
            args.thruster_probe.unwrap_or_default(),
        );
        if args.replay.is_none() && master_probe == thruster_probe {
            return Err("the two boards need two probes: --master-probe and --thruster-probe are the same".into());
        }
        Ok(Options {
            master_probe,
            thruster_probe,
            family: args.family.into(),
            timeout: args.timeout,
            log: args.log,
            dry_run: args.dry_run,
            replay: args.replay,
        })
    }
}

/// A probe argument: a serial number, or VID:PID:SERIAL; nothing that a shell or probe-rs would read otherwise.
pub fn probe_arg(text: &str) -> Result<String, String> {
    let fine = !text.is_empty() && text.chars().all(|c| c.is_ascii_alphanumeric() || c == ':');
    if fine {
        Ok(text.to_string())
    } else {
        Err(format!("{text:?} is not a serial number (or VID:PID:SERIAL)"))
    }
}

/// The probe selector probe-rs takes: VID:PID:SERIAL, the NUCLEO's ST-LINK/V3E unless the VID:PID is given.
pub fn probe_selector(probe: &str) -> String {
    if probe.contains(':') {
        probe.to_string()
    } else {
        format!("{ST_LINK_V3E}:{probe}")
    }
}

/// One command of the plan.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Command {
    /// What it is for, in words.
    pub what: &'static str,
    /// Where it runs, when that matters (Cargo reads the workspace's `.cargo/config.toml` from there).
    pub dir: Option<PathBuf>,
    /// The program.
    pub program: String,
    /// Its arguments.
    pub args: Vec<String>,
}

impl Command {
    /// A command run where `lbv` runs.
    pub fn new(what: &'static str, program: &str, args: &[&str]) -> Self {
        Self {
            what,
            dir: None,
            program: program.to_string(),
            args: args.iter().map(|arg| arg.to_string()).collect(),
        }
    }

    /// The command as a shell line (arguments with spaces or braces quoted).
    pub fn line(&self) -> String {
        let mut line = self
            .dir
            .as_ref()
            .map_or_else(String::new, |dir| format!("cd {} && ", dir.display()));
        line.push_str(&self.program);
        for arg in &self.args {
            line.push(' ');
            if arg.contains([' ', '{', '}']) {
                line.push_str(&format!("'{arg}'"));
            } else {
                line.push_str(arg);
            }
        }
        line
    }

    /// The command, ready to run.
    pub fn process(&self) -> std::process::Command {
        let mut command = std::process::Command::new(&self.program);
        command.args(&self.args);
        if let Some(dir) = &self.dir {
            command.current_dir(dir);
        }
        command
    }
}

/// The images' ELF files in `target_dir` (Cargo's target directory).
pub fn elf(target_dir: &Path, binary: &str) -> PathBuf {
    target_dir.join(TARGET).join("release").join(binary)
}

/// The commands, in order: build the thruster image (motor-less, of the chosen family) and its bootloader in
/// `workspace`; erase the thruster board (so that no update left on trial by an earlier run reverts the new
/// image), flash its bootloader and image and reset it so that it runs; then the same for the master (its
/// bootloader, and its acceptance image expecting that family), whose image is run with its defmt log streamed.
/// Only the last one's output is followed. The two bootloaders are one crate built for each board, so each is
/// flashed before the other is built.
pub fn plan(options: &Options, workspace: &Path, target_dir: &Path) -> Vec<Command> {
    let legacy = options.family == Family::Legacy;
    let thruster_features = if legacy { "motorless,legacy" } else { "motorless" };
    let master_features = if legacy { "acceptance,legacy" } else { "acceptance" };
    let thruster_elf = elf(target_dir, "thruster-fw").display().to_string();
    let bootloader_elf = elf(target_dir, "lbv-boot").display().to_string();
    let master_elf = elf(target_dir, "lbv-master-fw").display().to_string();
    let thruster_probe = probe_selector(&options.thruster_probe);
    let master_probe = probe_selector(&options.master_probe);
    // Bench images: they may accept update files signed with the development key (keys/README.md).
    let build = |package: &str, features: &[&str]| Command {
        dir: Some(workspace.to_path_buf()),
        ..Command::new(
            "build",
            "env",
            &[
                &[
                    "LBV_ALLOW_DEV_KEY=1",
                    "cargo",
                    "build",
                    "--release",
                    "--target",
                    TARGET,
                    "-p",
                    package,
                ],
                features,
            ]
            .concat(),
        )
    };
    vec![
        Command {
            what: "build the thruster image",
            ..build("thruster-fw", &["--features", thruster_features])
        },
        Command {
            what: "build the thruster's bootloader",
            ..build("lbv-boot", &["--features", "thruster"])
        },
        Command::new(
            "erase the thruster board",
            "probe-rs",
            &["erase", "--chip", THRUSTER_CHIP, "--probe", &thruster_probe],
        ),
        Command::new(
            "flash the thruster's bootloader",
            "probe-rs",
            &[
                "download",
                "--chip",
                THRUSTER_CHIP,
                "--probe",
                &thruster_probe,
                &bootloader_elf,
            ],
        ),
        Command::new(
            "flash the thruster image",
            "probe-rs",
            &[
                "download",
                "--chip",
                THRUSTER_CHIP,
                "--probe",
                &thruster_probe,
                &thruster_elf,
            ],
        ),
        Command::new(
            "start the thruster board",
            "probe-rs",
            &["reset", "--chip", THRUSTER_CHIP, "--probe", &thruster_probe],
        ),
        Command {
            what: "build the master's bootloader",
            ..build("lbv-boot", &["--features", "master"])
        },
        Command {
            what: "build the master image",
            ..build("lbv-master-fw", &["--features", master_features])
        },
        Command::new(
            "erase the master board",
            "probe-rs",
            &["erase", "--chip", MASTER_CHIP, "--probe", &master_probe],
        ),
        Command::new(
            "flash the master's bootloader",
            "probe-rs",
            &[
                "download",
                "--chip",
                MASTER_CHIP,
                "--probe",
                &master_probe,
                &bootloader_elf,
            ],
        ),
        Command::new(
            "flash and run the master board, following its log",
            "probe-rs",
            &[
                "run",
                "--chip",
                MASTER_CHIP,
                "--probe",
                &master_probe,
                "--log-format",
                LOG_FORMAT,
                &master_elf,
            ],
        ),
    ]
}

/// The image's text in a log line from where its report line begins: what probe-rs adds after it (a colour code,
/// the log's location ` (file:line)`) left off.
fn report_text(text: &str) -> &str {
    let text = text.split('\u{1b}').next().unwrap_or(text).trim_end();
    let location = |suffix: &str| {
        suffix
            .strip_suffix(')')
            .and_then(|location| location.rsplit_once(':'))
            .is_some_and(|(file, line)| {
                !file.is_empty() && !line.is_empty() && line.bytes().all(|b| b.is_ascii_digit())
            })
    };
    match text.rsplit_once(" (") {
        Some((report, suffix)) if location(suffix) => report,
        _ => text,
    }
}

/// Read one log line: the report line it holds, None for anything else (probe-rs's own output, other log lines, a
/// report line cut off or malformed).
pub fn parse_line(line: &str) -> Option<Report<'_>> {
    let at = line.find(MARKER)?;
    Report::parse(report_text(line.get(at..)?)).ok()
}

/// A failed step, as the summary names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FailedStep {
    /// Which step.
    pub step: Step,
    /// The thruster it tested, when it tests one.
    pub family: Option<Family>,
}

/// Failed steps whose lines are kept for the summary; all are counted.
pub const MAX_FAILURES: usize = 100;

/// One line of the master's log as read: its text (bytes that are not UTF-8 shown as U+FFFD) and whether it was
/// longer than [`MAX_LINE`] and cut.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogLine {
    /// The text, or the first [`MAX_LINE`] bytes of it.
    pub text: String,
    /// The line was longer and is cut.
    pub cut: bool,
}

impl From<Line<'_>> for LogLine {
    fn from(line: Line<'_>) -> LogLine {
        LogLine {
            text: String::from_utf8_lossy(line.bytes()).into_owned(),
            cut: matches!(line, Line::TooLong { .. }),
        }
    }
}

impl From<&str> for LogLine {
    fn from(text: &str) -> LogLine {
        LogLine {
            text: text.to_string(),
            cut: false,
        }
    }
}

/// What a log said, line by line. Its size does not grow with the log: counts, and the first [`MAX_FAILURES`]
/// failed steps.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Outcome {
    /// The test's start line was seen.
    pub started: bool,
    /// Steps that passed.
    pub passed: u64,
    /// Steps that failed.
    pub failed: u64,
    /// The first failed steps, in order.
    pub failures: Vec<FailedStep>,
    /// Prompts seen.
    pub prompts: u64,
    /// The verdict, once seen.
    pub verdict: Option<VerdictLine>,
    /// The firmware panicked (its panic handler's "panicked at").
    pub panicked: bool,
    /// Lines cut for their length: never read as report lines.
    pub cut_lines: u64,
}

impl Outcome {
    /// Take one log line; returns the report line it held, if any.
    pub fn feed<'l>(&mut self, line: &'l LogLine) -> Option<Report<'l>> {
        if line.text.contains("panicked at") {
            self.panicked = true;
        }
        if line.cut {
            self.cut_lines += 1;
            return None;
        }
        let report = parse_line(&line.text)?;
        match &report {
            Report::Start => self.started = true,
            Report::Step(step) if step.passed => self.passed += 1,
            Report::Step(step) => {
                self.failed += 1;
                if self.failures.len() < MAX_FAILURES {
                    self.failures.push(FailedStep {
                        step: step.step,
                        family: step.family,
                    });
                }
            }
            Report::Prompt { .. } => self.prompts += 1,
            Report::Verdict(verdict) => self.verdict = Some(*verdict),
        }
        Some(report)
    }

    /// Read a whole log.
    #[cfg(test)]
    pub fn of_log(log: &str) -> Outcome {
        let mut outcome = Outcome::default();
        for line in log.lines() {
            outcome.feed(&line.into());
        }
        outcome
    }

    /// Steps reported, passed or failed.
    pub fn steps(&self) -> u64 {
        self.passed + self.failed
    }
}

/// How following the log ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ending {
    /// The verdict line came.
    Verdict,
    /// The timeout passed first.
    Timeout,
    /// The log ended first (probe-rs exited, the probe was unplugged, the recording ended).
    LogEnded,
}

/// The exit status and a one-line summary for an outcome.
///
/// PASS needs the test's start line, at least one step, the verdict PASS, no failed step line, step counts that
/// match the verdict's, and no panic; a verdict that contradicts the step lines is a FAIL.
pub fn judge(outcome: &Outcome, ending: Ending, timeout: Duration) -> (u8, String) {
    let (passed, failed) = (outcome.passed, outcome.failed);
    if outcome.panicked {
        return (EXIT_FAIL, "FAIL: the master panicked".into());
    }
    match outcome.verdict {
        Some(verdict) => {
            let consistent = u64::from(verdict.passed) == passed && u64::from(verdict.failed) == failed;
            if !outcome.started || outcome.steps() == 0 {
                (
                    EXIT_FAIL,
                    format!(
                        "FAIL: a verdict with {} (a verdict alone proves nothing)",
                        if outcome.started {
                            "no step reported"
                        } else {
                            "no start line before it"
                        }
                    ),
                )
            } else if verdict.pass && failed == 0 && consistent {
                (EXIT_PASS, format!("PASS: {passed} steps passed"))
            } else if !consistent {
                (
                    EXIT_FAIL,
                    format!(
                        "FAIL: the verdict counts {} passed and {} failed, the log shows {passed} and {failed}",
                        verdict.passed, verdict.failed
                    ),
                )
            } else {
                (EXIT_FAIL, format!("FAIL: {failed} of {} steps failed", passed + failed))
            }
        }
        None if failed > 0 => {
            let code = if ending == Ending::Timeout {
                EXIT_TIMEOUT
            } else {
                EXIT_NO_VERDICT
            };
            (code, format!("FAIL: {failed} steps failed, and no verdict came"))
        }
        None => match ending {
            Ending::Timeout => (
                EXIT_TIMEOUT,
                format!(
                    "FAIL: no verdict within {} s ({} steps reported)",
                    timeout.as_secs_f64(),
                    outcome.steps()
                ),
            ),
            Ending::LogEnded | Ending::Verdict => (
                EXIT_NO_VERDICT,
                format!(
                    "FAIL: the log ended without a verdict ({} steps reported)",
                    outcome.steps()
                ),
            ),
        },
    }
}

/// A report line for the terminal.
pub fn describe(report: &Report<'_>) -> String {
    match report {
        Report::Start => "acceptance test started".into(),
        Report::Step(step) => {
            let figures: Vec<String> = step.figures.iter().map(|f| format!("{}={}", f.name, f.value)).collect();
            format!(
                "  {} {:<9} {:<14} {}",
                if step.passed { "ok  " } else { "FAIL" },
                step.family.map_or("", family_token),
                step.step.name(),
                figures.join(" ")
            )
        }
        Report::Prompt {
            prompt,
            family,
            instruction,
            ..
        } => format!(
            ">>> {} thruster: {instruction} ({})",
            family_token(*family),
            prompt.name()
        ),
        Report::Verdict(verdict) => format!(
            "verdict {}: {} passed, {} failed",
            if verdict.pass { "PASS" } else { "FAIL" },
            verdict.passed,
            verdict.failed
        ),
    }
}

/// Follow log lines as they arrive until the verdict, the end of the log or `timeout`: every line goes to `log`
/// (when given), every report line to `out`.
pub fn follow(
    lines: &Receiver<Vec<LogLine>>,
    timeout: Duration,
    mut log: Option<&mut dyn Write>,
    out: &mut dyn Write,
) -> (Outcome, Ending) {
    let deadline = Instant::now() + timeout;
    let mut outcome = Outcome::default();
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        let batch = match lines.recv_timeout(left) {
            Ok(batch) => batch,
            Err(RecvTimeoutError::Timeout) => return (outcome, Ending::Timeout),
            Err(RecvTimeoutError::Disconnected) => return (outcome, Ending::LogEnded),
        };
        for line in batch {
            if let Some(log) = log.as_mut() {
                let _ = writeln!(log, "{}", line.text);
            }
            if let Some(report) = outcome.feed(&line) {
                let _ = writeln!(out, "{}", describe(&report));
                if matches!(report, Report::Verdict(_)) {
                    return (outcome, Ending::Verdict);
                }
            }
        }
    }
}

/// Send every line of `source` to a channel from a thread of its own, in batches: a batch goes as soon as the
/// reader would wait for more input (so a live log is followed line by line) or holds [`BATCH_BYTES`]. The
/// channel closes at the end of the input (or at a read error); it is bounded, so the reader waits while the
/// follower is behind.
fn lines_of(source: impl Read + Send + 'static, to: SyncSender<Vec<LogLine>>) {
    std::thread::spawn(move || {
        let mut lines = Lines::new(BufReader::new(source), MAX_LINE);
        let (mut batch, mut bytes) = (Vec::new(), 0);
        while let Ok(Some((_, line))) = lines.next_line() {
            let line = LogLine::from(line);
            bytes += line.text.len();
            batch.push(line);
            if lines.get_ref().buffer().is_empty() || bytes >= BATCH_BYTES {
                if to.send(std::mem::take(&mut batch)).is_err() {
                    return;
                }
                bytes = 0;
            }
        }
        if !batch.is_empty() {
            let _ = to.send(batch);
        }
    });
}

/// The workspace this tool was built in.
pub fn workspace() -> PathBuf {
    let lbv = Path::new(env!("CARGO_MANIFEST_DIR"));
    lbv.parent().unwrap_or(lbv).to_path_buf()
}

/// Cargo's target directory: `CARGO_TARGET_DIR` (relative to the workspace), else the workspace's `target`.
pub fn target_dir(workspace: &Path) -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| workspace.join("target"), |dir| workspace.join(dir))
}

/// `lbv hil ...`
pub fn main(args: Args) -> ExitCode {
    let options = match Options::try_from(args) {
        Ok(options) => options,
        Err(message) => crate::refuse::<Args>("lbv hil", message),
    };
    let mut log = match options.log.as_ref().map(File::create).transpose() {
        Ok(log) => log,
        Err(error) => {
            eprintln!("lbv: cannot write the log: {error}");
            return ExitCode::from(EXIT_SETUP);
        }
    };
    let (sender, receiver) = mpsc::sync_channel(IN_FLIGHT);
    let mut child: Option<Child> = None;
    if let Some(replay) = &options.replay {
        match File::open(replay) {
            Ok(file) => lines_of(file, sender),
            Err(error) => {
                eprintln!("lbv: cannot read {}: {error}", replay.display());
                return ExitCode::from(EXIT_SETUP);
            }
        }
    } else {
        let workspace = workspace();
        let commands = plan(&options, &workspace, &target_dir(&workspace));
        if options.dry_run {
            for command in &commands {
                println!("# {}\n{}", command.what, command.line());
            }
            return ExitCode::SUCCESS;
        }
        let Some((run, setup)) = commands.split_last() else {
            return ExitCode::from(EXIT_SETUP);
        };
        for command in setup {
            println!("lbv hil: {}: {}", command.what, command.line());
            match command.process().status() {
                Ok(status) if status.success() => {}
                Ok(status) => {
                    eprintln!("lbv: {} failed ({status})", command.what);
                    return ExitCode::from(EXIT_SETUP);
                }
                Err(error) => {
                    eprintln!("lbv: cannot run {}: {error}", command.program);
                    return ExitCode::from(EXIT_SETUP);
                }
            }
        }
        println!("lbv hil: {}: {}", run.what, run.line());
        let spawned = run.process().stdout(Stdio::piped()).stderr(Stdio::piped()).spawn();
        let mut process = match spawned {
            Ok(process) => process,
            Err(error) => {
                eprintln!("lbv: cannot run {}: {error}", run.program);
                return ExitCode::from(EXIT_SETUP);
            }
        };
        // probe-rs writes the target's log on stdout and its own messages on stderr: follow both.
        if let Some(stdout) = process.stdout.take() {
            lines_of(stdout, sender.clone());
        }
        if let Some(stderr) = process.stderr.take() {
            lines_of(stderr, sender);
        }
        child = Some(process);
    }
    let mut stdout = std::io::stdout();
    let (outcome, ending) = follow(
        &receiver,
        options.timeout,
        log.as_mut().map(|file| file as &mut dyn Write),
        &mut stdout,
    );
    if let Some(mut process) = child {
        // probe-rs run keeps streaming until stopped.
        let _ = process.kill();
        let _ = process.wait();
    }
    let (code, summary) = judge(&outcome, ending, options.timeout);
    // Written, not printed: a reader that went away (`| head`) is no reason to stop before the exit status.
    for failure in &outcome.failures {
        let _ = writeln!(
            stdout,
            "failed: {} {}",
            failure.family.map_or("", family_token),
            failure.step.name()
        );
    }
    if outcome.failed > outcome.failures.len() as u64 {
        let more = outcome.failed - outcome.failures.len() as u64;
        let _ = writeln!(stdout, "failed: ... and {more} more");
    }
    if outcome.cut_lines > 0 {
        eprintln!(
            "lbv hil: {} log lines were longer than {MAX_LINE} bytes: cut (also in --log) and not read as report lines",
            outcome.cut_lines
        );
    }
    let _ = writeln!(stdout, "lbv hil: {summary}");
    ExitCode::from(code)
}

#[cfg(test)]
mod tests {
    use super::*;
    use lbv_master_fw::acceptance::report::Prompt;

    const PASS_LOG: &str = include_str!("../tests/fixtures/hil-pass.log");
    const FAIL_LOG: &str = include_str!("../tests/fixtures/hil-fail.log");
    const CUT_LOG: &str = include_str!("../tests/fixtures/hil-no-verdict.log");

    /// The options of a command line, or clap's or the check's error in words.
    fn parse(line: &str) -> Result<Options, String> {
        use clap::Parser as _;
        let args = Args::try_parse_from(std::iter::once("hil").chain(line.split_whitespace()));
        Options::try_from(args.map_err(|error| error.to_string())?)
    }

    fn options(line: &str) -> Options {
        parse(line).unwrap()
    }

    #[test]
    fn the_command_line_names_both_probes() {
        let o = options("--master-probe 0671FF3 --thruster-probe 066DFF4 --family legacy --timeout 90 --log x.log");
        assert_eq!(o.master_probe, "0671FF3");
        assert_eq!(o.thruster_probe, "066DFF4");
        assert_eq!(o.family, Family::Legacy);
        assert_eq!(o.timeout, Duration::from_secs(90));
        assert_eq!(o.log, Some(PathBuf::from("x.log")));
        assert_eq!(options("--master-probe A --thruster-probe B").family, Family::SeaBotix);
        assert_eq!(
            options("--replay x.log --timeout 0.5").timeout,
            Duration::from_millis(500)
        );
        for (bad, why) in [
            ("--master-probe A", "--thruster-probe"),
            ("--master-probe A --thruster-probe A", "same"),
            ("--master-probe A --thruster-probe B --family aveox", "seabotix"),
            (
                "--master-probe A --thruster-probe B --timeout -1",
                "unexpected argument",
            ),
            ("--master-probe A --thruster-probe B --timeout 0", "outside"),
            ("--master-probe A --thruster-probe B --timeout 1e19", "outside"),
            ("--master-probe A --thruster-probe B --timeout 86401", "outside"),
            ("--master-probe A --thruster-probe B --timeout NaN", "outside"),
            ("--master-probe A --thruster-probe B --timeout inf", "outside"),
            ("--master-probe A --thruster-probe B --timeout soon", "not a number"),
            ("--master-probe A --thruster-probe B;rm", "serial number"),
            ("--master-probe", "a value is required"),
            ("--frobnicate", "unexpected argument"),
            ("--replay x.log --master-probe A", "cannot be used with"),
        ] {
            let error = parse(bad).unwrap_err();
            assert!(error.contains(why), "{bad}: {error}");
        }
        let replay = options("--replay fixtures/hil-pass.log");
        assert_eq!(replay.replay, Some(PathBuf::from("fixtures/hil-pass.log")));
    }

    #[test]
    fn the_plan_flashes_each_board_with_its_bootloader_then_runs_the_master() {
        let o = options("--master-probe 0671FF3 --thruster-probe 0483:3748:066DFF4");
        let commands = plan(&o, Path::new("/w"), Path::new("/t"));
        let lines: Vec<String> = commands.iter().map(Command::line).collect();
        assert_eq!(
            lines,
            [
                "cd /w && env LBV_ALLOW_DEV_KEY=1 cargo build --release --target thumbv7em-none-eabihf -p thruster-fw --features motorless",
                "cd /w && env LBV_ALLOW_DEV_KEY=1 cargo build --release --target thumbv7em-none-eabihf -p lbv-boot --features thruster",
                "probe-rs erase --chip STM32G431RBTx --probe 0483:3748:066DFF4",
                "probe-rs download --chip STM32G431RBTx --probe 0483:3748:066DFF4 \
                 /t/thumbv7em-none-eabihf/release/lbv-boot",
                "probe-rs download --chip STM32G431RBTx --probe 0483:3748:066DFF4 \
                 /t/thumbv7em-none-eabihf/release/thruster-fw",
                "probe-rs reset --chip STM32G431RBTx --probe 0483:3748:066DFF4",
                "cd /w && env LBV_ALLOW_DEV_KEY=1 cargo build --release --target thumbv7em-none-eabihf -p lbv-boot --features master",
                "cd /w && env LBV_ALLOW_DEV_KEY=1 cargo build --release --target thumbv7em-none-eabihf -p lbv-master-fw --features acceptance",
                "probe-rs erase --chip STM32G474RETx --probe 0483:374e:0671FF3",
                "probe-rs download --chip STM32G474RETx --probe 0483:374e:0671FF3 \
                 /t/thumbv7em-none-eabihf/release/lbv-boot",
                "probe-rs run --chip STM32G474RETx --probe 0483:374e:0671FF3 --log-format '{L} {s}' \
                 /t/thumbv7em-none-eabihf/release/lbv-master-fw",
            ]
        );
        // The log format is one argument, not split at its space.
        assert!(commands[10].args.contains(&"{L} {s}".to_string()));
        let legacy = plan(
            &options("--master-probe A --thruster-probe B --family legacy"),
            Path::new("/w"),
            Path::new("/t"),
        );
        assert_eq!(legacy[0].args.last().map(String::as_str), Some("motorless,legacy"));
        assert_eq!(legacy[7].args.last().map(String::as_str), Some("acceptance,legacy"));
        assert!(legacy[2].args.contains(&"0483:374e:B".to_string()));
    }

    #[test]
    fn report_lines_are_read_whatever_surrounds_them() {
        let step = parse_line(
            "\u{1b}[32mINFO \u{1b}[0m ACCEPT step=failsafe family=seabotix result=PASS ready=1 rest_ms=112 \
             (lbv-master-fw/src/stm32.rs:201)",
        );
        let Some(Report::Step(step)) = step else {
            panic!("{step:?}")
        };
        assert_eq!(
            (step.step, step.family, step.passed),
            (Step::Failsafe, Some(Family::SeaBotix), true)
        );
        let figures: Vec<(&str, i32)> = step.figures.iter().map(|f| (f.name, f.value)).collect();
        assert_eq!(figures, [("ready", 1), ("rest_ms", 112)]);
        let discovery = parse_line("0.412 WARN  ACCEPT step=discovery result=FAIL seabotix=0 legacy=0 found=0");
        let Some(Report::Step(discovery)) = discovery else {
            panic!()
        };
        assert_eq!((discovery.family, discovery.passed), (None, false));
        assert_eq!(
            parse_line("INFO  ACCEPT verdict=FAIL passed=16 failed=1"),
            Some(Report::Verdict(VerdictLine {
                pass: false,
                passed: 16,
                failed: 1
            }))
        );
        assert_eq!(
            parse_line(
                "INFO  ACCEPT prompt=hold-rotor family=legacy wait_s=8: press and hold B1 on the thruster board"
            ),
            Some(Report::Prompt {
                prompt: Prompt::HoldRotor,
                family: Family::Legacy,
                wait_s: 8,
                instruction: "press and hold B1 on the thruster board",
            })
        );
        assert_eq!(parse_line("INFO  ACCEPT start"), Some(Report::Start));
        for noise in [
            "      Erasing ✔ 100% [####################]  48.00 KiB @  41.62 KiB/s",
            "INFO  lbv-master-fw: 1 thrusters",
            "└─ lbv_master_fw::stm32::acceptance::__task_task::{async_fn#0} @ lbv-master-fw/src/stm32.rs:201",
            "INFO  ACCEPT step=speed-forward family=seabotix result=PA",
            "INFO  ACCEPT verdict=PASS passed=9",
            "INFO  ACCEPT verdict=MAYBE passed=9 failed=0",
            "INFO  ACCEPTANCE step=x result=PASS",
            "",
        ] {
            assert_eq!(parse_line(noise), None, "{noise}");
        }
    }

    #[test]
    fn a_recorded_passing_run_passes() {
        let outcome = Outcome::of_log(PASS_LOG);
        assert!(outcome.started);
        assert_eq!((outcome.passed, outcome.failed), (9, 0));
        assert_eq!(outcome.prompts, 5);
        assert_eq!(
            outcome.verdict,
            Some(VerdictLine {
                pass: true,
                passed: 9,
                failed: 0
            })
        );
        let (code, summary) = judge(&outcome, Ending::Verdict, Duration::from_secs(300));
        assert_eq!(code, EXIT_PASS, "{summary}");
    }

    #[test]
    fn a_recorded_failing_run_fails_and_names_the_step() {
        let outcome = Outcome::of_log(FAIL_LOG);
        let failed: Vec<&str> = outcome.failures.iter().map(|failure| failure.step.name()).collect();
        assert_eq!(failed, ["held-rotor"]);
        let (code, summary) = judge(&outcome, Ending::Verdict, Duration::from_secs(300));
        assert_eq!(code, EXIT_FAIL);
        assert!(summary.contains("1 of 9 steps failed"), "{summary}");
    }

    #[test]
    fn a_log_without_a_verdict_fails() {
        let outcome = Outcome::of_log(CUT_LOG);
        assert!(outcome.verdict.is_none());
        assert!(outcome.steps() > 0);
        let (code, _) = judge(&outcome, Ending::LogEnded, Duration::from_secs(300));
        assert_eq!(code, EXIT_NO_VERDICT);
        let (code, summary) = judge(&outcome, Ending::Timeout, Duration::from_secs(300));
        assert_eq!(code, EXIT_TIMEOUT);
        assert!(summary.contains("300 s"), "{summary}");
    }

    #[test]
    fn a_verdict_that_contradicts_the_steps_or_a_panic_is_a_fail() {
        let contradicting = PASS_LOG.replace("result=PASS water_ms=", "result=FAIL water_ms=");
        let (code, summary) = judge(
            &Outcome::of_log(&contradicting),
            Ending::Verdict,
            Duration::from_secs(1),
        );
        assert_eq!(code, EXIT_FAIL, "{summary}");
        let miscounted = PASS_LOG.replace("passed=9 failed=0", "passed=12 failed=0");
        let (code, summary) = judge(&Outcome::of_log(&miscounted), Ending::Verdict, Duration::from_secs(1));
        assert_eq!(code, EXIT_FAIL);
        assert!(summary.contains("log shows 9"), "{summary}");
        let panicked = format!("{PASS_LOG}\nERROR panicked at 'index out of bounds', src/x.rs:1:1\n");
        assert_eq!(
            judge(&Outcome::of_log(&panicked), Ending::Verdict, Duration::from_secs(1)).0,
            EXIT_FAIL
        );
        assert_eq!(
            judge(&Outcome::default(), Ending::LogEnded, Duration::from_secs(1)).0,
            EXIT_NO_VERDICT,
            "an empty log"
        );
    }

    #[test]
    fn following_stops_at_the_verdict_and_keeps_the_whole_log() {
        let (sender, receiver) = mpsc::channel();
        sender.send(PASS_LOG.lines().map(LogLine::from).collect()).unwrap();
        sender.send(vec!["INFO  something after the verdict".into()]).unwrap();
        let (mut log, mut out) = (Vec::new(), Vec::new());
        let (outcome, ending) = follow(&receiver, Duration::from_secs(5), Some(&mut log), &mut out);
        assert_eq!(ending, Ending::Verdict);
        assert!(outcome.verdict.is_some_and(|v| v.pass));
        let log = String::from_utf8(log).unwrap();
        assert!(
            log.ends_with("ACCEPT verdict=PASS passed=9 failed=0\n"),
            "stops at the verdict"
        );
        let out = String::from_utf8(out).unwrap();
        assert_eq!(
            out.lines().count(),
            1 + 9 + 5 + 1,
            "start, steps, prompts, verdict:\n{out}"
        );
        assert!(
            out.contains(">>> seabotix thruster: press RESET (B2) on the thruster board now"),
            "{out}"
        );
    }

    #[test]
    fn following_ends_with_the_log_or_the_timeout() {
        let (sender, receiver) = mpsc::channel();
        for line in CUT_LOG.lines() {
            sender.send(vec![line.into()]).unwrap();
        }
        drop(sender);
        let (outcome, ending) = follow(&receiver, Duration::from_secs(5), None, &mut Vec::new());
        assert_eq!(ending, Ending::LogEnded);
        assert!(outcome.steps() > 0);

        // A board that goes quiet: the sender stays open, nothing comes.
        let (sender, receiver) = mpsc::channel::<Vec<LogLine>>();
        sender.send(vec!["INFO  ACCEPT start".into()]).unwrap();
        let started = Instant::now();
        let (outcome, ending) = follow(&receiver, Duration::from_millis(100), None, &mut Vec::new());
        assert_eq!(ending, Ending::Timeout);
        assert!(outcome.started);
        assert!(started.elapsed() >= Duration::from_millis(100));
        drop(sender);
    }

    #[test]
    fn a_verdict_without_the_start_or_any_step_is_a_fail() {
        for log in [
            "INFO  ACCEPT verdict=PASS passed=0 failed=0",
            "INFO  ACCEPT start\nINFO  ACCEPT verdict=PASS passed=0 failed=0",
            "INFO  ACCEPT step=discovery result=PASS seabotix=1 legacy=0 found=1\nINFO  ACCEPT verdict=PASS passed=1 failed=0",
        ] {
            let (code, summary) = judge(&Outcome::of_log(log), Ending::Verdict, Duration::from_secs(1));
            assert_eq!(code, EXIT_FAIL, "{log}: {summary}");
            assert!(summary.contains("verdict alone"), "{summary}");
        }
    }

    #[test]
    fn lines_that_are_not_utf8_or_too_long_hide_nothing_after_them() {
        let mut log = b"\xff\xfe not text\n".to_vec();
        log.extend(std::iter::repeat_n(b'x', MAX_LINE * 3));
        log.extend(b" ACCEPT verdict=PASS passed=9 failed=0\n");
        log.extend(PASS_LOG.as_bytes());
        let (sender, receiver) = mpsc::sync_channel(IN_FLIGHT);
        lines_of(std::io::Cursor::new(log), sender);
        let (outcome, ending) = follow(&receiver, Duration::from_secs(5), None, &mut Vec::new());
        assert_eq!(ending, Ending::Verdict);
        assert_eq!(outcome.cut_lines, 1, "the long line is cut, and its verdict not read");
        assert_eq!(judge(&outcome, ending, Duration::from_secs(5)).0, EXIT_PASS);
    }

    #[test]
    fn the_outcome_keeps_counts_not_lines() {
        let mut outcome = Outcome::default();
        let line = LogLine::from("INFO  ACCEPT step=speed-forward family=seabotix result=FAIL steps=102 ok=101");
        for _ in 0..10 * MAX_FAILURES {
            outcome.feed(&line);
        }
        assert_eq!(outcome.failed, 10 * MAX_FAILURES as u64);
        assert_eq!(outcome.failures.len(), MAX_FAILURES);
    }
}
