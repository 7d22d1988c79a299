//! The generic Chinese VFD of `seeds/004_e8ea1998fe1a671e.txt`: Modbus RTU or ASCII with the
//! 2000H/2100H register map and the parameters Pgg.nn at register 0xGGNN.
//!
//! | operation | exchanges |
//! |---|---|
//! | Status | 03 read 2100H..2103H (fault code, status bits, set and output frequency), 03 read 2104H (current): the drive answers at most 4 registers ("N<=8" data bytes). A drive that refuses the 4-register read (exception 02 or 03) is read one register per request (2100H..2104H) from then on |
//! | Run / Stop / Jog / Reset | 06 write 2000H = 1 (run in the commanded direction) / 7 (decelerate to stop) / 4 (jog) / 0AH (fault reset) |
//! | Reverse | 03 read 2101H, then 06 write 2000H = 3 (reverse run) or 2 (forward run), 6 or 5 while jogging |
//! | SetSpeed | 06 write 2001H, 0.01 Hz, after a check against the known limits |
//! | ReadParam / WriteParam | 03 read / 06 write of the register the catalog names |
//!
//! Decisions (where the manual is silent; they match the simulated drive of `drivebus-sim`):
//!
//! - **Reverse** needs a running drive. Commands 2 and 3 start the motor, and the only other way
//!   to set the direction of a plain run is P0.03, an EEPROM setting. A Reverse of a stopped
//!   drive is therefore [`DriveError::Unsupported`], with a sentence that says so.
//! - **Storage.** Function 06 is the only write. To a Pgg.nn setting it goes to EEPROM (the
//!   parameter keeps its value over power-off); 2000H and 2001H live in RAM. The master cannot
//!   choose, so a write must ask for the storage the catalog gives the parameter: a
//!   [`Storage::Ram`] write to an EEPROM setting (and a [`Storage::Eeprom`] write to a RAM
//!   register) is [`DriveError::Unsupported`], never silently turned into the other kind.
//! - **Speed limits.** SetSpeed is checked before anything is sent against the lower of P0.04
//!   (maximum frequency; 2001H above it is exception 03) and P0.05 (upper limit; the drive
//!   clamps the setpoint to it). The profile starts with the catalog defaults and learns the
//!   drive's values whenever a ReadParam or WriteParam of P0.04/P0.05 passes through it, or
//!   from [`GenericProfile::set_speed_limits`].
//! - **Refusals.** Exceptions 01, 02 and 03 are [`DriveError::Refused`] with the manual's
//!   meaning. The drive answers 03 to a command it cannot obey (run while tripped, run commands
//!   not from communication, reverse prohibited), so a Run while tripped is `Refused { code: 3 }`.
//! - **Fault codes.** The manual gives no list of 2100H codes; [`fault_text`] follows drivebus'
//!   numbering, the one the simulated drive uses.
//! - **Broadcast.** Address 0 reaches every drive and none answers: Run, Stop, Jog, Reset,
//!   SetSpeed and WriteParam go out with `expect_reply: false`; Status, ReadParam and Reverse
//!   need an answer and are [`DriveError::Unsupported`].

use std::fmt;
use std::str::FromStr;
use std::sync::atomic::{AtomicBool, AtomicI64, Ordering};
use std::sync::Arc;

use drivebus_proto::modbus::{ExceptionCode, Reply, ReplyPdu, Request, UnitId};

use super::{
    CodeSpace, DriveError, DriveStatus, Exchange, Fault, Operation, Outcome, Plan, Profile, Step,
    WireProtocol,
};
use crate::{format_fixed, Catalog, Family, ParamDef, Size, Storage};

pub use crate::registers::generic::{command, reg, status};

/// The broadcast address: every drive acts, none answers ("主机使用广播地址发送命令时, 从机不应答").
pub const BROADCAST: u8 = 0;

/// Refuses `what`, an operation that reads an answer, for the Modbus [`BROADCAST`] address
/// (no drive answers it); the generic and the templated drives share it.
pub(crate) fn needs_reply(address: u8, what: &str) -> Result<(), DriveError> {
    if address == BROADCAST {
        return Err(DriveError::Unsupported(format!(
            "{what} needs an answer, and no drive answers the broadcast address 0: use a drive's own address"
        )));
    }
    Ok(())
}
/// The highest address the manual allows ("最大可到 254 (FEH)").
pub const MAX_ADDRESS: u8 = 254;

/// Which Modbus transmission mode the drive speaks ("RTU 方式和ASCII 方式", selected by P3.10).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum GenericProtocol {
    /// Modbus RTU: binary, CRC-16, frames delimited by silence.
    Rtu,
    /// Modbus ASCII: `:` hex digits, LRC, CR LF (the manual's default mode).
    Ascii,
}

impl GenericProtocol {
    /// The wire protocol of this mode.
    pub fn wire(self) -> WireProtocol {
        self.framing().wire()
    }

    /// The mode that speaks `protocol`, if it is a Modbus framing.
    pub fn from_wire(protocol: WireProtocol) -> Option<Self> {
        match protocol {
            WireProtocol::ModbusRtu => Some(GenericProtocol::Rtu),
            WireProtocol::ModbusAscii => Some(GenericProtocol::Ascii),
            _ => None,
        }
    }

    fn framing(self) -> ModbusFraming {
        match self {
            GenericProtocol::Rtu => ModbusFraming::Rtu,
            GenericProtocol::Ascii => ModbusFraming::Ascii,
        }
    }
}

impl fmt::Display for GenericProtocol {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.wire().fmt(f)
    }
}

impl FromStr for GenericProtocol {
    type Err = DriveError;

    /// `modbus-rtu` or `modbus-ascii`, any letter case.
    fn from_str(s: &str) -> Result<Self, DriveError> {
        s.parse().ok().and_then(GenericProtocol::from_wire).ok_or_else(|| {
            DriveError::Unsupported(format!(
                "the generic drive speaks {} or {}, not {:?}",
                WireProtocol::ModbusRtu,
                WireProtocol::ModbusAscii,
                s.trim()
            ))
        })
    }
}

/// The text of a 2100H fault code. The manual gives no list; this is drivebus' numbering, the
/// one the simulated drive uses.
pub fn fault_text(code: u16) -> String {
    let text = match code {
        0 => "no fault",
        1 => "over-current",
        2 => "over-voltage",
        3 => "under-voltage",
        4 => "module over-temperature",
        5 => "external fault",
        6 => "communication time-out",
        _ => return format!("fault code {code} (the manual gives no list of 2100H codes)"),
    };
    text.to_string()
}

/// What an exception code means on this drive, in the manual's words ("错误码定义").
pub fn exception_meaning(code: u8) -> String {
    match code {
        0x01 => "function code error (功能码错误): the drive knows the function codes 03H, 06H and 08H"
            .to_string(),
        0x02 => "data address error (资料地址错误): the drive does not recognise the address, or the \
                 register cannot be written (a monitor)"
            .to_string(),
        0x03 => "data content error (资料内容错误。资料内容超限): the value is beyond its limits, or the \
                 drive cannot act on it now (a command while tripped or while run commands do not come \
                 from communication, P0.01 = 2; reverse prohibited by P0.03 = 2; a parameter locked by \
                 P0.15 or not writable while running)"
            .to_string(),
        other => match ExceptionCode(other).meaning() {
            Some(m) => format!("{m} (a Modbus exception the manual of this drive does not list)"),
            None => "an exception code neither the manual nor Modbus defines".to_string(),
        },
    }
}

/// A generic Chinese VFD at one address (0 = broadcast), spoken to in Modbus RTU or ASCII.
#[derive(Debug)]
pub struct GenericProfile {
    address: u8,
    protocol: GenericProtocol,
    catalog: Arc<Catalog>,
    limits: Arc<SpeedLimits>,
    /// The drive refused a multi-register read: status reads one register per request.
    word_reads: Arc<AtomicBool>,
}

impl GenericProfile {
    /// A profile for the drive at `address` (1..=254, or [`BROADCAST`] = 0) speaking `protocol`.
    pub fn new(address: u8, protocol: GenericProtocol) -> Result<Self, DriveError> {
        if address > MAX_ADDRESS {
            return Err(DriveError::OutOfRange(format!(
                "a generic drive's address is 1..254, or 0 for a broadcast; not {address}"
            )));
        }
        let catalog = Catalog::load(Family::Generic)
            .map_err(|e| DriveError::Unsupported(format!("the generic catalog does not load: {e}")))?;
        let limits =
            SpeedLimits::from_catalog(&catalog, "P0.04", "maximum frequency", "P0.05", "upper limit")?;
        Ok(GenericProfile {
            address,
            protocol,
            catalog,
            limits: Arc::new(limits),
            word_reads: Arc::new(AtomicBool::new(false)),
        })
    }

    /// The transmission mode in use.
    pub fn transmission(&self) -> GenericProtocol {
        self.protocol
    }

    /// True for the broadcast address 0.
    pub fn is_broadcast(&self) -> bool {
        self.address == BROADCAST
    }

    /// The limits SetSpeed is checked against, raw 0.01 Hz: (P0.04 maximum frequency, P0.05
    /// upper limit). They start at the catalog defaults.
    pub fn speed_limits(&self) -> (i64, i64) {
        self.limits.get()
    }

    /// Sets the limits SetSpeed is checked against, raw 0.01 Hz, as read from the drive. A
    /// ReadParam or WriteParam of P0.04 or P0.05 through this profile sets them as well.
    pub fn set_speed_limits(&self, max_frequency: i64, upper_limit: i64) {
        self.limits.set(max_frequency, upper_limit);
    }

    fn def(&self, name: &str) -> Result<&ParamDef, DriveError> {
        self.catalog.get(name).ok_or_else(|| {
            DriveError::Unsupported(format!(
                "{:?} is not a parameter of the generic drive (catalogs/generic.toml): name it as the \
                 manual does, P0.02 or 2103H",
                name.trim()
            ))
        })
    }

    fn needs_reply(&self, what: &str) -> Result<(), DriveError> {
        needs_reply(self.address, what)
    }

    fn plan_for(&self, job: Job) -> Box<dyn Plan> {
        Box::new(GenericPlan {
            framing: self.protocol.framing(),
            unit: self.address,
            limits: Arc::clone(&self.limits),
            word_reads: Arc::clone(&self.word_reads),
            job,
            stage: 0,
            sent: None,
            finished: false,
        })
    }
}

impl Profile for GenericProfile {
    fn family(&self) -> Family {
        Family::Generic
    }

    fn protocol(&self) -> WireProtocol {
        self.protocol.wire()
    }

    fn address(&self) -> u8 {
        self.address
    }

    fn param(&self, name: &str) -> Result<&ParamDef, DriveError> {
        self.def(name)
    }

    fn plan(&self, op: &Operation) -> Result<Box<dyn Plan>, DriveError> {
        let command = |value: u16, what: &str| Job::Write {
            register: reg::COMMAND,
            value,
            what: format!("2000H = {value} ({what})"),
            learn: None,
        };
        let job = match op {
            Operation::Status => {
                self.needs_reply("Status")?;
                Job::Status(StatusRead::default())
            }
            Operation::Run => command(command::RUN, "run"),
            Operation::Stop => command(command::DECELERATE_TO_STOP, "decelerate to stop"),
            Operation::Jog => command(command::JOG, "jog"),
            Operation::Reset => command(command::FAULT_RESET, "fault reset"),
            Operation::Reverse => {
                self.needs_reply("Reverse (it reads which way the drive turns)")?;
                Job::Reverse
            }
            Operation::SetSpeed(_) | Operation::ReadParam(_) | Operation::WriteParam { .. } => {
                let rules = RegisterRules {
                    setpoint: ("2001H", reg::FREQUENCY),
                    def: &|name| self.def(name),
                    needs_reply: &|what| self.needs_reply(what),
                    limits: &self.limits,
                    storage_check: &storage_rule,
                };
                match rules.job(op)? {
                    RegisterJob::Write { register, value, what, learn, .. } => {
                        Job::Write { register, value, what, learn }
                    }
                    RegisterJob::Read { register, signed, name } => Job::Read { register, signed, name },
                }
            }
        };
        Ok(self.plan_for(job))
    }
}

/// The generic drive writes every parameter where the catalog says it lives: a write must ask
/// for that storage.
fn storage_rule(def: &ParamDef, asked: Storage) -> Result<(), String> {
    if asked == def.storage {
        return Ok(());
    }
    Err(match asked {
        Storage::Ram => format!(
            "{} is an EEPROM setting and the generic drive stores every 06 write to it in EEPROM: the \
             protocol has no RAM-only write; ask for Storage::Eeprom",
            def.name
        ),
        Storage::Eeprom => format!(
            "{} lives in RAM only ({}): it cannot be stored in EEPROM; ask for Storage::Ram",
            def.name, def.title
        ),
    })
}

/// The Modbus register of a catalog entry (every generic and Toshiba number fits 16 bits).
pub(crate) fn register_of(def: &ParamDef) -> Result<u16, DriveError> {
    if def.size != Size::Word || def.array.is_some() {
        return Err(DriveError::Unsupported(format!(
            "{} is not a single 16-bit register; this profile reads and writes words only",
            def.name
        )));
    }
    u16::try_from(def.number).map_err(|_| {
        DriveError::Unsupported(format!("{} has number {:#X}, beyond 16 bits", def.name, def.number))
    })
}

/// The checks every WriteParam passes before anything is sent: read-only, storage (as
/// `storage_check` rules), range. The
/// result is the 16-bit value on the wire (negative values in two's complement).
pub(crate) fn checked_write(
    def: &ParamDef,
    raw: i64,
    storage: Storage,
    storage_check: &dyn Fn(&ParamDef, Storage) -> Result<(), String>,
) -> Result<u16, DriveError> {
    if def.read_only {
        return Err(DriveError::Unsupported(format!("{} ({}) is read-only", def.name, def.title)));
    }
    storage_check(def, storage).map_err(DriveError::Unsupported)?;
    def.check(raw).map_err(|e| DriveError::OutOfRange(e.to_string()))?;
    if raw < 0 {
        i16::try_from(raw).map(|v| v as u16).map_err(|_| {
            DriveError::OutOfRange(format!("{} = {raw} does not fit a 16-bit register", def.name))
        })
    } else {
        u16::try_from(raw).map_err(|_| {
            DriveError::OutOfRange(format!("{} = {raw} does not fit a 16-bit register", def.name))
        })
    }
}

/// What SetSpeed, ReadParam and WriteParam are on a drive whose parameters are 16-bit registers
/// (the generic drive, the VF-AS1): one write or one read of one register.
#[derive(Debug)]
pub(crate) enum RegisterJob {
    /// One write of `value` to `register`: `ram` for the setpoint and a [`Storage::Ram`] write,
    /// `what` in words, `learn` a parameter value the speed limits take note of.
    Write { register: u16, value: u16, ram: bool, what: String, learn: Option<(u32, i64)> },
    /// One read of `register`, two's complement where `signed`.
    Read { register: u16, signed: bool, name: String },
}

/// How a register profile checks SetSpeed, ReadParam and WriteParam before anything is sent.
pub(crate) struct RegisterRules<'a> {
    /// The setpoint's catalog name and register (`2001H`, `FA01`).
    pub(crate) setpoint: (&'static str, u16),
    /// The catalog entry of a parameter name, or the profile's refusal.
    pub(crate) def: &'a dyn Fn(&str) -> Result<&'a ParamDef, DriveError>,
    /// Refuses an operation that needs an answer at a broadcast address.
    pub(crate) needs_reply: &'a dyn Fn(&str) -> Result<(), DriveError>,
    /// The limits SetSpeed is checked against.
    pub(crate) limits: &'a SpeedLimits,
    /// The storage rules of the protocol in use.
    pub(crate) storage_check: &'a dyn Fn(&ParamDef, Storage) -> Result<(), String>,
}

impl RegisterRules<'_> {
    /// The job of `op`, a SetSpeed, ReadParam or WriteParam, after its checks.
    pub(crate) fn job(&self, op: &Operation) -> Result<RegisterJob, DriveError> {
        match op {
            Operation::SetSpeed(hz) => {
                let (name, register) = self.setpoint;
                let value = self.limits.check(*hz, (self.def)(name)?)?;
                let what = format!("{name} = {} Hz", format_fixed(i64::from(value), 2));
                Ok(RegisterJob::Write { register, value, ram: true, what, learn: None })
            }
            Operation::ReadParam(name) => {
                let def = (self.def)(name)?;
                (self.needs_reply)(&format!("ReadParam {}", def.name))?;
                let register = register_of(def)?;
                Ok(RegisterJob::Read { register, signed: def.min < 0, name: def.name.clone() })
            }
            Operation::WriteParam { name, raw, storage } => {
                let def = (self.def)(name)?;
                let register = register_of(def)?;
                let value = checked_write(def, *raw, *storage, self.storage_check)?;
                Ok(RegisterJob::Write {
                    register,
                    value,
                    ram: *storage == Storage::Ram,
                    what: format!("{} = {}", def.name, def.format(*raw)),
                    learn: Some((def.number, *raw)),
                })
            }
            other => Err(DriveError::Unsupported(format!("{other:?} is not a parameter read or write"))),
        }
    }
}

/// A register value read back as the catalog's raw integer (two's complement where the
/// parameter can be negative).
pub(crate) fn raw_of(value: u16, signed: bool) -> i64 {
    if signed {
        i64::from(value as i16)
    } else {
        i64::from(value)
    }
}

// ---------------------------------------------------------------------------------------------
// Speed limits, shared with the Toshiba profile
// ---------------------------------------------------------------------------------------------

/// The two frequency limits a setpoint must respect (maximum frequency and upper limit), raw
/// 0.01 Hz, known to a profile and its plans.
#[derive(Debug)]
pub(crate) struct SpeedLimits {
    max_number: u32,
    max_label: String,
    max: AtomicI64,
    upper_number: u32,
    upper_label: String,
    upper: AtomicI64,
}

impl SpeedLimits {
    /// Limits from two catalog entries' defaults; `*_what` name them in sentences.
    pub(crate) fn from_catalog(
        catalog: &Catalog,
        max_name: &str,
        max_what: &str,
        upper_name: &str,
        upper_what: &str,
    ) -> Result<Self, DriveError> {
        let find = |name: &str| {
            catalog
                .get(name)
                .ok_or_else(|| DriveError::Unsupported(format!("{} has no parameter {name}", catalog.file())))
        };
        let max = find(max_name)?;
        let upper = find(upper_name)?;
        Ok(SpeedLimits {
            max_number: max.number,
            max_label: format!("{max_what} {}", max.name),
            max: AtomicI64::new(max.default),
            upper_number: upper.number,
            upper_label: format!("{upper_what} {}", upper.name),
            upper: AtomicI64::new(upper.default),
        })
    }

    pub(crate) fn get(&self) -> (i64, i64) {
        (self.max.load(Ordering::Relaxed), self.upper.load(Ordering::Relaxed))
    }

    pub(crate) fn set(&self, max: i64, upper: i64) {
        self.max.store(max, Ordering::Relaxed);
        self.upper.store(upper, Ordering::Relaxed);
    }

    /// Takes note of a parameter value read from or written to the drive.
    pub(crate) fn learn(&self, number: u32, raw: i64) {
        if number == self.max_number {
            self.max.store(raw, Ordering::Relaxed);
        } else if number == self.upper_number {
            self.upper.store(raw, Ordering::Relaxed);
        }
    }

    /// Checks a setpoint in Hz and turns it into the raw 0.01 Hz value of `setpoint` (the
    /// register it is written to, whose catalog range bounds it too).
    pub(crate) fn check(&self, hz: f64, setpoint: &ParamDef) -> Result<u16, DriveError> {
        if !hz.is_finite() {
            return Err(DriveError::OutOfRange(format!("{hz} Hz is not a speed")));
        }
        if hz < 0.0 {
            return Err(DriveError::OutOfRange(format!(
                "{hz} Hz is below 0: the setpoint is a frequency without sign; Reverse changes the direction"
            )));
        }
        let (max, upper) = self.get();
        let (limit, label) = if upper <= max { (upper, &self.upper_label) } else { (max, &self.max_label) };
        let above = || {
            DriveError::OutOfRange(format!("{hz} Hz is above the {label} = {} Hz", format_fixed(limit, 2)))
        };
        let raw = setpoint.to_raw(hz).map_err(|_| above())?;
        if raw > limit {
            return Err(above());
        }
        u16::try_from(raw).map_err(|_| above())
    }
}

// ---------------------------------------------------------------------------------------------
// Modbus requests and replies, shared with the Toshiba profile
// ---------------------------------------------------------------------------------------------

/// RTU or ASCII framing of one Modbus request/reply.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ModbusFraming {
    Rtu,
    Ascii,
}

/// A Modbus request the profiles send: one 03 or 04 read, one 06 write, or one 10 write of up to
/// [`WRITE_MAX`] registers (a template's 32-bit values and its commands over adjacent registers).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ModbusAsk {
    /// 03: `quantity` registers from `start`.
    Read { start: u16, quantity: u16 },
    /// 04: `quantity` input registers from `start`.
    ReadInput { start: u16, quantity: u16 },
    /// 06: `value` into `register`.
    Write { register: u16, value: u16 },
    /// 10: the first `count` of `values` into `start` and the registers after it.
    WriteMany { start: u16, count: u8, values: [u16; WRITE_MAX] },
}

/// The most registers one 10 write of a profile carries.
pub(crate) const WRITE_MAX: usize = 16;

impl ModbusAsk {
    /// The request that writes `words` from `register`: 06 for one, 10 for more (at most
    /// [`WRITE_MAX`]; the rest are left out, so callers split longer runs first).
    pub(crate) fn write_words(register: u16, words: &[u16]) -> ModbusAsk {
        match words {
            [value] => ModbusAsk::Write { register, value: *value },
            _ => {
                let count = words.len().min(WRITE_MAX);
                let mut values = [0; WRITE_MAX];
                values[..count].copy_from_slice(&words[..count]);
                ModbusAsk::WriteMany { start: register, count: count as u8, values }
            }
        }
    }
}

impl fmt::Display for ModbusAsk {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            ModbusAsk::Read { start, quantity: 1 } => write!(f, "03 read of {start:04X}H"),
            ModbusAsk::Read { start, quantity } => {
                write!(f, "03 read of {start:04X}H..{:04X}H", u32::from(start) + u32::from(quantity) - 1)
            }
            ModbusAsk::ReadInput { start, quantity: 1 } => write!(f, "04 read of {start:04X}H"),
            ModbusAsk::ReadInput { start, quantity } => {
                write!(f, "04 read of {start:04X}H..{:04X}H", u32::from(start) + u32::from(quantity) - 1)
            }
            ModbusAsk::Write { register, value } => write!(f, "06 write of {value:04X}H to {register:04X}H"),
            ModbusAsk::WriteMany { start, count, ref values } => {
                f.write_str("10 write of")?;
                for v in &values[..usize::from(count)] {
                    write!(f, " {v:04X}H")?;
                }
                let last = u32::from(start) + u32::from(count).max(1) - 1;
                write!(f, " to {start:04X}H..{last:04X}H")
            }
        }
    }
}

/// What a Modbus reply said.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) enum ModbusAnswer {
    /// The registers read, as many as asked.
    Registers(Vec<u16>),
    /// The write was echoed.
    Written,
    /// An exception with this code.
    Exception(u8),
}

impl ModbusFraming {
    pub(crate) fn wire(self) -> WireProtocol {
        match self {
            ModbusFraming::Rtu => WireProtocol::ModbusRtu,
            ModbusFraming::Ascii => WireProtocol::ModbusAscii,
        }
    }

    fn long_name(self) -> &'static str {
        match self {
            ModbusFraming::Rtu => "Modbus RTU",
            ModbusFraming::Ascii => "Modbus ASCII",
        }
    }

    /// The whole frame of `ask` to `unit`.
    pub(crate) fn encode(self, unit: u8, ask: ModbusAsk) -> Result<Vec<u8>, DriveError> {
        let request = match ask {
            ModbusAsk::Read { start, quantity } => {
                Request::read_holding_registers(UnitId(unit), start, quantity)
            }
            ModbusAsk::ReadInput { start, quantity } => {
                Request::read_input_registers(UnitId(unit), start, quantity)
            }
            ModbusAsk::Write { register, value } => {
                Request::write_single_register(UnitId(unit), register, value)
            }
            ModbusAsk::WriteMany { start, count, ref values } => {
                let values = &values[..usize::from(count)];
                return self.emit(ask, &Request::write_multiple_registers(UnitId(unit), start, values));
            }
        };
        self.emit(ask, &request)
    }

    fn emit(self, ask: ModbusAsk, request: &Request<'_>) -> Result<Vec<u8>, DriveError> {
        let mut out = [0u8; 520];
        let n = match self {
            ModbusFraming::Rtu => request.emit_rtu(&mut out),
            ModbusFraming::Ascii => request.emit_ascii(&mut out),
        }
        .map_err(|e| DriveError::Protocol(format!("the {ask} cannot be framed: {e}")))?;
        Ok(out[..n].to_vec())
    }

    /// Reads the reply of `unit` to `ask`; anything that does not answer it is a protocol error.
    pub(crate) fn decode(self, unit: u8, ask: ModbusAsk, bytes: &[u8]) -> Result<ModbusAnswer, DriveError> {
        let bad = |why: String| DriveError::Protocol(format!("the reply to the {ask} {why}"));
        let reply = match self {
            ModbusFraming::Rtu => Reply::parse_rtu(bytes),
            ModbusFraming::Ascii => Reply::parse_ascii(bytes),
        }
        .map_err(|e| bad(format!("is not a valid {} frame: {e}", self.long_name())))?;
        if reply.unit.0 != unit {
            return Err(bad(format!("came from unit {}, not {unit}", reply.unit.0)));
        }
        let function = match ask {
            ModbusAsk::Read { .. } => 0x03,
            ModbusAsk::ReadInput { .. } => 0x04,
            ModbusAsk::Write { .. } => 0x06,
            ModbusAsk::WriteMany { .. } => 0x10,
        };
        match (reply.pdu, ask) {
            (ReplyPdu::Exception { function: f, code }, _) if f == function => {
                Ok(ModbusAnswer::Exception(code.0))
            }
            (ReplyPdu::ReadHoldingRegisters { values }, ModbusAsk::Read { quantity, .. })
            | (ReplyPdu::ReadInputRegisters { values }, ModbusAsk::ReadInput { quantity, .. }) => {
                if values.len() != usize::from(quantity) {
                    return Err(bad(format!("carries {} registers, not {quantity}", values.len())));
                }
                Ok(ModbusAnswer::Registers(values.iter().collect()))
            }
            (
                ReplyPdu::WriteSingleRegister { address, value },
                ModbusAsk::Write { register, value: sent },
            ) => {
                if address.0 != register || value != sent {
                    return Err(bad(format!(
                        "echoes {value:04X}H to {:04X}H instead of the value written",
                        address.0
                    )));
                }
                Ok(ModbusAnswer::Written)
            }
            (
                ReplyPdu::WriteMultipleRegisters { start, quantity },
                ModbusAsk::WriteMany { start: sent, count, .. },
            ) => {
                if start.0 != sent || quantity != u16::from(count) {
                    return Err(bad(format!("confirms {quantity} registers at {:04X}H instead", start.0)));
                }
                Ok(ModbusAnswer::Written)
            }
            (pdu, _) => Err(bad(format!("has function code {:02X}H, not {function:02X}H", pdu.function()))),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Plans
// ---------------------------------------------------------------------------------------------

/// What a plan does.
#[derive(Debug)]
enum Job {
    /// 2100H..2103H, then 2104H.
    Status(StatusRead),
    /// One 06 write; `learn` tells the limits a parameter value.
    Write { register: u16, value: u16, what: String, learn: Option<(u32, i64)> },
    /// 2101H, then 2000H = 2/3/5/6.
    Reverse,
    /// One 03 read of one register.
    Read { register: u16, signed: bool, name: String },
}

impl Job {
    /// The operation in words, for refusals.
    fn what(&self) -> String {
        match self {
            Job::Status(_) => "Status".to_string(),
            Job::Write { what, .. } => what.clone(),
            Job::Reverse => "Reverse".to_string(),
            Job::Read { name, .. } => format!("ReadParam {name}"),
        }
    }
}

#[derive(Debug, Default)]
struct StatusRead {
    fault: u16,
    bits: u16,
    set: u16,
    output: u16,
}

/// An operation in progress on a generic drive.
struct GenericPlan {
    framing: ModbusFraming,
    unit: u8,
    limits: Arc<SpeedLimits>,
    /// Shared with the profile: status reads one register per request.
    word_reads: Arc<AtomicBool>,
    job: Job,
    /// Exchanges answered so far.
    stage: u8,
    /// The request awaiting its reply.
    sent: Option<ModbusAsk>,
    finished: bool,
}

/// What a plan does next.
type Next = super::Next<ModbusAsk>;

impl GenericPlan {
    fn broadcast(&self) -> bool {
        self.unit == BROADCAST
    }

    /// The answer to the request in flight: registers, a write's echo (or a broadcast's
    /// silence), or the drive's refusal.
    fn answer(&self, ask: ModbusAsk, reply: Option<&[u8]>) -> Result<ModbusAnswer, DriveError> {
        if self.broadcast() {
            return Ok(ModbusAnswer::Written);
        }
        let bytes = reply.ok_or_else(|| DriveError::Protocol(format!("no reply came to the {ask}")))?;
        match self.framing.decode(self.unit, ask, bytes)? {
            ModbusAnswer::Exception(code) => Err(DriveError::Refused {
                code: u32::from(code),
                space: CodeSpace::ModbusException,
                meaning: format!("{} (in reply to the {ask}: {})", exception_meaning(code), self.job.what()),
            }),
            answer => Ok(answer),
        }
    }

    fn advance(&mut self, answer: Option<ModbusAnswer>) -> Result<Next, DriveError> {
        let regs = match &answer {
            Some(ModbusAnswer::Registers(r)) => r.as_slice(),
            _ => &[],
        };
        // The reply has been checked against the request: as many registers as asked.
        let word = |i: usize| regs.get(i).copied().unwrap_or(0);
        let stage = self.stage;
        self.stage = self.stage.saturating_add(1);
        match &mut self.job {
            Job::Status(s) if self.word_reads.load(Ordering::Relaxed) => {
                // 2100H, 2101H, 2102H, 2103H, 2104H one by one.
                if stage > 0 {
                    let value = word(0);
                    match stage {
                        1 => s.fault = value,
                        2 => s.bits = value,
                        3 => s.set = value,
                        4 => s.output = value,
                        _ => return Ok(Next::Done(Outcome::Status(status_of(self.unit, s, value)))),
                    }
                }
                Ok(Next::Send(ModbusAsk::Read { start: reg::FAULT_CODE + u16::from(stage), quantity: 1 }))
            }
            Job::Status(s) => match stage {
                0 => Ok(Next::Send(ModbusAsk::Read { start: reg::FAULT_CODE, quantity: 4 })),
                1 => {
                    *s = StatusRead { fault: word(0), bits: word(1), set: word(2), output: word(3) };
                    Ok(Next::Send(ModbusAsk::Read { start: reg::OUTPUT_CURRENT, quantity: 1 }))
                }
                _ => Ok(Next::Done(Outcome::Status(status_of(self.unit, s, word(0))))),
            },
            Job::Write { register, value, learn, .. } => match stage {
                0 => Ok(Next::Send(ModbusAsk::Write { register: *register, value: *value })),
                _ => {
                    if let Some((number, raw)) = learn {
                        self.limits.learn(*number, *raw);
                    }
                    Ok(Next::Done(Outcome::Done))
                }
            },
            Job::Reverse => match stage {
                0 => Ok(Next::Send(ModbusAsk::Read { start: reg::STATUS, quantity: 1 })),
                1 => {
                    let bits = word(0);
                    if bits & status::RUN == 0 {
                        return Err(DriveError::Unsupported(
                            "the drive is stopped, and the generic drive has no command that sets the \
                             direction without starting the motor (2000H = 2 and 3 run it; P0.03 is an \
                             EEPROM setting): Reverse acts on a running drive"
                                .to_string(),
                        ));
                    }
                    let reverse = bits & status::REVERSE != 0;
                    let value = match (bits & status::JOG != 0, reverse) {
                        (true, true) => command::JOG_FORWARD,
                        (true, false) => command::JOG_REVERSE,
                        (false, true) => command::FORWARD_RUN,
                        (false, false) => command::REVERSE_RUN,
                    };
                    Ok(Next::Send(ModbusAsk::Write { register: reg::COMMAND, value }))
                }
                _ => Ok(Next::Done(Outcome::Done)),
            },
            Job::Read { register, signed, .. } => match stage {
                0 => Ok(Next::Send(ModbusAsk::Read { start: *register, quantity: 1 })),
                _ => {
                    let raw = raw_of(word(0), *signed);
                    self.limits.learn(u32::from(*register), raw);
                    Ok(Next::Done(Outcome::Param(raw)))
                }
            },
        }
    }
}

fn status_of(unit: u8, s: &StatusRead, current: u16) -> DriveStatus {
    let reverse = s.bits & status::REVERSE != 0;
    DriveStatus {
        address: unit,
        running: s.bits & status::RUN != 0,
        direction: Some(if reverse { "reverse" } else { "forward" }.to_string()),
        output_hz: Some(f64::from(s.output) / 100.0),
        setpoint_hz: Some(f64::from(s.set) / 100.0),
        current_a: Some(f64::from(current) / 10.0),
        fault: (s.fault != 0).then(|| Fault { code: u32::from(s.fault), text: fault_text(s.fault) }),
        values: Vec::new(),
    }
}

impl Plan for GenericPlan {
    fn step(&mut self, reply: Option<&[u8]>) -> Result<Step, DriveError> {
        if self.finished {
            return Err(DriveError::Protocol("this plan has finished; plan the operation again".to_string()));
        }
        let answer = match self.sent.take() {
            Some(ask) => match self.answer(ask, reply) {
                Ok(a) => Some(a),
                // A drive that refuses a multi-register read (illegal address or value) is read
                // one register per request from now on: the status starts again.
                Err(DriveError::Refused { code: 2 | 3, .. })
                    if matches!(
                        (ask, &self.job),
                        (ModbusAsk::Read { quantity: 2.., .. }, Job::Status(_))
                    ) =>
                {
                    self.word_reads.store(true, Ordering::Relaxed);
                    self.stage = 0;
                    None
                }
                Err(e) => {
                    self.finished = true;
                    return Err(e);
                }
            },
            None => None,
        };
        let next = self.advance(answer);
        let (framing, unit, expect_reply) = (self.framing, self.unit, !self.broadcast());
        super::step_to(next, &mut self.sent, &mut self.finished, |ask| {
            Ok(Exchange { request: framing.encode(unit, ask)?, expect_reply })
        })
    }
}

impl fmt::Debug for GenericPlan {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("GenericPlan")
            .field("protocol", &self.framing.wire())
            .field("unit", &self.unit)
            .field("job", &self.job)
            .field("stage", &self.stage)
            .finish_non_exhaustive()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn profile(address: u8) -> GenericProfile {
        match GenericProfile::new(address, GenericProtocol::Rtu) {
            Ok(p) => p,
            Err(e) => panic!("{e}"),
        }
    }

    #[test]
    fn addresses_are_checked() {
        assert!(GenericProfile::new(254, GenericProtocol::Ascii).is_ok());
        assert!(GenericProfile::new(0, GenericProtocol::Ascii).is_ok());
        let e = GenericProfile::new(255, GenericProtocol::Rtu).err();
        assert_eq!(
            e,
            Some(DriveError::OutOfRange(
                "a generic drive's address is 1..254, or 0 for a broadcast; not 255".into()
            ))
        );
    }

    #[test]
    fn the_seed_write_of_p0_02_is_the_seeds_frame() {
        // seed 004: "01 06 00 02 13 88 25 5C" writes P0.02 = 50.00 Hz.
        let p = profile(1);
        let op = Operation::WriteParam { name: "P0.02".into(), raw: 5000, storage: Storage::Eeprom };
        let mut plan = p.plan(&op).map_err(|e| e.to_string()).unwrap_or_else(|e| panic!("{e}"));
        match plan.step(None) {
            Ok(Step::Send(x)) => {
                assert_eq!(x.request, [0x01, 0x06, 0x00, 0x02, 0x13, 0x88, 0x25, 0x5C]);
                assert!(x.expect_reply);
                let done = plan.step(Some(&x.request));
                assert_eq!(done, Ok(Step::Done(Outcome::Done)));
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn speed_limit_sentences() {
        let p = profile(1);
        let e = p.plan(&Operation::SetSpeed(50.5)).err();
        assert_eq!(
            e,
            Some(DriveError::OutOfRange("50.5 Hz is above the upper limit P0.05 = 50.00 Hz".into()))
        );
        p.set_speed_limits(4000, 4500);
        let e = p.plan(&Operation::SetSpeed(40.5)).err();
        assert_eq!(
            e,
            Some(DriveError::OutOfRange("40.5 Hz is above the maximum frequency P0.04 = 40.00 Hz".into()))
        );
        assert!(p.plan(&Operation::SetSpeed(40.0)).is_ok());
        assert!(matches!(p.plan(&Operation::SetSpeed(-1.0)), Err(DriveError::OutOfRange(_))));
        assert!(matches!(p.plan(&Operation::SetSpeed(f64::NAN)), Err(DriveError::OutOfRange(_))));
    }

    #[test]
    fn garbage_replies_are_protocol_errors() {
        let p = profile(1);
        for garbage in
            [&b""[..], b"\x01\x03", b"\x01\x03\x02\x00\x00\x00\x00", b"\xFF\xFF\xFF\xFF\xFF\xFF\xFF"]
        {
            let mut plan = p.plan(&Operation::Status).unwrap_or_else(|e| panic!("{e}"));
            assert!(matches!(plan.step(None), Ok(Step::Send(_))));
            assert!(matches!(plan.step(Some(garbage)), Err(DriveError::Protocol(_))), "{garbage:?}");
            assert!(matches!(plan.step(Some(garbage)), Err(DriveError::Protocol(_))));
        }
    }

    /// A Modbus RTU frame: `body` and its CRC.
    fn rtu(body: &[u8]) -> Vec<u8> {
        let mut v = body.to_vec();
        v.extend_from_slice(&drivebus_proto::checksum::crc16_modbus(body).to_le_bytes());
        v
    }

    /// The request a step sends.
    fn sent(step: Result<Step, DriveError>) -> Vec<u8> {
        match step {
            Ok(Step::Send(x)) => x.request,
            other => panic!("expected a request, got {other:?}"),
        }
    }

    /// A drive that answers exception 03 to the 4-register read is read one register per
    /// request, in this status and every later one; a drive that takes it is read in two.
    #[test]
    fn a_drive_refusing_multi_register_reads_is_read_one_register_at_a_time() {
        let p = profile(1);
        let mut plan = p.plan(&Operation::Status).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(sent(plan.step(None)), rtu(&[1, 3, 0x21, 0x00, 0, 4]));
        let values = [0u16, 0x0001, 4000, 3990, 75];
        let mut request = sent(plan.step(Some(&rtu(&[1, 0x83, 3]))));
        for (k, value) in values.iter().enumerate() {
            assert_eq!(request, rtu(&[1, 3, 0x21, k as u8, 0, 1]), "register {k}");
            let [hi, lo] = value.to_be_bytes();
            match plan.step(Some(&rtu(&[1, 3, 2, hi, lo]))) {
                Ok(Step::Send(x)) => request = x.request,
                Ok(Step::Done(Outcome::Status(st))) => {
                    assert_eq!(k, 4);
                    assert!(st.running && st.fault.is_none(), "{st:?}");
                    assert_eq!(
                        (st.setpoint_hz, st.output_hz, st.current_a),
                        (Some(40.0), Some(39.9), Some(7.5))
                    );
                }
                other => panic!("{other:?}"),
            }
        }
        // The next status starts with single reads at once.
        let mut plan = p.plan(&Operation::Status).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(sent(plan.step(None)), rtu(&[1, 3, 0x21, 0x00, 0, 1]));
        // Another refusal of a single read is the drive's answer, not a fallback.
        assert!(matches!(plan.step(Some(&rtu(&[1, 0x83, 2]))), Err(DriveError::Refused { code: 2, .. })));
        // A profile whose drive takes it reads 2100H..2103H and 2104H.
        let q = profile(1);
        let mut plan = q.plan(&Operation::Status).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(sent(plan.step(None)), rtu(&[1, 3, 0x21, 0x00, 0, 4]));
        let four = rtu(&[1, 3, 8, 0, 0, 0, 1, 0x0F, 0xA0, 0x0F, 0x96]);
        assert_eq!(sent(plan.step(Some(&four))), rtu(&[1, 3, 0x21, 0x04, 0, 1]));
    }
}
