//! Virtual drives.
pub mod bus;
pub mod model;
pub mod rng;
