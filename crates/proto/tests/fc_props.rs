//! Property tests for the Danfoss FC codec: round trips, the scanner contract, garbage,
//! and splits.

use drivebus_proto::codec::Codec;
use drivebus_proto::deframe::{Deframer, Event, Scan, Scanner};
use drivebus_proto::describe::{Describe, Direction};
use drivebus_proto::fc::Fc;
use drivebus_proto::fc::{
    Adr, Block, ControlWord, DanfossFc, FcScanner, Message, ParameterBlock, ParameterCommand,
    ParameterNumber, ParameterResponse, Reference, Reply, Request, StatusWord, TextBlock, MAX_TELEGRAM,
};
use drivebus_proto::session::Protocol;
use proptest::prelude::*;

mod support;
use support::{changed, damage, echo_refused, field_count, header_agrees, header_answers, pieces};

const COMMANDS: [u8; 8] = [0x0, 0x1, 0x2, 0x3, 0x4, 0xD, 0xE, 0xF];
const RESPONSES: [u8; 6] = [0x0, 0x1, 0x2, 0x3, 0x7, 0xF];

/// Everything a telegram carries, owned, so a typed frame can borrow the text.
#[derive(Clone, Debug)]
struct Spec {
    adr: Adr,
    /// 0 process, 1 parameter, 2 text.
    kind: u8,
    ak_index: usize,
    pnu: ParameterNumber,
    ind: u16,
    pwe: u32,
    text: Vec<u8>,
    pcd1: u16,
    pcd2: u16,
}

fn adr() -> impl Strategy<Value = Adr> {
    any::<u8>().prop_filter_map("valid ADR", |b| Adr::from_byte(b).ok())
}

fn spec() -> impl Strategy<Value = Spec> {
    (
        adr(),
        0u8..3,
        0usize..8,
        (0u16..=ParameterNumber::MAX).prop_map(|p| ParameterNumber::new(p).unwrap()),
        any::<u16>(),
        any::<u32>(),
        // A 4-character text is a parameter block on the wire: see `four_character_text`.
        proptest::collection::vec(any::<u8>(), 0..=100).prop_filter("not 4 chars", |t| t.len() != 4),
        any::<u16>(),
        any::<u16>(),
    )
        .prop_map(|(adr, kind, ak_index, pnu, ind, pwe, text, pcd1, pcd2)| Spec {
            adr,
            kind,
            ak_index,
            pnu,
            ind,
            pwe,
            text,
            pcd1,
            pcd2,
        })
}

fn block<'a, A>(s: &'a Spec, ak: A) -> Block<'a, A> {
    match s.kind {
        0 => Block::Process,
        1 => Block::Parameter(ParameterBlock { ak, pnu: s.pnu, ind: s.ind, pwe: s.pwe }),
        _ => Block::Text(TextBlock { ak, pnu: s.pnu, ind: s.ind, text: &s.text }),
    }
}

fn request(s: &Spec) -> Request<'_> {
    let ak = ParameterCommand::from_ak(COMMANDS[s.ak_index % COMMANDS.len()]).unwrap();
    Request {
        adr: s.adr,
        block: block(s, ak),
        ctw: ControlWord(s.pcd1),
        reference: Reference::from_word(s.pcd2),
    }
}

fn reply(s: &Spec) -> Reply<'_> {
    let ak = ParameterResponse::from_ak(RESPONSES[s.ak_index % RESPONSES.len()]).unwrap();
    Reply { adr: s.adr, block: block(s, ak), stw: StatusWord(s.pcd1), mav: Reference::from_word(s.pcd2) }
}

fn emit_request(s: &Spec) -> Vec<u8> {
    let mut b = [0u8; MAX_TELEGRAM];
    let n = request(s).emit(&mut b).unwrap();
    b[..n].to_vec()
}

fn emit_reply(s: &Spec) -> Vec<u8> {
    let mut b = [0u8; MAX_TELEGRAM];
    let n = reply(s).emit(&mut b).unwrap();
    b[..n].to_vec()
}

/// Deframes `chunks`, then lets the line go silent until nothing is held (an FC telegram
/// cut short dies at the first gap of more than 2 characters): good frames with their
/// stream positions, and the count of rejected candidates.
fn deframe_at(chunks: &[&[u8]]) -> (Vec<(u64, Vec<u8>)>, usize) {
    let mut d = Deframer::new(FcScanner);
    let mut good = Vec::new();
    let mut rejected = 0;
    let mut on = |e: Event<'_>| match e {
        Event::Frame { bytes, position } => good.push((position, bytes.to_vec())),
        Event::Rejected { .. } => rejected += 1,
    };
    for c in chunks {
        d.push(c, &mut on);
    }
    while d.buffered() > 0 {
        d.silence(&mut on);
    }
    d.finish(&mut on);
    (good, rejected)
}

fn deframe(chunks: &[&[u8]]) -> (Vec<Vec<u8>>, usize) {
    let (good, rejected) = deframe_at(chunks);
    (good.into_iter().map(|(_, f)| f).collect(), rejected)
}

/// True when `good` at `start` was found, or a false telegram (a chance BCC match inside a
/// broken one, 1 in 256) took some of its bytes.
fn found_or_overlapped(found: &[(u64, Vec<u8>)], start: usize, good: &[u8]) -> bool {
    let (start, end) = (start as u64, (start + good.len()) as u64);
    found
        .iter()
        .any(|(p, f)| (*p == start && f == good) || (*p != start && *p < end && p + f.len() as u64 > start))
}

/// Bytes that cannot hold a telegram: no STX.
fn garbage() -> impl Strategy<Value = Vec<u8>> {
    proptest::collection::vec(any::<u8>().prop_filter("no STX", |&b| b != 0x02), 0..40)
}

proptest! {
    #[test]
    fn request_round_trip(s in spec()) {
        let bytes = emit_request(&s);
        prop_assert_eq!(bytes.len(), request(&s).block.lge() + 2);
        prop_assert_eq!(FcScanner.scan(&bytes, 0), Scan::Frame { len: bytes.len() });
        prop_assert_eq!(Request::parse(&bytes).unwrap(), request(&s));
        // The codec reads it as the master's when told so (AK 7 is never a command).
        let f = DanfossFc::parse(&bytes, Some(Direction::Master)).unwrap();
        prop_assert_eq!(f.message, Message::Request(request(&s)));
        prop_assert_eq!(f.target(), s.adr.target());
        prop_assert!(field_count(&f) >= 4);
    }

    #[test]
    fn reply_round_trip(s in spec()) {
        let bytes = emit_reply(&s);
        prop_assert_eq!(Reply::parse(&bytes).unwrap(), reply(&s));
        // Told it is the drive's, the codec reads it so (no response AK is only the master's).
        let f = DanfossFc::parse(&bytes, Some(Direction::Drive)).unwrap();
        prop_assert_eq!(f.message, Message::Reply(reply(&s)));
        prop_assert_eq!(f.is_refusal(), reply(&s).response() == Some(ParameterResponse::CannotPerform));
    }

    #[test]
    fn four_character_text(s in spec(), text in proptest::array::uniform4(any::<u8>())) {
        let r = Request { block: Block::Text(TextBlock { ak: ParameterCommand::Text, pnu: s.pnu, ind: s.ind, text: &text }), ..request(&s) };
        let mut b = [0u8; MAX_TELEGRAM];
        let n = r.emit(&mut b).unwrap();
        prop_assert_eq!(n, 16);
        let Block::Parameter(p) = Request::parse(&b[..n]).unwrap().block else { panic!() };
        prop_assert_eq!(p.pwe_bytes(), text);
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..600), cut in 0usize..600) {
        let cut = cut.min(bytes.len());
        deframe(&[&bytes[..cut], &bytes[cut..]]);
        let _ = DanfossFc::parse(&bytes, None);
        let _ = Request::parse(&bytes);
        let _ = Reply::parse(&bytes);
        if !bytes.is_empty() {
            match FcScanner.scan(&bytes, 0) {
                Scan::Frame { len } => prop_assert!(len >= 8 && len <= bytes.len()),
                Scan::Invalid { len, skip, .. } => prop_assert!(skip >= 1 && skip <= len && len <= bytes.len()),
                Scan::Noise { len } => prop_assert!(len >= 1 && len <= bytes.len()),
                Scan::Incomplete { .. } => prop_assert!(bytes.len() < MAX_TELEGRAM),
            }
        }
    }

    #[test]
    fn arbitrary_stx_streams_never_panic(body in proptest::collection::vec(prop_oneof![Just(0x02u8), Just(0x06), Just(0x0E), any::<u8>()], 0..400)) {
        let (good, _) = deframe(&[&body]);
        for g in good {
            let _ = DanfossFc::parse(&g, None);
        }
    }

    #[test]
    fn frame_inside_garbage_is_found(s in spec(), before in garbage(), after in garbage(), as_reply in any::<bool>()) {
        let frame = if as_reply { emit_reply(&s) } else { emit_request(&s) };
        let mut stream = before.clone();
        stream.extend_from_slice(&frame);
        stream.extend_from_slice(&after);
        let (good, rejected) = deframe(&[&stream]);
        prop_assert_eq!(good, vec![frame]);
        prop_assert_eq!(rejected, 0);
    }

    #[test]
    fn frame_after_a_broken_one_is_found(s in spec(), t in spec(), cut in 1usize..200, flip in 1u8..=255) {
        // A telegram with a corrupted byte (its LGE included), then a good one.
        let bad = emit_request(&s);
        let good = emit_reply(&t);
        let mut broken = bad.clone();
        let at = cut % broken.len();
        broken[at] ^= flip;
        let mut stream = broken.clone();
        stream.extend_from_slice(&good);
        let (found, _) = deframe_at(&[&stream]);
        prop_assert!(found_or_overlapped(&found, broken.len(), &good), "{:02X?} not in {:02X?}", good, found);
        // A telegram cut short, then a good one.
        let head = &bad[..cut.min(bad.len() - 1)];
        let mut stream = head.to_vec();
        stream.extend_from_slice(&good);
        let (found, _) = deframe_at(&[&stream]);
        prop_assert!(found_or_overlapped(&found, head.len(), &good), "{:02X?} not in {:02X?}", good, found);
    }

    #[test]
    fn any_split_gives_the_same_frames(specs in proptest::collection::vec((spec(), garbage(), any::<bool>()), 1..6), cuts in proptest::collection::vec(any::<prop::sample::Index>(), 0..8)) {
        let mut stream = Vec::new();
        let mut frames = Vec::new();
        for (s, junk, as_reply) in &specs {
            stream.extend_from_slice(junk);
            let f = if *as_reply { emit_reply(s) } else { emit_request(s) };
            stream.extend_from_slice(&f);
            frames.push(f);
        }
        let (whole, _) = deframe(&[&stream]);
        prop_assert_eq!(&whole, &frames);
        let points: Vec<usize> = cuts.iter().map(|i| i.index(stream.len() + 1)).collect();
        let (split, _) = deframe(&pieces(&stream, &points));
        prop_assert_eq!(split, whole);
        let bytes: Vec<&[u8]> = stream.chunks(1).collect();
        prop_assert_eq!(deframe(&bytes).0, frames);
    }
}

/// `telegram` with its BCC (the last byte) made right again.
fn rebcc(mut telegram: Vec<u8>) -> Vec<u8> {
    if let Some((last, covered)) = telegram.split_last_mut() {
        *last = drivebus_proto::checksum::xor8(covered);
    }
    telegram
}

proptest! {
    /// The header look at a reply (ADR, LGE, PKE) agrees with the whole parse: the drive's
    /// answer, replies with the request's ADR or PNU or neither, a changed byte with its BCC
    /// made right, and junk.
    #[test]
    fn header_look_agrees_with_the_parse(
        req in spec(),
        other in spec(),
        (same_adr, same_pnu) in (any::<bool>(), any::<bool>()),
        (at, to, junk) in damage(),
    ) {
        let proto = Fc::default();
        let pending = proto.pending(&request(&req));
        prop_assume!(pending.is_some(), "a broadcast gets no reply");
        let pending = pending.unwrap();
        // The drive's answer: the same ADR, the same kind of block, the PNU echoed.
        let kind = if req.kind == 0 { 0 } else { 1 + other.kind % 2 };
        let answer = Spec { adr: req.adr, pnu: req.pnu, kind, ..other.clone() };
        header_answers(&proto, &pending, &emit_reply(&answer))?;
        let mut near = other.clone();
        if same_adr {
            near.adr = req.adr;
        }
        if same_pnu {
            near.pnu = req.pnu;
        }
        for bytes in [emit_reply(&near), emit_reply(&other), rebcc(changed(&emit_reply(&answer), at, to)), junk] {
            header_agrees(&proto, &pending, &bytes)?;
        }
        echo_refused(&proto, &pending, &emit_request(&req))?;
    }
}
