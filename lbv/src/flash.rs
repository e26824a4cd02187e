//! `lbv flash`: a board from nothing in one command. A NUCLEO whose flash is blank (or holds something else) needs
//! the bootloader before the image: an image alone sits in ACTIVE, past the bootloader's pages, and never starts.
//! So the command builds the board's bootloader and writes it, builds the image and runs it with probe-rs, its
//! defmt log streamed, as `cargo thruster` / `cargo master` do (docs/flashing.md).

use std::path::Path;
use std::process::ExitCode;

use crate::exit;
use crate::hil::{
    Command, FamilyArg, MASTER_CHIP, TARGET, THRUSTER_CHIP, elf, probe_arg, probe_selector, target_dir, workspace,
};

const HELP: &str = "\
Builds the board's bootloader and writes it, then builds the image and runs it with probe-rs,
streaming its log until interrupted. Without --erase the pages it does not write keep what they
hold (the master's settings among them).

Exit status: 0 every step ran (the log ended normally); 2 a bad command line, or a build or a
probe-rs step that failed (probe-rs's own message says why).";

/// `lbv flash`'s command line.
#[derive(Debug, Clone, PartialEq, clap::Parser)]
#[command(after_help = HELP)]
pub struct Args {
    /// The board to write
    #[arg(value_enum)]
    pub board: Board,
    /// The thruster's controller family; for the master, the family its dev-kit table expects (with --devkit)
    #[arg(long, value_enum, default_value_t = FamilyArg::Seabotix)]
    pub family: FamilyArg,
    /// Thruster: a brushed motor (phases A and B as an H-bridge)
    #[arg(long)]
    pub brushed: bool,
    /// Master: the two-board bench's table (one thruster wired to bus 2) instead of the vehicle's six
    #[arg(long)]
    pub devkit: bool,
    /// The board's ST-LINK, by serial number or VID:PID:SERIAL, when more than one is plugged in
    #[arg(long, value_name = "SERIAL", value_parser = probe_arg)]
    pub probe: Option<String>,
    /// Erase the whole chip first: an earlier update's state goes, and the master's settings with it
    #[arg(long)]
    pub erase: bool,
    /// Build images that take update files signed with the published development key (bench boards only:
    /// keys/README.md)
    #[arg(long)]
    pub dev_key: bool,
    /// Print the commands and run nothing
    #[arg(long)]
    pub dry_run: bool,
}

/// A board, as the command line names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Board {
    /// A NUCLEO-G431RB with its X-NUCLEO-IHM08M1: the thruster controller
    Thruster,
    /// The NUCLEO-G474RE: the master
    Master,
}

/// The commands, in order: build the board's bootloader, erase the chip (with --erase), write the bootloader,
/// build the image, and run it with its log streamed. The bootloader is written before the image is built: the
/// two boards' bootloaders are one crate, and a build for the other board would overwrite its ELF.
pub fn plan(args: &Args, workspace: &Path, target_dir: &Path) -> Vec<Command> {
    let (chip, boot_feature, package) = match args.board {
        Board::Thruster => (THRUSTER_CHIP, "thruster", "thruster-fw"),
        Board::Master => (MASTER_CHIP, "master", "lbv-master-fw"),
    };
    let legacy = args.family == FamilyArg::Legacy;
    let features: Vec<&str> = match args.board {
        Board::Thruster => [(legacy, "legacy"), (args.brushed, "brushed")]
            .into_iter()
            .filter_map(|(on, feature)| on.then_some(feature))
            .collect(),
        Board::Master => [(args.devkit, "devkit"), (args.devkit && legacy, "legacy")]
            .into_iter()
            .filter_map(|(on, feature)| on.then_some(feature))
            .collect(),
    };
    let features = features.join(",");
    let probe = args.probe.as_deref().map(probe_selector);
    let probe_args: Vec<&str> = probe.as_deref().map_or_else(Vec::new, |probe| vec!["--probe", probe]);
    let probe_rs = |what: &'static str, verb: &str, rest: &[&str]| {
        Command::new(
            what,
            "probe-rs",
            &[&[verb, "--chip", chip][..], &probe_args, rest].concat(),
        )
    };
    let cargo = |what: &'static str, package: &str, features: &str| {
        let mut words = vec!["build", "--release", "--target", TARGET, "-p", package];
        if !features.is_empty() {
            words.extend(["--features", features]);
        }
        // Bench images may take development-key files only when asked (keys/README.md).
        let command = if args.dev_key {
            Command::new(what, "env", &[&["LBV_ALLOW_DEV_KEY=1", "cargo"][..], &words].concat())
        } else {
            Command::new(what, "cargo", &words)
        };
        Command {
            dir: Some(workspace.to_path_buf()),
            ..command
        }
    };
    let bootloader = elf(target_dir, "lbv-boot").display().to_string();
    let image = elf(target_dir, package).display().to_string();
    let mut commands = vec![cargo("build the bootloader", "lbv-boot", boot_feature)];
    if args.erase {
        commands.push(probe_rs("erase the chip", "erase", &[]));
    }
    commands.extend([
        probe_rs("write the bootloader", "download", &[&bootloader]),
        cargo("build the image", package, &features),
        probe_rs("write the image and run it, following its log", "run", &[&image]),
    ]);
    commands
}

/// `lbv flash ...`
pub fn main(args: Args) -> ExitCode {
    let workspace = workspace();
    let commands = plan(&args, &workspace, &target_dir(&workspace));
    for command in &commands {
        if args.dry_run {
            println!("# {}\n{}", command.what, command.line());
            continue;
        }
        println!("lbv flash: {}: {}", command.what, command.line());
        match command.process().status() {
            Ok(status) if status.success() => {}
            Ok(status) => {
                eprintln!("lbv: {} failed ({status})", command.what);
                return ExitCode::from(exit::TROUBLE);
            }
            Err(error) => {
                eprintln!("lbv: cannot run {}: {error}", command.program);
                return ExitCode::from(exit::TROUBLE);
            }
        }
    }
    ExitCode::from(exit::OK)
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use clap::Parser;

    use super::*;

    fn lines(command_line: &[&str]) -> Vec<String> {
        let args = Args::try_parse_from([&["flash"][..], command_line].concat()).unwrap();
        plan(&args, Path::new("/ws"), &PathBuf::from("/ws/target"))
            .iter()
            .map(Command::line)
            .collect()
    }

    #[test]
    fn a_thruster_gets_its_bootloader_then_its_image() {
        assert_eq!(
            lines(&["thruster"]),
            [
                "cd /ws && cargo build --release --target thumbv7em-none-eabihf -p lbv-boot --features thruster",
                "probe-rs download --chip STM32G431RBTx /ws/target/thumbv7em-none-eabihf/release/lbv-boot",
                "cd /ws && cargo build --release --target thumbv7em-none-eabihf -p thruster-fw",
                "probe-rs run --chip STM32G431RBTx /ws/target/thumbv7em-none-eabihf/release/thruster-fw",
            ]
        );
        assert_eq!(
            lines(&[
                "thruster",
                "--family",
                "legacy",
                "--brushed",
                "--probe",
                "066DFF4",
                "--dev-key"
            ]),
            [
                "cd /ws && env LBV_ALLOW_DEV_KEY=1 cargo build --release --target thumbv7em-none-eabihf -p lbv-boot \
                 --features thruster",
                "probe-rs download --chip STM32G431RBTx --probe 0483:374e:066DFF4 \
                 /ws/target/thumbv7em-none-eabihf/release/lbv-boot",
                "cd /ws && env LBV_ALLOW_DEV_KEY=1 cargo build --release --target thumbv7em-none-eabihf -p thruster-fw \
                 --features legacy,brushed",
                "probe-rs run --chip STM32G431RBTx --probe 0483:374e:066DFF4 \
                 /ws/target/thumbv7em-none-eabihf/release/thruster-fw",
            ]
        );
    }

    #[test]
    fn a_master_gets_its_own_chip_bootloader_and_table() {
        assert_eq!(
            lines(&["master", "--devkit", "--family", "legacy", "--erase"]),
            [
                "cd /ws && cargo build --release --target thumbv7em-none-eabihf -p lbv-boot --features master",
                "probe-rs erase --chip STM32G474RETx",
                "probe-rs download --chip STM32G474RETx /ws/target/thumbv7em-none-eabihf/release/lbv-boot",
                "cd /ws && cargo build --release --target thumbv7em-none-eabihf -p lbv-master-fw --features devkit,legacy",
                "probe-rs run --chip STM32G474RETx /ws/target/thumbv7em-none-eabihf/release/lbv-master-fw",
            ]
        );
        // The vehicle's master: no features; --family alone says nothing without --devkit.
        assert!(
            lines(&["master", "--family", "legacy"])
                .iter()
                .any(|line| line.ends_with("-p lbv-master-fw"))
        );
    }

    #[test]
    fn a_probe_that_a_shell_would_read_is_refused() {
        for probe in ["", "06 6D", "$(reboot)", "a;b", "../x"] {
            assert!(
                Args::try_parse_from(["flash", "thruster", "--probe", probe]).is_err(),
                "{probe:?}"
            );
        }
        assert!(Args::try_parse_from(["flash", "boat"]).is_err());
    }
}
