//! The bus owner: one task per half-duplex bus runs one transaction at a time, with the
//! protocol's timing (the minimum silence before a request, the response timeout, the
//! turnaround after a broadcast) kept by the protocol's `MasterSession`.
//!
//! Commands go ahead of polling (two queues, commands served first). Each drive's link health
//! is tracked: after `offline_after` failed transactions in a row it is offline, and polls to it
//! are answered at once with [`BusError::Offline`] until its backoff has passed, when one probe
//! goes out (the backoff doubles up to `max_backoff` while it stays silent). So a dead drive
//! costs the others at most one timeout per backoff interval.

use std::collections::HashMap;
use std::fmt;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use drivebus_drive::profile::Exchange;
use drivebus_proto::line::CharFormat;
use drivebus_proto::protocol::WireProtocol;
use drivebus_proto::session::Protocol;
use drivebus_proto::Instant;
use tokio::sync::{mpsc, oneshot, watch};

use crate::engine::{with_engine, Action, Attempt, Engine};
use crate::link::Link;

/// How a bus is run.
#[derive(Clone, Debug)]
pub struct BusConfig {
    /// The protocol on the bus.
    pub protocol: WireProtocol,
    /// Baud rate (for character times and gaps).
    pub baud: u32,
    /// Character format.
    pub format: CharFormat,
    /// Response timeout; `None`: the protocol's default.
    pub response_timeout: Option<Duration>,
    /// Retries after a timeout or a damaged reply.
    pub retries: u8,
    /// Discard the local echo that 2-wire adapters hear of their own transmission.
    pub echo: bool,
    /// Failed transactions in a row after which a drive is offline.
    pub offline_after: u32,
    /// Longest wait between probes of an offline drive.
    pub max_backoff: Duration,
    /// The silence kept before each request; `None`: the protocol's (Modbus RTU t3.5, FC 2
    /// characters, ...). `Some(ZERO)` for links with no line behind them (a pty to a
    /// simulator, a TCP server that frames by itself).
    pub gap: Option<Duration>,
    /// RS-485 direction control on a serial port (off by default: USB-RS485 adapters switch
    /// by themselves).
    pub rs485: crate::link::Rs485,
    /// Modbus RTU: discard a reply with a silence over t1.5 between two of its bytes, as the
    /// Modbus serial-line specification says. Off by default: USB adapters and device servers
    /// deliver bytes in bursts with gaps of their own (an FTDI chip's latency timer is 16 ms),
    /// and would lose good replies. For on-board UARTs where a frame's bytes come as sent.
    pub strict_t15: bool,
}

impl BusConfig {
    /// A configuration with the protocol's defaults: 2 retries, no echo, offline after 3
    /// failures, probes at most every 30 s.
    pub fn new(protocol: WireProtocol, baud: u32, format: CharFormat) -> Self {
        BusConfig {
            protocol,
            baud,
            format,
            response_timeout: None,
            retries: 2,
            echo: false,
            offline_after: 3,
            max_backoff: Duration::from_secs(30),
            gap: None,
            rs485: crate::link::Rs485::Off,
            strict_t15: false,
        }
    }
}

/// Why a transaction failed. The drive's own refusal is not here: it is a valid reply.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum BusError {
    /// No (whole) reply within the response timeout, after every retry.
    Timeout {
        /// The link.
        link: String,
        /// The drive's address.
        address: u8,
        /// Attempts made.
        attempts: u8,
    },
    /// Replies came back damaged every time (bad checksum, cut short).
    Corrupt {
        /// The link.
        link: String,
        /// The last error.
        error: String,
    },
    /// The drive is offline and its next probe is not due yet.
    Offline {
        /// The drive's address.
        address: u8,
    },
    /// The link failed (port gone, connection refused).
    Link(String),
    /// The request itself is not a valid frame of the bus's protocol (a caller bug).
    BadRequest(String),
    /// The bus owner has stopped.
    Closed,
}

impl fmt::Display for BusError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BusError::Timeout { link, address, attempts } => write!(
                f,
                "no answer from drive {address} on {link} after {attempts} attempt{}: check the address, baud rate, serial format and wiring",
                if *attempts == 1 { "" } else { "s" }
            ),
            BusError::Corrupt { link, error } => {
                write!(f, "damaged replies on {link} ({error}): check termination, grounding and the serial format")
            }
            BusError::Offline { address } => write!(f, "drive {address} is offline; it is probed again after its backoff"),
            BusError::Link(e) => f.write_str(e),
            BusError::BadRequest(e) => write!(f, "cannot send that request: {e}"),
            BusError::Closed => f.write_str("the bus has stopped"),
        }
    }
}

impl std::error::Error for BusError {}

/// Whether a job may wait behind others.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Priority {
    /// A user's command: goes ahead of polling.
    Command,
    /// A request passed through from a Modbus bridge: after commands, ahead of polling.
    Bridge,
    /// Cyclic polling.
    Poll,
}

/// Counts of one bus.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BusStats {
    /// Requests put on the line (retries included).
    pub transactions: u64,
    /// Matching replies.
    pub replies: u64,
    /// Requests that got no reply in time.
    pub timeouts: u64,
    /// Damaged replies (bad checksum, cut short, malformed).
    pub checksum_errors: u64,
    /// Retries.
    pub retries: u64,
    /// Broadcasts sent.
    pub broadcasts: u64,
    /// Time the line carried our requests and the replies, seconds.
    pub wire_seconds: f64,
    /// Session time since the bus started, seconds.
    pub elapsed_seconds: f64,
}

impl BusStats {
    /// Time on the wire divided by elapsed time, 0..=1. Wire time is reckoned at the baud rate,
    /// so a link that carries bytes faster than that (a pty, a simulator without pacing) could
    /// reckon more than the time that passed: the figure stops at 1.
    pub fn utilization(&self) -> f64 {
        if self.elapsed_seconds > 0.0 {
            (self.wire_seconds / self.elapsed_seconds).min(1.0)
        } else {
            0.0
        }
    }
}

/// One drive's link health.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Health {
    /// True until `offline_after` failures in a row.
    pub online: bool,
    /// Session time of the last good reply, seconds.
    pub last_seen_s: Option<f64>,
    /// Failed transactions in a row.
    pub failures_in_row: u32,
    /// Transactions attempted.
    pub transactions: u64,
    /// Transactions that failed.
    pub errors: u64,
    pub(crate) backoff: Duration,
    pub(crate) next_probe: Option<Instant>,
}

struct Job {
    address: u8,
    exchange: Exchange,
    timeout: Option<Duration>,
    done: oneshot::Sender<Result<Option<Vec<u8>>, BusError>>,
}

/// A handle to a running bus owner; cheap to clone.
#[derive(Clone)]
pub struct Bus {
    commands: mpsc::UnboundedSender<Job>,
    bridged: mpsc::UnboundedSender<Job>,
    polls: mpsc::UnboundedSender<Job>,
    stats: Arc<Mutex<BusStats>>,
    health: Arc<Mutex<HashMap<u8, Health>>>,
    name: String,
    /// Closed (its sender dropped) when the owner task has ended and released the link.
    ended: watch::Receiver<()>,
}

impl Bus {
    /// Starts the owner task for `link` with `config` on the current tokio runtime.
    pub fn spawn<L: Link>(link: L, config: BusConfig) -> Result<Bus, BusError> {
        let stats = Arc::new(Mutex::new(BusStats::default()));
        let health = Arc::new(Mutex::new(HashMap::new()));
        let (ctx, crx) = mpsc::unbounded_channel();
        let (btx, brx) = mpsc::unbounded_channel();
        let (ptx, prx) = mpsc::unbounded_channel();
        let name = link.name();
        let (ended_tx, ended) = watch::channel(());
        with_engine!(config, stats.clone(), health.clone(), |engine| {
            tokio::spawn(Owner { link, engine, rx_buf: Vec::new(), _ended: ended_tx }.run(crx, brx, prx));
        });
        Ok(Bus { commands: ctx, bridged: btx, polls: ptx, stats, health, name, ended })
    }

    /// Drops this handle and waits until the owner task has ended and closed the link (the
    /// serial port free for another open). The owner ends once every clone of the handle is
    /// dropped, so drop the others (and the [`crate::drive::Drive`]s holding them) first.
    pub async fn close(self) {
        let Bus { commands, bridged, polls, mut ended, .. } = self;
        drop(commands);
        drop(bridged);
        drop(polls);
        // Err once the owner has dropped its sender, that is ended.
        while ended.changed().await.is_ok() {}
    }

    /// The link's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Sends `exchange` to drive `address` and waits for the reply frame (`None` when no reply
    /// is due). `timeout` overrides the bus's response timeout for this drive.
    pub async fn transact(
        &self,
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
}

struct Owner<L: Link, P: Protocol> {
    link: L,
    engine: Engine<P>,
    /// The read buffer, kept between exchanges.
    rx_buf: Vec<u8>,
    /// Dropped after the link (fields drop in order): tells [`Bus::close`] the link is closed.
    _ended: watch::Sender<()>,
}

impl<L: Link, P: Protocol> Owner<L, P> {
    async fn run(
        mut self,
        mut commands: mpsc::UnboundedReceiver<Job>,
        mut bridged: mpsc::UnboundedReceiver<Job>,
        mut polls: mpsc::UnboundedReceiver<Job>,
    ) {
        loop {
            let job = tokio::select! {
                biased;
                Some(j) = commands.recv() => (j, Priority::Command),
                Some(j) = bridged.recv() => (j, Priority::Bridge),
                Some(j) = polls.recv() => (j, Priority::Poll),
                else => return,
            };
            let (job, priority) = job;
            let result = self.job(&job, priority).await;
            let _ = job.done.send(result);
        }
    }

    async fn job(&mut self, job: &Job, priority: Priority) -> Result<Option<Vec<u8>>, BusError> {
        let broadcast = !job.exchange.expect_reply;
        let attempts = self.engine.admit(self.link.now(), job.address, broadcast, priority, job.timeout)?;
        let mut last = Attempt::Timeout;
        for i in 0..attempts {
            self.engine.start(self.link.now(), &job.exchange.request, i)?;
            last = self.attempt().await;
            match last {
                Attempt::Reply(_) | Attempt::NoneDue => break,
                Attempt::Link(_) => {
                    // The port may have gone and come back: reopen once, then give up.
                    if self.link.reopen().await.is_err() {
                        break;
                    }
                }
                Attempt::Timeout | Attempt::Damaged(_) => {}
            }
        }
        let (now, link) = (self.link.now(), self.link.name());
        self.engine.finish(now, link, job.address, broadcast, attempts, last)
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
