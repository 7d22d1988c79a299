//! Drive templates: a Modbus drive described in a TOML file (docs/templates.md) becomes a drive
//! kind like the built-in families. The file gives the drive's identity and the document its map
//! comes from, its protocols and serial defaults, where its status values are and how they are
//! coded and scaled, its command word, its setpoint, its parameters and its fault codes.
//!
//! [`Template::from_toml_str`] reads and checks a file and reports every error with its line;
//! [`register`] makes a checked template a kind ([`Family::Template`]), after which its name works
//! wherever a family's does (`--drive`, `family = "..."`), and [`profile::TemplateProfile`] speaks
//! to it with the same Modbus requests and replies as the built-in profiles.

mod check;
mod file;
pub mod kinds;
pub mod profile;

use std::collections::BTreeMap;
use std::fmt;

use drivebus_proto::line::CharFormat;
use drivebus_proto::protocol::WireProtocol;

use crate::ParamDef;
pub use kinds::{register, registered, shipped, KindId};

/// How far a template has been checked.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Checked {
    /// Against the simulator only: nobody has reported it on hardware yet.
    Simulator,
    /// Someone ran it against the drive itself.
    Hardware,
}

impl Checked {
    /// `simulator` or `hardware`, as the file says it.
    pub fn as_str(self) -> &'static str {
        match self {
            Checked::Simulator => "simulator",
            Checked::Hardware => "hardware",
        }
    }
}

/// Which register table a value is read from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum RegisterTable {
    /// Holding registers (function 03), the default.
    Holding,
    /// Input registers (function 04).
    Input,
}

/// How a value is coded in its registers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ValueType {
    /// One register, unsigned.
    U16,
    /// One register, two's complement.
    I16,
    /// Two registers, unsigned.
    U32,
    /// Two registers, two's complement.
    I32,
    /// Two registers, IEEE 754 single precision.
    F32,
}

impl ValueType {
    /// The names a file uses.
    pub const NAMES: &'static str = "u16, i16, u32, i32 or f32";

    /// Reads the name a file uses.
    pub fn parse(text: &str) -> Option<ValueType> {
        Some(match text {
            "u16" => ValueType::U16,
            "i16" => ValueType::I16,
            "u32" => ValueType::U32,
            "i32" => ValueType::I32,
            "f32" => ValueType::F32,
            _ => return None,
        })
    }

    /// Registers the value takes.
    pub fn words(self) -> u16 {
        match self {
            ValueType::U16 | ValueType::I16 => 1,
            _ => 2,
        }
    }

    /// The number `words` hold (the first word first as read; `low_first` when the low word
    /// comes first).
    pub fn decode(self, words: &[u16], low_first: bool) -> f64 {
        let w = |i: usize| words.get(i).copied().unwrap_or(0);
        let dword = || {
            if low_first {
                u32::from(w(1)) << 16 | u32::from(w(0))
            } else {
                u32::from(w(0)) << 16 | u32::from(w(1))
            }
        };
        match self {
            ValueType::U16 => f64::from(w(0)),
            ValueType::I16 => f64::from(w(0) as i16),
            ValueType::U32 => f64::from(dword()),
            ValueType::I32 => f64::from(dword() as i32),
            ValueType::F32 => f64::from(f32::from_bits(dword())),
        }
    }

    /// The registers of the raw integer (or, for f32, number) `raw`, in wire order.
    pub fn encode(self, raw: f64, low_first: bool) -> Vec<u16> {
        let dword = |bits: u32| {
            let (hi, lo) = ((bits >> 16) as u16, bits as u16);
            if low_first {
                vec![lo, hi]
            } else {
                vec![hi, lo]
            }
        };
        match self {
            ValueType::U16 | ValueType::I16 => vec![raw as i64 as u16],
            ValueType::U32 | ValueType::I32 => dword(raw as i64 as u32),
            ValueType::F32 => dword((raw as f32).to_bits()),
        }
    }
}

/// Where a value is and how to read it: value = raw × scale + offset, or one bit of it.
#[derive(Clone, Debug, PartialEq)]
pub struct RegisterValue {
    /// The (first) register.
    pub register: u16,
    /// Holding or input.
    pub table: RegisterTable,
    /// Its coding.
    pub kind: ValueType,
    /// Two-register values: the low word comes first.
    pub low_first: bool,
    /// Units per count (0.01 for 0.01 Hz; from `full_scale` and `max`: max / full_scale).
    pub scale: f64,
    /// Added after scaling.
    pub offset: f64,
    /// A flag: this bit of the raw value (set = true).
    pub bit: Option<u8>,
    /// A field of the register(s): the value is `(raw & mask) >> shift`, the shift being the
    /// mask's lowest set bit (`0xFF00`: the high byte). Its bits follow one another; u16 or u32
    /// only (a field is unsigned).
    pub mask: Option<u32>,
    /// The decimals the value is shown with (from the scale).
    pub decimals: i32,
}

impl RegisterValue {
    /// The raw number of the registers read for it: the whole value, or its `mask` field.
    fn raw(&self, words: &[u16]) -> f64 {
        let raw = self.kind.decode(words, self.low_first);
        match self.mask {
            Some(mask) => f64::from((raw as i64 as u32 & mask) >> mask.trailing_zeros()),
            None => raw,
        }
    }

    /// The value in units of the registers read for it.
    pub fn value(&self, words: &[u16]) -> f64 {
        crate::profile::round_to(self.raw(words) * self.scale + self.offset, self.decimals)
    }

    /// The flag of the registers read for it (a set bit, or any value but zero; with a `mask`,
    /// any bit of the field set).
    pub fn flag(&self, words: &[u16]) -> bool {
        match self.bit {
            Some(b) => (self.kind.decode(words, self.low_first) as i64 as u64) >> b & 1 == 1,
            None => self.raw(words) != 0.0,
        }
    }

    /// The registers holding the raw number `raw` (rounded by the caller; an f32 holds it as
    /// it is), in wire order: with a `mask`, `raw` (held to the field's largest value) shifted
    /// into the field and the other bits 0, so values sharing a register can be ORed together.
    pub fn encode(&self, raw: f64) -> Vec<u16> {
        match self.mask {
            Some(mask) => {
                let shift = mask.trailing_zeros();
                let largest = f64::from(mask >> shift);
                let field = (raw.clamp(0.0, largest) as u32) << shift & mask;
                self.kind.encode(f64::from(field), self.low_first)
            }
            None => self.kind.encode(raw, self.low_first),
        }
    }
}

/// The status values a template can name (the drive's state, as every front end shows it).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StatusMap {
    /// The fault code in force (0: none).
    pub fault: Option<RegisterValue>,
    /// Running.
    pub running: Option<RegisterValue>,
    /// Turning in reverse.
    pub reverse: Option<RegisterValue>,
    /// Output frequency, Hz.
    pub output_hz: Option<RegisterValue>,
    /// Setpoint, Hz.
    pub setpoint_hz: Option<RegisterValue>,
    /// Motor current, A.
    pub current_a: Option<RegisterValue>,
    /// A flag set while the drive is tripped: where given, the fault code shows only while it is
    /// set (a drive whose fault code register keeps the last fault after a reset).
    pub tripped: Option<RegisterValue>,
    /// The values beyond these (`[values]`: DC-bus voltage, power, temperature, ...), in the
    /// file's name order.
    pub extra: Vec<ExtraValue>,
}

/// A status value beyond the six every front end shows: its name, unit and register.
#[derive(Clone, Debug, PartialEq)]
pub struct ExtraValue {
    /// The name (`dc_bus_v`), as views and `/api/drives` show it.
    pub name: String,
    /// Its unit (`V`), or empty.
    pub unit: String,
    /// Where it is and how it is coded.
    pub value: RegisterValue,
}

impl StatusMap {
    /// The names a file may use under `[status]`.
    pub const NAMES: [&'static str; 7] =
        ["fault", "running", "reverse", "output_hz", "setpoint_hz", "current_a", "tripped"];

    /// Every value given, with its name, the `[values]` ones last.
    pub fn values(&self) -> impl Iterator<Item = (&str, &RegisterValue)> {
        [
            ("fault", &self.fault),
            ("running", &self.running),
            ("reverse", &self.reverse),
            ("output_hz", &self.output_hz),
            ("setpoint_hz", &self.setpoint_hz),
            ("current_a", &self.current_a),
            ("tripped", &self.tripped),
        ]
        .into_iter()
        .filter_map(|(n, v)| v.as_ref().map(|v| (n, v)))
        .chain(self.extra.iter().map(|e| (e.name.as_str(), &e.value)))
    }

    fn slot(&mut self, name: &str) -> Option<&mut Option<RegisterValue>> {
        Some(match name {
            "fault" => &mut self.fault,
            "running" => &mut self.running,
            "reverse" => &mut self.reverse,
            "output_hz" => &mut self.output_hz,
            "setpoint_hz" => &mut self.setpoint_hz,
            "current_a" => &mut self.current_a,
            "tripped" => &mut self.tripped,
            _ => return None,
        })
    }
}

/// One register a command (or the setpoint) writes, with its value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RegisterWrite {
    /// The register.
    pub register: u16,
    /// The value written to it.
    pub value: u16,
}

/// The requests of `writes`, in order: each run of registers that follow one another (register
/// = the previous one + 1) is one 10 write of at most 16 registers, any other register its own
/// write. Each item is the first register and the values written from it.
pub fn write_groups(writes: &[RegisterWrite]) -> Vec<(u16, Vec<u16>)> {
    let mut groups: Vec<(u16, Vec<u16>)> = Vec::new();
    for w in writes {
        match groups.last_mut() {
            Some((start, values))
                if values.len() < 16 && u32::from(*start) + values.len() as u32 == u32::from(w.register) =>
            {
                values.push(w.value)
            }
            _ => groups.push((w.register, vec![w.value])),
        }
    }
    groups
}

/// A command: a value written to the command register, a bit of the command word, or writes to
/// several registers.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum CommandValue {
    /// This value is written.
    Value(u16),
    /// This bit of the command word is set (the other bits as last written).
    Bit(u8),
    /// These registers are written, in order (adjacent ones in one write).
    Writes(Vec<RegisterWrite>),
}

/// `[command]`: how the drive is run, stopped, reversed, reset and jogged.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CommandMap {
    /// The command register (the value and bit forms; `None` where every command names its
    /// registers).
    pub register: Option<u16>,
    /// Run (in the direction last commanded).
    pub run: Option<CommandValue>,
    /// Stop.
    pub stop: Option<CommandValue>,
    /// Run forward (the value form: what Reverse writes to a drive turning in reverse; the writes
    /// form: the direction set to forward).
    pub forward: Option<CommandValue>,
    /// Run in reverse (bit form: the direction bit; writes form: the direction set to reverse).
    pub reverse: Option<CommandValue>,
    /// Fault reset (bit form: set, then cleared).
    pub reset: Option<CommandValue>,
    /// Jog.
    pub jog: Option<CommandValue>,
    /// The command word's other bits, in the bit form.
    pub idle: u16,
    /// Reverse is refused while the drive is stopped (a drive whose reverse command starts it).
    pub reverse_needs_running: bool,
}

impl CommandMap {
    /// Whether the commands are bits of a command word.
    pub fn is_bits(&self) -> bool {
        self.all().any(|(_, c)| matches!(c, CommandValue::Bit(_)))
    }

    /// Whether the commands are writes to several registers.
    pub fn is_writes(&self) -> bool {
        self.all().any(|(_, c)| matches!(c, CommandValue::Writes(_)))
    }

    /// Every command given, with its name, in the order a drive carries them out when several
    /// hold at once (reset, stop, forward, reverse, run, jog).
    pub fn all(&self) -> impl Iterator<Item = (&'static str, &CommandValue)> {
        [
            ("reset", &self.reset),
            ("stop", &self.stop),
            ("forward", &self.forward),
            ("reverse", &self.reverse),
            ("run", &self.run),
            ("jog", &self.jog),
        ]
        .into_iter()
        .filter_map(|(n, c)| c.as_ref().map(|c| (n, c)))
    }
}

/// `[setpoint]`: where the speed setpoint is written and how it is scaled.
#[derive(Clone, Debug, PartialEq)]
pub struct SetpointMap {
    /// The register.
    pub register: u16,
    /// Its coding.
    pub kind: ValueType,
    /// Two-register values: the low word comes first.
    pub low_first: bool,
    /// Hz per count (0.01; or max_hz / full_scale for "0x4000 = 100 % of maximum frequency").
    pub scale: f64,
    /// The highest setpoint, Hz, where the file gives it.
    pub max_hz: Option<f64>,
    /// Parameters the setpoint may not exceed (the lowest of them), by name.
    pub limit_params: Vec<String>,
    /// Other registers written with every setpoint, after its own (`writes`).
    pub writes: Vec<RegisterWrite>,
    /// The direction is the setpoint's sign: a negative setpoint runs the drive in reverse
    /// (`reverse = "negative"`).
    pub reverse_negative: bool,
}

/// A checked template: one drive model's Modbus map.
#[derive(Clone, Debug, PartialEq)]
pub struct Template {
    /// The drive kind it adds (`--drive`, `family = "..."`).
    pub kind: String,
    /// Who makes the drive.
    pub maker: String,
    /// The model (or series).
    pub model: String,
    /// The document its map comes from.
    pub source: String,
    /// How far it has been checked.
    pub checked: Checked,
    /// A remark.
    pub note: Option<String>,
    /// The protocols it speaks, the default first (Modbus RTU and ASCII; Modbus TCP is a bus
    /// setting open to every Modbus drive).
    pub protocols: Vec<WireProtocol>,
    /// The addresses a drive can have.
    pub addresses: (u8, u8),
    /// The most registers one read may span.
    pub max_read: u16,
    /// Factory baud rate.
    pub baud: u32,
    /// Factory character format, per protocol (the first protocol's is the default).
    pub formats: Vec<(WireProtocol, CharFormat)>,
    /// The status values.
    pub status: StatusMap,
    /// The command word.
    pub command: Option<CommandMap>,
    /// The setpoint.
    pub setpoint: Option<SetpointMap>,
    /// The parameters (their `number` is the register).
    pub params: Vec<ParamDef>,
    /// How each parameter is coded in its registers, by register.
    pub param_codings: BTreeMap<u32, ParamCoding>,
    /// The fault codes and their text.
    pub faults: BTreeMap<u32, String>,
    /// The parameters holding the last faults' codes, newest first (`fault_history`).
    pub fault_history: Vec<String>,
    /// The file it was read from.
    pub file: String,
}

impl Template {
    /// Reads and checks the template in `text`; `file` names it in errors. Every problem found
    /// is reported, each with its line.
    pub fn from_toml_str(file: &str, text: &str) -> Result<Template, TemplateError> {
        check::check(file, text)
    }

    /// Reads and checks the template file at `path`.
    pub fn load(path: &std::path::Path) -> Result<Template, TemplateError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| TemplateError {
            file: file.clone(),
            errors: vec![(0, format!("cannot read it: {e}"))],
        })?;
        Template::from_toml_str(&file, &text)
    }

    /// The text of a fault code: the template's, or a sentence saying it has none.
    pub fn fault_text(&self, code: u32) -> String {
        self.faults
            .get(&code)
            .cloned()
            .unwrap_or_else(|| format!("fault code {code} (not in the template's fault list)"))
    }

    /// How parameter `def` is coded in its registers (`type` and `word_order`).
    pub fn param_coding(&self, def: &ParamDef) -> ParamCoding {
        self.param_codings.get(&def.number).copied().unwrap_or(ParamCoding {
            kind: match (def.size, def.min < 0) {
                (crate::Size::Dword, true) => ValueType::I32,
                (crate::Size::Dword, false) => ValueType::U32,
                (_, true) => ValueType::I16,
                _ => ValueType::U16,
            },
            low_first: false,
        })
    }

    /// The registers that hold `raw` (the parameter's raw integer) of parameter `def`, in wire
    /// order; an f32 parameter holds the value in its unit.
    pub fn param_words(&self, def: &ParamDef, raw: i64) -> Vec<u16> {
        let c = self.param_coding(def);
        let v = if c.kind == ValueType::F32 { def.from_raw(raw) } else { raw as f64 };
        c.kind.encode(v, c.low_first)
    }

    /// The raw integer of parameter `def` from its registers (an f32 rounded to the
    /// parameter's scale).
    pub fn param_raw(&self, def: &ParamDef, words: &[u16]) -> i64 {
        let c = self.param_coding(def);
        let v = c.kind.decode(words, c.low_first);
        if c.kind == ValueType::F32 {
            (v * 10f64.powi(i32::from(def.scale))).round() as i64
        } else {
            v as i64
        }
    }

    /// The serial defaults on `protocol`.
    pub fn serial_default(&self, protocol: WireProtocol) -> (u32, CharFormat) {
        let format = self
            .formats
            .iter()
            .find(|(p, _)| *p == protocol)
            .or(self.formats.first())
            .map_or(CharFormat::NONE_8N1, |(_, f)| *f);
        (self.baud, format)
    }
}

/// How a parameter is coded in its registers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ParamCoding {
    /// Its type.
    pub kind: ValueType,
    /// Two-register values: the low word comes first.
    pub low_first: bool,
}

/// A template file that cannot be used: every error found, each with its line.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TemplateError {
    /// The file.
    pub file: String,
    /// Each error: its line (1-based; 0 for the file as a whole) and what is wrong.
    pub errors: Vec<(usize, String)>,
}

impl fmt::Display for TemplateError {
    /// One line per error: `FILE:LINE: what is wrong`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, (line, message)) in self.errors.iter().enumerate() {
            if i > 0 {
                f.write_str("\n")?;
            }
            match line {
                0 => write!(f, "{}: {message}", self.file)?,
                n => write!(f, "{}:{n}: {message}", self.file)?,
            }
        }
        Ok(())
    }
}

impl std::error::Error for TemplateError {}
