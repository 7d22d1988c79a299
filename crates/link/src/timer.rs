//! Sleeps that end when they should, not on the next whole millisecond.
//!
//! tokio's timers tick in milliseconds: a wait for the Modbus t3.5 gap (1.75 ms above 19200
//! baud) ends up to a millisecond late, on every transaction, which at 115200 baud costs a
//! quarter of the bus's throughput. [`sleep_until`] hands deadlines to one timer thread that
//! waits on a condition variable with microsecond timeouts and wakes the task; the thread idles
//! when nobody waits, and no task spins.
//!
//! Under tokio's paused clock (tests, simulated-time benchmarks) there is no wall time to keep:
//! [`sleep_until`] sees that the runtime's clock is not the wall clock and uses tokio's timer.

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::future::Future;
use std::pin::Pin;
use std::sync::{Condvar, Mutex, OnceLock};
use std::task::{Context, Poll, Waker};
use std::time::{Duration, Instant};

struct Entry {
    at: Instant,
    seq: u64,
    waker: Waker,
}

impl PartialEq for Entry {
    fn eq(&self, other: &Self) -> bool {
        (self.at, self.seq) == (other.at, other.seq)
    }
}
impl Eq for Entry {}
impl PartialOrd for Entry {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Entry {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        (self.at, self.seq).cmp(&(other.at, other.seq))
    }
}

#[derive(Default)]
struct Queue {
    heap: BinaryHeap<Reverse<Entry>>,
    seq: u64,
}

struct TimerThread {
    queue: Mutex<Queue>,
    changed: Condvar,
}

fn timer() -> &'static TimerThread {
    static TIMER: OnceLock<&'static TimerThread> = OnceLock::new();
    TIMER.get_or_init(|| {
        let t: &'static TimerThread =
            Box::leak(Box::new(TimerThread { queue: Mutex::new(Queue::default()), changed: Condvar::new() }));
        let spawned = std::thread::Builder::new().name("drivebus-timer".into()).spawn(move || run(t));
        if spawned.is_err() {
            // No thread: every sleep falls back to tokio's timer (see `PreciseSleep::poll`).
            t.queue.lock().unwrap_or_else(|p| p.into_inner()).seq = u64::MAX;
        }
        t
    })
}

fn run(t: &'static TimerThread) {
    let mut q = t.queue.lock().unwrap_or_else(|p| p.into_inner());
    loop {
        let now = Instant::now();
        while q.heap.peek().is_some_and(|Reverse(e)| e.at <= now) {
            if let Some(Reverse(e)) = q.heap.pop() {
                e.waker.wake();
            }
        }
        q = match q.heap.peek().map(|Reverse(e)| e.at) {
            Some(at) => {
                t.changed
                    .wait_timeout(q, at.saturating_duration_since(now))
                    .unwrap_or_else(|p| p.into_inner())
                    .0
            }
            None => t.changed.wait(q).unwrap_or_else(|p| p.into_inner()),
        };
    }
}

/// Whether the runtime's clock is the wall clock (not paused or advanced by tests).
fn runtime_clock_is_wall() -> bool {
    let tokio_now = tokio::time::Instant::now().into_std();
    let wall = Instant::now();
    let gap = if wall > tokio_now { wall - tokio_now } else { tokio_now - wall };
    gap < Duration::from_micros(200)
}

/// Deadlines further away than this wait on tokio's timer first, and on the timer thread only
/// for the last stretch: a response timeout of hundreds of milliseconds that is cancelled by the
/// reply costs no more than a tokio timer does.
const COARSE_MARGIN: Duration = Duration::from_millis(2);

/// Waits until `deadline` (a tokio instant) to within tens of microseconds on a running clock;
/// on a paused clock, as tokio's own timer does.
pub fn sleep_until(deadline: tokio::time::Instant) -> PreciseSleep {
    PreciseSleep { deadline, coarse: None, coarse_at: None, tokio_only: false }
}

/// The future of [`sleep_until`].
pub struct PreciseSleep {
    deadline: tokio::time::Instant,
    /// tokio's timer, for the stretch up to `COARSE_MARGIN` before the deadline (or all of it
    /// on a paused clock).
    coarse: Option<Pin<Box<tokio::time::Sleep>>>,
    coarse_at: Option<tokio::time::Instant>,
    tokio_only: bool,
}

impl PreciseSleep {
    /// Moves the deadline.
    pub fn reset(&mut self, deadline: tokio::time::Instant) {
        self.deadline = deadline;
        self.tokio_only = false;
    }

    /// Polls tokio's timer for `at`, re-arming it when `at` moved.
    fn poll_coarse(&mut self, at: tokio::time::Instant, cx: &mut Context<'_>) -> Poll<()> {
        if self.coarse_at != Some(at) {
            match self.coarse.as_mut() {
                Some(s) => s.as_mut().reset(at),
                None => self.coarse = Some(Box::pin(tokio::time::sleep_until(at))),
            }
            self.coarse_at = Some(at);
        }
        match self.coarse.as_mut() {
            Some(s) => s.as_mut().poll(cx),
            None => Poll::Ready(()),
        }
    }
}

impl Future for PreciseSleep {
    type Output = ();
    fn poll(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<()> {
        let now = tokio::time::Instant::now();
        if now >= self.deadline {
            return Poll::Ready(());
        }
        let deadline = self.deadline;
        if self.tokio_only || !runtime_clock_is_wall() {
            self.tokio_only = true;
            return self.poll_coarse(deadline, cx);
        }
        let early = deadline - COARSE_MARGIN.min(deadline - now);
        if now < early && self.poll_coarse(early, cx).is_pending() {
            return Poll::Pending;
        }
        let t = timer();
        let mut q = t.queue.lock().unwrap_or_else(|p| p.into_inner());
        if q.seq == u64::MAX {
            drop(q);
            self.tokio_only = true;
            return self.poll_coarse(deadline, cx);
        }
        q.seq += 1;
        let seq = q.seq;
        // A waker already queued for an earlier deadline is left there: a spurious wake-up
        // only polls this future again, which queues it anew.
        q.heap.push(Reverse(Entry { at: deadline.into_std(), seq, waker: cx.waker().clone() }));
        drop(q);
        t.changed.notify_one();
        Poll::Pending
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn a_sleep_ends_after_its_deadline_and_well_within_a_millisecond() {
        // Lateness is not asserted tightly (the machine may be busy); ending early is a bug.
        for us in [300u64, 1750, 2500] {
            let start = tokio::time::Instant::now();
            let deadline = start + Duration::from_micros(us);
            sleep_until(deadline).await;
            assert!(tokio::time::Instant::now() >= deadline, "{us} µs: woke early");
        }
    }

    #[tokio::test(start_paused = true)]
    async fn on_a_paused_clock_it_is_tokio_time() {
        let start = tokio::time::Instant::now();
        sleep_until(start + Duration::from_secs(3600)).await;
        assert!(start.elapsed() >= Duration::from_secs(3600));
    }
}
