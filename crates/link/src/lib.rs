//! # drivebus-link
//!
//! How drivebus reaches a bus. [`port`] says where a bus is ([`Port`]: a serial device with its
//! baud rate, format and RS-485 direction control, a serial device server over TCP, or a
//! virtual line of simulated drives behind the `virtual` feature, or a Modbus TCP server whose
//! framing [`mbap`] is) and opens it, the one place that does, for both drivers below. The
//! engine (`MasterSession` plus retries, reopening a lost link with a backoff ([`Backoff`],
//! which the gateway's RTU slave shares), echo removal, statistics and drive health) never waits: after each
//! attempt it says what to do next (retry, reopen the link and retry, or give up with which
//! error), and two thin drivers carry it out with their own I/O: the bus owner ([`owner`]), one
//! task per half-duplex bus over a [`PortLink`], commands ahead of polling, on-demand reads
//! sharing the bus fairly with polling ([`fair`]), or on a Modbus TCP bus with `max_in_flight`
//! above 1 the pipelined owner ([`Bus::spawn_pipelined`]: one engine per request in flight,
//! answers matched by transaction id); and the blocking bus ([`blocking`]) in the
//! calling thread. [`bus`] holds what both share: the configuration, errors and counts.
//!
//! ```text
//! Drive (profile: operation -> frames)  ──transact──►  Bus (queue) ──► owner task
//!                                                           Engine<P> + PortLink (async)
//! BlockingDrive                         ──transact──►  BlockingBus: Engine<P> + blocking port,
//!                                                      in the calling thread
//! ```
//!
//! A plan's frames are sent as the profile encoded them (`MasterSession::send_frame`); the loop
//! that drives a plan is `drivebus_drive::profile::run`.

pub mod backoff;
pub mod blocking;
pub mod bus;
pub mod drive;
mod engine;
pub mod fair;
mod learn;
pub mod link;
pub mod listen;
pub mod mbap;
mod overheard;
pub mod owner;
mod pipelined;
pub mod port;
pub mod port_link;
pub mod role;
#[cfg(feature = "virtual")]
pub mod sim_link;
pub mod timer;

pub use backoff::Backoff;
pub use bus::{BusConfig, BusError, BusStats, FairConfig, Health, Priority};
pub use link::{Clock, Link, SerialLink, TcpLink};
pub use owner::Bus;
pub use port::{Port, Rs485, SerialSettings};
pub use port_link::PortLink;
#[cfg(feature = "virtual")]
pub use sim_link::SimLink;
