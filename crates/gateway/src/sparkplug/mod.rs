//! Sparkplug B 3.0: the gateway as an edge node on an MQTT broker (rumqttc), each drive a
//! device, for hosts such as Ignition's MQTT Engine that tie many gateways into one namespace.
//!
//! ```text
//! spBv1.0/<group>/NBIRTH/<edge node>            bdSeq, Node Control/Rebirth, bus statistics
//! spBv1.0/<group>/NDEATH/<edge node>            bdSeq (the MQTT will)
//! spBv1.0/<group>/NDATA/<edge node>             bus statistics (every 10 s, or when a link changes)
//! spBv1.0/<group>/DBIRTH/<edge node>/<drive>    every metric, with names, aliases, types, units
//! spBv1.0/<group>/DDATA/<edge node>/<drive>     what changed, by alias, at the time the drive answered
//! spBv1.0/<group>/DDEATH/<edge node>/<drive>    the drive went offline
//! spBv1.0/<group>/NCMD/<edge node>              Node Control/Rebirth
//! spBv1.0/<group>/DCMD/<edge node>/<drive>      Setpoint, Command/*, Parameters/<name>
//! spBv1.0/STATE/<primary host>                  {"online": true|false, "timestamp": ...}
//! ```
//!
//! Each MQTT session takes the next `bdSeq` from the store ([`drivebus_store::Store::next_bd_seq`])
//! before it connects, and registers the NDEATH with it as its will. With a primary host, the
//! node births only once the host's STATE says online; when the host goes offline the node
//! publishes its NDEATH, disconnects and starts a new session (the next bdSeq) that births when
//! the host is back. While nobody listens, DDATA go to the store's queue and are sent when
//! publishing resumes, after the births, in order, flagged `is_historical`, before live data.
//! [`node`] (messages) and [`session`] (states) are the edge node without I/O; this module runs
//! them. docs/sparkplug.md is the user's description.

pub mod node;
pub mod payload;
pub mod session;

use std::sync::Arc;
use std::time::Duration;

use prost::Message;
use rumqttc::{AsyncClient, Event, LastWill, MqttOptions, Outgoing, Packet, Publish, QoS};
use tokio::sync::{broadcast, mpsc};

// The id rule is the configuration's (config/sparkplug.rs).
pub use crate::config::sparkplug::check_id;
use node::{DeviceMessage, Node, NodeCommand, Refusal};
use payload::Payload;
use session::{Session, Step};

use crate::config::SparkplugConfig;
use crate::core::{unix_ms, Change, Command, DriveEntry, Gateway};
use crate::metrics::{MessageLabels, RefusedLabels, SparkplugMetrics as Metrics};

/// Most messages sent from the store-and-forward queue per batch.
pub const DRAIN_BATCH: usize = 1000;

/// How long sending `n` kept messages takes at `rate` messages per second: the pause before
/// the next batch of a draining queue.
pub fn drain_pause(n: usize, rate: u64) -> Duration {
    Duration::from_secs_f64(n as f64 / rate.max(1) as f64)
}

/// How often kept data messages are written to the store, and the reload is looked for.
pub const FLUSH_INTERVAL: Duration = Duration::from_millis(250);

struct Settings {
    /// Host, port, and plain TCP or TLS (`mqtts://`).
    brokers: Vec<(String, u16, rumqttc::Transport)>,
    group: String,
    edge: String,
    primary: Option<String>,
    commands: bool,
    credentials: Option<(String, String)>,
    max: u64,
    max_age_ms: i64,
    rate: u64,
    client_id: String,
}

impl Settings {
    fn new(gw: &Gateway, cfg: &SparkplugConfig) -> Result<Settings, String> {
        let (secret, commands) = (cfg.credentials.is_some(), cfg.commands);
        let brokers = cfg
            .urls
            .iter()
            .map(|u| {
                let url = crate::config::mqtt::parse_url(u)?;
                let transport =
                    crate::config::tls::broker_transport("sparkplug", &url, &cfg.tls, secret, commands)?;
                Ok((url.host, url.port, transport))
            })
            .collect::<Result<Vec<_>, String>>()
            .map_err(|e| format!("Sparkplug: {e}"))?;
        if brokers.is_empty() {
            return Err("Sparkplug: give at least one broker URL".into());
        }
        let edge = cfg.edge_node_id.clone().unwrap_or_else(|| gw.config().name.clone());
        for id in [&cfg.group_id, &edge].into_iter().chain(cfg.primary_host.as_ref()) {
            check_id(id).map_err(|e| format!("Sparkplug id {e}"))?;
        }
        let safe = |s: &str| {
            s.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' { c } else { '_' }).collect::<String>()
        };
        let client_id = format!("drivebus-spb-{}-{}", safe(&cfg.group_id), safe(&edge));
        Ok(Settings {
            brokers,
            group: cfg.group_id.clone(),
            edge,
            primary: cfg.primary_host.clone(),
            commands: cfg.commands,
            credentials: cfg.credentials.clone(),
            max: cfg.store_forward_max,
            max_age_ms: (cfg.store_forward_max_age_s as i64).saturating_mul(1000),
            rate: cfg.store_forward_rate.max(1),
            client_id: client_id.chars().take(64).collect(),
        })
    }
}

/// Starts the edge node of `gw` on the current tokio runtime; returns at once (an error only for
/// settings that cannot work). It reconnects by itself, trying the brokers in turn.
pub fn spawn(gw: Arc<Gateway>, cfg: &SparkplugConfig) -> Result<tokio::task::JoinHandle<()>, String> {
    let s = Arc::new(Settings::new(&gw, cfg)?);
    Ok(tokio::spawn(run(gw, s)))
}

enum FromBroker {
    Connected { client: AsyncClient, bd_seq: u64 },
    Lost,
    Message(Publish),
}

/// The next bdSeq: from the store when there is one, else counted in memory from 0.
async fn next_bd_seq(gw: &Arc<Gateway>, key: &str, fallback: &mut u64) -> u64 {
    if let Some(store) = gw.store().cloned() {
        let key = key.to_string();
        match tokio::task::spawn_blocking(move || store.next_bd_seq(&key)).await {
            Ok(Ok(n)) => return n,
            Ok(Err(e)) => crate::log::warn(&format!("Sparkplug: bdSeq not kept in the store: {e}")),
            Err(e) => crate::log::warn(&format!("Sparkplug: bdSeq not kept in the store: {e}")),
        }
    }
    let n = *fallback;
    *fallback = (n + 1) % 256;
    n
}

/// One MQTT session after another, each a new client whose will is the NDEATH with its own
/// bdSeq; a broker that cannot be reached makes way for the next one in the list.
async fn sessions(gw: Arc<Gateway>, s: Arc<Settings>, tx: mpsc::Sender<FromBroker>) {
    let key = format!("{}/{}", s.group, s.edge);
    let death_topic = format!("{}/{}/NDEATH/{}", node::NAMESPACE, s.group, s.edge);
    let mut fallback = 0;
    let mut broker = 0;
    let mut backoff = Duration::from_millis(250);
    let mut reported = false;
    loop {
        let (host, port, transport) = s.brokers[broker % s.brokers.len()].clone();
        let bd_seq = next_bd_seq(&gw, &key, &mut fallback).await;
        let mut opts = MqttOptions::new(s.client_id.clone(), host.clone(), port);
        opts.set_keep_alive(Duration::from_secs(15));
        opts.set_transport(transport);
        opts.set_clean_session(true);
        let will = Node::ndeath(bd_seq, unix_ms()).encode_to_vec();
        opts.set_last_will(LastWill::new(death_topic.clone(), will, QoS::AtLeastOnce, false));
        opts.set_max_packet_size(1 << 20, 16 << 20);
        if let Some((user, password)) = &s.credentials {
            opts.set_credentials(user.clone(), password.clone());
        }
        let cap = 256 + 4 * gw.drives().len();
        let (client, mut eventloop) = AsyncClient::new(opts, cap);
        let mut connected = false;
        // The edge node left on purpose (its primary host went offline, or the gateway became
        // a standby): the next session goes
        // to the next broker in the list.
        let mut left = false;
        loop {
            let msg = match eventloop.poll().await {
                Ok(Event::Incoming(Packet::ConnAck(_))) => {
                    connected = true;
                    backoff = Duration::from_millis(250);
                    if reported {
                        crate::log::info(&format!("Sparkplug: connected again to {host}:{port}"));
                        reported = false;
                    }
                    FromBroker::Connected { client: client.clone(), bd_seq }
                }
                Ok(Event::Incoming(Packet::Publish(p))) => {
                    // Never wait here: the edge node may itself wait for this loop to take
                    // what it publishes. A flood of commands it cannot follow is dropped.
                    if let Err(mpsc::error::TrySendError::Full(FromBroker::Message(p))) =
                        tx.try_send(FromBroker::Message(p))
                    {
                        crate::log::warn(&format!(
                            "Sparkplug: too many messages at once: {} dropped",
                            p.topic
                        ));
                    }
                    continue;
                }
                Ok(Event::Outgoing(Outgoing::Disconnect)) => {
                    left = true;
                    break;
                }
                Ok(_) => continue,
                Err(e) => {
                    if !reported {
                        let e = crate::config::tls::explain(&host, &e.to_string());
                        crate::log::warn(&format!("Sparkplug: broker {host}:{port}: {e}; retrying"));
                        reported = true;
                    }
                    break;
                }
            };
            if tx.send(msg).await.is_err() {
                return;
            }
        }
        if connected && tx.send(FromBroker::Lost).await.is_err() {
            return;
        }
        if left || !connected {
            broker += 1;
        }
        tokio::time::sleep(backoff).await;
        backoff = (backoff * 2).min(Duration::from_secs(5));
    }
}

/// The edge node at work: one task owning the session state.
struct EdgeNode {
    gw: Arc<Gateway>,
    s: Arc<Settings>,
    node: Node,
    actor: String,
    client: Option<AsyncClient>,
    bd_seq: u64,
    /// Connected, waiting for the host, publishing, draining the queue, leaving.
    session: Session,
    pending: Vec<(String, i64, Vec<u8>)>,
    /// When the next batch of kept messages may go ([`Settings::rate`]).
    drain_next: tokio::time::Instant,
    drives: Arc<[Arc<DriveEntry>]>,
    buses: Vec<String>,
    written: mpsc::Sender<(String, String, f64)>,
}

/// The edge node's counts of `gw` (one per gateway, made empty on first use).
pub fn metrics(gw: &Gateway) -> Arc<Metrics> {
    crate::metrics::attached(gw).sparkplug.clone()
}

/// Each drive's id, writable parameters and named values. The lists are one per kind (catalog),
/// shared by every drive of that kind: a copy per drive took about 40 KB each (issue 25).
fn device_list(drives: &[Arc<DriveEntry>]) -> Vec<(String, node::DeviceDef)> {
    let mut lists: Vec<(Arc<drivebus_drive::Catalog>, node::DeviceDef)> = Vec::new();
    drives
        .iter()
        .map(|d| {
            let catalog = d.catalog();
            let def = match lists.iter().find(|(c, _)| Arc::ptr_eq(c, &catalog)) {
                Some((_, def)) => def.clone(),
                None => {
                    let def = node::DeviceDef {
                        params: catalog.iter().filter(|p| !p.read_only).cloned().collect(),
                        values: d.named_values().into(),
                    };
                    lists.push((catalog, def.clone()));
                    def
                }
            };
            (d.config.name.clone(), def)
        })
        .collect()
}

impl EdgeNode {
    fn key(&self) -> String {
        self.node.key()
    }

    async fn publish(&mut self, kind: &'static str, topic: String, p: &Payload) -> bool {
        let Some(client) = &self.client else { return false };
        match client.publish(topic, QoS::AtMostOnce, false, p.encode_to_vec()).await {
            Ok(()) => {
                metrics(&self.gw).messages.get_or_create(&MessageLabels { kind }).inc();
                true
            }
            Err(_) => {
                // The session ended under us: its end comes through the event loop.
                self.client = None;
                self.session.lost();
                false
            }
        }
    }

    async fn device(&mut self, id: &str, m: DeviceMessage) {
        let (kind, tag, mut p) = match m {
            DeviceMessage::Birth(p) => ("dbirth", "DBIRTH", p),
            DeviceMessage::Death(p) => ("ddeath", "DDEATH", p),
            DeviceMessage::Data(p) => {
                if self.session.keeps_data() {
                    self.keep(id, p);
                    return;
                }
                ("ddata", "DDATA", Node::live(p))
            }
        };
        if !self.session.publishing() {
            return;
        }
        self.node.stamp(&mut p);
        let topic = self.node.device_topic(tag, id);
        self.publish(kind, topic, &p).await;
    }

    fn keep(&mut self, id: &str, p: Payload) {
        if self.gw.store().is_none() {
            metrics(&self.gw).dropped.inc();
            return;
        }
        let time = p.timestamp.map_or_else(unix_ms, |t| t as i64);
        self.pending.push((id.to_string(), time, Node::to_keep(p).encode_to_vec()));
    }

    /// Writes kept messages to the store.
    async fn flush(&mut self) {
        let Some(store) = self.gw.store().cloned() else { return };
        if self.pending.is_empty() {
            return;
        }
        let items = std::mem::take(&mut self.pending);
        let n = items.len() as u64;
        let (key, max, oldest) = (self.key(), self.s.max, unix_ms() - self.s.max_age_ms);
        let r = tokio::task::spawn_blocking(move || store.spool_push(&key, &items, max, oldest)).await;
        let m = metrics(&self.gw);
        match r {
            Ok(Ok(pushed)) => {
                m.stored.inc_by(n);
                m.dropped.inc_by(pushed.over_count + pushed.too_old);
                m.queued.set(pushed.queued as i64);
            }
            Ok(Err(e)) => {
                m.dropped.inc_by(n);
                crate::log::warn(&format!("Sparkplug: {n} data messages not kept: {e}"));
            }
            Err(e) => {
                m.dropped.inc_by(n);
                crate::log::warn(&format!("Sparkplug: {n} data messages not kept: {e}"));
            }
        }
    }

    /// Sends one batch of kept messages, oldest first, flagged historical.
    async fn drain(&mut self) {
        self.flush().await;
        let Some(store) = self.gw.store().cloned() else {
            self.session.drained();
            return;
        };
        let key = self.key();
        let st = store.clone();
        // Batches of a tenth of a second's worth at the pace, so the pace is smooth.
        let n = DRAIN_BATCH.min((self.s.rate / 10).max(1) as usize);
        let batch = match tokio::task::spawn_blocking(move || st.spool_peek(&key, n)).await {
            Ok(Ok(b)) => b,
            Ok(Err(e)) => {
                crate::log::warn(&format!("Sparkplug: cannot read the kept data messages: {e}"));
                self.session.drained();
                return;
            }
            Err(_) => return,
        };
        let Some(last) = batch.last().map(|m| m.id) else {
            self.session.drained();
            metrics(&self.gw).queued.set(0);
            return;
        };
        let now = tokio::time::Instant::now();
        self.drain_next = self.drain_next.max(now) + drain_pause(batch.len(), self.s.rate);
        for m in batch {
            let Ok(p) = payload::decode(&m.payload) else { continue };
            let Some(mut p) = self.node.historical(&m.device, p) else { continue };
            self.node.stamp(&mut p);
            let topic = self.node.device_topic("DDATA", &m.device);
            if !self.publish("ddata_historical", topic, &p).await {
                // Not sent: they stay queued for the next session.
                return;
            }
        }
        let key = self.key();
        let left = tokio::task::spawn_blocking(move || store.spool_remove(&key, last)).await;
        if let Ok(Ok(n)) = left {
            metrics(&self.gw).queued.set(n as i64);
        }
    }

    /// Does what the session's state machine asks.
    async fn step(&mut self, step: Step) {
        match step {
            Step::Stay => {}
            Step::Birth => self.birth().await,
            Step::Leave => self.leave().await,
        }
    }

    /// NBIRTH and every DBIRTH: a new session, a host back online, a rebirth request.
    async fn birth(&mut self) {
        if self.client.is_none() {
            return;
        }
        self.sync_topology();
        let buses: Vec<_> = self.gw.buses().iter().map(|b| self.gw.bus_view(b)).collect();
        // seq 0, stamped by `nbirth`.
        let p = self.node.nbirth(self.bd_seq, &buses, unix_ms());
        let topic = self.node.node_topic("NBIRTH");
        // Publishing from the NBIRTH on; data keeps going to the queue until the births are out.
        self.session.born(true);
        if !self.publish("nbirth", topic, &p).await {
            return;
        }
        for d in self.drives.clone().iter() {
            let v = self.gw.drive_view(d);
            if let Some(m @ DeviceMessage::Birth(_)) = self.node.on_drive(&v, true, unix_ms()) {
                self.device(&v.id, m).await;
            }
        }
        let stored = match self.gw.store() {
            Some(store) => {
                let (store, key) = (store.clone(), self.key());
                tokio::task::spawn_blocking(move || store.spool_len(&key).unwrap_or(0)).await.unwrap_or(0)
            }
            None => 0,
        };
        self.session.born(stored > 0 || !self.pending.is_empty());
    }

    /// The primary host went offline, or the gateway masters no bus any more: the NDEATH of this
    /// session's bdSeq, then a disconnect; the session loop starts the next session (the next
    /// bdSeq), which births when the host is back and the gateway masters a bus.
    async fn leave(&mut self) {
        let Some(client) = self.client.take() else { return };
        let topic = self.node.node_topic("NDEATH");
        let p = Node::ndeath(self.bd_seq, unix_ms());
        // Queued before the DISCONNECT, so the broker has it first (MQTT 3.1.1 drops the will
        // on a DISCONNECT).
        if client.publish(topic, QoS::AtLeastOnce, false, p.encode_to_vec()).await.is_ok() {
            metrics(&self.gw).messages.get_or_create(&MessageLabels { kind: "ndeath" }).inc();
        }
        let _ = client.disconnect().await;
    }

    fn sync_topology(&mut self) -> (Vec<String>, bool) {
        let drives = self.gw.drives();
        let buses: Vec<String> = self.gw.buses().iter().map(|b| b.config.name.clone()).collect();
        let buses_changed = buses != self.buses;
        self.buses = buses;
        self.drives = drives.clone();
        (self.node.sync_devices(device_list(&drives)), buses_changed)
    }

    /// A reload changed the drives: DDEATH for those gone, DBIRTH for new ones; new buses
    /// change the node's metrics, which takes a rebirth.
    async fn reloaded(&mut self) {
        let (dead, buses_changed) = self.sync_topology();
        if !self.session.publishing() {
            return;
        }
        if buses_changed {
            let step = self.session.rebirth();
            self.step(step).await;
            return;
        }
        for id in dead {
            let p = Payload { timestamp: Some(unix_ms() as u64), ..Payload::default() };
            self.device(&id, DeviceMessage::Death(p)).await;
        }
        for d in self.drives.clone().iter() {
            let v = self.gw.drive_view(d);
            if !self.node.is_born(&v.id) {
                if let Some(m) = self.node.on_drive(&v, true, unix_ms()) {
                    self.device(&v.id, m).await;
                }
            }
        }
    }

    async fn connected(&mut self, client: AsyncClient, bd_seq: u64) {
        metrics(&self.gw).connections.inc();
        metrics(&self.gw).bd_seq.set(bd_seq as i64);
        self.bd_seq = bd_seq;
        let mut topics = vec![self.node.node_topic("NCMD"), format!("{}/+", self.node.node_topic("DCMD"))];
        if let Some(h) = &self.s.primary {
            // Births wait for the host's (retained) STATE saying online.
            topics.insert(0, format!("{}/STATE/{h}", node::NAMESPACE));
        }
        for t in topics {
            if let Err(e) = client.subscribe(t.clone(), QoS::AtLeastOnce).await {
                crate::log::warn(&format!("Sparkplug: cannot subscribe to {t}: {e}"));
            }
        }
        self.client = Some(client);
        let step = self.session.connected();
        self.step(step).await;
    }

    fn lost(&mut self) {
        self.client = None;
        self.session.lost();
    }

    async fn on_message(&mut self, p: Publish) {
        let topic = p.topic.clone();
        if let Some(h) = &self.s.primary {
            if topic == format!("{}/STATE/{h}", node::NAMESPACE) {
                self.on_state(&p.payload).await;
                return;
            }
        }
        if topic == self.node.node_topic("NCMD") {
            let cmds = payload::decode(&p.payload)
                .map_err(|e| Refusal { kind: "not_sparkplug", message: format!("NCMD: {e}") })
                .and_then(|pl| self.node.node_command(&pl));
            match cmds {
                Ok(cmds) if cmds.contains(&NodeCommand::Rebirth) => {
                    crate::log::info("Sparkplug: rebirth asked by NCMD");
                    let step = self.session.rebirth();
                    self.step(step).await;
                }
                Ok(_) => {}
                Err(r) => self.refused(None, r),
            }
            return;
        }
        let prefix = format!("{}/", self.node.node_topic("DCMD"));
        if let Some(device) = topic.strip_prefix(&prefix) {
            self.on_dcmd(device.to_string(), &p.payload);
        }
    }

    async fn on_state(&mut self, payload: &[u8]) {
        let (online, timestamp) = match session::parse_state(payload) {
            Ok(state) => state,
            Err(e) => return crate::log::warn(&format!("Sparkplug: {e}")),
        };
        let step = self.session.host_state(online, timestamp);
        match step {
            Step::Birth => crate::log::info("Sparkplug: the primary host is online: publishing"),
            Step::Leave => {
                crate::log::info("Sparkplug: the primary host is offline: NDEATH, new session, keeping data")
            }
            Step::Stay => {}
        }
        self.step(step).await;
    }

    fn refused(&self, device: Option<&str>, r: Refusal) {
        metrics(&self.gw).refused.get_or_create(&RefusedLabels { reason: r.kind }).inc();
        crate::log::warn(&format!("Sparkplug: command refused ({}): {}", r.kind, r.message));
        if let Some(id) = device.filter(|id| self.gw.drive(id).is_ok()) {
            let (gw, id, actor) = (self.gw.clone(), id.to_string(), self.actor.clone());
            let why = format!("{}: {}", r.kind, r.message);
            tokio::spawn(async move { gw.audit_refusal(&id, &actor, "sparkplug DCMD", &why).await });
        }
    }

    fn on_dcmd(&mut self, device: String, bytes: &[u8]) {
        if !self.s.commands {
            return self.refused(
                Some(&device),
                Refusal {
                    kind: "disabled",
                    message: format!(
                        "DCMD for {device:?}: commands are off: set [sparkplug] commands = true to accept them"
                    ),
                },
            );
        }
        let cmds = payload::decode(bytes)
            .map_err(|e| Refusal { kind: "not_sparkplug", message: format!("DCMD for {device:?}: {e}") })
            .and_then(|p| self.node.device_command(&device, &p));
        let cmds = match cmds {
            Ok(c) => c,
            Err(r) => return self.refused(Some(&device), r),
        };
        // Handed to the drive's lane here, in the order the DCMDs came, before any task runs:
        // the commands are carried out in that order whatever the tasks' order.
        let handed: Vec<_> = cmds
            .into_iter()
            .map(|c| {
                let param = match &c {
                    Command::SetParam { name, value, .. } => {
                        value.parse::<f64>().ok().map(|v| (name.clone(), v))
                    }
                    _ => None,
                };
                let action = c.action();
                (param, action, self.gw.command(&device, c, &self.actor))
            })
            .collect();
        let written = self.written.clone();
        tokio::spawn(async move {
            for (param, action, done) in handed {
                match done.await {
                    Ok(()) => {
                        if let Some((name, v)) = param {
                            let _ = written.send((device.clone(), name, v)).await;
                        }
                    }
                    Err(e) => crate::log::warn(&format!(
                        "Sparkplug: DCMD {action} for {device:?} failed: {}: {e}",
                        e.kind()
                    )),
                }
            }
        });
    }
}

async fn run(gw: Arc<Gateway>, s: Arc<Settings>) {
    let (tx, mut from_broker) = mpsc::channel(1024);
    tokio::spawn(sessions(gw.clone(), s.clone(), tx));
    let (written, mut written_rx) = mpsc::channel(64);
    let node = Node::new(&s.group, &s.edge);
    let mut e = EdgeNode {
        actor: format!("sparkplug:{}", node.key()),
        node,
        gw: gw.clone(),
        s: s.clone(),
        client: None,
        bd_seq: 0,
        session: Session::new(s.primary.is_some(), *gw.mastering().borrow()),
        pending: Vec::new(),
        drain_next: tokio::time::Instant::now(),
        drives: gw.drives(),
        buses: Vec::new(),
        written,
    };
    e.sync_topology();
    let mut changes = gw.subscribe();
    let mut mastering = gw.mastering();
    let mut tick = tokio::time::interval(FLUSH_INTERVAL);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            m = from_broker.recv() => match m {
                Some(FromBroker::Connected { client, bd_seq }) => e.connected(client, bd_seq).await,
                Some(FromBroker::Lost) => e.lost(),
                Some(FromBroker::Message(p)) => e.on_message(p).await,
                None => return,
            },
            c = changes.recv() => match c {
                Ok(Change::Drive(v)) => {
                    if let Some(m) = e.node.on_drive(&v, e.session.publishing(), unix_ms()) {
                        e.device(&v.id, m).await;
                    }
                }
                Ok(Change::Bus(b)) => {
                    if e.session.publishing() {
                        if let Some(mut p) = e.node.on_bus(&b, unix_ms()) {
                            e.node.stamp(&mut p);
                            let topic = e.node.node_topic("NDATA");
                            e.publish("ndata", topic, &p).await;
                        }
                    }
                }
                Ok(Change::Event(_)) => {}
                Err(broadcast::error::RecvError::Lagged(_)) => {
                    // Changes were missed: compare every drive with what was last sent.
                    for d in gw.drives().iter() {
                        let v = gw.drive_view(d);
                        if let Some(m) = e.node.on_drive(&v, e.session.publishing(), unix_ms()) {
                            e.device(&v.id, m).await;
                        }
                    }
                }
                Err(broadcast::error::RecvError::Closed) => return,
            },
            Some((device, name, v)) = written_rx.recv() => {
                if !e.session.keeps_data() {
                    if let Some(mut p) = e.node.param_written(&device, &name, v, unix_ms()) {
                        e.node.stamp(&mut p);
                        let topic = e.node.device_topic("DDATA", &device);
                        e.publish("ddata", topic, &p).await;
                    }
                }
            }
            _ = tick.tick() => {
                if !Arc::ptr_eq(&gw.drives(), &e.drives) {
                    e.reloaded().await;
                }
                e.flush().await;
            }
            Ok(()) = mastering.changed() => {
                let master = *mastering.borrow_and_update();
                let step = e.session.master(master);
                match step {
                    Step::Birth => crate::log::info("Sparkplug: the gateway masters a bus: NBIRTH"),
                    Step::Leave => crate::log::info(
                        "Sparkplug: the gateway masters no bus any more (standby): NDEATH, new session",
                    ),
                    Step::Stay => {}
                }
                e.step(step).await;
            }
            _ = tokio::time::sleep_until(e.drain_next), if e.session.phase() == session::Phase::Draining => e.drain().await,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_drain_keeps_its_pace() {
        assert_eq!(drain_pause(1000, 10_000), Duration::from_millis(100));
        assert_eq!(drain_pause(50, 500), Duration::from_millis(100));
        // A rate of 0 cannot come from the configuration; it is not a division by zero either.
        assert_eq!(drain_pause(1, 0), Duration::from_secs(1));
    }

    /// Drives of one family share one list of writable parameters: a copy per drive made the
    /// edge node hold about 40 KB a drive (issue 25).
    #[tokio::test]
    async fn drives_of_a_family_share_their_parameter_list() {
        let mut cfg = crate::GatewayConfig::demo();
        cfg.store = None;
        let gw = Gateway::start(cfg, None).unwrap();
        let drives = gw.drives();
        let list = device_list(&drives);
        assert_eq!(list.len(), drives.len());
        let mut families = 0;
        for (i, d) in drives.iter().enumerate() {
            let first = drives.iter().position(|e| e.config.family == d.config.family).unwrap();
            if first == i {
                families += 1;
                let writable = d.catalog().iter().filter(|p| !p.read_only).count();
                assert_eq!(list[i].1.params.len(), writable, "{}", d.config.name);
            } else {
                assert!(
                    Arc::ptr_eq(&list[i].1.params, &list[first].1.params),
                    "{} has a copy of its own",
                    d.config.name
                );
            }
        }
        assert!(families < drives.len(), "the demo has two drives of one family");
    }
}
