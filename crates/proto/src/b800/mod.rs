//! The B800 series RS-485 ASCII protocol (`seeds/000_04b515f0e0c1734e.txt`).
//!
//! ```text
//! FG1 [DA] [CMD]   ([DATA]) [CS] FG2     master -> drive   7E 38 31 35 32 32 46 7F   (81 'R', CS 2F)
//! FG1 [DA] [REPLY] ([DATA]) [CS] FG2     drive -> master   7E 30 31 37 32 33 35 7F   (01 'r', CS 35)
//! ```
//!
//! - Every field between the flags goes as upper-case hex ASCII (received in either case):
//!   seed 000: "a RUN command ('R' = 0x52 (hex)) is sent as two consecutive ASCII codes ie
//!   0x35, 0x32".
//! - CS is the NOT of the 8-bit sum of the ASCII characters of DA, CMD and DATA
//!   ([`crate::checksum::not_sum8`]), sent as two hex digits.
//! - The master sends DA = drive number + 128 (0x81–0xBF), or `G` (0x47) to every drive (no
//!   reply); a drive replies with its plain number 1–63. So the DA byte tells who sent a frame.
//! - Replies are the lower-case command letter, or `e` with an error code. Words go high byte
//!   first as 4 digits; the units of the reply words are project decisions (see
//!   protocols.md, "Project decisions", "B800"): `a` 0.1 A, `z` 60 x Hz, `m` rpm, `v` BCD, `t` status.
//!
//! Types: [`Request`] / [`Reply`] (typed frames, `parse` / `emit`), [`Packet`] (either side),
//! [`FrameScanner`] (the receiver state machine), [`B800`] (the [`Protocol`] for sessions and
//! the [`Codec`] `"b800"`), [`timing`].

use core::time::Duration;

use crate::codec::Codec;
use crate::describe::Direction;
use crate::error::FrameError;
use crate::line::CharFormat;
use crate::session::{frame_methods, Disposition, Protocol, Timing};

mod frame;
mod scan;
mod show;
mod values;

#[cfg(test)]
mod tests;

pub use frame::{MasterCommand, Packet, Reply, Request, SlaveReply, CMD_FIELD, REPLY_FIELD};
pub use scan::FrameScanner;
pub use show::Frame;
pub use values::{Address, Current, Destination, DriveState, DriveStatus, ErrorCode, Rpm, Speed, Version};

/// FG1, the start flag (seed 000: "0x7E, flags start of data transmission").
pub const FG1: u8 = 0x7E;
/// FG2, the stop flag (seed 000: "0x7F, flags end of data transmission").
pub const FG2: u8 = 0x7F;
/// The global DA (seed 000: "the ASCII code for 'G' (0x47) as the drive address").
pub const GLOBAL: u8 = b'G';
/// What a master adds to a drive number to make its DA.
pub const MASTER_OFFSET: u8 = 128;
/// The shortest frame: FG1, DA, CMD, CS (2 digits each), FG2.
pub const MIN_FRAME: usize = 8;
/// The longest frame: FG1, DA, CMD, a word of DATA, CS, FG2.
pub const MAX_FRAME: usize = 12;
/// The most bytes the scanner holds for a candidate: longer than [`MAX_FRAME`], so that a
/// frame with too much DATA is reported by name rather than as an overlong candidate.
pub const SCAN_LIMIT: usize = 32;

/// The seed's line speed (seed 000: "operating at 9600 bps").
pub const BAUD: u32 = 9600;
/// 8N1 (seed 000: "a Start bit (1), 8 Data bits (LSB first) and a Stop bit (0)"; no parity
/// is mentioned).
pub const FORMAT: CharFormat = CharFormat::NONE_8N1;
/// The master's response timeout (project decision: 100 ms).
pub const RESPONSE_TIMEOUT: Duration = Duration::from_millis(100);

/// The master's times for B800 at `baud` and `format`: response timeout 100 ms, one
/// character of silence between frames (the flags delimit frames, so no longer gap is needed).
pub fn timing(baud: u32, format: CharFormat) -> Timing {
    Timing::new(baud, format, RESPONSE_TIMEOUT, format.char_time(baud))
}

/// [`timing`] at the seed's 9600 bps 8N1.
pub fn default_timing() -> Timing {
    timing(BAUD, FORMAT)
}

/// The reply a master waits for: this drive, this reply letter (or `e`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Pending {
    /// The drive that must answer.
    pub from: Address,
    /// The reply letter that answers (the command's lower case).
    pub reply: u8,
}

impl Pending {
    /// True when `rep` comes from the drive and is the expected reply or an `e`.
    pub fn matches(&self, rep: &Reply) -> bool {
        self.matches_header(rep.da.get(), rep.reply.letter())
    }

    /// True when a reply from DA `da` with the REPLY letter `letter` in its header answers:
    /// this drive, the expected reply or an `e`, whatever DATA follows.
    #[inline]
    pub fn matches_header(&self, da: u8, letter: u8) -> bool {
        da == self.from.get() && (letter == self.reply || letter == ERROR_LETTER)
    }
}

impl Request {
    /// The reply due to this request; `None` for a global one.
    ///
    /// seed 000: "There is no reply from the B800s to a global command."
    pub const fn expected_reply(&self) -> Option<Pending> {
        match self.da {
            Destination::Drive(from) => Some(Pending { from, reply: self.cmd.reply_letter() }),
            Destination::Global => None,
        }
    }
}

/// The letter of the `e` reply (seed 000: "'e' (0x65) Error – command not executed").
pub(crate) const ERROR_LETTER: u8 = b'e';

/// The B800 protocol: [`Protocol`] for the master and slave sessions, and the [`Codec`]
/// named `"b800"`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct B800;

impl B800 {
    /// Whether the reply frame `bytes` answers `pending`, by its header only (the flags, the DA
    /// and REPLY digits): the reply is parsed once, by whoever uses it. A frame whose header
    /// does not read, or does not answer, is parsed whole, so that it is told apart as before
    /// (a frame that is no reply is an error, another drive's reply is not).
    pub fn answers(&self, pending: &Pending, bytes: &[u8]) -> Result<bool, FrameError> {
        match frame::header(bytes) {
            Some((da, letter)) if pending.matches_header(da, letter) => Ok(true),
            _ => Reply::parse(bytes).map(|rep| pending.matches(&rep)),
        }
    }

    /// The `e` reply drive `me` owes a rejected frame, if any (project decision): a frame
    /// for this drive with a wrong checksum gets 0x95, one with an unknown command 0x97.
    pub fn rejected_reply(&self, bytes: &[u8], error: &FrameError, me: u8) -> Option<Reply> {
        let me = Address::new(me)?;
        if raw_da(bytes)? != me.master_da() {
            return None;
        }
        let code = match error {
            FrameError::ChecksumMismatch { .. } => ErrorCode::BAD_CHECKSUM,
            FrameError::Unknown { field, .. } if *field == CMD_FIELD => ErrorCode::UNKNOWN_COMMAND,
            _ => return None,
        };
        Some(Reply::new(me, SlaveReply::error(code)))
    }
}

/// The DA byte of a frame candidate whose first two digits are hex.
fn raw_da(bytes: &[u8]) -> Option<u8> {
    match bytes {
        [FG1, a0, a1, ..] if frame::HEX[*a0 as usize] <= 0x0F && frame::HEX[*a1 as usize] <= 0x0F => {
            Some(frame::pair(*a0, *a1))
        }
        _ => None,
    }
}

impl Protocol for B800 {
    type ReplyScanner = FrameScanner;
    type RequestScanner = FrameScanner;
    type Pending = Pending;

    frame_methods!(Request, Reply);

    fn reply_scanner(&self) -> FrameScanner {
        FrameScanner::new(Some(Direction::Drive))
    }

    fn request_scanner(&self) -> FrameScanner {
        FrameScanner::new(Some(Direction::Master))
    }

    fn pending(&self, req: &Request) -> Option<Pending> {
        req.expected_reply()
    }

    fn matches(&self, pending: &Pending, rep: &Reply) -> bool {
        pending.matches(rep)
    }

    fn reply_matches(&self, pending: &Pending, bytes: &[u8]) -> Result<bool, FrameError> {
        self.answers(pending, bytes)
    }

    /// DA = `me` + 128: mine; `G`: act without replying; anything else: ignore.
    ///
    /// seed 000: "if a valid data packet is received with an incorrect (different) drive
    /// address, the B800 will ignore the data and no response at all will be generated."
    fn disposition(&self, req: &Request, me: u8) -> Disposition {
        match req.da {
            Destination::Drive(a) if a.get() == me => Disposition::Mine,
            Destination::Drive(_) => Disposition::NotMine,
            Destination::Global => Disposition::Broadcast { reply: false },
        }
    }

    /// A whole frame for this drive (DA = `me` + 128) with a wrong checksum or an unknown
    /// command is answered with `e` 0x95 / 0x97 (project decision; see
    /// [`B800::rejected_reply`]); anything else, including a global frame, is ignored.
    fn rejected_disposition(&self, bytes: &[u8], error: &FrameError, me: u8) -> Disposition {
        match self.rejected_reply(bytes, error, me) {
            Some(_) => Disposition::Mine,
            None => Disposition::NotMine,
        }
    }
}

impl Codec for B800 {
    const NAME: &'static str = "b800";
    type Scanner = FrameScanner;
    type Frame<'a> = Frame<'a>;

    fn scanner(from: Option<Direction>) -> FrameScanner {
        FrameScanner::new(from)
    }

    /// The DA byte always tells who sent a B800 frame, so `from` is not needed.
    fn parse(bytes: &[u8], _from: Option<Direction>) -> Result<Frame<'_>, FrameError> {
        Frame::parse(bytes)
    }
}
