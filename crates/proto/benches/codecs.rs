#![allow(missing_docs)] // criterion_group! generates undocumented items
//! Parse and encode throughput of every wire format.
//!
//! Parse: a buffer of 1024 back-to-back frames (one of the manuals' examples, repeated) goes
//! through `Deframer::push` and every frame through `Codec::parse`, as a receiver does it.
//! Reported twice: frames/s (`parse_frames`) and bytes/s (`parse_bytes`).
//! Encode: the same frame emitted 1024 times into a buffer (`encode_frames`).
//! Reply matching: whether one reply answers its request, by the header look the master
//! session uses (`Protocol::reply_matches`, `reply_matches/header`) against the whole parse
//! then `Protocol::matches` (`reply_matches/parse`), the trait's default.
//!
//! Run: `cargo bench -p drivebus-proto --bench codecs` (or `bench/codecs.sh` for a summary).

use criterion::measurement::WallTime;
use criterion::{
    black_box, criterion_group, criterion_main, BenchmarkGroup, BenchmarkId, Criterion, Throughput,
};
use drivebus_proto::session::Protocol;
use drivebus_proto::{b800, fc, modbus, toshiba};
use drivebus_proto::{Codec, Deframer, Direction, Event};

const FRAMES: usize = 1024;

/// One codec: its name, a sample frame, and how it is parsed and emitted.
struct Sample {
    name: &'static str,
    frame: Vec<u8>,
    parse: fn(&[u8]) -> usize,
    emit: fn(&[u8], &mut [u8]) -> usize,
}

/// One sample frame per codec, from the manuals (protocols.md section 5).
fn samples() -> Vec<Sample> {
    use modbus::{ascii::ModbusAscii, rtu::ModbusRtu};
    use toshiba::{ascii, binary};
    let sample = |name, frame: &[u8], parse, emit| Sample { name, frame: frame.to_vec(), parse, emit };
    vec![
        // TM1: read FD00, one register.
        sample(
            "modbus-rtu",
            &[0x01, 0x03, 0xFD, 0x00, 0x00, 0x01, 0xB5, 0xA6],
            parse_all::<ModbusRtu>,
            emit_all::<ModbusRtu>,
        ),
        // M4: read 2 registers from 2102H.
        sample("modbus-ascii", b":010321020002D7\r\n", parse_all::<ModbusAscii>, emit_all::<ModbusAscii>),
        // TA5 request form with checksum: (RFE03&..)CR.
        sample("toshiba-ascii", b"(RFE03)\r", parse_all::<ascii::AsciiCodec>, emit_all::<ascii::TipAscii>),
        // TB1: R comm-no 0000.
        sample(
            "toshiba-binary",
            &[0x2F, 0x52, 0x00, 0x00, 0x81],
            parse_all::<binary::BinaryCodec>,
            emit_all::<binary::TipBinary>,
        ),
        // D1: process telegram to address 4, CTW 047C, REF 2000.
        sample(
            "danfoss-fc",
            &[0x02, 0x06, 0x04, 0x04, 0x7C, 0x20, 0x00, 0x58],
            parse_all::<fc::DanfossFc>,
            emit_all::<fc::Fc>,
        ),
        // B2: drive 5, P 40.0 Hz.
        sample("b800", b"\x7E85500960\x35\x45\x7F", parse_all::<b800::B800>, emit_all::<b800::B800>),
    ]
}

fn parse_all<C: Codec>(buf: &[u8]) -> usize {
    let mut d = Deframer::new(C::scanner(Some(Direction::Master)));
    let mut n = 0;
    d.push(buf, &mut |e| {
        if let Event::Frame { bytes, .. } = e {
            if let Ok(f) = C::parse(bytes, Some(Direction::Master)) {
                black_box(&f);
                n += 1;
            }
        }
    });
    n
}

fn run_parse(c: &mut Criterion) {
    for (unit, group_name) in [(true, "parse_frames"), (false, "parse_bytes")] {
        let mut g = c.benchmark_group(group_name);
        g.measurement_time(std::time::Duration::from_secs(2))
            .warm_up_time(std::time::Duration::from_millis(500));
        for Sample { name, frame, parse: f, .. } in samples() {
            let buf = frame.repeat(FRAMES);
            g.throughput(if unit {
                Throughput::Elements(FRAMES as u64)
            } else {
                Throughput::Bytes(buf.len() as u64)
            });
            assert_eq!(f(&buf), FRAMES, "{name}: the sample must parse");
            g.bench_with_input(BenchmarkId::from_parameter(name), &buf, |b, buf| {
                b.iter(|| f(black_box(buf)))
            });
        }
        g.finish();
    }
}

/// The generic function `f` for the session `Protocol` of the sample named `name`.
macro_rules! for_protocol {
    ($name:expr, $f:ident) => {
        match $name {
            "modbus-rtu" => $f::<modbus::rtu::ModbusRtu>,
            "modbus-ascii" => $f::<modbus::ascii::ModbusAscii>,
            "toshiba-ascii" => $f::<toshiba::ascii::TipAscii>,
            "toshiba-binary" => $f::<toshiba::binary::TipBinary>,
            "danfoss-fc" => $f::<fc::Fc>,
            _ => $f::<b800::B800>,
        }
    };
}

/// Emits the request `frame` (parsed once) `FRAMES` times into one buffer; returns the bytes written.
fn emit_all<P: Protocol + Default>(frame: &[u8], out: &mut [u8]) -> usize {
    let proto = P::default();
    let req = proto.parse_request(frame).expect("sample parses");
    let mut at = 0;
    for _ in 0..FRAMES {
        at += proto.emit_request(black_box(&req), &mut out[at..]).expect("fits");
    }
    at
}

fn run_encode(c: &mut Criterion) {
    let mut g = c.benchmark_group("encode_frames");
    g.measurement_time(std::time::Duration::from_secs(2)).warm_up_time(std::time::Duration::from_millis(500));
    for Sample { name, frame, emit: f, .. } in samples() {
        let mut out = vec![0u8; frame.len() * FRAMES];
        assert_eq!(f(&frame, &mut out), out.len(), "{name}: the emitted frames have the sample's size");
        assert_eq!(&out[..frame.len()], &frame[..], "{name}: emit gives back the manual's bytes");
        g.throughput(Throughput::Elements(FRAMES as u64));
        g.bench_function(BenchmarkId::from_parameter(name), |b| b.iter(|| f(black_box(&frame), &mut out)));
    }
    g.finish();
}

/// One request and a reply that answers it per protocol, from the manuals (protocols.md
/// section 5).
fn exchanges() -> Vec<(&'static str, Vec<u8>, Vec<u8>)> {
    vec![
        // TM1/TM2: read FD00, 60.00 Hz.
        (
            "modbus-rtu",
            vec![0x01, 0x03, 0xFD, 0x00, 0x00, 0x01, 0xB5, 0xA6],
            vec![0x01, 0x03, 0x02, 0x17, 0x70, 0xB6, 0x50],
        ),
        // M3: write 0x1234 to 0405H; the reply is identical.
        ("modbus-ascii", b":010604051234AA\r\n".to_vec(), b":010604051234AA\r\n".to_vec()),
        // TA4/TA5: read FE03, 077B.
        ("toshiba-ascii", b"(RFE03)\r".to_vec(), b"(RFE03077B)\r".to_vec()),
        // TB2: W decel time 10.0 s; the reply is identical.
        (
            "toshiba-binary",
            vec![0x2F, 0x57, 0x00, 0x10, 0x00, 0x64, 0xFA],
            vec![0x2F, 0x57, 0x00, 0x10, 0x00, 0x64, 0xFA],
        ),
        // D3/D4: read parameter 520 at address 1, a double word.
        (
            "danfoss-fc",
            vec![0x02, 0x0E, 0x01, 0x12, 0x08, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0x17],
            vec![0x02, 0x0E, 0x01, 0x22, 0x08, 0, 0, 0, 0, 0x02, 0x0C, 0x06, 0x07, 0, 0, 0x28],
        ),
        // B2/B6: drive 5, P 40.0 Hz; 'p'.
        ("b800", b"\x7E85500960\x35\x45\x7F".to_vec(), b"\x7E057033\x7F".to_vec()),
    ]
}

/// Benchmarks whether `reply` answers `request` both ways, after checking that both say yes.
fn bench_reply_matches<P: Protocol + Default>(
    g: &mut BenchmarkGroup<'_, WallTime>,
    name: &str,
    request: &[u8],
    reply: &[u8],
) {
    let proto = P::default();
    let pending = proto.pending_of_frame(request).expect("sample parses").expect("a reply is due");
    let parsed = |bytes: &[u8]| proto.parse_reply(bytes).map(|rep| proto.matches(&pending, &rep));
    assert_eq!(proto.reply_matches(&pending, reply), Ok(true), "{name}: the header answers");
    assert_eq!(parsed(reply), Ok(true), "{name}: the parsed reply answers");
    g.bench_with_input(BenchmarkId::new("header", name), reply, |b, r| {
        b.iter(|| proto.reply_matches(black_box(&pending), black_box(r)))
    });
    g.bench_with_input(BenchmarkId::new("parse", name), reply, |b, r| b.iter(|| parsed(black_box(r))));
}

fn run_reply_matches(c: &mut Criterion) {
    let mut g = c.benchmark_group("reply_matches");
    g.measurement_time(std::time::Duration::from_secs(2)).warm_up_time(std::time::Duration::from_millis(500));
    for (name, request, reply) in exchanges() {
        let f: fn(&mut BenchmarkGroup<'_, WallTime>, &str, &[u8], &[u8]) =
            for_protocol!(name, bench_reply_matches);
        f(&mut g, name, &request, &reply);
    }
    g.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default();
    targets = run_parse, run_encode, run_reply_matches
}
criterion_main!(benches);
