//! Bearer tokens: `Authorization: Bearer <token>`, compared in constant time against every
//! configured token. Reads need a read or write token unless `[http] anonymous_read`; writes
//! need a write token (401 without or with an unknown token, 403 with a read token). A failed
//! login (an unknown or malformed token) is audited and logged like a refused write (aggregated
//! per address, `crate::refusals`); after [`MAX_LOGIN_FAILURES`] in a minute, the address's
//! requests with a token get 429 until the minute is over.

use std::net::SocketAddr;
use std::sync::Arc;

use axum::extract::connect_info::MockConnectInfo;
use axum::extract::{ConnectInfo, FromRequestParts};
use axum::http::request::Parts;
use axum::http::{header, StatusCode};

use crate::config::{Role, Token};
use crate::core::{Gateway, MAX_LOGIN_FAILURES};
use crate::http::error::ApiError;

/// Whether `a` and `b` are equal, in a time that depends only on `a`'s length.
pub fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    let mut diff = u8::from(a.len() != b.len());
    for (i, x) in a.iter().enumerate() {
        let y = if b.is_empty() { 0 } else { b[i % b.len()] };
        diff |= std::hint::black_box(x ^ y);
    }
    diff == 0
}

/// The configured token whose secret is `presented`, looking at every token whatever matches.
pub fn find_token<'t>(tokens: &'t [Token], presented: &str) -> Option<&'t Token> {
    let mut found = None;
    for t in tokens {
        if constant_time_eq(presented.as_bytes(), t.secret.as_bytes()) {
            found = Some(t);
        }
    }
    found
}

/// The client's address, when the server was started with connect info (or a test gave one).
fn client_ip(parts: &Parts) -> String {
    let served = parts.extensions.get::<ConnectInfo<SocketAddr>>().map(|ConnectInfo(a)| a);
    let mocked = || parts.extensions.get::<MockConnectInfo<SocketAddr>>().map(|MockConnectInfo(a)| a);
    served.or_else(mocked).map_or_else(|| "unknown".to_string(), |a| a.ip().to_string())
}

/// The token a request presents: `None` without an Authorization header.
fn presented(parts: &Parts) -> Result<Option<&str>, ApiError> {
    let Some(value) = parts.headers.get(header::AUTHORIZATION) else { return Ok(None) };
    let unauthorized = |m: &str| ApiError::new(StatusCode::UNAUTHORIZED, "unauthorized", m);
    let value = value.to_str().map_err(|_| unauthorized("the Authorization header is not text"))?;
    let (scheme, token) = value
        .trim()
        .split_once(' ')
        .ok_or_else(|| unauthorized("the Authorization header is not `Bearer <token>`"))?;
    if !scheme.eq_ignore_ascii_case("bearer") {
        return Err(unauthorized("the Authorization header is not `Bearer <token>`"));
    }
    Ok(Some(token.trim()))
}

/// The caller of a request that was authorized.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Caller {
    /// The token's name (`None`: anonymous).
    pub token: Option<String>,
    /// What the caller may do (`None`: anonymous read).
    pub role: Option<Role>,
    /// The client's IP address (`unknown` when not served over a socket).
    pub ip: String,
}

impl Caller {
    /// The actor in the audit trail: `http:<token name>@<client ip>`.
    pub fn actor(&self) -> String {
        format!("http:{}@{}", self.token.as_deref().unwrap_or("anonymous"), self.ip)
    }
}

async fn authorize(parts: &Parts, gw: &Arc<Gateway>, need: Role) -> Result<Caller, ApiError> {
    let ip = client_ip(parts);
    let tokens = &gw.config().tokens;
    let presented = match presented(parts) {
        Ok(p) => p,
        Err(e) => {
            gw.login_failed(&ip, &format!("unauthorized: {}", e.message)).await;
            return Err(e);
        }
    };
    if presented.is_some() && gw.login_blocked(&ip) {
        return Err(ApiError::new(
            StatusCode::TOO_MANY_REQUESTS,
            "too_many_failures",
            format!(
                "{MAX_LOGIN_FAILURES} failed logins from {ip} within a minute: requests with a token \
                 from {ip} are refused until that minute is over; then use a configured token"
            ),
        ));
    }
    match presented {
        None if need == Role::Read && gw.config().http.anonymous_read => {
            Ok(Caller { token: None, role: None, ip })
        }
        None => Err(ApiError::new(
            StatusCode::UNAUTHORIZED,
            "unauthorized",
            match need {
                Role::Read => "reads need a token: send Authorization: Bearer <token>",
                Role::Write => "writes need a write token: send Authorization: Bearer <token>",
            },
        )),
        Some(p) => {
            let Some(t) = find_token(tokens, p) else {
                gw.login_failed(&ip, "unauthorized: unknown token").await;
                return Err(ApiError::new(StatusCode::UNAUTHORIZED, "unauthorized", "unknown token"));
            };
            if t.role < need {
                return Err(ApiError::new(
                    StatusCode::FORBIDDEN,
                    "forbidden",
                    format!("token {:?} may only read: writes need a token with role = \"write\"", t.name),
                ));
            }
            Ok(Caller { token: Some(t.name.clone()), role: Some(t.role), ip })
        }
    }
}

/// Extractor: the request may read (a read or write token, or anonymous reads allowed).
#[derive(Clone, Debug)]
pub struct ReadAccess(pub Caller);

/// Extractor: the request may write (a write token).
#[derive(Clone, Debug)]
pub struct WriteAccess(pub Caller);

#[axum::async_trait]
impl FromRequestParts<Arc<Gateway>> for ReadAccess {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, gw: &Arc<Gateway>) -> Result<Self, ApiError> {
        authorize(parts, gw, Role::Read).await.map(ReadAccess)
    }
}

#[axum::async_trait]
impl FromRequestParts<Arc<Gateway>> for WriteAccess {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, gw: &Arc<Gateway>) -> Result<Self, ApiError> {
        authorize(parts, gw, Role::Write).await.map(WriteAccess)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn equal_only_when_equal() {
        assert!(constant_time_eq(b"abcdef0123456789", b"abcdef0123456789"));
        assert!(!constant_time_eq(b"abcdef0123456789", b"abcdef012345678"));
        assert!(!constant_time_eq(b"abcdef012345678", b"abcdef0123456789"));
        assert!(!constant_time_eq(b"abcdef0123456780", b"abcdef0123456789"));
        assert!(!constant_time_eq(b"", b"x"));
        assert!(!constant_time_eq(b"x", b""));
        assert!(constant_time_eq(b"", b""));
        // A repeated prefix of the secret is not the secret.
        assert!(!constant_time_eq(b"abab", b"ab"));
    }
}
