//! Sessions per user (`[opcua] max_sessions_per_user`): who holds how many sessions, keyed by
//! the user the gateway authenticated (a token's name, or anonymous), never by what the client
//! says of itself.
//!
//! async-opcua tells the authenticator who logs in but not the session, and tells the node
//! manager the session of each request but not when it ends. So a login is admitted while the
//! user holds fewer sessions than the cap, and recorded as a pending entry; the session's first
//! request to the drives' namespace links it to that entry (by the session object, held weakly:
//! a closed or expired session no longer counts). A pending entry counts for the library's
//! longest session timeout, the most a session can live without a request. A session that
//! reaches the drives beyond the cap (its pending entry aged out while it kept itself alive
//! elsewhere) is refused there. The bookkeeping alone, given the time, so it is tested on
//! explicit times.

use std::sync::Mutex;
use std::time::{Duration, Instant};

/// A session as seen by a request: who it is (the address of its object, which a weak
/// reference held by `open` keeps from being reused) and whether it is still open.
pub struct Seen {
    /// The session object's address.
    pub id: usize,
    /// Whether the session is open (activated, not closed nor expired).
    pub open: Box<dyn Fn() -> bool + Send + Sync>,
}

struct Entry {
    user: String,
    since: Instant,
    /// The session, once a request linked it.
    session: Option<Seen>,
}

impl Entry {
    fn live(&self, now: Instant, pending_for: Duration) -> bool {
        match &self.session {
            Some(s) => (s.open)(),
            None => now.saturating_duration_since(self.since) < pending_for,
        }
    }
}

/// The sessions of each user.
pub struct Sessions {
    entries: Mutex<Vec<Entry>>,
    /// How long a login not yet linked to its session counts.
    pending_for: Duration,
}

impl Sessions {
    /// No sessions; a login counts `pending_for` until its session is seen.
    pub fn new(pending_for: Duration) -> Self {
        Sessions { entries: Mutex::new(Vec::new()), pending_for }
    }

    /// A login of `user`: admitted (and counted) while the user holds fewer than `max`
    /// sessions.
    pub fn admit(&self, user: &str, max: usize, now: Instant) -> bool {
        let mut entries = self.entries.lock().unwrap_or_else(|p| p.into_inner());
        entries.retain(|e| e.live(now, self.pending_for));
        if entries.iter().filter(|e| e.user == user).count() >= max {
            return false;
        }
        entries.push(Entry { user: user.to_string(), since: now, session: None });
        true
    }

    /// A request of `session`, whose user is `user`: whether the session is within the cap
    /// (linking it to one of the user's pending logins the first time).
    pub fn seen(&self, user: &str, session: Seen, max: usize, now: Instant) -> bool {
        let mut entries = self.entries.lock().unwrap_or_else(|p| p.into_inner());
        let same = |e: &Entry| e.session.as_ref().is_some_and(|s| s.id == session.id);
        if entries.iter().any(|e| e.user == user && same(e)) {
            return true;
        }
        entries.retain(|e| e.live(now, self.pending_for));
        let pending =
            entries.iter_mut().filter(|e| e.user == user && e.session.is_none()).min_by_key(|e| e.since);
        if let Some(e) = pending {
            e.session = Some(session);
            return true;
        }
        // Its login aged out while it lived on: admitted only within the cap.
        if entries.iter().filter(|e| e.user == user).count() >= max {
            return false;
        }
        entries.push(Entry { user: user.to_string(), since: now, session: Some(session) });
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::{Arc, Weak};

    struct Fake(AtomicBool);

    fn session() -> Arc<Fake> {
        Arc::new(Fake(AtomicBool::new(true)))
    }

    /// As the node manager makes it from a request's session.
    fn weak(s: &Arc<Fake>) -> Seen {
        let w: Weak<Fake> = Arc::downgrade(s);
        Seen {
            id: Arc::as_ptr(s) as usize,
            open: Box::new(move || w.upgrade().is_some_and(|s| s.0.load(Ordering::Relaxed))),
        }
    }

    #[test]
    fn a_user_holds_at_most_max_sessions_and_a_closed_one_frees_its_place() {
        let t0 = Instant::now();
        let s = Sessions::new(Duration::from_secs(60));
        assert!(s.admit("ops", 2, t0));
        assert!(s.admit("ops", 2, t0));
        assert!(!s.admit("ops", 2, t0), "a third session of ops");
        // Another user, and anonymous, count apart.
        assert!(s.admit("anonymous", 2, t0));
        // The two sessions make requests: linked to their logins.
        let (a, b) = (session(), session());
        assert!(s.seen("ops", weak(&a), 2, t0));
        assert!(s.seen("ops", weak(&b), 2, t0));
        assert!(s.seen("ops", weak(&a), 2, t0), "a session seen again");
        // Linked sessions count as long as they are open, not for the pending time.
        let later = t0 + Duration::from_secs(3600);
        assert!(!s.admit("ops", 2, later));
        a.0.store(false, Ordering::Relaxed);
        assert!(s.admit("ops", 2, later), "a closed session freed its place");
        drop(b);
        assert!(s.admit("ops", 2, later), "a session gone freed its place");
        assert!(!s.admit("ops", 2, later));
    }

    #[test]
    fn a_login_never_seen_counts_for_the_pending_time_and_a_session_beyond_the_cap_is_refused() {
        let t0 = Instant::now();
        let s = Sessions::new(Duration::from_secs(60));
        assert!(s.admit("ops", 1, t0));
        assert!(!s.admit("ops", 1, t0 + Duration::from_secs(59)));
        let late = t0 + Duration::from_secs(61);
        assert!(s.admit("ops", 1, late), "the unseen login aged out");
        let (first, second) = (session(), session());
        assert!(s.seen("ops", weak(&first), 1, late));
        // A session whose login aged out, kept alive elsewhere, reaches the drives: over the cap.
        assert!(!s.seen("ops", weak(&second), 1, late));
        first.0.store(false, Ordering::Relaxed);
        assert!(s.seen("ops", weak(&second), 1, late));
    }
}
