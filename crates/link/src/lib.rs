//! # drivebus-link
//!
//! How drivebus reaches a bus: byte links ([`link`]: serial ports, TCP to serial device
//! servers, the simulator's virtual line) and the bus owner ([`owner`]): one task per
//! half-duplex bus that runs one transaction at a time with the protocol's timing, commands
//! ahead of polling, retries, and per-drive online/offline tracking with backoff.
//!
//! ```text
//! Drive (profile: operation -> frames)  ──transact──►  Bus (queue) ──► owner task
//!                                                           Engine<P> + Link (async)
//! BlockingDrive                         ──transact──►  BlockingBus: Engine<P> + blocking port,
//!                                                      in the calling thread
//! ```
//!
//! The engine (`MasterSession` plus retries, echo removal, statistics and drive health) never
//! waits; the async owner and the blocking bus ([`blocking`]) wait for it, each their way.

pub mod blocking;
pub mod drive;
mod engine;
pub mod link;
pub mod listen;
pub mod owner;
#[cfg(feature = "virtual")]
pub mod sim_link;
pub mod timer;

pub use link::{Clock, Link, Rs485, SerialLink, TcpLink};
pub use owner::{Bus, BusConfig, BusError, BusStats, Health, Priority};
#[cfg(feature = "virtual")]
pub use sim_link::SimLink;
