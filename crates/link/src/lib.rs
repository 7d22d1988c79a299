//! # drivebus-link
//!
//! How drivebus reaches a bus: byte links ([`link`]: serial ports, TCP to serial device
//! servers, the simulator's virtual line) and the bus owner ([`owner`]): one task per
//! half-duplex bus that runs one transaction at a time with the protocol's timing, commands
//! ahead of polling, retries, and per-drive online/offline tracking with backoff.
//!
//! ```text
//! Drive (profile: operation -> frames)  ──transact──►  Bus (queue) ──► owner task
//!                                                           MasterSession<P> + Link
//! ```

pub mod drive;
pub mod link;
pub mod owner;
pub mod timer;

pub use link::{Clock, Link, Rs485, SerialLink, SimLink, TcpLink};
pub use owner::{Bus, BusConfig, BusError, BusStats, Health, Priority};
