//! `GET /metrics` through the router on a virtual clock: every line is an exposition line,
//! the drive, bus and gateway series are there with plausible values, and the HTTP middleware
//! counts requests by route.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use axum::body::Body;
use axum::http::{Request, StatusCode};
use axum::routing::get;
use axum::Router;
use drivebus_gateway::core::Command;
use drivebus_gateway::{Gateway, GatewayConfig};
use tower::ServiceExt;

/// One parsed sample line: `name{labels} value`.
#[derive(Debug)]
struct Sample {
    name: String,
    labels: HashMap<String, String>,
    value: f64,
}

fn parse_line(line: &str) -> Result<Option<Sample>, String> {
    if line == "# EOF" {
        return Ok(None);
    }
    if let Some(rest) = line.strip_prefix("# ") {
        let mut w = rest.splitn(3, ' ');
        let kw = w.next().unwrap_or("");
        let name = w.next().unwrap_or("");
        if !["HELP", "TYPE", "UNIT"].contains(&kw) || !valid_name(name) {
            return Err(format!("bad comment line: {line:?}"));
        }
        if kw == "TYPE" {
            let t = w.next().unwrap_or("");
            if !["counter", "gauge", "histogram", "info", "unknown", "stateset", "summary"].contains(&t) {
                return Err(format!("bad type: {line:?}"));
            }
        }
        return Ok(None);
    }
    let (series, value) = line.rsplit_once(' ').ok_or_else(|| format!("no value: {line:?}"))?;
    let value: f64 = match value {
        "+Inf" => f64::INFINITY,
        "-Inf" => f64::NEG_INFINITY,
        v => v.parse().map_err(|_| format!("bad value: {line:?}"))?,
    };
    let (name, labels) = match series.split_once('{') {
        None => (series, HashMap::new()),
        Some((name, rest)) => {
            let body = rest.strip_suffix('}').ok_or_else(|| format!("unclosed labels: {line:?}"))?;
            let mut labels = HashMap::new();
            // Label values here never contain `,` or `"` (names are letters, digits, - and _).
            for pair in body.split(',').filter(|p| !p.is_empty()) {
                let (k, v) = pair.split_once('=').ok_or_else(|| format!("bad label: {line:?}"))?;
                let v = v
                    .strip_prefix('"')
                    .and_then(|v| v.strip_suffix('"'))
                    .ok_or_else(|| format!("unquoted label value: {line:?}"))?;
                if !valid_name(k) {
                    return Err(format!("bad label name: {line:?}"));
                }
                labels.insert(k.to_string(), v.to_string());
            }
            (name, labels)
        }
    };
    if !valid_name(name) {
        return Err(format!("bad metric name: {line:?}"));
    }
    Ok(Some(Sample { name: name.to_string(), labels, value }))
}

fn valid_name(n: &str) -> bool {
    !n.is_empty()
        && !n.starts_with(|c: char| c.is_ascii_digit())
        && n.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == ':')
}

async fn get_text(app: &Router, uri: &str) -> (StatusCode, String, String) {
    let resp = app.clone().oneshot(Request::get(uri).body(Body::empty()).unwrap()).await.unwrap();
    let status = resp.status();
    let ctype =
        resp.headers().get("content-type").map(|v| v.to_str().unwrap().to_string()).unwrap_or_default();
    let body = axum::body::to_bytes(resp.into_body(), 1 << 22).await.unwrap();
    (status, ctype, String::from_utf8(body.to_vec()).unwrap())
}

fn find<'a>(samples: &'a [Sample], name: &str, labels: &[(&str, &str)]) -> Option<&'a Sample> {
    samples.iter().find(|s| {
        s.name == name && labels.iter().all(|(k, v)| s.labels.get(*k).map(String::as_str) == Some(*v))
    })
}

fn app(gw: &Arc<Gateway>) -> Router {
    Router::new()
        .route("/api/ping", get(|| async { "pong" }))
        .merge(drivebus_gateway::http::metrics::routes())
        .layer(axum::middleware::from_fn_with_state(gw.clone(), drivebus_gateway::http::metrics::track))
        .with_state(gw.clone())
}

#[tokio::test(start_paused = true)]
async fn metrics_cover_drives_buses_and_the_gateway() {
    let gw = Gateway::start(GatewayConfig::demo(), None).unwrap();
    gw.command("pump-1", Command::Speed(40.0), "test").await.unwrap();
    gw.command("pump-1", Command::Run, "test").await.unwrap();
    gw.command("pump-3", Command::Run, "test").await.unwrap_err(); // locked
    drivebus_gateway::metrics::front_ends(&gw).modbus_request(3, false);
    drivebus_gateway::metrics::front_ends(&gw).modbus_request(6, true);
    tokio::time::sleep(Duration::from_secs(20)).await;

    let app = app(&gw);
    for _ in 0..3 {
        assert_eq!(get_text(&app, "/api/ping").await.0, StatusCode::OK);
    }
    assert_eq!(get_text(&app, "/nowhere").await.0, StatusCode::NOT_FOUND);

    let (status, ctype, text) = get_text(&app, "/metrics").await;
    assert_eq!(status, StatusCode::OK);
    assert!(ctype.starts_with("application/openmetrics-text"), "{ctype}");
    assert!(text.ends_with("# EOF\n"), "no EOF marker");
    let mut samples = Vec::new();
    for line in text.lines() {
        match parse_line(line) {
            Ok(Some(s)) => samples.push(s),
            Ok(None) => {}
            Err(e) => panic!("{e}\n{text}"),
        }
    }

    // Every demo drive has its link health and poll counts.
    for d in gw.drives().iter() {
        let id = d.config.name.as_str();
        let l = [("drive", id), ("bus", d.bus.as_str()), ("family", d.config.family.as_str())];
        let online = find(&samples, "drivebus_drive_online", &l).unwrap_or_else(|| panic!("{id} online"));
        assert_eq!(online.value, 1.0, "{id}");
        let polls = find(&samples, "drivebus_drive_polls_total", &l).unwrap();
        assert!(polls.value >= 5.0, "{id}: {} polls in 20 s", polls.value);
        let age = find(&samples, "drivebus_drive_data_age_seconds", &l).unwrap();
        assert!((0.0..5.0).contains(&age.value), "{id}: age {}", age.value);
        assert!(find(&samples, "drivebus_drive_poll_errors_total", &l).is_some());
        assert!(find(&samples, "drivebus_drive_fault_code", &l).is_some());
    }
    let pump = [("drive", "pump-1")];
    let hz = find(&samples, "drivebus_drive_output_hz", &pump).unwrap().value;
    assert!((hz - 40.0).abs() < 0.1, "pump-1 at {hz} Hz");
    assert_eq!(find(&samples, "drivebus_drive_running", &pump).unwrap().value, 1.0);
    assert_eq!(find(&samples, "drivebus_drive_setpoint_hz", &pump).unwrap().value, 40.0);
    assert!(find(&samples, "drivebus_drive_current_a", &pump).unwrap().value > 0.0);
    assert_eq!(find(&samples, "drivebus_drive_running", &[("drive", "pump-2")]).unwrap().value, 0.0);

    // Buses: as many replies as the owner counted, and never more replies than requests.
    for b in gw.buses().iter() {
        let l = [("bus", b.config.name.as_str())];
        let tx = find(&samples, "drivebus_bus_transactions_total", &l).unwrap().value;
        let rx = find(&samples, "drivebus_bus_replies_total", &l).unwrap().value;
        assert!(tx > 0.0 && rx > 0.0 && rx <= tx, "{l:?}: {rx} replies to {tx} requests");
        let bytes = find(&samples, "drivebus_bus_wire_bytes_total", &l).unwrap().value;
        assert!(bytes >= 4.0 * (tx + rx), "{l:?}: {bytes} bytes for {tx} requests and {rx} replies");
        for n in ["timeouts_total", "checksum_errors_total", "retries_total"] {
            assert!(find(&samples, &format!("drivebus_bus_{n}"), &l).is_some(), "{n}");
        }
        let u = find(&samples, "drivebus_bus_utilization", &l).unwrap().value;
        assert!((0.0..=1.0).contains(&u) && u > 0.0, "utilization {u}");
        assert_eq!(find(&samples, "drivebus_bus_online", &l).unwrap().value, 1.0);
    }

    // The gateway's own work.
    assert_eq!(find(&samples, "drivebus_commands_total", &[("result", "ok")]).unwrap().value, 2.0);
    assert_eq!(find(&samples, "drivebus_commands_total", &[("result", "failed")]).unwrap().value, 1.0);
    let ping = [("route", "/api/ping"), ("method", "GET"), ("status", "200")];
    assert_eq!(find(&samples, "drivebus_http_requests_total", &ping).unwrap().value, 3.0);
    let missing = [("route", "unmatched"), ("status", "404")];
    assert_eq!(find(&samples, "drivebus_http_requests_total", &missing).unwrap().value, 1.0);
    let count = find(&samples, "drivebus_http_request_duration_seconds_count", &[("route", "/api/ping")]);
    assert_eq!(count.unwrap().value, 3.0);
    let inf = [("route", "/api/ping"), ("le", "+Inf")];
    assert_eq!(find(&samples, "drivebus_http_request_duration_seconds_bucket", &inf).unwrap().value, 3.0);
    let fc3 = [("function", "3"), ("result", "ok")];
    assert_eq!(find(&samples, "drivebus_modbus_requests_total", &fc3).unwrap().value, 1.0);
    let fc6 = [("function", "6"), ("result", "exception")];
    assert_eq!(find(&samples, "drivebus_modbus_requests_total", &fc6).unwrap().value, 1.0);

    // A second scrape counts the first.
    let (_, _, again) = get_text(&app, "/metrics").await;
    let line = again
        .lines()
        .find(|l| l.starts_with("drivebus_http_requests_total{") && l.contains("route=\"/metrics\""))
        .expect("the first scrape is counted");
    assert!(line.ends_with(" 1"), "{line}");
}

#[tokio::test(start_paused = true)]
async fn values_not_read_yet_are_absent_not_zero() {
    let gw = Gateway::start(GatewayConfig::demo(), None).unwrap();
    // Before the first poll answered nothing is known of the drives.
    let text = drivebus_gateway::metrics::render(&gw).unwrap();
    let samples: Vec<Sample> = text.lines().filter_map(|l| parse_line(l).unwrap()).collect();
    assert!(find(&samples, "drivebus_drive_output_hz", &[]).is_none(), "{text}");
    assert!(find(&samples, "drivebus_drive_online", &[]).is_none(), "{text}");
    assert!(find(&samples, "drivebus_drive_polls_total", &[("drive", "fan-1")]).is_some());
}

#[tokio::test(start_paused = true)]
async fn metrics_need_a_read_token_when_reads_do() {
    let mut config = GatewayConfig::demo();
    config.http.anonymous_read = false;
    let token = "a-reader-secret".to_string();
    config.tokens.push(drivebus_gateway::config::Token {
        name: "historian".into(),
        secret: token.clone(),
        role: drivebus_gateway::config::Role::Read,
    });
    let gw = Gateway::start(config, None).unwrap();
    let app = app(&gw);
    let (status, _, body) = get_text(&app, "/metrics").await;
    assert_eq!(status, StatusCode::UNAUTHORIZED, "{body}");
    assert!(!body.contains("drivebus_drive_output_hz"), "no drive values leak: {body}");
    let resp = app
        .clone()
        .oneshot(
            Request::get("/metrics")
                .header("authorization", format!("Bearer {token}"))
                .body(Body::empty())
                .unwrap(),
        )
        .await
        .unwrap();
    assert_eq!(resp.status(), StatusCode::OK);
    // Modbus TCP latencies are there once a request was answered.
    drivebus_gateway::metrics::front_ends(&gw).modbus_latency(false, 20e-6);
    drivebus_gateway::metrics::front_ends(&gw).modbus_latency(true, 0.030);
    let text = drivebus_gateway::metrics::render(&gw).unwrap();
    assert!(text.contains("drivebus_modbus_request_duration_seconds_count{path=\"cache\"} 1"), "{text}");
    assert!(text.contains("drivebus_modbus_request_duration_seconds_count{path=\"bus\"} 1"), "{text}");
}

#[tokio::test(start_paused = true)]
async fn bus_errors_on_a_noisy_line_are_counted() {
    let gw = Gateway::start(GatewayConfig::demo(), None).unwrap();
    let noisy =
        gw.buses().iter().find(|b| b.config.name == "line-generic").expect("the demo's generic bus").clone();
    let line = noisy.line.as_ref().expect("a virtual bus");
    line.lock().unwrap().set_faults(drivebus_sim::bus::Faults {
        corrupt_rate: 0.02,
        drop_rate: 0.02,
        ..Default::default()
    });
    // A minute of polling on tokio's paused clock (virtual time; the test takes well under a second).
    tokio::time::sleep(Duration::from_secs(60)).await;

    let text = drivebus_gateway::metrics::render(&gw).unwrap();
    let samples: Vec<Sample> = text.lines().filter_map(|l| parse_line(l).unwrap()).collect();
    let value = |name: &str, bus: &str| {
        find(&samples, name, &[("bus", bus)]).unwrap_or_else(|| panic!("{name}")).value
    };
    for n in
        ["drivebus_bus_timeouts_total", "drivebus_bus_checksum_errors_total", "drivebus_bus_retries_total"]
    {
        assert!(value(n, "line-generic") > 0.0, "{n} counts the noise: {}", value(n, "line-generic"));
        assert_eq!(value(n, "line-toshiba"), 0.0, "{n} on a quiet line");
    }
    // The same counts as the bus owner's, which /api/buses shows too.
    let stats = noisy.stats();
    assert_eq!(value("drivebus_bus_checksum_errors_total", "line-generic"), stats.checksum_errors as f64);
    assert_eq!(value("drivebus_bus_timeouts_total", "line-generic"), stats.timeouts as f64);
}

#[tokio::test(start_paused = true)]
async fn front_end_counts_belong_to_their_gateway() {
    let one = Gateway::start(GatewayConfig::demo(), None).unwrap();
    let two = Gateway::start(GatewayConfig::demo(), None).unwrap();
    // The counts a front end attaches are one per gateway and per type, made on first use.
    assert!(Arc::ptr_eq(
        &drivebus_gateway::metrics::front_ends(&one),
        &drivebus_gateway::metrics::front_ends(&one)
    ));
    drivebus_gateway::metrics::front_ends(&one).mqtt_connected();
    drivebus_gateway::metrics::front_ends(&one).modbus_request(3, false);
    assert_eq!(drivebus_gateway::metrics::front_ends(&one).mqtt_connections(), 1);
    assert_eq!(drivebus_gateway::metrics::front_ends(&two).mqtt_connections(), 0);
    let (a, b) =
        (drivebus_gateway::metrics::render(&one).unwrap(), drivebus_gateway::metrics::render(&two).unwrap());
    assert!(a.contains("drivebus_mqtt_connections_total 1"), "{a}");
    assert!(b.contains("drivebus_mqtt_connections_total 0"), "{b}");
    assert!(a.contains("drivebus_modbus_requests_total{function=\"3\",result=\"ok\"} 1"), "{a}");
    assert!(!b.contains("drivebus_modbus_requests_total{"), "{b}");
    // The Sparkplug edge node's counts are there (zero) without an edge node.
    assert!(b.contains("drivebus_sparkplug_connections_total 0"), "{b}");
}

/// Every series docs/metrics.md lists, from its tables: name, type and label names.
fn documented_series() -> std::collections::BTreeMap<String, (String, Vec<String>)> {
    let doc = include_str!("../../../docs/metrics.md");
    let mut out = std::collections::BTreeMap::new();
    let mut section_labels: Vec<String> = Vec::new();
    for line in doc.lines() {
        if line.starts_with("### ") {
            // `### Per drive (labels `bus`, `drive`, `family`)`: the labels of the table below.
            section_labels = line.split('`').skip(1).step_by(2).map(str::to_string).collect();
            continue;
        }
        let Some(row) = line.strip_prefix("| `drivebus_") else { continue };
        let cells: Vec<&str> = row.split(" | ").collect();
        let name = format!("drivebus_{}", cells[0].trim_end_matches('`'));
        let kind = cells[1].trim().to_string();
        // The gateway's table has a labels column: `route`, `method`, `status` or
        // `result` = `ok` / `failed` (the first quoted word of each comma-separated part).
        let mut labels: Vec<String> = if cells.len() == 4 {
            cells[2]
                .split(", ")
                .filter_map(|part| part.split('`').nth(1))
                .filter(|l| !l.is_empty())
                .map(str::to_string)
                .collect()
        } else {
            section_labels.clone()
        };
        labels.sort();
        out.insert(name, (kind, labels));
    }
    out
}

/// The series of an exposition by the name docs/metrics.md gives them (counters with `_total`,
/// a histogram by its family name): type and label names (a histogram's `le` left out).
fn exposed_series(text: &str) -> std::collections::BTreeMap<String, (String, Vec<String>)> {
    let mut out = std::collections::BTreeMap::new();
    let mut family = (String::new(), String::new());
    for line in text.lines() {
        if let Some(t) = line.strip_prefix("# TYPE ") {
            let (name, kind) = t.split_once(' ').unwrap();
            family = (name.to_string(), kind.to_string());
            continue;
        }
        let Some(s) = parse_line(line).unwrap() else { continue };
        let (fam, kind) = (&family.0, family.1.as_str());
        let name = match kind {
            "counter" => {
                assert_eq!(s.name, format!("{fam}_total"), "{line}");
                s.name.clone()
            }
            "histogram" => {
                let ok = ["_bucket", "_sum", "_count"].iter().any(|x| s.name == format!("{fam}{x}"));
                assert!(ok, "{line} is not of histogram {fam}");
                fam.clone()
            }
            _ => {
                assert_eq!(&s.name, fam, "{line}");
                s.name.clone()
            }
        };
        let mut labels: Vec<String> = s.labels.keys().filter(|k| *k != "le").cloned().collect();
        labels.sort();
        let prev = out.insert(name.clone(), (kind.to_string(), labels.clone()));
        if let Some(p) = prev {
            assert_eq!(p, (kind.to_string(), labels), "{name}: series with other labels");
        }
    }
    out
}

/// The demo gateway with its store in a new, empty file of the folder
/// `drivebus-metrics-<test>-<pid>` in the temporary folder (no free-space floor); the folder, for
/// the test to remove.
fn demo_with_store(test: &str) -> (PathBuf, Arc<Gateway>) {
    let dir = std::env::temp_dir().join(format!("drivebus-metrics-{test}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let db = dir.join("events.db");
    std::fs::write(&db, b"").unwrap();
    let mut config = GatewayConfig::demo();
    config.store = Some(db);
    config.store_min_free_mb = 0;
    (dir, Gateway::start(config, None).unwrap())
}

#[tokio::test(start_paused = true)]
async fn the_exposition_has_exactly_the_series_docs_metrics_md_lists() {
    let (dir, gw) = demo_with_store("golden");
    gw.command("pump-1", Command::Speed(40.0), "test").await.unwrap();
    gw.command("pump-1", Command::Run, "test").await.unwrap();
    // Every conditional series made present: a request of each front end, an RTU slave's port.
    let f = drivebus_gateway::metrics::front_ends(&gw);
    f.modbus_request(3, false);
    f.mqtt_published("status");
    let sp = drivebus_gateway::sparkplug::metrics(&gw);
    sp.messages("nbirth");
    sp.refused("disabled");
    gw.health().slave_port("/dev/ttyRTU0", None);
    gw.health().listener("http", "127.0.0.1:8080".parse().unwrap(), true);
    // An OPC UA server's subscriptions (none) shown.
    let (_server, opcua) = opcua::server::ServerBuilder::new_anonymous("metrics")
        .pki_dir(dir.join("pki"))
        .create_sample_keypair(false)
        .build()
        .unwrap();
    drivebus_gateway::metrics::attached(&gw).serve_opcua(opcua.subscriptions().clone());
    tokio::time::sleep(Duration::from_secs(20)).await;
    let app = app(&gw);
    assert_eq!(get_text(&app, "/api/ping").await.0, StatusCode::OK);

    let text = drivebus_gateway::metrics::render(&gw).unwrap();
    assert!(text.contains("\ndrivebus_opcua_monitored_items 0\n"), "{text}");
    let documented = documented_series();
    assert!(documented.len() > 40, "the tables of docs/metrics.md were not read: {documented:?}");
    let exposed = exposed_series(&text);
    for (name, want) in &documented {
        assert_eq!(exposed.get(name), Some(want), "{name} as docs/metrics.md lists it\n{text}");
    }
    for name in exposed.keys() {
        assert!(documented.contains_key(name), "{name} is not in docs/metrics.md");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test(start_paused = true)]
async fn a_scrape_touches_no_file_the_store_is_checked_on_its_own_schedule() {
    use drivebus_gateway::health::STORE_CHECK_EVERY;
    let (dir, gw) = demo_with_store("noio");
    let app = app(&gw).merge(drivebus_gateway::http::health::routes().with_state(gw.clone()));
    let writable = |text: &str| {
        text.lines().find_map(|l| l.strip_prefix("drivebus_store_writable ")).map(str::to_string)
    };
    assert_eq!(writable(&drivebus_gateway::metrics::render(&gw).unwrap()).as_deref(), Some("1"));

    // The store's folder goes. Scrapes and /readyz read the verdict kept from the last check,
    // so they say the same as before until the next scheduled check.
    std::fs::remove_dir_all(&dir).unwrap();
    for _ in 0..3 {
        let text = drivebus_gateway::metrics::render(&gw).unwrap();
        assert_eq!(writable(&text).as_deref(), Some("1"), "{text}");
        assert!(text.contains("\ndrivebus_ready 1\n"), "{text}");
        assert_eq!(get_text(&app, "/readyz").await.0, StatusCode::OK);
    }
    tokio::time::sleep(STORE_CHECK_EVERY - Duration::from_secs(1)).await;
    assert_eq!(writable(&drivebus_gateway::metrics::render(&gw).unwrap()).as_deref(), Some("1"));

    // The scheduled check (off the async workers) sees it; the next scrape says so.
    tokio::time::sleep(Duration::from_secs(2)).await;
    let start = std::time::Instant::now();
    while writable(&drivebus_gateway::metrics::render(&gw).unwrap()).as_deref() != Some("0") {
        assert!(start.elapsed() < Duration::from_secs(30), "the scheduled check did not run");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let text = drivebus_gateway::metrics::render(&gw).unwrap();
    assert!(text.contains("\ndrivebus_ready 0\n"), "{text}");
    let (status, _, body) = get_text(&app, "/readyz").await;
    assert_eq!(status, StatusCode::SERVICE_UNAVAILABLE, "{body}");
    assert!(body.contains("store: cannot write"), "{body}");
}
