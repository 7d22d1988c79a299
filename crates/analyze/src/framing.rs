//! Framing: each protocol's deframer behind one trait object, so a listener runs several side by
//! side, and a whole frame parsed into the report the sniffer prints.

use drivebus_proto::protocol::{CodecJob, WireProtocol};
use drivebus_proto::{Codec, Deframer, Direction, Event, Scan, Scanner};

use crate::report::{describe, FrameReport};

/// A frame candidate out of a deframer: its bytes and, when it is not a whole frame with a
/// good checksum, why.
pub(super) struct Cut {
    pub(super) bytes: Vec<u8>,
    pub(super) error: Option<String>,
}

/// One protocol's deframer behind a trait object, so a listener can run several.
pub(super) trait Framer: Send {
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
    /// From now on, frames are read as sent by `from` (`None`: either direction); the bytes of
    /// a frame in progress are read again that way, and the frames they make go to `out`.
    fn expect(&mut self, from: Option<Direction>, out: &mut Vec<Cut>);
}

/// A deframer, whose frames it reads, and a copy of the bytes it holds for a frame in
/// progress.
struct Typed<C: Codec> {
    deframer: Deframer<C::Scanner>,
    from: Option<Direction>,
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
    fn expect(&mut self, from: Option<Direction>, out: &mut Vec<Cut>) {
        if from == self.from {
            return;
        }
        self.from = from;
        self.deframer = Deframer::new(C::scanner(from));
        let held = std::mem::take(&mut self.held);
        self.push(&held, out);
    }
}

/// A deframer for `protocol` and frames from `from` (`None`: both directions on one pair).
pub(super) fn framer(protocol: &str, from: Option<Direction>) -> Option<Box<dyn Framer>> {
    struct Make(Option<Direction>);
    impl CodecJob for Make {
        type Output = Box<dyn Framer>;
        fn run<C: Codec + 'static>(self) -> Box<dyn Framer>
        where
            C::Scanner: Send + 'static,
        {
            Box::new(Typed::<C> {
                deframer: Deframer::new(C::scanner(self.0)),
                from: self.0,
                held: Vec::new(),
            })
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
