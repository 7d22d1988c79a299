//! Health for the monitoring that watches the box: `GET /healthz` (the process answers) and
//! `GET /readyz` (every configured listener is up and the store is writable; 503 with the
//! reasons otherwise). Both are open without a token and say nothing about drives. The same
//! facts are metrics (`drivebus_ready`, `drivebus_listener_up`, `drivebus_store_writable`,
//! `drivebus_config_reloads_total`, `drivebus_config_reload_failed`; docs/metrics.md).

use std::net::SocketAddr;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use axum::extract::State;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use serde_json::json;

use crate::gateway::Gateway;

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

/// Why the gateway is not ready (empty when it is): listeners down, store not writable.
pub fn not_ready(gw: &Gateway) -> Vec<String> {
    let mut why: Vec<String> = gw
        .health()
        .listeners()
        .into_iter()
        .filter(|l| !l.up)
        .map(|l| format!("{} listener on {} is not up", l.name, l.addr))
        .collect();
    if let Some(path) = &gw.config().store {
        if let Err(e) = store_writable(path) {
            why.push(e);
        }
    }
    why
}

/// `/healthz` and `/readyz`, to merge into the HTTP router (no token needed).
pub fn routes() -> Router<Arc<Gateway>> {
    Router::new().route("/healthz", get(healthz)).route("/readyz", get(readyz))
}

async fn healthz() -> Response {
    Json(json!({ "status": "ok" })).into_response()
}

async fn readyz(State(gw): State<Arc<Gateway>>) -> Response {
    let gw2 = gw.clone();
    // The store check touches the disk: off the async workers.
    let why = tokio::task::spawn_blocking(move || not_ready(&gw2))
        .await
        .unwrap_or_else(|e| vec![format!("the readiness check failed: {e}")]);
    if why.is_empty() {
        Json(json!({ "ready": true })).into_response()
    } else {
        (StatusCode::SERVICE_UNAVAILABLE, Json(json!({ "ready": false, "reasons": why }))).into_response()
    }
}
