//! Virtual drives.
pub mod model;
