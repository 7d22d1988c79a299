//! `[modbus]`: the Modbus TCP listener.

use std::net::{IpAddr, Ipv6Addr};

use super::ctx::Ctx;
use super::file::FileModbus;
use super::{ConfigError, ModbusConfig};

/// Checks `[modbus]`: without `allow`, writes from loopback only.
pub(super) fn check(cx: &Ctx, raw: &FileModbus) -> Result<ModbusConfig, ConfigError> {
    let allow = match &raw.allow {
        None => vec![IpAddr::from([127, 0, 0, 1]), IpAddr::from(Ipv6Addr::LOCALHOST)],
        Some(list) => {
            let mut allow = Vec::new();
            for a in list {
                allow.push(a.get_ref().parse::<IpAddr>().or_else(|_| {
                    cx.err(a.span(), "modbus.allow", format!("{:?} is not an IP address", a.get_ref()))
                })?);
            }
            allow
        }
    };
    Ok(ModbusConfig {
        listen: cx.listener(&raw.listen, "modbus.listen", "127.0.0.1:5020")?,
        allow,
        read_only: raw.read_only,
        max_connections: cx.at_least_one(&raw.max_connections, "modbus.max_connections", 16_384)?,
    })
}
