//! The typed frames of binary mode and how they are written.

use crate::checksum::sum8;
use crate::describe::Direction;
use crate::error::{need, EmitError, FrameError};

use super::address::unit_byte;
use super::parse::parse_frame;
use super::{BinaryAddress, Cmd, CommNo, BLOCK, BLOCK_REPLY, MAX_FRAME, MAX_READ_GROUPS, N_R, N_W, START};
use crate::toshiba::{ErrorCode, ERROR_LETTER};

/// The body of an `X` block-communication request.
///
/// WDATA1 goes to the number set by f870, WDATA2 to f871 (FA00 and FA01 by default); the read
/// items are set by f875–f879 (FD01, FD00, FE03, FC90, FE05 by default).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct BlockRequest {
    /// nW, number of write groups, 0–2.
    pub n_w: u8,
    /// nR, number of read groups as sent; more than 5 gives a reply with none.
    pub n_r: u8,
    /// WDATA1 and WDATA2; entries from `n_w` on are not sent (and are 0 after parsing).
    pub wdata: [u16; 2],
}

impl BlockRequest {
    /// Writes `wdata` (0–2 groups) and reads `n_r` groups.
    pub fn new(wdata: &[u16], n_r: u8) -> Result<Self, EmitError> {
        let n_w = N_W.emit(wdata.len())?;
        let mut w = [0; 2];
        w[..wdata.len()].copy_from_slice(wdata);
        Ok(BlockRequest { n_w, n_r, wdata: w })
    }

    /// The write groups sent.
    pub fn wdata(&self) -> &[u16] {
        &self.wdata[..(self.n_w as usize).min(2)]
    }

    /// The read groups the reply carries: nR, or 0 when nR is out of range.
    pub const fn reply_groups(&self) -> u8 {
        if self.n_r > MAX_READ_GROUPS {
            0
        } else {
            self.n_r
        }
    }
}

/// The body of a `Y` block-communication reply.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct BlockReply {
    /// nR, number of read groups, 0–5.
    pub n_r: u8,
    /// RDATA1..RDATA5; entries from `n_r` on are not sent (and are 0 after parsing).
    pub rdata: [u16; 5],
}

impl BlockReply {
    /// A reply carrying `rdata` (0–5 groups).
    pub fn new(rdata: &[u16]) -> Result<Self, EmitError> {
        let n_r = N_R.emit(rdata.len())?;
        let mut r = [0; 5];
        r[..rdata.len()].copy_from_slice(rdata);
        Ok(BlockReply { n_r, rdata: r })
    }

    /// The read groups carried.
    pub fn rdata(&self) -> &[u16] {
        &self.rdata[..(self.n_r as usize).min(5)]
    }
}

/// What a request asks.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BinaryRequestBody {
    /// `R` (52H): read COMNO.
    Read {
        /// COMNO.
        comm_no: CommNo,
    },
    /// `W` (57H): write DATA to COMNO, RAM and EEPROM.
    Write {
        /// COMNO.
        comm_no: CommNo,
        /// DATA.
        data: u16,
    },
    /// `P` (50H): write DATA to COMNO, RAM only.
    WriteRam {
        /// COMNO.
        comm_no: CommNo,
        /// DATA.
        data: u16,
    },
    /// `G` (47H): read COMNO; the manual asks for dummy DATA (e.g. 0000).
    ReadDummy {
        /// COMNO.
        comm_no: CommNo,
        /// The dummy DATA.
        dummy: u16,
    },
    /// `X` (58H): block communication.
    Block(BlockRequest),
}

impl BinaryRequestBody {
    /// The command byte.
    pub const fn code(&self) -> u8 {
        match self {
            BinaryRequestBody::Read { .. } => b'R',
            BinaryRequestBody::Write { .. } => b'W',
            BinaryRequestBody::WriteRam { .. } => b'P',
            BinaryRequestBody::ReadDummy { .. } => b'G',
            BinaryRequestBody::Block(_) => BLOCK,
        }
    }

    /// The command, unless this is a block request.
    pub const fn cmd(&self) -> Option<Cmd> {
        match self {
            BinaryRequestBody::Read { .. } => Some(Cmd::R),
            BinaryRequestBody::Write { .. } => Some(Cmd::W),
            BinaryRequestBody::WriteRam { .. } => Some(Cmd::P),
            BinaryRequestBody::ReadDummy { .. } => Some(Cmd::G),
            BinaryRequestBody::Block(_) => None,
        }
    }

    /// COMNO, unless this is a block request.
    pub const fn comm_no(&self) -> Option<CommNo> {
        match *self {
            BinaryRequestBody::Read { comm_no }
            | BinaryRequestBody::Write { comm_no, .. }
            | BinaryRequestBody::WriteRam { comm_no, .. }
            | BinaryRequestBody::ReadDummy { comm_no, .. } => Some(comm_no),
            BinaryRequestBody::Block(_) => None,
        }
    }
}

/// A request, master to inverter.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct BinaryRequest {
    /// INV-NO.
    pub inv_no: BinaryAddress,
    /// What it asks.
    pub body: BinaryRequestBody,
}

impl BinaryRequest {
    /// `R`: read `comm_no`.
    pub const fn read(inv_no: BinaryAddress, comm_no: CommNo) -> Self {
        BinaryRequest { inv_no, body: BinaryRequestBody::Read { comm_no } }
    }

    /// `W`: write `data` to `comm_no` (RAM and EEPROM).
    pub const fn write(inv_no: BinaryAddress, comm_no: CommNo, data: u16) -> Self {
        BinaryRequest { inv_no, body: BinaryRequestBody::Write { comm_no, data } }
    }

    /// `P`: write `data` to `comm_no` (RAM only).
    pub const fn write_ram(inv_no: BinaryAddress, comm_no: CommNo, data: u16) -> Self {
        BinaryRequest { inv_no, body: BinaryRequestBody::WriteRam { comm_no, data } }
    }

    /// `G`: read `comm_no` with dummy data 0000.
    pub const fn read_dummy(inv_no: BinaryAddress, comm_no: CommNo) -> Self {
        BinaryRequest { inv_no, body: BinaryRequestBody::ReadDummy { comm_no, dummy: 0 } }
    }

    /// `X`: block communication.
    pub const fn block(inv_no: BinaryAddress, block: BlockRequest) -> Self {
        BinaryRequest { inv_no, body: BinaryRequestBody::Block(block) }
    }

    /// The reply of inverter `me` to `R`/`W`/`P`/`G` carrying `data` (the value read, or
    /// written); `None` for `X` (use [`block_reply`](Self::block_reply)).
    pub fn reply(&self, me: u8, tripped: bool, data: u16) -> Option<BinaryReply> {
        let cmd = self.body.cmd()?;
        let comm_no = self.body.comm_no()?;
        Some(BinaryReply {
            inv_no: self.reply_inv_no(me),
            tripped,
            body: BinaryReplyBody::Data { cmd, comm_no, data },
        })
    }

    /// The `Y` reply of inverter `me` to `X`: the first nR groups of `rdata` (0000 where
    /// `rdata` is short; none when nR is over 5); `None` for other commands.
    pub fn block_reply(&self, me: u8, tripped: bool, rdata: &[u16]) -> Option<BinaryReply> {
        let BinaryRequestBody::Block(b) = self.body else {
            return None;
        };
        let n = b.reply_groups() as usize;
        let mut r = [0u16; 5];
        for (slot, v) in r.iter_mut().zip(rdata).take(n) {
            *slot = *v;
        }
        let body = BinaryReplyBody::Block(BlockReply { n_r: n as u8, rdata: r });
        Some(BinaryReply { inv_no: self.reply_inv_no(me), tripped, body })
    }

    /// The error reply of inverter `me` with `code`.
    pub fn error_reply(&self, me: u8, tripped: bool, code: ErrorCode) -> BinaryReply {
        BinaryReply { inv_no: self.reply_inv_no(me), tripped, body: BinaryReplyBody::Error(code) }
    }

    fn reply_inv_no(&self, me: u8) -> Option<u8> {
        match self.inv_no {
            BinaryAddress::Omitted => None,
            BinaryAddress::Unit(n) => Some(n),
            BinaryAddress::Broadcast => Some(me),
        }
    }

    /// Reads a whole request frame (`W`/`P`/`G` read as requests).
    pub fn parse(bytes: &[u8]) -> Result<Self, FrameError> {
        match parse_frame(bytes, Some(Direction::Master)).map_err(|f| f.error)? {
            BinaryFrame::Request(r) => Ok(r),
            BinaryFrame::Reply(r) => Err(FrameError::Malformed(match r.body {
                BinaryReplyBody::Error(_) => "an error reply (4E or 6E) from a drive, not a request",
                BinaryReplyBody::Block(_) => "a block reply (Y) from a drive, not a request",
                BinaryReplyBody::Data { .. } if r.tripped => {
                    "a reply from a tripped drive (lower-case CMD), not a request"
                }
                BinaryReplyBody::Data { .. } => {
                    "a drive's reply to R (7 bytes without INV-NO), not a request"
                }
            })),
        }
    }

    /// Writes the frame into `out`; returns its length.
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, EmitError> {
        let mut w = Writer::new(self.inv_no.byte()?);
        w.push(self.body.code());
        match self.body {
            BinaryRequestBody::Read { comm_no } => w.word(comm_no.0),
            BinaryRequestBody::Write { comm_no, data }
            | BinaryRequestBody::WriteRam { comm_no, data }
            | BinaryRequestBody::ReadDummy { comm_no, dummy: data } => {
                w.word(comm_no.0);
                w.word(data);
            }
            BinaryRequestBody::Block(b) => {
                N_W.emit(b.n_w as usize)?;
                w.push(b.n_w);
                w.push(b.n_r);
                for &d in b.wdata() {
                    w.word(d);
                }
            }
        }
        w.finish(out)
    }
}

/// What a reply carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BinaryReplyBody {
    /// `R`/`W`/`P`/`G` echoed with COMNO and DATA (the value read, or written).
    Data {
        /// CMD of the request.
        cmd: Cmd,
        /// COMNO of the request.
        comm_no: CommNo,
        /// DATA.
        data: u16,
    },
    /// `Y`: the read groups of a block request.
    Block(BlockReply),
    /// `N` (4EH, `n` 6EH while tripped) and the error code.
    Error(ErrorCode),
}

/// A reply, inverter to master.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct BinaryReply {
    /// INV-NO: the inverter's number when the request carried one.
    pub inv_no: Option<u8>,
    /// CMD + 20H: the inverter is tripped.
    pub tripped: bool,
    /// Data, block data or error.
    pub body: BinaryReplyBody,
}

impl BinaryReply {
    /// The data carried by an `R`/`W`/`P`/`G` reply.
    pub fn data(&self) -> Option<u16> {
        match self.body {
            BinaryReplyBody::Data { data, .. } => Some(data),
            _ => None,
        }
    }

    /// The error code of an error reply.
    pub fn error(&self) -> Option<ErrorCode> {
        match self.body {
            BinaryReplyBody::Error(e) => Some(e),
            _ => None,
        }
    }

    /// The data in Hz, when the communication number is a 0.01 Hz value.
    pub fn hz(&self) -> Option<f64> {
        match self.body {
            BinaryReplyBody::Data { comm_no, data, .. } => comm_no.hz(data),
            _ => None,
        }
    }

    /// The data in its unit, where the communication number has one.
    pub fn value(&self) -> Option<f64> {
        match self.body {
            BinaryReplyBody::Data { comm_no, data, .. } => comm_no.value(data),
            _ => None,
        }
    }

    /// Reads a whole reply frame (`W`/`P`/`G` read as replies).
    pub fn parse(bytes: &[u8]) -> Result<Self, FrameError> {
        match parse_frame(bytes, Some(Direction::Drive)).map_err(|f| f.error)? {
            BinaryFrame::Reply(r) => Ok(r),
            BinaryFrame::Request(_) => {
                Err(FrameError::Malformed("a master's request (R without DATA, or X), not a reply"))
            }
        }
    }

    /// Writes the frame into `out`; returns its length.
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, EmitError> {
        let inv = match self.inv_no {
            Some(n) => Some(unit_byte(n)?),
            None => None,
        };
        let mut w = Writer::new(inv);
        let case = if self.tripped { 0x20 } else { 0 };
        match self.body {
            BinaryReplyBody::Data { cmd, comm_no, data } => {
                w.push(cmd.letter() | case);
                w.word(comm_no.0);
                w.word(data);
            }
            BinaryReplyBody::Block(b) => {
                N_R.emit(b.n_r as usize)?;
                w.push(BLOCK_REPLY | case);
                w.push(b.n_r);
                for &d in b.rdata() {
                    w.word(d);
                }
            }
            BinaryReplyBody::Error(code) => {
                w.push(ERROR_LETTER | case);
                w.word(code.0);
            }
        }
        w.finish(out)
    }
}

/// Builds a frame in a local buffer (never more than [`MAX_FRAME`] bytes).
struct Writer {
    buf: [u8; MAX_FRAME],
    len: usize,
}

impl Writer {
    fn new(inv: Option<u8>) -> Self {
        let mut w = Writer { buf: [0; MAX_FRAME], len: 0 };
        w.push(START);
        if let Some(n) = inv {
            w.push(n);
        }
        w
    }

    fn push(&mut self, b: u8) {
        if let Some(slot) = self.buf.get_mut(self.len) {
            *slot = b;
            self.len += 1;
        }
    }

    fn word(&mut self, v: u16) {
        let [h, l] = v.to_be_bytes();
        self.push(h);
        self.push(l);
    }

    fn finish(mut self, out: &mut [u8]) -> Result<usize, EmitError> {
        // manual: SUM = the sum of the bytes from 2F through the last data byte; not omissible.
        let s = sum8(&self.buf[..self.len]);
        self.push(s);
        need(out, self.len)?;
        out[..self.len].copy_from_slice(&self.buf[..self.len]);
        Ok(self.len)
    }
}

/// A frame in either direction.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BinaryFrame {
    /// From the master.
    Request(BinaryRequest),
    /// From an inverter.
    Reply(BinaryReply),
}

impl BinaryFrame {
    /// Reads a whole frame; `from` decides only for `W`/`P`/`G`, whose request and reply look
    /// alike (default: master).
    pub fn parse(bytes: &[u8], from: Option<Direction>) -> Result<Self, FrameError> {
        parse_frame(bytes, from).map_err(|f| f.error)
    }

    /// Writes the frame into `out`; returns its length.
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, EmitError> {
        match self {
            BinaryFrame::Request(r) => r.emit(out),
            BinaryFrame::Reply(r) => r.emit(out),
        }
    }
}
