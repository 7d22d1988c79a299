//! The tests' child processes: killed on drop ([`Killed`]), and waited on until they say
//! something on stdout (an event, not a sleep).

#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};

/// Reads `child`'s stdout until `want` has matched a line for each of its prefixes (events, not
/// sleeps); the rest of each matching line, in the order of `want`. The rest of the output is
/// drained in the background.
pub fn wait_for_lines(child: &mut Child, what: &str, want: &[&str]) -> Vec<String> {
    let mut lines = BufReader::new(child.stdout.take().expect("stdout")).lines();
    let mut found: Vec<Option<String>> = vec![None; want.len()];
    while found.iter().any(Option::is_none) {
        let line = match lines.next() {
            Some(Ok(l)) => l,
            _ => panic!("{what} ended before printing {want:?}"),
        };
        for (i, prefix) in want.iter().enumerate() {
            if let Some(rest) = line.trim().strip_prefix(prefix) {
                found[i].get_or_insert_with(|| rest.trim().to_string());
            }
        }
    }
    std::thread::spawn(move || for _ in lines {});
    found.into_iter().flatten().collect()
}

/// `child`'s stdout lines before the first one that contains `marker` (all of them if none
/// does); stdout is closed after it.
pub fn stdout_until(child: &mut Child, marker: &str) -> Vec<String> {
    let out = BufReader::new(child.stdout.take().expect("stdout"));
    out.lines().map_while(Result::ok).take_while(|l| !l.contains(marker)).collect()
}

/// `drivebus serve` with HTTP and Modbus TCP on free loopback ports (port 0) and OPC UA on
/// `opcua`, its stdout piped for [`wait_for_lines`]; more flags to be given.
pub fn serve_command(opcua: &str) -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_drivebus"));
    cmd.args(["serve", "--http", "127.0.0.1:0", "--modbus", "127.0.0.1:0", "--opcua", opcua])
        .stdout(Stdio::piped());
    cmd
}

/// A child process killed (and reaped) on drop.
pub struct Killed(pub Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}
