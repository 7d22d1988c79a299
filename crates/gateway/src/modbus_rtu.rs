//! The gateway as a Modbus RTU slave: a PLC on RS-485 reads the same unified register map as
//! Modbus TCP clients do (docs/register-map.md), each drive at its unit id as the slave address,
//! with the same handling ([`crate::modbus_tcp`]): reads from the cache, parameter reads and
//! writes through the drive. Writes are refused (exception 01, audited) unless the section
//! says `write = true` and `[modbus] read_only` is off.
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

use std::sync::Arc;
use std::time::Duration;

use drivebus_link::{Link, SerialLink};
use drivebus_proto::line::modbus_t15_t35;
use drivebus_proto::modbus::rtu::RtuScanner;
use drivebus_proto::{Deframer, Event};

use crate::bridge::bus_frame;
// A slave's settings are the configuration's (config/modbus_rtu.rs).
pub use crate::config::ModbusRtuConfig;
use crate::gateway::Gateway;
use crate::modbus_tcp::{Conn, Server};

/// A Modbus RTU slave with its port open.
pub struct Slave {
    gw: Arc<Gateway>,
    cfg: ModbusRtuConfig,
    link: SerialLink,
}

impl Slave {
    /// Opens `cfg.port`; the error says which port and why.
    pub fn open(gw: Arc<Gateway>, cfg: &ModbusRtuConfig) -> Result<Slave, String> {
        let link = SerialLink::open(&cfg.port, cfg.baud, cfg.format)
            .map_err(|e| format!("the Modbus RTU slave ([[modbus_rtu]] / --modbus-rtu): {e}"))?;
        Ok(Slave { gw, cfg: cfg.clone(), link })
    }

    /// Serves the unified map until the port fails (said on stderr).
    pub async fn run(self) {
        let port = self.cfg.port.clone();
        if let Err(e) = self.serve().await {
            eprintln!("drivebus serve: the Modbus RTU slave on {port} stopped: {e}");
        }
    }

    async fn serve(self) -> std::io::Result<()> {
        let Slave { gw, cfg, mut link } = self;
        let server = Server::new(gw.clone());
        let read_only = gw.config().modbus.read_only;
        let mut conn = Conn {
            ip: None,
            may_write: cfg.write && !read_only,
            forbidden: if read_only {
                "forbidden: Modbus writes are off ([modbus] read_only)".to_string()
            } else {
                format!("forbidden: the Modbus RTU slave on {} is read-only ([[modbus_rtu]] write)", cfg.port)
            },
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
                n = link.read(&mut buf) => deframer.push(&buf[..n?], &mut collect),
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
                link.write(&bus_frame(false, unit, &out[7..])).await?;
            }
        }
    }
}
