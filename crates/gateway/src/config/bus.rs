//! `[[bus]]`: the buses, each with its port, protocol, line settings, fair use and drives
//! ([`super::drive`]). What a bus does not say follows its first drive's family.

use std::time::Duration;

use drivebus_proto::line::CharFormat;
use drivebus_proto::protocol::WireProtocol;

use super::ctx::Ctx;
use super::drive::{self, Drives};
use super::file::FileBus;
use super::name::valid_name;
use super::{BusConfig, ConfigError, Port, PARAM_CACHE_MS};

/// The most requests a modbus-tcp bus may have in flight (`max_in_flight`).
const MAX_IN_FLIGHT: i64 = drivebus_link::bus::MAX_IN_FLIGHT as i64;

/// Checks the `[[bus]]` sections and their drives.
pub(super) fn check(cx: &Ctx, raw: &[FileBus]) -> Result<Vec<BusConfig>, ConfigError> {
    let mut buses: Vec<BusConfig> = Vec::new();
    let mut all = Drives::new();
    for b in raw {
        let name = b.name.get_ref().trim().to_string();
        if !valid_name(&name) {
            return cx.err(b.name.span(), "bus.name", "use letters, digits, - and _ only");
        }
        if buses.iter().any(|x| x.name == name) {
            return cx.err(b.name.span(), "bus.name", format!("two buses are named {name:?}"));
        }
        let mut port = port(cx, b)?;
        let rs485 = match &b.rs485 {
            Some(m) => m.get_ref().parse().or_else(|e: String| cx.err(m.span(), "bus.rs485", e))?,
            None => drivebus_link::Rs485::Off,
        };
        let mut drives = Vec::new();
        for d in &b.drive {
            let checked = all.check(cx, &name, d, &drives)?;
            drives.push(checked);
        }
        let first = drives.first().map(|d| d.family);
        let protocol = match (&b.protocol, first) {
            // Modbus TCP: the drives' Modbus frames in MBAP to a Modbus TCP server.
            (Some(p), _) if p.get_ref().trim().eq_ignore_ascii_case(drivebus_link::mbap::MODBUS_TCP) => {
                port = match port {
                    Port::Tcp(addr) => Port::ModbusTcp(drivebus_link::mbap::with_default_port(&addr)),
                    _ => return cx.err(
                        b.port.span(),
                        "bus.port",
                        "a modbus-tcp bus is reached over TCP: give tcp://HOST[:PORT] (port 502 by default)",
                    ),
                };
                WireProtocol::ModbusRtu
            }
            (Some(p), _) => p.get_ref().parse::<WireProtocol>().or_else(|e| {
                cx.err(p.span(), "bus.protocol", format!("{e} or {}", drivebus_link::mbap::MODBUS_TCP))
            })?,
            (None, Some(f)) => f.default_protocol(),
            (None, None) => {
                return cx.err(b.name.span(), "bus.protocol", "give the bus's protocol or a drive")
            }
        };
        let protocol_at = b.protocol.as_ref().map_or(b.name.span(), |p| p.span());
        if let Some(m) = &b.max_in_flight {
            if !matches!(port, Port::ModbusTcp(_)) {
                return cx.err(m.span(), "bus.max_in_flight", drivebus_link::bus::IN_FLIGHT_NEEDS_MODBUS_TCP);
            }
        }
        let max_in_flight =
            cx.within(&b.max_in_flight, 1..=MAX_IN_FLIGHT, "bus.max_in_flight", "", 1)? as usize;
        for (d, raw_drive) in drives.iter().zip(&b.drive) {
            if matches!(port, Port::ModbusTcp(_)) && d.family.check_protocol(protocol).is_err() {
                return cx.err(
                    protocol_at,
                    "bus.protocol",
                    format!(
                        "drive {:?}: a {} drive does not speak Modbus, so not modbus-tcp",
                        d.name, d.family
                    ),
                );
            }
            drive::check_protocol(cx, d, raw_drive, protocol, protocol_at.clone())?;
        }
        let (baud, format) = first.map_or((9600, CharFormat::NONE_8N1), |f| f.serial_default(protocol));
        let baud = cx.within(&b.baud, 300..=1_000_000, "bus.baud", "", baud)?;
        let format = match &b.serial {
            Some(s) => s.get_ref().parse::<CharFormat>().or_else(|e| cx.err(s.span(), "bus.serial", e))?,
            None => format,
        };
        let mut on_demand = drivebus_link::FairConfig::default();
        if let Some(v) = &b.on_demand_share {
            let share = *v.get_ref();
            if !(0.0..=1.0).contains(&share) {
                return cx.err(
                    v.span(),
                    "bus.on_demand_share",
                    format!("{share} is not a share of the bus time: use 0.0..1.0 (0.5: half)"),
                );
            }
            on_demand.share = share;
        }
        on_demand.queue = cx.at_least_one(&b.on_demand_queue, "bus.on_demand_queue", on_demand.queue)?;
        on_demand.per_client =
            cx.at_least_one(&b.on_demand_per_client, "bus.on_demand_per_client", on_demand.per_client)?;
        buses.push(BusConfig {
            on_demand,
            param_cache: Duration::from_millis(b.param_cache_ms.unwrap_or(PARAM_CACHE_MS)),
            name,
            port,
            protocol,
            baud,
            format,
            timeout: b.timeout_ms.map(Duration::from_millis),
            retries: b.retries.unwrap_or(2),
            echo: b.echo,
            strict_t15: b.strict_t15,
            rs485,
            role: None,
            max_in_flight,
            drives,
        });
    }
    Ok(buses)
}

/// A bus's `port`: a device path, `tcp://HOST:PORT` or `virtual` (with the `virtual` feature);
/// a `modbus-tcp` bus turns its `tcp://` port into [`Port::ModbusTcp`].
fn port(cx: &Ctx, b: &FileBus) -> Result<Port, ConfigError> {
    Ok(match b.port.get_ref().as_str() {
        "virtual" if cfg!(not(feature = "virtual")) => {
            return cx.err(
                b.port.span(),
                "bus.port",
                "this build has no virtual buses (built without the `virtual` feature): give a serial device or tcp://HOST:PORT",
            )
        }
        "virtual" => Port::Virtual,
        p if p.starts_with("tcp://") => Port::Tcp(p["tcp://".len()..].to_string()),
        "" => return cx.err(b.port.span(), "bus.port", "give a device path, tcp://HOST:PORT or virtual"),
        p => Port::Serial(p.to_string()),
    })
}
