//! The HTTP/JSON API (axum): drives, buses, commands, parameters, events, the live stream and
//! the OpenAPI description. Reads come from the cache; writes go through
//! [`Gateway::command`](crate::core::Gateway::command). docs/http-api.md describes every
//! route.
//!
//! Every answer that is not a success is JSON (`{"error": {"kind", "message"}}`, [`error`]),
//! including the framework's own (405, 413, unknown paths) and a handler panic. No request
//! reaches a drive unless it is authorized ([`auth`]) and valid.

pub mod api;
pub mod auth;
pub mod dashboard;
pub mod error;
pub mod health;
pub mod host;
pub mod metrics;
pub mod stream;
pub mod workbench;

use std::sync::Arc;

use axum::extract::{DefaultBodyLimit, Request, State};
use axum::http::{header, StatusCode};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::Router;
use futures_util::FutureExt;

use crate::core::Gateway;
use error::ApiError;

/// The API's routes as axum writes them (`:id` for `{id}`) with their methods; the OpenAPI
/// document describes exactly these (a test checks both ways).
pub const API_ROUTES: &[(&str, &[&str])] = &[
    ("/api/drives", &["GET"]),
    ("/api/drives/:id", &["GET"]),
    ("/api/drives/:id/run", &["POST"]),
    ("/api/drives/:id/stop", &["POST"]),
    ("/api/drives/:id/reverse", &["POST"]),
    ("/api/drives/:id/jog", &["POST"]),
    ("/api/drives/:id/reset", &["POST"]),
    ("/api/drives/:id/speed", &["POST"]),
    ("/api/drives/:id/params", &["GET"]),
    ("/api/drives/:id/params/:name", &["GET", "PUT"]),
    ("/api/drives/:id/backup", &["GET"]),
    ("/api/drives/:id/restore", &["POST"]),
    ("/api/drives/:id/trips", &["GET"]),
    ("/api/drives/:id/trend", &["GET"]),
    ("/api/buses", &["GET"]),
    ("/api/buses/:bus/scan", &["GET", "POST"]),
    ("/api/events", &["GET"]),
    ("/api/stream", &["GET"]),
    ("/api/openapi.json", &["GET"]),
];

/// The API routes, before the gateway is given as state (the dashboard and metrics routes are
/// merged beside them by [`router`]).
pub fn api_routes() -> Router<Arc<Gateway>> {
    let mut r =
        Router::new().route("/api/drives", get(api::drives)).route("/api/drives/:id", get(api::drive));
    for name in ["run", "stop", "reverse", "jog", "reset"] {
        r = r.route(&format!("/api/drives/:id/{name}"), post(api::command));
    }
    r.route("/api/drives/:id/speed", post(api::speed))
        .route("/api/drives/:id/params", get(workbench::params))
        .route("/api/drives/:id/params/:name", get(api::read_param).put(api::write_param))
        .route("/api/drives/:id/backup", get(workbench::backup))
        .route("/api/drives/:id/restore", post(workbench::restore))
        .route("/api/drives/:id/trips", get(workbench::trips))
        .route("/api/buses/:bus/scan", get(workbench::scan).post(workbench::start_scan))
        .route("/api/drives/:id/trend", get(api::trend))
        .route("/api/buses", get(api::buses))
        .route("/api/events", get(api::events))
        .route("/api/stream", get(stream::stream))
        .route("/api/openapi.json", get(api::openapi))
}

/// The whole HTTP service.
pub fn router(gw: Arc<Gateway>) -> Router {
    let max_body = gw.config().http.max_body;
    api_routes()
        .merge(dashboard::routes())
        .merge(metrics::routes())
        .merge(health::routes())
        .fallback(api::fallback)
        .layer(middleware::from_fn_with_state(gw.clone(), metrics::track))
        .layer(DefaultBodyLimit::max(max_body))
        .layer(middleware::map_response(json_errors))
        .layer(middleware::from_fn_with_state(gw.clone(), host::check))
        .layer(middleware::from_fn_with_state(gw.clone(), guard))
        .with_state(gw)
}

/// Serves the HTTP API, the dashboard and the metrics on `listener` until the process ends,
/// over TLS when `tls` is given (HTTPS; [`crate::config::tls::server_config`]), within the
/// gateway's `[limits]`: at most `per_address` connections from one address, the TLS handshake
/// and then a request header each within `header_timeout_ms`, a connection idle for
/// `idle_timeout_s` closed.
pub async fn serve(
    gw: Arc<Gateway>,
    listener: tokio::net::TcpListener,
    tls: Option<Arc<tokio_rustls::rustls::ServerConfig>>,
) -> std::io::Result<()> {
    let limits = gw.limits().listener(if tls.is_some() { "HTTPS" } else { "HTTP" });
    let cfg = gw.limits().config().clone();
    let app = router(gw);
    let acceptor = tls.map(tokio_rustls::TlsAcceptor::from);
    loop {
        let (sock, peer, permit) = limits.accept(&listener).await;
        let (app, cfg, acceptor) = (app.clone(), cfg.clone(), acceptor.clone());
        tokio::spawn(async move {
            let _permit = permit;
            let _ = sock.set_nodelay(true);
            let Some(acceptor) = acceptor else {
                return connection(app, &cfg, peer, sock).await;
            };
            // A handshake that does not end in time (or fails) closes the connection, as a
            // request header that does not come would.
            let handshake = acceptor.accept(sock);
            let tls = if cfg.header_timeout.is_zero() {
                handshake.await.ok()
            } else {
                tokio::time::timeout(cfg.header_timeout, handshake).await.ok().and_then(Result::ok)
            };
            if let Some(stream) = tls {
                connection(app, &cfg, peer, stream).await;
            }
        });
    }
}

/// Serves one connection from `peer` (plain or TLS) until it ends, its request header times
/// out, or it is idle too long.
async fn connection<S>(app: Router, cfg: &crate::limits::LimitsConfig, peer: std::net::SocketAddr, sock: S)
where
    S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send + 'static,
{
    let io = crate::limits::Activity::new(sock);
    let idle = io.idle(cfg.idle_timeout);
    let service = hyper::service::service_fn(move |mut req: Request<hyper::body::Incoming>| {
        req.extensions_mut().insert(axum::extract::ConnectInfo(peer));
        tower::ServiceExt::oneshot(app.clone(), req.map(axum::body::Body::new))
    });
    let conn = hyper::server::conn::http1::Builder::new()
        .timer(hyper_util::rt::TokioTimer::new())
        .header_read_timeout(cfg.header_timeout)
        .serve_connection(hyper_util::rt::TokioIo::new(io), service);
    tokio::select! {
        _ = conn => {}
        _ = idle => {}
    }
}

/// Refuses a declared body over `[http] max_body` before anything else looks at the request,
/// and turns a handler panic into a 500 JSON error instead of a dropped connection.
async fn guard(State(gw): State<Arc<Gateway>>, req: Request, next: Next) -> Response {
    let max = gw.config().http.max_body;
    let declared =
        req.headers().get(header::CONTENT_LENGTH).and_then(|v| v.to_str().ok()?.parse::<u64>().ok());
    if declared.is_some_and(|n| n > max as u64) {
        return ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            "too_large",
            format!("the request body has {} bytes: at most {max} ([http] max_body)", declared.unwrap_or(0)),
        )
        .into_response();
    }
    match std::panic::AssertUnwindSafe(next.run(req)).catch_unwind().await {
        Ok(r) => r,
        Err(_) => {
            ApiError::internal("the gateway failed on this request (a defect): see its log").into_response()
        }
    }
}

/// Gives every error answer that is not already JSON (the framework's 405, 413, 415, query and
/// path rejections) the JSON error body, keeping its status and its text as the message.
async fn json_errors(r: Response) -> Response {
    let status = r.status();
    if !(status.is_client_error() || status.is_server_error()) {
        return r;
    }
    let is_json = r
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/json"));
    if is_json {
        return r;
    }
    let (parts, body) = r.into_parts();
    let text = axum::body::to_bytes(body, 4096).await.unwrap_or_default();
    let mut out = ApiError::from_status(status, &String::from_utf8_lossy(&text)).into_response();
    // Keep headers that tell the client what to do (Allow on a 405).
    if let Some(allow) = parts.headers.get(header::ALLOW) {
        out.headers_mut().insert(header::ALLOW, allow.clone());
    }
    out
}
