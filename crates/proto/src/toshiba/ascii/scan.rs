//! The deframer's scanner for ASCII mode: `(` to CR, SUM checked when present.

use crate::checksum::sum8;
use crate::deframe::{Scan, Scanner};
use crate::error::{ChecksumKind, FrameError};

use super::parse::HEX;
use super::{CR, MAX_FRAME, START, SUM_MARK};
use crate::toshiba::{prefix_hint, BINARY_START};

/// The deframer's scanner for ASCII mode: `(` to CR, at most 17 bytes, SUM checked when present.
#[derive(Clone, Copy, Debug, Default)]
pub struct AsciiScanner;

impl Scanner for AsciiScanner {
    type Buffer = [u8; MAX_FRAME];

    #[inline]
    fn scan(&self, buf: &[u8], checked: usize) -> Scan {
        scan_ascii(buf, checked, false)
    }

    fn truncated(&self, buf: &[u8]) -> FrameError {
        FrameError::Truncated {
            what: "an ASCII-mode frame (no CR yet)",
            expected: buf.len() + 1,
            got: buf.len(),
        }
    }
}

/// Byte classes for the scanner: what a byte does inside an ASCII-mode frame.
const ORDINARY: u8 = 0;
const END: u8 = 1;
const RESTART: u8 = 2;
const SLASH: u8 = 3;
const BAD: u8 = 4;

const fn classes(tip: bool) -> [u8; 256] {
    let mut t = [BAD; 256];
    let mut c = 0x20;
    while c < 0x7F {
        t[c] = ORDINARY;
        c += 1;
    }
    t[CR as usize] = END;
    t[START as usize] = RESTART;
    if tip {
        t[BINARY_START as usize] = SLASH;
    }
    t
}

/// Classes on an ASCII-only line.
static CLASS: [u8; 256] = classes(false);
/// Classes on a line that carries both modes (2F starts a binary frame).
static CLASS_TIP: [u8; 256] = classes(true);

/// Scans for an ASCII-mode frame; `tip`: the line also carries binary mode, so 2F is a start code.
#[inline]
pub(crate) fn scan_ascii(buf: &[u8], checked: usize, tip: bool) -> Scan {
    if buf.first() != Some(&START) {
        return Scan::Noise { len: next_start(buf, tip) };
    }
    let table = if tip { &CLASS_TIP } else { &CLASS };
    let limit = buf.len().min(MAX_FRAME);
    let from = checked.clamp(1, limit);
    // The sum of the bytes before the one looked at, for SUM.
    let mut sum = sum8(&buf[..from]);
    for (i, &b) in buf[from..limit].iter().enumerate() {
        let class = table[b as usize];
        if class != ORDINARY {
            return special(buf, from + i, class, sum);
        }
        sum = sum.wrapping_add(b);
    }
    if limit == MAX_FRAME {
        return Scan::Invalid {
            len: MAX_FRAME,
            skip: MAX_FRAME,
            error: FrameError::Malformed("no CR within 17 bytes: an ASCII-mode frame is at most 17 bytes"),
        };
    }
    Scan::Incomplete { checked: limit }
}

/// The byte at `i` is not an ordinary frame byte: CR ends the frame, a start code cuts it short,
/// anything else is not allowed in one.
#[inline]
fn special(buf: &[u8], i: usize, class: u8, sum: u8) -> Scan {
    match class {
        END => finish_ascii(&buf[..=i], sum),
        RESTART => Scan::Invalid {
            len: i,
            skip: i,
            error: FrameError::Malformed(
                "a new start code '(' came before CR: the frame before it was cut short",
            ),
        },
        SLASH => Scan::Invalid {
            len: i,
            skip: i,
            error: FrameError::Malformed(
                "a binary-mode start code 2F came before CR: the ASCII-mode frame before it was cut short",
            ),
        },
        _ => Scan::Invalid {
            len: i + 1,
            skip: i + 1,
            error: FrameError::NonHex { byte: buf.get(i).copied().unwrap_or(0), offset: i },
        },
    }
}

/// Bytes before the next start code (`(`, and 2F on a line that carries both modes).
pub(crate) fn next_start(buf: &[u8], tip: bool) -> usize {
    buf.iter().skip(1).position(|&b| b == START || (tip && b == BINARY_START)).map_or(buf.len(), |p| p + 1)
}

/// A candidate from `(` to CR, whose bytes before CR add up to `sum`: checks SUM when `&`
/// is where it belongs.
#[inline]
fn finish_ascii(frame: &[u8], sum: u8) -> Scan {
    let len = frame.len();
    if len >= 6 && frame[len - 5] == SUM_MARK {
        let (hi, lo, stop) = (frame[len - 4], frame[len - 3], frame[len - 2]);
        let (h, l) = (HEX[hi as usize], HEX[lo as usize]);
        if (h | l) & 0x10 == 0 {
            let carried = h << 4 | l;
            // The covered bytes end with '&': the sum of all before CR less SUM and ')'.
            let computed = sum.wrapping_sub(hi).wrapping_sub(lo).wrapping_sub(stop);
            if carried != computed {
                let covered = &frame[..len - 4];
                return Scan::Invalid {
                    len,
                    skip: len,
                    error: FrameError::ChecksumMismatch {
                        kind: ChecksumKind::Sum,
                        carried: carried as u16,
                        computed: computed as u16,
                        hint: prefix_hint(covered, carried),
                    },
                };
            }
        }
    }
    Scan::Frame { len }
}
