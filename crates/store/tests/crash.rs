//! `kill -9` mid-stream loses no event whose `record` returned.
//!
//! The test re-runs its own binary as a child with `DRIVEBUS_STORE_CRASH_CHILD` set to a store
//! path. The child records events as fast as it can and prints `recorded <id> <n>` after each
//! `record` returns. The parent reads those lines, kills the child with SIGKILL part-way, reads
//! whatever lines were already printed, then reopens the file: every printed id must be there,
//! with the contents the child gave it.

use std::io::{BufRead, BufReader, Write};
use std::process::{Command, Stdio};

use drivebus_store::{Event, EventFilter, EventKind, Store};
use serde_json::json;

const CHILD_ENV: &str = "DRIVEBUS_STORE_CRASH_CHILD";

fn event(n: i64) -> Event {
    let mut e = Event::new(1_000_000 + n, EventKind::Command);
    e.drive = Some(format!("drive-{}", n % 7));
    e.actor = Some("http:crash-test@127.0.0.1".into());
    e.action = Some(format!("speed {} Hz", n % 50));
    e.result = Some("ok".into());
    e.detail = json!({ "n": n });
    e
}

/// The child's body; a no-op when run as an ordinary test.
#[test]
fn crash_child() {
    let Ok(path) = std::env::var(CHILD_ENV) else { return };
    let store = Store::open(std::path::Path::new(&path)).expect("child opens the store");
    let mut out = std::io::stdout().lock();
    for n in 0.. {
        let id = store.record(&event(n)).expect("child records");
        // Written straight to the descriptor (not the test harness's capture) and flushed, so
        // the parent sees it before the next event starts.
        writeln!(out, "recorded {id} {n}").expect("child writes");
        out.flush().expect("child flushes");
        // Samples in flight at the kill too: they may be lost, events may not.
        store.sample(drivebus_store::Sample {
            time_ms: n,
            drive: "x".into(),
            output_hz: Some(1.0),
            current_a: None,
            setpoint_hz: None,
        });
    }
}

#[test]
fn kill_9_loses_no_acknowledged_event() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("crash.db");
    let exe = std::env::current_exe().unwrap();
    for round in 0..3 {
        let mut child = Command::new(&exe)
            .args(["--exact", "crash_child", "--nocapture", "--test-threads=1"])
            .env(CHILD_ENV, &path)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("start the child");
        let stdout = child.stdout.take().unwrap();
        let mut lines = BufReader::new(stdout).lines();
        let mut acknowledged: Vec<(i64, i64)> = Vec::new();
        // Kill at a different point each round, mid-stream.
        let kill_after = 150 + round * 97;
        while acknowledged.len() < kill_after {
            let line = lines.next().expect("the child ended early").unwrap();
            if let Some(rest) = line.strip_prefix("recorded ") {
                let mut it = rest.split(' ').map(|x| x.parse::<i64>().unwrap());
                acknowledged.push((it.next().unwrap(), it.next().unwrap()));
            }
        }
        child.kill().expect("SIGKILL the child"); // std sends SIGKILL on Unix
        let status = child.wait().unwrap();
        assert!(!status.success(), "the child was killed, not finished: {status:?}");
        // Lines printed before the kill are still in the pipe: those events were acknowledged too.
        for line in lines {
            let Ok(line) = line else { break };
            if let Some(rest) = line.strip_prefix("recorded ") {
                let mut it = rest.split(' ').map(|x| x.parse::<i64>().unwrap());
                acknowledged.push((it.next().unwrap(), it.next().unwrap()));
            }
        }

        let store = Store::open(&path).expect("reopen after kill -9");
        let stored = store.events(&EventFilter { limit: usize::MAX, ..Default::default() }).unwrap();
        let by_id: std::collections::HashMap<i64, &Event> = stored.iter().map(|e| (e.id, e)).collect();
        for (id, n) in &acknowledged {
            let got = by_id.get(id).unwrap_or_else(|| panic!("round {round}: acknowledged event {id} lost"));
            assert_eq!(**got, Event { id: *id, ..event(*n) }, "round {round}");
        }
        // At most the one event in flight at the kill is stored without having been printed.
        let this_round = stored.iter().filter(|e| e.id > acknowledged[0].0 - 1).count();
        assert!(this_round >= acknowledged.len() && this_round <= acknowledged.len() + 1, "round {round}");
        drop(store);
    }
}
