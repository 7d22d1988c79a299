//! CI's check that no private key is committed (.ci/check-no-keys.sh), run on a repository made
//! here: it finds a PEM key, a DER key and a key store, and passes certificates and ordinary files.

use std::path::Path;
use std::process::Command;

fn git(dir: &Path, args: &[&str]) {
    let out = Command::new("git").current_dir(dir).args(args).output().expect("git");
    assert!(out.status.success(), "git {args:?}: {}", String::from_utf8_lossy(&out.stderr));
}

/// Runs the check on `dir`: its exit status and what it said on stderr.
fn check(dir: &Path) -> (bool, String) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.ci/check-no-keys.sh");
    let out = Command::new("bash").arg(script).arg(dir).output().expect("bash");
    (out.status.success(), String::from_utf8_lossy(&out.stderr).into_owned())
}

/// A repository with `files` added to its index.
fn repo(files: &[(&str, Vec<u8>)]) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    git(dir.path(), &["init", "-q"]);
    for (name, bytes) in files {
        let path = dir.path().join(name);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, bytes).unwrap();
        git(dir.path(), &["add", name]);
    }
    dir
}

/// Bytes that start as a DER structure of `header`, then filler.
fn der(header: &[u8]) -> Vec<u8> {
    let mut b = header.to_vec();
    b.resize(600, 0x5a);
    b
}

#[test]
fn the_check_finds_committed_private_keys_and_passes_certificates() {
    // Built at run time, so this file holds no key line itself.
    let pem = format!(
        "-----BEGIN {}PRIVATE KEY-----\nMIIEvQIBADANBgkqhkiG9w0BAQEFAASC\n-----END PRIVATE KEY-----\n",
        ""
    );
    let rsa = pem.replace("BEGIN PRIVATE", "BEGIN RSA PRIVATE");
    // A certificate: a SEQUENCE whose first member is a SEQUENCE (tbsCertificate).
    let cert = der(&[0x30, 0x82, 0x03, 0x10, 0x30, 0x82, 0x02, 0xf8, 0xa0, 0x03]);
    let clean = repo(&[
        ("README.md", b"a plant\n".to_vec()),
        ("pki/own/cert.der", cert.clone()),
        ("docs/keys.md", b"keys are made in <pki_dir>/private/private.pem\n".to_vec()),
    ]);
    let (ok, said) = check(clean.path());
    assert!(ok, "a repository with no key was refused: {said}");

    for (name, bytes) in [
        ("pki/private/private.pem", pem.into_bytes()),
        ("deep/in/there/server.txt", rsa.into_bytes()),
        // PKCS#8: SEQUENCE, INTEGER 0, the rsaEncryption algorithm.
        ("pki/private/key.der", der(&[0x30, 0x82, 0x04, 0xbe, 0x02, 0x01, 0x00, 0x30, 0x0d, 0x06])),
        // SEC1 EC key: SEQUENCE, INTEGER 1, OCTET STRING.
        ("ec.bin", der(&[0x30, 0x77, 0x02, 0x01, 0x01, 0x04, 0x20])),
        ("client.p12", b"anything".to_vec()),
    ] {
        let dirty = repo(&[("README.md", b"a plant\n".to_vec()), ("cert.der", cert.clone()), (name, bytes)]);
        let (ok, said) = check(dirty.path());
        assert!(!ok, "{name} was not found");
        assert!(said.contains(name), "the check does not name {name}: {said}");
        assert!(!said.contains("cert.der"), "a certificate was taken for a key: {said}");
    }
}
