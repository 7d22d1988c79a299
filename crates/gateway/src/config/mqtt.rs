//! `[mqtt]`: MQTT publishing (docs/mqtt.md). The broker URL, topic prefix and command pattern
//! rules live here; the MQTT front end (mqtt.rs) uses them at run time.

use super::broker::FileTls;
pub use super::broker::{is_loopback, parse_url, plaintext_refusal, BrokerUrl};
use super::ctx::Ctx;
use super::file::FileMqtt;
use super::{ConfigError, MqttConfig};

/// The commands accepted on `set/<command>` topics.
pub const COMMANDS: [&str; 6] = ["run", "stop", "reverse", "jog", "reset", "speed"];

/// Checks a configured topic prefix: levels without wildcards, no leading or trailing `/`.
pub fn check_prefix(prefix: &str) -> Result<(), String> {
    if prefix.is_empty() || prefix.starts_with('/') || prefix.ends_with('/') || prefix.contains("//") {
        return Err(format!("{prefix:?}: give levels separated by / (e.g. plant/hall-1)"));
    }
    if prefix.contains(['+', '#', '\0']) {
        return Err(format!("{prefix:?}: + and # are wildcards, not allowed in a topic"));
    }
    Ok(())
}

/// An `allow_commands` pattern: `<bus>/<drive>/<command>`, `*` matching any one level.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Pattern([String; 3]);

impl Pattern {
    /// Parses a pattern; an error says what is wrong.
    pub fn parse(s: &str) -> Result<Pattern, String> {
        let parts: Vec<&str> = s.split('/').collect();
        if parts.len() != 3 || parts.iter().any(|p| p.is_empty()) {
            return Err(format!("{s:?}: use <bus>/<drive>/<command>, * for any (e.g. line-1/*/stop)"));
        }
        if parts.iter().any(|p| *p != "*" && p.contains(['*', '+', '#'])) {
            return Err(format!("{s:?}: * stands alone for a whole level; + and # are not used"));
        }
        if parts[2] != "*" && !COMMANDS.contains(&parts[2]) {
            return Err(format!("{s:?}: no command {:?}: use {} or *", parts[2], COMMANDS.join(", ")));
        }
        Ok(Pattern([parts[0].to_string(), parts[1].to_string(), parts[2].to_string()]))
    }

    /// Whether the pattern allows `command` on `drive` of `bus`.
    pub fn matches(&self, bus: &str, drive: &str, command: &str) -> bool {
        self.0.iter().zip([bus, drive, command]).all(|(p, v)| p == "*" || p == v)
    }
}

/// Checks `[mqtt]`.
pub(super) fn check(cx: &Ctx, m: FileMqtt) -> Result<MqttConfig, ConfigError> {
    if let Some(p) = &m.topic_prefix {
        if let Err(e) = check_prefix(p.get_ref()) {
            return cx.err(p.span(), "mqtt.topic_prefix", e);
        }
    }
    for a in &m.allow_commands {
        if let Err(e) = Pattern::parse(a.get_ref()) {
            return cx.err(a.span(), "mqtt.allow_commands", e);
        }
    }
    if let Some(c) = &m.client_id {
        let id = c.get_ref();
        if id.is_empty() || id.len() > 64 || id.contains(['+', '#', '/']) {
            return cx.err(c.span(), "mqtt.client_id", "use 1 to 64 characters without +, # or /");
        }
    }
    let credentials = cx.credentials("mqtt", m.url.span(), &m.username, &m.password, &m.password_env)?;
    let keys = FileTls {
        ca_file: &m.ca_file,
        client_cert: &m.client_cert,
        client_key: &m.client_key,
        allow_plaintext: m.allow_plaintext,
    };
    let urls = [(m.url.get_ref().as_str(), m.url.span())];
    let commands = !m.allow_commands.is_empty();
    let tls = super::broker::check(cx, "mqtt", "url", &urls, keys, credentials.is_some(), commands)?;
    Ok(MqttConfig {
        url: m.url.into_inner(),
        topic_prefix: m.topic_prefix.map(|p| p.into_inner()),
        discovery: m.discovery,
        allow_commands: m.allow_commands.into_iter().map(|a| a.into_inner()).collect(),
        client_id: m.client_id.map(|c| c.into_inner()),
        credentials,
        tls,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patterns() {
        let p = Pattern::parse("line-1/*/stop").unwrap();
        assert!(p.matches("line-1", "pump-1", "stop"));
        assert!(!p.matches("line-1", "pump-1", "run"));
        assert!(!p.matches("line-2", "pump-1", "stop"));
        assert!(Pattern::parse("*/*/*").unwrap().matches("a", "b", "speed"));
        for bad in ["a/b", "a/b/c/d", "a//run", "a/b*/run", "a/+/run", "a/b/start", "#"] {
            assert!(Pattern::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn prefixes() {
        assert!(check_prefix("plant/hall-1").is_ok());
        for bad in ["", "/a", "a/", "a//b", "a/+", "a/#"] {
            assert!(check_prefix(bad).is_err(), "{bad}");
        }
    }
}
