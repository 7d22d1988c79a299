//! The B800 series virtual drive (`seeds/000_04b515f0e0c1734e.txt`), speaking the B800
//! hex-ASCII protocol through [`drivebus_proto::b800`].
//!
//! seed 000: "Each B800 acts as a slave unit any will only transmit data in response to a
//! request from the Host / master." The protocol has no parameter access: the parameters
//! (`crates/drive/catalogs/b800.toml`) are set through the control interface
//! ([`VirtualDrive::core_mut`]`().params`) and take effect at the drive's next step.
//!
//! ## Commands
//!
//! | cmd | reply | what the drive does |
//! |---|---|---|
//! | `R` | `r` | runs; with F-12 = 2, `R` to a running drive reverses it |
//! | `S` | `s` | ramps to a stop (F-05 = 1: coasts); to a tripped drive: resets the trip |
//! | `A` | `a` word | motor current, 0.1 A |
//! | `Z` | `z` word | output frequency, 60 x Hz |
//! | `M` | `m` word | motor speed, rpm = output Hz x F-09 / F-06 |
//! | `T` | `t` word | status: low byte 02 / 93 / 99 / 9A, high byte the trip code while tripped |
//! | `V` | `v` word | software version, BCD ([`VERSION`], 1.00) |
//! | `P` | `p` | keypad setpoint = DATA / 60 Hz, held within F-02..F-01 |
//! | `I` / `L` | `i` / `l` | keypad setpoint up / down one step (F-19, 0.5 Hz) within F-02..F-01 |
//!
//! ## Error replies, checked in this order
//!
//! The codes are the seed's list; which command earns which code is a project decision where
//! the seed gives only the code's title (marked "decision").
//!
//! | code | seed title | trigger |
//! |---|---|---|
//! | 91 | not in keypad mode | `R S P I L` with F-12 = 0 (terminals); `P I L` with F-12 = 2 |
//! | 98 | parameters locked | `P I L` with F-14 = 1 (decision, catalog note of F-14) |
//! | 9A | tripped | `R`, `I`, `L` while tripped; `S` while the trip's cause persists |
//! | 99 | hardware enable not present | `R` without hardware enable |
//! | 93 | running, cannot be carried out | `R` to a running drive with F-12 = 1 (decision: it is already running; with F-12 = 2 it reverses) |
//! | 94 | stopped, cannot be carried out | `I`, `L` to a drive that is not running (decision: they step a running ramp) |
//! | 02 | drive in standby (status information) | `S` to a drive already in standby (decision: nothing to stop, the drive reports its state) |
//! | 92 | rpm not available (F-10 = 0) | `M` with F-10 = 0 |
//! | 95 | incorrect checksum | a whole frame with DA = this drive + 128 and a wrong CS |
//! | 97 | command not recognised | a frame for this drive with a good CS and an unknown CMD |
//!
//! A global frame (DA `G`) is acted on by every drive and answered by none, whatever its
//! outcome; a frame for another drive is ignored (seed 000: "the B800 will ignore the data and
//! no response at all will be generated").
//!
//! ## Other decisions where the seed is silent
//!
//! - Trip codes in the status word's high byte and in F-13 ([`trip_code`]): 01 over-current,
//!   02 over-voltage, 03 under-voltage, 04 over-temperature, 05 communication loss, 06 external.
//! - F-33 (communication loss time, 0.1 s, 0 = off) and F-34 (action: 0 trip, 1 ramp to stop,
//!   2 coast) watch the time since the last valid telegram for this drive (global ones count).
//! - A `P` outside F-02..F-01 is held at the nearer limit and answered `p` (the seed has no
//!   code for a bad value: 95 is the checksum's).
//! - Not modelled (no effect): F-07, F-11, F-15..F-18, F-20..F-31 except those above.

use std::time::Duration;

use drivebus_drive::{Family, ParamStore};
use drivebus_proto::b800::{
    Address, Current, DriveState, DriveStatus, ErrorCode, MasterCommand, Reply, Rpm, SlaveReply, Speed,
    Version, B800,
};
use drivebus_proto::session::{Incoming, Responder, SlaveSession};
use drivebus_proto::Instant;

use crate::drive::{Device, DriveCore, VirtualDrive};
use crate::model::{ModelSettings, Rotation, RunRefusal, RunState, Trip};

/// The protocol name the drive reports (the codec's name).
pub const PROTOCOL: drivebus_proto::protocol::WireProtocol = drivebus_proto::protocol::WireProtocol::B800;

/// The software version a new drive reports to `V`: 1.00 (project decision: BCD, 0x0100).
pub const VERSION: Version = Version::from_raw(0x0100);

/// The B800 trip code for `trip`, as the `t` reply's high byte and F-13 carry it (project
/// decision; the seed lists no trip codes).
pub fn trip_code(trip: Trip) -> u8 {
    match trip {
        Trip::OverCurrent => 0x01,
        Trip::OverVoltage => 0x02,
        Trip::UnderVoltage => 0x03,
        Trip::OverTemperature => 0x04,
        Trip::CommunicationTimeout => 0x05,
        Trip::External => 0x06,
    }
}

/// F-12, where run, stop and speed commands come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Source {
    /// 0: terminals; the host may only ask.
    Terminals,
    /// 1: keypad; the host may run, stop and set the speed.
    Keypad,
    /// 2: the host runs and stops; the speed comes from elsewhere.
    HostRunStop,
}

/// What the drive derives from its parameters; re-derived when a parameter changes.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Derived {
    settings: ModelSettings,
    /// F-33, `None` when off.
    comm_timeout: Option<Duration>,
    /// F-34: 0 trip, 1 ramp to stop, 2 coast.
    comm_action: i64,
}

/// The local watch behind F-34 = 1 or 2 (F-34 = 0 uses the model's own time-out trip).
#[derive(Clone, Copy, Debug)]
struct CommWatch {
    last: Instant,
    lost: bool,
}

/// A B800 series drive on the line: the shared motor model, the B800 catalog's parameters and
/// a B800 slave session.
pub struct B800Drive {
    core: DriveCore,
    session: SlaveSession<B800>,
    version: Version,
    derived: Derived,
    comm: CommWatch,
}

impl std::fmt::Debug for B800Drive {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("B800Drive")
            .field("address", &self.core.address)
            .field("state", &self.core.model.state())
            .finish_non_exhaustive()
    }
}

impl B800Drive {
    /// A stopped drive numbered `address` (1–63) with the catalog's defaults (F-12 = 1 keypad,
    /// F-10 = 1 rpm available) at simulated time `now`; an error sentence for a bad address.
    pub fn new(address: u8, now: Instant) -> Result<Self, String> {
        if Address::new(address).is_none() {
            return Err(format!(
                "a B800 drive address is 1 to 63 (the master sends it + 128), not {address}"
            ));
        }
        let mut params = ParamStore::for_family(Family::B800)
            .map_err(|e| format!("the B800 parameter catalog does not load: {e}"))?;
        params
            .force("F-32", 0, i64::from(address))
            .map_err(|e| format!("the B800 catalog lacks the address parameter: {e}"))?;
        let derived = derive(&params);
        let mut core = DriveCore::new(params, derived.settings, address, now);
        apply_comm(&mut core, &derived);
        let session = SlaveSession::new(B800, address, core.response_delay);
        Ok(B800Drive { core, session, version: VERSION, derived, comm: CommWatch { last: now, lost: false } })
    }

    /// The software version the drive reports to `V`.
    pub fn version(&self) -> Version {
        self.version
    }

    /// Changes the software version the drive reports to `V`.
    pub fn set_version(&mut self, version: Version) {
        self.version = version;
    }

    /// The slave session's counts (requests, replies, ignored frames, deframer counts).
    pub fn session_stats(&self) -> drivebus_proto::session::SlaveStats {
        self.session.stats()
    }

    /// Takes in parameter, address and response-delay changes made through the control
    /// interface since the last step.
    fn sync(&mut self) {
        let derived = derive(&self.core.params);
        if derived != self.derived {
            if derived.settings != self.derived.settings {
                self.core.model.set_settings(derived.settings);
            }
            if (derived.comm_timeout, derived.comm_action)
                != (self.derived.comm_timeout, self.derived.comm_action)
            {
                apply_comm(&mut self.core, &derived);
                self.comm = CommWatch { last: self.core.model.now(), lost: false };
            }
            self.derived = derived;
        }
        self.sync_address();
        self.session.set_response_delay(self.core.response_delay);
    }

    /// `core.address` (the control interface) wins over F-32; F-32 changed alone moves the drive.
    fn sync_address(&mut self) {
        let current = self.session.address();
        if self.core.address != current {
            if Address::new(self.core.address).is_some() {
                self.session.set_address(self.core.address);
                let _ = self.core.params.force("F-32", 0, i64::from(self.core.address));
            } else {
                self.core.address = current;
            }
            return;
        }
        let f32 = self.core.params.get("F-32").and_then(|v| u8::try_from(v).ok());
        if let Some(a) = f32.filter(|&a| a != current && Address::new(a).is_some()) {
            self.session.set_address(a);
            self.core.address = a;
        }
    }

    /// F-34 = 1 or 2: ramp or coast to a stop once the line has been quiet for F-33.
    fn watch_comm(&mut self, now: Instant) {
        let Some(timeout) = self.derived.comm_timeout else { return };
        if self.derived.comm_action == 0 || self.comm.lost {
            return;
        }
        let due = self.comm.last + timeout;
        if now < due {
            return;
        }
        self.advance_model(due);
        self.comm.lost = true;
        if self.core.model.is_running() {
            if self.derived.comm_action == 1 {
                self.core.model.stop();
            } else {
                self.core.model.coast();
            }
        }
    }

    /// Advances the model to `now`. A reversal's zero crossing gets a step of its own:
    /// `DriveModel::advance_to` ramps toward one target per call, so one long step across the
    /// crossing would leave the output at 0 Hz until the next call (workaround for the shared
    /// model).
    fn advance_model(&mut self, now: Instant) {
        let m = &mut self.core.model;
        if m.state() == RunState::Running
            && !m.is_jogging()
            && m.output_rotation() != m.rotation()
            && m.output_mhz() > 0
        {
            let s = m.settings();
            let max_mhz = ((s.max_hz * 1000.0).round() as u128).max(1);
            let decel_us = s.decel.as_micros().max(1);
            // Rounded up, so the output has surely reached zero at `cross`.
            let us = (u128::from(m.output_mhz().unsigned_abs()) * decel_us).div_ceil(max_mhz);
            let cross = m.now() + Duration::from_micros(u64::try_from(us).unwrap_or(u64::MAX));
            if cross < now {
                m.advance_to(cross);
            }
        }
        m.advance_to(now);
    }

    /// F-13: the last four trip codes, newest first, 0 where there is none.
    fn refresh_trip_log(&mut self) {
        let mut codes = [0i64; 4];
        for (slot, rec) in codes.iter_mut().zip(self.core.model.recent_trips()) {
            *slot = i64::from(trip_code(rec.trip));
        }
        for (i, code) in codes.into_iter().enumerate() {
            if self.core.params.get_element("F-13", i) != Some(code) {
                let _ = self.core.params.force("F-13", i, code);
            }
        }
    }
}

/// A parameter's raw value, or `default` if the catalog lacks it.
fn param(params: &ParamStore, name: &str, default: i64) -> i64 {
    params.get(name).unwrap_or(default)
}

/// The model settings and communication watch the parameters ask for.
fn derive(params: &ParamStore) -> Derived {
    let tenths = |name: &str, default: i64| param(params, name, default) as f64 / 10.0;
    let ramp = |name: &str| {
        // F-03 / F-04 in 0.1 s; the model ramps over 0..F-01.
        let raw = u64::try_from(param(params, name, 50)).unwrap_or(0).max(1);
        Duration::from_millis(raw.saturating_mul(100))
    };
    let max_hz = tenths("F-01", 500).max(0.0);
    let min_hz = tenths("F-02", 0).clamp(0.0, max_hz);
    let settings = ModelSettings {
        accel: ramp("F-03"),
        decel: ramp("F-04"),
        min_hz,
        max_hz,
        rated_current_a: tenths("F-08", 41).max(0.1),
        rated_rpm: param(params, "F-09", 1420).max(0) as f64,
        base_hz: param(params, "F-06", 50).max(1) as f64,
        ..ModelSettings::default()
    };
    let comm_raw = u64::try_from(param(params, "F-33", 0)).unwrap_or(0);
    Derived {
        settings,
        comm_timeout: (comm_raw > 0).then(|| Duration::from_millis(comm_raw.saturating_mul(100))),
        comm_action: param(params, "F-34", 0),
    }
}

/// F-34 = 0 uses the model's communication time-out trip; other actions are watched locally.
fn apply_comm(core: &mut DriveCore, derived: &Derived) {
    let trip = if derived.comm_action == 0 { derived.comm_timeout } else { None };
    core.model.set_comm_timeout(trip);
}

/// F-12 as a control source; a value outside 0..=2 (forced past the range) reads as terminals.
fn source(core: &DriveCore) -> Source {
    match param(&core.params, "F-12", 1) {
        1 => Source::Keypad,
        2 => Source::HostRunStop,
        _ => Source::Terminals,
    }
}

/// A value clamped into a 16-bit reply word.
fn word(v: f64) -> u16 {
    if v.is_nan() {
        0
    } else {
        v.round().clamp(0.0, f64::from(u16::MAX)) as u16
    }
}

/// The `t` status word.
fn status(core: &DriveCore) -> DriveStatus {
    let m = &core.model;
    if let Some(t) = m.trip() {
        DriveStatus::tripped(trip_code(t))
    } else if !m.hardware_enable() {
        DriveStatus::new(DriveState::HardwareEnableMissing)
    } else if m.is_running() {
        DriveStatus::new(DriveState::Running)
    } else {
        DriveStatus::new(DriveState::Standby)
    }
}

/// `P`, `I`, `L`: keypad mode only (seed 000: "Keypad mode only (F-12 = 1)"), and not while
/// the parameters are locked (F-14 = 1, catalog note: "while locked the host's P, I and L get
/// error 0x98").
fn keypad_setpoint_allowed(core: &DriveCore) -> Result<(), ErrorCode> {
    if source(core) != Source::Keypad {
        return Err(ErrorCode::NOT_KEYPAD_MODE);
    }
    if param(&core.params, "F-14", 0) != 0 {
        return Err(ErrorCode::PARAMETERS_LOCKED);
    }
    Ok(())
}

/// The keypad setpoint's limits, millihertz: F-02..F-01.
fn limits_mhz(core: &DriveCore) -> (i64, i64) {
    let s = core.model.settings();
    let max = (s.max_hz * 1000.0).round() as i64;
    let min = ((s.min_hz * 1000.0).round() as i64).min(max);
    (min, max)
}

/// Carries out `cmd`; the reply, or the error code that says why not.
fn execute(core: &mut DriveCore, version: Version, cmd: MasterCommand) -> Result<SlaveReply, ErrorCode> {
    match cmd {
        MasterCommand::Run => run(core),
        MasterCommand::Stop => stop(core),
        MasterCommand::MotorCurrent => {
            Ok(SlaveReply::MotorCurrent(Current::from_raw(word(core.model.current_a() * 10.0))))
        }
        MasterCommand::SpeedHz => {
            // Project decision: `z` is the output frequency as 60 x Hz, like `P`.
            Ok(SlaveReply::SpeedHz(Speed::from_raw(word(core.model.output_mhz() as f64 * 60.0 / 1000.0))))
        }
        MasterCommand::SpeedRpm => {
            // seed 000: "0x92 B800 speed in RPM not available (F-10 = 0)".
            if param(&core.params, "F-10", 1) == 0 {
                return Err(ErrorCode::RPM_NOT_AVAILABLE);
            }
            // Catalog note of F-09: "the M command reports output frequency x F-09 / F-06".
            let base = param(&core.params, "F-06", 50).max(1) as f64;
            let rated = param(&core.params, "F-09", 1420).max(0) as f64;
            Ok(SlaveReply::SpeedRpm(Rpm::from_raw(word(core.model.output_hz() * rated / base))))
        }
        MasterCommand::Status => Ok(SlaveReply::Status(status(core))),
        MasterCommand::Version => Ok(SlaveReply::Version(version)),
        MasterCommand::SetSpeed(speed) => {
            keypad_setpoint_allowed(core)?;
            // seed 000: "the transmitted speed in Hertz is always 60x the speed required".
            let (min, max) = limits_mhz(core);
            let mhz = (i64::from(speed.raw()) * 1000 + 30) / 60;
            core.model.set_setpoint_hz(mhz.clamp(min, max) as f64 / 1000.0);
            Ok(SlaveReply::SetSpeed)
        }
        MasterCommand::Increase | MasterCommand::Reduce => {
            keypad_setpoint_allowed(core)?;
            if core.model.trip().is_some() {
                return Err(ErrorCode::TRIPPED);
            }
            // seed 000: "Increase speed on ramp" / "Reduce speed on ramp": they step a
            // running ramp, so a drive that is not running answers 0x94 (decision).
            if core.model.state() != RunState::Running {
                return Err(ErrorCode::STOPPED);
            }
            let (min, max) = limits_mhz(core);
            let step = param(&core.params, "F-19", 5).max(0) * 100;
            let now = (core.model.setpoint_hz() * 1000.0).round() as i64;
            let (next, reply) = if cmd == MasterCommand::Increase {
                (now.saturating_add(step), SlaveReply::Increase)
            } else {
                (now.saturating_sub(step), SlaveReply::Reduce)
            };
            core.model.set_setpoint_hz(next.clamp(min, max) as f64 / 1000.0);
            Ok(reply)
        }
    }
}

/// `R`: seed 000 "Send Run Command ... (F-12 = 1 or 2)"; "Sending a run command to an already
/// running drive reverses direction if F-12 = 2".
fn run(core: &mut DriveCore) -> Result<SlaveReply, ErrorCode> {
    let src = source(core);
    if src == Source::Terminals {
        return Err(ErrorCode::NOT_KEYPAD_MODE);
    }
    let refused = |r: RunRefusal| match r {
        RunRefusal::Tripped(_) => ErrorCode::TRIPPED,
        RunRefusal::NoHardwareEnable => ErrorCode::NO_HARDWARE_ENABLE,
    };
    if let Some(r) = core.model.run_refusal() {
        return Err(refused(r));
    }
    match (core.model.state(), src) {
        (RunState::Running, Source::HostRunStop) => {
            let other = match core.model.rotation() {
                Rotation::Forward => Rotation::Reverse,
                Rotation::Reverse => Rotation::Forward,
            };
            core.model.set_rotation(other);
            Ok(SlaveReply::Run)
        }
        // Already running in keypad mode: nothing to start (decision: 0x93).
        (RunState::Running, _) => Err(ErrorCode::RUNNING),
        _ => core.model.run().map(|()| SlaveReply::Run).map_err(refused),
    }
}

/// `S`: ramps (F-05 = 0) or coasts (F-05 = 1) to a stop; resets a trip (decision: the seed has
/// no reset command, and a tripped drive must be recoverable from the host).
fn stop(core: &mut DriveCore) -> Result<SlaveReply, ErrorCode> {
    if source(core) == Source::Terminals {
        return Err(ErrorCode::NOT_KEYPAD_MODE);
    }
    if core.model.trip().is_some() {
        return core.model.reset().map(|()| SlaveReply::Stop).map_err(|_| ErrorCode::TRIPPED);
    }
    if !core.model.is_running() {
        // seed 000: "0x02 Drive in Standby (status information)" (decision: nothing to stop).
        return Err(ErrorCode::STANDBY);
    }
    if param(&core.params, "F-05", 0) == 1 {
        core.model.coast();
    } else {
        core.model.stop();
    }
    Ok(SlaveReply::Stop)
}

/// One frame from the slave session: act, and answer unless it was global.
fn handle(
    core: &mut DriveCore,
    comm: &mut CommWatch,
    version: Version,
    now: Instant,
    incoming: Incoming<'_, drivebus_proto::b800::Request>,
    responder: &mut Responder<'_, B800>,
) {
    let me = core.address;
    let reply = match incoming {
        Incoming::Request { request, .. } => {
            // A valid telegram for this drive (or global): the line is alive.
            core.model.comm_seen(now);
            *comm = CommWatch { last: now, lost: false };
            let reply = execute(core, version, request.cmd).unwrap_or_else(SlaveReply::error);
            Address::new(me).map(|a| Reply::new(a, reply))
        }
        // A wrong checksum (0x95) or an unknown command (0x97) in a frame for this drive.
        Incoming::Rejected { bytes, error } => B800.rejected_reply(bytes, &error, me),
    };
    if let Some(reply) = reply {
        // Ignored for a global frame (seed 000: "There is no reply from the B800s to a global
        // command."); a B800 reply always fits the session's buffer.
        let _ = responder.reply(&reply);
    }
}

impl Device for B800Drive {
    fn receive(&mut self, now: Instant, bytes: &[u8]) {
        self.advance_to(now);
        let B800Drive { core, session, version, comm, .. } = self;
        let version = *version;
        session.handle_input(now, bytes, &mut |t, incoming, responder| {
            handle(core, comm, version, t, incoming, responder)
        });
        self.refresh_trip_log();
    }

    fn poll_transmit(&mut self, now: Instant) -> Option<Vec<u8>> {
        self.session.poll_transmit(now).map(<[u8]>::to_vec)
    }

    fn poll_timeout(&self) -> Option<Instant> {
        self.session.poll_timeout()
    }

    fn advance_to(&mut self, now: Instant) {
        self.sync();
        self.watch_comm(now);
        self.advance_model(now);
        self.refresh_trip_log();
    }

    crate::drive::device_is_a_drive!();
}

impl VirtualDrive for B800Drive {
    fn protocol(&self) -> String {
        PROTOCOL.name().to_string()
    }

    crate::drive::drive_core_at!(core);

    /// `F-12 = 1 keypad`, `F-12 = 0 terminals`, `F-12 = 2 host run/stop`.
    fn control_source(&self) -> String {
        let v = param(&self.core.params, "F-12", 1);
        let text = self.core.params.catalog().get("F-12").and_then(|d| d.choice(v)).unwrap_or("unknown");
        format!("F-12 = {v} {text}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_outside_1_to_63_are_refused() {
        let e = B800Drive::new(0, Instant::ZERO).unwrap_err();
        assert_eq!(e, "a B800 drive address is 1 to 63 (the master sends it + 128), not 0");
        assert!(B800Drive::new(64, Instant::ZERO).is_err());
        let d = B800Drive::new(63, Instant::ZERO).unwrap();
        assert_eq!(d.core().params.get("F-32"), Some(63));
        assert_eq!(d.control_source(), "F-12 = 1 keypad");
    }

    #[test]
    fn settings_follow_the_catalog() {
        let d = B800Drive::new(1, Instant::ZERO).unwrap();
        let s = d.core().model.settings();
        assert_eq!(s.max_hz, 50.0);
        assert_eq!(s.accel, Duration::from_secs(5));
        assert_eq!(s.rated_current_a, 4.1);
        assert_eq!(s.rated_rpm, 1420.0);
    }
}
