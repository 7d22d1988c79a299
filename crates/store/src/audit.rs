//! Two-step audit records: a command's event is committed before the command is carried out
//! (result `pending`), and its outcome written into it after ([`Store::set_result`]). So a
//! command the store cannot record is never carried out, and one interrupted by a crash stays
//! in the trail as `pending`.

use rusqlite::params;

use crate::{Store, StoreError};

/// The result of a command's event until its outcome is known.
pub const PENDING: &str = "pending";

impl Store {
    /// Writes `result` into event `id` (recorded `pending` before its command was carried out)
    /// and returns once committed.
    pub fn set_result(&self, id: i64, result: &str) -> Result<(), StoreError> {
        let conn = self.writer()?;
        conn.prepare_cached("UPDATE events SET result = ?2 WHERE id = ?1")
            .and_then(|mut s| s.execute(params![id, result]))
            .map(|_| ())
            .map_err(|e| StoreError::sqlite(self.path(), "recording a command's result", e))
    }

    /// Caps the file at `pages` pages (SQLite's `max_page_count`, for this process): writes
    /// that need more fail as on a full disk ("database or disk is full"). Returns the cap in
    /// force (never below the pages the file already has). For tests of a full disk.
    pub fn set_max_pages(&self, pages: u64) -> Result<u64, StoreError> {
        let conn = self.writer()?;
        conn.query_row(&format!("PRAGMA max_page_count = {pages}"), [], |r| r.get(0))
            .map_err(|e| StoreError::sqlite(self.path(), "capping the file's size", e))
    }
}
