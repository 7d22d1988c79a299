//! The B800 receiver state machine as a [`Scanner`].
//!
//! 1. Wait for FG1 (7E); bytes outside a frame are noise.
//! 2. Collect hex digits. Any other byte except 7F ends the frame ("non-hex byte 0x01 at
//!    offset 3 ends the frame", offset counted from the 7E); a 7E always starts a new frame.
//! 3. On FG2 (7F), require an even number of digits, at least 6 (DA, CMD, CS).
//! 4. Verify CS over the ASCII characters as received.
//!
//! Frames are delimited by flags, so a failed candidate is skipped whole: it cannot hold a
//! frame (a 7E inside it would have ended it).

use crate::deframe::{Scan, Scanner};
use crate::describe::Direction;
use crate::error::FrameError;

use super::frame::{pair, verify, HEX};
use super::values::{Address, Destination};
use super::{FG1, FG2, SCAN_LIMIT};

/// Cuts a byte stream into B800 frames.
///
/// With a direction set, whole frames whose DA shows the other side (a master's own echo, or
/// another drive's reply heard by a drive) are skipped as noise; damaged frames are reported
/// whichever side sent them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameScanner {
    from: Option<Direction>,
}

impl FrameScanner {
    /// A scanner for frames from `from`, or from both sides with `None` (a line monitor).
    pub const fn new(from: Option<Direction>) -> FrameScanner {
        FrameScanner { from }
    }

    /// The side whose frames this scanner delivers, `None` for both.
    pub const fn from(&self) -> Option<Direction> {
        self.from
    }

    /// The candidate `frame` (7E, digits, 7F) is complete: check it.
    #[inline]
    fn end(&self, frame: &[u8]) -> Scan {
        let len = frame.len();
        let digits = match frame {
            [_, digits @ .., _] => digits,
            _ => return Scan::Noise { len: len.max(1) },
        };
        // seed 000 gives the layout FG1 [DA] [CMD] ([DATA]) [CS] FG2, each field 2 digits
        // per byte: an odd count or fewer than 6 digits cannot be a frame.
        if let Err(error) = verify(digits) {
            return Scan::Invalid { len, skip: len, error };
        }
        if let (Some(side), [a0, a1, ..]) = (self.from, digits) {
            let da = pair(*a0, *a1);
            let other = match side {
                Direction::Master => Address::new(da).is_some(),
                Direction::Drive => Destination::from_da(da).is_some(),
            };
            if other {
                return Scan::Noise { len };
            }
        }
        Scan::Frame { len }
    }
}

impl Scanner for FrameScanner {
    type Buffer = [u8; SCAN_LIMIT];

    #[inline]
    fn scan(&self, buf: &[u8], checked: usize) -> Scan {
        match buf.first() {
            Some(&FG1) => {}
            Some(_) => {
                // Outside a frame everything up to the next 7E is noise (a stray 7F too).
                let len = buf.iter().position(|&b| b == FG1).unwrap_or(buf.len());
                return Scan::Noise { len };
            }
            None => return Scan::Incomplete { checked: 0 },
        }
        let end = buf.len().min(SCAN_LIMIT);
        // Bytes before `checked` were digits on the previous call.
        let start = checked.clamp(1, end.max(1));
        let Some(rest) = buf.get(start..end) else {
            return Scan::Incomplete { checked: 0 };
        };
        for (k, &b) in rest.iter().enumerate() {
            if HEX[b as usize] <= 0x0F {
                continue;
            }
            let i = start + k;
            return match b {
                FG2 => buf.get(..=i).map_or(Scan::Noise { len: 1 }, |frame| self.end(frame)),
                // A 7E always starts a new frame; the digits before it were a frame cut short.
                FG1 if i == 1 => Scan::Noise { len: 1 },
                FG1 => Scan::Invalid {
                    len: i,
                    skip: i,
                    error: FrameError::Malformed("a new start flag 7E came before the stop flag 7F"),
                },
                // seed 000: "Any non-ASCII byte received other than the START / STOP flags will
                // terminate the data reception and a new sequence must be started."
                // The seed says non-ASCII; an ASCII byte that is not a hex digit cannot be a
                // field either, so it ends the frame too (project decision).
                _ => Scan::Invalid {
                    len: i + 1,
                    skip: i + 1,
                    error: FrameError::NonHex { byte: b, offset: i },
                },
            };
        }
        if end == SCAN_LIMIT {
            // The longest B800 frame is 12 bytes; the limit leaves room to report wrong DATA
            // lengths by name, but nothing longer can be a frame.
            return Scan::Invalid {
                len: SCAN_LIMIT,
                skip: SCAN_LIMIT,
                error: FrameError::TooLong {
                    what: "a B800 frame (no stop flag 7F)",
                    max: super::MAX_FRAME,
                    got: SCAN_LIMIT,
                },
            };
        }
        Scan::Incomplete { checked: end }
    }

    fn truncated(&self, buf: &[u8]) -> FrameError {
        FrameError::Truncated {
            what: "a B800 frame (no stop flag 7F yet)",
            expected: (buf.len() + 1).max(super::MIN_FRAME),
            got: buf.len(),
        }
    }
}
