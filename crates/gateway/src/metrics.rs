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

use std::sync::atomic::Ordering;
use std::sync::Arc;

use prometheus_client::encoding::text::encode;
use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{exponential_buckets, Histogram};
use prometheus_client::registry::{Registry, Unit};

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

/// The front ends' own counts (HTTP, Modbus TCP, MQTT) of one gateway, shared with every
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
}

/// What the front ends attach to `gw`, made empty on first use.
pub fn attached(gw: &Gateway) -> Arc<FrontEnds> {
    gw.attached()
}

/// The front ends' counts of `gw`, made empty on first use.
pub fn front_ends(gw: &Gateway) -> Arc<FrontEndMetrics> {
    attached(gw).counts.clone()
}

/// Labels of a drive's series.
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct DriveLabels {
    bus: String,
    drive: String,
    family: String,
}

/// Labels of a bus's series.
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct BusLabels {
    bus: String,
}

/// Labels of the command count.
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct ResultLabels {
    result: &'static str,
}

/// Labels of a listener's series.
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct ListenerLabels {
    listener: String,
}

/// Labels of a Modbus RTU slave's series.
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct SlaveLabels {
    port: String,
}

type F64Gauge = Gauge<f64, std::sync::atomic::AtomicU64>;

/// The exposition now, as `GET /metrics` serves it.
pub fn render(gw: &Gateway) -> Result<String, String> {
    let mut reg = Registry::with_prefix("drivebus");

    // Per drive.
    let output_hz = Family::<DriveLabels, F64Gauge>::default();
    let setpoint_hz = Family::<DriveLabels, F64Gauge>::default();
    let current_a = Family::<DriveLabels, F64Gauge>::default();
    let running = Family::<DriveLabels, Gauge>::default();
    let fault_code = Family::<DriveLabels, Gauge>::default();
    let online = Family::<DriveLabels, Gauge>::default();
    let age = Family::<DriveLabels, F64Gauge>::default();
    let polls = Family::<DriveLabels, Counter>::default();
    let poll_errors = Family::<DriveLabels, Counter>::default();
    for d in gw.drives().iter() {
        let l = DriveLabels {
            bus: d.bus.clone(),
            drive: d.config.name.clone(),
            family: d.config.family.as_str().to_string(),
        };
        let v = gw.drive_view(d);
        let (n, errors, updated) = d.with_state(|s| (s.polls, s.poll_errors, s.updated));
        polls.get_or_create(&l).inc_by(n);
        poll_errors.get_or_create(&l).inc_by(errors);
        // A value the drive has not given yet is absent, not zero.
        if let Some(x) = v.output_hz {
            output_hz.get_or_create(&l).set(x);
        }
        if let Some(x) = v.setpoint_hz {
            setpoint_hz.get_or_create(&l).set(x);
        }
        if let Some(x) = v.current_a {
            current_a.get_or_create(&l).set(x);
        }
        if let Some(x) = v.running {
            running.get_or_create(&l).set(i64::from(x));
        }
        if v.online.is_some() || v.running.is_some() {
            fault_code.get_or_create(&l).set(v.fault.as_ref().map_or(0, |f| i64::from(f.code)));
        }
        if let Some(x) = v.online {
            online.get_or_create(&l).set(i64::from(x));
        }
        if let Some(t) = updated {
            age.get_or_create(&l).set(t.elapsed().as_secs_f64());
        }
    }
    reg.register("drive_output_hz", "Output frequency, Hz", output_hz);
    reg.register(
        "drive_setpoint_hz",
        "Speed setpoint, Hz (the last commanded where the drive does not tell)",
        setpoint_hz,
    );
    reg.register("drive_current_a", "Motor current, A", current_a);
    reg.register("drive_running", "1 when the output is on", running);
    reg.register("drive_fault_code", "The drive's code of the fault in force, 0 when none", fault_code);
    reg.register("drive_online", "1 when the drive answers its polls", online);
    reg.register_with_unit("drive_data_age", "Age of the cached values", Unit::Seconds, age);
    reg.register("drive_polls", "Status polls made", polls);
    reg.register("drive_poll_errors", "Status polls that failed", poll_errors);

    // Per bus.
    let transactions = Family::<BusLabels, Counter>::default();
    let replies = Family::<BusLabels, Counter>::default();
    let timeouts = Family::<BusLabels, Counter>::default();
    let checksum = Family::<BusLabels, Counter>::default();
    let retries = Family::<BusLabels, Counter>::default();
    let utilization = Family::<BusLabels, F64Gauge>::default();
    let wire_bytes = Family::<BusLabels, Counter>::default();
    let bus_online = Family::<BusLabels, Gauge>::default();
    let foreign = Family::<BusLabels, Counter>::default();
    let drive_master = Family::<BusLabels, Gauge>::default();
    let role = Family::<BusLabels, Gauge>::default();
    let takeovers = Family::<BusLabels, Counter>::default();
    let yields = Family::<BusLabels, Counter>::default();
    for b in gw.buses().iter() {
        let l = BusLabels { bus: b.config.name.clone() };
        let s = b.stats();
        transactions.get_or_create(&l).inc_by(s.transactions);
        replies.get_or_create(&l).inc_by(s.replies);
        timeouts.get_or_create(&l).inc_by(s.timeouts);
        checksum.get_or_create(&l).inc_by(s.checksum_errors);
        retries.get_or_create(&l).inc_by(s.retries);
        wire_bytes.get_or_create(&l).inc_by(s.wire_bytes);
        let u = s.utilization();
        utilization.get_or_create(&l).set(if u.is_finite() { u } else { 0.0 });
        bus_online.get_or_create(&l).set(i64::from(b.online()));
        foreign.get_or_create(&l).inc_by(s.foreign_broadcasts);
        drive_master.get_or_create(&l).set(i64::from(crate::core::drive_master(&s)));
        role.get_or_create(&l).set(i64::from(b.role() == drivebus_link::role::Role::Master));
        let rs = b.role_status();
        takeovers.get_or_create(&l).inc_by(rs.map_or(0, |r| r.takeovers));
        yields.get_or_create(&l).inc_by(rs.map_or(0, |r| r.yields));
    }
    reg.register("bus_transactions", "Requests sent, retries included", transactions);
    reg.register("bus_replies", "Replies received", replies);
    reg.register("bus_timeouts", "Requests not answered in time", timeouts);
    reg.register("bus_checksum_errors", "Damaged replies", checksum);
    reg.register("bus_retries", "Retries after a timeout or a damaged reply", retries);
    reg.register("bus_utilization", "Time on the wire over time elapsed (0..1)", utilization);
    reg.register("bus_wire_bytes", "Bytes of the requests and their replies on the line", wire_bytes);
    reg.register("bus_online", "1 unless the bus's port failed", bus_online);
    reg.register(
        "bus_foreign_broadcasts",
        "Broadcasts heard on the line that the gateway did not send (a drive acting as bus master)",
        foreign,
    );
    reg.register("bus_drive_master", "1 while a drive acts as bus master on the line", drive_master);
    reg.register("bus_role", "1 while the gateway masters the bus, 0 while it listens as a standby", role);
    reg.register("bus_takeovers", "Times the gateway took the line over from another master", takeovers);
    reg.register("bus_yields", "Times the gateway stopped sending on hearing another master", yields);

    // The gateway's own work.
    let c = &gw.counters;
    let commands = Family::<ResultLabels, Counter>::default();
    commands.get_or_create(&ResultLabels { result: "ok" }).inc_by(c.commands_ok.load(Ordering::Relaxed));
    commands
        .get_or_create(&ResultLabels { result: "failed" })
        .inc_by(c.commands_failed.load(Ordering::Relaxed));
    reg.register("commands", "Commands confirmed by a drive (ok) or refused or failed", commands);
    let store_errors = Counter::<u64>::default();
    store_errors.inc_by(c.store_errors.load(Ordering::Relaxed));
    reg.register("store_errors", "Events that could not be written to the store", store_errors);
    let not_recorded = Counter::<u64>::default();
    not_recorded.inc_by(c.commands_not_recorded.load(Ordering::Relaxed));
    reg.register(
        "commands_not_recorded",
        "Commands refused, not sent, because their audit record could not be committed",
        not_recorded,
    );
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
    attached(gw).sparkplug.register(&mut reg);

    // Health (the facts of /readyz) and reloads.
    let h = gw.health();
    let why = gw.not_ready();
    let ready = Gauge::<i64>::default();
    ready.set(i64::from(why.is_empty()));
    reg.register(
        "ready",
        "1 when every configured listener and Modbus RTU slave is up and the store is writable",
        ready,
    );
    let listener_up = Family::<ListenerLabels, Gauge>::default();
    for l in h.listeners() {
        listener_up.get_or_create(&ListenerLabels { listener: l.name }).set(i64::from(l.up));
    }
    reg.register("listener_up", "1 when the listener accepts connections", listener_up);
    let slaves = h.slave_ports();
    if !slaves.is_empty() {
        let slave_up = Family::<SlaveLabels, Gauge>::default();
        for p in slaves {
            slave_up.get_or_create(&SlaveLabels { port: p.port }).set(i64::from(p.down.is_none()));
        }
        reg.register("modbus_rtu_up", "1 when the Modbus RTU slave's port is open and served", slave_up);
    }
    let config = gw.config();
    if let Some(path) = &config.store {
        let writable = Gauge::<i64>::default();
        writable.set(i64::from(crate::health::store_writable(path, config.store_min_free_mb).is_ok()));
        reg.register(
            "store_writable",
            "1 when the store's folder and file take writes and its filesystem has [store] min_free_mb free",
            writable,
        );
    }
    let (ok, failed) = h.reloads();
    let reloads = Family::<ResultLabels, Counter>::default();
    reloads.get_or_create(&ResultLabels { result: "ok" }).inc_by(ok);
    reloads.get_or_create(&ResultLabels { result: "failed" }).inc_by(failed);
    reg.register("config_reloads", "Configuration reloads applied (ok) or refused (failed)", reloads);
    let reload_failed = Gauge::<i64>::default();
    reload_failed.set(i64::from(h.last_reload_error().is_some()));
    reg.register(
        "config_reload_failed",
        "1 while the last reload was refused (the previous configuration runs)",
        reload_failed,
    );

    let mut out = String::new();
    encode(&mut out, &reg).map_err(|e| format!("cannot encode the metrics: {e}"))?;
    Ok(out)
}
