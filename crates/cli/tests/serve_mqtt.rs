//! Two `drivebus serve` processes on one MQTT broker (an in-process rumqttd): each publishes
//! under its own `--name`, one subscriber sees both side by side, and neither knocks the
//! other off the broker (their client ids differ).

use std::collections::{HashMap, HashSet};
use std::net::SocketAddr;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use rumqttc::{Client, Event, MqttOptions, Packet, QoS};

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

fn broker() -> SocketAddr {
    use rumqttd::{Broker, Config, ConnectionSettings, RouterConfig, ServerSettings};
    let addr: SocketAddr = format!("127.0.0.1:{}", free_port()).parse().unwrap();
    let server = ServerSettings {
        name: "v4".into(),
        listen: addr,
        tls: None,
        next_connection_delay_ms: 1,
        connections: ConnectionSettings {
            connection_timeout_ms: 60_000,
            max_payload_size: 64 * 1024,
            max_inflight_count: 500,
            auth: None,
            external_auth: None,
            dynamic_filters: true,
        },
    };
    let config = Config {
        router: RouterConfig {
            max_connections: 100,
            max_outgoing_packet_count: 1000,
            max_segment_size: 16 * 1024 * 1024,
            max_segment_count: 10,
            ..Default::default()
        },
        v4: Some(HashMap::from([("1".to_string(), server)])),
        ..Default::default()
    };
    std::thread::spawn(move || {
        let mut broker = Broker::new(config);
        if let Err(e) = broker.start() {
            eprintln!("rumqttd: {e}");
        }
    });
    let start = Instant::now();
    while std::net::TcpStream::connect(addr).is_err() {
        assert!(start.elapsed() < Duration::from_secs(20), "the broker did not start");
        std::thread::sleep(Duration::from_millis(20));
    }
    addr
}

struct Serve(Child);

impl Drop for Serve {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn serve(name: &str, broker: SocketAddr) -> Serve {
    let child = Command::new(env!("CARGO_BIN_EXE_drivebus"))
        .args(["serve", "--demo", "--no-store", "--name", name])
        .args(["--http", &format!("127.0.0.1:{}", free_port())])
        .args(["--modbus", &format!("127.0.0.1:{}", free_port())])
        .args(["--mqtt", &format!("mqtt://{broker}")])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start drivebus serve");
    Serve(child)
}

#[test]
fn two_gateway_processes_side_by_side_on_one_broker() {
    let addr = broker();
    let _a = serve("hall-a", addr);
    let _b = serve("hall-b", addr);

    let mut opts = MqttOptions::new("subscriber", addr.ip().to_string(), addr.port());
    opts.set_keep_alive(Duration::from_secs(30));
    let (client, mut connection) = Client::new(opts, 100);
    client.subscribe("drivebus/#", QoS::AtLeastOnce).unwrap();

    // Every demo drive of both gateways, and each gateway online.
    let mut statuses: HashSet<String> = HashSet::new();
    let mut availability: HashMap<String, Vec<String>> = HashMap::new();
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut settled: Option<Instant> = None;
    for event in connection.iter() {
        assert!(Instant::now() < deadline, "seen so far: {statuses:?} {availability:?}");
        let Ok(Event::Incoming(Packet::Publish(p))) = event else { continue };
        let topic = p.topic.clone();
        let levels: Vec<&str> = topic.split('/').collect();
        match levels.as_slice() {
            ["drivebus", gw, "status"] => availability
                .entry(gw.to_string())
                .or_default()
                .push(String::from_utf8_lossy(&p.payload).into()),
            ["drivebus", gw, bus, drive, "status"] => {
                let v: serde_json::Value = serde_json::from_slice(&p.payload).expect("status is JSON");
                assert!(v.is_object(), "{topic}: {v}");
                statuses.insert(format!("{gw}/{bus}/{drive}"));
            }
            _ => {}
        }
        let both = ["hall-a", "hall-b"]
            .iter()
            .all(|g| statuses.iter().filter(|s| s.starts_with(&format!("{g}/"))).count() == 10);
        if both && settled.is_none() {
            settled = Some(Instant::now());
        }
        // Two more seconds after both are complete: any takeover would show as "offline".
        if settled.is_some_and(|t| t.elapsed() > Duration::from_secs(2)) {
            break;
        }
    }
    for g in ["hall-a", "hall-b"] {
        let seen = availability.get(g).cloned().unwrap_or_default();
        assert!(seen.iter().any(|s| s == "online"), "{g} online: {seen:?}");
        assert!(!seen.iter().any(|s| s == "offline"), "{g} was never knocked off: {seen:?}");
    }
}
