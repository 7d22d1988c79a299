//! The bus owner: one task per half-duplex bus runs one transaction at a time, with the
//! protocol's timing (the minimum silence before a request, the response timeout, the
//! turnaround after a broadcast) kept by the protocol's `MasterSession`.
//!
//! Commands go ahead of polling (commands served first, then bridged requests). On-demand reads
//! share the rest with polling ([`crate::fair`]): one bounded queue per client, served in
//! turn, and at most a configured share of the bus time while polls wait. A scan's probes
//! ([`Priority::Scan`]) go only when nothing else waits. Each drive's link health
//! is tracked: after `offline_after` failed transactions in a row it is offline, and polls to it
//! are answered at once with [`BusError::Offline`] until its backoff has passed, when one probe
//! goes out (the backoff doubles up to `max_backoff` while it stays silent). So a dead drive
//! costs the others at most one timeout per backoff interval.

use std::collections::{HashMap, VecDeque};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use drivebus_drive::profile::Exchange;
use drivebus_proto::session::Protocol;
use drivebus_proto::Instant;
use tokio::sync::{mpsc, oneshot, watch};

pub use crate::bus::{BusConfig, BusError, BusStats, Health, Priority};
use crate::engine::{with_engine, Action, Attempt, Engine, Next};
use crate::fair::{OnDemand, Share, Turn};
use crate::learn::Learnt;
use crate::link::Link;
use crate::overheard::{Heard, Overheard};
use crate::role::{BusRole, Role, RoleStatus, Transition};

/// A standby's poll waits this long to hear what answers it from the master's traffic, then
/// fails with [`BusError::Standby`] (the master polls something else, or nothing).
const SHADOW_WAIT: Duration = Duration::from_secs(5);

/// A bus that shares its line hears it in slices this long while no job waits (a job ends a
/// slice at once).
const IDLE_SLICE: Duration = Duration::from_millis(100);

/// A transaction waiting for the bus: to which drive, what, its timeout, and where its result
/// goes.
pub(crate) struct Job {
    pub(crate) address: u8,
    pub(crate) exchange: Exchange,
    pub(crate) timeout: Option<Duration>,
    pub(crate) done: oneshot::Sender<Result<Option<Vec<u8>>, BusError>>,
}

/// The owner's ends of a bus's queues but the on-demand reads'.
pub(crate) struct Queues {
    pub(crate) commands: mpsc::UnboundedReceiver<Job>,
    pub(crate) bridged: mpsc::UnboundedReceiver<Job>,
    pub(crate) polls: mpsc::UnboundedReceiver<Job>,
    pub(crate) scans: mpsc::UnboundedReceiver<Job>,
}

/// A handle to a running bus owner; cheap to clone.
#[derive(Clone)]
pub struct Bus {
    commands: mpsc::UnboundedSender<Job>,
    bridged: mpsc::UnboundedSender<Job>,
    polls: mpsc::UnboundedSender<Job>,
    scans: mpsc::UnboundedSender<Job>,
    on_demand: Arc<OnDemand<Job>>,
    stats: Arc<Mutex<BusStats>>,
    health: Arc<Mutex<HashMap<u8, Health>>>,
    name: String,
    /// Closed (its sender dropped) when the owner task has ended and released the link.
    ended: watch::Receiver<()>,
    /// The bus's role, when it shares the line with another gateway.
    role: Arc<Mutex<Option<RoleStatus>>>,
    /// What the bus heard of another master's traffic.
    learnt: Arc<Mutex<Learnt>>,
}

impl Bus {
    /// Starts the owner task for `link` with `config` on the current tokio runtime.
    pub fn spawn<L: Link>(link: L, config: BusConfig) -> Result<Bus, BusError> {
        let (bus, queues, ended_tx) = Bus::handle(link.name(), &config);
        let (stats, health, name) = (bus.stats.clone(), bus.health.clone(), bus.name.clone());
        let share = Share::new(config.on_demand.share);
        let od = bus.on_demand.clone();
        let role_config = config.role;
        let heard_config = config.clone();
        let status = bus.role.clone();
        let learning = bus.learnt.clone();
        with_engine!(config, stats, health, |engine| {
            let mut engine = engine;
            if !link.is_open() {
                engine.link_lost(link.now(), format!("{name} is not open"));
            }
            let listening = role_config.map(|rc| {
                let seed = std::process::id() as u64
                    ^ std::time::SystemTime::now()
                        .duration_since(std::time::UNIX_EPOCH)
                        .map_or(0, |d| d.as_nanos() as u64);
                let role = BusRole::new(rc, link.now(), seed);
                *status.lock().unwrap_or_else(|p| p.into_inner()) = Some(role.status(None));
                let heard = Overheard::new(&heard_config, engine.response_timeout());
                Listening { role, heard, status, learnt: learning }
            });
            let owner = Owner {
                link,
                engine,
                rx_buf: Vec::new(),
                listening,
                parked: Vec::new(),
                released: VecDeque::new(),
                _ended: ended_tx,
            };
            let Queues { commands, bridged, polls, scans } = queues;
            tokio::spawn(owner.run(commands, bridged, polls, scans, od, share));
        });
        Ok(bus)
    }

    /// A bus's handle and its owner's ends (the queues, the sender whose drop says the owner
    /// ended), for either owner: the channels, statistics, health, on-demand reads, role and
    /// what is learnt from the line, made in one place.
    fn handle(name: String, config: &BusConfig) -> (Bus, Queues, watch::Sender<()>) {
        let (commands, crx) = mpsc::unbounded_channel();
        let (bridged, brx) = mpsc::unbounded_channel();
        let (polls, prx) = mpsc::unbounded_channel();
        let (scans, srx) = mpsc::unbounded_channel();
        let (ended_tx, ended) = watch::channel(());
        let bus = Bus {
            commands,
            bridged,
            polls,
            scans,
            on_demand: Arc::new(OnDemand::new(config.on_demand)),
            stats: Arc::new(Mutex::new(BusStats::default())),
            health: Arc::new(Mutex::new(HashMap::new())),
            name,
            ended,
            role: Arc::new(Mutex::new(None)),
            learnt: Arc::new(Mutex::new(Learnt::new(config.protocol))),
        };
        (bus, Queues { commands: crx, bridged: brx, polls: prx, scans: srx }, ended_tx)
    }

    /// Starts a pipelined owner for a Modbus TCP bus with `config.max_in_flight` requests in
    /// flight (`crate::pipelined`). `link` carries MBAP bytes as they are: a TCP link to the
    /// Modbus TCP server (`Port::Tcp`), not a `Port::ModbusTcp` link, which frames for one
    /// request at a time.
    pub fn spawn_pipelined<L: Link>(link: L, config: BusConfig) -> Result<Bus, BusError> {
        if !config.modbus_tcp || config.protocol != drivebus_proto::protocol::WireProtocol::ModbusRtu {
            return Err(BusError::BadRequest(crate::bus::IN_FLIGHT_NEEDS_MODBUS_TCP.to_string()));
        }
        // A pipelined bus masters its connection alone: no role, nothing heard, nothing learnt.
        let (bus, queues, ended_tx) = Bus::handle(link.name(), &config);
        let owner =
            crate::pipelined::Pipelined::new(link, config, bus.stats.clone(), bus.health.clone(), ended_tx);
        tokio::spawn(owner.run(queues, bus.on_demand.clone()));
        Ok(bus)
    }

    /// Drops this handle and waits until the owner task has ended and closed the link (the
    /// serial port free for another open). The owner ends once every clone of the handle is
    /// dropped, so drop the others (and the `Drive`s holding them) first.
    pub async fn close(self) {
        let Bus { commands, bridged, polls, scans, mut ended, .. } = self;
        drop(commands);
        drop(bridged);
        drop(polls);
        drop(scans);
        // Err once the owner has dropped its sender, that is ended.
        while ended.changed().await.is_ok() {}
    }

    /// The link's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Sends `exchange` to drive `address` and waits for the reply frame (`None` when no reply
    /// is due). `timeout` overrides the bus's response timeout for this drive. On-demand reads
    /// are queued as one anonymous client's: [`Bus::transact_for`] names the client.
    pub async fn transact(
        &self,
        address: u8,
        exchange: Exchange,
        priority: Priority,
        timeout: Option<Duration>,
    ) -> Result<Option<Vec<u8>>, BusError> {
        self.transact_for("", address, exchange, priority, timeout).await
    }

    /// [`Bus::transact`] on behalf of `client` (an address, a session): on-demand reads of
    /// different clients are served in turn, and one refused with [`BusError::Busy`] when the
    /// bus's queue or the client's own is full.
    pub async fn transact_for(
        &self,
        client: &str,
        address: u8,
        exchange: Exchange,
        priority: Priority,
        timeout: Option<Duration>,
    ) -> Result<Option<Vec<u8>>, BusError> {
        let (tx, rx) = oneshot::channel();
        let job = Job { address, exchange, timeout, done: tx };
        let queue = match priority {
            Priority::Command => &self.commands,
            Priority::Bridge => &self.bridged,
            Priority::Poll => &self.polls,
            Priority::Scan => &self.scans,
            Priority::OnDemand => {
                if self.commands.is_closed() {
                    return Err(BusError::Closed);
                }
                self.on_demand.push(client, job).map_err(|(_, e)| e)?;
                return rx.await.map_err(|_| BusError::Closed)?;
            }
        };
        queue.send(job).map_err(|_| BusError::Closed)?;
        rx.await.map_err(|_| BusError::Closed)?
    }

    /// The bus's counts so far.
    pub fn stats(&self) -> BusStats {
        self.stats.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// Each drive's link health.
    pub fn health(&self) -> HashMap<u8, Health> {
        self.health.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// The bus's role (master or standby) and its takeovers and yields, when it shares the
    /// line with another gateway (`BusConfig::role`); `None` for the only master.
    pub fn role(&self) -> Option<RoleStatus> {
        *self.role.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The interval at which another master on the line was heard polling each drive
    /// (by address); empty for the only master, or before anything was heard.
    pub fn learnt_schedule(&self) -> HashMap<u8, Duration> {
        self.learnt.lock().unwrap_or_else(|p| p.into_inner()).schedule()
    }

    /// The interval at which another master on the line was heard polling drive `address`.
    pub fn learnt_interval(&self, address: u8) -> Option<Duration> {
        self.learnt.lock().unwrap_or_else(|p| p.into_inner()).interval(address)
    }
}

/// The listening side of a bus that shares its line: its role and what it hears.
struct Listening {
    role: BusRole,
    heard: Overheard,
    status: Arc<Mutex<Option<RoleStatus>>>,
    learnt: Arc<Mutex<Learnt>>,
}

/// A standby's poll waiting to be answered from what it hears: by a reply made of what was heard
/// since `since`, by the master's request to its drive left unanswered, or, at `give_up`, by
/// [`BusError::Standby`].
struct Parked {
    job: Job,
    since: Instant,
    give_up: Instant,
}

/// What a standby's poll waits to hear: the answer to its request, made of what was heard since
/// it began, or that the master got no answer from its drive.
#[derive(Clone, Copy)]
struct Want<'a> {
    request: &'a [u8],
    address: u8,
    since: Instant,
}

impl Listening {
    fn publish(&self, last: Option<Transition>) {
        let mut s = self.status.lock().unwrap_or_else(|p| p.into_inner());
        let last = last.or(s.and_then(|s| s.last));
        *s = Some(self.role.status(last));
    }
}

struct Owner<L: Link, P: Protocol> {
    link: L,
    engine: Engine<P>,
    /// The read buffer, kept between exchanges.
    rx_buf: Vec<u8>,
    /// With another gateway on the line: the role and the listener.
    listening: Option<Listening>,
    /// A standby's polls waiting for what answers them, each apart: one whose drive the master
    /// has not polled lately holds up no other (see [`Owner::shadow`]).
    parked: Vec<Parked>,
    /// Polls parked while listening, sent as the bus's own once it has taken the line.
    released: VecDeque<Job>,
    /// Dropped after the link (fields drop in order): tells [`Bus::close`] the link is closed.
    _ended: watch::Sender<()>,
}

impl<L: Link, P: Protocol> Owner<L, P> {
    async fn run(
        mut self,
        mut commands: mpsc::UnboundedReceiver<Job>,
        mut bridged: mpsc::UnboundedReceiver<Job>,
        mut polls: mpsc::UnboundedReceiver<Job>,
        mut scans: mpsc::UnboundedReceiver<Job>,
        on_demand: Arc<OnDemand<Job>>,
        mut share: Share,
    ) {
        // A poll taken from its channel that waits for its turn.
        let mut poll: Option<Job> = None;
        loop {
            // Commands first, then bridged requests. Every handle holds all the senders: the
            // commands' closed means all are, and the owner ends.
            let first = match commands.try_recv() {
                Ok(j) => Some((j, Priority::Command)),
                Err(mpsc::error::TryRecvError::Disconnected) => return,
                Err(mpsc::error::TryRecvError::Empty) => {
                    bridged.try_recv().ok().map(|j| (j, Priority::Bridge))
                }
            };
            if let Some((job, priority)) = first {
                let result = self.run_job(&job, priority).await;
                let _ = job.done.send(result);
                continue;
            }
            // Polls that waited while listening, now the bus's own to send (parked again if it
            // has yielded meanwhile).
            if let Some(job) = self.released.pop_front() {
                if let Some(job) = self.shadow(job).await {
                    let result = self.run_job(&job, Priority::Poll).await;
                    let _ = job.done.send(result);
                }
                continue;
            }
            if poll.is_none() {
                poll = polls.try_recv().ok();
            }
            let waiting = !on_demand.is_empty();
            let turn = match (poll.is_some(), waiting) {
                (true, true) => share.turn(),
                (true, false) => Turn::Poll,
                (false, true) => Turn::OnDemand,
                (false, false) => {
                    // Nothing else waits: a scan's probe may go now.
                    if let Ok(job) = scans.try_recv() {
                        let result = self.run_job(&job, Priority::Scan).await;
                        let _ = job.done.send(result);
                        continue;
                    }
                    // Nothing waits: sleep until something comes. A bus that shares its line
                    // hears it meanwhile, so what it learns is timed as it came.
                    let listen = self.listening.is_some();
                    let woken = tokio::select! {
                        biased;
                        j = commands.recv() => match j {
                            Some(j) => Some((j, Priority::Command)),
                            None => return,
                        },
                        Some(j) = bridged.recv() => Some((j, Priority::Bridge)),
                        Some(j) = polls.recv() => {
                            poll = Some(j);
                            None
                        }
                        _ = on_demand.ready() => None,
                        Some(j) = scans.recv() => Some((j, Priority::Scan)),
                        _ = self.hear_while_idle(), if listen => None,
                    };
                    if let Some((job, priority)) = woken {
                        let result = self.run_job(&job, priority).await;
                        let _ = job.done.send(result);
                    }
                    continue;
                }
            };
            // Only bus time both kinds waited for counts toward the share.
            let contended = poll.is_some() && waiting;
            let (job, priority) = match turn {
                Turn::Poll => (poll.take(), Priority::Poll),
                Turn::OnDemand => (on_demand.pop(), Priority::OnDemand),
            };
            let Some(job) = job else { continue };
            let job = if priority == Priority::Poll {
                match self.shadow(job).await {
                    Some(job) => job,
                    None => continue,
                }
            } else {
                job
            };
            let started = self.link.now();
            let result = self.run_job(&job, priority).await;
            if contended {
                share.spent(turn, self.link.now() - started);
            }
            let _ = job.done.send(result);
        }
    }

    /// Runs `job` as the bus's role allows: the only master sends at once; a master that shares
    /// the line first hears what came since its last exchange (another master's request makes
    /// it yield) and waits out a pause after garbled traffic; a standby refuses commands and
    /// answers a poll from what it hears of the master's traffic ([`crate::learn`]), or with a
    /// timeout when the master's request to that drive went unanswered (offline after
    /// `offline_after` of them, as a polled drive), unless the line falls silent and it takes
    /// the line.
    async fn run_job(&mut self, job: &Job, priority: Priority) -> Result<Option<Vec<u8>>, BusError> {
        if self.listening.is_none() {
            return self.job(job, priority).await;
        }
        if !self.link.is_open() {
            // Listening needs the port open too (a master's first job would open it).
            match self.link.reopen().await {
                Ok(()) => self.engine.link_restored(),
                Err(e) if !self.listening.as_ref().is_some_and(|l| l.role.may_send()) => {
                    return Err(BusError::Link(format!("{}: {e}", self.link.name())));
                }
                Err(_) => {}
            }
        }
        let now = self.link.now();
        let _ = self.hear_until(now, None).await;
        // A standby's poll is answered by what the master's last poll of that drive saw, and
        // newer: heard since the poll began, or within the master's interval (at most the
        // silence) before.
        let since = self.listening.as_ref().map_or(now, |l| {
            let every = l.learnt.lock().unwrap_or_else(|p| p.into_inner()).interval(job.address);
            self.link.now() - every.unwrap_or(Duration::ZERO).min(l.role.silence())
        });
        // The wait counts from the poll's start, however often the role's timer wakes it.
        let give_up = self.link.now() + SHADOW_WAIT;
        while let Some(l) = self.listening.as_mut() {
            if l.role.may_send() {
                break;
            }
            let master = l.role.role() == crate::role::Role::Master;
            if !master && priority != Priority::Poll {
                return Err(BusError::Standby(self.link.name()));
            }
            let until = l.role.poll_timeout().map_or(give_up, |t| t.min(give_up));
            let want = (!master).then_some(Want {
                request: job.exchange.request.as_slice(),
                address: job.address,
                since,
            });
            if let Some(w) = want {
                // A drive the master gets no answer from is offline here too, as a polled one:
                // its polls are answered at once until a reply of it is heard again.
                if !self.engine.online(w.address) {
                    return Err(BusError::Offline { address: w.address });
                }
                // Perhaps heard already.
                if let Some(reply) =
                    l.learnt.lock().unwrap_or_else(|p| p.into_inner()).answer(w.request, w.since)
                {
                    return Ok(Some(reply));
                }
                // A set-up value never heard though the master's polls of the drive were: the
                // master does not read it; say so at once (a status is then read without it).
                let learnt = l.learnt.lock().unwrap_or_else(|p| p.into_inner());
                if learnt.master_skips_setup(w.address, w.request) {
                    return Err(BusError::Unheard(self.link.name()));
                }
            }
            if let Some(answer) = self.hear_until(until, want).await {
                return answer;
            }
            let now = self.link.now();
            if let Some(l) = self.listening.as_mut() {
                if let Some(t) = l.role.poll(now) {
                    l.publish(Some(t));
                }
                if !l.role.may_send() && !master && now >= give_up {
                    return Err(BusError::Standby(self.link.name()));
                }
            }
        }
        let result = self.job(job, priority).await;
        if matches!(result, Err(BusError::Corrupt { .. })) {
            // Damaged replies on a shared line: perhaps another master talking at once.
            let now = self.link.now();
            if let Some(l) = self.listening.as_mut() {
                l.role.heard_garbled(now);
                l.publish(None);
            }
        }
        result
    }

    /// A standby's poll, answered from what was heard (as [`Owner::run_job`] does) without
    /// holding up the others: when nothing heard answers it yet it is parked, and
    /// [`Owner::hear_until`] answers it when the master's exchange with its drive is heard, so
    /// each drive's values are taken as they come whatever order the master polls in. `None`
    /// when the poll is answered or parked; the job back when the bus is not listening as a
    /// standby (it then runs as any other).
    async fn shadow(&mut self, job: Job) -> Option<Job> {
        if !self.listening.as_ref().is_some_and(|l| l.role.role() == Role::Standby) {
            return Some(job);
        }
        if !self.link.is_open() {
            match self.link.reopen().await {
                Ok(()) => self.engine.link_restored(),
                Err(e) => {
                    let _ = job.done.send(Err(BusError::Link(format!("{}: {e}", self.link.name()))));
                    return None;
                }
            }
        }
        let now = self.link.now();
        let _ = self.hear_until(now, None).await;
        let l = self.listening.as_ref()?;
        if l.role.role() != Role::Standby {
            return Some(job);
        }
        // A drive the master gets no answer from is offline here too, as a polled one: its polls
        // are answered at once until a reply of it is heard again.
        if !self.engine.online(job.address) {
            let _ = job.done.send(Err(BusError::Offline { address: job.address }));
            return None;
        }
        // Answered by what the master's last poll of that drive saw, and newer: heard within the
        // master's interval (at most the silence) before, or from now on.
        let learnt = l.learnt.lock().unwrap_or_else(|p| p.into_inner());
        let every = learnt.interval(job.address).unwrap_or(Duration::ZERO).min(l.role.silence());
        let since = now - every;
        if let Some(reply) = learnt.answer(&job.exchange.request, since) {
            drop(learnt);
            let _ = job.done.send(Ok(Some(reply)));
            return None;
        }
        // A set-up value never heard though the master's polls of the drive were: the master
        // does not read it; say so at once (a status is then read without it) rather than park
        // it until it gives up.
        if learnt.master_skips_setup(job.address, &job.exchange.request) {
            drop(learnt);
            let _ = job.done.send(Err(BusError::Unheard(self.link.name())));
            return None;
        }
        drop(learnt);
        self.parked.push(Parked { job, since, give_up: now + SHADOW_WAIT });
        None
    }

    /// Hears the line for a moment ([`IDLE_SLICE`]) while no job waits.
    async fn hear_while_idle(&mut self) {
        if !self.link.is_open() {
            if self.link.reopen().await.is_err() {
                // Tried again after a while (a master's next job reopens it too).
                tokio::time::sleep(IDLE_SLICE).await;
                return;
            }
            self.engine.link_restored();
        }
        let mut until = self.link.now() + IDLE_SLICE;
        // Parked polls end the slice when one gives up or the line is to be taken.
        if let Some(l) = self.listening.as_ref().filter(|_| !self.parked.is_empty()) {
            until = l.role.poll_timeout().map_or(until, |t| t.min(until));
            until = self.parked.iter().map(|p| p.give_up).fold(until, Instant::min);
        }
        let _ = self.hear_until(until, None).await;
    }

    /// Reads what the line carries until `deadline` (at least what has already come), telling
    /// the role what it heard and learning from it: values, the master's schedule, each drive's
    /// health (answered or not, as if polled). With `want`, returns as soon as it is answered:
    /// the reply, or a timeout when the master's request to that drive went unanswered.
    async fn hear_until(
        &mut self,
        deadline: Instant,
        want: Option<Want<'_>>,
    ) -> Option<Result<Option<Vec<u8>>, BusError>> {
        let mut buf = std::mem::take(&mut self.rx_buf);
        buf.resize(1024, 0);
        let mut heard = Vec::new();
        let mut sleep = crate::timer::sleep_until(self.link.clock().tokio(deadline));
        let mut answer = None;
        loop {
            let read = tokio::select! {
                biased;
                r = self.link.read(&mut buf) => match r {
                    Ok(n) => Some(n),
                    Err(_) => {
                        // The port failed: nothing more is heard before the deadline.
                        (&mut sleep).await;
                        None
                    }
                },
                _ = &mut sleep => None,
            };
            let now = self.link.now();
            let Some(l) = self.listening.as_mut() else { break };
            heard.clear();
            match read {
                Some(n) => l.heard.push(now, &buf[..n], &mut heard),
                // The deadline: a reply now overdue, a frame ended by the quiet, are heard too.
                None => l.heard.tick(now, &mut heard),
            }
            let mut learnt = l.learnt.lock().unwrap_or_else(|p| p.into_inner());
            let mut replied = false;
            let mut unanswered: Vec<u8> = Vec::new();
            for h in heard.drain(..) {
                match h {
                    Heard::Request { address, bytes } => {
                        if let Some(t) = l.role.heard_request(now) {
                            l.publish(Some(t));
                        }
                        learnt.request(now, address, &bytes);
                    }
                    Heard::Reply { address, request, reply } => {
                        learnt.reply(now, &request, &reply);
                        if let Some(a) = address {
                            self.engine.record(now, a, true);
                        }
                        replied = true;
                    }
                    Heard::NoReply { address: Some(a) } => {
                        self.engine.record(now, a, false);
                        unanswered.push(a);
                        if want.is_some_and(|w| w.address == a) {
                            answer = Some(Err(BusError::Timeout {
                                link: self.link.name(),
                                address: a,
                                attempts: 1,
                            }));
                        }
                    }
                    Heard::NoReply { address: None } => {}
                    Heard::Garbled => l.role.heard_garbled(now),
                }
            }
            if let Some(w) = want.filter(|_| replied && answer.is_none()) {
                answer = learnt.answer(w.request, w.since).map(|r| Ok(Some(r)));
            }
            // The parked polls this answers, or that wait no longer.
            let mut k = 0;
            while k < self.parked.len() {
                let p = &self.parked[k];
                let address = p.job.address;
                let result = if unanswered.contains(&address) {
                    Some(Err(BusError::Timeout { link: self.link.name(), address, attempts: 1 }))
                } else if replied {
                    learnt.answer(&p.job.exchange.request, p.since).map(|r| Ok(Some(r))).or_else(|| {
                        // A set-up value the master's polls of the drive, now heard, did not read.
                        learnt
                            .master_skips_setup(address, &p.job.exchange.request)
                            .then(|| Err(BusError::Unheard(self.link.name())))
                    })
                } else {
                    None
                };
                match result.or_else(|| (now >= p.give_up).then(|| Err(BusError::Standby(self.link.name()))))
                {
                    Some(r) => {
                        let _ = self.parked.remove(k).job.done.send(r);
                    }
                    None => k += 1,
                }
            }
            drop(learnt);
            // The line falls silent while polls wait: it is taken, and they go out as its own.
            if !self.parked.is_empty() {
                if let Some(t) = l.role.poll(now) {
                    l.publish(Some(t));
                }
                if l.role.may_send() {
                    self.released.extend(self.parked.drain(..).map(|p| p.job));
                }
            }
            l.publish(None);
            if answer.is_some() || read.is_none() {
                break;
            }
        }
        self.rx_buf = buf;
        answer
    }

    /// Carries out what the engine decides for `job`.
    async fn job(&mut self, job: &Job, priority: Priority) -> Result<Option<Vec<u8>>, BusError> {
        let ex = &job.exchange;
        let now = self.link.now();
        let mut next = self.engine.begin(
            now,
            self.link.name(),
            job.address,
            &ex.request,
            ex.expect_reply,
            priority,
            job.timeout,
        );
        loop {
            next = match next {
                Next::Attempt => {
                    let attempt = self.attempt().await;
                    self.engine.attempted(self.link.now(), attempt)
                }
                Next::Reopen => {
                    let reopened = self.link.reopen().await;
                    self.engine.reopened(self.link.now(), reopened)
                }
                Next::Done(result) => return result,
            }
        }
    }

    async fn attempt(&mut self) -> Attempt {
        let mut buf = std::mem::take(&mut self.rx_buf);
        buf.resize(1024, 0);
        let result = self.exchange(&mut buf).await;
        self.rx_buf = buf;
        result
    }

    async fn exchange(&mut self, buf: &mut [u8]) -> Attempt {
        // One timer for the whole exchange, moved when the session's deadline moves.
        let mut armed: Option<Instant> = None;
        // Session deadlines (the gap before a request, the response timeout) to the microsecond:
        // tokio's own timer would end each on the next whole millisecond.
        let mut sleep = crate::timer::sleep_until(tokio::time::Instant::now() + Duration::from_secs(3600));
        loop {
            let deadline = match self.engine.poll(self.link.now()) {
                Action::Transmit => {
                    let at = self.link.now();
                    if let Err(e) = self.link.write(self.engine.outgoing()).await {
                        return Attempt::Link(format!("{}: {e}", self.link.name()));
                    }
                    self.engine.sent(at);
                    continue;
                }
                Action::Done(attempt) => return attempt,
                Action::Wait(deadline) => deadline,
            };
            if armed != Some(deadline) {
                sleep.reset(self.link.clock().tokio(deadline));
                armed = Some(deadline);
            }
            tokio::select! {
                r = self.link.read(buf) => match r {
                    Ok(n) => self.engine.input(self.link.now(), &buf[..n]),
                    Err(e) => return Attempt::Link(format!("{}: {e}", self.link.name())),
                },
                _ = &mut sleep => {
                    armed = None;
                    self.engine.timeout(self.link.now());
                }
            }
        }
    }
}
