//! The metrics over HTTP: `GET /metrics` (the exposition [`crate::metrics`] renders, behind a
//! read token like every other read) and [`track`], the middleware that counts each HTTP
//! request. [`router`](super::router) layers it over every route:
//! `router.layer(axum::middleware::from_fn_with_state(gw.clone(), http::metrics::track))`.

use std::sync::Arc;
use std::time::Instant;

use axum::extract::{MatchedPath, Request, State};
use axum::http::{header, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;

use crate::core::Gateway;
use crate::http::auth::ReadAccess;
use crate::metrics;

/// `GET /metrics`, to merge into the HTTP router.
pub fn routes() -> Router<Arc<Gateway>> {
    Router::new().route("/metrics", get(scrape))
}

/// Needs a read token unless `[http] anonymous_read`, as every other read does: the series carry
/// every drive's values.
async fn scrape(_access: ReadAccess, State(gw): State<Arc<Gateway>>) -> Response {
    match metrics::render(&gw) {
        Ok(text) => ([(header::CONTENT_TYPE, metrics::CONTENT_TYPE)], text).into_response(),
        Err(e) => (
            StatusCode::INTERNAL_SERVER_ERROR,
            axum::Json(serde_json::json!({ "error": { "kind": "internal", "message": e } })),
        )
            .into_response(),
    }
}

/// Axum middleware counting each HTTP request by route, method and status, with its latency.
/// Wire it with `Router::layer(axum::middleware::from_fn_with_state(gw, track))` after the
/// routes so the matched route is known.
pub async fn track(State(gw): State<Arc<Gateway>>, req: Request, next: Next) -> Response {
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map_or_else(|| "unmatched".to_string(), |p| p.as_str().to_string());
    let method = match req.method().as_str() {
        m @ ("GET" | "HEAD" | "POST" | "PUT" | "PATCH" | "DELETE" | "OPTIONS") => m.to_string(),
        _ => "other".to_string(),
    };
    let start = Instant::now();
    let response = next.run(req).await;
    metrics::front_ends(&gw).http_request(
        &route,
        &method,
        response.status().as_u16(),
        start.elapsed().as_secs_f64(),
    );
    response
}
