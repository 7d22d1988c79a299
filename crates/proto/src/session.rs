//! Sans-IO sessions: the master's request/reply exchange and the slave's
//! listen/filter/answer loop, for any protocol that implements [`Protocol`].
//!
//! A session never reads a clock and never does I/O. The caller drives it:
//!
//! ```text
//! master.send(now, &request)?;               // queue one request (or send_frame: one already
//!                                            // encoded, its bytes sent as they are)
//! loop {
//!     if let Some(bytes) = master.poll_transmit(now) { write(bytes) }
//!     if let Some(event) = master.poll_event() { break event }   // reply, timeout, ...
//!     wait for input or until master.poll_timeout()
//!     master.handle_input(now, &input) or master.handle_timeout(now)
//! }
//! ```
//!
//! Timing is all in [`Timing`]: the response timeout, the turnaround delay after a broadcast
//! (no reply is due, so none is awaited), and the minimum silence before the next request
//! (Modbus t3.5, FC 2 characters). Every byte received pushes the next request back by the
//! minimum gap, so a master never talks over a drive that is still answering.

use core::time::Duration;

use crate::deframe::{Deframer, Event, FrameBuffer, Scanner, Stats};
use crate::error::{EmitError, FrameError, SessionError};
use crate::line::CharFormat;
use crate::time::Instant;

/// A wire protocol as a master and a slave use it.
pub trait Protocol {
    /// Frames a master receives (from drives).
    type ReplyScanner: Scanner;
    /// Frames a slave receives (from the master).
    type RequestScanner: Scanner;
    /// A typed request (master to drive).
    type Request<'a>;
    /// A typed reply (drive to master).
    type Reply<'a>;
    /// What a reply must match to answer a request (address, function, command).
    type Pending: Copy;

    /// A scanner for replies.
    fn reply_scanner(&self) -> Self::ReplyScanner;
    /// A scanner for requests.
    fn request_scanner(&self) -> Self::RequestScanner;
    /// Writes `req` into `out`; returns its length.
    fn emit_request(&self, req: &Self::Request<'_>, out: &mut [u8]) -> Result<usize, EmitError>;
    /// Writes `rep` into `out`; returns its length.
    fn emit_reply(&self, rep: &Self::Reply<'_>, out: &mut [u8]) -> Result<usize, EmitError>;
    /// Parses a whole request frame (checksum already checked by the scanner).
    fn parse_request<'a>(&self, bytes: &'a [u8]) -> Result<Self::Request<'a>, FrameError>;
    /// Parses a whole reply frame (checksum already checked by the scanner).
    fn parse_reply<'a>(&self, bytes: &'a [u8]) -> Result<Self::Reply<'a>, FrameError>;
    /// What a reply to `req` must match, or `None` when no reply is due (broadcast).
    fn pending(&self, req: &Self::Request<'_>) -> Option<Self::Pending>;
    /// Whether `rep` answers the request that `pending` describes.
    fn matches(&self, pending: &Self::Pending, rep: &Self::Reply<'_>) -> bool;
    /// What a reply to the request frame `bytes` (whole, checksum included, as
    /// [`emit_request`](Self::emit_request) writes it) must match, or `None` when no reply is
    /// due; an error when it is not a request of this protocol. For a frame encoded elsewhere
    /// (a drive profile) and sent as it is with [`MasterSession::send_frame`]. Default: the
    /// request parsed, then [`pending`](Self::pending); a protocol may look at the header only.
    fn pending_of_frame(&self, bytes: &[u8]) -> Result<Option<Self::Pending>, FrameError> {
        let req = self.parse_request(bytes)?;
        Ok(self.pending(&req))
    }
    /// Whether the reply frame `bytes` (checksum already checked by the scanner) answers the
    /// request that `pending` describes; an error when it is not a reply of this protocol. A
    /// master that hands the frame on to be parsed elsewhere (a drive profile) needs no more.
    /// Default: the reply parsed, then [`matches`](Self::matches); a protocol may look at the
    /// header only, so that the frame is parsed once, by whoever uses it.
    fn reply_matches(&self, pending: &Self::Pending, bytes: &[u8]) -> Result<bool, FrameError> {
        let rep = self.parse_reply(bytes)?;
        Ok(self.matches(pending, &rep))
    }
    /// How a slave numbered `me` treats `req`.
    fn disposition(&self, req: &Self::Request<'_>, me: u8) -> Disposition;
    /// How a slave numbered `me` treats a rejected request frame (some protocols answer a bad
    /// checksum addressed to them: TIP `N0004`, B800 `e 95`). Default: ignore it.
    fn rejected_disposition(&self, bytes: &[u8], error: &FrameError, me: u8) -> Disposition {
        let _ = (bytes, error, me);
        Disposition::NotMine
    }
}

/// The request and reply types of a [`Protocol`] and its four methods that emit and parse
/// them, for a protocol whose request type `$req` and reply type `$rep` each have
/// `emit(&self, out)` and `parse(bytes)` of their own: written inside its `impl Protocol`
/// block, `frame_methods!(Request, Reply);` (`frame_methods!(Request<'a>, Reply<'a>);` for
/// frames that borrow the bytes).
macro_rules! frame_methods {
    ($req:ident<'a>, $rep:ident<'a>) => {
        type Request<'a> = $req<'a>;
        type Reply<'a> = $rep<'a>;
        $crate::session::frame_methods!(@methods $req, $rep);
    };
    ($req:ident, $rep:ident) => {
        type Request<'a> = $req;
        type Reply<'a> = $rep;
        $crate::session::frame_methods!(@methods $req, $rep);
    };
    (@methods $req:ident, $rep:ident) => {
        fn emit_request(
            &self,
            req: &Self::Request<'_>,
            out: &mut [u8],
        ) -> Result<usize, $crate::error::EmitError> {
            req.emit(out)
        }
        fn emit_reply(
            &self,
            rep: &Self::Reply<'_>,
            out: &mut [u8],
        ) -> Result<usize, $crate::error::EmitError> {
            rep.emit(out)
        }
        fn parse_request<'a>(&self, bytes: &'a [u8]) -> Result<Self::Request<'a>, $crate::error::FrameError> {
            $req::parse(bytes)
        }
        fn parse_reply<'a>(&self, bytes: &'a [u8]) -> Result<Self::Reply<'a>, $crate::error::FrameError> {
            $rep::parse(bytes)
        }
    };
}
pub(crate) use frame_methods;

/// How a slave treats a frame it received.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Disposition {
    /// Addressed to this slave: act and answer.
    Mine,
    /// Addressed to several slaves: act; answer only if `reply` (TIP: the smallest matching
    /// number answers a wildcard; binary FF: inverter 00 answers).
    Broadcast {
        /// Whether this slave answers.
        reply: bool,
    },
    /// Not for this slave: stay silent.
    NotMine,
}

/// The times a master keeps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Timing {
    /// From the end of the request to a whole reply.
    pub response_timeout: Duration,
    /// Wait after a broadcast before the next request (no reply is due).
    pub turnaround: Duration,
    /// Silence after the last byte on the line before the next request.
    pub min_gap: Duration,
    /// While a reply is arriving, the deadline is at least this long after its last byte.
    pub inter_char_timeout: Duration,
    /// One character's time on the wire, to know when a request has left.
    pub char_time: Duration,
    /// Modbus RTU's t1.5: a silence longer than this between two bytes of a reply makes it
    /// incomplete, and it is discarded. `None` (the default): not enforced, because USB
    /// adapters and device servers deliver bytes in bursts with gaps of their own.
    pub max_char_gap: Option<Duration>,
}

impl Timing {
    /// Times for `baud` and `format` with the given response timeout and minimum gap in
    /// characters; turnaround after a broadcast is 100 ms (Modbus' usual value).
    pub fn new(baud: u32, format: CharFormat, response_timeout: Duration, gap: Duration) -> Self {
        let char_time = format.char_time(baud);
        Timing {
            response_timeout,
            turnaround: Duration::from_millis(100),
            min_gap: gap,
            inter_char_timeout: (char_time * 8).max(Duration::from_millis(20)),
            char_time,
            max_char_gap: None,
        }
    }
}

/// The outcome of one transaction.
#[derive(Debug, PartialEq)]
pub enum MasterEvent<R> {
    /// The reply that answers the request.
    Reply(R),
    /// A reply arrived but was damaged (bad checksum, cut short); retry.
    Corrupt(FrameError),
    /// A frame with a good checksum that does not follow the protocol.
    Invalid(FrameError),
    /// No reply within the response timeout.
    Timeout,
    /// A broadcast's turnaround delay has passed; no reply was due.
    BroadcastDone,
}

/// What a master session has counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MasterStats {
    /// Requests sent.
    pub requests: u64,
    /// Matching replies received.
    pub replies: u64,
    /// Transactions that timed out.
    pub timeouts: u64,
    /// Transactions ended by a damaged reply.
    pub corrupt: u64,
    /// Frames that answered nothing pending (late replies, other masters' traffic).
    pub unexpected: u64,
    /// The deframer's counts.
    pub deframer: Stats,
}

enum MasterState<K> {
    Idle,
    Queued { pending: Option<K> },
    Awaiting { pending: K, deadline: Instant },
    Turnaround { until: Instant },
    Done(Outcome),
}

#[derive(Clone, Copy)]
enum Outcome {
    Reply,
    Corrupt(FrameError),
    Invalid(FrameError),
    Timeout,
    BroadcastDone,
}

impl Outcome {
    /// The outcome as an event, a reply's made by `reply` (parsed or as bytes).
    fn event<R>(self, reply: impl FnOnce() -> MasterEvent<R>) -> MasterEvent<R> {
        match self {
            Outcome::Reply => reply(),
            Outcome::Corrupt(e) => MasterEvent::Corrupt(e),
            Outcome::Invalid(e) => MasterEvent::Invalid(e),
            Outcome::Timeout => MasterEvent::Timeout,
            Outcome::BroadcastDone => MasterEvent::BroadcastDone,
        }
    }
}

/// The master side of a protocol: one request at a time.
pub struct MasterSession<P: Protocol> {
    proto: P,
    timing: Timing,
    deframer: Deframer<P::ReplyScanner>,
    tx: <P::RequestScanner as Scanner>::Buffer,
    tx_len: usize,
    rx: <P::ReplyScanner as Scanner>::Buffer,
    rx_len: usize,
    state: MasterState<P::Pending>,
    ready_at: Instant,
    stats: MasterStats,
    /// When the last bytes of the reply in progress were heard.
    last_rx: Option<Instant>,
}

impl<P: Protocol> MasterSession<P> {
    /// A session for `proto` with `timing`.
    pub fn new(proto: P, timing: Timing) -> Self {
        let deframer = Deframer::new(proto.reply_scanner());
        MasterSession {
            proto,
            timing,
            deframer,
            tx: FrameBuffer::zeroed(),
            tx_len: 0,
            rx: FrameBuffer::zeroed(),
            rx_len: 0,
            state: MasterState::Idle,
            ready_at: Instant::ZERO,
            stats: MasterStats::default(),
            last_rx: None,
        }
    }

    /// The protocol.
    pub fn protocol(&self) -> &P {
        &self.proto
    }

    /// The timing in force.
    pub fn timing(&self) -> Timing {
        self.timing
    }

    /// Changes the timing (for example a per-drive response timeout).
    pub fn set_timing(&mut self, timing: Timing) {
        self.timing = timing;
    }

    /// Counts so far.
    pub fn stats(&self) -> MasterStats {
        MasterStats { deframer: self.deframer.stats(), ..self.stats }
    }

    /// True when a new request may be submitted.
    pub fn is_idle(&self) -> bool {
        matches!(self.state, MasterState::Idle)
    }

    /// The earliest time the next request may go on the wire.
    pub fn ready_at(&self) -> Instant {
        self.ready_at
    }

    /// Queues `req`. It goes on the wire at [`poll_transmit`](Self::poll_transmit) once the
    /// line has been quiet for the minimum gap.
    pub fn send(&mut self, now: Instant, req: &P::Request<'_>) -> Result<(), SessionError> {
        let _ = now;
        if !self.is_idle() {
            return Err(SessionError::Busy);
        }
        let len = self.proto.emit_request(req, self.tx.as_mut())?;
        self.queue(len, self.proto.pending(req));
        Ok(())
    }

    /// Queues `frame`, a request already encoded (whole, checksum included), whose reply must
    /// match `pending` (`None`: no reply is due; [`Protocol::pending_of_frame`] tells it from the
    /// frame). The bytes go on the wire as they are, at [`poll_transmit`](Self::poll_transmit).
    pub fn send_frame(
        &mut self,
        now: Instant,
        frame: &[u8],
        pending: Option<P::Pending>,
    ) -> Result<(), SessionError> {
        let _ = now;
        if !self.is_idle() {
            return Err(SessionError::Busy);
        }
        let tx = self.tx.as_mut();
        let Some(room) = tx.get_mut(..frame.len()) else {
            return Err(EmitError::BufferTooSmall { needed: frame.len(), capacity: tx.len() }.into());
        };
        room.copy_from_slice(frame);
        self.queue(frame.len(), pending);
        Ok(())
    }

    /// The request of `len` bytes in the transmit buffer waits for the line, its reply to match
    /// `pending`.
    fn queue(&mut self, len: usize, pending: Option<P::Pending>) {
        self.tx_len = len;
        self.last_rx = None;
        self.state = MasterState::Queued { pending };
    }

    /// The request bytes to write now, once; `None` until the line is ready.
    pub fn poll_transmit(&mut self, now: Instant) -> Option<&[u8]> {
        let MasterState::Queued { pending } = self.state else {
            return None;
        };
        if now < self.ready_at {
            return None;
        }
        // A new exchange: forget whatever half frame the line left behind.
        self.deframer.clear();
        let sent = now + self.timing.char_time * self.tx_len as u32;
        self.state = match pending {
            Some(pending) => MasterState::Awaiting { pending, deadline: sent + self.timing.response_timeout },
            None => MasterState::Turnaround { until: sent + self.timing.turnaround },
        };
        self.ready_at = sent + self.timing.min_gap;
        self.stats.requests += 1;
        Some(&self.tx.as_ref()[..self.tx_len])
    }

    /// The next instant the caller must call [`handle_timeout`](Self::handle_timeout) (or
    /// [`poll_transmit`](Self::poll_transmit), for a queued request).
    pub fn poll_timeout(&self) -> Option<Instant> {
        match self.state {
            MasterState::Queued { .. } => Some(self.ready_at),
            MasterState::Awaiting { deadline, .. } => Some(deadline),
            MasterState::Turnaround { until } => Some(until),
            MasterState::Idle | MasterState::Done(_) => None,
        }
    }

    /// Bytes from the line.
    pub fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        if bytes.is_empty() {
            return;
        }
        let quiet = now + self.timing.min_gap;
        if quiet > self.ready_at {
            self.ready_at = quiet;
        }
        if let MasterState::Awaiting { deadline, .. } = &mut self.state {
            let floor = now + self.timing.inter_char_timeout;
            if floor > *deadline {
                *deadline = floor;
            }
        }
        let awaiting = matches!(self.state, MasterState::Awaiting { .. });
        let MasterSession { proto, deframer, state, rx, rx_len, stats, .. } = self;
        let mut sink = Sink { proto, state, rx: rx.as_mut(), rx_len, stats };
        if let (Some(gap), Some(last)) = (self.timing.max_char_gap, self.last_rx) {
            // Modbus over serial line: "If a silent interval of more than 1.5 character times
            // occurs between two characters, the message frame is declared incomplete".
            if awaiting && deframer.buffered() > 0 && now.saturating_since(last) > gap {
                deframer.finish(&mut |e| sink.on_event(e));
            }
        }
        self.last_rx = Some(now);
        if !matches!(self.state, MasterState::Awaiting { .. }) && awaiting {
            // The reply in progress was declared incomplete: the exchange has ended.
            return;
        }
        let MasterSession { proto, deframer, state, rx, rx_len, stats, .. } = self;
        let mut sink = Sink { proto, state, rx: rx.as_mut(), rx_len, stats };
        deframer.push(bytes, &mut |e| sink.on_event(e));
        if awaiting && matches!(self.state, MasterState::Done(_)) {
            // The answer has been heard whole, so the request is off the line: the next one
            // may follow the gap after the answer's last byte, also where the link (a pty, a
            // TCP server) brought the answer sooner than the request's own wire time.
            self.ready_at = quiet;
        }
    }

    /// The line has been silent for t3.5 (Modbus RTU): the bytes held are a whole frame.
    pub fn handle_silence(&mut self, _now: Instant) {
        let MasterSession { proto, deframer, state, rx, rx_len, stats, .. } = self;
        let mut sink = Sink { proto, state, rx: rx.as_mut(), rx_len, stats };
        deframer.silence(&mut |e| sink.on_event(e));
    }

    /// Time has passed: ends a wait whose deadline is due.
    pub fn handle_timeout(&mut self, now: Instant) {
        match self.state {
            MasterState::Awaiting { deadline, .. } if now >= deadline => {
                // A reply cut off by silence may still be whole by its own length.
                self.handle_silence(now);
                if let MasterState::Awaiting { .. } = self.state {
                    self.stats.timeouts += 1;
                    self.state = MasterState::Done(Outcome::Timeout);
                }
            }
            MasterState::Turnaround { until } if now >= until => {
                self.state = MasterState::Done(Outcome::BroadcastDone);
            }
            _ => {}
        }
    }

    /// The outcome of the transaction, once it has one; the session is then idle again.
    pub fn poll_event(&mut self) -> Option<MasterEvent<P::Reply<'_>>> {
        let outcome = self.take_outcome()?;
        let (proto, frame) = (&self.proto, &self.rx.as_ref()[..self.rx_len]);
        Some(outcome.event(|| match proto.parse_reply(frame) {
            Ok(r) => MasterEvent::Reply(r),
            Err(e) => MasterEvent::Invalid(e),
        }))
    }

    /// Like [`poll_event`](Self::poll_event), with the reply as the frame's bytes, not parsed:
    /// for a master that hands the frame to whoever parses it (a drive profile), so that it is
    /// parsed once. Its checksum is checked and it answers the request
    /// ([`Protocol::reply_matches`]).
    pub fn poll_frame_event(&mut self) -> Option<MasterEvent<&[u8]>> {
        let outcome = self.take_outcome()?;
        let frame = &self.rx.as_ref()[..self.rx_len];
        Some(outcome.event(|| MasterEvent::Reply(frame)))
    }

    /// The finished transaction's outcome, once; the session is idle after it.
    fn take_outcome(&mut self) -> Option<Outcome> {
        let MasterState::Done(outcome) = self.state else {
            return None;
        };
        self.state = MasterState::Idle;
        Some(outcome)
    }

    /// The bytes of the last reply delivered by [`poll_event`](Self::poll_event), as received.
    pub fn reply_bytes(&self) -> &[u8] {
        &self.rx.as_ref()[..self.rx_len]
    }

    /// Abandons the transaction in flight (the caller gave up); the line gap still applies.
    pub fn abort(&mut self) {
        self.state = MasterState::Idle;
        self.last_rx = None;
    }
}

struct Sink<'s, P: Protocol> {
    proto: &'s P,
    state: &'s mut MasterState<P::Pending>,
    rx: &'s mut [u8],
    rx_len: &'s mut usize,
    stats: &'s mut MasterStats,
}

impl<P: Protocol> Sink<'_, P> {
    fn on_event(&mut self, e: Event<'_>) {
        let MasterState::Awaiting { pending, .. } = *self.state else {
            if let Event::Frame { .. } = e {
                self.stats.unexpected += 1;
            }
            return;
        };
        match e {
            Event::Frame { bytes, .. } => match self.proto.reply_matches(&pending, bytes) {
                Ok(true) => {
                    self.rx[..bytes.len()].copy_from_slice(bytes);
                    *self.rx_len = bytes.len();
                    self.stats.replies += 1;
                    *self.state = MasterState::Done(Outcome::Reply);
                }
                Ok(false) => self.stats.unexpected += 1,
                Err(err) => {
                    self.stats.corrupt += 1;
                    *self.state = MasterState::Done(Outcome::Invalid(err));
                }
            },
            Event::Rejected { error, .. } => {
                self.stats.corrupt += 1;
                *self.state = MasterState::Done(Outcome::Corrupt(error));
            }
        }
    }
}

/// A request as a slave's handler sees it.
#[derive(Debug)]
pub enum Incoming<'a, R> {
    /// A well-formed request this slave must act on.
    Request {
        /// The request.
        request: R,
        /// True when it was sent to several slaves.
        broadcast: bool,
    },
    /// A request addressed to this slave that could not be parsed or failed its checksum;
    /// some protocols answer it with an error reply.
    Rejected {
        /// The frame's bytes.
        bytes: &'a [u8],
        /// Why it was rejected.
        error: FrameError,
    },
}

/// Where a slave's handler puts its reply.
pub struct Responder<'s, P: Protocol> {
    proto: &'s P,
    out: &'s mut [u8],
    len: &'s mut usize,
    may_reply: bool,
}

impl<P: Protocol> Responder<'_, P> {
    /// Whether a reply is due (false for broadcasts that this slave must not answer).
    pub fn may_reply(&self) -> bool {
        self.may_reply
    }

    /// Queues `rep` as the answer. Ignored where no reply is due.
    pub fn reply(&mut self, rep: &P::Reply<'_>) -> Result<(), EmitError> {
        if !self.may_reply {
            return Ok(());
        }
        *self.len = self.proto.emit_reply(rep, self.out)?;
        Ok(())
    }

    /// Queues raw bytes as the answer (for tests that must send a broken frame).
    pub fn reply_raw(&mut self, bytes: &[u8]) -> Result<(), EmitError> {
        if !self.may_reply {
            return Ok(());
        }
        crate::error::need(self.out, bytes.len())?;
        self.out[..bytes.len()].copy_from_slice(bytes);
        *self.len = bytes.len();
        Ok(())
    }
}

/// What a slave session has counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SlaveStats {
    /// Requests addressed to this slave (or broadcast) and handed to the handler.
    pub requests: u64,
    /// Replies sent.
    pub replies: u64,
    /// Requests for other slaves, ignored.
    pub ignored: u64,
    /// Well-framed requests that did not parse.
    pub invalid: u64,
    /// The deframer's counts.
    pub deframer: Stats,
}

/// The slave side of a protocol: filters requests by address and hands them to a handler.
pub struct SlaveSession<P: Protocol> {
    deframer: Deframer<P::RequestScanner>,
    core: SlaveCore<P>,
}

struct SlaveCore<P: Protocol> {
    proto: P,
    address: u8,
    response_delay: Duration,
    tx: <P::RequestScanner as Scanner>::Buffer,
    tx_len: usize,
    tx_at: Instant,
    stats: SlaveStats,
}

impl<P: Protocol> SlaveSession<P> {
    /// A slave numbered `address` that answers `response_delay` after a request ends.
    pub fn new(proto: P, address: u8, response_delay: Duration) -> Self {
        let deframer = Deframer::new(proto.request_scanner());
        SlaveSession {
            deframer,
            core: SlaveCore {
                proto,
                address,
                response_delay,
                tx: FrameBuffer::zeroed(),
                tx_len: 0,
                tx_at: Instant::ZERO,
                stats: SlaveStats::default(),
            },
        }
    }

    /// The slave's number.
    pub fn address(&self) -> u8 {
        self.core.address
    }

    /// Changes the slave's number.
    pub fn set_address(&mut self, address: u8) {
        self.core.address = address;
    }

    /// Changes the delay between the end of a request and the start of the reply.
    pub fn set_response_delay(&mut self, delay: Duration) {
        self.core.response_delay = delay;
    }

    /// The protocol.
    pub fn protocol(&self) -> &P {
        &self.core.proto
    }

    /// Counts so far.
    pub fn stats(&self) -> SlaveStats {
        SlaveStats { deframer: self.deframer.stats(), ..self.core.stats }
    }

    /// Bytes from the line; each request for this slave goes to `handler`, which may answer
    /// through the [`Responder`].
    pub fn handle_input<H>(&mut self, now: Instant, bytes: &[u8], handler: &mut H)
    where
        H: FnMut(Instant, Incoming<'_, P::Request<'_>>, &mut Responder<'_, P>),
    {
        let SlaveSession { deframer, core } = self;
        deframer.push(bytes, &mut |e| core.dispatch(now, e, handler));
    }

    /// The line has been silent for t3.5 (Modbus RTU): the bytes held are a whole frame.
    pub fn handle_silence<H>(&mut self, now: Instant, handler: &mut H)
    where
        H: FnMut(Instant, Incoming<'_, P::Request<'_>>, &mut Responder<'_, P>),
    {
        let SlaveSession { deframer, core } = self;
        deframer.silence(&mut |e| core.dispatch(now, e, handler));
    }

    /// The reply to write, once its response delay has passed.
    pub fn poll_transmit(&mut self, now: Instant) -> Option<&[u8]> {
        let core = &mut self.core;
        if core.tx_len == 0 || now < core.tx_at {
            return None;
        }
        let len = core::mem::take(&mut core.tx_len);
        Some(&core.tx.as_ref()[..len])
    }

    /// When a queued reply is due.
    pub fn poll_timeout(&self) -> Option<Instant> {
        (self.core.tx_len > 0).then_some(self.core.tx_at)
    }
}

impl<P: Protocol> SlaveCore<P> {
    fn dispatch<H>(&mut self, now: Instant, e: Event<'_>, handler: &mut H)
    where
        H: FnMut(Instant, Incoming<'_, P::Request<'_>>, &mut Responder<'_, P>),
    {
        let me = self.address;
        let (incoming, disposition) = match e {
            Event::Frame { bytes, .. } => match self.proto.parse_request(bytes) {
                Ok(request) => {
                    let d = self.proto.disposition(&request, me);
                    (Incoming::Request { request, broadcast: matches!(d, Disposition::Broadcast { .. }) }, d)
                }
                Err(error) => {
                    self.stats.invalid += 1;
                    let d = self.proto.rejected_disposition(bytes, &error, me);
                    (Incoming::Rejected { bytes, error }, d)
                }
            },
            Event::Rejected { bytes, error, .. } => {
                let d = self.proto.rejected_disposition(bytes, &error, me);
                (Incoming::Rejected { bytes, error }, d)
            }
        };
        let may_reply = match disposition {
            Disposition::NotMine => {
                self.stats.ignored += 1;
                return;
            }
            Disposition::Mine => true,
            Disposition::Broadcast { reply } => reply,
        };
        self.stats.requests += 1;
        let mut len = 0;
        let mut responder = Responder { proto: &self.proto, out: self.tx.as_mut(), len: &mut len, may_reply };
        handler(now, incoming, &mut responder);
        if len > 0 {
            self.tx_len = len;
            self.tx_at = now + self.response_delay;
            self.stats.replies += 1;
        }
    }
}
