//! The profile of a template kind: the template's map turned into Modbus requests (the same
//! framing and reply checks as the built-in generic and Toshiba profiles) and the replies into a
//! [`DriveStatus`] and parameter values.
//!
//! | operation | exchanges |
//! |---|---|
//! | Status | the status values' registers, read in the fewest requests: registers that touch or overlap are merged into one read as long as it spans at most `max_read` registers; holding (03) and input (04) registers apart |
//! | Run / Stop / Jog / Reset | 06 write of the command value; in the bit form, the command word with the bit set (run, jog) or cleared (stop), reset as the bit set and then cleared; in the writes form, the command's writes in order, registers that follow one another in one 10 write |
//! | Reverse | the direction (and running) read, then the opposite direction's command written; where the direction is the setpoint's sign, the setpoint read and written back negated |
//! | SetSpeed | 06 (or 10 for a 32-bit register) write of the setpoint, scaled, after a check against `max_hz` or the lowest of `limit_params`, with the setpoint's `writes`; where the direction is the setpoint's sign, the setpoint read first and its sign kept |
//! | ReadParam / WriteParam | 03 read / 06 write (10 for 32-bit parameters, in the parameter's word order; an f32 holds the value in its unit) of the parameter's register |

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU16, Ordering};
use std::sync::{Arc, Mutex};

use drivebus_proto::modbus::ExceptionCode;

use super::{
    write_groups, CommandValue, RegisterTable, RegisterValue, RegisterWrite, SetpointMap, Template, ValueType,
};
use crate::profile::generic::{self, ModbusAnswer, ModbusAsk, ModbusFraming};
use crate::profile::{
    CodeSpace, DriveError, DriveStatus, Exchange, Fault, NamedValue, Operation, Outcome, Plan, Profile, Step,
    WireProtocol,
};
use crate::{format_fixed, Catalog, Family, ParamDef, Size};

/// One read of the status plan.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReadSpan {
    /// Holding or input registers.
    pub table: RegisterTable,
    /// The first register.
    pub start: u16,
    /// How many.
    pub quantity: u16,
}

/// The status values' registers in the fewest reads: sorted, and merged where they touch or
/// overlap, each read at most `max_read` registers long.
pub fn plan_reads(template: &Template) -> Vec<ReadSpan> {
    let setpoint = setpoint_direction(template);
    reads_of(template.status.values().map(|(_, v)| v).chain(setpoint.as_ref()), template.max_read)
}

/// Where the direction is the setpoint's sign and no `status.reverse` gives it: the setpoint
/// register as a status value (read with the status, its sign the direction).
fn setpoint_direction(template: &Template) -> Option<RegisterValue> {
    let sp = template.setpoint.as_ref().filter(|s| s.reverse_negative)?;
    if template.status.reverse.is_some() {
        return None;
    }
    Some(setpoint_value(sp))
}

/// The setpoint's register(s) as a value read back (Hz).
fn setpoint_value(sp: &SetpointMap) -> RegisterValue {
    RegisterValue {
        register: sp.register,
        table: RegisterTable::Holding,
        kind: sp.kind,
        low_first: sp.low_first,
        scale: if sp.kind == ValueType::F32 { 1.0 } else { sp.scale },
        offset: 0.0,
        bit: None,
        mask: None,
        decimals: 9,
    }
}

/// The requests of `writes`, in order: registers that follow one another in one 10 write.
fn writes_asks(writes: &[RegisterWrite]) -> Vec<ModbusAsk> {
    write_groups(writes).into_iter().map(|(start, values)| ModbusAsk::write_words(start, &values)).collect()
}

/// The requests that write the setpoint's raw value `value` (counts; Hz for an f32), with the
/// setpoint's other `writes` after it.
fn setpoint_asks(sp: &SetpointMap, value: f64) -> Vec<ModbusAsk> {
    let words = sp.kind.encode(value, sp.low_first);
    let mut writes: Vec<RegisterWrite> = words
        .iter()
        .enumerate()
        .map(|(i, &value)| RegisterWrite { register: sp.register.wrapping_add(i as u16), value })
        .collect();
    writes.extend(&sp.writes);
    writes_asks(&writes)
}

/// The reads of `values`, merged as [`plan_reads`] does.
fn reads_of<'a>(values: impl Iterator<Item = &'a RegisterValue>, max_read: u16) -> Vec<ReadSpan> {
    let mut wanted: Vec<(RegisterTable, u32, u32)> = values
        .map(|v| (v.table, u32::from(v.register), u32::from(v.register) + u32::from(v.kind.words())))
        .collect();
    wanted.sort();
    let mut spans: Vec<(RegisterTable, u32, u32)> = Vec::new();
    for (table, start, end) in wanted {
        match spans.last_mut() {
            Some((t, s, e)) if *t == table && start <= *e && end.max(*e) - *s <= u32::from(max_read) => {
                *e = end.max(*e);
            }
            _ => spans.push((table, start, end)),
        }
    }
    spans
        .into_iter()
        .map(|(table, s, e)| ReadSpan { table, start: s as u16, quantity: (e - s) as u16 })
        .collect()
}

/// A template kind's drive at one address (0: broadcast), in Modbus RTU or ASCII.
pub struct TemplateProfile {
    family: Family,
    template: &'static Template,
    catalog: Arc<Catalog>,
    address: u8,
    framing: ModbusFraming,
    reads: Arc<[ReadSpan]>,
    /// The reads before a Reverse: the direction and running flags only (the setpoint, where
    /// the direction is its sign).
    reverse_reads: Arc<[ReadSpan]>,
    /// The reads before a SetSpeed where the direction is the setpoint's sign: the setpoint.
    setpoint_reads: Arc<[ReadSpan]>,
    /// The raw values of the setpoint's limit parameters as last read or written (catalog
    /// defaults at first).
    limits: Arc<Mutex<Vec<(u32, i64)>>>,
    /// The command word as last written (bit form).
    word: Arc<AtomicU16>,
}

impl TemplateProfile {
    /// The profile of drive `address` of the template kind `family` on `protocol`.
    pub fn new(family: Family, protocol: WireProtocol, address: u8) -> Result<Self, DriveError> {
        let template = family.template().ok_or_else(|| {
            DriveError::Unsupported(format!("{family} is a built-in family, not a template"))
        })?;
        let framing = match protocol {
            WireProtocol::ModbusRtu => ModbusFraming::Rtu,
            WireProtocol::ModbusAscii => ModbusFraming::Ascii,
            other => return Err(DriveError::Unsupported(format!("a {family} drive does not speak {other}"))),
        };
        let (lo, hi) = template.addresses;
        if address != 0 && !(lo..=hi).contains(&address) {
            return Err(DriveError::OutOfRange(format!(
                "a {family} drive's address is {lo}..{hi}, or 0 for a broadcast; not {address}"
            )));
        }
        let catalog = Catalog::load(family).map_err(|e| DriveError::Unsupported(e.to_string()))?;
        let limits = template
            .setpoint
            .iter()
            .flat_map(|s| &s.limit_params)
            .filter_map(|n| catalog.get(n).map(|d| (d.number, d.default)))
            .collect();
        Ok(TemplateProfile {
            family,
            template,
            catalog,
            address,
            framing,
            reads: plan_reads(template).into(),
            reverse_reads: match template.setpoint.as_ref().filter(|s| s.reverse_negative) {
                Some(sp) => reads_of([setpoint_value(sp)].iter(), template.max_read).into(),
                None => reads_of(
                    [&template.status.reverse, &template.status.running].into_iter().flatten(),
                    template.max_read,
                )
                .into(),
            },
            setpoint_reads: match &template.setpoint {
                Some(sp) => reads_of([setpoint_value(sp)].iter(), template.max_read).into(),
                None => Arc::from(Vec::new()),
            },
            limits: Arc::new(Mutex::new(limits)),
            word: Arc::new(AtomicU16::new(template.command.as_ref().map_or(0, |c| c.idle))),
        })
    }

    /// The status plan's reads.
    pub fn reads(&self) -> &[ReadSpan] {
        &self.reads
    }

    fn def(&self, name: &str) -> Result<&ParamDef, DriveError> {
        self.catalog.get(name).ok_or_else(|| {
            DriveError::Unsupported(format!(
                "{:?} is not a parameter of the {} template ({})",
                name.trim(),
                self.family,
                self.template.file
            ))
        })
    }

    fn needs_reply(&self, what: &str) -> Result<(), DriveError> {
        generic::needs_reply(self.address, what)
    }

    /// The highest setpoint, Hz: the template's `max_hz`, or the lowest of its limit parameters.
    fn max_hz(&self) -> Option<(f64, String)> {
        let sp = self.template.setpoint.as_ref()?;
        let limits = self.limits.lock().unwrap_or_else(|p| p.into_inner());
        let from_params = limits
            .iter()
            .filter_map(|&(number, raw)| {
                self.catalog.by_number(number).map(|d| (d.from_raw(raw), d.name.clone()))
            })
            .min_by(|a, b| a.0.total_cmp(&b.0));
        match (sp.max_hz, from_params) {
            (Some(m), Some((p, name))) if p < m => Some((p, name)),
            (Some(m), _) => Some((m, "max_hz".to_string())),
            (None, p) => p,
        }
    }

    fn command(&self, op: &Operation) -> Result<Vec<ModbusAsk>, DriveError> {
        let c = self.template.command.as_ref().ok_or_else(|| {
            DriveError::Unsupported(format!(
                "the {} template gives no [command]: {op:?} cannot be sent",
                self.family
            ))
        })?;
        let pick = |v: Option<CommandValue>, name: &str| {
            v.ok_or_else(|| {
                DriveError::Unsupported(format!("the {} template gives no {name} command", self.family))
            })
        };
        // The value and bit forms always have a command register (checked).
        let register = c.register.unwrap_or(0);
        let write = |value: u16| ModbusAsk::Write { register, value };
        let bit = |v: &Option<CommandValue>| match v {
            Some(CommandValue::Bit(b)) => 1u16 << b,
            _ => 0,
        };
        let (run, stop, jog) = (bit(&c.run), bit(&c.stop), bit(&c.jog));
        let word = self.word.load(Ordering::Relaxed);
        let (name, v) = match op {
            Operation::Run => ("run", c.run.clone()),
            Operation::Stop => ("stop", c.stop.clone().or(c.run.clone())),
            Operation::Jog => ("jog", c.jog.clone()),
            Operation::Reset => ("reset", c.reset.clone()),
            _ => return Err(DriveError::Unsupported(format!("{op:?} is not a command"))),
        };
        let v = pick(v, name)?;
        Ok(match (op, v) {
            (_, CommandValue::Writes(w)) => writes_asks(&w),
            (_, CommandValue::Value(value)) => vec![write(value)],
            (Operation::Run, CommandValue::Bit(b)) => vec![write((word | 1 << b) & !stop & !jog)],
            (Operation::Stop, _) => vec![write((word & !run & !jog) | stop)],
            (Operation::Jog, CommandValue::Bit(b)) => vec![write((word | 1 << b) & !stop)],
            (Operation::Reset, CommandValue::Bit(b)) => vec![write(word | 1 << b), write(word & !(1 << b))],
            _ => return Err(DriveError::Unsupported(format!("{op:?} is not a command"))),
        })
    }

    /// The setpoint's raw value for `hz` (counts; Hz for an f32) and what it is, after the checks.
    fn setpoint(&self, hz: f64) -> Result<(f64, String), DriveError> {
        let sp = self.template.setpoint.as_ref().ok_or_else(|| {
            DriveError::Unsupported(format!("the {} template gives no [setpoint]", self.family))
        })?;
        if !hz.is_finite() || hz < 0.0 {
            return Err(DriveError::OutOfRange(format!(
                "{hz} Hz is not a setpoint: give 0 Hz or more (Reverse changes the direction)"
            )));
        }
        if let Some((max, what)) = self.max_hz() {
            if hz > max + 1e-9 {
                return Err(DriveError::OutOfRange(format!(
                    "{hz} Hz is above the maximum frequency ({what}) = {max} Hz"
                )));
            }
        }
        let raw = (hz / sp.scale).round();
        let fits = match sp.kind {
            ValueType::U16 => raw <= f64::from(u16::MAX),
            ValueType::I16 => raw <= f64::from(i16::MAX),
            ValueType::U32 => raw <= f64::from(u32::MAX),
            ValueType::I32 | ValueType::F32 => raw <= f64::from(i32::MAX),
        };
        if !fits {
            return Err(DriveError::OutOfRange(format!("{hz} Hz does not fit the setpoint register")));
        }
        let value = if sp.kind == ValueType::F32 { hz } else { raw };
        let decimals = (-(sp.scale.log10())).ceil().clamp(0.0, 9.0) as i64;
        let what = format!(
            "setpoint {:04X}H = {} Hz",
            sp.register,
            format_fixed((hz * 10f64.powi(decimals as i32)).round() as i64, decimals as i8)
        );
        Ok((value, what))
    }
}

/// The requests of `reads`: 03 for holding registers, 04 for input registers.
fn read_asks(reads: &[ReadSpan]) -> Vec<ModbusAsk> {
    reads
        .iter()
        .map(|r| match r.table {
            RegisterTable::Holding => ModbusAsk::Read { start: r.start, quantity: r.quantity },
            RegisterTable::Input => ModbusAsk::ReadInput { start: r.start, quantity: r.quantity },
        })
        .collect()
}

impl Profile for TemplateProfile {
    fn family(&self) -> Family {
        self.family
    }

    fn protocol(&self) -> WireProtocol {
        self.framing.wire()
    }

    fn address(&self) -> u8 {
        self.address
    }

    fn param(&self, name: &str) -> Result<&ParamDef, DriveError> {
        self.def(name)
    }

    fn plan(&self, op: &Operation) -> Result<Box<dyn Plan>, DriveError> {
        let (asks, finish, what): (Vec<ModbusAsk>, Finish, String) = match op {
            Operation::Status => {
                self.needs_reply("Status")?;
                (read_asks(&self.reads), Finish::Status, "Status".to_string())
            }
            Operation::Run | Operation::Stop | Operation::Jog | Operation::Reset => {
                (self.command(op)?, Finish::Command, format!("{op:?}"))
            }
            Operation::Reverse => {
                self.needs_reply("Reverse (it reads which way the drive turns)")?;
                let c = self.template.command.as_ref();
                let by_sign = self.template.setpoint.as_ref().is_some_and(|s| s.reverse_negative);
                if by_sign {
                    self.needs_reply("Reverse (it reads the setpoint, whose sign is the direction)")?;
                    return Ok(self.plan_with(Vec::new(), Finish::Reverse, "Reverse".to_string()));
                }
                if c.and_then(|c| c.reverse.as_ref()).is_none() {
                    return Err(DriveError::Unsupported(format!(
                        "the {} template gives no reverse command",
                        self.family
                    )));
                }
                if self.template.status.reverse.is_none() {
                    return Err(DriveError::Unsupported(format!(
                        "the {} template gives no status.reverse, so Reverse cannot tell which way the drive turns",
                        self.family
                    )));
                }
                (Vec::new(), Finish::Reverse, "Reverse".to_string())
            }
            Operation::SetSpeed(hz) => {
                let (value, what) = self.setpoint(*hz)?;
                let sp = self.template.setpoint.as_ref().ok_or_else(|| {
                    DriveError::Unsupported(format!("the {} template gives no [setpoint]", self.family))
                })?;
                if sp.reverse_negative {
                    self.needs_reply(&format!(
                        "{what} (it reads the setpoint, whose sign is the direction)"
                    ))?;
                    (Vec::new(), Finish::Speed(value), what)
                } else {
                    (setpoint_asks(sp, value), Finish::Command, what)
                }
            }
            Operation::ReadParam(name) => {
                let def = self.def(name)?;
                self.needs_reply(&format!("ReadParam {}", def.name))?;
                let start = u16::try_from(def.number).unwrap_or(0);
                let quantity = if def.size == Size::Dword { 2 } else { 1 };
                (
                    vec![ModbusAsk::Read { start, quantity }],
                    Finish::Param(def.clone()),
                    format!("ReadParam {}", def.name),
                )
            }
            Operation::WriteParam { name, raw, .. } => {
                let def = self.def(name)?;
                if def.read_only {
                    return Err(DriveError::Unsupported(format!(
                        "{} ({}) is read-only",
                        def.name, def.title
                    )));
                }
                def.check(*raw).map_err(|e| DriveError::OutOfRange(e.to_string()))?;
                let start = u16::try_from(def.number).unwrap_or(0);
                let ask = ModbusAsk::write_words(start, &self.template.param_words(def, *raw));
                (vec![ask], Finish::Learn(def.number, *raw), format!("{} = {}", def.name, def.format(*raw)))
            }
        };
        Ok(self.plan_with(asks, finish, what))
    }
}

impl TemplateProfile {
    /// The plan of `asks`, finished by `finish`; a Reverse or a signed SetSpeed reads first.
    fn plan_with(&self, asks: Vec<ModbusAsk>, finish: Finish, what: String) -> Box<dyn Plan> {
        let reads = match finish {
            Finish::Reverse => self.reverse_reads.clone(),
            Finish::Speed(_) => self.setpoint_reads.clone(),
            _ => self.reads.clone(),
        };
        let asks = match finish {
            Finish::Reverse | Finish::Speed(_) => read_asks(&reads),
            _ => asks,
        };
        Box::new(TemplatePlan {
            template: self.template,
            framing: self.framing,
            unit: self.address,
            reads,
            limits: self.limits.clone(),
            word: self.word.clone(),
            command_register: self.template.command.as_ref().and_then(|c| c.register),
            asks: asks.into(),
            answers: Vec::new(),
            finish,
            what,
            sent: None,
            finished: false,
        })
    }
}

/// What a plan does with its answers at the end.
#[derive(Debug)]
enum Finish {
    Status,
    Command,
    Reverse,
    /// A setpoint whose sign is the direction: this raw magnitude, written with the sign read.
    Speed(f64),
    Param(ParamDef),
    Learn(u32, i64),
}

struct TemplatePlan {
    template: &'static Template,
    framing: ModbusFraming,
    unit: u8,
    reads: Arc<[ReadSpan]>,
    limits: Arc<Mutex<Vec<(u32, i64)>>>,
    word: Arc<AtomicU16>,
    command_register: Option<u16>,
    asks: VecDeque<ModbusAsk>,
    answers: Vec<Vec<u16>>,
    finish: Finish,
    what: String,
    sent: Option<ModbusAsk>,
    finished: bool,
}

impl TemplatePlan {
    /// The words of `v` from the status reads' answers.
    fn words_of(&self, v: &RegisterValue) -> Option<Vec<u16>> {
        self.reads.iter().zip(&self.answers).find_map(|(r, regs)| {
            let offset = v.register.checked_sub(r.start)?;
            if r.table != v.table || offset + v.kind.words() > r.quantity {
                return None;
            }
            regs.get(usize::from(offset)..usize::from(offset + v.kind.words())).map(<[u16]>::to_vec)
        })
    }

    fn status(&self) -> DriveStatus {
        let s = &self.template.status;
        let num = |v: &Option<RegisterValue>| v.as_ref().and_then(|v| self.words_of(v).map(|w| v.value(&w)));
        let flag = |v: &Option<RegisterValue>| v.as_ref().and_then(|v| self.words_of(v).map(|w| v.flag(&w)));
        let output_hz = num(&s.output_hz);
        let tripped = flag(&s.tripped).unwrap_or(true);
        let fault = num(&s.fault).map(|c| c as i64 as u32).filter(|&c| c != 0 && tripped);
        // The direction: status.reverse, else (where the direction is the setpoint's sign) the
        // sign of the setpoint read with the status; none while the setpoint is 0.
        let reverse = flag(&s.reverse).or_else(|| {
            let sp = setpoint_direction(self.template)?;
            let v = self.words_of(&sp).map(|w| sp.kind.decode(&w, sp.low_first))?;
            (v != 0.0).then_some(v < 0.0)
        });
        let direction = reverse.map(|r| if r { "reverse" } else { "forward" }.to_string());
        // A drive with a direction shows its frequencies as magnitudes (a signed output
        // frequency is negative in reverse).
        let has_direction = direction.is_some();
        let magnitude = |v: Option<f64>| if has_direction { v.map(f64::abs) } else { v };
        DriveStatus {
            address: self.unit,
            running: flag(&s.running).unwrap_or_else(|| output_hz.is_some_and(|hz| hz != 0.0)),
            direction,
            output_hz: magnitude(output_hz),
            setpoint_hz: magnitude(num(&s.setpoint_hz)),
            current_a: num(&s.current_a),
            fault: fault.map(|code| Fault { code, text: self.template.fault_text(code) }),
            values: s
                .extra
                .iter()
                .filter_map(|x| {
                    self.words_of(&x.value).map(|w| NamedValue {
                        name: x.name.clone(),
                        value: x.value.value(&w),
                        unit: x.unit.clone(),
                    })
                })
                .collect(),
        }
    }

    fn learn(&self, number: u32, raw: i64) {
        let mut limits = self.limits.lock().unwrap_or_else(|p| p.into_inner());
        for l in limits.iter_mut().filter(|l| l.0 == number) {
            l.1 = raw;
        }
    }

    /// The setpoint read before a Reverse or a signed SetSpeed: its raw value (counts; Hz for an
    /// f32).
    fn setpoint_read(&self) -> Option<(&'static SetpointMap, f64)> {
        let sp = self.template.setpoint.as_ref()?;
        let v = setpoint_value(sp);
        let words = self.words_of(&v)?;
        Some((sp, sp.kind.decode(&words, sp.low_first)))
    }

    /// After the reads of a Reverse: the requests that turn the drive the other way.
    fn reverse_command(&self) -> Result<Vec<ModbusAsk>, DriveError> {
        if self.template.setpoint.as_ref().is_some_and(|s| s.reverse_negative) {
            let (sp, raw) = self
                .setpoint_read()
                .ok_or_else(|| DriveError::Protocol("the setpoint read gave no value".to_string()))?;
            if raw == 0.0 {
                return Err(DriveError::Unsupported(
                    "the setpoint is 0 Hz, and this drive's direction is the setpoint's sign: set a speed, then reverse"
                        .to_string(),
                ));
            }
            return Ok(setpoint_asks(sp, -raw));
        }
        let status = self.status();
        let c =
            self.template.command.as_ref().ok_or_else(|| DriveError::Unsupported("no [command]".into()))?;
        if c.reverse_needs_running && !status.running {
            return Err(DriveError::Unsupported(
                "the drive is stopped, and this drive's reverse command starts it: Reverse acts on a running drive"
                    .to_string(),
            ));
        }
        let in_reverse = status.direction.as_deref() == Some("reverse");
        let word = self.word.load(Ordering::Relaxed);
        if let (Some(CommandValue::Writes(r)), Some(CommandValue::Writes(f))) = (&c.reverse, &c.forward) {
            return Ok(writes_asks(if in_reverse { f } else { r }));
        }
        let register = c.register.unwrap_or(0);
        let value = match (c.reverse.clone(), c.forward.clone()) {
            (Some(CommandValue::Bit(b)), _) => {
                if in_reverse {
                    word & !(1 << b)
                } else {
                    word | 1 << b
                }
            }
            (Some(CommandValue::Value(r)), Some(CommandValue::Value(f))) => {
                if in_reverse {
                    f
                } else {
                    r
                }
            }
            (Some(CommandValue::Value(r)), _) if !in_reverse => r,
            _ => {
                return Err(DriveError::Unsupported(
                    "the template gives no forward command to turn a reversing drive back".to_string(),
                ))
            }
        };
        Ok(vec![ModbusAsk::Write { register, value }])
    }

    fn answer(&self, ask: ModbusAsk, reply: Option<&[u8]>) -> Result<ModbusAnswer, DriveError> {
        if self.unit == 0 {
            return Ok(ModbusAnswer::Written);
        }
        let bytes = reply.ok_or_else(|| DriveError::Protocol(format!("no reply came to the {ask}")))?;
        match self.framing.decode(self.unit, ask, bytes)? {
            ModbusAnswer::Exception(code) => Err(DriveError::Refused {
                code: u32::from(code),
                space: CodeSpace::ModbusException,
                meaning: format!(
                    "{} (in reply to the {ask}: {})",
                    ExceptionCode(code).meaning().unwrap_or("an exception code Modbus does not define"),
                    self.what
                ),
            }),
            answer => Ok(answer),
        }
    }

    fn next(&mut self) -> Result<Option<ModbusAsk>, DriveError> {
        if let Some(ask) = self.asks.pop_front() {
            return Ok(Some(ask));
        }
        if self.answers.len() == self.reads.len() {
            let asks = match self.finish {
                Finish::Reverse => self.reverse_command()?,
                Finish::Speed(magnitude) => {
                    let (sp, raw) = self
                        .setpoint_read()
                        .ok_or_else(|| DriveError::Protocol("the setpoint read gave no value".to_string()))?;
                    setpoint_asks(sp, if raw < 0.0 { -magnitude } else { magnitude })
                }
                _ => return Ok(None),
            };
            self.finish = Finish::Command;
            self.asks.extend(asks);
            return Ok(self.asks.pop_front());
        }
        Ok(None)
    }

    fn outcome(&self) -> Outcome {
        match &self.finish {
            Finish::Status => Outcome::Status(self.status()),
            Finish::Param(def) => {
                let words = self.answers.last().cloned().unwrap_or_default();
                let raw = self.template.param_raw(def, &words);
                self.learn(def.number, raw);
                Outcome::Param(raw)
            }
            Finish::Learn(number, raw) => {
                self.learn(*number, *raw);
                Outcome::Done
            }
            Finish::Command | Finish::Reverse | Finish::Speed(_) => Outcome::Done,
        }
    }
}

impl Plan for TemplatePlan {
    fn step(&mut self, reply: Option<&[u8]>) -> Result<Step, DriveError> {
        if self.finished {
            return Err(DriveError::Protocol("this plan has finished; plan the operation again".to_string()));
        }
        let result = (|| {
            if let Some(ask) = self.sent.take() {
                match self.answer(ask, reply)? {
                    ModbusAnswer::Registers(regs) => self.answers.push(regs),
                    _ => {
                        if let ModbusAsk::Write { register, value } = ask {
                            if Some(register) == self.command_register {
                                self.word.store(value, Ordering::Relaxed);
                            }
                        }
                    }
                }
            }
            self.next()
        })();
        match result {
            Ok(Some(ask)) => {
                let request = self.framing.encode(self.unit, ask)?;
                self.sent = Some(ask);
                Ok(Step::Send(Exchange { request, expect_reply: self.unit != 0 }))
            }
            Ok(None) => {
                self.finished = true;
                Ok(Step::Done(self.outcome()))
            }
            Err(e) => {
                self.finished = true;
                Err(e)
            }
        }
    }
}
