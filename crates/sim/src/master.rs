//! A minimal master for tests and benchmarks on a [`VirtualLine`]: puts one request on the line
//! and runs the line on simulated time until the protocol's deframer holds a whole reply, or the
//! response timeout passes. (Real masters use `drivebus-link`'s bus owner; this one has no
//! retries and no queue, so a test sees exactly what one exchange did.)

use std::time::Duration;

use crate::bus::VirtualLine;
use drivebus_proto::deframe::{Deframer, Event, Scanner};

/// The times a [`LineMaster`] keeps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LineMaster {
    /// Silence before each request (Modbus t3.5, seed 004's 10 ms).
    pub gap_before: Duration,
    /// Silence after each exchange (FC: 2 characters after a reply).
    pub gap_after: Duration,
    /// From the end of the request to a whole reply.
    pub timeout: Duration,
    /// Wait after a request no reply is due to (a broadcast).
    pub turnaround: Duration,
}

impl LineMaster {
    /// Sends `request`; returns the first whole reply frame the `scanner` finds, or `None`
    /// after a broadcast (`expect_reply` false) or when nothing whole came in time. Bytes left
    /// on the line from before the request are discarded.
    pub fn transact<S: Scanner>(
        &self,
        line: &mut VirtualLine,
        scanner: S,
        request: &[u8],
        expect_reply: bool,
    ) -> Option<Vec<u8>> {
        let start = line.now() + self.gap_before;
        line.run_until(start);
        let mut stale = Vec::new();
        line.master_read(&mut stale);
        line.master_write(start, request);
        let sent = start + line.char_time() * request.len() as u32;
        if !expect_reply {
            line.run_until(sent + self.turnaround);
            line.master_read(&mut stale);
            return None;
        }
        let deadline = sent + self.timeout;
        let mut deframer = Deframer::new(scanner);
        let mut frame = None;
        let mut got = Vec::new();
        while frame.is_none() {
            match line.next_deadline() {
                Some(t) if t <= deadline => line.advance_to(t),
                _ => {
                    line.advance_to(deadline);
                    break;
                }
            }
            got.clear();
            line.master_read(&mut got);
            deframer.push(&got, &mut |e| {
                if let Event::Frame { bytes, .. } = e {
                    frame.get_or_insert_with(|| bytes.to_vec());
                }
            });
        }
        let end = line.now() + self.gap_after;
        line.run_until(end);
        frame
    }
}
