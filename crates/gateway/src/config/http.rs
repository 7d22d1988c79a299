//! `[http]`: the HTTP listener.

use super::ctx::Ctx;
use super::file::FileHttp;
use super::{ConfigError, HttpConfig};

/// Checks `[http]`.
pub(super) fn check(cx: &Ctx, raw: &FileHttp) -> Result<HttpConfig, ConfigError> {
    let listen = cx.listener(&raw.listen, "http.listen", "127.0.0.1:8080")?;
    let max_body = cx.within(&raw.max_body, 256..=16 << 20, "http.max_body", " bytes", 64 * 1024)?;
    let mut hosts = Vec::new();
    for h in &raw.hosts {
        let name = h.get_ref().trim();
        if name.is_empty() || name.contains([':', '/', ' ', '[', ']', '@']) {
            return cx.err(
                h.span(),
                "http.hosts",
                format!(
                    "{:?}: give a host name alone (scada.plant.local), without scheme or port",
                    h.get_ref()
                ),
            );
        }
        hosts.push(name.to_ascii_lowercase());
    }
    Ok(HttpConfig { listen, anonymous_read: raw.anonymous_read.unwrap_or(false), max_body, hosts })
}
