//! TLS with rustls and its `ring` provider (never OpenSSL): the client side for MQTT and
//! Sparkplug B brokers (`mqtts://`), the server side for HTTPS, and the PEM files both read.
//! The configuration check builds the same configurations, so a file that cannot be used is an
//! error of `config check`, not of a connection later; the front ends import them from here.

use std::path::Path;
use std::sync::Arc;

use rustls_pki_types::pem::PemObject;
use rustls_pki_types::{CertificateDer, PrivateKeyDer};
use tokio_rustls::rustls::crypto::{ring, CryptoProvider};
use tokio_rustls::rustls::{ClientConfig, RootCertStore, ServerConfig};

use super::broker::{plaintext_refusal, BrokerUrl};
use super::BrokerTls;

/// The crypto provider every TLS configuration here uses.
fn provider() -> Arc<CryptoProvider> {
    Arc::new(ring::default_provider())
}

/// The certificates of PEM file `path` (`what` names the key in errors).
fn certificates(path: &Path, what: &str) -> Result<Vec<CertificateDer<'static>>, String> {
    let shown = path.display();
    let iter =
        CertificateDer::pem_file_iter(path).map_err(|e| format!("{what} {shown}: {}", pem_error(e)))?;
    let certs =
        iter.collect::<Result<Vec<_>, _>>().map_err(|e| format!("{what} {shown}: {}", pem_error(e)))?;
    if certs.is_empty() {
        return Err(format!(
            "{what} {shown}: no certificate in it: give a PEM file with a BEGIN CERTIFICATE block"
        ));
    }
    Ok(certs)
}

/// The private key of PEM file `path`.
fn private_key(path: &Path, what: &str) -> Result<PrivateKeyDer<'static>, String> {
    PrivateKeyDer::from_pem_file(path).map_err(|e| match e {
        rustls_pki_types::pem::Error::NoItemsFound => format!(
            "{what} {}: no private key in it: give a PEM file with a BEGIN PRIVATE KEY block \
             (or RSA / EC PRIVATE KEY)",
            path.display()
        ),
        e => format!("{what} {}: {}", path.display(), pem_error(e)),
    })
}

fn pem_error(e: rustls_pki_types::pem::Error) -> String {
    match e {
        rustls_pki_types::pem::Error::Io(e) => format!("cannot read it: {e}"),
        e => format!("not a PEM file rustls can read: {e:?}"),
    }
}

/// The TLS client configuration for a broker: its certificate verified against `ca_file` (or
/// the system's trusted roots) and the host name of the URL; the gateway's own certificate when
/// `client_cert` and `client_key` are given. Errors say which file and what to do.
pub fn client_config(tls: &BrokerTls) -> Result<Arc<ClientConfig>, String> {
    let mut roots = RootCertStore::empty();
    match &tls.ca_file {
        Some(ca) => {
            for c in certificates(ca, "ca_file")? {
                roots
                    .add(c)
                    .map_err(|e| format!("ca_file {}: a certificate rustls cannot use: {e}", ca.display()))?;
            }
        }
        None => {
            let found = rustls_native_certs::load_native_certs();
            roots.add_parsable_certificates(found.certs);
            if roots.is_empty() {
                return Err("no trusted CA certificates on this system: install them (ca-certificates) \
                            or give ca_file"
                    .into());
            }
        }
    }
    let builder = ClientConfig::builder_with_provider(provider())
        .with_safe_default_protocol_versions()
        .map_err(|e| format!("TLS: {e}"))?
        .with_root_certificates(roots);
    let config = match (&tls.client_cert, &tls.client_key) {
        (Some(cert), Some(key)) => builder
            .with_client_auth_cert(certificates(cert, "client_cert")?, private_key(key, "client_key")?)
            .map_err(|e| {
                format!("client_cert {} and client_key {}: {}", cert.display(), key.display(), key_error(&e))
            })?,
        (None, None) => builder.with_no_client_auth(),
        (Some(_), None) => return Err("client_cert needs client_key (the certificate's private key)".into()),
        (None, Some(_)) => return Err("client_key needs client_cert (the key's certificate)".into()),
    };
    Ok(Arc::new(config))
}

/// The TLS server configuration of a listener with certificate (chain) `cert` and its private
/// key `key`, both PEM. A key that is not the certificate's is an error.
pub fn server_config(cert: &Path, key: &Path) -> Result<Arc<ServerConfig>, String> {
    let config = ServerConfig::builder_with_provider(provider())
        .with_safe_default_protocol_versions()
        .map_err(|e| format!("TLS: {e}"))?
        .with_no_client_auth()
        .with_single_cert(certificates(cert, "tls_cert")?, private_key(key, "tls_key")?)
        .map_err(|e| {
            format!("tls_cert {} and tls_key {}: {}", cert.display(), key.display(), key_error(&e))
        })?;
    Ok(Arc::new(config))
}

fn key_error(e: &tokio_rustls::rustls::Error) -> String {
    match e {
        tokio_rustls::rustls::Error::InconsistentKeys(_) => {
            "the key is not the certificate's: give the key the certificate was made for".into()
        }
        e => format!("{e}: give a PEM certificate and its private key"),
    }
}

/// How to reach broker `url` of section `section` (`mqtt`, `sparkplug`): plain TCP, or TLS with
/// `tls`'s settings. A plain connection off this machine with a password (`secret`) or
/// commands is refused unless `allow_plaintext` ([`plaintext_refusal`]).
pub fn broker_transport(
    section: &str,
    url: &BrokerUrl,
    tls: &BrokerTls,
    secret: bool,
    commands: bool,
) -> Result<rumqttc::Transport, String> {
    if let Some(why) = plaintext_refusal(section, url, tls, secret, commands) {
        return Err(why);
    }
    if !url.tls {
        return Ok(rumqttc::Transport::Tcp);
    }
    let config = client_config(tls)?;
    Ok(rumqttc::Transport::tls_with_config(rumqttc::TlsConfiguration::Rustls(config)))
}

/// A broker connection's error in plain words: what a failed certificate check means and what
/// to do; any other error as it is.
pub fn explain(host: &str, error: &str) -> String {
    let say = |what: &str| format!("{error} ({what})");
    if error.contains("UnknownIssuer") || error.contains("unknown issuer") {
        say("the broker's certificate is not signed by a CA trusted here: give the CA that signed it in ca_file")
    } else if error.contains("NotValidForName") || error.contains("not valid for name") {
        say(&format!(
            "the broker's certificate is not made for {host:?}: use the name it was made for in the URL"
        ))
    } else if error.contains("Expired") || error.contains("NotValidYet") {
        say("the broker's certificate is outside its validity period: renew it, or check this machine's clock")
    } else if error.contains("CertificateRequired") || error.contains("certificate required") {
        say("the broker asks for a client certificate: give client_cert and client_key")
    } else {
        error.to_string()
    }
}
