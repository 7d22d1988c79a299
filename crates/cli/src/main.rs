//! `drivebus`: commission, monitor and decode variable-frequency drives on RS-485.
//!
//! The binary is thin (argument parsing and output); the protocols live in `drivebus-proto`.
//! Exit status: 0 done, 1 the drive (or the bytes) said no, 2 no answer or the link failed,
//! 3 bad usage. Errors go to stderr, one line each.

mod commands;
mod hexarg;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Talk to variable-frequency drives over RS-485.
#[derive(Parser, Debug)]
#[command(name = "drivebus", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Decode bytes captured on the wire: every frame, its fields named as the manual names
    /// them, values in units, and an exact diagnosis of bad bytes.
    Decode(commands::decode::DecodeArgs),
    /// Run virtual drives on a virtual RS-485 line, paced at the real baud rate, behind a
    /// pseudo-terminal or a TCP port.
    Simulate(commands::simulate::SimulateArgs),
}

/// Exit status for bad usage (unknown option, value out of range).
pub const EXIT_USAGE: u8 = 3;

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            use clap::error::ErrorKind;
            if matches!(e.kind(), ErrorKind::DisplayHelp | ErrorKind::DisplayVersion) {
                let _ = e.print();
                return ExitCode::SUCCESS;
            }
            // One line: clap's message without its usage block.
            let msg = e.to_string();
            let first = msg.lines().next().unwrap_or("bad usage").trim_start_matches("error: ");
            eprintln!("drivebus: {first} (see drivebus --help)");
            return ExitCode::from(EXIT_USAGE);
        }
    };
    let result = match cli.command {
        Command::Decode(args) => commands::decode::run(&args),
        Command::Simulate(args) => commands::simulate::run(&args),
    };
    match result {
        Ok(code) => ExitCode::from(code),
        Err(e) => {
            eprintln!("drivebus: {e:#}");
            ExitCode::from(EXIT_USAGE)
        }
    }
}
