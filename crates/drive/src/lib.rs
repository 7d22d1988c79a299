//! # drivebus-drive
//!
//! The protocol-neutral model of a drive: drive families and their parameter catalogs.

mod family;

pub use family::{Family, UnknownFamily};
