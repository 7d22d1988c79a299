//! Bad files give one clear line, not a panic; a reader works while a writer holds the file.

use std::path::Path;

use drivebus_store::{Event, EventFilter, EventKind, Resolution, Sample, Store, StoreError, TrendQuery};

fn one_line(e: &StoreError, needles: &[&str]) {
    let text = e.to_string();
    assert!(!text.contains('\n'), "{text}");
    for n in needles {
        assert!(text.contains(n), "missing {n:?} in {text:?}");
    }
}

#[test]
fn a_text_file_is_not_a_database() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("notes.db");
    std::fs::write(
        &path,
        "this is a text file, not a database, and it is long enough to have a header\n".repeat(20),
    )
    .unwrap();
    for e in [Store::open(&path).unwrap_err(), Store::open_read_only(&path).unwrap_err()] {
        assert!(matches!(e, StoreError::NotADatabase { .. }), "{e:?}");
        one_line(&e, &["notes.db", "not a drivebus event store", "give another file"]);
    }
    // and the file was left as it was
    assert!(std::fs::read_to_string(&path).unwrap().starts_with("this is a text file"));
}

#[test]
fn a_damaged_store_gives_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.db");
    {
        let store = Store::open(&path).unwrap();
        for i in 0..200 {
            let mut e = Event::new(i, EventKind::Command);
            e.action = Some("x".repeat(200));
            store.record(&e).unwrap();
        }
    }
    // Overwrite everything past the first page with garbage.
    let mut bytes = std::fs::read(&path).unwrap();
    assert!(bytes.len() > 8192, "{}", bytes.len());
    for (i, b) in bytes.iter_mut().enumerate().skip(4096) {
        *b = (i * 7 + 13) as u8;
    }
    std::fs::write(&path, &bytes).unwrap();
    // Either opening or reading fails, with an error that names the file; nothing panics.
    let result = Store::open_read_only(&path).and_then(|s| s.events(&EventFilter::default()));
    let e = result.expect_err("a damaged store reads as an error");
    one_line(&e, &["s.db"]);
}

#[test]
fn another_programs_database_is_foreign() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("other.db");
    {
        let conn = rusqlite_conn(&path);
        conn.execute_batch("CREATE TABLE customers (name TEXT); INSERT INTO customers VALUES ('x');")
            .unwrap();
    }
    for e in [Store::open(&path).unwrap_err(), Store::open_read_only(&path).unwrap_err()] {
        assert!(matches!(e, StoreError::Foreign { .. }), "{e:?}");
        one_line(&e, &["other.db", "something else"]);
    }
}

#[test]
fn a_newer_schema_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.db");
    drop(Store::open(&path).unwrap());
    rusqlite_conn(&path).execute_batch("PRAGMA user_version = 99").unwrap();
    let e = Store::open(&path).unwrap_err();
    assert!(matches!(e, StoreError::TooNew { found: 99, .. }), "{e:?}");
    one_line(&e, &["s.db", "99", "newer drivebus"]);
}

#[test]
fn missing_and_empty_files() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nothing.db");
    let e = Store::open_read_only(&missing).unwrap_err();
    assert!(matches!(e, StoreError::Missing { .. }), "{e:?}");
    one_line(&e, &["no event store at", "nothing.db", "--db FILE"]);
    assert!(!missing.exists(), "a read-only open must not create the file");

    let empty = dir.path().join("empty.db");
    std::fs::write(&empty, b"").unwrap();
    let e = Store::open_read_only(&empty).unwrap_err();
    one_line(&e, &["empty.db", "empty"]);
    // a writer adopts an empty file as a new store
    let store = Store::open(&empty).unwrap();
    assert_eq!(store.record(&Event::new(1, EventKind::Started)).unwrap(), 1);

    let e = Store::open(&dir.path().join("no/such/dir/s.db")).unwrap_err();
    one_line(&e, &["no/such/dir/s.db"]);
}

#[test]
fn reads_while_a_writer_holds_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.db");
    let writer = Store::open(&path).unwrap();
    for i in 0..10 {
        writer.record(&Event::new(i, EventKind::Online)).unwrap();
    }
    writer.sample(Sample {
        time_ms: 0,
        drive: "p".into(),
        output_hz: Some(5.0),
        current_a: None,
        setpoint_hz: None,
    });
    writer.flush().unwrap();

    // Another connection holds the write lock with an uncommitted event.
    let mut holder = rusqlite_conn(&path);
    let tx = holder.transaction_with_behavior(rusqlite::TransactionBehavior::Immediate).unwrap();
    tx.execute("INSERT INTO events (time_ms, kind) VALUES (99, 'trip')", []).unwrap();

    let reader = Store::open_read_only(&path).unwrap();
    let events = reader.events(&EventFilter::default()).unwrap();
    assert_eq!(events.len(), 10, "committed events only");
    assert!(events.iter().all(|e| e.kind == EventKind::Online));
    let trend = reader
        .trend(&TrendQuery { drive: "p".into(), since_ms: 0, until_ms: 1000, resolution: Resolution::Second })
        .unwrap();
    assert_eq!(trend.len(), 1);
    // The writer's own reads are not blocked either.
    assert_eq!(writer.events(&EventFilter::default()).unwrap().len(), 10);

    tx.commit().unwrap();
    let events = reader.events(&EventFilter::default()).unwrap();
    assert_eq!(events.len(), 11);
    assert_eq!(events[10].kind, EventKind::Trip);
    // and the writer goes on after the lock is released
    let id = writer.record(&Event::new(100, EventKind::Offline)).unwrap();
    assert_eq!(id, 12);
}

fn rusqlite_conn(path: &Path) -> rusqlite::Connection {
    rusqlite::Connection::open(path).unwrap()
}

#[test]
fn closing_the_last_handle_leaves_one_self_contained_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.db");
    {
        let store = Store::open(&path).unwrap();
        store.record(&Event::new(1, EventKind::Started)).unwrap();
    }
    assert!(!dir.path().join("s.db-wal").exists(), "the write-ahead log was checkpointed and removed");
    let copy = dir.path().join("copy.db");
    std::fs::copy(&path, &copy).unwrap();
    assert_eq!(Store::open_read_only(&copy).unwrap().events(&EventFilter::default()).unwrap().len(), 1);
}
