//! Generated sections of the Markdown docs: everything after a marker comment is rendered from
//! the code (the catalogs) and a test checks it; with `DRIVEBUS_BLESS=1` set, the test rewrites
//! it instead. docs/parameters.md and docs/register-map.md are kept this way.

use std::path::Path;

use crate::{format_fixed, ParamDef};

/// `text` for a cell of a Markdown table: its `|` escaped.
pub fn cell(text: &str) -> String {
    text.replace('|', "\\|")
}

/// The range of `p` in its unit, as the generated tables show it (`0.00..50.00 Hz`).
pub fn range(p: &ParamDef) -> String {
    let unit = if p.unit.is_empty() { String::new() } else { format!(" {}", p.unit) };
    format!("{}..{}{unit}", format_fixed(p.min, p.scale), format_fixed(p.max, p.scale))
}

/// Checks that `path` holds, after the comment that starts with `marker`, exactly `rendered`;
/// rewrites it when the environment has `DRIVEBUS_BLESS`. The error says to run `bless`.
pub fn check_section(path: &Path, marker: &str, rendered: &str, bless: &str) -> Result<(), String> {
    let current = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let at =
        current.find(marker).ok_or_else(|| format!("{} has no marker line {marker:?}", path.display()))?;
    let marker_end = current[at..].find("-->").map_or(current.len(), |i| at + i + 3);
    let expected = format!("{}\n{rendered}", &current[..marker_end]);
    if std::env::var_os("DRIVEBUS_BLESS").is_some() {
        return std::fs::write(path, &expected).map_err(|e| format!("{}: {e}", path.display()));
    }
    if current != expected {
        return Err(format!("{} is out of date with the catalogs; run {bless}", path.display()));
    }
    Ok(())
}
