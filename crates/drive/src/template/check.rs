//! The checks of a template file: every field read, every error kept with its line, so one
//! `drivebus template check` lists all of them.

use std::collections::{BTreeMap, HashMap};
use std::ops::Range;

use drivebus_proto::line::CharFormat;
use drivebus_proto::protocol::WireProtocol;
use toml::Spanned;

use super::file::{FileCommandValue, FileParam, FileTemplate, FileValue};
use super::{
    Checked, CommandMap, CommandValue, ExtraValue, ParamCoding, RegisterTable, RegisterValue, RegisterWrite,
    SetpointMap, StatusMap, Template, TemplateError, ValueType,
};
use crate::{Choice, Family, ParamDef, Size, Storage};

/// The errors found so far, with the text to find their lines in.
struct Errors<'a> {
    text: &'a str,
    list: Vec<(usize, String)>,
}

impl Errors<'_> {
    fn line(&self, span: Range<usize>) -> usize {
        1 + self.text[..span.start.min(self.text.len())].matches('\n').count()
    }

    fn at(&mut self, span: Range<usize>, message: impl Into<String>) {
        let line = self.line(span);
        self.list.push((line, message.into()));
    }
}

/// Reads and checks a template.
pub(super) fn check(file: &str, text: &str) -> Result<Template, TemplateError> {
    let mut e = Errors { text, list: Vec::new() };
    let raw: FileTemplate = match toml::from_str(text) {
        Ok(raw) => raw,
        Err(err) => {
            let line = err.span().map_or(0, |s| e.line(s));
            let message = err.message().trim_end().to_string();
            return Err(TemplateError { file: file.to_string(), errors: vec![(line, message)] });
        }
    };
    let template = read(&mut e, file, raw);
    if e.list.is_empty() {
        Ok(template)
    } else {
        e.list.sort_by_key(|(line, _)| *line);
        Err(TemplateError { file: file.to_string(), errors: e.list })
    }
}

fn read(e: &mut Errors<'_>, file: &str, raw: FileTemplate) -> Template {
    let kind = raw.kind.get_ref().trim().to_string();
    let good_name = !kind.is_empty()
        && kind.len() <= 40
        && kind.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'-' || b == b'_')
        && kind.as_bytes()[0].is_ascii_lowercase();
    if !good_name {
        e.at(
            raw.kind.span(),
            format!("kind {kind:?}: use lower-case letters, digits, - and _ (a letter first)"),
        );
    } else if Family::ALL.iter().any(|f| f.as_str() == kind) || kind == "auto" {
        e.at(
            raw.kind.span(),
            format!("kind {kind:?} is a built-in family's name: give the template its own"),
        );
    }
    for (field, value) in [("maker", &raw.maker), ("model", &raw.model), ("source", &raw.source)] {
        if value.get_ref().trim().is_empty() {
            e.at(
                value.span(),
                format!(
                    "{field} is empty: say {}",
                    match field {
                        "source" => "which public document the register map comes from",
                        _ => "whose drive this is",
                    }
                ),
            );
        }
    }
    let checked = match raw.checked.as_ref().map(|c| c.get_ref().as_str()) {
        None | Some("simulator") => Checked::Simulator,
        Some("hardware") => Checked::Hardware,
        Some(other) => {
            let span = raw.checked.as_ref().map(Spanned::span).unwrap_or_default();
            e.at(span, format!("checked {other:?}: use \"simulator\" or \"hardware\""));
            Checked::Simulator
        }
    };
    let mut protocols = Vec::new();
    for p in raw.protocols.get_ref() {
        match p.get_ref().parse::<WireProtocol>() {
            Ok(w) if w.is_modbus() => {
                if protocols.contains(&w) {
                    e.at(p.span(), format!("protocol {w} is listed twice"));
                }
                protocols.push(w)
            }
            _ if p.get_ref() == "modbus-tcp" => e.at(
                p.span(),
                "modbus-tcp is the bus's choice, not the drive's: list modbus-rtu (any Modbus drive is reached over Modbus TCP)",
            ),
            _ => e.at(p.span(), format!("protocol {:?}: a template speaks modbus-rtu or modbus-ascii", p.get_ref())),
        }
    }
    if raw.protocols.get_ref().is_empty() {
        e.at(
            raw.protocols.span(),
            "protocols is empty: give modbus-rtu, modbus-ascii or both (the first is the default)",
        );
    }
    let addresses = match &raw.addresses {
        None => (1, 247),
        Some(a) => {
            let [lo, hi] = *a.get_ref();
            if !(0..=255).contains(&lo) || !(0..=255).contains(&hi) || lo > hi || lo == 0 {
                e.at(a.span(), format!("addresses [{lo}, {hi}]: give [lowest, highest] within 1..255"));
                (1, 247)
            } else {
                (lo as u8, hi as u8)
            }
        }
    };
    let max_read = match &raw.max_read {
        None => 125,
        Some(m) if (1..=125).contains(m.get_ref()) => *m.get_ref() as u16,
        Some(m) => {
            e.at(m.span(), format!("max_read {}: a Modbus read takes 1..125 registers", m.get_ref()));
            125
        }
    };
    let serial = raw.serial.get_ref();
    let baud = *serial.baud.get_ref();
    if !(300..=1_000_000).contains(&baud) {
        e.at(serial.baud.span(), format!("baud {baud} is not in 300..1000000"));
    }
    let mut formats = Vec::new();
    let format_of = |e: &mut Errors<'_>, s: &Spanned<String>| match s.get_ref().parse::<CharFormat>() {
        Ok(f) => Some(f),
        Err(err) => {
            e.at(s.span(), format!("format {:?}: {err}", s.get_ref()));
            None
        }
    };
    let default_format = format_of(e, &serial.format).unwrap_or(CharFormat::NONE_8N1);
    for &p in &protocols {
        formats.push((p, default_format));
    }
    for (name, f) in &serial.formats {
        let Some(format) = format_of(e, f) else { continue };
        match name.parse::<WireProtocol>() {
            Ok(p) if protocols.contains(&p) => {
                if let Some(slot) = formats.iter_mut().find(|(q, _)| *q == p) {
                    slot.1 = format;
                }
            }
            _ => e.at(f.span(), format!("formats: {name:?} is not one of the template's protocols")),
        }
    }

    let mut status = StatusMap::default();
    for (name, v) in raw.status.get_ref() {
        let flag = is_flag(name);
        let value = value(e, &format!("status.{name}"), v, flag);
        if let Some(u) = &v.get_ref().unit {
            e.at(
                u.span(),
                format!("status.{name}: a unit is for [values]; the six status values have theirs"),
            );
        }
        match status.slot(name) {
            Some(slot) => *slot = value,
            None => e.at(v.span(), format!("status value {name:?}: use {}", StatusMap::NAMES.join(", "))),
        }
    }
    if status.running.is_none() && status.output_hz.is_none() {
        e.at(raw.status.span(), "[status] gives neither running nor output_hz: a drive's state needs one");
    }
    let mut extra = Vec::new();
    if let Some(values) = &raw.values {
        for (name, v) in values.get_ref() {
            let good = !name.is_empty()
                && name.len() <= 40
                && name.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_')
                && name.as_bytes()[0].is_ascii_lowercase();
            if !good {
                e.at(v.span(), format!("value {name:?}: use lower-case letters, digits and _ (a letter first), with its unit last: dc_bus_v, power_kw"));
                continue;
            }
            if StatusMap::NAMES.contains(&name.as_str()) {
                e.at(v.span(), format!("value {name:?} is a [status] value: give it there"));
                continue;
            }
            let what = format!("values.{name}");
            let Some(value) = value(e, &what, v, false) else { continue };
            let unit = v.get_ref().unit.as_ref().map_or(String::new(), |u| u.get_ref().trim().to_string());
            extra.push(ExtraValue { name: name.clone(), unit, value });
        }
    }
    status.extra = extra;
    let mut all: Vec<(String, &Spanned<FileValue>)> =
        raw.status.get_ref().iter().map(|(n, v)| (n.clone(), v)).collect();
    if let Some(values) = &raw.values {
        all.extend(values.get_ref().iter().map(|(n, v)| (format!("values.{n}"), v)));
    }
    check_flag_bits(e, &all);

    let (params, param_codings) = params(e, &raw.param);
    let command = raw.command.as_ref().map(|c| command(e, c));
    let setpoint = raw.setpoint.as_ref().map(|s| setpoint(e, s, &params));
    if let (Some(sp), Some(c), Some(raw_c)) = (&setpoint, &command, &raw.command) {
        let own = sp.register..sp.register.saturating_add(sp.kind.words());
        for (name, v) in c.all() {
            let CommandValue::Writes(writes) = v else { continue };
            if let Some((i, w)) = writes.iter().enumerate().find(|(_, w)| own.contains(&w.register)) {
                e.at(
                    raw_c.span(),
                    format!(
                        "command.{name}: write {}: register {} is the setpoint's: give the setpoint under [setpoint]",
                        i + 1,
                        w.register
                    ),
                );
            }
        }
        if sp.reverse_negative && (c.reverse.is_some() || c.forward.is_some()) {
            e.at(
                raw_c.span(),
                "[command]: the direction is the setpoint's sign here (setpoint.reverse = \"negative\"): leave reverse and forward out",
            );
        }
    }
    let mut fault_history = Vec::new();
    for name in &raw.fault_history {
        match params.iter().find(|d| d.name.eq_ignore_ascii_case(name.get_ref())) {
            Some(d) => fault_history.push(d.name.clone()),
            None => e.at(
                name.span(),
                format!(
                    "fault_history: {:?} is not one of the template's parameters: list the [[param]]s holding the last faults, newest first",
                    name.get_ref()
                ),
            ),
        }
    }
    if !raw.fault_history.is_empty() && status.fault.is_none() {
        e.at(raw.fault_history[0].span(), "fault_history needs status.fault: the codes are the fault list's");
    }
    let mut faults = BTreeMap::new();
    if let Some(f) = &raw.faults {
        for (code, text) in f.get_ref() {
            let parsed = match code.strip_prefix("0x").or_else(|| code.strip_prefix("0X")) {
                Some(hex) => u32::from_str_radix(hex, 16).ok(),
                None => code.parse::<u32>().ok(),
            };
            let field = status.fault.as_ref().and_then(|f| f.mask).map(|m| m >> m.trailing_zeros());
            match parsed {
                Some(c) if field.is_some_and(|largest| c > largest) => e.at(
                    text.span(),
                    format!(
                        "fault {code}: status.fault's mask holds 0..{} (a code this large never shows)",
                        field.unwrap_or(0)
                    ),
                ),
                Some(c) if !text.get_ref().trim().is_empty() => {
                    faults.insert(c, text.get_ref().clone());
                }
                Some(_) => e.at(text.span(), format!("fault {code}: the text is empty")),
                None => e.at(text.span(), format!("fault code {code:?} is not a number (decimal or 0x hex)")),
            }
        }
    }
    Template {
        kind,
        maker: raw.maker.into_inner(),
        model: raw.model.into_inner(),
        source: raw.source.into_inner(),
        checked,
        note: raw.note,
        protocols,
        addresses,
        max_read,
        baud: baud.clamp(300, 1_000_000) as u32,
        formats,
        status,
        command,
        setpoint,
        params,
        param_codings,
        faults,
        fault_history,
        file: file.to_string(),
    }
}

/// A register number, or an error.
fn register(e: &mut Errors<'_>, what: &str, r: &Spanned<i64>, words: u16) -> u16 {
    let n = *r.get_ref();
    if n < 0 || n + i64::from(words) - 1 > 0xFFFF {
        e.at(r.span(), format!("{what}: register {n} is not a Modbus register (0..65535, 0x0000..0xFFFF)"));
        return 0;
    }
    n as u16
}

fn value_type(e: &mut Errors<'_>, what: &str, t: &Option<Spanned<String>>) -> ValueType {
    match t {
        None => ValueType::U16,
        Some(t) => ValueType::parse(t.get_ref()).unwrap_or_else(|| {
            e.at(t.span(), format!("{what}: unknown type {:?}: use {}", t.get_ref(), ValueType::NAMES));
            ValueType::U16
        }),
    }
}

fn word_order(e: &mut Errors<'_>, what: &str, w: &Option<Spanned<String>>) -> bool {
    match w.as_ref().map(|w| w.get_ref().as_str()) {
        None | Some("high-first") => false,
        Some("low-first") => true,
        Some(other) => {
            let span = w.as_ref().map(Spanned::span).unwrap_or_default();
            e.at(span, format!("{what}: word_order {other:?}: use \"high-first\" or \"low-first\""));
            false
        }
    }
}

/// A scale given directly or as `full_scale` counts = `max` units.
fn scaling(
    e: &mut Errors<'_>,
    what: &str,
    scale: &Option<Spanned<f64>>,
    full_scale: &Option<Spanned<f64>>,
    max: &Option<Spanned<f64>>,
) -> f64 {
    match (scale, full_scale, max) {
        (Some(s), None, _) => {
            let v = *s.get_ref();
            if v == 0.0 || !v.is_finite() {
                e.at(
                    s.span(),
                    format!("{what}: scale of {v}: give the units per count, never zero (0.01 for 0.01 Hz)"),
                );
                1.0
            } else {
                v
            }
        }
        (None, Some(f), Some(m)) => {
            let (f_v, m_v) = (*f.get_ref(), *m.get_ref());
            if f_v <= 0.0 || !f_v.is_finite() {
                e.at(
                    f.span(),
                    format!("{what}: full_scale {f_v} must be a count above zero (0x4000 = 16384)"),
                );
                return 1.0;
            }
            if m_v <= 0.0 || !m_v.is_finite() {
                e.at(m.span(), format!("{what}: max {m_v} must be above zero"));
                return 1.0;
            }
            m_v / f_v
        }
        (None, Some(f), None) => {
            e.at(f.span(), format!("{what}: full_scale needs the value it stands for (max = ...)"));
            1.0
        }
        (Some(s), Some(_), _) => {
            e.at(s.span(), format!("{what}: give scale or full_scale, not both"));
            1.0
        }
        (None, None, Some(m)) => {
            e.at(m.span(), format!("{what}: max goes with full_scale"));
            1.0
        }
        (None, None, None) => 1.0,
    }
}

fn decimals(scale: f64) -> i32 {
    ((-scale.abs().log10()) - 1e-9).ceil().clamp(0.0, 9.0) as i32
}

/// Whether the `[status]` value `name` is a flag (a bit, or any value but zero).
fn is_flag(name: &str) -> bool {
    matches!(name, "running" | "reverse" | "tripped")
}

fn value(e: &mut Errors<'_>, what: &str, v: &Spanned<FileValue>, flag: bool) -> Option<RegisterValue> {
    let f = v.get_ref();
    let what = what.to_string();
    let kind = value_type(e, &what, &f.kind);
    let reg = register(e, &what, &f.register, kind.words());
    let table = match f.table.as_ref().map(|t| t.get_ref().as_str()) {
        None | Some("holding") => RegisterTable::Holding,
        Some("input") => RegisterTable::Input,
        Some(other) => {
            let span = f.table.as_ref().map(Spanned::span).unwrap_or_default();
            e.at(span, format!("{what}: table {other:?}: use \"holding\" (03) or \"input\" (04)"));
            RegisterTable::Holding
        }
    };
    let low_first = word_order(e, &what, &f.word_order);
    let scale = scaling(e, &what, &f.scale, &f.full_scale, &f.max);
    let offset = f.offset.as_ref().map_or(0.0, |o| *o.get_ref());
    let bit = match &f.bit {
        None => None,
        Some(b) => {
            let width = 16 * i64::from(kind.words());
            if !flag {
                e.at(
                    b.span(),
                    format!("{what}: a bit makes a flag; only running, reverse and tripped are flags"),
                );
                None
            } else if kind == ValueType::F32 || !(0..width).contains(b.get_ref()) {
                e.at(
                    b.span(),
                    format!(
                        "{what}: bit {} is not a bit of a {kind:?} value (0..{})",
                        b.get_ref(),
                        width - 1
                    ),
                );
                None
            } else {
                Some(*b.get_ref() as u8)
            }
        }
    };
    let mask = f.mask.as_ref().and_then(|m| field_mask(e, &what, m, kind, f.bit.is_some()));
    Some(RegisterValue {
        register: reg,
        table,
        kind,
        low_first,
        scale,
        offset,
        bit,
        mask,
        decimals: decimals(scale),
    })
}

/// A `mask`: bits that follow one another, within an unsigned integer type, not with `bit`.
fn field_mask(e: &mut Errors<'_>, what: &str, m: &Spanned<i64>, kind: ValueType, bit: bool) -> Option<u32> {
    let mask = *m.get_ref();
    let widest = match kind {
        ValueType::U16 => 0xFFFF,
        ValueType::U32 => 0xFFFF_FFFF,
        _ => {
            e.at(
                m.span(),
                format!(
                    "{what}: a mask takes an unsigned field: give type = \"u16\" or \"u32\" (not {kind:?})"
                ),
            );
            return None;
        }
    };
    if bit {
        e.at(m.span(), format!("{what}: give bit or mask, not both (a flag of one bit is bit = N)"));
        return None;
    }
    if mask == 0 {
        e.at(
            m.span(),
            format!("{what}: mask 0x0 takes no bit: give the field's bits (0xFF00: the high byte)"),
        );
        return None;
    }
    if !(1..=widest).contains(&mask) {
        e.at(
            m.span(),
            format!(
                "{what}: mask {} is wider than a {kind:?} (0x1..{widest:#X})",
                if mask < 0 { mask.to_string() } else { format!("{mask:#X}") }
            ),
        );
        return None;
    }
    let mask = mask as u32;
    if (mask >> mask.trailing_zeros()).count_ones() != (mask >> mask.trailing_zeros()).trailing_ones() {
        e.at(
            m.span(),
            format!("{what}: mask {mask:#06X} has gaps: a field's bits follow one another (0x00FF, 0xFF00, 0x0070)"),
        );
        return None;
    }
    Some(mask)
}

/// Two values on the same bits of a register: two numbers in the same register, two flags on the
/// same bit, a `mask` field overlapping another field, number or flag bit. A flag without a bit
/// (any value but zero) is not checked.
fn check_flag_bits(e: &mut Errors<'_>, status: &[(String, &Spanned<FileValue>)]) {
    // The bits of each register taken so far, and by whom.
    let mut taken: HashMap<(i64, String), Vec<(u16, &str)>> = HashMap::new();
    // In file order: the later of two is the one reported.
    let mut in_order: Vec<_> = status.iter().map(|(n, v)| (n.as_str(), *v)).collect();
    in_order.sort_by_key(|(_, v)| v.span().start);
    let label =
        |name: &str| if name.starts_with("values.") { name.to_string() } else { format!("status.{name}") };
    for (name, v) in in_order {
        let f = v.get_ref();
        let words: i64 = match f.kind.as_ref().map(|k| k.get_ref().as_str()) {
            Some("u32" | "i32" | "f32") => 2,
            _ => 1,
        };
        let low_first = f.word_order.as_ref().is_some_and(|w| w.get_ref() == "low-first");
        // The value's bits, as one number of 16 × words bits; where the error is reported.
        let (bits, span, what): (u64, _, String) = match (&f.bit, &f.mask) {
            (Some(b), _) if (0..16 * words).contains(b.get_ref()) => {
                (1 << b.get_ref(), b.span(), format!("bit {}", b.get_ref()))
            }
            (Some(_), _) => continue,
            (None, Some(m)) if *m.get_ref() > 0 && *m.get_ref() < 1 << (16 * words) => {
                (*m.get_ref() as u64, m.span(), format!("mask {:#06X}", m.get_ref()))
            }
            (None, Some(_)) => continue,
            (None, None) if is_flag(name) => continue,
            (None, None) => (u64::MAX >> (64 - 16 * words), f.register.span(), String::new()),
        };
        let table = f.table.as_ref().map_or("holding".to_string(), |t| t.get_ref().clone());
        for i in 0..words {
            // The word at register + i: the high word first unless low-first.
            let shift = if words == 2 && (i == 0) != low_first { 16 } else { 0 };
            let word = (bits >> shift) as u16;
            if word == 0 {
                continue;
            }
            let r = *f.register.get_ref() + i;
            let slot = taken.entry((r, table.clone())).or_default();
            if let Some((_, other)) = slot.iter().find(|(b, _)| b & word != 0) {
                let message = if what.is_empty() {
                    format!("{}: register {r} overlaps {}'s", label(name), label(other))
                } else {
                    format!("{}: {what} overlaps {}'s (register {r})", label(name), label(other))
                };
                e.at(span.clone(), message);
                break;
            }
            slot.push((word, name));
        }
    }
}

/// One `{ register = R, value = V }` of a list of writes (`what` names the list), or an error
/// at `span`.
fn register_write(
    e: &mut Errors<'_>,
    what: &str,
    index: usize,
    w: &super::file::FileWrite,
    span: Range<usize>,
) -> Option<RegisterWrite> {
    let n = index + 1;
    if !(0..=0xFFFF).contains(&w.register) {
        e.at(
            span,
            format!(
                "{what}: write {n}: register {} is not a Modbus register (0..65535, 0x0000..0xFFFF)",
                w.register
            ),
        );
        return None;
    }
    if !(0..=0xFFFF).contains(&w.value) {
        e.at(span, format!("{what}: write {n}: value {} does not fit a register (0..65535)", w.value));
        return None;
    }
    Some(RegisterWrite { register: w.register as u16, value: w.value as u16 })
}

fn command(e: &mut Errors<'_>, c: &Spanned<super::file::FileCommand>) -> CommandMap {
    let f = c.get_ref();
    let reg = f.register.as_ref().map(|r| register(e, "command", r, 1));
    let mut bits: HashMap<i64, &str> = HashMap::new();
    let (mut values, mut bitwise, mut writes) = (false, false, false);
    let mut one = |e: &mut Errors<'_>, name: &'static str, v: &Option<Spanned<FileCommandValue>>| {
        let v = v.as_ref()?;
        match v.get_ref() {
            FileCommandValue::Value(n) if (0..=0xFFFF).contains(n) => {
                values = true;
                Some(CommandValue::Value(*n as u16))
            }
            FileCommandValue::Value(n) => {
                e.at(v.span(), format!("command.{name}: {n} does not fit a register (0..65535)"));
                None
            }
            FileCommandValue::Bit { bit } if (0..16).contains(bit) => {
                bitwise = true;
                if let Some(other) = bits.insert(*bit, name) {
                    e.at(v.span(), format!("command.{name}: bit {bit} overlaps command.{other}'s"));
                }
                Some(CommandValue::Bit(*bit as u8))
            }
            FileCommandValue::Bit { bit } => {
                e.at(v.span(), format!("command.{name}: bit {bit} is not a bit of a register (0..15)"));
                None
            }
            FileCommandValue::Writes(list) => {
                writes = true;
                if list.is_empty() {
                    e.at(
                        v.span(),
                        format!("command.{name}: no writes: give [{{ register = R, value = V }}, ...]"),
                    );
                    return None;
                }
                let what = format!("command.{name}");
                let out: Vec<_> = list
                    .iter()
                    .enumerate()
                    .filter_map(|(i, w)| register_write(e, &what, i, w, v.span()))
                    .collect();
                (out.len() == list.len()).then_some(CommandValue::Writes(out))
            }
        }
    };
    let run = one(e, "run", &f.run);
    let stop = one(e, "stop", &f.stop);
    let forward = one(e, "forward", &f.forward);
    let reverse = one(e, "reverse", &f.reverse);
    let reset = one(e, "reset", &f.reset);
    let jog = one(e, "jog", &f.jog);
    if [values, bitwise, writes].iter().filter(|f| **f).count() > 1 {
        e.at(
            c.span(),
            "[command]: give every command as a value, every one as { bit = N }, or every one as writes ([{ register = R, value = V }, ...]), not a mix",
        );
    }
    match &f.register {
        None if values || bitwise => {
            e.at(c.span(), "[command] needs register: the command register the values or bits are written to")
        }
        Some(r) if writes && !values && !bitwise => e.at(
            r.span(),
            "command.register: every command here names its own registers (writes): leave register out",
        ),
        _ => {}
    }
    // A command given but bad has its own error already.
    if f.run.is_none() || (f.stop.is_none() && !bitwise) {
        e.at(c.span(), "[command] needs run and stop (in the bit form, stop clears run's bit)");
    }
    if writes && reverse.is_some() != forward.is_some() {
        e.at(
            c.span(),
            "[command]: in the writes form give reverse and forward together (the writes that set each direction)",
        );
    }
    let idle = match &f.idle {
        None => 0,
        Some(i) if (0..=0xFFFF).contains(i.get_ref()) => *i.get_ref() as u16,
        Some(i) => {
            e.at(i.span(), format!("command.idle {} does not fit a register", i.get_ref()));
            0
        }
    };
    CommandMap {
        register: reg,
        run,
        stop,
        forward,
        reverse,
        reset,
        jog,
        idle,
        reverse_needs_running: f.reverse_needs_running,
    }
}

fn setpoint(e: &mut Errors<'_>, s: &Spanned<super::file::FileSetpoint>, params: &[ParamDef]) -> SetpointMap {
    let f = s.get_ref();
    let kind = value_type(e, "setpoint", &f.kind);
    let reg = register(e, "setpoint", &f.register, kind.words());
    let low_first = word_order(e, "setpoint", &f.word_order);
    let scale = scaling(e, "setpoint", &f.scale, &f.full_scale, &f.max_hz);
    if f.scale.is_none() && f.full_scale.is_none() {
        e.at(s.span(), "[setpoint] needs scale (Hz per count) or full_scale with max_hz");
    }
    let max_hz = f.max_hz.as_ref().map(|m| *m.get_ref());
    let mut limit_params = Vec::new();
    for p in &f.limit_params {
        if params.iter().any(|d| d.name.eq_ignore_ascii_case(p.get_ref())) {
            limit_params.push(p.get_ref().clone());
        } else {
            e.at(
                p.span(),
                format!("setpoint.limit_params: {:?} is not one of the template's parameters", p.get_ref()),
            );
        }
    }
    if max_hz.is_none() && limit_params.is_empty() {
        e.at(
            s.span(),
            "[setpoint] needs a limit: max_hz, or limit_params naming the maximum frequency parameter",
        );
    }
    let mut writes = Vec::new();
    if let Some(list) = &f.writes {
        for (i, w) in list.get_ref().iter().enumerate() {
            let Some(w) = register_write(e, "setpoint.writes", i, w, list.span()) else { continue };
            if (reg..reg.saturating_add(kind.words())).contains(&w.register) {
                e.at(
                    list.span(),
                    format!(
                        "setpoint.writes: write {}: register {} is the setpoint's own",
                        i + 1,
                        w.register
                    ),
                );
                continue;
            }
            writes.push(w);
        }
        if list.get_ref().is_empty() {
            e.at(
                list.span(),
                "setpoint.writes is empty: give [{ register = R, value = V }, ...] or leave it out",
            );
        }
    }
    let reverse_negative = match f.reverse.as_ref().map(|r| (r, r.get_ref().as_str())) {
        None => false,
        Some((r, "negative")) => {
            if matches!(kind, ValueType::U16 | ValueType::U32) {
                e.at(
                    r.span(),
                    format!(
                        "setpoint.reverse = \"negative\" needs a signed type: give type = \"i16\", \"i32\" or \"f32\" (a {kind:?} has no negative)"
                    ),
                );
            }
            true
        }
        Some((r, other)) => {
            e.at(
                r.span(),
                format!("setpoint.reverse {other:?}: the one form is \"negative\" (a negative setpoint runs in reverse)"),
            );
            false
        }
    };
    SetpointMap { register: reg, kind, low_first, scale, max_hz, limit_params, writes, reverse_negative }
}

fn params(e: &mut Errors<'_>, raw: &[Spanned<FileParam>]) -> (Vec<ParamDef>, BTreeMap<u32, ParamCoding>) {
    let mut out: Vec<ParamDef> = Vec::new();
    let mut codings = BTreeMap::new();
    let mut registers: HashMap<u16, String> = HashMap::new();
    for p in raw {
        let f = p.get_ref();
        let name = f.name.get_ref().trim().to_string();
        let what = format!("parameter {name}");
        if name.is_empty() || name.chars().any(char::is_whitespace) {
            e.at(f.name.span(), format!("parameter name {name:?} is empty or has blanks"));
            continue;
        }
        if out.iter().any(|d| d.name.eq_ignore_ascii_case(&name)) {
            e.at(f.name.span(), format!("parameter {name} is listed twice"));
            continue;
        }
        let kind = value_type(e, &what, &f.kind);
        let low_first = word_order(e, &what, &f.word_order);
        if low_first && kind.words() == 1 {
            e.at(
                f.word_order.as_ref().map(Spanned::span).unwrap_or_default(),
                format!("{what}: word_order is for the 32-bit types (u32, i32, f32), not {kind:?}"),
            );
        }
        let reg = register(e, &what, &f.register, kind.words());
        for r in reg..reg.saturating_add(kind.words()) {
            if let Some(other) = registers.insert(r, name.clone()) {
                e.at(f.register.span(), format!("{what}: register {r:#06X} is also {other}'s"));
            }
        }
        let scale = f.scale.as_ref().map_or(1.0, |s| *s.get_ref());
        let places = -scale.log10();
        let decimals = places.round();
        if scale <= 0.0
            || !scale.is_finite()
            || (places - decimals).abs() > 1e-9
            || !(-9.0..=9.0).contains(&decimals)
        {
            let span = f.scale.as_ref().map(Spanned::span).unwrap_or_default();
            e.at(span, format!("{what}: scale {scale} must be a power of ten above zero (0.01, 0.1, 1, 10)"));
            continue;
        }
        let decimals = decimals as i8;
        let to_raw = |v: f64| (v * 10f64.powi(i32::from(decimals))).round() as i64;
        let [lo, hi] = *f.range.get_ref();
        let (min, max, default) = (to_raw(lo), to_raw(hi), to_raw(*f.default.get_ref()));
        let (tmin, tmax) = match kind {
            ValueType::U16 => (0, 0xFFFF),
            ValueType::I16 => (i64::from(i16::MIN), i64::from(i16::MAX)),
            ValueType::U32 => (0, i64::from(u32::MAX)),
            // An f32 holds the value itself; its raw integer (at the scale) is kept in an i32.
            _ => (i64::from(i32::MIN), i64::from(i32::MAX)),
        };
        if min > max {
            e.at(f.range.span(), format!("{what}: range [{lo}, {hi}] is upside down"));
            continue;
        }
        if min < tmin || max > tmax {
            e.at(
                f.range.span(),
                format!("{what}: range [{lo}, {hi}] does not fit a {kind:?} at scale {scale}"),
            );
            continue;
        }
        if !(min..=max).contains(&default) {
            e.at(
                f.default.span(),
                format!("{what}: default {} is outside its range [{lo}, {hi}]", f.default.get_ref()),
            );
        }
        let read_only = match f.access.as_ref().map(|a| a.get_ref().as_str()) {
            None | Some("rw") => false,
            Some("ro") => true,
            Some(other) => {
                e.at(
                    f.access.as_ref().map(Spanned::span).unwrap_or_default(),
                    format!("{what}: access {other:?}: use \"rw\" or \"ro\""),
                );
                false
            }
        };
        let storage = match f.storage.as_ref().map(|s| s.get_ref().as_str()) {
            None if read_only => Storage::Ram,
            None | Some("eeprom") => Storage::Eeprom,
            Some("ram") => Storage::Ram,
            Some(other) => {
                e.at(
                    f.storage.as_ref().map(Spanned::span).unwrap_or_default(),
                    format!("{what}: storage {other:?}: use \"eeprom\" or \"ram\""),
                );
                Storage::Eeprom
            }
        };
        let mut choices = Vec::new();
        for (k, text) in &f.choices {
            match k.parse::<i64>() {
                Ok(v) if (min..=max).contains(&v) => choices.push(Choice { value: v, text: text.clone() }),
                _ => e.at(p.span(), format!("{what}: choice {k:?} is not a raw value within its range")),
            }
        }
        choices.sort_by_key(|c| c.value);
        codings.insert(u32::from(reg), ParamCoding { kind, low_first });
        out.push(ParamDef {
            name,
            alias: None,
            title: f.title.get_ref().clone(),
            number: u32::from(reg),
            unit: f.unit.clone(),
            scale: decimals,
            min,
            max,
            default: default.clamp(min, max),
            read_only,
            storage,
            size: if kind.words() == 2 { Size::Dword } else { Size::Word },
            choices,
            array: None,
            while_running: f.while_running.unwrap_or(true),
            comm: f.comm,
            note: f.note.clone(),
            group: f.group.clone().unwrap_or_default(),
        });
    }
    (out, codings)
}
