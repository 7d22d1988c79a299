//! The part of a bus master that never waits: admission of a job (offline drives), what to do
//! after each attempt (retry, reopen the link and retry, give up with which error), when a lost
//! link is reopened (backoff), one attempt at a time on the protocol's `MasterSession`, local
//! echo stripping, statistics and per-drive health. The async bus owner (`owner`) and
//! the blocking bus (`blocking`) drive it with their own I/O: it says what to do next
//! ([`Next`]), what to write, until when to wait, and they carry it out.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use drivebus_proto::deframe::{Deframer, Event};
use drivebus_proto::protocol::WireProtocol;
use drivebus_proto::session::{Disposition, MasterEvent, MasterSession, Protocol, Timing};
use drivebus_proto::Instant;

use crate::backoff::Backoff;
use crate::bus::{BusConfig, BusError, BusStats, Health, Priority};

/// How one attempt ended.
#[derive(Debug)]
pub(crate) enum Attempt {
    /// The drive's reply frame.
    Reply(Vec<u8>),
    /// A broadcast: no reply is due.
    NoneDue,
    /// No (whole) reply in time.
    Timeout,
    /// A damaged reply (or a request that is not a frame).
    Damaged(String),
    /// The link failed.
    Link(String),
}

/// What the driver of an engine does next.
pub(crate) enum Action {
    /// Write [`Engine::outgoing`] to the link.
    Transmit,
    /// Read until bytes arrive or this session time, then call [`Engine::input`] or
    /// [`Engine::timeout`].
    Wait(Instant),
    /// The attempt is over.
    Done(Attempt),
}

/// What the driver of an engine does next for a job.
#[derive(Debug)]
pub(crate) enum Next {
    /// Run the attempt the engine has started ([`Engine::poll`] until [`Action::Done`]), then
    /// call [`Engine::attempted`].
    Attempt,
    /// Close and open the link again, then call [`Engine::reopened`].
    Reopen,
    /// The job is over: its result.
    Done(Result<Option<Vec<u8>>, BusError>),
}

/// A link that is lost: why, and when it is opened again.
#[derive(Debug)]
struct Lost {
    /// The last error (of the link, or of the last reopen).
    error: String,
    /// When the next reopen is due.
    reopen_at: Instant,
    /// The waits between failed reopens.
    backoff: Backoff,
}

/// The job in progress.
#[derive(Debug)]
struct Job {
    /// The link's name, for errors.
    link: String,
    address: u8,
    broadcast: bool,
    /// Attempts it may make.
    attempts: u8,
    /// Attempts started.
    made: u8,
    /// Whether the link was reopened for it already (once per job).
    reopened: bool,
    /// How the last attempt ended (a failed reopen before any attempt: that).
    last: Option<Attempt>,
    /// A scan's probe: the address's health is left alone.
    probe: bool,
}

/// How a session's exchange ended, owned (the session's event borrows it).
enum Ended {
    /// The reply frame (checksum checked, answering the request), for the profile to parse.
    Reply(Vec<u8>),
    BroadcastDone,
    Timeout,
    Damaged(String),
}

/// A bus master's state without I/O: the session, timing, counters and health.
pub(crate) struct Engine<P: Protocol> {
    session: MasterSession<P>,
    timing: Timing,
    config: BusConfig,
    stats: Arc<Mutex<BusStats>>,
    health: Arc<Mutex<HashMap<u8, Health>>>,
    /// Bytes of our own request still expected back as local echo.
    echo_left: Vec<u8>,
    /// The bytes to write on [`Action::Transmit`].
    out: Vec<u8>,
    /// Finds requests in what the line brings besides our own: broadcasts another talker
    /// sent (a drive acting as bus master).
    listener: Deframer<P::RequestScanner>,
    /// When the listener last heard bytes (Modbus RTU: a silence of t3.5 since then ends a
    /// frame, so a partial frame never holds the listener).
    last_heard: Option<Instant>,
    /// The request of the job in progress, as the profile encoded it.
    frame: Vec<u8>,
    /// The job in progress.
    job: Option<Job>,
    /// `Some` while the link is lost.
    lost: Option<Lost>,
}

/// Calls `$body` with an engine of `$config`'s protocol (the one place that goes from a
/// [`WireProtocol`](drivebus_proto::protocol::WireProtocol) to its session type).
macro_rules! with_engine {
    ($config:expr, $stats:expr, $health:expr, |$engine:ident| $body:expr) => {{
        let config: $crate::bus::BusConfig = $config;
        let timing = $crate::engine::timing_of(&config);
        use drivebus_proto::protocol::WireProtocol as W;
        use drivebus_proto::{b800, fc, modbus, toshiba};
        macro_rules! go {
            ($proto:expr) => {{
                let $engine = $crate::engine::Engine::new($proto, timing, config.clone(), $stats, $health);
                $body
            }};
        }
        match config.protocol {
            W::ModbusRtu => go!(modbus::rtu::ModbusRtu),
            W::ModbusAscii => go!(modbus::ascii::ModbusAscii),
            W::ToshibaAscii => go!(toshiba::ascii::TipAscii::default()),
            W::ToshibaBinary => go!(toshiba::binary::TipBinary::default()),
            W::DanfossFc => go!(fc::Fc::default()),
            W::B800 => go!(b800::B800),
        }
    }};
}
pub(crate) use with_engine;

/// The response timeout of a Modbus TCP bus unless one is given: a Modbus TCP/RTU gateway
/// answers after its own serial exchange.
const MODBUS_TCP_TIMEOUT: Duration = Duration::from_secs(1);

/// The protocol's timing with the configuration's overrides.
pub(crate) fn timing_of(config: &BusConfig) -> Timing {
    let mut timing = config.protocol.timing(config.baud, config.format);
    if let Some(rt) = config.response_timeout {
        timing.response_timeout = rt;
    }
    match (config.gap, config.family) {
        (Some(gap), _) => timing.min_gap = gap,
        (None, Some(family)) => {
            if let Some(silence) = drivebus_drive::registers::generic::line_silence(family, config.protocol) {
                timing.min_gap = timing.min_gap.max(silence);
            }
        }
        (None, None) => {}
    }
    if config.strict_t15 && config.protocol == WireProtocol::ModbusRtu {
        timing.max_char_gap = Some(drivebus_proto::line::modbus_t15_t35(config.baud).0);
    }
    if config.modbus_tcp {
        // No line: nothing to keep silent, and a frame comes whole whatever its pauses.
        timing.min_gap = config.gap.unwrap_or(Duration::ZERO);
        timing.max_char_gap = None;
        timing.response_timeout = config.response_timeout.unwrap_or(MODBUS_TCP_TIMEOUT);
    }
    timing
}

impl<P: Protocol> Engine<P> {
    /// An engine for `proto` with `timing`, counting into `stats` and `health`.
    pub(crate) fn new(
        proto: P,
        timing: Timing,
        config: BusConfig,
        stats: Arc<Mutex<BusStats>>,
        health: Arc<Mutex<HashMap<u8, Health>>>,
    ) -> Self {
        Engine {
            listener: Deframer::new(proto.request_scanner()),
            last_heard: None,
            session: MasterSession::new(proto, timing),
            timing,
            config,
            stats,
            health,
            echo_left: Vec::new(),
            out: Vec::with_capacity(64),
            frame: Vec::with_capacity(64),
            job: None,
            lost: None,
        }
    }

    /// The bus's response timeout.
    pub(crate) fn response_timeout(&self) -> Duration {
        self.timing.response_timeout
    }

    /// The link was opened again outside a job (a standby opens its port to listen).
    pub(crate) fn link_restored(&mut self) {
        self.lost = None;
    }

    /// The link is lost (or was never opened) at session time `now` for `error`: the next job
    /// reopens it first.
    pub(crate) fn link_lost(&mut self, now: Instant, error: String) {
        let backoff = self.lost.as_ref().map_or_else(Backoff::new, |l| l.backoff);
        self.lost = Some(Lost { error, reopen_at: now, backoff });
    }

    /// Begins a job on link `link` at session time `now`: `frame` to drive `address` (a
    /// broadcast when no reply is due), with `priority` and a response timeout of `timeout`
    /// instead of the bus's. A drive that is offline until its next probe, a lost link whose
    /// reopen is not due and a request that is not a frame end the job at once.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn begin(
        &mut self,
        now: Instant,
        link: String,
        address: u8,
        frame: &[u8],
        expect_reply: bool,
        priority: Priority,
        timeout: Option<Duration>,
    ) -> Next {
        let broadcast = !expect_reply;
        let attempts = match self.admit(now, address, broadcast, priority, timeout) {
            Ok(n) => n,
            Err(e) => return Next::Done(Err(e)),
        };
        self.frame.clear();
        self.frame.extend_from_slice(frame);
        let probe = priority == Priority::Scan;
        self.job =
            Some(Job { link, address, broadcast, attempts, made: 0, reopened: false, last: None, probe });
        match &self.lost {
            Some(lost) if now >= lost.reopen_at => Next::Reopen,
            Some(lost) => {
                let error = lost.error.clone();
                self.end(now, Attempt::Link(error))
            }
            None => self.next_attempt(now),
        }
    }

    /// The attempt [`Next::Attempt`] asked for ended as `attempt` at session time `now`.
    pub(crate) fn attempted(&mut self, now: Instant, attempt: Attempt) -> Next {
        let Some(job) = self.job.as_mut() else { return Next::Done(Err(BusError::Closed)) };
        match attempt {
            Attempt::Reply(_) | Attempt::NoneDue => {}
            Attempt::Timeout | Attempt::Damaged(_) => {
                if job.made < job.attempts {
                    job.last = Some(attempt);
                    return self.next_attempt(now);
                }
            }
            Attempt::Link(ref e) => {
                let error = e.clone();
                // The port may have gone and come back: reopen it now, once in a job.
                if !job.reopened {
                    job.last = Some(attempt);
                    self.link_lost(now, error);
                    return Next::Reopen;
                }
                self.link_lost(now, error);
            }
        }
        self.end(now, attempt)
    }

    /// The reopen [`Next::Reopen`] asked for ended with `result` at session time `now`: the
    /// job goes on with its next attempt, or ends with the link's error. A failed reopen is
    /// tried again by the first job after a backoff (250 ms, doubling up to 5 s); the jobs
    /// before it end at once with the link's error.
    pub(crate) fn reopened(&mut self, now: Instant, result: std::io::Result<()>) -> Next {
        let Some(job) = self.job.as_mut() else { return Next::Done(Err(BusError::Closed)) };
        job.reopened = true;
        let last = job.last.take();
        let more = job.made < job.attempts;
        let error = match result {
            Ok(()) => {
                self.lost = None;
                return match last {
                    Some(last) if !more => self.end(now, last),
                    _ => self.next_attempt(now),
                };
            }
            // An open error names its port already ("cannot open serial port /dev/ttyUSB0: ...").
            Err(e) => match e.to_string() {
                named if named.contains(job.link.as_str()) => named,
                other => format!("{}: {other}", job.link),
            },
        };
        let mut backoff = self.lost.as_ref().map_or_else(Backoff::new, |l| l.backoff);
        let wait = backoff.failed();
        self.lost = Some(Lost { error: error.clone(), reopen_at: now + wait, backoff });
        // The attempt's own link error says what went wrong first, where there was one.
        let last = match last {
            Some(a @ Attempt::Link(_)) => a,
            _ => Attempt::Link(error),
        };
        self.end(now, last)
    }

    /// Starts the job's next attempt.
    fn next_attempt(&mut self, now: Instant) -> Next {
        let Some(job) = self.job.as_mut() else { return Next::Done(Err(BusError::Closed)) };
        let i = job.made;
        job.made += 1;
        let frame = std::mem::take(&mut self.frame);
        let started = self.start(now, &frame, i);
        self.frame = frame;
        match started {
            Ok(()) => Next::Attempt,
            Err(e) => {
                // The caller's error: the drive's health is left alone.
                self.job = None;
                Next::Done(Err(e))
            }
        }
    }

    /// Ends the job with its last attempt.
    fn end(&mut self, now: Instant, last: Attempt) -> Next {
        let Some(job) = self.job.take() else { return Next::Done(Err(BusError::Closed)) };
        // A probe's answer or silence says nothing of a drive's health: not recorded.
        Next::Done(self.finish(now, job.link, job.address, job.broadcast || job.probe, job.attempts, last))
    }

    /// Admits a job to drive `address` at session time `now`: how many attempts it gets, or
    /// `Offline` when the drive is offline and its next probe is not due (polls and on-demand
    /// reads only).
    fn admit(
        &mut self,
        now: Instant,
        address: u8,
        broadcast: bool,
        priority: Priority,
        timeout: Option<Duration>,
    ) -> Result<u8, BusError> {
        let mut offline = false;
        if priority == Priority::Scan {
            // One attempt, whatever the address's health: a probe is not a drive's poll.
            offline = true;
        } else if !broadcast {
            let mut health = self.health.lock().unwrap_or_else(|p| p.into_inner());
            let h = health.entry(address).or_insert_with(|| Health { online: true, ..Health::default() });
            if !h.online
                && matches!(priority, Priority::Poll | Priority::OnDemand)
                && h.next_probe.is_some_and(|t| now < t)
            {
                return Err(BusError::Offline { address });
            }
            offline = !h.online;
        }
        let mut timing = self.timing;
        if let Some(t) = timeout {
            timing.response_timeout = t;
        }
        self.session.set_timing(timing);
        // An offline drive gets one probe, not the retries.
        Ok(if offline || broadcast { 1 } else { 1 + self.config.retries })
    }

    /// Starts attempt number `i` (0 for the first) of sending `frame`. A frame that is not a
    /// valid request of the bus's protocol is the caller's error: nothing is sent or counted,
    /// and the drive's health is left alone.
    pub(crate) fn start(&mut self, now: Instant, frame: &[u8], i: u8) -> Result<(), BusError> {
        self.session.abort();
        self.echo_left.clear();
        // The profile's bytes go on the wire as they are; what the reply must match comes from
        // a look at the frame.
        let pending = self
            .session
            .protocol()
            .pending_of_frame(frame)
            .map_err(|e| BusError::BadRequest(format!("the request is not a valid frame: {e}")))?;
        self.session.send_frame(now, frame, pending).map_err(|e| BusError::BadRequest(e.to_string()))?;
        if i > 0 {
            self.stat(now, |s| s.retries += 1);
        }
        Ok(())
    }

    /// What to do next at session time `now`.
    pub(crate) fn poll(&mut self, now: Instant) -> Action {
        if let Some(bytes) = self.session.poll_transmit(now) {
            self.out.clear();
            self.out.extend_from_slice(bytes);
            if self.config.echo {
                self.echo_left.clear();
                self.echo_left.extend_from_slice(&self.out);
            }
            return Action::Transmit;
        }
        let event = self.session.poll_frame_event().map(|e| match e {
            MasterEvent::Reply(frame) => Ended::Reply(frame.to_vec()),
            MasterEvent::BroadcastDone => Ended::BroadcastDone,
            MasterEvent::Timeout => Ended::Timeout,
            MasterEvent::Corrupt(e) | MasterEvent::Invalid(e) => Ended::Damaged(e.to_string()),
        });
        match event {
            Some(Ended::Reply(bytes)) => {
                let wire = (self.timing.char_time * bytes.len() as u32).as_secs_f64();
                self.stat(now, |s| {
                    s.replies += 1;
                    s.wire_seconds += wire;
                    s.wire_bytes += bytes.len() as u64;
                });
                Action::Done(Attempt::Reply(bytes))
            }
            Some(Ended::BroadcastDone) => {
                self.stat(now, |s| s.broadcasts += 1);
                Action::Done(Attempt::NoneDue)
            }
            Some(Ended::Timeout) => {
                self.stat(now, |s| s.timeouts += 1);
                Action::Done(Attempt::Timeout)
            }
            Some(Ended::Damaged(e)) => {
                self.stat(now, |s| s.checksum_errors += 1);
                Action::Done(Attempt::Damaged(e))
            }
            None => Action::Wait(self.session.poll_timeout().unwrap_or(now + Duration::from_secs(1))),
        }
    }

    /// The bytes of [`Action::Transmit`] went out at session time `now`: counted as a
    /// transaction, and their wire time as time on the line (a write that failed is neither).
    pub(crate) fn sent(&mut self, now: Instant) {
        let wire = (self.timing.char_time * self.out.len() as u32).as_secs_f64();
        let mut s = self.stats.lock().unwrap_or_else(|p| p.into_inner());
        s.transactions += 1;
        s.wire_seconds += wire;
        s.wire_bytes += self.out.len() as u64;
        // The request is on the line until its last character: elapsed time runs to there, so
        // the line is never busier than the time that has passed.
        s.elapsed_seconds = s.elapsed_seconds.max(now.as_nanos() as f64 / 1e9 + wire);
    }

    /// The bytes to write after [`Action::Transmit`].
    pub(crate) fn outgoing(&self) -> &[u8] {
        &self.out
    }

    /// Bytes read from the link at session time `now`.
    pub(crate) fn input(&mut self, now: Instant, mut input: &[u8]) {
        // Strip the local echo of our own request: as much of it as these bytes repeat.
        let same = self.echo_left.iter().zip(input).take_while(|(e, b)| e == b).count();
        input = &input[same..];
        if same < self.echo_left.len() && !input.is_empty() {
            // Something else than the echo came: there is no more echo to expect.
            self.echo_left.clear();
        } else {
            self.echo_left.drain(..same);
        }
        self.listen(now, input);
        self.session.handle_input(now, input);
    }

    /// The deadline of [`Action::Wait`] has passed.
    pub(crate) fn timeout(&mut self, now: Instant) {
        self.session.handle_timeout(now);
    }

    /// Ends a job after `attempts` attempts whose last ended as `last`: the job's result, and
    /// the drive's health updated.
    fn finish(
        &mut self,
        now: Instant,
        link: String,
        address: u8,
        broadcast: bool,
        attempts: u8,
        last: Attempt,
    ) -> Result<Option<Vec<u8>>, BusError> {
        let result = match last {
            Attempt::Reply(bytes) => Ok(Some(bytes)),
            Attempt::NoneDue => Ok(None),
            Attempt::Timeout => Err(BusError::Timeout { link, address, attempts }),
            Attempt::Damaged(error) => Err(BusError::Corrupt { link, error }),
            Attempt::Link(e) => Err(BusError::Link(e)),
        };
        if !broadcast {
            self.record(now, address, result.is_ok());
        }
        result
    }

    /// False once drive `address` is offline (no answer `offline_after` times in a row).
    pub(crate) fn online(&self, address: u8) -> bool {
        self.health.lock().unwrap_or_else(|p| p.into_inner()).get(&address).map_or(true, |h| h.online)
    }

    /// Counts a transaction with drive `address` that ended at `now`, answered or not, into its
    /// health (offline after `offline_after` failures in a row). A standby counts those it hears.
    pub(crate) fn record(&mut self, now: Instant, address: u8, ok: bool) {
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

    /// Counts the broadcasts in `input` (bytes that are not our own request's echo): requests
    /// to every drive that this master did not send, as a drive acting as bus master sends
    /// them every cycle.
    fn listen(&mut self, now: Instant, input: &[u8]) {
        if input.is_empty() {
            return;
        }
        let t35 = drivebus_proto::line::modbus_t15_t35(self.config.baud).1;
        let silence = self.config.protocol == WireProtocol::ModbusRtu
            && self.last_heard.is_some_and(|t| now.saturating_since(t) >= t35);
        self.last_heard = Some(now);
        let Engine { listener, session, .. } = self;
        let proto = session.protocol();
        let mut heard = 0u64;
        let mut on_event = |e: Event<'_>| {
            if let Event::Frame { bytes, .. } = e {
                let broadcast = proto
                    .parse_request(bytes)
                    .is_ok_and(|r| matches!(proto.disposition(&r, 0xFE), Disposition::Broadcast { .. }));
                heard += u64::from(broadcast);
            }
        };
        if silence {
            listener.silence(&mut on_event);
        }
        listener.push(input, &mut on_event);
        if heard > 0 {
            self.stat(now, |s| {
                s.foreign_broadcasts += heard;
                s.last_foreign_broadcast_s = Some(now.as_nanos() as f64 / 1e9);
            });
        }
    }

    fn stat(&self, now: Instant, f: impl FnOnce(&mut BusStats)) {
        let mut s = self.stats.lock().unwrap_or_else(|p| p.into_inner());
        f(&mut s);
        s.elapsed_seconds = s.elapsed_seconds.max(now.as_nanos() as f64 / 1e9);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use drivebus_proto::modbus::rtu::ModbusRtu;

    fn engine() -> (Engine<ModbusRtu>, Arc<Mutex<BusStats>>) {
        let config = BusConfig::new(WireProtocol::ModbusRtu, 9600, "8N1".parse().unwrap());
        let stats = Arc::new(Mutex::new(BusStats::default()));
        let timing = timing_of(&config);
        let e = Engine::new(ModbusRtu, timing, config, stats.clone(), Default::default());
        (e, stats)
    }

    const READ: [u8; 8] = [0x01, 0x03, 0x21, 0x00, 0x00, 0x02, 0xCE, 0x37];

    /// The first request with the line's silence kept: `Transmit`, and when.
    fn first_transmit(e: &mut Engine<ModbusRtu>) -> Instant {
        let mut now = Instant::ZERO;
        e.start(now, &READ, 0).unwrap();
        loop {
            match e.poll(now) {
                Action::Transmit => return now,
                Action::Wait(t) => now = t,
                Action::Done(a) => panic!("ended before sending: {a:?}"),
            }
        }
    }

    #[test]
    fn a_request_that_never_left_is_not_counted() {
        let (mut e, stats) = engine();
        first_transmit(&mut e);
        // The write failed (no port): nothing was on the line.
        let s = stats.lock().unwrap().clone();
        assert_eq!((s.transactions, s.wire_seconds, s.utilization(), s.wire_bytes), (0, 0.0, 0.0, 0));
    }

    #[test]
    fn the_line_is_never_busier_than_the_time_that_passed() {
        let (mut e, stats) = engine();
        let at = first_transmit(&mut e);
        e.sent(at);
        // Read while the request is still on the wire (8 characters at 9600 baud, 8.3 ms).
        let s = stats.lock().unwrap().clone();
        assert_eq!(s.transactions, 1);
        assert_eq!(s.wire_bytes, 8, "the 8 bytes of the request: {s:?}");
        assert!(s.wire_seconds > 0.008, "{s:?}");
        let u = s.utilization();
        assert!(u > 0.0 && u <= 1.0, "utilization {u} from {s:?}");
    }

    #[test]
    fn a_request_that_is_not_a_valid_frame_is_the_callers_error() {
        let (mut e, stats) = engine();
        // Too short to be a Modbus RTU request at all.
        let bad = &READ[..3];
        for i in 0..3 {
            match e.start(Instant::ZERO, bad, i) {
                Err(BusError::BadRequest(m)) => assert!(m.contains("not a valid frame"), "{m}"),
                other => panic!("{other:?}"),
            }
        }
        assert!(!matches!(e.poll(Instant::ZERO), Action::Transmit), "nothing to send");
        let s = stats.lock().unwrap().clone();
        assert_eq!((s.transactions, s.retries, s.checksum_errors), (0, 0, 0));
    }

    /// The reply to [`READ`]: registers 1 and 2.
    fn read_reply() -> Vec<u8> {
        let mut r = vec![0x01, 0x03, 0x04, 0x00, 0x01, 0x00, 0x02];
        let crc = drivebus_proto::checksum::crc16_modbus(&r);
        r.extend_from_slice(&crc.to_le_bytes());
        r
    }

    fn echo_engine() -> Engine<ModbusRtu> {
        let mut config = BusConfig::new(WireProtocol::ModbusRtu, 9600, "8N1".parse().unwrap());
        config.echo = true;
        let timing = timing_of(&config);
        Engine::new(ModbusRtu, timing, config, Default::default(), Default::default())
    }

    /// Feeds `chunks` after the request went out; the attempt's end.
    fn feed(e: &mut Engine<ModbusRtu>, chunks: &[&[u8]]) -> Option<Attempt> {
        let at = first_transmit(e);
        e.sent(at);
        let mut now = at;
        for c in chunks {
            now = now + Duration::from_millis(1);
            e.input(now, c);
        }
        match e.poll(now + Duration::from_millis(5)) {
            Action::Done(a) => Some(a),
            _ => None,
        }
    }

    #[test]
    fn the_local_echo_is_stripped_however_the_bytes_are_cut() {
        let reply = read_reply();
        let mut both = READ.to_vec();
        both.extend_from_slice(&reply);
        for cut in [1, 3, 8, 9, 12] {
            let mut e = echo_engine();
            match feed(&mut e, &[&both[..cut], &both[cut..]]) {
                Some(Attempt::Reply(r)) => assert_eq!(r, reply, "cut at {cut}"),
                other => panic!("cut at {cut}: {other:?}"),
            }
        }
    }

    /// The silence the engine of `config` keeps between a reply's last byte and the next
    /// request, on session (virtual) time.
    fn silence_after_a_reply(config: BusConfig) -> Duration {
        let timing = timing_of(&config);
        let mut e = Engine::new(ModbusRtu, timing, config, Default::default(), Default::default());
        let at = first_transmit(&mut e);
        e.sent(at);
        let heard = at + Duration::from_millis(20);
        e.input(heard, &read_reply());
        assert!(matches!(e.poll(heard), Action::Done(Attempt::Reply(_))));
        e.start(heard, &READ, 0).unwrap();
        let mut now = heard;
        loop {
            match e.poll(now) {
                Action::Transmit => return now - heard,
                Action::Wait(t) => now = t,
                Action::Done(a) => panic!("ended before sending: {a:?}"),
            }
        }
    }

    #[test]
    fn a_generic_rtu_bus_keeps_10_ms_between_frames_not_only_t35() {
        // 19200 baud 8N2: t3.5 is 2 ms; seed 004 asks for at least 10 ms of silence.
        let plain = BusConfig::new(WireProtocol::ModbusRtu, 19200, "8N2".parse().unwrap());
        let t35 = drivebus_proto::modbus::rtu::timing(19200, plain.format).min_gap;
        assert!(t35 < Duration::from_millis(3), "{t35:?}");
        assert_eq!(silence_after_a_reply(plain.clone()), t35);
        let generic = BusConfig { family: Some(drivebus_drive::Family::Generic), ..plain.clone() };
        assert_eq!(silence_after_a_reply(generic.clone()), Duration::from_millis(10));
        // Other families keep the protocol's; --gap overrides both.
        let toshiba = BusConfig { family: Some(drivebus_drive::Family::Toshiba), ..plain.clone() };
        assert_eq!(silence_after_a_reply(toshiba), t35);
        let gap = BusConfig { gap: Some(Duration::from_millis(2)), ..generic };
        assert_eq!(silence_after_a_reply(gap), Duration::from_millis(2));
        // At 9600 baud t3.5 (4.01 ms) is shorter than 10 ms too.
        let slow = BusConfig {
            family: Some(drivebus_drive::Family::Generic),
            ..BusConfig::new(WireProtocol::ModbusRtu, 9600, "8N2".parse().unwrap())
        };
        assert_eq!(silence_after_a_reply(slow), Duration::from_millis(10));
    }

    /// A generic master drive's broadcast: 06 to 0, 2001H = 40.00 Hz.
    fn broadcast() -> Vec<u8> {
        let mut b = vec![0x00, 0x06, 0x20, 0x01, 0x0F, 0xA0];
        let crc = drivebus_proto::checksum::crc16_modbus(&b);
        b.extend_from_slice(&crc.to_le_bytes());
        b
    }

    #[test]
    fn broadcasts_another_talker_sent_are_counted_after_a_cut_frame() {
        let (mut e, stats) = engine();
        let at = first_transmit(&mut e);
        e.sent(at);
        // The start of a frame that announces 246 data bytes, cut short (a collision) ...
        let mut now = at + Duration::from_millis(2);
        e.input(now, &[0x05, 0x10, 0x00, 0x00, 0x00, 0x7B, 0xF6, 0x01]);
        // ... then, after more than t3.5 of silence, a drive master's broadcast: counted.
        now = now + Duration::from_millis(20);
        e.input(now, &broadcast());
        let s = stats.lock().unwrap().clone();
        assert_eq!(s.foreign_broadcasts, 1, "{s:?}");
        assert_eq!(s.last_foreign_broadcast_s, Some(now.as_nanos() as f64 / 1e9));
        // Our own request and the drive's reply are not broadcasts.
        e.input(now + Duration::from_millis(20), &read_reply());
        assert_eq!(stats.lock().unwrap().foreign_broadcasts, 1);
    }

    /// Begins a job that reads [`READ`] from drive 1 at `now` on link "port".
    fn begin(e: &mut Engine<ModbusRtu>, now: Instant) -> Next {
        e.begin(now, "port".to_string(), 1, &READ, true, Priority::Command, None)
    }

    fn ms(n: u64) -> Instant {
        Instant::from_millis(n)
    }

    #[test]
    fn a_timeout_is_retried_until_the_attempts_run_out() {
        let (mut e, stats) = engine();
        assert!(matches!(begin(&mut e, ms(0)), Next::Attempt));
        assert!(matches!(e.attempted(ms(100), Attempt::Timeout), Next::Attempt));
        assert!(matches!(e.attempted(ms(200), Attempt::Damaged("crc".into())), Next::Attempt));
        match e.attempted(ms(300), Attempt::Timeout) {
            Next::Done(Err(BusError::Timeout { link, address: 1, attempts: 3 })) => assert_eq!(link, "port"),
            other => panic!("{other:?}"),
        }
        assert_eq!(stats.lock().unwrap().retries, 2);
        // A reply ends the job at once.
        assert!(matches!(begin(&mut e, ms(400)), Next::Attempt));
        assert!(matches!(e.attempted(ms(410), Attempt::Reply(read_reply())), Next::Done(Ok(Some(_)))));
    }

    #[test]
    fn a_lost_link_is_reopened_once_in_a_job_and_the_attempt_made_again() {
        let (mut e, _) = engine();
        assert!(matches!(begin(&mut e, ms(0)), Next::Attempt));
        assert!(matches!(e.attempted(ms(10), Attempt::Link("port: gone".into())), Next::Reopen));
        assert!(matches!(e.reopened(ms(20), Ok(())), Next::Attempt));
        // Lost again in the same job: it ends with the link's error, and the next job reopens
        // the link first, at once.
        match e.attempted(ms(30), Attempt::Link("port: gone again".into())) {
            Next::Done(Err(BusError::Link(m))) => assert_eq!(m, "port: gone again"),
            other => panic!("{other:?}"),
        }
        assert!(matches!(begin(&mut e, ms(30)), Next::Reopen));
        assert!(matches!(e.reopened(ms(40), Ok(())), Next::Attempt));
        assert!(matches!(e.attempted(ms(50), Attempt::Reply(read_reply())), Next::Done(Ok(Some(_)))));
    }

    #[test]
    fn a_link_that_will_not_reopen_is_tried_again_after_a_doubling_backoff() {
        let (mut e, stats) = engine();
        assert!(matches!(begin(&mut e, ms(0)), Next::Attempt));
        assert!(matches!(e.attempted(ms(10), Attempt::Link("port: unplugged".into())), Next::Reopen));
        // The reopen fails: the job ends with what went wrong first.
        let refused =
            || std::io::Error::new(std::io::ErrorKind::NotFound, "cannot open serial port port: gone");
        match e.reopened(ms(10), Err(refused())) {
            Next::Done(Err(BusError::Link(m))) => assert_eq!(m, "port: unplugged"),
            other => panic!("{other:?}"),
        }
        // Until the backoff has passed, jobs end at once with the reopen's error, nothing sent.
        let mut at = 10;
        for backoff in [250, 500, 1000, 2000, 4000, 5000, 5000] {
            match begin(&mut e, ms(at + backoff - 1)) {
                Next::Done(Err(BusError::Link(m))) => {
                    assert_eq!(m, "cannot open serial port port: gone")
                }
                other => panic!("{backoff} ms: {other:?}"),
            }
            at += backoff;
            assert!(matches!(begin(&mut e, ms(at)), Next::Reopen), "{backoff} ms");
            assert!(matches!(e.reopened(ms(at), Err(refused())), Next::Done(Err(BusError::Link(_)))));
        }
        assert_eq!(stats.lock().unwrap().transactions, 0);
        // Back: the job goes on with its first attempt (not a retry), and the backoff starts over.
        assert!(matches!(begin(&mut e, ms(at + 5000)), Next::Reopen));
        assert!(matches!(e.reopened(ms(at + 5000), Ok(())), Next::Attempt));
        assert_eq!(stats.lock().unwrap().retries, 0);
        // Lost again: this job has had its reopen; the next one reopens at once.
        assert!(matches!(e.attempted(ms(at + 5010), Attempt::Link("port: gone".into())), Next::Done(Err(_))));
        assert!(matches!(begin(&mut e, ms(at + 5010)), Next::Reopen));
        assert!(matches!(e.reopened(ms(at + 5010), Err(refused())), Next::Done(_)));
        assert!(matches!(begin(&mut e, ms(at + 5010 + 249)), Next::Done(Err(BusError::Link(_)))));
        assert!(matches!(begin(&mut e, ms(at + 5010 + 250)), Next::Reopen));
    }

    #[test]
    fn a_link_never_opened_is_opened_by_the_first_job() {
        let (mut e, _) = engine();
        e.link_lost(ms(0), "port is not open".into());
        assert!(matches!(begin(&mut e, ms(5)), Next::Reopen));
        // The error is the port's, by its name.
        match e.reopened(ms(5), Err(std::io::Error::other("refused"))) {
            Next::Done(Err(BusError::Link(m))) => assert_eq!(m, "port: refused"),
            other => panic!("{other:?}"),
        }
        // The drive's health counts the failures like any other.
        let h = e.health.lock().unwrap().get(&1).cloned().unwrap();
        assert_eq!((h.transactions, h.errors), (1, 1));
    }

    #[test]
    fn utilization_stops_at_one_on_a_link_faster_than_its_baud_rate() {
        let s = BusStats { wire_seconds: 2.0, elapsed_seconds: 1.0, ..BusStats::default() };
        assert_eq!(s.utilization(), 1.0);
    }
}
