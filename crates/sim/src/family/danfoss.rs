//! A virtual Danfoss VLT FC-series drive on the FC protocol (`danfoss-fc`).
//!
//! Manual: `seeds/003_26a4c04ca1af5f26.txt` (FC 280 Design Guide MG07B102, 5.4.4–5.4.7),
//! with protocols.md section 2 and its "Danfoss FC" project decisions. Parameters come from
//! `crates/drive/catalogs/danfoss.toml`.
//!
//! Every telegram, whatever its block, carries PCD1 (control word, FC profile) and PCD2 (bus
//! reference); every reply carries the status word and MAV. The parameter channel (AK, PNU,
//! IND, PWE) lives in [`channel`].
//!
//! What the manuals leave open, and what this drive does:
//!
//! - **Word and double word.** A word write (AK 2/E) to a double-word parameter, or a
//!   double-word write (AK 3/D) to a word parameter, is refused with fault 5 "wrong data type".
//!   A word write takes the value from PWElow only (PWEhigh is not looked at).
//! - **Order of the checks** on a write: 0 unknown PNU, 4 index on a non-array, 3 index past
//!   the end, 1 read-only, 5 wrong data type, 17 not while running, 2 out of range.
//! - **AK F** (text): IND high byte 04 (or IND 0000) reads the parameter's name (the catalog
//!   title); IND 00nn with nn >= 1 reads the text of value nn - 1 (the FC 300 example reads
//!   "ENGLISH" from 0-01 with IND 0001), fault 15 where the value has no text; any other high
//!   byte gives 15. A text write (IND 05xx) gets fault 5: no catalog parameter is a text string
//!   (data type 9), and the FC 202 guide says only those carry text.
//! - **Unknown AK** (5, 6, 7, 8–C from a master) with a good BCC: fault 18 "other error".
//! - **Description elements** (AK 4, answered with AK 3): 1 basic characteristics (data type
//!   in bits 0–7, bit 10 "additional text available" as in the FC 300 example `0405`, bit 9
//!   read-only and bit 14 array after the PROFIdrive layout the FC option manuals print),
//!   2 number of elements, 4 conversion index (high byte) and unit index (low byte),
//!   6 name (a text block with AK 3), 7 lower limit, 8 upper limit, 20 default; any other
//!   element gives fault 9.
//! - **Ramps** 3-41/3-42 (ramp 2: 3-51/3-52, control word bit 09) run from 0 Hz to 1-23 Motor
//!   Frequency, as the FC 280 programming guide defines them. Jog (bit 08) runs at 3-19 Jog
//!   Speed [RPM], converted with the pole pairs of 1-23/1-25, and is a start command of its own
//!   (bit 06 need not be set), like the digital input "jog".
//! - **Bus control**: the control word acts only while 8-02 Control Source = FC port and 8-01
//!   Control Site is not "digital only" (status bit 09). The simulated drive has no digital
//!   inputs wired, so 8-50 Coasting Select, 8-53 Start Select and 8-54 Reversing Select
//!   honour the bus for "bus" and "logic OR" and ignore it for "digital input" and "logic AND".
//! - **Control timeout** 8-03/8-04: any valid telegram for this drive (broadcasts and control
//!   words with bit 10 = 0 included) restarts it; on expiry the 8-04 function acts (freeze,
//!   stop, jog, max. speed, or stop and trip with alarm 17) until the next telegram.
//! - **15-30 Alarm Log** holds the FC alarm numbers of the model's trips, newest at index 0:
//!   13 over current, 7 DC over voltage, 8 DC under voltage, 29 heat sink temperature,
//!   17 control word timeout, 60 external interlock.
//! - **Response delay**: 8-35 Minimum Response Delay (10 ms by default), copied into
//!   [`DriveCore::response_delay`]. 8-31 Address takes effect at once (1–126; above gives
//!   fault 2); 8-30 and 8-32/8-33 are stored but the drive keeps speaking FC on its line.

mod channel;

use std::time::Duration;

use drivebus_drive::{Family, ParamStore};
use drivebus_proto::error::{EmitError, FrameError};
use drivebus_proto::fc::{
    Block, ControlWord, FaultCode, Fc, FcScanner, RawTelegram, Reference, Reply, Request, StatusWord,
};
use drivebus_proto::session::{Disposition, Incoming, Protocol, Responder, SlaveSession};
use drivebus_proto::Instant;

use crate::drive::{Device, DriveCore, VirtualDrive};
use crate::model::{ModelSettings, Rotation, RunState, Trip};

use channel::Answer;

/// The protocol name this drive answers.
pub const PROTOCOL: drivebus_proto::protocol::WireProtocol =
    drivebus_proto::protocol::WireProtocol::DanfossFc;

/// The FC alarm number of a model trip, as 15-30 Alarm Log shows it.
pub fn alarm_code(trip: Trip) -> u8 {
    match trip {
        Trip::OverCurrent => 13,
        Trip::OverVoltage => 7,
        Trip::UnderVoltage => 8,
        Trip::OverTemperature => 29,
        Trip::CommunicationTimeout => 17,
        Trip::External => 60,
    }
}

/// The FC protocol as this drive's slave session uses it: [`Fc`] in everything, except that a
/// telegram with a good BCC whose AK is not in the master's table is handed to the drive (it
/// answers AK 7, fault 18) instead of being dropped.
#[derive(Clone, Copy, Debug, Default)]
struct FcSlave(Fc);

impl Protocol for FcSlave {
    type ReplyScanner = FcScanner;
    type RequestScanner = FcScanner;
    type Request<'a> = Request<'a>;
    type Reply<'a> = Reply<'a>;
    type Pending = <Fc as Protocol>::Pending;

    fn reply_scanner(&self) -> FcScanner {
        self.0.reply_scanner()
    }
    fn request_scanner(&self) -> FcScanner {
        self.0.request_scanner()
    }
    fn emit_request(&self, req: &Request<'_>, out: &mut [u8]) -> Result<usize, EmitError> {
        self.0.emit_request(req, out)
    }
    fn emit_reply(&self, rep: &Reply<'_>, out: &mut [u8]) -> Result<usize, EmitError> {
        self.0.emit_reply(rep, out)
    }
    fn parse_request<'a>(&self, bytes: &'a [u8]) -> Result<Request<'a>, FrameError> {
        self.0.parse_request(bytes)
    }
    fn parse_reply<'a>(&self, bytes: &'a [u8]) -> Result<Reply<'a>, FrameError> {
        self.0.parse_reply(bytes)
    }
    fn pending(&self, req: &Request<'_>) -> Option<Self::Pending> {
        self.0.pending(req)
    }
    fn matches(&self, pending: &Self::Pending, rep: &Reply<'_>) -> bool {
        self.0.matches(pending, rep)
    }
    fn disposition(&self, req: &Request<'_>, me: u8) -> Disposition {
        self.0.disposition(req, me)
    }
    /// A bad BCC or a cut-off telegram stays unanswered (the raw parse fails); a whole telegram
    /// for this drive whose only fault is an unknown AK is the drive's to refuse.
    fn rejected_disposition(&self, bytes: &[u8], _error: &FrameError, me: u8) -> Disposition {
        match RawTelegram::parse(bytes) {
            Ok(raw) => match raw.adr.address() {
                None => Disposition::Broadcast { reply: false },
                Some(a) if a == me => Disposition::Mine,
                Some(_) => Disposition::NotMine,
            },
            Err(_) => Disposition::NotMine,
        }
    }
}

/// A virtual Danfoss FC drive: the shared motor model and parameters, the FC slave session,
/// and the FC-profile control state.
pub struct DanfossDrive {
    session: SlaveSession<FcSlave>,
    state: State,
}

/// Everything but the session, so the session's handler can borrow it.
struct State {
    core: DriveCore,
    /// The last control word acted on (bit 10 = 1, bus control): reset edges, ramp select,
    /// coasting for the status word, 16-00.
    ctw: ControlWord,
    /// The bus reference of that telegram.
    reference: Reference,
    /// The last valid telegram for this drive (8-03 control timeout).
    last_comm: Instant,
    /// The 8-04 function has acted since the last telegram.
    timeout_fired: bool,
    /// When the drive was created (15-00 operating hours).
    powered_at: Instant,
}

impl DanfossDrive {
    /// A stopped drive numbered `address` (1–126, 8-31) with the catalog's defaults, at `now`.
    pub fn new(address: u8, now: Instant) -> Result<Self, String> {
        if !(1..=126).contains(&address) {
            return Err(format!(
                "an FC drive's address is 1 to 126 (8-31 with the FC protocol), not {address}"
            ));
        }
        let mut params = ParamStore::for_family(Family::Danfoss)
            .map_err(|e| format!("the FC catalog does not load: {e}"))?;
        params
            .force("8-31", 0, i64::from(address))
            .map_err(|e| format!("the FC catalog has no 8-31 Address: {e}"))?;
        let settings = derive_settings(&params, false);
        let core = DriveCore::new(params, settings, address, now);
        let mut state = State {
            core,
            ctw: ControlWord(0),
            reference: Reference(0),
            last_comm: now,
            timeout_fired: false,
            powered_at: now,
        };
        state.core.response_delay = state.min_response_delay();
        let session = SlaveSession::new(FcSlave::default(), address, state.core.response_delay);
        Ok(DanfossDrive { session, state })
    }

    /// The last control word the drive acted on (bit 10 set, bus control), as 16-00 shows it.
    pub fn control_word(&self) -> ControlWord {
        self.state.ctw
    }

    /// The status word the drive would send now.
    pub fn status_word(&self) -> StatusWord {
        self.state.status_word()
    }

    /// The main actual value (output frequency, scaled like the reference) the drive would send now.
    pub fn main_actual_value(&self) -> Reference {
        self.state.mav()
    }

    /// The time at which the 8-03/8-04 control timeout acts next, if it is armed.
    pub fn control_timeout_at(&self) -> Option<Instant> {
        self.state.comm_deadline()
    }

    /// Brings the session up to date with the shared state (the control interface may have
    /// changed the address or the response delay).
    fn sync_session(&mut self) {
        self.session.set_address(self.state.core.address);
        self.session.set_response_delay(self.state.core.response_delay);
    }
}

impl Device for DanfossDrive {
    fn receive(&mut self, now: Instant, bytes: &[u8]) {
        self.advance_to(now);
        self.sync_session();
        let DanfossDrive { session, state } = self;
        session.handle_input(now, bytes, &mut |now, incoming, responder| {
            state.handle(now, incoming, responder);
        });
        // 8-31 may have changed the address.
        self.sync_session();
    }

    /// protocols.md 2.9: "The gap between characters inside a telegram must not exceed
    /// 2 characters": after a silence a half telegram is dropped, unanswered.
    fn silence(&mut self, now: Instant) {
        let DanfossDrive { session, state } = self;
        session.handle_silence(now, &mut |now, incoming, responder| {
            state.handle(now, incoming, responder);
        });
    }

    fn poll_transmit(&mut self, now: Instant) -> Option<Vec<u8>> {
        self.session.poll_transmit(now).map(<[u8]>::to_vec)
    }

    /// The reply's due time, or the control timeout's, whichever is first: the line then lets
    /// the drive act on the timeout at its exact time.
    fn poll_timeout(&self) -> Option<Instant> {
        match (self.session.poll_timeout(), self.state.comm_deadline()) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    fn advance_to(&mut self, now: Instant) {
        self.state.advance_to(now);
    }

    crate::drive::device_is_a_drive!();
}

impl VirtualDrive for DanfossDrive {
    fn protocol(&self) -> String {
        PROTOCOL.name().to_string()
    }

    crate::drive::drive_core_at!(state.core);

    fn control_source(&self) -> String {
        let p = &self.state.core.params;
        let text = |name: &str| -> String {
            let Some(def) = p.catalog().get(name) else { return format!("{name} missing") };
            let raw = p.get(name).unwrap_or(def.default);
            format!("{name} = {}", def.format(raw))
        };
        format!("{}, {}, {}", text("8-02"), text("8-01"), text("8-53"))
    }
}

impl State {
    fn param(&self, name: &str) -> i64 {
        let p = &self.core.params;
        p.get(name).or_else(|| p.catalog().get(name).map(|d| d.default)).unwrap_or(0)
    }

    /// 8-35 Minimum Response Delay (ms steps).
    fn min_response_delay(&self) -> Duration {
        Duration::from_millis(self.param("8-35").clamp(1, 10_000) as u64)
    }

    /// One telegram for this drive (or a broadcast).
    fn handle(
        &mut self,
        now: Instant,
        incoming: Incoming<'_, Request<'_>>,
        responder: &mut Responder<'_, FcSlave>,
    ) {
        let (adr, answer) = match incoming {
            Incoming::Request { request, .. } => {
                self.telegram_seen(now);
                self.apply_control(request.ctw, request.reference);
                // The monitors (16-xx, 15-30) as measured now, before the channel reads them.
                self.refresh_monitors();
                let answer = match request.block {
                    Block::Process => Answer::Process,
                    Block::Parameter(p) => self.parameter(p.ak, p.pnu, p.ind, p.pwe),
                    Block::Text(t) => self.text_block(t.ak, t.pnu, t.ind),
                };
                (request.adr, answer)
            }
            Incoming::Rejected { bytes, .. } => {
                // Only whole telegrams for this drive with an AK outside the master's table get
                // here (FcSlave::rejected_disposition).
                let Ok(raw) = RawTelegram::parse(bytes) else { return };
                self.telegram_seen(now);
                self.apply_control(ControlWord(raw.pcd1), Reference::from_word(raw.pcd2));
                let answer = match raw.block.header() {
                    Some((_, pnu, ind)) => Answer::fault(pnu, ind, FaultCode::OTHER_ERROR),
                    None => Answer::Process,
                };
                (raw.adr, answer)
            }
        };
        let stw = self.status_word();
        let mav = self.mav();
        let reply = match &answer {
            Answer::Process => Reply::process(adr, stw, mav),
            Answer::Param { ak, pnu, ind, pwe } => {
                Reply::parameter(adr, *ak, *pnu, *ind, *pwe).with_process(stw, mav)
            }
            Answer::Text { ak, pnu, ind, text } => {
                Reply::text(adr, *ak, *pnu, *ind, text).with_process(stw, mav)
            }
        };
        // Texts are cut to the codec's limit in `channel`, so emitting cannot fail; if it did,
        // the drive would stay silent, as a drive with a full buffer does.
        let _ = responder.reply(&reply);
    }

    /// A valid telegram for this drive: the control timeout starts again.
    fn telegram_seen(&mut self, now: Instant) {
        self.core.model.comm_seen(now);
        self.last_comm = now;
        self.timeout_fired = false;
    }

    /// Whether the control word acts (status bit 09 "bus control"): 8-02 Control Source is the
    /// FC port and 8-01 Control Site is not "digital only".
    fn bus_control(&self) -> bool {
        self.param("8-02") == 1 && self.param("8-01") != 1
    }

    /// Whether a "select" parameter (8-50, 8-53, 8-54) lets the bus act: "bus" (1) or
    /// "logic OR" (3); the digital inputs of the simulated drive are never active.
    fn bus_selected(&self, name: &str) -> bool {
        matches!(self.param(name), 1 | 3)
    }

    /// The bus reference in Hz, signed: 0x4000 is 3-03 Maximum Reference, 0 is 3-02 Minimum
    /// Reference (3-00 = min - max, clamped to that range) or 0 Hz (3-00 = -max - +max).
    fn reference_hz(&self, reference: Reference) -> f64 {
        let (lo, hi) = self.reference_range();
        let hz = reference.hz(lo, hi);
        if self.param("3-00") == 1 {
            hz
        } else {
            hz.clamp(lo.min(hi), hi.max(lo))
        }
    }

    /// The Hz at reference 0 and at 0x4000.
    fn reference_range(&self) -> (f64, f64) {
        let max = self.param("3-03") as f64 / 1000.0;
        let min = if self.param("3-00") == 1 { 0.0 } else { self.param("3-02") as f64 / 1000.0 };
        (min, max)
    }

    /// Acts on PCD1/PCD2 (protocols.md 2.6, FC profile).
    fn apply_control(&mut self, ctw: ControlWord, reference: Reference) {
        // protocols.md 2.6: bit 10 = 0 "data invalid: the control word is ignored", so
        // "PCD1 = 0000 is ignored" and parameter telegrams do not affect the drive.
        if !ctw.data_valid() || !self.bus_control() {
            return;
        }
        let previous = self.ctw;
        self.ctw = ctw;
        self.reference = reference;
        // Bit 07: "reset (on the 0->1 edge)"; holding it does not reset again.
        if ctw.reset() && !previous.reset() {
            // A cause that persists (heat sink still hot) keeps the trip.
            let _ = self.core.model.reset();
        }
        if ctw.ramp_2() != previous.ramp_2() {
            self.apply_settings();
        }
        self.apply_reference();
        let coast = ctw.coasting() && self.bus_selected("8-50");
        let start_allowed = self.bus_selected("8-53");
        let m = &mut self.core.model;
        if coast {
            // Bit 03 = 0: coasting, the motor is released at once.
            m.coast();
        } else if ctw.quick_stop() {
            // Bit 04 = 0: quick stop (3-81).
            m.quick_stop();
        } else if ctw.dc_brake() {
            // Bit 02 = 0: "DC brake (+stop)": the output stops at once.
            m.quick_stop();
        } else if ctw.jog() && start_allowed {
            // Bit 08 = 1: jog at 3-19.
            let _ = m.jog();
        } else if ctw.start() && start_allowed {
            // Bit 06 = 1: start (refused while tripped or without hardware enable).
            let _ = m.run();
        } else {
            // Bit 06 = 0: ramp stop.
            m.stop();
        }
    }

    /// Sets the model's setpoint and direction from the last reference and control word.
    fn apply_reference(&mut self) {
        let ctw = self.ctw;
        let hz = self.reference_hz(self.reference);
        let m = &mut self.core.model;
        if ctw.hold() {
            // Bit 05 = 0: "hold (freeze) output frequency".
            let out = m.output_hz();
            m.set_setpoint_hz(out);
        } else {
            m.set_setpoint_hz(hz.abs());
        }
        // Bit 15 = 1 reverses (8-54 permitting); a negative reference reverses too; 4-10 Motor
        // Speed Direction may allow one direction only.
        let bus_reverse = ctw.reverse() && self.bus_selected("8-54");
        let reverse = match self.param("4-10") {
            0 => false,
            1 => true,
            _ => bus_reverse != (hz < 0.0),
        };
        self.core.model.set_rotation(if reverse { Rotation::Reverse } else { Rotation::Forward });
    }

    /// Re-derives everything that follows from the parameters: model settings, response delay.
    fn apply_settings(&mut self) {
        let settings = derive_settings(&self.core.params, self.ctw.ramp_2());
        self.core.model.set_settings(settings);
        self.core.response_delay = self.min_response_delay();
    }

    /// When the 8-04 control timeout function acts next, if armed.
    fn comm_deadline(&self) -> Option<Instant> {
        let function = self.param("8-04");
        if function == 0 || self.timeout_fired || self.core.model.trip().is_some() {
            return None;
        }
        let tenths = u64::try_from(self.param("8-03")).unwrap_or(1).max(1);
        Some(self.last_comm + Duration::from_millis(tenths * 100))
    }

    fn advance_to(&mut self, now: Instant) {
        if let Some(deadline) = self.comm_deadline() {
            if deadline <= now {
                self.advance_model(deadline);
                self.control_timeout();
            }
        }
        self.advance_model(now);
    }

    /// Advances the model to `to`. Workaround: `DriveModel::advance_to` ends a step where a
    /// reversal crosses 0 Hz (the rest of that step is lost), so a long quiet spell would
    /// leave a reversing drive at 0 Hz; step to the crossing first.
    fn advance_model(&mut self, to: Instant) {
        let m = &mut self.core.model;
        if m.is_running() && m.output_rotation() != m.rotation() && m.output_mhz() > 0 {
            let s = m.settings();
            let max_mhz = ((s.max_hz * 1000.0).round() as u128).max(1);
            let ramp_us = s.decel.as_micros().max(1);
            let us = (m.output_mhz() as u128 * ramp_us).div_ceil(max_mhz);
            let crossing = m.now() + Duration::from_micros(us.min(u64::MAX as u128) as u64);
            if crossing < to {
                m.advance_to(crossing);
            }
        }
        m.advance_to(to);
    }

    /// 8-04 Control Timeout Function, acting until the next telegram.
    fn control_timeout(&mut self) {
        self.timeout_fired = true;
        let max_hz = self.core.model.settings().max_hz;
        let function = self.param("8-04");
        let m = &mut self.core.model;
        match function {
            1 => {
                // Freeze output.
                let out = m.output_hz();
                m.set_setpoint_hz(out);
            }
            2 => m.stop(),
            3 => {
                let _ = m.jog();
            }
            4 => {
                m.set_setpoint_hz(max_hz);
            }
            5 => m.trip_now(Trip::CommunicationTimeout),
            _ => {}
        }
    }

    /// The status word, FC profile (protocols.md 2.7).
    fn status_word(&self) -> StatusWord {
        let m = &self.core.model;
        let s = m.settings();
        let tripped = m.trip().is_some();
        let coasting = self.ctw.coasting() && self.bus_selected("8-50");
        let current_limit = s.rated_current_a * self.param("4-18") as f64 / 1000.0;
        let nominal = s.nominal_dc_v;
        let voltage = m.dc_bus_v() > nominal * 1.15 || m.dc_bus_v() < nominal * 0.8;
        let torque = m.current_a() > current_limit;
        let thermal = m.heatsink_c() > s.overtemp_c - 10.0;
        let mut w = StatusWord(0);
        // 00 control ready: 0 when the drive trips.
        w = w.with_bit(0, !tripped);
        // 01 drive ready.
        w = w.with_bit(1, !tripped && m.hardware_enable());
        // 02 enable (0: coasting).
        w = w.with_bit(2, !tripped && m.hardware_enable() && !coasting);
        // 03 trip.
        w = w.with_bit(3, tripped);
        // 07 warning.
        w = w.with_bit(7, voltage || torque || thermal);
        // 08 speed = reference.
        w = w.with_bit(8, self.at_reference());
        // 09 bus control.
        w = w.with_bit(9, self.bus_control());
        // 10 frequency limit OK.
        w = w.with_bit(10, self.within_limits());
        // 11 in operation: a start signal, or output above 0 Hz.
        w = w.with_bit(11, m.is_running());
        w = w.with_bit(13, voltage);
        w = w.with_bit(14, torque);
        w = w.with_bit(15, thermal);
        w
    }

    /// Running at the frequency asked for, in the direction asked for.
    fn at_reference(&self) -> bool {
        let m = &self.core.model;
        if m.state() != RunState::Running || m.output_rotation() != m.rotation() {
            return false;
        }
        let s = m.settings();
        let mhz = |hz: f64| (hz * 1000.0).round() as i64;
        let target = if m.is_jogging() { mhz(s.jog_hz) } else { mhz(m.setpoint_hz()).max(mhz(s.min_hz)) };
        m.output_mhz() == target
    }

    /// Status bit 10: the frequency asked for lies within 4-12..4-14 (else the output is held
    /// at a limit).
    fn within_limits(&self) -> bool {
        let m = &self.core.model;
        if !m.is_running() || m.is_jogging() {
            return true;
        }
        let asked = self.reference_hz(self.reference).abs();
        let low = self.param("4-12") as f64 / 10.0;
        let high = m.settings().max_hz;
        asked >= low - 1e-9 && asked <= high + 1e-9
    }

    /// MAV: the output frequency, signed by direction, scaled like the reference.
    fn mav(&self) -> Reference {
        let m = &self.core.model;
        let sign = if m.output_rotation() == Rotation::Reverse { -1.0 } else { 1.0 };
        let (lo, hi) = self.reference_range();
        Reference::from_hz(sign * m.output_hz(), lo, hi)
    }

    /// Writes the monitors (16-xx, 15-00/15-01, 15-30) into the store, as the drive measures them.
    fn refresh_monitors(&mut self) {
        let stw = self.status_word();
        let m = &self.core.model;
        let now = m.now();
        let power_10w = (3f64.sqrt() * m.output_v() * m.current_a() * 0.85 / 10.0).round() as i64;
        let values = [
            ("16-00", i64::from(self.ctw.0)),
            ("16-02", (self.reference.percent() * 10.0).round() as i64),
            ("16-03", i64::from(stw.0)),
            ("16-10", power_10w),
            ("16-12", (m.output_v() * 10.0).round() as i64),
            ("16-13", (m.output_hz() * 10.0).round() as i64),
            ("16-14", (m.current_a() * 100.0).round() as i64),
            ("16-30", m.dc_bus_v().round() as i64),
            ("16-34", m.heatsink_c().round() as i64),
            ("15-00", (now.saturating_since(self.powered_at).as_secs() / 3600) as i64),
            ("15-01", m.run_hours().floor() as i64),
        ];
        let log: Vec<i64> = m.recent_trips().map(|r| i64::from(alarm_code(r.trip))).collect();
        let p = &mut self.core.params;
        for (name, value) in values {
            let _ = p.force(name, 0, value);
        }
        for i in 0..10 {
            let _ = p.force("15-30", i, log.get(i).copied().unwrap_or(0));
        }
    }
}

/// The model's settings from the FC parameters; `ramp_2` selects 3-51/3-52 (control word bit 09).
fn derive_settings(p: &ParamStore, ramp_2: bool) -> ModelSettings {
    let get = |name: &str, fallback: i64| p.get(name).unwrap_or(fallback);
    let motor_hz = get("1-23", 50).max(1);
    let rated_rpm = get("1-25", 1420).max(1);
    // 4-14 Motor Speed High Limit [Hz] and 4-19 Max Output Frequency, 0.1 Hz.
    let max_dhz = get("4-14", 650).min(get("4-19", 1000)).max(0);
    let min_dhz = get("4-12", 0).clamp(0, max_dhz);
    let max_mhz = max_dhz as u128 * 100;
    // 3-41 "Ramp 1 Ramp Up Time" runs from 0 Hz to 1-23 Motor Frequency; the model ramps from
    // 0 to max_hz, so its time scales by max_hz / motor_hz (integer nanoseconds: exact).
    let ramp = |centis: i64| {
        let ns = centis.max(0) as u128 * 10_000_000 * max_mhz / (motor_hz as u128 * 1000);
        Duration::from_nanos(ns.min(u64::MAX as u128) as u64)
    };
    let (up, down) = if ramp_2 { ("3-51", "3-52") } else { ("3-41", "3-42") };
    // 3-19 Jog Speed [RPM] to Hz with the motor's pole pairs (1-23 and 1-25: 50 Hz, 1420 rpm
    // is 2 pole pairs, so 150 rpm is 5 Hz).
    let pole_pairs = ((60 * motor_hz) as f64 / rated_rpm as f64).round().max(1.0);
    let jog_hz = (get("3-19", 150) as f64 * pole_pairs / 60.0).min(max_dhz as f64 / 10.0);
    let defaults = ModelSettings::default();
    ModelSettings {
        accel: ramp(get(up, 300)),
        decel: ramp(get(down, 300)),
        min_hz: min_dhz as f64 / 10.0,
        max_hz: max_dhz as f64 / 10.0,
        jog_hz,
        rated_current_a: get("1-24", 840) as f64 / 100.0,
        rated_rpm: rated_rpm as f64,
        base_hz: motor_hz as f64,
        nominal_dc_v: get("1-22", 400) as f64 * 1.35,
        ..defaults
    }
}
