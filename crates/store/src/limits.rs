//! What the store keeps at most: events no older than a retention period, and a file no larger
//! than a size cap (oldest events and trend buckets deleted first). Enforced when the store opens
//! and then periodically by its background thread ([`crate::Store::enforce_limits`]).

use std::path::Path;
use std::time::Duration;

use rusqlite::Connection;

use crate::StoreError;

/// How often the background thread checks the size cap (cheap: two pragmas).
pub const SIZE_CHECK_INTERVAL: Duration = Duration::from_secs(10);

/// The limits of one store. The default keeps events 365 days and the file under 1 GiB.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Events older than this are deleted (`None`: kept for ever, within the size cap).
    pub retention: Option<Duration>,
    /// The data (events, trends) is kept under this many bytes (`None`: no cap).
    pub max_bytes: Option<u64>,
}

impl Default for Limits {
    fn default() -> Self {
        Limits { retention: Some(Duration::from_secs(365 * 86_400)), max_bytes: Some(1 << 30) }
    }
}

impl Limits {
    /// No retention, no cap (tests; a store that only an operator prunes).
    pub const NONE: Limits = Limits { retention: None, max_bytes: None };

    /// `retention_days` (0: for ever) and `max_size_mb` (0: no cap) as a configuration gives them.
    pub fn from_days_and_mb(retention_days: u64, max_size_mb: u64) -> Limits {
        Limits {
            retention: (retention_days > 0)
                .then(|| Duration::from_secs(retention_days.saturating_mul(86_400))),
            max_bytes: (max_size_mb > 0).then(|| max_size_mb.saturating_mul(1 << 20)),
        }
    }
}

/// What [`crate::Store::enforce_limits`] deleted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Enforced {
    /// Events deleted (past the retention, or oldest for the size cap).
    pub events: u64,
    /// Trend buckets deleted for the size cap.
    pub buckets: u64,
}

/// The tables the size cap takes the oldest rows of, all keyed by `time_ms`.
const TABLES: [&str; 3] = ["events", "trend_1s", "trend_1m"];

/// Bytes in use by the data (pages not on the free list).
pub(crate) fn used_bytes(conn: &Connection) -> rusqlite::Result<u64> {
    let pragma = |p: &str| conn.query_row(&format!("PRAGMA {p}"), [], |r| r.get::<_, i64>(0));
    let used = pragma("page_count")?.saturating_sub(pragma("freelist_count")?);
    Ok(used.max(0) as u64 * pragma("page_size")?.max(0) as u64)
}

/// Deletes events past the retention, then the oldest rows of every table until the data fits
/// under the cap: each round deletes everything older than a tenth of the time the store spans.
pub(crate) fn enforce(
    conn: &Connection,
    path: &Path,
    limits: &Limits,
    now_ms: i64,
) -> Result<Enforced, StoreError> {
    let sq = |e| StoreError::sqlite(path, "enforcing the retention and size cap", e);
    let mut done = Enforced::default();
    if let Some(keep) = limits.retention {
        let keep_ms = i64::try_from(keep.as_millis()).unwrap_or(i64::MAX);
        let cutoff = now_ms.saturating_sub(keep_ms);
        done.events += conn.execute("DELETE FROM events WHERE time_ms < ?1", [cutoff]).map_err(sq)? as u64;
    }
    let Some(max) = limits.max_bytes else { return Ok(done) };
    for _ in 0..64 {
        if used_bytes(conn).map_err(sq)? <= max {
            break;
        }
        let span: (Option<i64>, Option<i64>) = conn
            .query_row(
                "SELECT min(t), max(t) FROM (SELECT min(time_ms) AS t FROM events UNION ALL \
                 SELECT max(time_ms) FROM events UNION ALL SELECT min(time_ms) FROM trend_1s UNION ALL \
                 SELECT max(time_ms) FROM trend_1s UNION ALL SELECT min(time_ms) FROM trend_1m UNION ALL \
                 SELECT max(time_ms) FROM trend_1m)",
                [],
                |r| Ok((r.get(0)?, r.get(1)?)),
            )
            .map_err(sq)?;
        let (Some(oldest), Some(newest)) = span else { break };
        let cutoff = oldest.saturating_add((newest.saturating_sub(oldest) / 10).max(1));
        for table in TABLES {
            let n = conn.execute(&format!("DELETE FROM {table} WHERE time_ms < ?1"), [cutoff]).map_err(sq)?;
            if table == "events" {
                done.events += n as u64;
            } else {
                done.buckets += n as u64;
            }
        }
    }
    Ok(done)
}
