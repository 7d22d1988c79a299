//! What the property tests share: cutting a stream into pieces, counting a frame's fields, and
//! the checks that a protocol's header look agrees with its parse.
#![allow(dead_code)] // each test file uses what it needs

use drivebus_proto::describe::Describe;
use drivebus_proto::session::Protocol;
use proptest::prelude::*;

/// `stream` cut at `cuts` (each at most `stream.len()`, in any order): the pieces, in order.
pub fn pieces<'a>(stream: &'a [u8], cuts: &[usize]) -> Vec<&'a [u8]> {
    let mut cuts = cuts.to_vec();
    cuts.sort_unstable();
    let mut out = Vec::with_capacity(cuts.len() + 1);
    let mut from = 0;
    for c in cuts {
        out.push(&stream[from..c]);
        from = c;
    }
    out.push(&stream[from..]);
    out
}

/// How many fields `frame` describes.
pub fn field_count<D: Describe>(frame: &D) -> usize {
    let mut n = 0;
    frame.fields(&mut |_| n += 1);
    n
}

/// Wherever `bytes` parses as a reply, the header look ([`Protocol::reply_matches`]) gives what
/// the parsed reply gives ([`Protocol::matches`]); whatever `bytes` is, it does not panic.
pub fn header_agrees<P: Protocol>(
    proto: &P,
    pending: &P::Pending,
    bytes: &[u8],
) -> Result<(), TestCaseError> {
    let header = proto.reply_matches(pending, bytes);
    if let Ok(rep) = proto.parse_reply(bytes) {
        prop_assert_eq!(header, Ok(proto.matches(pending, &rep)), "{:02X?}", bytes);
    }
    Ok(())
}

/// [`header_agrees`], and `bytes` answers `pending`.
pub fn header_answers<P: Protocol>(
    proto: &P,
    pending: &P::Pending,
    bytes: &[u8],
) -> Result<(), TestCaseError> {
    header_agrees(proto, pending, bytes)?;
    prop_assert_eq!(proto.reply_matches(pending, bytes), Ok(true), "{:02X?}", bytes);
    Ok(())
}

/// [`header_agrees`], and where the parse refuses `bytes` as a reply, the header look refuses
/// it too: for the request itself heard as an echo, whose header is all there is to tell it
/// from the reply.
pub fn echo_refused<P: Protocol>(proto: &P, pending: &P::Pending, bytes: &[u8]) -> Result<(), TestCaseError> {
    header_agrees(proto, pending, bytes)?;
    if proto.parse_reply(bytes).is_err() {
        prop_assert!(proto.reply_matches(pending, bytes).is_err(), "{:02X?}", bytes);
    }
    Ok(())
}

/// Where to change a frame and to what (see [`changed`]), and some junk bytes.
pub fn damage() -> impl Strategy<Value = (prop::sample::Index, u8, Vec<u8>)> {
    (any::<prop::sample::Index>(), any::<u8>(), proptest::collection::vec(any::<u8>(), 0..40))
}

/// `frame` with the byte at `at` (modulo its length) replaced by `to`.
pub fn changed(frame: &[u8], at: prop::sample::Index, to: u8) -> Vec<u8> {
    let mut f = frame.to_vec();
    if !f.is_empty() {
        f[at.index(frame.len())] = to;
    }
    f
}
