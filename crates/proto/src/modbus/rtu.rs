//! Modbus RTU: address, PDU and CRC-16 (low byte first), frames delimited by silence.
//!
//! seed 002: "MODBUS-RTU sends and receives binary data without a frame-synchronizing start
//! code and defines the blank time to recognize the start of a frame ... after a blank time for
//! 3.5 bytes". seed 004 asks for "保持无输入信号大于等于 10ms" (at least 10 ms without input)
//! before and after a frame instead; drivebus keeps t3.5 ([`timing`]) and offers
//! [`timing_generic_vfd`] for drives that need the 10 ms.
//!
//! A byte stream has no silence in it, so [`RtuScanner`] predicts a frame's length from its
//! function code (and byte count, or the object list of a 2B/0E reply) and lets the CRC decide.
//! A request and a reply of the same function differ in length, so the scanner is told which
//! direction it hears; a line monitor hears both and tries both lengths ([`Accept::Either`]).
//! When the caller does see t3.5 of silence it calls [`crate::Deframer::silence`]: the bytes
//! held are then the whole frame, whatever their length.

use core::time::Duration;

use super::pdu::{self, PduLen, ReplyPdu, RequestPdu};
use super::{parse_either, Frame, Pending, Reply, Request, UnitId};
use crate::checksum::{crc16_modbus, crc16_modbus_one_byte, crc16_modbus_rewind, crc16_modbus_update};
use crate::codec::Codec;
use crate::deframe::{Scan, Scanner};
use crate::describe::Direction;
use crate::error::{ChecksumKind, EmitError, FrameError, MismatchHint};
use crate::line::{modbus_t15_t35, CharFormat};
use crate::session::{Disposition, Protocol, Timing};

/// The longest RTU frame: 256 bytes (address, 253 PDU bytes, CRC).
pub const MAX_ADU: usize = 256;

/// The shortest RTU frame: address, function code, CRC.
pub const MIN_ADU: usize = 4;

const WHAT_FRAME: &str = "Modbus RTU frame";

/// Which frames a scanner looks for.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Accept {
    /// Requests only (a slave).
    Requests,
    /// Replies only (a master).
    Replies,
    /// Both (a line monitor): the request length and the reply length are tried, shorter
    /// first, and the CRC decides.
    #[default]
    Either,
}

/// The RTU deframer's scanner.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct RtuScanner {
    accept: Accept,
}

impl RtuScanner {
    /// A scanner for `accept`.
    pub const fn new(accept: Accept) -> Self {
        RtuScanner { accept }
    }
    /// A scanner for requests (a slave).
    pub const fn requests() -> Self {
        Self::new(Accept::Requests)
    }
    /// A scanner for replies (a master).
    pub const fn replies() -> Self {
        Self::new(Accept::Replies)
    }
    /// A scanner for both (a line monitor).
    pub const fn either() -> Self {
        Self::new(Accept::Either)
    }
    /// What it looks for.
    pub const fn accept(&self) -> Accept {
        self.accept
    }
}

/// The ADU length of a frame starting at `buf` (at least 2 bytes) read as a request or a reply.
#[inline(always)]
fn adu_len(buf: &[u8], request: bool) -> PduLen {
    let fc = buf[1];
    let at = |i: usize| buf.get(1 + i).copied();
    let len = if request { pdu::request_len(fc, at) } else { pdu::reply_len(fc, at) };
    match len {
        PduLen::Known(n) => PduLen::Known(n + 3),
        PduLen::NeedMore(n) => PduLen::NeedMore(n + 1),
        PduLen::Unknown => PduLen::Unknown,
    }
}

/// True when the last two bytes of `frame` are the CRC of the rest.
#[inline(always)]
pub fn crc_ok(frame: &[u8]) -> bool {
    match frame.len().checked_sub(2) {
        Some(n) if n >= 2 => crc16_modbus(&frame[..n]).to_le_bytes() == [frame[n], frame[n + 1]],
        _ => false,
    }
}

/// Appends the CRC to the `len` bytes of `out`; returns the frame length.
fn put_crc(out: &mut [u8], len: usize) -> Result<usize, EmitError> {
    crate::error::need(out, len + 2)?;
    let crc = crc16_modbus(&out[..len]).to_le_bytes();
    out[len..len + 2].copy_from_slice(&crc);
    Ok(len + 2)
}

impl Scanner for RtuScanner {
    type Buffer = [u8; MAX_ADU];

    #[inline]
    fn scan(&self, buf: &[u8], _checked: usize) -> Scan {
        if buf.len() < 2 {
            return Scan::Incomplete { checked: 0 };
        }
        match self.accept {
            Accept::Requests => scan_one(buf, adu_len(buf, true), true),
            Accept::Replies => scan_one(buf, adu_len(buf, false), false),
            Accept::Either => scan_either(buf),
        }
    }

    /// The caller saw t3.5 of silence: `buf` is the whole frame. It is accepted when the CRC
    /// over all but its last two bytes matches them; otherwise the error says what is wrong
    /// (short by how many bytes, and whose CRC the last two bytes are).
    fn silence(&self, buf: &[u8]) -> Scan {
        if buf.len() > MAX_ADU {
            let error = FrameError::TooLong { what: WHAT_FRAME, max: MAX_ADU, got: buf.len() };
            return Scan::Invalid { len: buf.len(), skip: buf.len(), error };
        }
        if crc_ok(buf) {
            return Scan::Frame { len: buf.len() };
        }
        Scan::Invalid { len: buf.len(), skip: buf.len(), error: self.diagnose(buf) }
    }

    fn truncated(&self, buf: &[u8]) -> FrameError {
        self.diagnose(buf)
    }
}

#[inline(always)]
fn scan_one(buf: &[u8], len: PduLen, request: bool) -> Scan {
    match len {
        PduLen::Known(n) if n > MAX_ADU => too_long(buf, n),
        PduLen::Known(n) => match buf.get(..n) {
            None => Scan::Incomplete { checked: 0 },
            Some(frame) if crc_ok(frame) => Scan::Frame { len: n },
            Some(frame) => Scan::Invalid { len: n, skip: 1, error: mismatch(frame) },
        },
        PduLen::NeedMore(_) => Scan::Incomplete { checked: 0 },
        PduLen::Unknown => unknown_function(buf, request),
    }
}

fn too_long(buf: &[u8], n: usize) -> Scan {
    Scan::Invalid {
        len: buf.len().min(3),
        skip: 1,
        error: FrameError::TooLong { what: WHAT_FRAME, max: MAX_ADU, got: n },
    }
}

fn unknown_function(buf: &[u8], request: bool) -> Scan {
    Scan::Invalid { len: 2, skip: 1, error: unknown_function_error(buf, request) }
}

fn unknown_function_error(buf: &[u8], request: bool) -> FrameError {
    let fc = buf[1];
    match fc {
        pdu::function::ENCAPSULATED_INTERFACE => {
            FrameError::Unknown { field: "MEI type", value: buf.get(2).copied().unwrap_or(0) as u32 }
        }
        0x80..=0xFF if request => FrameError::Malformed(
            "a function code with the 0x80 bit set is an exception reply, not a request",
        ),
        _ => FrameError::Unknown { field: "function code", value: fc as u32 },
    }
}

/// A line monitor: the request reading and the reply reading, shorter first.
#[inline]
fn scan_either(buf: &[u8]) -> Scan {
    let q = adu_len(buf, true);
    let r = adu_len(buf, false);
    let usable = |l: PduLen| match l {
        PduLen::Known(n) if n <= MAX_ADU => Some(n),
        _ => None,
    };
    let (qn, rn) = (usable(q), usable(r));
    // Try the lengths that are in the buffer, shorter first.
    let (first, second) = match (qn, rn) {
        (Some(a), Some(b)) if b < a => (Some(b), Some(a)),
        (Some(a), Some(b)) if a == b => (Some(a), None),
        (a, b) => (a.or(b), if a.is_some() { b } else { None }),
    };
    let mut waiting = matches!(q, PduLen::NeedMore(_)) || matches!(r, PduLen::NeedMore(_));
    for n in [first, second].into_iter().flatten() {
        match buf.get(..n) {
            Some(frame) if crc_ok(frame) => return Scan::Frame { len: n },
            Some(_) => {}
            None => waiting = true,
        }
    }
    if waiting {
        return Scan::Incomplete { checked: 0 };
    }
    // Every reading failed: report the request reading where there is one.
    match (qn, rn) {
        (Some(n), _) | (None, Some(n)) => Scan::Invalid { len: n, skip: 1, error: mismatch(&buf[..n]) },
        (None, None) => match (q, r) {
            (PduLen::Known(n), _) | (_, PduLen::Known(n)) => too_long(buf, n),
            _ => unknown_function(buf, buf[1] & 0x80 == 0),
        },
    }
}

/// The error for a frame whose CRC does not match, with a hint where the carried CRC is
/// that of a prefix of the frame or of the same frame sent to another address.
pub fn mismatch(frame: &[u8]) -> FrameError {
    let n = frame.len().saturating_sub(2);
    let body = &frame[..n];
    let carried = match frame.get(n..) {
        Some(&[lo, hi]) => u16::from_le_bytes([lo, hi]),
        _ => 0,
    };
    let computed = crc16_modbus(body);
    FrameError::ChecksumMismatch {
        kind: ChecksumKind::Crc16,
        carried,
        computed,
        hint: mismatch_hint(body, carried),
    }
}

/// Whose CRC `carried` is: the first `k < body.len()` bytes of `body`, or `body` with another
/// first byte (address). Both searches are O(len): a running CRC, and the CRC run backwards.
pub fn mismatch_hint(body: &[u8], carried: u16) -> Option<MismatchHint> {
    if let Some(k) = prefix_match(body, carried) {
        return Some(MismatchHint::PrefixOnly { len: k.min(u8::MAX as usize) as u8 });
    }
    let (&first, rest) = body.split_first()?;
    // The CRC register after the address byte that would end in `carried` over the rest.
    let state = crc16_modbus_rewind(carried, rest);
    let address = crc16_modbus_one_byte(state)?;
    (address != first).then_some(MismatchHint::OtherAddress { address })
}

/// The shortest `k` in `1..body.len()` such that the CRC of `body[..k]` is `carried`.
fn prefix_match(body: &[u8], carried: u16) -> Option<usize> {
    let mut crc = 0xFFFF;
    for (i, &b) in body.iter().enumerate().take(body.len().saturating_sub(1)) {
        crc = crc16_modbus_update(crc, &[b]);
        if crc == carried {
            return Some(i + 1);
        }
    }
    None
}

/// "03 request, whose CRC is that of its first 4 bytes only," for truncated-frame messages.
macro_rules! prefix_whats {
    ($name:literal) => {
        [
            concat!($name, ", whose CRC is that of its first byte only,"),
            concat!($name, ", whose CRC is that of its first 2 bytes only,"),
            concat!($name, ", whose CRC is that of its first 3 bytes only,"),
            concat!($name, ", whose CRC is that of its first 4 bytes only,"),
            concat!($name, ", whose CRC is that of its first 5 bytes only,"),
            concat!($name, ", whose CRC is that of its first 6 bytes only,"),
            concat!($name, ", whose CRC is that of its first 7 bytes only,"),
            concat!($name, ", whose CRC is that of its first 8 bytes only,"),
        ]
    };
}

const PREFIX_FUNCTIONS: [u8; 6] = [0x03, 0x04, 0x06, 0x08, 0x10, 0x2B];
const PREFIX_REQUEST: [[&str; 8]; 6] = [
    prefix_whats!("03 request"),
    prefix_whats!("04 request"),
    prefix_whats!("06 request"),
    prefix_whats!("08 request"),
    prefix_whats!("10 request"),
    prefix_whats!("2B/0E request"),
];
const PREFIX_REPLY: [[&str; 8]; 6] = [
    prefix_whats!("03 reply"),
    prefix_whats!("04 reply"),
    prefix_whats!("06 reply"),
    prefix_whats!("08 reply"),
    prefix_whats!("10 reply"),
    prefix_whats!("2B/0E reply"),
];
const PREFIX_ANY: [&str; 8] = prefix_whats!("the frame");

fn prefix_what(fc: u8, request: bool, k: usize) -> Option<&'static str> {
    let k = k.checked_sub(1).filter(|&k| k < 8)?;
    Some(match PREFIX_FUNCTIONS.iter().position(|&f| f == fc) {
        Some(i) if request => PREFIX_REQUEST[i][k],
        Some(i) => PREFIX_REPLY[i][k],
        None => PREFIX_ANY[k],
    })
}

impl RtuScanner {
    /// What is wrong with `buf` taken as a whole frame whose CRC does not match.
    fn diagnose(&self, buf: &[u8]) -> FrameError {
        let got = buf.len();
        if got < 2 {
            return FrameError::Truncated { what: WHAT_FRAME, expected: MIN_ADU, got };
        }
        let fc = buf[1];
        let q = adu_len(buf, true);
        let r = adu_len(buf, false);
        // The reading to explain: the direction set, or for a monitor the one as long as the
        // frame, else the one that still needed more bytes, the request first.
        let whole = |l: PduLen| l == PduLen::Known(got);
        let short = |l: PduLen| match l {
            PduLen::Known(n) if n > got && n <= MAX_ADU => Some(n),
            PduLen::NeedMore(n) if n > got => Some(n),
            _ => None,
        };
        let reading = match self.accept {
            Accept::Requests => Some((true, q)),
            Accept::Replies => Some((false, r)),
            Accept::Either => match (short(q), short(r)) {
                _ if whole(q) => Some((true, q)),
                _ if whole(r) => Some((false, r)),
                (Some(_), _) => Some((true, q)),
                (None, Some(_)) => Some((false, r)),
                _ if q != PduLen::Unknown => Some((true, q)),
                _ if r != PduLen::Unknown => Some((false, r)),
                _ => None,
            },
        };
        let Some((request, len)) = reading else {
            return unknown_function_error(buf, fc & 0x80 == 0);
        };
        let what = if request { pdu::request_what(fc) } else { pdu::reply_what(fc) };
        let expected = match len {
            PduLen::Known(n) if n > MAX_ADU => {
                return FrameError::TooLong { what: WHAT_FRAME, max: MAX_ADU, got: n };
            }
            PduLen::Known(n) | PduLen::NeedMore(n) => n.max(MIN_ADU),
            PduLen::Unknown => return unknown_function_error(buf, request),
        };
        if got < MIN_ADU {
            return FrameError::Truncated { what, expected, got };
        }
        if got >= expected {
            // As long as a frame should be (or longer) and the CRC fails.
            return mismatch(buf);
        }
        // Short: say so, and whose CRC the last two bytes are if they belong to a prefix.
        let carried = u16::from_le_bytes([buf[got - 2], buf[got - 1]]);
        let what =
            prefix_match(&buf[..got - 2], carried).and_then(|k| prefix_what(fc, request, k)).unwrap_or(what);
        FrameError::Truncated { what, expected, got }
    }
}

fn split(frame: &[u8]) -> Result<(UnitId, &[u8]), FrameError> {
    if frame.len() < MIN_ADU {
        return Err(FrameError::Truncated { what: WHAT_FRAME, expected: MIN_ADU, got: frame.len() });
    }
    Ok((UnitId(frame[0]), &frame[1..frame.len() - 2]))
}

fn check(frame: &[u8]) -> Result<(), FrameError> {
    if frame.len() < MIN_ADU {
        return Err(FrameError::Truncated { what: WHAT_FRAME, expected: MIN_ADU, got: frame.len() });
    }
    if frame.len() > MAX_ADU {
        return Err(FrameError::TooLong { what: WHAT_FRAME, max: MAX_ADU, got: frame.len() });
    }
    if !crc_ok(frame) {
        return Err(mismatch(frame));
    }
    Ok(())
}

/// The RTU frame methods of a request and of a reply: the same but for the PDU type.
macro_rules! rtu_frame {
    ($adu:ident, $pdu:ident, $what:literal) => {
        impl<'a> $adu<'a> {
            #[doc = concat!("Parses an RTU ", $what, " frame, CRC included, and checks the CRC.")]
            pub fn parse_rtu(frame: &'a [u8]) -> Result<Self, FrameError> {
                check(frame)?;
                Self::parse_rtu_unchecked(frame)
            }

            #[doc = concat!("Parses an RTU ", $what, " frame whose CRC has been checked (by [`RtuScanner`]).")]
            #[inline]
            pub fn parse_rtu_unchecked(frame: &'a [u8]) -> Result<Self, FrameError> {
                let (unit, pdu) = split(frame)?;
                Ok($adu { unit, pdu: $pdu::parse(pdu).map_err(|e| super::adu_error(e, 3))? })
            }

            /// Writes the RTU frame (address, PDU, CRC) into `out`; returns its length.
            pub fn emit_rtu(&self, out: &mut [u8]) -> Result<usize, EmitError> {
                crate::error::need(out, self.pdu.wire_len() + 3)?;
                out[0] = self.unit.0;
                let n = self.pdu.emit(&mut out[1..])?;
                put_crc(out, 1 + n)
            }
        }
    };
}

rtu_frame!(Request, RequestPdu, "request");
rtu_frame!(Reply, ReplyPdu, "reply");

/// Modbus RTU for the sessions and the tools (`Protocol` and `Codec`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct ModbusRtu;

modbus_protocol!(
    ModbusRtu,
    RtuScanner,
    replies: RtuScanner::replies(),
    requests: RtuScanner::requests(),
    emit_rtu,
    parse_rtu_unchecked
);

impl ModbusRtu {
    /// Whether the reply frame `bytes` answers `pending`, by its header only (unit, function or
    /// its exception): whoever uses the reply parses it, once.
    pub fn answers(&self, pending: &Pending, bytes: &[u8]) -> Result<bool, FrameError> {
        match bytes {
            [unit, function, _, _, _, ..] => Ok(pending.matches_header(*unit, *function)),
            _ => Err(FrameError::Truncated { what: "Modbus RTU reply", expected: 5, got: bytes.len() }),
        }
    }

    /// How drive `me` treats a frame that did not parse. A frame with a bad CRC is dropped
    /// without a word (seed 004: "如果两值不同则接收消息有错误丢弃该消息帧,并不作任何回应": if the
    /// two values differ the message is in error, the frame is discarded and nothing is
    /// answered). A frame with a good CRC that does not parse (quantity 0, unknown function) is
    /// the addressee's to answer with an exception ([`pdu::ExceptionCode::for_error`]); nobody
    /// answers a broadcast.
    pub fn rejected(&self, bytes: &[u8], me: u8) -> Disposition {
        if bytes.len() >= MIN_ADU && bytes.len() <= MAX_ADU && crc_ok(bytes) {
            super::disposition(bytes[0], me)
        } else {
            Disposition::NotMine
        }
    }
}

impl Codec for ModbusRtu {
    const NAME: &'static str = "modbus-rtu";
    type Scanner = RtuScanner;
    type Frame<'a> = Frame<'a>;

    fn scanner(from: Option<Direction>) -> RtuScanner {
        match from {
            Some(Direction::Master) => RtuScanner::requests(),
            Some(Direction::Drive) => RtuScanner::replies(),
            None => RtuScanner::either(),
        }
    }

    fn parse(bytes: &[u8], from: Option<Direction>) -> Result<Frame<'_>, FrameError> {
        parse_either(
            from,
            || Request::parse_rtu_unchecked(bytes),
            || Reply::parse_rtu_unchecked(bytes),
            bytes.get(1).copied(),
        )
    }
}

/// The master's times for Modbus RTU at `baud` and `format`: minimum gap t3.5
/// ([`modbus_t15_t35`]: 3.5 characters of 11 bits, 1.75 ms above 19200 baud), response
/// timeout 100 ms, turnaround after a broadcast 100 ms.
pub fn timing(baud: u32, format: CharFormat) -> Timing {
    let (_, t35) = modbus_t15_t35(baud);
    Timing::new(baud, format, Duration::from_millis(100), t35)
}

/// The silence seed 004 asks for between frames: "保持无输入信号大于等于 10ms" (no input
/// for at least 10 ms).
pub const GENERIC_VFD_SILENCE: Duration = Duration::from_millis(10);

/// [`timing`] with the minimum gap at least [`GENERIC_VFD_SILENCE`], for the drive of seed 004.
pub fn timing_generic_vfd(baud: u32, format: CharFormat) -> Timing {
    let mut t = timing(baud, format);
    t.min_gap = t.min_gap.max(GENERIC_VFD_SILENCE);
    t
}
