//! One parameter's definition and the conversions between raw wire integers and values in units.

use std::fmt;

use serde::{Deserialize, Serialize};

/// Where a parameter's value lives, and where a write is asked to go.
///
/// As a property of a parameter: `Eeprom` is a setting that survives power-off, `Ram` a volatile
/// command, monitor or action. As the target of a write: `Ram` changes the running value only
/// (Toshiba `P`, FC AK 2/3), `Eeprom` also stores it (Toshiba `W`, Modbus 06 to a setting, FC AK D/E).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Storage {
    /// Volatile memory only.
    Ram,
    /// RAM and the non-volatile EEPROM.
    Eeprom,
}

impl Storage {
    /// "ram" or "eeprom", as catalog files write it.
    pub fn as_str(self) -> &'static str {
        match self {
            Storage::Ram => "ram",
            Storage::Eeprom => "eeprom",
        }
    }
}

/// The width of a parameter on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Size {
    /// 16 bits (Modbus register, Toshiba data word, FC Int16/Uint16/Uint8).
    Word,
    /// 32 bits (FC Int32/Uint32, sent with AK 3/D and answered with AK 2).
    Dword,
}

impl Size {
    /// "word" or "dword", as catalog files write it.
    pub fn as_str(self) -> &'static str {
        match self {
            Size::Word => "word",
            Size::Dword => "dword",
        }
    }

    /// The raw values a parameter of this size can hold, signed or unsigned.
    pub fn raw_limits(self) -> (i64, i64) {
        match self {
            Size::Word => (i64::from(i16::MIN), i64::from(u16::MAX)),
            Size::Dword => (i64::from(i32::MIN), i64::from(u32::MAX)),
        }
    }
}

/// One named value of a code parameter (FC 8-32 raw 2 is "9600 baud").
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Choice {
    /// The raw value.
    pub value: i64,
    /// What it means, as the manual says it.
    pub text: String,
}

/// The definition of one parameter of one drive family, as its catalog file gives it.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[non_exhaustive]
pub struct ParamDef {
    /// The name as the manual writes it: "P0.02", "0010", "f803", "4-14", "F-12".
    pub name: String,
    /// Another name the drive's panel shows, such as Toshiba's "dEC" for 0010.
    pub alias: Option<String>,
    /// What the parameter is, in the manual's words.
    pub title: String,
    /// The wire number: generic register 0xGGNN, Toshiba communication number, FC PNU, B800 index.
    pub number: u32,
    /// The unit of the scaled value: "Hz", "s", "A", "V", "rpm", "%", or "" for codes and counts.
    pub unit: String,
    /// Decimal places: value = raw x 10^-scale (2 for 0.01 Hz; negative for steps of 10, 100, ...).
    pub scale: i8,
    /// The smallest raw value the drive accepts.
    pub min: i64,
    /// The largest raw value the drive accepts.
    pub max: i64,
    /// The raw factory value.
    pub default: i64,
    /// The drive refuses every write (monitors, logs).
    pub read_only: bool,
    /// Where the value lives; writes to a `Ram` parameter never reach the EEPROM.
    pub storage: Storage,
    /// The width on the wire.
    pub size: Size,
    /// Names of raw values, in ascending order; empty for plain numbers.
    pub choices: Vec<Choice>,
    /// The number of elements of an array parameter (FC 15-30: 10); `None` for a single value.
    pub array: Option<u16>,
    /// `false` if the drive refuses writes while the motor runs (maximum frequency, motor data).
    pub while_running: bool,
    /// A communication setting (bus address, baud rate, character format, protocol, time-outs):
    /// copying it from another drive's backup would move this drive on the bus.
    pub comm: bool,
    /// A remark from the catalog: where a value comes from, what is unconfirmed.
    pub note: Option<String>,
    /// The group the parameter is listed in (the manual's chapter: "P0 basic functions",
    /// "4-** Limits / warnings"); empty when the catalog gives none.
    pub group: String,
}

impl ParamDef {
    /// The number of values the parameter holds: its array length, or 1.
    pub fn len(&self) -> usize {
        self.array.map_or(1, usize::from)
    }

    /// `true` for an array parameter with no elements, which a loaded catalog never has.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The text of a choice, if `raw` has one.
    pub fn choice(&self, raw: i64) -> Option<&str> {
        self.choices.iter().find(|c| c.value == raw).map(|c| c.text.as_str())
    }

    /// Whether the drive accepts `raw` (it lies within `min..=max`).
    pub fn contains(&self, raw: i64) -> bool {
        (self.min..=self.max).contains(&raw)
    }

    /// Checks a raw value against the range; the error reads like "4-14 is 0.0..500.0 Hz, 600.0 is out of range".
    pub fn check(&self, raw: i64) -> Result<(), RangeError> {
        if self.contains(raw) {
            Ok(())
        } else {
            Err(self.range_error(format_fixed(raw, self.scale)))
        }
    }

    /// Converts a value in `unit` to the raw integer, rounding half away from zero to the scale,
    /// and checks the range: `to_raw(50.0)` is 5000 for a 0.01 Hz parameter.
    ///
    /// The value is rounded as it is written in decimal, so 0.285 at scale 2 gives 29.
    pub fn to_raw(&self, value: f64) -> Result<i64, RangeError> {
        let shown = format!("{value}");
        if !value.is_finite() {
            return Err(self.range_error(shown));
        }
        let raw = decimal_to_raw(&shown, self.scale);
        match raw {
            Some(raw) if self.contains(raw) => Ok(raw),
            _ => Err(self.range_error(shown)),
        }
    }

    /// The value in `unit` of a raw integer: 5000 is 50.0 for a 0.01 Hz parameter.
    pub fn from_raw(&self, raw: i64) -> f64 {
        let raw = raw as f64;
        if self.scale >= 0 {
            raw / 10f64.powi(i32::from(self.scale))
        } else {
            raw * 10f64.powi(-i32::from(self.scale))
        }
    }

    /// A raw value for people: the choice text if it has one, else the scaled number and unit
    /// ("50.00 Hz", "10.0 s", "1420 rpm", "7").
    pub fn format(&self, raw: i64) -> String {
        if let Some(text) = self.choice(raw) {
            return text.to_string();
        }
        let number = format_fixed(raw, self.scale);
        if self.unit.is_empty() {
            number
        } else {
            format!("{number} {}", self.unit)
        }
    }

    /// Parses what a person typed for this parameter into a checked raw value: a choice text
    /// (any letter case, "9600 baud"), or a decimal number with or without the unit ("50", "50.00 Hz").
    pub fn parse_value(&self, text: &str) -> Result<i64, ValueError> {
        let t = text.trim();
        if let Some(c) = self.choices.iter().find(|c| c.text.eq_ignore_ascii_case(t)) {
            return Ok(c.value);
        }
        let number = strip_unit(t, &self.unit).trim_end();
        if !is_decimal(number) {
            return Err(ValueError::NotAValue {
                name: self.name.clone(),
                text: text.to_string(),
                choices: self.choices.iter().map(|c| c.text.clone()).collect(),
            });
        }
        match decimal_to_raw(number, self.scale) {
            Some(raw) if self.contains(raw) => Ok(raw),
            _ => Err(ValueError::Range(self.range_error(number.to_string()))),
        }
    }

    fn range_error(&self, value: String) -> RangeError {
        RangeError {
            name: self.name.clone(),
            value,
            min: self.min,
            max: self.max,
            scale: self.scale,
            unit: self.unit.clone(),
        }
    }
}

/// A value outside a parameter's range.
///
/// Displays as one line: "4-14 is 0.0..500.0 Hz, 600 is out of range".
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RangeError {
    /// The parameter's name.
    pub name: String,
    /// The refused value as the caller gave it (in units).
    pub value: String,
    /// The smallest raw value allowed.
    pub min: i64,
    /// The largest raw value allowed.
    pub max: i64,
    /// The parameter's scale, for showing `min` and `max` in units.
    pub scale: i8,
    /// The parameter's unit.
    pub unit: String,
}

impl fmt::Display for RangeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let min = format_fixed(self.min, self.scale);
        let max = format_fixed(self.max, self.scale);
        let unit = if self.unit.is_empty() { String::new() } else { format!(" {}", self.unit) };
        write!(f, "{} is {min}..{max}{unit}, {} is out of range", self.name, self.value)
    }
}

impl std::error::Error for RangeError {}

/// Text that [`ParamDef::parse_value`] cannot turn into a raw value.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ValueError {
    /// Neither a number nor one of the parameter's choices.
    NotAValue {
        /// The parameter's name.
        name: String,
        /// The text as given.
        text: String,
        /// The choice texts the parameter accepts besides numbers.
        choices: Vec<String>,
    },
    /// A number outside the parameter's range.
    Range(RangeError),
}

impl fmt::Display for ValueError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ValueError::NotAValue { name, text, choices } if choices.is_empty() => {
                write!(f, "{name} takes a number, not {text:?}")
            }
            ValueError::NotAValue { name, text, choices } => {
                write!(f, "{name} takes a number or one of {}, not {text:?}", choices.join(", "))
            }
            ValueError::Range(e) => e.fmt(f),
        }
    }
}

impl std::error::Error for ValueError {}

/// Writes a raw integer with `scale` decimal places ("5000" at scale 2 is "50.00"; at scale -1, "50000").
pub fn format_fixed(raw: i64, scale: i8) -> String {
    if scale <= 0 {
        let factor = 10i128.pow(u32::from(scale.unsigned_abs()));
        return (i128::from(raw) * factor).to_string();
    }
    let places = usize::from(scale.unsigned_abs());
    let divisor = 10u128.pow(u32::from(scale.unsigned_abs()));
    let magnitude = u128::from(raw.unsigned_abs());
    let sign = if raw < 0 { "-" } else { "" };
    format!("{sign}{}.{:0places$}", magnitude / divisor, magnitude % divisor)
}

fn strip_unit<'a>(text: &'a str, unit: &str) -> &'a str {
    if unit.is_empty() || text.len() < unit.len() {
        return text;
    }
    let split = text.len() - unit.len();
    match (text.get(..split), text.get(split..)) {
        (Some(head), Some(tail)) if tail.eq_ignore_ascii_case(unit) => head,
        _ => text,
    }
}

/// `[+-]digits[.digits]`, or `[+-].digits`.
fn is_decimal(text: &str) -> bool {
    let body = text.strip_prefix(['+', '-']).unwrap_or(text);
    let (int, frac) = body.split_once('.').unwrap_or((body, ""));
    let digits = |s: &str| s.bytes().all(|b| b.is_ascii_digit());
    !(int.is_empty() && frac.is_empty()) && digits(int) && digits(frac)
}

/// Exact decimal-to-raw conversion: shifts the decimal point by `scale` and rounds half away
/// from zero on the first dropped digit. `None` if the text is not a decimal or does not fit.
fn decimal_to_raw(text: &str, scale: i8) -> Option<i64> {
    if !is_decimal(text) {
        return None;
    }
    let negative = text.starts_with('-');
    let body = text.strip_prefix(['+', '-']).unwrap_or(text);
    let (int, frac) = body.split_once('.').unwrap_or((body, ""));
    let int = int.trim_start_matches('0');
    let digits: Vec<u8> = int.bytes().chain(frac.bytes()).map(|b| b - b'0').collect();
    // The decimal point sits after `point` digits; move it `scale` places to the right.
    let point = int.len() as i64 + i64::from(scale);
    let mut kept: i128 = 0;
    for i in 0..point.max(0) {
        let digit = usize::try_from(i).ok().and_then(|i| digits.get(i)).copied().unwrap_or(0);
        kept = kept.checked_mul(10)?.checked_add(i128::from(digit))?;
    }
    let next = usize::try_from(point).ok().and_then(|i| digits.get(i)).copied().unwrap_or(0);
    if next >= 5 {
        kept = kept.checked_add(1)?;
    }
    let signed = if negative { -kept } else { kept };
    i64::try_from(signed).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fixed_point_formatting() {
        assert_eq!(format_fixed(5000, 2), "50.00");
        assert_eq!(format_fixed(5, 2), "0.05");
        assert_eq!(format_fixed(-5, 2), "-0.05");
        assert_eq!(format_fixed(-4999000, 3), "-4999.000");
        assert_eq!(format_fixed(7, 0), "7");
        assert_eq!(format_fixed(75, -1), "750");
        assert_eq!(format_fixed(i64::MIN, 2), "-92233720368547758.08");
    }

    #[test]
    fn decimal_rounding() {
        assert_eq!(decimal_to_raw("50", 2), Some(5000));
        assert_eq!(decimal_to_raw("0.285", 2), Some(29));
        assert_eq!(decimal_to_raw("0.2849", 2), Some(28));
        assert_eq!(decimal_to_raw("-0.285", 2), Some(-29));
        assert_eq!(decimal_to_raw("10.05", 1), Some(101));
        assert_eq!(decimal_to_raw(".5", 0), Some(1));
        assert_eq!(decimal_to_raw("0.4", 0), Some(0));
        assert_eq!(decimal_to_raw("15", -1), Some(2));
        assert_eq!(decimal_to_raw("14.9", -1), Some(1));
        assert_eq!(decimal_to_raw("4", -1), Some(0));
        assert_eq!(decimal_to_raw("0.001", -2), Some(0));
        assert_eq!(decimal_to_raw("99999999999999999999999", 0), None);
        assert_eq!(decimal_to_raw("1e3", 0), None);
        assert_eq!(decimal_to_raw("", 0), None);
        assert_eq!(decimal_to_raw(".", 0), None);
        assert_eq!(decimal_to_raw("-", 0), None);
    }

    #[test]
    fn units_are_stripped_case_insensitively() {
        assert_eq!(strip_unit("50 Hz", "Hz"), "50 ");
        assert_eq!(strip_unit("50hz", "Hz"), "50");
        assert_eq!(strip_unit("50", "Hz"), "50");
        assert_eq!(strip_unit("25 °C", "°C"), "25 ");
        assert_eq!(strip_unit("5°", "°C"), "5°");
    }
}
