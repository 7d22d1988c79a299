//! A `port = "virtual"` bus: a line of simulated drives in this process, one per configured
//! drive (`serve --demo`). Behind the `virtual` feature: without it drivebus-sim is not in the
//! gateway's graph and the configuration refuses virtual buses.

use std::sync::{Arc, Mutex};

use drivebus_proto::Instant;
use drivebus_sim::bus::VirtualLine;
use drivebus_sim::config::{BusSpec, DriveSpec};

use crate::config::BusConfig;

/// Builds the virtual line of a `port = "virtual"` bus: one simulated drive per configured drive,
/// at the bus's baud rate and format.
pub fn virtual_line(bus: &BusConfig) -> Result<Arc<Mutex<VirtualLine>>, String> {
    let drives = bus
        .drives
        .iter()
        .map(|d| DriveSpec {
            family: d.family,
            address: d.address,
            protocol: Some(bus.protocol),
            response: std::time::Duration::from_millis(3),
            load: d.load,
            params: Vec::new(),
        })
        .collect();
    let spec = BusSpec::new(drives, Some(bus.baud), Some(bus.format))
        .map_err(|e| format!("bus {}: {e}", bus.name))?;
    let mut line = VirtualLine::new(spec.baud, spec.format, Instant::ZERO);
    for d in &spec.drives {
        let mut drive =
            drivebus_sim::family::build(d, Instant::ZERO).map_err(|e| format!("bus {}: {e}", bus.name))?;
        drive.core_mut().model.set_load(d.load);
        drive.core_mut().response_delay = d.response;
        line.add_device(drive);
    }
    Ok(Arc::new(Mutex::new(line)))
}
