//! The options that say where a drive is and how to reach it (`--port`, `--drive`,
//! `--address`, ...), each given to the subcommands it applies to, so that a subcommand's help
//! lists only its own options.
//!
//! They go before or after the command: `drivebus --port P --drive generic --address 1 status`
//! and `drivebus status --port P ...` are the same. Before the command, every one of them is
//! accepted by the parser and then checked against the command: `drivebus --port P serve` is
//! bad usage ("--port does not apply to drivebus serve"). After it, the parser knows the
//! command's own. An option given at both places takes the value after the command; repeated
//! ones (`--address`, `--drive`) collect both.

use clap::parser::ValueSource;
use clap::{Arg, ArgAction, ArgMatches, Command};

use crate::commands::target::{usage, Target};

/// `--port`.
fn port() -> Arg {
    Arg::new("port")
        .long("port")
        .value_name("DEVICE|tcp://HOST:PORT")
        .action(ArgAction::Append)
        .help("Serial device (/dev/ttyUSB0, a pty) or tcp://HOST:PORT of a serial device server")
}

/// `--drive` with `help` for what it names in this command.
fn drive(value_name: &'static str, help: &'static str) -> Arg {
    Arg::new("drive").long("drive").value_name(value_name).action(ArgAction::Append).help(help)
}

/// `--template`: a template file whose kind `--drive` may name.
fn template() -> Arg {
    Arg::new("template")
        .long("template")
        .value_name("FILE")
        .action(ArgAction::Append)
        .help("A drive template (docs/templates.md) whose kind --drive may name; repeat it for more")
}

/// `--address`.
fn address(help: &'static str) -> Arg {
    Arg::new("address")
        .long("address")
        .value_name("N")
        .value_parser(clap::value_parser!(u8))
        .action(ArgAction::Append)
        .help(help)
}

/// `--protocol`/`-p` with `help` for what it chooses in this command.
fn protocol(help: &'static str) -> Arg {
    Arg::new("protocol").long("protocol").short('p').value_name("PROTOCOL").help(help)
}

fn baud(help: &'static str) -> Arg {
    Arg::new("baud")
        .long("baud")
        .value_name("BAUD|auto")
        .value_parser(crate::commands::target::parse_baud)
        .help(help)
}

fn serial(help: &'static str) -> Arg {
    Arg::new("serial").long("serial").value_name("FORMAT").help(help)
}

fn timeout(help: &'static str) -> Arg {
    Arg::new("timeout").long("timeout").value_name("MS").value_parser(clap::value_parser!(u64)).help(help)
}

fn json() -> Arg {
    Arg::new("json").long("json").action(ArgAction::SetTrue).help("Output JSON")
}

/// The bus options of a command that talks to drives through the bus owner.
fn tuning() -> Vec<Arg> {
    vec![
        Arg::new("retries")
            .long("retries")
            .value_name("N")
            .value_parser(clap::value_parser!(u8))
            .default_value("2")
            .help("Retries after a timeout or a damaged reply"),
        Arg::new("gap").long("gap").value_name("MS").value_parser(clap::value_parser!(f64)).help(
            "Silence kept before each request, in milliseconds (default: the protocol's, e.g. Modbus RTU \
             t3.5); 0 for a pty or a TCP server with no RS-485 line behind it",
        ),
        Arg::new("rs485").long("rs485").value_name("MODE").default_value("off").help(
            "RS-485 direction control on a serial port: off (the adapter switches by itself, as most \
             USB-RS485 adapters do), auto (the kernel's RS-485 mode, else RTS), kernel, rts",
        ),
        Arg::new("strict_t15").long("strict-t15").action(ArgAction::SetTrue).help(
            "Modbus RTU: discard a reply with a silence over t1.5 between two of its bytes (on-board \
             UARTs; USB adapters deliver bytes in bursts and would lose good replies)",
        ),
        Arg::new("echo")
            .long("echo")
            .action(ArgAction::SetTrue)
            .help("Discard the local echo of our own requests (2-wire adapters that hear themselves)"),
        Arg::new("max_in_flight")
            .long("max-in-flight")
            .value_name("N")
            .value_parser(clap::value_parser!(usize))
            .help(
                "Modbus TCP (--protocol modbus-tcp): the most requests in flight on the connection, 1..16 \
                 (default 1), where the server or gateway takes pipelined requests",
            ),
    ]
}

const FAMILY: &str =
    "The drive family: generic, toshiba, danfoss, b800, or a template kind (shipped, or --template FILE)";
const DRIVE_PROTOCOL: &str =
    "The protocol, where the family speaks several (generic: modbus-ascii, modbus-rtu; \
     toshiba: toshiba-binary, toshiba-ascii, modbus-rtu), or modbus-tcp with --port tcp://HOST[:502] for any \
     Modbus drive behind a Modbus TCP server";
const BAUD: &str = "Baud rate (default: the family's)";
const SERIAL: &str = "Character format such as 8E1 (default: the family's)";

/// The options of a command for one drive (status, run, param, params, raw, ...).
fn one_drive() -> Vec<Arg> {
    drives(address("The drive's address (0: every drive, where the protocol has broadcast)"))
}

/// The options of a command for the drives `address` names.
fn drives(address: Arg) -> Vec<Arg> {
    let mut args = vec![
        port(),
        drive("FAMILY", FAMILY),
        template(),
        address,
        protocol(DRIVE_PROTOCOL),
        baud(BAUD),
        serial(SERIAL),
        timeout("Response timeout in milliseconds (default: the protocol's)"),
    ];
    args.extend(tuning());
    args.push(json());
    args
}

/// Every option, as accepted before the command (checked against it after parsing).
pub fn before_the_command() -> Vec<Arg> {
    let mut args = vec![
        port(),
        drive(
            "FAMILY | KIND@ADDR[:PROTOCOL] | ID",
            "The drive family (generic, toshiba, danfoss, b800, a template kind, or auto for scan: the families, then the template kinds); for simulate a drive \
             as KIND@ADDR[:PROTOCOL]; for events and trend the drive's name in the gateway",
        ),
        template(),
        address("The drive's address (monitor takes several: --address 1 --address 2)"),
        protocol("The protocol: for decode the wire format; for a drive, where its family speaks several"),
        baud(BAUD),
        serial(SERIAL),
        timeout("Response timeout in milliseconds (default: the protocol's)"),
    ];
    args.extend(tuning());
    args.push(json());
    args.into_iter().map(|a| a.help_heading("Options for the command, given before it")).collect()
}

/// Each command's own options, by its path of names.
fn per_command() -> Vec<(&'static [&'static str], Vec<Arg>)> {
    let mut out: Vec<(&'static [&'static str], Vec<Arg>)> = Vec::new();
    for path in [
        &["status"][..],
        &["run"],
        &["stop"],
        &["reverse"],
        &["jog"],
        &["reset"],
        &["trips"],
        &["speed"],
        &["param"],
        &["param", "get"],
        &["param", "set"],
        &["params"],
        &["params", "backup"],
        &["params", "restore"],
        &["params", "diff"],
        &["raw"],
        &["panel"],
    ] {
        out.push((path, one_drive()));
    }
    out.push((
        &["monitor"],
        drives(address("A drive to show; repeat it for more drives (--address 1 --address 2)")),
    ));
    out.push((
        &["scan"],
        vec![
            port(),
            drive(
                "FAMILY|auto",
                "The drive family to try (generic, toshiba, danfoss, b800), or auto for all",
            ),
            template(),
            protocol("Only this protocol (default: every protocol of the family)"),
            baud("The baud rate to try (--bauds for several; default: the family's)"),
            serial("The character format to try (--formats for several; default: the family's)"),
            timeout("Response timeout per try in milliseconds (default: 60)"),
            json(),
        ],
    ));
    out.push((
        &["decode"],
        vec![
            protocol(
                "The wire format: modbus-rtu, modbus-ascii, toshiba-ascii, toshiba-binary, danfoss-fc, b800",
            ),
            drive("FAMILY", "Name Modbus registers by this family's catalog (generic or toshiba)"),
            template(),
            json(),
        ],
    ));
    out.push((
        &["simulate"],
        vec![
            drive(
                "KIND@ADDR[:PROTOCOL]",
                "A drive on the virtual bus, repeated for more drives: generic@1:modbus-rtu, toshiba@2, \
                 danfoss@3, b800@5",
            ),
            template(),
            baud("The line's baud rate (default: the first drive's)"),
            serial("The line's character format such as 8E1 (default: the first drive's)"),
        ],
    ));
    out.push((
        &["sniff"],
        vec![
            port().help(
                "The serial device or tcp://HOST:PORT to listen on; twice for a 4-wire line (one port per direction)",
            ),
            protocol("The protocol on the line, or auto (default): found from the traffic"),
            baud("The line's baud rate, or auto (default): found from the traffic"),
            serial("The line's character format such as 8E1, or auto (default): found from the traffic"),
            json(),
        ],
    ));
    for path in [&["events"][..], &["trend"]] {
        out.push((path, vec![drive("ID", "The drive's name in the gateway"), json()]));
    }
    out
}

/// Adds the options to `cmd` and its subcommands.
pub fn add_to(mut cmd: Command) -> Command {
    cmd = cmd.args(before_the_command());
    for (path, args) in per_command() {
        cmd = add_at(cmd, path, args);
    }
    cmd
}

fn add_at(cmd: Command, path: &[&str], args: Vec<Arg>) -> Command {
    match path {
        [] => cmd.args(args),
        [first, rest @ ..] => {
            let first = first.to_string();
            cmd.mut_subcommand(first, |sub| add_at(sub, rest, args))
        }
    }
}

/// The matches of each level, the top first, the command's last.
fn levels(matches: &ArgMatches) -> (Vec<&ArgMatches>, Vec<&str>) {
    let mut levels = vec![matches];
    let mut names = Vec::new();
    let mut m = matches;
    while let Some((name, sub)) = m.subcommand() {
        levels.push(sub);
        names.push(name);
        m = sub;
    }
    (levels, names)
}

fn given(m: &ArgMatches, id: &str) -> bool {
    m.try_contains_id(id).unwrap_or(false) && m.value_source(id) == Some(ValueSource::CommandLine)
}

/// The value of `id`: from the deepest level that was given it, else the command's default.
fn one<T: Clone + Send + Sync + 'static>(levels: &[&ArgMatches], id: &str) -> Option<T> {
    let from = levels.iter().rev().find(|m| given(m, id)).or_else(|| levels.last())?;
    from.try_get_one::<T>(id).ok().flatten().cloned()
}

/// Every value of a repeatable `id`, the top level's first.
fn all<T: Clone + Send + Sync + 'static>(levels: &[&ArgMatches], id: &str) -> Vec<T> {
    levels
        .iter()
        .filter(|m| given(m, id))
        .flat_map(|m| m.try_get_many::<T>(id).ok().flatten().into_iter().flatten().cloned())
        .collect()
}

/// The target options of the command `matches` holds; an option given before a command it does
/// not apply to is bad usage.
pub fn target(matches: &ArgMatches) -> anyhow::Result<Target> {
    let (levels, names) = levels(matches);
    let leaf = levels.last().copied().unwrap_or(matches);
    let command = std::iter::once("drivebus").chain(names.iter().copied()).collect::<Vec<_>>().join(" ");
    for level in &levels[..levels.len() - 1] {
        for arg in before_the_command() {
            let id = arg.get_id().as_str();
            if given(level, id) && leaf.try_contains_id(id).is_err() {
                let flag = arg.get_long().unwrap_or(id);
                return Err(usage(format!("--{flag} does not apply to {command} (see {command} --help)")));
            }
        }
    }
    let templates: Vec<String> = all(&levels, "template");
    crate::commands::template::load(&templates)?;
    Ok(Target {
        port: all(&levels, "port"),
        drive: all(&levels, "drive"),
        address: all(&levels, "address"),
        protocol: one(&levels, "protocol"),
        baud: one(&levels, "baud"),
        serial: one(&levels, "serial"),
        timeout: one(&levels, "timeout"),
        retries: one(&levels, "retries").unwrap_or(2),
        gap: one(&levels, "gap"),
        rs485: one(&levels, "rs485").unwrap_or_else(|| "off".to_string()),
        strict_t15: one(&levels, "strict_t15").unwrap_or(false),
        echo: one(&levels, "echo").unwrap_or(false),
        max_in_flight: one(&levels, "max_in_flight"),
        json: one(&levels, "json").unwrap_or(false),
    })
}
