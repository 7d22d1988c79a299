//! Events: what the cache learns from a poll ([`Gateway::update`]: values and their age,
//! online/offline, trips and resets, trend samples) and every event on its way to the store,
//! the log and live subscribers ([`Gateway::record`]).

use std::sync::atomic::Ordering;
use std::sync::Arc;

use drivebus_drive::profile::DriveStatus;
use drivebus_link::drive::Error as LinkError;
use drivebus_link::owner::BusError;
use drivebus_store::time::now_ms;
use drivebus_store::{Event, EventKind, Sample};
use serde_json::json;

use super::cache::{BusEntry, DriveEntry};
use super::gateway::Gateway;
use super::views::Change;
use crate::log::log_line;

impl Gateway {
    /// Appends an event to the store (waiting for the commit) and tells live subscribers.
    /// Returns the stored event (with its id), or the event unstored when the store failed.
    pub fn record(&self, mut event: Event) -> Event {
        if let Some(store) = &self.store {
            match store.record(&event) {
                Ok(id) => event.id = id,
                Err(e) => {
                    self.counters.store_errors.fetch_add(1, Ordering::Relaxed);
                    crate::log::warn(&format!("event not stored: {e}"));
                }
            }
        }
        self.announce(&event);
        event
    }

    /// Tells the log (when on) and live subscribers about an event.
    pub(super) fn announce(&self, event: &Event) {
        if self.log_events.load(Ordering::Relaxed) {
            crate::log::event(event);
        }
        let _ = self.changes.send(Change::Event(event.clone()));
    }

    /// Prints every event as one line on stderr (what `drivebus serve` does).
    pub fn log_events(&self, on: bool) {
        self.log_events.store(on, Ordering::Relaxed);
    }

    /// [`Gateway::record`] off the async workers (the store commits on disk).
    pub(super) async fn record_async(self: &Arc<Self>, event: Event) -> Event {
        let gw = self.clone();
        let kept = event.clone();
        match tokio::task::spawn_blocking(move || gw.record(event)).await {
            Ok(e) => e,
            // The runtime is shutting down: the event is not stored, say so rather than panic.
            Err(e) => {
                self.counters.store_errors.fetch_add(1, Ordering::Relaxed);
                crate::log::warn(&format!("event not stored ({e}): {}", log_line(&kept)));
                kept
            }
        }
    }

    /// Puts a poll's (or a refresh's) `result` for drive `d` of `bus` in the cache: values and
    /// their age, online/offline, trips and resets as events, a trend sample; then tells live
    /// subscribers and applies the linkage the drive leads.
    pub(super) async fn update(
        self: &Arc<Self>,
        bus: &BusEntry,
        d: &Arc<DriveEntry>,
        result: Result<DriveStatus, LinkError>,
    ) {
        let now_ms = now_ms();
        let mut events = Vec::new();
        let event = |kind, detail| Event {
            id: 0,
            time_ms: now_ms,
            kind,
            bus: Some(d.bus.clone()),
            drive: Some(d.config.name.clone()),
            actor: Some("gateway".into()),
            action: None,
            result: None,
            detail,
        };
        let link_down = matches!(&result, Err(LinkError::Bus(BusError::Link(_))));
        if link_down && bus.online.swap(false, Ordering::Relaxed) {
            let why = match &result {
                Err(e) => e.to_string(),
                Ok(_) => String::new(),
            };
            events.push(Event { drive: None, ..event(EventKind::BusOffline, json!({ "error": why })) });
        }
        if result.is_ok() && !bus.online.swap(true, Ordering::Relaxed) {
            events.push(Event { drive: None, ..event(EventKind::BusOnline, json!({})) });
        }
        let mut linked = None;
        {
            let mut s = d.state.write().unwrap_or_else(|p| p.into_inner());
            s.polls += 1;
            let was_online = s.online;
            match result {
                Ok(status) => {
                    let old_fault = s.status.as_ref().and_then(|x| x.fault.clone());
                    match (&old_fault, &status.fault) {
                        (None, Some(f)) => {
                            let before = s.status.as_ref();
                            let detail =
                                crate::trip::trip_detail(f, before, s.updated_ms, s.commanded_hz, &status);
                            events.push(event(EventKind::Trip, detail));
                        }
                        (Some(f), None) => {
                            events.push(event(
                                EventKind::FaultReset,
                                json!({ "code": f.code, "text": f.text }),
                            ));
                        }
                        _ => {}
                    }
                    if was_online == Some(false) {
                        events.push(event(EventKind::Online, json!({})));
                    }
                    if let Some(store) = &self.store {
                        store.sample(Sample {
                            time_ms: now_ms,
                            drive: d.config.name.clone(),
                            output_hz: status.output_hz,
                            current_a: status.current_a,
                            setpoint_hz: status.setpoint_hz.or(s.commanded_hz),
                        });
                    }
                    linked = status.output_hz;
                    s.status = Some(status);
                    s.updated = Some(std::time::Instant::now());
                    s.updated_ms = Some(now_ms);
                    s.online = Some(true);
                    s.last_error = None;
                }
                Err(e) => {
                    s.poll_errors += 1;
                    s.last_error = Some(e.to_string());
                    // A drive the bus owner still counts as online had one bad poll; offline is
                    // the owner's verdict after several in a row (or a dead port).
                    let health_online = bus.bus.health().get(&d.config.address).map_or(true, |h| h.online);
                    if !health_online || link_down {
                        if was_online != Some(false) {
                            events.push(event(EventKind::Offline, json!({ "error": e.to_string() })));
                        }
                        s.online = Some(false);
                    }
                }
            }
        }
        for e in events {
            self.record_async(e).await;
        }
        let _ = self.changes.send(Change::Drive(self.drive_view(d)));
        if let Some(hz) = linked {
            self.follow(d, hz);
        }
    }
}
