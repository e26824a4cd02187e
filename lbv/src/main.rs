//! `lbv`: host tools for the LBV propulsion. `lbv bench` runs the whole vehicle (the real master and thruster
//! firmware cores, a battery board, simulated buses and motors) on virtual time.

mod bench;
mod scenarios;

use std::io::{IsTerminal, Write};
use std::process::ExitCode;

use bench::trace::Sample;
use scenarios::{Report, SCENARIOS, Scenario};

const USAGE: &str = "\
usage: lbv bench [--scenario NAME] [--seed N] [--duration SECONDS] [--json FILE] [--plot FILE.svg] [--quiet]
       lbv bench --all [--seed N] [--json FILE]
       lbv bench --list

With no options: the dive scenario, with a live view of the thrusters and a summary at the end.
--list       name every scenario
--all        run every scenario; the exit status is non-zero if any check fails
--json FILE  write the report (a list of reports with --all) as JSON
--plot FILE  draw rpm, current, temperature and faults over time as SVG
--quiet      no live view";

/// What the command line asked for.
#[derive(Debug, Default)]
struct Options {
    list: bool,
    all: bool,
    scenario: Option<String>,
    seed: u64,
    duration: Option<f64>,
    json: Option<String>,
    plot: Option<String>,
    quiet: bool,
}

fn parse(args: &[String]) -> Result<Options, String> {
    let mut options = Options {
        seed: 1,
        ..Options::default()
    };
    let mut args = args.iter();
    while let Some(arg) = args.next() {
        let mut value = |name: &str| args.next().cloned().ok_or(format!("{name} needs a value"));
        match arg.as_str() {
            "--list" => options.list = true,
            "--all" => options.all = true,
            "--quiet" => options.quiet = true,
            "--scenario" => options.scenario = Some(value("--scenario")?),
            "--seed" => options.seed = value("--seed")?.parse().map_err(|_| "--seed needs a number")?,
            "--duration" => {
                let seconds: f64 = value("--duration")?.parse().map_err(|_| "--duration needs seconds")?;
                if !(seconds.is_finite() && seconds > 0.0) {
                    return Err("--duration needs a positive number of seconds".into());
                }
                options.duration = Some(seconds);
            }
            "--json" => options.json = Some(value("--json")?),
            "--plot" => {
                let file = value("--plot")?;
                if !file.ends_with(".svg") {
                    return Err("--plot writes SVG: give a file name ending in .svg".into());
                }
                options.plot = Some(file);
            }
            "-h" | "--help" => return Err(String::new()),
            other => return Err(format!("unknown option {other}")),
        }
    }
    Ok(options)
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.first().map(String::as_str) {
        Some("bench") => {}
        _ => {
            eprintln!("{USAGE}");
            return ExitCode::from(2);
        }
    }
    let options = match parse(args.get(1..).unwrap_or_default()) {
        Ok(options) => options,
        Err(message) => {
            if !message.is_empty() {
                eprintln!("lbv: {message}");
            }
            eprintln!("{USAGE}");
            return ExitCode::from(2);
        }
    };
    if options.list {
        for scenario in SCENARIOS {
            println!("{:<22} {:>5.0} s  {}", scenario.name, scenario.seconds, scenario.about);
        }
        return ExitCode::SUCCESS;
    }
    let chosen: Vec<&Scenario> = if options.all {
        SCENARIOS.iter().collect()
    } else {
        let name = options.scenario.as_deref().unwrap_or("dive");
        match scenarios::find(name) {
            Some(scenario) => vec![scenario],
            None => {
                eprintln!("lbv: no scenario called {name} (lbv bench --list names them)");
                return ExitCode::from(2);
            }
        }
    };

    let live = !options.quiet && !options.all && std::io::stdout().is_terminal();
    let mut reports = Vec::new();
    for scenario in chosen {
        let (report, bench) = scenarios::run_with(scenario, options.seed, options.duration, live.then(live_view));
        summarise(&report);
        if let Some(file) = &options.plot {
            let svg = bench::plot::svg(
                &bench.trace,
                &format!("lbv bench: {} (seed {})", report.scenario, report.seed),
            );
            if let Err(error) = std::fs::write(file, svg) {
                eprintln!("lbv: cannot write {file}: {error}");
                return ExitCode::from(2);
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
            eprintln!("lbv: cannot write {file}: {error}");
            return ExitCode::from(2);
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
        ExitCode::FAILURE
    }
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
