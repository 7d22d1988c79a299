//! `[opcua]`: the OPC UA server (docs/opcua.md).

use std::path::PathBuf;

use super::ctx::Ctx;
use super::file::FileOpcUa;
use super::{ConfigError, HttpConfig, OpcUaConfig};

/// Checks `[opcua]`: on unless `disabled = true`; anonymous reads as `[http]` unless said.
pub(super) fn check(
    cx: &Ctx,
    raw: &FileOpcUa,
    http: &HttpConfig,
) -> Result<Option<OpcUaConfig>, ConfigError> {
    if raw.disabled {
        return Ok(None);
    }
    Ok(Some(OpcUaConfig {
        listen: cx.listener(&raw.listen, "opcua.listen", "127.0.0.1:4840")?,
        anonymous_read: raw.anonymous_read.unwrap_or(http.anonymous_read),
        pki_dir: raw.pki_dir.as_ref().map(PathBuf::from),
        trusted_clients: raw.trusted_clients.iter().map(PathBuf::from).collect(),
    }))
}
