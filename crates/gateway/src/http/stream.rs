//! `GET /api/stream`: the gateway's live changes as server-sent events. Each message's `event:`
//! is the change's type (`drive`, `event`, `bus`) and its `data:` the change as JSON. A client
//! too slow to keep up skips what it missed and is told with an `event: lagged` message whose
//! data is `{"type": "lagged", "skipped": N}`; the gateway never waits for it.

use std::convert::Infallible;
use std::sync::Arc;
use std::time::Duration;

use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, State};
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use futures_util::stream::{self, Stream};
use serde_json::json;
use tokio::sync::broadcast::error::RecvError;

use crate::core::{Change, Gateway};
use crate::http::auth::ReadAccess;
use crate::http::error::ApiError;

/// How often a keep-alive comment is sent when nothing changes.
pub const KEEP_ALIVE: Duration = Duration::from_secs(15);

/// The SSE event name of a change: its `type`.
pub fn change_type(c: &Change) -> &'static str {
    match c {
        Change::Drive(_) => "drive",
        Change::Event(_) => "event",
        Change::Bus(_) => "bus",
    }
}

/// Which changes a client wants: all, or those of one drive and its bus.
#[derive(Clone, Debug)]
struct Filter {
    drive: String,
    bus: String,
}

impl Filter {
    fn wants(&self, c: &Change) -> bool {
        match c {
            Change::Drive(v) => v.id == self.drive,
            Change::Event(e) => match &e.drive {
                Some(d) => *d == self.drive,
                None => e.bus.as_deref() == Some(self.bus.as_str()),
            },
            Change::Bus(b) => b.name == self.bus,
        }
    }
}

fn message(c: &Change) -> SseEvent {
    let data = serde_json::to_string(c)
        .unwrap_or_else(|e| json!({ "type": "error", "message": e.to_string() }).to_string());
    SseEvent::default().event(change_type(c)).data(data)
}

/// `GET /api/stream[?drive=<id>]`.
pub async fn stream(
    _: ReadAccess,
    State(gw): State<Arc<Gateway>>,
    q: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Sse<impl Stream<Item = Result<SseEvent, Infallible>>>, ApiError> {
    let Query(pairs) = q.map_err(|e| ApiError::bad_request(e.body_text()))?;
    let mut filter = None;
    for (k, v) in pairs {
        if k != "drive" {
            return Err(ApiError::bad_request(format!(
                "unknown query parameter {k:?}: this route takes drive"
            )));
        }
        let d = gw.drive(&v)?;
        filter = Some(Filter { drive: v, bus: d.bus.clone() });
    }
    let rx = gw.subscribe();
    let events = stream::unfold((rx, filter), |(mut rx, filter)| async move {
        loop {
            match rx.recv().await {
                Ok(c) if filter.as_ref().map_or(true, |f| f.wants(&c)) => {
                    return Some((Ok(message(&c)), (rx, filter)));
                }
                Ok(_) => continue,
                Err(RecvError::Lagged(n)) => {
                    let data = json!({ "type": "lagged", "skipped": n }).to_string();
                    return Some((Ok(SseEvent::default().event("lagged").data(data)), (rx, filter)));
                }
                Err(RecvError::Closed) => return None,
            }
        }
    });
    Ok(Sse::new(events).keep_alive(KeepAlive::new().interval(KEEP_ALIVE)))
}
