//! `lbv decode`: read what people capture on the bench (logic-analyser I2C exports, candump logs, a board's
//! post-mortem record) and print it decoded with the project's protocol crates.

pub mod can;
pub mod crash;
pub mod i2c;
pub mod tlog;

use std::fs::File;
use std::io::{self, BufRead, BufReader};
use std::path::Path;
use std::process::ExitCode;

/// `lbv decode`'s commands.
#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Thruster-bus transfers from sigrok's I2C decoder output (sigrok-cli or PulseView)
    I2c(i2c::Args),
    /// The BAT board's frames from candump logs
    Can(can::Args),
    /// A board's post-mortem record (panic, fault, watchdog), with the image's ELF for functions and lines
    Crash(crash::Args),
    /// A telemetry log (the master's black box, a ground station's .tlog), printed or plotted
    Tlog(tlog::Args),
}

/// `lbv decode ...`
pub fn main(command: Command) -> ExitCode {
    match command {
        Command::I2c(args) => i2c::main(&args),
        Command::Can(args) => can::main(&args),
        Command::Crash(args) => crash::main(&args),
        Command::Tlog(args) => tlog::main(&args),
    }
}

/// Why a decoder stopped before the end of its input.
#[derive(Debug)]
pub enum StreamError {
    /// Reading the input failed.
    Read(io::Error),
    /// Writing the output failed.
    Write(io::Error),
}

impl StreamError {
    /// Say on standard error why `command` stopped reading `input`, and give its exit status. A reader of the
    /// output that went away (`| head`) is not an error: there is nothing more to say.
    fn exit(self, command: &str, input: &str) -> ExitCode {
        match self {
            StreamError::Write(error) if error.kind() == io::ErrorKind::BrokenPipe => ExitCode::SUCCESS,
            StreamError::Write(error) => {
                eprintln!("{command}: cannot write the output: {error}");
                ExitCode::from(crate::exit::TROUBLE)
            }
            StreamError::Read(error) => {
                eprintln!("{command}: cannot read {input}: {error}");
                ExitCode::from(crate::exit::TROUBLE)
            }
        }
    }
}

/// Size of the input buffer.
const IN_BUFFER: usize = 256 * 1024;

/// The input named on the command line, standard input for none or `-`, and its name for messages; or why the
/// file cannot be opened.
fn open(input: Option<&Path>) -> Result<(Box<dyn BufRead>, String), String> {
    match input {
        Some(path) if path != Path::new("-") => match File::open(path) {
            Ok(file) => Ok((
                Box::new(BufReader::with_capacity(IN_BUFFER, file)),
                path.display().to_string(),
            )),
            Err(error) => Err(format!("cannot open {}: {error}", path.display())),
        },
        _ => Ok((
            Box::new(BufReader::with_capacity(IN_BUFFER, io::stdin())),
            "standard input".into(),
        )),
    }
}
