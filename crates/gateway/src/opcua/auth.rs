//! Who may do what over OPC UA: the gateway's tokens are its users (user name = the token's
//! name, password = the token; role read or write). Anonymous sessions may read where reads need
//! no token (`[opcua] anonymous_read`, by default `[http] anonymous_read`); writes and method
//! calls need a user with the write role. Checked against the configuration at each login, so a
//! reload that removes a token locks its holder out of new sessions at once.

use std::sync::Arc;

use async_trait::async_trait;
use opcua::server::authenticator::{
    user_pass_security_policy_id, user_pass_security_policy_uri, AuthManager, Password, UserToken,
};
use opcua::server::ServerEndpoint;
use opcua::types::{Error, StatusCode, UAString, UserTokenPolicy, UserTokenType};

use crate::config::Role;
use crate::gateway::Gateway;

/// The user token of anonymous sessions (async-opcua's own).
pub const ANONYMOUS: &str = "ANONYMOUS";

/// The gateway's tokens as OPC UA users.
pub struct TokenAuth {
    gw: Arc<Gateway>,
}

impl TokenAuth {
    /// Users from `gw`'s tokens, as configured at each login.
    pub fn new(gw: Arc<Gateway>) -> Self {
        TokenAuth { gw }
    }
}

/// The role of the session's user, `None` for an anonymous session or a user whose token is gone.
pub fn role(gw: &Gateway, user: &UserToken) -> Option<Role> {
    if user.0 == ANONYMOUS {
        return None;
    }
    gw.config().tokens.iter().find(|t| t.name == user.0).map(|t| t.role)
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
            Ok(())
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
        let found = config.tokens.iter().find(|t| {
            t.name == username
                && crate::http::auth::constant_time_eq(t.secret.as_bytes(), password.get().as_bytes())
        });
        match found {
            Some(t) => Ok(UserToken(t.name.clone())),
            None => {
                crate::log::warn(&format!(
                    "OPC UA: login refused for user {:?}: unknown user or wrong password",
                    crate::text::cut(username, 64).0
                ));
                Err(Error::new(StatusCode::BadUserAccessDenied, "unknown user or wrong password"))
            }
        }
    }

    fn user_token_policies(&self, endpoint: &ServerEndpoint) -> Vec<UserTokenPolicy> {
        let mut policies = vec![UserTokenPolicy {
            policy_id: user_pass_security_policy_id(endpoint),
            token_type: UserTokenType::UserName,
            issued_token_type: UAString::null(),
            issuer_endpoint_url: UAString::null(),
            security_policy_uri: user_pass_security_policy_uri(endpoint),
        }];
        if anonymous_read(&self.gw) {
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
}
