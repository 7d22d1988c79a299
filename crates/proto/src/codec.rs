//! One entry point per wire format for tools that handle any protocol the same way:
//! `drivebus decode`, the benchmarks and the fuzz targets.

use crate::deframe::Scanner;
use crate::describe::{Describe, Direction};
use crate::error::FrameError;

/// A wire format: how to cut a byte stream into frames and how to read a frame in
/// either direction.
pub trait Codec {
    /// The name users type (`modbus-rtu`, `toshiba-ascii`, `danfoss-fc`, `b800`, ...).
    const NAME: &'static str;
    /// The deframer's scanner.
    type Scanner: Scanner;
    /// A frame in either direction.
    type Frame<'a>: Describe;

    /// A scanner for frames from `from`, or for both directions when `None`
    /// (a line monitor hears both).
    fn scanner(from: Option<Direction>) -> Self::Scanner;

    /// Reads a whole frame whose checksum the scanner has checked. `from` says who sent it
    /// where the bytes cannot tell (a Modbus request and reply can look alike); with `None`
    /// the codec decides from the bytes, preferring the master's reading.
    fn parse(bytes: &[u8], from: Option<Direction>) -> Result<Self::Frame<'_>, FrameError>;
}
