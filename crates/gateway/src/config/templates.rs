//! `templates = ["FILE", ...]` at the top of the file: drive templates (docs/templates.md) whose
//! kinds `family = "..."` may then name, as a built-in family. A relative path is taken from the
//! configuration file's folder. Each file is checked as `drivebus template check` checks it.

use std::path::{Path, PathBuf};

use drivebus_drive::template::{self, Template};
use toml::Spanned;

use super::ctx::Ctx;
use super::ConfigError;

/// Reads and registers the templates; their paths as read.
pub(super) fn check(cx: &Ctx, raw: &[Spanned<String>]) -> Result<Vec<PathBuf>, ConfigError> {
    let base = Path::new(cx.file).parent().unwrap_or(Path::new(""));
    let mut out = Vec::new();
    for t in raw {
        let path = base.join(t.get_ref());
        let loaded = Template::load(&path).map_err(|e| {
            let more = e.errors.len() - 1;
            let first = e.to_string().lines().next().unwrap_or_default().to_string();
            if more == 0 {
                first
            } else {
                format!("{first} (and {more} more: drivebus template check {})", path.display())
            }
        });
        if let Err(e) = loaded.and_then(template::register) {
            return cx.err(t.span(), "templates", e);
        }
        out.push(path);
    }
    Ok(out)
}
