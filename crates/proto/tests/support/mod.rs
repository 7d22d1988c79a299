//! What the property tests share: cutting a stream into pieces, counting a frame's fields.
#![allow(dead_code)] // each test file uses what it needs

use drivebus_proto::describe::Describe;

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
