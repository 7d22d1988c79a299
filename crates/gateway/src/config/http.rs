//! `[http]`: the HTTP listener, HTTPS with `tls_cert` and `tls_key`, and the rule that write
//! tokens do not cross a network in clear (`allow_plaintext` to opt out).

use std::path::PathBuf;

use super::ctx::Ctx;
use super::file::FileHttp;
use super::{ConfigError, HttpConfig, HttpTls, Role, Token};

impl HttpConfig {
    /// Why this listener may not serve `tokens`: a write token would cross the network in clear
    /// (plain HTTP on an address other than loopback). `None` with HTTPS, on loopback, without
    /// a write token, or with `allow_plaintext`.
    pub fn plaintext_refusal(&self, tokens: &[Token]) -> Option<String> {
        let writes = tokens.iter().any(|t| t.role == Role::Write);
        if self.tls.is_some() || self.allow_plaintext || self.listen.ip().is_loopback() || !writes {
            return None;
        }
        Some(format!(
            "write tokens would cross the network in clear on http://{}: give [http] tls_cert and \
             tls_key (HTTPS), listen on 127.0.0.1, or set [http] allow_plaintext = true to accept that",
            self.listen
        ))
    }
}

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
    let tls = match (&raw.tls_cert, &raw.tls_key) {
        (Some(cert), Some(key)) => {
            let tls = HttpTls { cert: PathBuf::from(cert.get_ref()), key: PathBuf::from(key.get_ref()) };
            // Read them now: a file that cannot be used is this check's error.
            if let Err(e) = super::tls::server_config(&tls.cert, &tls.key) {
                let at = if e.starts_with("tls_key") { key.span() } else { cert.span() };
                let field = if e.starts_with("tls_key") { "http.tls_key" } else { "http.tls_cert" };
                return cx.err(at, field, e);
            }
            Some(tls)
        }
        (None, None) => None,
        (Some(cert), None) => {
            return cx.err(cert.span(), "http.tls_cert", "give tls_key too (the certificate's private key)")
        }
        (None, Some(key)) => {
            return cx.err(key.span(), "http.tls_key", "give tls_cert too (the key's certificate)")
        }
    };
    Ok(HttpConfig {
        listen,
        anonymous_read: raw.anonymous_read.unwrap_or(false),
        max_body,
        hosts,
        tls,
        allow_plaintext: raw.allow_plaintext,
    })
}

/// Checks the plain-text rule of `[http]` against the tokens; the error is at `listen`.
pub(super) fn check_plaintext(
    cx: &Ctx,
    raw: &FileHttp,
    http: &HttpConfig,
    tokens: &[Token],
) -> Result<(), ConfigError> {
    match (http.plaintext_refusal(tokens), &raw.listen) {
        (Some(why), Some(at)) => cx.err(at.span(), "http.listen", why),
        // The default address is loopback: the rule cannot refuse it.
        _ => Ok(()),
    }
}
