//! What a Sparkplug B edge node keeps across restarts: its `bdSeq` (the birth/death sequence
//! number, one per MQTT session) and the store-and-forward queue of data messages that could
//! not be published (no broker, or the primary host offline). The payloads are opaque bytes
//! here; the gateway encodes and decodes them.

use rusqlite::{params, OptionalExtension};

use crate::{Store, StoreError};

/// The tables, created (if missing) whenever a store is opened for writing; older drivebus
/// versions ignore them, so the schema version does not change.
pub const SPARKPLUG_SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS sparkplug_node (
    node    TEXT PRIMARY KEY,
    bd_seq  INTEGER,
    queued  INTEGER NOT NULL DEFAULT 0
);
CREATE TABLE IF NOT EXISTS sparkplug_spool (
    id      INTEGER PRIMARY KEY AUTOINCREMENT,
    node    TEXT NOT NULL,
    device  TEXT NOT NULL,
    time_ms INTEGER NOT NULL,
    payload BLOB NOT NULL
);
CREATE INDEX IF NOT EXISTS sparkplug_spool_node ON sparkplug_spool (node, id);
CREATE INDEX IF NOT EXISTS sparkplug_spool_time ON sparkplug_spool (node, time_ms);
";

/// A message waiting in the store-and-forward queue.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Spooled {
    /// Its place in the queue (increasing).
    pub id: i64,
    /// The device (drive) it is about.
    pub device: String,
    /// When its values were read, unix ms.
    pub time_ms: i64,
    /// The encoded message.
    pub payload: Vec<u8>,
}

/// What a push did: how many queued messages it dropped to stay within its limits, and how
/// many are queued now.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SpoolDropped {
    /// Dropped because the queue held more than its number of messages (oldest first).
    pub over_count: u64,
    /// Dropped because they were older than the age limit.
    pub too_old: u64,
    /// Messages in the queue after the push.
    pub queued: u64,
}

impl Store {
    /// The `bdSeq` for the next MQTT session of edge node `node` (`group/edge node`): one more
    /// than the last one handed out, wrapping from 255 to 0 as Sparkplug B 3.0 says; 0 for a
    /// node never seen. Committed before it returns, so a restart never reuses a number.
    pub fn next_bd_seq(&self, node: &str) -> Result<u64, StoreError> {
        let conn = self.writer()?;
        let sq = |e| StoreError::sqlite(self.path(), "updating the Sparkplug bdSeq", e);
        let last: Option<i64> = conn
            .query_row("SELECT bd_seq FROM sparkplug_node WHERE node = ?1", [node], |r| r.get(0))
            .optional()
            .map_err(sq)?
            .flatten();
        let next = last.map_or(0, |l| (l + 1).rem_euclid(256));
        conn.execute(
            "INSERT INTO sparkplug_node (node, bd_seq) VALUES (?1, ?2)
             ON CONFLICT (node) DO UPDATE SET bd_seq = excluded.bd_seq",
            params![node, next],
        )
        .map_err(sq)?;
        Ok(next as u64)
    }

    /// Appends `(device, time_ms, payload)` messages to `node`'s queue in one transaction, then
    /// drops the oldest beyond `max_messages` and those read before `oldest_ms`.
    pub fn spool_push(
        &self,
        node: &str,
        items: &[(String, i64, Vec<u8>)],
        max_messages: u64,
        oldest_ms: i64,
    ) -> Result<SpoolDropped, StoreError> {
        let mut conn = self.writer()?;
        let sq = |e| StoreError::sqlite(self.path(), "queueing Sparkplug messages", e);
        let tx = conn.transaction().map_err(sq)?;
        {
            let mut ins = tx
                .prepare_cached(
                    "INSERT INTO sparkplug_spool (node, device, time_ms, payload) VALUES (?1, ?2, ?3, ?4)",
                )
                .map_err(sq)?;
            for (device, time_ms, payload) in items {
                ins.execute(params![node, device, time_ms, payload]).map_err(sq)?;
            }
        }
        let too_old = tx
            .execute("DELETE FROM sparkplug_spool WHERE node = ?1 AND time_ms < ?2", params![node, oldest_ms])
            .map_err(sq)? as u64;
        let count = (queued(&tx, node).map_err(sq)? + items.len() as u64).saturating_sub(too_old);
        let excess = count.saturating_sub(max_messages);
        let over_count = if excess > 0 {
            tx.execute(
                "DELETE FROM sparkplug_spool WHERE id IN
                 (SELECT id FROM sparkplug_spool WHERE node = ?1 ORDER BY id LIMIT ?2)",
                params![node, excess as i64],
            )
            .map_err(sq)? as u64
        } else {
            0
        };
        let now = count.saturating_sub(over_count);
        set_queued(&tx, node, now).map_err(sq)?;
        tx.commit().map_err(sq)?;
        Ok(SpoolDropped { over_count, too_old, queued: now })
    }

    /// The oldest `max` messages of `node`'s queue, oldest first (they stay queued until
    /// [`Store::spool_remove`]).
    pub fn spool_peek(&self, node: &str, max: usize) -> Result<Vec<Spooled>, StoreError> {
        let conn = self.writer()?;
        let sq = |e| StoreError::sqlite(self.path(), "reading queued Sparkplug messages", e);
        let mut st = conn
            .prepare_cached(
                "SELECT id, device, time_ms, payload FROM sparkplug_spool WHERE node = ?1 ORDER BY id LIMIT ?2",
            )
            .map_err(sq)?;
        let rows = st
            .query_map(params![node, max as i64], |r| {
                Ok(Spooled { id: r.get(0)?, device: r.get(1)?, time_ms: r.get(2)?, payload: r.get(3)? })
            })
            .map_err(sq)?;
        rows.collect::<Result<Vec<_>, _>>().map_err(sq)
    }

    /// Removes `node`'s queued messages up to and including id `through` (they were sent);
    /// returns how many are still queued.
    pub fn spool_remove(&self, node: &str, through: i64) -> Result<u64, StoreError> {
        let mut conn = self.writer()?;
        let sq = |e| StoreError::sqlite(self.path(), "removing sent Sparkplug messages", e);
        let tx = conn.transaction().map_err(sq)?;
        let removed = tx
            .execute("DELETE FROM sparkplug_spool WHERE node = ?1 AND id <= ?2", params![node, through])
            .map_err(sq)? as u64;
        let now = queued(&tx, node).map_err(sq)?.saturating_sub(removed);
        set_queued(&tx, node, now).map_err(sq)?;
        tx.commit().map_err(sq)?;
        Ok(now)
    }

    /// How many messages wait in `node`'s queue (kept as a count, not counted row by row).
    pub fn spool_len(&self, node: &str) -> Result<u64, StoreError> {
        let conn = self.writer()?;
        queued(&conn, node)
            .map_err(|e| StoreError::sqlite(self.path(), "counting queued Sparkplug messages", e))
    }
}

fn queued(conn: &rusqlite::Connection, node: &str) -> Result<u64, rusqlite::Error> {
    let n: Option<i64> = conn
        .query_row("SELECT queued FROM sparkplug_node WHERE node = ?1", [node], |r| r.get(0))
        .optional()?;
    Ok(n.unwrap_or(0).max(0) as u64)
}

fn set_queued(conn: &rusqlite::Connection, node: &str, n: u64) -> Result<(), rusqlite::Error> {
    conn.execute(
        "INSERT INTO sparkplug_node (node, queued) VALUES (?1, ?2)
         ON CONFLICT (node) DO UPDATE SET queued = excluded.queued",
        params![node, n as i64],
    )?;
    Ok(())
}
