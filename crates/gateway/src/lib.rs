//! The drivebus gateway: many buses, one view.
//!
//! ```text
//!  config/   ──► Gateway::start ──► per bus: a bus owner (drivebus-link) + a poll scheduler
//!                      │                 │ status polls (Priority::Poll)    ▲ commands (Priority::Command)
//!                      ▼                 ▼                                  │
//!                 state cache ◄── update: values + age, trips, online ──► events ──► store (SQLite)
//!                      │                                                     │
//!     reads (no bus) ──┼── Modbus TCP (modbus_tcp.rs)                        └──► live stream (broadcast)
//!                      └── HTTP/JSON (http/), dashboard, MQTT, metrics
//! ```
//!
//! Every front end reads from the cache ([`Gateway::drive_view`]) and writes through
//! [`Gateway::command`], which checks the per-drive lock, sends the command through the
//! bus owner ahead of polling, and records the audit event before it answers. A `port =
//! "virtual"` bus runs simulated drives (drivebus-sim) on a paced virtual line in this process:
//! that is `drivebus serve --demo`.
//!
//! What runs (configuration, buses, drives) is one [`Topology`](crate::core::Topology), swapped whole by
//! [`Gateway::reload`] on SIGHUP: [`reload`] compares the running configuration with
//! the new one, and entries that did not change are carried over as they are (same bus owner,
//! statistics and cache), so their polling never stops. [`health`] keeps what `/healthz` and
//! `/readyz` answer; [`log`] writes the service's log lines as text or JSON.
//!
//! Layers, each importing only from those below it: the core ([`core`](crate::core), [`config`],
//! [`limits`], [`health`], [`log`], [`refusals`], [`text`], [`trip`], ...) knows no front end;
//! [`metrics`] observes the core; the front ends ([`http`], [`modbus_tcp`], [`modbus_rtu`],
//! [`bridge`], [`mqtt`], [`sparkplug`], [`opcua`]) use both; [`server`] starts them all.

pub mod bridge;
pub mod config;
pub mod core;
pub mod health;
pub mod http;
pub mod json;
pub mod limits;
pub mod log;
pub mod metrics;
pub mod modbus_rtu;
pub mod modbus_tcp;
pub mod mqtt;
pub mod opcua;
mod params;
pub mod refusals;
pub mod reload;
pub mod scan;
pub mod server;
pub mod sparkplug;
pub mod text;
pub mod trip;
#[cfg(feature = "virtual")]
pub mod virtual_bus;

pub use crate::core::{Command, CommandError, Gateway};
pub use config::GatewayConfig;
