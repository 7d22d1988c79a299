//! The running gateway: a bus owner and a poll scheduler per bus, a state cache where every
//! value carries its age, commands that go ahead of polling and are answered only when the drive
//! confirmed, linkage rules, events to the store and to live subscribers.
//!
//! Every front end (HTTP, Modbus TCP, MQTT, the dashboard) goes through [`Gateway`]: reads come
//! from the cache ([`Gateway::drive_view`], [`Gateway::registers`]) and never touch a bus;
//! writes go through [`Gateway::command`], which checks the lock, sends the command through the
//! bus owner and writes the audit trail before it answers.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicU8, Ordering};
use std::sync::{Arc, Mutex, RwLock};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use drivebus_drive::profile::{CodeSpace, DriveError, DriveStatus};
use drivebus_drive::{Family, ParamDef, Storage};
use drivebus_link::drive::{Drive, Error as LinkError};
use drivebus_link::owner::{Bus, BusConfig as OwnerConfig, BusError, BusStats};
use drivebus_proto::protocol::WireProtocol;
#[cfg(feature = "virtual")]
use drivebus_sim::bus::VirtualLine;
use drivebus_store::{Event, EventKind, Sample, Store};
use serde::Serialize;
use serde_json::json;
use tokio::sync::{broadcast, Notify};

use crate::config::{BusConfig, DriveConfig, GatewayConfig};
use crate::refusals::{Refusals, Refused, Seen};
#[cfg(feature = "virtual")]
use drivebus_link::port::VirtualPort;
use drivebus_link::port::{Port as LinkPort, SerialSettings};
use drivebus_link::PortLink;

/// Unix time now, ms.
pub fn unix_ms() -> i64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_millis() as i64)
}

/// Most characters of a message (an error, an audit result) that may quote a user's value.
pub const MAX_MESSAGE_CHARS: usize = 512;

/// The largest speed, Hz, a command may ask for; beyond it the command is refused before any
/// drive's profile sees it (no drive runs at 100 kHz; `1e308` is not worth 309 digits).
pub const MAX_SPEED_HZ: f64 = 100_000.0;

/// Failed logins from one address in a minute after which its requests with a token get 429
/// until the minute is over.
pub const MAX_LOGIN_FAILURES: u64 = 10;

/// A command to a drive.
#[derive(Clone, Debug, PartialEq)]
pub enum Command {
    /// Start.
    Run,
    /// Ramp to a stop.
    Stop,
    /// Reverse the direction.
    Reverse,
    /// Run at the jog speed.
    Jog,
    /// Reset a fault.
    Reset,
    /// Set the speed setpoint, Hz.
    Speed(f64),
    /// Write a parameter by the manual's name, value in its unit.
    SetParam {
        /// The manual's name (`P0.02`, `0010`, `4-14`, `F-12`).
        name: String,
        /// The value in its unit (`"50"`, `"50 Hz"`, a choice's number).
        value: String,
        /// Write to EEPROM where the protocol lets the master choose (RAM otherwise).
        eeprom: bool,
    },
    /// Write a parameter's raw value (as the drive holds it; a register client's write).
    SetParamRaw {
        /// The manual's name.
        name: String,
        /// The raw value.
        raw: i64,
        /// The value in its unit, for the audit trail.
        shown: String,
        /// Write to EEPROM where the protocol lets the master choose (RAM otherwise).
        eeprom: bool,
    },
}

impl Command {
    /// The command as written in the audit trail (`run`, `speed 40 Hz`, `param 4-14 = 50`).
    pub fn action(&self) -> String {
        match self {
            Command::Run => "run".into(),
            Command::Stop => "stop".into(),
            Command::Reverse => "reverse".into(),
            Command::Jog => "jog".into(),
            Command::Reset => "reset".into(),
            Command::Speed(hz) => format!("speed {} Hz", crate::text::number(*hz)),
            Command::SetParam { name, value: shown, eeprom }
            | Command::SetParamRaw { name, shown, eeprom, .. } => {
                let (name, shown) = (crate::text::shown(name), crate::text::shown(shown));
                format!("param {name} = {shown}{}", if *eeprom { " (eeprom)" } else { "" })
            }
        }
    }

    /// Parses a command name as used in URLs and topics (`run`, `stop`, `reverse`, `jog`, `reset`).
    pub fn from_name(name: &str) -> Option<Command> {
        Some(match name {
            "run" => Command::Run,
            "stop" => Command::Stop,
            "reverse" => Command::Reverse,
            "jog" => Command::Jog,
            "reset" => Command::Reset,
            _ => return None,
        })
    }
}

/// What happened to a command or parameter read that was not done: the core's typed outcome.
/// Each front end says it in its own words (HTTP status in `http::error`, Modbus exception in
/// `modbus_tcp`, OPC UA status in `opcua::manager`, the MQTT result's `kind`).
#[derive(Debug)]
pub enum CommandError {
    /// No drive has that id.
    UnknownDrive(String),
    /// The drive is locked against writes.
    Locked(String),
    /// The request was not valid (bad value, unknown parameter) and nothing was sent.
    Invalid(String),
    /// The drive answered no.
    Refused {
        /// The drive's code.
        code: u32,
        /// Which of the manual's lists the code belongs to.
        space: CodeSpace,
        /// The manual's meaning.
        meaning: String,
    },
    /// The operation does not exist for this drive.
    Unsupported(String),
    /// The drive did not answer, or its replies were damaged, or it is offline.
    NoAnswer(String),
    /// The bus's port is gone.
    LinkDown(String),
    /// The reply made no sense.
    Protocol(String),
    /// Too many parameter reads wait on the drive's bus (or from this client); nothing was
    /// sent: try again shortly.
    Busy(String),
    /// The command's audit record could not be committed (the store failed: disk full, read
    /// only): the command was not sent.
    NotRecorded(String),
}

impl std::fmt::Display for CommandError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CommandError::UnknownDrive(id) => {
                // A name is short; a client that sends a page of text gets its start back.
                let (shown, more) = crate::text::cut(id, 64);
                write!(f, "no drive {shown:?}{more}: GET /api/drives lists them")
            }
            CommandError::Locked(id) => {
                write!(f, "drive {id:?} is locked against writes: unlock it in the configuration")
            }
            CommandError::Invalid(s) | CommandError::Unsupported(s) | CommandError::Protocol(s) => {
                f.write_str(s)
            }
            CommandError::Refused { code, meaning, .. } => {
                write!(f, "the drive refused: code {code:#04X}, {meaning}")
            }
            CommandError::NoAnswer(s) | CommandError::LinkDown(s) | CommandError::Busy(s) => f.write_str(s),
            CommandError::NotRecorded(e) => write!(
                f,
                "the command was not sent: its audit record cannot be stored ({e}); free the store's disk or fix its permissions"
            ),
        }
    }
}

impl std::error::Error for CommandError {}

impl CommandError {
    /// A short kind for JSON errors and the audit trail.
    pub fn kind(&self) -> &'static str {
        match self {
            CommandError::UnknownDrive(_) => "unknown_drive",
            CommandError::Locked(_) => "locked",
            CommandError::Invalid(_) => "invalid",
            CommandError::Refused { .. } => "refused",
            CommandError::Unsupported(_) => "unsupported",
            CommandError::NoAnswer(_) => "no_answer",
            CommandError::LinkDown(_) => "link_down",
            CommandError::Protocol(_) => "protocol",
            CommandError::Busy(_) => "busy",
            CommandError::NotRecorded(_) => "not_recorded",
        }
    }
}

impl From<LinkError> for CommandError {
    fn from(e: LinkError) -> Self {
        match e {
            LinkError::Drive(DriveError::Refused { code, space, meaning }) => {
                CommandError::Refused { code, space, meaning }
            }
            LinkError::Drive(DriveError::OutOfRange(s)) => CommandError::Invalid(s),
            LinkError::Drive(DriveError::Unsupported(s)) => CommandError::Unsupported(s),
            LinkError::Drive(DriveError::Protocol(s)) => CommandError::Protocol(s),
            LinkError::Bus(BusError::Link(s)) => CommandError::LinkDown(s),
            LinkError::Bus(BusError::Closed) => CommandError::LinkDown("the bus has stopped".into()),
            LinkError::Bus(e @ BusError::Busy(_)) => CommandError::Busy(e.to_string()),
            LinkError::Bus(e) => CommandError::NoAnswer(e.to_string()),
        }
    }
}

/// A parameter's value as read from a drive.
#[derive(Clone, Debug, Serialize)]
pub struct ParamReading {
    /// The manual's name.
    pub name: String,
    /// The manual's title.
    pub title: String,
    /// Raw value on the wire.
    pub raw: i64,
    /// The value in its unit.
    pub value: f64,
    /// The unit.
    pub unit: String,
    /// The value as the keypad would show it (`50.00 Hz`, a choice's text).
    pub text: String,
}

/// What the cache holds of one drive.
#[derive(Clone, Debug, Default)]
pub struct DriveState {
    /// The last status read.
    pub status: Option<DriveStatus>,
    /// When it was read.
    pub updated: Option<std::time::Instant>,
    /// When it was read, unix ms.
    pub updated_ms: Option<i64>,
    /// `None` until the first poll; then whether the last poll was answered.
    pub online: Option<bool>,
    /// The last poll or linkage error.
    pub last_error: Option<String>,
    /// Polls made.
    pub polls: u64,
    /// Polls that failed.
    pub poll_errors: u64,
    /// The last speed commanded through the gateway, Hz.
    pub commanded_hz: Option<f64>,
}

/// One drive in the gateway.
pub struct DriveEntry {
    /// Its configuration.
    pub config: DriveConfig,
    /// The bus's name.
    pub bus: String,
    /// The bus's protocol.
    pub protocol: WireProtocol,
    /// Commands (ahead of polls); shares its profile with `poll`, so what a command teaches the
    /// profile (a Danfoss setpoint or 3-03 scaling) shows in the next poll.
    command: Drive,
    poll: Drive,
    /// Parameter values read a moment ago.
    params: crate::params::ParamCache,
    state: RwLock<DriveState>,
    locked: AtomicBool,
    linking: AtomicBool,
    /// How the linkage's last write to this follower went: [`LINKAGE_NONE`], [`LINKAGE_HOLDS`]
    /// or [`LINKAGE_FAILS`]. Only the linkage changes it, so polls and operators' commands do
    /// not make a failing linkage look new.
    linkage: AtomicU8,
}

/// No linkage write to the drive yet.
const LINKAGE_NONE: u8 = 0;
/// The linkage's last write to the drive was confirmed.
const LINKAGE_HOLDS: u8 = 1;
/// The linkage's last write to the drive failed.
const LINKAGE_FAILS: u8 = 2;

impl DriveEntry {
    /// A copy of the cached state.
    pub fn state(&self) -> DriveState {
        self.state.read().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// Reads the cached state without copying it.
    pub fn with_state<R>(&self, f: impl FnOnce(&DriveState) -> R) -> R {
        f(&self.state.read().unwrap_or_else(|p| p.into_inner()))
    }

    /// Whether writes are refused.
    pub fn locked(&self) -> bool {
        self.locked.load(Ordering::Relaxed)
    }

    /// The parameter named `name` in this drive's catalog.
    pub fn param(&self, name: &str) -> Result<&ParamDef, CommandError> {
        self.command.profile().param(name).map_err(|e| CommandError::Invalid(e.to_string()))
    }

    /// The drive's parameter catalog, in the family's order.
    pub fn catalog(&self) -> Arc<drivebus_drive::Catalog> {
        drivebus_drive::Catalog::load(self.config.family).expect("embedded catalogs load (tested)")
    }
}

/// One bus in the gateway.
pub struct BusEntry {
    /// Its configuration.
    pub config: BusConfig,
    bus: Bus,
    online: AtomicBool,
    wake: Arc<Notify>,
    /// The drives its scheduler polls; replaced by a reload that adds or removes drives.
    members: RwLock<Vec<Arc<DriveEntry>>>,
    /// Bumped when `members` changes, so the scheduler picks the new list up.
    generation: AtomicU64,
    /// Set when a reload removed or replaced the bus: its scheduler ends and the port closes.
    retired: AtomicBool,
    /// The simulated drives of a virtual bus.
    #[cfg(feature = "virtual")]
    pub line: Option<Arc<std::sync::Mutex<VirtualLine>>>,
}

impl BusEntry {
    /// The bus owner's counts.
    pub fn stats(&self) -> BusStats {
        self.bus.stats()
    }

    /// False after the port failed, until a poll is answered again.
    pub fn online(&self) -> bool {
        self.online.load(Ordering::Relaxed)
    }

    /// The bus owner, for requests a Modbus bridge passes through (`crate::bridge`).
    pub fn owner(&self) -> &Bus {
        &self.bus
    }
}

/// A drive as the API shows it: configuration, cached values and their age, link health.
#[derive(Clone, Debug, Serialize)]
pub struct DriveView {
    /// The drive's id.
    pub id: String,
    /// The bus's name.
    pub bus: String,
    /// The family.
    pub family: String,
    /// The wire protocol.
    pub protocol: String,
    /// Its number on the bus.
    pub address: u8,
    /// Its Modbus TCP unit id.
    pub unit_id: u8,
    /// Whether writes are refused.
    pub locked: bool,
    /// `true`/`false` after the first poll; `null` before.
    pub online: Option<bool>,
    /// Whether the output is on.
    pub running: Option<bool>,
    /// `forward`/`reverse`.
    pub direction: Option<String>,
    /// Output frequency, Hz.
    pub output_hz: Option<f64>,
    /// Setpoint, Hz (the drive's, or the last commanded where the drive does not tell).
    pub setpoint_hz: Option<f64>,
    /// Motor current, A.
    pub current_a: Option<f64>,
    /// The fault in force.
    pub fault: Option<FaultView>,
    /// Age of the values, ms (`null` before the first answer).
    pub age_ms: Option<u64>,
    /// When the drive last answered, unix ms.
    pub last_seen_ms: Option<i64>,
    /// Failed polls / polls.
    pub error_rate: f64,
    /// Polls made.
    pub polls: u64,
    /// The last error.
    pub last_error: Option<String>,
    /// The poll interval, ms.
    pub poll_ms: u64,
}

/// A fault as the API shows it.
#[derive(Clone, Debug, Serialize, PartialEq, Eq)]
pub struct FaultView {
    /// The drive's code.
    pub code: u32,
    /// The manual's text.
    pub text: String,
}

/// A bus as the API shows it.
#[derive(Clone, Debug, Serialize)]
pub struct BusView {
    /// Its name.
    pub name: String,
    /// Its port.
    pub port: String,
    /// Its protocol.
    pub protocol: String,
    /// Baud rate.
    pub baud: u32,
    /// Character format.
    pub serial: String,
    /// False after the port failed.
    pub online: bool,
    /// Requests sent (retries included).
    pub transactions: u64,
    /// Replies received.
    pub replies: u64,
    /// Requests not answered in time.
    pub timeouts: u64,
    /// Damaged replies.
    pub checksum_errors: u64,
    /// Retries.
    pub retries: u64,
    /// Time on the wire / elapsed.
    pub utilization: f64,
    /// Broadcasts heard that the gateway did not send.
    pub foreign_broadcasts: u64,
    /// True while a drive acts as bus master on this line: a broadcast the gateway did not
    /// send was heard within the last [`DRIVE_MASTER_WINDOW_S`] seconds.
    pub drive_master: bool,
    /// The drives' ids.
    pub drives: Vec<String>,
}

/// How long after the last broadcast it did not send the gateway still shows a bus as a
/// drive-master line, seconds.
pub const DRIVE_MASTER_WINDOW_S: f64 = 10.0;

/// True while a drive acts as bus master on the line of `stats` (see [`BusView::drive_master`]).
pub fn drive_master(stats: &BusStats) -> bool {
    stats.last_foreign_broadcast_s.is_some_and(|t| stats.elapsed_seconds - t <= DRIVE_MASTER_WINDOW_S)
}

/// A change for live subscribers (the HTTP stream, MQTT, the dashboard).
#[derive(Clone, Debug, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Change {
    /// A drive's values were refreshed.
    Drive(DriveView),
    /// Something happened (also in the store).
    Event(Event),
    /// A bus's statistics.
    Bus(BusView),
}

/// Counters of the gateway's own work, for metrics.
#[derive(Debug, Default)]
pub struct Counters {
    /// Commands accepted and confirmed by a drive.
    pub commands_ok: AtomicU64,
    /// Commands refused or failed.
    pub commands_failed: AtomicU64,
    /// Events that could not be written to the store.
    pub store_errors: AtomicU64,
    /// Commands refused because their audit record could not be committed.
    pub commands_not_recorded: AtomicU64,
    /// The front ends' own counts (HTTP, Modbus TCP, MQTT).
    pub front_ends: crate::metrics::FrontEndMetrics,
}

/// What the gateway runs: its configuration and the buses and drives built from it. A reload
/// ([`Gateway::reload`]) puts a new one in place; entries of what did not change are carried
/// over as they are (same bus owner, same statistics, same cache).
pub struct Topology {
    /// The configuration.
    pub config: Arc<GatewayConfig>,
    /// Every drive, in configuration order.
    pub drives: Arc<[Arc<DriveEntry>]>,
    /// Every bus, in configuration order.
    pub buses: Arc<[Arc<BusEntry>]>,
    index: HashMap<String, usize>,
    units: Vec<Option<usize>>,
}

impl Topology {
    fn new(config: GatewayConfig, buses: Vec<Arc<BusEntry>>) -> Topology {
        let drives: Vec<Arc<DriveEntry>> =
            buses.iter().flat_map(|b| b.members.read().unwrap_or_else(|p| p.into_inner()).clone()).collect();
        let index = drives.iter().enumerate().map(|(i, d)| (d.config.name.clone(), i)).collect();
        let mut units = vec![None; 256];
        for (i, d) in drives.iter().enumerate().filter(|(_, d)| d.config.unit_id != 0) {
            units[d.config.unit_id as usize] = Some(i);
        }
        Topology { config: Arc::new(config), drives: drives.into(), buses: buses.into(), index, units }
    }
}

/// The gateway.
pub struct Gateway {
    topology: RwLock<Arc<Topology>>,
    /// Serializes reloads (one SIGHUP at a time).
    reloading: tokio::sync::Mutex<()>,
    changes: broadcast::Sender<Change>,
    store: Option<Store>,
    /// Counters for metrics.
    pub counters: Counters,
    log_events: AtomicBool,
    health: crate::health::Health,
    limits: crate::limits::Limits,
    /// Refused writes counted per client and reason ([`Gateway::audit_refusal`]).
    refusals: Mutex<Refusals>,
}

impl Gateway {
    /// Builds every bus and drive of `config` and starts polling (on the current tokio runtime).
    /// `store` receives events and trends.
    pub fn start(config: GatewayConfig, store: Option<Store>) -> Result<Arc<Gateway>, String> {
        let buses = config.buses.iter().map(build_bus).collect::<Result<Vec<_>, _>>()?;
        let (changes, _) = broadcast::channel(1024);
        let limits = crate::limits::Limits::new(config.limits.clone());
        let gw = Arc::new(Gateway {
            limits,
            topology: RwLock::new(Arc::new(Topology::new(config, buses))),
            reloading: tokio::sync::Mutex::new(()),
            changes,
            store,
            counters: Counters::default(),
            log_events: AtomicBool::new(false),
            health: crate::health::Health::default(),
            refusals: Mutex::new(Refusals::default()),
        });
        let topo = gw.topology();
        gw.record(Event {
            id: 0,
            time_ms: unix_ms(),
            kind: EventKind::Started,
            bus: None,
            drive: None,
            actor: Some("gateway".into()),
            action: None,
            result: None,
            detail: json!({ "buses": topo.buses.len(), "drives": topo.drives.len() }),
        });
        for b in topo.buses.iter() {
            tokio::spawn(gw.clone().poll_bus(b.clone()));
        }
        tokio::spawn(gw.clone().publish_buses());
        tokio::spawn(gw.clone().close_refusal_windows());
        Ok(gw)
    }

    /// What runs now (configuration, buses, drives): one consistent snapshot.
    pub fn topology(&self) -> Arc<Topology> {
        self.topology.read().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// Puts `new` in place of the running configuration, restarting only what changed: a bus
    /// added, removed or changed (port, protocol, baud, format, timing; any drive of a virtual
    /// bus) is opened or closed; drives added or removed; tokens, allow lists, locks and linkage
    /// rules apply at once. Buses that did not change keep polling without a gap and keep their
    /// statistics and cache. What only a restart can change (listeners, store, MQTT, name) is
    /// listed in [`Reload::needs_restart`]. The reload is an event in the audit trail, by `actor`.
    pub async fn reload(self: &Arc<Self>, new: GatewayConfig, actor: &str) -> Result<Reload, String> {
        let _one = self.reloading.lock().await;
        let old = self.topology();
        let plan = crate::reload::plan(&old.config, &new);
        // Build first: a bus that cannot be built leaves everything as it was.
        let mut built = HashMap::new();
        for name in plan.buses_added.iter().chain(&plan.buses_changed) {
            let Some(b) = new.buses.iter().find(|b| &b.name == name) else { continue };
            built.insert(name.clone(), build_bus(b)?);
        }
        let mut buses = Vec::new();
        let mut fresh = Vec::new();
        for b in &new.buses {
            if let Some(entry) = built.remove(&b.name) {
                fresh.push(entry.clone());
                buses.push(entry);
                continue;
            }
            // Not added nor changed: the running bus of that name, built again if it is missing.
            let kept = match old.buses.iter().find(|x| x.config.name == b.name) {
                Some(k) => k.clone(),
                None => {
                    let entry = build_bus(b)?;
                    fresh.push(entry.clone());
                    buses.push(entry);
                    continue;
                }
            };
            let members = kept.members.read().unwrap_or_else(|p| p.into_inner()).clone();
            let mut next = Vec::new();
            for d in &b.drives {
                match members.iter().find(|m| m.config.name == d.name) {
                    Some(m) if crate::reload::same_drive(&m.config, d) => {
                        // A lock changed in the file applies at once (and only then: a lock
                        // set otherwise stays).
                        let was = old.config.drives().find(|(_, o)| o.name == d.name).map(|(_, o)| o.locked);
                        if was != Some(d.locked) {
                            m.locked.store(d.locked, Ordering::Relaxed);
                        }
                        next.push(m.clone());
                    }
                    _ => next.push(Arc::new(drive_entry(b, d, &kept.bus)?)),
                }
            }
            let changed =
                next.len() != members.len() || next.iter().zip(&members).any(|(a, b)| !Arc::ptr_eq(a, b));
            if changed {
                *kept.members.write().unwrap_or_else(|p| p.into_inner()) = next;
                kept.generation.fetch_add(1, Ordering::Relaxed);
                kept.wake.notify_one();
            }
            buses.push(kept);
        }
        for b in old.buses.iter() {
            if !buses.iter().any(|x| Arc::ptr_eq(x, b)) {
                b.retired.store(true, Ordering::Relaxed);
                b.wake.notify_one();
            }
        }
        let topo = Arc::new(Topology::new(new, buses));
        *self.topology.write().unwrap_or_else(|p| p.into_inner()) = topo;
        for b in fresh {
            tokio::spawn(self.clone().poll_bus(b));
        }
        let reload = Reload { summary: plan.summary(), needs_restart: plan.needs_restart.clone() };
        self.record_reload(actor, "ok".into(), plan.to_json()).await;
        Ok(reload)
    }

    /// Records a reload that was refused (the new configuration did not check): the old one
    /// keeps running.
    pub async fn reload_refused(self: &Arc<Self>, actor: &str, why: &str) {
        self.record_reload(actor, format!("error: {why}"), json!({})).await;
    }

    /// A reload in the audit trail: by `actor`, ended with `result`, what changed in `detail`.
    async fn record_reload(self: &Arc<Self>, actor: &str, result: String, detail: serde_json::Value) {
        self.record_async(Event {
            id: 0,
            time_ms: unix_ms(),
            kind: EventKind::Reload,
            bus: None,
            drive: None,
            actor: Some(actor.to_string()),
            action: None,
            result: Some(result),
            detail,
        })
        .await;
    }

    /// The configuration it runs now.
    pub fn config(&self) -> Arc<GatewayConfig> {
        self.topology().config.clone()
    }

    /// Every drive, in configuration order.
    pub fn drives(&self) -> Arc<[Arc<DriveEntry>]> {
        self.topology().drives.clone()
    }

    /// Every bus.
    pub fn buses(&self) -> Arc<[Arc<BusEntry>]> {
        self.topology().buses.clone()
    }

    /// The drive with id `id`.
    pub fn drive(&self, id: &str) -> Result<Arc<DriveEntry>, CommandError> {
        let topo = self.topology();
        topo.index
            .get(id)
            .map(|&i| topo.drives[i].clone())
            .ok_or_else(|| CommandError::UnknownDrive(id.to_string()))
    }

    /// The drive with Modbus TCP unit id `unit`.
    pub fn drive_by_unit(&self, unit: u8) -> Option<Arc<DriveEntry>> {
        let topo = self.topology();
        topo.units[unit as usize].map(|i| topo.drives[i].clone())
    }

    /// What the health checks know (listeners up, store writable, reloads).
    pub fn health(&self) -> &crate::health::Health {
        &self.health
    }

    /// The listeners' connection limits (`[limits]`, as at start).
    pub fn limits(&self) -> &crate::limits::Limits {
        &self.limits
    }

    /// The store, if configured.
    pub fn store(&self) -> Option<&Store> {
        self.store.as_ref()
    }

    /// Subscribes to live changes.
    pub fn subscribe(&self) -> broadcast::Receiver<Change> {
        self.changes.subscribe()
    }

    /// The API view of a drive.
    pub fn drive_view(&self, d: &DriveEntry) -> DriveView {
        d.with_state(|s| {
            let st = s.status.as_ref();
            DriveView {
                id: d.config.name.clone(),
                bus: d.bus.clone(),
                family: d.config.family.as_str().to_string(),
                protocol: d.protocol.to_string(),
                address: d.config.address,
                unit_id: d.config.unit_id,
                locked: d.locked(),
                online: s.online,
                running: st.map(|x| x.running),
                direction: st.and_then(|x| x.direction.clone()),
                output_hz: st.and_then(|x| x.output_hz),
                setpoint_hz: st.and_then(|x| x.setpoint_hz).or(s.commanded_hz),
                current_a: st.and_then(|x| x.current_a),
                fault: st
                    .and_then(|x| x.fault.as_ref())
                    .map(|f| FaultView { code: f.code, text: f.text.clone() }),
                age_ms: s.updated.map(|t| t.elapsed().as_millis() as u64),
                last_seen_ms: s.updated_ms,
                error_rate: if s.polls == 0 { 0.0 } else { s.poll_errors as f64 / s.polls as f64 },
                polls: s.polls,
                last_error: s.last_error.clone(),
                poll_ms: d.config.poll.as_millis() as u64,
            }
        })
    }

    /// The API view of a bus.
    pub fn bus_view(&self, b: &BusEntry) -> BusView {
        let s = b.stats();
        BusView {
            name: b.config.name.clone(),
            port: b.config.port.to_string(),
            protocol: b.config.protocol.to_string(),
            baud: b.config.baud,
            serial: b.config.format.to_string(),
            online: b.online(),
            transactions: s.transactions,
            replies: s.replies,
            timeouts: s.timeouts,
            checksum_errors: s.checksum_errors,
            retries: s.retries,
            utilization: s.utilization(),
            foreign_broadcasts: s.foreign_broadcasts,
            drive_master: drive_master(&s),
            drives: self
                .drives()
                .iter()
                .filter(|d| d.bus == b.config.name)
                .map(|d| d.config.name.clone())
                .collect(),
        }
    }

    /// Appends an event to the store (waiting for the commit) and tells live subscribers.
    /// Returns the stored event (with its id), or the event unstored when the store failed.
    pub fn record(&self, mut event: Event) -> Event {
        if let Some(store) = &self.store {
            match store.record(&event) {
                Ok(id) => event.id = id,
                Err(e) => {
                    self.counters.store_errors.fetch_add(1, Ordering::Relaxed);
                    crate::log::warn(&format!("event not stored: {e}"));
                }
            }
        }
        self.announce(&event);
        event
    }

    /// Tells the log (when on) and live subscribers about an event.
    fn announce(&self, event: &Event) {
        if self.log_events.load(Ordering::Relaxed) {
            crate::log::event(event);
        }
        let _ = self.changes.send(Change::Event(event.clone()));
    }

    /// Prints every event as one line on stderr (what `drivebus serve` does).
    pub fn log_events(&self, on: bool) {
        self.log_events.store(on, Ordering::Relaxed);
    }

    async fn record_async(self: &Arc<Self>, event: Event) -> Event {
        let gw = self.clone();
        let kept = event.clone();
        match tokio::task::spawn_blocking(move || gw.record(event)).await {
            Ok(e) => e,
            // The runtime is shutting down: the event is not stored, say so rather than panic.
            Err(e) => {
                self.counters.store_errors.fetch_add(1, Ordering::Relaxed);
                crate::log::warn(&format!("event not stored ({e}): {}", log_line(&kept)));
                kept
            }
        }
    }

    /// Sends `command` to drive `id` on behalf of `actor` (for the audit trail) and waits for the
    /// drive's confirmation. The command is in the store (result `pending`) before it is sent,
    /// and its result before this returns. A command whose audit record cannot be committed is
    /// not sent: [`CommandError::NotRecorded`].
    pub async fn command(
        self: &Arc<Self>,
        id: &str,
        command: Command,
        actor: &str,
    ) -> Result<(), CommandError> {
        let d = self.drive(id)?;
        if d.locked() {
            let e = CommandError::Locked(id.to_string());
            self.counters.commands_failed.fetch_add(1, Ordering::Relaxed);
            let outcome = format!("{}: {e}", e.kind());
            self.audit(Some(d.bus.clone()), id, actor, &command.action(), outcome).await;
            return Err(e);
        }
        let pending = self.audit_pending(&d, actor, &command).await?;
        let mut result = self.execute(&d, &command).await;
        if let Err(CommandError::Refused { meaning, .. }) = &mut result {
            // Say why from what the drive reports now.
            self.refresh(&d).await;
            if let Some(f) = d.with_state(|s| s.status.as_ref().and_then(|x| x.fault.clone())) {
                *meaning =
                    format!("{meaning}; the drive is tripped (fault {}: {}): reset it first", f.code, f.text);
            }
        }
        match &result {
            Ok(()) => self.counters.commands_ok.fetch_add(1, Ordering::Relaxed),
            Err(_) => self.counters.commands_failed.fetch_add(1, Ordering::Relaxed),
        };
        let outcome = match &result {
            Ok(()) => "ok".to_string(),
            Err(e) => crate::text::shown_max(&format!("{}: {e}", e.kind()), MAX_MESSAGE_CHARS),
        };
        self.audit_done(pending, outcome).await;
        if result.is_ok() {
            // Read the drive's state now, so the answer (and every front end's cache) shows
            // what the command did.
            self.refresh(&d).await;
        }
        result
    }

    /// Commits `command`'s audit record with result `pending` before it is carried out: the
    /// event, with its id, to finish with [`Gateway::audit_done`]. Without a store there is
    /// nothing to commit (the event is made, not stored). When the store cannot commit it, the
    /// command is refused, logged and counted.
    async fn audit_pending(
        self: &Arc<Self>,
        d: &DriveEntry,
        actor: &str,
        command: &Command,
    ) -> Result<Event, CommandError> {
        let mut event = Event {
            id: 0,
            time_ms: unix_ms(),
            kind: EventKind::Command,
            bus: Some(d.bus.clone()),
            drive: Some(d.config.name.clone()),
            actor: Some(actor.to_string()),
            action: Some(command.action()),
            result: Some(drivebus_store::PENDING.to_string()),
            detail: json!({}),
        };
        let Some(store) = self.store.clone() else { return Ok(event) };
        let kept = event.clone();
        let stored = tokio::task::spawn_blocking(move || store.record(&kept).map_err(|e| e.to_string()))
            .await
            .unwrap_or_else(|e| Err(e.to_string()));
        match stored {
            Ok(id) => {
                event.id = id;
                Ok(event)
            }
            Err(e) => {
                self.counters.store_errors.fetch_add(1, Ordering::Relaxed);
                self.counters.commands_failed.fetch_add(1, Ordering::Relaxed);
                self.counters.commands_not_recorded.fetch_add(1, Ordering::Relaxed);
                let e = CommandError::NotRecorded(e);
                crate::log::warn(&format!("{} refused: {e}", log_line(&event)));
                Err(e)
            }
        }
    }

    /// Writes the `result` of a command recorded by [`Gateway::audit_pending`] and tells the
    /// log and live subscribers. A result that cannot be stored leaves the record `pending`,
    /// logged and counted.
    async fn audit_done(self: &Arc<Self>, mut event: Event, result: String) {
        if let (Some(store), true) = (self.store.clone(), event.id != 0) {
            let (id, r) = (event.id, result.clone());
            let stored =
                tokio::task::spawn_blocking(move || store.set_result(id, &r).map_err(|e| e.to_string()))
                    .await
                    .unwrap_or_else(|e| Err(e.to_string()));
            if let Err(e) = stored {
                self.counters.store_errors.fetch_add(1, Ordering::Relaxed);
                crate::log::warn(&format!("result of event {id} not stored (it stays pending): {e}"));
            }
        }
        event.result = Some(result);
        self.announce(&event);
    }

    /// Puts a command in the audit trail: who, on which drive, what, and how it ended.
    async fn audit(
        self: &Arc<Self>,
        bus: Option<String>,
        drive: &str,
        actor: &str,
        action: &str,
        result: String,
    ) {
        self.record_async(Event {
            id: 0,
            time_ms: unix_ms(),
            kind: EventKind::Command,
            bus,
            drive: Some(drive.to_string()),
            actor: Some(actor.to_string()),
            action: Some(action.to_string()),
            result: Some(result),
            detail: json!({}),
        })
        .await;
    }

    /// Records a write that was refused before it became a command (a client not allowed to
    /// write, a read-only listener, a locked drive, a malformed MQTT command), so the audit
    /// trail shows every attempt. `why` starts with the reason's kind (`forbidden: ...`). The
    /// first refusal of a (client, reason) is written at once; repeats within a minute are
    /// counted and written as one event when the minute is over ([`crate::refusals`]).
    pub async fn audit_refusal(self: &Arc<Self>, id: &str, actor: &str, action: &str, why: &str) {
        self.counters.commands_failed.fetch_add(1, Ordering::Relaxed);
        self.refusal(Some(id), actor, action, why).await;
    }

    /// Records a failed login (an unknown or malformed token) from `ip` like a refusal:
    /// audited and logged, aggregated per address ([`Gateway::login_blocked`] counts them).
    pub async fn login_failed(self: &Arc<Self>, ip: &str, why: &str) {
        self.refusal(None, &format!("http:{ip}"), "login", why).await;
    }

    /// Whether `ip` failed to log in [`MAX_LOGIN_FAILURES`] times in its current minute.
    pub fn login_blocked(&self, ip: &str) -> bool {
        let seen = self
            .refusals
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .seen(&format!("http:{ip}"), "unauthorized");
        seen >= MAX_LOGIN_FAILURES
    }

    async fn refusal(self: &Arc<Self>, id: Option<&str>, actor: &str, action: &str, why: &str) {
        let id = id.map(crate::text::shown);
        let why = crate::text::shown_max(why, MAX_MESSAGE_CHARS);
        let sample = Refused { drive: id.clone(), action: action.to_string(), why };
        let client = crate::refusals::client_of(actor);
        let seen = self.refusals.lock().unwrap_or_else(|p| p.into_inner()).refused(
            tokio::time::Instant::now(),
            &client,
            sample.clone(),
        );
        if seen == Seen::First {
            self.write_refusal(&sample, actor, sample.why.clone(), json!({})).await;
        }
    }

    /// A refusal (or a window's count of them) in the audit trail.
    async fn write_refusal(
        self: &Arc<Self>,
        r: &Refused,
        actor: &str,
        result: String,
        detail: serde_json::Value,
    ) {
        let bus = r.drive.as_deref().and_then(|d| self.drive(d).ok()).map(|d| d.bus.clone());
        self.record_async(Event {
            id: 0,
            time_ms: unix_ms(),
            kind: EventKind::Command,
            bus,
            drive: r.drive.clone(),
            actor: Some(actor.to_string()),
            action: Some(r.action.clone()),
            result: Some(result),
            detail,
        })
        .await;
    }

    /// Writes the refusals counted over windows that closed: one event per client and reason.
    async fn close_refusal_windows(self: Arc<Self>) {
        let mut tick = tokio::time::interval(Duration::from_secs(1));
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tick.tick().await;
            let due =
                self.refusals.lock().unwrap_or_else(|p| p.into_inner()).due(tokio::time::Instant::now());
            for s in due {
                let detail =
                    json!({ "repeated": s.count, "reason": s.reason, "window_s": s.window.as_secs() });
                self.write_refusal(&s.sample, &s.client, s.result(), detail).await;
            }
        }
    }

    async fn execute(&self, d: &DriveEntry, command: &Command) -> Result<(), CommandError> {
        let map = CommandError::from;
        let storage = |eeprom: bool| if eeprom { Storage::Eeprom } else { Storage::Ram };
        // After a parameter write, a value read a moment ago is not the drive's any more.
        let forget = |name: &str| {
            if let Ok(def) = d.param(name) {
                d.params.forget(&def.name);
            }
        };
        match command {
            Command::Run => d.command.run().await.map_err(map)?,
            Command::Stop => d.command.stop().await.map_err(map)?,
            Command::Reverse => d.command.reverse().await.map_err(map)?,
            Command::Jog => d.command.jog().await.map_err(map)?,
            Command::Reset => d.command.reset().await.map_err(map)?,
            Command::Speed(hz) => {
                if !hz.is_finite() || hz.abs() > MAX_SPEED_HZ {
                    return Err(CommandError::Invalid(format!(
                        "speed {} Hz is not a speed: give a number of Hz within ±{MAX_SPEED_HZ}",
                        crate::text::number(*hz)
                    )));
                }
                d.command.set_speed(*hz).await.map_err(map)?;
                d.state.write().unwrap_or_else(|p| p.into_inner()).commanded_hz = Some(*hz);
            }
            Command::SetParam { name, value, eeprom } => {
                let written = d.command.write_param(name, value, storage(*eeprom)).await.map(|_| ());
                forget(name);
                written.map_err(map)?;
            }
            Command::SetParamRaw { name, raw, eeprom, .. } => {
                let written = d.command.write_param_raw(name, *raw, storage(*eeprom)).await;
                forget(name);
                written.map_err(map)?;
            }
        }
        Ok(())
    }

    /// Reads drive `d`'s status now, ahead of polls, into the cache (what a poll would do).
    async fn refresh(self: &Arc<Self>, d: &Arc<DriveEntry>) {
        let Some(bus) = self.buses().iter().find(|b| b.config.name == d.bus).cloned() else { return };
        let status = d.command.status().await;
        self.update(&bus, d, status).await;
    }

    /// Reads parameter `name` of drive `id` on behalf of `client` (its address, or a session
    /// where the address is not known): from the drive, in turn with other clients' reads and
    /// sharing the bus with polls ([`drivebus_link::fair`]), or the value read less than
    /// `param_cache_ms` ago. [`CommandError::Busy`] when too many reads wait on the bus.
    pub async fn read_param(&self, id: &str, name: &str, client: &str) -> Result<ParamReading, CommandError> {
        let d = self.drive(id)?;
        let def = d.param(name)?.clone();
        let reader = d.command.on_demand_for(client);
        let raw = d
            .params
            .read(&def.name, || async { reader.read_param(&def.name).await.map(|(raw, _)| raw) })
            .await?;
        Ok(ParamReading {
            name: def.name.clone(),
            title: def.title.clone(),
            raw,
            value: def.from_raw(raw),
            unit: def.unit.clone(),
            text: def.format(raw),
        })
    }

    async fn poll_bus(self: Arc<Self>, bus: Arc<BusEntry>) {
        let mut generation = u64::MAX;
        let mut mine: Vec<Arc<DriveEntry>> = Vec::new();
        let mut due: Vec<tokio::time::Instant> = Vec::new();
        loop {
            if bus.retired.load(Ordering::Relaxed) {
                return;
            }
            // A reload changed the drives: keep the kept drives' schedule, poll new ones now.
            let now_gen = bus.generation.load(Ordering::Relaxed);
            if now_gen != generation {
                generation = now_gen;
                let next = bus.members.read().unwrap_or_else(|p| p.into_inner()).clone();
                let now = tokio::time::Instant::now();
                due = next
                    .iter()
                    .map(|d| mine.iter().position(|m| Arc::ptr_eq(m, d)).map_or(now, |k| due[k]))
                    .collect();
                mine = next;
            }
            let wake = bus.wake.notified();
            if mine.is_empty() {
                wake.await;
                continue;
            }
            let k = (0..mine.len()).min_by_key(|&k| (due[k], mine[k].config.priority)).expect("not empty");
            tokio::select! {
                _ = tokio::time::sleep_until(due[k]) => {}
                _ = wake => continue,
            }
            let d = mine[k].clone();
            let result = d.poll.status().await;
            self.update(&bus, &d, result).await;
            let next = due[k] + d.config.poll;
            due[k] = next.max(tokio::time::Instant::now());
        }
    }

    async fn update(
        self: &Arc<Self>,
        bus: &BusEntry,
        d: &Arc<DriveEntry>,
        result: Result<DriveStatus, LinkError>,
    ) {
        let now_ms = unix_ms();
        let mut events = Vec::new();
        let event = |kind, detail| Event {
            id: 0,
            time_ms: now_ms,
            kind,
            bus: Some(d.bus.clone()),
            drive: Some(d.config.name.clone()),
            actor: Some("gateway".into()),
            action: None,
            result: None,
            detail,
        };
        let link_down = matches!(&result, Err(LinkError::Bus(BusError::Link(_))));
        if link_down && bus.online.swap(false, Ordering::Relaxed) {
            let why = match &result {
                Err(e) => e.to_string(),
                Ok(_) => String::new(),
            };
            events.push(Event { drive: None, ..event(EventKind::BusOffline, json!({ "error": why })) });
        }
        if result.is_ok() && !bus.online.swap(true, Ordering::Relaxed) {
            events.push(Event { drive: None, ..event(EventKind::BusOnline, json!({})) });
        }
        let mut linked = None;
        {
            let mut s = d.state.write().unwrap_or_else(|p| p.into_inner());
            s.polls += 1;
            let was_online = s.online;
            match result {
                Ok(status) => {
                    let old_fault = s.status.as_ref().and_then(|x| x.fault.clone());
                    match (&old_fault, &status.fault) {
                        (None, Some(f)) => {
                            let before = s.status.as_ref();
                            let detail =
                                crate::trip::trip_detail(f, before, s.updated_ms, s.commanded_hz, &status);
                            events.push(event(EventKind::Trip, detail));
                        }
                        (Some(f), None) => {
                            events.push(event(
                                EventKind::FaultReset,
                                json!({ "code": f.code, "text": f.text }),
                            ));
                        }
                        _ => {}
                    }
                    if was_online == Some(false) {
                        events.push(event(EventKind::Online, json!({})));
                    }
                    if let Some(store) = &self.store {
                        store.sample(Sample {
                            time_ms: now_ms,
                            drive: d.config.name.clone(),
                            output_hz: status.output_hz,
                            current_a: status.current_a,
                            setpoint_hz: status.setpoint_hz.or(s.commanded_hz),
                        });
                    }
                    linked = status.output_hz;
                    s.status = Some(status);
                    s.updated = Some(std::time::Instant::now());
                    s.updated_ms = Some(now_ms);
                    s.online = Some(true);
                    s.last_error = None;
                }
                Err(e) => {
                    s.poll_errors += 1;
                    s.last_error = Some(e.to_string());
                    // A drive the bus owner still counts as online had one bad poll; offline is
                    // the owner's verdict after several in a row (or a dead port).
                    let health_online = bus.bus.health().get(&d.config.address).map_or(true, |h| h.online);
                    if !health_online || link_down {
                        if was_online != Some(false) {
                            events.push(event(EventKind::Offline, json!({ "error": e.to_string() })));
                        }
                        s.online = Some(false);
                    }
                }
            }
        }
        for e in events {
            self.record_async(e).await;
        }
        let _ = self.changes.send(Change::Drive(self.drive_view(d)));
        if let Some(hz) = linked {
            self.follow(d, hz);
        }
    }

    /// Applies the linkage rules whose leader is drive `i`, now at `hz`.
    fn follow(self: &Arc<Self>, leader: &DriveEntry, hz: f64) {
        let topo = self.topology();
        for rule in &topo.config.linkage {
            if rule.leader != leader.config.name {
                continue;
            }
            let Some(&fi) = topo.index.get(&rule.follower) else { continue };
            let f = topo.drives[fi].clone();
            let target = ((hz * rule.ratio + rule.offset_hz).max(0.0) * 100.0).round() / 100.0;
            let current = f.with_state(|s| s.commanded_hz);
            if current.is_some_and(|c| (c - target).abs() < 0.005) || f.locked() {
                continue;
            }
            if f.linking.swap(true, Ordering::Relaxed) {
                continue;
            }
            let gw = self.clone();
            let actor = format!("linkage:{}", rule.leader);
            tokio::spawn(async move {
                // The audit trail has the linkage taking hold, failing and recovering; not each
                // setpoint it writes (one per leader poll).
                let result = f.command.set_speed(target).await;
                let now = if result.is_ok() { LINKAGE_HOLDS } else { LINKAGE_FAILS };
                let changed = f.linkage.swap(now, Ordering::Relaxed) != now;
                let audit = match &result {
                    Ok(()) => {
                        let mut s = f.state.write().unwrap_or_else(|p| p.into_inner());
                        s.commanded_hz = Some(target);
                        if s.last_error.as_deref().is_some_and(|e| e.starts_with("linkage:")) {
                            s.last_error = None;
                        }
                        changed.then(|| "ok".to_string())
                    }
                    Err(e) => {
                        f.state.write().unwrap_or_else(|p| p.into_inner()).last_error =
                            Some(format!("linkage: {e}"));
                        changed.then(|| format!("error: {e}"))
                    }
                };
                if let Some(result) = audit {
                    gw.audit(
                        Some(f.bus.clone()),
                        &f.config.name,
                        &actor,
                        &Command::Speed(target).action(),
                        result,
                    )
                    .await;
                }
                f.linking.store(false, Ordering::Relaxed);
            });
        }
    }

    async fn publish_buses(self: Arc<Self>) {
        let mut tick = tokio::time::interval(Duration::from_secs(1));
        loop {
            tick.tick().await;
            for b in self.buses().iter() {
                let _ = self.changes.send(Change::Bus(self.bus_view(b)));
            }
        }
    }

    /// Family name of a drive (for front ends that show it).
    pub fn family(d: &DriveEntry) -> Family {
        d.config.family
    }
}

/// An event as one log line: `2026-11-22T00:06:01.123Z trip line-1/pump-1 {"code":3,...}`.
pub fn log_line(e: &Event) -> String {
    let mut line = format!("{} {}", drivebus_store::time::format_rfc3339(e.time_ms), e.kind.as_str());
    match (&e.bus, &e.drive) {
        (Some(b), Some(d)) => line.push_str(&format!(" {b}/{d}")),
        (Some(b), None) => line.push_str(&format!(" {b}")),
        (None, Some(d)) => line.push_str(&format!(" {d}")),
        (None, None) => {}
    }
    if let Some(a) = &e.action {
        line.push_str(&format!(" {a}"));
    }
    if let Some(who) = e.actor.as_deref().filter(|w| *w != "gateway") {
        line.push_str(&format!(" by {who}"));
    }
    if let Some(r) = &e.result {
        line.push_str(&format!(": {r}"));
    }
    if !e.detail.is_null() && e.detail.as_object().map_or(true, |o| !o.is_empty()) {
        line.push_str(&format!(" {}", e.detail));
    }
    line
}

/// What a reload did, for the log and the caller.
#[derive(Clone, Debug)]
pub struct Reload {
    /// One line: what was added, removed and changed (`no change` when nothing).
    pub summary: String,
    /// Settings that changed but take effect only at the next start.
    pub needs_restart: Vec<String>,
}

/// Builds a bus of the configuration (owner, link, drives); its poll scheduler is not started.
fn build_bus(b: &BusConfig) -> Result<Arc<BusEntry>, String> {
    let mut owner = OwnerConfig::new(b.protocol, b.baud, b.format);
    owner.response_timeout = b.timeout;
    owner.retries = b.retries;
    owner.echo = b.echo;
    owner.strict_t15 = b.strict_t15;
    // A family whose manual asks for more silence than the protocol (generic RTU: 10 ms).
    owner.family = b
        .drives
        .iter()
        .map(|d| d.family)
        .find(|&f| drivebus_drive::registers::generic::line_silence(f, b.protocol).is_some());
    owner.on_demand = b.on_demand;
    // Opened by the bus owner before its first transaction, and again after a loss.
    let port = match &b.port {
        crate::config::Port::Serial(path) => LinkPort::Serial(SerialSettings {
            path: path.clone(),
            baud: b.baud,
            format: b.format,
            rs485: b.rs485,
        }),
        crate::config::Port::Tcp(addr) => LinkPort::Tcp(addr.clone()),
        #[cfg(feature = "virtual")]
        crate::config::Port::Virtual => {
            let line = crate::virtual_bus::virtual_line(b)?;
            LinkPort::Virtual(VirtualPort { line, name: format!("virtual:{}", b.name) })
        }
        #[cfg(not(feature = "virtual"))]
        crate::config::Port::Virtual => {
            return Err(format!("bus {}: this build has no virtual buses", b.name))
        }
    };
    #[cfg(feature = "virtual")]
    let line = match &port {
        LinkPort::Virtual(v) => Some(v.line.clone()),
        _ => None,
    };
    let bus = Bus::spawn(PortLink::new(port), owner).map_err(|e| format!("bus {}: {e}", b.name))?;
    let wake = Arc::new(Notify::new());
    let members = b.drives.iter().map(|d| drive_entry(b, d, &bus).map(Arc::new)).collect::<Result<_, _>>()?;
    Ok(Arc::new(BusEntry {
        config: b.clone(),
        bus,
        online: AtomicBool::new(true),
        wake,
        members: RwLock::new(members),
        generation: AtomicU64::new(0),
        retired: AtomicBool::new(false),
        #[cfg(feature = "virtual")]
        line,
    }))
}

/// A drive of bus `b`, reached through `bus`, with one profile for its commands and polls.
fn drive_entry(b: &BusConfig, d: &DriveConfig, bus: &Bus) -> Result<DriveEntry, String> {
    let profile = drivebus_drive::profile::for_drive(d.family, b.protocol, d.address)
        .map_err(|e| format!("drive {}: {e}", d.name))?;
    let mut command = Drive::new(bus.clone(), profile);
    if let Some(t) = b.timeout {
        command = command.with_timeout(t);
    }
    let poll = command.polling_twin();
    Ok(DriveEntry {
        config: d.clone(),
        bus: b.name.clone(),
        protocol: b.protocol,
        command,
        poll,
        params: crate::params::ParamCache::new(b.param_cache),
        state: RwLock::new(DriveState::default()),
        locked: AtomicBool::new(d.locked),
        linking: AtomicBool::new(false),
        linkage: AtomicU8::new(LINKAGE_NONE),
    })
}
