//! Who may do what over OPC UA: the gateway's tokens are its users (user name = the token's
//! name, password = the token; role read or write). Anonymous sessions may read where reads need
//! no token (`[opcua] anonymous_read`, by default `[http] anonymous_read`); writes and method
//! calls need a user with the write role. Checked against the configuration at each login, so a
//! reload that removes a token locks its holder out of new sessions at once.
//!
//! A session's user is the token that matched at login, name and secret: its role is that
//! token's, looked up by both (a fingerprint of the secret rides in the session's user token,
//! never the secret), never by the name alone.

use std::hash::BuildHasher;
use std::sync::{Arc, OnceLock};

use async_trait::async_trait;
use opcua::crypto::SecurityPolicy;
use opcua::server::authenticator::{user_pass_security_policy_id, AuthManager, Password, UserToken};
use opcua::server::ServerEndpoint;
use opcua::types::{Error, StatusCode, UAString, UserTokenPolicy, UserTokenType};

use super::sessions::Sessions;
use crate::config::{Role, Token};
use crate::core::Gateway;

/// The user token of anonymous sessions (async-opcua's own).
pub const ANONYMOUS: &str = "ANONYMOUS";

/// The gateway's tokens as OPC UA users.
pub struct TokenAuth {
    gw: Arc<Gateway>,
    sessions: Arc<Sessions>,
}

impl TokenAuth {
    /// Users from `gw`'s tokens, as configured at each login; their sessions counted in
    /// `sessions`.
    pub fn new(gw: Arc<Gateway>, sessions: Arc<Sessions>) -> Self {
        TokenAuth { gw, sessions }
    }

    /// Admits a session of `user` within `[opcua] max_sessions_per_user`; a refusal is audited.
    async fn admit(&self, user: &str) -> Result<(), Error> {
        let max = max_sessions_per_user(&self.gw);
        if self.sessions.admit(user, max, std::time::Instant::now()) {
            return Ok(());
        }
        let why =
            format!("too_many_sessions: user {user} holds {max} sessions ([opcua] max_sessions_per_user)");
        self.gw.audit_login_refusal(&format!("opcua:{user}"), &why).await;
        Err(Error::new(StatusCode::BadTooManySessions, why))
    }
}

/// `[opcua] max_sessions_per_user`, as configured now.
pub fn max_sessions_per_user(gw: &Gateway) -> usize {
    gw.config()
        .opcua
        .as_ref()
        .map_or(crate::config::DEFAULT_MAX_SESSIONS_PER_USER, |o| o.max_sessions_per_user)
}

/// A fingerprint of a token's secret: a keyed hash whose key is made at random once per process.
fn fingerprint(secret: &str) -> u64 {
    static KEY: OnceLock<std::collections::hash_map::RandomState> = OnceLock::new();
    KEY.get_or_init(Default::default).hash_one(secret)
}

/// The session's user token for a login with `token`: its name and its secret's fingerprint.
pub fn user_token(token: &Token) -> UserToken {
    UserToken(format!("{}\u{0}{:016x}", token.name, fingerprint(&token.secret)))
}

/// The user's name (the token's name; `anonymous`), for the audit trail and the logs.
pub fn user_name(user: &UserToken) -> &str {
    if user.0 == ANONYMOUS {
        return "anonymous";
    }
    user.0.split('\u{0}').next().unwrap_or_default()
}

/// The token of `tokens` that `username` and `password` match.
pub fn matching<'a>(tokens: &'a [Token], username: &str, password: &str) -> Option<&'a Token> {
    tokens.iter().find(|t| {
        t.name == username && crate::http::auth::constant_time_eq(t.secret.as_bytes(), password.as_bytes())
    })
}

/// The role of the session's user: that of the token it logged in with, found by name and
/// secret in `tokens`. `None` for an anonymous session or a user whose token is gone.
pub fn role(tokens: &[Token], user: &UserToken) -> Option<Role> {
    let (name, print) = user.0.split_once('\u{0}')?;
    tokens
        .iter()
        .find(|t| t.name == name && format!("{:016x}", fingerprint(&t.secret)) == print)
        .map(|t| t.role)
}

/// Whether anonymous sessions may read.
pub fn anonymous_read(gw: &Gateway) -> bool {
    let c = gw.config();
    c.opcua.as_ref().map_or(c.http.anonymous_read, |o| o.anonymous_read)
}

#[async_trait]
impl AuthManager for TokenAuth {
    async fn authenticate_anonymous_token(&self, _endpoint: &ServerEndpoint) -> Result<(), Error> {
        if anonymous_read(&self.gw) {
            self.admit("anonymous").await
        } else {
            Err(Error::new(
                StatusCode::BadIdentityTokenRejected,
                "anonymous sessions are off ([opcua] anonymous_read = false): log in with a token's name and secret",
            ))
        }
    }

    async fn authenticate_username_identity_token(
        &self,
        _endpoint: &ServerEndpoint,
        username: &str,
        password: &Password,
    ) -> Result<UserToken, Error> {
        let config = self.gw.config();
        match matching(&config.tokens, username, password.get()) {
            Some(t) => {
                self.admit(&t.name).await?;
                Ok(user_token(t))
            }
            None => {
                let who = format!("opcua:{}", crate::text::shown(crate::text::cut(username, 64).0));
                self.gw.audit_login_refusal(&who, "unauthorized: unknown user or wrong password").await;
                Err(Error::new(StatusCode::BadUserAccessDenied, "unknown user or wrong password"))
            }
        }
    }

    fn user_token_policies(&self, endpoint: &ServerEndpoint) -> Vec<UserTokenPolicy> {
        policies(endpoint, anonymous_read(&self.gw))
    }
}

/// The security policy of passwords on every endpoint, `None` included: clients encrypt the
/// password with the server's certificate, so it never crosses the wire in clear.
pub const PASSWORD_POLICY: SecurityPolicy = SecurityPolicy::Basic256Sha256;

/// The user token policies of `endpoint`: user name and password, encrypted with
/// [`PASSWORD_POLICY`] (the endpoint's `password_security_policy`, set by the server's
/// builder), and anonymous when `anonymous` reads are on.
pub fn policies(endpoint: &ServerEndpoint, anonymous: bool) -> Vec<UserTokenPolicy> {
    let mut policies = vec![UserTokenPolicy {
        policy_id: user_pass_security_policy_id(endpoint),
        token_type: UserTokenType::UserName,
        issued_token_type: UAString::null(),
        issuer_endpoint_url: UAString::null(),
        security_policy_uri: UAString::from(endpoint.password_security_policy().to_uri()),
    }];
    if anonymous {
        policies.insert(
            0,
            UserTokenPolicy {
                policy_id: UAString::from("anonymous"),
                token_type: UserTokenType::Anonymous,
                issued_token_type: UAString::null(),
                issuer_endpoint_url: UAString::null(),
                security_policy_uri: UAString::null(),
            },
        );
    }
    policies
}

#[cfg(test)]
mod tests {
    use super::*;

    fn token(name: &str, secret: &str, role: Role) -> Token {
        Token { name: name.into(), secret: secret.into(), role }
    }

    #[test]
    fn the_role_is_that_of_the_token_that_matched_not_of_its_name() {
        // Two tokens of one name (the configuration refuses it; this is the defence behind).
        let tokens = [
            token("ops", "write-secret-0123456789", Role::Write),
            token("ops", "read-secret-0123456789", Role::Read),
        ];
        let reader = user_token(matching(&tokens, "ops", "read-secret-0123456789").unwrap());
        assert_eq!(role(&tokens, &reader), Some(Role::Read));
        let writer = user_token(matching(&tokens, "ops", "write-secret-0123456789").unwrap());
        assert_eq!(role(&tokens, &writer), Some(Role::Write));
        assert_eq!(user_name(&reader), "ops");
        assert!(!reader.0.contains("read-secret"), "the secret is in the session's user: {:?}", reader.0);
        assert!(matching(&tokens, "ops", "read-secret-012345678").is_none());
        // A reload that changes the secret or removes the token: no role any more.
        let reloaded = [token("ops", "write-secret-0123456789", Role::Write)];
        assert_eq!(role(&reloaded, &reader), None);
        assert_eq!(role(&tokens, &UserToken(ANONYMOUS.into())), None);
        assert_eq!(user_name(&UserToken(ANONYMOUS.into())), "anonymous");
    }
}
