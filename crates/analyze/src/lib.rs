//! # drivebus-analyze
//!
//! What a passive listener makes of the bytes on a line, without I/O: frames cut by each
//! protocol's deframer plus the line's silences (Modbus RTU t3.5), the direction of each frame,
//! requests paired with their replies and the latency between them, per-address statistics and
//! the bus load. The caller gives timestamped reads; `drivebus sniff` and a standby gateway's
//! bus owner (`drivebus_link::owner`) do the I/O. [`report`] reads one frame in the manual's
//! words (`drivebus decode` prints it too).
//!
//! In four parts: [`framing`] (each protocol's deframer behind one trait, and parsing a frame),
//! [`pairing`] (a frame's direction on a shared pair, requests and their replies, missing
//! replies), [`statistics`] (per-address counts, latencies, the bus load) and [`detection`]
//! (which protocols are on the line, found from the traffic).

use std::collections::BTreeMap;
use std::time::Duration;

use drivebus_proto::line::{modbus_t15_t35, CharFormat};
use drivebus_proto::protocol::WireProtocol;
use drivebus_proto::{Direction, Target};
use serde_json::{json, Value};

use crate::report::{render_json, FrameReport};

mod detection;
mod framing;
mod pairing;
pub mod report;
mod statistics;

use framing::{framer, Framer};
use pairing::Pending;
pub use statistics::AddressStats;

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
    /// For a reply: the bytes of the request it answers.
    pub request: Option<Vec<u8>>,
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
        let mut v = render_json(self.protocol, &crate::report::Item::Frame(self.frame.clone()))
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
            return format!("INVALID: {e} [{}]", crate::report::hex_string(&f.bytes));
        }
        let (code, _, name) = f.command.clone().unwrap_or_default();
        let fields = f.fields.iter().map(|x| x.text.as_str()).collect::<Vec<_>>().join(", ");
        match self.direction {
            Direction::Master => match crate::report::master_drive_broadcast(self.protocol, f) {
                Some(note) => format!("{code} {name}; {fields} ({note})"),
                None => format!("{code} {name}; {fields}"),
            },
            Direction::Drive if f.refusal => format!("→ refused: {code} {name}; {fields}"),
            Direction::Drive => format!("→ ok: {code} {name}; {fields}"),
        }
    }
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
    /// False for a listener that runs for good: the reply latencies are not kept.
    keep_latencies: bool,
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
            keep_latencies: true,
        }
    }

    /// The listener for a line heard for good (a standby gateway's): the counts are kept, the
    /// reply latencies ([`AddressStats::latencies`]) are not, so its memory stays bounded.
    pub fn endless(mut self) -> Self {
        self.keep_latencies = false;
        self
    }

    /// The protocols being decoded (found so far, in auto mode).
    pub fn protocols(&self) -> &[&'static str] {
        &self.active
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
    /// settles after [`detection::DETECT_WITHIN`] of traffic.
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
            self.steer(p, at, out);
        }
    }

    fn decode(&mut self, port: usize, time: Duration, bytes: &[u8], out: &mut Vec<Record>) {
        for i in 0..self.ports[port].framers.len() {
            self.decode_with(port, i, time, bytes, out);
        }
    }

    /// Feeds `bytes` to the port's framer `i` only; a [`pairing::STEERED`] protocol's on a port
    /// that hears both directions a byte at a time, as a line delivers them: each frame found
    /// may change how the next is read ([`Analyzer::steer`]), however many frames one read
    /// holds.
    fn decode_with(&mut self, port: usize, i: usize, time: Duration, bytes: &[u8], out: &mut Vec<Record>) {
        let p = self.ports[port].framers[i].0;
        let steered = self.ports[port].side == Side::Both && pairing::STEERED.contains(&p);
        let step = if steered { 1 } else { bytes.len().max(1) };
        let mut cuts = Vec::new();
        for chunk in bytes.chunks(step) {
            self.ports[port].framers[i].1.push(chunk, &mut cuts);
            if cuts.is_empty() {
                continue;
            }
            for c in cuts.drain(..) {
                self.frame(p, port, time, c, out);
            }
            self.steer(p, time, out);
        }
    }
}
