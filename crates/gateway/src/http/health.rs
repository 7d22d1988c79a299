//! `GET /healthz` (the process answers) and `GET /readyz` (every configured listener is up and
//! the store is writable; 503 with the reasons otherwise): the facts [`crate::health`] keeps,
//! over HTTP. Both are open without a token and say nothing about drives.

use std::sync::Arc;

use axum::extract::State;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use serde_json::json;

use crate::core::Gateway;

/// `/healthz` and `/readyz`, to merge into the HTTP router (no token needed).
pub fn routes() -> Router<Arc<Gateway>> {
    Router::new().route("/healthz", get(healthz)).route("/readyz", get(readyz))
}

async fn healthz() -> Response {
    Json(json!({ "status": "ok" })).into_response()
}

async fn readyz(State(gw): State<Arc<Gateway>>) -> Response {
    let gw2 = gw.clone();
    // The store check touches the disk: off the async workers.
    let why = tokio::task::spawn_blocking(move || gw2.not_ready())
        .await
        .unwrap_or_else(|e| vec![format!("the readiness check failed: {e}")]);
    if why.is_empty() {
        Json(json!({ "ready": true })).into_response()
    } else {
        (StatusCode::SERVICE_UNAVAILABLE, Json(json!({ "ready": false, "reasons": why }))).into_response()
    }
}
