//! The commissioning commands: one drive at a time, on a serial port or a serial server.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result};
use clap::Subcommand;
use drivebus_drive::backup::{differences, is_setting, Backup};
use drivebus_drive::profile::{DriveError, DriveStatus};
use drivebus_drive::{Family, Storage};
use drivebus_link::drive::{open_with, Drive, Error};
use drivebus_link::owner::{BusConfig, BusError};
use drivebus_link::Priority;
use drivebus_proto::line::CharFormat;
use drivebus_proto::protocol::WireProtocol;
use serde_json::{json, Value};

use crate::commands::target::{fail, Target, EXIT_LINK, EXIT_REFUSED, EXIT_USAGE};
use crate::hexarg::parse_hex_args;
use drivebus_analyze::report::{decode_by_name, decode_reply, render_json, render_text, Item};

/// `param` subcommands.
#[derive(Subcommand, Debug)]
pub enum ParamCmd {
    /// Read a parameter by the manual's name (P0.02, 0010, 4-14, F-12).
    Get {
        /// The parameter's name.
        name: String,
    },
    /// Write a parameter (RAM unless --eeprom, where the protocol lets you choose).
    Set {
        /// The parameter's name.
        name: String,
        /// The value in the parameter's unit (50, 50.00, "50 Hz").
        value: String,
        /// Store it in EEPROM too (wears the EEPROM: about 10 000 writes per parameter).
        #[arg(long)]
        eeprom: bool,
    },
}

/// `params` subcommands.
#[derive(Subcommand, Debug)]
pub enum ParamsCmd {
    /// Read every setting (writable, stored in EEPROM) into FILE (JSON).
    Backup {
        /// The file to write.
        file: PathBuf,
    },
    /// Write the parameters of FILE that differ from the drive's (to EEPROM).
    Restore {
        /// The backup file.
        file: PathBuf,
        /// Only show what would be written.
        #[arg(long)]
        dry_run: bool,
        /// Restore the communication settings too (bus address, baud rate, format, protocol,
        /// time-outs): only onto the drive the backup came from, or to clone its place.
        #[arg(long)]
        include_comm: bool,
    },
    /// Compare the drive with FILE: exit 0 when equal, 1 with the list when not.
    Diff {
        /// The backup file.
        file: PathBuf,
    },
}

/// Turns a drive or bus error into a failure with its exit status, naming `target`.
pub(crate) fn classify(e: Error, target: &str) -> anyhow::Error {
    match e {
        Error::Drive(DriveError::Refused { .. }) => fail(EXIT_REFUSED, format!("{target}: {e}")),
        Error::Drive(DriveError::Protocol(_)) => fail(EXIT_LINK, format!("{target}: {e}")),
        Error::Drive(_) => fail(EXIT_USAGE, format!("{target}: {e}")),
        Error::Bus(BusError::BadRequest(_)) => fail(EXIT_USAGE, format!("{target}: {e}")),
        Error::Bus(_) => fail(EXIT_LINK, e.to_string()),
    }
}

/// The target options resolved: family, protocol, port and bus settings.
pub(crate) struct Resolved {
    pub(crate) family: Family,
    pub(crate) protocol: WireProtocol,
    pub(crate) address: u8,
    pub(crate) port: String,
    pub(crate) config: BusConfig,
    pub(crate) label: String,
}

fn resolve(t: &Target) -> Result<Resolved> {
    let address = match t.address.as_slice() {
        [one] => *one,
        [] => return Err(fail(EXIT_USAGE, "say which drive: --address N")),
        _ => return Err(fail(EXIT_USAGE, "give one --address: this command talks to one drive")),
    };
    resolve_for(t, address)
}

/// Resolves the target options for the drive at `address`.
pub(crate) fn resolve_for(t: &Target, address: u8) -> Result<Resolved> {
    let port = t.one_port()?.ok_or_else(|| {
        fail(EXIT_USAGE, "say where the drive is: --port /dev/ttyUSB0 or --port tcp://HOST:PORT")
    })?;
    let family_s = match t.drive.as_slice() {
        [one] => one.clone(),
        [] => return Err(fail(EXIT_USAGE, "say which drive family: --drive generic|toshiba|danfoss|b800")),
        _ => return Err(fail(EXIT_USAGE, "give one --drive: this command talks to one drive")),
    };
    let family: Family =
        family_s.parse().map_err(|e: drivebus_drive::UnknownFamily| fail(EXIT_USAGE, e.to_string()))?;
    let modbus_tcp =
        t.protocol.as_deref().is_some_and(|p| p.eq_ignore_ascii_case(drivebus_link::mbap::MODBUS_TCP));
    let protocol = match &t.protocol {
        // Modbus TCP: the drive's Modbus frames in MBAP (the link's framing).
        Some(_) if modbus_tcp => family.check_protocol(WireProtocol::ModbusRtu).map_err(|_| {
            fail(EXIT_USAGE, format!("a {family} drive does not speak Modbus, so not modbus-tcp"))
        })?,
        Some(p) => {
            let p: WireProtocol =
                p.parse().map_err(|e| fail(EXIT_USAGE, format!("--protocol {p:?}: {e}")))?;
            family.check_protocol(p).map_err(|e| fail(EXIT_USAGE, e))?
        }
        None => family.default_protocol(),
    };
    let (db, df) = family.serial_default(protocol);
    let format = match t.serial() {
        Some(s) => s.parse::<CharFormat>().map_err(|e| fail(EXIT_USAGE, format!("--serial {s:?}: {e}")))?,
        None => df,
    };
    let baud = t.baud().unwrap_or(db);
    let mut config = BusConfig::new(protocol, baud, format);
    config.retries = t.retries;
    config.response_timeout = t.timeout.map(Duration::from_millis);
    config.rs485 = t.rs485.parse().map_err(|e: String| fail(EXIT_USAGE, format!("--rs485: {e}")))?;
    config.echo = t.echo;
    config.strict_t15 = t.strict_t15;
    config.family = Some(family);
    config.modbus_tcp = modbus_tcp;
    if let Some(n) = t.max_in_flight {
        config.max_in_flight = max_in_flight(n, modbus_tcp)?;
    }
    if let Some(gap) = t.gap {
        if !(0.0..=1000.0).contains(&gap) {
            return Err(fail(EXIT_USAGE, format!("--gap {gap} is outside 0..1000 ms")));
        }
        config.gap = Some(Duration::from_secs_f64(gap / 1000.0));
    }
    let label = if modbus_tcp {
        format!("{family} drive {address} on {port} (modbus-tcp)")
    } else {
        format!("{family} drive {address} on {port}")
    };
    Ok(Resolved { family, protocol, address, port, config, label })
}

/// `--max-in-flight N`: the gateway's `max_in_flight` rule (1..16, a modbus-tcp link only).
fn max_in_flight(n: usize, modbus_tcp: bool) -> Result<usize> {
    use drivebus_link::bus::{IN_FLIGHT_NEEDS_MODBUS_TCP, MAX_IN_FLIGHT};
    if !modbus_tcp {
        return Err(fail(
            EXIT_USAGE,
            format!(
                "--max-in-flight: {IN_FLIGHT_NEEDS_MODBUS_TCP}: give --port tcp://HOST[:502] --protocol modbus-tcp, or drop it"
            ),
        ));
    }
    if !(1..=MAX_IN_FLIGHT).contains(&n) {
        return Err(fail(EXIT_USAGE, format!("--max-in-flight {n} is outside 1..{MAX_IN_FLIGHT}")));
    }
    Ok(n)
}

pub(crate) async fn connect(t: &Target) -> Result<(Drive, String)> {
    let r = resolve(t)?;
    let profile = drivebus_drive::profile::for_drive(r.family, r.protocol, r.address)
        .map_err(|e| fail(EXIT_USAGE, e.to_string()))?;
    let bus = open_with(&r.port, r.config).await.map_err(|e| classify(e, &r.label))?;
    Ok((Drive::new(bus, profile), r.label))
}

/// A single-threaded tokio runtime for one command.
pub(crate) fn runtime() -> Result<tokio::runtime::Runtime> {
    Ok(tokio::runtime::Builder::new_current_thread().enable_all().build()?)
}

pub(crate) fn status_json(s: &DriveStatus) -> Value {
    let mut out = json!({
        "address": s.address,
        "running": s.running,
        "direction": s.direction,
        "output_hz": s.output_hz,
        "setpoint_hz": s.setpoint_hz,
        "current_a": s.current_a,
        "fault": s.fault.as_ref().map(|f| json!({"code": f.code, "text": f.text})),
    });
    // A template's `[values]`, by name, where it gives any.
    if !s.values.is_empty() {
        out["values"] =
            s.values.iter().map(|v| (v.name.clone(), json!({"value": v.value, "unit": v.unit}))).collect();
    }
    out
}

fn opt(v: Option<f64>, unit: &str, d: usize) -> String {
    v.map_or("-".into(), |x| format!("{x:.d$} {unit}"))
}

/// `status`.
pub fn status(t: &Target) -> Result<u8> {
    runtime()?.block_on(async {
        let (drive, label) = connect(t).await?;
        let s = drive.status().await.map_err(|e| classify(e, &label))?;
        if t.json {
            println!("{}", status_json(&s));
        } else {
            println!("{label}");
            println!("  state      {}", if s.running { "running" } else { "stopped" });
            println!("  direction  {}", s.direction.as_deref().unwrap_or("-"));
            println!("  output     {}", opt(s.output_hz, "Hz", 2));
            println!("  setpoint   {}", opt(s.setpoint_hz, "Hz", 2));
            println!("  current    {}", opt(s.current_a, "A", 1));
            match &s.fault {
                Some(f) => println!("  fault      {} ({})", f.code, f.text),
                None => println!("  fault      none"),
            }
            for v in &s.values {
                println!("  {:<10} {} {}", v.name, v.value, v.unit);
            }
            let st = drive.bus().stats();
            println!(
                "  link       {} {}, {} {}, {} {}, {} damaged",
                st.transactions,
                plural(st.transactions, "transaction", "transactions"),
                st.retries,
                plural(st.retries, "retry", "retries"),
                st.timeouts,
                plural(st.timeouts, "timeout", "timeouts"),
                st.checksum_errors
            );
        }
        Ok(0)
    })
}

/// `run`, `stop`, `reverse`, `jog`, `reset`, `speed`.
pub fn command(t: &Target, what: &str, hz: Option<f64>) -> Result<u8> {
    runtime()?.block_on(async {
        let (drive, label) = connect(t).await?;
        let r = match what {
            "run" => drive.run().await,
            "stop" => drive.stop().await,
            "reverse" => drive.reverse().await,
            "jog" => drive.jog().await,
            "reset" => drive.reset().await,
            _ => drive.set_speed(hz.unwrap_or(0.0)).await,
        };
        r.map_err(|e| classify(e, &label))?;
        // Address 0: every drive takes it and none answers, so nothing confirms it.
        let broadcast = drive.profile().address() == 0;
        if t.json {
            println!("{}", json!({"ok": true, "command": what, "hz": hz, "broadcast": broadcast}));
        } else if broadcast {
            let what = hz.map_or(what.to_string(), |hz| format!("speed {hz} Hz"));
            println!("{}: {what} sent to all drives (broadcast: no confirmation)", drive.bus().name());
        } else {
            match hz {
                Some(hz) => println!("{label}: speed set to {hz} Hz"),
                None => println!("{label}: {what} done"),
            }
        }
        Ok(0)
    })
}

/// `param get|set`.
pub fn param(t: &Target, cmd: &ParamCmd) -> Result<u8> {
    runtime()?.block_on(async {
        let (drive, label) = connect(t).await?;
        match cmd {
            ParamCmd::Get { name } => {
                let (raw, def) = drive.read_param(name).await.map_err(|e| classify(e, &label))?;
                if t.json {
                    println!("{}", json!({"name": def.name, "raw": raw, "value": def.from_raw(raw), "unit": def.unit, "text": def.format(raw)}));
                } else {
                    println!("{} {} = {}", def.name, def.title, def.format(raw));
                }
            }
            ParamCmd::Set { name, value, eeprom } => {
                let def = drive.profile().param(name).map_err(|e| fail(EXIT_USAGE, e.to_string()))?;
                let choose = can_choose_storage(drive.profile().family(), drive.profile().protocol());
                let storage = if *eeprom {
                    Storage::Eeprom
                } else if choose {
                    Storage::Ram
                } else {
                    def.storage
                };
                let raw = drive.write_param(name, value, storage).await.map_err(|e| classify(e, &label))?;
                // Told once the write is done: a protocol without parameter access says only that.
                if storage == Storage::Eeprom {
                    let why = if *eeprom {
                        "as asked".to_string()
                    } else {
                        format!("every {} write of it goes to EEPROM", drive.profile().protocol())
                    };
                    eprintln!("drivebus: note: {name} is written to EEPROM ({why}; about 10 000 writes per parameter over the drive's life)");
                }
                let def = drive.profile().param(name).map_err(|e| fail(EXIT_USAGE, e.to_string()))?;
                if t.json {
                    println!("{}", json!({"name": def.name, "raw": raw, "value": def.from_raw(raw), "unit": def.unit, "storage": if *eeprom {"eeprom"} else {"ram"}}));
                } else {
                    println!("{} {} set to {}", def.name, def.title, def.format(raw));
                }
            }
        }
        Ok(0)
    })
}

/// Whether the protocol lets the master choose RAM or EEPROM for a write (TIP `P`/`W`, FC AK
/// 2/3 or E/D); Modbus 06 on the generic and Toshiba drives always stores.
fn can_choose_storage(family: Family, protocol: WireProtocol) -> bool {
    matches!(
        (family, protocol),
        (Family::Toshiba, WireProtocol::ToshibaAscii | WireProtocol::ToshibaBinary) | (Family::Danfoss, _)
    )
}

/// Reads every setting ([`is_setting`]) the protocol can reach, as a backup of the drive. A
/// protocol without parameter access (B800) has nothing to back up: that is an error, not an
/// empty set.
async fn read_all(drive: &Drive, label: &str) -> Result<Backup> {
    let p = drive.profile();
    let catalog = drivebus_drive::Catalog::load(p.family()).map_err(|e| fail(EXIT_USAGE, e.to_string()))?;
    let mut read = Vec::new();
    let mut unsupported = false;
    for def in catalog.iter().filter(|d| is_setting(d)) {
        match drive.read_param(&def.name).await {
            Ok((raw, _)) => read.push((def, raw)),
            Err(Error::Drive(DriveError::Unsupported(_))) => unsupported = true,
            Err(e) => return Err(classify(e, label)),
        }
    }
    if unsupported && read.is_empty() {
        return Err(fail(
            EXIT_USAGE,
            format!(
                "{label}: nothing to back up or compare: the {} protocol has no parameter access (read and set the parameters on the drive's keypad)",
                p.protocol()
            ),
        ));
    }
    Ok(Backup::new(p.family(), p.protocol().name(), p.address(), read))
}

fn load_backup(file: &PathBuf) -> Result<Backup> {
    let text = std::fs::read_to_string(file)
        .with_context(|| format!("cannot read {}", file.display()))
        .map_err(|e| fail(EXIT_USAGE, format!("{e:#}")))?;
    Backup::parse(&text).map_err(|e| fail(EXIT_USAGE, format!("{}: {e}", file.display())))
}

/// `params backup|restore|diff`.
pub fn params(t: &Target, cmd: &ParamsCmd) -> Result<u8> {
    runtime()?.block_on(async {
        let (drive, label) = connect(t).await?;
        let family = drive.profile().family();
        let catalog = drivebus_drive::Catalog::load(family).map_err(|e| fail(EXIT_USAGE, e.to_string()))?;
        match cmd {
            ParamsCmd::Backup { file } => {
                let backup = read_all(&drive, &label).await?;
                let n = backup.params.len();
                std::fs::write(file, backup.to_text())
                    .map_err(|e| fail(EXIT_USAGE, format!("cannot write {}: {e}", file.display())))?;
                println!(
                    "{label}: {n} {} saved to {}",
                    plural(n as u64, "parameter", "parameters"),
                    file.display()
                );
                Ok(0)
            }
            ParamsCmd::Restore { file, dry_run, include_comm } => {
                let backup = load_backup(file)?;
                backup
                    .check_family(family, &file.display().to_string())
                    .map_err(|e| fail(EXIT_USAGE, e.to_string()))?;
                let address = drive.profile().address();
                match backup.address {
                    Some(from) if from != u64::from(address) => println!(
                        "{label}: {} is the backup of {family} drive {from}{}, restored onto drive {address}",
                        file.display(),
                        backup.model.as_deref().map(|m| format!(" ({m})")).unwrap_or_default()
                    ),
                    _ => {}
                }
                let have = read_all(&drive, &label).await?;
                // Communication settings stay as they are unless asked: another drive's address
                // or baud rate would move this one on the bus.
                let (diffs, kept): (Vec<_>, Vec<_>) =
                    differences(&catalog, &have, &backup).into_iter().partition(|d| *include_comm || !d.comm);
                for d in &diffs {
                    println!(
                        "{}: {} -> {}{}",
                        d.name,
                        d.drive.value,
                        d.file.value,
                        if *dry_run { " (dry run)" } else { "" }
                    );
                    if !dry_run {
                        drive
                            .execute(&drivebus_drive::profile::Operation::WriteParam {
                                name: d.name.clone(),
                                raw: d.file.raw,
                                storage: Storage::Eeprom,
                            })
                            .await
                            .map_err(|e| classify(e, &label))?;
                    }
                }
                if !kept.is_empty() {
                    let names: Vec<&str> = kept.iter().map(|d| d.name.as_str()).collect();
                    println!(
                        "{label}: communication settings kept as they are: {} (--include-comm restores them)",
                        names.join(", ")
                    );
                }
                println!(
                    "{label}: {} {} {}",
                    diffs.len(),
                    plural(diffs.len() as u64, "parameter", "parameters"),
                    if *dry_run { "would be written" } else { "written to EEPROM" }
                );
                Ok(0)
            }
            ParamsCmd::Diff { file } => {
                let backup = load_backup(file)?;
                let have = read_all(&drive, &label).await?;
                let diffs = differences(&catalog, &have, &backup);
                if t.json {
                    println!(
                        "{}",
                        json!(diffs
                            .iter()
                            .map(|d| json!({"name": d.name, "drive": d.drive.raw, "file": d.file.raw}))
                            .collect::<Vec<_>>())
                    );
                } else if diffs.is_empty() {
                    println!("{label}: no differences from {}", file.display());
                } else {
                    for d in &diffs {
                        println!("{}: drive {}, file {}", d.name, d.drive.value, d.file.value);
                    }
                }
                Ok(if diffs.is_empty() { 0 } else { 1 })
            }
        }
    })
}

/// `one` for a count of 1, else `many` ("1 transaction", "2 transactions").
pub(crate) fn plural(n: u64, one: &'static str, many: &'static str) -> &'static str {
    if n == 1 {
        one
    } else {
        many
    }
}

/// `raw`'s bytes must be one valid request of the bus's protocol, as a drive would check it
/// (checksum included): the session would otherwise send its own encoding of them.
fn check_raw_request(protocol: WireProtocol, bytes: &[u8]) -> Result<()> {
    let (_, items) = decode_by_name(protocol, bytes, Some(drivebus_proto::Direction::Master), None);
    let not_one = || {
        fail(EXIT_USAGE, format!("the bytes are not one {protocol} request: check them with drivebus decode --protocol {protocol} --from master"))
    };
    match items.as_slice() {
        [Item::Frame(f)] if f.bytes.len() == bytes.len() => match &f.error {
            None => Ok(()),
            Some(e) => Err(fail(EXIT_USAGE, format!("not a valid {protocol} request: {e}"))),
        },
        _ => Err(not_one()),
    }
}

/// `raw`: sends the bytes as one request and prints the reply, decoded as its answer.
pub fn raw(t: &Target, hex: &[String]) -> Result<u8> {
    let bytes = parse_hex_args(hex).map_err(|e| fail(EXIT_USAGE, e.to_string()))?;
    let r = resolve(t)?;
    let name = r.protocol;
    check_raw_request(name, &bytes)?;
    runtime()?.block_on(async move {
        let bus = open_with(&r.port, r.config).await.map_err(|e| classify(e, &r.label))?;
        let exchange = drivebus_drive::profile::Exchange { request: bytes.clone(), expect_reply: true };
        let reply = bus
            .transact(r.address, exchange, Priority::Command, None)
            .await
            .map_err(|e| classify(Error::Bus(e), &r.label))?;
        match reply {
            Some(reply) => {
                let (p, items) = decode_reply(name, &bytes, &reply, Some(r.family));
                for (i, item) in items.iter().enumerate() {
                    if t.json {
                        if let Some(v) = render_json(p, item) {
                            println!("{v}");
                        }
                    } else {
                        print!("{}", render_text(p, i + 1, item));
                    }
                }
            }
            None => println!("{}: sent; no reply is due", r.label),
        }
        Ok(0)
    })
}
