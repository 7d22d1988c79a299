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
use drivebus_proto::session::{MasterEvent, MasterSession, Protocol, Timing};
use drivebus_proto::{b800, fc, modbus, toshiba, Instant};
use tokio::sync::{mpsc, oneshot};

use crate::link::Link;

/// How a bus is run.
#[derive(Clone, Debug)]
pub struct BusConfig {
    /// The codec name of the protocol on the bus (`modbus-rtu`, `danfoss-fc`, ...).
    pub protocol: String,
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
    pub fn new(protocol: &str, baud: u32, format: CharFormat) -> Self {
        BusConfig {
            protocol: protocol.to_string(),
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
    /// Time on the wire divided by elapsed time.
    pub fn utilization(&self) -> f64 {
        if self.elapsed_seconds > 0.0 {
            self.wire_seconds / self.elapsed_seconds
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
    backoff: Duration,
    next_probe: Option<Instant>,
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
    polls: mpsc::UnboundedSender<Job>,
    stats: Arc<Mutex<BusStats>>,
    health: Arc<Mutex<HashMap<u8, Health>>>,
    name: String,
}

impl Bus {
    /// Starts the owner task for `link` with `config` on the current tokio runtime.
    pub fn spawn<L: Link>(link: L, config: BusConfig) -> Result<Bus, BusError> {
        let t = |f: fn(u32, CharFormat) -> Timing| {
            let mut timing = f(config.baud, config.format);
            if let Some(rt) = config.response_timeout {
                timing.response_timeout = rt;
            }
            if let Some(gap) = config.gap {
                timing.min_gap = gap;
            }
            if config.strict_t15 && config.protocol == "modbus-rtu" {
                timing.max_char_gap = Some(drivebus_proto::line::modbus_t15_t35(config.baud).0);
            }
            timing
        };
        match config.protocol.as_str() {
            "modbus-rtu" => Ok(Self::spawn_typed(link, modbus::rtu::ModbusRtu, t(modbus::rtu::timing), config)),
            "modbus-ascii" => Ok(Self::spawn_typed(link, modbus::ascii::ModbusAscii, t(modbus::ascii::timing), config)),
            "toshiba-ascii" => Ok(Self::spawn_typed(link, toshiba::ascii::TipAscii::default(), t(toshiba::timing), config)),
            "toshiba-binary" => Ok(Self::spawn_typed(link, toshiba::binary::TipBinary::default(), t(toshiba::timing), config)),
            "danfoss-fc" => Ok(Self::spawn_typed(link, fc::Fc::default(), t(fc::timing), config)),
            "b800" => Ok(Self::spawn_typed(link, b800::B800, t(b800::timing), config)),
            other => Err(BusError::BadRequest(format!(
                "unknown protocol {other:?}: use modbus-rtu, modbus-ascii, toshiba-ascii, toshiba-binary, danfoss-fc or b800"
            ))),
        }
    }

    fn spawn_typed<L: Link, P: Protocol + Send + 'static>(
        link: L,
        proto: P,
        timing: Timing,
        config: BusConfig,
    ) -> Bus
    where
        P::Pending: Send,
        P::ReplyScanner: Send,
        P::RequestScanner: Send,
    {
        let (ctx, crx) = mpsc::unbounded_channel();
        let (ptx, prx) = mpsc::unbounded_channel();
        let stats = Arc::new(Mutex::new(BusStats::default()));
        let health = Arc::new(Mutex::new(HashMap::new()));
        let name = link.name();
        let owner = Owner {
            link,
            session: MasterSession::new(proto, timing),
            timing,
            config,
            stats: stats.clone(),
            health: health.clone(),
            rx_buf: Vec::new(),
        };
        tokio::spawn(owner.run(crx, prx));
        Bus { commands: ctx, polls: ptx, stats, health, name }
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
    session: MasterSession<P>,
    timing: Timing,
    config: BusConfig,
    stats: Arc<Mutex<BusStats>>,
    health: Arc<Mutex<HashMap<u8, Health>>>,
    /// The read buffer, kept between exchanges.
    rx_buf: Vec<u8>,
}

/// How a session's exchange ended, owned (the session's event borrows it).
enum Ended {
    Reply,
    BroadcastDone,
    Timeout,
    Damaged(String),
}

enum Attempt {
    Reply(Vec<u8>),
    NoneDue,
    Timeout,
    Damaged(String),
    Link(String),
}

impl<L: Link, P: Protocol> Owner<L, P> {
    async fn run(
        mut self,
        mut commands: mpsc::UnboundedReceiver<Job>,
        mut polls: mpsc::UnboundedReceiver<Job>,
    ) {
        loop {
            let job = tokio::select! {
                biased;
                Some(j) = commands.recv() => (j, Priority::Command),
                Some(j) = polls.recv() => (j, Priority::Poll),
                else => return,
            };
            let (job, priority) = job;
            let result = self.job(&job, priority).await;
            let _ = job.done.send(result);
        }
    }

    async fn job(&mut self, job: &Job, priority: Priority) -> Result<Option<Vec<u8>>, BusError> {
        let now = self.link.now();
        let broadcast = !job.exchange.expect_reply;
        if !broadcast {
            let mut health = self.health.lock().unwrap_or_else(|p| p.into_inner());
            let h = health.entry(job.address).or_insert_with(|| Health { online: true, ..Health::default() });
            if !h.online && priority == Priority::Poll && h.next_probe.is_some_and(|t| now < t) {
                return Err(BusError::Offline { address: job.address });
            }
        }
        let mut timing = self.timing;
        if let Some(t) = job.timeout {
            timing.response_timeout = t;
        }
        self.session.set_timing(timing);
        // An offline drive gets one probe, not the retries.
        let offline = self
            .health
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .get(&job.address)
            .is_some_and(|h| !h.online);
        let attempts = if offline || broadcast { 1 } else { 1 + self.config.retries };
        let mut last = Attempt::Timeout;
        for i in 0..attempts {
            if i > 0 {
                self.stat(|s| s.retries += 1);
            }
            last = self.attempt(&job.exchange.request).await;
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
        let link = self.link.name();
        let result = match last {
            Attempt::Reply(bytes) => Ok(Some(bytes)),
            Attempt::NoneDue => Ok(None),
            Attempt::Timeout => Err(BusError::Timeout { link, address: job.address, attempts }),
            Attempt::Damaged(error) => Err(BusError::Corrupt { link, error }),
            Attempt::Link(e) => Err(BusError::Link(e)),
        };
        if !broadcast {
            self.record(job.address, result.is_ok());
        }
        result
    }

    fn record(&mut self, address: u8, ok: bool) {
        let now = self.link.now();
        let mut health = self.health.lock().unwrap_or_else(|p| p.into_inner());
        let h = health.entry(address).or_insert_with(|| Health { online: true, ..Health::default() });
        h.transactions += 1;
        if ok {
            h.online = true;
            h.failures_in_row = 0;
            h.backoff = Duration::ZERO;
            h.next_probe = None;
            h.last_seen_s = Some(now.as_nanos() as f64 / 1e9);
        } else {
            h.errors += 1;
            h.failures_in_row += 1;
            if h.failures_in_row >= self.config.offline_after {
                h.online = false;
                h.backoff = if h.backoff.is_zero() {
                    Duration::from_millis(500)
                } else {
                    (h.backoff * 2).min(self.config.max_backoff)
                };
                h.next_probe = Some(now + h.backoff);
            }
        }
    }

    fn stat(&self, f: impl FnOnce(&mut BusStats)) {
        let mut s = self.stats.lock().unwrap_or_else(|p| p.into_inner());
        f(&mut s);
        s.elapsed_seconds = self.link.now().as_nanos() as f64 / 1e9;
    }

    async fn attempt(&mut self, frame: &[u8]) -> Attempt {
        let now = self.link.now();
        self.session.abort();
        // The typed request borrows the frame; it must not live across an await.
        let sent = match self.session.protocol().parse_request(frame) {
            Ok(req) => self.session.send(now, &req).map_err(|e| e.to_string()),
            Err(e) => Err(format!("the request is not a valid frame: {e}")),
        };
        if let Err(e) = sent {
            return Attempt::Damaged(e);
        }
        let char_time = self.timing.char_time;
        let mut echo_left: Vec<u8> = Vec::new();
        let mut buf = std::mem::take(&mut self.rx_buf);
        buf.resize(1024, 0);
        let result = self.exchange(&mut buf, &mut echo_left, char_time).await;
        self.rx_buf = buf;
        result
    }

    async fn exchange(&mut self, buf: &mut [u8], echo_left: &mut Vec<u8>, char_time: Duration) -> Attempt {
        // One timer for the whole exchange, moved when the session's deadline moves.
        let mut armed: Option<Instant> = None;
        // Session deadlines (the gap before a request, the response timeout) to the microsecond:
        // tokio's own timer would end each on the next whole millisecond.
        let mut sleep = crate::timer::sleep_until(tokio::time::Instant::now() + Duration::from_secs(3600));
        loop {
            let now = self.link.now();
            if let Some(bytes) = self.session.poll_transmit(now) {
                let bytes = bytes.to_vec();
                let wire = (char_time * bytes.len() as u32).as_secs_f64();
                self.stat(|s| {
                    s.transactions += 1;
                    s.wire_seconds += wire;
                });
                if self.config.echo {
                    echo_left.clear();
                    echo_left.extend_from_slice(&bytes);
                }
                if let Err(e) = self.link.write(&bytes).await {
                    return Attempt::Link(format!("{}: {e}", self.link.name()));
                }
            }
            let event = self.session.poll_event().map(|e| match e {
                MasterEvent::Reply(_) => Ended::Reply,
                MasterEvent::BroadcastDone => Ended::BroadcastDone,
                MasterEvent::Timeout => Ended::Timeout,
                MasterEvent::Corrupt(e) | MasterEvent::Invalid(e) => Ended::Damaged(e.to_string()),
            });
            if let Some(event) = event {
                return match event {
                    Ended::Reply => {
                        let bytes = self.session.reply_bytes().to_vec();
                        let wire = (char_time * bytes.len() as u32).as_secs_f64();
                        self.stat(|s| {
                            s.replies += 1;
                            s.wire_seconds += wire;
                        });
                        Attempt::Reply(bytes)
                    }
                    Ended::BroadcastDone => {
                        self.stat(|s| s.broadcasts += 1);
                        Attempt::NoneDue
                    }
                    Ended::Timeout => {
                        self.stat(|s| s.timeouts += 1);
                        Attempt::Timeout
                    }
                    Ended::Damaged(e) => {
                        self.stat(|s| s.checksum_errors += 1);
                        Attempt::Damaged(e)
                    }
                };
            }
            let deadline = self.session.poll_timeout().unwrap_or(now + Duration::from_secs(1));
            if armed != Some(deadline) {
                sleep.reset(self.link.clock().tokio(deadline));
                armed = Some(deadline);
            }
            tokio::select! {
                r = self.link.read(buf) => match r {
                    Ok(n) => {
                        let now = self.link.now();
                        let mut input = &buf[..n];
                        // Strip the local echo of our own request.
                        while let (Some(&e), Some(&b)) = (echo_left.first(), input.first()) {
                            if e != b {
                                echo_left.clear();
                                break;
                            }
                            echo_left.remove(0);
                            input = &input[1..];
                        }
                        self.session.handle_input(now, input);
                    }
                    Err(e) => return Attempt::Link(format!("{}: {e}", self.link.name())),
                },
                _ = &mut sleep => {
                    armed = None;
                    let now = self.link.now();
                    self.session.handle_timeout(now);
                }
            }
        }
    }
}
