//! `drivebus scan`: find the drives on a line across addresses, baud rates, character formats
//! and protocols.

use std::time::Duration;

use anyhow::Result;
use clap::Args;
use drivebus_drive::profile::for_drive;
use drivebus_drive::{template, Family};
use drivebus_link::drive::{open_with, probe, Drive};
use drivebus_link::owner::BusConfig;
use drivebus_proto::line::CharFormat;
use drivebus_proto::protocol::WireProtocol;
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;

use crate::commands::target::Target;

/// Arguments of `drivebus scan` (with `crate::options`' --port, --drive FAMILY|auto, --protocol,
/// --baud, --serial, --timeout, --json).
#[derive(Args, Debug)]
pub struct ScanArgs {
    /// Addresses to try, e.g. 1-32 or 1,2,5 (default: every address of the family).
    #[arg(long, value_name = "RANGE")]
    pub addresses: Option<String>,
    /// Baud rates to try, e.g. 9600,19200 (default: --baud, or the family's).
    #[arg(long, value_name = "LIST")]
    pub bauds: Option<String>,
    /// Character formats to try, e.g. 8N1,8E1,8O1,8N2 (default: --serial, or the family's).
    #[arg(long, value_name = "LIST")]
    pub formats: Option<String>,
    /// Stop at the first drive that answers.
    #[arg(long)]
    pub first: bool,
}

struct Found {
    family: Family,
    protocol: WireProtocol,
    address: u8,
    baud: u32,
    format: CharFormat,
    note: String,
    /// A refusal on a protocol several families speak (Modbus): the drive may be another
    /// family's, refusing this family's map. Listed only when no family read its status.
    tentative: bool,
}

impl Found {
    /// The protocol and address: one drive whatever family is tried there (a pty or a serial
    /// server answers at any baud rate and format).
    fn spot(&self) -> (WireProtocol, u8) {
        (self.protocol, self.address)
    }
}

fn parse_list(s: &str, what: &str) -> Result<Vec<u32>> {
    let mut out = Vec::new();
    for part in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let bad = || {
            crate::commands::target::usage(format!("{what} {part:?} is not a number or a range like 1-32"))
        };
        match part.split_once('-') {
            Some((a, b)) => {
                let (a, b): (u32, u32) =
                    (a.trim().parse().map_err(|_| bad())?, b.trim().parse().map_err(|_| bad())?);
                if a > b {
                    return Err(bad());
                }
                out.extend(a..=b);
            }
            None => out.push(part.parse().map_err(|_| bad())?),
        }
    }
    Ok(out)
}

/// Runs `drivebus scan`; exit 0 when a drive answered, 2 when none did.
pub fn run(args: &ScanArgs, t: &Target) -> Result<u8> {
    let port = t.one_port()?.ok_or_else(|| {
        crate::commands::target::usage("say which line: --port /dev/ttyUSB0 or --port tcp://HOST:PORT")
    })?;
    let families: Vec<Family> = match t.drive.as_slice() {
        [] => {
            return Err(crate::commands::target::usage(
                "say which drive family, or --drive auto to try them all",
            ))
        }
        // The built-in families first, then every template kind known to the command (the
        // shipped ones and --template FILEs).
        [one] if one == "auto" => Family::ALL.iter().copied().chain(template::registered()).collect(),
        names => names
            .iter()
            .map(|n| {
                n.parse().map_err(|_| {
                    crate::commands::target::usage(format!(
                        "unknown drive family {n:?}: use generic, toshiba, danfoss, b800 or auto"
                    ))
                })
            })
            .collect::<Result<_>>()?,
    };
    // The lists given, read once (a typo is reported before anything is sent).
    let bauds = args.bauds.as_deref().map(|l| parse_list(l, "baud")).transpose()?;
    let addresses = args.addresses.as_deref().map(|l| parse_list(l, "address")).transpose()?;
    let formats: Option<Vec<CharFormat>> = match (&args.formats, t.serial()) {
        (Some(list), _) => Some(
            list.split(',')
                .map(str::trim)
                .filter(|f| !f.is_empty())
                .map(|f| {
                    f.parse::<CharFormat>()
                        .map_err(|e| crate::commands::target::usage(format!("--formats: {f:?}: {e}")))
                })
                .collect::<Result<_>>()?,
        ),
        (None, Some(s)) => Some(vec![s
            .parse::<CharFormat>()
            .map_err(|e| crate::commands::target::usage(format!("--serial {s:?}: {e}")))?]),
        (None, None) => None,
    };
    // Every (family, protocol, baud, format, address) to try.
    let mut combos = Vec::new();
    for &family in &families {
        let protocols: Vec<WireProtocol> = match &t.protocol {
            Some(p) => vec![p
                .parse()
                .map_err(|e| crate::commands::target::usage(format!("--protocol {p:?}: {e}")))?],
            None => family.protocols().to_vec(),
        };
        for protocol in protocols {
            if for_drive(family, protocol, 1).is_err() {
                continue;
            }
            let (db, df) = family.serial_default(protocol);
            let bauds = match (&bauds, t.baud()) {
                (Some(list), _) => list.clone(),
                (None, Some(b)) => vec![b],
                (None, None) => vec![db],
            };
            let formats = match &formats {
                Some(list) => list.clone(),
                None => vec![df],
            };
            let (lo, hi) = family.address_range(protocol);
            let addresses: Vec<u8> = match &addresses {
                Some(list) => list
                    .iter()
                    .copied()
                    .filter(|&a| a >= lo as u32 && a <= hi as u32)
                    .map(|a| a as u8)
                    .collect(),
                None => (lo..=hi).collect(),
            };
            for &format in &formats {
                for &baud in &bauds {
                    for &address in &addresses {
                        combos.push((family, protocol, baud, format, address));
                    }
                }
            }
        }
    }
    if combos.is_empty() {
        return Err(crate::commands::target::usage(
            "nothing to scan: check --drive, --protocol, --addresses, --bauds and --formats",
        ));
    }
    let timeout = Duration::from_millis(t.timeout.unwrap_or(60));
    let bar = if t.json { ProgressBar::hidden() } else { ProgressBar::new(combos.len() as u64) };
    bar.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    let mut found: Vec<Found> = rt.block_on(async {
        let mut found = Vec::new();
        let mut current: Option<((WireProtocol, u32, CharFormat), drivebus_link::Bus)> = None;
        for (family, protocol, baud, format, address) in combos {
            bar.set_message(format!("{family} {protocol} {baud} address {address}"));
            bar.inc(1);
            let key = (protocol, baud, format);
            if current.as_ref().map(|(k, _)| k) != Some(&key) {
                // The port is ours alone: close it before opening it with the next settings.
                if let Some((_, old)) = current.take() {
                    old.close().await;
                }
                let mut config = BusConfig::new(protocol, baud, format);
                config.retries = 0;
                config.response_timeout = Some(timeout);
                config.offline_after = u32::MAX;
                let bus = open_with(&port, config)
                    .await
                    .map_err(|e| crate::commands::target::link_failure(e.to_string()))?;
                current = Some((key, bus));
            }
            let Some((_, bus)) = &current else { continue };
            // A template kind is tried only where no built-in family read a status: a template
            // that repeats a built-in map (generic-2000h) would find the same drive again.
            if matches!(family, Family::Template(_))
                && found.iter().any(|f: &Found| {
                    !f.tentative
                        && f.spot() == (protocol, address)
                        && !matches!(f.family, Family::Template(_))
                })
            {
                continue;
            }
            let Ok(profile) = for_drive(family, protocol, address) else { continue };
            let drive = Drive::new(bus.clone(), profile);
            let Some(probe) = probe(&drive).await else { continue };
            drop(drive);
            let (note, tentative) = (probe.note(), probe.tentative(protocol));
            let f = Found { family, protocol, address, baud, format, note, tentative };
            if f.tentative {
                // Told at the end, if no family reads a status there.
                found.push(f);
                continue;
            }
            bar.println(format!(
                "found {family} drive {address} ({}, {baud} {format}): {}",
                f.protocol, f.note
            ));
            found.push(f);
            if args.first {
                break;
            }
        }
        if let Some((_, bus)) = current.take() {
            bus.close().await;
        }
        Ok::<_, anyhow::Error>(found)
    })?;
    bar.finish_and_clear();
    // A refusal in one family's map where another family's status was read is that other
    // family's drive, not a find.
    let read: Vec<_> = found.iter().filter(|f| !f.tentative).map(Found::spot).collect();
    found.retain(|f| !f.tentative || !read.contains(&f.spot()));
    if args.first && found.iter().any(|f| !f.tentative) {
        found.retain(|f| !f.tentative);
    }
    if t.json {
        let list: Vec<_> = found
            .iter()
            .map(|f| json!({"family": f.family.to_string(), "protocol": f.protocol.name(), "address": f.address, "baud": f.baud, "serial": f.format.to_string(), "state": f.note}))
            .collect();
        println!("{}", json!(list));
    } else if found.is_empty() {
        eprintln!(
            "drivebus: no drive answered on {port}: check the wiring, the termination and --drive/--bauds"
        );
    } else {
        println!("{:<8} {:<15} {:>7} {:>7} {:<6} state", "family", "protocol", "address", "baud", "serial");
        for f in &found {
            println!(
                "{:<8} {:<15} {:>7} {:>7} {:<6} {}",
                f.family.to_string(),
                f.protocol,
                f.address,
                f.baud,
                f.format.to_string(),
                f.note
            );
        }
    }
    Ok(if found.is_empty() { crate::commands::target::EXIT_LINK } else { 0 })
}
