//! What several of the gateway's integration tests need: a fresh store file, letting the tasks
//! run on the paused clock, and waiting for a condition in real time with a deadline (an event,
//! not a fixed sleep).

#![allow(dead_code)]

use std::path::PathBuf;
use std::time::{Duration, Instant};

use drivebus_store::Store;

/// A store in a new file `drivebus-<name>-<pid>.db` of the temp directory (one an earlier run
/// left is removed first): its path, for the test to remove at its end, and the store.
pub fn fresh_store(name: &str) -> (PathBuf, Store) {
    let path = std::env::temp_dir().join(format!("drivebus-{name}-{}.db", std::process::id()));
    let _ = std::fs::remove_file(&path);
    let store = Store::open(&path).unwrap();
    (path, store)
}

/// Lets the gateway's tasks run for `secs` seconds; on a paused clock (`start_paused`) sleeping
/// advances the virtual time as far as the tasks need.
pub async fn settle(secs: u64) {
    tokio::time::sleep(Duration::from_secs(secs)).await;
}

/// Waits until `ok` holds, checking every 20 ms, and fails the test after `limit`.
pub async fn wait_for(what: &str, limit: Duration, mut ok: impl FnMut() -> bool) {
    let start = Instant::now();
    while !ok() {
        assert!(start.elapsed() < limit, "timed out waiting for {what}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}
