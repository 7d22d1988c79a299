//! The Modbus TCP server: the MBAP service ([`service`]: the listener, the connections, the
//! framing of requests and answers) over the unified register map ([`unified`]: what a request
//! means, each drive a unit id, one map for every family, docs/register-map.md, [`map`]).
//! Reads come from the cache; writes go through the bus owner and are answered when the drive
//! confirmed.

pub mod map;
mod service;
mod unified;

pub use service::{serve, serve_stream};
pub use unified::{exception_of, ILLEGAL_ADDRESS, ILLEGAL_FUNCTION, ILLEGAL_VALUE, TARGET_FAILED};
pub(crate) use unified::{Conn, Server};
