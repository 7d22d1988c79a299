//! `[[bridge]]` and `--bridge`: transparent Modbus bridges to buses (bridge.rs serves
//! them).

use std::net::SocketAddr;

use super::ctx::Ctx;
use super::file::FileBridge;
use super::{BridgeConfig, BusConfig, ConfigError, Framing};

/// Why bus `name` of `buses` cannot be bridged (it is none of them, or it speaks no Modbus).
fn unbridgeable(name: &str, buses: &[BusConfig]) -> Option<String> {
    match buses.iter().find(|x| x.name == name) {
        None => Some(format!(
            "no bus {name:?} (buses: {})",
            buses.iter().map(|x| x.name.as_str()).collect::<Vec<_>>().join(", ")
        )),
        Some(bus) if !bus.protocol.is_modbus() => Some(format!(
            "bus {name:?} speaks {}: a Modbus bridge needs a modbus-rtu or modbus-ascii bus",
            bus.protocol
        )),
        Some(_) => None,
    }
}

/// Checks the `[[bridge]]` sections: each names a Modbus bus of `buses`, a free address and the
/// function codes it passes.
pub(super) fn check(
    cx: &Ctx,
    raw: &[FileBridge],
    buses: &[BusConfig],
) -> Result<Vec<BridgeConfig>, ConfigError> {
    let mut out: Vec<BridgeConfig> = Vec::new();
    for b in raw {
        let name = b.bus.get_ref();
        if let Some(why) = unbridgeable(name, buses) {
            return cx.err(b.bus.span(), "bridge.bus", why);
        }
        let listen: SocketAddr = cx.addr(&b.listen, "bridge.listen", "127.0.0.1:5021")?;
        if listen.port() != 0 && out.iter().any(|x| x.listen == listen) {
            return cx.err(b.listen.span(), "bridge.listen", format!("{listen} is already another bridge's"));
        }
        let framing = match b.framing.as_ref().map(|f| (f.get_ref().as_str(), f.span())) {
            None | Some(("mbap", _)) => Framing::Mbap,
            Some(("rtu", _)) => Framing::Rtu,
            Some((other, span)) => {
                return cx.err(span, "bridge.framing", format!("{other:?}: use mbap or rtu"))
            }
        };
        let mut c = BridgeConfig::new(name, listen);
        c.framing = framing;
        if let Some(list) = &b.functions {
            c.functions = Vec::with_capacity(list.len());
            for f in list {
                let code = function(*f.get_ref()).or_else(|why| cx.err(f.span(), "bridge.functions", why))?;
                if c.functions.contains(&code) {
                    return cx.err(f.span(), "bridge.functions", format!("{code} is listed twice"));
                }
                c.functions.push(code);
            }
        }
        out.push(c);
    }
    Ok(out)
}

/// A function code of `functions = [...]`: a public Modbus function (01-08, 0B, 0C, 0F-11,
/// 14-18, 2B) or a user-defined one (41-48, 64-6E), in decimal or hex (`0x2B`, TOML's own).
fn function(code: i64) -> Result<u8, String> {
    const PUBLIC: &str =
        "public 1-8, 11, 12, 15-17, 20-24, 43 (device identification); user-defined 65-72, 100-110";
    let known = |c: u8| matches!(c, 1..=8 | 11 | 12 | 15..=17 | 20..=24 | 43 | 65..=72 | 100..=110);
    match u8::try_from(code) {
        Ok(c) if known(c) => Ok(c),
        Ok(c @ 1..=127) => Err(format!("{c} is no Modbus function code a drive answers (use {PUBLIC})")),
        _ => Err(format!("{code} is not a Modbus function code: codes are 1-127 ({PUBLIC})")),
    }
}

/// `--bridge BUS=HOST:PORT`: a bridge with MBAP framing and the default functions.
pub fn parse_arg(arg: &str) -> Result<BridgeConfig, String> {
    let (bus, addr) = arg
        .split_once('=')
        .ok_or_else(|| format!("--bridge {arg:?}: write BUS=HOST:PORT, e.g. line-1=127.0.0.1:5021"))?;
    let listen = addr
        .parse()
        .map_err(|_| format!("--bridge {arg:?}: {addr:?} is not HOST:PORT, e.g. 127.0.0.1:5021"))?;
    Ok(BridgeConfig::new(bus, listen))
}

/// Checks a bridge given on the command line against the buses, in the words of the file's check.
pub fn check_arg(b: &BridgeConfig, buses: &[BusConfig]) -> Result<(), String> {
    match unbridgeable(&b.bus, buses) {
        Some(why) => Err(format!("--bridge: {why}")),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn command_line_bridges_are_read_and_checked() {
        let b = parse_arg("line-1=127.0.0.1:5021").unwrap();
        assert_eq!((b.bus.as_str(), b.listen.port(), b.framing), ("line-1", 5021, Framing::Mbap));
        assert!(parse_arg("line-1").unwrap_err().contains("BUS=HOST:PORT"));
        assert!(parse_arg("line-1=nowhere").unwrap_err().contains("HOST:PORT"));
    }

    #[test]
    fn functions_are_the_defaults_or_known_codes() {
        let base = "[[bus]]\nname = \"l\"\nport = \"/dev/ttyUSB0\"\nprotocol = \"modbus-rtu\"\n\
                    [[bridge]]\nbus = \"l\"\nlisten = \"127.0.0.1:5021\"\n";
        let read = |extra: &str| super::super::GatewayConfig::from_toml("p.toml", &format!("{base}{extra}"));
        let b = read("").unwrap().bridges.remove(0);
        assert_eq!(b.functions, super::super::BRIDGE_FUNCTIONS);
        assert!(b.passes(&[0x03, 0, 0, 0, 1]) && b.passes(&[0x2B, 0x0E, 1, 0]));
        assert!(!b.passes(&[0x08, 0, 4, 0, 0]) && !b.passes(&[0x2B, 0x0D]) && !b.passes(&[0x41]));
        assert!(!b.passes(&[]));
        assert_eq!(parse_arg("l=127.0.0.1:5021").unwrap().functions, super::super::BRIDGE_FUNCTIONS);
        let b = read("functions = [3, 0x41]\n").unwrap().bridges.remove(0);
        assert_eq!(b.functions, [3, 0x41]);
        assert!(b.passes(&[0x41, 1]) && !b.passes(&[0x06, 0, 1, 0, 1]));
        let e = |extra: &str| read(extra).unwrap_err().to_string();
        assert_eq!(
            e("functions = [3, 99]\n"),
            "p.toml:8: field `bridge.functions`: 99 is no Modbus function code a drive answers (use \
             public 1-8, 11, 12, 15-17, 20-24, 43 (device identification); user-defined 65-72, 100-110)"
        );
        assert!(e("functions = [0]\n").contains("0 is not a Modbus function code: codes are 1-127"));
        assert!(e("functions = [131]\n").contains("131 is not a Modbus function code"));
        assert!(e("functions = [-3]\n").contains("-3 is not a Modbus function code"));
        assert!(e("functions = [3, 3]\n").contains("3 is listed twice"));
        assert!(
            e("functions = [\"read\"]\n").contains("bridge.functions"),
            "{}",
            e("functions = [\"read\"]\n")
        );
    }

    #[test]
    fn the_file_and_the_command_line_refuse_a_bus_in_the_same_words() {
        let bus = "[[bus]]\nname = \"tosh\"\nport = \"/dev/ttyUSB0\"\nprotocol = \"toshiba-binary\"\n";
        let buses = super::super::GatewayConfig::from_toml("p.toml", bus).unwrap().buses;
        let speaks =
            "bus \"tosh\" speaks toshiba-binary: a Modbus bridge needs a modbus-rtu or modbus-ascii bus";
        let refused = |arg: &str| check_arg(&parse_arg(arg).unwrap(), &buses).unwrap_err();
        assert_eq!(refused("line-9=127.0.0.1:5021"), "--bridge: no bus \"line-9\" (buses: tosh)");
        assert_eq!(refused("tosh=127.0.0.1:5021"), format!("--bridge: {speaks}"));
        let file = format!("{bus}[[bridge]]\nbus = \"tosh\"\nlisten = \"127.0.0.1:5021\"\n");
        let e = super::super::GatewayConfig::from_toml("p.toml", &file).unwrap_err();
        assert_eq!(e.to_string(), format!("p.toml:6: field `bridge.bus`: {speaks}"));
    }
}
