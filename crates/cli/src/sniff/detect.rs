//! Finding a line's baud rate and character format from its traffic alone.
//!
//! A receiver set to the wrong baud rate or format turns good characters into other bytes or
//! framing and parity errors; only the right setting gives frames with valid checksums. So the
//! sniffer listens a short while at each candidate setting and keeps the one whose bytes give
//! the most valid frames of any protocol ([`score`], [`pick`]). On a real port the candidates are
//! tried one after the other on the live line; [`receive`] models what a UART at one setting makes
//! of a line at another, bit by bit, so the same choice is tested on recorded traffic (on a
//! pseudo-terminal the baud rate is not real, so this is where baud and format detection are
//! tested).
//!
//! How long to listen at each candidate is the [`Search`]'s business, without I/O and with time
//! as an argument: until the candidate gives enough valid frames, or it has heard enough bursts
//! of traffic, or a time budget scaled to the gaps heard between bursts (a master polling once a
//! second needs longer than one polling every 20 ms). [`find_setting`] runs a search on a
//! [`SettingPort`]: the serial port, or in the tests recorded traffic replayed at its real timing
//! through the UART model.
//!
//! A receiver checks only the first stop bit, so 1 and 2 stop bits cannot be told apart: the
//! candidates have one stop bit, except the 7-bit format without parity, which no common
//! protocol uses with one (Modbus ASCII's 7N2).

use std::io;
use std::time::Duration;

use drivebus_proto::line::{CharFormat, Parity};

use super::analyze::PROTOCOLS;

/// The baud rates tried, the common ones first.
pub const BAUDS: [u32; 6] = [9600, 19200, 38400, 57600, 115200, 4800];

/// The character formats tried.
pub const FORMATS: [CharFormat; 6] = [
    CharFormat::EVEN_8E1,
    CharFormat::NONE_8N1,
    CharFormat { data_bits: 8, parity: Parity::Odd, stop_bits: 1 },
    CharFormat::NONE_7N2,
    CharFormat { data_bits: 7, parity: Parity::Even, stop_bits: 1 },
    CharFormat { data_bits: 7, parity: Parity::Odd, stop_bits: 1 },
];

/// Every (baud, format) candidate, in the order they are tried.
#[cfg(test)]
pub fn candidates() -> Vec<(u32, CharFormat)> {
    candidates_for(None, None)
}

/// The candidates left when the baud rate, the format or both are known: a given baud is tried
/// with every format, a given format at every baud; both given leaves that one setting.
pub fn candidates_for(baud: Option<u32>, format: Option<CharFormat>) -> Vec<(u32, CharFormat)> {
    let bauds: Vec<u32> = baud.map_or(BAUDS.to_vec(), |b| vec![b]);
    let formats: Vec<CharFormat> = format.map_or(FORMATS.to_vec(), |f| vec![f]);
    bauds.iter().flat_map(|&b| formats.iter().map(move |&f| (b, f))).collect()
}

/// A candidate giving this many valid frames ends the search: it is the line's setting.
pub const ENOUGH_FRAMES: u64 = 4;
/// A candidate that heard this many bursts (reads after a pause) without enough valid frames has
/// had its chance (three exchanges, request and reply apart)...
pub const ENOUGH_BURSTS: u32 = 6;
/// ...once it listened at least this long.
pub const MIN_LISTEN: Duration = Duration::from_millis(200);
/// No candidate listens longer than this.
pub const MAX_LISTEN: Duration = Duration::from_secs(3);
/// With the gaps heard between bursts known, a candidate listens at most this many times the
/// longest (a master's polling period: a few exchanges at any polling rate).
pub const GAPS_PER_CANDIDATE: u32 = 3;
/// Reads this far apart are two bursts (longer than a USB adapter's latency timer, shorter than
/// any master's polling period).
pub const BURST_GAP: Duration = Duration::from_millis(15);
/// With nothing heard at all for this long, the search gives up (an idle or miswired line).
pub const GIVE_UP: Duration = Duration::from_secs(5);

/// What a [`Search`] wants next.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Step {
    /// Keep listening at the current candidate, at most until this time.
    Listen(Duration),
    /// Set the port to this candidate and listen there.
    Switch(u32, CharFormat),
    /// The search is over: the best candidate, or `None` when none gave a valid frame.
    Done(Option<((u32, CharFormat), Score)>),
}

/// The search for a line's baud rate and format, one candidate after the other, without I/O:
/// the caller reads at [`Search::current`], gives the bytes with their time to
/// [`Search::push`], and asks [`Search::poll`] what to do.
#[derive(Clone, Debug)]
pub struct Search {
    candidates: Vec<(u32, CharFormat)>,
    /// Index of the candidate listened at.
    at: usize,
    /// When listening at it began (the first bytes heard, for the first candidate).
    since: Option<Duration>,
    /// When the search began.
    began: Duration,
    bytes: Vec<u8>,
    bursts: u32,
    last_read: Option<Duration>,
    /// Bursts heard in all.
    bursts_heard: u32,
    /// The longest pause between two bursts heard.
    longest_gap: Duration,
    scores: Vec<((u32, CharFormat), Score)>,
    done: bool,
}

impl Search {
    /// A search over `candidates` (see [`candidates_for`]) beginning at `now`.
    pub fn new(candidates: Vec<(u32, CharFormat)>, now: Duration) -> Search {
        Search {
            candidates,
            at: 0,
            since: None,
            began: now,
            bytes: Vec::new(),
            bursts: 0,
            last_read: None,
            bursts_heard: 0,
            longest_gap: Duration::ZERO,
            scores: Vec::new(),
            done: false,
        }
    }

    /// The candidate to listen at now (`None` when there are none).
    pub fn current(&self) -> Option<(u32, CharFormat)> {
        self.candidates.get(self.at).copied()
    }

    /// Bytes read at the current candidate at `now`.
    pub fn push(&mut self, now: Duration, bytes: &[u8]) {
        if bytes.is_empty() || self.done {
            return;
        }
        self.since.get_or_insert(now);
        match self.last_read {
            Some(last) if now.saturating_sub(last) < BURST_GAP => {}
            Some(last) => {
                self.longest_gap = self.longest_gap.max(now.saturating_sub(last));
                self.bursts += 1;
                self.bursts_heard += 1;
            }
            None => {
                self.bursts += 1;
                self.bursts_heard += 1;
            }
        }
        self.last_read = Some(now);
        self.bytes.extend_from_slice(bytes);
    }

    /// The time budget of one candidate: [`MAX_LISTEN`] until the traffic's pace is known,
    /// then [`GAPS_PER_CANDIDATE`] times the longest gap heard, within [`MIN_LISTEN`] and
    /// [`MAX_LISTEN`].
    pub fn budget(&self) -> Duration {
        if self.bursts_heard < ENOUGH_BURSTS {
            return MAX_LISTEN;
        }
        (self.longest_gap * GAPS_PER_CANDIDATE).clamp(MIN_LISTEN, MAX_LISTEN)
    }

    /// What to do at `now`.
    pub fn poll(&mut self, now: Duration) -> Step {
        if self.done {
            return Step::Done(pick(&self.scores));
        }
        let Some(current) = self.current() else { return self.finish() };
        let Some(since) = self.since else {
            // Nothing heard yet at all: wait at the first candidate, up to GIVE_UP.
            if self.bursts_heard == 0 && now.saturating_sub(self.began) >= GIVE_UP {
                return self.finish();
            }
            let limit = if self.bursts_heard == 0 { self.began + GIVE_UP } else { now + self.budget() };
            return Step::Listen(limit);
        };
        let score = score(&self.bytes);
        if score.frames >= ENOUGH_FRAMES {
            self.scores.push((current, score));
            self.done = true;
            return Step::Done(Some((current, score)));
        }
        let listened = now.saturating_sub(since);
        let heard_enough = self.bursts >= ENOUGH_BURSTS && listened >= MIN_LISTEN;
        if !heard_enough && listened < self.budget() {
            return Step::Listen(since + self.budget());
        }
        self.scores.push((current, score));
        self.next(now)
    }

    /// Passes over the current candidate (the port refused it) at `now`.
    pub fn skip(&mut self, now: Duration) -> Step {
        if self.done {
            return Step::Done(pick(&self.scores));
        }
        self.next(now)
    }

    fn next(&mut self, now: Duration) -> Step {
        self.at += 1;
        self.bytes.clear();
        self.bursts = 0;
        // The next candidate's window begins now, once traffic is known to be there.
        self.since = self.since.map(|_| now);
        self.last_read = None;
        match self.current() {
            Some((b, f)) => Step::Switch(b, f),
            None => self.finish(),
        }
    }

    fn finish(&mut self) -> Step {
        self.done = true;
        Step::Done(pick(&self.scores))
    }
}

/// A port the search listens on: set to a candidate, read with a short timeout, and its clock.
pub trait SettingPort {
    /// Sets the receiver to `baud` and `format` (bytes received before are dropped).
    fn set(&mut self, baud: u32, format: CharFormat) -> io::Result<()>;
    /// Reads what came, waiting at most the port's short timeout (0: nothing came).
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize>;
    /// The time now, on the clock reads are stamped with.
    fn now(&self) -> Duration;
}

/// Runs a [`Search`] over `candidates` on `port` until it is done or `stop` says so: the line's
/// setting and what it gave, or `None` when no candidate gave a valid frame. A candidate the
/// port refuses (a baud rate its driver lacks) is passed over.
pub fn find_setting(
    port: &mut impl SettingPort,
    candidates: Vec<(u32, CharFormat)>,
    stop: impl Fn() -> bool,
) -> io::Result<Option<((u32, CharFormat), Score)>> {
    let mut search = Search::new(candidates, port.now());
    let mut buf = [0u8; 4096];
    let mut set = search.current();
    loop {
        if stop() {
            return Ok(None);
        }
        if let Some((b, f)) = set.take() {
            if port.set(b, f).is_err() {
                match search.skip(port.now()) {
                    Step::Done(found) => return Ok(found),
                    _ => set = search.current(),
                }
                continue;
            }
        }
        let n = port.read(&mut buf)?;
        let now = port.now();
        search.push(now, &buf[..n]);
        match search.poll(now) {
            Step::Listen(_) => {}
            Step::Switch(b, f) => set = Some((b, f)),
            Step::Done(found) => return Ok(found),
        }
    }
}

/// What one candidate setting gave.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Score {
    /// The protocol with the most valid frames, if any.
    pub protocol: Option<&'static str>,
    /// Its valid frames.
    pub frames: u64,
    /// Bytes in them.
    pub bytes: u64,
}

/// The protocol whose deframer finds the most valid frames in `bytes`, and how many.
pub fn score(bytes: &[u8]) -> Score {
    let mut best = Score::default();
    for p in PROTOCOLS {
        let (mut frames, mut used) = (0u64, 0u64);
        for item in frames_of(p, bytes) {
            frames += 1;
            used += item as u64;
        }
        if used > best.bytes {
            best = Score { protocol: Some(p), frames, bytes: used };
        }
    }
    best
}

/// The lengths of the valid frames of `protocol` in `bytes` (either direction).
fn frames_of(protocol: &'static str, bytes: &[u8]) -> Vec<usize> {
    let mut out = Vec::new();
    let mut a = super::analyze::Analyzer::new(super::analyze::Settings {
        protocols: vec![protocol],
        baud: 9600,
        format: CharFormat::NONE_8N1,
        reply_timeout: Duration::from_secs(3600),
        sides: vec![super::analyze::Side::Both],
    });
    let mut records = a.push(0, Duration::ZERO, bytes);
    records.extend(a.finish(Duration::ZERO));
    for r in records {
        if r.valid() && r.kind == super::analyze::Kind::Frame {
            out.push(r.frame.bytes.len());
        }
    }
    out
}

/// The best candidate: most bytes in valid frames; on a tie, the first tried. `None` when no
/// candidate gave a valid frame.
pub fn pick(scores: &[((u32, CharFormat), Score)]) -> Option<((u32, CharFormat), Score)> {
    let mut best: Option<((u32, CharFormat), Score)> = None;
    for &(c, s) in scores {
        if s.frames > 0 && best.map_or(true, |(_, b)| s.bytes > b.bytes) {
            best = Some((c, s));
        }
    }
    best
}

/// A burst of characters on the line: when its first start bit begins, and its bytes, sent back
/// to back.
#[cfg(test)]
pub type Burst = (Duration, Vec<u8>);

/// What a UART set to `rx_baud` and `rx` receives from a line carrying `bursts` at `baud` and
/// `format`. It waits for a falling edge, samples each bit in its middle, checks the parity (if
/// it has one) and the first stop bit, and delivers a character with a parity or framing error
/// as 00, as a Linux port does by default (neither IGNPAR nor PARMRK).
#[cfg(test)]
pub fn receive(bursts: &[Burst], baud: u32, format: CharFormat, rx_baud: u32, rx: CharFormat) -> Vec<u8> {
    // The line's level as a list of (time in ns, level from then on); idle is high.
    let bit = 1e9 / baud as f64;
    let mut edges: Vec<(f64, bool)> = Vec::new();
    let mut level = true;
    let mut set = |t: f64, l: bool, edges: &mut Vec<(f64, bool)>| {
        if l != level {
            edges.push((t, l));
            level = l;
        }
    };
    for (start, bytes) in bursts {
        let mut t = start.as_nanos() as f64;
        for &b in bytes {
            for l in char_bits(b, format) {
                set(t, l, &mut edges);
                t += bit;
            }
        }
    }
    let level_at = |t: f64| -> bool {
        match edges.partition_point(|&(et, _)| et <= t) {
            0 => true,
            i => edges[i - 1].1,
        }
    };
    let rx_bit = 1e9 / rx_baud as f64;
    let mut out = Vec::new();
    let mut t = 0.0;
    loop {
        // The next falling edge at or after t.
        let from = edges.partition_point(|&(et, _)| et < t);
        let Some(&(start, _)) = edges[from..].iter().find(|&&(_, l)| !l) else { break };
        let sample = |k: usize| level_at(start + (k as f64 + 0.5) * rx_bit);
        let mut value = 0u8;
        let mut ones = 0;
        for i in 0..rx.data_bits as usize {
            if sample(1 + i) {
                value |= 1 << i;
                ones += 1;
            }
        }
        let mut n = 1 + rx.data_bits as usize;
        let mut ok = true;
        if rx.parity != Parity::None {
            let p = sample(n);
            let total = ones + p as u32;
            ok &= match rx.parity {
                Parity::Even => total % 2 == 0,
                _ => total % 2 == 1,
            };
            n += 1;
        }
        ok &= sample(n);
        out.push(if ok { value } else { 0 });
        t = start + (n as f64 + 0.5) * rx_bit;
    }
    out
}

/// A character's bits on the wire: start, data LSB first, parity, stop.
#[cfg(test)]
fn char_bits(b: u8, f: CharFormat) -> Vec<bool> {
    let mut bits = vec![false];
    let mut ones = 0;
    for i in 0..f.data_bits {
        let one = b >> i & 1 == 1;
        ones += one as u32;
        bits.push(one);
    }
    match f.parity {
        Parity::None => {}
        Parity::Even => bits.push(ones % 2 == 1),
        Parity::Odd => bits.push(ones % 2 == 0),
    }
    bits.extend(std::iter::repeat(true).take(f.stop_bits as usize));
    bits
}

/// Finds the baud rate, format and protocol of recorded line traffic, trying every candidate.
#[cfg(test)]
pub fn detect(bursts: &[Burst], baud: u32, format: CharFormat) -> Option<((u32, CharFormat), Score)> {
    let scores: Vec<_> =
        candidates().into_iter().map(|c| (c, score(&receive(bursts, baud, format, c.0, c.1)))).collect();
    pick(&scores)
}
