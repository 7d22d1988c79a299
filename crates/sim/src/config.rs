//! A whole virtual bus described in TOML, or built from `--drive KIND@ADDR[:PROTOCOL]` options.
//!
//! ```toml
//! baud = 9600          # optional: the first drive's family default
//! serial = "8N1"       # optional: idem
//! seed = 1             # fault injection seed
//! pacing = true        # false: bytes take no wire time (benchmarks over a pty or TCP)
//!
//! [faults]             # optional
//! corrupt_rate = 0.0   # probability a byte arrives with a bit flipped
//! drop_rate = 0.0      # probability a byte is lost
//! extra_latency_ms = 0 # added to every answer
//!
//! [[drive]]
//! kind = "generic"     # generic | toshiba | danfoss | b800
//! address = 1
//! protocol = "modbus-rtu"  # where the family speaks several
//! response_ms = 5      # the drive's response time
//! load = 0.5           # fraction of rated torque
//! params = { "P0.02" = "45 Hz" }  # set at start, as on the keypad
//! role = "master"      # optional: this drive broadcasts its run/stop and frequency
//! cycle_ms = 100       # the master's broadcast cycle
//! keypad_hz = 40       # the master's keypad frequency setting
//! ```

use std::time::Duration;

use drivebus_drive::Family;
use drivebus_proto::line::CharFormat;
use drivebus_proto::protocol::WireProtocol;
use serde::Deserialize;

use drivebus_proto::Instant;

use crate::bus::{Faults, VirtualLine};
use crate::interdrive::{BusMaster, DEFAULT_CYCLE};
pub use crate::spec::{ConfigError, DriveSpec};

/// The drive that is the line's bus master (`role = "master"`, or a Toshiba drive with f806 =
/// 3 or 4), see [`crate::interdrive`].
#[derive(Clone, Debug, PartialEq)]
pub struct MasterSpec {
    /// Which drive, an index into [`BusSpec::drives`].
    pub drive: usize,
    /// How often it broadcasts.
    pub cycle: Duration,
    /// Its keypad frequency setting at start, Hz.
    pub keypad_hz: Option<f64>,
}

/// A virtual bus: line settings, faults and drives.
#[derive(Clone, Debug, PartialEq)]
pub struct BusSpec {
    /// Baud rate.
    pub baud: u32,
    /// Character format.
    pub format: CharFormat,
    /// The drives.
    pub drives: Vec<DriveSpec>,
    /// Faults to inject from the start.
    pub faults: Faults,
    /// True (the default): every byte takes its wire time at `baud`. False: bytes arrive at
    /// once, so a client over a pty or TCP is measured, not the virtual line.
    pub pacing: bool,
    /// Seed for fault injection.
    pub seed: u64,
    /// The drive acting as bus master, if one does.
    pub master: Option<MasterSpec>,
}

/// The master role a bus file's drive takes, if it takes one: `role = "master"`, or for a
/// Toshiba drive f806 = 3 or 4 in its params; `cycle_ms` and `keypad_hz` only with it.
fn master_of(index: usize, spec: &DriveSpec, d: &FileDrive) -> Result<Option<MasterSpec>, ConfigError> {
    let bad = |m: String| Err(ConfigError(m));
    let by_role = match d.role.as_deref() {
        None => false,
        Some("master") => true,
        Some(other) => {
            return bad(format!(
            "field `role`: {other:?} is not a role: the only one is \"master\" (the other drives follow it)"
        ))
        }
    };
    let f806 = spec.params.iter().find(|(k, _)| k == "f806").map(|(_, v)| v.trim().to_string());
    let by_f806 = spec.family == Family::Toshiba && matches!(f806.as_deref(), Some("3" | "4"));
    if by_role && spec.family == Family::Toshiba && f806.is_some() && !by_f806 {
        return bad(format!(
            "role = \"master\" with f806 = {}: a Toshiba master has f806 = 3 (frequency command) or 4 (output frequency)",
            f806.unwrap_or_default()
        ));
    }
    if !(by_role || by_f806) {
        if d.cycle_ms.is_some() || d.keypad_hz.is_some() {
            return bad(
                "fields `cycle_ms` and `keypad_hz` belong to the master drive: add role = \"master\"".into(),
            );
        }
        return Ok(None);
    }
    let cycle = match d.cycle_ms {
        None => DEFAULT_CYCLE,
        Some(ms) if (10..=10_000).contains(&ms) => Duration::from_millis(ms),
        Some(ms) => return bad(format!("field `cycle_ms`: {ms} is outside 10..10000 ms")),
    };
    if let Some(hz) = d.keypad_hz {
        if !(0.0..=500.0).contains(&hz) {
            return bad(format!("field `keypad_hz`: {hz} is outside 0..500 Hz"));
        }
    }
    Ok(Some(MasterSpec { drive: index, cycle, keypad_hz: d.keypad_hz }))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileBus {
    baud: Option<u32>,
    serial: Option<String>,
    #[serde(default = "one")]
    seed: u64,
    #[serde(default = "yes")]
    pacing: bool,
    #[serde(default)]
    faults: FileFaults,
    #[serde(default, rename = "drive")]
    drives: Vec<FileDrive>,
}

fn one() -> u64 {
    1
}

fn yes() -> bool {
    true
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct FileFaults {
    #[serde(default)]
    corrupt_rate: f64,
    #[serde(default)]
    drop_rate: f64,
    #[serde(default)]
    extra_latency_ms: u64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileDrive {
    kind: String,
    address: u8,
    protocol: Option<String>,
    response_ms: Option<u64>,
    load: Option<f64>,
    #[serde(default)]
    params: toml::Table,
    role: Option<String>,
    cycle_ms: Option<u64>,
    keypad_hz: Option<f64>,
}

impl BusSpec {
    /// A bus of `drives` with the line settings given, or the first drive's family defaults.
    pub fn new(
        drives: Vec<DriveSpec>,
        baud: Option<u32>,
        format: Option<CharFormat>,
    ) -> Result<Self, ConfigError> {
        let first =
            drives.first().ok_or_else(|| ConfigError("no drive on the bus: add --drive KIND@ADDR".into()))?;
        let (db, df) = first.family.serial_default(first.protocol.unwrap_or(first.family.default_protocol()));
        let spec = BusSpec {
            baud: baud.unwrap_or(db),
            format: format.unwrap_or(df),
            drives,
            faults: Faults::default(),
            pacing: true,
            seed: 1,
            master: None,
        };
        spec.check()?;
        Ok(spec)
    }

    /// Reads a bus from TOML; errors name `file`, the line and the field.
    pub fn from_toml(file: &str, text: &str) -> Result<Self, ConfigError> {
        let raw: FileBus = toml::from_str(text).map_err(|e| {
            let line = e.span().map(|s| text[..s.start.min(text.len())].lines().count().max(1));
            let msg = e.message().trim().lines().map(str::trim).collect::<Vec<_>>().join(": ");
            match line {
                Some(l) => ConfigError(format!("{file}:{l}: {msg}")),
                None => ConfigError(format!("{file}: {msg}")),
            }
        })?;
        let mut drives = Vec::new();
        let mut master: Option<MasterSpec> = None;
        for (i, d) in raw.drives.iter().enumerate() {
            let at = format!("{file}: drive {} (kind {:?}, address {})", i + 1, d.kind, d.address);
            let family: Family = d.kind.parse().map_err(|_| {
                ConfigError(format!("{at}: field `kind`: use generic, toshiba, danfoss or b800"))
            })?;
            let spec = DriveSpec {
                family,
                address: d.address,
                protocol: match &d.protocol {
                    Some(p) => Some(
                        p.parse::<WireProtocol>()
                            .map_err(|e| ConfigError(format!("{at}: field `protocol`: {e}")))?,
                    ),
                    None => None,
                },
                response: Duration::from_millis(d.response_ms.unwrap_or(5)),
                load: d.load.unwrap_or(0.5),
                params: d
                    .params
                    .iter()
                    .map(|(k, v)| (k.clone(), v.as_str().map_or_else(|| v.to_string(), str::to_string)))
                    .collect(),
            };
            spec.check().map_err(|e| ConfigError(format!("{at}: {e}")))?;
            if let Some(m) = master_of(i, &spec, d).map_err(|e| ConfigError(format!("{at}: {e}")))? {
                if let Some(first) = &master {
                    return Err(ConfigError(format!(
                        "{at}: drive {} is the bus master already: a line has one master drive",
                        first.drive + 1
                    )));
                }
                master = Some(m);
            }
            drives.push(spec);
        }
        let format = match &raw.serial {
            Some(s) => Some(
                s.parse::<CharFormat>().map_err(|e| ConfigError(format!("{file}: field `serial`: {e}")))?,
            ),
            None => None,
        };
        let mut bus =
            BusSpec::new(drives, raw.baud, format).map_err(|e| ConfigError(format!("{file}: {e}")))?;
        for (name, v) in [("corrupt_rate", raw.faults.corrupt_rate), ("drop_rate", raw.faults.drop_rate)] {
            if !(0.0..=1.0).contains(&v) {
                return Err(ConfigError(format!(
                    "{file}: field `faults.{name}`: {v} is not a probability 0..1"
                )));
            }
        }
        bus.faults = Faults {
            corrupt_rate: raw.faults.corrupt_rate,
            drop_rate: raw.faults.drop_rate,
            extra_latency: Duration::from_millis(raw.faults.extra_latency_ms),
        };
        bus.seed = raw.seed;
        bus.pacing = raw.pacing;
        bus.master = master;
        Ok(bus)
    }

    /// Builds the line this bus describes at simulated time zero: every drive with its load,
    /// response time and parameters, the master drive wrapped as a [`BusMaster`].
    pub fn build_line(&self) -> Result<VirtualLine, ConfigError> {
        let mut line = VirtualLine::new(self.baud, self.format, Instant::ZERO);
        line.set_faults(self.faults);
        line.seed(self.seed);
        line.set_pacing(self.pacing);
        for (i, spec) in self.drives.iter().enumerate() {
            let at = |e: String| ConfigError(format!("{}@{}: {e}", spec.family, spec.address));
            let mut drive = crate::family::build(spec, Instant::ZERO)?;
            drive.core_mut().model.set_load(spec.load);
            drive.core_mut().response_delay = spec.response;
            let master = self.master.as_ref().filter(|m| m.drive == i);
            if master.is_some() {
                // Run and frequency from the keypad (generic), master by f806 (Toshiba); the
                // bus file's params may say otherwise.
                let defaults: &[(&str, &str)] = match spec.family {
                    Family::Generic => &[("P0.00", "0"), ("P0.01", "0")],
                    Family::Toshiba => &[("f806", "3")],
                    _ => &[],
                };
                for (name, value) in defaults {
                    drive.set_param(name, value).map_err(at)?;
                }
            }
            for (name, value) in &spec.params {
                drive.set_param(name, value).map_err(|e| at(format!("parameter {name}: {e}")))?;
            }
            match master {
                Some(m) => {
                    if let Some(hz) = m.keypad_hz {
                        drive.set_keypad_hz(hz).map_err(|e| at(format!("keypad_hz: {e}")))?;
                    }
                    let wrapped =
                        BusMaster::new(drive, m.cycle, line.char_time(), Instant::ZERO).map_err(at)?;
                    line.add_device(Box::new(wrapped));
                }
                None => {
                    line.add_device(drive);
                }
            }
        }
        Ok(line)
    }

    /// Checks line settings and that no two drives share an address.
    pub fn check(&self) -> Result<(), ConfigError> {
        if !(300..=1_000_000).contains(&self.baud) {
            return Err(ConfigError(format!("baud {} is outside 300..1000000", self.baud)));
        }
        for (i, a) in self.drives.iter().enumerate() {
            for b in &self.drives[..i] {
                if a.address == b.address && a.family == b.family {
                    return Err(ConfigError(format!(
                        "two {} drives have address {}: each drive on a bus needs its own",
                        a.family, a.address
                    )));
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn pacing_defaults_on_and_can_be_switched_off() {
        let on = BusSpec::from_toml("b.toml", "[[drive]]\nkind = \"generic\"\naddress = 1\n").unwrap();
        assert!(on.pacing);
        let off =
            BusSpec::from_toml("b.toml", "pacing = false\n[[drive]]\nkind = \"generic\"\naddress = 1\n")
                .unwrap();
        assert!(!off.pacing);
    }

    use super::*;

    #[test]
    fn drive_option_parses() {
        let d: DriveSpec = "generic@1:modbus-rtu".parse().unwrap();
        assert_eq!((d.family, d.address, d.protocol), (Family::Generic, 1, Some(WireProtocol::ModbusRtu)));
        let d: DriveSpec = "b800@5".parse().unwrap();
        assert_eq!((d.family, d.address, d.protocol), (Family::B800, 5, None));
    }

    #[test]
    fn drive_option_errors_say_what_to_do() {
        let e = "b800@64".parse::<DriveSpec>().unwrap_err().0;
        assert!(e.contains("1..63"), "{e}");
        let e = "pump@1".parse::<DriveSpec>().unwrap_err().0;
        assert!(e.contains("unknown kind") && e.contains("KIND@ADDR"), "{e}");
        let e = "danfoss@3:modbus-rtu".parse::<DriveSpec>().unwrap_err().0;
        assert!(e.contains("does not speak modbus-rtu: use danfoss-fc"), "{e}");
        let e = "generic1".parse::<DriveSpec>().unwrap_err().0;
        assert!(e.contains("no '@'"), "{e}");
    }

    #[test]
    fn serial_defaults_follow_the_first_drive() {
        let bus = BusSpec::new(vec!["toshiba@1".parse().unwrap()], None, None).unwrap();
        assert_eq!((bus.baud, bus.format), (19200, CharFormat::EVEN_8E1));
        let bus = BusSpec::new(vec!["generic@1".parse().unwrap()], None, None).unwrap();
        assert_eq!(bus.format, CharFormat::NONE_7N2);
    }

    #[test]
    fn toml_bus_and_its_errors() {
        let bus = BusSpec::from_toml(
            "bus.toml",
            "baud = 19200\nserial = \"8E1\"\n[faults]\ncorrupt_rate = 0.01\n[[drive]]\nkind = \"toshiba\"\naddress = 2\n[[drive]]\nkind = \"generic\"\naddress = 3\nprotocol = \"modbus-rtu\"\nload = 0.8\n",
        )
        .unwrap();
        assert_eq!(bus.drives.len(), 2);
        assert_eq!(bus.faults.corrupt_rate, 0.01);
        assert_eq!(bus.drives[1].load, 0.8);
        let bus = BusSpec::from_toml(
            "bus.toml",
            "[[drive]]\nkind = \"b800\"\naddress = 5\nparams = { \"F-12\" = 2, \"F-01\" = \"45 Hz\" }\n",
        )
        .unwrap();
        assert_eq!(
            bus.drives[0].params,
            [("F-01".to_string(), "45 Hz".to_string()), ("F-12".to_string(), "2".to_string())]
        );
        let e = BusSpec::from_toml("bus.toml", "[[drive]]\nkind = \"generic\"\naddress = 1\nspeed = 3\n")
            .unwrap_err()
            .0;
        assert!(e.starts_with("bus.toml:") && e.contains("speed"), "{e}");
        let e = BusSpec::from_toml("bus.toml", "[[drive]]\nkind = \"b800\"\naddress = 70\n").unwrap_err().0;
        assert!(e.contains("drive 1") && e.contains("1..63"), "{e}");
        let e = BusSpec::from_toml(
            "bus.toml",
            "[[drive]]\nkind = \"b800\"\naddress = 7\n[[drive]]\nkind = \"b800\"\naddress = 7\n",
        )
        .unwrap_err()
        .0;
        assert!(e.contains("two b800 drives have address 7"), "{e}");
        let e = BusSpec::from_toml("bus.toml", "").unwrap_err().0;
        assert!(e.contains("no drive"), "{e}");
    }
}
