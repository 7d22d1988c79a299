//! Throughput of the Modbus deframers + parse (run with
//! `cargo test --release -p drivebus-proto --test modbus_perf -- --ignored --nocapture`).

use std::time::Instant;

use drivebus_proto::modbus::ascii::ModbusAscii;
use drivebus_proto::modbus::rtu::ModbusRtu;
use drivebus_proto::{Codec, Deframer, Direction, Event};

fn run<C: Codec>(frame: &[u8], from: Option<Direction>, label: &str) -> f64 {
    let n = 100_000;
    let stream: Vec<u8> = frame.iter().copied().cycle().take(frame.len() * n).collect();
    let mut best = f64::MAX;
    for _ in 0..5 {
        let mut d = Deframer::new(C::scanner(from));
        let mut ok = 0u64;
        let t = Instant::now();
        for chunk in stream.chunks(4096) {
            d.push(std::hint::black_box(chunk), &mut |e| {
                if let Event::Frame { bytes, .. } = e {
                    if C::parse(bytes, from).is_ok() {
                        ok += 1;
                    }
                }
            });
        }
        let dt = t.elapsed().as_secs_f64();
        assert_eq!(ok, n as u64);
        best = best.min(dt);
    }
    let rate = n as f64 / best;
    println!("{label}: {:.1} M frames/s", rate / 1e6);
    rate
}

const RTU_REQUEST: [u8; 8] = [0x01, 0x03, 0xFD, 0x00, 0x00, 0x01, 0xB5, 0xA6];

#[test]
#[ignore]
fn throughput_rtu_requests() {
    run::<ModbusRtu>(&RTU_REQUEST, Some(Direction::Master), "RTU requests, 8-byte frames");
}

#[test]
#[ignore]
fn throughput_rtu_monitor() {
    run::<ModbusRtu>(&RTU_REQUEST, None, "RTU monitor, 8-byte frames");
}

#[test]
#[ignore]
fn throughput_rtu_replies() {
    let rep = [0x01, 0x03, 0x02, 0x17, 0x70, 0xB6, 0x50];
    run::<ModbusRtu>(&rep, Some(Direction::Drive), "RTU replies, 7-byte frames");
}

#[test]
#[ignore]
fn throughput_ascii() {
    run::<ModbusAscii>(b":010604051234AA\r\n", None, "ASCII, 17-char frames");
}
