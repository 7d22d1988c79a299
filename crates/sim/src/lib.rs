//! # drivebus-sim
//!
//! Virtual drives that behave as their manuals say, on a virtual RS-485 line paced at the real
//! baud rate: for commissioning practice, SCADA integration without hardware, and drivebus'
//! own tests.
//!
//! ## How the pieces fit
//!
//! ```text
//! master bytes ──► VirtualLine (paced characters, half duplex, faults) ──► every Device
//!                        ▲                                                    │
//!                        └──────────── replies, paced ◄──── family drive ◄────┘
//!   family drive = DriveCore { DriveModel (ramps, load, trips), ParamStore (catalog values) }
//!                  + the family's protocol slave session(s) from drivebus-proto
//! ```
//!
//! - [`model`]: the motor and inverter every family shares (state, ramps on a virtual clock,
//!   current from the load, DC bus, heat sink, trips and their log).
//! - [`drive`]: [`drive::DriveCore`] and the [`drive::VirtualDrive`] trait with its snapshot.
//! - [`family`]: generic, toshiba, danfoss, b800: each family's registers, commands, errors and
//!   addressing rules.
//! - [`bus`]: the virtual line; sans-IO, advanced by the caller's clock.
//! - [`spec`]: one drive as `--drive KIND@ADDR[:PROTOCOL]` or a bus file describes it;
//!   [`config`]: the whole bus.
//! - [`interdrive`]: a drive as bus master, broadcasting its run/stop and frequency.
//!
//! Nothing here reads a clock: tests run the whole bus on simulated time.

pub mod bus;
pub mod config;
pub mod drive;
pub mod family;
pub mod interdrive;
pub mod master;
pub mod model;
pub mod monitor;
pub mod rng;
pub mod runtime;
pub mod spec;
