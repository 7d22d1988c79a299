//! `drivebus`: commission, monitor and decode variable-frequency drives on RS-485.
//!
//! The binary is thin (argument parsing and output); the protocols live in `drivebus-proto`.
//! Exit status: 0 done, 1 the drive (or the bytes) said no, 2 no answer or the link failed,
//! 3 bad usage. Errors go to stderr, one line each.

mod commands;
mod hexarg;
mod options;
mod sniff;

use std::process::ExitCode;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

/// Talk to variable-frequency drives over RS-485.
#[derive(Parser, Debug)]
#[command(name = "drivebus", version = VERSION, about, long_about = None)]
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
    /// Listen to a line someone else drives, never transmit: every frame of every protocol
    /// decoded, requests paired with replies and their latency, per-address statistics, a pcap.
    Sniff(commands::sniff::SniffArgs),
    /// Read a drive's state: running, direction, output and setpoint Hz, current, fault.
    Status,
    /// Start the motor.
    Run,
    /// Ramp to a stop.
    Stop,
    /// Reverse the direction.
    Reverse,
    /// Run at the jog speed.
    Jog,
    /// Reset a fault.
    Reset,
    /// Read a drive's trip history as far as its protocol gives it: the trip in force and the
    /// logged trips, newest first, with the frequency and current at the trip where logged.
    Trips,
    /// Set the speed in Hz (checked against the drive's limits before anything is sent).
    Speed {
        /// The speed in Hz.
        #[arg(allow_negative_numbers = true)]
        hz: f64,
    },
    /// Read or write one parameter by the manual's name.
    #[command(subcommand)]
    Param(commands::drive::ParamCmd),
    /// Back up, restore or compare a drive's parameter set.
    #[command(subcommand)]
    Params(commands::drive::ParamsCmd),
    /// Find the drives on a line across addresses, baud rates and protocols (--drive auto for
    /// every family).
    Scan(commands::scan::ScanArgs),
    /// Live view of one or more drives (repeat --address): state, trend of frequency and
    /// current, link statistics; `q` quits. Prints lines instead when stdout is not a terminal.
    Monitor(commands::monitor::MonitorArgs),
    /// The drive's panel over the line: what its display shows, its keys pressed (--key run,
    /// --key up, ...), and on a Toshiba drive four characters put on its LEDs (--show TEXT).
    Panel(commands::panel::PanelArgs),
    /// Send bytes (hex) as one request and print the decoded reply.
    Raw {
        /// The request on the wire, in hex.
        #[arg(required = true, num_args = 1..)]
        hex: Vec<String>,
    },
    /// Run the gateway: every bus polled, one view over Modbus TCP, HTTP/JSON and the dashboard
    /// (`--demo` runs simulated drives with nothing attached).
    Serve(commands::serve::ServeArgs),
    /// List the gateway's event log (drivebus.db in the state folder, or the demo's drivebus-demo.db): commands with who, what and the result,
    /// trips, fault resets, drives and buses going online and offline. --drive ID narrows it.
    Events(commands::history::EventsArgs),
    /// Check a gateway configuration without running it.
    #[command(subcommand)]
    Config(commands::config::ConfigCmd),
    /// Check drive template files (every error with its line) or list the template kinds.
    #[command(subcommand)]
    Template(commands::template::TemplateCmd),
    /// Show one drive's trend (--drive ID) from the gateway's store: output Hz (average, min,
    /// max), current and setpoint per second or per minute.
    Trend(commands::history::TrendArgs),
}

/// The version and the commit it was built from (`0.1.0 (commit 1a2b3c4)`; build.rs).
const VERSION: &str = concat!(env!("CARGO_PKG_VERSION"), " (commit ", env!("DRIVEBUS_COMMIT"), ")");

/// Exit status for bad usage (unknown option, value out of range).
pub const EXIT_USAGE: u8 = 3;

/// SIGPIPE back to its default action (end the process), which Rust's runtime sets to ignore.
#[cfg(unix)]
fn default_sigpipe() {
    // SAFETY: setting a signal's disposition to SIG_DFL, before any other thread exists, has no
    // memory-safety condition: no handler runs Rust code.
    #[allow(unsafe_code)]
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

#[cfg(not(unix))]
fn default_sigpipe() {}

/// What clap said, as one line on stderr and exit 3 (help and version: printed, exit 0).
fn usage_exit(e: &clap::Error) -> ExitCode {
    use clap::error::ErrorKind;
    if matches!(e.kind(), ErrorKind::DisplayHelp | ErrorKind::DisplayVersion) {
        let _ = e.print();
        return ExitCode::SUCCESS;
    }
    if e.kind() == ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand {
        // The command given so far, from the help's usage line ("Usage: drivebus param <COMMAND>").
        let help = e.to_string();
        let usage = help.lines().find_map(|l| l.strip_prefix("Usage: ")).unwrap_or("drivebus");
        let given: Vec<&str> =
            usage.split_whitespace().take_while(|w| !w.starts_with('<') && !w.starts_with('[')).collect();
        let given = given.join(" ");
        eprintln!("drivebus: say which command: {given} <COMMAND> (see {given} --help)");
        return ExitCode::from(EXIT_USAGE);
    }
    // One line: clap's message without its usage block.
    let msg = e.to_string();
    // The lines before the usage block, joined (a missing argument is named on the line after
    // "the following required arguments were not provided:").
    let said: Vec<&str> = msg
        .lines()
        .take_while(|l| !l.trim().is_empty() && !l.starts_with("Usage:"))
        .map(|l| l.trim().trim_start_matches("error: "))
        .collect();
    let first = if said.is_empty() { "bad usage".to_string() } else { said.join(" ") };
    eprintln!("drivebus: {first} (see drivebus --help)");
    ExitCode::from(EXIT_USAGE)
}

fn main() -> ExitCode {
    // The command, and the target options given before or after it.
    let matches = match options::add_to(Cli::command()).try_get_matches() {
        Ok(m) => m,
        Err(e) => return usage_exit(&e),
    };
    let cli = match Cli::from_arg_matches(&matches) {
        Ok(cli) => cli,
        Err(e) => return usage_exit(&e),
    };
    let target = match options::target(&matches) {
        Ok(t) => t,
        Err(e) => {
            eprintln!("drivebus: {e}");
            return ExitCode::from(EXIT_USAGE);
        }
    };
    // A reader that stops early (`drivebus events | head -1`) ends a printing command quietly,
    // as it ends any Unix tool, instead of a panic in println!. The two services keep SIGPIPE
    // ignored: for them a closed socket or pipe is an error to report, not their end.
    if !matches!(cli.command, Command::Serve(_) | Command::Simulate(_)) {
        default_sigpipe();
    }
    let result = match cli.command {
        Command::Decode(args) => commands::decode::run(&args, &target),
        Command::Simulate(args) => commands::simulate::run(&args, &target),
        Command::Sniff(args) => commands::sniff::run(&args, &target),
        Command::Status => commands::drive::status(&target),
        Command::Run => commands::drive::command(&target, "run", None),
        Command::Stop => commands::drive::command(&target, "stop", None),
        Command::Reverse => commands::drive::command(&target, "reverse", None),
        Command::Jog => commands::drive::command(&target, "jog", None),
        Command::Reset => commands::drive::command(&target, "reset", None),
        Command::Trips => commands::trips::run(&target),
        Command::Speed { hz } => commands::drive::command(&target, "speed", Some(hz)),
        Command::Param(cmd) => commands::drive::param(&target, &cmd),
        Command::Params(cmd) => commands::drive::params(&target, &cmd),
        Command::Raw { hex } => commands::drive::raw(&target, &hex),
        Command::Scan(args) => commands::scan::run(&args, &target),
        Command::Serve(args) => commands::serve::run(&args),
        Command::Config(cmd) => commands::config::run(&cmd),
        Command::Template(cmd) => commands::template::run(&cmd),
        Command::Events(args) => commands::history::events(&args, &target),
        Command::Trend(args) => commands::history::trend(&args, &target),
        Command::Monitor(args) => commands::monitor::run(&args, &target),
        Command::Panel(args) => commands::panel::run(&args, &target),
    };
    match result {
        Ok(code) => ExitCode::from(code),
        Err(e) => {
            let code = e.downcast_ref::<commands::target::Failure>().map_or(EXIT_USAGE, |f| f.code);
            let line = format!("{e:#}").replace('\n', " ");
            eprintln!("drivebus: {line}");
            ExitCode::from(code)
        }
    }
}
