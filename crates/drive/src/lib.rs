//! # drivebus-drive
//!
//! The protocol-neutral model of a drive: drive families and their parameter catalogs.

mod family;
mod param;

pub use family::{Family, UnknownFamily};
pub use param::{format_fixed, Choice, ParamDef, RangeError, Size, Storage, ValueError};
