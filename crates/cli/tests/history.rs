//! `drivebus events` and `drivebus trend` end to end: a store made through drivebus_store, the
//! binary run on it, its output checked; missing and bad files; bad usage.

use std::path::Path;
use std::process::Command;

use drivebus_store::{Event, EventKind, Sample, Store};
use serde_json::{json, Value};

#[cfg(unix)]
#[path = "support/closed_pipe.rs"]
mod closed_pipe;

#[path = "support/output.rs"]
mod output;
use output::{output, Out};

/// Runs `drivebus` in `dir` with the state folder `dir/state/drivebus` (never the user's own).
fn run_in(dir: &Path, args: &[&str]) -> Out {
    output(
        Command::new(env!("CARGO_BIN_EXE_drivebus"))
            .current_dir(dir)
            .env("XDG_STATE_HOME", dir.join("state"))
            .env_remove("STATE_DIRECTORY")
            .args(args),
    )
}

/// Asserts a run that found nothing: success, nothing on stdout, `said` on stderr.
fn assert_found_nothing(r: &Out, said: &str) {
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert_eq!(r.stdout, "");
    assert!(r.stderr.contains(said), "{}", r.stderr);
}

/// The fixture's start: the last whole hour at least an hour ago. Trends of 1 s are kept for a
/// day of wall-clock time (the store prunes them when it opens), so a fixed date would age out.
/// Taken once per test binary, so every test sees the same start.
fn t0() -> i64 {
    static T0: std::sync::OnceLock<i64> = std::sync::OnceLock::new();
    *T0.get_or_init(|| {
        let now = drivebus_store::time::now_ms();
        now - now.rem_euclid(3_600_000) - 3_600_000
    })
}

/// `t0() + offset_ms` as the CLI prints it (RFC 3339, UTC).
fn at(offset_ms: i64) -> String {
    drivebus_store::time::format_rfc3339(t0() + offset_ms)
}

fn event(time_ms: i64, kind: EventKind, drive: &str, actor: &str, action: &str, result: &str) -> Event {
    Event {
        id: 0,
        time_ms,
        kind,
        bus: Some("line-1".into()),
        drive: Some(drive.into()),
        actor: (!actor.is_empty()).then(|| actor.into()),
        action: (!action.is_empty()).then(|| action.into()),
        result: (!result.is_empty()).then(|| result.into()),
        detail: Value::Null,
    }
}

/// A store in `dir/drivebus.db` with five events and two minutes of one drive's trend.
fn fixture(dir: &Path) {
    fixture_named(dir, "drivebus.db");
}

/// The same store in `dir/name`.
fn fixture_named(dir: &Path, name: &str) {
    let store = Store::open(&dir.join(name)).unwrap();
    store.record(&event(t0(), EventKind::Command, "pump-1", "http:ops@127.0.0.1", "run", "ok")).unwrap();
    store
        .record(&event(t0() + 1_000, EventKind::Command, "pump-1", "http:ops@127.0.0.1", "speed 40 Hz", "ok"))
        .unwrap();
    let mut trip = event(t0() + 60_000, EventKind::Trip, "fan-2", "", "", "");
    trip.detail = json!({"code": 7, "text": "overcurrent"});
    store.record(&trip).unwrap();
    store
        .record(&event(
            t0() + 120_000,
            EventKind::Command,
            "fan-2",
            "modbus:127.0.0.1:5555",
            "stop",
            "refused: locked",
        ))
        .unwrap();
    let mut gw = Event::new(t0() + 180_000, EventKind::Started);
    gw.actor = Some("gateway".into());
    store.record(&gw).unwrap();
    for i in 0..120 {
        let hz = if i < 60 { i as f64 } else { 50.0 };
        store.sample(Sample {
            time_ms: t0() + i * 1000,
            drive: "pump-1".into(),
            output_hz: Some(hz),
            current_a: Some(2.0),
            setpoint_hz: Some(50.0),
        });
    }
    store.flush().unwrap();
}

fn json_lines(stdout: &str) -> Vec<Value> {
    stdout.lines().map(|l| serde_json::from_str(l).expect("one JSON object per line")).collect()
}

#[test]
fn events_table_lists_every_column() {
    let dir = tempfile::tempdir().unwrap();
    fixture(dir.path());
    let r = run_in(dir.path(), &["events"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    let lines: Vec<&str> = r.stdout.lines().collect();
    assert_eq!(lines.len(), 6, "{}", r.stdout);
    for col in ["TIME", "KIND", "BUS", "DRIVE", "ACTOR", "ACTION", "RESULT"] {
        assert!(lines[0].contains(col), "{}", lines[0]);
    }
    let first: Vec<&str> = lines[1].split_whitespace().collect();
    assert_eq!(first, [at(0).as_str(), "command", "line-1", "pump-1", "http:ops@127.0.0.1", "run", "ok"]);
    assert!(lines[2].contains("speed 40 Hz"), "{}", lines[2]);
    assert!(lines[3].contains(at(60_000).as_str()) && lines[3].contains("trip"), "{}", lines[3]);
    assert!(lines[4].contains("refused: locked"), "{}", lines[4]);
    assert!(lines[5].contains("started") && lines[5].contains("gateway"), "{}", lines[5]);
}

#[test]
fn events_filters_reach_the_store() {
    let dir = tempfile::tempdir().unwrap();
    fixture(dir.path());
    let kinds = |args: &[&str]| {
        let mut all = vec!["events", "--json"];
        all.extend_from_slice(args);
        let r = run_in(dir.path(), &all);
        assert_eq!(r.code, 0, "{args:?}: {}", r.stderr);
        json_lines(&r.stdout)
            .iter()
            .map(|e| format!("{}@{}", e["kind"].as_str().unwrap(), e["time_ms"].as_i64().unwrap() - t0()))
            .collect::<Vec<_>>()
    };
    assert_eq!(kinds(&["--drive", "fan-2"]), ["trip@60000", "command@120000"]);
    assert_eq!(kinds(&["--kind", "command"]), ["command@0", "command@1000", "command@120000"]);
    assert_eq!(kinds(&["--kind", "command", "--drive", "pump-1", "--limit", "1"]), ["command@1000"]);
    assert_eq!(kinds(&["--since", &at(60_000), "--until", &at(180_000)]), ["trip@60000", "command@120000"]);
    let ms = (t0() + 120_000).to_string();
    assert_eq!(kinds(&["--since", &ms]), ["command@120000", "started@180000"]);
    // relative times: the fixture starts one to two hours ago
    assert_eq!(kinds(&["--since", "-1d"]).len(), 5);
    assert_eq!(kinds(&["--since", "-1s"]).len(), 0);
}

#[test]
fn events_json_is_the_stored_event() {
    let dir = tempfile::tempdir().unwrap();
    fixture(dir.path());
    let r = run_in(dir.path(), &["--json", "events", "--kind", "trip"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    let got = json_lines(&r.stdout);
    assert_eq!(got.len(), 1);
    assert_eq!(
        got[0],
        json!({"id": 3, "time_ms": t0() + 60_000, "kind": "trip", "bus": "line-1", "drive": "fan-2", "actor": null,
               "action": null, "result": null, "detail": {"code": 7, "text": "overcurrent"}})
    );
    let e: Event = serde_json::from_value(got[0].clone()).unwrap();
    assert_eq!(e.kind, EventKind::Trip);
}

#[test]
fn events_with_db_elsewhere_and_none_matching() {
    let dir = tempfile::tempdir().unwrap();
    fixture(dir.path());
    let other = tempfile::tempdir().unwrap();
    let db = dir.path().join("drivebus.db");
    let r = run_in(other.path(), &["events", "--db", db.to_str().unwrap(), "--kind", "bus_offline"]);
    assert_found_nothing(&r, "no events match");
}

#[test]
fn trend_table_and_json() {
    let dir = tempfile::tempdir().unwrap();
    fixture(dir.path());
    let (since, until) = (at(0), at(120_000));
    let range = ["--since", since.as_str(), "--until", until.as_str()];
    let mut args = vec!["trend", "--drive", "pump-1", "--resolution", "1m"];
    args.extend_from_slice(&range);
    let r = run_in(dir.path(), &args);
    assert_eq!(r.code, 0, "{}", r.stderr);
    let lines: Vec<&str> = r.stdout.lines().collect();
    assert_eq!(lines.len(), 3, "{}", r.stdout);
    assert!(lines[0].contains("OUTPUT HZ") && lines[0].contains("MAX HZ"), "{}", lines[0]);
    let row: Vec<&str> = lines[1].split_whitespace().collect();
    assert_eq!(row, [at(0).as_str(), "29.50", "0.00", "59.00", "2.00", "50.00", "60"]);
    let row: Vec<&str> = lines[2].split_whitespace().collect();
    assert_eq!(row, [at(60_000).as_str(), "50.00", "50.00", "50.00", "2.00", "50.00", "60"]);

    // 1 s resolution, JSON: one point per second; explicit --resolution beats the default
    let mut args = vec!["trend", "--drive", "pump-1", "--resolution", "1s", "--json"];
    args.extend_from_slice(&range);
    let r = run_in(dir.path(), &args);
    assert_eq!(r.code, 0, "{}", r.stderr);
    let pts = json_lines(&r.stdout);
    assert_eq!(pts.len(), 120);
    assert_eq!(pts[30]["time_ms"], json!(t0() + 30_000));
    assert_eq!(pts[30]["output_hz"], json!(30.0));
    assert_eq!(pts[30]["samples"], json!(1));
}

#[test]
fn trend_default_resolution_follows_since() {
    let dir = tempfile::tempdir().unwrap();
    fixture(dir.path());
    // --since older than a day and no --resolution: minute buckets
    let r = run_in(dir.path(), &["trend", "--drive", "pump-1", "--json", "--since", "0"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert_eq!(json_lines(&r.stdout).len(), 2, "{}", r.stdout);
    // --since within the last day: second buckets (samples a few seconds before now)
    let now = drivebus_store::time::now_ms();
    {
        let store = Store::open(&dir.path().join("drivebus.db")).unwrap();
        for t in [now - 5_000, now - 4_000] {
            store.sample(Sample {
                time_ms: t,
                drive: "live".into(),
                output_hz: Some(10.0),
                current_a: None,
                setpoint_hz: None,
            });
        }
    }
    let r = run_in(dir.path(), &["trend", "--drive", "live", "--json", "--since", "-1h"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    let pts = json_lines(&r.stdout);
    assert_eq!(pts.len(), 2, "{}", r.stdout);
    assert!(pts.iter().all(|p| p["samples"] == json!(1)), "{}", r.stdout);
    // and with no --since at all (the last hour at 1 s)
    let r = run_in(dir.path(), &["trend", "--drive", "live", "--json"]);
    assert_eq!(json_lines(&r.stdout).len(), 2, "{}", r.stdout);
    // an unknown drive: nothing, said on stderr, still success
    let r = run_in(dir.path(), &["trend", "--drive", "nope", "--since", "0", "--resolution", "1m"]);
    assert_found_nothing(&r, "no 1m trend for drive nope");
}

#[test]
fn a_missing_store_is_exit_2_with_what_to_do() {
    let dir = tempfile::tempdir().unwrap();
    for args in [&["events"][..], &["trend", "--drive", "p"][..]] {
        let r = run_in(dir.path(), args);
        assert_eq!(r.code, 2, "{args:?}");
        // The gateway's default store is named: drivebus.db in the state folder.
        let default = dir.path().join("state/drivebus/drivebus.db");
        assert_eq!(
            r.stderr.trim(),
            format!(
                "drivebus: no event store at {}: start `drivebus serve` or give --db FILE",
                default.display()
            ),
            "{args:?}"
        );
        assert!(!dir.path().join("drivebus.db").exists(), "reading must not create the store");
        assert!(!default.exists(), "reading must not create the store");
    }
}

#[test]
fn a_file_that_is_not_a_store_is_one_line() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("notes.txt"), "not a database\n".repeat(100)).unwrap();
    let r = run_in(dir.path(), &["events", "--db", "notes.txt"]);
    assert_eq!(r.code, 2);
    assert_eq!(r.stderr.lines().count(), 1, "{}", r.stderr);
    assert!(r.stderr.contains("notes.txt is not a drivebus event store"), "{}", r.stderr);
}

#[test]
fn bad_usage_is_exit_3() {
    let dir = tempfile::tempdir().unwrap();
    fixture(dir.path());
    for (args, needle) in [
        (&["events", "--since", "yesterday"][..], "RFC 3339"),
        (&["events", "--until", "-5x"][..], "RFC 3339"),
        (&["events", "--kind", "tripped"][..], "fault_reset"),
        (&["events", "--limit", "many"][..], "--limit"),
        (&["events", "--since", "-1h", "--until", "-2h"][..], "before --until"),
        (&["events", "--drive", "a", "--drive", "b"][..], "one --drive"),
        (&["trend"][..], "--drive ID"),
        (&["trend", "--drive", "p", "--resolution", "5m"][..], "1s or 1m"),
    ] {
        let r = run_in(dir.path(), args);
        assert_eq!(r.code, 3, "{args:?}: {}", r.stderr);
        assert_eq!(r.stderr.lines().count(), 1, "{args:?}: {}", r.stderr);
        assert!(r.stderr.contains(needle), "{args:?}: {}", r.stderr);
    }
}

#[test]
fn reads_while_a_writer_has_the_store_open() {
    let dir = tempfile::tempdir().unwrap();
    fixture(dir.path());
    let writer = Store::open(&dir.path().join("drivebus.db")).unwrap();
    writer.record(&event(t0() + 240_000, EventKind::Offline, "pump-1", "", "", "")).unwrap();
    let r = run_in(dir.path(), &["events", "--json", "--kind", "offline"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert_eq!(json_lines(&r.stdout).len(), 1);
    drop(writer);
}

/// `drivebus events | head -1`: the command ends quietly when its reader stops (it panicked
/// in println! before).
#[test]
#[cfg(unix)]
fn events_to_a_reader_that_stops_early_end_without_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(&dir.path().join("drivebus.db")).unwrap();
    let many: Vec<Event> = (0..5000)
        .map(|i| event(t0() + i, EventKind::Command, "pump-1", "http:ops@127.0.0.1", "speed 40 Hz", "ok"))
        .collect();
    store.record_batch(&many).unwrap();
    drop(store);
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_drivebus"));
    cmd.current_dir(dir.path()).args(["events", "--limit", "5000"]);
    let first = closed_pipe::first_line_then_close(cmd);
    assert!(first.contains("TIME"), "{first}");
}

/// `drivebus serve` without `[store] path` keeps drivebus.db in the state folder: `events`
/// finds it there without --db.
#[test]
fn events_find_the_gateways_default_store_in_the_state_folder() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("state/drivebus")).unwrap();
    fixture_named(&dir.path().join("state/drivebus"), "drivebus.db");
    let r = run_in(dir.path(), &["events", "--since", "0", "--kind", "trip"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert!(r.stdout.contains("fan-2") && r.stdout.contains("trip"), "{}", r.stdout);
}

/// `drivebus serve --demo` keeps its store, drivebus-demo.db, in the state folder
/// ($XDG_STATE_HOME/drivebus here): the README's `events` and `trend` lines find it without --db.
#[test]
fn events_and_trend_find_the_demos_store() {
    let dir = tempfile::tempdir().unwrap();
    let state = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(state.path().join("drivebus")).unwrap();
    fixture_named(&state.path().join("drivebus"), "drivebus-demo.db");
    let run = |args: &[&str]| {
        output(
            Command::new(env!("CARGO_BIN_EXE_drivebus"))
                .current_dir(dir.path())
                .env("XDG_STATE_HOME", state.path())
                .env_remove("STATE_DIRECTORY")
                .args(args),
        )
    };
    let r = run(&["events", "--since", "0", "--kind", "trip"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert!(r.stdout.contains("fan-2") && r.stdout.contains("trip"), "{}", r.stdout);
    let since = t0().to_string();
    let r = run(&["trend", "--drive", "pump-1", "--since", &since]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert!(r.stdout.lines().count() > 100, "{}", r.stdout);
    // A drivebus.db of its own (empty here) is read first.
    drop(Store::open(&dir.path().join("drivebus.db")).unwrap());
    let r = run(&["events"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert!(r.stderr.contains("no events match in drivebus.db"), "{}", r.stderr);
}
