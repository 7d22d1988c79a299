//! The template file as TOML gives it (serde, every field with its place in the file), before
//! the checks of [`super::check`].

use std::collections::BTreeMap;

use serde::Deserialize;
use toml::Spanned;

/// A whole template file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileTemplate {
    pub(super) kind: Spanned<String>,
    pub(super) maker: Spanned<String>,
    pub(super) model: Spanned<String>,
    pub(super) source: Spanned<String>,
    #[serde(default)]
    pub(super) checked: Option<Spanned<String>>,
    #[serde(default)]
    pub(super) note: Option<String>,
    pub(super) protocols: Spanned<Vec<Spanned<String>>>,
    #[serde(default)]
    pub(super) addresses: Option<Spanned<[i64; 2]>>,
    #[serde(default)]
    pub(super) max_read: Option<Spanned<i64>>,
    pub(super) serial: Spanned<FileSerial>,
    pub(super) status: Spanned<BTreeMap<String, Spanned<FileValue>>>,
    #[serde(default)]
    pub(super) command: Option<Spanned<FileCommand>>,
    #[serde(default)]
    pub(super) setpoint: Option<Spanned<FileSetpoint>>,
    #[serde(default)]
    pub(super) param: Vec<Spanned<FileParam>>,
    #[serde(default)]
    pub(super) faults: Option<Spanned<BTreeMap<String, Spanned<String>>>>,
    /// Parameters holding the last faults, newest first (`drivebus trips`).
    #[serde(default)]
    pub(super) fault_history: Vec<Spanned<String>>,
    /// Status values beyond the six, by name (`dc_bus_v = { register = 106, unit = "V" }`).
    #[serde(default)]
    pub(super) values: Option<Spanned<BTreeMap<String, Spanned<FileValue>>>>,
}

/// `[serial]`: the factory serial settings.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileSerial {
    pub(super) baud: Spanned<i64>,
    pub(super) format: Spanned<String>,
    /// Formats per protocol where they differ from `format` (`modbus-rtu = "8N2"`).
    #[serde(default)]
    pub(super) formats: BTreeMap<String, Spanned<String>>,
}

/// One register value: where it is, how it is coded and scaled.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileValue {
    pub(super) register: Spanned<i64>,
    #[serde(default)]
    pub(super) table: Option<Spanned<String>>,
    #[serde(default, rename = "type")]
    pub(super) kind: Option<Spanned<String>>,
    #[serde(default)]
    pub(super) word_order: Option<Spanned<String>>,
    #[serde(default)]
    pub(super) scale: Option<Spanned<f64>>,
    #[serde(default)]
    pub(super) offset: Option<Spanned<f64>>,
    #[serde(default)]
    pub(super) full_scale: Option<Spanned<f64>>,
    #[serde(default)]
    pub(super) max: Option<Spanned<f64>>,
    #[serde(default)]
    pub(super) bit: Option<Spanned<i64>>,
    /// A field of the register: `0xFF00` (the high byte), the shift implied by the mask.
    #[serde(default)]
    pub(super) mask: Option<Spanned<i64>>,
    /// The unit of a value under `[values]`.
    #[serde(default)]
    pub(super) unit: Option<Spanned<String>>,
}

/// A command: a value written to the command register, or a bit of the command word.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
pub(super) enum FileCommandValue {
    /// The value written.
    Value(i64),
    /// A bit of the command word.
    Bit {
        /// Its number.
        bit: i64,
    },
    /// Writes to several registers, in order.
    Writes(Vec<FileWrite>),
}

/// One register written, with its value (`{ register = 3, value = 1 }`).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileWrite {
    pub(super) register: i64,
    pub(super) value: i64,
}

/// `[command]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileCommand {
    /// The command register (value and bit forms).
    #[serde(default)]
    pub(super) register: Option<Spanned<i64>>,
    #[serde(default)]
    pub(super) run: Option<Spanned<FileCommandValue>>,
    #[serde(default)]
    pub(super) stop: Option<Spanned<FileCommandValue>>,
    #[serde(default)]
    pub(super) forward: Option<Spanned<FileCommandValue>>,
    #[serde(default)]
    pub(super) reverse: Option<Spanned<FileCommandValue>>,
    #[serde(default)]
    pub(super) reset: Option<Spanned<FileCommandValue>>,
    #[serde(default)]
    pub(super) jog: Option<Spanned<FileCommandValue>>,
    /// The command word's other bits (bit form).
    #[serde(default)]
    pub(super) idle: Option<Spanned<i64>>,
    #[serde(default)]
    pub(super) reverse_needs_running: bool,
}

/// `[setpoint]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileSetpoint {
    pub(super) register: Spanned<i64>,
    #[serde(default, rename = "type")]
    pub(super) kind: Option<Spanned<String>>,
    #[serde(default)]
    pub(super) word_order: Option<Spanned<String>>,
    #[serde(default)]
    pub(super) scale: Option<Spanned<f64>>,
    #[serde(default)]
    pub(super) full_scale: Option<Spanned<f64>>,
    #[serde(default)]
    pub(super) max_hz: Option<Spanned<f64>>,
    #[serde(default)]
    pub(super) limit_params: Vec<Spanned<String>>,
    /// Other registers written with every setpoint.
    #[serde(default)]
    pub(super) writes: Option<Spanned<Vec<FileWrite>>>,
    /// `"negative"`: the direction is the setpoint's sign.
    #[serde(default)]
    pub(super) reverse: Option<Spanned<String>>,
}

/// One `[[param]]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileParam {
    pub(super) name: Spanned<String>,
    pub(super) title: Spanned<String>,
    pub(super) register: Spanned<i64>,
    #[serde(default)]
    pub(super) unit: String,
    #[serde(default, rename = "type")]
    pub(super) kind: Option<Spanned<String>>,
    #[serde(default)]
    pub(super) word_order: Option<Spanned<String>>,
    #[serde(default)]
    pub(super) scale: Option<Spanned<f64>>,
    pub(super) range: Spanned<[f64; 2]>,
    pub(super) default: Spanned<f64>,
    #[serde(default)]
    pub(super) access: Option<Spanned<String>>,
    #[serde(default)]
    pub(super) storage: Option<Spanned<String>>,
    #[serde(default)]
    pub(super) comm: bool,
    #[serde(default)]
    pub(super) while_running: Option<bool>,
    #[serde(default)]
    pub(super) choices: BTreeMap<String, String>,
    #[serde(default)]
    pub(super) note: Option<String>,
    #[serde(default)]
    pub(super) group: Option<String>,
}
