//! INV-NO of a binary-mode request: none, one inverter, or every inverter (FF).

use crate::describe::Target;
use crate::error::EmitError;
use crate::session::Disposition;

use super::{BROADCAST, MAX_INV_NO};

/// INV-NO of a request.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BinaryAddress {
    /// No INV-NO (a 1:1 link).
    Omitted,
    /// One inverter, 00–3F.
    Unit(u8),
    /// FF: every inverter acts; inverter 00 answers.
    Broadcast,
}

impl BinaryAddress {
    /// How inverter `me` treats a request with this INV-NO.
    pub const fn disposition(self, me: u8) -> Disposition {
        match self {
            BinaryAddress::Omitted => Disposition::Mine,
            BinaryAddress::Unit(n) if n == me => Disposition::Mine,
            BinaryAddress::Unit(_) => Disposition::NotMine,
            // manual: "only the inverter numbered 00H replies" to a broadcast.
            BinaryAddress::Broadcast => Disposition::Broadcast { reply: me == 0 },
        }
    }

    /// The INV-NO the reply carries (a broadcast is answered by inverter 00).
    pub const fn reply_inv_no(self) -> Option<u8> {
        match self {
            BinaryAddress::Omitted => None,
            BinaryAddress::Unit(n) => Some(n),
            BinaryAddress::Broadcast => Some(0),
        }
    }

    /// The address for [`Describe`](crate::describe::Describe).
    pub const fn target(self) -> Target {
        match self {
            BinaryAddress::Omitted => Target::Implicit,
            BinaryAddress::Unit(n) => Target::Unit(n),
            BinaryAddress::Broadcast => Target::Broadcast,
        }
    }

    pub(super) fn from_byte(b: Option<u8>) -> Self {
        match b {
            None => BinaryAddress::Omitted,
            Some(BROADCAST) => BinaryAddress::Broadcast,
            Some(n) => BinaryAddress::Unit(n),
        }
    }

    pub(super) fn byte(self) -> Result<Option<u8>, EmitError> {
        match self {
            BinaryAddress::Omitted => Ok(None),
            BinaryAddress::Unit(n) => unit_byte(n).map(Some),
            BinaryAddress::Broadcast => Ok(Some(BROADCAST)),
        }
    }
}

pub(super) fn unit_byte(n: u8) -> Result<u8, EmitError> {
    if n > MAX_INV_NO {
        return Err(EmitError::OutOfRange {
            field: "INV-NO",
            value: n as u32,
            min: 0,
            max: MAX_INV_NO as u32,
        });
    }
    Ok(n)
}
