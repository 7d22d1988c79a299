//! Throughput of `Deframer::push` + `Codec::parse` over back-to-back B800 frames.
//! Run with `cargo test --release -p drivebus-proto --test b800_throughput -- --ignored --nocapture`.

use std::hint::black_box;
use std::time::Instant;

use drivebus_proto::b800::{
    Address, FrameScanner, MasterCommand, Packet, Reply, Request, SlaveReply, Speed, B800, MAX_FRAME,
};
use drivebus_proto::deframe::{Deframer, Event};
use drivebus_proto::Codec;

#[test]
#[ignore = "a measurement, run in release"]
fn frames_per_second() {
    let one = Address::new(1).unwrap();
    let packets = [
        Packet::Request(Request::to_drive(one, MasterCommand::Status)),
        Packet::Reply(Reply::new(one, SlaveReply::Run)),
        Packet::Request(Request::to_drive(one, MasterCommand::SetSpeed(Speed::from_raw(0x0960)))),
        Packet::Reply(Reply::new(one, SlaveReply::SpeedHz(Speed::from_raw(0x0960)))),
    ];
    let mut stream = Vec::new();
    let mut frames = 0u64;
    while stream.len() < 1 << 20 {
        for p in &packets {
            let mut buf = [0u8; MAX_FRAME];
            let n = p.emit(&mut buf).unwrap();
            stream.extend_from_slice(&buf[..n]);
            frames += 1;
        }
    }
    let rounds = 20;
    let start = Instant::now();
    let mut ok = 0u64;
    for _ in 0..rounds {
        let mut d = Deframer::new(FrameScanner::new(None));
        // Reads of 256 bytes, as from a serial port.
        for chunk in black_box(&stream).chunks(256) {
            d.push(chunk, &mut |e| {
                if let Event::Frame { bytes, .. } = e {
                    if <B800 as Codec>::parse(bytes, None).is_ok() {
                        ok += 1;
                    }
                }
            });
        }
    }
    let secs = start.elapsed().as_secs_f64();
    assert_eq!(ok, frames * rounds);
    let rate = ok as f64 / secs;
    println!(
        "b800: {:.1} million frames/s ({:.0} MB/s)",
        rate / 1e6,
        (stream.len() as f64 * rounds as f64) / secs / 1e6
    );
}
