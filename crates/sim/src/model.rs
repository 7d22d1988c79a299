//! The motor-and-inverter model every virtual drive shares, whatever protocol it speaks.
//!
//! State (stopped, running, tripped), direction, jog, hardware enable; a setpoint and an output
//! frequency that follows it along the acceleration and deceleration ramps; motor current
//! from a settable load; DC bus voltage; heat-sink temperature; run hours; trips with a log.
//!
//! Time comes from the caller ([`DriveModel::advance_to`]); nothing reads a clock. Frequencies
//! are kept in millihertz and the ramp is integrated exactly (a remainder is carried), so a
//! ramp of 10 s to 50 Hz reaches 40.000 Hz at 8 s of simulated time, not a microsecond before,
//! however the time is sliced.

use std::collections::VecDeque;
use std::time::Duration;

use drivebus_proto::Instant;

/// Whether the motor is driven.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunState {
    /// Ready, output off.
    Stopped,
    /// Output on (ramping or at speed).
    Running,
    /// Decelerating to a stop after a stop command.
    Stopping,
    /// Output off because of a fault; needs a reset.
    Tripped(Trip),
}

/// Motor direction.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rotation {
    /// Forward.
    Forward,
    /// Reverse.
    Reverse,
}

/// Why a drive tripped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Trip {
    /// Output current above the limit.
    OverCurrent,
    /// DC bus voltage above the limit (fast deceleration of a heavy load, high supply).
    OverVoltage,
    /// DC bus voltage below the limit (supply loss).
    UnderVoltage,
    /// Heat sink above its limit.
    OverTemperature,
    /// No valid telegram within the communication time-out (Toshiba f803/f804, FC 8-03/8-04).
    CommunicationTimeout,
    /// An external trip (terminal, emergency stop, or injected by a test).
    External,
}

impl Trip {
    /// A short name.
    pub fn name(self) -> &'static str {
        match self {
            Trip::OverCurrent => "over-current",
            Trip::OverVoltage => "over-voltage",
            Trip::UnderVoltage => "under-voltage",
            Trip::OverTemperature => "over-temperature",
            Trip::CommunicationTimeout => "communication time-out",
            Trip::External => "external trip",
        }
    }

    /// drivebus' number for the trip: 1 over-current, 2 over-voltage, 3 under-voltage, 4
    /// over-temperature, 5 external, 6 communication time-out. It is the generic drive's 2100H
    /// fault code (its manual gives no list), and the code a panel shows for a family without
    /// trip codes of its own.
    pub fn code(self) -> u16 {
        match self {
            Trip::OverCurrent => 1,
            Trip::OverVoltage => 2,
            Trip::UnderVoltage => 3,
            Trip::OverTemperature => 4,
            Trip::External => 5,
            Trip::CommunicationTimeout => 6,
        }
    }
}

/// One entry of the trip log.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TripRecord {
    /// What tripped.
    pub trip: Trip,
    /// When (simulated time).
    pub at: Instant,
    /// Output frequency at the trip, millihertz.
    pub output_mhz: i64,
}

/// The settings the model runs by; each family fills them from its parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ModelSettings {
    /// Time to ramp from 0 to `max_hz`.
    pub accel: Duration,
    /// Time to ramp from `max_hz` to 0.
    pub decel: Duration,
    /// Lowest running frequency (setpoints below are raised to it while running).
    pub min_hz: f64,
    /// Highest frequency (setpoints above are clamped to it).
    pub max_hz: f64,
    /// Jog frequency.
    pub jog_hz: f64,
    /// Motor rated current, amperes.
    pub rated_current_a: f64,
    /// Motor rated speed at `base_hz`, rpm.
    pub rated_rpm: f64,
    /// Motor base frequency, Hz.
    pub base_hz: f64,
    /// Nominal DC bus voltage, volts (about 1.35 x mains).
    pub nominal_dc_v: f64,
    /// Over-current trip threshold as a multiple of rated current.
    pub overcurrent_ratio: f64,
    /// Heat-sink trip temperature, degrees Celsius.
    pub overtemp_c: f64,
}

impl Default for ModelSettings {
    fn default() -> Self {
        ModelSettings {
            accel: Duration::from_secs(10),
            decel: Duration::from_secs(10),
            min_hz: 0.0,
            max_hz: 50.0,
            jog_hz: 5.0,
            rated_current_a: 10.0,
            rated_rpm: 1450.0,
            base_hz: 50.0,
            nominal_dc_v: 540.0,
            overcurrent_ratio: 2.0,
            overtemp_c: 90.0,
        }
    }
}

/// Ambient temperature of the simulated cabinet.
const AMBIENT_C: f64 = 25.0;
/// Thermal time constant of the heat sink.
const THERMAL_TAU_S: f64 = 300.0;
/// Heat-sink temperature rise above ambient at rated current, steady state.
const RISE_AT_RATED_C: f64 = 35.0;
/// Trip log length.
const TRIP_LOG_LEN: usize = 10;

/// One drive's motor, inverter and state.
#[derive(Clone, Debug)]
pub struct DriveModel {
    settings: ModelSettings,
    state: RunState,
    rotation: Rotation,
    jog: bool,
    hardware_enable: bool,
    setpoint_mhz: i64,
    /// Output frequency magnitude, millihertz.
    output_mhz: i64,
    /// Direction the output is actually turning (changes only through zero).
    output_rotation: Rotation,
    /// Carried remainder of the ramp integration (millihertz x microseconds).
    ramp_carry: i128,
    load: f64,
    supply_ratio: f64,
    heatsink_c: f64,
    run_time: Duration,
    now: Instant,
    trip_log: VecDeque<TripRecord>,
    comm_timeout: Option<Duration>,
    last_comm: Instant,
    /// The communication time-out counts only once a first telegram has been seen.
    comm_armed: bool,
}

impl DriveModel {
    /// A stopped drive at `now` with `settings`, hardware enable present.
    pub fn new(settings: ModelSettings, now: Instant) -> Self {
        DriveModel {
            settings,
            state: RunState::Stopped,
            rotation: Rotation::Forward,
            jog: false,
            hardware_enable: true,
            setpoint_mhz: 0,
            output_mhz: 0,
            output_rotation: Rotation::Forward,
            ramp_carry: 0,
            load: 0.5,
            supply_ratio: 1.0,
            heatsink_c: AMBIENT_C,
            run_time: Duration::ZERO,
            now,
            trip_log: VecDeque::with_capacity(TRIP_LOG_LEN),
            comm_timeout: None,
            last_comm: now,
            comm_armed: false,
        }
    }

    /// The settings in force.
    pub fn settings(&self) -> &ModelSettings {
        &self.settings
    }

    /// Changes the settings (a parameter write); the setpoint is clamped to the new limits.
    pub fn set_settings(&mut self, settings: ModelSettings) {
        self.settings = settings;
        self.setpoint_mhz = self.clamp_setpoint(self.setpoint_mhz);
    }

    /// The state.
    pub fn state(&self) -> RunState {
        self.state
    }

    /// True while the output is on (running or ramping to a stop).
    pub fn is_running(&self) -> bool {
        matches!(self.state, RunState::Running | RunState::Stopping)
    }

    /// The trip in force, if tripped.
    pub fn trip(&self) -> Option<Trip> {
        match self.state {
            RunState::Tripped(t) => Some(t),
            _ => None,
        }
    }

    /// The commanded direction.
    pub fn rotation(&self) -> Rotation {
        self.rotation
    }

    /// The direction the motor turns now.
    pub fn output_rotation(&self) -> Rotation {
        self.output_rotation
    }

    /// True while jogging.
    pub fn is_jogging(&self) -> bool {
        self.jog
    }

    /// Hardware enable (safe torque off released).
    pub fn hardware_enable(&self) -> bool {
        self.hardware_enable
    }

    /// Setpoint, Hz.
    pub fn setpoint_hz(&self) -> f64 {
        self.setpoint_mhz as f64 / 1000.0
    }

    /// Output frequency magnitude, Hz.
    pub fn output_hz(&self) -> f64 {
        self.output_mhz as f64 / 1000.0
    }

    /// Output frequency magnitude, millihertz (exact).
    pub fn output_mhz(&self) -> i64 {
        self.output_mhz
    }

    /// Motor speed, rpm (slip included, from the load).
    pub fn motor_rpm(&self) -> f64 {
        let s = &self.settings;
        if s.base_hz <= 0.0 {
            return 0.0;
        }
        let sync = 60.0 * 2.0 * s.base_hz / pole_pairs_x2(s);
        let rated_slip = (sync - s.rated_rpm).max(0.0) / sync;
        let f = self.output_hz();
        (f / s.base_hz) * sync * (1.0 - rated_slip * self.load.clamp(0.0, 2.0))
    }

    /// Motor current, amperes: magnetising current plus the load's share, plus the torque
    /// needed to accelerate (a constant-torque load).
    pub fn current_a(&self) -> f64 {
        if !self.is_running() || self.output_mhz == 0 && self.setpoint_mhz == 0 {
            return 0.0;
        }
        // A constant-torque load: current follows torque, not speed.
        let s = &self.settings;
        let ramping = self.output_mhz != self.target_mhz();
        let accel_share = if ramping { 0.3 } else { 0.0 };
        s.rated_current_a * (0.3 + 0.7 * self.load + accel_share)
    }

    /// DC bus voltage, volts.
    pub fn dc_bus_v(&self) -> f64 {
        let sag = if self.is_running() { 0.02 * self.load } else { 0.0 };
        self.settings.nominal_dc_v * self.supply_ratio * (1.0 - sag)
    }

    /// Output voltage, volts (V/f up to base frequency).
    pub fn output_v(&self) -> f64 {
        let s = &self.settings;
        let ratio = (self.output_hz() / s.base_hz.max(1.0)).min(1.0);
        s.nominal_dc_v / 1.35 * ratio
    }

    /// Heat-sink temperature, degrees Celsius.
    pub fn heatsink_c(&self) -> f64 {
        self.heatsink_c
    }

    /// Time spent running.
    pub fn run_time(&self) -> Duration {
        self.run_time
    }

    /// Run hours.
    pub fn run_hours(&self) -> f64 {
        self.run_time.as_secs_f64() / 3600.0
    }

    /// The load as a fraction of rated torque (0.5 by default).
    pub fn load(&self) -> f64 {
        self.load
    }

    /// Sets the load (fraction of rated torque).
    pub fn set_load(&mut self, load: f64) {
        self.load = load.clamp(0.0, 5.0);
    }

    /// Sets the supply as a fraction of nominal (1.0); below 0.65 the drive trips on
    /// under-voltage while running, above 1.25 on over-voltage.
    pub fn set_supply(&mut self, ratio: f64) {
        self.supply_ratio = ratio.clamp(0.0, 2.0);
    }

    /// Sets the hardware enable input.
    pub fn set_hardware_enable(&mut self, on: bool) {
        self.hardware_enable = on;
        if !on && self.is_running() {
            // Safe torque off: the motor coasts.
            self.coast();
        }
    }

    /// The trip log, oldest first.
    pub fn trip_log(&self) -> impl Iterator<Item = &TripRecord> {
        self.trip_log.iter()
    }

    /// The most recent trips, newest first.
    pub fn recent_trips(&self) -> impl Iterator<Item = &TripRecord> {
        self.trip_log.iter().rev()
    }

    /// Sets the communication time-out (None: off). It runs from the last valid telegram, and
    /// only once a first one has arrived: a drive nobody has talked to yet does not trip.
    pub fn set_comm_timeout(&mut self, timeout: Option<Duration>) {
        self.comm_timeout = timeout;
        self.last_comm = self.now;
    }

    /// A valid telegram for this drive arrived: (re)starts the communication time-out.
    pub fn comm_seen(&mut self, now: Instant) {
        self.last_comm = now;
        self.comm_armed = true;
    }

    /// Sets the setpoint, Hz (clamped to the limits; the sign is ignored).
    pub fn set_setpoint_hz(&mut self, hz: f64) {
        let mhz = (hz.abs() * 1000.0).round() as i64;
        self.setpoint_mhz = self.clamp_setpoint(mhz);
    }

    /// Sets the commanded direction; a running motor ramps through zero to the other side.
    pub fn set_rotation(&mut self, rotation: Rotation) {
        self.rotation = rotation;
    }

    /// Why a run command is refused, if it is.
    pub fn run_refusal(&self) -> Option<RunRefusal> {
        if let RunState::Tripped(t) = self.state {
            return Some(RunRefusal::Tripped(t));
        }
        if !self.hardware_enable {
            return Some(RunRefusal::NoHardwareEnable);
        }
        None
    }

    /// Starts the motor (or keeps it running) toward the setpoint.
    pub fn run(&mut self) -> Result<(), RunRefusal> {
        self.start(false)
    }

    /// Starts jogging at the jog frequency.
    pub fn jog(&mut self) -> Result<(), RunRefusal> {
        self.start(true)
    }

    /// Runs toward the setpoint, or jogs, unless the drive refuses to start.
    fn start(&mut self, jog: bool) -> Result<(), RunRefusal> {
        if let Some(r) = self.run_refusal() {
            return Err(r);
        }
        self.jog = jog;
        self.state = RunState::Running;
        Ok(())
    }

    /// Ramps to a stop.
    pub fn stop(&mut self) {
        if self.is_running() {
            self.state = if self.output_mhz == 0 { RunState::Stopped } else { RunState::Stopping };
        }
        self.jog = false;
    }

    /// Output off at once; the motor coasts (modelled as stopping at once).
    pub fn coast(&mut self) {
        if !matches!(self.state, RunState::Tripped(_)) {
            self.state = RunState::Stopped;
        }
        self.output_mhz = 0;
        self.ramp_carry = 0;
        self.jog = false;
    }

    /// Quick stop: modelled as coast (the decel is so short the difference is invisible to a master).
    pub fn quick_stop(&mut self) {
        self.coast();
    }

    /// Trips the drive now.
    pub fn trip_now(&mut self, trip: Trip) {
        if matches!(self.state, RunState::Tripped(_)) {
            return;
        }
        if self.trip_log.len() == TRIP_LOG_LEN {
            self.trip_log.pop_front();
        }
        self.trip_log.push_back(TripRecord { trip, at: self.now, output_mhz: self.output_mhz });
        self.state = RunState::Tripped(trip);
        self.output_mhz = 0;
        self.ramp_carry = 0;
        self.jog = false;
    }

    /// Resets a trip; fails while the cause persists (temperature still high, supply still out).
    pub fn reset(&mut self) -> Result<(), Trip> {
        let RunState::Tripped(t) = self.state else { return Ok(()) };
        let persists = match t {
            Trip::OverTemperature => self.heatsink_c > self.settings.overtemp_c - 10.0,
            Trip::UnderVoltage => self.supply_ratio < 0.65,
            Trip::OverVoltage => self.supply_ratio > 1.25,
            _ => false,
        };
        if persists {
            return Err(t);
        }
        self.state = RunState::Stopped;
        self.last_comm = self.now;
        Ok(())
    }

    /// The frequency the output is heading for now, millihertz.
    fn target_mhz(&self) -> i64 {
        match self.state {
            RunState::Running if self.jog => (self.settings.jog_hz * 1000.0).round() as i64,
            RunState::Running => {
                if self.output_rotation != self.rotation {
                    0
                } else {
                    self.setpoint_mhz.max((self.settings.min_hz * 1000.0).round() as i64)
                }
            }
            _ => 0,
        }
    }

    fn clamp_setpoint(&self, mhz: i64) -> i64 {
        let max = (self.settings.max_hz * 1000.0).round() as i64;
        mhz.clamp(0, max.max(0))
    }

    /// Advances the simulation to `now`.
    pub fn advance_to(&mut self, now: Instant) {
        if now <= self.now {
            return;
        }
        let dt = now - self.now;
        self.now = now;
        if let (Some(timeout), true) = (self.comm_timeout, self.comm_armed) {
            if now.saturating_since(self.last_comm) >= timeout && !matches!(self.state, RunState::Tripped(_))
            {
                self.trip_now(Trip::CommunicationTimeout);
            }
        }
        if self.is_running() {
            self.run_time += dt;
        }
        self.ramp(dt);
        self.thermal(dt);
        self.protections();
    }

    /// The simulated time the model has reached.
    pub fn now(&self) -> Instant {
        self.now
    }

    fn ramp(&mut self, dt: Duration) {
        // Integrated in nanoseconds with the remainder carried, so the result does not depend
        // on how time is sliced. A reversal ramps down to zero, turns, and spends the rest of
        // the step ramping up the other way.
        let mut left_ns = dt.as_nanos() as i128;
        for _ in 0..4 {
            let target = self.target_mhz();
            if self.output_mhz == target {
                self.ramp_carry = 0;
                let before = self.output_rotation;
                self.settle();
                if self.output_rotation == before || self.target_mhz() == self.output_mhz {
                    return;
                }
                continue;
            }
            if left_ns <= 0 {
                return;
            }
            let max_mhz = ((self.settings.max_hz * 1000.0).round() as i128).max(1);
            let up = target > self.output_mhz;
            let ramp = if up { self.settings.accel } else { self.settings.decel };
            let ramp_ns = (ramp.as_nanos() as i128).max(1);
            let distance = (target - self.output_mhz).unsigned_abs() as i128;
            // Time to cover the distance: max_mhz * t + carry >= distance * ramp_ns.
            let need_ns = ((distance * ramp_ns - self.ramp_carry).max(0) + max_mhz - 1) / max_mhz;
            if need_ns > left_ns {
                let numer = max_mhz * left_ns + self.ramp_carry;
                let delta = (numer / ramp_ns).min(distance) as i64;
                self.ramp_carry = numer % ramp_ns;
                self.output_mhz += if up { delta } else { -delta };
                return;
            }
            self.output_mhz = target;
            self.ramp_carry = 0;
            left_ns -= need_ns;
            self.settle();
        }
    }

    fn settle(&mut self) {
        if self.output_mhz == 0 {
            self.output_rotation = self.rotation;
            if self.state == RunState::Stopping {
                self.state = RunState::Stopped;
            }
        }
    }

    fn thermal(&mut self, dt: Duration) {
        let i = self.current_a() / self.settings.rated_current_a.max(0.1);
        let steady = AMBIENT_C + RISE_AT_RATED_C * i * i;
        let k = 1.0 - (-dt.as_secs_f64() / THERMAL_TAU_S).exp();
        self.heatsink_c += (steady - self.heatsink_c) * k;
    }

    fn protections(&mut self) {
        if matches!(self.state, RunState::Tripped(_)) {
            return;
        }
        let s = self.settings;
        if self.is_running() && self.current_a() > s.rated_current_a * s.overcurrent_ratio {
            self.trip_now(Trip::OverCurrent);
        } else if self.heatsink_c > s.overtemp_c {
            self.trip_now(Trip::OverTemperature);
        } else if self.supply_ratio > 1.25 {
            self.trip_now(Trip::OverVoltage);
        } else if self.is_running() && self.supply_ratio < 0.65 {
            self.trip_now(Trip::UnderVoltage);
        }
    }
}

/// Why the drive will not run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunRefusal {
    /// It is tripped; reset first.
    Tripped(Trip),
    /// The hardware enable input is off.
    NoHardwareEnable,
}

fn pole_pairs_x2(s: &ModelSettings) -> f64 {
    // Poles from rated speed: the synchronous speed just above rated.
    let sync_2pole = 120.0 * s.base_hz / 2.0;
    let mut poles = 2.0;
    while sync_2pole * 2.0 / poles > s.rated_rpm * 1.2 && poles < 12.0 {
        poles += 2.0;
    }
    poles
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(ms: u64) -> Instant {
        Instant::from_millis(ms)
    }

    /// A drive with the default settings, started at time 0 towards `hz`.
    fn started(hz: f64) -> DriveModel {
        let mut m = DriveModel::new(ModelSettings::default(), at(0));
        m.set_setpoint_hz(hz);
        m.run().unwrap();
        m
    }

    /// [`started`] towards `hz`, told to reverse at `ms`.
    fn reversed_at(hz: f64, ms: u64) -> DriveModel {
        let mut m = started(hz);
        m.advance_to(at(ms));
        m.set_rotation(Rotation::Reverse);
        m
    }

    #[test]
    fn ramp_reaches_40_hz_at_8_s_and_not_before() {
        // 10 s acceleration to 50 Hz: 5 Hz/s, so 40 Hz is reached at exactly 8 s.
        let mut m = started(40.0);
        // Slice the time unevenly: the result must not depend on the slicing.
        let mut t = 0u64;
        let mut step = 1u64;
        while t + step < 7_999_999 {
            t += step;
            step = (step * 7 + 3) % 9973 + 1;
            m.advance_to(Instant::from_micros(t));
        }
        m.advance_to(Instant::from_micros(7_999_999));
        assert!(m.output_mhz() < 40_000, "{} mHz at 7.999999 s", m.output_mhz());
        m.advance_to(at(8000));
        assert_eq!(m.output_mhz(), 40_000);
        m.advance_to(at(20_000));
        assert_eq!(m.output_mhz(), 40_000);
    }

    #[test]
    fn decelerates_to_stop_then_reports_stopped() {
        let mut m = started(50.0);
        m.advance_to(at(10_000));
        assert_eq!(m.output_hz(), 50.0);
        m.stop();
        assert_eq!(m.state(), RunState::Stopping);
        m.advance_to(at(15_000));
        assert_eq!(m.output_hz(), 25.0);
        m.advance_to(at(20_000));
        assert_eq!(m.state(), RunState::Stopped);
        assert_eq!(m.current_a(), 0.0);
    }

    #[test]
    fn reversing_ramps_through_zero() {
        let mut m = reversed_at(25.0, 5000);
        m.advance_to(at(7500));
        assert_eq!(m.output_hz(), 12.5);
        assert_eq!(m.output_rotation(), Rotation::Forward);
        m.advance_to(at(10_000));
        assert_eq!(m.output_rotation(), Rotation::Reverse);
        m.advance_to(at(15_000));
        assert_eq!((m.output_hz(), m.output_rotation()), (25.0, Rotation::Reverse));
    }

    #[test]
    fn trips_refuse_run_until_reset_and_are_logged() {
        let mut m = started(30.0);
        m.advance_to(at(3000));
        m.set_load(4.0);
        m.advance_to(at(3001));
        assert_eq!(m.trip(), Some(Trip::OverCurrent));
        assert_eq!(m.output_hz(), 0.0);
        assert_eq!(m.run(), Err(RunRefusal::Tripped(Trip::OverCurrent)));
        let log: Vec<_> = m.trip_log().collect();
        assert_eq!(log.len(), 1);
        assert_eq!(log[0].output_mhz, 15_005, "output at the trip, 3.001 s into a 5 Hz/s ramp");
        m.set_load(0.5);
        m.reset().unwrap();
        assert!(m.run().is_ok());
    }

    #[test]
    fn reversal_in_one_long_step_continues_past_zero() {
        let mut m = reversed_at(20.0, 4000);
        // 4 s down to zero, then 4 s up to 20 Hz the other way: all in one step.
        m.advance_to(at(12_000));
        assert_eq!((m.output_mhz(), m.output_rotation()), (20_000, Rotation::Reverse));
        // Half way: sliced or not, the same.
        let mut n = reversed_at(20.0, 4000);
        n.advance_to(at(10_000));
        assert_eq!((n.output_mhz(), n.output_rotation()), (10_000, Rotation::Reverse));
    }

    #[test]
    fn communication_timeout_waits_for_a_first_telegram() {
        let mut m = DriveModel::new(ModelSettings::default(), at(0));
        m.set_comm_timeout(Some(Duration::from_secs(1)));
        m.advance_to(at(60_000));
        assert_eq!(m.trip(), None);
    }

    #[test]
    fn communication_timeout_trips() {
        let mut m = DriveModel::new(ModelSettings::default(), at(0));
        m.set_comm_timeout(Some(Duration::from_secs(2)));
        m.comm_seen(at(0));
        m.advance_to(at(1500));
        m.comm_seen(at(1500));
        m.advance_to(at(3000));
        assert_eq!(m.trip(), None);
        m.advance_to(at(3500));
        assert_eq!(m.trip(), Some(Trip::CommunicationTimeout));
    }

    #[test]
    fn undervoltage_and_overtemperature() {
        let mut m = started(50.0);
        m.set_supply(0.5);
        m.advance_to(at(10));
        assert_eq!(m.trip(), Some(Trip::UnderVoltage));
        assert_eq!(m.reset(), Err(Trip::UnderVoltage));
        m.set_supply(1.0);
        m.reset().unwrap();

        let mut m = DriveModel::new(ModelSettings { overcurrent_ratio: 10.0, ..Default::default() }, at(0));
        m.set_setpoint_hz(50.0);
        m.set_load(1.8);
        m.run().unwrap();
        m.advance_to(at(3_600_000));
        assert_eq!(m.trip(), Some(Trip::OverTemperature));
        assert!(m.run_hours() > 0.0);
    }

    #[test]
    fn hardware_enable_missing_refuses_run() {
        let mut m = DriveModel::new(ModelSettings::default(), at(0));
        m.set_hardware_enable(false);
        assert_eq!(m.run(), Err(RunRefusal::NoHardwareEnable));
    }

    #[test]
    fn rpm_follows_frequency_with_slip() {
        let mut m = started(50.0);
        m.advance_to(at(10_000));
        let rpm = m.motor_rpm();
        assert!(rpm > 1440.0 && rpm < 1500.0, "{rpm}");
    }
}
