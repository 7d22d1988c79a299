//! Health for the monitoring that watches the box: which configured listeners are up, whether
//! the store takes writes, how reloads went. `GET /healthz` and `GET /readyz` serve these facts
//! (`http::health`; 503 with the reasons when not ready). The same facts are metrics
//! (`drivebus_ready`, `drivebus_listener_up`, `drivebus_store_writable`,
//! `drivebus_config_reloads_total`, `drivebus_config_reload_failed`; docs/metrics.md).

use std::net::SocketAddr;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Mutex;

/// A listener the configuration asks for (HTTP, Modbus TCP, ...).
#[derive(Clone, Debug)]
pub struct Listener {
    /// What it serves (`http`, `modbus`).
    pub name: String,
    /// Where it listens (the configured address until bound).
    pub addr: SocketAddr,
    /// Whether it accepts connections.
    pub up: bool,
}

/// What the health checks report, kept by the gateway.
#[derive(Debug, Default)]
pub struct Health {
    listeners: Mutex<Vec<Listener>>,
    reloads_ok: AtomicU64,
    reloads_failed: AtomicU64,
    last_reload_failed: AtomicBool,
    last_reload_error: Mutex<Option<String>>,
}

impl Health {
    /// Says that listener `name` is configured at `addr` and whether it is up now.
    pub fn listener(&self, name: &str, addr: SocketAddr, up: bool) {
        let mut l = self.listeners.lock().unwrap_or_else(|p| p.into_inner());
        match l.iter_mut().find(|x| x.name == name) {
            Some(x) => {
                x.addr = addr;
                x.up = up;
            }
            None => l.push(Listener { name: name.to_string(), addr, up }),
        }
    }

    /// Every configured listener.
    pub fn listeners(&self) -> Vec<Listener> {
        self.listeners.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// Counts a reload: `Ok` applied, `Err` refused with its reason.
    pub fn reloaded(&self, result: Result<(), &str>) {
        match result {
            Ok(()) => {
                self.reloads_ok.fetch_add(1, Ordering::Relaxed);
                self.last_reload_failed.store(false, Ordering::Relaxed);
                *self.last_reload_error.lock().unwrap_or_else(|p| p.into_inner()) = None;
            }
            Err(e) => {
                self.reloads_failed.fetch_add(1, Ordering::Relaxed);
                self.last_reload_failed.store(true, Ordering::Relaxed);
                *self.last_reload_error.lock().unwrap_or_else(|p| p.into_inner()) = Some(e.to_string());
            }
        }
    }

    /// Reloads applied and refused so far.
    pub fn reloads(&self) -> (u64, u64) {
        (self.reloads_ok.load(Ordering::Relaxed), self.reloads_failed.load(Ordering::Relaxed))
    }

    /// Why the gateway is not ready (empty when it is): a configured listener is not up, the
    /// store at `store` (when there is one) does not take writes.
    pub fn not_ready(&self, store: Option<&Path>) -> Vec<String> {
        let mut why: Vec<String> = self
            .listeners()
            .into_iter()
            .filter(|l| !l.up)
            .map(|l| format!("{} listener on {} is not up", l.name, l.addr))
            .collect();
        if let Some(path) = store {
            if let Err(e) = store_writable(path) {
                why.push(e);
            }
        }
        why
    }

    /// The error of the last reload, while the last one failed.
    pub fn last_reload_error(&self) -> Option<String> {
        self.last_reload_error.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }
}

/// Whether the store at `path` can take writes now: a file can be made (and removed) in its
/// folder and the store itself opens for writing. `Err` says why not.
pub fn store_writable(path: &Path) -> Result<(), String> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => std::path::PathBuf::from("."),
    };
    let probe = dir.join(format!(".drivebus-ready-{}", std::process::id()));
    std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(true)
        .open(&probe)
        .and_then(|_| std::fs::remove_file(&probe))
        .map_err(|e| format!("store: cannot write in {}: {e}", dir.display()))?;
    std::fs::OpenOptions::new()
        .append(true)
        .open(path)
        .map(drop)
        .map_err(|e| format!("store: cannot write {}: {e}", path.display()))
}
