#![no_main]
//! Fuzzes the danfoss_fc deframer and parser.

#[path = "common.rs"]
mod common;

libfuzzer_sys::fuzz_target!(|data: &[u8]| common::run::<drivebus_proto::fc::DanfossFc>(data));
