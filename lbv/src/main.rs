//! `lbv`: host tools for the LBV propulsion. `lbv bench` runs the whole vehicle (the real master and thruster
//! firmware cores, a battery board, simulated buses and motors) on virtual time; `lbv bench --udp` runs it in real
//! time with its MAVLink console on UDP, for a ground station to fly.

mod bench;
mod decode;
mod hil;
mod scenarios;

use std::io::{IsTerminal, Write};
use std::net::SocketAddr;
use std::process::ExitCode;

use bench::trace::Sample;
use scenarios::{Report, SCENARIOS, Scenario};

const USAGE: &str = "\
usage: lbv bench [--scenario NAME] [--seed N] [--duration SECONDS] [--json FILE] [--plot FILE.svg] [--quiet]
       lbv bench --all [--seed N] [--json FILE]
       lbv bench --list
       lbv bench --udp [--udp-send ADDR:PORT] [--udp-listen ADDR:PORT] [--udp-any] [--seed N] [--duration S] [--quiet]

With no options: the dive scenario, with a live view of the thrusters and a summary at the end.
--list       name every scenario
--all        run every scenario; the exit status is non-zero if any check fails
--duration S the soak's length; other scenarios run their script to the end, then on to S if it is longer
--json FILE  write the report (a list of reports with --all) as JSON
--plot FILE  draw rpm, current, temperature and faults over time as SVG
--quiet      no live view (with --udp: no status lines)

--udp        the dive scenario's vehicle with no scripted pilot, in real time, its MAVLink console on UDP for a
             ground station (QGroundControl, pymavlink) to arm and fly it; runs until interrupted, or for
             --duration seconds. A status line every second: armed, each thruster's rpm, datagrams.
--udp-send ADDR:PORT    where the master's MAVLink goes (default 127.0.0.1:14550, where QGroundControl and
                        `pymavlink udpin:0.0.0.0:14550` listen)
--udp-listen ADDR:PORT  where the bench receives the station's MAVLink (default 127.0.0.1:14551); a loopback
                        address only, unless --udp-any
--udp-any    allow --udp-listen on an address other than loopback (exposes the vehicle to the network)";

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
    udp: bool,
    udp_send: Option<SocketAddr>,
    udp_listen: Option<SocketAddr>,
    udp_any: bool,
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
            "--udp" => options.udp = true,
            "--udp-any" => options.udp_any = true,
            "--udp-send" => options.udp_send = Some(address("--udp-send", &value("--udp-send")?)?),
            "--udp-listen" => options.udp_listen = Some(address("--udp-listen", &value("--udp-listen")?)?),
            "-h" | "--help" => return Err(String::new()),
            other => return Err(format!("unknown option {other}")),
        }
    }
    if options.udp {
        if options.all {
            return Err("--udp runs one vehicle: it does not go with --all".into());
        }
        if let Some(name) = options.scenario.as_deref().filter(|name| *name != "dive") {
            return Err(format!(
                "--udp flies the dive scenario's vehicle with the ground station as pilot: --scenario {name} does \
                 not go with it"
            ));
        }
        if options.json.is_some() || options.plot.is_some() {
            return Err("--json and --plot report scripted scenarios: they do not go with --udp".into());
        }
        if let Some(listen) = options.udp_listen
            && !listen.ip().is_loopback()
            && !options.udp_any
        {
            return Err(format!(
                "--udp-listen {listen} is not a loopback address: add --udp-any to listen on the network"
            ));
        }
    } else if options.udp_send.is_some() || options.udp_listen.is_some() || options.udp_any {
        return Err("--udp-send, --udp-listen and --udp-any go with --udp".into());
    }
    Ok(options)
}

fn address(option: &str, text: &str) -> Result<SocketAddr, String> {
    text.parse()
        .map_err(|_| format!("{option} needs an address and port such as 127.0.0.1:14550, not {text}"))
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let rest = args.get(1..).unwrap_or_default();
    match args.first().map(String::as_str) {
        Some("bench") => bench_main(rest),
        Some("decode") => decode::main(rest),
        Some("hil") => hil::main(rest),
        _ => {
            eprintln!("{USAGE}\n{}\n{}", decode::USAGE, hil::USAGE);
            ExitCode::from(2)
        }
    }
}

/// Say what was wrong with the command line (nothing for `--help`), show the usage, and exit with `code`.
fn usage_error(message: &str, usage: &str, code: ExitCode) -> ExitCode {
    if !message.is_empty() {
        eprintln!("lbv: {message}");
    }
    eprintln!("{usage}");
    code
}

/// `lbv bench ...`
fn bench_main(args: &[String]) -> ExitCode {
    let options = match parse(args) {
        Ok(options) => options,
        Err(message) => return usage_error(&message, USAGE, ExitCode::from(2)),
    };
    if options.list {
        for scenario in SCENARIOS {
            println!("{:<22} {:>5.0} s  {}", scenario.name, scenario.seconds, scenario.about);
        }
        return ExitCode::SUCCESS;
    }
    if options.udp {
        return udp(&options);
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

/// `--udp`: the dive vehicle, no scripted pilot, its console bridged to UDP, paced to the wall clock.
fn udp(options: &Options) -> ExitCode {
    let send = options.udp_send.unwrap_or(bench::udp::DEFAULT_SEND);
    let listen = options.udp_listen.unwrap_or(bench::udp::DEFAULT_LISTEN);
    let Some(dive) = scenarios::find("dive") else {
        eprintln!("lbv: no dive scenario to take the vehicle from");
        return ExitCode::from(2);
    };
    let link = match bench::udp::UdpLink::open(listen, send) {
        Ok(link) => link,
        Err(error) => {
            eprintln!("lbv: cannot listen on {listen}: {error}");
            return ExitCode::from(2);
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
            return ExitCode::from(2);
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
