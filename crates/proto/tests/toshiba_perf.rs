//! Throughput of deframing + parsing back-to-back TIP frames (target: 10 million frames/s).
//!
//! Run with `cargo test --release -p drivebus-proto --test toshiba_perf -- --ignored --nocapture`.

use std::hint::black_box;
use std::time::Instant;

use drivebus_proto::codec::Codec;
use drivebus_proto::deframe::{Deframer, Event, Scanner};
use drivebus_proto::describe::Direction;
use drivebus_proto::toshiba::ascii::{AsciiAddress, AsciiCodec, AsciiRequest};
use drivebus_proto::toshiba::binary::{BinaryAddress, BinaryCodec, BinaryRequest};
use drivebus_proto::toshiba::{CommNo, TipRequest, TipScanner};

fn measure<S: Scanner>(name: &str, scanner: S, frame: &[u8], parse: impl Fn(&[u8]) -> bool) -> f64 {
    let stream: Vec<u8> = frame.iter().copied().cycle().take(frame.len() * 10_000).collect();
    let mut d = Deframer::new(scanner);
    let mut frames = 0u64;
    let start = Instant::now();
    let rounds: u64 = std::env::var("TOSHIBA_PERF_ROUNDS").ok().and_then(|r| r.parse().ok()).unwrap_or(200);
    for _ in 0..rounds {
        d.push(black_box(&stream), &mut |e| {
            if let Event::Frame { bytes, .. } = e {
                if parse(bytes) {
                    frames += 1;
                }
            }
        });
    }
    let secs = start.elapsed().as_secs_f64();
    assert_eq!(frames, rounds * 10_000);
    let rate = frames as f64 / secs;
    println!("{name:>28}: {:6.1} M frames/s ({} bytes each)", rate / 1e6, frame.len());
    rate
}

#[test]
#[ignore]
fn throughput() {
    let mut buf = [0u8; 32];
    let n = AsciiRequest::write(AsciiAddress::Unit(1), CommNo::FREQUENCY_COMMAND, 0x1770)
        .with_sum()
        .emit(&mut buf)
        .unwrap();
    let ascii = buf[..n].to_vec();
    let n = BinaryRequest::write(BinaryAddress::Unit(1), CommNo::FREQUENCY_COMMAND, 0x1770)
        .emit(&mut buf)
        .unwrap();
    let binary = buf[..n].to_vec();
    let n = BinaryRequest::read(BinaryAddress::Omitted, CommNo::OUTPUT_FREQUENCY).emit(&mut buf).unwrap();
    let read = buf[..n].to_vec();

    let a = measure("toshiba-ascii W with SUM", AsciiCodec::scanner(None), &ascii, |b| {
        AsciiCodec::parse(b, None).is_ok()
    });
    let b = measure("toshiba-binary W", BinaryCodec::scanner(Some(Direction::Master)), &binary, |b| {
        BinaryCodec::parse(b, None).is_ok()
    });
    let c = measure("toshiba-binary R (monitor)", BinaryCodec::scanner(None), &read, |b| {
        BinaryCodec::parse(b, None).is_ok()
    });
    let d = measure("TipScanner ascii", TipScanner { from: Some(Direction::Master) }, &ascii, |b| {
        TipRequest::parse(b).is_ok()
    });
    let e = measure("TipScanner binary", TipScanner { from: Some(Direction::Master) }, &binary, |b| {
        TipRequest::parse(b).is_ok()
    });
    measure("ascii scan only", AsciiCodec::scanner(None), &ascii, |b| !b.is_empty());
    let one = ascii.clone();
    measure("ascii parse only", AsciiCodec::scanner(None), &ascii, |_| {
        AsciiCodec::parse(black_box(&one), None).is_ok()
    });
    // Under valgrind (rounds set by hand) the rates mean nothing.
    if std::env::var_os("TOSHIBA_PERF_ROUNDS").is_none() {
        for r in [a, b, c, d, e] {
            assert!(r > 10e6, "below 10 M frames/s");
        }
    }
}
