//! The publisher: hands the gateway's changes (drive refreshes, bus statistics, the audit
//! trail's events) to the OPC UA monitored items that watch them, and once a second every
//! drive's values again from the cache (values that go stale turn Uncertain even when no poll
//! comes). docs/opcua.md, "Values, timestamps and status", describes what a client sees.
//!
//! Changes are taken in batches: the first change after a quiet spell waits [`GATHER`] for the
//! ones that follow it, and everything that came by then is handed over under one hold of the
//! subscriptions' lock (one lock of each session per batch, not per change), each changed value
//! to its items in the order the changes came. The library looks at its subscriptions only
//! every 10 ms and publishes each at its publishing interval (20 ms at the least), so the wait
//! moves a notification by a few milliseconds at most, while a plant's polls (2000 a second for
//! 1000 drives at 500 ms) go over in a few hundred batches a second instead of one each. A
//! publisher that fell behind does not wait: it catches up in batches of up to [`MAX_BATCH`].
//! (With 20 clients of 6000 items each at a 20 ms publishing interval the wait saves about 3 %
//! of a core: docs/opcua.md, "Performance"; with one client no saving shows.)
//!
//! Values are made only while some monitored item watches any node, and compared with the last
//! ones before any node is looked up (without allocating): a value that only confirms the last
//! one is looked up only when some item's trigger includes the source timestamp. When the
//! publisher fell so far behind that the broadcast dropped changes for it
//! (`drivebus_opcua_changes_lagged_total`), it hands every drive and bus over from the cache as
//! soon as it has caught up, instead of leaving the missed values to the next second's sweep.

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

/// How long the first change after a quiet spell waits for others to go over with it.
pub const GATHER: Duration = Duration::from_millis(5);

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
    /// Whether any monitored item watches a Value at all: without one nothing is worth making.
    fn watched(&self) -> bool;
    /// Whether some monitored item is notified of a value that only confirms the last one (its
    /// trigger is the source timestamp too): without one, confirmations are not looked up.
    fn confirmations_wanted(&self) -> bool;
    /// Hands `fresh` to every enabled monitored item on the Value of node `(ns, path)` (a string
    /// node id); one that only confirms the last value, only to the items whose trigger is the
    /// source timestamp too.
    fn hand(&mut self, ns: u16, path: &str, fresh: &Fresh);
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
    fn watched(&self) -> bool {
        self.any_items()
    }

    fn confirmations_wanted(&self) -> bool {
        self.any_timestamp_items()
    }

    fn hand(&mut self, ns: u16, path: &str, fresh: &Fresh) {
        let Some(mut batch) = self.notify_for((ns, path), AttributeId::Value) else {
            return;
        };
        let Fresh { value: dv, confirms } = fresh;
        for (handle, entry) in batch.entries() {
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

/// What was last handed over (or, for a confirmation no item wanted, would have been) per drive
/// ([`DRIVE_VARIABLES`] order) and bus ([`BUS_VARIABLES`] order), kept while some item watches
/// any Value: a poll that neither changes nor confirms anything hands over nothing.
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
    /// StatusValueTimestamp, as the client asked. The values are compared with the last ones
    /// before any node is looked up: most polls confirm most values, and a confirmation no
    /// item wants costs no look-up.
    fn drive(&mut self, out: &mut dyn Handover, v: &DriveView, bus_online: bool, now: DateTime) {
        if !out.watched() {
            return;
        }
        let confirmations = out.confirmations_wanted();
        if !self.last.drives.contains_key(&v.id) {
            self.last.drives.insert(v.id.clone(), Vec::new());
        }
        let Some(before) = self.last.drives.get_mut(&v.id) else { return };
        // The standard variables, then the named values of a templated drive (`Values/<name>`,
        // in the view's order, which is its template's).
        before.resize(DRIVE_VARIABLES.len() + v.values.len(), None);
        let standard =
            drive_values(v, bus_online, now).into_iter().zip(DRIVE_VARIABLES.iter().map(|d| ("", d.name)));
        let named = if v.values.is_empty() {
            Vec::new()
        } else {
            named_values(v, v.values.keys().map(String::as_str), bus_online, now)
        };
        let named = named.into_iter().zip(v.values.keys().map(|name| ("Values/", name.as_str())));
        for (i, (dv, (folder, name))) in standard.chain(named).enumerate() {
            let Some(fresh) = before.get_mut(i).and_then(|b| changed(b, &dv)) else { continue };
            if fresh.confirms && !confirmations {
                continue;
            }
            self.path.clear();
            let _ = write!(self.path, "Drives/{}/{folder}{name}", v.id);
            out.hand(self.ids.ns, &self.path, &fresh);
        }
    }

    /// Hands the changed statistics of a bus to the monitored items that watch them.
    fn bus(&mut self, out: &mut dyn Handover, b: &BusView, now: DateTime) {
        if !out.watched() {
            return;
        }
        if !self.last.buses.contains_key(&b.name) {
            self.last.buses.insert(b.name.clone(), Vec::new());
        }
        let Some(before) = self.last.buses.get_mut(&b.name) else { return };
        before.resize(BUS_VARIABLES.len(), None);
        for ((value, def), before) in
            bus_values(b).into_iter().zip(BUS_VARIABLES.iter()).zip(before.iter_mut())
        {
            if before.as_ref() == Some(&value) {
                continue;
            }
            *before = Some(value.clone());
            self.path.clear();
            let _ = write!(self.path, "Buses/{}/{}", b.name, def.name);
            out.hand(self.ids.ns, &self.path, &Fresh::changed(DataValue::new_at(value, now)));
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
    // The last batch took every change that was waiting: the next first change gathers.
    let mut caught_up = true;
    loop {
        tokio::select! {
            first = changes.recv() => {
                if caught_up && first.is_ok() {
                    tokio::time::sleep(GATHER).await;
                }
                let mut next = first.map_err(|e| match e {
                    RecvError::Lagged(n) => TryRecvError::Lagged(n),
                    RecvError::Closed => TryRecvError::Closed,
                });
                caught_up = loop {
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
        /// When each batch that handed something over was handed, and how many values it had.
        batches: Mutex<Vec<(Instant, usize)>>,
    }

    impl Subscribers for Recorder {
        fn values(&self, f: &mut dyn FnMut(&mut dyn Handover)) {
            let mut batch = Vec::new();
            f(&mut (&self.watched, &mut batch));
            if !batch.is_empty() {
                self.batches.lock().unwrap().push((Instant::now(), batch.len()));
            }
            self.got.lock().unwrap().extend(batch);
        }
        fn event(&self, _: &BaseEventType, _: &[NodeId]) {}
    }

    impl Handover for (&Vec<String>, &mut Vec<(String, DataValue, Instant)>) {
        fn watched(&self) -> bool {
            !self.0.is_empty()
        }
        // The recorder's items are notified of every value (StatusValueTimestamp).
        fn confirmations_wanted(&self) -> bool {
            true
        }
        fn hand(&mut self, ns: u16, path: &str, fresh: &Fresh) {
            assert_eq!(ns, 2);
            if self.0.iter().any(|w| w == path) {
                self.1.push((path.to_string(), fresh.value.clone(), Instant::now()));
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

    /// Counts the nodes it was handed values for; says whether confirmations are wanted.
    struct Counter {
        confirmations: bool,
        handed: Vec<(String, bool)>,
    }

    impl Handover for Counter {
        fn watched(&self) -> bool {
            true
        }
        fn confirmations_wanted(&self) -> bool {
            self.confirmations
        }
        fn hand(&mut self, _: u16, path: &str, fresh: &Fresh) {
            self.handed.push((path.to_string(), fresh.confirms));
        }
    }

    /// A poll that only confirms a drive's values looks up no node unless some item wants
    /// confirmations; a changed value is looked up either way.
    #[tokio::test(start_paused = true)]
    async fn a_confirmation_no_item_wants_is_not_looked_up() {
        let text = "[store]\ndisabled = true\n\
            [[bus]]\nname = \"line\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 38400\n\
            [[bus.drive]]\nname = \"a\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 100\n";
        let gw = Gateway::start(crate::GatewayConfig::from_toml("t.toml", text).unwrap(), None).unwrap();
        let view = || gw.drive_view(&gw.drive("a").unwrap());
        until(|| view().last_seen_ms.is_some()).await;
        let first = view();
        let mut confirmed = first.clone();
        confirmed.last_seen_ms = first.last_seen_ms.map(|ms| ms + 500);
        let mut changed = confirmed.clone();
        changed.last_seen_ms = confirmed.last_seen_ms.map(|ms| ms + 500);
        changed.output_hz = Some(first.output_hz.unwrap_or(0.0) + 1.0);
        let now = DateTime::now();
        for wanted in [false, true] {
            let mut p = Publisher { ids: Ids { ns: 2 }, last: Last::default(), path: String::new() };
            let mut out = Counter { confirmations: wanted, handed: Vec::new() };
            p.drive(&mut out, &first, true, now);
            assert_eq!(out.handed.len(), DRIVE_VARIABLES.len(), "every first value is handed over");
            out.handed.clear();
            p.drive(&mut out, &confirmed, true, now);
            // The drive's own values are confirmed by the later poll; what the gateway knows of
            // it (online, age, source) is stamped with `now` and did not change.
            let from_drive =
                DRIVE_VARIABLES.iter().filter(|d| !super::super::GATEWAY_KNOWLEDGE.contains(&d.name)).count();
            assert!(out.handed.iter().all(|(_, confirms)| *confirms), "{:?}", out.handed);
            assert_eq!(
                out.handed.len(),
                if wanted { from_drive } else { 0 },
                "confirmations wanted: {wanted}"
            );
            out.handed.clear();
            p.drive(&mut out, &changed, true, now);
            assert!(out.handed.contains(&("Drives/a/OutputFrequency".into(), false)), "{:?}", out.handed);
        }
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
            batches: Mutex::default(),
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

        // Changes that come within GATHER of the first go over with it, in one batch, GATHER
        // after the first came; one that comes later goes in the next batch.
        let t = Instant::now();
        let batches = rec.batches.lock().unwrap().len();
        let ms = Duration::from_millis;
        assert!(ms(2) < GATHER && ms(8) > GATHER);
        tx.send(hz("a", 12.0)).unwrap();
        tokio::time::sleep(ms(2)).await;
        tx.send(hz("b", 21.0)).unwrap();
        tokio::time::sleep(ms(6)).await;
        tx.send(hz("a", 13.0)).unwrap();
        until(|| rec.handed(HZ_A, t).len() >= 2).await;
        let gathered: Vec<_> =
            rec.batches.lock().unwrap()[batches..].iter().map(|(at, n)| (*at - t, *n)).collect();
        assert_eq!(gathered, [(GATHER, 2), (ms(8) + GATHER, 1)], "(handed after, values)");

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
