//! The service's log on stderr, one line per message or event: plain text (what a person
//! reads, the default) or JSON (`--log-format json`, for log shippers reading the journal).
//!
//! Text: `drivebus serve: MQTT: broker 127.0.0.1:1883: ...` and events as
//! [`log_line`] writes them. JSON: one object per line,
//! `{"time": "...Z", "level": "info"|"warn", "message": "..."}`, and for an event the event's
//! fields (`kind`, `bus`, `drive`, `actor`, `action`, `result`, `detail`) beside them.

use std::sync::atomic::{AtomicBool, Ordering};

use drivebus_store::Event;
use serde_json::{json, Value};

static JSON: AtomicBool = AtomicBool::new(false);

/// How log lines are written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// One sentence per line.
    Text,
    /// One JSON object per line.
    Json,
}

impl std::str::FromStr for Format {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "text" => Ok(Format::Text),
            "json" => Ok(Format::Json),
            other => Err(format!("{other:?}: use text or json")),
        }
    }
}

/// Sets the format of every line from now on (the process's whole log).
pub fn set_format(f: Format) {
    JSON.store(f == Format::Json, Ordering::Relaxed);
}

fn now() -> String {
    drivebus_store::time::format_rfc3339(drivebus_store::time::now_ms())
}

/// Writes `line` and its newline to stderr in one write: `eprintln!` writes a line in pieces,
/// and a line must never be split by another writer of the same stderr (a JSON line would not
/// parse).
fn write_line(mut line: String) {
    use std::io::Write;
    line.push('\n');
    let _ = std::io::stderr().lock().write_all(line.as_bytes());
}

fn message(level: &str, msg: &str) {
    if JSON.load(Ordering::Relaxed) {
        write_line(json!({ "time": now(), "level": level, "message": msg }).to_string());
    } else {
        write_line(format!("drivebus serve: {msg}"));
    }
}

/// Something an operator may want to know (a reload applied, a broker back).
pub fn info(msg: &str) {
    message("info", msg);
}

/// Something that went wrong and that the service works around (a dropped message, a refused
/// reload, a failed accept).
pub fn warn(msg: &str) {
    message("warn", msg);
}

/// An event (trip, command, reload, ...) as one line.
pub fn event(e: &Event) {
    if JSON.load(Ordering::Relaxed) {
        let mut v = json!({
            "time": drivebus_store::time::format_rfc3339(e.time_ms),
            "level": "info",
            "message": log_line(e),
            "kind": e.kind.as_str(),
        });
        let o = v.as_object_mut().expect("an object");
        for (k, x) in [
            ("bus", &e.bus),
            ("drive", &e.drive),
            ("actor", &e.actor),
            ("action", &e.action),
            ("result", &e.result),
        ] {
            if let Some(x) = x {
                o.insert(k.into(), Value::String(x.clone()));
            }
        }
        if !e.detail.is_null() {
            o.insert("detail".into(), e.detail.clone());
        }
        write_line(v.to_string());
    } else {
        write_line(log_line(e));
    }
}

/// An event as one log line: `2026-11-22T00:06:01.123Z trip line-1/pump-1 {"code":3,...}`.
pub fn log_line(e: &Event) -> String {
    let mut line = format!("{} {}", drivebus_store::time::format_rfc3339(e.time_ms), e.kind.as_str());
    match (&e.bus, &e.drive) {
        (Some(b), Some(d)) => line.push_str(&format!(" {b}/{d}")),
        (Some(b), None) => line.push_str(&format!(" {b}")),
        (None, Some(d)) => line.push_str(&format!(" {d}")),
        (None, None) => {}
    }
    if let Some(a) = &e.action {
        line.push_str(&format!(" {a}"));
    }
    if let Some(who) = e.actor.as_deref().filter(|w| *w != "gateway") {
        line.push_str(&format!(" by {who}"));
    }
    if let Some(r) = &e.result {
        line.push_str(&format!(": {r}"));
    }
    if !e.detail.is_null() && e.detail.as_object().map_or(true, |o| !o.is_empty()) {
        line.push_str(&format!(" {}", e.detail));
    }
    line
}
