//! A command whose audit record cannot be committed (the store's disk is full) is refused
//! before it reaches the drive: HTTP 503 `not_recorded`, Modbus exception 04, OPC UA
//! Bad_ResourceUnavailable; counted in the metrics. The store is filled for real: capped at
//! the pages it has (SQLite's max_page_count), then written until a write fails as on a full
//! disk.
//!
//! Real time; waits poll with generous deadlines.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use axum::body::Body;
use axum::extract::connect_info::MockConnectInfo;
use axum::http::{header, Request};
use drivebus_gateway::config::{Role, Token};
use drivebus_gateway::core::{Command, CommandError, Gateway};
use drivebus_gateway::GatewayConfig;
use drivebus_store::{Event, EventFilter, EventKind, Store};
use http_body_util::BodyExt;
use serde_json::json;
use tower::ServiceExt;

const PATIENCE: Duration = Duration::from_secs(60);
const TOKEN: &str = "write-token-0123456789abcdef";

fn store() -> Store {
    let dir = std::env::temp_dir().join(format!("drivebus-store-full-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    Store::open(&dir.join("events.db")).unwrap()
}

/// The simulated drive's own setpoint, Hz (what it was told, not what the gateway thinks).
fn drive_setpoint(gw: &Gateway) -> f64 {
    let bus = gw.buses()[0].clone();
    let mut line = bus.line.as_ref().expect("a virtual bus").lock().unwrap();
    let ports = line.devices() + 1;
    (0..ports).find_map(|p| line.drive(p).map(|d| d.core().model.setpoint_hz())).expect("drive 1")
}

async fn eventually(what: &str, mut ok: impl FnMut() -> bool) {
    let end = tokio::time::Instant::now() + PATIENCE;
    while !ok() {
        assert!(tokio::time::Instant::now() < end, "{what}: not within {PATIENCE:?}");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

#[tokio::test]
async fn a_command_whose_audit_record_cannot_be_committed_never_reaches_the_drive() {
    let text = "[[bus]]\nname = \"line-1\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 38400\n\
                [[bus.drive]]\nname = \"d1\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 100\n";
    let mut config = GatewayConfig::from_toml("plant.toml", text).unwrap();
    config.tokens = vec![Token { name: "ops".into(), secret: TOKEN.into(), role: Role::Write }];
    let store = store();
    let gw = Gateway::start(config, Some(store.clone())).unwrap();

    // While the store takes records, a command is recorded before it is sent, then its result.
    gw.command("d1", Command::Speed(20.0), "test").await.unwrap();
    eventually("the drive takes 20 Hz", || drive_setpoint(&gw) == 20.0).await;
    let filter = EventFilter { kind: Some(EventKind::Command), ..Default::default() };
    let trail = store.events(&filter).unwrap();
    assert_eq!(trail.len(), 1, "{trail:?}");
    assert_eq!(trail[0].result.as_deref(), Some("ok"));

    // The disk fills up: the file may not grow, and what is left of its pages is written full.
    store.set_max_pages(1).unwrap();
    for size in [2000, 200, 20, 0] {
        let filler =
            Event { detail: json!({ "filler": "x".repeat(size) }), ..Event::new(0, EventKind::Started) };
        let full = (0..100_000).any(|_| store.record(&filler).is_err());
        assert!(full, "the store never filled up with {size}-byte events");
    }

    // A command now is refused, and the drive never sees it.
    let e = gw.command("d1", Command::Speed(40.0), "test").await.unwrap_err();
    assert!(matches!(e, CommandError::NotRecorded(_)), "{e}");
    assert!(e.to_string().contains("not sent"), "{e}");
    assert_eq!(drivebus_gateway::modbus_tcp::exception_of(&e).0, 0x04);
    assert_eq!(
        drivebus_gateway::opcua::manager::status_of(&e),
        opcua::types::StatusCode::BadResourceUnavailable
    );
    // Over HTTP: 503 not_recorded.
    let app = drivebus_gateway::http::router(gw.clone())
        .layer(MockConnectInfo(SocketAddr::from(([127, 0, 0, 1], 1))));
    let req = Request::post("/api/drives/d1/speed")
        .header(header::AUTHORIZATION, format!("Bearer {TOKEN}"))
        .header(header::CONTENT_TYPE, "application/json")
        .body(Body::from(r#"{"hz": 45}"#))
        .unwrap();
    let r = app.oneshot(req).await.unwrap();
    let status = r.status().as_u16();
    let body: serde_json::Value =
        serde_json::from_slice(&r.into_body().collect().await.unwrap().to_bytes()).unwrap();
    assert_eq!(status, 503, "{body}");
    assert_eq!(body["error"]["kind"], "not_recorded", "{body}");

    // A few polls later the drive still runs to the 20 Hz it was given.
    let polls = gw.drive_view(&gw.drive("d1").unwrap()).polls;
    eventually("three more polls", || gw.drive_view(&gw.drive("d1").unwrap()).polls >= polls + 3).await;
    assert_eq!(drive_setpoint(&gw), 20.0, "the refused commands reached the drive");
    assert_eq!(gw.counters.commands_not_recorded.load(std::sync::atomic::Ordering::Relaxed), 2);
    let metrics = drivebus_gateway::metrics::render(&gw).unwrap();
    assert!(metrics.contains("drivebus_commands_not_recorded_total 2"), "{metrics}");
    let _ = Arc::strong_count(&gw);
}
