//! Reading a binary-mode frame, and the error reply a drive owes one it cannot accept.

use crate::checksum::sum8;
use crate::describe::Direction;
use crate::error::{ChecksumKind, FrameError};

use super::scan::{head, shape, Head, Shape};
use super::{
    BinaryAddress, BinaryFrame, BinaryReply, BinaryReplyBody, BinaryRequest, BinaryRequestBody, BlockReply,
    BlockRequest, Cmd, CommNo, Expect,
};
use super::{BLOCK, BLOCK_REPLY, BROADCAST, START};
use crate::toshiba::{prefix_hint, ErrorCode, ERROR_LETTER};

fn frame_name(cmd: u8) -> &'static str {
    match cmd {
        b'R' | b'r' => "an R frame",
        b'W' | b'w' => "a W frame",
        b'P' | b'p' => "a P frame",
        b'G' | b'g' => "a G frame",
        BLOCK => "an X (block) request",
        b'Y' | b'y' => "a Y (block) reply",
        _ => "an error reply",
    }
}

/// A parse failure with what a drive answers to it.
pub(super) struct Fault {
    pub(super) error: FrameError,
    answer: Option<ErrorCode>,
}

impl From<FrameError> for Fault {
    fn from(error: FrameError) -> Self {
        Fault { error, answer: None }
    }
}

fn word(bytes: &[u8], at: usize) -> u16 {
    match bytes.get(at..at + 2) {
        Some(&[h, l]) => u16::from_be_bytes([h, l]),
        _ => 0,
    }
}

/// The head of a whole frame, its length, and whether it goes to a drive (a request): the
/// start code, CMD and the length CMD gives checked; of what follows CMD only the group count
/// of X and Y is read. Inlined: it is the parse's hot path.
#[inline(always)]
fn layout(bytes: &[u8], from: Option<Direction>) -> Result<(Head, usize, bool), FrameError> {
    let n = bytes.len();
    let Some(&first) = bytes.first() else {
        return Err(FrameError::Truncated { what: "a binary-mode frame", expected: 5, got: 0 });
    };
    if first != START {
        return Err(FrameError::Unknown { field: "start code", value: first as u32 });
    }
    let truncated = |expected| FrameError::Truncated { what: "a binary-mode frame", expected, got: n };
    let Some(h) = head(bytes) else { return Err(truncated(5)) };
    let Some(shape) = shape(bytes, &h)? else { return Err(truncated(h.base + 3)) };
    let what = frame_name(h.cmd);
    let (len, to_drive) = match shape {
        Shape::Fixed(len) => {
            let to_drive = match h.cmd {
                BLOCK => true,
                b'W' | b'P' | b'G' => from != Some(Direction::Drive),
                _ => false,
            };
            (len, to_drive)
        }
        Shape::Read { request, .. } if n <= request => (request, true),
        Shape::Read { reply, .. } => (reply, false),
    };
    if n < len {
        return Err(FrameError::Truncated { what, expected: len, got: n });
    }
    if n > len {
        return Err(FrameError::TooLong { what, max: len, got: n });
    }
    Ok((h, len, to_drive))
}

/// What a reply with head `h` is, by its CMD and COMNO: `None` for an error reply.
#[inline(always)]
fn reply_kind(bytes: &[u8], h: &Head) -> Result<Option<Expect>, FrameError> {
    Ok(match h.cmd & !0x20 {
        ERROR_LETTER => None,
        BLOCK_REPLY => Some(Expect::Block),
        letter => match Cmd::from_letter(letter) {
            Some((cmd, _)) => Some(Expect::Data { cmd, comm_no: CommNo(word(bytes, h.base)) }),
            None => return Err(FrameError::Unknown { field: "binary-mode CMD", value: h.cmd as u32 }),
        },
    })
}

/// The INV-NO and the kind of a reply frame (`None`: an error reply), from its header only:
/// the start code, INV-NO, CMD, COMNO and the length CMD gives. DATA is not read and SUM not
/// checked (the scanner has); `None` when the header is not a reply's.
pub(super) fn reply_header(bytes: &[u8]) -> Option<(Option<u8>, Option<Expect>)> {
    let (h, _, to_drive) = layout(bytes, Some(Direction::Drive)).ok()?;
    match h.inv {
        Some(BROADCAST) => None,
        _ if to_drive => None,
        inv_no => Some((inv_no, reply_kind(bytes, &h).ok()?)),
    }
}

pub(super) fn parse_frame(bytes: &[u8], from: Option<Direction>) -> Result<BinaryFrame, Fault> {
    let (h, len, to_drive) = layout(bytes, from)?;
    let covered = &bytes[..len - 1];
    let carried = bytes[len - 1];
    let computed = sum8(covered);
    if carried != computed {
        return Err(Fault {
            error: FrameError::ChecksumMismatch {
                kind: ChecksumKind::Sum,
                carried: carried as u16,
                computed: computed as u16,
                hint: prefix_hint(covered, carried),
            },
            // protocols.md 1.6, transmission errors: a checksum error is answered with 0004 (2F 4E 00 04 81).
            answer: to_drive.then_some(ErrorCode::CHECKSUM_ERROR),
        });
    }
    let b = h.base;
    if to_drive {
        let inv_no = BinaryAddress::from_byte(h.inv);
        let comm_no = CommNo(word(bytes, b));
        let body = match h.cmd {
            b'R' => BinaryRequestBody::Read { comm_no },
            b'W' => BinaryRequestBody::Write { comm_no, data: word(bytes, b + 2) },
            b'P' => BinaryRequestBody::WriteRam { comm_no, data: word(bytes, b + 2) },
            b'G' => BinaryRequestBody::ReadDummy { comm_no, dummy: word(bytes, b + 2) },
            _ => {
                let n_w = bytes.get(b).copied().unwrap_or(0);
                let n_r = bytes.get(b + 1).copied().unwrap_or(0);
                let mut wdata = [0u16; 2];
                for (i, slot) in wdata.iter_mut().enumerate().take(n_w as usize) {
                    *slot = word(bytes, b + 2 + 2 * i);
                }
                BinaryRequestBody::Block(BlockRequest { n_w, n_r, wdata })
            }
        };
        return Ok(BinaryFrame::Request(BinaryRequest { inv_no, body }));
    }
    let inv_no = match h.inv {
        Some(BROADCAST) => {
            return Err(FrameError::Malformed(
                "a reply carries the inverter's own number, never the broadcast FF",
            )
            .into())
        }
        inv => inv,
    };
    let tripped = h.cmd & 0x20 != 0;
    let body = match reply_kind(bytes, &h)? {
        None => BinaryReplyBody::Error(ErrorCode(word(bytes, b))),
        Some(Expect::Block) => {
            let n_r = bytes.get(b).copied().unwrap_or(0);
            let mut rdata = [0u16; 5];
            for (i, slot) in rdata.iter_mut().enumerate().take(n_r as usize) {
                *slot = word(bytes, b + 1 + 2 * i);
            }
            BinaryReplyBody::Block(BlockReply { n_r, rdata })
        }
        Some(Expect::Data { cmd, comm_no }) => {
            BinaryReplyBody::Data { cmd, comm_no, data: word(bytes, b + 2) }
        }
    };
    Ok(BinaryFrame::Reply(BinaryReply { inv_no, tripped, body }))
}

/// What a drive answers to a request frame it rejected; `None`: silence.
pub(super) fn rejection(bytes: &[u8]) -> Option<(BinaryAddress, ErrorCode)> {
    match parse_frame(bytes, Some(Direction::Master)) {
        Err(Fault { answer: Some(code), .. }) => {
            let h = head(bytes)?;
            Some((BinaryAddress::from_byte(h.inv), code))
        }
        _ => None,
    }
}

/// The error reply inverter `me` sends to a request frame it rejected: only a checksum error
/// is answered in binary mode (`2F 4E 00 04 81`); command and format errors get `None`.
pub fn rejection_reply(bytes: &[u8], me: u8, tripped: bool) -> Option<BinaryReply> {
    let (inv_no, code) = rejection(bytes)?;
    let inv_no = match inv_no {
        BinaryAddress::Omitted => None,
        BinaryAddress::Unit(n) => Some(n),
        BinaryAddress::Broadcast => Some(me),
    };
    Some(BinaryReply { inv_no, tripped, body: BinaryReplyBody::Error(code) })
}
