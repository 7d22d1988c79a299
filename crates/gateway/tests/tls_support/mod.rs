//! Certificates made at test time (no key is ever in the tree): a CA, a server certificate
//! for some names signed by it, a client certificate signed by it, and a second CA that signed
//! neither.

#![allow(dead_code)]

use std::path::{Path, PathBuf};

use rcgen::{BasicConstraints, Certificate, CertificateParams, DnType, IsCa, KeyPair};

/// The files of a test PKI, in one folder.
pub struct TestPki {
    /// The folder.
    pub dir: PathBuf,
    /// The CA that signed the server's and the client's certificates.
    pub ca: PathBuf,
    /// A CA that signed nothing here.
    pub other_ca: PathBuf,
    /// The server's certificate and key.
    pub server_cert: PathBuf,
    /// Its key.
    pub server_key: PathBuf,
    /// The client's certificate and key.
    pub client_cert: PathBuf,
    /// Its key.
    pub client_key: PathBuf,
}

fn ca(name: &str) -> (Certificate, KeyPair) {
    let key = KeyPair::generate().unwrap();
    let mut params = CertificateParams::new(Vec::<String>::new()).unwrap();
    params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
    params.distinguished_name.push(DnType::CommonName, name);
    (params.self_signed(&key).unwrap(), key)
}

fn signed(names: &[&str], cn: &str, ca: &Certificate, ca_key: &KeyPair) -> (Certificate, KeyPair) {
    let key = KeyPair::generate().unwrap();
    let mut params = CertificateParams::new(names.iter().map(|n| n.to_string()).collect::<Vec<_>>()).unwrap();
    params.distinguished_name.push(DnType::CommonName, cn);
    (params.signed_by(&key, ca, ca_key).unwrap(), key)
}

impl TestPki {
    /// Makes the files in a new folder named after `tag`, the server's certificate for `names`
    /// (host names or addresses).
    pub fn new(tag: &str, names: &[&str]) -> TestPki {
        let dir = std::env::temp_dir().join(format!("drivebus-pki-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let (ca_cert, ca_key) = ca("drivebus test CA");
        let (other, _) = ca("another CA");
        let (server, server_key) = signed(names, "broker", &ca_cert, &ca_key);
        let (client, client_key) = signed(&["gateway"], "gateway", &ca_cert, &ca_key);
        let write = |name: &str, text: String| {
            let p = dir.join(name);
            std::fs::write(&p, text).unwrap();
            p
        };
        TestPki {
            ca: write("ca.pem", ca_cert.pem()),
            other_ca: write("other-ca.pem", other.pem()),
            server_cert: write("server.pem", server.pem()),
            server_key: write("server.key", server_key.serialize_pem()),
            client_cert: write("client.pem", client.pem()),
            client_key: write("client.key", client_key.serialize_pem()),
            dir,
        }
    }

    /// A path as a TOML string's content.
    pub fn toml(p: &Path) -> String {
        p.display().to_string().replace('\\', "\\\\")
    }
}

impl Drop for TestPki {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}
