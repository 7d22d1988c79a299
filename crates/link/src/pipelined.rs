//! The bus owner of a Modbus TCP bus with `max_in_flight` above 1: up to that many requests
//! pipelined on one connection, each answer matched to its request by transaction id and unit
//! ([`MbapTransactions`]) in whatever order it comes (a Modbus TCP/RTU gateway with several
//! serial lines answers the faster line first).
//!
//! Each request in flight runs on an engine of its own (a slot): its timeout, retries, reply
//! check, statistics and the drive's health are the engine's, as on a bus with one request at a
//! time. What the slots share is kept here: the connection, the jobs' order and the link's state.
//!
//! - Order: one request per drive (unit id) in flight, and a job waits while an earlier job to
//!   the same drive waits, so one drive's commands run in the order they came; pipelining is
//!   across drives. Commands go ahead of bridged requests, then polls and on-demand reads share
//!   the rest as on a half-duplex bus ([`crate::fair`]), scans when nothing else waits. A
//!   broadcast goes alone, once nothing is in flight.
//! - An answer to no request in flight (a stray transaction id, a second answer, one timed out)
//!   is counted ([`BusStats::stray_replies`]) and dropped.
//! - A lost connection fails the attempt of every request in flight; each is retried once the
//!   connection is opened again (once per job, as the engine decides), and a connection that will
//!   not open is tried again after the bus's backoff ([`Backoff`]), jobs before then failing at
//!   once with its error.
//!
//! The link carries MBAP bytes as they are (a TCP link to the Modbus TCP server, not
//! [`crate::mbap::MbapFraming`]'s RTU view).

use std::collections::VecDeque;
use std::io;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use drivebus_proto::modbus::rtu::ModbusRtu;
use drivebus_proto::Instant;
use tokio::sync::{mpsc, watch};

use crate::backoff::Backoff;
use crate::bus::{BusConfig, BusError, BusStats, Priority};
use crate::engine::{timing_of, Action, Attempt, Engine, Next};
use crate::fair::{OnDemand, Share, Turn};
use crate::link::Link;
use crate::mbap::MbapTransactions;
use crate::owner::{Job, Queues};

/// How urgent a job of `priority` is: lower goes first.
fn rank(priority: Priority) -> u8 {
    match priority {
        Priority::Command => 0,
        Priority::Bridge => 1,
        Priority::OnDemand | Priority::Poll => 2,
        Priority::Scan => 3,
    }
}

/// A job running on a slot.
struct Running {
    job: Job,
    /// When it began, and the turn it took over a waiting poll or on-demand read (its time
    /// counts toward the fair share).
    started: Instant,
    contended: Option<Turn>,
}

/// One request in flight: its engine and the job it runs.
struct Slot {
    engine: Engine<ModbusRtu>,
    running: Option<Running>,
    /// The transaction id of its attempt on the connection.
    transaction: Option<u16>,
    /// When its attempt times out (or a broadcast's turnaround ends).
    deadline: Option<Instant>,
    /// The connection was lost under its attempt: why (carried out by the main loop).
    lost: Option<String>,
}

impl Slot {
    fn address(&self) -> Option<u8> {
        self.running.as_ref().map(|r| r.job.address)
    }
}

/// The pipelined owner of one Modbus TCP connection.
pub(crate) struct Pipelined<L: Link> {
    link: L,
    slots: Vec<Slot>,
    transactions: MbapTransactions,
    /// Whether the connection is open.
    up: bool,
    /// While it will not open: the last error, and when the next open is due.
    down: Option<(String, Instant)>,
    backoff: Backoff,
    /// Jobs taken from their queues that wait for their drive's request in flight, in order.
    held: VecDeque<(Job, Priority)>,
    /// A poll taken from its queue that waits for its turn.
    poll: Option<Job>,
    share: Share,
    stats: Arc<Mutex<BusStats>>,
    /// Dropped after the link: tells [`crate::Bus::close`] the link is closed.
    _ended: watch::Sender<()>,
}

impl<L: Link> Pipelined<L> {
    /// An owner of `link` (not read or written yet) with `config.max_in_flight` slots.
    pub(crate) fn new(
        link: L,
        config: BusConfig,
        stats: Arc<Mutex<BusStats>>,
        health: Arc<Mutex<std::collections::HashMap<u8, crate::bus::Health>>>,
        ended: watch::Sender<()>,
    ) -> Self {
        let timing = timing_of(&config);
        let slots = (0..config.max_in_flight.max(1))
            .map(|_| Slot {
                engine: Engine::new(ModbusRtu, timing, config.clone(), stats.clone(), health.clone()),
                running: None,
                transaction: None,
                deadline: None,
                lost: None,
            })
            .collect();
        let up = link.is_open();
        Pipelined {
            link,
            slots,
            transactions: MbapTransactions::new(),
            up,
            down: None,
            backoff: Backoff::new(),
            held: VecDeque::new(),
            poll: None,
            share: Share::new(config.on_demand.share),
            stats,
            _ended: ended,
        }
    }

    /// Serves the queues until every handle of the bus is dropped.
    pub(crate) async fn run(mut self, mut q: Queues, on_demand: Arc<OnDemand<Job>>) {
        let mut buf = vec![0u8; 2048];
        let mut sleep = crate::timer::sleep_until(tokio::time::Instant::now() + Duration::from_secs(3600));
        let mut armed: Option<Instant> = None;
        loop {
            // Attempts the lost connection ended.
            for i in 0..self.slots.len() {
                if let Some(error) = self.slots[i].lost.take() {
                    let now = self.link.now();
                    let next = self.slots[i].engine.attempted(now, Attempt::Link(error));
                    if self.settle(i, next).await {
                        self.carry_on(i).await;
                    }
                }
            }
            if self.slots.iter().any(|s| s.lost.is_some()) {
                continue;
            }
            // Start jobs while a slot is free.
            while let Some(i) = self.slots.iter().position(|s| s.running.is_none()) {
                match self.next_job(&mut q, &on_demand) {
                    Ok(Some((job, priority, contended))) => self.start(i, job, priority, contended).await,
                    Ok(None) => break,
                    Err(()) => return,
                }
            }
            if self.slots.iter().any(|s| s.lost.is_some()) {
                continue;
            }
            let deadline = self.slots.iter().filter_map(|s| s.deadline).min();
            if let Some(d) = deadline {
                if armed != Some(d) {
                    sleep.reset(self.link.clock().tokio(d));
                    armed = Some(d);
                }
            }
            // New jobs are taken only when one could start.
            let free = self.slots.iter().any(|s| s.running.is_none()) && !self.broadcasting();
            let up = self.up;
            tokio::select! {
                biased;
                r = self.link.read(&mut buf), if up => match r {
                    Ok(n) => self.answers(&buf[..n]).await,
                    Err(e) => self.lose(format!("{}: {e}", self.link.name()), None),
                },
                _ = &mut sleep, if deadline.is_some() => {
                    armed = None;
                    self.expire().await;
                }
                j = q.commands.recv(), if free => match j {
                    Some(j) => self.held.push_back((j, Priority::Command)),
                    None => return,
                },
                Some(j) = q.bridged.recv(), if free => self.held.push_back((j, Priority::Bridge)),
                Some(j) = q.polls.recv(), if free && self.poll.is_none() => self.poll = Some(j),
                _ = on_demand.ready(), if free => {}
                Some(j) = q.scans.recv(), if free => self.held.push_back((j, Priority::Scan)),
            }
        }
    }

    /// Whether a broadcast is in flight (nothing else goes with it).
    fn broadcasting(&self) -> bool {
        self.slots.iter().any(|s| s.running.as_ref().is_some_and(|r| !r.job.exchange.expect_reply))
    }

    /// Whether `job` may start now: nothing in flight to its drive (a broadcast: nothing in
    /// flight at all), and no broadcast in flight.
    fn may_start(&self, job: &Job) -> bool {
        if self.broadcasting() {
            return false;
        }
        if !job.exchange.expect_reply {
            return self.slots.iter().all(|s| s.running.is_none());
        }
        self.slots.iter().all(|s| s.address() != Some(job.address))
    }

    /// The next job to start, by priority, keeping each drive's jobs in order: `Ok(None)` when
    /// none may start now, `Err` when the bus's handles are all dropped.
    #[allow(clippy::type_complexity)]
    fn next_job(
        &mut self,
        q: &mut Queues,
        on_demand: &OnDemand<Job>,
    ) -> Result<Option<(Job, Priority, Option<Turn>)>, ()> {
        // The held jobs first: the most urgent that may start and has no earlier job to its
        // drive before it. A held broadcast holds every job after it.
        let mut best: Option<usize> = None;
        let mut before: Vec<u8> = Vec::new();
        for (i, (job, priority)) in self.held.iter().enumerate() {
            let blocked = !job.exchange.expect_reply && i > 0 || before.contains(&job.address);
            if !blocked
                && self.may_start(job)
                && best.map_or(true, |b| rank(*priority) < rank(self.held[b].1))
            {
                best = Some(i);
            }
            if !job.exchange.expect_reply {
                break;
            }
            before.push(job.address);
        }
        if let Some(i) = best {
            return Ok(self.held.remove(i).map(|(j, p)| (j, p, None)));
        }
        if self.held.iter().any(|(j, _)| !j.exchange.expect_reply) {
            return Ok(None);
        }
        // Then the queues, in the half-duplex owner's order; a job that may not start yet
        // waits in `held`.
        loop {
            let (job, priority, contended) = match q.commands.try_recv() {
                Ok(j) => (j, Priority::Command, None),
                Err(mpsc::error::TryRecvError::Disconnected) => return Err(()),
                Err(mpsc::error::TryRecvError::Empty) => match q.bridged.try_recv() {
                    Ok(j) => (j, Priority::Bridge, None),
                    Err(_) => {
                        if self.poll.is_none() {
                            self.poll = q.polls.try_recv().ok();
                        }
                        let waiting = !on_demand.is_empty();
                        let turn = match (self.poll.is_some(), waiting) {
                            (true, true) => self.share.turn(),
                            (true, false) => Turn::Poll,
                            (false, true) => Turn::OnDemand,
                            (false, false) => match q.scans.try_recv() {
                                Ok(j) if self.held.is_empty() => {
                                    self.held.push_back((j, Priority::Scan));
                                    return Ok(self.next_scan());
                                }
                                Ok(j) => {
                                    self.held.push_back((j, Priority::Scan));
                                    return Ok(None);
                                }
                                Err(_) => return Ok(None),
                            },
                        };
                        let contended = (self.poll.is_some() && waiting).then_some(turn);
                        let job = match turn {
                            Turn::Poll => self.poll.take().map(|j| (j, Priority::Poll)),
                            Turn::OnDemand => on_demand.pop().map(|j| (j, Priority::OnDemand)),
                        };
                        let Some((job, priority)) = job else { return Ok(None) };
                        (job, priority, contended)
                    }
                },
            };
            if self.may_start(&job) && self.held.iter().all(|(h, _)| h.address != job.address) {
                return Ok(Some((job, priority, contended)));
            }
            self.held.push_back((job, priority));
        }
    }

    /// The scan just held, if it may start.
    fn next_scan(&mut self) -> Option<(Job, Priority, Option<Turn>)> {
        let startable = self.held.front().is_some_and(|(j, _)| self.may_start(j));
        startable.then(|| self.held.pop_front().map(|(j, p)| (j, p, None))).flatten()
    }

    /// Begins `job` on slot `i`.
    async fn start(&mut self, i: usize, job: Job, priority: Priority, contended: Option<Turn>) {
        let now = self.link.now();
        let name = self.link.name();
        let slot = &mut self.slots[i];
        // The connection's state is this owner's: the engine only carries it out.
        if self.up {
            slot.engine.link_restored();
        } else {
            let error = self.down.as_ref().map_or_else(|| format!("{name} is not open"), |d| d.0.clone());
            slot.engine.link_lost(now, error);
        }
        let ex = &job.exchange;
        let next =
            slot.engine.begin(now, name, job.address, &ex.request, ex.expect_reply, priority, job.timeout);
        slot.running = Some(Running { job, started: now, contended });
        if self.settle(i, next).await {
            self.carry_on(i).await;
        }
    }

    /// Carries out `next` for slot `i` until an attempt is to be made (true) or the job is over
    /// (false, its result sent).
    async fn settle(&mut self, i: usize, mut next: Next) -> bool {
        loop {
            next = match next {
                Next::Attempt => return true,
                Next::Reopen => {
                    let result = self.reconnect().await;
                    let now = self.link.now();
                    self.slots[i].engine.reopened(now, result)
                }
                Next::Done(result) => {
                    self.finish(i, result);
                    return false;
                }
            };
        }
    }

    /// Ends slot `i`'s job with `result`.
    fn finish(&mut self, i: usize, result: Result<Option<Vec<u8>>, BusError>) {
        let slot = &mut self.slots[i];
        if let Some(t) = slot.transaction.take() {
            self.transactions.forget(t);
        }
        slot.deadline = None;
        if let Some(r) = slot.running.take() {
            if let Some(turn) = r.contended {
                self.share.spent(turn, self.link.now() - r.started);
            }
            let _ = r.job.done.send(result);
        }
    }

    /// Goes on with slot `i`'s attempt: sends its request, or ends the attempt and settles what
    /// comes next, until it waits for an answer or a deadline, or its job is over.
    async fn carry_on(&mut self, i: usize) {
        loop {
            let now = self.link.now();
            let attempt = match self.slots[i].engine.poll(now) {
                Action::Transmit => {
                    let sent = self.transactions.send(self.slots[i].engine.outgoing());
                    let written = match sent {
                        Ok((t, bytes)) => {
                            self.slots[i].transaction = Some(t);
                            self.link.write(&bytes).await.map_err(|e| format!("{}: {e}", self.link.name()))
                        }
                        Err(e) => Err(e.to_string()),
                    };
                    match written {
                        Ok(()) => {
                            let at = self.link.now();
                            self.slots[i].engine.sent(at);
                            continue;
                        }
                        Err(e) => {
                            self.lose(e.clone(), Some(i));
                            Attempt::Link(e)
                        }
                    }
                }
                Action::Wait(deadline) => {
                    self.slots[i].deadline = Some(deadline);
                    return;
                }
                Action::Done(attempt) => attempt,
            };
            let slot = &mut self.slots[i];
            if let Some(t) = slot.transaction.take() {
                self.transactions.forget(t);
            }
            slot.deadline = None;
            let now = self.link.now();
            let next = self.slots[i].engine.attempted(now, attempt);
            if !self.settle(i, next).await {
                return;
            }
        }
    }

    /// Bytes read from the connection: each answer to a request in flight goes to its slot.
    async fn answers(&mut self, bytes: &[u8]) {
        let mut answered: Vec<(u16, Vec<u8>)> = Vec::new();
        let parsed = self.transactions.incoming(bytes, |t, rtu| answered.push((t, rtu.to_vec())));
        let stray = self.transactions.stray();
        self.stats.lock().unwrap_or_else(|p| p.into_inner()).stray_replies = stray;
        if let Err(e) = parsed {
            self.lose(format!("{}: {e}", self.link.name()), None);
        }
        for (t, rtu) in answered {
            let Some(i) = self.slots.iter().position(|s| s.transaction == Some(t)) else { continue };
            // The transaction is over: its id is not in flight any more.
            self.slots[i].transaction = None;
            let now = self.link.now();
            self.slots[i].engine.input(now, &rtu);
            self.carry_on(i).await;
        }
    }

    /// Deadlines that have passed: the attempts time out (or a broadcast's turnaround ends).
    async fn expire(&mut self) {
        let now = self.link.now();
        for i in 0..self.slots.len() {
            if self.slots[i].deadline.is_some_and(|d| d <= now) && self.slots[i].lost.is_none() {
                self.slots[i].deadline = None;
                self.slots[i].engine.timeout(now);
                self.carry_on(i).await;
            }
        }
    }

    /// The connection is lost for `error`: every attempt in flight but slot `except`'s (whose
    /// caller carries it out) ends with it.
    fn lose(&mut self, error: String, except: Option<usize>) {
        self.up = false;
        self.transactions.reset();
        for (i, s) in self.slots.iter_mut().enumerate() {
            if Some(i) != except && s.running.is_some() && (s.transaction.is_some() || s.deadline.is_some()) {
                s.transaction = None;
                s.deadline = None;
                s.lost = Some(error.clone());
            }
        }
    }

    /// Opens the connection again if it is lost and its backoff has passed.
    async fn reconnect(&mut self) -> io::Result<()> {
        if self.up {
            return Ok(());
        }
        let now = self.link.now();
        if let Some((error, at)) = &self.down {
            if now < *at {
                return Err(io::Error::other(error.clone()));
            }
        }
        match self.link.reopen().await {
            Ok(()) => {
                self.up = true;
                self.down = None;
                self.backoff = Backoff::new();
                self.transactions.reset();
                Ok(())
            }
            Err(e) => {
                let wait = self.backoff.failed();
                self.down = Some((e.to_string(), self.link.now() + wait));
                Err(e)
            }
        }
    }
}
