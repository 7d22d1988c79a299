//! tokio-modbus client of `bench/pty_clients.sh`: reads 2 registers at 2100H from drive 1
//! (Modbus RTU) in a tight loop for SECONDS and prints reads/s and latency percentiles.

use std::time::{Duration, Instant};

use tokio_modbus::client::Reader;
use tokio_modbus::prelude::*;

#[tokio::main(flavor = "current_thread")]
async fn main() {
    let args: Vec<String> = std::env::args().collect();
    let (Some(port), Some(secs)) = (args.get(1), args.get(2).and_then(|s| s.parse::<f64>().ok())) else {
        eprintln!("usage: tokio-modbus-client PORT SECONDS");
        std::process::exit(3);
    };
    let serial = match tokio_serial::SerialStream::open(&tokio_serial::new(port, 115_200)) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("tokio-modbus-client: cannot open {port}: {e}");
            std::process::exit(2);
        }
    };
    let mut ctx = rtu::attach_slave(serial, Slave(1));
    let mut lat = Vec::with_capacity(1 << 20);
    let mut errors = 0u64;
    let start = Instant::now();
    let end = start + Duration::from_secs_f64(secs);
    while Instant::now() < end {
        let t0 = Instant::now();
        let r = tokio::time::timeout(Duration::from_millis(500), ctx.read_holding_registers(0x2100, 2)).await;
        match r {
            Ok(Ok(Ok(regs))) if regs.len() == 2 => lat.push(t0.elapsed()),
            _ => errors += 1,
        }
    }
    let elapsed = start.elapsed();
    lat.sort();
    let pct = |p: f64| lat.get(((lat.len() as f64 * p) as usize).min(lat.len().saturating_sub(1)));
    let us = |d: Option<&Duration>| d.map_or(0.0, |d| d.as_secs_f64() * 1e6);
    println!(
        "tokio-modbus reads={} errors={} seconds={:.2} reads_per_s={:.0} p50_us={:.1} p99_us={:.1}",
        lat.len(),
        errors,
        elapsed.as_secs_f64(),
        lat.len() as f64 / elapsed.as_secs_f64(),
        us(pct(0.50)),
        us(pct(0.99)),
    );
}
