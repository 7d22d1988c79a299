//! Start-up and reload: buses and drives built from the configuration, the gateway started,
//! and a new configuration put in place restarting only what changed.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicU8, Ordering};
use std::sync::{Arc, Mutex, RwLock};

use drivebus_link::drive::Drive;
use drivebus_link::owner::{Bus, BusConfig as OwnerConfig};
use drivebus_store::time::now_ms;
use drivebus_store::{Event, EventKind, Store};
use serde_json::json;
use tokio::sync::Notify;

use super::cache::{BusEntry, DriveEntry, DriveState};
use super::gateway::{Gateway, Topology};
use super::linkage::LINKAGE_NONE;
use crate::config::{BusConfig, DriveConfig, GatewayConfig, HttpConfig};
#[cfg(feature = "virtual")]
use drivebus_link::port::VirtualPort;
use drivebus_link::port::{Port as LinkPort, SerialSettings};
use drivebus_link::PortLink;

impl Gateway {
    /// Builds every bus and drive of `config` and starts polling (on the current tokio runtime).
    /// `store` receives events and trends.
    pub fn start(config: GatewayConfig, store: Option<Store>) -> Result<Arc<Gateway>, String> {
        let buses = config.buses.iter().map(build_bus).collect::<Result<Vec<_>, _>>()?;
        let gw = Arc::new(Gateway::new(Topology::new(config, buses), store));
        let topo = gw.topology();
        gw.record(Event {
            id: 0,
            time_ms: now_ms(),
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
        gw.mastering.send_replace(gw.masters_any_bus());
        tokio::spawn(gw.clone().watch_roles());
        tokio::spawn(gw.clone().close_refusal_windows());
        // The first verdict before any front end asks; the next ones on their schedule.
        gw.check_store();
        tokio::spawn(gw.clone().check_store_every());
        Ok(gw)
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
        // The listener stays as it runs (address, TLS): its tokens are checked against it.
        let running = HttpConfig {
            listen: old.config.http.listen,
            tls: old.config.http.tls.clone(),
            ..new.http.clone()
        };
        if let Some(why) = running.plaintext_refusal(&new.tokens) {
            return Err(why);
        }
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
        self.store_recheck.notify_one();
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
            time_ms: now_ms(),
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
    owner.role = b.role;
    owner.modbus_tcp = matches!(b.port, crate::config::Port::ModbusTcp(_));
    // Opened by the bus owner before its first transaction, and again after a loss.
    let port = match &b.port {
        crate::config::Port::Serial(path) => LinkPort::Serial(SerialSettings {
            path: path.clone(),
            baud: b.baud,
            format: b.format,
            rs485: b.rs485,
        }),
        crate::config::Port::Tcp(addr) => LinkPort::Tcp(addr.clone()),
        crate::config::Port::ModbusTcp(addr) => LinkPort::ModbusTcp(addr.clone()),
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
    let bus = match port {
        // Requests pipelined: the owner carries MBAP itself on a plain TCP connection.
        LinkPort::ModbusTcp(addr) if b.max_in_flight > 1 => {
            owner.max_in_flight = b.max_in_flight;
            Bus::spawn_pipelined(PortLink::new(LinkPort::Tcp(addr)), owner)
        }
        port => Bus::spawn(PortLink::new(port), owner),
    }
    .map_err(|e| format!("bus {}: {e}", b.name))?;
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
        refreshed: Mutex::new(Vec::new()),
        poll_lag_us: AtomicU64::new(0),
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
        protocol_name: b.protocol_name(),
        command,
        poll,
        params: crate::params::ParamCache::new(b.param_cache),
        state: RwLock::new(DriveState::default()),
        locked: AtomicBool::new(d.locked),
        linking: AtomicBool::new(false),
        linkage: AtomicU8::new(LINKAGE_NONE),
    })
}
