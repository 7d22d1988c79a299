//! A `drivebus` run to its end: what it printed and its exit status, for the end-to-end tests.

#![allow(dead_code)]

use std::process::Command;

/// What a `drivebus` run printed, and its exit status.
pub struct Out {
    /// The exit status (-1 when killed).
    pub code: i32,
    /// Standard output.
    pub stdout: String,
    /// Standard error.
    pub stderr: String,
}

/// Runs `cmd` to its end and keeps what it printed.
pub fn output(cmd: &mut Command) -> Out {
    let out = cmd.output().expect("run drivebus");
    Out {
        code: out.status.code().unwrap_or(-1),
        stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
        stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
    }
}
