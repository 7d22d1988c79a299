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
//! A receiver checks only the first stop bit, so 1 and 2 stop bits cannot be told apart: the
//! candidates have one stop bit, except the 7-bit format without parity, which no common
//! protocol uses with one (Modbus ASCII's 7N2).

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
pub fn candidates() -> Vec<(u32, CharFormat)> {
    BAUDS.iter().flat_map(|&b| FORMATS.iter().map(move |&f| (b, f))).collect()
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
