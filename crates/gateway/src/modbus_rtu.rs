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
use drivebus_proto::line::{modbus_t15_t35, CharFormat};
use drivebus_proto::modbus::rtu::RtuScanner;
use drivebus_proto::{Deframer, Event};
use serde::Deserialize;
use toml::Spanned;

use crate::bridge::bus_frame;
use crate::config::{ConfigError, Ctx};
use crate::gateway::Gateway;
use crate::modbus_tcp::{Conn, Server};

/// One `[[modbus_rtu]]` slave.
#[derive(Clone, Debug, PartialEq)]
pub struct ModbusRtuConfig {
    /// The serial device.
    pub port: String,
    /// Baud rate (default 19200).
    pub baud: u32,
    /// Character format (default 8E1).
    pub format: CharFormat,
    /// Accept writes (with `[modbus] read_only` off).
    pub write: bool,
}

impl ModbusRtuConfig {
    /// A slave on `port` at the Modbus serial-line defaults (19200 8E1), read-only.
    pub fn new(port: &str) -> Self {
        ModbusRtuConfig { port: port.to_string(), baud: 19200, format: CharFormat::EVEN_8E1, write: false }
    }
}

/// A `[[modbus_rtu]]` as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct FileModbusRtu {
    port: Spanned<String>,
    baud: Option<Spanned<u32>>,
    serial: Option<Spanned<String>>,
    #[serde(default)]
    write: bool,
}

/// Reads the `[[modbus_rtu]]` sections.
pub(crate) fn configs(cx: &Ctx<'_>, file: &[FileModbusRtu]) -> Result<Vec<ModbusRtuConfig>, ConfigError> {
    let mut out: Vec<ModbusRtuConfig> = Vec::new();
    for m in file {
        let mut c = ModbusRtuConfig::new(m.port.get_ref());
        if c.port.is_empty() || c.port.starts_with("tcp://") || c.port == "virtual" {
            return cx.err(m.port.span(), "modbus_rtu.port", "give a serial device, e.g. /dev/ttyS1");
        }
        if out.iter().any(|x| x.port == c.port) {
            return cx.err(
                m.port.span(),
                "modbus_rtu.port",
                format!("{} is already another slave's", c.port),
            );
        }
        if let Some(b) = &m.baud {
            if !(300..=4_000_000).contains(b.get_ref()) {
                return cx.err(
                    b.span(),
                    "modbus_rtu.baud",
                    format!("{} is outside 300..4000000", b.get_ref()),
                );
            }
            c.baud = *b.get_ref();
        }
        if let Some(s) = &m.serial {
            c.format = s.get_ref().parse().or_else(|e| cx.err(s.span(), "modbus_rtu.serial", e))?;
        }
        c.write = m.write;
        out.push(c);
    }
    Ok(out)
}

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
