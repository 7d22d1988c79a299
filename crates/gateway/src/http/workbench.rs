//! The commissioning routes: a drive's parameters with their values, its backup file, a restore
//! with its diff, its trips, and finding drives on a bus (docs/http-api.md). The dashboard's
//! parameter, backup, trips and scan pages use only these.

use std::collections::HashMap;
use std::sync::Arc;

use axum::body::Bytes;
use axum::extract::rejection::{BytesRejection, QueryRejection};
use axum::extract::{Path, Query, State};
use axum::http::{header, HeaderValue};
use axum::response::{IntoResponse, Response};
use axum::Json;
use drivebus_drive::backup::Backup;
use drivebus_store::{EventFilter, EventKind};
use serde_json::{json, Value};

use crate::core::{Gateway, ParamRow, RestoreOptions};
use crate::http::api::{body, query, ApiResult};
use crate::http::auth::{ReadAccess, WriteAccess};
use crate::http::error::ApiError;
use crate::scan::{parse_addresses, ScanReport};

/// Trip events answered beside the drive's own history.
pub const TRIP_EVENTS: usize = 50;

/// A yes/no query parameter: `true`/`false` (`1`/`0`), `default` when not given.
fn flag(q: &HashMap<String, String>, key: &str, default: bool) -> Result<bool, ApiError> {
    match q.get(key).map(|s| s.trim()) {
        None | Some("") => Ok(default),
        Some("true" | "1") => Ok(true),
        Some("false" | "0") => Ok(false),
        Some(v) => {
            Err(ApiError::bad_request(format!("{key}={:?}: use true or false", crate::text::shown(v))))
        }
    }
}

/// `GET /api/drives/{id}/params?group=&read=`: every parameter of the drive's catalog (of
/// `group`), with the value read from the drive unless `read=false`.
pub async fn params(
    ReadAccess(caller): ReadAccess,
    State(gw): State<Arc<Gateway>>,
    Path(id): Path<String>,
    q: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> ApiResult<Vec<ParamRow>> {
    gw.drive(&id)?;
    let q = query(q, &["group", "read"])?;
    let read = flag(&q, "read", true)?;
    let group = q.get("group").map(String::as_str).filter(|g| !g.is_empty());
    Ok(Json(gw.read_params(&id, group, read, &caller.ip).await?))
}

/// `GET /api/drives/{id}/backup`: the file `drivebus params backup` writes, as a download.
pub async fn backup(
    ReadAccess(caller): ReadAccess,
    State(gw): State<Arc<Gateway>>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let text = gw.backup(&id, &caller.ip).await?.to_text();
    let mut r = ([(header::CONTENT_TYPE, "application/json")], text).into_response();
    // The id is a configured name; only safe characters go into the header.
    let file: String =
        id.chars().map(|c| if c.is_ascii_alphanumeric() || "-_.".contains(c) { c } else { '_' }).collect();
    if let Ok(v) = HeaderValue::from_str(&format!("attachment; filename=\"{file}.json\"")) {
        r.headers_mut().insert(header::CONTENT_DISPOSITION, v);
    }
    Ok(r)
}

/// `POST /api/drives/{id}/restore?dry_run=&only=&include_comm=` with a backup file as the body:
/// the differences, and (unless a dry run) each applied row's result.
pub async fn restore(
    WriteAccess(caller): WriteAccess,
    State(gw): State<Arc<Gateway>>,
    Path(id): Path<String>,
    q: Result<Query<Vec<(String, String)>>, QueryRejection>,
    b: Result<Bytes, BytesRejection>,
) -> ApiResult<Value> {
    let b = body(b)?;
    gw.drive(&id)?;
    let q = query(q, &["dry_run", "only", "include_comm"])?;
    let options = RestoreOptions {
        dry_run: flag(&q, "dry_run", false)?,
        include_comm: flag(&q, "include_comm", false)?,
        only: q
            .get("only")
            .map(|o| o.split(',').map(str::trim).filter(|n| !n.is_empty()).map(str::to_string).collect()),
    };
    let text = std::str::from_utf8(&b).map_err(|_| {
        ApiError::new(
            axum::http::StatusCode::BAD_REQUEST,
            "bad_backup",
            "not a drivebus backup: the body is not UTF-8 text",
        )
    })?;
    let file = Backup::parse(text)
        .map_err(|e| ApiError::new(axum::http::StatusCode::BAD_REQUEST, "bad_backup", e.to_string()))?;
    let rows = gw.restore(&id, &file, &options, &caller.actor(), &caller.ip).await?;
    let applied = rows.iter().filter(|r| r.result == Some("ok")).count();
    let failed = rows.iter().filter(|r| r.result == Some("failed")).count();
    Ok(Json(json!({
        "drive": id,
        "dry_run": options.dry_run,
        "from_address": file.address,
        "rows": rows,
        "applied": applied,
        "failed": failed,
    })))
}

/// `GET /api/drives/{id}/trips`: the drive's trip history as `drivebus trips --json` gives it,
/// and the gateway's trip events with their pre-trip snapshot (`events`, newest first; empty
/// without a store).
pub async fn trips(
    ReadAccess(caller): ReadAccess,
    State(gw): State<Arc<Gateway>>,
    Path(id): Path<String>,
) -> ApiResult<Value> {
    let mut history = gw.trip_history(&id, &caller.ip).await?;
    let events = match gw.store() {
        None => Vec::new(),
        Some(_) => {
            let filter = EventFilter {
                drive: Some(id.clone()),
                kind: Some(EventKind::Trip),
                limit: TRIP_EVENTS,
                ..EventFilter::default()
            };
            let gw = gw.clone();
            tokio::task::spawn_blocking(move || gw.store().map(|s| s.events(&filter)))
                .await
                .map_err(|e| ApiError::internal(format!("the event store reader failed: {e}")))?
                .transpose()
                .map_err(|e| ApiError::internal(format!("the event store failed: {e}")))?
                .unwrap_or_default()
        }
    };
    history["events"] = json!(events);
    Ok(Json(history))
}

/// `POST /api/buses/{bus}/scan?addresses=1-32`: starts finding drives on the bus (202).
pub async fn start_scan(
    WriteAccess(_): WriteAccess,
    State(gw): State<Arc<Gateway>>,
    Path(bus): Path<String>,
    q: Result<Query<Vec<(String, String)>>, QueryRejection>,
    b: Result<Bytes, BytesRejection>,
) -> Result<(axum::http::StatusCode, Json<ScanReport>), ApiError> {
    body(b)?;
    let q = query(q, &["addresses"])?;
    let addresses = match q.get("addresses").map(|s| s.trim()).filter(|s| !s.is_empty()) {
        None => None,
        Some(a) => Some(parse_addresses(a).map_err(|e| ApiError::bad_request(format!("addresses: {e}")))?),
    };
    Ok((axum::http::StatusCode::ACCEPTED, Json(gw.start_scan(&bus, addresses)?)))
}

/// `GET /api/buses/{bus}/scan`: the last scan's progress and findings (404 `not_scanned` when
/// the bus was not scanned since the gateway started).
pub async fn scan(
    _: ReadAccess,
    State(gw): State<Arc<Gateway>>,
    Path(bus): Path<String>,
) -> ApiResult<ScanReport> {
    gw.scan_report(&bus)?.map(Json).ok_or_else(|| {
        ApiError::new(
            axum::http::StatusCode::NOT_FOUND,
            "not_scanned",
            format!("bus {bus:?} was not scanned since the gateway started: POST /api/buses/{bus}/scan starts a scan"),
        )
    })
}
