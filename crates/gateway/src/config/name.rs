//! `name`: the gateway's name, and the rule every gateway, bus and drive name follows.

use toml::Spanned;

use super::ctx::Ctx;
use super::ConfigError;

/// True for a name of a gateway, bus or drive: letters, digits, `-` and `_`, so it can be an MQTT
/// topic level, a URL path segment and a Prometheus label as it is.
pub fn valid_name(name: &str) -> bool {
    !name.is_empty() && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
}

/// Checks `name` (default `drivebus`).
pub(super) fn check(cx: &Ctx, raw: &Option<Spanned<String>>) -> Result<String, ConfigError> {
    let Some(n) = raw else { return Ok("drivebus".to_string()) };
    let name = n.get_ref().trim().to_string();
    if !valid_name(&name) {
        return cx.err(
            n.span(),
            "name",
            "use letters, digits, - and _ only (it is the MQTT topic level and client id)",
        );
    }
    Ok(name)
}
