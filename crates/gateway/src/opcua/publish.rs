//! The publisher: hands the gateway's changes (drive refreshes, bus statistics, the audit
//! trail's events) to the OPC UA monitored items that watch them, and once a second every
//! drive's values again from the cache (values that go stale turn Uncertain even when no poll
//! comes). docs/opcua.md, "Values, timestamps and status", describes what a client sees.
//!
//! Changes are taken in batches: every change waiting when the publisher wakes is handed over
//! under one hold of the subscriptions' lock (one lock of each session per batch, not per
//! change), each changed value to its items in the order the changes came. Nothing waits for a
//! batch to fill: a publisher that keeps up hands each change over as it comes, one that fell
//! behind catches up in few batches. A value is made only for a node some monitored item
//! watches, its node id looked up without allocating. When the publisher fell so far behind
//! that the broadcast dropped changes for it (`drivebus_opcua_changes_lagged_total`), it hands
//! every drive and bus over from the cache as soon as it has caught up, instead of leaving the
//! missed values to the next second's sweep.

use std::collections::HashMap;
use std::fmt::Write as _;
use std::sync::Arc;
use std::time::Duration;

use opcua::server::address_space::{BaseEventType, Event};
use opcua::server::notify::SubscriptionDataNotifier;
use opcua::server::SubscriptionCache;
use opcua::types::{
    AttributeId, ByteString, DataValue, DateTime, LocalizedText, NodeId, NumericRange, ObjectId, StatusCode,
    UAString, Variant,
};
use tokio::sync::broadcast::error::{RecvError, TryRecvError};
use tokio::sync::broadcast::Receiver;

use super::nodes::{Ids, BUS_VARIABLES, DRIVE_VARIABLES};
use super::{bus_online, bus_values, datetime_ms, drive_values, named_values};
use crate::core::{BusView, Change, DriveView, Gateway};

/// The most changes handed over under one hold of the subscriptions' lock (the broadcast's
/// capacity: a publisher that fell behind catches up in one batch).
pub const MAX_BATCH: usize = 1024;

/// How often every drive's values are handed over again from the cache.
pub const SWEEP_EVERY: Duration = Duration::from_secs(1);

/// Where the publisher hands values and events: the server's [`SubscriptionCache`] (or, in
/// tests, a recorder of what it was handed).
pub trait Subscribers: Send + Sync + 'static {
    /// Runs `f` with a [`Handover`] for one batch of values; they reach their monitored items
    /// when it returns.
    fn values(&self, f: &mut dyn FnMut(&mut dyn Handover));
    /// Raises `event` on each node of `sources`.
    fn event(&self, event: &BaseEventType, sources: &[NodeId]);
}

/// One batch of values on its way to the monitored items.
pub trait Handover {
    /// Hands the value `make` makes to every enabled monitored item on the Value of node
    /// `(ns, path)` (a string node id). `make` is called only when there is such an item, at
    /// most once; `None` hands nothing. A [`Fresh`] that only confirms the last value goes
    /// only to the items whose trigger is the source timestamp too.
    fn hand(&mut self, ns: u16, path: &str, make: &mut dyn FnMut() -> Option<Fresh>);
}

/// A value to hand over.
pub struct Fresh {
    /// The value.
    pub value: DataValue,
    /// Whether it differs from the value last handed over in its source timestamp alone: an
    /// item whose trigger is StatusValue (the default) or Status would not be notified of it.
    pub confirms: bool,
}

impl Fresh {
    /// A value that changed (or of which nothing was handed before).
    fn changed(value: DataValue) -> Self {
        Fresh { value, confirms: false }
    }
}

impl Subscribers for SubscriptionCache {
    fn values(&self, f: &mut dyn FnMut(&mut dyn Handover)) {
        let mut notifier = self.data_notifier();
        f(&mut notifier);
    }

    fn event(&self, event: &BaseEventType, sources: &[NodeId]) {
        self.notify_events(sources.iter().map(|s| (event as &dyn Event, s)));
    }
}

impl Handover for SubscriptionDataNotifier<'_> {
    fn hand(&mut self, ns: u16, path: &str, make: &mut dyn FnMut() -> Option<Fresh>) {
        let Some(mut batch) = self.notify_for((ns, path), AttributeId::Value) else {
            return;
        };
        let mut value = None;
        for (handle, entry) in batch.entries() {
            if value.is_none() {
                value = make();
            }
            let Some(Fresh { value: dv, confirms }) = &value else { return };
            // A confirmation reaches only the items it can notify: looking up every item only
            // for it to compare and drop the value was most of the cost of many clients.
            if *confirms && !entry.timestamp_changes {
                continue;
            }
            let dv = match entry.index_range {
                NumericRange::None => dv.clone(),
                // A range of a scalar: what the library answers for its own nodes.
                _ => DataValue { value: None, status: Some(StatusCode::BadIndexRangeNoData), ..dv.clone() },
            };
            batch.data_value_to_item(dv, handle);
        }
    }
}

/// What was last handed over for a node: value, status and source timestamp.
type Handed = (Variant, StatusCode, Option<DateTime>);

/// `dv` when it differs from what was last handed over (`before`, then updated): a value
/// that neither changed nor was confirmed is not handed over again; one only confirmed (a
/// later source timestamp alone) is marked so.
fn changed(before: &mut Option<Handed>, dv: &DataValue) -> Option<Fresh> {
    let handed = (dv.value.clone().unwrap_or_default(), dv.status(), dv.source_timestamp);
    if before.as_ref() == Some(&handed) {
        return None;
    }
    let confirms = before.as_ref().is_some_and(|b| b.0 == handed.0 && b.1 == handed.1);
    *before = Some(handed);
    Some(Fresh { value: dv.clone(), confirms })
}

/// What was last handed over per drive ([`DRIVE_VARIABLES`] order) and bus ([`BUS_VARIABLES`]
/// order), for the nodes some item watched: a poll that neither changes nor confirms anything
/// hands over nothing.
#[derive(Default)]
struct Last {
    drives: HashMap<String, Vec<Option<Handed>>>,
    buses: HashMap<String, Vec<Option<Variant>>>,
}

/// The publisher's state between batches.
struct Publisher {
    ids: Ids,
    last: Last,
    /// The node id being looked up (reused: no allocation per value).
    path: String,
}

impl Publisher {
    /// Hands a drive's changed and confirmed values to the monitored items that watch them. A
    /// value the poll only confirmed (same value and status, a later source timestamp) notifies
    /// nothing under the default trigger (StatusValue), and each confirming poll under
    /// StatusValueTimestamp, as the client asked.
    fn drive(&mut self, out: &mut dyn Handover, v: &DriveView, bus_online: bool, now: DateTime) {
        if !self.last.drives.contains_key(&v.id) {
            self.last.drives.insert(v.id.clone(), Vec::new());
        }
        let Some(before) = self.last.drives.get_mut(&v.id) else { return };
        // The standard variables, then the named values of a templated drive (`Values/<name>`,
        // in the view's order, which is its template's).
        before.resize(DRIVE_VARIABLES.len() + v.values.len(), None);
        let mut values: Option<Vec<DataValue>> = None;
        for (i, def) in DRIVE_VARIABLES.iter().enumerate() {
            self.path.clear();
            let _ = write!(self.path, "Drives/{}/{}", v.id, def.name);
            out.hand(self.ids.ns, &self.path, &mut || {
                let dv = values.get_or_insert_with(|| drive_values(v, bus_online, now)).get(i)?;
                changed(&mut before[i], dv)
            });
        }
        let mut named: Option<Vec<DataValue>> = None;
        for (k, name) in v.values.keys().enumerate() {
            let i = DRIVE_VARIABLES.len() + k;
            self.path.clear();
            let _ = write!(self.path, "Drives/{}/Values/{}", v.id, name);
            out.hand(self.ids.ns, &self.path, &mut || {
                let dv = named
                    .get_or_insert_with(|| {
                        named_values(v, v.values.keys().map(String::as_str), bus_online, now)
                    })
                    .get(k)?;
                changed(&mut before[i], dv)
            });
        }
    }

    /// Hands the changed statistics of a bus to the monitored items that watch them.
    fn bus(&mut self, out: &mut dyn Handover, b: &BusView, now: DateTime) {
        if !self.last.buses.contains_key(&b.name) {
            self.last.buses.insert(b.name.clone(), Vec::new());
        }
        let Some(before) = self.last.buses.get_mut(&b.name) else { return };
        before.resize(BUS_VARIABLES.len(), None);
        let mut values: Option<Vec<Variant>> = None;
        for (i, def) in BUS_VARIABLES.iter().enumerate() {
            self.path.clear();
            let _ = write!(self.path, "Buses/{}/{}", b.name, def.name);
            out.hand(self.ids.ns, &self.path, &mut || {
                let value = values.get_or_insert_with(|| bus_values(b)).get(i)?;
                if before[i].as_ref() == Some(value) {
                    return None;
                }
                before[i] = Some(value.clone());
                Some(Fresh::changed(DataValue::new_at(value.clone(), now)))
            });
        }
    }

    /// Hands every drive (and with `buses`, every bus) over again from the cache, forgetting
    /// the drives a reload removed.
    fn sweep(&mut self, out: &mut dyn Handover, gw: &Gateway, buses: bool, now: DateTime) {
        let drives = gw.drives();
        self.last.drives.retain(|name, _| drives.iter().any(|d| &d.config.name == name));
        for d in drives.iter() {
            let v = gw.drive_view(d);
            self.drive(out, &v, bus_online(gw, &v.bus), now);
        }
        if buses {
            let all = gw.buses();
            self.last.buses.retain(|name, _| all.iter().any(|b| &b.config.name == name));
            for b in all.iter() {
                self.bus(out, &gw.bus_view(b), now);
            }
        }
    }

    /// Hands `batch` over (emptying it) under one hold of the subscriptions, then, with
    /// `sweep`, every drive and bus from the cache (newer than any change of the batch); then
    /// raises the batch's events.
    fn hand<S: Subscribers + ?Sized>(
        &mut self,
        subs: &S,
        gw: &Gateway,
        batch: &mut Vec<Change>,
        sweep: bool,
    ) {
        let now = DateTime::now();
        let mut events = Vec::new();
        subs.values(&mut |out| {
            for c in batch.drain(..) {
                match c {
                    Change::Drive(v) => {
                        // A drive a reload removed: its nodes are gone.
                        if gw.drive(&v.id).is_ok() {
                            self.drive(out, &v, bus_online(gw, &v.bus), now);
                        }
                    }
                    Change::Bus(b) => self.bus(out, &b, now),
                    Change::Event(e) => events.push(e),
                }
            }
            if sweep {
                self.sweep(out, gw, true, now);
            }
        });
        for e in &events {
            raise(subs, &self.ids, gw, e);
        }
    }
}

/// Raises an event of the audit trail (trip, fault reset, online, offline, bus online or
/// offline) on its drive or bus object, its folder and the Server object.
fn raise<S: Subscribers + ?Sized>(subs: &S, ids: &Ids, gw: &Gateway, e: &drivebus_store::Event) {
    use drivebus_store::EventKind as K;
    let severity = match e.kind {
        K::Trip => 800,
        K::Offline | K::BusOffline => 600,
        K::FaultReset | K::Online | K::BusOnline => 300,
        _ => return,
    };
    let (source, name) = match (&e.drive, &e.bus) {
        (Some(d), _) if gw.drive(d).is_ok() => (ids.drive(d), d.clone()),
        (None, Some(b)) => (ids.bus(b), b.clone()),
        _ => return,
    };
    let event_id = ByteString::from(format!("{}-{}-{}", e.kind.as_str(), name, e.time_ms).into_bytes());
    let event = BaseEventType::new(
        opcua::types::ObjectTypeId::BaseEventType,
        event_id,
        LocalizedText::from(crate::core::log_line(e).as_str()),
        datetime_ms(e.time_ms),
    )
    .set_source_node(source.clone())
    .set_source_name(UAString::from(name.as_str()))
    .set_severity(severity);
    let folder = if e.drive.is_some() { ids.drives() } else { ids.buses() };
    subs.event(&event, &[source, folder, ObjectId::Server.into()]);
}

/// Keeps the subscriptions current from `changes` (the gateway's, [`Gateway::subscribe`]) until
/// the gateway is gone: each batch of drive refreshes and bus statistics as it comes, the audit
/// trail's events as OPC UA events, after a lag every drive and bus from the cache, and every
/// [`SWEEP_EVERY`] every drive's values (ages and staleness). Drives and buses a reload added or
/// removed need nothing here: the node manager makes nodes from the gateway's drives as they are
/// now.
pub async fn publish<S: Subscribers>(
    gw: Arc<Gateway>,
    ids: Ids,
    subs: Arc<S>,
    mut changes: Receiver<Change>,
) {
    let mut publisher = Publisher { ids, last: Last::default(), path: String::new() };
    let mut tick = tokio::time::interval(SWEEP_EVERY);
    let mut batch = Vec::new();
    // Changes were dropped for the publisher: sweep once it has caught up (the changes still
    // waiting are older than the cache).
    let mut behind = false;
    loop {
        tokio::select! {
            first = changes.recv() => {
                let mut next = first.map_err(|e| match e {
                    RecvError::Lagged(n) => TryRecvError::Lagged(n),
                    RecvError::Closed => TryRecvError::Closed,
                });
                let caught_up = loop {
                    match next {
                        Ok(c) => batch.push(c),
                        Err(TryRecvError::Lagged(n)) => {
                            crate::metrics::front_ends(&gw).opcua_lagged(n);
                            behind = true;
                        }
                        Err(TryRecvError::Empty) => break true,
                        Err(TryRecvError::Closed) => {
                            publisher.hand(&*subs, &gw, &mut batch, false);
                            return;
                        }
                    }
                    if batch.len() >= MAX_BATCH {
                        break false;
                    }
                    next = changes.try_recv();
                };
                let sweep = behind && caught_up;
                publisher.hand(&*subs, &gw, &mut batch, sweep);
                behind &= !sweep;
            }
            _ = tick.tick() => {
                let now = DateTime::now();
                subs.values(&mut |out| publisher.sweep(out, &gw, false, now));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;
    use tokio::sync::broadcast;
    use tokio::time::Instant;

    /// Monitored items on some nodes' values: records what each was handed, and when.
    struct Recorder {
        watched: Vec<String>,
        got: Mutex<Vec<(String, DataValue, Instant)>>,
    }

    impl Subscribers for Recorder {
        fn values(&self, f: &mut dyn FnMut(&mut dyn Handover)) {
            let mut batch = Vec::new();
            f(&mut (&self.watched, &mut batch));
            self.got.lock().unwrap().extend(batch);
        }
        fn event(&self, _: &BaseEventType, _: &[NodeId]) {}
    }

    impl Handover for (&Vec<String>, &mut Vec<(String, DataValue, Instant)>) {
        fn hand(&mut self, ns: u16, path: &str, make: &mut dyn FnMut() -> Option<Fresh>) {
            assert_eq!(ns, 2);
            if self.0.iter().any(|w| w == path) {
                if let Some(v) = make() {
                    self.1.push((path.to_string(), v.value, Instant::now()));
                }
            }
        }
    }

    impl Recorder {
        /// The values handed to `path`'s items since `since`, as doubles, with their times.
        fn handed(&self, path: &str, since: Instant) -> Vec<(Option<f64>, Instant)> {
            let got = self.got.lock().unwrap();
            let double = |v: &DataValue| match v.value {
                Some(Variant::Double(x)) => Some(x),
                _ => None,
            };
            got.iter().filter(|(p, _, t)| p == path && *t >= since).map(|(_, v, t)| (double(v), *t)).collect()
        }
    }

    /// Waits (virtual time, generously) until `ready` holds.
    async fn until(mut ready: impl FnMut() -> bool) {
        for _ in 0..600 {
            if ready() {
                return;
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        panic!("not within 6 s");
    }

    /// A value whose source timestamp alone moved is marked a confirmation (handed only to
    /// items whose trigger includes the timestamp); a change of value or status, and the first
    /// value, are not.
    #[test]
    fn a_later_timestamp_alone_is_a_confirmation() {
        // ms milliseconds after 1601 (a DateTime counts 100 ns ticks).
        let at = |ms: i64| Some(DateTime::from(ms * 10_000));
        let dv = |x: f64, status: StatusCode, ms: i64| DataValue {
            value: Some(Variant::Double(x)),
            status: Some(status),
            source_timestamp: at(ms),
            ..DataValue::default()
        };
        let mut before = None;
        let confirms = |before: &mut Option<Handed>, v: DataValue| changed(before, &v).map(|f| f.confirms);
        assert_eq!(confirms(&mut before, dv(1.0, StatusCode::Good, 1000)), Some(false), "the first value");
        assert_eq!(confirms(&mut before, dv(1.0, StatusCode::Good, 1000)), None, "nothing new");
        assert_eq!(
            confirms(&mut before, dv(1.0, StatusCode::Good, 1500)),
            Some(true),
            "a later poll, same value"
        );
        assert_eq!(confirms(&mut before, dv(2.0, StatusCode::Good, 2000)), Some(false), "a new value");
        assert_eq!(
            confirms(&mut before, dv(2.0, StatusCode::UncertainLastUsableValue, 2000)),
            Some(false),
            "a new status"
        );
        assert_eq!(
            confirms(&mut before, dv(2.0, StatusCode::UncertainLastUsableValue, 2500)),
            Some(true),
            "a later timestamp, same value and status"
        );
    }

    const HZ_A: &str = "Drives/a/OutputFrequency";
    const HZ_B: &str = "Drives/b/OutputFrequency";

    #[tokio::test(start_paused = true)]
    async fn a_batch_hands_every_changed_value_and_a_missed_change_arrives_without_waiting_for_the_sweep() {
        let text = "[store]\ndisabled = true\n\
            [[bus]]\nname = \"line\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 38400\n\
            [[bus.drive]]\nname = \"a\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 100\n\
            [[bus.drive]]\nname = \"b\"\nfamily = \"generic\"\naddress = 2\npoll_ms = 100\n";
        let gw = Gateway::start(crate::GatewayConfig::from_toml("t.toml", text).unwrap(), None).unwrap();
        let view = |id: &str| gw.drive_view(&gw.drive(id).unwrap());
        until(|| view("a").last_seen_ms.is_some() && view("b").last_seen_ms.is_some()).await;

        let rec = Arc::new(Recorder {
            watched: vec![HZ_A.into(), HZ_B.into(), "Buses/line/Online".into()],
            got: Mutex::default(),
        });
        // A broadcast of 4 changes: the test decides when the publisher falls behind.
        let (tx, rx) = broadcast::channel(4);
        tokio::spawn(publish(gw.clone(), Ids { ns: 2 }, rec.clone(), rx));
        let start = Instant::now();
        until(|| !rec.handed(HZ_A, start).is_empty() && !rec.handed(HZ_B, start).is_empty()).await;

        // Right after a sweep, so the next one is most of a second away.
        tokio::time::sleep_until(start + SWEEP_EVERY + Duration::from_millis(10)).await;
        // Three changes sent at once are one batch: each changed value reaches its items, in
        // the order of the changes, none folded into a later one.
        let hz = |id: &str, hz: f64| {
            let mut v = view(id);
            v.output_hz = Some(hz);
            Change::Drive(v)
        };
        let t = Instant::now();
        for c in [hz("a", 10.0), hz("b", 20.0), hz("a", 11.0)] {
            tx.send(c).unwrap();
        }
        until(|| rec.handed(HZ_A, t).len() >= 2).await;
        let a: Vec<_> = rec.handed(HZ_A, t).into_iter().map(|(v, _)| v).collect();
        assert_eq!(a, [Some(10.0), Some(11.0)]);
        assert_eq!(rec.handed(HZ_B, t).iter().map(|(v, _)| *v).collect::<Vec<_>>(), [Some(20.0)]);

        // Then b changes and six changes of a follow before the publisher runs: the broadcast
        // keeps the last four, b's change is dropped for the publisher, and b's items hold 20
        // while the cache says otherwise. The publisher must bring b's value from the cache at
        // once, not at the next sweep.
        let lagged = crate::metrics::front_ends(&gw).opcua_changes_lagged();
        let t = Instant::now();
        tx.send(hz("b", 30.0)).unwrap();
        for i in 0..6 {
            tx.send(hz("a", 40.0 + f64::from(i))).unwrap();
        }
        until(|| !rec.handed(HZ_B, t).is_empty()).await;
        let (b, when) = rec.handed(HZ_B, t)[0];
        assert!(
            when - t < Duration::from_millis(100),
            "b's missed change reached its item {:?} after it was missed (the sweep's wait)",
            when - t
        );
        assert_eq!(b, view("b").output_hz, "b's value from the cache");
        assert_eq!(crate::metrics::front_ends(&gw).opcua_changes_lagged() - lagged, 3, "3 changes dropped");
        // The four changes kept still reach a's items, then the cache's value.
        let a: Vec<_> = rec.handed(HZ_A, t).into_iter().map(|(v, _)| v).collect();
        assert_eq!(a[..4], [Some(42.0), Some(43.0), Some(44.0), Some(45.0)], "{a:?}");
        assert_eq!(a.get(4).copied(), Some(view("a").output_hz), "{a:?}");
    }
}
