//! Danfoss VLT FC series on the FC protocol (`danfoss-fc`): [`DanfossProfile`].
//!
//! Manual: `seeds/003_26a4c04ca1af5f26.txt` (FC 280 Design Guide, 5.4.4–5.4.7) with
//! protocols.md section 2 and its "Danfoss FC" project decisions.
//!
//! ## Every telegram carries a control word
//!
//! An FC telegram always ends with PCD1 (control word, FC profile) and PCD2 (bus reference),
//! so a status read or a parameter telegram could stop or start the drive. The profile keeps
//! the last control word and reference it commanded (shared by all its plans), and:
//!
//! - telegrams that must not change the drive (status, parameters, the reads a command makes
//!   first) carry that control word with **bit 10 = 0** ("data invalid: the control word is
//!   ignored", protocols.md 2.6) and the last reference unchanged;
//! - commands are process blocks with bit 10 = 1: run `047C`, stop `043C`, jog `057C`
//!   (bit 08, at 3-19 Jog Speed), bit 15 for reverse, and the reference of the current
//!   setpoint. Reset is two telegrams, stop `043C` and then `04BC`, the 0->1 edge of bit 07.
//!
//! Reset leaves the drive stopped (with a start held through the reset edge, the motor would
//! restart at once): Run again after it.
//!
//! A profile that has commanded nothing yet reads 16-02 Reference [%] and 16-00 Control Word
//! (the last control word the drive acted on) before its first command (Run, Stop, Jog,
//! Reverse, Reset, SetSpeed), and builds on them: every command carries the drive's reference,
//! so a stop and then a run from separate processes runs at the speed set before; a SetSpeed
//! keeps a started drive started, in its direction; a Run to a drive that holds a start
//! already sends nothing, and is refused like any run if the drive is tripped.
//!
//! ## Reference and speed
//!
//! Reference and MAV are 0x4000 = 100 % of 3-02..3-03 (0 Hz..3-03 with 3-00 = -max..+max).
//! The profile **reads 3-00, 3-02 and 3-03 from the drive** the first time it needs them (a
//! status, a set speed), and 4-14 Motor Speed High Limit before the first SetSpeed, then keeps
//! them; reading or writing one of them through the profile updates what it keeps, and a status
//! after [`Profile::refresh_setup`] reads 3-00, 3-02, 3-03 and 16-02 again. A SetSpeed
//! is refused (`OutOfRange`) below 0 Hz, below 3-02 (min–max range) and above the lower of
//! 3-03 and 4-14; values that cannot be right on any drive (above 500 Hz, the highest 4-14)
//! are refused before anything is sent. A broadcast profile cannot read: it uses the catalog
//! defaults (3-00 min–max, 3-02 0 Hz, 3-03 50 Hz, 4-14 65 Hz) unless told otherwise with
//! [`DanfossProfile::set_reference_range`].
//!
//! ## Status
//!
//! One parameter telegram reading 16-14 Motor Current: its reply carries the status word
//! (running = bit 11 "in operation", trip = bit 03) and MAV (output frequency, signed by
//! direction; the profile's first status reads 3-00, 3-02 and 3-03 before it, to scale MAV).
//! A tripped drive costs one more read, 15-30 Alarm Log element 0, for the alarm number.
//! The setpoint is the one this profile last commanded; until it has commanded one, the
//! status reads 16-02 Reference [%] first (once, while the setpoint is unknown) and scales it
//! with 3-02..3-03.
//!
//! ## Refusals
//!
//! - AK 7 "command cannot be performed": `Refused` with the fault code of PWElow and its
//!   meaning (protocols.md 2.4).
//! - Run or Jog to a tripped drive (status bit 03): `Refused` with the FC alarm number
//!   (15-30 element 0) and its text; so is a Reset that leaves the trip in force.
//! - A command while the drive does not take the bus control word (status bit 09 "bus
//!   control" = 0: 8-02 Control Source, 8-01 Control Site): `Refused` with the status word as
//!   the code.
//!
//! ## Parameters
//!
//! By the manual's name (`4-14`, `414`), an array element as `15-30[3]`. Read: AK 1, the value
//! from PWE (AK 1 or 2 accepted; PWElow for a word parameter, signed where the catalog range
//! is). Write: AK 2 (word) / 3 (double word) to RAM, E / D to RAM and EEPROM, the width from
//! the catalog. Values are checked against the catalog range before sending; read-only
//! parameters are `Unsupported`.
//!
//! ## Broadcast
//!
//! Address 0 is the broadcast ADR (`80`, or `20` in format 1–31): commands and parameter
//! writes go to every drive and nothing answers, so Status and ReadParam are `Unsupported`,
//! and Reverse and SetSpeed need a Run, Stop or Jog first (the telegram must repeat a control
//! word the profile knows).

use std::sync::{Arc, Mutex, MutexGuard};

use drivebus_proto::fc::{
    AddressFormat, Adr, Block, ControlWord, FaultCode, ParameterNumber, ParameterResponse, Reference, Reply,
    Request, StatusWord, MAX_TELEGRAM,
};

use super::{
    CodeSpace, DriveError, DriveStatus, Exchange, Fault, Operation, Outcome, Plan, Profile, Step,
    WireProtocol,
};
use crate::{Catalog, Family, ParamDef, Size, Storage};

/// The protocol a Danfoss FC drive speaks.
pub const PROTOCOL: WireProtocol = WireProtocol::DanfossFc;

/// 3-00 Reference Range.
const REF_RANGE: u16 = 300;
/// 3-02 Minimum Reference (0.001 Hz).
const MIN_REF: u16 = 302;
/// 3-03 Maximum Reference (0.001 Hz).
const MAX_REF: u16 = 303;
/// 4-14 Motor Speed High Limit [Hz] (0.1 Hz).
const HIGH_LIMIT: u16 = 414;
/// 15-30 Alarm Log: Error Code.
const ALARM_LOG: u16 = 1530;
/// 16-00 Control Word: the last control word the drive acted on.
const CONTROL_WORD: u16 = 1600;
/// 16-02 Reference [%]: the reference the drive holds (conversion index -1).
const REFERENCE_PCT: u16 = 1602;
/// 16-14 Motor current (0.01 A).
const MOTOR_CURRENT: u16 = 1614;

/// The highest setpoint any FC drive takes: the top of 4-14's range, 500.0 Hz.
const HARD_MAX_HZ: f64 = 500.0;

/// The text of an FC alarm number, as 15-30 Alarm Log shows it (the FC-series alarm list of
/// the FC 280 / FC 300 guides; the simulated drive logs 7, 8, 13, 17, 29 and 60).
pub fn alarm_text(alarm: u32) -> Option<&'static str> {
    Some(match alarm {
        2 => "live zero error",
        4 => "mains phase loss",
        7 => "DC over voltage",
        8 => "DC under voltage",
        9 => "inverter overloaded",
        10 => "motor ETR over temperature",
        11 => "motor thermistor over temperature",
        12 => "torque limit",
        13 => "over current",
        14 => "earth fault",
        16 => "short circuit",
        17 => "control word timeout",
        29 => "heat sink temperature",
        30 => "motor phase U missing",
        31 => "motor phase V missing",
        32 => "motor phase W missing",
        38 => "internal fault",
        60 => "external interlock",
        _ => return None,
    })
}

/// The fault of an alarm number: its text, or a pointer to the alarm list.
fn alarm_fault(alarm: u32) -> Fault {
    let text = match alarm_text(alarm) {
        Some(t) => t.to_string(),
        None => format!("alarm {alarm} (see the drive's alarm list)"),
    };
    Fault { code: alarm, text }
}

/// How the drive scales the bus reference and MAV, and the speed limit above them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReferenceRange {
    /// 3-00 Reference Range = -max..+max: reference 0 is 0 Hz (with min–max it is 3-02).
    pub symmetric: bool,
    /// 3-02 Minimum Reference, Hz.
    pub min_hz: f64,
    /// 3-03 Maximum Reference, Hz: reference 0x4000 (100 %).
    pub max_hz: f64,
    /// 4-14 Motor Speed High Limit, Hz.
    pub high_limit_hz: f64,
}

impl ReferenceRange {
    /// The catalog's defaults: min–max, 3-02 = 0 Hz, 3-03 = 50 Hz, 4-14 = 65 Hz.
    pub fn catalog_defaults() -> ReferenceRange {
        ReferenceRange { symmetric: false, min_hz: 0.0, max_hz: 50.0, high_limit_hz: 65.0 }
    }

    /// The Hz of reference 0.
    fn zero_hz(&self) -> f64 {
        if self.symmetric {
            0.0
        } else {
            self.min_hz
        }
    }

    /// The reference (or MAV) for `hz`.
    pub fn reference(&self, hz: f64) -> Reference {
        Reference::from_hz(hz, self.zero_hz(), self.max_hz)
    }

    /// The Hz a reference (or MAV) stands for; negative in reverse.
    pub fn hz(&self, reference: Reference) -> f64 {
        reference.hz(self.zero_hz(), self.max_hz)
    }
}

/// What the profile knows of the drive's reference scaling (raw values, catalog units).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Known {
    /// 3-00 raw.
    range_mode: Option<i64>,
    /// 3-02 raw, 0.001 Hz.
    min_ref: Option<i64>,
    /// 3-03 raw, 0.001 Hz.
    max_ref: Option<i64>,
    /// 4-14 raw, 0.1 Hz.
    high_limit: Option<i64>,
}

impl Known {
    fn from_range(r: ReferenceRange) -> Known {
        Known {
            range_mode: Some(i64::from(r.symmetric)),
            min_ref: Some((r.min_hz * 1000.0).round() as i64),
            max_ref: Some((r.max_hz * 1000.0).round() as i64),
            high_limit: Some((r.high_limit_hz * 10.0).round() as i64),
        }
    }

    /// The scaling, once 3-00, 3-02 and 3-03 are known (4-14 defaults to its maximum).
    fn scale(&self) -> Option<ReferenceRange> {
        Some(ReferenceRange {
            symmetric: self.range_mode? == 1,
            min_hz: self.min_ref? as f64 / 1000.0,
            max_hz: self.max_ref? as f64 / 1000.0,
            high_limit_hz: self.high_limit.map_or(HARD_MAX_HZ, |r| r as f64 / 10.0),
        })
    }

    /// The parameters still to read: the scale, and 4-14 too when `limit`.
    fn missing(&self, limit: bool) -> Vec<u16> {
        let mut out = Vec::new();
        if self.range_mode.is_none() {
            out.push(REF_RANGE);
        }
        if self.min_ref.is_none() {
            out.push(MIN_REF);
        }
        if self.max_ref.is_none() {
            out.push(MAX_REF);
        }
        if limit && self.high_limit.is_none() {
            out.push(HIGH_LIMIT);
        }
        out
    }

    /// Takes in a value of one of the four, read or written at index 0.
    fn learn(&mut self, pnu: u16, raw: i64) {
        match pnu {
            REF_RANGE => self.range_mode = Some(raw),
            MIN_REF => self.min_ref = Some(raw),
            MAX_REF => self.max_ref = Some(raw),
            HIGH_LIMIT => self.high_limit = Some(raw),
            _ => {}
        }
    }
}

/// What the profile commanded last: shared by the profile and its plans.
#[derive(Clone, Copy, Debug, Default)]
struct Memory {
    /// The last control word sent with bit 10 = 1 (bit 07 cleared), `None` before the first.
    ctw: Option<ControlWord>,
    /// The reference sent with it.
    reference: Reference,
    /// The setpoint that reference stands for, Hz.
    setpoint_hz: Option<f64>,
    /// The drive's reference scaling, as far as known.
    known: Known,
    /// The next status reads the scaling again ([`Profile::refresh_setup`]).
    refresh: bool,
}

/// The profile's fixed part and its memory, shared with its plans.
#[derive(Debug)]
struct Inner {
    address: u8,
    adr: Adr,
    catalog: Arc<Catalog>,
    memory: Mutex<Memory>,
}

impl Inner {
    fn memory(&self) -> MutexGuard<'_, Memory> {
        self.memory.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    fn broadcast(&self) -> bool {
        self.adr.is_broadcast()
    }

    /// The catalog entry of a PNU the profile uses itself.
    fn def(&self, pnu: u16) -> Result<&ParamDef, DriveError> {
        self.catalog
            .by_number(u32::from(pnu))
            .ok_or_else(|| DriveError::Unsupported(format!("the FC catalog has no parameter with PNU {pnu}")))
    }
}

/// A Danfoss VLT FC-series drive on the FC protocol, for one address (or broadcast).
///
/// ```
/// use drivebus_drive::profile::danfoss::DanfossProfile;
/// use drivebus_drive::profile::{Operation, Profile, Step};
///
/// // Broadcast: every drive, no reply (a profile for one drive reads its reference first).
/// let fc = DanfossProfile::new(0)?;
/// let mut plan = fc.plan(&Operation::Stop)?;
/// let Step::Send(x) = plan.step(None)? else { panic!("a stop sends a telegram") };
/// // A process block to ADR 80: control word 043C (ramp stop), reference 0.
/// assert_eq!(x.request, [0x02, 0x06, 0x80, 0x04, 0x3C, 0x00, 0x00, 0xBC]);
/// # Ok::<(), drivebus_drive::profile::DriveError>(())
/// ```
#[derive(Debug)]
pub struct DanfossProfile {
    inner: Arc<Inner>,
}

impl DanfossProfile {
    /// Drive `address` (1–126, ADR = 0x80 | address), or 0 for broadcast, in address format
    /// 1–126 (the project's default).
    pub fn new(address: u8) -> Result<Self, DriveError> {
        Self::with_address_format(address, AddressFormat::OneTo126)
    }

    /// Drive `address` in `format` (1–126, or 1–31 for older drives: ADR = address), or 0 for
    /// broadcast.
    pub fn with_address_format(address: u8, format: AddressFormat) -> Result<Self, DriveError> {
        let adr = if address == 0 {
            Adr::broadcast(format)
        } else {
            Adr::new(address, format).map_err(|_| {
                DriveError::OutOfRange(format!(
                    "an FC drive address is 1 to {} in {} (0 for broadcast), not {address}",
                    format.max_address(),
                    format.name()
                ))
            })?
        };
        let catalog = Catalog::load(Family::Danfoss)
            .map_err(|e| DriveError::Unsupported(format!("the FC catalog does not load: {e}")))?;
        let mut memory = Memory::default();
        if adr.is_broadcast() {
            memory.known = Known::from_range(ReferenceRange::catalog_defaults());
        }
        Ok(DanfossProfile { inner: Arc::new(Inner { address, adr, catalog, memory: Mutex::new(memory) }) })
    }

    /// The reference scaling the profile uses, once it is known (read from the drive, set with
    /// [`set_reference_range`](Self::set_reference_range), or the catalog defaults for broadcast).
    pub fn reference_range(&self) -> Option<ReferenceRange> {
        let known = self.inner.memory().known;
        known.high_limit.and(known.scale())
    }

    /// Tells the profile how the drive scales the reference (3-00, 3-02, 3-03, 4-14), so it
    /// does not read them; `None` makes it read them again at the next status or set speed
    /// (after they were changed on the drive's panel).
    pub fn set_reference_range(&self, range: Option<ReferenceRange>) {
        self.inner.memory().known = range.map(Known::from_range).unwrap_or_default();
    }

    /// The control word and reference the profile sent last with bit 10 = 1, if any.
    pub fn last_command(&self) -> Option<(ControlWord, Reference)> {
        let m = self.inner.memory();
        m.ctw.map(|c| (c, m.reference))
    }

    /// The catalog entry and array index of `name` (`4-14`, `15-30[3]`).
    fn lookup(&self, name: &str) -> Result<(&ParamDef, u8), DriveError> {
        let (base, index) = split_index(name)?;
        let def =
            self.inner.catalog.get(base).ok_or_else(|| {
                DriveError::Unsupported(format!("the FC catalog has no parameter {base:?}"))
            })?;
        if usize::from(index) >= def.len() {
            let elements = match def.array {
                Some(n) => format!("an array of {n} (index 0..{})", n - 1),
                None => "not an array".to_string(),
            };
            return Err(DriveError::OutOfRange(format!(
                "{} {} is {elements}: there is no element {index}",
                def.name, def.title
            )));
        }
        if ParameterNumber::new(pnu_of(def)?).is_none() {
            return Err(DriveError::Unsupported(format!(
                "{} has PNU {}, above the 4095 that PKE can carry",
                def.name, def.number
            )));
        }
        Ok((def, index))
    }

    fn plan_for(&self, op: &Operation) -> Result<FcPlan, DriveError> {
        let inner = &self.inner;
        let broadcast = inner.broadcast();
        let no_reply = |what: &str| {
            DriveError::Unsupported(format!(
                "{what} needs a reply, and a broadcast telegram (ADR {:02X}) gets none",
                inner.adr.byte()
            ))
        };
        let mut plan = FcPlan::new(Arc::clone(inner), Goal::Done);
        let known_ctw = inner.memory().ctw.is_some();
        match op {
            Operation::Status => {
                if broadcast {
                    return Err(no_reply("a status"));
                }
                plan.goal = Goal::Status;
                let refresh = std::mem::take(&mut inner.memory().refresh);
                if refresh {
                    // Set-up values read again on the slow schedule: the drive's panel may
                    // have changed them, and a standby listening learns them from these reads.
                    for pnu in [REF_RANGE, MIN_REF, MAX_REF] {
                        plan.push(Action::read(pnu, 0, Why::Scale));
                    }
                } else {
                    plan.read_scale(false);
                }
                if refresh && inner.memory().ctw.is_none() {
                    // Nothing commanded: the setpoint is the drive's 16-02, read again (a
                    // standby's profile follows the setpoints its master commands so).
                    inner.memory().setpoint_hz = None;
                }
                let memory = *inner.memory();
                if memory.setpoint_hz.is_none() {
                    // Nothing commanded yet: the reference the drive holds (16-02).
                    plan.push(Action::read(REFERENCE_PCT, 0, Why::SyncReference));
                } else if refresh && memory.ctw.is_some() {
                    // The setpoint is the one commanded; 16-02 is read for a standby's sake
                    // (its profile, which commands nothing, reads it for the setpoint).
                    plan.push(Action::read(REFERENCE_PCT, 0, Why::Listeners));
                }
                plan.push(Action::read(MOTOR_CURRENT, 0, Why::Current));
            }
            Operation::Run | Operation::Jog => {
                let command = if *op == Operation::Run { Command::Run } else { Command::Jog };
                if !known_ctw && !broadcast {
                    plan.sync();
                }
                plan.push(Action::Command(command));
            }
            Operation::Stop => {
                // A fresh profile keeps the drive's reference (the telegram carries one): a
                // stop with reference 0 would make the next run start at 0 Hz.
                if !known_ctw && !broadcast {
                    plan.sync();
                }
                plan.push(Action::Command(Command::Stop));
            }
            Operation::Reverse => {
                if !known_ctw {
                    if broadcast {
                        return Err(needs_command("a reverse"));
                    }
                    plan.sync();
                }
                plan.push(Action::Command(Command::Reverse));
            }
            Operation::Reset => {
                if !known_ctw && !broadcast {
                    plan.sync();
                }
                plan.push(Action::Command(Command::ResetArm));
                plan.push(Action::Command(Command::ResetEdge));
            }
            Operation::SetSpeed(hz) => {
                let hz = *hz;
                check_speed_early(hz, inner.memory().known)?;
                if !known_ctw && broadcast {
                    return Err(needs_command("a set speed"));
                }
                plan.read_scale(true);
                if !known_ctw {
                    plan.sync();
                }
                plan.push(Action::Command(Command::SetSpeed(hz)));
            }
            Operation::ReadParam(name) => {
                let (def, index) = self.lookup(name)?;
                if broadcast {
                    return Err(no_reply("a parameter read"));
                }
                plan.goal = Goal::Param;
                plan.push(Action::Read { pnu: pnu_of(def)?, index, why: Why::User });
            }
            Operation::WriteParam { name, raw, storage } => {
                let (def, index) = self.lookup(name)?;
                if def.read_only {
                    return Err(DriveError::Unsupported(format!(
                        "{} {} is read-only: the drive refuses every write",
                        def.name, def.title
                    )));
                }
                def.check(*raw).map_err(|e| DriveError::OutOfRange(e.to_string()))?;
                plan.push(Action::Write { pnu: pnu_of(def)?, index, raw: *raw, storage: *storage });
            }
        }
        Ok(plan)
    }
}

/// The error for a broadcast command that must repeat an unknown control word.
fn needs_command(what: &str) -> DriveError {
    DriveError::Unsupported(format!(
        "{what} by broadcast repeats the control word last sent, and this profile has sent none: \
         give Run, Stop or Jog to the broadcast profile first"
    ))
}

/// The PNU of a catalog entry, as PKE carries it.
fn pnu_of(def: &ParamDef) -> Result<u16, DriveError> {
    u16::try_from(def.number).ok().filter(|&n| n <= ParameterNumber::MAX).ok_or_else(|| {
        DriveError::Unsupported(format!(
            "{} has PNU {}, above the 4095 that PKE can carry",
            def.name, def.number
        ))
    })
}

/// `15-30[3]` -> (`15-30`, 3); `4-14` -> (`4-14`, 0).
fn split_index(name: &str) -> Result<(&str, u8), DriveError> {
    let name = name.trim();
    let Some(open) = name.find('[') else { return Ok((name, 0)) };
    let index = name[open + 1..]
        .strip_suffix(']')
        .and_then(|digits| digits.trim().parse::<u8>().ok())
        .ok_or_else(|| {
            DriveError::Unsupported(format!(
                "{name:?} is not a parameter name: write an array element as 15-30[3] (index 0..255)"
            ))
        })?;
    Ok((name[..open].trim_end(), index))
}

/// The checks a set speed passes before anything is sent: a number, not below 0 Hz, not above
/// the known upper limit (or 500 Hz, the highest 4-14).
fn check_speed_early(hz: f64, known: Known) -> Result<(), DriveError> {
    if !hz.is_finite() {
        return Err(DriveError::OutOfRange(format!("{hz} is not a speed")));
    }
    if hz < 0.0 {
        return Err(DriveError::OutOfRange(format!(
            "{hz} Hz is below 0 Hz: give the direction with Reverse"
        )));
    }
    match (known.high_limit.is_some(), known.scale()) {
        (true, Some(range)) => check_speed(hz, &range),
        _ if hz > HARD_MAX_HZ => Err(DriveError::OutOfRange(format!(
            "{hz} Hz is above 500.0 Hz, the highest 4-14 Motor Speed High Limit an FC drive takes"
        ))),
        _ => Ok(()),
    }
}

/// A set speed against the drive's reference range and high limit.
fn check_speed(hz: f64, range: &ReferenceRange) -> Result<(), DriveError> {
    if hz < 0.0 {
        return Err(DriveError::OutOfRange(format!(
            "{hz} Hz is below 0 Hz: give the direction with Reverse"
        )));
    }
    if range.max_hz <= range.zero_hz() {
        return Err(DriveError::OutOfRange(format!(
            "the drive's reference range is empty (3-03 Maximum Reference = {:.3} Hz is not above {:.3} Hz): \
             no speed can be set by bus reference",
            range.max_hz,
            range.zero_hz()
        )));
    }
    if !range.symmetric && hz + 1e-9 < range.min_hz {
        return Err(DriveError::OutOfRange(format!(
            "{hz} Hz is below the minimum reference 3-02 = {:.3} Hz",
            range.min_hz
        )));
    }
    if hz > range.max_hz + 1e-9 {
        return Err(DriveError::OutOfRange(format!(
            "{hz} Hz is above the maximum reference 3-03 = {:.3} Hz",
            range.max_hz
        )));
    }
    if hz > range.high_limit_hz + 1e-9 {
        return Err(DriveError::OutOfRange(format!(
            "{hz} Hz is above the motor speed high limit 4-14 = {:.1} Hz",
            range.high_limit_hz
        )));
    }
    Ok(())
}

impl Profile for DanfossProfile {
    fn family(&self) -> Family {
        Family::Danfoss
    }

    fn protocol(&self) -> WireProtocol {
        PROTOCOL
    }

    /// The drive's number, 0 for broadcast.
    fn address(&self) -> u8 {
        self.inner.address
    }

    fn param(&self, name: &str) -> Result<&ParamDef, DriveError> {
        self.lookup(name).map(|(def, _)| def)
    }

    fn plan(&self, op: &Operation) -> Result<Box<dyn Plan>, DriveError> {
        Ok(Box::new(self.plan_for(op)?))
    }

    /// A status of 16-14 alone: the status word (running, trip) and the current; the output
    /// frequency only where 3-00, 3-02 and 3-03 are known, the setpoint only once commanded
    /// or read.
    fn plan_status_without_setup(&self) -> Option<Result<Box<dyn Plan>, DriveError>> {
        if self.inner.broadcast() {
            return Some(self.plan(&Operation::Status));
        }
        let mut plan = FcPlan::new(Arc::clone(&self.inner), Goal::Status);
        plan.push(Action::read(MOTOR_CURRENT, 0, Why::Current));
        Some(Ok(Box::new(plan)))
    }

    /// The next status reads 3-00, 3-02, 3-03 and 16-02 again (16-02 for the setpoint while
    /// the profile has commanded none, else only for a standby listening). A broadcast profile
    /// reads nothing.
    fn refresh_setup(&self) {
        if !self.inner.broadcast() {
            self.inner.memory().refresh = true;
        }
    }
}

/// What the plan ends with.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Goal {
    Done,
    Status,
    Param,
}

/// Why a read is made.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Why {
    /// One of 3-00, 3-02, 3-03, 4-14: remembered.
    Scale,
    /// Only for the status word and MAV of the reply.
    Sync,
    /// 16-02 Reference [%] for a profile that has commanded nothing: the reference to keep.
    SyncReference,
    /// 16-14 for a status.
    Current,
    /// Read so that a standby listening hears it; the value is not used.
    Listeners,
    /// 15-30 element 0 for a status of a tripped drive.
    Alarm,
    /// 15-30 element 0 for a refusal.
    Refusal(Refusal),
    /// The user's ReadParam.
    User,
}

/// A refusal that waits for the alarm number.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Refusal {
    /// Run or jog to a tripped drive.
    Tripped(StatusWord),
    /// The trip stayed after the reset edge.
    ResetFailed(StatusWord),
}

/// The process-data commands.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Command {
    Run,
    Stop,
    Reverse,
    Jog,
    SetSpeed(f64),
    /// The first reset telegram: stop, bit 07 = 0.
    ResetArm,
    /// The second: stop with bit 07 = 1.
    ResetEdge,
}

/// One telegram of a plan.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Action {
    Read { pnu: u16, index: u8, why: Why },
    Write { pnu: u16, index: u8, raw: i64, storage: Storage },
    Command(Command),
}

impl Action {
    fn read(pnu: u16, index: u8, why: Why) -> Action {
        Action::Read { pnu, index, why }
    }
}

/// The telegram in flight.
#[derive(Clone, Copy, Debug)]
struct Sent {
    action: Action,
    /// Control word and reference of a command telegram.
    ctw: ControlWord,
    reference: Reference,
    setpoint_hz: Option<f64>,
}

/// An FC plan: a queue of telegrams and what their replies taught.
struct FcPlan {
    inner: Arc<Inner>,
    goal: Goal,
    queue: std::collections::VecDeque<Action>,
    sent: Option<Sent>,
    /// Status word and MAV of the last reply.
    observed: Option<(StatusWord, Reference)>,
    /// 16-00 as read for a profile that has commanded nothing.
    drive_ctw: Option<ControlWord>,
    current_a: Option<f64>,
    alarm: Option<Fault>,
    value: Option<i64>,
}

impl FcPlan {
    fn new(inner: Arc<Inner>, goal: Goal) -> FcPlan {
        FcPlan {
            inner,
            goal,
            queue: std::collections::VecDeque::new(),
            sent: None,
            observed: None,
            drive_ctw: None,
            current_a: None,
            alarm: None,
            value: None,
        }
    }

    fn push(&mut self, action: Action) {
        self.queue.push_back(action);
    }

    /// Queues reads of the scale parameters not yet known (with 4-14 when `limit`).
    fn read_scale(&mut self, limit: bool) {
        if self.inner.broadcast() {
            return;
        }
        let missing = self.inner.memory().known.missing(limit);
        for pnu in missing {
            self.push(Action::read(pnu, 0, Why::Scale));
        }
    }

    /// Queues the read of 16-00 Control Word, the last control word the drive acted on, for a
    /// command from a profile that has sent none.
    fn sync(&mut self) {
        // The reference first, so that a run from a fresh profile keeps the drive's speed.
        self.push(Action::read(REFERENCE_PCT, 0, Why::SyncReference));
        self.push(Action::read(CONTROL_WORD, 0, Why::Sync));
    }

    /// The request for `action`, with what it sends.
    fn build(&mut self, action: Action) -> Result<(Vec<u8>, Sent), DriveError> {
        let adr = self.inner.adr;
        let memory = *self.inner.memory();
        // Telegrams that must not act: the last control word with bit 10 = 0, the last reference.
        let idle_ctw = memory.ctw.unwrap_or(ControlWord(0)).with(ControlWord::BIT_DATA_VALID, false);
        let idle =
            Sent { action, ctw: idle_ctw, reference: memory.reference, setpoint_hz: memory.setpoint_hz };
        let (request, sent) = match action {
            Action::Read { pnu, index, .. } => {
                let pnu = pnu_number(pnu)?;
                (Request::read(adr, pnu, index).with_process(idle.ctw, idle.reference), idle)
            }
            Action::Write { pnu, index, raw, storage } => {
                let def = self.inner.def(pnu)?;
                let eeprom = storage == Storage::Eeprom;
                let number = pnu_number(pnu)?;
                let request = match def.size {
                    Size::Word => Request::write_word(adr, number, index, raw as u16, eeprom),
                    Size::Dword => Request::write_double_word(adr, number, index, raw as u32, eeprom),
                };
                (request.with_process(idle.ctw, idle.reference), idle)
            }
            Action::Command(command) => {
                let sent = self.command(command, &memory)?;
                (Request::process(adr, sent.ctw, sent.reference), sent)
            }
        };
        let mut buf = [0u8; MAX_TELEGRAM];
        let n = request
            .emit(&mut buf)
            .map_err(|e| DriveError::Protocol(format!("the FC telegram cannot be built: {e}")))?;
        Ok((buf[..n].to_vec(), sent))
    }

    /// The control word and reference of a command, from the memory or what the drive showed.
    fn command(&self, command: Command, memory: &Memory) -> Result<Sent, DriveError> {
        let scale = memory.known.scale();
        // The control word in force: the memory's, else the drive's 16-00, else a stop.
        let current = memory.ctw.or(self.drive_ctw).unwrap_or(ControlWord::RAMP_STOP);
        let reverse = current.reverse();
        let base = |word: ControlWord| word.with(ControlWord::BIT_REVERSE, reverse);
        let mut sent = Sent {
            action: Action::Command(command),
            ctw: current,
            reference: memory.reference,
            setpoint_hz: memory.setpoint_hz,
        };
        match command {
            Command::Run => sent.ctw = base(ControlWord::START),
            Command::Stop | Command::ResetArm => sent.ctw = base(ControlWord::RAMP_STOP),
            Command::ResetEdge => sent.ctw = base(ControlWord::RAMP_STOP).with(ControlWord::BIT_RESET, true),
            Command::Jog => sent.ctw = base(ControlWord::JOG),
            Command::Reverse => sent.ctw = current.with(ControlWord::BIT_REVERSE, !current.reverse()),
            Command::SetSpeed(hz) => {
                let range = match (memory.known.high_limit.is_some(), scale) {
                    (true, Some(range)) => range,
                    _ => {
                        return Err(DriveError::Protocol(
                            "the reference range (3-00, 3-02, 3-03, 4-14) was not read".to_string(),
                        ))
                    }
                };
                check_speed(hz, &range)?;
                sent.reference = range.reference(hz);
                sent.setpoint_hz = Some(hz);
            }
        }
        Ok(sent)
    }

    /// Takes in the reply to `sent`.
    fn take_reply(&mut self, sent: Sent, bytes: &[u8]) -> Result<(), DriveError> {
        let reply = Reply::parse(bytes)
            .map_err(|e| DriveError::Protocol(format!("the reply is not an FC telegram: {e}")))?;
        if reply.adr != self.inner.adr {
            return Err(DriveError::Protocol(format!(
                "the reply carries ADR {:02X}, the request {:02X}",
                reply.adr.byte(),
                self.inner.adr.byte()
            )));
        }
        self.observed = Some((reply.stw, reply.mav));
        match sent.action {
            Action::Command(command) => {
                if !matches!(reply.block, Block::Process) {
                    return Err(DriveError::Protocol(
                        "a process block was answered with a parameter or text block".to_string(),
                    ));
                }
                self.commanded(sent, command, reply.stw)
            }
            Action::Read { pnu, index, why } => {
                let raw = match (self.value_of(&reply, pnu), why) {
                    (Ok(raw), _) => raw,
                    // The alarm log could not be read: refuse with the status word, or report
                    // the trip without its number.
                    (Err(DriveError::Refused { .. }), Why::Refusal(refusal)) => {
                        return Err(refused(refusal, None))
                    }
                    (Err(DriveError::Refused { .. }), Why::Alarm) => return Ok(()),
                    // Read for a listener only: a drive that will not tell still has a status.
                    (Err(DriveError::Refused { .. }), Why::Listeners) => return Ok(()),
                    (Err(e), _) => return Err(e),
                };
                match why {
                    Why::Scale => self.inner.memory().known.learn(pnu, raw),
                    Why::Sync => self.synced(raw)?,
                    Why::SyncReference => {
                        let reference = Reference::from_percent(raw as f64 / 10.0);
                        let mut memory = self.inner.memory();
                        memory.reference = reference;
                        // 16-02 has 0.1 % steps (0.05 Hz of 50 Hz): hundredths say all it knows.
                        memory.setpoint_hz =
                            memory.known.scale().map(|range| super::round_to(range.hz(reference), 2));
                    }
                    Why::Current => {
                        self.current_a = Some(self.inner.def(pnu)?.from_raw(raw));
                        if reply.stw.trip() {
                            self.queue.push_front(Action::read(ALARM_LOG, 0, Why::Alarm));
                        }
                    }
                    Why::Alarm => self.alarm = Some(alarm_fault(raw as u32)),
                    Why::Listeners => {}
                    Why::Refusal(refusal) => return Err(refused(refusal, Some(raw as u32))),
                    Why::User => {
                        if index == 0 {
                            self.inner.memory().known.learn(pnu, raw);
                        }
                        self.value = Some(raw);
                    }
                }
                Ok(())
            }
            Action::Write { pnu, index, .. } => {
                let raw = self.value_of(&reply, pnu)?;
                if index == 0 {
                    self.inner.memory().known.learn(pnu, raw);
                }
                Ok(())
            }
        }
    }

    /// Takes in 16-00 for a profile that has commanded nothing yet. A word with bit 10 = 0 was
    /// never acted on (0000 after power-up): the drive holds no bus start.
    fn synced(&mut self, raw: i64) -> Result<(), DriveError> {
        let word = ControlWord(raw as u16).with(ControlWord::BIT_RESET, false);
        let word = if word.data_valid() { word } else { ControlWord::RAMP_STOP };
        self.drive_ctw = Some(word);
        let started = word.start() && !word.jog();
        match self.queue.front() {
            // Already started: nothing to send. A tripped drive did not take the start: refused
            // as a run to it is (the status word of the 16-00 reply says so).
            Some(Action::Command(Command::Run)) if started => {
                self.queue.pop_front();
                match self.observed {
                    Some((stw, _)) if !stw.bus_control() => return Err(no_bus_control(stw)),
                    Some((stw, _)) if stw.trip() => {
                        self.queue.push_front(Action::read(ALARM_LOG, 0, Why::Refusal(Refusal::Tripped(stw))))
                    }
                    _ => {}
                }
            }
            _ => {}
        }
        Ok(())
    }

    /// The raw value of an AK 1/2 reply for `pnu`, or the drive's AK 7 refusal.
    fn value_of(&self, reply: &Reply<'_>, pnu: u16) -> Result<i64, DriveError> {
        let Block::Parameter(p) = reply.block else {
            return Err(DriveError::Protocol(
                "a parameter block was answered with a process or text block".to_string(),
            ));
        };
        if p.ak == ParameterResponse::CannotPerform {
            let code = FaultCode(p.pwe_low());
            let meaning = code.meaning().unwrap_or("not in the FC fault table");
            return Err(DriveError::Refused {
                code: u32::from(code.0),
                space: CodeSpace::FcFault,
                meaning: meaning.to_string(),
            });
        }
        if p.pnu.pnu() != pnu {
            return Err(DriveError::Protocol(format!(
                "the reply is for parameter {} (PNU {}), the request for PNU {pnu}",
                p.pnu,
                p.pnu.pnu()
            )));
        }
        if !matches!(p.ak, ParameterResponse::ValueWord | ParameterResponse::ValueDoubleWord) {
            return Err(DriveError::Protocol(format!(
                "a value was asked for and the drive answered AK {:X} ({})",
                p.ak.ak(),
                p.ak.name()
            )));
        }
        let def = self.inner.def(pnu)?;
        let signed = def.min < 0;
        Ok(match def.size {
            Size::Word if signed => i64::from(p.pwe as u16 as i16),
            Size::Word => i64::from(p.pwe as u16),
            Size::Dword if signed => i64::from(p.pwe as i32),
            Size::Dword => i64::from(p.pwe),
        })
    }

    /// The reply's status word after a command: remember it, or refuse.
    fn commanded(&mut self, sent: Sent, command: Command, stw: StatusWord) -> Result<(), DriveError> {
        if !stw.bus_control() {
            return Err(no_bus_control(stw));
        }
        self.remember(sent);
        match command {
            Command::Run | Command::Jog if stw.trip() => {
                self.queue.clear();
                self.queue.push_back(Action::read(ALARM_LOG, 0, Why::Refusal(Refusal::Tripped(stw))));
            }
            Command::ResetEdge if stw.trip() => {
                self.queue.clear();
                self.queue.push_back(Action::read(ALARM_LOG, 0, Why::Refusal(Refusal::ResetFailed(stw))));
            }
            _ => {}
        }
        Ok(())
    }

    /// A command the drive took: it now holds this control word and reference.
    fn remember(&mut self, sent: Sent) {
        if let Action::Command(_) = sent.action {
            let mut m = self.inner.memory();
            m.ctw = Some(sent.ctw.with(ControlWord::BIT_RESET, false));
            m.reference = sent.reference;
            m.setpoint_hz = sent.setpoint_hz;
        }
    }

    /// The outcome once the queue is empty.
    fn finish(&mut self) -> Result<Outcome, DriveError> {
        match self.goal {
            Goal::Done => Ok(Outcome::Done),
            Goal::Param => self
                .value
                .map(Outcome::Param)
                .ok_or_else(|| DriveError::Protocol("no value was read".to_string())),
            Goal::Status => {
                let (stw, mav) = self
                    .observed
                    .ok_or_else(|| DriveError::Protocol("no status word was read".to_string()))?;
                let memory = *self.inner.memory();
                let hz = memory.known.scale().map(|s| s.hz(mav));
                let direction = match hz {
                    Some(h) if h > 0.05 => Some("forward"),
                    Some(h) if h < -0.05 => Some("reverse"),
                    _ => memory.ctw.map(|c| if c.reverse() { "reverse" } else { "forward" }),
                };
                let fault = if stw.trip() {
                    Some(self.alarm.clone().unwrap_or(Fault {
                        code: 0,
                        text: format!("tripped (status word {stw}); the alarm number was not read"),
                    }))
                } else {
                    None
                };
                Ok(Outcome::Status(DriveStatus {
                    address: self.inner.address,
                    running: stw.in_operation(),
                    direction: direction.map(str::to_string),
                    output_hz: hz.map(|h| super::round_to(h.abs(), 3)),
                    setpoint_hz: memory.setpoint_hz,
                    current_a: self.current_a,
                    fault,
                    values: Vec::new(),
                }))
            }
        }
    }
}

/// The refusal of a command to a drive that does not take the bus control word.
fn no_bus_control(stw: StatusWord) -> DriveError {
    DriveError::Refused {
        code: u32::from(stw.0),
        space: CodeSpace::StatusWord,
        meaning: format!(
            "the drive ignores the bus control word: status word {stw} has bit 09 \"bus control\" = 0 \
             (8-02 Control Source, 8-01 Control Site)"
        ),
    }
}

/// The refusal once the alarm number is known (or could not be read).
fn refused(refusal: Refusal, alarm: Option<u32>) -> DriveError {
    let (stw, what) = match refusal {
        Refusal::Tripped(stw) => (stw, "the drive is tripped: reset it first"),
        Refusal::ResetFailed(stw) => (stw, "the trip is still in force after the reset: its cause persists"),
    };
    match alarm {
        Some(alarm) => {
            let fault = alarm_fault(alarm);
            DriveError::Refused {
                code: alarm,
                space: CodeSpace::Trip,
                meaning: format!("{what} (alarm {alarm}: {})", fault.text),
            }
        }
        None => DriveError::Refused {
            code: u32::from(stw.0),
            space: CodeSpace::StatusWord,
            meaning: format!("{what} (status word {stw})"),
        },
    }
}

fn pnu_number(pnu: u16) -> Result<ParameterNumber, DriveError> {
    ParameterNumber::new(pnu)
        .ok_or_else(|| DriveError::Unsupported(format!("PNU {pnu} is above the 4095 that PKE can carry")))
}

impl Plan for FcPlan {
    fn step(&mut self, reply: Option<&[u8]>) -> Result<Step, DriveError> {
        if let Some(sent) = self.sent.take() {
            if self.inner.broadcast() {
                // No reply comes: the drives took it.
                self.remember(sent);
                if let Action::Write { pnu, index: 0, raw, .. } = sent.action {
                    self.inner.memory().known.learn(pnu, raw);
                }
            } else {
                let bytes = reply.ok_or_else(|| {
                    DriveError::Protocol(format!("drive {} did not answer", self.inner.address))
                })?;
                self.take_reply(sent, bytes)?;
            }
        }
        match self.queue.pop_front() {
            Some(action) => {
                let (request, sent) = self.build(action)?;
                self.sent = Some(sent);
                Ok(Step::Send(Exchange { request, expect_reply: !self.inner.broadcast() }))
            }
            None => self.finish().map(Step::Done),
        }
    }
}
