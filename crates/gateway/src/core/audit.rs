//! The audit trail: a command's record (committed `pending` before it is sent, its result
//! after), refused writes and failed logins (counted per client and reason, [`crate::refusals`]).

use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use drivebus_store::time::now_ms;
use drivebus_store::{Event, EventKind};
use serde_json::json;

use super::cache::DriveEntry;
use super::command::{Command, CommandError, MAX_MESSAGE_CHARS};
use super::gateway::Gateway;
use crate::log::log_line;
use crate::refusals::{Refused, Seen};

/// Failed logins from one address in a minute after which its requests with a token get 429
/// until the minute is over.
pub const MAX_LOGIN_FAILURES: u64 = 10;

impl Gateway {
    /// Commits `command`'s audit record with result `pending` before it is carried out: the
    /// event, with its id, to finish with [`Gateway::audit_done`]. Without a store there is
    /// nothing to commit (the event is made, not stored). When the store cannot commit it, the
    /// command is refused, logged and counted.
    pub(super) async fn audit_pending(
        self: &Arc<Self>,
        d: &DriveEntry,
        actor: &str,
        command: &Command,
    ) -> Result<Event, CommandError> {
        let mut event = Event {
            id: 0,
            time_ms: now_ms(),
            kind: EventKind::Command,
            bus: Some(d.bus.clone()),
            drive: Some(d.config.name.clone()),
            actor: Some(actor.to_string()),
            action: Some(command.action()),
            result: Some(drivebus_store::PENDING.to_string()),
            detail: json!({}),
        };
        let Some(store) = self.store.clone() else { return Ok(event) };
        let kept = event.clone();
        let stored = tokio::task::spawn_blocking(move || store.record(&kept).map_err(|e| e.to_string()))
            .await
            .unwrap_or_else(|e| Err(e.to_string()));
        match stored {
            Ok(id) => {
                event.id = id;
                Ok(event)
            }
            Err(e) => {
                self.counters.store_errors.fetch_add(1, Ordering::Relaxed);
                self.counters.commands_failed.fetch_add(1, Ordering::Relaxed);
                self.counters.commands_not_recorded.fetch_add(1, Ordering::Relaxed);
                let e = CommandError::NotRecorded(e);
                crate::log::warn(&format!("{} refused: {e}", log_line(&event)));
                Err(e)
            }
        }
    }

    /// Writes the `result` of a command recorded by [`Gateway::audit_pending`] and tells the
    /// log and live subscribers. A result that cannot be stored leaves the record `pending`,
    /// logged and counted.
    pub(super) async fn audit_done(self: &Arc<Self>, mut event: Event, result: String) {
        if let (Some(store), true) = (self.store.clone(), event.id != 0) {
            let (id, r) = (event.id, result.clone());
            let stored =
                tokio::task::spawn_blocking(move || store.set_result(id, &r).map_err(|e| e.to_string()))
                    .await
                    .unwrap_or_else(|e| Err(e.to_string()));
            if let Err(e) = stored {
                self.counters.store_errors.fetch_add(1, Ordering::Relaxed);
                crate::log::warn(&format!("result of event {id} not stored (it stays pending): {e}"));
            }
        }
        event.result = Some(result);
        self.announce(&event);
    }

    /// Puts a command in the audit trail: who, on which drive, what, and how it ended.
    pub(super) async fn audit(
        self: &Arc<Self>,
        bus: Option<String>,
        drive: &str,
        actor: &str,
        action: &str,
        result: String,
    ) {
        self.record_async(Event {
            id: 0,
            time_ms: now_ms(),
            kind: EventKind::Command,
            bus,
            drive: Some(drive.to_string()),
            actor: Some(actor.to_string()),
            action: Some(action.to_string()),
            result: Some(result),
            detail: json!({}),
        })
        .await;
    }

    /// Records a write that was refused before it became a command (a client not allowed to
    /// write, a read-only listener, a locked drive, a malformed MQTT command), so the audit
    /// trail shows every attempt. `why` starts with the reason's kind (`forbidden: ...`). The
    /// first refusal of a (client, reason) is written at once; repeats within a minute are
    /// counted and written as one event when the minute is over ([`crate::refusals`]).
    pub async fn audit_refusal(self: &Arc<Self>, id: &str, actor: &str, action: &str, why: &str) {
        self.counters.commands_failed.fetch_add(1, Ordering::Relaxed);
        self.refusal(Some(id), actor, action, why).await;
    }

    /// Records a refused login that names no drive (an OPC UA session beyond its user's cap, a
    /// wrong password) like a refusal: audited and logged, aggregated per actor and reason.
    pub async fn audit_login_refusal(self: &Arc<Self>, actor: &str, why: &str) {
        self.refusal(None, actor, "login", why).await;
    }

    /// Records a failed login (an unknown or malformed token) from `ip` like a refusal:
    /// audited and logged, aggregated per address ([`Gateway::login_blocked`] counts them).
    pub async fn login_failed(self: &Arc<Self>, ip: &str, why: &str) {
        self.refusal(None, &format!("http:{ip}"), "login", why).await;
    }

    /// Whether `ip` failed to log in [`MAX_LOGIN_FAILURES`] times in its current minute.
    pub fn login_blocked(&self, ip: &str) -> bool {
        let seen = self
            .refusals
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .seen(&format!("http:{ip}"), "unauthorized");
        seen >= MAX_LOGIN_FAILURES
    }

    async fn refusal(self: &Arc<Self>, id: Option<&str>, actor: &str, action: &str, why: &str) {
        let id = id.map(crate::text::shown);
        let why = crate::text::shown_max(why, MAX_MESSAGE_CHARS);
        let sample = Refused { drive: id.clone(), action: action.to_string(), why };
        let client = crate::refusals::client_of(actor);
        let seen = self.refusals.lock().unwrap_or_else(|p| p.into_inner()).refused(
            tokio::time::Instant::now(),
            &client,
            sample.clone(),
        );
        if seen == Seen::First {
            self.write_refusal(&sample, actor, sample.why.clone(), json!({})).await;
        }
    }

    /// A refusal (or a window's count of them) in the audit trail.
    async fn write_refusal(
        self: &Arc<Self>,
        r: &Refused,
        actor: &str,
        result: String,
        detail: serde_json::Value,
    ) {
        let bus = r.drive.as_deref().and_then(|d| self.drive(d).ok()).map(|d| d.bus.clone());
        self.record_async(Event {
            id: 0,
            time_ms: now_ms(),
            kind: EventKind::Command,
            bus,
            drive: r.drive.clone(),
            actor: Some(actor.to_string()),
            action: Some(r.action.clone()),
            result: Some(result),
            detail,
        })
        .await;
    }

    /// Writes the refusals counted over windows that closed: one event per client and reason.
    pub(super) async fn close_refusal_windows(self: Arc<Self>) {
        let mut tick = tokio::time::interval(Duration::from_secs(1));
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tick.tick().await;
            let due =
                self.refusals.lock().unwrap_or_else(|p| p.into_inner()).due(tokio::time::Instant::now());
            for s in due {
                let detail =
                    json!({ "repeated": s.count, "reason": s.reason, "window_s": s.window.as_secs() });
                self.write_refusal(&s.sample, &s.client, s.result(), detail).await;
            }
        }
    }
}
