//! Modbus ASCII: `:` + address, PDU and LRC as hex digits + CR LF, at most 513 characters.
//!
//! seed 004 (the generic VFD's default mode, 7 data bits, 2 stop bits, no parity):
//! "起始字符=“:”(3AH)" start character ':'; address, function and data "由2个ASCII码组合"
//! (two ASCII characters each), "高位在前" (high nibble first); the LRC is "将要发送消息中
//! “从机地址”到“运行数据”没有转换成 ASCII 码的全部字节连续累加, 结果丢弃进位, ... 按位取反,
//! 后再加1" (the sum of the binary bytes from address to data, carry dropped, inverted, plus
//! one). Its end is typed "END Hi = CR(0DH), END Lo = CR(0AH)": 0AH is LF, so the seed's
//! "CR" for END Lo is a typo; drivebus follows the Modbus standard, CR LF (and so do the
//! seed's own examples, which end "CR ----0DH  LF ----0AH").
//!
//! Receiving accepts upper- and lower-case hex digits; sending uses upper case. A byte that
//! is not a hex digit inside a frame ends it; a new `:` restarts a frame (Modbus over Serial
//! Line: "the ':' character ... a receiving device that detects it ... starts a new message").

use core::time::Duration;

use super::pdu::{self, Data, ReplyPdu, RequestPdu};
use super::{parse_either, Frame, Pending, Reply, Request, UnitId};
use crate::checksum::lrc;
use crate::codec::Codec;
use crate::deframe::{Scan, Scanner};
use crate::describe::Direction;
use crate::error::{ChecksumKind, EmitError, FrameError};
use crate::hex;
use crate::line::CharFormat;
use crate::session::{Disposition, Protocol, Timing};

/// The longest ASCII frame: 513 characters (`:` + 2 × (1 + 253 + 1) digits - 2 + CR LF;
/// 1 + 2 + 2 + 2 × 252 + 2 + 2).
pub const MAX_FRAME: usize = 513;

/// The start character.
pub const START: u8 = b':';
/// Carriage return, the first end character.
pub const CR: u8 = 0x0D;
/// Line feed, the second end character.
pub const LF: u8 = 0x0A;

const WHAT_FRAME: &str = "Modbus ASCII frame (address, function code, LRC)";

/// 0..=15 for hex digits, 0xFF for every other byte.
const HEX_VALUE: [u8; 256] = {
    let mut t = [0xFFu8; 256];
    let mut c = 0;
    while c < 256 {
        if let Some(v) = hex::digit_value(c as u8) {
            t[c] = v;
        }
        c += 1;
    }
    t
};

#[inline(always)]
fn is_hex(c: u8) -> bool {
    HEX_VALUE[c as usize] != 0xFF
}

/// The ASCII deframer's scanner (the same for both directions: frames are delimited).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct AsciiScanner;

impl Scanner for AsciiScanner {
    type Buffer = [u8; MAX_FRAME];

    fn scan(&self, buf: &[u8], checked: usize) -> Scan {
        if buf[0] != START {
            // Bytes before a ':' cannot start a frame.
            let n = buf.iter().position(|&b| b == START).unwrap_or(buf.len());
            return Scan::Noise { len: n };
        }
        // Digits end at index 510 at the latest (CR at 511, LF at 512).
        let end = buf.len().min(MAX_FRAME - 2);
        let mut i = checked.max(1);
        while i < end && is_hex(buf[i]) {
            i += 1;
        }
        let Some(&c) = buf.get(i) else {
            return Scan::Incomplete { checked: i };
        };
        match c {
            CR => match buf.get(i + 1) {
                None => Scan::Incomplete { checked: i },
                Some(&LF) => {
                    let len = i + 2;
                    match check_digits(&buf[1..i]) {
                        Ok(()) => Scan::Frame { len },
                        Err(error) => Scan::Invalid { len, skip: len, error },
                    }
                }
                Some(_) => Scan::Invalid {
                    len: i + 1,
                    skip: i + 1,
                    error: FrameError::Malformed(
                        "CR not followed by LF: a Modbus ASCII frame ends with CR LF",
                    ),
                },
            },
            // A 511th digit: no room left for CR LF.
            _ if is_hex(c) => Scan::Invalid {
                len: i + 1,
                skip: i + 1,
                error: FrameError::TooLong { what: "Modbus ASCII frame", max: MAX_FRAME, got: i + 3 },
            },
            // A new ':' restarts a frame: the one before it is cut short.
            START => Scan::Invalid {
                len: i,
                skip: i,
                error: FrameError::Malformed("a new ':' started another frame before this one's CR LF"),
            },
            // "non-hex byte 0x01 at offset 3 ends the frame"
            _ => Scan::Invalid { len: i + 1, skip: i + 1, error: FrameError::NonHex { byte: c, offset: i } },
        }
    }

    fn truncated(&self, buf: &[u8]) -> FrameError {
        FrameError::Malformed(if buf.len() >= 2 && buf[buf.len() - 1] == CR {
            "the stream ended between CR and LF"
        } else {
            "the stream ended before the frame's CR LF"
        })
    }
}

/// Checks the hex digits between ':' and CR (all hex digits already): an even count, at
/// least address, function code and LRC, and the LRC.
#[inline]
fn check_digits(digits: &[u8]) -> Result<(), FrameError> {
    if digits.len() % 2 != 0 {
        return Err(FrameError::OddDigits { count: digits.len() });
    }
    let n = digits.len() / 2;
    if n < 3 {
        return Err(FrameError::Truncated { what: WHAT_FRAME, expected: 3, got: n });
    }
    let mut sum = 0u8;
    let mut carried = 0u8;
    for (i, pair) in digits.chunks_exact(2).enumerate() {
        let b = HEX_VALUE[pair[0] as usize] << 4 | (HEX_VALUE[pair[1] as usize] & 0x0F);
        if i + 1 == n {
            carried = b;
        } else {
            sum = sum.wrapping_add(b);
        }
    }
    let computed = sum.wrapping_neg();
    if computed != carried {
        return Err(FrameError::ChecksumMismatch {
            kind: ChecksumKind::Lrc,
            carried: carried as u16,
            computed: computed as u16,
            hint: None,
        });
    }
    Ok(())
}

/// Checks a whole frame (`:` ... CR LF) and returns the unit and the PDU's hex digits.
fn split(frame: &[u8]) -> Result<(UnitId, Data<'_>), FrameError> {
    split_with(frame, true)
}

/// [`split`]; with `check` false, a frame that has the shape of one (`:`, an even count of
/// at least 6 characters, CR LF) is taken as the scanner checked it: digits and LRC.
#[inline]
fn split_with(frame: &[u8], check: bool) -> Result<(UnitId, Data<'_>), FrameError> {
    let n = frame.len();
    if !check && (9..=MAX_FRAME).contains(&n) && n % 2 == 1 && frame[0] == START && frame[n - 2..] == [CR, LF]
    {
        let digits = &frame[1..n - 2];
        let unit = hex::decode_pair(digits[0], digits[1]).unwrap_or(0);
        return Ok((UnitId(unit), Data::hex_digits(&digits[2..digits.len() - 2])));
    }
    if frame.first() != Some(&START) {
        return Err(FrameError::Malformed("a Modbus ASCII frame starts with ':'"));
    }
    if frame.len() > MAX_FRAME {
        return Err(FrameError::TooLong { what: "Modbus ASCII frame", max: MAX_FRAME, got: frame.len() });
    }
    let n = frame.len();
    if n < 3 || frame[n - 2] != CR || frame[n - 1] != LF {
        return Err(FrameError::Malformed("a Modbus ASCII frame ends with CR LF"));
    }
    let digits = &frame[1..n - 2];
    if let Some(i) = digits.iter().position(|&c| !is_hex(c)) {
        return Err(FrameError::NonHex { byte: digits[i], offset: i + 1 });
    }
    check_digits(digits)?;
    let unit = hex::decode_pair(digits[0], digits[1]).unwrap_or(0);
    Ok((UnitId(unit), Data::hex_digits(&digits[2..digits.len() - 2])))
}

/// The ASCII frame methods of a request and of a reply, around each one's `parse_ascii_with`.
macro_rules! ascii_frame {
    ($adu:ident, $what:literal) => {
        impl<'a> $adu<'a> {
            #[doc = concat!("Parses an ASCII ", $what, " frame (`:` ... CR LF), checking digits and LRC.")]
            pub fn parse_ascii(frame: &'a [u8]) -> Result<Self, FrameError> {
                Self::parse_ascii_with(frame, true)
            }

            #[doc = concat!(
                "Parses an ASCII ", $what, " frame whose digits and LRC have been checked (by [`AsciiScanner`])."
            )]
            pub fn parse_ascii_unchecked(frame: &'a [u8]) -> Result<Self, FrameError> {
                Self::parse_ascii_with(frame, false)
            }

            /// Writes the ASCII frame into `out`; returns its length.
            pub fn emit_ascii(&self, out: &mut [u8]) -> Result<usize, EmitError> {
                let mut bin = [0u8; 1 + pdu::MAX_PDU];
                bin[0] = self.unit.0;
                let n = self.pdu.emit(&mut bin[1..])?;
                encode(&bin[..1 + n], out)
            }
        }
    };
}

ascii_frame!(Request, "request");
ascii_frame!(Reply, "reply");

impl<'a> Request<'a> {
    fn parse_ascii_with(frame: &'a [u8], check: bool) -> Result<Self, FrameError> {
        let (unit, pdu) = split_with(frame, check)?;
        match RequestPdu::parse_data(pdu) {
            Ok(pdu) => Ok(Request { unit, pdu }),
            Err(FrameError::Truncated { expected: 5, got: 4, .. })
                if matches!(pdu.get(0), Some(0x03 | 0x04)) && pdu.get(3) == Some(0) =>
            {
                // seed 004's `:0103210400D7`: the quantity's low byte is missing. A missing
                // 00 byte leaves the LRC unchanged, so the LRC fits quantity 0000 only.
                let what = if pdu.get(0) == Some(0x03) {
                    "03 request (the LRC would match quantity 0000, but quantity 0 is not allowed)"
                } else {
                    "04 request (the LRC would match quantity 0000, but quantity 0 is not allowed)"
                };
                Err(FrameError::Truncated { what, expected: 6, got: 5 })
            }
            Err(e) => Err(super::adu_error(e, 1)),
        }
    }
}

impl<'a> Reply<'a> {
    fn parse_ascii_with(frame: &'a [u8], check: bool) -> Result<Self, FrameError> {
        let (unit, pdu) = split_with(frame, check)?;
        Ok(Reply { unit, pdu: ReplyPdu::parse_data(pdu).map_err(|e| super::adu_error(e, 1))? })
    }
}

/// Writes `:` + the hex digits of `bin` and of its LRC + CR LF; returns the length.
pub fn encode(bin: &[u8], out: &mut [u8]) -> Result<usize, EmitError> {
    let len = 1 + 2 * bin.len() + 2 + 2;
    crate::error::at_most("frame length", len as u32, 9, MAX_FRAME as u32)?;
    crate::error::need(out, len)?;
    out[0] = START;
    hex::encode_into(bin, &mut out[1..1 + 2 * bin.len()]);
    let p = 1 + 2 * bin.len();
    out[p..p + 2].copy_from_slice(&hex::byte_digits(lrc(bin)));
    out[p + 2] = CR;
    out[p + 3] = LF;
    Ok(len)
}

/// Modbus ASCII for the sessions and the tools (`Protocol` and `Codec`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct ModbusAscii;

modbus_protocol!(
    ModbusAscii,
    AsciiScanner,
    replies: AsciiScanner,
    requests: AsciiScanner,
    emit_ascii,
    parse_ascii_unchecked
);

impl ModbusAscii {
    /// Whether the reply frame `bytes` answers `pending`, by its header only (`:` then the
    /// unit's and the function's digits): whoever uses the reply parses it, once.
    pub fn answers(&self, pending: &Pending, bytes: &[u8]) -> Result<bool, FrameError> {
        let digits = |at: usize| bytes.get(at..at + 2).and_then(|d| crate::hex::decode_pair(d[0], d[1]));
        match (digits(1), digits(3)) {
            (Some(unit), Some(function)) => Ok(pending.matches_header(unit, function)),
            _ => Reply::parse_ascii_unchecked(bytes).map(|rep| pending.matches(&rep)),
        }
    }

    /// How drive `me` treats a frame that did not parse. A frame with a bad LRC is dropped
    /// without a word (seed 004: "如果校验错误,则丢弃该消息帧,并不作任何回应": if the check fails,
    /// the frame is discarded and nothing is answered). A whole frame with a good LRC that does
    /// not parse is the addressee's to answer with an exception; nobody answers a broadcast.
    pub fn rejected(&self, bytes: &[u8], me: u8) -> Disposition {
        match split(bytes) {
            Ok((unit, _)) => super::disposition(unit.0, me),
            Err(_) => Disposition::NotMine,
        }
    }
}

impl Codec for ModbusAscii {
    const NAME: &'static str = "modbus-ascii";
    type Scanner = AsciiScanner;
    type Frame<'a> = Frame<'a>;

    fn scanner(_from: Option<Direction>) -> AsciiScanner {
        AsciiScanner
    }

    fn parse(bytes: &[u8], from: Option<Direction>) -> Result<Frame<'_>, FrameError> {
        let function = bytes.get(3..5).and_then(|d| hex::decode_pair(d[0], d[1]));
        parse_either(
            from,
            || Request::parse_ascii_unchecked(bytes),
            || Reply::parse_ascii_unchecked(bytes),
            function,
        )
    }
}

/// The master's times for Modbus ASCII at `baud` and `format`: up to 1 s between the
/// characters of a frame (Modbus over Serial Line's default), response timeout 100 ms to
/// the first character, no gap needed between frames beyond one character.
pub fn timing(baud: u32, format: CharFormat) -> Timing {
    let mut t = Timing::new(baud, format, Duration::from_millis(100), format.char_time(baud));
    t.inter_char_timeout = Duration::from_secs(1);
    t
}
