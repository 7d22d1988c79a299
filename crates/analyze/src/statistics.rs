//! Statistics: per-address counts and reply latencies, garbled frames and the bus load.

use std::collections::BTreeMap;
use std::time::Duration;

use super::Analyzer;

/// Counts for one drive address.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AddressStats {
    /// Requests to it.
    pub requests: u64,
    /// Replies from it.
    pub replies: u64,
    /// Requests that got no reply.
    pub timeouts: u64,
    /// Damaged replies and refusals (exceptions, error codes).
    pub errors: u64,
    /// Reply latencies, in the order seen.
    pub latencies: Vec<Duration>,
}

impl AddressStats {
    /// The `q` quantile (0..1) of the latencies, nearest rank.
    pub fn latency_quantile(&self, q: f64) -> Option<Duration> {
        if self.latencies.is_empty() {
            return None;
        }
        let mut v = self.latencies.clone();
        v.sort();
        let rank = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len());
        Some(v[rank - 1])
    }
}

impl Analyzer {
    /// Per (protocol, address) statistics.
    pub fn stats(&self) -> &BTreeMap<(&'static str, u8), AddressStats> {
        &self.stats
    }

    /// Invalid frames that no request was waiting for.
    pub fn garbled(&self) -> u64 {
        self.garbled
    }

    /// Frames reported, valid or not.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// The share of the time the line carried characters, from the first read to the last.
    pub fn bus_load(&self) -> f64 {
        let (Some(a), Some(b)) = (self.first, self.last) else { return 0.0 };
        let span = b.saturating_sub(a).as_secs_f64();
        if span <= 0.0 {
            return 0.0;
        }
        let busy = self.settings.format.wire_time(self.settings.baud, 1).as_secs_f64() * self.bytes as f64;
        (busy / span).min(1.0)
    }
}
