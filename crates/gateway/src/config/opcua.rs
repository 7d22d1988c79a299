//! `[opcua]`: the OPC UA server (docs/opcua.md).

use std::path::PathBuf;

use super::ctx::Ctx;
use super::file::FileOpcUa;
use super::{ConfigError, HttpConfig, OpcUaConfig, DEFAULT_MAX_SESSIONS_PER_USER};

/// Checks `[opcua]`: on unless `disabled = true`; anonymous reads as `[http]` unless said; a
/// host name without scheme or port; 1 or more sessions per user.
pub(super) fn check(
    cx: &Ctx,
    raw: &FileOpcUa,
    http: &HttpConfig,
) -> Result<Option<OpcUaConfig>, ConfigError> {
    if raw.disabled {
        return Ok(None);
    }
    let host = match &raw.host {
        None => None,
        Some(h) => {
            let name = h.get_ref().trim();
            let bad = name.is_empty()
                || !name.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '.' | '_'));
            if bad {
                return cx.err(
                    h.span(),
                    "opcua.host",
                    format!(
                        "{:?}: give the host name or IPv4 address clients use (gw-1.plant.local), \
                         without scheme or port",
                        h.get_ref()
                    ),
                );
            }
            Some(name.to_string())
        }
    };
    Ok(Some(OpcUaConfig {
        listen: cx.listener(&raw.listen, "opcua.listen", "127.0.0.1:4840")?,
        anonymous_read: raw.anonymous_read.unwrap_or(http.anonymous_read),
        pki_dir: raw.pki_dir.as_ref().map(PathBuf::from),
        trusted_clients: raw.trusted_clients.iter().map(PathBuf::from).collect(),
        insecure_writes: raw.insecure_writes,
        max_sessions_per_user: cx.at_least_one(
            &raw.max_sessions_per_user,
            "opcua.max_sessions_per_user",
            DEFAULT_MAX_SESSIONS_PER_USER,
        )?,
        host,
    }))
}
