//! The commissioning workbench: a drive's whole parameter list with its values, its backup
//! (the file `drivebus params backup` writes, [`drivebus_drive::backup`]), a restore that
//! compares and then writes each row as an audited command, and its trip history. Every read
//! goes through the fair on-demand queue ([`Gateway::read_param`]), every write through
//! [`Gateway::command`].

use std::sync::Arc;

use drivebus_drive::backup::{differences, is_setting, Backup, Entry};
use drivebus_drive::profile::trips::{history_json, history_of, history_reads};
use drivebus_drive::ParamDef;
use serde::Serialize;
use serde_json::Value;

use super::command::{Command, CommandError};
use super::gateway::Gateway;

/// A failure of one row, in the words the core gives it.
#[derive(Clone, Debug, Serialize, PartialEq, Eq)]
pub struct RowError {
    /// [`CommandError::kind`].
    pub kind: &'static str,
    /// What happened, one line.
    pub message: String,
}

impl From<&CommandError> for RowError {
    fn from(e: &CommandError) -> Self {
        RowError { kind: e.kind(), message: e.to_string() }
    }
}

/// One parameter of a drive's catalog with its value read from the drive.
#[derive(Clone, Debug, Serialize)]
pub struct ParamRow {
    /// The manual's name.
    pub name: String,
    /// The manual's title.
    pub title: String,
    /// The catalog's group (chapter).
    pub group: String,
    /// The unit ("" for codes and counts).
    pub unit: String,
    /// The smallest value, in the unit.
    pub min: f64,
    /// The largest value, in the unit.
    pub max: f64,
    /// The factory value, in the unit.
    pub default: f64,
    /// The factory value as the keypad shows it.
    pub default_text: String,
    /// `read-write` or `read-only`.
    pub access: &'static str,
    /// `eeprom` (a setting) or `ram` (a command, monitor or action).
    pub storage: &'static str,
    /// A communication setting (left out of a restore unless asked).
    pub comm: bool,
    /// The named values of a code parameter (raw value and text).
    pub choices: Vec<drivebus_drive::Choice>,
    /// The raw value read (`null` when not read).
    pub raw: Option<i64>,
    /// The value read, in the unit.
    pub value: Option<f64>,
    /// The value read as the keypad shows it.
    pub text: Option<String>,
    /// The value read differs from the factory value.
    pub differs: bool,
    /// Why the value was not read (the drive refused it, the protocol has no parameter access).
    pub error: Option<RowError>,
}

impl ParamRow {
    fn of(def: &ParamDef) -> ParamRow {
        ParamRow {
            name: def.name.clone(),
            title: def.title.clone(),
            group: def.group.clone(),
            unit: def.unit.clone(),
            min: def.from_raw(def.min),
            max: def.from_raw(def.max),
            default: def.from_raw(def.default),
            default_text: def.format(def.default),
            access: if def.read_only { "read-only" } else { "read-write" },
            storage: def.storage.as_str(),
            comm: def.comm,
            choices: def.choices.clone(),
            raw: None,
            value: None,
            text: None,
            differs: false,
            error: None,
        }
    }
}

/// Whether a read's failure is the parameter's own (the row says so and the list goes on) rather
/// than the drive's or the bus's (the whole list fails: every other read would too).
fn row_failure(e: &CommandError) -> bool {
    matches!(e, CommandError::Refused { .. } | CommandError::Unsupported(_) | CommandError::Invalid(_))
}

/// One row of a restore: a parameter whose value in the drive differs from the file's.
#[derive(Clone, Debug, Serialize)]
pub struct RestoreRow {
    /// The manual's name.
    pub name: String,
    /// The manual's title.
    pub title: String,
    /// The value in the drive.
    pub drive: Entry,
    /// The value in the file.
    pub file: Entry,
    /// A communication setting.
    pub comm: bool,
    /// Whether this restore writes it (not left out as a communication setting or by `only`).
    pub apply: bool,
    /// How its write went: `null` when not written (a dry run, or not applied), else `ok` or
    /// `failed`.
    pub result: Option<&'static str>,
    /// Why its write failed (the drive's refusal and its reason).
    pub error: Option<RowError>,
}

/// What a restore asks for besides the file.
#[derive(Clone, Debug, Default)]
pub struct RestoreOptions {
    /// Compare only: write nothing.
    pub dry_run: bool,
    /// Only these parameters (by the manual's name) are written.
    pub only: Option<Vec<String>>,
    /// Communication settings are written too.
    pub include_comm: bool,
}

impl Gateway {
    /// Every parameter of drive `id`'s catalog (those of `group` when given), each with the value
    /// read from the drive on behalf of `client` unless `read` is false. A parameter the drive
    /// refuses, or its protocol cannot read, says so in its row; a drive that does not answer
    /// fails the whole list.
    pub async fn read_params(
        &self,
        id: &str,
        group: Option<&str>,
        read: bool,
        client: &str,
    ) -> Result<Vec<ParamRow>, CommandError> {
        let d = self.drive(id)?;
        let catalog = d.catalog();
        if let Some(g) = group {
            if !catalog.iter().any(|p| p.group == g) {
                let mut groups: Vec<&str> = catalog.iter().map(|p| p.group.as_str()).collect();
                groups.dedup();
                return Err(CommandError::Invalid(format!(
                    "drive {id:?} has no parameter group {:?}: its groups are {}",
                    crate::text::shown(g),
                    groups.join(", ")
                )));
            }
        }
        let mut rows = Vec::new();
        for def in catalog.iter().filter(|p| group.map_or(true, |g| p.group == g)) {
            let mut row = ParamRow::of(def);
            if read {
                match self.read_param(id, &def.name, client).await {
                    Ok(r) => {
                        row.differs = r.raw != def.default;
                        row.raw = Some(r.raw);
                        row.value = Some(r.value);
                        row.text = Some(r.text);
                    }
                    Err(e) if row_failure(&e) => row.error = Some(RowError::from(&e)),
                    Err(e) => return Err(e),
                }
            }
            rows.push(row);
        }
        Ok(rows)
    }

    /// The backup of drive `id`, read on behalf of `client`: the file `drivebus params backup`
    /// writes. A protocol without parameter access has nothing to back up:
    /// [`CommandError::Unsupported`].
    pub async fn backup(&self, id: &str, client: &str) -> Result<Backup, CommandError> {
        let d = self.drive(id)?;
        let catalog = d.catalog();
        let mut read = Vec::new();
        let mut unsupported = false;
        for def in catalog.iter().filter(|p| is_setting(p)) {
            match self.read_param(id, &def.name, client).await {
                Ok(r) => read.push((def, r.raw)),
                Err(CommandError::Unsupported(_)) => unsupported = true,
                Err(e) => return Err(e),
            }
        }
        if unsupported && read.is_empty() {
            return Err(CommandError::Unsupported(format!(
                "drive {id:?} has nothing to back up: the {} protocol has no parameter access (read and set the parameters on the drive's keypad)",
                d.protocol
            )));
        }
        Ok(Backup::new(d.config.family, d.protocol.name(), d.config.address, read))
    }

    /// Restores `file` onto drive `id` on behalf of `actor` (reads as `client`): compares it with
    /// the drive, and unless a dry run writes each differing row that applies (communication
    /// settings only with `include_comm`, only the names in `only` when given) to EEPROM as an
    /// audited command, in order, with a result per row.
    pub async fn restore(
        self: &Arc<Self>,
        id: &str,
        file: &Backup,
        options: &RestoreOptions,
        actor: &str,
        client: &str,
    ) -> Result<Vec<RestoreRow>, CommandError> {
        let d = self.drive(id)?;
        let catalog = d.catalog();
        file.check_family(d.config.family, "the file").map_err(|e| CommandError::Invalid(e.to_string()))?;
        let only: Option<Vec<String>> = match &options.only {
            None => None,
            Some(names) => Some(
                names
                    .iter()
                    .map(|n| {
                        catalog.get(n).map(|p| p.name.clone()).ok_or_else(|| {
                            CommandError::Invalid(format!(
                                "only: drive {id:?} has no parameter {:?}",
                                crate::text::shown(n)
                            ))
                        })
                    })
                    .collect::<Result<_, _>>()?,
            ),
        };
        let have = self.backup(id, client).await?;
        let mut rows: Vec<RestoreRow> = differences(&catalog, &have, file)
            .into_iter()
            .map(|diff| {
                let apply = (options.include_comm || !diff.comm)
                    && only.as_ref().map_or(true, |o| o.contains(&diff.name));
                RestoreRow {
                    title: catalog.get(&diff.name).map(|p| p.title.clone()).unwrap_or_default(),
                    name: diff.name,
                    drive: diff.drive,
                    file: diff.file,
                    comm: diff.comm,
                    apply,
                    result: None,
                    error: None,
                }
            })
            .collect();
        if options.dry_run {
            return Ok(rows);
        }
        for row in rows.iter_mut().filter(|r| r.apply) {
            let command = Command::SetParamRaw {
                name: row.name.clone(),
                raw: row.file.raw,
                shown: row.file.value.clone(),
                eeprom: true,
            };
            let done = self.command(id, command, actor).await;
            row.result = Some(if done.is_ok() { "ok" } else { "failed" });
            row.error = done.err().as_ref().map(RowError::from);
        }
        Ok(rows)
    }

    /// Drive `id`'s trip history as `drivebus trips --json` gives it (the trip in force from
    /// the last poll, the logged trips read from the drive on behalf of `client`).
    pub async fn trip_history(&self, id: &str, client: &str) -> Result<Value, CommandError> {
        let d = self.drive(id)?;
        let family = d.config.family;
        let status = d.with_state(|s| s.status.clone()).ok_or_else(|| {
            CommandError::NoAnswer(format!("drive {id:?} has not answered a poll yet: try again shortly"))
        })?;
        let reader = d.command.on_demand_for(client);
        let mut raws = Vec::new();
        for name in history_reads(family) {
            let (raw, _) = reader.read_param(&name).await.map_err(CommandError::from)?;
            raws.push(raw);
        }
        Ok(history_json(d.config.address, family, &history_of(family, &status, &raws)))
    }
}
