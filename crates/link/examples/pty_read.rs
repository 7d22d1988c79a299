//! Reads 2 registers at 2100H from drive 1 (Modbus RTU) in a tight loop for a number of
//! seconds, and prints reads/s and latency percentiles: the drivebus clients of
//! `bench/pty_clients.sh`. `blocking` (the default) runs the blocking bus in this thread
//! (`drivebus_link::blocking::BlockingBus`, printed as `drivebus`); `async` runs the bus owner
//! task on a tokio runtime (printed as `drivebus-async`).
//!
//! ```text
//! cargo run --release -p drivebus-link --example pty_read -- PORT SECONDS [GAP_MS] [blocking|async]
//! ```

use std::time::{Duration, Instant};

use drivebus_drive::profile::Exchange;
use drivebus_link::blocking::BlockingBus;
use drivebus_link::drive::open_with;
use drivebus_link::{BusConfig, Priority};
use drivebus_proto::checksum::crc16_modbus;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let (Some(port), Some(secs)) = (args.get(1), args.get(2).and_then(|s| s.parse::<f64>().ok())) else {
        eprintln!("usage: pty_read PORT SECONDS [GAP_MS]");
        std::process::exit(3);
    };
    let gap_ms = args.get(3).and_then(|s| s.parse::<f64>().ok()).unwrap_or(0.0);
    let mut config = match "8N1".parse() {
        Ok(format) => BusConfig::new(drivebus_proto::protocol::WireProtocol::ModbusRtu, 115_200, format),
        Err(e) => {
            eprintln!("pty_read: {e}");
            std::process::exit(3);
        }
    };
    config.gap = Some(Duration::from_secs_f64(gap_ms / 1000.0));
    config.retries = 0;
    config.response_timeout = Some(Duration::from_millis(500));
    let (name, result) = match args.get(4).map(String::as_str) {
        None | Some("blocking") => ("drivebus", blocking_loop(port, config, secs)),
        Some("async") => ("drivebus-async", async_main(port, config, secs)),
        Some(other) => {
            eprintln!("pty_read: unknown mode {other:?}: use blocking or async");
            std::process::exit(3);
        }
    };
    report(name, result);
}

/// The async bus owner on a current-thread runtime.
fn async_main(port: &str, config: BusConfig, secs: f64) -> Result<(Vec<Duration>, u64, Duration), String> {
    let rt = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("pty_read: cannot start a runtime: {e}");
            std::process::exit(2);
        }
    };
    rt.block_on(async {
        let bus = open_with(port, config).await.map_err(|e| e.to_string())?;
        // The loop runs as a task beside the bus owner, as the gateway's pollers do: waking the
        // owner is then a local queue push, not a wake-up of the runtime's driver.
        tokio::spawn(async move { read_loop(bus, secs).await }).await.map_err(|e| e.to_string())?
    })
}

/// The blocking bus in this thread.
fn blocking_loop(port: &str, config: BusConfig, secs: f64) -> Result<(Vec<Duration>, u64, Duration), String> {
    let mut bus = BlockingBus::open(port, config).map_err(|e| e.to_string())?;
    let ex = Exchange { request: request(), expect_reply: true };
    let mut latencies = Vec::with_capacity(1 << 20);
    let mut errors = 0u64;
    let start = Instant::now();
    let end = start + Duration::from_secs_f64(secs);
    // One clock reading per read: the end of one is the start of the next.
    let mut t0 = start;
    while t0 < end {
        let ok = matches!(bus.transact(1, &ex, Priority::Command, None),
            Ok(Some(reply)) if reply.len() == 9 && reply[2] == 4);
        let t1 = Instant::now();
        if ok {
            latencies.push(t1 - t0);
        } else {
            errors += 1;
        }
        t0 = t1;
    }
    Ok((latencies, errors, start.elapsed()))
}

/// Read 2 registers at 2100H from drive 1.
fn request() -> Vec<u8> {
    let mut request = vec![0x01, 0x03, 0x21, 0x00, 0x00, 0x02];
    let crc = crc16_modbus(&request);
    request.extend_from_slice(&crc.to_le_bytes());
    request
}

fn report(name: &str, result: Result<(Vec<Duration>, u64, Duration), String>) {
    match result {
        Ok((mut lat, errors, elapsed)) => {
            lat.sort();
            let pct = |p: f64| lat.get(((lat.len() as f64 * p) as usize).min(lat.len().saturating_sub(1)));
            let us = |d: Option<&Duration>| d.map_or(0.0, |d| d.as_secs_f64() * 1e6);
            println!(
                "{name} reads={} errors={} seconds={:.2} reads_per_s={:.0} p50_us={:.1} p99_us={:.1}",
                lat.len(),
                errors,
                elapsed.as_secs_f64(),
                lat.len() as f64 / elapsed.as_secs_f64(),
                us(pct(0.50)),
                us(pct(0.99)),
            );
        }
        Err(e) => {
            eprintln!("pty_read: {e}");
            std::process::exit(2);
        }
    }
}

/// Reads for `secs` seconds: (latencies, errors, elapsed).
async fn read_loop(bus: drivebus_link::Bus, secs: f64) -> Result<(Vec<Duration>, u64, Duration), String> {
    let request = request();
    let mut latencies = Vec::with_capacity(1 << 20);
    let mut errors = 0u64;
    let start = Instant::now();
    let end = start + Duration::from_secs_f64(secs);
    while Instant::now() < end {
        let t0 = Instant::now();
        let ex = Exchange { request: request.clone(), expect_reply: true };
        match bus.transact(1, ex, Priority::Command, None).await {
            Ok(Some(reply)) if reply.len() == 9 && reply[2] == 4 => latencies.push(t0.elapsed()),
            _ => errors += 1,
        }
    }
    Ok::<_, String>((latencies, errors, start.elapsed()))
}
