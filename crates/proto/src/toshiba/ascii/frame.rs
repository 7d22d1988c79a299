//! The typed frames of ASCII mode and how they are written.

use crate::checksum::sum8;
use crate::describe::Direction;
use crate::error::{need, EmitError, FrameError};
use crate::hex;

use super::address::unit_chars;
use super::parse::parse_frame;
use super::{AsciiAddress, Cmd, CommNo, CR, MAX_FRAME, START, STOP, SUM_MARK};
use crate::toshiba::{ErrorCode, ERROR_LETTER};

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
