//! Toshiba VF-AS1 (manual E6581315, `seeds/002_43d8a4399c8be05f.txt`; protocols.md section 1 and
//! the "Toshiba" project decisions).
//!
//! One drive answers the TOSHIBA Inverter Protocol (TIP) in ASCII mode and in binary mode, told
//! apart per frame by the start code (`(` or 2F), or Modbus-RTU, as parameter f829 selects
//! (0 TOSHIBA, 1 Modbus-RTU). As on the real drive, f829 and the inverter number f802 take
//! effect at the next power-up: [`ToshibaDrive::power_cycle`].
//!
//! What the drive does:
//!
//! | number | what | unit |
//! |---|---|---|
//! | FA00 | command 1: 15 command priority, 14 frequency priority, 13 fault reset, 12 emergency stop, 11 coast stop, 10 run, 9 reverse, 8 jog, 6 acc/dec 2 | bits, RAM |
//! | FA01 | frequency command, used while FA00 bit 14 is set | 0.01 Hz, RAM |
//! | FD00 / FE00 | output frequency now / at the last trip | 0.01 Hz |
//! | FD01 / FE01 | operating status 1 now / at the last trip | bits (protocols.md 1.9) |
//! | FE02 | frequency command value | 0.01 Hz |
//! | FE03 / FE04 / FE05 | output current / DC voltage / output voltage | 0.01 % of rated |
//! | FC90 / FE10-FE13 | trip code now / past trips 1-4 | code |
//! | FC91 | alarm information | bits |
//! | FE70 / FE71 | rated current / rated voltage | 0.1 A / 0.1 V |
//! | FA50 | terminal board output data (held; read back) | bits, RAM |
//! | FA51 / FA52 | FM / AM analog output data (held; read back) | 0.1 %, RAM |
//! | FB05 | inverter model (capacity) code, [`MODEL_CODE`] | code |
//! | others | the parameters of `crates/drive/catalogs/toshiba.toml` by communication number | |
//!
//! TIP errors (protocols.md 1.6): 0000 impossible to execute (not while running, a monitor
//! written), 0001 data error (out of range), 0002 no such communication number, 0003 command
//! error (ASCII only), 0004 checksum error; format errors get no reply. Modbus maps them to the
//! exceptions 04, 03, 02 and 01 (protocols.md 1.8).

use std::collections::BTreeMap;
use std::time::Duration;

use drivebus_drive::profile::Fault;
use drivebus_drive::{Family, ParamStore, Storage, WriteError};
use drivebus_proto::modbus::rtu::ModbusRtu;
use drivebus_proto::modbus::{
    DeviceIdReply, DeviceObject, DeviceObjects, ExceptionCode, Registers, Reply, ReplyPdu, Request,
    RequestPdu, UnitId,
};
use drivebus_proto::session::{Incoming, Responder, SlaveSession};
use drivebus_proto::toshiba::binary::{BinaryRequestBody, BlockRequest};
use drivebus_proto::toshiba::{
    block_read_item, block_write_item, Alarm, Cmd, Command1, ErrorCode, Status1, Tip, TipReply, TipRequest,
};
use drivebus_proto::Instant;

use crate::drive::{Device, DriveCore, VirtualDrive};
use crate::model::{ModelSettings, Rotation, Trip};

/// Which protocol the drive speaks (parameter f829), as the Toshiba profile knows it.
pub use drivebus_drive::profile::toshiba::ToshibaProtocol;

/// The model the drive claims to be (Modbus 2B/0E ProductCode): 200 V class, 3.7 kW.
pub const MODEL_NAME: &str = "VFAS1-2037PM";
/// The vendor (Modbus 2B/0E VendorName), as the VF-S15 manual's example shows it.
pub const VENDOR_NAME: &str = "TOSHIBA";
/// FB05, the inverter model (capacity) code (project decision: the seed names FB05 only; the
/// type form's four digits as hex digits, 2037H for [`MODEL_NAME`]).
pub const MODEL_CODE: u16 = 0x2037;
/// The firmware version (Modbus 2B/0E MajorMinorRevision), as the VF-S15 manual's example.
pub const VERSION: &str = "0100";
/// The inverter's rated output current, 0.1 A (FE70): 17.5 A for a 200 V 3.7 kW VF-AS1.
pub const RATED_CURRENT_01A: u16 = 175;
/// The inverter's rated voltage, 0.1 V (FE71): 200 V class.
pub const RATED_VOLTAGE_01V: u16 = 2000;
/// No communication for this long after power-up (protocols.md 1.2: "about 2 s (VF-AS1)").
pub const STARTUP_DEAF: Duration = Duration::from_secs(2);
/// Jog frequency (f260 is not in the catalog; the VF-AS1 default is 5.00 Hz).
pub const JOG_HZ: f64 = 5.0;

/// Trip code (FC90) 0018H = 24, "Err5", communication time-out (the seed's table of contents
/// hints "(RFC90)CR ... H = 24d trip status").
pub const TRIP_ERR5_COMMUNICATION: u16 = 0x18;
/// Trip code 03H, OC3: over-current at constant speed.
pub const TRIP_OC3: u16 = 0x03;
/// Trip code 0CH, OP3: over-voltage at constant speed.
pub const TRIP_OP3: u16 = 0x0C;
/// Trip code 10H, OH: overheat.
pub const TRIP_OH: u16 = 0x10;
/// Trip code 11H, E: emergency stop (FA00 bit 12, or an external trip).
pub const TRIP_E: u16 = 0x11;
/// Trip code 1EH, UP1: main-circuit under-voltage.
pub const TRIP_UP1: u16 = 0x1E;

/// The VF-AS1 trip code (FC90, FE10-FE13) of a model trip. The model does not say whether it
/// was accelerating, so over-current and over-voltage report the constant-speed codes.
pub fn trip_code(trip: Trip) -> u16 {
    match trip {
        Trip::OverCurrent => TRIP_OC3,
        Trip::OverVoltage => TRIP_OP3,
        Trip::UnderVoltage => TRIP_UP1,
        Trip::OverTemperature => TRIP_OH,
        Trip::CommunicationTimeout => TRIP_ERR5_COMMUNICATION,
        Trip::External => TRIP_E,
    }
}

// Communication numbers the drive acts on.
const ACC: u32 = 0x0009;
const DEC: u32 = 0x0010;
const FH: u32 = 0x0011;
const UL: u32 = 0x0012;
const LL: u32 = 0x0013;
const VL: u32 = 0x0014;
const CMOD: u32 = 0x0003;
const VLV: u32 = 0x0409;
const THR1: u32 = 0x0600;
const REVERSE_PROHIBITION: u32 = 0x0311;
const RATED_MOTOR_CURRENT: u32 = 0x0415;
const RATED_MOTOR_RPM: u32 = 0x0417;
const ACC2: u32 = 0x0500;
const DEC2: u32 = 0x0501;
const STALL_LEVEL: u32 = 0x0601;
const INVERTER_NUMBER: u32 = 0x0802;
const TIMEOUT_TIME: u32 = 0x0803;
const TIMEOUT_ACTION: u32 = 0x0804;
const PROTOCOL: u32 = 0x0829;
const BLOCK_WRITE_1: u32 = 0x0870;
const BLOCK_READ_1: u32 = 0x0875;
const FA00: u32 = 0xFA00;
const FA01: u32 = 0xFA01;
const INTER_DRIVE: u32 = 0x0806;
const POINT_SELECTION: u32 = 0x0810;
const POINT_1_PERCENT: u32 = 0x0811;
const POINT_1_FREQ: u32 = 0x0812;
const POINT_2_PERCENT: u32 = 0x0813;
const POINT_2_FREQ: u32 = 0x0814;

/// A virtual Toshiba VF-AS1.
pub struct ToshibaDrive {
    tip: SlaveSession<Tip>,
    rtu: SlaveSession<ModbusRtu>,
    inner: Inner,
}

impl std::fmt::Debug for ToshibaDrive {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ToshibaDrive")
            .field("address", &self.inner.core.address)
            .field("protocol", &self.inner.protocol)
            .field("state", &self.inner.core.model.state())
            .field("output_hz", &self.inner.core.model.output_hz())
            .finish_non_exhaustive()
    }
}

/// Everything but the sessions, so a session's handler can borrow it.
struct Inner {
    core: DriveCore,
    /// The protocol in force (f829 as it was at the last power-up).
    protocol: ToshibaProtocol,
    /// The operation panel frequency, 0.01 Hz (used while FA00 bit 14 is clear).
    panel_centihz: u16,
    /// EEPROM values of parameters whose RAM value a `P` changed: restored at power-up.
    eeprom_shadow: BTreeMap<u32, i64>,
    /// The last valid telegram for this drive.
    last_comm: Instant,
    /// f803 elapsed with f804 = 0 (alarm only); cleared by a fault reset or power-up.
    comm_alarm: bool,
    /// f803 has elapsed since `last_comm` and its action was taken.
    timeout_fired: bool,
    /// f804 = 2: decelerating to a stop, then tripping Err5.
    decel_trip: bool,
    /// FA00 bit 15 was set by the last command: communication has command authority.
    comm_priority: bool,
    /// A coast stop was commanded and no run since.
    coast_stopped: bool,
    /// No communication until then (start-up after a power cycle).
    deaf_until: Option<Instant>,
    /// A master drive's broadcast block write was heard since power-up (f806 = 0..2): the
    /// communication time-out then means the master failed, and f806 says what to do.
    following: bool,
}

impl ToshibaDrive {
    /// A stopped VF-AS1 numbered `address` speaking `protocol` (f829 and f802 are set to match),
    /// at simulated time `now`. TIP numbers are 0..=99 (binary mode reaches 0..=63), Modbus
    /// numbers 1..=247.
    pub fn new(address: u8, protocol: ToshibaProtocol, now: Instant) -> Result<Self, String> {
        match protocol {
            ToshibaProtocol::Tip if address > 99 => {
                return Err(format!(
                    "a VF-AS1 speaking the TOSHIBA protocol has inverter number 0..99, not {address}"
                ))
            }
            ToshibaProtocol::ModbusRtu if address == 0 || address > 247 => {
                return Err(format!(
                    "a VF-AS1 speaking Modbus-RTU has inverter number 1..247 (0 is broadcast), not {address}"
                ))
            }
            _ => {}
        }
        let mut params = ParamStore::for_family(Family::Toshiba).map_err(|e| e.to_string())?;
        params.force(PROTOCOL, 0, protocol.f829()).map_err(|e| e.to_string())?;
        params.force(INVERTER_NUMBER, 0, i64::from(address)).map_err(|e| e.to_string())?;
        let settings = settings_from(&params);
        let core = DriveCore::new(params, settings, address, now);
        let delay = core.response_delay;
        let mut inner = Inner {
            core,
            protocol,
            panel_centihz: 0,
            eeprom_shadow: BTreeMap::new(),
            last_comm: now,
            comm_alarm: false,
            timeout_fired: false,
            decel_trip: false,
            comm_priority: false,
            coast_stopped: false,
            deaf_until: None,
            following: false,
        };
        inner.apply_comm_timeout();
        inner.apply_frequency();
        Ok(ToshibaDrive {
            tip: SlaveSession::new(Tip::default(), address, delay),
            rtu: SlaveSession::new(ModbusRtu, address, delay),
            inner,
        })
    }

    /// The protocol in force (f829 as it was at the last power-up).
    pub fn protocol_in_force(&self) -> ToshibaProtocol {
        self.inner.protocol
    }

    /// Switches the drive off and on at `now`: the motor coasts, a trip whose cause is gone
    /// clears, RAM values (FA00, FA01, values written with `P`) return to their EEPROM values,
    /// f829 (protocol) and f802 (inverter number) take effect, and the drive does not
    /// communicate for [`STARTUP_DEAF`] (protocols.md 1.2).
    pub fn power_cycle(&mut self, now: Instant) {
        let inner = &mut self.inner;
        inner.advance(now);
        inner.power_up(now);
        let delay = inner.core.response_delay;
        let address = inner.core.address;
        self.tip = SlaveSession::new(Tip::default(), address, delay);
        self.rtu = SlaveSession::new(ModbusRtu, address, delay);
    }

    /// The operation panel frequency, Hz (the frequency while FA00 bit 14 is clear).
    pub fn panel_frequency_hz(&self) -> f64 {
        f64::from(self.inner.panel_centihz) / 100.0
    }

    /// Sets the operation panel frequency, Hz (0.00..=500.00, rounded to 0.01 Hz).
    pub fn set_panel_frequency_hz(&mut self, hz: f64) {
        let centi = (hz * 100.0).round().clamp(0.0, 50000.0);
        self.inner.panel_centihz = centi as u16;
        self.inner.apply_frequency();
    }

    /// True when f803 elapsed without a valid telegram and f804 = 0 (alarm only): FD01 bit 2.
    pub fn comm_alarm(&self) -> bool {
        self.inner.comm_alarm
    }

    /// The trip code FC90 shows now (0 when not tripped).
    pub fn trip_code(&self) -> u16 {
        self.inner.core.model.trip().map_or(0, trip_code)
    }

    /// Keeps the sessions' number and reply delay in step with the core (the control
    /// interface may change them).
    fn sync_sessions(&mut self) {
        let core = &self.inner.core;
        self.tip.set_address(core.address);
        self.tip.set_response_delay(core.response_delay);
        self.rtu.set_address(core.address);
        self.rtu.set_response_delay(core.response_delay);
    }

    fn deaf(&self, now: Instant) -> bool {
        self.inner.deaf_until.is_some_and(|t| now < t)
    }
}

impl Device for ToshibaDrive {
    fn receive(&mut self, now: Instant, bytes: &[u8]) {
        self.inner.advance(now);
        if self.deaf(now) {
            return;
        }
        self.sync_sessions();
        let ToshibaDrive { tip, rtu, inner } = self;
        match inner.protocol {
            ToshibaProtocol::Tip => {
                tip.handle_input(now, bytes, &mut |t, inc, resp| inner.on_tip(t, inc, resp))
            }
            ToshibaProtocol::ModbusRtu => {
                rtu.handle_input(now, bytes, &mut |t, inc, resp| inner.on_rtu(t, inc, resp))
            }
        }
    }

    fn silence(&mut self, now: Instant) {
        // seed 002: "MODBUS-RTU decides the data that is first received subsequently as the
        // first byte of a frame after a blank time for 3.5 bytes". TIP frames delimit themselves.
        if self.inner.protocol != ToshibaProtocol::ModbusRtu || self.deaf(now) {
            return;
        }
        self.inner.advance(now);
        self.sync_sessions();
        let ToshibaDrive { rtu, inner, .. } = self;
        rtu.handle_silence(now, &mut |t, inc, resp| inner.on_rtu(t, inc, resp));
    }

    fn poll_transmit(&mut self, now: Instant) -> Option<Vec<u8>> {
        match self.inner.protocol {
            ToshibaProtocol::Tip => self.tip.poll_transmit(now).map(<[u8]>::to_vec),
            ToshibaProtocol::ModbusRtu => self.rtu.poll_transmit(now).map(<[u8]>::to_vec),
        }
    }

    fn poll_timeout(&self) -> Option<Instant> {
        match self.inner.protocol {
            ToshibaProtocol::Tip => self.tip.poll_timeout(),
            ToshibaProtocol::ModbusRtu => self.rtu.poll_timeout(),
        }
    }

    fn advance_to(&mut self, now: Instant) {
        self.inner.advance(now);
    }

    crate::drive::device_is_a_drive!();
}

impl VirtualDrive for ToshibaDrive {
    fn power_cycle(&mut self, now: Instant) {
        ToshibaDrive::power_cycle(self, now);
    }

    fn protocol(&self) -> String {
        self.inner.protocol.name()
    }

    /// The VF-AS1's own trip code (FC90) and its panel name.
    fn panel_fault(&self, trip: Trip) -> Fault {
        let code = trip_code(trip);
        Fault { code: u32::from(code), text: drivebus_drive::profile::toshiba::trip_text(code) }
    }

    crate::drive::drive_core_at!(inner.core);

    fn control_source(&self) -> String {
        let inner = &self.inner;
        let params = &inner.core.params;
        let fa00 = Command1(params.get(FA00).unwrap_or(0) as u16);
        let freq = if fa00.contains(Command1::FREQUENCY_PRIORITY) {
            "frequency from FA01 (FA00 bit 14)".to_string()
        } else {
            format!("frequency from the panel ({:.2} Hz)", f64::from(inner.panel_centihz) / 100.0)
        };
        if inner.comm_priority {
            format!("communication (FA00 bit 15 command priority), {freq}")
        } else {
            let cmod = params.get(CMOD).unwrap_or(0);
            let text = params.catalog().by_number(CMOD).and_then(|d| d.choice(cmod)).unwrap_or("?");
            format!("CMOd (0003) = {cmod} {text}, {freq}")
        }
    }

    fn set_param(&mut self, name: &str, value: &str) -> Result<(), String> {
        crate::drive::set_param_as_keypad(&mut self.inner.core, name, value)?;
        let inner = &mut self.inner;
        let settings = settings_from(&inner.core.params);
        if settings != *inner.core.model.settings() {
            inner.core.model.set_settings(settings);
        }
        inner.apply_comm_timeout();
        inner.apply_frequency();
        Ok(())
    }

    /// The operation panel frequency.
    fn set_keypad_hz(&mut self, hz: f64) -> Result<(), String> {
        if !(0.0..=500.0).contains(&hz) {
            return Err(format!("panel frequency {hz} Hz is outside 0..500 Hz"));
        }
        self.set_panel_frequency_hz(hz);
        Ok(())
    }
}

impl Inner {
    fn tripped(&self) -> bool {
        self.core.model.trip().is_some()
    }

    /// Lets the model reach `now`, taking the f803/f804 action at the very instant the
    /// communication time-out elapses (protocols.md 1.2: "if nothing valid is received within
    /// f803, the inverter takes the action set by f804").
    fn advance(&mut self, now: Instant) {
        if let Some(deadline) = self.timeout_deadline().filter(|&d| d <= now) {
            // f804 = 1: the model trips by itself at the deadline (model.set_comm_timeout).
            self.core.model.advance_to(deadline);
            self.timeout_fired = true;
            match self.param(TIMEOUT_ACTION) {
                _ if self.following => self.master_lost(),
                // "alarm only": FD01 bit 2, the motor runs on.
                0 => self.comm_alarm = true,
                // "trip (deceleration stop)": ramp down, then trip.
                2 if self.core.model.trip().is_none() => {
                    self.core.model.stop();
                    self.decel_trip = true;
                }
                _ => {}
            }
        }
        self.core.model.advance_to(now);
        if self.decel_trip && !self.core.model.is_running() {
            self.decel_trip = false;
            self.core.model.trip_now(Trip::CommunicationTimeout);
        }
    }

    /// When f803 runs out, unless it is off, has run out already or the drive is tripped.
    fn timeout_deadline(&self) -> Option<Instant> {
        let secs = self.param(TIMEOUT_TIME);
        if secs <= 0 || self.timeout_fired || self.tripped() {
            return None;
        }
        Some(self.last_comm + Duration::from_secs(secs as u64))
    }

    fn comm_seen(&mut self, now: Instant) {
        self.core.model.comm_seen(now);
        self.last_comm = now;
        self.timeout_fired = false;
    }

    /// The time-out starts again from the model's present (after a reset or a setting change).
    fn restart_timeout(&mut self) {
        self.last_comm = self.core.model.now();
        self.timeout_fired = false;
        self.comm_alarm = false;
        self.decel_trip = false;
    }

    fn param(&self, number: u32) -> i64 {
        self.core.params.get(number).unwrap_or(0)
    }

    fn power_up(&mut self, now: Instant) {
        let model = &mut self.core.model;
        model.coast();
        let _ = model.reset();
        // What only RAM held is gone: P-written values fall back to the EEPROM, RAM-only
        // parameters (FA00, FA01, f400) to their defaults.
        for (number, value) in std::mem::take(&mut self.eeprom_shadow) {
            let _ = self.core.params.force(number, 0, value);
        }
        let ram: Vec<(u32, i64)> = self
            .core
            .params
            .iter()
            .filter(|(d, _)| d.storage == Storage::Ram && !d.read_only)
            .map(|(d, _)| (d.number, d.default))
            .collect();
        for (number, value) in ram {
            let _ = self.core.params.force(number, 0, value);
        }
        self.protocol = ToshibaProtocol::from_f829(self.param(PROTOCOL));
        self.core.address = u8::try_from(self.param(INVERTER_NUMBER)).unwrap_or(0);
        self.comm_priority = false;
        self.coast_stopped = false;
        self.following = false;
        self.deaf_until = Some(now + STARTUP_DEAF);
        let settings = settings_from(&self.core.params);
        self.core.model.set_settings(settings);
        self.apply_comm_timeout();
        self.apply_frequency();
    }

    // ---------------------------------------------------------------------------------------
    // TIP
    // ---------------------------------------------------------------------------------------

    fn on_tip(&mut self, now: Instant, inc: Incoming<'_, TipRequest>, resp: &mut Responder<'_, Tip>) {
        let me = self.core.address;
        match inc {
            Incoming::Request { request, broadcast } => {
                self.comm_seen(now);
                let reply = match request {
                    TipRequest::Binary(b) => match b.body {
                        BinaryRequestBody::Block(block) => {
                            if broadcast && block.n_w > 0 {
                                self.heard_master();
                            }
                            let rdata = self.block(block);
                            b.block_reply(me, self.tripped(), &rdata).map(TipReply::Binary)
                        }
                        body => {
                            let comm_no = body.comm_no().map_or(0, |c| c.0);
                            let data = match body {
                                BinaryRequestBody::Write { data, .. }
                                | BinaryRequestBody::WriteRam { data, .. } => data,
                                _ => 0,
                            };
                            self.execute(&request, comm_no, data)
                        }
                    },
                    TipRequest::Ascii(a) => self.execute(&request, a.comm_no.0, a.value().unwrap_or(0)),
                };
                if let Some(r) = reply {
                    let _ = resp.reply(&r);
                }
            }
            Incoming::Rejected { bytes, .. } => {
                // protocols.md 1.6: checksum (0004), command (0003, ASCII only), communication
                // number and data errors are answered; format errors are not.
                if let Some(r) = Tip::rejection_reply(bytes, me, self.tripped()) {
                    let _ = resp.reply(&r);
                }
            }
        }
    }

    /// `R`, `G`, `W` or `P` on `comm_no`; the reply (data, or an error code). Lower case when
    /// tripped after the command (a fault reset answers in upper case).
    fn execute(&mut self, request: &TipRequest, comm_no: u16, data: u16) -> Option<TipReply> {
        let me = self.core.address;
        let result = match request.cmd() {
            Some(Cmd::R | Cmd::G) => self.read(comm_no),
            // manual VF-AS1 p.17: W writes RAM and EEPROM (FAxx RAM only), P writes RAM only;
            // both return the data received.
            Some(Cmd::W) => self.write(comm_no, data, Storage::Eeprom).map(|()| data),
            Some(Cmd::P) => self.write(comm_no, data, Storage::Ram).map(|()| data),
            None => return None,
        };
        let tripped = self.tripped();
        match result {
            Ok(v) => request.reply(me, tripped, v),
            Err(code) => Some(request.error_reply(me, tripped, code)),
        }
    }

    /// Block communication (protocols.md 1.7): WDATA1/2 go to the numbers f870/f871 select,
    /// the read items are the ones f875-f879 select.
    fn block(&mut self, block: BlockRequest) -> [u16; 5] {
        for (i, &w) in block.wdata().iter().enumerate() {
            let selection = u16::try_from(self.param(BLOCK_WRITE_1 + i as u32)).unwrap_or(0);
            let target = block_write_item(selection).map(|c| c.0);
            // A write the drive refuses (out of range, FA20 not simulated) is
            // skipped; the reply still carries the read items.
            if let Some(n) = target {
                let _ = self.write(n, w, Storage::Ram);
            }
        }
        let mut rdata = [0u16; 5];
        for (i, slot) in rdata.iter_mut().enumerate() {
            let selection = u16::try_from(self.param(BLOCK_READ_1 + i as u32)).unwrap_or(0);
            let item = block_read_item(selection).map(|c| c.0);
            *slot = item.and_then(|n| self.read(n).ok()).unwrap_or(0);
        }
        rdata
    }

    // ---------------------------------------------------------------------------------------
    // Modbus-RTU
    // ---------------------------------------------------------------------------------------

    fn on_rtu(&mut self, now: Instant, inc: Incoming<'_, Request<'_>>, resp: &mut Responder<'_, ModbusRtu>) {
        let unit = UnitId(self.core.address);
        match inc {
            Incoming::Request { request, .. } => {
                self.comm_seen(now);
                let function = request.pdu.function();
                let exception = |code| Reply::exception(unit, function, code);
                match request.pdu {
                    // seed 002: "Set the number of data words 0001 (fixed)"; its example with
                    // 0002 is answered "01 83 03 01 31".
                    RequestPdu::ReadHoldingRegisters { quantity, .. } if quantity != 1 => {
                        answer(resp, &exception(ExceptionCode::ILLEGAL_DATA_VALUE));
                    }
                    RequestPdu::ReadHoldingRegisters { start, .. } => match self.read(start.0) {
                        Ok(v) => {
                            let values = [v];
                            let pdu =
                                ReplyPdu::ReadHoldingRegisters { values: Registers::from_values(&values) };
                            answer(resp, &Reply { unit, pdu });
                        }
                        Err(code) => {
                            answer(resp, &exception(modbus_exception(code)));
                        }
                    },
                    // manual VF-S15 p.31: 06 writes RAM and EEPROM (FAxx RAM only); the reply
                    // echoes the request.
                    RequestPdu::WriteSingleRegister { address, value } => {
                        match self.write(address.0, value, Storage::Eeprom) {
                            Ok(()) => {
                                let pdu = ReplyPdu::WriteSingleRegister { address, value };
                                answer(resp, &Reply { unit, pdu });
                            }
                            Err(code) => {
                                answer(resp, &exception(modbus_exception(code)));
                            }
                        }
                    }
                    RequestPdu::ReadDeviceIdentification { code, object_id } => {
                        let objects = [
                            DeviceObject::new(0, VENDOR_NAME.as_bytes()),
                            DeviceObject::new(1, MODEL_NAME.as_bytes()),
                            DeviceObject::new(2, VERSION.as_bytes()),
                        ];
                        match code.0 {
                            // Stream access; an object id the drive does not have restarts at
                            // 00 (Modbus Application Protocol, 2B/0E).
                            1..=3 => {
                                let first = if object_id <= 2 { usize::from(object_id) } else { 0 };
                                let pdu = ReplyPdu::ReadDeviceIdentification(DeviceIdReply {
                                    code,
                                    // manual VF-S15 p.38: conformity level 01 (basic, stream only).
                                    conformity_level: 0x01,
                                    more_follows: false,
                                    next_object_id: 0,
                                    objects: DeviceObjects::from_list(&objects[first..]),
                                });
                                answer(resp, &Reply { unit, pdu });
                            }
                            // 04 (one specific object) needs individual access, which conformity
                            // level 01 does not offer.
                            _ => {
                                answer(resp, &exception(ExceptionCode::ILLEGAL_DATA_VALUE));
                            }
                        }
                    }
                    // VF-AS1 knows 03 and 06 (and 2B/0E): anything else is an illegal function.
                    _ => {
                        answer(resp, &exception(ExceptionCode::ILLEGAL_FUNCTION));
                    }
                }
            }
            Incoming::Rejected { bytes, error } => {
                // A frame with a good CRC that does not parse (a count of 0, an unknown
                // function): the session only hands over those addressed to this drive.
                self.comm_seen(now);
                let function = bytes.get(1).copied().unwrap_or(0);
                answer(resp, &Reply::exception(unit, function, ExceptionCode::for_error(&error)));
            }
        }
    }

    // ---------------------------------------------------------------------------------------
    // Reads and writes by communication number
    // ---------------------------------------------------------------------------------------

    fn read(&mut self, comm_no: u16) -> Result<u16, ErrorCode> {
        if let Some(v) = self.monitor(comm_no) {
            return Ok(v);
        }
        match self.core.params.get(u32::from(comm_no)) {
            Some(v) => Ok((v & 0xFFFF) as u16),
            None => Err(ErrorCode::COMM_NO_ERROR),
        }
    }

    fn write(&mut self, comm_no: u16, value: u16, storage: Storage) -> Result<(), ErrorCode> {
        let number = u32::from(comm_no);
        if self.monitor(comm_no).is_some() {
            // A monitor exists but cannot be written: "the command cannot be executed".
            return Err(ErrorCode::IMPOSSIBLE_TO_EXECUTE);
        }
        let raw = i64::from(value);
        // Catalog notes: the drive keeps LL <= UL <= FH.
        match number {
            UL if raw > self.param(FH) => return Err(ErrorCode::DATA_ERROR),
            LL if raw > self.param(UL) => return Err(ErrorCode::DATA_ERROR),
            _ => {}
        }
        let running = self.core.model.is_running();
        let before = self.core.params.get(number);
        let eeprom_param =
            self.core.params.catalog().by_number(number).is_some_and(|d| d.storage == Storage::Eeprom);
        self.core.params.set(number, raw, storage, running).map_err(|e| match e {
            WriteError::UnknownParameter { .. } | WriteError::NoSuchElement { .. } => {
                ErrorCode::COMM_NO_ERROR
            }
            WriteError::OutOfRange(_) => ErrorCode::DATA_ERROR,
            WriteError::ReadOnly { .. } | WriteError::NotWhileRunning { .. } => {
                ErrorCode::IMPOSSIBLE_TO_EXECUTE
            }
        })?;
        if eeprom_param {
            match storage {
                Storage::Ram => {
                    if let Some(old) = before {
                        self.eeprom_shadow.entry(number).or_insert(old);
                    }
                }
                Storage::Eeprom => {
                    self.eeprom_shadow.remove(&number);
                }
            }
        }
        match number {
            FA00 => self.command(Command1(value)),
            TIMEOUT_TIME | TIMEOUT_ACTION => self.apply_comm_timeout(),
            _ => {}
        }
        let settings = settings_from(&self.core.params);
        if settings != *self.core.model.settings() {
            self.core.model.set_settings(settings);
        }
        self.apply_frequency();
        Ok(())
    }

    /// FA00 written (protocols.md 1.9): commands act only with bit 15 (command priority).
    fn command(&mut self, c: Command1) {
        let model = &mut self.core.model;
        if !c.contains(Command1::COMMAND_PRIORITY) {
            if self.comm_priority {
                // Command authority goes back to CMOd (terminal board or panel), which gives
                // no run signal in the simulator: the motor ramps to a stop.
                model.stop();
            }
            self.comm_priority = false;
            return;
        }
        self.comm_priority = true;
        if c.contains(Command1::FAULT_RESET) {
            if model.trip().is_some() && model.reset().is_ok() {
                self.restart_timeout();
            } else {
                // Not tripped: the reset clears an alarm-only time-out.
                self.comm_alarm = false;
            }
        }
        let model = &mut self.core.model;
        if c.contains(Command1::EMERGENCY_STOP) {
            model.trip_now(Trip::External);
            return;
        }
        if c.contains(Command1::COAST_STOP) {
            model.coast();
            self.coast_stopped = true;
            return;
        }
        if !c.contains(Command1::RUN) {
            model.stop();
            return;
        }
        let reverse = c.contains(Command1::REVERSE);
        // f311: 1 reverse run prohibited, 2 forward run prohibited: that run command is ignored.
        let prohibited = match self.core.params.get(REVERSE_PROHIBITION).unwrap_or(0) {
            1 => reverse,
            2 => !reverse,
            _ => false,
        };
        if prohibited {
            model.stop();
            return;
        }
        model.set_rotation(if reverse { Rotation::Reverse } else { Rotation::Forward });
        let started = if c.contains(Command1::JOG) { model.jog() } else { model.run() };
        if started.is_ok() {
            self.coast_stopped = false;
        }
    }

    /// The setpoint: FA01 while FA00 bit 14 is set, else the panel frequency; within UL and FH.
    fn apply_frequency(&mut self) {
        let params = &self.core.params;
        let fa00 = Command1(params.get(FA00).unwrap_or(0) as u16);
        let centi = if fa00.contains(Command1::FREQUENCY_PRIORITY) {
            self.communication_frequency(params.get(FA01).unwrap_or(0))
        } else {
            i64::from(self.panel_centihz)
        };
        let limit = params.get(UL).unwrap_or(6000).min(params.get(FH).unwrap_or(8000));
        self.core.model.set_setpoint_hz(centi.clamp(0, limit.max(0)) as f64 / 100.0);
    }

    /// f803 (seconds, 0 = off) and f804 (0 alarm only, 1 trip, 2 trip after a deceleration
    /// stop). The model's own time-out trips for 1; 0 and 2 are handled in [`Inner::advance`].
    fn apply_comm_timeout(&mut self) {
        let secs = self.param(TIMEOUT_TIME);
        let timeout = (secs > 0 && self.param(TIMEOUT_ACTION) == 1 && !self.following)
            .then(|| Duration::from_secs(secs as u64));
        self.core.model.set_comm_timeout(timeout);
        self.restart_timeout();
    }

    // ---------------------------------------------------------------------------------------
    // Inter-drive communication, follower side (docs/simulator.md, "Decisions")
    // ---------------------------------------------------------------------------------------

    /// A broadcast block write came (a master drive's cycle): a slave (f806 = 0..2) follows
    /// from now on, and its communication time-out (f803) means the master failed.
    fn heard_master(&mut self) {
        if !self.following && self.param(INTER_DRIVE) <= 2 {
            self.following = true;
            self.apply_comm_timeout();
        }
    }

    /// f803 elapsed without the master's frames: f806 = 0 the frequency command drops to
    /// 0 Hz (the motor ramps down and stays in run), 1 operation goes on, 2 emergency stop
    /// trip (E).
    fn master_lost(&mut self) {
        match self.param(INTER_DRIVE) {
            0 => {
                let _ = self.core.params.force(FA01, 0, 0);
                self.apply_frequency();
            }
            2 => self.core.model.trip_now(Trip::External),
            _ => {}
        }
    }

    /// The frequency, 0.01 Hz, a communication frequency command `value` asks for: `value`
    /// itself, or with f810 = 1/2 (communication command points) a percentage (0.01 %) mapped
    /// through point 1 (f811 %, f812 Hz) and point 2 (f813 %, f814 Hz): the proportional
    /// control of speed of inter-drive communication.
    fn communication_frequency(&self, value: i64) -> i64 {
        if self.param(POINT_SELECTION) == 0 {
            return value;
        }
        let (p1, f1) = (self.param(POINT_1_PERCENT) * 100, self.param(POINT_1_FREQ));
        let (p2, f2) = (self.param(POINT_2_PERCENT) * 100, self.param(POINT_2_FREQ));
        if p1 == p2 {
            return f1;
        }
        (f1 + (value - p1) * (f2 - f1) / (p2 - p1)).max(0)
    }

    // ---------------------------------------------------------------------------------------
    // Monitors
    // ---------------------------------------------------------------------------------------

    /// The value of a monitor the drive measures, or `None` when `comm_no` is not one.
    fn monitor(&self, comm_no: u16) -> Option<u16> {
        let m = &self.core.model;
        let last_trip = m.recent_trips().next();
        Some(match comm_no {
            // seed 002: FD00 = 1770H during 60 Hz operation (0.01 Hz).
            0xFD00 => centihz(m.output_mhz()),
            0xFD01 => self.status1(),
            0xFE00 => last_trip.map_or(0, |r| centihz(r.output_mhz)),
            0xFE01 => last_trip.map_or(0, |r| {
                let mut s = Status1::TRIPPED | Status1::FAILURE_FL;
                if r.output_mhz > 0 {
                    s |= Status1::RUNNING;
                }
                if r.trip == Trip::External {
                    s |= Status1::EMERGENCY_STOPPED;
                }
                s
            }),
            0xFE02 => centihz((m.setpoint_hz() * 1000.0).round() as i64),
            // FE03: 0.01 % of the rated current (seed: "(RFE03077B)" = 19.15 %).
            0xFE03 => percent_001(m.current_a(), f64::from(RATED_CURRENT_01A) / 10.0),
            0xFE04 => percent_001(m.dc_bus_v(), m.settings().nominal_dc_v),
            0xFE05 => {
                let s = m.settings();
                let ratio = (m.output_hz() / s.base_hz.max(1.0)).min(1.0);
                let vlv = self.param(VLV) as f64 / 10.0;
                percent_001(ratio * vlv, f64::from(RATED_VOLTAGE_01V) / 10.0)
            }
            0xFE10..=0xFE13 => {
                let back = usize::from(comm_no - 0xFE10);
                m.recent_trips().nth(back).map_or(0, |r| trip_code(r.trip))
            }
            0xFC90 => m.trip().map_or(0, trip_code),
            0xFC91 => self.alarm(),
            0xFE70 => RATED_CURRENT_01A,
            0xFB05 => MODEL_CODE,
            0xFE71 => RATED_VOLTAGE_01V,
            // Terminal boards, PID feedback and analog inputs: nothing is wired.
            0xFD06 | 0xFD07 | 0xFE06 | 0xFE07 | 0xFD22 | 0xFE35 | 0xFE36 | 0xFE37 => 0,
            _ => return None,
        })
    }

    /// FD01, bits as protocols.md 1.9.
    fn status1(&self) -> u16 {
        let m = &self.core.model;
        let mut s = 0u16;
        match m.trip() {
            Some(t) => {
                s |= Status1::TRIPPED | Status1::FAILURE_FL;
                if t == Trip::External {
                    s |= Status1::EMERGENCY_STOPPED;
                }
            }
            None => {
                s |= Status1::STANDBY;
                if m.hardware_enable() {
                    s |= Status1::STANDBY_ST_ON;
                }
            }
        }
        if m.is_running() {
            s |= Status1::RUNNING;
        }
        if m.rotation() == Rotation::Reverse {
            s |= Status1::REVERSE;
        }
        if m.is_jogging() {
            s |= Status1::JOG;
        }
        if self.coast_stopped && !m.is_running() {
            s |= Status1::COAST_STOPPED;
        }
        if acc_dec_2(&self.core.params) {
            s |= Status1::ACC_PATTERN_2;
        }
        if self.alarm() != 0 || self.comm_alarm {
            s |= Status1::ALARM;
        }
        s
    }

    /// FC91, bits as protocols.md 1.9.
    fn alarm(&self) -> u16 {
        let m = &self.core.model;
        let s = m.settings();
        let i = m.current_a();
        let mut a = 0u16;
        let stall = self.param(STALL_LEVEL) as f64 / 100.0;
        if i > s.rated_current_a * stall {
            a |= Alarm::OVER_CURRENT;
        }
        if i > f64::from(RATED_CURRENT_01A) / 10.0 {
            a |= Alarm::INVERTER_OVERLOAD;
        }
        if i > s.rated_current_a * self.param(THR1) as f64 / 100.0 {
            a |= Alarm::MOTOR_OVERLOAD;
        }
        if m.heatsink_c() > s.overtemp_c - 10.0 {
            a |= Alarm::OVERHEAT;
        }
        let dc = m.dc_bus_v();
        if dc > s.nominal_dc_v * 1.15 {
            a |= Alarm::OVER_VOLTAGE;
        }
        if dc < s.nominal_dc_v * 0.75 {
            a |= Alarm::MAIN_UNDER_VOLTAGE;
        }
        a
    }
}

/// Queues a Modbus reply, unless the drive's number is 0: with f802 = 0 a Modbus drive hears
/// only broadcasts, which get no reply (seed 002: "Data will not be returned if "0"").
fn answer(resp: &mut Responder<'_, ModbusRtu>, reply: &Reply<'_>) {
    if reply.unit.0 != 0 {
        let _ = resp.reply(reply);
    }
}

/// TIP error code to Modbus exception (protocols.md 1.8): 0000 -> 04, 0001 -> 03, 0002 -> 02,
/// 0003 -> 01.
fn modbus_exception(code: ErrorCode) -> ExceptionCode {
    match code {
        ErrorCode::IMPOSSIBLE_TO_EXECUTE => ExceptionCode::SERVER_DEVICE_FAILURE,
        ErrorCode::COMM_NO_ERROR => ExceptionCode::ILLEGAL_DATA_ADDRESS,
        ErrorCode::COMMAND_ERROR => ExceptionCode::ILLEGAL_FUNCTION,
        _ => ExceptionCode::ILLEGAL_DATA_VALUE,
    }
}

/// FA00 selects acceleration/deceleration 2 (bit 6, with command priority).
fn acc_dec_2(params: &ParamStore) -> bool {
    let fa00 = Command1(params.get(FA00).unwrap_or(0) as u16);
    fa00.contains(Command1::COMMAND_PRIORITY | Command1::ACC_DEC_PATTERN_2)
}

/// The model's settings from the parameters: ACC/DEC (0009/0010, or f500/f501 with FA00
/// bit 6) are the times from 0 Hz to FH (0011); LL (0013); base frequency vL (0014); motor
/// rated current and speed (f415, f417). A 200 V class drive: DC bus 270 V.
fn settings_from(params: &ParamStore) -> ModelSettings {
    let get = |n: u32, default: i64| params.get(n).unwrap_or(default);
    let tenths = |t: i64| Duration::from_millis(t.max(1) as u64 * 100);
    let (acc, dec) = if acc_dec_2(params) { (ACC2, DEC2) } else { (ACC, DEC) };
    ModelSettings {
        accel: tenths(get(acc, 100)),
        decel: tenths(get(dec, 100)),
        min_hz: get(LL, 0) as f64 / 100.0,
        max_hz: get(FH, 8000) as f64 / 100.0,
        jog_hz: JOG_HZ,
        rated_current_a: get(RATED_MOTOR_CURRENT, 150) as f64 / 10.0,
        rated_rpm: get(RATED_MOTOR_RPM, 1710) as f64,
        base_hz: get(VL, 6000) as f64 / 100.0,
        nominal_dc_v: 270.0,
        ..ModelSettings::default()
    }
}

/// Millihertz to 0.01 Hz, rounded.
fn centihz(mhz: i64) -> u16 {
    ((mhz.max(0) + 5) / 10).min(0xFFFF) as u16
}

/// `value` as 0.01 % of `rated`, rounded.
fn percent_001(value: f64, rated: f64) -> u16 {
    if rated <= 0.0 {
        return 0;
    }
    (value / rated * 10000.0).round().clamp(0.0, 65535.0) as u16
}
