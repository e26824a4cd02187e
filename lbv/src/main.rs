//! `lbv`: host tools for the LBV propulsion. `lbv bench` runs the whole vehicle (the real master and thruster
//! firmware cores, a battery board, simulated buses and motors) on virtual time; `lbv bench --udp` runs it in real
//! time with its MAVLink console on UDP, for a ground station to fly. `lbv image` signs update files.

mod bench;
mod scenarios;

use std::io::{IsTerminal, Write};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};

use clap::{Parser, Subcommand};
use lbv::{decode, exit, flash, hil, image};

use bench::Engine;
use lbv::plot::Format;
use lbv::trace::Sample;
use scenarios::{Report, SCENARIOS, Scenario};

/// Host tools for the LBV propulsion: the virtual bench, capture decoders, the dev-kit bench test.
#[derive(Debug, Parser)]
#[command(name = "lbv", arg_required_else_help = true, term_width = 100, after_help = exit::HELP)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// The virtual bench: the whole vehicle (the real firmware cores, simulated buses, motors and battery) on
    /// virtual time; with --udp, in real time for a ground station to fly
    Bench(BenchArgs),
    /// Decode what people capture on the bench: I2C annotations from sigrok, candump logs, crash records
    #[command(subcommand)]
    Decode(decode::Command),
    /// Write a board from nothing: its bootloader, then its image, run with its log streamed
    Flash(flash::Args),
    /// The bench test of the two dev kits (master and thruster): build, flash, follow the master's log to the verdict
    Hil(hil::Args),
    /// Field update: signing keys, signed update files made from firmware ELFs, what a file is
    #[command(subcommand)]
    Image(image::Command),
}

/// Set once standard output is gone (a reader that stopped early, as `lbv bench --all | head -1`): the run goes
/// on to its end, its files and exit status, without the lines nobody reads.
static STDOUT_GONE: AtomicBool = AtomicBool::new(false);

/// A line on standard output, unless it is gone.
macro_rules! say {
    ($($arg:tt)*) => {
        say(format_args!($($arg)*))
    };
}

fn say(line: std::fmt::Arguments<'_>) {
    if STDOUT_GONE.load(Ordering::Relaxed) {
        return;
    }
    if writeln!(std::io::stdout().lock(), "{line}").is_err() {
        STDOUT_GONE.store(true, Ordering::Relaxed);
    }
}

/// The longest run --duration asks for: a simulated day.
const MAX_DURATION_S: f64 = 86_400.0;

const BENCH_HELP: &str = "\
With no options: the dive scenario, with a live view of the thrusters and a summary at the end.

--udp flies the dive scenario's vehicle with no scripted pilot, in real time, its MAVLink console
on UDP for a ground station (QGroundControl, pymavlink) to arm and fly; it runs until interrupted,
or for --duration seconds, with a status line every second (armed, each thruster's rpm, datagrams).

Exit status: 0 every check passed; 1 a check failed; 2 bad command line, an unknown scenario, a
file that cannot be written, a UDP port that cannot be opened.";

/// `lbv bench`: what to run and what to write.
#[derive(Debug, Parser)]
#[command(after_help = BENCH_HELP)]
struct BenchArgs {
    /// Name every scenario, with its default length and what it checks
    #[arg(long)]
    list: bool,
    /// Run every scenario
    #[arg(long, conflicts_with = "scenario")]
    all: bool,
    /// The scenario to run (lbv bench --list names them) [default: dive]
    #[arg(long, value_name = "NAME")]
    scenario: Option<String>,
    /// Seeds the motors' starting positions and the scenarios' random choices: the same seed, the same run
    #[arg(long, value_name = "N", default_value_t = 1)]
    seed: u64,
    /// The soak's length; other scenarios run their script to the end, then on to SECONDS if it is longer
    /// (0 < SECONDS <= 86400)
    #[arg(long, value_name = "SECONDS", value_parser = duration_seconds)]
    duration: Option<f64>,
    /// Write the report (a list of reports with --all) as JSON
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Draw rpm, current, temperature, faults and events over time, as SVG or PNG by the file's extension
    #[arg(long, value_name = "FILE.svg|FILE.png", value_parser = lbv::plot::file)]
    plot: Option<(PathBuf, Format)>,
    /// No live view (with --udp: no status lines)
    #[arg(long)]
    quiet: bool,
    /// Move time in fixed 50 us steps, every motor stepped every time (the reference the default event-driven
    /// engine is held against; several times slower)
    #[arg(long)]
    exact: bool,
    /// Run the dive vehicle in real time with its MAVLink console on UDP (see below)
    #[arg(long, conflicts_with_all = ["all", "json", "plot"])]
    udp: bool,
    /// Where the master's MAVLink goes (QGroundControl and `pymavlink udpin:0.0.0.0:14550` listen there)
    /// [default: 127.0.0.1:14550]
    #[arg(long, value_name = "ADDR:PORT", requires = "udp")]
    udp_send: Option<SocketAddr>,
    /// Where the bench takes the station's MAVLink: a loopback address unless --udp-any
    /// [default: 127.0.0.1:14551]
    #[arg(long, value_name = "ADDR:PORT", requires = "udp")]
    udp_listen: Option<SocketAddr>,
    /// Allow --udp-listen on an address other than loopback (exposes the vehicle to the network)
    #[arg(long, requires = "udp")]
    udp_any: bool,
    /// Write each update image the master receives over MAVLink FTP, as its sink got it, to DIR/<file> (for
    /// /update/thruster0.lbvu: DIR/thruster0.lbvu) once it is whole or stopped (a stopped one ends in .stopped)
    #[arg(long, value_name = "DIR", requires = "udp")]
    update_dir: Option<PathBuf>,
    /// With --udp: write the bench's trace to FILE as the run goes, a line of JSON each 10 ms (virtual time t in
    /// s, each thruster's rpm, current, temperature, faults and order, the battery, armed): what the plant did, to
    /// hold a ground station's log against
    #[arg(long, value_name = "FILE", requires = "udp")]
    trace: Option<PathBuf>,
    /// Write the one scenario's report as JSON on standard output and nothing else: how --all runs each scenario,
    /// in a process of its own
    #[arg(long, hide = true, conflicts_with_all = ["all", "udp", "list", "json"])]
    report_only: bool,
}

/// `--duration`: seconds, positive, finite, at most [`MAX_DURATION_S`].
fn duration_seconds(text: &str) -> Result<f64, String> {
    let seconds: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("{text:?} is not a number of seconds"))?;
    if seconds.is_finite() && seconds > 0.0 && seconds <= MAX_DURATION_S {
        Ok(seconds)
    } else {
        Err(format!("{text} is outside 0 < SECONDS <= {MAX_DURATION_S}"))
    }
}

impl BenchArgs {
    /// The engine asked for.
    fn engine(&self) -> Engine {
        if self.exact { Engine::Exact } else { Engine::Events }
    }

    /// The rules between options that clap's attributes do not say.
    fn check(&self) -> Result<(), String> {
        if !self.udp {
            return Ok(());
        }
        if let Some(name) = self.scenario.as_deref().filter(|name| *name != "dive") {
            return Err(format!(
                "--udp flies the dive scenario's vehicle with the ground station as pilot: --scenario {name} does \
                 not go with it"
            ));
        }
        if let Some(listen) = self.udp_listen
            && !listen.ip().is_loopback()
            && !self.udp_any
        {
            return Err(format!(
                "--udp-listen {listen} is not a loopback address: add --udp-any to listen on the network"
            ));
        }
        Ok(())
    }
}

fn main() -> ExitCode {
    match Cli::parse().command {
        Command::Bench(args) => {
            if let Err(message) = args.check() {
                lbv::refuse::<BenchArgs>("lbv bench", message);
            }
            bench_main(&args)
        }
        Command::Decode(command) => decode::main(command),
        Command::Flash(args) => flash::main(args),
        Command::Hil(args) => hil::main(args),
        Command::Image(command) => image::main(command),
    }
}

/// `lbv bench ...`
fn bench_main(options: &BenchArgs) -> ExitCode {
    if options.list {
        for scenario in SCENARIOS {
            say!("{:<22} {:>5.0} s  {}", scenario.name, scenario.seconds, scenario.about);
        }
        return ExitCode::SUCCESS;
    }
    if options.udp {
        return udp(options);
    }
    let chosen: Vec<&Scenario> = if options.all {
        SCENARIOS.iter().collect()
    } else {
        let name = options.scenario.as_deref().unwrap_or("dive");
        match scenarios::find(name) {
            Some(scenario) => vec![scenario],
            None => {
                eprintln!("lbv: no scenario called {name} (lbv bench --list names them)");
                return ExitCode::from(exit::TROUBLE);
            }
        }
    };

    let run = scenarios::Options {
        seconds: options.duration,
        samples: options.plot.is_some(),
        ..scenarios::Options::new(options.seed, options.engine())
    };
    if options.report_only {
        return report_only(chosen[0], &run, options);
    }
    let mut reports = Vec::new();
    let mut trouble = false;
    if options.all {
        let each = |report: Report| {
            summarise(&report);
            reports.push(report);
        };
        if let Err(error) = run_in_processes(&chosen, options, each) {
            eprintln!("lbv: {error}");
            trouble = true;
        }
    } else {
        let live = !options.quiet && std::io::stdout().is_terminal();
        for scenario in chosen {
            let (report, trace) = scenarios::run_guarded(scenario, &run, live.then(live_view));
            summarise(&report);
            if let Some((file, format)) = &options.plot
                && let Err(error) = plot(&report, &trace, file, *format)
            {
                eprintln!("lbv: cannot write {}: {error}", file.display());
                trouble = true;
            }
            reports.push(report);
        }
    }
    if trouble {
        return ExitCode::from(exit::TROUBLE);
    }
    if let Some(file) = &options.json {
        let json = if options.all {
            serde_json::to_string_pretty(&reports)
        } else {
            serde_json::to_string_pretty(&reports[0])
        };
        let written = json
            .map_err(|error| error.to_string())
            .and_then(|json| std::fs::write(file, json).map_err(|e| e.to_string()));
        if let Err(error) = written {
            eprintln!("lbv: cannot write {}: {error}", file.display());
            return ExitCode::from(exit::TROUBLE);
        }
    }
    let failed = reports.iter().filter(|report| !report.passed).count();
    if reports.len() > 1 {
        say!(
            "\n{} scenarios: {} passed, {} failed",
            reports.len(),
            reports.len() - failed,
            failed
        );
    }
    if failed == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(exit::FAILED)
    }
}

/// Draw `trace` as `--plot` asks.
fn plot(report: &Report, trace: &lbv::trace::Trace, file: &std::path::Path, format: Format) -> Result<(), String> {
    let title = format!("lbv bench: {} (seed {})", report.scenario, report.seed);
    lbv::plot::write(trace, &title, file, format)
}

/// `--report-only`: the scenario's report as JSON on standard output (and its plot if asked for).
fn report_only(scenario: &Scenario, run: &scenarios::Options, options: &BenchArgs) -> ExitCode {
    let (report, trace) = scenarios::run_guarded(scenario, run, None);
    if let Some((file, format)) = &options.plot
        && let Err(error) = plot(&report, &trace, file, *format)
    {
        eprintln!("lbv: cannot write {}: {error}", file.display());
        return ExitCode::from(exit::TROUBLE);
    }
    match serde_json::to_string(&report) {
        Ok(json) => say!("{json}"),
        Err(error) => {
            eprintln!("lbv: cannot write the report: {error}");
            return ExitCode::from(exit::TROUBLE);
        }
    }
    ExitCode::from(if report.passed { exit::OK } else { exit::FAILED })
}

/// `--all`: every scenario in a process of its own, as many at once as there are cores (a run holds its process's
/// critical section, see `lbv_sim::in_one_critical_section`, so runs side by side are processes). `each` gets the
/// reports in the scenarios' order, each as soon as it and those before it are in. A process that ends without a
/// report (it crashed) gives a failed one; an error is a process that could not be started or a plot not written.
fn run_in_processes(chosen: &[&Scenario], options: &BenchArgs, mut each: impl FnMut(Report)) -> Result<(), String> {
    let exe = std::env::current_exe().map_err(|error| format!("cannot find this program to run scenarios: {error}"))?;
    let workers = std::thread::available_parallelism().map_or(1, usize::from);
    let next = std::sync::atomic::AtomicUsize::new(0);
    let (done, results) = std::sync::mpsc::channel();
    let run = scenarios::Options::new(options.seed, options.engine());
    std::thread::scope(|scope| {
        for _ in 0..workers.clamp(1, chosen.len().max(1)) {
            let (next, done, exe) = (&next, done.clone(), &exe);
            scope.spawn(move || {
                loop {
                    let index = next.fetch_add(1, Ordering::Relaxed);
                    let Some(scenario) = chosen.get(index) else { break };
                    let mut command = std::process::Command::new(exe);
                    command.args(["bench", "--report-only", "--quiet", "--scenario", scenario.name]);
                    command.args(["--seed", &options.seed.to_string()]);
                    if let Some(seconds) = options.duration {
                        command.args(["--duration", &seconds.to_string()]);
                    }
                    if options.exact {
                        command.arg("--exact");
                    }
                    // As in one process: the last scenario's plot is the one left in the file.
                    if let Some((file, _)) = &options.plot
                        && index + 1 == chosen.len()
                    {
                        command.arg("--plot").arg(file);
                    }
                    let outcome = command.stderr(std::process::Stdio::inherit()).output();
                    let result = match outcome {
                        Ok(output) => match serde_json::from_slice::<Report>(&output.stdout) {
                            Ok(report) => Ok(report),
                            Err(_) if output.status.code() == Some(exit::TROUBLE.into()) => {
                                Err(format!("the {} scenario could not write its files", scenario.name))
                            }
                            Err(_) => Ok(Report::broken(
                                scenario.name,
                                &run,
                                format!("its process ended without a report ({})", output.status),
                            )),
                        },
                        Err(error) => Err(format!("cannot run the {} scenario: {error}", scenario.name)),
                    };
                    if done.send((index, result)).is_err() {
                        break;
                    }
                }
            });
        }
        drop(done);
        let mut waiting = std::collections::BTreeMap::new();
        let (mut due, mut trouble) = (0, Ok(()));
        for (index, result) in results {
            waiting.insert(index, result);
            while let Some(result) = waiting.remove(&due) {
                match result {
                    Ok(report) => each(report),
                    Err(error) => trouble = Err(error),
                }
                due += 1;
            }
        }
        trouble
    })
}

/// `--udp`: the dive vehicle, no scripted pilot, its console bridged to UDP, paced to the wall clock.
fn udp(options: &BenchArgs) -> ExitCode {
    let send = options.udp_send.unwrap_or(bench::udp::DEFAULT_SEND);
    let listen = options.udp_listen.unwrap_or(bench::udp::DEFAULT_LISTEN);
    let Some(dive) = scenarios::find("dive") else {
        eprintln!("lbv: no dive scenario to take the vehicle from");
        return ExitCode::from(exit::TROUBLE);
    };
    let link = match bench::udp::UdpLink::open(listen, send) {
        Ok(link) => link,
        Err(error) => {
            eprintln!("lbv: cannot listen on {listen}: {error}");
            return ExitCode::from(exit::TROUBLE);
        }
    };
    let listening = link.local_addr().unwrap_or(listen);
    let mut trace = match &options.trace {
        Some(path) => match std::fs::File::create(path) {
            Ok(file) => Some(std::io::BufWriter::new(file)),
            Err(error) => {
                eprintln!("lbv: cannot write {}: {error}", path.display());
                return ExitCode::from(exit::TROUBLE);
            }
        },
        None => None,
    };
    let mut config = (dive.vehicle)(options.seed);
    // The console's UART as the binding has it: a flood is dropped there and in the bridge's inboxes, not queued.
    config.console_baud = Some(bench::udp::CONSOLE_BAUD);
    let vehicle: Vec<String> = config.families.iter().map(|family| format!("{family:?}")).collect();
    say!(
        "lbv bench: MAVLink console on UDP, sending to {send}, listening on {listening}; vehicle {} (seed {}); \
         real time, {}",
        vehicle.join(" "),
        options.seed,
        match options.duration {
            Some(seconds) => format!("for {seconds} s"),
            None => "until interrupted (Ctrl-C)".into(),
        }
    );
    let mut bench = bench::Bench::new(&config, options.engine());
    bench.keep_samples(trace.is_some());
    let duration = options
        .duration
        .map(|seconds| embassy_time::Duration::from_micros((seconds * 1e6) as u64));
    let clock = match bench::udp::serve(
        &mut bench,
        &link,
        duration,
        !options.quiet,
        options.update_dir.as_deref(),
        trace.as_mut().map(|out| out as &mut dyn std::io::Write),
    ) {
        Ok(clock) => clock,
        Err(error) => {
            eprintln!("lbv: the UDP link failed: {error}");
            return ExitCode::from(exit::TROUBLE);
        }
    };
    let (simulated, wall) = (bench.seconds(), clock.elapsed().as_secs_f64());
    let counters = link.counters();
    say!(
        "lbv bench: {simulated:.1} s simulated in {wall:.1} s; datagrams in {}, out {}{}",
        counters.datagrams_in,
        counters.datagrams_out,
        bench::udp::drops(&counters)
    );
    if !clock.lost().is_zero() {
        say!(
            "lbv bench: could not keep pace with the wall clock (machine too slow or busy): virtual time fell \
             {:.2} s behind; it ran as fast as it could",
            clock.lost().as_secs_f64()
        );
    }
    ExitCode::SUCCESS
}

/// A compact view redrawn once per simulated second: one line per thruster and one for the battery.
fn live_view() -> bench::Monitor {
    let mut next = 0.0;
    let mut lines = 0;
    Box::new(move |sample: &Sample| {
        if sample.t < next {
            return;
        }
        next = sample.t + 1.0;
        let mut out = std::io::stdout().lock();
        if lines > 0 {
            let _ = write!(out, "\x1b[{lines}A");
        }
        let _ = writeln!(
            out,
            "\x1b[2Kt {:6.1} s   battery {:5.2} V   {}",
            sample.t,
            sample.battery_v,
            if sample.armed { "ARMED" } else { "disarmed" }
        );
        for (i, thruster) in sample.thrusters.iter().enumerate() {
            let _ = writeln!(
                out,
                "\x1b[2K  T{} {:>7} {:>6.0} rpm (order {:>4}) {:>5.1} A {:>6.1} C  {}",
                i + 1,
                if thruster.online { "online" } else { "OFFLINE" },
                thruster.rpm,
                thruster.ordered_step,
                thruster.current_a,
                thruster.temperature_c,
                fault_names(thruster.faults)
            );
        }
        lines = sample.thrusters.len() + 1;
        let _ = out.flush();
    })
}

fn fault_names(bits: u8) -> String {
    let faults = tmc_proto::Faults::from_bits_truncate(bits);
    if faults.is_empty() {
        "ok".into()
    } else {
        faults.iter().map(|f| f.name()).collect::<Vec<_>>().join(", ")
    }
}

fn summarise(report: &Report) {
    say!(
        "{} {} (seed {}): {:.1} s simulated in {:.2} s",
        if report.passed { "PASS" } else { "FAIL" },
        report.scenario,
        report.seed,
        report.sim_seconds,
        report.wall_seconds
    );
    for check in &report.checks {
        say!(
            "  {} {:<48} {}",
            if check.passed { "ok  " } else { "FAIL" },
            check.name,
            check.detail
        );
    }
    for key in [
        "real_time_factor",
        "poll_rate_hz",
        "bus_utilisation",
        "console_to_wire_latency_ms",
    ] {
        if let Some(value) = report.metrics.get(key) {
            say!("  {key}: {value}");
        }
    }
}
