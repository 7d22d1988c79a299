//! `[[bus.drive]]`: the drives of a bus. Names and Modbus TCP unit ids are unique across
//! buses; addresses on their bus, within what the family allows on the bus's protocol.

use std::collections::HashSet;
use std::ops::Range;
use std::time::Duration;

use drivebus_drive::Family;
use drivebus_proto::protocol::WireProtocol;

use super::ctx::Ctx;
use super::file::FileDrive;
use super::name::valid_name;
use super::{ConfigError, DriveConfig, PollPriority};

/// Highest Modbus TCP unit id.
const LAST_UNIT: u8 = 247;

/// The drives checked so far, on every bus: their names and unit ids.
pub(super) struct Drives {
    names: HashSet<String>,
    units: HashSet<u8>,
    /// The lowest unit id that may still be free, for a drive given none.
    next_unit: u8,
}

impl Drives {
    /// None yet.
    pub(super) fn new() -> Drives {
        Drives { names: HashSet::new(), units: HashSet::new(), next_unit: 1 }
    }

    /// Checks drive `d` of bus `bus`, whose drives before it are `on_bus`. A drive without
    /// `unit_id` gets the lowest one free; past the 247th, none (0: HTTP and MQTT only).
    pub(super) fn check(
        &mut self,
        cx: &Ctx,
        bus: &str,
        d: &FileDrive,
        on_bus: &[DriveConfig],
    ) -> Result<DriveConfig, ConfigError> {
        let family: Family = d
            .family
            .get_ref()
            .parse()
            .or_else(|e: drivebus_drive::UnknownFamily| cx.err(d.family.span(), "bus.drive.family", e))?;
        let name = d.name.get_ref().trim().to_string();
        if !valid_name(&name) {
            return cx.err(d.name.span(), "bus.drive.name", "use letters, digits, - and _ only");
        }
        if !self.names.insert(name.clone()) {
            return cx.err(d.name.span(), "bus.drive.name", format!("two drives are named {name:?}"));
        }
        let unit_id = match &d.unit_id {
            Some(u) if *u.get_ref() == 0 || *u.get_ref() > LAST_UNIT => {
                return cx.err(u.span(), "bus.drive.unit_id", "use 1..247");
            }
            Some(u) => *u.get_ref(),
            None => {
                while self.next_unit <= LAST_UNIT && self.units.contains(&self.next_unit) {
                    self.next_unit += 1;
                }
                if self.next_unit <= LAST_UNIT {
                    self.next_unit
                } else {
                    0
                }
            }
        };
        if unit_id != 0 && !self.units.insert(unit_id) {
            let span = d.unit_id.as_ref().map_or(d.name.span(), |u| u.span());
            return cx.err(span, "bus.drive.unit_id", format!("unit id {unit_id} is used twice"));
        }
        let poll_ms = cx.within(&d.poll_ms, 10..=3_600_000, "bus.drive.poll_ms", "", 500)?;
        let priority = match d.priority.as_ref().map(|p| (p.get_ref().as_str(), p.span())) {
            None | Some(("normal", _)) => PollPriority::Normal,
            Some(("high", _)) => PollPriority::High,
            Some(("low", _)) => PollPriority::Low,
            Some((other, span)) => {
                return cx.err(span, "bus.drive.priority", format!("{other:?}: use high, normal or low"))
            }
        };
        if on_bus.iter().any(|x| x.address == *d.address.get_ref()) {
            return cx.err(
                d.address.span(),
                "bus.drive.address",
                format!("two drives on bus {bus:?} have address {}", d.address.get_ref()),
            );
        }
        Ok(DriveConfig {
            name,
            family,
            address: *d.address.get_ref(),
            unit_id,
            poll: Duration::from_millis(poll_ms),
            priority,
            locked: d.locked,
            load: d.load.unwrap_or(0.4),
        })
    }
}

/// Checks that drive `d` (written as `raw`) speaks its bus's `protocol` (written at
/// `protocol_at`) and has an address of its own on it: never the broadcast address, which every
/// drive obeys and none answers (a lock on one drive would not hold).
pub(super) fn check_protocol(
    cx: &Ctx,
    d: &DriveConfig,
    raw: &FileDrive,
    protocol: WireProtocol,
    protocol_at: Range<usize>,
) -> Result<(), ConfigError> {
    if let Err(e) = d.family.check_protocol(protocol) {
        return cx.err(protocol_at, "bus.protocol", format!("drive {:?}: {e}", d.name));
    }
    if let Err(e) = d.family.check_address(protocol, d.address) {
        let broadcast =
            if d.address == 0 { " (0 is the broadcast address: every drive obeys it)" } else { "" };
        return cx.err(
            raw.address.span(),
            "bus.drive.address",
            format!("drive {:?}: {e}{broadcast}", d.name),
        );
    }
    if let Err(e) = drivebus_drive::profile::for_drive(d.family, protocol, d.address) {
        return cx.err(protocol_at, "bus.protocol", format!("drive {:?}: {e}", d.name));
    }
    Ok(())
}
