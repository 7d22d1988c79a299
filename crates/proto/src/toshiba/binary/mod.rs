//! TIP binary mode. `seeds/002_43d8a4399c8be05f.txt` names it; the frame is in protocols.md 1.5–1.7,
//! from the public VF-AS1 (p.10–17) and VF-S11 (p.7, p.15) manuals.
//!
//! ```text
//! 2F [INV-NO] CMD COMNO:2 [DATA:2] SUM                 R (no DATA), W, P, G (dummy DATA)
//! 2F [INV-NO] 58 nW nR [WDATA1:2] [WDATA2:2] SUM       X block communication
//! 2F [INV-NO] 59 nR RDATA1..RDATAn:2 SUM               Y block reply (project decision)
//! 2F [INV-NO] 4E ERROR:2 SUM                           N error reply
//! ```
//!
//! - INV-NO: one byte 00–3F, FF = broadcast (every inverter acts, only 00 answers), or omitted
//!   on a 1:1 link. It is told apart from CMD by value: INV-NO is at most 3F or FF, every
//!   command is 47H or more.
//! - SUM: the 8-bit sum of the bytes from 2F through the last data byte; it is not omissible.
//! - A tripped inverter answers with CMD + 20H (`r` 72H, `w`, `p`, `g`, `y`, `n` 6EH).
//! - A drive answers only a checksum error with an error reply (`2F 4E 00 04 81`); command
//!   errors, format errors and other inverters' numbers get no reply (protocols.md 1.6).
//!
//! Receiving (manual VF-S11 p.7): everything before 2F is ignored; if 2F comes more than once,
//! the last one counts; the frame is complete once the command's byte count is in. 2F is also
//! an ordinary data byte, so [`BinaryScanner`] applies the "last 2F" rule only where the later
//! 2F starts a whole frame with a good SUM, and otherwise keeps the first 2F.
//!
//! The pieces: [`BinaryAddress`] (`address`), the typed frames with `emit` (`frame`), the
//! [`BinaryScanner`] (`scan`), reading a frame and the error reply a drive owes a bad one
//! (`parse`), [`Describe`](crate::describe::Describe) for [`BinaryFrame`] (`show`); here the
//! session [`TipBinary`] and the codec [`BinaryCodec`].

use crate::codec::Codec;
use crate::describe::Direction;
use crate::error::{EmitError, FrameError};
use crate::session::{frame_methods, Disposition, Protocol};

use super::{Cmd, CommNo};

mod address;
mod frame;
mod parse;
mod scan;
mod show;

#[cfg(test)]
mod tests;

pub use address::BinaryAddress;
pub use frame::{
    BinaryFrame, BinaryReply, BinaryReplyBody, BinaryRequest, BinaryRequestBody, BlockReply, BlockRequest,
};
use parse::rejection;
pub use parse::rejection_reply;
pub use scan::BinaryScanner;
pub(crate) use scan::{scan_binary, truncated};

/// Start code 2FH (`/`).
pub const START: u8 = super::BINARY_START;
/// INV-NO for every inverter.
pub const BROADCAST: u8 = 0xFF;
/// The greatest inverter number binary mode carries (3FH = 63).
pub const MAX_INV_NO: u8 = 0x3F;
/// `X` (58H): block communication.
pub const BLOCK: u8 = b'X';
/// `Y` (59H): block communication reply.
pub const BLOCK_REPLY: u8 = b'Y';
/// The most write groups of a block request (nW); more is a format error.
pub const MAX_WRITE_GROUPS: u8 = 2;
/// The most read groups of a block request (nR); more gives a reply with none.
pub const MAX_READ_GROUPS: u8 = 5;
/// The longest binary-mode frame: a Y reply with INV-NO and 5 read groups, 15 bytes.
pub const MAX_FRAME: usize = 15;

/// A count of data groups and its limit: nW of an `X` request or nR of a `Y` reply.
#[derive(Clone, Copy)]
struct Groups {
    field: &'static str,
    max: u8,
}

/// nW, at most [`MAX_WRITE_GROUPS`].
const N_W: Groups = Groups { field: "nW (number of write data groups)", max: MAX_WRITE_GROUPS };
/// nR, at most [`MAX_READ_GROUPS`].
const N_R: Groups = Groups { field: "nR (number of read data groups)", max: MAX_READ_GROUPS };

impl Groups {
    /// `n` within the limit, else the error for a frame the caller cannot build.
    fn emit(self, n: usize) -> Result<u8, EmitError> {
        match u8::try_from(n) {
            Ok(n) if n <= self.max => Ok(n),
            _ => Err(EmitError::OutOfRange {
                field: self.field,
                value: n as u32,
                min: 0,
                max: self.max as u32,
            }),
        }
    }

    /// `n` within the limit, else the format error of a frame that says more (no reply).
    fn frame(self, n: u8) -> Result<u8, FrameError> {
        if n <= self.max {
            Ok(n)
        } else {
            Err(FrameError::OutOfRange { field: self.field, value: n as u32, min: 0, max: self.max as u32 })
        }
    }
}

/// What a reply must carry to answer a request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Expect {
    /// An `R`/`W`/`P`/`G` reply with this command and COMNO.
    Data {
        /// CMD of the request.
        cmd: Cmd,
        /// COMNO of the request.
        comm_no: CommNo,
    },
    /// A `Y` reply.
    Block,
}

/// What a reply to a binary request must match.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BinaryPending {
    /// INV-NO the reply carries.
    pub inv_no: Option<u8>,
    /// The kind of reply.
    pub expect: Expect,
}

impl BinaryPending {
    /// Whether `rep` answers the request.
    pub fn matches(&self, rep: &BinaryReply) -> bool {
        let kind = match rep.body {
            BinaryReplyBody::Error(_) => None,
            BinaryReplyBody::Data { cmd, comm_no, .. } => Some(Expect::Data { cmd, comm_no }),
            BinaryReplyBody::Block(_) => Some(Expect::Block),
        };
        self.matches_header(rep.inv_no, kind)
    }

    /// Whether a reply with `inv_no` and of `kind` (`None`: an error reply, which answers any
    /// request) in its header answers the request, whatever DATA follows.
    #[inline]
    pub fn matches_header(&self, inv_no: Option<u8>, kind: Option<Expect>) -> bool {
        inv_no == self.inv_no && kind.map_or(true, |k| k == self.expect)
    }
}

/// TIP binary mode as a [`Protocol`] for masters and single-mode drives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TipBinary {
    /// Whether the master waits for inverter 00's reply to a broadcast (FF), as the manual
    /// says; set to false when there is no inverter 00: broadcasts then get no reply.
    pub broadcast_reply: bool,
}

impl Default for TipBinary {
    fn default() -> Self {
        TipBinary { broadcast_reply: true }
    }
}

impl TipBinary {
    /// Whether the reply frame `bytes` answers `pending`, by its header only (INV-NO, CMD,
    /// COMNO; DATA is not read): the reply is parsed once, by whoever uses it. A frame whose
    /// header is not a reply's, or does not answer, is parsed whole, so that it is told apart
    /// as before (a frame that is no reply is an error, another inverter's reply is not).
    pub fn answers(&self, pending: &BinaryPending, bytes: &[u8]) -> Result<bool, FrameError> {
        match parse::reply_header(bytes) {
            Some((inv_no, kind)) if pending.matches_header(inv_no, kind) => Ok(true),
            _ => BinaryReply::parse(bytes).map(|rep| pending.matches(&rep)),
        }
    }

    /// What a reply to `req` must match; `None` when no reply is due.
    pub fn pending(&self, req: &BinaryRequest) -> Option<BinaryPending> {
        if req.inv_no == BinaryAddress::Broadcast && !self.broadcast_reply {
            return None;
        }
        let expect = match (req.body.cmd(), req.body.comm_no()) {
            (Some(cmd), Some(comm_no)) => Expect::Data { cmd, comm_no },
            _ => Expect::Block,
        };
        Some(BinaryPending { inv_no: req.inv_no.reply_inv_no(), expect })
    }

    /// How inverter `me` treats a request frame that did not parse: a checksum error
    /// addressed to it is answered (0004), anything else is not.
    pub fn rejected_disposition(&self, bytes: &[u8], me: u8) -> Disposition {
        match rejection(bytes) {
            Some((inv_no, _)) => inv_no.disposition(me),
            None => Disposition::NotMine,
        }
    }
}

impl Protocol for TipBinary {
    type ReplyScanner = BinaryScanner;
    type RequestScanner = BinaryScanner;
    type Pending = BinaryPending;

    frame_methods!(BinaryRequest, BinaryReply);

    fn reply_scanner(&self) -> BinaryScanner {
        BinaryScanner { from: Some(Direction::Drive) }
    }
    fn request_scanner(&self) -> BinaryScanner {
        BinaryScanner { from: Some(Direction::Master) }
    }
    fn pending(&self, req: &BinaryRequest) -> Option<BinaryPending> {
        TipBinary::pending(self, req)
    }
    fn matches(&self, pending: &BinaryPending, rep: &BinaryReply) -> bool {
        pending.matches(rep)
    }
    fn reply_matches(&self, pending: &BinaryPending, bytes: &[u8]) -> Result<bool, FrameError> {
        self.answers(pending, bytes)
    }
    fn disposition(&self, req: &BinaryRequest, me: u8) -> Disposition {
        req.inv_no.disposition(me)
    }
    fn rejected_disposition(&self, bytes: &[u8], _error: &FrameError, me: u8) -> Disposition {
        TipBinary::rejected_disposition(self, bytes, me)
    }
}

/// The `toshiba-binary` codec.
#[derive(Clone, Copy, Debug, Default)]
pub struct BinaryCodec;

impl Codec for BinaryCodec {
    const NAME: &'static str = "toshiba-binary";
    type Scanner = BinaryScanner;
    type Frame<'a> = BinaryFrame;

    fn scanner(from: Option<Direction>) -> BinaryScanner {
        BinaryScanner { from }
    }

    fn parse(bytes: &[u8], from: Option<Direction>) -> Result<BinaryFrame, FrameError> {
        BinaryFrame::parse(bytes, from)
    }
}
