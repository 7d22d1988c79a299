//! Errors, sorted by whose fault they are.
//!
//! - [`FrameError`]: the bytes on the wire are not a valid frame (bad checksum, truncated,
//!   a field out of the range the protocol allows). The peer or the line is at fault.
//! - [`EmitError`]: the caller asked to build a frame the protocol cannot carry
//!   (a buffer too small, a value out of range). The caller is at fault.
//! - [`SessionError`]: a session was used out of order, or the peer broke the exchange
//!   (a reply that does not match the request).
//!
//! A drive's refusal (a Modbus exception, a TIP error reply, an FC AK=7, a B800 `e`) is not an
//! error here: it is a valid frame, and the typed reply says what the drive refused and why.

use core::fmt;

/// Which checksum a frame carries, for messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ChecksumKind {
    /// Modbus RTU CRC-16, two bytes low byte first.
    Crc16,
    /// Modbus ASCII LRC.
    Lrc,
    /// Toshiba SUM.
    Sum,
    /// Danfoss FC BCC.
    Bcc,
    /// B800 CS.
    Cs,
}

impl ChecksumKind {
    /// The name the manuals use.
    pub const fn name(self) -> &'static str {
        match self {
            ChecksumKind::Crc16 => "CRC",
            ChecksumKind::Lrc => "LRC",
            ChecksumKind::Sum => "SUM",
            ChecksumKind::Bcc => "BCC",
            ChecksumKind::Cs => "checksum",
        }
    }
}

/// What a wrong checksum would be right for: a clue to a sender's bug.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MismatchHint {
    /// The checksum of only the first `len` bytes of the frame.
    PrefixOnly {
        /// Bytes covered.
        len: u8,
    },
    /// The checksum of the same frame with another address byte.
    OtherAddress {
        /// That address.
        address: u8,
    },
}

/// Why bytes are not a valid frame. Every variant prints as one sentence.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum FrameError {
    /// The checksum carried by the frame differs from the one computed over it.
    ChecksumMismatch {
        /// Which checksum.
        kind: ChecksumKind,
        /// The value the frame carries (for CRC-16: the number, sent low byte first).
        carried: u16,
        /// The value computed over the frame.
        computed: u16,
        /// What the carried value would be right for, where a search found it
        /// (seed 004's errata: a CRC over too few bytes, a CRC for another address).
        hint: Option<MismatchHint>,
    },
    /// The frame ended before all the bytes its header announces.
    Truncated {
        /// What was being read.
        what: &'static str,
        /// Bytes the frame needs.
        expected: usize,
        /// Bytes there are.
        got: usize,
    },
    /// The frame is longer than its header or the protocol allows.
    TooLong {
        /// What was being read.
        what: &'static str,
        /// The most bytes allowed.
        max: usize,
        /// Bytes there are.
        got: usize,
    },
    /// A byte that is not a hex digit inside a hex-ASCII frame.
    NonHex {
        /// The byte.
        byte: u8,
        /// Its offset from the start of the frame.
        offset: usize,
    },
    /// A hex-ASCII frame with an odd number of digits.
    OddDigits {
        /// Digits seen.
        count: usize,
    },
    /// A field whose value the protocol does not allow.
    OutOfRange {
        /// The manual's name for the field.
        field: &'static str,
        /// The value carried.
        value: u32,
        /// The least allowed value.
        min: u32,
        /// The greatest allowed value.
        max: u32,
    },
    /// A code the protocol does not define (a function, a command, a start code).
    Unknown {
        /// The manual's name for the field.
        field: &'static str,
        /// The value carried.
        value: u32,
    },
    /// Two fields that must agree do not (a byte count against a quantity, LGE against the data).
    Inconsistent {
        /// The field that disagrees.
        field: &'static str,
        /// The value it carries.
        value: u32,
        /// The value the rest of the frame implies.
        expected: u32,
    },
    /// A structural problem without a number to report.
    Malformed(&'static str),
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            FrameError::ChecksumMismatch { kind, carried, computed, hint } => {
                f.write_str(kind.name())?;
                f.write_str(" mismatch: frame carries ")?;
                match kind {
                    ChecksumKind::Crc16 => {
                        let [c0, c1] = carried.to_le_bytes();
                        let [k0, k1] = computed.to_le_bytes();
                        write!(f, "{c0:02X} {c1:02X}, computed {k0:02X} {k1:02X}")?;
                    }
                    _ => write!(f, "{carried:02X}, computed {computed:02X}")?,
                }
                match hint {
                    Some(MismatchHint::PrefixOnly { len }) => {
                        write!(f, " (the carried {} is that of the first {len} bytes only)", kind.name())
                    }
                    Some(MismatchHint::OtherAddress { address }) => write!(
                        f,
                        " (the carried {} is right for the same frame sent to address {address})",
                        kind.name()
                    ),
                    None => Ok(()),
                }
            }
            FrameError::Truncated { what, expected, got } => {
                write!(f, "truncated frame: {what} needs {expected} bytes, got {got}")
            }
            FrameError::TooLong { what, max, got } => {
                write!(f, "frame too long: {what} allows at most {max} bytes, got {got}")
            }
            FrameError::NonHex { byte, offset } => {
                write!(f, "non-hex byte 0x{byte:02X} at offset {offset} ends the frame")
            }
            FrameError::OddDigits { count } => {
                write!(f, "odd number of hex digits ({count}): a byte is two digits")
            }
            FrameError::OutOfRange { field, value, min, max } => {
                write!(f, "{field} {value} is not allowed ({min}..{max})")
            }
            FrameError::Unknown { field, value } => write!(f, "unknown {field} 0x{value:02X}"),
            FrameError::Inconsistent { field, value, expected } => {
                write!(f, "{field} {value} does not match the frame, which implies {expected}")
            }
            FrameError::Malformed(what) => f.write_str(what),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for FrameError {}

/// Why a frame could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum EmitError {
    /// The output buffer is too small.
    BufferTooSmall {
        /// Bytes the frame needs.
        needed: usize,
        /// Bytes the buffer holds.
        capacity: usize,
    },
    /// A value the protocol cannot carry.
    OutOfRange {
        /// The manual's name for the field.
        field: &'static str,
        /// The value asked for.
        value: u32,
        /// The least allowed value.
        min: u32,
        /// The greatest allowed value.
        max: u32,
    },
    /// A combination of fields the protocol does not allow.
    Invalid(&'static str),
}

impl fmt::Display for EmitError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            EmitError::BufferTooSmall { needed, capacity } => {
                write!(f, "frame needs {needed} bytes, the buffer holds {capacity}")
            }
            EmitError::OutOfRange { field, value, min, max } => {
                write!(f, "{field} {value} is out of range ({min}..{max})")
            }
            EmitError::Invalid(what) => f.write_str(what),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for EmitError {}

/// A session used out of order, or a peer that broke the exchange.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum SessionError {
    /// A request was submitted while another is still in flight.
    Busy,
    /// The request could not be built.
    Emit(EmitError),
}

impl fmt::Display for SessionError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SessionError::Busy => f.write_str("a request is still in flight: wait for its reply or timeout"),
            SessionError::Emit(e) => write!(f, "cannot build the request: {e}"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for SessionError {}

impl From<EmitError> for SessionError {
    fn from(e: EmitError) -> Self {
        SessionError::Emit(e)
    }
}

/// A value outside the range its field allows, before it is told as a [`FrameError`] (bytes
/// received) or an [`EmitError`] (a frame asked for): `?` turns it into either.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct OutOfRange {
    field: &'static str,
    value: u32,
    min: u32,
    max: u32,
}

impl From<OutOfRange> for FrameError {
    #[inline]
    fn from(e: OutOfRange) -> Self {
        FrameError::OutOfRange { field: e.field, value: e.value, min: e.min, max: e.max }
    }
}

impl From<OutOfRange> for EmitError {
    #[inline]
    fn from(e: OutOfRange) -> Self {
        EmitError::OutOfRange { field: e.field, value: e.value, min: e.min, max: e.max }
    }
}

/// Checks that `field`'s `value` is within `min..=max`.
#[inline]
pub(crate) const fn in_range(field: &'static str, value: u32, min: u32, max: u32) -> Result<(), OutOfRange> {
    if value < min {
        return Err(OutOfRange { field, value, min, max });
    }
    at_most(field, value, min, max)
}

/// Checks that `field`'s `value` is at most `max`; `min` is only told in the error (for a
/// value that cannot be below it).
#[inline]
pub(crate) const fn at_most(field: &'static str, value: u32, min: u32, max: u32) -> Result<(), OutOfRange> {
    if value > max {
        Err(OutOfRange { field, value, min, max })
    } else {
        Ok(())
    }
}

/// The named values of a code type (a drive's refusal codes: a Modbus exception code, an FC
/// fault code, a B800 error code; the Modbus read device ID code) from one list: a constant for
/// each named code, and `meaning` from the same entries plus the codes that have a meaning but
/// no constant (`also { .. }`).
macro_rules! named_codes {
    (
        $code_type:ident;
        $(#[$meaning_doc:meta])*
        fn meaning $(also { $($other:pat => $other_meaning:literal),* $(,)? })?;
        $(
            $(#[$doc:meta])*
            $name:ident($code:literal) => $meaning:literal,
        )*
    ) => {
        $(
            $(#[$doc])*
            pub const $name: $code_type = $code_type($code);
        )*

        $(#[$meaning_doc])*
        pub const fn meaning(self) -> Option<&'static str> {
            Some(match self.0 {
                $($code => $meaning,)*
                $($($other => $other_meaning,)*)?
                _ => return None,
            })
        }
    };
}

pub(crate) use named_codes;

/// Writes ` (meaning)` after a code, or ` (unknown)` for a code without one.
pub(crate) fn write_meaning(f: &mut fmt::Formatter<'_>, meaning: Option<&str>, unknown: &str) -> fmt::Result {
    write!(f, " ({})", meaning.unwrap_or(unknown))
}

/// Checks that `buf` holds `needed` bytes.
#[inline]
pub(crate) fn need(buf: &[u8], needed: usize) -> Result<(), EmitError> {
    if buf.len() < needed {
        Err(EmitError::BufferTooSmall { needed, capacity: buf.len() })
    } else {
        Ok(())
    }
}
