//! A bus with `protocol = "modbus-tcp"`: the gateway polls and commands simulated drives behind
//! a Modbus TCP endpoint (the simulator's `--modbus-tcp`), one unit id per drive, and opens the
//! connection again when the endpoint goes away and comes back; with `max_in_flight = 4` it
//! keeps four requests outstanding on the connection and matches answers that come back in
//! another order. Real time: the endpoint is a TCP port.

mod support;

use std::net::SocketAddr;
use std::time::Duration;

use drivebus_gateway::core::Command;
use drivebus_gateway::{Gateway, GatewayConfig};
use drivebus_sim::config::BusSpec;
use drivebus_sim::runtime::{Endpoint, Simulator};
use support::wait_for;
use tokio::task::JoinHandle;

/// A generic drive at 1 and a Toshiba drive at 2, both on Modbus RTU behind a Modbus TCP
/// endpoint at `addr`; the endpoint's address once it listens.
async fn endpoint(addr: SocketAddr) -> (SocketAddr, JoinHandle<()>) {
    let drives = vec!["generic@1:modbus-rtu".parse().unwrap(), "toshiba@2:modbus-rtu".parse().unwrap()];
    let bus = BusSpec::new(drives, Some(19200), Some("8E1".parse().unwrap())).unwrap();
    let sim = Simulator::new(&bus).unwrap();
    let (tx, rx) = tokio::sync::oneshot::channel();
    let task = tokio::spawn(async move {
        let _ = sim
            .serve(Endpoint::ModbusTcp(addr), false, move |at| {
                let _ = tx.send(at);
            })
            .await;
    });
    let at = rx.await.expect("the endpoint listens");
    (at.trim_start_matches("modbus-tcp ").parse().unwrap(), task)
}

fn config(addr: SocketAddr) -> GatewayConfig {
    let text = format!(
        "[store]\ndisabled = true\n\
         [[bus]]\nname = \"eth\"\nport = \"tcp://{addr}\"\nprotocol = \"modbus-tcp\"\ntimeout_ms = 500\nretries = 0\n\
         [[bus.drive]]\nname = \"fan\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 50\n\
         [[bus.drive]]\nname = \"pump\"\nfamily = \"toshiba\"\naddress = 2\npoll_ms = 50\n"
    );
    GatewayConfig::from_toml("t.toml", &text).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_gateway_polls_and_commands_drives_over_modbus_tcp_and_reconnects() {
    let (addr, sim) = endpoint("127.0.0.1:0".parse().unwrap()).await;
    let gw = Gateway::start(config(addr), None).unwrap();
    let view = |id: &str| gw.drive_view(&gw.drive(id).unwrap());
    wait_for("both drives online", Duration::from_secs(20), || {
        view("fan").online == Some(true) && view("pump").online == Some(true)
    })
    .await;
    assert_eq!(view("fan").protocol, "modbus-tcp");
    assert_eq!(gw.bus_view(&gw.buses()[0]).protocol, "modbus-tcp");

    gw.command("fan", Command::Speed(20.0), "test").await.expect("speed");
    gw.command("fan", Command::Run, "test").await.expect("run");
    wait_for("fan at 20 Hz", Duration::from_secs(60), || {
        view("fan").output_hz.is_some_and(|hz| (hz - 20.0).abs() < 0.01)
    })
    .await;
    assert_eq!(view("pump").running, Some(false), "the other unit id is another drive");

    // The endpoint goes away: offline. It comes back at the same address: the connection is
    // opened again with the bus's backoff and the drives are polled again.
    sim.abort();
    let _ = sim.await;
    wait_for("fan offline", Duration::from_secs(20), || view("fan").online == Some(false)).await;
    let (_, sim) = endpoint(addr).await;
    wait_for("fan online again", Duration::from_secs(30), || view("fan").online == Some(true)).await;
    sim.abort();
}

#[test]
fn a_modbus_tcp_bus_is_checked() {
    let bad = |text: &str, want: &str| {
        let e = GatewayConfig::from_toml("t.toml", text).expect_err(text).to_string();
        assert!(e.contains(want), "{e}");
    };
    bad(
        "[[bus]]\nname = \"a\"\nport = \"/dev/ttyUSB0\"\nprotocol = \"modbus-tcp\"\n[[bus.drive]]\nname = \"x\"\nfamily = \"generic\"\naddress = 1\n",
        "t.toml:3: field `bus.port`: a modbus-tcp bus is reached over TCP: give tcp://HOST[:PORT]",
    );
    bad(
        "[[bus]]\nname = \"a\"\nport = \"tcp://10.0.0.5\"\nprotocol = \"modbus-tcp\"\n[[bus.drive]]\nname = \"x\"\nfamily = \"danfoss\"\naddress = 1\n",
        "field `bus.protocol`: drive \"x\": a danfoss drive does not speak Modbus, so not modbus-tcp",
    );
    bad(
        "[[bus]]\nname = \"a\"\nport = \"tcp://10.0.0.5\"\nprotocol = \"modbus\"\n",
        "unknown protocol: use modbus-rtu, modbus-ascii, toshiba-ascii, toshiba-binary, danfoss-fc or b800 or modbus-tcp",
    );
    bad(
        "[[bus]]\nname = \"a\"\nport = \"tcp://10.0.0.5\"\nprotocol = \"modbus-tcp\"\nmax_in_flight = 0\n",
        "t.toml:5: field `bus.max_in_flight`: 0 is outside 1..16",
    );
    bad(
        "[[bus]]\nname = \"a\"\nport = \"tcp://10.0.0.5\"\nprotocol = \"modbus-tcp\"\nmax_in_flight = 17\n",
        "t.toml:5: field `bus.max_in_flight`: 17 is outside 1..16",
    );
    bad(
        "[[bus]]\nname = \"a\"\nport = \"tcp://10.0.0.5\"\nprotocol = \"modbus-rtu\"\nmax_in_flight = 1\n",
        "field `bus.max_in_flight`: only a modbus-tcp bus",
    );
    let c = GatewayConfig::from_toml(
        "t.toml",
        "[[bus]]\nname = \"a\"\nport = \"tcp://10.0.0.5\"\nprotocol = \"modbus-tcp\"\n[[bus.drive]]\nname = \"x\"\nfamily = \"generic\"\naddress = 1\n",
    )
    .unwrap();
    assert_eq!(c.buses[0].port, drivebus_gateway::config::Port::ModbusTcp("10.0.0.5:502".into()));
    assert_eq!(c.buses[0].protocol_name(), "modbus-tcp");
    assert_eq!(c.buses[0].max_in_flight, 1, "one request at a time unless asked");
    let c = GatewayConfig::from_toml(
        "t.toml",
        "[[bus]]\nname = \"a\"\nport = \"tcp://10.0.0.5\"\nprotocol = \"modbus-tcp\"\nmax_in_flight = 4\n[[bus.drive]]\nname = \"x\"\nfamily = \"generic\"\naddress = 1\n",
    )
    .unwrap();
    assert_eq!(c.buses[0].max_in_flight, 4);
}

/// What the holding endpoint saw.
#[derive(Default)]
struct Held {
    /// The most requests outstanding at once, and their unit ids then.
    most: usize,
    units: Vec<u8>,
    /// Batches answered in reverse order.
    reversed: usize,
}

/// Reads one MBAP frame from `s` (`None` at its end).
async fn mbap_frame(s: &mut tokio::net::TcpStream) -> Option<Vec<u8>> {
    use tokio::io::AsyncReadExt;
    let mut head = [0u8; 6];
    s.read_exact(&mut head).await.ok()?;
    let len = usize::from(u16::from_be_bytes([head[4], head[5]]));
    let mut frame = head.to_vec();
    frame.resize(6 + len, 0);
    s.read_exact(&mut frame[6..]).await.ok()?;
    Some(frame)
}

/// A Modbus TCP endpoint in front of `upstream` (the simulator's) that holds requests until
/// `batch` are outstanding, has the simulator answer each, then sends the answers back last
/// first, as a gateway to several serial lines may; its address and what it saw.
async fn holding_endpoint(
    upstream: SocketAddr,
    batch: usize,
) -> (SocketAddr, std::sync::Arc<std::sync::Mutex<Held>>) {
    use tokio::io::AsyncWriteExt;
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let at = listener.local_addr().unwrap();
    let held = std::sync::Arc::new(std::sync::Mutex::new(Held::default()));
    let seen = held.clone();
    tokio::spawn(async move {
        let (mut client, _) = listener.accept().await.unwrap();
        let mut sim = tokio::net::TcpStream::connect(upstream).await.unwrap();
        loop {
            let mut requests = Vec::new();
            while requests.len() < batch {
                let Some(f) = mbap_frame(&mut client).await else { return };
                requests.push(f);
            }
            {
                let mut h = seen.lock().unwrap();
                if requests.len() > h.most {
                    h.most = requests.len();
                    h.units = requests.iter().map(|f| f[6]).collect();
                }
            }
            let mut answers = Vec::new();
            for r in &requests {
                sim.write_all(r).await.unwrap();
                answers.push(mbap_frame(&mut sim).await.expect("the simulator answers"));
            }
            for a in answers.iter().rev() {
                if client.write_all(a).await.is_err() {
                    return;
                }
            }
            seen.lock().unwrap().reversed += 1;
        }
    });
    (at, held)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn four_requests_are_outstanding_at_once_and_answers_in_another_order_are_matched() {
    let drives = (1..=4).map(|a| format!("generic@{a}:modbus-rtu").parse().unwrap()).collect();
    let spec = BusSpec::new(drives, Some(19200), Some("8E1".parse().unwrap())).unwrap();
    let sim = Simulator::new(&spec).unwrap();
    let (tx, rx) = tokio::sync::oneshot::channel();
    let sim_task = tokio::spawn(async move {
        let _ = sim
            .serve(Endpoint::ModbusTcp("127.0.0.1:0".parse().unwrap()), false, move |at| {
                let _ = tx.send(at);
            })
            .await;
    });
    let upstream: SocketAddr = rx.await.unwrap().trim_start_matches("modbus-tcp ").parse().unwrap();
    let (addr, held) = holding_endpoint(upstream, 4).await;
    // A generous timeout: the endpoint holds each request until three others have come.
    let mut text = format!(
        "[store]\ndisabled = true\n\
         [[bus]]\nname = \"eth\"\nport = \"tcp://{addr}\"\nprotocol = \"modbus-tcp\"\nmax_in_flight = 4\ntimeout_ms = 10000\nretries = 0\n"
    );
    for a in 1..=4 {
        text.push_str(&format!(
            "[[bus.drive]]\nname = \"d{a}\"\nfamily = \"generic\"\naddress = {a}\npoll_ms = 50\n"
        ));
    }
    let gw = Gateway::start(GatewayConfig::from_toml("t.toml", &text).unwrap(), None).unwrap();
    let view = |id: &str| gw.drive_view(&gw.drive(id).unwrap());
    wait_for("four drives online", Duration::from_secs(60), || {
        (1..=4).all(|a| view(&format!("d{a}")).online == Some(true))
    })
    .await;
    // Each drive's own answer, though they came back last first: a setpoint given to one
    // drive shows on that drive only.
    gw.command("d3", Command::Speed(33.0), "test").await.expect("speed");
    wait_for("d3's setpoint", Duration::from_secs(60), || view("d3").setpoint_hz == Some(33.0)).await;
    wait_for("a few reversed batches", Duration::from_secs(60), || held.lock().unwrap().reversed >= 5).await;
    for a in [1, 2, 4] {
        assert_ne!(view(&format!("d{a}")).setpoint_hz, Some(33.0), "d{a}");
    }
    let (most, mut units) = {
        let h = held.lock().unwrap();
        (h.most, h.units.clone())
    };
    units.sort_unstable();
    assert_eq!((most, units), (4, vec![1, 2, 3, 4]), "four requests outstanding, one per drive");
    let stats = gw.buses()[0].stats();
    assert_eq!((stats.timeouts, stats.stray_replies), (0, 0), "{stats:?}");
    sim_task.abort();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_simulators_modbus_tcp_endpoint_answers_pipelined_requests() {
    use tokio::io::AsyncWriteExt;
    let (addr, sim) = endpoint("127.0.0.1:0".parse().unwrap()).await;
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    // Three reads in one write, before any answer: the generic drive's 2103H twice, the
    // Toshiba drive's FD00, each with its own transaction id.
    let mut requests = Vec::new();
    for (t, unit, reg) in [(7u16, 1u8, 0x2103u16), (8, 2, 0xFD00), (9, 1, 0x2103)] {
        let [t0, t1] = t.to_be_bytes();
        let [r0, r1] = reg.to_be_bytes();
        requests.extend_from_slice(&[t0, t1, 0, 0, 0, 6, unit, 0x03, r0, r1, 0, 1]);
    }
    s.write_all(&requests).await.unwrap();
    let mut answered = Vec::new();
    for _ in 0..3 {
        let f = tokio::time::timeout(Duration::from_secs(30), mbap_frame(&mut s)).await.unwrap().unwrap();
        assert_eq!(f[7], 0x03, "a read's answer, not an exception: {f:02X?}");
        answered.push((u16::from_be_bytes([f[0], f[1]]), f[6]));
    }
    answered.sort_unstable();
    assert_eq!(answered, [(7, 1), (8, 2), (9, 1)]);
    sim.abort();
}
