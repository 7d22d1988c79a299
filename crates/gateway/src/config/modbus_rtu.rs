//! `[[modbus_rtu]]`: the unified map as Modbus RTU slaves (modbus_rtu.rs serves them).

use super::ctx::Ctx;
use super::file::FileModbusRtu;
use super::{ConfigError, ModbusRtuConfig};

/// Checks the `[[modbus_rtu]]` sections: each on a serial device of its own.
pub(super) fn check(cx: &Ctx, raw: &[FileModbusRtu]) -> Result<Vec<ModbusRtuConfig>, ConfigError> {
    let mut out: Vec<ModbusRtuConfig> = Vec::new();
    for m in raw {
        let mut c = ModbusRtuConfig::new(m.port.get_ref());
        if c.port.is_empty() || c.port.starts_with("tcp://") || c.port == "virtual" {
            return cx.err(m.port.span(), "modbus_rtu.port", "give a serial device, e.g. /dev/ttyS1");
        }
        if out.iter().any(|x| x.port == c.port) {
            return cx.err(
                m.port.span(),
                "modbus_rtu.port",
                format!("{} is already another slave's", c.port),
            );
        }
        c.baud = cx.within(&m.baud, 300..=4_000_000, "modbus_rtu.baud", "", c.baud)?;
        if let Some(s) = &m.serial {
            c.format = s.get_ref().parse().or_else(|e| cx.err(s.span(), "modbus_rtu.serial", e))?;
        }
        c.write = m.write;
        out.push(c);
    }
    Ok(out)
}
