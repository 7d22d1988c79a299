//! The Rust tests' side of the witnesses (programs nobody here wrote): whether one is here, and
//! what to do when it is not. Every test that needs one is marked
//! `#[ignore = "needs <program> (.ci/install-witnesses.sh)"]`, so a plain `cargo test` lists it
//! as ignored, never as passed; `cargo test -- --ignored` runs them. `.ci/install-witnesses.sh`
//! installs them and CI sets `DRIVEBUS_REQUIRE_INTEROP=1`, so there a missing witness fails the
//! test; run by hand without it, the test says on stderr that it did not run. Included by the
//! tests with `#[path]`.

#![allow(dead_code)]

use std::io::Write;
use std::process::Command;

/// Whether missing witnesses fail (CI).
pub fn required() -> bool {
    std::env::var_os("DRIVEBUS_REQUIRE_INTEROP").is_some()
}

/// True when the witness `name` is here; otherwise says so (and fails where required).
pub fn witness(name: &str, present: bool, how: &str) -> bool {
    if present {
        return true;
    }
    assert!(!required(), "{name} is required in CI but missing: {how}");
    // Straight to stderr, past the test harness's capture, so that the run says it.
    let _ = writeln!(
        std::io::stderr(),
        "NOT RUN: {name} is not installed ({how}); .ci/install-witnesses.sh installs it"
    );
    false
}

/// Whether Python can import `module`.
pub fn python_has(module: &str) -> bool {
    Command::new("python3")
        .args(["-c", &format!("import {module}")])
        .output()
        .is_ok_and(|o| o.status.success())
}

/// Whether `program args` runs (and exits 0 when `success` is asked).
pub fn runs(program: &str, args: &[&str], success: bool) -> bool {
    Command::new(program).args(args).output().is_ok_and(|o| !success || o.status.success())
}
