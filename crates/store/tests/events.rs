//! Events round trip through the file with every filter.

use drivebus_store::{Event, EventFilter, EventKind, Store};
use serde_json::json;

fn ev(time_ms: i64, kind: EventKind, drive: Option<&str>) -> Event {
    let mut e = Event::new(time_ms, kind);
    e.drive = drive.map(str::to_string);
    e
}

fn ids(events: &[Event]) -> Vec<i64> {
    events.iter().map(|e| e.id).collect()
}

#[test]
fn every_field_survives_reopening() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("drivebus.db");
    let full = Event {
        id: 999, // ignored
        time_ms: 1_795_255_200_123,
        kind: EventKind::Command,
        bus: Some("line-1".into()),
        drive: Some("pump-3".into()),
        actor: Some("http:ops@127.0.0.1".into()),
        action: Some("speed 40 Hz".into()),
        result: Some("refused: above F-max".into()),
        detail: json!({"old": {"hz": 30.5}, "new": null, "text": "ünïcode ✓"}),
    };
    let bare = Event::new(-5, EventKind::BusOffline);
    let (a, b) = {
        let store = Store::open(&path).unwrap();
        (store.record(&full).unwrap(), store.record(&bare).unwrap())
    };
    assert!(b > a && a > 0, "ids {a}, {b}");
    let store = Store::open_read_only(&path).unwrap();
    let got = store.events(&EventFilter::default()).unwrap();
    assert_eq!(got.len(), 2);
    assert_eq!(got[0], Event { id: a, ..full });
    assert_eq!(got[1], Event { id: b, ..bare });
}

#[test]
fn kinds_parse_and_print_as_stored() {
    for k in EventKind::ALL {
        assert_eq!(k.as_str().parse::<EventKind>(), Ok(k));
        assert_eq!(serde_json::to_value(k).unwrap(), json!(k.as_str()));
    }
    assert_eq!(EventKind::FaultReset.as_str(), "fault_reset");
    let e = "tripped".parse::<EventKind>().unwrap_err().to_string();
    assert!(e.contains("\"tripped\"") && e.contains("fault_reset"), "{e}");
}

#[test]
fn every_filter_narrows() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(&dir.path().join("s.db")).unwrap();
    // 30 events: times 1000, 1010, ..; drives a/b/c in turn; kinds cycle through all nine.
    let mut all = Vec::new();
    for i in 0..30i64 {
        let drive = ["a", "b", "c"][(i % 3) as usize];
        let kind = EventKind::ALL[(i % 9) as usize];
        let mut e = ev(1000 + 10 * i, kind, Some(drive));
        e.id = store.record(&e).unwrap();
        all.push(e);
    }
    let q = |f: EventFilter| store.events(&f).unwrap();
    let expect =
        |pred: &dyn Fn(&Event) -> bool| all.iter().filter(|e| pred(e)).map(|e| e.id).collect::<Vec<_>>();

    assert_eq!(q(EventFilter::default()), all);
    // since inclusive, until exclusive
    let got = q(EventFilter { since_ms: Some(1100), until_ms: Some(1200), ..Default::default() });
    assert_eq!(ids(&got), expect(&|e| (1100..1200).contains(&e.time_ms)));
    assert_eq!(got.len(), 10);
    assert_eq!(got.first().unwrap().time_ms, 1100);
    assert_eq!(got.last().unwrap().time_ms, 1190);
    // drive
    let got = q(EventFilter { drive: Some("b".into()), ..Default::default() });
    assert_eq!(ids(&got), expect(&|e| e.drive.as_deref() == Some("b")));
    assert_eq!(got.len(), 10);
    // kind
    let got = q(EventFilter { kind: Some(EventKind::Trip), ..Default::default() });
    assert_eq!(ids(&got), expect(&|e| e.kind == EventKind::Trip));
    assert_eq!(got.len(), 4);
    // kind and drive together
    let got =
        q(EventFilter { kind: Some(EventKind::Command), drive: Some("a".into()), ..Default::default() });
    assert_eq!(ids(&got), expect(&|e| e.kind == EventKind::Command && e.drive.as_deref() == Some("a")));
    // limit keeps the newest, in order
    let got = q(EventFilter { limit: 5, ..Default::default() });
    assert_eq!(ids(&got), ids(&all[25..]));
    // after_id pages forward from the oldest
    let got = q(EventFilter { after_id: Some(all[9].id), limit: 4, ..Default::default() });
    assert_eq!(ids(&got), ids(&all[10..14]));
    let got = q(EventFilter { after_id: Some(all[29].id), ..Default::default() });
    assert!(got.is_empty());
    // limit 0 gives nothing; nothing matching gives nothing
    assert!(q(EventFilter { limit: 0, ..Default::default() }).is_empty());
    assert!(q(EventFilter { drive: Some("zz".into()), ..Default::default() }).is_empty());
    assert!(q(EventFilter { since_ms: Some(5000), ..Default::default() }).is_empty());
}

#[test]
fn paging_with_after_id_sees_every_event_once() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(&dir.path().join("s.db")).unwrap();
    for i in 0..23 {
        store.record(&ev(i, EventKind::Online, None)).unwrap();
    }
    let mut seen = Vec::new();
    let mut last = 0;
    loop {
        let page =
            store.events(&EventFilter { after_id: Some(last), limit: 5, ..Default::default() }).unwrap();
        let Some(tail) = page.last() else { break };
        last = tail.id;
        seen.extend(page.iter().map(|e| e.time_ms));
    }
    assert_eq!(seen, (0..23).collect::<Vec<_>>());
}

#[test]
fn clones_share_one_store_across_threads() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(&dir.path().join("s.db")).unwrap();
    let handles: Vec<_> = (0..4)
        .map(|t| {
            let s = store.clone();
            std::thread::spawn(move || {
                (0..25)
                    .map(|i| s.record(&ev(t * 100 + i, EventKind::Command, None)).unwrap())
                    .collect::<Vec<_>>()
            })
        })
        .collect();
    let mut ids: Vec<i64> = handles.into_iter().flat_map(|h| h.join().unwrap()).collect();
    ids.sort_unstable();
    ids.dedup();
    assert_eq!(ids.len(), 100);
    assert_eq!(store.events(&EventFilter::default()).unwrap().len(), 100);
}

#[test]
fn read_only_store_refuses_writes() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.db");
    drop(Store::open(&path).unwrap());
    let ro = Store::open_read_only(&path).unwrap();
    assert!(ro.is_read_only());
    let e = ro.record(&ev(1, EventKind::Started, None)).unwrap_err().to_string();
    assert!(e.contains("read-only") && e.contains("s.db"), "{e}");
    assert!(ro.flush().is_err());
    assert!(ro.prune(0).is_err());
    ro.sample(drivebus_store::Sample {
        time_ms: 0,
        drive: "a".into(),
        output_hz: Some(1.0),
        current_a: None,
        setpoint_hz: None,
    });
    assert_eq!(ro.dropped_samples(), 1);
}

#[test]
fn a_batch_is_stored_in_order_with_its_ids() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(&dir.path().join("s.db")).unwrap();
    let first = store.record(&ev(1, EventKind::BusOffline, None)).unwrap();
    let batch: Vec<Event> = ["a", "b", "c"].iter().map(|d| ev(2, EventKind::Offline, Some(d))).collect();
    let new_ids = store.record_batch(&batch).unwrap();
    assert_eq!(new_ids, vec![first + 1, first + 2, first + 3]);
    let got = store.events(&EventFilter { kind: Some(EventKind::Offline), ..Default::default() }).unwrap();
    assert_eq!(got.iter().map(|e| e.drive.clone().unwrap()).collect::<Vec<_>>(), ["a", "b", "c"]);
    assert_eq!(ids(&got), new_ids);
    assert!(store.record_batch(&[]).unwrap().is_empty());
}
