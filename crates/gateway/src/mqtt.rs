//! MQTT: the gateway's drives on a broker (rumqttc), and commands from it.
//!
//! ```text
//! <prefix>/status                          online | offline (retained; offline is the last will)
//! <prefix>/<bus>/<drive>/status            the drive's DriveView as JSON (retained)
//! <prefix>/<bus>/<drive>/events            each event of the drive as JSON
//! <prefix>/<bus>/<drive>/set/<command>     run | stop | reverse | jog | reset | speed (40 or {"hz":40})
//! <prefix>/<bus>/<drive>/result            {"command", "ok", "error"} for each command received
//! ```
//!
//! The prefix is `drivebus/<gateway name>` unless configured. A drive's status is published
//! when it changes, at most once a second, except that a change of running state, fault or
//! link health is published at once; the latest value held back is published when its second
//! is over. Commands go through [`Gateway::command`] (actor `mqtt:<client id>`) only where a
//! `allow_commands` pattern matches; every other command topic gets a result saying why and
//! reaches no drive. At each (re)connection the gateway says it is online, subscribes to its
//! command topics, and publishes every drive's latest status (and the Home Assistant discovery
//! messages when configured), so a broker that restarted empty has the whole state again.
//!
//! The gateway speaks MQTT 5: its CONNECT gives the broker a Maximum Packet Size
//! ([`MAX_INCOMING_PACKET`]), so a larger message is dropped by the broker instead of being
//! sent and ending the connection, and its command subscription asks for the retain flag as
//! published, so a retained command is recognised (and refused) on its first delivery too.
//! Every refused command message gets a result and an audit record ([`Gateway::audit_refusal`]).
//!
//! With `[standby]` the gateway publishes only while it masters at least one bus
//! ([`Gateway::mastering`]): a standby stays connected and subscribed, says `offline` on its
//! availability topic, and publishes no drive status, discovery or event; it answers command
//! messages (refused: `standby`). On becoming master it says `online` and publishes the
//! discovery messages and every drive's status at once; on losing its last bus it says
//! `offline` again. A killed master's will says `offline` as before.
//! docs/mqtt.md is the user's description.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::Duration;

use rumqttc::v5::mqttbytes::v5::{Filter, LastWill, Packet, Publish, RetainForwardRule};
use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::{AsyncClient, Event, MqttOptions};
use serde_json::{json, Value};
use tokio::sync::{broadcast, mpsc};
use tokio::time::Instant;

// The URL, prefix and command pattern rules are the configuration's (config/mqtt.rs).
pub use crate::config::mqtt::{check_prefix, parse_url, Pattern, COMMANDS};
use crate::config::MqttConfig;
use crate::core::{Change, Command, CommandError, DriveView, Gateway, ValueDef};

/// A drive's status is published at most this often unless its running state, fault or link
/// health changed.
pub const MIN_INTERVAL: Duration = Duration::from_secs(1);

/// Largest command payload accepted, bytes; a larger one is refused (`too_large`).
pub const MAX_COMMAND_PAYLOAD: usize = 256;

/// Largest MQTT packet the gateway takes from the broker, bytes (told to the broker at each
/// connection as the MQTT 5 Maximum Packet Size: the broker drops larger messages for us).
pub const MAX_INCOMING_PACKET: u32 = 1 << 20;

/// Most QoS 1 publishes awaiting the broker's acknowledgement at once (the broker's Receive
/// Maximum lowers it further); more wait in the client's queue.
pub const MAX_PUBLISHES_IN_FLIGHT: u16 = 1024;

/// Most MQTT commands in progress at once; more are refused (`busy`) rather than queued.
pub const MAX_COMMANDS_IN_FLIGHT: usize = 32;

/// The default topic prefix of gateway `name`: `drivebus/<name>` with every character other
/// than letters, digits, `-`, `_` and `.` replaced by `_`.
pub fn default_prefix(name: &str) -> String {
    format!("drivebus/{}", safe_level(name))
}

fn safe_level(s: &str) -> String {
    let s: String = s
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.') { c } else { '_' })
        .collect();
    if s.is_empty() {
        "_".into()
    } else {
        s
    }
}

/// Reads the payload of a `set/speed` message: a number of Hz (`40`, `40.5`) or `{"hz": 40}`.
pub fn parse_speed(payload: &[u8]) -> Result<f64, String> {
    let bad = || "speed wants a number of Hz: 40 or {\"hz\": 40}".to_string();
    let text = std::str::from_utf8(payload).map_err(|_| bad())?.trim();
    if let Err(e) = crate::json::check_unique_keys(text.as_bytes()) {
        return Err(format!("{e}: {}", bad()));
    }
    let hz = match serde_json::from_str::<Value>(text) {
        Ok(Value::Number(n)) => n.as_f64(),
        Ok(Value::Object(o)) if o.len() == 1 => o.get("hz").and_then(Value::as_f64),
        _ => None,
    };
    match hz {
        Some(hz) if hz.is_finite() => Ok(hz),
        _ => Err(bad()),
    }
}

/// Why a command message was not carried out before it reached the gateway.
#[derive(Debug, PartialEq)]
struct Refusal {
    kind: &'static str,
    message: String,
}

fn refuse(kind: &'static str, message: impl Into<String>) -> Refusal {
    Refusal { kind, message: message.into() }
}

/// The settings in force.
struct Settings {
    host: String,
    port: u16,
    /// Plain TCP or TLS (`mqtts://`).
    transport: rumqttc::Transport,
    prefix: String,
    client_id: String,
    allow: Vec<Pattern>,
    discovery: bool,
    gateway: String,
    credentials: Option<(String, String)>,
}

impl Settings {
    fn new(gw: &Gateway, cfg: &MqttConfig) -> Result<Settings, String> {
        let url = parse_url(&cfg.url).map_err(|e| format!("MQTT: {e}"))?;
        let commands = !cfg.allow_commands.is_empty();
        let transport =
            crate::config::tls::broker_transport("mqtt", &url, &cfg.tls, cfg.credentials.is_some(), commands)
                .map_err(|e| format!("MQTT: {e}"))?;
        let prefix = match &cfg.topic_prefix {
            Some(p) => {
                check_prefix(p).map_err(|e| format!("MQTT topic prefix {e}"))?;
                p.clone()
            }
            None => default_prefix(&gw.config().name),
        };
        let allow = cfg
            .allow_commands
            .iter()
            .map(|a| Pattern::parse(a).map_err(|e| format!("MQTT allow_commands {e}")))
            .collect::<Result<_, _>>()?;
        Ok(Settings {
            host: url.host,
            port: url.port,
            transport,
            prefix,
            client_id: cfg
                .client_id
                .clone()
                .unwrap_or_else(|| format!("drivebus-{}", safe_level(&gw.config().name))),
            allow,
            discovery: cfg.discovery,
            gateway: safe_level(&gw.config().name),
            credentials: cfg.credentials.clone(),
        })
    }

    fn availability(&self) -> String {
        format!("{}/status", self.prefix)
    }

    fn drive_topic(&self, bus: &str, drive: &str, leaf: &str) -> String {
        format!("{}/{bus}/{drive}/{leaf}", self.prefix)
    }

    /// `(bus, drive, command)` of a command topic, `None` for any other topic.
    fn command_topic<'t>(&self, topic: &'t str) -> Option<(&'t str, &'t str, &'t str)> {
        let rest = topic.strip_prefix(self.prefix.as_str())?.strip_prefix('/')?;
        let mut it = rest.split('/');
        match (it.next(), it.next(), it.next(), it.next(), it.next()) {
            (Some(bus), Some(drive), Some("set"), Some(cmd), None) => Some((bus, drive, cmd)),
            _ => None,
        }
    }
}

/// Starts publishing `gw` to the broker of `cfg` on the current tokio runtime; returns at once
/// (an error only for settings that cannot work). The task reconnects by itself forever.
pub fn spawn(gw: Arc<Gateway>, cfg: &MqttConfig) -> Result<tokio::task::JoinHandle<()>, String> {
    let settings = Settings::new(&gw, cfg)?;
    Ok(tokio::spawn(run(gw, settings)))
}

enum FromBroker {
    Connected,
    Lost,
    Message(Box<Publish>),
}

/// Per drive: when its status was last published, what it said, and what waits.
#[derive(Default)]
struct Throttle {
    last: Option<(Instant, Key)>,
    pending: Option<DriveView>,
}

/// What is published at once when it changes: link health, running state, fault code.
type Key = (Option<bool>, Option<bool>, Option<u32>);

fn key(v: &DriveView) -> Key {
    (v.online, v.running, v.fault.as_ref().map(|f| f.code))
}

struct Publisher {
    gw: Arc<Gateway>,
    s: Arc<Settings>,
    client: AsyncClient,
    connected: bool,
    /// The gateway masters a bus ([`Gateway::mastering`]): drive data is published.
    master: bool,
    in_flight: Arc<tokio::sync::Semaphore>,
}

impl Publisher {
    /// Hands a message to the client without waiting: while the broker is away nothing is
    /// queued (the state is republished at reconnection).
    fn send(&self, kind: &'static str, topic: String, retain: bool, payload: Vec<u8>) {
        if !self.connected {
            return;
        }
        send(&self.gw, &self.client, kind, topic, retain, payload);
    }

    fn status(&self, v: &DriveView) {
        let payload = serde_json::to_vec(v).unwrap_or_default();
        self.send("status", self.s.drive_topic(&v.bus, &v.id, "status"), true, payload);
    }

    fn on_connect(&self, throttle: &mut HashMap<String, Throttle>) {
        crate::metrics::front_ends(&self.gw).mqtt_connected();
        // The retain flag as published: a retained command is known as such when it is
        // delivered live too, not only when a subscription brings it.
        let filter = Filter {
            path: format!("{}/+/+/set/+", self.s.prefix),
            qos: QoS::AtLeastOnce,
            nolocal: true,
            preserve_retain: true,
            retain_forward_rule: RetainForwardRule::OnEverySubscribe,
        };
        if let Err(e) = self.client.try_subscribe_many([filter]) {
            crate::log::warn(&format!("MQTT: cannot subscribe to the command topics: {e}"));
        }
        self.announce(throttle);
    }

    /// Availability, and while master the discovery messages and every drive's status: at
    /// each connection and each change of [`Publisher::master`].
    fn announce(&self, throttle: &mut HashMap<String, Throttle>) {
        let availability: &[u8] = if self.master { b"online" } else { b"offline" };
        self.send("availability", self.s.availability(), true, availability.to_vec());
        throttle.clear();
        if !self.master {
            return;
        }
        if self.s.discovery {
            for d in self.gw.drives().iter() {
                for (topic, payload) in discovery(&self.s, &self.gw.drive_view(d), &d.named_values()) {
                    self.send("discovery", topic, true, payload.to_string().into_bytes());
                }
            }
        }
        let now = Instant::now();
        for d in self.gw.drives().iter() {
            let v = self.gw.drive_view(d);
            self.status(&v);
            throttle.insert(v.id.clone(), Throttle { last: Some((now, key(&v))), pending: None });
        }
    }

    fn on_drive(&self, v: DriveView, t: &mut Throttle) {
        if !self.master {
            return;
        }
        let now = Instant::now();
        let due = match &t.last {
            None => true,
            Some((at, k)) => *k != key(&v) || now.duration_since(*at) >= MIN_INTERVAL,
        };
        if due {
            self.status(&v);
            t.last = Some((now, key(&v)));
            t.pending = None;
        } else {
            t.pending = Some(v);
        }
    }

    fn flush(&self, throttle: &mut HashMap<String, Throttle>) {
        let now = Instant::now();
        for t in throttle.values_mut() {
            let ready = t.last.as_ref().map_or(true, |(at, _)| now.duration_since(*at) >= MIN_INTERVAL);
            if ready {
                if let Some(v) = t.pending.take() {
                    self.status(&v);
                    t.last = Some((now, key(&v)));
                }
            }
        }
    }

    fn on_event(&self, e: &drivebus_store::Event) {
        if !self.master {
            return;
        }
        let topic = match (&e.bus, &e.drive) {
            (Some(b), Some(d)) => self.s.drive_topic(b, d, "events"),
            (Some(b), None) => format!("{}/{b}/events", self.s.prefix),
            _ => format!("{}/events", self.s.prefix),
        };
        self.send("event", topic, false, serde_json::to_vec(e).unwrap_or_default());
    }

    /// Checks a command message; `Ok` with what to send to the gateway.
    fn check(&self, p: &Publish) -> Option<(String, String, String, Result<Command, Refusal>)> {
        let topic = std::str::from_utf8(&p.topic).ok()?;
        let (bus, drive, cmd) = self.s.command_topic(topic)?;
        if p.payload.is_empty() {
            // How a retained message is cleared, not a command.
            return None;
        }
        let result_topic = self.s.drive_topic(bus, drive, "result");
        let verdict = (|| {
            // The size first: nothing of an oversize payload is looked at.
            if p.payload.len() > MAX_COMMAND_PAYLOAD {
                return Err(refuse(
                    "too_large",
                    format!(
                        "a command payload has at most {MAX_COMMAND_PAYLOAD} bytes, this one has {}",
                        p.payload.len()
                    ),
                ));
            }
            if p.retain {
                return Err(refuse(
                    "retained",
                    "a retained command is refused (it would run again at every reconnection): \
                     publish without the retain flag and clear the retained message",
                ));
            }
            if !COMMANDS.contains(&cmd) {
                return Err(refuse("invalid", format!("no command {cmd:?}: use {}", COMMANDS.join(", "))));
            }
            if !self.s.allow.iter().any(|a| a.matches(bus, drive, cmd)) {
                return Err(refuse(
                    "forbidden",
                    format!("{bus}/{drive}/{cmd} is not allowed by [mqtt] allow_commands"),
                ));
            }
            let d = self.gw.drive(drive).map_err(|e| refuse(e.kind(), e.to_string()))?;
            if d.bus != bus {
                return Err(refuse(
                    "unknown_drive",
                    format!("drive {drive:?} is on bus {:?}, not {bus:?}", d.bus),
                ));
            }
            if cmd == "speed" {
                return parse_speed(&p.payload).map(Command::Speed).map_err(|m| refuse("invalid", m));
            }
            Command::from_name(cmd).ok_or_else(|| refuse("invalid", format!("no command {cmd:?}")))
        })();
        Some((result_topic, drive.to_string(), cmd.to_string(), verdict))
    }

    /// Who MQTT commands are by in the audit trail: `mqtt:<client id>`.
    fn actor(&self) -> String {
        format!("mqtt:{}", self.s.client_id)
    }

    fn on_message(&self, p: Publish) {
        let Some((topic, drive, cmd, verdict)) = self.check(&p) else { return };
        let permit = self.in_flight.clone().try_acquire_owned().map_err(|_| {
            refuse("busy", format!("{MAX_COMMANDS_IN_FLIGHT} MQTT commands are in progress: try again"))
        });
        let (command, permit) = match verdict.and_then(|c| permit.map(|p| (c, p))) {
            Ok(c) => c,
            Err(r) => {
                let body =
                    json!({ "command": cmd, "ok": false, "error": { "kind": r.kind, "message": r.message } });
                self.send("result", topic, false, body.to_string().into_bytes());
                let (gw, actor) = (self.gw.clone(), self.actor());
                let action = format!("mqtt set/{cmd}");
                let why = format!("{}: {}", r.kind, r.message);
                tokio::spawn(async move { gw.audit_refusal(&drive, &actor, &action, &why).await });
                return;
            }
        };
        let (gw, client) = (self.gw.clone(), self.client.clone());
        // Handed to the drive's lane now, in the order the messages came.
        let done = self.gw.command(&drive, command, &self.actor());
        tokio::spawn(async move {
            let _permit = permit;
            let result = done.await;
            let error = result
                .as_ref()
                .err()
                .map(|e: &CommandError| json!({ "kind": e.kind(), "message": e.to_string() }));
            let body = json!({ "command": cmd, "ok": result.is_ok(), "error": error });
            send(&gw, &client, "result", topic, false, body.to_string().into_bytes());
        });
    }
}

fn send(
    gw: &Gateway,
    client: &AsyncClient,
    kind: &'static str,
    topic: String,
    retain: bool,
    payload: Vec<u8>,
) {
    match client.try_publish(topic, QoS::AtLeastOnce, retain, payload) {
        Ok(()) => crate::metrics::front_ends(gw).mqtt_published(kind),
        Err(e) => crate::log::warn(&format!("MQTT: a {kind} message was dropped: {e}")),
    }
}

/// Home Assistant discovery messages of one drive: `(topic, config)`. `values` are the named
/// values its kind gives (a template's `[values]`): a sensor each, `<gateway>_<drive>_values_<name>`,
/// reading `values.<name>.value` of the status topic, in its unit.
fn discovery(s: &Settings, v: &DriveView, values: &[ValueDef]) -> Vec<(String, Value)> {
    let state_topic = s.drive_topic(&v.bus, &v.id, "status");
    let object = |value: &str| format!("{}_{}_{value}", s.gateway, v.id);
    let device = json!({
        "identifiers": [format!("drivebus_{}_{}", s.gateway, v.id)],
        "name": v.id,
        "manufacturer": "drivebus",
        "model": format!("{} ({})", v.family, v.protocol),
        // No "via_device": the gateway itself is not announced as a device, and Home Assistant
        // warns about a via_device it does not know. No "suggested_area" either: a gateway's
        // name is not a room, and Home Assistant would create an area of that name.
    });
    // (value, name, unit, device class, template)
    type Sensor<'a> = (String, &'a str, Option<&'a str>, Option<&'a str>, String);
    let mut sensors: Vec<Sensor> = vec![
        ("output_hz".into(), "output frequency", Some("Hz"), Some("frequency"), "{{ value_json.output_hz }}".into()),
        ("setpoint_hz".into(), "setpoint", Some("Hz"), Some("frequency"), "{{ value_json.setpoint_hz }}".into()),
        ("current_a".into(), "current", Some("A"), Some("current"), "{{ value_json.current_a }}".into()),
        (
            "state".into(),
            "state",
            None,
            None,
            "{{ 'offline' if value_json.online == false else ('fault' if value_json.fault else ('running' if value_json.running else 'stopped')) }}".into(),
        ),
        ("fault".into(), "fault", None, None, "{{ value_json.fault.text if value_json.fault else 'none' }}".into()),
    ];
    // `values` is also a method of a Jinja mapping: read it by key. Before the first answer the
    // status has no `values`, and the sensor is unknown.
    sensors.extend(values.iter().map(|x| {
        let template = format!(
            "{{{{ value_json['values']['{0}']['value'] if 'values' in value_json and '{0}' in value_json['values'] else none }}}}",
            x.name
        );
        let unit = (!x.unit.is_empty()).then_some(x.unit.as_str());
        (format!("values_{}", x.name), x.name.as_str(), unit, unit.and_then(device_class), template)
    }));
    sensors
        .iter()
        .map(|(value, name, unit, class, template)| {
            let mut c = json!({
                "name": name,
                "object_id": object(value),
                "unique_id": object(value),
                "state_topic": state_topic,
                "value_template": template,
                "availability_topic": s.availability(),
                "payload_available": "online",
                "payload_not_available": "offline",
                "device": device,
            });
            if let Some(u) = unit {
                c["unit_of_measurement"] = json!(u);
                c["state_class"] = json!("measurement");
            }
            if let Some(d) = class {
                c["device_class"] = json!(d);
            }
            (format!("homeassistant/sensor/{}/config", object(value)), c)
        })
        .collect()
}

/// Home Assistant's device class of a value in `unit`, where the unit is one that class takes.
fn device_class(unit: &str) -> Option<&'static str> {
    Some(match unit {
        "V" => "voltage",
        "A" => "current",
        "Hz" => "frequency",
        "W" | "kW" => "power",
        "°C" => "temperature",
        _ => return None,
    })
}

/// The client's options for a plant of `drives` drives.
fn options(s: &Settings, drives: usize) -> MqttOptions {
    let mut opts = MqttOptions::new(s.client_id.clone(), s.host.clone(), s.port);
    opts.set_keep_alive(Duration::from_secs(15));
    opts.set_transport(s.transport.clone());
    opts.set_clean_start(true);
    opts.set_last_will(LastWill::new(s.availability(), "offline", QoS::AtLeastOnce, true, None));
    opts.set_max_packet_size(Some(MAX_INCOMING_PACKET));
    // The client keeps a slot for every publish it may have in flight, made at once: without
    // a limit that is 65 536 slots, 14 MB, whatever the broker allows (issue 25).
    opts.set_outgoing_inflight_upper_limit(MAX_PUBLISHES_IN_FLIGHT);
    if let Some((user, password)) = &s.credentials {
        opts.set_credentials(user.clone(), password.clone());
    }
    opts.set_request_channel_capacity(64 + 16 * drives);
    opts
}

async fn run(gw: Arc<Gateway>, s: Settings) {
    let s = Arc::new(s);
    let opts = options(&s, gw.drives().len());
    let (client, mut eventloop) = AsyncClient::new(opts, 64 + 16 * gw.drives().len());

    // The event loop runs on its own so that publishing never waits for the network.
    let (tx, mut from_broker) = mpsc::channel(256);
    let endpoint = format!("{}:{}", s.host, s.port);
    let host = s.host.clone();
    tokio::spawn(async move {
        let mut backoff = Duration::from_millis(250);
        let mut reported = false;
        loop {
            let msg = match eventloop.poll().await {
                Ok(Event::Incoming(Packet::ConnAck(_))) => {
                    backoff = Duration::from_millis(250);
                    if reported {
                        crate::log::info(&format!("MQTT: connected again to {endpoint}"));
                    }
                    reported = false;
                    Some(FromBroker::Connected)
                }
                Ok(Event::Incoming(Packet::Publish(p))) => Some(FromBroker::Message(Box::new(p))),
                Ok(_) => None,
                Err(e) => {
                    if !reported {
                        let e = crate::config::tls::explain(&host, &e.to_string());
                        crate::log::warn(&format!("MQTT: broker {endpoint}: {e}; retrying"));
                        reported = true;
                    }
                    if tx.send(FromBroker::Lost).await.is_err() {
                        return;
                    }
                    tokio::time::sleep(backoff).await;
                    backoff = (backoff * 2).min(Duration::from_secs(5));
                    None
                }
            };
            if let Some(m) = msg {
                if tx.send(m).await.is_err() {
                    return;
                }
            }
        }
    });

    let mut p = Publisher {
        gw: gw.clone(),
        s,
        client,
        connected: false,
        master: *gw.mastering().borrow(),
        in_flight: Arc::new(tokio::sync::Semaphore::new(MAX_COMMANDS_IN_FLIGHT)),
    };
    let mut changes = gw.subscribe();
    let mut mastering = gw.mastering();
    let mut throttle: HashMap<String, Throttle> = HashMap::new();
    let mut tick = tokio::time::interval(Duration::from_millis(250));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            m = from_broker.recv() => match m {
                Some(FromBroker::Connected) => {
                    p.connected = true;
                    p.on_connect(&mut throttle);
                }
                Some(FromBroker::Lost) => p.connected = false,
                Some(FromBroker::Message(m)) => p.on_message(*m),
                None => return,
            },
            c = changes.recv() => match c {
                Ok(Change::Drive(v)) => {
                    let t = throttle.entry(v.id.clone()).or_default();
                    p.on_drive(v, t);
                }
                Ok(Change::Event(e)) => p.on_event(&e),
                Ok(Change::Bus(_)) => {}
                Err(broadcast::error::RecvError::Lagged(_)) => {}
                Err(broadcast::error::RecvError::Closed) => return,
            },
            _ = tick.tick() => p.flush(&mut throttle),
            Ok(()) = mastering.changed() => {
                p.master = *mastering.borrow_and_update();
                p.announce(&mut throttle);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The client's slots for publishes in flight are bounded: rumqttc makes one per packet id
    /// it may use, 65 536 of them (14 MB) unless told a limit (issue 25).
    #[test]
    fn publishes_in_flight_are_bounded() {
        let s = Settings {
            host: "127.0.0.1".into(),
            port: 1883,
            transport: rumqttc::Transport::Tcp,
            prefix: "drivebus/plant".into(),
            client_id: "drivebus-plant".into(),
            allow: Vec::new(),
            discovery: false,
            gateway: "plant".into(),
            credentials: None,
        };
        let opts = options(&s, 10_000);
        assert_eq!(opts.get_outgoing_inflight_upper_limit(), Some(MAX_PUBLISHES_IN_FLIGHT));
        assert!(usize::from(MAX_PUBLISHES_IN_FLIGHT) * std::mem::size_of::<Option<Publish>>() < 1 << 20);
    }

    #[test]
    fn speed_payloads() {
        assert_eq!(parse_speed(b"40").unwrap(), 40.0);
        assert_eq!(parse_speed(b" 40.5\n").unwrap(), 40.5);
        assert_eq!(parse_speed(br#"{"hz": 35}"#).unwrap(), 35.0);
        for bad in [
            &b"fast"[..],
            b"",
            b"{\"hz\":\"40\"}",
            b"{\"hz\":40,\"x\":1}",
            b"[40]",
            b"\xff",
            b"NaN",
            b"1e999",
            br#"{"hz":40,"hz":41}"#,
        ] {
            assert!(parse_speed(bad).is_err(), "{:?}", String::from_utf8_lossy(bad));
        }
    }

    #[test]
    fn prefixes() {
        assert_eq!(default_prefix("hall 1/a"), "drivebus/hall_1_a");
    }
}
