//! `[sparkplug]`: the Sparkplug B edge node (docs/sparkplug.md). The id rule lives here; the
//! Sparkplug front end (sparkplug/) uses it at run time.

use toml::Spanned;

use super::broker::FileTls;
use super::ctx::Ctx;
use super::file::FileSparkplug;
use super::{
    ConfigError, SparkplugConfig, SPARKPLUG_GROUP, SPARKPLUG_STORE_MAX, SPARKPLUG_STORE_MAX_AGE_S,
    SPARKPLUG_STORE_RATE,
};

/// Checks a group, edge node or host id: not empty, no `/`, `+` or `#` (they are topic levels).
pub fn check_id(id: &str) -> Result<(), String> {
    if id.is_empty() || id.contains(['/', '+', '#', '\0']) {
        return Err(format!("{id:?}: use a non-empty id without /, + or #"));
    }
    Ok(())
}

/// Checks `[sparkplug]`.
pub(super) fn check(cx: &Ctx, sp: FileSparkplug) -> Result<SparkplugConfig, ConfigError> {
    if sp.urls.get_ref().is_empty() {
        return cx.err(sp.urls.span(), "sparkplug.urls", "give at least one broker: [\"mqtt://HOST:PORT\"]");
    }
    for (field, id) in
        [("group_id", &sp.group_id), ("edge_node_id", &sp.edge_node_id), ("primary_host", &sp.primary_host)]
    {
        if let Some(id) = id {
            if let Err(e) = check_id(id.get_ref()) {
                return cx.err(id.span(), &format!("sparkplug.{field}"), e);
            }
        }
    }
    let credentials =
        cx.credentials("sparkplug", sp.urls.span(), &sp.username, &sp.password, &sp.password_env)?;
    let keys = FileTls {
        ca_file: &sp.ca_file,
        client_cert: &sp.client_cert,
        client_key: &sp.client_key,
        allow_plaintext: sp.allow_plaintext,
    };
    let urls: Vec<(&str, _)> = sp.urls.get_ref().iter().map(|u| (u.get_ref().as_str(), u.span())).collect();
    let tls = super::broker::check(cx, "sparkplug", "urls", &urls, keys, credentials.is_some(), sp.commands)?;
    let positive = |v: &Option<Spanned<u64>>, field: &str, default: u64| match v {
        Some(n) if *n.get_ref() == 0 => cx.err(n.span(), field, "give a number above 0"),
        Some(n) => Ok(*n.get_ref()),
        None => Ok(default),
    };
    Ok(SparkplugConfig {
        store_forward_max: positive(
            &sp.store_forward_max,
            "sparkplug.store_forward_max",
            SPARKPLUG_STORE_MAX,
        )?,
        store_forward_max_age_s: positive(
            &sp.store_forward_max_age_s,
            "sparkplug.store_forward_max_age_s",
            SPARKPLUG_STORE_MAX_AGE_S,
        )?,
        store_forward_rate: positive(
            &sp.store_forward_rate,
            "sparkplug.store_forward_rate",
            SPARKPLUG_STORE_RATE,
        )?,
        urls: sp.urls.into_inner().into_iter().map(Spanned::into_inner).collect(),
        group_id: sp.group_id.map_or_else(|| SPARKPLUG_GROUP.to_string(), Spanned::into_inner),
        edge_node_id: sp.edge_node_id.map(Spanned::into_inner),
        primary_host: sp.primary_host.map(Spanned::into_inner),
        commands: sp.commands,
        credentials,
        tls,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_are_topic_levels() {
        assert!(check_id("hall-1").is_ok());
        for bad in ["", "a/b", "a+", "#"] {
            assert!(check_id(bad).is_err(), "{bad}");
        }
    }
}
