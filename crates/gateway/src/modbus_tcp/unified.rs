//! The unified register map's requests (docs/register-map.md, [`super::map`]): each drive is a
//! unit id; one map for every family and template. Input registers and the command/setpoint
//! holding registers are answered from the cache under a read lock without allocating;
//! parameter reads and every write wait for the drive, and are answered when it confirmed.
//! Shared by the Modbus TCP service ([`super::service`]) and the Modbus RTU slave.

use std::net::IpAddr;
use std::sync::atomic::AtomicUsize;
use std::sync::Arc;
use std::time::Instant;

use drivebus_drive::profile::CodeSpace;
use drivebus_drive::{format_fixed, ParamDef};
use drivebus_proto::modbus::tcp::{Mbap, MBAP_LEN};
use drivebus_proto::modbus::{ExceptionCode, RegisterAddress, Registers, ReplyPdu, RequestPdu};

use super::map::*;
use super::service::{exception, reply};
use crate::config::ModbusConfig;
use crate::core::{Command, CommandError, DriveEntry, Gateway};
use crate::metrics::FrontEndMetrics;

/// Exception 01: illegal function (also: writes refused by configuration or a lock).
pub const ILLEGAL_FUNCTION: ExceptionCode = ExceptionCode::ILLEGAL_FUNCTION;
/// Exception 02: illegal data address.
pub const ILLEGAL_ADDRESS: ExceptionCode = ExceptionCode::ILLEGAL_DATA_ADDRESS;
/// Exception 03: illegal data value (counts, byte counts, values out of range).
pub const ILLEGAL_VALUE: ExceptionCode = ExceptionCode::ILLEGAL_DATA_VALUE;
/// Exception 0B: gateway target device failed to respond (no drive has the unit id).
pub const TARGET_FAILED: ExceptionCode = ExceptionCode::GATEWAY_TARGET_FAILED;

/// What the server remembers of the last command word written to a unit (for the edge-triggered
/// bits, and to compare against while the cache has not seen the command's effect yet).
#[derive(Clone, Copy, Debug, Default)]
struct Written {
    word: u16,
    at: Option<Instant>,
}

/// The unified map's request handling, shared by the Modbus TCP listener and the Modbus RTU
/// slave ([`crate::modbus_rtu`]).
pub(crate) struct Server {
    pub(super) gw: Arc<Gateway>,
    /// The gateway's front-end counts, where each request is counted.
    pub(super) metrics: Arc<FrontEndMetrics>,
    /// The listener's settings at start (`max_connections`); the write rules are read live.
    pub(super) config: ModbusConfig,
    /// Connections open now.
    pub(super) active: AtomicUsize,
    /// One per unit id; held across a write so concurrent writers to a drive are serialized.
    written: Vec<tokio::sync::Mutex<Written>>,
    /// What was last written to each unit, for reads until the cache has caught up.
    shown: Vec<std::sync::Mutex<Shown>>,
}

/// The last command word and setpoint written to a unit, and when the drive confirmed them.
#[derive(Clone, Copy, Debug, Default)]
struct Shown {
    word: u16,
    word_at: Option<Instant>,
    setpoint: u16,
    setpoint_at: Option<Instant>,
}

/// A request of the unified map, read from proto's [`RequestPdu`]; register values are views
/// into the request.
enum Request<'a> {
    Read { input: bool, addr: u16, count: u16 },
    Write { addr: u16, values: Registers<'a> },
    ReadWrite { addr: u16, count: u16, waddr: u16, values: Registers<'a> },
}

/// Reads a request PDU (function code first); errors are exception codes: 01 for a function the
/// map does not serve, 03 for counts and lengths the Modbus specification does not allow.
fn parse(pdu: &[u8]) -> Result<Request<'_>, ExceptionCode> {
    if !matches!(pdu.first(), Some(0x03 | 0x04 | 0x06 | 0x10 | 0x17)) {
        return Err(ILLEGAL_FUNCTION);
    }
    match RequestPdu::parse(pdu) {
        Ok(RequestPdu::ReadHoldingRegisters { start, quantity }) => {
            Ok(Request::Read { input: false, addr: start.0, count: quantity })
        }
        Ok(RequestPdu::ReadInputRegisters { start, quantity }) => {
            Ok(Request::Read { input: true, addr: start.0, count: quantity })
        }
        Ok(RequestPdu::WriteSingleRegister { address, .. }) => {
            Ok(Request::Write { addr: address.0, values: Registers::from_be_bytes(&pdu[3..5]) })
        }
        Ok(RequestPdu::WriteMultipleRegisters { start, values }) => {
            Ok(Request::Write { addr: start.0, values })
        }
        Ok(RequestPdu::ReadWriteMultipleRegisters { read_start, read_quantity, write_start, values }) => {
            Ok(Request::ReadWrite { addr: read_start.0, count: read_quantity, waddr: write_start.0, values })
        }
        Ok(_) => Err(ILLEGAL_FUNCTION),
        Err(_) => Err(ILLEGAL_VALUE),
    }
}

/// What a request that went to the drive answers with.
enum ReplyValues {
    Read(Vec<u16>),
    ReadWrite(Vec<u16>),
    Written { addr: u16, first: u16, quantity: u16 },
}

/// A parameter of the window and one of its halves (`true`: the high word).
type WindowSlot = (usize, bool);

/// The first and last parameter slots of window registers `addr..addr + count` over a catalog
/// of `params` parameters, or exception 02 where they leave the window.
fn param_window(params: usize, addr: u16, count: u16) -> Result<(WindowSlot, WindowSlot), ExceptionCode> {
    let first = param_slot(addr).ok_or(ILLEGAL_ADDRESS)?;
    let last_addr = addr.checked_add(count.max(1) - 1).ok_or(ILLEGAL_ADDRESS)?;
    let last = param_slot(last_addr).ok_or(ILLEGAL_ADDRESS)?;
    if last.0 >= params {
        return Err(ILLEGAL_ADDRESS);
    }
    Ok((first, last))
}

/// The parameter index and half (`true`: high word) of a window address.
fn param_slot(addr: u16) -> Option<WindowSlot> {
    let off = addr.checked_sub(PARAM_BASE)? as usize;
    Some((off / 2, off % 2 == 0))
}

impl Server {
    /// The handler of `gw`'s unified map, with its `[modbus]` rules.
    pub(crate) fn new(gw: Arc<Gateway>) -> Arc<Server> {
        let config = gw.config().modbus.clone();
        Arc::new(Server {
            metrics: crate::metrics::front_ends(&gw),
            gw,
            config,
            active: AtomicUsize::new(0),
            written: (0..256).map(|_| Default::default()).collect(),
            shown: (0..256).map(|_| Default::default()).collect(),
        })
    }

    /// Answers one request, an MBAP frame (header and PDU), into `out`: from the cache where it
    /// can, else through the drive.
    pub(crate) async fn answer(&self, conn: &mut Conn, frame: &[u8], out: &mut Vec<u8>) {
        let Ok(Some(mbap)) = Mbap::parse(frame) else { return };
        let Some(pdu) = frame.get(MBAP_LEN..mbap.frame_len()) else { return };
        if !self.answer_cached(&mbap, pdu, out) {
            self.answer_drive(conn, &mbap, pdu, out).await;
        }
    }

    /// Answers `pdu` into `out` from the cache; false when it needs the drive.
    pub(super) fn answer_cached(&self, mbap: &Mbap, pdu: &[u8], out: &mut Vec<u8>) -> bool {
        let fc = pdu[0];
        let Some(d) = self.gw.drive_by_unit(mbap.unit) else {
            exception(out, mbap, fc, TARGET_FAILED);
            return true;
        };
        let req = match parse(pdu) {
            Ok(r) => r,
            Err(code) => {
                exception(out, mbap, fc, code);
                return true;
            }
        };
        match req {
            Request::Read { input: true, addr, count } => {
                let Some(last) = addr.checked_add(count - 1).filter(|&l| l < INPUT_COUNT) else {
                    exception(out, mbap, fc, ILLEGAL_ADDRESS);
                    return true;
                };
                let mut regs = [0u16; INPUT_COUNT as usize];
                input_registers(&d, &mut regs);
                let values = Registers::from_values(&regs[addr as usize..=last as usize]);
                reply(out, mbap, &ReplyPdu::ReadInputRegisters { values });
                true
            }
            Request::Read { input: false, addr, count } if addr <= HR_SETPOINT => {
                match self.holding_range(&d, mbap.unit, addr, count) {
                    Ok((regs, range)) => {
                        let values = Registers::from_values(&regs[range]);
                        reply(out, mbap, &ReplyPdu::ReadHoldingRegisters { values });
                    }
                    Err(code) => exception(out, mbap, fc, code),
                }
                true
            }
            Request::Read { .. } | Request::Write { .. } | Request::ReadWrite { .. } => false,
        }
    }

    /// Holding registers `addr..addr + count` of the command/setpoint pair, or exception 02.
    fn holding_range(
        &self,
        d: &DriveEntry,
        unit: u8,
        addr: u16,
        count: u16,
    ) -> Result<([u16; 2], std::ops::Range<usize>), ExceptionCode> {
        if u32::from(addr) + u32::from(count) > 2 {
            return Err(ILLEGAL_ADDRESS);
        }
        Ok((self.holding(d, unit), addr as usize..(addr + count) as usize))
    }

    /// Holding registers 0 and 1 from the cache; bits 2 and 3 of the command word are the last
    /// written ones, and a write the drive confirmed shows until the cache is newer than it.
    fn holding(&self, d: &DriveEntry, unit: u8) -> [u16; 2] {
        let shown = *self.shown[unit as usize].lock().unwrap_or_else(|p| p.into_inner());
        d.with_state(|s| {
            let st = s.status.as_ref();
            let newer = |at: Option<Instant>| at.is_some_and(|w| s.updated.map_or(true, |u| w >= u));
            let mut word = shown.word & (CMD_RESET | CMD_JOG);
            if newer(shown.word_at) {
                word |= shown.word & (CMD_RUN | CMD_REVERSE);
            } else {
                if st.is_some_and(|x| x.running) {
                    word |= CMD_RUN;
                }
                if is_reverse(s) {
                    word |= CMD_REVERSE;
                }
            }
            let setpoint = if newer(shown.setpoint_at) {
                shown.setpoint
            } else {
                hundredths(st.and_then(|x| x.setpoint_hz).or(s.commanded_hz))
            };
            [word, setpoint]
        })
    }

    /// Answers a request that needs the drive: a parameter read or a write. The whole request
    /// is checked before anything is written: a read/write whose read part is outside the map
    /// writes nothing.
    pub(super) async fn answer_drive(&self, conn: &mut Conn, mbap: &Mbap, pdu: &[u8], out: &mut Vec<u8>) {
        let fc = pdu[0];
        let Some(d) = self.gw.drive_by_unit(mbap.unit) else {
            exception(out, mbap, fc, TARGET_FAILED);
            return;
        };
        let answer: Result<ReplyValues, ExceptionCode> = async {
            Ok(match parse(pdu)? {
                Request::Read { addr, count, .. } => {
                    ReplyValues::Read(self.read_window(&d, addr, count, &conn.client()).await?)
                }
                Request::Write { addr, values } => {
                    self.write(conn, mbap.unit, &d, addr, values).await?;
                    ReplyValues::Written {
                        addr,
                        first: values.get(0).unwrap_or(0),
                        quantity: values.len() as u16,
                    }
                }
                Request::ReadWrite { addr, count, waddr, values } => {
                    let window = addr >= PARAM_BASE;
                    if window {
                        param_window(d.catalog().len(), addr, count)?;
                    } else {
                        self.holding_range(&d, mbap.unit, addr, count)?;
                    }
                    self.write(conn, mbap.unit, &d, waddr, values).await?;
                    ReplyValues::ReadWrite(if window {
                        self.read_window(&d, addr, count, &conn.client()).await?
                    } else {
                        let (regs, range) = self.holding_range(&d, mbap.unit, addr, count)?;
                        regs[range].to_vec()
                    })
                }
            })
        }
        .await;
        match answer {
            Ok(ReplyValues::Read(v)) => {
                reply(out, mbap, &ReplyPdu::ReadHoldingRegisters { values: Registers::from_values(&v) })
            }
            Ok(ReplyValues::ReadWrite(v)) => {
                reply(out, mbap, &ReplyPdu::ReadWriteMultipleRegisters { values: Registers::from_values(&v) })
            }
            Ok(ReplyValues::Written { addr, first, .. }) if fc == 0x06 => reply(
                out,
                mbap,
                &ReplyPdu::WriteSingleRegister { address: RegisterAddress(addr), value: first },
            ),
            Ok(ReplyValues::Written { addr, quantity, .. }) => {
                reply(out, mbap, &ReplyPdu::WriteMultipleRegisters { start: RegisterAddress(addr), quantity })
            }
            Err(code) => exception(out, mbap, fc, code),
        }
    }

    /// Reads holding registers `addr..addr + count` of the parameter window from the drive.
    async fn read_window(
        &self,
        d: &DriveEntry,
        addr: u16,
        count: u16,
        client: &str,
    ) -> Result<Vec<u16>, ExceptionCode> {
        let catalog = d.catalog();
        let ((first, first_high), (last, last_high)) = param_window(catalog.len(), addr, count)?;
        let mut values = Vec::with_capacity(count as usize);
        for i in first..=last {
            let name = &catalog.params()[i].name;
            let reading =
                self.gw.read_param(&d.config.name, name, client).await.map_err(|e| exception_of(&e))?;
            let bits = reading.raw as i32 as u32;
            if i != first || first_high {
                values.push((bits >> 16) as u16);
            }
            if i != last || !last_high {
                values.push(bits as u16);
            }
        }
        Ok(values)
    }

    /// Writes holding registers from `addr` on unit `unit` (drive `d`); Ok once the drive confirmed.
    async fn write(
        &self,
        conn: &mut Conn,
        unit: u8,
        d: &DriveEntry,
        addr: u16,
        values: Registers<'_>,
    ) -> Result<(), ExceptionCode> {
        let n = values.len();
        let value = |i: usize| values.get(i).unwrap_or(0);
        let (may_write, forbidden) = match conn.ip {
            Some(ip) => {
                let rules = self.gw.config();
                let why = if rules.modbus.read_only {
                    "forbidden: the Modbus TCP listener is read-only ([modbus] read_only)".to_string()
                } else {
                    format!("forbidden: client {ip} may not write ([modbus] allow)")
                };
                (!rules.modbus.read_only && rules.modbus.allow.contains(&ip), why)
            }
            // The RTU slave: its section's `write`, and `[modbus] read_only` as configured now.
            None if self.gw.config().modbus.read_only => {
                (false, "forbidden: Modbus writes are off ([modbus] read_only)".to_string())
            }
            None => (conn.may_write, conn.forbidden.clone()),
        };
        if !may_write || d.locked() {
            let why = if !may_write {
                forbidden
            } else {
                format!("locked: {}", CommandError::Locked(d.config.name.clone()))
            };
            let action = format!("modbus write of {n} register(s) at {addr}");
            self.gw.audit_refusal(&d.config.name, &conn.actor, &action, &why).await;
            return Err(ILLEGAL_FUNCTION);
        }
        if addr <= HR_SETPOINT {
            if addr as usize + n > 2 {
                return Err(ILLEGAL_ADDRESS);
            }
            // A command word with bits the map does not define is refused before the setpoint
            // is written: nothing of the request is done.
            if addr == HR_COMMAND && value(0) & !CMD_MASK != 0 {
                return Err(ILLEGAL_VALUE);
            }
            // The setpoint first, so a drive told to run starts toward the new speed.
            if addr + n as u16 == 2 {
                let raw = value(n - 1);
                self.command(conn, d, Command::Speed(f64::from(raw) / 100.0)).await?;
                let mut shown = self.shown[unit as usize].lock().unwrap_or_else(|p| p.into_inner());
                shown.setpoint = raw;
                shown.setpoint_at = Some(Instant::now());
            }
            if addr == HR_COMMAND {
                self.command_word(conn, unit, d, value(0)).await?;
            }
            return Ok(());
        }
        let catalog = d.catalog();
        let (first, high) = param_slot(addr).ok_or(ILLEGAL_ADDRESS)?;
        // Aligned pairs (high, low) write 32-bit values; a single low register a 16-bit one.
        let writes: usize = if high && n % 2 == 0 {
            n / 2
        } else if !high && n == 1 {
            1
        } else {
            return Err(ILLEGAL_ADDRESS);
        };
        if first + writes > catalog.len() {
            return Err(ILLEGAL_ADDRESS);
        }
        let defs = &catalog.params()[first..first + writes];
        if defs.iter().any(|p| p.read_only) {
            return Err(ILLEGAL_ADDRESS);
        }
        // Every value in its parameter's limits before the first is written.
        let raws: Vec<i64> = defs
            .iter()
            .enumerate()
            .map(|(k, def)| {
                if high {
                    let v = (u32::from(value(2 * k)) << 16 | u32::from(value(2 * k + 1))) as i32;
                    if v < 0 && def.min >= 0 {
                        i64::from(v as u32)
                    } else {
                        i64::from(v)
                    }
                } else {
                    i64::from(value(0) as i16)
                }
            })
            .collect();
        if defs.iter().zip(&raws).any(|(def, &raw)| def.check(raw).is_err()) {
            return Err(ILLEGAL_VALUE);
        }
        for (def, raw) in defs.iter().zip(raws) {
            let shown = value_text(def, raw);
            self.command(conn, d, Command::SetParamRaw { name: def.name.clone(), raw, shown, eeprom: false })
                .await?;
        }
        Ok(())
    }

    /// Writes the command word: sends only what differs from the drive's state.
    async fn command_word(
        &self,
        conn: &mut Conn,
        unit: u8,
        d: &DriveEntry,
        word: u16,
    ) -> Result<(), ExceptionCode> {
        if word & !CMD_MASK != 0 {
            return Err(ILLEGAL_VALUE);
        }
        let mut written = self.written[unit as usize].lock().await;
        // Until the cache has seen the last command's effect, compare with what was commanded.
        let (running, reverse) = d.with_state(|s| match (written.at, s.updated) {
            (Some(w), Some(u)) if u > w => (s.status.as_ref().is_some_and(|x| x.running), is_reverse(s)),
            (Some(_), _) => (written.word & (CMD_RUN | CMD_JOG) != 0, written.word & CMD_REVERSE != 0),
            (None, _) => (s.status.as_ref().is_some_and(|x| x.running), is_reverse(s)),
        });
        let plan = plan_command(word, written.word, running, reverse);
        // Reverse, then run: the drive starts in the new direction. A B800 reverses only while
        // running (R to a running drive), so it runs first.
        let b800 = d.config.family == drivebus_drive::Family::B800;
        let steps = [
            (plan.reset, Command::Reset),
            (plan.stop, Command::Stop),
            (plan.reverse && !b800, Command::Reverse),
            (plan.run, Command::Run),
            (plan.reverse && b800, Command::Reverse),
            (plan.jog, Command::Jog),
        ];
        for (due, cmd) in steps {
            if due {
                if let Err(code) = self.command(conn, d, cmd).await {
                    // Compare with the cache next time; a failed edge can be retried.
                    written.at = None;
                    return Err(code);
                }
            }
        }
        *written = Written { word, at: Some(Instant::now()) };
        let mut shown = self.shown[unit as usize].lock().unwrap_or_else(|p| p.into_inner());
        shown.word = word;
        shown.word_at = written.at;
        Ok(())
    }

    async fn command(&self, conn: &mut Conn, d: &DriveEntry, cmd: Command) -> Result<(), ExceptionCode> {
        self.gw.command(&d.config.name, cmd, &conn.actor).await.map_err(|e: CommandError| exception_of(&e))
    }
}

/// The Modbus exception code that says what happened to a command or parameter read
/// (docs/register-map.md). A drive's own Modbus exception is passed through as it came.
pub fn exception_of(e: &CommandError) -> ExceptionCode {
    match e {
        CommandError::UnknownDrive(_) | CommandError::UnknownBus(_) | CommandError::NoAnswer(_) => {
            ExceptionCode::GATEWAY_TARGET_FAILED
        }
        CommandError::Locked(_) | CommandError::Unsupported(_) => ExceptionCode::ILLEGAL_FUNCTION,
        CommandError::Invalid(_) => ExceptionCode::ILLEGAL_DATA_VALUE,
        CommandError::Refused { code: code @ 1..=0xFF, space: CodeSpace::ModbusException, .. } => {
            ExceptionCode(*code as u8)
        }
        CommandError::Refused { .. } | CommandError::Protocol(_) => ExceptionCode::SERVER_DEVICE_FAILURE,
        CommandError::LinkDown(_) => ExceptionCode::GATEWAY_PATH_UNAVAILABLE,
        CommandError::Busy(_) | CommandError::Standby(_) => ExceptionCode::SERVER_DEVICE_BUSY,
        CommandError::NotRecorded(_) => ExceptionCode::SERVER_DEVICE_FAILURE,
    }
}

/// A client's standing.
pub(crate) struct Conn {
    /// A Modbus TCP client's address (IPv4-mapped IPv6 as IPv4): its writes are checked against
    /// the `[modbus]` rules as configured at the time. `None` for the RTU slave, whose writes
    /// need `may_write` and `[modbus] read_only` off at the time.
    pub(crate) ip: Option<IpAddr>,
    /// May it write (when `ip` is `None`, with `[modbus] read_only` off)?
    pub(crate) may_write: bool,
    /// Why its writes are refused when `may_write` is false (when `ip` is `None`).
    pub(crate) forbidden: String,
    /// Who it is in the audit trail (`modbus:127.0.0.1:5555`, `modbus-rtu:/dev/ttyS1`).
    pub(crate) actor: String,
}

impl Conn {
    /// The client whose parameter reads wait in one queue on the bus: its address (all its
    /// connections together), or its actor where it has none.
    fn client(&self) -> String {
        self.ip.map_or_else(|| self.actor.clone(), |ip| ip.to_string())
    }
}

/// A raw value as a number in the parameter's unit (what [`Command::SetParam`] takes).
fn value_text(def: &ParamDef, raw: i64) -> String {
    format_fixed(raw, def.scale)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_are_checked_before_anything_is_done() {
        assert!(matches!(parse(&[4, 0, 0, 0, 10]), Ok(Request::Read { input: true, addr: 0, count: 10 })));
        assert_eq!(parse(&[4, 0, 0, 0, 0]).err(), Some(ILLEGAL_VALUE));
        assert_eq!(parse(&[3, 0, 0, 0, 126]).err(), Some(ILLEGAL_VALUE));
        assert_eq!(parse(&[3, 0, 0, 0]).err(), Some(ILLEGAL_VALUE));
        assert_eq!(parse(&[0x10, 0, 0, 0, 2, 3, 0, 1, 0]).err(), Some(ILLEGAL_VALUE));
        assert!(matches!(parse(&[0x10, 0, 0, 0, 2, 4, 0, 1, 0, 2]), Ok(Request::Write { addr: 0, .. })));
        assert_eq!(parse(&[0x01, 0, 0, 0, 1]).err(), Some(ILLEGAL_FUNCTION));
        assert_eq!(parse(&[0x17, 0, 0, 0, 1, 0, 1, 0, 1, 2, 0]).err(), Some(ILLEGAL_VALUE));
    }

    #[test]
    fn window_addresses_name_a_parameter_and_a_half() {
        assert_eq!(param_slot(999), None);
        assert_eq!(param_slot(1000), Some((0, true)));
        assert_eq!(param_slot(1001), Some((0, false)));
        assert_eq!(param_slot(1006), Some((3, true)));
    }
}
