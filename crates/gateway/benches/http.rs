//! Request handling of the HTTP API in process: `GET /api/drives/{id}` (and `GET /api/drives`)
//! through the whole router (auth, routing, the JSON error layer, serialization) with tower's
//! `oneshot`, on the demo gateway while it polls its virtual buses. No sockets: this measures
//! the gateway's own work per request, not the network stack.
//!
//! Run: `cargo bench -p drivebus-gateway --bench http` (or `bench/http.sh`). Prints requests/s,
//! the median of 5 rounds, one request at a time and 8 at once.
#![allow(missing_docs)]

use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::body::Body;
use axum::http::{header, Request};
use axum::Router;
use drivebus_gateway::config::{Role, Token};
use drivebus_gateway::{Gateway, GatewayConfig};
use http_body_util::BodyExt;
use tower::ServiceExt;

const TOKEN: &str = "bench-token-0123456789abcdef";
const PER_ROUND: usize = 20_000;
const ROUNDS: usize = 5;

async fn one(app: &Router, path: &str, token: bool) {
    let mut req = Request::get(path);
    if token {
        req = req.header(header::AUTHORIZATION, format!("Bearer {TOKEN}"));
    }
    let r = app.clone().oneshot(req.body(Body::empty()).unwrap()).await.unwrap();
    assert!(r.status().is_success(), "{path}: {}", r.status());
    let bytes = r.into_body().collect().await.unwrap().to_bytes();
    std::hint::black_box(bytes);
}

async fn round(app: &Router, path: &'static str, token: bool, concurrent: usize) -> f64 {
    let start = Instant::now();
    let mut tasks = Vec::new();
    for _ in 0..concurrent {
        let app = app.clone();
        tasks.push(tokio::spawn(async move {
            for _ in 0..PER_ROUND / concurrent {
                one(&app, path, token).await;
            }
        }));
    }
    for t in tasks {
        t.await.unwrap();
    }
    (PER_ROUND / concurrent * concurrent) as f64 / start.elapsed().as_secs_f64()
}

async fn measure(app: &Router, what: &str, path: &'static str, token: bool, concurrent: usize) {
    round(app, path, token, concurrent).await; // warm-up
    let mut rates = Vec::new();
    for _ in 0..ROUNDS {
        rates.push(round(app, path, token, concurrent).await);
    }
    rates.sort_by(f64::total_cmp);
    let (lo, med, hi) = (rates[0], rates[ROUNDS / 2], rates[ROUNDS - 1]);
    println!(
        "{what:<44} {concurrent} at once: {med:>9.0} requests/s (min {lo:.0}, max {hi:.0}; {:.1} us each)",
        1e6 / med
    );
}

fn main() {
    let rt = tokio::runtime::Builder::new_multi_thread().enable_all().build().unwrap();
    rt.block_on(async {
        let mut config = GatewayConfig::demo();
        config.store = None;
        config.http.anonymous_read = false;
        config.tokens = vec![Token { name: "bench".into(), secret: TOKEN.into(), role: Role::Read }];
        let gw: Arc<Gateway> = Gateway::start(config, None).unwrap();
        // Let every drive answer once so the views are full.
        tokio::time::sleep(Duration::from_secs(3)).await;
        let app = drivebus_gateway::http::router(gw.clone());
        println!("HTTP request handling in process (oneshot), {} worker threads", num_threads());
        for concurrent in [1, 8] {
            measure(&app, "GET /api/drives/pump-1 (read token)", "/api/drives/pump-1", true, concurrent)
                .await;
            measure(&app, "GET /api/drives (10 drives, read token)", "/api/drives", true, concurrent).await;
        }
    });
}

fn num_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}
