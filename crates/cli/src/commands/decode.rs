//! `drivebus decode`: frames out of captured bytes, with an exact diagnosis of bad bytes.

use drivebus_gateway::text::count;
use std::io::Write as _;

use anyhow::Result;
use clap::{Args, ValueEnum};
use drivebus_proto::protocol::WireProtocol;

use drivebus_drive::Family;
use drivebus_proto::Direction;

use drivebus_analyze::report::{decode_by_name, render_json, render_text, FrameReport, Item};

use crate::hexarg::parse_hex_args;

/// Who sent the bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum From {
    /// The master (host, PLC, drivebus).
    Master,
    /// A drive.
    Drive,
}

/// Arguments of `drivebus decode` (with `--protocol`, `--drive` and `--json` from `crate::options`).
#[derive(Args, Debug)]
pub struct DecodeArgs {
    /// Who sent the bytes, where the protocol cannot tell (a Modbus request and its reply).
    #[arg(long, value_enum)]
    pub from: Option<From>,
    /// The bytes on the wire in hex, spaced or not, in one or several arguments
    /// (ASCII protocols too: 3A 30 31 ...).
    #[arg(required = true, num_args = 1.., value_name = "HEX")]
    pub hex: Vec<String>,
}

/// Runs `drivebus decode`; returns the exit status (0 a valid frame was found, 1 none).
pub fn run(args: &DecodeArgs, target: &crate::commands::target::Target) -> Result<u8> {
    let name = target.protocol.as_deref().ok_or_else(|| {
        anyhow::anyhow!(
            "say which wire format: --protocol {}",
            WireProtocol::NAMES.replace(", ", "|").replace(" or ", "|")
        )
    })?;
    let protocol: WireProtocol = name.parse().map_err(|e| anyhow::anyhow!("--protocol {name:?}: {e}"))?;
    let json = target.json;
    let bytes = parse_hex_args(&args.hex)?;
    let from = args.from.map(|f| match f {
        From::Master => Direction::Master,
        From::Drive => Direction::Drive,
    });
    let family = match target.drive.as_slice() {
        [] => None,
        [one] => Some(one.parse::<Family>().map_err(|_| {
            crate::commands::target::usage(format!(
                "unknown drive family {one:?}: use generic or toshiba to name Modbus registers"
            ))
        })?),
        _ => return Err(crate::commands::target::usage("give one --drive FAMILY to name the registers by")),
    };
    let (protocol, items) = decode_by_name(protocol, &bytes, from, family);
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    let mut valid = 0;
    let mut index = 0;
    for item in &items {
        if let Item::Frame(f) = item {
            index += 1;
            if f.error.is_none() {
                valid += 1;
            }
        }
        if json {
            if let Some(v) = render_json(protocol, item) {
                writeln!(out, "{v}")?;
            }
        } else {
            write!(out, "{}", render_text(protocol, index, item))?;
        }
        match item {
            Item::Frame(FrameReport { error: Some(e), offset, .. }) => {
                eprintln!("drivebus: {protocol} frame {index} at byte {offset}: {e}");
            }
            Item::Noise { offset, bytes } => {
                eprintln!(
                    "drivebus: skipped {} at byte {offset} that are not part of any {protocol} frame",
                    count(bytes.len(), "byte", "bytes")
                );
            }
            _ => {}
        }
    }
    if index == 0 {
        eprintln!("drivebus: no {protocol} frame found in {} bytes: check --protocol", bytes.len());
    }
    Ok(if valid > 0 { 0 } else { 1 })
}
