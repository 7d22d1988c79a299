//! The four drive families and how each one spells its parameter names.

use std::fmt;
use std::str::FromStr;

use drivebus_proto::line::CharFormat;
use drivebus_proto::protocol::WireProtocol;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use crate::template::KindId;

/// A drive kind: a built-in family (one wire protocol, one parameter catalog, one seed manual)
/// or a drive a template file describes ([`Family::Template`], [`crate::template`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Family {
    /// Generic Chinese VFD with Modbus RTU/ASCII and the 2000H/2100H map (`seeds/004_e8ea1998fe1a671e.txt`).
    Generic,
    /// Toshiba VF-AS1: Toshiba Inverter Protocol and Modbus-RTU (`seeds/002_43d8a4399c8be05f.txt`).
    Toshiba,
    /// Danfoss VLT FC series: FC protocol (`seeds/003_26a4c04ca1af5f26.txt`).
    Danfoss,
    /// B800 series: hex-ASCII protocol without parameter access (`seeds/000_04b515f0e0c1734e.txt`).
    B800,
    /// A Modbus drive a template describes (its kind's name, its map and its catalog).
    Template(KindId),
}

impl Serialize for Family {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.as_str())
    }
}

impl<'de> Deserialize<'de> for Family {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let name = String::deserialize(d)?;
        name.parse().map_err(serde::de::Error::custom)
    }
}

impl Family {
    /// Every family, in the order the docs list them.
    pub const ALL: [Family; 4] = [Family::Generic, Family::Toshiba, Family::Danfoss, Family::B800];

    /// The lower-case name used on the command line and in catalog files ("generic", "toshiba", ...).
    pub fn as_str(self) -> &'static str {
        match self {
            Family::Generic => "generic",
            Family::Toshiba => "toshiba",
            Family::Danfoss => "danfoss",
            Family::B800 => "b800",
            Family::Template(id) => crate::template::kinds::kind(id).name,
        }
    }

    /// The drive model the family's catalog follows, as a backup file records it.
    pub fn model(self) -> &'static str {
        match self {
            Family::Generic => "generic VFD (2000H/2100H Modbus map)",
            Family::Toshiba => "Toshiba VF-AS1",
            Family::Danfoss => "Danfoss VLT FC series",
            Family::B800 => "B800 series",
            Family::Template(id) => crate::template::kinds::kind(id).model,
        }
    }

    /// The seed manual this family's protocol and catalog come from, as `seeds/<file>`.
    pub fn manual(self) -> &'static str {
        match self {
            Family::Generic => "seeds/004_e8ea1998fe1a671e.txt",
            Family::Toshiba => "seeds/002_43d8a4399c8be05f.txt",
            Family::Danfoss => "seeds/003_26a4c04ca1af5f26.txt",
            Family::B800 => "seeds/000_04b515f0e0c1734e.txt",
            Family::Template(id) => crate::template::kinds::kind(id).source,
        }
    }

    /// The wire number that a parameter name or number written in this family's style stands for.
    ///
    /// Accepted spellings (case-insensitive, surrounding blanks ignored), besides `0x`-prefixed hex
    /// in every family:
    ///
    /// | family | spelling | number |
    /// |---|---|---|
    /// | generic | `P3.09`, `p3.09` | register 0x0309 (the name's digits as hex digits) |
    /// | generic | `2103H` | register 0x2103 |
    /// | toshiba | `f803`, `F803` | communication number 0x0803 |
    /// | toshiba | `0803`, `FA01` (four hex digits) | that communication number |
    /// | danfoss | `4-14`, `04-14` | PNU 414 |
    /// | danfoss | `414` | PNU 414 |
    /// | b800 | `F-12`, `F12`, `12` | local index 12 |
    ///
    /// Returns `None` for text that is not a number in this family's style; whether a parameter
    /// with that number exists is the catalog's business.
    pub fn parse_number(self, text: &str) -> Option<u32> {
        let t = text.trim();
        if let Some(hex) = t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
            return parse_hex(hex);
        }
        match self {
            Family::Generic => {
                if let Some(rest) = t.strip_prefix(['P', 'p']) {
                    let (group, item) = rest.split_once('.')?;
                    if !(1..=2).contains(&group.len()) || item.len() != 2 {
                        return None;
                    }
                    if !all_digits(group) || !all_digits(item) {
                        return None;
                    }
                    // Pgg.nn is register 0xGGNN: the digits as written become hex digits.
                    Some((parse_hex(group)? << 8) | parse_hex(item)?)
                } else {
                    let hex = t.strip_suffix(['H', 'h'])?;
                    parse_hex(hex)
                }
            }
            Family::Toshiba => {
                if let Some(digits) = t.strip_prefix(['F', 'f']) {
                    if digits.len() == 3 && all_digits(digits) {
                        // Extended parameter fNNN has communication number 0NNN.
                        return parse_hex(digits);
                    }
                }
                if t.len() == 4 {
                    parse_hex(t)
                } else {
                    None
                }
            }
            Family::Danfoss => {
                if let Some((group, item)) = t.split_once('-') {
                    if !(1..=2).contains(&group.len()) || item.len() != 2 {
                        return None;
                    }
                    if !all_digits(group) || !all_digits(item) {
                        return None;
                    }
                    Some(group.parse::<u32>().ok()? * 100 + item.parse::<u32>().ok()?)
                } else {
                    parse_decimal(t)
                }
            }
            Family::B800 => {
                let rest = t.strip_prefix(['F', 'f']).map(|r| r.strip_prefix('-').unwrap_or(r));
                parse_decimal(rest.unwrap_or(t))
            }
            // A template's parameter by its register: `0x2103` (above), `2103H` or decimal.
            Family::Template(_) => match t.strip_suffix(['H', 'h']) {
                Some(hex) => parse_hex(hex),
                None => parse_decimal(t),
            },
        }
    }

    /// A wire number written the way this family's documents write it: `0x0803` for generic and
    /// Toshiba, plain decimal for the FC PNU and the B800 local index.
    pub fn format_number(self, number: u32) -> String {
        match self {
            Family::Generic | Family::Toshiba | Family::Template(_) => format!("0x{number:04X}"),
            Family::Danfoss | Family::B800 => number.to_string(),
        }
    }
}

/// What a family speaks, in one table: the protocols, the default one, the address range and the
/// serial default of each. Everything that needs one of these facts (profiles, simulator, gateway
/// configuration, command line) asks here.
impl Family {
    /// The protocols this family speaks; the first is its default.
    pub fn protocols(self) -> &'static [WireProtocol] {
        match self {
            // seed 004: "默认通讯协议方式采用ASCII 方式" (the default is ASCII).
            Family::Generic => &[WireProtocol::ModbusAscii, WireProtocol::ModbusRtu],
            // Binary mode is the manual's compact one (and the only one with block communication).
            Family::Toshiba => {
                &[WireProtocol::ToshibaBinary, WireProtocol::ToshibaAscii, WireProtocol::ModbusRtu]
            }
            Family::Danfoss => &[WireProtocol::DanfossFc],
            Family::B800 => &[WireProtocol::B800],
            Family::Template(id) => crate::template::kinds::kind(id).protocols,
        }
    }

    /// The protocol a drive of this family is spoken to when none is given.
    pub fn default_protocol(self) -> WireProtocol {
        self.protocols()[0]
    }

    /// `protocol` if this family speaks it, else a sentence that says which it speaks.
    pub fn check_protocol(self, protocol: WireProtocol) -> Result<WireProtocol, String> {
        if self.protocols().contains(&protocol) {
            Ok(protocol)
        } else {
            let names: Vec<&str> = self.protocols().iter().map(|p| p.name()).collect();
            Err(format!("a {self} drive does not speak {protocol}: use {}", names.join(" or ")))
        }
    }

    /// The addresses a drive of this family can have on `protocol` (broadcast not included).
    pub fn address_range(self, protocol: WireProtocol) -> (u8, u8) {
        match (self, protocol) {
            // seed 004: addresses up to FEH (the Modbus specification stops at 247).
            (Family::Generic, _) => (1, 254),
            (Family::Toshiba, WireProtocol::ModbusRtu) => (1, 247),
            // TIP binary carries the inverter number in 6 bits; ASCII as two decimal digits.
            (Family::Toshiba, WireProtocol::ToshibaBinary) => (0, 63),
            (Family::Toshiba, _) => (0, 99),
            (Family::Danfoss, _) => (1, 126),
            (Family::B800, _) => (1, 63),
            (Family::Template(id), _) => crate::template::kinds::kind(id).template.addresses,
        }
    }

    /// `address` if a drive of this family can have it on `protocol`, else a sentence that says
    /// the range.
    pub fn check_address(self, protocol: WireProtocol, address: u8) -> Result<u8, String> {
        let (lo, hi) = self.address_range(protocol);
        if (lo..=hi).contains(&address) {
            Ok(address)
        } else {
            Err(format!("a {self} drive on {protocol} has an address in {lo}..{hi}, not {address}"))
        }
    }

    /// The serial settings a drive of this family leaves the factory with on `protocol`
    /// (protocols.md, project decisions).
    pub fn serial_default(self, protocol: WireProtocol) -> (u32, CharFormat) {
        match (self, protocol) {
            (Family::Generic, WireProtocol::ModbusRtu) => (9600, CharFormat::NONE_8N2),
            (Family::Generic, _) => (9600, CharFormat::NONE_7N2),
            (Family::Toshiba, _) => (19200, CharFormat::EVEN_8E1),
            (Family::Danfoss, _) => (9600, CharFormat::EVEN_8E1),
            (Family::B800, _) => (9600, CharFormat::NONE_8N1),
            (Family::Template(id), p) => crate::template::kinds::kind(id).template.serial_default(p),
        }
    }
}

fn all_digits(s: &str) -> bool {
    !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit())
}

fn parse_hex(s: &str) -> Option<u32> {
    if s.is_empty() || s.len() > 8 || !s.bytes().all(|b| b.is_ascii_hexdigit()) {
        return None;
    }
    u32::from_str_radix(s, 16).ok()
}

fn parse_decimal(s: &str) -> Option<u32> {
    if !all_digits(s) || s.len() > 9 {
        return None;
    }
    s.parse().ok()
}

impl fmt::Display for Family {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The text given to [`Family::from_str`] names no family.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UnknownFamily {
    /// The text as given.
    pub text: String,
}

impl fmt::Display for UnknownFamily {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "unknown drive family {:?}: expected generic, toshiba, danfoss, b800 or a template kind (",
            self.text
        )?;
        for kind in crate::template::registered() {
            write!(f, "{kind}, ")?;
        }
        f.write_str("or one a template file adds: docs/templates.md)")
    }
}

impl std::error::Error for UnknownFamily {}

impl FromStr for Family {
    type Err = UnknownFamily;

    /// Parses "generic", "toshiba", "danfoss", "b800" or a template kind's name, in any letter
    /// case.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let t = s.trim();
        Family::ALL
            .into_iter()
            .find(|f| f.as_str().eq_ignore_ascii_case(t))
            .or_else(|| crate::template::kinds::by_name(t))
            .ok_or_else(|| UnknownFamily { text: s.to_string() })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for f in Family::ALL {
            assert_eq!(f.to_string().parse::<Family>(), Ok(f));
            assert_eq!(f.as_str().to_uppercase().parse::<Family>(), Ok(f));
        }
        let err = "siemens".parse::<Family>().unwrap_err();
        assert_eq!(
            err.to_string(),
            "unknown drive family \"siemens\": expected generic, toshiba, danfoss, b800 or a template kind (generic-2000h, abb-acs550, siemens-v20, danfoss-fc51, invertek-optidrive-e3, or one a template file adds: docs/templates.md)"
        );
    }

    #[test]
    fn generic_numbers() {
        let g = Family::Generic;
        assert_eq!(g.parse_number("P0.02"), Some(0x0002));
        assert_eq!(g.parse_number("p3.09"), Some(0x0309));
        assert_eq!(g.parse_number("P3.10"), Some(0x0310));
        assert_eq!(g.parse_number("P10.05"), Some(0x1005));
        assert_eq!(g.parse_number("2103H"), Some(0x2103));
        assert_eq!(g.parse_number("0x2103"), Some(0x2103));
        assert_eq!(g.parse_number("P3.9"), None);
        assert_eq!(g.parse_number("P3.0A"), None);
        assert_eq!(g.parse_number("2103"), None);
    }

    #[test]
    fn toshiba_numbers() {
        let t = Family::Toshiba;
        assert_eq!(t.parse_number("f803"), Some(0x0803));
        assert_eq!(t.parse_number("F803"), Some(0x0803));
        assert_eq!(t.parse_number("0803"), Some(0x0803));
        assert_eq!(t.parse_number("0010"), Some(0x0010));
        assert_eq!(t.parse_number("FA01"), Some(0xFA01));
        assert_eq!(t.parse_number("fd00"), Some(0xFD00));
        assert_eq!(t.parse_number("10"), None);
        assert_eq!(t.parse_number("f80"), None);
    }

    #[test]
    fn danfoss_and_b800_numbers() {
        let d = Family::Danfoss;
        assert_eq!(d.parse_number("4-14"), Some(414));
        assert_eq!(d.parse_number("04-14"), Some(414));
        assert_eq!(d.parse_number("16-14"), Some(1614));
        assert_eq!(d.parse_number("0-01"), Some(1));
        assert_eq!(d.parse_number("414"), Some(414));
        assert_eq!(d.parse_number("4-1"), None);
        let b = Family::B800;
        assert_eq!(b.parse_number("F-12"), Some(12));
        assert_eq!(b.parse_number("f12"), Some(12));
        assert_eq!(b.parse_number("12"), Some(12));
        assert_eq!(b.parse_number("F-"), None);
    }
}
