#![no_main]
//! Fuzzes the modbus_rtu deframer and parser.

#[path = "common.rs"]
mod common;

libfuzzer_sys::fuzz_target!(|data: &[u8]| common::run::<drivebus_proto::modbus::rtu::ModbusRtu>(data));
