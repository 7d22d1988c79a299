//! On-demand reads share a bus fairly with polling, on tokio's paused clock: Modbus TCP
//! clients reading the whole parameter window of one drive and HTTP clients reading one of its
//! parameters, all at once and without pause, while another drive on the same bus keeps its
//! data age under four poll intervals; beyond the bounded queue, reads are refused as busy
//! (HTTP 429, Modbus exception 06) at once.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Arc;
use std::time::Duration;

use axum::body::Body;
use axum::extract::connect_info::MockConnectInfo;
use axum::http::Request;
use drivebus_gateway::core::{Change, Gateway};
use drivebus_gateway::GatewayConfig;
use http_body_util::BodyExt;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::time::Instant;
use tower::ServiceExt;

const POLL_MS: u64 = 250;

/// conveyor-1 polled every 250 ms and fan-1 (unit 3) on one 38 400 baud bus, as in the demo.
fn config(bus_extra: &str) -> GatewayConfig {
    let text = format!(
        "[http]\nanonymous_read = true\n\
         [[bus]]\nname = \"line-generic\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 38400\nserial = \"8N2\"\n{bus_extra}\n\
         [[bus.drive]]\nname = \"conveyor-1\"\nfamily = \"generic\"\naddress = 1\npoll_ms = {POLL_MS}\npriority = \"high\"\n\
         [[bus.drive]]\nname = \"fan-1\"\nfamily = \"generic\"\naddress = 3\nunit_id = 3\npoll_ms = 500\n"
    );
    GatewayConfig::from_toml("plant.toml", &text).unwrap()
}

/// Modbus TCP clients from `peer`'s address, each reading holding registers 1000..1124 of unit 3
/// (62 parameters) again as soon as answered; counts the answers and the busy exceptions.
fn window_readers(
    gw: &Arc<Gateway>,
    n: usize,
    peer: SocketAddr,
    answered: Arc<AtomicU32>,
    busy: Arc<AtomicU32>,
) {
    for _ in 0..n {
        let (mut client, server) = tokio::io::duplex(4096);
        tokio::spawn(drivebus_gateway::modbus_tcp::serve_stream(gw.clone(), server, peer));
        let (answered, busy) = (answered.clone(), busy.clone());
        tokio::spawn(async move {
            for tid in 0u16.. {
                let mut f = tid.to_be_bytes().to_vec();
                f.extend_from_slice(&[0, 0, 0, 6, 3, 0x03, 0x03, 0xE8, 0, 124]);
                client.write_all(&f).await.unwrap();
                let mut h = [0u8; 7];
                client.read_exact(&mut h).await.unwrap();
                let mut pdu = vec![0u8; u16::from_be_bytes([h[4], h[5]]) as usize - 1];
                client.read_exact(&mut pdu).await.unwrap();
                match pdu[..] {
                    [0x03, 248, ..] => answered.fetch_add(1, Ordering::Relaxed),
                    [0x83, 0x06] => busy.fetch_add(1, Ordering::Relaxed),
                    _ => panic!("unexpected answer {pdu:02X?}"),
                };
            }
        });
    }
}

/// HTTP clients from `peer`'s address, each reading fan-1's P0.02 again as soon as answered;
/// counts the answers (200) and the refusals (429 `busy`).
fn param_readers(
    gw: &Arc<Gateway>,
    n: usize,
    peer: SocketAddr,
    answered: Arc<AtomicU32>,
    busy: Arc<AtomicU32>,
) {
    let app = drivebus_gateway::http::router(gw.clone()).layer(MockConnectInfo(peer));
    for _ in 0..n {
        let (app, answered, busy) = (app.clone(), answered.clone(), busy.clone());
        tokio::spawn(async move {
            loop {
                let req = Request::get("/api/drives/fan-1/params/P0.02").body(Body::empty()).unwrap();
                let r = app.clone().oneshot(req).await.unwrap();
                let status = r.status().as_u16();
                if status == 429 {
                    assert_eq!(r.headers()["retry-after"], "1");
                }
                let body = r.into_body().collect().await.unwrap().to_bytes();
                match status {
                    200 => {
                        // The client's round trip: a virtual millisecond.
                        tokio::time::sleep(Duration::from_millis(1)).await;
                        answered.fetch_add(1, Ordering::Relaxed)
                    }
                    429 => {
                        let json: serde_json::Value = serde_json::from_slice(&body).unwrap();
                        assert_eq!(json["error"]["kind"], "busy", "{json}");
                        // A refused client comes back a little later, as a real one would.
                        tokio::time::sleep(Duration::from_millis(20)).await;
                        busy.fetch_add(1, Ordering::Relaxed)
                    }
                    s => panic!("unexpected answer {s}: {body:?}"),
                };
            }
        });
    }
}

/// The longest time between two refreshes of conveyor-1 over `run`.
async fn worst_age(gw: &Arc<Gateway>, run: Duration) -> Duration {
    let mut changes = gw.subscribe();
    let end = Instant::now() + run;
    let mut last = Instant::now();
    let mut worst = Duration::ZERO;
    loop {
        match tokio::time::timeout_at(end, changes.recv()).await {
            Err(_) => break,
            Ok(Ok(Change::Drive(v))) if v.id == "conveyor-1" => {
                worst = worst.max(last.elapsed());
                last = Instant::now();
            }
            Ok(_) => {}
        }
    }
    worst.max(last.elapsed())
}

fn counters() -> (Arc<AtomicU32>, Arc<AtomicU32>) {
    (Arc::new(AtomicU32::new(0)), Arc::new(AtomicU32::new(0)))
}

#[tokio::test(start_paused = true)]
async fn window_and_param_floods_leave_the_other_drives_polls_on_time() {
    // Every read goes to the drive (no parameter cache): the bus is flooded as it can be.
    let gw = Gateway::start(config("param_cache_ms = 0"), None).unwrap();
    tokio::time::sleep(Duration::from_secs(1)).await;
    let peer = SocketAddr::from(([127, 0, 0, 2], 50000));
    let (windows, windows_busy) = counters();
    let (params, params_busy) = counters();
    window_readers(&gw, 4, peer, windows.clone(), windows_busy.clone());
    param_readers(&gw, 16, SocketAddr::from(([127, 0, 0, 3], 50000)), params.clone(), params_busy.clone());

    let worst = worst_age(&gw, Duration::from_secs(20)).await;
    let poll = Duration::from_millis(POLL_MS);
    assert!(worst < 4 * poll, "conveyor-1's data age reached {worst:?} (poll every {poll:?})");
    // The floods were served too, in their share of the bus.
    let (w, p) = (windows.load(Ordering::Relaxed), params.load(Ordering::Relaxed));
    // The demo's generic bus keeps the manual's 10 ms silence before each request, so a read
    // takes some 15 ms of bus time: half of 20 s is some 650 reads (a window is 62 of them).
    let reads = w * 62 + p;
    assert!(w >= 2 && p >= 100 && reads >= 500, "{w} windows and {p} parameters read in 20 s");
    // 4 connections are within one client's 8 reads waiting; 16 are not (those over are busy).
    assert_eq!(windows_busy.load(Ordering::Relaxed), 0);
    assert!(params_busy.load(Ordering::Relaxed) > 0);
}

#[tokio::test(start_paused = true)]
async fn beyond_the_queue_reads_are_refused_as_busy() {
    let gw =
        Gateway::start(config("param_cache_ms = 0\non_demand_queue = 4\non_demand_per_client = 2"), None)
            .unwrap();
    tokio::time::sleep(Duration::from_secs(1)).await;
    let (windows, windows_busy) = counters();
    let (params, params_busy) = counters();
    window_readers(&gw, 4, SocketAddr::from(([127, 0, 0, 2], 50000)), windows.clone(), windows_busy.clone());
    param_readers(&gw, 16, SocketAddr::from(([127, 0, 0, 3], 50000)), params.clone(), params_busy.clone());
    let worst = worst_age(&gw, Duration::from_secs(10)).await;
    assert!(worst < 4 * Duration::from_millis(POLL_MS), "conveyor-1's data age reached {worst:?}");
    for (what, ok, busy) in [("window", &windows, &windows_busy), ("parameter", &params, &params_busy)] {
        let (ok, busy) = (ok.load(Ordering::Relaxed), busy.load(Ordering::Relaxed));
        assert!(ok > 0 && busy > 0, "{what} reads: {ok} answered, {busy} refused as busy");
    }
}

#[tokio::test(start_paused = true)]
async fn readers_of_one_parameter_share_a_read_made_a_moment_ago() {
    let gw = Gateway::start(config(""), None).unwrap();
    tokio::time::sleep(Duration::from_secs(1)).await;
    let bus = gw.buses()[0].clone();
    let transactions = || bus.stats().transactions;
    // 10 s of polls alone, then 10 s with 16 readers of P0.02.
    let start = transactions();
    tokio::time::sleep(Duration::from_secs(10)).await;
    let polls = transactions() - start;
    let (params, busy) = counters();
    param_readers(&gw, 16, SocketAddr::from(([127, 0, 0, 3], 50000)), params.clone(), busy.clone());
    let start = transactions();
    tokio::time::sleep(Duration::from_secs(10)).await;
    let reads = params.load(Ordering::Relaxed);
    let on_bus = transactions() - start - polls;
    assert!(reads > 1000, "{reads} reads answered");
    // One read from the drive per 200 ms at most (50 in 10 s), and a few polls' worth of slack.
    assert!(on_bus <= 55, "{on_bus} transactions on the bus for {reads} reads");
    assert_eq!(busy.load(Ordering::Relaxed), 0);
}
