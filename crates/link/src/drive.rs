//! The unified drive API: the same operations on every family, async first, with a blocking
//! wrapper for scripts and simple tools.
//!
//! ```no_run
//! # async fn demo() -> Result<(), drivebus_link::drive::Error> {
//! use drivebus_link::drive::{open, Drive};
//! use drivebus_drive::Family;
//! use drivebus_proto::protocol::WireProtocol;
//! let bus = open("/dev/ttyUSB0", WireProtocol::ModbusRtu, 9600, "8N2".parse().unwrap()).await?;
//! let drive = Drive::new(bus, drivebus_drive::profile::for_drive(Family::Generic, WireProtocol::ModbusRtu, 1)?);
//! drive.set_speed(40.0).await?;
//! drive.run().await?;
//! let status = drive.status().await?;
//! println!("{:?} Hz", status.output_hz);
//! # Ok(()) }
//! ```
//!
//! Blocking:
//!
//! ```no_run
//! use drivebus_link::drive::BlockingDrive;
//! use drivebus_drive::Family;
//! use drivebus_proto::protocol::WireProtocol;
//! let drive = BlockingDrive::open("tcp://10.0.0.5:4001", Family::Danfoss, WireProtocol::DanfossFc, 3, 9600, "8E1".parse().unwrap()).unwrap();
//! drive.run().unwrap();
//! ```

use std::fmt;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use drivebus_drive::profile::{self, DriveError, DriveStatus, Operation, Outcome, Plan, Profile};
use drivebus_drive::{Family, ParamDef, Storage};
use drivebus_proto::line::CharFormat;
use drivebus_proto::protocol::WireProtocol;

use crate::blocking::BlockingBus;
use crate::bus::{BusConfig, BusError, BusStats, Priority};
use crate::owner::Bus;
use crate::port::Port;
use crate::port_link::PortLink;

/// Why an operation on a drive failed.
#[derive(Debug)]
pub enum Error {
    /// The drive said no, or the value was out of range, or the operation does not exist.
    Drive(DriveError),
    /// No answer or a broken link.
    Bus(BusError),
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::Drive(e) => e.fmt(f),
            Error::Bus(e) => e.fmt(f),
        }
    }
}

impl std::error::Error for Error {}

impl From<DriveError> for Error {
    fn from(e: DriveError) -> Self {
        Error::Drive(e)
    }
}

impl From<BusError> for Error {
    fn from(e: BusError) -> Self {
        Error::Bus(e)
    }
}

/// Opens `port` (a device path or `tcp://host:port`) and starts a bus owner for `protocol`.
pub async fn open(port: &str, protocol: WireProtocol, baud: u32, format: CharFormat) -> Result<Bus, Error> {
    open_with(port, BusConfig::new(protocol, baud, format)).await
}

/// Opens `port` and starts a bus owner with `config`: on a Modbus TCP bus with
/// `max_in_flight` above 1, the pipelined owner ([`Bus::spawn_pipelined`]) over a plain TCP
/// connection to the server.
pub async fn open_with(port: &str, config: BusConfig) -> Result<Bus, Error> {
    let port = if config.modbus_tcp {
        Port::modbus_tcp(port).map_err(BusError::Link)?
    } else {
        Port::parse(port, config.baud, config.format, config.rs485)
    };
    if let (Port::ModbusTcp(addr), true) = (&port, config.max_in_flight > 1) {
        let link =
            PortLink::open(Port::Tcp(addr.clone())).await.map_err(|e| BusError::Link(e.to_string()))?;
        return Ok(Bus::spawn_pipelined(link, config)?);
    }
    let link = PortLink::open(port).await.map_err(|e| BusError::Link(e.to_string()))?;
    Ok(Bus::spawn(link, config)?)
}

/// How often a drive's status reads its set-up values again (the values a profile reads once
/// to decode a status: Danfoss 3-00, 3-02, 3-03; Toshiba FE70, f875–f879 in TIP binary mode):
/// a change made on the drive's panel shows within this time, and a standby gateway started
/// after this one learns them within it ([`Profile::refresh_setup`]).
pub const SETUP_REFRESH: Duration = Duration::from_secs(30);

/// One drive on a bus, spoken to through its family's profile.
#[derive(Clone)]
pub struct Drive {
    bus: Bus,
    profile: Arc<dyn Profile>,
    timeout: Option<Duration>,
    priority: Priority,
    /// Whose on-demand reads these are (the bus serves clients in turn).
    client: Arc<str>,
    /// When a status last read the set-up values (shared by the drive's twins).
    setup_read: Arc<Mutex<Option<tokio::time::Instant>>>,
}

impl Drive {
    /// A drive reached through `bus` with `profile`.
    pub fn new(bus: Bus, profile: Box<dyn Profile>) -> Self {
        Drive {
            bus,
            profile: Arc::from(profile),
            timeout: None,
            priority: Priority::Command,
            client: Arc::from(""),
            setup_read: Arc::default(),
        }
    }

    /// The same drive, with the same profile (so what a command teaches it, a setpoint or a
    /// scaling, shows in the next poll), whose requests are polls that wait behind commands.
    pub fn polling_twin(&self) -> Self {
        Drive { priority: Priority::Poll, ..self.clone() }
    }

    /// The same drive, whose requests are on-demand reads of `client` (an address, a
    /// session): they share the bus with polling, in turn with other clients' reads, and are
    /// refused with [`BusError::Busy`] beyond the bus's queue ([`crate::fair`]).
    pub fn on_demand_for(&self, client: &str) -> Self {
        Drive { priority: Priority::OnDemand, client: Arc::from(client), ..self.clone() }
    }

    /// The same drive, whose requests are a scan's probes ([`Priority::Scan`]): sent only when
    /// nothing else waits on the bus, once, leaving the address's health alone.
    pub fn scanning(&self) -> Self {
        Drive { priority: Priority::Scan, ..self.clone() }
    }

    /// Sets this drive's response timeout (the bus default otherwise).
    pub fn with_timeout(mut self, timeout: Duration) -> Self {
        self.timeout = Some(timeout);
        self
    }

    /// Marks this drive's requests as polling (they wait behind commands).
    pub fn polling(mut self) -> Self {
        self.priority = Priority::Poll;
        self
    }

    /// The profile.
    pub fn profile(&self) -> &dyn Profile {
        self.profile.as_ref()
    }

    /// The bus.
    pub fn bus(&self) -> &Bus {
        &self.bus
    }

    /// Runs `op` to completion.
    pub async fn execute(&self, op: &Operation) -> Result<Outcome, Error> {
        self.run_plan(self.profile.plan(op)?).await
    }

    /// Runs `plan` to completion.
    async fn run_plan(&self, mut plan: Box<dyn Plan>) -> Result<Outcome, Error> {
        let this = self;
        profile::run(&mut *plan, move |exchange| async move {
            let address = this.profile.address();
            Ok(this.bus.transact_for(&this.client, address, exchange, this.priority, this.timeout).await?)
        })
        .await
    }

    /// The drive's state. Every [`SETUP_REFRESH`] a status also reads the drive's set-up
    /// values again.
    ///
    /// On a standby's bus that never heard a set-up value the status reads (its master does not
    /// read it, [`BusError::Unheard`]), the status is read again without the set-up values
    /// ([`Profile::plan_status_without_setup`]): values that need them are unknown (`None`).
    pub async fn status(&self) -> Result<DriveStatus, Error> {
        self.refresh_setup_when_due();
        match self.execute(&Operation::Status).await {
            Err(Error::Bus(e @ BusError::Unheard(_))) => match self.profile.plan_status_without_setup() {
                Some(plan) => status_of(self.run_plan(plan?).await?),
                None => Err(e.into()),
            },
            outcome => status_of(outcome?),
        }
    }

    /// Tells the profile to read its set-up values again when [`SETUP_REFRESH`] has passed
    /// since the first status (which reads them anyway) or the last refresh.
    fn refresh_setup_when_due(&self) {
        let now = tokio::time::Instant::now();
        let mut last = self.setup_read.lock().unwrap_or_else(|p| p.into_inner());
        match *last {
            Some(at) if now.saturating_duration_since(at) < SETUP_REFRESH => {}
            Some(_) => {
                self.profile.refresh_setup();
                *last = Some(now);
            }
            None => *last = Some(now),
        }
    }

    /// Starts the motor.
    pub async fn run(&self) -> Result<(), Error> {
        self.execute(&Operation::Run).await.map(|_| ())
    }

    /// Ramps to a stop.
    pub async fn stop(&self) -> Result<(), Error> {
        self.execute(&Operation::Stop).await.map(|_| ())
    }

    /// Reverses the direction.
    pub async fn reverse(&self) -> Result<(), Error> {
        self.execute(&Operation::Reverse).await.map(|_| ())
    }

    /// Runs at the jog speed.
    pub async fn jog(&self) -> Result<(), Error> {
        self.execute(&Operation::Jog).await.map(|_| ())
    }

    /// Resets a fault.
    pub async fn reset(&self) -> Result<(), Error> {
        self.execute(&Operation::Reset).await.map(|_| ())
    }

    /// Sets the speed setpoint in Hz (checked against the drive's limits first).
    pub async fn set_speed(&self, hz: f64) -> Result<(), Error> {
        self.execute(&Operation::SetSpeed(hz)).await.map(|_| ())
    }

    /// Reads a parameter by the manual's name: its raw value and definition.
    pub async fn read_param(&self, name: &str) -> Result<(i64, ParamDef), Error> {
        let def = self.profile.param(name)?.clone();
        param_of(self.execute(&Operation::ReadParam(name.to_string())).await?, def)
    }

    /// Writes a parameter from a value in its unit (`"50"`, `"50 Hz"`, a choice's number).
    pub async fn write_param(&self, name: &str, value: &str, storage: Storage) -> Result<i64, Error> {
        let (op, raw) = param_write(self.profile.as_ref(), name, value, storage)?;
        self.execute(&op).await?;
        Ok(raw)
    }

    /// Writes a parameter's raw value (as the drive holds it), checked against its limits first.
    pub async fn write_param_raw(&self, name: &str, raw: i64, storage: Storage) -> Result<(), Error> {
        let def = self.profile.param(name)?;
        def.check(raw).map_err(|e| DriveError::OutOfRange(e.to_string()))?;
        self.execute(&Operation::WriteParam { name: name.to_string(), raw, storage }).await.map(|_| ())
    }
}

/// What a scan's probe of an address found ([`probe`]).
#[derive(Clone, Debug, PartialEq)]
pub enum Probe {
    /// A drive of the profile's family: its state.
    Status(DriveStatus),
    /// Something at the address refused the status read: it speaks the protocol, but on a
    /// protocol several families speak it may be another family's drive.
    Refused {
        /// The code it answered with.
        code: u32,
        /// What the code means.
        meaning: String,
    },
    /// Something answered with a reply that made no sense for this family.
    Odd(String),
}

impl Probe {
    /// How the find is told: `stopped`, `running at 40.00 Hz`, `answers (refused status: ...)`.
    pub fn note(&self) -> String {
        match self {
            Probe::Status(s) => format!(
                "{}{}",
                if s.running { "running" } else { "stopped" },
                s.output_hz.map(|h| format!(" at {h:.2} Hz")).unwrap_or_default()
            ),
            Probe::Refused { code, meaning } => format!("answers (refused status: {code}, {meaning})"),
            Probe::Odd(e) => format!("answers oddly: {e}"),
        }
    }

    /// A refusal on `protocol` when more than one family speaks it (the built-in families and
    /// the template kinds registered): the drive may be another family's, refusing this
    /// family's map (a find only where no family read its status).
    pub fn tentative(&self, protocol: WireProtocol) -> bool {
        matches!(self, Probe::Refused { .. })
            && Family::ALL
                .iter()
                .copied()
                .chain(drivebus_drive::template::registered())
                .filter(|f| f.protocols().contains(&protocol))
                .count()
                > 1
    }
}

/// Probes `drive`'s address with a status read: what answered there, or `None` when nothing
/// did (no answer, a damaged one, the link down).
pub async fn probe(drive: &Drive) -> Option<Probe> {
    match drive.status().await {
        Ok(s) => Some(Probe::Status(s)),
        // A refusal is an answer: something with this address speaks the protocol.
        Err(Error::Drive(DriveError::Refused { code, meaning, .. })) => {
            Some(Probe::Refused { code, meaning })
        }
        Err(Error::Drive(DriveError::Protocol(e))) => Some(Probe::Odd(e)),
        Err(_) => None,
    }
}

/// The same API without async, for scripts and single-threaded programs: runs on a
/// [`BlockingBus`] in the calling thread (no runtime).
pub struct BlockingDrive {
    bus: Mutex<BlockingBus>,
    profile: Box<dyn Profile>,
    timeout: Option<Duration>,
}

impl BlockingDrive {
    /// Opens `port` and speaks to the drive at `address` of `family` with `protocol`.
    pub fn open(
        port: &str,
        family: Family,
        protocol: WireProtocol,
        address: u8,
        baud: u32,
        format: CharFormat,
    ) -> Result<Self, Error> {
        let profile = drivebus_drive::profile::for_drive(family, protocol, address)?;
        let bus = BlockingBus::open(port, BusConfig::new(protocol, baud, format))?;
        Ok(Self::new(bus, profile))
    }

    /// A drive with `profile` on `bus`.
    pub fn new(bus: BlockingBus, profile: Box<dyn Profile>) -> Self {
        BlockingDrive { bus: Mutex::new(bus), profile, timeout: None }
    }

    /// This drive's response timeout instead of the bus's.
    pub fn with_timeout(mut self, timeout: Duration) -> Self {
        self.timeout = Some(timeout);
        self
    }

    /// The drive's profile.
    pub fn profile(&self) -> &dyn Profile {
        self.profile.as_ref()
    }

    /// The bus's counts so far.
    pub fn stats(&self) -> BusStats {
        self.bus.lock().unwrap_or_else(|p| p.into_inner()).stats()
    }

    /// Runs `op` to its end: one transaction after another, as the profile plans them.
    pub fn execute(&self, op: &Operation) -> Result<Outcome, Error> {
        let mut plan = self.profile.plan(op)?;
        let mut bus = self.bus.lock().unwrap_or_else(|p| p.into_inner());
        let address = self.profile.address();
        profile::run_blocking(&mut *plan, |exchange| {
            Ok(bus.transact(address, &exchange, Priority::Command, self.timeout)?)
        })
    }

    /// See [`Drive::status`].
    pub fn status(&self) -> Result<DriveStatus, Error> {
        status_of(self.execute(&Operation::Status)?)
    }
    /// See [`Drive::run`].
    pub fn run(&self) -> Result<(), Error> {
        self.execute(&Operation::Run).map(|_| ())
    }
    /// See [`Drive::stop`].
    pub fn stop(&self) -> Result<(), Error> {
        self.execute(&Operation::Stop).map(|_| ())
    }
    /// See [`Drive::reverse`].
    pub fn reverse(&self) -> Result<(), Error> {
        self.execute(&Operation::Reverse).map(|_| ())
    }
    /// See [`Drive::jog`].
    pub fn jog(&self) -> Result<(), Error> {
        self.execute(&Operation::Jog).map(|_| ())
    }
    /// See [`Drive::reset`].
    pub fn reset(&self) -> Result<(), Error> {
        self.execute(&Operation::Reset).map(|_| ())
    }
    /// See [`Drive::set_speed`].
    pub fn set_speed(&self, hz: f64) -> Result<(), Error> {
        self.execute(&Operation::SetSpeed(hz)).map(|_| ())
    }
    /// See [`Drive::read_param`].
    pub fn read_param(&self, name: &str) -> Result<(i64, ParamDef), Error> {
        let def = self.profile.param(name)?.clone();
        param_of(self.execute(&Operation::ReadParam(name.to_string()))?, def)
    }
    /// See [`Drive::write_param`].
    pub fn write_param(&self, name: &str, value: &str, storage: Storage) -> Result<i64, Error> {
        let (op, raw) = param_write(self.profile.as_ref(), name, value, storage)?;
        self.execute(&op)?;
        Ok(raw)
    }
}

/// The status in the outcome of [`Operation::Status`].
fn status_of(outcome: Outcome) -> Result<DriveStatus, Error> {
    match outcome {
        Outcome::Status(s) => Ok(s),
        other => Err(DriveError::Protocol(format!("a status read gave {other:?}")).into()),
    }
}

/// The raw value in the outcome of [`Operation::ReadParam`], with the parameter's definition.
fn param_of(outcome: Outcome, def: ParamDef) -> Result<(i64, ParamDef), Error> {
    match outcome {
        Outcome::Param(raw) => Ok((raw, def)),
        other => Err(DriveError::Protocol(format!("a parameter read gave {other:?}")).into()),
    }
}

/// The write of `value` (in the parameter's unit) to parameter `name`, and its raw value.
fn param_write(
    profile: &dyn Profile,
    name: &str,
    value: &str,
    storage: Storage,
) -> Result<(Operation, i64), Error> {
    let def = profile.param(name)?;
    let raw = def.parse_value(value).map_err(|e| DriveError::OutOfRange(e.to_string()))?;
    Ok((Operation::WriteParam { name: name.to_string(), raw, storage }, raw))
}
