//! Connection limits on real sockets (127.0.0.2 and 127.0.0.3 are loopback addresses too):
//! many idle connections from one address while another is served on every listener (HTTP,
//! Modbus TCP, the bridge); a half-sent HTTP header, half a Modbus frame and an idle connection
//! closed by their timeouts (short configured timeouts, the close awaited with a generous
//! deadline).

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use drivebus_gateway::{Gateway, GatewayConfig};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpSocket, TcpStream};

const PATIENCE: Duration = Duration::from_secs(60);
const PER_ADDRESS: usize = 20;

struct Listeners {
    http: SocketAddr,
    modbus: SocketAddr,
    bridge: SocketAddr,
}

async fn start(limits: &str) -> (Arc<Gateway>, Listeners) {
    let text = format!(
        "[http]\nanonymous_read = true\n[limits]\n{limits}\n\
         [[bus]]\nname = \"line-1\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 38400\n\
         [[bus.drive]]\nname = \"d1\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 100\n\
         [[bridge]]\nbus = \"line-1\"\nlisten = \"127.0.0.1:0\"\n"
    );
    let cfg = GatewayConfig::from_toml("plant.toml", &text).unwrap();
    let bridge_cfg = cfg.bridges[0].clone();
    let gw = Gateway::start(cfg, None).unwrap();
    let bind = || async { TcpListener::bind("127.0.0.1:0").await.unwrap() };
    let (h, m, b) = (bind().await, bind().await, bind().await);
    let at = Listeners {
        http: h.local_addr().unwrap(),
        modbus: m.local_addr().unwrap(),
        bridge: b.local_addr().unwrap(),
    };
    tokio::spawn(drivebus_gateway::http::serve(gw.clone(), h, None));
    tokio::spawn(drivebus_gateway::modbus_tcp::serve(gw.clone(), m));
    tokio::spawn(drivebus_gateway::bridge::serve(gw.clone(), bridge_cfg, b));
    (gw, at)
}

/// A connection to `to` from address `from`.
async fn connect_from(from: [u8; 4], to: SocketAddr) -> TcpStream {
    let s = TcpSocket::new_v4().unwrap();
    s.bind(SocketAddr::from((from, 0))).unwrap();
    s.connect(to).await.unwrap()
}

/// Whether the server closed `s` within the patience (EOF or reset); true at once if it did.
async fn closed(s: &mut TcpStream) -> bool {
    closed_by(s, tokio::time::Instant::now() + PATIENCE).await
}

/// Whether the server closed `s` by `deadline`.
async fn closed_by(s: &mut TcpStream, deadline: tokio::time::Instant) -> bool {
    let mut b = [0u8; 256];
    loop {
        match tokio::time::timeout_at(deadline, s.read(&mut b)).await {
            Err(_) => return false,
            Ok(Ok(0)) | Ok(Err(_)) => return true,
            Ok(Ok(_)) => {}
        }
    }
}

/// A GET of `path` on a fresh connection from `from`; the status line.
async fn http_get(from: [u8; 4], to: SocketAddr, path: &str) -> String {
    let mut s = connect_from(from, to).await;
    s.write_all(format!("GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n").as_bytes())
        .await
        .unwrap();
    let mut answer = Vec::new();
    tokio::time::timeout(PATIENCE, s.read_to_end(&mut answer)).await.expect("an answer in time").unwrap();
    String::from_utf8_lossy(&answer).lines().next().unwrap_or_default().to_string()
}

/// FC 03 of holding register 0 of unit 1 (MBAP) from `from`; the answer's function code.
async fn modbus_read(s: &mut TcpStream) -> u8 {
    s.write_all(&[0, 1, 0, 0, 0, 6, 1, 0x03, 0, 0, 0, 1]).await.unwrap();
    let mut h = [0u8; 9];
    tokio::time::timeout(PATIENCE, s.read_exact(&mut h)).await.expect("an answer in time").unwrap();
    let mut rest = vec![0u8; u16::from_be_bytes([h[4], h[5]]) as usize - 3];
    s.read_exact(&mut rest).await.unwrap();
    h[7]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn many_idle_connections_from_one_address_leave_the_others_served() {
    // Timeouts far off: only the limit closes connections here.
    let (gw, at) =
        start(&format!("per_address = {PER_ADDRESS}\nheader_timeout_ms = 600000\nidle_timeout_s = 0")).await;
    for (name, to) in [("HTTP", at.http), ("Modbus TCP", at.modbus), ("bridge", at.bridge)] {
        // 127.0.0.2 opens five times its share and sends nothing.
        let mut idle = Vec::new();
        for _ in 0..5 * PER_ADDRESS {
            idle.push(connect_from([127, 0, 0, 2], to).await);
        }
        // Those over the share are closed at once; the share stays open.
        let mut over = 0;
        let deadline = tokio::time::Instant::now() + PATIENCE;
        for s in idle.iter_mut().skip(PER_ADDRESS) {
            over += usize::from(closed_by(s, deadline).await);
        }
        assert_eq!(over, 4 * PER_ADDRESS, "{name}: connections over the share closed");
        // 127.0.0.3 is served.
        match name {
            "HTTP" => {
                let status = http_get([127, 0, 0, 3], to, "/api/drives/d1").await;
                assert!(status.contains(" 200 "), "{name}: {status}");
            }
            _ => {
                let mut s = connect_from([127, 0, 0, 3], to).await;
                assert_eq!(modbus_read(&mut s).await, 0x03, "{name}: the read is answered");
            }
        }
        // 127.0.0.2 gets its place back once it closes one.
        idle.truncate(PER_ADDRESS - 1);
        let mut again = connect_from([127, 0, 0, 2], to).await;
        let deadline = tokio::time::Instant::now() + PATIENCE;
        loop {
            // The server may see the close after the new connection: try until it has room.
            if name == "HTTP" {
                again
                    .write_all(b"GET /api/drives/d1 HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")
                    .await
                    .ok();
                let mut answer = Vec::new();
                let _ = tokio::time::timeout(PATIENCE, again.read_to_end(&mut answer)).await;
                if String::from_utf8_lossy(&answer).starts_with("HTTP/1.1 200") {
                    break;
                }
            } else {
                again.write_all(&[0, 1, 0, 0, 0, 6, 1, 0x03, 0, 0, 0, 1]).await.ok();
                let mut h = [0u8; 9];
                if let Ok(Ok(_)) = tokio::time::timeout(PATIENCE, again.read_exact(&mut h)).await {
                    break;
                }
            }
            assert!(tokio::time::Instant::now() < deadline, "{name}: 127.0.0.2 never got its place back");
            tokio::time::sleep(Duration::from_millis(50)).await;
            again = connect_from([127, 0, 0, 2], to).await;
        }
    }
    drop(gw);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn half_sent_requests_and_idle_connections_are_closed() {
    let (_gw, at) = start("header_timeout_ms = 300\nidle_timeout_s = 2").await;
    // A header that never ends.
    let mut s = connect_from([127, 0, 0, 2], at.http).await;
    s.write_all(b"GET /api/drives HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ").await.unwrap();
    let started = tokio::time::Instant::now();
    assert!(closed(&mut s).await, "a half-sent header is closed");
    assert!(started.elapsed() < Duration::from_secs(30));
    // Half an MBAP frame, on Modbus TCP and on the bridge.
    for to in [at.modbus, at.bridge] {
        let mut s = connect_from([127, 0, 0, 2], to).await;
        s.write_all(&[0, 1, 0, 0, 0, 6, 1, 0x03]).await.unwrap();
        assert!(closed(&mut s).await, "half a frame is closed");
    }
    // A connection that is used, then falls silent, is closed after the idle timeout.
    let mut s = connect_from([127, 0, 0, 2], at.modbus).await;
    assert_eq!(modbus_read(&mut s).await, 0x03);
    assert!(closed(&mut s).await, "an idle connection is closed");
    let mut s = connect_from([127, 0, 0, 2], at.http).await;
    assert!(closed(&mut s).await, "an HTTP connection that never sent anything is closed");
}
