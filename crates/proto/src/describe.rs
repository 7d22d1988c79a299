//! A protocol-neutral view of a decoded frame, for tools that print or log frames
//! (`drivebus decode`, the simulator's `-v`, the gateway's trace) without knowing the protocol.
//!
//! Every typed frame implements [`Describe`]: its direction, its address, its command or
//! function, and its fields one by one, named as the manual names them, each with the raw
//! value from the wire and, where the value carries a unit, the value in that unit.
//! Nothing here allocates: fields are handed to a callback one at a time.

use core::fmt;

/// Who sent a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Direction {
    /// From the master (the host, PLC or drivebus) to a drive.
    Master,
    /// From a drive (the slave) back to the master.
    Drive,
}

impl Direction {
    /// `"master"` or `"drive"`.
    pub const fn as_str(self) -> &'static str {
        match self {
            Direction::Master => "master",
            Direction::Drive => "drive",
        }
    }
}

/// Whom a frame is addressed to (from the master) or who answered (from a drive).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Target {
    /// One drive, by the number a user sets on the drive (B800 1–63 without the +128,
    /// FC 1–126, Modbus 1–247, Toshiba 0–99).
    Unit(u8),
    /// Every drive on the line (Modbus 0, B800 'G', FC broadcast ADR, Toshiba binary FF, `**`).
    Broadcast,
    /// Toshiba ASCII wildcard: `*d` matches every number ending in digit `d`,
    /// `d*` every number starting with `d`.
    Wildcard {
        /// The tens digit, or `None` for `*`.
        tens: Option<u8>,
        /// The units digit, or `None` for `*`.
        units: Option<u8>,
    },
    /// The frame carries no address (Toshiba 1:1 links omit INV-NO).
    Implicit,
}

impl Target {
    /// True for [`Target::Broadcast`] and [`Target::Wildcard`]: more than one drive may act.
    pub const fn is_broadcast(self) -> bool {
        matches!(self, Target::Broadcast | Target::Wildcard { .. })
    }
}

/// The command or function of a frame: its code on the wire and its name from the manual.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Command {
    /// The code on the wire (Modbus function, ASCII letter of TIP/B800 commands, FC AK).
    pub code: u8,
    /// How the code is shown: a letter (`'R'`) or a hex number (`03`).
    pub style: CodeStyle,
    /// The manual's name for it, e.g. "read holding registers", "run".
    pub name: &'static str,
}

/// How a [`Command`] code is printed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CodeStyle {
    /// A printable ASCII letter, shown as `'R'`.
    Letter,
    /// A number, shown as two hex digits.
    Hex,
}

impl fmt::Display for Command {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.style {
            CodeStyle::Letter => write!(f, "{} {}", self.code as char, self.name),
            CodeStyle::Hex => write!(f, "{:02X} {}", self.code, self.name),
        }
    }
}

/// The raw value of a field as it is on the wire.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Raw<'a> {
    /// A number shown in hex with this many digits (`0960`).
    Hex {
        /// The value.
        value: u32,
        /// Digits to print, zero padded.
        digits: u8,
    },
    /// A number shown in decimal.
    Dec(i64),
    /// A flag.
    Bool(bool),
    /// Bytes shown in hex (`54 4F 53`).
    Bytes(&'a [u8]),
    /// Printable text from the wire (a device name, a parameter's text).
    Text(&'a [u8]),
}

/// A value in physical units: `40.0 Hz`, `5.24 A`, `50.00 %`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Quantity {
    /// The value in `unit`.
    pub value: f64,
    /// The unit symbol (`"Hz"`, `"A"`, `"%"`, `"s"`, `"rpm"`, `"V"`, `"degC"`).
    pub unit: &'static str,
    /// Decimal places the wire resolution gives (1 for 0.1 A, 2 for 0.01 Hz).
    pub decimals: u8,
}

impl fmt::Display for Quantity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:.*} {}", self.decimals as usize, self.value, self.unit)
    }
}

/// One named field of a frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Field<'a> {
    /// The manual's name for the field (`"PKE"`, `"set speed"`, `"quantity"`).
    pub name: &'static str,
    /// The value as carried on the wire.
    pub raw: Raw<'a>,
    /// The value in its unit, where it has one.
    pub quantity: Option<Quantity>,
    /// What a coded value means (an error code's text, a bit's name), where it has one.
    pub meaning: Option<&'static str>,
}

impl<'a> Field<'a> {
    /// A field shown in hex with `digits` digits.
    pub const fn hex(name: &'static str, value: u32, digits: u8) -> Self {
        Field { name, raw: Raw::Hex { value, digits }, quantity: None, meaning: None }
    }
    /// A field shown in decimal.
    pub const fn dec(name: &'static str, value: i64) -> Self {
        Field { name, raw: Raw::Dec(value), quantity: None, meaning: None }
    }
    /// A flag.
    pub const fn flag(name: &'static str, value: bool) -> Self {
        Field { name, raw: Raw::Bool(value), quantity: None, meaning: None }
    }
    /// A run of bytes shown in hex.
    pub const fn bytes(name: &'static str, value: &'a [u8]) -> Self {
        Field { name, raw: Raw::Bytes(value), quantity: None, meaning: None }
    }
    /// Text from the wire.
    pub const fn text(name: &'static str, value: &'a [u8]) -> Self {
        Field { name, raw: Raw::Text(value), quantity: None, meaning: None }
    }
    /// Adds the value in a unit.
    pub const fn with_quantity(mut self, value: f64, unit: &'static str, decimals: u8) -> Self {
        self.quantity = Some(Quantity { value, unit, decimals });
        self
    }
    /// Adds what the value means.
    pub const fn with_meaning(mut self, meaning: &'static str) -> Self {
        self.meaning = Some(meaning);
        self
    }
}

impl fmt::Display for Field<'_> {
    /// `set speed 0960 = 40.0 Hz`, `exception code 03 (illegal data value)`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} ", self.name)?;
        match self.raw {
            Raw::Hex { value, digits } => write!(f, "{:0width$X}", value, width = digits as usize)?,
            Raw::Dec(v) => write!(f, "{v}")?,
            Raw::Bool(b) => write!(f, "{}", if b { "1" } else { "0" })?,
            Raw::Bytes(bytes) => {
                for (i, b) in bytes.iter().enumerate() {
                    if i > 0 {
                        f.write_str(" ")?;
                    }
                    write!(f, "{b:02X}")?;
                }
            }
            Raw::Text(t) => {
                f.write_str("\"")?;
                for &c in t {
                    if (0x20..0x7F).contains(&c) && c != b'"' && c != b'\\' {
                        write!(f, "{}", c as char)?;
                    } else {
                        write!(f, "\\x{c:02X}")?;
                    }
                }
                f.write_str("\"")?;
            }
        }
        if let Some(q) = self.quantity {
            write!(f, " = {q}")?;
        }
        if let Some(m) = self.meaning {
            write!(f, " ({m})")?;
        }
        Ok(())
    }
}

/// A decoded frame that can show itself field by field.
pub trait Describe {
    /// Who sent it.
    fn direction(&self) -> Direction;
    /// Whom it addresses, or who answered.
    fn target(&self) -> Target;
    /// Its command or function.
    fn command(&self) -> Command;
    /// True when the frame is a drive's refusal (a Modbus exception, a TIP `N`, an FC AK=7,
    /// a B800 `e`): a valid frame that says no.
    fn is_refusal(&self) -> bool {
        false
    }
    /// Calls `out` once per field, in wire order.
    fn fields(&self, out: &mut dyn FnMut(Field<'_>));
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Buf {
        bytes: [u8; 128],
        len: usize,
    }

    impl fmt::Write for Buf {
        fn write_str(&mut self, s: &str) -> fmt::Result {
            let end = self.len + s.len();
            if end > self.bytes.len() {
                return Err(fmt::Error);
            }
            self.bytes[self.len..end].copy_from_slice(s.as_bytes());
            self.len = end;
            Ok(())
        }
    }

    fn show(field: Field<'_>) -> Buf {
        let mut b = Buf { bytes: [0; 128], len: 0 };
        fmt::write(&mut b, format_args!("{field}")).unwrap();
        b
    }

    #[test]
    fn field_shows_raw_value_and_quantity() {
        let b = show(Field::hex("set speed", 0x0960, 4).with_quantity(40.0, "Hz", 1));
        assert_eq!(&b.bytes[..b.len], b"set speed 0960 = 40.0 Hz");
        let b = show(Field::hex("exception code", 3, 2).with_meaning("illegal data value"));
        assert_eq!(&b.bytes[..b.len], b"exception code 03 (illegal data value)");
        let b = show(Field::text("name", b"TOSHIBA"));
        assert_eq!(&b.bytes[..b.len], b"name \"TOSHIBA\"");
    }
}
