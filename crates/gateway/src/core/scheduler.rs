//! The poll loops: one scheduler per bus that polls each drive at its interval, a status read
//! ahead of polls after a command (which counts as the drive's poll), and the buses' statistics
//! for live subscribers.

use std::collections::HashMap;
use std::future::Future;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use super::cache::{BusEntry, DriveEntry};
use super::gateway::Gateway;
use super::views::Change;
use crate::config::PollPriority;
use drivebus_link::role::Role;
use drivebus_store::time::now_ms;
use drivebus_store::{Event, EventKind};

/// How often a drive is polled: at its `poll_ms`, or at the interval another master on the line
/// was heard polling it (`learnt`, a standby's schedule, kept after it takes the line) when that
/// is shorter. Never slower than `poll_ms`: `[standby] silence_ms` is checked against it, and a
/// line polled more slowly would fall silent long enough for another standby to take it.
pub(super) fn poll_every(own: Duration, learnt: Option<Duration>) -> Duration {
    learnt.filter(|l| !l.is_zero()).map_or(own, |l| l.min(own))
}

/// When a drive whose poll was due at `due` and ended at `now` is next due, at `every`: `every`
/// after `due` (a late poll is followed by the next at once, so the schedule catches up), or,
/// when the poll began while the bus listened (`listened`: its start-up listening, a standby's
/// wait), `every` after `now`. Such a poll went on the line (or was answered from the master's
/// traffic) when it ended, not when it was due: the next at once would poll the drive twice in
/// a row, a burst another gateway listening on the line would learn as the interval.
fn next_due(
    due: tokio::time::Instant,
    every: Duration,
    listened: bool,
    now: tokio::time::Instant,
) -> tokio::time::Instant {
    if listened {
        now + every
    } else {
        (due + every).max(now)
    }
}

/// Where a drive stands in its bus's schedule.
#[derive(Clone, Copy, Debug)]
struct Slot {
    /// When its next poll is due.
    due: tokio::time::Instant,
    /// When its status was last read: its last poll ended (answered or not), or a command's
    /// refresh read it (ahead of polls). `None` before either.
    read: Option<tokio::time::Instant>,
}

impl Slot {
    /// A drive not polled yet, due at `now`.
    fn new(now: tokio::time::Instant) -> Self {
        Slot { due: now, read: None }
    }

    /// A command's refresh read the drive's status at `at`: it stands for a poll, so the next
    /// is due no sooner than `every` after it, and the drive waits behind those read longer ago.
    fn refreshed(&mut self, every: Duration, at: tokio::time::Instant) {
        self.due = self.due.max(at + every);
        self.read = Some(self.read.map_or(at, |r| r.max(at)));
    }

    /// How urgent the drive's poll is at `now`, the smallest first: the drives due, the one read
    /// longest ago first (on a line too full to poll every drive at its interval, the oldest
    /// values first, whether a poll or a command's refresh read them last); then the one due
    /// next; by priority on a tie.
    fn urgency(
        &self,
        priority: PollPriority,
        now: tokio::time::Instant,
    ) -> (bool, Option<tokio::time::Instant>, tokio::time::Instant, PollPriority) {
        let waiting = self.due > now;
        (waiting, if waiting { None } else { self.read }, self.due, priority)
    }
}

impl Gateway {
    /// Reads drive `d`'s status now, ahead of polls, into the cache (what a poll would do); the
    /// bus's scheduler counts it as the drive's poll ([`Slot::refreshed`]).
    pub(super) async fn refresh(self: &Arc<Self>, d: &Arc<DriveEntry>) {
        let Some(bus) = self.buses().iter().find(|b| b.config.name == d.bus).cloned() else { return };
        let status = d.command.status().await;
        let read = status.is_ok();
        self.update(&bus, d, status).await;
        if read {
            let at = tokio::time::Instant::now();
            bus.refreshed.lock().unwrap_or_else(|p| p.into_inner()).push((d.clone(), at));
            bus.wake.notify_one();
        }
    }

    /// The scheduler of `bus`: polls each of its drives when due (the most urgent first,
    /// [`Slot::urgency`]; at [`poll_every`], a command's refresh counting as a poll) until a
    /// reload retires the bus; a reload that changes its drives keeps the kept drives' schedule
    /// and polls new ones at once. One drive is polled at a time, or up to the bus's
    /// `max_in_flight` drives at once on a modbus-tcp bus that pipelines (a drive's own reads
    /// stay one after another).
    pub(super) async fn poll_bus(self: Arc<Self>, bus: Arc<BusEntry>) {
        let own_limit = bus.config.max_in_flight.max(1);
        let mut generation = u64::MAX;
        let mut mine: Vec<Arc<DriveEntry>> = Vec::new();
        let mut slots: Vec<Slot> = Vec::new();
        // The polls under way, each with its drive and whether it began while the bus listened
        // (released even when a poll panics).
        let mut polling: InFlight<(Arc<DriveEntry>, bool)> = InFlight::default();
        loop {
            if bus.retired.load(Ordering::Relaxed) {
                return;
            }
            // A reload changed the drives: keep the kept drives' schedule, poll new ones now.
            let now_gen = bus.generation.load(Ordering::Relaxed);
            if now_gen != generation {
                generation = now_gen;
                let next = bus.members.read().unwrap_or_else(|p| p.into_inner()).clone();
                let now = tokio::time::Instant::now();
                slots = next
                    .iter()
                    .map(|d| mine.iter().position(|m| Arc::ptr_eq(m, d)).map_or(Slot::new(now), |k| slots[k]))
                    .collect();
                mine = next;
            }
            // Commands' refreshes stand for the drives' polls. A drive being polled is left to
            // its poll, which ends later than the refresh and schedules the next.
            let refreshed = std::mem::take(&mut *bus.refreshed.lock().unwrap_or_else(|p| p.into_inner()));
            for (d, at) in refreshed {
                let Some(k) = mine.iter().position(|m| Arc::ptr_eq(m, &d)) else { continue };
                if !polling.keys().any(|(b, _)| Arc::ptr_eq(b, &d)) {
                    let every = poll_every(d.config.poll, bus.bus.learnt_interval(d.config.address));
                    slots[k].refreshed(every, at);
                }
            }
            let wake = bus.wake.notified();
            if mine.is_empty() && polling.is_empty() {
                wake.await;
                continue;
            }
            // A standby's polls are answered from what it hears, each when the master's exchange
            // with that drive comes by: they all wait at once, so one the master has not polled
            // lately holds up no other (the bus owner sends none of them).
            let listening = bus.role() == Role::Standby;
            let limit = if listening { mine.len().max(own_limit) } else { own_limit };
            // The most urgent drive not being polled, while fewer than `limit` polls are under way.
            let now = tokio::time::Instant::now();
            let pick = (0..mine.len())
                .filter(|&k| polling.len() < limit && !polling.keys().any(|(b, _)| Arc::ptr_eq(b, &mine[k])))
                .min_by_key(|&k| slots[k].urgency(mine[k].config.priority, now));
            let at = pick.map_or_else(|| now + Duration::from_secs(3600), |k| slots[k].due);
            tokio::select! {
                _ = tokio::time::sleep_until(at), if pick.is_some() => {
                    let k = pick.expect("picked");
                    let d = mine[k].clone();
                    // How much longer than its interval the drive's values waited for this poll.
                    let every = poll_every(d.config.poll, bus.bus.learnt_interval(d.config.address));
                    let waited = slots[k].read.map(|r| tokio::time::Instant::now().saturating_duration_since(r));
                    let lag = waited.map_or(Duration::ZERO, |w| w.saturating_sub(every));
                    bus.poll_lag_us.store(u64::try_from(lag.as_micros()).unwrap_or(u64::MAX), Ordering::Relaxed);
                    let (gw, bus, drive) = (self.clone(), bus.clone(), d.clone());
                    polling.start((d, listening), async move {
                        let result = drive.poll.status().await;
                        gw.update(&bus, &drive, result).await;
                    });
                }
                Some((d, listened)) = polling.next_done(), if !polling.is_empty() => {
                    if let Some(k) = mine.iter().position(|m| Arc::ptr_eq(m, &d)) {
                        let every = poll_every(d.config.poll, bus.bus.learnt_interval(d.config.address));
                        let now = tokio::time::Instant::now();
                        slots[k] = Slot { due: next_due(slots[k].due, every, listened, now), read: Some(now) };
                    }
                }
                _ = wake => continue,
            }
        }
    }

    /// Keeps [`Gateway::mastering`] up to date: the buses' roles are looked at every
    /// [`super::gateway::ROLE_WATCH`] (they change in the bus owners, which tell no one).
    pub(super) async fn watch_roles(self: Arc<Self>) {
        let mut tick = tokio::time::interval(super::gateway::ROLE_WATCH);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tick.tick().await;
            let now = self.masters_any_bus();
            self.mastering.send_if_modified(|m| std::mem::replace(m, now) != now);
        }
    }

    /// Sends every bus's view to live subscribers once a second, and records each takeover
    /// and yield of a bus that shares its line with another gateway as an event.
    pub(super) async fn publish_buses(self: Arc<Self>) {
        let mut tick = tokio::time::interval(Duration::from_secs(1));
        // Per bus: the takeovers and yields already recorded.
        let mut seen: std::collections::HashMap<String, (u64, u64)> = std::collections::HashMap::new();
        loop {
            tick.tick().await;
            for b in self.buses().iter() {
                let _ = self.changes.send(Change::Bus(self.bus_view(b)));
                let Some(r) = b.role_status() else { continue };
                let (takeovers, yields) = seen.get(&b.config.name).copied().unwrap_or((0, 0));
                for (kind, new, what) in [
                    (
                        EventKind::Takeover,
                        r.takeovers.saturating_sub(takeovers),
                        "took the line over: the other gateway fell silent",
                    ),
                    (
                        EventKind::Yield,
                        r.yields.saturating_sub(yields),
                        "stopped sending: another gateway masters the line",
                    ),
                ] {
                    for _ in 0..new {
                        let mut e = Event::new(now_ms(), kind);
                        e.bus = Some(b.config.name.clone());
                        e.actor = Some("gateway".into());
                        e.result = Some(what.into());
                        e.detail = serde_json::json!({ "role": r.role.as_str() });
                        self.record_async(e).await;
                    }
                }
                seen.insert(b.config.name.clone(), (r.takeovers, r.yields));
            }
        }
    }
}

/// Tasks under way, each with its key (the scheduler's polls, keyed by drive): the key comes
/// back when its task ends, also when the task panicked or was cancelled, so a drive is never
/// left "being polled" for good.
struct InFlight<K> {
    tasks: tokio::task::JoinSet<()>,
    keys: HashMap<tokio::task::Id, K>,
}

impl<K> Default for InFlight<K> {
    fn default() -> Self {
        InFlight { tasks: tokio::task::JoinSet::new(), keys: HashMap::new() }
    }
}

impl<K> InFlight<K> {
    /// Runs `task` for `key`.
    fn start(&mut self, key: K, task: impl Future<Output = ()> + Send + 'static) {
        let id = self.tasks.spawn(task).id();
        self.keys.insert(id, key);
    }

    /// The tasks under way.
    fn len(&self) -> usize {
        self.keys.len()
    }

    /// Whether none is under way.
    fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }

    /// The keys of the tasks under way.
    fn keys(&self) -> impl Iterator<Item = &K> {
        self.keys.values()
    }

    /// The key of the next task to end, however it ended (`None` when none is under way).
    async fn next_done(&mut self) -> Option<K> {
        loop {
            let id = match self.tasks.join_next_with_id().await? {
                Ok((id, ())) => id,
                // A panic was told by the panic hook; the drive is polled again when due.
                Err(e) => e.id(),
            };
            if let Some(key) = self.keys.remove(&id) {
                return Some(key);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{next_due, poll_every, InFlight, Slot};
    use crate::config::PollPriority;
    use std::time::Duration;

    #[tokio::test]
    async fn a_task_that_panics_gives_its_key_back() {
        let mut polls: InFlight<&str> = InFlight::default();
        let (go, wait) = tokio::sync::oneshot::channel::<()>();
        polls.start("fan", async move {
            let _ = wait.await;
            panic!("a poll that fails badly");
        });
        polls.start("pump", std::future::pending());
        assert_eq!((polls.len(), polls.keys().any(|k| *k == "fan")), (2, true));
        go.send(()).unwrap();
        let back = tokio::time::timeout(std::time::Duration::from_secs(60), polls.next_done()).await;
        assert_eq!(back, Ok(Some("fan")));
        assert_eq!(polls.keys().collect::<Vec<_>>(), [&"pump"]);
        assert!(!polls.is_empty());
    }

    #[test]
    fn a_poll_held_up_by_listening_is_followed_an_interval_after_it_ended() {
        let t0 = tokio::time::Instant::now();
        let ms = Duration::from_millis;
        // Due at 0, held by the start-up listening until 520 ms: the next 500 ms after that.
        assert_eq!(next_due(t0, ms(500), true, t0 + ms(520)), t0 + ms(1020));
        // A standby's poll answered 5 ms after it was due, by the master's poll: the next 500 ms
        // after that poll was heard.
        assert_eq!(next_due(t0, ms(500), true, t0 + ms(5)), t0 + ms(505));
        // A master's poll that ended late (a slow reply, a busy line): the next at once.
        assert_eq!(next_due(t0, ms(500), false, t0 + ms(520)), t0 + ms(520));
        assert_eq!(next_due(t0, ms(500), false, t0 + ms(5)), t0 + ms(500));
    }

    #[test]
    fn a_commands_refresh_stands_for_the_drives_poll() {
        let t0 = tokio::time::Instant::now();
        let ms = Duration::from_millis;
        // Due at 500 ms, refreshed at 300 ms: the next poll an interval after the refresh.
        let mut s = Slot { due: t0 + ms(500), read: Some(t0) };
        s.refreshed(ms(500), t0 + ms(300));
        assert_eq!((s.due, s.read), (t0 + ms(800), Some(t0 + ms(300))));
        // A refresh never brings the next poll forward, nor makes the values look older.
        let mut s = Slot { due: t0 + ms(2000), read: Some(t0 + ms(900)) };
        s.refreshed(ms(500), t0 + ms(800));
        assert_eq!((s.due, s.read), (t0 + ms(2000), Some(t0 + ms(900))));
    }

    #[test]
    fn of_the_drives_due_the_one_read_longest_ago_goes_first() {
        let t0 = tokio::time::Instant::now();
        let ms = Duration::from_millis;
        let now = t0 + ms(2000);
        let normal = PollPriority::Normal;
        // On a full line every drive is overdue: whichever was due first, the oldest values go
        // first (a command's refresh read the first drive after the second's last poll).
        let refreshed = Slot { due: t0 + ms(100), read: Some(t0 + ms(1500)) };
        let polled = Slot { due: t0 + ms(900), read: Some(t0 + ms(1000)) };
        assert!(polled.urgency(normal, now) < refreshed.urgency(normal, now));
        // A drive never read goes first; one not due yet waits behind every drive due.
        let new = Slot::new(now);
        assert!(new.urgency(PollPriority::Low, now) < polled.urgency(PollPriority::High, now));
        let later = Slot { due: now + ms(1), read: Some(t0) };
        assert!(refreshed.urgency(PollPriority::Low, now) < later.urgency(PollPriority::High, now));
        // Of the drives not due, the one due first; on a tie, by priority.
        let sooner = Slot { due: now + ms(1), read: Some(t0 + ms(1900)) };
        let after = Slot { due: now + ms(2), read: Some(t0) };
        assert!(sooner.urgency(normal, now) < after.urgency(normal, now));
        assert!(later.urgency(PollPriority::High, now) < sooner.urgency(normal, now));
    }

    #[test]
    fn a_drive_is_polled_at_the_learnt_interval_never_slower_than_its_own() {
        let ms = Duration::from_millis;
        assert_eq!(poll_every(ms(1000), None), ms(1000), "nothing heard: its own poll_ms");
        assert_eq!(poll_every(ms(1000), Some(ms(200))), ms(200), "the master polled it faster");
        assert_eq!(poll_every(ms(1000), Some(ms(3000))), ms(1000), "never slower than poll_ms");
        assert_eq!(poll_every(ms(1000), Some(Duration::ZERO)), ms(1000));
    }
}
