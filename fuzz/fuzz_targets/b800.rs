#![no_main]
//! Fuzzes the b800 deframer and parser.

#[path = "common.rs"]
mod common;

libfuzzer_sys::fuzz_target!(|data: &[u8]| common::run::<drivebus_proto::b800::B800>(data));
