//! The gateway as a Modbus RTU slave: a PLC on RS-485 reads the same unified register map as
//! Modbus TCP clients do (docs/register-map.md), each drive at its unit id as the slave address,
//! with the same handling ([`crate::modbus_tcp`]): reads from the cache, parameter reads and
//! writes through the drive. Writes are refused (exception 01, audited) unless the section
//! says `write = true` and `[modbus] read_only` is off (as configured when the write comes: a
//! reload applies).
//!
//! ```toml
//! [[modbus_rtu]]
//! port = "/dev/ttyS1"
//! baud = 19200        # default 19200
//! serial = "8E1"      # default 8E1, as the Modbus serial-line specification says
//! write = false
//! ```
//!
//! Requests are framed by their length and CRC and by the t3.5 silence; a request to an address
//! that is no drive's unit id, and a broadcast (address 0), get no answer (another slave on the
//! line may have that address). An answer goes out t3.5 after the request's last byte.
//!
//! The port is a bus's port like the others: missing at start or lost later, it is opened again
//! on the buses' schedule ([`Backoff`]: at once after a loss, then 250 ms doubling to 5 s) while
//! the rest of `serve` runs; meanwhile `/readyz` and `drivebus_modbus_rtu_up` name it, and the
//! log (log.rs) says when it goes down and when it is back.

use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

use drivebus_link::{Backoff, Link, SerialLink};
use drivebus_proto::line::modbus_t15_t35;
use drivebus_proto::modbus::rtu::RtuScanner;
use drivebus_proto::{Deframer, Event};

use crate::bridge::bus_frame;
// A slave's settings are the configuration's (config/modbus_rtu.rs).
pub use crate::config::ModbusRtuConfig;
use crate::core::Gateway;
use crate::health::Health;
use crate::log;
use crate::modbus_tcp::{Conn, Server};

/// Serves the unified map on `cfg.port` for as long as the gateway runs: opens the port,
/// serves it until it fails, and opens it again on the buses' schedule while it will not open.
pub async fn run(gw: Arc<Gateway>, cfg: ModbusRtuConfig) {
    // An open error names its port already ("cannot open serial port /dev/ttyS1: ...").
    let open = || {
        SerialLink::open(&cfg.port, cfg.baud, cfg.format).map_err(|e| match e.to_string() {
            named if named.contains(&cfg.port) => named,
            other => format!("{}: {other}", cfg.port),
        })
    };
    let health = gw.clone();
    keep_open(health.health(), &cfg.port, open, |link| serve(gw.clone(), cfg.clone(), link)).await
}

/// Opens the port with `open` and serves it with `serve` until that ends with the port's error,
/// forever: a lost port is opened again at once, one that will not open after the [`Backoff`]'s
/// waits. `health` says meanwhile whether the port is served; the log says when it goes down
/// (once per error) and when it is back.
async fn keep_open<L, F>(
    health: &Health,
    port: &str,
    mut open: impl FnMut() -> Result<L, String>,
    mut serve: impl FnMut(L) -> F,
) where
    F: Future<Output = std::io::Error>,
{
    let mut backoff = Backoff::new();
    let mut said: Option<String> = None;
    health.slave_port(port, Some("not opened yet".to_string()));
    loop {
        match open() {
            Ok(link) => {
                if said.take().is_some() {
                    log::info(&format!("the Modbus RTU slave on {port} is open again"));
                }
                health.slave_port(port, None);
                backoff = Backoff::new();
                let e = format!("lost its port: {}", serve(link).await);
                log::warn(&format!("the Modbus RTU slave on {port} {e}; opening it again"));
                health.slave_port(port, Some(e.clone()));
                said = Some(e);
            }
            Err(e) => {
                if said.as_deref() != Some(e.as_str()) {
                    log::warn(&format!(
                        "the Modbus RTU slave ([[modbus_rtu]] / --modbus-rtu): {e}; trying again"
                    ));
                }
                health.slave_port(port, Some(e.clone()));
                said = Some(e);
                tokio::time::sleep(backoff.failed()).await;
            }
        }
    }
}

/// Serves the unified map on `link` until the port fails: that error.
async fn serve(gw: Arc<Gateway>, cfg: ModbusRtuConfig, mut link: SerialLink) -> std::io::Error {
    let server = Server::new(gw.clone());
    // `[modbus] read_only` is read at each write (modbus_tcp's `write`).
    let mut conn = Conn {
        ip: None,
        may_write: cfg.write,
        forbidden: format!(
            "forbidden: the Modbus RTU slave on {} is read-only ([[modbus_rtu]] write)",
            cfg.port
        ),
        actor: format!("modbus-rtu:{}", cfg.port),
    };
    let (_, t35) = modbus_t15_t35(cfg.baud);
    let mut deframer = Deframer::new(RtuScanner::requests());
    let mut buf = vec![0u8; 512];
    let mut mbap = Vec::with_capacity(260);
    let mut out = Vec::with_capacity(260);
    loop {
        let mut frames: Vec<Vec<u8>> = Vec::new();
        let mut collect = |e: Event<'_>| {
            if let Event::Frame { bytes, .. } = e {
                frames.push(bytes.to_vec());
            }
        };
        tokio::select! {
            n = link.read(&mut buf) => match n {
                Ok(n) => deframer.push(&buf[..n], &mut collect),
                Err(e) => return e,
            },
            _ = tokio::time::sleep(t35), if deframer.buffered() > 0 => deframer.silence(&mut collect),
        }
        let last_byte = tokio::time::Instant::now();
        for f in frames {
            let unit = f[0];
            if unit == 0 || gw.drive_by_unit(unit).is_none() {
                continue;
            }
            // The same request as Modbus TCP: an MBAP header, the PDU.
            mbap.clear();
            mbap.extend_from_slice(&[0, 0, 0, 0]);
            mbap.extend_from_slice(&((f.len() - 2) as u16).to_be_bytes());
            mbap.extend_from_slice(&f[..f.len() - 2]);
            out.clear();
            server.answer(&mut conn, &mbap, &mut out).await;
            if out.len() <= 7 {
                continue;
            }
            tokio::time::sleep_until(last_byte + t35.max(Duration::from_micros(1))).await;
            if let Err(e) = link.write(&bus_frame(false, unit, &out[7..])).await {
                return e;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Mutex;

    use tokio::time::Instant;

    use super::*;

    /// A port that will not open is tried again after 250 ms, 500 ms, ... up to 5 s (the buses'
    /// schedule), `/readyz`'s facts name it meanwhile; open, it is served; lost, it is opened
    /// again at once. Paused clock: the waits are the clock's, not the machine's.
    #[tokio::test(start_paused = true)]
    async fn a_port_that_will_not_open_is_tried_again_on_the_buses_schedule() {
        let health = Health::default();
        let start = Instant::now();
        let tries = Mutex::new(Vec::new());
        let served = Mutex::new(0u32);
        let open = || {
            let mut t = tries.lock().unwrap();
            t.push(start.elapsed().as_millis() as u64);
            // The 5th try finds the port, which is lost at once; then it is missing again.
            if t.len() == 5 {
                Ok(())
            } else {
                Err(format!("cannot open /dev/ttyRTU: try {}", t.len()))
            }
        };
        let serve = |()| {
            *served.lock().unwrap() += 1;
            async { std::io::Error::new(std::io::ErrorKind::UnexpectedEof, "/dev/ttyRTU closed") }
        };
        let run = keep_open(&health, "/dev/ttyRTU", open, serve);
        assert!(tokio::time::timeout(Duration::from_millis(8_000), run).await.is_err(), "it gave up");
        // 250, 500, 1000, 2000 ms apart; open at 3750 and lost: opened again at once, then
        // 250, 500, 1000, 2000 ms apart again (the schedule starts over after an open).
        assert_eq!(tries.into_inner().unwrap(), [0, 250, 750, 1750, 3750, 3750, 4000, 4500, 5500, 7500]);
        assert_eq!(*served.lock().unwrap(), 1);
        let p = &health.slave_ports()[0];
        assert_eq!(p.port, "/dev/ttyRTU");
        assert_eq!(p.down.as_deref(), Some("cannot open /dev/ttyRTU: try 10"));
        assert!(health.not_ready()[0].starts_with("Modbus RTU slave on /dev/ttyRTU is down: "));
    }
}
