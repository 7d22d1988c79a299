//! A drive kind with named values for the front ends' tests: the shipped generic-2000h map as
//! kind `tpl-values`, with `[values]` `dc_bus_v` (V, 2105H) and `power_kw` (kW, 2106H), which
//! the simulator fills from its motor model.

use std::path::{Path, PathBuf};

/// The kind the file names.
pub const KIND: &str = "tpl-values";

/// Writes the template as `tpl.toml` in `dir` (a configuration there names it
/// `templates = ["tpl.toml"]`); its path.
pub fn write(dir: &Path) -> PathBuf {
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../templates/generic-2000h.toml");
    let text = std::fs::read_to_string(shipped)
        .unwrap()
        .replace("kind = \"generic-2000h\"", &format!("kind = \"{KIND}\""));
    let values = "[values]\ndc_bus_v = { register = 0x2105, scale = 0.1, unit = \"V\" }\n\
                  power_kw = { register = 0x2106, scale = 0.01, unit = \"kW\" }\n";
    let path = dir.join("tpl.toml");
    std::fs::write(&path, format!("{text}\n{values}")).unwrap();
    path
}
