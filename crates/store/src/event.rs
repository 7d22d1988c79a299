//! Events: the audit trail of commands and the record of trips, fault resets and links coming
//! and going.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// One thing that happened, as stored. [`Store::record`](crate::Store::record) ignores `id` and
/// returns the id it was given.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Event {
    /// The store's id: increasing in the order events were committed; 0 before it is stored.
    pub id: i64,
    /// When it happened: unix time in milliseconds.
    pub time_ms: i64,
    /// What kind of event.
    pub kind: EventKind,
    /// The bus it happened on, if any.
    pub bus: Option<String>,
    /// The drive's id (name) in the gateway, if it is about one drive.
    pub drive: Option<String>,
    /// Who: `"http:token-name@127.0.0.1"`, `"modbus:127.0.0.1:5555"`, `"mqtt"`, `"linkage"`,
    /// `"gateway"`.
    pub actor: Option<String>,
    /// For commands, what was asked: `"run"`, `"stop"`, `"speed 40 Hz"`, `"param 4-14 = 50"`.
    pub action: Option<String>,
    /// How it ended: `"ok"`, `"refused: ..."`, `"timeout: ..."`, `"locked"`.
    pub result: Option<String>,
    /// Free JSON: fault code and text, old and new state. `null` when there is nothing more.
    #[serde(default)]
    pub detail: serde_json::Value,
}

impl Event {
    /// An event of `kind` at `time_ms` with every optional field empty and `detail` null.
    pub fn new(time_ms: i64, kind: EventKind) -> Event {
        Event {
            id: 0,
            time_ms,
            kind,
            bus: None,
            drive: None,
            actor: None,
            action: None,
            result: None,
            detail: serde_json::Value::Null,
        }
    }
}

/// The kinds of events. Stored and printed as the snake_case names of [`EventKind::as_str`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EventKind {
    /// A command from someone (HTTP, Modbus TCP, MQTT, linkage): the audit trail.
    Command,
    /// A drive tripped (faulted).
    Trip,
    /// A fault was reset.
    FaultReset,
    /// A drive answered again.
    Online,
    /// A drive stopped answering.
    Offline,
    /// A bus (its port) came back.
    BusOnline,
    /// A bus (its port) went away.
    BusOffline,
    /// The gateway started.
    Started,
    /// The gateway stopped.
    Stopped,
    /// The configuration was reloaded (or a reload was refused: see the result).
    Reload,
    /// The gateway took a bus's line over from another gateway that fell silent (`[standby]`).
    Takeover,
    /// The gateway heard another gateway master a bus and stopped sending on it.
    Yield,
}

impl EventKind {
    /// Every kind, in declaration order.
    pub const ALL: [EventKind; 12] = [
        EventKind::Command,
        EventKind::Trip,
        EventKind::FaultReset,
        EventKind::Online,
        EventKind::Offline,
        EventKind::BusOnline,
        EventKind::BusOffline,
        EventKind::Started,
        EventKind::Stopped,
        EventKind::Reload,
        EventKind::Takeover,
        EventKind::Yield,
    ];

    /// The name stored and printed: `"command"`, `"trip"`, `"fault_reset"`, `"online"`,
    /// `"offline"`, `"bus_online"`, `"bus_offline"`, `"started"`, `"stopped"`, `"reload"`,
    /// `"takeover"`, `"yield"`.
    pub fn as_str(self) -> &'static str {
        match self {
            EventKind::Command => "command",
            EventKind::Trip => "trip",
            EventKind::FaultReset => "fault_reset",
            EventKind::Online => "online",
            EventKind::Offline => "offline",
            EventKind::BusOnline => "bus_online",
            EventKind::BusOffline => "bus_offline",
            EventKind::Started => "started",
            EventKind::Stopped => "stopped",
            EventKind::Reload => "reload",
            EventKind::Takeover => "takeover",
            EventKind::Yield => "yield",
        }
    }
}

impl fmt::Display for EventKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The error of parsing an [`EventKind`]: one line listing the kinds.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UnknownKind(pub String);

impl fmt::Display for UnknownKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let names: Vec<&str> = EventKind::ALL.iter().map(|k| k.as_str()).collect();
        write!(f, "unknown event kind {:?}: give one of {}", self.0, names.join(", "))
    }
}

impl std::error::Error for UnknownKind {}

impl FromStr for EventKind {
    type Err = UnknownKind;

    fn from_str(s: &str) -> Result<EventKind, UnknownKind> {
        EventKind::ALL.into_iter().find(|k| k.as_str() == s).ok_or_else(|| UnknownKind(s.to_string()))
    }
}

/// Which events [`Store::events`](crate::Store::events) returns. Every field given narrows the
/// result; the default is the newest 1000 events of every kind.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct EventFilter {
    /// Only events with `time_ms >= since_ms`.
    pub since_ms: Option<i64>,
    /// Only events with `time_ms < until_ms`.
    pub until_ms: Option<i64>,
    /// Only events with `id > after_id`. With it set, the result is the *oldest* `limit` events
    /// after that id, so a reader pages forward by passing the last id it saw.
    pub after_id: Option<i64>,
    /// Only events about this drive.
    pub drive: Option<String>,
    /// Only events of this kind.
    pub kind: Option<EventKind>,
    /// At most this many events (0 gives none). Without `after_id` these are the newest ones.
    /// The result is always in id order, newest last.
    pub limit: usize,
}

impl Default for EventFilter {
    fn default() -> EventFilter {
        EventFilter { since_ms: None, until_ms: None, after_id: None, drive: None, kind: None, limit: 1000 }
    }
}
