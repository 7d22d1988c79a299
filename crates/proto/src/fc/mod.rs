//! Danfoss FC protocol telegrams (VLT FC 102/202/302, FC 280, FC 360, older VLT 2800/5000/6000).
//!
//! Source: seed 003 (`seeds/003_26a4c04ca1af5f26.txt`, FC 280 Design Guide MG07B102
//! 5.4.4–5.4.7) and protocols.md section 2 with the "Danfoss FC" project decisions.
//!
//! ```text
//! STX(02) LGE ADR <data> BCC       LGE = data bytes + 2 (ADR and BCC); LGE + 2 bytes in all
//! process block    PCD1 PCD2                              LGE 6
//! parameter block  PKE IND PWEhigh PWElow PCD1 PCD2       LGE 14
//! text block       PKE IND Ch1..Chn PCD1 PCD2             LGE 10 + n
//! BCC = XOR of STX .. the last data byte, starting from 0; words big-endian
//! ```
//!
//! - [`telegram`]: [`Adr`] (both address formats), the three [`Block`]s, typed [`Request`]
//!   and [`Reply`] with `parse`/`emit`, and the [`FcScanner`].
//! - [`parameter`]: [`ParameterNumber`] (`4-14` <-> PNU 414), the AK tables
//!   ([`ParameterCommand`], [`ParameterResponse`]), [`FaultCode`]s, description elements.
//! - [`words`]: [`ControlWord`], [`StatusWord`] (FC profile) and [`Reference`] (0x4000 = 100 %).
//! - [`Fc`]: the [`Protocol`] for the sessions; [`timing`]; [`DanfossFc`]: the `danfoss-fc`
//!   [`Codec`](crate::codec::Codec) with its [`Frame`].
//!
//! Who sent a telegram: the slave returns ADR unchanged, so ADR does not tell. AK 7 only
//! comes from a drive, AK 4, D and E only from the master; otherwise the caller says
//! (`from`), and the master is the default.

use core::time::Duration;

use crate::error::{EmitError, FrameError};
use crate::line::{bits_time, CharFormat};
use crate::session::{frame_methods, Disposition, Protocol, Timing};

pub mod frame;
pub mod parameter;
pub mod telegram;
pub mod words;

pub use frame::{infer_direction, DanfossFc, Frame, Message};
pub use parameter::{
    data_type, description_element, FaultCode, ParameterCommand, ParameterNumber, ParameterNumberError,
    ParameterResponse,
};
pub use telegram::{
    AddressFormat, Adr, Block, FcScanner, ParameterBlock, RawTelegram, Reply, Request, TextBlock,
    MAX_TELEGRAM,
};
pub use words::{ControlWord, Reference, StatusWord};

/// Default serial settings: 9600 baud (project decision).
pub const DEFAULT_BAUD: u32 = 9600;
/// Default character format: 8 data bits, even parity, 1 stop bit (8-33 "Even parity, 1 stop bit").
pub const DEFAULT_FORMAT: CharFormat = CharFormat::EVEN_8E1;
/// Response timeout: the VLT 2800/6000 telegram-traffic sections say "max. 50 ms".
pub const RESPONSE_TIMEOUT: Duration = Duration::from_millis(50);
/// Wait after a broadcast before the next telegram. The manuals give none; drivebus waits
/// the longest response time of the VLT 6000/FCD guides ("at most 20 ms"), by which a drive
/// has handled any telegram it would have answered.
pub const BROADCAST_TURNAROUND: Duration = Duration::from_millis(20);

/// The master's timing for `baud` and `format`: response timeout 50 ms, at least 2 characters
/// of silence after a reply before the next telegram (22 bits at 8E1, 2.3 ms at 9600:
/// protocols.md 2.9), [`BROADCAST_TURNAROUND`] after a broadcast.
pub fn timing(baud: u32, format: CharFormat) -> Timing {
    let mut t = Timing::new(baud, format, RESPONSE_TIMEOUT, two_chars(baud, format));
    t.turnaround = BROADCAST_TURNAROUND;
    t
}

/// The shortest delay before a drive answers: 2 characters (protocols.md 2.9, "at least
/// 2 characters"), for a `SlaveSession`.
pub fn min_response_delay(baud: u32, format: CharFormat) -> Duration {
    two_chars(baud, format)
}

/// Two characters' time: 22 bits at 8E1.
fn two_chars(baud: u32, format: CharFormat) -> Duration {
    bits_time(2 * format.bits_per_char(), baud)
}

/// The FC protocol for [`MasterSession`](crate::session::MasterSession) and
/// [`SlaveSession`](crate::session::SlaveSession).
///
/// `address_format` is the format of the ADR the master builds with [`Fc::adr`]; a slave
/// accepts its number in either format and echoes the ADR byte unchanged.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Fc {
    /// The address format of requests built with [`Fc::adr`] (default 1–126).
    pub address_format: AddressFormat,
}

impl Fc {
    /// The protocol with requests in `address_format`.
    pub const fn new(address_format: AddressFormat) -> Self {
        Fc { address_format }
    }

    /// The ADR of drive `address` in this protocol's address format.
    pub fn adr(&self, address: u8) -> Result<Adr, EmitError> {
        Adr::new(address, self.address_format)
    }

    /// The broadcast ADR in this protocol's address format.
    pub const fn broadcast(&self) -> Adr {
        Adr::broadcast(self.address_format)
    }
}

/// What a reply must match: the ADR byte (echoed unchanged), the telegram type, and the
/// parameter number where one was asked for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FcPending {
    /// The request's ADR.
    pub adr: Adr,
    /// The request's command and parameter number, `None` for a process block.
    pub parameter: Option<(ParameterCommand, ParameterNumber)>,
}

impl FcPending {
    /// Whether a reply with `adr` and `parameter` (AK and PNU; `None` for a process block) in
    /// its header answers the request: the same ADR byte; a process block answers a process
    /// block and a parameter or text block answers one of those; the PNU must be echoed,
    /// except in an AK 7 refusal and in the answer to AK 0 "no command" (the manuals do not
    /// say what PNU those carry).
    #[inline]
    pub fn matches_header(&self, adr: Adr, parameter: Option<(ParameterResponse, ParameterNumber)>) -> bool {
        if adr != self.adr {
            return false;
        }
        match (self.parameter, parameter) {
            (None, None) => true,
            (Some((cmd, pnu)), Some((ak, rpnu))) => {
                rpnu == pnu || ak == ParameterResponse::CannotPerform || cmd == ParameterCommand::NoCommand
            }
            _ => false,
        }
    }
}

impl Fc {
    /// Whether the reply telegram `bytes` answers `pending`, by its header only (ADR, LGE, PKE;
    /// IND, PWE, the text and PCD1/PCD2 are not read): the reply is parsed once, by whoever
    /// uses it. A telegram whose header does not read, or does not answer, is parsed whole, so
    /// that it is told apart as before (a telegram that is no reply is an error, another
    /// drive's reply is not).
    pub fn answers(&self, pending: &FcPending, bytes: &[u8]) -> Result<bool, FrameError> {
        match telegram::reply_header(bytes) {
            Some((adr, parameter)) if pending.matches_header(adr, parameter) => Ok(true),
            _ => Reply::parse(bytes).map(|rep| self.matches(pending, &rep)),
        }
    }
}

impl Protocol for Fc {
    type ReplyScanner = FcScanner;
    type RequestScanner = FcScanner;
    type Pending = FcPending;

    frame_methods!(Request<'a>, Reply<'a>);

    fn reply_scanner(&self) -> FcScanner {
        FcScanner
    }

    fn request_scanner(&self) -> FcScanner {
        FcScanner
    }

    /// No reply to a broadcast: protocols.md 2.3 "A broadcast gets no reply."
    fn pending(&self, req: &Request<'_>) -> Option<FcPending> {
        if req.adr.is_broadcast() {
            return None;
        }
        Some(FcPending { adr: req.adr, parameter: req.block.header().map(|(ak, pnu, _)| (ak, pnu)) })
    }

    /// See [`FcPending::matches_header`].
    fn matches(&self, pending: &FcPending, rep: &Reply<'_>) -> bool {
        pending.matches_header(rep.adr, rep.block.header().map(|(ak, pnu, _)| (ak, pnu)))
    }

    fn reply_matches(&self, pending: &FcPending, bytes: &[u8]) -> Result<bool, FrameError> {
        self.answers(pending, bytes)
    }

    /// The drive's number in either address format is [`Disposition::Mine`]; a broadcast in
    /// either format is acted on and never answered.
    fn disposition(&self, req: &Request<'_>, me: u8) -> Disposition {
        match req.adr.address() {
            None => Disposition::Broadcast { reply: false },
            Some(a) if a == me => Disposition::Mine,
            Some(_) => Disposition::NotMine,
        }
    }
}

#[cfg(test)]
mod tests;
