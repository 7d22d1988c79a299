//! The gateway: the [`Gateway`] every front end holds, what it runs ([`Topology`], swapped whole by
//! a reload), its counters and its accessors. The other files of this folder add its methods.

use std::any::Any;
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64};
use std::sync::{Arc, Mutex, OnceLock, RwLock};

use drivebus_drive::Family;
use drivebus_store::Store;
use tokio::sync::{broadcast, watch};

use super::cache::{BusEntry, DriveEntry};
use super::command::CommandError;
use super::views::{BusView, Change, DriveView};
use crate::config::GatewayConfig;
use crate::refusals::Refusals;

/// How often the buses' roles are looked at for [`Gateway::mastering`].
pub const ROLE_WATCH: std::time::Duration = std::time::Duration::from_millis(50);

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
    pub(super) index: HashMap<String, usize>,
    pub(super) units: Vec<Option<usize>>,
}

impl Topology {
    /// What runs with `config`: `buses` and their drives, indexed by name and unit id.
    pub(super) fn new(config: GatewayConfig, buses: Vec<Arc<BusEntry>>) -> Topology {
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
    pub(super) topology: RwLock<Arc<Topology>>,
    /// Serializes reloads (one SIGHUP at a time).
    pub(super) reloading: tokio::sync::Mutex<()>,
    pub(super) changes: broadcast::Sender<Change>,
    pub(super) store: Option<Store>,
    /// Counters for metrics.
    pub counters: Counters,
    pub(super) log_events: AtomicBool,
    pub(super) health: crate::health::Health,
    pub(super) limits: crate::limits::Limits,
    /// Refused writes counted per client and reason ([`Gateway::audit_refusal`]).
    pub(super) refusals: Mutex<Refusals>,
    /// The front ends' own state: one value, `metrics::FrontEnds`, which lists all of it
    /// ([`Gateway::attached`]).
    pub(super) attached: OnceLock<Arc<dyn Any + Send + Sync>>,
    /// Wakes the store's check before its time (a reload may change `[store] min_free_mb`).
    pub(super) store_recheck: tokio::sync::Notify,
    /// One lane per drive: commands in the order handed over ([`Gateway::in_lane`]).
    pub(super) lanes: super::lanes::Lanes,
    /// Bus scans, their progress and findings, by bus (`Gateway::start_scan`).
    pub(super) scans: super::scan::Scans,
    /// Whether the gateway masters at least one bus ([`Gateway::mastering`]).
    pub(super) mastering: watch::Sender<bool>,
}

impl Gateway {
    /// A gateway that runs `topology` (its schedulers not started yet) and records to `store`.
    pub(super) fn new(topology: Topology, store: Option<Store>) -> Gateway {
        let limits = crate::limits::Limits::new(topology.config.limits.clone());
        Gateway {
            topology: RwLock::new(Arc::new(topology)),
            reloading: tokio::sync::Mutex::new(()),
            changes: broadcast::channel(1024).0,
            store,
            counters: Counters::default(),
            log_events: AtomicBool::new(false),
            health: crate::health::Health::default(),
            limits,
            refusals: Mutex::new(Refusals::default()),
            attached: OnceLock::new(),
            store_recheck: tokio::sync::Notify::new(),
            lanes: super::lanes::Lanes::default(),
            scans: super::scan::Scans::default(),
            mastering: watch::channel(true).0,
        }
    }

    /// What runs now (configuration, buses, drives): one consistent snapshot.
    pub fn topology(&self) -> Arc<Topology> {
        self.topology.read().unwrap_or_else(|p| p.into_inner()).clone()
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

    /// The API view of a drive.
    pub fn drive_view(&self, d: &DriveEntry) -> DriveView {
        DriveView::of(d)
    }

    /// The API view of a bus.
    pub fn bus_view(&self, b: &BusEntry) -> BusView {
        BusView::of(b, &self.drives())
    }

    /// True while the gateway masters at least one of its buses: always without `[standby]`
    /// (and with no bus at all); with it, from the first bus it takes (at start or by a
    /// takeover) until it yields or listens on every bus. MQTT and Sparkplug B publish only
    /// then (docs/gateway.md, "A warm standby"). The receiver sees each change within
    /// [`ROLE_WATCH`].
    pub fn mastering(&self) -> watch::Receiver<bool> {
        self.mastering.subscribe()
    }

    /// Whether the gateway masters at least one bus now, from the buses' roles (see
    /// [`Gateway::mastering`]).
    pub fn masters_any_bus(&self) -> bool {
        let buses = self.buses();
        buses.is_empty() || buses.iter().any(|b| b.role() == drivebus_link::role::Role::Master)
    }

    /// Subscribes to live changes.
    pub fn subscribe(&self) -> broadcast::Receiver<Change> {
        self.changes.subscribe()
    }

    /// The front ends' state attached to this gateway, made with `T::default()` on first use:
    /// the front ends keep their counts there, one value per gateway, without the core knowing
    /// its type. There is one such type, `metrics::FrontEnds`, the one place that lists what
    /// each front end attaches; `metrics::attached` is the accessor the front ends use.
    pub fn attached<T: Any + Send + Sync + Default>(&self) -> Arc<T> {
        let any = self.attached.get_or_init(|| Arc::new(T::default())).clone();
        any.downcast::<T>().unwrap_or_else(|_| {
            unreachable!("one type is attached to a gateway: metrics::FrontEnds, through metrics::attached")
        })
    }

    /// The bus scans, by bus.
    pub(crate) fn scans(&self) -> &super::scan::Scans {
        &self.scans
    }

    /// Why the gateway is not ready (empty when it is): listeners down, store not writable at
    /// its last check (`/readyz`, the `drivebus_ready` metric). Touches no file.
    pub fn not_ready(&self) -> Vec<String> {
        self.health.not_ready()
    }

    /// Checks the store now ([`crate::health::store_writable`]: `statvfs`, `access`, an open
    /// for appending) and keeps the verdict in [`Gateway::health`]. Blocking: a store on a slow
    /// disk may take a while.
    pub fn check_store(&self) {
        let config = self.config();
        let verdict =
            config.store.as_deref().map(|p| crate::health::store_writable(p, config.store_min_free_mb));
        self.health.store_checked(verdict);
    }

    /// Checks the store every [`crate::health::STORE_CHECK_EVERY`] and after each reload, off
    /// the async workers, so that `/readyz` and `/metrics` read a kept verdict and touch no
    /// file.
    pub(super) async fn check_store_every(self: Arc<Self>) {
        loop {
            tokio::select! {
                _ = tokio::time::sleep(crate::health::STORE_CHECK_EVERY) => {}
                _ = self.store_recheck.notified() => {}
            }
            let gw = self.clone();
            if tokio::task::spawn_blocking(move || gw.check_store()).await.is_err() {
                self.health.store_checked(Some(Err("store: the check of the store failed".into())));
            }
        }
    }

    /// Family name of a drive (for front ends that show it).
    pub fn family(d: &DriveEntry) -> Family {
        d.config.family
    }
}
