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

use crate::checksum::sum8;
use crate::codec::Codec;
use crate::deframe::{Scan, Scanner};
use crate::describe::{CodeStyle, Command, Describe, Direction, Field, Target};
use crate::error::{need, ChecksumKind, EmitError, FrameError};
use crate::hex;
use crate::session::{Disposition, Protocol};

use super::{describe_value, prefix_hint, Cmd, CommNo, ErrorCode, ERROR_LETTER};

/// Start code `(` (28H).
pub const START: u8 = b'(';
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

/// INV-NO of a request.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum AsciiAddress {
    /// No INV-NO (a 1:1 link): the one inverter on the line acts and answers.
    Omitted,
    /// One inverter, 0–99.
    Unit(u8),
    /// A pattern with `*` digits: every inverter it matches acts; the smallest it can match answers.
    Wildcard {
        /// The tens digit, `None` for `*`.
        tens: Option<u8>,
        /// The units digit, `None` for `*`.
        units: Option<u8>,
    },
}

impl AsciiAddress {
    /// `**`: every inverter.
    pub const ALL: AsciiAddress = AsciiAddress::Wildcard { tens: None, units: None };

    /// True when inverter `me` acts on a request with this INV-NO.
    pub const fn matches(self, me: u8) -> bool {
        match self {
            AsciiAddress::Omitted => true,
            AsciiAddress::Unit(n) => n == me,
            AsciiAddress::Wildcard { tens, units } => {
                me <= 99
                    && match tens {
                        Some(t) => me / 10 == t,
                        None => true,
                    }
                    && match units {
                        Some(u) => me % 10 == u,
                        None => true,
                    }
            }
        }
    }

    /// The INV-NO the reply carries: the number itself, the smallest number a wildcard can
    /// match (each `*` read as 0: `*2` -> 02, `1*` -> 10, `**` -> 00), or none when omitted.
    pub const fn reply_inv_no(self) -> Option<u8> {
        match self {
            AsciiAddress::Omitted => None,
            AsciiAddress::Unit(n) => Some(n),
            AsciiAddress::Wildcard { tens, units } => {
                let t = match tens {
                    Some(t) => t,
                    None => 0,
                };
                let u = match units {
                    Some(u) => u,
                    None => 0,
                };
                Some(t * 10 + u)
            }
        }
    }

    /// How inverter `me` treats a request with this INV-NO.
    pub const fn disposition(self, me: u8) -> Disposition {
        match self {
            AsciiAddress::Omitted => Disposition::Mine,
            AsciiAddress::Unit(n) if n == me => Disposition::Mine,
            AsciiAddress::Unit(_) => Disposition::NotMine,
            AsciiAddress::Wildcard { .. } if self.matches(me) => {
                Disposition::Broadcast { reply: matches!(self.reply_inv_no(), Some(n) if n == me) }
            }
            AsciiAddress::Wildcard { .. } => Disposition::NotMine,
        }
    }

    /// The address for [`Describe`]: `**` is a broadcast.
    pub const fn target(self) -> Target {
        match self {
            AsciiAddress::Omitted => Target::Implicit,
            AsciiAddress::Unit(n) => Target::Unit(n),
            AsciiAddress::Wildcard { tens: None, units: None } => Target::Broadcast,
            AsciiAddress::Wildcard { tens, units } => Target::Wildcard { tens, units },
        }
    }

    /// The two INV-NO characters, or `None` when omitted.
    fn chars(self) -> Result<Option<[u8; 2]>, EmitError> {
        let digit = |d: Option<u8>| match d {
            None => Ok(WILDCARD),
            Some(d) if d <= 9 => Ok(b'0' + d),
            Some(d) => {
                Err(EmitError::OutOfRange { field: "INV-NO wildcard digit", value: d as u32, min: 0, max: 9 })
            }
        };
        match self {
            AsciiAddress::Omitted => Ok(None),
            AsciiAddress::Unit(n) => Ok(Some(unit_chars(n)?)),
            AsciiAddress::Wildcard { tens: Some(_), units: Some(_) } => Err(EmitError::Invalid(
                "a wildcard INV-NO needs at least one '*' digit; use AsciiAddress::Unit",
            )),
            AsciiAddress::Wildcard { tens, units } => Ok(Some([digit(tens)?, digit(units)?])),
        }
    }

    fn from_chars(c: u8, d: u8) -> AsciiAddress {
        let v = |x: u8| if x == WILDCARD { None } else { Some(x - b'0') };
        match (v(c), v(d)) {
            (Some(t), Some(u)) => AsciiAddress::Unit(t * 10 + u),
            (tens, units) => AsciiAddress::Wildcard { tens, units },
        }
    }
}

fn unit_chars(n: u8) -> Result<[u8; 2], EmitError> {
    if n > 99 {
        return Err(EmitError::OutOfRange { field: "INV-NO", value: n as u32, min: 0, max: 99 });
    }
    Ok([b'0' + n / 10, b'0' + n % 10])
}

/// DATA of a request as written: its value and how many hex digits (1–4) carry it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct AsciiData {
    /// The value.
    pub value: u16,
    /// Hex digits on the wire, 1–4.
    pub digits: u8,
}

impl AsciiData {
    /// `value` as 4 digits, the form drivebus sends.
    pub const fn new(value: u16) -> Self {
        AsciiData { value, digits: 4 }
    }
}

/// A request, master to inverter.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct AsciiRequest {
    /// INV-NO.
    pub inv_no: AsciiAddress,
    /// CMD: `R`, `W` or `P` (`G` is binary-mode only).
    pub cmd: Cmd,
    /// COMNO.
    pub comm_no: CommNo,
    /// DATA: none for `R`, 1–4 digits for `W` and `P`.
    pub data: Option<AsciiData>,
    /// Whether `&` and SUM are sent.
    pub sum: bool,
}

impl AsciiRequest {
    /// `R`: read `comm_no`.
    pub const fn read(inv_no: AsciiAddress, comm_no: CommNo) -> Self {
        AsciiRequest { inv_no, cmd: Cmd::R, comm_no, data: None, sum: false }
    }

    /// `W`: write `value` to `comm_no` (RAM and EEPROM).
    pub const fn write(inv_no: AsciiAddress, comm_no: CommNo, value: u16) -> Self {
        AsciiRequest { inv_no, cmd: Cmd::W, comm_no, data: Some(AsciiData::new(value)), sum: false }
    }

    /// `P`: write `value` to `comm_no` (RAM only).
    pub const fn write_ram(inv_no: AsciiAddress, comm_no: CommNo, value: u16) -> Self {
        AsciiRequest { inv_no, cmd: Cmd::P, comm_no, data: Some(AsciiData::new(value)), sum: false }
    }

    /// The same request with `&` and SUM.
    pub const fn with_sum(mut self) -> Self {
        self.sum = true;
        self
    }

    /// The value written by `W`/`P`.
    pub fn value(&self) -> Option<u16> {
        self.data.map(|d| d.value)
    }

    /// The reply of inverter `me` carrying `data` (the value read, or for `W`/`P` the value
    /// written): INV-NO as the request had it (a wildcard answered with `me`), SUM if the
    /// request had one.
    pub fn reply(&self, me: u8, tripped: bool, data: u16) -> AsciiReply {
        AsciiReply {
            inv_no: self.reply_inv_no(me),
            tripped,
            body: AsciiReplyBody::Data { cmd: self.cmd, comm_no: self.comm_no, data },
            sum: self.sum,
        }
    }

    /// The error reply of inverter `me` with `code`.
    pub fn error_reply(&self, me: u8, tripped: bool, code: ErrorCode) -> AsciiReply {
        AsciiReply {
            inv_no: self.reply_inv_no(me),
            tripped,
            body: AsciiReplyBody::Error(code),
            sum: self.sum,
        }
    }

    fn reply_inv_no(&self, me: u8) -> Option<u8> {
        match self.inv_no {
            AsciiAddress::Omitted => None,
            AsciiAddress::Unit(n) => Some(n),
            AsciiAddress::Wildcard { .. } => Some(me),
        }
    }

    /// Reads a whole request frame.
    pub fn parse(bytes: &[u8]) -> Result<Self, FrameError> {
        match parse_frame(bytes, Some(Direction::Master)).map_err(|f| f.error)? {
            AsciiFrame::Request(r) => Ok(r),
            AsciiFrame::Reply(r) => Err(FrameError::Malformed(not_a_request(&r))),
        }
    }

    /// Writes the frame into `out`; returns its length.
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, EmitError> {
        let mut w = Writer::new(self.inv_no.chars()?);
        if self.cmd == Cmd::G {
            return Err(EmitError::Invalid("G is a binary-mode command; ASCII mode has R, W and P"));
        }
        w.push(self.cmd.letter());
        w.hex4(self.comm_no.0);
        match (self.cmd, self.data) {
            (Cmd::R, Some(_)) => return Err(EmitError::Invalid("an R request carries no DATA")),
            (Cmd::R, None) => {}
            (_, None) => return Err(EmitError::Invalid("W and P requests carry DATA")),
            (_, Some(d)) => {
                if !(1..=4).contains(&d.digits) {
                    return Err(EmitError::OutOfRange {
                        field: "number of DATA digits",
                        value: d.digits as u32,
                        min: 1,
                        max: 4,
                    });
                }
                let max = (1u32 << (4 * d.digits as u32)) - 1;
                if d.value as u32 > max {
                    return Err(EmitError::OutOfRange { field: "DATA", value: d.value as u32, min: 0, max });
                }
                for i in (0..d.digits).rev() {
                    w.push(hex::nibble_digit((d.value >> (4 * i)) as u8));
                }
            }
        }
        w.finish(self.sum, out)
    }
}

/// What a reply carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum AsciiReplyBody {
    /// The command echoed with COMNO and DATA (the value read, or written).
    Data {
        /// CMD of the request.
        cmd: Cmd,
        /// COMNO of the request.
        comm_no: CommNo,
        /// DATA.
        data: u16,
    },
    /// `N` (`n` while tripped) and the error code.
    Error(ErrorCode),
}

/// A reply, inverter to master.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct AsciiReply {
    /// INV-NO: the inverter's number when the request carried one.
    pub inv_no: Option<u8>,
    /// Lower-case CMD: the inverter is tripped (or retry-waiting, trip-holding).
    pub tripped: bool,
    /// Data or error.
    pub body: AsciiReplyBody,
    /// Whether `&` and SUM are present.
    pub sum: bool,
}

impl AsciiReply {
    /// The data carried, unless this is an error reply.
    pub fn data(&self) -> Option<u16> {
        match self.body {
            AsciiReplyBody::Data { data, .. } => Some(data),
            AsciiReplyBody::Error(_) => None,
        }
    }

    /// The communication number, unless this is an error reply.
    pub fn comm_no(&self) -> Option<CommNo> {
        match self.body {
            AsciiReplyBody::Data { comm_no, .. } => Some(comm_no),
            AsciiReplyBody::Error(_) => None,
        }
    }

    /// The error code of an error reply.
    pub fn error(&self) -> Option<ErrorCode> {
        match self.body {
            AsciiReplyBody::Error(e) => Some(e),
            AsciiReplyBody::Data { .. } => None,
        }
    }

    /// The data in Hz, when the communication number is a 0.01 Hz value (FD00, FA01, ...).
    pub fn hz(&self) -> Option<f64> {
        match self.body {
            AsciiReplyBody::Data { comm_no, data, .. } => comm_no.hz(data),
            AsciiReplyBody::Error(_) => None,
        }
    }

    /// The data in its unit (19.15 for FE03 077B), where the communication number has one.
    pub fn value(&self) -> Option<f64> {
        match self.body {
            AsciiReplyBody::Data { comm_no, data, .. } => comm_no.value(data),
            AsciiReplyBody::Error(_) => None,
        }
    }

    /// Reads a whole reply frame (`W`/`P` read as echoes).
    pub fn parse(bytes: &[u8]) -> Result<Self, FrameError> {
        match parse_frame(bytes, Some(Direction::Drive)).map_err(|f| f.error)? {
            AsciiFrame::Reply(r) => Ok(r),
            AsciiFrame::Request(_) => Err(FrameError::Malformed(
                "a read request (R without DATA), not a reply: a reply to R carries 4 DATA digits",
            )),
        }
    }

    /// Writes the frame into `out` (always 4 data digits); returns its length.
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, EmitError> {
        let inv = match self.inv_no {
            Some(n) => Some(unit_chars(n)?),
            None => None,
        };
        let mut w = Writer::new(inv);
        let case = if self.tripped { 0x20 } else { 0 };
        match self.body {
            AsciiReplyBody::Data { cmd, comm_no, data } => {
                if cmd == Cmd::G {
                    return Err(EmitError::Invalid("G is a binary-mode command; ASCII mode has R, W and P"));
                }
                w.push(cmd.letter() | case);
                w.hex4(comm_no.0);
                w.hex4(data);
            }
            AsciiReplyBody::Error(code) => {
                w.push(ERROR_LETTER | case);
                w.hex4(code.0);
            }
        }
        w.finish(self.sum, out)
    }
}

fn not_a_request(r: &AsciiReply) -> &'static str {
    match r.body {
        AsciiReplyBody::Error(_) => "an error reply (N or n) from a drive, not a request",
        AsciiReplyBody::Data { .. } if r.tripped => {
            "a reply from a tripped drive (lower-case CMD), not a request"
        }
        AsciiReplyBody::Data { .. } => "a drive's reply (R with DATA), not a request",
    }
}

/// Builds a frame in a local buffer (never more than [`MAX_FRAME`] bytes).
struct Writer {
    buf: [u8; MAX_FRAME],
    len: usize,
}

impl Writer {
    fn new(inv: Option<[u8; 2]>) -> Self {
        let mut w = Writer { buf: [0; MAX_FRAME], len: 0 };
        w.push(START);
        if let Some([a, b]) = inv {
            w.push(a);
            w.push(b);
        }
        w
    }

    fn push(&mut self, b: u8) {
        if let Some(slot) = self.buf.get_mut(self.len) {
            *slot = b;
            self.len += 1;
        }
    }

    fn hex4(&mut self, v: u16) {
        let [h, l] = v.to_be_bytes();
        for b in hex::byte_digits(h).into_iter().chain(hex::byte_digits(l)) {
            self.push(b);
        }
    }

    fn finish(mut self, sum: bool, out: &mut [u8]) -> Result<usize, EmitError> {
        if sum {
            self.push(SUM_MARK);
            let s = sum8(&self.buf[..self.len]);
            let [h, l] = hex::byte_digits(s);
            self.push(h);
            self.push(l);
        }
        self.push(STOP);
        self.push(CR);
        need(out, self.len)?;
        out[..self.len].copy_from_slice(&self.buf[..self.len]);
        Ok(self.len)
    }
}

/// A frame in either direction.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum AsciiFrame {
    /// From the master.
    Request(AsciiRequest),
    /// From an inverter.
    Reply(AsciiReply),
}

impl AsciiFrame {
    /// Reads a whole frame; `from` decides only for `W`/`P` echoes (default: master).
    pub fn parse(bytes: &[u8], from: Option<Direction>) -> Result<Self, FrameError> {
        parse_frame(bytes, from).map_err(|f| f.error)
    }

    /// Writes the frame into `out`; returns its length.
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, EmitError> {
        match self {
            AsciiFrame::Request(r) => r.emit(out),
            AsciiFrame::Reply(r) => r.emit(out),
        }
    }
}

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
const HEX: [u8; 256] = {
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
fn rejection(bytes: &[u8]) -> Option<(AsciiAddress, bool, ErrorCode)> {
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
/// others are the caller's business: see [`TipAscii`]'s `rejected_disposition`).
pub fn rejection_reply(bytes: &[u8], me: u8, tripped: bool) -> Option<AsciiReply> {
    let (inv_no, sum, code) = rejection(bytes)?;
    let inv_no = match inv_no {
        AsciiAddress::Omitted => None,
        AsciiAddress::Unit(n) => Some(n),
        AsciiAddress::Wildcard { .. } => Some(me),
    };
    Some(AsciiReply { inv_no, tripped, body: AsciiReplyBody::Error(code), sum })
}

/// The deframer's scanner for ASCII mode: `(` to CR, at most 17 bytes, SUM checked when present.
#[derive(Clone, Copy, Debug, Default)]
pub struct AsciiScanner;

impl Scanner for AsciiScanner {
    type Buffer = [u8; MAX_FRAME];

    #[inline]
    fn scan(&self, buf: &[u8], checked: usize) -> Scan {
        scan_ascii(buf, checked, false)
    }

    fn truncated(&self, buf: &[u8]) -> FrameError {
        FrameError::Truncated {
            what: "an ASCII-mode frame (no CR yet)",
            expected: buf.len() + 1,
            got: buf.len(),
        }
    }
}

/// Byte classes for the scanner: what a byte does inside an ASCII-mode frame.
const ORDINARY: u8 = 0;
const END: u8 = 1;
const RESTART: u8 = 2;
const SLASH: u8 = 3;
const BAD: u8 = 4;

const fn classes(tip: bool) -> [u8; 256] {
    let mut t = [BAD; 256];
    let mut c = 0x20;
    while c < 0x7F {
        t[c] = ORDINARY;
        c += 1;
    }
    t[CR as usize] = END;
    t[START as usize] = RESTART;
    if tip {
        t[super::binary::START as usize] = SLASH;
    }
    t
}

/// Classes on an ASCII-only line.
static CLASS: [u8; 256] = classes(false);
/// Classes on a line that carries both modes (2F starts a binary frame).
static CLASS_TIP: [u8; 256] = classes(true);

/// Scans for an ASCII-mode frame; `tip`: the line also carries binary mode, so 2F is a start code.
#[inline]
pub(crate) fn scan_ascii(buf: &[u8], checked: usize, tip: bool) -> Scan {
    if buf.first() != Some(&START) {
        return Scan::Noise { len: next_start(buf, tip) };
    }
    let table = if tip { &CLASS_TIP } else { &CLASS };
    let limit = buf.len().min(MAX_FRAME);
    let from = checked.clamp(1, limit);
    // The sum of the bytes before the one looked at, for SUM.
    let mut sum = sum8(&buf[..from]);
    for (i, &b) in buf[from..limit].iter().enumerate() {
        let class = table[b as usize];
        if class != ORDINARY {
            return special(buf, from + i, class, sum);
        }
        sum = sum.wrapping_add(b);
    }
    if limit == MAX_FRAME {
        return Scan::Invalid {
            len: MAX_FRAME,
            skip: MAX_FRAME,
            error: FrameError::Malformed("no CR within 17 bytes: an ASCII-mode frame is at most 17 bytes"),
        };
    }
    Scan::Incomplete { checked: limit }
}

/// The byte at `i` is not an ordinary frame byte: CR ends the frame, a start code cuts it short,
/// anything else is not allowed in one.
#[inline]
fn special(buf: &[u8], i: usize, class: u8, sum: u8) -> Scan {
    match class {
        END => finish_ascii(&buf[..=i], sum),
        RESTART => Scan::Invalid {
            len: i,
            skip: i,
            error: FrameError::Malformed(
                "a new start code '(' came before CR: the frame before it was cut short",
            ),
        },
        SLASH => Scan::Invalid {
            len: i,
            skip: i,
            error: FrameError::Malformed(
                "a binary-mode start code 2F came before CR: the ASCII-mode frame before it was cut short",
            ),
        },
        _ => Scan::Invalid {
            len: i + 1,
            skip: i + 1,
            error: FrameError::NonHex { byte: buf.get(i).copied().unwrap_or(0), offset: i },
        },
    }
}

/// Bytes before the next start code (`(`, and 2F on a line that carries both modes).
pub(crate) fn next_start(buf: &[u8], tip: bool) -> usize {
    buf.iter()
        .skip(1)
        .position(|&b| b == START || (tip && b == super::binary::START))
        .map_or(buf.len(), |p| p + 1)
}

/// A candidate from `(` to CR, whose bytes before CR add up to `sum`: checks SUM when `&`
/// is where it belongs.
#[inline]
fn finish_ascii(frame: &[u8], sum: u8) -> Scan {
    let len = frame.len();
    if len >= 6 && frame[len - 5] == SUM_MARK {
        let (hi, lo, stop) = (frame[len - 4], frame[len - 3], frame[len - 2]);
        let (h, l) = (HEX[hi as usize], HEX[lo as usize]);
        if (h | l) & 0x10 == 0 {
            let carried = h << 4 | l;
            // The covered bytes end with '&': the sum of all before CR less SUM and ')'.
            let computed = sum.wrapping_sub(hi).wrapping_sub(lo).wrapping_sub(stop);
            if carried != computed {
                let covered = &frame[..len - 4];
                return Scan::Invalid {
                    len,
                    skip: len,
                    error: FrameError::ChecksumMismatch {
                        kind: ChecksumKind::Sum,
                        carried: carried as u16,
                        computed: computed as u16,
                        hint: prefix_hint(covered, carried),
                    },
                };
            }
        }
    }
    Scan::Frame { len }
}

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
        rep.inv_no == self.inv_no
            && match rep.body {
                AsciiReplyBody::Error(_) => true,
                AsciiReplyBody::Data { cmd, comm_no, .. } => cmd == self.cmd && comm_no == self.comm_no,
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
    type Request<'a> = AsciiRequest;
    type Reply<'a> = AsciiReply;
    type Pending = AsciiPending;

    fn reply_scanner(&self) -> AsciiScanner {
        AsciiScanner
    }
    fn request_scanner(&self) -> AsciiScanner {
        AsciiScanner
    }
    fn emit_request(&self, req: &AsciiRequest, out: &mut [u8]) -> Result<usize, EmitError> {
        req.emit(out)
    }
    fn emit_reply(&self, rep: &AsciiReply, out: &mut [u8]) -> Result<usize, EmitError> {
        rep.emit(out)
    }
    fn parse_request(&self, bytes: &[u8]) -> Result<AsciiRequest, FrameError> {
        AsciiRequest::parse(bytes)
    }
    fn parse_reply(&self, bytes: &[u8]) -> Result<AsciiReply, FrameError> {
        AsciiReply::parse(bytes)
    }
    fn pending(&self, req: &AsciiRequest) -> Option<AsciiPending> {
        TipAscii::pending(self, req)
    }
    fn matches(&self, pending: &AsciiPending, rep: &AsciiReply) -> bool {
        pending.matches(rep)
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

fn inv_field(inv_no: AsciiAddress, out: &mut dyn FnMut(Field<'_>)) {
    match inv_no {
        AsciiAddress::Omitted => {}
        AsciiAddress::Unit(n) => out(Field::dec("INV-NO", n as i64)),
        AsciiAddress::Wildcard { .. } => {
            if let Ok(Some(chars)) = inv_no.chars() {
                out(Field::text("INV-NO", &chars)
                    .with_meaning("wildcard: the smallest matching number answers"));
            }
        }
    }
}

fn sum_field(frame: &AsciiFrame, out: &mut dyn FnMut(Field<'_>)) {
    let mut buf = [0u8; MAX_FRAME];
    if let Ok(n) = frame.emit(&mut buf) {
        if n >= 6 && buf[n - 5] == SUM_MARK {
            if let Some(s) = hex::decode_pair(buf[n - 4], buf[n - 3]) {
                out(Field::hex("SUM", s as u32, 2));
            }
        }
    }
}

impl Describe for AsciiFrame {
    fn direction(&self) -> Direction {
        match self {
            AsciiFrame::Request(_) => Direction::Master,
            AsciiFrame::Reply(_) => Direction::Drive,
        }
    }

    fn target(&self) -> Target {
        match self {
            AsciiFrame::Request(r) => r.inv_no.target(),
            AsciiFrame::Reply(r) => r.inv_no.map_or(Target::Implicit, Target::Unit),
        }
    }

    fn command(&self) -> Command {
        match self {
            AsciiFrame::Request(r) => {
                Command { code: r.cmd.letter(), style: CodeStyle::Letter, name: r.cmd.name() }
            }
            AsciiFrame::Reply(r) => reply_command(r.tripped, &r.body),
        }
    }

    fn is_refusal(&self) -> bool {
        matches!(self, AsciiFrame::Reply(AsciiReply { body: AsciiReplyBody::Error(_), .. }))
    }

    fn fields(&self, out: &mut dyn FnMut(Field<'_>)) {
        match self {
            AsciiFrame::Request(r) => {
                inv_field(r.inv_no, out);
                out(r.comm_no.field());
                if let Some(d) = r.data {
                    describe_value(r.comm_no.format(), "data", d.value, d.digits, out);
                }
            }
            AsciiFrame::Reply(r) => {
                if let Some(n) = r.inv_no {
                    out(Field::dec("INV-NO", n as i64));
                }
                out(tripped_field(r.tripped));
                match r.body {
                    AsciiReplyBody::Data { comm_no, data, .. } => {
                        out(comm_no.field());
                        describe_value(comm_no.format(), "data", data, 4, out);
                    }
                    AsciiReplyBody::Error(code) => out(code.field()),
                }
            }
        }
        sum_field(self, out);
    }
}

/// The "tripped" field of a reply.
pub(crate) fn tripped_field(tripped: bool) -> Field<'static> {
    let f = Field::flag("tripped", tripped);
    if tripped {
        f.with_meaning("lower-case CMD: the inverter is tripped")
    } else {
        f
    }
}

fn reply_command(tripped: bool, body: &AsciiReplyBody) -> Command {
    let case = if tripped { 0x20 } else { 0 };
    match body {
        AsciiReplyBody::Data { cmd, .. } => {
            Command { code: cmd.letter() | case, style: CodeStyle::Letter, name: cmd.name() }
        }
        AsciiReplyBody::Error(_) => {
            Command { code: ERROR_LETTER | case, style: CodeStyle::Letter, name: "error reply" }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::deframe::{Deframer, Event};
    use std::format;
    use std::string::{String, ToString};
    use std::vec::Vec;

    fn emit_req(r: &AsciiRequest) -> Vec<u8> {
        let mut b = [0u8; 32];
        let n = r.emit(&mut b).unwrap();
        b[..n].to_vec()
    }

    fn emit_rep(r: &AsciiReply) -> Vec<u8> {
        let mut b = [0u8; 32];
        let n = r.emit(&mut b).unwrap();
        b[..n].to_vec()
    }

    fn describe(f: &AsciiFrame) -> String {
        let mut s = String::new();
        f.fields(&mut |fl| {
            if !s.is_empty() {
                s.push_str(", ");
            }
            s.push_str(&fl.to_string());
        });
        s
    }

    fn frames(stream: &[u8]) -> (Vec<Vec<u8>>, Vec<FrameError>) {
        let mut d = Deframer::new(AsciiScanner);
        let (mut good, mut bad) = (Vec::new(), Vec::new());
        d.push(stream, &mut |e| match e {
            Event::Frame { bytes, .. } => good.push(bytes.to_vec()),
            Event::Rejected { error, .. } => bad.push(error),
        });
        (good, bad)
    }

    /// TA4: `(RFE03)` CR, read output current (seeds/002_43d8a4399c8be05f.txt TOC: "RFE03CR").
    #[test]
    fn ta4_read_output_current() {
        let wire = [
            0x28, // '(' start code
            0x52, // 'R' read
            0x46, 0x45, 0x30, 0x33, // "FE03" COMNO: output current
            0x29, // ')' stop code
            0x0D, // CR
        ];
        let req = AsciiRequest::read(AsciiAddress::Omitted, CommNo::OUTPUT_CURRENT);
        assert_eq!(emit_req(&req), wire);
        assert_eq!(AsciiRequest::parse(&wire), Ok(req));
        let f = AsciiCodec::parse(&wire, None).unwrap();
        assert_eq!(f.direction(), Direction::Master);
        assert_eq!(f.target(), Target::Implicit);
        assert_eq!(f.command().to_string(), "R read");
        assert_eq!(describe(&f), "communication number FE03 (output current)");
    }

    /// TA5: `(RFE03077B)` CR, reply 077B = 19.15 % (seeds/002_43d8a4399c8be05f.txt TOC).
    #[test]
    fn ta5_reply_output_current() {
        let wire = [
            0x28, // '('
            0x52, // 'R' upper case: not tripped
            0x46, 0x45, 0x30, 0x33, // "FE03"
            0x30, 0x37, 0x37, 0x42, // "077B" DATA = 1915 = 19.15 %
            0x29, 0x0D, // ')' CR
        ];
        let rep = AsciiRequest::read(AsciiAddress::Omitted, CommNo::OUTPUT_CURRENT).reply(0, false, 0x077B);
        assert_eq!(emit_rep(&rep), wire);
        assert_eq!(AsciiReply::parse(&wire), Ok(rep));
        assert_eq!(rep.value(), Some(19.15));
        assert_eq!(rep.hz(), None);
        // R with DATA is a drive's, whatever the caller says.
        let f = AsciiCodec::parse(&wire, Some(Direction::Master)).unwrap();
        assert_eq!(f.direction(), Direction::Drive);
        assert_eq!(
            describe(&f),
            "tripped 0, communication number FE03 (output current), data 077B = 19.15 %"
        );
        assert_eq!(
            AsciiRequest::parse(&wire),
            Err(FrameError::Malformed("a drive's reply (R with DATA), not a request"))
        );
    }

    /// TA7: `(W00100064)` CR writes deceleration time 10.0 s; the reply is the same bytes.
    #[test]
    fn ta7_write_decel_time_echo() {
        let wire = [
            0x28, // '('
            0x57, // 'W' write RAM and EEPROM
            0x30, 0x30, 0x31, 0x30, // "0010" deceleration time
            0x30, 0x30, 0x36, 0x34, // "0064" = 100 = 10.0 s
            0x29, 0x0D, // ')' CR
        ];
        let req = AsciiRequest::write(AsciiAddress::Omitted, CommNo::DECELERATION_TIME, 0x64);
        assert_eq!(emit_req(&req), wire);
        assert_eq!(AsciiCodec::parse(&wire, None), Ok(AsciiFrame::Request(req)));
        let rep = req.reply(0, false, 0x64);
        assert_eq!(emit_rep(&rep), wire);
        assert_eq!(AsciiCodec::parse(&wire, Some(Direction::Drive)), Ok(AsciiFrame::Reply(rep)));
        assert_eq!(
            describe(&AsciiFrame::Request(req)),
            "communication number 0010 (deceleration time), data 0064 = 10.0 s"
        );
    }

    /// TA13: `(*2R0000)` CR to every inverter ending in 2; only 02 answers `(02R00000000)` CR.
    #[test]
    fn ta13_wildcard() {
        let wire = [
            0x28, // '('
            0x2A, 0x32, // "*2" INV-NO wildcard: 02, 12, 22, ...
            0x52, // 'R'
            0x30, 0x30, 0x30, 0x30, // "0000" COMNO
            0x29, 0x0D, // ')' CR
        ];
        let inv_no = AsciiAddress::Wildcard { tens: None, units: Some(2) };
        let req = AsciiRequest::read(inv_no, CommNo(0));
        assert_eq!(emit_req(&req), wire);
        assert_eq!(AsciiRequest::parse(&wire), Ok(req));
        assert_eq!(inv_no.disposition(2), Disposition::Broadcast { reply: true });
        assert_eq!(inv_no.disposition(12), Disposition::Broadcast { reply: false });
        assert_eq!(inv_no.disposition(22), Disposition::Broadcast { reply: false });
        assert_eq!(inv_no.disposition(3), Disposition::NotMine);
        let rep = req.reply(2, false, 0);
        assert_eq!(emit_rep(&rep), b"(02R00000000)\r");
        assert!(TipAscii::default().pending(&req).unwrap().matches(&rep));
        assert_eq!(AsciiFrame::Request(req).target(), Target::Wildcard { tens: None, units: Some(2) });
    }

    #[test]
    fn wildcard_smallest_number() {
        let w = |tens, units| AsciiAddress::Wildcard { tens, units };
        assert_eq!(w(None, Some(2)).reply_inv_no(), Some(2));
        assert_eq!(w(Some(1), None).reply_inv_no(), Some(10));
        assert_eq!(AsciiAddress::ALL.reply_inv_no(), Some(0));
        assert_eq!(w(Some(1), None).disposition(10), Disposition::Broadcast { reply: true });
        assert_eq!(w(Some(1), None).disposition(19), Disposition::Broadcast { reply: false });
        assert_eq!(w(Some(1), None).disposition(20), Disposition::NotMine);
        assert_eq!(AsciiAddress::ALL.disposition(0), Disposition::Broadcast { reply: true });
        assert_eq!(AsciiAddress::ALL.disposition(99), Disposition::Broadcast { reply: false });
        assert_eq!(AsciiAddress::ALL.disposition(100), Disposition::NotMine);
        assert_eq!(
            AsciiFrame::Request(AsciiRequest::read(AsciiAddress::ALL, CommNo(0))).target(),
            Target::Broadcast
        );
        assert_eq!(AsciiRequest::parse(b"(1*RFD00)\r").unwrap().inv_no, w(Some(1), None));
        assert_eq!(AsciiRequest::parse(b"(**RFD00)\r").unwrap().inv_no, AsciiAddress::ALL);
    }

    /// TA17 (negative): `(R11)` CR is a format error; a drive does not answer.
    #[test]
    fn ta17_r11_format_error() {
        let wire = b"(R11)\r";
        let err = AsciiRequest::parse(wire).unwrap_err();
        assert_eq!(
            err.to_string(),
            "format error: COMNO needs 4 hex digits before ')'; a drive reads ')' and CR as digits and does not answer"
        );
        assert_eq!(rejection_reply(wire, 0, false), None);
        assert_eq!(TipAscii::default().rejected_disposition(wire, 0), Disposition::NotMine);
        // The scanner frames it (it ends with CR), so the slave sees and ignores it.
        assert_eq!(frames(wire).0.len(), 1);
    }

    /// `(R0000&60)` CR: 28+52+30+30+30+30+26 = 160H, SUM = 60 (manual's rule).
    #[test]
    fn sum_example() {
        let wire = [
            0x28, 0x52, // '(' 'R'
            0x30, 0x30, 0x30, 0x30, // "0000"
            0x26, // '&' checksum discrimination code
            0x36, 0x30, // "60" SUM
            0x29, 0x0D, // ')' CR
        ];
        let req = AsciiRequest::read(AsciiAddress::Omitted, CommNo(0)).with_sum();
        assert_eq!(emit_req(&req), wire);
        assert_eq!(AsciiRequest::parse(&wire), Ok(req));
        assert_eq!(describe(&AsciiFrame::Request(req)), "communication number 0000, SUM 60");
        // The reply carries & and SUM because the request did.
        let rep = req.reply(0, false, 0x1234);
        let bytes = emit_rep(&rep);
        assert_eq!(bytes, b"(R00001234&2A)\r");
        assert_eq!(sum8(b"(R00001234&"), 0x2A);
        assert_eq!(AsciiReply::parse(&bytes), Ok(rep));
    }

    #[test]
    fn checksum_mismatch_is_diagnosed_and_answered() {
        let wire = b"(R0000&61)\r";
        let (good, bad) = frames(wire);
        assert!(good.is_empty());
        assert_eq!(bad[0].to_string(), "SUM mismatch: frame carries 61, computed 60");
        // SUM over everything but '&' (a common mistake): 0x160 - 0x26 = 0x13A.
        let err = AsciiRequest::parse(b"(R0000&3A)\r").unwrap_err();
        assert_eq!(
            err.to_string(),
            "SUM mismatch: frame carries 3A, computed 60 (the carried SUM is that of the first 6 bytes only)"
        );
        // A drive answers a checksum error addressed to it: (N0004&..)CR, SUM kept.
        let rep = rejection_reply(wire, 0, false).unwrap();
        assert_eq!(rep.error(), Some(ErrorCode::CHECKSUM_ERROR));
        assert_eq!(emit_rep(&rep), b"(N0004&60)\r");
        assert_eq!(TipAscii::default().rejected_disposition(wire, 7), Disposition::Mine);
        // Addressed to another inverter: silence.
        assert_eq!(TipAscii::default().rejected_disposition(b"(05R0000&61)\r", 7), Disposition::NotMine);
        assert_eq!(TipAscii::default().rejected_disposition(b"(07R0000&61)\r", 7), Disposition::Mine);
        let rep = rejection_reply(b"(07R0000&61)\r", 7, true).unwrap();
        assert_eq!(emit_rep(&rep), b"(07n0004&E7)\r");
    }

    /// The error replies (N) with every manual code, and the tripped form (n).
    #[test]
    fn error_replies() {
        for (code, name) in [
            (0, "impossible to execute"),
            (1, "data error"),
            (2, "communication number error"),
            (3, "command error"),
            (4, "checksum error"),
        ] {
            let rep = AsciiReply {
                inv_no: None,
                tripped: false,
                body: AsciiReplyBody::Error(ErrorCode(code)),
                sum: false,
            };
            let bytes = emit_rep(&rep);
            assert_eq!(bytes, format!("(N000{code})\r").as_bytes());
            let f = AsciiCodec::parse(&bytes, Some(Direction::Master)).unwrap();
            assert!(f.is_refusal());
            assert_eq!(f.direction(), Direction::Drive);
            assert_eq!(describe(&f), format!("tripped 0, error code 000{code} ({name})"));
        }
        // protocols.md 1.4 example: (N0001&5D)CR = data error.
        let wire = b"(N0001&5D)\r";
        let rep = AsciiReply::parse(wire).unwrap();
        assert_eq!(rep.error(), Some(ErrorCode::DATA_ERROR));
        assert!(rep.sum);
        let rep = AsciiReply::parse(b"(12n0000)\r").unwrap();
        assert!(rep.tripped);
        assert_eq!(rep.inv_no, Some(12));
        assert_eq!(AsciiCodec::parse(b"(12n0000)\r", None).unwrap().command().to_string(), "n error reply");
        assert_eq!(
            AsciiRequest::parse(b"(N0001)\r"),
            Err(FrameError::Malformed("an error reply (N or n) from a drive, not a request"))
        );
    }

    #[test]
    fn tripped_replies() {
        let req = AsciiRequest::read(AsciiAddress::Unit(3), CommNo::OUTPUT_FREQUENCY);
        let rep = req.reply(3, true, 0x1770);
        let bytes = emit_rep(&rep);
        assert_eq!(bytes, b"(03rFD001770)\r");
        assert_eq!(AsciiReply::parse(&bytes), Ok(rep));
        assert_eq!(rep.hz(), Some(60.0));
        assert!(TipAscii::default().pending(&req).unwrap().matches(&rep));
        // A lower-case W echo is a drive's even when the caller says master.
        let f = AsciiCodec::parse(b"(w00100064)\r", Some(Direction::Master)).unwrap();
        assert_eq!(f.direction(), Direction::Drive);
        assert_eq!(f.command().to_string(), "w write (RAM and EEPROM)");
        assert_eq!(
            AsciiRequest::parse(b"(pFA011770)\r"),
            Err(FrameError::Malformed("a reply from a tripped drive (lower-case CMD), not a request"))
        );
    }

    #[test]
    fn format_errors_get_no_reply() {
        let cases: &[(&[u8], &str)] = &[
            (b"(1RFD00)\r", "format error: one-digit INV-NO (it is two digits 00-99, or none); a drive does not answer"),
            (b"(RFD00]\r", "format error: the byte before CR is not the stop code ')'; a drive does not answer"),
            (b"(RFD00)X\r", "format error: the byte before CR is not the stop code ')'; a drive does not answer"),
            (b"()\r", "format error: no CMD between '(' and ')'"),
            (b"(12)\r", "format error: no CMD after INV-NO"),
            (b"(RF&D00)\r", "format error: '&' must be followed by exactly two SUM digits and ')'; a drive does not answer"),
            (b"(RFD00)", "format error: the frame does not end with CR (0D)"),
        ];
        for (wire, msg) in cases {
            let err = AsciiRequest::parse(wire).unwrap_err();
            assert_eq!(err.to_string(), *msg, "{}", String::from_utf8_lossy(wire));
            assert_eq!(rejection_reply(wire, 0, false), None);
        }
    }

    #[test]
    fn answered_errors() {
        // Unknown command: 0003 in ASCII mode (binary mode stays silent).
        let err = AsciiRequest::parse(b"(XFD00)\r").unwrap_err();
        assert_eq!(err.to_string(), "unknown ASCII-mode CMD 0x58");
        assert_eq!(rejection_reply(b"(XFD00)\r", 0, false).unwrap().error(), Some(ErrorCode::COMMAND_ERROR));
        // G is binary-mode only.
        assert_eq!(
            rejection_reply(b"(GFD000000)\r", 0, false).unwrap().error(),
            Some(ErrorCode::COMMAND_ERROR)
        );
        // A non-hex COMNO: no such communication number.
        let err = AsciiRequest::parse(b"(RFDX0)\r").unwrap_err();
        assert_eq!(err.to_string(), "non-hex byte 0x58 at offset 4 ends the frame");
        assert_eq!(rejection_reply(b"(RFDX0)\r", 0, false).unwrap().error(), Some(ErrorCode::COMM_NO_ERROR));
        // Too many digits: data error.
        let err = AsciiRequest::parse(b"(WFA0112345)\r").unwrap_err();
        assert_eq!(err.to_string(), "number of DATA digits 5 is not allowed (0..4)");
        assert_eq!(
            rejection_reply(b"(WFA0112345)\r", 0, false).unwrap().error(),
            Some(ErrorCode::DATA_ERROR)
        );
        // W without data: data error.
        assert_eq!(rejection_reply(b"(WFA01)\r", 0, false).unwrap().error(), Some(ErrorCode::DATA_ERROR));
        assert_eq!(
            AsciiRequest::parse(b"(WFA01)\r").unwrap_err().to_string(),
            "data error: W and P carry 1 to 4 DATA digits, this one has none"
        );
        // A lower-case command without DATA is neither a reply nor a request: silence.
        assert_eq!(rejection_reply(b"(wFA01)\r", 0, false), None);
        assert_eq!(
            AsciiReply::parse(b"(rFD00)\r").unwrap_err().to_string(),
            "a reply (lower-case CMD) carries 4 DATA digits"
        );
        // Wildcard: the reply carries this inverter's number.
        let rep = rejection_reply(b"(*5XFD00)\r", 5, false).unwrap();
        assert_eq!(emit_rep(&rep), b"(05N0003)\r");
        assert_eq!(
            TipAscii::default().rejected_disposition(b"(*5XFD00)\r", 15),
            Disposition::Broadcast { reply: false }
        );
    }

    #[test]
    fn short_data_and_lower_case_hex() {
        // DATA may be 1-4 digits; drivebus sends 4.
        let req = AsciiRequest::parse(b"(P0010a)\r").unwrap();
        assert_eq!(req.data, Some(AsciiData { value: 0xA, digits: 1 }));
        assert_eq!(emit_req(&req), b"(P0010A)\r");
        assert_eq!(
            describe(&AsciiFrame::Request(req)),
            "communication number 0010 (deceleration time), data A = 1.0 s"
        );
        // A reply with fewer digits is read leniently.
        assert_eq!(AsciiReply::parse(b"(RFD0017)\r").unwrap().data(), Some(0x17));
    }

    #[test]
    fn replies_are_not_requests_and_back() {
        assert!(AsciiReply::parse(b"(RFD00)\r").is_err());
        assert!(AsciiCodec::parse(b"(*2R00001234)\r", None).is_err());
    }

    #[test]
    fn emit_errors() {
        let mut b = [0u8; 32];
        let bad = AsciiRequest::read(AsciiAddress::Unit(100), CommNo(0));
        assert_eq!(
            bad.emit(&mut b),
            Err(EmitError::OutOfRange { field: "INV-NO", value: 100, min: 0, max: 99 })
        );
        let bad = AsciiRequest {
            data: Some(AsciiData { value: 0x100, digits: 2 }),
            ..AsciiRequest::write(AsciiAddress::Omitted, CommNo(0), 0)
        };
        assert!(bad.emit(&mut b).is_err());
        let bad = AsciiRequest { cmd: Cmd::G, ..AsciiRequest::read(AsciiAddress::Omitted, CommNo(0)) };
        assert!(bad.emit(&mut b).is_err());
        let bad = AsciiRequest::read(AsciiAddress::Wildcard { tens: Some(1), units: Some(2) }, CommNo(0));
        assert!(bad.emit(&mut b).is_err());
        let ok = AsciiRequest::read(AsciiAddress::Omitted, CommNo(0));
        assert_eq!(ok.emit(&mut b[..5]), Err(EmitError::BufferTooSmall { needed: 8, capacity: 5 }));
    }

    #[test]
    fn scanner_resyncs() {
        // Garbage, a frame cut short by a new '(', a frame with a control byte, then good frames.
        let stream = b"xx(RFD(RFE03)\r(R\x01D00)\r(W00100064)\r";
        let (good, bad) = frames(stream);
        assert_eq!(good, [b"(RFE03)\r".to_vec(), b"(W00100064)\r".to_vec()]);
        assert_eq!(bad.len(), 2);
        assert_eq!(bad[1].to_string(), "non-hex byte 0x01 at offset 2 ends the frame");
        // No CR within 17 bytes.
        let (good, bad) = frames(b"(RFD000000000000000000(RFD00)\r");
        assert_eq!(good, [b"(RFD00)\r".to_vec()]);
        assert_eq!(bad[0].to_string(), "no CR within 17 bytes: an ASCII-mode frame is at most 17 bytes");
        // Every split gives the same frames.
        let stream = b"(RFE03)\r(RFE03077B)\r(R0000&61)\r(R0000&60)\r";
        let (whole, _) = frames(stream);
        assert_eq!(whole.len(), 3);
        for i in 0..stream.len() {
            let mut d = Deframer::new(AsciiScanner);
            let mut got = Vec::new();
            for part in [&stream[..i], &stream[i..]] {
                d.push(part, &mut |e| {
                    if let Event::Frame { bytes, .. } = e {
                        got.push(bytes.to_vec())
                    }
                });
            }
            assert_eq!(got, whole, "split at {i}");
        }
    }

    #[test]
    fn longest_frame_fits() {
        let req = AsciiRequest::write(AsciiAddress::Unit(99), CommNo(0xFA01), 0x1770).with_sum();
        let bytes = emit_req(&req);
        assert_eq!(bytes.len(), MAX_FRAME);
        assert_eq!(frames(&bytes).0, [&bytes[..]]);
    }
}
