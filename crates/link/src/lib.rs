//! # drivebus-link
//!
//! How drivebus reaches a bus: byte links ([`link`]: serial ports, TCP to serial device
//! servers, the simulator's virtual line) and the bus owner ([`owner`]): one task per
//! half-duplex bus that runs one transaction at a time with the protocol's timing, commands
//! ahead of polling, on-demand reads sharing the bus fairly with polling ([`fair`]), retries,
//! and per-drive online/offline tracking with backoff.
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
pub mod bus;
pub mod drive;
mod engine;
pub mod fair;
pub mod link;
pub mod listen;
pub mod owner;
pub mod port;
pub mod port_link;
#[cfg(feature = "virtual")]
pub mod sim_link;
pub mod timer;

pub use bus::{BusConfig, BusError, BusStats, FairConfig, Health, Priority};
pub use link::{Clock, Link, SerialLink, TcpLink};
pub use owner::Bus;
pub use port::{Port, Rs485, SerialSettings};
pub use port_link::PortLink;
#[cfg(feature = "virtual")]
pub use sim_link::SimLink;
