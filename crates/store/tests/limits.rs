//! Retention and the size cap (issue 13, defect 5): the store deletes events past the
//! retention and, beyond the cap, the oldest events and trend buckets first; at open and on
//! every call of `enforce_limits` (the background thread's periodic check).

use std::time::Duration;

use drivebus_store::{Event, EventFilter, EventKind, Limits, Sample, Store};
use serde_json::json;

const DAY_MS: i64 = 86_400_000;
const NOW: i64 = 1_795_255_200_000;

fn event(time_ms: i64, text: &str) -> Event {
    let mut e = Event::new(time_ms, EventKind::Command);
    e.actor = Some("modbus:127.0.0.2".into());
    e.detail = json!({ "pad": text });
    e
}

fn all(store: &Store) -> Vec<Event> {
    store.events(&EventFilter { limit: 1_000_000, ..Default::default() }).unwrap()
}

#[test]
fn events_past_the_retention_are_deleted() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("drivebus.db");
    let limits = Limits { retention: Some(Duration::from_secs(30 * 86_400)), max_bytes: None };
    let store = Store::open_with_limits(&path, limits).unwrap();
    let now = drivebus_store::time::now_ms();
    for days_ago in [400, 31, 29, 1, 0] {
        store.record(&event(now - days_ago * DAY_MS, "")).unwrap();
    }
    store.enforce_limits(now).unwrap();
    let left: Vec<i64> = all(&store).iter().map(|e| (now - e.time_ms) / DAY_MS).collect();
    assert_eq!(left, [29, 1, 0]);
    assert_eq!(Limits::from_days_and_mb(30, 0), limits);
    assert_eq!(Limits::from_days_and_mb(0, 0), Limits::NONE);
}

#[test]
fn the_size_cap_deletes_the_oldest_events_and_buckets_first() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("drivebus.db");
    let pad = "x".repeat(1000);
    {
        // Written without limits: 4 000 events of ~1 KB over 40 days and a day of trends.
        let store = Store::open(&path).unwrap();
        let batch: Vec<Event> =
            (0..4000).map(|k| event(NOW - 40 * DAY_MS + k * DAY_MS / 100, &pad)).collect();
        store.record_batch(&batch).unwrap();
        for k in 0..3600 {
            store.sample(Sample {
                time_ms: NOW - DAY_MS + k * 1000,
                drive: "pump-1".into(),
                output_hz: Some(40.0),
                current_a: Some(3.0),
                setpoint_hz: Some(40.0),
            });
        }
        store.flush().unwrap();
        assert!(store.used_bytes().unwrap() > 4 << 20, "{}", store.used_bytes().unwrap());
    }
    // Opened again with a 1 MiB cap: enforced before the store is used.
    let cap = 1 << 20;
    let store = Store::open_with_limits(&path, Limits { retention: None, max_bytes: Some(cap) }).unwrap();
    assert!(store.used_bytes().unwrap() <= cap, "the cap was not enforced at open");
    let left = all(&store);
    assert!(!left.is_empty() && left.len() < 1000, "{} events left", left.len());
    // The newest are kept, the oldest gone.
    assert_eq!(left.last().unwrap().time_ms, NOW - 40 * DAY_MS + 3999 * DAY_MS / 100);
    let oldest_left = left[0].time_ms;
    assert!(left.windows(2).all(|w| w[0].time_ms <= w[1].time_ms));
    // More events: the next check deletes the oldest again, the file stays under the cap.
    let batch: Vec<Event> = (0..2000).map(|k| event(NOW + k, &pad)).collect();
    store.record_batch(&batch).unwrap();
    assert!(store.used_bytes().unwrap() > cap);
    let done = store.enforce_limits(NOW + 2000).unwrap();
    assert!(done.events > 0, "{done:?}");
    assert!(store.used_bytes().unwrap() <= cap);
    assert!(all(&store)[0].time_ms > oldest_left);
    assert_eq!(all(&store).last().unwrap().time_ms, NOW + 1999);
}
