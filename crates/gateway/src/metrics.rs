//! `GET /metrics`: the gateway for Prometheus (OpenMetrics text, `prometheus-client`).
//!
//! Metrics observe the core: drive and bus series are read from the cache and the bus owners
//! at each scrape (nothing is polled for a scrape), the gateway's own work from the counters
//! and health it exposes ([`Counters`](crate::core::Counters),
//! [`Gateway::health`](crate::core::Gateway::health)). The front ends' own counts (HTTP
//! requests and latencies, Modbus TCP requests, MQTT publishes) accumulate in
//! [`FrontEndMetrics`] and the Sparkplug edge node's in [`SparkplugMetrics`], one of each per
//! gateway ([`front_ends`], `sparkplug::metrics`); the core holds them without knowing them.
//! docs/metrics.md lists the series. `GET /metrics` and the HTTP request count are served by
//! the HTTP front end (`http::metrics`).

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock, RwLock};

use opcua::server::SubscriptionCache;

use prometheus_client::encoding::text::{encode_eof, encode_registry};
use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{exponential_buckets, Histogram};
use prometheus_client::registry::{Registry, Unit};

use crate::core::DriveEntry;
use crate::core::Gateway;

/// The content type of the exposition.
pub const CONTENT_TYPE: &str = "application/openmetrics-text; version=1.0.0; charset=utf-8";

/// Labels of an HTTP request count.
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct HttpLabels {
    /// The route's pattern (`/api/drives/:id`), or `unmatched`.
    pub route: String,
    /// `GET`, `POST`, ...
    pub method: String,
    /// The response's status code.
    pub status: u16,
}

/// Labels of an HTTP latency.
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct RouteLabels {
    /// The route's pattern, or `unmatched`.
    pub route: String,
}

/// Labels of a Modbus TCP request count.
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct ModbusLabels {
    /// The function code (decimal).
    pub function: u8,
    /// `ok`, or `exception` when the answer was an exception.
    pub result: &'static str,
}

/// Labels of a Modbus TCP latency.
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct ModbusPathLabels {
    /// `cache` for answers from the state cache, `bus` for those that took a bus transaction
    /// (writes, parameter reads).
    pub path: &'static str,
}

/// Labels of an MQTT publish count.
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct MqttLabels {
    /// `status`, `event`, `result`, `availability` or `discovery`.
    pub kind: &'static str,
}

type LatencyFamily = Family<RouteLabels, Histogram, fn() -> Histogram>;
type ModbusLatencyFamily = Family<ModbusPathLabels, Histogram, fn() -> Histogram>;

fn modbus_latency_histogram() -> Histogram {
    // 10 us .. 2.6 s: cached answers take microseconds, bus transactions milliseconds.
    Histogram::new(exponential_buckets(0.00001, 4.0, 10))
}

fn latency_histogram() -> Histogram {
    // 0.5 ms .. 8 s.
    Histogram::new(exponential_buckets(0.0005, 4.0, 8))
}

/// The front ends' own counts (HTTP, Modbus TCP, MQTT, OPC UA) of one gateway, shared with every
/// scrape ([`front_ends`]).
#[derive(Debug)]
pub struct FrontEndMetrics {
    http_requests: Family<HttpLabels, Counter>,
    http_latency: LatencyFamily,
    modbus_requests: Family<ModbusLabels, Counter>,
    modbus_latency: ModbusLatencyFamily,
    /// The family's two series, taken once: observing one on the request path takes that
    /// histogram's own lock, with no label hashing and no lock on the family.
    modbus_latency_cache: Histogram,
    modbus_latency_bus: Histogram,
    mqtt_publishes: Family<MqttLabels, Counter>,
    mqtt_connections: Counter,
    opcua_changes_lagged: Counter,
}

impl Default for FrontEndMetrics {
    fn default() -> Self {
        let modbus_latency: ModbusLatencyFamily =
            Family::new_with_constructor(modbus_latency_histogram as fn() -> Histogram);
        let modbus_latency_cache = modbus_latency.get_or_create(&ModbusPathLabels { path: "cache" }).clone();
        let modbus_latency_bus = modbus_latency.get_or_create(&ModbusPathLabels { path: "bus" }).clone();
        FrontEndMetrics {
            http_requests: Family::default(),
            http_latency: Family::new_with_constructor(latency_histogram as fn() -> Histogram),
            modbus_requests: Family::default(),
            modbus_latency,
            modbus_latency_cache,
            modbus_latency_bus,
            mqtt_publishes: Family::default(),
            mqtt_connections: Counter::default(),
            opcua_changes_lagged: Counter::default(),
        }
    }
}

impl FrontEndMetrics {
    /// Counts an HTTP request that `route` answered with `status` after `seconds`.
    pub fn http_request(&self, route: &str, method: &str, status: u16, seconds: f64) {
        self.http_requests
            .get_or_create(&HttpLabels { route: route.to_string(), method: method.to_string(), status })
            .inc();
        self.http_latency.get_or_create(&RouteLabels { route: route.to_string() }).observe(seconds);
    }

    /// Counts a Modbus TCP request with function code `function`; `exception` when it was
    /// answered with an exception. For modbus_tcp.rs:
    /// `metrics::front_ends(&gw).modbus_request(fc, exception.is_some())`.
    pub fn modbus_request(&self, function: u8, exception: bool) {
        let result = if exception { "exception" } else { "ok" };
        self.modbus_requests.get_or_create(&ModbusLabels { function, result }).inc();
    }

    /// Records the time a Modbus TCP request took to answer: from the state cache (`bus` false)
    /// or through a bus transaction.
    pub fn modbus_latency(&self, bus: bool, seconds: f64) {
        if bus {
            self.modbus_latency_bus.observe(seconds)
        } else {
            self.modbus_latency_cache.observe(seconds)
        }
    }

    /// Counts an MQTT message handed to the client (`kind` as in [`MqttLabels`]).
    pub fn mqtt_published(&self, kind: &'static str) {
        self.mqtt_publishes.get_or_create(&MqttLabels { kind }).inc();
    }

    /// Counts a (re)connection to the MQTT broker.
    pub fn mqtt_connected(&self) {
        self.mqtt_connections.inc();
    }

    /// Connections made to the MQTT broker so far.
    pub fn mqtt_connections(&self) -> u64 {
        self.mqtt_connections.get()
    }

    /// Counts `n` gateway changes the OPC UA publisher fell too far behind to receive (the
    /// broadcast dropped them for it).
    pub fn opcua_lagged(&self, n: u64) {
        self.opcua_changes_lagged.inc_by(n);
    }

    /// Gateway changes the OPC UA publisher missed so far ([`FrontEndMetrics::opcua_lagged`]).
    pub fn opcua_changes_lagged(&self) -> u64 {
        self.opcua_changes_lagged.get()
    }

    /// MQTT messages of `kind` handed to the client so far.
    pub fn mqtt_publishes(&self, kind: &'static str) -> u64 {
        self.mqtt_publishes.get_or_create(&MqttLabels { kind }).get()
    }
}

/// Labels of a Sparkplug message count.
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct MessageLabels {
    /// `nbirth`, `dbirth`, `ddata`, `ddata_historical`, `ddeath`, `ndata`.
    pub kind: &'static str,
}

/// Labels of a refused command count.
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct RefusedLabels {
    /// What was wrong (the refusal's kind, `sparkplug::node::Refusal::kind`).
    pub reason: &'static str,
}

/// The Sparkplug B edge node's counts (`sparkplug::metrics`), for `/metrics`.
#[derive(Debug, Default)]
pub struct SparkplugMetrics {
    pub(crate) messages: Family<MessageLabels, Counter>,
    pub(crate) refused: Family<RefusedLabels, Counter>,
    pub(crate) connections: Counter,
    pub(crate) stored: Counter,
    pub(crate) dropped: Counter,
    pub(crate) queued: Gauge,
    pub(crate) bd_seq: Gauge,
}

impl SparkplugMetrics {
    /// Messages of `kind` published so far.
    pub fn messages(&self, kind: &'static str) -> u64 {
        self.messages.get_or_create(&MessageLabels { kind }).get()
    }

    /// Commands refused for `reason` so far.
    pub fn refused(&self, reason: &'static str) -> u64 {
        self.refused.get_or_create(&RefusedLabels { reason }).get()
    }

    /// Data messages dropped from the store-and-forward queue (limits, or no store).
    pub fn dropped(&self) -> u64 {
        self.dropped.get()
    }

    /// Data messages put in the store-and-forward queue.
    pub fn stored(&self) -> u64 {
        self.stored.get()
    }

    /// Data messages waiting in the store-and-forward queue, as last counted.
    pub fn queued(&self) -> i64 {
        self.queued.get()
    }

    /// Connections made to a broker.
    pub fn connections(&self) -> u64 {
        self.connections.get()
    }

    /// Registers the series under `sparkplug_`.
    pub fn register(&self, reg: &mut Registry) {
        let reg = reg.sub_registry_with_prefix("sparkplug");
        reg.register("messages", "Sparkplug messages published, by kind", self.messages.clone());
        reg.register(
            "commands_refused",
            "DCMD/NCMD refused before reaching a drive, by reason",
            self.refused.clone(),
        );
        reg.register("connections", "Connections made to a Sparkplug broker", self.connections.clone());
        reg.register("stored", "Data messages kept for store-and-forward", self.stored.clone());
        reg.register(
            "dropped",
            "Kept data messages dropped (queue limits, or no store)",
            self.dropped.clone(),
        );
        reg.register("queued", "Data messages waiting in the store-and-forward queue", self.queued.clone());
        reg.register("bd_seq", "The bdSeq of the current MQTT session", self.bd_seq.clone());
    }
}

/// Everything the front ends attach to a gateway, in one place: their counts, which `/metrics`
/// reads. A front end that keeps state of its own on the gateway adds a field here.
#[derive(Debug, Default)]
pub struct FrontEnds {
    /// HTTP requests, Modbus TCP requests, MQTT publishes ([`front_ends`]).
    pub counts: Arc<FrontEndMetrics>,
    /// The Sparkplug B edge node's messages, refusals and queue (`sparkplug::metrics`).
    pub sparkplug: Arc<SparkplugMetrics>,
    /// The OPC UA server's subscriptions, once it runs ([`FrontEnds::serve_opcua`]).
    opcua: OpcUaServed,
    /// The exposition's registry, built on the first scrape ([`render`]).
    exposition: Exposition,
}

impl FrontEnds {
    /// Shows the subscriptions of the OPC UA server now serving in `/metrics`
    /// (`drivebus_opcua_monitored_items`).
    pub fn serve_opcua(&self, subscriptions: Arc<SubscriptionCache>) {
        *self.opcua.0.write().unwrap_or_else(|e| e.into_inner()) = Some(subscriptions);
    }

    /// The monitored items the OPC UA server holds, of every session; None while it does not
    /// run.
    pub fn opcua_monitored_items(&self) -> Option<usize> {
        let served = self.opcua.0.read().unwrap_or_else(|e| e.into_inner());
        served.as_ref().map(|subs| subs.monitored_item_count())
    }
}

/// The subscriptions of the OPC UA server, counted at each scrape.
#[derive(Default)]
struct OpcUaServed(RwLock<Option<Arc<SubscriptionCache>>>);

impl std::fmt::Debug for OpcUaServed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("OpcUaServed")
    }
}

/// What the front ends attach to `gw`, made empty on first use.
pub fn attached(gw: &Gateway) -> Arc<FrontEnds> {
    gw.attached()
}

/// The front ends' counts of `gw`, made empty on first use.
pub fn front_ends(gw: &Gateway) -> Arc<FrontEndMetrics> {
    attached(gw).counts.clone()
}

/// The exposition of one gateway: its registry, built on the first scrape and kept (attached
/// to the gateway), and the length of the last text, to size the next one's buffer at once.
#[derive(Debug, Default)]
struct Exposition {
    registry: OnceLock<Registry>,
    last_len: AtomicUsize,
}

/// The exposition now, as `GET /metrics` serves it.
///
/// The series come out in this order: drives, buses, the gateway's counts, the front ends',
/// Sparkplug's, the OPC UA server's, health. The drive, bus, gateway and health series are written by hand straight
/// from the cache, the bus owners' counts and the kept health facts into one buffer sized from
/// the last scrape: each drive's state is read under one short lock, its labels are written
/// once per scrape and copied into each of its series, and no series allocates. The front
/// ends' families (labels made by the front ends as they count) are encoded by
/// `prometheus-client` from a registry built once per gateway. The OPC UA server's monitored
/// items are counted in its subscriptions (a sum over the watched nodes under its read lock).
/// Nothing is polled, no file is touched (the store's check runs on its own schedule,
/// `health::STORE_CHECK_EVERY`).
pub fn render(gw: &Arc<Gateway>) -> Result<String, String> {
    let front_ends = attached(gw);
    let exposition = &front_ends.exposition;
    let reg = exposition.registry.get_or_init(|| registry(gw));
    let mut out = String::with_capacity(exposition.last_len.load(Ordering::Relaxed) + 4096);
    core_series(gw, &mut out);
    encode_registry(&mut out, reg).map_err(|e| format!("cannot encode the metrics: {e}"))?;
    if let Some(items) = front_ends.opcua_monitored_items() {
        single(
            &mut out,
            ("opcua_monitored_items", "Monitored items the OPC UA server holds, all sessions."),
            Value::Flag(i64::try_from(items).unwrap_or(i64::MAX)),
        );
    }
    health_series(gw, &mut out);
    encode_eof(&mut out).map_err(|e| format!("cannot encode the metrics: {e}"))?;
    exposition.last_len.store(out.len(), Ordering::Relaxed);
    Ok(out)
}

/// The registry of the front ends' families (HTTP, Modbus TCP, MQTT, OPC UA, Sparkplug B), built once
/// per gateway and shared with the front ends that count.
fn registry(gw: &Arc<Gateway>) -> Registry {
    let mut reg = Registry::with_prefix(PREFIX);
    let f = front_ends(gw);
    reg.register(
        "http_requests",
        "HTTP requests answered, by route, method and status",
        f.http_requests.clone(),
    );
    reg.register_with_unit(
        "http_request_duration",
        "Time to the response's head, by route",
        Unit::Seconds,
        f.http_latency.clone(),
    );
    reg.register(
        "modbus_requests",
        "Modbus TCP requests, by function code and result",
        f.modbus_requests.clone(),
    );
    reg.register_with_unit(
        "modbus_request_duration",
        "Time to answer a Modbus TCP request, from the cache or through the bus",
        Unit::Seconds,
        f.modbus_latency.clone(),
    );
    reg.register("mqtt_publishes", "MQTT messages handed to the client, by kind", f.mqtt_publishes.clone());
    reg.register("mqtt_connections", "Connections made to the MQTT broker", f.mqtt_connections.clone());
    reg.register(
        "opcua_changes_lagged",
        "Gateway changes the OPC UA publisher fell too far behind to receive",
        f.opcua_changes_lagged.clone(),
    );
    attached(gw).sparkplug.register(&mut reg);
    reg
}

/// The prefix of every series name.
const PREFIX: &str = "drivebus";

/// One value of a series.
#[derive(Clone, Copy)]
enum Value {
    Gauge(f64),
    /// An integer gauge: a 0/1 flag, a code, a number of things held.
    Flag(i64),
    Count(u64),
}

impl Value {
    /// The OpenMetrics type.
    fn kind(self) -> &'static str {
        match self {
            Value::Gauge(_) | Value::Flag(_) => "gauge",
            Value::Count(_) => "counter",
        }
    }

    /// Writes the value as `prometheus-client` writes a gauge or a counter of its type.
    fn write(self, out: &mut String) {
        match self {
            Value::Gauge(x) => out.push_str(dtoa::Buffer::new().format(x)),
            Value::Flag(x) => out.push_str(itoa::Buffer::new().format(x)),
            Value::Count(x) => out.push_str(itoa::Buffer::new().format(x)),
        }
    }
}

/// A family's name (without the prefix and the unit), help text and unit.
type Desc<'d> = (&'d str, &'d str, Option<&'d str>);

/// Writes `drivebus_<name>[_<unit>]`.
fn write_name(out: &mut String, (name, _, unit): Desc) {
    out.push_str(PREFIX);
    out.push('_');
    out.push_str(name);
    if let Some(unit) = unit {
        out.push('_');
        out.push_str(unit);
    }
}

/// Writes family `d` with one series per row that has a value; nothing (not even its
/// description) when none has one, as a registered family without series. A row is its label
/// text (`k="v",...`, [`push_labels`]; empty for none) and its value.
fn family<'a>(out: &mut String, d: Desc, rows: impl IntoIterator<Item = (&'a str, Option<Value>)>) {
    let mut described = false;
    for (labels, v) in rows {
        let Some(v) = v else { continue };
        if !described {
            described = true;
            for (what, text) in [("# HELP ", d.1), ("# TYPE ", v.kind())] {
                out.push_str(what);
                write_name(out, d);
                out.push(' ');
                out.push_str(text);
                out.push('\n');
            }
            if let Some(unit) = d.2 {
                out.push_str("# UNIT ");
                write_name(out, d);
                out.push(' ');
                out.push_str(unit);
                out.push('\n');
            }
        }
        write_name(out, d);
        if let Value::Count(_) = v {
            out.push_str("_total");
        }
        if !labels.is_empty() {
            out.push('{');
            out.push_str(labels);
            out.push('}');
        }
        out.push(' ');
        v.write(out);
        out.push('\n');
    }
}

/// Writes family `d` of one series without labels.
fn single(out: &mut String, (name, help): (&str, &str), v: Value) {
    family(out, (name, help, None), [("", Some(v))]);
}

/// Appends the label text `k="v",...` of `pairs`, the values escaped as OpenMetrics wants
/// (`\\`, `\"`, `\n`), and returns where it is in `text`.
fn push_labels(text: &mut String, pairs: &[(&str, &str)]) -> std::ops::Range<usize> {
    let start = text.len();
    for (i, (k, v)) in pairs.iter().enumerate() {
        if i > 0 {
            text.push(',');
        }
        text.push_str(k);
        text.push_str("=\"");
        for c in v.chars() {
            match c {
                '\\' => text.push_str("\\\\"),
                '"' => text.push_str("\\\""),
                '\n' => text.push_str("\\n"),
                c => text.push(c),
            }
        }
        text.push('"');
    }
    start..text.len()
}

/// `rows` as [`family`] takes them: each one's label text (at `labels` in `text`) and value.
fn rows<'a, R>(
    rows: &'a [R],
    text: &'a str,
    labels: fn(&R) -> std::ops::Range<usize>,
    value: impl Fn(&R) -> Option<Value> + 'a,
) -> impl Iterator<Item = (&'a str, Option<Value>)> + 'a {
    rows.iter().map(move |r| (&text[labels(r)], value(r)))
}

/// What a scrape reads of one drive, under one lock of its state.
struct DriveRow {
    labels: std::ops::Range<usize>,
    output_hz: Option<f64>,
    setpoint_hz: Option<f64>,
    current_a: Option<f64>,
    running: Option<bool>,
    fault_code: Option<u32>,
    online: Option<bool>,
    age: Option<f64>,
    polls: u64,
    poll_errors: u64,
}

impl DriveRow {
    fn of(d: &DriveEntry, labels: &mut String) -> DriveRow {
        let labels = push_labels(
            labels,
            &[("bus", &d.bus), ("drive", &d.config.name), ("family", d.config.family.as_str())],
        );
        d.with_state(|s| {
            let st = s.status.as_ref();
            let running = st.map(|x| x.running);
            DriveRow {
                labels,
                output_hz: st.and_then(|x| x.output_hz),
                setpoint_hz: s.setpoint_hz(),
                current_a: st.and_then(|x| x.current_a),
                running,
                // Known once the drive was polled: 0 without a fault.
                fault_code: (s.online.is_some() || running.is_some())
                    .then(|| st.and_then(|x| x.fault.as_ref()).map_or(0, |f| f.code)),
                online: s.online,
                age: s.updated.map(|t| t.elapsed().as_secs_f64()),
                polls: s.polls,
                poll_errors: s.poll_errors,
            }
        })
    }
}

/// What a scrape reads of one bus.
struct BusRow {
    labels: std::ops::Range<usize>,
    stats: drivebus_link::owner::BusStats,
    online: bool,
    /// The gateway masters the bus (not a standby listening).
    master: bool,
    /// How much longer than its interval its last polled drive waited, s.
    poll_lag: f64,
    takeovers: u64,
    yields: u64,
}

/// The drive, bus and gateway series, read from the cache, the bus owners and the counters.
fn core_series(gw: &Gateway, out: &mut String) {
    let topo = gw.topology();

    // Per drive: a snapshot of each (one lock each), then one pass per family. A value the
    // drive has not given yet is absent, not zero.
    let mut text = String::with_capacity(topo.drives.len() * 64);
    let drives: Vec<DriveRow> = topo.drives.iter().map(|d| DriveRow::of(d, &mut text)).collect();
    let per_drive = |f: fn(&DriveRow) -> Option<Value>| rows(&drives, &text, |r| r.labels.clone(), f);
    fn gauge(x: Option<f64>) -> Option<Value> {
        x.map(Value::Gauge)
    }
    fn flag(x: Option<bool>) -> Option<Value> {
        x.map(|b| Value::Flag(i64::from(b)))
    }
    family(out, ("drive_output_hz", "Output frequency, Hz.", None), per_drive(|r| gauge(r.output_hz)));
    family(
        out,
        ("drive_setpoint_hz", "Speed setpoint, Hz (the last commanded where the drive does not tell).", None),
        per_drive(|r| gauge(r.setpoint_hz)),
    );
    family(out, ("drive_current_a", "Motor current, A.", None), per_drive(|r| gauge(r.current_a)));
    family(out, ("drive_running", "1 when the output is on.", None), per_drive(|r| flag(r.running)));
    family(
        out,
        ("drive_fault_code", "The drive's code of the fault in force, 0 when none.", None),
        per_drive(|r| r.fault_code.map(|c| Value::Flag(i64::from(c)))),
    );
    family(out, ("drive_online", "1 when the drive answers its polls.", None), per_drive(|r| flag(r.online)));
    family(
        out,
        ("drive_data_age", "Age of the cached values.", Some("seconds")),
        per_drive(|r| gauge(r.age)),
    );
    family(out, ("drive_polls", "Status polls made.", None), per_drive(|r| Some(Value::Count(r.polls))));
    family(
        out,
        ("drive_poll_errors", "Status polls that failed.", None),
        per_drive(|r| Some(Value::Count(r.poll_errors))),
    );

    // Per bus.
    text.clear();
    let buses: Vec<BusRow> = topo
        .buses
        .iter()
        .map(|b| {
            let rs = b.role_status();
            BusRow {
                labels: push_labels(&mut text, &[("bus", b.config.name.as_str())]),
                stats: b.stats(),
                online: b.online(),
                master: b.role() == drivebus_link::role::Role::Master,
                poll_lag: b.poll_lag().as_secs_f64(),
                takeovers: rs.map_or(0, |r| r.takeovers),
                yields: rs.map_or(0, |r| r.yields),
            }
        })
        .collect();
    fn per_bus<'a>(
        buses: &'a [BusRow],
        text: &'a str,
        f: impl Fn(&BusRow) -> Value + 'a,
    ) -> impl Iterator<Item = (&'a str, Option<Value>)> + 'a {
        rows(buses, text, |r| r.labels.clone(), move |r| Some(f(r)))
    }
    let count = |name, help, f: fn(&drivebus_link::owner::BusStats) -> u64| {
        (name, help, move |r: &BusRow| Value::Count(f(&r.stats)))
    };
    for (name, help, v) in [
        count("bus_transactions", "Requests sent, retries included.", |s| s.transactions),
        count("bus_replies", "Replies received.", |s| s.replies),
        count("bus_timeouts", "Requests not answered in time.", |s| s.timeouts),
        count("bus_checksum_errors", "Damaged replies.", |s| s.checksum_errors),
        count("bus_retries", "Retries after a timeout or a damaged reply.", |s| s.retries),
        count(
            "bus_stray_replies",
            "Modbus TCP answers to no request in flight (a stray or repeated transaction id), dropped.",
            |s| s.stray_replies,
        ),
    ] {
        family(out, (name, help, None), per_bus(&buses, &text, v));
    }
    family(
        out,
        ("bus_utilization", "Time on the wire over time elapsed (0..1).", None),
        per_bus(&buses, &text, |r| {
            let u = r.stats.utilization();
            Value::Gauge(if u.is_finite() { u } else { 0.0 })
        }),
    );
    family(
        out,
        (
            "bus_poll_lag",
            "How much longer than its poll interval the last polled drive's values waited for the poll: above 0 for long, the line cannot poll its drives at their poll_ms.",
            Some("seconds"),
        ),
        per_bus(&buses, &text, |r| Value::Gauge(r.poll_lag)),
    );
    let (name, help, v) =
        count("bus_wire_bytes", "Bytes of the requests and their replies on the line.", |s| s.wire_bytes);
    family(out, (name, help, None), per_bus(&buses, &text, v));
    family(
        out,
        ("bus_online", "1 unless the bus's port failed.", None),
        per_bus(&buses, &text, |r| Value::Flag(i64::from(r.online))),
    );
    let (name, help, v) = count(
        "bus_foreign_broadcasts",
        "Broadcasts heard on the line that the gateway did not send (a drive acting as bus master).",
        |s| s.foreign_broadcasts,
    );
    family(out, (name, help, None), per_bus(&buses, &text, v));
    family(
        out,
        ("bus_drive_master", "1 while a drive acts as bus master on the line.", None),
        per_bus(&buses, &text, |r| Value::Flag(i64::from(crate::core::drive_master(&r.stats)))),
    );
    family(
        out,
        ("bus_role", "1 while the gateway masters the bus, 0 while it listens as a standby.", None),
        per_bus(&buses, &text, |r| Value::Flag(i64::from(r.master))),
    );
    family(
        out,
        ("bus_takeovers", "Times the gateway took the line over from another master.", None),
        per_bus(&buses, &text, |r| Value::Count(r.takeovers)),
    );
    family(
        out,
        ("bus_yields", "Times the gateway stopped sending on hearing another master.", None),
        per_bus(&buses, &text, |r| Value::Count(r.yields)),
    );

    // The gateway's own work.
    let c = &gw.counters;
    family(
        out,
        ("commands", "Commands confirmed by a drive (ok) or refused or failed.", None),
        [
            ("result=\"ok\"", Some(Value::Count(c.commands_ok.load(Ordering::Relaxed)))),
            ("result=\"failed\"", Some(Value::Count(c.commands_failed.load(Ordering::Relaxed)))),
        ],
    );
    single(
        out,
        ("store_errors", "Events that could not be written to the store."),
        Value::Count(c.store_errors.load(Ordering::Relaxed)),
    );
    single(
        out,
        (
            "commands_not_recorded",
            "Commands refused, not sent, because their audit record could not be committed.",
        ),
        Value::Count(c.commands_not_recorded.load(Ordering::Relaxed)),
    );
}

/// The health series (the facts of /readyz) and the reloads: the kept facts, the store's as of
/// its last scheduled check.
fn health_series(gw: &Gateway, out: &mut String) {
    let h = gw.health();
    let flag = |b: bool| Value::Flag(i64::from(b));
    single(
        out,
        ("ready", "1 when every configured listener and Modbus RTU slave is up and the store is writable."),
        flag(gw.not_ready().is_empty()),
    );
    let mut text = String::new();
    let listeners: Vec<_> = h
        .listeners()
        .iter()
        .map(|l| (push_labels(&mut text, &[("listener", l.name.as_str())]), l.up))
        .collect();
    family(
        out,
        ("listener_up", "1 when the listener accepts connections.", None),
        listeners.iter().map(|(l, up)| (&text[l.clone()], Some(flag(*up)))),
    );
    let mut text = String::new();
    let slaves: Vec<_> = h
        .slave_ports()
        .iter()
        .map(|p| (push_labels(&mut text, &[("port", p.port.as_str())]), p.down.is_none()))
        .collect();
    family(
        out,
        ("modbus_rtu_up", "1 when the Modbus RTU slave's port is open and served.", None),
        slaves.iter().map(|(l, up)| (&text[l.clone()], Some(flag(*up)))),
    );
    if let Some(verdict) = h.store_verdict() {
        single(
            out,
            (
                "store_writable",
                "1 when the store's folder and file take writes and its filesystem has [store] min_free_mb free.",
            ),
            flag(verdict.is_ok()),
        );
    }
    let (ok, failed) = h.reloads();
    family(
        out,
        ("config_reloads", "Configuration reloads applied (ok) or refused (failed).", None),
        [("result=\"ok\"", Some(Value::Count(ok))), ("result=\"failed\"", Some(Value::Count(failed)))],
    );
    single(
        out,
        ("config_reload_failed", "1 while the last reload was refused (the previous configuration runs)."),
        flag(h.last_reload_error().is_some()),
    );
}

#[cfg(test)]
mod tests {
    use prometheus_client::metrics::gauge::Gauge;
    use std::sync::atomic::AtomicU64;

    use super::*;

    type Labels = Vec<(String, String)>;

    fn labels(pairs: &[(&str, &str)]) -> Labels {
        pairs.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect()
    }

    /// The series written by hand are the text `prometheus-client` writes for the same
    /// families: names, units, `_total`, label escaping and number formats.
    #[test]
    fn hand_written_series_are_what_prometheus_client_writes() {
        let rows = [
            (
                labels(&[("bus", "line-1"), ("drive", "pump \"A\\1\"\nnew"), ("family", "generic")]),
                40.25,
                7,
                -3,
            ),
            (labels(&[("bus", "line-2"), ("drive", "fan-1"), ("family", "b800")]), 0.1, 0, 1),
        ];
        let mut reg = Registry::with_prefix(PREFIX);
        let hz = Family::<Labels, Gauge<f64, AtomicU64>>::default();
        let age = Family::<Labels, Gauge<f64, AtomicU64>>::default();
        let polls = Family::<Labels, Counter>::default();
        let fault = Family::<Labels, Gauge>::default();
        let ready = Gauge::<i64>::default();
        // The registry ends each help text with a full stop of its own.
        reg.register("drive_output_hz", "Output frequency, Hz", hz.clone());
        reg.register_with_unit("drive_data_age", "Age of the cached values", Unit::Seconds, age.clone());
        reg.register("drive_polls", "Status polls made", polls.clone());
        reg.register("drive_fault_code", "Fault", fault.clone());
        reg.register("ready", "1 when ready", ready.clone());
        for (l, x, n, f) in &rows {
            hz.get_or_create(l).set(*x);
            age.get_or_create(l).set(*x * 3.0);
            polls.get_or_create(l).inc_by(*n);
            fault.get_or_create(l).set(*f);
        }
        ready.set(1);
        let mut theirs = String::new();
        encode_registry(&mut theirs, &reg).unwrap();

        let mut text = String::new();
        let ours_rows: Vec<_> = rows
            .iter()
            .map(|(l, x, n, f)| {
                let pairs: Vec<(&str, &str)> = l.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect();
                (push_labels(&mut text, &pairs), *x, *n, *f)
            })
            .collect();
        let each = |f: &dyn Fn(f64, u64, i64) -> Value| {
            ours_rows.iter().map(|(l, x, n, c)| (&text[l.clone()], Some(f(*x, *n, *c)))).collect::<Vec<_>>()
        };
        let mut ours = String::new();
        family(
            &mut ours,
            ("drive_output_hz", "Output frequency, Hz.", None),
            each(&|x, _, _| Value::Gauge(x)),
        );
        family(
            &mut ours,
            ("drive_data_age", "Age of the cached values.", Some("seconds")),
            each(&|x, _, _| Value::Gauge(x * 3.0)),
        );
        family(&mut ours, ("drive_polls", "Status polls made.", None), each(&|_, n, _| Value::Count(n)));
        family(&mut ours, ("drive_fault_code", "Fault.", None), each(&|_, _, f| Value::Flag(f)));
        single(&mut ours, ("ready", "1 when ready."), Value::Flag(1));
        // The same descriptors in the same order, and the same series (a family of the
        // library keeps its series in a hash map: their order is its own).
        let described =
            |t: &str| t.lines().filter(|l| l.starts_with('#')).map(String::from).collect::<Vec<_>>();
        assert_eq!(described(&ours), described(&theirs));
        let sorted = |t: &str| {
            let mut l: Vec<String> = t.lines().map(String::from).collect();
            l.sort();
            l
        };
        assert_eq!(sorted(&ours), sorted(&theirs), "{ours}\n---\n{theirs}");
    }

    /// A family none of whose rows has a value is left out whole, as a registered family
    /// without series.
    #[test]
    fn a_family_without_values_is_not_written() {
        let mut out = String::new();
        family(
            &mut out,
            ("drive_output_hz", "Output frequency, Hz.", None),
            [("drive=\"a\"", None), ("", None)],
        );
        assert_eq!(out, "");
    }
}
