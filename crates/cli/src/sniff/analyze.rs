//! What a passive listener makes of the bytes on a line, without I/O: frames cut by each
//! protocol's deframer plus the line's silences (Modbus RTU t3.5), the direction of each frame,
//! requests paired with their replies and the latency between them, per-address statistics and
//! the bus load. The caller gives timestamped reads; `drivebus sniff` does the I/O.

use std::collections::BTreeMap;
use std::time::Duration;

use drivebus_proto::line::{modbus_t15_t35, CharFormat};
use drivebus_proto::protocol::{CodecJob, WireProtocol};
use drivebus_proto::{Codec, Deframer, Direction, Event, Scan, Scanner, Target};
use serde_json::{json, Value};

use crate::commands::decode::{describe, render_json, FrameReport};

/// The names of the six wire formats, in the order auto-detection lists them.
pub const PROTOCOLS: [&str; 6] = {
    let mut names = [""; 6];
    let mut i = 0;
    while i < names.len() {
        names[i] = WireProtocol::ALL[i].name();
        i += 1;
    }
    names
};

/// A frame candidate out of a deframer: its bytes and, when it is not a whole frame with a
/// good checksum, why.
struct Cut {
    bytes: Vec<u8>,
    error: Option<String>,
}

/// One protocol's deframer behind a trait object, so a listener can run several.
trait Framer: Send {
    fn push(&mut self, bytes: &[u8], out: &mut Vec<Cut>);
    fn silence(&mut self, out: &mut Vec<Cut>);
    fn finish(&mut self, out: &mut Vec<Cut>);
    fn buffered(&self) -> usize;
    /// True when the frame in progress, followed by `next`, is a whole frame with a good
    /// checksum: the gap before `next` was a late read, not a silence on the line.
    fn spans(&self, next: &[u8]) -> bool;
    /// True when `bytes` (a whole frame with a good checksum) parse as a frame from `from`
    /// (`None`: either direction); cheaper than a full report, for the scouts.
    fn valid(&self, bytes: &[u8], from: Option<Direction>) -> bool;
}

/// A deframer and a copy of the bytes it holds for a frame in progress.
struct Typed<C: Codec> {
    deframer: Deframer<C::Scanner>,
    held: Vec<u8>,
}

impl<C: Codec> Typed<C> {
    /// Keeps `held` equal to the deframer's unfinished bytes, after `bytes` were pushed.
    fn track(&mut self, bytes: &[u8]) {
        self.held.extend_from_slice(bytes);
        let keep = self.deframer.buffered();
        let drop = self.held.len().saturating_sub(keep);
        self.held.drain(..drop);
    }
}

fn collect(out: &mut Vec<Cut>) -> impl FnMut(Event<'_>) + '_ {
    move |e| match e {
        Event::Frame { bytes, .. } => out.push(Cut { bytes: bytes.to_vec(), error: None }),
        Event::Rejected { bytes, error, .. } => {
            out.push(Cut { bytes: bytes.to_vec(), error: Some(error.to_string()) })
        }
    }
}

impl<C: Codec> Framer for Typed<C>
where
    C::Scanner: Send,
{
    fn push(&mut self, bytes: &[u8], out: &mut Vec<Cut>) {
        self.deframer.push(bytes, &mut collect(out));
        self.track(bytes);
    }
    fn silence(&mut self, out: &mut Vec<Cut>) {
        self.deframer.silence(&mut collect(out));
        self.track(&[]);
    }
    fn finish(&mut self, out: &mut Vec<Cut>) {
        self.deframer.finish(&mut collect(out));
        self.track(&[]);
    }
    fn buffered(&self) -> usize {
        self.deframer.buffered()
    }
    fn spans(&self, next: &[u8]) -> bool {
        if self.held.is_empty() {
            return false;
        }
        let mut all = self.held.clone();
        all.extend_from_slice(next);
        matches!(self.deframer.scanner().scan(&all, 0), Scan::Frame { len } if len > self.held.len())
    }
    fn valid(&self, bytes: &[u8], from: Option<Direction>) -> bool {
        match from {
            Some(d) => C::parse(bytes, Some(d)).is_ok(),
            None => {
                C::parse(bytes, Some(Direction::Master)).is_ok()
                    || C::parse(bytes, Some(Direction::Drive)).is_ok()
            }
        }
    }
}

/// A deframer for `protocol` and frames from `from` (`None`: both directions on one pair).
fn framer(protocol: &str, from: Option<Direction>) -> Option<Box<dyn Framer>> {
    struct Make(Option<Direction>);
    impl CodecJob for Make {
        type Output = Box<dyn Framer>;
        fn run<C: Codec + 'static>(self) -> Box<dyn Framer>
        where
            C::Scanner: Send + 'static,
        {
            Box::new(Typed::<C> { deframer: Deframer::new(C::scanner(self.0)), held: Vec::new() })
        }
    }
    Some(protocol.parse::<WireProtocol>().ok()?.with_codec(Make(from)))
}

/// Reads a whole frame of `protocol` as sent by `from`.
pub fn parse(protocol: &str, bytes: &[u8], from: Direction) -> Result<FrameReport, String> {
    struct Parse<'a>(&'a [u8], Direction);
    impl CodecJob for Parse<'_> {
        type Output = Result<FrameReport, String>;
        fn run<C: Codec + 'static>(self) -> Self::Output
        where
            C::Scanner: Send + 'static,
        {
            let frame = C::parse(self.0, Some(self.1)).map_err(|e| e.to_string())?;
            Ok(describe(0, self.0, &frame))
        }
    }
    let protocol: WireProtocol = protocol.parse().map_err(|e| format!("{protocol:?}: {e}"))?;
    protocol.with_codec(Parse(bytes, from))
}

/// A frame identical to the waiting request (a Modbus 05/06 reply echoes its request) that
/// comes later than this after it is the master's retry, not the drive's echo: drives answer
/// within tens of milliseconds, masters retry after their timeout (100 ms and more).
pub const ECHO_WITHIN: Duration = Duration::from_millis(60);

/// Reads a frame heard on a pair that carries both directions. With no request waiting, as a
/// request first. With one waiting, as its reply first (a Modbus reply can look like a request,
/// and 06's reply is its request's echo), unless that reading names another drive or the frame
/// is the request again after [`ECHO_WITHIN`]: then as a request.
fn parse_either(
    protocol: &str,
    bytes: &[u8],
    time: Duration,
    waiting: Option<&Record>,
) -> Result<FrameReport, String> {
    let as_master = || parse(protocol, bytes, Direction::Master);
    let Some(req) = waiting else {
        return as_master().or_else(|e| parse(protocol, bytes, Direction::Drive).map_err(|_| e));
    };
    let reply = parse(protocol, bytes, Direction::Drive);
    let fits = match &reply {
        Ok(r) => {
            let same_drive = match (req.frame.target, r.target) {
                (Some(Target::Unit(a)), Some(Target::Unit(b))) => a == b,
                _ => true,
            };
            let retry = bytes == req.frame.bytes.as_slice() && time.saturating_sub(req.time) > ECHO_WITHIN;
            same_drive && !retry
        }
        Err(_) => false,
    };
    if fits {
        return reply;
    }
    as_master().or(reply)
}

/// What one port of the listener hears.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// Both directions (a 2-wire pair).
    Both,
    /// Only one direction (one pair of a 4-wire line).
    Only(Direction),
}

impl Side {
    fn direction(self) -> Option<Direction> {
        match self {
            Side::Both => None,
            Side::Only(d) => Some(d),
        }
    }
}

/// How the listener is set up.
#[derive(Clone, Debug)]
pub struct Settings {
    /// The protocols to decode; empty: find them from the traffic.
    pub protocols: Vec<&'static str>,
    /// The line's baud rate (for t3.5 and the bus load).
    pub baud: u32,
    /// The line's character format (for the bus load).
    pub format: CharFormat,
    /// A request with no reply after this long counts as a timeout.
    pub reply_timeout: Duration,
    /// What each port hears, by port number.
    pub sides: Vec<Side>,
}

/// With nothing read for this long (and at least t3.5), a frame in progress ends. Reads are
/// timestamped when they return, and a USB adapter or a busy reader splits one frame into reads
/// milliseconds apart (at 115200 baud t3.5 is 1.75 ms): a gap over t3.5 before the next read
/// ends the frame only when the bytes before and after it do not make one valid frame.
pub const QUIET: Duration = Duration::from_millis(500);

/// Auto-detection settles once a protocol has this many valid frames.
const SETTLE_FRAMES: u64 = 4;
/// A protocol is decoded once it has this many valid frames (found when the detection settles,
/// or later on a line where a second protocol starts talking).
const FOUND_FRAMES: u64 = 2;
/// A protocol found after the first choice decodes the reads of this long before...
const RECENT_TIME: Duration = Duration::from_secs(2);
/// ...up to this many.
const RECENT_READS: usize = 256;
/// Auto-detection settles with what it has after this long of traffic.
pub const DETECT_WITHIN: Duration = Duration::from_secs(5);

/// What the listener reports: a frame, or a request that got no reply.
#[derive(Clone, Debug, PartialEq)]
pub enum Kind {
    /// A frame, valid or not.
    Frame,
    /// The request this record repeats got no reply within the timeout, or before the next
    /// request.
    NoReply,
}

/// One line of the sniffer's output.
#[derive(Clone, Debug, PartialEq)]
pub struct Record {
    /// When the read that completed the frame returned (the caller's clock).
    pub time: Duration,
    /// The codec name.
    pub protocol: &'static str,
    /// Who sent it (for an invalid frame on a 2-wire pair: who was due to talk).
    pub direction: Direction,
    /// The frame decoded (its `error` set when it is not valid).
    pub frame: FrameReport,
    /// For a reply: the time from its request's read to its own.
    pub latency: Option<Duration>,
    /// Frame or missing reply.
    pub kind: Kind,
}

impl Record {
    /// The drive the frame is to or from, where the frame says.
    pub fn address(&self) -> Option<u8> {
        match self.frame.target {
            Some(Target::Unit(n)) => Some(n),
            Some(Target::Broadcast) => Some(0),
            _ => None,
        }
    }

    /// True for a whole frame with a good checksum that parsed.
    pub fn valid(&self) -> bool {
        self.frame.error.is_none()
    }

    /// The `--json` object: `time` (seconds), `protocol`, `direction`, `address`, `valid`,
    /// `function` (Modbus) or `command`, `fields`, `error` when invalid, `latency_ms` for a reply.
    pub fn json(&self) -> Value {
        let mut v = render_json(self.protocol, &crate::commands::decode::Item::Frame(self.frame.clone()))
            .unwrap_or_else(|| json!({}));
        if let Value::Object(o) = &mut v {
            o.remove("offset");
            o.insert("time".into(), json!(self.time.as_micros() as f64 / 1e6));
            o.insert("direction".into(), json!(self.direction.as_str()));
            if let Some(l) = self.latency {
                o.insert("latency_ms".into(), json!((l.as_micros() as f64 / 1e3 * 1000.0).round() / 1000.0));
            }
            if self.kind == Kind::NoReply {
                o.insert("valid".into(), json!(true));
                o.insert("event".into(), json!("no_reply"));
                o.insert("error".into(), json!("no reply"));
            }
        }
        v
    }

    /// The live table's row: direction, address, meaning in the manual's words, latency, error.
    pub fn row(&self, since: Duration) -> String {
        let t = self.time.saturating_sub(since).as_micros() as f64 / 1e6;
        let addr = self.address().map_or("-".to_string(), |a| a.to_string());
        let dir = match self.direction {
            Direction::Master => "master",
            Direction::Drive => "drive ",
        };
        let what = self.meaning();
        let latency = self.latency.map_or(String::new(), |l| format!("  {:.1} ms", l.as_secs_f64() * 1e3));
        format!("{t:>10.3}  {:<14} {dir}  {addr:>3}  {what}{latency}", self.protocol)
    }

    /// `drive 3: 06 write single register; register 2001, value 0FA0 = 40.00 Hz` for a request,
    /// `→ ok; ...` for a reply, `→ refused (...)`, `no reply`, `INVALID: why`.
    pub fn meaning(&self) -> String {
        let f = &self.frame;
        if self.kind == Kind::NoReply {
            let (code, _, name) = f.command.clone().unwrap_or_default();
            return format!("no reply to {code} {name}");
        }
        if let Some(e) = &f.error {
            return format!("INVALID: {e} [{}]", crate::commands::decode::hex_string(&f.bytes));
        }
        let (code, _, name) = f.command.clone().unwrap_or_default();
        let fields = f.fields.iter().map(|x| x.text.as_str()).collect::<Vec<_>>().join(", ");
        match self.direction {
            Direction::Master => match crate::commands::decode::master_drive_broadcast(self.protocol, f) {
                Some(note) => format!("{code} {name}; {fields} ({note})"),
                None => format!("{code} {name}; {fields}"),
            },
            Direction::Drive if f.refusal => format!("→ refused: {code} {name}; {fields}"),
            Direction::Drive => format!("→ ok: {code} {name}; {fields}"),
        }
    }
}

/// Counts for one drive address.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AddressStats {
    /// Requests to it.
    pub requests: u64,
    /// Replies from it.
    pub replies: u64,
    /// Requests that got no reply.
    pub timeouts: u64,
    /// Damaged replies and refusals (exceptions, error codes).
    pub errors: u64,
    /// Reply latencies, in the order seen.
    pub latencies: Vec<Duration>,
}

impl AddressStats {
    /// The `q` quantile (0..1) of the latencies, nearest rank.
    pub fn latency_quantile(&self, q: f64) -> Option<Duration> {
        if self.latencies.is_empty() {
            return None;
        }
        let mut v = self.latencies.clone();
        v.sort();
        let rank = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len());
        Some(v[rank - 1])
    }
}

/// A request waiting for its reply.
#[derive(Clone, Debug)]
struct Pending {
    record: Record,
}

struct Port {
    side: Side,
    /// The protocols decoded, with their deframers.
    framers: Vec<(&'static str, Box<dyn Framer>)>,
    /// Auto-detection: every protocol's deframer, scoring the traffic.
    scouts: Vec<(&'static str, Box<dyn Framer>)>,
    last: Option<Duration>,
}

/// The listener: timestamped reads in, [`Record`]s out.
pub struct Analyzer {
    settings: Settings,
    t35: Duration,
    ports: Vec<Port>,
    active: Vec<&'static str>,
    /// Valid frames per protocol seen by the scouts.
    score: BTreeMap<&'static str, u64>,
    /// Reads held while the protocol is not known yet: (port, time, bytes).
    held: Vec<(usize, Duration, Vec<u8>)>,
    first: Option<Duration>,
    last: Option<Duration>,
    bytes: u64,
    pending: BTreeMap<&'static str, Pending>,
    stats: BTreeMap<(&'static str, u8), AddressStats>,
    /// Invalid frames no request was waiting for (garbled bytes, noise).
    garbled: u64,
    /// Frames counted, valid or not.
    frames: u64,
    /// Auto mode: the last reads, for a protocol found late.
    recent: std::collections::VecDeque<(usize, Duration, Vec<u8>)>,
    /// True while decoding bytes in which a protocol not decoded yet found a valid frame.
    foreign: bool,
}

impl Analyzer {
    /// A listener with `settings`; with no protocols given it finds them from the traffic.
    pub fn new(settings: Settings) -> Self {
        let (_, t35) = modbus_t15_t35(settings.baud);
        let auto = settings.protocols.is_empty();
        let ports = settings
            .sides
            .iter()
            .map(|&side| Port {
                side,
                framers: settings
                    .protocols
                    .iter()
                    .filter_map(|p| Some((*p, framer(p, side.direction())?)))
                    .collect(),
                scouts: if auto {
                    PROTOCOLS.iter().filter_map(|p| Some((*p, framer(p, side.direction())?))).collect()
                } else {
                    Vec::new()
                },
                last: None,
            })
            .collect();
        Analyzer {
            t35,
            ports,
            active: settings.protocols.clone(),
            settings,
            score: BTreeMap::new(),
            held: Vec::new(),
            first: None,
            last: None,
            bytes: 0,
            pending: BTreeMap::new(),
            stats: BTreeMap::new(),
            garbled: 0,
            frames: 0,
            recent: std::collections::VecDeque::new(),
            foreign: false,
        }
    }

    /// The protocols being decoded (found so far, in auto mode).
    pub fn protocols(&self) -> &[&'static str] {
        &self.active
    }

    /// Per (protocol, address) statistics.
    pub fn stats(&self) -> &BTreeMap<(&'static str, u8), AddressStats> {
        &self.stats
    }

    /// Invalid frames that no request was waiting for.
    pub fn garbled(&self) -> u64 {
        self.garbled
    }

    /// Frames reported, valid or not.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// The share of the time the line carried characters, from the first read to the last.
    pub fn bus_load(&self) -> f64 {
        let (Some(a), Some(b)) = (self.first, self.last) else { return 0.0 };
        let span = b.saturating_sub(a).as_secs_f64();
        if span <= 0.0 {
            return 0.0;
        }
        let busy = self.settings.format.wire_time(self.settings.baud, 1).as_secs_f64() * self.bytes as f64;
        (busy / span).min(1.0)
    }

    /// Bytes `bytes` read on `port` at `time`.
    pub fn push(&mut self, port: usize, time: Duration, bytes: &[u8]) -> Vec<Record> {
        let mut out = Vec::new();
        if bytes.is_empty() || port >= self.ports.len() {
            return out;
        }
        self.first.get_or_insert(time);
        self.last = Some(self.last.map_or(time, |l| l.max(time)));
        self.bytes += bytes.len() as u64;
        // A gap longer than t3.5 since the port's last read ends the frame in progress.
        if self.ports[port].last.is_some_and(|l| time.saturating_sub(l) > self.t35) {
            self.silence(port, time, Some(bytes), &mut out);
        }
        self.ports[port].last = Some(time);
        self.expire(time, &mut out);
        self.foreign = false;
        if !self.ports[port].scouts.is_empty() {
            let foreign = self.scout(port, time, bytes, &mut out);
            if self.active.is_empty() {
                self.held.push((port, time, bytes.to_vec()));
                self.settle(time, &mut out);
                return out;
            }
            self.foreign = foreign;
        }
        self.decode(port, time, bytes, &mut out);
        self.foreign = false;
        out
    }

    /// Time passes with nothing read: after [`QUIET`] a frame in progress ends, requests time out, detection
    /// settles after [`DETECT_WITHIN`] of traffic.
    pub fn tick(&mut self, now: Duration) -> Vec<Record> {
        let mut out = Vec::new();
        for port in 0..self.ports.len() {
            if self.ports[port].last.is_some_and(|l| now.saturating_sub(l) > self.t35.max(QUIET)) {
                self.silence(port, now, None, &mut out);
            }
        }
        self.expire(now, &mut out);
        if self.active.is_empty() && !self.held.is_empty() {
            self.settle(now, &mut out);
        }
        out
    }

    /// The end of the input: unfinished frames are reported, waiting requests time out.
    pub fn finish(&mut self, now: Duration) -> Vec<Record> {
        let mut out = Vec::new();
        if self.active.is_empty() && !self.held.is_empty() {
            self.choose(1);
            self.replay(&mut out);
        }
        for port in 0..self.ports.len() {
            let mut cuts = Vec::new();
            for (_, f) in &mut self.ports[port].scouts {
                f.finish(&mut Vec::new());
            }
            let names: Vec<&'static str> = self.ports[port].framers.iter().map(|(p, _)| *p).collect();
            for (i, p) in names.into_iter().enumerate() {
                cuts.clear();
                self.ports[port].framers[i].1.finish(&mut cuts);
                for c in std::mem::take(&mut cuts) {
                    self.frame(p, port, now, c, &mut out);
                }
            }
        }
        let waiting: Vec<_> = std::mem::take(&mut self.pending).into_values().collect();
        for p in waiting {
            self.no_reply(p, now, &mut out);
        }
        out
    }

    /// A silence on `port` before `next` (`None`: a long quiet): ends the frames in progress,
    /// except those that `next` completes (a late read, not a silence).
    fn silence(&mut self, port: usize, time: Duration, next: Option<&[u8]>, out: &mut Vec<Record>) {
        let side = self.ports[port].side;
        for (p, f) in &mut self.ports[port].scouts {
            if f.buffered() > 0 && !next.is_some_and(|b| f.spans(b)) {
                let mut cuts = Vec::new();
                f.silence(&mut cuts);
                for c in cuts {
                    if c.error.is_none() && f.valid(&c.bytes, side.direction()) {
                        *self.score.entry(*p).or_default() += 1;
                    }
                }
            }
        }
        let at = self.ports[port].last.unwrap_or(time);
        self.silence_framers(port, at, next, out);
    }

    /// [`Analyzer::silence`] for the decoding framers only.
    fn silence_framers(&mut self, port: usize, at: Duration, next: Option<&[u8]>, out: &mut Vec<Record>) {
        for i in 0..self.ports[port].framers.len() {
            let f = &self.ports[port].framers[i].1;
            if f.buffered() == 0 || next.is_some_and(|b| f.spans(b)) {
                continue;
            }
            let mut cuts = Vec::new();
            self.ports[port].framers[i].1.silence(&mut cuts);
            let p = self.ports[port].framers[i].0;
            for c in cuts {
                self.frame(p, port, at, c, out);
            }
        }
    }

    /// Runs the scouts over `bytes`, counting valid frames per protocol; adds a protocol found
    /// after the first choice (a second protocol on a mixed line).
    ///
    /// Returns true when a protocol not decoded yet found a valid frame in these bytes: the
    /// decoded protocols' rejects of them are then that protocol's traffic, not errors.
    fn scout(&mut self, port: usize, time: Duration, bytes: &[u8], out: &mut Vec<Record>) -> bool {
        let side = self.ports[port].side;
        let mut foreign = false;
        for i in 0..self.ports[port].scouts.len() {
            let mut cuts = Vec::new();
            self.ports[port].scouts[i].1.push(bytes, &mut cuts);
            let (p, f) = &self.ports[port].scouts[i];
            let p = *p;
            for c in cuts {
                if c.error.is_none() && f.valid(&c.bytes, side.direction()) {
                    *self.score.entry(p).or_default() += 1;
                    foreign |= !self.active.contains(&p);
                }
            }
        }
        if !self.active.is_empty() {
            let late: Vec<&'static str> = self
                .score
                .iter()
                .filter(|(p, n)| **n >= FOUND_FRAMES && !self.active.contains(p))
                .map(|(p, _)| *p)
                .collect();
            for p in late {
                self.activate(p);
                // Its first frames went by before it was known: decode them from the history.
                let recent: Vec<(usize, Duration, Vec<u8>)> = self.recent.iter().cloned().collect();
                for (port, t, b) in recent {
                    if let Some(i) = self.ports[port].framers.iter().position(|(x, _)| *x == p) {
                        self.decode_with(port, i, t, &b, out);
                    }
                }
            }
        }
        self.recent.push_back((port, time, bytes.to_vec()));
        while self.recent.len() > RECENT_READS
            || self.recent.front().is_some_and(|(_, t, _)| time.saturating_sub(*t) > RECENT_TIME)
        {
            self.recent.pop_front();
        }
        foreign
    }

    /// Chooses the protocols once one has [`SETTLE_FRAMES`] valid frames, or after
    /// [`DETECT_WITHIN`] of traffic with any.
    fn settle(&mut self, now: Duration, out: &mut Vec<Record>) {
        let best = self.score.values().copied().max().unwrap_or(0);
        let waited = self.first.is_some_and(|f| now.saturating_sub(f) >= DETECT_WITHIN);
        if best >= SETTLE_FRAMES || (waited && best > 0) {
            self.choose(if best >= SETTLE_FRAMES { FOUND_FRAMES } else { 1 });
            self.replay(out);
        }
    }

    fn choose(&mut self, min: u64) {
        let found: Vec<&'static str> =
            PROTOCOLS.iter().copied().filter(|p| self.score.get(p).is_some_and(|&n| n >= min)).collect();
        for p in found {
            self.activate(p);
        }
    }

    fn activate(&mut self, p: &'static str) {
        if self.active.contains(&p) {
            return;
        }
        self.active.push(p);
        for port in &mut self.ports {
            if let Some(f) = framer(p, port.side.direction()) {
                port.framers.push((p, f));
            }
        }
    }

    /// Decodes what was held while the protocol was being found.
    fn replay(&mut self, out: &mut Vec<Record>) {
        let held = std::mem::take(&mut self.held);
        let mut last: Vec<Option<Duration>> = vec![None; self.ports.len()];
        for (port, time, bytes) in held {
            if let Some(at) = last[port].filter(|l| time.saturating_sub(*l) > self.t35) {
                self.silence_framers(port, at, Some(&bytes), out);
            }
            last[port] = Some(time);
            self.expire(time, out);
            self.decode(port, time, &bytes, out);
        }
    }

    fn decode(&mut self, port: usize, time: Duration, bytes: &[u8], out: &mut Vec<Record>) {
        for i in 0..self.ports[port].framers.len() {
            self.decode_with(port, i, time, bytes, out);
        }
    }

    /// Feeds `bytes` to the port's framer `i` only.
    fn decode_with(&mut self, port: usize, i: usize, time: Duration, bytes: &[u8], out: &mut Vec<Record>) {
        let mut cuts = Vec::new();
        self.ports[port].framers[i].1.push(bytes, &mut cuts);
        let p = self.ports[port].framers[i].0;
        for c in cuts {
            self.frame(p, port, time, c, out);
        }
    }

    /// Requests whose reply is overdue.
    fn expire(&mut self, now: Duration, out: &mut Vec<Record>) {
        let timeout = self.settings.reply_timeout;
        let due: Vec<&'static str> = self
            .pending
            .iter()
            .filter(|(_, p)| now.saturating_sub(p.record.time) > timeout)
            .map(|(k, _)| *k)
            .collect();
        for k in due {
            if let Some(p) = self.pending.remove(k) {
                self.no_reply(p, now, out);
            }
        }
    }

    /// Reports the request `p` as unanswered, at `now` (when that became clear).
    fn no_reply(&mut self, p: Pending, now: Duration, out: &mut Vec<Record>) {
        let mut r = p.record;
        r.time = now.max(r.time);
        if let Some(a) = r.address() {
            self.stats.entry((r.protocol, a)).or_default().timeouts += 1;
        }
        r.kind = Kind::NoReply;
        out.push(r);
    }

    fn frame(
        &mut self,
        protocol: &'static str,
        port: usize,
        time: Duration,
        cut: Cut,
        out: &mut Vec<Record>,
    ) {
        let side = self.ports[port].side;
        let reply_due = self.pending.contains_key(protocol);
        let single = self.active.len() == 1 && !self.foreign;
        let parsed = match cut.error {
            Some(e) => Err(e),
            None => match side {
                Side::Only(d) => parse(protocol, &cut.bytes, d),
                Side::Both => {
                    parse_either(protocol, &cut.bytes, time, self.pending.get(protocol).map(|p| &p.record))
                }
            },
        };
        let frame = match parsed {
            Ok(f) => f,
            Err(error) => {
                // With several protocols on the line, each deframer rejects the others' frames:
                // only a lone protocol's rejects are errors on the line, and not those of bytes
                // in which another protocol just found a valid frame.
                if !single {
                    return;
                }
                let direction =
                    side.direction().unwrap_or(if reply_due { Direction::Drive } else { Direction::Master });
                let mut frame = FrameReport::invalid(0, &cut.bytes, Some(direction), error);
                // A damaged reply answers the waiting request: an error for that drive.
                if direction == Direction::Drive {
                    if let Some(p) = self.pending.remove(protocol) {
                        frame.target = p.record.frame.target;
                        if let Some(a) = p.record.address() {
                            self.stats.entry((protocol, a)).or_default().errors += 1;
                        }
                    } else {
                        self.garbled += 1;
                    }
                } else {
                    self.garbled += 1;
                }
                self.frames += 1;
                out.push(Record { time, protocol, direction, frame, latency: None, kind: Kind::Frame });
                return;
            }
        };
        self.frames += 1;
        let direction = frame.direction.unwrap_or(Direction::Master);
        let mut record = Record { time, protocol, direction, frame, latency: None, kind: Kind::Frame };
        match direction {
            Direction::Master => {
                if let Some(p) = self.pending.remove(protocol) {
                    self.no_reply(p, time, out);
                }
                let broadcast = record.frame.target.is_some_and(|t| t.is_broadcast());
                if let Some(a) = record.address().filter(|_| !broadcast) {
                    self.stats.entry((protocol, a)).or_default().requests += 1;
                }
                if !broadcast {
                    self.pending.insert(protocol, Pending { record: record.clone() });
                }
            }
            Direction::Drive => {
                let mut answered = None;
                if let Some(p) = self.pending.get(protocol) {
                    let same = match (p.record.frame.target, record.frame.target) {
                        (Some(Target::Unit(a)), Some(Target::Unit(b))) => a == b,
                        _ => true,
                    };
                    if same {
                        answered = self.pending.remove(protocol);
                    }
                }
                if let Some(p) = &answered {
                    record.latency = Some(time.saturating_sub(p.record.time));
                    // A reply that carries no address (Toshiba 1:1) is the waiting request's drive's.
                    if record.address().is_none() {
                        record.frame.target = p.record.frame.target;
                    }
                }
                if let Some(a) = record.address() {
                    let s = self.stats.entry((protocol, a)).or_default();
                    s.replies += 1;
                    if record.frame.refusal {
                        s.errors += 1;
                    }
                    if let Some(l) = record.latency {
                        s.latencies.push(l);
                    }
                }
            }
        }
        out.push(record);
    }
}
