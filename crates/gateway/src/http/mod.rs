//! The HTTP/JSON API (axum): drives, buses, commands, parameters, events, the live stream and
//! the OpenAPI description. Reads come from the cache; writes go through
//! [`Gateway::command`](crate::gateway::Gateway::command).

use std::sync::Arc;

use axum::extract::State;
use axum::routing::get;
use axum::{Json, Router};

use crate::gateway::{DriveView, Gateway};

pub mod dashboard;

/// The whole HTTP service.
pub fn router(gw: Arc<Gateway>) -> Router {
    Router::new().route("/api/drives", get(drives)).merge(dashboard::routes()).with_state(gw)
}

async fn drives(State(gw): State<Arc<Gateway>>) -> Json<Vec<DriveView>> {
    Json(gw.drives().iter().map(|d| gw.drive_view(d)).collect())
}
