//! The Modbus PDU: function code + data, without the address and the checksum of a serial ADU.
//!
//! The same PDU travels in Modbus RTU (binary, [`super::rtu`]), Modbus ASCII (hex digits,
//! [`super::ascii`]) and Modbus TCP (binary, after the MBAP header). Parsing allocates nothing:
//! variable-length fields ([`Registers`], [`Data`], [`DeviceObjects`]) are views over the wire
//! bytes, binary or hex digits, decoded as they are read.
//!
//! Functions understood field by field: 03 read holding registers, 04 read input registers,
//! 06 write single register, 08 diagnostics, 10 write multiple registers, 2B/0E read device
//! identification, and exception replies. The other public function codes of the Modbus
//! Application Protocol (01, 02, 05, 07, 0B, 0C, 0F, 11, 14–18) are framed by their length
//! and carried as [`RequestPdu::Other`] / [`ReplyPdu::Other`], so a slave can answer them with
//! exception 01 and a line monitor can show them.
//!
//! Length errors are counted in PDU bytes (function code included); the ADU layers add their
//! address and checksum bytes before they report them.

use core::fmt;

use crate::error::{at_most, in_range, EmitError, FrameError, OutOfRange};
use crate::hex;

/// The longest PDU: 253 bytes (a 256-byte RTU ADU less address and CRC).
pub const MAX_PDU: usize = 253;

/// Function codes.
pub mod function {
    /// 01 read coils (framed, not decoded).
    pub const READ_COILS: u8 = 0x01;
    /// 02 read discrete inputs (framed, not decoded).
    pub const READ_DISCRETE_INPUTS: u8 = 0x02;
    /// 03 read holding registers.
    pub const READ_HOLDING_REGISTERS: u8 = 0x03;
    /// 04 read input registers.
    pub const READ_INPUT_REGISTERS: u8 = 0x04;
    /// 05 write single coil (framed, not decoded).
    pub const WRITE_SINGLE_COIL: u8 = 0x05;
    /// 06 write single register.
    pub const WRITE_SINGLE_REGISTER: u8 = 0x06;
    /// 08 diagnostics (seed 004: loop-back test).
    pub const DIAGNOSTICS: u8 = 0x08;
    /// 0F write multiple coils (framed, not decoded).
    pub const WRITE_MULTIPLE_COILS: u8 = 0x0F;
    /// 10 write multiple registers.
    pub const WRITE_MULTIPLE_REGISTERS: u8 = 0x10;
    /// 17: read/write multiple registers (the write is done before the read).
    pub const READ_WRITE_MULTIPLE_REGISTERS: u8 = 0x17;
    /// 2B encapsulated interface transport (MEI); with MEI type 0E: read device identification.
    pub const ENCAPSULATED_INTERFACE: u8 = 0x2B;
    /// The bit an exception reply sets in the function code.
    pub const EXCEPTION_BIT: u8 = 0x80;
}

/// MEI type 0E of function 2B: read device identification.
pub const MEI_READ_DEVICE_ID: u8 = 0x0E;

/// The Modbus Application Protocol's name for a function code (without the exception bit).
pub const fn function_name(code: u8) -> &'static str {
    match code {
        0x01 => "read coils",
        0x02 => "read discrete inputs",
        0x03 => "read holding registers",
        0x04 => "read input registers",
        0x05 => "write single coil",
        0x06 => "write single register",
        0x07 => "read exception status",
        0x08 => "diagnostics",
        0x0B => "get comm event counter",
        0x0C => "get comm event log",
        0x0F => "write multiple coils",
        0x10 => "write multiple registers",
        0x11 => "report server ID",
        0x14 => "read file record",
        0x15 => "write file record",
        0x16 => "mask write register",
        0x17 => "read/write multiple registers",
        0x18 => "read FIFO queue",
        0x2B => "read device identification",
        _ => "unknown function",
    }
}

/// A register number as it is on the wire: 0-based (the register some documents call
/// 40001 is `RegisterAddress(0)`). Toshiba calls it the communication number (FD00),
/// seed 004 the register address (2104H).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct RegisterAddress(pub u16);

impl fmt::Display for RegisterAddress {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:04X}", self.0)
    }
}

/// Bytes of a PDU field as they are on the wire: binary (RTU, TCP) or pairs of hex digits
/// (ASCII). Reading decodes; nothing is copied.
#[derive(Clone, Copy)]
pub struct Data<'a> {
    raw: &'a [u8],
    hex: bool,
}

impl<'a> Data<'a> {
    /// Binary bytes.
    pub const fn binary(bytes: &'a [u8]) -> Self {
        Data { raw: bytes, hex: false }
    }

    /// Hex digits, two per byte, checked to be hex digits of an even count by the caller.
    pub(crate) const fn hex_digits(digits: &'a [u8]) -> Self {
        Data { raw: digits, hex: true }
    }

    /// Number of bytes.
    #[inline]
    pub const fn len(&self) -> usize {
        if self.hex {
            self.raw.len() / 2
        } else {
            self.raw.len()
        }
    }

    /// True when there are no bytes.
    #[inline]
    pub const fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Byte `i`, or `None` past the end.
    #[inline]
    pub fn get(&self, i: usize) -> Option<u8> {
        if self.hex {
            let hi = *self.raw.get(2 * i)?;
            let lo = *self.raw.get(2 * i + 1)?;
            hex::decode_pair(hi, lo)
        } else {
            self.raw.get(i).copied()
        }
    }

    /// Byte `i`, 0 past the end (for offsets already checked against [`len`](Self::len)).
    #[inline]
    fn at(&self, i: usize) -> u8 {
        self.get(i).unwrap_or(0)
    }

    /// The big-endian 16-bit word at byte `i`.
    #[inline]
    fn word(&self, i: usize) -> u16 {
        u16::from_be_bytes([self.at(i), self.at(i + 1)])
    }

    /// Bytes `from..to` (clamped to the length).
    #[inline]
    pub fn slice(&self, from: usize, to: usize) -> Data<'a> {
        let to = to.min(self.len());
        let from = from.min(to);
        if self.hex {
            Data { raw: self.raw.get(2 * from..2 * to).unwrap_or(&[]), hex: true }
        } else {
            Data { raw: self.raw.get(from..to).unwrap_or(&[]), hex: false }
        }
    }

    /// The bytes, when they are binary on the wire.
    pub const fn as_binary(&self) -> Option<&'a [u8]> {
        if self.hex {
            None
        } else {
            Some(self.raw)
        }
    }

    /// The bytes as they are on the wire (hex digits for ASCII).
    pub const fn wire(&self) -> &'a [u8] {
        self.raw
    }

    /// The bytes, one by one.
    pub fn iter(&self) -> DataIter<'a> {
        DataIter { view: *self, at: 0 }
    }

    /// Copies the bytes into `out` (binary); returns how many. `out` must hold [`len`](Self::len).
    pub fn copy_to(&self, out: &mut [u8]) -> Result<usize, EmitError> {
        let n = self.len();
        crate::error::need(out, n)?;
        match self.as_binary() {
            Some(b) => out[..n].copy_from_slice(b),
            None => {
                for (o, b) in out.iter_mut().zip(self.iter()) {
                    *o = b;
                }
            }
        }
        Ok(n)
    }
}

impl PartialEq for Data<'_> {
    fn eq(&self, other: &Self) -> bool {
        self.len() == other.len() && self.iter().eq(other.iter())
    }
}

impl Eq for Data<'_> {}

impl fmt::Debug for Data<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("[")?;
        for (i, b) in self.iter().enumerate() {
            if i > 0 {
                f.write_str(" ")?;
            }
            write!(f, "{b:02X}")?;
        }
        f.write_str("]")
    }
}

/// An iterator over a view with `get(index)` and `len()` ([`Data`], [`Registers`]).
macro_rules! view_iter {
    ($(#[$m:meta])* $name:ident over $view:ident as $item:ty) => {
        $(#[$m])*
        #[derive(Clone)]
        pub struct $name<'a> {
            view: $view<'a>,
            at: usize,
        }

        impl Iterator for $name<'_> {
            type Item = $item;
            #[inline]
            fn next(&mut self) -> Option<$item> {
                let v = self.view.get(self.at)?;
                self.at += 1;
                Some(v)
            }
            fn size_hint(&self) -> (usize, Option<usize>) {
                let n = self.view.len().saturating_sub(self.at);
                (n, Some(n))
            }
        }

        impl ExactSizeIterator for $name<'_> {}
    };
}

view_iter! {
    /// The bytes of a [`Data`].
    DataIter over Data as u8
}

/// 16-bit register values: a view over big-endian wire bytes (parsed frames) or a slice of
/// values (frames the caller builds).
#[derive(Clone, Copy)]
pub struct Registers<'a> {
    repr: RegRepr<'a>,
}

#[derive(Clone, Copy)]
enum RegRepr<'a> {
    Wire(Data<'a>),
    Values(&'a [u16]),
}

impl<'a> Registers<'a> {
    /// Register values to send.
    pub const fn from_values(values: &'a [u16]) -> Self {
        Registers { repr: RegRepr::Values(values) }
    }

    /// Big-endian register bytes (an odd last byte is ignored).
    pub const fn from_be_bytes(bytes: &'a [u8]) -> Self {
        Registers { repr: RegRepr::Wire(Data::binary(bytes)) }
    }

    pub(crate) const fn from_data(data: Data<'a>) -> Self {
        Registers { repr: RegRepr::Wire(data) }
    }

    /// Number of registers.
    #[inline]
    pub fn len(&self) -> usize {
        match self.repr {
            RegRepr::Wire(d) => d.len() / 2,
            RegRepr::Values(v) => v.len(),
        }
    }

    /// True when there are none.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Register `i`, or `None` past the end.
    #[inline]
    pub fn get(&self, i: usize) -> Option<u16> {
        match self.repr {
            RegRepr::Wire(d) => Some(u16::from_be_bytes([d.get(2 * i)?, d.get(2 * i + 1)?])),
            RegRepr::Values(v) => v.get(i).copied(),
        }
    }

    /// The values in order.
    pub fn iter(&self) -> RegistersIter<'a> {
        RegistersIter { view: *self, at: 0 }
    }

    /// Writes the values big-endian into `out`; returns the bytes written.
    pub fn write_be(&self, out: &mut [u8]) -> Result<usize, EmitError> {
        let n = 2 * self.len();
        crate::error::need(out, n)?;
        for (chunk, v) in out[..n].chunks_exact_mut(2).zip(self.iter()) {
            chunk.copy_from_slice(&v.to_be_bytes());
        }
        Ok(n)
    }
}

impl PartialEq for Registers<'_> {
    fn eq(&self, other: &Self) -> bool {
        self.len() == other.len() && self.iter().eq(other.iter())
    }
}

impl Eq for Registers<'_> {}

impl fmt::Debug for Registers<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list().entries(self.iter().map(Hex4)).finish()
    }
}

struct Hex4(u16);

impl fmt::Debug for Hex4 {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:04X}", self.0)
    }
}

view_iter! {
    /// The values of a [`Registers`].
    RegistersIter over Registers as u16
}

/// An exception code (the byte after `function | 0x80`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ExceptionCode(pub u8);

impl ExceptionCode {
    crate::error::named_codes! {
        ExceptionCode;
        /// What the code means, for the codes the Modbus Application Protocol defines.
        fn meaning also { 0x07 => "negative acknowledge" };
        /// 01: the function code is not supported (seed 004: "功能码错误", function code error).
        ILLEGAL_FUNCTION(0x01) => "illegal function",
        /// 02: the register address does not exist (Toshiba: no such communication number).
        ILLEGAL_DATA_ADDRESS(0x02) => "illegal data address",
        /// 03: a value in the request is not allowed (Toshiba: data error, wrong count).
        ILLEGAL_DATA_VALUE(0x03) => "illegal data value",
        /// 04: the server failed while acting (Toshiba: impossible to execute).
        SERVER_DEVICE_FAILURE(0x04) => "server device failure",
        /// 05: accepted, a long action is under way.
        ACKNOWLEDGE(0x05) => "acknowledge",
        /// 06: busy with a long action; retry later.
        SERVER_DEVICE_BUSY(0x06) => "server device busy",
        /// 08: memory parity error in a file record.
        MEMORY_PARITY_ERROR(0x08) => "memory parity error",
        /// 0A: a gateway has no path to the target.
        GATEWAY_PATH_UNAVAILABLE(0x0A) => "gateway path unavailable",
        /// 0B: a gateway's target did not answer.
        GATEWAY_TARGET_FAILED(0x0B) => "gateway target device failed to respond",
    }

    /// The exception a server answers to a request that failed to parse with `error`:
    /// 01 for a function it does not know, 03 (illegal data value) for anything else.
    pub const fn for_error(error: &FrameError) -> Self {
        match error {
            FrameError::Unknown { field, .. } if is_function_field(field) => Self::ILLEGAL_FUNCTION,
            _ => Self::ILLEGAL_DATA_VALUE,
        }
    }
}

const fn is_function_field(field: &str) -> bool {
    let a = field.as_bytes();
    let b = FUNCTION_CODE.as_bytes();
    if a.len() != b.len() {
        return false;
    }
    let mut i = 0;
    while i < a.len() {
        if a[i] != b[i] {
            return false;
        }
        i += 1;
    }
    true
}

const FUNCTION_CODE: &str = "function code";

/// The read device ID code of a 2B/0E request: which objects to read.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ReadDeviceIdCode(pub u8);

impl ReadDeviceIdCode {
    crate::error::named_codes! {
        ReadDeviceIdCode;
        /// What the code asks for.
        fn meaning;
        /// 01: the basic objects (vendor name, product code, revision) as a stream.
        BASIC(1) => "basic device identification (stream)",
        /// 02: the regular objects as a stream.
        REGULAR(2) => "regular device identification (stream)",
        /// 03: the extended objects as a stream.
        EXTENDED(3) => "extended device identification (stream)",
        /// 04: one specific object.
        SPECIFIC(4) => "one specific identification object",
    }
}

/// The standard name of a device identification object.
pub const fn object_name(id: u8) -> Option<&'static str> {
    Some(match id {
        0x00 => "VendorName",
        0x01 => "ProductCode",
        0x02 => "MajorMinorRevision",
        0x03 => "VendorUrl",
        0x04 => "ProductName",
        0x05 => "ModelName",
        0x06 => "UserApplicationName",
        0x07..=0x7F => "reserved",
        _ => "private object",
    })
}

/// One device identification object: its id and its value (text, usually).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DeviceObject<'a> {
    /// The object id (00 VendorName, 01 ProductCode, 02 MajorMinorRevision, ...).
    pub id: u8,
    /// The object's value.
    pub value: Data<'a>,
}

impl<'a> DeviceObject<'a> {
    /// An object with a binary value (for replies the caller builds).
    pub const fn new(id: u8, value: &'a [u8]) -> Self {
        DeviceObject { id, value: Data::binary(value) }
    }
}

/// The object list of a 2B/0E reply: a view over the wire bytes, or objects to send.
#[derive(Clone, Copy)]
pub struct DeviceObjects<'a> {
    repr: ObjRepr<'a>,
}

#[derive(Clone, Copy)]
enum ObjRepr<'a> {
    /// `count` objects (id, length, value) in `data`, already checked to fit.
    Wire {
        data: Data<'a>,
        count: u8,
    },
    List(&'a [DeviceObject<'a>]),
}

impl<'a> DeviceObjects<'a> {
    /// Objects to send.
    pub const fn from_list(list: &'a [DeviceObject<'a>]) -> Self {
        DeviceObjects { repr: ObjRepr::List(list) }
    }

    /// Number of objects.
    pub fn len(&self) -> usize {
        match self.repr {
            ObjRepr::Wire { count, .. } => count as usize,
            ObjRepr::List(l) => l.len(),
        }
    }

    /// True when there are none.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The objects in order.
    pub fn iter(&self) -> DeviceObjectsIter<'a> {
        DeviceObjectsIter { objs: *self, index: 0, at: 0 }
    }

    /// Bytes the list takes on the wire.
    fn wire_len(&self) -> usize {
        self.iter().map(|o| 2 + o.value.len()).sum()
    }
}

impl PartialEq for DeviceObjects<'_> {
    fn eq(&self, other: &Self) -> bool {
        self.len() == other.len() && self.iter().eq(other.iter())
    }
}

impl Eq for DeviceObjects<'_> {}

impl fmt::Debug for DeviceObjects<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}

/// The objects of a [`DeviceObjects`].
#[derive(Clone)]
pub struct DeviceObjectsIter<'a> {
    objs: DeviceObjects<'a>,
    index: usize,
    at: usize,
}

impl<'a> Iterator for DeviceObjectsIter<'a> {
    type Item = DeviceObject<'a>;
    fn next(&mut self) -> Option<DeviceObject<'a>> {
        match self.objs.repr {
            ObjRepr::List(l) => {
                let o = l.get(self.index).copied()?;
                self.index += 1;
                Some(o)
            }
            ObjRepr::Wire { data, count } => {
                if self.index >= count as usize {
                    return None;
                }
                let id = data.get(self.at)?;
                let len = data.get(self.at + 1)? as usize;
                let value = data.slice(self.at + 2, self.at + 2 + len);
                self.at += 2 + len;
                self.index += 1;
                Some(DeviceObject { id, value })
            }
        }
    }
}

/// A 2B/0E read device identification reply.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DeviceIdReply<'a> {
    /// The read device ID code of the request, echoed.
    pub code: ReadDeviceIdCode,
    /// The identification level the device supports (01/02/03, +80 when it also gives
    /// individual access).
    pub conformity_level: u8,
    /// True (FF) when the objects do not all fit in this reply and another request must
    /// start at `next_object_id`.
    pub more_follows: bool,
    /// The object to ask for next when `more_follows`, else 00.
    pub next_object_id: u8,
    /// The objects.
    pub objects: DeviceObjects<'a>,
}

/// A request PDU (master to drive).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RequestPdu<'a> {
    /// 03: read `quantity` (1..125) holding registers from `start`.
    /// Toshiba: "Read command (03)", one word at a time on VF-AS1.
    ReadHoldingRegisters {
        /// The first register.
        start: RegisterAddress,
        /// How many registers, 1..125.
        quantity: u16,
    },
    /// 04: read `quantity` (1..125) input registers from `start`.
    ReadInputRegisters {
        /// The first register.
        start: RegisterAddress,
        /// How many registers, 1..125.
        quantity: u16,
    },
    /// 06: write `value` into register `address`. Toshiba: "Write command (06)".
    WriteSingleRegister {
        /// The register.
        address: RegisterAddress,
        /// The value.
        value: u16,
    },
    /// 08: diagnostics. Sub-function 0000 returns the query data; seed 004's loop-back test
    /// echoes any sub-function ("变频器将收到的资料原封不动送给主控设备": the drive sends the
    /// received data back unchanged).
    Diagnostics {
        /// The sub-function.
        sub_function: u16,
        /// The data after the sub-function.
        data: Data<'a>,
    },
    /// 10: write `values` (1..123 registers) from `start`.
    WriteMultipleRegisters {
        /// The first register.
        start: RegisterAddress,
        /// The values.
        values: Registers<'a>,
    },
    /// 17: write `values` (1..121 registers) from `write_start`, then read `read_quantity`
    /// (1..125) holding registers from `read_start` ("the write operation is performed before
    /// the read").
    ReadWriteMultipleRegisters {
        /// The first register read.
        read_start: RegisterAddress,
        /// How many registers are read, 1..125.
        read_quantity: u16,
        /// The first register written.
        write_start: RegisterAddress,
        /// The values written.
        values: Registers<'a>,
    },
    /// 2B/0E: read device identification.
    ReadDeviceIdentification {
        /// Which objects: basic, regular, extended stream, or one object.
        code: ReadDeviceIdCode,
        /// The first object to read (or the one object, for code 04).
        object_id: u8,
    },
    /// Another public function code, framed by its length but not decoded.
    Other {
        /// The function code.
        function: u8,
        /// The bytes after the function code.
        data: Data<'a>,
    },
}

/// A reply PDU (drive to master).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReplyPdu<'a> {
    /// 03: the register values read.
    ReadHoldingRegisters {
        /// The values.
        values: Registers<'a>,
    },
    /// 04: the register values read.
    ReadInputRegisters {
        /// The values.
        values: Registers<'a>,
    },
    /// 06: the request echoed.
    WriteSingleRegister {
        /// The register.
        address: RegisterAddress,
        /// The value written.
        value: u16,
    },
    /// 08: the request echoed (for sub-function 0000 and seed 004's loop-back).
    Diagnostics {
        /// The sub-function.
        sub_function: u16,
        /// The data.
        data: Data<'a>,
    },
    /// 10: the registers written.
    WriteMultipleRegisters {
        /// The first register.
        start: RegisterAddress,
        /// How many.
        quantity: u16,
    },
    /// 17: the register values read (after the write).
    ReadWriteMultipleRegisters {
        /// The values.
        values: Registers<'a>,
    },
    /// 2B/0E: the identification objects.
    ReadDeviceIdentification(DeviceIdReply<'a>),
    /// An exception: `function | 0x80` and a code.
    Exception {
        /// The function refused (without the 0x80 bit).
        function: u8,
        /// Why.
        code: ExceptionCode,
    },
    /// Another public function code, framed by its length but not decoded.
    Other {
        /// The function code.
        function: u8,
        /// The bytes after the function code.
        data: Data<'a>,
    },
}

/// How long a PDU is, as far as its first bytes tell.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum PduLen {
    /// The PDU is this many bytes (may exceed [`MAX_PDU`]: too long).
    Known(usize),
    /// At least this many PDU bytes are needed to know.
    NeedMore(usize),
    /// The function code (or MEI type) has no known layout.
    Unknown,
}

/// The length of a request PDU whose first bytes `at(0..)` return; `at(0)` is the function code.
#[inline(always)]
pub(crate) fn request_len(fc: u8, at: impl Fn(usize) -> Option<u8>) -> PduLen {
    match fc {
        0x01..=0x06 | 0x08 => PduLen::Known(5),
        0x07 | 0x0B | 0x0C | 0x11 => PduLen::Known(1),
        0x0F | 0x10 => count_at(5, &at),
        0x14 | 0x15 => count_at(1, &at),
        0x16 => PduLen::Known(7),
        0x17 => count_at(9, &at),
        0x18 => PduLen::Known(3),
        0x2B => match at(1) {
            None => PduLen::NeedMore(2),
            Some(MEI_READ_DEVICE_ID) => PduLen::Known(4),
            Some(_) => PduLen::Unknown,
        },
        _ => PduLen::Unknown,
    }
}

/// The length of a reply PDU whose first bytes `at(0..)` return; `at(0)` is the function code.
#[inline(always)]
pub(crate) fn reply_len(fc: u8, at: impl Fn(usize) -> Option<u8>) -> PduLen {
    match fc {
        0x01..=0x04 | 0x0C | 0x11 | 0x14 | 0x15 | 0x17 => count_at(1, &at),
        0x05 | 0x06 | 0x08 | 0x0B | 0x0F | 0x10 => PduLen::Known(5),
        0x07 => PduLen::Known(2),
        0x16 => PduLen::Known(7),
        0x18 => match (at(1), at(2)) {
            (Some(h), Some(l)) => PduLen::Known(3 + u16::from_be_bytes([h, l]) as usize),
            _ => PduLen::NeedMore(3),
        },
        0x2B => device_id_reply_len(&at),
        0x81..=0xFF => PduLen::Known(2),
        _ => PduLen::Unknown,
    }
}

#[inline(always)]
fn count_at(i: usize, at: &impl Fn(usize) -> Option<u8>) -> PduLen {
    match at(i) {
        Some(n) => PduLen::Known(i + 1 + n as usize),
        None => PduLen::NeedMore(i + 1),
    }
}

/// Walks the object list of a 2B/0E reply: `2B 0E code conformity more next count
/// (id len value)*`.
fn device_id_reply_len(at: &impl Fn(usize) -> Option<u8>) -> PduLen {
    match at(1) {
        None => return PduLen::NeedMore(2),
        Some(MEI_READ_DEVICE_ID) => {}
        Some(_) => return PduLen::Unknown,
    }
    let Some(count) = at(6) else {
        return PduLen::NeedMore(7);
    };
    let mut p = 7;
    for _ in 0..count {
        if p > MAX_PDU {
            break;
        }
        match at(p + 1) {
            Some(len) => p += 2 + len as usize,
            None => return PduLen::NeedMore(p + 2),
        }
    }
    PduLen::Known(p)
}

/// The PDU length error for `what`: too short or too long against `expected`.
fn length_error(what: &'static str, expected: usize, got: usize) -> FrameError {
    if got < expected {
        FrameError::Truncated { what, expected, got }
    } else {
        FrameError::TooLong { what, max: expected, got }
    }
}

/// `request_what` ("03 request") and `reply_what` ("03 reply") from one list of the function
/// codes [`request_len`] and [`reply_len`] know, for length messages.
macro_rules! what_tables {
    ($($fc:literal $digits:literal),* $(,)?) => {
        /// "03 request" and friends, for length messages.
        pub(crate) const fn request_what(fc: u8) -> &'static str {
            match fc {
                $($fc => concat!($digits, " request"),)*
                0x2B => "2B/0E request",
                _ => "request",
            }
        }

        /// "03 reply" and friends, for length messages.
        pub(crate) const fn reply_what(fc: u8) -> &'static str {
            match fc {
                $($fc => concat!($digits, " reply"),)*
                0x2B => "2B/0E reply",
                0x80..=0xFF => "exception reply",
                _ => "reply",
            }
        }
    };
}

what_tables! {
    0x01 "01", 0x02 "02", 0x03 "03", 0x04 "04", 0x05 "05", 0x06 "06", 0x07 "07", 0x08 "08", 0x0B "0B",
    0x0C "0C", 0x0F "0F", 0x10 "10", 0x11 "11", 0x14 "14", 0x15 "15", 0x16 "16", 0x17 "17", 0x18 "18",
}

/// The function code of a PDU parsed as a `what` ("request", "reply"): its first byte.
#[inline]
fn function_of(pdu: Data<'_>, what: &'static str) -> Result<u8, FrameError> {
    pdu.get(0).ok_or(FrameError::Truncated { what, expected: 1, got: 0 })
}

/// `len` when the function code `fc` (and the MEI type of a 2B) has a known layout.
#[inline]
fn known_layout(pdu: Data<'_>, fc: u8, len: PduLen) -> Result<PduLen, FrameError> {
    match (len, fc) {
        (PduLen::Unknown, 0x2B) => Err(FrameError::Unknown { field: "MEI type", value: pdu.at(1) as u32 }),
        (PduLen::Unknown, _) => Err(FrameError::Unknown { field: FUNCTION_CODE, value: fc as u32 }),
        (len, _) => Ok(len),
    }
}

/// The sub-function and data of an 08 diagnostics request or reply: any data length
/// (sub-function 0000 echoes N bytes, seed 004 echoes anything).
fn diagnostics<'a>(pdu: Data<'a>, what: &'static str) -> Result<(u16, Data<'a>), FrameError> {
    let got = pdu.len();
    if got < 3 {
        return Err(FrameError::Truncated { what, expected: 3, got });
    }
    Ok((pdu.word(1), pdu.slice(3, got)))
}

/// Checks a PDU against the length its shape predicts.
fn check_len(what: &'static str, len: PduLen, got: usize) -> Result<(), FrameError> {
    match len {
        PduLen::Known(n) if n == got => Ok(()),
        PduLen::Known(n) => Err(length_error(what, n, got)),
        PduLen::NeedMore(n) => Err(FrameError::Truncated { what, expected: n, got }),
        PduLen::Unknown => Err(FrameError::Malformed("unknown layout")),
    }
}

/// Checks a register quantity against `1..=max` ("quantity 0 is not allowed (1..125)").
#[inline]
fn quantity_ok(q: u16, max: u16) -> Result<(), OutOfRange> {
    in_range("quantity", q as u32, 1, max as u32)
}

/// Checks a read device ID code: 01 to 04.
#[inline]
fn device_id_code_ok(code: ReadDeviceIdCode) -> Result<(), OutOfRange> {
    in_range("read device ID code", code.0 as u32, 1, 4)
}

/// Checks a function code a frame is built with: 01 to 7F (the 0x80 bit marks exceptions).
#[inline]
fn function_ok(function: u8) -> Result<(), OutOfRange> {
    in_range("function code", function as u32, 1, 0x7F)
}

impl<'a> RequestPdu<'a> {
    /// Parses a binary request PDU (function code first).
    #[inline]
    pub fn parse(pdu: &'a [u8]) -> Result<Self, FrameError> {
        // Fast path for the usual 5-byte layouts, straight from the slice.
        if let &[fc, a0, a1, b0, b1] = pdu {
            let (a, b) = (u16::from_be_bytes([a0, a1]), u16::from_be_bytes([b0, b1]));
            match fc {
                0x03 if (1..=125).contains(&b) => {
                    return Ok(RequestPdu::ReadHoldingRegisters { start: RegisterAddress(a), quantity: b })
                }
                0x04 if (1..=125).contains(&b) => {
                    return Ok(RequestPdu::ReadInputRegisters { start: RegisterAddress(a), quantity: b })
                }
                0x06 => return Ok(RequestPdu::WriteSingleRegister { address: RegisterAddress(a), value: b }),
                _ => {}
            }
        }
        Self::parse_data(Data::binary(pdu))
    }

    /// Parses a request PDU given as [`Data`] (binary or hex digits).
    pub fn parse_data(pdu: Data<'a>) -> Result<Self, FrameError> {
        let got = pdu.len();
        let fc = function_of(pdu, "request")?;
        if fc & function::EXCEPTION_BIT != 0 {
            // Only drives send function codes with the 0x80 bit: they are exception replies.
            return Err(FrameError::Malformed(
                "a function code with the 0x80 bit set is an exception reply, not a request",
            ));
        }
        let what = request_what(fc);
        let len = known_layout(pdu, fc, request_len(fc, |i| pdu.get(i)))?;
        match fc {
            0x03 | 0x04 => {
                check_len(what, len, got)?;
                let start = RegisterAddress(pdu.word(1));
                let quantity = pdu.word(3);
                // Modbus Application Protocol: "Quantity of Registers 1 to 125 (0x7D)".
                quantity_ok(quantity, 125)?;
                Ok(if fc == 0x03 {
                    RequestPdu::ReadHoldingRegisters { start, quantity }
                } else {
                    RequestPdu::ReadInputRegisters { start, quantity }
                })
            }
            0x06 => {
                check_len(what, len, got)?;
                let (address, value) = (RegisterAddress(pdu.word(1)), pdu.word(3));
                Ok(RequestPdu::WriteSingleRegister { address, value })
            }
            0x08 => {
                let (sub_function, data) = diagnostics(pdu, what)?;
                Ok(RequestPdu::Diagnostics { sub_function, data })
            }
            0x10 => {
                // "Quantity of Registers 1 to 123 (0x7B)", "Byte Count 2 x N".
                let values = counted_values(pdu, (what, len), 3, 123, "byte count")?;
                Ok(RequestPdu::WriteMultipleRegisters { start: RegisterAddress(pdu.word(1)), values })
            }
            0x17 => {
                // "Quantity to Read 1 to 125", "Quantity to Write 1 to 121", "Byte Count 2 x N".
                let values = counted_values(pdu, (what, len), 7, 121, "write byte count")?;
                let read_quantity = pdu.word(3);
                quantity_ok(read_quantity, 125)?;
                Ok(RequestPdu::ReadWriteMultipleRegisters {
                    read_start: RegisterAddress(pdu.word(1)),
                    read_quantity,
                    write_start: RegisterAddress(pdu.word(5)),
                    values,
                })
            }
            0x2B => {
                check_len(what, len, got)?;
                let code = ReadDeviceIdCode(pdu.at(2));
                device_id_code_ok(code)?;
                Ok(RequestPdu::ReadDeviceIdentification { code, object_id: pdu.at(3) })
            }
            _ => {
                check_len(what, len, got)?;
                Ok(RequestPdu::Other { function: fc, data: pdu.slice(1, got) })
            }
        }
    }

    /// The function code on the wire.
    pub fn function(&self) -> u8 {
        match self {
            RequestPdu::ReadHoldingRegisters { .. } => function::READ_HOLDING_REGISTERS,
            RequestPdu::ReadInputRegisters { .. } => function::READ_INPUT_REGISTERS,
            RequestPdu::WriteSingleRegister { .. } => function::WRITE_SINGLE_REGISTER,
            RequestPdu::Diagnostics { .. } => function::DIAGNOSTICS,
            RequestPdu::WriteMultipleRegisters { .. } => function::WRITE_MULTIPLE_REGISTERS,
            RequestPdu::ReadWriteMultipleRegisters { .. } => function::READ_WRITE_MULTIPLE_REGISTERS,
            RequestPdu::ReadDeviceIdentification { .. } => function::ENCAPSULATED_INTERFACE,
            RequestPdu::Other { function, .. } => *function,
        }
    }

    /// Bytes the PDU takes in binary.
    pub fn wire_len(&self) -> usize {
        match self {
            RequestPdu::ReadHoldingRegisters { .. }
            | RequestPdu::ReadInputRegisters { .. }
            | RequestPdu::WriteSingleRegister { .. } => 5,
            RequestPdu::Diagnostics { data, .. } => 3 + data.len(),
            RequestPdu::WriteMultipleRegisters { values, .. } => 6 + 2 * values.len(),
            RequestPdu::ReadWriteMultipleRegisters { values, .. } => 10 + 2 * values.len(),
            RequestPdu::ReadDeviceIdentification { .. } => 4,
            RequestPdu::Other { data, .. } => 1 + data.len(),
        }
    }

    /// Writes the binary PDU into `out`; returns its length.
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, EmitError> {
        let n = self.wire_len();
        emit_start(n, self.function(), out)?;
        match *self {
            RequestPdu::ReadHoldingRegisters { start, quantity }
            | RequestPdu::ReadInputRegisters { start, quantity } => emit_span(out, start, quantity, 125)?,
            RequestPdu::WriteSingleRegister { address, value } => put_words(out, address.0, value),
            RequestPdu::Diagnostics { sub_function, data } => emit_diagnostics(out, n, sub_function, data)?,
            RequestPdu::WriteMultipleRegisters { start, values } => {
                let q = values.len();
                quantity_ok(q.min(u16::MAX as usize) as u16, 123)?;
                put_word(out, 1, start.0);
                put_word(out, 3, q as u16);
                out[5] = (2 * q) as u8;
                values.write_be(&mut out[6..n])?;
            }
            RequestPdu::ReadWriteMultipleRegisters { read_start, read_quantity, write_start, values } => {
                quantity_ok(read_quantity, 125)?;
                let q = values.len();
                quantity_ok(q.min(u16::MAX as usize) as u16, 121)?;
                put_word(out, 1, read_start.0);
                put_word(out, 3, read_quantity);
                put_word(out, 5, write_start.0);
                put_word(out, 7, q as u16);
                out[9] = (2 * q) as u8;
                values.write_be(&mut out[10..n])?;
            }
            RequestPdu::ReadDeviceIdentification { code, object_id } => {
                device_id_code_ok(code)?;
                out[1] = MEI_READ_DEVICE_ID;
                out[2] = code.0;
                out[3] = object_id;
            }
            RequestPdu::Other { function, data } => {
                function_ok(function)?;
                data.copy_to(&mut out[1..n])?;
            }
        }
        Ok(n)
    }
}

/// The register values of a write request whose quantity is the word at `at`, followed by a
/// byte count and the values (10 and 17): the quantity within `1..=max`, the byte count twice
/// it, the PDU's length what the byte count says.
fn counted_values<'a>(
    pdu: Data<'a>,
    (what, len): (&'static str, PduLen),
    at: usize,
    max: u16,
    count_field: &'static str,
) -> Result<Registers<'a>, FrameError> {
    let got = pdu.len();
    if got < at + 3 {
        return Err(FrameError::Truncated { what, expected: at + 3, got });
    }
    let quantity = pdu.word(at);
    quantity_ok(quantity, max)?;
    let count = pdu.at(at + 2);
    if count as u16 != 2 * quantity {
        return Err(FrameError::Inconsistent {
            field: count_field,
            value: count as u32,
            expected: 2 * quantity as u32,
        });
    }
    check_len(what, len, got)?;
    Ok(Registers::from_data(pdu.slice(at + 3, got)))
}

/// The start of every PDU [`emit`](RequestPdu::emit): checks the length `n` against
/// [`MAX_PDU`] and `out`, and writes the function code.
#[inline]
fn emit_start(n: usize, function: u8, out: &mut [u8]) -> Result<(), EmitError> {
    at_most("PDU length", n as u32, 1, MAX_PDU as u32)?;
    crate::error::need(out, n)?;
    out[0] = function;
    Ok(())
}

/// Writes the two words at bytes 1..5 that most PDUs start with.
#[inline]
fn put_words(out: &mut [u8], a: u16, b: u16) {
    put_word(out, 1, a);
    put_word(out, 3, b);
}

/// Writes a first register and a quantity within `1..=max` (03/04 requests, the 10 reply).
#[inline]
fn emit_span(out: &mut [u8], start: RegisterAddress, quantity: u16, max: u16) -> Result<(), EmitError> {
    quantity_ok(quantity, max)?;
    put_words(out, start.0, quantity);
    Ok(())
}

/// Writes the sub-function and data of an 08 diagnostics request or reply of `n` bytes.
fn emit_diagnostics(out: &mut [u8], n: usize, sub_function: u16, data: Data<'_>) -> Result<(), EmitError> {
    put_word(out, 1, sub_function);
    data.copy_to(&mut out[3..n])?;
    Ok(())
}

#[inline]
fn put_word(out: &mut [u8], at: usize, v: u16) {
    out[at..at + 2].copy_from_slice(&v.to_be_bytes());
}

impl<'a> ReplyPdu<'a> {
    /// Parses a binary reply PDU (function code first).
    #[inline]
    pub fn parse(pdu: &'a [u8]) -> Result<Self, FrameError> {
        // Fast paths for register reads and the 06 echo, straight from the slice.
        match *pdu {
            [fc @ (0x03 | 0x04), count, ref data @ ..]
                if count as usize == data.len() && count % 2 == 0 && (2..=250).contains(&count) =>
            {
                let values = Registers::from_be_bytes(data);
                return Ok(if fc == 0x03 {
                    ReplyPdu::ReadHoldingRegisters { values }
                } else {
                    ReplyPdu::ReadInputRegisters { values }
                });
            }
            [0x06, a0, a1, b0, b1] => {
                return Ok(ReplyPdu::WriteSingleRegister {
                    address: RegisterAddress(u16::from_be_bytes([a0, a1])),
                    value: u16::from_be_bytes([b0, b1]),
                })
            }
            _ => {}
        }
        Self::parse_data(Data::binary(pdu))
    }

    /// Parses a reply PDU given as [`Data`] (binary or hex digits).
    pub fn parse_data(pdu: Data<'a>) -> Result<Self, FrameError> {
        let got = pdu.len();
        let fc = function_of(pdu, "reply")?;
        let what = reply_what(fc);
        let len = known_layout(pdu, fc, reply_len(fc, |i| pdu.get(i)))?;
        match fc {
            0x03 | 0x04 | 0x17 => {
                if got < 2 {
                    return Err(FrameError::Truncated { what, expected: 2, got });
                }
                let count = pdu.at(1) as usize;
                if count != got - 2 {
                    if got == 5 && fc == 0x03 {
                        // seed 004's RTU "reply" 01 03 21 04 00 00 0E 37 is the request again.
                        return Err(FrameError::Malformed(
                            "not a valid 03 reply: it has the layout of a 03 request (starting address, \
                             quantity) where a reply has a byte count and register values",
                        ));
                    }
                    return Err(FrameError::Inconsistent {
                        field: "byte count",
                        value: count as u32,
                        expected: (got - 2) as u32,
                    });
                }
                if count % 2 != 0 {
                    return Err(FrameError::Malformed("odd byte count: a register is 2 bytes"));
                }
                in_range("byte count", count as u32, 2, 250)?;
                let values = Registers::from_data(pdu.slice(2, got));
                Ok(match fc {
                    0x03 => ReplyPdu::ReadHoldingRegisters { values },
                    0x04 => ReplyPdu::ReadInputRegisters { values },
                    _ => ReplyPdu::ReadWriteMultipleRegisters { values },
                })
            }
            0x06 => {
                check_len(what, len, got)?;
                let (address, value) = (RegisterAddress(pdu.word(1)), pdu.word(3));
                Ok(ReplyPdu::WriteSingleRegister { address, value })
            }
            0x08 => {
                let (sub_function, data) = diagnostics(pdu, what)?;
                Ok(ReplyPdu::Diagnostics { sub_function, data })
            }
            0x10 => {
                check_len(what, len, got)?;
                let quantity = pdu.word(3);
                quantity_ok(quantity, 123)?;
                Ok(ReplyPdu::WriteMultipleRegisters { start: RegisterAddress(pdu.word(1)), quantity })
            }
            0x2B => {
                check_len(what, len, got)?;
                let code = ReadDeviceIdCode(pdu.at(2));
                device_id_code_ok(code)?;
                let more_follows = match pdu.at(4) {
                    0x00 => false,
                    0xFF => true,
                    _ => return Err(FrameError::Malformed("more follows must be 00 or FF")),
                };
                Ok(ReplyPdu::ReadDeviceIdentification(DeviceIdReply {
                    code,
                    conformity_level: pdu.at(3),
                    more_follows,
                    next_object_id: pdu.at(5),
                    objects: DeviceObjects {
                        repr: ObjRepr::Wire { data: pdu.slice(7, got), count: pdu.at(6) },
                    },
                }))
            }
            0x80..=0xFF => {
                check_len(what, len, got)?;
                Ok(ReplyPdu::Exception {
                    function: fc & !function::EXCEPTION_BIT,
                    code: ExceptionCode(pdu.at(1)),
                })
            }
            _ => {
                check_len(what, len, got)?;
                Ok(ReplyPdu::Other { function: fc, data: pdu.slice(1, got) })
            }
        }
    }

    /// The function code on the wire (with the 0x80 bit for an exception).
    pub fn function(&self) -> u8 {
        match self {
            ReplyPdu::ReadHoldingRegisters { .. } => function::READ_HOLDING_REGISTERS,
            ReplyPdu::ReadInputRegisters { .. } => function::READ_INPUT_REGISTERS,
            ReplyPdu::WriteSingleRegister { .. } => function::WRITE_SINGLE_REGISTER,
            ReplyPdu::Diagnostics { .. } => function::DIAGNOSTICS,
            ReplyPdu::WriteMultipleRegisters { .. } => function::WRITE_MULTIPLE_REGISTERS,
            ReplyPdu::ReadWriteMultipleRegisters { .. } => function::READ_WRITE_MULTIPLE_REGISTERS,
            ReplyPdu::ReadDeviceIdentification(_) => function::ENCAPSULATED_INTERFACE,
            ReplyPdu::Exception { function, .. } => function | function::EXCEPTION_BIT,
            ReplyPdu::Other { function, .. } => *function,
        }
    }

    /// The function answered (without the 0x80 bit).
    pub fn answers_function(&self) -> u8 {
        self.function() & !function::EXCEPTION_BIT
    }

    /// True for an exception reply.
    pub fn is_exception(&self) -> bool {
        matches!(self, ReplyPdu::Exception { .. })
    }

    /// Bytes the PDU takes in binary.
    pub fn wire_len(&self) -> usize {
        match self {
            ReplyPdu::ReadHoldingRegisters { values }
            | ReplyPdu::ReadInputRegisters { values }
            | ReplyPdu::ReadWriteMultipleRegisters { values } => 2 + 2 * values.len(),
            ReplyPdu::WriteSingleRegister { .. } | ReplyPdu::WriteMultipleRegisters { .. } => 5,
            ReplyPdu::Diagnostics { data, .. } => 3 + data.len(),
            ReplyPdu::ReadDeviceIdentification(r) => 7 + r.objects.wire_len(),
            ReplyPdu::Exception { .. } => 2,
            ReplyPdu::Other { data, .. } => 1 + data.len(),
        }
    }

    /// Writes the binary PDU into `out`; returns its length.
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, EmitError> {
        let n = self.wire_len();
        emit_start(n, self.function(), out)?;
        match *self {
            ReplyPdu::ReadHoldingRegisters { values }
            | ReplyPdu::ReadInputRegisters { values }
            | ReplyPdu::ReadWriteMultipleRegisters { values } => {
                quantity_ok(values.len().min(u16::MAX as usize) as u16, 125)?;
                out[1] = (2 * values.len()) as u8;
                values.write_be(&mut out[2..n])?;
            }
            ReplyPdu::WriteSingleRegister { address, value } => put_words(out, address.0, value),
            ReplyPdu::Diagnostics { sub_function, data } => emit_diagnostics(out, n, sub_function, data)?,
            ReplyPdu::WriteMultipleRegisters { start, quantity } => emit_span(out, start, quantity, 123)?,
            ReplyPdu::ReadDeviceIdentification(r) => {
                device_id_code_ok(r.code)?;
                let count = r.objects.len();
                at_most("number of objects", count as u32, 0, 255)?;
                out[1] = MEI_READ_DEVICE_ID;
                out[2] = r.code.0;
                out[3] = r.conformity_level;
                out[4] = if r.more_follows { 0xFF } else { 0x00 };
                out[5] = r.next_object_id;
                out[6] = count as u8;
                let mut p = 7;
                for o in r.objects.iter() {
                    out[p] = o.id;
                    out[p + 1] = o.value.len() as u8;
                    p += 2;
                    p += o.value.copy_to(&mut out[p..n])?;
                }
            }
            ReplyPdu::Exception { function, code } => {
                function_ok(function)?;
                out[1] = code.0;
            }
            ReplyPdu::Other { function, data } => {
                function_ok(function)?;
                data.copy_to(&mut out[1..n])?;
            }
        }
        Ok(n)
    }
}
