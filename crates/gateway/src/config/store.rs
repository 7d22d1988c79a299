//! `[store]`: where events and trends are kept, and for how long.

use std::path::PathBuf;

use super::file::FileStore;

/// Checks `[store]`: the file (`None`: `disabled = true`) and its retention and size cap.
pub(super) fn check(raw: FileStore) -> (Option<PathBuf>, drivebus_store::Limits) {
    let limits = drivebus_store::Limits::from_days_and_mb(raw.retention_days, raw.max_size_mb);
    let path = if raw.disabled {
        None
    } else {
        Some(PathBuf::from(raw.path.unwrap_or_else(|| "drivebus.db".to_string())))
    };
    (path, limits)
}
