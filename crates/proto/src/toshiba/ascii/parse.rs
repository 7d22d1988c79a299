//! Reading an ASCII-mode frame, and the error reply a drive owes one it cannot accept.

use crate::describe::Direction;
use crate::error::{ChecksumKind, FrameError};
use crate::hex;

use super::{AsciiAddress, AsciiData, AsciiFrame, AsciiReply, AsciiReplyBody, AsciiRequest, Cmd, CommNo};
use super::{CR, MAX_FRAME, START, STOP, SUM_MARK, WILDCARD};
use crate::toshiba::{prefix_hint, ErrorCode, ERROR_LETTER};

/// A parse failure with what a drive answers to it.
pub(crate) struct Fault {
    pub(crate) error: FrameError,
    /// The error code a drive answers with; `None`: no reply (format error).
    pub(crate) answer: Option<ErrorCode>,
}

impl Fault {
    const fn format(error: FrameError) -> Self {
        Fault { error, answer: None }
    }
    const fn answered(error: FrameError, code: ErrorCode) -> Self {
        Fault { error, answer: Some(code) }
    }
}

/// The frame cut into its parts, structure checked.
struct Lexed<'a> {
    inv_no: AsciiAddress,
    letter: u8,
    /// After CMD up to `&` or `)`.
    rest: &'a [u8],
    /// Offset of `rest` in the frame.
    rest_at: usize,
    /// Offset of `&`, if present.
    amp: Option<usize>,
    /// Between `(` and `&` or `)`.
    body: &'a [u8],
}

fn lex(bytes: &[u8]) -> Result<Lexed<'_>, Fault> {
    let n = bytes.len();
    let Some(&first) = bytes.first() else {
        return Err(Fault::format(FrameError::Truncated {
            what: "an ASCII-mode frame",
            expected: 8,
            got: 0,
        }));
    };
    if first != START {
        return Err(Fault::format(FrameError::Unknown { field: "start code", value: first as u32 }));
    }
    if n > MAX_FRAME {
        return Err(Fault::format(FrameError::TooLong {
            what: "an ASCII-mode frame",
            max: MAX_FRAME,
            got: n,
        }));
    }
    // manual: the CR terminator is required in ASCII mode.
    if bytes[n - 1] != CR {
        return Err(Fault::format(FrameError::Malformed(
            "format error: the frame does not end with CR (0D)",
        )));
    }
    // protocols.md 1.6, transmission errors: format error (no reply) for "a code other than ')'
    // in the stop-code position".
    if n < 3 || bytes[n - 2] != STOP {
        return Err(Fault::format(FrameError::Malformed(
            "format error: the byte before CR is not the stop code ')'; a drive does not answer",
        )));
    }
    let inner = &bytes[1..n - 2];
    let (body, amp) = match inner.len().checked_sub(3) {
        Some(a) if inner[a] == SUM_MARK => (&inner[..a], Some(a + 1)),
        _ => (inner, None),
    };
    let inv_char = |c: &u8| c.is_ascii_digit() || *c == WILDCARD;
    let (inv_no, cmd_at) = match body.first() {
        None => return Err(Fault::format(FrameError::Malformed("format error: no CMD between '(' and ')'"))),
        Some(c) if inv_char(c) => match body.get(1) {
            Some(d) if inv_char(d) => (AsciiAddress::from_chars(*c, *d), 2),
            // protocols.md 1.6, transmission errors: "one-digit inverter number" is a format error.
            _ => return Err(Fault::format(FrameError::Malformed(
                "format error: one-digit INV-NO (it is two digits 00-99, or none); a drive does not answer",
            ))),
        },
        Some(_) => (AsciiAddress::Omitted, 0),
    };
    let Some(&letter) = body.get(cmd_at) else {
        return Err(Fault::format(FrameError::Malformed("format error: no CMD after INV-NO")));
    };
    Ok(Lexed { inv_no, letter, rest: &body[cmd_at + 1..], rest_at: cmd_at + 2, amp, body })
}

/// Hex digit values; 0x10 marks a byte that is not a hex digit.
pub(super) const HEX: [u8; 256] = {
    let mut t = [0x10u8; 256];
    let mut c = 0;
    while c < 256 {
        if let Some(v) = hex::digit_value(c as u8) {
            t[c] = v;
        }
        c += 1;
    }
    t
};

/// Decodes `digits` (at frame offset `at`) as a hex number.
#[inline]
fn hex_value(digits: &[u8], at: usize) -> Result<u16, FrameError> {
    let mut v = 0u16;
    let mut bad = 0u8;
    for &c in digits {
        let d = HEX[c as usize];
        bad |= d;
        v = v << 4 | (d & 0x0F) as u16;
    }
    if bad & 0x10 != 0 {
        if let Some(i) = digits.iter().position(|&c| HEX[c as usize] & 0x10 != 0) {
            return Err(FrameError::NonHex { byte: digits[i], offset: at + i });
        }
    }
    Ok(v)
}

/// What a reply's header says: INV-NO, and CMD with COMNO (`None`: an `N`/`n` error reply).
type ReplyHeader = (Option<u8>, Option<(Cmd, CommNo)>);

/// INV-NO and CMD with COMNO (`None`: an `N`/`n` error reply) of a reply frame, from its header
/// only: the framing, INV-NO, CMD, COMNO and the number of DATA digits a reply has (1 to 4, or
/// a 4-digit error code). DATA is not decoded and SUM is not checked (the scanner has); `None`
/// when the header is not a reply's, or a DATA digit is no hex digit (a byte changed on a line
/// without SUM: an error, as the parse says, so the attempt is retried as before).
pub(crate) fn reply_header(bytes: &[u8]) -> Option<ReplyHeader> {
    let lx = lex(bytes).ok()?;
    let inv_no = match lx.inv_no {
        AsciiAddress::Omitted => None,
        AsciiAddress::Unit(n) => Some(n),
        AsciiAddress::Wildcard { .. } => return None,
    };
    if lx.rest.iter().fold(0, |marks, &c| marks | HEX[c as usize]) & 0x10 != 0 {
        return None;
    }
    if lx.letter | 0x20 == ERROR_LETTER | 0x20 {
        return (lx.rest.len() == 4).then_some((inv_no, None));
    }
    let (cmd, _) = Cmd::from_letter(lx.letter).filter(|(c, _)| *c != Cmd::G)?;
    // COMNO, then 1 to 4 DATA digits: without DATA it is a read request, not a reply.
    if !(5..=8).contains(&lx.rest.len()) {
        return None;
    }
    let comm_no = CommNo(hex_value(&lx.rest[..4], lx.rest_at).ok()?);
    Some((inv_no, Some((cmd, comm_no))))
}

const MISPLACED_AMP: &str =
    "format error: '&' must be followed by exactly two SUM digits and ')'; a drive does not answer";

pub(crate) fn parse_frame(bytes: &[u8], from: Option<Direction>) -> Result<AsciiFrame, Fault> {
    let lx = lex(bytes)?;
    // A '&' anywhere but before the two SUM digits fails a check below (it is no INV-NO
    // digit, no command, no hex digit): it is a format error, whatever that check said.
    parse_lexed(bytes, &lx, from).map_err(|f| {
        if lx.body.contains(&SUM_MARK) {
            Fault::format(FrameError::Malformed(MISPLACED_AMP))
        } else {
            f
        }
    })
}

#[inline]
fn parse_lexed(bytes: &[u8], lx: &Lexed<'_>, from: Option<Direction>) -> Result<AsciiFrame, Fault> {
    let kind = Cmd::from_letter(lx.letter).filter(|(c, _)| *c != Cmd::G);
    // protocols.md 1.6, transmission errors: "(R11)CR" takes "11)" and CR as the communication
    // number: a format error.
    if kind.is_some() && lx.rest.len() < 4 {
        return Err(Fault::format(FrameError::Malformed(
            "format error: COMNO needs 4 hex digits before ')'; a drive reads ')' and CR as digits and does not answer",
        )));
    }
    // manual: SUM = the sum of the bytes from the start code through '&', last two hex digits.
    if let Some(amp) = lx.amp {
        let covered = &bytes[..=amp];
        let (hi, lo) = (bytes[amp + 1], bytes[amp + 2]);
        let (h, l) = (HEX[hi as usize], HEX[lo as usize]);
        if (h | l) & 0x10 != 0 {
            let (byte, offset) = if h & 0x10 == 0 { (lo, amp + 2) } else { (hi, amp + 1) };
            return Err(Fault::answered(FrameError::NonHex { byte, offset }, ErrorCode::CHECKSUM_ERROR));
        }
        let carried = h << 4 | l;
        let mut computed = 0u8;
        for &b in covered {
            computed = computed.wrapping_add(b);
        }
        if carried != computed {
            return Err(Fault::answered(
                FrameError::ChecksumMismatch {
                    kind: ChecksumKind::Sum,
                    carried: carried as u16,
                    computed: computed as u16,
                    hint: prefix_hint(covered, carried),
                },
                ErrorCode::CHECKSUM_ERROR,
            ));
        }
    }
    let sum = lx.amp.is_some();
    let reply_inv = |inv_no: AsciiAddress| match inv_no {
        AsciiAddress::Omitted => Ok(None),
        AsciiAddress::Unit(n) => Ok(Some(n)),
        AsciiAddress::Wildcard { .. } => Err(Fault::format(FrameError::Malformed(
            "a reply carries the inverter's own number, never a wildcard '*'",
        ))),
    };
    let Some((cmd, tripped)) = kind else {
        if lx.letter == ERROR_LETTER || lx.letter == ERROR_LETTER | 0x20 {
            if lx.rest.len() != 4 {
                return Err(Fault::format(FrameError::Malformed(
                    "an error reply carries a 4-digit error code",
                )));
            }
            let code = hex_value(lx.rest, lx.rest_at).map_err(Fault::format)?;
            return Ok(AsciiFrame::Reply(AsciiReply {
                inv_no: reply_inv(lx.inv_no)?,
                tripped: lx.letter != ERROR_LETTER,
                body: AsciiReplyBody::Error(ErrorCode(code)),
                sum,
            }));
        }
        // protocols.md 1.6, transmission errors: command error 0003, answered in ASCII mode.
        return Err(Fault::answered(
            FrameError::Unknown { field: "ASCII-mode CMD", value: lx.letter as u32 },
            ErrorCode::COMMAND_ERROR,
        ));
    };
    let comm_no = CommNo(
        hex_value(&lx.rest[..4], lx.rest_at).map_err(|e| Fault::answered(e, ErrorCode::COMM_NO_ERROR))?,
    );
    let digits = &lx.rest[4..];
    if digits.len() > 4 {
        // protocols.md 1.6, transmission errors: data error "too many digits".
        return Err(Fault::answered(
            FrameError::OutOfRange {
                field: "number of DATA digits",
                value: digits.len() as u32,
                min: 0,
                max: 4,
            },
            ErrorCode::DATA_ERROR,
        ));
    }
    let data = hex_value(digits, lx.rest_at + 4).map_err(|e| Fault::answered(e, ErrorCode::DATA_ERROR))?;
    if digits.is_empty() && tripped {
        // Lower case is a tripped drive's reply, which carries DATA; this is neither a reply
        // nor a request, and a drive does not answer it.
        return Err(Fault::format(FrameError::Malformed("a reply (lower-case CMD) carries 4 DATA digits")));
    }
    if digits.is_empty() && cmd.is_write() {
        return Err(Fault::answered(
            FrameError::Malformed("data error: W and P carry 1 to 4 DATA digits, this one has none"),
            ErrorCode::DATA_ERROR,
        ));
    }
    let is_reply = tripped
        || match cmd {
            Cmd::R => !digits.is_empty(),
            _ => from == Some(Direction::Drive),
        };
    if is_reply {
        Ok(AsciiFrame::Reply(AsciiReply {
            inv_no: reply_inv(lx.inv_no)?,
            tripped,
            body: AsciiReplyBody::Data { cmd, comm_no, data },
            sum,
        }))
    } else {
        let data = if digits.is_empty() {
            None
        } else {
            Some(AsciiData { value: data, digits: digits.len() as u8 })
        };
        Ok(AsciiFrame::Request(AsciiRequest { inv_no: lx.inv_no, cmd, comm_no, data, sum }))
    }
}

/// What a drive answers to a request frame it rejected: the error code and the INV-NO and
/// SUM form of the reply; `None` when it stays silent (format errors, frames that are replies,
/// frames that parse).
pub(super) fn rejection(bytes: &[u8]) -> Option<(AsciiAddress, bool, ErrorCode)> {
    match parse_frame(bytes, Some(Direction::Master)) {
        Err(Fault { answer: Some(code), .. }) => {
            let lx = lex(bytes).ok()?;
            Some((lx.inv_no, lx.amp.is_some(), code))
        }
        _ => None,
    }
}

/// The error reply inverter `me` sends to a request frame it rejected (a bad SUM, an unknown
/// command, a bad COMNO or DATA), or `None` when it stays silent (format errors, frames for
/// others are the caller's business: see [`TipAscii`](super::TipAscii)'s `rejected_disposition`).
pub fn rejection_reply(bytes: &[u8], me: u8, tripped: bool) -> Option<AsciiReply> {
    let (inv_no, sum, code) = rejection(bytes)?;
    let inv_no = match inv_no {
        AsciiAddress::Omitted => None,
        AsciiAddress::Unit(n) => Some(n),
        AsciiAddress::Wildcard { .. } => Some(me),
    };
    Some(AsciiReply { inv_no, tripped, body: AsciiReplyBody::Error(code), sum })
}
