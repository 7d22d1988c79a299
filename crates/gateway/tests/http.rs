//! The HTTP API in process (tower `oneshot`) on the demo gateway over a virtual clock: every
//! route, every error answer, the auth matrix, the live stream and the OpenAPI document.

mod support;

use std::collections::{BTreeMap, BTreeSet};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use axum::body::Body;
use axum::extract::connect_info::MockConnectInfo;
use axum::http::{header, Method, Request, StatusCode};
use axum::Router;
use drivebus_gateway::config::{Role, Token};
use drivebus_gateway::core::{Change, Gateway};
use drivebus_gateway::http::{api::OPENAPI, router, API_ROUTES};
use drivebus_gateway::GatewayConfig;
use http_body_util::BodyExt;
use serde_json::{json, Value};
use support::settle;
use tower::ServiceExt;

const WRITE: &str = "write-token-0123456789abcdef";
const READ: &str = "read-token-0123456789abcdef";
const MAX_BODY: usize = 1024;

fn config(anonymous_read: bool) -> GatewayConfig {
    let mut c = GatewayConfig::demo();
    c.http.anonymous_read = anonymous_read;
    c.http.max_body = MAX_BODY;
    c.store = None;
    c.tokens = vec![
        Token { name: "writer".into(), secret: WRITE.into(), role: Role::Write },
        Token { name: "reader".into(), secret: READ.into(), role: Role::Read },
    ];
    c
}

fn app_with(gw: &Arc<Gateway>) -> Router {
    router(gw.clone()).layer(MockConnectInfo(SocketAddr::from(([127, 0, 0, 7], 40000))))
}

fn app(anonymous_read: bool, store: bool) -> (Arc<Gateway>, Router) {
    let s = store.then(|| {
        static N: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let n = N.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!("drivebus-http-test-{}-{n}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        drivebus_store::Store::open(&dir.join("events.db")).unwrap()
    });
    let gw = Gateway::start(config(anonymous_read), s).unwrap();
    let app = app_with(&gw);
    (gw, app)
}

struct Reply {
    status: StatusCode,
    headers: axum::http::HeaderMap,
    json: Value,
}

async fn call(app: &Router, method: &str, path: &str, token: Option<&str>, body: Option<&str>) -> Reply {
    let mut req = Request::builder().method(method).uri(path);
    if let Some(t) = token {
        req = req.header(header::AUTHORIZATION, format!("Bearer {t}"));
    }
    let req = req.body(body.map_or_else(Body::empty, |b| Body::from(b.to_string()))).unwrap();
    let r = app.clone().oneshot(req).await.unwrap();
    let status = r.status();
    let headers = r.headers().clone();
    let bytes = r.into_body().collect().await.unwrap().to_bytes();
    let json = serde_json::from_slice(&bytes)
        .unwrap_or_else(|e| panic!("{method} {path}: {status} answered non-JSON ({e}): {bytes:?}"));
    Reply { status, headers, json }
}

/// Asserts a JSON error of `status` and `kind` with a one-line message; returns the message.
fn assert_error(r: &Reply, status: u16, kind: &str) -> String {
    assert_eq!(r.status.as_u16(), status, "{}", r.json);
    assert_eq!(r.json["error"]["kind"], kind, "{}", r.json);
    let m = r.json["error"]["message"].as_str().expect("a message").to_string();
    assert!(!m.is_empty() && !m.contains('\n'), "{m:?}");
    assert_eq!(r.headers[header::CONTENT_TYPE], "application/json");
    m
}

#[tokio::test(start_paused = true)]
async fn reads_answer_from_the_cache() {
    let (_gw, app) = app(true, false);
    settle(3).await;
    let r = call(&app, "GET", "/api/drives", None, None).await;
    assert_eq!(r.status, 200);
    let drives = r.json.as_array().unwrap();
    assert_eq!(drives.len(), 10);
    assert_eq!(drives[3]["id"], "pump-1");
    assert!(drives.iter().all(|d| d["online"] == true), "{}", r.json);
    let r = call(&app, "GET", "/api/drives/ahu-2", None, None).await;
    assert_eq!(r.status, 200);
    assert_eq!(r.json["id"], "ahu-2");
    assert_eq!(r.json["family"], "danfoss");
    assert_eq!(r.json["unit_id"], 8);
    let r = call(&app, "GET", "/api/buses", None, None).await;
    assert_eq!(r.status, 200);
    assert_eq!(r.json.as_array().unwrap().len(), 4);
    assert_eq!(r.json[1]["drives"], json!(["pump-1", "pump-2", "pump-3"]));
}

#[tokio::test(start_paused = true)]
async fn commands_run_a_drive_and_are_audited_with_the_caller() {
    let (gw, app) = app(false, false);
    let mut rx = gw.subscribe();
    let r = call(&app, "POST", "/api/drives/pump-1/speed", Some(WRITE), Some(r#"{"hz": 40}"#)).await;
    assert_eq!(r.status, 200, "{}", r.json);
    assert_eq!(r.json["ok"], true);
    assert_eq!(r.json["drive"]["id"], "pump-1");
    let r = call(&app, "POST", "/api/drives/pump-1/run", Some(WRITE), None).await;
    assert_eq!(r.status, 200, "{}", r.json);
    settle(20).await;
    let r = call(&app, "GET", "/api/drives/pump-1", Some(READ), None).await;
    assert_eq!(r.json["running"], true, "{}", r.json);
    let hz = r.json["output_hz"].as_f64().unwrap();
    assert!((hz - 40.0).abs() < 0.1, "pump-1 at {hz} Hz");
    let mut actions = Vec::new();
    while let Ok(c) = rx.try_recv() {
        if let Change::Event(e) = c {
            // (The demo's linkage writes conveyor-2's setpoint with an audit record of its own.)
            if e.kind == drivebus_store::EventKind::Command && e.drive.as_deref() == Some("pump-1") {
                assert_eq!(e.actor.as_deref(), Some("http:writer@127.0.0.7"), "{e:?}");
                actions.push(e.action.unwrap());
            }
        }
    }
    assert_eq!(actions, ["speed 40 Hz", "run"]);
    let r = call(&app, "POST", "/api/drives/pump-1/stop", Some(WRITE), None).await;
    assert_eq!(r.status, 200, "{}", r.json);
}

#[tokio::test(start_paused = true)]
async fn parameters_read_and_write() {
    let (_gw, app) = app(true, false);
    let r = call(&app, "PUT", "/api/drives/ahu-1/params/4-14", Some(WRITE), Some(r#"{"value": "55"}"#)).await;
    assert_eq!(r.status, 200, "{}", r.json);
    let r = call(&app, "GET", "/api/drives/ahu-1/params/4-14", None, None).await;
    assert_eq!(r.status, 200, "{}", r.json);
    assert_eq!(r.json["value"], 55.0);
    assert_eq!(r.json["unit"], "Hz");
    // A number is taken as its text.
    let body = r#"{"value": 52, "eeprom": false}"#;
    let r = call(&app, "PUT", "/api/drives/ahu-1/params/4-14", Some(WRITE), Some(body)).await;
    assert_eq!(r.status, 200, "{}", r.json);
    let r = call(&app, "GET", "/api/drives/ahu-1/params/4-14", None, None).await;
    assert_eq!(r.json["value"], 52.0);
}

#[tokio::test(start_paused = true)]
async fn bad_requests_are_one_line_json_errors_and_reach_no_drive() {
    let (gw, app) = app(true, false);
    settle(2).await;
    let w = Some(WRITE);
    let speed = "/api/drives/fan-1/speed";
    // Unknown drives, on reads and writes.
    let m = assert_error(&call(&app, "GET", "/api/drives/nobody", None, None).await, 404, "unknown_drive");
    assert_eq!(m, r#"no drive "nobody": GET /api/drives lists them"#);
    assert_error(&call(&app, "POST", "/api/drives/nobody/run", w, None).await, 404, "unknown_drive");
    assert_error(
        &call(&app, "POST", "/api/drives/nobody/speed", w, Some(r#"{"hz":1}"#)).await,
        404,
        "unknown_drive",
    );
    assert_error(&call(&app, "GET", "/api/drives/nobody/trend", None, None).await, 404, "unknown_drive");
    // Bodies.
    let m = assert_error(&call(&app, "POST", speed, w, Some("{\"hz\": 40")).await, 400, "bad_json");
    assert!(m.contains("not JSON"), "{m}");
    assert_error(&call(&app, "POST", speed, w, Some("hz=40")).await, 400, "bad_json");
    assert_error(&call(&app, "POST", speed, w, None).await, 400, "bad_json");
    let m = assert_error(&call(&app, "POST", speed, w, Some("{}")).await, 422, "invalid");
    assert!(m.contains("missing field `hz`"), "{m}");
    let m =
        assert_error(&call(&app, "POST", speed, w, Some(r#"{"hz": 40, "hertz": 1}"#)).await, 422, "invalid");
    assert!(m.contains("hertz"), "{m}");
    assert_error(&call(&app, "POST", speed, w, Some(r#"{"hz": "fast"}"#)).await, 422, "invalid");
    // An array is not the object (serde would read it as the fields in order).
    let m = assert_error(&call(&app, "POST", speed, w, Some("[25]")).await, 422, "invalid");
    assert!(m.contains("JSON object"), "{m}");
    assert_error(
        &call(&app, "PUT", "/api/drives/ahu-1/params/4-14", w, Some(r#"["55", true]"#)).await,
        422,
        "invalid",
    );
    // Out of range: refused before the drive, setpoint unchanged.
    let before = call(&app, "GET", "/api/drives/fan-1", None, None).await.json["setpoint_hz"].clone();
    assert_error(&call(&app, "POST", speed, w, Some(r#"{"hz": 500}"#)).await, 422, "invalid");
    assert_error(&call(&app, "POST", speed, w, Some(r#"{"hz": -1e300}"#)).await, 422, "invalid");
    settle(2).await;
    assert_eq!(call(&app, "GET", "/api/drives/fan-1", None, None).await.json["setpoint_hz"], before);
    // Oversize bodies, declared or not.
    let big = format!(r#"{{"hz": 40, "pad": "{}"}}"#, "x".repeat(MAX_BODY));
    let m = assert_error(&call(&app, "POST", speed, w, Some(&big)).await, 413, "too_large");
    assert!(m.contains("max_body") || m.contains("length limit"), "{m}");
    let req = Request::post(speed)
        .header(header::AUTHORIZATION, format!("Bearer {WRITE}"))
        .header(header::CONTENT_LENGTH, big.len())
        .body(Body::from(big.clone()))
        .unwrap();
    let r = app.clone().oneshot(req).await.unwrap();
    assert_eq!(r.status(), 413);
    // Parameters: unknown, out of range, wrong value type.
    let p = "/api/drives/ahu-1/params/";
    assert_error(&call(&app, "GET", &format!("{p}99-99"), None, None).await, 422, "invalid");
    let ok_body = Some(r#"{"value": "50"}"#);
    assert_error(&call(&app, "PUT", &format!("{p}99-99"), w, ok_body).await, 422, "invalid");
    assert_error(
        &call(&app, "PUT", &format!("{p}4-14"), w, Some(r#"{"value": "99999"}"#)).await,
        422,
        "invalid",
    );
    assert_error(&call(&app, "PUT", &format!("{p}4-14"), w, Some(r#"{"value": [1]}"#)).await, 422, "invalid");
    assert_error(
        &call(&app, "PUT", &format!("{p}4-14"), w, Some(r#"{"eeprom": true}"#)).await,
        422,
        "invalid",
    );
    // Methods and paths.
    let r = call(&app, "DELETE", "/api/drives", w, None).await;
    assert_error(&r, 405, "method_not_allowed");
    assert!(r.headers.get(header::ALLOW).is_some());
    assert_error(&call(&app, "GET", "/api/drives/pump-1/run", None, None).await, 405, "method_not_allowed");
    let m = assert_error(&call(&app, "GET", "/api/nothing", None, None).await, 404, "not_found");
    assert!(m.contains("/api/nothing"), "{m}");
    assert_error(&call(&app, "POST", "/api/drives/pump-1/fly", w, None).await, 404, "not_found");
    // Locked drives.
    assert_error(&call(&app, "POST", "/api/drives/pump-3/run", w, None).await, 423, "locked");
    // Query strings.
    assert_error(&call(&app, "GET", "/api/events?since=yesterday", None, None).await, 400, "bad_request");
    assert_error(&call(&app, "GET", "/api/events?sinse=1", None, None).await, 400, "bad_request");
    assert_error(&call(&app, "GET", "/api/events?limit=0", None, None).await, 400, "bad_request");
    assert_error(&call(&app, "GET", "/api/events?since=5&until=4", None, None).await, 400, "bad_request");
    assert_error(
        &call(&app, "GET", "/api/drives/ahu-1/trend?resolution=1h", None, None).await,
        400,
        "bad_request",
    );
    assert_error(&call(&app, "GET", "/api/stream?drive=nobody", None, None).await, 404, "unknown_drive");
    assert_error(&call(&app, "GET", "/api/stream?drives=ahu-1", None, None).await, 400, "bad_request");
    // No store.
    assert_error(&call(&app, "GET", "/api/events", None, None).await, 503, "no_store");
    assert_error(&call(&app, "GET", "/api/drives/ahu-1/trend", None, None).await, 503, "no_store");
    // None of it reached a drive: the only commands counted are the refused ones audited by the
    // gateway (the locked drive); nothing succeeded.
    assert_eq!(gw.counters.commands_ok.load(std::sync::atomic::Ordering::Relaxed), 0);
}

#[tokio::test(start_paused = true)]
async fn events_and_trends_come_from_the_store() {
    let (_gw, app) = app(true, true);
    let r = call(&app, "GET", "/api/events?since=0&limit=50&drive=pump-1&kind=command", None, None).await;
    assert_eq!(r.status, 200, "{}", r.json);
    assert!(r.json.is_array());
    let r = call(&app, "GET", "/api/drives/pump-1/trend?since=0&until=60000&resolution=1s", None, None).await;
    assert_eq!(r.status, 200, "{}", r.json);
    assert!(r.json.is_array());
}

#[tokio::test(start_paused = true)]
async fn auth_matrix() {
    for anonymous_read in [false, true] {
        let (_gw, app) = app(anonymous_read, false);
        let read = |t| {
            let app = app.clone();
            async move { call(&app, "GET", "/api/drives/mixer-1", t, None).await }
        };
        let write = |t| {
            let app = app.clone();
            async move { call(&app, "POST", "/api/drives/mixer-1/stop", t, None).await }
        };
        // Reads.
        let r = read(None).await;
        if anonymous_read {
            assert_eq!(r.status, 200);
        } else {
            assert_error(&r, 401, "unauthorized");
            assert_eq!(r.headers[header::WWW_AUTHENTICATE], "Bearer");
        }
        assert_eq!(read(Some(READ)).await.status, 200);
        assert_eq!(read(Some(WRITE)).await.status, 200);
        assert_error(&read(Some("not-a-token-0123456789")).await, 401, "unauthorized");
        // Writes.
        assert_error(&write(None).await, 401, "unauthorized");
        assert_error(&write(Some(READ)).await, 403, "forbidden");
        assert_error(&write(Some("not-a-token-0123456789")).await, 401, "unauthorized");
        assert_error(&write(Some(&WRITE[..WRITE.len() - 1])).await, 401, "unauthorized");
        assert_eq!(write(Some(WRITE)).await.status, 200);
        // Other schemes and malformed headers.
        let req = Request::post("/api/drives/mixer-1/stop")
            .header(header::AUTHORIZATION, format!("Basic {WRITE}"))
            .body(Body::empty())
            .unwrap();
        assert_eq!(app.clone().oneshot(req).await.unwrap().status(), 401);
        // Auth comes before validation: an unauthorized bad request says unauthorized.
        assert_error(
            &call(&app, "POST", "/api/drives/nobody/speed", Some(READ), Some("{")).await,
            403,
            "forbidden",
        );
        // The OpenAPI document is public.
        let r = call(&app, "GET", "/api/openapi.json", None, None).await;
        assert_eq!(r.status, 200);
    }
}

/// Reads SSE frames until `want` matches a message's (event, data); fails after `limit` of
/// virtual time.
async fn read_stream(body: Body, limit: Duration, mut want: impl FnMut(&str, &Value) -> bool) -> Vec<String> {
    let mut body = body;
    let mut seen = Vec::new();
    let mut buf = String::new();
    let found = tokio::time::timeout(limit, async {
        loop {
            let frame = body.frame().await.expect("the stream goes on").unwrap();
            let Ok(data) = frame.into_data() else { continue };
            buf.push_str(std::str::from_utf8(&data).unwrap());
            while let Some(end) = buf.find("\n\n") {
                let msg: String = buf.drain(..end + 2).collect();
                let mut event = "";
                let mut json = Value::Null;
                for line in msg.lines() {
                    if let Some(e) = line.strip_prefix("event: ") {
                        event = e;
                    } else if let Some(d) = line.strip_prefix("data: ") {
                        json = serde_json::from_str(d).unwrap();
                    }
                }
                seen.push(event.to_string());
                if want(event, &json) {
                    return;
                }
            }
        }
    })
    .await;
    assert!(found.is_ok(), "not seen; saw {seen:?}");
    seen
}

#[tokio::test(start_paused = true)]
async fn the_stream_delivers_a_drive_change_after_a_command() {
    let (_gw, app) = app(true, false);
    settle(2).await;
    let r = app
        .clone()
        .oneshot(Request::get("/api/stream?drive=mixer-2").body(Body::empty()).unwrap())
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()[header::CONTENT_TYPE], "text/event-stream");
    let body = r.into_body();
    let c = call(&app, "POST", "/api/drives/mixer-2/run", Some(WRITE), None).await;
    assert_eq!(c.status, 200, "{}", c.json);
    let mut kinds = BTreeSet::new();
    let seen = read_stream(body, Duration::from_secs(30), |event, data| {
        assert_eq!(event, data["type"], "{data}");
        match event {
            "drive" => assert_eq!(data["id"], "mixer-2"),
            "bus" => assert_eq!(data["name"], "line-b800"),
            "event" => assert_eq!(data["drive"], "mixer-2"),
            other => panic!("unexpected {other}"),
        }
        kinds.insert(event.to_string());
        event == "drive" && data["running"] == true
    })
    .await;
    assert!(kinds.contains("event"), "the audited command is streamed too: {seen:?}");
}

#[tokio::test(start_paused = true)]
async fn a_slow_stream_client_is_told_it_lagged() {
    let (_gw, app) = app(true, false);
    let r = app.clone().oneshot(Request::get("/api/stream").body(Body::empty()).unwrap()).await.unwrap();
    // Nobody reads for a while: the gateway goes on (the buffer holds 1024 changes).
    settle(300).await;
    let mut skipped = 0;
    read_stream(r.into_body(), Duration::from_secs(5), |event, data| {
        if event == "lagged" {
            skipped = data["skipped"].as_u64().unwrap();
            return true;
        }
        false
    })
    .await;
    assert!(skipped > 0);
}

fn openapi() -> Value {
    serde_json::from_str(OPENAPI).expect("openapi.json is JSON")
}

#[tokio::test(start_paused = true)]
async fn the_openapi_document_describes_exactly_the_routes_served() {
    let doc = openapi();
    assert_eq!(doc["openapi"].as_str().unwrap().get(..3), Some("3.1"));
    let documented: BTreeMap<String, BTreeSet<String>> = doc["paths"]
        .as_object()
        .unwrap()
        .iter()
        .map(|(p, ops)| {
            let methods = ops
                .as_object()
                .unwrap()
                .keys()
                .filter(|k| {
                    ["get", "put", "post", "delete", "patch", "head", "options"].contains(&k.as_str())
                })
                .map(|k| k.to_uppercase())
                .collect();
            (p.clone(), methods)
        })
        .collect();
    let table: BTreeMap<String, BTreeSet<String>> = API_ROUTES
        .iter()
        .map(|(p, m)| {
            let p = p.split('/').map(|s| s.strip_prefix(':').map_or(s.to_string(), |v| format!("{{{v}}}")));
            (p.collect::<Vec<_>>().join("/"), m.iter().map(|m| m.to_string()).collect())
        })
        .collect();
    assert_eq!(documented, table, "openapi.json and the router's table differ");
    // The router serves exactly the table: each listed method is routed (401 without a token,
    // nothing reaches a drive), every other method is 405.
    let (_gw, app) = app(false, false);
    for (path, methods) in API_ROUTES {
        let uri = path.replace(":id", "mixer-1").replace(":name", "F-01").replace(":bus", "line-b800");
        for m in ["GET", "POST", "PUT", "DELETE", "PATCH"] {
            let req = Request::builder().method(Method::from_bytes(m.as_bytes()).unwrap()).uri(&uri);
            let r = app.clone().oneshot(req.body(Body::empty()).unwrap()).await.unwrap();
            let expect: u16 = match (methods.contains(&m), *path == "/api/openapi.json") {
                (true, true) => 200,
                (true, false) => 401,
                (false, _) => 405,
            };
            assert_eq!(r.status().as_u16(), expect, "{m} {uri}");
        }
    }
}

#[tokio::test(start_paused = true)]
async fn the_openapi_schemas_match_what_is_served() {
    let doc = openapi();
    let schema_keys = |name: &str| -> BTreeSet<String> {
        let s = &doc["components"]["schemas"][name];
        s["properties"].as_object().unwrap_or_else(|| panic!("schema {name}")).keys().cloned().collect()
    };
    let keys = |v: &Value| -> BTreeSet<String> { v.as_object().unwrap().keys().cloned().collect() };
    let (gw, app) = app(true, false);
    settle(2).await;
    let drive = call(&app, "GET", "/api/drives/pump-1", None, None).await.json;
    // `values` is left out for a drive without named values (a built-in family's); a templated
    // drive's is checked in tests/templates.rs.
    let mut drive_keys = schema_keys("DriveView");
    assert!(drive_keys.remove("values"), "the schema names the optional values");
    assert_eq!(drive_keys, keys(&drive));
    let bus = call(&app, "GET", "/api/buses", None, None).await.json[0].clone();
    assert_eq!(schema_keys("BusView"), keys(&bus));
    let param = call(&app, "GET", "/api/drives/ahu-1/params/4-14", None, None).await.json;
    assert_eq!(schema_keys("ParamReading"), keys(&param));
    let event = drivebus_store::Event {
        id: 1,
        time_ms: 0,
        kind: drivebus_store::EventKind::Command,
        bus: None,
        drive: None,
        actor: None,
        action: None,
        result: None,
        detail: json!({}),
    };
    assert_eq!(schema_keys("Event"), keys(&serde_json::to_value(&event).unwrap()));
    let point = drivebus_store::TrendPoint {
        time_ms: 0,
        output_hz: None,
        current_a: None,
        output_hz_min: None,
        output_hz_max: None,
        setpoint_hz: None,
        samples: 0,
    };
    assert_eq!(schema_keys("TrendPoint"), keys(&serde_json::to_value(&point).unwrap()));
    // Every error kind the API answers with is listed.
    let kinds: BTreeSet<&str> = doc["components"]["schemas"]["Error"]["properties"]["error"]["properties"]
        ["kind"]["enum"]
        .as_array()
        .unwrap()
        .iter()
        .map(|k| k.as_str().unwrap())
        .collect();
    for k in [
        "unknown_drive",
        "locked",
        "invalid",
        "refused",
        "unsupported",
        "no_answer",
        "link_down",
        "protocol",
        "unauthorized",
        "forbidden",
        "bad_json",
        "bad_request",
        "too_large",
        "not_found",
        "method_not_allowed",
        "no_store",
        "internal",
        "unknown_bus",
        "bad_backup",
        "not_scanned",
        "busy",
    ] {
        assert!(kinds.contains(k), "error kind {k} is not in openapi.json");
    }
    drop(gw);
}

/// A command is answered with the drive's state read after the drive confirmed it: a speed
/// answers its setpoint, a run answers running (the answer used to show the state before).
#[tokio::test(start_paused = true)]
async fn a_command_answers_with_the_state_that_shows_it() {
    let (_gw, app) = app(true, false);
    settle(2).await;
    for id in ["conveyor-1", "pump-1", "ahu-1", "mixer-1"] {
        let r = call(&app, "POST", &format!("/api/drives/{id}/run"), Some(WRITE), None).await;
        assert_eq!(r.status, 200, "{id}: {}", r.json);
        assert_eq!(r.json["drive"]["running"], true, "{id}: {}", r.json);
        let r =
            call(&app, "POST", &format!("/api/drives/{id}/speed"), Some(WRITE), Some(r#"{"hz": 40}"#)).await;
        assert_eq!(r.status, 200, "{id}: {}", r.json);
        assert_eq!(r.json["drive"]["setpoint_hz"], 40.0, "{id}: {}", r.json);
    }
}

/// A generic drive that is tripped refuses a run with a Modbus exception; the refusal says that
/// it is tripped and with what, from what the drive reports.
#[tokio::test(start_paused = true)]
async fn a_refusal_by_a_tripped_drive_says_it_is_tripped() {
    let (gw, app) = app(true, false);
    settle(2).await;
    let bus = gw.buses().iter().find(|b| b.config.name == "line-generic").unwrap().clone();
    {
        let mut line = bus.line.as_ref().unwrap().lock().unwrap();
        let port = (0..line.devices()).find(|&p| line.drive(p).is_some()).expect("a drive on the line");
        let d = line.drive_mut(port).expect("conveyor-1, the bus's first drive");
        d.core_mut().model.trip_now(drivebus_sim::model::Trip::OverCurrent);
    }
    let r = call(&app, "POST", "/api/drives/conveyor-1/run", Some(WRITE), None).await;
    let m = assert_error(&r, 409, "refused");
    assert!(m.contains("the drive is tripped (fault") && m.contains("reset it first"), "{m}");
}

/// Times a user gives are checked, never wrapped: the extremes of an i64 are answered, not a
/// panic (debug build) or a wrapped span.
#[tokio::test(start_paused = true)]
async fn trend_times_at_the_extremes_are_answered() {
    let (_gw, app) = app(true, true);
    settle(2).await;
    for q in [
        format!("until={}", i64::MIN),
        format!("since={}", i64::MIN),
        format!("since={}&until={}", i64::MIN, i64::MAX),
        format!("until={}", i64::MAX),
    ] {
        let r = call(&app, "GET", &format!("/api/drives/pump-1/trend?{q}"), None, None).await;
        assert!(r.status == 200 || r.status == 400, "{q}: {} {}", r.status, r.json);
    }
    let r = call(&app, "GET", &format!("/api/drives/pump-1/trend?since={}", i64::MIN), None, None).await;
    assert_eq!(r.status, 200, "{}", r.json);
}

/// Issue 13, defect 10: a key given twice is refused; long user values are cut in answers and
/// the audit trail; a speed of 1e308 is refused without 309 digits anywhere.
#[tokio::test(start_paused = true)]
async fn duplicate_keys_long_values_and_huge_numbers() {
    let (gw, app) = app(false, true);
    let r = call(&app, "POST", "/api/drives/pump-1/speed", Some(WRITE), Some(r#"{"hz":40,"hz":41}"#)).await;
    let m = assert_error(&r, 422, "invalid");
    assert!(m.starts_with("duplicate key \"hz\": give each key once"), "{m}");
    let r = call(
        &app,
        "PUT",
        "/api/drives/pump-1/params/0010",
        Some(WRITE),
        Some(r#"{"value":"5","value":"6"}"#),
    )
    .await;
    assert_error(&r, 422, "invalid");
    assert_eq!(
        gw.counters.commands_ok.load(std::sync::atomic::Ordering::Relaxed),
        0,
        "nothing reached a drive"
    );

    let r = call(&app, "POST", "/api/drives/pump-1/speed", Some(WRITE), Some(r#"{"hz": 1e308}"#)).await;
    let m = assert_error(&r, 422, "invalid");
    assert!(m.contains("1e308") && m.len() < 200, "{m}");
    let audited = gw.store().unwrap().events(&drivebus_store::EventFilter::default()).unwrap();
    let speed =
        audited.iter().rev().find(|e| e.action.as_deref().is_some_and(|a| a.starts_with("speed "))).unwrap();
    assert_eq!(speed.action.as_deref(), Some("speed 1e308 Hz"));
    assert!(speed.result.as_deref().unwrap().len() < 200, "{speed:?}");

    // A long value (this test's max_body is 1 KiB; the same cut holds for 60 KB).
    let long = "9".repeat(900);
    let r = call(
        &app,
        "PUT",
        "/api/drives/pump-1/params/0010",
        Some(WRITE),
        Some(&format!(r#"{{"value":"{long}"}}"#)),
    )
    .await;
    let m = assert_error(&r, 422, "invalid");
    assert!(m.contains("…(900 bytes)") && m.len() < 600, "{} bytes: {m}", m.len());
    let r = call(&app, "GET", &format!("/api/drives/{long}"), Some(READ), None).await;
    let m = assert_error(&r, 404, "unknown_drive");
    assert!(m.len() < 200, "{m}");
}

/// Issue 13, defect 10: failed logins are audited once per address and minute with their count,
/// and after ten in a minute the address's requests with a token get 429, the right token too,
/// until the minute is over.
#[tokio::test(start_paused = true)]
async fn failed_logins_are_audited_and_rate_limited_per_address() {
    let (gw, app) = app(false, true);
    for _ in 0..10 {
        assert_error(
            &call(&app, "GET", "/api/drives", Some("guess-0123456789abcdef"), None).await,
            401,
            "unauthorized",
        );
    }
    let r = call(&app, "GET", "/api/drives", Some(READ), None).await;
    let m = assert_error(&r, 429, "too_many_failures");
    assert!(m.contains("127.0.0.7"), "{m}");
    // Another address is not concerned.
    let other = router(gw.clone()).layer(MockConnectInfo(SocketAddr::from(([127, 0, 0, 8], 40000))));
    assert_eq!(call(&other, "GET", "/api/drives", Some(READ), None).await.status, 200);
    let logins = || {
        let events = gw.store().unwrap().events(&drivebus_store::EventFilter::default()).unwrap();
        events.into_iter().filter(|e| e.action.as_deref() == Some("login")).collect::<Vec<_>>()
    };
    assert_eq!(logins().len(), 1, "{:?}", logins());
    assert_eq!(logins()[0].actor.as_deref(), Some("http:127.0.0.7"));
    assert_eq!(logins()[0].result.as_deref(), Some("unauthorized: unknown token"));
    settle(61).await;
    let l = logins();
    assert_eq!(l.len(), 2, "{l:?}");
    assert!(
        l[1].result.as_deref().unwrap().starts_with("9 refused from http:127.0.0.7 in the last 60 s"),
        "{l:?}"
    );
    // The minute is over: the right token works again.
    assert_eq!(call(&app, "GET", "/api/drives", Some(READ), None).await.status, 200);
}

/// Issue 13, defect 10: with anonymous reads, a Host that is not one of the gateway's names
/// (DNS rebinding) gets 421; addresses, localhost and `[http] hosts` are served.
#[tokio::test(start_paused = true)]
async fn with_anonymous_reads_the_host_must_be_a_name_of_the_gateway() {
    let get = |app: &Router, host: &str| {
        let req = Request::get("/api/drives").header(header::HOST, host).body(Body::empty()).unwrap();
        app.clone().oneshot(req)
    };
    let mut c = config(true);
    c.http.hosts = vec!["scada.plant.local".into()];
    let gw = Gateway::start(c, None).unwrap();
    let named = app_with(&gw);
    for ok in ["scada.plant.local:8080", "localhost:8080", "127.0.0.1:8080", "[::1]:8080", "10.0.0.5"] {
        assert_eq!(get(&named, ok).await.unwrap().status(), 200, "{ok}");
    }
    let r = get(&named, "evil.example:8080").await.unwrap();
    assert_eq!(r.status(), 421);
    let body: Value = serde_json::from_slice(&r.into_body().collect().await.unwrap().to_bytes()).unwrap();
    assert_eq!(body["error"]["kind"], "bad_host", "{body}");
    // With tokens required, a foreign page has no token: nothing to check.
    let (_gw, app) = app(false, false);
    let req = Request::get("/api/drives")
        .header(header::HOST, "evil.example")
        .header(header::AUTHORIZATION, format!("Bearer {READ}"))
        .body(Body::empty())
        .unwrap();
    assert_eq!(app.clone().oneshot(req).await.unwrap().status(), 200);
    assert!(GatewayConfig::from_toml("t.toml", "[http]\nhosts = [\"http://x:80\"]\n").is_err());
}

/// A text response (the backup file): its status, headers and body.
async fn call_text(
    app: &Router,
    method: &str,
    path: &str,
    token: Option<&str>,
    body: Option<&str>,
) -> (StatusCode, axum::http::HeaderMap, String) {
    let mut req = Request::builder().method(method).uri(path);
    if let Some(t) = token {
        req = req.header(header::AUTHORIZATION, format!("Bearer {t}"));
    }
    let req = req.body(body.map_or_else(Body::empty, |b| Body::from(b.to_string()))).unwrap();
    let r = app.clone().oneshot(req).await.unwrap();
    let (status, headers) = (r.status(), r.headers().clone());
    let bytes = r.into_body().collect().await.unwrap().to_bytes();
    (status, headers, String::from_utf8(bytes.to_vec()).unwrap())
}

/// The demo gateway with room for a backup file in a request body.
fn workbench_app(anonymous_read: bool) -> (Arc<Gateway>, Router) {
    let mut c = config(anonymous_read);
    c.http.max_body = 64 * 1024;
    let dir = std::env::temp_dir().join(format!(
        "drivebus-http-workbench-{}-{}",
        std::process::id(),
        rand_suffix()
    ));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let store = drivebus_store::Store::open(&dir.join("events.db")).unwrap();
    let gw = Gateway::start(c, Some(store)).unwrap();
    let app = app_with(&gw);
    (gw, app)
}

fn rand_suffix() -> u32 {
    static N: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
    N.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
}

/// Writes 42.5 Hz to P0.02 of fan-1 (and its EEPROM) as the write token; asserts it was taken.
async fn write_fan_1_p0_02_42_5(app: &Router) {
    let body = r#"{"value": "42.5", "eeprom": true}"#;
    let r = call(app, "PUT", "/api/drives/fan-1/params/P0.02", Some(WRITE), Some(body)).await;
    assert_eq!(r.status, 200, "{}", r.json);
}

#[tokio::test(start_paused = true)]
async fn the_parameter_list_gives_every_parameter_with_its_catalog_data_and_value() {
    let (_gw, app) = app(false, false);
    settle(2).await;
    let catalog = drivebus_drive::Catalog::load(drivebus_drive::Family::Generic).unwrap();
    let r = call(&app, "GET", "/api/drives/fan-1/params", Some(READ), None).await;
    assert_eq!(r.status, 200, "{}", r.json);
    let rows = r.json.as_array().unwrap();
    assert_eq!(rows.len(), catalog.len());
    let p = rows.iter().find(|p| p["name"] == "P0.02").expect("P0.02");
    assert_eq!(p["group"], "P0 basic functions");
    assert_eq!(p["unit"], "Hz");
    assert_eq!(
        (p["min"].as_f64(), p["max"].as_f64(), p["default"].as_f64()),
        (Some(0.0), Some(400.0), Some(50.0))
    );
    assert_eq!(p["access"], "read-write");
    assert_eq!(p["value"], 50.0, "{p}");
    assert_eq!(p["differs"], false);
    let monitor = rows.iter().find(|p| p["access"] == "read-only").expect("a read-only parameter");
    assert!(monitor["raw"].is_i64() || monitor["error"].is_object(), "{monitor}");
    // A value changed: read again (not a value from before the write), marked as differing.
    write_fan_1_p0_02_42_5(&app).await;
    let group = "/api/drives/fan-1/params?group=P0%20basic%20functions";
    let r = call(&app, "GET", group, Some(READ), None).await;
    assert_eq!(r.status, 200, "{}", r.json);
    let rows = r.json.as_array().unwrap();
    assert!(!rows.is_empty() && rows.iter().all(|p| p["group"] == "P0 basic functions"), "{}", r.json);
    let p = rows.iter().find(|p| p["name"] == "P0.02").unwrap();
    assert_eq!((p["value"].as_f64(), &p["differs"]), (Some(42.5), &json!(true)), "{p}");
    // Without reading: the catalog only.
    let r = call(&app, "GET", "/api/drives/fan-1/params?read=false", Some(READ), None).await;
    assert!(r.json.as_array().unwrap().iter().all(|p| p["value"].is_null()), "{}", r.json);
    // A protocol without parameter access says so on each row.
    let r = call(&app, "GET", "/api/drives/mixer-1/params", Some(READ), None).await;
    assert_eq!(r.status, 200, "{}", r.json);
    assert!(r.json.as_array().unwrap().iter().all(|p| p["error"]["kind"] == "unsupported"), "{}", r.json);
    // Refusals.
    assert_error(&call(&app, "GET", "/api/drives/fan-1/params", None, None).await, 401, "unauthorized");
    assert_error(
        &call(&app, "GET", "/api/drives/fan-9/params", Some(READ), None).await,
        404,
        "unknown_drive",
    );
    let m = assert_error(
        &call(&app, "GET", "/api/drives/fan-1/params?group=P9", Some(READ), None).await,
        422,
        "invalid",
    );
    assert!(m.contains("P0 basic functions"), "{m}");
    assert_error(
        &call(&app, "GET", "/api/drives/fan-1/params?read=maybe", Some(READ), None).await,
        400,
        "bad_request",
    );
}

#[tokio::test(start_paused = true)]
async fn backup_then_restore_shows_and_undoes_exactly_the_change() {
    let (gw, app) = workbench_app(false);
    settle(2).await;
    let (status, headers, file) = call_text(&app, "GET", "/api/drives/fan-1/backup", Some(READ), None).await;
    assert_eq!(status, 200, "{file}");
    assert_eq!(headers[header::CONTENT_DISPOSITION], "attachment; filename=\"fan-1.json\"");
    // The file `drivebus params backup` writes: the library's one writer, read back the same.
    let backup = drivebus_drive::backup::Backup::parse(&file).unwrap();
    assert_eq!(backup.to_text(), file);
    assert_eq!((backup.family.as_str(), backup.address), ("generic", Some(3)));
    let catalog = drivebus_drive::Catalog::load(drivebus_drive::Family::Generic).unwrap();
    let settings = catalog.iter().filter(|p| drivebus_drive::backup::is_setting(p)).count();
    assert_eq!(backup.params.len(), settings);
    assert_eq!(backup.params["P0.02"].raw, 5000);

    write_fan_1_p0_02_42_5(&app).await;
    // The diff: exactly P0.02, and nothing is written.
    let dry = "/api/drives/fan-1/restore?dry_run=true";
    let r = call(&app, "POST", dry, Some(WRITE), Some(&file)).await;
    assert_eq!(r.status, 200, "{}", r.json);
    assert_eq!(r.json["rows"].as_array().unwrap().len(), 1, "{}", r.json);
    let row = &r.json["rows"][0];
    assert_eq!(row["name"], "P0.02");
    assert_eq!(row["drive"], json!({"raw": 4250, "value": "42.50 Hz"}));
    assert_eq!(row["file"], json!({"raw": 5000, "value": "50.00 Hz"}));
    assert_eq!((&row["apply"], &row["result"]), (&json!(true), &Value::Null));
    let r = call(&app, "GET", "/api/drives/fan-1/params/P0.02", Some(READ), None).await;
    assert_eq!(r.json["value"], 42.5, "a dry run writes nothing");

    // Restored: the row's result, the command audited, and no difference left.
    let r = call(&app, "POST", "/api/drives/fan-1/restore", Some(WRITE), Some(&file)).await;
    assert_eq!(r.status, 200, "{}", r.json);
    assert_eq!((&r.json["applied"], &r.json["failed"]), (&json!(1), &json!(0)), "{}", r.json);
    assert_eq!(r.json["rows"][0]["result"], "ok");
    let r = call(&app, "POST", dry, Some(WRITE), Some(&file)).await;
    assert_eq!(r.json["rows"], json!([]), "{}", r.json);
    let events = call(&app, "GET", "/api/events?kind=command&drive=fan-1", Some(READ), None).await.json;
    let actions: Vec<&str> = events.as_array().unwrap().iter().filter_map(|e| e["action"].as_str()).collect();
    assert!(actions.contains(&"param P0.02 = 50.00 Hz (eeprom)"), "{actions:?}");
    drop(gw);
}

#[tokio::test(start_paused = true)]
async fn a_restore_leaves_comm_settings_out_unless_asked_and_applies_only_what_is_named() {
    let (_gw, app) = workbench_app(false);
    settle(2).await;
    let (_, _, file) = call_text(&app, "GET", "/api/drives/fan-1/backup", Some(READ), None).await;
    let mut b = drivebus_drive::backup::Backup::parse(&file).unwrap();
    b.params.get_mut("P3.11").unwrap().raw = 9; // its bus address
    b.params.get_mut("P0.02").unwrap().raw = 3000;
    b.params.get_mut("P0.03").unwrap().raw += 1;
    let file = b.to_text();
    let names = |r: &Reply, key: &str| -> Vec<String> {
        r.json["rows"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|x| x[key] == true)
            .map(|x| x["name"].as_str().unwrap().to_string())
            .collect()
    };
    let r = call(&app, "POST", "/api/drives/fan-1/restore?dry_run=true", Some(WRITE), Some(&file)).await;
    assert_eq!(r.status, 200, "{}", r.json);
    assert_eq!(names(&r, "comm"), ["P3.11"]);
    assert_eq!(names(&r, "apply"), ["P0.02", "P0.03"]);
    let r = call(
        &app,
        "POST",
        "/api/drives/fan-1/restore?dry_run=true&include_comm=true",
        Some(WRITE),
        Some(&file),
    )
    .await;
    assert_eq!(names(&r, "apply"), ["P0.02", "P0.03", "P3.11"]);
    let r = call(&app, "POST", "/api/drives/fan-1/restore?only=p0.02", Some(WRITE), Some(&file)).await;
    assert_eq!(r.status, 200, "{}", r.json);
    assert_eq!(r.json["applied"], 1, "{}", r.json);
    let r = call(&app, "GET", "/api/drives/fan-1/params/P0.02", Some(READ), None).await;
    assert_eq!(r.json["value"], 30.0);
    let r = call(&app, "GET", "/api/drives/fan-1/params/P3.11", Some(READ), None).await;
    assert_eq!(r.json["raw"], 3, "the bus address stays");
}

#[tokio::test(start_paused = true)]
async fn restore_refusals_are_one_line_and_write_nothing() {
    let (gw, app) = workbench_app(false);
    settle(2).await;
    let (_, _, file) = call_text(&app, "GET", "/api/drives/fan-1/backup", Some(READ), None).await;
    let url = "/api/drives/fan-1/restore";
    assert_error(&call(&app, "POST", url, None, Some(&file)).await, 401, "unauthorized");
    assert_error(&call(&app, "POST", url, Some(READ), Some(&file)).await, 403, "forbidden");
    assert_error(
        &call(&app, "POST", "/api/drives/fan-9/restore", Some(WRITE), Some(&file)).await,
        404,
        "unknown_drive",
    );
    for bad in [
        "{",
        "not json at all",
        r#"{"family": "generic"}"#,
        r#"{"family": "generic", "params": {"P0.02": {"raw": "x"}}}"#,
    ] {
        let m = assert_error(&call(&app, "POST", url, Some(WRITE), Some(bad)).await, 400, "bad_backup");
        assert!(m.starts_with("not a drivebus backup"), "{m}");
    }
    let toshiba = call_text(&app, "GET", "/api/drives/pump-1/backup", Some(READ), None).await.2;
    let m = assert_error(&call(&app, "POST", url, Some(WRITE), Some(&toshiba)).await, 422, "invalid");
    assert!(m.contains("toshiba parameters; this is a generic drive"), "{m}");
    let m = assert_error(
        &call(&app, "POST", &format!("{url}?only=P0.02,P9.99"), Some(WRITE), Some(&file)).await,
        422,
        "invalid",
    );
    assert!(m.contains("P9.99"), "{m}");
    assert_error(
        &call(&app, "POST", &format!("{url}?dry_run=perhaps"), Some(WRITE), Some(&file)).await,
        400,
        "bad_request",
    );
    assert_error(
        &call(&app, "GET", "/api/drives/mixer-1/backup", Some(READ), None).await,
        422,
        "unsupported",
    );
    assert_eq!(gw.counters.commands_ok.load(std::sync::atomic::Ordering::Relaxed), 0);
}

/// A drive that refuses a row says why, in that row; the other rows are still applied.
#[tokio::test(start_paused = true)]
async fn a_row_the_drive_refuses_carries_its_reason() {
    let (_gw, app) = workbench_app(false);
    settle(2).await;
    let (_, _, file) = call_text(&app, "GET", "/api/drives/fan-1/backup", Some(READ), None).await;
    let mut b = drivebus_drive::backup::Backup::parse(&file).unwrap();
    b.params.get_mut("P0.04").unwrap().raw = 6000; // maximum frequency: not while running
    b.params.get_mut("P0.03").unwrap().raw += 1;
    let r = call(&app, "POST", "/api/drives/fan-1/run", Some(WRITE), None).await;
    assert_eq!(r.status, 200, "{}", r.json);
    settle(1).await;
    let r = call(&app, "POST", "/api/drives/fan-1/restore", Some(WRITE), Some(&b.to_text())).await;
    assert_eq!(r.status, 200, "{}", r.json);
    let rows = r.json["rows"].as_array().unwrap();
    let refused = rows.iter().find(|x| x["name"] == "P0.04").unwrap();
    assert_eq!(refused["result"], "failed", "{}", r.json);
    assert_eq!(refused["error"]["kind"], "refused", "{}", r.json);
    assert!(
        refused["error"]["message"].as_str().unwrap().starts_with("the drive refused: code"),
        "{}",
        r.json
    );
    assert_eq!(rows.iter().find(|x| x["name"] == "P0.03").unwrap()["result"], "ok");
    assert_eq!((&r.json["applied"], &r.json["failed"]), (&json!(1), &json!(1)));
    // The single-parameter write says the same.
    let r = call(
        &app,
        "PUT",
        "/api/drives/fan-1/params/P0.04",
        Some(WRITE),
        Some(r#"{"value": "60", "eeprom": true}"#),
    )
    .await;
    let m = assert_error(&r, 409, "refused");
    assert!(m.starts_with("the drive refused: code"), "{m}");
}

#[tokio::test(start_paused = true)]
async fn trips_give_the_drives_history_and_the_gateways_trip_events() {
    let (gw, app) = workbench_app(false);
    settle(2).await;
    let r = call(&app, "GET", "/api/drives/conveyor-1/trips", Some(READ), None).await;
    assert_eq!(r.status, 200, "{}", r.json);
    assert_eq!((&r.json["family"], &r.json["address"]), (&json!("generic"), &json!(1)));
    assert!(r.json["source"].as_str().unwrap().contains("P4.00"), "{}", r.json);
    assert_eq!((&r.json["current"], &r.json["events"]), (&Value::Null, &json!([])), "{}", r.json);
    let bus = gw.buses().iter().find(|b| b.config.name == "line-generic").unwrap().clone();
    let r = call(&app, "POST", "/api/drives/conveyor-1/run", Some(WRITE), None).await;
    assert_eq!(r.status, 200);
    settle(3).await;
    {
        let mut line = bus.line.as_ref().unwrap().lock().unwrap();
        let port = (0..line.devices()).find(|&p| line.drive(p).is_some()).unwrap();
        line.drive_mut(port).unwrap().core_mut().model.trip_now(drivebus_sim::model::Trip::OverCurrent);
    }
    settle(2).await;
    let r = call(&app, "GET", "/api/drives/conveyor-1/trips", Some(READ), None).await;
    assert_eq!(r.status, 200, "{}", r.json);
    assert!(r.json["current"]["code"].is_u64(), "{}", r.json);
    assert!(!r.json["history"].as_array().unwrap().is_empty(), "{}", r.json);
    let events = r.json["events"].as_array().unwrap();
    assert_eq!(events.len(), 1, "{}", r.json);
    assert_eq!(events[0]["kind"], "trip");
    assert_eq!(events[0]["detail"]["before"]["running"], true, "the pre-trip snapshot: {}", r.json);
    assert_error(&call(&app, "GET", "/api/drives/conveyor-1/trips", None, None).await, 401, "unauthorized");
    assert_error(&call(&app, "GET", "/api/drives/nope/trips", Some(READ), None).await, 404, "unknown_drive");
}

#[tokio::test(start_paused = true)]
async fn a_bus_scan_finds_the_drives_while_polling_goes_on() {
    let (gw, app) = app(false, false);
    settle(2).await;
    let url = "/api/buses/line-generic/scan";
    assert_error(&call(&app, "GET", url, Some(READ), None).await, 404, "not_scanned");
    assert_error(&call(&app, "POST", url, None, None).await, 401, "unauthorized");
    assert_error(&call(&app, "POST", url, Some(READ), None).await, 403, "forbidden");
    assert_error(&call(&app, "POST", "/api/buses/line-9/scan", Some(WRITE), None).await, 404, "unknown_bus");
    assert_error(
        &call(&app, "POST", &format!("{url}?addresses=1-300"), Some(WRITE), None).await,
        400,
        "bad_request",
    );
    let r = call(&app, "POST", &format!("{url}?addresses=1-6"), Some(WRITE), None).await;
    assert_eq!(r.status, 202, "{}", r.json);
    // The built-in families, then the shipped template kinds speaking Modbus RTU.
    assert_eq!(
        (&r.json["running"], &r.json["families"]),
        (
            &json!(true),
            &json!([
                "generic",
                "toshiba",
                "generic-2000h",
                "abb-acs550",
                "siemens-v20",
                "danfoss-fc51",
                "invertek-optidrive-e3"
            ])
        )
    );
    assert_error(&call(&app, "POST", url, Some(WRITE), None).await, 429, "busy");
    // conveyor-1 is polled every 250 ms: while the scan runs, a poll at least every 4 of those.
    let conveyor = gw.drive("conveyor-1").unwrap();
    let (mut polls, mut last, mut worst) =
        (conveyor.state().polls, tokio::time::Instant::now(), Duration::ZERO);
    let report = loop {
        tokio::time::sleep(Duration::from_millis(10)).await;
        let now = tokio::time::Instant::now();
        let p = conveyor.state().polls;
        if p != polls {
            (polls, last) = (p, now);
        }
        worst = worst.max(now - last);
        let r = call(&app, "GET", url, Some(READ), None).await;
        if r.json["running"] == false {
            break r.json;
        }
        assert!(now.elapsed() < Duration::from_secs(600), "the scan never ended: {}", r.json);
    };
    assert!(worst <= Duration::from_millis(1000), "conveyor-1 went {worst:?} without a poll");
    assert_eq!(report["tried"], report["total"], "{report}");
    let found = scan_found(&report);
    assert_eq!(
        found,
        [(1, "generic", "conveyor-1"), (2, "generic", "conveyor-2"), (3, "generic", "fan-1")],
        "{report}"
    );
    let config = report["config"].as_str().unwrap();
    assert!(config.contains("# already configured on line-generic as fan-1:\n# [[bus.drive]]\n"), "{config}");
    assert!(report["found"][0]["model"].as_str().unwrap().contains("generic"), "{report}");
}

/// A drive with its own map (status at 100.., command at 200), speaking Modbus ASCII so that no
/// other test's bus (the demo's line-generic speaks RTU) sees its kind.
const SCAN_KIND: &str = r#"kind = "http-scan-bits"
maker = "Test"
model = "S1"
source = "written for this test"
protocols = ["modbus-ascii"]
[serial]
baud = 19200
format = "7E1"
[status]
running = { register = 100, bit = 0 }
output_hz = { register = 101, scale = 0.1 }
current_a = { register = 102, scale = 0.01 }
fault = { register = 103 }
[command]
register = 200
run = { bit = 0 }
reset = { bit = 7 }
[setpoint]
register = 201
full_scale = 0x4000
max_hz = 60.0
"#;

#[tokio::test(start_paused = true)]
async fn a_bus_scan_also_tries_the_template_kinds_the_gateway_knows() {
    let dir =
        std::env::temp_dir().join(format!("drivebus-http-scan-{}-{}", std::process::id(), rand_suffix()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("bits.toml"), SCAN_KIND).unwrap();
    let path = dir.join("plant.toml");
    let text = "templates = [\"bits.toml\"]\n[[bus]]\nname = \"a\"\nport = \"virtual\"\nprotocol = \"modbus-ascii\"\n\
         [[bus.drive]]\nname = \"fan\"\nfamily = \"http-scan-bits\"\naddress = 1\npoll_ms = 500\n\
         [[bus.drive]]\nname = \"pump\"\nfamily = \"generic\"\naddress = 2\npoll_ms = 500\n";
    let mut c = GatewayConfig::from_toml(&path.display().to_string(), text).unwrap_or_else(|e| panic!("{e}"));
    c.store = None;
    c.tokens = vec![Token { name: "writer".into(), secret: WRITE.into(), role: Role::Write }];
    let gw = Gateway::start(c, None).unwrap();
    let app = app_with(&gw);
    settle(2).await;
    let url = "/api/buses/a/scan";
    let r = call(&app, "POST", &format!("{url}?addresses=1-3"), Some(WRITE), None).await;
    assert_eq!(r.status, 202, "{}", r.json);
    let families: Vec<&str> =
        r.json["families"].as_array().unwrap().iter().map(|f| f.as_str().unwrap()).collect();
    // The built-in family speaking Modbus ASCII, then the shipped kind, then the configured one.
    assert_eq!(families, ["generic", "generic-2000h", "http-scan-bits"], "{}", r.json);
    let start = tokio::time::Instant::now();
    let report = loop {
        tokio::time::sleep(Duration::from_millis(50)).await;
        let r = call(&app, "GET", url, Some(WRITE), None).await;
        if r.json["running"] == false {
            break r.json;
        }
        assert!(start.elapsed() < Duration::from_secs(600), "the scan never ended: {}", r.json);
    };
    let found = scan_found(&report);
    // The templated drive is found by its kind; the generic one still by the built-in family
    // (the shipped generic-2000h kind, which reads the same map, is not reached there).
    assert_eq!(found, [(1, "http-scan-bits", "fan"), (2, "generic", "pump")], "{report}");
    assert_eq!(report["found"][0]["model"], "Test S1", "{report}");
    assert!(report["config"].as_str().unwrap().contains("# family = \"http-scan-bits\"\n"), "{report}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test(start_paused = true)]
async fn the_openapi_schemas_of_the_workbench_match_what_is_served() {
    let doc = openapi();
    let schema_keys = |name: &str| -> BTreeSet<String> {
        doc["components"]["schemas"][name]["properties"].as_object().unwrap().keys().cloned().collect()
    };
    let keys = |v: &Value| -> BTreeSet<String> { v.as_object().unwrap().keys().cloned().collect() };
    let (_gw, app) = workbench_app(true);
    settle(2).await;
    let rows =
        call(&app, "GET", "/api/drives/fan-1/params?group=P0%20basic%20functions", None, None).await.json;
    assert_eq!(schema_keys("ParamRow"), keys(&rows[0]));
    let (_, _, file) = call_text(&app, "GET", "/api/drives/fan-1/backup", None, None).await;
    assert_eq!(schema_keys("Backup"), keys(&serde_json::from_str(&file).unwrap()));
    let mut b = drivebus_drive::backup::Backup::parse(&file).unwrap();
    b.params.get_mut("P0.03").unwrap().raw += 1;
    let r = call(&app, "POST", "/api/drives/fan-1/restore", Some(WRITE), Some(&b.to_text())).await.json;
    assert_eq!(schema_keys("RestoreResult"), keys(&r));
    assert_eq!(schema_keys("RestoreRow"), keys(&r["rows"][0]));
    let trips = call(&app, "GET", "/api/drives/fan-1/trips", None, None).await.json;
    assert_eq!(schema_keys("Trips"), keys(&trips));
    let scan = call(&app, "POST", "/api/buses/line-generic/scan?addresses=3", Some(WRITE), None).await.json;
    assert_eq!(schema_keys("ScanReport"), keys(&scan));
}

/// `config` with every bus a standby that takes its line only after `silence` twice.
fn standby(mut c: GatewayConfig, silence: Duration) -> GatewayConfig {
    for b in &mut c.buses {
        b.role = Some(drivebus_link::role::RoleConfig { standby: true, silence });
    }
    c
}

#[tokio::test(start_paused = true)]
async fn a_standby_marks_its_values_and_refuses_commands_audited_once_per_window() {
    // A line nobody else masters: the standby listens for twice 60 s before it takes it.
    let gw = Gateway::start(standby(config(true), Duration::from_secs(60)), None).unwrap();
    let app = app_with(&gw);
    let mut rx = gw.subscribe();
    settle(3).await;
    assert!(!*gw.mastering().borrow(), "a standby on every bus masters none");
    let r = call(&app, "GET", "/api/buses", None, None).await;
    assert!(r.json.as_array().unwrap().iter().all(|b| b["role"] == "standby"), "{}", r.json);
    let r = call(&app, "GET", "/api/drives", None, None).await;
    assert!(r.json.as_array().unwrap().iter().all(|d| d["source"] == "standby"), "{}", r.json);

    for _ in 0..3 {
        let r = call(&app, "POST", "/api/drives/pump-1/run", Some(WRITE), None).await;
        let message = assert_error(&r, 503, "standby");
        assert!(message.contains("another gateway masters the line"), "{message}");
    }
    settle(1).await;
    // The first refusal audited at once, the repeats counted (crate::refusals), never a
    // command record per attempt.
    let audited = |rx: &mut tokio::sync::broadcast::Receiver<Change>| {
        let mut seen = Vec::new();
        while let Ok(c) = rx.try_recv() {
            if let Change::Event(e) = c {
                if e.kind == drivebus_store::EventKind::Command && e.drive.as_deref() == Some("pump-1") {
                    seen.push(e);
                }
            }
        }
        seen
    };
    let first = audited(&mut rx);
    assert_eq!(first.len(), 1, "{first:?}");
    assert!(first[0].result.as_deref().unwrap().starts_with("standby: "), "{first:?}");
    assert_eq!(first[0].actor.as_deref(), Some("http:writer@127.0.0.7"));
    settle(61).await;
    let window = audited(&mut rx);
    assert_eq!(window.len(), 1, "{window:?}");
    assert_eq!(window[0].detail["repeated"], 2, "{window:?}");
    assert_eq!(window[0].detail["reason"], "standby", "{window:?}");
}

#[tokio::test(start_paused = true)]
async fn a_standby_that_takes_its_silent_lines_serves_as_master() {
    let gw = Gateway::start(standby(config(true), Duration::from_millis(500)), None).unwrap();
    let app = app_with(&gw);
    let mut mastering = gw.mastering();
    assert!(!*mastering.borrow_and_update());
    tokio::time::timeout(Duration::from_secs(10), mastering.changed()).await.unwrap().unwrap();
    assert!(*mastering.borrow(), "the first bus taken");
    settle(3).await;
    let r = call(&app, "GET", "/api/drives", None, None).await;
    assert!(r.json.as_array().unwrap().iter().all(|d| d["source"] == "master"), "{}", r.json);
    let r = call(&app, "POST", "/api/drives/pump-1/run", Some(WRITE), None).await;
    assert_eq!(r.status, 200, "{}", r.json);
}

/// A scan report's findings: (address, family, the configured drive's name or "").
fn scan_found(report: &Value) -> Vec<(u64, &str, &str)> {
    report["found"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| {
            (
                f["address"].as_u64().unwrap(),
                f["family"].as_str().unwrap(),
                f["configured"].as_str().unwrap_or(""),
            )
        })
        .collect()
}
