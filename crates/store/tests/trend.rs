//! Trend downsampling and pruning on explicit (virtual) times.

use drivebus_store::{Resolution, Sample, Store, TrendQuery};

const MIN: i64 = 60_000;
const DAY: i64 = 86_400_000;
/// A round start time (a whole hour) one to two hours ago. The store's own thread prunes 1 s
/// buckets older than a day of wall-clock time, so a fixed date would age out of the tests.
fn t0() -> i64 {
    static T0: std::sync::OnceLock<i64> = std::sync::OnceLock::new();
    *T0.get_or_init(|| {
        let now = drivebus_store::time::now_ms();
        now - now.rem_euclid(3_600_000) - 3_600_000
    })
}

fn s(time_ms: i64, drive: &str, hz: Option<f64>, a: Option<f64>) -> Sample {
    Sample { time_ms, drive: drive.into(), output_hz: hz, current_a: a, setpoint_hz: hz.map(|h| h + 1.0) }
}

fn q(drive: &str, since_ms: i64, until_ms: i64, resolution: Resolution) -> TrendQuery {
    TrendQuery { drive: drive.into(), since_ms, until_ms, resolution }
}

#[test]
fn samples_in_one_second_are_averaged() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(&dir.path().join("t.db")).unwrap();
    store.sample(s(t0() + 100, "p1", Some(10.0), Some(2.0)));
    store.sample(s(t0() + 600, "p1", Some(20.0), None));
    store.sample(s(t0() + 999, "p1", Some(30.0), Some(4.0)));
    store.sample(s(t0() + 1000, "p1", None, Some(5.0)));
    store.sample(s(t0() + 1500, "p2", Some(99.0), Some(9.0)));
    store.flush().unwrap();
    let pts = store.trend(&q("p1", t0(), t0() + MIN, Resolution::Second)).unwrap();
    assert_eq!(pts.len(), 2, "{pts:?}");
    assert_eq!(pts[0].time_ms, t0());
    assert_eq!(pts[0].samples, 3);
    assert_eq!(pts[0].output_hz, Some(20.0));
    assert_eq!(pts[0].output_hz_min, Some(10.0));
    assert_eq!(pts[0].output_hz_max, Some(30.0));
    assert_eq!(pts[0].current_a, Some(3.0));
    assert_eq!(pts[0].setpoint_hz, Some(21.0));
    assert_eq!(pts[1].time_ms, t0() + 1000);
    assert_eq!(pts[1].output_hz, None);
    assert_eq!(pts[1].output_hz_min, None);
    assert_eq!(pts[1].current_a, Some(5.0));
    // the other drive is separate
    let p2 = store.trend(&q("p2", t0(), t0() + MIN, Resolution::Second)).unwrap();
    assert_eq!(p2.len(), 1);
    assert_eq!(p2[0].output_hz, Some(99.0));
}

#[test]
fn a_bucket_split_across_batches_averages_all_its_samples() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(&dir.path().join("t.db")).unwrap();
    store.sample(s(t0() + 10, "p", Some(10.0), None));
    store.flush().unwrap();
    store.sample(s(t0() + 20, "p", Some(40.0), None));
    store.sample(s(t0() + 30, "p", Some(f64::NAN), Some(f64::INFINITY)));
    store.flush().unwrap();
    let pts = store.trend(&q("p", t0(), t0() + 1000, Resolution::Second)).unwrap();
    assert_eq!(pts.len(), 1);
    assert_eq!(pts[0].samples, 3);
    assert_eq!(pts[0].output_hz, Some(25.0), "non-finite values are dropped");
    assert_eq!((pts[0].output_hz_min, pts[0].output_hz_max), (Some(10.0), Some(40.0)));
    assert_eq!(pts[0].current_a, None);
}

#[test]
fn minutes_keep_average_min_and_max() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(&dir.path().join("t.db")).unwrap();
    // Two minutes of one sample a second: minute 0 ramps 0..59 Hz, minute 1 is flat 50 Hz.
    for i in 0..60 {
        store.sample(s(t0() + i * 1000, "fan", Some(i as f64), Some(1.0)));
        store.sample(s(t0() + MIN + i * 1000, "fan", Some(50.0), Some(3.0)));
    }
    store.flush().unwrap();
    let secs = store.trend(&q("fan", t0(), t0() + 2 * MIN, Resolution::Second)).unwrap();
    assert_eq!(secs.len(), 120);
    assert!(secs.windows(2).all(|w| w[1].time_ms - w[0].time_ms == 1000));
    let mins = store.trend(&q("fan", t0() - MIN, t0() + 3 * MIN, Resolution::Minute)).unwrap();
    assert_eq!(mins.len(), 2, "{mins:?}");
    assert_eq!(mins[0].time_ms, t0());
    assert_eq!(mins[0].samples, 60);
    assert_eq!(mins[0].output_hz, Some(29.5));
    assert_eq!((mins[0].output_hz_min, mins[0].output_hz_max), (Some(0.0), Some(59.0)));
    assert_eq!(mins[0].current_a, Some(1.0));
    assert_eq!(mins[1].time_ms, t0() + MIN);
    assert_eq!(
        (mins[1].output_hz, mins[1].output_hz_min, mins[1].output_hz_max),
        (Some(50.0), Some(50.0), Some(50.0))
    );
    assert_eq!(mins[1].current_a, Some(3.0));
    // the query's range selects buckets by their start: since inclusive, until exclusive
    let one = store.trend(&q("fan", t0() + MIN, t0() + 2 * MIN, Resolution::Minute)).unwrap();
    assert_eq!(one.len(), 1);
    assert_eq!(one[0].time_ms, t0() + MIN);
    assert!(store.trend(&q("fan", t0() + 1, t0() + MIN, Resolution::Minute)).unwrap().is_empty());
}

#[test]
fn samples_before_1970_land_in_their_own_buckets() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(&dir.path().join("t.db")).unwrap();
    store.sample(s(-1, "p", Some(1.0), None));
    store.sample(s(0, "p", Some(2.0), None));
    store.flush().unwrap();
    let pts = store.trend(&q("p", -MIN, MIN, Resolution::Second)).unwrap();
    assert_eq!(pts.iter().map(|p| p.time_ms).collect::<Vec<_>>(), vec![-1000, 0]);
}

#[test]
fn prune_keeps_a_day_of_seconds_and_a_year_of_minutes() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(&dir.path().join("t.db")).unwrap();
    let now = t0() + 400 * DAY;
    let ages = [0, DAY - 1000, DAY + 1000, 2 * DAY, 364 * DAY, 366 * DAY];
    for age in ages {
        store.sample(s(now - age, "p", Some(1.0), None));
    }
    store.flush().unwrap();
    store.prune(now).unwrap();
    let kept = |res| {
        store
            .trend(&q("p", i64::MIN, i64::MAX, res))
            .unwrap()
            .iter()
            .map(|p| now - p.time_ms)
            .collect::<Vec<_>>()
    };
    // buckets are listed oldest first; ages are measured from each bucket's start
    assert_eq!(kept(Resolution::Second), vec![DAY - 1000, 0]);
    let minutes = kept(Resolution::Minute);
    assert_eq!(minutes.len(), 5, "{minutes:?}");
    assert!(minutes.iter().all(|&age| age <= 365 * DAY));
    // pruning again at the same time changes nothing; later, everything goes
    store.prune(now).unwrap();
    assert_eq!(kept(Resolution::Second).len(), 2);
    store.prune(now + 400 * DAY).unwrap();
    assert!(kept(Resolution::Second).is_empty() && kept(Resolution::Minute).is_empty());
}

#[test]
fn dropping_the_last_handle_writes_the_queue() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.db");
    {
        let store = Store::open(&path).unwrap();
        let clone = store.clone();
        drop(store);
        clone.sample(s(t0(), "p", Some(7.0), None));
    }
    let store = Store::open_read_only(&path).unwrap();
    let pts = store.trend(&q("p", t0(), t0() + 1000, Resolution::Second)).unwrap();
    assert_eq!(pts.len(), 1);
    assert_eq!(pts[0].output_hz, Some(7.0));
}

#[test]
fn the_background_thread_commits_without_flush() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.db");
    let store = Store::open(&path).unwrap();
    store.sample(s(t0(), "p", Some(7.0), None));
    let reader = Store::open_read_only(&path).unwrap();
    // Polls (no fixed sleep is asserted on): the thread commits at least once a second.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(30);
    loop {
        let pts = reader.trend(&q("p", t0(), t0() + 1000, Resolution::Second)).unwrap();
        if !pts.is_empty() {
            assert_eq!(pts[0].output_hz, Some(7.0));
            break;
        }
        assert!(std::time::Instant::now() < deadline, "samples never committed");
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    assert_eq!(store.take_background_error(), None);
}

#[test]
fn resolution_parses() {
    assert_eq!("1s".parse::<Resolution>(), Ok(Resolution::Second));
    assert_eq!("1m".parse::<Resolution>(), Ok(Resolution::Minute));
    let e = "5m".parse::<Resolution>().unwrap_err();
    assert!(e.contains("1s or 1m"), "{e}");
}
