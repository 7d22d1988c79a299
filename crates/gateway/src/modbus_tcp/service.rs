//! The MBAP service: the Modbus TCP listener, a task per connection that splits the stream into
//! MBAP frames ([`Mbap::next_frame`], shared with the bridge and the drive client) and writes the
//! answers, each framed by [`begin`]/[`end`]. What a request means is the unified map's
//! ([`super::unified`]).
//!
//! A task per connection with a reused input buffer and a reused output buffer: every complete
//! request in what one read returned is answered in order, and the answers go out in one write.
//! Answers the map gives from the cache are gathered; a request that needs the drive has the
//! answers before it sent first.
//!
//! A frame whose protocol id is not 0 or whose length is below 2 or above 254 closes the
//! connection (nothing after it can be trusted to be framed right).

use std::net::{IpAddr, SocketAddr};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use drivebus_proto::modbus::tcp::{Mbap, MAX_ADU, MBAP_LEN};
use drivebus_proto::modbus::{ExceptionCode, ReplyPdu};
use tokio::io::{AsyncRead, AsyncWrite, AsyncWriteExt};
use tokio::net::TcpListener;

use super::unified::{Conn, Server};
use crate::core::Gateway;

/// The longest Modbus TCP frame: 7 bytes of MBAP header and a 253-byte PDU.
const MAX_FRAME: usize = MAX_ADU;
/// Input buffer per connection (several pipelined requests).
const IN_BUF: usize = 2048;

/// Decrements the connection count when a connection ends.
struct Slot<'a>(&'a AtomicUsize);

impl Drop for Slot<'_> {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::Relaxed);
    }
}

/// Serves Modbus TCP clients on `listener` with the gateway's `[modbus]` configuration and its
/// `[limits]` until the process ends.
pub async fn serve(gw: Arc<Gateway>, listener: TcpListener) -> std::io::Result<()> {
    let limits = gw.limits().listener("Modbus TCP");
    let server = Server::new(gw);
    loop {
        let (socket, peer, permit) = limits.accept(&listener).await;
        if server.active.fetch_add(1, Ordering::Relaxed) >= server.config.max_connections {
            server.active.fetch_sub(1, Ordering::Relaxed);
            drop(socket);
            continue;
        }
        let server = server.clone();
        let _ = socket.set_nodelay(true);
        tokio::spawn(async move {
            let _permit = permit;
            let _slot = Slot(&server.active);
            let _ = server.connection(socket, peer).await;
        });
    }
}

/// Serves one Modbus TCP client on `stream` (any byte stream; `peer` is its address) until it
/// closes: what the listener does for each connection it accepts, for tests and embedders
/// that bring their own streams.
pub async fn serve_stream<S>(gw: Arc<Gateway>, stream: S, peer: SocketAddr) -> std::io::Result<()>
where
    S: AsyncRead + AsyncWrite + Unpin,
{
    Server::new(gw).connection(stream, peer).await
}

/// Starts an answer to `mbap`; its length is filled in by [`end`].
pub(super) fn begin(out: &mut Vec<u8>, mbap: &Mbap) -> usize {
    let start = out.len();
    out.resize(start + MBAP_LEN, 0);
    let _ = mbap.answer(0).emit(&mut out[start..]);
    start
}

/// Ends the answer begun at `start`: the MBAP length counts what was written after it.
pub(super) fn end(out: &mut [u8], start: usize) {
    let len = (out.len() - start - 6) as u16;
    out[start + 4..start + 6].copy_from_slice(&len.to_be_bytes());
}

/// Answers `mbap`'s request with the PDU `pdu`.
pub(super) fn reply(out: &mut Vec<u8>, mbap: &Mbap, pdu: &ReplyPdu<'_>) {
    let start = begin(out, mbap);
    let at = out.len();
    out.resize(at + pdu.wire_len(), 0);
    match pdu.emit(&mut out[at..]) {
        Ok(n) => out.truncate(at + n),
        Err(_) => {
            // A reply the map built wrong is the server's failure, not the client's.
            out.truncate(at);
            out.extend_from_slice(&[pdu.answers_function() | 0x80, ExceptionCode::SERVER_DEVICE_FAILURE.0]);
        }
    }
    end(out, start);
}

/// Answers `mbap`'s request for `function` with exception `code`.
pub(super) fn exception(out: &mut Vec<u8>, mbap: &Mbap, function: u8, code: ExceptionCode) {
    reply(out, mbap, &ReplyPdu::Exception { function: function & 0x7F, code });
}

impl Server {
    /// Serves one client on `sock` until it closes or breaks the framing.
    async fn connection<S>(&self, mut sock: S, peer: SocketAddr) -> std::io::Result<()>
    where
        S: AsyncRead + AsyncWrite + Unpin,
    {
        let ip = match peer.ip() {
            IpAddr::V6(v6) => v6.to_ipv4_mapped().map_or(IpAddr::V6(v6), IpAddr::V4),
            v4 => v4,
        };
        // Writes are checked against the [modbus] rules as configured when they come (a
        // reload changes them for open connections too); `may_write` and `forbidden` are unused.
        let mut conn = Conn {
            ip: Some(ip),
            may_write: false,
            forbidden: String::new(),
            actor: format!("modbus:{peer}"),
        };
        let mut buf = vec![0u8; IN_BUF];
        let mut len = 0;
        let mut out: Vec<u8> = Vec::with_capacity(512);
        let mut deadlines = crate::limits::ReadDeadlines::new(self.gw.limits().config());
        loop {
            // The rest of a frame begun within the header timeout; the next one within the idle
            // timeout: otherwise the connection is closed.
            let n = match deadlines.read(&mut sock, &mut buf[len..], len > 0).await? {
                Some(n) => n,
                None => return Ok(()),
            };
            if n == 0 {
                return Ok(());
            }
            len += n;
            let mut pos = 0;
            let mut close = false;
            loop {
                let (mbap, total) = match Mbap::next_frame(&buf[pos..len]) {
                    Ok(Some(frame)) => frame,
                    Ok(None) => break,
                    Err(_) => {
                        close = true;
                        break;
                    }
                };
                let frame = &buf[pos..pos + total];
                let pdu = &frame[MBAP_LEN..];
                let mut mark = out.len();
                let mut started = std::time::Instant::now();
                let mut via_bus = false;
                if !self.answer_cached(&mbap, pdu, &mut out) {
                    via_bus = true;
                    // The drive's answer takes a bus transaction: send the answers before it first.
                    if !out.is_empty() {
                        sock.write_all(&out).await?;
                        out.clear();
                        // The request's time is the drive's, not the client's reading of those.
                        started = std::time::Instant::now();
                    }
                    mark = 0;
                    self.answer_drive(&mut conn, &mbap, pdu, &mut out).await;
                }
                // The answer's function code has bit 7 set for an exception.
                let exception = out.get(mark + 7).is_some_and(|f| f & 0x80 != 0);
                self.metrics.modbus_request(frame[7], exception);
                self.metrics.modbus_latency(via_bus, started.elapsed().as_secs_f64());
                pos += total;
            }
            if !out.is_empty() {
                sock.write_all(&out).await?;
                out.clear();
            }
            if close {
                return Ok(());
            }
            buf.copy_within(pos..len, 0);
            len -= pos;
            debug_assert!(IN_BUF - len >= MAX_FRAME);
        }
    }
}
