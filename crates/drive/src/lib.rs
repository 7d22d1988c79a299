//! # drivebus-drive
//!
//! The protocol-neutral model of a drive. This crate knows what each drive family's parameters
//! are. It does not know how they travel on the wire (that is `drivebus-proto`). Two sides use it:
//!
//! - the **simulator**: each virtual drive keeps its values in a [`ParamStore`]. The store refuses
//!   writes the way the drive would (unknown, read-only, not while running, out of range) and counts
//!   EEPROM writes per parameter;
//! - the **master side**: `param get/set` by name and `params backup/restore/diff` look names up
//!   in a [`Catalog`], turn values in units into raw integers ([`ParamDef::to_raw`],
//!   [`ParamDef::parse_value`]) and show raw values to people ([`ParamDef::format`]).
//!
//! ## Catalogs are data
//!
//! Each family's catalog is a TOML file under `crates/drive/catalogs/`, compiled in with
//! `include_str!` and parsed once on first use ([`Catalog::load`]):
//!
//! | family | file | wire number | manual |
//! |---|---|---|---|
//! | [`Family::Generic`] | `generic.toml` | Modbus register 0xGGNN for Pgg.nn | `seeds/004_e8ea1998fe1a671e.txt` |
//! | [`Family::Toshiba`] | `toshiba.toml` | communication number (f803 is 0x0803) | `seeds/002_43d8a4399c8be05f.txt` |
//! | [`Family::Danfoss`] | `danfoss.toml` | PNU (4-14 is 414) | `seeds/003_26a4c04ca1af5f26.txt` |
//! | [`Family::B800`] | `b800.toml` | local index (F-12 is 12; the protocol has no parameter access) | `seeds/000_04b515f0e0c1734e.txt` |
//!
//! `docs/parameters.md` describes the file format and lists every parameter. A catalog from
//! elsewhere loads with [`Catalog::from_toml_str`]. Its errors name the file, the parameter and
//! the field.
//!
//! ## Raw values
//!
//! Values are kept as the raw integers the wire carries. `scale` is the number of decimal places:
//! value = raw × 10^-scale, so raw 5000 at scale 2 is 50.00 Hz. For FC this is minus the
//! parameter's conversion index.
//!
//! ```
//! use drivebus_drive::{Catalog, Family, ParamStore, Storage, WriteError};
//!
//! let fc = Catalog::load(Family::Danfoss)?;
//! let high = fc.get("4-14").expect("4-14 is in the FC catalog");
//! assert_eq!(high.number, 414);
//! assert_eq!(high.to_raw(65.0)?, 650);
//! assert_eq!(high.format(650), "65.0 Hz");
//! assert_eq!(high.to_raw(600.0).unwrap_err().to_string(), "4-14 is 0.0..500.0 Hz, 600 is out of range");
//!
//! let mut drive = ParamStore::new(fc.clone());
//! drive.set("4-14", 500, Storage::Eeprom, false)?;
//! assert_eq!(drive.get(414), Some(500));
//! assert_eq!(drive.eeprom_writes("4-14"), Some(1));
//! assert!(matches!(drive.set("16-13", 0, Storage::Ram, false), Err(WriteError::ReadOnly { .. })));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! Nothing here panics on catalog text or on user input. Bad data comes back as
//! [`CatalogError`], [`RangeError`], [`ValueError`] or [`WriteError`].

mod catalog;
mod config_error;
mod family;
mod param;
mod store;

pub mod backup;
pub mod docgen;
pub mod interdrive;
pub mod panel;
pub mod profile;
pub mod registers;
pub mod template;

pub use catalog::{Catalog, CatalogError, ParamKey};
pub use config_error::ConfigError;
pub use family::{Family, UnknownFamily};
pub use param::{format_fixed, Choice, ParamDef, RangeError, Size, Storage, ValueError};
pub use store::{ParamStore, WriteError};
