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

/// The kept facts, the store's as of its last scheduled check (`health::STORE_CHECK_EVERY`):
/// no file is touched, so a probe, which needs no token, cannot make the gateway do disk work,
/// and `/readyz` says what `drivebus_ready` says.
async fn readyz(State(gw): State<Arc<Gateway>>) -> Response {
    let why = gw.not_ready();
    if why.is_empty() {
        Json(json!({ "ready": true })).into_response()
    } else {
        (StatusCode::SERVICE_UNAVAILABLE, Json(json!({ "ready": false, "reasons": why }))).into_response()
    }
}
