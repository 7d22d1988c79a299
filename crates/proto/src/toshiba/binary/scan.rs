//! The deframer's scanner for binary mode: the command's byte count, SUM checked, and the
//! manual's "last 2F counts" where a later 2F starts a whole frame.

use crate::checksum::sum8;
use crate::deframe::{Scan, Scanner};
use crate::describe::Direction;
use crate::error::{ChecksumKind, FrameError};

use super::{BLOCK, BROADCAST, MAX_FRAME, MAX_INV_NO, N_R, N_W, START};
use crate::toshiba::{prefix_hint, ASCII_START};

/// INV-NO (if any), CMD and the bytes through CMD.
pub(super) struct Head {
    pub(super) inv: Option<u8>,
    pub(super) cmd: u8,
    /// Bytes from 2F through CMD.
    pub(super) base: usize,
}

/// Reads INV-NO and CMD; `None` until they are in.
pub(super) fn head(buf: &[u8]) -> Option<Head> {
    let b1 = *buf.get(1)?;
    // INV-NO is 00-3F or FF; every command is 47H or more.
    let (inv, cmd_at) = if b1 <= MAX_INV_NO || b1 == BROADCAST { (Some(b1), 2) } else { (None, 1) };
    let cmd = *buf.get(cmd_at)?;
    Some(Head { inv, cmd, base: cmd_at + 1 })
}

/// How long a frame with this head is.
#[derive(Clone, Copy)]
pub(super) enum Shape {
    /// One length for either direction.
    Fixed(usize),
    /// `R`: the request has no DATA, the reply has.
    Read { request: usize, reply: usize },
}

/// The frame's shape; `Ok(None)` until the count byte of X/Y is in.
pub(super) fn shape(buf: &[u8], h: &Head) -> Result<Option<Shape>, FrameError> {
    let base = h.base;
    Ok(Some(match h.cmd {
        b'R' => Shape::Read { request: base + 3, reply: base + 5 },
        b'r' | b'W' | b'w' | b'P' | b'p' | b'G' | b'g' => Shape::Fixed(base + 5),
        b'N' | b'n' => Shape::Fixed(base + 3),
        BLOCK => {
            let Some(&n_w) = buf.get(base) else { return Ok(None) };
            // manual: nW out of range is a format error (no reply).
            N_W.frame(n_w)?;
            Shape::Fixed(base + 3 + 2 * n_w as usize)
        }
        b'Y' | b'y' => {
            let Some(&n_r) = buf.get(base) else { return Ok(None) };
            N_R.frame(n_r)?;
            Shape::Fixed(base + 2 + 2 * n_r as usize)
        }
        // manual: "Any other command is rejected" (binary mode: no reply).
        other => return Err(FrameError::Unknown { field: "binary-mode CMD", value: other as u32 }),
    }))
}

/// One candidate at the start of `buf`, without looking further.
enum Check {
    Frame(usize),
    NeedMore,
    Bad { len: usize, error: FrameError },
}

#[inline]
fn sum_ok(buf: &[u8], len: usize) -> bool {
    match (buf.get(..len - 1), buf.get(len - 1)) {
        (Some(covered), Some(&carried)) => sum8(covered) == carried,
        _ => false,
    }
}

fn mismatch(buf: &[u8], len: usize) -> Check {
    let covered = &buf[..len - 1];
    let carried = buf[len - 1];
    let computed = sum8(covered);
    Check::Bad {
        len,
        error: FrameError::ChecksumMismatch {
            kind: ChecksumKind::Sum,
            carried: carried as u16,
            computed: computed as u16,
            hint: prefix_hint(covered, carried),
        },
    }
}

#[inline]
fn check(buf: &[u8], from: Option<Direction>) -> Check {
    let Some(h) = head(buf) else { return Check::NeedMore };
    let shape = match shape(buf, &h) {
        Ok(Some(s)) => s,
        Ok(None) => return Check::NeedMore,
        Err(error) => {
            let len = if h.cmd == BLOCK || h.cmd | 0x20 == b'y' { h.base + 1 } else { h.base };
            return Check::Bad { len, error };
        }
    };
    let n = buf.len();
    match shape {
        Shape::Fixed(len) => {
            if n < len {
                Check::NeedMore
            } else if sum_ok(buf, len) {
                Check::Frame(len)
            } else {
                mismatch(buf, len)
            }
        }
        // R: 5 bytes from the master, 7 from a drive (plus INV-NO). A scanner for one
        // direction waits for that length and takes the other only if it checks out too.
        Shape::Read { request, reply } => match from {
            Some(Direction::Master) => {
                if n < request {
                    Check::NeedMore
                } else if sum_ok(buf, request) {
                    Check::Frame(request)
                } else if n >= reply && sum_ok(buf, reply) {
                    Check::Frame(reply)
                } else {
                    mismatch(buf, request)
                }
            }
            Some(Direction::Drive) => {
                if n < reply {
                    Check::NeedMore
                } else if sum_ok(buf, reply) {
                    Check::Frame(reply)
                } else if sum_ok(buf, request) {
                    Check::Frame(request)
                } else {
                    mismatch(buf, reply)
                }
            }
            None => {
                if n < request {
                    Check::NeedMore
                } else if sum_ok(buf, request) {
                    Check::Frame(request)
                } else if n < reply {
                    Check::NeedMore
                } else if sum_ok(buf, reply) {
                    Check::Frame(reply)
                } else {
                    mismatch(buf, request)
                }
            }
        },
    }
}

/// Whether a whole frame of the other mode starts its argument: on a line that carries both
/// modes, `(` also starts a frame ([`crate::toshiba::TipScanner`] says how to tell one).
pub(crate) type OtherMode = fn(&[u8]) -> bool;

/// The offset of a later start code, before `end`, that begins a whole frame with a good
/// checksum (manual VF-S11 p.7: "If 2F arrives more than once, the last 2F counts").
fn later_frame(buf: &[u8], end: usize, from: Option<Direction>, ascii: Option<OtherMode>) -> Option<usize> {
    let end = end.min(buf.len());
    (1..end).find(|&p| match buf[p] {
        START => matches!(check(&buf[p..], from), Check::Frame(_)),
        ASCII_START => ascii.is_some_and(|whole| whole(&buf[p..])),
        _ => false,
    })
}

/// Scans for a binary-mode frame; `ascii`: the line also carries ASCII mode, so `(` is a start
/// code, and this tells whether one begins a whole ASCII-mode frame.
#[inline]
pub(crate) fn scan_binary(buf: &[u8], from: Option<Direction>, ascii: Option<OtherMode>) -> Scan {
    if buf.first() != Some(&START) {
        // manual: everything before 2F is ignored.
        return Scan::Noise { len: next_start(buf, ascii.is_some()) };
    }
    match check(buf, from) {
        Check::Frame(len) => Scan::Frame { len },
        Check::NeedMore => match later_frame(buf, buf.len(), from, ascii) {
            Some(p) => Scan::Noise { len: p },
            None => Scan::Incomplete { checked: 0 },
        },
        Check::Bad { len, error } => match later_frame(buf, len, from, ascii) {
            Some(p) => Scan::Noise { len: p },
            None => Scan::Invalid { len: len.min(buf.len()).max(1), skip: 1, error },
        },
    }
}

/// Bytes before the next start code (2F, and `(` on a line that carries both modes).
fn next_start(buf: &[u8], tip: bool) -> usize {
    buf.iter().skip(1).position(|&b| b == START || (tip && b == ASCII_START)).map_or(buf.len(), |p| p + 1)
}

/// The expected length of the candidate at the start of `buf`, for messages.
fn expected_len(buf: &[u8], from: Option<Direction>) -> usize {
    let fallback = buf.len() + 1;
    let Some(h) = head(buf) else { return fallback };
    match shape(buf, &h) {
        Ok(Some(Shape::Fixed(len))) => len,
        Ok(Some(Shape::Read { request, reply })) => match from {
            Some(Direction::Drive) => reply,
            _ if buf.len() < request => request,
            _ => reply,
        },
        _ => fallback,
    }
}

/// The deframer's scanner for binary mode. `from` says whose frames it reads: the length of
/// `R` differs (5 bytes from the master, 7 from a drive, plus INV-NO); with `None` it takes
/// whichever checks out.
#[derive(Clone, Copy, Debug, Default)]
pub struct BinaryScanner {
    /// Whose frames: `Some(Master)` for a drive, `Some(Drive)` for a master, `None` for a monitor.
    pub from: Option<Direction>,
}

impl Scanner for BinaryScanner {
    type Buffer = [u8; MAX_FRAME];

    #[inline]
    fn scan(&self, buf: &[u8], _checked: usize) -> Scan {
        scan_binary(buf, self.from, None)
    }

    fn truncated(&self, buf: &[u8]) -> FrameError {
        truncated(buf, self.from)
    }
}

pub(crate) fn truncated(buf: &[u8], from: Option<Direction>) -> FrameError {
    FrameError::Truncated { what: "a binary-mode frame", expected: expected_len(buf, from), got: buf.len() }
}
