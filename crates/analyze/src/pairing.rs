//! Pairing: which way a frame went on a pair that carries both directions, each reply matched
//! with its request and timed, requests left without a reply.

use std::time::Duration;

use drivebus_proto::protocol::WireProtocol;
use drivebus_proto::{Direction, Target};

use super::framing::{parse, Cut};
use super::{Analyzer, Kind, Record, Side};
use crate::report::FrameReport;

/// A frame identical to the waiting request (a Modbus 05/06 reply echoes its request) that
/// comes later than this after it is the master's retry, not the drive's echo: drives answer
/// within tens of milliseconds, masters retry after their timeout (100 ms and more).
pub const ECHO_WITHIN: Duration = Duration::from_millis(60);

/// Reads a frame heard on a pair that carries both directions. With no request waiting, as a
/// request first. With one waiting, as its reply first (a Modbus reply can look like a request,
/// and 06's reply is its request's echo), unless that reading names another drive or the frame
/// is the request again after [`ECHO_WITHIN`]: then as a request.
pub(super) fn parse_either(
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

/// The protocols whose frames' length depends on who sent them in a way the bytes cannot
/// settle, so a listener of both directions reads a frame as the reply while a request waits
/// ([`Analyzer::steer`]): TIP binary, whose `R` is 5 bytes from the master and 7 from a drive
/// (plus INV-NO), and the first 6 bytes of a reply whose first data byte equals the request's
/// SUM are that whole request again. In the others either reading frames alike (a Modbus RTU
/// listener predicts both lengths), and a master that polls again before a reply must still be
/// heard at once.
pub(super) const STEERED: [&str; 1] = [WireProtocol::ToshibaBinary.name()];

/// A request waiting for its reply.
#[derive(Clone, Debug)]
pub(super) struct Pending {
    pub(super) record: Record,
}

impl Analyzer {
    /// Requests whose reply is overdue.
    pub(super) fn expire(&mut self, now: Duration, out: &mut Vec<Record>) {
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
            self.steer(k, now, out);
        }
    }

    /// On a port that hears both directions, reads what comes next of a [`STEERED`] protocol
    /// as the drive's reply while a request waits, and as either otherwise. Frames the bytes in
    /// progress make when read again are reported at `time`.
    pub(super) fn steer(&mut self, protocol: &'static str, time: Duration, out: &mut Vec<Record>) {
        if !STEERED.contains(&protocol) {
            return;
        }
        // Each frame found may change what waits: a few rounds settle it.
        for _ in 0..4 {
            let from = self.pending.contains_key(protocol).then_some(Direction::Drive);
            let mut found = false;
            for port in 0..self.ports.len() {
                if self.ports[port].side != Side::Both {
                    continue;
                }
                for i in 0..self.ports[port].framers.len() {
                    if self.ports[port].framers[i].0 != protocol {
                        continue;
                    }
                    let mut cuts = Vec::new();
                    self.ports[port].framers[i].1.expect(from, &mut cuts);
                    for c in cuts {
                        found = true;
                        self.frame(protocol, port, time, c, out);
                    }
                }
            }
            if !found {
                return;
            }
        }
    }

    /// Reports the request `p` as unanswered, at `now` (when that became clear).
    pub(super) fn no_reply(&mut self, p: Pending, now: Duration, out: &mut Vec<Record>) {
        let mut r = p.record;
        r.time = now.max(r.time);
        if let Some(a) = r.address() {
            self.stats.entry((r.protocol, a)).or_default().timeouts += 1;
        }
        r.kind = Kind::NoReply;
        out.push(r);
    }

    pub(super) fn frame(
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
                out.push(Record {
                    time,
                    protocol,
                    direction,
                    frame,
                    latency: None,
                    request: None,
                    kind: Kind::Frame,
                });
                return;
            }
        };
        self.frames += 1;
        let direction = frame.direction.unwrap_or(Direction::Master);
        let mut record =
            Record { time, protocol, direction, frame, latency: None, request: None, kind: Kind::Frame };
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
                    record.request = Some(p.record.frame.bytes.clone());
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
                    if let Some(l) = record.latency.filter(|_| self.keep_latencies) {
                        s.latencies.push(l);
                    }
                }
            }
        }
        out.push(record);
    }
}
