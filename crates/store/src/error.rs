//! [`StoreError`]: what went wrong with the store file, in one line that says what to do.

use std::fmt;
use std::path::{Path, PathBuf};

/// Everything the store can fail with. `Display` is one line naming the file and what to do.
#[derive(Debug)]
#[non_exhaustive]
pub enum StoreError {
    /// [`Store::open_read_only`](crate::Store::open_read_only) was given a file that does not exist.
    Missing {
        /// The file asked for.
        path: PathBuf,
    },
    /// The file exists but is not an SQLite database (or its header is damaged).
    NotADatabase {
        /// The file.
        path: PathBuf,
    },
    /// The file exists but is empty: no store was ever created in it.
    Empty {
        /// The file.
        path: PathBuf,
    },
    /// The file is an SQLite database of something else (its tables are not the store's).
    Foreign {
        /// The file.
        path: PathBuf,
    },
    /// The file was written by a newer drivebus with a schema this one does not know.
    TooNew {
        /// The file.
        path: PathBuf,
        /// The schema version found in the file.
        found: i64,
    },
    /// A write was asked of a store opened with [`Store::open_read_only`](crate::Store::open_read_only).
    ReadOnly {
        /// The file.
        path: PathBuf,
    },
    /// A row the store cannot read back (edited by hand or damaged).
    BadRow {
        /// The file.
        path: PathBuf,
        /// Which row and what is wrong with it.
        what: String,
    },
    /// A value given to the store that it cannot keep (an event whose detail is not serializable).
    BadInput {
        /// What was wrong.
        what: String,
    },
    /// SQLite refused: I/O error, disk full, locked past the busy timeout, permissions.
    Sqlite {
        /// The file.
        path: PathBuf,
        /// What the store was doing.
        doing: &'static str,
        /// SQLite's error.
        source: rusqlite::Error,
    },
}

impl StoreError {
    pub(crate) fn sqlite(path: &Path, doing: &'static str, source: rusqlite::Error) -> StoreError {
        if let rusqlite::Error::SqliteFailure(e, _) = &source {
            if e.code == rusqlite::ErrorCode::NotADatabase {
                return StoreError::NotADatabase { path: path.to_path_buf() };
            }
        }
        StoreError::Sqlite { path: path.to_path_buf(), doing, source }
    }

    /// The file the error is about, if it is about one.
    pub fn path(&self) -> Option<&Path> {
        match self {
            StoreError::Missing { path }
            | StoreError::NotADatabase { path }
            | StoreError::Empty { path }
            | StoreError::Foreign { path }
            | StoreError::TooNew { path, .. }
            | StoreError::ReadOnly { path }
            | StoreError::BadRow { path, .. }
            | StoreError::Sqlite { path, .. } => Some(path),
            StoreError::BadInput { .. } => None,
        }
    }
}

impl fmt::Display for StoreError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            StoreError::Missing { path } => {
                write!(f, "no event store at {}: start `drivebus serve` or give --db FILE", path.display())
            }
            StoreError::NotADatabase { path } => write!(
                f,
                "{} is not a drivebus event store (not an SQLite database, or damaged): \
                 give another file, or move this one aside to start a new store",
                path.display()
            ),
            StoreError::Empty { path } => write!(
                f,
                "{} is empty, not a drivebus event store: start `drivebus serve` to create it, \
                 or give another file",
                path.display()
            ),
            StoreError::Foreign { path } => write!(
                f,
                "{} is an SQLite database of something else, not a drivebus event store: \
                 give another file",
                path.display()
            ),
            StoreError::TooNew { path, found } => write!(
                f,
                "{} has store schema version {found}, newer than this drivebus knows ({}): \
                 use a newer drivebus",
                path.display(),
                crate::SCHEMA_VERSION
            ),
            StoreError::ReadOnly { path } => {
                write!(f, "{} was opened read-only: open it with Store::open to write", path.display())
            }
            StoreError::BadRow { path, what } => write!(
                f,
                "{}: {what}: the file was edited or damaged; restore it from a backup",
                path.display()
            ),
            StoreError::BadInput { what } => write!(f, "{what}"),
            StoreError::Sqlite { path, doing, source } => {
                let hint = match source.sqlite_error_code() {
                    Some(rusqlite::ErrorCode::DatabaseBusy | rusqlite::ErrorCode::DatabaseLocked) => {
                        "another process holds the file locked; retry, or stop it"
                    }
                    Some(rusqlite::ErrorCode::DiskFull) => "the disk is full; free space",
                    Some(rusqlite::ErrorCode::ReadOnly | rusqlite::ErrorCode::PermissionDenied) => {
                        "the file or its directory is not writable; check permissions"
                    }
                    Some(rusqlite::ErrorCode::CannotOpen) => {
                        "the file cannot be opened; check the path and permissions"
                    }
                    Some(rusqlite::ErrorCode::DatabaseCorrupt) => {
                        "the file is damaged; restore it from a backup or move it aside"
                    }
                    _ => "check the file and the disk",
                };
                let msg = source.to_string().replace('\n', " ");
                write!(f, "{} ({doing}): {msg}: {hint}", path.display())
            }
        }
    }
}

impl std::error::Error for StoreError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            StoreError::Sqlite { source, .. } => Some(source),
            _ => None,
        }
    }
}
