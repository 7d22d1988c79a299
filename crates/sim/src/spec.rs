//! One drive of a virtual bus as the command line or a bus file describes it
//! ([`DriveSpec`]), and the error a bad description gives ([`ConfigError`]).

use std::str::FromStr;
use std::time::Duration;

use drivebus_drive::profile::toshiba::ToshibaProtocol;
use drivebus_drive::Family;
use drivebus_proto::protocol::WireProtocol;

/// One drive on the virtual bus.
#[derive(Clone, Debug, PartialEq)]
pub struct DriveSpec {
    /// The family.
    pub family: Family,
    /// Its number on the bus.
    pub address: u8,
    /// The wire protocol, where the family speaks several (`None`: the family default).
    pub protocol: Option<WireProtocol>,
    /// Its response time.
    pub response: Duration,
    /// Its load, fraction of rated torque.
    pub load: f64,
    /// Parameters set at start (name, value in its unit), as on the keypad.
    pub params: Vec<(String, String)>,
}

/// Why a bus description is not usable: one sentence naming the place.
pub use drivebus_drive::ConfigError;

impl FromStr for DriveSpec {
    type Err = ConfigError;

    /// `KIND@ADDR[:PROTOCOL]`, e.g. `generic@1:modbus-rtu`, `b800@5`.
    fn from_str(s: &str) -> Result<Self, ConfigError> {
        let bad = |why: String| {
            ConfigError(format!(
                "--drive {s:?}: {why} (expected KIND@ADDR[:PROTOCOL], e.g. generic@1:modbus-rtu)"
            ))
        };
        let (kind, rest) = s.split_once('@').ok_or_else(|| bad("no '@' between kind and address".into()))?;
        let family: Family = kind
            .parse()
            .map_err(|_| bad(format!("unknown kind {kind:?}: use generic, toshiba, danfoss or b800")))?;
        let (addr, protocol) = match rest.split_once(':') {
            Some((a, p)) => (a, Some(p.parse::<WireProtocol>().map_err(|e| bad(e.to_string()))?)),
            None => (rest, None),
        };
        let address: u8 =
            addr.parse().map_err(|_| bad(format!("address {addr:?} is not a number 0..255")))?;
        let spec = DriveSpec {
            family,
            address,
            protocol,
            response: Duration::from_millis(5),
            load: 0.5,
            params: Vec::new(),
        };
        spec.check().map_err(|e| bad(e.0))?;
        Ok(spec)
    }
}

impl DriveSpec {
    /// The protocols a master may use to talk to this drive: the one it was given, or its
    /// family's default (a TOSHIBA drive answers both TIP modes on one line).
    pub fn wire_protocols(&self) -> &'static [WireProtocol] {
        match (self.family, self.protocol) {
            (Family::Toshiba, None | Some(WireProtocol::ToshibaAscii | WireProtocol::ToshibaBinary)) => {
                ToshibaProtocol::Tip.wire_protocols()
            }
            (family, Some(p)) => {
                family.protocols().iter().find(|&&x| x == p).map_or(&[], core::slice::from_ref)
            }
            (family, None) => &family.protocols()[..1],
        }
    }

    /// Checks the address range and protocol of the family.
    pub fn check(&self) -> Result<(), ConfigError> {
        if let Some(p) = self.protocol {
            self.family.check_protocol(p).map_err(ConfigError)?;
        }
        // A drive answers every protocol it speaks on the line (a TOSHIBA drive both TIP modes):
        // its address is good if one of them can carry it.
        let answered = self.wire_protocols();
        if !answered.iter().any(|&p| self.family.check_address(p, self.address).is_ok()) {
            let widest =
                answered.iter().map(|&p| self.family.address_range(p)).max_by_key(|(lo, hi)| hi - lo);
            let (lo, hi) = widest.unwrap_or((0, 0));
            return Err(ConfigError(format!(
                "a {} drive's address is {lo}..{hi}, not {}",
                self.family, self.address
            )));
        }
        if !(0.0..=5.0).contains(&self.load) {
            return Err(ConfigError(format!(
                "load {} is outside 0..5 (fraction of rated torque)",
                self.load
            )));
        }
        Ok(())
    }
}
