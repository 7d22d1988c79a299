//! Throughput of the store, run by `bench/store.sh`: durable events per second (one fsync each),
//! from one thread and from four, trend samples per second through the queue and the batch
//! writer, and how long the CLI's queries take on a filled store.
//!
//! `cargo run --release -p drivebus-store --example store_bench -- [DIR]` (default: a new
//! directory under target/, on the same disk as the project, not a RAM disk).

use std::path::PathBuf;
use std::time::Instant;

use drivebus_store::{Event, EventFilter, EventKind, Resolution, Sample, Store, TrendQuery};

fn event(n: i64) -> Event {
    let mut e = Event::new(1_795_255_200_000 + n, EventKind::Command);
    e.bus = Some("line-1".into());
    e.drive = Some(format!("drive-{}", n % 32));
    e.actor = Some("http:ops@127.0.0.1".into());
    e.action = Some("speed 40 Hz".into());
    e.result = Some("ok".into());
    e.detail = serde_json::json!({ "old_hz": 30.0, "new_hz": 40.0 });
    e
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::env::args().nth(1).map_or_else(|| PathBuf::from("target/store-bench"), PathBuf::from);
    std::fs::create_dir_all(&dir)?;
    let path = dir.join("bench.db");
    for suffix in ["", "-wal", "-shm"] {
        let _ = std::fs::remove_file(format!("{}{suffix}", path.display()));
    }
    let store = Store::open(&path)?;
    println!("store file: {}", path.display());

    // 1. events, one thread: each record() is a committed, synced transaction.
    let n = 2_000;
    let t = Instant::now();
    for i in 0..n {
        store.record(&event(i))?;
    }
    let s = t.elapsed().as_secs_f64();
    println!(
        "events, 1 thread:   {n:>8} in {s:6.3} s = {:>9.0} events/s ({:.0} us each)",
        n as f64 / s,
        s * 1e6 / n as f64
    );

    // 2. events, four threads sharing the handle.
    let per = 500;
    let t = Instant::now();
    let handles: Vec<_> = (0..4)
        .map(|k| {
            let st = store.clone();
            std::thread::spawn(move || -> Result<(), drivebus_store::StoreError> {
                for i in 0..per {
                    st.record(&event(100_000 * (k + 1) + i))?;
                }
                Ok(())
            })
        })
        .collect();
    for h in handles {
        h.join().map_err(|_| "bench thread panicked")??;
    }
    let s = t.elapsed().as_secs_f64();
    let total = 4 * per;
    println!("events, 4 threads:  {total:>8} in {s:6.3} s = {:>9.0} events/s", total as f64 / s);

    // 2b. events in batches of 100 (record_batch: one sync per batch).
    let batch: Vec<Event> = (0..100).map(event).collect();
    let t = Instant::now();
    for _ in 0..20 {
        store.record_batch(&batch)?;
    }
    let s = t.elapsed().as_secs_f64();
    println!("events, batches of 100: {:>4} in {s:6.3} s = {:>9.0} events/s", 2_000, 2_000.0 / s);

    // 3. samples: 1000 drives x 600 s at one sample a second, queued then committed in batches
    //    of 100 s (100 000 samples), the way the background thread would under a backlog.
    let drives = 1_000;
    let seconds = 600;
    let names: Vec<String> = (0..drives).map(|d| format!("drive-{d}")).collect();
    let t0 = 1_795_255_200_000i64;
    let mut queue_s = 0.0;
    let t = Instant::now();
    for sec in 0..seconds {
        let q = Instant::now();
        for name in &names {
            store.sample(Sample {
                time_ms: t0 + sec * 1000,
                drive: name.clone(),
                output_hz: Some(sec as f64 % 50.0),
                current_a: Some(3.2),
                setpoint_hz: Some(50.0),
            });
        }
        queue_s += q.elapsed().as_secs_f64();
        if sec % 100 == 99 {
            store.flush()?;
        }
    }
    store.flush()?;
    let s = t.elapsed().as_secs_f64();
    let total = drives * seconds;
    println!(
        "samples:            {total:>8} in {s:6.3} s = {:>9.0} samples/s written (sample() alone: {:.0} ns each)",
        total as f64 / s,
        queue_s * 1e9 / total as f64
    );
    if store.dropped_samples() > 0 {
        println!("  (dropped {} samples: queue full)", store.dropped_samples());
    }

    // 4. the CLI's queries on the filled store.
    let t = Instant::now();
    let got = store.events(&EventFilter::default())?;
    println!(
        "events() newest 1000 of {:>6}:           {:6.2} ms",
        n + 2_000,
        t.elapsed().as_secs_f64() * 1e3
    );
    assert_eq!(got.len(), 1000);
    let t = Instant::now();
    let got = store.events(&EventFilter { drive: Some("drive-7".into()), ..Default::default() })?;
    println!(
        "events() one drive ({:>3} events):         {:6.2} ms",
        got.len(),
        t.elapsed().as_secs_f64() * 1e3
    );
    let t = Instant::now();
    let pts = store.trend(&TrendQuery {
        drive: "drive-500".into(),
        since_ms: t0,
        until_ms: t0 + seconds * 1000,
        resolution: Resolution::Second,
    })?;
    println!(
        "trend() 1s, {:>3} points of 1 drive:       {:6.2} ms",
        pts.len(),
        t.elapsed().as_secs_f64() * 1e3
    );
    let size = std::fs::metadata(&path)?.len()
        + std::fs::metadata(format!("{}-wal", path.display())).map_or(0, |m| m.len());
    println!("file size: {:.1} MiB (db + wal)", size as f64 / 1_048_576.0);
    Ok(())
}
