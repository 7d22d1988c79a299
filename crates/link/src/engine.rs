//! The part of a bus master that never waits: admission of a job (offline drives, retries),
//! one attempt at a time on the protocol's `MasterSession`, local echo stripping, statistics
//! and per-drive health. The async bus owner ([`crate::owner`]) and the blocking bus
//! ([`crate::blocking`]) drive it with their own I/O: it says what to write, until when to
//! wait, and how the attempt ended.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use drivebus_proto::protocol::WireProtocol;
use drivebus_proto::session::{MasterEvent, MasterSession, Protocol, Timing};
use drivebus_proto::Instant;

use crate::owner::{BusConfig, BusError, BusStats, Health, Priority};

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

/// How a session's exchange ended, owned (the session's event borrows it).
enum Ended {
    Reply,
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
}

/// Calls `$body` with an engine of `$config`'s protocol (the one place that goes from a
/// [`WireProtocol`](drivebus_proto::protocol::WireProtocol) to its session type).
macro_rules! with_engine {
    ($config:expr, $stats:expr, $health:expr, |$engine:ident| $body:expr) => {{
        let config: $crate::owner::BusConfig = $config;
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

/// The protocol's timing with the configuration's overrides.
pub(crate) fn timing_of(config: &BusConfig) -> Timing {
    let mut timing = config.protocol.timing(config.baud, config.format);
    if let Some(rt) = config.response_timeout {
        timing.response_timeout = rt;
    }
    if let Some(gap) = config.gap {
        timing.min_gap = gap;
    }
    if config.strict_t15 && config.protocol == WireProtocol::ModbusRtu {
        timing.max_char_gap = Some(drivebus_proto::line::modbus_t15_t35(config.baud).0);
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
            session: MasterSession::new(proto, timing),
            timing,
            config,
            stats,
            health,
            echo_left: Vec::new(),
            out: Vec::with_capacity(64),
        }
    }

    /// The bus configuration.
    pub(crate) fn config(&self) -> &BusConfig {
        &self.config
    }

    /// Admits a job to drive `address` at session time `now`: how many attempts it gets, or
    /// `Offline` when the drive is offline and its next probe is not due (polls only).
    pub(crate) fn admit(
        &mut self,
        now: Instant,
        address: u8,
        broadcast: bool,
        priority: Priority,
        timeout: Option<Duration>,
    ) -> Result<u8, BusError> {
        let mut offline = false;
        if !broadcast {
            let mut health = self.health.lock().unwrap_or_else(|p| p.into_inner());
            let h = health.entry(address).or_insert_with(|| Health { online: true, ..Health::default() });
            if !h.online && priority == Priority::Poll && h.next_probe.is_some_and(|t| now < t) {
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
        // The typed request borrows the frame.
        match self.session.protocol().parse_request(frame) {
            Ok(req) => self.session.send(now, &req).map_err(|e| BusError::BadRequest(e.to_string()))?,
            Err(e) => return Err(BusError::BadRequest(format!("the request is not a valid frame: {e}"))),
        }
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
        let event = self.session.poll_event().map(|e| match e {
            MasterEvent::Reply(_) => Ended::Reply,
            MasterEvent::BroadcastDone => Ended::BroadcastDone,
            MasterEvent::Timeout => Ended::Timeout,
            MasterEvent::Corrupt(e) | MasterEvent::Invalid(e) => Ended::Damaged(e.to_string()),
        });
        match event {
            Some(Ended::Reply) => {
                let bytes = self.session.reply_bytes().to_vec();
                let wire = (self.timing.char_time * bytes.len() as u32).as_secs_f64();
                self.stat(now, |s| {
                    s.replies += 1;
                    s.wire_seconds += wire;
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
        self.session.handle_input(now, input);
    }

    /// The deadline of [`Action::Wait`] has passed.
    pub(crate) fn timeout(&mut self, now: Instant) {
        self.session.handle_timeout(now);
    }

    /// Ends a job after `attempts` attempts whose last ended as `last`: the job's result, and
    /// the drive's health updated.
    pub(crate) fn finish(
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

    fn record(&mut self, now: Instant, address: u8, ok: bool) {
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
        assert_eq!((s.transactions, s.wire_seconds, s.utilization()), (0, 0.0, 0.0));
    }

    #[test]
    fn the_line_is_never_busier_than_the_time_that_passed() {
        let (mut e, stats) = engine();
        let at = first_transmit(&mut e);
        e.sent(at);
        // Read while the request is still on the wire (8 characters at 9600 baud, 8.3 ms).
        let s = stats.lock().unwrap().clone();
        assert_eq!(s.transactions, 1);
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

    #[test]
    fn utilization_stops_at_one_on_a_link_faster_than_its_baud_rate() {
        let s = BusStats { wire_seconds: 2.0, elapsed_seconds: 1.0, ..BusStats::default() };
        assert_eq!(s.utilization(), 1.0);
    }
}
