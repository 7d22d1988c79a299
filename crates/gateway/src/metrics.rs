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
use std::sync::{Arc, OnceLock, Weak};

use prometheus_client::collector::Collector;
use prometheus_client::encoding::text::encode;
use prometheus_client::encoding::{DescriptorEncoder, EncodeLabelSet, MetricEncoder, NoLabelSet};
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{exponential_buckets, Histogram};
use prometheus_client::metrics::MetricType;
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
    /// The exposition's registry, built on the first scrape ([`render`]).
    exposition: Exposition,
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
/// The registry is built once per gateway: the front ends' families are registered as they are
/// (shared with the front ends that count), and the drive, bus, gateway and health series are
/// written by collectors ([`CoreSeries`], [`HealthSeries`]) straight from the cache, the bus
/// owners' counts and the kept health facts at each scrape. Nothing is polled, no file is
/// touched (the store's check runs on its own schedule, `health::STORE_CHECK_EVERY`).
pub fn render(gw: &Arc<Gateway>) -> Result<String, String> {
    let front_ends = attached(gw);
    let exposition = &front_ends.exposition;
    let reg = exposition.registry.get_or_init(|| registry(gw));
    let mut out = String::with_capacity(exposition.last_len.load(Ordering::Relaxed) + 4096);
    encode(&mut out, reg).map_err(|e| format!("cannot encode the metrics: {e}"))?;
    exposition.last_len.store(out.len(), Ordering::Relaxed);
    Ok(out)
}

/// The registry of `gw`'s exposition; the series come out in this order: drives, buses, the
/// gateway's counts, the front ends', Sparkplug's, health.
fn registry(gw: &Arc<Gateway>) -> Registry {
    let mut reg = Registry::with_prefix("drivebus");
    reg.register_collector(Box::new(CoreSeries { gw: Arc::downgrade(gw) }));
    let f = front_ends(gw);
    // A sub-registry of the same prefix: encoded after the collector above.
    let fronts = reg.sub_registry_with_labels(std::iter::empty());
    fronts.register(
        "http_requests",
        "HTTP requests answered, by route, method and status",
        f.http_requests.clone(),
    );
    fronts.register_with_unit(
        "http_request_duration",
        "Time to the response's head, by route",
        Unit::Seconds,
        f.http_latency.clone(),
    );
    fronts.register(
        "modbus_requests",
        "Modbus TCP requests, by function code and result",
        f.modbus_requests.clone(),
    );
    fronts.register_with_unit(
        "modbus_request_duration",
        "Time to answer a Modbus TCP request, from the cache or through the bus",
        Unit::Seconds,
        f.modbus_latency.clone(),
    );
    fronts.register(
        "mqtt_publishes",
        "MQTT messages handed to the client, by kind",
        f.mqtt_publishes.clone(),
    );
    fronts.register("mqtt_connections", "Connections made to the MQTT broker", f.mqtt_connections.clone());
    attached(gw).sparkplug.register(&mut reg);
    reg.sub_registry_with_labels(std::iter::empty())
        .register_collector(Box::new(HealthSeries { gw: Arc::downgrade(gw) }));
    reg
}

/// One value of a series.
#[derive(Clone, Copy)]
enum Value {
    Gauge(f64),
    Flag(i64),
    Count(u64),
}

impl Value {
    fn kind(self) -> MetricType {
        match self {
            Value::Gauge(_) | Value::Flag(_) => MetricType::Gauge,
            Value::Count(_) => MetricType::Counter,
        }
    }

    /// Writes the value as a gauge (`Gauge`, `Flag`) or a counter (`Count`), as the
    /// registered metrics of those types do.
    fn encode(self, mut series: MetricEncoder) -> Result<(), std::fmt::Error> {
        match self {
            Value::Gauge(x) => series.encode_gauge(&x),
            Value::Flag(x) => series.encode_gauge(&x),
            Value::Count(x) => series.encode_counter::<NoLabelSet, _, u64>(&x, None),
        }
    }
}

/// Writes family `name` with one series per row that has a value; nothing (not even its
/// description) when none has one, as a registered family without series.
fn family<'r, R, L: EncodeLabelSet>(
    enc: &mut DescriptorEncoder,
    (name, help, unit): (&str, &str, Option<&Unit>),
    rows: &'r [R],
    labels: impl Fn(&'r R) -> L,
    value: impl Fn(&R) -> Option<Value>,
) -> Result<(), std::fmt::Error> {
    let Some(first) = rows.iter().find_map(&value) else { return Ok(()) };
    let mut m = enc.encode_descriptor(name, help, unit, first.kind())?;
    for r in rows {
        let Some(v) = value(r) else { continue };
        let l = labels(r);
        v.encode(m.encode_family(&l)?)?;
    }
    Ok(())
}

/// Writes family `name` of one series without labels.
fn single(enc: &mut DescriptorEncoder, (name, help): (&str, &str), v: Value) -> Result<(), std::fmt::Error> {
    v.encode(enc.encode_descriptor(name, help, None, v.kind())?)
}

/// What a scrape reads of one drive, under one lock of its state.
struct DriveRow<'a> {
    labels: [(&'static str, &'a str); 3],
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

impl<'a> DriveRow<'a> {
    fn labels(&self) -> [(&'static str, &'a str); 3] {
        self.labels
    }

    fn of(d: &'a DriveEntry) -> DriveRow<'a> {
        d.with_state(|s| {
            let st = s.status.as_ref();
            let running = st.map(|x| x.running);
            DriveRow {
                labels: [("bus", &d.bus), ("drive", &d.config.name), ("family", d.config.family.as_str())],
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
struct BusRow<'a> {
    labels: [(&'static str, &'a str); 1],
    stats: drivebus_link::owner::BusStats,
    online: bool,
    /// The gateway masters the bus (not a standby listening).
    master: bool,
    takeovers: u64,
    yields: u64,
}

impl<'a> BusRow<'a> {
    fn labels(&self) -> [(&'static str, &'a str); 1] {
        self.labels
    }
}

/// The drive, bus and gateway series, read from the cache, the bus owners and the counters at
/// each scrape.
#[derive(Debug)]
struct CoreSeries {
    gw: Weak<Gateway>,
}

impl Collector for CoreSeries {
    fn encode(&self, mut enc: DescriptorEncoder) -> Result<(), std::fmt::Error> {
        let Some(gw) = self.gw.upgrade() else { return Ok(()) };
        let topo = gw.topology();

        // Per drive. A value the drive has not given yet is absent, not zero.
        let drives: Vec<DriveRow> = topo.drives.iter().map(|d| DriveRow::of(d)).collect();
        let e = &mut enc;
        let dl = DriveRow::labels;
        let gauge = |x: Option<f64>| x.map(Value::Gauge);
        let flag = |x: Option<bool>| x.map(|b| Value::Flag(i64::from(b)));
        family(e, ("drive_output_hz", "Output frequency, Hz.", None), &drives, dl, |r| gauge(r.output_hz))?;
        family(
            e,
            (
                "drive_setpoint_hz",
                "Speed setpoint, Hz (the last commanded where the drive does not tell).",
                None,
            ),
            &drives,
            dl,
            |r| gauge(r.setpoint_hz),
        )?;
        family(e, ("drive_current_a", "Motor current, A.", None), &drives, dl, |r| gauge(r.current_a))?;
        family(e, ("drive_running", "1 when the output is on.", None), &drives, dl, |r| flag(r.running))?;
        family(
            e,
            ("drive_fault_code", "The drive's code of the fault in force, 0 when none.", None),
            &drives,
            dl,
            |r| r.fault_code.map(|c| Value::Flag(i64::from(c))),
        )?;
        family(e, ("drive_online", "1 when the drive answers its polls.", None), &drives, dl, |r| {
            flag(r.online)
        })?;
        family(e, ("drive_data_age", "Age of the cached values.", Some(&Unit::Seconds)), &drives, dl, |r| {
            gauge(r.age)
        })?;
        family(e, ("drive_polls", "Status polls made.", None), &drives, dl, |r| Some(Value::Count(r.polls)))?;
        family(e, ("drive_poll_errors", "Status polls that failed.", None), &drives, dl, |r| {
            Some(Value::Count(r.poll_errors))
        })?;

        // Per bus.
        let buses: Vec<BusRow> = topo
            .buses
            .iter()
            .map(|b| {
                let rs = b.role_status();
                BusRow {
                    labels: [("bus", b.config.name.as_str())],
                    stats: b.stats(),
                    online: b.online(),
                    master: b.role() == drivebus_link::role::Role::Master,
                    takeovers: rs.map_or(0, |r| r.takeovers),
                    yields: rs.map_or(0, |r| r.yields),
                }
            })
            .collect();
        let bl = BusRow::labels;
        let count = |name, help, f: fn(&drivebus_link::owner::BusStats) -> u64| {
            (name, help, move |r: &BusRow<'_>| Some(Value::Count(f(&r.stats))))
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
            family(e, (name, help, None), &buses, bl, v)?;
        }
        family(
            e,
            ("bus_utilization", "Time on the wire over time elapsed (0..1).", None),
            &buses,
            bl,
            |r| {
                let u = r.stats.utilization();
                Some(Value::Gauge(if u.is_finite() { u } else { 0.0 }))
            },
        )?;
        let (name, help, v) =
            count("bus_wire_bytes", "Bytes of the requests and their replies on the line.", |s| s.wire_bytes);
        family(e, (name, help, None), &buses, bl, v)?;
        family(e, ("bus_online", "1 unless the bus's port failed.", None), &buses, bl, |r| {
            Some(Value::Flag(i64::from(r.online)))
        })?;
        let (name, help, v) = count(
            "bus_foreign_broadcasts",
            "Broadcasts heard on the line that the gateway did not send (a drive acting as bus master).",
            |s| s.foreign_broadcasts,
        );
        family(e, (name, help, None), &buses, bl, v)?;
        family(
            e,
            ("bus_drive_master", "1 while a drive acts as bus master on the line.", None),
            &buses,
            bl,
            |r| Some(Value::Flag(i64::from(crate::core::drive_master(&r.stats)))),
        )?;
        family(
            e,
            ("bus_role", "1 while the gateway masters the bus, 0 while it listens as a standby.", None),
            &buses,
            bl,
            |r| Some(Value::Flag(i64::from(r.master))),
        )?;
        family(
            e,
            ("bus_takeovers", "Times the gateway took the line over from another master.", None),
            &buses,
            bl,
            |r| Some(Value::Count(r.takeovers)),
        )?;
        family(
            e,
            ("bus_yields", "Times the gateway stopped sending on hearing another master.", None),
            &buses,
            bl,
            |r| Some(Value::Count(r.yields)),
        )?;

        // The gateway's own work.
        let c = &gw.counters;
        let results = [
            ([("result", "ok")], c.commands_ok.load(Ordering::Relaxed)),
            ([("result", "failed")], c.commands_failed.load(Ordering::Relaxed)),
        ];
        family(
            e,
            ("commands", "Commands confirmed by a drive (ok) or refused or failed.", None),
            &results,
            |r| r.0,
            |r| Some(Value::Count(r.1)),
        )?;
        single(
            e,
            ("store_errors", "Events that could not be written to the store."),
            Value::Count(c.store_errors.load(Ordering::Relaxed)),
        )?;
        single(
            e,
            (
                "commands_not_recorded",
                "Commands refused, not sent, because their audit record could not be committed.",
            ),
            Value::Count(c.commands_not_recorded.load(Ordering::Relaxed)),
        )
    }
}

/// The health series (the facts of /readyz) and the reloads: the kept facts, the store's as of
/// its last scheduled check.
#[derive(Debug)]
struct HealthSeries {
    gw: Weak<Gateway>,
}

impl Collector for HealthSeries {
    fn encode(&self, mut enc: DescriptorEncoder) -> Result<(), std::fmt::Error> {
        let Some(gw) = self.gw.upgrade() else { return Ok(()) };
        let e = &mut enc;
        let h = gw.health();
        let flag = |b: bool| Value::Flag(i64::from(b));
        single(
            e,
            (
                "ready",
                "1 when every configured listener and Modbus RTU slave is up and the store is writable.",
            ),
            flag(gw.not_ready().is_empty()),
        )?;
        let listeners = h.listeners();
        family(
            e,
            ("listener_up", "1 when the listener accepts connections.", None),
            &listeners,
            |l| [("listener", l.name.as_str())],
            |l| Some(flag(l.up)),
        )?;
        let slaves = h.slave_ports();
        family(
            e,
            ("modbus_rtu_up", "1 when the Modbus RTU slave's port is open and served.", None),
            &slaves,
            |p| [("port", p.port.as_str())],
            |p| Some(flag(p.down.is_none())),
        )?;
        if let Some(verdict) = h.store_verdict() {
            single(
                e,
                (
                    "store_writable",
                    "1 when the store's folder and file take writes and its filesystem has [store] min_free_mb free.",
                ),
                flag(verdict.is_ok()),
            )?;
        }
        let (ok, failed) = h.reloads();
        family(
            e,
            ("config_reloads", "Configuration reloads applied (ok) or refused (failed).", None),
            &[([("result", "ok")], ok), ([("result", "failed")], failed)],
            |r| r.0,
            |r| Some(Value::Count(r.1)),
        )?;
        single(
            e,
            (
                "config_reload_failed",
                "1 while the last reload was refused (the previous configuration runs).",
            ),
            flag(h.last_reload_error().is_some()),
        )
    }
}
