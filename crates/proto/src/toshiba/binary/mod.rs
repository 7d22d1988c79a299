//! TIP binary mode. `seeds/002_43d8a4399c8be05f.txt` names it; the frame is in protocols.md 1.5–1.7,
//! from the public VF-AS1 (p.10–17) and VF-S11 (p.7, p.15) manuals.
//!
//! ```text
//! 2F [INV-NO] CMD COMNO:2 [DATA:2] SUM                 R (no DATA), W, P, G (dummy DATA)
//! 2F [INV-NO] 58 nW nR [WDATA1:2] [WDATA2:2] SUM       X block communication
//! 2F [INV-NO] 59 nR RDATA1..RDATAn:2 SUM               Y block reply (project decision)
//! 2F [INV-NO] 4E ERROR:2 SUM                           N error reply
//! ```
//!
//! - INV-NO: one byte 00–3F, FF = broadcast (every inverter acts, only 00 answers), or omitted
//!   on a 1:1 link. It is told apart from CMD by value: INV-NO is at most 3F or FF, every
//!   command is 47H or more.
//! - SUM: the 8-bit sum of the bytes from 2F through the last data byte; it is not omissible.
//! - A tripped inverter answers with CMD + 20H (`r` 72H, `w`, `p`, `g`, `y`, `n` 6EH).
//! - A drive answers only a checksum error with an error reply (`2F 4E 00 04 81`); command
//!   errors, format errors and other inverters' numbers get no reply (protocols.md 1.6).
//!
//! Receiving (manual VF-S11 p.7): everything before 2F is ignored; if 2F comes more than once,
//! the last one counts; the frame is complete once the command's byte count is in. 2F is also
//! an ordinary data byte, so [`BinaryScanner`] applies the "last 2F" rule only where the later
//! 2F starts a whole frame with a good SUM, and otherwise keeps the first 2F.

use crate::checksum::sum8;
use crate::codec::Codec;
use crate::deframe::{Scan, Scanner};
use crate::describe::{CodeStyle, Command, Describe, Direction, Field, Target};
use crate::error::{need, ChecksumKind, EmitError, FrameError};
use crate::session::{Disposition, Protocol};

use super::ascii::tripped_field;
use super::{
    describe_value, prefix_hint, Cmd, CommNo, ErrorCode, BLOCK_READ_DEFAULTS, BLOCK_WRITE_DEFAULTS,
    ERROR_LETTER,
};

/// Start code 2FH (`/`).
pub const START: u8 = 0x2F;
/// INV-NO for every inverter.
pub const BROADCAST: u8 = 0xFF;
/// The greatest inverter number binary mode carries (3FH = 63).
pub const MAX_INV_NO: u8 = 0x3F;
/// `X` (58H): block communication.
pub const BLOCK: u8 = b'X';
/// `Y` (59H): block communication reply.
pub const BLOCK_REPLY: u8 = b'Y';
/// The most write groups of a block request (nW); more is a format error.
pub const MAX_WRITE_GROUPS: u8 = 2;
/// The most read groups of a block request (nR); more gives a reply with none.
pub const MAX_READ_GROUPS: u8 = 5;
/// The longest binary-mode frame: a Y reply with INV-NO and 5 read groups, 15 bytes.
pub const MAX_FRAME: usize = 15;

/// INV-NO of a request.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BinaryAddress {
    /// No INV-NO (a 1:1 link).
    Omitted,
    /// One inverter, 00–3F.
    Unit(u8),
    /// FF: every inverter acts; inverter 00 answers.
    Broadcast,
}

impl BinaryAddress {
    /// How inverter `me` treats a request with this INV-NO.
    pub const fn disposition(self, me: u8) -> Disposition {
        match self {
            BinaryAddress::Omitted => Disposition::Mine,
            BinaryAddress::Unit(n) if n == me => Disposition::Mine,
            BinaryAddress::Unit(_) => Disposition::NotMine,
            // manual: "only the inverter numbered 00H replies" to a broadcast.
            BinaryAddress::Broadcast => Disposition::Broadcast { reply: me == 0 },
        }
    }

    /// The INV-NO the reply carries (a broadcast is answered by inverter 00).
    pub const fn reply_inv_no(self) -> Option<u8> {
        match self {
            BinaryAddress::Omitted => None,
            BinaryAddress::Unit(n) => Some(n),
            BinaryAddress::Broadcast => Some(0),
        }
    }

    /// The address for [`Describe`].
    pub const fn target(self) -> Target {
        match self {
            BinaryAddress::Omitted => Target::Implicit,
            BinaryAddress::Unit(n) => Target::Unit(n),
            BinaryAddress::Broadcast => Target::Broadcast,
        }
    }

    fn from_byte(b: Option<u8>) -> Self {
        match b {
            None => BinaryAddress::Omitted,
            Some(BROADCAST) => BinaryAddress::Broadcast,
            Some(n) => BinaryAddress::Unit(n),
        }
    }

    fn byte(self) -> Result<Option<u8>, EmitError> {
        match self {
            BinaryAddress::Omitted => Ok(None),
            BinaryAddress::Unit(n) => unit_byte(n).map(Some),
            BinaryAddress::Broadcast => Ok(Some(BROADCAST)),
        }
    }
}

fn unit_byte(n: u8) -> Result<u8, EmitError> {
    if n > MAX_INV_NO {
        return Err(EmitError::OutOfRange {
            field: "INV-NO",
            value: n as u32,
            min: 0,
            max: MAX_INV_NO as u32,
        });
    }
    Ok(n)
}

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
        if wdata.len() > MAX_WRITE_GROUPS as usize {
            return Err(EmitError::OutOfRange {
                field: "nW (number of write data groups)",
                value: wdata.len() as u32,
                min: 0,
                max: MAX_WRITE_GROUPS as u32,
            });
        }
        let mut w = [0; 2];
        w[..wdata.len()].copy_from_slice(wdata);
        Ok(BlockRequest { n_w: wdata.len() as u8, n_r, wdata: w })
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
        if rdata.len() > MAX_READ_GROUPS as usize {
            return Err(EmitError::OutOfRange {
                field: "nR (number of read data groups)",
                value: rdata.len() as u32,
                min: 0,
                max: MAX_READ_GROUPS as u32,
            });
        }
        let mut r = [0; 5];
        r[..rdata.len()].copy_from_slice(rdata);
        Ok(BlockReply { n_r: rdata.len() as u8, rdata: r })
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
                if b.n_w > MAX_WRITE_GROUPS {
                    return Err(EmitError::OutOfRange {
                        field: "nW (number of write data groups)",
                        value: b.n_w as u32,
                        min: 0,
                        max: MAX_WRITE_GROUPS as u32,
                    });
                }
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
                if b.n_r > MAX_READ_GROUPS {
                    return Err(EmitError::OutOfRange {
                        field: "nR (number of read data groups)",
                        value: b.n_r as u32,
                        min: 0,
                        max: MAX_READ_GROUPS as u32,
                    });
                }
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

/// INV-NO (if any), CMD and the bytes through CMD.
struct Head {
    inv: Option<u8>,
    cmd: u8,
    /// Bytes from 2F through CMD.
    base: usize,
}

/// Reads INV-NO and CMD; `None` until they are in.
fn head(buf: &[u8]) -> Option<Head> {
    let b1 = *buf.get(1)?;
    // INV-NO is 00-3F or FF; every command is 47H or more.
    let (inv, cmd_at) = if b1 <= MAX_INV_NO || b1 == BROADCAST { (Some(b1), 2) } else { (None, 1) };
    let cmd = *buf.get(cmd_at)?;
    Some(Head { inv, cmd, base: cmd_at + 1 })
}

/// How long a frame with this head is.
#[derive(Clone, Copy)]
enum Shape {
    /// One length for either direction.
    Fixed(usize),
    /// `R`: the request has no DATA, the reply has.
    Read { request: usize, reply: usize },
}

/// The frame's shape; `Ok(None)` until the count byte of X/Y is in.
fn shape(buf: &[u8], h: &Head) -> Result<Option<Shape>, FrameError> {
    let base = h.base;
    Ok(Some(match h.cmd {
        b'R' => Shape::Read { request: base + 3, reply: base + 5 },
        b'r' | b'W' | b'w' | b'P' | b'p' | b'G' | b'g' => Shape::Fixed(base + 5),
        b'N' | b'n' => Shape::Fixed(base + 3),
        BLOCK => {
            let Some(&n_w) = buf.get(base) else { return Ok(None) };
            // manual: nW out of range is a format error (no reply).
            if n_w > MAX_WRITE_GROUPS {
                return Err(FrameError::OutOfRange {
                    field: "nW (number of write data groups)",
                    value: n_w as u32,
                    min: 0,
                    max: MAX_WRITE_GROUPS as u32,
                });
            }
            Shape::Fixed(base + 3 + 2 * n_w as usize)
        }
        b'Y' | b'y' => {
            let Some(&n_r) = buf.get(base) else { return Ok(None) };
            if n_r > MAX_READ_GROUPS {
                return Err(FrameError::OutOfRange {
                    field: "nR (number of read data groups)",
                    value: n_r as u32,
                    min: 0,
                    max: MAX_READ_GROUPS as u32,
                });
            }
            Shape::Fixed(base + 2 + 2 * n_r as usize)
        }
        // manual: "Any other command is rejected" (binary mode: no reply).
        other => return Err(FrameError::Unknown { field: "binary-mode CMD", value: other as u32 }),
    }))
}

/// One candidate at the start of `buf`, without looking further.
enum Check {
    Frame(usize),
    NeedMore,
    Bad { len: usize, error: FrameError },
}

#[inline]
fn sum_ok(buf: &[u8], len: usize) -> bool {
    match (buf.get(..len - 1), buf.get(len - 1)) {
        (Some(covered), Some(&carried)) => sum8(covered) == carried,
        _ => false,
    }
}

fn mismatch(buf: &[u8], len: usize) -> Check {
    let covered = &buf[..len - 1];
    let carried = buf[len - 1];
    let computed = sum8(covered);
    Check::Bad {
        len,
        error: FrameError::ChecksumMismatch {
            kind: ChecksumKind::Sum,
            carried: carried as u16,
            computed: computed as u16,
            hint: prefix_hint(covered, carried),
        },
    }
}

#[inline]
fn check(buf: &[u8], from: Option<Direction>) -> Check {
    let Some(h) = head(buf) else { return Check::NeedMore };
    let shape = match shape(buf, &h) {
        Ok(Some(s)) => s,
        Ok(None) => return Check::NeedMore,
        Err(error) => {
            let len = if h.cmd == BLOCK || h.cmd | 0x20 == b'y' { h.base + 1 } else { h.base };
            return Check::Bad { len, error };
        }
    };
    let n = buf.len();
    match shape {
        Shape::Fixed(len) => {
            if n < len {
                Check::NeedMore
            } else if sum_ok(buf, len) {
                Check::Frame(len)
            } else {
                mismatch(buf, len)
            }
        }
        // R: 5 bytes from the master, 7 from a drive (plus INV-NO). A scanner for one
        // direction waits for that length and takes the other only if it checks out too.
        Shape::Read { request, reply } => match from {
            Some(Direction::Master) => {
                if n < request {
                    Check::NeedMore
                } else if sum_ok(buf, request) {
                    Check::Frame(request)
                } else if n >= reply && sum_ok(buf, reply) {
                    Check::Frame(reply)
                } else {
                    mismatch(buf, request)
                }
            }
            Some(Direction::Drive) => {
                if n < reply {
                    Check::NeedMore
                } else if sum_ok(buf, reply) {
                    Check::Frame(reply)
                } else if sum_ok(buf, request) {
                    Check::Frame(request)
                } else {
                    mismatch(buf, reply)
                }
            }
            None => {
                if n < request {
                    Check::NeedMore
                } else if sum_ok(buf, request) {
                    Check::Frame(request)
                } else if n < reply {
                    Check::NeedMore
                } else if sum_ok(buf, reply) {
                    Check::Frame(reply)
                } else {
                    mismatch(buf, request)
                }
            }
        },
    }
}

/// The offset of a later start code, before `end`, that begins a whole frame with a good
/// checksum (manual VF-S11 p.7: "If 2F arrives more than once, the last 2F counts").
fn later_frame(buf: &[u8], end: usize, from: Option<Direction>, tip: bool) -> Option<usize> {
    let end = end.min(buf.len());
    (1..end).find(|&p| match buf[p] {
        START => matches!(check(&buf[p..], from), Check::Frame(_)),
        // An ASCII frame without SUM has no check: it must at least parse.
        super::ascii::START if tip => match super::ascii::scan_ascii(&buf[p..], 0, true) {
            Scan::Frame { len } => {
                buf.get(p..p + len).is_some_and(|f| super::ascii::parse_frame(f, None).is_ok())
            }
            _ => false,
        },
        _ => false,
    })
}

/// Scans for a binary-mode frame; `tip`: the line also carries ASCII mode, so `(` is a start code.
#[inline]
pub(crate) fn scan_binary(buf: &[u8], from: Option<Direction>, tip: bool) -> Scan {
    if buf.first() != Some(&START) {
        // manual: everything before 2F is ignored.
        return Scan::Noise { len: next_start(buf, tip) };
    }
    match check(buf, from) {
        Check::Frame(len) => Scan::Frame { len },
        Check::NeedMore => match later_frame(buf, buf.len(), from, tip) {
            Some(p) => Scan::Noise { len: p },
            None => Scan::Incomplete { checked: 0 },
        },
        Check::Bad { len, error } => match later_frame(buf, len, from, tip) {
            Some(p) => Scan::Noise { len: p },
            None => Scan::Invalid { len: len.min(buf.len()).max(1), skip: 1, error },
        },
    }
}

/// Bytes before the next start code (2F, and `(` on a line that carries both modes).
fn next_start(buf: &[u8], tip: bool) -> usize {
    buf.iter()
        .skip(1)
        .position(|&b| b == START || (tip && b == super::ascii::START))
        .map_or(buf.len(), |p| p + 1)
}

/// The expected length of the candidate at the start of `buf`, for messages.
fn expected_len(buf: &[u8], from: Option<Direction>) -> usize {
    let fallback = buf.len() + 1;
    let Some(h) = head(buf) else { return fallback };
    match shape(buf, &h) {
        Ok(Some(Shape::Fixed(len))) => len,
        Ok(Some(Shape::Read { request, reply })) => match from {
            Some(Direction::Drive) => reply,
            _ if buf.len() < request => request,
            _ => reply,
        },
        _ => fallback,
    }
}

/// The deframer's scanner for binary mode. `from` says whose frames it reads: the length of
/// `R` differs (5 bytes from the master, 7 from a drive, plus INV-NO); with `None` it takes
/// whichever checks out.
#[derive(Clone, Copy, Debug, Default)]
pub struct BinaryScanner {
    /// Whose frames: `Some(Master)` for a drive, `Some(Drive)` for a master, `None` for a monitor.
    pub from: Option<Direction>,
}

impl Scanner for BinaryScanner {
    type Buffer = [u8; MAX_FRAME];

    #[inline]
    fn scan(&self, buf: &[u8], _checked: usize) -> Scan {
        scan_binary(buf, self.from, false)
    }

    fn truncated(&self, buf: &[u8]) -> FrameError {
        truncated(buf, self.from)
    }
}

pub(crate) fn truncated(buf: &[u8], from: Option<Direction>) -> FrameError {
    FrameError::Truncated { what: "a binary-mode frame", expected: expected_len(buf, from), got: buf.len() }
}

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
struct Fault {
    error: FrameError,
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

fn parse_frame(bytes: &[u8], from: Option<Direction>) -> Result<BinaryFrame, Fault> {
    let n = bytes.len();
    let Some(&first) = bytes.first() else {
        return Err(FrameError::Truncated { what: "a binary-mode frame", expected: 5, got: 0 }.into());
    };
    if first != START {
        return Err(FrameError::Unknown { field: "start code", value: first as u32 }.into());
    }
    let truncated = |expected| FrameError::Truncated { what: "a binary-mode frame", expected, got: n };
    let Some(h) = head(bytes) else { return Err(truncated(5).into()) };
    let Some(shape) = shape(bytes, &h)? else { return Err(truncated(h.base + 3).into()) };
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
        return Err(FrameError::Truncated { what, expected: len, got: n }.into());
    }
    if n > len {
        return Err(FrameError::TooLong { what, max: len, got: n }.into());
    }
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
    let body = match h.cmd & !0x20 {
        ERROR_LETTER => BinaryReplyBody::Error(ErrorCode(word(bytes, b))),
        BLOCK_REPLY => {
            let n_r = bytes.get(b).copied().unwrap_or(0);
            let mut rdata = [0u16; 5];
            for (i, slot) in rdata.iter_mut().enumerate().take(n_r as usize) {
                *slot = word(bytes, b + 1 + 2 * i);
            }
            BinaryReplyBody::Block(BlockReply { n_r, rdata })
        }
        letter => match Cmd::from_letter(letter) {
            Some((cmd, _)) => {
                BinaryReplyBody::Data { cmd, comm_no: CommNo(word(bytes, b)), data: word(bytes, b + 2) }
            }
            None => return Err(FrameError::Unknown { field: "binary-mode CMD", value: h.cmd as u32 }.into()),
        },
    };
    Ok(BinaryFrame::Reply(BinaryReply { inv_no, tripped, body }))
}

/// What a drive answers to a request frame it rejected; `None`: silence.
fn rejection(bytes: &[u8]) -> Option<(BinaryAddress, ErrorCode)> {
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

/// What a reply must carry to answer a request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Expect {
    /// An `R`/`W`/`P`/`G` reply with this command and COMNO.
    Data {
        /// CMD of the request.
        cmd: Cmd,
        /// COMNO of the request.
        comm_no: CommNo,
    },
    /// A `Y` reply.
    Block,
}

/// What a reply to a binary request must match.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BinaryPending {
    /// INV-NO the reply carries.
    pub inv_no: Option<u8>,
    /// The kind of reply.
    pub expect: Expect,
}

impl BinaryPending {
    /// Whether `rep` answers the request.
    pub fn matches(&self, rep: &BinaryReply) -> bool {
        rep.inv_no == self.inv_no
            && match (rep.body, self.expect) {
                (BinaryReplyBody::Error(_), _) => true,
                (BinaryReplyBody::Data { cmd, comm_no, .. }, Expect::Data { cmd: c, comm_no: n }) => {
                    cmd == c && comm_no == n
                }
                (BinaryReplyBody::Block(_), Expect::Block) => true,
                _ => false,
            }
    }
}

/// TIP binary mode as a [`Protocol`] for masters and single-mode drives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TipBinary {
    /// Whether the master waits for inverter 00's reply to a broadcast (FF), as the manual
    /// says; set to false when there is no inverter 00: broadcasts then get no reply.
    pub broadcast_reply: bool,
}

impl Default for TipBinary {
    fn default() -> Self {
        TipBinary { broadcast_reply: true }
    }
}

impl TipBinary {
    /// What a reply to `req` must match; `None` when no reply is due.
    pub fn pending(&self, req: &BinaryRequest) -> Option<BinaryPending> {
        if req.inv_no == BinaryAddress::Broadcast && !self.broadcast_reply {
            return None;
        }
        let expect = match (req.body.cmd(), req.body.comm_no()) {
            (Some(cmd), Some(comm_no)) => Expect::Data { cmd, comm_no },
            _ => Expect::Block,
        };
        Some(BinaryPending { inv_no: req.inv_no.reply_inv_no(), expect })
    }

    /// How inverter `me` treats a request frame that did not parse: a checksum error
    /// addressed to it is answered (0004), anything else is not.
    pub fn rejected_disposition(&self, bytes: &[u8], me: u8) -> Disposition {
        match rejection(bytes) {
            Some((inv_no, _)) => inv_no.disposition(me),
            None => Disposition::NotMine,
        }
    }
}

impl Protocol for TipBinary {
    type ReplyScanner = BinaryScanner;
    type RequestScanner = BinaryScanner;
    type Request<'a> = BinaryRequest;
    type Reply<'a> = BinaryReply;
    type Pending = BinaryPending;

    fn reply_scanner(&self) -> BinaryScanner {
        BinaryScanner { from: Some(Direction::Drive) }
    }
    fn request_scanner(&self) -> BinaryScanner {
        BinaryScanner { from: Some(Direction::Master) }
    }
    fn emit_request(&self, req: &BinaryRequest, out: &mut [u8]) -> Result<usize, EmitError> {
        req.emit(out)
    }
    fn emit_reply(&self, rep: &BinaryReply, out: &mut [u8]) -> Result<usize, EmitError> {
        rep.emit(out)
    }
    fn parse_request(&self, bytes: &[u8]) -> Result<BinaryRequest, FrameError> {
        BinaryRequest::parse(bytes)
    }
    fn parse_reply(&self, bytes: &[u8]) -> Result<BinaryReply, FrameError> {
        BinaryReply::parse(bytes)
    }
    fn pending(&self, req: &BinaryRequest) -> Option<BinaryPending> {
        TipBinary::pending(self, req)
    }
    fn matches(&self, pending: &BinaryPending, rep: &BinaryReply) -> bool {
        pending.matches(rep)
    }
    fn disposition(&self, req: &BinaryRequest, me: u8) -> Disposition {
        req.inv_no.disposition(me)
    }
    fn rejected_disposition(&self, bytes: &[u8], _error: &FrameError, me: u8) -> Disposition {
        TipBinary::rejected_disposition(self, bytes, me)
    }
}

/// The `toshiba-binary` codec.
#[derive(Clone, Copy, Debug, Default)]
pub struct BinaryCodec;

impl Codec for BinaryCodec {
    const NAME: &'static str = "toshiba-binary";
    type Scanner = BinaryScanner;
    type Frame<'a> = BinaryFrame;

    fn scanner(from: Option<Direction>) -> BinaryScanner {
        BinaryScanner { from }
    }

    fn parse(bytes: &[u8], from: Option<Direction>) -> Result<BinaryFrame, FrameError> {
        BinaryFrame::parse(bytes, from)
    }
}

const RDATA_NAMES: [&str; 5] = ["RDATA1", "RDATA2", "RDATA3", "RDATA4", "RDATA5"];
const WDATA_NAMES: [&str; 2] = ["WDATA1", "WDATA2"];

fn command_of(code: u8) -> Command {
    let name = match code & !0x20 {
        b'R' => Cmd::R.name(),
        b'W' => Cmd::W.name(),
        b'P' => Cmd::P.name(),
        b'G' => Cmd::G.name(),
        BLOCK => "block communication",
        BLOCK_REPLY => "block communication reply",
        _ => "error reply",
    };
    Command { code, style: CodeStyle::Letter, name }
}

impl Describe for BinaryFrame {
    fn direction(&self) -> Direction {
        match self {
            BinaryFrame::Request(_) => Direction::Master,
            BinaryFrame::Reply(_) => Direction::Drive,
        }
    }

    fn target(&self) -> Target {
        match self {
            BinaryFrame::Request(r) => r.inv_no.target(),
            BinaryFrame::Reply(r) => r.inv_no.map_or(Target::Implicit, Target::Unit),
        }
    }

    fn command(&self) -> Command {
        match self {
            BinaryFrame::Request(r) => command_of(r.body.code()),
            BinaryFrame::Reply(r) => {
                let case = if r.tripped { 0x20 } else { 0 };
                let code = match r.body {
                    BinaryReplyBody::Data { cmd, .. } => cmd.letter(),
                    BinaryReplyBody::Block(_) => BLOCK_REPLY,
                    BinaryReplyBody::Error(_) => ERROR_LETTER,
                };
                command_of(code | case)
            }
        }
    }

    fn is_refusal(&self) -> bool {
        matches!(self, BinaryFrame::Reply(BinaryReply { body: BinaryReplyBody::Error(_), .. }))
    }

    fn fields(&self, out: &mut dyn FnMut(Field<'_>)) {
        match self {
            BinaryFrame::Request(r) => {
                match r.inv_no {
                    BinaryAddress::Omitted => {}
                    BinaryAddress::Unit(n) => out(Field::hex("INV-NO", n as u32, 2)),
                    BinaryAddress::Broadcast => out(Field::hex("INV-NO", BROADCAST as u32, 2)
                        .with_meaning("broadcast: inverter 00 answers")),
                }
                match r.body {
                    BinaryRequestBody::Read { comm_no } => out(comm_no.field()),
                    BinaryRequestBody::Write { comm_no, data }
                    | BinaryRequestBody::WriteRam { comm_no, data } => {
                        out(comm_no.field());
                        comm_no.describe_data("data", data, out);
                    }
                    BinaryRequestBody::ReadDummy { comm_no, dummy } => {
                        out(comm_no.field());
                        out(Field::hex("dummy data", dummy as u32, 4));
                    }
                    BinaryRequestBody::Block(b) => {
                        out(Field::dec("nW", b.n_w as i64));
                        let n_r = Field::dec("nR", b.n_r as i64);
                        out(if b.n_r > MAX_READ_GROUPS {
                            n_r.with_meaning("more than 5: the reply carries no read data")
                        } else {
                            n_r
                        });
                        for ((&d, name), comm_no) in
                            b.wdata().iter().zip(WDATA_NAMES).zip(BLOCK_WRITE_DEFAULTS)
                        {
                            comm_no.describe_data(name, d, out);
                        }
                    }
                }
            }
            BinaryFrame::Reply(r) => {
                if let Some(n) = r.inv_no {
                    out(Field::hex("INV-NO", n as u32, 2));
                }
                out(tripped_field(r.tripped));
                match r.body {
                    BinaryReplyBody::Data { comm_no, data, .. } => {
                        out(comm_no.field());
                        describe_value(comm_no.format(), "data", data, 4, out);
                    }
                    BinaryReplyBody::Block(b) => {
                        out(Field::dec("nR", b.n_r as i64));
                        for ((&d, name), comm_no) in
                            b.rdata().iter().zip(RDATA_NAMES).zip(BLOCK_READ_DEFAULTS)
                        {
                            comm_no.describe_data(name, d, out);
                        }
                    }
                    BinaryReplyBody::Error(code) => out(code.field()),
                }
            }
        }
        let mut buf = [0u8; MAX_FRAME];
        if let Ok(n) = self.emit(&mut buf) {
            out(Field::hex("SUM", buf[n - 1] as u32, 2));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::deframe::{Deframer, Event};
    use std::string::{String, ToString};
    use std::vec::Vec;

    fn emit(f: &BinaryFrame) -> Vec<u8> {
        let mut b = [0u8; 32];
        let n = f.emit(&mut b).unwrap();
        b[..n].to_vec()
    }

    fn describe(f: &BinaryFrame) -> String {
        let mut s = String::new();
        f.fields(&mut |fl| {
            if !s.is_empty() {
                s.push_str(", ");
            }
            s.push_str(&fl.to_string());
        });
        s
    }

    type Rejections = Vec<(Vec<u8>, FrameError)>;

    fn run(from: Option<Direction>, chunks: &[&[u8]]) -> (Vec<Vec<u8>>, Rejections) {
        let mut d = Deframer::new(BinaryScanner { from });
        let (mut good, mut bad) = (Vec::new(), Vec::new());
        for c in chunks {
            d.push(c, &mut |e| match e {
                Event::Frame { bytes, .. } => good.push(bytes.to_vec()),
                Event::Rejected { bytes, error, .. } => bad.push((bytes.to_vec(), error)),
            });
        }
        (good, bad)
    }

    /// TB1: `2F 52 00 00 81`, R comm-no 0000 (manual VF-AS1 p.10).
    #[test]
    fn tb1_read() {
        let wire = [
            0x2F, // start code
            0x52, // 'R' (INV-NO omitted: 52H > 3FH is a command)
            0x00, 0x00, // COMNO 0000
            0x81, // SUM = 2F + 52 + 00 + 00
        ];
        let req = BinaryRequest::read(BinaryAddress::Omitted, CommNo(0));
        assert_eq!(emit(&BinaryFrame::Request(req)), wire);
        assert_eq!(BinaryRequest::parse(&wire), Ok(req));
        let f = BinaryCodec::parse(&wire, Some(Direction::Drive)).unwrap();
        assert_eq!(f, BinaryFrame::Request(req), "5-byte R is a request whatever `from` says");
        assert_eq!(f.command().to_string(), "R read");
        assert_eq!(f.target(), Target::Implicit);
        assert_eq!(describe(&f), "communication number 0000, SUM 81");
        for from in [None, Some(Direction::Master)] {
            assert_eq!(run(from, &[&wire]).0, [wire.to_vec()], "{from:?}");
        }
        // A master's reply scanner waits for the 7 bytes of a reply before it takes a request.
        assert!(run(Some(Direction::Drive), &[&wire]).0.is_empty());
        let two: Vec<u8> = wire.iter().chain(&wire).copied().collect();
        assert_eq!(run(Some(Direction::Drive), &[&two]).0, [wire.to_vec()]);
    }

    /// TB2: `2F 57 00 10 00 64 FA`, W deceleration time = 100 (10.0 s); the reply is identical.
    #[test]
    fn tb2_write_echo() {
        let wire = [
            0x2F, // start code
            0x57, // 'W' write RAM and EEPROM
            0x00, 0x10, // COMNO 0010 deceleration time
            0x00, 0x64, // DATA 100 = 10.0 s
            0xFA, // SUM
        ];
        let req = BinaryRequest::write(BinaryAddress::Omitted, CommNo::DECELERATION_TIME, 100);
        assert_eq!(emit(&BinaryFrame::Request(req)), wire);
        assert_eq!(BinaryCodec::parse(&wire, None), Ok(BinaryFrame::Request(req)));
        let rep = req.reply(0, false, 100).unwrap();
        assert_eq!(emit(&BinaryFrame::Reply(rep)), wire);
        assert_eq!(BinaryReply::parse(&wire), Ok(rep));
        assert_eq!(rep.value(), Some(10.0));
        assert_eq!(
            describe(&BinaryFrame::Reply(rep)),
            "tripped 0, communication number 0010 (deceleration time), data 0064 = 10.0 s, SUM FA"
        );
        assert!(TipBinary::default().pending(&req).unwrap().matches(&rep));
    }

    /// TB9–TB12: the manual's error replies (VF-S11 p.15).
    #[test]
    fn tb9_to_tb12_error_replies() {
        for (wire, code, name) in [
            ([0x2F, 0x4E, 0x00, 0x00, 0x7D], 0, "impossible to execute"), // TB9
            ([0x2F, 0x4E, 0x00, 0x01, 0x7E], 1, "data error"),            // TB10
            ([0x2F, 0x4E, 0x00, 0x02, 0x7F], 2, "communication number error"), // TB11
            ([0x2F, 0x4E, 0x00, 0x04, 0x81], 4, "checksum error"),        // TB12
        ] {
            // 2F start, 4E 'N' error, 2-byte error code, SUM.
            let rep =
                BinaryReply { inv_no: None, tripped: false, body: BinaryReplyBody::Error(ErrorCode(code)) };
            assert_eq!(emit(&BinaryFrame::Reply(rep)), wire);
            let f = BinaryCodec::parse(&wire, None).unwrap();
            assert_eq!(f, BinaryFrame::Reply(rep));
            assert!(f.is_refusal());
            assert_eq!(
                describe(&f),
                std::format!("tripped 0, error code 000{code} ({name}), SUM {:02X}", wire[4])
            );
            assert_eq!(run(Some(Direction::Drive), &[&wire]).0, [wire.to_vec()]);
        }
        // Tripped: 6E.
        let rep = BinaryReply::parse(&[0x2F, 0x6E, 0x00, 0x00, 0x9D]).unwrap();
        assert!(rep.tripped);
        assert_eq!(rep.error(), Some(ErrorCode::IMPOSSIBLE_TO_EXECUTE));
    }

    /// TB14: block write with a wrong SUM (D8, the correct one is D9): the drive answers
    /// `2F 4E 00 04 81` (manual VF-AS1 p.16).
    #[test]
    fn tb14_block_checksum_error() {
        let wire = [
            0x2F, // start code
            0x58, // 'X' block communication
            0x02, // nW: 2 write groups
            0x05, // nR: 5 read groups
            0xC4, 0x00, // WDATA1 -> FA00: command priority, frequency priority, run
            0x17, 0x70, // WDATA2 -> FA01: 6000 = 60.00 Hz
            0xD8, // SUM as printed; 2F+58+02+05+C4+00+17+70 = 2D9 -> D9
        ];
        let (good, bad) = run(Some(Direction::Master), &[&wire]);
        assert!(good.is_empty());
        assert_eq!(bad[0].0, wire);
        assert_eq!(bad[0].1.to_string(), "SUM mismatch: frame carries D8, computed D9");
        assert_eq!(TipBinary::default().rejected_disposition(&wire, 0), Disposition::Mine);
        let rep = rejection_reply(&wire, 0, false).unwrap();
        assert_eq!(emit(&BinaryFrame::Reply(rep)), [0x2F, 0x4E, 0x00, 0x04, 0x81]);

        let mut fixed = wire;
        fixed[8] = 0xD9;
        let req = BinaryRequest::parse(&fixed).unwrap();
        let block = BlockRequest::new(&[0xC400, 0x1770], 5).unwrap();
        assert_eq!(req, BinaryRequest::block(BinaryAddress::Omitted, block));
        assert_eq!(emit(&BinaryFrame::Request(req)), fixed);
        assert_eq!(
            describe(&BinaryFrame::Request(req)),
            "nW 2, nR 5, WDATA1 C400, command priority 1, frequency priority 1, run 1, WDATA2 1770 = 60.00 Hz, SUM D9"
        );
        assert_eq!(BinaryFrame::Request(req).command().to_string(), "X block communication");
    }

    #[test]
    fn block_reply() {
        let req = BinaryRequest::block(BinaryAddress::Unit(1), BlockRequest::new(&[], 5).unwrap());
        let rep = req.block_reply(1, false, &[0x0400, 0x1770, 0x077B, 0x0000, 0x2710]).unwrap();
        let bytes = emit(&BinaryFrame::Reply(rep));
        // 2F, INV-NO 01, 'Y', nR 5, five words, SUM.
        assert_eq!(bytes[..4], [0x2F, 0x01, 0x59, 0x05]);
        assert_eq!(bytes.len(), 15);
        assert_eq!(bytes.len(), MAX_FRAME);
        assert_eq!(BinaryReply::parse(&bytes), Ok(rep));
        assert!(TipBinary::default().pending(&req).unwrap().matches(&rep));
        assert_eq!(
            describe(&BinaryFrame::Reply(rep)),
            std::format!(
                "INV-NO 01, tripped 0, nR 5, RDATA1 0400, running 1, RDATA2 1770 = 60.00 Hz, \
                 RDATA3 077B = 19.15 %, RDATA4 0000, RDATA5 2710 = 100.00 %, SUM {:02X}",
                bytes[14]
            )
        );
        assert_eq!(run(Some(Direction::Drive), &[&bytes]).0, [&bytes[..]]);
        // nR over 5: the reply carries no read groups.
        let req = BinaryRequest::block(BinaryAddress::Omitted, BlockRequest::new(&[0xC400], 6).unwrap());
        let rep = req.block_reply(0, true, &[1, 2, 3]).unwrap();
        let bytes = emit(&BinaryFrame::Reply(rep));
        assert_eq!(bytes, [0x2F, 0x79, 0x00, 0xA8]);
        assert_eq!(BinaryReply::parse(&bytes), Ok(rep));
        // nW over 2 is a format error: no reply.
        let mut bad = [0x2F, 0x58, 0x03, 0x00, 0, 0, 0, 0, 0, 0, 0];
        let n = bad.len();
        bad[n - 1] = sum8(&bad[..n - 1]);
        let err = BinaryRequest::parse(&bad).unwrap_err();
        assert_eq!(err.to_string(), "nW (number of write data groups) 3 is not allowed (0..2)");
        assert_eq!(rejection_reply(&bad, 0, false), None);
        let (good, rejected) = run(Some(Direction::Master), &[&bad]);
        assert!(good.is_empty());
        assert_eq!(rejected[0].1, err);
    }

    #[test]
    fn inv_no_and_broadcast() {
        let req = BinaryRequest::read(BinaryAddress::Unit(0x3F), CommNo::OUTPUT_FREQUENCY);
        let bytes = emit(&BinaryFrame::Request(req));
        assert_eq!(bytes, [0x2F, 0x3F, 0x52, 0xFD, 0x00, 0xBD]);
        assert_eq!(BinaryRequest::parse(&bytes), Ok(req));
        let bc = BinaryRequest::write_ram(BinaryAddress::Broadcast, CommNo::FREQUENCY_COMMAND, 0x1770);
        let bytes = emit(&BinaryFrame::Request(bc));
        assert_eq!(bytes[..3], [0x2F, 0xFF, 0x50]);
        assert_eq!(BinaryRequest::parse(&bytes), Ok(bc));
        assert_eq!(BinaryFrame::Request(bc).target(), Target::Broadcast);
        assert_eq!(bc.inv_no.disposition(0), Disposition::Broadcast { reply: true });
        assert_eq!(bc.inv_no.disposition(5), Disposition::Broadcast { reply: false });
        assert_eq!(req.inv_no.disposition(0x3F), Disposition::Mine);
        assert_eq!(req.inv_no.disposition(1), Disposition::NotMine);
        // Inverter 00 answers with its own number.
        let rep = bc.reply(0, false, 0x1770).unwrap();
        assert_eq!(rep.inv_no, Some(0));
        assert!(TipBinary::default().pending(&bc).unwrap().matches(&rep));
        assert_eq!(TipBinary { broadcast_reply: false }.pending(&bc), None);
        // A reply never carries FF.
        let mut fake = [0x2F, 0xFF, 0x72, 0xFD, 0x00, 0x17, 0x70, 0];
        fake[7] = sum8(&fake[..7]);
        assert_eq!(
            BinaryReply::parse(&fake),
            Err(FrameError::Malformed("a reply carries the inverter's own number, never the broadcast FF"))
        );
        let mut b = [0u8; 16];
        assert_eq!(
            BinaryRequest::read(BinaryAddress::Unit(0x40), CommNo(0)).emit(&mut b),
            Err(EmitError::OutOfRange { field: "INV-NO", value: 0x40, min: 0, max: 0x3F })
        );
    }

    #[test]
    fn tripped_and_g() {
        let req = BinaryRequest::read_dummy(BinaryAddress::Unit(2), CommNo::OUTPUT_FREQUENCY);
        let bytes = emit(&BinaryFrame::Request(req));
        assert_eq!(bytes[..7], [0x2F, 0x02, 0x47, 0xFD, 0x00, 0x00, 0x00]);
        assert_eq!(BinaryRequest::parse(&bytes), Ok(req));
        let rep = req.reply(2, true, 0x1770).unwrap();
        let bytes = emit(&BinaryFrame::Reply(rep));
        assert_eq!(bytes[2], 0x67, "g: G + 20H while tripped");
        let f = BinaryCodec::parse(&bytes, None).unwrap();
        assert_eq!(f, BinaryFrame::Reply(rep), "lower case is a drive's whatever `from` says");
        assert_eq!(BinaryReply::parse(&bytes).unwrap().hz(), Some(60.0));
        assert_eq!(f.command().to_string(), "g read (dummy data)");
        // r: a tripped R reply.
        let rep =
            BinaryRequest::read(BinaryAddress::Omitted, CommNo::TRIP_CODE).reply(0, true, 0x18).unwrap();
        let bytes = emit(&BinaryFrame::Reply(rep));
        assert_eq!(bytes[..6], [0x2F, 0x72, 0xFC, 0x90, 0x00, 0x18]);
        assert_eq!(
            BinaryRequest::parse(&bytes),
            Err(FrameError::Malformed("a reply from a tripped drive (lower-case CMD), not a request"))
        );
    }

    #[test]
    fn unknown_command_gets_no_reply() {
        let wire = [0x2F, 0x41, 0x00, 0x00, 0x70];
        let err = BinaryRequest::parse(&wire).unwrap_err();
        assert_eq!(err.to_string(), "unknown binary-mode CMD 0x41");
        assert_eq!(rejection_reply(&wire, 0, false), None);
        assert_eq!(TipBinary::default().rejected_disposition(&wire, 0), Disposition::NotMine);
        let (good, bad) = run(Some(Direction::Master), &[&wire]);
        assert!(good.is_empty());
        assert_eq!(bad.len(), 1);
    }

    #[test]
    fn r_lengths_by_direction() {
        let request = [0x2F, 0x52, 0xFD, 0x00, 0x7E];
        let reply = [0x2F, 0x52, 0xFD, 0x00, 0x17, 0x70, 0x05];
        assert_eq!(sum8(&request[..4]), 0x7E);
        assert_eq!(sum8(&reply[..6]), 0x05);
        assert!(BinaryReply::parse(&request).is_err());
        assert_eq!(BinaryReply::parse(&reply).unwrap().hz(), Some(60.0));
        assert_eq!(
            BinaryRequest::parse(&reply),
            Err(FrameError::Malformed("a drive's reply to R (7 bytes without INV-NO), not a request"))
        );
        // A monitor hears both, back to back.
        let stream: Vec<u8> = request.iter().chain(&reply).copied().collect();
        assert_eq!(run(None, &[&stream]).0, [request.to_vec(), reply.to_vec()]);
        // A drive on a 2-wire line hears the other drive's reply as a whole frame.
        assert_eq!(run(Some(Direction::Master), &[&stream]).0, [request.to_vec(), reply.to_vec()]);
        assert_eq!(run(Some(Direction::Drive), &[&reply]).0, [reply.to_vec()]);
        // Odd lengths.
        assert_eq!(
            BinaryFrame::parse(&reply[..6], None).unwrap_err().to_string(),
            "truncated frame: an R frame needs 7 bytes, got 6"
        );
    }

    #[test]
    fn last_start_code_counts() {
        // A stray 2F before a frame: 2F 2F reads as INV-NO 2F, whose SUM fails; the second
        // 2F starts a frame that checks out, and nothing is reported for the stray byte.
        let stream = [0x2F, 0x2F, 0x52, 0x00, 0x00, 0x81];
        let (good, bad) = run(Some(Direction::Master), &[&stream]);
        assert_eq!(good, [stream[1..].to_vec()]);
        assert!(bad.is_empty());
        // A cut-off frame (X, needs 9 bytes) followed by a whole R: the R is found at once.
        let stream = [0x2F, 0x58, 0x02, 0x2F, 0x52, 0x00, 0x00, 0x81];
        let (good, bad) = run(Some(Direction::Master), &[&stream]);
        assert_eq!(good, [stream[3..].to_vec()]);
        assert!(bad.is_empty());
        // 2F as data is kept: W 002F = 002F.
        let req = BinaryRequest::write(BinaryAddress::Omitted, CommNo(0x2F), 0x2F2F);
        let bytes = emit(&BinaryFrame::Request(req));
        assert_eq!(run(Some(Direction::Master), &[&bytes]).0, [&bytes[..]]);
        for i in 0..bytes.len() {
            assert_eq!(
                run(Some(Direction::Master), &[&bytes[..i], &bytes[i..]]).0,
                [&bytes[..]],
                "split {i}"
            );
        }
    }

    #[test]
    fn garbage_then_frames() {
        let a = [0x2F, 0x52, 0x00, 0x00, 0x81];
        let b = [0x2F, 0x57, 0x00, 0x10, 0x00, 0x64, 0xFA];
        let mut stream = Vec::new();
        stream.extend_from_slice(&[0x00, 0x13, 0x2F, 0x52, 0x00, 0x00, 0x80]); // bad SUM
        stream.extend_from_slice(&a);
        stream.extend_from_slice(&[0x99]);
        stream.extend_from_slice(&b);
        let (good, bad) = run(Some(Direction::Master), &[&stream]);
        assert_eq!(good, [a.to_vec(), b.to_vec()]);
        assert_eq!(bad.len(), 1);
        assert_eq!(bad[0].1.to_string(), "SUM mismatch: frame carries 80, computed 81");
        for i in 0..stream.len() {
            for j in i..stream.len() {
                let (g, _) = run(Some(Direction::Master), &[&stream[..i], &stream[i..j], &stream[j..]]);
                assert_eq!(g, good, "split {i} {j}");
            }
        }
    }

    #[test]
    fn truncated_message() {
        let mut d = Deframer::new(BinaryScanner { from: Some(Direction::Master) });
        d.push(&[0x2F, 0x57, 0x00], &mut |_| {});
        let mut err = None;
        d.finish(&mut |e| {
            if let Event::Rejected { error, .. } = e {
                err = Some(error)
            }
        });
        assert_eq!(err.unwrap().to_string(), "truncated frame: a binary-mode frame needs 7 bytes, got 3");
    }
}
