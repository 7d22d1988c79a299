//! INV-NO of an ASCII-mode request: none, one inverter, or a pattern with `*` digits.

use crate::describe::Target;
use crate::error::EmitError;
use crate::session::Disposition;

use super::WILDCARD;

/// INV-NO of a request.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum AsciiAddress {
    /// No INV-NO (a 1:1 link): the one inverter on the line acts and answers.
    Omitted,
    /// One inverter, 0–99.
    Unit(u8),
    /// A pattern with `*` digits: every inverter it matches acts; the smallest it can match answers.
    Wildcard {
        /// The tens digit, `None` for `*`.
        tens: Option<u8>,
        /// The units digit, `None` for `*`.
        units: Option<u8>,
    },
}

impl AsciiAddress {
    /// `**`: every inverter.
    pub const ALL: AsciiAddress = AsciiAddress::Wildcard { tens: None, units: None };

    /// True when inverter `me` acts on a request with this INV-NO.
    pub const fn matches(self, me: u8) -> bool {
        match self {
            AsciiAddress::Omitted => true,
            AsciiAddress::Unit(n) => n == me,
            AsciiAddress::Wildcard { tens, units } => {
                me <= 99
                    && match tens {
                        Some(t) => me / 10 == t,
                        None => true,
                    }
                    && match units {
                        Some(u) => me % 10 == u,
                        None => true,
                    }
            }
        }
    }

    /// The INV-NO the reply carries: the number itself, the smallest number a wildcard can
    /// match (each `*` read as 0: `*2` -> 02, `1*` -> 10, `**` -> 00), or none when omitted.
    pub const fn reply_inv_no(self) -> Option<u8> {
        match self {
            AsciiAddress::Omitted => None,
            AsciiAddress::Unit(n) => Some(n),
            AsciiAddress::Wildcard { tens, units } => {
                let t = match tens {
                    Some(t) => t,
                    None => 0,
                };
                let u = match units {
                    Some(u) => u,
                    None => 0,
                };
                Some(t * 10 + u)
            }
        }
    }

    /// How inverter `me` treats a request with this INV-NO.
    pub const fn disposition(self, me: u8) -> Disposition {
        match self {
            AsciiAddress::Omitted => Disposition::Mine,
            AsciiAddress::Unit(n) if n == me => Disposition::Mine,
            AsciiAddress::Unit(_) => Disposition::NotMine,
            AsciiAddress::Wildcard { .. } if self.matches(me) => {
                Disposition::Broadcast { reply: matches!(self.reply_inv_no(), Some(n) if n == me) }
            }
            AsciiAddress::Wildcard { .. } => Disposition::NotMine,
        }
    }

    /// The address for [`Describe`](crate::describe::Describe): `**` is a broadcast.
    pub const fn target(self) -> Target {
        match self {
            AsciiAddress::Omitted => Target::Implicit,
            AsciiAddress::Unit(n) => Target::Unit(n),
            AsciiAddress::Wildcard { tens: None, units: None } => Target::Broadcast,
            AsciiAddress::Wildcard { tens, units } => Target::Wildcard { tens, units },
        }
    }

    /// The two INV-NO characters, or `None` when omitted.
    pub(super) fn chars(self) -> Result<Option<[u8; 2]>, EmitError> {
        let digit = |d: Option<u8>| match d {
            None => Ok(WILDCARD),
            Some(d) if d <= 9 => Ok(b'0' + d),
            Some(d) => {
                Err(EmitError::OutOfRange { field: "INV-NO wildcard digit", value: d as u32, min: 0, max: 9 })
            }
        };
        match self {
            AsciiAddress::Omitted => Ok(None),
            AsciiAddress::Unit(n) => Ok(Some(unit_chars(n)?)),
            AsciiAddress::Wildcard { tens: Some(_), units: Some(_) } => Err(EmitError::Invalid(
                "a wildcard INV-NO needs at least one '*' digit; use AsciiAddress::Unit",
            )),
            AsciiAddress::Wildcard { tens, units } => Ok(Some([digit(tens)?, digit(units)?])),
        }
    }

    pub(super) fn from_chars(c: u8, d: u8) -> AsciiAddress {
        let v = |x: u8| if x == WILDCARD { None } else { Some(x - b'0') };
        match (v(c), v(d)) {
            (Some(t), Some(u)) => AsciiAddress::Unit(t * 10 + u),
            (tens, units) => AsciiAddress::Wildcard { tens, units },
        }
    }
}

pub(super) fn unit_chars(n: u8) -> Result<[u8; 2], EmitError> {
    if n > 99 {
        return Err(EmitError::OutOfRange { field: "INV-NO", value: n as u32, min: 0, max: 99 });
    }
    Ok([b'0' + n / 10, b'0' + n % 10])
}
