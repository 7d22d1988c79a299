//! The state cache: what the gateway knows of each drive ([`DriveState`] in its
//! [`DriveEntry`]) and each bus ([`BusEntry`]), and the handles to reach them (the drive's
//! profile on its bus owner, the bus owner itself).

use std::sync::atomic::{AtomicBool, AtomicU64, AtomicU8, Ordering};
use std::sync::{Arc, Mutex, RwLock};

use drivebus_drive::profile::DriveStatus;
use drivebus_drive::ParamDef;
use drivebus_link::drive::Drive;
use drivebus_link::owner::{Bus, BusStats};
use drivebus_proto::protocol::WireProtocol;
#[cfg(feature = "virtual")]
use drivebus_sim::bus::VirtualLine;
use tokio::sync::Notify;

use super::command::CommandError;
use crate::config::{BusConfig, DriveConfig};

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

impl DriveState {
    /// The speed setpoint, Hz: the drive's own, else the last commanded through the gateway.
    pub fn setpoint_hz(&self) -> Option<f64> {
        self.status.as_ref().and_then(|x| x.setpoint_hz).or(self.commanded_hz)
    }
}

/// One drive in the gateway.
pub struct DriveEntry {
    /// Its configuration.
    pub config: DriveConfig,
    /// The bus's name.
    pub bus: String,
    /// The bus's protocol (Modbus RTU's frames on a Modbus TCP bus).
    pub protocol: WireProtocol,
    /// The bus's protocol as users name it (`modbus-tcp` on a Modbus TCP bus).
    pub protocol_name: &'static str,
    /// Commands (ahead of polls); shares its profile with `poll`, so what a command teaches the
    /// profile (a Danfoss setpoint or 3-03 scaling) shows in the next poll.
    pub(super) command: Drive,
    pub(super) poll: Drive,
    /// Parameter values read a moment ago.
    pub(super) params: crate::params::ParamCache,
    pub(super) state: RwLock<DriveState>,
    pub(super) locked: AtomicBool,
    pub(super) linking: AtomicBool,
    /// How the linkage's last write to this follower went: [`LINKAGE_NONE`], [`LINKAGE_HOLDS`]
    /// or [`LINKAGE_FAILS`]. Only the linkage changes it, so polls and operators' commands do
    /// not make a failing linkage look new.
    pub(super) linkage: AtomicU8,
}

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

    /// Master (the gateway polls the drive's bus) or standby (it only hears another gateway's
    /// polls of the drive, `[standby]`).
    pub fn role(&self) -> drivebus_link::role::Role {
        self.poll.bus().role().map_or(drivebus_link::role::Role::Master, |s| s.role)
    }

    /// The standby refusal of a command to this drive, while its bus listens: nothing is sent.
    pub fn standby_refusal(&self) -> Option<CommandError> {
        (self.role() == drivebus_link::role::Role::Standby).then(|| {
            let e = drivebus_link::bus::BusError::Standby(self.poll.bus().name().to_string());
            CommandError::Standby(e.to_string())
        })
    }

    /// The parameter named `name` in this drive's catalog.
    pub fn param(&self, name: &str) -> Result<&ParamDef, CommandError> {
        self.command.profile().param(name).map_err(|e| CommandError::Invalid(e.to_string()))
    }

    /// The drive's parameter catalog, in the family's order.
    pub fn catalog(&self) -> Arc<drivebus_drive::Catalog> {
        drivebus_drive::Catalog::load(self.config.family).expect("embedded catalogs load (tested)")
    }

    /// The named values beyond the six that the drive's kind gives (a template's `[values]`,
    /// in the file's order; none for a built-in family): known from the configuration, before
    /// the first poll, so the front ends announce them up front ([`DriveView::values`] holds
    /// their readings).
    ///
    /// [`DriveView::values`]: super::views::DriveView::values
    pub fn named_values(&self) -> Vec<ValueDef> {
        self.config.family.template().map_or_else(Vec::new, |t| {
            t.status.extra.iter().map(|e| ValueDef { name: e.name.clone(), unit: e.unit.clone() }).collect()
        })
    }
}

/// A named value a drive's kind gives: its name (`dc_bus_v`) and unit (`V`, or empty).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ValueDef {
    /// Its name, as [`super::views::DriveView::values`] keys it.
    pub name: String,
    /// Its unit, or empty.
    pub unit: String,
}

/// One bus in the gateway.
pub struct BusEntry {
    /// Its configuration.
    pub config: BusConfig,
    pub(super) bus: Bus,
    pub(super) online: AtomicBool,
    pub(super) wake: Arc<Notify>,
    /// The drives its scheduler polls; replaced by a reload that adds or removes drives.
    pub(super) members: RwLock<Vec<Arc<DriveEntry>>>,
    /// Bumped when `members` changes, so the scheduler picks the new list up.
    pub(super) generation: AtomicU64,
    /// Set when a reload removed or replaced the bus: its scheduler ends and the port closes.
    pub(super) retired: AtomicBool,
    /// The drives whose status a command's refresh read (ahead of polls), and when, for the
    /// scheduler to count as their polls.
    pub(super) refreshed: Mutex<Vec<(Arc<DriveEntry>, tokio::time::Instant)>>,
    /// How much longer than its interval the last polled drive's values waited, µs
    /// ([`BusEntry::poll_lag`]).
    pub(super) poll_lag_us: AtomicU64,
    /// The simulated drives of a virtual bus.
    #[cfg(feature = "virtual")]
    pub line: Option<Arc<std::sync::Mutex<VirtualLine>>>,
}

impl BusEntry {
    /// Master or standby, with the takeovers and yields, when the bus shares its line with
    /// another gateway (`[standby]`); `None` for the only master.
    pub fn role_status(&self) -> Option<drivebus_link::role::RoleStatus> {
        self.bus.role()
    }

    /// Master (it polls) or standby (it listens); the only master is master.
    pub fn role(&self) -> drivebus_link::role::Role {
        self.role_status().map_or(drivebus_link::role::Role::Master, |s| s.role)
    }

    /// How much longer than its poll interval the values of the bus's last polled drive waited
    /// for that poll (since its last poll ended or a command's refresh read it). Above zero for
    /// long, the line cannot poll its drives at their `poll_ms` (the silences, the requests, the
    /// drives' reply delays and the replies of one round take longer than the interval, or
    /// commands take the rest): each drive is then polled once a round.
    pub fn poll_lag(&self) -> std::time::Duration {
        std::time::Duration::from_micros(self.poll_lag_us.load(Ordering::Relaxed))
    }

    /// The bus owner's counts.
    pub fn stats(&self) -> BusStats {
        self.bus.stats()
    }

    /// False after the port failed, until a poll is answered again.
    pub fn online(&self) -> bool {
        self.online.load(Ordering::Relaxed)
    }

    /// The bus owner, for requests a front end passes through as they are (a Modbus bridge).
    pub fn owner(&self) -> &Bus {
        &self.bus
    }
}
