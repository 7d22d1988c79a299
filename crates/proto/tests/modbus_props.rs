//! Property tests for Modbus RTU and ASCII: emit-then-parse round trips for every frame type,
//! deframers fed arbitrary bytes, valid frames found inside garbage, and split invariance.

use drivebus_proto::deframe::{Deframer, Event, Scan, Scanner};
use drivebus_proto::modbus::ascii::{AsciiScanner, ModbusAscii};
use drivebus_proto::modbus::pdu::{DeviceObject, ExceptionCode, ReadDeviceIdCode};
use drivebus_proto::modbus::rtu::{ModbusRtu, RtuScanner};
use drivebus_proto::modbus::{
    Data, DeviceIdReply, DeviceObjects, RegisterAddress, Registers, Reply, ReplyPdu, Request, RequestPdu,
    UnitId,
};
use drivebus_proto::{Codec, Describe, Direction, EmitError};
use proptest::prelude::*;

mod support;
use support::{field_count, pieces};

/// An owned request PDU, for generating.
#[derive(Clone, Debug)]
enum Req {
    Read { input: bool, start: u16, quantity: u16 },
    Write { address: u16, value: u16 },
    Diag { sub: u16, data: Vec<u8> },
    WriteMany { start: u16, values: Vec<u16> },
    DevId { code: u8, object: u8 },
    ReadWrite { read: u16, quantity: u16, write: u16, values: Vec<u16> },
    Other { function: u8, data: Vec<u8> },
}

impl Req {
    fn pdu(&self) -> RequestPdu<'_> {
        match self {
            Req::Read { input: false, start, quantity } => {
                RequestPdu::ReadHoldingRegisters { start: RegisterAddress(*start), quantity: *quantity }
            }
            Req::Read { input: true, start, quantity } => {
                RequestPdu::ReadInputRegisters { start: RegisterAddress(*start), quantity: *quantity }
            }
            Req::Write { address, value } => {
                RequestPdu::WriteSingleRegister { address: RegisterAddress(*address), value: *value }
            }
            Req::Diag { sub, data } => {
                RequestPdu::Diagnostics { sub_function: *sub, data: Data::binary(data) }
            }
            Req::WriteMany { start, values } => RequestPdu::WriteMultipleRegisters {
                start: RegisterAddress(*start),
                values: Registers::from_values(values),
            },
            Req::DevId { code, object } => {
                RequestPdu::ReadDeviceIdentification { code: ReadDeviceIdCode(*code), object_id: *object }
            }
            Req::ReadWrite { read, quantity, write, values } => RequestPdu::ReadWriteMultipleRegisters {
                read_start: RegisterAddress(*read),
                read_quantity: *quantity,
                write_start: RegisterAddress(*write),
                values: Registers::from_values(values),
            },
            Req::Other { function, data } => {
                RequestPdu::Other { function: *function, data: Data::binary(data) }
            }
        }
    }
}

/// An owned reply PDU, for generating.
#[derive(Clone, Debug)]
enum Rep {
    Read { input: bool, values: Vec<u16> },
    ReadWrite { values: Vec<u16> },
    Write { address: u16, value: u16 },
    Diag { sub: u16, data: Vec<u8> },
    WriteMany { start: u16, quantity: u16 },
    DevId { code: u8, conformity: u8, more: bool, next: u8, objects: Vec<(u8, Vec<u8>)> },
    Exception { function: u8, code: u8 },
    Other { function: u8, data: Vec<u8> },
}

impl Rep {
    fn objects(&self) -> Vec<DeviceObject<'_>> {
        match self {
            Rep::DevId { objects, .. } => objects.iter().map(|(id, v)| DeviceObject::new(*id, v)).collect(),
            _ => Vec::new(),
        }
    }

    fn pdu<'a>(&'a self, objects: &'a [DeviceObject<'a>]) -> ReplyPdu<'a> {
        match self {
            Rep::Read { input: false, values } => {
                ReplyPdu::ReadHoldingRegisters { values: Registers::from_values(values) }
            }
            Rep::Read { input: true, values } => {
                ReplyPdu::ReadInputRegisters { values: Registers::from_values(values) }
            }
            Rep::ReadWrite { values } => {
                ReplyPdu::ReadWriteMultipleRegisters { values: Registers::from_values(values) }
            }
            Rep::Write { address, value } => {
                ReplyPdu::WriteSingleRegister { address: RegisterAddress(*address), value: *value }
            }
            Rep::Diag { sub, data } => ReplyPdu::Diagnostics { sub_function: *sub, data: Data::binary(data) },
            Rep::WriteMany { start, quantity } => {
                ReplyPdu::WriteMultipleRegisters { start: RegisterAddress(*start), quantity: *quantity }
            }
            Rep::DevId { code, conformity, more, next, .. } => {
                ReplyPdu::ReadDeviceIdentification(DeviceIdReply {
                    code: ReadDeviceIdCode(*code),
                    conformity_level: *conformity,
                    more_follows: *more,
                    next_object_id: *next,
                    objects: DeviceObjects::from_list(objects),
                })
            }
            Rep::Exception { function, code } => {
                ReplyPdu::Exception { function: *function, code: ExceptionCode(*code) }
            }
            Rep::Other { function, data } => {
                ReplyPdu::Other { function: *function, data: Data::binary(data) }
            }
        }
    }
}

/// Data bytes with a byte count at `at` followed by that many bytes, after `head` fixed bytes.
fn counted(head: usize) -> impl Strategy<Value = Vec<u8>> {
    (proptest::collection::vec(any::<u8>(), head), proptest::collection::vec(any::<u8>(), 0..40)).prop_map(
        |(mut h, body)| {
            h.push(body.len() as u8);
            h.extend(body);
            h
        },
    )
}

fn fixed(n: usize) -> impl Strategy<Value = Vec<u8>> {
    proptest::collection::vec(any::<u8>(), n)
}

/// Requests. `rtu_framable`: diagnostics carry exactly 2 data bytes (the length the RTU
/// scanner predicts); otherwise any length.
fn req(rtu_framable: bool) -> impl Strategy<Value = Req> {
    let diag_len = if rtu_framable { 2..3usize } else { 0..40usize };
    prop_oneof![
        (any::<bool>(), any::<u16>(), 1..=125u16).prop_map(|(input, start, quantity)| Req::Read {
            input,
            start,
            quantity
        }),
        (any::<u16>(), any::<u16>()).prop_map(|(address, value)| Req::Write { address, value }),
        (any::<u16>(), proptest::collection::vec(any::<u8>(), diag_len))
            .prop_map(|(sub, data)| Req::Diag { sub, data }),
        (any::<u16>(), proptest::collection::vec(any::<u16>(), 1..=123))
            .prop_map(|(start, values)| Req::WriteMany { start, values }),
        (1..=4u8, any::<u8>()).prop_map(|(code, object)| Req::DevId { code, object }),
        (any::<u16>(), 1..=125u16, any::<u16>(), proptest::collection::vec(any::<u16>(), 1..=121))
            .prop_map(|(read, quantity, write, values)| Req::ReadWrite { read, quantity, write, values }),
        prop_oneof![
            (prop_oneof![Just(0x01u8), Just(0x02), Just(0x05)], fixed(4)),
            (prop_oneof![Just(0x07u8), Just(0x0B), Just(0x0C), Just(0x11)], fixed(0)),
            (Just(0x16u8), fixed(6)),
            (Just(0x18u8), fixed(2)),
            (Just(0x0Fu8), counted(4)),
            (prop_oneof![Just(0x14u8), Just(0x15)], counted(0)),
        ]
        .prop_map(|(function, data)| Req::Other { function, data }),
    ]
}

fn rep(rtu_framable: bool) -> impl Strategy<Value = Rep> {
    let diag_len = if rtu_framable { 2..3usize } else { 0..40usize };
    prop_oneof![
        (any::<bool>(), proptest::collection::vec(any::<u16>(), 1..=125))
            .prop_map(|(input, values)| Rep::Read { input, values }),
        proptest::collection::vec(any::<u16>(), 1..=125).prop_map(|values| Rep::ReadWrite { values }),
        (any::<u16>(), any::<u16>()).prop_map(|(address, value)| Rep::Write { address, value }),
        (any::<u16>(), proptest::collection::vec(any::<u8>(), diag_len))
            .prop_map(|(sub, data)| Rep::Diag { sub, data }),
        (any::<u16>(), 1..=123u16).prop_map(|(start, quantity)| Rep::WriteMany { start, quantity }),
        (
            1..=4u8,
            any::<u8>(),
            any::<bool>(),
            any::<u8>(),
            proptest::collection::vec((any::<u8>(), proptest::collection::vec(any::<u8>(), 0..30)), 0..6)
        )
            .prop_map(|(code, conformity, more, next, objects)| Rep::DevId {
                code,
                conformity,
                more,
                next,
                objects
            }),
        (1..=0x7Fu8, any::<u8>()).prop_map(|(function, code)| Rep::Exception { function, code }),
        prop_oneof![
            (
                prop_oneof![Just(0x01u8), Just(0x02), Just(0x0C), Just(0x11), Just(0x14), Just(0x15)],
                counted(0)
            ),
            (prop_oneof![Just(0x05u8), Just(0x0B), Just(0x0F)], fixed(4)),
            (Just(0x07u8), fixed(1)),
            (Just(0x16u8), fixed(6)),
            (
                Just(0x18u8),
                proptest::collection::vec(any::<u8>(), 0..20).prop_map(|b| {
                    let mut v = (b.len() as u16).to_be_bytes().to_vec();
                    v.extend(b);
                    v
                })
            ),
        ]
        .prop_map(|(function, data)| Rep::Other { function, data }),
    ]
}

/// The bytes `emit` (RTU or ASCII, request or reply) writes for `frame`.
fn emitted<T>(frame: &T, emit: fn(&T, &mut [u8]) -> Result<usize, EmitError>) -> Vec<u8> {
    let mut buf = [0u8; 513];
    let n = emit(frame, &mut buf).unwrap();
    buf[..n].to_vec()
}

/// The frames of a mix of requests and replies (`true`: the request), emitted in order by
/// `request` and `reply` (RTU or ASCII).
fn mixed(
    items: &[(bool, Req, Rep, u8)],
    request: fn(&Request<'_>, &mut [u8]) -> Result<usize, EmitError>,
    reply: fn(&Reply<'_>, &mut [u8]) -> Result<usize, EmitError>,
) -> Vec<Vec<u8>> {
    let one = |(is_req, q, p, u): &(bool, Req, Rep, u8)| {
        if *is_req {
            emitted(&Request { unit: UnitId(*u), pdu: q.pdu() }, request)
        } else {
            let objs = p.objects();
            emitted(&Reply { unit: UnitId(*u), pdu: p.pdu(&objs) }, reply)
        }
    };
    items.iter().map(one).collect()
}

fn unit() -> impl Strategy<Value = u8> {
    any::<u8>()
}

fn frames<S: Scanner>(scanner: S, chunks: &[&[u8]], silence_at_end: bool) -> (Vec<Vec<u8>>, usize) {
    let mut d = Deframer::new(scanner);
    let mut good = Vec::new();
    let mut bad = 0;
    let mut on = |e: Event<'_>| match e {
        Event::Frame { bytes, .. } => good.push(bytes.to_vec()),
        Event::Rejected { .. } => bad += 1,
    };
    for c in chunks {
        d.push(c, &mut on);
    }
    if silence_at_end {
        d.finish(&mut on);
    }
    (good, bad)
}

/// The scanner contract of deframe.rs on one buffer.
fn check_contract<S: Scanner>(s: &S, buf: &[u8], cap: usize) {
    if buf.is_empty() {
        return;
    }
    for (scan, is_silence) in [(s.scan(buf, 0), false), (s.silence(buf), true)] {
        match scan {
            // Only RTU ends frames at silence; the default keeps waiting.
            Scan::Incomplete { .. } if is_silence => {}
            Scan::Frame { len } => assert!(len >= 1 && len <= buf.len()),
            Scan::Invalid { len, skip, .. } => {
                assert!(len >= 1 && len <= buf.len(), "len {len} of {}", buf.len());
                assert!(skip >= 1 && skip <= len);
            }
            Scan::Noise { len } => assert!(len >= 1 && len <= buf.len()),
            Scan::Incomplete { checked } => {
                assert!(buf.len() < cap, "Incomplete at {} bytes", buf.len());
                assert!(checked <= buf.len());
            }
        }
    }
    let _ = s.truncated(buf).to_string();
}

proptest! {
    #[test]
    fn rtu_request_round_trip(u in unit(), r in req(false)) {
        let q = Request { unit: UnitId(u), pdu: r.pdu() };
        let f = emitted(&q, Request::emit_rtu);
        prop_assert_eq!(Request::parse_rtu(&f).unwrap(), q);
        prop_assert_eq!(ModbusRtu::parse(&f, Some(Direction::Master)).unwrap(), drivebus_proto::modbus::Frame::Request(q));
        prop_assert!(field_count(&q) >= 1);
    }

    /// A reply in RTU and in ASCII: emitted, read back the same, framed by the scanners.
    #[test]
    fn reply_round_trip(u in unit(), r in rep(false)) {
        let objs = r.objects();
        let p = Reply { unit: UnitId(u), pdu: r.pdu(&objs) };
        prop_assert!(field_count(&p) >= 1);
        let f = emitted(&p, Reply::emit_rtu);
        prop_assert_eq!(Reply::parse_rtu(&f).unwrap(), p);
        if !matches!(&r, Rep::Diag { data, .. } if data.len() != 2) {
            // Diagnostics are framed at 2 data bytes; other lengths only by silence.
            prop_assert_eq!(RtuScanner::replies().scan(&f, 0), Scan::Frame { len: f.len() });
        }
        prop_assert_eq!(RtuScanner::replies().silence(&f), Scan::Frame { len: f.len() });
        let f = emitted(&p, Reply::emit_ascii);
        prop_assert_eq!(Reply::parse_ascii(&f).unwrap(), p);
        prop_assert_eq!(ModbusAscii::parse(&f, Some(Direction::Drive)).unwrap(), drivebus_proto::modbus::Frame::Reply(p));
    }

    #[test]
    fn ascii_request_round_trip(u in unit(), r in req(false), lower in any::<bool>()) {
        let q = Request { unit: UnitId(u), pdu: r.pdu() };
        let mut f = emitted(&q, Request::emit_ascii);
        prop_assert!(!f.iter().any(|c| c.is_ascii_lowercase()));
        if lower {
            f.make_ascii_lowercase();
        }
        prop_assert_eq!(AsciiScanner.scan(&f, 0), Scan::Frame { len: f.len() });
        prop_assert_eq!(Request::parse_ascii(&f).unwrap(), q);
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..700), cuts in proptest::collection::vec(any::<usize>(), 0..4)) {
        let cuts: Vec<usize> = cuts.into_iter().map(|c| c % (bytes.len() + 1)).collect();
        let chunks = pieces(&bytes, &cuts);
        for s in [RtuScanner::requests(), RtuScanner::replies(), RtuScanner::either()] {
            let _ = frames(s, &chunks, true);
            check_contract(&s, &bytes[..bytes.len().min(300)], 256);
        }
        let _ = frames(AsciiScanner, &chunks, true);
        check_contract(&AsciiScanner, &bytes, 513);
        for from in [None, Some(Direction::Master), Some(Direction::Drive)] {
            if let Ok(f) = ModbusRtu::parse(&bytes, from) {
                f.fields(&mut |f| { let _ = f.to_string(); });
            }
            if let Ok(f) = ModbusAscii::parse(&bytes, from) {
                f.fields(&mut |f| { let _ = f.to_string(); });
            }
        }
    }

    #[test]
    fn arbitrary_ascii_text_never_panics(body in "[:0-9A-Fa-fG\r\n]{0,600}") {
        let bytes = body.as_bytes();
        let _ = frames(AsciiScanner, &[bytes], true);
        check_contract(&AsciiScanner, bytes, 513);
        let _ = ModbusAscii::parse(bytes, None);
    }

    #[test]
    fn rtu_frame_found_after_garbage(garbage in proptest::collection::vec(any::<u8>(), 0..40), r in req(true), u in 1..=247u8) {
        // Garbage may make the scanner wait for a long candidate (up to 256 bytes) before it
        // gives up on it, so enough copies of the frame follow for one to be found after that.
        let q = Request { unit: UnitId(u), pdu: r.pdu() };
        let f = emitted(&q, Request::emit_rtu);
        let copies = 256 / f.len() + 2;
        let mut s = garbage.clone();
        for _ in 0..copies {
            s.extend_from_slice(&f);
        }
        let (good, _) = frames(RtuScanner::requests(), &[&s], false);
        prop_assert!(good.contains(&f), "frame not found after {:02X?}", garbage);
        let (good, _) = frames(RtuScanner::either(), &[&s], false);
        prop_assert!(good.contains(&f));
        // With silence before the frame (what a live line gives), the frame is always next.
        let mut d = Deframer::new(RtuScanner::requests());
        let mut got = Vec::new();
        d.push(&garbage, &mut |_| {});
        d.silence(&mut |_| {});
        d.push(&f, &mut |e| if let Event::Frame { bytes, .. } = e { got.push(bytes.to_vec()) });
        prop_assert_eq!(got, vec![f.clone()]);
    }

    #[test]
    fn ascii_frame_found_after_garbage(garbage in proptest::collection::vec(any::<u8>().prop_filter("no ':'", |b| *b != b':'), 0..80), r in rep(false), u in unit()) {
        // Without a ':' the garbage cannot hold a frame; the frame after it is found.
        let objs = r.objects();
        let p = Reply { unit: UnitId(u), pdu: r.pdu(&objs) };
        let f = emitted(&p, Reply::emit_ascii);
        let mut s = garbage.clone();
        s.extend_from_slice(&f);
        let (good, bad) = frames(AsciiScanner, &[&s], true);
        prop_assert_eq!(good, vec![f]);
        prop_assert_eq!(bad, 0);
    }

    #[test]
    fn rtu_splits_give_the_same_frames(
        items in proptest::collection::vec((any::<bool>(), req(true), rep(true), 1..=247u8), 1..6),
        cut1 in any::<usize>(), cut2 in any::<usize>(),
    ) {
        let stream = mixed(&items, |r, b| r.emit_rtu(b), |r, b| r.emit_rtu(b)).concat();
        let (whole, _) = frames(RtuScanner::either(), &[&stream], true);
        let c = [cut1 % (stream.len() + 1), cut2 % (stream.len() + 1)];
        let (split, _) = frames(RtuScanner::either(), &pieces(&stream, &c), true);
        prop_assert_eq!(&split, &whole);
        let bytes: Vec<&[u8]> = stream.chunks(1).collect();
        let (one_by_one, _) = frames(RtuScanner::either(), &bytes, true);
        prop_assert_eq!(&one_by_one, &whole);
    }

    #[test]
    fn rtu_requests_stream_is_found_whole(items in proptest::collection::vec((req(true), 1..=247u8), 1..6), cut in any::<usize>()) {
        let sent: Vec<Vec<u8>> = items.iter().map(|(q, u)| emitted(&Request { unit: UnitId(*u), pdu: q.pdu() }, Request::emit_rtu)).collect();
        let stream = sent.concat();
        let c = cut % (stream.len() + 1);
        let (split, bad) = frames(RtuScanner::requests(), &[&stream[..c], &stream[c..]], true);
        prop_assert_eq!(split, sent);
        prop_assert_eq!(bad, 0);
    }

    #[test]
    fn ascii_splits_give_the_same_frames(
        items in proptest::collection::vec((any::<bool>(), req(false), rep(false), any::<u8>()), 1..6),
        cut1 in any::<usize>(), cut2 in any::<usize>(),
    ) {
        let sent = mixed(&items, |r, b| r.emit_ascii(b), |r, b| r.emit_ascii(b));
        let stream = sent.concat();
        let c = [cut1 % (stream.len() + 1), cut2 % (stream.len() + 1)];
        let (split, bad) = frames(AsciiScanner, &pieces(&stream, &c), true);
        prop_assert_eq!(split, sent);
        prop_assert_eq!(bad, 0);
    }
}
