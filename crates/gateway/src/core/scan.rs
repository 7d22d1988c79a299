//! A bus scan's state (the progress and findings of [`Gateway::start_scan`](crate::core::Gateway::start_scan), kept per bus on
//! the gateway) and the address lists and configuration lines it reads and writes. The scan
//! itself (the probes through the bus owner) is `crate::scan`.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use serde::Serialize;

/// A drive a scan found.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Found {
    /// Its bus address.
    pub address: u8,
    /// The family whose status read it answered.
    pub family: String,
    /// The family's model.
    pub model: String,
    /// How it answered (`stopped`, `running at 40.00 Hz`, `answers (refused status: ...)`).
    pub state: String,
    /// The configured drive at that address, if there is one.
    pub configured: Option<String>,
}

/// A scan's progress and findings (`GET /api/buses/{bus}/scan`).
#[derive(Clone, Debug, Serialize, Default)]
pub struct ScanReport {
    /// The bus.
    pub bus: String,
    /// Whether it is still going.
    pub running: bool,
    /// Probes made.
    pub tried: usize,
    /// Probes in all.
    pub total: usize,
    /// The addresses it tries.
    pub addresses: Vec<u8>,
    /// The families it tries (those speaking the bus's protocol).
    pub families: Vec<String>,
    /// When it started, unix ms.
    pub started_ms: i64,
    /// When it ended, unix ms.
    pub finished_ms: Option<i64>,
    /// The drives found, by address.
    pub found: Vec<Found>,
    /// The `[[bus.drive]]` lines for the configuration (those already configured commented out).
    pub config: String,
}

/// The scans of one gateway, by bus (a field of the gateway: `Gateway::scans`).
#[derive(Default)]
pub struct Scans {
    pub(crate) by_bus: Mutex<HashMap<String, Arc<Mutex<ScanReport>>>>,
}

/// Parses an address list like `1-32` or `1,2,5`: addresses 0 to 255.
pub fn parse_addresses(s: &str) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    for part in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let bad = || format!("{:?} is not an address or a range like 1-32", crate::text::shown(part));
        let one = |t: &str| t.trim().parse::<u8>().map_err(|_| bad());
        match part.split_once('-') {
            Some((a, b)) => {
                let (a, b) = (one(a)?, one(b)?);
                if a > b {
                    return Err(bad());
                }
                out.extend(a..=b);
            }
            None => out.push(one(part)?),
        }
    }
    out.sort_unstable();
    out.dedup();
    if out.is_empty() {
        return Err("no address given: give a list like 1-32 or 1,2,5".into());
    }
    Ok(out)
}

/// The `[[bus.drive]]` lines for what was found (those configured already commented out).
pub(crate) fn config_lines(bus: &str, found: &[Found]) -> String {
    let mut out = String::new();
    for f in found {
        let block = format!(
            "[[bus.drive]]\nname = \"{}-{}\"\nfamily = \"{}\"\naddress = {}\n",
            f.family, f.address, f.family, f.address
        );
        match &f.configured {
            Some(name) => {
                out.push_str(&format!("# already configured on {bus} as {name}:\n"));
                for l in block.lines() {
                    out.push_str(&format!("# {l}\n"));
                }
            }
            None => out.push_str(&block),
        }
        out.push('\n');
    }
    out
}
