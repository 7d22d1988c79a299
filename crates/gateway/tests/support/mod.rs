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

/// A template (kind `gw-bits`) with a bit command word, a "0x4000 = 100 %" setpoint and two
/// named values, `dc_bus_v` (V) and `power_kw` (kW), which the simulator fills.
pub const BITS: &str = r#"kind = "gw-bits"
maker = "Test"
model = "B1"
source = "written for this test"
protocols = ["modbus-rtu"]
[serial]
baud = 19200
format = "8E1"
[status]
running = { register = 100, bit = 0 }
reverse = { register = 100, bit = 1 }
output_hz = { register = 101, scale = 0.1 }
current_a = { register = 102, scale = 0.01 }
fault = { register = 103 }
[values]
dc_bus_v = { register = 104, unit = "V" }
power_kw = { register = 105, scale = 0.1, unit = "kW" }
[command]
register = 200
run = { bit = 0 }
reverse = { bit = 1 }
reset = { bit = 7 }
[setpoint]
register = 201
full_scale = 0x4000
max_hz = 60.0
[[param]]
name = "acc"
title = "acceleration time"
register = 300
unit = "s"
scale = 0.1
range = [0.1, 3600.0]
default = 10.0
[faults]
7 = "external fault"
"#;

/// The configuration `text` as read from `plant.toml` in a new folder `drivebus-<name>-<pid>` of
/// the temp directory, beside [`BITS`] as `bits.toml` (so `templates = ["bits.toml"]` finds it):
/// the folder and the checked configuration.
pub fn with_bits_template(name: &str, text: &str) -> (PathBuf, drivebus_gateway::GatewayConfig) {
    let dir = std::env::temp_dir().join(format!("drivebus-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("bits.toml"), BITS).unwrap();
    let config = dir.join("plant.toml");
    std::fs::write(&config, text).unwrap();
    let c = drivebus_gateway::GatewayConfig::from_toml(&config.display().to_string(), text)
        .unwrap_or_else(|e| panic!("{e}"));
    (dir, c)
}
