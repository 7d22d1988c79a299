#![no_main]
//! Fuzzes the modbus_ascii deframer and parser.

#[path = "common.rs"]
mod common;

libfuzzer_sys::fuzz_target!(|data: &[u8]| common::run::<drivebus_proto::modbus::ascii::ModbusAscii>(data));
