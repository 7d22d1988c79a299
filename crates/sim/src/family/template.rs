//! A drive a template describes (docs/templates.md), on the virtual line: the common motor model
//! behind the template's own Modbus map, so a template can be tried with no hardware.
//!
//! - Reads (03, 04) answer the template's status registers from the model (values coded and
//!   scaled as the template says, flags as their bits, fields in their masks), the command and setpoint registers as
//!   last written, and the parameters from the template's catalog; any other register is
//!   exception 02, and a read longer than the template's `max_read` exception 03.
//! - Writes (06, 10) to the command register run, stop, reverse, reset and jog the model (a
//!   value the template does not name, or a command the model refuses, is exception 03); to the
//!   setpoint register set the setpoint (where the direction is the setpoint's sign, a negative
//!   one runs the model in reverse); to a parameter store it (read-only: 02; out of range: 03).
//!   A parameter named in the setpoint's `limit_params` limits the model's frequency. One 10
//!   write may span several of these registers.
//! - Commands in the writes form: the registers they name keep what was last written; after a
//!   write, every command whose writes all hold and which names a register just written is
//!   carried out (reset, stop, forward, reverse, run, jog, in that order; forward and reverse set
//!   the direction only). The registers of the setpoint's `writes` keep what was written.
//! - A signed output frequency or setpoint (i16, i32, f32) reads negative in reverse.
//! - A trip shows as the template's fault code whose text names it (over-current, over-voltage,
//!   under-voltage, temperature, external, communication), else drivebus' number of the trip.

use std::collections::{BTreeMap, HashMap};

use drivebus_drive::template::{CommandMap, CommandValue, RegisterTable, Template, ValueType};
use drivebus_drive::{Family, ParamStore, Storage, WriteError};
use drivebus_proto::modbus::ascii::ModbusAscii;
use drivebus_proto::modbus::rtu::ModbusRtu;
use drivebus_proto::modbus::{
    ExceptionCode, RegisterAddress, Registers, Reply, ReplyPdu, Request, RequestPdu,
};
use drivebus_proto::protocol::WireProtocol;
use drivebus_proto::session::{Incoming, SlaveSession};
use drivebus_proto::Instant;

use crate::drive::{Device, DriveCore, VirtualDrive};
use crate::model::{ModelSettings, Rotation, Trip};

enum Session {
    Rtu(Box<SlaveSession<ModbusRtu>>),
    Ascii(Box<SlaveSession<ModbusAscii>>),
}

/// A templated drive on the virtual line.
pub struct TemplateDrive {
    session: Session,
    state: State,
}

struct State {
    core: DriveCore,
    template: &'static Template,
    protocol: WireProtocol,
    /// The command register as last written.
    command: u16,
    /// The setpoint registers as last written.
    setpoint: [u16; 2],
    /// The registers the writes-form commands and the setpoint's `writes` name, as last written.
    written: BTreeMap<u16, u16>,
}

const ILLEGAL_FUNCTION: ExceptionCode = ExceptionCode::ILLEGAL_FUNCTION;
const ILLEGAL_ADDRESS: ExceptionCode = ExceptionCode::ILLEGAL_DATA_ADDRESS;
const ILLEGAL_VALUE: ExceptionCode = ExceptionCode::ILLEGAL_DATA_VALUE;

impl TemplateDrive {
    /// A stopped drive of the template kind `family`, numbered `address`, speaking `protocol`.
    pub fn new(family: Family, address: u8, protocol: WireProtocol, now: Instant) -> Result<Self, String> {
        let template = family.template().ok_or_else(|| format!("{family} is not a template kind"))?;
        family.check_protocol(protocol)?;
        family.check_address(protocol, address)?;
        let params = ParamStore::for_family(family).map_err(|e| e.to_string())?;
        let mut core = DriveCore::new(params, ModelSettings::default(), address, now);
        let delay = core.response_delay;
        let session = match protocol {
            WireProtocol::ModbusAscii => {
                Session::Ascii(Box::new(SlaveSession::new(ModbusAscii, address, delay)))
            }
            _ => Session::Rtu(Box::new(SlaveSession::new(ModbusRtu, address, delay))),
        };
        let idle = template.command.as_ref().map_or(0, |c| c.idle);
        core.model.set_settings(settings_of(template, &core.params));
        let written = template
            .command
            .iter()
            .flat_map(CommandMap::all)
            .filter_map(|(_, c)| match c {
                CommandValue::Writes(w) => Some(w.as_slice()),
                _ => None,
            })
            .chain(template.setpoint.iter().map(|s| s.writes.as_slice()))
            .flatten()
            .map(|w| (w.register, 0))
            .collect();
        Ok(TemplateDrive {
            session,
            state: State { core, template, protocol, command: idle, setpoint: [0; 2], written },
        })
    }
}

/// The model's settings: the maximum frequency from the setpoint's `max_hz` or its lowest limit
/// parameter; the rest the model's defaults.
fn settings_of(t: &Template, params: &ParamStore) -> ModelSettings {
    let mut s = ModelSettings::default();
    if let Some(sp) = &t.setpoint {
        let catalog = params.catalog();
        let from_params = sp
            .limit_params
            .iter()
            .filter_map(|n| catalog.get(n).map(|d| d.from_raw(params.get(d.number).unwrap_or(d.default))))
            .fold(f64::INFINITY, f64::min);
        let max = sp.max_hz.unwrap_or(f64::INFINITY).min(from_params);
        if max.is_finite() && max > 0.0 {
            s.max_hz = max;
            s.base_hz = max;
        }
    }
    s
}

/// The model's value for a template's `[values]` entry `name`, by the names docs/templates.md
/// lists (`dc_bus_v`, `output_v`, `power_kw`, `heatsink_c`, `run_hours`, `motor_rpm`); 0 for
/// any other.
fn extra_value(m: &crate::model::DriveModel, name: &str) -> f64 {
    match name {
        "dc_bus_v" => m.dc_bus_v(),
        "output_v" => m.output_v(),
        "power_kw" => 3f64.sqrt() * m.output_v() * m.current_a() * 0.85 / 1000.0,
        "heatsink_c" | "drive_temp_c" => m.heatsink_c(),
        "run_hours" => m.run_hours(),
        "motor_rpm" => m.motor_rpm(),
        _ => 0.0,
    }
}

/// The template's fault code for `trip`: the one whose text names it, else drivebus' number.
fn fault_code(t: &Template, trip: Trip) -> u32 {
    let words: &[&str] = match trip {
        Trip::OverCurrent => &["over-current", "overcurrent", "over current"],
        Trip::OverVoltage => &["over-voltage", "overvoltage", "over voltage"],
        Trip::UnderVoltage => &["under-voltage", "undervoltage", "under voltage"],
        Trip::OverTemperature => &["temperature", "overheat"],
        Trip::External => &["external"],
        Trip::CommunicationTimeout => &["communication", "comm"],
    };
    t.faults
        .iter()
        .find(|(_, text)| {
            let text = text.to_lowercase();
            words.iter().any(|w| text.contains(w))
        })
        .map_or(u32::from(trip.code()), |(code, _)| *code)
}

impl State {
    /// Every status register's value now (flags and `mask` fields sharing a register ORed together).
    fn status_registers(&self) -> HashMap<(RegisterTable, u16), u16> {
        let m = &self.core.model;
        let s = &self.template.status;
        let mut regs: HashMap<(RegisterTable, u16), u16> = HashMap::new();
        let mut put = |table: RegisterTable, register: u16, words: Vec<u16>| {
            for (i, w) in words.into_iter().enumerate() {
                *regs.entry((table, register.wrapping_add(i as u16))).or_insert(0) |= w;
            }
        };
        // A drive with a `tripped` flag keeps its last fault's code after a reset.
        let fault = match s.tripped {
            Some(_) => self.logged_fault(0),
            None => m.trip().map_or(0, |t| fault_code(self.template, t)),
        };
        let sign = |r: Rotation| if r == Rotation::Reverse { -1.0 } else { 1.0 };
        let signed = |v: &Option<drivebus_drive::template::RegisterValue>| {
            v.as_ref().is_some_and(|v| matches!(v.kind, ValueType::I16 | ValueType::I32 | ValueType::F32))
        };
        let out_sign = if signed(&s.output_hz) { sign(m.output_rotation()) } else { 1.0 };
        let set_sign = if signed(&s.setpoint_hz) { sign(m.rotation()) } else { 1.0 };
        let numbers = [
            (&s.output_hz, out_sign * m.output_hz()),
            (&s.setpoint_hz, set_sign * m.setpoint_hz()),
            (&s.current_a, m.current_a()),
            (&s.fault, f64::from(fault)),
        ];
        let extra = s.extra.iter().map(|x| (&x.value, extra_value(m, &x.name)));
        let numbers = numbers.iter().filter_map(|(v, n)| v.as_ref().map(|v| (v, *n))).chain(extra);
        for (value, v) in numbers {
            let raw = (v - value.offset) / value.scale;
            let raw = if value.kind == ValueType::F32 { raw } else { raw.round() };
            put(value.table, value.register, value.encode(raw));
        }
        let flags = [
            (&s.running, m.is_running()),
            (&s.reverse, m.output_rotation() == Rotation::Reverse),
            (&s.tripped, m.trip().is_some()),
        ];
        for (value, on) in flags {
            let Some(value) = value else { continue };
            let raw = match (value.bit, on) {
                (Some(b), true) => (1u64 << b) as f64,
                (None, true) => 1.0,
                (_, false) => 0.0,
            };
            put(value.table, value.register, value.encode(raw));
        }
        regs
    }

    /// The code of the `k`-th newest trip of the model's log (0: the newest), 0 where there is none.
    fn logged_fault(&self, k: usize) -> u32 {
        self.core.model.recent_trips().nth(k).map_or(0, |r| fault_code(self.template, r.trip))
    }

    /// Registers `start..start + quantity` of `table`, or the exception.
    fn read(&self, table: RegisterTable, start: u16, quantity: u16) -> Result<Vec<u16>, ExceptionCode> {
        if quantity > self.template.max_read {
            return Err(ILLEGAL_VALUE);
        }
        let status = self.status_registers();
        let catalog = self.core.params.catalog();
        let mut out = Vec::with_capacity(usize::from(quantity));
        for i in 0..quantity {
            let r = start.checked_add(i).ok_or(ILLEGAL_ADDRESS)?;
            let value = if let Some(v) = status.get(&(table, r)) {
                *v
            } else if table == RegisterTable::Input {
                return Err(ILLEGAL_ADDRESS);
            } else if self.template.command.as_ref().is_some_and(|c| c.register == Some(r)) {
                self.command
            } else if let Some(v) = self.written.get(&r) {
                *v
            } else if let Some(sp) = self
                .template
                .setpoint
                .as_ref()
                .filter(|s| (s.register..s.register + s.kind.words()).contains(&r))
            {
                self.setpoint[usize::from(r - sp.register)]
            } else if let Some(d) = catalog.by_number(u32::from(r)) {
                let history = self.template.fault_history.iter().position(|n| *n == d.name);
                let raw = match history {
                    Some(k) => i64::from(self.logged_fault(k)),
                    None => self.core.params.get(d.number).unwrap_or(d.default),
                };
                self.template.param_words(d, raw)[0]
            } else if let Some(d) = r.checked_sub(1).and_then(|p| catalog.by_number(u32::from(p))) {
                if d.size != drivebus_drive::Size::Dword {
                    return Err(ILLEGAL_ADDRESS);
                }
                let raw = self.core.params.get(d.number).unwrap_or(d.default);
                self.template.param_words(d, raw)[1]
            } else {
                return Err(ILLEGAL_ADDRESS);
            };
            out.push(value);
        }
        Ok(out)
    }

    /// Writes `values` from `start`: the registers one after another, each a command, setpoint,
    /// writes-form or parameter register (a setpoint or parameter whole); then the writes-form
    /// commands that now hold are carried out.
    fn write(&mut self, start: u16, values: &[u16]) -> Result<(), ExceptionCode> {
        let t = self.template;
        let mut touched = Vec::new();
        let mut i = 0;
        while i < values.len() {
            let r = start.checked_add(i as u16).ok_or(ILLEGAL_ADDRESS)?;
            let rest = &values[i..];
            if let Some(c) = t.command.as_ref().filter(|c| c.register == Some(r)) {
                self.command(c, rest[0])?;
                i += 1;
            } else if let Some(v) = self.written.get_mut(&r) {
                *v = rest[0];
                touched.push(r);
                i += 1;
            } else if let Some(sp) = t.setpoint.as_ref().filter(|s| s.register == r) {
                let words = usize::from(sp.kind.words());
                let words = rest.get(..words).ok_or(ILLEGAL_ADDRESS)?;
                self.write_setpoint(sp, words)?;
                i += words.len();
            } else {
                i += self.write_param(r, rest)?;
            }
        }
        if !touched.is_empty() {
            if let Some(c) = &t.command {
                self.writes_commands(c, &touched)?;
            }
        }
        Ok(())
    }

    /// The setpoint's registers written: the model's setpoint (and direction, where it is the
    /// setpoint's sign).
    fn write_setpoint(
        &mut self,
        sp: &drivebus_drive::template::SetpointMap,
        words: &[u16],
    ) -> Result<(), ExceptionCode> {
        let hz = sp.kind.decode(words, sp.low_first) * sp.scale;
        let max = self.core.model.settings().max_hz + 1e-9;
        // A NaN (an f32 setpoint) is refused too.
        if hz.is_nan() || hz.abs() > max || (!sp.reverse_negative && hz < 0.0) {
            return Err(ILLEGAL_VALUE);
        }
        self.setpoint[..words.len()].copy_from_slice(words);
        if sp.reverse_negative && hz != 0.0 {
            self.core.model.set_rotation(if hz < 0.0 { Rotation::Reverse } else { Rotation::Forward });
        }
        self.core.model.set_setpoint_hz(hz.abs());
        Ok(())
    }

    /// The parameter at register `r` written from `values`; the registers it took.
    fn write_param(&mut self, r: u16, values: &[u16]) -> Result<usize, ExceptionCode> {
        let t = self.template;
        let def = self.core.params.catalog().by_number(u32::from(r)).cloned().ok_or(ILLEGAL_ADDRESS)?;
        let words = if def.size == drivebus_drive::Size::Dword { 2 } else { 1 };
        let values = values.get(..words).ok_or(ILLEGAL_ADDRESS)?;
        let raw = t.param_raw(&def, values);
        let running = self.core.model.is_running();
        self.core.params.set(def.name.as_str(), raw, Storage::Eeprom, running).map_err(|e| match e {
            WriteError::UnknownParameter { .. }
            | WriteError::ReadOnly { .. }
            | WriteError::NoSuchElement { .. } => ILLEGAL_ADDRESS,
            WriteError::OutOfRange(_) | WriteError::NotWhileRunning { .. } => ILLEGAL_VALUE,
        })?;
        if t.setpoint
            .as_ref()
            .is_some_and(|s| s.limit_params.iter().any(|n| n.eq_ignore_ascii_case(&def.name)))
        {
            let settings = settings_of(t, &self.core.params);
            self.core.model.set_settings(settings);
        }
        Ok(words)
    }

    /// After a write to the registers `touched`: every writes-form command whose writes all hold
    /// now and which names one of them, carried out.
    fn writes_commands(&mut self, c: &CommandMap, touched: &[u16]) -> Result<(), ExceptionCode> {
        let holding: Vec<&str> = c
            .all()
            .filter_map(|(name, v)| match v {
                CommandValue::Writes(w) => Some((name, w)),
                _ => None,
            })
            .filter(|(_, w)| {
                // The last value written to each register is what it holds.
                let mut last: BTreeMap<u16, u16> = BTreeMap::new();
                for x in w.iter() {
                    last.insert(x.register, x.value);
                }
                last.iter().all(|(r, v)| self.written.get(r) == Some(v))
                    && w.iter().any(|x| touched.contains(&x.register))
            })
            .map(|(name, _)| name)
            .collect();
        let m = &mut self.core.model;
        for name in holding {
            match name {
                "reset" => m.reset().map(|_| ()).map_err(|_| ILLEGAL_VALUE)?,
                "stop" => m.stop(),
                "forward" => m.set_rotation(Rotation::Forward),
                "reverse" => m.set_rotation(Rotation::Reverse),
                "run" if !m.is_running() => m.run().map_err(|_| ILLEGAL_VALUE)?,
                "jog" if !m.is_running() => m.jog().map_err(|_| ILLEGAL_VALUE)?,
                _ => {}
            }
        }
        Ok(())
    }

    fn command(&mut self, c: &drivebus_drive::template::CommandMap, word: u16) -> Result<(), ExceptionCode> {
        let m = &mut self.core.model;
        let refused = |_| ILLEGAL_VALUE;
        if c.is_bits() {
            let bit = |v: &Option<CommandValue>| match v {
                Some(CommandValue::Bit(b)) => 1u16 << b,
                _ => 0,
            };
            let (run, stop, reverse, reset, jog) =
                (bit(&c.run), bit(&c.stop), bit(&c.reverse), bit(&c.reset), bit(&c.jog));
            let rising = |mask: u16| mask != 0 && word & mask != 0 && self.command & mask == 0;
            if rising(reset) {
                let _ = m.reset();
            }
            if reverse != 0 {
                m.set_rotation(if word & reverse != 0 { Rotation::Reverse } else { Rotation::Forward });
            }
            if stop != 0 && word & stop != 0 || word & (run | jog) == 0 {
                m.stop();
            } else if word & jog != 0 && !m.is_running() {
                m.jog().map_err(refused)?;
            } else if word & run != 0 && !m.is_running() {
                m.run().map_err(refused)?;
            }
            self.command = word;
            return Ok(());
        }
        let is = |v: &Option<CommandValue>| *v == Some(CommandValue::Value(word));
        if is(&c.reset) {
            m.reset().map_err(|_| ILLEGAL_VALUE)?;
        } else if is(&c.stop) {
            m.stop();
        } else if is(&c.run) {
            m.run().map_err(refused)?;
        } else if is(&c.forward) {
            m.set_rotation(Rotation::Forward);
            m.run().map_err(refused)?;
        } else if is(&c.reverse) {
            m.set_rotation(Rotation::Reverse);
            m.run().map_err(refused)?;
        } else if is(&c.jog) {
            m.jog().map_err(refused)?;
        } else {
            return Err(ILLEGAL_VALUE);
        }
        self.command = word;
        Ok(())
    }

    /// The answer to one request (`None` for a broadcast).
    fn handle(&mut self, now: Instant, incoming: Incoming<'_, Request<'_>>) -> Option<Answer> {
        let Incoming::Request { request, broadcast } = incoming else { return None };
        self.core.model.comm_seen(now);
        let unit = request.unit;
        let function = request.pdu.function();
        let result = match request.pdu {
            RequestPdu::ReadHoldingRegisters { start, quantity } => self
                .read(RegisterTable::Holding, start.0, quantity)
                .map(|v| Answer::Read { input: false, values: v }),
            RequestPdu::ReadInputRegisters { start, quantity } => self
                .read(RegisterTable::Input, start.0, quantity)
                .map(|v| Answer::Read { input: true, values: v }),
            RequestPdu::WriteSingleRegister { address, value } => {
                self.write(address.0, &[value]).map(|()| Answer::Written { address: address.0, value })
            }
            RequestPdu::WriteMultipleRegisters { start, values } => {
                let v: Vec<u16> = values.iter().collect();
                self.write(start.0, &v)
                    .map(|()| Answer::WrittenMany { start: start.0, quantity: v.len() as u16 })
            }
            _ => Err(ILLEGAL_FUNCTION),
        };
        if broadcast {
            return None;
        }
        Some(match result {
            Ok(a) => a.with_unit(unit.0),
            Err(code) => Answer::Exception { unit: unit.0, function, code },
        })
    }
}

/// A reply, owning its values.
enum Answer {
    Read { input: bool, values: Vec<u16> },
    Written { address: u16, value: u16 },
    WrittenMany { start: u16, quantity: u16 },
    Exception { unit: u8, function: u8, code: ExceptionCode },
    For { unit: u8, answer: Box<Answer> },
}

impl Answer {
    fn with_unit(self, unit: u8) -> Answer {
        Answer::For { unit, answer: Box::new(self) }
    }

    fn reply(&self) -> Option<Reply<'_>> {
        let Answer::For { unit, answer } = self else {
            return match self {
                Answer::Exception { unit, function, code } => {
                    Some(Reply::exception(drivebus_proto::modbus::UnitId(*unit), *function, *code))
                }
                _ => None,
            };
        };
        let pdu = match &**answer {
            Answer::Read { input: false, values } => {
                ReplyPdu::ReadHoldingRegisters { values: Registers::from_values(values) }
            }
            Answer::Read { input: true, values } => {
                ReplyPdu::ReadInputRegisters { values: Registers::from_values(values) }
            }
            Answer::Written { address, value } => {
                ReplyPdu::WriteSingleRegister { address: RegisterAddress(*address), value: *value }
            }
            Answer::WrittenMany { start, quantity } => {
                ReplyPdu::WriteMultipleRegisters { start: RegisterAddress(*start), quantity: *quantity }
            }
            _ => return None,
        };
        Some(Reply { unit: drivebus_proto::modbus::UnitId(*unit), pdu })
    }
}

impl Device for TemplateDrive {
    fn receive(&mut self, now: Instant, bytes: &[u8]) {
        let state = &mut self.state;
        let address = state.core.address;
        match &mut self.session {
            Session::Rtu(s) => {
                s.set_address(address);
                s.handle_input(now, bytes, &mut |now, incoming, responder| {
                    if let Some(a) = state.handle(now, incoming) {
                        if let Some(r) = a.reply() {
                            let _ = responder.reply(&r);
                        }
                    }
                })
            }
            Session::Ascii(s) => {
                s.set_address(address);
                s.handle_input(now, bytes, &mut |now, incoming, responder| {
                    if let Some(a) = state.handle(now, incoming) {
                        if let Some(r) = a.reply() {
                            let _ = responder.reply(&r);
                        }
                    }
                })
            }
        }
    }

    fn silence(&mut self, now: Instant) {
        let state = &mut self.state;
        if let Session::Rtu(s) = &mut self.session {
            s.handle_silence(now, &mut |now, incoming, responder| {
                if let Some(a) = state.handle(now, incoming) {
                    if let Some(r) = a.reply() {
                        let _ = responder.reply(&r);
                    }
                }
            });
        }
    }

    fn poll_transmit(&mut self, now: Instant) -> Option<Vec<u8>> {
        match &mut self.session {
            Session::Rtu(s) => s.poll_transmit(now).map(<[u8]>::to_vec),
            Session::Ascii(s) => s.poll_transmit(now).map(<[u8]>::to_vec),
        }
    }

    fn poll_timeout(&self) -> Option<Instant> {
        match &self.session {
            Session::Rtu(s) => s.poll_timeout(),
            Session::Ascii(s) => s.poll_timeout(),
        }
    }

    fn advance_to(&mut self, now: Instant) {
        self.state.core.model.advance_to(now);
    }

    crate::drive::device_is_a_drive!();
}

impl VirtualDrive for TemplateDrive {
    fn protocol(&self) -> String {
        self.state.protocol.name().to_string()
    }

    crate::drive::drive_core_at!(state.core);

    fn control_source(&self) -> String {
        format!("the {} template's command register", self.state.template.kind)
    }

    fn panel_fault(&self, trip: Trip) -> drivebus_drive::profile::Fault {
        let code = fault_code(self.state.template, trip);
        drivebus_drive::profile::Fault { code, text: self.state.template.fault_text(code) }
    }
}
