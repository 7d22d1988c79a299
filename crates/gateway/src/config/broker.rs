//! What `[mqtt]` and `[sparkplug]` share: a broker's URL (`mqtt://` or `mqtts://`), its TLS
//! keys (`ca_file`, `client_cert`, `client_key`) and the rule that a password or commands do
//! not cross a network in clear (`allow_plaintext` to opt out). The MQTT and Sparkplug front
//! ends apply the same rules at run time.

use std::net::IpAddr;
use std::ops::Range;
use std::path::PathBuf;

use toml::Spanned;

use super::ctx::Ctx;
use super::{BrokerTls, ConfigError};

/// A broker's address as its URL gives it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BrokerUrl {
    /// Its host name or address (the name its certificate must be made for, with TLS).
    pub host: String,
    /// Its port (1883 by default, 8883 with TLS).
    pub port: u16,
    /// `mqtts://`: TLS.
    pub tls: bool,
}

const USE: &str = "use mqtt://HOST:PORT or mqtts://HOST:PORT (TLS; the port may be left out)";

/// The broker of an `mqtt://HOST[:PORT]` (port 1883 by default) or `mqtts://HOST[:PORT]` (TLS,
/// port 8883 by default) URL; an error names what is wrong.
pub fn parse_url(url: &str) -> Result<BrokerUrl, String> {
    let (rest, tls) = match (url.strip_prefix("mqtt://"), url.strip_prefix("mqtts://")) {
        (Some(r), _) => (r, false),
        (_, Some(r)) => (r, true),
        _ => return Err(format!("{url:?}: {USE}")),
    };
    let rest = rest.strip_suffix('/').unwrap_or(rest);
    if rest.is_empty() || rest.contains(['/', '@', '?', '#']) {
        return Err(format!("{url:?}: {USE}"));
    }
    // [v6]:port, host:port, or a host alone.
    let (host, port) = if let Some(v6) = rest.strip_prefix('[') {
        let (h, p) = v6.split_once(']').ok_or_else(|| format!("{url:?}: unclosed [ in the host"))?;
        (h, p.strip_prefix(':'))
    } else {
        match rest.rsplit_once(':') {
            Some((h, p)) => (h, Some(p)),
            None => (rest, None),
        }
    };
    if host.is_empty() {
        return Err(format!("{url:?}: no host"));
    }
    let port = match port {
        None if tls => 8883,
        None => 1883,
        Some(p) => {
            p.parse::<u16>().ok().filter(|&p| p > 0).ok_or_else(|| format!("{url:?}: bad port {p:?}"))?
        }
    };
    Ok(BrokerUrl { host: host.to_string(), port, tls })
}

/// Whether `host` is this machine (`localhost`, 127.0.0.0/8, ::1): nothing crosses a network.
pub fn is_loopback(host: &str) -> bool {
    host.eq_ignore_ascii_case("localhost") || host.parse::<IpAddr>().is_ok_and(|ip| ip.is_loopback())
}

/// Why section `section`'s plain `mqtt://` connection to `url` is refused: a password
/// (`secret`) or commands would cross a network in clear. `None` for TLS, a broker on this
/// machine, or `allow_plaintext`.
pub fn plaintext_refusal(
    section: &str,
    url: &BrokerUrl,
    tls: &BrokerTls,
    secret: bool,
    commands: bool,
) -> Option<String> {
    if url.tls || tls.allow_plaintext || is_loopback(&url.host) || !(secret || commands) {
        return None;
    }
    let what = match (secret, commands) {
        (true, true) => "the broker password and motor commands",
        (true, false) => "the broker password",
        _ => "motor commands",
    };
    Some(format!(
        "{what} would cross the network to {} in clear: use mqtts://{}, or set [{section}] \
         allow_plaintext = true to accept that",
        url.host,
        if url.host.contains(':') { format!("[{}]", url.host) } else { url.host.clone() },
    ))
}

/// The TLS keys of `[section]` as written.
pub(super) struct FileTls<'a> {
    pub(super) ca_file: &'a Option<Spanned<String>>,
    pub(super) client_cert: &'a Option<Spanned<String>>,
    pub(super) client_key: &'a Option<Spanned<String>>,
    pub(super) allow_plaintext: bool,
}

/// Checks `[section]`'s broker settings: `urls` (each with its place), the TLS keys (their
/// files read and usable), and the plain-text rule for a section with a password (`secret`) or
/// commands.
pub(super) fn check(
    cx: &Ctx,
    section: &str,
    url_field: &str,
    urls: &[(&str, Range<usize>)],
    keys: FileTls,
    secret: bool,
    commands: bool,
) -> Result<BrokerTls, ConfigError> {
    let mut parsed = Vec::new();
    for (u, at) in urls {
        match parse_url(u) {
            Ok(b) => parsed.push((b, at.clone())),
            Err(e) => return cx.err(at.clone(), &format!("{section}.{url_field}"), e),
        }
    }
    let path = |v: &Option<Spanned<String>>| v.as_ref().map(|p| PathBuf::from(p.get_ref()));
    let tls = BrokerTls {
        ca_file: path(keys.ca_file),
        client_cert: path(keys.client_cert),
        client_key: path(keys.client_key),
        allow_plaintext: keys.allow_plaintext,
    };
    let given =
        [("ca_file", keys.ca_file), ("client_cert", keys.client_cert), ("client_key", keys.client_key)];
    let first = given.iter().find_map(|(k, v)| v.as_ref().map(|v| (*k, v.span())));
    if let Some((key, at)) = first {
        if !parsed.iter().any(|(b, _)| b.tls) {
            return cx.err(at, &format!("{section}.{key}"), "is for TLS: use an mqtts:// broker URL");
        }
        // Read the files now: a file that cannot be used is this check's error.
        if let Err(e) = super::tls::client_config(&tls) {
            let field = if e.starts_with("client_key") {
                "client_key"
            } else if e.starts_with("ca_file") {
                "ca_file"
            } else {
                "client_cert"
            };
            let at = given
                .iter()
                .find(|(k, _)| *k == field)
                .and_then(|(_, v)| v.as_ref())
                .map_or(at, |v| v.span());
            return cx.err(at, &format!("{section}.{field}"), e);
        }
    }
    for (b, at) in &parsed {
        if let Some(why) = plaintext_refusal(section, b, &tls, secret, commands) {
            return cx.err(at.clone(), &format!("{section}.{url_field}"), why);
        }
    }
    Ok(tls)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls() {
        let b = |host: &str, port, tls| BrokerUrl { host: host.into(), port, tls };
        assert_eq!(parse_url("mqtt://10.0.0.9:1884").unwrap(), b("10.0.0.9", 1884, false));
        assert_eq!(parse_url("mqtt://broker").unwrap(), b("broker", 1883, false));
        assert_eq!(parse_url("mqtt://[::1]:1883").unwrap(), b("::1", 1883, false));
        assert_eq!(parse_url("mqtts://broker").unwrap(), b("broker", 8883, true));
        assert_eq!(parse_url("mqtts://broker.plant:8884/").unwrap(), b("broker.plant", 8884, true));
        for bad in [
            "tcp://x:1",
            "mqtt://",
            "mqtt://x:0",
            "mqtt://x:99999",
            "mqtt://x:1/a",
            "mqtt://:1883",
            "mqtts://",
            "ssl://x",
        ] {
            assert!(parse_url(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_password_or_commands_in_clear_off_this_machine_are_refused_unless_opted_out() {
        let plain = parse_url("mqtt://10.0.0.9").unwrap();
        let none = BrokerTls::default();
        let why = plaintext_refusal("mqtt", &plain, &none, true, false).unwrap();
        assert!(
            why.contains("password") && why.contains("mqtts://10.0.0.9") && why.contains("allow_plaintext"),
            "{why}"
        );
        assert!(plaintext_refusal("sparkplug", &plain, &none, false, true).unwrap().contains("commands"));
        assert_eq!(
            plaintext_refusal("mqtt", &plain, &none, false, false),
            None,
            "nothing secret, no commands"
        );
        let opted = BrokerTls { allow_plaintext: true, ..BrokerTls::default() };
        assert_eq!(plaintext_refusal("mqtt", &plain, &opted, true, true), None);
        for local in ["mqtt://127.0.0.1", "mqtt://localhost:1884", "mqtt://[::1]", "mqtts://10.0.0.9"] {
            assert_eq!(
                plaintext_refusal("mqtt", &parse_url(local).unwrap(), &none, true, true),
                None,
                "{local}"
            );
        }
    }
}
