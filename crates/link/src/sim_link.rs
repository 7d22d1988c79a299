//! The simulator's virtual line as a [`Link`], for buses of simulated drives in this process
//! (`serve --demo`, tests, benchmarks). Behind the `virtual` feature: without it drivebus-sim is
//! not in this crate's graph.

use std::io;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use drivebus_sim::bus::VirtualLine;

use crate::link::{Clock, Link};

/// The simulator's virtual line in the same process: paced at its baud rate on tokio time.
pub struct SimLink {
    line: Arc<Mutex<VirtualLine>>,
    clock: Clock,
    name: String,
    /// Which of the line's masters this link is (`VirtualLine::add_master`).
    master: usize,
}

impl SimLink {
    /// A link to `line` (whose simulated time starts with this link).
    pub fn new(line: Arc<Mutex<VirtualLine>>, name: &str) -> Self {
        Self::with_clock(line, name, Clock::new())
    }

    /// A link to `line` telling time by `clock`.
    pub(crate) fn with_clock(line: Arc<Mutex<VirtualLine>>, name: &str, clock: Clock) -> Self {
        SimLink { line, clock, name: name.to_string(), master: drivebus_sim::bus::MASTER }
    }

    /// A link to `line` as its master `master` (from `VirtualLine::add_master`): a second
    /// gateway on the same line, telling time by the first one's `clock` (the line has one).
    pub fn for_master(line: Arc<Mutex<VirtualLine>>, name: &str, master: usize, clock: Clock) -> Self {
        SimLink { master, ..Self::with_clock(line, name, clock) }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, VirtualLine> {
        self.line.lock().unwrap_or_else(|p| p.into_inner())
    }
}

impl Link for SimLink {
    fn name(&self) -> String {
        self.name.clone()
    }
    fn clock(&self) -> Clock {
        self.clock
    }
    async fn write(&mut self, bytes: &[u8]) -> io::Result<()> {
        let now = self.now();
        let master = self.master;
        self.lock().master_write_from(master, now, bytes);
        Ok(())
    }
    async fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let mut got = Vec::new();
        loop {
            let now = self.now();
            let next = {
                let mut line = self.lock();
                line.advance_to(now);
                line.master_read_to(self.master, &mut got);
                line.next_deadline()
            };
            if !got.is_empty() {
                let n = got.len().min(buf.len());
                buf[..n].copy_from_slice(&got[..n]);
                if n < got.len() {
                    // Keep order: put the rest back by writing nothing and returning what fits;
                    // buffers here are always large enough (a frame's worth at most).
                    return Err(io::Error::other("read buffer smaller than a burst"));
                }
                return Ok(n);
            }
            match next {
                Some(t) if t > now => crate::timer::sleep_until(self.clock.tokio(t)).await,
                Some(_) => tokio::task::yield_now().await,
                // Nothing on the line: wait a while (a write from us is the only way out, and
                // the caller cancels this read to write).
                None => tokio::time::sleep(Duration::from_millis(50)).await,
            }
        }
    }
    async fn reopen(&mut self) -> io::Result<()> {
        Ok(())
    }
}
