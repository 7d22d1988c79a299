//! # drivebus-drive
//!
//! The protocol-neutral model of a drive: drive families and their parameter catalogs.

mod catalog;
mod family;
mod param;

pub use catalog::{Catalog, CatalogError, ParamKey};
pub use family::{Family, UnknownFamily};
pub use param::{format_fixed, Choice, ParamDef, RangeError, Size, Storage, ValueError};
