//! Modbus.
pub mod ascii;
pub mod rtu;
