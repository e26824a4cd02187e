//! `lbv`: host tools for the LBV propulsion. `lbv bench` runs the whole vehicle (the real master and thruster
//! firmware cores, a battery board, simulated buses and motors) on virtual time; `lbv bench --udp` runs it in real
//! time with its MAVLink console on UDP, for a ground station to fly.

mod bench;
mod scenarios;

use std::io::{IsTerminal, Write};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use lbv::{decode, exit, hil};

use bench::plot::Format;
use bench::trace::Sample;
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
    /// Decode what people capture on the bench: I2C annotations from sigrok, candump logs
    #[command(subcommand)]
    Decode(decode::Command),
    /// The bench test between two NUCLEO-G431RB dev kits: build, flash, follow the master's log to the verdict
    Hil(hil::Args),
}

/// The longest run --duration asks for: a simulated day (the trace of a run grows with its length).
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
    #[arg(long, value_name = "FILE.svg|FILE.png", value_parser = plot_file)]
    plot: Option<(PathBuf, Format)>,
    /// No live view (with --udp: no status lines)
    #[arg(long)]
    quiet: bool,
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

/// `--plot`: a file name ending in .svg or .png (the picture's format).
fn plot_file(text: &str) -> Result<(PathBuf, Format), String> {
    let path = PathBuf::from(text);
    let extension = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    match extension.as_deref() {
        Some("svg") => Ok((path, Format::Svg)),
        Some("png") => Ok((path, Format::Png)),
        _ => Err(format!("{text} does not end in .svg or .png")),
    }
}

impl BenchArgs {
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
        Command::Hil(args) => hil::main(args),
    }
}

/// `lbv bench ...`
fn bench_main(options: &BenchArgs) -> ExitCode {
    if options.list {
        for scenario in SCENARIOS {
            println!("{:<22} {:>5.0} s  {}", scenario.name, scenario.seconds, scenario.about);
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

    let live = !options.quiet && !options.all && std::io::stdout().is_terminal();
    let mut reports = Vec::new();
    for scenario in chosen {
        let (report, bench) = scenarios::run_with(scenario, options.seed, options.duration, live.then(live_view));
        summarise(&report);
        if let Some((file, format)) = &options.plot {
            let title = format!("lbv bench: {} (seed {})", report.scenario, report.seed);
            if let Err(error) = bench::plot::write(&bench.trace, &title, file, *format) {
                eprintln!("lbv: cannot write {}: {error}", file.display());
                return ExitCode::from(exit::TROUBLE);
            }
        }
        reports.push(report);
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
        println!(
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
    let config = (dive.vehicle)(options.seed);
    let vehicle: Vec<String> = config.families.iter().map(|family| format!("{family:?}")).collect();
    println!(
        "lbv bench: MAVLink console on UDP, sending to {send}, listening on {listening}; vehicle {} (seed {}); \
         real time, {}",
        vehicle.join(" "),
        options.seed,
        match options.duration {
            Some(seconds) => format!("for {seconds} s"),
            None => "until interrupted (Ctrl-C)".into(),
        }
    );
    let mut bench = bench::Bench::new(&config);
    let duration = options
        .duration
        .map(|seconds| embassy_time::Duration::from_micros((seconds * 1e6) as u64));
    let clock = match bench::udp::serve(&mut bench, &link, duration, !options.quiet) {
        Ok(clock) => clock,
        Err(error) => {
            eprintln!("lbv: the UDP link failed: {error}");
            return ExitCode::from(exit::TROUBLE);
        }
    };
    let (simulated, wall) = (bench.seconds(), clock.elapsed().as_secs_f64());
    let counters = link.counters();
    println!(
        "lbv bench: {simulated:.1} s simulated in {wall:.1} s; datagrams in {}, out {}, errors {}",
        counters.datagrams_in, counters.datagrams_out, counters.errors
    );
    if !clock.lost().is_zero() {
        println!(
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
    println!(
        "{} {} (seed {}): {:.1} s simulated in {:.2} s",
        if report.passed { "PASS" } else { "FAIL" },
        report.scenario,
        report.seed,
        report.sim_seconds,
        report.wall_seconds
    );
    for check in &report.checks {
        println!(
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
            println!("  {key}: {value}");
        }
    }
}
