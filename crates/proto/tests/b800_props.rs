//! Property tests for the B800 codec: emit/parse round trips, the deframer on arbitrary
//! bytes, frames inside garbage, and streams split anywhere.

use drivebus_proto::b800;
use drivebus_proto::b800::{
    Address, Current, Destination, DriveStatus, ErrorCode, FrameScanner, MasterCommand, Packet, Reply,
    Request, Rpm, SlaveReply, Speed, Version, B800, FG1, FG2, MAX_FRAME, SCAN_LIMIT,
};
use drivebus_proto::checksum::not_sum8;
use drivebus_proto::deframe::{Deframer, Event, Scan, Scanner, Stats};
use drivebus_proto::describe::{Describe, Direction};
use drivebus_proto::hex::byte_digits;
use drivebus_proto::session::Protocol;
use drivebus_proto::{Codec, FrameError};
use proptest::prelude::*;

mod support;
use support::{changed, damage, echo_refused, field_count, header_agrees, header_answers, pieces};

fn address() -> impl Strategy<Value = Address> {
    (1u8..=63).prop_map(|n| Address::new(n).unwrap())
}

fn command() -> impl Strategy<Value = MasterCommand> {
    prop_oneof![
        Just(MasterCommand::Run),
        Just(MasterCommand::Stop),
        Just(MasterCommand::MotorCurrent),
        Just(MasterCommand::SpeedHz),
        Just(MasterCommand::SpeedRpm),
        Just(MasterCommand::Status),
        Just(MasterCommand::Version),
        any::<u16>().prop_map(|w| MasterCommand::SetSpeed(Speed::from_raw(w))),
        Just(MasterCommand::Increase),
        Just(MasterCommand::Reduce),
    ]
}

fn request() -> impl Strategy<Value = Request> {
    let da = prop_oneof![address().prop_map(Destination::Drive), Just(Destination::Global)];
    (da, command()).prop_map(|(da, cmd)| Request::new(da, cmd))
}

fn slave_reply() -> impl Strategy<Value = SlaveReply> {
    prop_oneof![
        Just(SlaveReply::Run),
        Just(SlaveReply::Stop),
        any::<u16>().prop_map(|w| SlaveReply::MotorCurrent(Current::from_raw(w))),
        any::<u16>().prop_map(|w| SlaveReply::SpeedHz(Speed::from_raw(w))),
        any::<u16>().prop_map(|w| SlaveReply::SpeedRpm(Rpm::from_raw(w))),
        any::<u16>().prop_map(|w| SlaveReply::Status(DriveStatus::from_raw(w))),
        any::<u16>().prop_map(|w| SlaveReply::Version(Version::from_raw(w))),
        Just(SlaveReply::SetSpeed),
        Just(SlaveReply::Increase),
        Just(SlaveReply::Reduce),
        (any::<u8>(), any::<bool>()).prop_map(|(c, word)| SlaveReply::Error { code: ErrorCode(c), word }),
    ]
}

fn reply() -> impl Strategy<Value = Reply> {
    (address(), slave_reply()).prop_map(|(da, r)| Reply::new(da, r))
}

fn packet() -> impl Strategy<Value = Packet> {
    prop_oneof![request().prop_map(Packet::Request), reply().prop_map(Packet::Reply)]
}

fn wire(p: &Packet) -> Vec<u8> {
    let mut buf = [0u8; MAX_FRAME];
    let n = p.emit(&mut buf).unwrap();
    buf[..n].to_vec()
}

/// The frame `w` of packet `p`, sent by `from`: `len` bytes, read back as `p`, taken by the
/// codec as `from`'s, and found whole (nothing rejected) by the deframer for `from`'s frames.
fn read_back(w: &[u8], p: Packet, len: usize, from: Direction) -> Result<b800::Frame<'_>, TestCaseError> {
    prop_assert_eq!(w.len(), len);
    prop_assert_eq!(Packet::parse(w), Ok(p));
    let f = <B800 as Codec>::parse(w, None).unwrap();
    prop_assert_eq!(f.direction(), from);
    let (good, bad, _) = deframe_chunks(Some(from), &[w]);
    prop_assert_eq!(good, vec![w.to_vec()]);
    prop_assert!(bad.is_empty());
    Ok(f)
}

/// Good frames, rejected candidates, counts.
type Deframed = (Vec<Vec<u8>>, Vec<(Vec<u8>, FrameError)>, Stats);

fn deframe_chunks(from: Option<Direction>, chunks: &[&[u8]]) -> Deframed {
    let mut d = Deframer::new(FrameScanner::new(from));
    let mut good = Vec::new();
    let mut bad = Vec::new();
    for c in chunks {
        d.push(c, &mut |e| match e {
            Event::Frame { bytes, .. } => good.push(bytes.to_vec()),
            Event::Rejected { bytes, error, .. } => bad.push((bytes.to_vec(), error)),
        });
    }
    (good, bad, d.stats())
}

/// Bytes that look like B800 traffic: hex digits, flags and a few others.
fn b800ish() -> impl Strategy<Value = Vec<u8>> {
    proptest::collection::vec(
        prop_oneof![
            6 => prop::sample::select(b"0123456789ABCDEFabcdef".to_vec()),
            1 => Just(FG1),
            1 => Just(FG2),
            1 => any::<u8>(),
        ],
        0..200,
    )
}

proptest! {
    #[test]
    fn request_round_trip(r in request()) {
        let w = wire(&Packet::Request(r));
        prop_assert_eq!(Request::parse(&w), Ok(r));
        let f = read_back(&w, Packet::Request(r), r.wire_len(), Direction::Master)?;
        prop_assert_eq!(f.command().code, r.cmd.letter());
    }

    #[test]
    fn reply_round_trip(r in reply()) {
        let w = wire(&Packet::Reply(r));
        prop_assert_eq!(Reply::parse(&w), Ok(r));
        let f = read_back(&w, Packet::Reply(r), r.wire_len(), Direction::Drive)?;
        prop_assert_eq!(f.is_refusal(), r.reply.is_error());
        prop_assert!(field_count(&f) >= 2);
    }

    /// Lower-case digits (with the CS over the lower-case characters) read the same.
    #[test]
    fn lower_case_reads_the_same(p in packet()) {
        let w = wire(&p);
        let body: Vec<u8> = w[1..w.len() - 3].iter().map(|c| c.to_ascii_lowercase()).collect();
        let mut lower = vec![FG1];
        lower.extend_from_slice(&body);
        lower.extend(byte_digits(not_sum8(&body)).map(|c| c.to_ascii_lowercase()));
        lower.push(FG2);
        prop_assert_eq!(Packet::parse(&lower), Ok(p));
        let (good, _, _) = deframe_chunks(None, &[&lower]);
        prop_assert_eq!(good, vec![lower.clone()]);
    }

    /// Any single changed digit is caught (by the CS, or as a non-hex byte).
    #[test]
    fn a_changed_digit_is_caught(p in packet(), at in any::<prop::sample::Index>(), to in any::<u8>()) {
        let mut w = wire(&p);
        let i = 1 + at.index(w.len() - 2);
        // A change of case only keeps a CS digit's value.
        prop_assume!(!w[i].eq_ignore_ascii_case(&to));
        w[i] = to;
        prop_assert!(Packet::parse(&w).is_err());
    }

    #[test]
    fn speed_hz_round_trip(raw in any::<u16>()) {
        let s = Speed::from_raw(raw);
        prop_assert_eq!(Speed::from_hz(s.hz()), Ok(s));
    }

    #[test]
    fn parse_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..40)) {
        let _ = Packet::parse(&bytes);
        let _ = Request::parse(&bytes);
        let _ = Reply::parse(&bytes);
        let _ = <B800 as Codec>::parse(&bytes, None);
    }

    #[test]
    fn parse_never_panics_on_framed_digits(body in b800ish()) {
        let mut w = vec![FG1];
        w.extend_from_slice(&body);
        w.push(FG2);
        if let Ok(f) = <B800 as Codec>::parse(&w, None) {
            f.fields(&mut |_| {});
            let _ = f.command();
        }
    }

    /// Arbitrary bytes in arbitrary chunks: no panic, every frame delivered parses or fails
    /// cleanly, and the scanner keeps its contract.
    #[test]
    fn deframers_never_panic(
        stream in prop_oneof![proptest::collection::vec(any::<u8>(), 0..300), b800ish()],
        cuts in proptest::collection::vec(any::<prop::sample::Index>(), 0..6),
    ) {
        let cuts: Vec<usize> = cuts.iter().map(|c| c.index(stream.len() + 1)).collect();
        for from in [None, Some(Direction::Master), Some(Direction::Drive)] {
            let mut d = Deframer::new(<B800 as Codec>::scanner(from));
            for piece in pieces(&stream, &cuts) {
                d.push(piece, &mut |e| {
                    if let Event::Frame { bytes, .. } = e {
                        let _ = <B800 as Codec>::parse(bytes, from);
                    }
                });
            }
            d.finish(&mut |_| {});
            prop_assert_eq!(d.buffered(), 0);
        }
        let s = FrameScanner::new(None);
        for start in 0..stream.len() {
            let end = (start + SCAN_LIMIT + 4).min(stream.len());
            let buf = &stream[start..end];
            match s.scan(buf, 0) {
                Scan::Frame { len } => prop_assert!((1..=buf.len()).contains(&len)),
                Scan::Invalid { len, skip, .. } => {
                    prop_assert!((1..=buf.len()).contains(&len));
                    prop_assert!((1..=len).contains(&skip));
                }
                Scan::Noise { len } => prop_assert!((1..=buf.len()).contains(&len)),
                Scan::Incomplete { checked } => {
                    prop_assert!(buf.len() < SCAN_LIMIT);
                    prop_assert!(checked <= buf.len());
                }
            }
        }
    }

    /// Garbage without a start flag cannot hold a frame: exactly the frame is found.
    #[test]
    fn frame_inside_clean_garbage(
        p in packet(),
        before in proptest::collection::vec(any::<u8>().prop_filter("no 7E", |b| *b != FG1), 0..60),
        after in proptest::collection::vec(any::<u8>().prop_filter("no 7E", |b| *b != FG1), 0..60),
    ) {
        let w = wire(&p);
        let mut stream = before.clone();
        stream.extend_from_slice(&w);
        stream.extend_from_slice(&after);
        let (good, bad, stats) = deframe_chunks(None, &[&stream]);
        prop_assert_eq!(good, vec![w.clone()]);
        prop_assert!(bad.is_empty());
        prop_assert_eq!(stats.dropped_bytes, (before.len() + after.len()) as u64);
    }

    /// Garbage of any kind (a start flag included) before a frame never hides it.
    #[test]
    fn frame_after_any_garbage(p in packet(), before in b800ish(), after in b800ish()) {
        let w = wire(&p);
        let mut stream = before;
        stream.extend_from_slice(&w);
        stream.extend_from_slice(&after);
        let (good, _, _) = deframe_chunks(None, &[&stream]);
        prop_assert!(good.contains(&w));
    }

    /// Several frames with junk between them, split anywhere, give what the whole gives.
    #[test]
    fn any_split_gives_the_same_frames(
        parts in proptest::collection::vec((packet(), b800ish()), 1..6),
        cuts in proptest::collection::vec(any::<prop::sample::Index>(), 1..8),
    ) {
        let mut stream = Vec::new();
        for (p, junk) in &parts {
            stream.extend_from_slice(&wire(p));
            stream.extend_from_slice(junk);
        }
        let whole = deframe_chunks(None, &[&stream]);
        let cuts: Vec<usize> = cuts.iter().map(|c| c.index(stream.len() + 1)).collect();
        let split = deframe_chunks(None, &pieces(&stream, &cuts));
        prop_assert_eq!(&split, &whole);
        // Byte at a time too.
        let bytes: Vec<&[u8]> = stream.chunks(1).collect();
        prop_assert_eq!(&deframe_chunks(None, &bytes), &whole);
    }

    /// Clean traffic (frames back to back) comes out frame for frame, in order.
    #[test]
    fn back_to_back_frames(ps in proptest::collection::vec(packet(), 1..10)) {
        let frames: Vec<Vec<u8>> = ps.iter().map(wire).collect();
        let stream: Vec<u8> = frames.concat();
        let (good, bad, _) = deframe_chunks(None, &[&stream]);
        prop_assert_eq!(&good, &frames);
        prop_assert!(bad.is_empty());
        let parsed: Vec<Packet> = good.iter().map(|f| Packet::parse(f).unwrap()).collect();
        prop_assert_eq!(parsed, ps);
    }
}

/// `frame` with its CS digits made right again (and its flags left as they are).
fn recs(mut frame: Vec<u8>) -> Vec<u8> {
    let n = frame.len();
    if n >= 4 {
        let cs = byte_digits(not_sum8(&frame[1..n - 3]));
        frame[n - 3..n - 1].copy_from_slice(&cs);
    }
    frame
}

proptest! {
    /// The header look at a reply (DA and REPLY digits) agrees with the whole parse: any
    /// reply from the drive asked or another, an error reply, a changed digit with its CS made
    /// right, and junk.
    #[test]
    fn header_look_agrees_with_the_parse(
        (drive, cmd) in (address(), command()),
        (other, from_drive) in (slave_reply(), any::<bool>()),
        other_drive in address(),
        code in any::<u8>(),
        (at, to, junk) in damage(),
        framed in b800ish(),
    ) {
        let req = Request::to_drive(drive, cmd);
        let pending = B800.pending(&req).expect("a drive answers");
        let refusal = wire(&Packet::Reply(Reply::new(drive, SlaveReply::error(ErrorCode(code)))));
        header_answers(&B800, &pending, &refusal)?;
        let from = if from_drive { drive } else { other_drive };
        let reply = wire(&Packet::Reply(Reply::new(from, other)));
        // The reply with the letter that answers, whatever DATA it carries.
        let mut lettered = wire(&Packet::Reply(Reply::new(drive, other)));
        lettered[3..5].copy_from_slice(&byte_digits(cmd.reply_letter()));
        let lettered = recs(lettered);
        for bytes in [reply.clone(), lettered, recs(changed(&reply, at, to)), junk, framed] {
            header_agrees(&B800, &pending, &bytes)?;
        }
        echo_refused(&B800, &pending, &wire(&Packet::Request(req)))?;
    }
}
