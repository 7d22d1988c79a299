//! Detection: which protocols are on the line, found from the traffic by every protocol's
//! deframer scoring valid frames; a protocol that starts talking later is found too, and its
//! first frames decoded from the recent reads.

use std::time::Duration;

use super::framing::framer;
use super::{Analyzer, Record, PROTOCOLS};

/// Auto-detection settles once a protocol has this many valid frames.
pub(super) const SETTLE_FRAMES: u64 = 4;
/// A protocol is decoded once it has this many valid frames (found when the detection settles,
/// or later on a line where a second protocol starts talking).
pub(super) const FOUND_FRAMES: u64 = 2;
/// A protocol found after the first choice decodes the reads of this long before...
pub(super) const RECENT_TIME: Duration = Duration::from_secs(2);
/// ...up to this many.
pub(super) const RECENT_READS: usize = 256;
/// Auto-detection settles with what it has after this long of traffic.
pub const DETECT_WITHIN: Duration = Duration::from_secs(5);

impl Analyzer {
    /// Runs the scouts over `bytes`, counting valid frames per protocol; adds a protocol found
    /// after the first choice (a second protocol on a mixed line).
    ///
    /// Returns true when a protocol not decoded yet found a valid frame in these bytes: the
    /// decoded protocols' rejects of them are then that protocol's traffic, not errors.
    pub(super) fn scout(&mut self, port: usize, time: Duration, bytes: &[u8], out: &mut Vec<Record>) -> bool {
        let side = self.ports[port].side;
        let mut foreign = false;
        for i in 0..self.ports[port].scouts.len() {
            let mut cuts = Vec::new();
            self.ports[port].scouts[i].1.push(bytes, &mut cuts);
            let (p, f) = &self.ports[port].scouts[i];
            let p = *p;
            for c in cuts {
                if c.error.is_none() && f.valid(&c.bytes, side.direction()) {
                    *self.score.entry(p).or_default() += 1;
                    foreign |= !self.active.contains(&p);
                }
            }
        }
        if !self.active.is_empty() {
            let late: Vec<&'static str> = self
                .score
                .iter()
                .filter(|(p, n)| **n >= FOUND_FRAMES && !self.active.contains(p))
                .map(|(p, _)| *p)
                .collect();
            for p in late {
                self.activate(p);
                // Its first frames went by before it was known: decode them from the history.
                let recent: Vec<(usize, Duration, Vec<u8>)> = self.recent.iter().cloned().collect();
                for (port, t, b) in recent {
                    if let Some(i) = self.ports[port].framers.iter().position(|(x, _)| *x == p) {
                        self.decode_with(port, i, t, &b, out);
                    }
                }
            }
        }
        self.recent.push_back((port, time, bytes.to_vec()));
        while self.recent.len() > RECENT_READS
            || self.recent.front().is_some_and(|(_, t, _)| time.saturating_sub(*t) > RECENT_TIME)
        {
            self.recent.pop_front();
        }
        foreign
    }

    /// Chooses the protocols once one has [`SETTLE_FRAMES`] valid frames, or after
    /// [`DETECT_WITHIN`] of traffic with any.
    pub(super) fn settle(&mut self, now: Duration, out: &mut Vec<Record>) {
        let best = self.score.values().copied().max().unwrap_or(0);
        let waited = self.first.is_some_and(|f| now.saturating_sub(f) >= DETECT_WITHIN);
        if best >= SETTLE_FRAMES || (waited && best > 0) {
            self.choose(if best >= SETTLE_FRAMES { FOUND_FRAMES } else { 1 });
            self.replay(out);
        }
    }

    pub(super) fn choose(&mut self, min: u64) {
        let found: Vec<&'static str> =
            PROTOCOLS.iter().copied().filter(|p| self.score.get(p).is_some_and(|&n| n >= min)).collect();
        for p in found {
            self.activate(p);
        }
    }

    pub(super) fn activate(&mut self, p: &'static str) {
        if self.active.contains(&p) {
            return;
        }
        self.active.push(p);
        for port in &mut self.ports {
            if let Some(f) = framer(p, port.side.direction()) {
                port.framers.push((p, f));
            }
        }
    }

    /// Decodes what was held while the protocol was being found.
    pub(super) fn replay(&mut self, out: &mut Vec<Record>) {
        let held = std::mem::take(&mut self.held);
        let mut last: Vec<Option<Duration>> = vec![None; self.ports.len()];
        for (port, time, bytes) in held {
            if let Some(at) = last[port].filter(|l| time.saturating_sub(*l) > self.t35) {
                self.silence_framers(port, at, Some(&bytes), out);
            }
            last[port] = Some(time);
            self.expire(time, out);
            self.decode(port, time, &bytes, out);
        }
    }
}
