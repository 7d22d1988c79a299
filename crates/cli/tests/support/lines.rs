//! The tests' child processes: killed on drop ([`Killed`]), and waited on until they say
//! something on stdout (an event, not a sleep).

#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::process::Child;

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

/// A child process killed (and reaped) on drop.
pub struct Killed(pub Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}
