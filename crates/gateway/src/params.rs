//! Parameter reads served from a value read a moment ago: a parameter read within
//! `param_cache_ms` of the last read of the same parameter of the same drive is answered with
//! that value, and reads of one parameter that come together go to the drive once (the others
//! wait for that answer). So many clients reading the same parameters cost the bus one read
//! per parameter per moment. A write of the parameter forgets its value.

use std::collections::HashMap;
use std::future::Future;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::time::Instant;

/// One value and when it was read.
type Slot = Arc<tokio::sync::Mutex<Option<(Instant, i64)>>>;

/// The recent parameter values of one drive.
pub(crate) struct ParamCache {
    keep: Duration,
    slots: Mutex<HashMap<String, Slot>>,
}

impl ParamCache {
    /// Values are kept for `keep` (zero: every read goes to the drive).
    pub(crate) fn new(keep: Duration) -> Self {
        ParamCache { keep, slots: Mutex::new(HashMap::new()) }
    }

    /// The raw value of parameter `name` (the catalog's name): the one read less than `keep`
    /// ago, or what `read` gets from the drive.
    pub(crate) async fn read<E, F>(&self, name: &str, read: impl FnOnce() -> F) -> Result<i64, E>
    where
        F: Future<Output = Result<i64, E>>,
    {
        if self.keep.is_zero() {
            return read().await;
        }
        let slot =
            self.slots.lock().unwrap_or_else(|p| p.into_inner()).entry(name.to_string()).or_default().clone();
        // Reads of the same parameter wait for the one in flight and take its value.
        let mut held = slot.lock().await;
        if let Some((at, raw)) = *held {
            if at.elapsed() < self.keep {
                return Ok(raw);
            }
        }
        let raw = read().await?;
        *held = Some((Instant::now(), raw));
        Ok(raw)
    }

    /// Forgets the value of parameter `name` (it was written).
    pub(crate) fn forget(&self, name: &str) {
        let slot = self.slots.lock().unwrap_or_else(|p| p.into_inner()).get(name).cloned();
        if let Some(slot) = slot {
            // A read in flight is left to finish: its value is what the drive had before the write
            // was confirmed, so it is not kept.
            match slot.try_lock() {
                Ok(mut held) => *held = None,
                Err(_) => {
                    self.slots.lock().unwrap_or_else(|p| p.into_inner()).remove(name);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicU32, Ordering};

    #[tokio::test(start_paused = true)]
    async fn a_value_read_a_moment_ago_is_reused_until_written_or_old() {
        let cache = ParamCache::new(Duration::from_millis(200));
        let reads = AtomicU32::new(0);
        let read = || async {
            tokio::time::sleep(Duration::from_millis(10)).await;
            Ok::<_, ()>(i64::from(reads.fetch_add(1, Ordering::Relaxed)))
        };
        // Ten readers at once: one read on the bus.
        let all = futures_util::future::join_all((0..10).map(|_| cache.read("P0.02", read))).await;
        assert!(all.iter().all(|r| *r == Ok(0)), "{all:?}");
        assert_eq!(cache.read("P0.02", read).await, Ok(0));
        assert_eq!(cache.read("P0.03", read).await, Ok(1), "another parameter is read");
        cache.forget("P0.02");
        assert_eq!(cache.read("P0.02", read).await, Ok(2), "a written parameter is read again");
        tokio::time::sleep(Duration::from_millis(200)).await;
        assert_eq!(cache.read("P0.02", read).await, Ok(3), "an old value is read again");
        assert_eq!(ParamCache::new(Duration::ZERO).read("P0.02", read).await, Ok(4));
        assert_eq!(ParamCache::new(Duration::ZERO).read("P0.02", read).await, Ok(5));
    }
}
