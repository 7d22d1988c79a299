//! # drivebus-proto
//!
//! The wire protocols of variable-frequency drives on RS-485, as pure code: no I/O, no clock,
//! no allocator (`#![no_std]`), so the same codecs run in drive or PLC firmware and on a PC.
//!
//! ## The six wire formats
//!
//! | module | wire format | manual |
//! |---|---|---|
//! | [`modbus::rtu`] | Modbus RTU (03, 06, 08, 10, 2B/0E, exceptions) | `seeds/002_43d8a4399c8be05f.txt`, `seeds/004_e8ea1998fe1a671e.txt` |
//! | [`modbus::ascii`] | Modbus ASCII (`:` ... LRC CR LF) | `seeds/004_e8ea1998fe1a671e.txt` |
//! | [`toshiba::ascii`] | Toshiba Inverter Protocol, ASCII mode | `seeds/002_43d8a4399c8be05f.txt` (VF-AS1 manual E6581315) |
//! | [`toshiba::binary`] | Toshiba Inverter Protocol, binary mode | the same |
//! | [`fc`] | Danfoss FC protocol telegrams | `seeds/003_26a4c04ca1af5f26.txt` (FC 280 Design Guide) |
//! | [`b800`] | B800 hex-ASCII protocol | `seeds/000_04b515f0e0c1734e.txt` |
//!
//! ## How the pieces fit
//!
//! ```text
//! bytes ──► Deframer<Scanner> ──► whole frame (checksum checked) ──► parse ──► typed frame
//!                                                                              │
//!         MasterSession<Protocol>: send(now, request) → poll_transmit → handle_input
//!           → poll_event: Reply | Timeout | Corrupt | BroadcastDone; poll_timeout for deadlines
//!         SlaveSession<Protocol>: handle_input → address filter → handler → poll_transmit
//! ```
//!
//! - Each wire format has **typed frames** in both directions with `parse` and `emit`
//!   (fields named as the manual names them, unit-carrying values with typed accessors),
//!   a [`deframe::Scanner`] for the streaming [`deframe::Deframer`], an implementation of
//!   [`session::Protocol`] for the sessions, and of [`codec::Codec`] + [`describe::Describe`]
//!   for tools.
//! - [`protocol::WireProtocol`] names the six and dispatches from a protocol to its codec
//!   and session types; every other crate asks it rather than spelling a protocol's name.
//! - [`checksum`] holds the six checksums, [`hex`] the hex-ASCII helpers, [`line`](mod@line) the
//!   character format and the times it implies, [`time`] the caller-supplied clock.
//! - Errors say whose fault they are: [`error::FrameError`] for bad bytes,
//!   [`error::EmitError`] for a frame the caller cannot build, and a drive's refusal is a
//!   typed reply, not an error.
//!
//! Nothing in this crate panics on input from the wire; `parse` and the deframers return
//! errors for every malformed input (the fuzz targets under `fuzz/` check this).
#![no_std]
#![forbid(unsafe_code)]

#[cfg(any(feature = "std", test))]
extern crate std;

pub mod checksum;
pub mod codec;
pub mod deframe;
pub mod describe;
pub mod error;
pub mod hex;
pub mod line;
pub mod protocol;
pub mod session;
pub mod time;

pub mod b800;
pub mod fc;
pub mod modbus;
pub mod toshiba;

pub use codec::Codec;
pub use deframe::{Deframer, Event, Scan, Scanner, Stats};
pub use describe::{Describe, Direction, Field, Target};
pub use error::{EmitError, FrameError, SessionError};
pub use time::Instant;
