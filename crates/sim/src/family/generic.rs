//! The generic Chinese VFD of `seeds/004_e8ea1998fe1a671e.txt`: Modbus RTU or ASCII with the
//! 2000H/2100H register map and the parameters Pgg.nn at register 0xGGNN.
//!
//! What the manual says and the simulator does:
//!
//! - Functions 03 (read), 06 (write one register) and 08 (loop-back: "变频器将收到的资料原封
//!   不动送给主控设备", the drive sends the received data back unchanged, whatever the
//!   sub-function). Every other function is answered with exception 01 ("功能码错误。变频器能够
//!   辩识功能码: 03H 06H 08H").
//! - Exceptions 01, 02 ("资料地址错误", an address the drive does not know) and 03 ("资料内容
//!   错误。资料内容超限", data out of its limits) only.
//! - A 03 read carries at most 8 data bytes ("N<=8, 最大 8 个字节"): 1 to 4 registers; more is
//!   exception 03.
//! - Address 0 is a broadcast: every drive acts, none answers ("主机使用广播地址发送命令时,
//!   从机不应答"). A frame with a bad CRC or LRC is dropped without a word ("丢弃该消息帧,
//!   并不作任何回应").
//!
//! Where the manual is silent (the project decisions in `protocols.md` and these choices):
//!
//! - Writing a read-only register (2100H..210BH, the P4 fault records) is exception 02: the
//!   address is not one the drive accepts for 06. A value out of range, a parameter that cannot
//!   change while running, a locked parameter (P0.15) and every refused command are exception 03.
//! - 2000H commands 1..9 need P0.01 = 2 (communication); otherwise exception 03. Fault reset
//!   (0AH) is accepted from any control source. A run or jog command the drive cannot obey
//!   (tripped, no hardware enable, reverse prohibited by P0.03 = 2) and a fault reset while the
//!   cause persists are exception 03 as well, so a master always learns that nothing happened.
//! - Command 1 (run) and 4 (jog) keep the commanded direction: the last 2/3/5/6 command, or
//!   P0.03 (0 forward, 1 reverse) as set at start or written while the motor stands. Command 7
//!   stops on the ramp (P0.13 = 1: coasts), 8 coasts, 9 stops a jog and does nothing otherwise.
//! - The simulator starts with P0.01 = 2 (run commands from communication) and P0.00 = 4
//!   (frequency from 2001H), not the catalog's keypad defaults, so that a fresh master can run
//!   the drive; P3.10 = 3 (RTU 8N2) or 0 (ASCII 7N2, the catalog default) and P3.11 = the
//!   address match the drive as built. These are forced, not written: no EEPROM count.
//! - The setpoint is 2001H when P0.00 = 4 and P0.02 otherwise (the simulation has no
//!   potentiometer, analog inputs or multi-step terminals), limited to P0.05 and P0.04. 2001H,
//!   P0.02, P0.05 and P0.06 above the maximum frequency P0.04 are exception 03, so is
//!   P0.06 above P0.05.
//! - 2100H fault codes: 0 none, 1 over-current, 2 over-voltage, 3 under-voltage, 4 module
//!   over-temperature, 5 external fault, 6 communication time-out ([`Trip::code`]). The P4
//!   fault records follow the trips.
//! - 2000H and 2001H read back the last command and setpoint written; 2109H/210AH (VI, CI) read
//!   the values the control interface forces into those catalog entries (0 by default);
//!   210BH reads version 1.00 (0x0100).
//! - P0.14 = 1 restores the simulator's starting values except the communication group
//!   P3.09..P3.14, = 2 clears P4.00..P4.03; it reads back 0. P3.11 changes the address after
//!   the reply. P3.12 lengthens the response delay (the longer of it and the core's delay).
//!   P3.13 (0.1 s, 0 off) is the communication time-out unless P3.14 = 0 (alarm only); the
//!   model trips and coasts for both 1 and 2. P3.09/P3.10 are stored; the virtual line keeps
//!   the baud rate and format it was built with.
//! - RTU frames are framed by the codec's length prediction, and by the silence after them for
//!   function codes whose length no Modbus layout gives (41H, 2BH with an MEI type other than
//!   0EH): those get exception 01 too, as a drive that frames by silence answers them.

use std::time::Duration;

use drivebus_drive::{Family, ParamStore, Storage, WriteError};
use drivebus_proto::hex;
use drivebus_proto::line::CharFormat;
use drivebus_proto::modbus::ascii::ModbusAscii;
use drivebus_proto::modbus::rtu::{self, ModbusRtu, MAX_ADU, MIN_ADU};
use drivebus_proto::modbus::{
    Data, ExceptionCode, RegisterAddress, Registers, Reply, ReplyPdu, Request, RequestPdu, UnitId,
};
use drivebus_proto::session::{Incoming, SlaveSession};
use drivebus_proto::{FrameError, Instant};

use crate::drive::{Device, DriveCore, VirtualDrive};
use crate::model::{ModelSettings, Rotation, Trip};

/// The register map of this drive, shared with the master profile.
pub use drivebus_drive::registers::generic::{command, reg, status};

/// The software version 210BH reads, BCD: 1.00.
pub const VERSION_BCD: u16 = 0x0100;

// Parameters the drive acts on (register 0xGGNN of Pgg.nn).
const P0_00_FREQ_SOURCE: u32 = 0x0000;
const P0_01_RUN_SOURCE: u32 = 0x0001;
const P0_02_KEYPAD_FREQ: u32 = 0x0002;
const P0_03_DIRECTION: u32 = 0x0003;
const P0_04_MAX_FREQ: u32 = 0x0004;
const P0_05_UPPER_LIMIT: u32 = 0x0005;
const P0_06_LOWER_LIMIT: u32 = 0x0006;
const P0_07_ACCEL: u32 = 0x0007;
const P0_08_DECEL: u32 = 0x0008;
const P0_10_MAX_VOLTAGE: u32 = 0x0010;
const P0_13_STOP_MODE: u32 = 0x0013;
const P0_14_INIT: u32 = 0x0014;
const P0_15_PROTECT: u32 = 0x0015;
const P1_05_JOG_FREQ: u32 = 0x0105;
const P1_10_RATED_CURRENT: u32 = 0x0110;
const P1_11_RATED_FREQ: u32 = 0x0111;
const P1_12_RATED_SPEED: u32 = 0x0112;
const P3_09_BAUD: u32 = 0x0309;
const P3_10_FORMAT: u32 = 0x0310;
const P3_11_ADDRESS: u32 = 0x0311;
const P3_12_DELAY: u32 = 0x0312;
const P3_13_TIMEOUT: u32 = 0x0313;
const P3_14_TIMEOUT_ACTION: u32 = 0x0314;
const P4_00_LAST_FAULT: u32 = 0x0400;
const P4_01_PREVIOUS_FAULT: u32 = 0x0401;
const P4_02_FAULT_FREQ: u32 = 0x0402;
const P4_03_FAULT_CURRENT: u32 = 0x0403;
const P4_04_RUN_TIME: u32 = 0x0404;

/// P0.00 = 4: frequency from communication (2001H).
const SOURCE_COMM: i64 = 4;
/// P0.01 = 2: run commands from communication.
const RUN_SOURCE_COMM: i64 = 2;

pub use drivebus_drive::profile::generic::GenericProtocol;

/// The default character format of `protocol`: ASCII 1-7-2 without parity (the manual's
/// default, "1 位起始位,7 位数据位,2 位停止位"), RTU 1-8-2 without parity (the family's table).
pub fn char_format(protocol: GenericProtocol) -> CharFormat {
    Family::Generic.serial_default(protocol.wire()).1
}

/// The P3.10 value for [`char_format`]: 3 (RTU 1-8-2) or 0 (ASCII 1-7-2).
fn p3_10(protocol: GenericProtocol) -> i64 {
    match protocol {
        GenericProtocol::Rtu => 3,
        GenericProtocol::Ascii => 0,
    }
}

/// A generic Chinese VFD on the virtual line, answering Modbus RTU or ASCII.
pub struct GenericDrive {
    session: Session,
    state: State,
    /// RTU bytes heard since the last silence (at most one frame's worth).
    heard: Vec<u8>,
    /// An exception 01 this file frames itself (see [`GenericDrive::unsized_function`]).
    own_reply: Option<(Instant, Vec<u8>)>,
}

enum Session {
    Rtu(Box<SlaveSession<ModbusRtu>>),
    Ascii(Box<SlaveSession<ModbusAscii>>),
}

/// Everything but the slave session, so the session's handler can borrow it.
struct State {
    core: DriveCore,
    protocol: GenericProtocol,
    /// The newest trip already copied into the P4 fault records.
    recorded_trip: Option<(Instant, Trip)>,
    /// Motor current before the last model step, for P4.03 at a trip.
    current_before_a: f64,
    /// A new address from a P3.11 write, applied once the reply is queued.
    new_address: Option<u8>,
    /// The session handed over a frame since the last RTU silence.
    handled: bool,
}

impl GenericDrive {
    /// A stopped drive numbered `address` (1..=254, "最大可到 254 (FEH)") speaking `protocol`.
    pub fn new(address: u8, protocol: GenericProtocol, now: Instant) -> Result<Self, String> {
        if !(1..=254).contains(&address) {
            return Err(format!(
                "a generic drive's address is 1..254 (0 is the broadcast address), not {address}"
            ));
        }
        let params = ParamStore::for_family(Family::Generic).map_err(|e| e.to_string())?;
        let settings = settings_from(&params);
        let core = DriveCore::new(params, settings, address, now);
        let delay = core.response_delay;
        let session = match protocol {
            GenericProtocol::Rtu => Session::Rtu(Box::new(SlaveSession::new(ModbusRtu, address, delay))),
            GenericProtocol::Ascii => {
                Session::Ascii(Box::new(SlaveSession::new(ModbusAscii, address, delay)))
            }
        };
        let mut state = State {
            core,
            protocol,
            recorded_trip: None,
            current_before_a: 0.0,
            new_address: None,
            handled: false,
        };
        state.starting_values();
        state.core.params.force(P3_11_ADDRESS, 0, i64::from(address)).map_err(|e| e.to_string())?;
        state
            .core
            .params
            .force(u32::from(reg::VERSION), 0, i64::from(VERSION_BCD))
            .map_err(|e| e.to_string())?;
        state.apply_parameters();
        state.apply_comm_timeout();
        Ok(GenericDrive { session, state, heard: Vec::with_capacity(MAX_ADU), own_reply: None })
    }

    /// The transmission mode it speaks.
    pub fn protocol_kind(&self) -> GenericProtocol {
        self.state.protocol
    }

    /// The value a 03 read of `register` returns now, or `None` for an address the drive does
    /// not know (exception 02).
    pub fn register(&mut self, register: u16) -> Option<u16> {
        self.state.sync_fault_records();
        self.state.read_register(register)
    }

    /// Brings the session in line with the core before bytes are handled: the address (the
    /// control interface may change `core.address`) and the response delay (P3.12).
    fn prepare(&mut self) {
        let address = self.state.core.address;
        if self.state.param(P3_11_ADDRESS) != i64::from(address) {
            let _ = self.state.core.params.force(P3_11_ADDRESS, 0, i64::from(address));
        }
        let delay = self.state.reply_delay();
        match &mut self.session {
            Session::Rtu(s) => {
                s.set_address(address);
                s.set_response_delay(delay);
            }
            Session::Ascii(s) => {
                s.set_address(address);
                s.set_response_delay(delay);
            }
        }
    }

    /// An RTU frame with a good CRC, addressed to this drive, whose function code has no
    /// length the codec knows (41H, 2BH with an MEI type other than 0EH): the codec's request
    /// scanner rejects such a frame after its first two bytes, so the session never hands it
    /// over. The real drive frames by silence and answers "功能码错误" (01); so does this one.
    fn unsized_function(&mut self, now: Instant) {
        let handled = std::mem::replace(&mut self.state.handled, false);
        let frame = &self.heard;
        let whole = !handled && (MIN_ADU..=MAX_ADU).contains(&frame.len()) && rtu::crc_ok(frame);
        let head = whole.then(|| (frame[0], frame[1]));
        self.heard.clear();
        let Some((address, function)) = head else { return };
        let me = self.state.core.address;
        if function & 0x80 != 0 || (address != me && address != 0) {
            return;
        }
        self.state.core.model.comm_seen(now);
        if address == 0 {
            // A broadcast is never answered, not even with an exception.
            return;
        }
        let reply = Reply::exception(UnitId(address), function, ILLEGAL_FUNCTION);
        let mut out = [0u8; 5];
        if let Ok(n) = reply.emit_rtu(&mut out) {
            self.own_reply = Some((now + self.state.reply_delay(), out[..n].to_vec()));
        }
    }

    /// Applies a P3.11 write once its reply has been queued under the old address.
    fn finish(&mut self) {
        if let Some(address) = self.state.new_address.take() {
            self.state.core.address = address;
            match &mut self.session {
                Session::Rtu(s) => s.set_address(address),
                Session::Ascii(s) => s.set_address(address),
            }
        }
    }
}

impl Device for GenericDrive {
    fn receive(&mut self, now: Instant, bytes: &[u8]) {
        self.prepare();
        if matches!(self.session, Session::Rtu(_)) {
            let room = MAX_ADU + 1 - self.heard.len().min(MAX_ADU + 1);
            self.heard.extend_from_slice(&bytes[..bytes.len().min(room)]);
        }
        let state = &mut self.state;
        match &mut self.session {
            Session::Rtu(s) => s.handle_input(now, bytes, &mut |now, incoming, responder| {
                if let Some(answer) = state.handle(now, incoming, Framing::Rtu) {
                    // A reply always fits the session's frame buffer; nothing to do otherwise.
                    let _ = responder.reply(&answer.reply());
                }
            }),
            Session::Ascii(s) => s.handle_input(now, bytes, &mut |now, incoming, responder| {
                if let Some(answer) = state.handle(now, incoming, Framing::Ascii) {
                    let _ = responder.reply(&answer.reply());
                }
            }),
        }
        self.finish();
    }

    fn silence(&mut self, now: Instant) {
        // RTU frames end with silence ("保持无输入信号大于等于 10ms"); ASCII ends with CR LF.
        self.prepare();
        let state = &mut self.state;
        if let Session::Rtu(s) = &mut self.session {
            s.handle_silence(now, &mut |now, incoming, responder| {
                if let Some(answer) = state.handle(now, incoming, Framing::Rtu) {
                    let _ = responder.reply(&answer.reply());
                }
            });
            self.unsized_function(now);
        }
        self.finish();
    }

    fn poll_transmit(&mut self, now: Instant) -> Option<Vec<u8>> {
        let from_session = match &mut self.session {
            Session::Rtu(s) => s.poll_transmit(now).map(<[u8]>::to_vec),
            Session::Ascii(s) => s.poll_transmit(now).map(<[u8]>::to_vec),
        };
        from_session.or_else(|| match &self.own_reply {
            Some((at, _)) if *at <= now => self.own_reply.take().map(|(_, bytes)| bytes),
            _ => None,
        })
    }

    fn poll_timeout(&self) -> Option<Instant> {
        let session = match &self.session {
            Session::Rtu(s) => s.poll_timeout(),
            Session::Ascii(s) => s.poll_timeout(),
        };
        let own = self.own_reply.as_ref().map(|(at, _)| *at);
        [session, own].into_iter().flatten().min()
    }

    fn advance_to(&mut self, now: Instant) {
        self.state.current_before_a = self.state.core.model.current_a();
        self.state.core.model.advance_to(now);
        self.state.sync_fault_records();
    }

    crate::drive::device_is_a_drive!();
}

impl VirtualDrive for GenericDrive {
    fn protocol(&self) -> String {
        self.state.protocol.wire().name().to_string()
    }

    crate::drive::drive_core_at!(state.core);

    fn control_source(&self) -> String {
        let params = &self.state.core.params;
        let value = params.get(P0_01_RUN_SOURCE).unwrap_or(0);
        let text = params.catalog().by_number(P0_01_RUN_SOURCE).and_then(|d| d.choice(value)).unwrap_or("?");
        format!("P0.01 = {value} {text}")
    }

    fn set_param(&mut self, name: &str, value: &str) -> Result<(), String> {
        crate::drive::set_param_as_keypad(&mut self.state.core, name, value)?;
        self.state.apply_parameters();
        self.state.apply_comm_timeout();
        Ok(())
    }

    /// RUN works while P0.01 = 0 (run commands from the keypad); STOP always works.
    fn press_run(&mut self, run: bool) -> Result<(), String> {
        let source = self.state.param(P0_01_RUN_SOURCE);
        if run && source != 0 {
            return Err(format!(
                "P0.01 = {source}: run commands do not come from the keypad; set P0.01 = 0 first"
            ));
        }
        let coast = self.state.param(P0_13_STOP_MODE) == 1;
        let model = &mut self.state.core.model;
        if !run && coast {
            model.coast();
            return Ok(());
        }
        if !run {
            model.stop();
            return Ok(());
        }
        model.run().map_err(|_| {
            "the drive does not start: it is tripped or its hardware enable input is off".to_string()
        })
    }

    /// P0.02, the keypad digital frequency setting.
    fn set_keypad_hz(&mut self, hz: f64) -> Result<(), String> {
        self.set_param("P0.02", &format!("{hz}"))
    }
}

/// How the bytes of a rejected frame are laid out, to find its address and function code.
#[derive(Clone, Copy)]
enum Framing {
    Rtu,
    Ascii,
}

impl Framing {
    /// The address and function code of a frame the codec rejected (already known to carry a
    /// good CRC or LRC: the session hands over no other).
    fn head(self, bytes: &[u8]) -> Option<(u8, u8)> {
        match self {
            Framing::Rtu => Some((*bytes.first()?, *bytes.get(1)?)),
            Framing::Ascii => {
                let digits = bytes.get(1..5)?;
                Some((hex::decode_pair(digits[0], digits[1])?, hex::decode_pair(digits[2], digits[3])?))
            }
        }
    }
}

/// A reply to send, owning its data so it outlives the request it answers.
enum Answer {
    Read { unit: UnitId, values: [u16; 4], len: usize },
    Write { unit: UnitId, address: u16, value: u16 },
    Echo { unit: UnitId, sub_function: u16, data: Vec<u8> },
    Exception { unit: UnitId, function: u8, code: ExceptionCode },
}

impl Answer {
    fn reply(&self) -> Reply<'_> {
        match self {
            Answer::Read { unit, values, len } => Reply {
                unit: *unit,
                pdu: ReplyPdu::ReadHoldingRegisters { values: Registers::from_values(&values[..*len]) },
            },
            Answer::Write { unit, address, value } => Reply {
                unit: *unit,
                pdu: ReplyPdu::WriteSingleRegister { address: RegisterAddress(*address), value: *value },
            },
            Answer::Echo { unit, sub_function, data } => Reply {
                unit: *unit,
                pdu: ReplyPdu::Diagnostics { sub_function: *sub_function, data: Data::binary(data) },
            },
            Answer::Exception { unit, function, code } => Reply::exception(*unit, *function, *code),
        }
    }
}

const ILLEGAL_FUNCTION: ExceptionCode = ExceptionCode::ILLEGAL_FUNCTION;
const ILLEGAL_ADDRESS: ExceptionCode = ExceptionCode::ILLEGAL_DATA_ADDRESS;
const ILLEGAL_VALUE: ExceptionCode = ExceptionCode::ILLEGAL_DATA_VALUE;

/// The model's settings from the parameters: P0.07/P0.08 ramps (0.1 s, from 0 to the maximum
/// frequency), P0.04 maximum and P0.06 lower limit frequency, P1.05 jog frequency, motor data
/// P1.10 (0.1 A), P1.11 (0.01 Hz), P1.12 (rpm); the DC bus is 1.35 x P0.10 (the maximum output
/// voltage stands for the mains the drive is built for).
fn settings_from(params: &ParamStore) -> ModelSettings {
    let p = |number: u32, fallback: i64| params.get(number).unwrap_or(fallback).max(0) as f64;
    let defaults = ModelSettings::default();
    ModelSettings {
        accel: Duration::from_millis(100 * p(P0_07_ACCEL, 100) as u64),
        decel: Duration::from_millis(100 * p(P0_08_DECEL, 100) as u64),
        min_hz: p(P0_06_LOWER_LIMIT, 0) / 100.0,
        max_hz: p(P0_04_MAX_FREQ, 5000) / 100.0,
        jog_hz: p(P1_05_JOG_FREQ, 500) / 100.0,
        rated_current_a: p(P1_10_RATED_CURRENT, 37) / 10.0,
        rated_rpm: p(P1_12_RATED_SPEED, 1440),
        base_hz: p(P1_11_RATED_FREQ, 5000) / 100.0,
        nominal_dc_v: 1.35 * p(P0_10_MAX_VOLTAGE, 380),
        ..defaults
    }
}

/// A measured value as an unsigned register, rounded and saturated.
fn unsigned(v: f64) -> u16 {
    v.round().clamp(0.0, f64::from(u16::MAX)) as u16
}

/// A measured value as a signed (two's complement) register, rounded and saturated.
fn signed(v: f64) -> u16 {
    v.round().clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16 as u16
}

/// The exception a refused parameter write gets.
fn write_exception(e: &WriteError) -> ExceptionCode {
    match e {
        // "资料地址错误。资料地址变频器无法辩识": not an address the drive writes.
        WriteError::UnknownParameter { .. }
        | WriteError::ReadOnly { .. }
        | WriteError::NoSuchElement { .. } => ILLEGAL_ADDRESS,
        // "资料内容错误。资料内容超限": a value the drive does not take (now).
        WriteError::OutOfRange(_) | WriteError::NotWhileRunning { .. } => ILLEGAL_VALUE,
    }
}

impl State {
    fn param(&self, number: u32) -> i64 {
        self.core.params.get(number).unwrap_or(0)
    }

    /// The simulator's starting values that differ from the catalog defaults (see the module
    /// docs): forced, so they cost no EEPROM write.
    fn starting_values(&mut self) {
        let params = &mut self.core.params;
        let _ = params.force(P0_00_FREQ_SOURCE, 0, SOURCE_COMM);
        let _ = params.force(P0_01_RUN_SOURCE, 0, RUN_SOURCE_COMM);
        let _ = params.force(P3_10_FORMAT, 0, p3_10(self.protocol));
        let direction = if self.param(P0_03_DIRECTION) == 1 { Rotation::Reverse } else { Rotation::Forward };
        self.core.model.set_rotation(direction);
    }

    /// Re-derives the model's settings and setpoint from the parameters.
    fn apply_parameters(&mut self) {
        let settings = settings_from(&self.core.params);
        if settings != *self.core.model.settings() {
            self.core.model.set_settings(settings);
        }
        self.apply_setpoint();
    }

    /// The setpoint: 2001H when P0.00 = 4, else P0.02; limited to P0.05 (and P0.04).
    fn apply_setpoint(&mut self) {
        let raw = if self.param(P0_00_FREQ_SOURCE) == SOURCE_COMM {
            self.param(u32::from(reg::FREQUENCY))
        } else {
            self.param(P0_02_KEYPAD_FREQ)
        };
        let limit = self.param(P0_05_UPPER_LIMIT).min(self.param(P0_04_MAX_FREQ));
        self.core.model.set_setpoint_hz(raw.min(limit).max(0) as f64 / 100.0);
    }

    /// P3.13 (0.1 s, 0 off) with P3.14 (0 alarm only: no trip).
    fn apply_comm_timeout(&mut self) {
        let tenths = self.param(P3_13_TIMEOUT);
        let timeout = (tenths > 0 && self.param(P3_14_TIMEOUT_ACTION) != 0)
            .then(|| Duration::from_millis(100 * tenths as u64));
        self.core.model.set_comm_timeout(timeout);
    }

    /// The delay before a reply: the core's, or P3.12 (ms) if longer.
    fn reply_delay(&self) -> Duration {
        let p3_12 = Duration::from_millis(self.param(P3_12_DELAY).max(0) as u64);
        self.core.response_delay.max(p3_12)
    }

    /// Copies a new trip into the P4 fault records and the run hours into P4.04.
    fn sync_fault_records(&mut self) {
        let newest = self.core.model.trip_log().last().copied();
        if let Some(record) = newest {
            if self.recorded_trip != Some((record.at, record.trip)) {
                self.recorded_trip = Some((record.at, record.trip));
                let previous = self.param(P4_00_LAST_FAULT);
                let current = (self.current_before_a * 10.0).round() as i64;
                let params = &mut self.core.params;
                let _ = params.force(P4_01_PREVIOUS_FAULT, 0, previous);
                let _ = params.force(P4_00_LAST_FAULT, 0, i64::from(record.trip.code()));
                let _ = params.force(P4_02_FAULT_FREQ, 0, (record.output_mhz / 10).clamp(0, 40000));
                let _ = params.force(P4_03_FAULT_CURRENT, 0, current.clamp(0, 65535));
            }
        }
        let hours = (self.core.model.run_hours().floor() as i64).clamp(0, 65535);
        let _ = self.core.params.force(P4_04_RUN_TIME, 0, hours);
    }

    /// One request (or rejected frame) for this drive; the answer to send, if one is due.
    fn handle(
        &mut self,
        now: Instant,
        incoming: Incoming<'_, Request<'_>>,
        framing: Framing,
    ) -> Option<Answer> {
        self.handled = true;
        match incoming {
            Incoming::Request { request, broadcast } => {
                self.core.model.comm_seen(now);
                self.sync_fault_records();
                let answer = self.request(&request);
                // Broadcast: "从机不应答", the slaves do not answer.
                (!broadcast).then_some(answer)
            }
            Incoming::Rejected { bytes, error } => {
                // The session hands over only frames with a good CRC/LRC addressed to this drive
                // or broadcast (a bad check is dropped silently, "并不作任何回应").
                let (unit, function) = framing.head(bytes)?;
                self.core.model.comm_seen(now);
                if unit == 0 {
                    return None;
                }
                Some(Answer::Exception {
                    unit: UnitId(unit),
                    function,
                    code: rejected_exception(function, &error),
                })
            }
        }
    }

    fn request(&mut self, request: &Request<'_>) -> Answer {
        let unit = request.unit;
        let exception = |code| Answer::Exception { unit, function: request.pdu.function(), code };
        match request.pdu {
            RequestPdu::ReadHoldingRegisters { start, quantity } => match self.read(start.0, quantity) {
                Ok((values, len)) => Answer::Read { unit, values, len },
                Err(code) => exception(code),
            },
            RequestPdu::WriteSingleRegister { address, value } => match self.write(address.0, value) {
                Ok(()) => Answer::Write { unit, address: address.0, value },
                Err(code) => exception(code),
            },
            RequestPdu::Diagnostics { sub_function, data } => {
                // "此命令用来测试主控设备与变频器之间通讯是否正常。变频器将收到的资料原封不动送给
                // 主控设备": any sub-function, the data sent back unchanged.
                Answer::Echo { unit, sub_function, data: data.iter().collect() }
            }
            // "变频器能够辩识功能码: 03H 06H 08H": anything else is error 01.
            _ => exception(ILLEGAL_FUNCTION),
        }
    }

    /// 03: `quantity` registers from `start`.
    fn read(&mut self, start: u16, quantity: u16) -> Result<([u16; 4], usize), ExceptionCode> {
        // "N*8-bit 资料, N<=8, 最大 8 个字节": at most 4 registers in a reply.
        if !(1..=4).contains(&quantity) {
            return Err(ILLEGAL_VALUE);
        }
        let mut values = [0u16; 4];
        for (i, value) in values.iter_mut().take(usize::from(quantity)).enumerate() {
            let address = start.checked_add(i as u16).ok_or(ILLEGAL_ADDRESS)?;
            *value = self.read_register(address).ok_or(ILLEGAL_ADDRESS)?;
        }
        Ok((values, usize::from(quantity)))
    }

    fn read_register(&self, address: u16) -> Option<u16> {
        let m = &self.core.model;
        Some(match address {
            reg::FAULT_CODE => m.trip().map_or(0, Trip::code),
            reg::STATUS => self.status(),
            reg::SET_FREQUENCY => unsigned(m.setpoint_hz() * 100.0),
            // Truncated: 40.00 Hz only once the ramp is there.
            reg::OUTPUT_FREQUENCY => unsigned((m.output_mhz() / 10) as f64),
            reg::OUTPUT_CURRENT => unsigned(m.current_a() * 10.0),
            reg::DC_BUS_VOLTAGE => unsigned(m.dc_bus_v() * 10.0),
            reg::OUTPUT_VOLTAGE => unsigned(m.output_v()),
            reg::MOTOR_SPEED => unsigned(m.motor_rpm()),
            reg::MODULE_TEMPERATURE => signed(m.heatsink_c() * 10.0),
            // 2000H, 2001H, 2109H..210BH and Pgg.nn: the stored value.
            _ => self.core.params.get(u32::from(address))? as u16,
        })
    }

    /// 2101H.
    fn status(&self) -> u16 {
        let m = &self.core.model;
        let mut bits = 0;
        let running = m.is_running();
        let source = self.param(P0_00_FREQ_SOURCE);
        let undervoltage =
            m.trip() == Some(Trip::UnderVoltage) || m.dc_bus_v() < 0.65 * m.settings().nominal_dc_v;
        let flags = [
            (running, status::RUN),
            (undervoltage, status::UNDERVOLTAGE),
            (m.rotation() == Rotation::Reverse, status::REVERSE),
            (m.is_jogging(), status::JOG),
            (running && source == 5, status::MULTI_STEP),
            (running && !m.is_jogging(), status::NORMAL_RUN),
            (source == SOURCE_COMM, status::FREQUENCY_FROM_COMM),
            (source == 2 || source == 3, status::FREQUENCY_FROM_ANALOG),
            (self.param(P0_01_RUN_SOURCE) == RUN_SOURCE_COMM, status::RUN_FROM_COMM),
            (self.param(P0_15_PROTECT) != 0, status::PROTECTED),
        ];
        for (on, bit) in flags {
            if on {
                bits |= bit;
            }
        }
        bits
    }

    /// 06: one register.
    fn write(&mut self, address: u16, value: u16) -> Result<(), ExceptionCode> {
        match address {
            reg::COMMAND => self.command(value),
            reg::FREQUENCY => self.set_frequency(value),
            // The monitors are read with 03 ("监控变频器状态 03H"): not an address for 06.
            reg::FAULT_CODE..=reg::VERSION => Err(ILLEGAL_ADDRESS),
            _ => self.write_parameter(address, value),
        }
    }

    /// 2000H.
    fn command(&mut self, value: u16) -> Result<(), ExceptionCode> {
        if !(1..=10).contains(&value) {
            return Err(ILLEGAL_VALUE);
        }
        const FAULT_RESET: u16 = 0x0A;
        if value != FAULT_RESET && self.param(P0_01_RUN_SOURCE) != RUN_SOURCE_COMM {
            // Run and stop commands come from the keypad or the terminals (P0.01 = 0, 1).
            return Err(ILLEGAL_VALUE);
        }
        let reverse_prohibited = self.param(P0_03_DIRECTION) == 2;
        let coast_to_stop = self.param(P0_13_STOP_MODE) == 1;
        let m = &mut self.core.model;
        let direction = match value {
            2 | 5 => Some(Rotation::Forward),
            3 | 6 => Some(Rotation::Reverse),
            _ => None,
        };
        let starts = matches!(value, 1..=6);
        if starts {
            if m.run_refusal().is_some() {
                return Err(ILLEGAL_VALUE);
            }
            let turns = direction.unwrap_or(m.rotation());
            if turns == Rotation::Reverse && reverse_prohibited {
                return Err(ILLEGAL_VALUE);
            }
            m.set_rotation(turns);
            let started = if matches!(value, 4..=6) { m.jog() } else { m.run() };
            started.map_err(|_| ILLEGAL_VALUE)?;
        }
        match value {
            7 if coast_to_stop => m.coast(),
            7 => m.stop(),
            8 => m.coast(),
            9 if m.is_jogging() => m.stop(),
            FAULT_RESET => m.reset().map_err(|_| ILLEGAL_VALUE)?,
            _ => {}
        }
        let _ = self.core.params.force(u32::from(reg::COMMAND), 0, i64::from(value));
        Ok(())
    }

    /// 2001H: checked against the maximum frequency P0.04.
    fn set_frequency(&mut self, value: u16) -> Result<(), ExceptionCode> {
        if i64::from(value) > self.param(P0_04_MAX_FREQ) {
            return Err(ILLEGAL_VALUE);
        }
        self.core
            .params
            .set(u32::from(reg::FREQUENCY), i64::from(value), Storage::Ram, false)
            .map_err(|e| write_exception(&e))?;
        self.apply_setpoint();
        Ok(())
    }

    /// Pgg.nn at 0xGGNN.
    fn write_parameter(&mut self, address: u16, value: u16) -> Result<(), ExceptionCode> {
        let number = u32::from(address);
        let def = self.core.params.catalog().by_number(number).ok_or(ILLEGAL_ADDRESS)?;
        if def.read_only {
            return Err(ILLEGAL_ADDRESS);
        }
        let raw = if def.min < 0 { i64::from(value as i16) } else { i64::from(value) };
        // P0.15: 1 only P0.02 writable, 2 all locked (P0.15 itself stays writable).
        match self.param(P0_15_PROTECT) {
            1 if number != P0_02_KEYPAD_FREQ && number != P0_15_PROTECT => return Err(ILLEGAL_VALUE),
            2 if number != P0_15_PROTECT => return Err(ILLEGAL_VALUE),
            _ => {}
        }
        // Frequencies above the maximum frequency, and a lower limit above the upper limit.
        let max = self.param(P0_04_MAX_FREQ);
        let too_high = match number {
            P0_02_KEYPAD_FREQ | P0_05_UPPER_LIMIT => raw > max,
            P0_06_LOWER_LIMIT => raw > max || raw > self.param(P0_05_UPPER_LIMIT),
            _ => false,
        };
        if too_high {
            return Err(ILLEGAL_VALUE);
        }
        let running = self.core.model.is_running();
        self.core.params.set(number, raw, Storage::Eeprom, running).map_err(|e| write_exception(&e))?;
        match number {
            P0_14_INIT => self.initialise(raw),
            // The direction a plain run (command 1) takes, while the motor stands.
            P0_03_DIRECTION if !running && raw != 2 => {
                let turns = if raw == 1 { Rotation::Reverse } else { Rotation::Forward };
                self.core.model.set_rotation(turns);
            }
            P3_11_ADDRESS => self.new_address = u8::try_from(raw).ok(),
            P3_13_TIMEOUT | P3_14_TIMEOUT_ACTION => self.apply_comm_timeout(),
            _ => {}
        }
        self.apply_parameters();
        Ok(())
    }

    /// P0.14: 1 restores the starting values (keeping P3.09..P3.14), 2 clears the fault records;
    /// it reads back 0 ("an action").
    fn initialise(&mut self, action: i64) {
        match action {
            1 => {
                let keep = [
                    P3_09_BAUD,
                    P3_10_FORMAT,
                    P3_11_ADDRESS,
                    P3_12_DELAY,
                    P3_13_TIMEOUT,
                    P3_14_TIMEOUT_ACTION,
                ]
                .map(|n| (n, self.param(n)));
                self.core.params.reset_to_defaults();
                self.starting_values();
                for (n, v) in keep {
                    let _ = self.core.params.force(n, 0, v);
                }
                let _ = self.core.params.force(u32::from(reg::VERSION), 0, i64::from(VERSION_BCD));
                self.sync_fault_records();
            }
            2 => {
                for n in [P4_00_LAST_FAULT, P4_01_PREVIOUS_FAULT, P4_02_FAULT_FREQ, P4_03_FAULT_CURRENT] {
                    let _ = self.core.params.force(n, 0, 0);
                }
            }
            _ => {}
        }
        let _ = self.core.params.force(P0_14_INIT, 0, 0);
    }
}

/// The exception for a frame with a good check that the codec could not parse: 01 for every
/// function but 03, 06 and 08 ("变频器能够辩识功能码: 03H 06H 08H"), else what the codec
/// says: 01 for a function it does not know, 03 for the rest (a quantity of 0, a short PDU).
fn rejected_exception(function: u8, error: &FrameError) -> ExceptionCode {
    match function {
        0x03 | 0x06 | 0x08 => ExceptionCode::for_error(error),
        _ => ILLEGAL_FUNCTION,
    }
}
