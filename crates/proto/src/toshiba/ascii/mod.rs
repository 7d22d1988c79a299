//! TIP ASCII mode. `seeds/002_43d8a4399c8be05f.txt` names it; the frame is in protocols.md 1.4,
//! from the public VF-S11 (p.8–9) and VF-S15 (p.7–8) manuals.
//!
//! ```text
//! "(" [INV-NO:2] CMD COMNO:4 [DATA:0..4] ["&" SUM:2] ")" CR        request and reply
//! "(" [INV-NO:2] "N"|"n" ERROR:4 ["&" SUM:2] ")" CR                 error reply
//! ```
//!
//! - INV-NO: two decimal digits 00–99, omitted on 1:1 links; `*` is a wildcard digit
//!   (`*2` = 02, 12, 22, ...; `**` = every inverter). Only the smallest number the pattern can
//!   match answers (manual VF-S11 p.9: `(*2R0000)` -> `(02R00000000)` from inverter 02 only).
//! - CMD `R` read, `W` write RAM+EEPROM, `P` write RAM; a tripped inverter answers in lower case.
//! - SUM: the 8-bit sum of the bytes from `(` through `&`, as two hex digits.
//! - drivebus replies always carry 4 data digits, and `&`+SUM exactly when the request had it
//!   (project decisions).
//!
//! Who sent a frame: a lower-case command or `N`/`n` is a drive's; `R` without data is a
//! master's, `R` with data a drive's; `W`/`P` with data are an echo, the same both ways, so the
//! caller's `from` decides (default: master).
//!
//! Format errors (a one-digit INV-NO, `(R11)` CR, a wrong stop code) get no reply from a drive;
//! checksum, command, communication-number and data errors get an `N` reply
//! (protocols.md 1.6, VF-AS1 manual 4.3 "Transmission errors"). [`rejection_reply`] builds it.
//!
//! The pieces: [`AsciiAddress`] (INV-NO with wildcards, `address`), the typed frames with
//! `emit` (`frame`), reading a frame and the error reply a drive owes a bad one (`parse`), the
//! [`AsciiScanner`] (`scan`), [`Describe`](crate::describe::Describe) for
//! [`AsciiFrame`] (`show`); here the session [`TipAscii`] and the codec [`AsciiCodec`].

use crate::codec::Codec;
use crate::describe::Direction;
use crate::error::FrameError;
use crate::session::{frame_methods, Disposition, Protocol};

use super::{Cmd, CommNo};

mod address;
mod frame;
mod parse;
mod scan;
mod show;

#[cfg(test)]
mod tests;

pub use address::AsciiAddress;
pub use frame::{AsciiData, AsciiFrame, AsciiReply, AsciiReplyBody, AsciiRequest};
pub(crate) use parse::parse_frame;
use parse::rejection;
pub use parse::rejection_reply;
pub(crate) use scan::scan_ascii;
pub use scan::AsciiScanner;

/// Start code `(` (28H).
pub const START: u8 = super::ASCII_START;
/// Stop code `)` (29H).
pub const STOP: u8 = b')';
/// CR (0DH), after the stop code.
pub const CR: u8 = 0x0D;
/// Checksum discrimination code `&` (26H).
pub const SUM_MARK: u8 = b'&';
/// Wildcard digit of INV-NO `*` (2AH).
pub const WILDCARD: u8 = b'*';
/// The longest ASCII-mode frame: `(` 2 + 1 + 4 + 4 `&` 2 `)` CR = 17 bytes
/// (the manual: "to a maximum of 17 bytes").
pub const MAX_FRAME: usize = 17;

/// What a reply to an ASCII request must match.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AsciiPending {
    /// INV-NO the reply carries.
    pub inv_no: Option<u8>,
    /// CMD of the request.
    pub cmd: Cmd,
    /// COMNO of the request.
    pub comm_no: CommNo,
}

impl AsciiPending {
    /// Whether `rep` answers the request.
    pub fn matches(&self, rep: &AsciiReply) -> bool {
        let data = match rep.body {
            AsciiReplyBody::Error(_) => None,
            AsciiReplyBody::Data { cmd, comm_no, .. } => Some((cmd, comm_no)),
        };
        self.matches_header(rep.inv_no, data)
    }

    /// Whether a reply with `inv_no` and `data` (CMD and COMNO; `None` for an error reply) in
    /// its header answers the request, whatever DATA follows.
    #[inline]
    pub fn matches_header(&self, inv_no: Option<u8>, data: Option<(Cmd, CommNo)>) -> bool {
        inv_no == self.inv_no
            && match data {
                None => true,
                Some((cmd, comm_no)) => cmd == self.cmd && comm_no == self.comm_no,
            }
    }
}

/// TIP ASCII mode as a [`Protocol`] for masters and single-mode drives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TipAscii {
    /// Whether the master waits for the reply to a wildcard request (from the smallest number
    /// the pattern matches, as the manual says). Set to false when no inverter has that number:
    /// the master then treats wildcards as broadcasts with no reply due.
    pub broadcast_reply: bool,
}

impl Default for TipAscii {
    fn default() -> Self {
        TipAscii { broadcast_reply: true }
    }
}

impl TipAscii {
    /// Whether the reply frame `bytes` answers `pending`, by its header only (INV-NO, CMD,
    /// COMNO; DATA is not decoded): the reply is parsed once, by whoever uses it. A frame whose
    /// header is not a reply's, or does not answer, is parsed whole, so that it is told apart
    /// as before (a frame that is no reply is an error, another inverter's reply is not).
    pub fn answers(&self, pending: &AsciiPending, bytes: &[u8]) -> Result<bool, FrameError> {
        match parse::reply_header(bytes) {
            Some((inv_no, data)) if pending.matches_header(inv_no, data) => Ok(true),
            _ => AsciiReply::parse(bytes).map(|rep| pending.matches(&rep)),
        }
    }

    /// What a reply to `req` must match; `None` when no reply is due.
    pub fn pending(&self, req: &AsciiRequest) -> Option<AsciiPending> {
        if matches!(req.inv_no, AsciiAddress::Wildcard { .. }) && !self.broadcast_reply {
            return None;
        }
        Some(AsciiPending { inv_no: req.inv_no.reply_inv_no(), cmd: req.cmd, comm_no: req.comm_no })
    }

    /// How inverter `me` treats a request frame that did not parse: an error reply (checksum,
    /// command, communication number, data errors) when addressed to it, else silence.
    pub fn rejected_disposition(&self, bytes: &[u8], me: u8) -> Disposition {
        match rejection(bytes) {
            Some((inv_no, _, _)) => inv_no.disposition(me),
            None => Disposition::NotMine,
        }
    }
}

impl Protocol for TipAscii {
    type ReplyScanner = AsciiScanner;
    type RequestScanner = AsciiScanner;
    type Pending = AsciiPending;

    frame_methods!(AsciiRequest, AsciiReply);

    fn reply_scanner(&self) -> AsciiScanner {
        AsciiScanner
    }
    fn request_scanner(&self) -> AsciiScanner {
        AsciiScanner
    }
    fn pending(&self, req: &AsciiRequest) -> Option<AsciiPending> {
        TipAscii::pending(self, req)
    }
    fn matches(&self, pending: &AsciiPending, rep: &AsciiReply) -> bool {
        pending.matches(rep)
    }
    fn reply_matches(&self, pending: &AsciiPending, bytes: &[u8]) -> Result<bool, FrameError> {
        self.answers(pending, bytes)
    }
    fn disposition(&self, req: &AsciiRequest, me: u8) -> Disposition {
        req.inv_no.disposition(me)
    }
    fn rejected_disposition(&self, bytes: &[u8], _error: &FrameError, me: u8) -> Disposition {
        TipAscii::rejected_disposition(self, bytes, me)
    }
}

/// The `toshiba-ascii` codec.
#[derive(Clone, Copy, Debug, Default)]
pub struct AsciiCodec;

impl Codec for AsciiCodec {
    const NAME: &'static str = "toshiba-ascii";
    type Scanner = AsciiScanner;
    type Frame<'a> = AsciiFrame;

    fn scanner(_from: Option<Direction>) -> AsciiScanner {
        AsciiScanner
    }

    fn parse(bytes: &[u8], from: Option<Direction>) -> Result<AsciiFrame, FrameError> {
        AsciiFrame::parse(bytes, from)
    }
}
