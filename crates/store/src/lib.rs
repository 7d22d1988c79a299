//! # drivebus-store
//!
//! The gateway's memory: one SQLite file (WAL mode) holding
//!
//! - the **event log**: every command with who, when, what and the result (the audit trail),
//!   every trip, fault reset, drive and bus online/offline change, and the gateway's start and
//!   stop ([`Store::record`], [`Store::events`]);
//! - **trends** of each drive's output frequency, current and setpoint, in 1 s buckets kept for a
//!   day and 1 min buckets (average, minimum and maximum of the output frequency) kept for a year
//!   ([`Store::sample`], [`Store::trend`], [`Store::prune`]).
//! - the **Sparkplug B** edge node's `bdSeq` and its store-and-forward queue
//!   ([`Store::next_bd_seq`], [`Store::spool_push`], [`Store::spool_peek`], [`Store::spool_remove`]).
//!
//! It sits beside the other crates, not under them: `drivebus serve` (crates/gateway) records
//! events and samples as it polls; `drivebus events` and `drivebus trend` (crates/cli) open the
//! same file with [`Store::open_read_only`] while the gateway runs. Nothing here knows about
//! protocols or drives beyond their names. The crate needs no async runtime: every call blocks,
//! so an async caller uses `spawn_blocking` or a thread of its own.
//!
//! ## Durability
//!
//! [`Store::record`] returns only after the event is committed with `synchronous=FULL`: the
//! write-ahead log is synced to disk before the call returns, so an acknowledged event survives
//! `kill -9` of the process and, as far as the disk honours its flushes, a power cut. The
//! crash test in `tests/crash.rs` kills a recording child with SIGKILL and finds every event whose
//! id the child had printed.
//!
//! Samples are cheaper: [`Store::sample`] only queues; a background thread commits the queue at
//! least once a second (one transaction, one sync, per batch), so a crash loses at most the last
//! second of trend data. [`Store::flush`] writes the queue at once.
//!
//! ## Downsampling
//!
//! Every sample is added to its 1 s bucket and its 1 min bucket in the same transaction. Several
//! samples in one bucket are **averaged** (the tables keep sums and counts, so buckets that span
//! batches average correctly); the minimum and maximum output frequency are kept per bucket. A
//! 1 min average is over the samples, not over the 1 s averages. [`Store::prune`] deletes 1 s
//! buckets older than a day and 1 min buckets older than a year; the background thread calls it
//! when the store opens and every ten minutes.
//!
//! ## Retention and size cap
//!
//! [`Limits`]: events older than the retention are deleted, and when the data outgrows the size
//! cap the oldest events and trend buckets go first ([`Store::enforce_limits`]). Both are
//! enforced when the store opens (before it is used), then by the background thread: the
//! retention every ten minutes, the cap every [`SIZE_CHECK_INTERVAL`].
//!
//! ## Concurrency
//!
//! A [`Store`] is a cheap `Clone + Send + Sync` handle. Writes go through one connection (one
//! writer at a time is SQLite's rule); reads use a second connection and, thanks to WAL, do not
//! wait for writes. Other processes may read the file at the same time; every connection waits
//! up to [`BUSY_TIMEOUT`] for a lock before giving up.
//!
//! The schema is in `docs/store.md` and in [`SCHEMA`].

mod audit;
mod error;
mod event;
mod limits;
mod sparkplug;
pub mod time;
mod trend;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use rusqlite::{params, Connection, OpenFlags};

pub use audit::PENDING;
pub use error::StoreError;
pub use event::{Event, EventFilter, EventKind, UnknownKind};
pub use limits::{Enforced, Limits, SIZE_CHECK_INTERVAL};
pub use sparkplug::{SpoolDropped, Spooled, SPARKPLUG_SCHEMA};
pub use trend::{Resolution, Sample, TrendPoint, TrendQuery};

/// The `application_id` in the SQLite header that marks a drivebus store ("DBST").
pub const APPLICATION_ID: i32 = 0x4442_5354;

/// The schema version this crate writes (kept in `user_version`).
pub const SCHEMA_VERSION: i64 = 1;

/// How long a connection waits for another one's lock before failing.
pub const BUSY_TIMEOUT: Duration = Duration::from_secs(5);

/// How often the background thread commits queued samples.
pub const FLUSH_INTERVAL: Duration = Duration::from_secs(1);

/// How often the background thread prunes old trend buckets.
pub const PRUNE_INTERVAL: Duration = Duration::from_secs(600);

/// At most this many samples wait in the queue; beyond it new samples are dropped and counted
/// ([`Store::dropped_samples`]) rather than growing memory without bound when the disk stalls.
pub const MAX_QUEUED_SAMPLES: usize = 262_144;

/// `CREATE TABLE <name>` of one trend resolution (`trend_1s`, `trend_1m`): a row per drive and
/// bucket, with the sums and counts the averages are made of.
macro_rules! trend_table {
    ($name:literal) => {
        concat!(
            "CREATE TABLE ",
            $name,
            " (
    drive   TEXT NOT NULL,
    time_ms INTEGER NOT NULL,
    samples INTEGER NOT NULL,
    hz_sum  REAL NOT NULL, hz_n INTEGER NOT NULL, hz_min REAL, hz_max REAL,
    a_sum   REAL NOT NULL, a_n  INTEGER NOT NULL,
    sp_sum  REAL NOT NULL, sp_n INTEGER NOT NULL,
    PRIMARY KEY (drive, time_ms)
) WITHOUT ROWID;
"
        )
    };
}

/// The schema, created in one transaction when a new file is opened with [`Store::open`].
pub const SCHEMA: &str = concat!(
    "
CREATE TABLE events (
    id      INTEGER PRIMARY KEY AUTOINCREMENT,
    time_ms INTEGER NOT NULL,
    kind    TEXT NOT NULL,
    bus     TEXT,
    drive   TEXT,
    actor   TEXT,
    action  TEXT,
    result  TEXT,
    detail  TEXT NOT NULL DEFAULT 'null'
);
CREATE INDEX events_time ON events (time_ms);
CREATE INDEX events_drive ON events (drive, time_ms);
",
    trend_table!("trend_1s"),
    trend_table!("trend_1m"),
);

/// A handle on one store file. Clones share the connections and the background thread, which
/// stops (after writing the queued samples) when the last clone is dropped.
#[derive(Clone)]
pub struct Store {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for Store {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Store")
            .field("path", &self.inner.shared.path)
            .field("read_only", &self.inner.shared.writer.is_none())
            .finish()
    }
}

struct Inner {
    shared: Arc<Shared>,
    worker: Option<JoinHandle<()>>,
}

struct Shared {
    path: PathBuf,
    /// Declared (so dropped) before the writer: the last connection to close checkpoints the
    /// write-ahead log into the main file, and only the writer can.
    reader: Mutex<Connection>,
    /// `None` for a read-only store.
    writer: Option<Mutex<Connection>>,
    queue: Mutex<Queue>,
    wake: Condvar,
    limits: Limits,
}

#[derive(Default)]
struct Queue {
    samples: Vec<Sample>,
    dropped: u64,
    stop: bool,
    last_error: Option<String>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

impl Drop for Inner {
    fn drop(&mut self) {
        lock(&self.shared.queue).stop = true;
        self.shared.wake.notify_all();
        if let Some(worker) = self.worker.take() {
            let _ = worker.join();
        }
    }
}

impl Store {
    /// Opens the store at `path` for reading and writing, creating the file and its schema if it
    /// does not exist, and starts the background thread that commits samples and prunes.
    /// No retention nor size cap ([`Limits::NONE`]; see [`Store::open_with_limits`]).
    ///
    /// Fails with [`StoreError::NotADatabase`] for a file that is not SQLite,
    /// [`StoreError::Foreign`] for another program's database and [`StoreError::TooNew`] for a
    /// store written by a newer drivebus.
    pub fn open(path: &Path) -> Result<Store, StoreError> {
        Store::open_with_limits(path, Limits::NONE)
    }

    /// [`Store::open`] with the retention and size cap `limits`, enforced before this returns
    /// and then periodically by the background thread.
    pub fn open_with_limits(path: &Path, limits: Limits) -> Result<Store, StoreError> {
        let sq = |doing| move |e| StoreError::sqlite(path, doing, e);
        let mut writer = Connection::open(path).map_err(sq("opening"))?;
        writer.busy_timeout(BUSY_TIMEOUT).map_err(sq("setting the busy timeout"))?;
        let app_id: i32 =
            writer.query_row("PRAGMA application_id", [], |r| r.get(0)).map_err(sq("reading the header"))?;
        if app_id != 0 && app_id != APPLICATION_ID {
            return Err(StoreError::Foreign { path: path.to_path_buf() });
        }
        let mode: String = writer
            .query_row("PRAGMA journal_mode=WAL", [], |r| r.get(0))
            .map_err(sq("switching to WAL mode"))?;
        if !mode.eq_ignore_ascii_case("wal") {
            return Err(StoreError::sqlite(path, "switching to WAL mode", rusqlite::Error::InvalidQuery));
        }
        writer.pragma_update(None, "synchronous", "FULL").map_err(sq("setting synchronous=FULL"))?;
        {
            let tx = writer
                .transaction_with_behavior(rusqlite::TransactionBehavior::Immediate)
                .map_err(sq("creating the schema"))?;
            check_header(&tx, path, true)?;
            let app_id: i32 =
                tx.query_row("PRAGMA application_id", [], |r| r.get(0)).map_err(sq("reading the header"))?;
            if app_id == 0 {
                tx.execute_batch(SCHEMA).map_err(sq("creating the schema"))?;
                tx.pragma_update(None, "application_id", APPLICATION_ID)
                    .map_err(sq("creating the schema"))?;
                tx.pragma_update(None, "user_version", SCHEMA_VERSION).map_err(sq("creating the schema"))?;
            }
            tx.execute_batch(SPARKPLUG_SCHEMA).map_err(sq("creating the Sparkplug tables"))?;
            tx.commit().map_err(sq("creating the schema"))?;
        }
        // The limits hold from the start: enforced before the store is used.
        let mut queue = Queue::default();
        if limits != Limits::NONE {
            if let Err(e) = limits::enforce(&writer, path, &limits, time::now_ms()) {
                queue.last_error = Some(e.to_string());
            }
        }
        let reader = open_reader(path)?;
        let shared = Arc::new(Shared {
            path: path.to_path_buf(),
            reader: Mutex::new(reader),
            writer: Some(Mutex::new(writer)),
            queue: Mutex::new(queue),
            wake: Condvar::new(),
            limits,
        });
        let worker = {
            let shared = Arc::clone(&shared);
            std::thread::Builder::new()
                .name("drivebus-store".into())
                .spawn(move || background(&shared))
                .map_err(|e| StoreError::BadInput {
                    what: format!("{}: cannot start the store's thread: {e}", path.display()),
                })?
        };
        Ok(Store { inner: Arc::new(Inner { shared, worker: Some(worker) }) })
    }

    /// Opens an existing store for reading only (the CLI, while `drivebus serve` writes it).
    /// A missing file is [`StoreError::Missing`]; writes on the result fail with
    /// [`StoreError::ReadOnly`] and samples are dropped.
    pub fn open_read_only(path: &Path) -> Result<Store, StoreError> {
        if !path.exists() {
            return Err(StoreError::Missing { path: path.to_path_buf() });
        }
        let reader = open_reader(path)?;
        let shared = Arc::new(Shared {
            path: path.to_path_buf(),
            reader: Mutex::new(reader),
            writer: None,
            queue: Mutex::new(Queue::default()),
            wake: Condvar::new(),
            limits: Limits::NONE,
        });
        Ok(Store { inner: Arc::new(Inner { shared, worker: None }) })
    }

    /// The file this store is in.
    pub fn path(&self) -> &Path {
        &self.inner.shared.path
    }

    /// Deletes what [`Limits`] say is too old or too much, as of `now_ms` (the background thread
    /// does this; tests call it with a virtual clock). Returns what was deleted.
    pub fn enforce_limits(&self, now_ms: i64) -> Result<Enforced, StoreError> {
        let conn = self.writer()?;
        limits::enforce(&conn, self.path(), &self.inner.shared.limits, now_ms)
    }

    /// Bytes in use by the data (the file does not shrink when rows are deleted: freed pages
    /// are reused).
    pub fn used_bytes(&self) -> Result<u64, StoreError> {
        let conn = lock(&self.inner.shared.reader);
        limits::used_bytes(&conn).map_err(|e| StoreError::sqlite(self.path(), "reading the size", e))
    }

    /// The limits this store enforces.
    pub fn limits(&self) -> Limits {
        self.inner.shared.limits
    }

    /// Whether this store was opened with [`Store::open_read_only`].
    pub fn is_read_only(&self) -> bool {
        self.inner.shared.writer.is_none()
    }

    fn writer(&self) -> Result<MutexGuard<'_, Connection>, StoreError> {
        match &self.inner.shared.writer {
            Some(w) => Ok(lock(w)),
            None => Err(StoreError::ReadOnly { path: self.path().to_path_buf() }),
        }
    }

    /// Appends an event and returns only after it is committed (durable across `kill -9`): the
    /// audit trail. Returns the new id; `event.id` is ignored. Each call is one synced commit
    /// (a few milliseconds on a disk that honours flushes); see [`Store::record_batch`] for bursts.
    pub fn record(&self, event: &Event) -> Result<i64, StoreError> {
        let detail = detail_json(event)?;
        let conn = self.writer()?;
        insert_event(&conn, event, &detail)
            .map_err(|e| StoreError::sqlite(self.path(), "recording an event", e))
    }

    /// Appends several events in one transaction with one sync, for bursts such as every drive on
    /// a bus going offline at once. Returns their ids in order once committed; on an error none
    /// of them is stored.
    pub fn record_batch(&self, events: &[Event]) -> Result<Vec<i64>, StoreError> {
        let details = events.iter().map(detail_json).collect::<Result<Vec<_>, _>>()?;
        let mut conn = self.writer()?;
        let sq = |e| StoreError::sqlite(self.path(), "recording events", e);
        let tx = conn.transaction().map_err(sq)?;
        let ids = events
            .iter()
            .zip(&details)
            .map(|(e, d)| insert_event(&tx, e, d))
            .collect::<Result<Vec<_>, _>>()
            .map_err(sq)?;
        tx.commit().map_err(sq)?;
        Ok(ids)
    }

    /// Queues a trend sample; a background thread commits the queue at least once per second
    /// into the 1 s and 1 min buckets. Never blocks on the disk. On a read-only store, or with
    /// [`MAX_QUEUED_SAMPLES`] already waiting, the sample is dropped and counted.
    pub fn sample(&self, sample: Sample) {
        let mut q = lock(&self.inner.shared.queue);
        if self.is_read_only() || q.samples.len() >= MAX_QUEUED_SAMPLES {
            q.dropped += 1;
            return;
        }
        q.samples.push(sample);
    }

    /// How many samples were dropped because the queue was full or the store is read-only.
    pub fn dropped_samples(&self) -> u64 {
        lock(&self.inner.shared.queue).dropped
    }

    /// The last error the background thread met writing samples or pruning, if any since the
    /// last call (it is cleared by reading it).
    pub fn take_background_error(&self) -> Option<String> {
        lock(&self.inner.shared.queue).last_error.take()
    }

    /// Writes the queued samples now (tests, shutdown). Returns when they are committed.
    pub fn flush(&self) -> Result<(), StoreError> {
        if self.is_read_only() {
            return Err(StoreError::ReadOnly { path: self.path().to_path_buf() });
        }
        write_queued(&self.inner.shared)
    }

    /// The events matching `filter`, in id order (newest last). See [`EventFilter`] for which
    /// events are kept when there are more than `limit`.
    pub fn events(&self, filter: &EventFilter) -> Result<Vec<Event>, StoreError> {
        use rusqlite::types::Value;
        if filter.limit == 0 {
            return Ok(Vec::new());
        }
        let mut sql = String::from(
            "SELECT id, time_ms, kind, bus, drive, actor, action, result, detail FROM events WHERE 1",
        );
        let mut args: Vec<Value> = Vec::new();
        if let Some(t) = filter.since_ms {
            sql.push_str(" AND time_ms >= ?");
            args.push(Value::Integer(t));
        }
        if let Some(t) = filter.until_ms {
            sql.push_str(" AND time_ms < ?");
            args.push(Value::Integer(t));
        }
        if let Some(id) = filter.after_id {
            sql.push_str(" AND id > ?");
            args.push(Value::Integer(id));
        }
        if let Some(d) = &filter.drive {
            sql.push_str(" AND drive = ?");
            args.push(Value::Text(d.clone()));
        }
        if let Some(k) = filter.kind {
            sql.push_str(" AND kind = ?");
            args.push(Value::Text(k.as_str().to_string()));
        }
        let ascending = filter.after_id.is_some();
        sql.push_str(if ascending { " ORDER BY id ASC LIMIT ?" } else { " ORDER BY id DESC LIMIT ?" });
        args.push(Value::Integer(i64::try_from(filter.limit).unwrap_or(i64::MAX)));

        let path = self.path();
        let sq = |e| StoreError::sqlite(path, "reading events", e);
        let conn = lock(&self.inner.shared.reader);
        let mut st = conn.prepare(&sql).map_err(sq)?;
        let rows = st
            .query_map(rusqlite::params_from_iter(args), |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, i64>(1)?,
                    r.get::<_, String>(2)?,
                    r.get::<_, Option<String>>(3)?,
                    r.get::<_, Option<String>>(4)?,
                    r.get::<_, Option<String>>(5)?,
                    r.get::<_, Option<String>>(6)?,
                    r.get::<_, Option<String>>(7)?,
                    r.get::<_, Option<String>>(8)?,
                ))
            })
            .map_err(sq)?;
        let mut out = Vec::new();
        for row in rows {
            let (id, time_ms, kind, bus, drive, actor, action, result, detail) = row.map_err(sq)?;
            let kind = kind.parse::<EventKind>().map_err(|e| StoreError::BadRow {
                path: path.to_path_buf(),
                what: format!("event {id}: {e}"),
            })?;
            // A detail that is not JSON (edited by hand) is kept as a string rather than hiding
            // the event from the audit trail.
            let detail = match detail {
                None => serde_json::Value::Null,
                Some(text) => serde_json::from_str(&text).unwrap_or(serde_json::Value::String(text)),
            };
            out.push(Event { id, time_ms, kind, bus, drive, actor, action, result, detail });
        }
        if !ascending {
            out.reverse();
        }
        Ok(out)
    }

    /// The trend of one drive: buckets of the query's resolution starting in
    /// `since_ms..until_ms`, oldest first. Samples still queued are not included (call
    /// [`Store::flush`] first for those).
    pub fn trend(&self, query: &TrendQuery) -> Result<Vec<TrendPoint>, StoreError> {
        let sql = format!(
            "SELECT time_ms, samples, hz_sum, hz_n, hz_min, hz_max, a_sum, a_n, sp_sum, sp_n
             FROM {} WHERE drive = ?1 AND time_ms >= ?2 AND time_ms < ?3 ORDER BY time_ms",
            table(query.resolution)
        );
        let path = self.path();
        let sq = |e| StoreError::sqlite(path, "reading a trend", e);
        let conn = lock(&self.inner.shared.reader);
        let mut st = conn.prepare_cached(&sql).map_err(sq)?;
        let avg = |sum: f64, n: i64| if n > 0 { Some(sum / n as f64) } else { None };
        let rows = st
            .query_map(params![query.drive, query.since_ms, query.until_ms], |r| {
                Ok(TrendPoint {
                    time_ms: r.get(0)?,
                    samples: u32::try_from(r.get::<_, i64>(1)?).unwrap_or(u32::MAX),
                    output_hz: avg(r.get(2)?, r.get(3)?),
                    output_hz_min: r.get(4)?,
                    output_hz_max: r.get(5)?,
                    current_a: avg(r.get(6)?, r.get(7)?),
                    setpoint_hz: avg(r.get(8)?, r.get(9)?),
                })
            })
            .map_err(sq)?;
        rows.collect::<Result<Vec<_>, _>>().map_err(sq)
    }

    /// Deletes 1 s buckets that started more than a day before `now_ms` and 1 min buckets that
    /// started more than a year (365 days) before. Events are kept.
    pub fn prune(&self, now_ms: i64) -> Result<(), StoreError> {
        let conn = self.writer()?;
        prune_with(&conn, self.path(), now_ms)
    }
}

fn detail_json(event: &Event) -> Result<String, StoreError> {
    serde_json::to_string(&event.detail)
        .map_err(|e| StoreError::BadInput { what: format!("event detail is not storable JSON: {e}") })
}

fn insert_event(conn: &Connection, event: &Event, detail: &str) -> Result<i64, rusqlite::Error> {
    conn.prepare_cached(
        "INSERT INTO events (time_ms, kind, bus, drive, actor, action, result, detail)
         VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
    )?
    .execute(params![
        event.time_ms,
        event.kind.as_str(),
        event.bus,
        event.drive,
        event.actor,
        event.action,
        event.result,
        detail
    ])?;
    Ok(conn.last_insert_rowid())
}

fn table(res: Resolution) -> &'static str {
    match res {
        Resolution::Second => "trend_1s",
        Resolution::Minute => "trend_1m",
    }
}

/// Checks that the open file is a drivebus store (or, when `allow_new`, still empty).
fn check_header(conn: &Connection, path: &Path, allow_new: bool) -> Result<(), StoreError> {
    let sq = |e| StoreError::sqlite(path, "reading the header", e);
    let app_id: i32 = conn.query_row("PRAGMA application_id", [], |r| r.get(0)).map_err(sq)?;
    if app_id == APPLICATION_ID {
        let version: i64 = conn.query_row("PRAGMA user_version", [], |r| r.get(0)).map_err(sq)?;
        if version > SCHEMA_VERSION {
            return Err(StoreError::TooNew { path: path.to_path_buf(), found: version });
        }
        return Ok(());
    }
    if app_id != 0 {
        return Err(StoreError::Foreign { path: path.to_path_buf() });
    }
    let tables: i64 = conn.query_row("SELECT count(*) FROM sqlite_master", [], |r| r.get(0)).map_err(sq)?;
    if tables > 0 {
        return Err(StoreError::Foreign { path: path.to_path_buf() });
    }
    if allow_new {
        Ok(())
    } else {
        Err(StoreError::Empty { path: path.to_path_buf() })
    }
}

fn open_reader(path: &Path) -> Result<Connection, StoreError> {
    let sq = |doing| move |e| StoreError::sqlite(path, doing, e);
    let conn = Connection::open_with_flags(
        path,
        OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX | OpenFlags::SQLITE_OPEN_URI,
    )
    .map_err(sq("opening"))?;
    conn.busy_timeout(BUSY_TIMEOUT).map_err(sq("setting the busy timeout"))?;
    check_header(&conn, path, false)?;
    Ok(conn)
}

fn prune_with(conn: &Connection, path: &Path, now_ms: i64) -> Result<(), StoreError> {
    for res in [Resolution::Second, Resolution::Minute] {
        let cutoff = now_ms.saturating_sub(res.retention_ms());
        conn.execute(&format!("DELETE FROM {} WHERE time_ms < ?1", table(res)), [cutoff])
            .map_err(|e| StoreError::sqlite(path, "pruning old trend buckets", e))?;
    }
    Ok(())
}

/// One bucket being summed in memory before it is added to the table.
#[derive(Default)]
struct Agg {
    samples: i64,
    hz_sum: f64,
    hz_n: i64,
    hz_min: Option<f64>,
    hz_max: Option<f64>,
    a_sum: f64,
    a_n: i64,
    sp_sum: f64,
    sp_n: i64,
}

impl Agg {
    fn add(&mut self, s: &Sample) {
        self.samples += 1;
        if let Some(hz) = s.output_hz.filter(|v| v.is_finite()) {
            self.hz_sum += hz;
            self.hz_n += 1;
            self.hz_min = Some(self.hz_min.map_or(hz, |m| m.min(hz)));
            self.hz_max = Some(self.hz_max.map_or(hz, |m| m.max(hz)));
        }
        if let Some(a) = s.current_a.filter(|v| v.is_finite()) {
            self.a_sum += a;
            self.a_n += 1;
        }
        if let Some(sp) = s.setpoint_hz.filter(|v| v.is_finite()) {
            self.sp_sum += sp;
            self.sp_n += 1;
        }
    }
}

/// Takes the queue and adds it to both tables in one transaction. On failure the samples go back
/// to the front of the queue (up to its limit) so a passing lock or full disk loses nothing.
fn write_queued(shared: &Shared) -> Result<(), StoreError> {
    let Some(writer) = &shared.writer else {
        return Err(StoreError::ReadOnly { path: shared.path.clone() });
    };
    let batch = std::mem::take(&mut lock(&shared.queue).samples);
    if batch.is_empty() {
        return Ok(());
    }
    let mut conn = lock(writer);
    match write_batch(&mut conn, &batch) {
        Ok(()) => Ok(()),
        Err(e) => {
            drop(conn);
            let mut q = lock(&shared.queue);
            let newer = std::mem::replace(&mut q.samples, batch);
            q.samples.extend(newer);
            if q.samples.len() > MAX_QUEUED_SAMPLES {
                let excess = q.samples.len() - MAX_QUEUED_SAMPLES;
                q.samples.drain(..excess);
                q.dropped += excess as u64;
            }
            Err(StoreError::sqlite(&shared.path, "writing trend samples", e))
        }
    }
}

fn write_batch(conn: &mut Connection, batch: &[Sample]) -> Result<(), rusqlite::Error> {
    let tx = conn.transaction()?;
    for res in [Resolution::Second, Resolution::Minute] {
        let width = res.millis();
        let mut buckets: HashMap<(&str, i64), Agg> = HashMap::new();
        for s in batch {
            let start = s.time_ms.div_euclid(width) * width;
            buckets.entry((s.drive.as_str(), start)).or_default().add(s);
        }
        let mut st = tx.prepare_cached(&format!(
            "INSERT INTO {} (drive, time_ms, samples, hz_sum, hz_n, hz_min, hz_max, a_sum, a_n, sp_sum, sp_n)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11)
             ON CONFLICT (drive, time_ms) DO UPDATE SET
               samples = samples + excluded.samples,
               hz_sum = hz_sum + excluded.hz_sum, hz_n = hz_n + excluded.hz_n,
               hz_min = min(coalesce(hz_min, excluded.hz_min), coalesce(excluded.hz_min, hz_min)),
               hz_max = max(coalesce(hz_max, excluded.hz_max), coalesce(excluded.hz_max, hz_max)),
               a_sum = a_sum + excluded.a_sum, a_n = a_n + excluded.a_n,
               sp_sum = sp_sum + excluded.sp_sum, sp_n = sp_n + excluded.sp_n",
            table(res)
        ))?;
        for ((drive, start), a) in &buckets {
            st.execute(params![
                drive, start, a.samples, a.hz_sum, a.hz_n, a.hz_min, a.hz_max, a.a_sum, a.a_n, a.sp_sum,
                a.sp_n
            ])?;
        }
    }
    tx.commit()
}

/// The background thread: commits the queue every [`FLUSH_INTERVAL`], prunes every
/// [`PRUNE_INTERVAL`], and writes what is left when the last handle is dropped.
fn background(shared: &Shared) {
    let mut last_prune: Option<Instant> = None;
    let mut last_size_check: Option<Instant> = None;
    loop {
        let stop = {
            let q = lock(&shared.queue);
            let (q, _) = shared
                .wake
                .wait_timeout_while(q, FLUSH_INTERVAL, |q| !q.stop)
                .unwrap_or_else(PoisonError::into_inner);
            q.stop
        };
        let mut errors = Vec::new();
        if let Err(e) = write_queued(shared) {
            errors.push(e.to_string());
        }
        let prune = last_prune.map_or(true, |t| t.elapsed() >= PRUNE_INTERVAL);
        let size_check = last_size_check.map_or(true, |t| t.elapsed() >= SIZE_CHECK_INTERVAL);
        if let Some(writer) = &shared.writer {
            if prune {
                last_prune = Some(Instant::now());
                if let Err(e) = prune_with(&lock(writer), &shared.path, time::now_ms()) {
                    errors.push(e.to_string());
                }
            }
            if prune || size_check {
                last_size_check = Some(Instant::now());
                // The retention with the pruning; the cap at every check.
                let limits = if prune { shared.limits } else { Limits { retention: None, ..shared.limits } };
                if let Err(e) = limits::enforce(&lock(writer), &shared.path, &limits, time::now_ms()) {
                    errors.push(e.to_string());
                }
            }
        }
        if let Some(e) = errors.pop() {
            lock(&shared.queue).last_error = Some(e);
        }
        if stop {
            return;
        }
    }
}
