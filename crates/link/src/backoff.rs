//! How long to wait before opening a lost port again: 250 ms, doubling after each failed open
//! up to 5 s. The bus engine reopens a bus's port on this schedule, and the gateway's Modbus RTU
//! slave its own port, so both come back alike.

use std::time::Duration;

/// The waits between opens of a port that will not open: [`Backoff::FIRST`], doubling after each
/// failure up to [`Backoff::MAX`]. Sans-IO: the caller waits, on whatever clock it keeps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Backoff {
    next: Duration,
}

impl Default for Backoff {
    fn default() -> Self {
        Backoff::new()
    }
}

impl Backoff {
    /// The first wait after a failed open.
    pub const FIRST: Duration = Duration::from_millis(250);
    /// The longest wait between two opens.
    pub const MAX: Duration = Duration::from_secs(5);

    /// A schedule that starts at [`Backoff::FIRST`] (the port was open, or never tried).
    pub fn new() -> Self {
        Backoff { next: Self::FIRST }
    }

    /// An open failed: the wait before the next one (the one after is twice as long, up to
    /// [`Backoff::MAX`]).
    pub fn failed(&mut self) -> Duration {
        let wait = self.next;
        self.next = (wait * 2).min(Self::MAX);
        wait
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn waits_double_from_250_ms_up_to_5_s() {
        let mut b = Backoff::new();
        let waits: Vec<u64> = (0..8).map(|_| b.failed().as_millis() as u64).collect();
        assert_eq!(waits, [250, 500, 1000, 2000, 4000, 5000, 5000, 5000]);
        assert_eq!(Backoff::default(), Backoff::new());
    }
}
