//! Modbus on a serial line: RTU ([`rtu`]) and ASCII ([`ascii`]), as the drives of
//! `seeds/002_43d8a4399c8be05f.txt` (Toshiba VF-AS1, Modbus-RTU) and
//! `seeds/004_e8ea1998fe1a671e.txt` (generic Chinese VFD, 2000H/2100H map, RTU and ASCII) speak it.
//!
//! - [`pdu`]: the PDU (function code + data), shared with a Modbus TCP server.
//! - [`Request`] / [`Reply`]: a unit address plus a PDU, the same for RTU and ASCII; [`Frame`]
//!   is either, for tools ([`crate::Codec`], [`crate::Describe`]).
//! - [`rtu`]: address + PDU + CRC (low byte first), delimited by silence, and its scanner.
//! - [`ascii`]: `:` + hex digits + LRC + CR LF.
//!
//! Addressing (seed 002: "Specify an inverter number between 0 and 247"; seed 004: up to 254
//! (FEH)): address 0 is a broadcast that every drive executes and none answers
//! (seed 004: "主机使用广播地址发送命令时, 从机不应答", when the master sends with the
//! broadcast address the slaves do not answer). drivebus accepts 1..=255 as unit numbers
//! and leaves the 247 limit of the specification to the user.

/// The session [`Protocol`](crate::session::Protocol) of a Modbus framing: the same for RTU and
/// ASCII but for the scanners, the frame methods and the framing's own `rejected` (which frames
/// that do not parse the addressee answers).
macro_rules! modbus_protocol {
    ($framing:ty, $scanner:ty, replies: $replies:expr, requests: $requests:expr, $emit:ident, $parse:ident) => {
        impl Protocol for $framing {
            type ReplyScanner = $scanner;
            type RequestScanner = $scanner;
            type Request<'a> = Request<'a>;
            type Reply<'a> = Reply<'a>;
            type Pending = Pending;

            fn reply_scanner(&self) -> $scanner {
                $replies
            }
            fn request_scanner(&self) -> $scanner {
                $requests
            }
            fn emit_request(&self, req: &Request<'_>, out: &mut [u8]) -> Result<usize, EmitError> {
                req.$emit(out)
            }
            fn emit_reply(&self, rep: &Reply<'_>, out: &mut [u8]) -> Result<usize, EmitError> {
                rep.$emit(out)
            }
            fn parse_request<'a>(&self, bytes: &'a [u8]) -> Result<Request<'a>, FrameError> {
                Request::$parse(bytes)
            }
            fn parse_reply<'a>(&self, bytes: &'a [u8]) -> Result<Reply<'a>, FrameError> {
                Reply::$parse(bytes)
            }
            fn pending(&self, req: &Request<'_>) -> Option<Pending> {
                req.pending()
            }
            fn matches(&self, pending: &Pending, rep: &Reply<'_>) -> bool {
                pending.matches(rep)
            }
            fn reply_matches(&self, pending: &Pending, bytes: &[u8]) -> Result<bool, FrameError> {
                self.answers(pending, bytes)
            }
            fn disposition(&self, req: &Request<'_>, me: u8) -> Disposition {
                req.disposition(me)
            }
            fn rejected_disposition(&self, bytes: &[u8], _error: &FrameError, me: u8) -> Disposition {
                self.rejected(bytes, me)
            }
        }
    };
}

pub mod ascii;
pub mod pdu;
pub mod rtu;
pub mod tcp;

#[cfg(test)]
mod tests;

use core::fmt;

use crate::describe::{CodeStyle, Command, Describe, Direction, Field, Target};
use crate::session::Disposition;

pub use pdu::{
    Data, DeviceIdReply, DeviceObject, DeviceObjects, ExceptionCode, ReadDeviceIdCode, RegisterAddress,
    Registers, ReplyPdu, RequestPdu,
};

/// A PDU length error told in the bytes of the ADU that carries the PDU: `overhead` (the
/// address, and the CRC of an RTU frame) added to both counts; other errors unchanged.
pub(crate) fn adu_error(e: crate::FrameError, overhead: usize) -> crate::FrameError {
    use crate::FrameError;
    match e {
        FrameError::Truncated { what, expected, got } => {
            FrameError::Truncated { what, expected: expected + overhead, got: got + overhead }
        }
        FrameError::TooLong { what, max, got } => {
            FrameError::TooLong { what, max: max + overhead, got: got + overhead }
        }
        e => e,
    }
}

/// A Modbus unit (slave) address: 0 is broadcast, 1..=247 single drives (seed 004 allows up to 254).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct UnitId(pub u8);

impl UnitId {
    /// Address 0: every drive acts, none answers.
    pub const BROADCAST: UnitId = UnitId(0);

    /// True for address 0.
    pub const fn is_broadcast(self) -> bool {
        self.0 == 0
    }

    /// The target a tool shows.
    pub const fn target(self) -> Target {
        if self.is_broadcast() {
            Target::Broadcast
        } else {
            Target::Unit(self.0)
        }
    }
}

impl fmt::Display for UnitId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// A request: the unit it addresses and the PDU (the same for RTU and ASCII).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Request<'a> {
    /// The drive addressed (Toshiba: inverter number; seed 004: address), 0 = broadcast.
    pub unit: UnitId,
    /// Function code and data.
    pub pdu: RequestPdu<'a>,
}

/// A reply: the unit that answers and the PDU.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reply<'a> {
    /// The drive answering.
    pub unit: UnitId,
    /// Function code and data (or an exception).
    pub pdu: ReplyPdu<'a>,
}

/// A frame in either direction, for tools.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Frame<'a> {
    /// From the master.
    Request(Request<'a>),
    /// From a drive.
    Reply(Reply<'a>),
}

/// What a reply must match: the unit and the function (or its exception).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Pending {
    /// The unit asked.
    pub unit: UnitId,
    /// The function asked for.
    pub function: u8,
}

impl<'a> Request<'a> {
    /// 03: read `quantity` holding registers from `start`.
    pub const fn read_holding_registers(unit: UnitId, start: u16, quantity: u16) -> Self {
        Request { unit, pdu: RequestPdu::ReadHoldingRegisters { start: RegisterAddress(start), quantity } }
    }

    /// 04: read `quantity` input registers from `start`.
    pub const fn read_input_registers(unit: UnitId, start: u16, quantity: u16) -> Self {
        Request { unit, pdu: RequestPdu::ReadInputRegisters { start: RegisterAddress(start), quantity } }
    }

    /// 06: write `value` into register `address`.
    pub const fn write_single_register(unit: UnitId, address: u16, value: u16) -> Self {
        Request { unit, pdu: RequestPdu::WriteSingleRegister { address: RegisterAddress(address), value } }
    }

    /// 10: write `values` from `start`.
    pub const fn write_multiple_registers(unit: UnitId, start: u16, values: &'a [u16]) -> Self {
        Request {
            unit,
            pdu: RequestPdu::WriteMultipleRegisters {
                start: RegisterAddress(start),
                values: Registers::from_values(values),
            },
        }
    }

    /// 08: diagnostics `sub_function` with `data` (seed 004's loop-back test).
    pub const fn diagnostics(unit: UnitId, sub_function: u16, data: &'a [u8]) -> Self {
        Request { unit, pdu: RequestPdu::Diagnostics { sub_function, data: Data::binary(data) } }
    }

    /// 2B/0E: read device identification `code` from `object_id`.
    pub const fn read_device_identification(unit: UnitId, code: ReadDeviceIdCode, object_id: u8) -> Self {
        Request { unit, pdu: RequestPdu::ReadDeviceIdentification { code, object_id } }
    }

    /// What the reply must match, or `None` for a broadcast (no reply is due).
    pub fn pending(&self) -> Option<Pending> {
        (!self.unit.is_broadcast()).then_some(Pending { unit: self.unit, function: self.pdu.function() })
    }

    /// How a slave numbered `me` treats this request.
    pub fn disposition(&self, me: u8) -> Disposition {
        disposition(self.unit.0, me)
    }
}

impl Reply<'_> {
    /// An exception reply from `unit` refusing `function`.
    pub const fn exception(unit: UnitId, function: u8, code: ExceptionCode) -> Reply<'static> {
        Reply { unit, pdu: ReplyPdu::Exception { function: function & 0x7F, code } }
    }
}

impl Pending {
    /// True when `rep` answers it: same unit, same function or its exception.
    #[inline]
    pub fn matches(&self, rep: &Reply<'_>) -> bool {
        rep.unit == self.unit && rep.pdu.answers_function() == self.function
    }

    /// True when a reply from `unit` with `function` in its header answers it (the function or
    /// its exception), whatever follows.
    #[inline]
    pub fn matches_header(&self, unit: u8, function: u8) -> bool {
        unit == self.unit.0 && function & !pdu::function::EXCEPTION_BIT == self.function
    }
}

/// Address filter of a slave numbered `me` for a frame sent to `address`.
#[inline]
pub(crate) fn disposition(address: u8, me: u8) -> Disposition {
    if address == me {
        Disposition::Mine
    } else if address == 0 {
        // seed 002: "Data will not be returned if "0" (broadcast communication)".
        Disposition::Broadcast { reply: false }
    } else {
        Disposition::NotMine
    }
}

/// A register of the seed drives' maps, for annotating frames.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RegisterInfo {
    /// What the register holds, with the drive it belongs to.
    pub name: &'static str,
    /// The unit, the value of one count in it, and the decimals that resolution gives.
    pub unit: Option<(&'static str, f64, u8)>,
}

impl RegisterInfo {
    /// The raw register value in the register's unit (`0x1770` -> `60.0` for a 0.01 Hz
    /// register), or `None` for a register without a unit.
    pub fn quantity(&self, raw: u16) -> Option<f64> {
        self.unit.map(|(_, scale, _)| raw as f64 * scale)
    }

    /// The raw register value for `value` in the register's unit (`50.0` Hz -> `5000` for a
    /// 0.01 Hz register), rounded; `None` without a unit or when it does not fit 0..=65535.
    pub fn raw(&self, value: f64) -> Option<u16> {
        let (_, scale, _) = self.unit?;
        let raw = value / scale;
        // Round half up without `f64::round` (not in `core`); NaN fails the range test.
        (-0.5..65535.5).contains(&raw).then_some((raw + 0.5) as u16)
    }
}

/// The seed drives' registers that drivebus knows by name. The two maps do not overlap:
/// the generic VFD (seed 004) uses 2000H–210BH, the Toshiba (seed 002) FAxx–FExx.
/// Parameters (generic Pgg.nn at GGnnH, Toshiba's low communication numbers) overlap and
/// are not named.
pub fn register_info(address: RegisterAddress) -> Option<RegisterInfo> {
    const HZ: Option<(&str, f64, u8)> = Some(("Hz", 0.01, 2));
    let (name, unit) = match address.0 {
        0x2000 => {
            ("command (generic VFD: 1 run, 2 fwd, 3 rev, 4 jog, 7 decel stop, 8 e-stop, A reset)", None)
        }
        0x2001 => ("frequency set (generic VFD)", HZ),
        0x2100 => ("fault code (generic VFD)", None),
        0x2101 => ("status bits (generic VFD)", None),
        0x2102 => ("set frequency (generic VFD)", HZ),
        0x2103 => ("output frequency (generic VFD)", HZ),
        0x2104 => ("output current (generic VFD)", Some(("A", 0.1, 1))),
        0x2105 => ("DC bus voltage (generic VFD)", Some(("V", 0.1, 1))),
        0x2106 => ("output voltage (generic VFD)", Some(("V", 1.0, 0))),
        0x2107 => ("motor speed (generic VFD)", Some(("rpm", 1.0, 0))),
        0x2108 => ("module temperature (generic VFD)", Some(("degC", 0.1, 1))),
        0x2109 => ("VI analog input (generic VFD)", Some(("V", 0.01, 2))),
        0x210A => ("CI analog input (generic VFD)", Some(("mA", 0.01, 2))),
        0x210B => ("software version, BCD (generic VFD)", None),
        0xFA00 => ("communication command 1 (Toshiba)", None),
        0xFA01 => ("frequency command from communication (Toshiba)", HZ),
        0xFD00 => ("output frequency (Toshiba)", HZ),
        0xFD01 => ("inverter operating status 1 (Toshiba)", None),
        0xFE02 => ("frequency command value (Toshiba)", HZ),
        0xFE03 => ("output current (Toshiba)", Some(("%", 0.01, 2))),
        0xFE05 => ("output voltage (Toshiba)", Some(("%", 0.01, 2))),
        0xFC90 => ("current trip code (Toshiba)", None),
        0xFC91 => ("alarm information (Toshiba)", None),
        0xFE70 => ("rated current (Toshiba)", Some(("A", 0.1, 1))),
        _ => return None,
    };
    Some(RegisterInfo { name, unit })
}

/// The standard name of a diagnostics sub-function.
pub const fn sub_function_meaning(sub: u16) -> &'static str {
    match sub {
        0x0000 => "return query data",
        0x0001 => "restart communications option",
        0x0002 => "return diagnostic register",
        0x0003 => "change ASCII input delimiter",
        0x0004 => "force listen only mode",
        0x000A => "clear counters and diagnostic register",
        0x000B => "return bus message count",
        0x000C => "return bus communication error count",
        0x000D => "return bus exception error count",
        0x000E => "return server message count",
        0x000F => "return server no response count",
        0x0010 => "return server NAK count",
        0x0011 => "return server busy count",
        0x0012 => "return bus character overrun count",
        0x0014 => "clear overrun counter and flag",
        _ => "not a standard sub-function (seed 004's loop-back test echoes any)",
    }
}

const fn exception_name(function: u8) -> &'static str {
    match function {
        0x01 => "exception to read coils",
        0x02 => "exception to read discrete inputs",
        0x03 => "exception to read holding registers",
        0x04 => "exception to read input registers",
        0x05 => "exception to write single coil",
        0x06 => "exception to write single register",
        0x08 => "exception to diagnostics",
        0x0F => "exception to write multiple coils",
        0x10 => "exception to write multiple registers",
        0x2B => "exception to read device identification",
        _ => "exception",
    }
}

fn conformity_meaning(level: u8) -> &'static str {
    match level {
        0x01 => "basic identification, stream access only",
        0x02 => "regular identification, stream access only",
        0x03 => "extended identification, stream access only",
        0x81 => "basic identification, stream and individual access",
        0x82 => "regular identification, stream and individual access",
        0x83 => "extended identification, stream and individual access",
        _ => "not a conformity level the specification defines",
    }
}

/// Calls `f` with the bytes of `data` in binary (decoding hex digits into a stack buffer).
fn with_binary<R>(data: Data<'_>, f: impl FnOnce(&[u8]) -> R) -> R {
    match data.as_binary() {
        Some(b) => f(b),
        None => {
            let mut buf = [0u8; pdu::MAX_PDU];
            let n = data.len().min(buf.len());
            for (o, b) in buf.iter_mut().zip(data.iter()) {
                *o = b;
            }
            f(&buf[..n])
        }
    }
}

fn address_field(name: &'static str, a: RegisterAddress) -> Field<'static> {
    let f = Field::hex(name, a.0 as u32, 4);
    match register_info(a) {
        Some(info) => f.with_meaning(info.name),
        None => f,
    }
}

fn value_field(a: Option<RegisterAddress>, v: u16) -> Field<'static> {
    let f = Field::hex("register value", v as u32, 4);
    match a.and_then(register_info).and_then(|i| i.unit) {
        Some((unit, scale, decimals)) => f.with_quantity(v as f64 * scale, unit, decimals),
        None => f,
    }
}

fn register_fields(start: Option<RegisterAddress>, values: &Registers<'_>, out: &mut dyn FnMut(Field<'_>)) {
    for (i, v) in values.iter().enumerate() {
        let a = start.map(|s| RegisterAddress(s.0.wrapping_add(i as u16)));
        out(value_field(a, v));
    }
}

/// The fields of an 06 request or reply: the register and its value.
fn single_register_fields(address: RegisterAddress, value: u16, out: &mut dyn FnMut(Field<'_>)) {
    out(address_field("register address", address));
    out(value_field(Some(address), value));
}

/// The fields of an 08 request or reply: the sub-function and the data.
fn diagnostics_fields(sub_function: u16, data: Data<'_>, out: &mut dyn FnMut(Field<'_>)) {
    out(Field::hex("sub-function", sub_function as u32, 4).with_meaning(sub_function_meaning(sub_function)));
    data_field(data, out);
}

/// The data of a PDU shown as bytes.
fn data_field(data: Data<'_>, out: &mut dyn FnMut(Field<'_>)) {
    with_binary(data, |b| out(Field::bytes("data", b)));
}

fn mei_fields(code: ReadDeviceIdCode, out: &mut dyn FnMut(Field<'_>)) {
    out(Field::hex("MEI type", pdu::MEI_READ_DEVICE_ID as u32, 2).with_meaning("read device identification"));
    let f = Field::hex("read device ID code", code.0 as u32, 2);
    out(match code.meaning() {
        Some(m) => f.with_meaning(m),
        None => f,
    });
}

fn object_id_field(name: &'static str, id: u8) -> Field<'static> {
    let f = Field::hex(name, id as u32, 2);
    match pdu::object_name(id) {
        Some(m) => f.with_meaning(m),
        None => f,
    }
}

impl Describe for Request<'_> {
    fn direction(&self) -> Direction {
        Direction::Master
    }
    fn target(&self) -> Target {
        self.unit.target()
    }
    fn command(&self) -> Command {
        let code = self.pdu.function();
        Command { code, style: CodeStyle::Hex, name: pdu::function_name(code) }
    }
    fn fields(&self, out: &mut dyn FnMut(Field<'_>)) {
        match self.pdu {
            RequestPdu::ReadHoldingRegisters { start, quantity }
            | RequestPdu::ReadInputRegisters { start, quantity } => {
                out(address_field("starting address", start));
                out(Field::dec("quantity", quantity as i64));
            }
            RequestPdu::WriteSingleRegister { address, value } => single_register_fields(address, value, out),
            RequestPdu::Diagnostics { sub_function, data } => diagnostics_fields(sub_function, data, out),
            RequestPdu::WriteMultipleRegisters { start, values } => {
                out(address_field("starting address", start));
                out(Field::dec("quantity", values.len() as i64));
                out(Field::dec("byte count", 2 * values.len() as i64));
                register_fields(Some(start), &values, out);
            }
            RequestPdu::ReadWriteMultipleRegisters { read_start, read_quantity, write_start, values } => {
                out(address_field("read starting address", read_start));
                out(Field::dec("quantity to read", read_quantity as i64));
                out(address_field("write starting address", write_start));
                out(Field::dec("quantity to write", values.len() as i64));
                out(Field::dec("write byte count", 2 * values.len() as i64));
                register_fields(Some(write_start), &values, out);
            }
            RequestPdu::ReadDeviceIdentification { code, object_id } => {
                mei_fields(code, out);
                out(object_id_field("object ID", object_id));
            }
            RequestPdu::Other { data, .. } => data_field(data, out),
        }
    }
}

impl Describe for Reply<'_> {
    fn direction(&self) -> Direction {
        Direction::Drive
    }
    fn target(&self) -> Target {
        self.unit.target()
    }
    fn command(&self) -> Command {
        let code = self.pdu.function();
        let name = match self.pdu {
            ReplyPdu::Exception { function, .. } => exception_name(function),
            _ => pdu::function_name(code),
        };
        Command { code, style: CodeStyle::Hex, name }
    }
    fn is_refusal(&self) -> bool {
        self.pdu.is_exception()
    }
    fn fields(&self, out: &mut dyn FnMut(Field<'_>)) {
        match self.pdu {
            ReplyPdu::ReadHoldingRegisters { values }
            | ReplyPdu::ReadInputRegisters { values }
            | ReplyPdu::ReadWriteMultipleRegisters { values } => {
                out(Field::dec("byte count", 2 * values.len() as i64));
                register_fields(None, &values, out);
            }
            ReplyPdu::WriteSingleRegister { address, value } => single_register_fields(address, value, out),
            ReplyPdu::Diagnostics { sub_function, data } => diagnostics_fields(sub_function, data, out),
            ReplyPdu::WriteMultipleRegisters { start, quantity } => {
                out(address_field("starting address", start));
                out(Field::dec("quantity", quantity as i64));
            }
            ReplyPdu::ReadDeviceIdentification(r) => {
                mei_fields(r.code, out);
                out(Field::hex("conformity level", r.conformity_level as u32, 2)
                    .with_meaning(conformity_meaning(r.conformity_level)));
                out(Field::hex("more follows", if r.more_follows { 0xFF } else { 0 }, 2));
                out(object_id_field("next object ID", r.next_object_id));
                out(Field::dec("number of objects", r.objects.len() as i64));
                for o in r.objects.iter() {
                    out(object_id_field("object ID", o.id));
                    out(Field::dec("object length", o.value.len() as i64));
                    with_binary(o.value, |b| out(Field::text("object value", b)));
                }
            }
            ReplyPdu::Exception { code, .. } => {
                let f = Field::hex("exception code", code.0 as u32, 2);
                out(f.with_meaning(
                    code.meaning().unwrap_or("not an exception code the specification defines"),
                ));
            }
            ReplyPdu::Other { data, .. } => data_field(data, out),
        }
    }
}

impl Frame<'_> {
    /// The request or the reply, which describes itself.
    fn inner(&self) -> &dyn Describe {
        match self {
            Frame::Request(r) => r,
            Frame::Reply(r) => r,
        }
    }
}

impl Describe for Frame<'_> {
    fn direction(&self) -> Direction {
        self.inner().direction()
    }
    fn target(&self) -> Target {
        self.inner().target()
    }
    fn command(&self) -> Command {
        self.inner().command()
    }
    fn is_refusal(&self) -> bool {
        self.inner().is_refusal()
    }
    fn fields(&self, out: &mut dyn FnMut(Field<'_>)) {
        self.inner().fields(out)
    }
}

/// Reads a frame in the direction `from`, or as a request first and a reply second.
pub(crate) fn parse_either<'a>(
    from: Option<Direction>,
    request: impl FnOnce() -> Result<Request<'a>, crate::FrameError>,
    reply: impl FnOnce() -> Result<Reply<'a>, crate::FrameError>,
    function: Option<u8>,
) -> Result<Frame<'a>, crate::FrameError> {
    match from {
        Some(Direction::Master) => request().map(Frame::Request),
        Some(Direction::Drive) => reply().map(Frame::Reply),
        None => match request() {
            Ok(r) => Ok(Frame::Request(r)),
            Err(req_err) => match reply() {
                Ok(r) => Ok(Frame::Reply(r)),
                // An exception code can only be a reply: its error says more.
                Err(rep_err) if function.is_some_and(|f| f & 0x80 != 0) => Err(rep_err),
                Err(_) => Err(req_err),
            },
        },
    }
}
