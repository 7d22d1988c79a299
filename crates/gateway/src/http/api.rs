//! The JSON routes: drives, commands, parameters, buses, events and trends.

use std::collections::HashMap;
use std::sync::Arc;

use axum::body::Bytes;
use axum::extract::rejection::{BytesRejection, QueryRejection};
use axum::extract::{Path, Query, State};
use axum::http::Uri;
use axum::Json;
use drivebus_store::{Event, EventFilter, EventKind, Resolution, TrendPoint, TrendQuery};
use serde::de::DeserializeOwned;
use serde::Deserialize;
use serde_json::{json, Value};

use crate::core::{unix_ms, BusView, Command, DriveView, Gateway, ParamReading};
use crate::http::auth::{ReadAccess, WriteAccess};
use crate::http::error::ApiError;

/// Events answered when the query gives no `limit`.
pub const DEFAULT_EVENT_LIMIT: usize = 100;
/// Most events one request may ask for.
pub const MAX_EVENT_LIMIT: usize = 10_000;
/// The span of a trend when the query gives no `since`, ms.
pub const DEFAULT_TREND_SPAN_MS: i64 = 3_600_000;

pub(crate) type ApiResult<T> = Result<Json<T>, ApiError>;

/// `GET /api/drives`.
pub async fn drives(_: ReadAccess, State(gw): State<Arc<Gateway>>) -> Json<Vec<DriveView>> {
    Json(gw.drives().iter().map(|d| gw.drive_view(d)).collect())
}

/// `GET /api/drives/{id}`.
pub async fn drive(
    _: ReadAccess,
    State(gw): State<Arc<Gateway>>,
    Path(id): Path<String>,
) -> ApiResult<DriveView> {
    let d = gw.drive(&id)?;
    Ok(Json(gw.drive_view(&d)))
}

/// `GET /api/buses`.
pub async fn buses(_: ReadAccess, State(gw): State<Arc<Gateway>>) -> Json<Vec<BusView>> {
    Json(gw.buses().iter().map(|b| gw.bus_view(b)).collect())
}

/// The body of a request, within `[http] max_body` (413 `too_large` beyond).
pub(crate) fn body(b: Result<Bytes, BytesRejection>) -> Result<Bytes, ApiError> {
    b.map_err(|e| ApiError::from_status(e.status(), &e.body_text()))
}

/// Parses a JSON body: 400 `bad_json` when it is not JSON, 422 `invalid` when it is JSON of the
/// wrong shape (a missing or unknown field, a wrong type).
fn parse_json<T: DeserializeOwned>(bytes: &[u8], example: &str) -> Result<T, ApiError> {
    if bytes.iter().all(u8::is_ascii_whitespace) {
        return Err(ApiError::bad_json(format!("the body is empty: send JSON like {example}")));
    }
    let refuse = |e: serde_json::Error| {
        use serde_json::error::Category;
        match e.classify() {
            Category::Data => ApiError::invalid(format!("{e}: send JSON like {example}")),
            Category::Io | Category::Syntax | Category::Eof => {
                ApiError::bad_json(format!("the body is not JSON ({e}): send JSON like {example}"))
            }
        }
    };
    // A key given twice (`{"hz":40,"hz":41}`) is refused, not resolved to one of them.
    crate::json::check_unique_keys(bytes).map_err(refuse)?;
    let value: Value = serde_json::from_slice(bytes).map_err(refuse)?;
    // serde would take an array for the fields in order (`[25]` for `{"hz": 25}`): only the
    // documented object is a request.
    if !value.is_object() {
        return Err(ApiError::invalid(format!("the body must be a JSON object like {example}")));
    }
    serde_json::from_value(value).map_err(|e| ApiError::invalid(format!("{e}: send JSON like {example}")))
}

async fn run_command(gw: &Arc<Gateway>, id: &str, command: Command, actor: &str) -> ApiResult<Value> {
    gw.command(id, command, actor).await?;
    let d = gw.drive(id)?;
    Ok(Json(json!({ "ok": true, "drive": gw.drive_view(&d) })))
}

/// `POST /api/drives/{id}/run|stop|reverse|jog|reset` (no body; one is ignored within
/// `[http] max_body`): the command is the route's last segment.
pub async fn command(
    WriteAccess(caller): WriteAccess,
    State(gw): State<Arc<Gateway>>,
    Path(id): Path<String>,
    uri: Uri,
    b: Result<Bytes, BytesRejection>,
) -> ApiResult<Value> {
    body(b)?;
    let name = uri.path().rsplit('/').next().unwrap_or_default();
    let command = Command::from_name(name).ok_or_else(|| ApiError::not_found(uri.path()))?;
    gw.drive(&id)?;
    run_command(&gw, &id, command, &caller.actor()).await
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SpeedBody {
    hz: f64,
}

/// `POST /api/drives/{id}/speed` with `{"hz": 40}`.
pub async fn speed(
    WriteAccess(caller): WriteAccess,
    State(gw): State<Arc<Gateway>>,
    Path(id): Path<String>,
    b: Result<Bytes, BytesRejection>,
) -> ApiResult<Value> {
    let b = body(b)?;
    gw.drive(&id)?;
    let SpeedBody { hz } = parse_json(&b, r#"{"hz": 40}"#)?;
    if !hz.is_finite() {
        return Err(ApiError::invalid(format!("hz {hz} is not a number of Hz")));
    }
    run_command(&gw, &id, Command::Speed(hz), &caller.actor()).await
}

/// `GET /api/drives/{id}/params/{name}`: read from the drive.
pub async fn read_param(
    ReadAccess(caller): ReadAccess,
    State(gw): State<Arc<Gateway>>,
    Path((id, name)): Path<(String, String)>,
) -> ApiResult<ParamReading> {
    gw.drive(&id)?.param(&name)?;
    Ok(Json(gw.read_param(&id, &name, &caller.ip).await?))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ParamBody {
    value: Value,
    #[serde(default)]
    eeprom: bool,
}

/// `PUT /api/drives/{id}/params/{name}` with `{"value": "50", "eeprom": false}`.
pub async fn write_param(
    WriteAccess(caller): WriteAccess,
    State(gw): State<Arc<Gateway>>,
    Path((id, name)): Path<(String, String)>,
    b: Result<Bytes, BytesRejection>,
) -> ApiResult<Value> {
    let b = body(b)?;
    let d = gw.drive(&id)?;
    d.param(&name)?;
    let example = r#"{"value": "50", "eeprom": false}"#;
    let ParamBody { value, eeprom } = parse_json(&b, example)?;
    let value = match value {
        Value::String(s) => s,
        Value::Number(n) => n.to_string(),
        other => {
            return Err(ApiError::invalid(format!(
                "value {} is not a string or a number: send {example}",
                crate::text::shown(&other.to_string())
            )))
        }
    };
    // The catalog checks the value (unit, range, choices) before anything is sent.
    d.param(&name)?.parse_value(&value).map_err(|e| {
        let e = crate::text::shown_max(&e.to_string(), 256);
        ApiError::invalid(format!("{name} = {:?}: {e}", crate::text::shown(&value)))
    })?;
    run_command(&gw, &id, Command::SetParam { name, value, eeprom }, &caller.actor()).await
}

/// The query string as keys and values, refusing keys not in `allowed` and repeated keys.
pub(crate) fn query(
    q: Result<Query<Vec<(String, String)>>, QueryRejection>,
    allowed: &[&str],
) -> Result<HashMap<String, String>, ApiError> {
    let Query(pairs) = q.map_err(|e| ApiError::bad_request(e.body_text()))?;
    let mut out = HashMap::new();
    for (k, v) in pairs {
        if !allowed.contains(&k.as_str()) {
            return Err(ApiError::bad_request(format!(
                "unknown query parameter {k:?}: this route takes {}",
                allowed.join(", ")
            )));
        }
        if out.insert(k.clone(), v).is_some() {
            return Err(ApiError::bad_request(format!("query parameter {k:?} is given twice")));
        }
    }
    Ok(out)
}

fn number<T: std::str::FromStr>(
    q: &HashMap<String, String>,
    key: &str,
    what: &str,
) -> Result<Option<T>, ApiError> {
    match q.get(key).map(|s| s.trim()) {
        None | Some("") => Ok(None),
        Some(s) => {
            s.parse().map(Some).map_err(|_| ApiError::bad_request(format!("{key}={s:?} is not {what}")))
        }
    }
}

const UNIX_MS: &str = "a time in unix milliseconds (e.g. 1700000000000)";

async fn from_store<T: Send + 'static>(
    gw: Arc<Gateway>,
    f: impl FnOnce(&drivebus_store::Store) -> Result<T, drivebus_store::StoreError> + Send + 'static,
) -> Result<T, ApiError> {
    if gw.store().is_none() {
        return Err(ApiError::no_store());
    }
    tokio::task::spawn_blocking(move || match gw.store() {
        Some(s) => f(s).map_err(|e| ApiError::internal(format!("the event store failed: {e}"))),
        None => Err(ApiError::no_store()),
    })
    .await
    .map_err(|e| ApiError::internal(format!("the event store reader failed: {e}")))?
}

/// `GET /api/events?since=&until=&after_id=&drive=&kind=&limit=` (times in unix ms).
pub async fn events(
    _: ReadAccess,
    State(gw): State<Arc<Gateway>>,
    q: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> ApiResult<Vec<Event>> {
    let q = query(q, &["since", "until", "after_id", "drive", "kind", "limit"])?;
    let limit = number::<usize>(&q, "limit", "a count")?.unwrap_or(DEFAULT_EVENT_LIMIT);
    if limit == 0 || limit > MAX_EVENT_LIMIT {
        return Err(ApiError::bad_request(format!("limit={limit}: give 1 to {MAX_EVENT_LIMIT}")));
    }
    let kind = match q.get("kind").map(|s| s.trim()).filter(|s| !s.is_empty()) {
        None => None,
        Some(k) => {
            Some(k.parse::<EventKind>().map_err(|e| ApiError::bad_request(format!("kind={k:?}: {e}")))?)
        }
    };
    let filter = EventFilter {
        since_ms: number(&q, "since", UNIX_MS)?,
        until_ms: number(&q, "until", UNIX_MS)?,
        after_id: number(&q, "after_id", "an event id")?,
        drive: q.get("drive").filter(|s| !s.is_empty()).cloned(),
        kind,
        limit,
    };
    if let (Some(s), Some(u)) = (filter.since_ms, filter.until_ms) {
        if s > u {
            return Err(ApiError::bad_request(format!("since={s} is after until={u}")));
        }
    }
    Ok(Json(from_store(gw, move |s| s.events(&filter)).await?))
}

/// `GET /api/drives/{id}/trend?since=&until=&resolution=1s|1m` (times in unix ms; the last
/// hour by default; `1s` up to an hour, `1m` beyond, unless given).
pub async fn trend(
    _: ReadAccess,
    State(gw): State<Arc<Gateway>>,
    Path(id): Path<String>,
    q: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> ApiResult<Vec<TrendPoint>> {
    gw.drive(&id)?;
    let q = query(q, &["since", "until", "resolution"])?;
    // Times a user gives may be anything an i64 holds: checked arithmetic only.
    let until_ms = number(&q, "until", UNIX_MS)?.unwrap_or_else(unix_ms);
    let since_ms = number(&q, "since", UNIX_MS)?.unwrap_or(until_ms.saturating_sub(DEFAULT_TREND_SPAN_MS));
    if since_ms > until_ms {
        return Err(ApiError::bad_request(format!("since={since_ms} is after until={until_ms}")));
    }
    let span = until_ms.checked_sub(since_ms).unwrap_or(i64::MAX);
    let resolution = match q.get("resolution").map(|s| s.trim()) {
        None | Some("") => Resolution::for_span(span),
        Some("1s") => Resolution::Second,
        Some("1m") => Resolution::Minute,
        Some(r) => return Err(ApiError::bad_request(format!("resolution={r:?}: use 1s or 1m"))),
    };
    let tq = TrendQuery { drive: id, since_ms, until_ms, resolution };
    Ok(Json(from_store(gw, move |s| s.trend(&tq)).await?))
}

/// The OpenAPI description (`GET /api/openapi.json`).
pub const OPENAPI: &str = include_str!("openapi.json");

/// `GET /api/openapi.json`: public, it holds no plant data.
pub async fn openapi() -> Result<([(axum::http::HeaderName, &'static str); 1], &'static str), ApiError> {
    Ok(([(axum::http::header::CONTENT_TYPE, "application/json")], OPENAPI))
}

/// 404 JSON for every path no route serves.
pub async fn fallback(uri: axum::http::Uri) -> ApiError {
    ApiError::not_found(uri.path())
}
