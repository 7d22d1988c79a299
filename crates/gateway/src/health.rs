//! Health for the monitoring that watches the box: which configured listeners are up, whether
//! the store takes writes, how reloads went. `GET /healthz` and `GET /readyz` serve these facts
//! (`http::health`; 503 with the reasons when not ready). The same facts are metrics
//! (`drivebus_ready`, `drivebus_listener_up`, `drivebus_store_writable`,
//! `drivebus_config_reloads_total`, `drivebus_config_reload_failed`; docs/metrics.md).
//!
//! Reading these facts touches no file: the store's check ([`store_writable`]) runs on its own
//! schedule, every [`STORE_CHECK_EVERY`] and after each reload (`Gateway::check_store_every`),
//! and its verdict is kept here ([`Health::store_checked`]) for `/readyz` and `/metrics`.

use std::net::SocketAddr;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::Duration;

/// How often the store's writability and free space are checked (and after each reload).
pub const STORE_CHECK_EVERY: Duration = Duration::from_secs(5);

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

/// A Modbus RTU slave's port (`[[modbus_rtu]]`): the device and, while it is down, why.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SlavePort {
    /// The serial device.
    pub port: String,
    /// Why it is not served now (`None`: open and served).
    pub down: Option<String>,
}

/// What the health checks report, kept by the gateway.
#[derive(Debug, Default)]
pub struct Health {
    listeners: Mutex<Vec<Listener>>,
    slaves: Mutex<Vec<SlavePort>>,
    reloads_ok: AtomicU64,
    reloads_failed: AtomicU64,
    last_reload_failed: AtomicBool,
    last_reload_error: Mutex<Option<String>>,
    /// The last verdict of the store's check; `None` without a store.
    store: Mutex<Option<Result<(), String>>>,
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

    /// Says that the Modbus RTU slave on `port` is served (`down` is `None`) or why it is not.
    pub fn slave_port(&self, port: &str, down: Option<String>) {
        let mut l = self.slaves.lock().unwrap_or_else(|p| p.into_inner());
        match l.iter_mut().find(|x| x.port == port) {
            Some(x) => x.down = down,
            None => l.push(SlavePort { port: port.to_string(), down }),
        }
    }

    /// Every Modbus RTU slave's port.
    pub fn slave_ports(&self) -> Vec<SlavePort> {
        self.slaves.lock().unwrap_or_else(|p| p.into_inner()).clone()
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

    /// Keeps the verdict of the store's check ([`store_writable`]; `None`: there is no store).
    pub fn store_checked(&self, verdict: Option<Result<(), String>>) {
        *self.store.lock().unwrap_or_else(|p| p.into_inner()) = verdict;
    }

    /// The verdict of the last check of the store (`None`: there is no store).
    pub fn store_verdict(&self) -> Option<Result<(), String>> {
        self.store.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// Why the gateway is not ready (empty when it is): a configured listener is not up, a
    /// Modbus RTU slave's port is down, the store did not take writes or its filesystem had
    /// less than `[store] min_free_mb` free at its last check ([`Health::store_checked`]).
    /// Touches no file.
    pub fn not_ready(&self) -> Vec<String> {
        let mut why: Vec<String> = self
            .listeners()
            .into_iter()
            .filter(|l| !l.up)
            .map(|l| format!("{} listener on {} is not up", l.name, l.addr))
            .collect();
        for p in self.slave_ports() {
            if let Some(e) = p.down {
                why.push(format!("Modbus RTU slave on {} is down: {e}", p.port));
            }
        }
        if let Some(Err(e)) = self.store_verdict() {
            why.push(e);
        }
        why
    }

    /// The error of the last reload, while the last one failed.
    pub fn last_reload_error(&self) -> Option<String> {
        self.last_reload_error.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }
}

/// The space left on a filesystem, as `statvfs` tells it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Space {
    /// Bytes an unprivileged process may still write (`f_bavail` blocks).
    pub free_bytes: u64,
    /// Mounted read-only.
    pub read_only: bool,
}

/// The space of the filesystem that holds `dir` (`statvfs`: nothing is written).
pub fn space_of(dir: &Path) -> Result<Space, String> {
    use nix::sys::statvfs::{statvfs, FsFlags};
    let s =
        statvfs(dir).map_err(|e| format!("store: cannot see the filesystem of {}: {e}", dir.display()))?;
    // 32 bits wide on 32-bit targets (armhf), 64 on the others.
    #[allow(clippy::useless_conversion)]
    let free_bytes = u64::from(s.blocks_available()).saturating_mul(u64::from(s.fragment_size()));
    Ok(Space { free_bytes, read_only: s.flags().contains(FsFlags::ST_RDONLY) })
}

/// Whether `space`, that of the filesystem holding the store's folder `dir`, is enough: not
/// read-only, at least `min_free_mb` MiB free (0: any). `Err` says what is short.
pub fn enough_space(dir: &Path, space: Space, min_free_mb: u64) -> Result<(), String> {
    const MIB: u64 = 1 << 20;
    if space.read_only {
        return Err(format!("store: the filesystem of {} is read-only", dir.display()));
    }
    if space.free_bytes < min_free_mb.saturating_mul(MIB) {
        return Err(format!(
            "store: {} MiB free on the filesystem of {}, below [store] min_free_mb = {min_free_mb}",
            space.free_bytes / MIB,
            dir.display()
        ));
    }
    Ok(())
}

/// Whether the store at `path` can take writes now: its filesystem has `min_free_mb` MiB free
/// and is not read-only, its folder may be written and the store itself opens for writing.
/// Nothing is created: `statvfs`, `access` and an open for appending. `Err` says why not.
pub fn store_writable(path: &Path, min_free_mb: u64) -> Result<(), String> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => std::path::PathBuf::from("."),
    };
    nix::unistd::access(&dir, nix::unistd::AccessFlags::W_OK)
        .map_err(|e| format!("store: cannot write in {}: {e}", dir.display()))?;
    enough_space(&dir, space_of(&dir)?, min_free_mb)?;
    std::fs::OpenOptions::new()
        .append(true)
        .open(path)
        .map(drop)
        .map_err(|e| format!("store: cannot write {}: {e}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn free_space_below_the_threshold_or_a_read_only_filesystem_is_not_ready() {
        let dir = Path::new("/var/lib/drivebus");
        let mib = |n: u64| n << 20;
        let space = |free_bytes, read_only| Space { free_bytes, read_only };
        assert_eq!(enough_space(dir, space(mib(64), false), 64), Ok(()));
        assert_eq!(
            enough_space(dir, space(mib(64) - 1, false), 64),
            Err("store: 63 MiB free on the filesystem of /var/lib/drivebus, below [store] min_free_mb = 64"
                .to_string())
        );
        assert_eq!(enough_space(dir, space(0, false), 0), Ok(()));
        assert_eq!(
            enough_space(dir, space(mib(1000), true), 64),
            Err("store: the filesystem of /var/lib/drivebus is read-only".to_string())
        );
    }

    #[test]
    fn the_store_check_reads_the_filesystem_and_creates_nothing() {
        let dir = std::env::temp_dir().join(format!("drivebus-health-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let db = dir.join("events.db");
        std::fs::write(&db, b"").unwrap();
        assert!(space_of(&dir).unwrap().free_bytes > 0);
        assert_eq!(store_writable(&db, 0), Ok(()));
        // No filesystem has this much free: the check says so, with the figure it saw.
        let e = store_writable(&db, u64::MAX >> 20).unwrap_err();
        assert!(e.contains("MiB free on the filesystem of") && e.contains("min_free_mb"), "{e}");
        assert!(store_writable(&dir.join("none.db"), 0).unwrap_err().starts_with("store: cannot write"));
        let files: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(files, ["events.db"], "the check left files behind");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
