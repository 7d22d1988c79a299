//! A transparent Modbus bridge (what mbusd does) on a bus the gateway also polls: a Modbus TCP
//! request for unit id N goes to address N on the bus, as RTU or ASCII as the bus speaks, through
//! the bus owner (after commands, ahead of polls: one transaction at a time with the polling),
//! and the drive's answer goes back as it came. Only the functions of the bridge's `functions`
//! list reach the bus (by default the reads, the writes and device identification); any other
//! is answered with exception 01. The `[modbus]` allow list and read-only switch apply to
//! writes, as configured when each write comes (a reload changes them for open connections
//! too). Every write is in the audit trail, and every refusal (aggregated, refusals.rs).
//!
//! ```toml
//! [[bridge]]
//! bus = "line-1"              # a modbus-rtu or modbus-ascii bus
//! listen = "127.0.0.1:5021"
//! framing = "mbap"            # mbap (Modbus TCP, the default) | rtu (RTU frames over TCP)
//! functions = [1, 2, 3, 4, 5, 6, 15, 16, 23, 43]   # the default (43: MEI type 14 only)
//! ```

use std::net::{IpAddr, SocketAddr};
use std::sync::Arc;

use drivebus_drive::profile::Exchange;
use drivebus_link::owner::{BusError, Priority};
use drivebus_proto::checksum::{crc16_modbus, lrc};
use drivebus_proto::modbus::rtu::RtuScanner;
use drivebus_proto::{Deframer, Event as FrameEvent};
use drivebus_store::{Event, EventKind};
use serde_json::json;
use tokio::io::AsyncWriteExt;
use tokio::net::{TcpListener, TcpStream};

// A bridge's settings and their checks (file and --bridge) are the configuration's (config/bridge.rs).
pub use crate::config::bridge::{check_arg as check, parse_arg};
pub use crate::config::{BridgeConfig, Framing};
use crate::core::{unix_ms, Gateway};
use drivebus_proto::modbus::tcp::{Mbap, MBAP_LEN};
use drivebus_proto::modbus::ExceptionCode;

/// Exception 0A: gateway path unavailable (the bus is down).
pub const PATH_UNAVAILABLE: ExceptionCode = ExceptionCode::GATEWAY_PATH_UNAVAILABLE;

/// True for the function codes that change something in the drive.
pub fn is_write(fc: u8) -> bool {
    matches!(fc, 0x05 | 0x06 | 0x0F | 0x10 | 0x15 | 0x16 | 0x17)
}

/// A request PDU for `unit` as the bus's frame: RTU (CRC) or ASCII (`:` hex LRC CR LF).
pub fn bus_frame(ascii: bool, unit: u8, pdu: &[u8]) -> Vec<u8> {
    let mut adu = Vec::with_capacity(pdu.len() + 3);
    adu.push(unit);
    adu.extend_from_slice(pdu);
    if !ascii {
        adu.extend_from_slice(&crc16_modbus(&adu).to_le_bytes());
        return adu;
    }
    adu.push(lrc(&adu));
    let mut out = Vec::with_capacity(2 * adu.len() + 3);
    out.push(b':');
    for b in adu {
        out.extend_from_slice(format!("{b:02X}").as_bytes());
    }
    out.extend_from_slice(b"\r\n");
    out
}

/// The PDU of a reply frame of the bus (checked by the bus owner): RTU or ASCII.
pub fn reply_pdu(ascii: bool, frame: &[u8]) -> Option<Vec<u8>> {
    if !ascii {
        return (frame.len() >= 4).then(|| frame[1..frame.len() - 2].to_vec());
    }
    let hex = frame.strip_prefix(b":")?.strip_suffix(b"\r\n")?;
    let bytes: Option<Vec<u8>> = hex
        .chunks(2)
        .map(|p| std::str::from_utf8(p).ok().and_then(|s| u8::from_str_radix(s, 16).ok()))
        .collect();
    let bytes = bytes?;
    (bytes.len() >= 3).then(|| bytes[1..bytes.len() - 1].to_vec())
}

/// Serves the bridge `cfg` on `listener` until the process ends.
pub async fn serve(gw: Arc<Gateway>, cfg: BridgeConfig, listener: TcpListener) -> std::io::Result<()> {
    let limits = gw.limits().listener(&format!("the Modbus bridge to {}", cfg.bus));
    loop {
        let (sock, peer, permit) = limits.accept(&listener).await;
        let (gw, cfg) = (gw.clone(), cfg.clone());
        tokio::spawn(async move {
            let _permit = permit;
            let _ = connection(gw, cfg, sock, peer).await;
        });
    }
}

/// One request taken off the connection: its unit, PDU and MBAP header (MBAP framing).
struct Request {
    unit: u8,
    pdu: Vec<u8>,
    header: Option<Mbap>,
}

async fn connection(
    gw: Arc<Gateway>,
    cfg: BridgeConfig,
    mut sock: TcpStream,
    peer: SocketAddr,
) -> std::io::Result<()> {
    let _ = sock.set_nodelay(true);
    let ip = match peer.ip() {
        IpAddr::V6(v6) => v6.to_ipv4_mapped().map_or(IpAddr::V6(v6), IpAddr::V4),
        v4 => v4,
    };
    let actor = format!("modbus-bridge:{peer}");
    let mut buf = vec![0u8; 2048];
    let mut len = 0;
    let mut rtu = Deframer::new(RtuScanner::requests());
    let mut deadlines = crate::limits::ReadDeadlines::new(gw.limits().config());
    loop {
        // The rest of an MBAP frame begun within the header timeout; the next request within
        // the idle timeout: otherwise the connection is closed.
        let Some(n) = deadlines.read(&mut sock, &mut buf[len..], len > 0).await? else {
            return Ok(());
        };
        if n == 0 {
            return Ok(());
        }
        let mut requests = Vec::new();
        match cfg.framing {
            Framing::Mbap => {
                len += n;
                let mut pos = 0;
                loop {
                    let (header, total) = match Mbap::next_frame(&buf[pos..len]) {
                        Ok(Some(frame)) => frame,
                        Ok(None) => break,
                        // Nothing after a damaged header can be trusted to be framed right.
                        Err(_) => return Ok(()),
                    };
                    requests.push(Request {
                        unit: header.unit,
                        pdu: buf[pos + MBAP_LEN..pos + total].to_vec(),
                        header: Some(header),
                    });
                    pos += total;
                }
                buf.copy_within(pos..len, 0);
                len -= pos;
            }
            Framing::Rtu => rtu.push(&buf[..n], &mut |e| {
                if let FrameEvent::Frame { bytes, .. } = e {
                    requests.push(Request {
                        unit: bytes[0],
                        pdu: bytes[1..bytes.len() - 2].to_vec(),
                        header: None,
                    });
                }
            }),
        }
        for r in requests {
            let answer = pass(&gw, &cfg, &r, ip, &actor).await;
            let Some(pdu) = answer else { continue };
            let out = match r.header {
                Some(h) => {
                    let mut out = vec![0u8; MBAP_LEN];
                    let _ = h.answer(pdu.len()).emit(&mut out);
                    out.extend_from_slice(&pdu);
                    out
                }
                None => bus_frame(false, r.unit, &pdu),
            };
            sock.write_all(&out).await?;
        }
    }
}

/// Why a write from `ip` is refused under the `[modbus]` rules as configured now (`None`: it
/// may write).
fn forbidden(gw: &Gateway, ip: IpAddr) -> Option<String> {
    let modbus = &gw.config().modbus;
    if modbus.read_only {
        Some("forbidden: Modbus writes are off ([modbus] read_only)".to_string())
    } else if !modbus.allow.contains(&ip) {
        Some(format!("forbidden: client {ip} may not write ([modbus] allow)"))
    } else {
        None
    }
}

/// Passes one request to the bus; returns the answer's PDU (`None`: none is due, a broadcast).
async fn pass(
    gw: &Arc<Gateway>,
    cfg: &BridgeConfig,
    r: &Request,
    ip: IpAddr,
    actor: &str,
) -> Option<Vec<u8>> {
    let fc = *r.pdu.first()?;
    let exception = |code: ExceptionCode| Some(vec![fc | 0x80, code.0]);
    let bus = gw.buses().iter().find(|b| b.config.name == cfg.bus)?.clone();
    let ascii = bus.config.protocol == drivebus_proto::protocol::WireProtocol::ModbusAscii;
    let write = is_write(fc);
    // The drive's name where the gateway knows it, else bus@address.
    let drive = gw
        .drives()
        .iter()
        .find(|d| d.bus == cfg.bus && d.config.address == r.unit)
        .map_or_else(|| format!("{}@{}", cfg.bus, r.unit), |d| d.config.name.clone());
    let action = format!("modbus bridge: function {fc:02X} [{}]", hex(&r.pdu));
    // A function off the bridge's list never reaches the bus; a write only under the rules.
    let refused = if !cfg.passes(&r.pdu) {
        Some(format!("forbidden: function {fc:02X} is not passed by this bridge ([[bridge]] functions)"))
    } else if write {
        forbidden(gw, ip)
    } else {
        None
    };
    if let Some(why) = refused {
        gw.audit_refusal(&drive, actor, &action, &why).await;
        return if r.unit == 0 { None } else { exception(ExceptionCode::ILLEGAL_FUNCTION) };
    }
    let exchange = Exchange { request: bus_frame(ascii, r.unit, &r.pdu), expect_reply: r.unit != 0 };
    let unit = r.unit;
    let transact = async move { bus.owner().transact(unit, exchange, Priority::Bridge, None).await };
    if !write {
        return answer_of(ascii, fc, transact.await).0;
    }
    // A write takes its turn in the drive's lane, with the gateway's own commands to it; its
    // audit record too, so the trail lists them in the order they were carried out.
    let (gw2, bus_name, drive2, actor2, action2) =
        (gw.clone(), cfg.bus.clone(), drive.clone(), actor.to_string(), action.clone());
    let done = gw.in_lane(&drive, async move {
        let (answer, outcome) = answer_of(ascii, fc, transact.await);
        audit(&gw2, &bus_name, &drive2, &actor2, &action2, outcome).await;
        answer
    });
    match done.await {
        Ok(answer) => answer,
        Err(e) => {
            // Too many writes wait for this drive: nothing was sent.
            audit(gw, &cfg.bus, &drive, actor, &action, format!("{}: {e}", e.kind())).await;
            exception(ExceptionCode::SERVER_DEVICE_BUSY)
        }
    }
}

/// The answer to a request (its PDU; `None` for a broadcast) and the audit trail's outcome, from
/// the bus's result.
fn answer_of(ascii: bool, fc: u8, result: Result<Option<Vec<u8>>, BusError>) -> (Option<Vec<u8>>, String) {
    let exception = |code: ExceptionCode| Some(vec![fc | 0x80, code.0]);
    match result {
        Ok(None) => (None, "ok (broadcast)".to_string()),
        Ok(Some(frame)) => match reply_pdu(ascii, &frame) {
            Some(p) if p.first().is_some_and(|f| f & 0x80 != 0) => {
                let code = p.get(1).copied().unwrap_or(0);
                (Some(p), format!("refused: exception {code:02X}"))
            }
            Some(p) => (Some(p), "ok".to_string()),
            None => (
                exception(ExceptionCode::GATEWAY_TARGET_FAILED),
                "failed: a reply the bridge cannot read".to_string(),
            ),
        },
        Err(BusError::BadRequest(e)) => (exception(ExceptionCode::ILLEGAL_FUNCTION), format!("refused: {e}")),
        Err(e @ (BusError::Link(_) | BusError::Closed)) => {
            (exception(PATH_UNAVAILABLE), format!("failed: {e}"))
        }
        Err(e) => (exception(ExceptionCode::GATEWAY_TARGET_FAILED), format!("timeout: {e}")),
    }
}

async fn audit(gw: &Arc<Gateway>, bus: &str, drive: &str, actor: &str, action: &str, result: String) {
    let mut event = Event::new(unix_ms(), EventKind::Command);
    event.bus = Some(bus.to_string());
    event.drive = Some(drive.to_string());
    event.actor = Some(actor.to_string());
    event.action = Some(action.to_string());
    event.result = Some(result);
    event.detail = json!({});
    let gw = gw.clone();
    let _ = tokio::task::spawn_blocking(move || gw.record(event)).await;
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02X}")).collect::<Vec<_>>().join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_for_the_bus_and_back() {
        // Seed 004's example: 01 03 2102 0002.
        let pdu = [0x03, 0x21, 0x02, 0x00, 0x02];
        let rtu = bus_frame(false, 1, &pdu);
        assert_eq!(rtu[..6], [1, 3, 0x21, 2, 0, 2]);
        assert_eq!(reply_pdu(false, &rtu).unwrap(), pdu);
        let ascii = bus_frame(true, 1, &pdu);
        assert_eq!(ascii, b":010321020002D7\r\n");
        assert_eq!(reply_pdu(true, &ascii).unwrap(), pdu);
        assert_eq!(reply_pdu(true, b":01\r\n"), None);
        assert!(is_write(0x06) && is_write(0x10) && !is_write(0x03));
    }
}
