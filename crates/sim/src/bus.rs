//! The virtual RS-485 line: many devices on one pair of wires, paced at the real baud rate.
//!
//! Every byte takes its wire time (`CharFormat::char_time`: 1.146 ms for an 11-bit character
//! at 9600 baud) and reaches every other device when its last bit has arrived. The line is half
//! duplex: a talker that starts while another is still sending garbles the bytes that overlap,
//! for both. Faults can be injected at run time: byte corruption, dropped bytes, extra latency,
//! a silent device.
//!
//! The line is sans-IO like the protocol sessions: it never reads a clock. The caller advances
//! it with [`VirtualLine::advance_to`] and asks [`VirtualLine::next_deadline`] when something will
//! happen next; a test drives it on a virtual clock, the simulator's runtime maps it to wall time.
//! The master (the program under test, on a pty or TCP) is master [`MASTER`]; more masters can
//! share the line ([`VirtualLine::add_master`]: a standby gateway beside an active one), each
//! hearing every other talker, masters and devices alike. Devices are numbered from 1 in the
//! order they are added.

use std::collections::VecDeque;
use std::time::Duration;

use drivebus_proto::line::{modbus_t15_t35, CharFormat};
use drivebus_proto::Instant;

pub use crate::drive::Device;
use crate::drive::VirtualDrive;
use crate::rng::Rng;

/// The first external master (every line has it).
pub const MASTER: usize = 0;

/// The most bursts a log keeps unread.
const LOG_KEEP: usize = 4096;

/// Who puts a character on the line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Talker {
    /// An external master, by its number (0 = [`MASTER`]).
    Master(usize),
    /// A device, by its port (1, 2, ...).
    Device(usize),
}

/// Faults to inject, settable at run time.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Faults {
    /// Probability that a byte arrives with one bit flipped.
    pub corrupt_rate: f64,
    /// Probability that a byte is lost.
    pub drop_rate: f64,
    /// Added to every device's answer.
    pub extra_latency: Duration,
}

/// What the line has carried.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LineStats {
    /// Bytes put on the line by the masters.
    pub master_bytes: u64,
    /// Bytes put on the line by devices.
    pub device_bytes: u64,
    /// Bytes garbled by two talkers at once.
    pub collisions: u64,
    /// Frames (a talker's run of characters without a gap) with at least one byte garbled by
    /// two talkers at once: both frames of a collision count.
    pub garbled_frames: u64,
    /// Bytes corrupted by injected noise.
    pub corrupted: u64,
    /// Bytes lost to injected drops.
    pub dropped: u64,
    /// Time the line carried a signal.
    pub busy: Duration,
}

#[derive(Clone, Copy, Debug)]
struct Slot {
    /// When the character's last bit arrives.
    end: Instant,
    byte: u8,
    talker: Talker,
    /// The run of characters (frame) this one belongs to.
    run: u64,
    garbled: bool,
}

struct Port {
    device: Option<Box<dyn Device + Send>>,
    silent: bool,
    /// When this talker's current transmission ends.
    tx_end: Instant,
    /// This talker's current run of characters.
    run: u64,
}

/// An external master's end of the line.
struct MasterPort {
    /// When this master's current transmission ends.
    tx_end: Instant,
    /// This master's current run of characters.
    run: u64,
    /// Bytes that reached this master, not yet read.
    inbox: VecDeque<u8>,
    /// This master's frames garbled by another talker at once (counted in
    /// [`LineStats::garbled_frames`] too).
    garbled_frames: u64,
}

/// One RS-485 line with its devices.
pub struct VirtualLine {
    baud: u32,
    format: CharFormat,
    char_time: Duration,
    t35: Duration,
    ports: Vec<Port>,
    /// The external masters, [`MASTER`] first.
    masters: Vec<MasterPort>,
    /// Characters on the wire, in arrival order.
    wire: VecDeque<Slot>,
    /// The last run number handed out.
    runs: u64,
    /// Runs already counted in [`LineStats::garbled_frames`] (the most recent few).
    garbled_runs: VecDeque<u64>,
    now: Instant,
    last_byte_end: Instant,
    silence_due: bool,
    faults: Faults,
    rng: Rng,
    stats: LineStats,
    /// What a listener on the line hears (both directions), when a tap is attached.
    tap: Option<VecDeque<u8>>,
    /// Every burst delivered with who sent it, when a log is attached.
    log: Option<VecDeque<(Talker, Vec<u8>)>>,
}

impl VirtualLine {
    /// An empty line at `baud` with `format`, at simulated time `now`.
    pub fn new(baud: u32, format: CharFormat, now: Instant) -> Self {
        let (_, t35) = modbus_t15_t35(baud);
        VirtualLine {
            baud,
            format,
            char_time: format.char_time(baud),
            t35,
            ports: vec![Port { device: None, silent: false, tx_end: now, run: 0 }],
            masters: vec![MasterPort { tx_end: now, run: 0, inbox: VecDeque::new(), garbled_frames: 0 }],
            wire: VecDeque::new(),
            runs: 0,
            garbled_runs: VecDeque::new(),
            now,
            last_byte_end: now,
            silence_due: false,
            faults: Faults::default(),
            rng: Rng::new(1),
            stats: LineStats::default(),
            tap: None,
            log: None,
        }
    }

    /// The baud rate.
    pub fn baud(&self) -> u32 {
        self.baud
    }

    /// The character format.
    pub fn format(&self) -> CharFormat {
        self.format
    }

    /// With `pacing` (the default) every character takes its wire time; without, characters
    /// arrive the moment they are sent (collisions cannot happen then). For benchmarks of
    /// the programs on the other side of a pty or TCP port.
    pub fn set_pacing(&mut self, pacing: bool) {
        self.char_time = if pacing { self.format.char_time(self.baud) } else { Duration::ZERO };
    }

    /// One character's wire time.
    pub fn char_time(&self) -> Duration {
        self.char_time
    }

    /// Adds a device; returns its port number (1, 2, ...).
    pub fn add_device(&mut self, device: Box<dyn Device + Send>) -> usize {
        self.ports.push(Port { device: Some(device), silent: false, tx_end: self.now, run: 0 });
        self.ports.len() - 1
    }

    /// Adds another external master; returns its number (1, 2, ...; [`MASTER`] is 0). It hears
    /// the drives and every other master, and they hear it.
    pub fn add_master(&mut self) -> usize {
        self.masters.push(MasterPort { tx_end: self.now, run: 0, inbox: VecDeque::new(), garbled_frames: 0 });
        self.masters.len() - 1
    }

    /// How many frames of master `master` another talker garbled (a master's share of
    /// [`LineStats::garbled_frames`]): on a line with two masters, tells the one that sent into
    /// another's traffic from the one sent into. 0 for an unknown master.
    pub fn master_garbled_frames(&self, master: usize) -> u64 {
        self.masters.get(master).map_or(0, |m| m.garbled_frames)
    }

    /// Number of external masters (at least 1).
    pub fn masters(&self) -> usize {
        self.masters.len()
    }

    /// The device on `port`.
    pub fn device_mut(&mut self, port: usize) -> Option<&mut (dyn Device + Send + 'static)> {
        self.ports.get_mut(port)?.device.as_deref_mut()
    }

    /// The virtual drive on `port`, if that device is one, brought up to the line's time.
    pub fn drive(&mut self, port: usize) -> Option<&dyn VirtualDrive> {
        let now = self.now;
        let d = self.ports.get_mut(port)?.device.as_deref_mut()?;
        d.advance_to(now);
        d.as_drive()
    }

    /// The virtual drive on `port`, mutable, brought up to the line's time.
    pub fn drive_mut(&mut self, port: usize) -> Option<&mut dyn VirtualDrive> {
        let now = self.now;
        let d = self.ports.get_mut(port)?.device.as_deref_mut()?;
        d.advance_to(now);
        d.as_drive_mut()
    }

    /// Number of devices.
    pub fn devices(&self) -> usize {
        self.ports.len() - 1
    }

    /// Silences a device (it hears but never answers) or lets it talk again.
    pub fn set_silent(&mut self, port: usize, silent: bool) {
        if let Some(p) = self.ports.get_mut(port) {
            p.silent = silent;
        }
    }

    /// True if the device on `port` is silenced.
    pub fn is_silent(&self, port: usize) -> bool {
        self.ports.get(port).is_some_and(|p| p.silent)
    }

    /// The faults in force.
    pub fn faults(&self) -> Faults {
        self.faults
    }

    /// Sets the faults to inject.
    pub fn set_faults(&mut self, faults: Faults) {
        self.faults = faults;
    }

    /// Seeds the fault generator (for repeatable tests).
    pub fn seed(&mut self, seed: u64) {
        self.rng = Rng::new(seed);
    }

    /// What the line has carried.
    pub fn stats(&self) -> LineStats {
        self.stats
    }

    /// The simulated time the line has reached.
    pub fn now(&self) -> Instant {
        self.now
    }

    /// The master writes `bytes` at `now`: they go on the wire one character time apart,
    /// after whatever the master is still sending.
    pub fn master_write(&mut self, now: Instant, bytes: &[u8]) {
        self.master_write_from(MASTER, now, bytes);
    }

    /// Master `master` (see [`VirtualLine::add_master`]) writes `bytes` at `now`. An unknown
    /// master's bytes are ignored.
    pub fn master_write_from(&mut self, master: usize, now: Instant, bytes: &[u8]) {
        if master >= self.masters.len() {
            return;
        }
        self.advance_to(now);
        let now = self.now;
        self.transmit_at(Talker::Master(master), now, bytes);
    }

    /// Attaches a tap: from now on every character that arrives on the line, from the master
    /// or a device, is also kept for [`VirtualLine::tap_read`], as a passive listener hears it
    /// (garbled, corrupted or dropped alike).
    pub fn attach_tap(&mut self) {
        self.tap.get_or_insert_with(VecDeque::new);
    }

    /// Bytes the tap has heard since the last call (nothing without [`VirtualLine::attach_tap`]).
    pub fn tap_read(&mut self, out: &mut Vec<u8>) {
        if let Some(t) = self.tap.as_mut() {
            out.extend(t.drain(..));
        }
    }

    /// True when the tap holds bytes not yet read.
    pub fn tap_pending(&self) -> bool {
        self.tap.as_ref().is_some_and(|t| !t.is_empty())
    }

    /// Attaches a log: from now on every burst delivered is also kept with who sent it, for
    /// [`VirtualLine::log_read`] (a monitor that tells the masters' requests from the drives'
    /// answers on a line with several masters).
    pub fn attach_log(&mut self) {
        self.log.get_or_insert_with(VecDeque::new);
    }

    /// The bursts logged since the last call, with who sent each (at most the last 4096).
    pub fn log_read(&mut self, out: &mut Vec<(Talker, Vec<u8>)>) {
        if let Some(l) = self.log.as_mut() {
            out.extend(l.drain(..));
        }
    }

    /// Bytes that have reached the master by now.
    pub fn master_read(&mut self, out: &mut Vec<u8>) {
        self.master_read_to(MASTER, out);
    }

    /// Bytes that have reached master `master` by now: the drives' and the other masters'.
    pub fn master_read_to(&mut self, master: usize, out: &mut Vec<u8>) {
        if let Some(m) = self.masters.get_mut(master) {
            out.extend(m.inbox.drain(..));
        }
    }

    /// True when bytes wait for the master.
    pub fn master_has_input(&self) -> bool {
        !self.masters[MASTER].inbox.is_empty()
    }

    /// The next time something happens on the line (a byte arrives, a device answers, a
    /// silence is detected), if anything is pending.
    pub fn next_deadline(&self) -> Option<Instant> {
        let other = self.next_other_event();
        // Bytes go out a burst at a time: the end of the front talker's run of characters,
        // or the first other event before it.
        let burst = self.burst_end(other.unwrap_or(Instant(u64::MAX)));
        match (burst, other) {
            (Some(b), Some(o)) => Some(b.min(o)),
            (b, o) => b.or(o),
        }
    }

    /// The earliest silence or device timer.
    fn next_other_event(&self) -> Option<Instant> {
        let mut next: Option<Instant> = None;
        let mut consider = |t: Instant| {
            next = Some(next.map_or(t, |n| n.min(t)));
        };
        if let Some(t) = self.silence_at() {
            consider(t);
        }
        for p in &self.ports {
            if let Some(t) = p.device.as_ref().and_then(|d| d.poll_timeout()) {
                consider(t.max(self.now));
            }
        }
        next
    }

    /// When receivers will have heard t3.5 of silence, unless a character starts before.
    fn silence_at(&self) -> Option<Instant> {
        if !self.silence_due {
            return None;
        }
        let at = self.last_byte_end + self.t35;
        match self.wire.front() {
            Some(s) if s.end - self.char_time < at => None,
            _ => Some(at),
        }
    }

    /// The end of the last character of the front talker's run that ends by `limit` (or the
    /// front character's end, if even that one ends later).
    fn burst_end(&self, limit: Instant) -> Option<Instant> {
        let first = self.wire.front()?;
        let mut end = first.end;
        for s in self.wire.iter().skip(1) {
            if s.talker != first.talker || s.end > limit {
                break;
            }
            end = s.end;
        }
        Some(end)
    }

    /// Advances the line to `now`: delivers every byte whose last bit has arrived, signals
    /// silences, and lets devices answer, in time order.
    pub fn advance_to(&mut self, now: Instant) {
        if now < self.now {
            return;
        }
        let mut batch: Vec<u8> = Vec::new();
        loop {
            // The next event at or before `now`.
            let next_byte = self.wire.front().map(|s| s.end).filter(|&t| t <= now);
            let next_silence = self.silence_at().filter(|&t| t <= now);
            let next_device = self
                .ports
                .iter()
                .filter_map(|p| p.device.as_ref().and_then(|d| d.poll_timeout()))
                .filter(|&t| t <= now)
                .min();
            let t = [next_byte, next_silence, next_device].into_iter().flatten().min();
            let Some(t) = t else { break };
            let t = t.max(self.now);
            self.now = t;
            if next_byte.is_some_and(|b| b <= t) {
                // Deliver the front talker's run of characters in one batch, up to `now` or
                // the next other event, whichever comes first: devices see whole bursts, as a
                // UART FIFO gives them, and a frame is complete when its last byte is.
                let limit = [Some(now), next_silence, next_device].into_iter().flatten().min().unwrap_or(now);
                let Some(first) = self.wire.front().copied() else { continue };
                batch.clear();
                let talker = first.talker;
                let mut last = t;
                while let Some(s) = self.wire.front().copied() {
                    if s.talker != talker || (s.end > limit && s.end > t) {
                        break;
                    }
                    self.wire.pop_front();
                    last = s.end;
                    if let Some(b) = self.arrive(s) {
                        batch.push(b);
                    }
                }
                self.now = last.max(self.now);
                self.last_byte_end = last;
                self.silence_due = true;
                self.deliver(talker, last, &batch);
                continue;
            }
            if next_silence == Some(t) {
                self.silence_due = false;
                for p in self.ports.iter_mut() {
                    if let Some(d) = p.device.as_mut() {
                        d.silence(t);
                    }
                }
                continue;
            }
            // A device's timer: let it move and perhaps answer.
            for i in 1..self.ports.len() {
                let due =
                    self.ports[i].device.as_ref().and_then(|d| d.poll_timeout()).is_some_and(|d| d <= t);
                if !due {
                    continue;
                }
                let out = self.ports[i].device.as_mut().and_then(|d| {
                    d.advance_to(t);
                    d.poll_transmit(t)
                });
                if let Some(bytes) = out {
                    if !self.ports[i].silent {
                        self.transmit_at(Talker::Device(i), t + self.faults.extra_latency, &bytes);
                    }
                }
            }
        }
        self.now = now;
    }

    /// Runs the line event by event until `end` (bytes delivered, silences, answers in order).
    pub fn run_until(&mut self, end: Instant) {
        while let Some(t) = self.next_deadline().filter(|&t| t <= end) {
            self.advance_to(t);
        }
        self.advance_to(end);
    }

    /// Brings every device's own state (motor ramps) up to the line's time. Devices otherwise
    /// advance lazily, when they hear bytes or their timers fire; a control interface calls
    /// this before it reads their state.
    pub fn advance_devices(&mut self) {
        let now = self.now;
        for p in self.ports.iter_mut() {
            if let Some(d) = p.device.as_mut() {
                d.advance_to(now);
            }
        }
    }

    fn arrive(&mut self, s: Slot) -> Option<u8> {
        if self.rng.chance(self.faults.drop_rate) {
            self.stats.dropped += 1;
            return None;
        }
        let mut b = s.byte;
        if s.garbled {
            b ^= 0xA5;
        }
        if self.rng.chance(self.faults.corrupt_rate) {
            b ^= 1 << self.rng.below(8);
            self.stats.corrupted += 1;
        }
        Some(b)
    }

    fn deliver(&mut self, talker: Talker, t: Instant, bytes: &[u8]) {
        if bytes.is_empty() {
            return;
        }
        for (i, m) in self.masters.iter_mut().enumerate() {
            if talker != Talker::Master(i) {
                m.inbox.extend(bytes.iter().copied());
            }
        }
        if let Some(tap) = self.tap.as_mut() {
            tap.extend(bytes.iter().copied());
        }
        if let Some(log) = self.log.as_mut() {
            // Nobody reading (the first master's client not connected): the oldest go.
            if log.len() >= LOG_KEEP {
                log.pop_front();
            }
            log.push_back((talker, bytes.to_vec()));
        }
        for (i, p) in self.ports.iter_mut().enumerate() {
            if talker == Talker::Device(i) {
                continue;
            }
            if let Some(d) = p.device.as_mut() {
                d.advance_to(t);
                d.receive(t, bytes);
            }
        }
    }

    fn transmit_at(&mut self, talker: Talker, at: Instant, bytes: &[u8]) {
        if bytes.is_empty() {
            return;
        }
        let (tx_end, run) = match talker {
            Talker::Master(m) => {
                let p = &mut self.masters[m];
                (&mut p.tx_end, &mut p.run)
            }
            Talker::Device(i) => {
                let p = &mut self.ports[i];
                (&mut p.tx_end, &mut p.run)
            }
        };
        // Characters sent back to back continue the talker's frame; after a gap, a new one.
        if at > *tx_end || *run == 0 {
            self.runs += 1;
            *run = self.runs;
        }
        let run = *run;
        let start = at.max(*tx_end);
        let mut end = start;
        let mut new_slots = Vec::with_capacity(bytes.len());
        for &byte in bytes {
            end = end + self.char_time;
            new_slots.push(Slot { end, byte, talker, run, garbled: false });
        }
        *tx_end = end;
        // Half duplex: characters of other talkers that overlap in time garble, both ways.
        let mut garbled_runs = Vec::new();
        for s in self.wire.iter_mut() {
            if s.talker == talker {
                continue;
            }
            let s_start = s.end - self.char_time;
            for n in new_slots.iter_mut() {
                let n_start = n.end - self.char_time;
                if n_start < s.end && s_start < n.end {
                    if !s.garbled {
                        self.stats.collisions += 1;
                    }
                    s.garbled = true;
                    n.garbled = true;
                    garbled_runs.push((s.run, s.talker));
                    garbled_runs.push((n.run, n.talker));
                }
            }
        }
        for (r, who) in garbled_runs {
            if !self.garbled_runs.contains(&r) {
                self.stats.garbled_frames += 1;
                if let Talker::Master(m) = who {
                    self.masters[m].garbled_frames += 1;
                }
                if self.garbled_runs.len() == 64 {
                    self.garbled_runs.pop_front();
                }
                self.garbled_runs.push_back(r);
            }
        }
        if matches!(talker, Talker::Master(_)) {
            self.stats.master_bytes += bytes.len() as u64;
        } else {
            self.stats.device_bytes += bytes.len() as u64;
        }
        self.stats.busy += self.char_time * bytes.len() as u32;
        for n in new_slots {
            // Keep arrival order.
            let pos = self.wire.iter().rposition(|s| s.end <= n.end).map_or(0, |p| p + 1);
            self.wire.insert(pos, n);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::{Arc, Mutex};

    /// What a test device heard: (arrival, bytes) per delivery.
    type Heard = Arc<Mutex<Vec<(Instant, Vec<u8>)>>>;

    /// Answers every byte string it hears with the same bytes, after `delay`.
    struct Echo {
        heard: Heard,
        pending: Option<(Instant, Vec<u8>)>,
        delay: Duration,
        silences: Arc<Mutex<u32>>,
        answered: usize,
    }

    impl Device for Echo {
        fn receive(&mut self, now: Instant, bytes: &[u8]) {
            self.heard.lock().unwrap().push((now, bytes.to_vec()));
        }
        fn silence(&mut self, now: Instant) {
            *self.silences.lock().unwrap() += 1;
            // Answer only what was heard since the last answer.
            let heard = self.heard.lock().unwrap();
            let all: Vec<u8> = heard[self.answered..].iter().flat_map(|(_, b)| b.clone()).collect();
            self.answered = heard.len();
            drop(heard);
            if !all.is_empty() {
                self.pending = Some((now + self.delay, all));
            }
        }
        fn poll_transmit(&mut self, now: Instant) -> Option<Vec<u8>> {
            match &self.pending {
                Some((t, _)) if *t <= now => self.pending.take().map(|(_, b)| b),
                _ => None,
            }
        }
        fn poll_timeout(&self) -> Option<Instant> {
            self.pending.as_ref().map(|(t, _)| *t)
        }
    }

    fn echo(delay_ms: u64) -> (Echo, Heard, Arc<Mutex<u32>>) {
        let heard = Arc::new(Mutex::new(Vec::new()));
        let silences = Arc::new(Mutex::new(0));
        (
            Echo {
                heard: heard.clone(),
                pending: None,
                delay: Duration::from_millis(delay_ms),
                silences: silences.clone(),
                answered: 0,
            },
            heard,
            silences,
        )
    }

    /// A line at `baud` 8E1 from time 0 with an echo answering after `delay_ms` on port 1; what
    /// the echo heard and how many silences it saw.
    fn echo_line(baud: u32, delay_ms: u64) -> (VirtualLine, Heard, Arc<Mutex<u32>>) {
        let mut line = VirtualLine::new(baud, CharFormat::EVEN_8E1, Instant::ZERO);
        let (dev, heard, silences) = echo(delay_ms);
        line.add_device(Box::new(dev));
        (line, heard, silences)
    }

    fn run_until_idle(line: &mut VirtualLine) {
        while let Some(t) = line.next_deadline() {
            line.advance_to(t);
        }
    }

    #[test]
    fn without_pacing_bytes_arrive_at_once() {
        let (mut line, heard, _) = echo_line(9600, 0);
        line.set_pacing(false);
        let t = Instant::from_millis(3);
        line.master_write(t, &[1, 2, 3]);
        line.advance_to(t);
        assert_eq!(*heard.lock().unwrap(), vec![(t, vec![1, 2, 3])]);
        assert_eq!(line.stats().collisions, 0);
        // The echo answers at the silence, and it is at the master at that instant.
        let silence = line.next_deadline().unwrap();
        line.advance_to(silence);
        let mut out = Vec::new();
        line.master_read(&mut out);
        assert_eq!(out, [1, 2, 3]);
    }

    #[test]
    fn bytes_take_their_wire_time() {
        let (mut line, heard, _) = echo_line(9600, 5);
        line.master_write(Instant::ZERO, &[1, 2, 3]);
        // 11 bits at 9600: the first byte is whole after 1.146 ms, the third after 3.438 ms.
        line.advance_to(Instant::from_nanos(1_145_833));
        assert!(heard.lock().unwrap().is_empty());
        line.advance_to(Instant::from_nanos(1_145_834));
        assert_eq!(heard.lock().unwrap().len(), 1);
        line.advance_to(Instant::from_nanos(3 * 1_145_834));
        let got: Vec<u8> = heard.lock().unwrap().iter().flat_map(|(_, b)| b.clone()).collect();
        assert_eq!(got, [1, 2, 3]);
    }

    #[test]
    fn device_answers_after_silence_and_delay_and_master_reads_it() {
        let (mut line, _, silences) = echo_line(9600, 5);
        line.master_write(Instant::ZERO, &[0xAB, 0xCD]);
        run_until_idle(&mut line);
        assert_eq!(*silences.lock().unwrap(), 2, "after the request and after the reply");
        let mut got = Vec::new();
        line.master_read(&mut got);
        assert_eq!(got, [0xAB, 0xCD]);
        // Request 2 chars + t3.5 + 5 ms + 2 chars of reply.
        let expect = 4 * 1_145_834u64 / 1000 + 4010 + 5000;
        let now = line.now().as_micros();
        assert!(now >= expect && now <= expect + 4100, "{now} vs {expect}");
        assert_eq!(line.stats().master_bytes, 2);
        assert_eq!(line.stats().device_bytes, 2);
    }

    #[test]
    fn the_tap_hears_both_directions_when_they_arrive() {
        let (mut line, _, _) = echo_line(9600, 5);
        line.attach_tap();
        line.master_write(Instant::ZERO, &[0xAB, 0xCD]);
        let mut tap = Vec::new();
        // Nothing before the first character's last bit.
        line.advance_to(Instant::from_nanos(1_145_833));
        line.tap_read(&mut tap);
        assert!(tap.is_empty());
        // The request once it is on the line, then the reply: as a listener hears them.
        line.advance_to(Instant::from_nanos(2 * 1_145_834));
        line.tap_read(&mut tap);
        assert_eq!(tap, [0xAB, 0xCD]);
        run_until_idle(&mut line);
        tap.clear();
        line.tap_read(&mut tap);
        assert_eq!(tap, [0xAB, 0xCD], "the echo's reply");
        let mut master = Vec::new();
        line.master_read(&mut master);
        assert_eq!(master, [0xAB, 0xCD], "the master still gets the reply");
    }

    #[test]
    fn without_a_tap_nothing_is_kept() {
        let mut line = VirtualLine::new(9600, CharFormat::EVEN_8E1, Instant::ZERO);
        line.master_write(Instant::ZERO, &[1, 2, 3]);
        run_until_idle(&mut line);
        let mut tap = Vec::new();
        line.tap_read(&mut tap);
        assert!(tap.is_empty());
    }

    #[test]
    fn two_talkers_at_once_garble() {
        let (mut line, _, _) = echo_line(9600, 0);
        line.master_write(Instant::ZERO, &[1, 2, 3, 4]);
        // The device hears t3.5 of silence at 4.583 + 4.010 ms and starts its echo at once;
        // at 9 ms the master talks over it.
        line.advance_to(Instant::from_millis(9));
        line.master_write(Instant::from_millis(9), &[9, 9, 9, 9, 9, 9]);
        run_until_idle(&mut line);
        assert!(line.stats().collisions > 0);
        let mut got = Vec::new();
        line.master_read(&mut got);
        assert_ne!(got, [1, 2, 3, 4]);
    }

    #[test]
    fn every_master_hears_the_other_masters_and_the_drives() {
        let (mut line, heard, _) = echo_line(9600, 5);
        let standby = line.add_master();
        assert_eq!((standby, line.masters()), (1, 2));
        line.master_write(Instant::ZERO, &[0xAB, 0xCD]);
        // The standby hears each character when its last bit has arrived, not before.
        line.advance_to(Instant::from_nanos(1_145_833));
        let mut got = Vec::new();
        line.master_read_to(standby, &mut got);
        assert!(got.is_empty(), "{got:02X?}");
        line.advance_to(Instant::from_nanos(2 * 1_145_834));
        line.master_read_to(standby, &mut got);
        assert_eq!(got, [0xAB, 0xCD]);
        // Then the drive's answer, which both masters hear; the sender never hears itself.
        run_until_idle(&mut line);
        got.clear();
        line.master_read_to(standby, &mut got);
        assert_eq!(got, [0xAB, 0xCD], "the echo's reply");
        got.clear();
        line.master_read(&mut got);
        assert_eq!(got, [0xAB, 0xCD], "only the reply, not its own request");
        // The standby's request reaches the drive and the first master alike.
        let t = line.now() + Duration::from_millis(20);
        line.master_write_from(standby, t, &[0x11]);
        run_until_idle(&mut line);
        got.clear();
        line.master_read(&mut got);
        assert_eq!(got, [0x11, 0x11], "the standby's request, then the echo");
        assert_eq!(heard.lock().unwrap().last().unwrap().1, [0x11]);
        assert_eq!(line.stats().master_bytes, 3);
        assert_eq!((line.stats().collisions, line.stats().garbled_frames), (0, 0));
    }

    #[test]
    fn two_masters_at_once_garble_both_frames_and_each_is_counted_once() {
        let mut line = VirtualLine::new(9600, CharFormat::EVEN_8E1, Instant::ZERO);
        let b = line.add_master();
        let (dev, heard, _) = echo(1);
        line.add_device(Box::new(dev));
        // A sends 8 bytes; B starts 2 ms later, in the middle of A's frame.
        line.master_write(Instant::ZERO, &[1, 2, 3, 4, 5, 6, 7, 8]);
        line.master_write_from(b, Instant::from_millis(2), &[9, 9, 9, 9]);
        line.advance_to(Instant::from_millis(12));
        let stats = line.stats();
        assert_eq!(stats.garbled_frames, 2, "A's frame and B's: {stats:?}");
        assert_eq!((line.master_garbled_frames(MASTER), line.master_garbled_frames(b)), (1, 1));
        assert!(stats.collisions >= 4, "{stats:?}");
        // What the drive heard is not A's frame.
        let all: Vec<u8> = heard.lock().unwrap().iter().flat_map(|(_, b)| b.clone()).collect();
        assert!(!all.windows(8).any(|w| w == [1, 2, 3, 4, 5, 6, 7, 8]), "{all:?}");
        // A master that waits for silence collides with nobody: no new garbled frame.
        run_until_idle(&mut line);
        let before = line.stats().garbled_frames;
        let t = line.now() + Duration::from_millis(10);
        line.master_write_from(b, t, &[7, 7]);
        run_until_idle(&mut line);
        assert_eq!(line.stats().garbled_frames, before);
        // Several writes back to back are one frame: a second overlap on it is not recounted.
        let t = line.now() + Duration::from_millis(10);
        line.master_write(t, &[1, 1, 1]);
        line.master_write(t + Duration::from_micros(500), &[1, 1, 1]);
        line.master_write_from(b, t + Duration::from_micros(100), &[2]);
        line.master_write_from(b, t + Duration::from_micros(200), &[2]);
        line.advance_to(t + Duration::from_millis(8));
        assert_eq!(line.stats().garbled_frames, before + 2);
    }

    #[test]
    fn the_log_tells_who_sent_each_burst() {
        let (mut line, _, _) = echo_line(9600, 5);
        let b = line.add_master();
        line.attach_log();
        line.master_write(Instant::ZERO, &[1, 2]);
        run_until_idle(&mut line);
        let t = line.now() + Duration::from_millis(20);
        line.master_write_from(b, t, &[3]);
        run_until_idle(&mut line);
        let mut log = Vec::new();
        line.log_read(&mut log);
        assert_eq!(
            log,
            [
                (Talker::Master(0), vec![1, 2]),
                (Talker::Device(1), vec![1, 2]),
                (Talker::Master(b), vec![3]),
                (Talker::Device(1), vec![3]),
            ]
        );
    }

    #[test]
    fn an_unknown_master_is_ignored() {
        let mut line = VirtualLine::new(9600, CharFormat::EVEN_8E1, Instant::ZERO);
        line.master_write_from(3, Instant::ZERO, &[1, 2]);
        let mut got = Vec::new();
        line.master_read_to(3, &mut got);
        run_until_idle(&mut line);
        assert!(got.is_empty());
        assert_eq!(line.stats().master_bytes, 0);
    }

    #[test]
    fn silent_device_never_answers_and_noise_is_counted() {
        let (mut line, heard, _) = echo_line(115200, 1);
        line.set_silent(1, true);
        line.set_faults(Faults { corrupt_rate: 1.0, ..Default::default() });
        line.master_write(Instant::ZERO, &[0u8; 10]);
        run_until_idle(&mut line);
        let mut got = Vec::new();
        line.master_read(&mut got);
        assert!(got.is_empty());
        let heard: Vec<u8> = heard.lock().unwrap().iter().flat_map(|(_, b)| b.clone()).collect();
        assert_eq!(heard.len(), 10);
        assert!(heard.iter().all(|&b| b.count_ones() == 1), "one bit flipped per byte");
        assert_eq!(line.stats().corrupted, 10);
    }
}
