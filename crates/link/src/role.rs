//! A bus's role when more than one gateway sits on the line: master (it polls) or listening (it
//! only hears), and the moves between them, without I/O and with time as an argument.
//!
//! The rules (issue 27, `[standby]`):
//! - At start every gateway listens before it sends: `silence` for an active one, twice that
//!   (plus a random jitter of up to half of `silence`) for a standby, so at a common start the
//!   active one takes the line.
//! - A listening gateway that hears no master request for `silence` (plus a fresh random jitter
//!   of up to half of it, so two listeners do not take over at the same instant) becomes the
//!   master: a takeover when another master had been heard.
//! - A master that hears a request it did not send yields: it stops sending and listens again,
//!   under the same rule. Two masters on one line therefore do not stay two.
//! - Two masters that talk at once garble each other, and neither hears the other's request: a
//!   master that hears garbled traffic pauses for a random time of up to half the silence
//!   before it sends again. The one that pauses less sends first, whole, and the other hears it
//!   and yields; on a noisy line with one master the pause is all it costs.
//!
//! The caller says what it heard ([`BusRole::heard_request`]: a whole, valid master request
//! that is not its own and not a drive acting as bus master; [`BusRole::heard_garbled`]: bytes
//! that make no valid frame, or bytes while it was sending), asks [`BusRole::poll`] at
//! [`BusRole::poll_timeout`], and sends only while [`BusRole::may_send`].

use std::time::Duration;

use drivebus_proto::Instant;

/// How a bus's role is set up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RoleConfig {
    /// A standby listens first, and longer at start.
    pub standby: bool,
    /// How long the line must carry no master request before a listener takes it.
    pub silence: Duration,
}

impl RoleConfig {
    /// The default silence before a takeover (`[standby] silence_ms`).
    pub const DEFAULT_SILENCE: Duration = Duration::from_millis(500);
}

/// What the bus does, as `/api/buses` names it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// It polls the drives.
    Master,
    /// It only listens.
    Standby,
}

impl Role {
    /// `master` or `standby`.
    pub fn as_str(self) -> &'static str {
        match self {
            Role::Master => "master",
            Role::Standby => "standby",
        }
    }
}

/// Why a bus listens.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Listening {
    /// The gateway has just started (as the active one).
    Starting,
    /// It is a standby, or has been listening to another master.
    Standby,
    /// It was master and heard another master's request.
    Yielded,
}

/// The state of one bus's role.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum State {
    /// Sends nothing; becomes master at `until` unless a master request is heard before.
    Listening {
        /// Why.
        why: Listening,
        /// When it takes the line if the line stays silent.
        until: Instant,
    },
    /// Polls the drives, since `since`.
    Master {
        /// When it became master.
        since: Instant,
        /// After garbled traffic: sends nothing before this time.
        paused_until: Option<Instant>,
    },
}

/// A move between roles, for the log, the audit and the counters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Transition {
    /// Became master at `at`. `takeover`: another master had been heard before (a standby
    /// taking over, or a yielded master taking the line back), not a gateway's first start.
    TookLine {
        /// When.
        at: Instant,
        /// How long the line had carried no master request (since the start when none was
        /// ever heard).
        silent_for: Duration,
        /// True when another master had been heard on this line before.
        takeover: bool,
    },
    /// Heard another master's request while master, at `at`: stopped sending.
    Yielded {
        /// When.
        at: Instant,
    },
}

/// What a bus's role is, for the API, metrics and events.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RoleStatus {
    /// Master or standby now.
    pub role: Role,
    /// Takeovers so far.
    pub takeovers: u64,
    /// Yields so far.
    pub yields: u64,
    /// The last move, if any.
    pub last: Option<Transition>,
}

/// One bus's role and its counters.
#[derive(Clone, Debug)]
pub struct BusRole {
    config: RoleConfig,
    state: State,
    started: Instant,
    last_request: Option<Instant>,
    rng: u64,
    takeovers: u64,
    yields: u64,
}

impl BusRole {
    /// A bus starting at `now`: listening first (see the module's rules). `seed` feeds the
    /// jitter (give each gateway its own: its process id and the time, say).
    pub fn new(config: RoleConfig, now: Instant, seed: u64) -> BusRole {
        let mut r = BusRole {
            config,
            state: State::Master { since: now, paused_until: None },
            started: now,
            last_request: None,
            // xorshift64 has no zero state.
            rng: seed | 1,
            takeovers: 0,
            yields: 0,
        };
        r.state = if config.standby {
            State::Listening { why: Listening::Standby, until: now + config.silence * 2 + r.jitter() }
        } else {
            State::Listening { why: Listening::Starting, until: now + config.silence }
        };
        r
    }

    /// The state now.
    pub fn state(&self) -> State {
        self.state
    }

    /// How long the line must carry no master request before a listener takes it.
    pub fn silence(&self) -> Duration {
        self.config.silence
    }

    /// Master or standby.
    pub fn role(&self) -> Role {
        match self.state {
            State::Master { .. } => Role::Master,
            State::Listening { .. } => Role::Standby,
        }
    }

    /// True while the bus may send requests (master, and not pausing after garbled traffic).
    pub fn may_send(&self) -> bool {
        matches!(self.state, State::Master { paused_until: None, .. })
    }

    /// The role and counters, with the last move `last`.
    pub fn status(&self, last: Option<Transition>) -> RoleStatus {
        RoleStatus { role: self.role(), takeovers: self.takeovers, yields: self.yields, last }
    }

    /// How many times this bus took the line over from another master.
    pub fn takeovers(&self) -> u64 {
        self.takeovers
    }

    /// How many times this bus yielded to another master.
    pub fn yields(&self) -> u64 {
        self.yields
    }

    /// When [`BusRole::poll`] has something to do, if ever (without a request heard).
    pub fn poll_timeout(&self) -> Option<Instant> {
        match self.state {
            State::Listening { until, .. } => Some(until),
            State::Master { paused_until, .. } => paused_until,
        }
    }

    /// Garbled traffic (bytes that make no valid frame, or bytes heard while sending) at `now`:
    /// a master pauses for a random time of up to half the silence; a listener counts it as a
    /// master talking.
    pub fn heard_garbled(&mut self, now: Instant) {
        match self.state {
            State::Master { since, paused_until } => {
                let until = now + self.jitter();
                self.state =
                    State::Master { since, paused_until: Some(paused_until.map_or(until, |p| p.max(until))) };
            }
            State::Listening { .. } => {
                // Not a request: it does not make a later takeover a "takeover".
                let until = now + self.config.silence + self.jitter();
                if let State::Listening { why, until: old } = self.state {
                    let why = if why == Listening::Starting { Listening::Standby } else { why };
                    self.state = State::Listening { why, until: old.max(until) };
                }
            }
        }
    }

    /// Another master's request was heard at `now`: a listener waits for the line to fall
    /// silent again; a master yields.
    pub fn heard_request(&mut self, now: Instant) -> Option<Transition> {
        self.last_request = Some(self.last_request.map_or(now, |l| l.max(now)));
        let until = now + self.config.silence + self.jitter();
        match self.state {
            State::Listening { why, until: old } => {
                let why = if why == Listening::Starting { Listening::Standby } else { why };
                self.state = State::Listening { why, until: old.max(until) };
                None
            }
            State::Master { .. } => {
                self.yields += 1;
                self.state = State::Listening { why: Listening::Yielded, until };
                Some(Transition::Yielded { at: now })
            }
        }
    }

    /// Time passes: a listener whose silence ran out takes the line; a master's pause ends.
    pub fn poll(&mut self, now: Instant) -> Option<Transition> {
        if let State::Master { since, paused_until: Some(p) } = self.state {
            if now >= p {
                self.state = State::Master { since, paused_until: None };
            }
            return None;
        }
        let State::Listening { until, .. } = self.state else { return None };
        if now < until {
            return None;
        }
        let takeover = self.last_request.is_some();
        if takeover {
            self.takeovers += 1;
        }
        self.state = State::Master { since: now, paused_until: None };
        let silent_since = self.last_request.unwrap_or(self.started);
        Some(Transition::TookLine { at: now, silent_for: now.saturating_since(silent_since), takeover })
    }

    /// A random wait of up to half the silence.
    fn jitter(&mut self) -> Duration {
        let mut x = self.rng;
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        self.rng = x;
        let half = self.config.silence.as_nanos() as u64 / 2;
        Duration::from_nanos(if half == 0 { 0 } else { x % (half + 1) })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(n: u64) -> Instant {
        Instant::from_millis(n)
    }

    const SILENCE: Duration = Duration::from_millis(500);

    fn active(seed: u64) -> BusRole {
        BusRole::new(RoleConfig { standby: false, silence: SILENCE }, ms(0), seed)
    }

    fn standby(seed: u64) -> BusRole {
        BusRole::new(RoleConfig { standby: true, silence: SILENCE }, ms(0), seed)
    }

    #[test]
    fn an_active_gateway_listens_its_silence_then_takes_the_line() {
        let mut r = active(7);
        assert_eq!(r.state(), State::Listening { why: Listening::Starting, until: ms(500) });
        assert!(!r.may_send());
        assert_eq!(r.poll(ms(499)), None);
        assert_eq!(
            r.poll(ms(500)),
            Some(Transition::TookLine { at: ms(500), silent_for: SILENCE, takeover: false })
        );
        assert!(r.may_send());
        assert_eq!(r.role().as_str(), "master");
        assert_eq!((r.takeovers(), r.yields(), r.poll_timeout()), (0, 0, None));
    }

    #[test]
    fn a_standby_listens_twice_the_silence_plus_a_jitter_of_at_most_half() {
        for seed in 0..200 {
            let r = standby(seed);
            let Some(until) = r.poll_timeout() else { panic!("listening") };
            assert!(until >= ms(1000) && until <= ms(1250), "seed {seed}: {until:?}");
            assert_eq!(r.role(), Role::Standby);
        }
        // The jitter differs from seed to seed.
        let times: std::collections::BTreeSet<_> = (0..50).map(|s| standby(s).poll_timeout()).collect();
        assert!(times.len() > 10, "{times:?}");
    }

    #[test]
    fn requests_heard_keep_a_listener_listening_and_silence_hands_it_the_line() {
        let mut r = standby(3);
        // A master polling every 100 ms for 10 s.
        for t in (0..10_000).step_by(100) {
            assert_eq!(r.poll(ms(t)), None, "at {t} ms");
            assert_eq!(r.heard_request(ms(t)), None);
        }
        // The master falls silent after its request at 9900 ms: the standby takes over after
        // 500 ms plus its jitter, at most 750 ms.
        let until = r.poll_timeout().unwrap();
        assert!(until >= ms(10_400) && until <= ms(10_650), "{until:?}");
        assert_eq!(r.poll(until - Duration::from_nanos(1)), None);
        match r.poll(until) {
            Some(Transition::TookLine { at, silent_for, takeover: true }) => {
                assert_eq!(at, until);
                assert_eq!(silent_for, until.saturating_since(ms(9900)));
            }
            other => panic!("{other:?}"),
        }
        assert_eq!((r.takeovers(), r.yields()), (1, 0));
    }

    #[test]
    fn an_active_gateway_that_hears_a_master_at_start_stays_listening() {
        // The old master restarted while the other polls: it never takes the line.
        let mut r = active(11);
        for t in (0..5000).step_by(150) {
            r.heard_request(ms(t));
            assert_eq!(r.poll(ms(t + 1)), None, "at {t} ms");
        }
        assert_eq!(r.state(), State::Listening { why: Listening::Standby, until: r.poll_timeout().unwrap() });
    }

    #[test]
    fn a_master_that_hears_another_yields_and_listens_again() {
        let mut r = active(5);
        r.poll(ms(500));
        assert!(r.may_send());
        assert_eq!(r.heard_request(ms(800)), Some(Transition::Yielded { at: ms(800) }));
        assert!(!r.may_send());
        let Some(until) = r.poll_timeout() else { panic!("listening") };
        assert!(until >= ms(1300) && until <= ms(1550), "{until:?}");
        assert!(matches!(r.state(), State::Listening { why: Listening::Yielded, .. }));
        // Silence again: it takes the line back, a takeover (another master had been heard).
        assert!(matches!(r.poll(until), Some(Transition::TookLine { takeover: true, .. })));
        assert_eq!((r.takeovers(), r.yields()), (1, 1));
    }

    /// Two gateways on one line, on simulated time: each polls every `period` while master, a
    /// request occupying the line for `frame`; a request is heard by the other when it ends,
    /// unless the two overlapped (both garbled, neither heard). `kill`: the first stops at that
    /// time, and restarts (as the active one) at `restart`. Returns, per millisecond from
    /// `check_from`, who was master, the times the second took over, and the collisions.
    struct Pair {
        roles: [BusRole; 2],
        alive: [bool; 2],
        next_send: [Option<Instant>; 2],
        /// Requests on the line: (sender, start, end).
        wire: Vec<(usize, Instant, Instant)>,
        collisions: u64,
        /// Collisions from each time on (for "none after 3 s").
        collision_times: Vec<Instant>,
    }

    const PERIOD: Duration = Duration::from_millis(40);
    const FRAME: Duration = Duration::from_millis(8);

    impl Pair {
        fn new(a: BusRole, b: BusRole) -> Pair {
            Pair {
                roles: [a, b],
                alive: [true, true],
                next_send: [None, None],
                wire: Vec::new(),
                collisions: 0,
                collision_times: Vec::new(),
            }
        }

        /// One millisecond step at `now`.
        fn step(&mut self, now: Instant) {
            // Requests that ended now are heard by the other, if not garbled.
            let ended: Vec<(usize, Instant, Instant)> =
                self.wire.iter().copied().filter(|w| w.2 == now).collect();
            for (who, start, end) in ended {
                let garbled = self.wire.iter().any(|o| o.0 != who && o.1 < end && start < o.2);
                let other = 1 - who;
                if self.alive[other] {
                    if garbled {
                        self.roles[other].heard_garbled(now);
                    } else {
                        self.roles[other].heard_request(now);
                    }
                }
            }
            self.wire.retain(|w| w.2 > now);
            for i in 0..2 {
                if !self.alive[i] {
                    continue;
                }
                self.roles[i].poll(now);
                if !self.roles[i].may_send() {
                    self.next_send[i] = None;
                    continue;
                }
                let due = *self.next_send[i].get_or_insert(now);
                if now >= due {
                    let end = now + FRAME;
                    if self.wire.iter().any(|o| o.0 != i && o.1 < end && now < o.2) {
                        self.collisions += 1;
                        self.collision_times.push(now);
                    }
                    // A sender hears the other's bytes arrive over its own.
                    if self.wire.iter().any(|o| o.0 != i && o.2 > now) {
                        self.roles[i].heard_garbled(now);
                    }
                    self.wire.push((i, now, end));
                    self.next_send[i] = Some(now + PERIOD);
                }
            }
        }

        fn masters(&self) -> Vec<usize> {
            (0..2).filter(|&i| self.alive[i] && self.roles[i].may_send()).collect()
        }
    }

    #[test]
    fn started_together_the_active_one_masters_and_a_kill_hands_over_within_the_budget() {
        let mut takeovers = Vec::new();
        for seed in 0..20u64 {
            let mut p = Pair::new(active(seed * 2 + 1), standby(seed * 2 + 2));
            let (kill, restart) = (ms(5000), ms(8000));
            let mut took = None;
            for t in 0..12_000u64 {
                let now = ms(t);
                if now == kill {
                    p.alive[0] = false;
                }
                if now == restart {
                    p.alive[0] = true;
                    p.roles[0] =
                        BusRole::new(RoleConfig { standby: false, silence: SILENCE }, now, seed + 99);
                }
                p.step(now);
                if (3000..5000).contains(&t) {
                    assert_eq!(p.masters(), [0], "seed {seed} at {t} ms: the active one masters");
                }
                if took.is_none() && now > kill && p.roles[1].may_send() {
                    took = Some(now.saturating_since(kill));
                }
                if t >= 8000 {
                    assert_eq!(p.masters(), [1], "seed {seed} at {t} ms: the restarted one stays standby");
                }
            }
            let took = took.expect("the standby took over");
            // Its last request heard was at most a period before the kill; 500 ms + jitter up to
            // 250 ms after it.
            assert!(took <= Duration::from_millis(750), "seed {seed}: {took:?}");
            assert_eq!(p.collisions, 0, "seed {seed}");
            takeovers.push(took);
        }
        assert!(takeovers.iter().any(|t| *t != takeovers[0]), "the jitter varies: {takeovers:?}");
    }

    #[test]
    fn two_active_gateways_started_together_end_with_one_master_and_no_collision() {
        for seed in 0..50u64 {
            let mut p = Pair::new(active(seed * 2 + 1), active(seed * 2 + 2));
            for t in 0..6000u64 {
                p.step(ms(t));
                if t >= 3000 {
                    assert_eq!(p.masters().len(), 1, "seed {seed} at {t} ms: {:?}", p.masters());
                }
            }
            assert!(p.collision_times.iter().all(|c| *c < ms(3000)), "seed {seed}: {:?}", p.collision_times);
        }
    }
}
