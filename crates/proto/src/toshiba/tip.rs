//! One line, both modes: a VF-AS1 picks ASCII or binary mode per frame by its start code
//! (protocols.md 1.3: `(` 28H ASCII with CR, 2F binary without).

use crate::deframe::{Scan, Scanner};
use crate::describe::{Command, Describe, Direction, Field, Target};
use crate::error::{EmitError, FrameError};
use crate::session::{frame_methods, Disposition, Protocol};

use super::ascii::{self, AsciiFrame, AsciiPending, AsciiReply, AsciiRequest, TipAscii};
use super::binary::{self, BinaryFrame, BinaryPending, BinaryReply, BinaryRequest, TipBinary};
use super::{Cmd, ErrorCode};

/// The deframer's scanner for a line that carries both modes: `(` starts an ASCII-mode frame,
/// 2F a binary-mode one; anything else before a start code is ignored.
#[derive(Clone, Copy, Debug, Default)]
pub struct TipScanner {
    /// Whose frames (decides the length of binary `R`): see [`binary::BinaryScanner`].
    pub from: Option<Direction>,
}

impl Scanner for TipScanner {
    type Buffer = [u8; ascii::MAX_FRAME];

    #[inline]
    fn scan(&self, buf: &[u8], checked: usize) -> Scan {
        match buf.first() {
            Some(&binary::START) => binary::scan_binary(buf, self.from, Some(ascii_frame_at)),
            _ => ascii::scan_ascii(buf, checked, true),
        }
    }

    fn truncated(&self, buf: &[u8]) -> FrameError {
        match buf.first() {
            Some(&binary::START) => binary::truncated(buf, self.from),
            _ => ascii::AsciiScanner.truncated(buf),
        }
    }
}

/// Whether a whole ASCII-mode frame starts `buf`: one without SUM has no check, so it must at
/// least parse (the binary scanner asks, to tell a `(` in its data from a new frame).
fn ascii_frame_at(buf: &[u8]) -> bool {
    match ascii::scan_ascii(buf, 0, true) {
        Scan::Frame { len } => buf.get(..len).is_some_and(|f| ascii::parse_frame(f, None).is_ok()),
        _ => false,
    }
}

/// A request in either mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TipRequest {
    /// ASCII mode.
    Ascii(AsciiRequest),
    /// Binary mode.
    Binary(BinaryRequest),
}

impl TipRequest {
    /// Reads a whole request frame of either mode.
    pub fn parse(bytes: &[u8]) -> Result<Self, FrameError> {
        match bytes.first() {
            Some(&binary::START) => BinaryRequest::parse(bytes).map(TipRequest::Binary),
            _ => AsciiRequest::parse(bytes).map(TipRequest::Ascii),
        }
    }

    /// Writes the frame into `out`; returns its length.
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, EmitError> {
        match self {
            TipRequest::Ascii(r) => r.emit(out),
            TipRequest::Binary(r) => r.emit(out),
        }
    }

    /// The command (`None` for a binary block request).
    pub fn cmd(&self) -> Option<Cmd> {
        match self {
            TipRequest::Ascii(r) => Some(r.cmd),
            TipRequest::Binary(r) => r.body.cmd(),
        }
    }

    /// The reply of inverter `me` in the request's mode carrying `data` (the value read, or
    /// written); `None` for a binary block request.
    pub fn reply(&self, me: u8, tripped: bool, data: u16) -> Option<TipReply> {
        match self {
            TipRequest::Ascii(r) => Some(TipReply::Ascii(r.reply(me, tripped, data))),
            TipRequest::Binary(r) => r.reply(me, tripped, data).map(TipReply::Binary),
        }
    }

    /// The error reply of inverter `me` in the request's mode.
    pub fn error_reply(&self, me: u8, tripped: bool, code: ErrorCode) -> TipReply {
        match self {
            TipRequest::Ascii(r) => TipReply::Ascii(r.error_reply(me, tripped, code)),
            TipRequest::Binary(r) => TipReply::Binary(r.error_reply(me, tripped, code)),
        }
    }
}

/// A reply in either mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TipReply {
    /// ASCII mode.
    Ascii(AsciiReply),
    /// Binary mode.
    Binary(BinaryReply),
}

impl TipReply {
    /// Reads a whole reply frame of either mode.
    pub fn parse(bytes: &[u8]) -> Result<Self, FrameError> {
        match bytes.first() {
            Some(&binary::START) => BinaryReply::parse(bytes).map(TipReply::Binary),
            _ => AsciiReply::parse(bytes).map(TipReply::Ascii),
        }
    }

    /// Writes the frame into `out`; returns its length.
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, EmitError> {
        match self {
            TipReply::Ascii(r) => r.emit(out),
            TipReply::Binary(r) => r.emit(out),
        }
    }

    /// The data of a data reply.
    pub fn data(&self) -> Option<u16> {
        match self {
            TipReply::Ascii(r) => r.data(),
            TipReply::Binary(r) => r.data(),
        }
    }

    /// The error code of an error reply.
    pub fn error(&self) -> Option<ErrorCode> {
        match self {
            TipReply::Ascii(r) => r.error(),
            TipReply::Binary(r) => r.error(),
        }
    }

    /// Whether the inverter is tripped (lower-case CMD).
    pub fn tripped(&self) -> bool {
        match self {
            TipReply::Ascii(r) => r.tripped,
            TipReply::Binary(r) => r.tripped,
        }
    }

    /// The data in Hz, when the communication number is a 0.01 Hz value.
    pub fn hz(&self) -> Option<f64> {
        match self {
            TipReply::Ascii(r) => r.hz(),
            TipReply::Binary(r) => r.hz(),
        }
    }
}

/// What a reply must match, in the request's mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TipPending {
    /// An ASCII-mode request.
    Ascii(AsciiPending),
    /// A binary-mode request.
    Binary(BinaryPending),
}

/// TIP in both modes on one line: a drive that answers either, or a master that uses both.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Tip {
    /// ASCII-mode settings.
    pub ascii: TipAscii,
    /// Binary-mode settings.
    pub binary: TipBinary,
}

impl Tip {
    /// The error reply inverter `me` sends to a request frame of either mode it rejected, or
    /// `None` when it stays silent (see [`ascii::rejection_reply`], [`binary::rejection_reply`]).
    pub fn rejection_reply(bytes: &[u8], me: u8, tripped: bool) -> Option<TipReply> {
        match bytes.first() {
            Some(&binary::START) => binary::rejection_reply(bytes, me, tripped).map(TipReply::Binary),
            _ => ascii::rejection_reply(bytes, me, tripped).map(TipReply::Ascii),
        }
    }
}

impl Protocol for Tip {
    type ReplyScanner = TipScanner;
    type RequestScanner = TipScanner;
    type Pending = TipPending;

    frame_methods!(TipRequest, TipReply);

    fn reply_scanner(&self) -> TipScanner {
        TipScanner { from: Some(Direction::Drive) }
    }
    fn request_scanner(&self) -> TipScanner {
        TipScanner { from: Some(Direction::Master) }
    }
    fn pending(&self, req: &TipRequest) -> Option<TipPending> {
        match req {
            TipRequest::Ascii(r) => self.ascii.pending(r).map(TipPending::Ascii),
            TipRequest::Binary(r) => self.binary.pending(r).map(TipPending::Binary),
        }
    }
    fn matches(&self, pending: &TipPending, rep: &TipReply) -> bool {
        match (pending, rep) {
            (TipPending::Ascii(p), TipReply::Ascii(r)) => p.matches(r),
            (TipPending::Binary(p), TipReply::Binary(r)) => p.matches(r),
            _ => false,
        }
    }
    /// By the header only, in the pending request's mode (see [`TipAscii::answers`],
    /// [`TipBinary::answers`]); a frame of the other mode is parsed whole.
    fn reply_matches(&self, pending: &TipPending, bytes: &[u8]) -> Result<bool, FrameError> {
        match (pending, bytes.first()) {
            (TipPending::Ascii(p), Some(&ascii::START)) => self.ascii.answers(p, bytes),
            (TipPending::Binary(p), Some(&binary::START)) => self.binary.answers(p, bytes),
            _ => self.parse_reply(bytes).map(|rep| self.matches(pending, &rep)),
        }
    }
    fn disposition(&self, req: &TipRequest, me: u8) -> Disposition {
        match req {
            TipRequest::Ascii(r) => r.inv_no.disposition(me),
            TipRequest::Binary(r) => r.inv_no.disposition(me),
        }
    }
    fn rejected_disposition(&self, bytes: &[u8], _error: &FrameError, me: u8) -> Disposition {
        match bytes.first() {
            Some(&binary::START) => self.binary.rejected_disposition(bytes, me),
            _ => self.ascii.rejected_disposition(bytes, me),
        }
    }
}

impl Describe for TipRequest {
    fn direction(&self) -> Direction {
        Direction::Master
    }
    fn target(&self) -> Target {
        self.frame().target()
    }
    fn command(&self) -> Command {
        self.frame().command()
    }
    fn fields(&self, out: &mut dyn FnMut(Field<'_>)) {
        self.frame().fields(out)
    }
}

impl TipRequest {
    fn frame(&self) -> Frame {
        match *self {
            TipRequest::Ascii(r) => Frame::Ascii(AsciiFrame::Request(r)),
            TipRequest::Binary(r) => Frame::Binary(BinaryFrame::Request(r)),
        }
    }
}

impl Describe for TipReply {
    fn direction(&self) -> Direction {
        Direction::Drive
    }
    fn target(&self) -> Target {
        self.frame().target()
    }
    fn command(&self) -> Command {
        self.frame().command()
    }
    fn is_refusal(&self) -> bool {
        self.error().is_some()
    }
    fn fields(&self, out: &mut dyn FnMut(Field<'_>)) {
        self.frame().fields(out)
    }
}

impl TipReply {
    fn frame(&self) -> Frame {
        match *self {
            TipReply::Ascii(r) => Frame::Ascii(AsciiFrame::Reply(r)),
            TipReply::Binary(r) => Frame::Binary(BinaryFrame::Reply(r)),
        }
    }
}

enum Frame {
    Ascii(AsciiFrame),
    Binary(BinaryFrame),
}

impl Frame {
    fn target(&self) -> Target {
        match self {
            Frame::Ascii(f) => f.target(),
            Frame::Binary(f) => f.target(),
        }
    }
    fn command(&self) -> Command {
        match self {
            Frame::Ascii(f) => f.command(),
            Frame::Binary(f) => f.command(),
        }
    }
    fn fields(&self, out: &mut dyn FnMut(Field<'_>)) {
        match self {
            Frame::Ascii(f) => f.fields(out),
            Frame::Binary(f) => f.fields(out),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::deframe::{Deframer, Event};
    use std::vec::Vec;

    fn run(from: Option<Direction>, stream: &[u8]) -> (Vec<Vec<u8>>, usize) {
        let mut d = Deframer::new(TipScanner { from });
        let mut good = Vec::new();
        let mut bad = 0;
        d.push(stream, &mut |e| match e {
            Event::Frame { bytes, .. } => good.push(bytes.to_vec()),
            Event::Rejected { .. } => bad += 1,
        });
        (good, bad)
    }

    #[test]
    fn both_modes_on_one_line() {
        let a = b"(RFE03)\r".to_vec();
        let b = [0x2F, 0x52, 0x00, 0x00, 0x81].to_vec();
        let c = b"(W00100064)\r".to_vec();
        let d = [0x2F, 0x57, 0x00, 0x10, 0x00, 0x64, 0xFA].to_vec();
        let mut stream = Vec::new();
        for f in [&a, &b, &c, &d] {
            stream.extend_from_slice(b"\x00zz");
            stream.extend_from_slice(f);
        }
        let (good, bad) = run(Some(Direction::Master), &stream);
        assert_eq!(good, [a.clone(), b.clone(), c.clone(), d.clone()]);
        assert_eq!(bad, 0);
        assert!(matches!(TipRequest::parse(&a), Ok(TipRequest::Ascii(_))));
        assert!(matches!(TipRequest::parse(&b), Ok(TipRequest::Binary(_))));
    }

    #[test]
    fn cut_ascii_frame_does_not_hide_binary() {
        // An ASCII frame cut off by a binary start code: the binary frame is still found.
        let mut stream = b"(RFE".to_vec();
        stream.extend_from_slice(&[0x2F, 0x52, 0x00, 0x00, 0x81]);
        let (good, bad) = run(Some(Direction::Master), &stream);
        assert_eq!(good, [[0x2F, 0x52, 0x00, 0x00, 0x81].to_vec()]);
        assert_eq!(bad, 1);
    }

    #[test]
    fn rejection_in_each_mode() {
        let r = Tip::rejection_reply(b"(R0000&61)\r", 0, false).unwrap();
        assert_eq!(r.error(), Some(ErrorCode::CHECKSUM_ERROR));
        assert!(matches!(r, TipReply::Ascii(_)));
        let r = Tip::rejection_reply(&[0x2F, 0x52, 0x00, 0x00, 0x80], 0, false).unwrap();
        assert!(matches!(r, TipReply::Binary(_)));
        assert_eq!(Tip::rejection_reply(b"(1R0000)\r", 0, false), None);
    }
}
