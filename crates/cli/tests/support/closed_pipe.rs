//! A reader that stops early (`drivebus ... | head -1`): the command must end quietly, by
//! SIGPIPE as any Unix tool does or done before the pipe closed, never with a panic.

use std::io::{BufRead, BufReader};
use std::os::unix::process::ExitStatusExt;
use std::process::{Command, Stdio};

/// Runs `cmd`, reads its first line, closes the pipe, and checks how the command ended. Returns
/// the first line for the caller to check.
pub fn first_line_then_close(mut cmd: Command) -> String {
    let mut child = cmd.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("start drivebus");
    let mut out = BufReader::new(child.stdout.take().expect("stdout"));
    let mut first = String::new();
    out.read_line(&mut first).expect("a first line");
    drop(out);
    let result = child.wait_with_output().expect("drivebus ends");
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_ne!(result.status.code(), Some(101), "a panic's exit status: {stderr}");
    const SIGPIPE: i32 = 13;
    assert!(
        result.status.signal() == Some(SIGPIPE) || result.status.success(),
        "{:?} {stderr}",
        result.status
    );
    first
}
