//! Streaming deframing: bytes in any split, whole frames out in order.
//!
//! Each protocol supplies a [`Scanner`], a pure function that looks at the bytes after the
//! last frame and says what they are: a whole frame, a frame that cannot be valid, bytes to
//! skip, or "need more". [`Deframer`] drives it over a stream: it keeps a fixed buffer for a
//! frame split across reads (no allocator, bounded memory), scans the caller's bytes in place
//! when nothing is buffered (no copy on the fast path), resynchronises after garbage or a bad
//! checksum without losing the next good frame, and counts what it dropped.
//!
//! Resynchronisation: when a candidate frame fails (bad checksum, impossible length), the
//! scanner says how many bytes to skip. For protocols without an end flag (Modbus RTU, FC,
//! Toshiba binary) that is one byte, so a good frame that starts inside the bad one is still
//! found; while the deframer searches inside the failed candidate it reports nothing more
//! about it (one bad frame is one checksum failure, not one per byte).

use crate::error::FrameError;

/// A fixed-size buffer for one frame, `[u8; N]` for any `N`.
pub trait FrameBuffer: AsRef<[u8]> + AsMut<[u8]> + Send + Sync {
    /// A zeroed buffer.
    fn zeroed() -> Self;
}

impl<const N: usize> FrameBuffer for [u8; N] {
    #[inline]
    fn zeroed() -> Self {
        [0; N]
    }
}

/// What a [`Scanner`] found at the start of a buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scan {
    /// The first `len` bytes are a whole frame with a good checksum.
    Frame {
        /// Bytes in the frame, start and end flags included.
        len: usize,
    },
    /// The first `len` bytes were a frame candidate and cannot be a valid frame.
    Invalid {
        /// Bytes of the failed candidate (reported with the error).
        len: usize,
        /// Bytes to drop before scanning again, `1..=len`.
        skip: usize,
        /// Why.
        error: FrameError,
    },
    /// The first `len` bytes cannot start a frame (line noise, bytes before a start code).
    Noise {
        /// Bytes to drop, at least 1.
        len: usize,
    },
    /// A frame may be in progress; more bytes are needed.
    Incomplete {
        /// Bytes already checked (a hint for the next call on the same bytes, so that
        /// delimited protocols do not scan a long frame again from its start).
        checked: usize,
    },
}

/// A protocol's framing rules, as a pure function of the buffered bytes.
pub trait Scanner {
    /// A buffer that holds the longest frame of the protocol.
    type Buffer: FrameBuffer;

    /// Looks at `buf` (never empty). `checked` is the `checked` of the previous
    /// [`Scan::Incomplete`] for the same start of buffer, 0 otherwise.
    ///
    /// Must never return `Incomplete` for more bytes than `Buffer` holds, and must make
    /// progress: `Frame.len`, `Invalid.skip` and `Noise.len` are at least 1 and at most `buf.len()`.
    fn scan(&self, buf: &[u8], checked: usize) -> Scan;

    /// The line went silent after `buf` (a frame in progress, never empty): what is it?
    ///
    /// Only Modbus RTU delimits frames by silence; the default keeps waiting.
    fn silence(&self, buf: &[u8]) -> Scan {
        let _ = buf;
        Scan::Incomplete { checked: 0 }
    }

    /// The stream ended with `buf` (never empty) unfinished.
    fn truncated(&self, buf: &[u8]) -> FrameError {
        FrameError::Truncated { what: "the frame in progress", expected: buf.len() + 1, got: buf.len() }
    }
}

/// One result of deframing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Event<'a> {
    /// A whole frame with a good checksum. Its fields are not checked yet: parse it.
    Frame {
        /// The frame's bytes, flags included.
        bytes: &'a [u8],
        /// Offset of its first byte in the stream since the deframer was made.
        position: u64,
    },
    /// A frame candidate that is not a valid frame.
    Rejected {
        /// The candidate's bytes.
        bytes: &'a [u8],
        /// Offset of its first byte in the stream.
        position: u64,
        /// Why it was rejected.
        error: FrameError,
    },
}

/// What a deframer has seen since it was made.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Stats {
    /// Good frames delivered.
    pub frames: u64,
    /// Bytes that were not part of a good frame.
    pub dropped_bytes: u64,
    /// Candidates rejected for a bad checksum.
    pub checksum_failures: u64,
    /// Candidates rejected for any other reason.
    pub malformed: u64,
}

/// A streaming deframer over a protocol's [`Scanner`]. Memory: one `S::Buffer`.
pub struct Deframer<S: Scanner> {
    scanner: S,
    buf: S::Buffer,
    /// Bytes held in `buf`.
    len: usize,
    /// The `checked` hint for `buf`.
    checked: usize,
    /// Bytes still to pass of a failed candidate, searched silently for a frame inside it.
    resync: usize,
    /// Stream offset of `buf[0]` (or of the next input byte when `buf` is empty).
    position: u64,
    stats: Stats,
}

impl<S: Scanner + Default> Default for Deframer<S> {
    fn default() -> Self {
        Self::new(S::default())
    }
}

impl<S: Scanner> Deframer<S> {
    /// A deframer with an empty buffer.
    pub fn new(scanner: S) -> Self {
        Deframer {
            scanner,
            buf: S::Buffer::zeroed(),
            len: 0,
            checked: 0,
            resync: 0,
            position: 0,
            stats: Stats::default(),
        }
    }

    /// The scanner (its settings).
    pub fn scanner(&self) -> &S {
        &self.scanner
    }

    /// What the deframer has seen so far.
    pub fn stats(&self) -> Stats {
        self.stats
    }

    /// Bytes held for a frame in progress.
    pub fn buffered(&self) -> usize {
        self.len
    }

    /// Forgets any frame in progress (the bytes count as dropped).
    pub fn clear(&mut self) {
        self.stats.dropped_bytes += self.len as u64;
        self.position += self.len as u64;
        self.len = 0;
        self.checked = 0;
        self.resync = 0;
    }

    /// Feeds `input`, calling `on_event` for every frame completed, in order.
    pub fn push(&mut self, mut input: &[u8], on_event: &mut impl FnMut(Event<'_>)) {
        loop {
            if self.len == 0 {
                // Fast path: scan the caller's bytes in place.
                let used = self.scan_slice_in_place(input, on_event);
                let rest = &input[used..];
                if !rest.is_empty() {
                    let cap = self.buf.as_ref().len();
                    debug_assert!(rest.len() <= cap, "scanner asked to buffer more than its buffer holds");
                    let n = rest.len().min(cap);
                    self.buf.as_mut()[..n].copy_from_slice(&rest[..n]);
                    self.len = n;
                }
                return;
            }
            // A frame is in progress: append what fits and scan the buffer.
            let old = self.len;
            let cap = self.buf.as_ref().len();
            let n = input.len().min(cap - old);
            self.buf.as_mut()[old..old + n].copy_from_slice(&input[..n]);
            self.len += n;
            let appended = input;
            input = &input[n..];
            let used = self.scan_buffer(on_event);
            if used >= old {
                // Everything before the appended bytes is done: the rest of them is still
                // in the caller's slice, so continue there without copying.
                let from = used - old;
                self.len = 0;
                self.checked = 0;
                input = &appended[from..];
                continue;
            }
            // Keep the unfinished frame at the front of the buffer.
            self.buf.as_mut().copy_within(used..self.len, 0);
            self.len -= used;
            if input.is_empty() {
                return;
            }
            if self.len == cap {
                // Cannot happen with a correct scanner; recover rather than stall.
                self.drop_buffer_front(1);
            }
        }
    }

    /// Tells the deframer that the line went silent (Modbus RTU t3.5): the buffered bytes are
    /// a whole frame or nothing.
    pub fn silence(&mut self, on_event: &mut impl FnMut(Event<'_>)) {
        if self.len == 0 {
            return;
        }
        let scan = self.scanner.silence(&self.buf.as_ref()[..self.len]);
        if let Scan::Incomplete { .. } = scan {
            return;
        }
        // Applied with any resynchronisation still in force: the tail of a candidate that
        // already failed is not reported a second time.
        let used = self.apply(scan, on_event);
        self.buf.as_mut().copy_within(used..self.len, 0);
        self.len -= used;
        self.checked = 0;
        if self.len > 0 {
            // The scanner kept bytes after a skip: scan them as usual.
            let mut tmp = S::Buffer::zeroed();
            let n = self.len;
            tmp.as_mut()[..n].copy_from_slice(&self.buf.as_ref()[..n]);
            self.len = 0;
            self.push(&tmp.as_ref()[..n], on_event);
        }
        if self.len == 0 {
            // Silence is a frame boundary: whatever comes next is a new candidate.
            self.resync = 0;
        }
    }

    /// Ends the stream: an unfinished frame is reported as [`Event::Rejected`].
    pub fn finish(&mut self, on_event: &mut impl FnMut(Event<'_>)) {
        self.silence(on_event);
        if self.len > 0 {
            let bytes = &self.buf.as_ref()[..self.len];
            let error = self.scanner.truncated(bytes);
            if self.resync == 0 {
                self.stats.malformed += 1;
                on_event(Event::Rejected { bytes, position: self.position, error });
            }
            self.stats.dropped_bytes += self.len as u64;
            self.position += self.len as u64;
            self.len = 0;
            self.checked = 0;
            self.resync = 0;
        }
    }

    fn drop_buffer_front(&mut self, n: usize) {
        self.buf.as_mut().copy_within(n..self.len, 0);
        self.len -= n;
        self.position += n as u64;
        self.stats.dropped_bytes += n as u64;
        self.checked = 0;
    }

    /// Scans `input` from its start; returns the bytes used. Stops at `Incomplete`.
    fn scan_slice_in_place(&mut self, input: &[u8], on_event: &mut impl FnMut(Event<'_>)) -> usize {
        let mut at = 0;
        while at < input.len() {
            let rest = &input[at..];
            let scan = self.scanner.scan(rest, 0);
            match scan {
                Scan::Incomplete { checked } => {
                    self.checked = checked;
                    break;
                }
                _ => at += self.emit(scan, rest, on_event),
            }
        }
        at
    }

    /// Scans the buffer from its start; returns the bytes used. Stops at `Incomplete`.
    fn scan_buffer(&mut self, on_event: &mut impl FnMut(Event<'_>)) -> usize {
        let mut at = 0;
        let mut checked = self.checked;
        while at < self.len {
            let scan = self.scanner.scan(&self.buf.as_ref()[at..self.len], checked);
            checked = 0;
            match scan {
                Scan::Incomplete { checked } => {
                    self.checked = checked;
                    break;
                }
                _ => {
                    let len = self.len;
                    // Split borrows: the event borrows the buffer while stats change.
                    let Deframer { buf, stats, resync, position, .. } = self;
                    at += emit_one(scan, &buf.as_ref()[at..len], stats, resync, position, on_event);
                }
            }
        }
        at
    }

    fn apply(&mut self, scan: Scan, on_event: &mut impl FnMut(Event<'_>)) -> usize {
        let len = self.len;
        let Deframer { buf, stats, resync, position, .. } = self;
        emit_one(scan, &buf.as_ref()[..len], stats, resync, position, on_event)
    }

    fn emit(&mut self, scan: Scan, bytes: &[u8], on_event: &mut impl FnMut(Event<'_>)) -> usize {
        emit_one(scan, bytes, &mut self.stats, &mut self.resync, &mut self.position, on_event)
    }
}

/// Applies one non-`Incomplete` scan result to the bytes it was made on; returns bytes used.
#[inline]
fn emit_one(
    scan: Scan,
    bytes: &[u8],
    stats: &mut Stats,
    resync: &mut usize,
    position: &mut u64,
    on_event: &mut impl FnMut(Event<'_>),
) -> usize {
    let used = match scan {
        Scan::Frame { len } => {
            let len = len.clamp(1, bytes.len());
            stats.frames += 1;
            *resync = 0;
            on_event(Event::Frame { bytes: &bytes[..len], position: *position });
            len
        }
        Scan::Invalid { len, skip, error } => {
            let len = len.clamp(1, bytes.len());
            let skip = skip.clamp(1, len);
            if *resync == 0 {
                if matches!(error, FrameError::ChecksumMismatch { .. }) {
                    stats.checksum_failures += 1;
                } else {
                    stats.malformed += 1;
                }
                on_event(Event::Rejected { bytes: &bytes[..len], position: *position, error });
                *resync = len - skip;
            } else {
                *resync = resync.saturating_sub(skip);
            }
            stats.dropped_bytes += skip as u64;
            skip
        }
        Scan::Noise { len } => {
            let len = len.clamp(1, bytes.len());
            *resync = resync.saturating_sub(len);
            stats.dropped_bytes += len as u64;
            len
        }
        Scan::Incomplete { .. } => 0,
    };
    *position += used as u64;
    used
}

#[cfg(test)]
mod tests {
    //! The driver tested with a toy protocol: `<` payload `>` where the payload is one
    //! digit giving the count of bytes that follow it, and a bad frame is one whose count
    //! does not match.
    use super::*;

    #[derive(Default)]
    struct Toy;

    impl Scanner for Toy {
        type Buffer = [u8; 16];
        fn scan(&self, buf: &[u8], _checked: usize) -> Scan {
            if buf[0] != b'<' {
                let n = buf.iter().position(|&b| b == b'<').unwrap_or(buf.len());
                return Scan::Noise { len: n };
            }
            match buf.iter().position(|&b| b == b'>') {
                Some(end) => {
                    let body = &buf[1..end];
                    if !body.is_empty() && (body[0].wrapping_sub(b'0')) as usize == body.len() - 1 {
                        Scan::Frame { len: end + 1 }
                    } else {
                        Scan::Invalid { len: end + 1, skip: 1, error: FrameError::Malformed("bad toy") }
                    }
                }
                None if buf.len() >= 16 => Scan::Invalid {
                    len: buf.len(),
                    skip: 1,
                    error: FrameError::TooLong { what: "toy", max: 16, got: buf.len() },
                },
                None => Scan::Incomplete { checked: buf.len() },
            }
        }
    }

    extern crate std;
    use std::vec::Vec;

    fn run(chunks: &[&[u8]]) -> (Vec<Vec<u8>>, Vec<Vec<u8>>, Stats) {
        let mut d = Deframer::new(Toy);
        let mut good = Vec::new();
        let mut bad = Vec::new();
        for c in chunks {
            d.push(c, &mut |e| match e {
                Event::Frame { bytes, .. } => good.push(bytes.to_vec()),
                Event::Rejected { bytes, .. } => bad.push(bytes.to_vec()),
            });
        }
        (good, bad, d.stats())
    }

    #[test]
    fn every_split_gives_the_same_frames() {
        let stream: &[u8] = b"xx<2ab><0>junk<1z><3abc>";
        let (whole, _, s) = run(&[stream]);
        assert_eq!(whole.len(), 4);
        assert_eq!(s.dropped_bytes, 6);
        for i in 0..stream.len() {
            for j in i..stream.len() {
                let (g, _, st) = run(&[&stream[..i], &stream[i..j], &stream[j..]]);
                assert_eq!(g, whole, "split at {i},{j}");
                assert_eq!(st, s);
            }
        }
    }

    #[test]
    fn byte_at_a_time() {
        let stream: &[u8] = b"<1a><2bc>";
        let chunks: Vec<&[u8]> = stream.chunks(1).collect();
        let (g, _, _) = run(&chunks);
        assert_eq!(g, [b"<1a>".to_vec(), b"<2bc>".to_vec()]);
    }

    #[test]
    fn bad_frame_is_reported_once_and_next_frame_survives() {
        let (g, b, s) = run(&[b"<5ab><1z>"]);
        assert_eq!(b, [b"<5ab>".to_vec()]);
        assert_eq!(g, [b"<1z>".to_vec()]);
        assert_eq!(s.malformed, 1);
        assert_eq!(s.dropped_bytes, 5);
    }

    #[test]
    fn positions_are_stream_offsets() {
        let mut d = Deframer::new(Toy);
        let mut pos = Vec::new();
        for c in [&b"ab<1"[..], b"x>", b"<0>"] {
            d.push(c, &mut |e| {
                if let Event::Frame { position, .. } = e {
                    pos.push(position)
                }
            });
        }
        assert_eq!(pos, [2, 6]);
    }

    #[test]
    fn finish_reports_a_truncated_frame() {
        let mut d = Deframer::new(Toy);
        let mut n = 0;
        d.push(b"<3ab", &mut |_| n += 1);
        assert_eq!(n, 0);
        let mut rejected = None;
        d.finish(&mut |e| {
            if let Event::Rejected { error, .. } = e {
                rejected = Some(error)
            }
        });
        assert!(matches!(rejected, Some(FrameError::Truncated { .. })));
        assert_eq!(d.buffered(), 0);
    }

    /// Ends every candidate at silence: the whole buffer is one frame or one bad candidate.
    #[derive(Default)]
    struct Silent;

    impl Scanner for Silent {
        type Buffer = [u8; 16];
        fn scan(&self, buf: &[u8], _checked: usize) -> Scan {
            // A frame is "<" + 3 bytes; a bad one is reported and searched byte by byte.
            if buf[0] != b'<' {
                return Scan::Noise { len: 1 };
            }
            if buf.len() < 4 {
                return Scan::Incomplete { checked: 0 };
            }
            if buf[1..4].iter().all(|b| b.is_ascii_digit()) {
                Scan::Frame { len: 4 }
            } else {
                Scan::Invalid { len: 4, skip: 1, error: FrameError::Malformed("bad") }
            }
        }
        fn silence(&self, buf: &[u8]) -> Scan {
            Scan::Invalid { len: buf.len(), skip: buf.len(), error: FrameError::Malformed("cut short") }
        }
    }

    #[test]
    fn silence_does_not_report_the_tail_of_a_failed_candidate_again() {
        let mut d = Deframer::new(Silent);
        let mut rejected = Vec::new();
        // "<a<1" fails as a whole; its tail "<1" is searched silently; silence then ends it.
        d.push(b"<a<1", &mut |e| {
            if let Event::Rejected { bytes, .. } = e {
                rejected.push(bytes.to_vec())
            }
        });
        d.silence(&mut |e| {
            if let Event::Rejected { bytes, .. } = e {
                rejected.push(bytes.to_vec())
            }
        });
        assert_eq!(rejected, [b"<a<1".to_vec()]);
        // After the silence a new bad candidate is reported again.
        d.push(b"<b<2", &mut |e| {
            if let Event::Rejected { bytes, .. } = e {
                rejected.push(bytes.to_vec())
            }
        });
        assert_eq!(rejected.len(), 2);
        assert_eq!(d.stats().dropped_bytes, 4 + 2);
        assert_eq!(d.buffered(), 2);
    }

    #[test]
    fn overlong_garbage_is_bounded() {
        let mut d = Deframer::new(Toy);
        let mut good = 0;
        let junk = [b'<'; 100];
        d.push(&junk, &mut |e| {
            if let Event::Frame { .. } = e {
                good += 1
            }
        });
        d.push(b"<1a>", &mut |e| {
            if let Event::Frame { .. } = e {
                good += 1
            }
        });
        assert_eq!(good, 1);
        assert!(d.buffered() <= 16);
    }
}
