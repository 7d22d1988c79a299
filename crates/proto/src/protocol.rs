//! The six wire protocols as one type: the names users type and read (each codec carries its
//! own, [`Codec::NAME`]), parsed and printed here and nowhere else, and the dispatch from a
//! protocol to its codec and session types. The codecs know nothing of this module.
//!
//! ```
//! use drivebus_proto::protocol::WireProtocol;
//! let p: WireProtocol = "toshiba-binary".parse().unwrap();
//! assert_eq!(p, WireProtocol::ToshibaBinary);
//! assert_eq!(p.to_string(), "toshiba-binary");
//! assert!("modbus".parse::<WireProtocol>().is_err());
//! ```

use core::fmt;
use core::str::FromStr;

use crate::codec::Codec;
use crate::line::CharFormat;
use crate::session::{Protocol, Timing};
use crate::{b800, fc, modbus, toshiba};

/// A wire protocol drivebus speaks, master and slave.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum WireProtocol {
    /// Modbus RTU (binary, CRC-16, t3.5 silences).
    ModbusRtu,
    /// Modbus ASCII (`:` ... LRC CR LF).
    ModbusAscii,
    /// TOSHIBA Inverter Protocol, ASCII mode (`(` ... `)` CR).
    ToshibaAscii,
    /// TOSHIBA Inverter Protocol, binary mode (2F/5A ... SUM).
    ToshibaBinary,
    /// Danfoss FC protocol telegrams (STX LGE ADR ... BCC).
    DanfossFc,
    /// B800 hex-ASCII protocol (7E ... 7F).
    B800,
}

impl WireProtocol {
    /// Every protocol, in the order the docs list them.
    pub const ALL: [WireProtocol; 6] = [
        WireProtocol::ModbusRtu,
        WireProtocol::ModbusAscii,
        WireProtocol::ToshibaAscii,
        WireProtocol::ToshibaBinary,
        WireProtocol::DanfossFc,
        WireProtocol::B800,
    ];

    /// The name users type and read on the command line, in TOML and JSON (`modbus-rtu`, ...).
    /// Each codec carries its name ([`Codec::NAME`]); this reads it.
    pub const fn name(self) -> &'static str {
        match self {
            WireProtocol::ModbusRtu => <modbus::rtu::ModbusRtu as Codec>::NAME,
            WireProtocol::ModbusAscii => <modbus::ascii::ModbusAscii as Codec>::NAME,
            WireProtocol::ToshibaAscii => <toshiba::ascii::AsciiCodec as Codec>::NAME,
            WireProtocol::ToshibaBinary => <toshiba::binary::BinaryCodec as Codec>::NAME,
            WireProtocol::DanfossFc => <fc::DanfossFc as Codec>::NAME,
            WireProtocol::B800 => <b800::B800 as Codec>::NAME,
        }
    }

    /// Every name, as a sentence's list: "modbus-rtu, modbus-ascii, ... or b800".
    pub const NAMES: &'static str =
        "modbus-rtu, modbus-ascii, toshiba-ascii, toshiba-binary, danfoss-fc or b800";

    /// Whether this is one of the Modbus serial framings.
    pub const fn is_modbus(self) -> bool {
        matches!(self, WireProtocol::ModbusRtu | WireProtocol::ModbusAscii)
    }

    /// The protocol's own timing at `baud` and `format` (inter-frame silence, response timeout).
    pub fn timing(self, baud: u32, format: CharFormat) -> Timing {
        match self {
            WireProtocol::ModbusRtu => modbus::rtu::timing(baud, format),
            WireProtocol::ModbusAscii => modbus::ascii::timing(baud, format),
            WireProtocol::ToshibaAscii | WireProtocol::ToshibaBinary => toshiba::timing(baud, format),
            WireProtocol::DanfossFc => fc::timing(baud, format),
            WireProtocol::B800 => b800::timing(baud, format),
        }
    }

    /// Runs `job` with this protocol's [`Codec`] (the deframer and parser tools use).
    pub fn with_codec<J: CodecJob>(self, job: J) -> J::Output {
        match self {
            WireProtocol::ModbusRtu => job.run::<modbus::rtu::ModbusRtu>(),
            WireProtocol::ModbusAscii => job.run::<modbus::ascii::ModbusAscii>(),
            WireProtocol::ToshibaAscii => job.run::<toshiba::ascii::AsciiCodec>(),
            WireProtocol::ToshibaBinary => job.run::<toshiba::binary::BinaryCodec>(),
            WireProtocol::DanfossFc => job.run::<fc::DanfossFc>(),
            WireProtocol::B800 => job.run::<b800::B800>(),
        }
    }

    /// Runs `job` with this protocol's session [`Protocol`] (what a master or slave session
    /// speaks), in its default settings.
    pub fn with_session<J: SessionJob>(self, job: J) -> J::Output {
        match self {
            WireProtocol::ModbusRtu => job.run(modbus::rtu::ModbusRtu),
            WireProtocol::ModbusAscii => job.run(modbus::ascii::ModbusAscii),
            WireProtocol::ToshibaAscii => job.run(toshiba::ascii::TipAscii::default()),
            WireProtocol::ToshibaBinary => job.run(toshiba::binary::TipBinary::default()),
            WireProtocol::DanfossFc => job.run(fc::Fc::default()),
            WireProtocol::B800 => job.run(b800::B800),
        }
    }
}

/// Something to do with a protocol's [`Codec`], whichever it is: [`WireProtocol::with_codec`]
/// calls [`CodecJob::run`] with the codec's type.
pub trait CodecJob {
    /// What the job gives.
    type Output;
    /// Does the job with codec `C`.
    fn run<C: Codec + 'static>(self) -> Self::Output
    where
        C::Scanner: Send + 'static;
}

/// Something to do with a protocol's session [`Protocol`], whichever it is:
/// [`WireProtocol::with_session`] calls [`SessionJob::run`] with it.
pub trait SessionJob {
    /// What the job gives.
    type Output;
    /// Does the job with `protocol`.
    fn run<P: Protocol + Send + 'static>(self, protocol: P) -> Self::Output;
}

impl fmt::Display for WireProtocol {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.pad(self.name())
    }
}

/// A protocol name that is not one of [`WireProtocol::NAMES`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct UnknownProtocol;

impl fmt::Display for UnknownProtocol {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "unknown protocol: use {}", WireProtocol::NAMES)
    }
}

impl FromStr for WireProtocol {
    type Err = UnknownProtocol;

    /// Reads a protocol's name, as [`WireProtocol::name`] prints it (case-insensitive).
    fn from_str(s: &str) -> Result<Self, UnknownProtocol> {
        WireProtocol::ALL.into_iter().find(|p| p.name().eq_ignore_ascii_case(s.trim())).ok_or(UnknownProtocol)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_name_reads_back_and_codecs_agree() {
        struct Name;
        impl CodecJob for Name {
            type Output = &'static str;
            fn run<C: Codec + 'static>(self) -> &'static str
            where
                C::Scanner: Send + 'static,
            {
                C::NAME
            }
        }
        for p in WireProtocol::ALL {
            assert_eq!(p.name().parse::<WireProtocol>(), Ok(p));
            assert_eq!(p.with_codec(Name), p.name(), "the codec of {p} names itself so");
            assert!(WireProtocol::NAMES.contains(p.name()));
        }
        assert_eq!("MODBUS-RTU".parse::<WireProtocol>(), Ok(WireProtocol::ModbusRtu));
        assert_eq!("fc".parse::<WireProtocol>(), Err(UnknownProtocol));
    }
}
