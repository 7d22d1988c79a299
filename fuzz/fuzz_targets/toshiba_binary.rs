#![no_main]
//! Fuzzes the toshiba_binary deframer and parser.

#[path = "common.rs"]
mod common;

libfuzzer_sys::fuzz_target!(|data: &[u8]| common::run::<drivebus_proto::toshiba::binary::BinaryCodec>(data));
