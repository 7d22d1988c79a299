//! `[store]`: where events and trends are kept, and for how long.

use std::path::PathBuf;

use super::file::FileStore;
use super::{ConfigError, Ctx};

/// The store's file name in the state folder when `[store] path` is not given.
pub const DEFAULT_FILE: &str = "drivebus.db";

/// Checks `[store]`: the file (`None`: `disabled = true`) and its retention and size cap.
/// Without `path` the file is [`DEFAULT_FILE`] in `state_dir` (the state folder, never the
/// working directory).
pub(super) fn check(
    cx: &Ctx,
    raw: FileStore,
    state_dir: Result<PathBuf, String>,
) -> Result<(Option<PathBuf>, drivebus_store::Limits), ConfigError> {
    let limits = drivebus_store::Limits::from_days_and_mb(raw.retention_days, raw.max_size_mb);
    let path = match (raw.disabled, raw.path) {
        (true, _) => None,
        (false, Some(path)) => Some(PathBuf::from(path)),
        (false, None) => Some(state_dir.map(|d| d.join(DEFAULT_FILE)).map_err(|e| {
            ConfigError(format!(
                "{}: [store] has no path and there is {e}: name the file with [store] path = \"/var/lib/drivebus/drivebus.db\", or keep nothing with disabled = true",
                cx.file
            ))
        })?),
    };
    Ok((path, limits))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check_text(text: &str, state: Result<PathBuf, String>) -> Result<Option<PathBuf>, ConfigError> {
        let cx = Ctx { file: "t.toml", text };
        let raw: super::super::file::FileConfig = toml::from_str(text).unwrap();
        check(&cx, raw.store, state).map(|(p, _)| p)
    }

    #[test]
    fn without_a_path_the_store_goes_to_the_state_folder_never_the_working_directory() {
        let state = || Ok(PathBuf::from("/var/lib/drivebus"));
        assert_eq!(check_text("", state()).unwrap(), Some(PathBuf::from("/var/lib/drivebus/drivebus.db")));
        assert_eq!(
            check_text("[store]\nretention_days = 3\n", state()).unwrap().unwrap(),
            PathBuf::from("/var/lib/drivebus/drivebus.db")
        );
        // A path the user names is taken as written.
        assert_eq!(
            check_text("[store]\npath = \"plant.db\"\n", state()).unwrap(),
            Some(PathBuf::from("plant.db"))
        );
        assert_eq!(check_text("[store]\ndisabled = true\n", state()).unwrap(), None);
    }

    #[test]
    fn without_a_path_and_without_a_state_folder_the_error_says_what_to_write() {
        let e = check_text(
            "",
            Err("no state folder: neither $STATE_DIRECTORY, $XDG_STATE_HOME nor $HOME is an absolute path"
                .into()),
        )
        .unwrap_err()
        .to_string();
        assert!(e.starts_with("t.toml: [store] has no path"), "{e}");
        assert!(e.contains("[store] path = \"/var/lib/drivebus/drivebus.db\""), "{e}");
        assert!(!e.contains('\n'), "{e}");
        // Disabled, no state folder is needed.
        assert_eq!(check_text("[store]\ndisabled = true\n", Err("none".into())).unwrap(), None);
    }
}
