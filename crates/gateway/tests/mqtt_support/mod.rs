//! Shared by the MQTT tests: an in-process broker (rumqttd) on a free port, a TCP relay that
//! can cut its connections and switch brokers (a broker restart as the gateway sees it), and a
//! subscriber that keeps what it receives; Debian's Mosquitto started on a free port.
#![allow(dead_code)]

use std::collections::HashMap;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use drivebus_gateway::config::MqttConfig;
use drivebus_gateway::{Gateway, GatewayConfig};
use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};
use tokio::net::{TcpListener, TcpStream};
use tokio::task::JoinHandle;

/// Generous: only a broken gateway takes this long.
pub const PATIENCE: Duration = Duration::from_secs(60);

/// A port nobody listens on now.
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// Starts a rumqttd broker (MQTT 3.1.1) on a free loopback port; it lives until the test
/// process ends.
pub async fn rumqttd() -> SocketAddr {
    rumqttd_both().await.0
}

/// Starts a rumqttd broker listening for MQTT 3.1.1 and MQTT 5 clients (the gateway's MQTT
/// client speaks 5, the test's subscribers 3.1.1): `(v4, v5)` addresses.
pub async fn rumqttd_both() -> (SocketAddr, SocketAddr) {
    use rumqttd::{Broker, Config, ConnectionSettings, RouterConfig, ServerSettings};
    let v4: SocketAddr = format!("127.0.0.1:{}", free_port()).parse().unwrap();
    let v5: SocketAddr = format!("127.0.0.1:{}", free_port()).parse().unwrap();
    let server = |name: &str, listen| ServerSettings {
        name: name.into(),
        listen,
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
        v4: Some(HashMap::from([("1".to_string(), server("v4", v4))])),
        v5: Some(HashMap::from([("2".to_string(), server("v5", v5))])),
        ..Default::default()
    };
    std::thread::spawn(move || {
        let mut broker = Broker::new(config);
        if let Err(e) = broker.start() {
            eprintln!("rumqttd: {e}");
        }
    });
    wait_listening(v4).await;
    wait_listening(v5).await;
    (v4, v5)
}

/// Waits until something accepts connections on `addr`.
pub async fn wait_listening(addr: SocketAddr) {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    while TcpStream::connect(addr).await.is_err() {
        assert!(tokio::time::Instant::now() < deadline, "nothing listens on {addr}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// A TCP relay to a broker: [`Relay::switch`] drops every connection and sends new ones to
/// another broker, as a broker restart looks to its clients.
pub struct Relay {
    /// Where clients connect.
    pub addr: SocketAddr,
    upstream: Arc<Mutex<SocketAddr>>,
    conns: Arc<Mutex<Vec<JoinHandle<()>>>>,
}

impl Relay {
    /// A relay on a free port to `upstream`.
    pub async fn start(upstream: SocketAddr) -> Relay {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let up = Arc::new(Mutex::new(upstream));
        let conns: Arc<Mutex<Vec<JoinHandle<()>>>> = Arc::default();
        let (up2, conns2) = (up.clone(), conns.clone());
        tokio::spawn(async move {
            loop {
                let Ok((mut client, _)) = listener.accept().await else { return };
                let target = *up2.lock().unwrap();
                let task = tokio::spawn(async move {
                    if let Ok(mut server) = TcpStream::connect(target).await {
                        let _ = tokio::io::copy_bidirectional(&mut client, &mut server).await;
                    }
                });
                conns2.lock().unwrap().push(task);
            }
        });
        Relay { addr, upstream: up, conns }
    }

    /// Drops every relayed connection; new ones go to `upstream`.
    pub fn switch(&self, upstream: SocketAddr) {
        *self.upstream.lock().unwrap() = upstream;
        for c in self.conns.lock().unwrap().drain(..) {
            c.abort();
        }
    }
}

/// One message as a subscriber received it.
#[derive(Clone, Debug)]
pub struct Msg {
    /// Its topic.
    pub topic: String,
    /// Its payload as text.
    pub text: String,
    /// Its payload as it came.
    pub payload: Vec<u8>,
    /// Whether it came as a retained message.
    pub retain: bool,
}

/// A client subscribed to `filter`, keeping every message.
pub struct Subscriber {
    /// What came, in order.
    pub log: Arc<Mutex<Vec<Msg>>>,
    /// The client, to publish with.
    pub client: AsyncClient,
}

impl Subscriber {
    /// Connects to `broker` as `id` and subscribes to `filter`.
    pub async fn start(broker: SocketAddr, id: &str, filter: &str) -> Subscriber {
        Subscriber::start_with_max(broker, id, filter, 64 * 1024).await
    }

    /// [`Subscriber::start`] able to publish packets of up to `max_out` bytes.
    pub async fn start_with_max(broker: SocketAddr, id: &str, filter: &str, max_out: usize) -> Subscriber {
        let mut opts = MqttOptions::new(id, broker.ip().to_string(), broker.port());
        opts.set_keep_alive(Duration::from_secs(30));
        opts.set_max_packet_size(1 << 20, max_out);
        let (client, mut eventloop) = AsyncClient::new(opts, 100);
        client.subscribe(filter, QoS::AtLeastOnce).await.unwrap();
        let log: Arc<Mutex<Vec<Msg>>> = Arc::default();
        let log2 = log.clone();
        tokio::spawn(async move {
            loop {
                match eventloop.poll().await {
                    Ok(Event::Incoming(Packet::Publish(p))) => log2.lock().unwrap().push(Msg {
                        topic: p.topic.clone(),
                        text: String::from_utf8_lossy(&p.payload).into_owned(),
                        payload: p.payload.to_vec(),
                        retain: p.retain,
                    }),
                    Ok(_) => {}
                    Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
                }
            }
        });
        Subscriber { log, client }
    }

    /// The last message on each topic.
    pub fn latest(&self) -> HashMap<String, Msg> {
        self.log.lock().unwrap().iter().map(|m| (m.topic.clone(), m.clone())).collect()
    }

    /// Waits (at most [`PATIENCE`]) until `f` finds what it wants in the messages received.
    pub async fn wait<T>(&self, what: &str, mut f: impl FnMut(&[Msg]) -> Option<T>) -> T {
        let deadline = tokio::time::Instant::now() + PATIENCE;
        loop {
            if let Some(t) = f(&self.log.lock().unwrap()) {
                return t;
            }
            if tokio::time::Instant::now() > deadline {
                let log = self.log.lock().unwrap();
                let tail: Vec<_> = log.iter().rev().take(20).collect();
                panic!("waited {PATIENCE:?} for {what}; last messages: {tail:#?}");
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    /// Waits for the latest message on `topic` to satisfy `f`; returns its JSON.
    pub async fn wait_json(
        &self,
        topic: &str,
        mut f: impl FnMut(&serde_json::Value) -> bool,
    ) -> serde_json::Value {
        self.wait(topic, |log| {
            log.iter()
                .rev()
                .find(|m| m.topic == topic)
                .and_then(|m| serde_json::from_str::<serde_json::Value>(&m.text).ok())
                .filter(|v| f(v))
        })
        .await
    }

    /// Publishes `payload` on `topic`.
    pub async fn publish(&self, topic: &str, payload: &str, retain: bool) {
        self.client.publish(topic, QoS::AtLeastOnce, retain, payload.as_bytes().to_vec()).await.unwrap();
    }
}

/// The demo as gateway `name`, publishing to `broker` with `allow` as its command rules.
pub fn demo_gateway(name: &str, broker: SocketAddr, allow: &[&str], discovery: bool) -> Arc<Gateway> {
    demo_gateway_with(name, broker, allow, discovery, None)
}

/// [`demo_gateway`] logging in with `credentials`.
pub fn demo_gateway_with(
    name: &str,
    broker: SocketAddr,
    allow: &[&str],
    discovery: bool,
    credentials: Option<(&str, &str)>,
) -> Arc<Gateway> {
    demo_gateway_as(name, broker, allow, discovery, credentials, None)
}

/// [`demo_gateway_with`] whose buses, with `role`, share their lines with another gateway
/// (`[standby]`).
pub fn demo_gateway_as(
    name: &str,
    broker: SocketAddr,
    allow: &[&str],
    discovery: bool,
    credentials: Option<(&str, &str)>,
    role: Option<drivebus_link::role::RoleConfig>,
) -> Arc<Gateway> {
    let mut config = GatewayConfig::demo();
    config.name = name.to_string();
    config.store = None;
    for b in &mut config.buses {
        b.role = role;
    }
    let mqtt = MqttConfig {
        url: format!("mqtt://{broker}"),
        topic_prefix: None,
        discovery,
        allow_commands: allow.iter().map(|s| s.to_string()).collect(),
        client_id: None,
        credentials: credentials.map(|(u, p)| (u.to_string(), p.to_string())),
        tls: Default::default(),
    };
    let gw = Gateway::start(config, None).unwrap();
    drivebus_gateway::mqtt::spawn(gw.clone(), &mqtt).unwrap();
    gw
}

/// Every event `gw` records from now on.
pub fn collect_events(gw: &Arc<Gateway>) -> Arc<Mutex<Vec<drivebus_store::Event>>> {
    let mut changes = gw.subscribe();
    let events: Arc<Mutex<Vec<drivebus_store::Event>>> = Arc::default();
    let kept = events.clone();
    tokio::spawn(async move {
        loop {
            match changes.recv().await {
                Ok(drivebus_gateway::core::Change::Event(e)) => kept.lock().unwrap().push(e),
                Ok(_) | Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {}
                Err(_) => return,
            }
        }
    });
    events
}

/// The demo's drives as `(bus, drive)`.
pub fn demo_drives() -> Vec<(String, String)> {
    GatewayConfig::demo().drives().map(|(b, d)| (b.name.clone(), d.name.clone())).collect()
}

/// Waits until `sub` has heard a status, retained or not, of every demo drive under `prefix`;
/// `what` names the wait in the timeout's message.
pub async fn wait_every_status(sub: &Subscriber, prefix: &str, what: &str) {
    let drives = demo_drives();
    sub.wait(what, |log| {
        drives
            .iter()
            .all(|(b, d)| log.iter().any(|m| m.topic == format!("{prefix}/{b}/{d}/status")))
            .then_some(())
    })
    .await
}

/// Waits until `sub` holds a retained status of every demo drive under `prefix` (what a
/// broker keeps for whoever subscribes) and the latest status of each says online.
pub async fn wait_all_statuses(sub: &Subscriber, prefix: &str) {
    let drives = demo_drives();
    sub.wait(&format!("every drive's retained status under {prefix}"), |log| {
        let ok = drives.iter().all(|(bus, drive)| {
            let topic = format!("{prefix}/{bus}/{drive}/status");
            let json = |m: &Msg| serde_json::from_str::<serde_json::Value>(&m.text).ok();
            let retained = log.iter().any(|m| {
                m.topic == topic
                    && m.retain
                    && json(m).is_some_and(|v| v["id"] == drive.as_str() && v["bus"] == bus.as_str())
            });
            let latest = log.iter().rev().find(|m| m.topic == topic).and_then(json);
            retained && latest.is_some_and(|v| v["online"] == true)
        });
        ok.then_some(())
    })
    .await
}

/// Debian's `mosquitto`, where it is installed.
pub fn mosquitto_binary() -> Option<PathBuf> {
    let mut dirs: Vec<PathBuf> =
        std::env::var_os("PATH").map(|p| std::env::split_paths(&p).collect()).unwrap_or_default();
    dirs.extend(["/usr/sbin", "/usr/local/sbin", "/opt/homebrew/sbin"].map(PathBuf::from));
    dirs.into_iter().map(|d| d.join("mosquitto")).find(|p| p.is_file())
}

/// A Mosquitto process, killed on drop.
pub struct Mosquitto {
    child: Child,
    /// Where it listens.
    pub addr: SocketAddr,
}

impl Mosquitto {
    /// Starts Mosquitto on loopback `port`, anonymous clients allowed.
    pub async fn start(bin: &Path, port: u16) -> Mosquitto {
        Mosquitto::start_with(bin, port, "allow_anonymous true\n").await
    }

    /// Starts with `extra` lines of configuration (the listener and persistence are set here).
    pub async fn start_with(bin: &Path, port: u16, extra: &str) -> Mosquitto {
        let dir = std::env::temp_dir().join(format!("drivebus-mosquitto-{}-{port}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let conf = dir.join("mosquitto.conf");
        std::fs::write(
            &conf,
            format!("listener {port} 127.0.0.1\n{extra}persistence false\nlog_dest stderr\n"),
        )
        .unwrap();
        let child = Command::new(bin)
            .arg("-c")
            .arg(&conf)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {}: {e}", bin.display()));
        let addr: SocketAddr = format!("127.0.0.1:{port}").parse().unwrap();
        wait_listening(addr).await;
        Mosquitto { child, addr }
    }

    /// Kills it (a broker gone without a word).
    pub fn stop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Mosquitto {
    fn drop(&mut self) {
        self.stop();
    }
}
