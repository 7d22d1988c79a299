//! The `Host` header against DNS rebinding: with `[http] anonymous_read`, a web page elsewhere
//! could point a name of its own at the gateway's address and read the API from a browser in
//! the plant. A request whose `Host` is a name the gateway does not know gets 421: the
//! configured `[http] hosts`, `localhost` (and `*.localhost`) and any IP address (the listen
//! address among them; a rebinding attack needs a name) are accepted, as is a request without
//! `Host` (not a browser). Without `anonymous_read` every read needs a token a foreign page
//! does not have, and nothing is checked.

use std::net::IpAddr;
use std::sync::Arc;

use axum::extract::{Request, State};
use axum::http::{header, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use crate::core::Gateway;
use crate::http::error::ApiError;

/// Middleware: 421 `bad_host` for a `Host` that is not one of the gateway's names.
pub async fn check(State(gw): State<Arc<Gateway>>, req: Request, next: Next) -> Response {
    let config = gw.config();
    if config.http.anonymous_read {
        if let Some(host) = req.headers().get(header::HOST) {
            let host = String::from_utf8_lossy(host.as_bytes());
            if !allowed(&host, &config.http.hosts) {
                return ApiError::new(
                    StatusCode::MISDIRECTED_REQUEST,
                    "bad_host",
                    format!(
                        "Host {:?} is not a name of this gateway: use its address or a name listed \
                         in [http] hosts (docs/http-api.md)",
                        crate::text::shown(&host)
                    ),
                )
                .into_response();
            }
        }
    }
    next.run(req).await
}

/// Whether a `Host` header value (`name`, `name:port`, `[v6]:port`) names this gateway: an IP
/// address, `localhost` or `*.localhost`, or one of `hosts` (without case, a final dot ignored).
pub fn allowed(host: &str, hosts: &[String]) -> bool {
    let host = host.trim();
    let name = match host.strip_prefix('[') {
        Some(v6) => v6.split(']').next().unwrap_or_default(),
        None => match host.rsplit_once(':') {
            Some((name, port)) if port.bytes().all(|b| b.is_ascii_digit()) => name,
            _ => host,
        },
    };
    let name = name.strip_suffix('.').unwrap_or(name).to_ascii_lowercase();
    if name.is_empty() {
        return false;
    }
    name.parse::<IpAddr>().is_ok()
        || name == "localhost"
        || name.ends_with(".localhost")
        || hosts.iter().any(|h| h.strip_suffix('.').unwrap_or(h).eq_ignore_ascii_case(&name))
}

#[cfg(test)]
mod tests {
    use super::allowed;

    #[test]
    fn names_addresses_and_localhost() {
        let hosts = vec!["scada.plant.local".to_string()];
        for ok in [
            "scada.plant.local",
            "SCADA.plant.local.:8080",
            "localhost:8080",
            "app.localhost",
            "127.0.0.1:8080",
            "10.0.0.5",
            "[::1]:8080",
            "[fe80::1]",
        ] {
            assert!(allowed(ok, &hosts), "{ok}");
        }
        for bad in [
            "evil.example",
            "evil.example:8080",
            "scada.plant.local.evil.example",
            "",
            ":8080",
            "localhost.evil.example",
        ] {
            assert!(!allowed(bad, &hosts), "{bad}");
        }
    }
}
