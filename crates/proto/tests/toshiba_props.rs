//! Property tests for the Toshiba Inverter Protocol codecs, ASCII and binary mode.

use drivebus_proto::codec::Codec;
use drivebus_proto::deframe::{Deframer, Event, Scan, Scanner};
use drivebus_proto::describe::{Describe, Direction};
use drivebus_proto::session::Protocol;
use drivebus_proto::toshiba::ascii::{
    AsciiAddress, AsciiCodec, AsciiData, AsciiFrame, AsciiReply, AsciiReplyBody, AsciiRequest, AsciiScanner,
    TipAscii,
};
use drivebus_proto::toshiba::binary::{
    BinaryAddress, BinaryCodec, BinaryFrame, BinaryReply, BinaryReplyBody, BinaryRequest, BinaryRequestBody,
    BinaryScanner, BlockReply, BlockRequest, TipBinary,
};
use drivebus_proto::toshiba::{Cmd, CommNo, ErrorCode, Tip, TipReply, TipRequest, TipScanner};
use proptest::prelude::*;

mod support;
use support::{changed, damage, echo_refused, header_agrees, header_answers};

// ---------------------------------------------------------------- strategies

fn ascii_address() -> impl Strategy<Value = AsciiAddress> {
    prop_oneof![
        Just(AsciiAddress::Omitted),
        (0u8..=99).prop_map(AsciiAddress::Unit),
        (0u8..=9).prop_map(|u| AsciiAddress::Wildcard { tens: None, units: Some(u) }),
        (0u8..=9).prop_map(|t| AsciiAddress::Wildcard { tens: Some(t), units: None }),
        Just(AsciiAddress::ALL),
    ]
}

fn ascii_data() -> impl Strategy<Value = AsciiData> {
    (1u8..=4).prop_flat_map(|digits| {
        let max = ((1u32 << (4 * digits as u32)) - 1) as u16;
        (0..=max).prop_map(move |value| AsciiData { value, digits })
    })
}

fn ascii_request() -> impl Strategy<Value = AsciiRequest> {
    let read = (ascii_address(), any::<u16>(), any::<bool>()).prop_map(|(inv_no, c, sum)| AsciiRequest {
        inv_no,
        cmd: Cmd::R,
        comm_no: CommNo(c),
        data: None,
        sum,
    });
    let write =
        (ascii_address(), prop_oneof![Just(Cmd::W), Just(Cmd::P)], any::<u16>(), ascii_data(), any::<bool>())
            .prop_map(|(inv_no, cmd, c, d, sum)| AsciiRequest {
                inv_no,
                cmd,
                comm_no: CommNo(c),
                data: Some(d),
                sum,
            });
    prop_oneof![read, write]
}

fn ascii_reply() -> impl Strategy<Value = AsciiReply> {
    let body = prop_oneof![
        (prop_oneof![Just(Cmd::R), Just(Cmd::W), Just(Cmd::P)], any::<u16>(), any::<u16>())
            .prop_map(|(cmd, c, data)| AsciiReplyBody::Data { cmd, comm_no: CommNo(c), data }),
        any::<u16>().prop_map(|e| AsciiReplyBody::Error(ErrorCode(e))),
    ];
    (proptest::option::of(0u8..=99), any::<bool>(), body, any::<bool>())
        .prop_map(|(inv_no, tripped, body, sum)| AsciiReply { inv_no, tripped, body, sum })
}

fn binary_address() -> impl Strategy<Value = BinaryAddress> {
    prop_oneof![
        Just(BinaryAddress::Omitted),
        (0u8..=0x3F).prop_map(BinaryAddress::Unit),
        Just(BinaryAddress::Broadcast)
    ]
}

fn block_request() -> impl Strategy<Value = BlockRequest> {
    (proptest::collection::vec(any::<u16>(), 0..=2), any::<u8>())
        .prop_map(|(w, n_r)| BlockRequest::new(&w, n_r).expect("0-2 groups"))
}

fn binary_request() -> impl Strategy<Value = BinaryRequest> {
    let body = prop_oneof![
        any::<u16>().prop_map(|c| BinaryRequestBody::Read { comm_no: CommNo(c) }),
        (any::<u16>(), any::<u16>())
            .prop_map(|(c, data)| BinaryRequestBody::Write { comm_no: CommNo(c), data }),
        (any::<u16>(), any::<u16>())
            .prop_map(|(c, data)| BinaryRequestBody::WriteRam { comm_no: CommNo(c), data }),
        (any::<u16>(), any::<u16>())
            .prop_map(|(c, dummy)| BinaryRequestBody::ReadDummy { comm_no: CommNo(c), dummy }),
        block_request().prop_map(BinaryRequestBody::Block),
    ];
    (binary_address(), body).prop_map(|(inv_no, body)| BinaryRequest { inv_no, body })
}

fn binary_reply() -> impl Strategy<Value = BinaryReply> {
    let body = prop_oneof![
        (prop_oneof![Just(Cmd::R), Just(Cmd::W), Just(Cmd::P), Just(Cmd::G)], any::<u16>(), any::<u16>())
            .prop_map(|(cmd, c, data)| BinaryReplyBody::Data { cmd, comm_no: CommNo(c), data }),
        proptest::collection::vec(any::<u16>(), 0..=5)
            .prop_map(|r| BinaryReplyBody::Block(BlockReply::new(&r).expect("0-5 groups"))),
        any::<u16>().prop_map(|e| BinaryReplyBody::Error(ErrorCode(e))),
    ];
    (proptest::option::of(0u8..=0x3F), any::<bool>(), body).prop_map(|(inv_no, tripped, body)| BinaryReply {
        inv_no,
        tripped,
        body,
    })
}

// ---------------------------------------------------------------- helpers

/// What an inverter numbered in `inv` answers: its number, tripped, DATA and an error code.
fn answer_parts(inv: std::ops::RangeInclusive<u8>) -> impl Strategy<Value = (u8, bool, u16, u16)> {
    (inv, any::<bool>(), any::<u16>(), any::<u16>())
}

/// `frame` with its binary-mode SUM (the last byte) made right again.
fn resummed(mut frame: Vec<u8>) -> Vec<u8> {
    if let Some((last, covered)) = frame.split_last_mut() {
        *last = drivebus_proto::checksum::sum8(covered);
    }
    frame
}

fn emit_with(f: impl Fn(&mut [u8]) -> Result<usize, drivebus_proto::EmitError>) -> Vec<u8> {
    let mut b = [0u8; 32];
    let n = f(&mut b).expect("valid frame emits");
    b[..n].to_vec()
}

/// Frames found by a deframer over `chunks`, in order.
fn deframe<S: Scanner>(scanner: S, chunks: &[&[u8]]) -> Vec<Vec<u8>> {
    let mut d = Deframer::new(scanner);
    let mut out = Vec::new();
    for c in chunks {
        d.push(c, &mut |e| {
            if let Event::Frame { bytes, .. } = e {
                out.push(bytes.to_vec())
            }
        });
    }
    d.finish(&mut |e| {
        if let Event::Frame { bytes, .. } = e {
            out.push(bytes.to_vec())
        }
    });
    out
}

/// Feeds `bytes` in chunks of the given sizes and finishes; only checks that nothing panics
/// and that the deframer never holds more than its buffer.
fn churn<S: Scanner>(scanner: S, bytes: &[u8], sizes: &[usize]) {
    let mut d = Deframer::new(scanner);
    let mut at = 0;
    let mut i = 0;
    while at < bytes.len() {
        let n = sizes.get(i % sizes.len().max(1)).copied().unwrap_or(1).max(1).min(bytes.len() - at);
        d.push(&bytes[at..at + n], &mut |e| {
            if let Event::Frame { bytes, .. } = e {
                assert!(!bytes.is_empty());
            }
        });
        at += n;
        i += 1;
    }
    d.finish(&mut |_| {});
    assert_eq!(d.buffered(), 0);
}

/// Every result obeys deframe.rs: progress, no `Incomplete` beyond the buffer, and the
/// `checked` hint of a prefix does not change the verdict.
fn check_contract<S: Scanner>(scanner: S, bytes: &[u8]) -> Result<(), TestCaseError> {
    let cap = <S::Buffer as drivebus_proto::deframe::FrameBuffer>::zeroed().as_ref().len();
    let mut checked = 0;
    for end in 1..=bytes.len() {
        let buf = &bytes[..end];
        let scan = scanner.scan(buf, checked);
        prop_assert_eq!(scan, scanner.scan(buf, 0), "checked hint changed the verdict at {}", end);
        match scan {
            Scan::Frame { len } => prop_assert!((1..=end).contains(&len)),
            Scan::Invalid { len, skip, .. } => prop_assert!(1 <= skip && skip <= len && len <= end),
            Scan::Noise { len } => prop_assert!((1..=end).contains(&len)),
            Scan::Incomplete { checked: c } => {
                prop_assert!(end < cap, "Incomplete with {} bytes, buffer {}", end, cap);
                checked = c;
                continue;
            }
        }
        break;
    }
    Ok(())
}

fn describe_all(f: &impl Describe) {
    let _ = (f.direction(), f.target(), f.command(), f.is_refusal());
    f.fields(&mut |field| {
        let _ = field.to_string();
    });
}

// ---------------------------------------------------------------- properties

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn ascii_request_round_trip(req in ascii_request()) {
        let bytes = emit_with(|b| req.emit(b));
        prop_assert!(bytes.len() <= 17);
        prop_assert_eq!(AsciiRequest::parse(&bytes), Ok(req));
        prop_assert_eq!(AsciiCodec::parse(&bytes, None), Ok(AsciiFrame::Request(req)));
        prop_assert_eq!(TipAscii::default().parse_request(&bytes), Ok(req));
        prop_assert_eq!(deframe(AsciiScanner, &[&bytes]), vec![bytes.clone()]);
        describe_all(&AsciiFrame::Request(req));
    }

    #[test]
    fn ascii_reply_round_trip(rep in ascii_reply()) {
        let bytes = emit_with(|b| rep.emit(b));
        prop_assert!(bytes.len() <= 17);
        prop_assert_eq!(AsciiReply::parse(&bytes), Ok(rep));
        prop_assert_eq!(AsciiCodec::parse(&bytes, Some(Direction::Drive)), Ok(AsciiFrame::Reply(rep)));
        prop_assert_eq!(deframe(AsciiScanner, &[&bytes]), vec![bytes.clone()]);
        // A reply is never taken for a request by a drive.
        let echo = matches!(rep.body, AsciiReplyBody::Data { cmd: Cmd::W | Cmd::P, .. }) && !rep.tripped;
        prop_assert!(AsciiRequest::parse(&bytes).is_err() || echo);
        describe_all(&AsciiFrame::Reply(rep));
    }

    #[test]
    fn binary_request_round_trip(req in binary_request()) {
        let bytes = emit_with(|b| req.emit(b));
        prop_assert!(bytes.len() <= 15);
        prop_assert_eq!(BinaryRequest::parse(&bytes), Ok(req));
        prop_assert_eq!(BinaryCodec::parse(&bytes, None), Ok(BinaryFrame::Request(req)));
        prop_assert_eq!(BinaryCodec::parse(&bytes, Some(Direction::Master)), Ok(BinaryFrame::Request(req)));
        prop_assert_eq!(TipBinary::default().parse_request(&bytes), Ok(req));
        prop_assert_eq!(deframe(BinaryScanner { from: Some(Direction::Master) }, &[&bytes]), vec![bytes.clone()]);
        prop_assert_eq!(deframe(TipScanner { from: Some(Direction::Master) }, &[&bytes]), vec![bytes.clone()]);
        describe_all(&BinaryFrame::Request(req));
    }

    #[test]
    fn binary_reply_round_trip(rep in binary_reply()) {
        let bytes = emit_with(|b| rep.emit(b));
        prop_assert!(bytes.len() <= 15);
        prop_assert_eq!(BinaryReply::parse(&bytes), Ok(rep));
        prop_assert_eq!(BinaryCodec::parse(&bytes, Some(Direction::Drive)), Ok(BinaryFrame::Reply(rep)));
        prop_assert_eq!(TipBinary::default().parse_reply(&bytes), Ok(rep));
        prop_assert_eq!(deframe(BinaryScanner { from: Some(Direction::Drive) }, &[&bytes]), vec![bytes.clone()]);
        prop_assert_eq!(deframe(TipScanner { from: Some(Direction::Drive) }, &[&bytes]), vec![bytes.clone()]);
        describe_all(&BinaryFrame::Reply(rep));
    }

    #[test]
    fn arbitrary_bytes_never_panic(
        bytes in proptest::collection::vec(any::<u8>(), 0..200),
        sizes in proptest::collection::vec(1usize..20, 1..8),
        me in any::<u8>(),
    ) {
        churn(AsciiScanner, &bytes, &sizes);
        for from in [None, Some(Direction::Master), Some(Direction::Drive)] {
            churn(BinaryScanner { from }, &bytes, &sizes);
            churn(TipScanner { from }, &bytes, &sizes);
        }
        for end in 0..bytes.len().min(20) {
            let b = &bytes[..end];
            for from in [None, Some(Direction::Master), Some(Direction::Drive)] {
                if let Ok(f) = AsciiCodec::parse(b, from) { describe_all(&f); }
                if let Ok(f) = BinaryCodec::parse(b, from) { describe_all(&f); }
            }
            let _ = Tip::rejection_reply(b, me, false);
            let err = drivebus_proto::FrameError::Malformed("x");
            let _ = Tip::default().rejected_disposition(b, &err, me);
        }
    }

    #[test]
    fn ascii_frame_found_in_any_garbage(
        pre in proptest::collection::vec(any::<u8>(), 0..40),
        post in proptest::collection::vec(any::<u8>(), 0..40),
        req in ascii_request(),
    ) {
        // '(' always starts a frame anew and never occurs inside one, so any garbage before a
        // frame is cut off by its start code.
        let frame = emit_with(|b| req.emit(b));
        let stream: Vec<u8> = pre.iter().chain(&frame).chain(&post).copied().collect();
        let found = deframe(AsciiScanner, &[&stream]);
        prop_assert!(found.contains(&frame), "{:?} not in {:?}", frame, found);
    }

    #[test]
    fn binary_frame_found_in_garbage_without_start_codes(
        pre in proptest::collection::vec(any::<u8>().prop_filter("no start code", |b| *b != 0x2F && *b != b'('), 0..40),
        post in proptest::collection::vec(any::<u8>(), 0..40),
        req in binary_request(),
        rep in binary_reply(),
    ) {
        let frame = emit_with(|b| req.emit(b));
        let stream: Vec<u8> = pre.iter().chain(&frame).chain(&post).copied().collect();
        prop_assert_eq!(&deframe(BinaryScanner { from: Some(Direction::Master) }, &[&stream])[0], &frame);
        prop_assert_eq!(&deframe(TipScanner { from: Some(Direction::Master) }, &[&stream])[0], &frame);
        let frame = emit_with(|b| rep.emit(b));
        let stream: Vec<u8> = pre.iter().chain(&frame).chain(&post).copied().collect();
        prop_assert_eq!(&deframe(BinaryScanner { from: Some(Direction::Drive) }, &[&stream])[0], &frame);
        prop_assert_eq!(&deframe(TipScanner { from: Some(Direction::Drive) }, &[&stream])[0], &frame);
    }

    #[test]
    fn any_split_gives_the_same_frames(
        ascii in proptest::collection::vec(ascii_request(), 1..4),
        binary in proptest::collection::vec(binary_request(), 1..4),
        replies in proptest::collection::vec(binary_reply(), 1..4),
        cut1 in any::<prop::sample::Index>(),
        cut2 in any::<prop::sample::Index>(),
    ) {
        let mut frames: Vec<Vec<u8>> = Vec::new();
        for (a, b) in ascii.iter().zip(binary.iter().cycle()) {
            frames.push(emit_with(|o| a.emit(o)));
            frames.push(emit_with(|o| b.emit(o)));
        }
        let stream: Vec<u8> = frames.concat();
        let (i, j) = {
            let (a, b) = (cut1.index(stream.len() + 1), cut2.index(stream.len() + 1));
            (a.min(b), a.max(b))
        };
        let chunks: [&[u8]; 3] = [&stream[..i], &stream[i..j], &stream[j..]];
        // A drive hearing both modes.
        let scanner = TipScanner { from: Some(Direction::Master) };
        prop_assert_eq!(&deframe(scanner, &[&stream]), &frames);
        prop_assert_eq!(&deframe(scanner, &chunks), &frames);
        // Binary only, master side.
        let frames: Vec<Vec<u8>> = replies.iter().map(|r| emit_with(|o| r.emit(o))).collect();
        let stream = frames.concat();
        let (i, j) = {
            let (a, b) = (cut1.index(stream.len() + 1), cut2.index(stream.len() + 1));
            (a.min(b), a.max(b))
        };
        let scanner = BinaryScanner { from: Some(Direction::Drive) };
        prop_assert_eq!(&deframe(scanner, &[&stream]), &frames);
        prop_assert_eq!(&deframe(scanner, &[&stream[..i], &stream[i..j], &stream[j..]]), &frames);
        // ASCII only.
        let frames: Vec<Vec<u8>> = ascii.iter().map(|r| emit_with(|o| r.emit(o))).collect();
        let stream = frames.concat();
        let i = cut1.index(stream.len() + 1);
        prop_assert_eq!(&deframe(AsciiScanner, &[&stream[..i], &stream[i..]]), &frames);
    }

    #[test]
    fn scanners_keep_the_contract(bytes in proptest::collection::vec(any::<u8>(), 1..40), start in 0usize..3) {
        let mut bytes = bytes;
        // Often start at a start code, to reach the frame logic.
        match start {
            0 => bytes[0] = 0x2F,
            1 => bytes[0] = b'(',
            _ => {}
        }
        check_contract(AsciiScanner, &bytes)?;
        for from in [None, Some(Direction::Master), Some(Direction::Drive)] {
            check_contract(BinaryScanner { from }, &bytes)?;
            check_contract(TipScanner { from }, &bytes)?;
        }
    }

    #[test]
    fn frequency_round_trip(centi in any::<u16>()) {
        let f = drivebus_proto::toshiba::Frequency(centi);
        prop_assert_eq!(drivebus_proto::toshiba::Frequency::from_hz(f.hz()), Some(f));
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// The header look at an ASCII-mode reply agrees with the whole parse: the inverter's own
    /// answer, its error reply, any other reply, a changed byte, and junk.
    #[test]
    fn ascii_header_look_agrees_with_the_parse(
        req in ascii_request(),
        other in ascii_reply(),
        (me, tripped, data, code) in answer_parts(0u8..=99),
        (at, to, junk) in damage(),
    ) {
        let proto = TipAscii::default();
        let pending = proto.pending(&req).expect("a wildcard is answered by default");
        let me = pending.inv_no.unwrap_or(me);
        let answer = emit_with(|b| req.reply(me, tripped, data).emit(b));
        header_answers(&proto, &pending, &answer)?;
        let refusal = emit_with(|b| req.error_reply(me, tripped, ErrorCode(code)).emit(b));
        header_answers(&proto, &pending, &refusal)?;
        header_agrees(&proto, &pending, &emit_with(|b| other.emit(b)))?;
        header_agrees(&proto, &pending, &changed(&answer, at, to))?;
        header_agrees(&proto, &pending, &junk)?;
        // The request itself, heard as an echo: R without DATA is no reply, an error as the
        // parse says; a W or P echo reads as the reply it looks like.
        echo_refused(&proto, &pending, &emit_with(|b| req.emit(b)))?;
    }

    /// The same for binary mode: the answer, the error reply, any reply, a changed byte with
    /// its SUM made right, and junk.
    #[test]
    fn binary_header_look_agrees_with_the_parse(
        req in binary_request(),
        other in binary_reply(),
        (me, tripped, data, code) in answer_parts(0u8..=0x3F),
        (at, to, junk) in damage(),
    ) {
        let proto = TipBinary::default();
        let pending = proto.pending(&req).expect("a broadcast is answered by default");
        let me = pending.inv_no.unwrap_or(me);
        if let Some(answer) = req.reply(me, tripped, data) {
            let answer = emit_with(|b| answer.emit(b));
            header_answers(&proto, &pending, &answer)?;
            header_agrees(&proto, &pending, &resummed(changed(&answer, at, to)))?;
        }
        let refusal = emit_with(|b| req.error_reply(me, tripped, ErrorCode(code)).emit(b));
        header_answers(&proto, &pending, &refusal)?;
        let other = emit_with(|b| other.emit(b));
        header_agrees(&proto, &pending, &other)?;
        header_agrees(&proto, &pending, &resummed(changed(&other, at, to)))?;
        header_agrees(&proto, &pending, &junk)?;
        // The request heard as an echo: R and X are no replies.
        echo_refused(&proto, &pending, &emit_with(|b| req.emit(b)))?;
    }

    /// Both modes on one line: a reply of either mode against a request of either mode.
    #[test]
    fn tip_header_look_agrees_with_the_parse(
        (ascii, binary) in (ascii_request(), binary_request()),
        (ascii_rep, binary_rep) in (ascii_reply(), binary_reply()),
        binary_first in any::<bool>(),
    ) {
        let proto = Tip::default();
        let (a, b) = (TipRequest::Ascii(ascii), TipRequest::Binary(binary));
        let req = if binary_first { b } else { a };
        let pending = proto.pending(&req).expect("answered by default");
        for rep in [TipReply::Ascii(ascii_rep), TipReply::Binary(binary_rep)] {
            header_agrees(&proto, &pending, &emit_with(|buf| rep.emit(buf)))?;
        }
        if let Some(answer) = req.reply(0, false, 0x1234) {
            header_agrees(&proto, &pending, &emit_with(|buf| answer.emit(buf)))?;
        }
    }
}

#[test]
fn codec_names() {
    assert_eq!(AsciiCodec::NAME, "toshiba-ascii");
    assert_eq!(BinaryCodec::NAME, "toshiba-binary");
}
