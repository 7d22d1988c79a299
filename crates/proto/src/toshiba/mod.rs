//! Toshiba.
pub mod ascii;
pub mod binary;
