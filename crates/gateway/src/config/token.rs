//! `[[token]]`: the bearer tokens.

use super::ctx::Ctx;
use super::file::FileToken;
use super::{ConfigError, Role, Token};

/// Checks the `[[token]]` sections: a known role, a secret of 16 characters or more, no secret
/// and no name twice (a name is a user: OPC UA logs in by name).
pub(super) fn check(cx: &Ctx, raw: &[FileToken]) -> Result<Vec<Token>, ConfigError> {
    let mut tokens = Vec::new();
    for t in raw {
        let role = match t.role.get_ref().as_str() {
            "read" => Role::Read,
            "write" => Role::Write,
            other => return cx.err(t.role.span(), "token.role", format!("{other:?}: use read or write")),
        };
        if t.token.get_ref().len() < 16 {
            return cx.err(t.token.span(), "token.token", "a token needs at least 16 characters");
        }
        if tokens.iter().any(|x: &Token| x.name == *t.name.get_ref()) {
            return cx.err(
                t.name.span(),
                "token.name",
                format!("{:?}: two tokens have the same name; give each its own", t.name.get_ref()),
            );
        }
        if tokens.iter().any(|x: &Token| x.secret == *t.token.get_ref()) {
            return cx.err(t.token.span(), "token.token", "two tokens have the same secret");
        }
        tokens.push(Token { name: t.name.get_ref().clone(), secret: t.token.get_ref().clone(), role });
    }
    Ok(tokens)
}
