//! A drive a template describes (docs/templates.md), on the virtual line: the common motor model
//! behind the template's own Modbus map, so a template can be tried with no hardware.
//!
//! - Reads (03, 04) answer the template's status registers from the model (values coded and
//!   scaled as the template says, flags as their bits), the command and setpoint registers as
//!   last written, and the parameters from the template's catalog; any other register is
//!   exception 02, and a read longer than the template's `max_read` exception 03.
//! - Writes (06, 10) to the command register run, stop, reverse, reset and jog the model (a
//!   value the template does not name, or a command the model refuses, is exception 03); to the
//!   setpoint register set the setpoint; to a parameter store it (read-only: 02; out of range:
//!   03). A parameter named in the setpoint's `limit_params` limits the model's frequency.
//! - A trip shows as the template's fault code whose text names it (over-current, over-voltage,
//!   under-voltage, temperature, external, communication), else drivebus' number of the trip.

use std::collections::HashMap;

use drivebus_drive::template::{CommandValue, RegisterTable, Template, ValueType};
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
        Ok(TemplateDrive {
            session,
            state: State { core, template, protocol, command: idle, setpoint: [0; 2] },
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
    /// Every status register's value now (flags sharing a register ORed together).
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
        let numbers = [
            (&s.output_hz, m.output_hz()),
            (&s.setpoint_hz, m.setpoint_hz()),
            (&s.current_a, m.current_a()),
            (&s.fault, f64::from(fault)),
        ];
        let extra = s.extra.iter().map(|x| (&x.value, extra_value(m, &x.name)));
        let numbers = numbers.iter().filter_map(|(v, n)| v.as_ref().map(|v| (v, *n))).chain(extra);
        for (value, v) in numbers {
            let raw = (v - value.offset) / value.scale;
            let raw = if value.kind == ValueType::F32 { raw } else { raw.round() };
            put(value.table, value.register, value.kind.encode(raw, value.low_first));
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
            put(value.table, value.register, value.kind.encode(raw, value.low_first));
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
            } else if self.template.command.as_ref().is_some_and(|c| c.register == r) {
                self.command
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

    /// Writes `values` from `start`.
    fn write(&mut self, start: u16, values: &[u16]) -> Result<(), ExceptionCode> {
        let t = self.template;
        if let Some(c) = t.command.as_ref().filter(|c| c.register == start) {
            if values.len() != 1 {
                return Err(ILLEGAL_ADDRESS);
            }
            return self.command(c, values[0]);
        }
        if let Some(sp) = t.setpoint.as_ref().filter(|s| s.register == start) {
            if values.len() != usize::from(sp.kind.words()) {
                return Err(ILLEGAL_ADDRESS);
            }
            let hz = sp.kind.decode(values, sp.low_first) * sp.scale;
            if !(0.0..=self.core.model.settings().max_hz + 1e-9).contains(&hz) {
                return Err(ILLEGAL_VALUE);
            }
            self.setpoint[..values.len()].copy_from_slice(values);
            self.core.model.set_setpoint_hz(hz);
            return Ok(());
        }
        let def = self.core.params.catalog().by_number(u32::from(start)).cloned().ok_or(ILLEGAL_ADDRESS)?;
        let words = if def.size == drivebus_drive::Size::Dword { 2 } else { 1 };
        if values.len() != words {
            return Err(ILLEGAL_ADDRESS);
        }
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
        Ok(())
    }

    fn command(&mut self, c: &drivebus_drive::template::CommandMap, word: u16) -> Result<(), ExceptionCode> {
        let m = &mut self.core.model;
        let refused = |_| ILLEGAL_VALUE;
        if c.is_bits() {
            let bit = |v: Option<CommandValue>| match v {
                Some(CommandValue::Bit(b)) => 1u16 << b,
                _ => 0,
            };
            let (run, stop, reverse, reset, jog) =
                (bit(c.run), bit(c.stop), bit(c.reverse), bit(c.reset), bit(c.jog));
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
        let is = |v: Option<CommandValue>| v == Some(CommandValue::Value(word));
        if is(c.reset) {
            m.reset().map_err(|_| ILLEGAL_VALUE)?;
        } else if is(c.stop) {
            m.stop();
        } else if is(c.run) {
            m.run().map_err(refused)?;
        } else if is(c.forward) {
            m.set_rotation(Rotation::Forward);
            m.run().map_err(refused)?;
        } else if is(c.reverse) {
            m.set_rotation(Rotation::Reverse);
            m.run().map_err(refused)?;
        } else if is(c.jog) {
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
