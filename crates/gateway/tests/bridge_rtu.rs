//! The transparent Modbus bridge and the Modbus RTU slave, with programs nobody here wrote:
//! mbpoll writes and reads a simulated generic drive's registers through the bridge while the
//! gateway keeps polling the same bus; pymodbus over a pty pair reads the unified map from the
//! RTU slave. Plus raw-socket tests of the allow rules and the audit trail.
//!
//! The witness tests are ignored by a plain `cargo test` (`cargo test -- --ignored` runs them).
//! `.ci/install-witnesses.sh` installs the witnesses and CI sets `DRIVEBUS_REQUIRE_INTEROP=1`, so
//! there a missing witness is a failure.

use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;
use std::time::Duration;

use drivebus_gateway::core::Change;
use drivebus_gateway::{Gateway, GatewayConfig};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

#[path = "../../../tests/interop/witness.rs"]
mod witness;
use witness::witness;

/// A virtual bus `line-1` with a generic drive (`pump-1`, address 1) polled every 100 ms, and a
/// bridge to it; `modbus` is extra `[modbus]` settings.
fn config(modbus: &str) -> GatewayConfig {
    GatewayConfig::from_toml("bridge-test.toml", &config_text(modbus)).unwrap()
}

/// The text of [`config`].
fn config_text(modbus: &str) -> String {
    format!(
        r#"
name = "bridge-test"
[modbus]
listen = "127.0.0.1:0"
{modbus}
[store]
disabled = true
[[bus]]
name = "line-1"
port = "virtual"
protocol = "modbus-rtu"
baud = 19200
serial = "8N2"
[[bus.drive]]
name = "pump-1"
family = "generic"
address = 1
poll_ms = 100
[[bridge]]
bus = "line-1"
listen = "127.0.0.1:0"
"#
    )
}

/// The gateway and its bridge's address.
async fn start(modbus: &str) -> (Arc<Gateway>, std::net::SocketAddr) {
    start_config(config(modbus)).await
}

/// The gateway of `cfg` with its first bridge serving: the gateway and the bridge's address.
async fn start_config(cfg: GatewayConfig) -> (Arc<Gateway>, std::net::SocketAddr) {
    let bridge = cfg.bridges[0].clone();
    let gw = Gateway::start(cfg, None).unwrap();
    let l = TcpListener::bind(bridge.listen).await.unwrap();
    let addr = l.local_addr().unwrap();
    tokio::spawn(drivebus_gateway::bridge::serve(gw.clone(), bridge, l));
    (gw, addr)
}

/// One MBAP request, its answer's PDU.
async fn mbap(sock: &mut TcpStream, tid: u16, unit: u8, pdu: &[u8]) -> Vec<u8> {
    let mut req = tid.to_be_bytes().to_vec();
    req.extend_from_slice(&[0, 0]);
    req.extend_from_slice(&((pdu.len() + 1) as u16).to_be_bytes());
    req.push(unit);
    req.extend_from_slice(pdu);
    sock.write_all(&req).await.unwrap();
    let mut head = [0u8; 7];
    tokio::time::timeout(Duration::from_secs(10), sock.read_exact(&mut head)).await.unwrap().unwrap();
    assert_eq!(&head[..2], &tid.to_be_bytes());
    assert_eq!(head[6], unit);
    let mut body = vec![0u8; u16::from_be_bytes([head[4], head[5]]) as usize - 1];
    sock.read_exact(&mut body).await.unwrap();
    body
}

/// Waits for `done` on the gateway's view of pump-1, with a generous deadline.
async fn until(gw: &Gateway, what: &str, done: impl Fn(&drivebus_gateway::core::DriveView) -> bool) {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(20);
    loop {
        let v = gw.drive_view(&gw.drive("pump-1").unwrap());
        if done(&v) {
            return;
        }
        assert!(tokio::time::Instant::now() < deadline, "{what}: {v:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// Waits for an audit event whose result starts with `result`.
async fn audited(changes: &mut tokio::sync::broadcast::Receiver<Change>, actor: &str, result: &str) {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(20);
    loop {
        let left = deadline.saturating_duration_since(tokio::time::Instant::now());
        match tokio::time::timeout(left, changes.recv()).await {
            Ok(Ok(Change::Event(e)))
                if e.actor.as_deref().is_some_and(|a| a.starts_with(actor))
                    && e.result.as_deref().is_some_and(|r| r.starts_with(result)) =>
            {
                assert_eq!(e.drive.as_deref(), Some("pump-1"));
                assert!(e.action.as_deref().is_some_and(|a| a.contains("modbus bridge")), "{e:?}");
                return;
            }
            Ok(Ok(_)) | Ok(Err(tokio::sync::broadcast::error::RecvError::Lagged(_))) => {}
            other => panic!("no audit event {actor} {result}: {other:?}"),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_bridge_passes_reads_and_writes_through_and_audits_writes() {
    let (gw, addr) = start("").await;
    let mut changes = gw.subscribe();
    until(&gw, "pump-1 online", |v| v.online == Some(true)).await;
    let mut sock = TcpStream::connect(addr).await.unwrap();
    // 06 to 2001H = 4000 (40.00 Hz): the drive's echo, passed back as it came.
    let w = [0x06, 0x20, 0x01, 0x0F, 0xA0];
    assert_eq!(mbap(&mut sock, 7, 1, &w).await, w);
    audited(&mut changes, "modbus-bridge:", "ok").await;
    // 03 of 2102H (frequency command) reads it back.
    assert_eq!(mbap(&mut sock, 8, 1, &[0x03, 0x21, 0x02, 0, 1]).await, [0x03, 2, 0x0F, 0xA0]);
    // The drive's own refusal comes back as its exception; an absent drive is 0B.
    assert_eq!(mbap(&mut sock, 9, 1, &[0x03, 0x7F, 0x00, 0, 1]).await, [0x83, 0x02]);
    assert_eq!(mbap(&mut sock, 10, 9, &[0x03, 0x21, 0x02, 0, 1]).await, [0x83, 0x0B]);
    // The gateway's own view shows the bridged write.
    until(&gw, "the setpoint written through the bridge", |v| v.setpoint_hz == Some(40.0)).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_read_only_gateway_refuses_bridged_writes_and_audits_them() {
    let (gw, addr) = start("read_only = true").await;
    let mut changes = gw.subscribe();
    let mut sock = TcpStream::connect(addr).await.unwrap();
    assert_eq!(mbap(&mut sock, 1, 1, &[0x06, 0x20, 0x01, 0x0F, 0xA0]).await, [0x86, 0x01]);
    audited(&mut changes, "modbus-bridge:", "forbidden").await;
    // Reads still pass.
    let r = mbap(&mut sock, 2, 1, &[0x03, 0x21, 0x03, 0, 1]).await;
    assert_eq!(&r[..2], &[0x03, 2]);
}

/// Issue 24 item 9: function 08 sub-function 04 (force listen-only mode), a vendor code and
/// 2B with MEI type 0D are not on the bridge's default list: exception 01, a refusal in the
/// audit trail, and nothing on the bus. Device identification (2B/0E) is passed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn functions_off_the_bridges_list_get_exception_01_an_audit_and_no_bus_traffic() {
    // One poll at start, then none for an hour: the bus's count is the bridge's alone.
    let text = config_text("").replace("poll_ms = 100", "poll_ms = 3600000");
    let (gw, addr) = start_config(GatewayConfig::from_toml("b.toml", &text).unwrap()).await;
    let mut changes = gw.subscribe();
    until(&gw, "pump-1 online", |v| v.online == Some(true)).await;
    let sent = || gw.bus_view(&gw.buses()[0]).transactions;
    let mut sock = TcpStream::connect(addr).await.unwrap();
    let before = sent();
    assert_eq!(mbap(&mut sock, 1, 1, &[0x03, 0x21, 0x02, 0, 1]).await[..2], [0x03, 2]);
    assert!(sent() > before, "a bridged read is on the bus's count");
    let quiet = sent();
    assert_eq!(mbap(&mut sock, 2, 1, &[0x08, 0x00, 0x04, 0x00, 0x00]).await, [0x88, 0x01]);
    audited(&mut changes, "modbus-bridge:127.0.0.1:", "forbidden: function 08 is not passed").await;
    assert_eq!(mbap(&mut sock, 3, 1, &[0x2B, 0x0D, 0x00, 0x00]).await, [0xAB, 0x01]);
    // A vendor code from another client: a refusal of its own in the audit trail (repeats from
    // one client are counted and written once a minute, refusals.rs).
    let other = tokio::net::TcpSocket::new_v4().unwrap();
    other.bind("127.0.0.2:0".parse().unwrap()).unwrap();
    let mut other = other.connect(addr).await.unwrap();
    assert_eq!(mbap(&mut other, 4, 1, &[0x41, 0x01, 0x02]).await, [0xC1, 0x01]);
    audited(&mut changes, "modbus-bridge:127.0.0.2:", "forbidden: function 41 is not passed").await;
    assert_eq!(sent(), quiet, "a refused function reached the bus");
    // Read device identification is on the default list: it goes to the drive.
    let _ = mbap(&mut sock, 5, 1, &[0x2B, 0x0E, 0x01, 0x00]).await;
    assert!(sent() > quiet, "2B/0E was not passed");
}

/// Issue 24 item 13: the bridge reads `[modbus] read_only` at each write, so a reload that
/// turns it on refuses the next write on a connection opened before.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_reload_to_read_only_refuses_the_next_bridged_write_on_an_open_connection() {
    let (gw, addr) = start("").await;
    let mut changes = gw.subscribe();
    until(&gw, "pump-1 online", |v| v.online == Some(true)).await;
    let mut sock = TcpStream::connect(addr).await.unwrap();
    let w = [0x06, 0x20, 0x01, 0x0F, 0xA0];
    assert_eq!(mbap(&mut sock, 1, 1, &w).await, w);
    gw.reload(config("read_only = true"), "test").await.unwrap();
    assert_eq!(mbap(&mut sock, 2, 1, &w).await, [0x86, 0x01]);
    audited(&mut changes, "modbus-bridge:", "forbidden: Modbus writes are off").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs mbpoll (.ci/install-witnesses.sh)"]
async fn mbpoll_writes_and_reads_through_the_bridge_while_the_gateway_polls() {
    if !witness("mbpoll", Command::new("mbpoll").arg("-V").output().is_ok(), "apt-get install mbpoll") {
        return;
    }
    let (gw, addr) = start("").await;
    until(&gw, "pump-1 online", |v| v.online == Some(true)).await;
    let polls_before = gw.drive_view(&gw.drive("pump-1").unwrap()).polls;
    let mbpoll = |args: Vec<String>| async move {
        let out = tokio::task::spawn_blocking(move || Command::new("mbpoll").args(&args).output().unwrap())
            .await
            .unwrap();
        let text =
            format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
        assert!(out.status.success(), "mbpoll {text}");
        text
    };
    let common = |reg: &str| -> Vec<String> {
        [
            "-m",
            "tcp",
            "-p",
            &addr.port().to_string(),
            "-a",
            "1",
            "-t",
            "4",
            "-0",
            "-1",
            "-r",
            reg,
            "127.0.0.1",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect()
    };
    // 2001H = 8193 (0-based): 4000 = 40.00 Hz; then 2102H = 8450 reads it back.
    let mut w = common("8193");
    w.push("4000".into());
    mbpoll(w).await;
    let text = mbpoll(common("8450")).await;
    assert!(
        text.contains("[8450]: \t4000") || text.contains("[8450]:\t4000") || text.contains("[8450]: 4000"),
        "{text}"
    );
    // The gateway kept polling the bus meanwhile, and its own view shows the write.
    until(&gw, "more polls and the bridged setpoint", |v| {
        v.polls > polls_before && v.setpoint_hz == Some(40.0)
    })
    .await;
}

/// Two ptys joined back to back, as socat's `pty,link=A pty,link=B` does: what is written to one
/// is read from the other.
struct PtyPair {
    a: PathBuf,
    b: PathBuf,
    _slaves: [OwnedFd; 2],
}

fn pty_pair(dir: &Path) -> PtyPair {
    use nix::sys::termios;
    let mut slaves = Vec::new();
    let mut masters = Vec::new();
    let mut links = Vec::new();
    for name in ["a", "b"] {
        let p = nix::pty::openpty(None, None).unwrap();
        let mut t = termios::tcgetattr(p.slave.as_fd()).unwrap();
        termios::cfmakeraw(&mut t);
        termios::tcsetattr(p.slave.as_fd(), termios::SetArg::TCSANOW, &t).unwrap();
        let link = dir.join(name);
        std::os::unix::fs::symlink(nix::unistd::ttyname(p.slave.as_fd()).unwrap(), &link).unwrap();
        links.push(link);
        slaves.push(p.slave);
        masters.push(std::fs::File::from(p.master));
    }
    let (m0, m1) = (masters.remove(0), masters.remove(0));
    for (mut from, mut to) in [(m0.try_clone().unwrap(), m1.try_clone().unwrap()), (m1, m0)] {
        std::thread::spawn(move || {
            use std::io::{Read, Write};
            let mut buf = [0u8; 512];
            while let Ok(n) = from.read(&mut buf) {
                if n == 0 || to.write_all(&buf[..n]).is_err() {
                    break;
                }
            }
        });
    }
    let s1 = slaves.pop().unwrap();
    let s0 = slaves.pop().unwrap();
    PtyPair { a: links.remove(0), b: links.remove(0), _slaves: [s0, s1] }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs pymodbus (.ci/install-witnesses.sh)"]
async fn pymodbus_reads_the_unified_map_from_the_rtu_slave() {
    let has = Command::new("python3").args(["-c", "import pymodbus"]).status().is_ok_and(|s| s.success());
    if !witness("pymodbus", has, "python3 -m pip install pymodbus pyserial") {
        return;
    }
    let dir = std::env::temp_dir().join(format!("drivebus-rtu-slave-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let pair = pty_pair(&dir);
    let mut cfg = config("");
    // 8N1: a pty carries no parity bit (and refuses even parity set twice).
    let text = format!(
        "[[modbus_rtu]]\nport = {:?}\nbaud = 19200\nserial = \"8N1\"\n",
        pair.a.display().to_string()
    );
    let rtu = GatewayConfig::from_toml("x.toml", &format!("{text}\n")).unwrap().modbus_rtu;
    cfg.modbus_rtu = rtu;
    let slave_cfg = cfg.modbus_rtu[0].clone();
    let gw = Gateway::start(cfg, None).unwrap();
    tokio::spawn(drivebus_gateway::modbus_rtu::run(gw.clone(), slave_cfg));
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/interop/pymodbus_rtu_slave.py");
    let b = pair.b.clone();
    let out = tokio::task::spawn_blocking(move || {
        Command::new("python3").arg(script).arg(&b).args(["1", "1", "1"]).output().unwrap()
    })
    .await
    .unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "pymodbus against the RTU slave: {text}");
    assert!(text.contains("write refused"), "{text}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_bridge_and_rtu_sections_are_named_with_their_line() {
    let base = r#"
[[bus]]
name = "line-1"
port = "virtual"
protocol = "modbus-rtu"
[[bus]]
name = "tosh"
port = "virtual"
protocol = "toshiba-binary"
"#;
    for (extra, needle) in [
        ("[[bridge]]\nbus = \"line-9\"\nlisten = \"127.0.0.1:5021\"\n", "bridge.bus`: no bus \"line-9\""),
        (
            "[[bridge]]\nbus = \"tosh\"\nlisten = \"127.0.0.1:5021\"\n",
            "needs a modbus-rtu or modbus-ascii bus",
        ),
        (
            "[[bridge]]\nbus = \"line-1\"\nlisten = \"nowhere\"\n",
            "bridge.listen`: \"nowhere\" is not HOST:PORT",
        ),
        ("[[bridge]]\nbus = \"line-1\"\nlisten = \"127.0.0.1:5021\"\nframing = \"udp\"\n", "use mbap or rtu"),
        ("[[modbus_rtu]]\nport = \"/dev/ttyS1\"\nserial = \"9Z1\"\n", "modbus_rtu.serial`"),
        ("[[modbus_rtu]]\nport = \"tcp://1.2.3.4:1\"\n", "give a serial device"),
        ("[[modbus_rtu]]\nport = \"/dev/ttyS1\"\nbaud = 5\n", "outside 300..4000000"),
    ] {
        let text = format!("{base}{extra}");
        let e = GatewayConfig::from_toml("plant.toml", &text).unwrap_err().to_string();
        assert!(e.contains(needle) && e.starts_with("plant.toml:"), "{extra}: {e}");
        assert_eq!(e.lines().count(), 1, "{e}");
    }
    let ok =
        GatewayConfig::from_toml("plant.toml", &format!("{base}[[modbus_rtu]]\nport = \"/dev/ttyS1\"\n"))
            .unwrap();
    let m = &ok.modbus_rtu[0];
    assert_eq!(
        (m.baud, m.format.to_string(), m.write),
        (19200, "8E1".to_string(), false),
        "the serial-line defaults"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rtu_over_tcp_reaches_a_modbus_ascii_bus() {
    let text = r#"
[store]
disabled = true
[[bus]]
name = "line-a"
port = "virtual"
protocol = "modbus-ascii"
[[bus.drive]]
name = "pump-1"
family = "generic"
address = 2
poll_ms = 100
[[bridge]]
bus = "line-a"
listen = "127.0.0.1:0"
framing = "rtu"
"#;
    let (_gw, addr) = start_config(GatewayConfig::from_toml("ascii.toml", text).unwrap()).await;
    let mut sock = TcpStream::connect(addr).await.unwrap();
    // An RTU frame in (03 of 210BH from address 2), an RTU frame out: the bus spoke ASCII.
    let req = drivebus_gateway::bridge::bus_frame(false, 2, &[0x03, 0x21, 0x0B, 0, 1]);
    sock.write_all(&req).await.unwrap();
    let mut answer = [0u8; 7];
    tokio::time::timeout(Duration::from_secs(10), sock.read_exact(&mut answer)).await.unwrap().unwrap();
    assert_eq!(answer.to_vec(), drivebus_gateway::bridge::bus_frame(false, 2, &[0x03, 2, 0x01, 0x00]));
}
