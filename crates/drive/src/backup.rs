//! The parameter backup file: what `drivebus params backup` writes and the gateway's
//! `GET /api/drives/{id}/backup` answers, one writer ([`Backup::to_text`]) and one reader
//! ([`Backup::parse`]) for both, and the comparison a restore starts from ([`differences`]).
//!
//! The file is JSON:
//!
//! ```json
//! {
//!   "address": 3,
//!   "family": "generic",
//!   "model": "generic VFD (2000H/2100H Modbus map)",
//!   "params": { "P0.02": { "raw": 5000, "value": "50.00 Hz" } },
//!   "protocol": "modbus-rtu"
//! }
//! ```
//!
//! It holds the drive's settings ([`is_setting`]: writable and kept in EEPROM), raw as the
//! drive holds them and as the keypad shows them.

use std::collections::BTreeMap;
use std::fmt;

use serde_json::{json, Map, Value};

use crate::{Catalog, Family, ParamDef};

/// Whether a parameter is a setting a backup holds: writable and kept in EEPROM (not a
/// command, a setpoint or a monitor).
pub fn is_setting(def: &ParamDef) -> bool {
    !def.read_only && def.storage == crate::Storage::Eeprom
}

/// A name from a file, cut to 64 characters for a message.
fn shown(s: &str) -> String {
    let cut: String = s.chars().take(64).collect();
    if cut.len() < s.len() {
        format!("{cut}...")
    } else {
        cut
    }
}

/// One parameter of a backup: its raw value and the value as the keypad shows it.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Entry {
    /// The raw value.
    pub raw: i64,
    /// The value as shown (`50.00 Hz`, a choice's text); empty when the file gives none.
    pub value: String,
}

/// A backup: whose parameters they are and the parameters, by the manual's name.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Backup {
    /// The drive's family, as written in the file (`generic`, `toshiba`, ...).
    pub family: String,
    /// The model, where the file names it.
    pub model: Option<String>,
    /// The protocol it was read over, where the file names it.
    pub protocol: Option<String>,
    /// The drive's bus address, where the file gives it.
    pub address: Option<u64>,
    /// The parameters, by name.
    pub params: BTreeMap<String, Entry>,
}

/// A backup file that cannot be read: one line saying what is wrong.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BackupError(pub String);

impl fmt::Display for BackupError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for BackupError {}

impl Backup {
    /// The backup of a `family` drive at `address`, read over `protocol`: `readings` are the
    /// settings' definitions and raw values.
    pub fn new<'d>(
        family: Family,
        protocol: &str,
        address: u8,
        readings: impl IntoIterator<Item = (&'d ParamDef, i64)>,
    ) -> Backup {
        let params = readings
            .into_iter()
            .map(|(d, raw)| (d.name.clone(), Entry { raw, value: d.format(raw) }))
            .collect();
        Backup {
            family: family.to_string(),
            model: Some(family.model().to_string()),
            protocol: Some(protocol.to_string()),
            address: Some(u64::from(address)),
            params,
        }
    }

    /// The file's text (pretty JSON, keys in order, ending with a newline).
    pub fn to_text(&self) -> String {
        let params: Map<String, Value> =
            self.params.iter().map(|(n, e)| (n.clone(), json!({"raw": e.raw, "value": e.value}))).collect();
        let doc = json!({
            "family": self.family,
            "model": self.model,
            "protocol": self.protocol,
            "address": self.address,
            "params": params,
        });
        // A map of strings and numbers always serializes.
        serde_json::to_string_pretty(&doc).unwrap_or_default() + "\n"
    }

    /// Reads a backup file's text. Refuses (one line, saying what to do) what is not JSON, a
    /// file without a `family` or a `params` object, and a parameter without an integer `raw`.
    pub fn parse(text: &str) -> Result<Backup, BackupError> {
        let bad = |m: String| BackupError(format!("not a drivebus backup: {m}"));
        let v: Value = serde_json::from_str(text).map_err(|e| bad(format!("{e}")))?;
        let Some(doc) = v.as_object() else {
            return Err(bad(
                "the file is not a JSON object (back a drive up with `drivebus params backup`)".into()
            ));
        };
        let family = doc
            .get("family")
            .and_then(Value::as_str)
            .ok_or_else(|| bad("no \"family\" (generic, toshiba, danfoss or b800)".into()))?
            .to_string();
        let params =
            doc.get("params").and_then(Value::as_object).ok_or_else(|| bad("no \"params\" object".into()))?;
        let mut out = BTreeMap::new();
        for (name, p) in params {
            let shown = shown(name);
            let raw = p
                .get("raw")
                .and_then(Value::as_i64)
                .ok_or_else(|| bad(format!("parameter {shown:?} has no integer \"raw\" value")))?;
            let value = p.get("value").and_then(Value::as_str).unwrap_or_default().to_string();
            out.insert(name.clone(), Entry { raw, value });
        }
        Ok(Backup {
            family,
            model: doc.get("model").and_then(Value::as_str).map(str::to_string),
            protocol: doc.get("protocol").and_then(Value::as_str).map(str::to_string),
            address: doc.get("address").and_then(Value::as_u64),
            params: out,
        })
    }

    /// Refuses the backup of another family's drive (`what` names the file).
    pub fn check_family(&self, family: Family, what: &str) -> Result<(), BackupError> {
        if self.family == family.as_str() {
            return Ok(());
        }
        let shown = shown(&self.family);
        Err(BackupError(format!("{what} holds {shown} parameters; this is a {family} drive")))
    }
}

/// A parameter whose value in the drive differs from the file's.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Difference {
    /// The manual's name.
    pub name: String,
    /// In the drive.
    pub drive: Entry,
    /// In the file.
    pub file: Entry,
    /// A communication setting ([`ParamDef::comm`]): restored only when asked.
    pub comm: bool,
}

/// The parameters of `file` whose raw value differs from `drive`'s (a parameter the drive's
/// backup does not hold is left out), in name order; `catalog` says which are communication
/// settings.
pub fn differences(catalog: &Catalog, drive: &Backup, file: &Backup) -> Vec<Difference> {
    file.params
        .iter()
        .filter_map(|(name, want)| {
            let have = drive.params.get(name)?;
            (have.raw != want.raw).then(|| Difference {
                name: name.clone(),
                drive: have.clone(),
                file: want.clone(),
                comm: catalog.get(name).is_some_and(|d| d.comm),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Backup {
        let c = Catalog::load(Family::Generic).expect("catalog");
        let p002 = c.get("P0.02").expect("P0.02");
        let p311 = c.get("P3.11").expect("P3.11");
        Backup::new(Family::Generic, "modbus-rtu", 3, [(p002, 5000), (p311, 3)])
    }

    #[test]
    fn the_file_reads_back_as_written() {
        let b = sample();
        let text = b.to_text();
        assert!(text.ends_with("}\n"), "{text}");
        assert!(
            text.contains("\"P0.02\": {\n      \"raw\": 5000,\n      \"value\": \"50.00 Hz\"\n    }"),
            "{text}"
        );
        assert_eq!(Backup::parse(&text), Ok(b));
    }

    #[test]
    fn a_malformed_file_is_refused_in_one_line() {
        for (text, says) in [
            ("{", "EOF"),
            ("[]", "not a JSON object"),
            (r#"{"params": {}}"#, "no \"family\""),
            (r#"{"family": "generic"}"#, "no \"params\" object"),
            (r#"{"family": "generic", "params": {"P0.02": {"raw": "x"}}}"#, "\"P0.02\" has no integer"),
        ] {
            let e = Backup::parse(text).expect_err(text).to_string();
            assert!(e.starts_with("not a drivebus backup: ") && e.contains(says), "{text}: {e}");
            assert!(!e.contains('\n'), "{e}");
        }
        let b = sample();
        assert_eq!(
            b.check_family(Family::Danfoss, "the file").unwrap_err().to_string(),
            "the file holds generic parameters; this is a danfoss drive"
        );
    }

    #[test]
    fn differences_name_the_drive_and_the_file_and_mark_comm_settings() {
        let c = Catalog::load(Family::Generic).expect("catalog");
        let drive = sample();
        let mut file = sample();
        file.params.get_mut("P0.02").expect("P0.02").raw = 4000;
        file.params.get_mut("P3.11").expect("P3.11").raw = 7;
        file.params.insert("P9.99".into(), Entry { raw: 1, value: String::new() });
        let d = differences(&c, &drive, &file);
        assert_eq!(d.len(), 2, "{d:?}");
        assert_eq!(
            (d[0].name.as_str(), d[0].drive.raw, d[0].file.raw, d[0].comm),
            ("P0.02", 5000, 4000, false)
        );
        assert_eq!((d[1].name.as_str(), d[1].comm), ("P3.11", true));
        assert!(differences(&c, &drive, &drive).is_empty());
    }
}
