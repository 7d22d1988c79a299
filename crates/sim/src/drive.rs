//! What every virtual drive has, whatever its family: the motor model, the parameter values,
//! the address, the response time, and a snapshot for the control interface.
//!
//! A family (`family/`) wraps a [`DriveCore`] with its protocol behaviour and implements
//! [`VirtualDrive`] (and so [`Device`], to sit on the virtual line of `bus.rs`).

use std::time::Duration;

use drivebus_drive::{Family, ParamStore};
use drivebus_proto::Instant;
use serde::Serialize;

use drivebus_drive::profile::Fault;

use crate::model::{DriveModel, ModelSettings, Rotation, RunRefusal, RunState, Trip};

/// The state shared by every family.
#[derive(Clone, Debug)]
pub struct DriveCore {
    /// Motor, ramps, trips.
    pub model: DriveModel,
    /// Parameter values and EEPROM write counts.
    pub params: ParamStore,
    /// The drive's number on the bus.
    pub address: u8,
    /// Time from the end of a request to the start of the reply.
    pub response_delay: Duration,
}

impl DriveCore {
    /// A stopped drive numbered `address` with its family's default parameters.
    pub fn new(params: ParamStore, settings: ModelSettings, address: u8, now: Instant) -> Self {
        DriveCore {
            model: DriveModel::new(settings, now),
            params,
            address,
            response_delay: Duration::from_millis(5),
        }
    }
}

/// One row of the trip log, for the control interface.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TripEntry {
    /// What tripped.
    pub trip: String,
    /// Simulated time of the trip, seconds since the simulation started.
    pub at_s: f64,
    /// Output frequency at the trip, Hz.
    pub output_hz: f64,
}

/// A virtual drive's state as the control interface shows it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DriveSnapshot {
    /// `generic`, `toshiba`, `danfoss` or `b800`.
    pub family: String,
    /// The drive's number on the bus.
    pub address: u8,
    /// The wire protocols it answers, joined by `+` (`modbus-rtu`, `toshiba-ascii+toshiba-binary`, ...).
    pub protocol: String,
    /// `stopped`, `running`, `stopping` or `tripped`.
    pub state: String,
    /// `forward` or `reverse` (commanded).
    pub direction: String,
    /// True while jogging.
    pub jog: bool,
    /// Hardware enable input.
    pub hardware_enable: bool,
    /// Where run commands come from (the family's setting, in its own words).
    pub control_source: String,
    /// Setpoint, Hz.
    pub setpoint_hz: f64,
    /// Output frequency, Hz.
    pub output_hz: f64,
    /// Motor current, A.
    pub current_a: f64,
    /// DC bus voltage, V.
    pub dc_bus_v: f64,
    /// Heat-sink temperature, degC.
    pub heatsink_c: f64,
    /// Run hours.
    pub run_hours: f64,
    /// Load, fraction of rated torque.
    pub load: f64,
    /// The trip in force.
    pub trip: Option<String>,
    /// The trip log, oldest first.
    pub trip_log: Vec<TripEntry>,
    /// EEPROM writes since start, all parameters.
    pub eeprom_writes: u64,
    /// True when the drive is silenced by fault injection.
    pub silent: bool,
    /// `master` when the drive is the line's bus master (it broadcasts its run/stop and
    /// frequency to the other drives); absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub role: Option<String>,
    /// What the drive's panel display shows now (`drivebus_drive::panel`).
    pub display: String,
}

/// A device on the virtual line (`bus.rs`): it hears every byte and may answer (a virtual
/// drive, a drive acting as bus master, a test's echo).
pub trait Device {
    /// Bytes that arrived from the line at `now` (in order, all of them whole characters).
    fn receive(&mut self, now: Instant, bytes: &[u8]);
    /// The line has been quiet for t3.5 after the last byte (Modbus RTU frame end).
    fn silence(&mut self, now: Instant) {
        let _ = now;
    }
    /// Bytes to put on the line now, if an answer is due.
    fn poll_transmit(&mut self, now: Instant) -> Option<Vec<u8>>;
    /// When the device next needs [`Device::poll_transmit`] or [`Device::advance_to`].
    fn poll_timeout(&self) -> Option<Instant>;
    /// Lets the device's own state (a motor ramp) reach `now`.
    fn advance_to(&mut self, now: Instant) {
        let _ = now;
    }
    /// This device as a virtual drive, if it is one (for the control interface).
    fn as_drive(&self) -> Option<&dyn VirtualDrive> {
        None
    }
    /// This device as a virtual drive, mutable.
    fn as_drive_mut(&mut self) -> Option<&mut dyn VirtualDrive> {
        None
    }
}

/// Fills in [`Device::as_drive`] and [`Device::as_drive_mut`] inside the `impl Device` of a
/// type that is a [`VirtualDrive`]: the device is its own drive.
macro_rules! device_is_a_drive {
    () => {
        fn as_drive(&self) -> Option<&dyn $crate::drive::VirtualDrive> {
            Some(self)
        }

        fn as_drive_mut(&mut self) -> Option<&mut dyn $crate::drive::VirtualDrive> {
            Some(self)
        }
    };
}
pub(crate) use device_is_a_drive;

/// Fills in [`VirtualDrive::core`] and [`VirtualDrive::core_mut`] inside the `impl VirtualDrive`
/// of a type whose [`DriveCore`] is the field at `path` (`core`, `state.core`).
macro_rules! drive_core_at {
    ($($path:ident).+) => {
        fn core(&self) -> &$crate::drive::DriveCore {
            &self.$($path).+
        }

        fn core_mut(&mut self) -> &mut $crate::drive::DriveCore {
            &mut self.$($path).+
        }
    };
}
pub(crate) use drive_core_at;

/// A virtual drive: a [`Device`] with a model and parameters that a control interface can
/// inspect and disturb.
pub trait VirtualDrive: Device + Send {
    /// The family: that of its parameter catalog.
    fn family(&self) -> Family {
        self.core().params.catalog().family()
    }
    /// The wire protocol it answers, as a user would name it.
    fn protocol(&self) -> String;
    /// The shared state.
    fn core(&self) -> &DriveCore;
    /// The shared state, mutable (control interface, tests).
    fn core_mut(&mut self) -> &mut DriveCore;
    /// Where run commands come from, in the family's words (`F-12 = 1 keypad`, ...).
    fn control_source(&self) -> String;
    /// Switches the drive off and on at `now` (settings that take effect at power-up, such as
    /// Toshiba's f829 protocol selection, do). Default: the motor coasts and a trip whose cause
    /// is gone clears.
    fn power_cycle(&mut self, now: Instant) {
        let model = &mut self.core_mut().model;
        model.advance_to(now);
        model.coast();
        let _ = model.reset();
    }
    /// Sets parameter `name` from a value in its unit (`"2"`, `"50 Hz"`), as the keypad would:
    /// range and read-only checks apply, nothing counts as a bus write.
    fn set_param(&mut self, name: &str, value: &str) -> Result<(), String> {
        set_param_as_keypad(self.core_mut(), name, value)
    }
    /// Presses the keypad's RUN (`true`) or STOP (`false`) key. Default: STOP ramps the motor
    /// down; RUN starts it unless the model refuses (tripped, no hardware enable). Families
    /// whose run source parameter can exclude the keypad check it first.
    fn press_run(&mut self, run: bool) -> Result<(), String> {
        let model = &mut self.core_mut().model;
        if !run {
            model.stop();
            return Ok(());
        }
        model.run().map_err(|why| match why {
            RunRefusal::Tripped(t) => {
                format!("the drive does not start: it is tripped ({}); reset it first", t.name())
            }
            RunRefusal::NoHardwareEnable => {
                "the drive does not start: its hardware enable input is off".to_string()
            }
        })
    }
    /// Sets the keypad frequency setting, Hz (the frequency a drive running from its keypad
    /// turns at). Default: not simulated for this family.
    fn set_keypad_hz(&mut self, hz: f64) -> Result<(), String> {
        let _ = hz;
        Err(format!(
            "a simulated {} drive has no keypad frequency setting; set its parameters instead",
            self.family()
        ))
    }
    /// What the panel shows for `trip`, code and text. Default: drivebus' number of the trip
    /// ([`Trip::code`]) and its name; a family with trip codes of its own says its own.
    fn panel_fault(&self, trip: Trip) -> Fault {
        Fault { code: u32::from(trip.code()), text: trip.name().to_string() }
    }
    /// The drive's state for the control interface.
    fn snapshot(&self) -> DriveSnapshot {
        let display = panel_display(self);
        DriveSnapshot {
            display,
            ..snapshot_of(self.core(), self.family(), self.protocol(), self.control_source())
        }
    }
}

/// Builds a snapshot from the shared state.
pub fn snapshot_of(
    core: &DriveCore,
    family: Family,
    protocol: String,
    control_source: String,
) -> DriveSnapshot {
    let m = &core.model;
    let state = match m.state() {
        RunState::Stopped => "stopped",
        RunState::Running => "running",
        RunState::Stopping => "stopping",
        RunState::Tripped(_) => "tripped",
    };
    let round = |v: f64, d: i32| (v * 10f64.powi(d)).round() / 10f64.powi(d);
    DriveSnapshot {
        family: family.to_string(),
        address: core.address,
        protocol,
        state: state.into(),
        direction: match m.rotation() {
            Rotation::Forward => "forward".into(),
            Rotation::Reverse => "reverse".into(),
        },
        jog: m.is_jogging(),
        hardware_enable: m.hardware_enable(),
        control_source,
        setpoint_hz: round(m.setpoint_hz(), 3),
        output_hz: round(m.output_hz(), 3),
        current_a: round(m.current_a(), 2),
        dc_bus_v: round(m.dc_bus_v(), 1),
        heatsink_c: round(m.heatsink_c(), 1),
        run_hours: round(m.run_hours(), 4),
        load: m.load(),
        trip: m.trip().map(|t| t.name().to_string()),
        trip_log: m
            .trip_log()
            .map(|r| TripEntry {
                trip: r.trip.name().into(),
                at_s: r.at.as_nanos() as f64 / 1e9,
                output_hz: r.output_mhz as f64 / 1000.0,
            })
            .collect(),
        eeprom_writes: core.params.total_eeprom_writes(),
        silent: false,
        role: None,
        display: String::new(),
    }
}

/// What the panel of `drive` shows now (see `drivebus_drive::panel`): a Toshiba drive with
/// FA10 = 1 shows the LED data FA11/FA12; otherwise the trip in force
/// ([`VirtualDrive::panel_fault`]), or the frequency.
pub fn panel_display<D: VirtualDrive + ?Sized>(drive: &D) -> String {
    use drivebus_drive::panel;
    use drivebus_drive::profile::DriveStatus;
    let (family, core) = (drive.family(), drive.core());
    let p = |n: u32| core.params.get(n).unwrap_or(0);
    if family == Family::Toshiba && p(0xFA10) == 1 {
        return panel::led_text(p(0xFA11) as u16, p(0xFA12) as u16);
    }
    let m = &core.model;
    let fault = m.trip().map(|t| drive.panel_fault(t));
    let status = DriveStatus {
        address: core.address,
        running: m.is_running(),
        direction: None,
        output_hz: Some(m.output_hz()),
        setpoint_hz: Some(m.setpoint_hz()),
        current_a: None,
        fault,
        values: Vec::new(),
    };
    panel::display(family, &status)
}

/// Sets parameter `name` of `core` from a value in its unit, as the keypad would (range and
/// read-only checks apply, nothing counts as a bus write): the body of
/// [`VirtualDrive::set_param`], for families that re-derive their state afterwards.
pub fn set_param_as_keypad(core: &mut DriveCore, name: &str, value: &str) -> Result<(), String> {
    let def = core
        .params
        .catalog()
        .get(name)
        .ok_or_else(|| format!("no parameter {name:?} in the catalog"))?
        .clone();
    let raw = def.parse_value(value).map_err(|e| e.to_string())?;
    let running = core.model.is_running();
    core.params.set(def.name.as_str(), raw, drivebus_drive::Storage::Ram, running).map_err(|e| e.to_string())
}
