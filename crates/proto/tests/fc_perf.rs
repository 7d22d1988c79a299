//! Throughput of the FC deframer + parse (run with
//! `cargo test --release -p drivebus-proto --test fc_perf -- --ignored --nocapture`).

use drivebus_proto::codec::Codec;
use drivebus_proto::deframe::{Deframer, Event};
use drivebus_proto::fc::{DanfossFc, FcScanner};

#[test]
#[ignore = "a measurement, not a check; run in release"]
fn frames_per_second() {
    let frames: [&[u8]; 2] = [
        &[0x02, 0x06, 0x04, 0x04, 0x7C, 0x20, 0x00, 0x58],
        &[0x02, 0x0E, 0x01, 0x22, 0x08, 0x00, 0x00, 0x00, 0x00, 0x02, 0x0C, 0x06, 0x07, 0x00, 0x00, 0x28],
    ];
    for (name, frame) in [("process 8 bytes", frames[0]), ("parameter 16 bytes", frames[1])] {
        let count = 1_000_000usize;
        let stream: Vec<u8> = frame.iter().copied().cycle().take(frame.len() * count).collect();
        let mut best = f64::MAX;
        for _ in 0..5 {
            let mut d = Deframer::new(FcScanner);
            let mut n = 0usize;
            let t = std::time::Instant::now();
            for chunk in stream.chunks(4096) {
                d.push(chunk, &mut |e| {
                    if let Event::Frame { bytes, .. } = e {
                        if DanfossFc::parse(bytes, None).is_ok() {
                            n += 1;
                        }
                    }
                });
            }
            best = best.min(t.elapsed().as_secs_f64());
            assert_eq!(n, count);
        }
        println!("{name}: {:.1} million frames/s", count as f64 / best / 1e6);
    }
}
