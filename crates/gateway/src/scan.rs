//! Finding drives on a running bus: each address, for each family that speaks the bus's
//! protocol (the built-in families, then the template kinds the gateway knows), is probed with a status read through the bus's owner at the lowest priority
//! ([`drivebus_link::Priority::Scan`]: only when nothing else waits, one attempt, the address's
//! health left alone), so polling goes on as before. One scan per bus at a time; its progress
//! and findings stay for [`Gateway::scan_report`] after it ends.

use std::sync::{Arc, Mutex};

use crate::core::scan::config_lines;
pub use crate::core::scan::{parse_addresses, Found, ScanReport, Scans};
use crate::core::{unix_ms, CommandError, Gateway};
use drivebus_drive::profile::for_drive;
use drivebus_drive::{template, Family};
use drivebus_link::drive::{probe, Drive};

impl Gateway {
    /// Starts a scan of bus `bus` over `addresses` (every address the bus's families use when
    /// `None`); refused while one runs there.
    pub fn start_scan(
        self: &Arc<Self>,
        bus: &str,
        addresses: Option<Vec<u8>>,
    ) -> Result<ScanReport, CommandError> {
        let entry = self
            .buses()
            .iter()
            .find(|b| b.config.name == bus)
            .cloned()
            .ok_or_else(|| CommandError::UnknownBus(bus.to_string()))?;
        let protocol = entry.config.protocol;
        // The built-in families first, then the template kinds the gateway knows (the shipped
        // ones and the configuration's `templates = [...]`): a kind is reached only where no
        // family before it read a status, as `drivebus scan --drive auto` does.
        let families: Vec<Family> = Family::ALL
            .iter()
            .copied()
            .chain(template::registered())
            .filter(|f| f.protocols().contains(&protocol))
            .collect();
        let addresses = addresses.unwrap_or_else(|| {
            let mut all: Vec<u8> = families
                .iter()
                .flat_map(|f| {
                    let (lo, hi) = f.address_range(protocol);
                    lo.max(1)..=hi
                })
                .collect();
            all.sort_unstable();
            all.dedup();
            all
        });
        let scans = self.scans();
        let report = {
            let mut all = scans.by_bus.lock().unwrap_or_else(|p| p.into_inner());
            if let Some(r) = all.get(bus) {
                if r.lock().unwrap_or_else(|p| p.into_inner()).running {
                    return Err(CommandError::Busy(format!(
                        "bus {bus:?} is being scanned already: GET /api/buses/{bus}/scan shows its progress"
                    )));
                }
            }
            let report = Arc::new(Mutex::new(ScanReport {
                bus: bus.to_string(),
                running: true,
                tried: 0,
                total: addresses.len() * families.len(),
                addresses: addresses.clone(),
                families: families.iter().map(|f| f.to_string()).collect(),
                started_ms: unix_ms(),
                ..ScanReport::default()
            }));
            all.insert(bus.to_string(), report.clone());
            report
        };
        let first = report.lock().unwrap_or_else(|p| p.into_inner()).clone();
        let gw = self.clone();
        let (bus, owner) = (bus.to_string(), entry.owner().clone());
        tokio::spawn(async move {
            for &address in &addresses {
                // The first family that reads a status there; else the first that answered.
                let mut best: Option<Found> = None;
                for &family in &families {
                    let probed = match for_drive(family, protocol, address) {
                        Ok(profile) => probe(&Drive::new(owner.clone(), profile).scanning()).await,
                        Err(_) => None,
                    };
                    report.lock().unwrap_or_else(|p| p.into_inner()).tried += 1;
                    let Some(p) = probed else { continue };
                    let configured = gw
                        .drives()
                        .iter()
                        .find(|d| d.bus == bus && d.config.address == address)
                        .map(|d| d.config.name.clone());
                    let f = Found {
                        address,
                        family: family.to_string(),
                        model: family.model().to_string(),
                        state: p.note(),
                        configured,
                    };
                    let tentative = p.tentative(protocol);
                    if best.is_none() || !tentative {
                        best = Some(f);
                    }
                    if !tentative {
                        let skipped =
                            families.len() - 1 - families.iter().position(|&x| x == family).unwrap_or(0);
                        report.lock().unwrap_or_else(|p| p.into_inner()).tried += skipped;
                        break;
                    }
                }
                if let Some(f) = best {
                    let mut r = report.lock().unwrap_or_else(|p| p.into_inner());
                    r.found.push(f);
                    r.config = config_lines(&bus, &r.found);
                }
            }
            let mut r = report.lock().unwrap_or_else(|p| p.into_inner());
            r.running = false;
            r.finished_ms = Some(unix_ms());
        });
        Ok(first)
    }

    /// The last scan of bus `bus` (`None`: never scanned since the gateway started).
    pub fn scan_report(&self, bus: &str) -> Result<Option<ScanReport>, CommandError> {
        if !self.buses().iter().any(|b| b.config.name == bus) {
            return Err(CommandError::UnknownBus(bus.to_string()));
        }
        let scans = self.scans();
        let all = scans.by_bus.lock().unwrap_or_else(|p| p.into_inner());
        Ok(all.get(bus).map(|r| r.lock().unwrap_or_else(|p| p.into_inner()).clone()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn address_lists_are_read_or_refused_in_one_line() {
        assert_eq!(parse_addresses("1-3, 7,2"), Ok(vec![1, 2, 3, 7]));
        for bad in ["", "0-300", "5-1", "x"] {
            let e = parse_addresses(bad).expect_err(bad);
            assert!(!e.contains('\n') && !e.is_empty(), "{e}");
        }
    }

    #[test]
    fn config_lines_comment_out_configured_drives() {
        let found = vec![
            Found {
                address: 3,
                family: "generic".into(),
                model: "m".into(),
                state: "stopped".into(),
                configured: Some("fan-1".into()),
            },
            Found {
                address: 9,
                family: "generic".into(),
                model: "m".into(),
                state: "stopped".into(),
                configured: None,
            },
        ];
        let text = config_lines("line-generic", &found);
        assert!(text.contains("# already configured on line-generic as fan-1:\n# [[bus.drive]]\n"), "{text}");
        assert!(
            text.contains("\n[[bus.drive]]\nname = \"generic-9\"\nfamily = \"generic\"\naddress = 9\n"),
            "{text}"
        );
    }
}
