//! Refusals in the audit trail without a flood: the first refusal of a (client, reason) is
//! audited at once; the ones that follow within a window are counted and written as one audit
//! event (and so one log line) when the window closes: "1204 refused from modbus:127.0.0.2 in
//! the last 60 s: forbidden: ...". A client that keeps being refused gets one event per window.
//!
//! [`Refusals`] is the bookkeeping alone (sans-IO: every call is given the time), so that it is
//! tested on explicit times; [`crate::core::Gateway::audit_refusal`] feeds it and a task of
//! the gateway closes the windows that are due.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::time::Duration;

use tokio::time::Instant;

/// How long repeats of one refusal are counted before they are written as one event.
pub const WINDOW: Duration = Duration::from_secs(60);

/// Most (client, reason) pairs counted at once; refusals of further pairs are counted under the
/// client `other clients`, so that a flood from ever new addresses cannot grow the table.
pub const MAX_KEYS: usize = 4096;

/// The client shown for refusals counted beyond [`MAX_KEYS`].
pub const OTHER_CLIENTS: &str = "other clients";

/// The refusal a window counts: the first one's drive, action and reason in full.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Refused {
    /// The drive the first refused write was for (`None`: no drive, a failed login).
    pub drive: Option<String>,
    /// What was refused (`modbus write of 1 register(s) at 0`, `mqtt set/run`).
    pub action: String,
    /// Why, in full (`forbidden: client 127.0.0.2 may not write ([modbus] allow)`).
    pub why: String,
}

/// What to do with a refusal just seen.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Seen {
    /// The first of its (client, reason) in a while: audit and log it now.
    First,
    /// A repeat: counted, written when its window closes.
    Counted,
}

/// Repeats of one (client, reason) counted over a window that has closed.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Summary {
    /// Who was refused (`modbus:127.0.0.2`, `mqtt:drivebus-hall-1`, [`OTHER_CLIENTS`]).
    pub client: String,
    /// The reason's kind (`forbidden`, `locked`, `too_large`, ...).
    pub reason: String,
    /// Refusals counted in the window (the first one, audited on its own, not included).
    pub count: u64,
    /// The refusal that opened the counting.
    pub sample: Refused,
    /// How long the window was.
    pub window: Duration,
}

impl Summary {
    /// The audit event's result: `1204 refused from modbus:127.0.0.2 in the last 60 s: <why>`.
    pub fn result(&self) -> String {
        format!(
            "{} refused from {} in the last {} s: {}",
            self.count,
            self.client,
            self.window.as_secs(),
            self.sample.why
        )
    }
}

struct Window {
    closes: Instant,
    count: u64,
    sample: Refused,
}

/// The windows open now, per (client, reason).
pub struct Refusals {
    window: Duration,
    open: HashMap<(String, String), Window>,
}

impl Default for Refusals {
    fn default() -> Self {
        Refusals::new(WINDOW)
    }
}

impl Refusals {
    /// Counts repeats over windows of `window`.
    pub fn new(window: Duration) -> Refusals {
        Refusals { window, open: HashMap::new() }
    }

    /// A refusal of `sample` for `client` at `now`. The reason is the kind that starts
    /// `sample.why` (the text before its first `:`).
    pub fn refused(&mut self, now: Instant, client: &str, sample: Refused) -> Seen {
        let reason = reason_of(&sample.why).to_string();
        let mut key = (client.to_string(), reason);
        if !self.open.contains_key(&key) && self.open.len() >= MAX_KEYS {
            key.0 = OTHER_CLIENTS.to_string();
        }
        match self.open.get_mut(&key) {
            Some(w) => {
                w.count += 1;
                Seen::Counted
            }
            None => {
                self.open.insert(key, Window { closes: now + self.window, count: 0, sample });
                Seen::First
            }
        }
    }

    /// The windows closed at `now` that counted repeats, one summary each. A window that
    /// counted some opens again (the flood goes on: one summary per window); one that counted
    /// none is forgotten, so the next refusal is a first again.
    pub fn due(&mut self, now: Instant) -> Vec<Summary> {
        let mut out = Vec::new();
        let window = self.window;
        self.open.retain(|(client, reason), w| {
            if w.closes > now {
                return true;
            }
            if w.count == 0 {
                return false;
            }
            out.push(Summary {
                client: client.clone(),
                reason: reason.clone(),
                count: w.count,
                sample: w.sample.clone(),
                window,
            });
            w.count = 0;
            w.closes = now + window;
            true
        });
        out.sort_by(|a, b| (&a.client, &a.reason).cmp(&(&b.client, &b.reason)));
        out
    }

    /// Refusals of `client` for `reason` in its window open now (the first included; 0 when
    /// none is open).
    pub fn seen(&self, client: &str, reason: &str) -> u64 {
        self.open.get(&(client.to_string(), reason.to_string())).map_or(0, |w| 1 + w.count)
    }

    /// When the next window closes, if any is open.
    pub fn next_due(&self) -> Option<Instant> {
        self.open.values().map(|w| w.closes).min()
    }
}

/// The kind that starts a refusal's text (`forbidden` of `forbidden: client ... may not
/// write`), at most 32 characters.
pub fn reason_of(why: &str) -> &str {
    let kind = why.split_once(':').map_or(why, |(k, _)| k).trim();
    crate::text::cut(kind, 32).0
}

/// Who a refusal is counted for: the actor without its port (`modbus:127.0.0.2` for
/// `modbus:127.0.0.2:50412`), so that many connections of one address count as one client.
pub fn client_of(actor: &str) -> String {
    if let Some((scheme, addr)) = actor.split_once(':') {
        if let Ok(a) = addr.parse::<SocketAddr>() {
            return format!("{scheme}:{}", a.ip());
        }
    }
    crate::text::cut(actor, 128).0.to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(why: &str) -> Refused {
        Refused {
            drive: Some("pump-1".into()),
            action: "modbus write of 1 register(s) at 0".into(),
            why: why.into(),
        }
    }

    const WHY: &str = "forbidden: client 127.0.0.2 may not write ([modbus] allow)";

    #[test]
    fn the_first_is_audited_the_repeats_are_one_summary_per_window() {
        let t0 = Instant::now();
        let at = |ms: u64| t0 + Duration::from_millis(ms);
        let mut r = Refusals::new(Duration::from_secs(60));
        assert_eq!(r.refused(at(0), "modbus:127.0.0.2", sample(WHY)), Seen::First);
        for k in 1..=1204 {
            assert_eq!(r.refused(at(k * 10), "modbus:127.0.0.2", sample(WHY)), Seen::Counted);
        }
        assert_eq!(r.seen("modbus:127.0.0.2", "forbidden"), 1205);
        assert_eq!(r.seen("modbus:127.0.0.2", "locked"), 0);
        // Another client, another reason: firsts of their own.
        assert_eq!(r.refused(at(0), "modbus:127.0.0.3", sample(WHY)), Seen::First);
        assert_eq!(r.refused(at(0), "modbus:127.0.0.2", sample("locked: drive \"pump-3\"")), Seen::First);
        assert_eq!(r.next_due(), Some(at(60_000)));
        assert!(r.due(at(59_999)).is_empty());
        let s = r.due(at(60_000));
        assert_eq!(s.len(), 1, "{s:?}");
        assert_eq!(
            (s[0].client.as_str(), s[0].reason.as_str(), s[0].count),
            ("modbus:127.0.0.2", "forbidden", 1204)
        );
        assert_eq!(
            s[0].result(),
            "1204 refused from modbus:127.0.0.2 in the last 60 s: forbidden: client 127.0.0.2 may not write ([modbus] allow)"
        );
        // The windows that counted nothing are gone: their next refusal is a first again.
        assert_eq!(r.refused(at(61_000), "modbus:127.0.0.3", sample(WHY)), Seen::First);
        // The flood goes on: counted in the next window, one summary at its end.
        assert_eq!(r.refused(at(61_000), "modbus:127.0.0.2", sample(WHY)), Seen::Counted);
        assert_eq!(r.refused(at(62_000), "modbus:127.0.0.2", sample(WHY)), Seen::Counted);
        let s = r.due(at(120_000));
        assert_eq!(s.len(), 1);
        assert_eq!(s[0].count, 2);
        // Quiet for a whole window: forgotten.
        assert!(r.due(at(180_000)).is_empty());
        assert_eq!(r.refused(at(180_001), "modbus:127.0.0.2", sample(WHY)), Seen::First);
    }

    #[test]
    fn ever_new_clients_do_not_grow_the_table() {
        let t0 = Instant::now();
        let mut r = Refusals::new(WINDOW);
        for k in 0..MAX_KEYS + 100 {
            r.refused(t0, &format!("mqtt:{k}"), sample(WHY));
        }
        assert_eq!(r.open.len(), MAX_KEYS + 1);
        let s = r.due(t0 + WINDOW);
        assert_eq!(s.len(), 1);
        assert_eq!((s[0].client.as_str(), s[0].count), (OTHER_CLIENTS, 99));
    }

    #[test]
    fn clients_and_reasons() {
        assert_eq!(client_of("modbus:127.0.0.2:50412"), "modbus:127.0.0.2");
        assert_eq!(client_of("modbus:[::1]:502"), "modbus:::1");
        assert_eq!(client_of("mqtt:drivebus-hall-1"), "mqtt:drivebus-hall-1");
        assert_eq!(reason_of("too_large: a command payload has at most 256 bytes"), "too_large");
        assert_eq!(reason_of("no colon"), "no colon");
        assert_eq!(reason_of(&"x".repeat(100)).len(), 32);
    }
}
